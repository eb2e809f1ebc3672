"""What measuring conflicts costs: wall time of suite runs with conflicts on against the same
runs with ``[conflicts] enabled = false``.

Each scenario of the suite (the first ``--scenarios``) runs with the chosen controller (the
paper planner with the constant-velocity predictor by default, ``--predictor map`` for the
shipped LSTM, ``--controller baseline`` for the cheapest controller, where the share is largest)
with conflicts off and on, interleaved and repeated. Reported per scenario: the median wall
time of each (whole run: SUMO start to summary), their ratio, and from the runs with conflicts
the median share of ``conflict_ms`` (summed over the steps) in the step loop (``loop_wall``), the
figure least disturbed by other jobs on a shared machine; also the ratio of the median CPU times
(the process's, SUMO included: libsumo runs in it). One run before the timed ones is discarded (imports,
numba compilation). ``steps.parquet`` is checked to be the same with
and without conflicts (measuring changes nothing the ego does).

    python tools/bench_conflicts.py [--suite scenarios/suite] [--scenarios 4] [--repeats 3]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def one(spec, out: Path, on: bool, controller: str, predictor: str) -> tuple[float, float, float, int, bytes]:
    """(wall s, CPU s, conflict share of the loop, steps, steps.parquet bytes) of one run."""
    import time

    import pandas as pd

    from sumo_ethics.config import ConflictConfig
    from sumo_ethics.runner import make_controller, run
    from sumo_ethics.settings import planner_config
    from sumo_ethics.sim.hazards import HazardInjector

    cfg = spec.run_config(out, planner_config(None, predictor=predictor), overwrite=True)
    cfg = replace(cfg, controller=controller, conflicts=ConflictConfig(enabled=on))
    cpu = time.process_time()
    s = run(cfg, controller=make_controller(cfg), hooks=(HazardInjector(spec.hazards),))
    cpu = time.process_time() - cpu
    share = 0.0
    if on:
        ms = pd.read_parquet(out / "timings.parquet", columns=["conflict_ms"])["conflict_ms"]
        share = float(ms.sum()) / 1e3 / s.data["loop_wall"]
    return s.data["wall_time"], cpu, share, s.data["steps"], (out / "steps.parquet").read_bytes()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--suite", type=Path, default=ROOT / "scenarios" / "suite")
    ap.add_argument("--scenarios", type=int, default=4)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--controller", default="ethical", choices=["ethical", "baseline"])
    ap.add_argument("--predictor", default="cv")
    args = ap.parse_args()
    if args.scenarios < 1 or args.repeats < 1:
        raise SystemExit("error: --scenarios and --repeats must be at least 1")
    import torch

    torch.set_num_threads(1)
    from sumo_ethics.suite.spec import load_suite

    specs = load_suite(args.suite)[: args.scenarios]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        one(specs[0], Path(tmp) / "warmup", True, args.controller, args.predictor)  # imports, numba compiles
        for spec in specs:
            walls: dict[bool, list[float]] = {False: [], True: []}
            cpus: dict[bool, list[float]] = {False: [], True: []}
            shares, ref, n = [], None, 0
            for r in range(args.repeats):
                for on in ((False, True) if r % 2 == 0 else (True, False)):  # interleaved, order alternating
                    w, cpu, share, n, steps = one(spec, Path(tmp) / f"{spec.name}-{int(on)}", on, args.controller,
                                                  args.predictor)
                    walls[on].append(w)
                    cpus[on].append(cpu)
                    if on:
                        shares.append(share)
                    ref = ref or steps
                    assert steps == ref, f"{spec.name}: steps.parquet differs with conflicts {'on' if on else 'off'}"
            off, on_ = statistics.median(walls[False]), statistics.median(walls[True])
            cpu_ratio = statistics.median(cpus[True]) / statistics.median(cpus[False])
            rows.append((spec.name, n, off, on_, on_ / off, cpu_ratio, statistics.median(shares)))
            print(f"{spec.name}: {n} steps, off {off:.2f} s, on {on_:.2f} s, ratio {on_ / off:.3f} (CPU {cpu_ratio:.3f}), "
                  f"conflicts {100 * statistics.median(shares):.2f} % of the loop", flush=True)
    print()
    print(f"controller {args.controller}" + (f", predictor {args.predictor}" if args.controller == "ethical" else "")
          + f", {args.repeats} repeats, medians")
    print("| scenario | steps | wall off [s] | wall on [s] | wall on / off | CPU on / off | conflict_ms / loop |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for name, n, off, on_, ratio, cpu_ratio, share in rows:
        print(f"| {name} | {n} | {off:.2f} | {on_:.2f} | {ratio:.3f} | {cpu_ratio:.3f} | {100 * share:.2f} % |")
    print(f"| median over scenarios | | | | {statistics.median(r[4] for r in rows):.3f} | "
          f"{statistics.median(r[5] for r in rows):.3f} | {100 * statistics.median(r[6] for r in rows):.2f} % |")


if __name__ == "__main__":
    main()
