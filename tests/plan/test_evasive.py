"""The planner's evasive candidates (plan/ethical.py::evasive_candidates): braking and swerving at once."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import straight_road_scene
from sumo_ethics.errors import ConfigError
from sumo_ethics.plan.ethical import EthicalPlanner, PlannerConfig, brake_candidates, evasive_candidates
from sumo_ethics.plan.feasibility import check
from sumo_ethics.plan.sampling import FrenetState, sample
from sumo_ethics.settings import planner_config
from sumo_ethics.suite.evaluate import BUILTIN
from sumo_ethics.types import AgentStates


def _road():
    scene = straight_road_scene(AgentStates.empty(), np.zeros((0, 30, 2)))
    return scene, scene.route, scene.vehicle, FrenetState.at_speed(scene.route.path, 10.0, 0.0, 10.0)


def test_only_the_evasive_candidates_brake_hard_and_swerve_at_once():
    """At 10 m/s on the conftest road (drivable from 1.75 m right to 5.25 m left of the path, the
    ego 1.61 m wide): no feasible candidate of the grid decelerates by 5 m/s^2 or more in its first
    0.1 s (its quartics start at the current acceleration, 0), the straight braking ones keep d = 0,
    while feasible evasive candidates lose 0.7-0.8 m/s in the first step (7-8 m/s^2, the maximum
    deceleration being 8) and some of them end 2 m or more to the side."""
    _, route, veh, state = _road()
    grid = sample(route.path, state, PlannerConfig().sampling, 14.0, left=route.left, right=route.right, margin=0.805)
    ev = evasive_candidates(route.path, state, PlannerConfig().sampling, veh.max_decel, 14.0, route.left, route.right,
                            0.805)
    assert ev.x.shape == (3 * 5 * 9, 40)  # horizons 1, 2, 4 s x 5 end speeds x 9 end offsets, the grid's T
    assert sorted(set(ev.horizon)) == [1.0, 2.0, 4.0]

    def usable(c):
        f = check(c, route, veh)
        return f.feasible & f.on_road

    first_decel = (10.0 - grid.speed[:, 0]) / 0.1
    assert first_decel[usable(grid)].max() < 5.0
    straight = brake_candidates(route.path, state, 40, 0.1, np.array([3.0, 5.5, 8.0]))
    assert np.all(straight.d == 0.0)
    ok = usable(ev)
    decel = (10.0 - ev.speed[:, 0]) / 0.1
    assert ok.sum() >= 20
    assert decel[ok].min() >= 7.0 and decel[ok].max() <= veh.max_decel
    assert (ok & (np.abs(ev.d[:, -1]) >= 2.0)).sum() >= 5
    # the end offsets span the drivable interval less half the ego's width (clipped at max_offset 3.5)
    ends = np.unique(ev.d[:, -1].round(6))
    assert len(ends) == 9 and ends[0] == pytest.approx(-1.75 + 0.805) and ends[-1] == pytest.approx(3.5)
    # every usable evasive candidate stays within the lateral acceleration limit
    assert np.abs(ev.speed[ok] ** 2 * ev.curvature[ok]).max() <= veh.max_lat_accel + 1e-9


def test_the_planner_appends_them_after_the_grid_and_the_straight_brakes():
    scene, *_ = _road()
    on = EthicalPlanner(PlannerConfig(predictor="cv")).act(scene)
    off = EthicalPlanner(PlannerConfig(predictor="cv", evasive=False)).act(scene)
    assert on.info["n_candidates"] == 4 * 15 * 17 + 3 + 135 and off.info["n_candidates"] == 4 * 15 * 17 + 3
    # nobody around: both drive on alike (the grid's indices are the same in both)
    assert on.command == off.command


def test_the_setting_and_the_published_planners():
    assert planner_config(None).evasive is True
    assert planner_config({"evasive": False}).evasive is False
    with pytest.raises(ConfigError, match="evasive must be true or false"):
        planner_config({"evasive": "yes"})
    from sumo_ethics.sweep.grid import parse_set

    assert parse_set(["evasive=true,false"]) == {"evasive": [True, False]}  # a sweep can compare both
    # origin and paper as published: without them; ours (the defaults of run) with them
    assert BUILTIN["origin"]["evasive"] is False and BUILTIN["paper"]["evasive"] is False
    assert "evasive" not in BUILTIN["ours"]


def test_evasive_candidates_only_in_an_emergency():
    """emergency_only by hand: 5 candidates, the last two evasive. While a plain candidate of the
    pool stays out of every envelope the evasive ones are not in the pool; once every plain one
    enters an envelope they are (and the cost with its envelope terms decides)."""
    from sumo_ethics.plan.ethical import emergency_only

    evasive = np.array([False, False, False, True, True])
    pool = np.array([True, True, False, True, True])
    calm = np.array([False, True, False, False, False])  # plain candidate 0 stays out
    assert emergency_only(pool, evasive, calm).tolist() == [True, True, False, False, False]
    # the only plain candidate outside every envelope is not in the pool: that is no way out
    blocked = np.array([True, True, False, False, True])
    assert emergency_only(pool, evasive, blocked).tolist() == pool.tolist()
    assert emergency_only(pool, None, calm).tolist() == pool.tolist()  # evasive off: as it was
