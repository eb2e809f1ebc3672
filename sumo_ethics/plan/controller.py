"""The controller interface the runner drives, and the scene it hands over each step."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

from sumo_ethics.config import EgoVehicle
from sumo_ethics.sim.route import RoutePath
from sumo_ethics.sim.world import EgoCommand
from sumo_ethics.types import AgentStates, DecisionTrace, Observation


@dataclass(frozen=True)
class Scene:
    """Everything a controller may know at one step (no simulator handles).

    ego: the ego (1 agent); others: neighbours within the sensing radius; route: the
    reference path; s, d: the ego's Frenet position on it [m]; stop_s: arc length of the
    next red/yellow stop line ahead [m] or None; history: the neighbours' recent past for a
    predictor (None until a controller asks for it); rule_breakers: ids of the neighbours that
    break a traffic rule now (:mod:`sumo_ethics.sim.rules`; the responsibility principle).
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
