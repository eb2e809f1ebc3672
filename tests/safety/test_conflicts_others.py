"""Conflicts among the road users that are not egos (``[conflicts] everyone``,
sumo_ethics.safety.pairs): numbers worked by hand on pairs, then real SUMO runs on the testbed."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest

from sumo_ethics.config import ConflictConfig
from sumo_ethics.errors import ConfigError
from sumo_ethics.record import schema
from sumo_ethics.record.reader import read_table, recover_summary
from sumo_ethics.record.recorder import RunRecorder
from sumo_ethics.safety.pairs import PairConflictBook, pair_counts
from sumo_ethics.settings import conflicts_config
from sumo_ethics.types import RoadUserClass as C

from conftest import write_scenario
from test_conflicts import DT, Sink, agents

EVERYONE = ConflictConfig(everyone=True)


def observe(book, t, step, *parts, exclude=()):
    """One step of ``book`` with the road users of ``parts`` (ids sorted, as the sim reads them)."""
    from sumo_ethics.runner.fleet import union_states

    s = union_states(list(parts))
    book.observe(t, step, s, np.zeros(len(s)), frozenset(exclude))


def test_head_on_pair_ttc_drac_and_distance():
    # the ego book's head-on case, for two cars neither of which is an ego: centres 40 m apart at
    # t = 0, 10 m/s each; gap 35.5 - 20 t, TTC = 1.775 - t, below 1.5 s at the steps 0.3, 0.4, 0.5
    sink = Sink()
    book = PairConflictBook(sink, EVERYONE, DT)
    for k in range(6):
        t = round(k * DT, 10)
        observe(book, t, k, agents(["c1"], 10 * t, 0.0, 0.0, 10.0, 4.5, 1.8, C.CAR),
                agents(["c2"], 40 - 10 * t, 0.0, math.pi, 10.0, 4.5, 1.8, C.CAR))
    r, = sink.conflicts
    assert (r["id_a"], r["id_b"], r["class_a"], r["class_b"], r["type_a"]) == ("c1", "c2", "car", "car", "t")
    assert r["start"] == pytest.approx(0.3) and r["end"] == pytest.approx(0.5) and r["n_steps"] == 3
    assert r["step_start"] == 3 and r["ttc_below"] and not r["pet_below"] and not r["contact"]
    assert r["min_ttc"] == pytest.approx(1.275) and r["min_distance"] == pytest.approx(25.5)
    assert r["max_drac"] == pytest.approx(20.0 / (2 * 1.275))  # |v_rel| / (2 TTC) = 400 / 51
    assert r["time_worst"] == pytest.approx(0.5) and r["x_a"] == pytest.approx(5.0) and r["x_b"] == pytest.approx(35.0)


def test_walker_crossing_after_a_car_party_a_is_the_car():
    # the ego book's crossing case (PET 0.6 s, the true one 0.525 s) between a car and a walker,
    # neither an ego: the walker's id sorts first, party a is still the car (its class comes first)
    sink = Sink()
    book = PairConflictBook(sink, EVERYONE, DT)
    for k in range(50):
        t = round(k * DT, 10)
        observe(book, t, k, agents(["car"], -19.95 + 10 * t, 0.0, 0.0, 10.0, 4.5, 1.8, C.CAR),
                agents(["a_walker"], 0.0, -3.82 + t, math.pi / 2, 1.0, 0.3, 0.5, C.PEDESTRIAN))
    r, = sink.conflicts
    assert (r["id_a"], r["id_b"], r["class_a"], r["class_b"]) == ("car", "a_walker", "car", "pedestrian")
    assert r["min_pet"] == pytest.approx(0.6) and r["start"] == pytest.approx(2.8) and r["end"] == pytest.approx(3.1)
    assert r["pet_below"] and not r["ttc_below"] and math.isnan(r["min_ttc"]) and r["max_drac"] == 0.0
    assert r["min_distance"] == pytest.approx(5.55, abs=1e-9)
    assert pair_counts(sink.conflicts)["by_group"] == {"vehicle-vehicle": 0, "vehicle-vru": 1, "vru-vru": 0}


def test_pairs_with_an_ego_two_walkers_and_far_pairs_are_not_measured():
    sink = Sink()
    book = PairConflictBook(sink, EVERYONE, DT)
    for k in range(6):  # the head-on pair again, c1 now an ego (its own book measures it)
        t = round(k * DT, 10)
        observe(book, t, k, agents(["c1"], 10 * t, 0.0, 0.0, 10.0, 4.5, 1.8, C.CAR),
                agents(["c2"], 40 - 10 * t, 0.0, math.pi, 10.0, 4.5, 1.8, C.CAR), exclude={"c1"})
    assert sink.conflicts == [] and book.pairs["candidates"] == 0
    # two walkers walking into each other (SUMO's walkers overlap in crowds): no pair
    book = PairConflictBook(sink, EVERYONE, DT)
    for k in range(20):
        t = round(k * DT, 10)
        observe(book, t, k, agents(["w1", "w2"], [-1.0 + t, 1.0 - t], 0.0, [0.0, math.pi], 1.0, 0.3, 0.5,
                                   C.PEDESTRIAN))
    assert sink.conflicts == [] and book.pairs["candidates"] == 0
    # two cars at 10 m/s each, 100 m apart on parallel roads: R = 2.5 + 15 m each, 100 > 35: no candidate
    book = PairConflictBook(sink, EVERYONE, DT)
    observe(book, 0.0, 0, agents(["a", "b"], [0.0, 0.0], [0.0, 100.0], 0.0, 10.0, 4.5, 1.8, C.CAR))
    assert book.pairs == {"road_users": 2, "candidates": 0, "ttc": 0, "pet": 0}


def test_a_road_user_that_leaves_frees_its_trail():
    # a car drives east through x = 0 and leaves the simulation after 0.1 s; then a walker standing at
    # the origin takes its trail slot, and a car standing across the road at x = 2 (heading north)
    # covers the departed car's footprint of t = 0.1 (its box x -1.45..3.05): with the old trail left
    # in the slot that would be a PET of 0.1 s into the walker's "trail"; the pair has none
    sink = Sink()
    book = PairConflictBook(sink, EVERYONE, DT)
    for k in range(5):
        t = round(k * DT, 10)
        parts = [agents(["car"], -0.2 + 10 * t, 0.0, 0.0, 10.0, 4.5, 1.8, C.CAR)] if k < 2 else [
            agents(["w"], 0.0, 0.0, math.pi / 2, 0.0, 0.3, 0.5, C.PEDESTRIAN),
            agents(["z"], 2.0, 0.0, math.pi / 2, 0.0, 4.5, 1.8, C.CAR)]
        observe(book, t, k, *parts)
    assert book.slot == {"w": 0, "z": 1} and book.pairs["candidates"] == 3 and book.pairs["pet"] >= 2
    assert sink.conflicts == []


def test_killed_run_keeps_the_rows_and_the_rebuilt_summary_counts_them(tmp_path):
    (tmp_path / "config.json").write_text(json.dumps({"seed": 1, "conflicts": {"enabled": True, "everyone": True}}))
    rec = RunRecorder(tmp_path)
    rec.record_conflicts()
    rec.record_conflicts_others()
    book = PairConflictBook(rec.others_sink, EVERYONE, DT)
    for k in range(6):
        t = round(k * DT, 10)
        observe(book, t, k, agents(["c1"], 10 * t, 0.0, 0.0, 10.0, 4.5, 1.8, C.CAR),
                agents(["c2"], 40 - 10 * t, 0.0, math.pi, 10.0, 4.5, 1.8, C.CAR))
    rec.flush()  # what a kill after the flush leaves: partial/conflicts_others.parquet
    t = read_table(tmp_path, "conflicts_others")
    assert t.schema.names == schema.CONFLICTS_OTHERS.names
    assert t.to_pylist()[0]["min_ttc"] == pytest.approx(1.275)
    s = recover_summary(tmp_path)
    assert s["conflicts_others"] == {"total": 1, "ttc": 1, "pet": 0, "contact": 0,
                                     "by_group": {"vehicle-vehicle": 1, "vehicle-vru": 0, "vru-vru": 0},
                                     "by_pair": {"car-car": 1}}


def test_everyone_settings():
    assert conflicts_config({"everyone": True}) == ConflictConfig(everyone=True)
    for bad in ({"everyone": 1}, {"everyone": True, "enabled": False}):
        with pytest.raises(ConfigError):
            conflicts_config(bad)



def test_traffic_table_others_per_100_vehicle_km_by_hand():
    from sumo_ethics.analysis.stats import traffic_table

    runs = pd.DataFrame({
        "penetration": [0.0, 0.0, 0.5, 0.5], "fleet_egos": [0.0, 0.0, 3.0, 3.0],
        **{c: [0.0] * 4 for c in ("harm_all_egos", "harm_all_other_vehicles", "harm_all_vru", "harm_all_total",
                                  "time_loss_egos", "time_loss_other_vehicles", "time_loss_persons")},
        "vehicle_km": [100.0, 300.0, 200.0, 200.0], "person_km": [1.0] * 4, "distance": [0.0, 0.0, 5000.0, 5000.0],
        "conflicts_total": [0.0, 0.0, 2.0, 4.0], "conflicts_others": [6.0, 10.0, 3.0, np.nan],
        "conflicts_others_vru": [2.0, 2.0, 1.0, np.nan],
    })
    t = traffic_table(runs, ["penetration"], n_boot=200).set_index("penetration")
    # 16 conflicts among the others over 400 vehicle-km = 4 per 100 vehicle-km, 4 with a VRU = 1
    assert t.loc[0.0, "conflicts_others_per_100vkm"] == pytest.approx(4.0)
    assert t.loc[0.0, "conflicts_others_vru_per_100vkm"] == pytest.approx(1.0)
    assert t.loc[0.0, "conflicts_everyone_per_100vkm"] == pytest.approx(4.0)
    # at 0.5 only the run that measured the others counts: 3 over 200 vehicle-km; everyone's 3 + 2
    assert t.loc[0.5, "conflicts_others_per_100vkm"] == pytest.approx(1.5)
    assert t.loc[0.5, "conflicts_everyone_per_100vkm"] == pytest.approx(2.5)
    without = traffic_table(runs.drop(columns=["conflicts_others", "conflicts_others_vru"]), ["penetration"])
    assert without["conflicts_others_per_100vkm"].isna().all()


def test_traffic_figure_shows_everyones_conflicts_when_measured(tmp_path, monkeypatch):
    """The traffic figure gains a panel of everyone's conflicts per 100 vehicle-km where the runs
    measured the others' (the legend then goes below the panels), and has none without."""
    import matplotlib.pyplot as plt

    from sumo_ethics.analysis import plots
    from sumo_ethics.analysis.stats import traffic_table

    runs = pd.DataFrame({
        "penetration": [0.0, 0.0, 0.5, 0.5], "fleet": ["ego", "ethical"] * 2, "fleet_egos": [0.0, 0.0, 3.0, 3.0],
        **{c: [0.0] * 4 for c in ("harm_all_egos", "harm_all_other_vehicles", "harm_all_vru", "harm_all_total",
                                  "time_loss_egos", "time_loss_other_vehicles")},
        "time_loss_persons": [np.nan] * 4,
        "vehicle_km": [100.0, 300.0, 200.0, 200.0], "person_km": [1.0] * 4, "distance": [0.0, 0.0, 5000.0, 5000.0],
        "conflicts_total": [0.0, 0.0, 2.0, 4.0], "conflicts_others": [6.0, 10.0, 3.0, 1.0],
        "conflicts_others_vru": [2.0, 2.0, 1.0, 0.0],
    })
    titles = []
    orig = plots._save

    def keep(fig, folder, name):
        titles.append([ax.get_title() for ax in fig.axes if ax.axison])
        return orig(fig, folder, name)

    monkeypatch.setattr(plots, "_save", keep)
    for table in (runs, runs.drop(columns=["conflicts_others", "conflicts_others_vru"])):
        plots.traffic_vs_parameter(traffic_table(table, ["penetration", "fleet"], n_boot=50),
                                   ["penetration", "fleet"], tmp_path)
    plt.close("all")
    assert "everyone's conflicts (egos' and others')" in titles[0] and len(titles[0]) == 8
    assert not any("everyone" in t for t in titles[1]) and len(titles[1]) == 7


# ---- real SUMO ------------------------------------------------------------------------------------
class HoldSpeeds:
    """A run hook: the SUMO car ``vid`` drives blind (speed mode 0: no car following) at its 10 m/s
    until its snapshot time reaches ``stop_at``, then stands at once (speed mode 0 ignores the
    deceleration limit)."""

    def __init__(self, vid: str, stop_at: float) -> None:
        self.vid, self.stop_at = vid, stop_at

    def __call__(self, snap, world) -> None:
        import libsumo

        if self.vid in libsumo.vehicle.getIDList():
            libsumo.vehicle.setSpeedMode(self.vid, 0)
            libsumo.vehicle.setSpeed(self.vid, 0.0 if snap.time >= self.stop_at - 1e-9 else 10.0)


ROUTES = """
  <vType id="ten" vClass="passenger" length="4.5" width="1.8" maxSpeed="10" speedFactor="1" sigma="0"
         lcStrategic="-1" lcSpeedGain="0" lcKeepRight="0" lcCooperative="-1"/>
  <vehicle id="parked" type="car" route="r_main" depart="0" departLane="2" departPos="124" departSpeed="0">
    <stop lane="main_0_2" endPos="124.5" duration="1000"/></vehicle>
  <vehicle id="f" type="ten" route="r_main" depart="0" departLane="2" departPos="20.5" departSpeed="10"/>
  <vehicle id="ego" type="car" route="r_main" depart="0" departLane="1" departPos="150" departSpeed="10"/>"""


@pytest.mark.sumo
def test_run_follower_closing_on_a_stopped_car(scenario_dir, tmp_path):
    """Two SUMO cars on lane 2 of the testbed (x along the lane): ``parked`` standing at its stop
    (front at endPos 124.5, rear at x = 120), ``f`` (no lane changes) at 10 m/s, blind (speed mode
    0) until it is made to stand at 9.3 s; the ego drives away ahead on lane 1. Inserted in the
    step from 0 to 0.1 s, ``f``'s front is at 20.5 + 10 (t - 0.1) at time t: the gap is 100.5 - 10 t,
    TTC = gap / 10 = 10.05 - t, below 1.5 s from 8.6 s (1.45 s; 1.55 s at 8.5 s) to 9.3 s (0.75 s,
    gap 7.5 m, the centre at 112.5 - 2.25 = 110.25), DRAC 10 / (2 x 0.75) = 6.667 m/s^2 there (SUMO's
    positions come within 0.01 mm of these)."""
    from sumo_ethics.config import RunConfig
    from sumo_ethics.runner import run

    from conftest import Scripted

    cfg_file = write_scenario(scenario_dir, ROUTES)
    outs = [tmp_path / f"on{i}" for i in range(2)] + [tmp_path / "off"]
    for out in outs:
        on = out.name != "off"
        rc = RunConfig(cfg_file, out, ego_id="ego", end=12, progress=False,
                       conflicts=ConflictConfig(everyone=on))
        summary = run(rc, controller=Scripted(10.0), hooks=(HoldSpeeds("f", 9.3),))
        assert summary.status.value == "timeout", summary.message
    c = pd.read_parquet(outs[0] / "conflicts_others.parquet")
    assert list(c.columns) == schema.CONFLICTS_OTHERS.names
    r, = c.itertuples()
    assert (r.id_a, r.id_b, r.class_a, r.class_b, r.type_a, r.type_b) == ("f", "parked", "car", "car", "ten", "car")
    assert r.start == pytest.approx(8.6) and r.end == pytest.approx(9.3) and r.n_steps == 8
    assert r.min_ttc == pytest.approx(0.75, abs=1e-5) and r.time_worst == pytest.approx(9.3)
    assert r.max_drac == pytest.approx(20.0 / 3.0, abs=1e-4) and r.min_distance == pytest.approx(7.5, abs=1e-4)
    assert r.x_a == pytest.approx(110.25, abs=1e-4) and r.x_b == pytest.approx(122.25, abs=1e-4)
    assert r.speed_a == pytest.approx(10.0) and r.speed_b == 0.0
    assert r.ttc_below and not r.pet_below and not r.contact
    steps = pd.read_parquet(outs[0] / "steps.parquet")
    assert r.step_start == int(steps.loc[np.isclose(steps.time, 8.6), "step"].iloc[0])
    s = json.loads((outs[0] / "summary.json").read_text())["conflicts_others"]
    assert (s["total"], s["by_pair"], s["by_group"]["vehicle-vehicle"]) == (1, {"car-car": 1}, 1)
    assert s["steps"] == len(steps) and s["pairs_per_step"]["candidates"] > 0
    # same seed, same bytes; the option off: no file, the other outputs the same bytes as with it on
    assert (outs[0] / "conflicts_others.parquet").read_bytes() == (outs[1] / "conflicts_others.parquet").read_bytes()
    assert not (outs[2] / "conflicts_others.parquet").exists()
    assert "conflicts_others" not in json.loads((outs[2] / "summary.json").read_text())
    assert "everyone" not in json.loads((outs[2] / "config.json").read_text())["conflicts"]
    for name in ("steps.parquet", "collisions.parquet", "conflicts.parquet"):
        assert (outs[0] / name).read_bytes() == (outs[2] / name).read_bytes(), name
