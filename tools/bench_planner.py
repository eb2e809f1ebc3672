"""Median wall time of one full planning step of the ethical planner, on one core.

K = 1020 candidates (4 horizons x 15 end speeds x 17 offsets) against N = 20 predicted agents
over a 4 s horizon at 0.1 s (T = 40): prediction, sampling, feasibility, collision
probability, harm, risk, every cost term, mean-path overlap and selection.

    OPENBLAS_NUM_THREADS=1 python tools/bench_planner.py [--predictor cv|map_cslstm|attention|...] [--repeats 200]

The map-aware predictors (map_cslstm, map) read the scene's three lanes from a synthetic lane
graph (:func:`lane_source`) instead of SUMO, no traffic lights.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from sumo_ethics.config import EgoVehicle  # noqa: E402
from sumo_ethics.geometry import Polyline  # noqa: E402
from sumo_ethics.contract import RoutePath, Scene  # noqa: E402
from sumo_ethics.plan.ethical import EthicalPlanner, PlannerConfig  # noqa: E402
from sumo_ethics.predict import registry  # noqa: E402
from sumo_ethics.plan.history import History  # noqa: E402
from sumo_ethics.types import AgentStates, RoadUserClass  # noqa: E402


def scene(n_agents: int, seed: int = 0) -> Scene:
    """A straight 3-lane road; agents spread 40 m behind to 90 m ahead of the ego (some close)."""
    rng = np.random.default_rng(seed)
    path = Polyline.from_points(np.stack([np.linspace(0, 1000, 1001), np.zeros(1001)], axis=-1))
    m = len(path.s)
    route = RoutePath(edges=("e",), path=path, lane_of_vertex=("e_0",) * m, speed_limit=np.full(m, 13.89),
                      left=np.full(m, 5.0), right=np.full(m, -1.6), links=())
    x = 100 + rng.uniform(-40, 90, n_agents)
    y = rng.choice([0.0, 3.2, 6.4, -3.0], n_agents) + rng.normal(0, 0.3, n_agents)
    cls = rng.choice([RoadUserClass.CAR, RoadUserClass.CAR, RoadUserClass.TRUCK, RoadUserClass.BICYCLE,
                      RoadUserClass.PEDESTRIAN], n_agents).astype(np.int8)
    length = np.choose(np.minimum(cls, 5), [4.5, 12.0, 12.0, 2.2, 1.8, 0.3])
    width = np.choose(np.minimum(cls, 5), [1.8, 2.5, 2.5, 0.9, 0.65, 0.5])
    speed = np.where(cls == RoadUserClass.PEDESTRIAN, 1.3, rng.uniform(5, 14, n_agents))
    yaw = np.where(cls == RoadUserClass.PEDESTRIAN, np.pi / 2, 0.0)
    others = AgentStates(tuple(f"a{i:02d}" for i in range(n_agents)), x, y, yaw, speed, np.zeros(n_agents), length,
                         width, np.full(n_agents, 1400.0), cls)
    ego = AgentStates(("ego",), np.array([100.0]), np.array([0.0]), np.zeros(1), np.array([12.0]), np.zeros(1),
                      np.array([4.508]), np.array([1.61]), np.array([1475.0]), np.zeros(1, np.int8))
    hist = History(0.1)
    for k in range(31):  # 3 s of straight-line history
        dtk = (k - 30) * 0.1
        hist.push(AgentStates(others.ids, x + speed * np.cos(yaw) * dtk, y + speed * np.sin(yaw) * dtk, yaw, speed,
                              others.accel, length, width, others.mass, cls))
    obs = hist.observation(0.0, ego, others)
    return Scene(time=0.0, dt=0.1, ego=ego, others=others, route=route, s=100.0, d=0.0, stop_s=None,
                 vehicle=EgoVehicle(), history=obs)


def lane_source(sc: Scene):
    """Map source of :func:`scene`'s road for the map-aware predictors: lanes e_0..e_2 at y = 0,
    3.2, 6.4 m from x = -100 to 1100 m; each vehicle on the nearest, pedestrians on none."""
    from sumo_ethics.predict import features as F

    ys = (0.0, 3.2, 6.4)
    graph = F.LaneGraph.build([f"e_{i}" for i in range(3)], [np.array([[-100.0, y], [1100.0, y]]) for y in ys],
                              np.full(3, 13.89), [(), (), ()])
    cur = sc.others

    def source(agent_ids, person):
        lane = np.where(person, -1, np.argmin(np.abs(cur.y[:, None] - np.array(ys)), axis=1))
        n = len(agent_ids)
        return graph, F.MapContext(lane, cur.x + 100.0, np.full(n, np.inf), np.zeros(n, dtype=np.int64))

    return source


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
