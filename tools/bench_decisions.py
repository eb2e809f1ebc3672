"""What recording decisions costs: wall time and storage of suite runs with ``--record-decisions
risky`` (the default of evaluate and sweep) and ``all`` against the same runs with ``off``.

Each scenario of the suite (the first ``--scenarios``) runs with the paper planner in every mode,
the modes interleaved and repeated; reported are the median wall time per mode (whole run:
SUMO start to summary, including collision snapshot figures), the median ratio to ``off`` over
scenarios, and the decisions' storage per run. Runs of one scenario are identical in every mode
(recording does not change decisions; checked here on ``steps.parquet``).

    python tools/bench_decisions.py [--suite scenarios/suite] [--scenarios 6] [--repeats 3]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def one(spec, out: Path, mode: str) -> tuple[float, int, int, bytes]:
    from sumo_ethics.runner import make_controller, run
    from sumo_ethics.settings import planner_config
    from sumo_ethics.sim.hazards import HazardInjector
    from sumo_ethics.suite.outcome import snapshots_of

    cfg = spec.run_config(out, planner_config(None), record_decisions=mode, overwrite=True)
    s = run(cfg, controller=make_controller(cfg), hooks=(HazardInjector(spec.hazards),))
    s.data.update(snapshots_of(out))  # the figures are drawn from the folder after the run, as evaluate does
    dec = s.data.get("decisions", {})
    return s.data["wall_time"] + s.data.get("snapshot_wall", 0.0), dec.get("bytes", 0), dec.get("steps", 0), \
        (out / "steps.parquet").read_bytes()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--suite", type=Path, default=ROOT / "scenarios" / "suite")
    ap.add_argument("--scenarios", type=int, default=6)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--modes", default="off,risky,all")
    args = ap.parse_args()
    import torch

    torch.set_num_threads(1)
    from sumo_ethics.suite.spec import load_suite

    modes = args.modes.split(",")
    specs = load_suite(args.suite)[: args.scenarios]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for spec in specs:
            walls = {m: [] for m in modes}
            size = {}
            ref = None
            for _ in range(args.repeats):
                for m in modes:
                    w, b, n, steps = one(spec, Path(tmp) / f"{spec.name}-{m}", m)
                    walls[m].append(w)
                    size[m] = (b, n)
                    ref = ref or steps
                    assert steps == ref, f"{spec.name}: steps.parquet differs with --record-decisions {m}"
            med = {m: statistics.median(v) for m, v in walls.items()}
            rows.append((spec.name, med, size))
            print(f"{spec.name}: " + ", ".join(f"{m} {med[m]:.2f} s ({size[m][1]} steps, {size[m][0] / 1e6:.2f} MB)"
                                              for m in modes), flush=True)
    print()
    print("| mode | median wall / off (over scenarios) | max | decisions per run: median MB | max MB | "
          "median steps kept |")
    print("| --- | --- | --- | --- | --- | --- |")
    for m in modes:
        ratio = [r[1][m] / r[1]["off"] for r in rows] if "off" in modes else [float("nan")]
        mb = [r[2][m][0] / 1e6 for r in rows]
        print(f"| {m} | {statistics.median(ratio):.3f} | {max(ratio):.3f} | {statistics.median(mb):.2f} | "
              f"{max(mb):.2f} | {statistics.median([r[2][m][1] for r in rows]):.0f} |")


if __name__ == "__main__":
    main()
