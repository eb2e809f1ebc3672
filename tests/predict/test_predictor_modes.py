"""Multi-modal predictors (``modes`` > 1): the mixture losses worked out by hand, the most likely
mode first everywhere, the run-time prediction carrying every mode with its weight, and the
evaluation's mixture NLL."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from sumo_ethics.predict.accuracy import metrics, mixture_nll_points, nll_points  # noqa: E402
from sumo_ethics.predict.models import (  # noqa: E402
    TrajectoryLSTM,
    bivariate_nll,
    load_model,
    mixture_nll,
    save_model,
    winner_mse,
)
from sumo_ethics.predict.predictor import LSTMPredictor  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
from sumo_ethics.predict.synthetic import lane_source, make_observation  # noqa: E402

LOG_2PI = math.log(2.0 * math.pi)


def _gauss(mx: float, my: float, s: float = 1.0) -> list[float]:
    return [mx, my, s, s, 0.0]


def test_mixture_nll_by_hand():
    # one step; mode 0 (weight 0.75) sits on the truth, mode 1 (0.25) 2 m beside it, sigma 1 m:
    # NLL = -log(0.75 N(0) + 0.25 N(2)) = log(2 pi) - log(0.75 + 0.25 exp(-2))
    params = torch.tensor([[[_gauss(0.0, 0.0)], [_gauss(2.0, 0.0)]]])  # (B=1, M=2, T=1, 5)
    log_w = torch.log(torch.tensor([[0.75, 0.25]]))
    y = torch.zeros(1, 1, 2)
    want = LOG_2PI - math.log(0.75 + 0.25 * math.exp(-2.0))
    assert float(mixture_nll(params, log_w, y)) == pytest.approx(want, abs=1e-6)
    # two steps: the modes are whole trajectories, the product over steps is inside the sum:
    # mode 0 misses by 1 m at step 2 only, mode 1 by 1 m at step 1 only -> both exp(-1/2) N(0)^2
    params = torch.tensor([[[_gauss(0.0, 0.0), _gauss(1.0, 0.0)], [_gauss(0.0, 1.0), _gauss(0.0, 0.0)]]])
    y = torch.zeros(1, 2, 2)
    want2 = -(math.log(0.75 * math.exp(-0.5) + 0.25 * math.exp(-0.5)) - 2 * LOG_2PI) / 2  # per point
    assert float(mixture_nll(params, log_w, y)) == pytest.approx(want2, abs=1e-6)
    # a masked step counts for nothing: only step 1, where mode 0 is exact and mode 1 1 m off
    mask = torch.tensor([[True, False]])
    want3 = LOG_2PI - math.log(0.75 + 0.25 * math.exp(-0.5))
    assert float(mixture_nll(params, log_w, y, mask)) == pytest.approx(want3, abs=1e-6)


def test_one_mode_mixture_nll_is_the_gaussian_nll():
    g = torch.Generator().manual_seed(3)
    params = torch.cat([torch.randn(4, 1, 6, 2, generator=g), torch.rand(4, 1, 6, 2, generator=g) + 0.5,
                        0.5 * torch.rand(4, 1, 6, 1, generator=g)], -1)
    y = torch.randn(4, 6, 2, generator=g)
    mask = torch.rand(4, 6, generator=g) > 0.3
    a = mixture_nll(params, torch.zeros(4, 1), y, mask)
    b = bivariate_nll(params[:, 0], y, mask)
    assert float(a) == pytest.approx(float(b), rel=1e-6)
    # and the numpy twin of the evaluation, per point
    p_np, y_np = params.numpy().astype(float), y.numpy().astype(float)
    np.testing.assert_allclose(mixture_nll_points(p_np, np.ones((4, 1)), y_np), nll_points(p_np[:, 0], y_np), rtol=1e-12)


def test_winner_takes_all_warm_up_by_hand():
    # the truth lies on mode 1 (weight 0.2): its squared error 0 counts, plus -log 0.2
    params = torch.tensor([[[_gauss(3.0, 4.0)] * 2, [_gauss(0.0, 0.0)] * 2]])  # mode 0 is 5 m off
    log_w = torch.log(torch.tensor([[0.8, 0.2]]))
    assert float(winner_mse(params, log_w, torch.zeros(1, 2, 2))) == pytest.approx(-math.log(0.2), abs=1e-6)
    # the truth 1 m from mode 0 and 4 m from mode 1: mode 0 wins, 1 m^2 + -log 0.8
    y = torch.tensor([[[3.0, 3.0], [3.0, 3.0]]])
    assert float(winner_mse(params, log_w, y)) == pytest.approx(1.0 - math.log(0.8), abs=1e-6)


def _model(modes: int, seed: int = 0) -> TrajectoryLSTM:
    torch.manual_seed(seed)
    m = TrajectoryLSTM(kind="map_cslstm", nbr_frame="agent", modes=modes).eval()
    with torch.no_grad():  # make the means and the weights depend on the inputs
        m.output.weight.normal_(0.0, 0.1)
        if modes > 1:
            m.mode_head.weight.normal_(0.0, 0.3)
    return m


def test_forward_gives_the_most_likely_mode_and_modes_survive_the_file(tmp_path):
    m = _model(3)
    obs = make_observation(12)
    pred = LSTMPredictor(m, {"kind": "map_cslstm"}, map_source=lane_source(obs))
    mean, cov, w = pred.mode_outputs(obs)
    assert mean.shape == (12, 3, 20, 2) and cov.shape == (12, 3, 20, 2, 2) and w.shape == (12, 3)
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-9)
    assert np.all(np.diff(w, axis=1) <= 0.0)  # most likely first
    assert not np.allclose(w, 1.0 / 3.0, atol=1e-3)  # the weights depend on the scene
    main, _ = pred.model_outputs(obs)
    np.testing.assert_array_equal(main, mean[:, 0])
    path = save_model(m, tmp_path / "m3.pt")
    m2, header = load_model(path)
    assert m2.modes == 3 and header["config"]["modes"] == 3
    mean2, _, w2 = LSTMPredictor(m2, header, map_source=lane_source(obs)).mode_outputs(obs)
    np.testing.assert_array_equal(mean2, mean)
    np.testing.assert_array_equal(w2, w)
    # a one-mode model's file has no "modes" entry (older files read as one mode)
    assert "modes" not in load_model(save_model(_model(1), tmp_path / "m1.pt"))[1]["config"]


def test_prediction_carries_every_mode_with_its_weight():
    m = _model(3, seed=1)
    obs = make_observation(8)
    lp = LSTMPredictor(m, {"kind": "map_cslstm"}, map_source=lane_source(obs))
    p = lp.predict(obs, horizon_steps=40, dt=0.1)
    assert p.n_modes == 3 and p.weight.shape == (8, 3)
    mean, _, w = lp.mode_outputs(obs)
    np.testing.assert_array_equal(p.weight, w)
    # at 0.2 s (horizon step 1 of 0.1 s) every mode lies halfway between now and its first model step
    for k, (mode, _) in enumerate(p.by_mode()):
        np.testing.assert_allclose(mode.mean[:, 1], mean[:, k, 0], atol=1e-9)
        np.testing.assert_allclose(mode.mean[:, 0], 0.5 * (obs.current.xy + mean[:, k, 0]), atol=1e-9)
    # a one-mode model still gives a plain prediction
    q = LSTMPredictor(_model(1), {"kind": "map_cslstm"}, map_source=lane_source(obs)).predict(obs, 40, 0.1)
    assert q.n_modes == 1 and q.weight is None and q.alternatives == ()


def test_evaluation_metrics_of_a_mixture_by_hand():
    # one sample standing at (0, 0) for the 20 steps; mode 0 (0.6) at (1, 0), mode 1 (0.4) at
    # (0, 0), sigma 1 m, at every step
    params = np.array([[[_gauss(1.0, 0.0)] * 20, [_gauss(0.0, 0.0)] * 20]])
    w = np.array([[0.6, 0.4]])
    out = metrics(params, np.zeros((1, 20, 2)), np.ones((1, 20), bool), w)
    assert out["ade"] == pytest.approx(1.0)  # the most likely mode
    assert out["min_ade"] == pytest.approx(0.0)  # the closest mode
    assert out["nll"] == pytest.approx(LOG_2PI - math.log(0.6 * math.exp(-0.5) + 0.4), abs=1e-12)
    assert out["in_1sigma"] == 1.0  # (1 m from mode 0 with sigma 1: on its 1-sigma ellipse)


def test_improvement_summary_names_models_given_by_the_user():
    import pandas as pd

    from sumo_ethics.predict.accuracy import improvement_summary

    df = pd.DataFrame({"model": ["constant_velocity", "constant_velocity_calibrated", "mine"],
                       "group": ["vehicle"] * 3, "ade": [2.0, 2.0, 1.5]})
    text = improvement_summary(df)
    # 1 - 1.5 / 2.0 = 25 % below constant velocity; the calibrated CV is a reference, not a model
    assert "- vehicle: mine +25.0% vs constant velocity" in text and "calibrated +" not in text


def test_winner_takes_all_skips_modes_a_target_may_not_have():
    # the truth lies on mode 1, but mode 1 has weight 0 (log -inf, e.g. a pedestrian with one
    # mode): mode 0, 5 m off at both steps, wins: 25 m^2 and -log 1 = 0
    params = torch.tensor([[[_gauss(3.0, 4.0)] * 2, [_gauss(0.0, 0.0)] * 2]])
    log_w = torch.tensor([[0.0, -math.inf]])
    assert float(winner_mse(params, log_w, torch.zeros(1, 2, 2))) == pytest.approx(25.0, abs=1e-5)


def _options_model(seed: int = 0, **kw) -> TrajectoryLSTM:
    torch.manual_seed(seed)
    m = TrajectoryLSTM(kind="map_cslstm", nbr_frame="agent", modes=3, **kw).eval()
    with torch.no_grad():
        m.output.weight.normal_(0.0, 0.3)
        m.output.bias.normal_(0.0, 0.3)
        m.mode_head.weight.normal_(0.0, 0.3)
    return m


def _forward_all(m: TrajectoryLSTM, groups: list[int]):
    g = torch.Generator().manual_seed(5)
    b = len(groups)
    hist = torch.cumsum(0.2 * torch.randn(b, 16, 2, generator=g), 1)
    empty = torch.zeros(0, dtype=torch.long)
    out, log_w = m(hist, torch.tensor(groups), torch.zeros(0, 16, 2), empty, empty, empty, nbr_yaw=torch.zeros(0),
                   all_modes=True)
    return hist, out, log_w


def test_constant_velocity_mode_and_one_mode_pedestrians():
    from sumo_ethics.predict import features as F

    groups = [F.GROUP_VEHICLE, F.GROUP_CYCLIST, F.GROUP_PEDESTRIAN, F.GROUP_VEHICLE]
    m = _options_model(cv_mode=True, single_mode_groups=(F.GROUP_PEDESTRIAN,))
    hist, out, log_w = _forward_all(m, groups)
    # the last mode of a vehicle or cyclist is the last 0.2 s displacement repeated: k * v at step k
    v = hist[:, -1] - hist[:, -2]
    k = torch.arange(1, 21, dtype=torch.float32)[:, None]
    for i in (0, 1, 3):
        torch.testing.assert_close(out[i, 2, :, :2], k * v[i], rtol=0, atol=1e-6)
    # a pedestrian decodes absolute positions: its constant-velocity mode stands still (and it
    # has weight 0 anyway); the free modes are not constant velocity
    assert float(out[2, 2, :, :2].detach().abs().max()) == 0.0
    assert float((out[0, 0, :, :2] - k * v[0]).detach().abs().max()) > 1e-3
    # the pedestrian has mode 0 only, with weight 1; the others keep learned weights
    assert log_w[2].tolist() == [0.0, -math.inf, -math.inf]
    assert torch.isfinite(log_w[[0, 1, 3]]).all()
    torch.testing.assert_close(log_w[[0, 1, 3]].exp().sum(-1), torch.ones(3))
    # the losses stay finite and so do their gradients
    m.train()
    _, out, log_w = _forward_all(m, groups)
    y = torch.zeros(4, 20, 2)
    loss = mixture_nll(out, log_w, y) + winner_mse(out, log_w, y)
    loss.backward()
    assert torch.isfinite(loss) and all(torch.isfinite(p.grad).all() for p in m.parameters() if p.grad is not None)


def test_stay_mode_pedestrians():
    """A stay group gets mode 0 and a last mode whose mean is exactly where it stands (spread
    sigma_min), both weights learned; the middle mode has weight 0. Other groups keep all modes as without the option."""
    from sumo_ethics.predict import features as F

    groups = [F.GROUP_VEHICLE, F.GROUP_PEDESTRIAN, F.GROUP_CYCLIST, F.GROUP_PEDESTRIAN]
    m = _options_model(stay_mode_groups=(F.GROUP_PEDESTRIAN,))
    _, out, log_w = _forward_all(m, groups)
    plain = _options_model()  # the same weights without the option
    _, out0, log_w0 = _forward_all(plain, groups)
    for i in (1, 3):
        assert float(out[i, 2, :, :2].detach().abs().max()) == 0.0  # stays: mean 0 at every step
        assert torch.equal(out[i, 2, :, 2:], torch.tensor([[m.sigma_min, m.sigma_min, 0.0]] * 20))  # spread fixed
        assert log_w[i, 1].item() == -math.inf and torch.isfinite(log_w[i, [0, 2]]).all()
        # mode 0 and the stay mode share the weight the plain model gives modes 0 and 2
        w0 = log_w0[i, [0, 2]].exp()
        torch.testing.assert_close(log_w[i, [0, 2]].exp(), w0 / w0.sum())
        torch.testing.assert_close(out[i, :2], out0[i, :2])  # mode 0's mean (and mode 1) untouched
    # vehicles and cyclists: bit for bit the model without the option
    assert torch.equal(out[[0, 2]], out0[[0, 2]]) and torch.equal(log_w[[0, 2]], log_w0[[0, 2]])
    # a standing pedestrian whose truth is to stay: the mixture NLL and the warm-up stay finite,
    # and the warm-up picks the stay mode for it (mode 0's mean is elsewhere)
    m.train()
    _, out, log_w = _forward_all(m, groups)
    y = torch.zeros(4, 20, 2)
    per_mode = ((out[..., :2] - y[:, None]) ** 2).sum(-1).mean(-1).masked_fill(torch.isinf(log_w), math.inf)
    assert per_mode.argmin(-1)[[1, 3]].tolist() == [2, 2]
    loss = mixture_nll(out, log_w, y) + winner_mse(out, log_w, y)
    loss.backward()
    assert torch.isfinite(loss) and all(torch.isfinite(p.grad).all() for p in m.parameters() if p.grad is not None)
    # a residual-decoded group can stay too: its stay mode is 0, not the constant-velocity rollout
    hist, out, _ = _forward_all(_options_model(stay_mode_groups=(F.GROUP_VEHICLE,)), groups)
    assert float(out[0, 2, :, :2].detach().abs().max()) == 0.0 and float((hist[0, -1] - hist[0, -2]).abs().max()) > 0
    with pytest.raises(ValueError, match="both"):
        TrajectoryLSTM(kind="map_cslstm", modes=3, single_mode_groups=(2,), stay_mode_groups=(2,))


def test_stay_mode_only_while_standing():
    """With stay_speed, a stay group's target at or above that speed over its last 0.2 s (pedestrian
    scale 2 m: 0.5 m/s is 0.05 normalised) gets mode 0 alone; a slower one keeps mode 0 and the stay
    mode as without the gate; other groups are untouched."""
    from sumo_ethics.predict import features as F

    groups = [F.GROUP_PEDESTRIAN, F.GROUP_PEDESTRIAN, F.GROUP_PEDESTRIAN, F.GROUP_VEHICLE, F.GROUP_CYCLIST]
    gated = _options_model(stay_mode_groups=(F.GROUP_PEDESTRIAN, F.GROUP_CYCLIST), stay_speed=0.5)
    free = _options_model(stay_mode_groups=(F.GROUP_PEDESTRIAN, F.GROUP_CYCLIST))  # the same weights, no gate
    hist = torch.zeros(5, 16, 2)
    # last steps: pedestrians 0.04 (0.4 m/s: stands) and 0.06 (0.6 m/s: walks) x 2 m, and exactly 0.5 m/s;
    # vehicle 1.0 x 5 m over 0.2 s = 25 m/s; cyclist 0.02 x 5 m = 0.5 m/s (its scale is 5 m too)
    hist[0, -1] = torch.tensor([0.04, 0.0])
    hist[1, -1] = torch.tensor([0.0, 0.06])
    hist[2, -1] = torch.tensor([0.05, 0.0])  # 0.05 x 2 m / 0.2 s = 0.5 m/s exactly (in float32 too): moving
    hist[3, -1] = torch.tensor([1.0, 0.0])
    hist[4, -1] = torch.tensor([0.0, 0.01])  # 0.01 x 5 m / 0.2 s = 0.25 m/s: stands
    assert gated.pos_scale.tolist()[F.GROUP_PEDESTRIAN] == 2.0 and gated.pos_scale.tolist()[F.GROUP_CYCLIST] == 5.0
    empty = torch.zeros(0, dtype=torch.long)
    args = (hist, torch.tensor(groups), torch.zeros(0, 16, 2), empty, empty, empty)
    out, log_w = gated(*args, nbr_yaw=torch.zeros(0), all_modes=True)
    out0, log_w0 = free(*args, nbr_yaw=torch.zeros(0), all_modes=True)
    assert torch.equal(out, out0)  # the gate changes weights only
    assert log_w[1].tolist() == log_w[2].tolist() == [0.0, -math.inf, -math.inf]
    for i in (0, 4):
        assert torch.equal(log_w[i], log_w0[i]) and torch.isfinite(log_w[i, [0, 2]]).all()
    assert torch.equal(log_w[3], log_w0[3])
    with pytest.raises(ValueError, match="stay_speed"):
        TrajectoryLSTM(kind="map_cslstm", modes=3, stay_speed=0.5)
    with pytest.raises(ValueError, match="stay_speed"):
        TrajectoryLSTM(kind="map_cslstm", modes=3, stay_mode_groups=(2,), stay_speed=0.0)


def test_model_options_survive_the_file_and_reach_the_prediction(tmp_path):
    from sumo_ethics.predict import features as F

    m = _options_model(seed=2, dec=64, cv_mode=True, single_mode_groups=(F.GROUP_PEDESTRIAN,))
    m2, header = load_model(save_model(m, tmp_path / "opt.pt"))
    assert (m2.dec_size, m2.cv_mode, m2.single_mode_groups) == (64, True, (F.GROUP_PEDESTRIAN,))
    assert header["config"]["dec"] == 64
    obs = make_observation(16)  # its first two agents are pedestrians
    p = LSTMPredictor(m2, header, map_source=lane_source(obs)).predict(obs, 20, 0.1)
    np.testing.assert_array_equal(p.weight[:2], [[1.0, 0.0, 0.0]] * 2)
    assert np.all(p.weight[2:, 0] < 1.0)
    # the default options leave the file's config as before
    cfg = load_model(save_model(_model(3), tmp_path / "plain.pt"))[1]["config"]
    assert not {"dec", "cv_mode", "single_mode_groups", "stay_mode_groups"} & set(cfg)
    # a stay group survives the file and reaches the prediction: the pedestrians' middle mode weight 0
    m3, header = load_model(save_model(_options_model(stay_mode_groups=(F.GROUP_PEDESTRIAN,)), tmp_path / "stay.pt"))
    assert m3.stay_mode_groups == (F.GROUP_PEDESTRIAN,) and m3.stay_speed is None
    assert "stay_speed" not in header["config"]
    gated = _options_model(stay_mode_groups=(F.GROUP_PEDESTRIAN,), stay_speed=0.5)
    assert load_model(save_model(gated, tmp_path / "gated.pt"))[0].stay_speed == 0.5
    p = LSTMPredictor(m3, header, map_source=lane_source(obs)).predict(obs, 20, 0.1)
    assert np.all((p.weight[:2] == 0.0).sum(1) == 1) and np.all(p.weight[2:] > 0.0)  # modes by falling weight
    # in the world frame the stay mode sits on the pedestrian now, spread 0.01 x 2 m (pedestrian scale)
    mean, cov, w = LSTMPredictor(m3, header, map_source=lane_source(obs)).mode_outputs(obs)
    for i in (0, 1):
        k = int(np.flatnonzero(np.all(np.abs(mean[i, :, :, :] - obs.current.xy[i]) < 1e-9, axis=(1, 2)))[0])
        assert w[i, k] > 0.0
        np.testing.assert_allclose(cov[i, k], np.broadcast_to(np.eye(2) * 0.02**2, cov[i, k].shape), atol=1e-12)


def test_min_ade_ignores_modes_of_weight_zero():
    # mode 1 sits on the truth but has weight 0: the closest mode that counts is mode 0, 1 m off
    params = np.array([[[_gauss(1.0, 0.0)] * 20, [_gauss(0.0, 0.0)] * 20]])
    out = metrics(params, np.zeros((1, 20, 2)), np.ones((1, 20), bool), np.array([[1.0, 0.0]]))
    assert out["min_ade"] == pytest.approx(1.0) and out["ade"] == pytest.approx(1.0)
    assert out["nll"] == pytest.approx(LOG_2PI + 0.5, abs=1e-12)


def test_selection_score_by_hand():
    """Mean over (table, class) of ADE / constant velocity's ADE, classes under min_samples left out."""
    import pandas as pd

    from sumo_ethics.predict.accuracy import selection_scores

    def table(rows):
        return pd.DataFrame([{"model": m, "group": g, "ade": a, "n": n} for m, g, a, n in rows])

    val = table([("constant_velocity", "vehicle", 1.0, 900), ("constant_velocity", "cyclist", 0.4, 600),
                 ("constant_velocity", "pedestrian", 0.2, 100), ("constant_velocity_calibrated", "vehicle", 1.0, 900),
                 ("a", "vehicle", 0.6, 900), ("a", "cyclist", 0.3, 600), ("a", "pedestrian", 0.01, 100),
                 ("b", "vehicle", 0.7, 900), ("b", "cyclist", 0.2, 600), ("b", "pedestrian", 0.3, 100),
                 ("a", "all", 0.0, 1600)])
    sel = table([("constant_velocity", "vehicle", 0.5, 700), ("a", "vehicle", 0.6, 700), ("b", "vehicle", 0.4, 700)])
    out = selection_scores({"val": val, "sel": sel})
    # a: (0.6 + 0.75 + 1.2) / 3 = 0.85; b: (0.7 + 0.5 + 0.8) / 3 = 0.6667 (pedestrians: 100 < 500 samples)
    assert list(out.index) == ["b", "a"]
    assert list(out.columns) == ["val:vehicle", "val:cyclist", "sel:vehicle", "score"]
    assert out.loc["a", "score"] == pytest.approx(0.85)
    assert out.loc["b", "score"] == pytest.approx(2.0 / 3.0)
