"""Notes on a run that its status alone does not tell, for ``summary.json`` and the lines
``sumo-ethics run`` prints at the end.

- ``tight_bends``: the ego's route bends tighter than its ``max_curvature`` (junction shapes
  from OpenStreetMap often do). The planner lets the ego follow the road's own curvature there
  (``plan.feasibility``), so the run goes on, but the ego then turns tighter than its limits
  say a car can: the summary names the tightest bend and how the ego passed.
- ``standstill``: the ego ended the run standing for at least :data:`STANDSTILL_NOTE` seconds
  with no road user within the sensing radius and no red light ahead: nothing on the road held
  it, the planner found no way on (a timeout that is the planner's, not the traffic's).

Pure Python over the values the runner records each step; no simulator calls.
"""

from __future__ import annotations

import math
from typing import Any, Sequence

from sumo_ethics.contract import TightBend

__all__ = ["RunNotes", "STANDSTILL_NOTE", "STILL_SPEED", "lines"]

#: m/s: below this the ego counts as standing
STILL_SPEED = 0.1
#: s: a standstill with nothing around at the end of a run at least this long is noted
STANDSTILL_NOTE = 10.0


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
        self.last_time = math.nan

    def step(self, time: float, s: float, speed: float, n_neighbours: int, stop_s: float, lane: str) -> None:
        """One recorded step: time [s], the ego's arc length s [m] and speed [m/s], the number of
        neighbours within the sensing radius, the red-light stop line ahead (NaN: none) and its lane."""
        self.last_time = time
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
