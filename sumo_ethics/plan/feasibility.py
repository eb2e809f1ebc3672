"""Physical feasibility and road keeping of candidate trajectories, vectorised over (K, T).

Origin checks speed, curvature and lateral acceleration but never longitudinal acceleration;
we check all four, plus whether the ego's body stays inside the drivable area.
Only a candidate's ``valid`` steps are checked.

Curvature judges what the ego adds to the road, not the road itself. Junction shapes built
from OpenStreetMap are often tighter than a car's turning circle (eclipse-sumo's bs3d network
has a right turn of about 2 m radius, 2.4 m on the smoothed reference path); a limit applied to
the road's own bend left the ego no moving candidate there, so it braked and stood in the
junction for the rest of the run.
So where the road bends tighter than ``max_curvature`` a step's curvature may follow it, in the
road's direction, up to the road's own curvature at that step plus :data:`ROAD_CURVATURE_TOL`;
elsewhere the limit holds as before. The lateral acceleration limit still applies, so the ego
slows down to sqrt(max_lat_accel / |k|) in such a bend.
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

__all__ = ["Feasibility", "LAT_ACCEL_RELAX", "ROAD_CURVATURE_TOL", "RouteLike", "check"]

# absolute slack on every bound, for round-off in the sampled profiles
_TOL = 1e-9

#: [m/s^2] slack over the least peak lateral acceleration of any candidate when none keeps the limit
#: (Feasibility.least_lateral)
LAT_ACCEL_RELAX = 0.25

#: curvature [1/m] a candidate may add to a road that bends tighter than the vehicle's
#: ``max_curvature``: room to correct a small lateral offset inside such a bend (a 0.3 m
#: correction over 5 m of travel needs about 0.07 1/m at its peak, over 7 m 0.035 1/m),
#: not to swerve
ROAD_CURVATURE_TOL = 0.05


class RouteLike(Protocol):
    """What :func:`check` needs of a route (``sim.route.RoutePath`` fits).

    path: the reference path; left, right: (M,) drivable lateral bounds [m] at the path's
    vertices, left > 0 > right; speed_limit: (M,) [m/s] (optional attribute).
    """

    @property
    def path(self) -> Polyline: ...

    @property
    def left(self) -> np.ndarray: ...

    @property
    def right(self) -> np.ndarray: ...


@dataclass(frozen=True)
class Feasibility:
    """Per-candidate verdicts, each (K,) bool.

    speed_ok: 0 <= speed <= max_speed (and <= factor x speed limit, if checked) at every step;
    a negative (signed) speed means the profile reverses along the path.
    accel_ok: -max_decel <= accel <= max_accel.
    curvature_ok: lower <= curvature <= upper at every step, [lower, upper] the vehicle's
    [-max_curvature, max_curvature] widened towards the road where it bends tighter (see check).
    lat_accel_ok: |speed^2 curvature| <= max_lat_accel. on_road: body inside the drivable area.
    beyond_limit: |curvature| > max_curvature at some step, i.e. the candidate (if curvature_ok)
    follows a road bend tighter than the vehicle's own limit.
    lat_accel_peak: (K,) float, the largest |speed^2 curvature| over the valid steps [m/s^2].
    """

    speed_ok: np.ndarray
    accel_ok: np.ndarray
    curvature_ok: np.ndarray
    lat_accel_ok: np.ndarray
    on_road: np.ndarray
    beyond_limit: np.ndarray
    lat_accel_peak: np.ndarray

    @property
    def feasible(self) -> np.ndarray:
        """(K,) physically feasible: speed, acceleration, curvature and lateral acceleration ok."""
        return self.speed_ok & self.accel_ok & self.curvature_ok & self.lat_accel_ok

    def least_lateral(self, tol: float = LAT_ACCEL_RELAX) -> tuple[np.ndarray, float]:
        """((K,) bool, limit [m/s^2]) for when no candidate is feasible: the candidates feasible in
        speed, acceleration and curvature whose peak lateral acceleration is within ``tol`` of the
        least any of them reaches, and that relaxed limit (nan and none when no candidate keeps the
        other three). Where the road bends tighter than the ego's speed allows (a takeover at
        SUMO's speed on a ramp's junction lane) every candidate breaks max_lat_accel in its first
        steps whatever it does; these are the ones that break it least."""
        base = self.speed_ok & self.accel_ok & self.curvature_ok
        if not base.any():
            return base, float("nan")
        limit = float(self.lat_accel_peak[base].min()) + tol
        return base & (self.lat_accel_peak <= limit), limit

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

    curvature, per step (K, T), with k = ``cand.curvature``, k_r = ``cand.road_curvature`` [1/m]
    (0 if the candidates do not carry it: the plain limit) and c = max_curvature:
    upper = k_r + ROAD_CURVATURE_TOL where k_r > c, else c; lower = k_r - ROAD_CURVATURE_TOL where
    k_r < -c, else -c; lower <= k <= upper. A candidate on the reference path (k == k_r) passes
    however tight the path bends; turning tighter than such a bend by more than the tolerance,
    against its direction beyond c, or beyond c where the road does not need it, fails. Unlike
    the symmetric |k| <= max(c, |k_r| + tol) it keeps the sign (a left turn of 0.5 1/m in a right
    bend of 0.5 1/m adds 1 1/m to the road) and never relaxes c where the road is within it.
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
    c = vehicle.max_curvature
    upper: np.ndarray | float = c
    lower: np.ndarray | float = -c
    if cand.road_curvature is not None:
        kr = cand.road_curvature
        upper = np.where(kr > c, kr + ROAD_CURVATURE_TOL, c)
        lower = np.where(kr < -c, kr - ROAD_CURVATURE_TOL, -c)
    curvature_ok = (k <= upper + _TOL) & (k >= lower - _TOL)
    beyond = np.abs(k) > c + _TOL
    lat = np.abs(v * v * k)
    lat_accel_ok = lat <= vehicle.max_lat_accel + _TOL

    psi = cand.yaw - reference_heading(path, cand.s)
    extent = 0.5 * vehicle.length * np.abs(np.sin(psi)) + 0.5 * vehicle.width * np.abs(np.cos(psi))
    left = np.interp(cand.s, path.s, np.asarray(route.left, dtype=float))
    right = np.interp(cand.s, path.s, np.asarray(route.right, dtype=float))
    on_road = (cand.d + extent <= left + _TOL) & (cand.d - extent >= right - _TOL)

    return Feasibility(
        speed_ok=every(speed_ok), accel_ok=every(accel_ok), curvature_ok=every(curvature_ok),
        lat_accel_ok=every(lat_accel_ok), on_road=every(on_road), beyond_limit=np.any(beyond & valid, axis=1),
        lat_accel_peak=np.where(valid, lat, 0.0).max(axis=1),
    )
