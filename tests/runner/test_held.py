"""A timeout says what held the ego (summary.json ``held``, the run's message): a red light and
for how long, a road user standing ahead on its path, no way on, or the time limit with the ego
still moving. Pure cases first, then short real SUMO runs with the baseline controller."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from conftest import write_scenario
from sumo_ethics.notes import BLOCKER_REACH, HELD_REASONS, RunNotes, blocker_ahead, held

NAN = float("nan")


def notes_of(speeds: list[float], dt: float = 1.0, validity: float = NAN) -> RunNotes:
    n = RunNotes([], 0.2, 0.05)
    for i, v in enumerate(speeds):
        n.step(i * dt, 10.0 * i, v, 3, NAN, "a_0", validity)
    return n


def test_still_moving_at_the_time_limit():
    h = held(notes_of([5.0, 6.0, 7.5]), 120.4, None, None)
    assert h["reason"] == "moving" and h["speed"] == 7.5 and h["route_left"] == 120.4
    assert h["says"] == "the ego was still moving (7.5 m/s, 120 m of its route left)"


def test_red_light_names_how_long_and_when_the_phase_ends():
    n = notes_of([8.0, 3.0, 0.05, 0.0, 0.0, 0.0])  # standing from t = 2 s to t = 5 s
    h = held(n, 300.0, {"distance": 1.6, "phase_ends": 10006.0}, None)
    assert h["reason"] == "red_light" and (h["since"], h["duration"]) == (2.0, 3.0)
    assert h["says"] == "the ego stood 3 s at a red light (stop line 2 m ahead; the signal's phase ends at t=10006 s)"
    queued = held(n, 300.0, {"distance": 26.0, "phase_ends": None},
                  {"id": "4_left.2", "class": "car", "gap": 2.1, "speed": 0.0})
    assert queued["reason"] == "red_light" and "behind car '4_left.2'" in queued["says"]
    far = held(n, 300.0, {"distance": 80.0, "phase_ends": None}, None)  # too far ahead to hold it
    assert far["reason"] == "no_way_on"


def test_road_user_standing_ahead():
    n = notes_of([0.0] * 11)
    blocker = {"id": "parked", "class": "truck", "gap": 3.25, "speed": 0.0}
    h = held(n, 80.0, None, blocker)
    assert h["reason"] == "road_user_ahead" and h["duration"] == 10.0 and h["blocker"] == blocker
    assert h["says"] == "the ego stood 10 s behind truck 'parked', standing 3.2 m ahead on its path"


@pytest.mark.parametrize("validity, why", [(4.0, " (no candidate was feasible)"), (1.0, " (standing cost least)"),
                                           (NAN, "")])
def test_no_way_on(validity, why):
    h = held(notes_of([0.0] * 5, validity=validity), 80.0, None, None)
    assert h["reason"] == "no_way_on" and h["reason"] in HELD_REASONS
    assert h["says"] == f"the ego stood 4 s with no red light and no standing road user ahead: its controller found " \
                        f"no way on{why}"


def test_blocker_ahead_is_the_nearest_standing_one_on_the_path():
    # ego centre at s = 100, half length 2.25: its front at 102.25
    ps = np.array([110.0, 106.0, 90.0, 104.5, 140.0, 107.0])
    pd = np.array([0.3, 2.5, 0.0, 0.0, 0.0, -1.0])
    speed = np.array([0.0, 0.0, 0.0, 3.0, 0.0, 0.2])
    length = np.full(6, 4.0)
    ids = ["a", "beside", "behind", "moving", "far", "b"]
    labels = ["car", "car", "car", "car", "car", "bicycle"]
    got = blocker_ahead(100.0, 2.25, ps, pd, speed, length, ids, labels)
    assert got == {"id": "b", "class": "bicycle", "gap": 2.75, "speed": 0.2}  # 107 - 2 - 102.25
    assert blocker_ahead(100.0, 2.25, ps[:5], pd[:5], speed[:5], length[:5], ids[:5], labels[:5])["id"] == "a"
    assert math.isclose(140.0 - 2 - 102.25, 35.75) and 35.75 > BLOCKER_REACH  # "far" is beyond reach
    assert blocker_ahead(100.0, 2.25, ps[2:3], pd[2:3], speed[2:3], length[2:3], ["behind"], ["car"]) is None


# ---- real SUMO: a few simulated seconds with the baseline controller ---------------------------
def _run(cfg, out, end):
    from sumo_ethics.config import RunConfig
    from sumo_ethics.runner import run

    s = run(RunConfig(cfg, out, end=end, ego_id="ego", controller="baseline", progress=False))
    return s, json.loads((out / "summary.json").read_text())


@pytest.mark.sumo
def test_timeout_at_a_red_light(tmp_path):
    from conftest import build_signalised

    net, add = build_signalised(tmp_path / "net")  # C held red for 1000 s
    (tmp_path / "r.rou.xml").write_text("""<routes>
      <vType id="car" vClass="passenger" length="4.5" width="1.8"/>
      <vehicle id="ego" type="car" depart="0" departPos="70" departSpeed="5"><route edges="WC CE"/></vehicle>
    </routes>""")
    cfg = tmp_path / "x.sumocfg"
    cfg.write_text(f'<configuration><input><net-file value="{net}"/><route-files value="r.rou.xml"/>'
                   f'<additional-files value="{add}"/></input><time><end value="30"/><step-length value="0.1"/></time>'
                   '</configuration>')
    s, d = _run(cfg, tmp_path / "run", 14.0)
    h = d["held"]
    assert s.status.value == "timeout" and h["reason"] == "red_light", d["message"]
    assert h["phase_ends"] == 1000.0 and h["stop_line"] < 5.0 and 3.0 < h["duration"] < 14.0
    assert d["message"].startswith("time limit 14 s reached; the ego stood ") and "at a red light" in d["message"]


@pytest.mark.sumo
def test_timeout_behind_a_standing_car_and_still_moving(tmp_path):
    cfg = write_scenario(tmp_path / "s", """
      <vehicle id="parked" type="car" route="r_main" depart="0" departLane="1" departPos="60" departSpeed="0">
        <stop lane="main_0_1" endPos="60.5" duration="1000"/></vehicle>
      <vehicle id="ego" type="car" route="r_main" depart="0" departLane="1" departPos="20" departSpeed="5"/>""")
    s, d = _run(cfg, tmp_path / "run", 20.0)
    h = d["held"]
    assert s.status.value == "timeout" and h["reason"] == "road_user_ahead", d["message"]
    assert h["blocker"]["id"] == "parked" and h["blocker"]["class"] == "car" and h["blocker"]["gap"] < 10.0
    assert "behind car 'parked'" in d["message"]
    s, d = _run(cfg, tmp_path / "early", 2.0)  # 2 s: the ego is still driving up to it
    assert d["held"]["reason"] == "moving" and d["held"]["speed"] > 1.0
    assert "the ego was still moving" in d["message"]
