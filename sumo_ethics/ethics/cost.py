"""The cost of each candidate: Origin's J_origin, the paper's J_utility and J_risk (METHOD.md section 2).

Definitions, per candidate k, with N predicted agents, ego_risk / other_risk (K, N) and
boundary harm b (K,) from :class:`~sumo_ethics.ethics.risk.RiskTerms`:

- the divisor N of Bayes, Equality and Responsibility (``n_norm``, recorded per candidate) is
  chosen by ``CostConfig.normalise``: "in_range" (Origin's, the default) every predicted road
  user, i.e. everyone within the sensing radius; "at_risk" the parties the candidate has a
  non-zero collision probability with (``ego_risk + other_risk > 0`` or
  ``RiskTerms.at_risk``: a step that counts), at least 1. Under "in_range" the same risk against one party costs
  20x less with 20 road users in range than with one (parked cars far away dilute the ethics
  against progress); under "at_risk" it costs the same, and with nobody at risk B = b / 2.
  Ego and Maximin are sums and maxima and divide by nothing under either;
- Bayes ``B = (sum_n ego_risk + sum_n other_risk + b) / (2N)``;
- Equality ``E = sum_n |ego_risk - other_risk| / N``;
- Maximin ``M = h_max ** maximin_exponent`` with h_max the largest harm among the parties the
  candidate can collide with: max over n of the ego's and agent n's harm, each weighed by Maximin's
  ramp of that step's share of the collision probability (0 up to ``ProbabilityConfig.p_min``,
  rising to 1 at ``maximin_full`` x p_min: ``ego_harm_max``, ``other_harm_max``), and b. A party
  whose share of P stays below p_min contributes nothing, and its price grows continuously with
  P. (Origin keeps harms only where the risk is below 1e-9, the opposite of its comment; not copied.)
- Ego ``Ego = sum_n ego_risk + b``;
- Responsibility ``R = sum_n (1 - breaks_rules_n) other_risk_n / N``: the risk the candidate puts on
  road users who keep the rules (``RiskTerms.rule_breaker``; see :mod:`sumo_ethics.sim.rules`), so
  risk put on a rule-abiding party costs more than the same risk put on one who broke a rule
  (Origin's fifth principle, with the simulation's rule knowledge instead of reachable sets);
- ``J_origin = w_risk (w_B B + w_E E + w_M M + w_ego Ego + w_R R) + w_v |v_desired - mean v| + w_d mean |d|``,
  means over the candidate's valid steps;
- ``J(s) = sum_n ego_risk + sum_n other_risk + b``: leaving the road is an ego risk with
  probability 1, as in Bayes and Ego;
- ``J_mean``: UtilityMode.CANDIDATE_MEAN (default) the mean of J over the feasible candidates of
  this step (all candidates if ``feasible`` is None or selects none), candidates with a
  non-finite J left out (0 if none is finite); UtilityMode.LITERAL
  ``J / N_r`` with N_r = N + 1 parties (the ego and the N agents);
- ``J_utility = 0 if J <= J_mean else J`` (J counts as <= J_mean within a relative 1e-9, so
  candidates tied at the mean are not penalised by rounding);
- ``J_utility`` is charged in cost units: ``utility_scale`` (default 1e4) per unit of J, so that
  omega_u in [0, 1] spans "off" to "dominant" (w_u = 1 prices an above-average risk at 10,000
  per unit, 2.4x what J_origin's Bayes term charges for the same risk against one neighbour,
  250 x 33.3 / 2 = 4,163, and more with more neighbours since Bayes divides by 2N);
- ``J_risk = omega_o J_origin + omega_u J_utility``, the total that selection minimises.

Ex-ante risk of each candidate per class (recorded for the chosen one): ``ego_risk_sum/max``,
``other_risk_sum/max`` (third parties) and ``vru_risk_sum/max`` (the VRUs among them), sums and
maxima over the parties.

With N = 0: B = b ("in_range"; b / 2 under "at_risk", N = 1), E = 0, R = 0, M = b ** exponent, Ego = J = b.

Each of these terms is an entry of the list in :mod:`sumo_ethics.ethics.terms` (its function, group,
weight key, unit and label), and :func:`score` sums them from that list: a term registered there is
scored, weighted, recorded and drawn like these.
"""

from __future__ import annotations

import enum
import functools
import math
import operator
from dataclasses import dataclass, field, fields
from typing import Any, Mapping

import numpy as np

from sumo_ethics.ethics.probability import EthicsConfigError, _check_number
from sumo_ethics.ethics.risk import RiskTerms
from sumo_ethics.ethics.terms import BUILTIN, TermInputs, cost_terms, weight_of
from sumo_ethics.types import Candidates, CostBreakdown

__all__ = ["PrincipleWeights", "PRESETS", "PRICES", "REFERENCE_PRICE", "principle_scale", "UtilityMode", "NORMALISE", "CostConfig", "score", "TERMS", "tolerance_bound"]

_TIE_RTOL = 1e-9


@dataclass(frozen=True)
class PrincipleWeights:
    """Weights of J_origin; defaults are Origin's "ethical" set.

    bayes, equality, maximin, ego, responsibility: weights of the five principles [-]; risk: factor on their
    weighted sum [-]; velocity: per m/s of |v_desired - mean v| [1/(m/s)]; lateral: per m of
    mean |d| [1/m].
    """

    bayes: float = 33.3
    equality: float = 33.3
    maximin: float = 33.3
    ego: float = 0.0
    responsibility: float = 0.0
    risk: float = 250.0
    velocity: float = 1.0
    lateral: float = 10.0

    def __post_init__(self) -> None:
        for f in fields(self):
            _check_number("PrincipleWeights", f.name, getattr(self, f.name))

    @staticmethod
    def preset(name: str) -> "PrincipleWeights":
        """One of :data:`PRESETS` by name; ValueError listing the known names otherwise."""
        try:
            return PRESETS[name]
        except (KeyError, TypeError):
            raise EthicsConfigError(
                f"unknown principle-weight preset {name!r}; known presets: {', '.join(sorted(PRESETS))}"
            ) from None


#: Named weight sets. "ethical": Origin's (responsibility 0, as in Origin's "ethical" file).
#: "standard": Origin's with every principle 0, so risk is ignored (``risk`` keeps 250 but
#: multiplies zero). "ego", "bayes", "maximin": one principle alone at 100, about the sum of the
#: ethical principle weights (99.9). Their scales do NOT match: Ego and Maximin divide by nothing,
#: Bayes (and Equality, Responsibility) divide by N, so under normalise="in_range" one risk r
#: against one party costs 25,000 r under "ego" but 25,000 r / (2N) under "bayes" (12,500 r with
#: one road user in range, 625 r with twenty); normalise="at_risk" makes N the parties at risk,
#: so that ratio no longer depends on the traffic around. "responsible": the ethical weights
#: plus responsibility 33.3.
PRESETS: dict[str, PrincipleWeights] = {
    "ethical": PrincipleWeights(),
    "standard": PrincipleWeights(bayes=0.0, equality=0.0, maximin=0.0, ego=0.0),
    "ego": PrincipleWeights(bayes=0.0, equality=0.0, maximin=0.0, ego=100.0),
    "bayes": PrincipleWeights(bayes=100.0, equality=0.0, maximin=0.0, ego=0.0),
    "maximin": PrincipleWeights(bayes=0.0, equality=0.0, maximin=100.0, ego=0.0),
    "responsible": PrincipleWeights(responsibility=33.3),
}


#: the principles' price level (CostConfig.price): "preset", the weights as given (Origin's); "equal",
#: every principle weight scaled by CostConfig.principle_scale, so that one collision that would harm
#: the ego and one other party alike (risk r each, the other keeping the rules, N = 1) costs
#: w_risk x REFERENCE_PRICE x r in J_origin under every preset that prices it linearly
PRICES = ("preset", "equal")
#: what that collision costs per unit of r (before w_risk) under "equal": the "ego" preset's own price
REFERENCE_PRICE = 100.0


class UtilityMode(enum.Enum):
    """How J_mean of J_utility is read; record it with every run."""

    CANDIDATE_MEAN = "candidate_mean"  # mean of J over this step's feasible candidates
    LITERAL = "literal"  # J / N_r, N_r = number of parties (ego + N agents)


#: default w_u (the paper's sense: a weight in [0, 1]); J_utility is charged UTILITY_SCALE per
#: unit of risk, so w_u = 0.5 charges an above-average risk 5,000 per unit (see the module doc).
DEFAULT_OMEGA_U = 0.5
#: cost units per unit of J(s) in J_utility (CostConfig.utility_scale)
UTILITY_SCALE = 1e4
#: divisors of Bayes, Equality and Responsibility (CostConfig.normalise): every predicted road
#: user in range (Origin's), or the parties with a non-zero collision probability (at least 1)
NORMALISE = ("in_range", "at_risk")


@dataclass(frozen=True)
class CostConfig:
    """Weights of J_risk = omega_o J_origin + omega_u J_utility.

    weights: J_origin's weights (a PrincipleWeights or a preset name); omega_o, omega_u [-];
    utility: UtilityMode (or its value string); desired_speed: default v_desired [m/s] for
    :func:`score`; maximin_exponent: M = h_max ** exponent [-]; utility_scale: cost units per
    unit of risk in J_utility [-]; normalise: the N that Bayes, Equality and Responsibility divide
    by, one of :data:`NORMALISE` (see the module doc); term_weights: the weights of registered cost
    terms by their weight key (:mod:`sumo_ethics.ethics.terms`; a term not named here weighs its
    ``default_weight``); price: one of :data:`PRICES`, the principles' price level
    (:attr:`principle_scale`).
    """

    weights: PrincipleWeights = PrincipleWeights()
    omega_o: float = 1.0
    omega_u: float = DEFAULT_OMEGA_U
    utility: UtilityMode = UtilityMode.CANDIDATE_MEAN
    desired_speed: float | None = None
    maximin_exponent: float = 10.0
    utility_scale: float = UTILITY_SCALE
    normalise: str = "in_range"
    term_weights: dict[str, float] = field(default_factory=dict)
    price: str = "preset"

    def __post_init__(self) -> None:
        if self.price not in PRICES:
            raise EthicsConfigError(f"price must be one of {', '.join(PRICES)}, got {self.price!r}")
        if not isinstance(self.term_weights, dict):
            object.__setattr__(self, "term_weights", dict(self.term_weights))
        for key, value in self.term_weights.items():
            _check_number("CostConfig.term_weights", str(key), value)
        if self.normalise not in NORMALISE:
            raise EthicsConfigError(f"normalise must be one of {', '.join(NORMALISE)}, got {self.normalise!r}")
        if isinstance(self.weights, str):
            object.__setattr__(self, "weights", PrincipleWeights.preset(self.weights))
        if not isinstance(self.weights, PrincipleWeights):
            raise EthicsConfigError(f"CostConfig.weights must be PrincipleWeights or a preset name, got {self.weights!r}")
        if not isinstance(self.utility, UtilityMode):
            try:
                object.__setattr__(self, "utility", UtilityMode(self.utility))
            except ValueError:
                known = ", ".join(m.value for m in UtilityMode)
                raise EthicsConfigError(f"CostConfig.utility must be one of {known}, got {self.utility!r}") from None
        _check_number("CostConfig", "omega_o", self.omega_o)
        _check_number("CostConfig", "omega_u", self.omega_u)
        _check_number("CostConfig", "maximin_exponent", self.maximin_exponent, positive=True)
        _check_number("CostConfig", "utility_scale", self.utility_scale)
        if self.desired_speed is not None:
            _check_number("CostConfig", "desired_speed", self.desired_speed)

    @property
    def principle_scale(self) -> float:
        """The factor on every principle weight: 1 under price "preset"; under "equal",
        :data:`REFERENCE_PRICE` / (bayes + ego + responsibility): per unit of r the reference collision
        of :data:`PRICES` costs bayes x 2r / 2 (Bayes: the risks summed over 2N) + equality x 0 + ego x r
        + responsibility x r, and Maximin's h^exponent is no price per unit of r (a "maximin"-only
        preset, whose sum is 0, keeps 1). "ethical" (33.3 each): 3.003; "responsible": 1.5015."""
        return principle_scale(self.weights, self.price)


def principle_scale(weights: PrincipleWeights, price: str) -> float:
    """:attr:`CostConfig.principle_scale` of ``weights`` under ``price`` (one of :data:`PRICES`)."""
    if price == "preset":
        return 1.0
    linear = weights.bayes + weights.ego + weights.responsibility
    return REFERENCE_PRICE / linear if linear > 0.0 else 1.0


#: Names of the (K,) terms in every CostBreakdown from :func:`score` without extra inputs (no
#: phantoms, no registered terms), in order: the built-in terms of :mod:`sumo_ethics.ethics.terms`.
TERMS = tuple(t.name for t in BUILTIN if not t.optional)


def score(
    cand: Candidates,
    risk: RiskTerms,
    cfg: CostConfig = CostConfig(),
    desired_speed: float | None = None,
    feasible: np.ndarray | None = None,
    extra: Mapping[str, Any] | None = None,
    weights: Mapping[str, float] | None = None,
) -> CostBreakdown:
    """Every registered cost term of K candidates (:func:`sumo_ethics.ethics.terms.cost_terms`),
    each (K,), and total = J_risk plus the weighted "total" terms (the phantoms').

    desired_speed: v_desired [m/s] (default ``cfg.desired_speed``); feasible: (K,) bool, the
    candidates J_mean averages over in CANDIDATE_MEAN mode (None: all); extra: further inputs of
    the terms (``TermInputs.extra``; the planner's ``phantom_risk``); weights: weights of terms
    that neither ``cfg.weights`` nor ``cfg.term_weights`` give (:func:`~sumo_ethics.ethics.terms.weight_of`).
    """
    v_des = cfg.desired_speed if desired_speed is None else desired_speed
    if v_des is None or not math.isfinite(v_des) or v_des < 0:
        raise ValueError(f"score needs a finite non-negative desired_speed (argument or CostConfig), got {v_des!r}")
    K = cand.x.shape[0]
    er, orr = risk.ego_risk, risk.other_risk
    if er.shape[0] != K or risk.boundary_harm.shape != (K,):
        raise ValueError(f"risk terms are for {er.shape[0]} candidates, cand has {K}")
    N = er.shape[1]
    if cfg.normalise == "at_risk":
        at_risk = ((er + orr) > 0.0) | risk.at_risk
        n_norm = np.maximum(at_risk.sum(axis=1), 1).astype(float)
    else:
        n_norm = np.full(K, float(N))
    inputs = TermInputs(cand, risk, cfg, float(v_des), feasible, n_norm, extra or {})
    terms = cost_terms()
    values: dict[str, np.ndarray] = {}
    for t in terms:  # every term that is not a sum of the others; None: not this step
        if t.compute is not None:
            v = t.compute(inputs)
            if v is not None:
                values[t.name] = v

    # J_origin = w_risk (sum of the weighted principles) + the weighted "origin" terms, in order
    principles = [weight_of(t, cfg, weights) * values[t.name] for t in terms if t.group == "principle"]
    j_origin = (cfg.weights.risk * cfg.principle_scale * functools.reduce(operator.add, principles) if principles
                else np.zeros(K))
    for t in terms:
        if t.group == "origin" and t.name in values:
            j_origin = j_origin + weight_of(t, cfg, weights) * values[t.name]

    j_total = inputs.j_total
    if cfg.utility is UtilityMode.LITERAL:
        j_mean = j_total / (N + 1)
    else:
        pool = np.ones(K, bool) if feasible is None else np.asarray(feasible, dtype=bool)
        if pool.shape != (K,):
            raise ValueError(f"feasible must have shape ({K},), got {pool.shape}")
        pool = pool & np.isfinite(j_total)  # one non-finite J must not switch J_utility off for all
        if not pool.any():
            pool = np.isfinite(j_total)
        j_mean = np.full(K, j_total[pool].mean() if pool.any() else 0.0)
    above = j_total > j_mean + _TIE_RTOL * np.abs(j_mean)
    j_utility = np.where(above, cfg.utility_scale * j_total, 0.0)
    j_risk = cfg.omega_o * j_origin + cfg.omega_u * j_utility
    values.update(j_origin=j_origin, j_mean=j_mean, j_utility=j_utility, j_risk=j_risk)

    total = j_risk
    out: dict[str, np.ndarray] = {}
    for t in terms:  # the breakdown in the registry's order; a "total" term's weighted value after it
        if t.name not in values:
            continue
        out[t.name] = values[t.name]
        if t.group == "total" and t.weighted:
            weighted = weight_of(t, cfg, weights) * values[t.name]
            out[t.weighted] = weighted
            total = total + weighted
    return CostBreakdown(terms=out, total=total)


def tolerance_bound(cost: CostBreakdown, risk: RiskTerms, cfg: CostConfig = CostConfig(),
                    feasible: np.ndarray | None = None) -> np.ndarray:
    """(K,) how far each candidate's J_risk (``cost.total``, scored from ``risk``) can lie from
    the J_risk of the exact risk terms, given ``risk.slack`` (the bounded search's tolerance mode;
    0 everywhere without slack). With s_e, s_o the (K, N) slack of ego_risk and other_risk, N the
    divisor (``n_norm``), b the breakers, H the Maximin harm and s_H its slack:

    - Bayes <= sum_n (s_e + s_o) / 2N, Equality <= sum_n max(s_e, s_o) / N (both terms move the
      same way), Responsibility <= sum_n (1 - b) s_o / N, Ego <= sum_n s_e, Maximin <= (H + s_H)^e - H^e;
    - J_utility: J can be sum_n (s_e + s_o) = dJ higher, J_mean at most max dJ over ``feasible``;
      a candidate above the mean by more than that stays above it (bound w_u scale dJ), one below
      by more than its own dJ stays below (0), else the indicator may flip: w_u scale (J + dJ).

    The bound is w_o w_risk (w_B dB + w_E dE + w_M dM + w_ego dEgo + w_R dR) + that J_utility part;
    in the exact mode it is 0. The tolerance mode's chosen candidate costs, in exact terms, at
    most its bound plus the exact choice's bound more than the exact choice (tests/ethics/test_risk_tolerance.py,
    ``tools/tolerance_check.py`` on recorded planning steps)."""
    K = cost.total.shape[0]
    if risk.slack is None or risk.slack.shape[2] == 0:
        return np.zeros(K)
    s_e, s_o, s_he, s_ho = risk.slack
    t = cost.terms
    n_norm = t["n_norm"]
    w = cfg.weights
    d_bayes = (s_e + s_o).sum(axis=1) / (2 * n_norm)
    d_equality = np.maximum(s_e, s_o).sum(axis=1) / n_norm
    breakers = np.zeros(s_o.shape[1], bool) if risk.rule_breaker is None else risk.rule_breaker
    d_resp = (s_o * ~breakers).sum(axis=1) / n_norm
    d_ego = s_e.sum(axis=1)
    h = t["max_harm"]
    h_up = np.maximum(np.maximum((risk.ego_harm_max + s_he).max(axis=1), (risk.other_harm_max + s_ho).max(axis=1)),
                      risk.boundary_harm)
    d_maximin = h_up**cfg.maximin_exponent - h**cfg.maximin_exponent
    d_origin = w.risk * cfg.principle_scale * (w.bayes * d_bayes + w.equality * d_equality + w.maximin * d_maximin + w.ego * d_ego
                         + w.responsibility * d_resp)
    d_j = (s_e + s_o).sum(axis=1)
    j, j_mean = t["j_total_risk"], t["j_mean"]
    pool = np.ones(K, bool) if feasible is None else np.asarray(feasible, dtype=bool)
    d_mean = float(d_j[pool].max()) if pool.any() else float(d_j.max())
    if cfg.utility is UtilityMode.LITERAL:
        d_mean = d_j  # J_mean = J / N_r moves with the candidate's own J
    above = j > j_mean + d_mean + _TIE_RTOL * np.abs(j_mean)
    below = j + d_j <= j_mean
    d_utility = cfg.utility_scale * np.where(above, d_j, np.where(below, 0.0, j + d_j))
    return cfg.omega_o * d_origin + cfg.omega_u * d_utility
