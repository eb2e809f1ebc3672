"""Fleets: several egos in one run (sumo_ethics.runner.fleet), on the bundled testbed and urban_grid."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from conftest import SCENARIOS, Scripted, write_scenario, sumo_binary
from sumo_ethics.config import FleetSpec, RunConfig
from sumo_ethics.errors import ConfigError
from sumo_ethics.runner.fleet import draw, fleet_booking, inserted_departs, planner_of, run_fleet, union_states
from sumo_ethics.plan.baseline import RouteFollower
from sumo_ethics.contract import Decision, Scene
from sumo_ethics.sim.session import FORCED_OPTIONS
from sumo_ethics.types import AgentStates, Prediction


# ---- who becomes an ego, with which planner (no SUMO) -------------------------------------------
def test_fleet_shares_hold_over_a_large_draw():
    shares = (("ethical", 0.5), ("ego", 0.3), ("baseline", 0.2))
    n = 20_000
    names = [planner_of(7, f"veh{i}", shares) for i in range(n)]
    for name, share in shares:
        got = names.count(name) / n
        assert abs(got - share) < 4 * math.sqrt(share * (1 - share) / n), (name, got)
    # the same seed and id give the same planner; another seed reshuffles
    assert names[:200] == [planner_of(7, f"veh{i}", shares) for i in range(200)]
    assert names[:200] != [planner_of(8, f"veh{i}", shares) for i in range(200)]


def test_penetration_draws_are_nested_and_hold_their_share():
    ids = [f"v{i}" for i in range(10_000)]
    at = {p: {k for k in ids if draw(3, 0, k) < p} for p in (0.1, 0.25, 0.5)}
    assert at[0.1] <= at[0.25] <= at[0.5]  # the egos at 10 % stay egos at 25 %
    for p, egos in at.items():
        assert abs(len(egos) / len(ids) - p) < 4 * math.sqrt(p * (1 - p) / len(ids))
    # the planner draw is a separate stream: it is not the penetration draw
    assert [draw(3, 0, k) for k in ids[:5]] != [draw(3, 1, k) for k in ids[:5]]


def test_inserted_departures_spread_over_the_first_half():
    assert inserted_departs(4, 100.0, 500.0, 0.1) == pytest.approx([100.0, 150.0, 200.0, 250.0])
    assert inserted_departs(1, 0.0, 60.0, 0.1) == [0.0]


@pytest.mark.parametrize("kwargs, message", [
    ({"egos": -1}, "--egos"),
    ({"penetration": 1.5}, "--penetration"),
    ({"ids": ("a", "a")}, "same vehicle twice"),
    ({"shares": (("ethical", 0.5), ("ego", 0.4))}, "sum to 1"),
    ({"shares": (("ethical", 0.5), ("ethical", 0.5))}, "twice"),
])
def test_fleet_spec_refuses_bad_input(kwargs, message):
    with pytest.raises(ConfigError, match=message):
        FleetSpec(**kwargs)


def test_fleet_shares_parse():
    assert FleetSpec.parse_shares("ethical=0.5, ego=0.5") == (("ethical", 0.5), ("ego", 0.5))
    assert FleetSpec.parse_shares("baseline") == (("baseline", 1.0),)
    with pytest.raises(ConfigError, match="not a number"):
        FleetSpec.parse_shares("ethical=half")


def test_fleet_booking_of_an_ego_ego_collision_books_both_once():
    row = {"id_a": "A", "id_b": "B", "class_b": "car", "harm_a": 0.2, "harm_b": 0.3, "involves_ego": True,
           "detector": "geometry"}
    both = fleet_booking(row, {"A", "B"})
    assert both == {"ego_a": True, "ego_b": True, "harm_ego": 0.5, "harm_third_party": 0.0, "harm_vru": 0.0}
    one = fleet_booking(row | {"class_b": "pedestrian"}, {"A"})
    assert one == {"ego_a": True, "ego_b": False, "harm_ego": 0.2, "harm_third_party": 0.3, "harm_vru": 0.3}
    unconfirmed = fleet_booking(row | {"detector": "sumo_unconfirmed"}, {"A", "B"})
    assert unconfirmed["harm_ego"] == unconfirmed["harm_third_party"] == 0.0


def _agents(ids, x):
    n = len(ids)
    return AgentStates(tuple(ids), np.asarray(x, float), np.zeros(n), np.zeros(n), np.ones(n), np.zeros(n),
                       np.full(n, 4.5), np.full(n, 1.8), np.full(n, 1500.0), np.zeros(n, np.int8), ("car",) * n)


def test_union_of_what_the_egos_see_keeps_each_road_user_once():
    u = union_states([_agents(["e1"], [0.0]), _agents(["b", "a"], [5.0, 7.0]), _agents(["a", "e1"], [99.0, 99.0])])
    assert u.ids == ("a", "b", "e1")
    assert list(u.x) == [7.0, 5.0, 0.0]  # the first state seen of each (an ego's own read first)


def test_prediction_take_keeps_every_mode_of_a_subset():
    n, t = 3, 4
    mean = np.arange(n * t * 2, dtype=float).reshape(n, t, 2)
    cov = np.broadcast_to(np.eye(2), (n, t, 2, 2)).copy()
    alt = Prediction(("a", "b", "c"), 0.1, mean + 100, cov, np.zeros((n, t)))
    p = Prediction(("a", "b", "c"), 0.1, mean, cov, np.zeros((n, t)), (alt,), np.array([[0.7, 0.3], [0.6, 0.4],
                                                                                        [0.9, 0.1]]))
    sub = p.take([2, 0])
    assert sub.ids == ("c", "a")
    assert np.array_equal(sub.mean, mean[[2, 0]])
    assert np.array_equal(sub.alternatives[0].mean, mean[[2, 0]] + 100)
    assert np.array_equal(sub.weight, [[0.9, 0.1], [0.7, 0.3]])


# ---- in SUMO -------------------------------------------------------------------------------------
class Recording:
    """A controller that keeps every command it gives (time of the scene -> pose)."""

    def __init__(self, inner) -> None:
        self.inner = inner
        self.name = inner.name
        self.needs_history = getattr(inner, "needs_history", False)
        self.commands: dict[float, tuple[float, float]] = {}

    def __getattr__(self, name):
        return getattr(self.inner, name)

    def act(self, scene: Scene) -> Decision:
        d = self.inner.act(scene)
        self.commands[round(scene.time, 6)] = (d.command.x, d.command.y)
        return d


@pytest.mark.sumo
def test_two_egos_each_driven_by_its_own_planner(tmp_path, scenario_dir):
    routes = ('<vehicle id="a" type="car" route="r_main" depart="0" departPos="80" departLane="1" departSpeed="5"/>'
              '<vehicle id="b" type="car" route="r_main" depart="2" departPos="10" departLane="2" departSpeed="8"/>'
              '<vehicle id="c" type="car" route="r_main" depart="0" departPos="40" departLane="1" departSpeed="4"/>')
    cfg = write_scenario(scenario_dir, routes, end=20.0)
    made: dict[str, Recording] = {}

    def make(name: str, vid: str):
        made[vid] = Recording(Scripted(6.0) if vid == "a" else RouteFollower())
        return made[vid]

    rc = RunConfig(scenario=cfg, out=tmp_path / "run", progress=False,
                   fleet=FleetSpec(ids=("a", "b"), shares=(("baseline", 1.0),)))
    summary = run_fleet(rc, make)
    steps = pd.read_parquet(tmp_path / "run" / "steps.parquet")
    assert set(steps["ego_id"]) == {"a", "b"}
    for vid, rec in made.items():
        own = steps[steps["ego_id"] == vid]
        assert len(own) > 100
        # the pose recorded after each step is the pose its own planner chose for that step
        planned = np.array([rec.commands[round(t - 0.1, 6)] for t in own["time"]])
        err = np.hypot(own["x"].to_numpy() - planned[:, 0], own["y"].to_numpy() - planned[:, 1])
        assert err.max() < 0.03, (vid, err.max())
    a = steps[steps["ego_id"] == "a"]
    moved = np.hypot(np.diff(a["x"]), np.diff(a["y"]))
    assert np.allclose(moved[1:], 0.6, atol=0.01)  # SUMO placed it 6 m/s x 0.1 s apart: its own speed, not b's
    b = steps[steps["ego_id"] == "b"]
    assert b["y"].iloc[-1] == pytest.approx(-1.6, abs=0.2)  # b kept its own lane (the left one)
    egos = {e["id"]: e for e in summary.data["egos"]}
    assert set(egos) == {"a", "b"} and summary.data["fleet"]["egos"] == 2
    assert json.loads((tmp_path / "run" / "config.json").read_text())["fleet"]["ids"] == ["a", "b"]


@pytest.mark.sumo
def test_an_ego_ego_collision_is_one_event_with_harm_to_both(tmp_path, scenario_dir):
    routes = ('<vehicle id="front" type="car" route="r_main" depart="0" departPos="60" departLane="1" departSpeed="3"/>'
              '<vehicle id="back" type="car" route="r_main" depart="0" departPos="10" departLane="1" departSpeed="12"/>'
              # traffic that goes on after the crash (the crashed egos leave the road while it drives)
              '<vehicle id="other" type="car" route="r_main" depart="0" departPos="5" departLane="2" departSpeed="5"/>')
    cfg = write_scenario(scenario_dir, routes, end=20.0)
    speeds = {"front": 3.0, "back": 12.0}
    rc = RunConfig(scenario=cfg, out=tmp_path / "run", progress=False,
                   fleet=FleetSpec(ids=("front", "back"), shares=(("baseline", 1.0),)))
    summary = run_fleet(rc, lambda name, vid: Scripted(speeds[vid]))
    col = pd.read_parquet(tmp_path / "run" / "collisions.parquet")
    ego = col[col["involves_ego"]]
    assert len(ego) == 1  # one event, not one per ego
    r = ego.iloc[0]
    assert r["ego_a"] and r["ego_b"] and {r["id_a"], r["id_b"]} == {"front", "back"}
    # a rear-end impact of equal masses at 12 and 3 m/s: closing speed 9 m/s, each 4.5 m/s change
    assert r["delta_v"] == pytest.approx(9.0, abs=0.01)
    assert r["dv_a"] == pytest.approx(4.5, abs=0.01) and r["dv_b"] == pytest.approx(4.5, abs=0.01)
    assert r["harm_ego"] == pytest.approx(r["harm_a"] + r["harm_b"]) and r["harm_third_party"] == 0.0
    assert summary.data["harm"]["ego"] == pytest.approx(r["harm_a"] + r["harm_b"])
    assert summary.data["collisions"]["ego_ego"] == 1
    assert {e["id"]: e["status"] for e in summary.data["egos"]} == {"front": "collision", "back": "collision"}
    assert summary.data["status"] == "completed" and summary.data["sim_time"] == pytest.approx(20.0)
    trips = pd.read_parquet(tmp_path / "run" / "trips.parquet").set_index("id")
    assert not trips.loc["front", "arrived"] and not trips.loc["back", "arrived"]  # taken off the road
    assert trips.loc["other", "distance"] > 80.0  # and the traffic drove on
    assert "trips_error" not in summary.data  # summary.json's vehicle-km: the trips' distances driven
    veh = trips[trips["kind"] == "vehicle"]
    assert summary.data["traffic"]["vehicle_km"] == pytest.approx(veh["distance"].sum() / 1e3)


def _plain_sumo_trips(cfg: Path, out: Path, end: float, seed: int = 42) -> pd.DataFrame:
    from sumo_ethics.record.trips import read_tripinfo

    cmd = [sumo_binary("sumo"), "-c", str(cfg), "--seed", str(seed), "--end", f"{end:g}",
           "--no-step-log", "true", "--tripinfo-output", str(out), "--tripinfo-output.write-unfinished", "true"]
    for k, v in FORCED_OPTIONS.items():  # the collision reporting a run switches on (it changes no motion)
        cmd += [f"--{k}", v]
    subprocess.run(cmd, check=True, capture_output=True)
    return read_tripinfo(out)


@pytest.mark.sumo
def test_penetration_zero_reproduces_the_plain_sumo_trips(tmp_path):
    scenario = SCENARIOS / "urban_grid" / "urban_grid.sumocfg"
    rc = RunConfig(scenario=scenario, out=tmp_path / "run", progress=False, end=90.0, fleet=FleetSpec(penetration=0.0))
    summary = run_fleet(rc)
    assert summary.data["fleet"]["egos"] == 0
    ours = pd.read_parquet(tmp_path / "run" / "trips.parquet")
    plain = _plain_sumo_trips(scenario, tmp_path / "plain.xml", 90.0)
    assert len(ours) > 50 and not ours["ego"].any()
    cols = ["id", "kind", "depart", "arrival", "duration", "distance", "time_loss", "waiting_time"]
    pd.testing.assert_frame_equal(ours[cols].reset_index(drop=True), plain[cols].reset_index(drop=True))


@pytest.mark.sumo
def test_penetration_one_makes_every_eligible_vehicle_an_ego(tmp_path):
    scenario = SCENARIOS / "urban_grid" / "urban_grid.sumocfg"
    rc = RunConfig(scenario=scenario, out=tmp_path / "run", progress=False, end=40.0,
                   fleet=FleetSpec(penetration=1.0, shares=(("baseline", 1.0),)))
    summary = run_fleet(rc)
    f = summary.data["fleet"]
    trips = pd.read_parquet(tmp_path / "run" / "trips.parquet")
    motor = trips[(trips["kind"] == "vehicle") & trips["vclass"].isin(["passenger", "truck", "bus", "motorcycle",
                                                                        "delivery", "trailer"])]
    assert f["egos"] == f["eligible"] > 5
    assert f["eligible"] <= len(motor)
    assert set(trips.loc[trips["ego"], "id"]) == {e["id"] for e in summary.data["egos"]}
    assert not trips.loc[trips["kind"] == "person", "ego"].any()
    assert not trips.loc[trips["vclass"] == "bicycle", "ego"].any()
    steps = pd.read_parquet(tmp_path / "run" / "steps.parquet")
    assert set(steps["ego_id"]) <= {e["id"] for e in summary.data["egos"]}
    # plausible motion of every ego, from the positions SUMO reports: no jumps, accelerations within
    # the limits the baseline drives with (the first step after a takeover included)
    for _, e in steps.groupby("ego_id"):
        v = np.hypot(np.diff(e["x"]), np.diff(e["y"])) / 0.1
        assert v.max() < 25.0
        assert (np.diff(v) / 0.1).min() > -8.5 and (np.diff(v) / 0.1).max() < 3.5


@pytest.mark.sumo
def test_the_single_ego_run_writes_no_fleet_columns(tmp_path, scenario_dir):
    from sumo_ethics.runner import run

    routes = '<vehicle id="a" type="car" route="r_main" depart="0" departPos="80" departLane="1" departSpeed="5"/>'
    cfg = write_scenario(scenario_dir, routes, end=5.0)
    run(RunConfig(scenario=cfg, out=tmp_path / "run", progress=False, ego_id="a"), Scripted(5.0))
    assert "fleet" not in json.loads((tmp_path / "run" / "config.json").read_text())
    assert "ego_id" not in pd.read_parquet(tmp_path / "run" / "steps.parquet").columns
    assert "ego_b" not in pd.read_parquet(tmp_path / "run" / "collisions.parquet").columns
    assert not (tmp_path / "run" / "trips.parquet").exists()


@pytest.mark.sumo
@pytest.mark.parametrize("sig", ["SIGKILL", "SIGTERM"])
def test_a_killed_fleet_run_keeps_its_rows(tmp_path, sig):
    import signal
    import sys
    import time

    from sumo_ethics.record.reader import read_table, recover_summary

    out = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-m", "sumo_ethics.cli", "run", str(SCENARIOS / "testbed" / "testbed.sumocfg"),
                             "--egos", "3", "--fleet", "baseline", "--end", "300", "--quiet", "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not (out / "partial").is_dir() or len(read_table(out, "steps")) < 100:  # a few chunks on disk
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline
        time.sleep(0.05)
    proc.send_signal(getattr(signal, sig))
    _, err = proc.communicate(timeout=60)
    steps = read_table(out, "steps").to_pandas()
    assert len(steps) >= 100 and {"ego_id", "planner"} <= set(steps.columns)
    s = recover_summary(out)
    if sig == "SIGKILL":
        assert s["status"] == "incomplete" and s["fleet"]["egos"] == steps["ego_id"].nunique()
    else:
        assert proc.returncode == 143 and len(err.strip().splitlines()) == 1, err
        assert s["status"] == "interrupted" and s["ego_steps"] == len(steps)
        assert s["fleet"]["egos"] >= steps["ego_id"].nunique()
    # each ego's distance from its own first row to its last, not across egos
    per = steps.groupby("ego_id")["s"].agg(lambda v: v.iloc[-1] - v.iloc[0])
    assert s["distance"] == pytest.approx(per.sum(), rel=0.05)


def test_traffic_table_rates_by_hand():
    from sumo_ethics.analysis.stats import traffic_table

    runs = pd.DataFrame({
        "penetration": [0.1, 0.1, 0.5], "fleet_egos": [2.0, 4.0, 10.0],
        "harm_all_egos": [0.5, 0.0, 1.0], "harm_all_other_vehicles": [0.0, 0.25, 0.0], "harm_all_vru": [0.1, 0.0, 0.0],
        "harm_all_total": [0.6, 0.25, 1.0], "vehicle_km": [1000.0, 3000.0, 2000.0], "person_km": [1.0, 1.0, 1.0],
        "time_loss_egos": [10.0, 20.0, 5.0], "time_loss_other_vehicles": [1.0, 3.0, 2.0],
        "time_loss_persons": [np.nan, 4.0, 6.0], "conflicts_total": [2.0, 1.0, 0.0], "distance": [5000.0, 10000.0, 2000.0],
    })
    t = traffic_table(runs, ["penetration"], n_boot=200).set_index("penetration")
    # 0.5 harm to egos over 4,000 vehicle-km = 125 per 10^6 vehicle-km
    assert t.loc[0.1, "harm_egos_per_Mvkm"] == pytest.approx(125.0)
    assert t.loc[0.1, "harm_vru_per_Mvkm"] == pytest.approx(25.0)
    assert t.loc[0.1, "harm_total_per_Mvkm"] == pytest.approx(212.5)
    assert t.loc[0.1, "conflicts_per_100km"] == pytest.approx(20.0)  # 3 conflicts over 15 ego-km
    assert t.loc[0.1, "time_loss_egos"] == pytest.approx(15.0) and t.loc[0.1, "time_loss_persons"] == 4.0
    assert t.loc[0.1, "egos"] == 3.0 and t.loc[0.5, "harm_egos_per_Mvkm"] == pytest.approx(500.0)
    lo, hi = t.loc[0.1, "time_loss_egos_ci_lo"], t.loc[0.1, "time_loss_egos_ci_hi"]
    assert 10.0 <= lo <= 15.0 <= hi <= 20.0
    assert traffic_table(runs.drop(columns=["vehicle_km"]), ["penetration"]).empty  # no fleet runs


@pytest.mark.sumo
def test_named_planner_tables_of_the_toml_drive_their_share(tmp_path, capfd):
    from sumo_ethics.cli import main
    from sumo_ethics.ethics.cost import PRESETS

    toml = tmp_path / "fleet.toml"
    toml.write_text('[planner]\nomega_u = 0.25\n\n[planners.cautious]\nweights = "maximin"\nmax_risk = 0.01\n')
    out = tmp_path / "run"
    code = main(["run", str(SCENARIOS / "testbed" / "testbed.sumocfg"), "--egos", "2", "--fleet", "cautious",
                 "--config", str(toml), "--end", "6", "--quiet", "--out", str(out)])
    assert code == 0, capfd.readouterr().err
    cfg = json.loads((out / "config.json").read_text())
    (name, pc), = cfg["fleet"]["planners"]
    assert name == "cautious" and pc["max_risk"] == 0.01 and pc["cost"]["omega_u"] == 0.25  # [planner] underneath
    assert pc["cost"]["weights"]["maximin"] == PRESETS["maximin"].maximin > 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["fleet"]["by_planner"] == {"cautious": 2}
    assert main(["run", str(SCENARIOS / "testbed" / "testbed.sumocfg"), "--egos", "2", "--fleet", "careful",
                 "--config", str(toml), "--quiet", "--out", str(tmp_path / "r2")]) == 2
    assert "unknown planner 'careful'" in capfd.readouterr().err


@pytest.mark.sumo
def test_a_fleet_run_is_the_same_bytes_with_the_same_seed(tmp_path):
    scenario = SCENARIOS / "urban_grid" / "urban_grid.sumocfg"
    outs = []
    for k in range(2):
        rc = RunConfig(scenario=scenario, out=tmp_path / f"run{k}", progress=False, end=30.0, seed=5,
                       fleet=FleetSpec(egos=3, penetration=0.3, shares=(("baseline", 1.0),)))
        run_fleet(rc)
        outs.append(tmp_path / f"run{k}")
    for name in ("steps.parquet", "collisions.parquet", "conflicts.parquet", "trips.parquet"):
        assert (outs[0] / name).read_bytes() == (outs[1] / name).read_bytes(), name
    assert pd.read_parquet(outs[0] / "steps.parquet")["ego_id"].nunique() >= 5


def test_shared_prediction_is_one_call_giving_each_ego_its_rows():
    from sumo_ethics.runner.fleet import SharedPrediction
    from sumo_ethics.plan.history import History
    from sumo_ethics.predict import ConstantVelocityPredictor

    union = _agents(["a", "b", "c", "d"], [0.0, 10.0, 20.0, 30.0])
    h = History(0.1)
    h.push(union)
    shared = SharedPrediction(ConstantVelocityPredictor())
    shared.begin(h.observation(0.0, AgentStates.empty(), union))
    for ids in (["d", "a"], ["b"]):
        sub = union.take([union.index[k] for k in ids])
        obs = h.observation(0.0, union.take([0]), sub)
        got = shared.predict(obs, 30, 0.1)
        own = ConstantVelocityPredictor().predict(obs, 30, 0.1)  # constant velocity: one agent's own alone
        assert got.ids == tuple(ids) and np.array_equal(got.mean, own.mean) and np.array_equal(got.cov, own.cov)
    assert shared.calls == 1


def test_the_priors_done_once_for_the_union_give_each_ego_its_own_rows():
    """A fleet's planners take their priors (lateral drift, hard braking) from the shared prediction,
    done once per step for every road user any ego sees: each ego's rows are exactly what its own
    priors on its own road users give, and the priors did move them (a braking car held within its
    stopping distance)."""
    from sumo_ethics.plan.ethical import EthicalPlanner, PlannerConfig
    from sumo_ethics.plan.history import History
    from sumo_ethics.predict import ConstantVelocityPredictor
    from sumo_ethics.runner.fleet import SharedPrediction

    ids = ["a", "b", "c", "d"]
    h = History(0.1)
    for k in range(12):  # a drifts left at 1.5 m/s; b brakes at 6 m/s^2 from 12 m/s; d stands
        t = 0.1 * k
        st = AgentStates(tuple(ids), np.array([10.0 * t, 20.0 + 12.0 * t - 3.0 * t * t, 40.0 + 8.0 * t, 60.0]),
                         np.array([1.5 * t, 3.5, -3.5, 0.0]), np.zeros(4), np.array([10.0, 12.0 - 6.0 * t, 8.0, 0.0]),
                         np.array([0.0, -6.0, 0.0, 0.0]), np.full(4, 4.5), np.full(4, 1.8), np.full(4, 1500.0),
                         np.zeros(4, np.int8), ("car",) * 4)
        h.push(st)
    shared = SharedPrediction(ConstantVelocityPredictor())
    shared.begin(h.observation(1.1, AgentStates.empty(), st))
    cfg = PlannerConfig(predictor="cv")
    for sub_ids in (["b", "a"], ["c", "a", "d"]):
        sub = st.take([st.index[k] for k in sub_ids])
        obs = h.observation(1.1, st.take([3]), sub)
        via_union, n_union = EthicalPlanner(cfg, predictor=shared)._predict(obs, 40, 0.1)
        own, n_own = EthicalPlanner(cfg, predictor=ConstantVelocityPredictor())._predict(obs, 40, 0.1)
        raw = ConstantVelocityPredictor().predict(obs, 40, 0.1)
        assert via_union.ids == own.ids == tuple(sub_ids) and n_union == n_own == 0
        for f in ("mean", "cov", "yaw"):
            np.testing.assert_array_equal(getattr(via_union, f), getattr(own, f))
        if "b" in sub_ids:  # b: 12 - 6 x 1.1 = 5.4 m/s at -6 m/s^2 stops within 5.4^2 / 12 = 2.43 m (cv: 21.6 m in 4 s)
            b = sub_ids.index("b")
            assert np.hypot(*(own.mean[b, -1] - st.xy[1])) == pytest.approx(5.4**2 / 12.0, abs=0.05)
            assert np.hypot(*(raw.mean[b, -1] - st.xy[1])) == pytest.approx(21.6, abs=0.05)
    assert sum(1 for key in shared.cache if key[0] == "prepared") == 1  # one union, one set of priors


@pytest.mark.sumo
def test_a_fleet_of_planners_is_the_same_bytes_on_one_or_two_threads(tmp_path):
    """The egos plan on the kernels' threads (sumo_ethics.cores), their results taken in order: the
    same outputs as one thread, with staggered replanning and shared plans on."""
    from sumo_ethics import cores
    from sumo_ethics.plan.ethical import PlannerConfig
    from sumo_ethics.runner.fleet import make_fleet_controllers

    scenario = SCENARIOS / "urban_grid" / "urban_grid.sumocfg"
    before = cores.threads()
    outs = []
    try:
        for n in (1, 2):
            cores.set_threads(n)
            rc = RunConfig(scenario=scenario, out=tmp_path / f"run{n}", progress=False, end=14.0, seed=4,
                           planner=PlannerConfig(predictor="cv", replan_every=2, share_plans=True),
                           fleet=FleetSpec(egos=3, shares=(("ethical", 1.0),)))
            run_fleet(rc, make_fleet_controllers(rc))
            outs.append(tmp_path / f"run{n}")
    finally:
        cores.set_threads(before)
    for name in ("steps.parquet", "collisions.parquet", "trips.parquet"):
        assert (outs[0] / name).read_bytes() == (outs[1] / name).read_bytes(), name
    steps = pd.read_parquet(outs[0] / "steps.parquet")
    assert steps["ego_id"].nunique() == 3 and (steps["replanned"] == 0).any() and (steps["replanned"] > 0).any()


def test_the_first_line_of_a_fleet_run_counts_its_egos_outcomes():
    """The run's own status ('completed': it reached its end) says nothing of the egos: the line
    counts them first, every outcome named even at 0, and says how the run ended last."""
    from sumo_ethics.cli import fleet_outcome_line

    d = {"status": "completed", "message": "time limit 30 s reached",
         "fleet": {"egos": 12, "by_status": {"timeout": 12}}}
    assert fleet_outcome_line(d) == ("12 egos: 0 completed, 0 collision, 12 timeout, 0 error; the run ended: "
                                     "time limit 30 s reached")
    d["fleet"] = {"egos": 4, "by_status": {"teleported": 1, "completed": 2, "collision": 1}}
    assert fleet_outcome_line(d).startswith("4 egos: 2 completed, 1 collision, 0 timeout, 0 error, 1 teleported;")
    d["fleet"] = {"egos": 0, "by_status": {}}
    assert fleet_outcome_line(d) == "no ego was taken over; the run ended: time limit 30 s reached"


@pytest.mark.sumo
def test_a_fleet_run_prints_its_egos_outcomes_first(tmp_path):
    out = tmp_path / "run"
    p = subprocess.run([sys.executable, "-m", "sumo_ethics.cli", "run", str(SCENARIOS / "testbed" / "testbed.sumocfg"),
                        "--egos", "2", "--fleet", "baseline", "--end", "3", "--quiet", "--out", str(out)],
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    first = p.stdout.splitlines()[0]
    s = json.loads((out / "summary.json").read_text())
    n = s["fleet"]["by_status"]
    assert s["status"] == "completed" and n.get("completed", 0) == 0  # the run ended, the egos did not
    assert first == (f"{s['fleet']['egos']} egos: 0 completed, {n.get('collision', 0)} collision, "
                     f"{n.get('timeout', 0)} timeout, 0 error; the run ended: time limit 3 s reached"), p.stdout
