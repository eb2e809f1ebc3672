"""Occlusion and phantoms in real SUMO: the sensor's map read from a running simulation, the default
leaving a run's outputs as they were, and a suite pedestrian behind a parked car."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import shapely

from conftest import SCENARIOS, write_scenario

pytestmark = pytest.mark.sumo
NARROW = SCENARIOS / "suite" / "networks" / "narrow" / "narrow.net.xml"


def test_sight_map_reads_walkable_areas_lanes_and_buildings(tmp_path):
    """The suite's narrow street (net file): four sidewalks 88 x 1.5 m (132 m^2 each), one crossing
    6 x 4 m at N1 (24 m^2), walking areas; four 3 m road lanes entering N0, N1 or N2; no bike lane.
    From an additional file: a 10 x 8 m building ("building.yes", opaque) and a lawn ("landuse.grass",
    not opaque)."""
    import libsumo

    from sumo_ethics.sim.sight import sight_map

    add = tmp_path / "polys.add.xml"
    add.write_text('<additional><poly id="b1" type="building.yes" shape="20,10 30,10 30,18 20,18"/>'
                   '<poly id="g1" type="landuse.grass" shape="40,10 50,10 50,20 40,20"/></additional>')
    libsumo.start(["sumo", "-n", str(NARROW), "-a", str(add), "--no-step-log", "--no-warnings"])
    try:
        m = sight_map(("building",))
    finally:
        libsumo.close()
    assert len(m.opaque) == 1 and m.opaque[0].area == pytest.approx(80.0)
    areas = sorted(round(g.area, 6) for g in m.walkable)
    assert areas.count(132.0) == 4 and areas.count(24.0) == 1
    crossing = [g for g in m.walkable if round(g.area, 6) == 24.0][0]
    assert crossing.bounds == pytest.approx((88.0, -3.0, 92.0, 3.0))
    assert {ln.kind for ln in m.lanes} == {"road"} and len(m.lanes) == 4
    assert {ln.id: ln.junction for ln in m.lanes}["n_e0_1"] == "N1"
    assert all(ln.speed == pytest.approx(8.33) for ln in m.lanes)


def _steps(out: Path) -> bytes:
    return (out / "steps.parquet").read_bytes()


def test_occlusion_off_leaves_the_outputs_as_they_were(scenario_dir, tmp_path):
    """A 12 s run on the testbed with a pedestrian crossing: the default planner and the same planner
    with occlusion and phantoms said false write the same steps.parquet, byte for byte, with none of
    the perception columns, and the same config.json but for the folder's name (without the
    perception keys, as before they existed)."""
    from sumo_ethics.config import RunConfig
    from sumo_ethics.runner import run
    from sumo_ethics.settings import planner_config

    cfg = write_scenario(scenario_dir, """
      <vehicle id="ego" type="car" route="r_main" depart="0" departLane="1" departPos="140" departSpeed="10"/>
      <person id="walker" type="ped" depart="0" departPos="194"><walk from="main_0" to="opp_0"/></person>""")
    outs = []
    for i, table in enumerate(({"predictor": "cv"}, {"predictor": "cv", "occlusion": False, "phantoms": False})):
        out = tmp_path / f"r{i}"
        run(RunConfig(cfg, out, ego_id="ego", end=12, progress=False, planner=planner_config(table), seed=3))
        outs.append(out)
    assert _steps(outs[0]) == _steps(outs[1])
    configs = [json.loads((o / "config.json").read_text()) for o in outs]
    for c in configs:
        del c["out"]
    assert configs[0] == configs[1] and "occlusion" not in configs[0]["planner"]  # as before, byte for byte
    cols = set(pd.read_parquet(outs[0] / "steps.parquet").columns)
    assert not cols & {"n_in_range", "n_visible", "n_remembered", "n_phantoms", "cost_phantom"}


def test_a_suite_pedestrian_behind_a_parked_car(tmp_path):
    """Suite scenario s0024 (a pedestrian waits behind a car parked on the narrow street, then steps
    out) with occlusion and phantoms (constant-velocity predictor, to be quick): while she waits
    behind the car she is in range but not seen; pedestrian phantoms stand in the car's shadow; the
    recorded decisions carry the view; every step counts seen <= in range."""
    from sumo_ethics.record.decisions import load, recorded_steps
    from sumo_ethics.suite.evaluate import parse_planner, run_one

    spec = parse_planner("occ=base=ours;occlusion=true;phantoms=true;predictor=cv")
    out = tmp_path / "occ"
    row = run_one(str(SCENARIOS / "suite" / "s0024"), spec, str(out), record_decisions="all")
    assert row["status"] in ("completed", "timeout", "collision"), row
    steps = pd.read_parquet(out / "steps.parquet")
    assert (steps.n_visible <= steps.n_in_range).all() and (steps.n_phantoms > 0).any()
    assert {"cost_phantom", "cost_phantom_risk", "n_remembered"} <= set(steps.columns)
    events = json.loads((out / "hazard_events.json").read_text())
    spawn = next(e["time"] for e in events if e["event"] == "spawn" and e["type"] == "pedestrian")
    trigger = next(e["time"] for e in events if e["event"] == "trigger" and e["type"] == "pedestrian")
    ped = next(e["actor"] for e in events if e["event"] == "spawn" and e["type"] == "pedestrian")
    hidden = 0
    for step in recorded_steps(out):
        d = load(out, step)
        assert d.view is not None and d.view.visible.area > 0.0
        if spawn + 0.2 < d.time < trigger:  # waiting behind the car
            assert ped not in d.view.seen and ped not in d.agent_ids
            hidden += 1
    assert hidden > 10
    # the phantoms stand on hidden ground
    d = load(out, [s for s in recorded_steps(out) if len(load(out, s).view.phantoms)][0])
    pts = shapely.points(d.view.phantoms[:, :2])
    assert shapely.contains(d.view.hidden.buffer(0.01), pts).all()
    assert np.isfinite(d.view.phantom_risk).all()


def test_each_ego_of_a_fleet_has_its_own_view(scenario_dir, tmp_path):
    """Three cars in one lane of the testbed, 20 m apart: egos "a" (middle) and "b" (behind), "c" ahead
    driven by SUMO. "a" sees both others; from "b", "c" is hidden behind "a" (a 1.8 m wide box 20 m
    away covers +-2.6 deg of b's view, c 50 m away spans +-1.0 deg within it): in range but not seen."""
    from sumo_ethics.config import FleetSpec, RunConfig
    from sumo_ethics.runner.fleet import run_fleet
    from sumo_ethics.settings import planner_config

    routes = ''.join(f'<vehicle id="{v}" type="car" route="r_main" depart="0" departPos="{p}" departLane="1" '
                     'departSpeed="8"/>' for v, p in (("b", 10), ("a", 30), ("c", 50)))
    cfg = write_scenario(scenario_dir, routes, end=2.0)
    rc = RunConfig(scenario=cfg, out=tmp_path / "run", progress=False, planner=planner_config(
        {"predictor": "cv", "occlusion": True}), fleet=FleetSpec(ids=("a", "b")))
    run_fleet(rc)
    steps = pd.read_parquet(tmp_path / "run" / "steps.parquet")
    first = steps.groupby("ego_id").head(5).set_index(["ego_id", "step"])
    a, b = first.loc["a"], first.loc["b"]
    assert (a.n_in_range == 2).all() and (a.n_visible == 2).all()
    assert (b.n_in_range == 2).all() and (b.n_visible == 1).all()
