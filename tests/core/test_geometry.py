"""Geometry: angle wrapping, oriented-box overlap (SAT), Polyline Frenet frame."""

from __future__ import annotations

import numpy as np
import pytest

from sumo_ethics.geometry import OrientedBoxes, Polyline, boxes_overlap, wrap_angle

PI = np.pi


def unit_square(x=0.0, y=0.0, yaw=0.0):
    return OrientedBoxes(np.asarray(x), np.asarray(y), np.asarray(yaw), np.asarray(1.0), np.asarray(1.0))


# --------------------------------------------------------------------------- wrap_angle
def test_wrap_angle_range_and_values():
    a = np.array([0.0, PI, -PI, 3 * PI, -3 * PI, 2 * PI, PI + 0.1, -PI - 0.1, 7.0])
    w = wrap_angle(a)
    assert np.all(w > -PI) and np.all(w <= PI)
    np.testing.assert_allclose(w[:6], [0.0, PI, PI, PI, PI, 0.0], atol=1e-12)
    np.testing.assert_allclose(w[6:], [-PI + 0.1, PI - 0.1, 7.0 - 2 * PI], atol=1e-12)
    assert wrap_angle(0.5).shape == ()


# --------------------------------------------------------------------------- boxes
def test_corners_axis_aligned_and_rotated():
    b = OrientedBoxes(np.array(1.0), np.array(2.0), np.array(0.0), np.array(4.0), np.array(2.0))
    # FL, RL, RR, FR of a 4 x 2 box centred at (1, 2) heading +x
    np.testing.assert_allclose(b.corners(), [[3, 3], [-1, 3], [-1, 1], [3, 1]], atol=1e-12)
    r = OrientedBoxes(np.array(0.0), np.array(0.0), np.array(PI / 2), np.array(4.0), np.array(2.0))
    # heading +y: front-left is (-1, 2)
    np.testing.assert_allclose(r.corners(), [[-1, 2], [-1, -2], [1, -2], [1, 2]], atol=1e-12)


def test_unit_squares_overlap_by_distance():
    a = unit_square()
    assert boxes_overlap(a, unit_square(0.9, 0.0))  # 0.9 < 0.5 + 0.5
    assert not boxes_overlap(a, unit_square(1.1, 0.0))  # gap of 0.1
    assert not boxes_overlap(a, unit_square(1.0, 0.0))  # touching edges: strict, no overlap
    assert not boxes_overlap(a, unit_square(1.0, 1.0))  # touching corners
    assert boxes_overlap(a, unit_square(0.0, 0.0))  # identical
    assert boxes_overlap(a, unit_square(0.0, -0.9, yaw=0.3))


def test_rotated_square_sat_vs_aabb():
    # B: unit square rotated 45 deg at (1.1, 1.1). Its axis-aligned bounding box has half-size
    # sqrt(2)/2 = 0.7071, spanning x, y in [0.393, 1.807], which overlaps A = [-0.5, 0.5]^2.
    # SAT on axis (1, 1)/sqrt(2): centre distance 1.1 * sqrt(2) = 1.556; A's half-projection
    # 0.5 * (1/sqrt2 + 1/sqrt2) = 0.7071, B's 0.5 -> 1.207 < 1.556, separated.
    a = unit_square()
    b = unit_square(1.1, 1.1, PI / 4)
    aabb_half = np.sqrt(2) / 2
    assert 1.1 - aabb_half < 0.5  # the AABBs overlap
    assert not boxes_overlap(a, b)
    assert not boxes_overlap(b, a)
    # moved closer along the diagonal: 0.7071 + 0.5 = 1.207 > 0.8 * sqrt2 = 1.131 -> overlap
    assert boxes_overlap(a, unit_square(0.8, 0.8, PI / 4))


def test_long_thin_boxes_cross():
    # two 10 x 0.5 boxes crossing at right angles: centres 4 m apart along x still overlap
    a = OrientedBoxes(np.array(0.0), np.array(0.0), np.array(0.0), np.array(10.0), np.array(0.5))
    b = OrientedBoxes(np.array(4.0), np.array(0.0), np.array(PI / 2), np.array(10.0), np.array(0.5))
    assert boxes_overlap(a, b)
    b2 = OrientedBoxes(np.array(5.3), np.array(0.0), np.array(PI / 2), np.array(10.0), np.array(0.5))
    assert not boxes_overlap(a, b2)  # 5.3 > 5 + 0.25


def test_boxes_overlap_broadcasts_knt():
    K, N, T = 3, 4, 5
    rng = np.random.default_rng(0)
    ego = OrientedBoxes(
        x=rng.uniform(-5, 5, (K, 1, T)), y=rng.uniform(-5, 5, (K, 1, T)), yaw=rng.uniform(-PI, PI, (K, 1, T)),
        length=np.asarray(4.5), width=np.asarray(1.8),
    )
    other = OrientedBoxes(
        x=rng.uniform(-5, 5, (1, N, T)), y=rng.uniform(-5, 5, (1, N, T)), yaw=rng.uniform(-PI, PI, (1, N, T)),
        length=np.full((N, 1), 4.0), width=np.full((N, 1), 2.0),
    )
    res = boxes_overlap(ego, other)
    assert res.shape == (K, N, T) and res.dtype == bool
    assert ego.corners().shape == (K, 1, T, 4, 2)
    # symmetric, and equal to element-wise evaluation
    assert np.array_equal(res, boxes_overlap(other, ego))
    for k, n, t in [(0, 0, 0), (2, 3, 4), (1, 2, 3)]:
        e1 = OrientedBoxes(ego.x[k, 0, t], ego.y[k, 0, t], ego.yaw[k, 0, t], 4.5, 1.8)
        o1 = OrientedBoxes(other.x[0, n, t], other.y[0, n, t], other.yaw[0, n, t], 4.0, 2.0)
        assert bool(boxes_overlap(e1, o1)) == res[k, n, t]
    assert res.any() and not res.all()


# --------------------------------------------------------------------------- Polyline
def test_polyline_from_points_drops_duplicates_only():
    # consecutive duplicate (5, 0) dropped, collinear points kept
    p = Polyline.from_points(np.array([[0, 0], [5, 0], [5, 0], [10, 0], [10, 10]], dtype=float))
    np.testing.assert_allclose(p.xy, [[0, 0], [5, 0], [10, 0], [10, 10]])
    np.testing.assert_allclose(p.s, [0, 5, 10, 20])
    np.testing.assert_allclose(p.heading, [0, 0, PI / 2])
    assert p.length == 20.0
    with pytest.raises(ValueError):
        Polyline.from_points(np.array([[1.0, 1.0], [1.0, 1.0]]))
    with pytest.raises(ValueError):
        Polyline.from_points(np.zeros((0, 2)))
    with pytest.raises(ValueError):
        Polyline.from_points(np.zeros((3, 3)))
    with pytest.raises(ValueError):  # frozen, read-only arrays
        p.xy[0, 0] = 1.0


L_PATH = np.array([[0, 0], [10, 0], [10, 10]], dtype=float)


def test_project_known_points():
    p = Polyline.from_points(L_PATH)
    pts = np.array(
        [
            [3.0, 1.0],  # above first leg: s = 3, left +1
            [3.0, -2.0],  # below first leg: right -2
            [11.0, 4.0],  # right of second leg (east of x = 10): s = 10 + 4, d = -1
            [9.0, 6.0],  # left of second leg: s = 16, d = +1
            [10.0, 0.0],  # the corner itself: s = 10, d = 0
            [12.0, -2.0],  # outside the corner (closest point is the vertex): s = 10, d = -2*sqrt2
            [8.0, 1.0],  # inside the corner, 1 m from leg 1 and 2 m from leg 2: s = 8, d = +1
            [-3.0, 0.5],  # behind the start: extrapolated, s = -3, d = 0.5
            [10.5, 14.0],  # beyond the end: extrapolated, s = 24, d = -0.5
        ]
    )
    s, d = p.project(pts)
    np.testing.assert_allclose(s, [3, 3, 14, 16, 10, 10, 8, -3, 24], atol=1e-12)
    np.testing.assert_allclose(d, [1, -2, -1, 1, 0, -2 * np.sqrt(2), 1, 0.5, -0.5], atol=1e-12)


def test_project_outer_corner_along_leg_extension_is_right_side():
    # (12, 0) continues leg 1 past the corner; equidistant (2 m) from both legs at the vertex.
    # Outside of a left turn is the right side: d = -2.
    p = Polyline.from_points(L_PATH)
    s, d = p.project(np.array([[12.0, 0.0], [10.0, -2.0]]))
    np.testing.assert_allclose(s, [10, 10])
    np.testing.assert_allclose(d, [-2, -2])


def test_to_xy_and_round_trip():
    p = Polyline.from_points(L_PATH)
    x, y, yaw = p.to_xy(np.array([0.0, 5.0, 10.0, 15.0, 20.0, -2.0, 23.0]), np.array([0.0, 1.0, 0.0, 1.0, 0.0, -1.0, 2.0]))
    np.testing.assert_allclose(x, [0, 5, 10, 9, 10, -2, 8], atol=1e-12)
    np.testing.assert_allclose(y, [0, 1, 0, 5, 10, -1, 13], atol=1e-12)
    np.testing.assert_allclose(yaw, [0, 0, PI / 2, PI / 2, PI / 2, 0, PI / 2], atol=1e-12)
    # points near the path that project onto a segment interior (not the outer corner wedge)
    rng = np.random.default_rng(1)
    leg1 = np.stack([rng.uniform(0.5, 8.5, 50), rng.uniform(-1.5, 1.5, 50)], axis=-1)
    leg2 = np.stack([rng.uniform(8.5, 11.5, 50), rng.uniform(1.6, 9.5, 50)], axis=-1)
    pts = np.concatenate([leg1, leg2, [[-4.0, 0.7], [10.3, 15.0]]]).reshape(2, 51, 2)
    s, d = p.project(pts)
    assert s.shape == d.shape == (2, 51)
    x, y, _ = p.to_xy(s, d)
    np.testing.assert_allclose(np.stack([x, y], axis=-1), pts, atol=1e-9)


def test_project_broadcast_and_blocking(monkeypatch):
    import sumo_ethics.geometry as g

    p = Polyline.from_points(L_PATH)
    pts = np.random.default_rng(2).uniform(-2, 12, (3, 4, 5, 2))
    s, d = p.project(pts)
    assert s.shape == d.shape == (3, 4, 5)
    monkeypatch.setattr(g, "_PROJECT_BLOCK_PAIRS", 3)  # one point per block
    s2, d2 = p.project(pts)
    np.testing.assert_array_equal(s, s2)
    np.testing.assert_array_equal(d, d2)


def test_heading_and_curvature():
    p = Polyline.from_points(L_PATH)
    np.testing.assert_allclose(p.heading_at(np.array([-1.0, 3.0, 9.99, 10.0, 25.0])), [0, 0, 0, PI / 2, PI / 2])
    # corner at s = 10 turns pi/2 over (10 + 10)/2 = 10 m: k = pi/20 there, 0 at the ends
    np.testing.assert_allclose(p.curvature_at(np.array([0.0, 5.0, 10.0, 15.0, 20.0, 30.0])),
                               [0, PI / 40, PI / 20, PI / 40, 0, 0], atol=1e-12)
    # a finely sampled circle of radius 20, turning right (clockwise): curvature -1/20
    th = np.linspace(PI / 2, -PI / 2, 181)
    circle = Polyline.from_points(np.stack([20 * np.cos(th), 20 * np.sin(th)], axis=-1))
    k = circle.curvature_at(np.linspace(2.0, circle.length - 2.0, 40))
    np.testing.assert_allclose(k, -1 / 20, rtol=1e-4)
    # integral of the curvature = heading change from first to last segment (-pi + 1 deg,
    # since each segment's heading is that of its chord)
    s = np.linspace(0, circle.length, 200001)
    total = circle.heading[-1] - circle.heading[0]
    np.testing.assert_allclose(total, -PI + PI / 180, rtol=1e-12)
    np.testing.assert_allclose(np.trapezoid(circle.curvature_at(s), s), total, rtol=1e-6)


def test_windowed_projection_matches_full():
    # a zig-zag path; points near the middle project the same with a window around them
    t = np.linspace(0, 200, 81)
    path = Polyline.from_points(np.stack([t, 5 * np.sin(t / 15)], axis=-1))
    rng = np.random.default_rng(1)
    pts = np.stack([rng.uniform(60, 140, 200), rng.uniform(-8, 8, 200)], axis=-1)
    s_full, d_full = path.project(pts)
    s_win, d_win = path.project(pts, near=(40.0, 180.0))
    np.testing.assert_allclose(s_win, s_full, atol=1e-9)
    np.testing.assert_allclose(d_win, d_full, atol=1e-9)


def test_project_point_is_bit_identical_to_batched_projection():
    # the per-step single-point path must give exactly the batched result, ends, corners
    # (bisector side) and windows included
    rng = np.random.default_rng(7)
    for _ in range(30):
        path = Polyline.from_points(np.cumsum(rng.normal(size=(int(rng.integers(2, 30)), 2)) * 3.0, axis=0))
        pts = np.concatenate([rng.normal(size=(40, 2)) * 15 + path.xy.mean(axis=0), path.xy,
                              path.xy + rng.normal(size=path.xy.shape) * 1e-3])
        for near in (None, (0.3 * path.length, 0.6 * path.length), (-5.0, 3.0), (path.length - 1, path.length + 5)):
            s_all, d_all = path._project_flat(pts, *path._window(near))
            one = np.array([path.project_point(x, y, near) for x, y in pts])
            assert one[:, 0].tobytes() == s_all.tobytes() and one[:, 1].tobytes() == d_all.tobytes()
            s1, d1 = path.project(pts[3], near=near)
            assert s1.shape == () and float(s1) == s_all[3] and float(d1) == d_all[3]


def test_may_be_within_never_drops_a_point_inside_the_corridor():
    t = np.linspace(0, 300, 301)
    path = Polyline.from_points(np.stack([t, 20 * np.sin(t / 25)], axis=-1))
    rng = np.random.default_rng(3)
    pts = np.stack([rng.uniform(-20, 320, 4000), rng.uniform(-30, 30, 4000)], axis=-1)
    for near in ((100.0, 220.0), (-10.0, 50.0), (250.0, 400.0)):
        keep = path.may_be_within(pts[:, 0], pts[:, 1], 1.6, near)
        _, d = path.project(pts, near=near)
        assert keep[np.abs(d) < 1.6].all()
        if near == (100.0, 220.0):
            assert keep.mean() < 0.5  # and it does filter
