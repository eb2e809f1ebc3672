"""Median latency of one LSTMPredictor.predict call: 32 agents, 3 s history at 0.1 s, one core.

    python tools/bench_predictor.py [--kind attention|cslstm] [--weights PATH] [--agents 32] [--repeats 200]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch


def make_observation(n_agents: int = 32, hist_s: float = 3.0, dt: float = 0.1, seed: int = 0):
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--kind", default="attention")
    ap.add_argument("--weights", default=None)
    ap.add_argument("--agents", type=int, default=32)
    ap.add_argument("--repeats", type=int, default=200)
    ap.add_argument("--horizon", type=int, default=20, help="output steps at 0.1 s")
    args = ap.parse_args()
    torch.set_num_threads(1)
    from sumo_ethics.predict.predictor import LSTMPredictor

    pred = LSTMPredictor.from_file(args.weights, kind=args.kind) if args.weights else LSTMPredictor.default(args.kind)
    obs = make_observation(args.agents)
    for _ in range(10):
        pred.predict(obs, args.horizon, 0.1)
    times, cpu = [], []
    for _ in range(args.repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        pred.predict(obs, args.horizon, 0.1)
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    ms, cms = np.array(times) * 1e3, np.array(cpu) * 1e3
    print(f"{pred.kind}: {args.agents} agents, median {np.median(ms):.2f} ms wall (p90 {np.percentile(ms, 90):.2f}), "
          f"median {np.median(cms):.2f} ms CPU, over {args.repeats} runs (torch threads {torch.get_num_threads()}; "
          f"wall time is inflated when other processes share the core)")


if __name__ == "__main__":
    main()
