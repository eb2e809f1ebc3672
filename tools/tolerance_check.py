"""The risk's tolerance mode against its exact mode on real planning steps (issue 55).

Runs suite scenarios (with their hazards, as ``evaluate`` does) and a city scenario with the default
planner. At every planning step the same scene is also planned in the exact mode (tolerance 0, the
planner's state copied), and the two are compared:

- every (candidate, road user) risk term of the tolerance mode lies below the exact one by at most
  its slack, and every slack is at most the tolerance;
- the candidate the tolerance mode chose costs, in the exact mode's selection totals, at most the
  two candidates' cost bounds (:func:`sumo_ethics.ethics.cost.tolerance_bound`) more than the exact
  mode's choice; where the exact mode's two best candidates differ by more than those bounds, the
  choice is the same.

The run is driven by the tolerance mode (what the planner does), so the scenes are the planner's own.

    python tools/tolerance_check.py --suite scenarios/suite --scenarios 6 \\
        --city /path/to/Doerpfeldstr/all_modes.sumocfg --city-depart 50400 --city-end 50460 --out runs/tolcheck
"""

from __future__ import annotations

import argparse
import json
import statistics
from dataclasses import replace
from pathlib import Path

import numpy as np

import sumo_ethics.plan.ethical as E
from sumo_ethics.ethics.cost import tolerance_bound

TERMS = ("ego_risk", "other_risk", "ego_harm_max", "other_harm_max")
ROWS: list[dict] = []
WHERE = {"scenario": ""}
_plan = E.EthicalPlanner.plan


def _shadowed(self: E.EthicalPlanner, scene):  # type: ignore[no-untyped-def]
    """EthicalPlanner.plan, with the exact mode planned on the same scene first and compared."""
    pc = self.cfg.probability
    if pc.tolerance == 0.0 or pc.method != "shapes":
        return _plan(self, scene)
    exact = E.EthicalPlanner(replace(self.cfg, probability=replace(pc, tolerance=0.0)), predictor=self.predictor)
    exact._lateral, exact._accel, exact._sampling = self._lateral, self._accel, self._sampling
    got: list = []
    real = E.assess_risk

    def spy(*a, **k):  # type: ignore[no-untyped-def]
        r = real(*a, **k)
        got.append(r)
        return r

    E.assess_risk = spy
    try:
        de = _plan(exact, scene)
        dt = _plan(self, scene)
    finally:
        E.assess_risk = real
    if de.trace is None or dt.trace is None or len(got) != 2:  # nothing weighed (an emergency stop)
        return dt
    re_, rt = got
    row = {"scenario": WHERE["scenario"], "time": scene.time, "K": len(dt.trace.cost.total), "N": len(scene.others)}
    assert rt.slack is not None
    row["slack_max"] = float(rt.slack.max()) if rt.slack.size else 0.0
    worst_below, worst_over = 0.0, -np.inf
    for i, name in enumerate(TERMS):
        gap = getattr(re_, name) - getattr(rt, name)
        if gap.size:
            worst_below = min(worst_below, float(gap.min()))
            worst_over = max(worst_over, float((gap - rt.slack[i]).max()))
    row["term_below_exact_min"] = worst_below  # >= -1e-12: never above the exact term
    row["term_over_slack_max"] = worst_over if worst_over > -np.inf else 0.0  # <= 1e-12: within the slack
    bound = tolerance_bound(dt.trace.cost, rt, self.cfg.cost)
    je, jt = de.trace.chosen, dt.trace.chosen
    sel = de.trace.selection
    row["same_choice"] = bool(je == jt)
    row["exact_cost_of_choice_over_best"] = float(sel[jt] - sel[je])
    row["bounds"] = float(bound[jt] + bound[je])
    row["bound_median"] = float(np.median(bound))
    eligible = np.isfinite(sel) & de.trace.eligible
    best2 = np.sort(sel[eligible])[:2]
    row["exact_best_two_gap"] = float(best2[1] - best2[0]) if len(best2) == 2 else float("inf")
    row["ok"] = bool(row["term_below_exact_min"] >= -1e-12 and row["term_over_slack_max"] <= 1e-12
                     and row["slack_max"] <= pc.tolerance + 1e-15
                     and row["exact_cost_of_choice_over_best"] <= row["bounds"] + 1e-9)
    ROWS.append(row)
    return dt


def run_suite(suite: Path, count: int, out: Path) -> None:
    from sumo_ethics.suite.evaluate import parse_planner, run_one

    spec = parse_planner("ours")
    for d in sorted(p for p in suite.iterdir() if (p / "hazards.json").is_file())[:count]:
        WHERE["scenario"] = f"suite/{d.name}"
        row = run_one(str(d), spec, str(out / "suite" / d.name), "off")
        print(f"{d.name}: {row.get('status')} ({sum(r['scenario'] == WHERE['scenario'] for r in ROWS)} steps)",
              flush=True)


def run_city(cfg_path: Path, depart: float, end: float, seed: int, out: Path) -> None:
    from sumo_ethics.config import RunConfig
    from sumo_ethics.runner import make_controller, run

    WHERE["scenario"] = f"city/{cfg_path.stem}"
    cfg = RunConfig(scenario=cfg_path, out=out / "city", seed=seed, end=end, ego_depart=depart, progress=False,
                    overwrite=True)
    s = run(cfg, controller=make_controller(cfg))
    print(f"{cfg_path.name}: {s.data['status']} ({sum(r['scenario'] == WHERE['scenario'] for r in ROWS)} steps)",
          flush=True)


def main() -> None:
    import pandas as pd

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--suite", type=Path, default=Path("scenarios/suite"))
    ap.add_argument("--scenarios", type=int, default=6, help="the suite's first N scenarios (0: none)")
    ap.add_argument("--city", type=Path, help="a city scenario's .sumocfg (its own ego inserted)")
    ap.add_argument("--city-depart", type=float, default=0.0)
    ap.add_argument("--city-end", type=float, default=60.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", type=Path, default=Path("runs/tolcheck"))
    a = ap.parse_args()
    E.EthicalPlanner.plan = _shadowed  # type: ignore[method-assign]
    a.out.mkdir(parents=True, exist_ok=True)
    if a.scenarios:
        run_suite(a.suite, a.scenarios, a.out)
    if a.city is not None:
        run_city(a.city, a.city_depart, a.city_end, a.seed, a.out)
    df = pd.DataFrame(ROWS)
    df.to_csv(a.out / "steps.csv", index=False)
    by = df.groupby(df.scenario.str.split("/").str[0])
    summary = {}
    for name, g in list(by) + [("all", df)]:
        differ = g[~g.same_choice]
        clear = g.exact_best_two_gap > g.bounds
        summary[name] = {
            "steps": len(g), "ok": int(g.ok.sum()), "same_choice": int(g.same_choice.sum()),
            "same_choice_where_best_two_differ_by_more_than_the_bounds": f"{int(g[clear].same_choice.sum())} of {int(clear.sum())}",
            "largest_slack": float(g.slack_max.max()), "term_below_exact_min": float(g.term_below_exact_min.min()),
            "term_over_slack_max": float(g.term_over_slack_max.max()),
            "median_bound_per_candidate": float(statistics.median(g.bound_median)),
            "different_choices_exact_cost_over_best_max": float(differ.exact_cost_of_choice_over_best.max())
            if len(differ) else 0.0,
        }
    (a.out / "summary.json").write_text(json.dumps(summary, indent=2))
    print(json.dumps(summary, indent=2))


if __name__ == "__main__":
    main()
