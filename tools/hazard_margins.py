"""How much room a planner had in the cut-ins and oncoming drifts that ended in an ego collision.

    python tools/hazard_margins.py RUNS_DIR [RUNS_DIR ...]

RUNS_DIR: one planner's run folders of an evaluation (e.g. ``runs/evaluate/runs/ours``). For each
scenario whose run ended in a booked ego collision (not an unconfirmed SUMO report) with a
``cut_in`` or ``oncoming_drift`` actor, from
the scenario's ``hazards.json`` and vehicle types and the run's ``hazard_events.json`` (the state
of the ego and the actor when the hazard was triggered) and ``collisions.parquet``:

- cut-in: the gap [m] from the ego's front to the actor's rear and the closing speed [m/s] at the
  trigger, and the constant deceleration [m/s^2] that keeps the ego behind the actor if it brakes
  0, 0.3 or 0.5 s after the trigger, with the actor taken as in the ego's lane at once and
  driving on at its speed: dv^2 / (2 (gap - dv tau)) ("inf" where the gap is gone first). Compare
  with the ego's ``max_decel`` (config.json).
- oncoming drift: how far the drifting actor's side reaches into the ego's box [m] when the ego
  keeps its lane centre (widths from the scenario's vehicle types; the actor's centre at
  ``lane_offset - drift`` from the ego's lane centre), against the room between the ego's side
  and the edge of its lane ((lane width - ego width) / 2, the lane as wide as ``lane_offset``):
  only where the overlap is smaller can a position inside the lane avoid the contact, and the
  run's collision check counts boxes closer than 0.2 m (sumo_ethics.collision.CONFIRM_TOLERANCE
  on both boxes).

A Markdown table on stdout, one row per collision.
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
