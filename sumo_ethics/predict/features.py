"""Feature layout shared by the dataset builder and the predictor (numpy only, no torch).

Everything a model sees is built here, once, so training data and run-time inputs
cannot drift apart.

Layout (FEATURE_VERSION 1):

- Model rate ``MODEL_DT`` = 0.2 s (5 Hz). SUMO data at 10 Hz are subsampled; a run-time
  history at any other spacing is linearly interpolated onto this grid.
- History: ``HIST_STEPS`` = 16 positions at t = -3.0, -2.8, ..., 0 s (3 s, the last one is now).
- Horizon: ``FUT_STEPS`` = 20 positions at t = 0.2 ... 4.0 s (4 s, as Wale-Net).
- Frame: every sequence (the target's and its neighbours') is expressed in the target's
  own frame: translated to the target's current centre and rotated by minus its yaw, so
  +x is the target's heading. Models are therefore rotation and translation invariant.
- Missing history (agent seen for less than 3 s) is filled by extrapolating backwards at
  the velocity of the first two valid samples (standing still if only one is valid).
- Agent class enters as one of three groups (``GROUP_*``): vehicle (car, truck, bus,
  motorcycle, other), cyclist (bicycle), pedestrian.
- Social grid: 13 (longitudinal) x 3 (lateral) cells centred on the target, as CS-LSTM.
  The cell size depends on the TARGET's group (``GRID_CELL``): vehicles 4.6 m x 3.6 m
  (about 15 ft by one lane, +/-30 m ahead/behind, one lane left/right), cyclists
  3.0 m x 2.5 m (+/-19.5 m x +/-3.75 m), pedestrians 1.5 m x 2.0 m (+/-9.75 m x +/-3 m:
  a sidewalk and the kerb lane). Neighbours of any class fill the grid; when several
  fall in one cell the one nearest to the target is kept; the target itself never is.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from sumo_ethics.geometry import start_side, wrap_angle
from sumo_ethics.types import RoadUserClass

FEATURE_VERSION = 1
MODEL_DT = 0.2
HIST_STEPS = 16
FUT_STEPS = 20
GRID_LON = 13
GRID_LAT = 3
N_CELLS = GRID_LON * GRID_LAT

GROUP_VEHICLE, GROUP_CYCLIST, GROUP_PEDESTRIAN = 0, 1, 2
N_GROUPS = 3
GROUP_NAMES = ("vehicle", "cyclist", "pedestrian")

#: RoadUserClass value -> group index
CLASS_TO_GROUP = np.array(
    [
        GROUP_VEHICLE,  # CAR
        GROUP_VEHICLE,  # TRUCK
        GROUP_VEHICLE,  # BUS
        GROUP_VEHICLE,  # MOTORCYCLE
        GROUP_CYCLIST,  # BICYCLE
        GROUP_PEDESTRIAN,  # PEDESTRIAN
        GROUP_VEHICLE,  # OTHER
    ],
    dtype=np.int64,
)
assert len(CLASS_TO_GROUP) == len(RoadUserClass)

#: (N_GROUPS, 2) cell size [m] (longitudinal, lateral) of the target's social grid
GRID_CELL = np.array([[4.6, 3.6], [3.0, 2.5], [1.5, 2.0]])

#: (N_GROUPS,) position normalisation [m] by the target's group (model inputs/outputs / scale)
POS_SCALE = np.array([10.0, 5.0, 2.0])


def class_group(cls: np.ndarray) -> np.ndarray:
    """(N,) RoadUserClass ints -> (N,) group indices."""
    return CLASS_TO_GROUP[np.asarray(cls, dtype=np.int64)]


def backfill(hist: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Fill invalid history steps by linear extrapolation of the first valid ones.

    hist: (N, H, 2), valid: (N, H) bool with the valid samples forming a suffix that
    includes the last step (agents appear, then stay). Invalid steps after the first
    valid one are filled by linear interpolation. Returns a new (N, H, 2) array.
    """
    hist = np.array(hist, dtype=float, copy=True)
    valid = np.asarray(valid, dtype=bool)
    n, h, _ = hist.shape
    if n == 0:
        return hist
    steps = np.arange(h)
    for i in np.flatnonzero(~valid.all(axis=1)):
        idx = np.flatnonzero(valid[i])
        if idx.size == 0:
            hist[i] = 0.0
            continue
        if idx.size == 1:
            hist[i] = hist[i, idx[0]]
            continue
        first, second = idx[0], idx[1]
        vel = (hist[i, second] - hist[i, first]) / (second - first)
        for d in range(2):
            hist[i, :, d] = np.interp(steps, idx, hist[i, idx, d])
        before = steps < first
        hist[i, before] = hist[i, first] + (steps[before] - first)[:, None] * vel
    return hist


def resample_history(hist: np.ndarray, valid: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(N, H, 2) history at spacing ``dt`` (last = now) -> (N, HIST_STEPS, 2) at MODEL_DT.

    Linear interpolation in time; model steps older than an agent's first valid sample
    are extrapolated backwards (see :func:`backfill`). Returns (hist, valid) where valid
    marks model steps covered by observations.
    """
    hist = np.asarray(hist, dtype=float)
    valid = np.asarray(valid, dtype=bool)
    n, h, _ = hist.shape
    t_obs = (np.arange(h) - (h - 1)) * float(dt)
    t_mod = (np.arange(HIST_STEPS) - (HIST_STEPS - 1)) * MODEL_DT
    if h == HIST_STEPS and abs(dt - MODEL_DT) < 1e-9:
        return backfill(hist, valid), valid.copy()
    out = np.zeros((n, HIST_STEPS, 2))
    out_valid = np.zeros((n, HIST_STEPS), dtype=bool)
    full = valid.all(axis=1)
    if full.any() and h >= 2:
        # all samples valid: one vectorised interpolation (extrapolating linearly before the oldest)
        q = (t_mod - t_obs[0]) / float(dt)
        i0 = np.clip(np.floor(q).astype(int), 0, h - 2)
        w = (q - i0)[None, :, None]
        hf = hist[full]
        out[full] = hf[:, i0] * (1.0 - w) + hf[:, i0 + 1] * w
        out_valid[full] = t_mod >= t_obs[0] - 1e-9
    for i in np.flatnonzero(~full if h >= 2 else np.ones(n, dtype=bool)):
        idx = np.flatnonzero(valid[i])
        if idx.size == 0:
            continue
        ts = t_obs[idx]
        covered = (t_mod >= ts[0] - 1e-9) & (t_mod <= ts[-1] + 1e-9)
        out_valid[i] = covered
        if idx.size == 1:
            out[i] = hist[i, idx[0]]
            continue
        for d in range(2):
            out[i, :, d] = np.interp(t_mod, ts, hist[i, idx, d])
        early = t_mod < ts[0]
        vel = (hist[i, idx[1]] - hist[i, idx[0]]) / (ts[1] - ts[0])
        out[i, early] = hist[i, idx[0]] + (t_mod[early] - ts[0])[:, None] * vel
        late = t_mod > ts[-1]  # observation older than now: hold the last sample
        out[i, late] = hist[i, idx[-1]]
    return out, out_valid


def rotation(yaw: np.ndarray) -> np.ndarray:
    """(N,) yaw -> (N, 2, 2) rotation matrices R(yaw) (target frame -> world)."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def to_target_frame(points: np.ndarray, origin: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """World points (N, ..., 2) -> frame of target n (origin (N, 2), yaw (N,))."""
    c, s = np.cos(yaw), np.sin(yaw)
    shape = (-1,) + (1,) * (points.ndim - 2)
    dx = points[..., 0] - origin[:, 0].reshape(shape)
    dy = points[..., 1] - origin[:, 1].reshape(shape)
    c, s = c.reshape(shape), s.reshape(shape)
    return np.stack([c * dx + s * dy, -s * dx + c * dy], axis=-1)


def build_features(
    hist: np.ndarray,
    cls: np.ndarray,
    yaw: np.ndarray,
    targets: np.ndarray | None = None,
    histories: bool = True,
) -> dict[str, np.ndarray]:
    """Model inputs for ``targets`` among M agents with (backfilled) histories at MODEL_DT.

    hist: (M, HIST_STEPS, 2) world centre positions, last = now; cls: (M,) RoadUserClass;
    yaw: (M,) current yaw; targets: (N,) indices into the M agents (default: all).

    Returns float32/int64 arrays:
    ``tgt_hist`` (N, H, 2) target history in its own frame [m]; ``tgt_group`` (N,);
    ``nbr_hist`` (P, H, 2) neighbour histories in their target's frame [m];
    ``nbr_group`` (P,); ``nbr_batch`` (P,) target row of each neighbour;
    ``nbr_cell`` (P,) grid cell = lon_index * GRID_LAT + lat_index; ``nbr_agent`` (P,);
    ``nbr_yaw`` (P,) the neighbour's yaw in its target's frame [rad, wrapped] and ``nbr_pos``
    (P, 2) its position there now [m] (``nbr_hist[:, -1]``; both read by models that encode every
    agent once in its own frame, ``nbr_frame="agent"``, whose run time needs no ``tgt_hist`` and
    ``nbr_hist``: ``histories=False`` leaves them out).
    """
    hist = np.asarray(hist, dtype=float)
    m = hist.shape[0]
    targets = np.arange(m) if targets is None else np.asarray(targets, dtype=np.int64)
    groups = class_group(cls)
    now = hist[:, -1, :]
    origin = now[targets]
    tyaw = np.asarray(yaw, dtype=float)[targets]
    n = len(targets)
    # current positions of every agent in every target's frame: (N, M, 2)
    rel = to_target_frame(np.broadcast_to(now, (n, m, 2)), origin, tyaw)
    cell = GRID_CELL[groups[targets]]  # (N, 2)
    li = np.floor(rel[..., 0] / cell[:, None, 0] + GRID_LON / 2).astype(np.int64)
    lj = np.floor(rel[..., 1] / cell[:, None, 1] + GRID_LAT / 2).astype(np.int64)
    inside = (li >= 0) & (li < GRID_LON) & (lj >= 0) & (lj < GRID_LAT)
    inside[np.arange(n), targets] = False
    ti, ai = np.nonzero(inside)
    cells = li[ti, ai] * GRID_LAT + lj[ti, ai]
    dist = np.hypot(rel[ti, ai, 0], rel[ti, ai, 1])
    # nearest neighbour per (target, cell): sort by (target, cell, distance), keep first
    order = np.lexsort((dist, cells, ti))
    ti, ai, cells = ti[order], ai[order], cells[order]
    key = ti * N_CELLS + cells
    keep = np.ones(len(key), dtype=bool)
    keep[1:] = key[1:] != key[:-1]
    ti, ai, cells = ti[keep], ai[keep], cells[keep]
    out = {
        "tgt_group": groups[targets].astype(np.int64),
        "nbr_group": groups[ai].astype(np.int64),
        "nbr_batch": ti.astype(np.int64),
        "nbr_cell": cells.astype(np.int64),
        "nbr_agent": ai.astype(np.int64),
        "nbr_yaw": wrap_angle(np.asarray(yaw, dtype=float)[ai] - tyaw[ti]).astype(np.float32),
        "nbr_pos": rel[ti, ai].astype(np.float32),  # the same arithmetic as nbr_hist's last point
    }
    if histories:
        out["tgt_hist"] = to_target_frame(hist[targets], origin, tyaw).astype(np.float32)
        out["nbr_hist"] = to_target_frame(hist[ai], origin[ti], tyaw[ti]).astype(np.float32)
    return out


def own_frame(hist: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """(M, H, 2) histories, (M,) yaw -> (M, H, 2) each in its own frame (origin now, +x its heading)."""
    return to_target_frame(hist, hist[:, -1], yaw)


# ---------------------------------------------------------------------------------------------
# Map and signal context (MAP_VERSION 4), for the map-aware models (kinds "map", "map_cslstm")
#
# For each vehicle or cyclist on a lane:
#
# - ``map_pts`` (N, MAP_LANES, MAP_POINTS, 2): centre lines of the lanes it may take next, in
#   the target's frame [m]. Rows 0..MAP_AHEAD-1: the paths through its current lane and its
#   successors (internal junction lanes included, in SUMO's link order, depth first), one row
#   per branch; row MAP_AHEAD: the lane to its left, row MAP_AHEAD + 1: the lane to its right
#   (same edge, each followed through its first successors). Every row is sampled at arc
#   lengths pos + k * ds, k = 0..MAP_POINTS-1 from the target's lane position, with
#   ``ds = max(MAP_DS_MIN, MAP_DS_PER_SPEED * speed)`` (2.5 m at rest, 0.5 s of travel at
#   speed: 9 ds = 4.5 s, the 4 s horizon's reach plus a margin); a path that ends (a dead
#   end) repeats its last point.
# - ``map_valid`` (N, MAP_LANES) bool: which rows exist; ``map_kind`` (N, MAP_LANES):
#   0 ahead, 1 left, 2 right.
# - ``map_scalar`` (N, MAP_SCALARS): [on a lane, a traffic light ahead, its stop-line
#   distance / 50 m clipped to [0, 2], green, yellow, red (one-hot of its link state),
#   speed limit of the lane / 30 m/s].
#
# For each pedestrian on a walking lane (new in MAP_VERSION 2; version 1 gave them nothing):
# sidewalks and crossings have no direction of travel, so a pedestrian's rows follow its
# heading, and a walking area (a junction's patch of pavement) has no centre line at all.
#
# - Row 0: its current sidewalk or crossing from its position, in the direction of the lane
#   it faces (the lane's shape reversed when its heading is more than 90 degrees off the
#   lane's); on a walking area: the next lane of its walk (below) from the end nearer to it.
# - Row 1: the next lane of its walk (``MapContext.next_lane``, SUMO's next edge of the
#   walk), from the end nearer to it, when it is on a sidewalk or crossing.
# - Points ``MAP_DS_PERSON`` = 1 m apart (9 m: 4 s at a brisk walk plus a margin).
# - Scalars: [on a lane, a signalised crossing ahead (the one it is on or the next one of
#   its walk), the distance to it / 50 m, green, yellow, red, 0]: the walking-lane speed
#   limit is the road's, so it is left 0. Whether the light of the crossing it waits at is
#   red is what tells a pedestrian who will stay from one who will walk off.
#
# Version 3 adds scalar 7 for vehicles and pedestrians alike: how long the light's current
# state holds, from its program (the time to the light's next switch plus the durations of the
# following phases in which this link keeps its colour) / 10 s, clipped to [0, 2]; 2 when no
# phase changes it, 0 without a light. Whether a pedestrian waiting at red walks off within the
# horizon depends on when the light turns green, which the colour alone does not tell.
#
# Version 4 adds, for vehicles, scalars 8 and 9: the left and the right blinker (SUMO's
# ``vehicle.getSignals`` bits 1 and 0; the hazard flasher, bit 2, lights both). A vehicle that
# will turn at the junction ahead shows it (99-100 % within 50 m of the lane's end on the
# bundled urban scenario, ``tools/blinker_check.py``) and slows for the turn; one going straight
# shows nothing and keeps its speed through a green light. For pedestrians it adds row 2: when
# the next lane of its walk is a walking area (which has no row), the lane after it toward the
# walk's next sidewalk (a crossing, or that sidewalk; ``MapContext.after_lane``), from the end
# nearer to it. Models of earlier versions see neither (``models.batch_to_tensors``).
#
# Version 5 changes row 0 of a pedestrian on a walking area: the straight walk from its position to
# the next lane's nearer end, then along that lane (before: that lane alone, from its nearer end).
# On the small walking areas of the bundled networks the two differ little, since a pedestrian
# there is within a metre or two of the next lane; on a city junction from OSM a walking area
# spans 15 m or more, and a row that starts far ahead and off to the side made the models predict
# the pedestrian would stop. Datasets keep the earlier row 0 as well (``map_row0_v4``), so that a
# model of versions 2-4 reads its own inputs from a version-5 dataset (``models.batch_to_tensors``).
MAP_VERSION = 5
#: map versions this code can build (version 1: pedestrians get no map context; version 2: no
#: time to the light's switch, 7 scalars; version 3: no blinkers and no lane after a walking area;
#: version 4: a walking-area pedestrian's row 0 starts at the next lane)
MAP_VERSIONS = (1, 2, 3, 4, 5)
MAP_AHEAD = 4
MAP_LANES = MAP_AHEAD + 2
MAP_POINTS = 10
MAP_DS_MIN = 2.5
MAP_DS_PER_SPEED = 0.5
MAP_DS_PERSON = 1.0
MAP_SCALARS = 10
#: the row of a pedestrian's lane after a walking area (version 4)
MAP_ROW_AFTER = 2
#: ``MapContext.blinker`` bits (SUMO's vehicle signals): right blinker, left blinker, hazard flasher
BLINKER_RIGHT, BLINKER_LEFT, BLINKER_EMERGENCY = 1, 2, 4
MAP_KIND_AHEAD, MAP_KIND_LEFT, MAP_KIND_RIGHT = 0, 1, 2
TLS_DIST_SCALE = 50.0
TLS_SWITCH_SCALE = 10.0
SPEED_SCALE = 30.0
#: link state character -> 0 none/off, 1 green, 2 yellow, 3 red
TLS_CODES = {"G": 1, "g": 1, "s": 1, "y": 2, "Y": 2, "u": 2, "r": 3, "R": 3}


def map_scalars(version: int) -> int:
    """Number of map scalars of a map version (7 before version 3, 8 in version 3, then 10)."""
    return MAP_SCALARS if version >= 4 else 8 if version == 3 else 7


WALKING_AREA = re.compile(r":.+_w\d+_0")


class LaneGraph:
    """Lanes of a network as plain arrays: centre lines, speed limits, successors, neighbours.

    ids: lane ids; shapes: (P_i, 2) centre lines [m]; speed: (L,) limits [m/s];
    succ: per lane the ids it leads to (via internal lanes, as SUMO links them); lengths:
    SUMO's lane lengths (positions along a lane are scaled onto its shape's arc length).
    """

    def __init__(self, ids, shapes, speed, succ, left, right, lengths) -> None:
        self.ids = tuple(ids)
        self.index = {k: i for i, k in enumerate(self.ids)}
        self.shapes = [np.asarray(s, dtype=float) for s in shapes]
        self.cum = [np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(s, axis=0).T))]) for s in self.shapes]
        self.speed = np.asarray(speed, dtype=float)
        self.succ = tuple(tuple(s) for s in succ)
        self.left = np.asarray(left, dtype=np.int64)
        self.right = np.asarray(right, dtype=np.int64)
        self.lengths = np.asarray(lengths, dtype=float)
        self._poly: dict[tuple[int, ...], tuple[np.ndarray, np.ndarray]] = {}
        self._rev: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def __getstate__(self) -> dict:
        """Pickled without the caches of sim.lanes.after_walking_area and sim.lanes.pavement (an
        answer of that code as it was must not come back with a lane graph stored in a dataset)."""
        return {k: v for k, v in self.__dict__.items() if k not in ("_after", "_walk_adj", "_pavement")}

    def to_dict(self) -> dict:
        """The graph as plain JSON values (no caches); :meth:`from_dict` gives it back exactly
        (Python writes floats with their shortest round-trip repr)."""
        return {"ids": list(self.ids), "shapes": [s.tolist() for s in self.shapes], "speed": self.speed.tolist(),
                "succ": [list(s) for s in self.succ], "left": self.left.tolist(), "right": self.right.tolist(),
                "lengths": self.lengths.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> "LaneGraph":
        """Inverse of :meth:`to_dict`; ValueError when a field is missing or the lanes disagree."""
        try:
            ids, shapes = d["ids"], [np.asarray(s, dtype=float).reshape(-1, 2) for s in d["shapes"]]
            fields = (d["speed"], d["succ"], d["left"], d["right"], d["lengths"])
        except (KeyError, TypeError) as exc:
            raise ValueError(f"not a lane graph ({type(exc).__name__}: {exc})") from None
        if any(len(f) != len(ids) for f in (shapes, *fields)):
            raise ValueError("not a lane graph (its per-lane fields differ in length)")
        return cls(ids, shapes, *fields)

    @classmethod
    def build(cls, ids, shapes, speed, links, lengths=None) -> "LaneGraph":
        """From lane ids, shapes, limits and successor ids; lane ``edge_i``'s left neighbour is
        ``edge_{i+1}``, its right one ``edge_{i-1}`` where SUMO numbers the lanes from the right (its
        right-hand networks), the other way round where ``edge_{i+1}`` lies to the right of
        ``edge_i`` (``netconvert --lefthand`` numbers them from the left)."""
        ids = tuple(ids)
        index = {k: i for i, k in enumerate(ids)}
        succ = [tuple(index[s] for s in nxt if s in index) for nxt in links]
        left, right = np.full(len(ids), -1), np.full(len(ids), -1)
        for i, k in enumerate(ids):
            edge, _, num = k.rpartition("_")
            if k.startswith(":") or not edge or not num.isdigit():
                continue
            up, down = index.get(f"{edge}_{int(num) + 1}", -1), index.get(f"{edge}_{int(num) - 1}", -1)
            if (up >= 0 or down >= 0) and _right_of(shapes[i], shapes[up] if up >= 0 else shapes[down], up < 0):
                up, down = down, up  # numbered from the left
            left[i], right[i] = up, down
        if lengths is None:
            lengths = [float(np.hypot(*np.diff(np.asarray(s, dtype=float), axis=0).T).sum()) for s in shapes]
        return cls(ids, shapes, speed, succ, left, right, lengths)

    def shape_pos(self, lane: int, pos: float) -> float:
        """SUMO lane position -> arc length along the lane's shape [m]."""
        geo = self.cum[lane][-1]
        length = self.lengths[lane]
        return float(pos) * geo / length if length > 1e-9 else 0.0

    def paths(self, lane: int, start: float, reach: float, limit: int) -> list[tuple[int, ...]]:
        """Up to ``limit`` lane sequences from ``lane`` (arc length ``start`` on it) covering
        ``reach`` metres, depth first in link order; dead ends end a path early."""
        left0 = reach - (self.cum[lane][-1] - start)
        if limit < 1:
            return []
        if left0 <= 0.0 or not self.succ[lane]:  # the common case: the reach ends on this lane
            return [(lane,)]
        out: list[tuple[int, ...]] = []

        def walk(path: tuple[int, ...], left: float) -> None:
            if len(out) >= limit:
                return
            nxt = self.succ[path[-1]]
            if left <= 0.0 or not nxt or len(path) >= 12:
                out.append(path)
                return
            for j in nxt:
                walk(path + (j,), left - self.cum[j][-1])

        walk((lane,), left0)
        return out

    def first_path(self, lane: int, start: float, reach: float) -> tuple[int, ...]:
        return self.paths(lane, start, reach, 1)[0]

    def is_walking_area(self, lane: int) -> bool:
        """A junction's walking area (SUMO id ``:<junction>_w<k>_0``): a patch of pavement, no centre line."""
        return WALKING_AREA.fullmatch(self.ids[lane]) is not None

    def facing(self, lane: int, start: float, yaw: float) -> tuple[tuple[np.ndarray, np.ndarray], float]:
        """A lane's centre line (points, arc lengths) and the arc length ``start`` on it, both
        reversed when ``yaw`` [rad] is more than 90 degrees off the lane's direction there
        (pedestrians walk sidewalks and crossings either way)."""
        pts, cum = self.polyline((lane,))
        if len(pts) < 2:
            return (pts, cum), start
        k = int(np.clip(np.searchsorted(cum, start, side="right") - 1, 0, len(pts) - 2))
        d = pts[k + 1] - pts[k]
        if d[0] * np.cos(yaw) + d[1] * np.sin(yaw) >= 0.0:
            return (pts, cum), start
        return self.reversed_line(lane), float(cum[-1] - start)

    def from_nearer_end(self, lane: int, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A lane's centre line (points, arc lengths) starting at its end nearer to ``xy``."""
        pts, cum = self.polyline((lane,))
        if np.hypot(*(pts[-1] - xy)) < np.hypot(*(pts[0] - xy)):
            return self.reversed_line(lane)
        return pts, cum

    def reversed_line(self, lane: int) -> tuple[np.ndarray, np.ndarray]:
        """A lane's centre line from its end to its start (points, arc lengths), cached."""
        rev = self.__dict__.setdefault("_rev", {})  # lane graphs pickled before this have no _rev
        if lane not in rev:
            pts, cum = self.polyline((lane,))
            rev[lane] = (pts[::-1].copy(), cum[-1] - cum[::-1])
        return rev[lane]

    def polyline(self, path: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
        """Concatenated centre line (P, 2) of a lane sequence and its arc lengths (P,)."""
        got = self._poly.get(path)
        if got is None:
            pts = [self.shapes[path[0]]]
            for j in path[1:]:
                s = self.shapes[j]
                pts.append(s[1:] if np.hypot(*(s[0] - pts[-1][-1])) < 1e-6 else s)
            p = np.concatenate(pts)
            cum = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(p, axis=0).T))]) if len(p) > 1 else np.zeros(1)
            got = self._poly[path] = (p, cum)
        return got


@dataclass(frozen=True)
class MapContext:
    """Per agent (N,): lane index into a LaneGraph (-1 none), position of its centre along that
    lane [m, SUMO's lane length units], distance to the next traffic light's stop line [m]
    (inf: none) and its state (TLS_CODES value); for a pedestrian the light is that of the
    signalised crossing it is on or walks to next, the distance the one to that crossing.
    person: (N,) bool, pedestrians (None: none); next_lane: (N,) the next lane of a
    pedestrian's walk (-1 none; None: none for all); tls_switch: (N,) how long that light's
    state holds [s] (inf: no change in its program, or unknown; None: unknown for all);
    blinker: (N,) a vehicle's signal bits (BLINKER_RIGHT | BLINKER_LEFT | BLINKER_EMERGENCY; None:
    none lit); after_lane: (N,) for a pedestrian whose next lane is a walking area, the lane after
    it toward the walk's next sidewalk (-1 none; None: none for all)."""

    lane: np.ndarray
    lane_pos: np.ndarray
    tls_dist: np.ndarray
    tls_state: np.ndarray
    person: np.ndarray | None = None
    next_lane: np.ndarray | None = None
    tls_switch: np.ndarray | None = None
    blinker: np.ndarray | None = None
    after_lane: np.ndarray | None = None

    @staticmethod
    def empty(n: int) -> "MapContext":
        return MapContext(np.full(n, -1, dtype=np.int64), np.zeros(n), np.full(n, np.inf), np.zeros(n, dtype=np.int64),
                          np.zeros(n, dtype=bool), np.full(n, -1, dtype=np.int64), np.full(n, np.inf),
                          np.zeros(n, dtype=np.int64), np.full(n, -1, dtype=np.int64))


def _right_of(lane: np.ndarray, other: np.ndarray, lower: bool) -> bool:
    """Whether the lanes of this edge are numbered from the left: ``other`` (the lane numbered one
    above ``lane``, or one below where ``lower``) starts to the right of ``lane``'s first segment
    (one below: to its left)."""
    cross = start_side(lane, other)
    return cross > 0.0 if lower else cross < 0.0


def sample_path(graph: LaneGraph, path: tuple[int, ...], start: float, ds: float) -> np.ndarray:
    """(MAP_POINTS, 2) world points at arc lengths start + k ds along ``path``."""
    pts, cum = graph.polyline(path)
    s = start + np.arange(MAP_POINTS) * ds
    return np.stack([np.interp(s, cum, pts[:, 0]), np.interp(s, cum, pts[:, 1])], -1)


def _sample_many(lines: Sequence[tuple[np.ndarray, np.ndarray]], s: np.ndarray) -> np.ndarray:
    """Points at arc lengths s (R, K) along R polylines (pts (P_r, 2), cum (P_r,)), held at
    the ends: :func:`sample_path` for all rows in one vectorised pass."""
    r = len(lines)
    lens = np.array([len(c) for _, c in lines])
    first = np.concatenate([[0], np.cumsum(lens)[:-1]])
    big = 1e7 * np.arange(r)  # rows apart on one axis, so one searchsorted serves all
    cum = np.concatenate([c for _, c in lines]) + np.repeat(big, lens)
    pts = np.concatenate([p for p, _ in lines])
    ends = np.array([c[-1] for _, c in lines])
    q = np.clip(s, 0.0, ends[:, None]) + big[:, None]
    i = np.searchsorted(cum, q, side="right") - 1
    i = np.clip(i, first[:, None], np.maximum(first + lens - 2, first)[:, None])
    j = np.minimum(i + 1, (first + lens - 1)[:, None])
    span = cum[j] - cum[i]
    w = np.where(span > 0, (q - cum[i]) / np.where(span > 0, span, 1.0), 0.0)
    w = np.clip(w, 0.0, 1.0)[..., None]
    return pts[i] * (1.0 - w) + pts[j] * w


def _signal_scalars(out: np.ndarray, rows: np.ndarray, tls_dist: np.ndarray, tls_state: np.ndarray,
                    tls_switch: np.ndarray) -> None:
    """Scalars 0-5 and 7 (see the layout above) of the targets ``rows`` (on a lane), written into
    ``out`` (N, MAP_SCALARS); tls_dist, tls_state, tls_switch (N,) as in MapContext."""
    out[rows, 0] = 1.0
    dist = np.asarray(tls_dist, dtype=float)[rows]
    lit = rows[np.isfinite(dist)]
    out[lit, 1] = 1.0
    out[lit, 2] = np.clip(dist[np.isfinite(dist)] / TLS_DIST_SCALE, 0.0, 2.0)
    code = np.asarray(tls_state)[lit].astype(np.int64)
    out[lit[code > 0], 2 + code[code > 0]] = 1.0
    out[lit, 7] = np.clip(np.asarray(tls_switch, dtype=float)[lit] / TLS_SWITCH_SCALE, 0.0, 2.0)


def _walk_lines(graph: LaneGraph, lane: int, lane_pos: float, next_lane: int, xy: np.ndarray,
                yaw: float, after_lane: int = -1) -> list[tuple[int, tuple[np.ndarray, np.ndarray], float]]:
    """A pedestrian's rows (see the layout above): (row, centre line, arc length to start at)
    each; ``after_lane`` >= 0 (version 4) fills row MAP_ROW_AFTER."""
    out = []
    if not graph.is_walking_area(lane):
        line, s0 = graph.facing(lane, graph.shape_pos(lane, lane_pos), yaw)
        out.append((0, line, s0))
    if next_lane >= 0 and next_lane != lane and not graph.is_walking_area(next_lane):
        out.append((len(out), graph.from_nearer_end(next_lane, xy), 0.0))
    if after_lane >= 0 and after_lane != lane and not graph.is_walking_area(after_lane):
        out.append((MAP_ROW_AFTER, graph.from_nearer_end(after_lane, xy), 0.0))
    return out


def walk_across(graph: LaneGraph, next_lane: int, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row 0 of a pedestrian on a walking area (version 5): the straight line from ``xy`` (2,) [m] to
    the nearer end of ``next_lane``, then that lane's centre line (points (P + 1, 2), arc lengths)."""
    pts, cum = graph.from_nearer_end(next_lane, xy)
    gap = float(np.hypot(pts[0, 0] - xy[0], pts[0, 1] - xy[1]))
    return np.vstack([np.asarray(xy, dtype=float)[None], pts]), np.concatenate([[0.0], cum + gap])


def map_features(graph: LaneGraph | None, ctx: MapContext, xy: np.ndarray, yaw: np.ndarray,
                 speed: np.ndarray, version: int = MAP_VERSION) -> dict[str, np.ndarray]:
    """Map inputs of N targets (see the layout above): map_pts, map_valid, map_kind, map_scalar.

    xy (N, 2), yaw (N,), speed (N,): the targets' current centre, heading and speed; ctx:
    their lanes and signals. Targets without a lane (or without a graph) get all rows invalid
    and zero scalars, and so do pedestrians for ``version`` 1 (the features of models trained
    before pedestrians had map context); each version gets its own scalars only
    (:func:`map_scalars`), and before version 4 no blinkers and no pedestrian row MAP_ROW_AFTER.
    From version 5 on, row 0 of a pedestrian on a walking area is :func:`walk_across`, and the
    result also holds ``map_row0_v4`` (N, MAP_POINTS, 2): row 0 as versions 2-4 build it.
    """
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    n = len(xy)
    pts = np.zeros((n, MAP_LANES, MAP_POINTS, 2))
    valid = np.zeros((n, MAP_LANES), dtype=bool)
    kind = np.zeros((n, MAP_LANES), dtype=np.int64)
    kind[:, MAP_AHEAD] = MAP_KIND_LEFT
    kind[:, MAP_AHEAD + 1] = MAP_KIND_RIGHT
    scalar = np.zeros((n, MAP_SCALARS))
    if graph is not None:
        speed = np.maximum(np.asarray(speed, dtype=float), 0.0)
        person = np.zeros(n, dtype=bool) if ctx.person is None else np.asarray(ctx.person, dtype=bool)
        nxt = np.full(n, -1) if ctx.next_lane is None else np.asarray(ctx.next_lane)
        switch = np.full(n, np.inf) if ctx.tls_switch is None else np.asarray(ctx.tls_switch, dtype=float)
        after = np.full(n, -1) if ctx.after_lane is None or version < 4 else np.asarray(ctx.after_lane)
        lanes = np.asarray(ctx.lane, dtype=np.int64)
        on = np.flatnonzero(lanes >= 0)
        if version < 2:  # pedestrians get no map context
            on = on[~person[on]]
        _signal_scalars(scalar, on, ctx.tls_dist, ctx.tls_state, switch)
        veh = on[~person[on]]
        scalar[veh, 6] = graph.speed[lanes[veh]] / SPEED_SCALE
        if ctx.blinker is not None and version >= 4:
            bits = np.asarray(ctx.blinker, dtype=np.int64)[veh]
            scalar[veh, 8] = (bits & (BLINKER_LEFT | BLINKER_EMERGENCY)) > 0
            scalar[veh, 9] = (bits & (BLINKER_RIGHT | BLINKER_EMERGENCY)) > 0
        # rows (target, row, centre line, first arc length, spacing); the per-target walk runs on
        # Python scalars (numpy's scalar arithmetic costs more than the walk itself). The pedestrians'
        # rows after a walking area (version 4) are sampled in a second pass, so that the rows of
        # versions 1-3 are sampled exactly as those versions did (_sample_many's rounding depends
        # on a row's place among all rows)
        rows: list[tuple] = []  # (target, row, centre line, first arc length, spacing)
        later: list[tuple] = []
        across: list[tuple] = []  # version 5: row 0 of the pedestrians on a walking area, sampled last

        lane_l, pos_l, speed_l = lanes.tolist(), np.asarray(ctx.lane_pos, dtype=float).tolist(), speed.tolist()
        for i in on.tolist():
            lane = lane_l[i]
            if person[i]:
                for r, line, s0 in _walk_lines(graph, lane, pos_l[i], int(nxt[i]), xy[i], float(yaw[i]), int(after[i])):
                    (later if r == MAP_ROW_AFTER else rows).append((i, r, line, s0, MAP_DS_PERSON))
                if version >= 5 and nxt[i] >= 0 and nxt[i] != lane and graph.is_walking_area(lane) \
                        and not graph.is_walking_area(int(nxt[i])):
                    across.append((i, 0, walk_across(graph, int(nxt[i]), xy[i]), 0.0, MAP_DS_PERSON))
                continue
            ds = max(MAP_DS_MIN, MAP_DS_PER_SPEED * speed_l[i])
            reach = (MAP_POINTS - 1) * ds
            start = graph.shape_pos(lane, pos_l[i])
            for r, path in enumerate(graph.paths(lane, start, reach, MAP_AHEAD)):
                rows.append((i, r, graph.polyline(path), start, ds))
            for r, side in ((MAP_AHEAD, int(graph.left[lane])), (MAP_AHEAD + 1, int(graph.right[lane]))):
                if side >= 0:
                    s0 = min(start, graph.cum[side][-1])
                    rows.append((i, r, graph.polyline(graph.first_path(side, s0, reach)), s0, ds))
        yaw = np.asarray(yaw, dtype=float)
        for done in (rows, later, across):
            if done is across and version >= 5:
                row0_v4 = pts[:, 0].copy()
            if not done:
                continue
            who, row, lines, first, spacing = zip(*done)
            who_a, row_a = np.array(who), np.array(row)
            where = np.asarray(first, dtype=float)[:, None] + np.arange(MAP_POINTS, dtype=float) * np.asarray(spacing, dtype=float)[:, None]
            world = _sample_many(lines, where)  # (R, MAP_POINTS, 2)
            c, s_ = np.cos(yaw[who_a])[:, None], np.sin(yaw[who_a])[:, None]
            dx = world[..., 0] - xy[who_a, 0][:, None]
            dy = world[..., 1] - xy[who_a, 1][:, None]
            pts[who_a, row_a] = np.stack([c * dx + s_ * dy, -s_ * dx + c * dy], -1)
            valid[who_a, row_a] = True
    out = {
        "map_pts": pts.astype(np.float32),
        "map_valid": valid,
        "map_kind": kind,
        "map_scalar": scalar[:, :map_scalars(version)].astype(np.float32),
    }
    if version >= 5:
        out["map_row0_v4"] = (row0_v4 if graph is not None else pts[:, 0]).astype(np.float32)
    return out
