"""Figures of a sweep (matplotlib, Agg backend), each saved as PNG and SVG.

- harm per class vs the first ``--by`` key (w_u by default), means with bootstrap 95% CI bands;
- completion and ego-collision rate vs that key;
- distribution of harm per ego collision by class (ego / third party / VRU);
- ego-vs-third-party harm per run (trade-off scatter), coloured by w_u.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from sumo_ethics.analysis.stats import ego_collision_harm  # noqa: E402

CLASS_COLOURS = {"ego": "#1f77b4", "third party": "#ff7f0e", "VRU": "#d62728", "total": "#444444"}
LABELS = {"omega_u": "utility weight $w_u$ [-]", "omega_o": "origin weight $w_o$ [-]",
          "max_risk": "max risk [-]", "end": "time limit [s]", "ego_depart": "ego departure [s]",
          "radius": "sensing radius [m]", "seed": "seed"}
HARM_LABEL = "harm per run [-]"


def _label(key: str) -> str:
    return LABELS.get(key, key)


def _save(fig, folder: Path, name: str) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    paths = [folder / f"{name}.png", folder / f"{name}.svg"]
    fig.savefig(paths[0], dpi=110, bbox_inches="tight")
    fig.savefig(paths[1], bbox_inches="tight")
    plt.close(fig)
    return paths


def _hues(summary: pd.DataFrame, by: Sequence[str]) -> list[tuple[str, pd.DataFrame]]:
    """(label, rows) per combination of the --by keys after the first (one unlabelled group if none)."""
    rest = list(by[1:])
    if not rest:
        return [("", summary)]
    out = []
    for key, g in summary.groupby(rest, sort=True, dropna=False):
        key = key if isinstance(key, tuple) else (key,)
        out.append((", ".join(f"{k}={v}" for k, v in zip(rest, key)), g))
    return out


def _is_numeric(s: pd.Series) -> bool:
    return pd.api.types.is_numeric_dtype(s) and not pd.api.types.is_bool_dtype(s)


def _wide(values) -> bool:
    """Values spanning two or more decades (e.g. w_u = 0, 1, 10, 100): plot on a symlog axis."""
    v = np.abs(np.asarray(values, dtype=float))
    pos = v[v > 0]
    return len(pos) >= 2 and pos.max() / pos.min() >= 100


def _scale_x(ax, values) -> None:
    v = np.asarray(values, dtype=float)
    if _wide(v):
        pos = np.abs(v[v != 0])
        ax.set_xscale("symlog", linthresh=float(pos.min()))
        ax.set_xticks(sorted(set(v.tolist())), [f"{x:g}" for x in sorted(set(v.tolist()))])


def _line_ci(ax, g: pd.DataFrame, x: str, col: str, colour, label: str, marker: str = "o") -> None:
    g = g.sort_values(x)
    xs = g[x].to_numpy() if _is_numeric(g[x]) else np.arange(len(g))
    ax.plot(xs, g[f"{col}"].to_numpy(), marker=marker, color=colour, label=label, lw=1.8, ms=5)
    ax.fill_between(xs, g[f"{col}_ci_lo"].to_numpy(dtype=float), g[f"{col}_ci_hi"].to_numpy(dtype=float),
                    color=colour, alpha=0.18, lw=0)
    if not _is_numeric(g[x]):
        ax.set_xticks(xs, [str(v) for v in g[x]])
    else:
        _scale_x(ax, xs)


def harm_vs_parameter(summary: pd.DataFrame, by: Sequence[str], folder: Path) -> list[Path]:
    x = by[0]
    hues = _hues(summary, by)
    panels = [("harm_ego", "ego"), ("harm_third_party", "third party"), ("harm_vru", "VRU")]
    fig, axes = plt.subplots(1, 3, figsize=(13, 4), sharey=True)
    cmap = plt.get_cmap("tab10")
    for ax, (col, cls) in zip(axes, panels):
        for i, (label, g) in enumerate(hues):
            colour = CLASS_COLOURS[cls] if len(hues) == 1 else cmap(i % 10)
            g = g.rename(columns={f"{col}_mean": col})
            _line_ci(ax, g, x, col, colour, label or f"{cls}: mean, 95% CI")
        ax.set_title(f"harm to {cls}")
        ax.set_xlabel(_label(x))
        ax.grid(alpha=0.3)
        if len(hues) == 1:
            ax.legend(fontsize=8, loc="best")
    if len(hues) > 1:  # one legend for the three panels, below them
        handles, labels = axes[0].get_legend_handles_labels()
        fig.legend(handles, [f"{lab} (mean, 95% CI band)" for lab in labels], loc="lower center",
                   ncol=min(len(hues), 4), fontsize=9, frameon=False, bbox_to_anchor=(0.5, -0.06))
    axes[0].set_ylabel("mean harm per run [-]\n(P(MAIS 3+), summed over collisions)")
    n = int(summary["n_runs"].min()), int(summary["n_runs"].max())
    fig.suptitle(f"Harm per class vs {_label(x)} (bootstrap 95% CI over runs, {n[0]}-{n[1]} runs per point)"
                 if n[0] != n[1] else
                 f"Harm per class vs {_label(x)} (bootstrap 95% CI over runs, {n[0]} runs per point)")
    fig.tight_layout()
    return _save(fig, folder, "harm_vs_" + x.replace(".", "_"))


def completion_vs_parameter(summary: pd.DataFrame, by: Sequence[str], folder: Path) -> list[Path]:
    x = by[0]
    hues = _hues(summary, by)
    fig, ax = plt.subplots(figsize=(7, 4.2))
    cmap = plt.get_cmap("tab10")
    for i, (label, g) in enumerate(hues):
        suffix = f" ({label})" if label else ""
        _line_ci(ax, g, x, "completion_rate", cmap((2 * i) % 10), f"completed{suffix}")
        _line_ci(ax, g, x, "collision_rate", cmap((2 * i + 1) % 10), f"ego collision{suffix}", marker="s")
    ax.set_ylim(-0.03, 1.03)
    ax.set_xlabel(_label(x))
    ax.set_ylabel("share of runs [-]")
    ax.set_title(f"Completion and ego-collision rate vs {_label(x)}\n(bootstrap 95% CI over runs)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    fig.tight_layout()
    return _save(fig, folder, "completion_vs_" + x.replace(".", "_"))


def harm_per_collision(collisions: pd.DataFrame, folder: Path) -> list[Path]:
    long = ego_collision_harm(collisions)
    fig, ax = plt.subplots(figsize=(7, 4.2))
    classes = ["ego", "third party", "VRU"]
    data = [long.loc[long["class"] == c, "harm"].to_numpy(dtype=float) for c in classes]
    rng = np.random.default_rng(0)
    for i, (c, d) in enumerate(zip(classes, data)):
        if len(d):
            ax.boxplot([d], positions=[i], widths=0.5, showfliers=False,
                       medianprops={"color": CLASS_COLOURS[c], "lw": 2})
            ax.scatter(i + rng.uniform(-0.15, 0.15, len(d)), d, s=14, color=CLASS_COLOURS[c], alpha=0.7,
                       zorder=3)
        else:
            ax.text(i, 0.5, "none", transform=ax.get_xaxis_transform(), ha="center", va="center", color="0.5")
    ax.set_xticks(range(len(classes)), [f"{c}\n(n={len(d)})" for c, d in zip(classes, data)])
    ax.set_xlim(-0.6, len(classes) - 0.4)
    ax.set_ylabel("harm per ego collision [-]\n(P(MAIS 3+))")
    ax.set_xlabel("harmed party (third party: cars, trucks, buses; VRU: pedestrians, cyclists, motorcyclists)")
    ax.set_title("Distribution of harm per ego collision, by class")
    if long.empty:
        ax.text(0.5, 0.5, "no ego collisions in this sweep", transform=ax.transAxes, ha="center", va="center")
        ax.set_ylim(0, 1)
    else:
        ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3, axis="y")
    fig.tight_layout()
    return _save(fig, folder, "harm_per_collision")


def tradeoff(runs: pd.DataFrame, folder: Path, colour_by: str = "omega_u") -> list[Path]:
    fig, ax = plt.subplots(figsize=(6.5, 5))
    c = runs[colour_by] if colour_by in runs.columns and _is_numeric(runs[colour_by]) else None
    rng = np.random.default_rng(0)
    jitter = 0.004 * max(float(runs[["harm_ego", "harm_third_party"]].to_numpy().max(initial=0.0)), 1e-3)
    xs = runs["harm_ego"].to_numpy(dtype=float) + rng.normal(0, jitter, len(runs))
    ys = runs["harm_third_party"].to_numpy(dtype=float) + rng.normal(0, jitter, len(runs))
    norm = None
    if c is not None and _wide(c):
        from matplotlib.colors import SymLogNorm

        norm = SymLogNorm(linthresh=float(np.abs(c[c != 0]).min()), vmin=float(c.min()), vmax=float(c.max()))
    sc = ax.scatter(xs, ys, c=c if c is not None else "#1f77b4", cmap="viridis", norm=norm, s=28, alpha=0.8,
                    edgecolors="k", linewidths=0.3, label="one run (slightly jittered)")
    if c is not None and c.nunique() > 1:
        fig.colorbar(sc, ax=ax, label=_label(colour_by))
        means = runs.groupby(colour_by)[["harm_ego", "harm_third_party"]].mean().reset_index()
        ax.plot(means["harm_ego"], means["harm_third_party"], "-", color="0.4", lw=1, zorder=1)
        ax.scatter(means["harm_ego"], means["harm_third_party"], c=means[colour_by], cmap="viridis", s=120,
                   marker="D", edgecolors="k", linewidths=1.0, label=f"mean per {colour_by}", zorder=4,
                   norm=norm if norm is not None else plt.Normalize(c.min(), c.max()), alpha=0.85)
    lim = max(float(np.nanmax(np.r_[xs, ys, 0.0])) * 1.1, 0.01)
    ax.plot([0, lim], [0, lim], ":", color="0.5", lw=1, label="equal harm")
    ax.set_xlim(-0.02 * lim, lim)
    ax.set_ylim(-0.02 * lim, lim)
    ax.set_xlabel("harm to the ego per run [-]")
    ax.set_ylabel("harm to third parties per run [-] (incl. VRU)")
    ax.set_title("Ego vs third-party harm per run")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    return _save(fig, folder, "tradeoff_ego_vs_third_party")
