"""TTC for road users that turn (issue 38: constant-heading TTC counts cars passing on a bend).

Checked by geometry a person can follow (cars on concentric circles 3.2 m apart never touch),
against the exact constant-velocity TTC where nobody turns, and against an independent
brute-force simulation with shapely polygons on a 1 ms grid.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from shapely.geometry import Polygon

from sumo_ethics.config import ConflictConfig
from sumo_ethics.geometry import OrientedBoxes as Boxes
from sumo_ethics.safety.conflicts import ConflictBook
from sumo_ethics.safety.measures import box_ttc, ttc_with_turns, turning_ttc, yaw_rates
from sumo_ethics.safety.pairs import PairConflictBook
from sumo_ethics.types import RoadUserClass as C

from test_conflicts import Sink, agents

R_IN, R_OUT, V = 30.0, 33.2, 10.0  # a left bend: inner lane anticlockwise, outer lane clockwise


def bend_pair(theta: float) -> tuple[Boxes, Boxes]:
    """Car a on the inner circle at angle 0 heading anticlockwise; car b on the outer circle at
    angle theta heading clockwise (towards a): oncoming traffic in a bend."""
    a = Boxes(R_IN, 0.0, math.pi / 2, 4.5, 1.8)
    b = Boxes(R_OUT * math.cos(theta), R_OUT * math.sin(theta), theta - math.pi / 2, 4.5, 1.8)
    return a, b


def test_cars_passing_on_a_bend_are_no_conflict():
    a, b = bend_pair(0.7)  # b 21.5 m ahead along the outer arc
    # with constant headings their tangents cross: a false TTC of 1.12 s (below the 1.5 s threshold)
    vb = (V * math.cos(0.7 - math.pi / 2), V * math.sin(0.7 - math.pi / 2))
    assert box_ttc(a, (0.0, V), b, vb) == pytest.approx(1.1203, abs=1e-3)
    # on their circles (3.2 m apart, 1.8 m wide, a sagitta of 2.25^2 / 60 = 0.08 m) they never touch
    assert turning_ttc(a, V, V / R_IN, b, V, -V / R_OUT, 3.0) == math.inf
    assert ttc_with_turns(a, V, V / R_IN, b, V, -V / R_OUT, 1.5) == math.inf


def test_without_turns_it_is_the_exact_constant_velocity_ttc():
    a, b = Boxes(0.0, 0.0, 0.0, 4.5, 1.8), Boxes(30.0, 0.0, math.pi, 4.5, 1.8)
    # head-on, 10 m/s each: gap 25.5 m at 20 m/s -> 1.275 s
    assert float(ttc_with_turns(a, 10.0, 0.0, b, 10.0, 0.0, 1.5)) == pytest.approx(1.275, abs=1e-12)
    assert turning_ttc(a, 10.0, 0.0, b, 10.0, 0.0, 3.0) == pytest.approx(1.275, abs=1e-3)


def _poly(x, y, yaw, length, width) -> Polygon:
    c, s = math.cos(yaw), math.sin(yaw)
    pts = [(x + dl * length / 2 * c - dw * width / 2 * s, y + dl * length / 2 * s + dw * width / 2 * c)
           for dl, dw in ((1, 1), (-1, 1), (-1, -1), (1, -1))]
    return Polygon(pts)


def _pose(x, y, h, v, w, t):
    """Pose after t [s] on the circle of speed v [m/s] and yaw rate w [rad/s] (straight for w = 0)."""
    if abs(w) < 1e-12:
        return x + v * t * math.cos(h), y + v * t * math.sin(h), h
    return x + v / w * (math.sin(h + w * t) - math.sin(h)), y + v / w * (math.cos(h) - math.cos(h + w * t)), h + w * t


def brute_force_ttc(x1, y1, h1, v1, w1, x2, y2, h2, v2, w2, horizon=3.0, step=1e-3) -> float:
    """Both cars placed on their circles every 1 ms; the first time their shapely polygons share area."""
    for k in range(int(horizon / step) + 1):
        t = k * step
        p1 = _poly(*_pose(x1, y1, h1, v1, w1, t), 4.5, 1.8)
        p2 = _poly(*_pose(x2, y2, h2, v2, w2, t), 4.5, 1.8)
        if p1.intersection(p2).area > 1e-9:
            return t
    return math.inf


@pytest.mark.parametrize("case", [
    # a car turning left across the path of an oncoming straight car
    (0.0, 0.0, 0.0, 8.0, 0.25, 30.0, 6.0, math.pi, 8.0, 0.0),
    # a car turning right into a crossing car's lane
    (0.0, 0.0, math.pi / 2, 6.0, -0.3, 14.0, 10.0, math.pi, 7.0, 0.0),
    # both turning
    (0.0, 0.0, 0.0, 9.0, 0.25, 18.0, 14.0, -math.pi / 2, 3.0, -0.1),
])
def test_turning_ttc_equals_a_brute_force_shapely_simulation(case):
    x1, y1, h1, v1, w1, x2, y2, h2, v2, w2 = case
    want = brute_force_ttc(*case)
    assert math.isfinite(want)  # the cases do collide within 3 s
    got = turning_ttc(Boxes(x1, y1, h1, 4.5, 1.8), v1, w1, Boxes(x2, y2, h2, 4.5, 1.8), v2, w2, 3.0)
    assert got == pytest.approx(want, abs=2e-3)


def test_yaw_rates_by_hand():
    # 0.05 rad in 0.1 s: 0.5 rad/s; wrapped across +-pi; capped at 0.2 / m x speed; walkers 0; unknown 0
    r = yaw_rates(np.array([0.05, -3.1, 0.5, 1.0, 0.3]), np.array([0.0, 3.1, 0.0, 0.0, np.nan]), 0.1,
                  np.array([10.0, 10.0, 2.0, 10.0, 10.0]), np.array([False, False, False, True, False]))
    np.testing.assert_allclose(r, [0.5, (2 * math.pi - 6.2) / 0.1, 0.4, 0.0, 0.0])


@pytest.mark.parametrize("turning", [True, False])
def test_the_books_see_the_bend_from_the_second_instant_on(turning):
    """Both conflict books with ``[conflicts] turning = true``, fed the bend pair moving on their
    circles every 0.1 s for 1 s: at the first instant nobody's turn is known yet (the
    constant-velocity TTC, 1.12 s, opens an event); from the second on, no conflict: the event
    ends at t = 0. Fed the pair going straight along the same tangents, the constant-velocity
    conflict goes on. With the default (constant heading) the bend is a conflict throughout."""
    def on_circles(t):
        ta, tb = V / R_IN * t, 0.7 - V / R_OUT * t
        a = agents(["a"], R_IN * math.cos(ta), R_IN * math.sin(ta), ta + math.pi / 2, V, 4.5, 1.8, C.CAR)
        b = agents(["b"], R_OUT * math.cos(tb), R_OUT * math.sin(tb), tb - math.pi / 2, V, 4.5, 1.8, C.CAR)
        return a, b

    def straight(t):
        a0, b0 = on_circles(0.0)
        a = agents(["a"], a0.x, a0.y + V * t, a0.yaw, V, 4.5, 1.8, C.CAR)
        hb = float(b0.yaw[0])
        b = agents(["b"], b0.x + V * t * math.cos(hb), b0.y + V * t * math.sin(hb), hb, V, 4.5, 1.8, C.CAR)
        return a, b

    for motion in (on_circles, straight):
        ego_sink, pair_sink = Sink(), Sink()
        ego_book = ConflictBook(ego_sink, ConflictConfig(turning=turning), 0.1)
        pair_book = PairConflictBook(pair_sink, ConflictConfig(turning=turning), 0.1)
        for k in range(11):
            t = round(0.1 * k, 10)
            a, b = motion(t)
            ego_book.observe(SimpleNamespace(time=t, ego=a, others=b), k)
            both = agents(["a", "b"], np.r_[a.x, b.x], np.r_[a.y, b.y], np.r_[a.yaw, b.yaw], V, 4.5, 1.8, C.CAR)
            pair_book.observe(t, k, both, np.zeros(2), frozenset())
        for sink in (ego_sink, pair_sink):
            r, = sink.conflicts
            assert r["start"] == 0.0, motion.__name__
            if motion is on_circles and not turning:  # the tangents cross at t = 0 and 0.1 s (TTC 1.12, 1.03 s)
                assert r["end"] == pytest.approx(0.1) and r["min_ttc"] == pytest.approx(1.0286, abs=1e-3)
            elif motion is on_circles:  # one instant, at the constant-velocity TTC
                assert r["end"] == 0.0 and r["min_ttc"] == pytest.approx(1.1203, abs=1e-3)
            else:  # to the end: the TTC falls by a second each second, 1.1203 - 1.0 at t = 1 s
                assert r["end"] == pytest.approx(1.0) and r["min_ttc"] == pytest.approx(0.1203, abs=1e-3)


def test_the_turning_ttc_is_a_setting_and_a_sweep_key(tmp_path):
    from sumo_ethics.errors import ConfigError
    from sumo_ethics.settings import conflicts_config
    from sumo_ethics.sweep import make_sweep

    from conftest import SCENARIOS

    assert ConflictConfig().turning is False  # constant heading by default (docs/conflicts.md says why)
    assert conflicts_config({"turning": True}).turning is True
    with pytest.raises(ConfigError, match="conflicts.turning must be true or false"):
        conflicts_config({"turning": "yes"})
    sweep = make_sweep(SCENARIOS / "urban" / "urban.sumocfg", "0.5", "0", ["conflicts_turning=true,false"])
    cfgs = [spec.run_config(tmp_path / "r").conflicts for spec in sweep.specs()]
    assert sorted(c.turning for c in cfgs) == [False, True] and not any(c.everyone for c in cfgs)
