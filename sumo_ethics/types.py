"""Frozen datatypes shared by every stage.

One internal frame everywhere: metres, seconds, radians, yaw counter-clockwise from +x,
positions at the vehicle's geometric centre. SUMO's front-bumper positions and
navigational degrees live only in :mod:`sumo_ethics.sim`.

Axis letters: N agents, K candidates, T horizon steps, H history steps.
"""

from __future__ import annotations

import enum
import functools
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np


class RoadUserClass(enum.IntEnum):
    """What kind of road user an agent is; decides mass and which harm model applies."""

    CAR = 0
    TRUCK = 1
    BUS = 2
    MOTORCYCLE = 3  # motorcycles and mopeds
    BICYCLE = 4
    PEDESTRIAN = 5
    OTHER = 6  # rail, emergency, ... treated as a protected vehicle

    @property
    def is_vulnerable(self) -> bool:
        """Pedestrians, cyclists and motorcyclists: booked as VRU, harmed with the unprotected model."""
        return self in (RoadUserClass.MOTORCYCLE, RoadUserClass.BICYCLE, RoadUserClass.PEDESTRIAN)

    @property
    def label(self) -> str:
        return self.name.lower()

    @staticmethod
    def from_vclass(vclass: str) -> "RoadUserClass":
        """SUMO vClass -> class; anything not listed (rail, ships, ...) is OTHER."""
        return _VCLASS.get(vclass, RoadUserClass.OTHER)


_VCLASS: dict[str, RoadUserClass] = {
    **{v: RoadUserClass.CAR for v in (
        "passenger", "private", "taxi", "evehicle", "delivery", "emergency", "authority", "army",
        "vip", "hov", "custom1", "custom2", "ignoring")},
    **{v: RoadUserClass.TRUCK for v in ("truck", "trailer")},
    **{v: RoadUserClass.BUS for v in ("bus", "coach")},
    **{v: RoadUserClass.MOTORCYCLE for v in ("motorcycle", "moped")},
    **{v: RoadUserClass.BICYCLE for v in ("bicycle", "scooter")},
    **{v: RoadUserClass.PEDESTRIAN for v in ("pedestrian", "wheelchair")},
}


#: (C,) bool lookup: VULNERABLE[cls] for an int array of RoadUserClass values.
VULNERABLE = np.array([c.is_vulnerable for c in RoadUserClass], dtype=bool)


class HarmClass(enum.Enum):
    """Booking of harm, as in the paper's Table 1."""

    EGO = "ego"
    THIRD_PARTY = "third_party"
    VRU = "vru"  # the third-party harm that fell on vulnerable road users (subset of THIRD_PARTY)


class RunStatus(enum.Enum):
    COMPLETED = "completed"
    COLLISION = "collision"
    TIMEOUT = "timeout"
    ERROR = "error"
    INTERRUPTED = "interrupted"  # Ctrl-C or SIGTERM


def _frozen_array(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a)
    a.setflags(write=False)
    return a


def kernel_input(a: Any, dtype: Any = float) -> np.ndarray:
    """``a`` as a C-contiguous, read-only array of ``dtype``, for a numba kernel's input (no copy
    where it already is one; a read-only view where it is writable). numba compiles one machine code
    per argument type and read-only is part of the type: a slice of a frozen array that stays
    contiguous is read-only, one that does not is copied and writable. Passed through this, every
    call has one type, so the kernel is compiled (and cached, by the warm-up) once."""
    out = np.ascontiguousarray(a, dtype=dtype)
    if out.flags.writeable:
        out = out.view()
        out.setflags(write=False)
    return out


@dataclass(frozen=True)
class AgentStates:
    """N road users at one instant, internal frame.

    ids: (N,) tuple of SUMO ids; x, y: (N,) centre position [m]; yaw: (N,) [rad, CCW from +x];
    speed: (N,) [m/s]; accel: (N,) [m/s^2]; length, width: (N,) true size [m];
    mass: (N,) [kg]; cls: (N,) int8 RoadUserClass values; type_id: (N,) SUMO vType ids.
    """

    ids: tuple[str, ...]
    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray
    speed: np.ndarray
    accel: np.ndarray
    length: np.ndarray
    width: np.ndarray
    mass: np.ndarray
    cls: np.ndarray
    type_id: tuple[str, ...] = field(default=())

    def __post_init__(self) -> None:
        n = len(self.ids)
        for name in ("x", "y", "yaw", "speed", "accel", "length", "width", "mass", "cls"):
            arr = getattr(self, name)
            if np.shape(arr) != (n,):
                raise ValueError(f"AgentStates.{name} has shape {np.shape(arr)}, expected ({n},)")
            object.__setattr__(self, name, _frozen_array(arr))
        if not self.type_id:
            object.__setattr__(self, "type_id", ("",) * n)

    @staticmethod
    def trusted(ids: tuple[str, ...], x: np.ndarray, y: np.ndarray, yaw: np.ndarray, speed: np.ndarray,
                accel: np.ndarray, length: np.ndarray, width: np.ndarray, mass: np.ndarray, cls: np.ndarray,
                type_id: tuple[str, ...]) -> "AgentStates":
        """Build without the shape checks, for internal hot paths (the scene read every step)
        whose arrays have shape (N,) by construction; they are still made read-only. About
        6x cheaper than the checked constructor. Everything user-facing uses the latter."""
        self = object.__new__(AgentStates)
        for name, value in zip(_AGENT_FIELDS, (ids, x, y, yaw, speed, accel, length, width, mass, cls, type_id)):
            if isinstance(value, np.ndarray):
                value.setflags(write=False)
            object.__setattr__(self, name, value)
        return self

    def __len__(self) -> int:
        return len(self.ids)

    @property
    def xy(self) -> np.ndarray:
        """(N, 2) centre positions [m]."""
        return np.stack([self.x, self.y], axis=-1)

    @functools.cached_property
    def index(self) -> dict[str, int]:
        """Position of each id in ``ids`` (built once per instance)."""
        return {k: i for i, k in enumerate(self.ids)}

    def take(self, index: np.ndarray | list[int]) -> "AgentStates":
        """The subset of agents at integer positions ``index``."""
        idx = np.asarray(index, dtype=int)
        return AgentStates.trusted(
            tuple(self.ids[i] for i in idx), self.x[idx], self.y[idx], self.yaw[idx], self.speed[idx],
            self.accel[idx], self.length[idx], self.width[idx], self.mass[idx], self.cls[idx],
            tuple(self.type_id[i] for i in idx),
        )

    @staticmethod
    def empty() -> "AgentStates":
        z = np.zeros(0)
        return AgentStates((), z, z, z, z, z, z, z, z, np.zeros(0, dtype=np.int8), ())


_AGENT_FIELDS = tuple(f.name for f in fields(AgentStates))


@dataclass(frozen=True)
class Observation:
    """What a predictor sees: the recent past of N neighbours around the ego.

    history: (N, H, 2) centre positions [m], oldest first, last row = now;
    valid: (N, H) bool, False where an agent was not yet observed (padding);
    dt: history sample interval [s]; current: the agents' full states now;
    ego: the ego's state now (1 agent).
    """

    time: float
    dt: float
    history: np.ndarray
    valid: np.ndarray
    current: AgentStates
    ego: AgentStates

    def __post_init__(self) -> None:
        object.__setattr__(self, "history", _frozen_array(self.history))
        object.__setattr__(self, "valid", _frozen_array(self.valid))


@dataclass(frozen=True)
class Prediction:
    """Per-agent Gaussian trajectories over the horizon, optionally several modes per agent.

    mean: (N, T, 2) [m]; cov: (N, T, 2, 2) [m^2]; yaw: (N, T) heading [rad];
    dt: horizon step [s]; step t is at time now + (t + 1) * dt.

    Multi-modal predictions: ``mean``/``cov``/``yaw`` are each agent's most likely mode;
    ``alternatives`` holds the other modes (each a single-mode Prediction of the same agents and
    steps, ordered by falling weight per agent) and ``weight`` (N, 1 + len(alternatives)) the
    probability of each mode, the first column that of the main one; rows sum to 1. A
    single-mode prediction has no alternatives and ``weight`` None (= 1). Consumers that read
    only mean/cov/yaw see the most likely future; the risk integrates every mode
    (:meth:`by_mode`).
    """

    ids: tuple[str, ...]
    dt: float
    mean: np.ndarray
    cov: np.ndarray
    yaw: np.ndarray
    alternatives: tuple["Prediction", ...] = ()
    weight: np.ndarray | None = None

    def __post_init__(self) -> None:
        for name in ("mean", "cov", "yaw"):
            object.__setattr__(self, name, _frozen_array(getattr(self, name)))
        alts = tuple(self.alternatives)
        object.__setattr__(self, "alternatives", alts)
        n = len(self.ids)
        if self.weight is None:
            if alts:
                raise ValueError("a Prediction with alternative modes needs their weights")
            return
        w = _frozen_array(np.asarray(self.weight, dtype=float))
        if w.shape != (n, 1 + len(alts)):
            raise ValueError(f"Prediction.weight must have shape ({n}, {1 + len(alts)}), got {w.shape}")
        for a in alts:
            if a.alternatives or tuple(a.ids) != tuple(self.ids) or a.mean.shape != self.mean.shape:
                raise ValueError("alternative modes must be single-mode predictions of the same agents and steps")
        object.__setattr__(self, "weight", w)

    @property
    def n_modes(self) -> int:
        return 1 + len(self.alternatives)

    def single(self) -> "Prediction":
        """The most likely mode alone."""
        return self if self.weight is None else Prediction(self.ids, self.dt, self.mean, self.cov, self.yaw)

    def by_mode(self) -> tuple[tuple["Prediction", np.ndarray], ...]:
        """((single-mode prediction, (N,) weight), ...) over the modes, the most likely first."""
        n = len(self.ids)
        w = np.ones((n, 1)) if self.weight is None else self.weight
        return tuple((m, w[:, i]) for i, m in enumerate((self.single(),) + self.alternatives))

    def take(self, index: np.ndarray | list[int]) -> "Prediction":
        """The agents at integer positions ``index``, every mode and weight kept."""
        idx = np.asarray(index, dtype=int)

        def one(m: Prediction) -> Prediction:
            return Prediction(tuple(m.ids[i] for i in idx), m.dt, m.mean[idx], m.cov[idx], m.yaw[idx])

        main = one(self.single())
        if self.weight is None:
            return main
        return Prediction(main.ids, main.dt, main.mean, main.cov, main.yaw, tuple(one(a) for a in self.alternatives),
                          self.weight[idx])

    def map_modes(self, fn) -> "Prediction":
        """``fn`` (single-mode Prediction -> single-mode Prediction) applied to every mode, weights kept."""
        main = fn(self.single())
        if self.weight is None:
            return main
        return Prediction(main.ids, main.dt, main.mean, main.cov, main.yaw, tuple(fn(a) for a in self.alternatives),
                          self.weight)


@dataclass(frozen=True)
class Candidates:
    """K candidate ego trajectories over T steps of ``dt`` (step t at now + (t + 1) * dt).

    x, y: (K, T) centre [m]; yaw: (K, T) [rad]; speed: (K, T) [m/s]; accel: (K, T) longitudinal
    [m/s^2]; curvature: (K, T) [1/m]; s, d: (K, T) Frenet arc length and lateral offset [m];
    horizon: (K,) horizon of each candidate [s] (past it the candidate keeps its end speed and
    lateral offset: what the ego would do next); valid: (K, T) bool, False only for padding.
    road_curvature: (K, T) [1/m] or None: the reference path's own curvature at each step's s,
    computed like ``curvature`` (``plan.sampling.sample``), so a candidate on the path (d = 0)
    has road_curvature == curvature and ``curvature - road_curvature`` is what a candidate adds
    to the road (turning relative to it, or keeping an offset on the inside of a bend). None:
    not known (``plan.feasibility.check`` then applies the vehicle's limit as on a straight road).
    """

    dt: float
    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray
    speed: np.ndarray
    accel: np.ndarray
    curvature: np.ndarray
    s: np.ndarray
    d: np.ndarray
    horizon: np.ndarray
    valid: np.ndarray
    road_curvature: np.ndarray | None = None

    def __post_init__(self) -> None:
        for name in ("x", "y", "yaw", "speed", "accel", "curvature", "s", "d", "horizon", "valid"):
            object.__setattr__(self, name, _frozen_array(getattr(self, name)))
        if self.road_curvature is not None:
            object.__setattr__(self, "road_curvature", _frozen_array(self.road_curvature))

    def __len__(self) -> int:
        return int(self.x.shape[0])

    def take(self, index: np.ndarray) -> "Candidates":
        """The candidates at integer positions ``index`` (K',); all of them in order: these same ones."""
        idx = np.asarray(index, dtype=int)
        if idx.ndim == 1 and len(idx) == len(self) and np.array_equal(idx, np.arange(len(self))):
            return self  # frozen arrays: nothing to copy
        return Candidates(self.dt, self.x[idx], self.y[idx], self.yaw[idx], self.speed[idx], self.accel[idx],
                          self.curvature[idx], self.s[idx], self.d[idx], self.horizon[idx], self.valid[idx],
                          None if self.road_curvature is None else self.road_curvature[idx])

    def take_steps(self, start: int) -> "Candidates":
        """The candidates from step ``start`` on, (K, T - start); their horizons shortened by as much."""
        sl = slice(start, None)
        return Candidates(self.dt, self.x[:, sl], self.y[:, sl], self.yaw[:, sl], self.speed[:, sl],
                          self.accel[:, sl], self.curvature[:, sl], self.s[:, sl], self.d[:, sl],
                          np.maximum(self.horizon - start * self.dt, 0.0), self.valid[:, sl],
                          None if self.road_curvature is None else self.road_curvature[:, sl])


@dataclass(frozen=True)
class CostBreakdown:
    """Every named cost term per candidate, each (K,); ``total`` is what selection minimises."""

    terms: dict[str, np.ndarray]
    total: np.ndarray

    def row(self, k: int) -> dict[str, float]:
        """The terms of candidate k as plain floats, for logging."""
        return {name: float(v[k]) for name, v in self.terms.items()} | {"total": float(self.total[k])}


#: why a candidate could not be chosen although it may score lower (DecisionTrace.excluded; explain)
EXCLUSIONS = ("", "crosses a red/yellow stop line", "leaves the road", "enters a predicted envelope (others stay out)",
              "brakes at the maximum deceleration with no emergency (another candidate stays out of every envelope)")


@dataclass(frozen=True)
class ViewTrace:
    """What the ego's sensor gave the planner at one step (``[planner] occlusion`` / ``phantoms``,
    :mod:`sumo_ethics.plan.perception`), kept for explain and the sumo-gui view.

    eye: (2,) the sensor's position [m]; radius: its range [m]; visible, hidden: shapely geometries of
    the visible region and of the shadows within the range; seen, remembered: ids of the road users
    seen and remembered while hidden; phantoms: the P hypothetical road users, phantom_prediction
    their predictions (None without phantoms), phantom_existence (P,) their existence probabilities,
    phantom_risk (P,) the chosen candidate's expected risk with each [-].
    """

    eye: np.ndarray
    radius: float
    visible: object
    hidden: object
    seen: tuple[str, ...]
    remembered: tuple[str, ...]
    phantoms: AgentStates
    phantom_prediction: Prediction | None
    phantom_existence: np.ndarray
    phantom_risk: np.ndarray


@dataclass(frozen=True)
class DecisionTrace:
    """What one planning step weighed, kept so the decision can be explained afterwards.

    The controller fills it from arrays it computed anyway (no copies); the runner hands it to the
    recorder and never reads it. ego: the ego (1 agent) at planning time; agents: the N
    neighbours; prediction: their (N, T) Gaussians; candidates: the K scored (feasible)
    candidates; cost: their named terms, each (K,), and ``cost.total`` = J_risk; selection: (K,)
    what the selection rule minimised (J_risk + envelope + entry under "cost", J_risk else);
    validity: (K,) int8 index of each candidate's validity class (``plan.ethical.VALIDITY``);
    eligible: (K,) bool, the candidates the rule could choose (the hard pool, or the chosen class);
    first_hit: (K,) int first step entering a predicted envelope (T if never); risk: (K,) summed
    ex-ante risk over every party (ego's and the others') [-]; chosen: index of the chosen one;
    excluded: (K,) int8 the hard constraint that kept a candidate from being chosen
    (:data:`EXCLUSIONS`; 0 none), None where not known; agent_risk: (N,) the chosen candidate's
    ex-ante risk with each neighbour (to the ego and to it, summed) [-], None where not known
    (what ``run --gui`` draws: the road users at risk); view: what the ego's sensor saw
    (:class:`ViewTrace`), None without ``[planner] occlusion`` or ``phantoms``.
    """

    ego: AgentStates
    agents: AgentStates
    prediction: Prediction
    candidates: Candidates
    cost: CostBreakdown
    selection: np.ndarray
    validity: np.ndarray
    eligible: np.ndarray
    first_hit: np.ndarray
    risk: np.ndarray
    chosen: int
    excluded: np.ndarray | None = None
    agent_risk: np.ndarray | None = None
    view: ViewTrace | None = None
