"""Collision probability, Origin's fast method (METHOD.md section 1; ``method="origin"``)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import dblquad

from sumo_ethics.ethics.probability import (
    ProbabilityConfig,
    gaussian_box_mass,
)
from sumo_ethics.ethics.probability import collision_probability as _collision_probability
from sumo_ethics.ethics.probability import sparse_collision_probability as _sparse_collision_probability
from sumo_ethics.types import Candidates, Prediction

EGO_L, EGO_W = 4.508, 1.610
DT = 0.1
ORIGIN = ProbabilityConfig(method="origin")


def collision_probability(*args):
    """Origin's method unless a config is passed (the module tests Origin's formula)."""
    return _collision_probability(*(args if len(args) == 7 else (*args, ORIGIN)))


def sparse_collision_probability(*args):
    return _sparse_collision_probability(*(args if len(args) == 7 else (*args, ORIGIN)))


def make_candidates(x, y, yaw, speed=None, valid=None) -> Candidates:
    x, y = np.atleast_2d(np.asarray(x, float)), np.atleast_2d(np.asarray(y, float))
    yaw = np.broadcast_to(np.asarray(yaw, float), x.shape).copy()
    speed = np.zeros(x.shape) if speed is None else np.broadcast_to(np.asarray(speed, float), x.shape).copy()
    valid = np.ones(x.shape, bool) if valid is None else np.asarray(valid, bool)
    z = np.zeros(x.shape)
    return Candidates(
        dt=DT, x=x, y=y, yaw=yaw, speed=speed, accel=z, curvature=z, s=z, d=z,
        horizon=np.full(x.shape[0], x.shape[1] * DT), valid=valid,
    )


def make_prediction(mean, cov, yaw) -> Prediction:
    mean = np.asarray(mean, float)
    n = mean.shape[0]
    return Prediction(ids=tuple(f"a{i}" for i in range(n)), dt=DT, mean=mean, cov=np.asarray(cov, float), yaw=np.asarray(yaw, float))


def stationary(xy, yaw, T, var=1e-4) -> Prediction:
    """One agent standing at xy with heading yaw and an isotropic covariance var * I."""
    mean = np.broadcast_to(np.asarray(xy, float), (1, T, 2))
    cov = np.broadcast_to(var * np.eye(2), (1, T, 2, 2))
    return make_prediction(mean, cov, np.full((1, T), yaw))


def drive_along_x(T=60, y=0.0, x0=-15.0, v=10.0) -> Candidates:
    x = x0 + v * DT * (np.arange(T) + 1)
    return make_candidates(x[None], np.full((1, T), y), 0.0)


# ------------------------------------------------------------------ rectangle mass
def brute_force_mass(mean, cov, cxy, yaw, length, width) -> float:
    """Gaussian pdf integrated over the rotated box, in box coordinates (Jacobian 1)."""
    inv = np.linalg.inv(cov)
    norm = 1.0 / (2.0 * math.pi * math.sqrt(np.linalg.det(cov)))
    c, s = math.cos(yaw), math.sin(yaw)

    def pdf(v: float, u: float) -> float:
        x = cxy[0] + c * u - s * v - mean[0]
        y = cxy[1] + s * u + c * v - mean[1]
        return norm * math.exp(-0.5 * (inv[0, 0] * x * x + 2 * inv[0, 1] * x * y + inv[1, 1] * y * y))

    val, _ = dblquad(pdf, -length / 2, length / 2, -width / 2, width / 2, epsabs=1e-10, epsrel=1e-10)
    return val


def random_case(rng: np.random.Generator):
    sx, sy = rng.uniform(0.15, 2.0, 2)
    rho = rng.uniform(-0.9, 0.9)
    cov = np.array([[sx * sx, rho * sx * sy], [rho * sx * sy, sy * sy]])
    cxy = rng.uniform(-3, 3, 2)
    yaw = rng.uniform(-math.pi, math.pi)
    length, width = rng.uniform(0.5, 5.0), rng.uniform(0.5, 2.5)
    mean = cxy + rng.normal(0.0, 1.5, 2)
    return mean, cov, cxy, yaw, length, width


def test_rotated_box_mass_matches_brute_force_integration():
    rng = np.random.default_rng(7)
    cases = [random_case(rng) for _ in range(50)]
    mean, cov, cxy, yaw, length, width = (np.array(v) for v in zip(*cases))
    got = gaussian_box_mass(mean, cov, cxy, yaw, length, width)  # one vectorised call
    ref = np.array([brute_force_mass(*case) for case in cases])
    assert got.shape == (50,)
    assert np.max(np.abs(got - ref)) < 1e-5  # METHOD.md asks for 1e-3; we are at ~1e-6
    assert np.ptp(ref) > 0.5  # the cases span near-empty to near-full boxes


def test_box_mass_high_correlation_and_degenerate_limits():
    # A thin Gaussian along the diagonal of an axis-aligned unit box: rho = 0.999 in the box frame.
    s = np.array([[1.0, 0.999], [0.999, 1.0]]) * 0.25
    got = gaussian_box_mass(np.zeros(2), s, np.zeros(2), 0.0, 1.0, 1.0)
    ref = brute_force_mass(np.zeros(2), s, np.zeros(2), 0.0, 1.0, 1.0)
    assert got == pytest.approx(ref, abs=1e-5)
    # Isotropic: the mass separates into the product of two 1-D intervals.
    from scipy.stats import norm

    expect = (norm.cdf(1.0) - norm.cdf(-1.0)) * (norm.cdf(0.5) - norm.cdf(-0.5))
    assert gaussian_box_mass(np.zeros(2), np.eye(2), np.zeros(2), 0.3, 2.0, 1.0) == pytest.approx(expect, abs=1e-5)
    # Far away: exactly 0; deep inside a huge box: exactly 1 (tail gate).
    assert gaussian_box_mass(np.array([20.0, 0]), np.eye(2), np.zeros(2), 0.0, 2.0, 2.0) == 0.0
    assert gaussian_box_mass(np.zeros(2), 0.01 * np.eye(2), np.zeros(2), 0.0, 20.0, 20.0) == 1.0


def test_standard_rectangle_all_correlation_branches():
    # Genz's two branches (|rho| < 0.925 by node class, asymptotic above), both signs, against
    # a 1-D adaptive quadrature of phi(x) [Phi((u2 - r x)/s) - Phi((l2 - r x)/s)].
    from scipy.integrate import quad
    from scipy.stats import norm

    from sumo_ethics.ethics.probability import _rect_mass_std

    rng = np.random.default_rng(5)
    M = 160
    l1, l2 = rng.uniform(-4, 3, M), rng.uniform(-4, 3, M)
    u1, u2 = l1 + rng.uniform(0.05, 5, M), l2 + rng.uniform(0.05, 5, M)
    r = np.concatenate([rng.uniform(-1, 1, M - 16) * 0.9999, [0, 0.3, -0.3, 0.75, -0.75, 0.925, -0.925, 0.999] * 2])

    def ref(a, b, c, d, rr):
        sc = math.sqrt(1 - rr * rr)
        f = lambda x: norm.pdf(x) * (norm.cdf((d - rr * x) / sc) - norm.cdf((c - rr * x) / sc))  # noqa: E731
        pts = [p for p in ((c / rr, d / rr) if rr else ()) if a < p < b]
        return quad(f, a, b, epsabs=1e-12, epsrel=1e-12, limit=200, points=pts or None)[0]

    expect = np.array([ref(*z) for z in zip(l1, u1, l2, u2, r)])
    got = _rect_mass_std(*(v.astype(np.float32) for v in (l1, u1, l2, u2, r)))
    assert np.max(np.abs(got - expect)) < 1e-5


# ------------------------------------------------------------------ Origin's fast method
def test_through_a_small_stationary_agent_gives_p_near_one():
    # Agent 0.5 m long: L = 1.5 m, its three points at x = -0.75, 0, 0.75 all fit in the 4.508 m
    # ego box when the ego centre is within 2.254 - 0.75 = 1.5 m of it: P = 1/3 * 3 * ~1 = ~1.
    T = 60
    cand = drive_along_x(T)
    pred = stationary([0.0, 0.0], 0.0, T)
    p = collision_probability(cand, pred, np.array([0.5]), np.array([0.5]), EGO_L, EGO_W)
    assert p.shape == (1, 1, T)
    assert p.max() > 0.95
    assert p.max() <= 1.0


def test_through_a_stationary_car_gives_what_the_formula_gives():
    # Car 4.5 m long: L = 5.5 m, points at -2.75, 0, +2.75 along its heading. The 4.508 m ego
    # box holds at most two of them when aligned -> max P = 2/3; crossing it at right angles the
    # 1.61 m wide box holds one -> max P = 1/3. (Origin's score, not a calibrated probability.)
    T = 60
    cand = drive_along_x(T)
    aligned = collision_probability(cand, stationary([0.0, 0.0], 0.0, T), np.array([4.5]), np.array([1.8]), EGO_L, EGO_W)
    crossing = collision_probability(
        cand, stationary([0.0, 0.0], math.pi / 2, T), np.array([4.5]), np.array([1.8]), EGO_L, EGO_W
    )
    assert aligned.max() == pytest.approx(2.0 / 3.0, abs=1e-6)
    assert crossing.max() == pytest.approx(1.0 / 3.0, abs=1e-6)


def test_ten_metres_away_is_exactly_zero():
    T = 60
    cand = drive_along_x(T, y=0.0)
    pred = stationary([0.0, 10.0], 0.0, T, var=4.0)  # wide covariance, but beyond the 5 m gate
    p = collision_probability(cand, pred, np.array([4.5]), np.array([1.8]), EGO_L, EGO_W)
    assert np.all(p == 0.0)


def test_invalid_steps_short_prediction_and_empty_inputs():
    T = 60
    cand = drive_along_x(T)
    valid = np.ones((1, T), bool)
    valid[0, 10:] = False
    masked = make_candidates(cand.x, cand.y, cand.yaw, valid=valid)
    pred = stationary([0.0, 0.0], 0.0, T, var=1.0)
    full = collision_probability(cand, pred, np.array([0.5]), np.array([0.5]), EGO_L, EGO_W)
    p = collision_probability(masked, pred, np.array([0.5]), np.array([0.5]), EGO_L, EGO_W)
    np.testing.assert_array_equal(p[..., :10], full[..., :10])
    assert np.all(p[..., 10:] == 0.0) and full[..., 10:].max() > 0.5
    # Prediction shorter than the candidates: zero past its horizon.
    short = stationary([0.0, 0.0], 0.0, 20, var=1.0)
    p = collision_probability(cand, short, np.array([0.5]), np.array([0.5]), EGO_L, EGO_W)
    assert p.shape == (1, 1, T) and np.all(p[..., 20:] == 0.0)
    np.testing.assert_array_equal(p[..., :20], full[..., :20])
    # No agents.
    none = make_prediction(np.zeros((0, T, 2)), np.zeros((0, T, 2, 2)), np.zeros((0, T)))
    assert collision_probability(cand, none, np.zeros(0), np.zeros(0), EGO_L, EGO_W).shape == (1, 0, T)


def test_zero_covariance_is_replaced_by_point_one_identity():
    T = 60
    cand = drive_along_x(T, y=0.6)
    zero = make_prediction(np.zeros((1, T, 2)), np.zeros((1, T, 2, 2)), np.zeros((1, T)))
    tenth = make_prediction(np.zeros((1, T, 2)), np.broadcast_to(0.1 * np.eye(2), (1, T, 2, 2)), np.zeros((1, T)))
    args = (np.array([4.5]), np.array([1.8]), EGO_L, EGO_W)
    np.testing.assert_array_equal(collision_probability(cand, zero, *args), collision_probability(cand, tenth, *args))


def reference_probability(cand, pred, length, ego_l, ego_w, cfg=ProbabilityConfig()):
    """METHOD.md read literally: 3 Gaussians x 3 ego boxes, each pair integrated, 5 m gate. Dense."""
    K, T = cand.x.shape
    N = len(pred.ids)
    out = np.zeros((K, N, T))
    cov = pred.cov.copy()
    zero = np.all(cov == 0, axis=(-2, -1))
    cov[zero] = cfg.zero_cov_var * np.eye(2)
    half = (length + cfg.length_margin) / 2
    ego = np.stack([cand.x, cand.y], -1)[:, None]  # (K, 1, T, 2)
    heading = np.stack([np.cos(pred.yaw), np.sin(pred.yaw)], -1)  # (N, T, 2)
    ego_dir = np.stack([np.cos(cand.yaw), np.sin(cand.yaw)], -1)[:, None]
    centres = [pred.mean + g * half[:, None, None] * heading for g in (-1, 0, 1)]
    near = np.zeros((K, N, T), bool)
    for c in centres:
        near |= np.linalg.norm(ego - c[None], axis=-1) <= cfg.gate_radius
    for c in centres:
        for j in (-1, 0, 1):
            box = ego + j * ego_l / 3 * ego_dir
            out += gaussian_box_mass(c[None], cov[None], box, cand.yaw[:, None], ego_l / 3, ego_w)
    return np.where(near & cand.valid[:, None], np.clip(out / 3, 0, 1), 0.0)


def test_vectorised_probability_matches_the_literal_three_by_three_boxes():
    rng = np.random.default_rng(3)
    K, N, T = 40, 6, 25
    t = (np.arange(T) + 1) * DT
    v = rng.uniform(0, 15, K)[:, None]
    lat = rng.uniform(-3.5, 3.5, K)[:, None]
    yaw0 = rng.normal(0, 0.1, K)[:, None]
    cand = make_candidates(v * t * np.cos(yaw0) - lat * np.sin(yaw0), v * t * np.sin(yaw0) + lat, yaw0 + 0 * t,
                           valid=rng.random((K, T)) > 0.1)
    start = rng.uniform([-5, -6], [30, 6], (N, 2))
    heading = rng.uniform(-math.pi, math.pi, N)
    speed = rng.uniform(0, 10, N)
    mean = start[:, None] + (speed[:, None] * t)[..., None] * np.stack([np.cos(heading), np.sin(heading)], -1)[:, None]
    L = rng.normal(size=(N, T, 2, 2)) * (0.2 + 0.1 * t)[None, :, None, None]
    cov = L @ np.swapaxes(L, -1, -2) + 1e-3 * np.eye(2)
    cov[0] = 0.0  # one agent with a zero covariance
    pred = make_prediction(mean, cov, np.broadcast_to(heading[:, None], (N, T)))
    length = rng.uniform(0.5, 12, N)
    p = collision_probability(cand, pred, length, np.full(N, 1.8), EGO_L, EGO_W)
    ref = reference_probability(cand, pred, length, EGO_L, EGO_W)
    assert p.shape == (K, N, T)
    assert np.max(np.abs(p - ref)) < 1e-5  # float32 integration, CDF approximation, 5-sigma tail gate
    assert (p > 0.01).sum() > 50  # the scene has real overlaps
    sp = sparse_collision_probability(cand, pred, length, np.full(N, 1.8), EGO_L, EGO_W)
    order = np.lexsort((sp.t, sp.n, sp.k))
    np.testing.assert_array_equal(order, np.arange(sp.p.size))  # sorted by (k, n, t)
    assert np.all(sp.p > 0)


def test_inflate_by_other_width_only_grows_p():
    T = 60
    cand = drive_along_x(T, y=1.6)
    pred = stationary([0.0, 0.0], 0.0, T, var=0.05)
    args = (np.array([4.5]), np.array([1.8]), EGO_L, EGO_W)
    plain = collision_probability(cand, pred, *args)
    wide = collision_probability(cand, pred, *args, ProbabilityConfig(method="origin", inflate_by_other_width=True))
    assert np.all(wide >= plain - 1e-12) and wide.max() > plain.max() + 0.1


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"gate_radius": float("nan")}, "gate_radius"),
        ({"length_margin": -1.0}, "length_margin"),
        ({"zero_cov_var": 0.0}, "zero_cov_var"),
        ({"p_min": 1.5}, "p_min"),
        ({"inflate_by_other_width": 1}, "inflate_by_other_width"),
    ],
)
def test_config_rejects_nonsense(kwargs, match):
    with pytest.raises(ValueError, match=match):
        ProbabilityConfig(**kwargs)
