"""Candidate ego trajectories sampled in the Frenet frame of the reference path (Werling et al. 2010).

Grid (METHOD.md section 3, enlarged): every horizon T x every end speed x every lateral end
offset. Longitudinal motion is a quartic s(t) (start position, speed and acceleration, end
speed with zero end acceleration); lateral motion a quintic d(t) (start offset, rate and
acceleration, end offset with zero rate and acceleration), or below ``low_speed`` a quintic
d(s) over the arc length travelled, which stays well defined when the ego barely moves.

All candidates share one time grid t = dt, 2 dt, ..., ceil(max(horizons) / dt) dt. Past its
own horizon a candidate keeps its end speed along the path at constant offset d_end: those
states are what the ego would do next, so they stay ``valid``; ``Candidates.horizon`` records T.

Candidate k is grid point (i_T, i_v, i_d) in C order: k = (i_T * n_speeds + i_v) * n_offsets + i_d.

The coefficients and the path lookups are numpy on the small (horizon, end speed, step) arrays; the
full-size (candidate, step) part is one numba kernel (:func:`_cartesian_kernel`, nogil: a fleet's egos
sample on several threads at once).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

from typing import cast

import numba
import numpy as np

from sumo_ethics.errors import ConfigError, is_number
from sumo_ethics.geometry import Polyline, wrap_angle
from sumo_ethics.types import Candidates

__all__ = [
    "SamplingConfig",
    "FrenetState",
    "sample",
    "end_speeds",
    "quartic_coeffs",
    "quintic_coeffs",
    "reference_heading",
]

# below this speed [m/s] the heading along the candidate is held from the last moving step
_STILL = 1e-2
# guards for the low-speed start state: d' = d_dot / s_dot only above this speed [m/s] ...
_DERIV_SPEED = 0.1
# ... and clipped to these magnitudes (|d'| <= 1 is a 45 degree heading offset; |d''| in 1/m)
_MAX_D1, _MAX_D2 = 1.0, 1.0
# arc length [m] below which a low-speed candidate cannot move sideways (it stays at d0)
_MIN_TRAVEL = 1e-3


def _finite(name: str, value: object) -> float:
    if not is_number(value):
        raise ConfigError(f"sampling.{name} must be a finite number, got {value!r}")
    return float(cast(float, value))  # is_number: a finite real number


def _count(name: str, value: object) -> None:
    if not is_number(value, 1, integer=True):
        raise ConfigError(f"sampling.{name} must be an integer >= 1, got {value!r}")


@dataclass(frozen=True)
class SamplingConfig:
    """The candidate grid. Units in the field comments.

    End speeds: ``n_speeds`` values evenly spaced over [0, v_max] including both ends
    (``np.linspace(0, v_max, n_speeds)``); ``n_speeds == 1`` gives v_max alone.
    Lateral end offsets: ``n_offsets`` values evenly spaced over the drivable interval at the
    candidate's end station (see :func:`sample`), intersected with [-max_offset, max_offset];
    ``n_offsets == 1`` gives the point of that interval nearest the path (d = 0).
    Bare defaults: 3 horizons x 15 x 23 = 1035 candidates (Origin: 1 x 15 x 15 = 225); the
    planner's default grid is PlannerConfig's (4 horizons x 15 x 17 = 1020).
    """

    horizons: tuple[float, ...] = (2.0, 3.0, 4.0)  # s
    # s, output step; the ethical planner samples at the run's step (EthicalPlanner.plan sets dt to the
    # scene's; settings.planner_config refuses a [planner.sampling] dt that differs from it)
    dt: float = 0.1
    n_speeds: int = 15
    n_offsets: int = 23
    max_offset: float = 3.5  # m
    low_speed: float = 3.0  # m/s: below this (start speed) the lateral profile is d(s), not d(t)

    def __post_init__(self) -> None:
        dt = _finite("dt", self.dt)
        if dt <= 0:
            raise ConfigError(f"sampling.dt must be positive, got {self.dt!r}")
        try:
            hs = tuple(self.horizons)
        except TypeError:
            raise ConfigError(f"sampling.horizons must be a sequence of seconds, got {self.horizons!r}") from None
        if not hs:
            raise ConfigError("sampling.horizons must hold at least one horizon [s]")
        for h in hs:
            if _finite("horizons", h) < dt:
                raise ConfigError(f"sampling.horizons must each be at least one step (dt = {dt} s), got {h!r}")
        object.__setattr__(self, "horizons", tuple(float(h) for h in hs))
        _count("n_speeds", self.n_speeds)
        _count("n_offsets", self.n_offsets)
        if _finite("max_offset", self.max_offset) < 0:
            raise ConfigError(f"sampling.max_offset must be >= 0, got {self.max_offset!r}")
        if _finite("low_speed", self.low_speed) < 0:
            raise ConfigError(f"sampling.low_speed must be >= 0, got {self.low_speed!r}")

    @property
    def n_steps(self) -> int:
        """T: output steps covering the longest horizon."""
        return int(math.ceil(max(self.horizons) / self.dt - 1e-9))

    @property
    def n_candidates(self) -> int:
        """K = len(horizons) * n_speeds * n_offsets."""
        return len(self.horizons) * self.n_speeds * self.n_offsets


@dataclass(frozen=True)
class FrenetState:
    """The ego's start state in the path's Frenet frame.

    s, d: arc length and lateral offset (left positive) [m]; s_dot, s_ddot: their first and
    second time derivatives along the path [m/s, m/s^2]; d_dot, d_ddot: lateral rate [m/s]
    and acceleration [m/s^2].
    """

    s: float
    d: float
    s_dot: float
    s_ddot: float = 0.0
    d_dot: float = 0.0
    d_ddot: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if not is_number(v):
                raise ConfigError(f"FrenetState.{f.name} must be a finite number, got {v!r}")
            object.__setattr__(self, f.name, float(v))

    @classmethod
    def at_speed(cls, path: Polyline, s: float, d: float, speed: float, s_ddot: float = 0.0, d_dot: float = 0.0,
                 d_ddot: float = 0.0) -> FrenetState:
        """The start state of a vehicle at (s, d) [m] moving at ``speed`` [m/s] with lateral rate
        ``d_dot`` [m/s]: s_dot is chosen so that the candidates of :func:`sample` start at
        ``speed``, i.e. sqrt((s_dot (1 - kappa_r d))^2 + d_dot^2) = speed with kappa_r =
        ``path.curvature_at(s)``. Taking s_dot = speed instead starts them off by up to a few
        tenths of a m/s beside a curve or while moving sideways: a jump the feasibility check
        never sees (A10KW: 1.3 m/s^2 on top of a 3 m/s^2 candidate). |d_dot| is capped at
        speed sin(45 deg) (the heading offset the low-speed d(s) profile allows)."""
        speed = max(float(speed), 0.0)
        cap = speed * math.sqrt(0.5)
        d_dot = min(max(float(d_dot), -cap), cap)
        one = max(1.0 - float(path.curvature_at(s)) * d, 1e-3)
        s_dot = math.sqrt(max(speed * speed - d_dot * d_dot, 0.0)) / one
        return cls(s=s, d=d, s_dot=s_dot, s_ddot=s_ddot, d_dot=d_dot, d_ddot=d_ddot)

    @classmethod
    def from_cartesian(cls, path: Polyline, x: float, y: float, yaw: float, speed: float,
                       accel: float = 0.0, curvature: float = 0.0,
                       near: tuple[float, float] | None = None) -> "FrenetState":
        """Frenet state of a vehicle at (x, y) [m] heading ``yaw`` [rad] with ``speed`` [m/s],
        longitudinal ``accel`` [m/s^2] and path ``curvature`` [1/m].

        Uses the smooth :func:`reference_heading` and ``path.curvature_at``; neglects the
        derivative of the path's curvature. ``near`` as in :meth:`Polyline.project`.
        """
        s, d = (float(v) for v in path.project(np.array([x, y], dtype=float), near=near))
        kr = float(path.curvature_at(s))
        dth = float(wrap_angle(yaw - reference_heading(path, np.asarray(s))))
        one = max(1.0 - kr * d, 1e-3)
        c, sn = math.cos(dth), math.sin(dth)
        s_dot = speed * c / one
        d_dot = speed * sn
        dth_dot = speed * curvature - kr * s_dot  # rate of the heading offset
        d_ddot = accel * sn + speed * c * dth_dot
        s_ddot = (accel * c - speed * sn * dth_dot + s_dot * kr * d_dot) / one
        return cls(s=s, d=d, s_dot=s_dot, s_ddot=s_ddot, d_dot=d_dot, d_ddot=d_ddot)


# --------------------------------------------------------------------------- polynomials
def quartic_coeffs(v0: np.ndarray | float, a0: np.ndarray | float, v_end: np.ndarray | float,
                   T: np.ndarray | float) -> np.ndarray:
    """Quartic s(t) - s0 = c1 t + c2 t^2 + c3 t^3 + c4 t^4 with s'(0) = v0, s''(0) = a0,
    s'(T) = v_end, s''(T) = 0. Inputs broadcast [m/s, m/s^2, m/s, s]; returns (..., 5)
    coefficients c0..c4 (c0 = 0) in ascending powers of t.
    """
    v0, a0, v_end, T = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (v0, a0, v_end, T)))
    V = v_end - v0 - a0 * T  # speed still to gain after the start acceleration
    A = -a0  # acceleration still to gain
    c3 = (3.0 * V - A * T) / (3.0 * T**2)
    c4 = (A * T - 2.0 * V) / (4.0 * T**3)
    return np.stack([np.zeros_like(v0), v0, a0 / 2.0, c3, c4], axis=-1)


def quintic_coeffs(x0: np.ndarray | float, x1: np.ndarray | float, x2: np.ndarray | float, x_end: np.ndarray | float,
                   T: np.ndarray | float) -> np.ndarray:
    """Quintic x(u) = c0 + ... + c5 u^5 with x(0) = x0, x'(0) = x1, x''(0) = x2, x(T) = x_end,
    x'(T) = x''(T) = 0, for u in [0, T] (time [s] or arc length [m]). Inputs broadcast;
    returns (..., 6) coefficients in ascending powers of u.
    """
    x0, x1, x2, x_end, T = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (x0, x1, x2, x_end, T)))
    c2 = x2 / 2.0
    D = x_end - (x0 + x1 * T + c2 * T**2)  # remaining gap in value, rate and acceleration
    D1 = -(x1 + 2.0 * c2 * T)
    D2 = -x2
    c3 = (10.0 * D - 4.0 * D1 * T + 0.5 * D2 * T**2) / T**3
    c4 = (-15.0 * D + 7.0 * D1 * T - D2 * T**2) / T**4
    c5 = (6.0 * D - 3.0 * D1 * T + 0.5 * D2 * T**2) / T**5
    return np.stack([x0, x1, c2, c3, c4, c5], axis=-1)


def _horner(c: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Value, first and second derivative of polynomials c (..., P) at u (broadcast)."""
    p = c.shape[-1]
    v = c[..., p - 1]
    d1 = np.zeros_like(v)
    d2 = np.zeros_like(v)
    for i in range(p - 2, -1, -1):  # loop over polynomial degree only (<= 5)
        d2 = d2 * u + 2.0 * d1
        d1 = d1 * u + v
        v = v * u + c[..., i]
    return v, d1, d2


def end_speeds(cfg: SamplingConfig, v_max: float) -> np.ndarray:
    """(n_speeds,) end speeds [m/s]: linspace(0, v_max, n_speeds); just v_max if n_speeds == 1."""
    if cfg.n_speeds == 1:
        return np.array([float(v_max)])
    return np.linspace(0.0, float(v_max), cfg.n_speeds)


def reference_heading(path: Polyline, s: np.ndarray) -> np.ndarray:
    """Smooth (continuous) heading [rad] of the path at arc length s, any shape.

    Each interior vertex takes the mean of its two segments' headings, the end vertices their
    segment's heading; in between the heading is linearly interpolated in s (constant beyond
    the ends). Unlike ``Polyline.heading_at`` it does not jump at vertices, so headings built
    on it can be differenced into a curvature. Result is not wrapped.
    """
    return np.interp(s, path.s, path.vertex_heading)


def _bound_at(bound: float | np.ndarray | None, path: Polyline, s: np.ndarray, default: float) -> np.ndarray:
    if bound is None:
        return np.full(np.shape(s), default)
    b = np.asarray(bound, dtype=float)
    if b.ndim == 0:
        return np.full(np.shape(s), float(b))
    if b.shape != path.s.shape:
        raise ConfigError(f"lateral bounds must be a number or one value per path vertex {path.s.shape}, got {b.shape}")
    return np.interp(s, path.s, b)


# --------------------------------------------------------------------------- sampling
def _heading_curvature(heading: np.ndarray, heading0: float, speed: np.ndarray, speed0: float, dt: float,
                       out: np.ndarray, step: np.ndarray, dh: np.ndarray, den: np.ndarray) -> None:
    """Curvature [1/m] of a path sampled every ``dt`` [s], written into ``out`` (..., T): the central
    difference of ``heading`` [rad] over the distance travelled (trapezoidal in ``speed`` [m/s]),
    one-sided at the last step, from ``heading0`` and ``speed0`` before step 0; 0 where that
    distance is under _MIN_TRAVEL. step, dh, den: scratch arrays of the same shape (overwritten)."""
    step[..., 0] = speed[..., 0] + speed0
    np.add(speed[..., 1:], speed[..., :-1], out=step[..., 1:])
    step *= 0.5 * dt  # distance travelled into each step [m]
    dh[..., 0] = heading[..., 0] - heading0
    np.subtract(heading[..., 1:], heading[..., :-1], out=dh[..., 1:])  # heading change into each step
    np.add(dh[..., :-1], dh[..., 1:], out=out[..., :-1])
    out[..., -1] = dh[..., -1]
    np.add(step[..., :-1], step[..., 1:], out=den[..., :-1])
    den[..., -1] = step[..., -1]
    moved = den > _MIN_TRAVEL
    np.divide(out, den, out=out, where=moved)
    np.copyto(out, 0.0, where=~moved)


@numba.njit(cache=True, nogil=True)
def _cartesian_kernel(de, lat, along_path, low, dth0, yaw0, v_start, dt, out, row0):  # pragma: no cover - compiled
    """The full-size part of :func:`sample`, one pass per candidate: de (nH, nV, nD) lateral end offsets;
    lat (6, nH, 1 or nV, T) the lateral quintic's value, 1st and 2nd derivative for end offset 0, then
    per metre of it; along_path (10, nH, nV, T) the path's x, y, sin and cos of its heading, curvature,
    reference heading, then s_dot, s_ddot, s and the road's curvature at each station; writes x, y, yaw,
    speed, accel, curvature, s, d, road_curvature into rows row0 ... row0 + nH nV nD - 1 of out (9, K', T),
    candidate (h, v, k) at row row0 + (h nV + v) nD + k. The arithmetic is the numpy formulation's,
    operation for operation."""
    nH, nV, nD = de.shape
    nT = lat.shape[3]
    q0, q1, q2, b0, b1, b2 = lat[0], lat[1], lat[2], lat[3], lat[4], lat[5]
    xc, yc, sin_h, cos_h, kr = along_path[0], along_path[1], along_path[2], along_path[3], along_path[4]
    href, sd, sdd, s_abs, kref = along_path[5], along_path[6], along_path[7], along_path[8], along_path[9]
    per_speed = lat.shape[2] > 1
    two_pi = 2.0 * np.pi
    inv_two_pi = 1.0 / (2.0 * np.pi)
    for h in range(nH):
        for v in range(nV):
            w = v if per_speed else 0
            for k in range(nD):
                r = row0 + (h * nV + v) * nD + k
                e = de[h, v, k]
                held = dth0
                for t in range(nT):
                    d = e * b0[h, w, t] + q0[h, w, t]
                    d_dot = e * b1[h, w, t] + q1[h, w, t]
                    d_ddot = e * b2[h, w, t] + q2[h, w, t]
                    out[0, r, t] = xc[h, v, t] - d * sin_h[h, v, t]
                    out[1, r, t] = d * cos_h[h, v, t] + yc[h, v, t]
                    one = 1.0 - kr[h, v, t] * d
                    s1 = sd[h, v, t]
                    s2 = sdd[h, v, t]
                    rel = 0.0
                    if low:
                        rel = math.atan2(d_dot, one)  # d(s) is a geometric path: its slope exists at standstill
                        d_ddot = d_ddot * (s1 * s1) + d_dot * s2  # d_ddot = d'' s_dot^2 + d' s_ddot
                        d_dot = d_dot * s1  # d_dot = d' s_dot
                    along = s1 * one
                    speed = math.sqrt(along * along + d_dot * d_dot)
                    still = speed < _STILL
                    acc = ((s2 * one - (s1 * kr[h, v, t]) * d_dot) * along) + d_dot * d_ddot
                    acc = s2 if still else acc / speed
                    if not low:
                        if still:  # hold the heading from the last moving step
                            rel = held
                        else:
                            rel = math.atan2(d_dot, along)
                            held = rel
                    out[2, r, t] = rel + href[h, v, t]  # unwrapped for the curvature below
                    out[3, r, t] = speed
                    out[4, r, t] = acc
                    out[6, r, t] = s_abs[h, v, t]
                    out[7, r, t] = d
                    out[8, r, t] = kref[h, v, t]
                # curvature: central difference of yaw over the distance travelled (trapezoidal in |speed|),
                # one-sided at the last step, from the start pose before step 0
                prev_yaw, prev_speed = yaw0, v_start
                for t in range(nT):
                    yaw_t, speed_t = out[2, r, t], out[3, r, t]
                    step = (speed_t + prev_speed) * (0.5 * dt)
                    dh = yaw_t - prev_yaw
                    if t + 1 < nT:
                        step_next = (out[3, r, t + 1] + speed_t) * (0.5 * dt)
                        num = dh + (out[2, r, t + 1] - yaw_t)
                        den = step + step_next
                    else:
                        num, den = dh, step
                    out[5, r, t] = num / den if den > _MIN_TRAVEL else 0.0
                    prev_yaw, prev_speed = yaw_t, speed_t
                for t in range(nT):  # wrap the heading into [-pi, pi]; sign the speed where s runs backwards
                    y = out[2, r, t]
                    out[2, r, t] = y - np.rint(y * inv_two_pi) * two_pi
                    if sd[h, v, t] < 0.0:
                        out[3, r, t] = -out[3, r, t]
                        out[4, r, t] = -out[4, r, t]


def sample(path: Polyline, start: FrenetState, cfg: SamplingConfig, v_max: float,
           left: float | np.ndarray | None = None, right: float | np.ndarray | None = None,
           margin: float = 0.0, out: np.ndarray | None = None, row: int = 0) -> Candidates:
    """Sample the candidate grid from ``start`` along ``path``.

    v_max: highest end speed here [m/s] (e.g. the speed limit, capped by the ego's top speed).
    left, right: drivable area as lateral offsets [m] (left > right), either one number or
    (M,) values at the path's vertices (``RoutePath.left/right``), linearly interpolated at
    each candidate's end station s(T); None means +/- ``cfg.max_offset``.
    margin: kept between the end offsets and the drivable edges [m] (half the ego's width
    keeps the end pose on the road). End offsets span [right + margin, left - margin]
    clipped to [-max_offset, max_offset]; an empty interval collapses to its midpoint.

    Longitudinal: quartic s(t) (:func:`quartic_coeffs`). Lateral: for start.s_dot >= low_speed
    a quintic d(t) over T (:func:`quintic_coeffs`); below, a quintic d(sigma) over the arc
    length Sigma = s(T) - s0 the candidate travels, with d'(0) = d_dot/s_dot and
    d''(0) = (d_ddot - d' s_ddot)/s_dot^2 (0 below 0.1 m/s, clipped to |d'| <= 1, |d''| <= 1/m);
    a candidate travelling under 1 mm stays at d0. Speeds are never clamped: where a quartic
    dips below s_dot = 0 (possible only when braking with start acceleration a0 < 0), the
    signed ``speed`` goes negative and ``feasibility.check`` rejects the candidate.

    Cartesian output (Candidates, all (K, T) unless noted, T = cfg.n_steps):
    x, y = path.to_xy(s, d); yaw = reference_heading(s) + atan2(d_dot, s_dot (1 - kappa_r d)),
    held from the last step with speed >= 1 cm/s while (nearly) still; speed = sign(s_dot)
    sqrt((s_dot (1 - kappa_r d))^2 + d_dot^2) with kappa_r = path.curvature_at(s); accel = its
    analytic time derivative (neglecting d kappa_r / ds), s_ddot where the speed is ~0;
    curvature = central difference of yaw over the distance travelled between the neighbouring
    steps (start pose before step 0, one-sided at the last step), 0 where that distance is
    under 1 mm; road_curvature = the reference path's own curvature along the candidate: the same
    difference of reference_heading(s) alone over the distance along the path (trapezoidal in
    |s_dot|), so a candidate on the path (d = 0, no lateral motion) has road_curvature ==
    curvature exactly; beside the path the candidate's curvature differs from it by what it adds
    (a parallel curve on the inside of a bend is tighter than the path).
    horizon: (K,) T of each candidate [s]; valid: all True.

    out, row: where the arrays go: rows row ... row + K - 1 of a (9, K', T) float64 block (x, y, yaw,
    speed, accel, curvature, s, d, road_curvature; the Candidates' arrays are views of it), so that
    several samplings and other candidates share one block without a copy; None: a block of their own.
    """
    v_max = float(v_max)
    if not math.isfinite(v_max) or v_max < 0:
        raise ConfigError(f"v_max must be a finite speed >= 0 [m/s], got {v_max!r}")
    H = np.asarray(cfg.horizons)  # (nH,)
    nH, nV, nD, nT = len(H), cfg.n_speeds, cfg.n_offsets, cfg.n_steps
    dt = cfg.dt
    t = dt * np.arange(1, nT + 1)  # (T,)
    ve = end_speeds(cfg, v_max)  # (nV,)

    # ---- longitudinal: (nH, nV, T); past T continue at v_end
    tau = np.minimum(t[None, :], H[:, None])  # (nH, T) time inside each horizon
    extra = t[None, :] - tau  # (nH, T)
    cs = quartic_coeffs(start.s_dot, start.s_ddot, ve[None, :], H[:, None])  # (nH, nV, 5)
    P = tau[:, None, :] ** np.arange(5)[:, None]  # (nH, 5, T)
    dP = np.zeros_like(P)
    dP[:, 1:] = np.arange(1, 5)[:, None] * P[:, :-1]
    ddP = np.zeros_like(P)
    ddP[:, 2:] = (np.arange(2, 5) * np.arange(1, 4))[:, None] * P[:, :-2]
    ve3 = ve[None, :, None]
    s_rel = cs @ P + ve3 * extra[:, None, :]  # (nH, nV, T), s - s0
    s_dot = cs @ dP  # equals v_end past T
    s_ddot = cs @ ddP  # 0 past T
    sigma_end = (cs * H[:, None, None] ** np.arange(5)).sum(-1)  # (nH, nV) s(T) - s0

    # ---- lateral end offsets at each end station: (nH, nV, nD)
    s_end = start.s + sigma_end
    lo = np.maximum(_bound_at(right, path, s_end, -cfg.max_offset) + margin, -cfg.max_offset)
    hi = np.minimum(_bound_at(left, path, s_end, cfg.max_offset) - margin, cfg.max_offset)
    mid = 0.5 * (lo + hi)
    lo, hi = np.minimum(lo, mid), np.maximum(hi, mid)
    if nD == 1:
        d_end = np.clip(0.0, lo, hi)[..., None]
    else:
        d_end = lo[..., None] + (hi - lo)[..., None] * np.linspace(0.0, 1.0, nD)

    s_full = s_rel[:, :, None, :]  # (nH, nV, 1, T): broadcast over offsets
    s_dot_f = s_dot[:, :, None, :]
    s_ddot_f = s_ddot[:, :, None, :]
    # The quintic is linear in its end value: x(u; x_end) = x(u; 0) + x_end * B(u / T) with
    # B(w) = 10 w^3 - 15 w^4 + 6 w^5. Evaluate both parts on small arrays, combine once.
    low = start.s_dot < cfg.low_speed
    unit = np.array([0.0, 0.0, 0.0, 10.0, -15.0, 6.0])  # B in powers of w
    if not low:
        # quintic in time; the end state (d_end, 0, 0) holds past T (tau stops at T)
        c0 = quintic_coeffs(start.d, start.d_dot, start.d_ddot, 0.0, H[:, None, None, None])  # (nH, 1, 1, 1, 6)
        u = tau[:, None, None, :]  # (nH, 1, 1, T)
        L = H[:, None, None, None]
        p1 = p2 = 0.0
    else:
        # quintic over the arc length sigma travelled (Werling et al. 2010), robust at standstill
        moving = abs(start.s_dot) >= _DERIV_SPEED
        p1 = float(np.clip(start.d_dot / start.s_dot, -_MAX_D1, _MAX_D1)) if moving else 0.0
        p2 = float(np.clip((start.d_ddot - p1 * start.s_ddot) / start.s_dot**2, -_MAX_D2, _MAX_D2)) if moving else 0.0
        Sig = sigma_end[:, :, None, None]  # (nH, nV, 1, 1)
        travels = Sig >= _MIN_TRAVEL
        L = np.where(travels, Sig, 1.0)
        c0 = quintic_coeffs(start.d, p1, p2, 0.0, L)  # (nH, nV, 1, 1, 6)
        u = np.clip(s_full, 0.0, L)  # (nH, nV, 1, T); past the end (or behind the start) d is constant
    q0, q1, q2 = _horner(c0, u)
    b0, b1, b2 = _horner(unit, u / L)
    b1, b2 = b1 / L, b2 / L**2
    if low:
        inside = (s_full > 0.0) & (s_full < L) & travels
        q0 = np.where(travels, q0, start.d)
        q1, q2, b1, b2 = (np.where(inside, v, 0.0) for v in (q1, q2, b1, b2))
        b0 = np.where(travels, b0, 0.0)
    # ---- Cartesian. Path lookups depend on s only, i.e. on (horizon, end speed, step):
    # evaluate them on (nH, nV, 1, T) and broadcast over the offsets (23x less work).
    s_abs = start.s + s_full  # (nH, nV, 1, T)
    xc, yc, _ = path.to_xy(s_abs, 0.0)
    hseg = path.heading_at(s_abs)
    kr = path.curvature_at(s_abs)
    href = reference_heading(path, s_abs)
    kr0 = float(path.curvature_at(start.s))
    one0 = 1.0 - kr0 * start.d
    v_start = math.sqrt((start.s_dot * one0) ** 2 + start.d_dot**2)
    if low:
        dth0 = math.atan2(p1, one0)
    else:
        dth0 = math.atan2(start.d_dot, start.s_dot * one0) if v_start >= _STILL else 0.0
    href0 = float(reference_heading(path, np.asarray(start.s)))
    # the road's own curvature along the candidate: the central difference of the path's heading over
    # the distance the path covers (trapezoidal in |s_dot|). It depends on s only, so it is computed on
    # (nH, nV, 1, T); on the path (d = 0, d_dot = 0) speed == |s_dot| and it agrees with the
    # candidate's curvature bit for bit
    sd_abs = np.abs(s_dot_f)
    kref = np.empty_like(href)
    _heading_curvature(href, href0, sd_abs, abs(start.s_dot), dt, kref, *(np.empty_like(sd_abs) for _ in range(3)))

    # the lateral parts (nH, 1 or nV, T) and the path's lookups along each station (nH, nV, T), each one block
    lat = np.stack(np.broadcast_arrays(q0, q1, q2, b0, b1, b2))
    along_path = np.stack(np.broadcast_arrays(xc, yc, np.sin(hseg), np.cos(hseg), kr, href, s_dot_f, s_ddot_f, s_abs,
                                              kref))
    K = nH * nV * nD
    if out is None:
        out, row = np.empty((9, K, nT)), 0
    elif out.dtype != np.float64 or out.ndim != 3 or out.shape[0] != 9 or out.shape[2] != nT or not (
            0 <= row and row + K <= out.shape[1]) or not out.flags.c_contiguous or not out.flags.writeable:
        raise ValueError(f"out must be a writable C-contiguous float64 (9, K', {nT}) block with rows {row} to "
                         f"{row + K - 1}, got {out.dtype} {out.shape}")
    _cartesian_kernel(np.ascontiguousarray(d_end, dtype=float), lat.reshape(6, nH, -1, nT),
                      along_path.reshape(10, nH, nV, nT), low, dth0, href0 + dth0, v_start, dt, out, row)
    x, y, yaw, speed, accel, curvature, s_out, d, road = out[:, row:row + K]
    return Candidates(dt=dt, x=x, y=y, yaw=yaw, speed=speed, accel=accel, curvature=curvature, s=s_out, d=d,
                      horizon=np.repeat(H, nV * nD), valid=np.ones((K, nT), dtype=bool), road_curvature=road)


if __name__ == "__main__":  # timing: python -m sumo_ethics.plan.sampling
    import functools
    import timeit

    pts = np.stack([np.linspace(0, 400, 201), 5 * np.sin(np.linspace(0, 400, 201) / 40)], axis=-1)
    p = Polyline.from_points(pts)
    c = SamplingConfig()
    for v in (12.0, 1.0):
        st = FrenetState(s=20.0, d=0.3, s_dot=v, s_ddot=0.5, d_dot=0.1)
        sample(p, st, c, 14.0, left=3.0, right=-4.0, margin=0.8)
        ts = timeit.repeat(functools.partial(sample, p, st, c, 14.0, left=3.0, right=-4.0, margin=0.8), number=1,
                           repeat=200)
        print(f"v0={v}: K={c.n_candidates} T={c.n_steps}: median {1e3 * float(np.median(ts)):.3f} ms, "
              f"min {1e3 * min(ts):.3f} ms")
