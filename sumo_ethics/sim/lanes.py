"""Map and signal context for the map-aware predictor: the libsumo side.

The predictor's map features (:mod:`sumo_ethics.predict.features`) are built from plain
arrays; this module is where they come from in a running simulation:

- :func:`lane_graph` reads every lane's centre line, speed limit and successors once
  (``lane.getShape``, ``lane.getMaxSpeed``, ``lane.getLinks``) into a
  :class:`~sumo_ethics.predict.features.LaneGraph`.
- :func:`agent_context` reads, for a list of road users, the lane each one is on, the position
  of its centre along that lane (for vehicles SUMO's front-bumper position minus half its
  length, at least 0) and the next traffic light ahead (distance to its stop line and the state
  of the link it will use, and how long that state holds: :class:`SignalClock`). For pedestrians: their sidewalk, crossing or walking area, the next
  lane of their walk, and the signalised crossing they are on or walk to next
  (:func:`crossing_signals`: distance to its nearer end, its state), as arrays; from map
  version 4 also each vehicle's blinkers and each pedestrian's lane after a walking area.
- :class:`SumoMapSource` bundles them for the run-time predictor; the dataset builder calls
  the same functions, so training and run-time inputs come from the same code.
"""

from __future__ import annotations

import heapq
import re

import numpy as np

from sumo_ethics.predict.features import MAP_VERSION, TLS_CODES, WALKING_AREA, LaneGraph, MapContext
from sumo_ethics.sim.backend import sumo
from sumo_ethics.sim.route import lane_allows

CROSSING = re.compile(r":.+_c\d+_0")


def lane_graph() -> LaneGraph:
    """Every lane of the loaded network (internal junction lanes included) as a LaneGraph."""
    ln = sumo.lane
    ids = tuple(ln.getIDList())
    shapes = [np.asarray(ln.getShape(k), dtype=float)[:, :2] for k in ids]
    speed = np.array([ln.getMaxSpeed(k) for k in ids], dtype=float)
    lengths = np.array([ln.getLength(k) for k in ids], dtype=float)
    links = []
    for k in ids:
        nxt = []
        for link in ln.getLinks(k):
            # (approached lane, prio, open, foe, via internal lane, state, direction, length)
            nxt.append(link[4] if link[4] else link[0])
        links.append(tuple(nxt))
    return LaneGraph.build(ids, shapes, speed, links, lengths)


def tls_code(state: str) -> int:
    """A link state character -> TLS_CODES index (0 none, 1 green, 2 yellow, 3 red)."""
    return TLS_CODES.get(state, 0)


def time_to_change(states: list[str] | tuple[str, ...], durations, phase: int, remaining: float, link: int) -> float:
    """How long link ``link`` of a traffic light keeps its colour [s] (inf: no phase changes it).

    states, durations: the light's program (one state string and duration [s] per phase);
    phase: the current phase, ``remaining`` [s] of it left. The colour is the TLS_CODES value
    ('G' and 'g' are both green), so a change is green -> yellow, yellow -> red, red -> green
    or red+yellow. The following phases are taken at their programmed durations (an actuated
    light's may differ).
    """
    n = len(states)
    if n == 0 or link >= len(states[phase % n]):
        return float("inf")
    code = tls_code(states[phase % n][link])
    t = float(remaining)
    for k in range(1, n):
        j = (phase + k) % n
        if link >= len(states[j]) or tls_code(states[j][link]) != code:
            return t
        t += float(durations[j])
    return float("inf")


class SignalClock:
    """Per traffic light, its colours now and how long each link keeps its colour (read once
    per simulation step and light; the programs once per program)."""

    def __init__(self) -> None:
        self._programs: dict[tuple[str, str], tuple[tuple[str, ...], tuple[float, ...]]] = {}
        self._now: dict[str, tuple[str, int, float, tuple[str, str]]] = {}
        self._time = -1.0

    def _read(self, tls: str) -> tuple[str, int, float, tuple[str, str]]:
        t = sumo.simulation.getTime()
        if t != self._time:
            self._now.clear()
            self._time = t
        if tls not in self._now:
            tl = sumo.trafficlight
            key = (tls, tl.getProgram(tls))
            if key not in self._programs:
                logic = next((lg for lg in tl.getAllProgramLogics(tls) if lg.programID == key[1]), None)
                phases = logic.phases if logic is not None else ()
                self._programs[key] = (tuple(ph.state for ph in phases), tuple(ph.duration for ph in phases))
            self._now[tls] = (tl.getRedYellowGreenState(tls), tl.getPhase(tls), tl.getNextSwitch(tls) - t, key)
        return self._now[tls]

    def state(self, tls: str) -> str:
        """The light's state string now."""
        return self._read(tls)[0]

    def holds(self, tls: str, link: int) -> float:
        """How long link ``link`` of light ``tls`` keeps its colour [s] (:func:`time_to_change`)."""
        _, phase, remaining, key = self._read(tls)
        states, durations = self._programs[key]
        return time_to_change(states, durations, phase, remaining, link)


#: crossing lane id -> (traffic light id, link index) of the link that signals it
CrossingSignals = dict[str, tuple[str, int]]


def crossing_signals() -> CrossingSignals:
    """Every signalised pedestrian crossing of the loaded network: its lane -> (light, link index).

    SUMO signals a crossing by one link from a walking area into it (``trafficlight.getControlledLinks``);
    crossing lanes are the internal lanes ``:<junction>_c<k>_0``.
    """
    out: CrossingSignals = {}
    for tls in sumo.trafficlight.getIDList():
        for index, links in enumerate(sumo.trafficlight.getControlledLinks(tls)):
            for link in links:
                for lane in link[:2]:
                    if CROSSING.fullmatch(lane):
                        out.setdefault(lane, (tls, index))
    return out


def pavement(graph: LaneGraph, edge: str) -> str:
    """The lane a person stands on who is on ``edge`` but, by SUMO, on no lane: the edge's
    lowest-numbered lane that allows pedestrians, the one nearest the kerb (the rightmost on SUMO's
    right-hand networks, the leftmost on ``lefthand`` ones, which netconvert numbers from the left;
    "" when it has none).

    A person waiting at a stop for a ride (stage "waiting for ANY") has an empty
    ``person.getLaneID`` but its stop's edge and position along it (``getRoadID``,
    ``getLanePosition``); SUMO puts it on the pavement beside the stop (DLR's Bologna
    ``acosta``: each of 237 waiting persons 1.0 m from the centre line of its edge's sidewalk,
    ``simulation.convertRoad(x, y, vClass="pedestrian")``). Without a lane the predictor saw a
    standing pedestrian with no map context, which the training data never has. Cached on the
    graph per edge.
    """
    cache = graph.__dict__.setdefault("_pavement", {})
    if edge not in cache:
        lanes = (f"{edge}_{i}" for i in range(sumo.edge.getLaneNumber(edge) if edge else 0))
        cache[edge] = next((lane for lane in lanes if lane_allows(lane, "pedestrian")), "")
    return cache[edge]


def _is_internal_walk(lane_id: str) -> bool:
    return WALKING_AREA.fullmatch(lane_id) is not None or CROSSING.fullmatch(lane_id) is not None


def after_walking_area(graph: LaneGraph, area: int, targets: frozenset[str], skip: int = -1) -> int:
    """The lane a pedestrian takes after walking area ``area`` toward the next sidewalk of its walk.

    The shortest way (by SUMO's lane lengths) from ``area`` through the junction's walking areas
    and crossings to a lane of an edge in ``targets`` (the walk's next edge; on a crossing, any
    edge of the walk: the nearest is the one across). Returns the way's first lane after ``area``
    (a crossing, or that sidewalk), -1 when there is none within 8 lanes. Pedestrians walk
    crossings both ways, so links are followed in both directions. ``skip``: a lane not to walk
    through (the crossing the pedestrian is on). Cached on the graph.

    SUMO's own router adds 20 s for a crossing that is red when the pedestrian enters the walking
    area, and routes again while it waits there, so on a diagonal walk (two crossings either
    way) it may take the other one: ``tools/walk_check.py`` measures how often this is right.
    The lights are not reckoned in here: tried, it was right less often (docs/prediction.md,
    "Lanes and signals").
    """
    cache = graph.__dict__.setdefault("_after", {})
    key = (area, targets, skip)
    if key in cache:
        return cache[key]
    adj = graph.__dict__.get("_walk_adj")
    if adj is None:  # lane -> lanes linked to it either way, for walking areas and crossings
        adj = {}
        for i, nxt in enumerate(graph.succ):
            for j in nxt:
                if _is_internal_walk(graph.ids[i]) or _is_internal_walk(graph.ids[j]):
                    adj.setdefault(i, []).append(j)
                    adj.setdefault(j, []).append(i)
        adj = graph.__dict__["_walk_adj"] = {k: tuple(v) for k, v in adj.items()}
    best = -1
    heap: list[tuple[float, int, int, int]] = [(0.0, 0, area, -1)]  # (length, hops, lane, first lane after area)
    done: set[int] = set()
    while heap:
        dist, hops, lane, first = heapq.heappop(heap)
        if lane in done:
            continue
        done.add(lane)
        lane_id = graph.ids[lane]
        if lane != area and not _is_internal_walk(lane_id):
            if lane_id.rpartition("_")[0] in targets:
                best = first
                break
            continue  # another sidewalk: the walk does not go there
        if hops >= 8:
            continue
        for j in adj.get(lane, ()):
            if j in done or j == skip:
                continue
            cost = float(graph.lengths[j]) if _is_internal_walk(graph.ids[j]) else 0.0  # a sidewalk: from its near end
            heapq.heappush(heap, (dist + cost, hops + 1, j, j if first < 0 else first))
    cache[key] = best
    return best


def _person_context(graph: LaneGraph, signals: CrossingSignals, k: str, i: int, ctx: dict[str, np.ndarray],
                    clock: SignalClock, switch_times: bool, after: bool = False) -> None:
    """Fill row ``i`` of ``ctx``'s arrays for person ``k`` (see :func:`agent_context`); ``after``:
    also its lane after a walking area (map version 4)."""
    p = sumo.person
    if p.getVehicle(k):  # riding: getLaneID is its vehicle's lane
        return
    lane_id = p.getLaneID(k) or pavement(graph, p.getRoadID(k))
    j = graph.index.get(lane_id, -1)
    if j < 0:  # on a lane this graph does not know
        return
    ctx["lane"][i] = j
    ctx["lane_pos"][i] = max(p.getLanePosition(k), 0.0)
    nxt = p.getNextEdge(k)
    nxt_lane = f"{nxt}_0" if nxt else ""
    ctx["next_lane"][i] = graph.index.get(nxt_lane, -1)
    if after and ctx["next_lane"][i] >= 0 and WALKING_AREA.fullmatch(nxt_lane):
        edges = p.getEdges(k)
        road = lane_id.rpartition("_")[0]  # its edge (the lane read above; no second look-up)
        # (a walk that passes an edge twice is taken at its first pass; on a crossing, an edge of
        # the walk already walked counts too: both are rare, and tools/walk_check.py counts them)
        if road in edges:  # on a sidewalk: the walk's next edge
            at = edges.index(road)
            targets = frozenset(edges[at + 1: at + 2])
        else:  # on a crossing: the edge of the walk at the other side
            targets = frozenset(edges)
        if targets:
            ctx["after_lane"][i] = after_walking_area(graph, int(ctx["next_lane"][i]), targets, skip=j)
    for cand, on in ((lane_id, True), (nxt_lane, False)):
        sig = signals.get(cand)
        if sig is None or cand not in graph.index:
            continue
        tls, link = sig
        state = clock.state(tls)
        ctx["tls_state"][i] = tls_code(state[link]) if link < len(state) else 0
        if switch_times:
            ctx["tls_switch"][i] = clock.holds(tls, link)
        if on:
            ctx["tls_dist"][i] = 0.0
        else:
            ends = graph.shapes[graph.index[cand]][[0, -1]]
            ctx["tls_dist"][i] = float(np.hypot(*(ends - np.asarray(p.getPosition(k))).T).min())
        return


def agent_context(graph: LaneGraph, ids: list[str] | tuple[str, ...], person: np.ndarray,
                  signals: CrossingSignals | None = None, clock: SignalClock | None = None,
                  version: int = MAP_VERSION) -> MapContext:
    """Lane index (-1: none), lane position, next traffic light distance/state and how long
    that state holds of ``ids``, and for persons their next lane (see the module docstring).

    person: (N,) bool, True for persons; signals: :func:`crossing_signals` of the network (read
    here when not given and there are persons); clock: a :class:`SignalClock` kept across
    steps (it caches the lights' programs; a new one when not given); version: the map version
    the context is for: what it does not use is not looked up (version 1: persons get no
    context; before 3: no switch times, tls_switch inf; before 4: no blinkers (0) and no lane
    after a walking area (-1): :func:`after_walking_area`).
    """
    n = len(ids)
    person = np.asarray(person, dtype=bool)
    ctx = {"lane": np.full(n, -1, dtype=np.int64), "lane_pos": np.zeros(n), "tls_dist": np.full(n, np.inf),
           "tls_state": np.zeros(n, dtype=np.int64), "next_lane": np.full(n, -1, dtype=np.int64),
           "tls_switch": np.full(n, np.inf), "blinker": np.zeros(n, dtype=np.int64),
           "after_lane": np.full(n, -1, dtype=np.int64)}
    lane, pos, tls_dist, tls_state = ctx["lane"], ctx["lane_pos"], ctx["tls_dist"], ctx["tls_state"]
    walks, switch_times, v4 = version >= 2, version >= 3, version >= 4
    if walks and signals is None and person.any():
        signals = crossing_signals()
    clock = SignalClock() if clock is None else clock
    v = sumo.vehicle
    index = graph.index
    for i, k in enumerate(ids):
        if person[i]:
            if not walks:
                continue
            if signals is None:  # read above: there are persons
                raise RuntimeError("agent_context: the crossing signals are not read for the persons")
            try:
                _person_context(graph, signals, k, i, ctx, clock, switch_times, after=v4)
            except sumo.TraCIException:  # left the simulation in between: no context
                lane[i], pos[i], tls_dist[i], tls_state[i], ctx["next_lane"][i] = -1, 0.0, np.inf, 0, -1
                ctx["tls_switch"][i], ctx["after_lane"][i] = np.inf, -1
            continue
        try:
            lane_id = v.getLaneID(k)
            j = index.get(lane_id, -1)
            if j < 0:
                continue
            lane[i] = j
            # SUMO's lane position is the front bumper's; the features use the centre's
            pos[i] = max(v.getLanePosition(k) - 0.5 * v.getLength(k), 0.0)
            nxt = v.getNextTLS(k)
            if v4:
                ctx["blinker"][i] = v.getSignals(k) & 7  # right, left blinker, hazard flasher
        except sumo.TraCIException:  # left the simulation in between: no context
            lane[i] = -1
            continue
        if nxt:  # (light id, link index, distance, state)
            tls_dist[i] = float(nxt[0][2])
            tls_state[i] = tls_code(nxt[0][3])
            if switch_times:
                ctx["tls_switch"][i] = clock.holds(nxt[0][0], int(nxt[0][1]))
    return MapContext(lane=lane, lane_pos=pos, tls_dist=tls_dist, tls_state=tls_state, person=person,
                      next_lane=ctx["next_lane"], tls_switch=ctx["tls_switch"], blinker=ctx["blinker"],
                      after_lane=ctx["after_lane"])


class SumoMapSource:
    """Map context of the running simulation for the map-aware predictor (built lazily), for a
    model of map version ``version`` (what it does not read is not looked up)."""

    def __init__(self, version: int = MAP_VERSION) -> None:
        self.version = int(version)
        self._graph: LaneGraph | None = None
        self._signals: CrossingSignals | None = None
        self._clock = SignalClock()

    @property
    def graph(self) -> LaneGraph:
        if self._graph is None:
            self._graph = lane_graph()
            self._signals = crossing_signals()
        return self._graph

    def __call__(self, ids: tuple[str, ...], person: np.ndarray) -> tuple[LaneGraph, MapContext]:
        graph = self.graph
        return graph, agent_context(graph, ids, person, self._signals, self._clock, self.version)
