"""Scenarios nobody here wrote: the ones shipped inside the eclipse-sumo package."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest
import sumo

from sumo_ethics.config import RunConfig
from sumo_ethics.runner import run

pytestmark = pytest.mark.sumo
GAME = Path(sumo.SUMO_HOME) / "tools" / "game"


@pytest.mark.parametrize("name, ego, controller", [
    ("ramp", None, "baseline"), ("ramp", "onramp.0", "baseline"), ("cross", None, "baseline"),
    ("cross", "1_right.0", "baseline"), ("corridor", None, "baseline"), ("square", None, "baseline"),
    ("ramp", "onramp.0", "ethical"), ("cross", "1_right.0", "ethical"),
    # the planner's ego entered the junction 2.4 m off its lane at t = 21 s: SUMO reported 0 m/s
    # for that step (-21 m/s^2) until the speed was also set with setPreviousSpeed
    ("cross", None, "ethical"),
])
def test_runs_on_shipped_scenario(tmp_path, name, ego, controller):
    from sumo_ethics.plan.ethical import PlannerConfig

    cfg = GAME / f"{name}.sumocfg"
    out = tmp_path / "run"
    summary = run(RunConfig(cfg, out, seed=1, end=150 if controller == "baseline" else 40, ego_id=ego,
                            progress=False, controller=controller, planner=PlannerConfig(predictor="cv")))
    assert summary.status.value in ("completed", "timeout", "collision")
    steps = pd.read_parquet(out / "steps.parquet")
    assert len(steps) > 10
    dt = summary.data["step_length"]
    assert dt == pytest.approx(steps.time.diff().dropna().median())  # their own step length (0.1 or 0.2 s)
    # the ego's speed is the commanded one; SUMO reports it too while the ego is on a lane (at a
    # few edge changes it re-derives it from the moved distance: millimetres per second off); off
    # every lane (a tight turn cut by the smoothed path) it reports the previous step's speed
    assert (steps.speed == steps.speed_cmd).all()
    on_lane = steps.lane != ""
    assert (~on_lane).mean() < 0.05
    assert (steps.speed_sumo - steps.speed_cmd)[on_lane].abs().max() < 0.05
    assert steps.accel.abs().max() <= 8.0 + 1e-6  # no teleports: within the ego's braking limit
    if ego is not None:
        assert summary.data["ego_id"] == ego
    if "input_additional.add.xml" in cfg.read_text():  # its edgeData dumps land in the run, not in GAME
        assert (out / "sumo-outputs" / "netstate.xml").is_file()
        assert "sumo-outputs/additional-files/" in summary.data["redirected_outputs"]["additional-files"]
