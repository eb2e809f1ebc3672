"""The braking prior keeps a hard-braking agent within its stopping distance (hand-computed)."""

import numpy as np
import pytest

from sumo_ethics.predict.braking import apply_braking_prior, stopping_progress
from sumo_ethics.predict.constant_velocity import ConstantVelocityPredictor
from sumo_ethics.types import AgentStates


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
