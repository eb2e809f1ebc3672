"""The static world the ego's sensor looks at, read from the running simulation: the SUMO side of
:class:`~sumo_ethics.plan.perception.SightMap` (``[planner] occlusion`` and ``phantoms``).

- opaque polygons: every polygon SUMO loaded (``<poly>`` of the scenario's additional files, e.g. an
  OSM import's buildings) whose type is one of ``PerceptionConfig.opaque`` ("building" matches
  "building.yes"), read through libsumo's polygon domain (so polygons added at run time count too);
- walkable areas: sidewalks (lanes only pedestrians may use, their centre line widened by half
  their width on each side, flat ends), crossings (the same) and walking areas (their outline), read
  from the network file with sumolib;
- lanes for phantom cyclists and vehicles: bike lanes (only bicycles may use them) and the other
  lanes that vehicles use, each with its speed limit and the junction it enters;
- link_state: a lane's signal now, "r" when every link leaving it shows red, else "G".

:func:`sight_map` is the factory the runner hands the planner; the map of a network and polygon set
is built once per process (a fleet's egos share it).
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import shapely

from sumo_ethics.plan.perception import LaneLine, SightMap, opaque_type
from sumo_ethics.sim.backend import sumo


def polygons(opaque: tuple[str, ...]) -> tuple[tuple[str, ...], tuple[shapely.Geometry, ...]]:
    """(ids, shapely polygons) of the simulation's polygons whose type is opaque; invalid outlines
    repaired (``make_valid``), lines and points left out."""
    ids, shapes = [], []
    for pid in sumo.polygon.getIDList():
        if not opaque_type(sumo.polygon.getType(pid), opaque):
            continue
        pts = np.asarray(sumo.polygon.getShape(pid), dtype=float).reshape(-1, 2)
        if len(pts) < 3:
            continue
        g = shapely.make_valid(shapely.Polygon(pts))
        parts = [p for p in shapely.get_parts(g) if p.geom_type == "Polygon" and p.area > 0.0]
        if parts:
            ids.append(pid)
            shapes.append(shapely.union_all(parts) if len(parts) > 1 else parts[0])
    return tuple(ids), tuple(shapes)


def _strip(xy: np.ndarray, width: float) -> Any:
    """A lane's area: its centre line widened by half its width on each side, flat ends."""
    return shapely.buffer(shapely.linestrings(xy), width / 2.0, cap_style="flat", join_style="mitre")


@lru_cache(maxsize=4)
def _network(path: str, mtime: float) -> tuple[tuple[shapely.Geometry, ...], tuple[LaneLine, ...]]:
    """(walkable polygons, lanes) of a network file."""
    import sumolib

    net = sumolib.net.readNet(path, withInternal=True, withPedestrianConnections=True)
    walkable: list[shapely.Geometry] = []
    lanes: list[LaneLine] = []
    for edge in net.getEdges(withInternal=True):
        function = edge.getFunction() or ""
        to = edge.getToNode()
        for lane in edge.getLanes():
            xy = np.asarray(lane.getShape(), dtype=float)[:, :2]
            if len(xy) < 2:
                continue
            allowed = set(lane.getPermissions())
            if function == "walkingarea":
                if len(xy) >= 3:
                    g = shapely.make_valid(shapely.Polygon(xy))
                    walkable += [p for p in shapely.get_parts(g) if p.geom_type == "Polygon" and p.area > 0.0]
            elif function == "crossing" or (function == "" and allowed and allowed <= {"pedestrian"}):
                walkable.append(_strip(xy, float(lane.getWidth())))
            elif function == "" and allowed and allowed <= {"bicycle"}:
                lanes.append(LaneLine(lane.getID(), "bike", xy, float(lane.getSpeed()), to.getID() if to else ""))
            elif function == "" and allowed - {"pedestrian", "bicycle"}:
                lanes.append(LaneLine(lane.getID(), "road", xy, float(lane.getSpeed()), to.getID() if to else ""))
    return tuple(walkable), tuple(lanes)


def link_state(lane: str) -> str:
    """"r" when every link leaving ``lane`` shows red (a vehicle there stops), else "G"."""
    links = sumo.lane.getLinks(lane)
    return "r" if links and all(link[5] in "rR" for link in links) else "G"


@lru_cache(maxsize=8)
def _map(path: str, mtime: float, opaque: tuple[str, ...], polygon_ids: tuple[str, ...]) -> SightMap:
    walkable, lanes = _network(path, mtime)
    _, shapes = polygons(opaque)
    return SightMap(opaque=shapes, walkable=walkable, lanes=lanes, link_state=link_state)


def net_file() -> Path:
    """The running simulation's network file."""
    return Path(sumo.simulation.getOption("net-file")).resolve()


def sight_map(opaque: tuple[str, ...]) -> SightMap:
    """The :class:`SightMap` of the running simulation with polygons of the ``opaque`` types."""
    p = net_file()
    ids, _ = polygons(opaque)
    return _map(str(p), p.stat().st_mtime, tuple(opaque), ids)
