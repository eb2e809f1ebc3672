"""Notes on a run that its status alone does not tell, for ``summary.json`` and the lines
``sumo-ethics run`` prints at the end.

- ``tight_bends``: the ego's route bends tighter than its ``max_curvature`` (junction shapes
  from OpenStreetMap often do). The planner lets the ego follow the road's own curvature there
  (``plan.feasibility``), so the run goes on, but the ego then turns tighter than its limits
  say a car can: the summary names the tightest bend and how the ego passed.
- ``standstill``: the ego ended the run standing for at least :data:`STANDSTILL_NOTE` seconds
  with no road user within the sensing radius and no red light ahead: nothing on the road held
  it, the planner found no way on (a timeout that is the planner's, not the traffic's).
- ``held`` (:func:`held`): what held the ego when a run timed out: a red light (how long it stood
  there, when the signal's phase ends), a road user standing ahead on its path, no way on the
  planner would take, or nothing: the time limit came with the ego still moving.

Pure Python over the values the runner records each step; no simulator calls.
"""

from __future__ import annotations

import math
from typing import Any, Sequence

from sumo_ethics.contract import TightBend

__all__ = ["HELD_REASONS", "RunNotes", "STANDSTILL_NOTE", "STILL_SPEED", "held", "lines"]

#: m/s: below this the ego counts as standing
STILL_SPEED = 0.1
#: s: a standstill with nothing around at the end of a run at least this long is noted
STANDSTILL_NOTE = 10.0
#: what can hold the ego at a timeout (summary.json ``held.reason``)
HELD_REASONS = ("moving", "red_light", "road_user_ahead", "no_way_on")
#: m: a red stop line at most this far ahead of the ego's front holds a standing ego
RED_REACH = 50.0
#: m: a standing road user at most this far ahead of the ego's front (bumper to bumper) holds it
BLOCKER_REACH = 25.0
#: m: a road user whose centre is at most this far beside the ego's path is on it
PATH_HALF_WIDTH = 2.0
#: m/s: below this a road user ahead counts as standing
BLOCKER_SPEED = 0.5
#: the validity code of a step with no candidate (plan.ethical.VALIDITY's "emergency")
_EMERGENCY = 4


class RunNotes:
    """Collects the notes during a run: :meth:`step` once per recorded step, :meth:`summary` at the end.

    bends: the route's bends beyond the ego's curvature limit ``limit`` [1/m]
    (``sim.route.tight_bends``); tolerance: what the planner lets the ego add there [1/m].
    """

    def __init__(self, bends: Sequence[TightBend], limit: float, tolerance: float) -> None:
        self.bends = list(bends)
        self.limit, self.tolerance = float(limit), float(tolerance)
        self.max_s = -math.inf  # m, furthest the ego's centre got along the route
        self.bend_speed = 0.0  # m/s, highest ego speed inside a bend
        self.still_since: dict[str, Any] | None = None  # time, s and lane where the standstill began
        self.stood_since = math.nan  # s, when the ego last came to stand (NaN: moving)
        self.last_time = math.nan
        self.last_speed = math.nan
        self.last_validity = math.nan  # the last step's validity code (NaN: none, e.g. the baseline)

    def step(self, time: float, s: float, speed: float, n_neighbours: int, stop_s: float, lane: str,
             validity: float = math.nan) -> None:
        """One recorded step: time [s], the ego's arc length s [m] and speed [m/s], the number of
        neighbours within the sensing radius, the red-light stop line ahead (NaN: none), its lane
        and the chosen candidate's validity code (NaN: none)."""
        self.last_time, self.last_speed, self.last_validity = time, speed, validity
        if speed >= STILL_SPEED:
            self.stood_since = math.nan
        elif math.isnan(self.stood_since):
            self.stood_since = time
        self.max_s = max(self.max_s, s)
        if any(b.s_start <= s <= b.s_end for b in self.bends):
            self.bend_speed = max(self.bend_speed, speed)
        alone = speed < STILL_SPEED and n_neighbours == 0 and math.isnan(stop_s)
        if not alone:
            self.still_since = None
        elif self.still_since is None:
            self.still_since = {"time": time, "s": s, "lane": lane}

    def summary(self, completed: bool) -> dict[str, Any]:
        """The ``summary.json`` fields: ``tight_bends`` if the route has any, ``standstill`` if an
        unfinished run ended with the ego standing alone for at least STANDSTILL_NOTE seconds."""
        out: dict[str, Any] = {}
        if self.bends:
            t = max(self.bends, key=lambda b: abs(b.curvature))
            k = abs(t.curvature)
            passed = sum(self.max_s >= b.s_end for b in self.bends)
            out["tight_bends"] = {
                "limit": self.limit, "count": len(self.bends), "passed": passed,
                "tightest": {"curvature": round(k, 4), "radius": round(1.0 / k, 2),
                             "turn": "left" if t.curvature > 0 else "right", "lane": t.lane,
                             "s": round(t.s, 1), "x": round(t.x, 2), "y": round(t.y, 2)},
                "max_speed_in_bends": round(self.bend_speed, 2),
                "note": (f"the route bends tighter than the ego's max_curvature ({self.limit:g} 1/m); the ego "
                         f"passed {passed} of these bends, following the road's own geometry there (the planner "
                         f"allows at most {self.tolerance:g} 1/m beyond the road and still limits the lateral "
                         f"acceleration)"),
            }
        if self.still_since is not None and not completed:
            duration = self.last_time - self.still_since["time"]
            if duration >= STANDSTILL_NOTE - 1e-9:
                out["standstill"] = {
                    "since": self.still_since["time"], "duration": round(duration, 3),
                    "s": round(self.still_since["s"], 2), "lane": self.still_since["lane"],
                    "note": ("the ego ended the run standing with no road user within the sensing radius and no "
                             "red light ahead: the planner found no acceptable way on (steps.parquet: n_feasible, "
                             "validity)"),
                }
        return out


def blocker_ahead(s: float, half: float, ps: Any, pd: Any, speed: Any, length: Any, ids: Sequence[str],
                  labels: Sequence[str]) -> dict[str, Any] | None:
    """The nearest road user standing (below :data:`BLOCKER_SPEED`) ahead of the ego on its path:
    ``{"id", "class", "gap", "speed"}`` or None. s, half: the ego's arc length [m] and half length;
    ps, pd, speed, length: (N,) the road users' arc length and offset on the ego's path, speed and
    length; ids, labels: their SUMO ids and class labels. On the path: the centre within
    :data:`PATH_HALF_WIDTH` of it; ahead: in front of the ego's centre, the gap between the ego's
    front and the road user's rear at most :data:`BLOCKER_REACH`."""
    best: dict[str, Any] | None = None
    for i in range(len(ids)):
        gap = float(ps[i]) - s - half - float(length[i]) / 2
        if float(ps[i]) > s and abs(float(pd[i])) <= PATH_HALF_WIDTH and float(speed[i]) < BLOCKER_SPEED \
                and gap <= BLOCKER_REACH and (best is None or gap < best["gap"]):
            best = {"id": ids[i], "class": labels[i], "gap": round(max(gap, 0.0), 2), "speed": round(float(speed[i]), 2)}
    return best


def held(notes: RunNotes, route_left: float, red: dict[str, Any] | None,
         blocker: dict[str, Any] | None) -> dict[str, Any]:
    """summary.json's ``held``: what held the ego when its run timed out, from the last step.

    route_left: m of its route ahead of its front; red: the red (or yellow) stop line ahead,
    ``{"distance": m from the front, "phase_ends": s or None}``, None if there is none; blocker: the
    nearest road user standing ahead on its path, ``{"id", "class", "gap": m bumper to bumper,
    "speed"}``, None if there is none. ``reason`` is one of :data:`HELD_REASONS`; ``says`` the
    words the run's message ends with."""
    speed = notes.last_speed
    if math.isnan(speed) or speed >= STILL_SPEED:
        left = f", {route_left:.0f} m of its route left" if math.isfinite(route_left) else ""
        return {"reason": "moving", "speed": None if math.isnan(speed) else round(speed, 2),
                "route_left": round(route_left, 1) if math.isfinite(route_left) else None,
                "says": f"the ego was still moving ({0.0 if math.isnan(speed) else speed:.1f} m/s{left})"}
    since = notes.stood_since if not math.isnan(notes.stood_since) else notes.last_time
    stood = max(notes.last_time - since, 0.0)
    out: dict[str, Any] = {"since": round(since, 3), "duration": round(stood, 3)}
    if red is not None and red["distance"] <= RED_REACH:  # at the line, or in the queue before it
        ends = red.get("phase_ends")
        phase = f"; the signal's phase ends at t={ends:g} s" if ends is not None else ""
        queue = (f", behind {blocker['class']} '{blocker['id']}'" if blocker is not None
                 and blocker["gap"] <= BLOCKER_REACH else "")
        return out | {"reason": "red_light", "stop_line": round(red["distance"], 1), "phase_ends": ends,
                      "says": f"the ego stood {stood:.0f} s at a red light (stop line {red['distance']:.0f} m "
                              f"ahead{queue}{phase})"}
    if blocker is not None and blocker["gap"] <= BLOCKER_REACH:
        return out | {"reason": "road_user_ahead", "blocker": blocker,
                      "says": f"the ego stood {stood:.0f} s behind {blocker['class']} '{blocker['id']}', standing "
                              f"{blocker['gap']:.1f} m ahead on its path"}
    why = "no candidate was feasible" if notes.last_validity == _EMERGENCY else \
        "standing cost least" if not math.isnan(notes.last_validity) else ""
    return out | {"reason": "no_way_on", "last_validity": None if math.isnan(notes.last_validity)
                  else int(notes.last_validity),
                  "says": f"the ego stood {stood:.0f} s with no red light and no standing road user ahead: its "
                          f"controller found no way on{f' ({why})' if why else ''}"}


def lines(summary: dict[str, Any]) -> list[str]:
    """The end-of-run lines for the notes in a ``summary.json`` dict (none if it has none)."""
    out = []
    b = summary.get("tight_bends")
    if b:
        t = b["tightest"]
        how = (f"the ego followed the road's geometry through {b['passed']} of them (at most "
               f"{b['max_speed_in_bends']:.1f} m/s)" if b["passed"] else "the ego passed none of them")
        out.append(f"note: the route bends tighter than the ego's limit ({b['limit']:g} 1/m) in {b['count']} "
                   f"place{'s' if b['count'] != 1 else ''}, tightest {t['curvature']:.2f} 1/m (radius {t['radius']:.1f} m, "
                   f"{t['turn']}) on {t['lane']} at s = {t['s']:.0f} m; {how}")
    st = summary.get("standstill")
    if st:
        out.append(f"warning: the ego stood still for the last {st['duration']:.0f} s (from t={st['since']:g} s on "
                   f"{st['lane'] or 'no lane'}) with nobody within the sensing radius and no red light ahead: "
                   f"the planner found no way on")
    return out
