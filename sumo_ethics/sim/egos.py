"""The libsumo side of a fleet run (:mod:`sumo_ethics.runner.fleet`): inserting egos, noticing which
vehicles depart, arrive or teleport, telling which may become egos, and letting go of an ego.

An ego is driven by :class:`~sumo_ethics.sim.world.SumoWorld` exactly as in the single-ego run;
here are only the calls that concern the whole simulation (one ``simulationStep`` for every ego).
"""

from __future__ import annotations

import numpy as np

from sumo_ethics.config import EgoVehicle
from sumo_ethics.errors import ConfigError
from sumo_ethics.sim.backend import sumo, tc
from sumo_ethics.sim.ego import EGO_TYPE, _usable_edges, check_ego_vehicle, define_ego_type, random_route
from sumo_ethics.sim.world import sumo_collisions  # noqa: F401 - re-exported for the fleet loop

#: SUMO's default speed and lane-change modes, restored when an ego is handed back
DEFAULT_SPEED_MODE = 31
DEFAULT_LANE_CHANGE_MODE = 1621


def insert_egos(ids: list[str], departs: list[float], seed: int, ego: EgoVehicle, min_length: float,
                lane: str = "best") -> dict[str, tuple[str, ...]]:
    """Add the inserted egos ``ids`` to SUMO's insertion queue, each departing at its time of
    ``departs`` [s] on a route drawn with ``seed`` (ego i with the generator seeded (seed, i)).
    Returns id -> route edges; ConfigError when the network has no route for a car."""
    define_ego_type(ego)
    edges = _usable_edges()
    if not edges:
        raise ConfigError("the network has no edge a passenger car may use")
    routes: dict[str, tuple[str, ...]] = {}
    for i, (vid, depart) in enumerate(zip(ids, departs)):
        route = random_route(edges, np.random.default_rng([seed, i]), min_length)
        if not route:
            raise ConfigError("found no route for the egos on this network")
        sumo.route.add(f"{vid}_route", list(route))
        sumo.vehicle.add(vid, f"{vid}_route", typeID=EGO_TYPE, depart=f"{depart:.3f}", departLane=lane,
                           departSpeed="max")
        routes[vid] = route
    return routes


def departed() -> tuple[str, ...]:
    """Vehicles that entered the network in the step just taken."""
    return tuple(sumo.simulation.getDepartedIDList())


def teleporting() -> frozenset[str]:
    """Vehicles SUMO started to teleport in the step just taken (jammed, or after a collision)."""
    return frozenset(sumo.simulation.getStartingTeleportIDList())


def eligible(vid: str) -> bool:
    """Whether a vehicle of the scenario may become an ego: a motor road vehicle without stops or
    taxi device (the rules of ``--ego``, :func:`sumo_ethics.sim.ego.check_ego_vehicle`)."""
    try:
        check_ego_vehicle(vid)
    except ConfigError:
        return False
    return True


def route_edges(vid: str) -> tuple[str, ...]:
    return tuple(sumo.vehicle.getRoute(vid))


def _unsubscribe(vid: str) -> None:
    v = sumo.vehicle
    v.unsubscribeContext(vid, tc.CMD_GET_VEHICLE_VARIABLE, 0)
    v.unsubscribeContext(vid, tc.CMD_GET_PERSON_VARIABLE, 0)


def speed_factor(vid: str) -> float:
    """A vehicle's own speedFactor (drawn by SUMO from its vType's speed distribution)."""
    return float(sumo.vehicle.getSpeedFactor(vid))


def hold_speed(vid: str) -> None:
    """For the step between a takeover and the ego's first planned step: keep its speed (the
    takeover switched SUMO's checks off and tripled its speed factor)."""
    sumo.vehicle.setSpeed(vid, sumo.vehicle.getSpeed(vid))


def release(vid: str, factor: float = 1.0) -> None:
    """Hand an ego back to SUMO (its goal reached, or its control given up): SUMO's own car
    following and lane changing drive it from here, with its own speed ``factor``; its
    subscriptions end."""
    v = sumo.vehicle
    if vid not in v.getIDList():
        return
    _unsubscribe(vid)
    v.setSpeedMode(vid, DEFAULT_SPEED_MODE)
    v.setLaneChangeMode(vid, DEFAULT_LANE_CHANGE_MODE)
    v.setSpeedFactor(vid, factor)
    v.setSpeed(vid, -1)  # SUMO's own speed from now on


def remove(vid: str) -> None:
    """Take a crashed ego off the road (SUMO's collision.action remove does this to its own);
    its subscriptions end first (SUMO fails on a subscription of a vehicle that is gone)."""
    if vid in sumo.vehicle.getIDList():
        _unsubscribe(vid)
        sumo.vehicle.remove(vid, tc.REMOVE_VAPORIZED)


def advance() -> None:
    """One simulation step for everyone."""
    sumo.simulationStep()


def pending() -> int:
    """Vehicles and persons still running or waiting to depart (0: the scenario is over)."""
    return int(sumo.simulation.getMinExpectedNumber())


def vclasses() -> dict[str, str]:
    """vType id -> vClass of every vType SUMO knows (for the trips of the run)."""
    vt = sumo.vehicletype
    return {t: vt.getVehicleClass(t) for t in vt.getIDList()}
