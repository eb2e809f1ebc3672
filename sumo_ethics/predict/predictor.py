"""LSTMPredictor: Observation (numpy) -> Prediction (numpy) with a trained CS-LSTM / attention / map model.

The map-aware models (kinds "map", the default, and "map_cslstm") also read each target's lane polylines and signal state
(:func:`features.map_features`), asked of its ``map_source`` (in a run:
:class:`sumo_ethics.sim.lanes.SumoMapSource`, wired by the planner); without a source it
predicts from the histories alone, as if no agent were on a lane.

Run-time path, per call, one batched forward pass for all N agents:

1. The history (obs.dt spacing, any length) is resampled to the model's 5 Hz, 3 s grid
   (:func:`features.resample_history`); an agent with fewer than two observed samples
   gets a straight history from its current speed and yaw.
2. The ego (obs.ego) has no history in an Observation; it joins as a NEIGHBOUR (never a
   target) with a constant-velocity history built backwards from its current state.
3. Features in each target's frame (:func:`features.build_features`), one forward pass.
4. Outputs (target frame, 0.2 s steps up to 4 s) are rotated back to the world frame and
   resampled to the requested ``dt`` x ``horizon_steps`` by linear interpolation of
   mean and covariance (from the current position with covariance ``sigma0^2 I`` at
   t = 0). Beyond the model horizon the mean continues at the last predicted velocity and
   the covariance grows as ``cov_end * (t / t_end)^2`` (standard deviations linear in t).
5. Yaw along the prediction is the direction of motion of the mean path, kept at the
   previous value while the mean moves slower than 0.3 m/s.

Calibration: a weights file's ``<stem>.calibration.json`` (:mod:`sumo_ethics.predict.calibration`)
scales each agent's sigma along and across its heading by class, horizon and the lateral motion
its modes foresee, before step 4; ``calibrated=False`` (``from_file``, ``default``) loads the
model's own spreads, as published.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from sumo_ethics.predict import PredictorError
from sumo_ethics.predict import features as F
from sumo_ethics.predict.calibration import Calibration, load_for
from sumo_ethics.predict.protocols import MapSource, MapSourceFactory
from sumo_ethics.predict.models import KINDS, MAP_KINDS, TrajectoryLSTM, load_model, rank_modes
from sumo_ethics.types import AgentStates, Observation, Prediction


WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"
MIN_YAW_SPEED = 0.3  # [m/s] below this the predicted yaw is held


def default_weights(kind: str) -> Path:
    """Path of the weights shipped in the package for ``kind`` ("map_cslstm", "map", "attention" or "cslstm")."""
    return WEIGHTS_DIR / f"{kind}.pt"


def lstm(kind: str, weights: Path | str | None = None, calibrated: bool = True,
         maps: MapSourceFactory | None = None) -> "LSTMPredictor":
    """The registry's factory of the LSTM predictors (:mod:`sumo_ethics.predict.registry`): model
    ``kind`` from ``weights`` or the shipped file, with the calibration beside it unless
    ``calibrated=False``; a map-aware model gets ``maps(its map version)`` (None: no map context)."""
    predictor = (LSTMPredictor.from_file(weights, kind=kind, calibrated=calibrated) if weights
                 else LSTMPredictor.default(kind, calibrated=calibrated))
    if predictor.uses_map and maps is not None:
        predictor.map_source = maps(predictor.model.map_version)  # looks up what the model reads
    return predictor


def straight_history(xy: np.ndarray, yaw: np.ndarray, speed: np.ndarray) -> np.ndarray:
    """(N, 2), (N,), (N,) -> (N, HIST_STEPS, 2) constant-velocity history ending at xy."""
    t = (np.arange(F.HIST_STEPS) - (F.HIST_STEPS - 1)) * F.MODEL_DT
    v = np.stack([np.cos(yaw), np.sin(yaw)], -1) * np.asarray(speed, dtype=float)[:, None]
    return np.asarray(xy, dtype=float)[:, None, :] + t[None, :, None] * v[:, None, :]


class LSTMPredictor:
    """A trained TrajectoryLSTM behind the ``predict(obs, horizon_steps, dt)`` interface."""

    def __init__(self, model: TrajectoryLSTM, header: dict, path: Path | None = None, sigma0: float = 0.1,
                 map_source: MapSource | None = None, calibration: Calibration | None = None) -> None:
        self.model = model.eval()
        # one batched forward pass of a small LSTM per step: extra threads only add contention
        # (measured on 2 busy cores: 4.6 ms with 1 thread, 800 ms with 2)
        torch.set_num_threads(1)
        self.header = header
        self.path = path
        self.kind = header.get("kind", getattr(model, "kind", "?"))
        self.sigma0 = sigma0
        self._scale = np.asarray(header.get("pos_scale", F.POS_SCALE), dtype=np.float32)
        self.uses_map = self.kind in MAP_KINDS
        #: (ids, is_person) -> (LaneGraph, MapContext) of the agents; None: no map (all rows invalid)
        self.map_source = map_source
        #: sigma factors applied to every output (None: the model's own spreads)
        self.calibration = calibration

    @classmethod
    def from_file(cls, path: Path | str, kind: str | None = None, map_source: MapSource | None = None,
                  calibrated: bool = True) -> "LSTMPredictor":
        """Load weights; ``kind`` (optional) must match the file's. Problems -> PredictorError.
        ``calibrated``: apply the calibration shipped beside the file (``<stem>.calibration.json``),
        if there is one fitted for these weights; False: the model's own spreads."""
        model, header = load_model(Path(path), kind=kind)
        cal = load_for(path) if calibrated else None
        return cls(model, header, Path(path), map_source=map_source, calibration=cal)

    @classmethod
    def default(cls, kind: str = "map", map_source: MapSource | None = None, calibrated: bool = True) -> "LSTMPredictor":
        """The weights shipped with the package (sumo_ethics/predict/weights/<kind>.pt), calibrated
        unless ``calibrated=False``."""
        if kind not in KINDS:
            raise PredictorError(f"unknown predictor kind {kind!r}: expected one of {', '.join(KINDS)}")
        return cls.from_file(default_weights(kind), kind=kind, map_source=map_source, calibrated=calibrated)

    def __repr__(self) -> str:
        return (f"LSTMPredictor(kind={self.kind!r}, path={str(self.path)!r}, "
                f"calibrated={self.calibration is not None})")

    # ------------------------------------------------------------------ run-time
    def model_outputs(self, obs: Observation) -> tuple[np.ndarray, np.ndarray]:
        """World-frame (N, FUT_STEPS, 2) means and (N, FUT_STEPS, 2, 2) covariances at 0.2 s steps
        of each agent's most likely mode."""
        mean, cov, _ = self.mode_outputs(obs)
        return mean[:, 0], cov[:, 0]

    def mode_outputs(self, obs: Observation) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World-frame (N, M, FUT_STEPS, 2) means, (N, M, FUT_STEPS, 2, 2) covariances at 0.2 s
        steps and (N, M) weights of the model's M modes, per agent by falling weight (M = 1 and
        weight 1 for a single-mode model)."""
        cur = obs.current
        n = len(cur)
        xy, yaw = cur.xy, np.asarray(cur.yaw, dtype=float)
        if np.asarray(obs.history).shape[1] > 0:
            hist, hvalid = F.resample_history(obs.history, obs.valid, obs.dt)
        else:
            hist, hvalid = np.zeros((n, F.HIST_STEPS, 2)), np.zeros((n, F.HIST_STEPS), dtype=bool)
        hist[:, -1] = xy
        few = hvalid.sum(axis=1) < 2
        if few.any():
            hist[few] = straight_history(xy[few], yaw[few], cur.speed[few])
        cls = np.asarray(cur.cls, dtype=np.int64)
        ego: AgentStates = obs.ego
        if len(ego) > 0:
            hist = np.concatenate([hist, straight_history(ego.xy, ego.yaw, ego.speed)])
            cls = np.concatenate([cls, np.asarray(ego.cls, dtype=np.int64)])
            yaw_all = np.concatenate([yaw, np.asarray(ego.yaw, dtype=float)])
        else:
            yaw_all = yaw
        agent_frame = getattr(self.model, "nbr_frame", "target") == "agent"
        feats = F.build_features(hist, cls, yaw_all, targets=np.arange(n), histories=not agent_frame)
        g = feats["tgt_group"]
        s = self._scale[g]
        extra = {}
        if self.uses_map:
            person = g == F.GROUP_PEDESTRIAN
            if self.map_source is not None:
                graph, ctx = self.map_source(cur.ids, person)
            else:
                graph, ctx = None, F.MapContext.empty(n)
            mf = F.map_features(graph, ctx, xy, yaw, cur.speed, version=getattr(self.model, "map_version", 1))
            extra = {"map_pts": torch.from_numpy(mf["map_pts"] / s[:, None, None, None]),
                     "map_valid": torch.from_numpy(mf["map_valid"]),
                     "map_scalar": torch.from_numpy(mf["map_scalar"])}
        if agent_frame:
            out, log_w = self._scene_outputs(hist, cls, yaw_all, feats, s, extra)
        else:
            with torch.inference_mode():
                out, log_w = self.model(
                    torch.from_numpy(feats["tgt_hist"] / s[:, None, None]),
                    torch.from_numpy(g),
                    torch.from_numpy(feats["nbr_hist"] / s[feats["nbr_batch"]][:, None, None]),
                    torch.from_numpy(feats["nbr_group"]),
                    torch.from_numpy(feats["nbr_batch"]),
                    torch.from_numpy(feats["nbr_cell"]),
                    **extra, all_modes=True,
                )
        out, log_w = rank_modes(out, log_w)  # most likely mode first
        params, w = out.numpy().astype(float), np.exp(log_w.numpy().astype(float))
        mu = params[..., :2] * s[:, None, None, None]
        sx, sy, rho = params[..., 2] * s[:, None, None], params[..., 3] * s[:, None, None], params[..., 4]
        w = w / w.sum(axis=1, keepdims=True)
        if self.calibration is not None:  # factors along / across the heading now (calibration.py)
            sx, sy = self.calibration.sigmas(g, mu[..., 1], w, np.asarray(cur.speed, dtype=float), sx, sy)
        # to the world frame: mean = xy + R mu, cov = R [[a, b], [b, d]] R^T with R = R(yaw), written
        # out elementwise (numpy's matmul over stacks of 2 x 2 matrices took 5x longer)
        c, s_ = np.cos(yaw)[:, None, None], np.sin(yaw)[:, None, None]
        a, b, d = sx * sx, rho * sx * sy, sy * sy
        mean = np.stack([xy[:, None, None, 0] + c * mu[..., 0] - s_ * mu[..., 1],
                         xy[:, None, None, 1] + s_ * mu[..., 0] + c * mu[..., 1]], -1)
        cs = c * s_
        cov = np.empty(params.shape[:3] + (2, 2))
        cov[..., 0, 0] = c * c * a - 2.0 * cs * b + s_ * s_ * d
        cov[..., 1, 1] = s_ * s_ * a + 2.0 * cs * b + c * c * d
        cov[..., 0, 1] = cov[..., 1, 0] = cs * (a - d) + (c * c - s_ * s_) * b
        return mean, cov, w

    def _scene_outputs(self, hist: np.ndarray, cls: np.ndarray, yaw: np.ndarray, feats: dict, s: np.ndarray,
                       extra: dict) -> tuple[torch.Tensor, torch.Tensor]:
        """Outputs ((N, M, FUT_STEPS, 5), (N, M) log weights) of an ``nbr_frame="agent"`` model: every
        agent (targets first, then the ego) is encoded once in its own frame (``scene_forward``)."""
        n = len(feats["tgt_group"])
        g_all = F.class_group(cls)
        own = F.own_frame(hist, yaw) / self._scale[g_all][:, None, None]
        nb = feats["nbr_batch"]
        pose = np.concatenate([feats["nbr_pos"] / s[nb][:, None], np.cos(feats["nbr_yaw"])[:, None],
                               np.sin(feats["nbr_yaw"])[:, None]], -1)
        with torch.inference_mode():
            out = self.model.scene_forward(
                torch.from_numpy(own.astype(np.float32)), torch.from_numpy(g_all), torch.arange(n),
                torch.from_numpy(feats["nbr_agent"]), torch.from_numpy(nb), torch.from_numpy(feats["nbr_cell"]),
                torch.from_numpy(pose.astype(np.float32)), **extra, all_modes=True)
        if not isinstance(out, tuple):  # all_modes=True: (every mode, log weights)
            raise TypeError("scene_forward(all_modes=True) gave one tensor, not the modes and their weights")
        return out

    def predict(self, obs: Observation, horizon_steps: int, dt: float) -> Prediction:
        cur = obs.current
        n = len(cur)
        t = (np.arange(horizon_steps) + 1) * float(dt)
        if n == 0:
            return Prediction((), float(dt), np.zeros((0, horizon_steps, 2)), np.zeros((0, horizon_steps, 2, 2)), np.zeros((0, horizon_steps)))
        mean_m, cov_m, w = self.mode_outputs(obs)
        k = w.shape[1]  # the modes stacked mode-major as N * k rows, resampled at once
        xy = np.tile(cur.xy, (k, 1))
        mean, cov = resample_outputs(xy, np.concatenate(mean_m.swapaxes(0, 1)), np.concatenate(cov_m.swapaxes(0, 1)),
                                     t, self.sigma0)
        yaw = path_yaw(xy, np.tile(np.asarray(cur.yaw, dtype=float), k), mean, float(dt))
        modes = [Prediction(ids=cur.ids, dt=float(dt), mean=mean[m * n:(m + 1) * n], cov=cov[m * n:(m + 1) * n],
                            yaw=yaw[m * n:(m + 1) * n]) for m in range(k)]
        if k == 1:
            return modes[0]
        main = modes[0]
        return Prediction(main.ids, main.dt, main.mean, main.cov, main.yaw, tuple(modes[1:]), w)


def resample_outputs(xy: np.ndarray, mean_m: np.ndarray, cov_m: np.ndarray, t: np.ndarray, sigma0: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """Model outputs at 0.2 s steps -> times ``t`` [s] (see module docstring, step 4)."""
    n, k = mean_m.shape[:2]
    tau = np.arange(k + 1) * F.MODEL_DT  # 0, 0.2, ..., 4.0
    m_full = np.concatenate([np.asarray(xy, dtype=float)[:, None, :], mean_m], axis=1)
    c0 = np.broadcast_to(np.eye(2) * sigma0**2, (n, 1, 2, 2))
    c_full = np.concatenate([c0, cov_m], axis=1)
    t_end = tau[-1]
    inside = t <= t_end + 1e-9
    ti = np.clip(t, 0.0, t_end)
    j = np.clip(np.searchsorted(tau, ti, side="left"), 1, k)
    w = (ti - tau[j - 1]) / F.MODEL_DT
    mean = m_full[:, j - 1] * (1 - w)[None, :, None] + m_full[:, j] * w[None, :, None]
    cov = c_full[:, j - 1] * (1 - w)[None, :, None, None] + c_full[:, j] * w[None, :, None, None]
    if not inside.all():
        extra = ~inside
        v_end = (mean_m[:, -1] - mean_m[:, -2]) / F.MODEL_DT  # (N, 2)
        dt_extra = t[extra] - t_end
        mean[:, extra] = mean_m[:, -1][:, None, :] + dt_extra[None, :, None] * v_end[:, None, :]
        cov[:, extra] = cov_m[:, -1][:, None] * ((t[extra] / t_end) ** 2)[None, :, None, None]
    return mean, cov


def path_yaw(xy: np.ndarray, yaw0: np.ndarray, mean: np.ndarray, dt: float) -> np.ndarray:
    """(N, T) heading of the mean path; held where it moves slower than MIN_YAW_SPEED."""
    prev = np.concatenate([np.asarray(xy, dtype=float)[:, None, :], mean[:, :-1]], axis=1)
    d = mean - prev
    moving = np.hypot(d[..., 0], d[..., 1]) > MIN_YAW_SPEED * dt
    ang = np.arctan2(d[..., 1], d[..., 0])
    out = np.empty(mean.shape[:2])
    last = np.asarray(yaw0, dtype=float).copy()
    for k in range(mean.shape[1]):
        last = np.where(moving[:, k], ang[:, k], last)
        out[:, k] = last
    return out
