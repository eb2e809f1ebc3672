"""The map models' fast run-time path (nbr_frame="agent"): every agent encoded once in its
own frame and placed by its pose, the decoder's input projection taken once. It must give
what the training path gives on the same scene, be rotation and translation invariant, and
leave the older models' code path untouched."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from sumo_ethics.predict import features as F  # noqa: E402
from sumo_ethics.predict.models import (  # noqa: E402
    TrajectoryLSTM, batch_to_tensors, load_model, lstm_recurrence, save_model,
)
from sumo_ethics.predict.predictor import LSTMPredictor, straight_history  # noqa: E402
from sumo_ethics.types import AgentStates, Observation, RoadUserClass  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
from sumo_ethics.predict.synthetic import lane_source, make_observation  # noqa: E402


def _model(kind: str, seed: int = 0) -> TrajectoryLSTM:
    torch.manual_seed(seed)
    m = TrajectoryLSTM(kind=kind, nbr_frame="agent").eval()
    with torch.no_grad():  # the residual init zeroes the mean head: make the outputs depend on everything
        m.output.weight.normal_(0.0, 0.1)
    return m


def test_neighbour_yaw_in_the_target_frame_by_hand():
    # target 0 heads 170 deg; agent 1 is 10 m ahead of it heading -170 deg: 20 deg in the target's
    # frame (-340 wrapped); agent 2 is 10 m behind heading 100 deg: -70 deg
    yaw = np.radians([170.0, -170.0, 100.0])
    head = np.array([np.cos(yaw[0]), np.sin(yaw[0])])
    now = np.array([[0.0, 0.0], 10.0 * head, -10.0 * head])
    hist = straight_history(now, yaw, np.array([5.0, 5.0, 5.0]))
    f = F.build_features(hist, np.zeros(3, dtype=np.int64), yaw, targets=np.array([0]))
    by_agent = dict(zip(f["nbr_agent"].tolist(), np.degrees(f["nbr_yaw"]).tolist()))
    assert by_agent.keys() == {1, 2}
    assert by_agent[1] == pytest.approx(20.0, abs=1e-4) and by_agent[2] == pytest.approx(-70.0, abs=1e-4)
    # the neighbours' positions now: agent 1 10 m straight ahead, agent 2 10 m behind; the run time
    # (histories=False) gets them without the histories, bit for bit the histories' last points
    np.testing.assert_allclose(f["nbr_pos"][np.argsort(f["nbr_agent"])], [[10.0, 0.0], [-10.0, 0.0]], atol=1e-5)
    np.testing.assert_array_equal(f["nbr_pos"], f["nbr_hist"][:, -1])
    lean = F.build_features(hist, np.zeros(3, dtype=np.int64), yaw, targets=np.array([0]), histories=False)
    assert "nbr_hist" not in lean and "tgt_hist" not in lean
    np.testing.assert_array_equal(lean["nbr_pos"], f["nbr_pos"])
    # own frame: a straight history along its heading is (-5 m/s x t, 0) for every agent
    own = F.own_frame(hist, yaw)
    t = (np.arange(F.HIST_STEPS) - (F.HIST_STEPS - 1)) * F.MODEL_DT
    np.testing.assert_allclose(own[..., 0], np.broadcast_to(5.0 * t, (3, F.HIST_STEPS)), atol=1e-9)
    np.testing.assert_allclose(own[..., 1], 0.0, atol=1e-9)


def _training_path_means(model: TrajectoryLSTM, obs: Observation, source) -> np.ndarray:
    """World-frame means of ``obs``'s agents through model.forward, fed as a dataset sample batch."""
    cur = obs.current
    n = len(cur)
    hist, _ = F.resample_history(obs.history, obs.valid, obs.dt)
    hist = np.concatenate([hist, straight_history(obs.ego.xy, obs.ego.yaw, obs.ego.speed)])
    cls = np.concatenate([cur.cls, obs.ego.cls]).astype(np.int64)
    yaw = np.concatenate([cur.yaw, obs.ego.yaw])
    feats = F.build_features(hist, cls, yaw, targets=np.arange(n))
    graph, ctx = source(cur.ids, feats["tgt_group"] == F.GROUP_PEDESTRIAN)
    x = batch_to_tensors(dict(feats, **F.map_features(graph, ctx, cur.xy, cur.yaw, cur.speed)), model.pos_scale,
                         with_map=True)
    with torch.enable_grad():  # the training path: nn.LSTM decoder, per-pair neighbour rows
        out = model(**x).detach().numpy().astype(float)
    mu = out[..., :2] * F.POS_SCALE[feats["tgt_group"]][:, None, None]
    return cur.xy[:, None, :] + (F.rotation(cur.yaw)[:, None] @ mu[..., None])[..., 0]


@pytest.mark.parametrize("kind", ["map", "map_cslstm"])
def test_scene_path_equals_the_training_path(kind):
    """32 agents with 271 neighbour pairs: encoding each agent once (run time) and each pair in
    its target's frame (training) give the same means to float32 rounding (< 0.1 mm)."""
    m = _model(kind)
    obs = make_observation(32)
    source = lane_source(obs)
    fast, _ = LSTMPredictor(m, {"kind": kind}, map_source=source).model_outputs(obs)
    slow = _training_path_means(m, obs, source)
    assert np.abs(fast - slow).max() < 1e-4


def test_fast_decoder_equals_nn_lstm_and_old_kinds_keep_nn_lstm():
    m = _model("map")
    enc = torch.randn(7, m.decoder.input_size)
    with torch.inference_mode():
        fast = m.decode(enc)
    with torch.enable_grad():
        ref = m.decode(enc).detach()
    assert fast.shape == (7, F.FUT_STEPS, m.decoder.hidden_size)
    assert (fast - ref).abs().max() < 1e-5
    old = TrajectoryLSTM(kind="attention").eval()
    enc = torch.randn(7, old.decoder.input_size)
    with torch.inference_mode():
        h, _ = old.decoder(enc[:, None, :].expand(7, F.FUT_STEPS, enc.shape[-1]))
        assert torch.equal(old.decode(enc), h)



def test_fewer_decoder_steps_emit_every_output_step_in_order(tmp_path):
    """dec_steps=5: each decoder state gives 4 consecutive 0.2 s output steps through its own rows
    of the output layer; an untrained model still starts at constant velocity (mode 0), the run-time
    and the training path agree, the option survives the weights file, and 3 (not a divisor of 20)
    is refused."""
    torch.manual_seed(3)
    m = TrajectoryLSTM(kind="map_cslstm", nbr_frame="agent", modes=3, dec=64, dec_steps=5).eval()
    assert m.output.out_features == 4 * 3 * 5
    b = 4
    hist = torch.cumsum(torch.full((b, F.HIST_STEPS, 2), 0.05), 1)  # 0.05 per model step along x and y
    group = torch.tensor([0, 1, 0, 1])
    none = torch.zeros(0, dtype=torch.long)
    args = (hist, group, torch.zeros(0, F.HIST_STEPS, 2), none, none, none)
    with torch.inference_mode():
        params, _ = m(*args, nbr_yaw=torch.zeros(0), all_modes=True)
    assert params.shape == (b, 3, F.FUT_STEPS, 5)
    steps = torch.arange(1, F.FUT_STEPS + 1, dtype=torch.float32)
    assert torch.allclose(params[:, 0, :, 0], 0.05 * steps.expand(b, -1), atol=1e-6)  # mode 0 = CV
    # output step k comes from decoder state k // 4, rows (k % 4) x 15 .. + 15 of the output layer
    with torch.inference_mode():
        enc = torch.randn(2, m.decoder.input_size)
        h = m.decode(enc)
        assert h.shape == (2, 5, 64)
        out = m.output(h).reshape(2, F.FUT_STEPS, 15)
        w, bias = m.output.weight, m.output.bias
        assert torch.allclose(out[:, 6], h[:, 1] @ w[30:45].t() + bias[30:45], atol=1e-6)
    with torch.enable_grad():
        slow, _ = m(*args, nbr_yaw=torch.zeros(0), all_modes=True)
    assert (slow.detach() - params).abs().max() < 1e-5
    save_model(m, tmp_path / "d5.pt")
    back, header = load_model(tmp_path / "d5.pt")
    assert back.dec_steps == 5 and header["config"]["dec_steps"] == 5
    save_model(TrajectoryLSTM(kind="map_cslstm"), tmp_path / "d20.pt")  # one decoder step per output step:
    assert "dec_steps" not in load_model(tmp_path / "d20.pt")[1]["config"]  # files as before
    with pytest.raises(ValueError, match="dec_steps must divide"):
        TrajectoryLSTM(kind="map_cslstm", dec_steps=3)

def test_decoder_recurrence_first_step_by_hand():
    torch.manual_seed(1)
    pre, w_hh = torch.randn(9, 4 * 16), torch.randn(16, 4 * 16) * 0.3
    with torch.inference_mode():
        h = lstm_recurrence(pre, w_hh, F.FUT_STEPS)
    assert h.shape == (9, F.FUT_STEPS, 16)
    # zero states: c1 = i * g and h1 = o * tanh(c1) with the gates of ``pre`` (rows i, f, g, o)
    i, g, o = torch.sigmoid(pre[:, :16]), torch.tanh(pre[:, 32:48]), torch.sigmoid(pre[:, 48:])
    assert torch.allclose(h[:, 0], o * torch.tanh(i * g), atol=1e-6)


@pytest.mark.parametrize("targets", [1, 5, 32])
def test_social_grid_as_matrix_products_equals_the_convolutions(targets):
    """The run-time social pooling (strided windows x weights) against Conv2d, Conv2d, MaxPool2d
    of the training path, on sparse grids as scenes give them (most cells empty)."""
    m = _model("map_cslstm", seed=3)
    gen = torch.Generator().manual_seed(targets)
    occupied = (torch.rand(targets, F.N_CELLS, 1, generator=gen) < 0.3).float()
    grid = (torch.randn(targets, F.N_CELLS, m.enc_size, generator=gen) * occupied).reshape(targets, -1)
    with torch.inference_mode():
        fast = m.social_fast(grid)
        image = grid.view(targets, F.GRID_LON, F.GRID_LAT, m.enc_size).permute(0, 3, 1, 2)
        ref = m.soc_maxpool(m.act(m.conv_3x1(m.act(m.soc_conv(image))))).reshape(targets, m.soc_size)
    assert fast.shape == (targets, m.soc_size) == (targets, 80)
    with torch.inference_mode():  # no targets: an empty result, as the convolutions give
        assert m.social_fast(grid[:0]).shape == (0, 80)
    assert (fast - ref).abs().max() < 1e-5 * max(1.0, float(ref.abs().max()))
    assert not torch.equal(fast[0], torch.zeros_like(fast[0]))


def _rotated(obs: Observation, angle: float, shift: np.ndarray) -> Observation:
    c, s = np.cos(angle), np.sin(angle)
    r = np.array([[c, -s], [s, c]])

    def states(a: AgentStates) -> AgentStates:
        xy = a.xy @ r.T + shift
        return AgentStates(a.ids, xy[:, 0], xy[:, 1], a.yaw + angle, a.speed, a.accel, a.length, a.width, a.mass, a.cls)

    return Observation(time=obs.time, dt=obs.dt, history=obs.history @ r.T + shift, valid=obs.valid,
                       current=states(obs.current), ego=states(obs.ego))


def test_predictions_turn_and_move_with_the_scene():
    """Turning the whole scene by 37 deg and moving it by (500, -300) m turns and moves every
    predicted mean the same way (the histories alone, no map). The synthetic scene's pedestrians
    are first moved 0.2 m away from the road: 3.0 m beside the cars they sit exactly on the edge
    of their social grid, where float rounding of the turned scene decides whether a car is in it."""
    m = _model("map")
    obs = make_observation(32)
    ped = np.asarray(obs.current.cls) == int(RoadUserClass.PEDESTRIAN)  # 3.0 m beside the cars -> 3.2 m
    hist, y = obs.history.copy(), obs.current.y.copy()
    hist[ped, :, 1] -= 0.2
    y[ped] -= 0.2
    cur = obs.current
    obs = Observation(obs.time, obs.dt, hist, obs.valid, AgentStates(cur.ids, cur.x, y, cur.yaw, cur.speed, cur.accel,
                                                                     cur.length, cur.width, cur.mass, cur.cls), obs.ego)
    angle, shift = np.radians(37.0), np.array([500.0, -300.0])
    a, _ = LSTMPredictor(m, {"kind": "map"}).model_outputs(obs)
    b, _ = LSTMPredictor(m, {"kind": "map"}).model_outputs(_rotated(obs, angle, shift))
    c, s = np.cos(angle), np.sin(angle)
    np.testing.assert_allclose(b, a @ np.array([[c, -s], [s, c]]).T + shift, atol=2e-3)


def test_agent_frame_model_needs_neighbour_yaw_and_keeps_its_frame_on_disk(tmp_path):
    m = _model("map_cslstm")
    obs = make_observation(8)
    hist, _ = F.resample_history(obs.history, obs.valid, obs.dt)
    f = F.build_features(hist, obs.current.cls, obs.current.yaw)
    x = batch_to_tensors(f, m.pos_scale)
    x.pop("nbr_yaw")
    with pytest.raises(ValueError, match="needs nbr_yaw"):
        m(**x)
    loaded, header = load_model(save_model(m, tmp_path / "m.pt"), kind="map_cslstm")
    assert loaded.nbr_frame == "agent" and header["config"]["nbr_frame"] == "agent"
    assert not hasattr(loaded, "att_proj")  # the CS-LSTM counterpart has no attention


def _random_scene(seed: int, n: int = 20) -> Observation:
    """n road users of every class within 25 m, random headings, curved 3 s histories (turn
    rates up to 0.3 rad/s), and an ego heading somewhere else."""
    rng = np.random.default_rng(seed)
    yaw = rng.uniform(-np.pi, np.pi, n)
    rate = rng.uniform(-0.3, 0.3, n)
    cls = rng.choice([0, 1, 3, 4, 5], n).astype(np.int8)  # car, truck, motorcycle, bicycle, pedestrian
    speed = np.where(cls == 5, rng.uniform(0.5, 2.0, n), rng.uniform(0.0, 14.0, n))
    xy = rng.uniform(-25.0, 25.0, (n, 2))
    t = (np.arange(31) - 30) * 0.1
    heading = yaw[:, None] + rate[:, None] * t  # heading along the history, yaw now
    step = np.stack([np.cos(heading), np.sin(heading)], -1) * speed[:, None, None] * 0.1
    back = np.cumsum(step[:, ::-1], axis=1)[:, ::-1] - step  # position now minus position then
    hist = xy[:, None, :] - back
    z = np.zeros(n)
    cur = AgentStates(tuple(f"a{i}" for i in range(n)), xy[:, 0], xy[:, 1], yaw, speed, z, z + 4.0, z + 1.8, z + 1500,
                      cls)
    ego = AgentStates(("ego",), np.array([3.0]), np.array([-2.0]), np.array([2.2]), np.array([8.0]), np.zeros(1),
                      np.array([4.5]), np.array([1.8]), np.array([1500.0]), np.array([0], dtype=np.int8))
    return Observation(time=0.0, dt=0.1, history=hist, valid=np.ones((n, 31), dtype=bool), current=cur, ego=ego)


@pytest.mark.parametrize("kind", ["map", "map_cslstm"])
def test_scene_path_equals_the_training_path_with_any_headings(kind):
    """Random headings and curved histories of cars, trucks, motorcycles, bicycles and
    pedestrians (so every neighbour has a yaw of its own in its target's frame): the two paths
    still agree."""
    m = _model(kind, seed=1)
    for seed in range(3):
        obs = _random_scene(seed)
        feats = F.build_features(np.concatenate([F.resample_history(obs.history, obs.valid, obs.dt)[0],
                                                 straight_history(obs.ego.xy, obs.ego.yaw, obs.ego.speed)]),
                                 np.r_[obs.current.cls, obs.ego.cls], np.r_[obs.current.yaw, obs.ego.yaw],
                                 targets=np.arange(len(obs.current)))
        assert len(feats["nbr_yaw"]) > 20 and np.abs(feats["nbr_yaw"]).max() > 1.0

        def no_map(ids, person):
            return None, F.MapContext.empty(len(ids))

        fast, _ = LSTMPredictor(m, {"kind": kind}, map_source=no_map).model_outputs(obs)
        assert np.abs(fast - _training_path_means(m, obs, no_map)).max() < 1e-4


def test_training_an_agent_frame_model_on_an_old_dataset_is_refused_in_one_line(tmp_path):
    """A dataset built before nbr_yaw: `train --model map_cslstm` says how to derive its samples again."""
    import subprocess

    old = tmp_path / "old"
    old.mkdir()
    np.savez(old / "samples.npz", split=np.array([0, 1], dtype=np.int8), nbr_ptr=np.array([0, 0, 0]))
    (old / "split.json").write_text("{}")
    p = subprocess.run([sys.executable, "-m", "sumo_ethics.cli", "train", str(old), "--model", "map_cslstm", "--out",
                        str(tmp_path / "m.pt")], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert p.returncode == 2
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and "has no nbr_yaw" in lines[0] and "--samples-from" in lines[0]
    assert not (tmp_path / "m.pt").exists()
