"""Where a predictor loses against constant velocity: ADE of the most likely mode on subsets of a
dataset's samples (light ahead and its colour, distance to the stop line, how long a red holds,
speed, manoeuvre, and whether the road user really moved). The command line is
tools/prediction_breakdown.py (its docstring says what each column means)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd


def subsets(b: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Named (S,) masks over the samples ``b`` (map scalars as in features.map_features; a light
    100 m away or more has its distance clipped to 100 m, the time a light's state holds at 20 s).
    The "truth" subsets split by where the sample's future really ends (its last valid point), to
    tell the road users who stay from those who leave."""
    from sumo_ethics.predict import features as F
    from sumo_ethics.predict.samples import MANOEUVRES

    sc, speed = b["map_scalar"], b["tgt_speed"]
    light = sc[:, 1] > 0
    dist = sc[:, 2] * F.TLS_DIST_SCALE
    out = {"all": np.ones(len(speed), dtype=bool), "no light ahead": ~light, "red ahead": sc[:, 5] > 0,
           "yellow ahead": sc[:, 4] > 0, "green ahead": sc[:, 3] > 0}
    for lo, hi in ((0, 20), (20, 50), (50, 100), (100, np.inf)):
        out[f"green ahead, {lo}-{hi:g} m"] = (sc[:, 3] > 0) & (dist >= lo) & (dist < hi)
    if sc.shape[1] > 7:  # map version 3 on: how long the light's state holds (clipped at 20 s)
        holds = sc[:, 7] * F.TLS_SWITCH_SCALE
        out["red ahead, ends within 4 s"] = (sc[:, 5] > 0) & (holds < 4.0)
        out["red ahead, holds 8 s or more"] = (sc[:, 5] > 0) & (holds >= 8.0)
    for vlo, vhi in ((0, 0.5), (0.5, 5), (5, 10), (10, np.inf)):
        out[f"speed {vlo}-{vhi:g} m/s"] = (speed >= vlo) & (speed < vhi)
    for i, m in enumerate(MANOEUVRES):
        out[f"m:{m}"] = b["manoeuvre"] == i
    # what really happened: the last valid future point within 0.5 m of where the target is now, or not
    last = np.maximum(b["fut_valid"].sum(1) - 1, 0)
    end = b["fut"][np.arange(len(speed)), last]
    out["truth: ends within 0.5 m"] = np.hypot(end[:, 0], end[:, 1]) <= 0.5
    out["truth: ends over 0.5 m away"] = ~out["truth: ends within 0.5 m"]
    if "map_row0_v4" in b:  # a map version-5 dataset
        out["on a walking area"] = np.any(b["map_pts"][:, 0] != b["map_row0_v4"], axis=(1, 2))
        out["row 0 over 3 m away"] = b["map_valid"][:, 0] & (np.hypot(*b["map_row0_v4"][:, 0].T) > 3.0)
    return out


def breakdown(dataset: Path, group: str = "vehicle", scenarios: list[str] | None = None, moving: bool | None = None,
              models: dict[str, str] | None = None, v5_row: bool = False) -> pd.DataFrame:
    """Rows per subset (``subsets``, those of 20 samples or more): n and the mean ADE [m] of
    constant velocity and of each model's most likely mode, its closest mode of non-zero weight
    (min_ade) and its most likely mode's weight. ``moving``: None all, True those at 0.5 m/s or
    faster now, False the others; ``models``: name -> weights file (default: the shipped map);
    ``v5_row``: also each earlier-version model reading the version-5 row 0 ("NAME, v5 row")."""
    import torch

    from sumo_ethics.predict import features as F
    from sumo_ethics.predict.samples import load_samples, run_scenarios, subset
    from sumo_ethics.predict.accuracy import (
        STANDING_SPEED,
        cv_outputs,
        lstm_outputs,
        metrics,
    )
    from sumo_ethics.predict.models import MAP_KINDS, load_model
    from sumo_ethics.predict.predictor import default_weights

    torch.set_num_threads(1)
    if not (Path(dataset) / "samples.npz").is_file():
        raise ValueError(f"{dataset}: no samples.npz (not a dataset folder)")
    s = load_samples(Path(dataset))
    stem = run_scenarios(Path(dataset))
    name = np.array([stem.get(int(r), "?") for r in s["run_id"]])
    keep = s["tgt_group"] == F.GROUP_NAMES.index(group)
    if scenarios:
        keep &= np.isin(name, scenarios)
    if moving is not None:
        keep &= (s["tgt_speed"] >= STANDING_SPEED) if moving else (s["tgt_speed"] < STANDING_SPEED)
    if not keep.any():
        raise ValueError("no samples left after the filters")
    if v5_row and "map_row0_v4" not in s:
        raise ValueError(f"--v5-row: {dataset} is not a map version-5 dataset (derive it again with "
                         f"'sumo-ethics dataset --samples-from {dataset} --out NEW')")
    b = subset(s, np.flatnonzero(keep))
    fut, valid = b["fut"].astype(float), b["fut_valid"].astype(bool)
    last = valid.sum(1) - 1  # each sample's last valid point (futures are valid from the start without a gap)
    rows = np.arange(len(fut))
    # (S, [M,] T, 5) Gaussians and (S, M) mode weights (None: one mode), as evaluate-predictor has them
    outputs: dict[str, tuple[np.ndarray, np.ndarray | None]] = {"constant velocity": (cv_outputs(b), None)}
    for label, path in (models or {"map": str(default_weights("map"))}).items():
        model, _ = load_model(Path(path))
        outputs[label] = lstm_outputs(model, b)
        if v5_row and model.kind in MAP_KINDS and 2 <= model.map_version < 5:
            outputs[f"{label}, v5 row"] = lstm_outputs(model, {k: v for k, v in b.items() if k != "map_row0_v4"})
    # per sample: how far the most likely mode ends ahead of the truth along the heading [m]
    along = {label: (p if w is None else p[:, 0])[rows, last, 0] - fut[rows, last, 0] for label, (p, w) in outputs.items()}
    table = []
    for key, m in subsets(b).items():
        if m.sum() < 20:
            continue
        row = {"subset": key, "n": int(m.sum())}
        for label, (p, w) in outputs.items():
            met = metrics(p[m], fut[m], valid[m], None if w is None else w[m])  # ADE averaged over valid points
            row[label] = met["ade"]
            if w is not None:
                row[f"{label} min_ade"] = met["min_ade"]
                row[f"{label} top weight"] = float(w[m, 0].mean())
            row[f"{label} along"] = float(along[label][m].mean())
        table.append(row)
    if not table:
        raise ValueError(f"fewer than 20 samples in every subset ({int(keep.sum())} in all)")
    return pd.DataFrame(table)
