"""Running a folder written by ``sumo-ethics import-commonroad`` (``commonroad.json`` beside the sumocfg).

:class:`CommonRoadHook` is a run hook (:class:`sumo_ethics.contract.StepHook`) that

- at the takeover places the ego at the planning problem's initial state (position, heading,
  speed) for the first controlled step, which is CommonRoad time step ``first_step``: simulation
  time ``T0 + (k - first_step) * dt``, T0 the time of that first step;
- every step replays the recorded obstacles (all of them in replay mode; in reactive mode those
  SUMO cannot drive: parked, off the road, static): each is added with its own vType (class and
  size) when its record begins, moved with ``moveToXY`` (exact position, keepRoute 2|4) to its
  recorded state for the coming step, and removed when its record ends; nothing reacts to the ego;
  between recorded steps (a run step shorter than the scenario's) the state is interpolated;
- checks the goal region every step (:meth:`sumo_ethics.goal.Goal.completes` under the import's
  completion rule, the ego's centre, heading and speed at its CommonRoad time step) and ends the run
  as completed when it is reached (:class:`~sumo_ethics.contract.StopRun`); a goal without a
  position only at the end of its time window (rule ``commonroad``);
- asks the controller every step for no more than the speed that is halfway through the goal
  region as its time window opens (:meth:`desired_speed`, :class:`sumo_ethics.goal.Pace`);
- measures, every step, how far each replayed obstacle is from its recorded position as SUMO
  reports it (``replay.max_error_m`` in summary.json's ``commonroad`` entry).
"""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from sumo_ethics.contract import StepHook, StopRun
from sumo_ethics.goal import Goal, Pace
from sumo_ethics.errors import ConfigError
from sumo_ethics.sim.backend import sumo
from sumo_ethics.sim.frames import centre_to_front, front_to_centre
from sumo_ethics.types import RunStatus

MARKER = "commonroad.json"
_KEEP = 2 | 4  # exact position (may leave the road), any lane: the recorded pose whatever the lanes say
_ROUTE = "cr_replay_route"


def marker_of(sumocfg: Path) -> Path | None:
    """The ``commonroad.json`` beside ``sumocfg`` if the folder was written by import-commonroad."""
    p = Path(sumocfg).parent / MARKER
    return p if p.is_file() else None


class GoalReached(Exception):
    pass


class CommonRoadHook(StepHook):
    """Replay, goal check and initial state of an imported CommonRoad scenario (see the module doc)."""

    def __init__(self, marker: Path) -> None:
        try:
            self.meta = json.loads(Path(marker).read_text())
        except (OSError, ValueError) as exc:
            raise ConfigError(f"{marker}: not a readable import-commonroad file ({exc})") from None
        if self.meta.get("format") != 1:
            raise ConfigError(f"{marker}: unknown format {self.meta.get('format')!r}; import the scenario again")
        self.folder = Path(marker).parent
        self.dt_cr = float(self.meta["dt"])
        self.first = int(self.meta["first_step"])
        self.goal = Goal.from_list(self.meta["goal"])
        self.pace: Pace | None = None  # along the ego's reference path, from the takeover on
        import pandas as pd

        obs = self.meta["obstacles"]
        table = pd.read_parquet(self.folder / obs["file"])
        replayed = set(obs["replayed"])
        self.info = {k: v for k, v in obs["info"].items() if k in replayed}
        self.tracks: dict[str, dict[str, np.ndarray]] = {}
        for sid, g in table[table.sumo_id.isin(replayed)].groupby("sumo_id", sort=True):
            g = g.sort_values("step")
            self.tracks[sid] = {c: g[c].to_numpy() for c in ("step", "x", "y", "yaw", "speed")}
        self.added: set[str] = set()
        self._routes: set[str] = set()  # insertion routes added, one per edge
        self.t0: float | None = None
        self.goal_reached = False
        self.completion = str(self.meta.get("completion", "commonroad"))  # imports before the option: commonroad
        self.goal_time: float | None = None
        self.goal_step: int | None = None
        self.max_error = 0.0
        self.n_checked = 0
        self.n_missing = 0
        self.last_step_checked: int | None = None

    # ---- time ---------------------------------------------------------------------------
    def step_at(self, t: float) -> float:
        """CommonRoad time step (fractional between recorded steps) at simulation time t."""
        if self.t0 is None:
            raise RuntimeError("the CommonRoad replay has no start time before its start (the takeover)")
        return self.first + (t - self.t0) / self.dt_cr

    # ---- the runner's calls -------------------------------------------------------------
    def start(self, world: Any) -> Any:
        """Right after the takeover, before the runner's first step: the ego and the obstacles are
        placed for that step's end, which is CommonRoad step ``first_step``. Returns the ego's
        reference path, changing to the goal's lanes where the route reaches them, with the goal's
        top speed as their speed limit when the goal gives one (None: the runner's own, when the
        goal names no lanes). The goal's pace (:meth:`desired_speed`) is measured along the path the
        ego follows."""
        from sumo_ethics.sim.route import build_route_path
        from sumo_ethics.contract import EgoCommand

        dt = sumo.simulation.getDeltaT()
        self.t0 = sumo.simulation.getTime() + dt
        e = self.meta["ego"]
        world.apply(EgoCommand(e["x"], e["y"], e["yaw"], e["speed"]))
        self._place(self.t0)
        goal_lanes = frozenset(self.meta.get("goal_lanes", ()))
        if not goal_lanes:
            if world.route is not None:
                self.pace = Pace.of(self.goal, world.route.path.xy, self.dt_cr)
            return None
        v = sumo.vehicle
        ego = world.ego_id
        edges = tuple(v.getRoute(ego)[v.getRouteIndex(ego):])
        route = build_route_path(edges, v.getLaneID(ego), v.getVehicleClass(ego), np.array([e["x"], e["y"]]),
                                 target_lanes=goal_lanes)
        # the goal's top speed, where every goal state gives one, as the speed limit on the goal lanes
        tops = [st.velocity[1] for st in self.goal.states if st.velocity is not None]
        if tops and len(tops) == len(self.goal.states):
            on_goal = np.array([lane in goal_lanes for lane in route.lane_of_vertex])
            route = replace(route, speed_limit=np.where(on_goal, np.minimum(route.speed_limit, max(tops)),
                                                        route.speed_limit))
        world.route = route
        self.pace = Pace.of(self.goal, route.path.xy, self.dt_cr)
        return route

    def desired_speed(self, t: float, s: float) -> float | None:
        """The highest speed [m/s] the ego should aim at at simulation time t [s] with its centre at arc
        length s [m] on its reference path, so as not to reach the goal region before its time window
        opens (:meth:`sumo_ethics.goal.Pace.speed`: halfway through the region as the window opens, never
        below the goal's lowest speed); None: the route's speed limit (the goal gives no position or time window,
        the window is open, or the ego is late)."""
        return None if self.pace is None else self.pace.speed(self.step_at(t), s)

    def on_read(self, snap: Any, world: Any) -> None:
        """Ends the run in the goal region (StopRun), else places the obstacles for the coming step."""
        u = self.step_at(snap.time)
        k = int(round(u))
        self._check(snap.time, u)
        ego = snap.ego
        if abs(u - k) < 1e-6 and self.goal.completes(k, float(ego.x[0]), float(ego.y[0]), float(ego.yaw[0]),
                                                     float(ego.speed[0]), self.completion):
            self.goal_reached, self.goal_time, self.goal_step = True, float(snap.time), k
            late = " (late: after the goal's time window, counted as the paper's evaluation does)" \
                if self.goal.late(k) else ""
            raise StopRun(RunStatus.COMPLETED, f"CommonRoad goal reached at t={snap.time:g} s (time step {k}){late}")
        self._place(snap.time + sumo.simulation.getDeltaT())

    def route_end(self, t: float) -> tuple[RunStatus, str]:
        """The ego passed its route's end (past the goal lanes) outside the goal region: not completed."""
        k = self.step_at(t)
        return RunStatus.TIMEOUT, (f"end of the route reached at t={t:g} s (time step {k:.0f}) without reaching the "
                                   f"CommonRoad goal region")

    def summary(self) -> dict[str, Any]:
        return {"commonroad": {
            "scenario_id": self.meta["scenario_id"], "mode": self.meta["mode"], "source": self.meta["source"],
            "completion": self.completion, "goal_reached": self.goal_reached,
            "goal_late": self.goal_reached and self.goal_step is not None and self.goal.late(self.goal_step),
            "goal_time": self.goal_time, "goal_time_step": self.goal_step,
            "first_step": self.first, "last_step": self.meta["last_step"], "time_offset": self.t0,
            "obstacles": self.meta["obstacles"]["count"], "replayed": len(self.info),
            "driven_by_sumo": len(self.meta["obstacles"]["driven_by_sumo"]),
            "replay": {"checked": self.n_checked, "missing": self.n_missing, "max_error_m": self.max_error}}}

    # ---- replay -------------------------------------------------------------------------
    def _state(self, sid: str, u: float) -> tuple[float, float, float, float] | None:
        """Recorded (x, y, yaw, speed) at fractional step u; None outside the record."""
        tr = self.tracks[sid]
        steps = tr["step"]
        if u < steps[0] - 1e-6 or u > steps[-1] + 1e-6:
            return None
        i = int(np.searchsorted(steps, u - 1e-6))
        i = min(i, len(steps) - 1)
        if abs(steps[i] - u) < 1e-6 or i == 0:
            return float(tr["x"][i]), float(tr["y"][i]), float(tr["yaw"][i]), float(tr["speed"][i])
        a = (u - steps[i - 1]) / (steps[i] - steps[i - 1])
        y0, y1 = tr["yaw"][i - 1], tr["yaw"][i]
        dyaw = (y1 - y0 + math.pi) % (2 * math.pi) - math.pi
        lerp = lambda c: float(tr[c][i - 1] + a * (tr[c][i] - tr[c][i - 1]))  # noqa: E731
        return lerp("x"), lerp("y"), float(y0 + a * dyaw), lerp("speed")

    def _place(self, t: float) -> None:
        """Every replayed obstacle at its recorded state for simulation time t (the coming step's end)."""
        v = sumo.vehicle
        u = self.step_at(t)
        for sid, m in self.info.items():
            st = self._state(sid, u)
            if st is None:
                if sid in self.added:
                    v.remove(sid)
                    self.added.discard(sid)
                continue
            x, y, yaw, speed = st
            if sid not in self.added:
                edge = m.get("edge", self.meta["ego"]["route"][0])  # imports before the edge was chosen: the ego's
                route = f"{_ROUTE}_{edge}"
                if route not in self._routes:
                    sumo.route.add(route, [edge])
                    self._routes.add(route)
                v.add(sid, route, typeID=f"{sid}_type", depart="now", departSpeed="0")
                v.setSpeedMode(sid, 32)
                v.setLaneChangeMode(sid, 0)
                v.setSpeedFactor(sid, 3.0)
                self.added.add(sid)
            fx, fy, angle = (float(q) for q in centre_to_front(x, y, yaw, m["length"]))
            v.moveToXY(sid, "", -1, fx, fy, angle, _KEEP, 100.0)
            v.setSpeed(sid, max(0.0, speed))

    def _check(self, t: float, u: float) -> None:
        """How far SUMO has each replayed obstacle from its record at time t (one getter pair each)."""
        v = sumo.vehicle
        present = set(v.getIDList())
        for sid, m in self.info.items():
            st = self._state(sid, u)
            if st is None:
                continue
            if sid not in present:
                self.n_missing += 1
                continue
            fx, fy = v.getPosition(sid)
            x, y, _ = front_to_centre(np.array(fx), np.array(fy), np.array(v.getAngle(sid)), np.array(m["length"]))
            self.max_error = max(self.max_error, float(math.hypot(float(x) - st[0], float(y) - st[1])))
            self.n_checked += 1
