"""How often does w_u change a decision? Counterfactual choices on the same scenes.

Runs suite scenarios with the planner at one w_u (default 0) and, at every planning step,
also works out which candidate every other w_u of ``--omega-u`` would have chosen from the
same candidates and cost terms (J_risk = w_o J_origin + w_u J_utility is linear in w_u, so the
alternatives need no rerun and every w_u meets identical scenes). Reports, per w_u, the share
of *risky* steps (some feasible candidate has non-zero risk) whose choice differs from the
w_u = 0 choice, and the mean total ex-ante risk of the chosen candidates.

    python tools/wu_decisions.py scenarios/dilemmas --limit 20 --omega-u 0,0.25,0.5,0.75,1 \
        --planner-set predictor=cv --out docs/wu_decisions.md
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import sys
from pathlib import Path

import numpy as np


def _run(args: tuple[str, dict, tuple[float, ...], str]) -> dict:
    scenario_dir, options, omegas, out_dir = args
    from sumo_ethics.plan.ethical import EthicalPlanner, hard_pool, select
    from sumo_ethics.runner import run
    from sumo_ethics.settings import planner_config
    from sumo_ethics.sim.hazards import HazardInjector
    from sumo_ethics.suite.spec import load

    records: list[tuple[bool, list[int], list[float]]] = []

    class Probe(EthicalPlanner):
        def choose(self, cost, classes, penalty, legal, on_road, first_hit, steps, travel):
            total, j, cls = super().choose(cost, classes, penalty, legal, on_road, first_hit, steps, travel)
            t = cost.terms
            risk = t["ego_risk_sum"] + t["other_risk_sum"]
            picks = []
            for wu in omegas:
                alt = self.cfg.cost.omega_o * t["j_origin"] + wu * t["j_utility"]
                if self.cfg.selection == "cost":
                    k = int(np.argmin(np.where(hard_pool(legal, on_road), alt + penalty, np.inf)))
                else:
                    ttc = self.cfg.selection == "validity_ttc"
                    k, _ = select(classes, alt, first_hit if ttc else None, steps, travel if ttc else None)
                picks.append(int(k))
            records.append((bool(np.any(risk > 0)), picks, [float(risk[k]) for k in picks]))
            return total, j, cls

    spec = load(Path(scenario_dir))
    pcfg = planner_config(None, **options)
    cfg = spec.run_config(Path(out_dir), pcfg, overwrite=True)
    try:
        run(cfg, controller=Probe(pcfg), hooks=(HazardInjector(spec.hazards),))
    except Exception as exc:  # noqa: BLE001 - a failed run still reports its steps
        print(f"{spec.name}: {exc}", file=sys.stderr)
    return {"scenario": spec.name, "records": records}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("suite", type=Path)
    ap.add_argument("--limit", type=int)
    ap.add_argument("--omega-u", default="0,0.1,0.25,0.5,0.75,1")
    ap.add_argument("--run-omega-u", type=float, default=0.0, help="w_u that drives the ego (default 0)")
    ap.add_argument("--planner-set", action="append", default=[], help="planner option key=value (repeat)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, help="Markdown file for the table")
    ap.add_argument("--runs", type=Path, default=Path("runs/wu_decisions"))
    a = ap.parse_args()
    omegas = tuple(float(v) for v in a.omega_u.split(","))
    if 0.0 not in omegas:
        omegas = (0.0, *omegas)
    options = {"omega_u": a.run_omega_u}
    for kv in a.planner_set:
        k, _, v = kv.partition("=")
        try:
            options[k] = json.loads(v)
        except ValueError:
            options[k] = v
    scen = sorted(p.parent for p in a.suite.glob("*/hazards.json"))[: a.limit]
    tasks = [(str(s), options, omegas, str(a.runs / s.name)) for s in scen]
    with mp.get_context("spawn").Pool(a.workers, maxtasksperchild=1) as pool:
        results = pool.map(_run, tasks, chunksize=1)
    i0 = omegas.index(0.0)
    risky = [(picks, risks) for res in results for r, picks, risks in res["records"] if r]
    i0_ = omegas.index(0.0)
    chosen_risky = [(p, rk) for p, rk in risky if rk[i0_] > 0]
    n_steps = sum(len(res["records"]) for res in results)
    lines = [f"# Decisions changed by w_u ({len(scen)} scenarios of {a.suite}, ego driven at w_u = {a.run_omega_u:g}, "
             f"options {json.dumps({k: v for k, v in options.items() if k != 'omega_u'})})", "",
             f"{n_steps} planning steps, {len(risky)} risky (some feasible candidate has non-zero risk), "
             f"{len(chosen_risky)} in which the w_u = 0 choice itself carries risk.", "",
             "| w_u | risky steps with another choice than w_u = 0 | of those where the w_u = 0 choice carries risk | "
             "scenarios with any change | mean total ex-ante risk of the choice (risky steps) |",
             "| --- | --- | --- | --- | --- |"]
    for i, wu in enumerate(omegas):
        changed = sum(p[i] != p[i0] for p, _ in risky)
        scen_changed = sum(any(p[i] != p[i0] for r, p, _ in res["records"] if r) for res in results)
        mean_risk = float(np.mean([rk[i] for _, rk in risky])) if risky else float("nan")
        share = 100.0 * changed / max(len(risky), 1)
        changed_c = sum(p[i] != p[i0] for p, _ in chosen_risky)
        share_c = 100.0 * changed_c / max(len(chosen_risky), 1)
        lines.append(f"| {wu:g} | {changed} ({share:.1f} %) | {changed_c} ({share_c:.1f} %) | {scen_changed} / {len(scen)} "
                     f"| {mean_risk:.3e} |")
    text = "\n".join(lines) + "\n\nCommand: `python tools/wu_decisions.py " + " ".join(sys.argv[1:]) + "`\n"
    print(text)
    if a.out:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(text)


if __name__ == "__main__":
    main()
