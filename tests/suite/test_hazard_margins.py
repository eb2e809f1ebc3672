"""The margins of tools/hazard_margins.py (sumo_ethics.suite.margins) against numbers worked out by hand, on hand-built run folders."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pandas as pd
import pytest

from sumo_ethics.suite import margins as hm



def test_needed_deceleration_by_hand():
    # 10 m/s closing, 11 m gap: 100 / 22 = 4.545; 0.5 s late the gap is 6 m: 100 / 12 = 8.33
    assert hm.needed_decel(11.0, 10.0, 0.0) == pytest.approx(100 / 22)
    assert hm.needed_decel(11.0, 10.0, 0.5) == pytest.approx(100 / 12)
    assert hm.needed_decel(11.0, 10.0, 1.1) == math.inf  # the gap is gone before braking starts
    assert hm.needed_decel(11.0, -2.0, 0.3) == 0.0  # not closing


def _run(tmp: Path, name: str, hazard: dict, trigger: dict, collision: dict) -> Path:
    scen = tmp / "suite" / name
    scen.mkdir(parents=True)
    (scen / f"{name}.sumocfg").write_text("<configuration/>")
    (scen / f"{name}.rou.xml").write_text('<routes><vType id="car" length="4.0" width="2.0"/></routes>')
    hazard = {"anchor": {"edge": "e0", "pos": 50.0}, "trigger": {"distance": 20.0}, **hazard}
    (scen / "hazards.json").write_text(json.dumps({"name": name, "seed": 1, "network": "narrow", "hazards": [hazard],
                                                   "ego": {"from": "e0", "to": "e1", "depart": 0.0, "end": 60.0}}))
    run = tmp / "runs" / name
    run.mkdir(parents=True)
    (run / "config.json").write_text(json.dumps({"scenario": str(scen / f"{name}.sumocfg"), "ego": {"width": 1.6}}))
    (run / "hazard_events.json").write_text(json.dumps([{"hazard": "h0", "event": "trigger", **trigger}]))
    pd.DataFrame([{"involves_ego": True, "detector": "geometry", "id_b": "hazard_h0", "speed_a": 0.0,
                   "fault": "other", **collision}]).to_parquet(run / "collisions.parquet")
    return run


def test_rows_of_a_cut_in_and_a_drift(tmp_path):
    cut = _run(tmp_path, "s1", {"id": "h0", "type": "cut_in", "params": {"vtype": "car"}},
               {"time": 10.0, "actor_s": 30.0, "ego_front_s": 17.0, "ego_speed": 27.0, "actor_speed": 17.0},
               {"time": 11.5})
    row = hm.margins(cut)
    # the actor's rear 30 - 2 = 28 m, the ego's front 17 m: 11 m; closing 27 - 17 = 10 m/s
    assert row["gap at trigger [m]"] == 11.0 and row["closing [m/s]"] == 10.0
    assert row["decel needed, 0 s late [m/s^2]"] == 4.5 and row["decel needed, 0.5 s late [m/s^2]"] == 8.3

    drift = _run(tmp_path, "s2", {"id": "h0", "type": "oncoming_drift",
                                  "params": {"vtype": "car", "lane_offset": 3.0, "drift": 1.5}},
                 {"time": 20.0, "actor_s": 50.0, "ego_front_s": 30.0, "ego_speed": 0.0, "actor_speed": -7.0},
                 {"time": 22.0})
    row = hm.margins(drift)
    # the actor's centre 3.0 - 1.5 = 1.5 m from the ego's lane centre; half widths 1.0 + 0.8 = 1.8
    assert row["overlap at lane centre [m]"] == pytest.approx(0.3)
    assert row["room to lane edge [m]"] == pytest.approx(0.7)  # (3.0 - 1.6) / 2


def test_an_unconfirmed_sumo_report_is_not_a_row(tmp_path):
    run = _run(tmp_path, "s3", {"id": "h0", "type": "cut_in", "params": {"vtype": "car"}},
               {"time": 10.0, "actor_s": 30.0, "ego_front_s": 17.0, "ego_speed": 27.0, "actor_speed": 17.0},
               {"time": 11.5, "detector": "sumo_unconfirmed"})
    assert hm.margins(run) is None
