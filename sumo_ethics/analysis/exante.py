"""Ex-ante risk: the risk the chosen trajectory puts on each class of road user, per run.

Every planning step records the chosen candidate's risk (collision probability x harm, the
maximum over its horizon) per party class, summed and maximised over the parties
(``steps.parquet`` columns ``cost_{ego,other,vru}_risk_{sum,max}``; "other" = third parties,
VRUs among them). Per run this module reduces them to

- ``risk_<cls>_mean``: the mean over the run's planning steps of the summed risk to the class;
- ``risk_<cls>_peak``: the largest risk any single party of the class carried at any step;
- ``risk_total_mean``: ego + third party; ``risk_worst_peak``: the largest of the class peaks
  (the worst-off party's risk, what Maximin looks after); ``risky_share``: the share of steps
  whose chosen candidate has any risk.

Steps without planner terms (baseline controller, emergency braking) are skipped; a run with
none gives NaN. This is the analysis of Geisslinger et al. (2023): the distribution of risk a
setting puts on each class, visible even where nobody collides.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

#: class label -> the steps.parquet columns (sum over parties, max over parties)
CLASSES = {"ego": ("cost_ego_risk_sum", "cost_ego_risk_max"),
           "third_party": ("cost_other_risk_sum", "cost_other_risk_max"),
           "vru": ("cost_vru_risk_sum", "cost_vru_risk_max")}
LABELS = {"ego": "Ego", "third_party": "Third party", "vru": "VRU"}
#: the steps.parquet columns a per-run summary is made from
INPUTS = tuple(col for pair in CLASSES.values() for col in pair)
COLUMNS = tuple(f"risk_{c}_{k}" for c in CLASSES for k in ("mean", "peak")) + (
    "risk_total_mean", "risk_worst_peak", "risky_share")


def run_risk(steps: pd.DataFrame) -> dict[str, float]:
    """The per-run ex-ante risk summary (module doc) of one run's steps table."""
    if not set(INPUTS) <= set(steps.columns):
        return {k: float("nan") for k in COLUMNS}
    s = steps[list(INPUTS)].dropna()
    if s.empty:
        return {k: float("nan") for k in COLUMNS}
    out: dict[str, float] = {}
    for c, (col_sum, col_max) in CLASSES.items():
        out[f"risk_{c}_mean"] = float(s[col_sum].mean())
        out[f"risk_{c}_peak"] = float(s[col_max].max())
    out["risk_total_mean"] = out["risk_ego_mean"] + out["risk_third_party_mean"]
    out["risk_worst_peak"] = max(out["risk_ego_peak"], out["risk_third_party_peak"])
    out["risky_share"] = float(((s["cost_ego_risk_sum"] + s["cost_other_risk_sum"]) > 0).mean())
    return out


def run_risk_file(run_dir: Path) -> dict[str, float]:
    """:func:`run_risk` of ``run_dir/steps.parquet`` (NaNs when it is missing or unreadable)."""
    try:
        steps = pd.read_parquet(Path(run_dir) / "steps.parquet", columns=list(INPUTS))
    except Exception:  # noqa: BLE001 - no planner columns, no file, a truncated file
        return {k: float("nan") for k in COLUMNS}
    return run_risk(steps)


def per_run(steps: pd.DataFrame, keys: Sequence[str] = ("run_id",)) -> pd.DataFrame:
    """:func:`run_risk` for every run of a tidy steps table (one row per run, ``keys`` kept)."""
    rows = [{**dict(zip(keys, k if isinstance(k, tuple) else (k,))), **run_risk(g)}
            for k, g in steps.groupby(list(keys), sort=True, observed=True)]
    return pd.DataFrame(rows, columns=[*keys, *COLUMNS])


def risk_table(runs: pd.DataFrame, by: Sequence[str], n_boot: int = 2000, seed: int = 0) -> pd.DataFrame:
    """Per group of ``by`` and class: runs, median, mean [95 % bootstrap CI] of the per-run mean
    risk, and the median per-run peak."""
    from sumo_ethics.analysis.stats import bootstrap_ci

    rows = []
    for key, g in runs.groupby(list(by), sort=True, observed=True):
        key = key if isinstance(key, tuple) else (key,)
        for c in (*CLASSES, "total"):
            x = g[f"risk_{c}_mean"].dropna().to_numpy()
            lo, hi = bootstrap_ci(x, n_boot=n_boot, seed=seed) if len(x) else (np.nan, np.nan)
            peak = g[f"risk_{c}_peak"].dropna() if c != "total" else g["risk_worst_peak"].dropna()
            rows.append({**dict(zip(by, key)), "class": c, "runs": len(x),
                         "mean": float(x.mean()) if len(x) else np.nan, "ci_lo": lo, "ci_hi": hi,
                         "median": float(np.median(x)) if len(x) else np.nan,
                         "peak_median": float(peak.median()) if len(peak) else np.nan})
    return pd.DataFrame(rows)


def risk_boxplot(runs: pd.DataFrame, by: str, folder: Path, name: str = "exante_risk",
                 order: Sequence | None = None, title: str = "") -> list[Path]:
    """Box plots (one panel per class: ego, third party, VRU) of the per-run mean ex-ante risk
    for each value of ``by``; symlog y axis (risks span orders of magnitude and may be 0).
    PNG and SVG in ``folder``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib import ticker

    values = list(order) if order is not None else sorted(runs[by].dropna().unique(), key=lambda v: (str(type(v)), v))
    names = [f"{v:g}" if isinstance(v, (float, np.floating)) else str(v) for v in values]
    fig, axes = plt.subplots(3, 1, figsize=(max(7.0, 0.8 * len(values) + 2.5), 9.5), sharex=True)
    colours = plt.get_cmap("tab10")
    for ax, c in zip(axes, CLASSES):
        data = [runs.loc[runs[by] == v, f"risk_{c}_mean"].dropna().to_numpy() for v in values]
        bp = ax.boxplot(data, patch_artist=True, widths=0.6, showfliers=True,
                        flierprops={"markersize": 3, "alpha": 0.6}, medianprops={"color": "black"})
        for i, patch in enumerate(bp["boxes"]):
            patch.set_facecolor(colours(i % 10))
            patch.set_alpha(0.55)
        for i, d in enumerate(data):  # mean as a white diamond
            if len(d):
                ax.plot(i + 1, d.mean(), marker="D", color="white", markeredgecolor="black", markersize=5, zorder=3)
        ax.set_title(LABELS[c] + (" (VRUs included)" if c == "third_party" else ""), loc="left", fontsize=10)
        ax.set_yscale("symlog", linthresh=1e-4)
        # labels at 1, 2 and 5 x 10^k: risks often span less than a decade
        ax.yaxis.set_major_locator(ticker.SymmetricalLogLocator(base=10, linthresh=1e-4, subs=(1.0, 2.0, 5.0)))
        ax.yaxis.set_major_formatter(ticker.FuncFormatter(lambda y, _: "0" if y == 0 else f"{y:.0e}".replace("e-0", "e-")))
        ax.yaxis.set_minor_locator(ticker.NullLocator())
        top = max((float(d.max()) for d in data if len(d)), default=1e-4)
        ax.set_ylim(0.0, max(top, 1e-4) * 1.6)
        ax.grid(axis="y", alpha=0.3)
        ax.set_ylabel("risk per step")
    counts = [int(runs.loc[runs[by] == v, "risk_total_mean"].notna().sum()) for v in values]
    labels = [f"{n}\n({k} runs)" for n, k in zip(names, counts)]
    long = max(map(len, names)) > 6
    axes[-1].set_xticks(range(1, len(values) + 1), labels, rotation=30 if long else 0, ha="right" if long else "center")
    axes[-1].set_xlabel(by)
    fig.suptitle(title or f"Ex-ante risk of the chosen trajectory [P(MAIS3+)], per-run mean, by {by}\n"
                 "box: quartiles, whiskers 1.5 IQR, ◆ mean; symlog axis, linear below 1e-4", fontsize=10)
    fig.tight_layout()
    folder.mkdir(parents=True, exist_ok=True)
    paths = [folder / f"{name}.png", folder / f"{name}.svg"]
    for p in paths:
        fig.savefig(p, dpi=130)
    plt.close(fig)
    return paths
