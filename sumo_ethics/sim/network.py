"""The road as drawn in figures: lane, crossing, walking area and junction shapes and the stop
lines of signalised junctions, read from a SUMO network file with sumolib (``.net.xml`` or
``.net.xml.gz``). Only for pictures: the planner reads the road from the running SUMO."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

#: lane kinds, in drawing order
KINDS = ("junction", "road", "bike", "sidewalk", "walkingarea", "crossing")


@dataclass(frozen=True)
class LaneShape:
    """One lane: id, kind (one of :data:`KINDS`), centre line (P, 2) [m], width [m]; a walking
    area's or junction's ``xy`` is its outline."""

    id: str
    kind: str
    xy: np.ndarray
    width: float


@dataclass(frozen=True)
class RoadMap:
    """lanes: every lane, crossing, walking area and junction outline; stop_lines: (M, 2, 2)
    segments [m] across the ends of the lanes entering a signalised junction."""

    lanes: tuple[LaneShape, ...]
    stop_lines: np.ndarray

    def window(self, x0: float, y0: float, x1: float, y1: float) -> RoadMap:
        """The lanes whose bounding box meets the box (x0, y0)-(x1, y1) grown by 20 m."""
        m = 20.0

        def inside(xy: np.ndarray) -> bool:
            lo, hi = xy.min(axis=0), xy.max(axis=0)
            return bool(lo[0] <= x1 + m and hi[0] >= x0 - m and lo[1] <= y1 + m and hi[1] >= y0 - m)

        stops = self.stop_lines[[inside(s) for s in self.stop_lines]] if len(self.stop_lines) else self.stop_lines
        return RoadMap(tuple(ln for ln in self.lanes if inside(ln.xy)), stops)


def _kind(function: str, permissions: set[str]) -> str:
    if function in ("crossing", "walkingarea"):
        return function
    if function == "internal":
        return "junction"
    if permissions and permissions <= {"pedestrian"}:
        return "sidewalk"
    if permissions and permissions <= {"bicycle"}:
        return "bike"
    return "road"


@lru_cache(maxsize=4)
def _read(path: str, mtime: float) -> RoadMap:
    import sumolib

    net = sumolib.net.readNet(path, withInternal=True, withPedestrianConnections=True)
    lanes: list[LaneShape] = []
    stops: list[np.ndarray] = []
    for node in net.getNodes():
        shape = node.getShape()
        if len(shape) >= 3:
            lanes.append(LaneShape(node.getID(), "junction", np.asarray(shape, dtype=float)[:, :2], 0.0))
    for edge in net.getEdges(withInternal=True):
        function = edge.getFunction() or ""
        signalised = edge.getToNode() is not None and "traffic_light" in (edge.getToNode().getType() or "")
        for lane in edge.getLanes():
            xy = np.asarray(lane.getShape(), dtype=float)[:, :2]
            if len(xy) < 2:
                continue
            kind = _kind(function, set(lane.getPermissions()))
            if kind == "junction" and function == "internal":
                continue  # junction outlines are drawn from the node shapes
            lanes.append(LaneShape(lane.getID(), kind, xy, float(lane.getWidth())))
            if signalised and function == "" and kind in ("road", "bike"):
                p, q = xy[-2], xy[-1]
                u = (q - p) / max(float(np.hypot(*(q - p))), 1e-9)
                n = np.array([-u[1], u[0]]) * lane.getWidth() / 2
                stops.append(np.stack([q - n, q + n]))
    order = {k: i for i, k in enumerate(KINDS)}
    lanes.sort(key=lambda ln: order[ln.kind])
    return RoadMap(tuple(lanes), np.array(stops).reshape(-1, 2, 2))


def read_road(net_file: Path) -> RoadMap:
    """The drawable road of a SUMO network file (cached per file and modification time)."""
    p = Path(net_file).resolve()
    return _read(str(p), p.stat().st_mtime)
