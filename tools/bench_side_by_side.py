"""tools/bench_planner.py on this tree and on another checkout, interleaved, on one core.

    git worktree add /tmp/base 0996b73
    python tools/bench_side_by_side.py --base /tmp/base [--agents 20,60] [--rounds 5] [--repeats 100]

Each round runs the planner benchmark once per tree and agent count, alternating the trees,
each in a fresh process (``PYTHONPATH`` set to the tree, ``taskset -c 0`` where it exists, one
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


def one(tree: Path, agents: int, repeats: int, predictor: str) -> dict[str, float]:
    env = dict(os.environ, PYTHONPATH=str(tree), OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1",
               MKL_NUM_THREADS="1")
    cmd = [sys.executable, str(HERE / "tools" / "bench_planner.py"), "--predictor", predictor, "--agents",
           str(agents), "--repeats", str(repeats)]
    if shutil.which("taskset"):
        cmd = ["taskset", "-c", "0", *cmd]
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True, cwd=tree).stdout
    row = {"step": float(re.search(r"median ([\d.]+) ms", out).group(1))}
    row.update({k: float(v) for k, v in re.findall(r"(\w+)_ms ([\d.]+) ms", out)})
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", type=Path, required=True, help="the other checkout (e.g. a worktree of 0996b73)")
    ap.add_argument("--agents", default="20,60")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--repeats", type=int, default=100)
    ap.add_argument("--predictor", default="map")
    a = ap.parse_args()
    trees = {"base": a.base.resolve(), "this": HERE}
    counts = [int(c) for c in a.agents.split(",")]
    runs: dict[tuple[str, int], list[dict[str, float]]] = {}
    for r in range(a.rounds):
        for n in counts:
            for name in (("base", "this") if r % 2 == 0 else ("this", "base")):
                runs.setdefault((name, n), []).append(one(trees[name], n, a.repeats, a.predictor))
    print(f"planning step, {a.predictor} predictor, 1 core: median over {a.rounds} interleaved rounds of each "
          f"run's median over {a.repeats} steps [ms]")
    print("| agents | stage | base | this |")
    print("| --- | --- | --- | --- |")
    for n in counts:
        for key in runs[("this", n)][0]:
            vals = [statistics.median(x[key] for x in runs[(name, n)]) for name in ("base", "this")]
            print(f"| {n} | {key} | {vals[0]:.2f} | {vals[1]:.2f} |")


if __name__ == "__main__":
    main()
