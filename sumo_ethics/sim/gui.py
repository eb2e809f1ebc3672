"""sumo-gui as a live view of a run (``sumo-ethics run --gui``).

The view follows the ego, ringed in cyan (``vehicle.highlight``), in sumo-gui's "real world"
scheme. Each step the decision is drawn as polygons on a high
layer: the chosen trajectory (magenta), the predictions of the road users the chosen trajectory
puts at risk (orange: the predicted mean path and the 1-sigma ellipse every second) and, for the
rest of the run, a red ring where the ego collided. Drawing only: polygons (the highlight is one)
take no part in the simulation, so a run writes the same steps.parquet as without --gui. The ego
is not painted: ``vehicle.setColor`` would show in a scenario's vehroute-output. With ``[planner]
occlusion`` or ``phantoms`` the sensor's view is drawn too: the outline of each shadow within its range
and the range's edge (dark grey-blue; a translucent fill would let sumo-gui's background through the
map's own polygons where they are drawn later than ours) and each phantom road user (violet: its box
and predicted mean path).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterable

import numpy as np

from sumo_ethics.geometry import ellipses
from sumo_ethics.record.decisions import whole_seconds
from sumo_ethics.sim.backend import sumo

#: RGBA colours of what is drawn (pure hues, unlike anything sumo-gui draws itself); the ego's ring
EGO_COLOUR = (0, 255, 255, 255)
TRAJECTORY_COLOUR = (255, 0, 255, 255)
RISK_COLOUR = (255, 140, 0, 255)
COLLISION_COLOUR = (255, 0, 0, 255)
HIDDEN_COLOUR = (60, 60, 90, 255)
RANGE_COLOUR = (60, 60, 90, 255)
PHANTOM_COLOUR = (150, 60, 220, 255)
#: the polygons' layer: above roads and vehicles
LAYER = 120
#: line widths [m]
TRAJECTORY_WIDTH, PATH_WIDTH, RING_WIDTH = 0.5, 0.25, 0.6
#: radius [m] of the ring drawn around a collision
RING_RADIUS = 3.0
VIEW = "View #0"
#: sumo-gui's colour scheme set for the view: vehicles as car shapes (the standard one draws triangles)
SCHEME = "real world"
#: half the width and height [m] of the area shown around the ego at the start (zoom as you like)
SPAN = (45.0, 30.0)
#: prefix of every polygon id drawn here
PREFIX = "sumo-ethics:"


@dataclass(frozen=True)
class GuiOptions:
    """``run --gui``: delay_ms, sumo-gui's pause between steps [ms] (0: as fast as it goes)."""

    delay_ms: float = 0.0

    def sumo_args(self) -> list[str]:
        """sumo-gui's options: start at once, quit when the run ends, the delay."""
        return ["--start", "true", "--quit-on-end", "true", "--delay", f"{self.delay_ms:g}"]


def decision_shapes(trace: Any) -> dict[str, tuple[np.ndarray, tuple[int, ...], bool, float]]:
    """What one decision draws: polygon id -> (points (M, 2), colour, filled, line width [m]).

    ``trace``: the Decision's DecisionTrace (None draws nothing). The chosen candidate's centres
    ahead of the ego's front bumper, from there (the ego stays visible); for every neighbour with risk > 0 under it (``trace.agent_risk``), its
    predicted mean path from where it is and its 1-sigma ellipse at each whole second.
    """
    if trace is None:
        return {}
    c, k, e = trace.candidates, trace.chosen, trace.ego
    x, y, yaw, half = float(e.x[0]), float(e.y[0]), float(e.yaw[0]), float(e.length[0]) / 2
    pts = np.c_[c.x[k][c.valid[k]], c.y[k][c.valid[k]]]
    ahead = pts[np.hypot(pts[:, 0] - x, pts[:, 1] - y) > half]
    front = [x + half * np.cos(yaw), y + half * np.sin(yaw)]
    out: dict[str, tuple[np.ndarray, tuple[int, ...], bool, float]] = {
        f"{PREFIX}trajectory": (np.r_[[front], ahead], TRAJECTORY_COLOUR, False, TRAJECTORY_WIDTH)}
    out.update(view_shapes(getattr(trace, "view", None)))
    risk = trace.agent_risk
    if risk is None or not len(risk):
        return out
    p, a = trace.prediction, trace.agents
    seconds = whole_seconds((np.arange(p.mean.shape[1]) + 1) * p.dt)  # step t is at (t + 1) dt
    for n, i in enumerate(np.flatnonzero(risk > 0.0)):
        m = p.mean[i]
        if not np.isfinite(m).all():
            continue
        out[f"{PREFIX}risk:{n}"] = (np.r_[[[a.x[i], a.y[i]]], m], RISK_COLOUR, False, PATH_WIDTH)
        for t in seconds:
            e = ellipses(m[t], p.cov[i, t], 1.0, 24)
            out[f"{PREFIX}risk:{n}:{t}"] = (np.r_[e, e[:1]], RISK_COLOUR, False, PATH_WIDTH)
    return out


def view_shapes(view: Any) -> dict[str, tuple[np.ndarray, tuple[int, ...], bool, float]]:
    """What the sensor's view draws (a types.ViewTrace; None: nothing): the outline of each part of
    the shadows within the range (its exterior), the range's edge, each phantom's box and predicted
    mean path."""
    if view is None:
        return {}
    import shapely

    from sumo_ethics.geometry import OrientedBoxes

    out: dict[str, tuple[np.ndarray, tuple[int, ...], bool, float]] = {}
    parts = [g for g in shapely.get_parts(view.hidden) if g.geom_type == "Polygon" and not g.is_empty]
    for n, g in enumerate(parts):
        out[f"{PREFIX}hidden:{n}"] = (np.asarray(g.exterior.coords)[:, :2], HIDDEN_COLOUR, False, PATH_WIDTH)
    a = np.linspace(0.0, 2.0 * np.pi, 72)
    ring = np.asarray(view.eye)[None, :] + view.radius * np.c_[np.cos(a), np.sin(a)]
    out[f"{PREFIX}range"] = (ring, RANGE_COLOUR, False, PATH_WIDTH)
    ph = view.phantoms
    for i in range(len(ph)):
        c = OrientedBoxes(ph.x[i], ph.y[i], ph.yaw[i], ph.length[i], ph.width[i]).corners()
        out[f"{PREFIX}phantom:{i}"] = (np.r_[c, c[:1]], PHANTOM_COLOUR, False, PATH_WIDTH)
        if view.phantom_prediction is not None:
            m = view.phantom_prediction.mean[i]
            out[f"{PREFIX}phantom:{i}:path"] = (np.r_[[[ph.x[i], ph.y[i]]], m], PHANTOM_COLOUR, False, PATH_WIDTH)
    return out


class View:
    """The sumo-gui view of one ego: follows it and draws its decisions and collisions."""

    def __init__(self, ego_id: str) -> None:
        self.ego_id = ego_id
        self.drawn: dict[str, tuple[tuple[int, ...], bool, float]] = {}  # id -> colour, fill, width
        self.rings = 0
        sumo.vehicle.highlight(ego_id, EGO_COLOUR)
        x, y = sumo.vehicle.getPosition(ego_id)
        sumo.gui.setBoundary(VIEW, x - SPAN[0], y - SPAN[1], x + SPAN[0], y + SPAN[1])
        sumo.gui.setSchema(VIEW, SCHEME)
        sumo.gui.trackVehicle(VIEW, ego_id)

    def decided(self, decision: Any) -> None:
        """Draw ``decision`` (a contract.Decision), replacing the last one's polygons."""
        shapes = decision_shapes(decision.trace)
        for pid, (pts, colour, fill, width) in shapes.items():
            self._put(pid, pts, colour, fill, width)
        for pid in [p for p in self.drawn if p not in shapes and not p.startswith(f"{PREFIX}collision")]:
            sumo.polygon.remove(pid)
            del self.drawn[pid]

    def collided(self, rows: Iterable[dict[str, Any]]) -> None:
        """A ring (kept to the end) around each ego collision of ``rows`` (collisions.parquet
        rows) not drawn yet, centred between the two parties."""
        rows = [r for r in rows if r["involves_ego"] and r["detector"] != "sumo_unconfirmed"]
        for r in rows[self.rings:]:
            centre = np.array([(r["x_a"] + r["x_b"]) / 2, (r["y_a"] + r["y_b"]) / 2])
            a = np.linspace(0.0, 2.0 * np.pi, 24, endpoint=False)
            ring = centre + RING_RADIUS * np.c_[np.cos(a), np.sin(a)]
            self._put(f"{PREFIX}collision:{self.rings}", np.r_[ring, ring[:1]], COLLISION_COLOUR, False, RING_WIDTH)
            self.rings += 1

    def _put(self, pid: str, pts: np.ndarray, colour: tuple[int, ...], fill: bool, width: float) -> None:
        if len(pts) < 2:
            return
        shape = [(float(x), float(y)) for x, y in pts]
        style = (colour, fill, width)
        if self.drawn.get(pid) == style:
            sumo.polygon.setShape(pid, shape)
            return
        if pid in self.drawn:
            sumo.polygon.remove(pid)
        sumo.polygon.add(pid, shape, colour, fill=fill, polygonType="sumo-ethics", layer=LAYER, lineWidth=width)
        self.drawn[pid] = style
