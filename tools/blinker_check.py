"""Do SUMO's turn signals tell where a vehicle goes at the next junction? Shares of vehicles
showing no, the left or the right blinker, by the direction of their next link (straight, left,
right) and their distance to the end of their lane: evidence for a blinker input to the predictor.

    python tools/blinker_check.py [SUMOCFG] [--seconds 300] [--seed 1]

Every 0.5 s of simulated time, every vehicle on a normal lane with a next link is counted
(``vehicle.getSignals``: bit 0 right blinker, bit 1 left blinker; ``vehicle.getNextLinks``: the
direction of its next link).
"""

from __future__ import annotations

import collections
from pathlib import Path

from _sumo_check import parse_args, sumo_running

BANDS = ((0.0, 20.0), (20.0, 50.0), (50.0, float("inf")))


def count(cfg: Path, seconds: float, seed: int) -> collections.Counter:
    """(direction, band index, blinker "-"/"L"/"R") -> vehicle samples."""
    out: collections.Counter = collections.Counter()
    with sumo_running(cfg, seed) as ls:
        _count_steps(ls, seconds, out)
    return out


def _count_steps(ls, seconds: float, out: collections.Counter) -> None:
    """Step the running simulation for ``seconds`` and count into ``out`` (see :func:`count`)."""
    for step in range(round(seconds / 0.1)):
        ls.simulationStep()
        if step % 5:
            continue
        for v in ls.vehicle.getIDList():
            lane = ls.vehicle.getLaneID(v)
            links = ls.vehicle.getNextLinks(v)
            if not links or not lane or lane.startswith(":"):
                continue
            left = ls.lane.getLength(lane) - ls.vehicle.getLanePosition(v)
            band = next(i for i, (lo, hi) in enumerate(BANDS) if lo <= left < hi)
            sig = ls.vehicle.getSignals(v)
            out[(links[0][6], band, "R" if sig & 1 else "L" if sig & 2 else "-")] += 1


def main() -> None:
    args = parse_args("blinker_check", __doc__)
    stats = count(args.config, args.seconds, args.seed)
    print(f"{args.config.name}, {args.seconds:g} s, seed {args.seed}: share of vehicles per blinker")
    print("distance to lane end | next link | n | none | left | right")
    for b, (lo, hi) in enumerate(BANDS):
        for direction, name in (("s", "straight"), ("l", "left"), ("r", "right")):
            n = {k: stats[(direction, b, k)] for k in "-LR"}
            total = sum(n.values())
            if total:
                print(f"{lo:g}-{hi:g} m | {name} | {total} | {n['-'] / total:.2f} | {n['L'] / total:.2f} | {n['R'] / total:.2f}")


if __name__ == "__main__":
    main()
