"""Constant-velocity baseline predictor (numpy only, no torch).

Mean: every agent keeps its current speed along its current heading (yaw).
Uncertainty: independent standard deviations along the heading (longitudinal) and
across it (lateral) that grow linearly with the prediction time t [s]:

    sigma_lon(t) = sigma0 + g_lon * t,  sigma_lat(t) = sigma0 + g_lat * t   [m]

with sigma0 in metres and the growth rates g in metres per second (m/s of standard
deviation per second of horizon). cov(t) = R(yaw) diag(sigma_lon^2, sigma_lat^2) R(yaw)^T.
Rates depend on the agent group: vehicles mostly drift along their lane
(g_lon > g_lat), pedestrians and cyclists turn freely, so they get larger lateral
growth relative to their speed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sumo_ethics.geometry import not_psd
from sumo_ethics.predict import features as F
from sumo_ethics.types import Observation, Prediction

#: default (g_lon, g_lat) [m/s] per group: vehicle, cyclist, pedestrian
DEFAULT_GROWTH = ((0.5, 0.15), (0.4, 0.25), (0.3, 0.35))


@dataclass(frozen=True)
class ConstantVelocityPredictor:
    """sigma0: standard deviation at t = 0 [m]; growth: (g_lon, g_lat) [m/s] for vehicles,
    growth_cyclist / growth_pedestrian likewise for bicycles and pedestrians."""

    sigma0: float = 0.1
    growth: tuple[float, float] = DEFAULT_GROWTH[0]
    growth_cyclist: tuple[float, float] = DEFAULT_GROWTH[1]
    growth_pedestrian: tuple[float, float] = DEFAULT_GROWTH[2]

    def __post_init__(self) -> None:
        if self.sigma0 <= 0:
            raise ValueError(f"sigma0 must be > 0 m, got {self.sigma0}")
        for g in (self.growth, self.growth_cyclist, self.growth_pedestrian):
            if len(g) != 2 or min(g) < 0:
                raise ValueError(f"growth rates must be two non-negative m/s values, got {g}")

    def growth_table(self) -> np.ndarray:
        """(N_GROUPS, 2) growth rates [m/s] indexed by class group."""
        return np.array([self.growth, self.growth_cyclist, self.growth_pedestrian], dtype=float)

    def predict(self, obs: Observation, horizon_steps: int, dt: float) -> Prediction:
        cur = obs.current
        t = (np.arange(horizon_steps) + 1) * float(dt)
        return self.predict_arrays(cur.ids, cur.xy, cur.yaw, cur.speed, cur.cls, t, float(dt))

    def predict_arrays(self, ids: tuple[str, ...], xy: np.ndarray, yaw: np.ndarray, speed: np.ndarray,
                       cls: np.ndarray, t: np.ndarray, dt: float) -> Prediction:
        """Array form of :meth:`predict`: xy (N, 2), yaw/speed/cls (N,), t (T,) [s]."""
        n, tn = len(ids), len(t)
        yaw = np.asarray(yaw, dtype=float)
        heading = np.stack([np.cos(yaw), np.sin(yaw)], -1)  # (N, 2)
        mean = np.asarray(xy, dtype=float)[:, None, :] + (np.asarray(speed, dtype=float)[:, None] * t)[..., None] * heading[:, None, :]
        g = self.growth_table()[F.class_group(cls)] if n else np.zeros((0, 2))
        sig = self.sigma0 + g[:, None, :] * t[None, :, None]  # (N, T, 2) lon, lat
        rot = F.rotation(yaw)  # (N, 2, 2)
        diag = np.zeros((n, tn, 2, 2))
        diag[..., 0, 0] = sig[..., 0] ** 2
        diag[..., 1, 1] = sig[..., 1] ** 2
        cov = rot[:, None] @ diag @ np.swapaxes(rot, -1, -2)[:, None]
        return Prediction(ids=tuple(ids), dt=dt, mean=mean, cov=cov, yaw=np.repeat(yaw[:, None], tn, axis=1))


def non_finite(pred: Prediction) -> np.ndarray:
    """(N,) bool: the agents whose mean, covariance or yaw is non-finite in any mode (or whose mode
    weights are), or whose covariance has a negative principal variance (no Gaussian has it:
    :func:`sumo_ethics.geometry.not_psd`): those :func:`replace_non_finite` replaces."""
    bad = np.zeros(len(pred.ids), dtype=bool)
    for m, _ in pred.by_mode():
        finite = np.isfinite(m.cov).all(axis=(1, 2, 3))
        bad |= ~(np.isfinite(m.mean).all(axis=(1, 2)) & finite & np.isfinite(m.yaw).all(axis=1))
        bad |= finite & not_psd(np.where(np.isfinite(m.cov), m.cov, 0.0)).any(axis=1)
    if pred.weight is not None:
        bad |= ~np.isfinite(pred.weight).all(axis=1)
    return bad


def replace_non_finite(pred: Prediction, obs: Observation, horizon_steps: int, dt: float,
                       fallback: ConstantVelocityPredictor | None = None) -> tuple[Prediction, int]:
    """(prediction, number of agents replaced): every agent whose mean, covariance or yaw is
    non-finite in any mode (or whose mode weights are), or whose covariance has a negative
    principal variance (no Gaussian has it: :func:`sumo_ethics.geometry.not_psd`), gets the
    constant-velocity prediction from its current state in every mode, with weights (1, 0, ...).
    Agents already valid are returned as they were (the same arrays when none is replaced); the
    planner records the count as ``n_fallback``."""
    bad = non_finite(pred)
    if not bad.any():
        return pred, 0
    cv = (fallback or ConstantVelocityPredictor()).predict(obs, horizon_steps, dt)
    row = {agent: i for i, agent in enumerate(cv.ids)}
    idx = np.flatnonzero(bad)
    src = np.array([row[pred.ids[i]] for i in idx], dtype=int)

    def fix(m: Prediction) -> Prediction:
        mean, cov, yaw = m.mean.copy(), m.cov.copy(), m.yaw.copy()
        mean[idx], cov[idx], yaw[idx] = cv.mean[src], cv.cov[src], cv.yaw[src]
        return Prediction(m.ids, m.dt, mean, cov, yaw)

    out = pred.map_modes(fix)
    if pred.weight is None:
        return out, int(bad.sum())
    w = pred.weight.copy()
    w[idx] = 0.0
    w[idx, 0] = 1.0
    return Prediction(out.ids, out.dt, out.mean, out.cov, out.yaw, out.alternatives, w), int(bad.sum())
