"""Fit the predictors' covariance calibration and draw coverage curves before and after.

    python tools/calibrate_predictor.py fit DATA [--models map,map_cslstm,attention,cslstm] [--split val]
    python tools/calibrate_predictor.py report --data test=DATA:test --data never_trained=DATA_NEW:all \
        [--models map] --out docs/predictor_calibration

``fit`` evaluates each shipped model (or NAME=FILE.pt) on the ``--split`` samples of a prediction
dataset (``sumo-ethics dataset``) and writes ``<weights stem>.calibration.json`` beside its weights
file (sumo_ethics/predict/calibration.py says what is fitted, and how).

``report`` evaluates the models, uncalibrated and with their calibration file, on each
``NAME=DATASET:SPLIT`` (split train, val, test or all) and writes into ``--out``:
- ``coverage.csv``: per dataset, model, variant (uncalibrated / calibrated), class group,
  manoeuvre (vehicles and cyclists; the dataset's label of the future, used only to group the
  rows; and "standing now" / "moving now", slower or not than 0.5 m/s when predicted) and horizon (1 s, 2 s, 4 s and "all" steps): points, the share of true positions inside
  the most likely mode's ellipse of nominal mass 10 %, 20 %, ..., 95 % (cov_<level>), in_1sigma,
  in_2sigma, ADE of the most likely mode [m] and the mixture NLL per point [nats];
- ``coverage.md``: the 1- and 2-sigma columns before and after, with NLL and ADE;
- ``coverage.png``: the coverage curves (observed against nominal) before (dashed) and after, and
  ``coverage_by_horizon.png`` for vehicles at 1, 2 and 4 s.
Deterministic: the same datasets, models and seed give the same bytes.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from sumo_ethics.predict import calibration as C
from sumo_ethics.predict import features as F
from sumo_ethics.predict.samples import MANOEUVRES, load_samples, subset
from sumo_ethics.predict.accuracy import lstm_outputs, mixture_nll_points, split_indices, to_markdown

HORIZONS = (1.0, 2.0, 4.0)


def weights_of(spec: str) -> tuple[str, Path]:
    from sumo_ethics.predict.predictor import default_weights

    name, eq, path = spec.partition("=")
    return (name, Path(path)) if eq else (name, default_weights(name))


def model_outputs(path: Path, batch: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    from sumo_ethics.predict import one_thread
    from sumo_ethics.predict.models import load_model

    one_thread(load=True)
    model, _ = load_model(path)
    return lstm_outputs(model, batch)


def cmd_fit(args: argparse.Namespace) -> None:
    batch = load_split(Path(args.dataset), args.split, args.max_samples, args.seed)
    fut = batch["fut"].astype(float)
    valid = batch["fut_valid"] if "fut_valid" in batch else np.ones(fut.shape[:2], dtype=bool)
    for spec in args.models.split(","):
        name, path = weights_of(spec)
        params, weight = model_outputs(path, batch)
        meta = {"fitted_on": f"split {args.split!r} of a dataset of {Path(args.dataset).name}",
                "samples": int(len(fut)), "points": int(valid.sum()), "seed": args.seed,
                "tool": "tools/calibrate_predictor.py fit"}
        sw = C.balanced_weights(batch["tgt_group"], batch["manoeuvre"])  # each future manoeuvre weighs the same
        meta["sample_weight"] = f"balanced over the future manoeuvres of each class group (at least {C.BALANCE_MIN})"
        cal = C.fit(params, weight, batch["tgt_group"], batch["tgt_speed"], fut, valid, sample_weight=sw, meta=meta,
                    weights_sha256=C.file_sha256(path))
        out = cal.write(C.calibration_path(path))
        print(f"{name}: {out}")
        for g, gname in enumerate(F.GROUP_NAMES):
            for s, sname in enumerate(C.STATES):
                lon = " ".join(f"{v:5.2f}" for v in cal.scale[g, s, :, 0])
                lat = " ".join(f"{v:5.2f}" for v in cal.scale[g, s, :, 1])
                print(f"  {gname:10s} {sname:14s} lon [{lon}]  lat [{lat}]  n {cal.n_points[g, s].tolist()}")


def rows_for(dname: str, model: str, variant: str, params: np.ndarray, weight: np.ndarray,
             batch: dict[str, np.ndarray]) -> list[dict]:
    fut = batch["fut"].astype(float)
    valid = batch["fut_valid"] if "fut_valid" in batch else np.ones(fut.shape[:2], dtype=bool)
    group = batch["tgt_group"]
    man = batch["manoeuvre"] if "manoeuvre" in batch else np.full(len(fut), -1)
    nll = mixture_nll_points(params, weight, fut)
    main = params[:, 0]
    err = np.linalg.norm(main[..., :2] - fut, axis=-1)
    m2 = C.mahalanobis2(main, fut)
    sels: list[tuple[str, str, np.ndarray]] = [("all", "all", np.ones(len(fut), dtype=bool))]
    for g, gname in enumerate(F.GROUP_NAMES):
        sels.append((gname, "all", group == g))
        if g != F.GROUP_PEDESTRIAN:
            sels += [(gname, m, (group == g) & (man == i)) for i, m in enumerate(MANOEUVRES)]
        standing = batch["tgt_speed"] < C.STAND_SPEED  # now, not a label of the future
        sels += [(gname, "standing now", (group == g) & standing), (gname, "moving now", (group == g) & ~standing)]
    hsteps = [("all", np.ones(F.FUT_STEPS, dtype=bool))]
    for h in HORIZONS:
        st = np.zeros(F.FUT_STEPS, dtype=bool)
        st[int(round(h / F.MODEL_DT)) - 1] = True
        hsteps.append((f"{h:g}s", st))
    k2 = C.ellipse_k(np.asarray(C.LEVELS)) ** 2
    rows = []
    for gname, mname, sel in sels:
        for hname, st in hsteps:
            v = valid & sel[:, None] & st[None, :]
            n = int(v.sum())
            if n == 0:
                continue
            d = m2[v]
            row = {"dataset": dname, "model": model, "variant": variant, "group": gname, "manoeuvre": mname,
                   "horizon": hname, "samples": int((v.any(axis=1)).sum()), "points": n}
            row.update({f"cov_{int(round(100 * p))}": float((d[:, None] <= k2[None]).mean(axis=0)[i])
                        for i, p in enumerate(C.LEVELS)})
            row["in_1sigma"] = float((d <= 1.0).mean())
            row["in_2sigma"] = float((d <= 4.0).mean())
            row["ade"] = float(err[v].mean())
            row["nll"] = float(nll[v].mean())
            rows.append(row)
    return rows


def cmd_report(args: argparse.Namespace) -> None:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    notes = []
    for spec in args.data:
        dname, _, rest = spec.partition("=")
        dpath, _, split = rest.rpartition(":")
        batch = load_split(Path(dpath), split, args.max_samples, args.seed)
        notes.append(f"- `{dname}`: split `{split}` of a dataset of {Path(dpath).name}, {len(batch['fut'])} samples")
        for mspec in args.models.split(","):
            name, path = weights_of(mspec)
            params, weight = model_outputs(path, batch)
            rows += rows_for(dname, name, "uncalibrated", params, weight, batch)
            cal = C.load_for(path)
            if cal is None:
                print(f"{name}: no calibration file fitted for {path}", file=sys.stderr)
                continue
            rows += rows_for(dname, name, "calibrated", cal.apply(params, weight, batch["tgt_group"], batch["tgt_speed"]), weight, batch)
    df = pd.DataFrame(rows)
    df.to_csv(out / "coverage.csv", index=False, float_format="%.4f")
    (out / "coverage.md").write_text(markdown(df, notes) + "\n")
    plot(df, out / "coverage.png", args.models.split(",")[0].partition("=")[0])
    print(f"wrote {out}/coverage.csv, coverage.md, coverage.png, coverage_by_horizon.png")


def markdown(df: pd.DataFrame, notes: list[str]) -> str:
    key = ["dataset", "model", "group", "manoeuvre", "horizon"]
    before = df[df["variant"] == "uncalibrated"].set_index(key)
    after = df[df["variant"] == "calibrated"].set_index(key)
    t = before[["points"]].copy()
    for col, label in (("in_1sigma", "1-sigma"), ("in_2sigma", "2-sigma"), ("nll", "NLL"), ("ade", "ADE")):
        t[f"{label} before"] = before[col]
        t[f"{label} after"] = after[col].reindex(before.index)
    t = t.reset_index()
    main = t[(t["horizon"] == "all") & (t["points"] >= 50)]
    by_h = t[(t["horizon"] != "all") & t["manoeuvre"].isin(["all", "turn", "lane_change", "hazard", "standing now"])
             & (t["points"] >= 50)]
    pct = lambda x: f"{100 * x:.1f}"  # noqa: E731
    fmt = main.copy()
    for frame in (fmt,):
        for c in frame.columns:
            if "sigma" in c:
                frame[c] = frame[c].map(pct)
    fmt_h = by_h.copy()
    for c in fmt_h.columns:
        if "sigma" in c:
            fmt_h[c] = fmt_h[c].map(pct)
    return "\n".join([
        "# Predictor calibration: coverage before and after", "",
        "Share of true positions [%] inside the most likely mode's 1-sigma ellipse (nominal 39.3 %) and "
        "2-sigma ellipse (nominal 86.5 %), before and after the calibration shipped beside the weights file "
        "(sumo_ethics/predict/calibration.py); NLL: the mixture's, per point [nats]; ADE: the most likely "
        "mode's [m] (the means are untouched, so it cannot change). Manoeuvre: the dataset's label of the "
        "future, used here only to group the rows (the calibration sees only what is known when predicting). "
        "Rows with fewer than 50 points are left out; coverage.csv has them all, and the curves at every level.",
        "", *notes, "", "## All horizon steps (0.2-4 s)", "", to_markdown(fmt), "",
        "## By horizon", "", to_markdown(fmt_h)])


def plot(df: pd.DataFrame, path: Path, model: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    levels = np.asarray(C.LEVELS)
    cols = [f"cov_{int(round(100 * p))}" for p in C.LEVELS]
    series = [("vehicle", "all", "vehicles", "tab:blue"), ("vehicle", "lane_change", "vehicles, lane change", "tab:red"),
              ("vehicle", "turn", "vehicles, turn", "tab:orange"), ("vehicle", "hazard", "hazard actors (vehicles)", "tab:purple"),
              ("vehicle", "standing now", "vehicles standing now", "tab:gray"), ("cyclist", "all", "cyclists", "tab:green"), ("pedestrian", "all", "pedestrians", "tab:brown")]
    datasets = list(dict.fromkeys(df["dataset"]))
    fig, axes = plt.subplots(1, len(datasets), figsize=(6.2 * len(datasets), 6.0), squeeze=False)
    def panel(ax, d: pd.DataFrame, rows: list, title: str) -> None:
        """Coverage curves of ``rows`` (before dashed, after solid) against the nominal diagonal."""
        ax.plot([0, 1], [0, 1], color="0.6", lw=1, label="nominal")
        for g, m, label, colour in rows:
            for variant, style in (("uncalibrated", "--"), ("calibrated", "-")):
                r = d[(d["group"] == g) & (d["manoeuvre"] == m) & (d["variant"] == variant)]
                if r.empty or int(r["points"].iloc[0]) < 50:
                    continue
                ax.plot(levels, r[cols].to_numpy()[0], style, color=colour, marker="o", ms=3,
                        label=f"{label} ({'after' if variant == 'calibrated' else 'before'})")
        ax.set_title(title)
        ax.set_xlabel("nominal mass of the ellipse")
        ax.set_ylabel("share of true positions inside")
        ax.set_xlim(0, 1)
        ax.set_ylim(0, 1)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="lower right")

    for ax, dname in zip(axes[0], datasets):
        d = df[(df["dataset"] == dname) & (df["model"] == model) & (df["horizon"] == "all")]
        ax.axvline(C.TARGET, color="0.85", lw=1)
        panel(ax, d, series, f"{model}: {dname}")
    fig.suptitle("Coverage of the most likely mode's ellipses, all steps 0.2-4 s (dashed: before, solid: after)")
    fig.tight_layout()
    fig.savefig(path, dpi=110, metadata={"Software": None})
    plt.close(fig)
    # by horizon: vehicles, their lane changes and turns, at 1, 2 and 4 s, one row per dataset
    fig, axes = plt.subplots(len(datasets), len(HORIZONS), figsize=(4.6 * len(HORIZONS), 4.4 * len(datasets)),
                             squeeze=False)
    for row, dname in zip(axes, datasets):
        for ax, h in zip(row, HORIZONS):
            d = df[(df["dataset"] == dname) & (df["model"] == model) & (df["horizon"] == f"{h:g}s")]
            panel(ax, d, [*series[:3], series[4]], f"{model}: {dname}, {h:g} s ahead")
    fig.suptitle("Coverage by horizon (dashed: before, solid: after)")
    fig.tight_layout()
    fig.savefig(path.with_name(path.stem + "_by_horizon.png"), dpi=100, metadata={"Software": None})
    plt.close(fig)


def load_split(dataset: Path, split: str, max_samples: int | None, seed: int) -> dict[str, np.ndarray]:
    samples = load_samples(dataset)
    return subset(samples, split_indices(samples, split, max_samples, seed))


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    f = sub.add_parser("fit")
    f.add_argument("dataset")
    f.add_argument("--models", default="map,map_cslstm,attention,cslstm")
    f.add_argument("--split", default="val")
    f.add_argument("--max-samples", type=int, default=60_000)
    f.add_argument("--seed", type=int, default=0)
    r = sub.add_parser("report")
    r.add_argument("--data", action="append", required=True, help="NAME=DATASET:SPLIT (repeat)")
    r.add_argument("--models", default="map")
    r.add_argument("--out", required=True)
    r.add_argument("--max-samples", type=int, default=60_000)
    r.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    cmd_fit(args) if args.cmd == "fit" else cmd_report(args)


if __name__ == "__main__":
    main()
