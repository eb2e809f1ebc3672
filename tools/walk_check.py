"""Is the map context's lane after a walking area (map version 4) the lane pedestrians really take?

    python tools/walk_check.py [SUMOCFG] [--seconds 300] [--seed 1]

Every 1 s of simulated time, each walking pedestrian whose next lane is a walking area gets its
``after_lane`` from :func:`sumo_ethics.sim.lanes.agent_context` (the shortest walk through the
junction to the walk's next sidewalk). Its lanes are then followed every 0.1 s; a row is scored
when the pedestrian enters that walking area and leaves it within the run, and it is right when
the first lane after the walking area is ``after_lane``.
"""

from __future__ import annotations

import collections
from pathlib import Path

from _sumo_check import parse_args, sumo_running


def check(cfg: Path, seconds: float, seed: int) -> collections.Counter:
    """Counts: rows (next lane a walking area), with an after lane, scored, right; and examples."""
    import numpy as np

    from sumo_ethics.sim.lanes import (
        SignalClock,
        agent_context,
        crossing_signals,
        lane_graph,
    )

    out: collections.Counter = collections.Counter()
    lanes: dict[str, list[str]] = collections.defaultdict(list)  # each pedestrian's lanes, in order
    asked: list[tuple[str, int, str, str | None]] = []  # (person, lanes seen by then, walking area, after lane)
    with sumo_running(cfg, seed) as ls:
        graph, signals, clock = lane_graph(), crossing_signals(), SignalClock()
        for step in range(round(seconds / 0.1)):
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
    args = parse_args("walk_check", __doc__)
    c = check(args.config, args.seconds, args.seed)
    share = f"{c['right'] / c['scored']:.1%}" if c["scored"] else "-"
    print(f"{args.config.name}, {args.seconds:g} s, seed {args.seed}: {c['rows']} rows heading into a walking area, "
          f"{c['with an after lane']} with an after lane; {c['scored']} scored, {c['right']} right ({share})")


if __name__ == "__main__":
    main()
