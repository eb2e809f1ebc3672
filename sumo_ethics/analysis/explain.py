"""Pictures of recorded decisions: ``sumo-ethics explain`` (one planning step) and the collision
snapshots drawn from a finished run folder (:func:`draw_snapshots`: by ``sumo-ethics run`` when the
run ends, ``evaluate`` and sweeps, or ``sumo-ethics explain RUN --snapshots``; reading the run:
:mod:`recorded`; drawing: :mod:`drawing`; the frames of ``sumo-ethics replay``: :mod:`replay`).

A decision figure has three parts. Left, the scene: the road from the SUMO network, every road
user as its true box coloured by class, each predicted trajectory (mean and 1- / 2-sigma ellipses
every second) and the candidates coloured by validity class. Middle, the same candidates coloured
by J_risk. Right, the chosen candidate's named cost terms beside the best candidate of another
validity class (the alternative the rule did not take).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sumo_ethics.analysis.drawing import (CLASS_COLOURS, EGO_COLOUR, HIDDEN_COLOUR, PHANTOM_COLOUR, VALIDITY_COLOURS,
                                          VALIDITY_LABELS, draw_agents, draw_candidates, draw_road, draw_view, fmt,
                                          window)
from sumo_ethics.analysis.recorded import (collision_mark, decisions_of, fleet_egos, is_fleet, load_checked, party_label,
                                            road_of, weights_of)
from sumo_ethics.ethics.terms import BUILTIN, CostTerm, cost_terms, term
from sumo_ethics.record import decisions as rec
from sumo_ethics.record.decisions import RecordedDecision
from sumo_ethics.types import EXCLUSIONS, RoadUserClass

#: the rows that are no cost term: what the selection rule added and what it minimised
SELECTION_ROWS = (("penalty", "envelope + entry"), ("selection", "selection total"))
#: the aggregates at the panel's top, in this order
HEAD_TERMS = ("j_risk", "j_origin", "j_utility")


def panel_rows() -> list[tuple[str, str, bool]]:
    """The cost panel's rows (name, label, optional) from the registered cost terms
    (:func:`sumo_ethics.ethics.terms.cost_terms`): J_risk, J_origin and J_utility; the terms summed
    into J_origin (principles, then progress, lateral and any registered "origin" term); the
    selection's penalty and total; the recorded quantities with a label; each "total" term, its
    weighted value first. An optional row is drawn only where the decision has the term."""
    terms = cost_terms()
    by_name = {t.name: t for t in terms}
    rows = [(n, by_name[n].label or n, False) for n in HEAD_TERMS]
    rows += [(t.name, t.label or t.name, t.optional) for t in terms if t.group in ("principle", "origin")]
    rows += [(n, label, False) for n, label in SELECTION_ROWS]
    rows += [(t.name, t.label, t.optional) for t in terms if t.group == "record" and t.label]
    for t in terms:
        if t.group == "total" and t.weighted:
            rows += [(t.weighted, t.weighted_label or t.weighted, t.optional), (t.name, t.label or t.name, t.optional)]
    return rows


#: the rows of a decision with every built-in term (panel_rows() reads the registry when it draws)
PANEL_TERMS = tuple((name, label) for name, label, _ in panel_rows())
#: rows shown only where the decision has the term (``[planner] phantoms``)
OPTIONAL_TERMS = tuple(name for name, _, optional in panel_rows() if optional)


@dataclass(frozen=True)
class Explained:
    """What :func:`explain` drew: the files, the decision, the candidates drawn, the alternative."""

    paths: tuple[Path, ...]
    decision: RecordedDecision
    n_drawn: int
    alternative: int | None


# ---- finding a decision ---------------------------------------------------------------------------
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
    t = _summed(name)
    if weights is not None and t is not None:
        scale = weights.get("risk", 1.0) if t.group == "principle" else 1.0
        value *= scale * weights.get(t.weight or name, 1.0)
    return value


def _summed(name: str) -> CostTerm | None:
    """The registered term ``name`` if it is weighted into J_origin (a principle or an "origin" term)."""
    try:
        t = term(name)
    except KeyError:
        return None
    return t if t.group in ("principle", "origin") else None


#: the principles' names (the built-in "principle" terms)
PRINCIPLES = tuple(t.name for t in BUILTIN if t.group == "principle")


def excluded_note(d: RecordedDecision, k: int) -> str:
    """'\\nexcluded: <the hard constraint>' for a candidate a hard constraint kept from being
    chosen (DecisionTrace.excluded), else ''."""
    code = 0 if d.excluded is None else int(d.excluded[k])
    return f"\nexcluded: {EXCLUSIONS[code]}" if code else ""


def cost_panel(ax: Any, d: RecordedDecision, alt: int | None, weights: dict[str, float] | None = None) -> None:
    """A table of the chosen candidate's named cost terms beside the alternative's; with the
    run's principle ``weights`` the J_origin rows are weighted (they then add up to J_origin).
    A hard constraint that kept the alternative from being chosen is a note under the table (a
    header of two lines fits its cell)."""
    import textwrap

    ax.axis("off")
    if alt is None:
        ax.text(0.5, 0.02, "Every candidate is in the chosen class:\nno alternative of another class.",
                ha="center", va="bottom", fontsize=9, transform=ax.transAxes)
    head = ["term", f"chosen\n{VALIDITY_LABELS[int(d.validity[d.chosen])]}"]
    note = excluded_note(d, alt).strip() if alt is not None else ""
    if alt is not None:
        head.append(f"best of another class:\n{VALIDITY_LABELS[int(d.validity[alt])]}{' *' if note else ''}")

    def label_of(name: str, label: str) -> str:
        t = _summed(name)
        if weights is None or t is None:
            return label
        w = weights.get(t.weight or name, 1.0)
        if t.group == "principle":
            return f"{label.split(' (')[0]} x {weights.get('risk', 1.0):g} x {w:g}"
        return f"{label} x {w:g}"

    rows = [(name, label) for name, label, optional in panel_rows() if not optional or name in d.terms]
    cells = [[label_of(name, label)] + [fmt(_term(d, d.chosen, name, weights))]
             + ([fmt(_term(d, alt, name, weights))] if alt is not None else []) for name, label in rows]
    table = ax.table(cellText=cells, colLabels=head, loc="upper center", cellLoc="right", colLoc="center",
                     colWidths=[0.47, 0.19, 0.33][:len(head)])
    table.auto_set_font_size(False)
    table.set_fontsize(8)
    table.scale(1.0, 1.35)
    lines = max(h.count("\n") + 1 for h in head)
    for (r, c), cell in table.get_celld().items():
        if r == 0:
            cell.set_text_props(weight="bold")
            cell.set_height(cell.get_height() * (0.8 * lines + 0.4))
        if c == 0:
            cell.set_text_props(ha="left")
    if note:  # right under the table (AXESPAD below the axes' top; cell heights are axes fractions), wrapped
        bottom = 1.0 - table.AXESPAD - sum(cell.get_height() for (r, c), cell in table.get_celld().items() if c == 0)
        ax.text(0.0, bottom - 0.01, "* " + textwrap.fill(note, 60, subsequent_indent="  "), ha="left", va="top",
                fontsize=8, transform=ax.transAxes)
    ax.set_title("Named cost terms [cost units]\nrisks: P(collision) x harm, summed over parties", fontsize=9.5)


def overflowing_text(fig: Any) -> list[str]:
    """The texts of a drawn figure that do not fit: a title, axis label, drawn tick label, unclipped
    annotation, legend entry or table cell reaching beyond the canvas, or a table cell's text beyond
    its cell. Empty when every text fits (tests/record/test_decisions.py checks the explain figure)."""
    from matplotlib.table import Table

    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    w, h = fig.bbox.width, fig.bbox.height
    texts = [fig._suptitle] if fig._suptitle is not None else []
    for ax in fig.axes:
        texts += [ax.title] + [t for t in ax.texts if not t.get_clip_on()]  # clipped ones stay in their axes
        if not ax.axison:  # axis("off"): no labels or ticks drawn
            continue
        texts += [ax.xaxis.label, ax.yaxis.label]
        for axis, (lo, hi) in ((ax.xaxis, sorted(ax.get_xlim())), (ax.yaxis, sorted(ax.get_ylim()))):
            texts += [t for t, loc in zip(axis.get_ticklabels(), axis.get_ticklocs()) if lo <= loc <= hi]
    texts += [t for leg in fig.legends for t in leg.get_texts()]
    cells = [cell for tab in fig.findobj(Table) for cell in tab.get_celld().values()]
    out = []
    for t in texts + [c.get_text() for c in cells]:
        if t.get_visible() and t.get_text().strip():
            e = t.get_window_extent(r)
            if e.x0 < -0.5 or e.y0 < -0.5 or e.x1 > w + 0.5 or e.y1 > h + 0.5:
                out.append(f"{t.get_text()!r} beyond the canvas")
    for cell in cells:
        t, e = cell.get_text(), cell.get_window_extent(r)
        te = t.get_window_extent(r)
        if t.get_text().strip() and (te.x0 < e.x0 - 0.5 or te.x1 > e.x1 + 0.5 or te.y0 < e.y0 - 0.5 or te.y1 > e.y1 + 0.5):
            out.append(f"{t.get_text()!r} beyond its table cell")
    return out


def decision_figure(d: RecordedDecision, road: Any, title: str, weights: dict[str, float] | None = None,
                    hit: tuple[float, float, str] | None = None) -> tuple[Any, int, int | None]:
    """The three-part figure of one decision; (figure, candidates drawn, alternative index)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.artist import Artist
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
        viewed = draw_view(ax, d)
        if i == 0:
            n_drawn = draw_candidates(ax, d, [VALIDITY_COLOURS[int(v)] for v in d.validity])
            ax.set_title(f"Candidates by validity class ({d.n_candidates}; chosen in black)", fontsize=10)
            handles: list[Artist] = [Line2D([], [], color=VALIDITY_COLOURS[c], lw=2, label=VALIDITY_LABELS[c])
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
            if viewed:
                handles.append(Patch(fc=HIDDEN_COLOUR, alpha=0.28, hatch="///", ec=HIDDEN_COLOUR,
                                     label="hidden from the sensor (range dashed)"))
                if d.view is not None and d.view.remembered:
                    handles.append(Patch(fc="none", ec="black", ls=":", label="remembered, unseen"))
                if d.view is not None and len(d.view.phantoms):
                    handles.append(Patch(fc="none", ec=PHANTOM_COLOUR, ls="--",
                                         label="phantom (p: existence), its risk"))
            fig.legend(handles=handles, loc="outside lower center", ncol=min(len(handles), 5), fontsize=8.5,
                       frameon=False)
        else:
            j = np.asarray(d.j_risk, dtype=float)
            pos = j[j > 0]
            lo = max(float(pos.min()) if len(pos) else 1e-3, 1e-3)
            hi = max(float(j.max()), lo * 10)
            norm = LogNorm(vmin=lo, vmax=hi)
            cmap = plt.get_cmap("viridis")
            draw_candidates(ax, d, cmap(norm(np.clip(j, lo, hi))))
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


def describe(run: Path, d: RecordedDecision, ego: str | None = None) -> str:
    """Title line: run (and fleet ego), step, time, speed, the choice."""
    speed = d.ego[3]
    who = "ego" if ego is None else f"ego '{ego}'"
    return (f"{Path(run).name}: step {d.step}, planning time t = {d.time:.2f} s, {who} at {speed:.1f} m/s; "
            f"chose candidate {d.chosen} of {d.n_candidates} ({VALIDITY_LABELS[int(d.validity[d.chosen])]}), "
            f"J_risk {fmt(float(d.j_risk[d.chosen]))}")


def explain(run: Path, step: int, out: Path | None = None, title: str | None = None,
            hit: tuple[float, float, str] | None = None, ego: str | None = None) -> Explained:
    """Draw the decision recorded for ``step`` of ``run`` to ``out`` (.png and .svg; default
    RUN/explain/step_NNNNNN); in a fleet run with per-ego decisions that of ``ego`` (required:
    :func:`sumo_ethics.analysis.recorded.decisions_of`), with its planner's weights, by default
    to RUN/explain/<ego folder>/step_NNNNNN."""
    import matplotlib.pyplot as plt

    run = Path(run)
    ego = decisions_of(run, ego)
    d = load_checked(run, step, ego)
    fig, n, alt = decision_figure(d, road_of(run), title or describe(run, d, ego), weights_of(run, ego), hit)
    folder = run / "explain" if ego is None else run / "explain" / rec.ego_folder(ego)
    base = Path(out) if out is not None else folder / f"step_{step:06d}"
    base = base.with_suffix("") if base.suffix in (".png", ".svg") else base
    base.parent.mkdir(parents=True, exist_ok=True)
    paths = []
    for ext in (".png", ".svg"):
        p = base.with_name(base.name + ext)
        fig.savefig(p, dpi=110, metadata={"Date": None} if ext == ".svg" else None)
        paths.append(p)
    plt.close(fig)
    return Explained(tuple(paths), d, n, alt)


def collision_snapshots(run: Path, rows: list[dict[str, Any]], egos: frozenset[str] | None = None) -> list[Path]:
    """A figure of the last planning step before each booked ego collision in ``rows``, written
    to RUN/snapshots/collision_<event>.png/.svg (the decisions must be recorded); in a fleet run
    (``egos``: its egos) one per ego party whose decision is recorded,
    RUN/snapshots/collision_<event>_<ego folder>.png/.svg."""
    from sumo_ethics.collision import is_booked

    out: list[Path] = []
    snaps = Path(run) / rec.SNAPSHOTS
    if egos is None:
        have = set(rec.recorded_steps(run))
        for r in rows:
            if not is_booked(r) or int(r["step"]) not in have:
                continue
            title = (f"Collision {r['event']}: ego and {party_label(r, 'b')} at t = {r['time']:.2f} s, "
                     f"harm ego {r['harm_ego']:.3f}, third party {r['harm_third_party']:.3f}. "
                     f"The last decision before impact:")
            res = explain(run, int(r["step"]), snaps / f"collision_{r['event']}", title=title, hit=collision_mark(r))
            out.extend(res.paths)
        return out
    kept: dict[str, set[int]] = {}
    for r in rows:
        if not is_booked(r):
            continue
        for p, q in (("a", "b"), ("b", "a")):
            ego = r[f"id_{p}"]
            if ego not in egos:
                continue
            if ego not in kept:
                kept[ego] = set(rec.recorded_steps(run, ego))
            if int(r["step"]) not in kept[ego]:
                continue
            title = (f"Collision {r['event']}: ego '{ego}' and {party_label(r, q)} at t = "
                     f"{r['time']:.2f} s, harm to '{ego}' {r[f'harm_{p}']:.3f}, to '{r[f'id_{q}']}' "
                     f"{r[f'harm_{q}']:.3f}. The last decision of '{ego}' before impact:")
            # ".png" ends the name: explain drops it, and only it (an id may end in ".svg")
            res = explain(run, int(r["step"]), snaps / f"collision_{r['event']}_{rec.ego_folder(ego)}.png",
                          title=title, hit=collision_mark(r, ego), ego=ego)
            out.extend(res.paths)
    return out


def draw_snapshots(run: Path, update_summary: bool = True) -> dict[str, Any]:
    """Draw the collision snapshot figures of run folder ``run`` from what it recorded
    (collisions.parquet and the decisions kept: :func:`collision_snapshots`; in a fleet run one per
    ego party), as ``sumo-ethics run`` does when a run ends (the run loop itself draws nothing) and
    ``sumo-ethics explain RUN --snapshots`` on request; ``evaluate`` and sweeps draw them for each run.

    Returns summary.json's keys for them: ``snapshots`` (the .png files, relative to ``run``),
    ``snapshot_wall`` [s] and, when drawing failed (never raised: the decisions stay on disk for
    ``explain``), ``snapshot_error``; empty when the run booked no ego collision. With
    ``update_summary`` those keys are written into the run's summary.json (when it has one)."""
    import json
    import time

    from sumo_ethics import fileio
    from sumo_ethics.collision import is_booked
    from sumo_ethics.record.reader import read_table

    run = Path(run)
    try:
        rows = read_table(run, "collisions").to_pylist()
    except Exception:  # noqa: BLE001 - no run folder, or an unreadable table: nothing to draw
        return {}
    if not any(is_booked(r) for r in rows):
        return {}
    out: dict[str, Any] = {}
    w = time.perf_counter()
    try:
        egos = frozenset(fleet_egos(run)) if is_fleet(run) else None
        paths = collision_snapshots(run, rows, egos)
        out["snapshots"] = [str(p.relative_to(run)) for p in paths if p.suffix == ".png"]
    except Exception as exc:  # noqa: BLE001 - a figure must never cost the run's outputs
        out["snapshot_error"] = f"{type(exc).__name__}: {exc}"
    out["snapshot_wall"] = time.perf_counter() - w
    summary = run / "summary.json"
    if update_summary and summary.is_file():
        try:
            data = json.loads(summary.read_text(encoding="utf-8"))
            for key in ("snapshots", "snapshot_error", "snapshot_wall"):
                data.pop(key, None)
            fileio.write_json(summary, data | out)
        except (OSError, ValueError) as exc:
            out["snapshot_error"] = f"summary.json not updated: {type(exc).__name__}: {exc}"
    return out
