"""The pace to a CommonRoad goal (sumo_ethics.goal.Pace) by hand, and the planner aiming at it.

Path: the x axis from 0 to 300 m. Goal region: a 10 m x 4 m box from x = 95 to 105 m (middle
100 m), window time steps [100, 110] at dt = 0.1 s (it opens at 10 s). The pace is
(middle - s) / (time until the window opens), never below the goal's lowest speed nor 0; no limit
(None) once the window is open or the region is passed.
"""

from __future__ import annotations

import numpy as np
import pytest
from shapely.geometry import Polygon

from conftest import straight_road_scene
from sumo_ethics.contract import Scene
from sumo_ethics.goal import Goal, GoalState, Pace, along
from sumo_ethics.plan.ethical import EthicalPlanner, PlannerConfig
from sumo_ethics.predict.constant_velocity import ConstantVelocityPredictor
from sumo_ethics.types import AgentStates

PATH = np.array([[0.0, 0.0], [300.0, 0.0]])
BOX = Polygon([(95, -2), (105, -2), (105, 2), (95, 2)])
DT = 0.1


def goal(velocity=None, polygons=(BOX,), window=(100, 110)) -> Goal:
    return Goal((GoalState(time_step=window, velocity=velocity, polygons=polygons),))


def test_along_the_path() -> None:
    assert along(BOX, PATH) == (95.0, 105.0)
    # a path that never meets the region: both ends at its point nearest to it
    assert along(Polygon([(95, 5), (105, 5), (105, 9), (95, 9)]), PATH) == (95.0, 95.0)
    bent = np.array([[0.0, 0.0], [50.0, 0.0], [50.0, 200.0]])  # 50 m along x, then up
    assert along(Polygon([(48, 100), (52, 100), (52, 120), (48, 120)]), bent) == (150.0, 170.0)


def test_pace_by_hand() -> None:
    pace = Pace.of(goal(), PATH, DT)
    assert pace is not None
    assert pace.speed(0, 0.0) == pytest.approx(10.0)  # 100 m to go, the window opens in 10 s
    assert pace.speed(50, 80.0) == pytest.approx(4.0)  # 20 m in 5 s
    assert pace.speed(50, 99.0) == pytest.approx(0.2)  # inside the region: 1 m to the middle in 5 s
    assert pace.speed(50, 101.0) == 0.0  # past the middle before the window opens: wait
    assert pace.speed(100, 0.0) is None  # the window is open: late, the limit
    assert pace.speed(120, 0.0) is None  # the window has closed
    assert pace.speed(50, 106.0) is None  # past the region
    # the goal's lowest speed is a floor; its top speed plays no part here (the goal lanes' limit)
    low = Pace.of(goal(velocity=(12.0, 20.0)), PATH, DT)
    assert low is not None and low.speed(0, 0.0) == pytest.approx(12.0) and low.speed(50, 101.0) == 12.0
    assert low.speed(0, -100.0) == pytest.approx(20.0)  # 200 m in 10 s: above the floor
    negative = Pace.of(goal(velocity=(-3.0, 3.0)), PATH, DT)  # a goal speed interval reaching below 0
    assert negative is not None and negative.speed(50, 101.0) == 0.0
    # a fractional time step (a run step shorter than the scenario's)
    assert pace.speed(99.5, 99.0) == pytest.approx(1.0 / 0.05)


def test_pace_of_several_goal_states() -> None:
    near = GoalState(time_step=(100, 110), polygons=(BOX,))
    far = GoalState(time_step=(100, 110), polygons=(Polygon([(195, -2), (205, -2), (205, 2), (195, 2)]),))
    pace = Pace.of(Goal((near, far)), PATH, DT)
    assert pace is not None
    assert pace.speed(0, 0.0) == pytest.approx(20.0)  # either will do: the one asking the least slowing
    assert pace.speed(50, 106.0) == pytest.approx(94.0 / 5.0)  # the near one passed: the far one
    early = GoalState(time_step=(0, 10), polygons=(BOX,))
    assert Pace.of(Goal((early, far)), PATH, DT).speed(0, 0.0) is None  # one window is open already
    # a goal state without a position or without a time window is met without timing: no pace
    assert Pace.of(Goal((near, GoalState(time_step=(100, 110)))), PATH, DT) is None
    assert Pace.of(Goal((GoalState(polygons=(BOX,)),)), PATH, DT) is None


def _scene(desired: float | None) -> Scene:
    """The ego at x = 10 m, 10 m/s, on an empty straight road limited to 14 m/s."""
    none = AgentStates(ids=(), x=np.zeros(0), y=np.zeros(0), yaw=np.zeros(0), speed=np.zeros(0), accel=np.zeros(0),
                       length=np.zeros(0), width=np.zeros(0), mass=np.zeros(0), cls=np.zeros(0, np.int8))
    return straight_road_scene(none, np.zeros((0, 5, 2)), desired, dt=DT)


def test_the_planner_aims_at_the_desired_speed() -> None:
    def decide(desired):
        return EthicalPlanner(PlannerConfig(predictor="cv"), predictor=ConstantVelocityPredictor()).act(_scene(desired))

    free, slow, above = decide(None), decide(4.0), decide(20.0)
    assert "desired_speed" not in free.info  # no hook asked: nothing new in steps.parquet
    assert slow.info["desired_speed"] == 4.0 and above.info["desired_speed"] == 14.0  # capped at the limit
    assert slow.command.speed < 10.0 < free.command.speed  # slows down for 4 m/s, speeds up for 14 m/s
    assert above.command == free.command  # above the limit: as without
