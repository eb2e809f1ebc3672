"""The planner's kernels compiled in a background process (sumo_ethics.plan.warmup): after it,
a new process finds every kernel the planner calls in numba's cache and compiles nothing, and
real planning steps call every kernel with the types the warm-up compiled (nothing compiled at the
first step)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

from sumo_ethics.plan import warmup

PROBE = """
import json
from sumo_ethics.ethics import search, shapes
from sumo_ethics.plan import feasibility, sampling, warmup
warmup.compile_kernels()
print(json.dumps({f.__name__: [sum(f.stats.cache_hits.values()), sum(f.stats.cache_misses.values())]
                  for f in (search._search_kernel, shapes._envelope_kernel, feasibility._check_kernel,
                            sampling._profile_kernel, sampling._cartesian_kernel)}))
"""


def test_background_compile_fills_the_cache_a_new_process_loads(tmp_path, monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))  # an empty cache: the background process compiles
    warmup.start()
    warmup.wait()
    for kernel in ("search._search_kernel", "shapes._envelope_kernel", "feasibility._check_kernel",
                   "sampling._profile_kernel", "sampling._cartesian_kernel"):
        assert any(tmp_path.rglob(f"*{kernel}*.nbi")), kernel
    out = subprocess.run([sys.executable, "-c", PROBE], env=dict(os.environ), capture_output=True, text=True,
                         check=True, timeout=300).stdout
    stats = json.loads(out.strip().splitlines()[-1])
    for name, (hits, misses) in stats.items():
        assert hits == 1 and misses == 0, (name, hits, misses)  # loaded, not compiled


def test_wait_without_start_is_a_no_op():
    warmup.wait()
    warmup.wait()


SIGNATURES = """
import json
import numba
from sumo_ethics import geometry
from sumo_ethics.ethics import probability, search, shapes
from sumo_ethics.plan import feasibility, sampling, warmup
from sumo_ethics.plan.ethical import EthicalPlanner, PlannerConfig
from sumo_ethics.plan.synthetic import lane_source, scene

mods = (search, shapes, feasibility, sampling, probability, geometry)

def signatures():
    return {f"{m.__name__}.{k}": [str(s) for s in v.signatures] for m in mods for k, v in vars(m).items()
            if isinstance(v, numba.core.registry.CPUDispatcher)}

warmup.compile_kernels()
warmup.compile_helpers()
before = signatures()
for n, replan in ((3, 1), (20, 1), (45, 3)):  # a few, many road users; planning and following a plan
    sc = scene(n, seed=n)
    planner = EthicalPlanner(PlannerConfig(replan_every=replan))
    planner.predictor.map_source = lane_source(sc)
    for _ in range(4):
        planner.act(sc)
print(json.dumps({"before": before, "after": signatures()}))
"""


def test_planning_steps_call_the_kernels_with_the_types_the_warmup_compiled(tmp_path):
    """The default planner's steps (3 to 45 road users, replanning every step and every third)
    after the warm-up: no kernel gains a second compiled signature (a read-only array where the
    warm-up passed a writable one, or a literal 0 where it passed an int, is a new type and a new
    compile of some seconds at the first step); every kernel has one signature."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))
    out = subprocess.run([sys.executable, "-c", SIGNATURES], env=env, capture_output=True, text=True, check=True,
                         timeout=600).stdout
    got = json.loads(out.strip().splitlines()[-1])
    before, after = got["before"], got["after"]
    assert "sumo_ethics.ethics.shapes._envelope_kernel" in after and "sumo_ethics.ethics.search._search_kernel" in after
    assert {k: v for k, v in after.items() if v != before.get(k)} == {}
    assert {k: v for k, v in after.items() if len(v) > 1} == {}
