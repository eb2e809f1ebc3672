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

import numpy as np

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
) -> dict[str, np.ndarray]:
    """Model inputs for ``targets`` among M agents with (backfilled) histories at MODEL_DT.

    hist: (M, HIST_STEPS, 2) world centre positions, last = now; cls: (M,) RoadUserClass;
    yaw: (M,) current yaw; targets: (N,) indices into the M agents (default: all).

    Returns float32/int64 arrays:
    ``tgt_hist`` (N, H, 2) target history in its own frame [m]; ``tgt_group`` (N,);
    ``nbr_hist`` (P, H, 2) neighbour histories in their target's frame [m];
    ``nbr_group`` (P,); ``nbr_batch`` (P,) target row of each neighbour;
    ``nbr_cell`` (P,) grid cell = lon_index * GRID_LAT + lat_index; ``nbr_agent`` (P,).
    """
    hist = np.asarray(hist, dtype=float)
    m = hist.shape[0]
    targets = np.arange(m) if targets is None else np.asarray(targets, dtype=np.int64)
    groups = class_group(cls)
    now = hist[:, -1, :]
    origin = now[targets]
    tyaw = np.asarray(yaw, dtype=float)[targets]
    tgt_hist = to_target_frame(hist[targets], origin, tyaw)
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
    nbr_hist = to_target_frame(hist[ai], origin[ti], tyaw[ti])
    return {
        "tgt_hist": tgt_hist.astype(np.float32),
        "tgt_group": groups[targets].astype(np.int64),
        "nbr_hist": nbr_hist.astype(np.float32),
        "nbr_group": groups[ai].astype(np.int64),
        "nbr_batch": ti.astype(np.int64),
        "nbr_cell": cells.astype(np.int64),
        "nbr_agent": ai.astype(np.int64),
    }
