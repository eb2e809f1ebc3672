"""Where a predictor loses against constant velocity: ADE of the most likely mode on subsets of a
dataset's samples (light ahead and its colour, distance to the stop line, how long a red holds,
speed, manoeuvre, and whether the road user really moved).

    python tools/prediction_breakdown.py DATASET [--scenario corridor,square,grid6] [--group vehicle]
        [--moving | --standing] [--model NAME=FILE ...] [--v5-row]

DATASET: a folder written by ``sumo-ethics dataset`` (every sample is used, as for scenarios never
trained on); --scenario keeps the runs of those scenario stems (suite runs are named "suite");
--model: weights files (default: the shipped map, the planner's default). ADE and min_ade are averaged over the
valid future points, as ``sumo-ethics evaluate-predictor`` does (a sample with a partial future
counts by its points). Besides each model's ADE it prints the ADE of its closest mode (min_ade),
the mean weight of its most likely mode and how far that mode ends ahead of the truth along the
target's heading at the horizon (``along``, metres; negative: short of it), which tell a mixture
that holds the truth but ranks it second from one that misses it. Subsets of fewer than 20
samples are left out. --v5-row (a map version-5 dataset) adds, for each model of an earlier map
version, its ADE when it reads the version-5 row 0 of the pedestrians on a walking area (the straight
walk to the next lane, then that lane) instead of its own version's row: what that row alone does,
without retraining. The subsets "on a walking area" (the samples whose row 0 version 5 changed) and
"row 0 over 3 m away" (its first point, as versions 2-4 build it) tell where it matters.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path



from sumo_ethics.predict.breakdown import breakdown  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dataset", type=Path)
    ap.add_argument("--scenario", default=None, help="comma-separated scenario stems to keep")
    ap.add_argument("--group", default="vehicle", choices=("vehicle", "cyclist", "pedestrian"))
    move = ap.add_mutually_exclusive_group()
    move.add_argument("--moving", action="store_true", help="only those at 0.5 m/s or faster now")
    move.add_argument("--standing", action="store_true", help="only those slower than 0.5 m/s now")
    ap.add_argument("--model", action="append", default=[], metavar="NAME=FILE")
    ap.add_argument("--v5-row", action="store_true",
                    help="also each earlier-version model with the map version-5 row 0 of walking-area pedestrians")
    args = ap.parse_args()
    bad = [m for m in args.model if "=" not in m or not Path(m.split("=", 1)[1]).is_file()]
    names = [m.split("=", 1)[0] for m in args.model]
    twice = sorted({n for n in names if names.count(n) > 1})
    if bad or twice:
        what = f"--model {bad[0]!r}: give NAME=FILE with an existing weights file" if bad else \
            f"--model name {twice[0]!r} given twice"
        print(f"prediction_breakdown: {what}", file=sys.stderr)
        sys.exit(2)
    moving = True if args.moving else False if args.standing else None
    try:
        df = breakdown(args.dataset, args.group, args.scenario.split(",") if args.scenario else None, moving,
                       dict(m.split("=", 1) for m in args.model) or None, args.v5_row)
    except (ValueError, RuntimeError, OSError) as exc:  # bad dataset or filters; a weights file refused (PredictorError)
        print(f"prediction_breakdown: {exc}", file=sys.stderr)
        sys.exit(2)
    print(f"{args.group}s of {args.dataset}" + (f" ({args.scenario})" if args.scenario else "")
          + {True: " moving", False: " standing", None: ""}[moving] + ": ADE [m] of the most likely mode")
    print(df.round(3).to_string(index=False))


if __name__ == "__main__":
    main()
