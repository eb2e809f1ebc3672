"""Hazards injected through libsumo at run time, relative to the ego.

A :class:`HazardInjector` is a run hook (:class:`~sumo_ethics.contract.StepHook`, passed to
``runner.run(..., hooks=(injector,))``): every step, right before the controller acts and so before
the ego's command is applied, it gets the controller's :class:`~sumo_ethics.contract.Scene`
(``before_act``). Each hazard (a
:class:`~sumo_ethics.suite.spec.HazardSpec`) waits for its spawn/trigger condition, measured
from the ego's front bumper along the ego's reference path, then drives its actor
kinematically: a pose is commanded every step with ``moveToXY`` (exact pose; see the _KEEP_*
flags for which lanes SUMO may file it on), so the actor is exactly where the hazard says, whatever SUMO's
own models would do. Positions are Frenet (s, d) on the ego's path, or a straight line
across it (red-light runner). Every spawn, trigger and removal is logged in ``events``
with the actor's pose, so tests and analyses can check where each actor was.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from sumo_ethics.contract import StepHook
from sumo_ethics.sim.backend import sumo
from sumo_ethics.sim.frames import centre_to_front

_FALLBACK = {"ped": "DEFAULT_PEDTYPE", "bicycle": "DEFAULT_BIKETYPE"}
# moveToXY keepRoute bits: 2 = exact position, may leave the road; 4 = ignore lane permissions.
# Persons may be matched to any lane (they step onto the carriageway). Moving vehicles only to
# lanes their class may use: one matched onto a crossing or walking area crashes SUMO 1.28.
# Parked vehicles to the nearest lane, usually the sidewalk beside them: on the carriageway
# SUMO's car following (blind to lateral offsets) would queue the traffic behind them forever.
_KEEP_PERSON = 2 | 4
_KEEP_VEHICLE = 2
_KEEP_PARKED = 2 | 4


def _on_junction(route: Any, s0: float, s1: float) -> bool:
    """Whether the ego's path between arc lengths s0 and s1 [m] crosses a junction (internal lane)."""
    i0, i1 = route.vertex_at(max(s0, 0.0)), route.vertex_at(max(s1, 0.0))
    return any(lane.startswith(":") for lane in route.lane_of_vertex[i0:i1 + 1])


def _smooth(u: float) -> float:
    """0 -> 1 cosine ramp for u in [0, 1]."""
    u = min(max(u, 0.0), 1.0)
    return 0.5 - 0.5 * math.cos(math.pi * u)


@dataclass
class Actor:
    """One injected road user, kinematic, in the ego path's Frenet frame or on a line."""

    sumo_id: str
    is_person: bool
    length: float
    width: float
    s: float = 0.0
    d: float = 0.0
    v: float = 0.0  # along the path [m/s], negative: against the ego's direction
    # straight-line motion (frame "line"): position and unit direction in world coordinates
    line: tuple[float, float, float, float] | None = None
    travelled: float = 0.0
    line_length: float = 0.0  # frame "line": removed once it has travelled this far [m]
    added: bool = False
    parked: bool = False
    type_id: str = ""  # the SUMO vehicle type it is added with
    x: float = 0.0  # its centre pose as last commanded [m, m, rad]
    y: float = 0.0
    yaw: float = 0.0
    d_last: float | None = None  # d [m] and yaw [rad] at the last placement (None before the first)
    yaw_last: float | None = None
    ego_speeds: list[float] = field(default_factory=list)  # tailgater: the ego's speeds over its reaction time


@dataclass
class HazardState:
    spec: Any  # HazardSpec
    anchor_s: float | None = None
    phase: str = "wait"  # wait -> spawned -> triggered -> done (or off_path/missed)
    actor: Actor | None = None
    props: list[Actor] = field(default_factory=list)
    t_trigger: float | None = None
    d0: float = 0.0
    v0: float = 0.0
    d_prev: float = 0.0

    def anchor(self) -> float:
        """anchor_s [m]: placed by the injector's set-up, before any hazard advances."""
        if self.anchor_s is None:
            raise RuntimeError(f"hazard {self.spec.id}: its anchor is not placed on the ego's path yet")
        return self.anchor_s

    def since_trigger(self, t: float) -> float:
        """Time [s] from the trigger to t; 0 unless triggered."""
        if self.phase != "triggered":
            return 0.0
        if self.t_trigger is None:
            raise RuntimeError(f"hazard {self.spec.id}: triggered without a trigger time")
        return t - self.t_trigger


class HazardInjector(StepHook):
    """Spawns and drives the hazards of one scenario: a run hook (``before_act``), or call
    :meth:`on_step` every step."""

    def __init__(self, hazards: Sequence[Any]) -> None:
        self.states = [HazardState(h) for h in hazards]
        self.events: list[dict[str, Any]] = []
        self._route_id: str | None = None
        self._ready = False

    # ---- the per-step hook --------------------------------------------------------------
    def before_act(self, scene: Any) -> None:
        """The run hook's phase: :meth:`on_step` with the scene the controller is about to act on."""
        self.on_step(scene)

    def on_step(self, scene: Any) -> None:
        """Scene at time t -> spawn/trigger/move every hazard actor for time t + dt."""
        if not self._ready:
            self._setup(scene)
        ego_front = scene.s + float(scene.ego.length[0]) / 2.0
        v_ego = float(scene.ego.speed[0])
        for st in self.states:
            if st.phase in ("done", "off_path", "missed"):
                continue
            try:
                self._advance(st, scene, ego_front, v_ego)
            except sumo.TraCIException as exc:  # SUMO removed our actor (or refused it)
                self._log(scene.time, st, "lost", ego_front, v_ego, message=str(exc).splitlines()[0] if str(exc) else "")
                st.phase = "done"

    # ---- set-up -------------------------------------------------------------------------
    def _setup(self, scene: Any) -> None:
        self._ready = True
        path = scene.route.path
        ego_front = scene.s + float(scene.ego.length[0]) / 2.0
        self._route_id = "sumo_ethics_hazard_route"
        if self._route_id not in sumo.route.getIDList():  # hazard vehicles drive along the ego's
            sumo.route.add(self._route_id, list(scene.route.edges))  # route (junction lanes included)
        for st in self.states:
            xy = self._anchor_xy(st.spec.anchor)
            s, d = (float(v) for v in path.project(np.asarray(xy, dtype=float)))
            st.anchor_s = s
            if abs(d) > 30.0 or not 0.0 <= s <= path.length:
                st.phase = "off_path"
                self._log(scene.time, st, "off_path", ego_front, float(scene.ego.speed[0]),
                          message=f"anchor {abs(d):.1f} m from the ego's path")
            elif s < ego_front:
                st.phase = "missed"
                self._log(scene.time, st, "missed", ego_front, float(scene.ego.speed[0]),
                          message="anchor behind the ego at takeover")
            elif st.spec.type == "parked" and _on_junction(scene.route, st.anchor_s - 2.5, st.anchor_s + 2.5):
                st.phase = "missed"
                self._log(scene.time, st, "skipped", ego_front, float(scene.ego.speed[0]),
                          message="no car parks on a junction")
            elif st.spec.type == "parked":
                st.actor = self._parked(scene, st, st.anchor_s, st.spec.params["side"], st.spec.params["intrusion"],
                                        st.spec.params["vtype"], st.spec.id)
                st.phase = "spawned"
                self._log(scene.time, st, "spawn", ego_front, float(scene.ego.speed[0]))
            elif st.spec.type == "pedestrian" and st.spec.params["occluder"]:
                if _on_junction(scene.route, st.anchor_s - 6.0, st.anchor_s - 1.0):
                    self._log(scene.time, st, "occluder_skipped", ego_front, float(scene.ego.speed[0]),
                              message="no car parks on a junction")
                    continue
                p = st.spec.params
                occ = self._parked(scene, st, st.anchor_s - 3.5, p["side"], 0.2, "car", f"{st.spec.id}_occluder")
                st.props.append(occ)

    @staticmethod
    def _anchor_xy(a: Any) -> tuple[float, float]:
        if a.edge is not None:
            lane = f"{a.edge}_{sumo.edge.getLaneNumber(a.edge) - 1}"
            pos = min(a.pos, sumo.lane.getLength(lane))
            return sumo.simulation.convert2D(a.edge, pos, sumo.edge.getLaneNumber(a.edge) - 1)
        if a.junction is not None:
            return sumo.junction.getPosition(a.junction)
        return a.xy

    def _vtype(self, vtype: str) -> str:
        known = self._known_types()
        if vtype in known:
            return vtype
        return _FALLBACK.get(vtype, "DEFAULT_VEHTYPE")

    def _known_types(self) -> set[str]:
        if not hasattr(self, "_types"):
            self._types = set(sumo.vehicletype.getIDList())
        return self._types

    def _parked(self, scene: Any, st: HazardState, s: float, side: str, intrusion: float, vtype: str,
                name: str) -> Actor:
        a = self._new_actor(name, vtype)
        i = scene.route.vertex_at(s)
        if side == "right":
            a.d = float(scene.route.right[i]) + intrusion - a.width / 2.0
        else:
            a.d = float(scene.route.left[i]) - intrusion + a.width / 2.0
        a.s, a.v, a.parked = s, 0.0, True
        self._place(scene, a)
        return a

    # ---- actors -------------------------------------------------------------------------
    def _new_actor(self, name: str, vtype: str) -> Actor:
        tid = self._vtype(vtype)
        vt = sumo.vehicletype
        a = Actor(sumo_id=f"hazard_{name}", is_person=vt.getVehicleClass(tid) == "pedestrian",
                  length=vt.getLength(tid), width=vt.getWidth(tid))
        a.type_id = tid
        return a

    def _place(self, scene: Any, a: Actor) -> None:
        """Command the actor's pose (and speed) for the end of the coming step."""
        path = scene.route.path
        if a.line is not None:
            x0, y0, ux, uy = a.line
            x, y, yaw, speed = x0 + ux * a.travelled, y0 + uy * a.travelled, math.atan2(uy, ux), abs(a.v)
        else:
            px, py, h = path.to_xy(np.array(a.s), np.array(a.d))
            x, y, h = float(px), float(py), float(h)
            dd = a.d - (a.d if a.d_last is None else a.d_last)
            a.d_last = a.d
            vs = a.v if a.v != 0.0 else 0.0
            lat = dd / scene.dt
            yaw = h + math.atan2(lat, vs) if (abs(vs) > 0.05 or abs(lat) > 0.05) else (h + (math.pi if a.v < 0 else 0.0))
            if a.is_person and abs(vs) <= 0.05 and abs(lat) <= 0.05:
                yaw = h if a.yaw_last is None else a.yaw_last
            speed = math.hypot(vs, lat)
        a.yaw_last = yaw
        fx, fy, angle = (float(v) for v in centre_to_front(x, y, yaw, a.length))
        if a.is_person:
            if not a.added:
                sumo.person.add(a.sumo_id, self._walk_edge(scene), 0.0, typeID=a.type_id)
                sumo.person.appendWaitingStage(a.sumo_id, 3600.0)
                a.added = True
            sumo.person.moveToXY(a.sumo_id, "", fx, fy, angle, _KEEP_PERSON, 100.0)
            sumo.person.setSpeed(a.sumo_id, max(speed, 0.01))
        else:
            v = sumo.vehicle
            if not a.added:
                v.add(a.sumo_id, self._route_id, typeID=a.type_id, depart="now", departSpeed="0")
                v.setSpeedMode(a.sumo_id, 32)
                v.setLaneChangeMode(a.sumo_id, 0)
                v.setSpeedFactor(a.sumo_id, 3.0)
                a.added = True
            v.moveToXY(a.sumo_id, "", -1, fx, fy, angle, _KEEP_PARKED if a.parked else _KEEP_VEHICLE, 100.0)
            v.setSpeed(a.sumo_id, speed)
        a.x, a.y, a.yaw = x, y, yaw

    def _walk_edge(self, scene: Any) -> str:
        """An edge of the ego's route a person may be put on (SUMO refuses edges without a
        lane pedestrians may use); the person is then moved off it with moveToXY."""
        for e in scene.route.edges:
            for i in range(sumo.edge.getLaneNumber(e)):
                lane = f"{e}_{i}"
                allowed = sumo.lane.getAllowed(lane)
                if ("pedestrian" in allowed) if allowed else ("pedestrian" not in sumo.lane.getDisallowed(lane)):
                    return e
        return scene.route.edges[0]

    def _remove(self, a: Actor) -> None:
        if not a.added:
            return
        try:
            if a.is_person:
                sumo.person.remove(a.sumo_id)
            else:
                sumo.vehicle.remove(a.sumo_id)
        except sumo.TraCIException:
            pass
        a.added = False

    # ---- the hazard state machine -------------------------------------------------------
    def _advance(self, st: HazardState, scene: Any, ego_front: float, v_ego: float) -> None:
        spec, dt, t = st.spec, scene.dt, scene.time
        for prop in st.props:
            if prop.added:
                self._place(scene, prop)
        if st.phase == "wait":
            spawn_now = spec.spawn is not None and st.anchor() - ego_front <= spec.spawn
            if spawn_now or self._triggered(st, ego_front, v_ego):
                self._spawn(st, scene, ego_front, v_ego)
                st.phase = "spawned"
                self._log(t, st, "spawn", ego_front, v_ego)
            else:
                return
        a = st.actor
        if a is None:  # spawned in the wait phase above, or parked at set-up
            raise RuntimeError(f"hazard {spec.id} is {st.phase} without an actor")
        if st.phase == "spawned" and spec.type != "parked" and self._triggered(st, ego_front, v_ego):
            st.phase, st.t_trigger = "triggered", t
            st.d0, st.v0 = a.d, a.v
            self._log(t, st, "trigger", ego_front, v_ego)
        self._move(st, scene, t, dt)
        if self._finished(st, a, scene, ego_front):
            self._remove(a)
            for prop in st.props:
                self._remove(prop)
            st.phase = "done"
            self._log(t, st, "remove", ego_front, v_ego)
            return
        self._place(scene, a)

    def _triggered(self, st: HazardState, ego_front: float, v_ego: float) -> bool:
        spec = st.spec
        kind, value = spec.trigger_kind, spec.trigger_value
        if kind is None:
            return False
        if kind in ("distance", "ttc") or st.actor is None:
            gap, closing = st.anchor() - ego_front, v_ego
        else:
            a = st.actor
            gap = a.s - a.length / 2.0 - ego_front
            closing = v_ego - a.v
        if kind in ("distance", "gap"):
            return gap <= value
        return gap <= value * max(closing, 1e-3) if gap > 0 else True

    def _spawn(self, st: HazardState, scene: Any, ego_front: float, v_ego: float) -> None:
        spec, p = st.spec, st.spec.params
        a = self._new_actor(spec.id, p["vtype"])
        route = scene.route
        kind = spec.type
        anchor_s = st.anchor()
        if kind == "pedestrian":
            i = route.vertex_at(anchor_s)
            a.s = anchor_s
            a.d = float(route.right[i]) - p["offset"] if p["side"] == "right" else float(route.left[i]) + p["offset"]
            a.v = 0.0
        elif kind == "emergency_stop":
            a.s = ego_front + p["gap"] + a.length / 2.0
            a.d, a.v = 0.0, max(v_ego * p["speed_ratio"], 1.0)
        elif kind == "cut_in":
            a.s = ego_front + p["gap"] + a.length / 2.0
            a.d = p["lane_offset"] if p["side"] == "left" else -p["lane_offset"]
            a.v = max(v_ego * p["speed_ratio"], 1.0)
        elif kind == "oncoming_drift":
            a.s, a.d, a.v = anchor_s, p["lane_offset"], -p["speed"]
        elif kind == "cyclist_swerve":  # placed so that the ego comes up to it at the anchor
            eta = max(anchor_s - ego_front, 0.0) / max(v_ego, 1.0)
            a.s = max(anchor_s - p["speed"] * eta, ego_front + 15.0 + a.length / 2.0)  # never on the ego
            a.d, a.v = p["offset"], p["speed"]
        elif kind == "escort":  # alongside in the next lane, at the ego's speed
            a.s = scene.s + p["ahead"]
            a.d = p["lane_offset"] if p["side"] == "left" else -p["lane_offset"]
            a.v = v_ego
        elif kind == "tailgater":  # close behind, following with a reaction time
            a.s = ego_front - float(scene.ego.length[0]) - p["gap"] - a.length / 2.0
            a.d, a.v = 0.0, v_ego
            a.ego_speeds = [v_ego]
        elif kind == "red_light_runner":
            px, py, h = (float(v) for v in route.path.to_xy(np.array(anchor_s), np.array(0.0)))
            eta = max(anchor_s - ego_front, 0.0) / max(v_ego, 0.1)
            dist = p["speed"] * max(eta - p["lead"], 0.5) + a.length / 2.0
            sign = 1.0 if p["side"] == "left" else -1.0
            nx, ny = -math.sin(h) * sign, math.cos(h) * sign  # unit vector towards the start side
            a.line = (px + nx * dist, py + ny * dist, -nx, -ny)
            a.v = p["speed"]
            a.s = anchor_s
            a.line_length = 2.0 * dist + 30.0
        st.actor = a

    def _move(self, st: HazardState, scene: Any, t: float, dt: float) -> None:
        a, p, kind = st.actor, st.spec.params, st.spec.type
        if a is None:
            return
        trig = st.phase == "triggered"
        since = st.since_trigger(t)
        if kind == "pedestrian":
            if trig:
                a.v = 0.0
                step = p["speed"] * dt
                a.d += step if p["side"] == "right" else -step
            return
        if kind == "red_light_runner":
            a.travelled += a.v * dt
            return
        if kind == "escort":
            if not trig:  # keeps its place beside the ego
                a.v = float(scene.ego.speed[0])
                a.s = scene.s + p["ahead"] + a.v * dt
                return
            if since >= p["hold"]:
                a.v = max(0.0, a.v - p["decel"] * dt)
        elif kind == "tailgater":
            speeds = a.ego_speeds
            speeds.append(float(scene.ego.speed[0]))
            lag = int(round(p["reaction"] / dt))
            target = speeds[max(len(speeds) - 1 - lag, 0)]
            del speeds[:-(lag + 1)]  # keep only the reaction window
            a.v = min(max(target, a.v - p["decel"] * dt), a.v + 2.0 * dt)
        if kind == "emergency_stop" and trig:
            v_stop_t = st.v0 / p["decel"]
            if since < v_stop_t:
                a.v = max(0.0, st.v0 - p["decel"] * (since + dt))
            elif since < v_stop_t + p["hold"]:
                a.v = 0.0
            else:  # drive off again, up to the lane's speed limit
                limit = float(scene.route.speed_limit[scene.route.vertex_at(a.s)])
                a.v = min(max(st.v0, limit), a.v + 2.5 * dt)
        elif kind == "cut_in" and trig:
            a.d = st.d0 * (1.0 - _smooth((since + dt) / p["duration"]))
        elif kind == "oncoming_drift" and trig:
            u = since + dt
            dur, hold = p["duration"], p["hold"]
            if u <= dur:
                a.d = st.d0 - p["drift"] * _smooth(u / dur)
            elif u <= dur + hold:
                a.d = st.d0 - p["drift"]
            else:
                a.d = st.d0 - p["drift"] * (1.0 - _smooth((u - dur - hold) / dur))
        elif kind == "cyclist_swerve" and trig:  # out, hold, back to its line
            u, dur = since + dt, p["duration"]
            back = max(u - dur - p["hold"], 0.0)
            a.d = st.d0 + p["swerve"] * (_smooth(u / dur) - _smooth(back / dur))
        a.s += a.v * dt

    def _finished(self, st: HazardState, a: Actor, scene: Any, ego_front: float) -> bool:
        kind = st.spec.type
        if kind == "parked":
            return False
        if kind == "red_light_runner":
            return a.travelled > a.line_length
        if kind == "pedestrian":
            route = scene.route
            i = route.vertex_at(st.anchor())
            width = float(route.left[i] - route.right[i]) + 2.0 * st.spec.params["offset"] + 1.0
            return abs(a.d - st.d0) > width if st.phase == "triggered" else False
        ego_s = ego_front
        if a.s + a.length / 2.0 < ego_s - 40.0:
            return True  # left behind the ego
        return a.s + a.length / 2.0 > scene.route.path.length - 1.0 or a.s - ego_s > 200.0

    # ---- log ----------------------------------------------------------------------------
    def _log(self, t: float, st: HazardState, event: str, ego_front: float, v_ego: float, message: str = "") -> None:
        a = st.actor
        row = {"time": round(float(t), 6), "hazard": st.spec.id, "type": st.spec.type, "event": event,
               "anchor_s": st.anchor_s, "ego_front_s": float(ego_front), "ego_speed": float(v_ego)}
        if a is not None:
            row.update(actor=a.sumo_id, actor_s=float(a.s), actor_d=float(a.d), actor_speed=float(a.v))
            if a.line is not None:
                row.update(actor_x=a.line[0] + a.line[2] * a.travelled, actor_y=a.line[1] + a.line[3] * a.travelled)
        if message:
            row["message"] = message
        self.events.append(row)
