"""The same planner names in two evaluations, paired: NEW's result minus OLD's, per planner.

    python tools/compare_evaluations.py OLD NEW [--label-old paper --label-new ours] [--planner ours keep]

OLD and NEW are `sumo-ethics evaluate` output folders (their results.csv). For every planner name in
both, over the scenarios both ran (same scenario, same seed): completion and total / ego / third-party
/ VRU harm summed over the runs in each, and NEW minus OLD with a 95 % paired bootstrap CI over
scenarios, how many scenarios are better / worse, and the Wilcoxon p (Table 1's own statistics,
sumo_ethics.suite.evaluate.table). Also conflicts and over-cautious brakings per 100 ego-km of each.
Used for the dilemma study on `ours` against the same presets on `paper`'s settings.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

from sumo_ethics.suite.evaluate import safety_table, table


def rows(folder: Path) -> pd.DataFrame:
    r = pd.read_csv(folder / "results.csv")
    return r[r["status"] != "error"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("old", type=Path)
    ap.add_argument("new", type=Path)
    ap.add_argument("--label-old", default="old")
    ap.add_argument("--label-new", default="new")
    ap.add_argument("--planner", nargs=2, metavar=("OLD_NAME", "NEW_NAME"),
                    help="pair planner OLD_NAME of OLD with NEW_NAME of NEW (shown as OLD_NAME) instead of equal names")
    a = ap.parse_args()
    old, new = rows(a.old), rows(a.new)
    if a.planner:
        old = old[old.planner == a.planner[0]]
        new = new[new.planner == a.planner[1]].assign(planner=a.planner[0])
    lo, ln = a.label_old, a.label_new
    print(f"| planner | scenarios | completed {lo} / {ln} | total harm {lo} / {ln} | {ln} - {lo}: total harm "
          f"[95 % CI] (better / worse) | ego | third party | VRU | conflicts / 100 km {lo} / {ln} "
          f"| over-cautious / 100 km {lo} / {ln} |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for p in [p for p in new["planner"].unique() if p in set(old["planner"])]:
        o, n = old[old.planner == p], new[new.planner == p]
        both = sorted(set(zip(o.scenario, o.seed)) & set(zip(n.scenario, n.seed)))
        keep = {s for s, _ in both}
        o, n = o[o.scenario.isin(keep)], n[n.scenario.isin(keep)]
        recs = [r | {"planner": lo} for r in o.to_dict("records")] + [r | {"planner": ln} for r in n.to_dict("records")]
        t1, paired = table(recs, [lo, ln], reference=lo)
        by = {r["planner"]: r for r in t1}
        d = {r["metric"]: r for r in paired}
        rate = {r["planner"]: r for r in safety_table(recs, [lo, ln])}  # per 100 ego-km

        def diff(k: str, d: dict = d) -> str:
            r = d[k]
            return f"{r['difference']:+.2f} [{r['lo']:+.2f}, {r['hi']:+.2f}]"

        print(f"| {p} | {len(keep)} | {by[lo]['completed']:.0f} / {by[ln]['completed']:.0f} % "
              f"| {by[lo]['total']:.2f} / {by[ln]['total']:.2f} | {diff('total')} ({d['total']['better']} / "
              f"{d['total']['worse']}) | {diff('ego')} | {diff('third_party')} | {diff('vru')} "
              f"| {rate[lo]['conflicts_total_per_100km']:.0f} / {rate[ln]['conflicts_total_per_100km']:.0f} "
              f"| {rate[lo]['overcautious_per_100km']:.0f} / {rate[ln]['overcautious_per_100km']:.0f} |")


if __name__ == "__main__":
    main()
