"""The ego's sensor, memory and phantoms (plan/perception.py, plan/phantoms.py) without SUMO: where
phantoms appear worked out by hand, the memory's growing uncertainty, the braking contingency, the
planner keys."""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely

from conftest import straight_road_scene
from sumo_ethics.errors import ConfigError
from sumo_ethics.plan.ethical import EthicalPlanner, PlannerConfig
from sumo_ethics.plan.perception import (Perception, PerceptionConfig, SightMap, concat_predictions)
from sumo_ethics.plan.phantoms import contingency, phantom_risk
from sumo_ethics.predict.constant_velocity import ConstantVelocityPredictor
from sumo_ethics.types import AgentStates, Candidates, Prediction, RoadUserClass
from dataclasses import replace


def agents(rows, ids=None):
    """AgentStates from rows (x, y, yaw, speed, length, width, mass, class)."""
    a = np.array(rows, dtype=float).reshape(-1, 8)
    ids = ids or tuple(f"a{i}" for i in range(len(a)))
    return AgentStates(tuple(ids), a[:, 0], a[:, 1], a[:, 2], a[:, 3], np.zeros(len(a)), a[:, 4], a[:, 5], a[:, 6],
                       a[:, 7].astype(np.int8))


CAR, PED = int(RoadUserClass.CAR), int(RoadUserClass.PEDESTRIAN)


def scene_with(others, t=0.0, ego_x=10.0, speed=10.0):
    """The conftest road (path y = 0 along x; lanes y -1.75 .. 5.25; ego 4.508 m long at ego_x)."""
    sc = straight_road_scene(others, np.repeat(others.xy[:, None], 31, axis=1) if len(others) else np.zeros((0, 31, 2)))
    ego = AgentStates(("ego",), np.array([ego_x]), np.zeros(1), np.zeros(1), np.array([speed]), np.zeros(1),
                      np.array([4.508]), np.array([1.61]), np.array([1475.0]), np.zeros(1, np.int8))
    return replace(sc, time=t, ego=ego, s=ego_x)


# ---- phantoms where a map says one could be ---------------------------------------------------------
#: a crossing across the whole road at x 48..52, from the right sidewalk's far edge to the left one's
CROSSING = shapely.box(48.0, -4.75, 52.0, 8.25)
#: a bus standing in the left lane just before the crossing: x 36..48, y 2.0..4.5
BUS = [42.0, 3.25, 0.0, 0.0, 12.0, 2.5, 13000.0, int(RoadUserClass.BUS)]


def phantoms_of(others, sight, **cfg):
    p = Perception(PerceptionConfig(**cfg), occlusion=True, phantoms=True, sight=sight)
    return p.perceive(scene_with(others), 40, 0.1)


def test_a_phantom_appears_at_a_crossing_hidden_by_a_bus():
    """Seen from the ego's centre (10, 0) the bus's extreme sight lines run through its corners (48, 2)
    (slope 2/38) and (36, 4.5); on the crossing it hides y from 2.0-2.2 up to 6.6-7.3. The hidden part
    of the crossing, shrunk by the phantom's half size (0.25 m), comes nearest the ego's path at its
    corner on the crossing's near edge x = 48.25, 0.25 m above the sight line through (48, 2):
    y = 2 x 38.25 / 38 + 0.25 sqrt(1 + (2/38)^2) = 2.2635. The phantom stands there facing the path
    (-pi/2) and walks at 1.4 m/s; its walk to the path (x = 48.25) passes the bus (x <= 48)."""
    pc = phantoms_of(agents([BUS]), SightMap(walkable=(CROSSING,)))
    ph = pc.phantoms
    assert ph.kind == ("pedestrian",)
    assert ph.agents.x[0] == pytest.approx(48.25, abs=1e-6)
    assert ph.agents.y[0] == pytest.approx(2 * 38.25 / 38 + 0.25 * math.sqrt(1 + (2 / 38) ** 2), abs=1e-6)
    assert ph.agents.yaw[0] == pytest.approx(-math.pi / 2)
    assert ph.agents.speed[0] == pytest.approx(1.4)
    assert ph.existence[0] == pytest.approx(PerceptionConfig().pedestrian_existence)
    # predicted straight towards and across the path at 1.4 m/s: 2.8 m down after 2 s
    assert ph.prediction.mean[0, 19] == pytest.approx([48.25, ph.agents.y[0] - 2.8], abs=1e-9)
    assert pc.counts() == {"n_in_range": 1.0, "n_visible": 1.0, "n_remembered": 0.0, "n_phantoms": 1.0}


def test_no_phantom_where_the_map_has_no_walkable_place():
    """The same bus with no crossing: its shadow holds no walkable ground, so no pedestrian phantom;
    a sidewalk on the right (y -4.75..-1.75, in full view) gives none either; nor does a map without
    anything walkable, nor a crossing the ego sees whole (no bus)."""
    right = shapely.box(0.0, -4.75, 500.0, -1.75)
    for others, walk in ((agents([BUS]), ()), (agents([BUS]), (right,)), (AgentStates.empty(), (CROSSING,))):
        assert len(phantoms_of(others, SightMap(walkable=walk)).phantoms) == 0


def test_a_phantom_steps_out_in_front_of_a_parked_car():
    """A car parked at the kerb, x 37.5..42.5, y -3.4..-1.4, beside a sidewalk y -4.75..-1.75, seen
    from (10, 0): behind it the sidewalk is hidden from its front (x = 42.5) to where the sight line
    over its near front corner (slope -1.4/32.5) reaches the kerb, x = 50.6. Shrunk by 0.25 m, the
    hidden sidewalk comes nearest the path at y = -2.0 all along; the nearest along the path is
    x = 42.75, 0.25 m past the car's front. The phantom faces the path (+pi/2). Beside the car
    (x < 42.5) the walk to the path would cross the car: no phantom there."""
    car = [40.0, -2.4, 0.0, 0.0, 5.0, 2.0, 1500.0, CAR]
    ph = phantoms_of(agents([car]), SightMap(walkable=(shapely.box(0.0, -4.75, 500.0, -1.75),))).phantoms
    assert len(ph) == 1
    assert (ph.agents.x[0], ph.agents.y[0]) == pytest.approx((42.75, -2.0), abs=1e-6)
    assert ph.agents.yaw[0] == pytest.approx(math.pi / 2)


def test_no_phantom_whose_walk_to_the_path_crosses_a_road_user():
    """A walkable island x 41..43, y -5.6..-4.7 behind a long truck parked at x 30..46, y -4.6..-2.6:
    every sight line from (10, 0) to the island enters the truck's rear face (at x = 30, y from -2.85
    to -3.61), so all of it is hidden, but every walk from it to the path crosses the truck: no phantom.
    Move the island past the truck's front (x 47..49) and the walk is clear: a phantom."""
    truck = [38.0, -3.6, 0.0, 0.0, 16.0, 2.0, 25000.0, int(RoadUserClass.TRUCK)]
    island = shapely.box(41.0, -5.6, 43.0, -4.7)
    assert len(phantoms_of(agents([truck]), SightMap(walkable=(island,))).phantoms) == 0
    past = phantoms_of(agents([truck]), SightMap(walkable=(shapely.box(47.0, -5.6, 49.0, -4.7),))).phantoms
    assert len(past) == 1 and past.agents.x[0] == pytest.approx(47.25)


def test_no_phantom_inside_a_building_over_the_sidewalk():
    """The parked car of the test above with a building x 42..60, y -6..-1.9 over the sidewalk's
    kerb strip (maps overlap so): the point past the car's front where the phantom stood, (42.75, -2.0),
    is inside it, and so is every hidden sidewalk point up to x = 60, beyond the 50 m window: no phantom."""
    car = [40.0, -2.4, 0.0, 0.0, 5.0, 2.0, 1500.0, CAR]
    walk = (shapely.box(0.0, -4.75, 500.0, -1.75),)
    assert len(phantoms_of(agents([car]), SightMap(walkable=walk)).phantoms) == 1
    inside = SightMap(walkable=walk, opaque=(shapely.box(42.0, -6.0, 60.0, -1.9),))
    assert len(phantoms_of(agents([car]), inside).phantoms) == 0


def test_phantom_cyclist_and_vehicle_on_hidden_lanes():
    """A bike lane along y = -2.5 (x 0..200) behind the parked car: its hidden stretch ends where the
    sight line over the car's near front corner (42.5, -1.4) reaches y = -2.5: x = 10 + 2.5 x 32.5 / 1.4
    = 68.0; the cyclist phantom (2 m long) stands 1 m short of it, at x = 67.0, riding on at 5 m/s. A
    lane entering junction J from the left (x = 60, from y = 40 down to y = 6) hidden by a building
    x 45..58, y 6..30 (its far corner (58, 6) bounds the sight line, slope 6/48): the lane is hidden
    from y = 40 down to y = 6 x 50 / 48 = 6.25; a car phantom (4.8 m) at y = 6.25 + 2.4, heading -y at
    the lane's 13.9 m/s (a sensor range of 80 m, phantoms up to 60 m ahead: the junction is 48 m
    ahead). No phantom vehicle when its signal shows red, nor on a lane of the ego's route."""
    from sumo_ethics.plan.perception import LaneLine

    car = [40.0, -2.4, 0.0, 0.0, 5.0, 2.0, 1500.0, CAR]
    bike = LaneLine("b_0", "bike", np.array([[0.0, -2.5], [200.0, -2.5]]), 5.0, "K")
    side = LaneLine("n_0", "road", np.array([[60.0, 40.0], [60.0, 0.0]]), 13.9, "J")
    building = shapely.box(45.0, 6.0, 58.0, 30.0)
    others = agents([car])
    sc = scene_with(others)
    # the ego's path crosses junction J at x 58..62
    lanes = tuple("e_0" if not 58 <= x <= 62 else ":J_0_0" for x in np.linspace(0, 500, 501))
    path = type(sc.route.path).from_points(np.c_[np.linspace(0, 500, 501), np.zeros(501)])
    route = replace(sc.route, path=path, lane_of_vertex=lanes, speed_limit=np.full(501, 14.0), left=np.full(501, 5.25),
                    right=np.full(501, -1.75))
    sc = replace(sc, route=route)

    def run(state=None, edges=("e",)):
        sight = SightMap(opaque=(building,), lanes=(bike, side), link_state=state)
        cfg = PerceptionConfig(pedestrian_existence=0.0, sensor_range=80.0, lookahead_min=60.0)
        p = Perception(cfg, occlusion=True, phantoms=True, sight=sight)
        return p.perceive(replace(sc, route=replace(route, edges=edges)), 40, 0.1).phantoms

    ph = run()
    assert ph.kind == ("cyclist", "vehicle")
    assert (ph.agents.x[0], ph.agents.y[0]) == pytest.approx((10 + 2.5 * 32.5 / 1.4 - 1.0, -2.5), abs=1e-6)
    assert ph.agents.speed[0] == pytest.approx(5.0) and ph.agents.yaw[0] == pytest.approx(0.0)
    assert ph.prediction.mean[0, 9] == pytest.approx([10 + 2.5 * 32.5 / 1.4 - 1.0 + 5.0, -2.5])
    assert (ph.agents.x[1], ph.agents.y[1]) == pytest.approx((60.0, 6.0 * 50 / 48 + 2.4), abs=1e-6)
    assert ph.agents.yaw[1] == pytest.approx(-math.pi / 2) and ph.agents.speed[1] == pytest.approx(13.9)
    assert run(state=lambda lane: "r").kind == ("cyclist",)
    assert run(edges=("e", "n")).kind == ("cyclist",)


# ---- the memory -------------------------------------------------------------------------------------
def test_a_road_user_hidden_is_remembered_with_growing_uncertainty_then_forgotten():
    """A pedestrian at (30, -3) walking +x at 1 m/s is seen at t = 0; a van then stands between it and
    the ego. At t = 0.5 s it is remembered at (30.5, -3) (dead reckoned), age 0.5 s; its prediction is
    the constant-velocity one from its last seen state at 0.5 s + (t + 1) 0.1 s: longitudinal sigma
    0.1 + 0.3 x (0.5 + 0.1) = 0.28 m at the first step (0.1 + 0.3 x 0.1 = 0.13 m for one just seen).
    With memory 2 s it is gone at t = 2.1 s."""
    ped = agents([[30.0, -3.0, 0.0, 1.0, 0.3, 0.5, 75.0, PED]], ids=("p",))
    van = agents([[22.0, -1.9, 0.0, 0.0, 5.0, 2.2, 2500.0, CAR]], ids=("van",))
    p = Perception(PerceptionConfig(memory=2.0), occlusion=True, phantoms=False)
    first = p.perceive(scene_with(ped), 40, 0.1)
    assert first.seen.ids == ("p",) and not len(first.remembered)
    moved = agents([[30.5, -3.0, 0.0, 1.0, 0.3, 0.5, 75.0, PED]], ids=("p",))
    both = agents([list(van.x) + list(van.y) + [0.0, 0.0, 5.0, 2.2, 2500.0, CAR]], ids=("van",))
    from sumo_ethics.plan.perception import concat_agents

    later = p.perceive(scene_with(concat_agents(both, moved), t=0.5), 40, 0.1)
    assert later.seen.ids == ("van",) and later.remembered.ids == ("p",)
    assert later.age[0] == pytest.approx(0.5)
    assert (later.remembered.x[0], later.remembered.y[0]) == pytest.approx((30.5, -3.0))
    pred = later.remembered_prediction(40, 0.1)
    assert math.sqrt(pred.cov[0, 0, 0, 0]) == pytest.approx(0.1 + 0.3 * 0.6)
    assert pred.mean[0, 0] == pytest.approx([30.6, -3.0])
    cv = ConstantVelocityPredictor().predict_arrays(("p",), np.array([[30.0, -3.0]]), np.zeros(1), np.ones(1),
                                                    np.array([PED], np.int8), np.array([0.1]), 0.1)
    assert math.sqrt(cv.cov[0, 0, 0, 0]) == pytest.approx(0.13)
    # the observation the predictor reads: the van seen now; the pedestrian's rows stay in memory
    assert later.observation.current.ids == ("van",)
    gone = p.perceive(scene_with(concat_agents(both, moved), t=2.1), 40, 0.1)
    assert not len(gone.remembered)


def test_a_remembered_road_user_is_forgotten_where_it_would_be_in_view():
    """Seen at (30, -3) standing; then gone from the scene (say, it entered a house). Its place is in
    full view: nothing is seen there, so it is forgotten at once."""
    ped = agents([[30.0, -3.0, 0.0, 0.0, 0.3, 0.5, 75.0, PED]], ids=("p",))
    p = Perception(PerceptionConfig(), occlusion=True, phantoms=False)
    p.perceive(scene_with(ped), 40, 0.1)
    assert not len(p.perceive(scene_with(AgentStates.empty(), t=0.1), 40, 0.1).remembered)


def test_history_from_what_was_seen():
    """A car seen at t = 0 and 0.1 s, hidden at 0.2 s, seen again at 0.3 s: the predictor's rows of
    0.2 s are invalid (it was not seen), the others hold where it was seen."""
    p = Perception(PerceptionConfig(), occlusion=True, phantoms=False)
    wall = agents([[25.0, -1.9, 0.0, 0.0, 4.0, 2.0, 1500.0, CAR]], ids=("wall",))
    from sumo_ethics.plan.perception import concat_agents

    for i, hidden in enumerate((False, False, True, False)):
        car = agents([[40.0 + i, -3.0 if hidden else 3.0, 0.0, 10.0, 4.0, 1.8, 1500.0, CAR]], ids=("c",))
        pc = p.perceive(scene_with(concat_agents(wall, car) if hidden else car, t=0.1 * i), 40, 0.1)
        assert ("c" in pc.seen.ids) is not hidden
    obs = pc.observation
    row = obs.current.index["c"]
    assert obs.valid[row, -4:].tolist() == [True, True, False, True]
    assert obs.history[row, -1].tolist() == [43.0, 3.0]


# ---- the braking contingency and the phantoms' risk --------------------------------------------------
def straight(v, x0=0.0, T=40, dt=0.1):
    t = (np.arange(T) + 1) * dt
    x = x0 + v * t
    z = np.zeros((1, T))
    return Candidates(dt, x[None], z.copy(), z.copy(), np.full((1, T), v), z.copy(), z.copy(), x[None], z.copy(),
                      np.full(1, T * dt), np.ones((1, T), bool))


EGO0 = AgentStates(("ego",), np.zeros(1), np.zeros(1), np.zeros(1), np.full(1, 10.0), np.zeros(1), np.full(1, 4.508),
                   np.full(1, 1.61), np.full(1, 1475.0), np.zeros(1, np.int8))


def test_contingency_drives_on_for_the_reaction_then_brakes_to_a_stop():
    """10 m/s, reaction 0.3 s, 8 m/s^2: x = 10 t up to 0.3 s (3 m), then 3 + 10 tau - 4 tau^2 to a stop
    at tau = 1.25 s (t = 1.55 s, x = 9.25 m); steps from t = 1.6 s, standing, are invalid."""
    c = contingency(straight(10.0), replace(EGO0, speed=np.full(1, 10.0)), 0.3, 8.0)
    t = (np.arange(40) + 1) * 0.1
    tau = np.clip(t - 0.3, 0.0, 1.25)
    assert c.x[0] == pytest.approx(np.where(t <= 0.3 + 1e-9, 10 * t, 3 + 10 * tau - 4 * tau**2), abs=1e-9)
    assert c.speed[0] == pytest.approx(np.maximum(np.where(t <= 0.3 + 1e-9, 10.0, 10 - 8 * (t - 0.3)), 0.0), abs=1e-9)
    assert c.valid[0].tolist() == [bool(x) for x in (t < 1.55)]


def _ped_phantom(x, existence=0.1, y0=-3.0):
    """A phantom pedestrian at (x, y0) walking +y at 1.4 m/s."""
    from sumo_ethics.plan.phantoms import Phantoms

    t = (np.arange(40) + 1) * 0.1
    mean = np.stack([np.full(40, x), y0 + 1.4 * t], -1)[None]
    cv = ConstantVelocityPredictor().predict_arrays(("ph",), np.array([[x, y0]]), np.array([np.pi / 2]),
                                                    np.array([1.4]), np.array([PED], np.int8), t, 0.1)
    pred = Prediction(("ph",), 0.1, mean, cv.cov, np.full((1, 40), np.pi / 2))
    return Phantoms(agents([[x, y0, np.pi / 2, 1.4, 0.3, 0.5, 75.0, PED]], ids=("ph",)), pred, ("pedestrian",),
                    np.array([existence]))


def test_a_phantom_costs_only_what_the_ego_could_no_longer_avoid():
    """A phantom 20 m ahead at the kerb (y = -3) walking into the lane: at 8 m/s the ego, braking 0.3 s
    after it steps out, stops with its front at 2.25 + 2.4 + 4 = 8.7 m: no risk. At 16 m/s it would
    need 2.25 + 4.8 + 16 = 23 m: it reaches the phantom's path before stopping, a risk. A standing ego
    the phantom walks into carries none. The risk scales with the existence probability."""
    from sumo_ethics.ethics.probability import ProbabilityConfig

    pc = ProbabilityConfig()
    ph = _ped_phantom(20.0)
    slow = phantom_risk(straight(8.0), ph, replace(EGO0, speed=np.full(1, 8.0)), pc, 0.3, 8.0)
    fast = phantom_risk(straight(16.0), ph, replace(EGO0, speed=np.full(1, 16.0)), pc, 0.3, 8.0)
    still = phantom_risk(straight(0.0, x0=18.0), _ped_phantom(20.0, y0=-2.0), replace(EGO0, x=np.full(1, 18.0),
                                                                                      speed=np.zeros(1)), pc, 0.3, 8.0)
    assert slow[0, 0] == 0.0 and still[0, 0] == 0.0
    assert fast[0, 0] > 1e-3
    double = phantom_risk(straight(16.0), _ped_phantom(20.0, existence=0.2), replace(EGO0, speed=np.full(1, 16.0)),
                          pc, 0.3, 8.0)
    assert double[0, 0] == pytest.approx(2 * fast[0, 0])


def test_concat_predictions_pads_the_modes():
    a = Prediction(("a",), 0.1, np.zeros((1, 3, 2)), np.tile(np.eye(2), (1, 3, 1, 1)), np.zeros((1, 3)),
                   (Prediction(("a",), 0.1, np.ones((1, 3, 2)), np.tile(np.eye(2), (1, 3, 1, 1)), np.zeros((1, 3))),),
                   np.array([[0.7, 0.3]]))
    b = Prediction(("b",), 0.1, np.full((1, 3, 2), 5.0), np.tile(np.eye(2), (1, 3, 1, 1)), np.zeros((1, 3)))
    c = concat_predictions(a, b)
    assert c.ids == ("a", "b") and c.weight.tolist() == [[0.7, 0.3], [1.0, 0.0]]
    assert c.alternatives[0].mean[1].tolist() == b.mean[0].tolist()


# ---- the planner, its keys ----------------------------------------------------------------------------
def test_default_off_plans_as_before():
    """With the defaults (and with occlusion and phantoms said false) the planner perceives nothing
    of its own: the same command, the same logged numbers, no perception columns."""
    others = agents([[40.0, -2.4, 0.0, 0.0, 5.0, 2.0, 2000.0, CAR], [43.5, -3.2, np.pi / 2, 0.0, 0.3, 0.5, 75.0, PED]])
    sc = straight_road_scene(others, np.repeat(others.xy[:, None], 31, axis=1))
    a = EthicalPlanner(PlannerConfig(predictor="cv")).act(sc)
    b = EthicalPlanner(PlannerConfig(predictor="cv", occlusion=False, phantoms=False)).act(sc)
    assert a.command == b.command and a.info == b.info
    assert "n_visible" not in a.info and a.trace.view is None


def test_occlusion_hides_the_pedestrian_from_the_planner():
    """The pedestrian behind the parked car is not among the planner's road users with occlusion on;
    with phantoms a phantom stands past the car's front and its risk is a term of its own."""
    others = agents([[40.0, -2.4, 0.0, 0.0, 5.0, 2.0, 2000.0, CAR], [43.5, -3.2, np.pi / 2, 0.0, 0.3, 0.5, 75.0, PED]])
    sc = straight_road_scene(others, np.repeat(others.xy[:, None], 31, axis=1))
    sight = SightMap(walkable=(shapely.box(0.0, -4.75, 500.0, -1.75),))
    d = EthicalPlanner(PlannerConfig(predictor="cv", occlusion=True, phantoms=True), sight=sight).act(sc)
    assert d.trace.agents.ids == ("a0",)
    assert d.info["n_in_range"] == 2 and d.info["n_visible"] == 1 and d.info["n_phantoms"] == 1
    assert "cost_phantom" in d.info and "cost_phantom_risk" in d.info
    assert d.trace.view.phantoms.xy[0] == pytest.approx([42.75, -2.0])


def test_planner_keys_and_the_perception_table(tmp_path):
    from sumo_ethics.settings import load_run_toml, planner_config
    from sumo_ethics.suite.evaluate import parse_planner

    spec = parse_planner("occ=base=ours;occlusion=true;phantoms=true")
    cfg = planner_config(None, **spec.options)
    assert cfg.occlusion and cfg.phantoms
    toml = tmp_path / "p.toml"
    toml.write_text("[perception]\nocclusion = true\nsensor_range = 40\nopaque = ['building', 'wall']\n")
    table, _ = load_run_toml(toml)
    cfg = planner_config(table)
    assert cfg.occlusion and not cfg.phantoms
    assert cfg.perception.sensor_range == 40 and cfg.perception.opaque == ("building", "wall")
    toml.write_text("[perception]\nrange = 40\n")
    with pytest.raises(ConfigError, match="unknown key.*range.*known:.*sensor_range"):
        planner_config(load_run_toml(toml)[0])
    toml.write_text("[planner]\nocclusion = true\n[perception]\nocclusion = false\n")
    with pytest.raises(ConfigError, match="both"):
        load_run_toml(toml)
    for bad in ({"occlusion": "yes"}, {"perception": {"min_share": 1.5}}, {"perception": {"sensor_range": 0}},
                {"perception": {"max_phantoms": 2.5}}):
        with pytest.raises(ConfigError):
            planner_config(bad)


def test_sweep_sets_occlusion(tmp_path):
    from sumo_ethics.sweep.grid import make_sweep, parse_set

    assert parse_set(["occlusion=true,false"]) == {"occlusion": [True, False]}
    sweep = make_sweep(straight_road_scene.__globals__["SCENARIOS"] / "testbed" / "testbed.sumocfg", "0.5", "0",
                       ["occlusion=true,false", "perception.sensor_range=30"])
    cfgs = [s.run_config(tmp_path).planner for s in sweep.specs()]
    assert sorted(c.occlusion for c in cfgs) == [False, True]
    assert {c.perception.sensor_range for c in cfgs} == {30.0}


def test_a_recorded_decision_keeps_the_view_and_explain_draws_it(tmp_path):
    """The decision of the planner with occlusion and phantoms, recorded (record.decisions) and read
    back: the sensor's position and range, the visible and hidden regions (WKB, exact), who was seen,
    the phantom (float32 relative to the ego: within a millimetre) with its existence probability;
    explain's figure draws it (the hidden region, the phantom with its legend entry)."""
    from sumo_ethics.analysis.explain import decision_figure
    from sumo_ethics.record import decisions as rec

    others = agents([[40.0, -2.4, 0.0, 0.0, 5.0, 2.0, 2000.0, CAR], [43.5, -3.2, np.pi / 2, 0.0, 0.3, 0.5, 75.0, PED]])
    sc = straight_road_scene(others, np.repeat(others.xy[:, None], 31, axis=1))
    sight = SightMap(walkable=(shapely.box(0.0, -4.75, 500.0, -1.75),))
    d = EthicalPlanner(PlannerConfig(predictor="cv", occlusion=True, phantoms=True), sight=sight).act(sc)
    rec.write(rec.step_path(tmp_path, 1), rec.encode(d.trace, 1, 0.0, 0.1))
    back = rec.load(tmp_path, 1)
    v = back.view
    assert v is not None and v.radius == 50.0 and v.eye.tolist() == [10.0, 0.0]
    assert v.visible.equals(d.trace.view.visible) and v.hidden.equals(d.trace.view.hidden)
    assert v.seen == ("a0",) and v.remembered == ()
    assert v.phantoms[0, :2] == pytest.approx([42.75, -2.0], abs=1e-3)
    assert v.phantom_existence.tolist() == pytest.approx([0.1])
    assert "phantom" in back.terms and "phantom_risk" in back.terms
    fig, _, _ = decision_figure(back, None, "test")
    labels = [t.get_text() for leg in fig.legends for t in leg.get_texts()]
    assert any(lb.startswith("phantom") for lb in labels) and any(lb.startswith("hidden") for lb in labels)
    import matplotlib.pyplot as plt

    plt.close(fig)
