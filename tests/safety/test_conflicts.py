"""Conflicts (box TTC, DRAC, distance, PET, events) and fault, with numbers worked by hand;
then real SUMO runs on the testbed network writing conflicts.parquet."""

from __future__ import annotations

import math
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from sumo_ethics.collision import CollisionBook
from sumo_ethics.config import ConflictConfig, RunConfig
from sumo_ethics.errors import ConfigError
from sumo_ethics.geometry import OrientedBoxes as Boxes
from sumo_ethics.geometry import boxes_overlap
from sumo_ethics.record import schema
from sumo_ethics.record.reader import read_table
from sumo_ethics.record.recorder import RunRecorder
from sumo_ethics.safety.conflicts import ConflictBook
from sumo_ethics.safety.fault import FaultContext, fault
from sumo_ethics.safety.measures import box_distance, box_ttc, drac, pet_from_trail
from sumo_ethics.settings import conflicts_config
from sumo_ethics.types import AgentStates
from sumo_ethics.types import RoadUserClass as C

from conftest import SCENARIOS, Scripted, build_signalised, write_scenario

CAR = {"length": 4.5, "width": 1.8}
PED = {"length": 0.3, "width": 0.5}  # SUMO's pedestrian box (the testbed's vType)


# ---- box TTC, DRAC, distance ---------------------------------------------------------------
def test_ttc_head_on():
    # two 4.5 x 1.8 m cars, centres 30 m apart on one line, 10 m/s each towards the other:
    # gap 30 - 4.5 = 25.5 m closed at 20 m/s -> TTC = 25.5 / 20 = 1.275 s
    a, b = Boxes(0.0, 0.0, 0.0, **CAR), Boxes(30.0, 0.0, math.pi, **CAR)
    ttc = box_ttc(a, (10.0, 0.0), b, (-10.0, 0.0))
    assert ttc == pytest.approx(1.275, abs=1e-12)
    # DRAC = v_rel^2 / (2 gap) = 400 / 51 = 7.843 m/s^2
    assert drac(ttc, 20.0) == pytest.approx(400.0 / 51.0, abs=1e-12)
    # moving apart, or standing: never
    assert box_ttc(a, (-10.0, 0.0), b, (10.0, 0.0)) == math.inf
    assert box_ttc(a, (0.0, 0.0), b, (0.0, 0.0)) == math.inf
    assert drac(math.inf, 20.0) == 0.0


def test_ttc_at_right_angle():
    # A: car at the origin heading east at 10 m/s. B: car at (18, -20) heading north at 10 m/s.
    # Along x: B's half extent is its half width 0.9, A's half length 2.25 -> overlap while
    # |18 - 10 t| < 3.15, t in (1.485, 2.115). Along y: A's half width 0.9 + B's half length 2.25
    # -> overlap while |-20 + 10 t| < 3.15, t in (1.685, 2.315). Both: from t = 1.685 s, when B's
    # front (y = -20 + 16.85 + 2.25 = -0.9) reaches A's right side (A's front is at x = 19.1 > 18 - 0.9).
    a, b = Boxes(0.0, 0.0, 0.0, **CAR), Boxes(18.0, -20.0, math.pi / 2, **CAR)
    assert box_ttc(a, (10.0, 0.0), b, (0.0, 10.0)) == pytest.approx(1.685, abs=1e-12)
    # B 3 m further east: along x overlap only while |21 - 10 t| < 3.15, t in (1.785, 2.415),
    # along y still (1.685, 2.315): TTC = 1.785 s, A's front corner reaches B's left side
    b2 = Boxes(21.0, -20.0, math.pi / 2, **CAR)
    assert box_ttc(a, (10.0, 0.0), b2, (0.0, 10.0)) == pytest.approx(1.785, abs=1e-12)
    # B at x = 26: x interval (2.285, 2.915) shares (2.285, 2.315) with y's: TTC 2.285 s
    assert box_ttc(a, (10.0, 0.0), Boxes(26.0, -20.0, math.pi / 2, **CAR), (0.0, 10.0)) == pytest.approx(2.285)
    # B at x = 26.5: x interval (2.335, 2.965) starts after y's ends (2.315): B is across before A comes
    assert box_ttc(a, (10.0, 0.0), Boxes(26.5, -20.0, math.pi / 2, **CAR), (0.0, 10.0)) == math.inf


def test_ttc_is_exact_against_dense_sampling():
    """Random pairs at any angle: the exact TTC against the first overlap found by sampling
    boxes_overlap every 1 ms (they agree to within one sample)."""
    rng = np.random.default_rng(3)
    n = 1000
    ax, ay, bx, by = rng.uniform(-15, 15, (4, n))
    ayaw, byaw = rng.uniform(-np.pi, np.pi, (2, n))
    avx, avy, bvx, bvy = rng.uniform(-12, 12, (4, n))
    a, b = Boxes(ax, ay, ayaw, 4.5, 1.8), Boxes(bx, by, byaw, 2.0, 0.8)
    ttc = box_ttc(a, (avx, avy), b, (bvx, bvy))
    t = np.arange(0.0, 4.0, 1e-3)[:, None]
    hit = boxes_overlap(Boxes(ax + avx * t, ay + avy * t, ayaw, 4.5, 1.8), Boxes(bx + bvx * t, by + bvy * t, byaw, 2.0, 0.8))
    first = np.where(hit.any(axis=0), t[np.argmax(hit, axis=0), 0], np.inf)
    within = ttc < 3.99
    assert within.sum() > 50 and np.isinf(first[~within & (ttc > 4.0)]).all()
    assert np.all(np.abs(first[within] - ttc[within]) <= 1.0001e-3)


def test_drac_of_a_follower():
    # follower 15 m/s, leader 5 m/s 10 m ahead (bumper to bumper): TTC = 10 / 10 = 1 s,
    # DRAC = (15 - 5)^2 / (2 * 10) = 5 m/s^2
    a, b = Boxes(0.0, 0.0, 0.0, **CAR), Boxes(14.5, 0.0, 0.0, **CAR)
    ttc = box_ttc(a, (15.0, 0.0), b, (5.0, 0.0))
    assert ttc == pytest.approx(1.0) and drac(ttc, 10.0) == pytest.approx(5.0)


def test_box_distance():
    a = Boxes(0.0, 0.0, 0.0, **CAR)
    assert box_distance(a, Boxes(10.0, 0.0, 0.0, **CAR)) == pytest.approx(5.5)  # 10 - 2 x 2.25
    assert box_distance(a, Boxes(0.0, 5.0, 0.0, **CAR)) == pytest.approx(3.2)  # 5 - 2 x 0.9
    # a 2 x 2 m square turned 45 deg at (5, 0): its corner at 5 - sqrt(2) faces A's front at 2.25
    assert box_distance(a, Boxes(5.0, 0.0, math.pi / 4, 2.0, 2.0)) == pytest.approx(2.75 - math.sqrt(2))
    # corner to corner: B's rear-left corner (10 - 2.25, -3 + 0.9) to A's front-right (2.25, -0.9)
    assert box_distance(a, Boxes(10.0, -3.0, 0.0, **CAR)) == pytest.approx(math.hypot(5.5, 1.2))
    assert box_distance(a, Boxes(1.0, 0.5, 0.3, **CAR)) == 0.0  # overlapping


# ---- PET --------------------------------------------------------------------------------------
DT = 0.1


def car_east(t: np.ndarray, x0: float) -> Boxes:
    return Boxes(x0 + 10.0 * t, np.zeros_like(t), np.zeros_like(t), **CAR)


def test_pet_pedestrian_crossing_after_a_car():
    # car eastbound on y = 0 at 10 m/s, centre x = -19.95 + 10 t: its rear (x - 2.25) leaves the
    # walker's strip x <= 0.25 at t = 2.245 s. Walker northbound on x = 0 at 1 m/s, centre
    # y = -3.82 + t: its front (y + 0.15) enters the car's strip y >= -0.9 at t = 2.77 s.
    # PET = 2.77 - 2.245 = 0.525 s. Sampled every 0.1 s: the walker overlaps the car's footprint
    # first at t = 2.8, the latest car box covering x in (-0.25, 0.25) is that of t = 2.2 -> 0.6 s
    # (the sampled PET is at most two steps above the true one, never below).
    times = np.round(np.arange(0, 28) * DT, 10)  # 0 .. 2.7
    trail = car_east(times[:, None], -19.95)
    def walker(t):
        return Boxes(np.array([0.0]), np.array([-3.82 + t]), np.array([math.pi / 2]), **PED)

    assert pet_from_trail(walker(2.7), 2.7, trail, times, math.radians(30))[0] == math.inf  # not yet in
    times = np.append(times, 2.8)
    trail = car_east(times[:-1, None], -19.95)
    pet = pet_from_trail(walker(2.8), 2.8, trail, times[:-1], math.radians(30))[0]
    assert pet == pytest.approx(0.6, abs=1e-9) and 0.525 <= pet <= 0.525 + 2 * DT
    # the same walker on the car's own heading (walking east behind it) is no crossing: no PET
    along = Boxes(np.array([0.0]), np.array([0.0]), np.array([0.0]), **PED)
    assert pet_from_trail(along, 2.8, trail, times[:-1], math.radians(30))[0] == math.inf


def agents(ids, x, y, yaw, speed, length, width, cls) -> AgentStates:
    n = len(ids)
    def f(v):
        return np.broadcast_to(np.asarray(v, float), (n,)).copy()

    return AgentStates(tuple(ids), f(x), f(y), f(yaw), f(speed), np.zeros(n), f(length), f(width), np.full(n, 75.0),
                       np.broadcast_to(np.asarray(cls, np.int8), (n,)).copy(), tuple(["t"] * n))


class Sink:
    def __init__(self) -> None:
        self.conflicts: list[dict] = []
        self.collisions: list[dict] = []

    def add_conflict(self, row: dict) -> int:
        self.conflicts.append(row)
        return len(self.conflicts) - 1

    def update_conflict(self, i: int, **ch) -> None:
        self.conflicts[i].update(ch)

    def add_collision(self, row: dict) -> int:
        self.collisions.append(row)
        return len(self.collisions) - 1

    def update_collision(self, i: int, **ch) -> None:
        self.collisions[i].update(ch)


def crossing_run(car_x0: float, walker_y0: float, steps: int) -> list[dict]:
    """ConflictBook over ``steps`` steps of 0.1 s: ego car eastbound at 10 m/s from x = car_x0,
    a walker northbound on x = 0 at 1 m/s from y = walker_y0."""
    sink = Sink()
    book = ConflictBook(sink, ConflictConfig(), DT)
    for k in range(steps):
        t = round(k * DT, 10)
        ego = agents(["ego"], car_x0 + 10 * t, 0.0, 0.0, 10.0, 4.5, 1.8, C.CAR)
        walker = agents(["w"], 0.0, walker_y0 + t, math.pi / 2, 1.0, 0.3, 0.5, C.PEDESTRIAN)
        book.observe(SimpleNamespace(time=t, ego=ego, others=walker), k)
    return sink.conflicts


def test_conflict_event_of_a_walker_crossing_after_the_ego():
    rows = crossing_run(-19.95, -3.82, 50)  # the case above: PET 0.6 s (true 0.525 s)
    assert len(rows) == 1
    r = rows[0]
    assert (r["id_a"], r["id_b"], r["class_b"]) == ("ego", "w", "pedestrian")
    assert r["min_pet"] == pytest.approx(0.6) and r["start"] == pytest.approx(2.8)
    assert r["pet_below"] and not r["ttc_below"] and not r["contact"]
    assert math.isnan(r["min_ttc"]) and r["max_drac"] == 0.0  # never on a collision course
    # PET grows by 0.1 s a step while the walker crosses the ego's older footprint, below 1 s
    # from 2.8 to 3.2 s (2.8 - 2.2 ... 3.2 - 2.2 = 1.0 is not below 1)
    assert r["end"] == pytest.approx(3.1) and r["n_steps"] == 4
    # distance at 2.8 (the smallest, the car moving away): the car's rear at -19.95 + 28 - 2.25 = 5.8,
    # the walker's east side at 0.25, their y ranges overlapping (-0.9..-0.87) -> 5.55 m
    assert r["min_distance"] == pytest.approx(5.55, abs=1e-9)


def test_conflict_event_of_the_ego_crossing_after_a_walker():
    # walker centre y = -1.0 + t leaves the car's strip (rear y - 0.15 >= 0.9) at t = 2.05 s; car
    # centre x = -28.45 + 10 t: its front (x + 2.25) reaches x = -0.25 at t = 2.595 s -> PET 0.545 s;
    # sampled: the ego overlaps the walker's footprint first at 2.6, the walker's latest there is 2.0 -> 0.6
    rows = crossing_run(-28.45, -1.0, 40)
    assert len(rows) == 1
    assert rows[0]["min_pet"] == pytest.approx(0.6) and rows[0]["start"] == pytest.approx(2.6)


def test_no_conflict_when_the_walker_crosses_long_after():
    # the walker's front (-6.67 + t) enters the car's strip at 5.77 s, 3.525 s after the car left
    assert crossing_run(-19.95, -6.82, 60) == []


def test_head_on_event_ttc_drac_and_distance():
    sink = Sink()
    book = ConflictBook(sink, ConflictConfig(), DT)
    for k in range(6):  # head-on at 10 m/s each, centres 40 m apart at t = 0
        t = round(k * DT, 10)
        ego = agents(["ego"], 10 * t, 0.0, 0.0, 10.0, 4.5, 1.8, C.CAR)
        car = agents(["c"], 40 - 10 * t, 0.0, math.pi, 10.0, 4.5, 1.8, C.CAR)
        book.observe(SimpleNamespace(time=t, ego=ego, others=car), k)
    r, = sink.conflicts
    # gap 35.5 - 20 t, TTC = gap / 20 = 1.775 - t: below 1.5 s from t > 0.275, i.e. the steps 0.3
    # (1.475 s), 0.4 and 0.5 (1.275 s, gap 25.5 m: the head-on case above)
    assert r["start"] == pytest.approx(0.3) and r["end"] == pytest.approx(0.5) and r["n_steps"] == 3
    assert r["min_ttc"] == pytest.approx(1.275) and r["min_distance"] == pytest.approx(25.5)
    assert r["max_drac"] == pytest.approx(400 / 51)
    assert r["time_worst"] == pytest.approx(0.5) and r["x_a"] == pytest.approx(5.0) and r["x_b"] == pytest.approx(35.0)


def test_conflicts_are_kept_by_a_killed_run(tmp_path):
    rec = RunRecorder(tmp_path)
    rec.record_conflicts()
    rows = crossing_run(-19.95, -3.82, 50)
    for r in rows:
        rec.add_conflict(r)
    rec.flush()  # what a kill after the flush leaves: partial/conflicts.parquet
    t = read_table(tmp_path, "conflicts").to_pylist()
    assert len(t) == 1 and t[0]["min_pet"] == pytest.approx(0.6) and t[0]["id_b"] == "w"
    assert read_table(tmp_path, "conflicts").schema.names == schema.CONFLICTS.names


# ---- fault -----------------------------------------------------------------------------------
def test_fault_rules():
    braking = FaultContext(ego_accel=-4.0, decel_limit=8.0)
    assert fault(4.0, "rear", "c", C.CAR, 12.0, "front", braking) == \
        ("other", "struck from behind while braking within the limit")
    assert fault(4.0, "rear", "c", C.CAR, 12.0, "front", FaultContext(ego_accel=-9.5, decel_limit=8.0))[0] == "shared"
    assert fault(0.0, "rear", "c", C.CAR, 12.0, "front") == ("other", "ego standing, struck")
    assert fault(0.05, "side", "p", C.PEDESTRIAN, 1.3, "front") == ("other", "pedestrian entered the standing ego's box")
    assert fault(8.0, "front", "p", C.PEDESTRIAN, 0.0, "side") == ("ego", "ego moved into a standing pedestrian")
    assert fault(8.0, "front", "c", C.CAR, 3.0, "rear") == ("ego", "ego struck the car from behind")
    assert fault(8.0, "side", "c", C.CAR, 8.0, "front", FaultContext(ego_in_envelope=True))[0] == "ego"
    assert fault(8.0, "side", "c", C.CAR, 8.0, "front", FaultContext(ego_in_envelope=False))[0] == "unknown"
    assert fault(8.0, "side", "c", C.CAR, 8.0, "front", FaultContext(rule_breakers=frozenset({"c"})))[0] == "other"
    assert fault(8.0, "side", "c", C.CAR, 8.0, "front", FaultContext(ego_ran_red=True))[0] == "ego"


def test_collision_book_rear_end_into_the_braking_ego():
    """A car at 12 m/s runs into the back of the ego braking at 4 m/s^2 from 5 m/s: fault other."""
    sink = Sink()
    book = CollisionBook(sink, gap=1.0, lookup=lambda _: None)
    # t = 0: centres 4.6 m apart (a 0.1 m gap); 0.1 s later the ego at 10.48 (5 -> 4.6 m/s), the
    # car at 6.6: centres 3.88 m apart < 4.5 -> contact
    s0 = SimpleNamespace(time=0.0, ego=agents(["ego"], 10.0, 0.0, 0.0, 5.0, 4.5, 1.8, C.CAR),
                         others=agents(["c"], 5.4, 0.0, 0.0, 12.0, 4.5, 1.8, C.CAR), collisions=())
    s1 = SimpleNamespace(time=0.1, ego=agents(["ego"], 10.48, 0.0, 0.0, 4.6, 4.5, 1.8, C.CAR),
                         others=agents(["c"], 6.6, 0.0, 0.0, 12.0, 4.5, 1.8, C.CAR), collisions=())
    assert book.detect(s0, s1, 1, FaultContext(ego_accel=-4.0, decel_limit=8.0))
    r, = sink.collisions
    assert (r["area_a"], r["area_b"]) == ("rear", "front")
    assert (r["fault"], r["fault_reason"]) == ("other", "struck from behind while braking within the limit")


def test_conflicts_settings():
    assert conflicts_config({"ttc": 2.0, "enabled": False}) == ConflictConfig(enabled=False, ttc=2.0)
    for bad in ({"ttc": -1.0}, {"pet": "x"}, {"thresholds": 1}, {"enabled": 1}, {"crossing_angle": 120}):
        with pytest.raises(ConfigError):
            conflicts_config(bad)


@pytest.mark.parametrize("body, key", [("ttc = -1.5", "conflicts.ttc"),
                                       ("enabled = false\neveryone = true", "conflicts.everyone")])
def test_bad_conflicts_setting_is_one_line_exit_2(tmp_path, body, key):
    toml = tmp_path / "c.toml"
    toml.write_text(f"[conflicts]\n{body}\n")
    p = subprocess.run([sys.executable, "-m", "sumo_ethics.cli", "run", str(SCENARIOS / "testbed" / "testbed.sumocfg"),
                        "--config", str(toml), "--quiet", "--out", str(tmp_path / "out")],
                       check=False, capture_output=True, text=True, timeout=120)
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert p.returncode == 2 and len(lines) == 1 and key in lines[0], p.stderr
    assert not (tmp_path / "out").exists()


# ---- real SUMO ------------------------------------------------------------------------------------
@pytest.mark.sumo
def test_run_rear_end_into_a_parked_car_writes_conflicts(scenario_dir, tmp_path):
    cfg = write_scenario(scenario_dir, """
      <vehicle id="parked" type="car" route="r_main" depart="0" departLane="2" departPos="124" departSpeed="0">
        <stop lane="main_0_2" endPos="124.5" duration="1000"/></vehicle>
      <vehicle id="ego" type="car" route="r_main" depart="0" departLane="2" departPos="20" departSpeed="10"/>""")
    outs = [tmp_path / f"run{i}" for i in range(2)]
    for out in outs:
        summary = run_scripted(cfg, out, Scripted(10.0))
    c = pd.read_parquet(outs[0] / "conflicts.parquet")
    assert list(c.columns) == schema.CONFLICTS.names
    assert len(c) == 1
    r = c.iloc[0]
    assert (r.id_a, r.id_b, r.class_a, r.class_b) == ("ego", "parked", "car", "car")
    # TTC = gap / 10 m/s with the gap from the ego's front (x + 2.25) to the parked car's rear (119.5)
    steps = pd.read_parquet(outs[0] / "steps.parquet").set_index("step")
    def ttc(step):
        return (119.5 - steps.loc[step, "x"] - 2.25) / 10.0

    assert ttc(r.step_start) < 1.5 <= ttc(r.step_start - 1)
    assert r.contact and r.min_ttc == 0.0 and r.min_distance == 0.0 and r.ttc_below
    col = pd.read_parquet(outs[0] / "collisions.parquet")
    assert (col.fault.iloc[0], col.fault_reason.iloc[0]) == ("ego", "ego moved into a standing car")
    assert r.start < col.time.iloc[0] <= r.end
    assert summary.data["conflicts"] == {"total": 1, "ttc": 1, "pet": 0, "contact": 1, "vru": 0,
                                         "by_class": {"car": 1}}
    assert summary.data["collisions"]["fault"] == {"ego": 1, "other": 0, "shared": 0, "unknown": 0}
    for name in ("conflicts.parquet", "collisions.parquet", "steps.parquet"):  # same seed, same bytes
        assert (outs[0] / name).read_bytes() == (outs[1] / name).read_bytes(), name


def run_scripted(cfg, out, controller, **kw):
    from sumo_ethics.runner import run

    return run(RunConfig(cfg, out, ego_id="ego", end=kw.pop("end", 20), progress=False, **kw), controller=controller)


class DriveThenStand:
    """Drives along the route at ``speed``, ``d`` metres left of the lane centre, until its centre
    reaches arc length ``stop_s``, then stands."""

    name = "drive_then_stand"
    needs_history = False

    def __init__(self, speed: float, stop_s: float, d: float = 0.0) -> None:
        self.speed, self.stop_s, self.d = speed, stop_s, d

    def act(self, scene):
        from sumo_ethics.contract import Decision
        from sumo_ethics.contract import EgoCommand

        v = self.speed if scene.s < self.stop_s else 0.0
        s = min(scene.s + v * scene.dt, max(scene.s, self.stop_s))
        x, y, yaw = scene.route.path.to_xy(np.array(s), np.array(self.d))
        return Decision(EgoCommand(float(x), float(y), float(yaw), v))


@pytest.mark.sumo
def test_run_walker_into_the_standing_ego_is_the_others_fault(scenario_dir, tmp_path):
    # the ego drives at 5 m/s 2.5 m right of lane 1's centre (y = -7.3: its box, y -8.2..-6.4,
    # reaches over the south sidewalk) and stands with its centre at x = 195 from t = 2.45 s. The
    # walker, leaving x = 190 on that sidewalk at t = 3 s eastwards (y = -8.0), walks into its rear
    # (SUMO's pedestrians do not see cars): the ego stood, the walker entered its box
    cfg = write_scenario(scenario_dir, """
      <vehicle id="ego" type="car" route="r_main" depart="0" departLane="1" departPos="185" departSpeed="5"/>
      <person id="walker" type="ped" depart="3" departPos="190"><walk from="main_0" to="opp_0"/></person>""")
    out = tmp_path / "run"
    summary = run_scripted(cfg, out, DriveThenStand(5.0, 195.0, d=-2.5), end=30)
    col = pd.read_parquet(out / "collisions.parquet")
    ego = col[col.involves_ego]
    assert summary.status.value == "collision" and len(ego) == 1, summary.message
    r = ego.iloc[0]
    assert r.id_b == "walker" and r.speed_a < 0.1 and r.time > 3.0
    assert (r.fault, r.fault_reason) == ("other", "pedestrian entered the standing ego's box")
    c = pd.read_parquet(out / "conflicts.parquet")
    w = c[c.id_b == "walker"]
    # the walker at about 1.3 m/s closing on the standing ego: TTC below 1.5 s some 2 m before contact
    assert len(w) == 1 and w.ttc_below.iloc[0] and w.contact.iloc[0] and w.start.iloc[0] < r.time


class FollowThenMatch:
    """Drives along the route at ``fast`` m/s until the bumper gap to ``leader`` is at most ``gap``
    metres, then at ``slow`` m/s (the leader's speed)."""

    name = "follow_then_match"
    needs_history = False

    def __init__(self, leader: str, fast: float, slow: float, gap: float) -> None:
        self.leader, self.fast, self.slow, self.gap = leader, fast, slow, gap
        self.matched = False

    def act(self, scene):
        from sumo_ethics.contract import Decision
        from sumo_ethics.contract import EgoCommand

        o = scene.others
        if self.leader in o.index:
            i = o.index[self.leader]
            self.matched = self.matched or o.x[i] - scene.ego.x[0] - (o.length[i] + scene.ego.length[0]) / 2 <= self.gap
        v = self.slow if self.matched else self.fast
        x, y, yaw = scene.route.path.to_xy(np.array(scene.s + v * scene.dt), np.array(0.0))
        return Decision(EgoCommand(float(x), float(y), float(yaw), v))


@pytest.mark.sumo
def test_min_ttc_matches_sumos_ssm_device(scenario_dir, tmp_path):
    """SUMO's SSM device (TTC of the ego following a leader) in the same run: the same minimum TTC.

    On the right lane (no keep-right lane change for the leader) the ego closes at 10 m/s on a
    leader held at 5 m/s (speedFactor 1, sigma 0), both 4.5 m long, and drops to 5 m/s once the
    bumper gap is 6 m or less. The gap falls 0.5 m a step, from 35.5 m at t = 0 (less the ego's
    first step): the last step before slowing has a gap of 5.98 m, TTC = 5.98 / 5 = 1.196 s. SUMO
    writes its TTC with two decimals (1.20) and labels the step by its start (5.9 s for our 6.0 s):
    the values agree to 0.005 s plus rounding."""
    import xml.etree.ElementTree as ET

    cfg = write_scenario(scenario_dir, """
      <vType id="five" vClass="passenger" length="4.5" width="1.8" maxSpeed="5" speedFactor="1" sigma="0"/>
      <vehicle id="lead" type="five" route="r_main" depart="0" departLane="1" departPos="60" departSpeed="5"/>
      <vehicle id="ego" type="car" route="r_main" depart="0" departLane="1" departPos="20" departSpeed="10"/>""")
    out = tmp_path / "run"
    ssm = tmp_path / "ssm.xml"
    summary = run_scripted(cfg, out, FollowThenMatch("lead", 10.0, 5.0, 6.0), end=12,
                           conflicts=ConflictConfig(ttc=3.0),  # SUMO's default threshold: both log the approach
                           sumo_args=("--device.ssm.probability", "1", "--device.ssm.measures", "TTC",
                                      "--device.ssm.thresholds", "3", "--device.ssm.file", str(ssm)))
    assert summary.status.value == "timeout", summary.message
    c = pd.read_parquet(out / "conflicts.parquet")
    ours = c[c.id_b == "lead"]
    assert len(ours) == 1 and not ours.contact.iloc[0]
    (sumo,) = [m for conf in ET.parse(ssm).getroot().iter("conflict") if (conf.get("ego"), conf.get("foe")) == ("ego", "lead")
               for m in conf.iter("minTTC")]
    assert ours.min_ttc.iloc[0] == pytest.approx(1.196, abs=1e-3)  # by hand, see the docstring
    assert ours.min_ttc.iloc[0] == pytest.approx(float(sumo.get("value")), abs=0.005 + 1e-9)
    assert ours.time_worst.iloc[0] == pytest.approx(float(sumo.get("time")) + 0.1)
    # the gap is 5.98 + 5 (6.0 - t) m: TTC first below 3 s at t = 4.2 (14.98 m; 15.48 m at 4.1)
    assert ours.start.iloc[0] == pytest.approx(4.2)


def test_a_killed_runs_rebuilt_summary_counts_conflicts_and_faults(tmp_path):
    import json

    from sumo_ethics.record.reader import recover_summary

    (tmp_path / "config.json").write_text(json.dumps({"seed": 1, "conflicts": {"enabled": True}}))
    rec = RunRecorder(tmp_path)
    rec.record_conflicts()
    for r in crossing_run(-19.95, -3.82, 50):
        rec.add_conflict(r)
    rec.flush()
    s = recover_summary(tmp_path)
    assert s["status"] == "incomplete"
    assert s["conflicts"] == {"total": 1, "ttc": 0, "pet": 1, "contact": 0, "vru": 1, "by_class": {"pedestrian": 1}}
    assert s["collisions"]["fault"] == {"ego": 0, "other": 0, "shared": 0, "unknown": 0}


@pytest.mark.sumo
def test_run_ego_through_a_red_light_is_the_egos_fault(tmp_path):
    # the ego drives W -> E at 10 m/s through the red light at x = 0 and into a car parked on CE
    # 20 m after the junction: it passed the stop line at red within 5 s, so rule 3 decides (before
    # rule 5, "moved into a standing car")
    net, add = build_signalised(tmp_path / "net")
    (tmp_path / "r.rou.xml").write_text("""<routes>
      <vType id="car" vClass="passenger" length="4.5" width="1.8"/>
      <vehicle id="parked" type="car" depart="0" departPos="25" departSpeed="0"><route edges="CE"/>
        <stop lane="CE_0" endPos="25" duration="1000"/></vehicle>
      <vehicle id="ego" type="car" depart="0" departPos="60" departSpeed="10"><route edges="WC CE"/></vehicle>
    </routes>""")
    cfg = tmp_path / "x.sumocfg"
    cfg.write_text(f'<configuration><input><net-file value="{net}"/><route-files value="r.rou.xml"/>'
                   f'<additional-files value="{add}"/></input><time><end value="30"/><step-length value="0.1"/></time>'
                   '</configuration>')
    out = tmp_path / "run"
    summary = run_scripted(cfg, out, Scripted(10.0), end=30)
    col = pd.read_parquet(out / "collisions.parquet")
    ego = col[col.involves_ego]
    assert summary.status.value == "collision" and len(ego) == 1, summary.message
    r = ego.iloc[0]
    assert r.id_b == "parked" and r.speed_b < 0.1
    assert (r.fault, r.fault_reason) == ("ego", "ego entered the junction at red")
    steps = pd.read_parquet(out / "steps.parquet")
    assert steps.stop_s.notna().any()  # the red stop line was seen ahead


def test_box_distance_against_sampled_outlines():
    """Random pairs at any angle: the distance against the closest of 400 points on each outline
    (never below the true one, at most one sample spacing, 4.5 / 100 m, above it)."""
    rng = np.random.default_rng(5)
    n = 300
    a = Boxes(rng.uniform(-3, 3, n), rng.uniform(-3, 3, n), rng.uniform(-np.pi, np.pi, n), 4.5, 1.8)
    b = Boxes(rng.uniform(-8, 8, n), rng.uniform(-8, 8, n), rng.uniform(-np.pi, np.pi, n), 2.0, 0.8)

    def outline(box: Boxes) -> np.ndarray:  # (n, 400, 2) points along the edges
        c = box.corners()
        f = np.linspace(0, 1, 100, endpoint=False)[:, None]
        return np.concatenate([c[:, k:k + 1] + f * (c[:, (k + 1) % 4:(k + 1) % 4 + 1] - c[:, k:k + 1])
                               for k in range(4)], axis=1)

    pa, pb = outline(a), outline(b)
    sampled = np.linalg.norm(pa[:, :, None] - pb[:, None], axis=-1).min(axis=(1, 2))
    exact = box_distance(a, b)
    apart = ~boxes_overlap(a, b)
    assert apart.sum() > 200 and (exact[~apart] == 0).all()
    assert np.all(exact[apart] <= sampled[apart] + 1e-9) and np.all(sampled[apart] - exact[apart] <= 4.5 / 100)
