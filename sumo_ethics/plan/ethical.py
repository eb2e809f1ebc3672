"""The ethical planner: candidate trajectories scored by J_risk = w_o J_origin + w_u J_utility.

predict (neighbours) -> sample (Frenet candidates) -> check (feasibility) -> assess risk
(P(collision) x harm) -> score (named cost terms) -> select (validity class, then lowest J_risk).

A multi-modal prediction (several futures per agent, with weights) goes whole through the
braking and lateral priors (each mode alike) and the risk (every mode by its weight,
:func:`~sumo_ethics.ethics.risk.assess_risk`); the envelope test (:func:`first_overlap`) and
the recorded prediction's mean and covariance use the most likely mode.
"""

from __future__ import annotations

import math
import time
import zlib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

from sumo_ethics.errors import ConfigError, is_number
from sumo_ethics.plan import warmup
from sumo_ethics.ethics.cost import CostConfig, UtilityMode, score
from sumo_ethics.ethics.probability import ProbabilityConfig
from sumo_ethics.ethics.risk import assess_risk
from sumo_ethics.contract import Decision, EgoCommand, Scene
from sumo_ethics.plan.feasibility import check
from sumo_ethics.plan.perception import Perception, PerceptionConfig, SightMap
from sumo_ethics.plan.phantoms import phantom_risk
from sumo_ethics.plan.sampling import FrenetState, SamplingConfig, quintic_coeffs, reference_heading, sample
from sumo_ethics.plan.side import side_to_keep
from sumo_ethics.predict import registry
from sumo_ethics.predict.braking import apply_braking_prior, apply_lateral_prior, recent_motion
from sumo_ethics.predict.constant_velocity import non_finite, replace_non_finite
from sumo_ethics.predict.protocols import MapSourceFactory, Predictor
from sumo_ethics.types import Candidates, DecisionTrace, Observation, Prediction


#: validity classes, best first (the selected candidate's class is logged as ``validity``)
VALIDITY = ("safe", "no_overlap_on_road", "no_overlap", "feasible", "emergency")
#: selection rules (PlannerConfig.selection):
#: "cost": red lights and the road edge stay hard constraints; among the candidates left, the lowest
#:   J_risk + envelope x [enters a road user's predicted envelope] + entry x [how early] wins, so
#:   when every candidate enters someone's envelope (unavoidable harm) the ethical cost decides;
#: "validity": Origin's rule: the lowest J_risk within the best non-empty validity class;
#: "validity_ttc": this project's earlier rule: as "validity", but in a class whose members all enter
#:   an envelope, the latest-entering and then least-travelling ones are kept before the cost.
SELECTIONS = ("cost", "validity", "validity_ttc")


@dataclass(frozen=True)
class PlannerConfig:
    """Everything the ethical planner decides with.

    max_risk: a candidate is "safe" when its largest risk against any party (ego's plus the
    other's) stays below this [-]; predictor: a name of the predictor registry
    (:mod:`sumo_ethics.predict.registry`): "map" (the paper's attention LSTM that also reads lanes
    and signals, the default), "map_cslstm" (the same without the attention), "attention" (the
    paper's), "cslstm", "cv" (constant velocity), or one registered since; predictor_weights: a
    weights file of a learned predictor (None: its shipped one);
    braking_prior: agents decelerating at least this hard [m/s^2] are predicted to keep braking
    until they stand; lateral_prior: agents moving across their straight predicted path keep
    their lateral speed for this long [s] (both ``sumo_ethics.predict.braking``; 0 = off);
    lateral_onset: the lateral prior sees a lane change's onset: sideways motion measured across
    the direction of travel over the last second, and a growing sideways speed kept growing
    (:func:`~sumo_ethics.predict.braking.recent_motion`; ``origin`` and ``paper`` run without it);
    calibrated: apply the covariance calibration shipped beside the LSTM's weights file
    (``predict/calibration.py``; False: the model's own spreads, as published; no effect on "cv");
    selection: one of :data:`SELECTIONS`; envelope: the cost of entering a road user's predicted
    envelope (its box at the predicted mean with Origin's margins, the ego's box stretched by its
    braking distance) in "cost" selection [-], about 100x a typical progress term, so the ego keeps
    out of envelopes whenever it can and only unavoidable entries are weighed by the risk terms;
    entry: in "cost" selection, the cost of entering an envelope at once, falling linearly to 0
    for an entry at the end of the horizon [-] (a time-to-collision term: later is better; what it
    did to completion: docs/method.md, step 6 "Select");
    evasive: also sample candidates that brake at ``vehicle.max_decel`` from the first step while
    moving to the lateral end offsets (:func:`evasive_candidates`): the grid's own profiles start
    from the current acceleration and take about a second to build up braking, and the straight
    braking candidates keep their lateral offset, so without them the ego can brake or swerve but
    not both at once (a car cutting in ahead; ``origin`` and ``paper`` run without them, as published);
    replan_every: plan every n-th step and follow the committed plan between (Frenetix plans every
    3rd step); the steps are staggered by the ego's id (a fleet's egos do not all plan in the same
    step), and the ego plans at once when it is off its plan, a predicted road user enters the rest
    of the plan's envelope, a road user the plan did not weigh is at risk from it, or the plan runs
    out (1: every step, the default; with occlusion or phantoms every step too; see
    :meth:`EthicalPlanner.follow`);
    share_plans: in a fleet, predict the other egos that share their plans by their committed
    plans (one mode with a tracking spread) instead of the model, and share this ego's
    (:class:`sumo_ethics.runner.fleet.SharedPrediction`; no effect on a single ego);
    occlusion: the planner knows only the road users its sensor sees and remembers (``perception``:
    range, memory, ...; :mod:`~sumo_ethics.plan.perception`), else every one in the sensing radius;
    phantoms: hypothetical road users where one could come out of a shadow, their risk a cost term of
    its own (:mod:`~sumo_ethics.plan.phantoms`); both off by default;
    keep_side: while oncoming traffic approaches beside the path, the lateral term's reference moves
    this far [m] from the lane's centre to the side away from it, within the drivable area
    (:mod:`~sumo_ethics.plan.side`; 0: off, the default).
    """

    cost: CostConfig = field(default_factory=CostConfig)
    # 4 horizons (1 s gives hard stops) x 15 end speeds x 17 lateral offsets = 1020 candidates
    sampling: SamplingConfig = field(default_factory=lambda: SamplingConfig(horizons=(1.0, 2.0, 3.0, 4.0),
                                                                            n_offsets=17))
    probability: ProbabilityConfig = field(default_factory=ProbabilityConfig)
    predictor: str = "map"
    predictor_weights: str | None = None  # a weights file for a learned predictor (default: shipped)
    calibrated: bool = True
    max_risk: float = 0.01
    braking_prior: float = 3.0
    lateral_prior: float = 1.5
    lateral_onset: bool = True
    selection: str = "cost"
    envelope: float = 1000.0
    entry: float = 1000.0
    evasive: bool = True
    replan_every: int = 1
    share_plans: bool = False
    occlusion: bool = False
    phantoms: bool = False
    keep_side: float = 0.0
    perception: PerceptionConfig = field(default_factory=PerceptionConfig)

    def __post_init__(self) -> None:
        if self.selection not in SELECTIONS:
            raise ConfigError(f"unknown selection '{self.selection}'; known: {', '.join(SELECTIONS)}")
        for name in ("envelope", "entry"):
            value = getattr(self, name)
            if not is_number(value, 0.0, 1e12, hi_open=True):
                raise ConfigError(f"{name} must be a cost >= 0, got {value!r}")
        registry.check(self.predictor, self.predictor_weights)  # known, and a weights file only for a learned one
        for flag in ("calibrated", "evasive", "lateral_onset", "share_plans", "occlusion", "phantoms"):
            if not isinstance(getattr(self, flag), bool):
                raise ConfigError(f"{flag} must be true or false, got {getattr(self, flag)!r}")
        if not (isinstance(self.replan_every, int) and not isinstance(self.replan_every, bool)
                and 1 <= self.replan_every <= 100):
            raise ConfigError(f"replan_every must be a whole number of steps from 1 to 100, got {self.replan_every!r}")
        if not (isinstance(self.max_risk, (int, float)) and 0.0 < self.max_risk <= 1.0):
            raise ConfigError(f"max_risk must be in (0, 1], got {self.max_risk!r}")
        if not is_number(self.keep_side, 0.0, 5.0):
            raise ConfigError(f"keep_side must be a distance from 0 to 5 m (0 = off), got {self.keep_side!r}")
        if not (isinstance(self.lateral_prior, (int, float)) and 0.0 <= self.lateral_prior < 1e3):
            raise ConfigError(f"lateral_prior must be a time >= 0 s (0 = off), got {self.lateral_prior!r}")
        if not (isinstance(self.braking_prior, (int, float)) and 0.0 <= self.braking_prior < 1e3):
            raise ConfigError(f"braking_prior must be a deceleration >= 0 m/s^2 (0 = off), got {self.braking_prior!r}")


def keep_heap_warm(pad: int = 64 << 20) -> None:
    """Ask glibc to keep ``pad`` bytes at the top of the heap: the planner's numpy temporaries
    otherwise make it shrink and regrow the heap every step (thousands of page faults, 2-3 ms)."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").mallopt(-2, pad)  # M_TOP_PAD
    except (OSError, AttributeError):  # not glibc: nothing to tune
        pass


def make_predictor(name: str, weights: str | None = None, calibrated: bool = True,
                   maps: MapSourceFactory | None = None) -> Predictor:
    """Predictor ``name`` of the registry (:func:`sumo_ethics.predict.registry.make`): a learned one
    (the LSTMs "map", "map_cslstm", "attention", "cslstm") from ``weights`` or its shipped file,
    with the calibration shipped beside it unless ``calibrated=False``. ``maps``: the map source
    for a model of a map version (in a run the runner passes ``sim.lanes.SumoMapSource``, which reads
    lanes and signals from the running simulation); None: a map-aware model predicts without map
    context (tests, benchmarks that set ``map_source`` themselves)."""
    return registry.make(name, weights=weights, calibrated=calibrated, maps=maps)


def first_overlap(cand: Candidates, pred: Prediction, length: np.ndarray, width: np.ndarray, ego_length: float,
                  ego_width: float, brake: float | None = None) -> np.ndarray:
    """(K,) int: the first step at which the ego box meets an agent's box at its predicted mean
    (T if never). length, width: (N,) the agents' boxes [m] (pass them with safety margins).

    Multi-modal ``pred``: only the most likely mode's mean path counts (``pred.mean``, i.e.
    ``pred.single()``). The envelope is a near-hard constraint (PlannerConfig.envelope), so
    avoiding every mode's path would let an unlikely "pulls away" mode block a lane as firmly
    as the likely one; the other modes act through the risk terms, by their weights.

    brake [m/s^2]: if given, the ego box at each step is stretched forward by its stopping
    distance v^2 / (2 brake), so a candidate also "meets" a road user it could no longer stop
    for (a candidate that ends its horizon too close behind a slower leader is not safe).
    Which (k, n, t) are tested is decided by distance alone (both boxes' half-diagonals, the
    stretch included; :func:`sumo_ethics.ethics.shapes.envelope_first_hit`), never by a
    collision probability.
    """
    from sumo_ethics.ethics.shapes import envelope_first_hit

    K, T = cand.x.shape
    tp = min(T, pred.mean.shape[1])
    if len(pred.ids) == 0 or tp == 0 or K == 0:
        return np.full(K, T, dtype=np.int64)
    first = envelope_first_hit(cand.x[:, :tp], cand.y[:, :tp], cand.yaw[:, :tp], cand.speed[:, :tp],
                               cand.valid[:, :tp], pred.mean[:, :tp, 0], pred.mean[:, :tp, 1], pred.yaw[:, :tp],
                               length, width, ego_length, ego_width, brake)
    return np.where(first >= tp, T, first)  # the kernel sees tp steps: "never" comes back as tp


#: the straight brakes let the ego's sideways motion settle over the arc length they cover in this time [s]
BRAKE_SETTLE = 1.0


def brake_candidates(path, state: FrenetState, n_steps: int, dt: float, decels: np.ndarray,
                     max_curvature: float = 0.2, d_end: float | None = None,
                     max_lat_accel: float = 4.0) -> Candidates:
    """Braking at constant decelerations ``decels`` (B,) [m/s^2] from the first step: the quartic profiles
    take a second to build up braking (they start from the current acceleration), these do not.

    Laterally they keep the offset, but an ego moving sideways (a lane change or a swerve under way,
    ``state.d_dot``) does not turn onto the path within one step: its slope across the path,
    d' = d_dot / s_dot (clipped to 1, 0 below 0.1 m/s), settles to 0 along a quintic d(sigma) with d'' = 0
    at both ends, ending at d + d' Sigma / 2, then d stays. Sigma is the arc length the brake covers in
    :data:`BRAKE_SETTLE` s, but at least 2 |d'| / ``max_curvature`` [1/m] (the quintic's sharpest turn
    is 1.875 |d'| / Sigma): a brake that stops sooner stands at an angle to the path, as a car braking
    with its wheels held would, instead of turning faster than it can steer. Its heading is the path's plus atan2(d', 1 - kappa d): no
    jump at the start, and none at a standstill (a function of the distance travelled). Curvature and
    road_curvature are :func:`central_curvature` of the heading and of the path's own heading from the
    ego's (the same when the ego moves along the path); speed is the along-path speed v0 - b t.

    ``d_end`` [m]: brakes to the side instead (the side to keep, :mod:`~sumo_ethics.plan.side`): the
    quintic runs from (d, d', 0) to (d_end, 0, 0) over all the arc L the brake covers within the
    horizon (at least 2 |d'| / ``max_curvature``, as above; none below 0.5 m: it stays), or as far
    towards d_end (from where settling d' alone ends) as turns within 0.9 of ``max_curvature`` and of
    ``max_lat_accel`` [m/s^2] / v0^2, less what settling d' takes (a shift by D turns at most
    10 / sqrt(3) |D| / L^2 sharp); the feasibility check judges it as any other."""
    t = dt * np.arange(1, n_steps + 1)[None, :]  # (1, T)
    b = np.asarray(decels, dtype=float)[:, None]  # (B, 1)
    v0 = max(state.s_dot, 0.0)
    t_stop = v0 / b
    tc = np.minimum(t, t_stop)
    s = state.s + v0 * tc - 0.5 * b * tc**2
    v = np.maximum(v0 - b * t, 0.0)
    a = np.where(t <= t_stop, -b, 0.0) * np.ones_like(s)
    p1 = float(np.clip(state.d_dot / state.s_dot, -1.0, 1.0)) if state.s_dot >= 0.1 else 0.0
    href = reference_heading(path, s)
    href0 = float(reference_heading(path, np.asarray(state.s)))
    if p1 == 0.0 and d_end is None:
        d = np.full_like(s, state.d)
        yaw, yaw0 = href, href0
    else:
        if d_end is None:  # settle the sideways slope
            ts = np.minimum(BRAKE_SETTLE, t_stop)  # (B, 1)
            sig_end = np.maximum(v0 * ts - 0.5 * b * ts**2, 2.0 * abs(p1) / max_curvature)  # (B, 1) [m]
            travels = sig_end >= 1e-3
        else:  # move towards d_end over the whole arc, as far as the curvature limit lets it
            sig_end = np.maximum(s[:, -1:] - state.s, 2.0 * abs(p1) / max_curvature)
            travels = sig_end >= 0.5
        L = np.where(travels, sig_end, 1.0)
        settled = state.d + 0.5 * p1 * L  # where settling the slope alone ends
        if d_end is None:
            target = settled
        else:  # a quintic shift by D over L turns at most 10 / sqrt(3) |D| / L^2 sharp, settling the slope
            # p1 at most 1.875 |p1| / L: what is left of the limit at the starting speed goes to the shift
            sharpest = min(max_curvature, max_lat_accel / max(v0 * v0, 1e-6))
            budget = np.maximum(sharpest - 1.875 * abs(p1) / L, 0.0)
            reach = 0.9 * budget * L**2 / (10.0 / math.sqrt(3.0))
            target = settled + np.clip(d_end - settled, -reach, reach)
        c = quintic_coeffs(state.d, p1, 0.0, target, L)  # (B, 1, 6)
        u = np.clip(s - state.s, 0.0, L)
        d = sum(c[..., i] * u**i for i in range(6))
        slope = sum(i * c[..., i] * u ** (i - 1) for i in range(1, 6))
        d = np.where(travels, d, state.d)
        slope = np.where(travels & (u < L), slope, 0.0)
        yaw = href + np.arctan2(slope, 1.0 - path.curvature_at(s) * d)
        yaw0 = href0 + math.atan2(p1, 1.0 - float(path.curvature_at(state.s)) * state.d)
    x, y, _ = path.to_xy(s, d)
    shape = s.shape
    road = central_curvature(href, href0, v, v0, dt)
    k = road if p1 == 0.0 and d_end is None else central_curvature(yaw, yaw0, v, v0, dt)
    return Candidates(dt=dt, x=x, y=y, yaw=yaw, speed=v, accel=a, curvature=k, s=s, d=d,
                      horizon=np.full(shape[0], n_steps * dt), valid=np.ones(shape, dtype=bool), road_curvature=road)


def central_curvature(heading: np.ndarray, heading0: float, speed: np.ndarray, speed0: float, dt: float) -> np.ndarray:
    """(..., T) curvature [1/m] of a motion sampled every ``dt`` [s]: the central difference of the unwrapped
    ``heading`` [rad] over the distance travelled (trapezoidal in ``|speed|`` [m/s]), one-sided at the
    last step, from ``heading0`` and ``speed0`` just before step 0; 0 where that distance is under 1 mm
    (:func:`~sumo_ethics.plan.sampling.sample`'s definition)."""
    h = np.concatenate([np.full(heading.shape[:-1] + (1,), heading0), heading], axis=-1)
    v = np.abs(np.concatenate([np.full(speed.shape[:-1] + (1,), speed0), speed], axis=-1))
    step = (v[..., 1:] + v[..., :-1]) * (0.5 * dt)  # distance into each step [m]
    dh = np.diff(h, axis=-1)  # heading change into each step
    num = dh.copy()
    den = step.copy()
    num[..., :-1] += dh[..., 1:]
    den[..., :-1] += step[..., 1:]
    return np.where(den > 1e-3, num / np.where(den > 1e-3, den, 1.0), 0.0)


#: the evasive candidates' grid (:func:`evasive_candidates`): end speeds and lateral end offsets
EVASIVE_SPEEDS, EVASIVE_OFFSETS = 5, 9


def evasive_candidates(path, state: FrenetState, grid: SamplingConfig, decel: float, v_max: float,
                       left: np.ndarray | float | None, right: np.ndarray | float | None,
                       margin: float, out: np.ndarray | None = None, row: int = 0) -> Candidates:
    """Candidates that brake at once while moving sideways: :func:`sample` from ``state`` as if the
    ego already decelerated at ``decel`` [m/s^2] (its quartics start at s'' = -decel), on horizons
    of 1 s, 2 s and the grid's longest (those below it), :data:`EVASIVE_SPEEDS` end speeds and
    :data:`EVASIVE_OFFSETS` lateral end offsets over the drivable area; (3 x 5 x 9 = 135, K, T) with
    the grid's T. Like the straight braking candidates (:func:`brake_candidates`) they jump to the
    deceleration at the first step; the feasibility check judges their acceleration, curvature and
    lateral acceleration as any other's. out, row: as :func:`sample`'s."""
    ev = evasive_grid(grid)
    return sample(path, replace(state, s_ddot=-float(decel)), ev, v_max=v_max, left=left, right=right, margin=margin,
                  out=out, row=row)


def evasive_grid(grid: SamplingConfig) -> SamplingConfig:
    """The evasive candidates' grid beside ``grid`` (:func:`evasive_candidates`)."""
    top = max(grid.horizons)
    horizons = tuple(h for h in (1.0, 2.0) if h < top) + (top,)
    return replace(grid, horizons=horizons, n_speeds=EVASIVE_SPEEDS, n_offsets=EVASIVE_OFFSETS)


#: the order of :func:`sample`'s block (its ``out``): the Candidates' (K, T) float arrays
BLOCK_FIELDS = ("x", "y", "yaw", "speed", "accel", "curvature", "s", "d", "road_curvature")


def concat(*parts: Candidates) -> Candidates:
    """The candidates of ``parts`` one after another (same dt and T), each array copied once.
    road_curvature: None if no part knows it, else 0 (a straight road: the strict limit) for the
    parts that do not."""
    road = None
    if any(c.road_curvature is not None for c in parts):
        road = np.concatenate([np.zeros_like(c.curvature) if c.road_curvature is None else c.road_curvature
                               for c in parts])

    def cat(f: str) -> np.ndarray:
        return np.concatenate([getattr(c, f) for c in parts])

    return Candidates(parts[0].dt, cat("x"), cat("y"), cat("yaw"), cat("speed"), cat("accel"), cat("curvature"),
                      cat("s"), cat("d"), cat("horizon"), cat("valid"), road_curvature=road)


def select(classes: list[np.ndarray], total: np.ndarray, first_hit: np.ndarray | None = None, steps: int = 0,
           travel: np.ndarray | None = None) -> tuple[int, int]:
    """(candidate, class index): the lowest total within the best non-empty class.

    With first_hit and travel given ("validity_ttc"), in a class whose members all enter a road
    user's safety envelope (first_hit < steps), the ones that enter it latest come first, and
    among those the ones that travel least: time to collision, then caution, before cost.
    A candidate whose total is non-finite (NaN counts as +inf) belongs to no class;
    (-1, len(classes)) if every class is empty.
    """
    finite = np.isfinite(total)
    for c, members in enumerate(classes):
        members = members & finite
        if members.any():
            if first_hit is not None and travel is not None:
                hits = first_hit[members]
                if (hits < steps).all():
                    members = members & (first_hit == hits.max())
                    members = members & (travel <= travel[members].min() + 0.05)
            return int(np.argmin(np.where(members, total, np.inf))), c
    return -1, len(classes)


def hard_pool(legal: np.ndarray, on_road: np.ndarray) -> np.ndarray:
    """(K,) bool: the candidates "cost" selection may choose: legal (no red stop line crossed) and
    on the road, else on the road, else all (the hard constraints, dropped from the last)."""
    return next((m for m in (legal & on_road, on_road) if m.any()), np.ones_like(on_road))


def emergency_only(pool: np.ndarray, evasive: np.ndarray | None, overlap: np.ndarray) -> np.ndarray:
    """(K,) bool: ``pool`` without the evasive candidates (:func:`evasive_candidates`) while one of its
    other candidates stays outside every predicted envelope: braking at the maximum deceleration
    at once is for emergencies, not for the everyday slowing down the grid's gentler profiles do
    (chosen freely they made the ego brake hard with nothing in sight, 4x as often on the suite)."""
    if evasive is None or not evasive.any():
        return pool
    return pool & ~evasive if (pool & ~evasive & ~overlap).any() else pool


def exclusion_codes(legal: np.ndarray, on_road: np.ndarray, overlap: np.ndarray, selection: str,
                    evasive: np.ndarray | None = None) -> np.ndarray:
    """(K,) int8 index into :data:`sumo_ethics.types.EXCLUSIONS`: the hard constraint that keeps each candidate out of
    :func:`hard_pool` (a red/yellow stop line, then the road edge; only where some candidate keeps
    it) and, under "cost" selection, out of the envelope-free pool when that is not empty, or an
    evasive candidate held back while there is no emergency (:func:`emergency_only`); 0 none."""
    code = np.zeros(len(legal), dtype=np.int8)
    if (legal & on_road).any():
        code[~legal] = 1
        code[legal & ~on_road] = 2
    elif on_road.any():
        code[~on_road] = 2
    if selection == "cost":
        pool = hard_pool(legal, on_road)
        if (pool & ~overlap).any():
            code[pool & overlap] = 3
        held = pool & ~emergency_only(pool, evasive, overlap)
        code[held & (code == 0)] = 4
    return code


def validity_classes(classes: list[np.ndarray]) -> np.ndarray:
    """(K,) int8: the index of the first class each candidate belongs to (len(classes) if none)."""
    member = np.vstack(classes + [np.ones_like(classes[0])])
    return np.argmax(member, axis=0).astype(np.int8)


def class_of(classes: list[np.ndarray], k: int) -> int:
    """Index of the first class candidate k belongs to (len(classes) if none)."""
    return next((c for c, members in enumerate(classes) if members[k]), len(classes))


#: [m and m/s] an ego further than this from where its committed plan put it (or at a speed this far
#: from the plan's) plans anew (replan_every > 1)
OFF_PLAN = 0.25
#: why a step was planned with replan_every > 1 (steps.parquet ``replanned``; 0: it followed its plan)
REPLAN = {"followed": 0, "no_plan": 1, "turn": 2, "off_plan": 3, "envelope": 4, "new_at_risk": 5}


@dataclass(frozen=True)
class Plan:
    """A committed plan (replan_every > 1): the chosen candidate (1, T), the time it was chosen at
    [s], the road users it saw, and its step's named numbers."""

    cand: Candidates
    time: float
    ids: frozenset[str]
    info: dict[str, float]


class EthicalPlanner:
    """The default controller: the paper's utility-risk planner on top of Origin's J_origin."""

    name = "ethical"
    needs_history = True

    def __init__(self, cfg: PlannerConfig = PlannerConfig(), predictor: Predictor | None = None,
                 maps: MapSourceFactory | None = None,
                 sight: Callable[[tuple[str, ...]], SightMap] | SightMap | None = None) -> None:
        """``predictor``: a ready one (else built from ``cfg``); ``maps``: the map source factory a
        map-aware predictor is given (:func:`make_predictor`); ``sight``: the sensor's static world
        (or a factory of it from the opaque polygon types) for ``occlusion`` and ``phantoms``."""
        self.cfg = cfg
        self.predictor = predictor or make_predictor(cfg.predictor, cfg.predictor_weights, cfg.calibrated, maps)
        keep_heap_warm()
        self._lateral = (0.0, 0.0)  # d', d'' of the last chosen candidate at the next step
        self._accel = 0.0
        self._sampling: SamplingConfig | None = None
        self._evasive_grid: SamplingConfig = evasive_grid(self.cfg.sampling)
        self._plan: Plan | None = None  # the committed plan (replan_every > 1)
        self._shares_plans = cfg.share_plans and callable(getattr(self.predictor, "publish", None))
        self.replan_reason = REPLAN["no_plan"]
        # the settings that shape _priors (a fleet's shared prediction caches its rows under them)
        self._prior_key = (cfg.lateral_prior, cfg.lateral_onset, cfg.braking_prior)
        # [planner] occlusion / phantoms: the ego's own sensor, memory and phantoms (plan/perception.py)
        self.perception = (Perception(cfg.perception, cfg.occlusion, cfg.phantoms, sight)
                           if cfg.occlusion or cfg.phantoms else None)

    @property
    def predictor_info(self) -> dict:
        """What predicted the neighbours (summary.json ``predictor``): kind, weights file (absolute path),
        number of trajectory modes and whether its covariance calibration was applied."""
        path = getattr(self.predictor, "path", None)
        model = getattr(self.predictor, "model", None)
        return {"kind": getattr(self.predictor, "kind", self.cfg.predictor),
                "weights": str(Path(path).resolve()) if path else None, "modes": int(getattr(model, "modes", 1)),
                "calibrated": getattr(self.predictor, "calibration", None) is not None}

    @property
    def needs_rules(self) -> bool:
        """Whether the runner must name the rule breakers (only the responsibility term uses them)."""
        return self.cfg.cost.weights.responsibility > 0.0

    def act(self, scene: Scene) -> Decision:
        warmup.wait()  # the kernels compiled in the background (sumo-ethics run, evaluate, sweep), if any
        if self.cfg.replan_every > 1:
            followed = self.follow(scene)
            if followed is not None:
                return followed
        decision = self.plan(scene)
        if self.cfg.replan_every > 1:
            decision.info["replanned"] = float(self.replan_reason)
        return decision

    def plan(self, scene: Scene) -> Decision:
        """One planning step: predict, sample, assess, score, select (see the module docstring)."""
        self._plan = None
        veh = scene.vehicle
        ego_length, ego_width = float(scene.ego.length[0]), float(scene.ego.width[0])
        if self._sampling is None:  # plan at the simulation's step so commands fall on samples (the one step:
            # settings.planner_config refuses a sampling dt that differs, runner.loop.on_run_step sets it)
            self._sampling = replace(self.cfg.sampling, dt=scene.dt)
            self._evasive_grid = evasive_grid(self._sampling)
        sc = self._sampling
        w0 = time.perf_counter()
        horizon_steps = int(round(max(sc.horizons) / sc.dt))
        agents = scene.others
        obs = scene.history
        if obs is None:
            raise ValueError("the ethical planner needs the neighbours' history in its scene (needs_history)")
        percept = None
        if self.perception is not None:  # occlusion: only what the sensor sees, its history as seen
            percept = self.perception.perceive(scene, horizon_steps, sc.dt)
            obs, agents = percept.observed(obs, agents)
        pred, n_fallback = self._predict(obs, horizon_steps, sc.dt)
        if percept is not None:  # the road users remembered while hidden, from where they were last seen
            pred, agents = percept.with_remembered(pred, agents, horizon_steps, sc.dt)
        w1 = time.perf_counter()
        route = scene.route
        i = route.vertex_at(scene.s)
        v_limit = min(float(route.speed_limit[i]), veh.max_speed)
        # the progress term's v_desired: the limit, or less where a run hook asks for less (an imported
        # CommonRoad goal's time window); the candidates still reach the limit
        v_desired = v_limit if scene.desired_speed is None else min(v_limit, scene.desired_speed)
        v = float(scene.ego.speed[0])
        # the sampled candidates start at the ego's speed v (not at s_dot = v: see at_speed)
        state = FrenetState.at_speed(route.path, scene.s, scene.d, v, s_ddot=self._accel, d_dot=self._lateral[0],
                                     d_ddot=self._lateral[1])
        # one block for the grid, the straight braking and the evasive candidates (appended: the grid's
        # indices stay as they were), each written in place (no copy to put them together)
        decels = np.array([veh.comfort_decel, 0.5 * (veh.comfort_decel + veh.max_decel), veh.max_decel])
        # the side to keep while oncoming traffic passes (keep_side): the lateral term's reference, and
        # brakes that end at the side (as far as the drivable area leaves room), for emergencies only
        side, room, d_ref = side_to_keep(route, scene.s, scene.d, v, agents, ego_width, self.cfg.keep_side)
        n_side = len(decels) if side and side * (side * room - scene.d) > 0.05 else 0  # only towards the side
        n_grid, n_plain = sc.n_candidates, sc.n_candidates + len(decels)
        n_evasive = self._evasive_grid.n_candidates if self.cfg.evasive else 0
        block = np.empty((9, n_plain + n_evasive + n_side, sc.n_steps))
        grid = sample(route.path, state, sc, v_max=v_limit, left=route.left, right=route.right, margin=ego_width / 2.0,
                      out=block, row=0)
        brakes = brake_candidates(route.path, replace(state, s_dot=v), sc.n_steps, sc.dt, decels,  # speed v - b t
                                  max_curvature=veh.max_curvature)
        for f, name in enumerate(BLOCK_FIELDS):
            block[f, n_grid:n_plain] = getattr(brakes, name)
        parts = [grid, brakes]
        if self.cfg.evasive:  # braking and swerving at once
            parts.append(evasive_candidates(route.path, state, sc, veh.max_decel, v_limit, route.left, route.right,
                                            ego_width / 2.0, out=block, row=n_plain))
        if n_side:  # after the evasive ones, and like them eligible only in an emergency (emergency_only)
            side_brakes = brake_candidates(route.path, replace(state, s_dot=v), sc.n_steps, sc.dt, decels,
                                           max_curvature=veh.max_curvature, d_end=side * room,
                                           max_lat_accel=veh.max_lat_accel)
            for f, name in enumerate(BLOCK_FIELDS):
                block[f, n_plain + n_evasive:] = getattr(side_brakes, name)
            parts.append(side_brakes)
        x, y, yaw, speed, accel, curvature, s, d, road = block
        cand = Candidates(sc.dt, x, y, yaw, speed, accel, curvature, s, d, np.concatenate([c.horizon for c in parts]),
                          np.ones(block.shape[1:], dtype=bool), road_curvature=road)
        # an ego above the limit (e.g. at takeover) must be allowed to slow down to it
        feas = check(cand, route, veh, speed_limit_factor=max(1.0, (v + 0.01) / max(v_limit, 0.1)))
        w2 = time.perf_counter()
        # only physically feasible candidates can be chosen: risk and cost are for those alone
        feasible, lat_limit = feas.feasible, veh.max_lat_accel
        if not feasible.any():  # the bend asks every candidate for more than the limit: the least excess
            feasible, lat_limit = feas.least_lateral()
        keep = np.flatnonzero(feasible)
        if len(keep) == 0:
            dec = self._emergency(scene, {"predict_ms": 1e3 * (w1 - w0), "sample_ms": 1e3 * (w2 - w1)})
            dec.info["n_fallback"] = float(n_fallback)
            if percept is not None:  # what the sensor saw is recorded on every step, an emergency's too
                dec.info.update(percept.counts())
            return dec
        fc = cand.take(keep)
        on_road = feas.on_road[keep]
        # (K,) the evasive ones among them, and the brakes to the side: for emergencies only
        evasive = keep >= n_plain if self.cfg.evasive or n_side else None
        breakers = np.array([i in scene.rule_breakers for i in agents.ids], dtype=bool)
        risk = assess_risk(fc, pred, agents, ego_mass=float(scene.ego.mass[0]), ego_cls=int(scene.ego.cls[0]),
                           ego_length=ego_length, ego_width=ego_width, prob_cfg=self.cfg.probability,
                           off_road=~on_road, rule_breaker=breakers, steps=False,
                           need_at_risk=self.cfg.cost.normalise == "at_risk")
        pc = self.cfg.probability  # Origin's safety margins (+1.0 m length, +0.5 m width)
        first_hit = first_overlap(fc, pred, agents.length + pc.length_margin,
                                  agents.width + pc.width_margin, ego_length, ego_width, brake=veh.max_decel)
        overlap = first_hit < horizon_steps
        legal = np.ones(len(fc), dtype=bool)
        if scene.stop_s is not None:  # do not cross a red/yellow stop line with the front bumper
            legal = ~np.any(fc.valid & (fc.s + ego_length / 2.0 > scene.stop_s), axis=1)
        worst = np.max(risk.ego_risk + risk.other_risk, axis=1) if len(agents) else np.zeros(len(fc))
        # METHOD.md's classes: criteria are dropped from the last: max risk, then staying on the
        # road, then avoiding the predicted mean paths; a red light counts like the road edge
        classes = [legal & ~overlap & on_road & (worst < self.cfg.max_risk), legal & ~overlap & on_road,
                   ~overlap, np.ones(len(fc), dtype=bool)]
        # J_mean averages over the candidates the selection rule chooses among
        ph_risk = None
        if percept is not None and percept.phantoms is not None:  # the phantoms' risk: a term of its own
            ph_risk = phantom_risk(fc, percept.phantoms, scene.ego, self.cfg.probability, self.cfg.perception.reaction,
                                   veh.max_decel)
        # every registered cost term (sumo_ethics.ethics.terms), the phantoms' among them
        extra: dict[str, Any] = {} if ph_risk is None else {"phantom_risk": ph_risk.sum(axis=1)}
        if self.cfg.keep_side > 0.0:
            extra["lateral_reference"] = d_ref
        cost = score(fc, risk, self.cfg.cost, desired_speed=v_desired,
                     feasible=self.pool(classes, legal, on_road, overlap, evasive), extra=extra,
                     weights={"phantom": self.cfg.perception.weight})
        w3 = time.perf_counter()
        envelope = self.cfg.envelope * overlap
        entry = self.cfg.entry * np.maximum(horizon_steps - first_hit, 0) / horizon_steps
        total, j, cls = self.choose(cost, classes, envelope + entry, legal, on_road, first_hit, horizon_steps,
                                    fc.s[:, -1] - scene.s, evasive)
        if j < 0:  # every candidate's total is non-finite: none can be weighed
            dec = self._emergency(scene, {"predict_ms": 1e3 * (w1 - w0), "sample_ms": 1e3 * (w2 - w1)})
            dec.info["n_fallback"] = float(n_fallback)
            if percept is not None:  # what the sensor saw is recorded on every step, an emergency's too
                dec.info.update(percept.counts())
            return dec
        k = int(keep[j])
        w4 = time.perf_counter()
        timings = {"predict_ms": 1e3 * (w1 - w0), "sample_ms": 1e3 * (w2 - w1), "risk_cost_ms": 1e3 * (w3 - w2),
                   "select_ms": 1e3 * (w4 - w3)}
        info: dict[str, Any] = {f"cost_{name}": v for name, v in cost.row(j).items()}
        info.update(cost_envelope=float(envelope[j]), cost_entry=float(entry[j]), cost_selection=float(total[j]),
                    n_rule_breakers=float(breakers.sum()), n_fallback=float(n_fallback), validity=float(cls),
                    n_candidates=float(len(cand)),
                    n_feasible=float(feas.feasible.sum()), lat_accel_limit=float(lat_limit), horizon=float(cand.horizon[k]),
                    utility_literal=float(self.cfg.cost.utility is UtilityMode.LITERAL))
        if scene.desired_speed is not None:
            info["desired_speed"] = v_desired
        if self.cfg.keep_side > 0.0:
            info["lateral_reference"] = d_ref
        if percept is not None:  # road users in range, seen, remembered; phantoms
            info.update(percept.counts())
            timings.update(percept.timings_ms)
        d0 = scene.d
        dt = sc.dt
        d1, d2 = float(cand.d[k, 0]), float(cand.d[k, min(1, cand.d.shape[1] - 1)])
        self._lateral = ((d2 - d0) / (2 * dt), (d2 - 2 * d1 + d0) / dt**2)
        self._accel = float(cand.accel[k, 0])
        cmd = EgoCommand(float(cand.x[k, 0]), float(cand.y[k, 0]), float(cand.yaw[k, 0]), float(cand.speed[k, 0]))
        if self.cfg.replan_every > 1:
            self._plan = Plan(cand.take(np.array([k])), scene.time, frozenset(agents.ids), dict(info))
        if self._shares_plans:
            self.predictor.publish(scene.ego.ids[0], scene.time, cand.x[k], cand.y[k], cand.yaw[k])  # type: ignore[attr-defined]
        eligible = emergency_only(hard_pool(legal, on_road), evasive, overlap) if self.cfg.selection == "cost" else \
            (classes[cls] if cls < len(classes) else np.ones(len(fc), dtype=bool))
        trace = DecisionTrace(
            ego=scene.ego, agents=agents, prediction=pred, candidates=fc, cost=cost, selection=total,
            validity=validity_classes(classes), eligible=eligible, first_hit=first_hit,
            risk=(risk.ego_risk.sum(axis=1) + risk.other_risk.sum(axis=1)) if len(agents) else np.zeros(len(fc)),
            chosen=j, excluded=exclusion_codes(legal, on_road, overlap, self.cfg.selection, evasive),
            agent_risk=risk.ego_risk[j] + risk.other_risk[j] if len(agents) else np.zeros(0),
            view=None if percept is None else percept.trace(None if ph_risk is None else ph_risk[j]))
        return Decision(cmd, info=info, timings_ms=timings, trace=trace)

    def _predict(self, obs: Observation | None, horizon_steps: int, dt: float) -> tuple[Prediction, int]:
        """The prediction of ``obs``' road users with the priors, and how many fell back to constant velocity.
        A fleet's shared prediction does the priors once per step for every ego's road users together
        (``prepared``: the same rows, as the priors treat each road user on its own)."""
        if obs is None:
            raise ValueError("the ethical planner needs the neighbours' history in its scene (needs_history)")
        prepared = getattr(self.predictor, "prepared", None)
        if prepared is not None and self.perception is None:  # (a sensor's view has its own histories)
            got = prepared(obs, horizon_steps, dt, self._shares_plans, self._prior_key,
                           lambda pred, union: self._priors(pred, union, horizon_steps, dt))
            if got is not None:
                return got
        if self._shares_plans:  # the other egos' committed plans instead of their predictions
            pred = self.predictor.predict(obs, horizon_steps, dt, plans=True)  # type: ignore[call-arg]
        else:
            pred = self.predictor.predict(obs, horizon_steps, dt)
        pred, replaced = self._priors(pred, obs, horizon_steps, dt)
        return pred, int(replaced.sum())

    def _priors(self, pred: Prediction, obs: Observation, horizon_steps: int, dt: float) -> tuple[Prediction, np.ndarray]:
        """``pred`` with the priors, and (N,) bool: the road users that fell back to constant velocity."""
        # the priors treat every mode of a multi-modal prediction alike (they map over the modes)
        if self.cfg.lateral_prior > 0.0:  # first: a car braking to a stand also stops moving sideways
            travel, lateral = recent_motion(obs) if self.cfg.lateral_onset else (None, None)
            pred = apply_lateral_prior(pred, obs.current, horizon=self.cfg.lateral_prior, travel=travel,
                                       lateral_accel=lateral)
        if self.cfg.braking_prior > 0.0:
            pred = apply_braking_prior(pred, obs.current, self.cfg.braking_prior)
        # an agent with a non-finite mean, covariance or yaw in any mode is predicted at constant velocity
        replaced = non_finite(pred)
        if replaced.any():
            pred, _ = replace_non_finite(pred, obs, horizon_steps, dt)
        return pred, replaced

    def follow(self, scene: Scene) -> Decision | None:
        """The committed plan's next state (``replan_every`` > 1), or None where the planner must
        plan now (the reason in ``self.replan_reason``, a code of :data:`REPLAN`): no plan or no next
        state in it, the step is this ego's turn (every ``replan_every``-th step, offset by a hash
        of its id so a fleet's egos take turns), the ego is more than :data:`OFF_PLAN` m or m/s off
        where the plan put it, a predicted road user's box (with Origin's margins) enters the
        remaining plan stretched by its stopping distance (:func:`first_overlap`), or a road user
        the plan did not weigh is at risk from its remaining steps (some step's collision
        probability reaches p_min). The step's numbers are those of the plan it follows
        (``replanned`` 0)."""
        plan, n, dt = self._plan, self.cfg.replan_every, scene.dt
        if plan is None or self.perception is not None:  # with occlusion or phantoms: every step
            self.replan_reason = REPLAN["no_plan"]
            return None
        T = plan.cand.x.shape[1]
        j = int(round((scene.time - plan.time) / dt))  # the plan's state after this step
        tick = int(round(scene.time / dt))
        phase = zlib.crc32(scene.ego.ids[0].encode()) % n
        if j < 1 or j >= T:
            self.replan_reason = REPLAN["no_plan"]
            return None
        if (tick + phase) % n == 0:
            self.replan_reason = REPLAN["turn"]
            return None
        c = plan.cand
        ego = scene.ego
        if (math.hypot(float(ego.x[0]) - c.x[0, j - 1], float(ego.y[0]) - c.y[0, j - 1]) > OFF_PLAN
                or abs(float(ego.speed[0]) - c.speed[0, j - 1]) > OFF_PLAN):
            self.replan_reason = REPLAN["off_plan"]
            return None
        w0 = time.perf_counter()
        # the step's prediction over the planning horizon (a fleet's shared one), its first T - j steps
        full, n_fallback = self._predict(scene.history, T, dt)
        pred = full.map_modes(lambda m: Prediction(m.ids, m.dt, m.mean[:, :T - j], m.cov[:, :T - j], m.yaw[:, :T - j]))
        rest = c.take_steps(j)
        others = scene.others
        pc = self.cfg.probability
        ego_length, ego_width = float(ego.length[0]), float(ego.width[0])
        hit = first_overlap(rest, pred, others.length + pc.length_margin, others.width + pc.width_margin,
                            ego_length, ego_width, brake=scene.vehicle.max_decel)
        if hit[0] < T - j:
            self.replan_reason = REPLAN["envelope"]
            return None
        new = np.flatnonzero([k not in plan.ids for k in others.ids])
        if len(new):
            risk = assess_risk(rest, pred.take(new), others.take(new), ego_mass=float(ego.mass[0]),
                               ego_cls=int(ego.cls[0]), ego_length=ego_length, ego_width=ego_width, prob_cfg=pc,
                               steps=False, need_at_risk=True)
            if risk.at_risk is not None and risk.at_risk.any():
                self.replan_reason = REPLAN["new_at_risk"]
                return None
        d1, d2 = float(c.d[0, j]), float(c.d[0, min(j + 1, T - 1)])
        d0 = scene.d
        self._lateral = ((d2 - d0) / (2 * dt), (d2 - 2 * d1 + d0) / dt**2)
        self._accel = float(c.accel[0, j])
        info = dict(plan.info, replanned=0.0, n_fallback=float(n_fallback))
        return Decision(EgoCommand(float(c.x[0, j]), float(c.y[0, j]), float(c.yaw[0, j]), float(c.speed[0, j])),
                        info=info, timings_ms={"predict_ms": 1e3 * (time.perf_counter() - w0)})

    def pool(self, classes: list[np.ndarray], legal: np.ndarray, on_road: np.ndarray,
             overlap: np.ndarray, evasive: np.ndarray | None = None) -> np.ndarray:
        """(K,) bool: the candidates the selection rule weighs against each other, over which
        J_mean (candidate-mean reading) is taken. "cost": the first non-empty of legal and on the
        road / on the road / all (the evasive candidates only in an emergency, :func:`emergency_only`),
        narrowed to those outside every envelope if any are; "validity"/"validity_ttc": the best
        non-empty validity class."""
        if self.cfg.selection == "cost":
            base = emergency_only(hard_pool(legal, on_road), evasive, overlap)
            free = base & ~overlap
            return free if free.any() else base
        return next((m for m in classes if m.any()), np.ones_like(on_road))

    def choose(self, cost: Any, classes: list[np.ndarray], penalty: np.ndarray, legal: np.ndarray,
               on_road: np.ndarray, first_hit: np.ndarray, steps: int,
               travel: np.ndarray, evasive: np.ndarray | None = None) -> tuple[np.ndarray, int, int]:
        """(selection total (K,), chosen candidate, its validity class) under ``cfg.selection``.

        "cost": the lowest J_risk + penalty (the envelope and entry terms) within
        :func:`hard_pool` (the evasive candidates only in an emergency, :func:`emergency_only`);
        "validity"/"validity_ttc": the class rule (see :data:`SELECTIONS`).
        A non-finite total is never chosen (NaN counts as +inf; the pools are taken over the finite
        candidates); chosen candidate -1 when no total is finite.
        """
        mode = self.cfg.selection
        if mode == "cost":
            total = cost.total + penalty
            finite = np.isfinite(total)
            pool = emergency_only(hard_pool(legal & finite, on_road & finite) & finite, evasive, first_hit < steps)
            if not pool.any():
                return total, -1, len(classes)
            j = int(np.argmin(np.where(pool, total, np.inf)))
            return total, j, class_of(classes, j)
        ttc = mode == "validity_ttc"
        j, cls = select(classes, cost.total, first_hit if ttc else None, steps, travel if ttc else None)
        return cost.total, j, cls

    def _emergency(self, scene: Scene, timings: dict[str, float]) -> Decision:
        """Nothing is feasible: brake as hard as allowed along the reference path, keeping d (no plan kept)."""
        veh = scene.vehicle
        v = float(scene.ego.speed[0])
        v_next = max(0.0, v - veh.max_decel * scene.dt)
        s_next = scene.s + 0.5 * (v + v_next) * scene.dt
        x, y, yaw = scene.route.path.to_xy(np.array(s_next), np.array(scene.d))
        self._lateral, self._accel = (0.0, 0.0), (v_next - v) / scene.dt
        return Decision(EgoCommand(float(x), float(y), float(yaw), v_next),
                        info={"validity": float(len(VALIDITY) - 1)}, timings_ms=timings)
