"""Pictures of recorded decisions: ``sumo-ethics explain`` (one planning step), the collision
snapshots a run writes, and the frames of ``sumo-ethics replay``.

A decision figure has three parts. Left, the scene: the road from the SUMO network, every road
user as its true box coloured by class, each predicted trajectory (mean and 1- / 2-sigma ellipses
every second) and the candidates coloured by validity class. Middle, the same candidates coloured
by J_risk. Right, the chosen candidate's named cost terms beside the best candidate of another
validity class (the alternative the rule did not take).
"""

from __future__ import annotations

import json
import zipfile
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from sumo_ethics.errors import ConfigError
from sumo_ethics.record import decisions as rec
from sumo_ethics.record.decisions import RecordedDecision
from sumo_ethics.types import EXCLUSIONS, RoadUserClass

#: box and prediction colour per road-user class
CLASS_COLOURS = {
    "car": "#1f77b4", "truck": "#8c564b", "bus": "#9467bd", "motorcycle": "#ff7f0e",
    "bicycle": "#e7298a", "pedestrian": "#d62728", "other": "#7f7f7f",
}
EGO_COLOUR = "#111111"
#: validity classes (plan.ethical.VALIDITY) and their colours, best first
VALIDITY_LABELS = ("safe", "no overlap, on road", "no overlap", "feasible", "emergency")
VALIDITY_COLOURS = ("#1b7837", "#7fbf7b", "#c2a5cf", "#762a83", "#7f7f7f")  # ordered: green (best) to purple
ROAD_COLOURS = {"junction": "#c8c8c8", "road": "#b4b4b4", "bike": "#d9b38c", "sidewalk": "#e6e6e6",
                "walkingarea": "#e6e6e6", "crossing": "#f4f4f4"}
#: cost terms shown in the panel, in order, with their labels
PANEL_TERMS = (
    ("j_risk", "J_risk = w_o J_origin + w_u J_util."),
    ("j_origin", "J_origin"),
    ("j_utility", "J_utility"),
    ("bayes", "Bayes (risk sum / 2N)"),
    ("equality", "Equality (risk spread)"),
    ("maximin", "Maximin (max harm^10)"),
    ("ego", "Ego (own risk)"),
    ("responsibility", "Responsibility"),
    ("progress", "progress (speed deficit)"),
    ("lateral", "lateral offset"),
    ("penalty", "envelope + entry"),
    ("selection", "selection total"),
    ("ego_risk_sum", "risk to the ego"),
    ("other_risk_sum", "risk to third parties"),
    ("vru_risk_sum", "  of which VRUs"),
    ("boundary_harm", "leaving the road (ego harm)"),
)


@dataclass(frozen=True)
class Explained:
    """What :func:`explain` drew: the files, the decision, the candidates drawn, the alternative."""

    paths: tuple[Path, ...]
    decision: RecordedDecision
    n_drawn: int
    alternative: int | None


# ---- finding a decision ---------------------------------------------------------------------------
def recorded(run: Path) -> list[int]:
    """The recorded steps of ``run``; ConfigError naming the flag when there are none."""
    run = Path(run)
    if not run.is_dir():
        raise ConfigError(f"run folder not found: {run}")
    steps = rec.recorded_steps(run)
    if not steps:
        mode = record_mode(run)
        if mode in (None, "off"):
            raise ConfigError(f"{run} has no recorded decisions: run it with --record-decisions risky (or all)")
        raise ConfigError(f"{run} kept no decisions with --record-decisions {mode} (no chosen trajectory carried "
                          "risk and the ego did not collide); run it with --record-decisions all for every step")
    return steps


def record_mode(run: Path) -> str | None:
    """The recording mode a run was made with (config.json, else summary.json), or None."""
    for name, key in (("config.json", ("record_decisions",)), ("summary.json", ("decisions", "mode"))):
        try:
            d: Any = json.loads((Path(run) / name).read_text())
            for k in key:
                d = d[k]
            return str(d)
        except (OSError, ValueError, KeyError, TypeError):
            continue
    return None


def resolve_step(run: Path, step: int | None = None, time: float | None = None, collision: int | None = None,
                 conflict: int | None = None) -> int:
    """The recorded step named by exactly one of ``step``, ``time`` [s] (the nearest recorded
    planning time), ``collision`` (an event number of collisions.parquet: its last planning step
    before impact) or ``conflict`` (an event number of conflicts.parquet: the planning step nearest
    its worst moment, ``time_worst``). ConfigError when it is not recorded."""
    if sum(v is not None for v in (step, time, collision, conflict)) != 1:
        raise ConfigError("give exactly one of --step, --time, --collision and --conflict")
    run = Path(run)
    if conflict is not None:
        time = float(_conflict_row(run, conflict)["time_worst"])
    steps = recorded(run)
    if time is not None and not np.isfinite(time):
        raise ConfigError(f"--time must be a finite time in seconds, got {time}")
    if collision is not None:
        from sumo_ethics.record.reader import read_table

        rows = read_table(run, "collisions").to_pylist()
        match = [r for r in rows if r["event"] == collision]
        if not match:
            raise ConfigError(f"{run} has no collision event {collision} (events: "
                              f"{', '.join(str(r['event']) for r in rows) or 'none'})")
        step = int(match[0]["step"])
    if time is not None:
        times = np.array([_time_of(run, s) for s in steps])
        i = int(np.argmin(np.abs(times - time)))
        if abs(times[i] - time) > 0.5:
            raise ConfigError(f"no decision recorded near t={time:g} s; the nearest is at t={times[i]:g} s "
                              f"(recorded: {_spans(times)})")
        return steps[i]
    if step not in steps:
        near = min(steps, key=lambda s: abs(s - step))
        raise ConfigError(f"step {step} of {run} has no recorded decision; the nearest recorded step is {near}")
    return int(step)


@contextmanager
def readable(run: Path, step: int) -> Iterator[None]:
    """Reading step ``step``'s decision file of ``run``: a file that cannot be read (cut short by
    a full disk, or not a decision file) becomes one ConfigError line."""
    try:
        yield
    except (OSError, ValueError, KeyError, IndexError, EOFError, zipfile.BadZipFile) as exc:
        raise ConfigError(f"{rec.step_path(run, step)} is not a readable decision file (truncated or corrupt: "
                          f"{type(exc).__name__})") from None


def load_checked(run: Path, step: int) -> RecordedDecision:
    """:func:`sumo_ethics.record.decisions.load`, with a ConfigError for an unreadable file."""
    with readable(run, step):
        return rec.load(run, step)


def _conflict_row(run: Path, event: int) -> dict:
    """Conflict ``event`` of conflicts.parquet; ConfigError naming the events there are."""
    from sumo_ethics.record.reader import read_table

    rows = read_table(Path(run), "conflicts").to_pylist()
    match = [r for r in rows if r["event"] == event]
    if not match:
        raise ConfigError(f"{run} has no conflict event {event} (events: "
                          f"{', '.join(str(r['event']) for r in rows[:20]) or 'none'}"
                          f"{' ...' if len(rows) > 20 else ''})")
    return match[0]


def conflict_mark(run: Path, event: int) -> tuple[float, float, str]:
    """Where the other party of conflict ``event`` was at its worst moment, and what the conflict was."""
    r = _conflict_row(run, event)
    what = [f"min TTC {r['min_ttc']:.2f} s" if np.isfinite(r["min_ttc"]) else "",
            f"min PET {r['min_pet']:.2f} s" if np.isfinite(r["min_pet"]) else ""]
    return (float(r["x_b"]), float(r["y_b"]),
            f"conflict {event}: {r['class_b']} '{r['id_b']}', {', '.join(w for w in what if w)}")


def hit_of(run: Path, event: int) -> tuple[float, float, str] | None:
    """Where the other party of collision ``event`` was just before impact, and who it was."""
    from sumo_ethics.record.reader import read_table

    rows = [r for r in read_table(Path(run), "collisions").to_pylist() if r["event"] == event]
    return (float(rows[0]["x_b"]), float(rows[0]["y_b"]), f"hit: {rows[0]['class_b']} '{rows[0]['id_b']}'") if rows else None


def _time_of(run: Path, step: int) -> float:
    with readable(run, step), np.load(rec.step_path(run, step), allow_pickle=False) as z:
        return float(z["meta"][1])


def _spans(times: np.ndarray) -> str:
    return f"{len(times)} steps between t={times.min():g} and {times.max():g} s"


# ---- drawing --------------------------------------------------------------------------------------
def _box(x: float, y: float, yaw: float, length: float, width: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    corners = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]]) * [length / 2, width / 2]
    return corners @ np.array([[c, s], [-s, c]]) + [x, y]


def _ellipse(mean: np.ndarray, cov: np.ndarray, k: float, n: int = 40) -> np.ndarray:
    vals, vecs = np.linalg.eigh(cov)
    a = np.linspace(0, 2 * np.pi, n)
    circle = np.stack([np.cos(a), np.sin(a)], -1) * (k * np.sqrt(np.maximum(vals, 0)))
    return circle @ vecs.T + mean


def window(d: RecordedDecision, near: float = 30.0, margin: float = 6.0, min_size: float = 30.0,
           extra: np.ndarray | None = None) -> tuple[float, float, float, float]:
    """The plot window [m]: the ego, its candidates and the road users within ``near`` metres of
    it, with ``margin``, at least ``min_size`` metres each way and at most 160 m."""
    pts = [d.ego[None, :2], d.cand_xy.reshape(-1, 2)]
    if len(d.agents):
        close = np.hypot(*(d.agents[:, :2] - d.ego[:2]).T) <= near
        pts.append(d.agents[close, :2])
    if extra is not None:  # (M, 2) further points to show, e.g. where a collision's other party was
        pts.append(np.asarray(extra, dtype=float).reshape(-1, 2))
    p = np.concatenate(pts)
    lo, hi = p.min(axis=0) - margin, p.max(axis=0) + margin
    centre, size = (lo + hi) / 2, np.clip(hi - lo, min_size, 160.0)
    # no taller than 1.25 x its width (the maps stand side by side), no wider than 2.5 x its height
    size = np.maximum(size, [size[1] / 1.25, size[0] / 2.5])
    return centre[0] - size[0] / 2, centre[1] - size[1] / 2, centre[0] + size[0] / 2, centre[1] + size[1] / 2


def draw_road(ax: Any, road: Any) -> None:
    from matplotlib.collections import LineCollection, PolyCollection
    from shapely.geometry import LineString, Polygon

    for kind in ROAD_COLOURS:
        polys = []
        for ln in road.lanes:
            if ln.kind != kind:
                continue
            if kind in ("junction", "walkingarea") or ln.width <= 0:
                polys.append(ln.xy)
            else:
                g = LineString(ln.xy).buffer(ln.width / 2, cap_style="flat")
                if isinstance(g, Polygon) and not g.is_empty:
                    polys.append(np.asarray(g.exterior.coords))
        if polys:
            ax.add_collection(PolyCollection(polys, facecolors=ROAD_COLOURS[kind], edgecolors="none", zorder=0,
                                             hatch="|||" if kind == "crossing" else None))
    centre = [ln.xy for ln in road.lanes if ln.kind in ("road", "bike")]
    if centre:
        ax.add_collection(LineCollection(centre, colors="white", linewidths=0.6, linestyles=(0, (4, 4)), zorder=0.5))
    if len(road.stop_lines):
        ax.add_collection(LineCollection(list(road.stop_lines), colors="white", linewidths=2.5, zorder=0.6))


#: [m] the least distance between two mode-probability labels in a figure
LABEL_GAP = 2.0


def draw_agents(ax: Any, d: RecordedDecision, predictions: bool = True) -> list[str]:
    """Boxes (true size) and predictions of every road user and the ego; the classes drawn."""
    from matplotlib.patches import Polygon as Patch
    from matplotlib.patheffects import withStroke

    seen = []
    labelled: list[np.ndarray] = []  # where mode probabilities are written [m]
    for i, row in enumerate(d.agents):
        x, y, yaw, _, length, width, cls = row
        label = RoadUserClass(int(cls)).label
        colour = CLASS_COLOURS[label]
        seen.append(label)
        ax.add_patch(Patch(_box(x, y, yaw, length, width), closed=True, fc=colour, ec="black", lw=0.6, zorder=5))
        if RoadUserClass(int(cls)) in (RoadUserClass.PEDESTRIAN, RoadUserClass.BICYCLE):  # small: ringed
            ax.plot(x, y, "o", ms=11, mfc="none", mec=colour, mew=1.5, zorder=5.1)
        if predictions and d.pred_mean.shape[0] > i:
            m = d.pred_mean[i]
            ax.plot(np.r_[x, m[:, 0]], np.r_[y, m[:, 1]], color=colour, lw=1.2, zorder=4)
            for t in d.whole_seconds():
                e1, e2 = _ellipse(m[t], d.pred_cov[i, t], 1.0), _ellipse(m[t], d.pred_cov[i, t], 2.0)
                ax.fill(e1[:, 0], e1[:, 1], color=colour, alpha=0.22, lw=0, zorder=3)
                ax.plot(e2[:, 0], e2[:, 1], color=colour, alpha=0.5, lw=0.6, ls="--", zorder=3)
            if d.pred_alt_mean is not None:  # the other modes of a multi-modal prediction: dotted mean paths,
                w = d.pred_weight[i]  # as wide as they are likely; where the main mode is not nearly sure,
                for alt, wk in zip(d.pred_alt_mean[:, i], w[1:]):  # every mode of 5 % or more is labelled
                    if wk <= 0.0:  # no prediction (a one-mode pedestrian's other modes)
                        continue
                    ax.plot(np.r_[x, alt[:, 0]], np.r_[y, alt[:, 1]], color=colour, lw=0.5 + 2.0 * wk, ls=":", zorder=4)
                if w[0] < 0.95:
                    ends = [m[-1]] + list(d.pred_alt_mean[:, i, -1])
                    for end, wk in zip(ends, w):
                        # a label needs LABEL_GAP m of its own (paths ending together would print over
                        # each other: the first, most likely, is kept); a white rim keeps it readable on a box
                        if wk >= 0.05 and all(np.hypot(*(end - q)) >= LABEL_GAP for q in labelled):
                            labelled.append(np.asarray(end))
                            ax.text(end[0], end[1], f"{wk:.0%}", fontsize=7, color=colour, zorder=8, clip_on=True,
                                    ha="center", va="bottom", path_effects=[withStroke(linewidth=2.0, foreground="white")])
    ex, ey, eyaw, _, el, ew = d.ego[:6]
    ax.add_patch(Patch(_box(ex, ey, eyaw, el, ew), closed=True, fc=EGO_COLOUR, ec="white", lw=1.0, zorder=6))
    return seen


def _candidates(ax: Any, d: RecordedDecision, colours: Any, chosen: bool = True) -> int:
    from matplotlib.collections import LineCollection

    start = np.broadcast_to(d.ego[:2], (d.n_candidates, 1, 2))
    paths = np.concatenate([start, d.cand_xy], axis=1)
    ax.add_collection(LineCollection(list(paths), colors=colours, linewidths=0.7, alpha=0.55, zorder=2))
    if chosen:
        p = paths[d.chosen]
        ax.plot(p[:, 0], p[:, 1], color="white", lw=4.0, zorder=7, solid_capstyle="round")
        ax.plot(p[:, 0], p[:, 1], color="black", lw=2.0, zorder=7.1, solid_capstyle="round", label="chosen")
        whole = rec.whole_seconds(d.cand_t)
        ax.plot(d.cand_xy[d.chosen, whole, 0], d.cand_xy[d.chosen, whole, 1], "o", ms=4.5, mfc="white", mec="black",
                zorder=7.2)
    return len(paths)


def alternative(d: RecordedDecision) -> int | None:
    """The best candidate (lowest selection total) of another validity class than the chosen one."""
    other = np.flatnonzero(d.validity != d.validity[d.chosen])
    return None if len(other) == 0 else int(other[np.argmin(d.selection[other])])


def _term(d: RecordedDecision, k: int, name: str, weights: dict[str, float] | None = None) -> float:
    """Term ``name`` of candidate k; principle and progress/lateral terms times their weights
    (from the run's config) when ``weights`` is given, so they add up to J_origin."""
    if name == "selection":
        return float(d.selection[k])
    if name == "penalty":
        return float(d.selection[k] - d.j_risk[k])
    value = float(d.terms.get(name, np.full(d.n_candidates, np.nan))[k])
    if weights is not None and name in PRINCIPLES:
        value *= weights.get("risk", 1.0) * weights.get(name, 1.0)
    elif weights is not None and name in ("progress", "lateral"):
        value *= weights.get("velocity" if name == "progress" else "lateral", 1.0)
    return value


PRINCIPLES = ("bayes", "equality", "maximin", "ego", "responsibility")


def _fmt(v: float) -> str:
    if not np.isfinite(v):
        return "-"
    if v == 0:
        return "0"
    return f"{v:.3g}" if 1e-3 <= abs(v) < 1e5 else f"{v:.2e}"


def excluded_note(d: RecordedDecision, k: int) -> str:
    """'\\nexcluded: <the hard constraint>' for a candidate a hard constraint kept from being
    chosen (DecisionTrace.excluded), else ''."""
    code = 0 if d.excluded is None else int(d.excluded[k])
    return f"\nexcluded: {EXCLUSIONS[code]}" if code else ""


def cost_panel(ax: Any, d: RecordedDecision, alt: int | None, weights: dict[str, float] | None = None) -> None:
    """A table of the chosen candidate's named cost terms beside the alternative's; with the
    run's principle ``weights`` the J_origin rows are weighted (they then add up to J_origin)."""
    ax.axis("off")
    if alt is None:
        ax.text(0.5, 0.02, "Every candidate is in the chosen class:\nno alternative of another class.",
                ha="center", va="bottom", fontsize=9, transform=ax.transAxes)
    head = ["term", f"chosen\n{VALIDITY_LABELS[int(d.validity[d.chosen])]}"]
    if alt is not None:
        head.append(f"best of another class:\n{VALIDITY_LABELS[int(d.validity[alt])]}{excluded_note(d, alt)}")
    def label_of(name: str, label: str) -> str:
        if weights is None:
            return label
        if name in PRINCIPLES:
            return f"{label.split(' (')[0]} x {weights.get('risk', 1.0):g} x {weights.get(name, 1.0):g}"
        if name in ("progress", "lateral"):
            return f"{label} x {weights.get('velocity' if name == 'progress' else 'lateral', 1.0):g}"
        return label

    cells = [[label_of(name, label)] + [_fmt(_term(d, d.chosen, name, weights))]
             + ([_fmt(_term(d, alt, name, weights))] if alt is not None else []) for name, label in PANEL_TERMS]
    table = ax.table(cellText=cells, colLabels=head, loc="upper center", cellLoc="right", colLoc="center",
                     colWidths=[0.46, 0.22, 0.32][:len(head)])
    table.auto_set_font_size(False)
    table.set_fontsize(8)
    table.scale(1.0, 1.35)
    for (r, c), cell in table.get_celld().items():
        if r == 0:
            cell.set_text_props(weight="bold")
            cell.set_height(cell.get_height() * 1.8)
        if c == 0:
            cell.set_text_props(ha="left")
    ax.set_title("Named cost terms [cost units]\nrisks: P(collision) x harm, summed over parties", fontsize=9.5)


def decision_figure(d: RecordedDecision, road: Any, title: str, weights: dict[str, float] | None = None,
                    hit: tuple[float, float, str] | None = None) -> tuple[Any, int, int | None]:
    """The three-part figure of one decision; (figure, candidates drawn, alternative index)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch
    from matplotlib.patheffects import withStroke

    x0, y0, x1, y1 = window(d, extra=None if hit is None else np.array([hit[:2]]))
    if (x1 - x0) > 1.6 * (y1 - y0):  # a long straight window: the two maps one above the other
        fig = plt.figure(figsize=(17, 8.5), layout="constrained")
        gs = fig.add_gridspec(2, 2, width_ratios=[2.0, 0.75])
        axes = [fig.add_subplot(gs[0, 0]), fig.add_subplot(gs[1, 0])]
        panel = fig.add_subplot(gs[:, 1])
    else:
        fig = plt.figure(figsize=(17, 7.2), layout="constrained")
        gs = fig.add_gridspec(1, 3, width_ratios=[1.0, 1.0, 0.9])
        axes = [fig.add_subplot(gs[0, 0]), fig.add_subplot(gs[0, 1])]
        panel = fig.add_subplot(gs[0, 2])
    box = road.window(x0, y0, x1, y1) if road is not None else None
    n_drawn = 0
    for i, ax in enumerate(axes):
        if box is not None:
            draw_road(ax, box)
        seen = draw_agents(ax, d)
        if i == 0:
            n_drawn = _candidates(ax, d, [VALIDITY_COLOURS[int(v)] for v in d.validity])
            ax.set_title(f"Candidates by validity class ({d.n_candidates}; chosen in black)", fontsize=10)
            handles = [Line2D([], [], color=VALIDITY_COLOURS[c], lw=2, label=VALIDITY_LABELS[c])
                       for c in sorted(set(int(v) for v in d.validity))]
            handles.append(Line2D([], [], color="black", lw=2.5, marker="o", mfc="white", mec="black",
                                  label="chosen (dots: each second)"))
            in_view = {RoadUserClass(int(a[6])).label for a in d.agents if x0 <= a[0] <= x1 and y0 <= a[1] <= y1}
            classes = sorted(set(seen) & in_view, key=lambda s: list(CLASS_COLOURS).index(s))
            handles += [Patch(fc=EGO_COLOUR, label="ego")] + [Patch(fc=CLASS_COLOURS[c], label=c) for c in classes]
            handles.append(Patch(fc="0.5", alpha=0.35, ec="0.3", ls="--", label="predicted 1 sigma (2 sigma dashed), every second"))
            if d.pred_alt_mean is not None:
                handles.append(Line2D([], [], color="0.3", lw=1.2, ls=":",
                                      label="other modes' mean paths (width, %: probability)"))
            fig.legend(handles=handles, loc="outside lower center", ncol=min(len(handles), 7), fontsize=8.5,
                       frameon=False)
        else:
            j = np.asarray(d.j_risk, dtype=float)
            pos = j[j > 0]
            lo = max(float(pos.min()) if len(pos) else 1e-3, 1e-3)
            hi = max(float(j.max()), lo * 10)
            norm = LogNorm(vmin=lo, vmax=hi)
            cmap = plt.get_cmap("viridis")
            _candidates(ax, d, cmap(norm(np.clip(j, lo, hi))))
            ax.set_title("The same candidates by J_risk", fontsize=10)
        if hit is not None:  # the other party of a collision just before impact (or of a conflict at its worst)
            ax.plot(hit[0], hit[1], marker="X", ms=13, mfc="red", mec="white", mew=1.2, zorder=8)
            # the label goes towards the middle of the panel, so that it never runs off its edge
            right, top = hit[0] > (x0 + x1) / 2, hit[1] > (y0 + y1) / 2
            ax.annotate(hit[2], (hit[0], hit[1]), xytext=(-8 if right else 8, -8 if top else 8),
                        textcoords="offset points", ha="right" if right else "left", va="top" if top else "bottom",
                        color="red", fontsize=9, weight="bold", zorder=8,
                        path_effects=[withStroke(linewidth=2.0, foreground="white")])
        ax.set_xlim(x0, x1)
        ax.set_ylim(y0, y1)
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_facecolor("#f7f7f2")
    from matplotlib.ticker import NullFormatter

    cb = fig.colorbar(plt.cm.ScalarMappable(norm=norm, cmap=cmap), ax=axes, shrink=0.5, location="bottom",
                      label="J_risk of the candidate (second map) [cost units, log scale]")
    cb.ax.xaxis.set_minor_formatter(NullFormatter())
    alt = alternative(d)
    cost_panel(panel, d, alt, weights)
    fig.suptitle(title, fontsize=11.5)
    return fig, n_drawn, alt


def net_file(run: Path) -> Path | None:
    """The SUMO network of a run's scenario (from config.json), or None if it cannot be found."""
    from sumo_ethics.sim.scenario import read_scenario

    try:
        cfg = json.loads((Path(run) / "config.json").read_text())
        net = Path(cfg.get("resolved", {}).get("net", ""))
        if net.name and net.is_file():  # runs since the network's absolute path was recorded
            return net
        scenario = Path(cfg["scenario"])
        if not scenario.is_absolute():  # the summary names it resolved
            scenario = Path(json.loads((Path(run) / "summary.json").read_text()).get("scenario") or scenario)
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None
    # a relative path is relative to where the run was started: here, or a folder above the run
    bases = [Path.cwd()] if scenario.is_absolute() else [Path.cwd(), *Path(run).resolve().parents]
    for base in bases:
        try:
            return read_scenario(base / scenario).net
        except ConfigError:
            continue
    return None


def weights_of(run: Path) -> dict[str, float] | None:
    """The run's cost weights (``planner.cost.weights`` of config.json), or None."""
    try:
        w = json.loads((Path(run) / "config.json").read_text())["planner"]["cost"]["weights"]
        return {k: float(v) for k, v in w.items()}
    except (OSError, ValueError, KeyError, TypeError):
        return None


def road_of(run: Path) -> Any:
    path = net_file(run)
    if path is None:
        return None
    from sumo_ethics.sim.network import read_road

    return read_road(path)


def describe(run: Path, d: RecordedDecision) -> str:
    """Title line: run, step, time, speed, the choice."""
    speed = d.ego[3]
    return (f"{Path(run).name}: step {d.step}, planning time t = {d.time:.2f} s, ego at {speed:.1f} m/s; "
            f"chose candidate {d.chosen} of {d.n_candidates} ({VALIDITY_LABELS[int(d.validity[d.chosen])]}), "
            f"J_risk {_fmt(float(d.j_risk[d.chosen]))}")


def explain(run: Path, step: int, out: Path | None = None, title: str | None = None,
            hit: tuple[float, float, str] | None = None) -> Explained:
    """Draw the decision recorded for ``step`` of ``run`` to ``out`` (.png and .svg; default
    RUN/explain/step_NNNNNN)."""
    import matplotlib.pyplot as plt

    run = Path(run)
    d = load_checked(run, step)
    fig, n, alt = decision_figure(d, road_of(run), title or describe(run, d), weights_of(run), hit)
    base = Path(out) if out is not None else run / "explain" / f"step_{step:06d}"
    base = base.with_suffix("") if base.suffix in (".png", ".svg") else base
    base.parent.mkdir(parents=True, exist_ok=True)
    paths = []
    for ext in (".png", ".svg"):
        p = base.with_name(base.name + ext)
        fig.savefig(p, dpi=110, metadata={"Date": None} if ext == ".svg" else None)
        paths.append(p)
    plt.close(fig)
    return Explained(tuple(paths), d, n, alt)


def collision_snapshots(run: Path, rows: list[dict[str, Any]]) -> list[Path]:
    """A figure of the last planning step before each booked ego collision in ``rows``, written
    to RUN/snapshots/collision_<event>.png/.svg (the decisions must be recorded)."""
    from sumo_ethics.collision import is_booked

    out = []
    have = set(rec.recorded_steps(run))
    for r in rows:
        if not is_booked(r) or int(r["step"]) not in have:
            continue
        title = (f"Collision {r['event']}: ego and {r['class_b']} '{r['id_b']}' at t = {r['time']:.2f} s, "
                 f"harm ego {r['harm_ego']:.3f}, third party {r['harm_third_party']:.3f}. "
                 f"The last decision before impact:")
        res = explain(run, int(r["step"]), Path(run) / rec.SNAPSHOTS / f"collision_{r['event']}", title=title,
                      hit=(float(r["x_b"]), float(r["y_b"]), f"hit: {r['class_b']} '{r['id_b']}'"))
        out.extend(res.paths)
    return out
