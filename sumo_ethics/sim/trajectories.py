"""Every road user's state each step, with map context at the predictor's rate: the libsumo side
of the prediction datasets (:mod:`sumo_ethics.predict.samples` turns the rows into samples).

Two ways in, one set of columns (those of a dataset's ``trajectories.parquet`` but run_id, seed,
scenario and scale, which the caller adds):

- :func:`record_run` starts SUMO, steps it alone and reads every road user through
  subscriptions (the dataset builder's runs of whole scenarios);
- :class:`TrafficRecorder` is called by a run that someone else drives (a suite scenario with
  its ego and hazards) and reads the road users of the current step.

Positions are SUMO's front bumpers, turned into centres (``sim.frames.front_to_centre``) by the
caller of :func:`record_run` and per road user by :class:`TrafficRecorder`. Riders (persons in
a vehicle) are left out: they are their vehicle, as at run time; so are the steps in which SUMO
gives a road user no position (:func:`on_road`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sumo_ethics.predict.features import LaneGraph, MapContext
from sumo_ethics.sim.backend import sumo, tc
from sumo_ethics.sim.lanes import SignalClock, agent_context, crossing_signals, lane_graph
from sumo_ethics.types import RoadUserClass

#: the map-context columns and their values on rows between the predictor's steps
CONTEXT_COLUMNS = {"lane": -1, "lane_pos": 0.0, "tls_dist": np.inf, "tls_state": 0, "next_lane": -1,
                   "tls_switch": np.inf, "blinker": 0, "after_lane": -1}


def on_road(pos: tuple[float, float]) -> bool:
    """Whether SUMO gives the road user a position: not while it is inserted but not yet placed (a
    suite hazard's first step), parked off the road or teleporting (INVALID_DOUBLE_VALUE, -2^30 m,
    which became 1e9 m jumps in the samples of every dataset recorded before this check)."""
    return pos[0] != tc.INVALID_DOUBLE_VALUE and pos[1] != tc.INVALID_DOUBLE_VALUE


class TypeInfo:
    """Length, width and class per vehicle type, asked of SUMO once per type; a person is a
    pedestrian whatever its type's vClass (as at run time)."""

    def __init__(self) -> None:
        self._types: dict[tuple[str, bool], tuple[float, float, int]] = {}

    def __call__(self, type_id: str, person: bool = False) -> tuple[float, float, int]:
        key = (type_id, person)
        if key not in self._types:
            vt = sumo.vehicletype
            cls = RoadUserClass.PEDESTRIAN if person else RoadUserClass.from_vclass(vt.getVehicleClass(type_id))
            self._types[key] = (vt.getLength(type_id), vt.getWidth(type_id), int(cls))
        return self._types[key]


def record_run(cmd: list[str], sim_seconds: float, sim_dt: float = 0.1, model_dt: float = 0.2
               ) -> tuple[dict[str, list[Any]], LaneGraph]:
    """Run SUMO (``cmd``, started and closed here) for ``sim_seconds`` or until no one is left ->
    (columns: time, agent_id, x, y (front bumper), angle (SUMO's, degrees), speed, type (length,
    width, class) and the map context of :data:`CONTEXT_COLUMNS`, one entry per road user and
    step; the network's lane graph). Map context at the model rate only (other rows as
    :data:`CONTEXT_COLUMNS`)."""
    sumo.start(cmd)
    vars_ = (tc.VAR_POSITION, tc.VAR_ANGLE, tc.VAR_SPEED)
    info = TypeInfo()
    agent_type: dict[str, tuple[float, float, int]] = {}
    cols: dict[str, list[Any]] = {k: [] for k in ("time", "agent_id", "x", "y", "angle", "speed", "type",
                                                  *CONTEXT_COLUMNS)}
    graph = lane_graph()
    signals = crossing_signals()
    clock = SignalClock()
    ratio = int(round(model_dt / sim_dt))
    t0 = sumo.simulation.getTime()
    try:
        while sumo.simulation.getTime() - t0 < sim_seconds and sumo.simulation.getMinExpectedNumber() > 0:
            sumo.simulationStep()
            for v in sumo.simulation.getDepartedIDList():
                sumo.vehicle.subscribe(v, vars_)
                agent_type[v] = info(sumo.vehicle.getTypeID(v))
            for p in sumo.simulation.getDepartedPersonIDList():
                sumo.person.subscribe(p, vars_ + (tc.VAR_VEHICLE,))
                agent_type[p] = info(sumo.person.getTypeID(p), person=True)
            t = sumo.simulation.getTime()
            at_model_rate = int(round(t / sim_dt)) % ratio == 0
            for is_person, res in enumerate((sumo.vehicle.getAllSubscriptionResults(),
                                             sumo.person.getAllSubscriptionResults())):
                if is_person:  # a rider is in its vehicle, not a pedestrian (as at run time)
                    res = {k: r for k, r in res.items() if not r[tc.VAR_VEHICLE]}
                res = {k: r for k, r in res.items() if on_road(r[tc.VAR_POSITION])}
                ids = list(res)
                if at_model_rate:
                    ctx = agent_context(graph, ids, np.full(len(ids), bool(is_person)), signals, clock)
                else:
                    ctx = MapContext.empty(len(ids))
                for name in CONTEXT_COLUMNS:
                    cols[name].extend(getattr(ctx, name).tolist())
                for aid, r in res.items():
                    pos = r[tc.VAR_POSITION]
                    cols["time"].append(t)
                    cols["agent_id"].append(aid)
                    cols["x"].append(pos[0])
                    cols["y"].append(pos[1])
                    cols["angle"].append(r[tc.VAR_ANGLE])
                    cols["speed"].append(r[tc.VAR_SPEED])
                    cols["type"].append(agent_type[aid])
    finally:
        sumo.close()
    return cols, graph


class TrafficRecorder:
    """Every road user's state each step (the whole simulation, not only the ego's
    neighbours), with map context at the predictor's rate: the rows of a prediction dataset
    (columns as ``sumo_ethics.predict.samples``'s trajectories) from a run driven by someone
    else, e.g. a suite scenario with its hazards. ``skip``: ids left out (the ego)."""

    def __init__(self, skip: tuple[str, ...] = (), sim_dt: float = 0.1, model_dt: float = 0.2) -> None:
        self.skip = set(skip)
        self.graph = lane_graph()
        self.signals = crossing_signals()
        self.clock = SignalClock()
        self.ratio = int(round(model_dt / sim_dt))
        self.sim_dt = sim_dt
        self.cols: dict[str, list] = {k: [] for k in ("time", "agent_id", "cls", "x", "y", "yaw", "speed", "length",
                                                      "width", *CONTEXT_COLUMNS)}
        self._info = TypeInfo()

    def step(self) -> None:
        """Record the simulation's current state."""
        from sumo_ethics.sim.frames import front_to_centre

        t = sumo.simulation.getTime()
        at_rate = int(round(t / self.sim_dt)) % self.ratio == 0
        for person, dom in ((False, sumo.vehicle), (True, sumo.person)):
            where = {k: dom.getPosition(k) for k in dom.getIDList()
                     if k not in self.skip and not (person and dom.getVehicle(k))}  # no riders
            ids = [k for k, pos in where.items() if on_road(pos)]
            if not ids:
                continue
            ctx = agent_context(self.graph, ids, np.full(len(ids), person), self.signals, self.clock) if at_rate else None
            for i, k in enumerate(ids):
                length, width, cls = self._info(dom.getTypeID(k), person)
                fx, fy = where[k]
                x, y, yaw = front_to_centre(np.array([fx]), np.array([fy]), np.array([dom.getAngle(k)]), np.array([length]))
                c = self.cols
                c["time"].append(round(t, 3))
                c["agent_id"].append(k)
                c["cls"].append(cls)
                c["x"].append(float(x[0]))
                c["y"].append(float(y[0]))
                c["yaw"].append(float(yaw[0]))
                c["speed"].append(dom.getSpeed(k))
                c["length"].append(length)
                c["width"].append(width)
                for name, between in CONTEXT_COLUMNS.items():
                    c[name].append(getattr(ctx, name)[i].item() if ctx is not None else between)
