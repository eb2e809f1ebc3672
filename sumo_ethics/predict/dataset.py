"""Trajectory data from SUMO and training samples for the predictors (no torch).

``build_dataset`` runs every scenario x seed (one libsumo simulation per spawned
process, ``--step-length 0.1 --lanechange.duration 2``, demand scaled with ``--scale``
varying by seed), and writes to ``out``:

- ``trajectories.parquet``: one row per agent per 0.1 s step, internal frame (centre
  position, yaw CCW from +x): run_id, seed, scenario, scale, time, agent_id, cls
  (RoadUserClass int), x, y, yaw, speed, length, width.
- ``samples.npz``: training samples at the model rate (5 Hz, see
  :mod:`sumo_ethics.predict.features`): a target with 3 s history and 4 s future,
  neighbours in its social grid, all in the target's frame. One anchor every
  ``anchor_every`` s per agent. Neighbours are stored packed (``nbr_*`` arrays, sorted by
  sample, ``nbr_ptr`` offsets).
- ``split.json``: the seeds of each split; the split is by run seed, never by frame.
"""

from __future__ import annotations

import json
import logging
import multiprocessing as mp
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from sumo_ethics.predict import features as F
from sumo_ethics.sim.frames import front_to_centre
from sumo_ethics.types import RoadUserClass

log = logging.getLogger(__name__)

SIM_DT = 0.1
DEFAULT_SCALES = (0.7, 1.0, 1.3)

@dataclass(frozen=True)
class RunSpec:
    run_id: int
    scenario: Path
    seed: int
    scale: float
    sim_seconds: float


def _simulate(spec: RunSpec) -> pd.DataFrame:
    """One SUMO run through libsumo -> trajectory rows (runs inside a worker process)."""
    import libsumo as ls

    cmd = [
        "sumo", "-c", str(spec.scenario), "--seed", str(spec.seed), "--scale", f"{spec.scale:g}",
        "--step-length", f"{SIM_DT}", "--lanechange.duration", "2",
        "--no-step-log", "true", "--no-warnings", "true", "--duration-log.disable", "true",
    ]
    ls.start(cmd)
    vars_ = (ls.VAR_POSITION, ls.VAR_ANGLE, ls.VAR_SPEED)
    type_info: dict[str, tuple[float, float, int]] = {}
    agent_type: dict[str, tuple[float, float, int]] = {}

    def info(type_id: str) -> tuple[float, float, int]:
        if type_id not in type_info:
            type_info[type_id] = (
                ls.vehicletype.getLength(type_id),
                ls.vehicletype.getWidth(type_id),
                int(RoadUserClass.from_vclass(ls.vehicletype.getVehicleClass(type_id))),
            )
        return type_info[type_id]

    rows_t, rows_id, rows_x, rows_y, rows_a, rows_v = [], [], [], [], [], []
    t0 = ls.simulation.getTime()
    try:
        while ls.simulation.getTime() - t0 < spec.sim_seconds and ls.simulation.getMinExpectedNumber() > 0:
            ls.simulationStep()
            for v in ls.simulation.getDepartedIDList():
                ls.vehicle.subscribe(v, vars_)
                agent_type[v] = info(ls.vehicle.getTypeID(v))
            for p in ls.simulation.getDepartedPersonIDList():
                ls.person.subscribe(p, vars_)
                agent_type[p] = info(ls.person.getTypeID(p))
            t = ls.simulation.getTime()
            for res in (ls.vehicle.getAllSubscriptionResults(), ls.person.getAllSubscriptionResults()):
                for aid, r in res.items():
                    pos = r[ls.VAR_POSITION]
                    rows_t.append(t)
                    rows_id.append(aid)
                    rows_x.append(pos[0])
                    rows_y.append(pos[1])
                    rows_a.append(r[ls.VAR_ANGLE])
                    rows_v.append(r[ls.VAR_SPEED])
    finally:
        ls.close()
    ids = np.array(rows_id, dtype=object)
    tinfo = np.array([agent_type[a] for a in rows_id]).reshape(-1, 3)
    length, width, cls = tinfo[:, 0], tinfo[:, 1], tinfo[:, 2].astype(np.int8)
    x, y, yaw = front_to_centre(np.array(rows_x), np.array(rows_y), np.array(rows_a), length)
    return pd.DataFrame(
        {
            "run_id": np.full(len(ids), spec.run_id, dtype=np.int32),
            "seed": np.full(len(ids), spec.seed, dtype=np.int32),
            "scenario": str(spec.scenario),
            "scale": np.float32(spec.scale),
            "time": np.round(np.array(rows_t), 3),
            "agent_id": ids.astype(str),
            "cls": cls,
            "x": x, "y": y, "yaw": yaw,
            "speed": np.array(rows_v, dtype=np.float32),
            "length": length.astype(np.float32), "width": width.astype(np.float32),
        }
    )


def split_seeds(seeds: list[int], val_fraction: float = 0.15, test_fraction: float = 0.2) -> dict[str, list[int]]:
    """Split run seeds (not frames) into train / val / test; test and val take the last seeds."""
    s = sorted(set(int(x) for x in seeds))
    if len(s) < 3:
        raise ValueError(f"need at least 3 seeds for a train/val/test split, got {s}")
    n_test = max(1, round(len(s) * test_fraction))
    n_val = max(1, round(len(s) * val_fraction))
    return {"train": s[: len(s) - n_test - n_val], "val": s[len(s) - n_test - n_val: len(s) - n_test], "test": s[len(s) - n_test:]}


def simulate_runs(specs: list[RunSpec], workers: int = 1) -> pd.DataFrame:
    """Run every spec in a fresh spawned process (libsumo: one simulation per process)."""
    ctx = mp.get_context("spawn")
    frames = []
    with ctx.Pool(processes=max(1, workers), maxtasksperchild=1) as pool:
        for i, df in enumerate(pool.imap(_simulate, specs)):
            log.info("run %d/%d: %s seed %d scale %.2f -> %d rows", i + 1, len(specs), specs[i].scenario.name, specs[i].seed, specs[i].scale, len(df))
            frames.append(df)
    return pd.concat(frames, ignore_index=True)


def samples_from_run(df: pd.DataFrame, anchor_every: float = 1.0, min_history: float = 1.0) -> dict[str, np.ndarray]:
    """Training samples from one run's trajectory rows (see module docstring)."""
    ratio = int(round(F.MODEL_DT / SIM_DT))
    k = np.round(df["time"].to_numpy() / SIM_DT).astype(np.int64)
    keep = k % ratio == 0
    d = df.loc[keep]
    frame = (k[keep] // ratio)
    frame = frame - frame.min()
    agent_codes, agent_names = pd.factorize(d["agent_id"])
    na, nf = len(agent_names), int(frame.max()) + 1
    pos = np.full((na, nf, 2), np.nan)
    yaw = np.zeros((na, nf))
    speed = np.zeros((na, nf))
    pos[agent_codes, frame, 0] = d["x"].to_numpy()
    pos[agent_codes, frame, 1] = d["y"].to_numpy()
    yaw[agent_codes, frame] = d["yaw"].to_numpy()
    speed[agent_codes, frame] = d["speed"].to_numpy()
    cls = np.zeros(na, dtype=np.int64)
    cls[agent_codes] = d["cls"].to_numpy()
    present = ~np.isnan(pos[..., 0])

    h, fsteps = F.HIST_STEPS, F.FUT_STEPS
    step = max(1, int(round(anchor_every / F.MODEL_DT)))
    min_valid = int(round(min_history / F.MODEL_DT)) + 1
    out: dict[str, list[np.ndarray]] = {key: [] for key in (
        "tgt_hist", "tgt_group", "tgt_cls", "tgt_speed", "fut", "time",
        "nbr_hist", "nbr_group", "nbr_cell", "nbr_count")}
    for f in range(h - 1, nf - fsteps, step):
        here = np.flatnonzero(present[:, f])
        if here.size == 0:
            continue
        hv = present[here, f - h + 1: f + 1]
        fut_ok = present[here, f + 1: f + 1 + fsteps].all(axis=1)
        tmask = fut_ok & (hv.sum(axis=1) >= min_valid)
        if not tmask.any():
            continue
        hist = np.nan_to_num(pos[here, f - h + 1: f + 1])
        hist = F.backfill(hist, hv)
        targets = np.flatnonzero(tmask)
        feats = F.build_features(hist, cls[here], yaw[here, f], targets)
        ta = here[targets]
        fut = F.to_target_frame(pos[ta, f + 1: f + 1 + fsteps], pos[ta, f], yaw[ta, f])
        out["tgt_hist"].append(feats["tgt_hist"])
        out["tgt_group"].append(feats["tgt_group"])
        out["tgt_cls"].append(cls[ta])
        out["tgt_speed"].append(speed[ta, f].astype(np.float32))
        out["fut"].append(fut.astype(np.float32))
        out["time"].append(np.full(len(ta), f * F.MODEL_DT, dtype=np.float32))
        out["nbr_hist"].append(feats["nbr_hist"])
        out["nbr_group"].append(feats["nbr_group"])
        out["nbr_cell"].append(feats["nbr_cell"])
        out["nbr_count"].append(np.bincount(feats["nbr_batch"], minlength=len(ta)))
    if not out["tgt_hist"]:
        return {}
    return {key: np.concatenate(v) for key, v in out.items()}


def build_samples(traj: pd.DataFrame, split: dict[str, list[int]], anchor_every: float = 1.0) -> dict[str, np.ndarray]:
    """Samples of every run, concatenated, with ``run_id``/``seed``/``split`` per sample."""
    parts = []
    split_of = {s: i for i, name in enumerate(("train", "val", "test")) for s in split[name]}
    for run_id, df in traj.groupby("run_id", sort=True):
        s = samples_from_run(df, anchor_every=anchor_every)
        if not s:
            continue
        seed = int(df["seed"].iloc[0])
        n = len(s["tgt_hist"])
        s["run_id"] = np.full(n, run_id, dtype=np.int32)
        s["seed"] = np.full(n, seed, dtype=np.int32)
        s["split"] = np.full(n, split_of.get(seed, 0), dtype=np.int8)
        parts.append(s)
    out = {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}
    out["nbr_ptr"] = np.concatenate([[0], np.cumsum(out.pop("nbr_count"))]).astype(np.int64)
    return out


def build_dataset(
    scenarios: list[Path],
    seeds: list[int],
    out: Path,
    *,
    scales: tuple[float, ...] = DEFAULT_SCALES,
    sim_seconds: float = 600.0,
    anchor_every: float = 1.0,
    workers: int = 1,
    val_fraction: float = 0.15,
    test_fraction: float = 0.2,
) -> Path:
    """Simulate scenarios x seeds and write trajectories.parquet, samples.npz, split.json.

    The demand scale of seed s is ``scales[i % len(scales)]`` where i is the seed's rank,
    so every split sees every scale when it has enough seeds. Returns ``out``.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    seeds = sorted(set(int(s) for s in seeds))
    split = split_seeds(seeds, val_fraction, test_fraction)
    specs = []
    for scenario in scenarios:
        for i, seed in enumerate(seeds):
            specs.append(RunSpec(len(specs), Path(scenario).resolve(), seed, float(scales[i % len(scales)]), sim_seconds))
    traj = simulate_runs(specs, workers=workers)
    traj.to_parquet(out / "trajectories.parquet", index=False)
    samples = build_samples(traj, split, anchor_every=anchor_every)
    np.savez_compressed(out / "samples.npz", **samples)
    meta = {
        "split": split,
        "scenarios": [str(Path(s)) for s in scenarios],
        "runs": [{"run_id": s.run_id, "scenario": str(s.scenario), "seed": s.seed, "scale": s.scale} for s in specs],
        "feature_version": F.FEATURE_VERSION,
        "model_dt": F.MODEL_DT,
        "hist_steps": F.HIST_STEPS,
        "fut_steps": F.FUT_STEPS,
        "n_samples": {name: int((samples["split"] == i).sum()) for i, name in enumerate(("train", "val", "test"))},
    }
    (out / "split.json").write_text(json.dumps(meta, indent=2))
    return out


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
    for k in ("nbr_hist", "nbr_group", "nbr_cell"):
        out[k] = samples[k][pair]
    out["nbr_batch"] = np.repeat(np.arange(len(index)), counts)
    out["nbr_ptr"] = np.concatenate([[0], np.cumsum(counts)])
    return out
