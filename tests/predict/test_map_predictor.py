"""The map-aware predictor: map features on a hand-made lane geometry, the model's shapes,
refusal of weights of another kind or map version, the shipped default, and the map
context read from a real SUMO run."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from sumo_ethics.predict import PredictorError  # noqa: E402
from sumo_ethics.predict import features as F  # noqa: E402
from sumo_ethics.predict.models import TrajectoryLSTM, load_model, save_model  # noqa: E402
from sumo_ethics.predict.predictor import LSTMPredictor, default_weights  # noqa: E402
from sumo_ethics.types import AgentStates, Observation, RoadUserClass  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
URBAN = ROOT / "scenarios" / "urban" / "urban.sumocfg"


def junction_graph() -> F.LaneGraph:
    """Two-lane road 'a' along +x from 0 to 100 m (lane a_0 at y = 0, a_1 at y = 3.2, on its
    left); a_0 leads to 'b_0' straight up the y axis from (100, 0) (50 m, 8 m/s) and to 'c_0'
    straight on to (200, 0); a_1 leads to 'd_1' (100, 3.2)->(200, 3.2)."""
    shapes = {
        "a_0": [[0, 0], [100, 0]],
        "a_1": [[0, 3.2], [100, 3.2]],
        "b_0": [[100, 0], [100, 50]],
        "c_0": [[100, 0], [200, 0]],
        "d_1": [[100, 3.2], [200, 3.2]],
    }
    ids = list(shapes)
    links = [("b_0", "c_0"), ("d_1",), (), (), ()]
    return F.LaneGraph.build(ids, [np.array(shapes[k], float) for k in ids], [13.9, 13.9, 8.0, 13.9, 13.9], links)


def test_map_features_by_hand():
    g = junction_graph()
    # a car on a_0 at lane position 90 m, heading +x at 10 m/s: ds = max(2.5, 0.5 * 10) = 5 m,
    # points at arc lengths 90, 95, ..., 135 m along each path; a red light 20 m ahead that
    # stays red for 3 more seconds
    ctx = F.MapContext(lane=np.array([0]), lane_pos=np.array([90.0]), tls_dist=np.array([20.0]),
                       tls_state=np.array([3]), tls_switch=np.array([3.0]))
    f = F.map_features(g, ctx, np.array([[90.0, 0.0]]), np.array([0.0]), np.array([10.0]))
    pts, valid = f["map_pts"][0], f["map_valid"][0]
    # two branches ahead (b_0 first: SUMO's link order), no third or fourth; a_1 on the left, no right lane
    assert valid.tolist() == [True, True, False, False, True, False]
    # via b_0: 0, 5, 10 m along x, then up the y axis 5, 10, ..., 35 m (target frame = world shifted by 90 m)
    want_b = [[0, 0], [5, 0], [10, 0]] + [[10, 5 * k] for k in range(1, 8)]
    np.testing.assert_allclose(pts[0], want_b, atol=1e-5)
    # via c_0: straight on, 0 ... 45 m
    np.testing.assert_allclose(pts[1], [[5 * k, 0] for k in range(10)], atol=1e-5)
    # left lane a_1 then d_1, 3.2 m to the left
    np.testing.assert_allclose(pts[4], [[5 * k, 3.2] for k in range(10)], atol=1e-5)
    assert np.all(pts[[2, 3, 5]] == 0)
    # [on a lane, light ahead, 20/50, green, yellow, red, 13.9/30, red for 3 s / 10 s]
    # and no blinker (left, right)
    np.testing.assert_allclose(f["map_scalar"][0], [1, 1, 0.4, 0, 0, 1, 13.9 / 30, 0.3, 0, 0], atol=1e-6)
    # map version 2 models read the first 7 scalars only, version 3 the first 8
    for version, n in ((2, 7), (3, 8)):
        fv = F.map_features(g, ctx, np.array([[90.0, 0.0]]), np.array([0.0]), np.array([10.0]), version=version)
        np.testing.assert_array_equal(fv["map_scalar"], f["map_scalar"][:, :n])
        np.testing.assert_array_equal(fv["map_pts"], f["map_pts"])


def test_blinkers_are_the_vehicles_scalars_8_and_9():
    """SUMO's signal bits: 1 right blinker, 2 left blinker, 4 hazard flasher (both lit); other
    bits (brake light 8) are not blinkers; pedestrians have none; version 3 reads 8 scalars."""
    g = junction_graph()
    bits = np.array([0, 1, 2, 4, 3, 8, 2])
    n = len(bits)
    person = np.array([False] * 6 + [True])
    ctx = F.MapContext(np.zeros(n, dtype=np.int64), np.full(n, 50.0), np.full(n, np.inf), np.zeros(n, dtype=np.int64),
                       person=person, blinker=bits)
    xy, yaw, v = np.column_stack([np.full(n, 50.0), np.zeros(n)]), np.zeros(n), np.full(n, 5.0)
    f = F.map_features(g, ctx, xy, yaw, v)
    assert f["map_scalar"][:, 8:].tolist() == [[0, 0], [0, 1], [1, 0], [1, 1], [1, 1], [0, 0], [0, 0]]
    f3 = F.map_features(g, ctx, xy, yaw, v, version=3)
    assert f3["map_scalar"].shape == (n, 8)
    np.testing.assert_array_equal(f3["map_scalar"], f["map_scalar"][:, :8])


def test_map_features_rotate_into_the_target_frame_and_hold_a_dead_end():
    g = junction_graph()
    # on b_0 (heading +y, yaw pi/2) at 40 m of 50, standing: ds = 2.5 m; b_0 is a dead end
    # after 10 m, so points 5..9 repeat its end; in the target's frame +x is +y of the world
    ctx = F.MapContext(np.array([2]), np.array([40.0]), np.array([np.inf]), np.array([0]))
    f = F.map_features(g, ctx, np.array([[100.0, 40.0]]), np.array([np.pi / 2]), np.array([0.0]))
    ahead = f["map_pts"][0, 0]
    np.testing.assert_allclose(ahead[:, 0], [0, 2.5, 5, 7.5, 10, 10, 10, 10, 10, 10], atol=1e-5)
    np.testing.assert_allclose(ahead[:, 1], 0, atol=1e-5)
    np.testing.assert_allclose(f["map_scalar"][0], [1, 0, 0, 0, 0, 0, 8.0 / 30, 0, 0, 0], atol=1e-6)


def test_no_lane_means_no_map():
    f = F.map_features(junction_graph(), F.MapContext.empty(2), np.zeros((2, 2)), np.zeros(2), np.ones(2))
    assert not f["map_valid"].any() and not f["map_scalar"].any()
    f = F.map_features(None, F.MapContext(np.array([0]), np.array([0.0]), np.array([5.0]), np.array([1])),
                       np.zeros((1, 2)), np.zeros(1), np.ones(1))
    assert not f["map_valid"].any()


def test_lane_positions_scale_onto_the_shape():
    """SUMO's lane length may differ from its shape's length: positions are scaled."""
    g = F.LaneGraph.build(["e_0"], [np.array([[0.0, 0.0], [50.0, 0.0]])], [10.0], [()], lengths=[100.0])
    assert g.shape_pos(0, 50.0) == pytest.approx(25.0)


def walking_graph() -> F.LaneGraph:
    """A sidewalk 's_0' along +x from (0, 0) to (20, 0); a walking area ':J_w0_0' (a square
    patch, 20..24 x -2..2); a crossing ':J_c0_0' up the line x = 22 from (22, 2) to (22, 12);
    a sidewalk 't_0' from (22, 14) to (22, 40)."""
    shapes = {
        "s_0": [[0, 0], [20, 0]],
        ":J_w0_0": [[20, -2], [24, -2], [24, 2], [20, 2], [20, -2]],
        ":J_c0_0": [[22, 2], [22, 12]],
        "t_0": [[22, 14], [22, 40]],
    }
    ids = list(shapes)
    links = [(":J_w0_0",), ("s_0",), (":J_w0_0",), ()]
    return F.LaneGraph.build(ids, [np.array(shapes[k], float) for k in ids], [13.9] * 4, links)


def _walker(lane, pos, next_lane=-1, tls_dist=np.inf, tls_state=0, tls_switch=np.inf):
    return F.MapContext(np.array([lane]), np.array([pos]), np.array([tls_dist]), np.array([tls_state]),
                        person=np.array([True]), next_lane=np.array([next_lane]), tls_switch=np.array([tls_switch]))


def test_pedestrian_rows_follow_its_heading_along_a_sidewalk():
    g = walking_graph()
    # at 10 m along s_0 walking -x (yaw pi): the sidewalk reversed, 1 m apart: world x = 10, 9, ..., 1,
    # which is straight ahead in its frame; its next lane is the walking area: no second row
    f = F.map_features(g, _walker(0, 10.0, next_lane=1), np.array([[10.0, 0.0]]), np.array([np.pi]), np.array([1.2]))
    np.testing.assert_allclose(f["map_pts"][0, 0], [[k, 0] for k in range(10)], atol=1e-5)
    assert f["map_valid"][0].tolist() == [True, False, False, False, False, False]
    # no light, and the walking lane's speed limit (the road's) is left out
    np.testing.assert_allclose(f["map_scalar"][0], [1, 0, 0, 0, 0, 0, 0, 0, 0, 0], atol=1e-6)
    # at 15 m walking +x: 15, 16, ..., 20 m, then the sidewalk's end held
    f = F.map_features(g, _walker(0, 15.0), np.array([[15.0, 0.0]]), np.array([0.0]), np.array([1.2]))
    np.testing.assert_allclose(f["map_pts"][0, 0, :, 0], [0, 1, 2, 3, 4, 5, 5, 5, 5, 5], atol=1e-5)


def test_pedestrian_waiting_on_a_walking_area_sees_its_crossing_and_the_red_light():
    g = walking_graph()
    # standing at (21, 1.5) facing +y on the walking area, its walk goes on over the crossing,
    # whose light is red 0.5 m away for 2.5 s more. In the pedestrian's frame +x is world +y and
    # +y is world -x. Version 4: row 0 is the crossing from its nearer end (22, 2), world (22, 2 + k):
    # (0.5 + k, -1)
    ctx, args = _walker(1, 2.0, next_lane=2, tls_dist=0.5, tls_state=3, tls_switch=2.5), \
        (np.array([[21.0, 1.5]]), np.array([np.pi / 2]), np.array([0.0]))
    f4 = F.map_features(g, ctx, *args, version=4)
    np.testing.assert_allclose(f4["map_pts"][0, 0], [[0.5 + k, -1.0] for k in range(10)], atol=1e-5)
    # version 5: the straight walk to (22, 2), sqrt(1^2 + 0.5^2) = 1.118 m, then the crossing. At 1 m:
    # 1 / 1.118 of (1, 0.5) from (21, 1.5), world (21.894, 1.947): (0.447, -0.894); at k >= 2 m,
    # k - 1.118 m up the crossing, world (22, 2 + k - 1.118): (0.5 + k - 1.118, -1)
    f = F.map_features(g, ctx, *args)
    gap = np.hypot(1.0, 0.5)
    np.testing.assert_allclose(f["map_pts"][0, 0, :2], [[0, 0], [0.5 / gap, -1 / gap]], atol=1e-5)
    np.testing.assert_allclose(f["map_pts"][0, 0, 2:], [[0.5 + k - gap, -1.0] for k in range(2, 10)], atol=1e-5)
    # the version-4 row travels with it, for the models of versions 2-4
    np.testing.assert_array_equal(f["map_row0_v4"][0], f4["map_pts"][0, 0])
    assert f["map_valid"][0].tolist() == f4["map_valid"][0].tolist() == [True, False, False, False, False, False]
    # [on a lane, a signalised crossing ahead, 0.5 / 50, green, yellow, red, 0, 2.5 s / 10 s]
    np.testing.assert_allclose(f["map_scalar"][0], [1, 1, 0.01, 0, 0, 1, 0, 0.25, 0, 0], atol=1e-6)


def test_pedestrian_on_a_crossing_sees_its_rest_and_the_sidewalk_beyond():
    g = walking_graph()
    # 4 m along the crossing at (22, 6) heading +y, green: row 0 the crossing's last 6 m (held at
    # its end, world y = 12), row 1 the sidewalk t_0 from its nearer end (22, 14): 8, 9, ... m ahead
    f = F.map_features(g, _walker(2, 4.0, next_lane=3, tls_dist=0.0, tls_state=1), np.array([[22.0, 6.0]]),
                       np.array([np.pi / 2]), np.array([1.3]))
    np.testing.assert_allclose(f["map_pts"][0, 0, :, 0], [0, 1, 2, 3, 4, 5, 6, 6, 6, 6], atol=1e-5)
    np.testing.assert_allclose(f["map_pts"][0, 1], [[8 + k, 0] for k in range(10)], atol=1e-5)
    assert f["map_valid"][0].tolist() == [True, True, False, False, False, False]
    # green with no phase that changes it (tls_switch inf): the clipped 2
    np.testing.assert_allclose(f["map_scalar"][0], [1, 1, 0, 1, 0, 0, 0, 2, 0, 0], atol=1e-6)


def test_pedestrian_walking_to_a_walking_area_sees_the_crossing_after_it_from_version_4():
    g = walking_graph()
    # at 10 m along s_0 walking +x toward the walking area (its next lane, which has no row); the
    # walk goes on over the crossing: row 2 is the crossing from its nearer end (22, 2), world
    # (22, 2 + k), in the walker's frame (origin (10, 0), +x = world +x): (12, 2 + k)
    ctx = F.MapContext(np.array([0]), np.array([10.0]), np.array([np.inf]), np.array([0]), person=np.array([True]),
                       next_lane=np.array([1]), tls_switch=np.array([np.inf]), after_lane=np.array([2]))
    args = (np.array([[10.0, 0.0]]), np.array([0.0]), np.array([1.2]))
    f = F.map_features(g, ctx, *args)
    assert f["map_valid"][0].tolist() == [True, False, True, False, False, False]
    np.testing.assert_allclose(f["map_pts"][0, 0], [[k, 0] for k in range(10)], atol=1e-5)
    np.testing.assert_allclose(f["map_pts"][0, F.MAP_ROW_AFTER], [[12, 2 + k] for k in range(10)], atol=1e-5)
    # version 3 has no such row; a version-3 model's tensors of the version-4 sample are its own features
    f3 = F.map_features(g, ctx, *args, version=3)
    assert f3["map_valid"][0].tolist() == [True, False, False, False, False, False] and not f3["map_pts"][0, 2].any()
    from sumo_ethics.predict.models import batch_to_tensors

    def tensors(feats, version):
        batch = {"tgt_group": np.array([F.GROUP_PEDESTRIAN]), "nbr_batch": np.zeros(0, dtype=np.int64),
                 "tgt_hist": np.zeros((1, F.HIST_STEPS, 2)), "nbr_hist": np.zeros((0, F.HIST_STEPS, 2)),
                 "nbr_group": np.zeros(0, dtype=np.int64), "nbr_cell": np.zeros(0, dtype=np.int64), **feats}
        return batch_to_tensors(batch, with_map=True, map_version=version)

    t4_as_3, t3 = tensors(f, 3), tensors(f3, 3)
    for key in ("map_pts", "map_valid", "map_scalar"):
        assert torch.equal(t4_as_3[key], t3[key]), key
    assert tensors(f, 4)["map_valid"][0, 2]


def test_the_lane_after_a_walking_area_is_the_first_step_of_the_shortest_walk_to_the_next_sidewalk():
    """A junction with two walking areas w0 and w1 joined by crossing c0 (linked w0 -> c0 -> w1, as
    SUMO links a crossing one way, though pedestrians walk it both ways); sidewalk s ends at w0,
    u starts at w0 and t at w1; w0 -> c1 -> w1 is a longer crossing."""
    from sumo_ethics.sim.lanes import after_walking_area

    ids = ["s_0", ":J_w0_0", ":J_c0_0", ":J_c1_0", ":J_w1_0", "t_0", "u_0"]
    lengths = [50.0, 3.0, 10.0, 25.0, 3.0, 40.0, 30.0]
    links = [(":J_w0_0",), (":J_c0_0", ":J_c1_0", "u_0"), (":J_w1_0",), (":J_w1_0",), ("t_0",), (), ()]
    shapes = [np.array([[0.0, 0.0], [x, 0.0]]) for x in lengths]
    g = F.LaneGraph.build(ids, shapes, [13.9] * len(ids), links, lengths)
    w0, c0, w1, t, u = (g.index[k] for k in (":J_w0_0", ":J_c0_0", ":J_w1_0", "t_0", "u_0"))
    # from s, at w0: on to t over the shorter crossing c0 (13 m against 28 m), or straight to u
    assert after_walking_area(g, w0, frozenset({"t"})) == c0
    assert after_walking_area(g, w0, frozenset({"u"})) == u
    # against the crossing's link direction: from w1 back to s over c0
    assert after_walking_area(g, w1, frozenset({"s"})) == c0
    # not over the crossing the walker is on: the longer one is left; an edge not there: none
    assert after_walking_area(g, w1, frozenset({"s"}), skip=c0) == g.index[":J_c1_0"]
    assert after_walking_area(g, w0, frozenset({"x"})) == -1
    # on a crossing, any edge of the walk: the one across (its walk s -> t, arriving at w1: t, not s)
    assert after_walking_area(g, w1, frozenset({"s", "t"}), skip=c0) == t


def test_map_version_1_gives_pedestrians_nothing_and_vehicles_the_same():
    g = junction_graph()
    car = F.MapContext(np.array([0, 0]), np.array([90.0, 50.0]), np.array([20.0, 5.0]), np.array([3, 1]),
                       person=np.array([False, True]), next_lane=np.array([-1, -1]))
    xy, yaw, v = np.array([[90.0, 0.0], [50.0, 0.0]]), np.zeros(2), np.array([10.0, 1.0])
    new, old = F.map_features(g, car, xy, yaw, v), F.map_features(g, car, xy, yaw, v, version=1)
    for key in old:  # the car: the same (version 1 has the first 7 scalars)
        np.testing.assert_array_equal(new[key][0][..., :old[key].shape[-1]] if key == "map_scalar" else new[key][0],
                                      old[key][0])
    assert new["map_valid"][1, 0] and not old["map_valid"][1].any() and not old["map_scalar"][1].any()
    assert not old["map_pts"][1].any()
    # the tensors of a version-1 model empty the pedestrians' rows of a version-2 sample the same way
    from sumo_ethics.predict.models import batch_to_tensors

    batch = {"tgt_group": np.array([F.GROUP_VEHICLE, F.GROUP_PEDESTRIAN]), "nbr_batch": np.zeros(0, dtype=np.int64),
             "tgt_hist": np.zeros((2, F.HIST_STEPS, 2)), "nbr_hist": np.zeros((0, F.HIST_STEPS, 2)),
             "nbr_group": np.zeros(0, dtype=np.int64), "nbr_cell": np.zeros(0, dtype=np.int64), **new}
    t1, t2 = batch_to_tensors(batch, with_map=True, map_version=1), batch_to_tensors(batch, with_map=True)
    assert not t1["map_valid"][1].any() and not t1["map_scalar"][1].any() and not t1["map_pts"][1].any()
    assert torch.equal(t1["map_pts"][0], t2["map_pts"][0]) and torch.equal(t1["map_valid"][0], t2["map_valid"][0])
    assert t2["map_valid"][1, 0]


def test_each_target_of_a_mixed_batch_gets_what_it_gets_alone():
    """Cars and pedestrians, with and without a lane, before red, yellow and green lights and none,
    in one call: every row equals the call for that target alone, for each map version."""
    a, w = junction_graph(), walking_graph()
    # one graph with both: the walking graph's lanes after the junction graph's 5
    g = F.LaneGraph.build(a.ids + w.ids, a.shapes + w.shapes, np.concatenate([a.speed, w.speed]),
                          [tuple(a.ids[j] for j in s) for s in a.succ] + [tuple(w.ids[j] for j in s) for s in w.succ])
    lane = np.array([0, 5, -1, 1, 6, 0, 2, 8])  # a_0, s_0 (walker), none, a_1, walking area (walker), a_0, b_0, t_0 (walker)
    person = np.array([False, True, False, False, True, False, False, True])
    ctx = F.MapContext(lane, np.array([90.0, 10.0, 0.0, 20.0, 1.0, 40.0, 5.0, 3.0]),
                       np.array([20.0, np.inf, 5.0, 150.0, 0.0, np.inf, 30.0, 2.0]), np.array([3, 0, 1, 2, 3, 1, 1, 0]),
                       person=person, next_lane=np.array([-1, 6, -1, -1, 7, -1, -1, -1]),
                       tls_switch=np.array([12.0, np.inf, 3.0, np.inf, 25.0, 4.0, 0.5, np.inf]),
                       blinker=np.array([2, 1, 1, 4, 3, 0, 1, 0]), after_lane=np.array([-1, 7, -1, -1, -1, -1, -1, -1]))
    xy = np.array([[90.0, 0.0], [10.0, 0.0], [5.0, 5.0], [20.0, 3.2], [21.0, 1.5], [40.0, 0.0], [100.0, 5.0], [22.0, 17.0]])
    yaw = np.array([0.0, np.pi, 0.3, 0.0, np.pi / 2, 0.0, np.pi / 2, np.pi / 2])
    speed = np.array([10.0, 1.2, 3.0, 14.0, 0.0, 0.0, 6.0, 1.4])
    for version in F.MAP_VERSIONS:
        batch = F.map_features(g, ctx, xy, yaw, speed, version=version)
        assert batch["map_valid"][[0, 3, 5, 6]].any(axis=1).all() and not batch["map_valid"][2].any()
        for i in range(len(lane)):
            one = F.MapContext(*(np.asarray(getattr(ctx, k))[i:i + 1] for k in
                                 ("lane", "lane_pos", "tls_dist", "tls_state", "person", "next_lane", "tls_switch",
                                  "blinker", "after_lane")))
            alone = F.map_features(g, one, xy[i:i + 1], yaw[i:i + 1], speed[i:i + 1], version=version)
            for key in batch:
                np.testing.assert_array_equal(batch[key][i], alone[key][0], err_msg=f"{key} of target {i}, version {version}")
    # by hand, version 4: the car before the red light 20 m ahead, which holds 12 s, blinking left;
    # the yellow one 150 m ahead (distance clipped to 2 x 50 m), its switch time unknown (clipped to
    # 2 x 10 s), hazard flasher on; the walker on s_0 sees the crossing after its walking area
    np.testing.assert_allclose(batch["map_scalar"][0], [1, 1, 0.4, 0, 0, 1, 13.9 / 30, 1.2, 1, 0], atol=1e-6)
    np.testing.assert_allclose(batch["map_scalar"][3], [1, 1, 2, 0, 1, 0, 13.9 / 30, 2, 1, 1], atol=1e-6)
    assert not batch["map_scalar"][[1, 4], 8:].any()  # walkers have no blinkers
    assert batch["map_valid"][1].tolist() == [True, False, True, False, False, False]


def test_version_5_samples_give_earlier_models_exactly_their_own_inputs():
    """Many targets at random places (walkers on a walking area and walkers with a lane after
    their walking area among them): a version 2-4 model's tensors of version-5 features equal
    those of its own version's features, bit for bit; so a version-4 file trains and is evaluated
    the same from a version-5 dataset. (A version-1
    model's tensors of later features agree up to float32 rounding only: its features leave the
    pedestrians' rows out of the one sampling pass, which moves the vehicles' rows in it.)"""
    from sumo_ethics.predict.models import batch_to_tensors

    a, w = junction_graph(), walking_graph()
    g = F.LaneGraph.build(a.ids + w.ids, a.shapes + w.shapes, np.concatenate([a.speed, w.speed]),
                          [tuple(a.ids[j] for j in s) for s in a.succ] + [tuple(w.ids[j] for j in s) for s in w.succ])
    rng = np.random.default_rng(4)
    n = 400
    person = rng.random(n) < 0.5
    lane = np.where(person, rng.choice([5, 6, 7], n), rng.choice([0, 1, 2, 3, 4], n))
    ctx = F.MapContext(lane, rng.uniform(0, 60, n), np.where(rng.random(n) < 0.5, rng.uniform(0, 80, n), np.inf),
                       rng.integers(0, 4, n), person=person, next_lane=np.where(person, rng.choice([-1, 6, 7, 8], n), -1),
                       tls_switch=rng.uniform(0, 30, n), blinker=rng.integers(0, 8, n),
                       after_lane=np.where(person & (rng.random(n) < 0.7), rng.choice([7, 8], n), -1))
    xy, yaw, speed = rng.uniform(0, 150, (n, 2)), rng.uniform(-np.pi, np.pi, n), rng.uniform(0, 15, n)
    group = np.where(person, F.GROUP_PEDESTRIAN, F.GROUP_VEHICLE)
    base = {"tgt_group": group, "nbr_batch": np.zeros(0, dtype=np.int64), "tgt_hist": np.zeros((n, F.HIST_STEPS, 2)),
            "nbr_hist": np.zeros((0, F.HIST_STEPS, 2)), "nbr_group": np.zeros(0, dtype=np.int64),
            "nbr_cell": np.zeros(0, dtype=np.int64)}
    v5 = F.map_features(g, ctx, xy, yaw, speed)
    assert v5["map_valid"][person, F.MAP_ROW_AFTER].sum() > 50  # the second pass has rows
    across = np.any(v5["map_pts"][:, 0] != v5["map_row0_v4"], axis=-1).any(axis=-1)
    assert across.sum() > 15 and person[across].all()  # and the third: walkers on the walking area
    for version in (2, 3, 4):
        own = F.map_features(g, ctx, xy, yaw, speed, version=version)
        t4 = batch_to_tensors({**base, **v5}, with_map=True, map_version=version)
        tv = batch_to_tensors({**base, **own}, with_map=True, map_version=version)
        for key in ("map_pts", "map_valid", "map_scalar"):
            assert torch.equal(t4[key], tv[key]), (version, key)


def _batch(n: int = 3, n_nbr: int = 4):
    rng = np.random.default_rng(0)
    return dict(
        tgt_hist=torch.tensor(rng.normal(size=(n, F.HIST_STEPS, 2)), dtype=torch.float32),
        tgt_group=torch.tensor([0, 1, 2][:n]),
        nbr_hist=torch.tensor(rng.normal(size=(n_nbr, F.HIST_STEPS, 2)), dtype=torch.float32),
        nbr_group=torch.zeros(n_nbr, dtype=torch.long),
        nbr_batch=torch.tensor([0, 0, 1, 2][:n_nbr]),
        nbr_cell=torch.tensor([3, 20, 7, 30][:n_nbr]),
    )


def test_map_model_shapes_and_masking():
    torch.manual_seed(0)
    m = TrajectoryLSTM(kind="map").eval()
    b = _batch()
    pts = torch.randn(3, F.MAP_LANES, F.MAP_POINTS, 2)
    valid = torch.zeros(3, F.MAP_LANES, dtype=torch.bool)
    valid[0, :2] = True
    scalar = torch.rand(3, F.MAP_SCALARS)
    with torch.no_grad():
        out = m(**b, map_pts=pts, map_valid=valid, map_scalar=scalar)
        assert out.shape == (3, F.FUT_STEPS, 5)
        assert torch.all(out[..., 2:4] > 0) and torch.all(out[..., 4].abs() < 1)
        # invalid polylines change nothing
        pts2 = pts.clone()
        pts2[0, 2:] += 100.0
        pts2[1:] += 100.0
        assert torch.equal(out, m(**b, map_pts=pts2, map_valid=valid, map_scalar=scalar))
        # a valid one does
        pts3 = pts.clone()
        pts3[0, 0] += 1.0
        assert not torch.equal(out[0], m(**b, map_pts=pts3, map_valid=valid, map_scalar=scalar)[0])
        # no map inputs at all = every polyline invalid and zero scalars
        none = m(**b)
        assert torch.equal(none, m(**b, map_pts=pts, map_valid=torch.zeros_like(valid), map_scalar=torch.zeros_like(scalar)))


def test_old_kinds_are_unchanged_by_the_map_code():
    """cslstm and attention build the same parameters in the same order as before the map kind
    (the shipped ablation files still load and the seeded initialisation is the same)."""
    for kind in ("cslstm", "attention"):
        model, header = load_model(default_weights(kind), kind=kind)
        assert header["feature_version"] == 1 and not any(k.startswith(("poly_enc", "map_query", "scalar_emb"))
                                                          for k in model.state_dict())


def test_weights_of_another_kind_or_map_version_are_refused(tmp_path):
    torch.manual_seed(0)
    path = save_model(TrajectoryLSTM(kind="map"), tmp_path / "m.pt")
    with pytest.raises(PredictorError, match="holds a 'map' model, expected 'attention'"):
        load_model(path, kind="attention")
    blob = torch.load(path, weights_only=True)
    blob["map_version"] = 0
    torch.save(blob, tmp_path / "old_map.pt")
    with pytest.raises(PredictorError, match="map_version=0, this code reads 1 or 2 or 3 or 4 or 5"):
        load_model(tmp_path / "old_map.pt")
    blob["map_version"], blob["kind"] = F.MAP_VERSION, "transformer"
    torch.save(blob, tmp_path / "other.pt")
    with pytest.raises(PredictorError, match="unknown model kind 'transformer'"):
        load_model(tmp_path / "other.pt")
    blob["kind"], blob["feature_version"] = "map", 2
    torch.save(blob, tmp_path / "fv2.pt")
    with pytest.raises(PredictorError, match="feature_version=2"):
        load_model(tmp_path / "fv2.pt")


@pytest.mark.skipif(not URBAN.exists(), reason="bundled urban scenario missing")
def test_cli_refuses_a_map_file_for_the_attention_predictor_before_sumo_starts(tmp_path):
    torch.manual_seed(0)
    path = save_model(TrajectoryLSTM(kind="map"), tmp_path / "m.pt")
    out = tmp_path / "o"
    p = subprocess.run([sys.executable, "-m", "sumo_ethics.cli", "run", str(URBAN), "--predictor", "attention",
                        "--predictor-weights", str(path), "--out", str(out)], capture_output=True, text=True,
                       cwd=ROOT, timeout=120)
    assert p.returncode == 2, p.stderr
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and "holds a 'map' model, expected 'attention'" in lines[0]
    assert "--predictor map," in lines[0]  # how to run it
    assert not (out / "summary.json").exists() and not (out / "steps.parquet").exists()
    # a file of the earlier default's kind, given without --predictor (the default is map now)
    cs = save_model(TrajectoryLSTM(kind="map_cslstm", nbr_frame="agent", modes=3), tmp_path / "cs.pt")
    p = subprocess.run([sys.executable, "-m", "sumo_ethics.cli", "run", str(URBAN), "--predictor-weights", str(cs),
                        "--out", str(tmp_path / "o2")], capture_output=True, text=True, cwd=ROOT, timeout=120)
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 2 and len(lines) == 1, p.stderr
    assert "holds a 'map_cslstm' model, expected 'map' (choose its kind: --predictor map_cslstm" in lines[0]


def _observation(n: int = 5) -> Observation:
    t = (np.arange(31) - 30) * 0.1
    x0 = np.arange(n) * 10.0
    speed = np.full(n, 10.0)
    hist = np.stack([x0[:, None] + speed[:, None] * t, np.zeros((n, 31))], -1)
    z = np.zeros(n)
    cur = AgentStates(tuple(f"v{i}" for i in range(n)), x0, z, z, speed, z, z + 4.5, z + 1.8, z + 1500,
                      np.full(n, int(RoadUserClass.CAR), dtype=np.int8))
    ego = AgentStates(("ego",), np.array([-20.0]), np.zeros(1), np.zeros(1), np.array([10.0]), np.zeros(1),
                      np.array([4.5]), np.array([1.8]), np.array([1500.0]), np.array([0], dtype=np.int8))
    return Observation(time=0.0, dt=0.1, history=hist, valid=np.ones((n, 31), dtype=bool), current=cur, ego=ego)


def test_default_shipped_model_loads_and_predicts():
    p = LSTMPredictor.default()
    assert p.kind == "map" and p.uses_map and p.model.nbr_frame == "agent" and p.model.modes == 3
    assert default_weights("map_cslstm").stat().st_size < 5e6 and default_weights("map").stat().st_size < 5e6
    obs = _observation()
    pred = p.predict(obs, 40, 0.1)  # no map source: histories only
    assert pred.mean.shape == (5, 40, 2) and pred.cov.shape == (5, 40, 2, 2)
    assert np.all(np.isfinite(pred.mean)) and np.all(np.linalg.eigvalsh(pred.cov) > 0)
    # cars driving +x at 10 m/s on a straight lane: 4 s ahead about 40 m further, not sideways
    graph = F.LaneGraph.build(["r_0"], [np.array([[-100.0, 0.0], [400.0, 0.0]])], [13.9], [()])

    def source(ids, person):
        n = len(ids)
        return graph, F.MapContext(np.zeros(n, dtype=np.int64), obs.current.x + 100.0, np.full(n, np.inf),
                                   np.zeros(n, dtype=np.int64))

    pm = LSTMPredictor.default(map_source=source).predict(obs, 40, 0.1)
    d = pm.mean[:, -1] - obs.current.xy
    assert np.all(np.abs(d[:, 0] - 40.0) < 8.0) and np.all(np.abs(d[:, 1]) < 1.0)


@pytest.mark.sumo
@pytest.mark.skipif(not URBAN.exists(), reason="bundled urban scenario missing")
def test_a_map_version_1_source_does_not_look_up_pedestrians_or_switch_times(monkeypatch):
    """Version 1 gives pedestrians no map rows and no version before 3 reads switch times: the
    run-time source for such a model does not ask SUMO for them (about six libsumo calls per
    pedestrian and step), and the model's map inputs are the same as from a version-3 source."""
    import libsumo

    from sumo_ethics.sim.lanes import SumoMapSource

    calls = {"person": 0, "switch": 0}
    lane_id, next_switch = libsumo.person.getLaneID, libsumo.trafficlight.getNextSwitch

    def count(key, fn):
        def wrapped(*a):
            calls[key] += 1
            return fn(*a)
        return wrapped

    monkeypatch.setattr(libsumo.person, "getLaneID", count("person", lane_id))
    monkeypatch.setattr(libsumo.trafficlight, "getNextSwitch", count("switch", next_switch))
    libsumo.start(["sumo", "-c", str(URBAN), "--no-step-log", "--no-warnings"])
    try:
        while libsumo.simulation.getTime() < 60.0 - 1e-9:
            libsumo.simulationStep()
        vehicles, persons = libsumo.vehicle.getIDList(), libsumo.person.getIDList()
        ids = tuple(vehicles) + tuple(persons)
        person = np.array([False] * len(vehicles) + [True] * len(persons))
        xy = np.array([libsumo.vehicle.getPosition(k) for k in vehicles] + [libsumo.person.getPosition(k) for k in persons])
        yaw, speed = np.zeros(len(ids)), np.ones(len(ids))
        graph, old = SumoMapSource(1)(ids, person)
        asked_old = dict(calls)
        _, new = SumoMapSource(3)(ids, person)
    finally:
        libsumo.close()
    assert len(persons) > 0 and asked_old == {"person": 0, "switch": 0}
    assert calls["person"] >= len(persons) and calls["switch"] > 0
    assert (old.lane[person] == -1).all() and (new.lane[person] >= 0).any() and np.isinf(old.tls_switch).all()
    assert np.isfinite(new.tls_switch[~person]).any()
    for name in ("lane", "lane_pos", "tls_dist", "tls_state"):  # the vehicles: the same
        np.testing.assert_array_equal(getattr(old, name)[~person], getattr(new, name)[~person])
    f_old, f_new = (F.map_features(graph, c, xy, yaw, speed, version=1) for c in (old, new))
    for key in f_old:
        np.testing.assert_array_equal(f_old[key], f_new[key])


# the bundled urban junction's program (networks/urban/urban.net.xml, light "C")
URBAN_PHASES = ("gGGgrrrrgGGgrrrrrGrG", "gGGgrrrrgGGgrrrrrrrr", "yyyyrrrryyyyrrrrrrrr",
                "rrrrgGGgrrrrgGGgGrGr", "rrrrgGGgrrrrgGGgrrrr", "rrrryyyyrrrryyyyrrrr")
URBAN_DURATIONS = (37, 5, 3, 37, 5, 3)


def test_time_a_link_keeps_its_colour_by_hand():
    from sumo_ethics.sim.lanes import time_to_change

    # 27 s left of phase 0: link 17 (a crossing) is green in phase 0 only -> 27 s; link 0 is
    # green ('g' and 'G' alike) in phases 0 and 1, yellow in 2 -> 27 + 5 = 32 s; link 16 is
    # red in phases 0-2, green in 3 -> 27 + 5 + 3 = 35 s
    holds = [time_to_change(URBAN_PHASES, URBAN_DURATIONS, 0, 27.0, k) for k in (17, 0, 16)]
    assert holds == [27.0, 32.0, 35.0]
    # from phase 5 (2 s left) link 0 turns green in phase 0 -> 2 s; link 4 (yellow) red next -> 2 s
    assert time_to_change(URBAN_PHASES, URBAN_DURATIONS, 5, 2.0, 0) == 2.0
    # a link that never changes, and a link the program does not have
    assert time_to_change(("GGr", "GGy"), (10, 3), 0, 4.0, 0) == float("inf")
    assert time_to_change(("GGr",), (10,), 0, 4.0, 7) == float("inf")


@pytest.mark.sumo
@pytest.mark.skipif(not URBAN.exists(), reason="bundled urban scenario missing")
def test_signal_clock_reads_the_running_light_and_its_colours_last_that_long():
    import libsumo

    from sumo_ethics.sim.lanes import SignalClock

    libsumo.start(["sumo", "-c", str(URBAN), "--no-step-log", "--no-warnings"])
    try:
        while libsumo.simulation.getTime() < 10.0 - 1e-9:
            libsumo.simulationStep()
        clock = SignalClock()
        # t = 10 s in phase 0 (37 s): 27 s left, as worked out above
        assert [clock.holds("C", k) for k in (17, 0, 16)] == pytest.approx([27.0, 32.0, 35.0])
        # and SUMO agrees: link 17 changes colour 27 s later, link 16 35 s later
        start, seen = libsumo.simulation.getTime(), {}
        while len(seen) < 2:
            libsumo.simulationStep()
            state = libsumo.trafficlight.getRedYellowGreenState("C")
            for k in (17, 16):
                if k not in seen and state[k] != URBAN_PHASES[0][k]:
                    seen[k] = libsumo.simulation.getTime() - start
    finally:
        libsumo.close()
    # (the new colour is read after the step that starts at the switch time: one 0.1 s step later)
    assert seen == pytest.approx({17: 27.1, 16: 35.1})


@pytest.mark.sumo
@pytest.mark.skipif(not URBAN.exists(), reason="bundled urban scenario missing")
def test_a_person_riding_a_car_gets_no_walking_context(tmp_path):
    """SUMO gives a riding person its vehicle's lane; that is not a walk."""
    import libsumo

    from sumo_ethics.sim.lanes import agent_context, lane_graph

    routes = tmp_path / "ride.rou.xml"
    routes.write_text('<routes><vType id="car" vClass="passenger"/><vType id="walker" vClass="pedestrian"/>'
                      '<trip id="v0" type="car" depart="triggered" from="W_in" to="E_out"/>'
                      '<person id="rider" depart="0"><ride from="W_in" to="E_out" lines="v0"/></person>'
                      '<person id="walker" type="walker" depart="0"><walk from="W_in" to="E_out"/></person></routes>')
    libsumo.start(["sumo", "-n", str(ROOT / "networks" / "urban" / "urban.net.xml"), "-r", str(routes),
                   "--no-step-log", "--no-warnings"])
    try:
        for _ in range(20):
            libsumo.simulationStep()
        graph = lane_graph()
        ctx = agent_context(graph, ["rider", "walker"], np.array([True, True]))
        assert libsumo.person.getVehicle("rider") == "v0" and libsumo.person.getLaneID("rider")  # on its car's lane
    finally:
        libsumo.close()
    assert ctx.lane[0] == -1 and ctx.next_lane[0] == -1 and not np.isfinite(ctx.tls_dist[0])
    assert ctx.lane[1] >= 0 and ctx.person.all()


@pytest.mark.sumo
@pytest.mark.skipif(not URBAN.exists(), reason="bundled urban scenario missing")
def test_a_person_waiting_for_a_ride_stands_on_the_pavement_of_its_edge(tmp_path):
    """SUMO gives a person waiting for a bus no lane; its context is its edge's sidewalk (lane 0
    of W_in, the only one of its two lanes that allows pedestrians), at its stop's position."""
    import libsumo

    from sumo_ethics.sim.lanes import agent_context, lane_graph

    (tmp_path / "stops.add.xml").write_text('<additional><busStop id="bs" lane="W_in_1" startPos="60" endPos="80"/>'
                                            '<busStop id="bs2" lane="E_out_1" startPos="20" endPos="40"/></additional>')
    routes = tmp_path / "wait.rou.xml"
    routes.write_text('<routes><vType id="walker" vClass="pedestrian"/>'
                      # waits where it departs, 50 m into W_in, for a line that never comes
                      '<person id="waiter" type="walker" depart="0" departPos="50">'
                      '<ride from="W_in" to="E_out" lines="nobus"/></person>'
                      # walks from 20 m to the stop's end (80 m) at ~1 m/s, then waits there
                      '<person id="walker" type="walker" depart="0" departPos="20"><walk from="W_in" busStop="bs"/>'
                      '<ride busStop="bs2" lines="nobus"/></person></routes>')
    libsumo.start(["sumo", "-n", str(ROOT / "networks" / "urban" / "urban.net.xml"), "-r", str(routes),
                   "-a", str(tmp_path / "stops.add.xml"), "--no-step-log", "--no-warnings"])
    try:
        for _ in range(5):
            libsumo.simulationStep()
        graph = lane_graph()
        walking = agent_context(graph, ["waiter", "walker"], np.array([True, True]))
        for _ in range(115):
            libsumo.simulationStep()
        both_wait = agent_context(graph, ["waiter", "walker"], np.array([True, True]))
        raw = [libsumo.person.getLaneID(k) for k in ("waiter", "walker")]
    finally:
        libsumo.close()
    sidewalk = graph.index["W_in_0"]
    assert raw == ["", ""]  # what SUMO says of both while they wait
    assert walking.lane.tolist() == [sidewalk, sidewalk] and walking.lane_pos[0] == pytest.approx(50.0)
    assert both_wait.lane.tolist() == [sidewalk, sidewalk]
    assert both_wait.lane_pos.tolist() == pytest.approx([50.0, 80.0], abs=0.5)  # where each waits along W_in
    assert both_wait.next_lane.tolist() == [-1, -1] and not np.isfinite(both_wait.tls_dist).any()


@pytest.mark.sumo
@pytest.mark.skipif(not URBAN.exists(), reason="bundled urban scenario missing")
def test_dataset_carries_map_context_from_sumo(tmp_path):
    from sumo_ethics.predict.samples import MANOEUVRES, load_samples
    from sumo_ethics.recording.build import build_dataset

    out = build_dataset([URBAN], [1, 2, 3], tmp_path / "ds", sim_seconds=60.0, anchor_every=1.0)
    s = load_samples(out)
    veh = s["tgt_group"] == F.GROUP_VEHICLE
    ped = s["tgt_group"] == F.GROUP_PEDESTRIAN
    # vehicles on lanes: the ahead row exists and starts at the car itself (its lane's centre line)
    on = veh & s["map_valid"][:, 0]
    assert on.mean() > 0.9 * veh.mean()
    assert np.median(np.hypot(*s["map_pts"][on, 0, 0].T)) < 0.5
    # pedestrians (map version 2): every one on a walking lane has a row, and the urban junction's
    # crossings are signalised: those standing at them wait at a red light
    assert s["map_valid"][ped, 0].mean() > 0.9
    assert (s["map_scalar"][ped, 0] == 1).all() and (s["map_scalar"][ped, 6] == 0).all()
    moving = ped & (s["tgt_speed"] > 0.8) & s["map_valid"][:, 0]
    ahead = s["map_pts"][moving, 0, -1] - s["map_pts"][moving, 0, 0]
    assert (ahead[:, 0] > 0).mean() > 0.9  # the row runs the way they walk
    standing = ped & (s["tgt_speed"] < 0.1)
    assert standing.any() and (s["map_scalar"][standing, 5] == 1).mean() > 0.5
    # (map version 3) how long their red lasts: the junction's crossings (links 16-19 of
    # URBAN_PHASES) are red until t = 45 s (links 16, 18) or 90 s (17, 19) in the first cycle,
    # so every pedestrian row at red has time + tls_switch at one of those two
    import pandas as pd

    df = pd.read_parquet(out / "trajectories.parquet", columns=["time", "cls", "lane", "tls_state", "tls_switch"])
    red = df[(df["cls"] == int(RoadUserClass.PEDESTRIAN)) & (df["lane"] >= 0) & (df["tls_state"] == 3)]
    assert len(red) > 20
    ends = (red["time"] + red["tls_switch"]).to_numpy()
    assert np.all(np.minimum(np.abs(ends - 45.0), np.abs(ends - 90.0)) < 1e-3)
    # the urban scenario has traffic lights: some vehicles see one ahead, some a red one
    assert s["map_scalar"][on, 1].mean() > 0.2 and s["map_scalar"][on, 5].any()
    labels = set(np.unique(s["manoeuvre"][veh]).tolist())
    assert {MANOEUVRES.index("straight"), MANOEUVRES.index("turn")} <= labels
    assert (s["manoeuvre"][ped] == -1).all()
    # (map version 4) the blinkers: nearly every vehicle that turns within the 4 s shows one
    # (97.6 % on this data) and blinking vehicles turn more often than others
    blink = veh & (s["map_scalar"][:, 8:].sum(axis=1) > 0)
    turn = veh & (s["manoeuvre"] == MANOEUVRES.index("turn"))
    assert (blink & turn).sum() > 0.9 * turn.sum() and (blink & turn).sum() / blink.sum() > turn.sum() / veh.sum()
    # and the lane after a walking area: most walkers head for one (their next lane, no row of its
    # own), and nearly every one who walks on within the run steps onto that lane next (SUMO may
    # route a pedestrian waiting there over the other crossing of a diagonal walk)
    assert s["map_valid"][ped, F.MAP_ROW_AFTER].mean() > 0.5
    df = pd.read_parquet(out / "trajectories.parquet", columns=["run_id", "agent_id", "time", "lane", "next_lane",
                                                                "after_lane"])
    walks = {k: g.sort_values("time")[["time", "lane"]].to_numpy() for k, g in df[df["lane"] >= 0].groupby(["run_id", "agent_id"])}
    scored = right = 0
    for run, aid, t, area, after in df.loc[df["after_lane"] >= 0, ["run_id", "agent_id", "time", "next_lane",
                                                                    "after_lane"]].itertuples(index=False):
        later = walks[run, aid]
        later = later[later[:, 0] > t, 1]
        reached = np.flatnonzero(later == area)
        beyond = later[reached[0]:][later[reached[0]:] != area] if len(reached) else []
        if len(beyond):
            scored += 1
            right += beyond[0] == after
    assert scored >= 10 and right >= 0.9 * scored


SUITE = ROOT / "scenarios" / "suite"


@pytest.mark.sumo
@pytest.mark.skipif(not (SUITE / "s0002").is_dir(), reason="bundled suite missing")
def test_suite_runs_bring_hazard_actors_into_the_data(tmp_path):
    """A suite scenario recorded with its hazards: the hazard actor is in the trajectories, and
    its samples are labelled 'hazard' with a future observed for at least 1 s. The step the actor
    is inserted in, SUMO gives it no position yet (-2^30 m): that row used to be recorded, and the
    actor's first samples had a 1.5e9 m jump in their history."""
    from sumo_ethics.predict.samples import HAZARD_MIN_FUTURE, MANOEUVRES, load_samples
    from sumo_ethics.recording.build import build_dataset

    out = build_dataset([], [], tmp_path / "ds", suite=[SUITE / "s0002"], suite_anchor_every=0.4)
    traj = __import__("pandas").read_parquet(out / "trajectories.parquet")
    assert traj["agent_id"].str.startswith("hazard_").any()
    # every recorded position is on this network (its junctions lie within 1 km of the origin)
    assert traj[["x", "y"]].abs().to_numpy().max() < 1000.0 and (traj["speed"] >= 0).all()
    s = load_samples(out)
    assert np.abs(s["tgt_hist"]).max() < 1000.0 and np.abs(s["nbr_hist"]).max(initial=0.0) < 1000.0
    hz = s["manoeuvre"] == MANOEUVRES.index("hazard")
    assert hz.any()
    assert s["fut_valid"][hz][:, :HAZARD_MIN_FUTURE].all()
    assert s["fut_valid"][~hz].all()


@pytest.mark.sumo
@pytest.mark.skipif(not URBAN.exists(), reason="bundled urban scenario missing")
def test_runs_with_the_default_map_predictor_are_byte_identical_for_one_seed(tmp_path):
    """The default planner (map predictor, lanes and signals read from SUMO each step): the
    same seed gives the same step table, byte for byte."""
    outs = []
    for k in range(2):
        out = tmp_path / f"r{k}"
        p = subprocess.run([sys.executable, "-m", "sumo_ethics.cli", "run", str(URBAN), "--end", "22", "--ego-depart",
                            "15", "--seed", "3", "--quiet", "--out", str(out)], capture_output=True, text=True,
                           cwd=ROOT, timeout=300)
        assert p.returncode == 0, p.stderr
        outs.append(out)
    assert '"predictor": "map"' in (outs[0] / "config.json").read_text()
    used = __import__("json").loads((outs[0] / "summary.json").read_text())["predictor"]
    assert used["kind"] == "map" and used["weights"] == str(default_weights("map"))
    assert (outs[0] / "steps.parquet").read_bytes() == (outs[1] / "steps.parquet").read_bytes()


def _queue_at_light(state: int, switch: float = 20.0) -> tuple[Observation, object]:
    """Four cars standing for 3 s in a queue 5, 12, 19 and 26 m before a stop line (x = 0) whose
    light shows ``state`` (features.TLS_CODES: 1 green, 3 red) for ``switch`` more seconds, and
    the map source of that lane."""
    x0 = np.array([-5.0, -12.0, -19.0, -26.0])
    n = len(x0)
    hist = np.stack([np.repeat(x0[:, None], 31, 1), np.zeros((n, 31))], -1)
    z = np.zeros(n)
    cur = AgentStates(tuple(f"v{i}" for i in range(n)), x0, z, z, z, z, z + 4.5, z + 1.8, z + 1500,
                      np.full(n, int(RoadUserClass.CAR), dtype=np.int8))
    ego = AgentStates(("ego",), np.array([-60.0]), np.zeros(1), np.zeros(1), np.array([10.0]), np.zeros(1),
                      np.array([4.5]), np.array([1.8]), np.array([1500.0]), np.array([0], dtype=np.int8))
    obs = Observation(time=0.0, dt=0.1, history=hist, valid=np.ones((n, 31), dtype=bool), current=cur, ego=ego)
    graph = F.LaneGraph.build(["r_0"], [np.array([[-200.0, 0.0], [200.0, 0.0]])], [13.9], [()])

    def source(ids, person):
        k = len(ids)
        return graph, F.MapContext(np.zeros(k, dtype=np.int64), x0 + 200.0, -x0, np.full(k, state, dtype=np.int64),
                                   tls_switch=np.full(k, switch))

    return obs, source


def _queue_modes(state: int, switch: float = 20.0) -> tuple[np.ndarray, np.ndarray]:
    """The shipped default on :func:`_queue_at_light`: how far each car moves along the lane in
    4 s in each mode (4 cars, 3 modes) [m], and the modes' weights (4, 3), most likely first."""
    obs, source = _queue_at_light(state, switch)
    p = LSTMPredictor.default(map_source=source)
    assert p.model.modes == 3 and p.model.map_version == 5
    mean, _, w = p.mode_outputs(obs)
    return mean[:, :, -1, 0] - obs.current.x[:, None], w


def test_shipped_default_keeps_a_queue_at_a_red_light_standing_until_the_light_changes():
    # the single-Gaussian model of earlier versions moved the first car 0.83 m in 4 s at red (the
    # average of "stays" and "pulls away"); knowing how long the red holds (map version 3), the
    # default keeps the queue standing in every mode while it holds and sets it off as it ends
    moved, w = _queue_modes(3, switch=20.0)
    # red for 20 s more: nobody leaves in 4 s. The shipped file's most likely mode (weight 0.92-0.98)
    # moves 1 cm at most; its other modes drift up to 0.55 m either way, which by their weights
    # (0.02-0.08) is 2 cm at most
    assert np.all(w[:, 0] > 0.9) and np.all(np.abs(moved[:, 0]) < 0.05)
    assert np.all((w * np.abs(moved)).sum(axis=1) < 0.1)
    soon, w_soon = _queue_modes(3, switch=1.0)  # red for 1 s more
    # the first car moves off in its most likely mode (8.1 m in 4 s; the shipped file keeps a stay
    # mode for it beside that, weight 0.44), and the modes in which it leaves weigh more than half ...
    assert soon[0, 0] > 1.0 and (w_soon[0] * (soon[0] > 1.0)).sum() > 0.5
    assert np.all(np.diff(soon[:, 0]) < 0)  # ... and the queue follows in order, each car less far
    assert np.all(w_soon[:, 0] < w[:, 0])  # the "stays" mode loses weight for every car
    green, w_g = _queue_modes(1, switch=20.0)
    assert np.all(green[:, 1:] > 1.0)  # at green the other modes pull away
    assert 1.0 - w_g[0, 0] > 1.0 - w[0, 0]  # and the first car is likelier to go than at red


def test_fast_file_has_five_decoder_steps_and_keeps_a_red_queue():
    """models/superseded/map_cslstm_fast.pt: the default's recipe with a 5-step decoder (each step emits 0.8 s).
    Cars on a straight lane go about 40 m in 4 s; a queue at a red that holds 20 s more stays in its
    most likely mode, and at green the other modes pull away. Unlike the default, its most likely
    mode still stays 1 s before the red ends (docs/predictor_seeds.md, "Fewer decoder steps")."""
    path = Path(__file__).resolve().parents[2] / "models" / "superseded" / "map_cslstm_fast.pt"
    assert path.stat().st_size < 5e6
    fast = LSTMPredictor.from_file(path, kind="map_cslstm")
    assert (fast.model.dec_steps, fast.model.modes, fast.model.map_version) == (5, 3, 4)
    obs = _observation()
    graph = F.LaneGraph.build(["r_0"], [np.array([[-100.0, 0.0], [400.0, 0.0]])], [13.9], [()])

    def lane(ids, person):
        n = len(ids)
        return graph, F.MapContext(np.zeros(n, dtype=np.int64), obs.current.x + 100.0, np.full(n, np.inf),
                                   np.zeros(n, dtype=np.int64))

    fast.map_source = lane
    d = fast.predict(obs, 40, 0.1).mean[:, -1] - obs.current.xy
    assert np.all(np.abs(d[:, 0] - 40.0) < 8.0) and np.all(np.abs(d[:, 1]) < 1.0)
    moved = {}
    for state, switch in ((3, 20.0), (1, 20.0), (3, 1.0)):
        queue, source = _queue_at_light(state, switch)
        mean, _, w = LSTMPredictor.from_file(path, map_source=source).mode_outputs(queue)
        moved[state, switch] = (mean[:, :, -1, 0] - queue.current.x[:, None], w)
    red, w_red = moved[3, 20.0]
    assert np.all(w_red[:, 0] > 0.9) and np.all(np.abs(red[:, 0]) < 0.1)  # the queue stays (0.03 m at most)
    green, _ = moved[1, 20.0]
    assert np.all(green[:, 1:] > 1.0)
    soon, _ = moved[3, 1.0]
    assert np.all(np.abs(soon[:, 0]) < 0.1) and np.all(soon[0, 1:] > 1.0)  # stays; only the other modes go


@pytest.mark.parametrize(("y1", "left_of_0", "right_of_0"), [(3.2, 1, -1), (-3.2, -1, 1)])
def test_lane_neighbours_by_position_on_right_and_left_hand_networks(y1, left_of_0, right_of_0):
    """Two lanes of edge e heading +x: e_1 at y = +3.2 (SUMO's right-hand numbering, from the right:
    e_1 is e_0's left neighbour) or at y = -3.2 (netconvert --lefthand numbers from the left: e_1 is
    e_0's right neighbour)."""
    shapes = [np.array([[0.0, 0.0], [100.0, 0.0]]), np.array([[0.0, y1], [100.0, y1]])]
    g = F.LaneGraph.build(["e_0", "e_1"], shapes, [13.9, 13.9], [(), ()])
    assert (int(g.left[0]), int(g.right[0])) == (left_of_0, right_of_0)
    assert (int(g.left[1]), int(g.right[1])) == ((-1, 0) if y1 > 0 else (0, -1))  # e_0 on e_1's other side
