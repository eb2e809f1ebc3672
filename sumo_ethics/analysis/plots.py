"""Figures of a sweep (matplotlib, Agg backend), each saved as PNG and SVG.

- harm per class vs the first ``--by`` key (w_u by default), means with bootstrap 95% CI bands
  (one series) or error bars set side by side (several series: the other ``--by`` keys);
- completion and ego-collision rate vs that key (error bars side by side);
- distribution of harm per ego collision by class (ego / third party / VRU);
- ego-vs-third-party harm per run (trade-off scatter): colour by the first ``--by`` key, marker by
  the others.

w_u (and w_o) are always on a symlog axis with a linear range up to 1, so the same value sits at
the same place in every sweep; other numeric keys are linear unless they span two decades.
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
          "radius": "sensing radius [m]", "seed": "seed", "penetration": "share of vehicles that are egos [-]",
          "egos": "inserted egos"}
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


#: keys always drawn on a symlog axis with this linear threshold, so that the same value sits at
#: the same place in every sweep (w_u spans decades: 0, 0.5, 1000 ...)
SYMLOG_KEYS = {"omega_u": 1.0, "omega_o": 1.0}


def _symlog(key: str, values) -> float | None:
    """The symlog linear threshold for ``key`` (None: a linear axis)."""
    if key in SYMLOG_KEYS:
        return SYMLOG_KEYS[key]
    v = np.asarray(values, dtype=float)
    return float(np.abs(v[v != 0]).min()) if _wide(v) else None


def _scale_x(ax, values, key: str = "") -> None:
    v = np.asarray(values, dtype=float)
    lin = _symlog(key, v)
    if lin is not None:
        ax.set_xscale("symlog", linthresh=lin)
        ticks = sorted(set(v.tolist()))
        ax.set_xticks(ticks, [f"{x:g}" for x in ticks])
        ax.minorticks_off()
        if len(ticks) > 6:
            ax.tick_params(axis="x", labelrotation=45)


def _dodge(ax, i: int, n: int, width: float = 7.0):
    """A transform shifting series ``i`` of ``n`` sideways by a few points, so that series with
    equal values (and their CI bars) stay visible side by side, on any axis scale."""
    from matplotlib.transforms import offset_copy

    return offset_copy(ax.transData, fig=ax.figure, x=(i - (n - 1) / 2) * width, y=0.0, units="points")


MARKERS = ("o", "s", "^", "D", "v", "P", "X", "*")
LINESTYLES = ("-", "--", "-.", ":")


def _line_ci(ax, g: pd.DataFrame, x: str, col: str, colour, label: str, marker: str = "o", slot: int = 0,
             slots: int = 1, linestyle: str = "-") -> None:
    """Means with their 95% CI: a shaded band for a single series, dodged error bars when
    several series share the axis (bands of several series merge into one block)."""
    g = g.sort_values(x)
    numeric = _is_numeric(g[x])
    xs = g[x].to_numpy() if numeric else np.arange(len(g))
    y = g[f"{col}"].to_numpy(dtype=float)
    lo, hi = g[f"{col}_ci_lo"].to_numpy(dtype=float), g[f"{col}_ci_hi"].to_numpy(dtype=float)
    if slots == 1:
        ax.plot(xs, y, marker=marker, color=colour, label=label, lw=1.8, ms=5, ls=linestyle)
        ax.fill_between(xs, lo, hi, color=colour, alpha=0.18, lw=0)
    else:
        ax.errorbar(xs, y, yerr=np.vstack([y - lo, hi - y]).clip(min=0), marker=marker, color=colour, label=label,
                    lw=1.5, ms=5, ls=linestyle, capsize=3, elinewidth=1.2, transform=_dodge(ax, slot, slots))
        ax.update_datalim(np.c_[np.r_[xs, xs], np.r_[lo, hi]])  # a shifted artist does not autoscale
        ax.autoscale_view()
    if not numeric:
        ax.set_xticks(xs, [str(v) for v in g[x]])
    else:
        _scale_x(ax, xs, x)


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
            _line_ci(ax, g, x, col, colour, label or f"{cls}: mean, 95% CI", marker=MARKERS[i % len(MARKERS)],
                     slot=i, slots=len(hues), linestyle=LINESTYLES[i % len(LINESTYLES)])
        ax.set_title(f"harm to {cls}")
        ax.set_xlabel(_label(x))
        ax.grid(alpha=0.3)
        if len(hues) == 1:
            ax.legend(fontsize=8, loc="best")
    if len(hues) > 1:  # one legend for the three panels, below them
        handles, labels = axes[0].get_legend_handles_labels()
        fig.legend(handles, [f"{lab} (mean, 95% CI bar)" for lab in labels], loc="lower center",
                   ncol=min(len(hues), 4), fontsize=9, frameon=False, bbox_to_anchor=(0.5, -0.06))
    axes[0].set_ylabel("mean harm per run [-]\n(P(MAIS 3+), summed over collisions)")
    n = int(summary["n_runs"].min()), int(summary["n_runs"].max())
    fig.suptitle(f"Harm per class vs {_label(x)} (bootstrap 95% CI over runs, {n[0]}-{n[1]} runs per point)"
                 if n[0] != n[1] else
                 f"Harm per class vs {_label(x)} (bootstrap 95% CI over runs, {n[0]} runs per point)")
    fig.tight_layout()
    return _save(fig, folder, "harm_vs_" + x.replace(".", "_"))


def traffic_vs_parameter(table: pd.DataFrame, by: Sequence[str], folder: Path) -> list[Path]:
    """Fleet runs (analysis.stats.traffic_table): everyone's harm by party per 10^6 vehicle-km, the
    egos' conflicts per 100 ego-km and the mean time loss per trip by party, against the first
    ``--by`` key (e.g. penetration), one series per combination of the others (e.g. the fleet)."""
    x = by[0]
    hues = _hues(table, by)
    everyone = "conflicts_everyone_per_100vkm"
    panels = [("harm_egos_per_Mvkm", "harm to egos"), ("harm_other_vehicles_per_Mvkm", "harm to other vehicles"),
              ("harm_vru_per_Mvkm", "harm to VRUs"), ("conflicts_per_100km", "egos' conflicts"),
              *([(everyone, "everyone's conflicts (egos' and others')")]
                if everyone in table and table[everyone].notna().any() else []),
              ("time_loss_egos", "time loss of egos"), ("time_loss_other_vehicles", "time loss of other vehicles"),
              ("time_loss_persons", "time loss of pedestrians")]
    units = {"harm": "per $10^6$ vehicle-km [-]", "conflicts_per_100km": "per 100 ego-km",
             everyone: "per 100 vehicle-km of all trips", "time": "mean per trip [s]"}
    fig, axes = plt.subplots(2, 4, figsize=(17, 8.2 if len(panels) == 8 else 7.5), sharex=True)
    cmap = plt.get_cmap("tab10")
    for ax, (col, title) in zip(axes.flat, panels):
        for i, (label, g) in enumerate(hues):
            if g[col].notna().any():
                _line_ci(ax, g, x, col, cmap(i % 10), label or "mean, 95% CI", marker=MARKERS[i % len(MARKERS)],
                         slot=i, slots=len(hues), linestyle=LINESTYLES[i % len(LINESTYLES)])
        if not table[col].notna().any():
            ax.text(0.5, 0.5, "no values\n(e.g. no trip of this party ended)", ha="center", va="center",
                    transform=ax.transAxes, color="0.4")
        ax.tick_params(labelbottom=True)
        ax.set_title(title)
        ax.set_xlabel(_label(x))
        ax.set_ylabel(units.get(col, units.get(col[:4], "")))
        ax.grid(alpha=0.3)
    handles, labels = axes.flat[0].get_legend_handles_labels()
    labels = [f"{lab} (95% CI)" for lab in labels]
    if len(panels) < len(axes.flat):  # the spare panel holds the legend
        axes.flat[-1].axis("off")
        if handles:
            axes.flat[-1].legend(handles, labels, loc="center", fontsize=10, frameon=False)
    n = int(table["n_runs"].min()), int(table["n_runs"].max())
    runs = f"{n[0]} run" + ("" if n[0] == 1 else "s") if n[0] == n[1] else f"{n[0]}-{n[1]} runs"
    fig.suptitle(f"Traffic outcomes vs {_label(x)} (bootstrap 95% CI over runs, {runs} per point)")
    if len(panels) == len(axes.flat):  # every panel used: the legend goes below them
        fig.tight_layout(rect=(0, 0.06, 1, 1))
        if handles:
            fig.legend(handles, labels, loc="lower center", ncol=min(len(labels), 4), fontsize=10, frameon=False)
    else:
        fig.tight_layout()
    return _save(fig, folder, "traffic_vs_" + x.replace(".", "_"))


def completion_vs_parameter(summary: pd.DataFrame, by: Sequence[str], folder: Path) -> list[Path]:
    x = by[0]
    hues = _hues(summary, by)
    fig, ax = plt.subplots(figsize=(7, 4.2))
    cmap = plt.get_cmap("tab10")
    n = 2 * len(hues)  # every series side by side (dodged): equal values no longer hide each other
    for i, (label, g) in enumerate(hues):
        suffix = f" ({label})" if label else ""
        style = LINESTYLES[i % len(LINESTYLES)]
        _line_ci(ax, g, x, "completion_rate", cmap((2 * i) % 10), f"completed{suffix}",
                 marker=MARKERS[(2 * i) % len(MARKERS)], slot=2 * i, slots=n, linestyle=style)
        _line_ci(ax, g, x, "collision_rate", cmap((2 * i + 1) % 10), f"ego collision{suffix}",
                 marker=MARKERS[(2 * i + 1) % len(MARKERS)], slot=2 * i + 1, slots=n, linestyle=style)
    ax.set_ylim(-0.03, 1.03)
    ax.set_xlabel(_label(x))
    ax.set_ylabel("share of runs [-]")
    ax.set_title(f"Completion and ego-collision rate vs {_label(x)}\n(mean, bootstrap 95% CI over runs; "
                 f"series side by side)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
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
        elif not long.empty:  # with no collision at all, one message says so (below), not three
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


def tradeoff(runs: pd.DataFrame, folder: Path, by: Sequence[str] = ("omega_u",)) -> list[Path]:
    """Ego vs third-party harm per run: colour by the first ``--by`` key (one colour per value),
    marker by the combination of the others; the mean of each group as a large marker."""
    from matplotlib.artist import Artist
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch
    from matplotlib.ticker import MaxNLocator

    by = [k for k in by if k in runs.columns] or ["omega_u"]
    key, rest = by[0], list(by[1:])
    fig, ax = plt.subplots(figsize=(8.5, 5.5))
    rng = np.random.default_rng(0)
    top = float(runs[["harm_ego", "harm_third_party"]].to_numpy().max(initial=0.0))
    jitter = 0.004 * max(top, 1e-3)
    values = sorted(runs[key].dropna().unique().tolist()) if key in runs.columns else [None]
    cmap = plt.get_cmap("viridis" if len(values) > 10 else "tab10")
    colours = {v: cmap(i / max(len(values) - 1, 1) if len(values) > 10 else i % 10) for i, v in enumerate(values)}
    groups = [((), runs)] if not rest else [((k if isinstance(k, tuple) else (k,)), g)
                                            for k, g in runs.groupby(rest, sort=True, dropna=False)]
    xs_all, ys_all = [], []
    handles: list[Artist] = []
    for gi, (_gkey, g) in enumerate(groups):
        marker = MARKERS[gi % len(MARKERS)]
        for v in values:
            sub = g if v is None else g[g[key] == v]
            if sub.empty:
                continue
            xs = sub["harm_ego"].to_numpy(dtype=float) + rng.normal(0, jitter, len(sub))
            ys = sub["harm_third_party"].to_numpy(dtype=float) + rng.normal(0, jitter, len(sub))
            xs_all.append(xs)
            ys_all.append(ys)
            ax.scatter(xs, ys, color=colours[v], marker=marker, s=26, alpha=0.6, edgecolors="k", linewidths=0.3)
            ax.scatter([sub["harm_ego"].mean()], [sub["harm_third_party"].mean()], color=colours[v], marker=marker,
                       s=150, edgecolors="k", linewidths=1.2, zorder=4)
    for v in values:
        handles.append(Patch(color=colours[v], label=f"{_short(key)} = {v:g}" if isinstance(v, float)
                             else f"{_short(key)} = {v}"))
    if rest:
        for gi, (gkey, _) in enumerate(groups):
            handles.append(Line2D([], [], color="0.4", marker=MARKERS[gi % len(MARKERS)], ls="", ms=8,
                                  label=", ".join(f"{k}={x}" for k, x in zip(rest, gkey))))
    handles.append(Line2D([], [], color="0.4", marker="o", ls="", ms=4, label="small: one run (jittered)"))
    handles.append(Line2D([], [], color="0.4", marker="o", ls="", ms=10, label="large: mean of the group"))
    allv = np.concatenate(xs_all + ys_all) if xs_all else np.zeros(1)
    lim = max(float(np.nanmax(np.r_[allv, 0.0])) * 1.1, 0.01)
    handles.append(ax.plot([0, lim], [0, lim], ":", color="0.5", lw=1, label="equal harm")[0])
    ax.set_xlim(-0.02 * lim, lim)
    ax.set_ylim(-0.02 * lim, lim)
    ax.xaxis.set_major_locator(MaxNLocator(5))  # few, short tick labels: they must not run together
    ax.yaxis.set_major_locator(MaxNLocator(5))
    ax.set_xlabel("harm to the ego per run [-]")
    ax.set_ylabel("harm to third parties per run [-] (incl. VRU)")
    ax.set_title("Ego vs third-party harm per run" + (f" by {', '.join(by)}" if by else ""))
    ax.grid(alpha=0.3)
    ax.legend(handles=handles, fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    fig.tight_layout()
    return _save(fig, folder, "tradeoff_ego_vs_third_party")


def _short(key: str) -> str:
    return {"omega_u": "w_u", "omega_o": "w_o"}.get(key, key)
