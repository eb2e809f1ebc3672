"""Median latency of one LSTMPredictor.predict call: 32 agents, 3 s history at 0.1 s, one core.

    python tools/bench_predictor.py [--kind map|map_cslstm|attention|cslstm] [--weights PATH] [--agents 32] [--repeats 200]
    python tools/bench_predictor.py --compare map map_cslstm old=/path/old.pt   # interleaved
    python tools/bench_predictor.py --compare map --parts   # + the model's forward pass alone

``--parts`` also times each model's forward pass alone (its inputs captured from one call), in the
same round robin; the rest of a call is numpy: history resampling, neighbour and map features,
the world frame and the resampling to the planner's steps.

For the map-aware models (map, the default, and map_cslstm) the call includes building every agent's map features
from a synthetic lane graph: a 4-lane road (lanes r_0..r_3, 600 m) whose lanes each branch into
a straight and a turning successor at x = 100 m, so each agent has its current lane, two
branches ahead and its left/right neighbours (the libsumo reads of a real run, about 3 calls per
vehicle, are not included).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch


from sumo_ethics.predict.synthetic import lane_source, make_observation  # noqa: E402


def captured_forward(pred, obs, horizon: int):
    """A no-argument function running ``pred``'s model forward pass on the inputs of one predict call."""
    model = pred.model
    name = "scene_forward" if getattr(model, "nbr_frame", "target") == "agent" else "forward"
    inner, seen = getattr(model, name), {}

    def spy(*a, **k):
        seen.update(a=a, k=k)
        return inner(*a, **k)

    setattr(model, name, spy)
    try:
        pred.predict(obs, horizon, 0.1)
    finally:
        delattr(model, name)  # the class's method again

    def run():
        with torch.inference_mode():
            return inner(*seen["a"], **seen["k"])

    return run


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--kind", default="map", help="a shipped model (map, map_cslstm, attention, cslstm)")
    ap.add_argument("--weights", default=None, help="a weights file instead of the shipped one")
    ap.add_argument("--compare", nargs="+", metavar="NAME=FILE|KIND",
                    help="several models, timed in turn (round robin) so machine load hits them alike")
    ap.add_argument("--agents", type=int, default=32)
    ap.add_argument("--repeats", type=int, default=200)
    ap.add_argument("--horizon", type=int, default=20, help="output steps at 0.1 s")
    ap.add_argument("--parts", action="store_true", help="also time the model's forward pass alone")
    args = ap.parse_args()
    torch.set_num_threads(1)
    from sumo_ethics.predict.predictor import LSTMPredictor

    obs = make_observation(args.agents)
    specs = args.compare or [f"{args.kind}={args.weights}" if args.weights else args.kind]
    preds = {}
    for spec in specs:
        name, _, path = spec.partition("=")
        pred = LSTMPredictor.from_file(path) if path else LSTMPredictor.default(name)
        pred.map_source = lane_source(obs) if pred.uses_map else None
        preds[name] = pred
    for pred in preds.values():
        for _ in range(10):
            pred.predict(obs, args.horizon, 0.1)
    forward = {name: captured_forward(pred, obs, args.horizon) for name, pred in preds.items()} if args.parts else {}
    wall = {k: [] for k in preds}
    cpu = {k: [] for k in preds}
    model_cpu = {k: [] for k in forward}
    for _ in range(args.repeats):
        for name, pred in preds.items():
            t0, c0 = time.perf_counter(), time.process_time()
            pred.predict(obs, args.horizon, 0.1)
            wall[name].append(time.perf_counter() - t0)
            cpu[name].append(time.process_time() - c0)
            if name in forward:
                c0 = time.process_time()
                forward[name]()
                model_cpu[name].append(time.process_time() - c0)
    for name, pred in preds.items():
        ms, cms = np.array(wall[name]) * 1e3, np.array(cpu[name]) * 1e3
        frame = getattr(pred.model, "nbr_frame", "target")
        steps = getattr(pred.model, "dec_steps", pred.model.fut_steps)
        print(f"{name} ({pred.kind}, {pred.model.modes} mode(s), neighbours encoded per {frame}, {steps} decoder steps): "
              f"{args.agents} agents, median {np.median(ms):.2f} ms wall (p90 {np.percentile(ms, 90):.2f}), "
              f"median {np.median(cms):.2f} ms CPU, over {args.repeats} runs")
        if name in model_cpu:
            print(f"  of which the forward pass alone: median {np.median(model_cpu[name]) * 1e3:.2f} ms CPU")
    print(f"(torch threads {torch.get_num_threads()}; wall time is inflated when other processes share the core)")


if __name__ == "__main__":
    main()
