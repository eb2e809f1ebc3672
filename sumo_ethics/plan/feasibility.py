"""Physical feasibility and road keeping of candidate trajectories, vectorised over (K, T).

Origin checks speed, curvature and lateral acceleration but never longitudinal acceleration;
we check all four, plus whether the ego's body stays inside the drivable area.
Only a candidate's ``valid`` steps are checked.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from sumo_ethics.config import EgoVehicle
from sumo_ethics.errors import ConfigError
from sumo_ethics.geometry import Polyline
from sumo_ethics.plan.sampling import reference_heading
from sumo_ethics.types import Candidates

__all__ = ["Feasibility", "RouteLike", "check"]

# absolute slack on every bound, for round-off in the sampled profiles
_TOL = 1e-9


class RouteLike(Protocol):
    """What :func:`check` needs of a route (``sim.route.RoutePath`` fits).

    path: the reference path; left, right: (M,) drivable lateral bounds [m] at the path's
    vertices, left > 0 > right; speed_limit: (M,) [m/s] (optional attribute).
    """

    path: Polyline
    left: np.ndarray
    right: np.ndarray


@dataclass(frozen=True)
class Feasibility:
    """Per-candidate verdicts, each (K,) bool.

    speed_ok: 0 <= speed <= max_speed (and <= factor x speed limit, if checked) at every step;
    a negative (signed) speed means the profile reverses along the path.
    accel_ok: -max_decel <= accel <= max_accel. curvature_ok: |curvature| <= max_curvature.
    lat_accel_ok: |speed^2 curvature| <= max_lat_accel. on_road: body inside the drivable area.
    """

    speed_ok: np.ndarray
    accel_ok: np.ndarray
    curvature_ok: np.ndarray
    lat_accel_ok: np.ndarray
    on_road: np.ndarray

    @property
    def feasible(self) -> np.ndarray:
        """(K,) physically feasible: speed, acceleration, curvature and lateral acceleration ok."""
        return self.speed_ok & self.accel_ok & self.curvature_ok & self.lat_accel_ok

    @property
    def admissible(self) -> np.ndarray:
        """(K,) feasible and on the road."""
        return self.feasible & self.on_road


def check(cand: Candidates, route: RouteLike, vehicle: EgoVehicle,
          speed_limit_factor: float | None = 1.0) -> Feasibility:
    """Check every candidate against the ego's limits and the drivable area.

    speed_limit_factor: also require speed <= factor x the route's speed limit, taken at the
    path vertex at or before each step's s (limits change at lane starts); None, or a route
    without ``speed_limit``, checks only ``vehicle.max_speed``.

    on_road: at every valid step the body's lateral half extent across the path,
    L/2 |sin(psi)| + W/2 |cos(psi)| with psi = yaw - reference heading (the body's yaw is
    included, so a car angled across a lane change reaches further out), must satisfy
    right(s) <= d - extent and d + extent <= left(s), bounds linearly interpolated in s.
    """
    if speed_limit_factor is not None and not (math.isfinite(speed_limit_factor) and speed_limit_factor > 0):
        raise ConfigError(f"speed_limit_factor must be a positive number or None, got {speed_limit_factor!r}")
    valid = np.asarray(cand.valid, dtype=bool)
    invalid = ~valid

    def every(ok: np.ndarray) -> np.ndarray:
        return np.all(ok | invalid, axis=1)

    v, a, k = cand.speed, cand.accel, cand.curvature
    path = route.path
    speed_ok = (v >= -_TOL) & (v <= vehicle.max_speed + _TOL)
    limit = getattr(route, "speed_limit", None)
    if speed_limit_factor is not None and limit is not None:
        idx = np.clip(np.searchsorted(path.s, cand.s, side="right") - 1, 0, len(path.s) - 1)
        speed_ok &= v <= speed_limit_factor * np.asarray(limit, dtype=float)[idx] + _TOL
    accel_ok = (a >= -vehicle.max_decel - _TOL) & (a <= vehicle.max_accel + _TOL)
    curvature_ok = np.abs(k) <= vehicle.max_curvature + _TOL
    lat_accel_ok = np.abs(v * v * k) <= vehicle.max_lat_accel + _TOL

    psi = cand.yaw - reference_heading(path, cand.s)
    extent = 0.5 * vehicle.length * np.abs(np.sin(psi)) + 0.5 * vehicle.width * np.abs(np.cos(psi))
    left = np.interp(cand.s, path.s, np.asarray(route.left, dtype=float))
    right = np.interp(cand.s, path.s, np.asarray(route.right, dtype=float))
    on_road = (cand.d + extent <= left + _TOL) & (cand.d - extent >= right - _TOL)

    return Feasibility(
        speed_ok=every(speed_ok), accel_ok=every(accel_ok), curvature_ok=every(curvature_ok),
        lat_accel_ok=every(lat_accel_ok), on_road=every(on_road),
    )
