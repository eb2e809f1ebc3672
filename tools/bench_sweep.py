"""Benchmark: the same 20-run sweep with 1 and with 2 local workers; wall times and speed-up.

    python tools/bench_sweep.py [--scenario scenarios/urban/urban.sumocfg] [--end 60] [--workers 1,2]

Runs 20 runs (w_u 0:1:0.25 x seeds 0-3) of the ethical planner with constant-velocity
prediction into fresh temporary folders, once per worker count, and prints the load average
before and after (the machine may be shared: the speed-up is bounded by the free cores).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
import time
from pathlib import Path

from sumo_ethics.sweep import make_sweep, run_sweep

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", type=Path, default=ROOT / "scenarios" / "testbed" / "testbed.sumocfg")
    ap.add_argument("--omega-u", default="0:1:0.25")
    ap.add_argument("--seeds", default="0-3")
    ap.add_argument("--end", type=float, default=40.0)
    ap.add_argument("--ego-depart", type=float, default=2.0)
    ap.add_argument("--predictor", default="cv")
    ap.add_argument("--workers", default="1,2")
    ap.add_argument("--json", type=Path, help="Also write the figures here.")
    args = ap.parse_args()

    sw = make_sweep(args.scenario, args.omega_u, args.seeds,
                    options={"end": args.end, "ego_depart": args.ego_depart, "predictor": args.predictor})
    n = len(sw.specs())
    results = {"runs": n, "scenario": str(args.scenario), "end": args.end, "cpus": os.cpu_count(),
               "load_before": os.getloadavg(), "wall": {}}
    print(f"{n} runs of {args.scenario.name} (end {args.end:g} s, predictor {args.predictor}); "
          f"{os.cpu_count()} CPUs, load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    for w in (int(x) for x in args.workers.split(",")):
        tmp = Path(tempfile.mkdtemp(prefix=f"bench-sweep-{w}-"))
        try:
            t0 = time.perf_counter()
            res = run_sweep(sw, tmp / "sweep", workers=w, progress=False)
            wall = time.perf_counter() - t0
            params = [json.loads((p / "params.json").read_text()) for p in (tmp / "sweep" / "runs").iterdir()]
            run_walls = [p["wall_time"] for p in params]
            run_cpu = [p["cpu_time"] for p in params]
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        assert res.done == n and res.failed == 0, res
        results["wall"][w] = wall
        results.setdefault("run_wall_mean", {})[w] = sum(run_walls) / n
        results.setdefault("run_cpu_mean", {})[w] = sum(run_cpu) / n
        # runs in flight on average: near w means the pool kept every worker busy; a run's own
        # wall time growing with w means the workers share too few free cores
        busy = sum(run_walls) / wall
        print(f"  {w} worker(s): {wall:7.1f} s wall ({wall / n:.2f} s per run; a run's own wall time "
              f"mean {sum(run_walls) / n:.2f} s, CPU {sum(run_cpu) / n:.2f} s; {busy:.2f} runs in flight on average), "
              f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    ws = sorted(results["wall"])
    print("  (a run's wall time above its CPU time = waiting for a core: the machine is busy)")
    for w in ws[1:]:
        print(f"  speed-up {ws[0]} -> {w} workers: {results['wall'][ws[0]] / results['wall'][w]:.2f}x")
    results["load_after"] = os.getloadavg()
    if args.json:
        args.json.write_text(json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()
