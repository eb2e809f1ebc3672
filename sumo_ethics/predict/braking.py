"""Braking prior: an agent that is braking hard now keeps braking until it stands.

Learned and constant-velocity predictors lag behind an emergency stop: they see the speed
drop a step at a time and keep placing the braking car metres ahead of where it will
stand. This post-processor caps each hard-braking agent's predicted progress along its own
predicted path at the constant-deceleration distance

    s_max(t) = v t - |a| t^2 / 2   for t <= v / |a|,   v^2 / (2 |a|) after   [m]

with v [m/s] and a [m/s^2] the agent's current speed and acceleration. The path (its
shape), the covariance and the headings are kept; only how far along the path the agent
gets is shortened. Agents braking more gently than ``threshold`` are left as predicted.

Both priors apply to every mode of a multi-modal prediction alike (``Prediction.map_modes``:
alternatives and weights are kept).
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

    pred.mean: (N, T, 2) [m], agents in the order of ``current`` (same ids). Every mode of a
    multi-modal ``pred`` is capped alike; alternatives and weights are kept."""
    if pred.weight is not None:
        return pred.map_modes(lambda mode: apply_braking_prior(mode, current, threshold))
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


#: lateral speed [m/s] across a straight predicted path from which the lateral prior acts
LATERAL_SPEED = 0.5


def apply_lateral_prior(pred: Prediction, current: AgentStates, horizon: float = 1.5,
                        min_speed: float = LATERAL_SPEED, max_bend: float = 0.1) -> Prediction:
    """``pred`` with agents that move across their own straight predicted path kept moving so.

    Learned models trained on lane-keeping traffic pull a car that drifts, cuts in or swerves
    back onto its lane within a second. The predicted path's start direction is that of the
    circular arc through the agent, its mid-horizon and its last predicted point; the path
    counts as straight when that arc turns by less than ``max_bend`` [rad]. If the agent's
    heading then carries a lateral speed v_lat >= ``min_speed`` [m/s] across the start
    direction, the mean is shifted across it to v_lat * min(t, horizon) [m] where the model
    predicts less lateral motion that way, so that the agent keeps its lateral speed for
    ``horizon`` s and then keeps that offset. Apply it before the braking prior, which then
    also stops the sideways motion of a car braking to a stand. Agents turning, standing or
    aligned with their path are left as predicted; covariances and headings are kept. Every
    mode of a multi-modal ``pred`` is treated alike (its own path); alternatives and weights are kept.
    """
    if pred.weight is not None:
        return pred.map_modes(lambda mode: apply_lateral_prior(mode, current, horizon, min_speed, max_bend))
    n, T = pred.mean.shape[:2]
    if n == 0 or T < 2:
        return pred
    xy = current.xy
    t = (np.arange(T) + 1) * pred.dt
    chord = pred.mean[:, -1] - xy  # (N, 2) to the last predicted point
    mid = pred.mean[:, T // 2] - xy
    length = np.linalg.norm(chord, axis=-1)
    # signed angle chord -> mid-chord: -1/4 of an arc's total turn; start tangent = chord + 2x it
    bend = np.arctan2(chord[:, 0] * mid[:, 1] - chord[:, 1] * mid[:, 0], np.einsum("ni,ni->n", chord, mid))
    start = np.arctan2(chord[:, 1], chord[:, 0]) + 2.0 * bend
    normal = np.stack([-np.sin(start), np.cos(start)], -1)  # left of the start direction
    v_lat = current.speed * np.sin(current.yaw - start)  # (N,) m/s, + = leftwards
    act = (length > 1.0) & (4.0 * np.abs(bend) < max_bend) & (np.abs(v_lat) >= min_speed) & (current.speed > 1.0)
    if not act.any():
        return pred
    want = v_lat[act, None] * np.minimum(t, horizon)[None, :]  # (A, T) wanted lateral offset
    have = np.einsum("ati,ai->at", pred.mean[act] - xy[act, None, :], normal[act])  # already predicted
    extra = np.where(np.abs(want) > np.abs(have) * (np.sign(have) == np.sign(want)), want - have, 0.0)
    mean = pred.mean.copy()
    mean[act] += extra[..., None] * normal[act, None, :]
    return Prediction(ids=pred.ids, dt=pred.dt, mean=mean, cov=pred.cov, yaw=pred.yaw)
