"""Synthetic predictor inputs without SUMO, for benchmarks (tools/bench_predictor.py) and tests.

:func:`make_observation`: n road users on a 4-lane road (a few pedestrians) with straight 3 s
histories; :func:`lane_source`: a synthetic lane graph for them, lanes r_0..r_3 (600 m) that each
branch into a straight and a turning successor at x = 100 m, so each road user has its current
lane, two branches ahead and its left/right neighbours.
"""

from __future__ import annotations

from typing import Any

import numpy as np


def make_observation(n_agents: int = 32, hist_s: float = 3.0, dt: float = 0.1, seed: int = 0) -> Any:
    """Synthetic scene: n agents on a 4-lane road (a few pedestrians), straight 3 s histories."""
    from sumo_ethics.types import AgentStates, Observation, RoadUserClass

    rng = np.random.default_rng(seed)
    h = int(round(hist_s / dt)) + 1
    x0 = rng.uniform(-60, 60, n_agents)
    y0 = rng.integers(0, 4, n_agents) * 3.5
    speed = rng.uniform(5, 15, n_agents)
    cls = np.full(n_agents, int(RoadUserClass.CAR), dtype=np.int8)
    cls[: n_agents // 8] = int(RoadUserClass.PEDESTRIAN)
    speed[: n_agents // 8] = 1.3
    y0[: n_agents // 8] = -3.0
    yaw = np.zeros(n_agents)
    t = (np.arange(h) - (h - 1)) * dt
    hist = np.stack([x0[:, None] + speed[:, None] * t, np.repeat(y0[:, None], h, 1)], -1)
    z = np.zeros(n_agents)
    cur = AgentStates(tuple(f"a{i}" for i in range(n_agents)), x0, y0.astype(float), yaw, speed, z, z + 4.5, z + 1.8, z + 1500, cls)
    ego = AgentStates(("ego",), np.array([0.0]), np.array([3.5]), np.zeros(1), np.array([10.0]), np.zeros(1),
                      np.array([4.5]), np.array([1.8]), np.array([1500.0]), np.array([0], dtype=np.int8))
    return Observation(time=0.0, dt=dt, history=hist, valid=np.ones(hist.shape[:2], dtype=bool), current=cur, ego=ego)


def lane_source(obs: Any) -> Any:
    """A map source for make_observation's road (see the module docstring)."""
    from sumo_ethics.predict import features as F

    ids, shapes, links = [], [], []
    for i in range(4):
        y = i * 3.5
        ids += [f"r_{i}", f"s_{i}", f"t_{i}"]
        shapes += [np.array([[-300.0, y], [100.0, y]]), np.array([[100.0, y], [400.0, y]]),
                   np.array([[100.0, y], [110.0, y + 5.0], [115.0, y + 60.0]])]
        links += [(f"s_{i}", f"t_{i}"), (), ()]
    graph = F.LaneGraph.build(ids, shapes, np.full(len(ids), 13.9), links)
    cur = obs.current

    def source(agent_ids: Any, person: Any) -> Any:
        lane = np.where(person, -1, 3 * np.clip(np.round(cur.y / 3.5), 0, 3).astype(np.int64))
        return graph, F.MapContext(lane, cur.x + 300.0, np.full(len(agent_ids), 40.0), np.full(len(agent_ids), 3))

    return source
