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

Two numba kernels (nogil: a fleet's egos sample on several threads at once): the (horizon, end speed,
step) part, the quartics, the path along them and the lateral quintics' parts (:func:`_profile_kernel`,
the formulas of :func:`quartic_coeffs` and :func:`quintic_coeffs`), then the (candidate, step) part
(:func:`_cartesian_kernel`). They agree with the numpy formulation they replaced within 2e-11 (relative,
checked at 81a8608 on 400 random paths, grids and start states), and with the two formulas evaluated
by numpy's polynomials (``tests/plan/test_sampling.py``).
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
    coefficients c0..c4 (c0 = 0) in ascending powers of t. (:func:`_profile_kernel` evaluates the same.)
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


def _bound_at(bound: float | np.ndarray | None, path: Polyline, default: float) -> np.ndarray:
    """(M,) a lateral bound at the path's vertices [m]: one number everywhere, or the given values; None: ``default``."""
    b = np.array(default if bound is None else bound, dtype=float)  # a copy, read-only like the path's arrays
    if b.ndim == 0:
        b = np.full(path.s.shape, float(b))
    elif b.shape != path.s.shape:
        raise ConfigError(f"lateral bounds must be a number or one value per path vertex {path.s.shape}, got {b.shape}")
    b.setflags(write=False)  # (one type for the kernel whatever the caller passes: one compile)
    return b


# --------------------------------------------------------------------------- sampling
@numba.njit(cache=True, nogil=True)
def vertex_walk(x: float, xp, j: int) -> int:  # pragma: no cover - compiled
    """The last index of ``xp`` (ascending) at or before ``x``, clipped to [0, len - 1] (numpy's
    ``searchsorted(xp, x, "right") - 1``; NaN sorts last), walked from the caller's previous ``j``: a
    candidate's stations move a vertex or so per step, so this beats a binary search."""
    n = len(xp)
    if x != x:
        return n - 1
    while j + 1 < n and xp[j + 1] <= x:
        j += 1
    while j > 0 and xp[j] > x:
        j -= 1
    return j


@numba.njit(cache=True, nogil=True)
def interp_at(x: float, xp, fp, j: int) -> float:  # pragma: no cover - compiled
    """np.interp(x, xp, fp) with j from :func:`vertex_walk` (numpy's formula, bit for bit)."""
    n = len(xp)
    if x < xp[0]:
        return fp[0]
    if x >= xp[n - 1]:
        return fp[n - 1]
    j = min(j, n - 2)  # (only NaN gets here with n - 1: its result is NaN either way)
    slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j])
    return slope * (x - xp[j]) + fp[j]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _horner5(c5, c4, c3, c2, c1, c0, u):  # pragma: no cover - compiled
    """Value, first and second derivative of c0 + c1 u + ... + c5 u^5 at u (Horner's scheme)."""
    v, d1, d2 = c5, 0.0, 0.0
    d2 = d2 * u + 2.0 * d1
    d1 = d1 * u + v
    v = v * u + c4
    d2 = d2 * u + 2.0 * d1
    d1 = d1 * u + v
    v = v * u + c3
    d2 = d2 * u + 2.0 * d1
    d1 = d1 * u + v
    v = v * u + c2
    d2 = d2 * u + 2.0 * d1
    d1 = d1 * u + v
    v = v * u + c1
    d2 = d2 * u + 2.0 * d1
    d1 = d1 * u + v
    v = v * u + c0
    return v, d1, d2


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _profile_kernel(H, ve, fracs, nT, dt, s0, d0, v0, a0, dd0, ddd0, low, p1, p2, ps, pxy, phead, pk, ph, left, right,
                    margin, max_offset, href0, lat, along_path, d_end):  # pragma: no cover - compiled
    """The (horizon, end speed) part of :func:`sample`: per (h, v) the quartic s(t) with its speed and
    acceleration, the path's lookups along it (x, y, sin and cos of the segment's heading, curvature,
    reference heading; the road's curvature from it), the lateral quintic's parts for end offset 0 and
    per metre of it, and the lateral end offsets. Writes lat (6, nH, nV, T), along_path (10, nH, nV, T)
    and d_end (nH, nV, nD) in :func:`_cartesian_kernel`'s layout."""
    nH, nV, nD = len(H), len(ve), len(fracs)
    n = len(ps)
    nseg = n - 1
    for h in range(nH):
        T = H[h]
        for v in range(nV):
            V = ve[v] - v0 - a0 * T  # speed still to gain after the start acceleration
            A = -a0
            c1, c2 = v0, a0 / 2.0
            c3 = (3.0 * V - A * T) / (3.0 * T**2)
            c4 = (A * T - 2.0 * V) / (4.0 * T**3)
            sig = (((c4 * T + c3) * T + c2) * T + c1) * T  # s(T) - s0
            # the lateral end offsets over the drivable interval at the end station
            j = vertex_walk(s0 + sig, ps, int(0))  # (not a literal 0: that would compile a second vertex_walk)
            r_end, l_end = interp_at(s0 + sig, ps, right, j), interp_at(s0 + sig, ps, left, j)
            lo = max(r_end + margin, -max_offset)
            hi = min(l_end - margin, max_offset)
            mid = 0.5 * (lo + hi)
            lo, hi = min(lo, mid), max(hi, mid)
            for k in range(nD):
                d_end[h, v, k] = min(max(0.0, lo), hi) if nD == 1 else lo + (hi - lo) * fracs[k]
            # the lateral quintic: in time (c over T), or over the arc length (low speed, c over L)
            travels = sig >= _MIN_TRAVEL
            L = T if not low else (sig if travels else 1.0)
            x1, x2 = (dd0, ddd0) if not low else (p1, p2)
            q2c = x2 / 2.0
            D = 0.0 - (d0 + x1 * L + q2c * L**2)
            D1 = -(x1 + 2.0 * q2c * L)
            D2 = -x2
            q3 = (10.0 * D - 4.0 * D1 * L + 0.5 * D2 * L**2) / L**3
            q4 = (-15.0 * D + 7.0 * D1 * L - D2 * L**2) / L**4
            q5 = (6.0 * D - 3.0 * D1 * L + 0.5 * D2 * L**2) / L**5
            jp = int(0)
            for i in range(nT):
                t = dt * (i + 1)
                tau = min(t, T)
                extra = t - tau
                s_rel = (((c4 * tau + c3) * tau + c2) * tau + c1) * tau + ve[v] * extra
                s_dot = ((4.0 * c4 * tau + 3.0 * c3) * tau + 2.0 * c2) * tau + c1
                s_ddot = (12.0 * c4 * tau + 6.0 * c3) * tau + 2.0 * c2
                u = tau if not low else min(max(s_rel, 0.0), L)
                # Horner with derivatives, as _horner: the quintic (d0, x1, q2c, q3, q4, q5) and B(w) = 10 w^3 - 15 w^4 + 6 w^5
                qv, qd1, qd2 = _horner5(q5, q4, q3, q2c, x1, d0, u)
                w = u / L
                bv, bd1, bd2 = _horner5(6.0, -15.0, 10.0, 0.0, 0.0, 0.0, w)
                bd1 = bd1 / L
                bd2 = bd2 / L**2
                if low:
                    inside = s_rel > 0.0 and s_rel < L and travels
                    if not travels:
                        qv, bv = d0, 0.0
                    if not inside:
                        qd1, qd2, bd1, bd2 = 0.0, 0.0, 0.0, 0.0
                lat[0, h, v, i], lat[1, h, v, i], lat[2, h, v, i] = qv, qd1, qd2
                lat[3, h, v, i], lat[4, h, v, i], lat[5, h, v, i] = bv, bd1, bd2
                # the path at s: its segment (the later one at a vertex, the end segments beyond the ends)
                sa = s0 + s_rel
                jp = vertex_walk(sa, ps, jp)
                g = min(jp, nseg - 1)
                ds = sa - ps[g]
                hc, hs = math.cos(phead[g]), math.sin(phead[g])
                along_path[0, h, v, i] = pxy[g, 0] + ds * hc - 0.0 * hs
                along_path[1, h, v, i] = pxy[g, 1] + ds * hs + 0.0 * hc
                along_path[2, h, v, i] = hs
                along_path[3, h, v, i] = hc
                along_path[4, h, v, i] = interp_at(sa, ps, pk, jp)  # 0 beyond the ends: pk's end values are 0
                along_path[5, h, v, i] = interp_at(sa, ps, ph, jp)
                along_path[6, h, v, i] = s_dot
                along_path[7, h, v, i] = s_ddot
                along_path[8, h, v, i] = sa
            # the road's own curvature: the central difference of the reference heading over the distance
            # the path covers (trapezoidal in |s_dot|), one-sided at the last step
            prev_h, prev_v = href0, abs(v0)
            for i in range(nT):
                h_i, v_i = along_path[5, h, v, i], abs(along_path[6, h, v, i])
                step = (v_i + prev_v) * (0.5 * dt)
                dh = h_i - prev_h
                if i + 1 < nT:
                    num = dh + (along_path[5, h, v, i + 1] - h_i)
                    den = step + (abs(along_path[6, h, v, i + 1]) + v_i) * (0.5 * dt)
                else:
                    num, den = dh, step
                along_path[9, h, v, i] = num / den if den > _MIN_TRAVEL else 0.0
                prev_h, prev_v = h_i, v_i


@numba.njit(cache=True, nogil=True, error_model="numpy")
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
    ve = end_speeds(cfg, v_max)  # (nV,)

    low = start.s_dot < cfg.low_speed
    # below low_speed the lateral quintic runs over the arc length sigma travelled (Werling et al. 2010),
    # from d' = d_dot / s_dot and d'' = (d_ddot - d' s_ddot) / s_dot^2 (0 when barely moving; clipped)
    moving = abs(start.s_dot) >= _DERIV_SPEED
    p1 = float(np.clip(start.d_dot / start.s_dot, -_MAX_D1, _MAX_D1)) if low and moving else 0.0
    p2 = float(np.clip((start.d_ddot - p1 * start.s_ddot) / start.s_dot**2, -_MAX_D2, _MAX_D2)) if low and moving \
        else 0.0
    kr0 = float(path.curvature_at(start.s))
    one0 = 1.0 - kr0 * start.d
    v_start = math.sqrt((start.s_dot * one0) ** 2 + start.d_dot**2)
    if low:
        dth0 = math.atan2(p1, one0)
    else:
        dth0 = math.atan2(start.d_dot, start.s_dot * one0) if v_start >= _STILL else 0.0
    href0 = float(reference_heading(path, np.asarray(start.s)))

    # per (horizon, end speed): the longitudinal quartic, the path along it, the lateral quintic's parts
    # and the end offsets (_profile_kernel); then per candidate the Cartesian states (_cartesian_kernel)
    K = nH * nV * nD
    if out is None:
        out, row = np.empty((9, K, nT)), 0
    elif out.dtype != np.float64 or out.ndim != 3 or out.shape[0] != 9 or out.shape[2] != nT or not (
            0 <= row and row + K <= out.shape[1]) or not out.flags.c_contiguous or not out.flags.writeable:
        raise ValueError(f"out must be a writable C-contiguous float64 (9, K', {nT}) block with rows {row} to "
                         f"{row + K - 1}, got {out.dtype} {out.shape}")
    lat, along_path, d_end = np.empty((6, nH, nV, nT)), np.empty((10, nH, nV, nT)), np.empty((nH, nV, nD))
    _profile_kernel(H, ve, np.linspace(0.0, 1.0, nD), nT, dt, float(start.s), float(start.d), float(start.s_dot),
                    float(start.s_ddot), float(start.d_dot), float(start.d_ddot), low, p1, p2, path.s, path.xy,
                    path.heading, path.vertex_curvature, path.vertex_heading,
                    _bound_at(left, path, cfg.max_offset), _bound_at(right, path, -cfg.max_offset), float(margin),
                    float(cfg.max_offset), href0, lat, along_path, d_end)
    _cartesian_kernel(d_end, lat, along_path, low, dth0, href0 + dth0, v_start, dt, out, row)
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
