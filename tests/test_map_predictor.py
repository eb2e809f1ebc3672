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

ROOT = Path(__file__).resolve().parents[1]
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
    # points at arc lengths 90, 95, ..., 135 m along each path; a red light 20 m ahead
    ctx = F.MapContext(lane=np.array([0]), lane_pos=np.array([90.0]), tls_dist=np.array([20.0]),
                       tls_state=np.array([3]))
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
    # [on a lane, light ahead, 20/50, green, yellow, red, 13.9/30]
    np.testing.assert_allclose(f["map_scalar"][0], [1, 1, 0.4, 0, 0, 1, 13.9 / 30], atol=1e-6)


def test_map_features_rotate_into_the_target_frame_and_hold_a_dead_end():
    g = junction_graph()
    # on b_0 (heading +y, yaw pi/2) at 40 m of 50, standing: ds = 2.5 m; b_0 is a dead end
    # after 10 m, so points 5..9 repeat its end; in the target's frame +x is +y of the world
    ctx = F.MapContext(np.array([2]), np.array([40.0]), np.array([np.inf]), np.array([0]))
    f = F.map_features(g, ctx, np.array([[100.0, 40.0]]), np.array([np.pi / 2]), np.array([0.0]))
    ahead = f["map_pts"][0, 0]
    np.testing.assert_allclose(ahead[:, 0], [0, 2.5, 5, 7.5, 10, 10, 10, 10, 10, 10], atol=1e-5)
    np.testing.assert_allclose(ahead[:, 1], 0, atol=1e-5)
    np.testing.assert_allclose(f["map_scalar"][0], [1, 0, 0, 0, 0, 0, 8.0 / 30], atol=1e-6)


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
    with pytest.raises(PredictorError, match="map_version=0, this code needs 1"):
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
    assert not (out / "summary.json").exists() and not (out / "steps.parquet").exists()


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
    assert p.kind == "map_cslstm" and p.uses_map and p.model.nbr_frame == "agent"
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
def test_dataset_carries_map_context_from_sumo(tmp_path):
    from sumo_ethics.predict.dataset import MANOEUVRES, build_dataset, load_samples

    out = build_dataset([URBAN], [1, 2, 3], tmp_path / "ds", sim_seconds=60.0, anchor_every=1.0)
    s = load_samples(out)
    veh = s["tgt_group"] == F.GROUP_VEHICLE
    ped = s["tgt_group"] == F.GROUP_PEDESTRIAN
    # vehicles on lanes: the ahead row exists and starts at the car itself (its lane's centre line)
    on = veh & s["map_valid"][:, 0]
    assert on.mean() > 0.9 * veh.mean()
    assert np.median(np.hypot(*s["map_pts"][on, 0, 0].T)) < 0.5
    assert not s["map_valid"][ped].any()
    # the urban scenario has traffic lights: some vehicles see one ahead, some a red one
    assert s["map_scalar"][on, 1].mean() > 0.2 and s["map_scalar"][on, 5].any()
    labels = set(np.unique(s["manoeuvre"][veh]).tolist())
    assert {MANOEUVRES.index("straight"), MANOEUVRES.index("turn")} <= labels
    assert (s["manoeuvre"][ped] == -1).all()


SUITE = ROOT / "scenarios" / "suite"


@pytest.mark.sumo
@pytest.mark.skipif(not (SUITE / "s0002").is_dir(), reason="bundled suite missing")
def test_suite_runs_bring_hazard_actors_into_the_data(tmp_path):
    """A suite scenario recorded with its hazards: the hazard actor is in the trajectories, and
    its samples are labelled 'hazard' with a future observed for at least 1 s."""
    from sumo_ethics.predict.dataset import HAZARD_MIN_FUTURE, MANOEUVRES, build_dataset, load_samples

    out = build_dataset([], [], tmp_path / "ds", suite=[SUITE / "s0002"], suite_anchor_every=0.4)
    traj = __import__("pandas").read_parquet(out / "trajectories.parquet")
    assert traj["agent_id"].str.startswith("hazard_").any()
    s = load_samples(out)
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
    assert '"predictor": "map_cslstm"' in (outs[0] / "config.json").read_text()
    used = __import__("json").loads((outs[0] / "summary.json").read_text())["predictor"]
    assert used["kind"] == "map_cslstm" and used["weights"] == str(default_weights("map_cslstm"))
    assert (outs[0] / "steps.parquet").read_bytes() == (outs[1] / "steps.parquet").read_bytes()


def _queue_at_light(state: int) -> tuple[Observation, object]:
    """Four cars standing for 3 s in a queue 5, 12, 19 and 26 m before a stop line (x = 0) whose
    light shows ``state`` (features.TLS_CODES: 1 green, 3 red), and the map source of that lane."""
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
        return graph, F.MapContext(np.zeros(k, dtype=np.int64), x0 + 200.0, -x0, np.full(k, state, dtype=np.int64))

    return obs, source


def test_shipped_default_keeps_a_queue_at_a_red_light_standing_as_its_most_likely_mode():
    # the single-Gaussian model this replaced moved the first car 0.83 m in 4 s at red (the
    # average of "stays" and "pulls away"); with modes, "stays" is a mode of its own
    obs, source = _queue_at_light(3)
    p = LSTMPredictor.default(map_source=source)
    assert p.model.modes == 3
    mean, _, w = p.mode_outputs(obs)
    moved = mean[:, :, -1, 0] - obs.current.x[:, None]  # (4 cars, 3 modes) along the lane after 4 s
    assert np.all(w[:, 0] > 0.75) and np.all(np.abs(moved[:, 0]) < 0.1)  # most likely: stays (< 10 cm)
    assert w[0, 0] > 0.9  # the first car, right at the red light, the most surely
    assert np.all(moved[:, 1:] > 0.1)  # the other modes pull away
    # at green the first car is likelier to go than at red
    obs_g, source_g = _queue_at_light(1)
    _, _, w_g = LSTMPredictor.default(map_source=source_g).mode_outputs(obs_g)
    assert 1.0 - w_g[0, 0] > 1.0 - w[0, 0]
