"""The bounded search for the "shapes" risk terms (ethics/search.py): its harm, its bounds, and
that the planner's risk terms hold the exhaustive evaluation's: to rounding in the exact mode, to
the stated tolerance otherwise."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from conftest import straight_road_scene
from sumo_ethics.ethics import search
from sumo_ethics.ethics.harm import HarmCoefficients, Party, crash_outcome
from sumo_ethics.ethics.probability import ProbabilityConfig
from sumo_ethics.ethics.risk import assess_risk
from sumo_ethics.ethics.shapes import octagon, polygon_mass
from sumo_ethics.plan import ethical
from sumo_ethics.plan.ethical import EthicalPlanner, PlannerConfig
from sumo_ethics.types import VULNERABLE, AgentStates, Candidates, Prediction, RoadUserClass

C = RoadUserClass
# (class, length, width, mass): car, truck, bus, a 16.5 m trailer, bicycle, pedestrian
BODIES = [(C.CAR, 4.5, 1.8, 1400.0), (C.TRUCK, 12.0, 2.5, 25000.0), (C.BUS, 12.0, 2.55, 13000.0),
          (C.TRUCK, 16.5, 2.6, 25000.0), (C.BICYCLE, 1.8, 0.65, 90.0), (C.PEDESTRIAN, 0.3, 0.5, 75.0),
          (C.MOTORCYCLE, 2.2, 0.9, 250.0)]


def test_order_harm_is_numpys_harm_to_1e_14():
    rng = np.random.default_rng(3)
    m = 200_000
    pick_a, pick_b = rng.integers(0, len(BODIES), m), rng.integers(0, len(BODIES), m)
    cls_a = np.array([BODIES[i][0] for i in pick_a], np.int8)
    cls_b = np.array([BODIES[i][0] for i in pick_b], np.int8)
    mass_a, mass_b = np.array([BODIES[i][3] for i in pick_a]), np.array([BODIES[i][3] for i in pick_b])
    ya, yb = rng.uniform(-7, 7, m), rng.uniform(-7, 7, m)
    dx, dy = rng.normal(0, 5, m), rng.normal(0, 5, m)
    dx[:2000], dy[:2000] = 0.0, 0.0  # coincident centres: crash_outcome calls that bearing 0
    # bearings exactly on the front/side and side/rear boundaries of party a (45 and 135 degrees)
    r = rng.uniform(0.5, 5, 4000)
    ang = ya[2000:6000] + np.where(np.arange(4000) % 2 == 0, np.pi / 4, 3 * np.pi / 4)
    dx[2000:6000], dy[2000:6000] = r * np.cos(ang), r * np.sin(ang)
    xa, yya = rng.uniform(-100, 100, m), rng.uniform(-100, 100, m)
    a = Party(xa, yya, ya, rng.uniform(0, 30, m), mass_a, cls_a)
    b = Party(xa + dx, yya + dy, yb, rng.uniform(0, 30, m), mass_b, cls_b)
    ref = crash_outcome(a, b, HarmCoefficients())
    got = search.order_harm(a, b, HarmCoefficients())
    # numpy's harm within _DH of the interval (a low, a high, b low, b high) ...
    assert (got[0] - search._DH <= ref.harm_a).all() and (ref.harm_a <= got[1] + search._DH).all()
    assert (got[2] - search._DH <= ref.harm_b).all() and (ref.harm_b <= got[3] + search._DH).all()
    # ... which is a point (low = high) off the impact-area boundaries, and there within _DH of it
    wide = (got[1] > got[0]) | (got[3] > got[2])
    assert not wide[6000:].any() and not wide[:2000].any()
    assert np.abs(got[0] - ref.harm_a)[~wide].max() <= search._DH
    # on the boundary bearings of party a (45 and 135 degrees), a protected pair's interval holds
    # both areas' harms: front and side at 45 degrees, side and rear at 135
    protected = ~VULNERABLE[cls_a] & ~VULNERABLE[cls_b]
    assert wide[2000:6000][protected[2000:6000]].mean() > 0.9
    # a number worked by hand: two 1475 kg cars head-on at 10 m/s each: dv = 10 m/s for each,
    # frontal: 1 / (1 + exp(4.457 - 0.177 * 10)) = 0.0637
    car = Party(np.zeros(1), np.zeros(1), np.zeros(1), np.full(1, 10.0), np.full(1, 1475.0), np.zeros(1, np.int8))
    other = Party(np.full(1, 4.5), np.zeros(1), np.full(1, math.pi), np.full(1, 10.0), np.full(1, 1475.0),
                  np.zeros(1, np.int8))
    assert search.order_harm(car, other, HarmCoefficients())[:, 0] == pytest.approx([0.06376] * 4, abs=5e-5)


def _random_case(rng):
    _, ol, ow, _ = BODIES[rng.integers(len(BODIES))]
    sig = rng.choice([0.05, 0.1, 0.3, 1.0, 5.0])
    s1, s2 = sig, sig * rng.uniform(0.2, 3.0)
    th = rng.uniform(-np.pi, np.pi)
    R = np.array([[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]])
    cov = R @ np.diag([s1 * s1, s2 * s2]) @ R.T
    ego_yaw, other_yaw = rng.uniform(-np.pi, np.pi), rng.uniform(-np.pi, np.pi)
    reach = (4.508 + 1.61 + ol + ow) / 2 + 2.0 * max(s1, s2)
    dx, dy = rng.uniform(-reach, reach, 2)
    return dx, dy, ego_yaw, other_yaw, ol, ow, cov


def _exact_p(dx, dy, ego_yaw, other_yaw, ol, ow, cov):
    """The shapes P by shapes.polygon_mass in the ego's frame (tested against Monte Carlo in test_shapes)."""
    c, s = math.cos(ego_yaw), math.sin(ego_yaw)
    R = np.array([[c, s], [-s, c]])
    return polygon_mass(octagon(4.508, 1.61, ol, ow, other_yaw - ego_yaw), R @ np.array([dx, dy]), R @ cov @ R.T)


def test_bounds_bracket_the_exact_probability_on_seeded_random_cases():
    rng = np.random.default_rng(11)
    ratios = []
    for _ in range(3000):
        case = _random_case(rng)
        lo, up = search.p_bounds(case[0], case[1], case[2], case[3], 4.508, 1.61, case[4], case[5], case[6])
        p = _exact_p(*case)
        assert lo - 1e-7 <= p <= up + 1e-7, (case, lo, p, up)  # 1e-7: the integral's own stated error
        assert 0.0 <= lo <= up <= 1.0
        if p > 1e-3:
            ratios.append(up / p)
    # tight enough to prune: the upper bound is within 1.5x of P for most cases
    assert np.median(ratios) < 1.5


def test_bounds_bracket_a_seeded_monte_carlo():
    rng = np.random.default_rng(5)
    for i in range(6):
        dx, dy, ego_yaw, other_yaw, ol, ow, cov = _random_case(rng)
        if i == 0:  # a truck 0.4 m over the ego's side, sigma 0.1 m: nearly certain overlap
            dx, dy, ego_yaw, other_yaw, ol, ow, cov = 0.0, 1.61 / 2 + 2.5 / 2 - 0.4, 0.0, 0.0, 12.0, 2.5, 0.01 * np.eye(2)
        centres = rng.multivariate_normal([dx, dy], cov, size=1_000_000)
        c, s = math.cos(ego_yaw), math.sin(ego_yaw)
        co, so = math.cos(other_yaw), math.sin(other_yaw)
        # separating-axis test of the two boxes for every sampled centre of the other
        hit = np.ones(len(centres), bool)
        for ax, ay in ((c, s), (-s, c), (co, so), (-so, co)):
            proj = np.abs(centres[:, 0] * ax + centres[:, 1] * ay)
            ego_half = 4.508 / 2 * abs(c * ax + s * ay) + 1.61 / 2 * abs(-s * ax + c * ay)
            oth_half = ol / 2 * abs(co * ax + so * ay) + ow / 2 * abs(-so * ax + co * ay)
            hit &= proj <= ego_half + oth_half
        mc = hit.mean()
        se = math.sqrt(max(mc * (1 - mc), 1e-12) / len(centres))
        lo, up = search.p_bounds(dx, dy, ego_yaw, other_yaw, 4.508, 1.61, ol, ow, cov)
        assert lo - 4 * se - 1e-6 <= mc <= up + 4 * se + 1e-6, (i, lo, mc, up)
        if i == 0:
            assert lo > 0.99


def _capture(monkeypatch, planner: EthicalPlanner, scene):
    """The planner's call of assess_risk on ``scene``: (args, kwargs), steps dropped."""
    got = {}
    real = ethical.assess_risk

    def spy(*a, **k):
        got["call"] = (a, {key: v for key, v in k.items() if key != "steps"})
        return real(*a, **k)

    monkeypatch.setattr(ethical, "assess_risk", spy)
    planner.act(scene)
    monkeypatch.setattr(ethical, "assess_risk", real)
    return got["call"]


def _traffic(seed: int, n: int):
    """n road users of every class within 40 m behind to 70 m ahead of the ego of
    conftest.straight_road_scene, in its lanes and across them, with 3 s of straight history."""
    rng = np.random.default_rng(seed)
    pick = rng.integers(0, len(BODIES), n)
    cls = np.array([BODIES[i][0] for i in pick], np.int8)
    length, width = np.array([BODIES[i][1] for i in pick]), np.array([BODIES[i][2] for i in pick])
    mass = np.array([BODIES[i][3] for i in pick])
    x = 10.0 + rng.uniform(-40, 70, n)
    y = rng.choice([0.0, 3.5, -0.6, 1.2], n) + rng.normal(0, 0.3, n)
    walking = cls == C.PEDESTRIAN
    yaw = np.where(walking, np.pi / 2, np.where(rng.random(n) < 0.2, np.pi, 0.0))  # some oncoming
    speed = np.where(walking, 1.3, rng.uniform(0, 14, n))
    others = AgentStates(tuple(f"a{i}" for i in range(n)), x, y, yaw, speed, np.zeros(n), length, width, mass, cls)
    t = (np.arange(-29, 1) * 0.1)[None, :, None]
    hist = np.stack([x, y], -1)[:, None, :] + t * (speed[:, None] * np.stack([np.cos(yaw), np.sin(yaw)], -1))[:, None]
    return straight_road_scene(others, hist)


TERMS = ("ego_risk", "other_risk", "ego_harm_max", "other_harm_max")


def _check_against_exhaustive(args, kwargs, min_risk: float = 0.0) -> None:
    """The bounded search against the exhaustive evaluation (every gated step integrated): in the
    exact mode (tolerance 0) the same terms to rounding (1e-12) and the same at_risk; in the
    tolerance mode each term at most ``tolerance`` below the exhaustive one and never above it,
    and at_risk the same where the cost asks for it (need_at_risk)."""
    cfg = kwargs.get("prob_cfg", ProbabilityConfig())
    full = assess_risk(*args, **kwargs, steps=True)
    exact = assess_risk(*args, **{**kwargs, "prob_cfg": replace(cfg, tolerance=0.0)}, steps=False)
    fast = assess_risk(*args, **kwargs, steps=False, need_at_risk=True)
    assert full.complete and not exact.complete and not fast.complete
    assert full.ego_risk.max() > min_risk and full.ego_harm_max.any()  # the scene puts road users at risk
    for name in TERMS:
        ref = getattr(full, name)
        assert np.abs(getattr(exact, name) - ref).max() <= 1e-12, name
        below = ref - getattr(fast, name)
        assert below.min() >= -1e-12 and below.max() <= cfg.tolerance, (name, below.min(), below.max())
    assert np.array_equal(full.at_risk, exact.at_risk) and np.array_equal(full.at_risk, fast.at_risk)
    for name in ("boundary_harm", "vulnerable"):
        assert np.array_equal(getattr(full, name), getattr(fast, name)), name
    with pytest.raises(ValueError, match="steps=True"):
        _ = fast.p


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_planner_risk_terms_hold_the_exhaustive_ones_to_the_tolerance(monkeypatch, seed):
    """The default planner (map predictor, three calibrated modes, shapes probability): its risk
    terms by the bounded search against the exhaustive evaluation, exact mode and tolerance mode."""
    planner = EthicalPlanner(PlannerConfig())
    a, k = _capture(monkeypatch, planner, _traffic(seed, 24))
    assert a[1].weight is not None and a[1].weight.shape[1] == 3
    assert k["prob_cfg"].tolerance == 1e-4
    _check_against_exhaustive(a, {key: v for key, v in k.items() if key != "need_at_risk"})


@pytest.mark.parametrize("sig", [0.05, 0.3, 3.0])
def test_single_mode_terms_hold_the_exhaustive_ones(sig):
    """A single-mode prediction of crossing and parallel road users of every class at one
    spread: the bounded search holds the exhaustive terms (exact mode, tolerance mode); and the
    "origin" probability ignores steps."""
    rng = np.random.default_rng(int(sig * 100))
    K, T, N = 120, 40, 14
    t = (np.arange(T) + 1) * 0.1
    v = rng.uniform(2, 15, K)[:, None]
    d = rng.uniform(-3, 3, K)[:, None] * np.minimum(t / 3.0, 1.0)
    x, y = 10.0 + v * t, d + 0.0 * t
    yaw = np.arctan2(np.gradient(y, axis=1), np.gradient(x, axis=1))
    cand = Candidates(dt=0.1, x=x, y=y, yaw=yaw, speed=v + 0 * t, accel=0 * t, curvature=0 * t, s=x, d=y,
                      horizon=np.full(K, 4.0), valid=np.ones((K, T), bool))
    pick = rng.integers(0, len(BODIES), N)
    cls = np.array([BODIES[i][0] for i in pick], np.int8)
    ax, ay = rng.uniform(15, 60, N), rng.uniform(-6, 6, N)
    ayaw = rng.choice([0.0, np.pi / 2, -np.pi / 2, np.pi, 0.3], N)
    aspeed = rng.uniform(0, 10, N)
    mean = np.stack([ax[:, None] + aspeed[:, None] * np.cos(ayaw)[:, None] * t,
                     ay[:, None] + aspeed[:, None] * np.sin(ayaw)[:, None] * t], -1)
    grow = (sig * (1 + t))[None, :, None, None] ** 2
    cov = grow * np.array([[1.0, 0.3], [0.3, 0.6]])
    agents = AgentStates(tuple(f"a{i}" for i in range(N)), ax, ay, ayaw, aspeed, np.zeros(N),
                         np.array([BODIES[i][1] for i in pick]), np.array([BODIES[i][2] for i in pick]),
                         np.array([BODIES[i][3] for i in pick]), cls)
    pred = Prediction(agents.ids, 0.1, mean, np.broadcast_to(cov, (N, T, 2, 2)).copy(), np.repeat(ayaw[:, None], T, 1))
    args = (cand, pred, agents, 1475.0, int(C.CAR), 4.508, 1.61)
    _check_against_exhaustive(args, {}, min_risk=0.01)
    origin = ProbabilityConfig(method="origin")
    o_full, o_fast = assess_risk(*args, prob_cfg=origin), assess_risk(*args, prob_cfg=origin, steps=False)
    assert o_fast.complete and np.array_equal(o_full.ego_risk, o_fast.ego_risk)
