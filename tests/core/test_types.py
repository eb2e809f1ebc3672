import numpy as np
import pytest

from sumo_ethics.types import AgentStates


def _cols(n):
    z = np.arange(n, dtype=float)
    return (z, z + 1, z + 2, z + 3, z + 4, z + 5, z + 6, z + 7, np.zeros(n, dtype=np.int8))


def test_trusted_matches_checked_construction_and_is_read_only():
    ids, types = ("a", "b", "c"), ("t1", "t2", "t3")
    checked = AgentStates(ids, *_cols(3), type_id=types)
    fast = AgentStates.trusted(ids, *_cols(3), types)
    for name in ("x", "y", "yaw", "speed", "accel", "length", "width", "mass", "cls"):
        np.testing.assert_array_equal(getattr(fast, name), getattr(checked, name))
        with pytest.raises(ValueError):
            getattr(fast, name)[0] = 1
    assert fast.ids == ids and fast.type_id == types and len(fast) == 3
    assert fast.index == {"a": 0, "b": 1, "c": 2}
    sub = fast.take([2, 0])
    assert sub.ids == ("c", "a") and sub.type_id == ("t3", "t1") and sub.x.tolist() == [2.0, 0.0]


def test_checked_construction_still_validates():
    with pytest.raises(ValueError):
        AgentStates(("a", "b"), *_cols(3))
