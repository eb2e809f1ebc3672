"""Paired differences between two fleets of penetration sweeps (``--set fleet=A,B``).

A vehicle's draw is the same at every penetration and under every fleet (common random
numbers), so the runs of fleet A and fleet B at the same penetration and seed are a pair. For each
outcome, the mean over the pairs (penetration > 0) of A minus B with a percentile bootstrap 95 % CI
over pairs (``analysis.stats.bootstrap_ci``, 4,000 resamples, seed 0), and in how many pairs A is
higher / lower:

- everyone's conflicts (the egos' and the others', ``conflicts_everyone=true``) per 100 vehicle-km;
- the egos' conflicts per 100 ego-km;
- all harm (every confirmed collision, every party) per 10^6 vehicle-km;
- the mean time loss per trip of the egos and of the other vehicles [s].

With a second sweep, fleet B's runs come from it (the same scenario and seeds, another setting:
e.g. ``--set normalise=at_risk``); only the penetrations both swept are paired.

    python tools/fleet_paired.py runs/fleet_urban [--a ethical --b ego]
    python tools/fleet_paired.py runs/fleet_urban_atrisk runs/fleet_urban --a ethical --b ego
"""

from __future__ import annotations

import argparse

from sumo_ethics.analysis import load
from sumo_ethics.analysis.stats import bootstrap_ci

OUTCOMES = {
    "everyone's conflicts per 100 vehicle-km": lambda r: (r.conflicts_others + r.conflicts_total) / r.vehicle_km * 100,
    "the egos' conflicts per 100 ego-km": lambda r: r.conflicts_total / (r.distance / 1000) * 100,
    "all harm per 10^6 vehicle-km": lambda r: r.harm_all_total / r.vehicle_km * 1e6,
    "the egos' time loss per trip [s]": lambda r: r.time_loss_egos,
    "other vehicles' time loss per trip [s]": lambda r: r.time_loss_other_vehicles,
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sweep", help="fleet A's sweep (and fleet B's, without a second)")
    ap.add_argument("sweep_b", nargs="?", help="fleet B's sweep")
    ap.add_argument("--a", default="ethical")
    ap.add_argument("--b", default="ego")
    args = ap.parse_args()
    runs_a = load(args.sweep).runs
    runs_b = load(args.sweep_b).runs if args.sweep_b else runs_a
    key = ["penetration", "seed"]
    a = runs_a[(runs_a["penetration"] > 0) & (runs_a["fleet"] == args.a)].set_index(key)
    b = runs_b[(runs_b["penetration"] > 0) & (runs_b["fleet"] == args.b)].set_index(key)
    pairs = a.index.intersection(b.index)
    a, b = a.loc[pairs], b.loc[pairs]
    print(f"| `{args.a}` minus `{args.b}` | mean difference [95 % CI] | pairs where `{args.a}` is higher / lower |")
    print("| --- | --- | --- |")
    for name, outcome in OUTCOMES.items():
        d = (outcome(a) - outcome(b)).dropna().to_numpy()
        lo, hi = bootstrap_ci(d, n_boot=4000, seed=0)
        print(f"| {name} | {d.mean():+,.2f} [{lo:,.2f}, {hi:,.2f}] | {int((d > 0).sum())} / {int((d < 0).sum())} |")
    print(f"\n{len(pairs)} pairs")


if __name__ == "__main__":
    main()
