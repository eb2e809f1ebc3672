"""What occlusion and phantoms cost per planning step, side by side with them off (docs/occlusion.md).

    python tools/bench_occlusion.py scene [--agents 20,60] [--repeats 30]
    python tools/bench_occlusion.py city [--scenario CFG --route=FROM,TO --depart S] [--seconds 60] [--out DIR]

``scene``: a synthetic city street without SUMO: a straight two-way road (two 3.5 m lanes each way,
the ego in the right one at 10 m/s), 2 m sidewalks on both sides, a crossing 40 m ahead, ten
buildings along each side (20 x 12 m, 2 m gaps, 3 m back from the sidewalks), N road users placed
with a fixed seed from 40 m behind to 90 m ahead (cars driving in the lanes, parked cars at the kerbs,
pedestrians on the sidewalks). Per planning step, medians over ``--repeats`` steps after a warm-up:
the visible region and who is seen (``visibility.view``, ``visible_share``), the whole percept (the
memory and the phantoms' placement included), and the planner's whole step (constant-velocity
predictor, so that the predictor's cost does not hide the rest) with occlusion off, on, and on with
phantoms.

``city``: a public scenario with buildings, by default eclipse-sumo's A10KW (tools/game: OpenStreetMap
around the A10 Center near Berlin, 17 buildings from polyconvert), an ego of ours on a 461 m route
past them (edge 151495035#0 to 4935299#1) departing at 100 s; or another, e.g. DLR's OSM export of
central Braunschweig (github.com/DLR-TS/sumo-scenarios, port_tutorials/port_brunswick: 5,566 buildings)
with ``--scenario .../city.sumocfg --route=-7016614#0,-24982513#0 --depart 300`` (519 m through the old
town; city.sumocfg: its network, osm.poly.xml, the passenger and truck trips and the pedestrian trips
walked on foot, ``modes="public"`` dropped, since the snapshot lacks the public transport routes). The default planner (the map-aware LSTM) with occlusion off, on, and on with phantoms; the
medians of timings.parquet and the means of the perception columns of steps.parquet.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def street(n_agents: int, seed: int = 5):
    """(scene, SightMap) of the synthetic street (see the module doc)."""
    import shapely

    from sumo_ethics.config import EgoVehicle
    from sumo_ethics.contract import RoutePath, Scene
    from sumo_ethics.geometry import Polyline
    from sumo_ethics.plan.perception import SightMap
    from sumo_ethics.types import AgentStates, Observation, RoadUserClass

    rng = np.random.default_rng(seed)
    path = Polyline.from_points(np.array([[0.0, 0.0], [400.0, 0.0]]))  # the ego's lane centre, y = 0
    route = RoutePath(edges=("e",), path=path, lane_of_vertex=("e_0", "e_0"), speed_limit=np.full(2, 13.9),
                      left=np.full(2, 12.25), right=np.full(2, -1.75), links=())
    # lanes (centres) y = 0, 3.5 (ours), 7, 10.5 (oncoming); kerbs y = -1.75, 12.25; sidewalks 2 m
    walk = (shapely.box(0, -3.75, 400, -1.75), shapely.box(0, 12.25, 400, 14.25), shapely.box(138, -3.75, 142, 14.25))
    blocks = tuple(shapely.box(x, y0, x + 20, y0 + 12) for x in np.arange(50, 270, 22) for y0 in (-18.75, 17.25))
    ego_x = 100.0
    kinds = rng.choice(3, n_agents, p=[0.5, 0.25, 0.25])  # driving, parked, pedestrian
    x = ego_x + rng.uniform(-40, 90, n_agents)
    lane_y = rng.choice([0.0, 3.5, 7.0, 10.5], n_agents)
    y = np.where(kinds == 0, lane_y, np.where(kinds == 1, rng.choice([-1.05, 11.55], n_agents),
                                                rng.choice([-2.75, 13.25], n_agents)))
    yaw = np.where((kinds == 0) & (lane_y > 5), np.pi, 0.0) + np.where(kinds == 2, np.pi / 2, 0.0)
    speed = np.where(kinds == 0, rng.uniform(6, 12, n_agents), np.where(kinds == 2, 1.3, 0.0))
    length = np.where(kinds == 2, 0.3, 4.5)
    width = np.where(kinds == 2, 0.5, 1.8)
    cls = np.where(kinds == 2, int(RoadUserClass.PEDESTRIAN), int(RoadUserClass.CAR)).astype(np.int8)
    mass = np.where(kinds == 2, 75.0, 1500.0)
    others = AgentStates(tuple(f"a{i}" for i in range(n_agents)), x, y, yaw, speed, np.zeros(n_agents), length, width,
                         mass, cls)
    ego = AgentStates(("ego",), np.array([ego_x]), np.zeros(1), np.zeros(1), np.array([10.0]), np.zeros(1),
                      np.array([4.508]), np.array([1.61]), np.array([1475.0]), np.zeros(1, np.int8))
    t = np.arange(-30, 1) * 0.1
    hist = np.stack([x[:, None] + speed[:, None] * np.cos(yaw)[:, None] * t, y[:, None] + speed[:, None] * np.sin(yaw)[:, None] * t], -1)
    obs = Observation(0.0, 0.1, hist, np.ones(hist.shape[:2], bool), others, ego)
    scene = Scene(time=0.0, dt=0.1, ego=ego, others=others, route=route, s=ego_x, d=0.0, stop_s=None,
                  vehicle=EgoVehicle(), history=obs)
    return scene, SightMap(opaque=blocks, walkable=walk)


def _median_ms(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(1e3 * (time.perf_counter() - t0))
    return statistics.median(times)


def _scene_row(n: int, repeats: int) -> str:
    """One row of the scene table: n road users (see :func:`bench_scene`)."""
    import shapely

    from sumo_ethics.geometry import OrientedBoxes
    from sumo_ethics.plan.ethical import EthicalPlanner, PlannerConfig
    from sumo_ethics.plan.perception import Perception, PerceptionConfig
    from sumo_ethics.visibility import view, visible_share

    scene, sight = street(n)
    o = scene.others
    corners = OrientedBoxes(o.x, o.y, o.yaw, o.length, o.width).corners()
    eye = np.array([float(scene.ego.x[0]), 0.0])
    near = [sight.opaque[i] for i in sight.near("opaque", shapely.Point(eye).buffer(50.0))]

    def vis() -> None:
        visible_share(view(eye, 50.0, corners, near), corners)

    for _ in range(3):
        vis()
    t_vis = _median_ms(vis, repeats)
    perc = Perception(PerceptionConfig(), occlusion=True, phantoms=True, sight=sight)
    clock = iter(range(10**9))

    def percept():
        return perc.perceive(replace(scene, time=0.1 * next(clock)), 40, 0.1)

    for _ in range(3):
        percept()
    t_perc = _median_ms(percept, repeats)
    last = percept()
    t_ph = statistics.median(percept().timings_ms["phantoms_ms"] for _ in range(repeats))
    step = {}
    for name, kw in (("off", {}), ("occ", {"occlusion": True}), ("ph", {"occlusion": True, "phantoms": True})):
        planner = EthicalPlanner(PlannerConfig(predictor="cv", **kw), sight=sight)
        tick = iter(range(10**9))
        for _ in range(3):
            planner.act(replace(scene, time=0.1 * next(tick)))
        step[name] = _median_ms(lambda p=planner, k=tick: p.act(replace(scene, time=0.1 * next(k))), repeats)
    return (f"| {n} | {t_vis:.2f} | {t_perc:.2f} | {t_ph:.2f} | {step['off']:.1f} | {step['occ']:.1f} | "
            f"{step['ph']:.1f} | {len(last.seen)} / {last.in_range} | {len(last.phantoms.agents)} |")


def bench_scene(agents: list[int], repeats: int) -> None:
    print(f"synthetic street, {repeats} steps per cell after 3 of warm-up; medians [ms]")
    print("| road users | visibility | whole percept (+ memory, phantoms) | phantoms | planner step: off | occlusion | "
          "occlusion + phantoms | seen / in range | phantoms |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for n in agents:
        print(_scene_row(n, repeats))


A10KW = "tools/game/A10KW.sumocfg"
ROUTE = ("151495035#0", "4935299#1")


def bench_city(cfg: Path | None, route: tuple[str, str], depart: float, seconds: float, out: Path) -> None:
    import pandas as pd
    import sumo

    from sumo_ethics.config import RunConfig
    from sumo_ethics.runner import run
    from sumo_ethics.settings import planner_config

    cfg = cfg or Path(sumo.SUMO_HOME) / A10KW
    rows = []
    for name, table in (("off", {}), ("occlusion", {"occlusion": True}),
                        ("occlusion + phantoms", {"occlusion": True, "phantoms": True})):
        folder = out / name.replace(" + ", "_")
        t0 = time.perf_counter()
        s = run(RunConfig(cfg, folder, seed=1, ego_from=route[0], ego_to=route[1], ego_depart=depart,
                          end=depart + seconds, progress=False, overwrite=True, planner=planner_config(table)))
        wall = time.perf_counter() - t0
        tm = pd.read_parquet(folder / "timings.parquet")
        st = pd.read_parquet(folder / "steps.parquet")
        med = tm.median(numeric_only=True)
        row = {"planner": name, "status": s.status.value, "steps": len(tm), "wall_s": round(wall, 1),
               "controller_ms": med["controller_ms"], "predict_ms": med["predict_ms"],
               "risk_cost_ms": med["risk_cost_ms"]}
        for col in ("visibility_ms", "memory_ms", "phantoms_ms"):
            row[col] = med.get(col, float("nan"))
        for col in ("n_neighbours", "n_in_range", "n_visible", "n_remembered", "n_phantoms"):
            row[col] = st[col].mean() if col in st else float("nan")
        rows.append(row)
    df = pd.DataFrame(rows)
    print(f"{cfg}, ego {route[0]} -> {route[1]} from {depart:g} s, {seconds:g} s; medians of timings.parquet [ms], "
          "means of steps.parquet")
    print("| " + " | ".join(df.columns) + " |")
    print("|" + " --- |" * len(df.columns))
    for _, r in df.iterrows():
        print("| " + " | ".join(f"{v:.2f}" if isinstance(v, float) else str(v) for v in r) + " |")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="what", required=True)
    sc = sub.add_parser("scene")
    sc.add_argument("--agents", default="20,60")
    sc.add_argument("--repeats", type=int, default=30)
    ci = sub.add_parser("city")
    ci.add_argument("--scenario", type=Path, default=None, help="a .sumocfg (default: eclipse-sumo's A10KW)")
    ci.add_argument("--route", default=",".join(ROUTE), metavar="FROM,TO", help="the ego's first and last edge")
    ci.add_argument("--depart", type=float, default=100.0)
    ci.add_argument("--seconds", type=float, default=60.0)
    ci.add_argument("--out", type=Path, default=Path("runs/bench_occlusion"))
    a = ap.parse_args(argv)
    from sumo_ethics.predict import one_thread

    one_thread(load=False)
    if a.what == "scene":
        bench_scene([int(v) for v in a.agents.split(",")], a.repeats)
    else:
        start, _, goal = a.route.partition(",")
        bench_city(a.scenario, (start, goal), a.depart, a.seconds, a.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
