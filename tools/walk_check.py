"""Is the map context's lane after a walking area (map version 4) the lane pedestrians really take?

    python tools/walk_check.py [SUMOCFG] [--seconds 300] [--seed 1]

Every 1 s of simulated time, each walking pedestrian whose next lane is a walking area gets its
``after_lane`` from :func:`sumo_ethics.sim.lanes.agent_context` (the shortest walk through the
junction to the walk's next sidewalk). Its lanes are then followed every 0.1 s; a row is scored
when the pedestrian enters that walking area and leaves it within the run, and it is right when
the first lane after the walking area is ``after_lane``.
"""

from __future__ import annotations

import argparse
import collections
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def check(cfg: Path, seconds: float, seed: int) -> collections.Counter:
    """Counts: rows (next lane a walking area), with an after lane, scored, right; and examples."""
    import libsumo as ls
    import numpy as np

    from sumo_ethics.sim.lanes import SignalClock, agent_context, crossing_signals, lane_graph
    from sumo_ethics.sim.scenario import read_scenario, redirected
    from sumo_ethics.sim.session import output_args

    out: collections.Counter = collections.Counter()
    lanes: dict[str, list[str]] = collections.defaultdict(list)  # each pedestrian's lanes, in order
    asked: list[tuple[str, int, str, str | None]] = []  # (person, lanes seen by then, walking area, after lane)
    with tempfile.TemporaryDirectory() as scratch:  # the config's own outputs go there, not next to it
        ls.start(["sumo", "-c", str(cfg), "--seed", str(seed), "--step-length", "0.1", "--no-step-log", "true",
                  "--no-warnings", "true"] + output_args(redirected(read_scenario(cfg), Path(scratch))[0]))
        try:
            graph, signals, clock = lane_graph(), crossing_signals(), SignalClock()
            for step in range(int(round(seconds / 0.1))):
                ls.simulationStep()
                walkers = [p for p in ls.person.getIDList() if not ls.person.getVehicle(p)]
                for p in walkers:
                    lane = ls.person.getLaneID(p)
                    if lane and (not lanes[p] or lanes[p][-1] != lane):
                        lanes[p].append(lane)
                if step % 10 or not walkers:
                    continue
                ctx = agent_context(graph, walkers, np.ones(len(walkers), dtype=bool), signals, clock, version=4)
                for i, p in enumerate(walkers):
                    nxt = int(ctx.next_lane[i])
                    if nxt >= 0 and graph.is_walking_area(nxt):
                        after = int(ctx.after_lane[i])
                        asked.append((p, len(lanes[p]), graph.ids[nxt], graph.ids[after] if after >= 0 else None))
        finally:
            ls.close()
    for p, seen, area, after in asked:
        out["rows"] += 1
        out["with an after lane"] += after is not None
        later = lanes[p][seen:]
        if area not in later or later.index(area) + 1 >= len(later):
            continue  # never got there, or still on it when the run ended
        out["scored"] += 1
        taken = later[later.index(area) + 1]
        out["right"] += taken == after
        if taken != after and out["shown"] < 3:
            out["shown"] += 1
            print(f"  {p}: after {area} took {taken}, the context said {after}")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("config", nargs="?", type=Path, default=ROOT / "scenarios" / "urban" / "urban.sumocfg")
    ap.add_argument("--seconds", type=float, default=300.0)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    if not args.config.is_file():
        print(f"walk_check: {args.config}: no such file", file=sys.stderr)
        sys.exit(2)
    if not args.seconds > 0:
        print(f"walk_check: --seconds {args.seconds:g}: must be positive", file=sys.stderr)
        sys.exit(2)
    c = check(args.config, args.seconds, args.seed)
    share = f"{c['right'] / c['scored']:.1%}" if c["scored"] else "-"
    print(f"{args.config.name}, {args.seconds:g} s, seed {args.seed}: {c['rows']} rows heading into a walking area, "
          f"{c['with an after lane']} with an after lane; {c['scored']} scored, {c['right']} right ({share})")


if __name__ == "__main__":
    main()
