"""Candidate sampling (quartic/quintic Frenet profiles) and feasibility checks.

Numbers are hand-checkable. On a straight path along +x from the origin, Frenet (s, d) is
Cartesian (x, y). Grid used below: v_max = 14 with 15 speeds gives end speeds 0, 1, ..., 14;
23 offsets over +/- 3.5 m give d_end = -3.5, -3.18, ..., 0 (index 11), ..., 3.5 (index 22).
Candidate k = (i_T * 15 + i_v) * 23 + i_d.

Timing (python -m sumo_ethics.plan.sampling, default 1035 x 40 grid, one core): about
0.7 ms median on the development machine (numba kernels; 1.9 ms in numpy before).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from sumo_ethics.config import EgoVehicle
from sumo_ethics.errors import ConfigError
from sumo_ethics.geometry import Polyline
from sumo_ethics.plan.feasibility import check
from sumo_ethics.plan.sampling import FrenetState, SamplingConfig, quartic_coeffs, quintic_coeffs, sample

STRAIGHT = Polyline.from_points(np.array([[0.0, 0.0], [1000.0, 0.0]]))
CFG = SamplingConfig()
NV, ND = CFG.n_speeds, CFG.n_offsets


def k_of(i_t: int, v_end: int, i_d: int) -> int:
    """Index of the candidate with horizon index i_t, end speed v_end [m/s] (grid 0..14), offset index i_d."""
    return (i_t * NV + v_end) * ND + i_d


def run(v0: float, a0: float = 0.0, d0: float = 0.0, path: Polyline = STRAIGHT, cfg: SamplingConfig = CFG, **kw):
    return sample(path, FrenetState(s=10.0, d=d0, s_dot=v0, s_ddot=a0), cfg, 14.0, **kw)


@dataclass(frozen=True)
class Road:
    path: Polyline
    left: np.ndarray
    right: np.ndarray


def road(half: float, path: Polyline = STRAIGHT) -> Road:
    m = len(path.s)
    return Road(path, np.full(m, half), np.full(m, -half))


# --------------------------------------------------------------------------- grid
def test_default_grid_size_and_shapes():
    c = run(10.0)
    assert len(c) == 3 * 15 * 23 == 1035 >= 4 * 225
    for name in ("x", "y", "yaw", "speed", "accel", "curvature", "s", "d", "valid"):
        assert getattr(c, name).shape == (1035, 40), name
    assert c.dt == 0.1 and c.valid.all()
    np.testing.assert_array_equal(c.horizon, np.repeat([2.0, 3.0, 4.0], 15 * 23))
    assert all(np.isfinite(getattr(c, n)).all() for n in ("x", "y", "yaw", "speed", "accel", "curvature"))


def test_straight_constant_speed_candidate_is_exact():
    c = run(10.0)
    t = 0.1 * np.arange(1, 41)
    for i_t in range(3):
        k = k_of(i_t, 10, 11)  # v_end = v0 = 10, d_end = d0 = 0
        np.testing.assert_allclose(c.x[k], 10.0 + 10.0 * t, atol=1e-9)
        np.testing.assert_allclose(c.y[k], 0.0, atol=1e-12)
        np.testing.assert_allclose(c.yaw[k], 0.0, atol=1e-12)
        np.testing.assert_allclose(c.speed[k], 10.0, atol=1e-9)
        np.testing.assert_allclose(c.accel[k], 0.0, atol=1e-9)
        np.testing.assert_allclose(c.curvature[k], 0.0, atol=1e-9)


def test_quartic_and_quintic_boundary_conditions():
    T = 3.0
    c = quartic_coeffs(5.0, 1.5, 12.0, T)
    v = np.polynomial.polynomial.Polynomial(c)
    assert v(0.0) == 0.0
    assert v.deriv(1)(0.0) == pytest.approx(5.0) and v.deriv(2)(0.0) == pytest.approx(1.5)
    assert v.deriv(1)(T) == pytest.approx(12.0, abs=1e-9) and v.deriv(2)(T) == pytest.approx(0.0, abs=1e-9)
    q = np.polynomial.polynomial.Polynomial(quintic_coeffs(0.5, -0.2, 0.3, 2.0, 4.0))
    assert (q(0.0), q.deriv(1)(0.0), q.deriv(2)(0.0)) == pytest.approx((0.5, -0.2, 0.3))
    assert (q(4.0), q.deriv(1)(4.0), q.deriv(2)(4.0)) == pytest.approx((2.0, 0.0, 0.0), abs=1e-9)


def test_sampled_speed_profile_meets_both_ends():
    c = run(5.0, a0=1.0)
    for i_t, T in enumerate((2.0, 3.0, 4.0)):
        n = round(T / 0.1) - 1  # step index at t = T
        for v_end in (0, 7, 12):
            k = k_of(i_t, v_end, 11)
            assert c.speed[k, n] == pytest.approx(v_end, abs=1e-9)
            assert c.accel[k, n] == pytest.approx(0.0, abs=1e-9)
            # past the horizon: constant end speed, straight on, still valid
            np.testing.assert_allclose(c.speed[k, n:], v_end, atol=1e-9)
            np.testing.assert_allclose(np.diff(c.x[k, n:]), 0.1 * v_end, atol=1e-9)
            assert c.valid[k].all() and c.horizon[k] == T
            # start: s(0.1) = s0 + v0 dt + a0 dt^2 / 2 + O(dt^3); speed(0.1) = v0 + a0 dt + O(dt^2)
            assert c.s[k, 0] == pytest.approx(10.0 + 0.5 + 0.005, abs=2e-3)
            assert c.speed[k, 0] == pytest.approx(5.0 + 0.1, abs=0.05)


def test_lateral_move_peak_acceleration_matches_quintic():
    c = run(10.0)
    k = k_of(2, 10, 22)  # 4 s horizon, keep 10 m/s, move 0 -> 3.5 m
    assert c.d[k, 39] == pytest.approx(3.5, abs=1e-9)
    y = np.concatenate([[0.0], c.y[k]])  # y = d on this path; y(0) = d0 = 0
    d_dd = np.diff(y, 2) / 0.1**2
    expected = 10.0 * math.sqrt(3.0) / 3.0 * 3.5 / 16.0  # 1.2630 m/s^2
    assert expected == pytest.approx(1.26295, abs=1e-5)
    assert np.abs(d_dd).max() == pytest.approx(expected, rel=0.02)
    # the Cartesian lateral acceleration v^2 kappa sees the same peak
    assert np.abs(c.speed[k] ** 2 * c.curvature[k]).max() == pytest.approx(expected, rel=0.03)
    # heading = atan2(d_dot, s_dot): peak d_dot = 15/8 D/T at mid-move
    assert np.abs(c.yaw[k]).max() == pytest.approx(math.atan2(15 / 8 * 3.5 / 4.0, 10.0), rel=0.01)


def test_curved_path_constant_speed_has_path_curvature():
    a = np.linspace(0.0, np.pi, 400)
    circle = Polyline.from_points(50.0 * np.stack([np.sin(a), 1.0 - np.cos(a)], axis=-1))  # left turn, R = 50
    c = run(10.0, path=circle)
    k = k_of(2, 10, 11)
    np.testing.assert_allclose(c.curvature[k], 1 / 50, rtol=0.02)
    np.testing.assert_allclose(c.speed[k], 10.0, atol=1e-9)
    np.testing.assert_allclose(np.hypot(c.x[k], c.y[k] - 50.0), 50.0, atol=0.01)
    # 2 m to the left of a left turn, staying there: radius 48, speed along it 10 * 48 / 50
    c2 = run(10.0, d0=2.0, path=circle, left=2.0, right=-2.0)
    k2 = k_of(2, 10, 22)  # d_end = 2
    np.testing.assert_allclose(c2.d[k2], 2.0, atol=1e-12)
    np.testing.assert_allclose(c2.speed[k2], 9.6, rtol=1e-6)  # polyline curvature ~ 1/50
    np.testing.assert_allclose(c2.curvature[k2], 1 / 48, rtol=0.02)


def test_end_offsets_span_drivable_area_minus_margin():
    c = run(10.0, left=3.0, right=-4.0, margin=0.8)
    k_lo, k_hi = k_of(0, 10, 0), k_of(0, 10, 22)
    assert c.d[k_lo, 19] == pytest.approx(-3.2) and c.d[k_hi, 19] == pytest.approx(2.2)
    narrow = run(10.0, left=np.full(2, 0.5), right=np.full(2, -0.3), margin=0.8)  # empty: midpoint
    np.testing.assert_allclose(narrow.d[:, -1], 0.1)


# --------------------------------------------------------------------------- low speed
def test_low_speed_sampling_from_standstill_is_finite():
    c = run(0.0, d0=0.5)
    for name in ("x", "y", "yaw", "speed", "accel", "curvature", "s", "d"):
        assert np.isfinite(getattr(c, name)).all(), name
    assert (c.speed >= 0.0).all()
    still = k_of(0, 0, 22)  # stop candidate cannot move sideways: stays put
    np.testing.assert_allclose(c.s[still], 10.0)
    np.testing.assert_allclose(c.d[still], 0.5)
    np.testing.assert_allclose(c.curvature[still], 0.0)
    moving = k_of(2, 3, 22)  # to 3 m/s while moving to the left edge
    assert c.d[moving, -1] == pytest.approx(3.5)
    assert np.all(np.diff(c.d[moving]) >= -1e-12)


def test_low_speed_lateral_profile_is_over_arc_length():
    c = run(1.0, d0=0.0)  # below low_speed = 3: d(s) quintic over the distance travelled
    k = k_of(1, 2, 22)
    s_rel = c.s[k] - 10.0
    sig = s_rel[29]  # distance travelled by T = 3 s
    u = s_rel[:30] / sig
    np.testing.assert_allclose(c.d[k, :30], 3.5 * (10 * u**3 - 15 * u**4 + 6 * u**5), atol=1e-9)


# --------------------------------------------------------------------------- feasibility
def test_feasibility_flags_hard_braking():
    c = run(20.0)
    f = check(c, road(3.5), EgoVehicle(max_decel=8.0), speed_limit_factor=None)
    # quartic stop from 20 m/s in T: peak deceleration 1.5 v0 / T = 15 (T = 2), 7.5 (T = 4)
    assert np.min(c.accel[k_of(0, 0, 11)]) == pytest.approx(-15.0, rel=0.01)
    assert not f.accel_ok[k_of(0, 0, 11)]
    assert f.accel_ok[k_of(2, 0, 11)]
    assert f.feasible[k_of(2, 14, 11)] or not f.accel_ok[k_of(2, 14, 11)]


def test_feasibility_flags_leaving_the_road():
    c = run(10.0)
    f = check(c, road(1.75), EgoVehicle())  # one 3.5 m lane; ego 1.61 m wide
    assert f.on_road[k_of(2, 10, 11)]
    assert not f.on_road[k_of(2, 10, 22)]  # d_end = 3.5
    assert not f.on_road[k_of(2, 10, 0)]
    assert f.feasible[k_of(2, 10, 22)]  # physically fine, just off the road


def test_feasibility_flags_sharp_lateral_move_at_speed():
    c = sample(STRAIGHT, FrenetState(s=0.0, d=0.0, s_dot=30.0), CFG, 30.0)
    f = check(c, road(10.0), EgoVehicle(max_lat_accel=4.0))
    k2 = (0 * NV + 14) * ND + 22  # 2 s, keep 30 m/s, 3.5 m: peak 5.77 * 3.5 / 4 = 5.05 m/s^2
    k4 = (2 * NV + 14) * ND + 22  # 4 s: 1.26 m/s^2
    assert not f.lat_accel_ok[k2] and f.lat_accel_ok[k4]
    assert f.curvature_ok[k4]


def test_feasibility_speed_limit_and_reversing():
    c = run(10.0)
    r = Road(STRAIGHT, np.full(2, 3.5), np.full(2, -3.5))
    r_lim = type("R", (), {"path": STRAIGHT, "left": r.left, "right": r.right, "speed_limit": np.full(2, 12.0)})()
    f = check(c, r_lim, EgoVehicle())
    assert f.speed_ok[k_of(2, 12, 11)] and not f.speed_ok[k_of(2, 13, 11)]
    assert check(c, r_lim, EgoVehicle(), speed_limit_factor=1.2).speed_ok[k_of(2, 14, 11)]
    # braking hard at low speed: the quartic to a stop dips below zero speed -> rejected
    back = run(0.5, a0=-3.0)
    assert back.speed[k_of(0, 0, 11)].min() < 0.0
    assert not check(back, r, EgoVehicle()).speed_ok[k_of(0, 0, 11)]


def test_feasibility_ignores_invalid_steps():
    c = run(20.0)
    valid = np.ones_like(c.valid)
    valid[:, :] = False
    masked = type(c)(**{**{n: getattr(c, n) for n in c.__dataclass_fields__}, "valid": valid})
    f = check(masked, road(0.1), EgoVehicle(max_decel=1.0))
    assert f.feasible.all() and f.on_road.all()


# --------------------------------------------------------------------------- start state
def test_frenet_state_from_cartesian_on_straight_path():
    st = FrenetState.from_cartesian(STRAIGHT, 10.0, 1.0, 0.1, 10.0, accel=2.0)
    assert (st.s, st.d) == pytest.approx((10.0, 1.0))
    assert st.s_dot == pytest.approx(10 * math.cos(0.1)) and st.d_dot == pytest.approx(10 * math.sin(0.1))
    assert st.s_ddot == pytest.approx(2 * math.cos(0.1)) and st.d_ddot == pytest.approx(2 * math.sin(0.1))


# a left bend of radius 5 m (curvature 0.2 1/m) from s = 10 m on, like the junction turns on A10KW
_ARC = np.linspace(0.0, math.pi / 2, 60)
BEND = Polyline.from_points(np.vstack([np.stack([np.linspace(-10.0, 0.0, 11), np.zeros(11)], -1)[:-1],
                                       np.stack([5 * np.sin(_ARC), 5 - 5 * np.cos(_ARC)], -1)]))


@pytest.mark.parametrize("speed, d, d_dot", [(5.0, 0.4, 0.5), (5.0, -0.4, -0.5), (5.0, 0.4, 0.0), (5.0, 0.0, 0.5),
                                             (10.0, 0.0, 0.0), (2.0, 0.3, 0.2)])
def test_start_state_at_speed_starts_the_candidates_at_that_speed(speed, d, d_dot):
    st = FrenetState.at_speed(BEND, 12.0, d, speed, d_dot=d_dot)
    kr = float(BEND.curvature_at(12.0))
    assert kr == pytest.approx(0.2, abs=1e-3)
    one = 1 - kr * d
    assert math.hypot(st.s_dot * one, st.d_dot) == pytest.approx(speed)  # sample's start speed
    assert (st.s, st.d, st.d_dot) == (12.0, d, d_dot)
    if speed < SamplingConfig().low_speed:
        return
    # so the first step's speed change is the mean of the candidates' own acceleration over it:
    # (a(0) + a(dt)) / 2 with a(0) = -s_dot (1 - kr d) s_dot kr d_dot / speed (s_ddot = d_ddot = 0).
    # With s_dot = speed it was off by up to 4 m/s^2 here (0.4 m beside the bend: 8% too fast).
    c = sample(BEND, st, SamplingConfig(horizons=(3.0,), n_speeds=29, n_offsets=5), 14.0)
    a0 = -st.s_dot * one * st.s_dot * kr * st.d_dot / speed
    jump = (c.speed[:, 0] - speed) / 0.1
    assert np.abs(jump - 0.5 * (a0 + c.accel[:, 0])).max() < 0.05


def test_start_state_at_speed_caps_the_lateral_rate():
    st = FrenetState.at_speed(BEND, 12.0, 0.0, 1.0, d_dot=2.0)
    assert st.d_dot == pytest.approx(math.sqrt(0.5)) and st.s_dot == pytest.approx(math.sqrt(0.5))
    still = FrenetState.at_speed(BEND, 12.0, 0.3, 0.0, d_dot=0.4)
    assert (still.s_dot, still.d_dot) == (0.0, 0.0)


# --------------------------------------------------------------------------- config
@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"horizons": (2.0, 0.05)}, "at least one step"),
        ({"horizons": ()}, "at least one horizon"),
        ({"n_speeds": 0}, "n_speeds must be an integer >= 1"),
        ({"n_offsets": 2.5}, "n_offsets must be an integer >= 1"),
        ({"dt": -0.1}, "dt must be positive"),
        ({"dt": float("nan")}, "dt must be a finite number"),
        ({"horizons": (float("nan"),)}, "horizons must be a finite number"),
        ({"max_offset": -1.0}, "max_offset must be >= 0"),
        ({"low_speed": float("inf")}, "low_speed must be a finite number"),
    ],
)
def test_bad_config_raises(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        SamplingConfig(**kwargs)


def test_bad_start_and_speed_raise():
    with pytest.raises(ConfigError, match="FrenetState.s_dot must be a finite number"):
        FrenetState(s=0.0, d=0.0, s_dot=float("nan"))
    with pytest.raises(ConfigError, match="v_max"):
        sample(STRAIGHT, FrenetState(0.0, 0.0, 1.0), CFG, -1.0)
    with pytest.raises(ConfigError, match="speed_limit_factor"):
        check(run(5.0), road(2.0), EgoVehicle(), speed_limit_factor=0.0)


def test_small_grid_counts():
    cfg = SamplingConfig(horizons=(1.0,), n_speeds=1, n_offsets=1)
    c = run(5.0, cfg=cfg)
    assert len(c) == 1 and c.x.shape == (1, 10)
    assert c.speed[0, -1] == pytest.approx(14.0) and c.d[0, -1] == pytest.approx(0.0)


# --------------------------------------------------------------------------- one block
def test_sampling_into_a_block_writes_its_rows_only():
    """``out``/``row``: the rows of a shared block hold exactly what a sampling of its own gives (same
    kernel, same bytes); the rows before and after stay as they were; a block of the wrong shape is refused."""
    cfg = SamplingConfig(horizons=(2.0, 4.0), n_speeds=4, n_offsets=3)  # K = 24, T = 40
    st = FrenetState(s=10.0, d=0.4, s_dot=8.0, s_ddot=-1.0, d_dot=0.2)
    alone = sample(STRAIGHT, st, cfg, 14.0, left=3.0, right=-3.0, margin=0.8)
    block = np.full((9, 30, cfg.n_steps), -7.0)
    into = sample(STRAIGHT, st, cfg, 14.0, left=3.0, right=-3.0, margin=0.8, out=block, row=5)
    for f, name in enumerate(("x", "y", "yaw", "speed", "accel", "curvature", "s", "d", "road_curvature")):
        np.testing.assert_array_equal(getattr(into, name), getattr(alone, name))
        np.testing.assert_array_equal(block[f, 5:29], getattr(alone, name))
    assert (block[:, :5] == -7.0).all() and (block[:, 29:] == -7.0).all()
    with pytest.raises(ValueError, match="rows 10 to 33"):
        sample(STRAIGHT, st, cfg, 14.0, out=block, row=10)  # 24 rows do not fit from row 10 of 30
    with pytest.raises(ValueError, match="C-contiguous"):
        sample(STRAIGHT, st, cfg, 14.0, out=np.zeros((9, 24, 20)))  # T = 20 instead of 40


def test_feasibility_vertex_walk_matches_a_fresh_search_per_step():
    """The check finds each step's path vertex by walking from the step before; a candidate that drives
    back and forth across many short segments (60 such, at random offsets) gets the verdicts it gets when every
    step is checked as a candidate of its own (each a fresh search from the first vertex)."""
    from sumo_ethics.types import Candidates

    xs = np.linspace(0.0, 60.0, 31)  # 2 m segments, a lane that narrows and widens
    path = Polyline.from_points(np.stack([xs, np.zeros_like(xs)], -1))
    half = 1.2 + 0.8 * np.abs(np.sin(xs / 7.0))
    r = type("R", (), {"path": path, "left": half, "right": -half, "speed_limit": 8.0 + 4.0 * np.cos(xs / 9.0)})()
    T, K = 40, 60
    rng = np.random.default_rng(3)
    s = 30.0 + 6.0 * np.sin(np.linspace(0.0, 2.0 * np.pi, T))[None, :] + rng.uniform(-20.0, 20.0, (K, 1))
    d = rng.uniform(-1.2, 1.2, (K, 1)) * np.ones((1, T))
    speed = np.abs(np.gradient(s, 0.1, axis=1))  # up to 9.7 m/s against limits of 8 to 12
    z = np.zeros((K, T))
    c = Candidates(0.1, s, d, z, speed, z, z, s, d, np.full(K, 4.0), np.ones((K, T), bool), road_curvature=z)
    whole = check(c, r, EgoVehicle(), speed_limit_factor=1.0)
    def one_step(i: int, t: int) -> Candidates:
        cell = (slice(i, i + 1), slice(t, t + 1))
        return Candidates(0.1, s[cell], d[cell], z[cell], speed[cell], z[cell], z[cell], s[cell], d[cell],
                          np.full(1, 0.1), np.ones((1, 1), bool), road_curvature=z[cell])

    for i in range(K):
        per_step = [check(one_step(i, t), r, EgoVehicle(), speed_limit_factor=1.0) for t in range(T)]
        assert whole.on_road[i] == all(f.on_road[0] for f in per_step)
        assert whole.speed_ok[i] == all(f.speed_ok[0] for f in per_step)
    # the rows differ: the narrow stretches put some off the road, the limits some too fast
    assert 0 < whole.on_road.sum() < K and 0 < whole.speed_ok.sum() < K


@pytest.mark.parametrize("seed", range(5))
def test_sampled_profiles_are_the_quartic_and_quintic_evaluated_by_numpy(seed):
    """On a straight path along +x, x = s and y = d: every candidate's x(t) - s0 is the quartic of
    ``quartic_coeffs`` (then v_end on past its horizon) and y(t) the quintic of ``quintic_coeffs`` to its
    end offset (then held), both evaluated here by numpy.polynomial, from random start states."""
    rng = np.random.default_rng(seed)
    cfg = SamplingConfig(horizons=(1.0, 2.5, 4.0), n_speeds=6, n_offsets=5)
    st = FrenetState(s=float(rng.uniform(0, 50)), d=float(rng.uniform(-1, 1)), s_dot=float(rng.uniform(3.5, 15)),
                     s_ddot=float(rng.uniform(-2, 2)), d_dot=float(rng.uniform(-0.5, 0.5)),
                     d_ddot=float(rng.uniform(-0.5, 0.5)))
    c = sample(STRAIGHT, st, cfg, 14.0, left=3.0, right=-3.0, margin=0.9)
    t = cfg.dt * np.arange(1, cfg.n_steps + 1)
    ve = np.linspace(0.0, 14.0, 6)
    for k in range(len(c)):
        i_t, rest = divmod(k, 6 * 5)
        i_v = rest // 5
        T = cfg.horizons[i_t]
        tau = np.minimum(t, T)
        s_poly = np.polynomial.Polynomial(quartic_coeffs(st.s_dot, st.s_ddot, ve[i_v], T))
        np.testing.assert_allclose(c.x[k] - st.s, s_poly(tau) + ve[i_v] * (t - tau), rtol=0, atol=1e-9)
        d_poly = np.polynomial.Polynomial(quintic_coeffs(st.d, st.d_dot, st.d_ddot, c.d[k, -1], T))
        np.testing.assert_allclose(c.y[k], d_poly(tau), rtol=0, atol=1e-9)
        assert -3.0 + 0.9 - 1e-12 <= c.d[k, -1] <= 3.0 - 0.9 + 1e-12
