"""The converted SUMO net of an imported CommonRoad scenario, read with sumolib (the adapter owns
sumolib): which lane a recorded position is on, the lane leading into a junction lane, and the
ego's and the obstacles' routes. Used by ``sumo_ethics.commonroad.importer``; no libsumo."""

from __future__ import annotations

import math
from typing import Any

import sumolib

from sumo_ethics.goal import Goal
from sumo_ethics.errors import ConfigError


def read_net(path: Any) -> Any:
    """The net with its junction lanes."""
    return sumolib.net.readNet(str(path), withInternal=True)


def _angle_diff(a: float, b: float) -> float:
    return abs((a - b + math.pi) % (2.0 * math.pi) - math.pi)


def match_lane(net: Any, x: float, y: float, yaw: float, vclass: str, radius: float = 4.0,
               max_angle: float = math.radians(45.0), junctions: bool = False) -> tuple[Any, float] | None:
    """The lane nearest to (x, y) running within ``max_angle`` of ``yaw`` that ``vclass`` may use
    (junction lanes too with ``junctions``), and the position of (x, y) along it [m]; None if there is
    none within ``radius``."""
    best = None
    for lane, _dist in net.getNeighboringLanes(x, y, radius, includeJunctions=junctions):
        if lane.getID().startswith(":") and not junctions:
            continue
        if not lane.allows(vclass):
            continue
        pos, d = lane.getClosestLanePosAndDist((x, y))
        shape = lane.getShape()
        seg = _segment_at(shape, pos)
        heading = math.atan2(seg[1][1] - seg[0][1], seg[1][0] - seg[0][0])
        if _angle_diff(heading, yaw) > max_angle:
            continue
        key = (d, lane.getID())
        if best is None or key < best[0]:
            best = (key, lane, pos)
    return None if best is None else (best[1], best[2])


def _segment_at(shape: list, pos: float) -> tuple:
    run = 0.0
    for a, b in zip(shape[:-1], shape[1:]):
        seg = math.hypot(b[0] - a[0], b[1] - a[1])
        if run + seg >= pos:
            return a, b
        run += seg
    return shape[-2], shape[-1]


def from_lane(net: Any, internal: str) -> Any:
    """The normal lane whose connection runs through junction lane ``internal`` (or a lane split from it)."""
    base = internal.rsplit("_", 1)[0]
    exact, same_edge = [], []
    for edge in sorted(net.getEdges(withInternal=False), key=lambda e: e.getID()):
        for lane in edge.getLanes():
            for conn in lane.getOutgoing():
                via = conn.getViaLaneID() or ""
                if via == internal:
                    exact.append(lane)
                elif via.rsplit("_", 1)[0] == base:
                    same_edge.append(lane)
    if exact or same_edge:
        return (exact or same_edge)[0]
    raise ConfigError(f"unsupported: the ego starts on junction lane {internal}, which no lane leads into")


def shortest_path(net: Any, a: Any, b: Any, vclass: str) -> list[str] | None:
    if a.getID() == b.getID():
        return [a.getID()]
    edges, _ = net.getShortestPath(a, b, vClass=vclass)
    return None if edges is None else [e.getID() for e in edges]


def ego_route(net: Any, start: Any, goal: Goal, vclass: str = "passenger") -> tuple[list[str], list[str], list[str]]:
    """(route edges, goal edges, goal lanes: the lanes of the route within half a lane width of the
    goal region, which the ego's reference path changes to): the shortest route from edge ``start`` to the goal region: to an edge
    with a lane through it, or through a junction lane crossing it (the connection's edges); extended by
    one successor so the goal lies before the route's end. Without a goal position, the longest of the
    shortest routes to every reachable edge."""
    from shapely.geometry import LineString

    region = goal.region()
    edges = [e for e in net.getEdges(withInternal=False) if e.allows(vclass)]

    def hits(lane: Any) -> bool:  # the lane's centre line within half its width of the goal region
        return LineString([p[:2] for p in lane.getShape()]).distance(region) <= lane.getWidth() / 2.0

    if region is not None:
        goal_edges = sorted(e.getID() for e in edges if any(hits(lane) for lane in e.getLanes()))
        # junction lanes through the goal: the route must take their connection (from edge -> to edge)
        via = sorted({(lane.getEdge().getID(), c.getTo().getID()) for e in edges for lane in e.getLanes()
                      for c in lane.getOutgoing() if c.getViaLaneID() and hits(net.getLane(c.getViaLaneID()))})
        if not goal_edges and not via:
            raise ConfigError("unsupported: no lane of the converted network passes within half a lane width of the goal region")
        options = []
        for g in goal_edges:
            p = shortest_path(net, start, net.getEdge(g), vclass)
            if p is not None:
                options.append((sum(net.getEdge(e).getLength() for e in p), p))
        for a, b in via:
            p = shortest_path(net, start, net.getEdge(a), vclass)
            if p is not None and b not in p:
                p = p + [b]
                options.append((sum(net.getEdge(e).getLength() for e in p), p))
        if not options:
            raise ConfigError("unsupported: no route from the ego's start lane to the goal region in the converted network")
        route = min(options)[1]
        goal_edges = sorted(set(goal_edges) | {b for _, b in via})
        lanes = [lane for e in route for lane in net.getEdge(e).getLanes() if lane.allows(vclass)]
        # the lanes through the region; only without one, those passing within half a width of it
        goal_lanes = sorted(lane.getID() for lane in lanes if LineString([p[:2] for p in lane.getShape()])
                            .intersects(region)) or sorted(lane.getID() for lane in lanes if hits(lane))
    else:
        goal_edges, goal_lanes = [], []
        reachable: list[tuple[float, list[int], list[str]]] = []  # (length, [-edges], path)
        for e in sorted(edges, key=lambda e: e.getID()):
            p = shortest_path(net, start, e, vclass)
            if p is not None:
                reachable.append((sum(net.getEdge(x).getLength() for x in p), [-len(p)], p))
        route = max(reachable, key=lambda o: (o[0], o[1]))[2]
    nxt = sorted(e.getID() for e in net.getEdge(route[-1]).getOutgoing() if e.allows(vclass))
    if nxt:
        route = route + [nxt[0]]
    return route, goal_edges, goal_lanes


def obstacle_route(net: Any, states: list[dict[str, Any]], vclass: str) -> tuple[Any, float, list[str]] | None:
    """(first lane, position along it, route edges) along an obstacle's recorded positions, or None
    when its first position is on no lane heading its way (parked, off the road)."""
    first = match_lane(net, states[0]["x"], states[0]["y"], states[0]["yaw"], vclass, radius=2.5)
    if first is None:
        return None
    lane, pos = first
    edges = [lane.getEdge().getID()]
    for s in states[1:: max(1, len(states) // 50)] + [states[-1]]:
        m = match_lane(net, s["x"], s["y"], s["yaw"], vclass, radius=2.5)
        if m is None or m[0].getEdge().getID() == edges[-1]:
            continue
        p = shortest_path(net, net.getEdge(edges[-1]), m[0].getEdge(), vclass)
        if p is None:
            break  # unreachable in the net: the route ends where it can
        edges += p[1:]
    return lane, pos, edges


#: a vClass SUMO may refuse on every lane (a highway net disallows pedestrians and bicycles) -> classes the
#: project books the same way (sumo_ethics.types: wheelchair is a pedestrian, scooter a bicycle)
SAME_KIND = {"pedestrian": ("wheelchair",), "bicycle": ("scooter",)}


def replay_edge(net: Any, vclass: str) -> tuple[str, str] | None:
    """(vClass, edge) for a replayed road user: an edge one of its lanes allows the class on (SUMO
    inserts it there before moving it to its recorded place), trying classes of the same kind when
    no lane allows its own; None when none does."""
    edges = sorted(net.getEdges(withInternal=False), key=lambda e: e.getID())
    for vc in (vclass, *SAME_KIND.get(vclass, ())):
        for e in edges:
            if any(lane.allows(vc) for lane in e.getLanes()):
                return vc, e.getID()
    return None
