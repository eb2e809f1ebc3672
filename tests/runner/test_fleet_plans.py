"""Plan sharing in a fleet (``share_plans``): an ego's committed plan, published after it plans,
is what the other egos predict for it from the next step on (one mode, a tracking spread)."""

from __future__ import annotations

import numpy as np
import pytest

from sumo_ethics.predict.constant_velocity import ConstantVelocityPredictor
from sumo_ethics.runner.fleet import PLAN_SIGMA0, PLAN_SIGMA_RATE, SharedPrediction
from sumo_ethics.types import AgentStates, Observation

DT = 0.1


def _obs(t: float) -> Observation:
    """Two vehicles: the ego e1 at (0, 0) heading +x at 10 m/s, a car c1 at (30, 3.5) at 8 m/s."""
    cur = AgentStates(("c1", "e1"), np.array([30.0, 0.0]), np.array([3.5, 0.0]), np.zeros(2), np.array([8.0, 10.0]),
                      np.zeros(2), np.full(2, 4.5), np.full(2, 1.8), np.full(2, 1400.0), np.zeros(2, np.int8))
    return Observation(time=t, dt=DT, history=np.zeros((2, 1, 2)), valid=np.ones((2, 1), bool), current=cur,
                       ego=cur.take([1]))


def test_a_published_plan_is_the_egos_prediction_from_the_next_step():
    shared = SharedPrediction(ConstantVelocityPredictor())
    shared.begin(_obs(0.0))
    # e1's plan at t = 0: a lane change to y = 3 over its 40 steps (x at 10 m/s)
    T = 40
    t = DT * np.arange(1, T + 1)
    x, y, yaw = 10.0 * t, 3.0 * np.minimum(t / 3.0, 1.0), np.zeros(T)
    shared.publish("e1", 0.0, x, y, yaw)
    same_step = shared.predict(_obs(0.0), T, DT, plans=True)
    assert same_step.mean[1, 0, 1] == 0.0  # not used within the step it was published in (cv: y stays 0)
    shared.begin(_obs(2 * DT))  # two steps on
    pred = shared.predict(_obs(2 * DT), T, DT, plans=True)
    e1 = list(pred.ids).index("e1")
    # now + (j + 1) dt is the plan's step j + 2: x = 10 (j + 3) dt, y from the lane change
    np.testing.assert_allclose(pred.mean[e1, :38, 0], x[2:])
    np.testing.assert_allclose(pred.mean[e1, :38, 1], y[2:])
    # past the plan's end it goes on at its last speed (10 m/s) and heading (0)
    np.testing.assert_allclose(pred.mean[e1, 38:, 0], x[-1] + 10.0 * DT * np.array([1.0, 2.0]))
    np.testing.assert_allclose(pred.mean[e1, 38:, 1], y[-1])
    sig = PLAN_SIGMA0 + PLAN_SIGMA_RATE * t
    np.testing.assert_allclose(pred.cov[e1, :, 0, 0], sig**2)
    np.testing.assert_allclose(pred.cov[e1, :, 0, 1], 0.0)
    # the other road user keeps the model's prediction, and so does e1 without plans
    c1 = list(pred.ids).index("c1")
    base = shared.predict(_obs(2 * DT), T, DT)
    np.testing.assert_array_equal(pred.mean[c1], base.mean[c1])
    assert base.mean[e1, 0, 1] == 0.0 and base.mean[e1, 0, 0] == pytest.approx(10.0 * DT)


def test_a_plan_of_an_ego_gone_from_the_scene_is_dropped():
    shared = SharedPrediction(ConstantVelocityPredictor())
    shared.begin(_obs(0.0))
    shared.publish("e9", 0.0, np.zeros(3), np.zeros(3), np.zeros(3))
    shared.begin(_obs(DT))
    assert "e9" not in shared.shared
