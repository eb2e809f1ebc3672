"""What measuring the conflicts among everyone costs (``[conflicts] everyone = true``): the same run
with the option off and on, interleaved and repeated.

By default a fleet run on eclipse-sumo's ``tools/game/fokr_bs_demo.sumocfg`` (Braunschweig's
Forschungskreuzung, 0.05 s steps, from 15:00:00) to ``--end`` with every ``--penetration`` share of
its eligible vehicles an ego driven by the baseline route follower: the cheapest controller, so the
step loop is mostly SUMO and the added cost stands out. Reported per run: the step loop's wall
time per step (``loop_wall`` / steps), and with the option on the measuring's own time per step
(reading every road user and their pairs, ``summary.json`` ``conflicts_others.ms_per_step``), the
road users read, candidate pairs from the k-d tree and pairs measured for TTC and PET per step, and
the events. The option must change nothing else: steps, collisions and conflicts parquet are
compared byte for byte between off and on.

    python tools/bench_conflicts_others.py [--scenario X.sumocfg] [--end 54040] [--penetration 0.2] [--repeats 2]
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
from pathlib import Path


def fokr() -> Path:
    import sumo

    return Path(sumo.SUMO_HOME) / "tools" / "game" / "fokr_bs_demo.sumocfg"


def one(scenario: Path, end: float, penetration: float, seed: int, out: Path, on: bool) -> dict:
    from sumo_ethics.config import ConflictConfig, FleetSpec, RunConfig
    from sumo_ethics.runner.fleet import run_fleet

    cfg = RunConfig(scenario, out, seed=seed, end=end, progress=False, conflicts=ConflictConfig(everyone=on),
                    fleet=FleetSpec(penetration=penetration, shares=(("baseline", 1.0),)))
    s = run_fleet(cfg).data
    files = {n: (out / f"{n}.parquet").read_bytes() for n in ("steps", "collisions", "conflicts")}
    return {"loop_ms": 1e3 * s["loop_wall"] / max(s["steps"], 1), "steps": s["steps"], "egos": s["fleet"]["egos"],
            "others": s.get("conflicts_others"), "files": files}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenario", type=Path, default=None, help="a .sumocfg (default: eclipse-sumo's fokr_bs_demo)")
    ap.add_argument("--end", type=float, default=54040.0, help="end time [s] (default 15:00:40)")
    ap.add_argument("--penetration", type=float, default=0.2)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--repeats", type=int, default=2)
    a = ap.parse_args()
    scenario = a.scenario or fokr()
    runs: dict[bool, list[dict]] = {False: [], True: []}
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(a.repeats):
            for on in (False, True):
                r = one(scenario, a.end, a.penetration, a.seed, Path(tmp) / f"{on}-{k}", on)
                runs[on].append(r)
                extra = ""
                if on:
                    o = r["others"]
                    p = o["pairs_per_step"]
                    extra = (f", measuring {o['ms_per_step']:.2f} ms/step: {p['road_users']:.1f} road users, "
                             f"{p['candidates']:.1f} candidate pairs, {p['ttc']:.1f} TTC, {p['pet']:.1f} PET per step; "
                             f"{o['total']} events {json.dumps(o['by_group'])}")
                print(f"{'on ' if on else 'off'} #{k}: {r['steps']} steps, {r['egos']} egos, "
                      f"loop {r['loop_ms']:.2f} ms/step{extra}", flush=True)
    off = statistics.median(r["loop_ms"] for r in runs[False])
    on_ = statistics.median(r["loop_ms"] for r in runs[True])
    meas = statistics.median(r["others"]["ms_per_step"] for r in runs[True])
    same = all(r["files"] == runs[False][0]["files"] for r in runs[False] + runs[True])
    print(f"median loop per step: off {off:.2f} ms, on {on_:.2f} ms (+{on_ - off:.2f} ms); the measuring itself "
          f"{meas:.2f} ms/step; steps/collisions/conflicts the same bytes off and on: {same}")


if __name__ == "__main__":
    main()
