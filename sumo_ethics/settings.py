"""Planner settings from the command line and TOML files, validated before SUMO starts.

A TOML file for ``run`` may also have a ``[conflicts]`` table (:class:`~sumo_ethics.config.ConflictConfig`:
enabled, ttc, pet, gap, crossing_angle, everyone; sweeps read ``[planner]`` alone). A TOML file has a ``[planner]`` table (omega_u, omega_o, weights, utility, normalise, price, predictor,
predictor_weights, calibrated, max_risk, braking_prior, lateral_prior, lateral_onset, selection, envelope, entry,
evasive, replan_every, share_plans, occlusion, phantoms, keep_side) with optional sub-tables ``[planner.sampling]``, ``[planner.probability]``,
``[planner.principles]`` (custom J_origin weights), ``[planner.perception]`` (the sensor, memory and
phantoms: :class:`~sumo_ethics.plan.perception.PerceptionConfig`) and ``[planner.terms]`` (the weights of
cost terms registered in :mod:`sumo_ethics.ethics.terms`, by weight key); unknown keys are errors. ``probability =
"origin"`` (or ``"shapes"``) is short for ``[planner.probability] method = ...``. A ``run`` file's
``[perception]`` table is the same as ``[planner.perception]`` and may also switch ``occlusion`` and
``phantoms`` (``[perception] occlusion = true``).
"""

from __future__ import annotations

import sys
from dataclasses import fields, replace
from pathlib import Path
from typing import Any

from sumo_ethics.config import require_number
from sumo_ethics.errors import ConfigError

if sys.version_info >= (3, 11):
    import tomllib
else:  # tomllib is Python 3.11+; tomli is the same parser (a dependency on 3.10 only)
    import tomli as tomllib


#: bounds on the candidate grid, checked before anything is allocated: the planner holds
#: (candidates x neighbours x steps) arrays, so these keep one planning step within memory
#: (measured: 5000 candidates x 40 steps against 100 neighbours peaks at about 600 MB). The steps
#: are the run's: the planner plans on the simulation's step (see :func:`planner_config`)
MAX_CANDIDATES = 5000  # len(horizons) x n_speeds x n_offsets (default 4 x 15 x 17 = 1020)
MAX_HORIZON = 10.0  # s, the longest horizon (default 4 s)
MAX_HORIZON_STEPS = 100  # longest horizon / the run's step (default 4 s / 0.1 s = 40)
MAX_CANDIDATE_STEPS = 200_000  # candidates x horizon steps (default 1020 x 40 = 40,800)


def step_phrase(step: float, source: str | None = None) -> str:
    """``the run's step of 0.01 s (--step-length)``: a step [s] and where it came from (``sim.scenario.Plan``'s
    step_source: "--step-length", "scenario" or "the default: ..."; None: the grid's own ``sampling.dt``)."""
    if source is None:
        return f"sampling.dt = {step:g} s"
    where = {"scenario": "the scenario's <step-length>"}.get(source, source)
    return f"the run's step of {step:g} s ({where})"


def check_grid_size(sampling: Any) -> None:
    """ConfigError when a SamplingConfig's grid has more candidates or a longer horizon [s] than the
    stated limits (the bounds that do not depend on the step)."""
    k = sampling.n_candidates
    if k > MAX_CANDIDATES:
        raise ConfigError(f"the candidate grid is too large: {len(sampling.horizons)} horizons x {sampling.n_speeds} "
                          f"speeds x {sampling.n_offsets} offsets = {k} candidates; the limit is {MAX_CANDIDATES}")
    if max(sampling.horizons) > MAX_HORIZON:
        raise ConfigError(f"sampling.horizons: {max(sampling.horizons):g} s is beyond the limit of {MAX_HORIZON:g} s")


def check_grid_bounds(sampling: Any, step: float | None = None, source: str | None = None) -> None:
    """ConfigError when a SamplingConfig's grid is beyond the stated limits at ``step`` [s], the step
    the planner will plan on (the run's; None: ``sampling.dt``; ``source`` as in :func:`step_phrase`).

    Steps counted: ceil(longest horizon / step). Candidate steps: the grid's candidates x those steps
    (the braking and evasive candidates come on top: see docs/usage.md)."""
    check_grid_size(sampling)
    if step is not None and step != sampling.dt:
        sampling = replace(sampling, dt=step)  # ConfigError if a horizon is shorter than the step
    k, n = sampling.n_candidates, sampling.n_steps
    at = step_phrase(sampling.dt, source if step is not None else None)
    fit = max(sampling.horizons) / MAX_HORIZON_STEPS  # the shortest step the longest horizon fits in
    if n > MAX_HORIZON_STEPS:
        raise ConfigError(f"the candidate grid at {at}: the longest horizon of {max(sampling.horizons):g} s is {n} "
                          f"steps; the limit is {MAX_HORIZON_STEPS} steps (a step of at least {fit:g} s, or "
                          "shorter horizons)")
    if k * n > MAX_CANDIDATE_STEPS:
        fit = max(sampling.horizons) * k / MAX_CANDIDATE_STEPS
        raise ConfigError(f"the candidate grid at {at}: {k} candidates x {n} steps = {k * n} candidate steps; the "
                          f"limit is {MAX_CANDIDATE_STEPS} (a step of at least {fit:.3g} s, shorter horizons or "
                          "fewer candidates)")


def planning_step(sampling: Any, given: dict[str, Any], step: float, source: str | None = None) -> Any:
    """``sampling`` on the run's ``step`` [s]: the planner plans on the simulation's step (its commands fall on
    the candidates' samples, the predictors read histories at that step). A ``dt`` in ``given`` (the
    ``[planner.sampling]`` table) that differs from ``step`` is a ConfigError naming both; the grid's bounds
    are checked at ``step``."""
    if "dt" in given and not abs(float(given["dt"]) - step) <= 1e-9 * max(1.0, step):
        raise ConfigError(f"[planner.sampling] dt = {float(given['dt']):g} s differs from {step_phrase(step, source)}: "
                          f"the planner plans on the run's step; run with --step-length {float(given['dt']):g} "
                          "(or set the scenario's <step-length>), or drop dt")
    check_grid_bounds(sampling, step, source)
    return replace(sampling, dt=step)


def _known(table: dict[str, Any], allowed: set[str], where: str) -> None:
    unknown = set(table) - allowed
    if unknown:
        raise ConfigError(f"unknown key(s) in {where}: {', '.join(sorted(unknown))}; known: {', '.join(sorted(allowed))}")


def _weight(name: str, value: Any) -> float:
    return require_number(name, value, allow_zero=True)


#: the documented range of w_u, the paper's (docs/method.md, "What w_u means")
OMEGA_U_RANGE = (0.0, 1.0)


def _omega_u(value: Any) -> float:
    """w_u, refused outside :data:`OMEGA_U_RANGE` with one line."""
    lo, hi = OMEGA_U_RANGE
    w = _weight("omega_u", value)
    if not lo <= w <= hi:
        raise ConfigError(f"omega_u (w_u) must be from {lo:g} to {hi:g}, the paper's range (docs/method.md, "
                          f"'What w_u means'), got {value!r}")
    return w


def load_toml(path: Path) -> dict[str, Any]:
    """The ``[planner]`` table of a TOML file (the only table sweeps read)."""
    return _read_toml(path, {"planner"})[0]


def load_run_toml(path: Path):
    """The ``[planner]`` table and the :class:`~sumo_ethics.config.ConflictConfig` of ``[conflicts]``
    (enabled, ttc, pet, gap, crossing_angle, everyone) of a TOML file for ``run``."""
    planner, data = _read_toml(path, {"planner", "conflicts", "planners", "perception"})
    return with_perception(planner, data.get("perception"), str(path)), conflicts_config(data.get("conflicts"), str(path))


#: the keys of a run file's [perception] table that switch the planner's perception (the rest are
#: PerceptionConfig's, [planner.perception])
PERCEPTION_SWITCHES = ("occlusion", "phantoms")


def with_perception(planner: dict[str, Any], table: Any, where: str = "settings") -> dict[str, Any]:
    """The ``[planner]`` table with a ``[perception]`` table merged in: ``occlusion`` and ``phantoms``
    as planner keys, the rest into ``[planner.perception]`` (a key given in both is an error)."""
    if table is None:
        return planner
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: 'perception' must be a table ([perception]), got {table!r}")
    out = dict(planner)
    sub = dict(out.get("perception", {})) if isinstance(out.get("perception", {}), dict) else out["perception"]
    for k, val in table.items():
        dest, name = (out, k) if k in PERCEPTION_SWITCHES else (sub, k)
        if name in dest:
            raise ConfigError(f"{where}: '{k}' is set in both [perception] and [planner]")
        dest[name] = val
    if sub:
        out["perception"] = sub
    return out


def named_planners(path: Path) -> dict[str, dict[str, Any]]:
    """The ``[planners.NAME]`` tables of a TOML file for ``run --fleet``: name -> its keys (those of
    ``[planner]``, which they override)."""
    named = _read_toml(path, {"planner", "conflicts", "planners", "perception"})[1].get("planners", {})
    if not isinstance(named, dict) or not all(isinstance(v, dict) for v in named.values()):
        raise ConfigError(f"{path}: 'planners' must hold named tables ([planners.NAME]), got {named!r}")
    return named


def conflicts_config(table: Any, where: str = "settings"):
    """A validated ConflictConfig from a ``[conflicts]`` table (None: the defaults)."""
    from sumo_ethics.config import ConflictConfig

    if table is None:
        return ConflictConfig()
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: 'conflicts' must be a table ([conflicts]), got {table!r}")
    _known(table, {f.name for f in fields(ConflictConfig)}, f"[conflicts] of {where}")
    return ConflictConfig(**table)


def _read_toml(path: Path, tables: set[str]) -> tuple[dict[str, Any], dict[str, Any]]:
    path = Path(path)
    if path.is_dir():
        raise ConfigError(f"config file {path} is a folder, not a TOML file")
    try:
        with open(path, "rb") as f:
            data = tomllib.load(f)
    except FileNotFoundError:
        raise ConfigError(f"config file not found: {path}") from None
    except OSError as exc:
        raise ConfigError(f"cannot read config file {path}: {exc.strerror or exc}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"malformed TOML in {path}: {exc}") from None
    _known(data, tables, str(path))
    planner = data.get("planner", {})
    if not isinstance(planner, dict):
        raise ConfigError(f"{path}: 'planner' must be a table ([planner]), got {planner!r}")
    return planner, data


#: the [planner] table's keys that are not sub-tables: the cost's (CostConfig), then PlannerConfig's own
#: fields (tests/sweep/test_sweep.py checks they are all of them)
COST_KEYS = ("omega_u", "omega_o", "weights", "utility", "normalise", "price")
PLANNER_KEYS = COST_KEYS + ("predictor", "predictor_weights", "calibrated", "max_risk", "braking_prior", "lateral_prior",
                            "lateral_onset", "selection", "envelope", "entry", "evasive", "replan_every",
                            "share_plans", "occlusion", "phantoms", "keep_side")
#: the ones ``sweep --set`` takes: all but omega_u, which has ``--omega-u``
SET_PLANNER_KEYS = tuple(k for k in PLANNER_KEYS if k != "omega_u")


def registered_weight_keys() -> set[str]:
    """The weight keys ``[planner.terms]`` takes: those of the cost terms registered beside the
    built-in ones (:func:`sumo_ethics.ethics.terms.register`; the built-in weights have their own
    keys: ``weights``, ``[planner.principles]``, ``[planner.perception] weight``)."""
    from sumo_ethics.ethics.terms import BUILTIN, cost_terms

    return {t.weight for t in cost_terms() if t.weight and t not in BUILTIN}


def planner_config(table: dict[str, Any] | None = None, step: float | None = None, step_source: str | None = None,
                   **overrides: Any):
    """A validated PlannerConfig from a ``[planner]`` table and command-line overrides (None = unset).

    step: the run's step [s] when it is known (``sim.scenario.resolve_step``; ``step_source`` says where
    it came from): the grid plans on it (``sampling.dt`` = step), a ``[planner.sampling] dt`` that
    differs is refused and the grid's bounds are checked at it (:func:`planning_step`). None: the
    grid keeps ``dt`` (given or 0.1 s) and its bounds are checked at that; the runner plans on the
    run's step all the same and checks the bounds at it before SUMO starts."""
    from sumo_ethics.ethics.cost import DEFAULT_OMEGA_U, CostConfig, PrincipleWeights, UtilityMode
    from sumo_ethics.ethics.probability import ProbabilityConfig
    from sumo_ethics.plan.ethical import PlannerConfig
    from sumo_ethics.plan.perception import PerceptionConfig
    from sumo_ethics.plan.sampling import SamplingConfig

    if table is not None and not isinstance(table, dict):
        raise ConfigError(f"[planner] must be a table, got {table!r}")
    t = dict(table or {})
    t.update({k: v for k, v in overrides.items() if v is not None})
    _known(t, set(PLANNER_KEYS) | {"sampling", "probability", "principles", "perception", "terms"}, "[planner]")
    if isinstance(t.get("probability"), str):  # probability = "origin" is short for [planner.probability] method
        t["probability"] = {"method": t["probability"]}
    for sub in ("sampling", "probability", "principles", "perception", "terms"):
        if not isinstance(t.get(sub, {}), dict):
            raise ConfigError(f"[planner.{sub}] must be a table, got {t[sub]!r}")
    try:
        weights = PrincipleWeights.preset(t.get("weights", "ethical"))
        if "principles" in t:
            p = t["principles"]
            _known(p, {f.name for f in fields(PrincipleWeights)}, "[planner.principles]")
            weights = PrincipleWeights(**{**{f.name: getattr(weights, f.name) for f in fields(PrincipleWeights)},
                                          **{k: _weight(f"principles.{k}", v) for k, v in p.items()}})
        utility = t.get("utility", UtilityMode.CANDIDATE_MEAN.value)
        terms = t.get("terms", {})  # the weights of registered cost terms (sumo_ethics.ethics.terms)
        _known(terms, registered_weight_keys(), "[planner.terms]")
        cost = CostConfig(weights=weights, omega_o=_weight("omega_o", t.get("omega_o", 1.0)),
                          omega_u=_omega_u(t.get("omega_u", DEFAULT_OMEGA_U)), utility=utility,
                          normalise=t.get("normalise", "in_range"), price=t.get("price", "preset"),
                          term_weights={k: _weight(f"terms.{k}", v) for k, v in terms.items()})
        sampling = dict(t.get("sampling", {}))  # the caller's table stays as it was
        _known(sampling, {f.name for f in fields(SamplingConfig)}, "[planner.sampling]")
        if "horizons" in sampling:
            sampling["horizons"] = tuple(sampling["horizons"])
        probability = t.get("probability", {})
        _known(probability, {f.name for f in fields(ProbabilityConfig)}, "[planner.probability]")
        # keys not set keep PlannerConfig's own defaults (its grid, not SamplingConfig's bare one)
        grid = replace(PlannerConfig().sampling, **sampling)
        if step is not None:
            grid = planning_step(grid, sampling, step, step_source)
        else:
            check_grid_bounds(grid)
        given = {k: t[k] for k in PLANNER_KEYS[len(COST_KEYS):] if k in t and k != "predictor_weights"}
        if t.get("predictor_weights") is not None:
            given["predictor_weights"] = str(t["predictor_weights"])
        perception = PerceptionConfig.from_table(t.get("perception", {}))
        return PlannerConfig(cost=cost, sampling=grid, probability=ProbabilityConfig(**probability),
                             perception=perception, **given)
    except ConfigError:
        raise
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"invalid planner setting: {exc}") from None
