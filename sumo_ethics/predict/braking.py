"""Braking prior: an agent that is braking hard now keeps braking until it stands.

Learned and constant-velocity predictors lag behind an emergency stop: they see the speed
drop a step at a time and keep placing the braking car metres ahead of where it will
stand. This post-processor caps each hard-braking agent's predicted progress along its own
predicted path at the constant-deceleration distance

    s_max(t) = v t - |a| t^2 / 2   for t <= v / |a|,   v^2 / (2 |a|) after   [m]

with v [m/s] and a [m/s^2] the agent's current speed and acceleration. The path (its
shape), the covariance and the headings are kept; only how far along the path the agent
gets is shortened. Agents braking more gently than ``threshold`` are left as predicted.
"""

from __future__ import annotations

import numpy as np

from sumo_ethics.types import AgentStates, Prediction

#: deceleration [m/s^2] from which an agent counts as braking hard (comfortable braking is ~3)
HARD_BRAKING = 3.0


def stopping_progress(speed: np.ndarray, accel: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(N, T) distance [m] covered by t [s] at constant deceleration ``accel`` < 0 from ``speed``,
    standing still once stopped. speed, accel: (N,); t: (T,)."""
    v = np.maximum(np.asarray(speed, dtype=float), 0.0)[:, None]
    b = np.maximum(-np.asarray(accel, dtype=float), 1e-9)[:, None]
    tt = np.minimum(np.asarray(t, dtype=float)[None, :], v / b)
    return v * tt - 0.5 * b * tt ** 2


def apply_braking_prior(pred: Prediction, current: AgentStates, threshold: float = HARD_BRAKING) -> Prediction:
    """``pred`` with every agent whose accel <= -threshold kept within its stopping distance.

    pred.mean: (N, T, 2) [m], agents in the order of ``current`` (same ids)."""
    braking = np.flatnonzero(np.asarray(current.accel) <= -threshold)
    if len(braking) == 0 or pred.mean.shape[1] == 0:
        return pred
    t = (np.arange(pred.mean.shape[1]) + 1) * pred.dt
    start = current.xy[braking]  # (B, 2)
    path = np.concatenate([start[:, None, :], pred.mean[braking]], axis=1)  # (B, T+1, 2)
    seg = np.linalg.norm(np.diff(path, axis=1), axis=-1)  # (B, T)
    arc = np.concatenate([np.zeros((len(braking), 1)), np.cumsum(seg, axis=1)], axis=1)  # (B, T+1)
    cap = stopping_progress(current.speed[braking], current.accel[braking], t)  # (B, T)
    target = np.minimum(arc[:, 1:], cap)
    mean = pred.mean.copy()
    for row, n in enumerate(braking):  # B is a handful of agents: interpolate each path
        mean[n, :, 0] = np.interp(target[row], arc[row], path[row, :, 0])
        mean[n, :, 1] = np.interp(target[row], arc[row], path[row, :, 1])
    return Prediction(ids=pred.ids, dt=pred.dt, mean=mean, cov=pred.cov, yaw=pred.yaw)
