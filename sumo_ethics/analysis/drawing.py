"""Drawing primitives for recorded decisions (matplotlib): the road, every road user's box and
prediction, the candidates, the colours, the view window. ``explain`` and ``replay`` draw with them."""

from __future__ import annotations

from typing import Any

import numpy as np

from sumo_ethics.geometry import OrientedBoxes, ellipses
from sumo_ethics.record import decisions as rec
from sumo_ethics.record.decisions import RecordedDecision
from sumo_ethics.types import RoadUserClass

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
        ax.add_patch(Patch(OrientedBoxes(x, y, yaw, length, width).corners(), closed=True, fc=colour, ec="black", lw=0.6, zorder=5))
        if RoadUserClass(int(cls)) in (RoadUserClass.PEDESTRIAN, RoadUserClass.BICYCLE):  # small: ringed
            ax.plot(x, y, "o", ms=11, mfc="none", mec=colour, mew=1.5, zorder=5.1)
        if predictions and d.pred_mean.shape[0] > i:
            m = d.pred_mean[i]
            ax.plot(np.r_[x, m[:, 0]], np.r_[y, m[:, 1]], color=colour, lw=1.2, zorder=4)
            for t in d.whole_seconds():
                e1, e2 = ellipses(m[t], d.pred_cov[i, t], 1.0, 40), ellipses(m[t], d.pred_cov[i, t], 2.0, 40)
                ax.fill(e1[:, 0], e1[:, 1], color=colour, alpha=0.22, lw=0, zorder=3)
                ax.plot(e2[:, 0], e2[:, 1], color=colour, alpha=0.5, lw=0.6, ls="--", zorder=3)
            if d.pred_alt_mean is not None and d.pred_weight is not None:  # other modes (recorded together): dotted mean paths,
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
    ax.add_patch(Patch(OrientedBoxes(ex, ey, eyaw, el, ew).corners(), closed=True, fc=EGO_COLOUR, ec="white", lw=1.0, zorder=6))
    return seen


#: what the sensor did not see (the shadows within its range) and the phantom road users
HIDDEN_COLOUR = "#5a5a78"
PHANTOM_COLOUR = "#7b2cbf"


def geometry_patch(geom: Any, **kw: Any) -> Any:
    """A matplotlib PathPatch of a shapely (Multi)Polygon, holes included (None if empty)."""
    import shapely
    from matplotlib.patches import PathPatch
    from matplotlib.path import Path as MPath

    rings = []
    for part in shapely.get_parts(geom):
        if part.geom_type != "Polygon" or part.is_empty:
            continue
        rings.append(np.asarray(part.exterior.coords)[:, :2])
        rings.extend(np.asarray(r.coords)[:, :2] for r in part.interiors)
    if not rings:
        return None
    verts = np.concatenate(rings)
    codes = np.concatenate([[MPath.MOVETO] + [MPath.LINETO] * (len(r) - 2) + [MPath.CLOSEPOLY] for r in rings])
    return PathPatch(MPath(verts, codes), **kw)


def draw_view(ax: Any, d: RecordedDecision) -> bool:
    """What the ego's sensor saw (``d.view``, ``[planner] occlusion``/``phantoms``): the shadows within
    its range shaded and hatched, the range's edge dashed, the remembered road users' boxes ringed
    with dots, each phantom as a dashed box with its predicted mean path and its existence
    probability (and the chosen candidate's expected risk with it). False (nothing drawn) without a view."""
    from matplotlib.patches import Circle, Polygon as Patch
    from matplotlib.patheffects import withStroke

    v = d.view
    if v is None:
        return False
    patch = geometry_patch(v.hidden, fc=HIDDEN_COLOUR, alpha=0.28, ec=HIDDEN_COLOUR, lw=0.4, hatch="///", zorder=1)
    if patch is not None:
        ax.add_patch(patch)
    ax.add_patch(Circle((float(v.eye[0]), float(v.eye[1])), v.radius, fill=False, ec=HIDDEN_COLOUR, lw=1.0, ls="--",
                        zorder=1.1))
    ax.plot(v.eye[0], v.eye[1], marker="^", ms=6, color="white", mec="black", zorder=6.5)
    remembered = set(v.remembered)
    for aid, row in zip(d.agent_ids, d.agents):
        if aid in remembered:
            x, y, yaw, _, length, width, _ = row
            c = OrientedBoxes(x, y, yaw, length + 1.0, width + 1.0).corners()
            ax.add_patch(Patch(c, closed=True, fill=False, ec="black", lw=1.0, ls=":", zorder=5.2))
    for i, row in enumerate(v.phantoms):
        x, y, yaw, _, length, width, _ = row
        ax.add_patch(Patch(OrientedBoxes(x, y, yaw, length, width).corners(), closed=True, fc="none",
                           ec=PHANTOM_COLOUR, lw=1.4, ls="--", zorder=5.3))
        ax.plot(x, y, "o", ms=11, mfc="none", mec=PHANTOM_COLOUR, mew=1.2, ls="none", zorder=5.3)
        if v.phantom_mean.shape[0] > i:
            m = v.phantom_mean[i]
            ax.plot(np.r_[x, m[:, 0]], np.r_[y, m[:, 1]], color=PHANTOM_COLOUR, lw=1.2, ls="--", zorder=4)
        risk = v.phantom_risk[i] if len(v.phantom_risk) > i else float("nan")
        ax.text(x, y, f"  p={v.phantom_existence[i]:.2g}\n  risk {fmt(float(risk))}", fontsize=7,
                color=PHANTOM_COLOUR, ha="left", va="center", zorder=8, clip_on=True,
                path_effects=[withStroke(linewidth=2.0, foreground="white")])
    return True


def draw_candidates(ax: Any, d: RecordedDecision, colours: Any, chosen: bool = True) -> int:
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


def fmt(v: float) -> str:
    """A number for a figure: 3 significant digits, "-" for NaN or infinite."""
    if not np.isfinite(v):
        return "-"
    if v == 0:
        return "0"
    return f"{v:.3g}" if 1e-3 <= abs(v) < 1e5 else f"{v:.2e}"
