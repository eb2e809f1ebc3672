"""SUMO <-> internal frame conversions, by hand and round trip."""

import numpy as np
import pytest

from sumo_ethics.sim.frames import centre_to_front, front_to_centre, sumo_angle_to_yaw, yaw_to_sumo_angle


def test_compass_angles():
    # north = +y, east = +x, south, west
    assert sumo_angle_to_yaw([0, 90, 180, 270]) == pytest.approx([np.pi / 2, 0.0, -np.pi / 2, np.pi])
    assert yaw_to_sumo_angle([np.pi / 2, 0.0, -np.pi / 2, np.pi]) == pytest.approx([0, 90, 180, 270])


def test_front_bumper_to_centre_by_hand():
    # a 4 m car facing north-east (SUMO 45 deg) with its front at (10, 10): centre 2 m back
    x, y, yaw = front_to_centre(10.0, 10.0, 45.0, 4.0)
    assert (x, y, yaw) == pytest.approx((10 - np.sqrt(2), 10 - np.sqrt(2), np.pi / 4))


def test_round_trip():
    rng = np.random.default_rng(0)
    x, y, ang, length = rng.uniform(-500, 500, 100), rng.uniform(-500, 500, 100), rng.uniform(0, 360, 100), \
        rng.uniform(0.2, 18, 100)
    fx, fy, fa = centre_to_front(*front_to_centre(x, y, ang, length), length)
    assert fx == pytest.approx(x, abs=1e-9) and fy == pytest.approx(y, abs=1e-9)
    assert np.abs((fa - ang + 180) % 360 - 180).max() < 1e-9
