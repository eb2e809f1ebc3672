"""The README's first command on a fresh copy of the code, then again: does the first run pay for a compile?

Each repeat unpacks this checkout's HEAD into a new folder (no ``__pycache__``: neither Python's
bytecode nor numba's compiled kernels), then runs the README's first command there twice with
``PYTHONPATH`` on that folder (the installed dependencies as they are) and times both runs:

    sumo-ethics run scenarios/urban/urban.sumocfg --ego-depart 60 --seed 1

    python tools/bench_first_run.py [--repeats 3] [--threads auto]

It prints each pair, the medians and the ratio first / second (issue 55's goal: at most 1.5).
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
COMMAND = ["run", "scenarios/urban/urban.sumocfg", "--ego-depart", "60", "--seed", "1"]


def timed(tree: Path, out: Path, threads: str) -> float:
    env = dict(os.environ, PYTHONPATH=str(tree))
    env.pop("NUMBA_CACHE_DIR", None)  # numba's cache beside the fresh sources
    cmd = [sys.executable, "-m", "sumo_ethics.cli", *COMMAND, "--out", str(out), "--overwrite", "--quiet",
           "--threads", threads]
    t = time.perf_counter()
    subprocess.run(cmd, cwd=tree, env=env, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--threads", default="auto")
    a = ap.parse_args()
    pairs = []
    for r in range(a.repeats):
        tree = Path(tempfile.mkdtemp(prefix="first_run_"))
        try:
            archive = subprocess.run(["git", "archive", "HEAD"], cwd=ROOT, capture_output=True, check=True).stdout
            subprocess.run(["tar", "-x", "-C", str(tree)], input=archive, check=True)
            first = timed(tree, tree / "runs" / "first", a.threads)
            second = timed(tree, tree / "runs" / "second", a.threads)
        finally:
            shutil.rmtree(tree, ignore_errors=True)
        pairs.append((first, second))
        print(f"repeat {r + 1}: first run {first:.1f} s, second run {second:.1f} s ({first / second:.2f}x)", flush=True)
    f = statistics.median(p[0] for p in pairs)
    s = statistics.median(p[1] for p in pairs)
    print(f"median over {a.repeats}: first {f:.1f} s, second {s:.1f} s, first / second {f / s:.2f} "
          f"(threads {a.threads})")


if __name__ == "__main__":
    main()
