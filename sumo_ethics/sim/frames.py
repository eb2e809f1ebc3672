"""SUMO <-> internal frame conversion; the only place that knows SUMO's conventions.

SUMO: position = centre of the FRONT bumper, angle in navigational degrees
(0 = north, clockwise). Internal: position = vehicle centre, yaw in radians CCW from +x.
"""

from __future__ import annotations

import numpy as np


def sumo_angle_to_yaw(angle_deg: np.ndarray | float) -> np.ndarray:
    """Navigational degrees (0 = north, clockwise) -> yaw [rad] CCW from +x in (-pi, pi]."""
    yaw = np.radians(90.0 - np.asarray(angle_deg, dtype=float))
    return np.pi - np.mod(np.pi - yaw, 2.0 * np.pi)


def yaw_to_sumo_angle(yaw: np.ndarray | float) -> np.ndarray:
    """Yaw [rad] CCW from +x -> navigational degrees in [0, 360)."""
    return np.mod(90.0 - np.degrees(np.asarray(yaw, dtype=float)), 360.0)


def front_to_centre(
    x: np.ndarray, y: np.ndarray, angle_deg: np.ndarray, length: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """SUMO front-bumper pose (..., [m], [deg]) -> internal centre (x, y [m], yaw [rad])."""
    yaw = sumo_angle_to_yaw(angle_deg)
    half = 0.5 * np.asarray(length, dtype=float)
    return np.asarray(x) - half * np.cos(yaw), np.asarray(y) - half * np.sin(yaw), yaw


def centre_to_front(
    x: np.ndarray | float, y: np.ndarray | float, yaw: np.ndarray | float, length: np.ndarray | float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Internal centre pose (x, y [m], yaw [rad]) -> SUMO front bumper (x, y [m], angle [deg])."""
    half = 0.5 * np.asarray(length, dtype=float)
    yaw = np.asarray(yaw, dtype=float)
    return np.asarray(x) + half * np.cos(yaw), np.asarray(y) + half * np.sin(yaw), yaw_to_sumo_angle(yaw)
