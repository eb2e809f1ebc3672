#!/usr/bin/env python3
"""Time `sumo-ethics evaluate` against scenario count and workers.

    python tools/bench_evaluate.py [--suite scenarios/suite] [--counts 4,8,16] [--workers 1,2]
                                   [--planner origin] [--out runs/bench-evaluate]

For each (count, workers) it evaluates the first `count` scenarios with the planner(s) and
prints wall time, runs per minute and the projected time for the full suite.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--suite", default="scenarios/suite")
    ap.add_argument("--counts", default="4,8,16")
    ap.add_argument("--workers", default="1,2")
    ap.add_argument("--planner", action="append", default=None)
    ap.add_argument("--out", default="runs/bench-evaluate")
    a = ap.parse_args()
    from sumo_ethics.suite.evaluate import evaluate
    from sumo_ethics.suite.spec import load_suite

    total = len(load_suite(Path(a.suite)))
    planners = a.planner or ["origin"]
    rows = []
    for w in (int(x) for x in a.workers.split(",")):
        for n in (int(x) for x in a.counts.split(",")):
            t0 = time.perf_counter()
            evaluate(Path(a.suite), planners, Path(a.out) / f"n{n}-w{w}", workers=w, limit=n)
            wall = time.perf_counter() - t0
            runs = n * len(planners)
            row = {"scenarios": n, "workers": w, "planners": len(planners), "wall_s": round(wall, 1),
                   "s_per_run": round(wall / runs, 2),
                   "projected_full_suite_min": round(wall / runs * total * len(planners) / 60, 1)}
            rows.append(row)
            print(json.dumps(row), flush=True)
    Path(a.out).mkdir(parents=True, exist_ok=True)
    (Path(a.out) / "bench.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
