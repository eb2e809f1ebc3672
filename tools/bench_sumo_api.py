"""SUMO-side cost of the ways a run can drive the ego and read its neighbours, in isolation.

One plug-in run (baseline controller) records the ego's trajectory; every variant then
restarts SUMO with the same scenario and seed, inserts the ego the same way, and replays that
trajectory for the same steps with only the libsumo calls the variant names, no Python
processing. Reported per ego step (medians over interleaved repeats): ``step`` the wall time
of ``simulationStep`` [ms], ``calls`` the wall time of the variant's other libsumo calls
(moveToXY, setSpeed, fetching subscription results, getCollisions, ...) [ms], and their sum
minus the plain run's step. The ``busy`` variants run untimed work between the steps:
Python and numpy work (not streaming through memory) makes SUMO's own step slower, a cost of
interleaving that the plug-in pays on top of its calls.

    python tools/bench_sumo_api.py [--repeats 3] [--variants plain,full,...]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import libsumo
import numpy as np
import pandas as pd
from libsumo import constants as tc

from sumo_ethics.config import RunConfig
from sumo_ethics.runner import run
from sumo_ethics.sim.ego import insert_ego
from sumo_ethics.sim import session
from sumo_ethics.sim.frames import centre_to_front
from sumo_ethics.sim.world import _PER_VARS, _VEH_VARS

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Variant:
    """What a variant does each ego step. move: moveToXY keepRoute bits (None: SUMO drives the
    ego); subs: context subscriptions as (domain, variables); radius [m]."""

    move: int | None = 2
    match: float = 10.0
    set_speed: bool = True
    subs: tuple[tuple[int, tuple[int, ...]], ...] = ((tc.CMD_GET_VEHICLE_VARIABLE, _VEH_VARS),
                                                     (tc.CMD_GET_PERSON_VARIABLE, _PER_VARS))
    radius: float = 80.0
    collisions: bool = False
    lane_id: bool = False
    busy_kb: int = 0  # untimed streaming numpy work between steps over this much memory [kB]
    busy_us: float = 0.0  # untimed small-array numpy work between steps for this long [us]


_POS = (tc.VAR_POSITION, tc.VAR_ANGLE, tc.VAR_SPEED)
VARIANTS: dict[str, Variant] = {
    "plain": Variant(move=None, set_speed=False, subs=()),
    "subs-only": Variant(move=None, set_speed=False),
    "subs-veh-only": Variant(move=None, set_speed=False, subs=((tc.CMD_GET_VEHICLE_VARIABLE, _VEH_VARS),)),
    "move2-only": Variant(subs=()),
    "move2-no-setSpeed": Variant(subs=(), set_speed=False),
    "move2-match2": Variant(subs=(), match=2.0),
    "move1-only": Variant(move=1, subs=()),
    "full": Variant(),
    "full+collisions": Variant(collisions=True),
    "full+laneID": Variant(lane_id=True),
    "full-r50": Variant(radius=50.0),
    "full+busy256kB": Variant(busy_kb=256),
    "full+busy1MB": Variant(busy_kb=1024),
    "full+numpy200us": Variant(busy_us=200.0),
    "full-no-type": Variant(subs=((tc.CMD_GET_VEHICLE_VARIABLE, _POS + (tc.VAR_ACCELERATION,)),
                                  (tc.CMD_GET_PERSON_VARIABLE, _POS))),
    "full-no-type-accel": Variant(subs=((tc.CMD_GET_VEHICLE_VARIABLE, _POS), (tc.CMD_GET_PERSON_VARIABLE, _POS))),
}


def _small_numpy_work(seconds: float) -> None:
    """Many small numpy calls, like the plug-in's per-step Python side, for ``seconds``."""
    end = time.perf_counter() + seconds
    a = np.linspace(0.0, 1.0, 20)
    while time.perf_counter() < end:
        b = np.hypot(a, np.cos(a)) + np.sin(a)
        a = np.sort(np.minimum(np.maximum(b, 0.0), 1.0))[::-1].copy()


def trajectory(cfg: RunConfig) -> tuple[float, pd.DataFrame]:
    """Takeover time [s] and the recorded ego steps of one plug-in run."""
    s = run(cfg)
    return s.data["takeover_time"], pd.read_parquet(cfg.out / "steps.parquet")


def replay(cfg: RunConfig, t0: float, steps: pd.DataFrame, v: Variant) -> tuple[float, float]:
    """Total wall time [s] of simulationStep and of the variant's other calls over the replay."""
    files = session.read_scenario(cfg.scenario)
    with tempfile.TemporaryDirectory() as tmp:
        session.start(files, cfg.seed, Path(tmp) / "err.log")
        try:
            ego = "ego"
            insert_ego(cfg, ego)
            while libsumo.simulation.getTime() < t0 - 1e-9:
                libsumo.simulationStep()
            vh = libsumo.vehicle
            length = vh.getLength(ego)
            if v.move is not None:
                vh.setSpeedMode(ego, 32)
                vh.setLaneChangeMode(ego, 0)
                vh.setSpeedFactor(ego, 3.0)
                vh.setPreviousSpeed(ego, vh.getSpeed(ego))
            for dom, vars_ in v.subs:
                vh.subscribeContext(ego, dom, v.radius, vars_)
            libsumo.simulationStep()
            fx, fy, ang = centre_to_front(steps.x.to_numpy(), steps.y.to_numpy(), steps.yaw.to_numpy(), length)
            cmds = list(zip(fx.tolist(), fy.tolist(), ang.tolist(), steps.speed_cmd.to_numpy().tolist()))
            t_step = t_calls = 0.0
            scratch = np.zeros(v.busy_kb * 128)  # float64: 128 per kB
            for x, y, a, sp in cmds:
                w0 = time.perf_counter()
                if v.move is not None:
                    vh.moveToXY(ego, "", -1, x, y, a, v.move, v.match)
                if v.set_speed:
                    vh.setSpeed(ego, sp)
                w1 = time.perf_counter()
                libsumo.simulationStep()
                w2 = time.perf_counter()
                if v.subs:
                    vh.getContextSubscriptionResults(ego)
                if v.collisions:
                    libsumo.simulation.getCollisions()
                if v.lane_id:
                    vh.getLaneID(ego)
                w3 = time.perf_counter()
                if v.busy_kb:  # not timed
                    scratch += 1.0
                if v.busy_us:
                    _small_numpy_work(v.busy_us * 1e-6)
                t_step += w2 - w1
                t_calls += (w1 - w0) + (w3 - w2)
            return t_step, t_calls
        finally:
            session.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", type=Path, default=ROOT / "scenarios/urban_grid/urban_grid.sumocfg")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=2)
    ap.add_argument("--depart", type=float, default=300.0)
    ap.add_argument("--end", type=float, default=480.0)
    ap.add_argument("--ego-from", default="W0_in")
    ap.add_argument("--ego-to", default="E1_out")
    ap.add_argument("--variants", default=",".join(VARIANTS), help=f"comma-separated from {', '.join(VARIANTS)}")
    a = ap.parse_args()
    names = [n.strip() for n in a.variants.split(",")]
    unknown = set(names) - set(VARIANTS)
    if unknown:
        ap.error(f"unknown variants: {', '.join(sorted(unknown))}")
    with tempfile.TemporaryDirectory() as tmp:
        cfg = RunConfig(a.scenario, Path(tmp) / "run", seed=a.seed, end=a.end, ego_depart=a.depart,
                        ego_from=a.ego_from, ego_to=a.ego_to, stop_at_collision=False, progress=False,
                        controller="baseline")
        t0, steps = trajectory(cfg)
        res: dict[str, list[tuple[float, float]]] = {n: [] for n in names}
        for _ in range(a.repeats):
            for n in names:
                res[n].append(replay(cfg, t0, steps, VARIANTS[n]))
    n_steps = len(steps)
    med = {n: (1e3 * statistics.median(r[0] for r in rs) / n_steps, 1e3 * statistics.median(r[1] for r in rs) / n_steps)
           for n, rs in res.items()}
    base = med.get("plain", (float("nan"), 0.0))[0]
    print(f"{n_steps} ego steps replayed, medians of {a.repeats} repeats, ms per step")
    print(f"{'variant':<22}{'step':>8}{'calls':>8}{'total':>8}{'vs plain':>10}")
    for n, (st, ca) in med.items():
        print(f"{n:<22}{st:8.3f}{ca:8.3f}{st + ca:8.3f}{st + ca - base:+10.3f}")


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
