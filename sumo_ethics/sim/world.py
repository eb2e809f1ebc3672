"""Reading the scene around the ego and actuating it: the libsumo side of each step.

One context subscription per domain (vehicles, persons) returns every neighbour in range in
one call. Both come back merged in one dict, the ego included; persons are told apart by
the variable set (only vehicles are subscribed with acceleration); a person is always a
pedestrian, whatever vClass its vType has. A person riding a vehicle (a bus or taxi passenger,
a ``<ride>`` stage) is part of that vehicle and left out: SUMO reports it at its vehicle's
position, where it would be a pedestrian inside a car to the planner and the collision check.

Road users on another level cannot meet the ego and are left out of the scene, so neither the
planner nor the collision check sees them: more than ``VERTICAL_CLEARANCE`` above or below it
(positions are read in 3D), or, in a network without elevation, on a lane that crosses the
ego's lane without a junction (see :func:`crossings_without_junction`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sumo_ethics.ethics.harm import MassModel, vtype_mass
from sumo_ethics.sim.backend import sumo, tc
from sumo_ethics.sim.frames import centre_to_front, front_to_centre
from sumo_ethics.contract import EgoCommand, JunctionLink, RoutePath
from sumo_ethics.sim.route import build_route_path
from sumo_ethics.types import AgentStates, RoadUserClass

_VEH_VARS = (tc.VAR_POSITION3D, tc.VAR_ANGLE, tc.VAR_SPEED, tc.VAR_TYPE, tc.VAR_ACCELERATION)
_PER_VARS = (tc.VAR_POSITION3D, tc.VAR_ANGLE, tc.VAR_SPEED, tc.VAR_TYPE, tc.VAR_VEHICLE)  # vehicle: '' or the ridden one

#: road users whose elevation differs from the ego's by more than this [m] are on another level
#: (a bridge deck is some 5 m above the road below; a ramp changes height by a few % per metre)
VERTICAL_CLEARANCE = 3.0

#: red or yellow link states: the baseline stops before these.
STOP_STATES = frozenset("rRyYu")


@dataclass(frozen=True)
class TypeInfo:
    cls: RoadUserClass
    length: float
    width: float
    mass: float


@dataclass(frozen=True)
class Snapshot:
    """The scene at one instant: ego (1 agent) and neighbours within the sensing radius;
    collisions: SUMO's collision reports of the step that led here (see :func:`sumo_collisions`);
    sumo_speed: the ego's speed as SUMO reports it [m/s] (``ego.speed`` is the commanded one
    after a commanded step, see :meth:`SumoWorld.read`)."""

    time: float
    ego: AgentStates
    others: AgentStates
    collisions: tuple[tuple[str, str, str, str, float, float, str, str], ...] = ()
    sumo_speed: float = float("nan")


class SumoWorld:
    """The ego's view of the running SUMO simulation."""

    def __init__(self, ego_id: str, radius: float, masses: MassModel = MassModel()) -> None:
        self.ego_id = ego_id
        self.radius = radius
        self.masses = masses
        self._types: dict[str, TypeInfo] = {}  # vehicle types
        self._person_types: dict[str, TypeInfo] = {}  # the same vTypes used by persons: pedestrians
        self.route: RoutePath | None = None
        self.ego_length = 0.0
        #: lane -> the ego's route lanes it crosses without a junction (a bridge in a flat network)
        self._crossing: dict[str, frozenset[str]] = {}
        self._crossing_box = np.zeros(4)  # x0, y0, x1, y1 around those lanes
        #: speed [m/s] the ego was placed with in the step just taken (None: SUMO drove it)
        self._commanded: float | None = None
        self._speed = 0.0  # the ego's speed at the last read [m/s]
        self._dt = 0.0  # the step length [s]

    # ---- types -------------------------------------------------------------------------
    def type_info(self, type_id: str, person: bool = False) -> TypeInfo:
        """Class, size and mass of a vType; a person is a pedestrian whatever its vType says. The
        mass: the vType's own where the scenario gives one (:func:`~sumo_ethics.ethics.harm.vtype_mass`),
        else the class's (MassModel)."""
        info = (self._person_types if person else self._types).get(type_id)
        if info is None:
            vt = sumo.vehicletype
            vclass = vt.getVehicleClass(type_id)
            cls = RoadUserClass.PEDESTRIAN if person else RoadUserClass.from_vclass(vclass)
            length, width = vt.getLength(type_id), vt.getWidth(type_id)
            given = vtype_mass(vclass, vt.getMass(type_id), vt.getParameter(type_id, "mass"))  # NaN: not given
            mass = float(self.masses.mass(np.array([int(cls)]), np.array([length]), np.array([width]),
                                          np.array([given]))[0])
            info = (self._person_types if person else self._types)[type_id] = TypeInfo(cls, length, width, mass)
        return info

    # ---- takeover ----------------------------------------------------------------------
    def takeover(self) -> RoutePath:
        """Take control of the ego: speed/lane-change modes, context subscriptions, route path."""
        v = sumo.vehicle
        ego = self.ego_id
        edges = v.getRoute(ego)
        lane = v.getLaneID(ego)
        vclass = v.getVehicleClass(ego)
        start = np.asarray(v.getPosition(ego), dtype=float)
        self.route = build_route_path(tuple(edges[v.getRouteIndex(ego):]), lane, vclass, start)
        self._crossing = crossings_without_junction(edges[v.getRouteIndex(ego):])
        if self._crossing:
            pts = np.concatenate([np.asarray(sumo.lane.getShape(k))[:, :2] for k in self._crossing])
            self._crossing_box = np.r_[pts.min(axis=0) - 5.0, pts.max(axis=0) + 5.0]
        self.ego_length = v.getLength(ego)
        self._dt = sumo.simulation.getDeltaT()
        speed = v.getSpeed(ego)
        v.setSpeedMode(ego, 32)  # no safety checks: the controller decides
        v.setLaneChangeMode(ego, 0)
        v.setSpeedFactor(ego, 3.0)  # moveToXY infers speed from displacement, capped by limit x factor
        v.setPreviousSpeed(ego, speed)
        v.subscribeContext(ego, tc.CMD_GET_VEHICLE_VARIABLE, self.radius, _VEH_VARS)
        v.subscribeContext(ego, tc.CMD_GET_PERSON_VARIABLE, self.radius, _PER_VARS)
        return self.route

    # ---- reading -----------------------------------------------------------------------
    def read(self) -> Snapshot | None:
        """The scene now; None once the ego is no longer in the simulation.

        After a commanded step the ego's speed is the commanded one (the speed the planner placed
        it with; its acceleration the change from the last read over the step), not SUMO's:
        SUMO re-derives a moved vehicle's speed from the route distance, and where the move
        crosses onto a lane its lane has no link to (a junction lane reached from the
        neighbouring lane) it reports 0 m/s for a moving ego (A10KW, t = 362.6 s: -43.7 m/s^2,
        and the planner then started from a standstill). SUMO's own value is kept in
        ``Snapshot.sumo_speed``.
        """
        res = sumo.vehicle.getContextSubscriptionResults(self.ego_id)
        if self.ego_id not in res:
            res = self._read_off_network()
            if res is None:
                return None
        res = {k: r for k, r in res.items() if not r.get(tc.VAR_VEHICLE)}  # riders travel inside their vehicle
        ego, others = self._states([self.ego_id] + sorted(k for k in res if k != self.ego_id), res)
        sumo_speed = float(ego.speed[0])
        if self._commanded is not None:
            speed = self._commanded
            ego = AgentStates.trusted(ego.ids, ego.x, ego.y, ego.yaw, np.array([speed]),
                                      np.array([(speed - self._speed) / self._dt]), ego.length, ego.width, ego.mass,
                                      ego.cls, ego.type_id)
        self._speed = float(ego.speed[0])
        return Snapshot(sumo.simulation.getTime(), ego, others, tuple(sumo_collisions()), sumo_speed)

    def step(self, cmd: EgoCommand | None = None) -> None:
        """Apply ``cmd`` (if any) and advance SUMO one step (then :meth:`read` the scene)."""
        self.command(cmd)
        sumo.simulationStep()

    def command(self, cmd: EgoCommand | None) -> None:
        """Place the ego at ``cmd`` during the next step (None: SUMO drives it); a fleet commands
        every ego, then steps SUMO once."""
        self._commanded = None
        if cmd is not None:
            self.apply(cmd)

    def party_state(self, agent_id: str) -> AgentStates | None:
        """Full state of any vehicle or person by id (None if it is not in the simulation)."""
        return party_state(agent_id, self)

    def _read_off_network(self) -> dict | None:
        """Context subscriptions return nothing while the ego is off every lane (moved there by
        moveToXY): read everyone within the radius one by one instead (slow, rare)."""
        v, p = sumo.vehicle, sumo.person
        if self.ego_id not in v.getIDList():
            return None
        ex, ey = v.getPosition(self.ego_id)
        res: dict = {}
        for dom, vars_ in ((v, _VEH_VARS), (p, _PER_VARS)):
            for k in dom.getIDList():
                x, y, z = dom.getPosition3D(k)
                if k == self.ego_id or (x - ex) ** 2 + (y - ey) ** 2 <= self.radius**2:
                    r = {tc.VAR_POSITION3D: (x, y, z), tc.VAR_ANGLE: dom.getAngle(k), tc.VAR_SPEED: dom.getSpeed(k),
                         tc.VAR_TYPE: dom.getTypeID(k)}
                    if tc.VAR_ACCELERATION in vars_:
                        r[tc.VAR_ACCELERATION] = dom.getAcceleration(k)
                    else:
                        r[tc.VAR_VEHICLE] = dom.getVehicle(k)
                    res[k] = r
        return res

    def _states(self, ids: list[str], res: dict) -> tuple[AgentStates, AgentStates]:
        """States of ``ids`` (the ego first, then the neighbours in sorted order) from
        subscription results, split into (ego, others); one vectorised pass for all. Neighbours
        on another level (more than VERTICAL_CLEARANCE above or below the ego) are dropped."""
        rows = [res[k] for k in ids]
        types = tuple(r[tc.VAR_TYPE] for r in rows)
        accel_var = tc.VAR_ACCELERATION  # only vehicles are subscribed with it: its absence marks persons
        known, known_p = self._types, self._person_types
        info = [(known.get(t) if accel_var in r else known_p.get(t)) or self.type_info(t, accel_var not in r)
                for t, r in zip(types, rows)]
        # one (9, N) conversion for every numeric column, rows contiguous
        num = np.array([(*r[tc.VAR_POSITION3D], r[tc.VAR_ANGLE], r[tc.VAR_SPEED], r.get(accel_var, 0.0),
                         t.length, t.width, t.mass) for r, t in zip(rows, info)], dtype=float).reshape(-1, 9).T.copy()
        z = num[2]
        dz = z.max() - z.min()
        level = np.abs(z - z[0]) <= VERTICAL_CLEARANCE if dz > VERTICAL_CLEARANCE else None
        if self._crossing:  # the route crosses roads without a junction: who is on one, above or below?
            on_crossing = self._on_crossing_road(ids, num[0], num[1], [accel_var not in r for r in rows])
            level = ~on_crossing if level is None else level & ~on_crossing
        if level is not None and not level.all():
            keep = np.flatnonzero(level)
            num, ids = num[:, keep], [ids[i] for i in keep]
            types, info = tuple(types[i] for i in keep), [info[i] for i in keep]
        fx, fy, _, angle, speed, accel, length, width, mass = num
        x, y, yaw = front_to_centre(fx, fy, angle, length)
        cls = np.array([t.cls for t in info], dtype=np.int8)
        # the arrays are (N,) by construction: skip AgentStates' checks (this runs every step)
        ego, others = (AgentStates.trusted(tuple(ids[part]), x[part], y[part], yaw[part], speed[part], accel[part],
                                           length[part], width[part], mass[part], cls[part], types[part])
                       for part in (slice(None, 1), slice(1, None)))
        return ego, others

    def red_phase_end(self) -> float | None:
        """When the phase of the ego's next traffic light ends [s], if that light shows it red or
        yellow (SUMO's getNextTLS and getNextSwitch); None otherwise."""
        try:
            upcoming = sumo.vehicle.getNextTLS(self.ego_id)
            if upcoming and upcoming[0][3] in "rRyYu":
                return float(sumo.trafficlight.getNextSwitch(upcoming[0][0]))
        except sumo.TraCIException:
            pass
        return None

    def link_state(self, link: JunctionLink) -> str:
        """Current signal state character of a link on the ego's path ('G', 'r', ...)."""
        return sumo.lane.getLinks(link.lane)[link.index][5]

    def sumo_lane(self) -> str:
        return sumo.vehicle.getLaneID(self.ego_id)

    def _on_crossing_road(self, ids: list[str], fx: np.ndarray, fy: np.ndarray, persons: list[bool]) -> np.ndarray:
        """(N,) bool: on a lane crossing the ego's current lane without a junction. Lanes are read
        (one call each) only for road users near those lanes, and only while the ego is on one
        of the route lanes they cross."""
        out = np.zeros(len(ids), dtype=bool)
        ego_lane = sumo.vehicle.getLaneID(self.ego_id)
        if not any(ego_lane in crossed for crossed in self._crossing.values()):
            return out
        x0, y0, x1, y1 = self._crossing_box
        near = np.flatnonzero((fx >= x0) & (fx <= x1) & (fy >= y0) & (fy <= y1))
        for i in near[near > 0]:
            dom = sumo.person if persons[i] else sumo.vehicle
            out[i] = ego_lane in self._crossing.get(dom.getLaneID(ids[i]), ())
        return out

    def sumo_speed(self) -> float:
        return sumo.vehicle.getSpeed(self.ego_id)

    # ---- acting ------------------------------------------------------------------------
    def apply(self, cmd: EgoCommand) -> None:
        """Place the ego at ``cmd`` during the next step, with its true speed."""
        fx, fy, angle = centre_to_front(cmd.x, cmd.y, cmd.yaw, self.ego_length)
        v = sumo.vehicle
        # keepRoute 3 = 1 | 2: exact pose (may leave the road), matched onto the lanes of the ego's
        # own route; with 2 alone SUMO maps it onto the nearest lane in plan view, e.g. onto a road
        # on a bridge above, or a crossing movement's junction lane. Lanes searched within 10 m.
        v.moveToXY(self.ego_id, "", -1, float(fx), float(fy), float(angle), 3, 10.0)
        speed = max(0.0, float(cmd.speed))
        v.setSpeed(self.ego_id, speed)
        # matched onto its route, SUMO derives the speed from the route distance moved, and reported
        # 0 m/s for one step where an ego 2.4 m off its lane entered a junction (tools/game/cross):
        # the planner then started from a standstill (-21 m/s^2). Tell SUMO the speed as well (the
        # other drivers see it in the next step); :meth:`read` returns it whatever SUMO reports.
        v.setPreviousSpeed(self.ego_id, speed)
        self._commanded = speed


def crossings_without_junction(route_edges) -> dict[str, frozenset[str]]:
    """Lanes that cross a lane of ``route_edges`` without a junction: lane -> the route lanes it
    crosses. In a network without elevation (OSM imports usually have none) such a crossing is
    a bridge or a tunnel: netconvert builds a junction wherever roads meet at grade. Normal
    lanes only; lanes of edges that share a junction with the route edge do not count."""
    from shapely import STRtree
    from shapely.geometry import LineString

    edge, lane = sumo.edge, sumo.lane
    route = [e for e in dict.fromkeys(route_edges) if not e.startswith(":")]
    route_lanes = [f"{e}_{i}" for e in route for i in range(edge.getLaneNumber(e))]
    if not route_lanes:
        return {}
    others = [k for k in lane.getIDList() if k[0] != ":"]
    tree = STRtree([LineString(lane.getShape(k)) for k in others])
    nodes = {}

    def ends(e: str) -> set[str]:
        if e not in nodes:
            nodes[e] = {edge.getFromJunction(e), edge.getToJunction(e)}
        return nodes[e]

    out: dict[str, set[str]] = {}
    for a in route_lanes:
        ea = lane.getEdgeID(a)
        for j in tree.query(LineString(lane.getShape(a)), predicate="intersects"):
            b = others[int(j)]
            eb = lane.getEdgeID(b)
            if eb != ea and not ends(ea) & ends(eb):
                out.setdefault(b, set()).add(a)
    return {k: frozenset(v) for k, v in out.items()}


def sumo_collisions() -> list[tuple[str, str, str, str, float, float, str, str]]:
    """This step's SUMO collision reports: (collider, victim, colliderType, victimType,
    colliderSpeed, victimSpeed, type, lane)."""
    return [(c.collider, c.victim, c.colliderType, c.victimType, c.colliderSpeed, c.victimSpeed, c.type, c.lane)
            for c in sumo.simulation.getCollisions()]


def party_state(agent_id: str, world: SumoWorld) -> AgentStates | None:
    """Full state of any vehicle or person by id (for collisions outside the ego's range)."""
    for dom, is_person in ((sumo.vehicle, False), (sumo.person, True)):
        try:
            x, y = dom.getPosition(agent_id)
            angle, speed, type_id = dom.getAngle(agent_id), dom.getSpeed(agent_id), dom.getTypeID(agent_id)
        except sumo.TraCIException:
            continue
        info = world.type_info(type_id, is_person)
        cx, cy, yaw = front_to_centre(np.array([x]), np.array([y]), np.array([angle]), np.array([info.length]))
        return AgentStates(
            ids=(agent_id,), x=cx, y=cy, yaw=yaw, speed=np.array([speed]), accel=np.zeros(1),
            length=np.array([info.length]), width=np.array([info.width]), mass=np.array([info.mass]),
            cls=np.array([int(info.cls)], dtype=np.int8), type_id=(type_id,),
        )
    return None
