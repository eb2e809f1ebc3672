"""The planner's kernels compiled in a background process (sumo_ethics.plan.warmup): after it,
a new process finds every kernel the planner calls in numba's cache and compiles nothing."""

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
