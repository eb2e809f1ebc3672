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
- The shadow of an opaque polygon (a building) includes the polygon: for a convex one, the convex
  hull of its vertices and of those pushed out (as a box's); for any other, the polygon and, for
  every edge facing the eye, the quadrilateral between the edge and the edge pushed out along its
  sight rays beyond the range (:func:`polygon_shadows`); vectorised over polygons and edges.
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


def _hull_shadows(e: np.ndarray, polys: list[Any], radius: float) -> np.ndarray:
    """(P,) the shadows of convex ``polys`` (the polygons included): the convex hull of each one's
    vertices and of those vertices pushed out along their sight rays; vectorised over the polygons."""
    coords, idx = shapely.get_coordinates(shapely.get_exterior_ring(np.asarray(polys, dtype=object)), return_index=True)
    rel = coords - e
    starts = np.flatnonzero(np.r_[True, idx[1:] != idx[:-1]])
    counts = np.diff(np.r_[starts, len(idx)])
    mid = np.add.reduceat(rel, starts, axis=0) / counts[:, None]  # (P, 2) towards each polygon
    m = mid[idx]
    ang = np.arctan2(m[:, 0] * rel[:, 1] - m[:, 1] * rel[:, 0], (m * rel).sum(axis=1))
    half = 0.5 * (np.maximum.reduceat(ang, starts) - np.minimum.reduceat(ang, starts))
    far = _push(e, coords, _reach(radius, np.cos(half), np.maximum.reduceat(np.hypot(*rel.T), starts))[idx])
    pts = np.concatenate([coords, far])
    group = np.concatenate([idx, idx])
    order = np.argsort(group, kind="stable")
    return np.asarray(shapely.convex_hull(shapely.multipoints(pts[order], indices=group[order])), dtype=object)


def _edge_shadows(e: np.ndarray, polys: list[Any], radius: float) -> np.ndarray:
    """The quadrilaterals between each edge of ``polys`` (any shape) that faces the eye and that edge
    pushed out along its sight rays (their union with the polygons is the polygons' shadow)."""
    rings = shapely.get_rings(shapely.orient_polygons(np.asarray(polys, dtype=object)))  # solid on the left
    coords, idx = shapely.get_coordinates(rings, return_index=True)
    same = idx[1:] == idx[:-1]  # consecutive vertices of one ring: an edge
    a, b = coords[:-1][same], coords[1:][same]
    ra, rb = a - e, b - e
    cross = ra[:, 0] * rb[:, 1] - ra[:, 1] * rb[:, 0]  # < 0: the eye right of a -> b, outside the solid
    facing = cross < -1e-9 * np.maximum(np.hypot(*ra.T) * np.hypot(*rb.T), 1e-12)  # end-on edges hide nothing
    a, b, cross, dot = a[facing], b[facing], cross[facing], (ra * rb).sum(axis=1)[facing]
    half = 0.5 * np.abs(np.arctan2(cross, dot))
    reach = _reach(radius, np.cos(half), np.maximum(np.hypot(*(a - e).T), np.hypot(*(b - e).T)))
    quads = np.stack([a, b, _push(e, b, reach), _push(e, a, reach), a], axis=1)
    return np.asarray(shapely.polygons(quads), dtype=object) if len(quads) else np.empty(0, dtype=object)


def polygon_shadows(eye: np.ndarray, polygons: Sequence[Any], radius: float) -> list[Any]:
    """The shadows that opaque ``polygons`` cast from ``eye`` within ``radius`` [m] and past it, the
    polygons included (a list of geometries whose union is the hidden region). A convex polygon's is
    the convex hull of its vertices and of those pushed out along their sight rays; a non-convex
    one's is the polygon and, for every edge facing the eye, the quadrilateral between the edge and
    the edge pushed out. A polygon containing the eye hides nothing (the sensor would be inside it)."""
    e = np.asarray(eye, dtype=float).reshape(2)
    parts = [g for p in polygons if p is not None for g in shapely.get_parts(p) if g.geom_type == "Polygon"]
    polys = [p for p in parts if not p.is_empty and not p.covers(shapely.Point(e))]
    if not polys:
        return []
    arr = np.asarray(polys, dtype=object)
    area = shapely.area(arr)
    convex = shapely.area(shapely.convex_hull(arr)) <= area * (1.0 + 1e-9) + 1e-12
    convex &= shapely.get_num_interior_rings(arr) == 0
    out: list[Any] = []
    if convex.any():
        out += list(_hull_shadows(e, [polys[i] for i in np.flatnonzero(convex)], radius))
    if (~convex).any():
        rest = [polys[i] for i in np.flatnonzero(~convex)]
        out += rest + list(_edge_shadows(e, rest, radius))
    return out


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
        """The disc of the range (a polygon of 4 x QUAD_SEGS vertices), built once."""
        d = self.__dict__.get("_disc")
        if d is None:
            d = shapely.Point(self.eye).buffer(self.radius, quad_segs=QUAD_SEGS)
            object.__setattr__(self, "_disc", d)
        return d


def view(eye: np.ndarray, radius: float, corners: np.ndarray, opaque: Sequence[Any] = ()) -> View:
    """The :class:`View` from ``eye`` within ``radius`` [m] past the boxes ``corners`` (N, 4, 2) (road
    users: each box hides what is behind it) and the ``opaque`` polygons (buildings)."""
    e = np.asarray(eye, dtype=float).reshape(2)
    disc = shapely.Point(e).buffer(radius, quad_segs=QUAD_SEGS)
    c = np.asarray(corners, dtype=float).reshape(-1, 4, 2)
    if len(c):  # boxes wholly beyond the range hide nothing within it
        near = np.hypot(*(c.mean(axis=1) - e).T) - np.hypot(*(c[:, 0] - c[:, 2]).T) / 2.0 <= radius
        c = c[near]
    parts = [g for g in box_shadows(e, c, radius) if g is not None] + polygon_shadows(e, opaque, radius)
    if not parts:
        out = View(e, float(radius), disc, shapely.Polygon())
    else:
        shade = shapely.union_all(np.asarray(parts, dtype=object))
        out = View(e, float(radius), shapely.difference(disc, shade), shapely.intersection(disc, shade))
    object.__setattr__(out, "_disc", disc)
    return out


def visible_share(v: View, corners: np.ndarray) -> np.ndarray:
    """(N,) the share of each box's area [0, 1] that lies in the visible region of ``v``."""
    b = boxes(corners)
    if len(b) == 0:
        return np.zeros(0)
    area = shapely.area(b)
    seen = shapely.area(shapely.intersection(b, v.visible))
    return np.clip(np.where(area > 0.0, seen / np.maximum(area, 1e-12), 0.0), 0.0, 1.0)
