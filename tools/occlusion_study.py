"""The occlusion study's tables from ``sumo-ethics evaluate`` folders (docs/occlusion.md).

    python tools/occlusion_study.py runs/occ_main [runs/occ_held ...] [--reference ours]

Per folder (a suite's scenarios run with the omniscient planner and with occlusion, without and with
phantoms), per planner: runs, ego collisions (all, and with a pedestrian), harm (total,
VRU), completion, and the travel time on the scenarios every planner completed (mean, and its ratio
to the reference's, paired: the same scenarios); then each planner against the reference, paired
over the scenarios, with a 95 % bootstrap interval (2,000 resamples of the scenarios, seed 0) of the
difference in collisions, harm and completion.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd


def load(folder: Path) -> pd.DataFrame:
    df = pd.read_csv(folder / "results.csv")
    df["collided"] = df["status"].eq("collision")
    df["ped_hit"] = df["collided"] & df["collided_with"].fillna("").str.contains("pedestrian")
    return df


def boot(diff: np.ndarray, n: int = 2000, seed: int = 0) -> tuple[float, float]:
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(diff), (n, len(diff)))
    means = diff[idx].sum(axis=1)
    return float(np.percentile(means, 2.5)), float(np.percentile(means, 97.5))


def table(df: pd.DataFrame, reference: str) -> str:
    planners = list(dict.fromkeys(df["planner"]))
    done = df.pivot(index="scenario", columns="planner", values="completed").fillna(False)
    common = done.index[done.all(axis=1)]
    times = df[df["scenario"].isin(common)].pivot(index="scenario", columns="planner", values="drive_time")
    lines = [f"{df['scenario'].nunique()} scenarios; travel time over the {len(common)} every planner completed",
             "", "| planner | runs | ego collisions | with a pedestrian | total harm | VRU harm | completed (%) | "
             "travel time [s] | x reference |", "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for p in planners:
        d = df[df["planner"] == p]
        t = times[p].mean() if p in times else float("nan")
        ratio = (times[p] / times[reference]).mean() if p in times and reference in times else float("nan")
        lines.append(f"| {p} | {len(d)} | {int(d['collided'].sum())} | {int(d['ped_hit'].sum())} | {d['total'].sum():.3f} | "
                     f"{d['vru'].sum():.3f} | {100 * d['completed'].mean():.1f} | {t:.1f} | {ratio:.2f} |")
    lines += ["", f"Paired against `{reference}`: difference summed over the scenarios [95 % bootstrap CI]", "",
              "| planner | ego collisions | total harm | completed runs |", "| --- | --- | --- | --- |"]
    ref = df[df["planner"] == reference].set_index("scenario")
    for p in planners:
        if p == reference:
            continue
        d = df[df["planner"] == p].set_index("scenario").reindex(ref.index)
        cells = []
        for col in ("collided", "total", "completed"):
            diff = d[col].astype(float).to_numpy() - ref[col].astype(float).to_numpy()
            lo, hi = boot(diff)
            cells.append(f"{diff.sum():+.3g} [{lo:+.3g}, {hi:+.3g}]")
        lines.append(f"| {p} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folders", nargs="+", type=Path)
    ap.add_argument("--reference", default="ours")
    a = ap.parse_args(argv)
    for folder in a.folders:
        print(f"## {folder}\n")
        print(table(load(folder), a.reference))
        print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
