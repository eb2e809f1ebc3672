"""Forced collisions in real SUMO: each is detected exactly once, with the right classes and harm."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from sumo_ethics.config import RunConfig
from sumo_ethics.runner import run

from conftest import Scripted, write_scenario

pytestmark = pytest.mark.sumo

CAR_MASS = -1333.5 + 526.9 * (4.5 * 1.8) ** 0.8  # 1475.27 kg: SUMO's default 1500 kg is ignored


def logistic(z: float) -> float:
    return 1.0 / (1.0 + math.exp(-z))


def ego_rows(out) -> pd.DataFrame:
    df = pd.read_parquet(out / "collisions.parquet")
    return df[df.involves_ego]


def test_rear_end_into_parked_car(scenario_dir, tmp_path):
    cfg = write_scenario(scenario_dir, """
      <vehicle id="parked" type="car" route="r_main" depart="0" departLane="2" departPos="124" departSpeed="0">
        <stop lane="main_0_2" endPos="124.5" duration="1000"/></vehicle>
      <vehicle id="ego" type="car" route="r_main" depart="0" departLane="2" departPos="20" departSpeed="10"/>""")
    out = tmp_path / "run"
    # keep driving through the car: the overlap lasts many steps and must stay one event
    summary = run(RunConfig(cfg, out, ego_id="ego", stop_at_collision=False, end=20, progress=False),
                  controller=Scripted(10.0))
    rows = ego_rows(out)
    assert len(rows) == 1
    r = rows.iloc[0]
    assert (r.id_b, r.class_a, r.class_b) == ("parked", "car", "car")
    assert (r.area_a, r.area_b) == ("front", "rear")
    assert r.speed_a == pytest.approx(10.0, abs=1e-6) and r.speed_b == pytest.approx(0.0, abs=1e-6)
    # equal masses: delta_v = 10 m/s, split 5 / 5
    assert r.mass_a == pytest.approx(CAR_MASS, abs=0.01) and r.mass_b == pytest.approx(CAR_MASS, abs=0.01)
    assert r.delta_v == pytest.approx(10.0, abs=1e-3) and r.dv_a == pytest.approx(5.0, abs=1e-3)
    # by hand: front 1/(1+exp(4.457-0.177*5)) = 0.02733; rear adds -0.431 -> 0.01794
    assert r.harm_a == pytest.approx(0.02733, abs=1e-4)
    assert r.harm_b == pytest.approx(0.01794, abs=1e-4)
    assert r.harm_ego == r.harm_a and r.harm_third_party == r.harm_b and r.harm_vru == 0.0
    # first contact when the ego's front reaches the parked car's rear (x = 124 - 4.5 = 119.5)
    steps = pd.read_parquet(out / "steps.parquet")
    assert steps.set_index("step").loc[r.step, "x"] + 2.25 == pytest.approx(119.5, abs=1.1)
    assert summary.data["harm"]["total"] == pytest.approx(r.harm_a + r.harm_b)


def test_pedestrian_hit_on_crosswalk(scenario_dir, tmp_path):
    cfg = write_scenario(scenario_dir, """
      <vehicle id="ego" type="car" route="r_main" depart="0" departLane="1" departPos="185" departSpeed="0"/>
      <person id="walker" type="ped" depart="0" departPos="190"><walk from="main_0" to="opp_0"/></person>""")
    out = tmp_path / "run"

    def walker_on_crossing(scene):  # charge once the walker has stepped onto the road
        o = scene.others
        return any(k == "walker" and 197 < x < 203 and y > -6.5 for k, x, y in zip(o.ids, o.x, o.y))

    summary = run(RunConfig(cfg, out, ego_id="ego", end=60, progress=False),
                  controller=Scripted(10.0, trigger=walker_on_crossing))
    assert summary.status.value == "collision"
    rows = ego_rows(out)
    assert len(rows) == 1
    r = rows.iloc[0]
    assert (r.id_b, r.class_b, r.area_a) == ("walker", "pedestrian", "front")
    assert r.mass_b == 75.0
    assert r.detector in ("geometry", "both")
    # harm from the recorded pre-impact states, worked through METHOD.md by hand
    pdof = r.yaw_b - r.yaw_a + math.pi
    dv = math.sqrt(r.speed_a**2 + r.speed_b**2 + 2 * r.speed_a * r.speed_b * math.cos(pdof))
    dv_ped = CAR_MASS / (CAR_MASS + 75.0) * dv
    dv_car = 75.0 / (CAR_MASS + 75.0) * dv
    assert r.speed_a == pytest.approx(10.0, abs=1e-6)
    assert r.harm_b == pytest.approx(logistic(-3.164 + 0.288 * dv_ped), abs=1e-9)
    assert r.harm_a == pytest.approx(logistic(-4.591 + 0.185 * dv_car), abs=1e-9)
    assert 0.38 < r.harm_b < 0.42  # about 0.396 at 10 m/s into a 1.2 m/s walker
    assert r.harm_vru == r.harm_third_party == r.harm_b


def test_sideswipe_from_lateral_offset(scenario_dir, tmp_path):
    cfg = write_scenario(scenario_dir, """
      <vehicle id="side" type="slowcar" route="r_main" depart="0" departLane="1" departPos="30" departSpeed="10"/>
      <vehicle id="ego" type="car" route="r_main" depart="0" departLane="2" departPos="30" departSpeed="10"/>""")
    out = tmp_path / "run"
    # drift right at 0.8 m/s from t = 1 s: lanes are 3.2 m apart, cars 1.8 m wide
    summary = run(RunConfig(cfg, out, ego_id="ego", end=20, progress=False),
                  controller=Scripted(10.0, offset=lambda t: -0.8 * max(0.0, t - 1.0)))
    assert summary.status.value == "collision"
    rows = ego_rows(out)
    assert len(rows) == 1
    r = rows.iloc[0]
    assert (r.id_b, r.class_b, r.area_a, r.area_b) == ("side", "car", "side", "side")
    assert r.detector == "geometry"  # SUMO does not see sideswipes between lanes
    # closing speed is the lateral speed: sqrt(10^2 + 0.8^2) heading vs 10 m/s straight
    assert r.delta_v == pytest.approx(0.8, abs=0.05)
    assert r.harm_a == pytest.approx(logistic(-4.457 + 0.177 * r.dv_a + 0.244), abs=1e-9)
    assert r.harm_vru == 0.0


@pytest.mark.parametrize("controller, predictor", [("baseline", "cv"), ("ethical", "cv"), ("ethical", "attention")])
def test_same_seed_same_parquet(tmp_path, controller, predictor):
    from sumo_ethics.plan.ethical import PlannerConfig

    cfgs = [RunConfig(SCENARIOS_URBAN, tmp_path / f"r{i}", seed=7, end=45, ego_depart=15, progress=False,
                      controller=controller, planner=PlannerConfig(predictor=predictor)) for i in range(2)]
    for c in cfgs:
        run(c)
    for name in ("steps.parquet", "collisions.parquet"):
        assert (cfgs[0].out / name).read_bytes() == (cfgs[1].out / name).read_bytes(), name
    assert len(pd.read_parquet(cfgs[0].out / "steps.parquet")) > 100


def test_sumo_failure_mid_run_keeps_rows(scenario_dir, tmp_path):
    # SUMO parses the next route chunk when vehicle "b" departs: the broken one fails at t = 300 s
    cfg = write_scenario(scenario_dir, """
      <vehicle id="ego" type="car" route="r_main" depart="10" departLane="1" departSpeed="0"/>
      <vehicle id="b" type="car" route="r_main" depart="300"/>
      <vehicle id="late" type="car" depart="450"><route edges="main_0 nowhere"/></vehicle>""", end=600)
    out = tmp_path / "run"
    # after a fatal SUMO error libsumo cannot be restarted in the same process: run it in its own
    code = (f"import sys; sys.path.insert(0, {str(Path(__file__).resolve().parents[1])!r})\n"
            "from conftest import Scripted\n"
            "from sumo_ethics.config import RunConfig\nfrom sumo_ethics.runner import run\n"
            f"run(RunConfig({str(cfg)!r}, {str(out)!r}, ego_id='ego', progress=False), controller=Scripted(1.0))\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert p.returncode != 0 and "SimulationError" in p.stderr and "nowhere" in p.stderr
    steps = pd.read_parquet(out / "steps.parquet")
    assert len(steps) > 100 and steps.time.max() < 300.01
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "error" and "nowhere" in summary["message"] and "t=300" in summary["message"]


from conftest import SCENARIOS  # noqa: E402

SCENARIOS_URBAN = SCENARIOS / "urban" / "urban.sumocfg"
