"""Training samples for the predictors from recorded trajectories (no torch, no SUMO).

A dataset folder (written by :func:`sumo_ethics.recording.build.build_dataset`, which runs every scenario x seed (one libsumo simulation per fresh
process, ``--step-length 0.1 --lanechange.duration 2``, demand scaled with ``--scale``
varying by seed) holds:

- ``trajectories.parquet``: one row per agent per 0.1 s step, internal frame (centre
  position, yaw CCW from +x): run_id, seed, scenario, scale, time, agent_id, cls
  (RoadUserClass int), x, y, yaw, speed, length, width, and at the model rate (every
  0.2 s; other rows lane = -1) the map context of :mod:`sumo_ethics.sim.lanes`: lane (index
  into the run's lane graph, -1 none), lane_pos (centre), tls_dist, tls_state, next_lane (a
  pedestrian's next lane, -1 none; datasets built before map version 2 have no such column and
  no lanes for pedestrians), tls_switch (how long the light's state holds [s], inf none or no
  change; from map version 3), blinker (a vehicle's signal bits, features.BLINKER_*) and
  after_lane (a pedestrian's lane after a walking area, -1 none; both from map version 4).
- ``lane_graphs.json.gz``: scenario path -> :class:`features.LaneGraph` of its network
  (:mod:`sumo_ethics.predict.graph_files`; older folders: ``lane_graphs.pkl``, converted on first read).
- ``samples.npz``: training samples at the model rate (5 Hz, see
  :mod:`sumo_ethics.predict.features`): a target with 3 s history and 4 s future,
  neighbours in its social grid, all in the target's frame. One anchor every
  ``anchor_every`` s per agent. Neighbours are stored packed (``nbr_*`` arrays, sorted by
  sample, ``nbr_ptr`` offsets).
  Per sample also its map features (``map_pts``, ``map_valid``, ``map_scalar``, and
  ``map_row0_v4``: row 0 as map versions 2-4 build it, for the models of those versions), its
  manoeuvre label (``manoeuvre``, see :data:`MANOEUVRES`) and ``fut_valid`` (T,) bool
  (hazard actors may vanish after 1 s: their futures are partly observed).
- ``split.json``: the seeds of each split; the split is by run seed, never by frame. Suite
  scenarios recorded with their hazards (``suite=``) are split by scenario.

While it builds, each finished run is kept in ``out/partial`` (:mod:`sumo_ethics.recording.runstore`):
a build stopped by Ctrl-C, SIGTERM, a crash or a kill resumes from them when called again with
the same arguments, and gives the same bytes as one never stopped.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pandas as pd

from sumo_ethics.errors import ConfigError
from sumo_ethics.predict import features as F
from sumo_ethics.predict.graph_files import read_dataset_graphs, write_dataset_graphs

log = logging.getLogger(__name__)

#: the recording step [s] of trajectories.parquet (the model rate is features.MODEL_DT)
SIM_DT = 0.1
#: suite runs enter the dataset with these seeds (SUITE_SEED0 + their index): the split is by
#: scenario, every 10th to test, the one before it to validation
SUITE_SEED0 = 100_000
NO_POSITION = 1e9  # [m] |x| or |y| at least this: SUMO gave no position (INVALID_DOUBLE_VALUE is -2^30)
MAX_TRACK_SPEED = 70.0  # [m/s] faster between two model steps: SUMO placed the road user elsewhere


def split_seeds(seeds: list[int], val_fraction: float = 0.15, test_fraction: float = 0.2) -> dict[str, list[int]]:
    """Split run seeds (not frames) into train / val / test; test and val take the last seeds."""
    s = sorted(set(int(x) for x in seeds))
    if len(s) < 3:
        raise ValueError(f"need at least 3 seeds for a train/val/test split, got {s}")
    n_test = max(1, round(len(s) * test_fraction))
    n_val = max(1, round(len(s) * val_fraction))
    return {"train": s[: len(s) - n_test - n_val], "val": s[len(s) - n_test - n_val: len(s) - n_test], "test": s[len(s) - n_test:]}


MANOEUVRES = ("straight", "turn", "stop_at_light", "lane_change", "hazard")
HAZARD_MIN_FUTURE = 5  # model steps (1 s) of future a hazard actor's sample needs at least
TURN_ANGLE = 0.5  # [rad] heading change over the horizon that makes a turn (about 29 degrees)


def manoeuvre_labels(group: np.ndarray, fut: np.ndarray, speed: np.ndarray, lanes: np.ndarray,
                     tls_dist: np.ndarray, tls_state: np.ndarray, hazard: np.ndarray,
                     graph: F.LaneGraph | None) -> np.ndarray:
    """(S,) MANOEUVRES index of each sample, first match wins:

    hazard: the target is an injected hazard actor (id ``hazard_*``); stop_at_light: a red or
    yellow light ahead within the 4 s reach (speed x 4 s + 10 m); lane_change: between two
    consecutive model steps of [now, +4 s] the target's lane becomes its left or right
    neighbour; turn: the heading of its path at the end of the horizon differs from now by more
    than TURN_ANGLE; straight: anything else. Pedestrians: -1.
    fut: (S, T, 2) target frame; lanes: (S, T + 1) lane index now and at each future step.
    """
    s = len(group)
    out = np.zeros(s, dtype=np.int8)
    seg = fut[:, -1] - fut[:, -3]
    moved = np.hypot(seg[:, 0], seg[:, 1]) > 0.5
    head = np.where(moved, np.arctan2(seg[:, 1], seg[:, 0]), np.arctan2(fut[:, -1, 1], np.abs(fut[:, -1, 0]) + 1e-6))
    far = np.hypot(fut[:, -1, 0], fut[:, -1, 1]) > 2.0
    out[far & (np.abs(head) > TURN_ANGLE)] = 1
    if graph is not None and lanes.shape[1] > 1:
        a, b = lanes[:, :-1], lanes[:, 1:]
        ok = (a >= 0) & (b >= 0)
        side = ok & ((b == graph.left[np.maximum(a, 0)]) | (b == graph.right[np.maximum(a, 0)]))
        out[side.any(axis=1)] = 3
    light = np.isfinite(tls_dist) & (tls_dist <= speed * 4.0 + 10.0) & ((tls_state == 2) | (tls_state == 3))
    out[light] = 2
    out[hazard] = 4
    out[group == F.GROUP_PEDESTRIAN] = -1
    return out


def track_pieces(agent_id: np.ndarray, frame: np.ndarray, x: np.ndarray, y: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """(R,) rows at the model rate -> (R,) piece codes, (P,) agent id of each piece: an agent's
    track is cut where it is not seen for a model step or more (a pedestrian riding a bus, a car
    in a parking area) or moves faster than MAX_TRACK_SPEED (SUMO placing it elsewhere), so no
    sample's history bridges the gap (bridged, it was a jump of hundreds of metres). Codes in
    order of first appearance, as ``pd.factorize`` gives them for a track without cuts."""
    codes, names = pd.factorize(agent_id)
    order = np.lexsort((frame, codes))
    c, f = codes[order], frame[order]
    step = np.hypot(np.diff(x[order]), np.diff(y[order]))
    new = np.ones(len(order), dtype=bool)
    new[1:] = (c[1:] != c[:-1]) | (f[1:] - f[:-1] > 1) | (step > MAX_TRACK_SPEED * F.MODEL_DT)
    piece = np.empty(len(order), dtype=np.int64)
    piece[order] = np.cumsum(new) - 1
    piece_codes, _ = pd.factorize(piece)
    first = np.unique(piece_codes, return_index=True)[1]  # each piece's first row
    return piece_codes, names[codes[first]]


def samples_from_run(df: pd.DataFrame, anchor_every: float = 1.0, min_history: float = 1.0,
                     graph: F.LaneGraph | None = None) -> dict[str, np.ndarray]:
    """Training samples from one run's trajectory rows (see module docstring).

    With the run's lane ``graph`` (and the map columns in ``df``), each sample also carries
    its map features (``map_*``, see :func:`features.map_features`); without, those are empty.
    """
    ratio = int(round(F.MODEL_DT / SIM_DT))
    k = np.round(df["time"].to_numpy() / SIM_DT).astype(np.int64)
    # rows without a position (SUMO's INVALID_DOUBLE_VALUE, -2^30 m; the recorder drops them since
    # sim.recorder.on_road, older datasets have them) are steps the road user was not seen
    seen = (np.abs(df["x"].to_numpy()) < NO_POSITION) & (np.abs(df["y"].to_numpy()) < NO_POSITION)
    keep = (k % ratio == 0) & seen
    d = df.loc[keep]
    frame = (k[keep] // ratio)
    frame = frame - frame.min()
    agent_codes, agent_names = track_pieces(d["agent_id"].to_numpy(), frame, d["x"].to_numpy(), d["y"].to_numpy())
    na, nf = len(agent_names), int(frame.max()) + 1
    pos = np.full((na, nf, 2), np.nan)
    yaw = np.zeros((na, nf))
    speed = np.zeros((na, nf))
    pos[agent_codes, frame, 0] = d["x"].to_numpy()
    pos[agent_codes, frame, 1] = d["y"].to_numpy()
    yaw[agent_codes, frame] = d["yaw"].to_numpy()
    speed[agent_codes, frame] = d["speed"].to_numpy()
    lane = np.full((na, nf), -1, dtype=np.int64)
    lane_pos = np.zeros((na, nf))
    tls_dist = np.full((na, nf), np.inf)
    tls_state = np.zeros((na, nf), dtype=np.int64)
    next_lane = np.full((na, nf), -1, dtype=np.int64)
    tls_switch = np.full((na, nf), np.inf)
    blinker = np.zeros((na, nf), dtype=np.int64)
    after_lane = np.full((na, nf), -1, dtype=np.int64)
    has_map = graph is not None and "lane" in d.columns
    if has_map:
        lane[agent_codes, frame] = d["lane"].to_numpy()
        lane_pos[agent_codes, frame] = d["lane_pos"].to_numpy()
        tls_dist[agent_codes, frame] = d["tls_dist"].to_numpy()
        tls_state[agent_codes, frame] = d["tls_state"].to_numpy()
        if "next_lane" in d.columns:
            next_lane[agent_codes, frame] = d["next_lane"].to_numpy()
        if "tls_switch" in d.columns:
            tls_switch[agent_codes, frame] = d["tls_switch"].to_numpy()
        if "blinker" in d.columns:
            blinker[agent_codes, frame] = d["blinker"].to_numpy()
            after_lane[agent_codes, frame] = d["after_lane"].to_numpy()
    cls = np.zeros(na, dtype=np.int64)
    cls[agent_codes] = d["cls"].to_numpy()
    hazard_agent = np.array([str(a).startswith("hazard_") for a in agent_names], dtype=bool)
    present = ~np.isnan(pos[..., 0])

    h, fsteps = F.HIST_STEPS, F.FUT_STEPS
    step = max(1, int(round(anchor_every / F.MODEL_DT)))
    min_valid = int(round(min_history / F.MODEL_DT)) + 1
    out: dict[str, list[np.ndarray]] = {key: [] for key in (
        "tgt_hist", "tgt_group", "tgt_cls", "tgt_speed", "fut", "time",
        "nbr_hist", "nbr_group", "nbr_cell", "nbr_yaw", "nbr_count",
        "map_pts", "map_valid", "map_scalar", "map_row0_v4", "manoeuvre", "fut_valid")}
    for f in range(h - 1, nf - fsteps, step):
        here = np.flatnonzero(present[:, f])
        if here.size == 0:
            continue
        hv = present[here, f - h + 1: f + 1]
        fp = np.logical_and.accumulate(present[here, f + 1: f + 1 + fsteps], axis=1)  # future seen without a gap
        fut_ok = fp[:, -1]
        # hazard actors live a few seconds: 0.4 s of history and 1 s of future suffice for them
        hz = hazard_agent[here]
        tmask = (fut_ok & (hv.sum(axis=1) >= min_valid)) | (hz & fp[:, HAZARD_MIN_FUTURE - 1] & (hv.sum(axis=1) >= 3))
        if not tmask.any():
            continue
        hist = np.nan_to_num(pos[here, f - h + 1: f + 1])
        hist = F.backfill(hist, hv)
        targets = np.flatnonzero(tmask)
        feats = F.build_features(hist, cls[here], yaw[here, f], targets)
        ta = here[targets]
        fvalid = fp[targets]
        fpos = pos[ta, f + 1: f + 1 + fsteps]
        last = fpos[np.arange(len(ta)), fvalid.sum(axis=1) - 1]  # hold the last seen position
        fpos = np.where(fvalid[..., None], fpos, last[:, None, :])
        fut = F.to_target_frame(fpos, pos[ta, f], yaw[ta, f])
        ctx = F.MapContext(lane[ta, f], lane_pos[ta, f], tls_dist[ta, f], tls_state[ta, f],
                           person=feats["tgt_group"] == F.GROUP_PEDESTRIAN, next_lane=next_lane[ta, f],
                           tls_switch=tls_switch[ta, f], blinker=blinker[ta, f], after_lane=after_lane[ta, f])
        mf = F.map_features(graph if has_map else None, ctx, pos[ta, f], yaw[ta, f], speed[ta, f])
        out["tgt_hist"].append(feats["tgt_hist"])
        out["tgt_group"].append(feats["tgt_group"])
        out["tgt_cls"].append(cls[ta])
        out["tgt_speed"].append(speed[ta, f].astype(np.float32))
        out["fut"].append(fut.astype(np.float32))
        out["fut_valid"].append(fvalid)
        out["time"].append(np.full(len(ta), f * F.MODEL_DT, dtype=np.float32))
        out["nbr_hist"].append(feats["nbr_hist"])
        out["nbr_group"].append(feats["nbr_group"])
        out["nbr_cell"].append(feats["nbr_cell"])
        out["nbr_yaw"].append(feats["nbr_yaw"])
        out["nbr_count"].append(np.bincount(feats["nbr_batch"], minlength=len(ta)))
        out["map_pts"].append(mf["map_pts"])
        out["map_valid"].append(mf["map_valid"])
        out["map_scalar"].append(mf["map_scalar"])
        out["map_row0_v4"].append(mf["map_row0_v4"])
        out["manoeuvre"].append(manoeuvre_labels(
            feats["tgt_group"], fut, speed[ta, f], lane[ta, f: f + 1 + fsteps], tls_dist[ta, f], tls_state[ta, f],
            hazard_agent[ta], graph if has_map else None))
    if not out["tgt_hist"]:
        return {}
    return {key: np.concatenate(v) for key, v in out.items()}


def build_samples(traj: pd.DataFrame, split: dict[str, list[int]], anchor_every: float = 1.0,
                  graphs: dict[str, F.LaneGraph] | None = None, suite_anchor_every: float = 0.4) -> dict[str, np.ndarray]:
    """Samples of every run, concatenated, with ``run_id``/``seed``/``split`` per sample.

    graphs: scenario path -> lane graph (from :func:`simulate_runs`), for the map features;
    suite runs (seed >= SUITE_SEED0: short, rare hazard behaviour) are anchored every
    ``suite_anchor_every`` s instead of ``anchor_every``."""
    parts = []
    split_of = {s: i for i, name in enumerate(("train", "val", "test")) for s in split[name]}
    graphs = graphs or {}
    for run_id, df in traj.groupby("run_id", sort=True):
        seed = int(df["seed"].iloc[0])
        every = suite_anchor_every if seed >= SUITE_SEED0 else anchor_every
        s = samples_from_run(df, anchor_every=every, graph=graphs.get(str(df["scenario"].iloc[0])))
        if not s:
            continue
        n = len(s["tgt_hist"])
        s["run_id"] = np.full(n, run_id, dtype=np.int32)
        s["seed"] = np.full(n, seed, dtype=np.int32)
        s["split"] = np.full(n, split_of.get(seed, 0), dtype=np.int8)
        parts.append(s)
    if not parts:
        raise ConfigError("the runs gave no prediction samples: a sample needs 3 s of an agent's history and "
                          "up to 4 s of its future, so simulate longer (--sim-seconds) or busier scenarios")
    out = {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}
    out["nbr_ptr"] = np.concatenate([[0], np.cumsum(out.pop("nbr_count"))]).astype(np.int64)
    return out


def map_version_of(dataset: Path) -> int:
    """The map version of a dataset folder's samples (split.json; 1 for datasets without it)."""
    meta = Path(dataset) / "split.json"
    return int(json.loads(meta.read_text()).get("map_version") or 1) if meta.is_file() else 1


def add_train_samples(samples: dict[str, np.ndarray], extra: dict[str, np.ndarray],
                      groups: tuple[int, ...] | None = None) -> dict[str, np.ndarray]:
    """``samples`` followed by ``extra``'s training-split samples of the class groups ``groups``
    (features.GROUP_*; None: all), neighbours repacked, in ``samples``' dtypes: training data
    from other runs (e.g. only their cyclists and pedestrians) without touching the validation
    and test splits. ValueError when the two hold different arrays (other layouts)."""
    if set(samples) != set(extra):
        raise ValueError(f"the samples hold other arrays ({', '.join(sorted(set(samples) ^ set(extra)))} in one only)")
    keep = extra["split"] == 0
    if groups is not None:
        keep &= np.isin(extra["tgt_group"], groups)
    add = subset(extra, np.flatnonzero(keep))
    out = {}
    for k, v in samples.items():
        tail = add[k][1:] + v[-1] if k == "nbr_ptr" else add[k]
        out[k] = np.concatenate([v, tail.astype(v.dtype)])
    return out


def split_counts(samples: dict[str, np.ndarray]) -> dict[str, int]:
    """Number of samples in each split (train, val, test)."""
    return {name: int((samples["split"] == i).sum()) for i, name in enumerate(("train", "val", "test"))}


def require_nbr_yaw(samples: dict[str, np.ndarray], dataset: Path, who: str = "") -> None:
    """PredictorError unless the samples carry ``nbr_yaw`` (agent-frame models need it;
    datasets built before it lack it). ``who``: the model asking, for the message."""
    if "nbr_yaw" not in samples:
        from sumo_ethics.predict import PredictorError

        raise PredictorError(f"{who + ': ' if who else ''}dataset {dataset} has no nbr_yaw (built before it): derive "
                             f"its samples again with 'sumo-ethics dataset --samples-from {dataset} --out NEW'")


def rebuild_samples(src: Path, out: Path, anchor_every: float = 2.0, suite_anchor_every: float = 0.4) -> Path:
    """Derive ``out``/samples.npz again from ``src``'s recorded trajectories (no simulation),
    after a change of the sample layout; lane graphs, split and trajectories are copied.
    The anchor spacings are the dataset's own (split.json); the arguments serve datasets built
    before they were recorded there (the CLI's defaults)."""
    import shutil

    src, out = Path(src), Path(out)
    if out.resolve() == src.resolve():
        raise ValueError("rebuild_samples writes a new dataset folder: out must differ from src")
    out.mkdir(parents=True, exist_ok=True)
    meta = json.loads((src / "split.json").read_text())
    traj = pd.read_parquet(src / "trajectories.parquet")
    graphs = read_dataset_graphs(src)
    meta.setdefault("anchor_every", anchor_every)
    meta.setdefault("suite_anchor_every", suite_anchor_every)
    if int(meta.get("map_version") or 1) >= 4:  # map version 5 reads no recorded column that version 4 lacks
        meta["map_version"] = F.MAP_VERSION
    samples = build_samples(traj, meta["split"], anchor_every=meta["anchor_every"], graphs=graphs,
                            suite_anchor_every=meta["suite_anchor_every"])
    np.savez_compressed(out / "samples.npz", **samples)  # type: ignore[arg-type]  # array names, no allow_pickle
    shutil.copyfile(src / "trajectories.parquet", out / "trajectories.parquet")
    write_dataset_graphs(out, graphs)
    meta["n_samples"] = split_counts(samples)
    (out / "split.json").write_text(json.dumps(meta, indent=2))
    return out


def run_scenarios(dataset: Path) -> dict[int, str]:
    """run_id -> scenario name of a dataset folder (its split.json): the .sumocfg's stem for the
    simulated scenarios, "suite" for every suite run (numbered after them); {} without split.json."""
    meta_path = Path(dataset) / "split.json"
    if not meta_path.is_file():
        return {}
    meta = json.loads(meta_path.read_text())
    names = {int(r["run_id"]): Path(r["scenario"]).stem for r in meta.get("runs", [])}
    first = len(meta.get("runs", []))
    names.update({first + i: "suite" for i in range(len(meta.get("suite", [])))})
    return names


def load_samples(path: Path) -> dict[str, np.ndarray]:
    """samples.npz (or a dataset folder holding one) -> dict of arrays."""
    path = Path(path)
    if path.is_dir():
        path = path / "samples.npz"
    with np.load(path) as z:
        return {k: z[k] for k in z.files}


def subset(samples: dict[str, np.ndarray], index: np.ndarray) -> dict[str, np.ndarray]:
    """Samples at ``index`` (sample rows), with their neighbours repacked."""
    index = np.asarray(index, dtype=np.int64)
    ptr = samples["nbr_ptr"]
    counts = ptr[index + 1] - ptr[index]
    starts = np.repeat(ptr[index], counts)
    within = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    pair = starts + within
    out = {k: v[index] for k, v in samples.items() if not k.startswith("nbr_")}
    for k in ("nbr_hist", "nbr_group", "nbr_cell", "nbr_yaw"):
        if k in samples:
            out[k] = samples[k][pair]
    out["nbr_batch"] = np.repeat(np.arange(len(index)), counts)
    out["nbr_ptr"] = np.concatenate([[0], np.cumsum(counts)])
    return out
