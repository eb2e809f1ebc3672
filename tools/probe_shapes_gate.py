"""Where the "shapes" collision probability spends its time: per predicted mode, the (k, n, t)
entries the geometric gate lets through, how many the slab quick exits settle (P = 0 or 1), how
many need the polygon integral, the agents' spread and the kernel's wall time; and how many the
planner's bounded search (sumo_ethics.ethics.search) integrates on the same entries, and its time;
and the (candidate, road user) pairs at risk, each of which needs at least one integral in any exact
search (the step holding its maximum of P x harm must be integrated to know that maximum to the
bit): times the time of one integral, a floor under the risk's time that no tighter bound can lower.

    OPENBLAS_NUM_THREADS=1 python tools/probe_shapes_gate.py [--agents 20,60] [--predictor map] [--uncalibrated]

Same synthetic scene as tools/bench_planner.py (1023 candidates, 40 steps, the map predictor).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numba  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
import bench_planner  # noqa: E402

from sumo_ethics.ethics import search  # noqa: E402
from sumo_ethics.ethics import shapes as S  # noqa: E402
from sumo_ethics.plan.ethical import EthicalPlanner, PlannerConfig  # noqa: E402


@numba.njit(cache=False)
def _count(ex, ey, eyaw, evalid, mx, my, psi, sxx, sxy, syy, oa, ob, ea, eb, z):
    """valid (k, n, t), gated, P = 0 by the slabs, P = 1 by the slabs, integrated."""
    K, _ = ex.shape
    N, tp = mx.shape
    r_e = math.sqrt(ea * ea + eb * eb)
    c = np.zeros(5, np.int64)
    buf = np.empty((4, 8))
    for k in range(K):
        for n in range(N):
            r_o = math.sqrt(oa[n] ** 2 + ob[n] ** 2)
            for t in range(tp):
                if not evalid[k, t]:
                    continue
                c[0] += 1
                rad = r_e + r_o + z * math.sqrt(sxx[n, t] + syy[n, t])
                dx = mx[n, t] - ex[k, t]
                dy = my[n, t] - ey[k, t]
                if dx * dx + dy * dy > rad * rad:
                    continue
                c[1] += 1
                p = S._entry_p(dx, dy, math.cos(eyaw[k, t]), math.sin(eyaw[k, t]), ea, eb, math.cos(psi[n, t]),
                               math.sin(psi[n, t]), oa[n], ob[n], sxx[n, t], sxy[n, t], syy[n, t], z, buf)
                c[2 if p == 0.0 else 3 if p == 1.0 else 4] += 1
    return c


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--agents", default="20,60")
    ap.add_argument("--predictor", default="map")
    ap.add_argument("--uncalibrated", action="store_true")
    a = ap.parse_args()
    calls: list[tuple] = []
    real = search.bounded_entries

    def spy(*args):
        calls.append(args)
        return real(*args)

    search.bounded_entries = spy  # what the planner calls (probability.bounded_shapes_entries)
    print("| agents | mode | median sigma_max at 4 s [m] | valid (k, n, t) | gated | P = 0 (slabs) | P = 1 (slabs) "
          "| integrated | exhaustive kernel [ms] | integrated by the search | search kernel [ms] "
          "| (k, n) at risk: integrals any exact search needs |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for n_agents in (int(v) for v in a.agents.split(",")):
        calls.clear()
        sc = bench_planner.scene(n_agents)
        planner = EthicalPlanner(PlannerConfig(predictor=a.predictor, calibrated=not a.uncalibrated))
        if hasattr(planner.predictor, "map_source"):  # the map-aware LSTMs (their source is None until set)
            planner.predictor.map_source = bench_planner.lane_source(sc)
        planner.act(sc)
        for m, args in enumerate(calls):
            f = np.ascontiguousarray
            # the exhaustive kernel's arguments: ego x, y, yaw, valid; agent x, y, yaw, sxx, sxy, syy
            arr = [f(args[i], dtype=float) for i in (0, 1, 2, 4, 5, 6, 7, 9, 10, 11)]
            arr[3] = f(args[4], dtype=np.bool_)
            c = _count(*arr, f(np.asarray(args[12]) / 2), f(np.asarray(args[13]) / 2), args[14] / 2, args[15] / 2,
                       args[16])
            full_args = (*[args[i] for i in (0, 1, 2, 4, 5, 6, 7, 9, 10, 11, 12, 13, 14, 15, 16, 17)],)
            walls, walls_s = [], []
            for _ in range(3):
                w = time.perf_counter()
                S.shapes_sparse(*full_args)
                walls.append(time.perf_counter() - w)
                w = time.perf_counter()
                _, _, _, _, at_risk, counts = real(*args)
                walls_s.append(time.perf_counter() - w)
            sig = np.sqrt(np.maximum(args[9], args[11]))[:, -1]
            print(f"| {n_agents} | {m} | {np.median(sig):.2f} | {c[0]:,} | {c[1]:,} | {c[2]:,} | {c[3]:,} | {c[4]:,} "
                  f"| {1e3 * min(walls):.0f} | {counts[1]:,} | {1e3 * min(walls_s):.0f} | {int(at_risk.sum()):,} |")


if __name__ == "__main__":
    main()
