"""A junction turn tighter than the ego's turning limit, in real SUMO.

The network (built with netconvert here) is one 60 m lane east into junction J at (0, 0) and
one 60 m lane south out of it: the right turn :J_0_0 is 2.6 m long with a radius of about 1.6 m
(2.4 m on the planner's smoothed reference path, 0.42 1/m), like the OSM junction shapes of
eclipse-sumo's bs3d network, far tighter than the ego's max_curvature of 0.2 1/m.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import sumo_ethics.plan.ethical as ethical
from sumo_ethics.config import EgoVehicle, RunConfig
from sumo_ethics.plan.ethical import EthicalPlanner, PlannerConfig
from sumo_ethics.runner import run
from sumo_ethics.sim.netbuild import PlainNet

pytestmark = pytest.mark.sumo
LIMITS = EgoVehicle()
DT = 0.1


@pytest.fixture(scope="module")
def bend_scenario(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("bend")
    net = PlainNet("bend", {"walkingareas": "false"})
    net.node("A", -60, 0, type="priority")
    net.node("J", 0, 0, type="priority")
    net.node("B", 0, -60, type="priority")
    net.edge("in", "A", "J", numLanes=1, speed=13.89)
    net.edge("out", "J", "B", numLanes=1, speed=13.89)
    net.build(folder)
    cfg = folder / "bend.sumocfg"
    cfg.write_text('<configuration><input><net-file value="bend.net.xml"/></input>'
                   f'<time><begin value="0"/><end value="40"/><step-length value="{DT}"/></time></configuration>\n')
    return cfg


def drive(cfg: Path, out: Path, end: float = 40.0):
    return run(RunConfig(cfg, out, ego_from="in", ego_to="out", end=end, progress=False),
               controller=EthicalPlanner(PlannerConfig(predictor="cv")))


def test_the_ego_drives_through_a_junction_turn_tighter_than_its_limit(bend_scenario, tmp_path):
    out = tmp_path / "run"
    s = drive(bend_scenario, out)
    assert s.status.value == "completed", s.message
    steps = pd.read_parquet(out / "steps.parquet")
    bend = steps[steps.lane == ":J_0_0"]
    assert len(bend) >= 3  # it drove the junction lane
    # physically plausible: accelerations within the limits, no jump beyond the step's travel
    assert steps.accel.max() <= LIMITS.max_accel + 1e-6
    assert steps.accel.min() >= -LIMITS.max_decel - 1e-6
    jump = np.hypot(np.diff(steps.x), np.diff(steps.y))
    travel = np.maximum(steps.speed.values[1:], steps.speed.values[:-1]) * DT
    assert (jump <= travel + 0.05).all(), (jump - travel).max()
    assert (steps.speed - steps.speed_sumo).abs().max() < 0.05  # SUMO drove the ego at the commanded speed
    # slowed down for the bend: v^2 k <= 4 m/s^2 at k = 0.42 gives about 3.1 m/s
    assert bend.speed.max() < 3.6 and steps.speed.max() > 10.0
    # the lateral acceleration it drove (speed x yaw rate) stays near the limit; the planner's
    # curvature is a central difference over two steps, which smooths the per-step peak a little
    yaw_rate = np.diff(np.unwrap(steps.yaw.values)) / DT
    lat = 0.5 * (steps.speed.values[1:] + steps.speed.values[:-1]) * np.abs(yaw_rate)
    assert lat.max() <= 1.2 * LIMITS.max_lat_accel
    assert steps.d.abs().max() < 0.3  # on its lane through the turn
    # the summary names the tight bend and says the ego followed it
    summary = json.loads((out / "summary.json").read_text())
    b = summary["tight_bends"]
    assert (b["count"], b["passed"]) == (1, 1)
    assert b["tightest"]["lane"] == ":J_0_0" and b["tightest"]["turn"] == "right"
    assert b["tightest"]["curvature"] > 2 * LIMITS.max_curvature
    assert "passed 1 of these bends, following the road's own geometry" in b["note"]
    assert "standstill" not in summary


def test_under_the_old_rule_the_ego_stands_at_the_turn_and_the_summary_says_so(bend_scenario, tmp_path, monkeypatch):
    """Control: the curvature limit applied to the road itself (candidates without their road
    curvature) leaves no moving candidate at the bend; the run ends with a standstill note."""
    plain = ethical.check
    monkeypatch.setattr(ethical, "check", lambda cand, *a, **kw: plain(replace(cand, road_curvature=None), *a, **kw))
    out = tmp_path / "old"
    s = drive(bend_scenario, out, end=25.0)
    assert s.status.value == "timeout"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["tight_bends"]["passed"] == 0 and "passed 0 of these bends" in summary["tight_bends"]["note"]
    st = summary["standstill"]
    assert st["duration"] >= 10.0 and math.isfinite(st["s"])
    steps = pd.read_parquet(out / "steps.parquet")
    assert steps.speed.iloc[-1] == 0.0 and summary["distance"] < 60.0
    assert steps.lane.iloc[-1] in ("in_0", ":J_0_0")  # at the turn, never through it
