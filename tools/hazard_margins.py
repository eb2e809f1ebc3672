"""How much room a planner had in the cut-ins and oncoming drifts that ended in an ego collision.

    python tools/hazard_margins.py RUNS_DIR [RUNS_DIR ...]

RUNS_DIR: one planner's run folders of an evaluation (e.g. ``runs/evaluate/runs/ours``). What each
column means: :mod:`sumo_ethics.suite.margins`. A Markdown table on stdout, one row per collision.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

from sumo_ethics.analysis.stats import to_markdown
from sumo_ethics.suite.margins import HAZARDS, margins


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path, help="one planner's run folders (OUT/runs/PLANNER)")
    a = ap.parse_args()
    rows = [r for d in a.runs for run in sorted(p for p in d.iterdir() if p.is_dir()) if (r := margins(run))]
    if not rows:
        print("no ego collision with a cut-in or oncoming-drift actor")
        return
    for kind in HAZARDS:
        part = pd.DataFrame([r for r in rows if r["hazard"] == kind]).dropna(axis=1, how="all")
        if not part.empty:
            print(to_markdown(part.drop(columns="hazard")), end="\n\n")


if __name__ == "__main__":
    main()
