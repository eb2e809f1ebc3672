"""Pure-numpy geometry in the internal frame: oriented boxes, overlap tests, reference paths.

Frame: metres, radians, yaw counter-clockwise from +x, positions at the box centre.
Everything broadcasts over arbitrary leading shapes, e.g. (K, N, T) for candidates x
agents x horizon steps; no Python loops over boxes or points.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

__all__ = ["wrap_angle", "OrientedBoxes", "boxes_overlap", "Polyline"]


def wrap_angle(a: np.ndarray | float) -> np.ndarray:
    """Angles [rad] wrapped into (-pi, pi]; any shape."""
    a = np.asarray(a, dtype=float)
    w = np.mod(a + np.pi, 2.0 * np.pi) - np.pi  # [-pi, pi)
    return np.where(w == -np.pi, np.pi, w)


@dataclass(frozen=True)
class OrientedBoxes:
    """Rectangles given by centre, heading and size; fields broadcast against each other.

    x, y: centre [m]; yaw: heading of the length axis [rad, CCW from +x];
    length, width: full extents [m] along and across the heading.
    """

    x: np.ndarray | float
    y: np.ndarray | float
    yaw: np.ndarray | float
    length: np.ndarray | float
    width: np.ndarray | float

    @property
    def shape(self) -> tuple[int, ...]:
        return np.broadcast_shapes(*(np.shape(v) for v in (self.x, self.y, self.yaw, self.length, self.width)))

    def corners(self) -> np.ndarray:
        """(..., 4, 2) corners [m], counter-clockwise from front-left: FL, RL, RR, FR."""
        x, y, yaw, hl, hw = np.broadcast_arrays(
            *(np.asarray(v, dtype=float) for v in (self.x, self.y, self.yaw, self.length, self.width))
        )
        hl, hw = hl / 2.0, hw / 2.0
        c, s = np.cos(yaw), np.sin(yaw)
        sl = np.array([1.0, -1.0, -1.0, 1.0])  # along heading
        sw = np.array([1.0, 1.0, -1.0, -1.0])  # along left normal
        dl = hl[..., None] * sl
        dw = hw[..., None] * sw
        cx = x[..., None] + dl * c[..., None] - dw * s[..., None]
        cy = y[..., None] + dl * s[..., None] + dw * c[..., None]
        return np.stack([cx, cy], axis=-1)


def start_side(shape: np.ndarray, other: np.ndarray) -> float:
    """Which side of polyline ``shape``'s first segment the first point of ``other`` lies on (both
    (P, 2) [m]): the cross product of that segment with the offset to the point, > 0 left, < 0 right,
    0 on its line or where either has too few points. Two lanes of one SUMO edge start side by side,
    so it tells which way their indices count (netconvert numbers a right-hand edge's lanes from the
    right, a ``--lefthand`` one's from the left)."""
    a, b = np.asarray(shape, dtype=float), np.asarray(other, dtype=float)
    if len(a) < 2 or len(b) < 1:
        return 0.0
    d, r = a[1] - a[0], b[0] - a[0]
    return float(d[0] * r[1] - d[1] * r[0])


def boxes_overlap(a: OrientedBoxes, b: OrientedBoxes) -> np.ndarray:
    """Separating-axis test for two broadcastable sets of oriented boxes.

    Returns a bool array of the broadcast shape: True where the interiors intersect.
    The test is strict: boxes that only touch (edge on edge, corner on edge) do not overlap.
    Four candidate axes (each box's heading and normal); on each, the boxes overlap iff
    ``|centre distance . u| < r_a + r_b`` with ``r = L/2 |h . u| + W/2 |n . u|``.
    """
    dx = np.asarray(b.x, dtype=float) - np.asarray(a.x, dtype=float)
    dy = np.asarray(b.y, dtype=float) - np.asarray(a.y, dtype=float)
    ca, sa = np.cos(a.yaw), np.sin(a.yaw)
    cb, sb = np.cos(b.yaw), np.sin(b.yaw)
    hla, hwa = np.asarray(a.length, dtype=float) / 2.0, np.asarray(a.width, dtype=float) / 2.0
    hlb, hwb = np.asarray(b.length, dtype=float) / 2.0, np.asarray(b.width, dtype=float) / 2.0
    # cos/sin of the relative heading: |h_a . h_b| = |n_a . n_b| = |cos|, |h_a . n_b| = |n_a . h_b| = |sin|
    cr = np.abs(ca * cb + sa * sb)
    sr = np.abs(sa * cb - ca * sb)
    # axes of a: h_a = (ca, sa), n_a = (-sa, ca)
    sep = np.abs(dx * ca + dy * sa) >= hla + hlb * cr + hwb * sr
    sep |= np.abs(-dx * sa + dy * ca) >= hwa + hlb * sr + hwb * cr
    # axes of b
    sep |= np.abs(dx * cb + dy * sb) >= hlb + hla * cr + hwa * sr
    sep |= np.abs(-dx * sb + dy * cb) >= hwb + hla * sr + hwa * cr
    return ~sep


# Points x segments are evaluated in blocks of at most this many pairs (~8 float64 temporaries
# each, so about 8 * 8 B * 2e6 = 128 MB peak), whatever the number of points.
_PROJECT_BLOCK_PAIRS = 2_000_000
# Up to this many points are projected one by one (project_point), more in one (P, S) batch.
_FEW_POINTS = 4


@dataclass(frozen=True)
class Polyline:
    """A piecewise-linear reference path with a Frenet frame (s along, d to the left).

    xy: (M, 2) vertices [m], M >= 2, no two consecutive equal; s: (M,) cumulative arc
    length [m], s[0] = 0; heading: (M-1,) per-segment heading [rad, CCW from +x].
    Build with :meth:`from_points`. Frenet positions beyond either end extrapolate along the
    end segments (s < 0 or s > length).
    """

    xy: np.ndarray
    s: np.ndarray
    heading: np.ndarray

    def __post_init__(self) -> None:
        xy = np.asarray(self.xy, dtype=float)
        s = np.asarray(self.s, dtype=float)
        h = np.asarray(self.heading, dtype=float)
        m = xy.shape[0] if xy.ndim == 2 else -1
        if xy.ndim != 2 or xy.shape[1] != 2 or m < 2 or s.shape != (m,) or h.shape != (m - 1,):
            raise ValueError(f"Polyline needs xy (M>=2, 2), s (M,), heading (M-1,); got {xy.shape}, {s.shape}, {h.shape}")
        if np.any(np.diff(s) <= 0.0):
            raise ValueError("Polyline arc length must be strictly increasing (consecutive duplicate points?)")
        for name, arr in (("xy", xy), ("s", s), ("heading", h)):
            arr = arr.copy()
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @classmethod
    def from_points(cls, points: np.ndarray) -> "Polyline":
        """Path through (M, 2) points [m]; consecutive duplicates are dropped.

        Raises ValueError if fewer than 2 distinct points remain.
        """
        p = np.asarray(points, dtype=float)
        if p.ndim != 2 or p.shape[1] != 2:
            raise ValueError(f"points must have shape (M, 2), got {p.shape}")
        if not np.all(np.isfinite(p)):
            raise ValueError("points must be finite")
        if p.shape[0] > 0:
            keep = np.ones(p.shape[0], dtype=bool)
            keep[1:] = np.any(p[1:] != p[:-1], axis=1)
            p = p[keep]
        if p.shape[0] < 2:
            raise ValueError("a Polyline needs at least 2 distinct points")
        seg = np.diff(p, axis=0)
        seg_len = np.hypot(seg[:, 0], seg[:, 1])
        s = np.concatenate([[0.0], np.cumsum(seg_len)])
        return cls(xy=p, s=s, heading=np.arctan2(seg[:, 1], seg[:, 0]))

    @property
    def length(self) -> float:
        """Total arc length [m]."""
        return float(self.s[-1])

    @functools.cached_property
    def _unit(self) -> np.ndarray:
        """(M-1, 2) unit direction of each segment (computed once)."""
        return np.stack([np.cos(self.heading), np.sin(self.heading)], axis=-1)

    @functools.cached_property
    def _columns(self) -> tuple[np.ndarray, ...]:
        """Contiguous (M-1,) start x, start y [m], unit direction x, y and length [m] of each
        segment, for :meth:`project_point` and :meth:`may_be_within` (computed once)."""
        return (np.ascontiguousarray(self.xy[:-1, 0]), np.ascontiguousarray(self.xy[:-1, 1]),
                np.ascontiguousarray(self._unit[:, 0]), np.ascontiguousarray(self._unit[:, 1]), np.diff(self.s))

    def _segment_index(self, s: np.ndarray) -> np.ndarray:
        """Index of the segment holding arc length s (clipped to the end segments)."""
        idx = np.searchsorted(self.s, s, side="right") - 1
        return np.minimum(np.maximum(idx, 0), len(self.heading) - 1)  # np.clip costs ~5 us more

    def _window(self, near: tuple[float, float] | None) -> tuple[int, int]:
        """Segments lo..hi-1 overlapping the arc-length range ``near`` (all segments if None)."""
        nseg = len(self.heading)
        if near is None:
            return 0, nseg
        lo, hi = (int(i) for i in np.searchsorted(self.s, near, side="right") - 1)
        return min(max(lo, 0), nseg - 1), min(max(hi, 0), nseg - 1) + 1

    def project(self, xy: np.ndarray, near: tuple[float, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Exact nearest-point projection of (..., 2) points [m] -> (s (...), d (...)) [m].

        s: arc length of the closest point on the path; d: signed distance to it, left of
        the path positive. Where the closest point is the first (last) vertex and the point
        lies behind (beyond) it, the end segment's line is used instead, so s < 0 (s > length)
        and d is the perpendicular offset from that line. Where the closest point is an
        interior vertex (outside of a corner), the side is taken from the corner's bisector.
        Ties between segments go to the lower s.
        Cost: points x segments pairs, evaluated in blocks of ~2e6 pairs (~128 MB peak).
        ``near = (s_min, s_max)`` searches only the segments overlapping that arc-length range
        (for per-step tracking where the answer is known to lie close to the last one).
        """
        q = np.asarray(xy, dtype=float)
        if q.shape[-1:] != (2,):
            raise ValueError(f"project expects (..., 2) points, got {q.shape}")
        lead = q.shape[:-1]
        flat = q.reshape(-1, 2)
        lo, hi = self._window(near)
        if flat.shape[0] <= _FEW_POINTS:  # per point: no (P, S) temporaries, a third of the cost
            sd = np.array([self._project_one(float(x), float(y), lo, hi) for x, y in flat]).reshape(-1, 2)
            return sd[:, 0].reshape(lead), sd[:, 1].reshape(lead)
        block = max(1, _PROJECT_BLOCK_PAIRS // (hi - lo))
        s_out = np.empty(flat.shape[0])
        d_out = np.empty(flat.shape[0])
        for start in range(0, flat.shape[0], block):  # blocks bound memory; each is fully vectorised
            sl = slice(start, start + block)
            s_out[sl], d_out[sl] = self._project_flat(flat[sl], lo, hi)
        return s_out.reshape(lead), d_out.reshape(lead)

    def may_be_within(self, x: np.ndarray, y: np.ndarray, dist: float,
                      near: tuple[float, float] | None = None) -> np.ndarray:
        """Cheap conservative pre-filter for :meth:`project` of (N,) points x, y [m] -> (N,) bool.

        False only where :meth:`project` (with the same ``near``) would surely give |d| >= dist:
        the point is farther than dist + half the longest segment from every vertex of the
        window. Where the window holds an end segment (where points beyond the end get an
        extrapolated d) every point is kept.
        """
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        lo, hi = self._window(near)
        if lo == 0 or hi == len(self.heading):
            return np.ones(x.shape, dtype=bool)
        vx, vy = self.xy[lo:hi + 1, 0], self.xy[lo:hi + 1, 1]  # (S+1,) vertices of the window
        seg_len = self._columns[4][lo:hi]
        r = dist + 0.5 * float(np.max(seg_len)) + 1e-6
        return np.min((x[:, None] - vx) ** 2 + (y[:, None] - vy) ** 2, axis=1) < r * r

    def project_point(self, x: float, y: float, near: tuple[float, float] | None = None) -> tuple[float, float]:
        """:meth:`project` of the single point (x, y) [m] -> (s, d) [m] as floats.

        The same arithmetic as :meth:`_project_flat`, bit for bit: numpy over the (S,)
        segments, plain floats for the chosen one (no (P, S) temporaries, no fancy indexing).
        """
        return self._project_one(x, y, *self._window(near))

    def _project_one(self, x: float, y: float, lo: int, hi: int) -> tuple[float, float]:
        """:meth:`project_point` over segments lo..hi-1."""
        x0, y0, ux, uy, seg_len = (c[lo:hi] for c in self._columns)
        nseg = hi - lo
        rx, ry = x - x0, y - y0  # (S,)
        along = rx * ux + ry * uy
        cross = ux * ry - uy * rx  # left positive
        t = np.minimum(np.maximum(along, 0.0), seg_len)
        j = int(np.argmin((along - t) ** 2 + cross**2))
        along_j, cross_j, t_j, len_j = float(along[j]), float(cross[j]), float(t[j]), float(seg_len[j])
        before = j == 0 and along_j < 0.0 and lo == 0  # extrapolate beyond the ends
        after = j == nseg - 1 and along_j > len_j and hi == len(self.heading)
        if before or after:
            t_j = along_j
        s = float(self.s[lo + j]) + t_j
        dist = float(np.hypot(along_j - t_j, cross_j))
        # side: at an interior vertex use the bisector of the two adjacent segments
        at_end_vertex = t_j >= len_j and j < nseg - 1 and not after
        at_start_vertex = t_j <= 0.0 and j > 0 and not before
        side_of = cross_j
        if at_end_vertex or at_start_vertex:
            v = j + at_end_vertex  # vertex index within the window, 1..nseg-1
            bx, by = float(ux[v - 1] + ux[v]), float(uy[v - 1] + uy[v])
            cross_v = bx * (y - float(y0[v])) - by * (x - float(x0[v]))
            if float(np.hypot(bx, by)) > 1e-9:
                side_of = cross_v
        return s, float(np.sign(side_of)) * dist

    def _project_flat(self, p: np.ndarray, lo: int, hi: int) -> tuple[np.ndarray, np.ndarray]:
        """(P, 2) -> (P,), (P,); all pairs of points and segments lo..hi-1 at once."""
        a = self.xy[lo:hi]  # (S, 2)
        u = self._unit[lo:hi]  # (S, 2)
        seg_len = np.diff(self.s[lo:hi + 1])  # (S,)
        nseg = len(seg_len)
        first, last = lo == 0, hi == len(self.heading)
        rel = p[:, None, :] - a[None, :, :]  # (P, S, 2)
        along = rel[..., 0] * u[:, 0] + rel[..., 1] * u[:, 1]  # (P, S)
        cross = u[:, 0] * rel[..., 1] - u[:, 1] * rel[..., 0]  # (P, S), left positive
        t = np.minimum(np.maximum(along, 0.0), seg_len)  # np.clip, without its overhead
        dist2 = (along - t) ** 2 + cross**2
        j = np.argmin(dist2, axis=1)  # (P,)
        rows = np.arange(p.shape[0])
        along_j, cross_j, t_j = along[rows, j], cross[rows, j], t[rows, j]
        # extrapolate beyond the ends along the end segments
        before = (j == 0) & (along_j < 0.0) & first
        after = (j == nseg - 1) & (along_j > seg_len[j]) & last
        t_j = np.where(before | after, along_j, t_j)
        s = self.s[lo + j] + t_j
        dist = np.hypot(along_j - t_j, cross_j)
        # side: at an interior vertex use the bisector of the two adjacent segments
        at_end_vertex = (t_j >= seg_len[j]) & (j < nseg - 1) & ~after
        at_start_vertex = (t_j <= 0.0) & (j > 0) & ~before
        at_vertex = at_end_vertex | at_start_vertex
        v = j + at_end_vertex.astype(int)  # vertex index (valid where at_vertex)
        vi = np.minimum(np.maximum(v, 1), nseg - 1)
        bis = u[vi - 1] + u[vi]  # (P, 2), direction of the corner's bisector tangent
        rel_v = p - a[vi] if nseg > 1 else p - self.xy[lo]
        cross_v = bis[:, 0] * rel_v[:, 1] - bis[:, 1] * rel_v[:, 0]
        use_bis = at_vertex & (np.hypot(bis[:, 0], bis[:, 1]) > 1e-9)
        side = np.sign(np.where(use_bis, cross_v, cross_j))
        return s, side * dist

    def to_xy(self, s: np.ndarray | float, d: np.ndarray | float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Frenet (s, d) [m] -> (x, y, yaw) of the broadcast shape.

        Piecewise linear: the point at arc length s, moved d to the left of its segment;
        yaw is that segment's heading. Beyond the ends the end segments extend linearly.
        At a vertex the later segment is used. Inverse of :meth:`project` for points whose
        closest point lies on a segment's interior (not in the outer wedge of a corner).
        """
        s, d = np.broadcast_arrays(np.asarray(s, dtype=float), np.asarray(d, dtype=float))
        j = self._segment_index(s)
        ds = s - self.s[j]
        c, sn = np.cos(self.heading[j]), np.sin(self.heading[j])
        x = self.xy[j, 0] + ds * c - d * sn
        y = self.xy[j, 1] + ds * sn + d * c
        return x, y, self.heading[j]

    def heading_at(self, s: np.ndarray | float) -> np.ndarray:
        """Heading [rad] of the segment at arc length s (same convention as :meth:`to_xy`)."""
        return self.heading[self._segment_index(np.asarray(s, dtype=float))]

    def curvature_at(self, s: np.ndarray | float) -> np.ndarray:
        """Signed curvature [1/m] (left turn positive) at arc length s.

        Method: each interior vertex i turns the heading by dtheta_i = wrap(h_i - h_{i-1});
        that turn is spread as a hat function over the two adjacent segments, i.e. vertex
        curvature k_i = dtheta_i / ((len_{i-1} + len_i) / 2), linearly interpolated in s
        between vertices, 0 at both ends and beyond. The integral of the curvature over s
        equals the total heading change, and a finely sampled circle of radius R gives 1/R
        away from its ends.
        """
        return np.interp(np.asarray(s, dtype=float), self.s, self.vertex_curvature, left=0.0, right=0.0)

    @functools.cached_property
    def vertex_curvature(self) -> np.ndarray:
        """(M,) the curvature [1/m] at the vertices that :meth:`curvature_at` interpolates (computed once)."""
        k = np.zeros(len(self.s))
        if len(self.heading) >= 2:
            seg_len = np.diff(self.s)
            dtheta = wrap_angle(np.diff(self.heading))
            k[1:-1] = dtheta / (0.5 * (seg_len[:-1] + seg_len[1:]))
        k.setflags(write=False)
        return k

    @functools.cached_property
    def vertex_heading(self) -> np.ndarray:
        """(M,) the smooth heading [rad, unwrapped] at the vertices: each interior vertex the mean of its
        two segments' (unwrapped) headings, the end vertices their segment's (computed once)."""
        h = np.unwrap(self.heading)
        hv = np.empty(len(self.s))
        hv[0], hv[-1] = h[0], h[-1]
        hv[1:-1] = 0.5 * (h[:-1] + h[1:])
        hv.setflags(write=False)
        return hv


def ellipses(mean: np.ndarray, cov: np.ndarray, k: float = 1.0, n: int = 32) -> np.ndarray:
    """(..., n, 2) closed outlines (first point repeated last) of the k-sigma ellipses of 2-D
    Gaussians: mean (..., 2) [m], cov (..., 2, 2) [m^2]."""
    mean, cov = np.asarray(mean, dtype=float), np.asarray(cov, dtype=float)
    vals, vecs = np.linalg.eigh(cov)  # (..., 2), (..., 2, 2): columns are the axes
    a = np.linspace(0.0, 2.0 * np.pi, n)
    circle = np.stack([np.cos(a), np.sin(a)], -1) * (k * np.sqrt(np.maximum(vals, 0.0)))[..., None, :]
    return np.einsum("...nj,...ij->...ni", circle, vecs) + mean[..., None, :]


def principal_variances(sxx: np.ndarray, sxy: np.ndarray, syy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(larger, smaller) eigenvalues [m^2] of the 2 x 2 covariances with entries sxx, sxy, syy; broadcasts."""
    mid = 0.5 * (sxx + syy)
    rad = np.hypot(0.5 * (sxx - syy), sxy)
    return mid + rad, mid - rad


def not_psd(cov: np.ndarray, rtol: float = 1e-9) -> np.ndarray:
    """(...) bool: the (..., 2, 2) covariance has a negative principal variance beyond rounding
    (below -rtol x the larger one, or -rtol m^2 where that is below 1), i.e. no Gaussian has it."""
    c = np.asarray(cov, dtype=float)
    big, small = principal_variances(c[..., 0, 0], 0.5 * (c[..., 0, 1] + c[..., 1, 0]), c[..., 1, 1])
    return small < -rtol * np.maximum(np.abs(big), 1.0)


def floor_covariance(sxx: np.ndarray, sxy: np.ndarray, syy: np.ndarray,
                     min_var: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The covariances with entries sxx, sxy, syy [m^2], each principal variance raised to at least
    ``min_var`` [m^2], in their own principal frame (so turning the scene turns the result with
    it); entries that need no floor are returned as they were."""
    sxx, sxy, syy = (np.array(v, dtype=float) for v in np.broadcast_arrays(sxx, sxy, syy))
    big, small = principal_variances(sxx, sxy, syy)
    big_f = np.maximum(big, min_var)
    small_f = np.maximum(small, min_var)
    fix = (big_f != big) | (small_f != small)
    if fix.any():
        half = 0.5 * (sxx - syy)
        rad = np.hypot(half, sxy)
        safe = np.where(rad > 0.0, rad, 1.0)
        c2 = np.where(rad > 0.0, half / safe, 1.0)  # cos, sin of twice the first axis's angle
        s2 = np.where(rad > 0.0, sxy / safe, 0.0)
        mid, dev = 0.5 * (big_f + small_f), 0.5 * (big_f - small_f)
        sxx = np.where(fix, mid + dev * c2, sxx)
        syy = np.where(fix, mid - dev * c2, syy)
        sxy = np.where(fix, dev * s2, sxy)
    return sxx, sxy, syy
