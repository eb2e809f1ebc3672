"""CollisionBook without SUMO: snapshots made by hand, SUMO's reports given as tuples."""

from __future__ import annotations

import numpy as np
import pytest

from sumo_ethics.collision import CollisionBook
from sumo_ethics.sim.world import Snapshot
from sumo_ethics.types import AgentStates, RoadUserClass


class Sink:
    def __init__(self) -> None:
        self.collisions: list[dict] = []

    def add_collision(self, row: dict) -> int:
        self.collisions.append(row)
        return len(self.collisions) - 1

    def update_collision(self, i: int, **changes) -> None:
        self.collisions[i].update(changes)


def agent(id_: str, x: float, yaw: float, speed: float, length: float, cls: RoadUserClass) -> AgentStates:
    return AgentStates(ids=(id_,), x=np.array([x]), y=np.zeros(1), yaw=np.array([yaw]), speed=np.array([speed]),
                       accel=np.zeros(1), length=np.array([length]), width=np.array([2.0]),
                       mass=np.array([1500.0 if cls is RoadUserClass.CAR else 12000.0]),
                       cls=np.array([int(cls)], np.int8), type_id=(cls.label,))


def snap(t: float, ego_x: float, truck_x: float, report: bool) -> Snapshot:
    """Ego (4 m car) eastbound at 10 m/s, a 12 m truck westbound at 20 m/s on the same line."""
    rep = (("ego", "truck", "car", "truck", 10.0, 20.0, "collision", "lane_0"),) if report else ()
    return Snapshot(t, agent("ego", ego_x, 0.0, 10.0, 4.0, RoadUserClass.CAR),
                    agent("truck", truck_x, np.pi, 20.0, 12.0, RoadUserClass.TRUCK), rep)


def test_a_sumo_report_confirmed_later_is_booked_at_the_confirmation():
    sink = Sink()
    book = CollisionBook(sink, gap=1.0, lookup=lambda _: None)
    # t = 0.1: SUMO reports the pair while the boxes are 14 m apart (ego front 2, truck front 16)
    assert not book.detect(snap(0.0, 0.0, 25.0, False), snap(0.1, 1.0, 22.0, True), step=1)
    row = sink.collisions[0]
    assert row["detector"] == "sumo_unconfirmed" and row["harm_ego"] == 0.0 and row["step"] == 1
    # then closing at 30 m/s (3 m per 0.1 s step), SUMO reporting the pair every step
    t, ex, tx = 0.1, 1.0, 22.0
    hit_step = None
    for k in range(2, 8):
        nt, nex, ntx = t + 0.1, ex + 1.0, tx - 2.0
        if book.detect(snap(t, ex, tx, True), snap(nt, nex, ntx, True), step=k):
            hit_step = k
            break
        t, ex, tx = nt, nex, ntx
    # the boxes touch when the centres are 8 m apart (half lengths 2 + 6); from 21 m at step 1, 3 m per
    # step: 18, 15, 12, 9, 6 -> they meet during step 6 (9 -> 6 m), at t = 0.6 s
    assert hit_step == 6
    assert len(sink.collisions) == 1
    row = sink.collisions[0]
    assert row["event"] == 0 and row["step"] == 6 and row["time"] == pytest.approx(0.6)
    assert row["detector"] == "both" and row["sumo_type"] == "collision"
    assert row["x_a"] == pytest.approx(5.0) and row["x_b"] == pytest.approx(14.0)  # states just before
    assert row["harm_ego"] == row["harm_a"] > 0 and row["harm_third_party"] == row["harm_b"] > 0


def test_a_confirmed_contact_is_booked_once():
    sink = Sink()
    book = CollisionBook(sink, gap=1.0, lookup=lambda _: None)
    assert book.detect(snap(0.0, 0.0, 9.0, False), snap(0.1, 1.0, 7.0, True), step=1)
    assert not book.detect(snap(0.1, 1.0, 7.0, True), snap(0.2, 1.5, 6.0, True), step=2)
    assert len(sink.collisions) == 1 and sink.collisions[0]["step"] == 1 and sink.collisions[0]["detector"] == "both"
