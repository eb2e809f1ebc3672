"""Paired differences between the two fleets of a penetration sweep (``--set fleet=A,B``).

A vehicle's draw is the same at every penetration and under every fleet (common random
numbers), so the runs of fleet A and fleet B at the same penetration and seed are a pair. For each
outcome, the mean over the pairs (penetration > 0) of A minus B with a percentile bootstrap 95 % CI
over pairs (4,000 resamples, seed 0), and in how many pairs A is higher / lower:

- everyone's conflicts (the egos' and the others', ``conflicts_everyone=true``) per 100 vehicle-km;
- the egos' conflicts per 100 ego-km;
- all harm (every confirmed collision, every party) per 10^6 vehicle-km;
- the mean time loss per trip of the egos and of the other vehicles [s].

    python tools/fleet_paired.py runs/fleet_urban [--a ethical --b ego]
"""

from __future__ import annotations

import argparse

import numpy as np

from sumo_ethics.analysis import load

OUTCOMES = {
    "everyone's conflicts per 100 vehicle-km": lambda r: (r.conflicts_others + r.conflicts_total) / r.vehicle_km * 100,
    "the egos' conflicts per 100 ego-km": lambda r: r.conflicts_total / (r.distance / 1000) * 100,
    "all harm per 10^6 vehicle-km": lambda r: r.harm_all_total / r.vehicle_km * 1e6,
    "the egos' time loss per trip [s]": lambda r: r.time_loss_egos,
    "other vehicles' time loss per trip [s]": lambda r: r.time_loss_other_vehicles,
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sweep")
    ap.add_argument("--a", default="ethical")
    ap.add_argument("--b", default="ego")
    args = ap.parse_args()
    runs = load(args.sweep).runs
    runs = runs[runs["penetration"] > 0]
    rng = np.random.default_rng(0)
    print(f"| `{args.a}` minus `{args.b}` | mean difference [95 % CI] | pairs where `{args.a}` is higher / lower |")
    print("| --- | --- | --- |")
    for name, outcome in OUTCOMES.items():
        table = runs.assign(v=outcome(runs)).pivot_table(index=["penetration", "seed"], columns="fleet", values="v")
        d = (table[args.a] - table[args.b]).dropna().to_numpy()
        boot = rng.choice(d, (4000, len(d))).mean(axis=1)
        lo, hi = np.percentile(boot, [2.5, 97.5])
        print(f"| {name} | {d.mean():+,.2f} [{lo:,.2f}, {hi:,.2f}] | {int((d > 0).sum())} / {int((d < 0).sum())} |")
    print(f"\n{len(d)} pairs")


if __name__ == "__main__":
    main()
