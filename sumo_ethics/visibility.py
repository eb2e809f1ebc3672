"""What a sensor sees, in plan view: a disc of its range around it minus the shadows that road
users' boxes and opaque polygons (buildings) cast. Pure numpy and shapely 2, no simulator.

The model (2-D, every obstacle as tall as the sight line; see docs/occlusion.md):

- A point is *hidden* when the segment from the sensor (the *eye*) to it crosses an obstacle, or
  when it is farther than the range; the *visible region* is the disc of the range minus the
  hidden points.
- The shadow of a road user's box (convex, the eye outside it) is the convex hull of its four
  corners and of the corners pushed out along their sight rays beyond the range, less the box
  itself: a box is seen by its near side, so its own far half is not in its own shadow (it may be
  in another's). Vectorised over the boxes (:func:`box_shadows`).
- The shadow of a polygon (a building, convex or not) is the polygon and, for every edge of it,
  the quadrilateral between the edge and the edge pushed out along its sight rays beyond the
  range (:func:`polygon_shadows`); vectorised over all edges.
- An obstacle that contains the eye casts no shadow (the ego's own box is never an obstacle).

Exact polygons, not a ray cast: a ray cast of M rays misses objects narrower than the ray spacing
(at 0.5 deg, 0.44 m at 50 m: a pedestrian), where the polygons are exact to float precision.
Its cost is measured in ``tools/bench_occlusion.py`` (docs/occlusion.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
import shapely
from shapely import Geometry

__all__ = ["View", "box_shadows", "polygon_shadows", "view", "visible_share", "boxes"]

#: sight rays are pushed out to (1 + REACH_MARGIN) x the range beyond the chord of an obstacle's
#: extreme rays; an obstacle wider than 2 acos(MIN_COS) as seen from the eye (174 deg) is pushed out
#: as if it were that wide (the eye is then within millimetres of its side)
REACH_MARGIN = 0.05
MIN_COS = 0.05
#: the disc of the range as a polygon of 4 x QUAD_SEGS vertices (its area within 0.3 % of the circle's)
QUAD_SEGS = 16


def boxes(corners: np.ndarray) -> np.ndarray:
    """(N,) shapely polygons of (N, 4, 2) box corners [m] (``geometry.OrientedBoxes.corners``)."""
    c = np.asarray(corners, dtype=float).reshape(-1, 4, 2)
    if not len(c):
        return np.empty(0, dtype=object)
    return np.asarray(shapely.polygons(np.concatenate([c, c[:, :1]], axis=1)), dtype=object)


def _reach(radius: float, cos_half: np.ndarray, farthest: np.ndarray) -> np.ndarray:
    """How far [m] from the eye an obstacle's points are pushed out along their sight rays (all
    of one obstacle to the same distance): so far that the chord between its two extreme rays
    (half-angle with cosine ``cos_half``) lies beyond the range, and never nearer than its
    ``farthest`` point [m] (pushed points must move outwards, or the shadow folds over itself)."""
    return np.maximum(radius / np.maximum(cos_half, MIN_COS), farthest) * (1.0 + REACH_MARGIN)


def _push(eye: np.ndarray, pts: np.ndarray, reach: np.ndarray) -> np.ndarray:
    """Points ``pts`` (..., 2) moved along their sight rays from ``eye`` to distance ``reach`` (...,)."""
    v = pts - eye
    n = np.maximum(np.hypot(v[..., 0], v[..., 1]), 1e-9)
    return eye + v * (reach / n)[..., None]


def box_shadows(eye: np.ndarray, corners: np.ndarray, radius: float) -> np.ndarray:
    """(N,) shapely polygons: the region each box hides from ``eye`` within ``radius`` [m] and past
    it, less the box itself; None for a box that contains the eye or touches it. corners: (N, 4, 2)
    counter-clockwise (``geometry.OrientedBoxes.corners``)."""
    e = np.asarray(eye, dtype=float).reshape(2)
    c = np.asarray(corners, dtype=float).reshape(-1, 4, 2)
    n = len(c)
    out = np.full(n, None, dtype=object)
    if n == 0:
        return out
    rel = c - e
    edge = np.roll(rel, -1, axis=1) - rel
    # the eye (the origin of rel) is inside or on a counter-clockwise box when it is left of every edge
    inside = ((edge[..., 0] * -rel[..., 1] - edge[..., 1] * -rel[..., 0]) >= -1e-12).all(axis=1)
    mid = rel.mean(axis=1)
    cross = mid[:, None, 0] * rel[..., 1] - mid[:, None, 1] * rel[..., 0]
    dot = (mid[:, None, :] * rel).sum(axis=-1)
    ang = np.arctan2(cross, dot)  # each corner's bearing from the bearing of the box's centre, (-pi/2, pi/2)
    half = 0.5 * (ang.max(axis=1) - ang.min(axis=1))
    far = _push(e, c, _reach(radius, np.cos(half), np.hypot(rel[..., 0], rel[..., 1]).max(axis=1))[:, None])
    keep = np.flatnonzero(~inside)
    if len(keep):
        hull = shapely.convex_hull(shapely.multipoints(np.concatenate([c[keep], far[keep]], axis=1)))
        out[keep] = shapely.difference(hull, boxes(c[keep]))
    return out


def _rings(polygons: Sequence[Any]) -> list[np.ndarray]:
    """The (P, 2) coordinates of every ring (exterior and holes) of ``polygons`` (MultiPolygons split)."""
    rings = []
    for g in shapely.get_parts(np.asarray(list(polygons), dtype=object)):
        if g is None or g.is_empty:
            continue
        rings.append(np.asarray(g.exterior.coords)[:, :2])
        rings.extend(np.asarray(r.coords)[:, :2] for r in g.interiors)
    return rings


def polygon_shadows(eye: np.ndarray, polygons: Sequence[Any], radius: float) -> Any:
    """The region opaque ``polygons`` hide from ``eye`` within ``radius`` [m] and past it, the
    polygons included (one geometry; empty without polygons). A polygon containing the eye hides
    nothing (the sensor would be inside it)."""
    e = np.asarray(eye, dtype=float).reshape(2)
    polys = [p for p in polygons if p is not None and not p.is_empty and not p.covers(shapely.Point(e))]
    rings = _rings(polys)
    if not rings:
        return shapely.GeometryCollection()
    a = np.concatenate([r[:-1] for r in rings])
    b = np.concatenate([r[1:] for r in rings])
    ra, rb = a - e, b - e
    cross = ra[:, 0] * rb[:, 1] - ra[:, 1] * rb[:, 0]
    dot = (ra * rb).sum(axis=1)
    ok = np.abs(cross) > 1e-9 * np.maximum(np.hypot(*ra.T) * np.hypot(*rb.T), 1e-12)  # edges seen end-on hide nothing
    a, b, cross, dot = a[ok], b[ok], cross[ok], dot[ok]
    half = 0.5 * np.abs(np.arctan2(cross, dot))
    reach = _reach(radius, np.cos(half), np.maximum(np.hypot(*(a - e).T), np.hypot(*(b - e).T)))
    quads = np.stack([a, b, _push(e, b, reach), _push(e, a, reach), a], axis=1)
    return shapely.union_all(np.concatenate([shapely.polygons(quads), np.asarray(polys, dtype=object)]))


@dataclass(frozen=True)
class View:
    """What the sensor at ``eye`` (2,) [m] with range ``radius`` [m] sees: ``visible``, the disc
    less every shadow (road users' boxes lie in it where they are seen: a box is seen by its near
    side); ``hidden``, the shadows within the disc (opaque polygons included)."""

    eye: np.ndarray
    radius: float
    visible: Geometry
    hidden: Geometry

    def disc(self) -> Any:
        return shapely.Point(self.eye).buffer(self.radius, quad_segs=QUAD_SEGS)


def view(eye: np.ndarray, radius: float, corners: np.ndarray, opaque: Sequence[Any] = ()) -> View:
    """The :class:`View` from ``eye`` within ``radius`` [m] past the boxes ``corners`` (N, 4, 2) (road
    users: each box hides what is behind it) and the ``opaque`` polygons (buildings)."""
    e = np.asarray(eye, dtype=float).reshape(2)
    disc = shapely.Point(e).buffer(radius, quad_segs=QUAD_SEGS)
    c = np.asarray(corners, dtype=float).reshape(-1, 4, 2)
    if len(c):  # boxes wholly beyond the range hide nothing within it
        near = np.hypot(*(c.mean(axis=1) - e).T) - np.hypot(*(c[:, 0] - c[:, 2]).T) / 2.0 <= radius
        c = c[near]
    parts = [g for g in box_shadows(e, c, radius) if g is not None]
    walls = polygon_shadows(e, opaque, radius)
    if not walls.is_empty:
        parts.append(walls)
    if not parts:
        return View(e, float(radius), disc, shapely.Polygon())
    shade = shapely.union_all(np.asarray(parts, dtype=object))
    return View(e, float(radius), shapely.difference(disc, shade), shapely.intersection(disc, shade))


def visible_share(v: View, corners: np.ndarray) -> np.ndarray:
    """(N,) the share of each box's area [0, 1] that lies in the visible region of ``v``."""
    b = boxes(corners)
    if len(b) == 0:
        return np.zeros(0)
    area = shapely.area(b)
    seen = shapely.area(shapely.intersection(b, v.visible))
    return np.clip(np.where(area > 0.0, seen / np.maximum(area, 1e-12), 0.0), 0.0, 1.0)
