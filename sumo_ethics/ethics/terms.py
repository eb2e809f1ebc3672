"""The named cost terms: one list that :func:`~sumo_ethics.ethics.cost.score`, the weighted sums,
the :class:`~sumo_ethics.types.CostBreakdown`, ``steps.parquet``'s ``cost_*`` columns, the recorded
decisions and ``explain``'s cost panel all read (like Frenetix's named cost functions).

A term is a :class:`CostTerm`: its name (the CostBreakdown key; the steps.parquet column is
``cost_<name>``), a function of the scored inputs (:class:`TermInputs`) giving a (K,) array (or
None: the term does not apply to this step, and is left out of the breakdown), where it goes
(``group``), its weight key, unit, description and explain's label:

- ``"principle"``: one of J_origin's five principles, ``w_risk x weights[weight] x value``;
- ``"origin"``: added to J_origin as ``weight x value`` (progress, lateral, and new comfort terms);
- ``"total"``: added to the total (what selection minimises) after J_risk, ``weight x value``, with
  the weighted value recorded as a second term ``weighted`` (the phantoms' risk);
- ``"record"``: a quantity recorded with the terms and summed into nothing (the risk per class);
- ``"aggregate"``: J_origin, J_mean, J_utility, J_risk: computed by ``score`` from the others
  (``compute`` None); listed here for their place in the breakdown and their labels.

The weight of a term is read by :func:`weight_of`: a field of ``CostConfig.weights``
(PrincipleWeights) if ``weight`` names one, else ``CostConfig.term_weights[weight]``, else the
``weights`` passed to ``score`` (the planner passes ``[planner.perception] weight`` as
``phantom``), else the term's ``default_weight``.

Adding a term is one function and one :func:`register` call; ``score`` sums it, the CostBreakdown,
steps.parquet (``cost_<name>``), the recorded decisions and explain's panel carry it
(``docs/extending.md``). The built-in terms keep their order, so the columns and the
floats of existing runs are unchanged; registered terms come after them.
"""

from __future__ import annotations

import functools
from contextlib import contextmanager
from dataclasses import dataclass, field, fields
from typing import Any, Callable, Iterator, Mapping

import numpy as np

__all__ = ["CostTerm", "TermInputs", "GROUPS", "register", "unregister", "registered", "cost_terms", "term",
           "weight_of", "BUILTIN"]

#: where a term's value goes (module doc)
GROUPS = ("principle", "origin", "total", "record", "aggregate")


@dataclass
class TermInputs:
    """What every term function reads: the K candidates ``cand`` (:class:`~sumo_ethics.types.Candidates`),
    their ``risk`` (:class:`~sumo_ethics.ethics.risk.RiskTerms`), the ``cfg`` (CostConfig), the
    desired speed [m/s], the ``feasible`` mask J_mean averages over (None: all), ``n_norm`` (K,) the
    divisor of Bayes, Equality and Responsibility, and ``extra``: whatever else the caller of
    ``score`` passes (the planner: ``phantom_risk``, (K,) the phantoms' summed risk, with phantoms).
    The shared sums are computed once, on first use."""

    cand: Any
    risk: Any
    cfg: Any
    desired_speed: float
    feasible: np.ndarray | None
    n_norm: np.ndarray
    extra: Mapping[str, Any] = field(default_factory=dict)

    @property
    def K(self) -> int:
        return int(self.cand.x.shape[0])

    @property
    def N(self) -> int:
        return int(self.risk.ego_risk.shape[1])

    @functools.cached_property
    def ego_risk_sum(self) -> np.ndarray:
        return self.risk.ego_risk.sum(axis=1)

    @functools.cached_property
    def other_risk_sum(self) -> np.ndarray:
        return self.risk.other_risk.sum(axis=1)

    @functools.cached_property
    def vru_risk(self) -> np.ndarray:
        """(K, N) the risk put on vulnerable road users."""
        return self.risk.other_risk * self.risk.vulnerable

    @functools.cached_property
    def j_total(self) -> np.ndarray:
        """J(s) = sum_n ego_risk + sum_n other_risk + b."""
        return self.ego_risk_sum + self.other_risk_sum + self.risk.boundary_harm

    @functools.cached_property
    def max_harm(self) -> np.ndarray:
        """Maximin's h_max: the largest ramped harm among the parties and the boundary harm."""
        bh = self.risk.boundary_harm
        if not self.N:
            return bh.copy()
        return np.maximum(np.maximum(self.risk.ego_harm_max.max(axis=1), self.risk.other_harm_max.max(axis=1)), bh)

    @functools.cached_property
    def valid(self) -> np.ndarray:
        """(K, T) bool: the candidates' valid steps."""
        return self.cand.valid.astype(bool)

    @functools.cached_property
    def count(self) -> np.ndarray:
        """(K,) the number of valid steps (at least 1): means over a candidate divide by it."""
        return np.maximum(self.valid.sum(axis=1), 1)

    def mean_over_steps(self, values: np.ndarray) -> np.ndarray:
        """(K,) the mean of (K, T) ``values`` over each candidate's valid steps."""
        return np.where(self.valid, values, 0.0).sum(axis=1) / self.count


@dataclass(frozen=True)
class CostTerm:
    """One named cost term (module doc). name: the CostBreakdown key and ``cost_<name>`` column;
    compute: (TermInputs) -> (K,) array or None (not this step); group: one of :data:`GROUPS`;
    weight: its weight key (:func:`weight_of`; None for "record" and "aggregate"); unit,
    description: what it measures; label: explain's row (None: not drawn); weighted, weighted_label:
    "total" terms: the name and label of weight x value; optional: explain shows the row only where
    a decision has the term; default_weight: used when no config gives the weight."""

    name: str
    compute: Callable[[TermInputs], np.ndarray | None] | None
    group: str = "origin"
    weight: str | None = None
    unit: str = "-"
    description: str = ""
    label: str | None = None
    weighted: str | None = None
    weighted_label: str | None = None
    optional: bool = False
    default_weight: float = 0.0

    def __post_init__(self) -> None:
        if self.group not in GROUPS:
            raise ValueError(f"cost term {self.name!r}: group must be one of {', '.join(GROUPS)}, got {self.group!r}")
        if self.group in ("principle", "origin", "total") and not self.weight:
            raise ValueError(f"cost term {self.name!r} of group {self.group!r} needs a weight key")
        if self.group == "total" and not self.weighted:
            raise ValueError(f"cost term {self.name!r} of group 'total' needs the name of its weighted value")
        if self.group != "aggregate" and self.compute is None:
            raise ValueError(f"cost term {self.name!r} needs a compute function")


# ---- the built-in terms (cost.py's module doc defines them) ---------------------------------------
def _bayes(i: TermInputs) -> np.ndarray:
    if i.N:
        return i.j_total / (2 * i.n_norm)
    bh = i.risk.boundary_harm
    return bh / (2 * i.n_norm) if i.cfg.normalise == "at_risk" else bh.copy()


def _equality(i: TermInputs) -> np.ndarray:
    if not i.N:
        return np.zeros(i.K)
    return np.abs(i.risk.ego_risk - i.risk.other_risk).sum(axis=1) / i.n_norm


def _maximin(i: TermInputs) -> np.ndarray:
    return i.max_harm**i.cfg.maximin_exponent


def _ego(i: TermInputs) -> np.ndarray:
    return i.ego_risk_sum + i.risk.boundary_harm


def _responsibility(i: TermInputs) -> np.ndarray:
    if not i.N:
        return np.zeros(i.K)
    breakers = i.risk.rule_breaker
    if breakers is None:  # RiskTerms.__post_init__ makes it all False when unknown
        raise ValueError("RiskTerms.rule_breaker is not set")
    return (i.risk.other_risk * ~breakers).sum(axis=1) / i.n_norm


def _progress(i: TermInputs) -> np.ndarray:
    return np.abs(i.desired_speed - i.mean_over_steps(i.cand.speed))


def _lateral(i: TermInputs) -> np.ndarray:
    ref = i.extra.get("lateral_reference")  # the side to keep (sumo_ethics.plan.side), else the lane's centre
    return i.mean_over_steps(np.abs(i.cand.d if ref is None else i.cand.d - float(ref)))


def _max_of(values: Callable[[TermInputs], np.ndarray]) -> Callable[[TermInputs], np.ndarray]:
    def compute(i: TermInputs) -> np.ndarray:
        return values(i).max(axis=1) if i.N else np.zeros(i.K)
    return compute


def _phantom_risk(i: TermInputs) -> np.ndarray | None:
    value = i.extra.get("phantom_risk")
    return None if value is None else np.asarray(value, dtype=float)


#: the built-in terms in the order of every CostBreakdown (and of steps.parquet's cost_* columns)
BUILTIN: tuple[CostTerm, ...] = (
    CostTerm("bayes", _bayes, "principle", "bayes", "risk", "(sum of risks + boundary harm) / 2N",
             "Bayes (risk sum / 2N)"),
    CostTerm("equality", _equality, "principle", "equality", "risk", "sum of |ego risk - other risk| / N",
             "Equality (risk spread)"),
    CostTerm("maximin", _maximin, "principle", "maximin", "harm^e", "the largest ramped harm ** maximin_exponent",
             "Maximin (max harm^10)"),
    CostTerm("ego", _ego, "principle", "ego", "risk", "the ego's risk + boundary harm", "Ego (own risk)"),
    CostTerm("responsibility", _responsibility, "principle", "responsibility", "risk",
             "risk put on road users who keep the rules / N", "Responsibility"),
    CostTerm("progress", _progress, "origin", "velocity", "m/s", "|v_desired - mean speed|", "progress (speed deficit)"),
    CostTerm("lateral", _lateral, "origin", "lateral", "m", "mean |d - d_ref| (d_ref: 0, or the side to keep)",
             "lateral offset"),
    CostTerm("j_origin", None, "aggregate", unit="cost", description="Origin's weighted sum", label="J_origin"),
    CostTerm("j_total_risk", lambda i: i.j_total, "record", unit="risk", description="J(s): every party's risk summed"),
    CostTerm("j_mean", None, "aggregate", unit="risk", description="J_mean: the mean J of the pool"),
    CostTerm("j_utility", None, "aggregate", unit="cost", description="utility_scale x J above J_mean",
             label="J_utility"),
    CostTerm("j_risk", None, "aggregate", unit="cost", description="omega_o J_origin + omega_u J_utility",
             label="J_risk = w_o J_origin + w_u J_util."),
    CostTerm("ego_risk_sum", lambda i: i.ego_risk_sum, "record", unit="risk", description="the ego's risk, summed",
             label="risk to the ego"),
    CostTerm("other_risk_sum", lambda i: i.other_risk_sum, "record", unit="risk",
             description="third parties' risk, summed", label="risk to third parties"),
    CostTerm("vru_risk_sum", lambda i: i.vru_risk.sum(axis=1), "record", unit="risk",
             description="the VRUs' risk, summed", label="  of which VRUs"),
    CostTerm("ego_risk_max", _max_of(lambda i: i.risk.ego_risk), "record", unit="risk"),
    CostTerm("other_risk_max", _max_of(lambda i: i.risk.other_risk), "record", unit="risk"),
    CostTerm("vru_risk_max", _max_of(lambda i: i.vru_risk), "record", unit="risk"),
    CostTerm("boundary_harm", lambda i: i.risk.boundary_harm, "record", unit="harm",
             description="harm of leaving the road (an ego risk)", label="leaving the road (ego harm)"),
    CostTerm("max_harm", lambda i: i.max_harm, "record", unit="harm", description="Maximin's h_max"),
    CostTerm("n_norm", lambda i: i.n_norm, "record", unit="-", description="the divisor N"),
    CostTerm("phantom_risk", _phantom_risk, "total", "phantom", "risk",
             "expected risk summed over the phantoms (existence x P x harm); with [planner] phantoms",
             "phantoms' risk (x existence)", weighted="phantom", weighted_label="phantoms: weight x risk",
             optional=True),
)

_TERMS: list[CostTerm] = list(BUILTIN)


def cost_terms() -> tuple[CostTerm, ...]:
    """The registered terms, built-in first, in the order of every CostBreakdown."""
    return tuple(_TERMS)


def term(name: str) -> CostTerm:
    """The registered term ``name`` (KeyError otherwise)."""
    for t in _TERMS:
        if t.name == name:
            return t
    raise KeyError(f"no cost term {name!r}; registered: {', '.join(t.name for t in _TERMS)}")


def register(new: CostTerm) -> CostTerm:
    """Add ``new`` after the registered terms (ValueError if its name, or its weighted name, is
    taken); returns it, so ``register`` can decorate a module-level definition."""
    taken = {n for t in _TERMS for n in (t.name, t.weighted) if n} | {"total"}
    for n in (new.name, new.weighted):
        if n in taken:
            raise ValueError(f"a cost term {n!r} is registered already")
    _TERMS.append(new)
    return new


def unregister(name: str) -> None:
    """Remove the registered term ``name`` (a built-in one cannot be removed)."""
    if any(t.name == name for t in BUILTIN):
        raise ValueError(f"{name!r} is a built-in cost term")
    _TERMS[:] = [t for t in _TERMS if t.name != name]


@contextmanager
def registered(*new: CostTerm) -> Iterator[tuple[CostTerm, ...]]:
    """``with registered(term): ...``: the terms registered inside the block only (tests, studies)."""
    done: list[CostTerm] = []
    try:
        for t in new:
            done.append(register(t))
        yield tuple(done)
    finally:
        for t in done:
            unregister(t.name)


def weight_of(t: CostTerm, cfg: Any, weights: Mapping[str, float] | None = None) -> float:
    """The weight of term ``t`` under CostConfig ``cfg``: a PrincipleWeights field of that name,
    else ``cfg.term_weights``, else ``weights`` (passed to score), else ``t.default_weight``."""
    key = t.weight
    if key is None:
        raise ValueError(f"cost term {t.name!r} has no weight")
    if key in _principle_fields(cfg):
        return float(getattr(cfg.weights, key))
    own = getattr(cfg, "term_weights", None) or {}
    if key in own:
        return float(own[key])
    if weights is not None and key in weights:
        return float(weights[key])
    return float(t.default_weight)


def _principle_fields(cfg: Any) -> frozenset[str]:
    return frozenset(f.name for f in fields(cfg.weights))
