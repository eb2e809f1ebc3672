"""Memory of a long run: resident set size (RSS) every 1,000 steps of an 18,000-step run.

Outputs are streamed (a chunk of rows is written every 2 simulated seconds), so memory must stay
flat: the check is that RSS never rises more than 50 MB above its value after 1,000 steps.
Before streaming every row was held until the end (about 4 MB more per 1,000 steps).

The scenario is built here with netconvert: a straight 26 km road, two lanes each way, with
traffic both ways; the ego (the baseline controller by default, fast) drives it from one end
for 1800.0 s of 0.1 s steps without reaching the other.

    python tools/bench_memory.py [--steps 18000] [--controller baseline|ethical] [--limit-mb 50]

(``--controller ethical`` uses the constant-velocity predictor.) Exits 1 when the limit is broken.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import psutil
import sumo

from sumo_ethics.config import RunConfig
from sumo_ethics.runner import run

SEGMENTS, SEGMENT_M = 13, 2000.0


def build_scenario(folder: Path) -> Path:
    nodes = "".join(f'<node id="n{i}" x="{i * SEGMENT_M}" y="0" type="priority"/>' for i in range(SEGMENTS + 1))
    edges = "".join(f'<edge id="e{i}" from="n{i}" to="n{i + 1}" numLanes="2" speed="13.89"/>'
                    f'<edge id="r{i}" from="n{i + 1}" to="n{i}" numLanes="2" speed="13.89"/>' for i in range(SEGMENTS))
    (folder / "n.nod.xml").write_text(f"<nodes>{nodes}</nodes>\n")
    (folder / "e.edg.xml").write_text(f"<edges>{edges}</edges>\n")
    netconvert = Path(sumo.SUMO_HOME) / "bin" / "netconvert"
    subprocess.run([str(netconvert), "-n", "n.nod.xml", "-e", "e.edg.xml", "-o", "long.net.xml", "--no-turnarounds",
                    "true", "--offset.disable-normalization", "true"], cwd=folder, check=True, capture_output=True)
    fwd = " ".join(f"e{i}" for i in range(SEGMENTS))
    back = " ".join(f"r{i}" for i in reversed(range(SEGMENTS)))
    (folder / "long.rou.xml").write_text(
        '<routes><vType id="car" vClass="passenger" length="4.5" width="1.8"/>'
        f'<route id="fwd" edges="{fwd}"/><route id="back" edges="{back}"/>'
        '<flow id="f" type="car" route="fwd" begin="0" end="3600" vehsPerHour="400" departLane="random"/>'
        '<flow id="b" type="car" route="back" begin="0" end="3600" vehsPerHour="400" departLane="random"/>'
        "</routes>\n")
    cfg = folder / "long.sumocfg"
    cfg.write_text('<configuration><input><net-file value="long.net.xml"/><route-files value="long.rou.xml"/>'
                   '</input><time><begin value="0"/><end value="4000"/><step-length value="0.1"/></time>'
                   "</configuration>\n")
    return cfg


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=18_000)
    ap.add_argument("--controller", choices=["baseline", "ethical"], default="baseline")
    ap.add_argument("--limit-mb", type=float, default=50.0)
    ap.add_argument("--every", type=int, default=1000, help="sample RSS every this many steps")
    a = ap.parse_args()
    proc = psutil.Process()
    samples: list[tuple[int, float, float]] = []  # (step, RSS MB, wall s)
    t0 = time.perf_counter()
    state = {"step": 0}

    def sample(snapshot, world) -> None:  # a step hook: called once per ego step
        state["step"] += 1
        if state["step"] % a.every == 0:
            samples.append((state["step"], proc.memory_info().rss / 2**20, time.perf_counter() - t0))

    with tempfile.TemporaryDirectory() as tmp:
        cfg = build_scenario(Path(tmp))
        depart = 10.0
        planner = None
        if a.controller == "ethical":
            from sumo_ethics.plan.ethical import PlannerConfig

            planner = PlannerConfig(predictor="cv")
        rc = RunConfig(cfg, Path(tmp) / "run", seed=1, ego_from="e0", ego_to=f"e{SEGMENTS - 1}", ego_depart=depart,
                       end=depart + a.steps * 0.1 + 0.15, controller=a.controller, planner=planner, progress=False,
                       stop_at_collision=False)
        s = run(rc, hooks=(sample,))
        import pyarrow.parquet as pq

        rows = pq.read_metadata(Path(tmp) / "run" / "steps.parquet").num_rows
    print(f"{a.controller} controller, {s.data['steps']} steps ({rows} rows in steps.parquet), status "
          f"{s.status.value}: {s.message}; wall {time.perf_counter() - t0:.1f} s")
    print(f"{'step':>7} {'RSS MB':>8} {'vs 1000':>8} {'wall s':>7}")
    base = next((m for k, m, _ in samples if k == a.every), samples[0][1] if samples else 0.0)
    for k, m, w in samples:
        print(f"{k:>7} {m:>8.1f} {m - base:>+8.1f} {w:>7.1f}")
    rise = max((m for k, m, _ in samples if k >= a.every), default=base) - base
    ok = rise <= a.limit_mb and s.data["steps"] >= a.steps
    print(f"largest rise over the RSS after {a.every} steps: {rise:+.1f} MB (limit {a.limit_mb:g} MB): "
          f"{'flat' if ok else 'NOT flat'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
