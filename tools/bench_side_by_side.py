"""tools/bench_planner.py on this tree and on another checkout, interleaved, on one core.

    git worktree add /tmp/base 0996b73
    python tools/bench_side_by_side.py --base /tmp/base [--base /tmp/other ...] [--agents 20,60] [--rounds 5] [--repeats 100]
        [--threads 1,2]

Each round runs the planner benchmark once per tree and agent count, rotating the trees' order,
each in a fresh process running the tree's own ``tools/bench_planner.py`` (the same scene; only
its imports follow the tree's layout) with ``PYTHONPATH`` set to the tree, ``taskset -c 0`` where it exists, one
BLAS and torch thread); the table gives the median over rounds of each run's median step and
of its stages. The machines are shared: compare the two columns of one table, not tables of
different days.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import statistics
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]


def one(tree: Path, agents: int, repeats: int, predictor: str, threads: int = 1) -> dict[str, float]:
    env = dict(os.environ, PYTHONPATH=str(tree), OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1",
               MKL_NUM_THREADS="1", SUMO_ETHICS_THREADS=str(threads))
    # each tree's own copy of the benchmark: the scene is the same, the imports follow the tree's layout
    cmd = [sys.executable, str(tree / "tools" / "bench_planner.py"), "--predictor", predictor, "--agents",
           str(agents), "--repeats", str(repeats)]
    if shutil.which("taskset"):
        cmd = ["taskset", "-c", ",".join(str(c) for c in range(threads)), *cmd]
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True, cwd=tree).stdout
    row = {"step": float(re.search(r"median ([\d.]+) ms", out).group(1))}
    row.update({k: float(v) for k, v in re.findall(r"(\w+)_ms ([\d.]+) ms", out)})
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", type=Path, action="append", required=True,
                    help="another checkout (e.g. a worktree of 0996b73); repeat for several")
    ap.add_argument("--agents", default="20,60")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--repeats", type=int, default=100)
    ap.add_argument("--predictor", default="map")
    ap.add_argument("--threads", default="1", help="this tree's risk-kernel threads, one column each "
                    "(e.g. 1,2: the second on cores 0 and 1); the other trees run on core 0")
    a = ap.parse_args()
    counts_t = [int(t) for t in a.threads.split(",")]
    trees = {base.name: (base.resolve(), 1) for base in a.base}
    for t in counts_t:
        trees["this" if t == 1 else f"this, {t} threads"] = (HERE, t)
    names = list(trees)
    counts = [int(c) for c in a.agents.split(",")]
    runs: dict[tuple[str, int], list[dict[str, float]]] = {}
    for r in range(a.rounds):
        for n in counts:
            for name in names[r % len(names):] + names[:r % len(names)]:  # each tree first in turn
                runs.setdefault((name, n), []).append(one(trees[name][0], n, a.repeats, a.predictor, trees[name][1]))
    print(f"planning step, {a.predictor} predictor, one core unless said: median over {a.rounds} interleaved rounds "
          f"of each run's median over {a.repeats} steps [ms]")
    print("| agents | stage | " + " | ".join(names) + " |")
    print("| --- | --- | " + " | ".join("---" for _ in names) + " |")
    for n in counts:
        for key in runs[(names[-1], n)][0]:
            vals = [statistics.median(x.get(key, float("nan")) for x in runs[(name, n)]) for name in names]
            print(f"| {n} | {key} | " + " | ".join(f"{v:.2f}" for v in vals) + " |")


if __name__ == "__main__":
    main()
