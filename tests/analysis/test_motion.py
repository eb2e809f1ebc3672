"""The sideways acceleration of recorded steps (sumo_ethics.analysis.motion), worked by hand."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest

from sumo_ethics.analysis.motion import lateral_check, step_lateral_accel


def test_a_heading_snapped_in_one_step_is_seen_and_a_steady_bend_is_not(tmp_path):
    # a bend of radius 50 m at 10 m/s turns 0.2 rad/s: 2.0 m/s^2 every step; then a snap of 6 degrees in
    # 0.1 s at 7.2 m/s: 7.2 x 0.10472 / 0.1 = 7.54 m/s^2
    yaw = [0.0, 0.02, 0.04, 0.06, 0.06 + math.radians(6.0)]
    steps = pd.DataFrame({"time": 0.1 * np.arange(5), "yaw": yaw, "speed": [10.0, 10.0, 10.0, 10.0, 7.2]})
    lateral, turn = step_lateral_accel(steps)
    np.testing.assert_allclose(lateral[:3], 2.0, rtol=1e-9)
    assert lateral[3] == pytest.approx(7.2 * math.radians(6.0) / 0.1, rel=1e-9)
    # across +-pi the wrapped change counts (0.02 rad, not 2 pi - 0.02)
    across = pd.DataFrame({"time": [0.0, 0.1], "yaw": [math.pi - 0.01, -math.pi + 0.01], "speed": [10.0, 10.0]})
    lat, turn = step_lateral_accel(across)
    assert turn[0] == pytest.approx(0.02, rel=1e-9) and lat[0] == pytest.approx(2.0, rel=1e-9)
    run = tmp_path / "runs" / "a"
    run.mkdir(parents=True)
    steps.to_parquet(run / "steps.parquet")
    (run / "summary.json").write_text(json.dumps({"ego_limits": {"max_lat_accel": 4.0}}))
    r = lateral_check(tmp_path / "runs")
    assert r.run.tolist() == ["a"] and r.steps_over.tolist() == [1] and r.steps.tolist() == [4]
    assert r.max_lateral.iloc[0] == pytest.approx(7.54, abs=0.01) and r.turn_deg.iloc[0] == pytest.approx(6.0)
    assert r.speed.iloc[0] == 7.2


def test_a_fleet_run_is_checked_ego_by_ego_against_the_config_limit(tmp_path):
    """Two egos' rows interleaved as a fleet's steps.parquet holds them: one heading east along a
    bend of radius 50 m at 10 m/s (2.0 m/s^2), one heading west on a straight (0). Read in the file's
    order the headings would jump by pi every row (314 m/s^2); ego by ego the largest is 2.0, and
    the limit (4.0) comes from config.json's ego (a fleet's summary has no ego_limits)."""
    t = 0.1 * np.arange(4)
    a = pd.DataFrame({"time": t, "yaw": 0.02 * np.arange(4), "speed": 10.0, "ego_id": "a"})
    b = pd.DataFrame({"time": t, "yaw": math.pi, "speed": 10.0, "ego_id": "b"})
    steps = pd.concat([a, b]).sort_values(["time", "ego_id"], kind="stable").reset_index(drop=True)
    run = tmp_path / "runs" / "fleet"
    run.mkdir(parents=True)
    steps.to_parquet(run / "steps.parquet")
    (run / "summary.json").write_text(json.dumps({"fleet": {}}))
    (run / "config.json").write_text(json.dumps({"ego": {"max_lat_accel": 4.0}}))
    r = lateral_check(tmp_path / "runs")
    assert r.limit.tolist() == [4.0] and r.steps.tolist() == [6] and r.steps_over.tolist() == [0]
    assert r.max_lateral.iloc[0] == pytest.approx(2.0, rel=1e-9) and r.ego.iloc[0] == "a"
