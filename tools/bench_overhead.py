"""Wall time of a run with the takeover, collision checks and recording vs the same SUMO run
with no plug-in attached, on the dense bundled scenario (~200 vehicles, ~50 pedestrians).

Both sides run the same scenario, seed and forced collision options; the plain side inserts
the same ego route as an ordinary SUMO vehicle. Timed is the window from the ego's takeover
to the end of the run (the warm-up before it is identical on both sides), on the plug-in side
once for the step loop alone and once including the fixed end-of-run cost (closing SUMO,
writing the Parquet outputs and the summary; the first run in a process also pays ~0.15 s for
pyarrow importing pandas, which this tool has imported already). Repeats are interleaved;
medians are reported, with the plug-in's per-step phases from ``timings.parquet`` (``other``
is the loop time no phase covers).

    python tools/bench_overhead.py [--repeats 5] [--scenario scenarios/urban_grid/urban_grid.sumocfg]
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

import libsumo
import pandas as pd

from sumo_ethics.config import RunConfig
from sumo_ethics.runner import run
from sumo_ethics.sim import session

ROOT = Path(__file__).resolve().parents[1]


def plugin_run(cfg: Path, out: Path, seed: int, depart: float, end: float, ego_from: str, ego_to: str,
               controller: str) -> dict:
    s = run(RunConfig(cfg, out, seed=seed, end=end, ego_depart=depart, ego_from=ego_from, ego_to=ego_to,
                      stop_at_collision=False, progress=False, controller=controller))
    d = s.data
    phases = pd.read_parquet(out / "timings.parquet").drop(columns="step").mean().to_dict()  # ms per step
    return {"window": d["wall_time"] - d["takeover_wall"], "loop": d["loop_wall"] - d["takeover_wall"],
            "t0": d["takeover_time"], "t1": d["sim_time"], "steps": d["steps"], "phases": phases}


def plain_run(cfg: Path, seed: int, t0: float, t1: float, route: list[str]) -> tuple[float, int, int]:
    files = session.read_scenario(cfg)
    with tempfile.TemporaryDirectory() as tmp:
        session.start(files, seed, Path(tmp) / "err.log")
        try:
            libsumo.route.add("bench_ego_route", route)
            while libsumo.simulation.getTime() < t0 - 1e-9:
                libsumo.simulationStep()
                if abs(libsumo.simulation.getTime() - (t0 - 5.0)) < 1e-6:
                    libsumo.vehicle.add("bench_ego", "bench_ego_route", depart="now", departLane="best")
            nveh, nper = libsumo.vehicle.getIDCount(), libsumo.person.getIDCount()
            w = time.perf_counter()
            while libsumo.simulation.getTime() < t1 - 1e-9:
                libsumo.simulationStep()
            return time.perf_counter() - w, nveh, nper
        finally:
            session.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", type=Path, default=ROOT / "scenarios/urban_grid/urban_grid.sumocfg")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--seed", type=int, default=2)
    ap.add_argument("--depart", type=float, default=300.0)
    ap.add_argument("--end", type=float, default=480.0)
    ap.add_argument("--ego-from", default="W0_in")
    ap.add_argument("--ego-to", default="E1_out")
    ap.add_argument("--controller", default="baseline",
                    help="the takeover is measured with the cheap baseline; the planner has tools/bench_planner.py")
    a = ap.parse_args()
    plug, loop, plain, phases = [], [], [], []
    info = {}
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(a.repeats):
            r = plugin_run(a.scenario, Path(tmp) / f"run{i}", a.seed, a.depart, a.end, a.ego_from, a.ego_to,
                           a.controller)
            plug.append(r["window"])
            loop.append(r["loop"])
            phases.append(r["phases"])
            route = json.loads((Path(tmp) / f"run{i}" / "summary.json").read_text())["route_edges"]
            w, nveh, nper = plain_run(a.scenario, a.seed, r["t0"], r["t1"], route)
            plain.append(w)
            info = {"window_s": r["t1"] - r["t0"], "steps": r["steps"], "vehicles": nveh, "persons": nper}
            print(f"repeat {i}: plug-in {plug[-1]:.3f} s (loop {loop[-1]:.3f} s), plain {plain[-1]:.3f} s, "
                  f"ratio {plug[-1] / plain[-1]:.3f} (loop {loop[-1] / plain[-1]:.3f})")
    n = info["steps"]
    mp, ml, mq = statistics.median(plug), statistics.median(loop), statistics.median(plain)
    print(f"scenario {a.scenario.name}: {info['vehicles']} vehicles and {info['persons']} persons at takeover, "
          f"{info['window_s']:.0f} s simulated after takeover ({n} ego steps, controller: {a.controller})")
    print(f"median wall: plug-in {mp:.3f} s (step loop {ml:.3f} s), plain SUMO {mq:.3f} s")
    print(f"ratio of medians: {mp / mq:.3f} with the end-of-run outputs, {ml / mq:.3f} step loop only; "
          f"median of paired ratios {statistics.median(p / q for p, q in zip(plug, plain)):.3f} / "
          f"{statistics.median(p / q for p, q in zip(loop, plain)):.3f} (target <= 1.3)")
    per = {k: statistics.median(ph[k] for ph in phases) for k in phases[0]}
    per["other"] = 1e3 * ml / n - sum(per.values())
    print(f"per step [ms]: plug-in {1e3 * mp / n:.3f} ({1e3 * ml / n:.3f} in the loop + {1e3 * (mp - ml) / n:.3f} "
          f"end-of-run outputs spread over the steps), plain {1e3 * mq / n:.3f}")
    print("plug-in loop per step [ms]: " + ", ".join(f"{k.removesuffix('_ms')} {v:.3f}" for k, v in per.items())
          + "  (sumo = moveToXY + setSpeed + simulationStep)")


if __name__ == "__main__":
    main()
