"""Run notes: the route's bends tighter than the ego's limit, and a standstill with nothing around."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sumo_ethics.geometry import Polyline
from sumo_ethics.notes import STANDSTILL_NOTE, RunNotes, lines
from sumo_ethics.contract import RoutePath, TightBend
from sumo_ethics.sim.route import tight_bends

NAN = float("nan")


def route_with_bends() -> RoutePath:
    """20 m straight, a right quarter circle of radius 2 m (curvature -0.5), 20 m straight, a left
    quarter circle of radius 4 m (+0.25), 20 m straight; vertices about 0.1-1 m apart."""
    a = np.linspace(0.0, math.pi / 2, 21)[1:]
    pts = [np.stack([np.linspace(-20.0, 0.0, 21), np.zeros(21)], -1)]
    pts.append(np.stack([2 * np.sin(a), -2 + 2 * np.cos(a)], -1))  # ends at (2, -2) heading -y
    pts.append(np.stack([np.full(20, 2.0), -2.0 - np.linspace(1.0, 20.0, 20)], -1))  # to (2, -22)
    pts.append(np.stack([6 - 4 * np.cos(a), -22 - 4 * np.sin(a)], -1))  # left turn, ends at (6, -26) heading +x
    pts.append(np.stack([6 + np.linspace(1.0, 20.0, 20), np.full(20, -26.0)], -1))
    path = Polyline.from_points(np.vstack(pts))
    m = len(path.s)
    lanes = tuple("a_0" if s < 20.0 else ":J_0_0" if s < 20.0 + math.pi else "b_0" for s in path.s)
    return RoutePath(edges=("a", "b"), path=path, lane_of_vertex=lanes, speed_limit=np.full(m, 13.89),
                     left=np.full(m, 1.6), right=np.full(m, -1.6), links=())


def test_tight_bends_finds_each_bend_beyond_the_limit():
    r = route_with_bends()
    bends = tight_bends(r, 0.2)
    assert len(bends) == 2
    right, left = bends
    assert right.curvature == pytest.approx(-0.5, rel=0.02) and right.lane == ":J_0_0"
    assert 20.0 <= right.s_start < right.s <= right.s_end <= 20.0 + math.pi + 0.2
    assert left.curvature == pytest.approx(0.25, rel=0.02)
    assert [b.s for b in tight_bends(r, 0.3)] == [right.s]  # the left bend (0.25) is within 0.3
    assert tight_bends(r, 0.6) == []


def notes_after(speeds, s_values, neighbours=0, stop_s=NAN, dt=1.0, completed=False):
    r = route_with_bends()
    n = RunNotes(tight_bends(r, 0.2), 0.2, 0.05)
    for i, (v, s) in enumerate(zip(speeds, s_values)):
        n.step(i * dt, s, v, neighbours, stop_s, "a_0")
    return n.summary(completed)


def test_tight_bends_summary_names_the_tightest_and_what_the_ego_did():
    s = list(np.linspace(0.0, 30.0, 31))  # through the right bend, not the left one (s about 43-50)
    v = [3.0] * 31
    out = notes_after(v, s)
    b = out["tight_bends"]
    assert (b["count"], b["passed"], b["limit"]) == (2, 1, 0.2)
    t = b["tightest"]
    assert t["turn"] == "right" and t["lane"] == ":J_0_0" and t["radius"] == pytest.approx(2.0, rel=0.03)
    assert b["max_speed_in_bends"] == 3.0
    assert "standstill" not in out
    (line,) = lines(out)
    assert "tightest 0.50 1/m (radius 2.0 m, right) on :J_0_0" in line and "through 1 of them" in line
    # stopped inside the bend (it runs from s = 20 to 20 + pi): not passed
    inside = notes_after([3.0] * 23, list(np.linspace(0.0, 21.5, 23)))["tight_bends"]
    assert inside["passed"] == 0
    assert lines({"tight_bends": inside})[0].endswith("; the ego passed none of them")


def test_standstill_alone_is_noted_only_when_long_and_alone():
    moving, still = [5.0] * 5, [0.0] * 20
    s = list(range(5)) + [5] * 20
    out = notes_after(moving + still, s)  # 20 steps of 1 s standing: since t = 5, 19 s until t = 24
    st = out["standstill"]
    assert st["since"] == 5.0 and st["duration"] == 19.0 and st["s"] == 5
    assert any(x.startswith("warning: the ego stood still for the last 19 s") for x in lines(out))
    # short, with someone around, at a red light, or at the goal: nothing to say
    short = int(STANDSTILL_NOTE) - 1
    assert "standstill" not in notes_after(moving + [0.0] * short, list(range(5)) + [5] * short)
    assert "standstill" not in notes_after(moving + still, s, neighbours=1)
    assert "standstill" not in notes_after(moving + still, s, stop_s=12.0)
    assert "standstill" not in notes_after(moving + still, s, completed=True)
    # moving again ends it
    assert "standstill" not in notes_after(moving + still + [1.0], s + [6])


def test_no_bends_no_notes():
    r = route_with_bends()
    n = RunNotes(tight_bends(r, 1.0), 1.0, 0.05)
    n.step(0.0, 0.0, 10.0, 0, NAN, "a_0")
    assert n.summary(False) == {} and lines({}) == []
    assert isinstance(tight_bends(r, 0.2)[0], TightBend)
