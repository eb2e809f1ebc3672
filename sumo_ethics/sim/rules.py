"""Who breaks a traffic rule right now, as far as SUMO knows (the responsibility principle).

The rule, applied to every neighbouring vehicle (cars, trucks, buses, motorcycles, bicycles)
each step; a vehicle that meets any clause is a *rule breaker*:

1. **Red light**: it entered a signalised junction on a link showing red ('r' or 'R') at the
   step it moved from its approach lane onto the junction; it stays a rule breaker until it
   has left the junction. (Yellow is not a violation; right of way at unsignalised junctions
   is not assessed.)
2. **Wrong way**: on a normal lane, its heading differs from the lane's direction at its
   position by more than ``WRONG_WAY`` (120 degrees).
3. **Outside its lane**: on a normal lane, its centre is more than
   ``(lane width - its width) / 2 + OUTSIDE_TOLERANCE`` (0.5 m) from the lane's centre line,
   i.e. its body reaches at least 0.5 m over a lane edge (a drift into the oncoming lane, a
   car straddling two lanes).

Pedestrians are never rule breakers under this rule: persons in SUMO scenarios cross where
their route takes them, and a person stepping onto the road is exactly whom the ethics
must not discount. The planner's responsibility term (:mod:`sumo_ethics.ethics.cost`)
charges the risk put on road users who are *not* rule breakers.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from sumo_ethics.contract import StepHook
from sumo_ethics.geometry import Polyline, wrap_angle
from sumo_ethics.sim.backend import sumo
from sumo_ethics.types import AgentStates, RoadUserClass

WRONG_WAY = math.radians(120.0)
OUTSIDE_TOLERANCE = 0.5  # m
RED = frozenset("rR")


def heading_error(yaw: float, lane_yaw: float) -> float:
    """|yaw - lane_yaw| wrapped to [0, pi], in radians."""
    return abs(float(wrap_angle(yaw - lane_yaw)))


def outside_lane(lateral: float, lane_width: float, width: float, tol: float = OUTSIDE_TOLERANCE) -> bool:
    """Whether a body ``width`` wide at ``lateral`` m from the lane centre reaches more than
    ``tol`` over a lane edge of a lane ``lane_width`` wide [m]."""
    return abs(lateral) > (lane_width - width) / 2.0 + tol


class RuleMonitor(StepHook):
    """Tracks the neighbours' lanes from step to step and names the rule breakers (module doc).
    As a run hook (the loop adds one for a controller that ``needs_rules``) it reads them every
    step (:meth:`on_read`) into :attr:`current`, the scene's ``rule_breakers``."""

    def __init__(self) -> None:
        self.current: frozenset[str] = frozenset()  # the rule breakers at the last read
        self._lane: dict[str, str] = {}  # vehicle -> lane at the last step
        self._red: set[str] = set()  # vehicles that entered their junction at red
        self._shapes: dict[str, tuple[Polyline, float]] = {}  # lane -> (centre line, width)
        self._links: dict[str, dict[str, str]] = {}  # lane -> {internal via lane: link state}

    def _shape(self, lane: str) -> tuple[Polyline, float]:
        got = self._shapes.get(lane)
        if got is None:
            line = Polyline.from_points(np.asarray(sumo.lane.getShape(lane), dtype=float))
            got = self._shapes[lane] = (line, sumo.lane.getWidth(lane))
        return got

    def _entry_state(self, approach: str, via: str) -> str:
        """Signal state now of the link from lane ``approach`` into junction lane ``via`` ('' if none)."""
        for link in sumo.lane.getLinks(approach):
            if link[4] == via:
                return link[5]
        return ""

    def on_read(self, snapshot: Any, world: Any) -> None:
        """The rule breakers among the snapshot's neighbours, into :attr:`current`."""
        self.current = self.breakers(snapshot.others)

    def breakers(self, others: AgentStates) -> frozenset[str]:
        """Ids of the rule-breaking vehicles among ``others`` (their states now)."""
        out: set[str] = set()
        seen: dict[str, str] = {}
        v = sumo.vehicle
        for i, vid in enumerate(others.ids):
            if int(others.cls[i]) == RoadUserClass.PEDESTRIAN:
                continue
            try:
                lane = v.getLaneID(vid)
            except sumo.TraCIException:
                continue
            seen[vid] = lane
            if not lane:  # off every lane
                continue
            before = self._lane.get(vid, "")
            if lane.startswith(":"):
                if before and not before.startswith(":") and self._entry_state(before, lane) in RED:
                    self._red.add(vid)
                if vid in self._red:
                    out.add(vid)
                continue
            self._red.discard(vid)
            line, width = self._shape(lane)
            if heading_error(float(others.yaw[i]), float(line.heading_at(v.getLanePosition(vid)))) > WRONG_WAY:
                out.add(vid)
            elif outside_lane(v.getLateralLanePosition(vid), width, float(others.width[i])):
                out.add(vid)
        self._lane = seen
        self._red &= set(seen)
        return frozenset(out)
