"""The contract between the runner and what it drives, on the ground floor (no simulator in it).

The runner hands a controller a :class:`Scene` every step and takes back a :class:`Decision`
holding an :class:`EgoCommand`; the reference path (:class:`RoutePath`, with its junction links
and tight bends) is built by the SUMO adapter (:mod:`sumo_ethics.sim.route`) and read here as plain
arrays. What a run does every step besides driving the ego is a :class:`StepHook` (hazards, rule
breakers, a CommonRoad replay); a hook ends a run by raising :class:`StopRun`. Nothing here
imports libsumo, so planners, predictors and the ethics can be built and tested without SUMO.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Protocol

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


class StepHook:
    """What a run does every step besides driving the ego: hazards, rule breakers, a CommonRoad
    replay, a probe in a test. Subclass it and override the phases you need (like traci's
    ``StepListener``); every method here does nothing. The run loop (:mod:`sumo_ethics.runner.loop`)
    calls them in this order:

    ``start(world)``
        once, after the takeover and before the first step; a :class:`RoutePath` returned replaces
        the ego's reference path (the last hook's that returns one wins);
    every step, for the state at time t:

    ``on_read(snapshot, world)``
        after the state is read (``sim.world.Snapshot``; ``world``: the ``sim.world.SumoWorld``),
        before the scene is built; may act on SUMO (only code under ``sumo_ethics/sim`` should);
    ``desired_speed(t, s)``
        while the scene is built: the highest speed [m/s] the ego should aim at, at time t [s] and
        arc length s [m] on its path, or None; the lowest any hook asks for is the scene's
        ``desired_speed``;
    ``before_act(scene)``
        the :class:`Scene` built, right before the controller acts (hazards command their actors
        here for the same step);
    ``after_step(snapshot, world, row)``
        after SUMO stepped, collisions were detected and the step's ``steps.parquet`` row (``row``,
        read only) was recorded; ``snapshot`` is the state after the step;

    ``route_end(t)``
        when the ego passes its route's end at time t: ``(status, message)`` to end the run with,
        or None (the first hook's answer counts; none: completed);
    ``summary()``
        at the end: a dict merged into summary.json.

    ``on_read`` and ``after_step`` end the run by raising :class:`StopRun`. A fleet run takes no
    hooks. A plain callable ``hook(snapshot, world)`` is still accepted by ``runner.run``: it is
    wrapped as :class:`FunctionHook` (its ``on_read``).
    """

    def start(self, world: Any) -> RoutePath | None:
        return None

    def on_read(self, snapshot: Any, world: Any) -> None:
        return None

    def desired_speed(self, t: float, s: float) -> float | None:
        return None

    def before_act(self, scene: Scene) -> None:
        return None

    def after_step(self, snapshot: Any, world: Any, row: Mapping[str, Any]) -> None:
        return None

    def route_end(self, t: float) -> tuple[RunStatus, str] | None:
        return None

    def summary(self) -> dict[str, Any]:
        return {}


class FunctionHook(StepHook):
    """A callable ``fn(snapshot, world)`` as a :class:`StepHook`: called at ``on_read``."""

    def __init__(self, fn: Callable[[Any, Any], None]) -> None:
        self.fn = fn

    def on_read(self, snapshot: Any, world: Any) -> None:
        self.fn(snapshot, world)


def as_hook(hook: StepHook | Callable[[Any, Any], None]) -> StepHook:
    """``hook`` as a :class:`StepHook` (a plain callable wrapped in :class:`FunctionHook`)."""
    if isinstance(hook, StepHook):
        return hook
    if callable(hook):
        return FunctionHook(hook)
    raise TypeError(f"a run hook is a StepHook or a callable hook(snapshot, world), got {hook!r}")
