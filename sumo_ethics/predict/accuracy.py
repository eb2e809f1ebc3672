"""Held-out evaluation: constant velocity vs CS-LSTM vs attention vs map, per agent group and manoeuvre.

On the TEST seeds of a dataset (split by run seed, see samples.py), for each model and
agent group (vehicle, cyclist, pedestrian, all): RMSE of the mean at 1, 2, 3, 4 s,
ADE (mean displacement over the 20 steps of 0.2 s), FDE (at 4 s) [m], and the mean
bivariate Gaussian NLL per predicted point [nats, positions in metres].
Written as ``prediction_eval.csv`` and ``prediction_eval.md``; ``prediction_eval_ci.{csv,md}``
gives each learned model's ADE as a ratio to constant velocity's (and attention's to its CS-LSTM
counterpart's) with a 95 % interval from a bootstrap over the runs (:func:`ratio_intervals`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from sumo_ethics.predict import features as F
from sumo_ethics.predict.constant_velocity import ConstantVelocityPredictor
from sumo_ethics.predict.samples import load_samples, map_version_of, require_nbr_yaw, run_scenarios, subset

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
    r = [(float(x[0]), float(x[1])) for x in rates]  # (along, across) per group
    return ConstantVelocityPredictor(sigma0=sigma0, growth=r[0], growth_cyclist=r[1], growth_pedestrian=r[2])


def lstm_outputs(model, batch: dict[str, np.ndarray], batch_size: int = 1024) -> tuple[np.ndarray, np.ndarray]:
    """Model Gaussians in the target frame [m]: (S, M, FUT_STEPS, 5) every mode, the most likely
    first, and (S, M) mode weights (M = 1, weight 1, for a single-mode model)."""
    import torch

    from sumo_ethics.predict.models import MAP_KINDS, batch_to_tensors, rank_modes

    outs, weights = [], []
    with torch.inference_mode():
        for start in range(0, len(batch["tgt_speed"]), batch_size):
            b = subset(batch, np.arange(start, min(start + batch_size, len(batch["tgt_speed"]))))
            x = batch_to_tensors(b, model.pos_scale, with_map=model.kind in MAP_KINDS, map_version=model.map_version)
            s = model.scale(x["tgt_group"])[:, None, None, None]
            o, log_w = rank_modes(*model(**x, all_modes=True))
            outs.append(torch.cat([o[..., :4] * s, o[..., 4:]], -1).numpy().astype(float))
            weights.append(np.exp(log_w.numpy().astype(float)))
    return np.concatenate(outs), np.concatenate(weights)


def nll_points(params: np.ndarray, fut: np.ndarray) -> np.ndarray:
    """Per-point bivariate Gaussian NLL (numpy twin of models.bivariate_nll_terms)."""
    mux, muy, sx, sy, rho = np.moveaxis(params, -1, 0)
    dx, dy = (fut[..., 0] - mux) / sx, (fut[..., 1] - muy) / sy
    one_m = 1.0 - rho**2
    return 0.5 * (dx**2 + dy**2 - 2 * rho * dx * dy) / one_m + np.log(sx) + np.log(sy) + 0.5 * np.log(one_m) + np.log(2 * np.pi)


def mahalanobis2(params: np.ndarray, fut: np.ndarray) -> np.ndarray:
    """Squared Mahalanobis distance of each true point from its predicted Gaussian."""
    mux, muy, sx, sy, rho = np.moveaxis(params, -1, 0)
    dx, dy = (fut[..., 0] - mux) / sx, (fut[..., 1] - muy) / sy
    return (dx**2 + dy**2 - 2 * rho * dx * dy) / (1.0 - rho**2)


#: probability mass inside the 1- and 2-sigma ellipse of a 2D Gaussian (1 - exp(-k^2 / 2))
ELLIPSE_MASS = {1: 1.0 - np.exp(-0.5), 2: 1.0 - np.exp(-2.0)}


def mixture_nll_points(params: np.ndarray, weight: np.ndarray, fut: np.ndarray) -> np.ndarray:
    """(S, T) per-point NLL under each point's mixture of the modes' Gaussians: params (S, M, T, 5),
    weight (S, M), fut (S, T, 2). Equals :func:`nll_points` for one mode of weight 1."""
    logp = np.log(np.maximum(weight, 1e-300))[:, :, None] - nll_points(params, fut[:, None])  # (S, M, T)
    top = logp.max(axis=1)
    return -(top + np.log(np.exp(logp - top[:, None]).sum(axis=1)))


def metrics(params: np.ndarray, fut: np.ndarray, valid: np.ndarray | None = None,
            weight: np.ndarray | None = None) -> dict[str, float]:
    """RMSE at 1-4 s, ADE, FDE [m], NLL per point [nats] and the share of true points inside the
    predicted 1- and 2-sigma ellipses (in_1sigma, in_2sigma; a calibrated Gaussian gives 0.393
    and 0.865). ``valid`` (S, T) restricts every term to observed future points (FDE: each
    sample's last observed one; the RMSE at a horizon: the samples observed then).

    params (S, T, 5), or (S, M, T, 5) with ``weight`` (S, M) for M modes, the most likely first:
    the displacement errors and the ellipses are those of the most likely mode, the NLL that of
    the mixture; min_ade is the ADE of each sample's closest mode of non-zero weight (= ade for one mode)."""
    if weight is None:
        params, weight = params[:, None], np.ones((len(params), 1))
    modes = params
    params = modes[:, 0]
    err = np.linalg.norm(params[..., :2] - fut, axis=-1)  # (S, T)
    valid = np.ones(err.shape, dtype=bool) if valid is None else np.asarray(valid, dtype=bool)
    out: dict[str, float] = {"n": float(len(fut))}
    for h in HORIZONS_S:
        k = int(round(h / F.MODEL_DT)) - 1
        v = valid[:, k]
        out[f"rmse_{h:g}s"] = float(np.sqrt(np.mean(err[v, k] ** 2))) if v.any() else float("nan")
    out["ade"] = float(err[valid].mean())
    err_m = np.linalg.norm(modes[..., :2] - fut[:, None], axis=-1)  # (S, M, T)
    per_mode = (err_m * valid[:, None]).sum(-1) / np.maximum(valid.sum(-1), 1)[:, None]
    per_mode = np.where(weight > 0, per_mode, np.inf)  # a mode of weight 0 is no prediction
    out["min_ade"] = float((per_mode.min(axis=1) * valid.sum(-1)).sum() / valid.sum())
    last = valid.sum(axis=1) - 1
    out["fde"] = float(err[np.arange(len(err)), last].mean())
    out["nll"] = float(mixture_nll_points(modes, weight, fut)[valid].mean())
    m2 = mahalanobis2(params, fut)[valid]
    out["in_1sigma"] = float((m2 <= 1.0).mean())
    out["in_2sigma"] = float((m2 <= 4.0).mean())
    return out


#: [m/s] below this a vehicle or cyclist counts as standing in the evaluation's groups <class>:standing
#: and <class>:moving (a standing one either stays, where constant velocity is exact, or starts)
STANDING_SPEED = 0.5


def split_indices(samples: dict[str, np.ndarray], split: str, max_samples: int | None = None,
                  seed: int = 0) -> np.ndarray:
    """Indices of one split ("train", "val", "test" or "all") of a dataset's samples, at most
    ``max_samples`` of them (a seeded draw, kept in order)."""
    if split == "all":
        idx = np.arange(len(samples["split"]))
    else:
        idx = np.flatnonzero(samples["split"] == {"train": 0, "val": 1, "test": 2}[split])
    if max_samples is not None and len(idx) > max_samples:
        idx = np.sort(np.random.default_rng(seed).choice(idx, size=max_samples, replace=False))
    return idx


def evaluate(
    dataset: Path,
    out: Path | None,
    weights: dict[str, Path | str] | None = None,
    max_samples: int | None = 50_000,
    seed: int = 0,
    split: str = "test",
    calibration_dataset: Path | None = None,
    title: str | None = None,
    calibrated: bool = False,
) -> pd.DataFrame:
    """Table of metrics (rows: model x group, group = a class or, for vehicles and cyclists, a
    manoeuvre ``m:<name>``) on the ``split`` seeds ("all": every sample, for a dataset of
    scenarios never trained on); written to ``out`` if given. The calibrated constant velocity
    is fitted on the train split of ``calibration_dataset`` (default: ``dataset``). ``calibrated``:
    also a row ``<name>_calibrated`` for every model with a covariance calibration beside its
    weights file (predict/calibration.py: the same means, other spreads)."""
    from sumo_ethics.predict.samples import MANOEUVRES
    from sumo_ethics.predict.models import KINDS, MAP_KINDS, load_model
    from sumo_ethics.predict.predictor import default_weights

    samples = load_samples(dataset)
    idx = split_indices(samples, split, max_samples, seed)
    batch = subset(samples, idx)
    if weights is None:
        weights = {k: default_weights(k) for k in KINDS if default_weights(k).is_file()}
    cal_samples = samples if calibration_dataset is None else load_samples(calibration_dataset)
    cv_cal = calibrate_cv(cal_samples)
    outputs: dict[str, tuple[np.ndarray, np.ndarray | None]] = {
        "constant_velocity": (cv_outputs(batch), None), "constant_velocity_calibrated": (cv_outputs(batch, cv_cal), None)}
    data_map_version = map_version_of(dataset)
    for name, path in weights.items():
        model, _ = load_model(Path(path))
        if model.kind in MAP_KINDS and model.map_version > data_map_version:
            from sumo_ethics.predict import PredictorError

            raise PredictorError(f"{name} ({path}) reads map version {model.map_version}, "
                                 f"dataset {dataset} has version {data_map_version}: build the dataset again")
        if model.nbr_frame == "agent":
            require_nbr_yaw(batch, dataset, who=f"{name} ({path})")
        model_out = outputs[name] = lstm_outputs(model, batch)
        if calibrated:
            from sumo_ethics.predict.calibration import load_for

            cal = load_for(path)
            if cal is not None:
                lstm_params, lstm_weight = model_out  # with the model's weights (never None)
                outputs[f"{name}_calibrated"] = (cal.apply(lstm_params, lstm_weight, batch["tgt_group"], batch["tgt_speed"]),
                                                 lstm_weight)
    fut = batch["fut"].astype(float)
    valid = batch["fut_valid"] if "fut_valid" in batch else np.ones(fut.shape[:2], dtype=bool)
    groups = batch["tgt_group"]
    selections: list[tuple[str, np.ndarray]] = [("all", np.ones(len(fut), dtype=bool))]
    selections += [(g, groups == i) for i, g in enumerate(F.GROUP_NAMES)]
    standing = batch["tgt_speed"] < STANDING_SPEED
    for i in (F.GROUP_VEHICLE, F.GROUP_CYCLIST, F.GROUP_PEDESTRIAN):
        selections += [(f"{F.GROUP_NAMES[i]}:standing", (groups == i) & standing),
                       (f"{F.GROUP_NAMES[i]}:moving", (groups == i) & ~standing)]
    if "manoeuvre" in batch:
        selections += [(f"m:{m}", batch["manoeuvre"] == i) for i, m in enumerate(MANOEUVRES)]
    rows = []
    for name, (params, weight) in outputs.items():
        for gname, sel in selections:
            if not sel.any():
                continue
            rows.append({"model": name, "group": gname,
                         **metrics(params[sel], fut[sel], valid[sel], None if weight is None else weight[sel])})
    df = pd.DataFrame(rows)
    df["n"] = df["n"].astype(int)
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        df.to_csv(out / "prediction_eval.csv", index=False)
        what = "Test seeds only" if split == "test" else f"Split {split!r}"
        note = (f"{title + ': ' if title else ''}{what} of {dataset} ({len(idx)} samples). Groups m:<manoeuvre> are vehicles "
                f"and cyclists by manoeuvre (dataset.manoeuvre_labels); <class>:standing are those slower than "
                f"{STANDING_SPEED} m/s now, <class>:moving the others. in_1sigma / in_2sigma: share of true "
                f"positions inside the predicted 1- and 2-sigma ellipses (a calibrated Gaussian: 0.393 / 0.865). "
                f"Multi-modal models: ade, fde, rmse and the ellipses are those of the most likely mode, nll that "
                f"of the mixture, min_ade that of each sample's closest mode of non-zero weight (= ade for one mode). "
                f"constant_velocity_calibrated: growth rates [m/s] (lon, lat) "
                f"fitted on the train seeds: vehicle {tuple(round(v, 3) for v in cv_cal.growth)}, "
                f"cyclist {tuple(round(v, 3) for v in cv_cal.growth_cyclist)}, "
                f"pedestrian {tuple(round(v, 3) for v in cv_cal.growth_pedestrian)}.")
        (out / "prediction_eval.md").write_text(to_markdown(df) + "\n\n" + note + "\n\n" + improvement_summary(df) + "\n")
        names = run_scenarios(dataset) if split == "all" else {}
        scenario = np.array([names.get(int(r), "?") for r in batch["run_id"]]) if names else None
        if "run_id" in batch:
            per_scenario = [] if scenario is None else [
                (f"{scen}/{g}", sel) for scen, g, sel in scenario_selections(scenario, groups)]
            ci = ratio_intervals(outputs, fut, valid, batch["run_id"], selections + per_scenario)
            ci.to_csv(out / "prediction_eval_ci.csv", index=False)
            (out / "prediction_eval_ci.md").write_text(ci_markdown(ci) + f"\n\nADE of the most likely mode over "
                f"that of the reference ({what.lower()} of {dataset}, the samples of prediction_eval.md): below 1 "
                "the model is better. 95 % interval: 2.5th-97.5th percentile over 2,000 resamples of the runs "
                "(samples of one run are road users seconds apart, not independent); an interval holding 1 "
                "does not tell the two apart, and one from few runs is rough. Groups <scenario>/<class>: the "
                "samples of one scenario (every suite scenario together as 'suite').\n")
        if scenario is not None:
            by = by_scenario(outputs, batch, scenario)
            by.to_csv(out / "prediction_eval_by_scenario.csv", index=False)
            wide = by.pivot_table(index=["scenario", "group", "n"], columns="model", values="ade", sort=False).reset_index()
            (out / "prediction_eval_by_scenario.md").write_text(
                to_markdown(wide) + f"\n\nADE [m] of the most likely mode per scenario and class ({dataset}; every "
                f"suite scenario together as 'suite'), the same samples as prediction_eval.md.\n")
    return df


def by_scenario(outputs: dict[str, tuple[np.ndarray, np.ndarray | None]], batch: dict[str, np.ndarray],
                scenario: np.ndarray) -> pd.DataFrame:
    """Rows (model, scenario, group, n, ade, fde, nll) per class group and scenario: outputs as in
    :func:`evaluate`, scenario (S,) the name of each sample's scenario."""
    fut = batch["fut"].astype(float)
    valid = batch["fut_valid"] if "fut_valid" in batch else np.ones(fut.shape[:2], dtype=bool)
    rows = []
    for name, (params, weight) in outputs.items():
        for scen, g, sel in scenario_selections(scenario, batch["tgt_group"]):
            if sel.any():
                m = metrics(params[sel], fut[sel], valid[sel], None if weight is None else weight[sel])
                rows.append({"model": name, "scenario": scen, "group": g, "n": int(sel.sum()),
                             "ade": m["ade"], "fde": m["fde"], "nll": m["nll"]})
    return pd.DataFrame(rows)


def scenario_selections(scenario: np.ndarray, group: np.ndarray) -> list[tuple[str, str, np.ndarray]]:
    """(scenario, class group name, (S,) mask) for every scenario (sorted) and class group of the
    samples: scenario (S,) each sample's scenario name, group (S,) its class group."""
    return [(scen, g, (scenario == scen) & (group == i))
            for scen in sorted(set(scenario.tolist())) for i, g in enumerate(F.GROUP_NAMES)]


#: classes a selection score averages over (docs/predictor_seeds.md, "How a shipped file is chosen")
SELECTION_CLASSES = ("vehicle", "cyclist", "pedestrian")


def selection_scores(tables: dict[str, pd.DataFrame], min_samples: int = 500,
                     reference: str = "constant_velocity") -> pd.DataFrame:
    """Score of every learned model over several evaluation tables (:func:`evaluate` outputs, one
    per selection dataset): for each table and class with at least ``min_samples`` samples, its
    ADE divided by the ``reference`` model's; the score is the mean of these ratios (lower is
    better). Rows: models by score; columns ``<table>:<class>`` ratios and ``score``."""
    ratios: dict[str, pd.Series] = {}
    for name, df in tables.items():
        rows = df[df["group"].isin(SELECTION_CLASSES) & (df["n"] >= min_samples)]
        ade = rows.pivot(index="model", columns="group", values="ade")
        for cls in SELECTION_CLASSES:
            if cls in ade.columns and reference in ade.index and ade.loc[reference, cls] > 0:
                ratios[f"{name}:{cls}"] = ade[cls] / ade.loc[reference, cls]
    out = pd.DataFrame(ratios)
    out = out[[not m.startswith(reference) for m in out.index]]
    out["score"] = out.mean(axis=1)
    return out.sort_values("score")


#: (model, reference) pairs whose ADE ratio :func:`improvement_summary` and :func:`ratio_intervals`
#: report besides every learned model against constant velocity: the attention ablation
ABLATION_PAIRS = (("attention", "cslstm"), ("map", "map_cslstm"), ("map_agent", "map_cslstm"), ("map", "attention"),
                  ("map_cslstm", "cslstm"))


def ratio_intervals(outputs: dict[str, tuple[np.ndarray, np.ndarray | None]], fut: np.ndarray, valid: np.ndarray,
                    run_id: np.ndarray, selections: list[tuple[str, np.ndarray]], n_boot: int = 2000,
                    seed: int = 0) -> pd.DataFrame:
    """ADE ratios with 95 % intervals: rows (model, reference, group, n, runs, ade, ade_reference,
    ratio, lo, hi) for every learned model against constant velocity and for ABLATION_PAIRS.

    outputs as in :func:`evaluate` (the most likely mode, index 0, is scored); fut (S, T, 2),
    valid (S, T), run_id (S,) each sample's run; selections: (group, (S,) mask). The ratio is
    that of the two ADEs (point errors summed over valid points); the interval is the 2.5th and
    97.5th percentile of the ratio over ``n_boot`` resamples of the group's runs with replacement
    (samples of one run are not independent: the same road users, seconds apart). ratio < 1:
    the model is better; an interval that holds 1 does not tell the two apart. Few runs give a
    rough interval (the ``runs`` column says how many)."""
    names = list(outputs)
    learned = [m for m in names if not m.startswith("constant_velocity")]
    pairs = [(m, "constant_velocity") for m in learned if "constant_velocity" in outputs]
    pairs += [(m, r) for m, r in ABLATION_PAIRS if m in outputs and r in outputs]
    err = {}
    for m in {x for pair in pairs for x in pair}:
        params = outputs[m][0]
        mean = params[:, 0, :, :2] if params.ndim == 4 else params[..., :2]
        err[m] = (np.linalg.norm(mean - fut, axis=-1) * valid).sum(axis=1)  # (S,) summed point errors
    rng = np.random.default_rng(seed)
    rows = []
    for gname, sel in selections:
        if not sel.any():
            continue
        runs, inv = np.unique(run_id[sel], return_inverse=True)
        counts = rng.multinomial(len(runs), np.full(len(runs), 1.0 / len(runs)), size=n_boot)  # (B, R)
        pts = valid[sel].sum()
        for m, ref in pairs:
            a = np.bincount(inv, weights=err[m][sel], minlength=len(runs))  # (R,) per run
            b = np.bincount(inv, weights=err[ref][sel], minlength=len(runs))
            ratio = a.sum() / b.sum() if b.sum() > 0 else np.nan
            with np.errstate(divide="ignore", invalid="ignore"):
                boot = (counts @ a) / (counts @ b)
            lo, hi = np.nanpercentile(boot, [2.5, 97.5]) if np.isfinite(boot).any() else (np.nan, np.nan)
            rows.append({"model": m, "reference": ref, "group": gname, "n": int(sel.sum()), "runs": len(runs),
                         "ade": a.sum() / pts, "ade_reference": b.sum() / pts, "ratio": ratio, "lo": lo, "hi": hi})
    return pd.DataFrame(rows)


def improvement_summary(df: pd.DataFrame) -> str:
    """ADE improvements per group (Markdown): every learned model over constant velocity, and each
    attention model over its CS-LSTM counterpart (attention/cslstm, map/map_cslstm)."""
    lines = ["ADE reduction (positive = better):", ""]
    piv = df.pivot(index="group", columns="model", values="ade")
    learned = [m for m in piv.columns if not m.startswith("constant_velocity")]  # shipped or named by --model
    pairs = [(m, "constant_velocity", "constant velocity") for m in learned]
    pairs += [(m, ref, "CS-LSTM" if ref == "cslstm" else ref) for m, ref in ABLATION_PAIRS]
    for g in piv.index:
        r = piv.loc[g]
        parts = []
        for m, ref, label in pairs:
            if m in r and ref in r and r[ref] > 0:  # a reference of exactly 0 m (all standing) has no ratio
                parts.append(f"{m} {100 * (1 - r[m] / r[ref]):+.1f}% vs {label}")
        if parts:
            lines.append(f"- {g}: " + ", ".join(parts))
    return "\n".join(lines)


def ci_markdown(ci: pd.DataFrame) -> str:
    """:func:`ratio_intervals` rows as a pipe table, the interval in one column."""
    if ci.empty:
        return "(no learned model)"
    t = ci[["model", "reference", "group", "n", "runs", "ade", "ade_reference", "ratio"]].copy()
    t["95 % interval"] = [f"{lo:.3f}-{hi:.3f}" for lo, hi in zip(ci["lo"], ci["hi"])]
    return to_markdown(t)


def to_markdown(df: pd.DataFrame, digits: int = 3) -> str:
    """A pipe table without the tabulate dependency."""
    cols = list(df.columns)
    fmt = [lambda v: f"{v:.{digits}f}" if isinstance(v, float) else str(v)]
    lines = ["| " + " | ".join(cols) + " |", "| " + " | ".join("---" for _ in cols) + " |"]
    for _, row in df.iterrows():
        lines.append("| " + " | ".join(fmt[0](row[c]) for c in cols) + " |")
    return "\n".join(lines)
