"""Risk = collision probability x harm, for the ego and each predicted road user (METHOD.md section 1).

For candidate k, agent n, step t: ``risk = P[k, n, t] * harm[k, n, t]``, booked for both
parties; a candidate's risk against n is the maximum over t. Harm comes from
:func:`~sumo_ethics.ethics.harm.crash_outcome` with the ego's candidate state at t and the
agent's predicted state at t (mean position, predicted yaw, speed from finite differences of
the predicted mean, prefixed with the agent's current position).

Harm is evaluated only where P > 0 (inside the 5 m gate and above ``ProbabilityConfig.p_min``):
elsewhere it cannot contribute to any risk and the dense harm arrays hold 0. Everything per
step is kept sparse (typically a few % of K x N x T); the dense (K, N, T) arrays are built on
first access. Leaving the road is a risk to the ego with probability 1: ``boundary_harm`` is
the angle-free harm at the speed of leaving.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from sumo_ethics.ethics.harm import HarmCoefficients, Party, crash_outcome, leave_road_harm
from sumo_ethics.ethics.probability import ProbabilityConfig, SparseProbability, sparse_collision_probability
from sumo_ethics.types import VULNERABLE, AgentStates, Candidates, Prediction

__all__ = ["RiskTerms", "assess_risk", "boundary_harm"]


@dataclass(frozen=True)
class RiskTerms:
    """Risk of K candidates against N predicted agents over T steps.

    ego_risk, other_risk: (K, N) max_t p * harm for the ego and for agent n; ego_harm_max,
    other_harm_max: (K, N) max harm over the steps with p > 0 (0 if none), the harms Maximin looks
    at; vulnerable: (N,) bool, agent n is a VRU; boundary_harm: (K,) ego harm of leaving the road
    (0 if the candidate stays on it); rule_breaker: (N,) bool, agent n broke a traffic rule
    (responsibility principle; all False when unknown). sparse: the (k, n, t) entries with p > 0 and
    ego_harm_at, other_harm_at: (M,) the harms there. The dense (K, N, T) views ``p``,
    ``ego_harm``, ``other_harm`` (0 where p = 0) are built on first access.
    """

    ego_risk: np.ndarray
    other_risk: np.ndarray
    ego_harm_max: np.ndarray
    other_harm_max: np.ndarray
    vulnerable: np.ndarray
    boundary_harm: np.ndarray
    sparse: SparseProbability
    ego_harm_at: np.ndarray
    other_harm_at: np.ndarray
    rule_breaker: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = self.ego_risk.shape[1]
        rb = np.zeros(n, bool) if self.rule_breaker is None else np.asarray(self.rule_breaker, dtype=bool)
        if rb.shape != (n,):
            raise ValueError(f"rule_breaker must have shape ({n},), got {rb.shape}")
        object.__setattr__(self, "rule_breaker", rb)

    @property
    def shape(self) -> tuple[int, int, int]:
        """(K, N, T)."""
        return self.sparse.shape

    @cached_property
    def p(self) -> np.ndarray:
        """(K, N, T) collision probability."""
        return self.sparse.dense()

    @cached_property
    def ego_harm(self) -> np.ndarray:
        """(K, N, T) P(MAIS3+) of the ego if it collides with agent n at t; 0 where p = 0."""
        return self.sparse.dense(self.ego_harm_at)

    @cached_property
    def other_harm(self) -> np.ndarray:
        """(K, N, T) P(MAIS3+) of agent n if the ego collides with it at t; 0 where p = 0."""
        return self.sparse.dense(self.other_harm_at)

    @staticmethod
    def from_risks(
        ego_risk: np.ndarray,
        other_risk: np.ndarray,
        ego_harm_max: np.ndarray,
        other_harm_max: np.ndarray,
        boundary_harm: np.ndarray,
        vulnerable: np.ndarray | None = None,
        T: int = 0,
        rule_breaker: np.ndarray | None = None,
    ) -> "RiskTerms":
        """Terms given directly as (K, N) / (K,) arrays, without per-step entries (tests, replays)."""
        er = np.asarray(ego_risk, dtype=float)
        K, N = er.shape
        empty = np.zeros(0, dtype=np.intp)
        return RiskTerms(
            ego_risk=er, other_risk=np.asarray(other_risk, dtype=float),
            ego_harm_max=np.asarray(ego_harm_max, dtype=float), other_harm_max=np.asarray(other_harm_max, dtype=float),
            vulnerable=np.zeros(N, bool) if vulnerable is None else np.asarray(vulnerable, dtype=bool),
            boundary_harm=np.asarray(boundary_harm, dtype=float),
            sparse=SparseProbability(empty, empty, empty, np.zeros(0), (K, N, T)),
            ego_harm_at=np.zeros(0), other_harm_at=np.zeros(0), rule_breaker=rule_breaker,
        )


def boundary_harm(
    cand: Candidates, off_road: np.ndarray | None, coeffs: HarmCoefficients = HarmCoefficients()
) -> np.ndarray:
    """(K,) ego harm of leaving the road, as a risk with probability 1.

    off_road: None (nobody leaves), (K,) bool (candidate k leaves somewhere: harm at its highest
    speed over its valid steps, since the step is unknown) or (K, T) bool (harm at the speed of
    the first valid off-road step).
    """
    K, T = cand.x.shape
    if off_road is None:
        return np.zeros(K)
    off = np.asarray(off_road, dtype=bool)
    valid = cand.valid.astype(bool)
    if off.shape == (K,):
        speed = np.max(np.where(valid, cand.speed, 0.0), axis=1, initial=0.0)
        leaves = off
    elif off.shape == (K, T):
        off = off & valid
        leaves = off.any(axis=1)
        first = np.argmax(off, axis=1)
        speed = cand.speed[np.arange(K), first] if T else np.zeros(K)
    else:
        raise ValueError(f"off_road must have shape ({K},) or ({K}, {T}), got {off.shape}")
    return np.where(leaves, leave_road_harm(np.abs(speed), coeffs), 0.0)


def _agent_speed(pred: Prediction, agents: AgentStates) -> np.ndarray:
    """(N, Tp) predicted speed [m/s]: central differences of [current position, mean_0, ..., mean_Tp-1]."""
    if pred.mean.shape[1] == 0:
        return np.zeros(pred.mean.shape[:2])
    seq = np.concatenate([agents.xy[:, None, :], pred.mean], axis=1)
    vel = np.gradient(seq, pred.dt, axis=1)[:, 1:]
    return np.hypot(vel[..., 0], vel[..., 1])


def _group_max(values: np.ndarray, sp: SparseProbability, shape: tuple[int, int]) -> np.ndarray:
    """(K, N) max of ``values`` (M,) over each (k, n) group of the sorted entries; 0 for no entries."""
    out = np.zeros(shape)
    if values.size == 0:
        return out
    pair = sp.k * shape[1] + sp.n
    starts = np.flatnonzero(np.r_[True, pair[1:] != pair[:-1]])
    out.ravel()[pair[starts]] = np.maximum.reduceat(values, starts)
    return out


def assess_risk(
    cand: Candidates,
    pred: Prediction,
    agents: AgentStates,
    ego_mass: float,
    ego_cls: int,
    ego_length: float,
    ego_width: float,
    coeffs: HarmCoefficients = HarmCoefficients(),
    prob_cfg: ProbabilityConfig = ProbabilityConfig(),
    off_road: np.ndarray | None = None,
    rule_breaker: np.ndarray | None = None,
) -> RiskTerms:
    """Probability, harm and risk of K candidates against the N agents of ``pred``.

    agents: the same N agents now, in the order of ``pred.ids`` (their true size, mass and class
    are used); ego_mass [kg], ego_cls: RoadUserClass int, ego_length, ego_width: true size [m];
    off_road: see :func:`boundary_harm`; rule_breaker: (N,) bool, see :class:`RiskTerms`. N = 0 gives (K, 0, T) / (K, 0) arrays.
    """
    if tuple(agents.ids) != tuple(pred.ids):
        raise ValueError("agents and pred must list the same agents in the same order")
    K, T = cand.x.shape
    N = len(agents)
    sp = sparse_collision_probability(cand, pred, agents.length, agents.width, ego_length, ego_width, prob_cfg)
    ie = sp.k * T + sp.t  # flat (k, t); take() is much faster than 2-D fancy indexing
    tp = pred.mean.shape[1]
    ia = sp.n * tp + sp.t  # flat (n, t)
    speed_o = _agent_speed(pred, agents)
    mean = np.asarray(pred.mean, dtype=float).reshape(-1, 2)
    ego = Party(
        x=cand.x.ravel().take(ie), y=cand.y.ravel().take(ie), yaw=cand.yaw.ravel().take(ie),
        speed=np.abs(cand.speed.ravel().take(ie)), mass=np.asarray(float(ego_mass)), cls=np.asarray(int(ego_cls)),
    )
    other = Party(
        x=mean[:, 0].take(ia), y=mean[:, 1].take(ia), yaw=pred.yaw.ravel().take(ia), speed=speed_o.ravel().take(ia),
        mass=agents.mass.take(sp.n), cls=agents.cls.take(sp.n),
    )
    crash = crash_outcome(ego, other, coeffs)
    h_e, h_o = np.asarray(crash.harm_a, dtype=float), np.asarray(crash.harm_b, dtype=float)
    return RiskTerms(
        ego_risk=_group_max(sp.p * h_e, sp, (K, N)),
        other_risk=_group_max(sp.p * h_o, sp, (K, N)),
        ego_harm_max=_group_max(h_e, sp, (K, N)),
        other_harm_max=_group_max(h_o, sp, (K, N)),
        vulnerable=VULNERABLE[np.asarray(agents.cls, dtype=np.intp)],
        boundary_harm=boundary_harm(cand, off_road, coeffs),
        sparse=sp,
        ego_harm_at=h_e,
        other_harm_at=h_o,
        rule_breaker=rule_breaker,
    )
