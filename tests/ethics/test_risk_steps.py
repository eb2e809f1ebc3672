"""The "shapes" collision probability on the predictors' 5 Hz grid (``ProbabilityConfig.step``).

Step indices are written out by hand; the grid's entries are compared with those of the
every-step evaluation (``step = 0``), and a pedestrian crossing the ego's path is caught on the
grid because the boxes overlap for longer than 0.2 s (worked out below).
"""

from __future__ import annotations

import numpy as np
import pytest

from sumo_ethics.ethics.probability import ProbabilityConfig, risk_steps, sparse_collision_probability
from sumo_ethics.types import Candidates, Prediction

EGO_L, EGO_W = 4.508, 1.610


@pytest.mark.parametrize("dt, steps, step, expected", [
    (0.1, 40, 0.2, [0] + list(range(1, 40, 2))),  # 0.1 s, then 0.2, 0.4, ..., 4.0 s
    (0.05, 80, 0.2, [0] + list(range(3, 80, 4))),  # 0.05 s, then 0.2, 0.4, ..., 4.0 s
    (0.04, 10, 0.2, [0, 4, 9]),  # 0.04, 0.2, 0.4 s
    (0.2, 20, 0.2, list(range(20))),  # the grid itself
    (1.0, 4, 0.2, list(range(4))),  # 1 s steps: coarser than the grid
    (0.15, 27, 0.2, list(range(27))),  # 0.2 s is no whole number of 0.15 s steps
    (0.1, 40, 0.0, list(range(40))),  # step 0: every step
])
def test_the_steps_evaluated_by_hand(dt, steps, step, expected):
    assert risk_steps(dt, steps, step).tolist() == expected


def _crossing(v: float, dt: float, T: int) -> tuple[Candidates, Prediction]:
    """Ego from x = -20 m along +x at v [m/s]; a pedestrian (0.215 x 0.478 m) crossing at x = 0
    from y = -3 m at 1.4 m/s, heading +y, sigma 0.1 m."""
    t = dt * np.arange(1, T + 1)
    x = -20.0 + v * t
    z = np.zeros((1, T))
    cand = Candidates(dt=dt, x=x[None], y=z.copy(), yaw=z.copy(), speed=np.full((1, T), v), accel=z.copy(),
                      curvature=z.copy(), s=x[None], d=z.copy(), horizon=np.array([T * dt]),
                      valid=np.ones((1, T), bool))
    mean = np.stack([np.zeros(T), -3.0 + 1.4 * t], axis=-1)[None]
    cov = np.broadcast_to(np.diag([0.01, 0.01]), (1, T, 2, 2)).copy()
    return cand, Prediction(("ped",), dt, mean, cov, np.full((1, T), np.pi / 2))


def test_grid_entries_equal_the_every_step_ones_at_the_grid_steps():
    cand, pred = _crossing(10.0, 0.1, 40)
    size = (np.array([0.215]), np.array([0.478]))
    every = sparse_collision_probability(cand, pred, *size, EGO_L, EGO_W, ProbabilityConfig(step=0.0))
    grid = sparse_collision_probability(cand, pred, *size, EGO_L, EGO_W, ProbabilityConfig())
    on = np.isin(every.t, risk_steps(0.1, 40, 0.2))
    assert every.t.size > grid.t.size > 0
    np.testing.assert_array_equal(grid.t, every.t[on])
    np.testing.assert_array_equal(grid.p, every.p[on])  # the same bytes where both evaluate
    assert grid.shape == every.shape == (1, 1, 40)


def test_a_crossing_pedestrian_is_not_missed_between_grid_steps():
    # Ego at 14 m/s, centre at x = 0 at t = 20 / 14 = 1.43 s; the pedestrian (moved to start at
    # y = -2 m) is at y = 0 then. Along x the boxes overlap while the ego centre is within
    # 4.508 / 2 + 0.478 / 2 = 2.493 m of x = 0, i.e. for t in [1.25, 1.61] s (0.356 s > 0.2 s, so
    # a grid step, 1.4 s, falls inside); along y the pedestrian is within 1.61 / 2 + 0.215 / 2 =
    # 0.9125 m of the ego's axis for t in [0.78, 2.08] s.
    v, dt, T = 14.0, 0.1, 40
    cand, pred = _crossing(v, dt, T)
    pred = Prediction(pred.ids, dt, pred.mean + np.array([0.0, 1.0]), pred.cov, pred.yaw)  # y = 0 at t = 1.43 s
    size = (np.array([0.215]), np.array([0.478]))
    every = sparse_collision_probability(cand, pred, *size, EGO_L, EGO_W, ProbabilityConfig(step=0.0)).dense()
    grid = sparse_collision_probability(cand, pred, *size, EGO_L, EGO_W, ProbabilityConfig()).dense()
    assert every.max() > 0.999 and grid.max() > 0.999
    # the steps with a certain overlap: ego centre within 2.493 m of x = 0 -> t in [1.25, 1.61] s
    certain = np.flatnonzero(every[0, 0] > 0.999)
    assert 0.1 * (certain[0] + 1) >= 1.25 - 1e-9 and 0.1 * (certain[-1] + 1) <= 1.61 + 1e-9
