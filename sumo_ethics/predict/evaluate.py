"""Held-out evaluation: constant velocity vs CS-LSTM vs attention, per agent group.

On the TEST seeds of a dataset (split by run seed, see dataset.py), for each model and
agent group (vehicle, cyclist, pedestrian, all): RMSE of the mean at 1, 2, 3, 4 s,
ADE (mean displacement over the 20 steps of 0.2 s), FDE (at 4 s) [m], and the mean
bivariate Gaussian NLL per predicted point [nats, positions in metres].
Written as ``prediction_eval.csv`` and ``prediction_eval.md``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from sumo_ethics.predict import features as F
from sumo_ethics.predict.constant_velocity import ConstantVelocityPredictor
from sumo_ethics.predict.dataset import load_samples, subset

HORIZONS_S = (1.0, 2.0, 3.0, 4.0)


def cv_outputs(batch: dict[str, np.ndarray], cv: ConstantVelocityPredictor | None = None) -> np.ndarray:
    """(S, FUT_STEPS, 5) constant-velocity Gaussians in the target frame [m]."""
    cv = cv or ConstantVelocityPredictor()
    n = len(batch["tgt_speed"])
    t = (np.arange(F.FUT_STEPS) + 1) * F.MODEL_DT
    p = cv.predict_arrays(("",) * n, np.zeros((n, 2)), np.zeros(n), batch["tgt_speed"], batch["tgt_cls"], t, F.MODEL_DT)
    sx, sy = np.sqrt(p.cov[..., 0, 0]), np.sqrt(p.cov[..., 1, 1])
    return np.concatenate([p.mean, sx[..., None], sy[..., None], np.zeros_like(sx)[..., None]], axis=-1)


def calibrate_cv(samples: dict[str, np.ndarray], split_code: int = 0, sigma0: float = 0.1) -> ConstantVelocityPredictor:
    """Constant velocity with growth rates fitted on ``split_code`` samples (default train).

    Per group, the RMS longitudinal / lateral error of constant velocity at each horizon
    step is fitted by sigma0 + g * t (least squares through sigma0, g >= 0).
    """
    t = (np.arange(F.FUT_STEPS) + 1) * F.MODEL_DT
    rates = []
    for g in range(F.N_GROUPS):
        m = (samples["split"] == split_code) & (samples["tgt_group"] == g)
        if not m.any():
            rates.append(ConstantVelocityPredictor().growth_table()[g])
            continue
        err = samples["fut"][m].astype(float)
        err[..., 0] -= samples["tgt_speed"][m][:, None] * t
        rms = np.sqrt((err**2).mean(axis=0)) - sigma0  # (T, 2)
        rates.append(np.maximum((t @ rms) / (t @ t), 0.0))
    r = [tuple(float(v) for v in x) for x in rates]
    return ConstantVelocityPredictor(sigma0=sigma0, growth=r[0], growth_cyclist=r[1], growth_pedestrian=r[2])


def lstm_outputs(model, batch: dict[str, np.ndarray], batch_size: int = 1024) -> np.ndarray:
    """(S, FUT_STEPS, 5) model Gaussians in the target frame [m]."""
    import torch

    from sumo_ethics.predict.models import batch_to_tensors

    outs = []
    with torch.inference_mode():
        for start in range(0, len(batch["tgt_speed"]), batch_size):
            b = subset(batch, np.arange(start, min(start + batch_size, len(batch["tgt_speed"]))))
            x = batch_to_tensors(b, model.pos_scale)
            s = model.scale(x["tgt_group"])[:, None, None]
            o = model(**x)
            outs.append(torch.cat([o[..., :4] * s, o[..., 4:]], -1).numpy().astype(float))
    return np.concatenate(outs)


def nll_points(params: np.ndarray, fut: np.ndarray) -> np.ndarray:
    """Per-point bivariate Gaussian NLL (numpy twin of models.bivariate_nll_terms)."""
    mux, muy, sx, sy, rho = np.moveaxis(params, -1, 0)
    dx, dy = (fut[..., 0] - mux) / sx, (fut[..., 1] - muy) / sy
    one_m = 1.0 - rho**2
    return 0.5 * (dx**2 + dy**2 - 2 * rho * dx * dy) / one_m + np.log(sx) + np.log(sy) + 0.5 * np.log(one_m) + np.log(2 * np.pi)


def metrics(params: np.ndarray, fut: np.ndarray) -> dict[str, float]:
    err = np.linalg.norm(params[..., :2] - fut, axis=-1)  # (S, T)
    out: dict[str, float] = {"n": float(len(fut))}
    for h in HORIZONS_S:
        k = int(round(h / F.MODEL_DT)) - 1
        out[f"rmse_{h:g}s"] = float(np.sqrt(np.mean(err[:, k] ** 2)))
    out["ade"] = float(err.mean())
    out["fde"] = float(err[:, -1].mean())
    out["nll"] = float(nll_points(params, fut).mean())
    return out


def evaluate(
    dataset: Path,
    out: Path | None,
    weights: dict[str, Path | str] | None = None,
    max_samples: int | None = 50_000,
    seed: int = 0,
    split: str = "test",
) -> pd.DataFrame:
    """Table of metrics (rows: model x group) on the ``split`` seeds; written to ``out`` if given."""
    from sumo_ethics.predict.models import load_model
    from sumo_ethics.predict.predictor import default_weights

    samples = load_samples(dataset)
    code = {"train": 0, "val": 1, "test": 2}[split]
    idx = np.flatnonzero(samples["split"] == code)
    if max_samples is not None and len(idx) > max_samples:
        idx = np.sort(np.random.default_rng(seed).choice(idx, size=max_samples, replace=False))
    batch = subset(samples, idx)
    if weights is None:
        weights = {k: default_weights(k) for k in ("cslstm", "attention")}
    cv_cal = calibrate_cv(samples)
    outputs = {"constant_velocity": cv_outputs(batch), "constant_velocity_calibrated": cv_outputs(batch, cv_cal)}
    for name, path in weights.items():
        model, _ = load_model(Path(path))
        outputs[name] = lstm_outputs(model, batch)
    fut = batch["fut"].astype(float)
    groups = batch["tgt_group"]
    rows = []
    for name, params in outputs.items():
        for g, gname in [(None, "all"), *enumerate(F.GROUP_NAMES)]:
            sel = np.ones(len(fut), dtype=bool) if g is None else groups == g
            if not sel.any():
                continue
            rows.append({"model": name, "group": gname, **metrics(params[sel], fut[sel])})
    df = pd.DataFrame(rows)
    df["n"] = df["n"].astype(int)
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        df.to_csv(out / "prediction_eval.csv", index=False)
        note = (f"Test seeds only ({len(idx)} samples). constant_velocity_calibrated: growth rates [m/s] (lon, lat) "
                f"fitted on the train seeds: vehicle {tuple(round(v, 3) for v in cv_cal.growth)}, "
                f"cyclist {tuple(round(v, 3) for v in cv_cal.growth_cyclist)}, "
                f"pedestrian {tuple(round(v, 3) for v in cv_cal.growth_pedestrian)}.")
        (out / "prediction_eval.md").write_text(to_markdown(df) + "\n\n" + note + "\n\n" + improvement_summary(df) + "\n")
    return df


def improvement_summary(df: pd.DataFrame) -> str:
    """ADE improvements of attention over constant velocity and CS-LSTM, per group (Markdown)."""
    lines = ["ADE reduction of the attention model (positive = attention better):", ""]
    piv = df.pivot(index="group", columns="model", values="ade")
    for g in piv.index:
        r = piv.loc[g]
        parts = []
        if "attention" in r and "constant_velocity" in r:
            parts.append(f"{100 * (1 - r['attention'] / r['constant_velocity']):+.1f}% vs constant velocity")
        if "attention" in r and "cslstm" in r:
            parts.append(f"{100 * (1 - r['attention'] / r['cslstm']):+.1f}% vs CS-LSTM")
        if parts:
            lines.append(f"- {g}: attention ADE reduction " + ", ".join(parts))
    return "\n".join(lines)


def to_markdown(df: pd.DataFrame, digits: int = 3) -> str:
    """A pipe table without the tabulate dependency."""
    cols = list(df.columns)
    fmt = [lambda v: f"{v:.{digits}f}" if isinstance(v, float) else str(v)]
    lines = ["| " + " | ".join(cols) + " |", "| " + " | ".join("---" for _ in cols) + " |"]
    for _, row in df.iterrows():
        lines.append("| " + " | ".join(fmt[0](row[c]) for c in cols) + " |")
    return "\n".join(lines)
