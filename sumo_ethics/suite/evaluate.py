"""``sumo-ethics evaluate``: every scenario of a suite with every planner -> the paper's Table 1.

Each (scenario, planner) run is one task in a fresh process (libsumo: one simulation per
process, and none after a fatal SUMO error): :func:`sumo_ethics.processes.run_each`, forked
from a forkserver that has imported torch, libsumo and the package once (a spawned process
would re-import torch for every run). Every planner meets the same
scenarios with the same seeds, so the comparison is paired.

Table columns as in the paper (METHOD.md section 5; docs/suite.md, "evaluate: Table 1 for a
suite"): Completed (%), and harm summed over all runs: Total = Ego + Third party, VRU (part of
third party). 95 % confidence intervals are percentile bootstraps over scenarios
(:func:`table`): a planner's row resamples the scenarios it has a run for; the paired comparison
gives, per planner against the reference, the bootstrap interval of the per-scenario differences
over the scenarios both have a run for (each drawn uniformly) and a Wilcoxon signed-rank p-value
of those differences.
"""

from __future__ import annotations

import json
import os
import time
from contextlib import closing
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable

import numpy as np

from sumo_ethics.analysis.exante import run_risk_file
from sumo_ethics.errors import ConfigError
from sumo_ethics.ethics.cost import DEFAULT_OMEGA_U
from sumo_ethics.predict import one_thread
from sumo_ethics.suite.outcome import (FAULTS, HARD_BRAKE, WARRANT_AFTER, WARRANT_BEFORE, outcome, read_summary,
                                       snapshots_of)

#: the paper's planner: attention predictor, J_utility at this weight (see docs/suite.md, "The planners of evaluate")
PAPER_OMEGA_U = DEFAULT_OMEGA_U

#: origin: Origin's weights, predictor class (CS-LSTM), collision probability (three-point score)
#: and selection rule (validity levels); paper: the paper's method (attention, J_utility, selection
#: by cost) on Origin's probability; both divide Bayes, equality and responsibility by every road
#: user in range, as published (normalise "in_range"), without the evasive candidates (braking and
#: swerving at once) and the lateral prior's onset model (lateral_onset); ours: this project's planner, what ``run``
#: and ``sweep`` use by default (PlannerConfig's defaults: the map-aware attention predictor,
#: the collision probability over true shapes, principles on one scale); "default" names it too.
#: the paper's planner, and the base of a planner defined as NAME=key=value;... unless it names
#: another (``base=ours`` or ``base=origin``)
PAPER: dict[str, Any] = {"weights": "ethical", "predictor": "attention", "omega_u": PAPER_OMEGA_U, "selection": "cost",
                         "normalise": "in_range", "probability": "origin", "calibrated": False, "evasive": False,
                         "lateral_onset": False}
BUILTIN: dict[str, dict[str, Any] | None] = {
    "baseline": None,  # the route-following controller
    # as published: Origin's probability and normalisation, their predictors' own spreads without the
    # calibration (predict/calibration.py)
    "origin": {"weights": "ethical", "predictor": "cslstm", "omega_u": 0.0, "selection": "validity",
               "normalise": "in_range", "probability": "origin", "calibrated": False, "evasive": False,
               "lateral_onset": False},
    "paper": PAPER,
    "ours": {},
}
#: other names of built-in planners
ALIASES = {"default": "ours"}
METRICS = ("completed", "total", "ego", "third_party", "vru")
LABELS = {"completed": "Completed (%)", "total": "Total harm", "ego": "Ego", "third_party": "Third party",
          "vru": "VRU"}


@dataclass(frozen=True)
class PlannerSpec:
    """A named planner: ``options`` for ``planner_config`` (None: the baseline controller), over
    the defaults of run and sweep; ``base``: the built-in planner a planner of one's own was
    defined over ("paper" unless it said ``base=``)."""

    name: str
    options: dict[str, Any] | None
    base: str = "paper"

    def describe(self) -> str:
        if self.options is None:
            return "baseline (route following, IDM)"
        if not self.options:
            return "the defaults of run and sweep"
        over = "base=ours;" if self.base == "ours" else ""  # origin's and paper's options are all listed
        return over + ";".join(f"{k}={v}" for k, v in self.options.items())


def _value(text: str) -> Any:
    t = text.strip()
    for conv in (int, float):
        try:
            return conv(t)
        except ValueError:
            pass
    if t.lower() in ("true", "false"):
        return t.lower() == "true"
    return t


def parse_planner(text: str) -> PlannerSpec:
    """``origin`` | ``paper`` | ``ours`` (or ``default``) | ``baseline`` | ``NAME=key=value;key=value`` (options of
    ``planner_config``, applied over the ``paper`` planner's settings, e.g. ``fast=predictor=cv;omega_u=0.3``,
    or over another built-in planner's with ``base=ours`` / ``base=origin``, e.g.
    ``mm=base=ours;weights=maximin``). Validated at once: an unknown name or key is a ConfigError."""
    from sumo_ethics.settings import planner_config

    text = text.strip()
    text = ALIASES.get(text, text)
    if "=" not in text:
        if text not in BUILTIN:
            raise ConfigError(f"unknown planner '{text}'; known: {', '.join(BUILTIN)}, "
                              "or define one as NAME=key=value;key=value (e.g. fast=predictor=cv;omega_u=0.3)")
        opts = BUILTIN[text]
        spec = PlannerSpec(text, dict(opts) if opts is not None else None)
    else:
        name, _, rest = text.partition("=")
        name = name.strip()
        if not name or not name.replace("_", "").replace("-", "").isalnum():
            raise ConfigError(f"planner name must be letters, digits, '-' or '_', got {name!r} in {text!r}")
        given: dict[str, Any] = {}
        for item in filter(None, (p.strip() for p in rest.split(";"))):
            key, eq, val = item.partition("=")
            if not eq or not key.strip():
                raise ConfigError(f"planner {name}: expected key=value, got {item!r}")
            given[key.strip()] = _value(val)
        base = str(given.pop("base", "paper"))
        base = ALIASES.get(base, base)
        if base not in ("origin", "paper", "ours"):
            raise ConfigError(f"planner {name}: base must be origin, paper or ours, got {base!r}")
        spec = PlannerSpec(name, {**(BUILTIN[base] or {}), **given}, base)
    if spec.options is not None:
        planner_config(None, **spec.options)  # raises ConfigError on unknown keys / bad values
    return spec


def parse_planners(texts: Iterable[str]) -> list[PlannerSpec]:
    specs = [parse_planner(t) for t in texts]
    names = [s.name for s in specs]
    if not specs:
        raise ConfigError("give at least one --planner")
    if len(set(names)) != len(names):
        raise ConfigError(f"planner names must be unique, got {names}")
    return specs


# ---- one run (in a worker process) ------------------------------------------------------
def run_one(scenario_dir: str, planner: PlannerSpec, out_dir: str, record_decisions: str = "risky") -> dict[str, Any]:
    """Run one scenario with one planner, keeping its decisions by ``record_decisions``; returns
    the result row (never raises)."""
    if (Path(scenario_dir) / "commonroad.json").is_file():  # an imported CommonRoad scenario
        from sumo_ethics.suite import commonroad

        return commonroad.run_one(scenario_dir, planner, out_dir, record_decisions)
    t0 = time.perf_counter()
    row: dict[str, Any] = {"scenario": Path(scenario_dir).name, "planner": planner.name}
    try:
        one_thread(load=True)
        from sumo_ethics.runner import make_controller, run
        from sumo_ethics.settings import planner_config
        from sumo_ethics.sim.hazards import HazardInjector
        from sumo_ethics.suite.spec import load

        spec = load(Path(scenario_dir))
        row.update(network=spec.network, hazard=",".join(spec.hazard_types), seed=spec.seed)
        pcfg = planner_config(None, **planner.options) if planner.options is not None else None
        cfg = spec.run_config(Path(out_dir), pcfg, overwrite=True, record_decisions=record_decisions)
        injector = HazardInjector(spec.hazards)
        try:
            summary = run(cfg, controller=make_controller(cfg), hooks=(injector,))
            data = summary.data
        except Exception as exc:  # noqa: BLE001 - a failed run is a row with status error
            data = read_summary(Path(out_dir)) or {"status": "error", "message": str(exc)}
            if not data.get("message"):
                data["message"] = f"{type(exc).__name__}: {exc}"
        finally:
            Path(out_dir).mkdir(parents=True, exist_ok=True)
            (Path(out_dir) / "hazard_events.json").write_text(json.dumps(injector.events, indent=1))
        data.update(snapshots_of(Path(out_dir)))  # drawn from the run folder (the run draws none)
        harm = data.get("harm", {})
        fired = sorted({e["type"] for e in injector.events if e["event"] == "trigger"})
        row.update(status=data.get("status", "error"), completed=bool(data.get("completed", False)),
                   total=float(harm.get("total", 0.0)), ego=float(harm.get("ego", 0.0)),
                   third_party=float(harm.get("third_party", 0.0)), vru=float(harm.get("vru", 0.0)),
                   message=str(data.get("message", ""))[:200], steps=int(data.get("steps", 0) or 0),
                   hazards_fired=",".join(fired), **outcome(Path(out_dir), data),
                   **run_risk_file(Path(out_dir)))
    except Exception as exc:  # noqa: BLE001
        row.update(status="error", completed=False, total=0.0, ego=0.0, third_party=0.0, vru=0.0,
                   message=f"{type(exc).__name__}: {exc}"[:200], steps=0, hazards_fired="", collided_with="")
    row["wall_s"] = time.perf_counter() - t0
    return row


def safety_table(rows: list[dict[str, Any]], planners: list[str], n_boot: int = 2000,
                 seed: int = 0) -> list[dict[str, Any]]:
    """Per planner: conflicts (all, VRU) per 100 ego-km, the sum over its runs over their distance
    with a bootstrap CI over scenarios, and the harm of its ego collisions summed by fault."""
    from sumo_ethics.analysis.stats import rate_ci

    out = []
    for p in planners:
        sub = [r for r in rows if r["planner"] == p and np.isfinite(r.get("conflicts_total", np.nan))]
        km = np.array([r.get("distance", 0.0) / 1000.0 for r in sub])
        row: dict[str, Any] = {"planner": p, "runs": len(sub), "ego_km": float(km.sum())}
        for name in ("conflicts_total", "conflicts_vru", "overcautious"):
            n = np.nan_to_num(np.array([r.get(name, np.nan) for r in sub], dtype=float), nan=0.0)
            rate, lo, hi = rate_ci(n, km, 100.0, n_boot, seed)
            row.update({name: float(n.sum()), f"{name}_per_100km": rate, f"{name}_per_100km_lo": lo,
                        f"{name}_per_100km_hi": hi})
        for f in FAULTS:
            row[f"harm_fault_{f}"] = float(sum(r.get(f"harm_fault_{f}", 0.0) for r in rows if r["planner"] == p))
        out.append(row)
    return out


def safety_markdown(st: list[dict[str, Any]]) -> list[str]:
    """The conflicts and fault section of table1.md."""
    if not any(r["runs"] for r in st):
        return []
    lines = ["", "Conflicts (near misses, docs/conflicts.md) per 100 ego-km [95 % bootstrap CI over runs], "
             f"over-cautious brakings (below -{HARD_BRAKE:.2f} m/s^2 with no conflict from {WARRANT_BEFORE:g} s before "
             f"to {WARRANT_AFTER:g} s after and no red light ahead) per 100 ego-km, and the harm of the ego's "
             "collisions (ego + third party) by who caused them:", "",
             "| Algorithm | Ego-km | Conflicts / 100 km | VRU conflicts / 100 km | Over-cautious brakings / 100 km | "
             + " | ".join(f"Harm, fault {f}" for f in FAULTS) + " |",
             "| --- |" + " --- |" * (4 + len(FAULTS))]
    for r in st:
        lines.append(f"| {r['planner']} | {r['ego_km']:.1f} | "
                     + " | ".join(_fmt(r[f"{n}_per_100km"], r[f"{n}_per_100km_lo"], r[f"{n}_per_100km_hi"], True)
                                  for n in ("conflicts_total", "conflicts_vru", "overcautious"))
                     + " | " + " | ".join(f"{r[f'harm_fault_{f}']:.2f}" for f in FAULTS) + " |")
    return lines


# ---- many runs --------------------------------------------------------------------------
def _run_task(task: tuple) -> dict[str, Any]:
    """One task of :func:`run_suite` in its run process: :func:`run_one`'s row."""
    return run_one(*task)


def _dead_row(scenario: str, planner: PlannerSpec, why: str) -> dict[str, Any]:
    from sumo_ethics.suite.spec import load

    try:
        spec = load(Path(scenario))
        where = {"network": spec.network, "hazard": ",".join(spec.hazard_types), "seed": spec.seed}
    except ConfigError:
        where = {}
    return {**where, "scenario": Path(scenario).name, "planner": planner.name, "status": "error", "completed": False,
            "total": 0.0, "ego": 0.0, "third_party": 0.0, "vru": 0.0, "message": why[:200], "steps": 0,
            "hazards_fired": "", "collided_with": "", "wall_s": 0.0}


def _row_from_folder(scenario: str, planner: PlannerSpec, out_dir: str, *_: Any) -> dict[str, Any] | None:
    """The row of a finished run (for --resume), None if the folder holds no finished run."""
    out = Path(out_dir)
    if (Path(scenario) / "commonroad.json").is_file():  # an imported CommonRoad scenario
        from sumo_ethics.suite import commonroad

        return commonroad.row_from_folder(scenario, planner, out_dir)
    data = read_summary(out)
    if data is None or not (out / "hazard_events.json").is_file():
        return None
    from sumo_ethics.suite.spec import load

    spec = load(Path(scenario))
    events = json.loads((out / "hazard_events.json").read_text())
    h = data.get("harm", {})
    return {"scenario": spec.name, "planner": planner.name, "network": spec.network,
            "hazard": ",".join(spec.hazard_types), "seed": spec.seed, "status": data.get("status", "error"),
            "completed": bool(data.get("completed")), "total": float(h.get("total", 0.0)),
            "ego": float(h.get("ego", 0.0)), "third_party": float(h.get("third_party", 0.0)),
            "vru": float(h.get("vru", 0.0)), "message": str(data.get("message", ""))[:200],
            "steps": int(data.get("steps", 0) or 0),
            "hazards_fired": ",".join(sorted({e["type"] for e in events if e["event"] == "trigger"})),
            **outcome(out, data), "wall_s": float(data.get("wall_time", 0.0) or 0.0),
            **run_risk_file(out)}


def run_suite(scenarios: list[Path], planners: list[PlannerSpec], out: Path, workers: int = 2,
              progress: Callable[[int, int, dict[str, Any]], None] | None = None,
              resume: bool = False, record_decisions: str = "risky") -> list[dict[str, Any]]:
    """Every scenario with every planner; one row per run (order: scenario, then planner).

    Each run is its own process (:func:`sumo_ethics.processes.run_each`), forked from a
    forkserver that has the heavy modules loaded: a run that crashes (a SUMO abort, a segfault,
    out of memory) is an error row naming its exit code and takes no other run with it; Ctrl-C
    or SIGTERM kills the runs in flight (a run's folder holds what it wrote). ``resume``: runs
    whose folder already holds a finished run are read back instead of run again.
    """
    from sumo_ethics.processes import one_line, run_each

    if workers < 1:
        raise ConfigError(f"--workers must be at least 1, got {workers}")
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    tasks = [(str(s), p, str(out / "runs" / p.name / s.name), record_decisions) for s in scenarios for p in planners]
    rows: list[dict[str, Any]] = []

    def done(row: dict[str, Any]) -> None:
        rows.append(row)
        if progress is not None:
            progress(len(rows), len(tasks), row)

    todo = []
    for t in tasks:
        row = _row_from_folder(*t) if resume else None
        if row is not None:
            done(row)
        else:
            todo.append(t)
    results = run_each(_run_task, todo, workers, preload=["sumo_ethics.suite.preload"],
                       on_error=lambda t, exc: _dead_row(t[0], t[1], one_line(exc)),
                       on_crash=lambda t, why: _dead_row(t[0], t[1], why))
    with closing(results):  # closed: no run process runs on
        for _, row in results:
            done(row)
    order = {(Path(s).name, p.name): i for i, (s, p, *_) in enumerate(tasks)}
    rows.sort(key=lambda r: order[(r["scenario"], r["planner"])])
    return rows


# ---- statistics -------------------------------------------------------------------------
def _matrix(rows: list[dict[str, Any]], planners: list[str]) -> tuple[list[str], dict[str, np.ndarray]]:
    """Per planner: (S, 5) array of completed (0/1), total, ego, third party, VRU per scenario."""
    scen = sorted({r["scenario"] for r in rows})
    idx = {s: i for i, s in enumerate(scen)}
    out = {}
    for p in planners:
        m = np.full((len(scen), len(METRICS)), np.nan)
        for r in rows:
            if r["planner"] == p:
                m[idx[r["scenario"]]] = [float(r["completed"]), r["total"], r["ego"], r["third_party"], r["vru"]]
        out[p] = m
    return scen, out


def _stat(m: np.ndarray) -> np.ndarray:
    """(…, S, 5) -> (…, 5): completion in %, harms summed over runs (the paper's Table 1)."""
    return np.concatenate([100.0 * np.nanmean(m[..., :1], axis=-2), np.nansum(m[..., 1:], axis=-2)], axis=-1)


def _wilcoxon_p(d: np.ndarray) -> float:
    """Wilcoxon signed-rank p of paired differences ``d`` (1 when all are 0, NaN when undefined)."""
    from scipy.stats import wilcoxon

    if np.allclose(d, 0.0):
        return 1.0
    try:
        return float(wilcoxon(d, zero_method="zsplit").pvalue)
    except ValueError:
        return float("nan")


def table(rows: list[dict[str, Any]], planners: list[str], reference: str | None = None, n_boot: int = 2000,
          seed: int = 0) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """(Table 1 rows with 95 % bootstrap CIs, paired comparison rows against ``reference``).

    Each interval is the 2.5th and 97.5th percentile of the statistic over ``n_boot`` resamples
    (:func:`sumo_ethics.analysis.stats.bootstrap`, seeded with ``seed``) that draw scenarios
    uniformly, with replacement, from the scenarios the statistic is computed on: a planner's
    row from the k scenarios it has a run for, a paired comparison from the k scenarios both
    planners have a run for (a difference exists only there). So every resample holds k runs,
    as the estimate does (a harm summed over k runs stays a sum over k runs), and every one of
    the k scenarios has the same chance 1/k at each draw however many runs are missing. With no
    run missing, k is the number of scenarios and every planner and pair draws the same
    resamples. A planner without runs: completion NaN, harms 0, intervals NaN.
    """
    from sumo_ethics.analysis.stats import bootstrap

    scen, mats = _matrix(rows, planners)

    def interval(samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if not len(samples):
            return np.full(len(METRICS), np.nan), np.full(len(METRICS), np.nan)
        b = bootstrap(samples, _stat, n_boot, seed)  # (n_boot, 5)
        return np.percentile(b, 2.5, axis=0), np.percentile(b, 97.5, axis=0)

    t1 = []
    for p in planners:
        m = mats[p][~np.isnan(mats[p][:, 0])]  # (k, 5): the scenarios it has a run for
        value = _stat(m) if len(m) else np.array([np.nan] + [0.0] * (len(METRICS) - 1))
        lo, hi = interval(m)
        row: dict[str, Any] = {"planner": p, "runs": len(m)}
        for j, k in enumerate(METRICS):
            row[k], row[f"{k}_lo"], row[f"{k}_hi"] = float(value[j]), float(lo[j]), float(hi[j])
        t1.append(row)
    paired = []
    if reference is not None and reference in mats:
        ref = mats[reference]
        for p in planners:
            if p == reference:
                continue
            ok = ~np.isnan(mats[p][:, 0]) & ~np.isnan(ref[:, 0])
            d = mats[p][ok] - ref[ok]  # (k, 5): per scenario both have, planner - reference
            val = _stat(d) if ok.any() else np.zeros(len(METRICS))
            lo, hi = interval(d) if ok.any() else (np.zeros(len(METRICS)), np.zeros(len(METRICS)))
            for j, k in enumerate(METRICS):
                col = d[:, j]
                pval = _wilcoxon_p(col)
                paired.append({"planner": p, "reference": reference, "metric": k, "difference": float(val[j]),
                               "lo": float(lo[j]), "hi": float(hi[j]),
                               "better": int(np.sum(col > 0) if k == "completed" else np.sum(col < 0)),
                               "worse": int(np.sum(col < 0) if k == "completed" else np.sum(col > 0)),
                               "wilcoxon_p": pval, "scenarios": int(ok.sum())})
    return t1, paired


def _fmt(v: float, lo: float, hi: float, pct: bool) -> str:
    f = "{:.1f}" if pct else "{:.2f}"
    return f"{f.format(v)} [{f.format(lo)}, {f.format(hi)}]"


def markdown(t1: list[dict[str, Any]], paired: list[dict[str, Any]], by_hazard: list[dict[str, Any]],
             meta: dict[str, Any]) -> str:
    lines = [f"# Table 1 on {meta.get('suite', 'the suite')} ({meta.get('scenarios', '?')} scenarios)", "",
             "Harm summed over all runs; [95 % bootstrap CI over scenarios].", "",
             "| Algorithm | " + " | ".join(LABELS[k] for k in METRICS) + " |",
             "| --- |" + " --- |" * len(METRICS)]
    for r in t1:
        lines.append(f"| {r['planner']} | " + " | ".join(_fmt(r[k], r[f'{k}_lo'], r[f'{k}_hi'], k == 'completed')
                                                      for k in METRICS) + " |")
    if paired:
        lines += ["", f"Paired comparison against {paired[0]['reference']} (same scenarios and seeds): difference "
                  "(planner - reference) [95 % paired bootstrap CI], scenarios better / worse, Wilcoxon p.", "",
                  "| Planner | Metric | Difference | Better / worse | Wilcoxon p |", "| --- | --- | --- | --- | --- |"]
        for r in paired:
            lines.append(f"| {r['planner']} | {LABELS[r['metric']]} | "
                         f"{_fmt(r['difference'], r['lo'], r['hi'], r['metric'] == 'completed')} | "
                         f"{r['better']} / {r['worse']} | {r['wilcoxon_p']:.3g} |")
    if by_hazard:
        planners = [r["planner"] for r in t1]
        lines += ["", "Ego collisions per hazard type (runs ending in a collision / scenarios):", "",
                  "| Hazard | Scenarios | " + " | ".join(planners) + " |", "| --- | --- |" + " --- |" * len(planners)]
        for r in by_hazard:
            lines.append(f"| {r['hazard']} | {r['scenarios']} | " + " | ".join(str(r[p]) for p in planners) + " |")
    if meta.get("imports"):
        fails = meta.get("import_failures", {})
        n_fail = sum(fails.values())
        lines += ["", f"CommonRoad, {meta.get('commonroad_mode')} mode: {meta['imports'] - n_fail} of {meta['imports']} "
                  f"files imported ({meta.get('import_seconds', 0):.0f} s of import time; OUT/imports.csv has each "
                  "file's time and cause)" + (": failed " + "; ".join(f"{n} x {c}" for c, n in fails.items())
                                               if fails else "") + "."]
        if meta.get("commonroad_completion") == "origin":
            late = meta.get("late", {})
            lines += ["", "Completion as the paper's evaluation counted it (`--completion origin`): reaching the goal "
                      "after its time window completes too, and a run lasts twice the goal's last time step. Completed "
                      "late: " + ", ".join(f"{k} {v}" for k, v in late.items()) + "."]
    if meta:
        lines += ["", "Planners: " + "; ".join(f"`{k}` = {v}" for k, v in meta.get("planners", {}).items()) + ".",
                  f"Wall time {meta.get('wall_s', 0):.0f} s with {meta.get('workers')} workers." if meta.get("workers")
                  else f"Wall time of the runs, summed: {meta.get('wall_s', 0):.0f} s (one worker running them all)."]
    return "\n".join(lines) + "\n"


def hazard_breakdown(rows: list[dict[str, Any]], planners: list[str]) -> list[dict[str, Any]]:
    kinds = sorted({r.get("hazard", "") for r in rows})
    out = []
    for k in kinds:
        sub = [r for r in rows if r.get("hazard", "") == k]
        row: dict[str, Any] = {"hazard": k or "(none)", "scenarios": len({r["scenario"] for r in sub})}
        for p in planners:
            row[p] = sum(1 for r in sub if r["planner"] == p and r["status"] == "collision")
        out.append(row)
    return out


#: per-run metrics compared as paired means: the ex-ante risk (sumo_ethics.analysis.exante) and the
#: harm of the worst-off party of the ego's collisions (what Maximin is about)
RISK_METRICS = ("risk_ego_mean", "risk_third_party_mean", "risk_vru_mean", "risk_total_mean", "risk_worst_peak",
                "harm_worst")


def paired_risk(rows: list[dict[str, Any]], planners: list[str], reference: str, n_boot: int = 2000,
                seed: int = 0) -> list[dict[str, Any]]:
    """Per planner and risk metric: mean over scenarios of (planner - reference) [95 % paired
    bootstrap CI], scenarios lower / higher, Wilcoxon p, over the scenarios where both have a value
    (the CI resamples those uniformly, as :func:`table` does; one stream seeded with ``seed`` serves
    every planner and metric in turn)."""
    scen = sorted({r["scenario"] for r in rows})
    idx = {sc: i for i, sc in enumerate(scen)}
    val = {p: np.full((len(scen), len(RISK_METRICS)), np.nan) for p in planners}
    for r in rows:
        if r["planner"] in val:
            val[r["planner"]][idx[r["scenario"]]] = [float(r.get(m, np.nan)) for m in RISK_METRICS]
    from sumo_ethics.analysis.stats import bootstrap

    rng = np.random.default_rng(seed)
    out = []
    for p in planners:
        if p == reference:
            continue
        for j, m in enumerate(RISK_METRICS):
            d = val[p][:, j] - val[reference][:, j]
            d = d[~np.isnan(d)]
            if not len(d):
                continue
            boot = bootstrap(d, lambda r: r.mean(axis=1), n_boot, rng)  # uniform over the scenarios both have
            pval = _wilcoxon_p(d)
            out.append({"planner": p, "reference": reference, "metric": m, "difference": float(d.mean()),
                        "lo": float(np.percentile(boot, 2.5)), "hi": float(np.percentile(boot, 97.5)),
                        "lower": int(np.sum(d < 0)), "higher": int(np.sum(d > 0)), "wilcoxon_p": pval,
                        "scenarios": int(len(d))})
    return out


def risk_markdown(rt: Any, paired: list[dict[str, Any]]) -> str:
    """The ex-ante risk tables (per planner and class; paired differences) as Markdown."""
    lines = ["# Ex-ante risk per class", "",
             "Per run: the mean over planning steps of the chosen trajectory's risk (P x harm) summed over",
             "the parties of the class; `total` = ego + third party. Mean over scenarios [95 % bootstrap CI],",
             "median, and the median of the per-run peak risk of a single party (total: the worst-off party).", "",
             "| Planner | Class | Mean [95 % CI] | Median | Peak (median) |", "| --- | --- | --- | --- | --- |"]
    for r in rt.to_dict("records"):
        lines.append(f"| {r['planner']} | {r['class']} | {r['mean']:.2e} [{r['ci_lo']:.2e}, {r['ci_hi']:.2e}] | "
                     f"{r['median']:.2e} | {r['peak_median']:.2e} |")
    if paired:
        lines += ["", f"Paired against {paired[0]['reference']}: mean difference (planner - reference) "
                  "[95 % paired bootstrap CI], scenarios lower / higher, Wilcoxon p. `risk_worst_peak`: the "
                  "largest risk on a single party; `harm_worst`: the largest harm booked to a single party "
                  "in the run (0 without a collision).", "",
                  "| Planner | Metric | Difference | Lower / higher | Wilcoxon p |", "| --- | --- | --- | --- | --- |"]
        for r in paired:
            lines.append(f"| {r['planner']} | {r['metric']} | {r['difference']:.2e} [{r['lo']:.2e}, {r['hi']:.2e}] | "
                         f"{r['lower']} / {r['higher']} | {r['wilcoxon_p']:.3g} |")
    return "\n".join(lines) + "\n"


def write_outputs(rows: list[dict[str, Any]], planners: list[PlannerSpec], out: Path, reference: str | None,
                  meta: dict[str, Any]) -> tuple[Path, Path]:
    import pandas as pd

    from sumo_ethics.analysis.exante import risk_boxplot, risk_table

    names = [p.name for p in planners]
    out.mkdir(parents=True, exist_ok=True)
    pd.DataFrame(rows).to_csv(out / "results.csv", index=False)
    t1, paired = table(rows, names, reference)
    pd.DataFrame(t1).to_csv(out / "table1.csv", index=False)
    if paired:
        pd.DataFrame(paired).to_csv(out / "paired.csv", index=False)
    bh = hazard_breakdown(rows, names)
    pd.DataFrame(bh).to_csv(out / "by_hazard.csv", index=False)
    st = safety_table(rows, names)
    pd.DataFrame(st).to_csv(out / "safety.csv", index=False)
    md = markdown(t1, paired, bh, meta)
    extra = safety_markdown(st)
    if extra:
        md = md.rstrip("\n") + "\n" + "\n".join(extra) + "\n"
    (out / "table1.md").write_text(md)
    df = pd.DataFrame(rows)
    if "risk_total_mean" in df and df["risk_total_mean"].notna().any():
        planned = [n for n in names if df.loc[df.planner == n, "risk_total_mean"].notna().any()]
        rt = risk_table(df[df.planner.isin(planned)], ["planner"])
        rt["order"] = rt.planner.map({n: i for i, n in enumerate(names)})
        rt = rt.sort_values(["order"], kind="stable").drop(columns="order")
        rt.to_csv(out / "risk.csv", index=False)
        pr = paired_risk(rows, planned, reference) if reference in planned else []
        if pr:
            pd.DataFrame(pr).to_csv(out / "risk_paired.csv", index=False)
        (out / "risk.md").write_text(risk_markdown(rt, pr))
        risk_boxplot(df[df.planner.isin(planned)], "planner", out / "figures", order=planned)
    (out / "meta.json").write_text(json.dumps(meta, indent=1, default=str))
    return out / "table1.csv", out / "table1.md"


def evaluate(suite: Path, planner_texts: list[str], out: Path, workers: int = 2, limit: int | None = None,
             reference: str | None = None, progress: Callable | None = None,
             resume: bool = False, record_decisions: str = "risky", mode: str = "replay",
             on_import: Callable[[str], None] | None = None, completion: str = "commonroad") -> tuple[Path, Path]:
    """Table 1 of ``suite``: a generated suite, or a folder of CommonRoad files (imported on the fly in
    ``mode`` with the ``completion`` rule, see sumo_ethics.suite.commonroad; failed imports are listed
    in OUT/imports.csv) or of imported CommonRoad folders."""
    from sumo_ethics.suite import commonroad
    from sumo_ethics.suite.spec import HAZARD_FILE, load_suite

    if limit is not None and not (isinstance(limit, int) and limit >= 1):
        raise ConfigError(f"--limit must be a whole number of scenarios, 1 or more, got {limit!r}")
    planners = parse_planners(planner_texts)
    names = [p.name for p in planners]
    ref = reference or ("origin" if "origin" in names else names[0])
    if ref not in names:
        raise ConfigError(f"--reference {ref!r} is not one of the planners {names}")
    t0 = time.perf_counter()
    extra: dict[str, Any] = {}
    if commonroad.is_input(suite) and not (Path(suite) / HAZARD_FILE).is_file() \
            and not any(Path(suite).glob(f"*/{HAZARD_FILE}")):
        folders, imports = commonroad.prepare(Path(suite), Path(out), mode, workers, on_import, completion)
        if not folders:
            raise ConfigError(f"none of the {len(imports)} CommonRoad files in {suite} imported; the causes are in "
                              f"{Path(out) / 'imports.csv'}")
        folders = folders[:limit] if limit is not None else folders
        failed = commonroad.failure_summary(imports)
        extra = {"commonroad_mode": mode, "commonroad_completion": completion, "imports": len(imports), "import_failures": dict(failed),
                 "import_seconds": float(sum(r["seconds"] for r in imports)), "import_wall_s": time.perf_counter() - t0}
    else:
        specs = load_suite(suite)  # validates every hazard file before anything runs
        if limit is not None:
            specs = specs[:limit]
        folders = [s.folder for s in specs if s.folder is not None]
        if len(folders) != len(specs):  # load_suite gives every scenario its folder
            raise ConfigError(f"a scenario of {suite} has no folder")
    rows = run_suite(folders, planners, Path(out), workers, progress, resume, record_decisions)
    if extra.get("commonroad_completion") == "origin":
        extra["late"] = {p.name: sum(bool(r.get("goal_late")) for r in rows if r["planner"] == p.name) for p in planners}
    meta = {"suite": str(suite), "scenarios": len(folders), "workers": workers, "wall_s": time.perf_counter() - t0,
            "planners": {p.name: p.describe() for p in planners}, "reference": ref, **extra}
    return write_outputs(rows, planners, Path(out), ref, meta)


def rows_from_runs(out: Path, suite: Path) -> list[dict[str, Any]]:
    """Result rows rebuilt from the run folders under ``out/runs`` (for an interrupted
    evaluation: only scenarios every planner has finished are kept, so the table stays paired)."""
    from sumo_ethics.suite.spec import load

    out, rows = Path(out), []
    planners = sorted(p.name for p in (out / "runs").iterdir() if p.is_dir())
    for p in planners:
        for run_dir in sorted((out / "runs" / p).iterdir()):
            data = read_summary(run_dir)
            if data is None:
                continue
            spec = load(Path(suite) / run_dir.name)
            h = data.get("harm", {})
            rows.append({"scenario": run_dir.name, "planner": p, "network": spec.network,
                         "hazard": ",".join(spec.hazard_types), "status": data.get("status", "error"),
                         "completed": bool(data.get("completed")), "total": float(h.get("total", 0.0)),
                         "ego": float(h.get("ego", 0.0)), "third_party": float(h.get("third_party", 0.0)),
                         "vru": float(h.get("vru", 0.0)), "wall_s": float(data.get("wall_time", 0.0))})
    done = {s for s in {r["scenario"] for r in rows} if sum(r["scenario"] == s for r in rows) == len(planners)}
    return [r for r in rows if r["scenario"] in done]
