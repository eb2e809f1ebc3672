"""The visible region (sumo_ethics.visibility) against geometry worked out by hand, and against a
brute-force test of every sight line (numpy segment intersections, no shapely)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely

from sumo_ethics.geometry import OrientedBoxes
from sumo_ethics.visibility import box_shadows, polygon_shadows, view, visible_share


def corners(x, y, yaw, length, width):
    return OrientedBoxes(np.atleast_1d(float(x)), np.atleast_1d(float(y)), np.atleast_1d(float(yaw)),
                         np.atleast_1d(float(length)), np.atleast_1d(float(width))).corners()


def stack(*boxes):
    return np.concatenate(boxes, axis=0)


# a van parked at the kerb: x 7.5..12.5, y -3..-1; a pedestrian (0.5 x 0.5) just past its front, y -3.75..-3.25
VAN = corners(10.0, -2.0, 0.0, 5.0, 2.0)
PED = corners(13.5, -3.5, math.pi / 2, 0.5, 0.5)


def test_pedestrian_behind_a_parked_van_is_hidden_from_behind_and_seen_from_ahead():
    """From (0, 0) every sight line to the pedestrian's corners enters the van through its rear
    face x = 7.5 (at y = -1.77 .. -2.12, inside -3 .. -1): hidden whole. From (20, 0), ahead of
    both, no sight line meets the van (x <= 12.5 < 13.25): seen whole. From (10, 2), beside the
    van, the line to the pedestrian's centre meets the van's top face y = -1 at x = 11.9: hidden."""
    both = stack(VAN, PED)
    for eye, share in (((0.0, 0.0), 0.0), ((20.0, 0.0), 1.0), ((10.0, 2.0), 0.0)):
        v = view(np.array(eye), 50.0, both)
        s = visible_share(v, both)
        assert s[1] == pytest.approx(share, abs=1e-9), eye
        assert s[0] == pytest.approx(1.0, abs=1e-9)  # the van itself is seen by its near side


def test_half_a_box_in_a_shadow():
    """An occluder x 4..6, y -2..0 seen from the origin: its upper extreme sight line is the x axis,
    its lower one runs through (4, -2) (slope -1/2, y = -4.75 at x = 9.5). A 1 x 1 box centred on
    the x axis at x = 10 has its lower half, and only that, in the shadow: share 0.5."""
    occ = corners(5.0, -1.0, 0.0, 2.0, 2.0)
    box = corners(10.0, 0.0, 0.0, 1.0, 1.0)
    v = view(np.zeros(2), 50.0, stack(occ, box))
    assert visible_share(v, box)[0] == pytest.approx(0.5, abs=1e-9)


def test_a_building_casts_the_shadow_it_should():
    """A square building x 10..20, y 10..20 seen from the origin, range 50 m. Its extreme sight
    lines run through (20, 10) and (10, 20), at atan(1/2) and atan(2); what it hides within the
    range is that sector, (atan 2 - atan 1/2) / 2 x 50^2 = 804.4 m^2, less the quadrilateral
    (0,0) (20,10) (10,10) (10,20) in front of it (shoelace: 100 m^2): 704.4 m^2, the building's own
    100 m^2 included. The disc is a 64-gon (its area 0.14 % below the circle's): within 3 m^2."""
    building = shapely.box(10.0, 10.0, 20.0, 20.0)
    v = view(np.zeros(2), 50.0, np.zeros((0, 4, 2)), [building])
    expected = (math.atan(2.0) - math.atan(0.5)) / 2.0 * 50.0**2 - 100.0
    assert v.hidden.area == pytest.approx(expected, abs=3.0)
    assert v.visible.area + v.hidden.area == pytest.approx(v.disc().area, rel=1e-9)
    for p, hidden in (((30.0, 30.0), True), ((15.0, 15.0), True), ((30.0, 10.0), False), ((5.0, 5.0), False),
                      ((12.0, 22.0), True), ((12.0, 25.0), False), ((9.0, 25.0), False)):
        assert v.hidden.contains(shapely.Point(p)) is hidden, p
        assert v.visible.contains(shapely.Point(p)) is not hidden, p


def test_an_eye_inside_an_obstacle_is_not_blinded():
    """A box or building around the eye (the ego's own box, a collision, a tunnel) hides nothing."""
    assert box_shadows(np.zeros(2), corners(0.0, 0.0, 0.3, 4.0, 2.0), 50.0)[0] is None
    assert polygon_shadows(np.zeros(2), [shapely.box(-1.0, -1.0, 1.0, 1.0)], 50.0) == []
    assert view(np.zeros(2), 30.0, corners(0.0, 0.0, 0.3, 4.0, 2.0)).visible.area == pytest.approx(
        view(np.zeros(2), 30.0, np.zeros((0, 4, 2))).visible.area)


def _segments_cross(p, q, a, b):
    """(P, E) bool: segment p-q (P, 2 each) properly crosses segment a-b (E, 2 each)."""
    def orient(u, v, w):
        return (v[..., 0] - u[..., 0]) * (w[..., 1] - u[..., 1]) - (v[..., 1] - u[..., 1]) * (w[..., 0] - u[..., 0])
    p, q = p[:, None], q[:, None]
    a, b = a[None], b[None]
    return ((orient(p, q, a) * orient(p, q, b)) < 0) & ((orient(a, b, p) * orient(a, b, q)) < 0)


def _inside(pts, ring):
    """(P,) bool: even-odd point in polygon (ring (R, 2), closed)."""
    x, y = pts[:, 0:1], pts[:, 1:2]
    a, b = ring[None, :-1], ring[None, 1:]
    crosses = ((a[..., 1] > y) != (b[..., 1] > y)) & (
        x < (b[..., 0] - a[..., 0]) * (y - a[..., 1]) / (b[..., 1] - a[..., 1] + 1e-300) + a[..., 0])
    return crosses.sum(axis=1) % 2 == 1


def test_view_agrees_with_every_sight_line():
    """2,000 seeded random points near 6 random boxes and an L-shaped (non-convex) building: a point
    is hidden by brute force when it is beyond the range, inside the building, or the segment from
    the eye to it crosses an edge of an obstacle (a point inside a road user's box is seen: boxes
    are seen by their near side, unless that side is hidden, which the crossing test finds).
    The view's polygons agree on every point more than 1 cm from their boundary (and from the range)."""
    rng = np.random.default_rng(7)
    eye = np.array([1.0, -2.0])
    n = 6
    box = OrientedBoxes(rng.uniform(-25, 25, n), rng.uniform(-25, 25, n), rng.uniform(-3, 3, n),
                        rng.uniform(0.5, 12, n), rng.uniform(0.5, 3, n)).corners()
    box = box[np.hypot(*(box.mean(axis=1) - eye).T) > 8.0]  # none around the eye
    ell = shapely.Polygon([(-20, 10), (-5, 10), (-5, 14), (-16, 14), (-16, 28), (-20, 28)])
    radius = 30.0
    v = view(eye, radius, box, [ell])
    pts = rng.uniform(-35, 35, (2000, 2))
    ring = np.asarray(ell.exterior.coords)
    edges_a = [ring[:-1]] + [b for b in box]
    edges_b = [ring[1:]] + [np.roll(b, -1, axis=0) for b in box]
    a, b = np.concatenate(edges_a), np.concatenate(edges_b)
    crossed = _segments_cross(np.repeat(eye[None], len(pts), 0), pts, a, b).any(axis=1)
    in_box = np.zeros(len(pts), bool)
    for bx in box:
        in_box |= _inside(pts, np.r_[bx, bx[:1]])
    # a point inside a box is hidden only if the box's near side is: crossing its own box's edges
    # does not count, so test the box's points against the other obstacles' edges alone
    own = np.zeros(len(pts), bool)
    for i, bx in enumerate(box):
        inside = _inside(pts, np.r_[bx, bx[:1]])
        others_a = np.concatenate([ring[:-1]] + [box[j] for j in range(len(box)) if j != i])
        others_b = np.concatenate([ring[1:]] + [np.roll(box[j], -1, axis=0) for j in range(len(box)) if j != i])
        hid = _segments_cross(np.repeat(eye[None], len(pts), 0), pts, others_a, others_b).any(axis=1)
        own |= inside & hid
    hidden = np.where(in_box, own, crossed) | _inside(pts, ring) | (np.hypot(*(pts - eye).T) > radius)
    margin = shapely.distance(shapely.points(pts), shapely.boundary(v.visible))
    # the disc is a 64-gon: points between it and the circle (within 3.6 cm of the range) are left out
    dist = np.hypot(*(pts - eye).T)
    sure = (margin > 0.01) & (np.abs(dist - radius) > radius * (1 - math.cos(math.pi / 64)) + 0.01)
    got = ~shapely.contains_xy(v.visible, pts[:, 0], pts[:, 1])
    assert sure.sum() > 1900
    assert (got[sure] == hidden[sure]).all()
    assert 0.1 < hidden.mean() < 0.9  # the check is not vacuous


def test_a_wall_seen_wide_hides_everything_behind_it_up_to_the_range():
    """A wall y 2..3, x -20..20, 2 m from the eye, spans 169 deg of its view: every point behind it
    within the range is hidden (the shadow's far side is pushed out past the range however wide the
    wall is seen), and beside its ends is seen."""
    v = view(np.zeros(2), 30.0, np.zeros((0, 4, 2)), [shapely.box(-20.0, 2.0, 20.0, 3.0)])
    for p in ((0.0, 29.5), (-10.0, 27.0), (12.0, 20.0), (-1.0, 3.5)):
        assert v.hidden.contains(shapely.Point(p)), p
    for p in ((-29.0, 2.5), (28.0, 2.0), (0.0, -29.5)):
        assert v.visible.contains(shapely.Point(p)), p


def test_a_convex_building_shadow_by_its_hull_equals_the_union_of_its_edges():
    """The two ways of casting a building's shadow agree: for convex polygons (the hull of its
    vertices and of those pushed out) and edge by edge (the polygon and a quadrilateral per edge
    facing the eye, as non-convex polygons are cast): the same region within the range."""
    from sumo_ethics.visibility import _edge_shadows, _hull_shadows

    rng = np.random.default_rng(3)
    eye = np.array([2.0, -1.0])
    disc = shapely.Point(eye).buffer(40.0)
    for _ in range(20):
        pts = rng.uniform(-30, 30, (9, 2))
        poly = shapely.convex_hull(shapely.multipoints(pts))
        if poly.covers(shapely.Point(eye)):
            continue
        hull = _hull_shadows(eye, [poly], 40.0)[0].intersection(disc)
        edges = shapely.union_all(np.r_[_edge_shadows(eye, [poly], 40.0), [poly]]).intersection(disc)
        assert hull.symmetric_difference(edges).area < 1e-6 * max(hull.area, 1.0)
        assert hull.area > poly.area  # it hides more than itself
