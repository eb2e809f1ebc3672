"""Replay against reactive on the same CommonRoad files, and both beside the published Table 1.

    python tools/commonroad_modes.py REPLAY_OUT REACTIVE_OUT

REPLAY_OUT and REACTIVE_OUT are two ``sumo-ethics evaluate`` folders (``results.csv``) of the same
CommonRoad files in ``--mode replay`` and ``--mode reactive``. Prints Markdown:

- per planner and mode, over the files both modes ran: completed, ego collisions, timeouts and the
  harm sums;
- per planner, how each file's outcome moves from replay to reactive;
- the published Table 1 (METHOD.md: Origin and the paper on 2000 CommonRoad scenarios) beside
  this project's, both as sums per 100 runs, so different numbers of runs compare.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pandas as pd

#: The paper's Table 1 (2000 CommonRoad 2020a scenarios, harm summed over all runs; METHOD.md §5).
PUBLISHED = {"origin": {"runs": 2000, "completed": 70.70, "total": 22.35, "ego": 11.50, "third_party": 10.84,
                        "vru": 3.11},
             "paper": {"runs": 2000, "completed": 77.95, "total": 18.16, "ego": 9.86, "third_party": 8.30,
                       "vru": 3.45}}
HARM = ("total", "ego", "third_party", "vru")
OUTCOMES = ("completed", "collision", "timeout", "error")


def _fault(run: Path) -> str:
    """Who caused the run's first booked ego collision (summary.json), '' without one."""
    try:
        f = json.loads((run / "summary.json").read_text())["collisions"]["fault"]
    except (OSError, ValueError, KeyError):
        return ""
    return max(f, key=f.get) if sum(f.values()) else ""


def _load(folder: Path, mode: str) -> pd.DataFrame:
    r = pd.read_csv(folder / "results.csv")
    r["file"] = r.scenario.str.removesuffix(f"-{mode}")
    r["outcome"] = r.status.where(r.status.isin(OUTCOMES), "error")
    r.loc[r.completed.astype(bool), "outcome"] = "completed"
    r["fault"] = [_fault(folder / "runs" / p / s) if o == "collision" else ""
                  for p, s, o in zip(r.planner, r.scenario, r.outcome)]
    return r


def tables(replay: Path, reactive: Path) -> str:
    a, b = _load(replay, "replay"), _load(reactive, "reactive")
    files = sorted(set(a.file) & set(b.file))
    a, b = a[a.file.isin(files)], b[b.file.isin(files)]
    planners = list(dict.fromkeys(a.planner))
    out = [f"{len(files)} files ran in both modes ({a.file.nunique()} in replay, "
           f"{_load(reactive, 'reactive').file.nunique()} in reactive).", "",
           "| planner | mode | completed | ego collisions (fault ego / other / unknown) | timeouts | errors | total harm | ego | "
           "third party | VRU |",
           "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for p in planners:
        for mode, r in (("replay", a), ("reactive", b)):
            s = r[r.planner == p]
            n = s.outcome.value_counts()
            out.append(f"| {p} | {mode} | {n.get('completed', 0)} / {len(s)} ({100 * n.get('completed', 0) / len(s):.1f} %) "
                       f"| {n.get('collision', 0)} ({' / '.join(str(int((s.fault == f).sum())) for f in ('ego', 'other', 'unknown'))}) "
                       f"| {n.get('timeout', 0)} | {n.get('error', 0)} | "
                       + " | ".join(f"{s[h].sum():.2f}" for h in HARM) + " |")
    out += ["", "Outcome per file, replay (rows) -> reactive (columns):", "",
            "| planner | replay | " + " | ".join(f"-> {o}" for o in OUTCOMES[:3]) + " |",
            "| --- | --- |" + " --- |" * 3]
    for p in planners:
        m = a[a.planner == p].set_index("file").outcome.to_frame("replay").join(
            b[b.planner == p].set_index("file").outcome.rename("reactive"))
        ct = pd.crosstab(m.replay, m.reactive)
        for o in OUTCOMES[:3]:
            if o in ct.index:
                out.append(f"| {p} | {o} | " + " | ".join(str(int(ct.loc[o].get(q, 0))) for q in OUTCOMES[:3]) + " |")
    out += ["", "Beside the published Table 1 (sums per 100 runs; completion in %):", "",
            "| source | algorithm | runs | completed (%) | total harm | ego | third party | VRU |",
            "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for p, v in PUBLISHED.items():
        out.append(f"| published, CommonRoad 2020a | {p} | {v['runs']} | {v['completed']:.1f} | "
                   + " | ".join(f"{100 * v[h] / v['runs']:.2f}" for h in HARM) + " |")
    for mode, r in (("replay", a), ("reactive", b)):
        for p in planners:
            s = r[r.planner == p]
            out.append(f"| here, {mode} | {p} | {len(s)} | {100 * s.completed.astype(bool).mean():.1f} | "
                       + " | ".join(f"{100 * s[h].sum() / len(s):.2f}" for h in HARM) + " |")
    return "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("replay", type=Path)
    ap.add_argument("reactive", type=Path)
    args = ap.parse_args()
    print(tables(args.replay, args.reactive))


if __name__ == "__main__":
    main()
