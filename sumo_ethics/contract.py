"""The contract between the runner and what it drives, on the ground floor (no simulator in it).

The runner hands a controller a :class:`Scene` every step and takes back a :class:`Decision`
holding an :class:`EgoCommand`; the reference path (:class:`RoutePath`, with its junction links
and tight bends) is built by the SUMO adapter (:mod:`sumo_ethics.sim.route`) and read here as plain
arrays. A hook ends a run by raising :class:`StopRun`. Nothing here imports libsumo, so planners,
predictors and the ethics can be built and tested without SUMO.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from sumo_ethics.config import EgoVehicle
from sumo_ethics.geometry import Polyline
from sumo_ethics.types import AgentStates, DecisionTrace, Observation, RunStatus


@dataclass(frozen=True)
class JunctionLink:
    """A link the path takes into a junction: stop line at arc length ``s`` [m]."""

    s: float
    lane: str
    index: int  # position of the link in sumo.lane.getLinks(lane)


@dataclass(frozen=True)
class RoutePath:
    """Reference path along the ego's route.

    path: centre line of the chosen lanes; lane_of_vertex: (M,) lane id per vertex;
    speed_limit, left, right: (M,) lane speed limit [m/s] and drivable area as lateral
    offsets [m] (left > 0 > right) over the lanes of the same edge the ego may use.
    """

    edges: tuple[str, ...]
    path: Polyline
    lane_of_vertex: tuple[str, ...]
    speed_limit: np.ndarray
    left: np.ndarray
    right: np.ndarray
    links: tuple[JunctionLink, ...]

    @property
    def length(self) -> float:
        return self.path.length

    def vertex_at(self, s: float) -> int:
        """Index of the last vertex at or before arc length ``s`` [m] (0 before the start)."""
        return min(max(int(np.searchsorted(self.path.s, s, side="right")) - 1, 0), len(self.path.s) - 1)


@dataclass(frozen=True)
class TightBend:
    """A stretch of the reference path bending tighter than a curvature limit.

    s_start, s_end: arc lengths [m] of its first and last path vertex beyond the limit;
    s: arc length [m] of its tightest vertex, curvature there [1/m] (signed, left turn positive),
    lane: the SUMO lane of that vertex, x, y: its position [m].
    """

    s_start: float
    s_end: float
    s: float
    curvature: float
    lane: str
    x: float
    y: float


@dataclass(frozen=True)
class EgoCommand:
    """Where the ego is to be after the next step: centre pose [m, rad], speed [m/s]."""

    x: float
    y: float
    yaw: float
    speed: float


class StopRun(Exception):
    """Raised by a hook to end the run with ``status`` and ``message`` (e.g. a goal region reached)."""

    def __init__(self, status: RunStatus, message: str) -> None:
        super().__init__(message)
        self.status, self.message = status, message


@dataclass(frozen=True)
class Scene:
    """Everything a controller may know at one step (no simulator handles).

    ego: the ego (1 agent); others: neighbours within the sensing radius; route: the
    reference path; s, d: the ego's Frenet position on it [m]; stop_s: arc length of the
    next red/yellow stop line ahead [m] or None; history: the neighbours' recent past for a
    predictor (None until a controller asks for it); rule_breakers: ids of the neighbours that
    break a traffic rule now (:mod:`sumo_ethics.sim.rules`; the responsibility principle);
    desired_speed: the highest speed [m/s] a run hook asks the ego to aim at now (an imported
    CommonRoad goal's time window, :class:`sumo_ethics.goal.Pace`; the planner aims at the lower of it
    and the route's speed limit), or None: aim at the limit.
    """

    time: float
    dt: float
    ego: AgentStates
    others: AgentStates
    route: RoutePath
    s: float
    d: float
    stop_s: float | None
    vehicle: EgoVehicle
    history: Observation | None = None
    rule_breakers: frozenset[str] = frozenset()
    desired_speed: float | None = None


@dataclass(frozen=True)
class Decision:
    """A controller's answer: the command, plus named numbers explaining it (logged per step) and,
    from a planner that weighs candidates, what it weighed (``trace``, for recorded decisions)."""

    command: EgoCommand
    info: dict[str, float] = field(default_factory=dict)
    timings_ms: dict[str, float] = field(default_factory=dict)
    trace: DecisionTrace | None = None


class Controller(Protocol):
    name: str
    needs_history: bool

    def act(self, scene: Scene) -> Decision:
        """Scene in, command for the next step out."""
        ...
