"""Median wall time of one full planning step of the ethical planner, on one core.

K = 1020 candidates (4 horizons x 15 end speeds x 17 offsets) against N = 20 predicted agents
over a 4 s horizon at 0.1 s (T = 40): prediction, sampling, feasibility, collision
probability, harm, risk, every cost term, mean-path overlap and selection.

    OPENBLAS_NUM_THREADS=1 python tools/bench_planner.py [--predictor cv|map_cslstm|attention|...] [--repeats 200]

The map-aware predictors (map_cslstm, map) read the scene's three lanes from a synthetic lane
graph (:func:`sumo_ethics.plan.synthetic.lane_source`) instead of SUMO, no traffic lights.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from sumo_ethics.plan.ethical import EthicalPlanner, PlannerConfig  # noqa: E402
from sumo_ethics.plan.synthetic import lane_source, scene  # noqa: E402
from sumo_ethics.predict import registry  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--predictor", default="cv", choices=registry.names())
    ap.add_argument("--agents", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=200)
    a = ap.parse_args()
    try:
        import torch

        torch.set_num_threads(1)
    except ImportError:
        pass
    sc = scene(a.agents)
    planner = EthicalPlanner(PlannerConfig(predictor=a.predictor))
    if hasattr(planner.predictor, "map_source"):  # the map-aware LSTMs (their source is None until set)
        planner.predictor.map_source = lane_source(sc)  # no SUMO here (see the module docstring)
    for _ in range(10):
        d = planner.act(sc)
    times, parts = [], {}
    for _ in range(a.repeats):
        w = time.perf_counter()
        d = planner.act(sc)
        times.append(1e3 * (time.perf_counter() - w))
        for k, v in d.timings_ms.items():
            parts.setdefault(k, []).append(v)
    print(f"{int(d.info['n_candidates'])} candidates x {a.agents} agents x 40 steps, predictor {a.predictor}: "
          f"median {statistics.median(times):.2f} ms, p90 {np.percentile(times, 90):.2f} ms over {a.repeats} steps")
    print("  median per stage: " + ", ".join(f"{k} {statistics.median(v):.2f} ms" for k, v in parts.items()))


if __name__ == "__main__":
    main()
