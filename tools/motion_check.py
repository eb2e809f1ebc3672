"""Executed steps beyond the ego's lateral acceleration limit, in every run below a folder
(``sumo_ethics.analysis.motion``): how many runs have one, how many steps, and the worst runs.

    python tools/motion_check.py RUNS [--slack 0.5] [--top 10]

RUNS: an ``evaluate`` or ``sweep`` output folder, or any folder of run folders (a fleet run's egos are
checked each in its own time order).
"""

from __future__ import annotations

import argparse
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", type=Path)
    ap.add_argument("--slack", type=float, default=0.5, help="m/s^2 above the limit before a step counts")
    ap.add_argument("--top", type=int, default=10)
    a = ap.parse_args()
    from sumo_ethics.analysis.motion import lateral_check

    r = lateral_check(a.runs, a.slack)
    over = r[r.steps_over > 0]
    print(f"{len(r)} runs, {len(over)} with a step beyond the lateral limit + {a.slack:g} m/s^2: "
          f"{int(r.steps_over.sum())} of {int(r.steps.sum())} steps")
    print(r.sort_values("max_lateral", ascending=False).head(a.top).to_string(index=False))


if __name__ == "__main__":
    main()
