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

from sumo_ethics.types import AgentStates, Observation, Prediction

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
#: the lateral prior's onset model (``lateral_accel`` given): the fastest sideways speed it lets an
#: agent reach [m/s] (a 3.5 m lane change in about 2.2 s at its middle) and the farthest it moves it
#: aside [m] (a lane's width, across its direction of travel)
LATERAL_SPEED_MAX = 2.5
LATERAL_SHIFT_MAX = 3.5
#: the past [s] whose chord gives an agent's direction of travel (:func:`recent_motion`), and the
#: distance [m] it must have covered in it for that direction to count
TRAVEL_WINDOW = 1.0
TRAVEL_MIN = 2.0


def recent_motion(obs: Observation, window: float = TRAVEL_WINDOW, min_travel: float = TRAVEL_MIN
                  ) -> tuple[np.ndarray, np.ndarray]:
    """((N,) direction of travel [rad], (N,) lateral acceleration [m/s^2]) of the agents of ``obs``.

    The direction: of the chord from the agent's position ``window`` s ago to now (the window
    shortened to the history's length), NaN where the agent was not observed then or covered less
    than ``min_travel`` m. The lateral acceleration: the second difference of the last three
    positions (centred one step back) across the agent's heading now (+ leftwards; not across the
    direction of travel, so hard braking with a heading off that direction leaks into it), 0
    without three observed positions."""
    h = np.asarray(obs.history, dtype=float)
    n, H = h.shape[:2]
    if n == 0 or H < 3:
        return np.full(n, np.nan), np.zeros(n)
    k = min(max(int(round(window / obs.dt)), 1), H - 1)
    chord = h[:, -1] - h[:, -1 - k]
    seen = obs.valid[:, -1] & obs.valid[:, -1 - k] & (np.hypot(chord[:, 0], chord[:, 1]) >= min_travel)
    heading = np.where(seen, np.arctan2(chord[:, 1], chord[:, 0]), np.nan)
    acc = (h[:, -1] - 2.0 * h[:, -2] + h[:, -3]) / obs.dt**2
    yaw = np.asarray(obs.current.yaw, dtype=float)
    lateral = np.where(obs.valid[:, -3:].all(axis=1), np.cos(yaw) * acc[:, 1] - np.sin(yaw) * acc[:, 0], 0.0)
    return heading, lateral


def apply_lateral_prior(pred: Prediction, current: AgentStates, horizon: float = 1.5,
                        min_speed: float = LATERAL_SPEED, max_bend: float = 0.1,
                        travel: np.ndarray | None = None, lateral_accel: np.ndarray | None = None) -> Prediction:
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

    The onset of a lane change (``travel`` and ``lateral_accel``, (N,) each, from
    :func:`recent_motion`): the sideways motion is measured across the agent's direction of
    travel over the last second instead of the predicted path (a model that bends its path
    towards the new lane hides the motion across it), where that direction is known (not NaN);
    and a lateral speed that grows (lateral_accel of its sign) keeps growing at that rate up to
    :data:`LATERAL_SPEED_MAX` for ``horizon`` s, the offset at most :data:`LATERAL_SHIFT_MAX`
    across the direction of travel (not across the lane: with the chord already tilted, a car can
    be put further aside of its lane). A cut-in on a cosine ramp is seen 0.2-0.3 s after it starts,
    at 0.5 m/s sideways. Known flaw: in the last tenths of a second of a smooth lane change the
    heading has straightened while the chord still tilts, so the sideways speed across the chord
    and the sideways deceleration both point back, and the car is predicted up to about 1 m back
    towards its old lane (docs/limitations.md).
    """
    if pred.weight is not None:
        return pred.map_modes(lambda mode: apply_lateral_prior(mode, current, horizon, min_speed, max_bend, travel,
                                                                lateral_accel))
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
    if travel is not None:  # the direction of travel over the last second, where known
        start = np.where(np.isfinite(travel), travel, start)
    normal = np.stack([-np.sin(start), np.cos(start)], -1)  # left of the start direction
    v_lat = current.speed * np.sin(current.yaw - start)  # (N,) m/s, + = leftwards
    act = (length > 1.0) & (4.0 * np.abs(bend) < max_bend) & (np.abs(v_lat) >= min_speed) & (current.speed > 1.0)
    if not act.any():
        return pred
    th = np.minimum(t, horizon)[None, :]
    vl = v_lat[act, None]
    want = vl * th  # (A, T) wanted lateral offset
    if lateral_accel is not None:  # a growing sideways speed keeps growing up to LATERAL_SPEED_MAX
        a = np.where(np.sign(lateral_accel[act]) == np.sign(v_lat[act]), lateral_accel[act], 0.0)[:, None]
        ta = np.clip((LATERAL_SPEED_MAX - np.abs(vl)) / np.maximum(np.abs(a), 1e-9), 0.0, None)
        tt = np.minimum(th, ta)
        want = np.clip(vl * th + a * (0.5 * tt**2 + tt * (th - tt)), -LATERAL_SHIFT_MAX, LATERAL_SHIFT_MAX)
    have = np.einsum("ati,ai->at", pred.mean[act] - xy[act, None, :], normal[act])  # already predicted
    extra = np.where(np.abs(want) > np.abs(have) * (np.sign(have) == np.sign(want)), want - have, 0.0)
    mean = pred.mean.copy()
    mean[act] += extra[..., None] * normal[act, None, :]
    return Prediction(ids=pred.ids, dt=pred.dt, mean=mean, cov=pred.cov, yaw=pred.yaw)
