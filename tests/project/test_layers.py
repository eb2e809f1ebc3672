"""The house's layers (issue 42): imports run one way, and the planner, the ethics and the predictor
work without the simulator.

- ``tools/import_graph.py`` reads every import of the package (function-local ones too): no loop
  among sub-packages or files, and no arrow from a floor to a higher one (its FLOORS).
- With libsumo, traci and sumolib made unimportable, the ethical planner with the shipped map-aware
  attention LSTM plans a step on a synthetic three-lane road (``sumo_ethics.plan.synthetic``'s scene, the one tools/bench_planner.py times) and
  picks a candidate that keeps clear of the agents' boxes at their predicted means.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _graph(*flags: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(ROOT / "tools" / "import_graph.py"), *flags], capture_output=True,
                          text=True, timeout=120)


def test_no_loop_and_no_arrow_back_up_between_rooms():
    out = _graph()
    assert out.returncode == 0, out.stdout + out.stderr
    assert ", 0 loop(s), 0 arrow(s) back up" in out.stdout


def test_no_loop_and_no_arrow_back_up_between_files():
    out = _graph("--files")
    assert out.returncode == 0, out.stdout + out.stderr
    assert ", 0 loop(s), 0 arrow(s) back up" in out.stdout


def test_the_graph_tool_sees_a_loop_and_an_arrow_up(tmp_path):
    """The checker can fail: a copy of the package with one import added from the ground floor
    (``geometry``) to the runner shows a loop and an arrow back up."""
    import shutil

    copy = tmp_path / "house"
    shutil.copytree(ROOT / "sumo_ethics", copy / "sumo_ethics", ignore=shutil.ignore_patterns("__pycache__", "weights"))
    (copy / "tools").mkdir()
    shutil.copy(ROOT / "tools" / "import_graph.py", copy / "tools")
    geometry = copy / "sumo_ethics" / "geometry.py"
    geometry.write_text(geometry.read_text() + "\n\ndef _late():\n    from sumo_ethics.runner import run  # noqa\n")
    out = subprocess.run([sys.executable, str(copy / "tools" / "import_graph.py")], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 1
    assert "up: geometry -> runner" in out.stdout
    assert "1 loop(s)" in out.stdout


BLOCKED = textwrap.dedent("""
    import sys
    for name in ("libsumo", "traci", "sumolib", "sumo"):
        sys.modules[name] = None  # any import of them raises ImportError
    import numpy as np
    from sumo_ethics.plan import synthetic
    from sumo_ethics.plan.ethical import EthicalPlanner, PlannerConfig
    sc = synthetic.scene(8, seed=3)
    planner = EthicalPlanner(PlannerConfig())  # the default: the map-aware attention LSTM, calibrated
    planner.predictor.map_source = synthetic.lane_source(sc)
    d = planner.act(sc)
    c = d.command
    assert all(np.isfinite([c.x, c.y, c.yaw, c.speed])), c
    # one 0.1 s step at 12 m/s: the ego moves about 1.2 m along the road, not sideways off it
    assert 0.5 < c.x - 100.0 < 2.0 and abs(c.y) < 0.5, c
    loaded = sorted(m for m in ("libsumo", "traci", "sumolib") if sys.modules.get(m) is not None)
    print("planned", d.info.get("validity"), "torch" in sys.modules, loaded)
""")


def test_the_planner_and_predictor_plan_a_step_with_libsumo_blocked():
    code = BLOCKED
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert out.returncode == 0, out.stderr[-3000:]
    line = out.stdout.strip().splitlines()[-1]
    assert line.startswith("planned ") and line.endswith(" True []"), line  # torch ran the LSTM; no SUMO module
