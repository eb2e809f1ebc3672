"""Surrogate safety measures between oriented boxes: pure numpy, broadcasting, no simulator.

Frame as everywhere (:mod:`sumo_ethics.geometry`): metres, seconds, radians, yaw CCW from +x,
box centre. Every function broadcasts its array arguments against each other (e.g. the ego,
shape (), against N road users, shape (N,)); no Python loops over pairs.

* :func:`box_ttc`: time to collision of two rectangles moving at constant velocity and
  constant heading: the earliest t >= 0 at which their interiors overlap, exact (no time
  sampling). With fixed headings the relative motion is a pure translation, so on each of the
  four separating axes (each box's heading and normal) the overlap is one open time interval;
  the boxes overlap exactly when t lies in all four, i.e. TTC = max of the interval starts
  when that is below the min of their ends.
* :func:`turning_ttc`: the same for road users that turn: each keeps its speed and its yaw
  rate (constant turn rate and velocity, each on its circle), first overlap on a 0.05 s grid up
  to a horizon, refined by bisection to 1 ms. Two cars passing each other on a bend stay on
  their arcs and never meet; with constant headings their tangents cross (a false conflict).
  :func:`ttc_with_turns` uses it only for pairs where one party turns (|yaw rate| above
  ``TURNING``), and the exact :func:`box_ttc` for the rest.
* :func:`drac`: deceleration rate to avoid the crash, |v_rel| / (2 TTC): the constant
  deceleration of the relative motion that stops it where the boxes would first touch. On one
  line this is the usual v_rel^2 / (2 gap) (gap = |v_rel| TTC).
* :func:`box_distance`: the smallest distance between two rectangles (0 when they overlap).
* :func:`pet_from_trail`: post-encroachment time from past footprints: for boxes ``now`` and
  a trail of the other party's boxes at earlier times, ``now_time - t_last`` where t_last is
  the latest trail time whose box overlaps the box now, counted only where the paths cross
  (headings apart by at least ``min_angle``); never below the true PET, at most two sampling
  intervals above it.
"""

from __future__ import annotations

import numpy as np

from sumo_ethics.geometry import OrientedBoxes, boxes_overlap, wrap_angle

__all__ = ["box_distance", "box_ttc", "crossing", "drac", "pet_from_trail", "ttc_with_turns", "turning_ttc",
           "yaw_rates"]

#: relative speeds along an axis below this [m/s] count as no motion along it
_STILL = 1e-9


def _floats(v) -> np.ndarray:
    return np.asarray(v, dtype=float)


def box_ttc(a: OrientedBoxes, va: tuple[np.ndarray | float, np.ndarray | float], b: OrientedBoxes,
            vb: tuple[np.ndarray | float, np.ndarray | float]) -> np.ndarray:
    """Time to collision [s] of boxes a and b moving at constant velocity and heading.

    a, b: boxes (broadcastable shapes); va, vb: (vx, vy) velocities [m/s] of each, broadcastable
    to the boxes' shape. Returns the broadcast shape: 0 where the boxes overlap now, the
    earliest time their interiors overlap, +inf where they never do. Exact up to rounding.
    """
    f = _floats
    dx, dy = f(b.x) - f(a.x), f(b.y) - f(a.y)
    wx, wy = f(vb[0]) - f(va[0]), f(vb[1]) - f(va[1])  # b relative to a
    ya, yb = f(a.yaw), f(b.yaw)
    hla, hwa, hlb, hwb = f(a.length) / 2, f(a.width) / 2, f(b.length) / 2, f(b.width) / 2
    shape = np.broadcast_shapes(dx.shape, dy.shape, wx.shape, wy.shape, ya.shape, yb.shape, hla.shape, hwa.shape,
                                hlb.shape, hwb.shape)
    u = np.empty((2, 4, *shape))  # the four candidate axes (x, y): a's heading and normal, b's
    ca, sa, cb, sb = np.cos(ya), np.sin(ya), np.cos(yb), np.sin(yb)
    u[0, 0], u[1, 0], u[0, 1], u[1, 1] = ca, sa, -sa, ca
    u[0, 2], u[1, 2], u[0, 3], u[1, 3] = cb, sb, -sb, cb
    # half extent of both boxes along each axis (as in boxes_overlap): |cos|, |sin| of the relative heading
    cr, sr = np.abs(np.cos(yb - ya)), np.abs(np.sin(yb - ya))
    r = np.empty((4, *shape))
    r[0], r[1] = hla + hlb * cr + hwb * sr, hwa + hlb * sr + hwb * cr
    r[2], r[3] = hlb + hla * cr + hwa * sr, hwb + hla * sr + hwa * cr
    p = dx * u[0] + dy * u[1]  # (4, ...) centre distance along each axis
    w = wx * u[0] + wy * u[1]  # its rate of change
    moving = np.abs(w) > _STILL
    inv = np.divide(1.0, w, out=np.zeros_like(w), where=moving)
    t1, t2 = (-r - p) * inv, (r - p) * inv
    # an axis without relative motion: overlapping for ever (-inf, inf) or never (inf, -inf)
    fixed = np.where(np.abs(p) >= r, np.inf, -np.inf)
    lo = np.where(moving, np.minimum(t1, t2), fixed)
    hi = np.where(moving, np.maximum(t1, t2), -fixed)
    enter = np.maximum(lo.max(axis=0), 0.0)
    leave = hi.min(axis=0)
    return np.where((enter < leave) & (leave > 0), enter, np.inf)


#: a road user turns when its yaw rate is above this [rad/s] (0.02 rad/s: a 500 m radius at 10 m/s)
TURNING = 0.02
#: the tightest turn a yaw rate is taken for [1/m] (a 5 m radius, as the ego's EgoVehicle.max_curvature)
MAX_CURVATURE = 0.2
#: the turning TTC's grid [s] and its refinement [s]
TURN_GRID, TURN_TOL = 0.05, 1e-3


def _arc(b: OrientedBoxes, speed: np.ndarray, rate: np.ndarray, t: np.ndarray) -> OrientedBoxes:
    """Boxes ``b`` after t [s] at constant speed [m/s] and yaw rate [rad/s] (on a circle; straight
    where the rate is 0); all broadcast."""
    f = _floats
    yaw0, v, w = f(b.yaw), f(speed), f(rate)
    yaw = yaw0 + w * t
    straight = np.abs(w) < 1e-9
    ws = np.where(straight, 1.0, w)
    dx = np.where(straight, v * t * np.cos(yaw0), v / ws * (np.sin(yaw) - np.sin(yaw0)))
    dy = np.where(straight, v * t * np.sin(yaw0), v / ws * (np.cos(yaw0) - np.cos(yaw)))
    return OrientedBoxes(f(b.x) + dx, f(b.y) + dy, yaw, b.length, b.width)


def _take(v, shape: tuple[int, ...], k: np.ndarray) -> np.ndarray:
    """Elements ``k`` (flat indices) of ``v`` broadcast to ``shape``."""
    return np.broadcast_to(_floats(v), shape).ravel()[k]


def _take_boxes(b: OrientedBoxes, shape: tuple[int, ...], k: np.ndarray) -> OrientedBoxes:
    """Boxes ``k`` (flat indices) of ``b`` broadcast to ``shape``."""
    return OrientedBoxes(*(_take(v, shape, k) for v in (b.x, b.y, b.yaw, b.length, b.width)))


def turning_ttc(a: OrientedBoxes, speed_a, rate_a, b: OrientedBoxes, speed_b, rate_b, horizon: float) -> np.ndarray:
    """Time to collision [s] of boxes a and b each keeping its speed [m/s] and yaw rate [rad/s]
    (constant turn rate and velocity): 0 where they overlap now, the first time within
    ``horizon`` [s] they overlap (to 1 ms; a contact shorter than the 0.05 s grid can be missed),
    +inf where they do not within it. Arguments of shape (P,) (or broadcastable); returns (P,)."""
    f = _floats
    shape = np.broadcast_shapes(*(np.shape(f(v)) for v in (a.x, a.y, a.yaw, a.length, a.width, b.x, b.y, b.yaw,
                                                           b.length, b.width, speed_a, rate_a, speed_b, rate_b)))
    times = np.arange(0.0, horizon + 1e-9, TURN_GRID)
    grid = times.reshape((-1,) + (1,) * len(shape))  # (G, 1, ...)
    hit = boxes_overlap(_arc(a, speed_a, rate_a, grid), _arc(b, speed_b, rate_b, grid))  # (G, P)
    hit = np.broadcast_to(hit, (len(times),) + shape)
    first = np.argmax(hit, axis=0)
    found = hit.any(axis=0)
    out = np.full(shape, np.inf)
    out[found & (first == 0)] = 0.0
    refine = np.flatnonzero((found & (first > 0)).ravel())
    if len(refine):  # bisection between the last grid time apart and the first together
        hi = times[first.ravel()[refine]]
        lo = hi - TURN_GRID
        pa, pb = _take_boxes(a, shape, refine), _take_boxes(b, shape, refine)
        va, wa, vb, wb = (_take(v, shape, refine) for v in (speed_a, rate_a, speed_b, rate_b))
        while (hi - lo).max() > TURN_TOL:
            mid = 0.5 * (lo + hi)
            now = boxes_overlap(_arc(pa, va, wa, mid), _arc(pb, vb, wb, mid))
            hi, lo = np.where(now, mid, hi), np.where(now, lo, mid)
        out.ravel()[refine] = hi
    return out


def ttc_with_turns(a: OrientedBoxes, speed_a, rate_a, b: OrientedBoxes, speed_b, rate_b, horizon: float) -> np.ndarray:
    """Time to collision [s] of pairs (P,): exact at constant velocity and heading (:func:`box_ttc`)
    where neither party turns (|yaw rate| <= TURNING), :func:`turning_ttc` up to ``horizon`` where
    one does."""
    f = _floats
    va = (f(speed_a) * np.cos(f(a.yaw)), f(speed_a) * np.sin(f(a.yaw)))
    vb = (f(speed_b) * np.cos(f(b.yaw)), f(speed_b) * np.sin(f(b.yaw)))
    out = np.array(box_ttc(a, va, b, vb), dtype=float)
    turning = np.broadcast_to((np.abs(f(rate_a)) > TURNING) | (np.abs(f(rate_b)) > TURNING), out.shape)
    k = np.flatnonzero(turning.ravel() & (out.ravel() > 0))
    if len(k):
        s = out.shape
        out.ravel()[k] = turning_ttc(_take_boxes(a, s, k), _take(speed_a, s, k), _take(rate_a, s, k),
                                     _take_boxes(b, s, k), _take(speed_b, s, k), _take(rate_b, s, k), horizon)
    return out


def yaw_rates(yaw_now: np.ndarray | float, yaw_before: np.ndarray | float, dt: float, speed: np.ndarray | float,
              walker: np.ndarray | bool) -> np.ndarray:
    """Yaw rates [rad/s] for :func:`ttc_with_turns` from two headings [rad] dt [s] apart: wrapped,
    at most ``MAX_CURVATURE`` x speed (a heading that jumps, e.g. at a lane's seam, is no turn
    tighter than a car can drive), 0 for pedestrians (``walker``: their heading jumps at the
    corners of walking areas; they keep the constant-velocity TTC) and where the heading before is
    unknown (NaN) or dt is not positive. All arrays broadcast."""
    shape = np.broadcast_shapes(np.shape(yaw_now), np.shape(yaw_before), np.shape(speed), np.shape(walker))
    if not dt > 0:
        return np.zeros(shape)
    d = wrap_angle(np.asarray(yaw_now, dtype=float) - np.asarray(yaw_before, dtype=float)) / dt
    cap = MAX_CURVATURE * np.abs(np.asarray(speed, dtype=float))
    return np.where(np.isfinite(d) & ~np.asarray(walker, dtype=bool), np.clip(d, -cap, cap), 0.0)


def drac(ttc: np.ndarray, rel_speed: np.ndarray) -> np.ndarray:
    """Deceleration rate to avoid the crash [m/s^2]: |v_rel| / (2 TTC), any shape.

    ttc: [s] (from :func:`box_ttc`); rel_speed: |v_b - v_a| [m/s]. 0 where TTC is infinite (no
    crash ahead), +inf where it is 0 (the boxes overlap now).
    """
    ttc = np.asarray(ttc, dtype=float)
    v = np.abs(np.asarray(rel_speed, dtype=float))
    with np.errstate(divide="ignore", invalid="ignore"):
        out = v / (2.0 * ttc)
    return np.where(np.isinf(ttc), 0.0, np.where(ttc <= 0, np.inf, out))


_SL = np.array([1.0, -1.0, -1.0, 1.0])  # corner signs along the heading (FL, RL, RR, FR)
_SW = np.array([1.0, 1.0, -1.0, -1.0])  # and along the left normal


def _corners_to_box(a: OrientedBoxes, b: OrientedBoxes) -> np.ndarray:
    """Smallest distance [m] from b's four corners to the rectangle a (0 for a corner inside a)."""
    f = _floats
    ca, sa = np.cos(f(a.yaw)), np.sin(f(a.yaw))
    dx, dy = f(b.x) - f(a.x), f(b.y) - f(a.y)
    bx, by = dx * ca + dy * sa, dy * ca - dx * sa  # b's centre in a's frame
    rel = f(b.yaw) - f(a.yaw)
    cr, sr = np.cos(rel), np.sin(rel)
    hl, hw = f(b.length)[..., None] / 2 * _SL, f(b.width)[..., None] / 2 * _SW  # (..., 4)
    px = bx[..., None] + hl * cr[..., None] - hw * sr[..., None]  # corners in a's frame
    py = by[..., None] + hl * sr[..., None] + hw * cr[..., None]
    ox = np.maximum(np.abs(px) - f(a.length)[..., None] / 2, 0.0)  # how far outside a, along and across
    oy = np.maximum(np.abs(py) - f(a.width)[..., None] / 2, 0.0)
    return np.hypot(ox, oy).min(axis=-1)


def box_distance(a: OrientedBoxes, b: OrientedBoxes) -> np.ndarray:
    """Smallest distance [m] between the rectangles a and b (broadcast shape); 0 where they overlap.

    For two disjoint convex polygons the closest pair always involves a corner of one of them,
    so this is the smaller of the distances from b's corners to a and from a's corners to b.
    """
    d = np.minimum(_corners_to_box(a, b), _corners_to_box(b, a))
    return np.where(boxes_overlap(a, b), 0.0, d)


def crossing(yaw_a: np.ndarray | float, yaw_b: np.ndarray | float, min_angle: float) -> np.ndarray:
    """Whether two headings [rad] cross: their angle, folded into [0, pi/2], is at least
    ``min_angle`` [rad] (same-direction and opposite traffic is not a crossing)."""
    d = np.abs(wrap_angle(np.asarray(yaw_a, dtype=float) - np.asarray(yaw_b, dtype=float)))
    return np.minimum(d, np.pi - d) >= min_angle


def pet_from_trail(now: OrientedBoxes, now_time: float, trail: OrientedBoxes, trail_time: np.ndarray,
                   min_angle: float) -> np.ndarray:
    """Post-encroachment time [s] of N boxes ``now`` into a party's past footprint.

    now: N boxes (fields (N,)) at ``now_time`` [s]; trail: the other party's boxes at W earlier
    instants, fields (W, 1) or (W, N) (one trail shared by all N, or one per box), at
    ``trail_time`` (W,) [s], in any order (NaN rows: empty). Returns (N,): now_time - (latest
    trail time whose box overlaps the box now and whose heading crosses it by ``min_angle``
    [rad]), +inf where none. Some place both boxes cover was left by the first party no earlier
    than that trail time and reached by the second no later than now, so the result is never
    below the true PET (the shortest such gap over the places both covered); sampled every dt,
    called at the first step after the second party's arrival, it is at most 2 dt above it.
    Pass only trail instants before now_time.
    """
    hit = boxes_overlap(trail, now) & crossing(trail.yaw, now.yaw, min_angle)  # (W, N)
    hit = np.broadcast_to(hit, np.broadcast_shapes(hit.shape, (len(trail_time), np.shape(now.x)[-1])))
    tt = np.asarray(trail_time, dtype=float)[:, None]
    latest = np.where(hit, tt, -np.inf).max(axis=0)
    return np.where(np.isfinite(latest), now_time - latest, np.inf)
