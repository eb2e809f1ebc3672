"""Covariance calibration of the predictors (predict/calibration.py): numbers checkable by hand."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from sumo_ethics.predict import calibration as C
from sumo_ethics.predict import features as F

T = F.FUT_STEPS


def moving(a: np.ndarray) -> np.ndarray:
    """(len(a),) speeds [m/s] of agents in motion (none of them ``standing``)."""
    return np.full(len(a), 10.0)


def synthetic(n: int, sigma_lon: float, sigma_lat: float, shrink: float, seed: int, lateral: float = 0.0,
              group: int = F.GROUP_VEHICLE):
    """n one-mode predictions with mean (t, lateral * t / 4) and true errors N(0, diag(sigma^2)),
    the predicted sigmas ``shrink`` times the true ones."""
    rng = np.random.default_rng(seed)
    t = (np.arange(T) + 1) * F.MODEL_DT
    params = np.zeros((n, 1, T, 5))
    params[..., 0] = t
    params[..., 1] = lateral * t / t[-1]
    params[..., 2] = shrink * sigma_lon
    params[..., 3] = shrink * sigma_lat
    fut = params[:, 0, :, :2] + rng.normal(size=(n, T, 2)) * np.array([sigma_lon, sigma_lat])
    return params, np.ones((n, 1)), np.full(n, group), fut


def test_ellipse_mass_is_one_minus_exp():
    # k = 1: 1 - e^-0.5 = 0.3935; k = 2: 1 - e^-2 = 0.8647 (chi-square with 2 degrees of freedom)
    assert C.ellipse_mass(1.0) == pytest.approx(0.39347, abs=1e-5)
    assert C.ellipse_mass(2.0) == pytest.approx(0.86466, abs=1e-5)
    assert C.TARGET == pytest.approx(0.86466, abs=1e-5)
    assert C.ellipse_k(C.ellipse_mass(1.7)) == pytest.approx(1.7)
    # against a seeded Monte Carlo of a correlated 2-D Gaussian: the share inside its k-sigma ellipse
    rng = np.random.default_rng(1)
    sx, sy, rho = 2.0, 0.5, 0.6
    cov = np.array([[sx * sx, rho * sx * sy], [rho * sx * sy, sy * sy]])
    pts = rng.multivariate_normal([3.0, -1.0], cov, size=200_000)
    params = np.broadcast_to(np.array([3.0, -1.0, sx, sy, rho]), (len(pts), 5))
    m2 = C.mahalanobis2(params, pts)
    for k in (0.5, 1.0, 2.0, 3.0):
        assert (m2 <= k * k).mean() == pytest.approx(1 - math.exp(-k * k / 2), abs=0.004)


def test_coverage_curve_of_a_calibrated_gaussian_is_the_diagonal():
    params, w, g, fut = synthetic(4000, 1.0, 0.5, 1.0, seed=2)
    cov = C.coverage(params[:, 0], fut)
    assert np.allclose(cov, C.LEVELS, atol=0.01)


def test_half_sigma_predictor_gets_factor_two_and_nominal_coverage():
    # a predictor whose sigmas are half the truth: its 2-sigma ellipse is the true 1-sigma one and
    # holds 1 - e^-0.5 = 39.3 %; the fit should find factor 2 on both axes, after which the
    # 2-sigma ellipse of fresh samples holds 86.5 %
    params, w, g, fut = synthetic(6000, 1.2, 0.3, 0.5, seed=3)
    before = C.coverage(params[:, 0], fut, levels=(C.TARGET,))[0]
    assert before == pytest.approx(0.393, abs=0.01)
    cal = C.fit(params, w, g, moving(g), fut, level=C.TARGET)
    fitted = cal.scale[F.GROUP_VEHICLE, 0]  # the steady state: the means do not move sideways
    assert np.allclose(fitted, 2.0, rtol=0.05)
    assert (cal.n_points[F.GROUP_VEHICLE, 0] > 0).all()
    assert (cal.n_points[F.GROUP_VEHICLE, 1:] == 0).all()  # no lateral samples: pooled fallback
    assert np.allclose(cal.scale[F.GROUP_VEHICLE, 1:], fitted[None])
    assert np.all(cal.scale[F.GROUP_CYCLIST] == 1.0)  # no cyclists at all: factor 1
    p2, w2, g2, fut2 = synthetic(6000, 1.2, 0.3, 0.5, seed=4)
    after = C.coverage(cal.apply(p2, w2, g2, moving(g2))[:, 0], fut2, levels=(C.TARGET,))[0]
    assert after == pytest.approx(0.865, abs=0.01)


def test_fit_level_sets_the_share_inside_the_2_sigma_ellipse():
    # fitted to hold 91 % (the shipped FIT_LEVEL), the predicted 2-sigma ellipse must be the truth's
    # k-sigma ellipse with 1 - exp(-k^2/2) = 0.91, k = sqrt(-2 ln 0.09) = 2.194; predicted sigma = true / 2,
    # so 2 * factor * sigma_true / 2 = k * sigma_true: factor = 2 * k / 2 = 2.194
    params, w, g, fut = synthetic(6000, 1.0, 0.5, 0.5, seed=8)
    cal = C.fit(params, w, g, moving(g), fut)
    assert C.FIT_LEVEL == 0.91
    assert np.allclose(cal.scale[F.GROUP_VEHICLE, 0], 2.0 * math.sqrt(-2 * math.log(0.09)) / 2.0, rtol=0.05)
    p2, w2, g2, fut2 = synthetic(6000, 1.0, 0.5, 0.5, seed=9)
    assert C.coverage(cal.apply(p2, w2, g2, moving(g2))[:, 0], fut2, levels=(C.TARGET,))[0] == pytest.approx(0.91, abs=0.01)


def test_balanced_weights_give_each_manoeuvre_the_same_total():
    group = np.array([0] * 1000 + [0] * 600 + [0] * 10 + [2] * 7)
    man = np.array([0] * 1000 + [3] * 600 + [1] * 10 + [-1] * 7)
    w = C.balanced_weights(group, man)
    assert w[:1000].sum() == pytest.approx(1.0) and w[1000:1600].sum() == pytest.approx(1.0)
    assert w[1600:1610].sum() == pytest.approx(10 / 500)  # fewer than BALANCE_MIN: proportionally less
    assert C.weighted_quantile(np.array([3.0, 1.0, 2.0, 4.0]), np.array([1.0, 1.0, 1.0, 1.0]), 0.5) == 2.0
    assert C.weighted_quantile(np.array([3.0, 1.0, 2.0, 4.0]), np.array([0.1, 0.1, 0.1, 10.0]), 0.5) == 4.0


def test_too_wide_lateral_shrinks_and_axes_are_fitted_separately():
    # lateral sigma predicted 4x too wide, longitudinal right: factors about 1 and 0.25
    params, w, g, fut = synthetic(6000, 1.0, 0.2, 1.0, seed=5)
    params[..., 3] = 0.8
    cal = C.fit(params, w, g, moving(g), fut, level=C.TARGET)
    assert np.allclose(cal.scale[F.GROUP_VEHICLE, 0, :, 0], 1.0, rtol=0.06)
    assert np.allclose(cal.scale[F.GROUP_VEHICLE, 0, :, 1], 0.25, rtol=0.06)


def test_state_comes_from_the_predicted_modes_not_the_future():
    mu_y = np.zeros((4, 2, T))
    mu_y[1, 0, -1] = 1.0  # the most likely mode ends 1 m to the side: lateral
    mu_y[2, 1, 5] = -3.0  # a second mode 3 m to the right, weight 0.3: strong lateral
    mu_y[3, 1, 5] = -3.0  # ... with weight 0.05 it does not count: steady
    w = np.array([[1.0, 0.0], [1.0, 0.0], [0.7, 0.3], [0.95, 0.05]])
    assert C.state_of(mu_y, w).tolist() == [0, 1, 2, 0]
    # slower than 0.5 m/s now: the steady ones (0 and 3) are standing, the lateral ones stay lateral
    assert C.state_of(mu_y, w, np.array([0.2, 0.2, 0.49, 0.0])).tolist() == [3, 1, 2, 3]
    assert C.state_of(mu_y, w, np.array([0.5, 0.2, 0.49, 7.0])).tolist() == [0, 1, 2, 0]
    assert C.lateral_extent(mu_y, w).tolist() == [0.0, 1.0, 3.0, 0.0]


def test_interpolation_between_bin_centres():
    cal = C.Calibration.identity()
    scale = cal.scale.copy()
    scale[0, 0, :, 1] = np.arange(len(C.BINS)) + 1.0  # 1, 2, 3, ... at the bin centres
    table = C.Calibration(scale, cal.n_points).per_step()
    c = C.bin_centres()
    t = (np.arange(T) + 1) * F.MODEL_DT
    for i, ti in enumerate(t):
        want = np.interp(ti, c, np.arange(len(C.BINS)) + 1.0)
        assert table[0, 0, i, 1] == pytest.approx(want)
    assert table[0, 0, 0, 1] == 1.0 and table[0, 0, -1, 1] == len(C.BINS)  # held beyond the ends
    assert np.all(table[..., 0] == 1.0)


def test_file_round_trip_and_hash_check(tmp_path: Path):
    params, w, g, fut = synthetic(3000, 1.0, 0.4, 0.5, seed=6)
    weights = tmp_path / "m.pt"
    weights.write_bytes(b"weights")
    cal = C.fit(params, w, g, moving(g), fut, weights_sha256=C.file_sha256(weights), meta={"note": "test"})
    path = cal.write(C.calibration_path(weights))
    assert path.name == "m.calibration.json"
    back = C.load_for(weights)
    assert back is not None and np.array_equal(back.scale, cal.scale) and np.array_equal(back.n_points, cal.n_points)
    again = tmp_path / "again.json"
    back.write(again)
    assert again.read_bytes() == path.read_bytes()  # same inputs, same bytes
    weights.write_bytes(b"other weights")
    assert C.load_for(weights) is None  # fitted for other weights: not applied
    d = json.loads(path.read_text())
    d["states"] = ["a", "b", "c"]
    path.write_text(json.dumps(d))
    with pytest.raises(ValueError):
        C.Calibration.read(path)


def test_fit_is_deterministic():
    params, w, g, fut = synthetic(2000, 1.0, 0.4, 0.7, seed=7, lateral=1.0)
    a = C.fit(params, w, g, moving(g), fut, min_points=100).to_dict()
    b = C.fit(params.copy(), w.copy(), g.copy(), moving(g.copy()), fut.copy(), min_points=100).to_dict()
    assert json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)
    assert (np.asarray(a["n_points"])[F.GROUP_VEHICLE, 1] > 0).all()  # 1 m sideways: the lateral state


def test_standing_agents_get_their_own_factors():
    # the same steady predictions (sigma 0.5 m predicted on both axes): the moving half's true
    # errors are N(0, 1 m) on both axes, the standing half's N(0, 1 m) along and N(0, 0.2 m) across.
    # Pooled (version 1) both would get one lateral factor. With the standing state each cell gets
    # (true / predicted) x k / 2, k = 2.194 (the 2-sigma ellipse holds FIT_LEVEL = 91 %): the moving
    # ones k on both axes, the standing ones k along and 0.4 k / 2 = 0.2 k across
    k = math.sqrt(-2 * math.log(1 - C.FIT_LEVEL))
    pm, wm, gm, fm = synthetic(6000, 1.0, 1.0, 0.5, seed=11)
    ps, ws, gs, fs = synthetic(6000, 1.0, 0.2, 2.5, seed=12)
    ps[..., 0] = 0.0  # standing: no progress expected,
    ps[..., 2] = 0.5  # the same predicted spread as the moving ones
    fs = ps[:, 0, :, :2] + np.random.default_rng(13).normal(size=fs.shape) * np.array([1.0, 0.2])
    speed = np.r_[np.full(6000, 8.0), np.full(6000, 0.1)]
    cal = C.fit(np.r_[pm, ps], np.r_[wm, ws], np.r_[gm, gs], speed, np.r_[fm, fs])
    moving_f, standing_f = cal.scale[F.GROUP_VEHICLE, 0], cal.scale[F.GROUP_VEHICLE, C.STANDING]
    assert np.allclose(moving_f, k, rtol=0.06)  # 0.5 m predicted, 1 m true on both axes
    assert np.allclose(standing_f[:, 0], k, rtol=0.06)  # along: 0.5 predicted, 1 true
    assert np.allclose(standing_f[:, 1], 0.2 * k, rtol=0.06)  # across: 0.5 predicted, 0.2 true
    assert (cal.n_points[F.GROUP_VEHICLE, C.STANDING] > 0).all()
    # applied: a standing agent's lateral sigma at 4 s is 0.5 x 0.2 k = 0.22 m, a moving one's 0.5 k = 1.1 m
    _, sy = cal.sigmas(np.zeros(2, dtype=int), np.zeros((2, 1, T)), np.ones((2, 1)), np.array([0.0, 8.0]),
                       np.full((2, 1, T), 0.5), np.full((2, 1, T), 0.5))
    assert sy[:, 0, -1] == pytest.approx([0.1 * k, 0.5 * k], rel=0.06)


def test_a_version_1_file_loads_with_the_steady_factors_for_standing_agents(tmp_path: Path):
    params, w, g, fut = synthetic(3000, 1.0, 0.4, 0.5, seed=6)
    cal = C.fit(params, w, g, moving(g), fut)
    d = cal.to_dict()
    v1 = {**d, "version": 1, "states": ["steady", "lateral", "strong_lateral"],
          "scale_lon": [rows[:3] for rows in d["scale_lon"]], "scale_lat": [rows[:3] for rows in d["scale_lat"]],
          "n_points": [rows[:3] for rows in d["n_points"]]}
    v1.pop("stand_speed_mps")
    back = C.Calibration.from_dict(v1)
    assert np.array_equal(back.scale[:, C.STANDING], cal.scale[:, 0])
    assert np.array_equal(back.scale[:, :3], cal.scale[:, :3]) and (back.n_points[:, C.STANDING] == 0).all()


# ------------------------------------------------------------ applied on load (torch)
def test_calibration_is_applied_when_the_predictor_loads(tmp_path: Path):
    pytest.importorskip("torch")
    from sumo_ethics.predict.predictor import LSTMPredictor, default_weights
    from test_predict import straight_obs

    src = default_weights("map")
    weights = tmp_path / "mine.pt"
    shutil.copyfile(src, weights)
    cal = C.Calibration.identity()
    scale = cal.scale.copy()
    scale[..., 0] = 2.0  # lon x 2: variance x 4
    scale[..., 1] = 3.0  # lat x 3: variance x 9
    C.Calibration(scale, cal.n_points, C.file_sha256(weights)).write(C.calibration_path(weights))
    obs = straight_obs(speed=8.0, yaw=0.0)
    plain = LSTMPredictor.from_file(weights, calibrated=False)
    calib = LSTMPredictor.from_file(weights)
    assert plain.calibration is None and calib.calibration is not None
    _, cov0, w0 = plain.mode_outputs(obs)
    mean1, cov1, w1 = calib.mode_outputs(obs)
    # heading 0: the world x axis is the agent's longitudinal axis
    assert np.allclose(cov1[..., 0, 0], 4.0 * cov0[..., 0, 0])
    assert np.allclose(cov1[..., 1, 1], 9.0 * cov0[..., 1, 1])
    assert np.allclose(cov1[..., 0, 1], 6.0 * cov0[..., 0, 1])
    assert np.array_equal(w0, w1)
    p0, p1 = plain.predict(obs, 20, 0.2), calib.predict(obs, 20, 0.2)
    assert np.array_equal(p0.mean, p1.mean)  # the means are untouched
    assert np.allclose(p1.cov[..., 1, 1], 9.0 * p0.cov[..., 1, 1])


@pytest.mark.parametrize("kind", ["map", "map_cslstm", "attention", "cslstm"])
def test_shipped_weights_carry_a_matching_calibration(kind: str):
    from sumo_ethics.predict.predictor import WEIGHTS_DIR

    weights = WEIGHTS_DIR / f"{kind}.pt"
    cal = C.load_for(weights)
    assert cal is not None, f"no calibration fitted for {weights}"
    assert np.all((cal.scale >= C.SCALE_MIN) & (cal.scale <= C.SCALE_MAX))
    assert cal.n_points[F.GROUP_VEHICLE].sum() > 0


def test_planner_config_switches_the_calibration():
    pytest.importorskip("torch")
    from sumo_ethics.errors import ConfigError
    from sumo_ethics.plan.ethical import PlannerConfig, make_predictor
    from sumo_ethics.settings import planner_config
    from sumo_ethics.suite.evaluate import parse_planner

    assert PlannerConfig().calibrated is True
    assert make_predictor("map").calibration is not None
    assert make_predictor("map", calibrated=False).calibration is None
    for name in ("origin", "paper"):  # the baselines stay as published
        cfg = planner_config(None, **parse_planner(name).options)
        assert cfg.calibrated is False
    assert planner_config({"calibrated": False}).calibrated is False
    with pytest.raises(ConfigError):
        planner_config({"calibrated": "yes"})


def test_cap_keeps_a_factor_from_blowing_up_a_wide_spread():
    # cap 1 m: sigma 0.1 x 4 = 0.4 stays; sigma 0.8 x 4 = 3.2 is capped at 1; sigma 2 (model wider than the
    # cap) stays 2: the cap never narrows the model's own spread
    cal = C.Calibration.identity()
    scale = np.full(cal.scale.shape, 4.0)
    cap = np.ones((F.N_GROUPS, len(C.BINS), 2))
    cal = C.Calibration(scale, cal.n_points, cap=cap)
    sx = np.array([0.1, 0.8, 2.0])[:, None, None] * np.ones((3, 1, T))
    mu_y = np.zeros((3, 1, T))
    out_x, out_y = cal.sigmas(np.zeros(3, dtype=int), mu_y, np.ones((3, 1)), moving(sx), sx, sx)
    assert np.allclose(out_x[:, 0, 0], [0.4, 1.0, 2.0]) and np.allclose(out_y, out_x)
    # fitted caps are the 99.5th percentile of the absolute errors: N(0, 1) -> 2.807
    params, w, g, fut = synthetic(8000, 1.0, 1.0, 1.0, seed=10)
    fitted = C.fit(params, w, g, moving(g), fut, level=C.TARGET)
    assert np.allclose(fitted.cap[F.GROUP_VEHICLE], 2.807, rtol=0.05)
    assert C.Calibration.from_dict(fitted.to_dict()).cap.tolist() == fitted.cap.tolist()
