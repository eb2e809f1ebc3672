"""The plain baseline: follow the route's lane centre with IDM car-following.

It brakes for vehicles ahead in its lane and for red/yellow signals, and ignores
pedestrians and everything beside its lane: a deliberately naive reference point for the
ethical planner, kept under the name ``baseline``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sumo_ethics.contract import Decision, Scene
from sumo_ethics.contract import EgoCommand
from sumo_ethics.types import RoadUserClass


@dataclass(frozen=True)
class IDMParams:
    """Intelligent Driver Model: standstill gap [m], time headway [s], accel exponent."""

    min_gap: float = 2.0
    headway: float = 1.5
    delta: float = 4.0
    lookahead: float = 100.0  # m
    corridor: float = 1.6  # m; |lateral offset| of a leader's centre from the path


def idm_accel(v: float, v0: float, gap: float, dv: float, a_max: float, b: float, p: IDMParams) -> float:
    """IDM acceleration [m/s^2] for speed v, desired speed v0, gap [m] and approach rate dv [m/s]."""
    s_star = p.min_gap + max(0.0, v * p.headway + v * dv / (2.0 * np.sqrt(a_max * b)))
    free = 1.0 - (v / max(v0, 0.1)) ** p.delta
    return a_max * (free - (s_star / max(gap, 0.01)) ** 2)


class RouteFollower:
    """Baseline controller: lane centre, speed limit, IDM behind the leader, stops at red."""

    name = "baseline"
    needs_history = False

    def __init__(self, params: IDMParams = IDMParams()) -> None:
        self.p = params

    def leader_gap(self, scene: Scene) -> tuple[float, float]:
        """Bumper gap [m] and speed [m/s] of the nearest vehicle ahead on the path (inf if none)."""
        o = scene.others
        gap, v_lead = np.inf, 0.0
        if len(o):
            e = scene.ego
            ahead_xy = (o.x - e.x[0]) * np.cos(e.yaw[0]) + (o.y - e.y[0]) * np.sin(e.yaw[0])
            near = (scene.s - 10.0, scene.s + self.p.lookahead + 10.0)
            # cheap pre-filters; only the few vehicles that may be in the corridor are projected
            cand = np.flatnonzero((o.cls != RoadUserClass.PEDESTRIAN) & (ahead_xy > -10.0))
            cand = cand[scene.route.path.may_be_within(o.x[cand], o.y[cand], self.p.corridor, near)]
            if len(cand):
                s, d = scene.route.path.project(np.stack([o.x[cand], o.y[cand]], axis=-1), near=near)
                ahead = (np.abs(d) < self.p.corridor) & (s > scene.s) & (s - scene.s < self.p.lookahead)
                if ahead.any():
                    gaps = s - scene.s - (o.length[cand] + scene.ego.length[0]) / 2.0
                    k = int(np.argmin(np.where(ahead, gaps, np.inf)))
                    i = cand[k]
                    gap, v_lead = float(gaps[k]), float(o.speed[i] * np.cos(o.yaw[i] - scene.ego.yaw[0]))
        if scene.stop_s is not None:
            stop_gap = scene.stop_s - scene.s - scene.ego.length[0] / 2.0
            if stop_gap < gap:
                gap, v_lead = stop_gap, 0.0
        return gap, v_lead

    def allowed_speed(self, scene: Scene) -> float:
        """Highest speed [m/s] from which every lower speed limit ahead is reached braking at the
        comfortable rate: min over vertices ahead of sqrt(limit^2 + 2 b distance)."""
        r = scene.route
        i = r.vertex_at(scene.s)
        j = r.vertex_at(scene.s + self.p.lookahead) + 1
        dist = np.maximum(r.path.s[i:j + 1] - scene.s - scene.ego.length[0] / 2.0, 0.0)
        lim = r.speed_limit[i:j + 1]
        return float(np.min(np.sqrt(lim**2 + 2.0 * scene.vehicle.comfort_decel * dist)))

    def act(self, scene: Scene) -> Decision:
        veh = scene.vehicle
        v = float(scene.ego.speed[0])
        v0 = min(self.allowed_speed(scene), veh.max_speed)
        gap, v_lead = self.leader_gap(scene)
        acc = idm_accel(v, v0, gap, v - v_lead, veh.max_accel, veh.comfort_decel, self.p)
        acc = min(max(float(acc), -veh.max_decel), veh.max_accel)  # np.clip costs ~5 us on a scalar
        v_next = max(0.0, v + acc * scene.dt)
        acc = (v_next - v) / scene.dt
        s_next = scene.s + 0.5 * (v + v_next) * scene.dt
        x, y, yaw = scene.route.path.to_xy(np.array(s_next), np.array(0.0))
        return Decision(EgoCommand(float(x), float(y), float(yaw), v_next),
                        info={"accel_cmd": acc, "leader_gap": gap if np.isfinite(gap) else -1.0})
