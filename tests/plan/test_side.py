"""The side to keep while oncoming traffic passes (sumo_ethics.plan.side, PlannerConfig.keep_side).

The road: a straight single lane along +x, 3.2 m wide (drivable from -1.6 to +1.6 m about its
centre), the ego 1.8 m wide at x = 100 m. An oncoming truck, 2.5 m wide, in the middle of the
next lane to the left, at y = +3.2 m, heading -x (right-hand traffic): its near side passes
3.2 - 1.25 - 1.6 = 0.35 m beyond the centre line, closer than CLEARANCE (0.5 m); mirrored to
y = -3.2 m it is a left-hand network's. By hand: the room towards the right edge is 1.6 - 0.9
(half the ego) - 0.2 (EDGE_MARGIN) = 0.5 m, so with keep_side 0.5 the reference is -0.5 m (right),
+0.5 m mirrored; with keep_side 0.3, -0.3. A 1.8 m wide car in the middle of that lane passes
3.2 - 0.9 - 1.6 = 0.7 m beyond it and moves nothing, unless it drifts.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from sumo_ethics.config import EgoVehicle
from sumo_ethics.contract import RoutePath, Scene
from sumo_ethics.errors import ConfigError
from sumo_ethics.geometry import Polyline
from sumo_ethics.plan.ethical import EthicalPlanner, PlannerConfig
from sumo_ethics.plan.history import History
from sumo_ethics.plan.side import keep_side_reference
from sumo_ethics.types import AgentStates, RoadUserClass

EGO_WIDTH = 1.8


def road(half: float = 1.6) -> RoutePath:
    path = Polyline.from_points(np.stack([np.linspace(0, 400, 401), np.zeros(401)], axis=-1))
    m = len(path.s)
    return RoutePath(edges=("e",), path=path, lane_of_vertex=("e_0",) * m, speed_limit=np.full(m, 13.89),
                     left=np.full(m, half), right=np.full(m, -half), links=())


def agents(x, y, yaw, speed, cls=RoadUserClass.TRUCK, width: float = 2.5) -> AgentStates:
    n = len(x)
    c = np.full(n, int(cls), dtype=np.int8)
    return AgentStates(tuple(f"o{i}" for i in range(n)), np.asarray(x, float), np.asarray(y, float),
                       np.asarray(yaw, float), np.asarray(speed, float), np.zeros(n), np.full(n, 4.5),
                       np.full(n, width), np.full(n, 1400.0), c)


@pytest.mark.parametrize(("y", "expected"), [(3.2, -0.5), (-3.2, 0.5)])
def test_the_side_away_from_oncoming_traffic(y, expected):
    """Oncoming on the left (right-hand traffic): keep right; on the right (a left-hand network): keep left."""
    ref = keep_side_reference(road(), 100.0, 0.0, 10.0, agents([140.0], [y], [math.pi], [10.0]), EGO_WIDTH, 0.5)
    assert ref == pytest.approx(expected, abs=1e-12)
    ref = keep_side_reference(road(), 100.0, 0.0, 10.0, agents([140.0], [y], [math.pi], [10.0]), EGO_WIDTH, 0.3)
    assert ref == pytest.approx(expected * 0.6, abs=1e-12)


def test_room_bounds_the_shift():
    """A 2.6 m lane leaves 1.3 - 0.9 - 0.2 = 0.2 m; a lane as wide as the ego leaves none."""
    others = agents([140.0], [3.0], [math.pi], [10.0])  # 3.0 - 1.25 - 1.3 = 0.45 m beyond: close
    assert keep_side_reference(road(1.3), 100.0, 0.0, 10.0, others, EGO_WIDTH, 0.5) == pytest.approx(-0.2, abs=1e-12)
    assert keep_side_reference(road(0.9), 100.0, 0.0, 10.0, others, EGO_WIDTH, 0.5) == 0.0


@pytest.mark.parametrize(("x", "y", "yaw", "speed", "cls", "why"), [
    (140.0, 3.2, 0.0, 10.0, RoadUserClass.TRUCK, "same direction"),
    (140.0, 3.2, math.pi / 2, 10.0, RoadUserClass.TRUCK, "crossing"),
    (60.0, 3.2, math.pi, 10.0, RoadUserClass.TRUCK, "behind (already passed)"),
    (140.0, 3.2, math.pi, 0.0, RoadUserClass.TRUCK, "parked"),
    (140.0, 3.2, math.pi, 1.3, RoadUserClass.PEDESTRIAN, "a pedestrian"),
    (140.0, 0.3, math.pi, 10.0, RoadUserClass.TRUCK, "head on in the ego's lane: no side"),
    (140.0, 7.0, math.pi, 10.0, RoadUserClass.TRUCK, "two lanes away"),
    (240.0, 3.2, math.pi, 10.0, RoadUserClass.TRUCK, "140 m ahead: 7 s at 20 m/s closing"),
])
def test_no_shift_without_oncoming_traffic_beside_the_path(x, y, yaw, speed, cls, why):
    ref = keep_side_reference(road(), 100.0, 0.0, 10.0, agents([x], [y], [yaw], [speed], cls), EGO_WIDTH, 0.5)
    assert ref == 0.0, why


def test_the_side_holds_while_a_car_drifts_in_and_passes():
    """A car drifting into the ego's lane keeps its side until it is 0.5 m from the ego's line
    (0.9 m: still left; 0.3 m: head on, no side), and one still beside the ego, its centre 3 m
    behind the ego's, still counts (up to PASSING, 5 m); the side is taken from the ego's own offset
    (ego at d = -0.6: a car at d = -0.2 is 0.4 m to its left, too close to tell)."""
    drift = lambda y, x=125.0: agents([x], [y], [math.pi + 0.1], [10.0])  # noqa: E731
    assert keep_side_reference(road(), 100.0, 0.0, 10.0, drift(0.9), EGO_WIDTH, 0.5) == pytest.approx(-0.5)
    assert keep_side_reference(road(), 100.0, 0.0, 10.0, drift(0.3), EGO_WIDTH, 0.5) == 0.0
    assert keep_side_reference(road(), 100.0, 0.0, 10.0, drift(3.2, 97.0), EGO_WIDTH, 0.5) == pytest.approx(-0.5)
    assert keep_side_reference(road(), 100.0, 0.0, 10.0, drift(3.2, 94.0), EGO_WIDTH, 0.5) == 0.0
    assert keep_side_reference(road(), 100.0, -0.6, 10.0, drift(-0.2), EGO_WIDTH, 0.5) == 0.0


@pytest.mark.parametrize(("x", "y", "cls", "ref", "why"), [
    (130.0, -2.5, RoadUserClass.PEDESTRIAN, 0.0, "on the right sidewalk, 0.9 m beyond the edge, 30 m ahead"),
    (120.0, -1.0, RoadUserClass.BICYCLE, 0.0, "a cyclist at the right of the ego's lane"),
    (97.0, -2.5, RoadUserClass.PEDESTRIAN, 0.0, "3 m behind the ego's centre: still beside it"),
    (130.0, 5.0, RoadUserClass.PEDESTRIAN, -0.5, "on the other side"),
    (90.0, -2.5, RoadUserClass.PEDESTRIAN, -0.5, "10 m behind"),
    (130.0, -4.7, RoadUserClass.PEDESTRIAN, -0.5, "3.1 m beyond the edge"),
    (200.0, -2.5, RoadUserClass.PEDESTRIAN, -0.5, "100 m ahead: beyond 6 s at 10 m/s"),
    (130.0, -2.5, RoadUserClass.MOTORCYCLE, -0.5, "a motorcycle is traffic, not a kerb user"),
])
def test_no_shift_towards_a_pedestrian_or_cyclist_on_that_side(x, y, cls, ref, why):
    """With the oncoming truck of the module doc (keep right, -0.5 m), a pedestrian or cyclist ahead on
    the right within 6 s at the ego's 10 m/s (60 m) and up to VRU_ZONE (3 m) beyond the right edge
    (-1.6 m) keeps the ego in the middle."""
    truck = agents([140.0], [3.2], [math.pi], [10.0])
    kerb = agents([x], [y], [0.0], [1.3], cls, width=0.65)
    both = AgentStates(truck.ids + ("v0",), *(np.concatenate([getattr(truck, f), getattr(kerb, f)]) for f in (
        "x", "y", "yaw", "speed", "accel", "length", "width", "mass", "cls")))
    assert keep_side_reference(road(), 100.0, 0.0, 10.0, both, EGO_WIDTH, 0.5) == pytest.approx(ref), why


def test_reach_in_time_and_both_sides():
    """115 m ahead closes in 5.75 s at 10 + 10 m/s (within 6 s); oncoming on both sides moves nothing;
    an oncoming cyclist counts."""
    one = agents([215.0], [3.2], [math.pi], [10.0])
    assert keep_side_reference(road(), 100.0, 0.0, 10.0, one, EGO_WIDTH, 0.5) == pytest.approx(-0.5)
    both = agents([140.0, 150.0], [3.2, -3.2], [math.pi, math.pi], [10.0, 10.0])
    assert keep_side_reference(road(), 100.0, 0.0, 10.0, both, EGO_WIDTH, 0.5) == 0.0
    bike = agents([130.0], [2.0], [math.pi], [5.0], RoadUserClass.BICYCLE, width=0.65)  # 0.075 m beyond
    assert keep_side_reference(road(), 100.0, 0.0, 10.0, bike, EGO_WIDTH, 0.5) == pytest.approx(-0.5)
    assert keep_side_reference(road(), 100.0, 0.0, 10.0, one, EGO_WIDTH, 0.0) == 0.0  # off


def scene(oncoming_y: float | None) -> Scene:
    """The road above, the ego at x = 100 m, 8 m/s; an oncoming car 40 m ahead at 8 m/s (or none)
    with 3 s of straight history."""
    route = road()
    ego = AgentStates(("ego",), np.array([100.0]), np.array([0.0]), np.zeros(1), np.array([8.0]), np.zeros(1),
                      np.array([4.5]), np.array([EGO_WIDTH]), np.array([1475.0]), np.zeros(1, np.int8))
    others = agents([] if oncoming_y is None else [140.0], [] if oncoming_y is None else [oncoming_y],
                    [] if oncoming_y is None else [math.pi], [] if oncoming_y is None else [8.0])
    hist = History(0.1)
    for k in range(31):
        dtk = (k - 30) * 0.1
        hist.push(AgentStates(others.ids, others.x + others.speed * np.cos(others.yaw) * dtk, others.y,
                              others.yaw, others.speed, others.accel, others.length, others.width, others.mass,
                              others.cls))
    return Scene(time=0.0, dt=0.1, ego=ego, others=others, route=route, s=100.0, d=0.0, stop_s=None,
                 vehicle=EgoVehicle(width=EGO_WIDTH), history=hist.observation(0.0, ego, others))


@pytest.mark.parametrize(("oncoming_y", "side"), [(3.2, -1.0), (-3.2, 1.0)])
def test_the_planner_moves_to_the_side_away_while_the_oncoming_car_approaches(oncoming_y, side):
    """With keep_side 0.5 the chosen candidate ends 0.4-0.6 m to the side away from the oncoming
    truck (the grid's end offsets are 0.0875 m apart across -0.7..0.7 m); without it the risk terms
    alone move it less far (0.35 m: the truck's predicted spread reaches into the lane); with no
    oncoming road user it keeps the centre (within one grid step) either way."""
    on = EthicalPlanner(PlannerConfig(predictor="cv", keep_side=0.5))
    dec = on.act(scene(oncoming_y))
    d_end = float(dec.trace.candidates.d[dec.trace.chosen, -1])
    assert dec.info["lateral_reference"] == pytest.approx(0.5 * side)
    assert 0.4 <= side * d_end <= 0.6, d_end
    # no emergency: the brakes to the side (3 more candidates) are not eligible, and it drives on
    assert dec.trace.candidates.speed[dec.trace.chosen, -1] > 7.0
    assert int(dec.info["n_candidates"]) == int(EthicalPlanner(PlannerConfig(predictor="cv")).act(
        scene(oncoming_y)).info["n_candidates"]) + 3
    off = EthicalPlanner(PlannerConfig(predictor="cv")).act(scene(oncoming_y))
    assert 0.0 <= side * float(off.trace.candidates.d[off.trace.chosen, -1]) < 0.4
    assert "lateral_reference" not in off.info
    alone = EthicalPlanner(PlannerConfig(predictor="cv", keep_side=0.5)).act(scene(None))
    assert alone.info["lateral_reference"] == 0.0
    assert abs(float(alone.trace.candidates.d[alone.trace.chosen, -1])) <= 0.09


@pytest.mark.parametrize("bad", [-0.1, 6.0, float("nan"), True, "wide"])
def test_keep_side_refuses_what_is_no_distance(bad):
    with pytest.raises(ConfigError, match="keep_side"):
        PlannerConfig(keep_side=bad)


@pytest.fixture(scope="module")
def narrow_streets(tmp_path_factory):
    """A 300 m two-way street of one 3.2 m lane each way, built right-hand and left-hand
    (netconvert --lefthand), with an oncoming truck (2.5 m wide: 0.35 m beyond the centre line)
    every 10 s on the other lane."""
    from sumo_ethics.sim.netbuild import PlainNet

    made = {}
    for hand in ("right", "left"):
        folder = tmp_path_factory.mktemp(f"narrow_{hand}")
        net = PlainNet("narrow", {"walkingareas": "false", **({"lefthand": "true"} if hand == "left" else {})})
        net.node("A", 0, 0, type="priority")
        net.node("B", 300, 0, type="priority")
        net.two_way("f", "b", "A", "B", numLanes=1, width=3.2, speed=13.89)
        net.build(folder)
        (folder / "narrow.rou.xml").write_text(
            '<routes><vType id="truck" vClass="truck" length="7.5" width="2.5"/>'
            '<flow id="onc" type="truck" begin="0" end="60" period="10" from="b" to="b" departSpeed="8"/></routes>\n')
        (folder / "narrow.sumocfg").write_text(
            '<configuration><input><net-file value="narrow.net.xml"/><route-files value="narrow.rou.xml"/></input>'
            '<time><begin value="0"/><end value="40"/><step-length value="0.1"/></time></configuration>\n')
        made[hand] = folder / "narrow.sumocfg"
    return made


@pytest.mark.sumo
@pytest.mark.parametrize(("hand", "side"), [("right", -1.0), ("left", 1.0)])
def test_in_sumo_the_ego_keeps_the_side_away_from_oncoming_cars(narrow_streets, tmp_path, hand, side):
    """In SUMO, on the right-hand street the ego keeps right of its lane's centre while the oncoming
    cars pass, on the left-hand one left: by hand 1.6 - 0.9 - 0.2 = 0.5 m. Never towards them, and
    the motion within the ego's limits."""
    import pandas as pd

    from sumo_ethics.config import RunConfig
    from sumo_ethics.runner import run

    out = tmp_path / "run"
    s = run(RunConfig(narrow_streets[hand], out, ego_from="f", ego_to="f", end=30.0, progress=False),
            controller=EthicalPlanner(PlannerConfig(predictor="cv", keep_side=0.5)))
    assert s.status.value in ("completed", "timeout"), s.message
    steps = pd.read_parquet(out / "steps.parquet")
    on = steps[steps.lateral_reference != 0.0]
    assert len(on) >= 20 and set(np.round(on.lateral_reference, 9)) == {0.5 * side}
    assert (side * steps.d).min() > -0.05  # never towards the oncoming cars
    settled = on.iloc[len(on) // 2:]  # the second half of the steps with an oncoming car ahead
    assert 0.4 <= (side * settled.d).median() <= 0.6, settled.d.describe()
    limits = EgoVehicle()
    assert steps.accel.between(-limits.max_decel - 1e-6, limits.max_accel + 1e-6).all()
    yaw_rate = np.diff(np.unwrap(steps.yaw.values)) / 0.1
    lat = 0.5 * (steps.speed.values[1:] + steps.speed.values[:-1]) * np.abs(yaw_rate)
    assert lat.max() <= 1.2 * limits.max_lat_accel


def test_brakes_to_the_side_reach_what_the_lateral_limit_allows():
    """From 8 m/s, braking at 3, 5.5 and 8 m/s^2 towards d = -0.5 m: they stop after 64 / (2 b) =
    10.67, 5.82 and 4.00 m. A quintic shift by D over L turns at most 10 / sqrt(3) D / L^2 sharp;
    within 0.9 of 4 m/s^2 / (8 m/s)^2 = 0.0625 1/m that is D <= 0.9 x 0.0625 L^2 / 5.7735:
    1.108 (so the full 0.5), 0.330 and 0.156 m. Each stands still at its end offset, heading
    along the road, and turns within the limit all the way."""
    from sumo_ethics.plan.ethical import brake_candidates
    from sumo_ethics.plan.feasibility import check
    from sumo_ethics.plan.sampling import FrenetState

    route = road()
    state = FrenetState.at_speed(route.path, 100.0, 0.0, 8.0)
    b = np.array([3.0, 5.5, 8.0])
    c = brake_candidates(route.path, state, 40, 0.1, b, max_curvature=0.2, d_end=-0.5, max_lat_accel=4.0)
    reach = 0.9 * 0.0625 * (64.0 / (2.0 * b)) ** 2 / (10.0 / math.sqrt(3.0))
    assert reach == pytest.approx([1.108, 0.330, 0.156], abs=1e-3)
    assert c.d[:, -1] == pytest.approx(-np.minimum(0.5, reach), abs=1e-9)
    assert c.s[:, -1] == pytest.approx(100.0 + 64.0 / (2.0 * b), abs=1e-9)
    assert c.speed[:, -1] == pytest.approx(0.0) and c.yaw[:, -1] == pytest.approx(0.0, abs=1e-9)
    assert (c.speed**2 * np.abs(c.curvature)).max() <= 4.0
    assert check(c, route, EgoVehicle()).feasible.all()
    straight = brake_candidates(route.path, state, 40, 0.1, b, max_curvature=0.2)
    assert (straight.d == 0.0).all() and np.array_equal(straight.s, c.s)  # the same braking, only sideways


def encroaching(keep_side: float):
    """The road above; the ego at x = 100 m, 8 m/s; a car 25 m ahead, 1.8 m to its left, coming at
    10 m/s and drifting into the ego's lane at 1 m/s (heading pi + 0.1) for the last 3 s."""
    route = road()
    ego = AgentStates(("ego",), np.array([100.0]), np.array([0.0]), np.zeros(1), np.array([8.0]), np.zeros(1),
                      np.array([4.5]), np.array([EGO_WIDTH]), np.array([1475.0]), np.zeros(1, np.int8))
    yaw = math.pi + 0.1
    others = agents([125.0], [1.8], [yaw], [10.0], RoadUserClass.CAR, width=1.8)
    hist = History(0.1)
    for k in range(31):
        dtk = (k - 30) * 0.1
        hist.push(AgentStates(others.ids, others.x + 10.0 * math.cos(yaw) * dtk, others.y + 10.0 * math.sin(yaw) * dtk,
                              others.yaw, others.speed, others.accel, others.length, others.width, others.mass,
                              others.cls))
    sc = Scene(time=0.0, dt=0.1, ego=ego, others=others, route=route, s=100.0, d=0.0, stop_s=None,
               vehicle=EgoVehicle(width=EGO_WIDTH), history=hist.observation(0.0, ego, others))
    return EthicalPlanner(PlannerConfig(predictor="cv", keep_side=keep_side)).act(sc)


def test_an_encroaching_car_the_ego_brakes_away_from_not_in_its_path():
    """Every candidate meets the drifting car's predicted box, so the planner brakes hard (8 m/s^2,
    stopped 4 m on). Without keep_side it stops on its lane's centre; with it, braking at 8 m/s^2
    while moving right by what the lateral limit allows (0.156 m, above), which meets that box
    a step later."""
    on, off = encroaching(0.5), encroaching(0.0)
    for dec, d_end in ((off, 0.0), (on, -0.156)):
        c, j = dec.trace.candidates, dec.trace.chosen
        assert c.accel[j, 0] == pytest.approx(-8.0) and c.speed[j, -1] == 0.0
        assert c.s[j, -1] == pytest.approx(104.0)
        assert c.d[j, -1] == pytest.approx(d_end, abs=1e-3)
    assert on.trace.first_hit[on.trace.chosen] > off.trace.first_hit[off.trace.chosen]


def test_no_brake_to_the_side_that_would_steer_towards_the_oncoming_car():
    """The ego already 0.65 m to the right, beyond the 0.5 m of room the side leaves (1.6 - 0.9 -
    0.2): a "brake to the side" would steer it back left, towards the oncoming car, so none is
    sampled (the same number of candidates as without keep_side)."""
    sc = scene(3.2)
    shifted = Scene(**{**sc.__dict__, "d": -0.65,
                       "ego": AgentStates(("ego",), np.array([100.0]), np.array([-0.65]), np.zeros(1), np.array([8.0]),
                                          np.zeros(1), np.array([4.5]), np.array([EGO_WIDTH]), np.array([1475.0]),
                                          np.zeros(1, np.int8))})
    on = EthicalPlanner(PlannerConfig(predictor="cv", keep_side=0.5)).act(shifted)
    off = EthicalPlanner(PlannerConfig(predictor="cv")).act(shifted)
    assert on.info["lateral_reference"] == pytest.approx(-0.5)
    assert on.info["n_candidates"] == off.info["n_candidates"]


def test_a_brake_to_the_side_from_a_sideways_motion_stays_within_the_limits():
    """From 6 m/s moving left at 1 m/s (slope d' = 1/6), braking towards d = -0.5 at 3, 5.5 and 8 m/s^2
    over L = 6, 3.27 and 2.25 m (each at least 2 |d'| / 0.2 = 1.67 m). Settling the slope alone ends
    at d' L / 2 = 0.5, 0.273, 0.1875 m and takes 1.875 |d'| / L = 0.052, 0.095, 0.139 1/m of the
    limit, min(0.2, 4 / 6^2) = 0.111; the rest, 0.059, 0.016 and none, allows a shift of
    0.9 x rest x L^2 / 5.7735 = 0.331, 0.026 and 0 m: ends at 0.169, 0.247, 0.1875 m by hand, all
    three within the limits (before, without the 1.67 m floor and the settling's share, every one
    turned too sharply and none was feasible)."""
    from sumo_ethics.plan.ethical import brake_candidates
    from sumo_ethics.plan.feasibility import check
    from sumo_ethics.plan.sampling import FrenetState

    route = road()
    state = FrenetState(s=100.0, d=0.0, s_dot=6.0, d_dot=1.0)
    b = np.array([3.0, 5.5, 8.0])
    c = brake_candidates(route.path, state, 40, 0.1, b, max_curvature=0.2, d_end=-0.5, max_lat_accel=4.0)
    settle = brake_candidates(route.path, state, 40, 0.1, b, max_curvature=0.2)
    assert check(c, route, EgoVehicle()).feasible.all()
    assert c.d[:, -1] == pytest.approx([0.169, 0.247, 0.1875], abs=1e-3)
    assert c.d[2, -1] == pytest.approx(settle.d[2, -1])  # no limit left: only the slope settles
    assert (c.speed[:, -1] == 0.0).all()
