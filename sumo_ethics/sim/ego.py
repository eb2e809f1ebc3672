"""Choosing and inserting the ego: a vehicle of the scenario taken over, or one inserted on a
seeded random route (or --ego-from/--ego-to), and the limits the planner drives it with."""

from __future__ import annotations

from dataclasses import replace
from typing import Callable

import numpy as np

from sumo_ethics.config import EgoVehicle, RunConfig
from sumo_ethics.errors import ConfigError, SimulationError
from sumo_ethics.sim import scenario as scenario_files
from sumo_ethics.sim.backend import sumo
from sumo_ethics.sim.route import lane_allows
from sumo_ethics.types import RoadUserClass

EGO_TYPE = "sumo_ethics_ego"
EGO_ROUTE = "sumo_ethics_ego_route"
INSERT_PATIENCE = 120.0  # s of simulation time to wait for the ego's insertion


def _step_until(pred: Callable[[], bool], limit: float) -> bool:
    while sumo.simulation.getTime() < limit:
        sumo.simulationStep()
        if pred():
            return True
    return False


def wait_for_vehicle(ego_id: str, end: float) -> None:
    """Step until ``ego_id`` departs; ConfigError if it never does before ``end``."""
    if ego_id in sumo.vehicle.getIDList():
        return
    while sumo.simulation.getTime() < end:
        sumo.simulationStep()
        if ego_id in sumo.simulation.getDepartedIDList():
            return
        if sumo.simulation.getMinExpectedNumber() == 0:
            break
    raise ConfigError(f"vehicle '{ego_id}' never departed (simulated until t={sumo.simulation.getTime():g} s)")


def check_ego_vehicle(ego_id: str) -> None:
    """ConfigError for a taken-over vehicle the planner does not model: not a motor road
    vehicle (a bicycle, tram, train), or one with stops or a taxi device (it would have to serve them)."""
    v = sumo.vehicle
    scenario_files.check_ego_class(ego_id, v.getVehicleClass(ego_id))
    try:
        v.getParameter(ego_id, "device.taxi.state")
        scenario_files.refuse_stops(ego_id, "is a taxi")
    except sumo.TraCIException:
        pass
    if v.getStops(ego_id):
        scenario_files.refuse_stops(ego_id)


def _usable_edges() -> list[str]:
    """Non-internal edges with at least one lane a passenger car may use."""
    return sorted(e for e in sumo.edge.getIDList() if not e.startswith(":") and any(
        lane_allows(f"{e}_{i}", "passenger") for i in range(sumo.edge.getLaneNumber(e))))


def find_ego_route(cfg: RunConfig) -> tuple[str, ...]:
    """Edges for the inserted ego: --ego-from/--ego-to, else a seeded random route."""
    known = set(sumo.edge.getIDList())
    if cfg.ego_from is not None:
        for e in (cfg.ego_from, cfg.ego_to):
            if e not in known:
                raise ConfigError(f"unknown edge '{e}' in --ego-from/--ego-to")
        stage = sumo.simulation.findRoute(cfg.ego_from, cfg.ego_to, vType=EGO_TYPE)
        if not stage.edges:
            raise ConfigError(f"no route from edge '{cfg.ego_from}' to edge '{cfg.ego_to}'")
        return tuple(stage.edges)
    edges = _usable_edges()
    if len(edges) < 1:
        raise ConfigError("the network has no edge a passenger car may use")
    route = random_route(edges, np.random.default_rng(cfg.seed), cfg.min_route_length)
    if not route:
        raise ConfigError("found no route for the ego on this network; give --ego-from and --ego-to")
    return route


def random_route(edges: list[str], rng: np.random.Generator, min_length: float) -> tuple[str, ...]:
    """The first route between two random ``edges`` at least ``min_length`` [m] long (else the
    longest of 300 draws; () if none connects)."""
    best: tuple[float, tuple[str, ...]] = (0.0, ())
    for _ in range(300):
        a, b = rng.choice(len(edges), size=2)
        stage = sumo.simulation.findRoute(edges[a], edges[b], vType=EGO_TYPE)
        if stage.edges and stage.length > best[0]:
            best = (stage.length, tuple(stage.edges))
            if stage.length >= min_length:
                break
    return best[1]


def ego_limits(ego_id: str, car: EgoVehicle) -> EgoVehicle:
    """The limits the planner drives a taken-over vehicle with: always its own size (the body SUMO
    simulates, whatever its vClass: a 12 m vType left at the default vClass was planned and
    checked for collisions as a 4.5 m car), and a car's limits (``car``), but for a truck, bus or
    motorcycle no more than its vType's top speed, acceleration and decelerations."""
    v, vt = sumo.vehicle, sumo.vehicletype
    own = replace(car, length=v.getLength(ego_id), width=v.getWidth(ego_id))
    if RoadUserClass.from_vclass(v.getVehicleClass(ego_id)) is RoadUserClass.CAR:
        return own
    t = v.getTypeID(ego_id)
    return replace(own, max_speed=min(car.max_speed, v.getMaxSpeed(ego_id)), max_accel=min(car.max_accel, vt.getAccel(t)),
                   comfort_decel=min(car.comfort_decel, vt.getDecel(t)),
                   max_decel=min(car.max_decel, vt.getEmergencyDecel(t)))


def insert_ego(cfg: RunConfig, ego_id: str, depart: float) -> tuple[str, ...]:
    """Define the ego's vType, wait until ``depart`` [s], insert it, step until it departs."""
    define_ego_type(cfg.ego)
    edges = find_ego_route(cfg)
    _step_until(lambda: False, depart)
    sumo.route.add(EGO_ROUTE, list(edges))
    sumo.vehicle.add(ego_id, EGO_ROUTE, typeID=EGO_TYPE, depart="now", departLane=cfg.ego_depart_lane,
                       departSpeed="max")
    limit = sumo.simulation.getTime() + INSERT_PATIENCE
    if not _step_until(lambda: ego_id in sumo.simulation.getDepartedIDList(), limit):
        raise SimulationError(f"the ego could not be inserted on edge '{edges[0]}' within {INSERT_PATIENCE:g} s")
    return edges


def define_ego_type(ego: EgoVehicle) -> None:
    """The vType of inserted egos (EGO_TYPE): a passenger car with ``ego``'s body and limits."""
    vt = sumo.vehicletype
    vt.copy("DEFAULT_VEHTYPE", EGO_TYPE)
    vt.setVehicleClass(EGO_TYPE, "passenger")
    vt.setLength(EGO_TYPE, ego.length)
    vt.setWidth(EGO_TYPE, ego.width)
    vt.setMass(EGO_TYPE, ego.mass)
    vt.setParameter(EGO_TYPE, "mass", repr(float(ego.mass)))  # given, even if it equals SUMO's 1500 kg
    vt.setMaxSpeed(EGO_TYPE, ego.max_speed)
    vt.setAccel(EGO_TYPE, ego.max_accel)
    vt.setDecel(EGO_TYPE, ego.comfort_decel)
    vt.setEmergencyDecel(EGO_TYPE, ego.max_decel)


def start_ego(cfg: RunConfig, ego_id: str, end: float, depart: float) -> tuple[EgoVehicle, tuple[str, ...]]:
    """Bring the ego into the simulation: wait for the scenario's vehicle ``cfg.ego_id`` (checked
    and driven within its own limits), else insert one at ``depart`` [s]. Returns the limits the
    planner drives it with and its route's edges."""
    if cfg.ego_id is not None:
        wait_for_vehicle(ego_id, end)
        check_ego_vehicle(ego_id)
        return ego_limits(ego_id, cfg.ego), tuple(sumo.vehicle.getRoute(ego_id))
    return cfg.ego, insert_ego(cfg, ego_id, depart)
