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

import numba
import numpy as np

from sumo_ethics.config import EgoVehicle
from sumo_ethics.errors import ConfigError
from sumo_ethics.geometry import Polyline
from sumo_ethics.plan.sampling import interp_at, vertex_walk
from sumo_ethics.types import Candidates, kernel_input

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
    path = route.path
    limit = getattr(route, "speed_limit", None)
    use_limit = speed_limit_factor is not None and limit is not None
    f = kernel_input  # one argument type, whatever the caller passes: one compile
    K, T = cand.x.shape
    road = cand.road_curvature
    res = _check_kernel(
        f(cand.speed, dtype=float), f(cand.accel, dtype=float), f(cand.curvature, dtype=float),
        f(np.zeros((K, T)) if road is None else road, dtype=float), road is not None, f(cand.yaw, dtype=float),
        f(cand.s, dtype=float), f(cand.d, dtype=float), f(cand.valid, dtype=np.bool_), f(path.s, dtype=float),
        path.vertex_heading, f(np.asarray(route.left, dtype=float)), f(np.asarray(route.right, dtype=float)),
        f(limit if use_limit else np.zeros(len(path.s))), use_limit,
        float(speed_limit_factor or 1.0), float(vehicle.max_speed), float(vehicle.max_decel), float(vehicle.max_accel),
        float(vehicle.max_curvature), float(vehicle.max_lat_accel), float(vehicle.length), float(vehicle.width),
        ROAD_CURVATURE_TOL, _TOL)
    return Feasibility(speed_ok=res[0], accel_ok=res[1], curvature_ok=res[2], lat_accel_ok=res[3], on_road=res[4],
                       beyond_limit=res[5], lat_accel_peak=res[6])


@numba.njit(cache=True, nogil=True)
def _check_kernel(v, a, k, kr, has_kr, yaw, s, d, valid, ps, hv, left, right, limit, use_limit, factor, max_speed,
                  max_decel, max_accel, c, max_lat, length, width, road_tol, tol):
    """The verdicts of :func:`check` over (K, T), one pass per candidate."""
    K, T = v.shape
    speed_ok = np.ones(K, dtype=np.bool_)
    accel_ok = np.ones(K, dtype=np.bool_)
    curv_ok = np.ones(K, dtype=np.bool_)
    lat_ok = np.ones(K, dtype=np.bool_)
    on_road = np.ones(K, dtype=np.bool_)
    beyond = np.zeros(K, dtype=np.bool_)
    peak = np.zeros(K)
    for i in range(K):
        j = int(0)
        for t in range(T):
            if not valid[i, t]:
                continue
            x = s[i, t]
            j = vertex_walk(x, ps, j)  # the last vertex at or before s, walked from the step before
            vi = v[i, t]
            ok = vi >= -tol and vi <= max_speed + tol
            if use_limit:
                ok = ok and vi <= factor * limit[j] + tol
            if not ok:
                speed_ok[i] = False
            ai = a[i, t]
            if not (ai >= -max_decel - tol and ai <= max_accel + tol):
                accel_ok[i] = False
            ki = k[i, t]
            upper = c
            lower = -c
            if has_kr:
                r = kr[i, t]
                if r > c:
                    upper = r + road_tol
                if r < -c:
                    lower = r - road_tol
            if not (ki <= upper + tol and ki >= lower - tol):
                curv_ok[i] = False
            if abs(ki) > c + tol:
                beyond[i] = True
            lat = abs(vi * vi * ki)
            if not (lat <= max_lat + tol):
                lat_ok[i] = False
            if lat > peak[i]:
                peak[i] = lat
            psi = yaw[i, t] - interp_at(x, ps, hv, j)
            extent = 0.5 * length * abs(math.sin(psi)) + 0.5 * width * abs(math.cos(psi))
            di = d[i, t]
            if not (di + extent <= interp_at(x, ps, left, j) + tol and di - extent >= interp_at(x, ps, right, j) - tol):
                on_road[i] = False
    return speed_ok, accel_ok, curv_ok, lat_ok, on_road, beyond, peak
