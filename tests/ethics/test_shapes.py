"""Collision probability over true shapes (``method="shapes"``) and the envelope test.

References that share no code with the package: scipy's Owen's T, numerical quadrature, a
seeded Monte Carlo of the other's centre with a numpy separating-axis test of the two boxes,
shapely's distances, and positions worked out by hand.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import ndtr, owens_t
from shapely.geometry import Polygon

from sumo_ethics.ethics.probability import ProbabilityConfig, collision_probability
from sumo_ethics.ethics.risk import assess_risk
from sumo_ethics.ethics.shapes import _owens_t, octagon, polygon_mass
from sumo_ethics.plan.ethical import PlannerConfig, first_overlap
from sumo_ethics.types import AgentStates, Candidates, Prediction, RoadUserClass

EGO_L, EGO_W = 4.508, 1.610
DT = 0.1
#: (length, width) [m]: car, truck, bus, 16.5 m trailer, bicycle, pedestrian (SUMO's default sizes)
SIZES = {"car": (4.5, 1.8), "truck": (7.1, 2.4), "bus": (12.0, 2.5), "trailer": (16.5, 2.55),
         "bicycle": (1.6, 0.65), "pedestrian": (0.215, 0.478)}


def corners(x, y, yaw, length, width) -> np.ndarray:
    """(..., 4, 2) corners of boxes centred at (x, y), written out by hand."""
    c, s = np.cos(yaw)[..., None], np.sin(yaw)[..., None]
    lx = np.array([1, -1, -1, 1]) * length / 2
    ly = np.array([1, 1, -1, -1]) * width / 2
    return np.stack([np.asarray(x)[..., None] + c * lx - s * ly, np.asarray(y)[..., None] + s * lx + c * ly], axis=-1)


def sat_overlap(x, y, yaw: float, length: float, width: float) -> np.ndarray:
    """Whether the ego box (origin, heading 0) overlaps boxes of heading ``yaw`` centred at the
    points (x, y): the separating-axis theorem written from scratch, with each box's half-extent
    on an axis taken from its hand-written corners."""
    ego = corners(0.0, 0.0, 0.0, EGO_L, EGO_W)
    oth = corners(0.0, 0.0, yaw, length, width)
    hit = np.ones(np.shape(x), bool)
    for a in ([1.0, 0.0], [0.0, 1.0], [math.cos(yaw), math.sin(yaw)], [-math.sin(yaw), math.cos(yaw)]):
        reach = np.abs(ego @ a).max() + np.abs(oth @ a).max()
        hit &= np.abs(x * a[0] + y * a[1]) <= reach
    return hit


def one_step(x, y, yaw, cov, length, width, ego_yaw=0.0, cfg=ProbabilityConfig()) -> float:
    """P of one agent at one step against the ego at the origin."""
    cand = Candidates(dt=DT, x=np.zeros((1, 1)), y=np.zeros((1, 1)), yaw=np.full((1, 1), ego_yaw),
                      speed=np.zeros((1, 1)), accel=np.zeros((1, 1)), curvature=np.zeros((1, 1)), s=np.zeros((1, 1)),
                      d=np.zeros((1, 1)), horizon=np.array([DT]), valid=np.ones((1, 1), bool))
    pred = Prediction(("a",), DT, np.array([[[x, y]]], float), np.asarray(cov, float).reshape(1, 1, 2, 2),
                      np.array([[yaw]], float))
    return float(collision_probability(cand, pred, np.array([length]), np.array([width]), EGO_L, EGO_W, cfg)[0, 0, 0])


def test_owens_t_matches_scipy():
    rng = np.random.default_rng(0)
    h = rng.uniform(0.0, 8.3, 3000)
    a = np.exp(rng.uniform(-6.0, 6.0, 3000))
    mine = np.array([_owens_t(hh, aa, float(ndtr(hh))) for hh, aa in zip(h, a)])
    np.testing.assert_allclose(mine, owens_t(h, a), rtol=0, atol=3e-9)


def test_octagon_is_exactly_where_the_boxes_overlap():
    """Inside the octagon <=> the boxes overlap (shapely's intersection), away from its boundary."""
    rng = np.random.default_rng(1)
    for _ in range(300):
        ol, ow = rng.uniform(0.2, 17.0, 2)
        rel = rng.uniform(-7.0, 7.0)
        poly = Polygon(octagon(EGO_L, EGO_W, ol, ow, rel))
        assert poly.is_valid and poly.exterior.is_ccw
        x, y = rng.uniform(-12.0, 12.0, 2)
        from shapely.geometry import Point

        if poly.exterior.distance(Point(x, y)) < 1e-9:
            continue
        ego = Polygon(corners(0.0, 0.0, 0.0, EGO_L, EGO_W))
        other = Polygon(corners(x, y, rel, ol, ow))
        assert poly.contains(Point(x, y)) == ego.intersects(other)


def test_polygon_mass_matches_quadrature():
    """A triangle with a known mass: the quadrant x > 0, y > 0 cut at 40 sigma is 1/4, a half-plane
    strip is a difference of normal CDFs, and a rotated rectangle matches scipy's dblquad."""
    from scipy.integrate import dblquad
    from scipy.stats import norm

    big = 40.0
    quad = np.array([[0.0, 0.0], [big, 0.0], [big, big], [0.0, big]])
    assert polygon_mass(quad, np.zeros(2), np.eye(2)) == pytest.approx(0.25, abs=1e-9)
    strip = np.array([[-big, 0.3], [big, 0.3], [big, 1.7], [-big, 1.7]])
    assert polygon_mass(strip, np.zeros(2), np.eye(2) * 0.49) == pytest.approx(norm.cdf(1.7 / 0.7) - norm.cdf(0.3 / 0.7),
                                                                            abs=1e-9)
    cov = np.array([[0.8, 0.3], [0.3, 0.4]])
    inv = np.linalg.inv(cov)
    verts = corners(0.4, -0.2, 0.5, 3.0, 1.2)
    pdf = lambda y, x: math.exp(-0.5 * np.array([x, y]) @ inv @ np.array([x, y])) / (2 * math.pi * math.sqrt(np.linalg.det(cov)))  # noqa: E731
    poly = Polygon(verts)
    xs = verts[:, 0]

    def y_range(x):
        from shapely.geometry import LineString

        seg = poly.intersection(LineString([(x, -50), (x, 50)]))
        return (seg.bounds[1], seg.bounds[3]) if not seg.is_empty else (0.0, 0.0)

    ref = dblquad(pdf, xs.min(), xs.max(), lambda x: y_range(x)[0], lambda x: y_range(x)[1], epsabs=1e-10)[0]
    assert polygon_mass(verts, np.zeros(2), cov) == pytest.approx(ref, abs=1e-6)


def _cases(rng, kind: str, n: int):
    """n seeded poses of a road user of ``kind`` around the ego, parallel (+/- 0.2 rad) or crossing."""
    length, width = SIZES[kind]
    x = rng.uniform(-(EGO_L + length) / 2 - 1.0, (EGO_L + length) / 2 + 1.0, n)
    y = rng.uniform(-(EGO_W + length) / 2 - 1.0, (EGO_W + length) / 2 + 1.0, n)
    return x, y, length, width


def _penetration(x, y, yaw, length, width) -> float:
    """Signed overlap of the ego box and the other box: > 0 the penetration depth (the shortest
    shift that separates them: the smallest overlap of their projections on the four box axes,
    from the corners), < 0 minus their distance (shapely)."""
    ego = corners(0.0, 0.0, 0.0, EGO_L, EGO_W)
    other = corners(x, y, yaw, length, width)
    if not Polygon(ego).intersects(Polygon(other)):
        return -Polygon(ego).distance(Polygon(other))
    depth = np.inf
    for ax in ([1.0, 0.0], [0.0, 1.0], [math.cos(yaw), math.sin(yaw)], [-math.sin(yaw), math.cos(yaw)]):
        pe, po = ego @ np.array(ax), other @ np.array(ax)
        depth = min(depth, min(pe.max(), po.max()) - max(pe.min(), po.min()))
    return depth


@pytest.mark.parametrize("kind", list(SIZES))
@pytest.mark.parametrize("crossing", [False, True])
def test_overlapping_boxes_score_high_and_separated_ones_zero(kind, crossing):
    """sigma 0.05 m: boxes overlapping by 0.2 m or more give P >= 0.5; at every sigma, boxes
    further apart than 5 sigma give P < 1e-6 (a half-plane bound: Phi(-5) = 2.9e-7)."""
    rng = np.random.default_rng(hash((kind, crossing)) % 2**32)
    base = math.pi / 2 if crossing else 0.0
    length, width = SIZES[kind]
    seen_in = seen_out = 0
    for sigma in (0.05, 0.1, 0.3):
        x, y, _, _ = _cases(rng, kind, 150)
        yaw = base + rng.uniform(-0.2, 0.2, len(x))
        for xi, yi, wi in zip(x, y, yaw):
            depth = _penetration(xi, yi, wi, length, width)
            p = one_step(xi, yi, wi, np.eye(2) * sigma**2, length, width)
            if sigma == 0.05 and depth >= 0.2:
                assert p >= 0.5, (kind, xi, yi, wi, depth, p)
                seen_in += 1
            if depth < -5 * sigma:
                assert p < 1e-6, (kind, xi, yi, wi, depth, p)
                seen_out += 1
    assert seen_in >= 10 and seen_out >= 10  # both claims were exercised


def test_monte_carlo_agreement_on_200_random_cases():
    """10^6 samples of the other's centre, each tested by the hand-written separating-axis test:
    |P - share of overlapping samples| <= 2e-3 (the Monte Carlo's own standard error is <= 5e-4)."""
    rng = np.random.default_rng(7)
    kinds = list(SIZES)
    worst = 0.0
    z = rng.standard_normal((1_000_000, 2))  # one draw, shaped per case by its covariance's Cholesky factor
    for i in range(200):
        length, width = SIZES[kinds[i % len(kinds)]]
        sigma = rng.choice([0.05, 0.1, 0.3, 1.0])
        a = rng.normal(size=(2, 2)) * sigma
        cov = a @ a.T + 1e-4 * np.eye(2)
        yaw = rng.uniform(-math.pi, math.pi)
        reach = (EGO_L + length) / 2
        mx, my = rng.uniform(-reach, reach), rng.uniform(-(EGO_W + length) / 2, (EGO_W + length) / 2)
        p = one_step(mx, my, yaw, cov, length, width)
        s = np.array([mx, my]) + z @ np.linalg.cholesky(cov).T
        mc = sat_overlap(s[:, 0], s[:, 1], yaw, length, width).mean()
        worst = max(worst, abs(p - mc))
    assert worst <= 2e-3


def test_certain_contact_is_one_and_the_origin_score_is_not():
    """Two aligned cars on the same spot: P = 1 (Origin's three-point score: 2/3 at most)."""
    tiny = np.eye(2) * 1e-4
    assert one_step(0.0, 0.0, 0.0, tiny, 4.5, 1.8) == pytest.approx(1.0, abs=1e-9)
    assert one_step(0.0, 0.0, 0.0, tiny, 4.5, 1.8, cfg=ProbabilityConfig(method="origin")) <= 2 / 3 + 1e-9


def test_trailer_around_the_ego_and_a_truck_beside_it():
    """The ego standing inside a trailer's footprint 4.4 m from its centre, and a truck whose side
    reaches 0.405 m over the ego's box (centre 1.65 m to the side, half-width 1.25 m): at sigma
    0.1 m the trailer's P is 1 and the truck's the normal mass within 4.05 sigma sideways (the
    boxes are aligned and 11.6 m long together: along them the mass is 1); Origin's score gives
    0 to the truck."""
    from scipy.stats import norm

    cov = np.eye(2) * 0.01
    assert one_step(4.4, 0.0, 0.0, cov, 16.5, 2.55) == pytest.approx(1.0, abs=1e-9)
    inside = norm.cdf((EGO_W / 2 + 1.25 - 1.65) / 0.1) - norm.cdf((-EGO_W / 2 - 1.25 - 1.65) / 0.1)
    assert one_step(0.0, 1.65, 0.0, cov, 7.1, 2.5) == pytest.approx(inside, abs=1e-8)
    assert one_step(0.0, 1.65, 0.0, cov, 7.1, 2.5, cfg=ProbabilityConfig(method="origin")) == 0.0
    # its side exactly on the ego's edge: half the mass of the lateral Gaussian is inside
    assert one_step(0.0, EGO_W / 2 + 1.25, 0.0, cov, 7.1, 2.5) == pytest.approx(0.5, abs=1e-6)


def _straight(T: int, speed: float, valid_steps: int | None = None) -> Candidates:
    t = DT * np.arange(1, T + 1)[None, :]
    x = speed * t
    z = np.zeros_like(x)
    valid = np.ones_like(x, bool) if valid_steps is None else (np.arange(T) < valid_steps)[None, :]
    return Candidates(dt=DT, x=x, y=z, yaw=z, speed=z + speed, accel=z, curvature=z, s=x, d=z,
                      horizon=np.array([T * DT]), valid=valid)


def _standing(x: float, y: float, T: int, sigma: float = 0.1) -> Prediction:
    return Prediction(("a",), DT, np.broadcast_to([[x, y]], (1, T, 2)).copy(),
                      np.broadcast_to(np.eye(2) * sigma**2, (1, T, 2, 2)).copy(), np.zeros((1, T)))


def test_truck_beside_the_ego_enters_at_step_zero_and_is_not_safe():
    T = 40
    cand = _straight(T, 0.0)
    pred = _standing(0.0, 1.65, T)
    truck = AgentStates(("a",), np.array([0.0]), np.array([1.65]), np.zeros(1), np.zeros(1), np.zeros(1),
                        np.array([7.1]), np.array([2.5]), np.array([25000.0]),
                        np.array([RoadUserClass.TRUCK], np.int8))
    risk = assess_risk(cand, pred, truck, 1475.0, RoadUserClass.CAR, EGO_L, EGO_W)
    assert risk.p[0, 0, 0] > 0.9999  # 4.05 sigma inside (see the test above)
    assert (risk.ego_risk + risk.other_risk)[0, 0] >= PlannerConfig().max_risk  # not "safe"
    pc = ProbabilityConfig()
    first = first_overlap(cand, pred, np.array([7.1 + pc.length_margin]), np.array([2.5 + pc.width_margin]),
                          EGO_L, EGO_W)
    assert first[0] == 0


def test_stopped_car_past_the_candidates_end_is_flagged_by_its_stopping_distance():
    """14 m/s for 2 s (then invalid); a stopped car 3.5 m past the ego's front at the candidate's
    end. With Origin's margins the car's envelope starts at 36.004 - 2.75 = 33.254 m; the ego's
    front at step i (time (i + 1) 0.1 s) is 1.4 (i + 1) + 2.254 m, stretched by 14^2 / (2 x 8) =
    12.25 m: it reaches 33.254 first at i = 13. Without the stretch it never does."""
    T = 40
    cand = _straight(T, 14.0, valid_steps=20)
    end_front = 14.0 * 2.0 + EGO_L / 2
    car_x = end_front + 3.5 + 4.5 / 2
    pred = _standing(car_x, 0.0, T)
    args = (np.array([4.5 + 1.0]), np.array([1.8 + 0.5]), EGO_L, EGO_W)
    assert first_overlap(cand, pred, *args, brake=8.0)[0] == 13
    assert first_overlap(cand, pred, *args)[0] == T


def test_gate_is_geometric_a_wide_gaussian_far_away_still_counts():
    """A mean 9 m beside the ego with sigma 3 m: Origin's 5 m gate gives 0, the true mass is
    the normal tail beyond (9 - 1.8 / 2 - 0.805) / 3 sigma across (the ego and car both long
    compared with the sideways offset, so a half-plane bound from above and below)."""
    from scipy.stats import norm

    p = one_step(0.0, 9.0, 0.0, np.eye(2) * 9.0, 4.5, 1.8)
    assert one_step(0.0, 9.0, 0.0, np.eye(2) * 9.0, 4.5, 1.8, cfg=ProbabilityConfig(method="origin")) == 0.0
    lateral = norm.cdf(-(9.0 - 0.9 - 0.805) / 3.0) - norm.cdf(-(9.0 + 0.9 + 0.805) / 3.0)
    along = norm.cdf((4.5 + EGO_L) / 2 / 3.0) - norm.cdf(-(4.5 + EGO_L) / 2 / 3.0)
    assert p == pytest.approx(lateral * along, rel=1e-6)  # aligned boxes: the octagon is a rectangle


def test_same_inputs_same_bytes():
    rng = np.random.default_rng(3)
    K, N, T = 30, 6, 40
    x = np.cumsum(rng.uniform(0.5, 1.5, (K, T)), axis=1)
    z = np.zeros((K, T))
    cand = Candidates(dt=DT, x=x, y=rng.uniform(-2, 2, (K, 1)) + z, yaw=z, speed=z + 10, accel=z, curvature=z, s=x,
                      d=z, horizon=np.full(K, 4.0), valid=np.ones((K, T), bool))
    mean = np.stack([rng.uniform(0, 40, N), rng.uniform(-3, 3, N)], axis=-1)[:, None, :] + np.zeros((N, T, 2))
    a = rng.normal(size=(N, T, 2, 2)) * 0.5
    pred = Prediction(tuple("abcdef"), DT, mean, a @ a.transpose(0, 1, 3, 2), rng.uniform(-3, 3, (N, T)))
    args = (np.full(N, 4.5), np.full(N, 1.8), EGO_L, EGO_W)
    p1 = collision_probability(cand, pred, *args)
    p2 = collision_probability(cand, pred, *args)
    assert p1.tobytes() == p2.tobytes() and (p1 > 0).sum() > 20


def test_config_method_is_checked():
    from sumo_ethics.errors import ConfigError

    with pytest.raises(ConfigError, match="method must be one of shapes, origin"):
        ProbabilityConfig(method="boxes")
    assert PlannerConfig().probability.method == "shapes"
