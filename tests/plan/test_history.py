import numpy as np

from sumo_ethics.plan.history import History
from sumo_ethics.types import AgentStates


def agents(ids, xs):
    n = len(ids)
    z = np.zeros(n)
    return AgentStates(tuple(ids), np.array(xs, float), z, z, z, z, z + 4, z + 2, z + 1000, np.zeros(n, np.int8))


def test_history_rows_and_padding():
    h = History(dt=1.0, seconds=3.0)  # 4 rows: t-3 .. t
    ego = agents(["ego"], [0.0])
    h.push(agents(["a"], [1.0]))
    h.push(agents(["a", "b"], [2.0, 10.0]))
    obs = h.observation(1.0, ego, agents(["a", "b"], [2.0, 10.0]))
    assert obs.history.shape == (2, 4, 2)
    np.testing.assert_array_equal(obs.valid, [[False, False, True, True], [False, False, False, True]])
    np.testing.assert_array_equal(obs.history[0, 2:, 0], [1.0, 2.0])


def test_gap_leaves_invalid_rows_and_old_tracks_expire():
    h = History(dt=1.0, seconds=3.0)
    ego = agents(["ego"], [0.0])
    h.push(agents(["a"], [1.0]))
    h.push(agents([], []))
    h.push(agents(["a"], [3.0]))
    obs = h.observation(2.0, ego, agents(["a"], [3.0]))
    np.testing.assert_array_equal(obs.valid[0], [False, True, False, True])
    for _ in range(4):
        h.push(agents([], []))
    assert "a" not in h._xy
