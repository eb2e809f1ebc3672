"""CommonRoad's goal region, checked without commonroad-io: pure numpy and shapely.

A planning problem's goal is a list of goal states; the goal is reached when ANY of them holds.
A goal state holds when every quantity it gives holds (those it leaves out are free), exactly as
``commonroad.planning.goal.GoalRegion.is_reached``:

- ``time_step``: the integer CommonRoad time step lies in the closed interval;
- ``position``: the point lies in (or on the boundary of) one of the shapes (rectangles and
  polygons as polygons, circles as centre and radius; a goal given by lanelets is the union of
  those lanelets' polygons, which commonroad-io builds as a shape group);
- ``orientation``: the angle, wrapped, lies in the interval (commonroad-io's ``AngleInterval``:
  ``0 <= wrap(value - start) <= wrap(end - start)``, wrap into [-pi, pi));
- ``velocity``: the speed lies in the closed interval.

:meth:`Goal.completes` is what ends a run: the same, but a goal state without a position holds
only at the last step of its time window (see there); or, under the ``origin`` rule, as the paper's
evaluation counted: reaching the goal after its time window completes too (late).

:class:`Pace` is how fast the ego should go so as not to reach the goal region before its time
window opens (the speed an imported CommonRoad scenario's run asks the planner to aim at).

The serialised form (one dict per goal state, written by the importer into ``commonroad.json``)
keeps the run independent of commonroad-io: an imported folder runs with the base install.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
import shapely
from shapely.geometry import LineString, Point, Polygon

TWO_PI = 2.0 * math.pi
#: completion rules of :meth:`Goal.completes`
COMPLETIONS = ("commonroad", "origin")
#: under the ``origin`` rule a run lasts this many times its goal's last time step (Origin's
#: ScenarioHandler: ``max_simulation_time_steps = int(goal time_step.end * 2.0)``)
ORIGIN_TIME_FACTOR = 2.0


def _wrap(a: float) -> float:
    """commonroad-io's ``vectorized_angle_difference`` applied to one difference: into [-pi, pi)."""
    d = math.fmod(a, TWO_PI)
    return float(np.arctan2(np.sin(d), np.cos(d)))


@dataclass(frozen=True)
class GoalState:
    time_step: tuple[int, int] | None = None
    velocity: tuple[float, float] | None = None
    orientation: tuple[float, float] | None = None
    polygons: tuple[Polygon, ...] = ()  # position shapes as polygons (rectangles, polygons, lanelets)
    circles: tuple[tuple[float, float, float], ...] = ()  # (x, y, radius)

    @property
    def has_position(self) -> bool:
        return bool(self.polygons or self.circles)

    def holds(self, step: int, x: float, y: float, yaw: float, speed: float, late: bool = False) -> bool:
        """Every quantity the state gives holds; ``late``: a time step after the window counts too."""
        if self.time_step is not None and not self.time_step[0] <= step <= (math.inf if late else self.time_step[1]):
            return False
        if self.has_position and not self.contains(x, y):
            return False
        if self.orientation is not None:
            span = _wrap(self.orientation[1] - self.orientation[0])
            diff = _wrap(yaw - self.orientation[0])
            if not 0.0 <= diff <= span:
                return False
        if self.velocity is not None and not self.velocity[0] <= speed <= self.velocity[1]:
            return False
        return True

    def contains(self, x: float, y: float) -> bool:
        p = Point(x, y)
        if any(poly.intersects(p) for poly in self.polygons):
            return True
        return any(math.hypot(x - cx, y - cy) <= r for cx, cy, r in self.circles)

    def region(self) -> Any:
        """The union of this state's position shapes (None without a position)."""
        geoms = list(self.polygons) + [Point(cx, cy).buffer(r, 32) for cx, cy, r in self.circles]
        return shapely.union_all(geoms) if geoms else None

    def to_dict(self) -> dict[str, Any]:
        return {"time_step": list(self.time_step) if self.time_step else None,
                "velocity": list(self.velocity) if self.velocity else None,
                "orientation": list(self.orientation) if self.orientation else None,
                "polygons": [np.asarray(p.exterior.coords)[:-1].round(6).tolist() for p in self.polygons],
                "circles": [list(c) for c in self.circles]}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "GoalState":
        def pair(v):
            return None if v is None else (v[0], v[1])

        return cls(time_step=None if d.get("time_step") is None else (int(d["time_step"][0]), int(d["time_step"][1])),
                   velocity=pair(d.get("velocity")), orientation=pair(d.get("orientation")),
                   polygons=tuple(Polygon(p) for p in d.get("polygons", ())),
                   circles=tuple((float(c[0]), float(c[1]), float(c[2])) for c in d.get("circles", ())))


@dataclass(frozen=True)
class Goal:
    """The goal region: reached when any of ``states`` holds."""

    states: tuple[GoalState, ...]

    def is_reached(self, step: int, x: float, y: float, yaw: float, speed: float) -> bool:
        """commonroad-io's ``GoalRegion.is_reached`` for this state."""
        return any(s.holds(step, x, y, yaw, speed) for s in self.states)

    def completes(self, step: int, x: float, y: float, yaw: float, speed: float, rule: str = "commonroad") -> bool:
        """Whether a run ends here as completed.

        ``commonroad``: :meth:`is_reached`, except that a goal state giving no position (a time window,
        perhaps with speed or heading: "drive on safely until then") counts only at its window's last
        step. commonroad-io's check alone would end such a run at its first step (any state in the
        window reaches it), before anything happened.

        ``origin``: as the paper's and Origin's evaluation (EthicalTrajectoryPlanning's
        ``GoalReachedChecker``: reached in time, or reached with the time exceeded): a goal state holds
        from its window's first step on, also after the window has closed (:meth:`late` tells which),
        and one without a position as soon as its window opens."""
        if rule == "origin":
            return any(s.holds(step, x, y, yaw, speed, late=True) for s in self.states)
        return any(s.holds(step, x, y, yaw, speed) and (s.has_position or s.time_step is None
                                                       or step >= s.time_step[1]) for s in self.states)

    def late(self, step: int) -> bool:
        """Whether ``step`` is after the time window of every goal state that has one (False if none has)."""
        ends = [s.time_step[1] for s in self.states if s.time_step is not None]
        return bool(ends) and step > max(ends)

    @property
    def last_step(self) -> int | None:
        """The latest time step at which the goal can still be reached (None: no time limit)."""
        ends = [s.time_step[1] for s in self.states if s.time_step is not None]
        return max(ends) if ends and len(ends) == len(self.states) else None

    def region(self) -> Any:
        """The union of every position shape (None if no goal state gives a position)."""
        geoms = [p for s in self.states for p in s.polygons]
        geoms += [Point(cx, cy).buffer(r, 32) for s in self.states for cx, cy, r in s.circles]
        return shapely.union_all(geoms) if geoms else None

    def to_list(self) -> list[dict[str, Any]]:
        return [s.to_dict() for s in self.states]

    @classmethod
    def from_list(cls, items: Sequence[dict[str, Any]]) -> "Goal":
        return cls(tuple(GoalState.from_dict(d) for d in items))


def along(region: Any, xy: np.ndarray) -> tuple[float, float]:
    """(entry, exit) [m]: the arc lengths along the polyline ``xy`` (M, 2) [m] of the first and the
    last of its points in ``region`` (a shapely geometry); where it never meets the region, both are
    the arc length of its point nearest to it."""
    line = LineString(np.asarray(xy, dtype=float))
    inside = line.intersection(region)
    if inside.is_empty:
        nearest = float(line.project(Point(shapely.shortest_line(line, region).coords[0])))
        return nearest, nearest
    s = np.asarray(shapely.line_locate_point(line, shapely.points(shapely.get_coordinates(inside))))
    return float(s.min()), float(s.max())


@dataclass(frozen=True)
class Pace:
    """How fast the ego may go so as not to reach the goal region before its time window opens.

    One entry per goal state, each (G,): ``entry``, ``exit``: arc lengths [m] along the ego's
    reference path where it enters and leaves that state's region (:func:`along`); ``opens``,
    ``closes``: its time window [CommonRoad time steps]; ``lowest``: its lowest speed [m/s] (0 where
    it gives none). ``dt``: the scenario's time step [s]. Build it with :meth:`of`.
    """

    entry: np.ndarray
    exit: np.ndarray
    opens: np.ndarray
    closes: np.ndarray
    lowest: np.ndarray
    dt: float

    @classmethod
    def of(cls, goal: Goal, xy: np.ndarray, dt: float) -> "Pace | None":
        """The pace to ``goal`` along the reference path ``xy`` (M, 2) [m]; None when some goal state
        gives no position or no time window (it is met without timing the arrival)."""
        if not all(s.has_position and s.time_step is not None for s in goal.states):
            return None
        ends = np.array([along(s.region(), xy) for s in goal.states], dtype=float).reshape(-1, 2)
        windows = np.array([s.time_step for s in goal.states], dtype=float).reshape(-1, 2)
        lowest = np.array([max(s.velocity[0], 0.0) if s.velocity is not None else 0.0 for s in goal.states])
        return cls(ends[:, 0], ends[:, 1], windows[:, 0], windows[:, 1], lowest, float(dt))

    def speed(self, step: float, s: float) -> float | None:
        """The highest speed [m/s] to aim at at CommonRoad time step ``step`` (fractional) with the
        ego's centre at arc length ``s`` [m]; None: no limit (the route's own).

        For each goal state still to be met (``s`` not past its region, ``step`` not past its window):
        before its window opens, (middle - s) / (time until it opens), the speed that is halfway through
        the region (middle = (entry + exit) / 2) as the window opens (past the middle: 0, wait), but
        never below the state's lowest speed; once its window is open (or the ego is late), no limit.
        Halfway, not the near edge: the planner tracks the speed only roughly, and half the region
        either side is the slack for arriving early or late; an ego that starts inside the region
        drives on instead of braking to wait at its edge. The goal is met by any state, so the pace is
        the highest of these: None if any state asks for no limit, or if no state is left to meet."""
        left = (s <= self.exit) & (step <= self.closes)
        if not left.any():
            return None
        wait = (self.opens[left] - step) * self.dt  # (G',) s until each window opens
        if (wait <= 0.0).any():
            return None
        middle = 0.5 * (self.entry[left] + self.exit[left])
        return float(max(np.max(np.maximum((middle - s) / wait, self.lowest[left])), 0.0))
