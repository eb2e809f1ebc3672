"""The braking prior keeps a hard-braking agent within its stopping distance (hand-computed)."""

import numpy as np
import pytest

from sumo_ethics.predict.braking import apply_braking_prior, stopping_progress
from sumo_ethics.predict.constant_velocity import ConstantVelocityPredictor
from sumo_ethics.types import AgentStates, Prediction


def _agents(accel: list[float]) -> AgentStates:
    n = len(accel)
    return AgentStates(ids=tuple(f"a{i}" for i in range(n)), x=np.zeros(n), y=np.arange(n) * 10.0,
                       yaw=np.zeros(n), speed=np.full(n, 10.0), accel=np.array(accel, dtype=float),
                       length=np.full(n, 4.5), width=np.full(n, 1.8), mass=np.full(n, 1500.0),
                       cls=np.zeros(n, dtype=np.int8))


def test_stopping_progress_by_hand():
    # 10 m/s at -5 m/s^2: 7.5 m after 1 s, stands after 2 s at 10 m
    got = stopping_progress(np.array([10.0]), np.array([-5.0]), np.array([1.0, 2.0, 3.0]))
    assert got[0] == pytest.approx([7.5, 10.0, 10.0])


def test_hard_braker_capped_others_untouched():
    cur = _agents([-5.0, -1.0])  # a0 brakes hard, a1 gently
    t = np.array([0.5, 1.0, 1.5, 2.0])  # step i at (i + 1) dt, dt = 0.5 s
    pred = ConstantVelocityPredictor().predict_arrays(cur.ids, cur.xy, cur.yaw, cur.speed, cur.cls, t, 0.5)
    out = apply_braking_prior(pred, cur, threshold=3.0)
    # a0: 10 t - 2.5 t^2 (constant velocity would say 5, 10, 15, 20 m)
    assert out.mean[0, :, 0] == pytest.approx([4.375, 7.5, 9.375, 10.0])
    assert np.all(out.mean[0, :, 1] == 0.0)
    assert np.array_equal(out.mean[1], pred.mean[1])  # -1 m/s^2 is below the threshold
    assert np.array_equal(out.cov, pred.cov)


def test_no_braker_returns_same_prediction():
    cur = _agents([0.0, 1.0])
    pred = ConstantVelocityPredictor().predict_arrays(cur.ids, cur.xy, cur.yaw, cur.speed, cur.cls,
                                                      np.array([0.1, 0.2]), 0.1)
    assert apply_braking_prior(pred, cur) is pred


def _one(yaw: float, speed: float, mean: np.ndarray) -> tuple[AgentStates, Prediction]:
    cur = AgentStates(ids=("a",), x=np.zeros(1), y=np.zeros(1), yaw=np.array([yaw]), speed=np.array([speed]),
                      accel=np.zeros(1), length=np.array([4.5]), width=np.array([1.8]), mass=np.array([1500.0]),
                      cls=np.zeros(1, dtype=np.int8))
    T = len(mean)
    return cur, Prediction(ids=("a",), dt=0.1, mean=mean[None], cov=np.tile(np.eye(2), (1, T, 1, 1)),
                           yaw=np.zeros((1, T)))


def test_lateral_prior_continues_a_drift_by_hand():
    from sumo_ethics.predict.braking import apply_lateral_prior

    t = (np.arange(30) + 1) * 0.1
    # heading 0.1 rad left of a straight predicted path along +x at 10 m/s: v_lat = 10 sin 0.1 = 0.998 m/s
    cur, pred = _one(0.1, 10.0, np.stack([10.0 * t, np.zeros(30)], -1))
    out = apply_lateral_prior(pred, cur, horizon=1.5)
    v_lat = 10.0 * np.sin(0.1)
    np.testing.assert_allclose(out.mean[0, :, 1], v_lat * np.minimum(t, 1.5))  # 0.0998 m per 0.1 s, then held
    np.testing.assert_array_equal(out.mean[0, :, 0], pred.mean[0, :, 0])  # progress along the path kept


def test_lateral_prior_leaves_turning_standing_and_aligned_agents():
    from sumo_ethics.predict.braking import apply_lateral_prior

    t = (np.arange(30) + 1) * 0.1
    # a left turn (path direction bends by 0.6 rad): the heading lags the chord, but no prior
    ang = 0.2 * t
    turn = np.stack([np.sin(ang) / 0.2 * 10.0, (1 - np.cos(ang)) / 0.2 * 10.0], -1)
    cur, pred = _one(0.0, 10.0, turn)
    assert apply_lateral_prior(pred, cur) is pred
    cur, pred = _one(0.3, 0.5, np.stack([0.5 * t, np.zeros(30)], -1))  # too slow to count
    assert apply_lateral_prior(pred, cur) is pred
    cur, pred = _one(0.0, 10.0, np.stack([10.0 * t, np.zeros(30)], -1))  # no lateral speed
    assert apply_lateral_prior(pred, cur) is pred


def test_lateral_prior_leaves_gentle_curves_and_predicted_drifts():
    from sumo_ethics.predict.braking import apply_lateral_prior

    t = (np.arange(40) + 1) * 0.1
    # 30 m/s on a 400 m radius, heading along the arc's tangent: a curve, not a drift
    ang = 30.0 * t / 400.0
    arc = np.stack([400.0 * np.sin(ang), 400.0 * (1 - np.cos(ang))], -1)
    cur, pred = _one(0.0, 30.0, arc)
    assert apply_lateral_prior(pred, cur) is pred
    # a gentler curve (total turn 0.08 rad < 0.1): straight enough, and still no lateral speed
    ang = 0.02 * t
    arc = np.stack([np.sin(ang) / 0.02 * 10.0, (1 - np.cos(ang)) / 0.02 * 10.0], -1)
    cur, pred = _one(0.0, 10.0, arc)
    assert np.abs(apply_lateral_prior(pred, cur).mean - pred.mean).max() < 1e-9
    # the model already predicts the drift (1 m/s to the left for 1.5 s, then along): unchanged
    v_lat = 10.0 * np.sin(0.1)
    drift = np.stack([10.0 * np.cos(0.1) * t, v_lat * np.minimum(t, 1.5)], -1)
    cur, pred = _one(0.1, 10.0, drift)
    assert np.abs(apply_lateral_prior(pred, cur).mean - pred.mean).max() < 0.05


def test_braking_after_lateral_stops_the_sideways_motion_too():
    from sumo_ethics.predict.braking import apply_braking_prior, apply_lateral_prior

    t = (np.arange(30) + 1) * 0.1
    cur, pred = _one(0.2, 5.0, np.stack([5.0 * t, np.zeros(30)], -1))
    cur = AgentStates(cur.ids, cur.x, cur.y, cur.yaw, cur.speed, np.array([-9.0]), cur.length, cur.width, cur.mass,
                      cur.cls)
    out = apply_braking_prior(apply_lateral_prior(pred, cur), cur)
    stop = int(np.ceil(5.0 / 9.0 / 0.1))  # stands after 0.56 s
    assert np.abs(out.mean[0, stop:] - out.mean[0, stop]).max() < 1e-9  # no sliding once stopped
    assert out.mean[0, -1, 1] > 0.1  # it did move left while braking
    # it stands v^2 / 2a = 1.389 m along its (slightly bent) path from where it was
    assert np.hypot(*out.mean[0, -1]) == pytest.approx(25.0 / 18.0, abs=0.01)


def _cut_in(since: float, width: float = 3.75, duration: float = 2.33, v: float = 17.6, dt: float = 0.1):
    """A car on the suite's cut-in ramp (sumo_ethics.sim.hazards: lateral offset width * (1 - cos(pi u)) / 2,
    u = time since the start / duration), ``since`` s after it started, with 3 s of straight driving
    before: (Observation, its true lateral offsets 0.1 ... 3.0 s ahead)."""
    import math

    from sumo_ethics.types import Observation

    def offset(s):
        u = np.clip(np.asarray(s, dtype=float) / duration, 0.0, 1.0)
        return width * (0.5 - 0.5 * np.cos(np.pi * u))

    ts = since + dt * np.arange(-30, 1)  # 31 samples, oldest first, the last is now
    hist = np.stack([v * ts, offset(ts)], -1)[None]
    v_lat = math.pi / 2 * width / duration * math.sin(math.pi * min(since / duration, 1.0))
    cur = AgentStates(ids=("a",), x=hist[:, -1, 0], y=hist[:, -1, 1], yaw=np.array([math.atan2(v_lat, v)]),
                      speed=np.array([math.hypot(v, v_lat)]), accel=np.zeros(1), length=np.array([4.5]),
                      width=np.array([1.8]), mass=np.array([1500.0]), cls=np.zeros(1, dtype=np.int8))
    ego = AgentStates(ids=("ego",), x=np.zeros(1), y=np.array([-10.0]), yaw=np.zeros(1), speed=np.zeros(1),
                      accel=np.zeros(1), length=np.array([4.5]), width=np.array([1.8]), mass=np.array([1500.0]),
                      cls=np.zeros(1, dtype=np.int8))
    obs = Observation(time=since, dt=dt, history=hist, valid=np.ones((1, 31), dtype=bool), current=cur, ego=ego)
    return obs, offset(since + dt * np.arange(1, 31)) - offset(since)


def test_recent_motion_by_hand():
    from sumo_ethics.predict.braking import recent_motion

    # 0.3 s into a 3.75 m cut-in over 2.33 s: the chord of the last second runs 17.6 m ahead and
    # 0.151 - 0 m aside (the ramp 0.7 s before its start is still at 0): atan(0.151 / 17.6) = 0.0086 rad
    obs, _ = _cut_in(0.3)
    heading, lateral = recent_motion(obs)
    assert heading[0] == pytest.approx(np.arctan2(3.75 * (0.5 - 0.5 * np.cos(np.pi * 0.3 / 2.33)), 17.6), abs=1e-9)
    # the ramp's lateral acceleration pi^2/2 * 3.75/2.33^2 cos(pi u) at 0.2 s (the second difference of
    # the positions at 0.1, 0.2, 0.3 s is centred there): 3.28 m/s^2, within 2 % (the heading's cosine)
    assert lateral[0] == pytest.approx(np.pi**2 / 2 * 3.75 / 2.33**2 * np.cos(np.pi * 0.2 / 2.33), rel=0.02)
    # fewer than 2 m travelled in the last second: no direction; three positions needed for an acceleration
    obs_slow, _ = _cut_in(0.3, v=1.5)
    assert np.isnan(recent_motion(obs_slow)[0][0])


def test_lateral_onset_sees_a_cut_in_early():
    """0.3 s into the cut-in, a lane-keeping prediction (straight ahead): the onset model puts the car
    within 0.25 m of where the ramp has it 1 s later (2.07 m aside); the constant lateral speed, 1.0 m."""
    from sumo_ethics.predict.braking import apply_lateral_prior, recent_motion

    obs, truth = _cut_in(0.3)
    cur = obs.current
    t = (np.arange(30) + 1) * 0.1
    pred = Prediction(ids=("a",), dt=0.1, mean=np.stack([cur.x[0] + 17.6 * t, np.full(30, cur.y[0])], -1)[None],
                      cov=np.tile(np.eye(2), (1, 30, 1, 1)), yaw=np.zeros((1, 30)))
    travel, lateral = recent_motion(obs)
    onset = apply_lateral_prior(pred, cur, horizon=1.5, travel=travel, lateral_accel=lateral)
    plain = apply_lateral_prior(pred, cur, horizon=1.5)
    aside = onset.mean[0, 9, 1] - cur.y[0]
    assert truth[9] == pytest.approx(2.07, abs=0.01)  # the ramp at 1.3 s minus at 0.3 s
    assert aside == pytest.approx(truth[9], abs=0.25)
    assert plain.mean[0, 9, 1] - cur.y[0] == pytest.approx(1.0, abs=0.05)
    # never more than one lane aside of the direction of travel, whatever the acceleration
    far = apply_lateral_prior(pred, cur, horizon=30.0, travel=travel, lateral_accel=lateral * 10)
    normal = np.array([-np.sin(travel[0]), np.cos(travel[0])])
    across = (far.mean[0] - np.array([cur.x[0], cur.y[0]])) @ normal
    assert np.max(np.abs(across)) == pytest.approx(3.5)


def test_lateral_onset_reads_motion_across_the_travel_not_a_bent_path():
    """A model that already bends its path towards the new lane (here: straight along the car's
    heading, 0.3 s into the cut-in) hides the sideways motion across that path: the old prior sees
    none (the model's 1.0 m a second later stays), the onset model measures it across the last
    second's chord and puts the car within 0.25 m of the ramp's 2.07 m."""
    from sumo_ethics.predict.braking import apply_lateral_prior, recent_motion

    obs, truth = _cut_in(0.3)
    cur = obs.current
    t = (np.arange(30) + 1) * 0.1
    heading = np.array([np.cos(cur.yaw[0]), np.sin(cur.yaw[0])])
    path = np.array([cur.x[0], cur.y[0]]) + cur.speed[0] * t[:, None] * heading
    pred = Prediction(ids=("a",), dt=0.1, mean=path[None], cov=np.tile(np.eye(2), (1, 30, 1, 1)),
                      yaw=np.full((1, 30), cur.yaw[0]))
    assert path[9, 1] - cur.y[0] == pytest.approx(1.0, abs=0.02)  # the model's own: 1 s at ~1.0 m/s sideways
    assert np.array_equal(apply_lateral_prior(pred, cur, horizon=1.5).mean, pred.mean)
    travel, lateral = recent_motion(obs)
    assert np.array_equal(apply_lateral_prior(pred, cur, horizon=1.5, lateral_accel=lateral).mean, pred.mean)
    onset = apply_lateral_prior(pred, cur, horizon=1.5, travel=travel, lateral_accel=lateral)
    assert onset.mean[0, 9, 1] - cur.y[0] == pytest.approx(truth[9], abs=0.25)
