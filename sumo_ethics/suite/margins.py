"""How much room a planner had in the cut-ins and oncoming drifts that ended in an ego collision.

The command line is ``python tools/hazard_margins.py RUNS_DIR [RUNS_DIR ...]``.

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

import json
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import pandas as pd

from sumo_ethics.collision import is_booked
from sumo_ethics.suite.spec import load

HAZARDS = ("cut_in", "oncoming_drift")
TAUS = (0.0, 0.3, 0.5)


def vehicle_types(route_file: Path) -> dict[str, tuple[float, float]]:
    """vType id -> (length, width) [m] of a scenario's route file."""
    root = ET.parse(route_file).getroot()
    return {str(v.get("id")): (float(v.get("length", 5.0)), float(v.get("width", 1.8))) for v in root.iter("vType")}


def needed_decel(gap: float, dv: float, tau: float) -> float:
    """Constant deceleration [m/s^2] that sheds the closing speed dv [m/s] within gap [m] after a
    delay tau [s]; 0 when not closing, inf when the gap is gone before braking starts."""
    if dv <= 0.0:
        return 0.0
    room = gap - dv * tau
    return math.inf if room <= 0.0 else dv * dv / (2.0 * room)


def margins(run: Path) -> dict | None:
    """The row of one run folder, or None (no ego collision with a cut-in or drift actor)."""
    cfg = json.loads((run / "config.json").read_text())
    scenario = Path(cfg["scenario"])
    spec = load(scenario.parent)
    hazards = {h.id: h for h in spec.hazards if h.type in HAZARDS}
    col = pd.read_parquet(run / "collisions.parquet")
    col = col[col.apply(is_booked, axis=1) & col.id_b.isin([f"hazard_{h}" for h in hazards])] if len(col) else col
    if col.empty or not (run / "hazard_events.json").exists():
        return None
    hit = col.iloc[0]
    h = hazards[hit.id_b.removeprefix("hazard_")]
    events = json.loads((run / "hazard_events.json").read_text())
    trig = next((e for e in events if e["hazard"] == h.id and e["event"] == "trigger"), None)
    if trig is None:
        return None
    p = h.params
    length, width = vehicle_types(scenario.with_name(f"{scenario.stem}.rou.xml"))[p.get("vtype", "car")]
    ego_w = float(cfg["ego"]["width"])
    row = {"scenario": run.name, "network": spec.network, "hazard": h.type, "trigger [s]": trig["time"],
           "impact [s]": float(hit.time), "ego speed at impact [m/s]": round(float(hit.speed_a), 2),
           "fault": hit.fault}
    if h.type == "cut_in":
        gap = trig["actor_s"] - trig["ego_front_s"] - length / 2.0
        dv = trig["ego_speed"] - abs(trig["actor_speed"])
        row.update({"gap at trigger [m]": round(gap, 1), "closing [m/s]": round(dv, 1)})
        row.update({f"decel needed, {tau:g} s late [m/s^2]": round(needed_decel(gap, dv, tau), 1) for tau in TAUS})
    else:
        overlap = (width + ego_w) / 2.0 - (p["lane_offset"] - p["drift"])
        room = (p["lane_offset"] - ego_w) / 2.0
        row.update({"drift [m]": p["drift"], "overlap at lane centre [m]": round(overlap, 2),
                    "room to lane edge [m]": round(room, 2)})
    return row
