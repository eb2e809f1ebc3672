"""The curvature check judges what the ego adds to the road, not the road itself.

Hand-worked numbers: the ego's limits are the defaults, max_curvature c = 0.2 1/m and
max_lat_accel 4 m/s^2; ROAD_CURVATURE_TOL = 0.05 1/m. A right bend of radius 2 m has
curvature -0.5 1/m (left turns positive): a candidate on it may curve between -0.55 and +0.2,
and its lateral acceleration v^2 |k| reaches 4 m/s^2 at v = sqrt(4 / 0.5) = sqrt(8) = 2.83 m/s
(2.8 m/s: 3.92 m/s^2, feasible; 2.9 m/s: 4.205 m/s^2, not).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import pytest

from sumo_ethics.config import EgoVehicle
from sumo_ethics.geometry import Polyline
from sumo_ethics.plan.ethical import brake_candidates, concat
from sumo_ethics.plan.feasibility import ROAD_CURVATURE_TOL, check
from sumo_ethics.plan.sampling import FrenetState, SamplingConfig, quintic_coeffs, sample
from sumo_ethics.types import Candidates

R = 2.0  # m, radius of the test bend
# 10 m straight along +x, a right quarter circle of radius 2 m (30 segments), 10 m straight down
_A = np.linspace(0.0, math.pi / 2, 31)
ARC = Polyline.from_points(np.vstack([
    np.stack([np.linspace(-10.0, 0.0, 11), np.zeros(11)], -1)[:-1],
    np.stack([R * np.sin(_A), -R + R * np.cos(_A)], -1),
    np.stack([np.full(10, R), -R - np.linspace(1.0, 10.0, 10)], -1),
]))
ARC_START = 10.0  # m, arc length where the bend begins


@dataclass(frozen=True)
class Road:
    path: Polyline
    left: np.ndarray
    right: np.ndarray


WIDE = Road(ARC, np.full(len(ARC.s), 3.0), np.full(len(ARC.s), -3.0))


def hand_made(k: list[float], road: list[float] | None, v: list[float]) -> Candidates:
    """One candidate per entry, 2 steps of 0.1 s, constant curvature k [1/m], road curvature and speed."""
    K = len(k)
    z = np.zeros((K, 2))
    col = lambda a: np.asarray(a, dtype=float)[:, None] + z  # noqa: E731
    return Candidates(dt=0.1, x=z, y=z, yaw=z, speed=col(v), accel=z, curvature=col(k), s=z, d=z,
                      horizon=np.full(K, 0.2), valid=np.ones((K, 2), dtype=bool),
                      road_curvature=None if road is None else col(road))


def test_tolerance_is_the_documented_number():
    assert ROAD_CURVATURE_TOL == 0.05  # the numbers below are worked with it


def test_rule_by_hand():
    rows = [  # (k, road, v): expected curvature_ok, lat_accel_ok
        (-0.50, -0.5, 2.8),   # 0: on the bend, 2.8^2 x 0.5 = 3.92 <= 4
        (-0.54, -0.5, 1.0),   # 1: adds 0.04 <= 0.05
        (-0.56, -0.5, 1.0),   # 2: adds 0.06 > 0.05
        (-0.30, -0.5, 1.0),   # 3: wider than the bend
        (+0.25, -0.5, 1.0),   # 4: against the bend beyond c = 0.2
        (+0.20, -0.5, 1.0),   # 5: against the bend within c
        (+0.22, +0.18, 1.0),  # 6: the road is within c: no allowance
        (-0.50, -0.5, 2.9),   # 7: on the bend, 2.9^2 x 0.5 = 4.205 > 4
        (+0.50, +0.5, 2.8),   # 8: the same bend to the left
        (+0.56, +0.5, 1.0),   # 9: adds 0.06 > 0.05 to the left bend
    ]
    c = hand_made(*(list(col) for col in zip(*rows)))
    f = check(c, WIDE, EgoVehicle(), speed_limit_factor=None)
    np.testing.assert_array_equal(f.curvature_ok, [1, 1, 0, 1, 0, 1, 0, 1, 1, 0])
    np.testing.assert_array_equal(f.lat_accel_ok, [1, 1, 1, 1, 1, 1, 1, 0, 1, 1])
    np.testing.assert_array_equal(f.beyond_limit, [1, 1, 1, 1, 1, 0, 1, 1, 1, 1])
    assert f.feasible[0] and not f.feasible[7] and f.feasible[8]
    # without the road's curvature the plain limit applies: every candidate beyond 0.2 fails
    plain = check(replace(c, road_curvature=None), WIDE, EgoVehicle(), speed_limit_factor=None)
    np.testing.assert_array_equal(plain.curvature_ok, [0, 0, 0, 0, 0, 1, 0, 0, 0, 0])


def test_rule_checks_only_valid_steps():
    c = hand_made([-0.56], [-0.5], [1.0])  # adds 0.06 to the bend at both steps
    one = replace(c, valid=np.array([[True, False]]))
    none = replace(c, valid=np.zeros((1, 2), dtype=bool))
    assert not check(one, WIDE, EgoVehicle()).curvature_ok[0]
    f = check(none, WIDE, EgoVehicle())
    assert f.curvature_ok[0] and not f.beyond_limit[0]


def through_the_bend(v: float, n_offsets: int = 3) -> Candidates:
    """Candidates at constant speed v [m/s] from 3 m before the bend, 4 s long (through it at
    1 m/s and up), end offsets -1, 0, +1 m (right, on the path, left)."""
    cfg = SamplingConfig(horizons=(4.0,), dt=0.1, n_speeds=1, n_offsets=n_offsets, max_offset=1.0)
    return sample(ARC, FrenetState.at_speed(ARC, ARC_START - 3.0, 0.0, v), cfg, v)


@pytest.mark.parametrize("v", [1.0, 2.8, 5.0, 8.0])  # the low-speed d(s) and the d(t) profiles
def test_on_the_path_road_curvature_is_the_candidates_own(v):
    c = through_the_bend(v)
    on = 1  # d_end = 0
    assert np.abs(c.d[on]).max() == 0.0
    np.testing.assert_array_equal(c.road_curvature[on], c.curvature[on])  # bit for bit
    assert c.curvature[on].min() == pytest.approx(-1.0 / R, rel=0.02)  # the bend, turning right
    # the road's curvature depends on s only: beside the path it is the same along the same s
    np.testing.assert_allclose(c.road_curvature[0], c.road_curvature[on])


def test_the_ego_follows_a_bend_tighter_than_its_limit_at_a_lateral_acceleration_speed():
    veh = EgoVehicle()
    v_bend = math.sqrt(veh.max_lat_accel * R)  # 2.83 m/s
    slow, fast = through_the_bend(2.8), through_the_bend(2.9)
    assert 2.8 < v_bend < 2.9
    f_slow = check(slow, WIDE, veh, speed_limit_factor=None)
    f_fast = check(fast, WIDE, veh, speed_limit_factor=None)
    on = 1
    assert f_slow.feasible[on] and f_slow.beyond_limit[on]
    assert np.abs(slow.speed[on] ** 2 * slow.curvature[on]).max() == pytest.approx(2.8**2 / R, rel=0.01)
    # 2.9 m/s: the curvature is still acceptable, the lateral acceleration is not
    assert f_fast.curvature_ok[on] and not f_fast.lat_accel_ok[on] and not f_fast.feasible[on]
    # the old rule (curvature against the vehicle's limit alone) rejected the road itself
    assert not check(replace(slow, road_curvature=None), WIDE, veh, speed_limit_factor=None).curvature_ok[on]


def test_a_candidate_adding_curvature_to_the_bend_is_rejected():
    c = through_the_bend(2.8)
    f = check(c, WIDE, EgoVehicle(), speed_limit_factor=None)
    inside = 0  # moves 1 m to the right, into the inside of the right bend, while in it
    added = c.curvature[inside] - c.road_curvature[inside]
    assert added.min() < -ROAD_CURVATURE_TOL and c.curvature[inside].min() < -1.0 / R - ROAD_CURVATURE_TOL
    assert not f.curvature_ok[inside]
    assert f.speed_ok[inside] and f.accel_ok[inside] and f.lat_accel_ok[inside]  # curvature alone rejects it


def test_brake_candidates_follow_the_road_and_concat_keeps_it():
    st = FrenetState(s=ARC_START + 0.5, d=0.0, s_dot=2.0)
    b = brake_candidates(ARC, st, 40, 0.1, np.array([3.0, 8.0]))
    np.testing.assert_array_equal(b.road_curvature, b.curvature)
    assert b.curvature.min() < -0.4
    assert check(b, WIDE, EgoVehicle()).curvature_ok.all()
    s = through_the_bend(1.0)
    both = concat(s, b)
    np.testing.assert_array_equal(both.road_curvature, np.concatenate([s.road_curvature, b.road_curvature]))
    np.testing.assert_array_equal(both.take([4]).road_curvature, b.road_curvature[1:])
    # a source without road curvature counts as a straight road (the plain limit) after concat
    mixed = concat(replace(s, road_curvature=None), b)
    np.testing.assert_array_equal(mixed.road_curvature[:3], 0.0)
    assert concat(replace(s, road_curvature=None), replace(b, road_curvature=None)).road_curvature is None


def test_when_no_candidate_keeps_the_lateral_limit_the_least_excess_ones_remain():
    # on the bend of radius 2 m (k = -0.5) at 3.0, 3.1 and 3.4 m/s: 4.5, 4.805 and 5.78 m/s^2, all over
    # the limit of 4. With the slack of 0.25 the relaxed limit is 4.5 + 0.25 = 4.75: only the first
    # remains. The fourth adds 0.06 1/m to the bend (curvature fails): never chosen, even at 1 m/s.
    c = hand_made([-0.5, -0.5, -0.5, -0.56], [-0.5] * 4, [3.0, 3.1, 3.4, 1.0])
    f = check(c, WIDE, EgoVehicle(), speed_limit_factor=None)
    assert not f.feasible[:3].any() and not f.feasible[3]
    np.testing.assert_allclose(f.lat_accel_peak, [4.5, 4.805, 5.78, 0.56], rtol=1e-12)
    ok, limit = f.least_lateral()
    assert limit == pytest.approx(4.75) and ok.tolist() == [True, False, False, False]
    ok, limit = f.least_lateral(tol=0.4)  # 4.9: the second one too
    assert ok.tolist() == [True, True, False, False]
    none = check(hand_made([-0.56], [-0.5], [3.0]), WIDE, EgoVehicle(), speed_limit_factor=None)
    ok, limit = none.least_lateral()
    assert not ok.any() and math.isnan(limit)  # nothing keeps the other limits: the emergency brake


def test_a_straight_brake_from_a_lane_change_lets_the_sideways_motion_settle():
    """At 10 m/s on a straight road while moving left at 1 m/s (a lane change under way: slope
    d' = 0.1), braking at 3 m/s^2 covers 10 - 1.5 = 8.5 m in the first second; over that arc the slope
    settles to 0 along the quintic with d(0) = 0.5, d'(0) = 0.1, d''(0) = 0 and d(8.5) = 0.5 + 0.1 x 8.5 / 2
    = 0.925, d'(8.5) = d''(8.5) = 0 (evaluated here with numpy's polynomials). So the heading starts at the
    ego's, atan(0.1), instead of snapping onto the road's within the first step (9.5 m/s^2 sideways),
    and the brake stays within the lateral limit of 4."""
    path = Polyline.from_points(np.array([[0.0, 0.0], [500.0, 0.0]]))
    road = type("R", (), {"path": path, "left": np.full(2, 5.0), "right": np.full(2, -5.0)})()
    moving = brake_candidates(path, FrenetState(s=20.0, d=0.5, s_dot=10.0, d_dot=1.0), 40, 0.1, np.array([3.0]))
    sigma = moving.s[0] - 20.0
    q = np.polynomial.Polynomial(quintic_coeffs(0.5, 0.1, 0.0, 0.925, 8.5))
    inside = sigma < 8.5
    np.testing.assert_allclose(moving.d[0, inside], q(sigma[inside]), atol=1e-12)
    np.testing.assert_allclose(moving.d[0, ~inside], 0.925, atol=1e-12)
    np.testing.assert_allclose(moving.yaw[0, inside], np.arctan(q.deriv()(sigma[inside])), atol=1e-12)
    assert moving.y[0, -1] == pytest.approx(0.925, abs=1e-12) and moving.yaw[0, -1] == 0.0
    f = check(moving, road, EgoVehicle(max_lat_accel=4.0), speed_limit_factor=None)
    assert f.feasible[0] and 0.5 < f.lat_accel_peak[0] < 4.0
    # the first step turns by what the quintic turns over 0.985 m, not by atan(0.1)
    assert abs(moving.yaw[0, 0] - math.atan(0.1)) < 0.01
    still = brake_candidates(path, FrenetState(s=20.0, d=0.5, s_dot=10.0), 40, 0.1, np.array([3.0]))
    assert (still.curvature == 0.0).all() and (still.d == 0.5).all()
    assert check(still, road, EgoVehicle(), speed_limit_factor=None).feasible[0]


def test_a_brake_that_stops_sooner_than_it_could_steer_stands_at_an_angle():
    """At 0.3 m/s moving sideways at 0.12 m/s (slope 0.4) braking at 3 m/s^2 stops within 0.1 s, 1.5 cm on:
    settling the slope over that would turn at 0.4 x 1.875 / 0.015 = 50 1/m. The slope settles over
    2 x 0.4 / 0.2 = 4 m instead (the ego's limit 0.2 1/m), so the brake stops at nearly the ego's angle to
    the path and stays within the curvature limit: a candidate the check keeps."""
    path = Polyline.from_points(np.array([[0.0, 0.0], [500.0, 0.0]]))
    road = type("R", (), {"path": path, "left": np.full(2, 5.0), "right": np.full(2, -5.0)})()
    slow = brake_candidates(path, FrenetState(s=20.0, d=0.5, s_dot=0.3, d_dot=0.12), 40, 0.1, np.array([3.0]),
                            max_curvature=0.2)
    assert slow.s[0, -1] - 20.0 == pytest.approx(0.3**2 / 6.0, rel=1e-12)
    assert abs(slow.yaw[0, -1] - math.atan(0.4)) < 0.01  # still at (nearly) the ego's angle when it stands
    assert np.abs(slow.curvature).max() <= 0.2 and check(slow, road, EgoVehicle(), speed_limit_factor=None).feasible[0]
