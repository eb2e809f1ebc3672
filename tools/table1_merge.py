"""Table 1 from the result rows of several `sumo-ethics evaluate` runs on the same suite.

    python tools/table1_merge.py OUT SOURCE [SOURCE ...] [--reference origin]

SOURCE is ``results.csv:planner,planner=new_name,...``: the rows of those planners in that
results.csv (renamed where ``=`` says so), so a planner changed since an evaluation can be run again
alone and set beside the others' earlier rows, e.g. the default planner after a change against
``origin``, ``paper`` and ``baseline`` of docs/table1-all and its own earlier rows:

    python tools/table1_merge.py docs/table1-evasive \\
        docs/table1-all/results.csv:origin,paper,ours=ours_before,baseline runs/t1_ours_ev/results.csv:ours

OUT gets what `evaluate` writes (table1.md with the paired differences, ego collisions per hazard and
the safety table; results.csv, paired.csv, by_hazard.csv, safety.csv, risk.md and the ex-ante risk
figure), over the scenarios every named planner has a row for (same scenario and seed).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

from sumo_ethics.suite.evaluate import PlannerSpec, write_outputs


def read(source: str) -> tuple[pd.DataFrame, dict[str, str]]:
    path, _, names = source.rpartition(":")
    if not path or not names:
        raise SystemExit(f"malformed SOURCE {source!r}: expected results.csv:planner,planner=new_name")
    rows = pd.read_csv(path)
    frames, order = [], {}
    for item in names.split(","):
        old, _, new = item.partition("=")
        part = rows[rows.planner == old].copy()
        if part.empty:
            raise SystemExit(f"{path} has no rows of planner {old!r}")
        part["planner"] = new or old
        frames.append(part)
        order[new or old] = f"`{old}` of {path}"
    return pd.concat(frames), order


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("sources", nargs="+")
    ap.add_argument("--reference", default="origin")
    ap.add_argument("--suite", default="scenarios/suite", help="the suite's name in the table's title")
    a = ap.parse_args()
    frames, names, described = [], [], {}
    for s in a.sources:
        f, n = read(s)
        frames.append(f)
        names += list(n)
        described.update(n)
    df = pd.concat(frames, ignore_index=True)
    if len(set(names)) != len(names):
        raise SystemExit(f"a planner name is given twice: {names}")
    # the scenarios every planner ran with the same seed
    keys = df.groupby(["scenario", "seed"]).planner.nunique()
    both = keys[keys == len(names)].index
    df = df.set_index(["scenario", "seed"]).loc[both].reset_index()
    rows = [{k: v for k, v in r.items() if not (isinstance(v, float) and pd.isna(v))} for r in df.to_dict("records")]
    # the runs' own wall times summed: the time of one worker running them all, not of one evaluation
    meta = {"suite": a.suite, "sources": a.sources, "scenarios": int(len(both)), "planners": described,
            "reference": a.reference, "wall_s": float(df.wall_s.sum()), "workers": None}
    _, md = write_outputs(rows, [PlannerSpec(n, {}) for n in names], a.out, a.reference, meta)  # meta.json too
    print(md.read_text())


if __name__ == "__main__":
    main()
