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

__all__ = ["box_distance", "box_ttc", "crossing", "drac", "pet_from_trail"]

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
