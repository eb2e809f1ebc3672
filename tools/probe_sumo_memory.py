"""Does SUMO's own memory grow over a long run? libsumo alone on urban_grid, no egos, no planner.

    python tools/probe_sumo_memory.py 300                      # plain SUMO, the run's forced options
    python tools/probe_sumo_memory.py 300 --tripinfo           # + the tripinfo output a run writes
    python tools/probe_sumo_memory.py 300 --subscribe          # + two context subscriptions (vehicles,
                                                               #   persons, 80 m) on every vehicle as it
                                                               #   departs, read every step, as fleet egos

Samples the resident memory every 5 simulated seconds and fits RSS ~ 1 + road users + t over the
samples after the first 20 % (the fit of ``tools/bench_fleet.py --memory``): the time slope [MB per
100 s] is growth that the traffic in the network does not explain (MB = 10^6 bytes, as there). Used to look for the fleet's
growth (issue 39, docs/fleets.md). Not sumo_ethics code: the probe talks to libsumo directly.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import libsumo as sumo
import numpy as np
import traci.constants as tc
from bench_fleet import growth_fit, rss_mb

from sumo_ethics.sim import session

ROOT = Path(__file__).resolve().parents[1]
VEH = [tc.VAR_POSITION, tc.VAR_ANGLE, tc.VAR_SPEED, tc.VAR_ACCELERATION, tc.VAR_LENGTH, tc.VAR_WIDTH, tc.VAR_TYPE]
PER = [tc.VAR_POSITION, tc.VAR_ANGLE, tc.VAR_SPEED, tc.VAR_LENGTH, tc.VAR_WIDTH, tc.VAR_TYPE]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("seconds", type=float)
    ap.add_argument("--tripinfo", action="store_true")
    ap.add_argument("--subscribe", action="store_true")
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args()
    cmd = ["sumo", "-c", str(ROOT / "scenarios" / "urban_grid" / "urban_grid.sumocfg"), "--seed", str(a.seed),
           "--no-step-log", "true", "--no-warnings", "true"]
    for k, v in session.FORCED_OPTIONS.items():
        cmd += [f"--{k}", v]
    with tempfile.TemporaryDirectory() as tmp:
        if a.tripinfo:
            cmd += ["--tripinfo-output", str(Path(tmp) / "tripinfo.xml"), "--tripinfo-output.write-unfinished", "true"]
        sumo.start(cmd)
        samples, subscribed = [], set()
        while sumo.simulation.getTime() < a.seconds:
            sumo.simulationStep()
            t = sumo.simulation.getTime()
            if a.subscribe:
                for vid in sumo.simulation.getDepartedIDList():
                    sumo.vehicle.subscribeContext(vid, tc.CMD_GET_VEHICLE_VARIABLE, 80.0, VEH)
                    sumo.vehicle.subscribeContext(vid, tc.CMD_GET_PERSON_VARIABLE, 80.0, PER)
                    subscribed.add(vid)
                live = set(sumo.vehicle.getIDList())
                subscribed &= live
                for vid in subscribed:
                    sumo.vehicle.getContextSubscriptionResults(vid)
            if abs(t / 5.0 - round(t / 5.0)) < 1e-6:
                samples.append((t, rss_mb(), sumo.vehicle.getIDCount() + sumo.person.getIDCount()))
        sumo.close()
    s = np.array(samples)
    late = s[s[:, 0] >= 0.2 * a.seconds]
    coef, se, _ = growth_fit(late[:, 1], [late[:, 2]], late[:, 0])
    at = [int(q * (len(s) - 1)) for q in (0.25, 0.5, 0.75, 1.0)]
    print(f"{a.seconds:g} s, tripinfo {a.tripinfo}, subscriptions {a.subscribe}: RSS at 25/50/75/100 % "
          + " / ".join(f"{s[i, 1]:.0f}" for i in at) + " MB; road users " + " / ".join(f"{int(s[i, 2])}" for i in at)
          + f"; fit {coef[1]:.3f} MB per road user, {coef[2]:.2f} MB per 100 s "
          f"[95 % CI {coef[2] - 1.96 * se[2]:.2f}, {coef[2] + 1.96 * se[2]:.2f}]")


if __name__ == "__main__":
    main()
