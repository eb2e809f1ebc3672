"""Risk = collision probability x harm, for the ego and each predicted road user (METHOD.md section 1).

For candidate k, agent n, step t: ``risk = P[k, n, t] * harm[k, n, t]``, booked for both
parties; a candidate's risk against n is the maximum over t. Harm comes from
:func:`~sumo_ethics.ethics.harm.crash_outcome` with the ego's candidate state at t and the
agent's predicted state at t (mean position, predicted yaw, speed from finite differences of
the predicted mean, prefixed with the agent's current position).

Harm counts only where a step's share of the collision probability reaches the one threshold
``ProbabilityConfig.p_min`` (1e-3 for "shapes": the gate per mode weight, the risk terms, Maximin and
the at-risk set; 1e-9 for Origin's score): elsewhere it cannot contribute to any risk and the dense
harm arrays hold 0. Everything per step is kept sparse (typically a few % of K x N x T); the dense
(K, N, T) arrays are built on first access. The planner's terms come from the bounded search
instead (``steps=False``, :mod:`sumo_ethics.ethics.search`), to ``ProbabilityConfig.tolerance``,
each with its slack. Leaving the road is a risk to the ego with probability 1: ``boundary_harm`` is
the angle-free harm at the speed of leaving.

A multi-modal prediction (several futures per agent, with weights) is integrated mode by mode:
each mode is assessed as above and its max-over-t risk weighted by the mode's probability
(an expectation over the modes); see :func:`assess_risk`.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from sumo_ethics.ethics.harm import HarmCoefficients, Party, crash_outcome, leave_road_harm
from sumo_ethics.ethics.probability import (
    ProbabilityConfig, SparseProbability, bounded_shapes_terms, maximin_ramp, sparse_collision_probability)
from sumo_ethics.types import VULNERABLE, AgentStates, Candidates, Prediction

__all__ = ["RiskTerms", "assess_risk", "boundary_harm"]


@dataclass(frozen=True)
class RiskTerms:
    """Risk of K candidates against N predicted agents over T steps.

    ego_risk, other_risk: (K, N) max_t p * harm for the ego and for agent n (with several
    modes: sum_m w[n, m] max_t p_m * harm_m); ego_harm_max, other_harm_max: (K, N) max harm over
    the steps (and modes) with p > 0 (0 if none), the harms Maximin looks at; vulnerable: (N,)
    bool, agent n is a VRU; boundary_harm: (K,) ego harm of leaving the road (0 if the
    candidate stays on it); rule_breaker: (N,) bool, agent n broke a traffic rule
    (responsibility principle; all False when unknown). sparse: the (k, n, t) entries with p > 0,
    one per (k, n, t), sorted (with modes: p = sum_m w[n, m] p_m) and ego_harm_at, other_harm_at:
    (M,) the harms there (with modes: the expected harm given a collision there). The dense
    (K, N, T) views ``p``, ``ego_harm``, ``other_harm`` (0 where p = 0) are built on first access.
    at_risk: (K, N) bool, some step of (k, n) counts (an entry; the "at_risk" normalisation).
    complete: False where the terms come from the bounded search (``assess_risk(..., steps=False)``):
    the same (K, N) terms and at_risk (:mod:`sumo_ethics.ethics.search`), ``sparse`` empty, the (K, N, T) views raise.
    slack: None (exact) or (4, K, N): how far the exact ego_risk, other_risk, ego_harm_max and
    other_harm_max may lie above these, each at most ``ProbabilityConfig.tolerance`` (0 where the
    search left nothing unexamined); :func:`sumo_ethics.ethics.cost.tolerance_bound` turns it into
    a bound on each candidate's cost.
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
    at_risk: np.ndarray | None = None
    complete: bool = True
    slack: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = self.ego_risk.shape[1]
        rb = np.zeros(n, bool) if self.rule_breaker is None else np.asarray(self.rule_breaker, dtype=bool)
        if rb.shape != (n,):
            raise ValueError(f"rule_breaker must have shape ({n},), got {rb.shape}")
        object.__setattr__(self, "rule_breaker", rb)
        if self.at_risk is None:  # from the entries: some step of (k, n) counts
            at = np.zeros(self.ego_risk.shape, dtype=bool)
            at[self.sparse.k, self.sparse.n] = True
            object.__setattr__(self, "at_risk", at)
        elif np.shape(self.at_risk) != self.ego_risk.shape:
            raise ValueError(f"at_risk must have shape {self.ego_risk.shape}, got {np.shape(self.at_risk)}")

    def _entries(self) -> SparseProbability:
        if not self.complete:
            raise ValueError("these risk terms keep no per-step entries (assess_risk(..., steps=False)): "
                             "assess with steps=True for the (K, N, T) views")
        return self.sparse

    @property
    def shape(self) -> tuple[int, int, int]:
        """(K, N, T)."""
        return self.sparse.shape

    @cached_property
    def p(self) -> np.ndarray:
        """(K, N, T) collision probability."""
        return self._entries().dense()

    @cached_property
    def ego_harm(self) -> np.ndarray:
        """(K, N, T) P(MAIS3+) of the ego if it collides with agent n at t; 0 where p = 0."""
        return self._entries().dense(self.ego_harm_at)

    @cached_property
    def other_harm(self) -> np.ndarray:
        """(K, N, T) P(MAIS3+) of agent n if the ego collides with it at t; 0 where p = 0."""
        return self._entries().dense(self.other_harm_at)

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
        return RiskTerms(
            ego_risk=er, other_risk=np.asarray(other_risk, dtype=float),
            ego_harm_max=np.asarray(ego_harm_max, dtype=float), other_harm_max=np.asarray(other_harm_max, dtype=float),
            vulnerable=np.zeros(N, bool) if vulnerable is None else np.asarray(vulnerable, dtype=bool),
            boundary_harm=np.asarray(boundary_harm, dtype=float),
            sparse=SparseProbability.none((K, N, T)),
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


def _entries(cand: Candidates, pred: Prediction, agents: AgentStates, ego_mass: float, ego_cls: int,
             ego_length: float, ego_width: float, coeffs: HarmCoefficients, prob_cfg: ProbabilityConfig
             ) -> tuple[SparseProbability, np.ndarray, np.ndarray]:
    """The paper's per-step terms of one mode, every gated step integrated: the sparse P entries and
    the ego's and the agent's harm there, (M,) each. ``pred`` is read as single-mode (mean/cov/yaw);
    its rows and those of ``agents`` correspond one to one (ids are not checked: rows may repeat agents)."""
    T = cand.x.shape[1]
    speed_o = _agent_speed(pred, agents)
    sp = sparse_collision_probability(cand, pred, agents.length, agents.width, ego_length, ego_width, prob_cfg)
    ie = sp.k * T + sp.t  # flat (k, t); take() is much faster than 2-D fancy indexing
    tp = pred.mean.shape[1]
    ia = sp.n * tp + sp.t  # flat (n, t)
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
    return sp, np.asarray(crash.harm_a, dtype=float), np.asarray(crash.harm_b, dtype=float)


def _bounded(cand: Candidates, pred: Prediction, agents: AgentStates, ego_mass: float, ego_cls: int,
             ego_length: float, ego_width: float, coeffs: HarmCoefficients, prob_cfg: ProbabilityConfig,
             need_at_risk: bool) -> tuple[tuple[np.ndarray, ...], np.ndarray, np.ndarray]:
    """((ego_risk, other_risk, ego_harm_max, other_harm_max) (K, N), at_risk (K, N), slack (4, K, N))
    by the bounded search (:func:`~sumo_ethics.ethics.probability.bounded_shapes_terms`), mode by
    mode: the risks and their slack summed over the modes (each weighted by its weight), the harm
    maxima, their slack (the largest a maximum over the modes can gain) and at_risk over them. A
    mode is searched only for the agents whose weight reaches p_min (elsewhere it counts nowhere)."""
    K = cand.x.shape[0]
    N = len(agents)
    out = np.zeros((4, K, N))
    slack = np.zeros((4, K, N))
    upper = np.zeros((2, K, N))  # the harm maxima's upper ends over the modes
    at_risk = np.zeros((K, N), dtype=bool)
    ego_speed = np.abs(cand.speed)
    vul = VULNERABLE[np.asarray(agents.cls, dtype=np.intp)]
    mass = np.asarray(agents.mass, dtype=float)
    for mode, w in pred.by_mode():
        rows = np.flatnonzero(w >= prob_cfg.threshold)
        if rows.size == 0:
            continue
        if rows.size < N:  # searched for the agents it can count for only
            mode, sub, w = mode.take(rows), agents.take(rows), w.take(rows)
        else:
            sub = agents
        harm_inputs = (ego_speed, float(ego_mass), bool(VULNERABLE[int(ego_cls)]), _agent_speed(mode, sub),
                       mass.take(rows), vul.take(rows), coeffs.as_array())
        terms, gap, mode_at, _ = bounded_shapes_terms(cand, mode, sub.length, sub.width, ego_length, ego_width,
                                                      prob_cfg, w, harm_inputs, need_at_risk)
        out[:2, :, rows] += terms[:2]
        slack[:2, :, rows] += gap[:2]
        out[2:, :, rows] = np.maximum(out[2:, :, rows], terms[2:])
        upper[:, :, rows] = np.maximum(upper[:, :, rows], terms[2:] + gap[2:])
        at_risk[:, rows] |= mode_at
    slack[2:] = upper - out[2:]
    return (out[0], out[1], out[2], out[3]), at_risk, slack


def _integrate_modes(cand: Candidates, pred: Prediction, agents: AgentStates,
                     args: tuple[float, int, float, float, HarmCoefficients, ProbabilityConfig], p_min: float
                     ) -> tuple[SparseProbability, np.ndarray, np.ndarray, tuple[np.ndarray, ...]]:
    """Every mode of ``pred`` (weight not None) through :func:`_entries`, combined by the weights.

    Returns the combined sparse entries (unique per (k, n, t), p = sum_m w[n, m] p_m), the
    p-weighted harms there, and (ego_risk, other_risk, ego_harm_max, other_harm_max) (K, N);
    see :func:`assess_risk`. An entry of mode m counts only where w[n, m] p_m >= ``p_min``.
    One call per mode, not the modes stacked as extra agent rows: each mode's terms are then
    exactly those of a single-mode prediction of it (at equal cost: the work grows with the gated entries).
    """
    K, T = cand.x.shape
    N = len(agents)
    zeros = np.zeros((K, N))
    ego_risk, other_risk, ego_hmax, other_hmax = zeros, zeros, zeros, zeros
    parts = []
    for mode, w in pred.by_mode():
        rows = np.flatnonzero(w >= p_min)  # w p_m < p_min where w is: such an agent's mode counts nowhere
        if rows.size == 0:
            continue
        if rows.size == N:
            sp, h_e, h_o = _entries(cand, mode, agents, *args)
        else:  # assessed for the agents it can count for only (e.g. a one-mode pedestrian's weight-0 modes)
            sp, h_e, h_o = _entries(cand, mode.take(rows), agents.take(rows), *args)
            sp = SparseProbability(sp.k, rows.take(sp.n), sp.t, sp.p, (K, N, T))  # rows rise: still sorted
        wp = w.take(sp.n) * sp.p  # (E,) the mode's share of the marginal probability
        keep = np.flatnonzero(wp >= p_min)  # a negligible mode at (k, n, t) counts nowhere (see assess_risk)
        k, n, t, p, wp, h_e, h_o = (a.take(keep) for a in (sp.k, sp.n, sp.t, sp.p, wp, h_e, h_o))
        kept = SparseProbability(k, n, t, p, (K, N, T))  # still sorted by (k, n, t)
        ego_risk = ego_risk + w * _group_max(p * h_e, kept, (K, N))
        other_risk = other_risk + w * _group_max(p * h_o, kept, (K, N))
        ramp = maximin_ramp(wp, p_min, args[5].p_full)
        ego_hmax = np.maximum(ego_hmax, _group_max(ramp * h_e, kept, (K, N)))
        other_hmax = np.maximum(other_hmax, _group_max(ramp * h_o, kept, (K, N)))
        parts.append(((k * N + n) * T + t, wp, h_e, h_o))
    terms = (ego_risk, other_risk, ego_hmax, other_hmax)

    # one entry per (k, n, t): the modes' shares summed (the stable sort keeps the mode order)
    if parts:
        key, wp, h_e, h_o = (np.concatenate(a) for a in zip(*parts))
        order = np.argsort(key, kind="stable")
        key, wp, h_e, h_o = key.take(order), wp.take(order), h_e.take(order), h_o.take(order)
    if not parts or key.size == 0:  # (no agent at all skips every mode)
        return SparseProbability.none((K, N, T)), np.zeros(0), np.zeros(0), terms
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    single = np.diff(np.r_[starts, key.size]) == 1
    p_c = np.add.reduceat(wp, starts)

    def harm_at(h: np.ndarray) -> np.ndarray:  # E[harm | collision at (k, n, t)]; one mode: its harm as is
        return np.where(single, h.take(starts), np.add.reduceat(wp * h, starts) / p_c)

    first = key.take(starts)
    out = SparseProbability(first // (N * T), (first // T) % N, first % T, p_c, (K, N, T))
    return out, harm_at(h_e), harm_at(h_o), terms


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
    steps: bool = True,
    need_at_risk: bool = False,
) -> RiskTerms:
    """Probability, harm and risk of K candidates against the N agents of ``pred``.

    agents: the same N agents now, in the order of ``pred.ids`` (their true size, mass and class
    are used); ego_mass [kg], ego_cls: RoadUserClass int, ego_length, ego_width: true size [m];
    off_road: see :func:`boundary_harm`; rule_breaker: (N,) bool, see :class:`RiskTerms`. N = 0 gives (K, 0, T) / (K, 0) arrays.

    Modes: a single-mode ``pred`` (``weight`` None) gives the paper's terms. With modes m of
    weights w[n, m] (:meth:`Prediction.by_mode`), each mode is one hypothesis of agent n's future
    and is assessed exactly as a single-mode prediction (p_m, harms at its own mean, yaw and
    speed), then integrated by its weight: ego_risk[k, n] = sum_m w[n, m] max_t p_m harm_ego_m
    (other_risk likewise), p = sum_m w[n, m] p_m (marginal collision probability) and
    ego_harm_max / other_harm_max = the largest harm over every mode's entries. A mode's entry
    counts only where its share w[n, m] p_m reaches ``prob_cfg.threshold`` (as a single mode's does
    where p_m does), so a negligible-weight mode can neither add risk nor a Maximin harm, and every
    combined entry has p >= p_min. The per-step entries stay unique per (k, n, t): ``ego_harm_at``
    / ``other_harm_at`` hold the expected harm given a collision there, sum_m w p_m h_m / p (one
    mode's harm as is), so dense p x harm is the expected per-step risk (its max over t can fall
    below ego_risk, which takes the max within each mode).

    steps=False (the planner's choice; "shapes" probability only, else ignored): the (K, N) terms
    and at_risk by the bounded search of :mod:`sumo_ethics.ethics.search`, the same numbers as
    with steps=True at a fraction of the integrals, without the per-step entries (``complete``
    False).
    """
    if tuple(agents.ids) != tuple(pred.ids):
        raise ValueError("agents and pred must list the same agents in the same order")
    K = cand.x.shape[0]
    N = len(agents)
    args = (ego_mass, ego_cls, ego_length, ego_width, coeffs, prob_cfg)
    bounded = not steps and prob_cfg.method == "shapes"
    at_risk = slack = None
    if bounded:
        (ego_risk, other_risk, ego_harm_max, other_harm_max), at_risk, slack = _bounded(cand, pred, agents, *args,
                                                                                         need_at_risk)
        sp, h_e, h_o = SparseProbability.none((K, N, cand.x.shape[1])), np.zeros(0), np.zeros(0)
    elif pred.weight is None:
        sp, h_e, h_o = _entries(cand, pred, agents, *args)
        ego_risk, other_risk = _group_max(sp.p * h_e, sp, (K, N)), _group_max(sp.p * h_o, sp, (K, N))
        ramp = maximin_ramp(sp.p, prob_cfg.threshold, prob_cfg.p_full)
        ego_harm_max, other_harm_max = _group_max(ramp * h_e, sp, (K, N)), _group_max(ramp * h_o, sp, (K, N))
    else:
        sp, h_e, h_o, (ego_risk, other_risk, ego_harm_max, other_harm_max) = _integrate_modes(
            cand, pred, agents, args, prob_cfg.threshold)
    return RiskTerms(
        ego_risk=ego_risk,
        other_risk=other_risk,
        ego_harm_max=ego_harm_max,
        other_harm_max=other_harm_max,
        vulnerable=VULNERABLE[np.asarray(agents.cls, dtype=np.intp)],
        boundary_harm=boundary_harm(cand, off_road, coeffs),
        sparse=sp,
        ego_harm_at=h_e,
        other_harm_at=h_o,
        rule_breaker=rule_breaker,
        at_risk=at_risk,
        complete=not bounded,
        slack=slack,
    )
