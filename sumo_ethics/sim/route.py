"""The ego's route as a reference path: lanes (with internal junction lanes) -> Polyline.

Lanes are chosen backwards from the route's end, so every chosen lane can still reach the
rest of the route (choosing the first link forwards breaks before turns; SUMO.md).
"""

from __future__ import annotations


import numpy as np

from sumo_ethics.errors import SimulationError
from sumo_ethics.contract import JunctionLink, RoutePath, TightBend
from sumo_ethics.geometry import Polyline, start_side
from sumo_ethics.sim.backend import sumo


def tight_bends(route: RoutePath, limit: float) -> list[TightBend]:
    """The stretches of ``route`` whose curvature (``Polyline.curvature_at`` at the path's
    vertices) exceeds ``limit`` [1/m] in magnitude, in order along the route; runs of
    consecutive vertices beyond the limit form one bend. Pure numpy, no simulator calls."""
    path = route.path
    k = path.curvature_at(path.s)
    over = np.abs(k) > limit
    if not over.any():
        return []
    edges = np.diff(np.r_[0, over.astype(np.int8), 0])
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    bends = []
    for i0, i1 in zip(starts, ends):  # one iteration per bend (a few per route)
        j = i0 + int(np.argmax(np.abs(k[i0:i1 + 1])))
        bends.append(TightBend(s_start=float(path.s[i0]), s_end=float(path.s[i1]), s=float(path.s[j]),
                               curvature=float(k[j]), lane=str(route.lane_of_vertex[j]),
                               x=float(path.xy[j, 0]), y=float(path.xy[j, 1])))
    return bends


def lane_allows(lane: str, vclass: str) -> bool:
    allowed = sumo.lane.getAllowed(lane)
    if allowed:
        return vclass in allowed
    return vclass not in sumo.lane.getDisallowed(lane)


def _lanes(edge: str) -> list[str]:
    return [f"{edge}_{i}" for i in range(sumo.edge.getLaneNumber(edge))]


def _leftwards(lanes: list[str]) -> int:
    """+1 where a higher lane index lies further left (SUMO's right-hand networks: lane 0 at the
    right kerb), -1 where it lies further right (``netconvert --lefthand``: lane 0 at the left
    kerb): the side of lane 1's first point from lane 0's first segment."""
    if len(lanes) < 2:
        return 1
    return 1 if start_side(sumo.lane.getShape(lanes[0]), sumo.lane.getShape(lanes[1])) >= 0.0 else -1


def _drivable(edge: str, lane: str, vclass: str) -> tuple[float, float]:
    """Lateral extent [m] (left > 0 > right) of the contiguous usable lanes of ``edge`` around ``lane``."""
    lanes = _lanes(edge) if not edge.startswith(":") else [lane]
    widths = [sumo.lane.getWidth(x) for x in lanes]
    usable = [lane_allows(x, vclass) for x in lanes]
    i = lanes.index(lane)
    step = _leftwards(lanes)  # the index step towards the left

    def extent(direction: int) -> float:
        total = widths[i] / 2
        j = i + direction
        while 0 <= j < len(lanes) and usable[j]:
            total += widths[j]
            j += direction
        return total

    return extent(step), -extent(-step)


def lane_change_shape(lane: str, target: str, start_xy: np.ndarray | None, length: float = 60.0) -> np.ndarray:
    """Centre line that moves from ``lane`` to the parallel ``target`` lane of the same edge.

    The blend (smoothstep) runs over ``length`` metres starting at the point of ``lane``
    nearest ``start_xy`` (or 10% into the lane), ending by 90% of the lane at the latest.
    """
    a = Polyline.from_points(np.asarray(sumo.lane.getShape(lane), dtype=float))
    b = Polyline.from_points(np.asarray(sumo.lane.getShape(target), dtype=float))
    n = max(len(a.s), len(b.s), int(np.ceil(a.length / 2.0)) + 1)
    f = np.linspace(0.0, 1.0, n)
    xa, ya, _ = a.to_xy(f * a.length, np.zeros(n))
    xb, yb, _ = b.to_xy(f * b.length, np.zeros(n))
    f0 = 0.1 if start_xy is None else float(np.clip(a.project(start_xy)[0] / a.length, 0.0, 0.9))
    f1 = min(max(f0 + length / a.length, f0 + 0.05), 1.0)
    u = np.clip((f - f0) / (f1 - f0), 0.0, 1.0)
    w = (u * u * (3.0 - 2.0 * u))[:, None]
    return (1.0 - w) * np.stack([xa, ya], axis=-1) + w * np.stack([xb, yb], axis=-1)


def smooth_path(raw: Polyline, spacing: float = 1.0, half_window: int = 2) -> tuple[Polyline, np.ndarray]:
    """Resample ``raw`` every ``spacing`` metres and smooth it with a moving average of
    2 * half_window + 1 points (ends kept), so that SUMO's coarse junction shapes do not give
    curvature spikes. Returns the new path and each new vertex's arc length on ``raw``."""
    n = max(int(np.ceil(raw.length / spacing)), 1) + 1
    s = np.linspace(0.0, raw.length, n)
    x, y, _ = raw.to_xy(s, np.zeros(n))
    pts = np.stack([x, y], axis=-1)
    if n > 2 * half_window + 1:
        kernel = np.ones(2 * half_window + 1) / (2 * half_window + 1)
        padded = np.concatenate([np.repeat(pts[:1], half_window, 0), pts, np.repeat(pts[-1:], half_window, 0)])
        sm = np.stack([np.convolve(padded[:, i], kernel, mode="valid") for i in (0, 1)], axis=-1)
        sm[0], sm[-1] = pts[0], pts[-1]
        pts = sm
    return Polyline.from_points(pts), s


def build_route_path(edges: tuple[str, ...], start_lane: str, vclass: str,
                     start_xy: np.ndarray | None = None, target_lanes: frozenset[str] = frozenset()) -> RoutePath:
    """Lane-level reference path for ``edges`` starting from the ego's current lane.

    Lane changes the route needs (an acceleration lane, a turn from another lane) become a
    smooth blend between the two lane centre lines along the edge. ``target_lanes``: on an edge
    with some of these lanes (that lead on along the route), the path takes one of them (an
    imported CommonRoad scenario's goal lanes).
    """
    edges = tuple(e for e in edges if not e.startswith(":"))
    if not edges:
        raise SimulationError("the ego's route has no edges")
    usable = [[ln for ln in _lanes(e) if lane_allows(ln, vclass)] for e in edges]
    # exits[i]: lanes of edge i with a connection to edge i + 1 (any lane of the last edge);
    # the other usable lanes of an edge reach an exit by changing lanes along it
    exits: list[list[str]] = [[] for _ in edges]
    exits[-1] = usable[-1]
    for i in range(len(edges) - 1):
        nxt = set(usable[i + 1])
        exits[i] = [ln for ln in usable[i] if any(lk[0] in nxt for lk in sumo.lane.getLinks(ln))]
        if not exits[i]:
            raise SimulationError(f"the ego's route is not drivable: no lane of {edges[i]} leads to {edges[i + 1]}")
    if target_lanes:
        exits = [[ln for ln in ex if ln in target_lanes] or ex for ex in exits]

    def index(lane_id: str) -> int:
        return int(lane_id.rsplit("_", 1)[1])

    lane = start_lane if start_lane in usable[0] else exits[0][0]

    pts: list[np.ndarray] = []
    lane_ids: list[str] = []
    vmax: list[float] = []
    bounds: list[tuple[float, float]] = []
    link_at: list[tuple[int, str, int]] = []  # (vertex index of the stop line, lane, link index)

    def add(lane_id: str, edge_id: str, shape: np.ndarray | None = None) -> None:
        shape = np.asarray(sumo.lane.getShape(lane_id), dtype=float) if shape is None else shape
        pts.append(shape)
        lane_ids.extend([lane_id] * len(shape))
        vmax.extend([sumo.lane.getMaxSpeed(lane_id)] * len(shape))
        bounds.extend([_drivable(edge_id, lane_id, vclass)] * len(shape))

    for i, edge in enumerate(edges):
        target = lane if lane in exits[i] else min(exits[i], key=lambda x: abs(index(x) - index(lane)))
        if target == lane:
            add(lane, edge)
        else:
            add(target, edge, lane_change_shape(lane, target, start_xy if i == 0 else None))
        lane = target
        if i + 1 == len(edges):
            break
        lane_links = sumo.lane.getLinks(lane)
        choices = [(j, lk) for j, lk in enumerate(lane_links) if lk[0] in usable[i + 1]]
        j, link = min(choices, key=lambda c: c[1][0] not in exits[i + 1])  # prefer no further lane change
        link_at.append((len(lane_ids) - 1, lane, j))
        via = link[4]
        while via and via.startswith(":"):
            add(via, via)
            nxt = sumo.lane.getLinks(via)
            via = (nxt[0][4] or nxt[0][0]) if nxt else ""
        lane = link[0]

    xy = np.vstack(pts)
    keep = np.ones(len(xy), dtype=bool)
    keep[1:] = np.hypot(*np.diff(xy, axis=0).T) > 1e-6
    # a lane's first point repeats the previous lane's last one and is dropped; the point kept
    # there starts the new lane's first segment, so it takes the new lane's label and values
    for j in np.flatnonzero(~keep)[::-1]:
        lane_ids[j - 1], vmax[j - 1], bounds[j - 1] = lane_ids[j], vmax[j], bounds[j]
    raw = Polyline.from_points(xy[keep])
    path, raw_s = smooth_path(raw)
    vertex = np.clip(np.searchsorted(raw.s, raw_s, side="right") - 1, 0, len(raw.s) - 1)  # raw vertex per new one
    new_index = np.cumsum(keep) - 1  # raw vertex index after dropping duplicates
    links = [JunctionLink(s=float(np.interp(raw.s[new_index[v]], raw_s, path.s)), lane=ln, index=j)
             for v, ln, j in link_at]
    lb = np.asarray(bounds)[keep][vertex]
    # the lanes' own str objects, shared by their vertices: a numpy array's items would be one new
    # numpy.str_ per vertex (some 2,500 objects, 150 kB, per urban_grid route, as long as its ego drives)
    lane_of_vertex = tuple(lane_ids[i] for i in np.flatnonzero(keep)[vertex])
    return RoutePath(
        edges=edges,
        path=path,
        lane_of_vertex=lane_of_vertex,
        speed_limit=np.asarray(vmax)[keep][vertex],
        left=lb[:, 0],
        right=lb[:, 1],
        links=tuple(links),
    )
