"""Prediction: features, models, NLL, predictors, weight files (fast, no SUMO)."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from sumo_ethics.types import AgentStates, Observation, RoadUserClass

torch = pytest.importorskip("torch")

from sumo_ethics.predict import PredictorError  # noqa: E402
from sumo_ethics.predict import features as F  # noqa: E402
from sumo_ethics.predict.constant_velocity import ConstantVelocityPredictor  # noqa: E402
from sumo_ethics.predict.samples import samples_from_run, subset  # noqa: E402
from sumo_ethics.predict.models import (  # noqa: E402
    TrajectoryLSTM,
    batch_to_tensors,
    bivariate_nll,
    bivariate_nll_terms,
    masked_mse,
    save_model,
)
from sumo_ethics.predict.predictor import LSTMPredictor, default_weights  # noqa: E402

from conftest import sumo_binary  # noqa: E402


def states(xy, yaw, speed, cls, prefix="a") -> AgentStates:
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    n = len(xy)
    z = np.zeros(n)
    return AgentStates(tuple(f"{prefix}{i}" for i in range(n)), xy[:, 0], xy[:, 1], np.asarray(yaw, float) + z,
                       np.asarray(speed, float) + z, z, z + 4.5, z + 1.8, z + 1500, (np.asarray(cls) + z).astype(np.int8))


def straight_obs(speed=10.0, yaw=0.0, dt=0.1, hist_s=3.0, cls=RoadUserClass.CAR, x0=(0.0, 0.0)) -> Observation:
    h = int(round(hist_s / dt)) + 1
    t = (np.arange(h) - (h - 1)) * dt
    d = np.array([math.cos(yaw), math.sin(yaw)])
    hist = np.asarray(x0)[None, :] + t[:, None] * speed * d[None, :]
    cur = states(x0, yaw, speed, int(cls))
    ego = states((x0[0] - 60.0, x0[1] - 60.0), 0.0, 0.0, int(RoadUserClass.CAR), prefix="ego")
    return Observation(0.0, dt, hist[None], np.ones((1, h), dtype=bool), cur, ego)


# ---------------------------------------------------------------- import cost
def test_import_predict_does_not_import_torch():
    code = "import sys, sumo_ethics.predict as p; p.PredictorError; assert 'torch' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True, cwd=Path(__file__).resolve().parents[2])


# ---------------------------------------------------------------- features
def test_grid_cell_in_target_frame():
    # target at origin heading north; neighbour 10 m ahead (north) -> lon +10 m, lat 0
    hist = np.zeros((2, F.HIST_STEPS, 2))
    hist[1, :, 1] = 10.0
    feats = F.build_features(hist, np.array([0, 0]), np.array([math.pi / 2, 0.0]), targets=np.array([0]))
    assert feats["nbr_agent"].tolist() == [1]
    lon = int(10.0 / 4.6 + 6.5)  # 8
    assert feats["nbr_cell"].tolist() == [lon * F.GRID_LAT + 1]
    np.testing.assert_allclose(feats["nbr_hist"][0, -1], [10.0, 0.0], atol=1e-5)


def test_resample_history_rates_agree():
    o1 = straight_obs(dt=0.1)
    o2 = straight_obs(dt=1.0)
    h1, v1 = F.resample_history(o1.history, o1.valid, 0.1)
    h2, v2 = F.resample_history(o2.history, o2.valid, 1.0)
    np.testing.assert_allclose(h1, h2, atol=1e-9)
    np.testing.assert_allclose(h1[0, 0], [-30.0, 0.0], atol=1e-9)
    assert v1.all() and v2.all()


def test_backfill_extrapolates_backwards():
    hist = np.zeros((1, 5, 2))
    hist[0, 2:, 0] = [0.0, 1.0, 2.0]
    valid = np.array([[False, False, True, True, True]])
    np.testing.assert_allclose(F.backfill(hist, valid)[0, :, 0], [-2, -1, 0, 1, 2])


def test_samples_from_synthetic_run():
    t = np.round(np.arange(0, 10.0, 0.1), 3)
    df = pd.DataFrame({"time": t, "agent_id": "v", "cls": 0, "x": 5.0 * t, "y": 0.0, "yaw": 0.0, "speed": 5.0})
    s = samples_from_run(df, anchor_every=1.0)
    assert len(s["tgt_hist"]) > 0
    np.testing.assert_allclose(s["fut"][0, :, 0], 5.0 * F.MODEL_DT * (np.arange(F.FUT_STEPS) + 1), atol=1e-4)
    np.testing.assert_allclose(s["tgt_hist"][0, -1], [0, 0], atol=1e-5)
    assert s["nbr_count"].sum() == 0


def test_add_train_samples_takes_only_the_extra_training_samples_of_the_groups():
    from sumo_ethics.predict.samples import add_train_samples

    # base: 2 samples with 1 and 2 neighbours; extra: 4 samples (vehicle/cyclist/pedestrian in
    # train, a cyclist in val) with 1, 0, 2 and 1 neighbours, told apart by their nbr_cell
    base = {"split": np.array([0, 1], np.int8), "tgt_group": np.array([0, 2]), "tgt_speed": np.float32([1, 2]),
            "nbr_cell": np.array([10, 20, 21]), "nbr_ptr": np.array([0, 1, 3])}
    extra = {"split": np.array([0, 0, 0, 1], np.int8), "tgt_group": np.array([0, 1, 2, 1]),
             "tgt_speed": np.float64([3, 4, 5, 6]), "nbr_cell": np.array([30, 50, 51, 60]),
             "nbr_ptr": np.array([0, 1, 1, 3, 4])}
    out = add_train_samples(base, extra, (1, 2))
    # the cyclist (no neighbour) and the pedestrian (2) of the training split, after the base's
    np.testing.assert_array_equal(out["tgt_speed"], [1, 2, 4, 5])
    assert out["tgt_speed"].dtype == np.float32  # the base's dtypes
    np.testing.assert_array_equal(out["split"], [0, 1, 0, 0])
    np.testing.assert_array_equal(out["nbr_cell"], [10, 20, 21, 50, 51])
    np.testing.assert_array_equal(out["nbr_ptr"], [0, 1, 3, 3, 5])
    np.testing.assert_array_equal(subset(out, np.array([3]))["nbr_cell"], [50, 51])
    assert len(add_train_samples(base, extra)["split"]) == 5  # all groups: the three training samples
    with pytest.raises(ValueError, match="nbr_yaw in one only"):
        add_train_samples(base, {**extra, "nbr_yaw": np.zeros(4)})


# ---------------------------------------------------------------- NLL
def test_nll_matches_torch_distributions():
    g = torch.Generator().manual_seed(0)
    n = 64
    mu = torch.randn(n, 2, generator=g)
    sig = torch.rand(n, 2, generator=g) * 2 + 0.1
    rho = torch.rand(n, 1, generator=g) * 1.8 - 0.9
    x = torch.randn(n, 2, generator=g) * 2
    params = torch.cat([mu, sig, rho], -1)
    cov = torch.stack([
        torch.stack([sig[:, 0] ** 2, rho[:, 0] * sig[:, 0] * sig[:, 1]], -1),
        torch.stack([rho[:, 0] * sig[:, 0] * sig[:, 1], sig[:, 1] ** 2], -1),
    ], -2)
    ref = -torch.distributions.MultivariateNormal(mu, covariance_matrix=cov).log_prob(x)
    torch.testing.assert_close(bivariate_nll_terms(params, x), ref, rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(bivariate_nll(params, x), ref.mean(), rtol=1e-4, atol=1e-4)
    mask = torch.arange(n) < 10
    torch.testing.assert_close(bivariate_nll(params, x, mask), ref[:10].mean(), rtol=1e-4, atol=1e-4)


# ---------------------------------------------------------------- models
def random_batch(b=3, p=5, seed=0):
    g = torch.Generator().manual_seed(seed)
    return {
        "tgt_hist": torch.randn(b, F.HIST_STEPS, 2, generator=g),
        "tgt_group": torch.tensor([0, 1, 2][:b] + [0] * max(0, b - 3)),
        "nbr_hist": torch.randn(p, F.HIST_STEPS, 2, generator=g),
        "nbr_group": torch.zeros(p, dtype=torch.long),
        "nbr_batch": torch.tensor([0, 0, 1, 0, 1][:p]),
        "nbr_cell": torch.tensor([3, 20, 7, 33, 19][:p]),
    }


@pytest.mark.parametrize("kind", ["cslstm", "attention"])
def test_model_shapes_and_padding(kind):
    torch.manual_seed(0)
    model = TrajectoryLSTM(kind).eval()
    x = random_batch()
    with torch.no_grad():
        out = model(**x)
        assert out.shape == (3, F.FUT_STEPS, 5)
        assert (out[..., 2:4] > 0).all() and (out[..., 4].abs() < 1).all()
        # a padded (invalid) neighbour, even with garbage history, changes nothing
        xp = dict(x)
        xp["nbr_hist"] = torch.cat([x["nbr_hist"], 100 * torch.ones(1, F.HIST_STEPS, 2)])
        xp["nbr_group"] = torch.cat([x["nbr_group"], torch.tensor([2])])
        xp["nbr_batch"] = torch.cat([x["nbr_batch"], torch.tensor([2])])
        xp["nbr_cell"] = torch.cat([x["nbr_cell"], torch.tensor([5])])
        valid = torch.ones(6, dtype=torch.bool)
        valid[-1] = False
        torch.testing.assert_close(model(**xp, nbr_valid=valid), out)
        # neighbours of one target do not affect another (target 2 has none)
        x2 = dict(x)
        x2["nbr_hist"] = x["nbr_hist"] + 1.0
        out2 = model(**x2)
        torch.testing.assert_close(out2[2], out[2])
        assert not torch.allclose(out2[0], out[0])
        # no neighbours at all
        empty = dict(x, nbr_hist=x["nbr_hist"][:0], nbr_group=x["nbr_group"][:0], nbr_batch=x["nbr_batch"][:0],
                     nbr_cell=x["nbr_cell"][:0])
        assert torch.isfinite(model(**empty)).all()


def test_attention_weights_sum_to_one():
    torch.manual_seed(0)
    model = TrajectoryLSTM("attention")
    x = torch.randn(2, 64)
    h = torch.randn(3, 64)
    batch = torch.tensor([0, 0, 0])
    w = model.attend(x, h, batch)
    assert torch.equal(w[1], torch.zeros(64))  # target without neighbours
    # one neighbour: all weight on it
    torch.testing.assert_close(model.attend(x, h[:1], torch.tensor([1]))[1], h[0])


def tiny_dataset(n=16):
    t = (np.arange(F.HIST_STEPS) - (F.HIST_STEPS - 1)) * F.MODEL_DT
    tf = (np.arange(F.FUT_STEPS) + 1) * F.MODEL_DT
    rng = np.random.default_rng(0)
    v = rng.uniform(2, 12, n)
    a = rng.uniform(-3, 3, n)
    hist = np.stack([v[:, None] * t + 0.5 * a[:, None] * t**2, np.zeros((n, len(t)))], -1)
    fut = np.stack([v[:, None] * tf + 0.5 * a[:, None] * tf**2, 0.3 * a[:, None] * tf**2], -1)
    return {
        "tgt_hist": hist.astype(np.float32), "tgt_group": np.zeros(n, dtype=np.int64), "fut": fut.astype(np.float32),
        "nbr_hist": hist[:4].astype(np.float32) + 5, "nbr_group": np.zeros(4, dtype=np.int64),
        "nbr_cell": np.array([1, 5, 9, 30]), "nbr_ptr": np.concatenate([[0, 1, 2, 3, 4], np.full(n - 4, 4)]),
        "tgt_speed": v.astype(np.float32), "tgt_cls": np.zeros(n, dtype=np.int64),
    }


def test_model_overfits_tiny_dataset():
    torch.manual_seed(0)
    torch.set_num_threads(1)
    data = subset(tiny_dataset(), np.arange(16))
    model = TrajectoryLSTM("attention")
    x = batch_to_tensors(data)
    y = torch.as_tensor(data["fut"]) / model.scale(x["tgt_group"])[:, None, None]
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    first = None
    for _ in range(300):
        loss = masked_mse(model(**x), y)
        first = loss.item() if first is None else first
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert loss.item() < first / 10


# ---------------------------------------------------------------- predictors
def test_constant_velocity_hand_numbers():
    cv = ConstantVelocityPredictor(sigma0=0.1, growth=(0.5, 0.15))
    obs = straight_obs(speed=2.0, yaw=math.pi / 2, x0=(1.0, 2.0))
    p = cv.predict(obs, horizon_steps=2, dt=0.5)
    np.testing.assert_allclose(p.mean[0], [[1.0, 3.0], [1.0, 4.0]], atol=1e-12)
    # heading north: longitudinal std along y, lateral along x
    np.testing.assert_allclose(p.cov[0, 0], [[0.175**2, 0], [0, 0.35**2]], atol=1e-12)
    np.testing.assert_allclose(p.cov[0, 1], [[0.25**2, 0], [0, 0.6**2]], atol=1e-12)
    np.testing.assert_allclose(p.yaw, math.pi / 2)
    assert p.dt == 0.5 and p.ids == ("a0",)
    ped = cv.predict(straight_obs(speed=1.0, cls=RoadUserClass.PEDESTRIAN), 1, 1.0)
    g = cv.growth_pedestrian
    np.testing.assert_allclose(np.diag(ped.cov[0, 0]), [(0.1 + g[0]) ** 2, (0.1 + g[1]) ** 2])
    assert g[1] > cv.growth[1]


@pytest.mark.parametrize("kind", ["attention", "cslstm"])
def test_shipped_weights_car_straight(kind):
    pred = LSTMPredictor.default(kind)
    p = pred.predict(straight_obs(speed=10.0), horizon_steps=60, dt=0.1)
    assert p.mean.shape == (1, 60, 2) and p.cov.shape == (1, 60, 2, 2) and p.yaw.shape == (1, 60)
    assert np.isfinite(p.mean).all() and np.isfinite(p.cov).all()
    assert np.linalg.norm(p.mean[0, 9] - [10.0, 0.0]) < 1.5
    assert (np.linalg.eigvalsh(p.cov) > 0).all()
    # beyond the 4 s model horizon: keeps moving, covariance keeps growing
    assert p.mean[0, 59, 0] > p.mean[0, 39, 0] + 10
    assert np.trace(p.cov[0, 59]) > np.trace(p.cov[0, 39])
    # rotation invariance: same car heading north
    q = pred.predict(straight_obs(speed=10.0, yaw=math.pi / 2), horizon_steps=60, dt=0.1)
    np.testing.assert_allclose(q.mean[0][:, ::-1] * [1, -1], p.mean[0], atol=1e-3)
    # history at another spacing gives about the same answer
    r = pred.predict(straight_obs(speed=10.0, dt=0.5), horizon_steps=60, dt=0.1)
    np.testing.assert_allclose(r.mean, p.mean, atol=0.05)


def test_padded_history_changes_nothing():
    pred = LSTMPredictor.default("attention")
    full = straight_obs(speed=8.0)
    hist = np.array(full.history)
    valid = np.array(full.valid)
    hist[0, :20] = 1e3  # garbage where not observed
    valid[0, :20] = False
    padded = Observation(0.0, 0.1, hist, valid, full.current, full.ego)
    a = pred.predict(full, 40, 0.1)
    b = pred.predict(padded, 40, 0.1)
    np.testing.assert_allclose(b.mean, a.mean, atol=1e-4)
    np.testing.assert_allclose(b.cov, a.cov, atol=1e-6)


def test_predictor_empty_observation():
    pred = LSTMPredictor.default("attention")
    o = straight_obs()
    empty = Observation(0.0, 0.1, np.zeros((0, 31, 2)), np.zeros((0, 31), bool), AgentStates.empty(), o.ego)
    p = pred.predict(empty, 10, 0.1)
    assert p.mean.shape == (0, 10, 2)


def test_missing_corrupt_and_wrong_kind_weights(tmp_path):
    missing = tmp_path / "nope.pt"
    with pytest.raises(PredictorError, match="nope.pt"):
        LSTMPredictor.from_file(missing)
    corrupt = tmp_path / "corrupt.pt"
    corrupt.write_bytes(b"this is not a torch file")
    with pytest.raises(PredictorError, match="corrupt.pt"):
        LSTMPredictor.from_file(corrupt)
    cs = save_model(TrajectoryLSTM("cslstm"), tmp_path / "cs.pt")
    with pytest.raises(PredictorError, match="cs.pt"):
        LSTMPredictor.from_file(cs, kind="attention")
    assert LSTMPredictor.from_file(cs, kind="cslstm").kind == "cslstm"
    blob = torch.load(cs, weights_only=True)
    blob["feature_version"] = 999
    torch.save(blob, tmp_path / "old.pt")
    with pytest.raises(PredictorError, match="old.pt"):
        LSTMPredictor.from_file(tmp_path / "old.pt")
    torch.save({"state_dict": {}}, tmp_path / "foreign.pt")
    with pytest.raises(PredictorError, match="foreign.pt"):
        LSTMPredictor.from_file(tmp_path / "foreign.pt")
    with pytest.raises(PredictorError):
        LSTMPredictor.default("transformer")


def test_default_weights_are_small():
    for kind in ("attention", "cslstm"):
        assert default_weights(kind).stat().st_size < 5e6


def test_path_yaw_holds_the_heading_while_standing():
    """Heading of a predicted path at 0.1 s steps: the direction of each step, held where the
    step is shorter than MIN_YAW_SPEED x dt (0.03 m), and the current yaw until the first move."""
    from sumo_ethics.predict.predictor import path_yaw

    xy = np.array([[0.0, 0.0], [5.0, 5.0]])
    # agent 0: stands 2 steps (0.01 m each), moves +y 1 m, stands, moves -x 1 m, stands
    # agent 1: moves 1 m at 45 degrees, then stands
    steps = np.array([[[0.01, 0.0], [0.0, 0.01], [0.0, 1.0], [0.0, 0.0], [-1.0, 0.0], [0.02, 0.0]],
                      [[1.0, 1.0], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0]]])
    mean = xy[:, None] + np.cumsum(steps, axis=1)
    yaw = path_yaw(xy, np.array([0.3, -2.0]), mean, 0.1)
    half_pi, pi = np.pi / 2, np.pi
    assert yaw[0] == pytest.approx([0.3, 0.3, half_pi, half_pi, pi, pi])
    assert yaw[1] == pytest.approx([pi / 4] * 6)


def test_prediction_breakdown_refuses_bad_input_in_one_line(tmp_path):
    tool = Path(__file__).resolve().parents[2] / "tools" / "prediction_breakdown.py"
    for args, says in (([str(tmp_path)], "no samples.npz"),
                       ([str(tmp_path), "--model", f"x={tmp_path / 'none.pt'}"], "existing weights file"),
                       ([str(tmp_path), "--model", f"x={default_weights('cslstm')}", "--model", f"x={default_weights('map')}"],
                        "given twice")):
        r = subprocess.run([sys.executable, str(tool), *args], capture_output=True, text=True)
        assert r.returncode == 2 and says in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr


@pytest.mark.sumo
def test_long_red_scenario_holds_each_red_119_s(tmp_path):
    """The long-red urban_grid of tools/train_shipped.py: each light's greens of 30 s or more three times as
    long (37 -> 111 s; the 5 s green and the 3 s yellow kept), so a red holds 111 + 5 + 3 = 119 s.
    SUMO runs the config with that program: J00's link 4 (red in the first three phases) is red
    from 0 to 119 s, green from then until 119 + 111 + 5 = 235 s, then yellow for 3 s."""
    import xml.etree.ElementTree as ET


    from sumo_ethics.recording.long_red import long_red_scenario

    root = Path(__file__).resolve().parents[2]
    cfg = long_red_scenario(tmp_path / "scen", root / "networks" / "urban_grid" / "urban_grid.net.xml",
                            root / "scenarios" / "urban_grid" / "urban_grid.rou.xml")
    add = ET.parse(cfg.with_name("urban_grid_long_red.add.xml")).getroot()
    durations = {tl.get("id"): [float(p.get("duration")) for p in tl.iter("phase")] for tl in add.iter("tlLogic")}
    assert durations == {j: [111, 5, 3, 111, 5, 3] for j in ("J00", "J01", "J10", "J11")}
    (tmp_path / "save.add.xml").write_text(
        f'<additional><timedEvent type="SaveTLSStates" source="J00" dest="{tmp_path / "tls.xml"}"/></additional>')
    subprocess.run([sumo_binary("sumo"), "-c", str(cfg), "--end", "240", "--step-length", "1",
                    "--additional-files", f"{cfg.with_name('urban_grid_long_red.add.xml')},{tmp_path / 'save.add.xml'}",
                    "--no-step-log", "--no-warnings"], check=True, capture_output=True)
    states = {float(e.get("time")): e.get("state") for e in ET.parse(tmp_path / "tls.xml").getroot().iter("tlsState")}
    red = [t for t, st in sorted(states.items()) if st[4] == "r"]
    assert red[0] == 0.0 and max(t for t in red if t < 200) == 118.0  # red 0-119 s
    assert all(states[t][4] in "gG" for t in np.arange(119.0, 235.0)) and states[235.0][4] == "y"
    assert states[238.0][4] == "r"


def test_prediction_breakdown_red_and_truth_subsets():
    """The subsets by how long a red holds and by where the future really ends, on four samples
    worked out by hand: red holding 2 s (ends within 4 s), red holding 30 s (clipped at 20 s:
    8 s or more), green, and no light; futures ending 0.3, 0.6 (then invalid) and 0 m away."""
    from sumo_ethics.predict.breakdown import subsets

    sc = np.zeros((4, 10), dtype=np.float32)
    sc[:3, 1] = 1.0  # a light ahead for the first three
    sc[0, 5], sc[0, 7] = 1.0, 2.0 / F.TLS_SWITCH_SCALE  # red, holds 2 s
    sc[1, 5], sc[1, 7] = 1.0, 2.0  # red, holds 20 s or more (the clip)
    sc[2, 3], sc[2, 7] = 1.0, 0.5  # green, holds 5 s
    fut = np.zeros((4, 20, 2), dtype=np.float32)
    fut[0, -1] = [0.3, 0.0]  # ends 0.3 m away
    fut[1, 4] = [0.0, 0.6]  # 0.6 m at its last valid point (the points after it are invalid)
    fut[2, -1] = [0.3, 0.4]  # 0.5 m: within
    valid = np.ones((4, 20), dtype=bool)
    valid[1, 5:] = False
    b = {"map_scalar": sc, "tgt_speed": np.zeros(4, dtype=np.float32), "manoeuvre": np.zeros(4, dtype=np.int8),
         "fut": fut, "fut_valid": valid}
    got = subsets(b)
    assert got["red ahead, ends within 4 s"].tolist() == [True, False, False, False]
    assert got["red ahead, holds 8 s or more"].tolist() == [False, True, False, False]
    assert got["truth: ends within 0.5 m"].tolist() == [True, False, True, True]
    assert got["truth: ends over 0.5 m away"].tolist() == [False, True, False, False]
    b["map_scalar"] = sc[:, :7]  # a map version 1-2 dataset: 7 scalars, no switch time
    assert "red ahead, holds 8 s or more" not in subsets(b)


def test_pedestrian_speed_scale_in_training():
    """TrainConfig.ped_speed_scale: pedestrians' histories and futures scaled about their current
    position, the other classes untouched; the loss is that of the samples scaled by hand."""
    from sumo_ethics.predict.train import _loss, speed_factors

    group = np.array([F.GROUP_VEHICLE, F.GROUP_PEDESTRIAN, F.GROUP_CYCLIST, F.GROUP_PEDESTRIAN])
    assert speed_factors(group, (1.25, 1.25), np.random.default_rng(0)).tolist() == [1.0, 1.25, 1.0, 1.25]
    k = speed_factors(np.full(1000, F.GROUP_PEDESTRIAN), (0.8, 1.4), np.random.default_rng(0))
    assert 0.8 <= k.min() < 0.82 and 1.38 < k.max() <= 1.4  # log-uniform: the median at sqrt(0.8 * 1.4)
    assert np.median(k) == pytest.approx(math.sqrt(0.8 * 1.4), rel=0.03)
    data = tiny_dataset(8)
    data["tgt_group"][[1, 3]] = F.GROUP_PEDESTRIAN
    data["tgt_cls"][[1, 3]] = int(RoadUserClass.PEDESTRIAN)
    factor = np.array([1, 1.25, 1, 0.8, 1, 1, 1, 1])
    by_hand = dict(data, tgt_hist=data["tgt_hist"] * factor[:, None, None].astype(np.float32),
                   fut=data["fut"] * factor[:, None, None].astype(np.float32))
    torch.manual_seed(0)
    model = TrajectoryLSTM("cslstm")
    idx = np.arange(8)
    with torch.no_grad():
        scaled = _loss(model, data, idx, use_nll=True, factor=factor)
        assert scaled.item() == _loss(model, by_hand, idx, use_nll=True).item()
        assert scaled.item() != _loss(model, data, idx, use_nll=True).item()
        assert _loss(model, data, idx, True, np.ones(8)).item() == _loss(model, data, idx, True).item()
    np.testing.assert_allclose(by_hand["tgt_hist"][1, -2], data["tgt_hist"][1, -2] * 1.25)  # the step before "now"
