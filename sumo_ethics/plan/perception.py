"""What the ego's sensor sees, what it remembers, and where road users it cannot see could be.

``[planner] occlusion = true`` (:class:`PerceptionConfig`, docs/occlusion.md): each planning step the
ego's sensor sees a disc of ``sensor_range`` around it less the shadows of the other road users'
boxes and of the scenario's opaque polygons (:mod:`sumo_ethics.visibility`). The planner then knows

- the road users *seen* now: at least ``min_share`` of the box's area in the visible region; the
  predictor reads their history as the sensor saw it (rows of the steps a road user was hidden are
  invalid, as for one that was not yet there);
- the road users *remembered*: seen within the last ``memory`` seconds, hidden now. Each is
  predicted at constant velocity from its last seen state, its uncertainty that of the
  constant-velocity predictor ``age`` seconds further out (``age``: how long it has been unseen), so
  it grows while the road user stays hidden. It is forgotten after ``memory`` seconds, when its
  predicted position is in view and nothing is seen there (it is not where it would be), or when it
  would be beyond the range.

``[planner] phantoms = true`` adds hypothetical road users where the map says one could come out of
a shadow (:mod:`sumo_ethics.plan.phantoms`); their risk is a cost term of its own (``phantom``).
Default off: the planner knows every road user in the run's sensing radius, as before.

The static world the sensor looks at (opaque polygons, walkable areas, bike lanes, junction
approaches) is a :class:`SightMap`, built from the running simulation by ``sim.sight`` and handed to the
planner as a factory (the planner imports no libsumo); without one, only road users hide each other.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any, Callable

import numpy as np
import shapely
from shapely import Geometry

from sumo_ethics.contract import Scene
from sumo_ethics.errors import ConfigError, is_number
from sumo_ethics.geometry import OrientedBoxes
from sumo_ethics.plan.history import History
from sumo_ethics.predict.constant_velocity import ConstantVelocityPredictor
from sumo_ethics.types import AgentStates, Observation, Prediction, ViewTrace
from sumo_ethics.visibility import View, view, visible_share

__all__ = ["PerceptionConfig", "LaneLine", "SightMap", "Percept", "Perception", "concat_agents",
           "concat_predictions"]


@dataclass(frozen=True)
class PerceptionConfig:
    """The sensor, the memory and the phantoms (``[planner.perception]``, or ``[perception]`` in a
    ``run --config`` file; switched on by ``[planner] occlusion`` and ``phantoms``).

    sensor_range: radius of the sensor's disc [m] (Frenetix-Occlusion's default sensor radius, 50 m);
    eye: where the sensor sits, ahead of the ego's centre along its heading [m] (0: the roof's middle);
    min_share: a road user is seen when at least this share of its box's area (plan view) lies in
    the visible region [-] (a box is seen by its near side);
    memory: how long a road user seen and then hidden is remembered [s];
    opaque: the polygon types (SUMO ``<poly type=...>``) that block the view: a type matches a name
    equal to it or starting with it and a dot ("building" matches "building.yes").

    Phantoms (:mod:`sumo_ethics.plan.phantoms`): pedestrian_speed, cyclist_speed [m/s] (those of
    Frenetix-Occlusion's phantom agents, 1.4 and 5.0); vehicle_speed: a phantom vehicle's speed as a
    share of its lane's speed limit [-]; pedestrian_existence, cyclist_existence, vehicle_existence:
    the probability that a road user of that kind is there [-] (what its risk is weighed by);
    weight: the cost of one unit of expected phantom risk (existence x P(collision) x harm, the
    ego's and the phantom's) [-], by default that of an above-average risk to a real party under
    J_utility at w_u = 0.5 (0.5 x 1e4); reaction: a phantom is seen as it steps out of its shadow and
    the ego brakes at its maximum deceleration this long after [s] (its risk is that of each candidate
    so braked: :func:`~sumo_ethics.plan.phantoms.contingency`); lookahead, lookahead_min: phantoms are placed up to
    max(lookahead x the ego's speed, lookahead_min) ahead of the ego [s, m] (Frenetix-Occlusion:
    4 s, 25 m); spacing: pedestrian phantoms at least this far apart along the ego's path [m]
    (Frenetix-Occlusion: 5 m); max_phantoms: at most this many of each kind, the nearest [-].
    """

    sensor_range: float = 50.0
    eye: float = 0.0
    min_share: float = 0.25
    memory: float = 2.0
    opaque: tuple[str, ...] = ("building",)
    pedestrian_speed: float = 1.4
    cyclist_speed: float = 5.0
    vehicle_speed: float = 1.0
    pedestrian_existence: float = 0.1
    cyclist_existence: float = 0.1
    vehicle_existence: float = 0.1
    weight: float = 5000.0
    reaction: float = 0.3
    lookahead: float = 4.0
    lookahead_min: float = 25.0
    spacing: float = 5.0
    max_phantoms: int = 3

    def __post_init__(self) -> None:
        positive = {"sensor_range": 1e4, "pedestrian_speed": 50.0, "cyclist_speed": 50.0, "vehicle_speed": 5.0}
        for name, hi in positive.items():
            if not is_number(getattr(self, name), 0.0, hi, lo_open=True):
                raise ConfigError(f"perception.{name} must be a number in (0, {hi:g}], got {getattr(self, name)!r}")
        for name in ("eye", "memory", "weight", "reaction", "lookahead", "lookahead_min", "spacing"):
            if not is_number(getattr(self, name), -1e3 if name == "eye" else 0.0, 1e12):
                raise ConfigError(f"perception.{name} must be a finite number{'' if name == 'eye' else ' >= 0'}, "
                                  f"got {getattr(self, name)!r}")
        for name in ("min_share", "pedestrian_existence", "cyclist_existence", "vehicle_existence"):
            if not is_number(getattr(self, name), 0.0, 1.0):
                raise ConfigError(f"perception.{name} must be a probability in [0, 1], got {getattr(self, name)!r}")
        if not is_number(self.max_phantoms, 0, 100, integer=True):
            raise ConfigError(f"perception.max_phantoms must be an integer in [0, 100], got {self.max_phantoms!r}")
        opaque = (self.opaque,) if isinstance(self.opaque, str) else self.opaque
        if not isinstance(opaque, (tuple, list)) or not all(isinstance(t, str) and t for t in opaque):
            raise ConfigError(f"perception.opaque must be a list of polygon types, got {self.opaque!r}")
        object.__setattr__(self, "opaque", tuple(opaque))

    @staticmethod
    def from_table(table: dict[str, Any], where: str = "[planner.perception]") -> "PerceptionConfig":
        """From a TOML table; unknown keys are a ConfigError naming the known ones."""
        if not isinstance(table, dict):
            raise ConfigError(f"{where} must be a table, got {table!r}")
        known = {f.name for f in fields(PerceptionConfig)}
        unknown = set(table) - known
        if unknown:
            raise ConfigError(f"unknown key(s) in {where}: {', '.join(sorted(unknown))}; known: {', '.join(sorted(known))}")
        t = dict(table)
        if isinstance(t.get("opaque"), list):
            t["opaque"] = tuple(t["opaque"])
        return PerceptionConfig(**t)


def opaque_type(kind: str, opaque: tuple[str, ...]) -> bool:
    """Whether polygon type ``kind`` blocks the view under ``opaque`` (equal, or a prefix and a dot)."""
    return any(kind == t or kind.startswith(t + ".") for t in opaque)


@dataclass(frozen=True)
class LaneLine:
    """A lane phantoms may drive on: id, kind ("road" or "bike"), centre line (P, 2) [m] in its
    direction of travel, speed limit [m/s], the junction it enters ("" if none)."""

    id: str
    kind: str
    xy: np.ndarray
    speed: float
    junction: str = ""


@dataclass(frozen=True)
class SightMap:
    """The static world the sensor looks at: ``opaque`` polygons (buildings), ``walkable`` polygons
    (sidewalks, crossings, walking areas), ``lanes`` (bike lanes and the lanes entering junctions);
    ``link_state``: the current signal state of a lane's first link ("r": red; None: unknown).
    Pure data with spatial indexes (shapely STRtrees), built once."""

    opaque: tuple[Geometry, ...] = ()
    walkable: tuple[Geometry, ...] = ()
    lanes: tuple[LaneLine, ...] = ()
    link_state: Callable[[str], str] | None = None
    _trees: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)

    def _tree(self, name: str) -> shapely.STRtree:
        tree = self._trees.get(name)
        if tree is None:
            geoms = (getattr(self, name) if name != "lanes" else
                     tuple(shapely.linestrings(ln.xy) for ln in self.lanes))
            tree = self._trees[name] = shapely.STRtree(np.asarray(geoms, dtype=object))
        return tree

    def lines(self) -> np.ndarray:
        """(L,) the lanes' centre lines as shapely LineStrings (built once)."""
        self._tree("lanes")
        return self._tree("lanes").geometries

    def near(self, name: str, area: Geometry) -> np.ndarray:
        """Indexes of the ``opaque``, ``walkable`` or ``lanes`` items whose bounding boxes meet ``area``."""
        if not getattr(self, name):
            return np.zeros(0, dtype=np.intp)
        return np.sort(self._tree(name).query(area))


#: an empty map: only road users hide each other, no phantom has a place to be
NO_MAP = SightMap()


def concat_agents(a: AgentStates, b: AgentStates) -> AgentStates:
    """The agents of ``a`` followed by those of ``b``."""
    if not len(b):
        return a
    if not len(a):
        return b
    cols = {f.name: np.concatenate([getattr(a, f.name), getattr(b, f.name)]) for f in fields(AgentStates)
            if f.name not in ("ids", "type_id")}
    return AgentStates(ids=a.ids + b.ids, type_id=a.type_id + b.type_id, **cols)


def concat_predictions(a: Prediction, b: Prediction) -> Prediction:
    """The agents of ``a`` followed by those of ``b`` (same dt and steps). With several modes in
    either, the other's agents get copies of their one mode in the missing modes, weight (1, 0, ...)."""
    if not len(b.ids):
        return a
    if not len(a.ids):
        return b
    q = max(a.n_modes, b.n_modes)

    def modes(p: Prediction) -> tuple[list[Prediction], np.ndarray]:
        ms = [p.single(), *p.alternatives]
        w = np.ones((len(p.ids), 1)) if p.weight is None else np.asarray(p.weight)
        pad = q - len(ms)
        if pad:
            ms += [p.single()] * pad
            w = np.concatenate([w, np.zeros((len(p.ids), pad))], axis=1)
        return ms, w

    ma, wa = modes(a)
    mb, wb = modes(b)
    joined = [Prediction(a.ids + b.ids, a.dt, np.concatenate([x.mean, y.mean]), np.concatenate([x.cov, y.cov]),
                         np.concatenate([x.yaw, y.yaw])) for x, y in zip(ma, mb)]
    if q == 1:
        return joined[0]
    main = joined[0]
    return Prediction(main.ids, main.dt, main.mean, main.cov, main.yaw, tuple(joined[1:]), np.concatenate([wa, wb]))


def _corners(s: AgentStates) -> np.ndarray:
    return OrientedBoxes(s.x, s.y, s.yaw, s.length, s.width).corners() if len(s) else np.zeros((0, 4, 2))


@dataclass(frozen=True)
class Percept:
    """What the ego's sensor gave the planner at one step.

    view: the visible region (:class:`~sumo_ethics.visibility.View`); in_range: road users whose
    centre is within the sensor's range; seen: those seen (:class:`PerceptionConfig` ``min_share``),
    observation: their history as seen (None when occlusion is off: the scene's); remembered: the road
    users remembered while hidden, at their dead-reckoned states now, ``age`` (R,) [s] since each was
    last seen, ``last`` their states then; phantoms: the hypothetical road users
    (:class:`~sumo_ethics.plan.phantoms.Phantoms`) or None; occlusion: whether the planner sees only
    this (else everyone in the sensing radius, the phantoms aside).
    """

    view: View
    in_range: int
    seen: AgentStates
    observation: Observation | None
    remembered: AgentStates
    age: np.ndarray
    last: AgentStates
    phantoms: Any = None
    occlusion: bool = True
    timings_ms: dict[str, float] = field(default_factory=dict)

    def observed(self, obs: Observation, others: AgentStates) -> tuple[Observation, AgentStates]:
        """(observation, agents) the predictor and the planner work with: what was seen, or, with
        occlusion off, the scene's own ``obs`` and ``others``."""
        if not self.occlusion:
            return obs, others
        if self.observation is None:
            raise ValueError("a percept with occlusion carries the observation of what was seen")
        return self.observation, self.seen

    def with_remembered(self, pred: Prediction, agents: AgentStates, horizon_steps: int,
                        dt: float) -> tuple[Prediction, AgentStates]:
        """``pred`` and ``agents`` (the seen ones) followed by the remembered road users, predicted
        at constant velocity from their last seen state (:meth:`remembered_prediction`)."""
        if not self.occlusion or not len(self.remembered):
            return pred, agents
        return (concat_predictions(pred, self.remembered_prediction(horizon_steps, dt)),
                concat_agents(agents, self.remembered))

    def remembered_prediction(self, horizon_steps: int, dt: float) -> Prediction:
        """Constant velocity from each remembered road user's last seen state, at the times
        ``age + (t + 1) dt``: its mean goes on from where it was last seen, and its covariance is that
        of the constant-velocity predictor ``age`` seconds further out (it grows while unseen)."""
        last = self.last
        t = self.age[:, None] + (np.arange(horizon_steps) + 1)[None, :] * float(dt)  # (R, T)
        cv = ConstantVelocityPredictor()
        parts = [cv.predict_arrays(last.ids[i:i + 1], last.xy[i:i + 1], last.yaw[i:i + 1], last.speed[i:i + 1],
                                   last.cls[i:i + 1], t[i], float(dt)) for i in range(len(last))]
        return Prediction(last.ids, float(dt), np.concatenate([p.mean for p in parts]),
                          np.concatenate([p.cov for p in parts]), np.concatenate([p.yaw for p in parts]))

    def counts(self) -> dict[str, float]:
        """steps.parquet's columns: road users in range, seen, remembered; phantoms."""
        return {"n_in_range": float(self.in_range), "n_visible": float(len(self.seen)),
                "n_remembered": float(len(self.remembered)),
                "n_phantoms": float(0 if self.phantoms is None else len(self.phantoms.agents))}

    def trace(self, phantom_risk: np.ndarray | None = None) -> ViewTrace:
        """What a recorded decision keeps of it (explain, the sumo-gui view): the visible region, the
        hidden one, the seen, remembered and phantom road users; ``phantom_risk`` (P,): the chosen
        candidate's expected risk with each phantom."""
        ph = self.phantoms
        agents = AgentStates.empty() if ph is None else ph.agents
        return ViewTrace(eye=np.asarray(self.view.eye, dtype=float), radius=float(self.view.radius),
                         visible=self.view.visible, hidden=self.view.hidden, seen=tuple(self.seen.ids),
                         remembered=tuple(self.remembered.ids), phantoms=agents,
                         phantom_prediction=None if ph is None else ph.prediction,
                         phantom_existence=np.zeros(0) if ph is None else ph.existence,
                         phantom_risk=np.zeros(len(agents)) if phantom_risk is None else np.asarray(phantom_risk))


class Perception:
    """One ego's sensor, memory and phantoms; :meth:`perceive` once per planning step."""

    def __init__(self, cfg: PerceptionConfig, occlusion: bool, phantoms: bool,
                 sight: Callable[[tuple[str, ...]], SightMap] | SightMap | None = None) -> None:
        self.cfg = cfg
        self.occlusion = occlusion
        self.phantoms = phantoms
        self._sight = sight
        self.map: SightMap | None = sight if isinstance(sight, SightMap) else None
        self.history: History | None = None
        #: id -> (time last seen [s], the road user's state then (1 agent))
        self.memory: dict[str, tuple[float, AgentStates]] = {}

    def sight_map(self) -> SightMap:
        if self.map is None:
            self.map = NO_MAP if self._sight is None or isinstance(self._sight, SightMap) else self._sight(self.cfg.opaque)
        return self.map

    def eye(self, ego: AgentStates) -> np.ndarray:
        yaw = float(ego.yaw[0])
        return np.array([float(ego.x[0]) + self.cfg.eye * math.cos(yaw), float(ego.y[0]) + self.cfg.eye * math.sin(yaw)])

    def perceive(self, scene: Scene, horizon_steps: int, dt: float) -> Percept:
        """The step's :class:`Percept` of ``scene`` (its ``others`` are every road user in the sensing
        radius, the truth), phantoms predicted over ``horizon_steps`` steps of ``dt`` [s]."""
        import time

        w0 = time.perf_counter()
        cfg, others, t = self.cfg, scene.others, scene.time
        sight = self.sight_map()
        eye = self.eye(scene.ego)
        disc = shapely.Point(eye).buffer(cfg.sensor_range)
        opaque = [sight.opaque[i] for i in sight.near("opaque", disc)]
        corners = _corners(others)
        v = view(eye, cfg.sensor_range, corners, opaque)
        dist = np.hypot(others.x - eye[0], others.y - eye[1]) if len(others) else np.zeros(0)
        in_range = dist <= cfg.sensor_range
        seen_mask = in_range & (visible_share(v, corners) >= cfg.min_share) if len(others) else np.zeros(0, bool)
        seen = others.take(np.flatnonzero(seen_mask))
        w1 = time.perf_counter()
        remembered, age, last = self._remember(seen, t, v)
        obs = None
        if self.occlusion:
            if self.history is None:
                self.history = History(scene.dt)
            self.history.push(seen)
            obs = self.history.observation(t, scene.ego, seen)
        w2 = time.perf_counter()
        phantoms = None
        if self.phantoms:
            from sumo_ethics.plan.phantoms import place

            blockers = others if not self.occlusion else concat_agents(seen, remembered)
            phantoms = place(v, sight, scene, blockers, cfg, horizon_steps, dt)
        w3 = time.perf_counter()
        return Percept(v, int(in_range.sum()), seen, obs, remembered, age, last, phantoms, self.occlusion,
                       {"visibility_ms": 1e3 * (w1 - w0), "memory_ms": 1e3 * (w2 - w1), "phantoms_ms": 1e3 * (w3 - w2)})

    def _remember(self, seen: AgentStates, t: float, v: View) -> tuple[AgentStates, np.ndarray, AgentStates]:
        """Update the memory with the road users seen at time t [s]; (the remembered ones at their
        dead-reckoned states now, their ages [s], their last seen states)."""
        cfg = self.cfg
        for i, k in enumerate(seen.ids):
            self.memory[k] = (t, seen.take([i]))
        hidden = [k for k in sorted(self.memory) if k not in seen.index]
        keep: list[str] = []
        for k in hidden:
            if t - self.memory[k][0] > cfg.memory + 1e-9:
                del self.memory[k]
            else:
                keep.append(k)
        if not keep:
            return AgentStates.empty(), np.zeros(0), AgentStates.empty()
        last = concat_all([self.memory[k][1] for k in keep])
        age = np.array([t - self.memory[k][0] for k in keep])
        now = dead_reckoned(last, age)
        # forgotten: beyond the range, or where it would be is in view and nothing is seen there
        out = np.hypot(now.x - v.eye[0], now.y - v.eye[1]) > cfg.sensor_range
        gone = out | (visible_share(v, _corners(now)) >= cfg.min_share)
        for k in (keep[int(i)] for i in np.flatnonzero(gone)):
            del self.memory[k]
        stay = np.flatnonzero(~gone)
        return now.take(stay), age[stay], last.take(stay)


def concat_all(parts: list[AgentStates]) -> AgentStates:
    out = AgentStates.empty()
    for p in parts:
        out = concat_agents(out, p)
    return out


def dead_reckoned(last: AgentStates, age: np.ndarray) -> AgentStates:
    """``last`` moved on at constant velocity for ``age`` (N,) seconds (acceleration 0)."""
    x = last.x + last.speed * age * np.cos(last.yaw)
    y = last.y + last.speed * age * np.sin(last.yaw)
    return AgentStates(last.ids, x, y, last.yaw, last.speed, np.zeros(len(last)), last.length, last.width, last.mass,
                       last.cls, last.type_id)
