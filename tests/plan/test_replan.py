"""Staggered replanning (``replan_every``, issue 55): between its turns the ego follows its committed
plan state by state, and plans at once when a road user it did not weigh is at risk or a predicted
road user enters the rest of its plan. Scenes are built by hand on conftest's straight road."""

from __future__ import annotations

import zlib
from dataclasses import replace

import numpy as np

from conftest import straight_road_scene
from sumo_ethics.contract import Scene
from sumo_ethics.plan.ethical import REPLAN, EthicalPlanner, PlannerConfig
from sumo_ethics.types import AgentStates, Observation, RoadUserClass

DT = 0.1


def _road_users(t: float, extra: AgentStates | None = None) -> tuple[AgentStates, np.ndarray]:
    """Two cars ahead in the other lane at 8 m/s (far from the ego's lane) at time t, and 3 s of history."""
    x0 = np.array([60.0, 90.0]) + 8.0 * t
    cars = AgentStates(("c0", "c1"), x0, np.full(2, 3.5), np.zeros(2), np.full(2, 8.0), np.zeros(2), np.full(2, 4.5),
                       np.full(2, 1.8), np.full(2, 1400.0), np.zeros(2, np.int8))
    if extra is not None:
        cars = AgentStates(cars.ids + extra.ids, np.r_[cars.x, extra.x], np.r_[cars.y, extra.y],
                           np.r_[cars.yaw, extra.yaw], np.r_[cars.speed, extra.speed], np.r_[cars.accel, extra.accel],
                           np.r_[cars.length, extra.length], np.r_[cars.width, extra.width],
                           np.r_[cars.mass, extra.mass], np.r_[cars.cls, extra.cls])
    back = (np.arange(-29, 1) * DT)[None, :, None]
    v = (cars.speed[:, None] * np.stack([np.cos(cars.yaw), np.sin(cars.yaw)], -1))[:, None]
    return cars, np.stack([cars.x, cars.y], -1)[:, None, :] + back * v


def _scene(t: float, ego: AgentStates, extra: AgentStates | None = None) -> Scene:
    others, hist = _road_users(t, extra)
    base = straight_road_scene(others, hist)
    obs = base.history
    assert obs is not None
    return replace(base, time=t, ego=ego, s=float(ego.x[0]), d=float(ego.y[0]),
                   history=Observation(time=t, dt=DT, history=obs.history, valid=obs.valid, current=others, ego=ego))


def _ego_at(cmd) -> AgentStates:
    return AgentStates(("ego",), np.array([cmd.x]), np.array([cmd.y]), np.array([cmd.yaw]), np.array([cmd.speed]),
                       np.zeros(1), np.full(1, 4.508), np.full(1, 1.61), np.full(1, 1475.0), np.zeros(1, np.int8))


def test_the_ego_follows_its_plan_between_its_turns():
    """replan_every 3: the ego plans on the steps where (step + crc32(id) % 3) % 3 == 0 and, in
    between, commands exactly the states of the candidate it chose last (its position, heading
    and speed one and two steps on)."""
    planner = EthicalPlanner(PlannerConfig(predictor="cv", replan_every=3))
    phase = zlib.crc32(b"ego") % 3
    ego = straight_road_scene(*_road_users(0.0)).ego
    plan = None
    reasons = []
    for i in range(9):
        t = i * DT
        d = planner.act(_scene(t, ego))
        reasons.append(int(d.info["replanned"]))
        if d.trace is not None:  # planned: remember the chosen candidate and its step
            c = d.trace.candidates
            plan, at = (c.x[d.trace.chosen], c.y[d.trace.chosen], c.speed[d.trace.chosen]), i
        else:  # followed: the plan's state (i - at) steps on
            assert plan is not None
            j = i - at
            assert (d.command.x, d.command.y, d.command.speed) == (plan[0][j], plan[1][j], plan[2][j])
        ego = _ego_at(d.command)
    turns = [i for i in range(9) if (i + phase) % 3 == 0]
    assert reasons[0] == REPLAN["no_plan"]
    for i in range(1, 9):
        assert reasons[i] == (REPLAN["turn"] if i in turns else REPLAN["followed"]), (i, reasons)


def test_a_road_user_stepping_in_makes_it_plan_at_once():
    """A pedestrian appears 12 m ahead at the lane's edge walking into the lane: the step after, not
    the ego's turn, it plans anew (a road user its plan did not weigh is at risk, or her predicted
    box enters the rest of its plan)."""
    planner = EthicalPlanner(PlannerConfig(predictor="cv", replan_every=3))
    phase = zlib.crc32(b"ego") % 3
    ego = straight_road_scene(*_road_users(0.0)).ego
    start = next(i for i in range(3) if (i + phase) % 3 == 0)  # the ego's first turn
    for i in range(start + 1):
        d = planner.act(_scene(i * DT, ego))
        ego = _ego_at(d.command)
    i = start + 1  # not its turn
    ped = AgentStates(("p",), np.array([float(ego.x[0]) + 12.0]), np.array([-1.5]), np.array([np.pi / 2]),
                      np.array([1.4]), np.zeros(1), np.array([0.3]), np.array([0.5]), np.array([75.0]),
                      np.array([RoadUserClass.PEDESTRIAN], np.int8))
    d = planner.act(_scene(i * DT, ego, extra=ped))
    assert int(d.info["replanned"]) in (REPLAN["envelope"], REPLAN["new_at_risk"]) and d.trace is not None
    # without her the same step follows the plan
    planner2 = EthicalPlanner(PlannerConfig(predictor="cv", replan_every=3))
    ego2 = straight_road_scene(*_road_users(0.0)).ego
    for k in range(start + 1):
        ego2 = _ego_at(planner2.act(_scene(k * DT, ego2)).command)
    assert int(planner2.act(_scene(i * DT, ego2)).info["replanned"]) == REPLAN["followed"]


def test_replan_every_one_writes_no_replanned_column():
    d = EthicalPlanner(PlannerConfig(predictor="cv")).act(_scene(0.0, straight_road_scene(*_road_users(0.0)).ego))
    assert "replanned" not in d.info


def test_replan_every_must_be_a_whole_number_of_steps():
    import pytest

    from sumo_ethics.errors import ConfigError
    from sumo_ethics.settings import planner_config

    for bad in (0, 1.5, True, 101):
        with pytest.raises(ConfigError, match="replan_every"):
            planner_config(None, replan_every=bad)
    assert planner_config({"replan_every": 3}).replan_every == 3
