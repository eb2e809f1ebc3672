"""Phantom road users: hypothetical ones where the map says one could come out of a shadow unseen
(``[planner] phantoms = true``; docs/occlusion.md).

Where (:func:`place`), within ``lookahead`` of the ego along its path (``PerceptionConfig``):

- **pedestrians** in the hidden part of a walkable area (sidewalks, crossings, walking areas of the
  :class:`~sumo_ethics.plan.perception.SightMap`), shrunk by half the phantom's size so that all of
  it is hidden and on walkable ground: at the point of each hidden patch nearest the ego's path
  (then the nearest along it) from which the straight walk to the path crosses no road user's box
  and no opaque polygon; walking straight towards the path and across it at ``pedestrian_speed``;
  at most one per patch, ``spacing`` apart along the path. A shadow with no walkable ground in it
  has no pedestrian phantom.
- **cyclists** on a bike lane's hidden stretch, at its downstream end (where a cyclist riding the
  lane would come into view), riding on along the lane and straight past its end at ``cyclist_speed``.
- **vehicles** on a lane entering a junction the ego's path crosses ahead (not a lane of the ego's
  route), at the downstream end of its hidden stretch, at ``vehicle_speed`` x its speed limit,
  along the lane and straight on across the junction; none where the lane's signal shows red.

Sizes (length x width) are Frenetix-Occlusion's phantom agents': pedestrian 0.3 x 0.5 m, bicycle
2.0 x 0.9 m, car 4.8 x 2.0 m; masses those of the harm model. Each is predicted along its way at
constant speed with the constant-velocity predictor's uncertainty for its class, and exists with
its class's probability (``*_existence``). Their risk (:func:`phantom_risk`): existence x
P(collision) x harm, the ego's and the phantom's, summed over the phantoms, is the cost term
``phantom`` (x ``weight``), apart from every real party's risk.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import shapely

from sumo_ethics.ethics.harm import MassModel
from sumo_ethics.ethics.probability import ProbabilityConfig
from sumo_ethics.ethics.risk import assess_risk
from sumo_ethics.geometry import OrientedBoxes
from sumo_ethics.predict import features as F
from sumo_ethics.predict.constant_velocity import ConstantVelocityPredictor
from sumo_ethics.types import AgentStates, Candidates, Prediction, RoadUserClass
from sumo_ethics.visibility import View, boxes

__all__ = ["Phantoms", "place", "phantom_risk", "SIZES", "KINDS"]

#: the phantom kinds and their class and size (length, width) [m]: Frenetix-Occlusion's phantom agents
KINDS = ("pedestrian", "cyclist", "vehicle")
SIZES = {"pedestrian": (RoadUserClass.PEDESTRIAN, 0.3, 0.5), "cyclist": (RoadUserClass.BICYCLE, 2.0, 0.9),
         "vehicle": (RoadUserClass.CAR, 4.8, 2.0)}
#: pedestrian phantoms farther than this from the ego's path [m] are not placed (Frenetix-Occlusion: 15 m)
LATERAL = 15.0
#: the hidden walkable patches' outlines are sampled at this spacing [m]
SAMPLE = 0.5
#: signal states of a lane's link that stop a phantom vehicle (red)
STOP = frozenset("rR")


@dataclass(frozen=True)
class Phantoms:
    """P hypothetical road users: their states now (ids ``phantom:<kind>:<i>``), predictions, kinds
    and existence probabilities (P,)."""

    agents: AgentStates
    prediction: Prediction
    kind: tuple[str, ...]
    existence: np.ndarray

    def __len__(self) -> int:
        return len(self.agents)


def _cov(cls: int, yaw: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(T, 2, 2) the constant-velocity predictor's covariance for class ``cls`` along headings
    ``yaw`` (T,) at times ``t`` (T,) [s]."""
    cv = ConstantVelocityPredictor()
    g = cv.growth_table()[F.class_group(np.array([cls], dtype=np.int8))][0]
    sig = cv.sigma0 + g[None, :] * t[:, None]
    c, s = np.cos(yaw), np.sin(yaw)
    rot = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)
    diag = np.zeros((len(t), 2, 2))
    diag[:, 0, 0], diag[:, 1, 1] = sig[:, 0] ** 2, sig[:, 1] ** 2
    return rot @ diag @ np.swapaxes(rot, -1, -2)


def _along(xy: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points (U, 2) and headings (U,) at arc lengths ``u`` along the polyline ``xy`` (P, 2),
    straight on past either end."""
    seg = np.diff(xy, axis=0)
    ln = np.hypot(seg[:, 0], seg[:, 1])
    ok = ln > 1e-9
    xy = np.r_[xy[:1], xy[1:][ok]]
    seg, ln = seg[ok], ln[ok]
    arc = np.r_[0.0, np.cumsum(ln)]
    i = np.clip(np.searchsorted(arc, u, side="right") - 1, 0, len(seg) - 1)
    unit = seg[i] / ln[i][:, None]
    pts = xy[i] + unit * (u - arc[i])[:, None]
    return pts, np.arctan2(unit[:, 1], unit[:, 0])


def _prediction(kind: str, rows: list[tuple[np.ndarray, np.ndarray]], horizon_steps: int, dt: float,
                ids: tuple[str, ...]) -> Prediction:
    cls = int(SIZES[kind][0])
    t = (np.arange(horizon_steps) + 1) * dt
    return Prediction(ids, dt, np.stack([m for m, _ in rows]) if rows else np.zeros((0, horizon_steps, 2)),
                      np.stack([_cov(cls, y, t) for _, y in rows]) if rows else np.zeros((0, horizon_steps, 2, 2)),
                      np.stack([y for _, y in rows]) if rows else np.zeros((0, horizon_steps)))


def _window(scene: Any, cfg: Any) -> tuple[float, float]:
    """The stretch of the ego's path [s0, s1] [m] phantoms are placed along: from its front bumper
    to max(lookahead x speed, lookahead_min) ahead of its centre, within the sensor's range."""
    v = float(scene.ego.speed[0])
    ahead = min(max(cfg.lookahead * v, cfg.lookahead_min), cfg.sensor_range)
    return scene.s + float(scene.ego.length[0]) / 2.0, scene.s + ahead


def _pedestrians(v: View, sight: Any, scene: Any, walls: np.ndarray, cfg: Any, window: tuple[float, float]
                 ) -> list[tuple[float, float, float, float]]:
    """(x, y, yaw, s) of the pedestrian phantoms, nearest along the path first. ``walls``: the
    geometries a phantom's walk to the path may not cross (known road users' boxes, buildings; a
    point inside a building, where a walkable area overlaps one, starts its walk in it: none there)."""
    walkable = sight.near("walkable", v.disc())
    if not len(walkable):
        return []
    _, length, width = SIZES["pedestrian"]
    r = 0.5 * max(length, width)
    patches = shapely.intersection(np.asarray([sight.walkable[i] for i in walkable], dtype=object), v.hidden)
    patches = patches[~shapely.is_empty(patches)]
    parts = shapely.get_parts(shapely.buffer(patches, -r)) if len(patches) else np.empty(0, dtype=object)
    parts = parts[(shapely.get_type_id(parts) == 3) & ~shapely.is_empty(parts)] if len(parts) else parts  # polygons
    if not len(parts):
        return []
    pts, part = shapely.get_coordinates(shapely.segmentize(shapely.get_exterior_ring(parts), SAMPLE),
                                        return_index=True)
    path = scene.route.path
    s, d = path.project(pts, near=(window[0] - LATERAL, window[1] + LATERAL))  # only the window's segments
    ok = np.flatnonzero((s > window[0] + r) & (s <= window[1]) & (np.abs(d) <= LATERAL))
    if not len(ok):
        return []
    pts, part, s, d = pts[ok], part[ok], s[ok], d[ok]
    fx, fy, _ = path.to_xy(s, np.zeros_like(s))
    walks = shapely.linestrings(np.stack([pts, np.c_[fx, fy]], axis=1))
    blocked = np.zeros(len(pts), dtype=bool)
    if len(walls):
        hit = shapely.STRtree(walls).query(walks, predicate="intersects")
        blocked[hit[0]] = True
    clear = np.flatnonzero(~blocked)
    if not len(clear):
        return []
    pts, part, s, d = pts[clear], part[clear], s[clear], d[clear]
    order = np.lexsort((s, np.round(np.abs(d), 1), part))  # per patch: nearest the path, then nearest along it
    first = order[np.r_[True, part[order][1:] != part[order][:-1]]]
    heading = path.heading_at(s[first])
    picks = [(float(pts[j, 0]), float(pts[j, 1]), float(h) + (np.pi / 2 if d[j] < 0 else -np.pi / 2), float(s[j]))
             for j, h in zip(first, heading)]
    picks.sort(key=lambda p: p[3])
    kept: list[tuple[float, float, float, float]] = []
    for p in picks:
        if all(abs(p[3] - q[3]) >= cfg.spacing for q in kept):
            kept.append(p)
    return kept[:cfg.max_phantoms]


def _on_lanes(v: View, sight: Any, lanes: list[int], kind: str, cfg: Any) -> list[tuple[float, float, float, int, float]]:
    """(x, y, distance from the eye, lane index, arc length [m]) of a phantom on each lane of
    ``lanes`` that has a hidden stretch, the nearest ``max_phantoms``: at the stretch's downstream
    end, set back half the phantom's length. Vectorised over the lanes."""
    if not lanes:
        return []
    _, length, _ = SIZES[kind]
    idx = np.asarray(lanes, dtype=np.intp)
    lines = sight.lines()[idx]
    hidden = shapely.intersection(lines, v.hidden)
    some = np.flatnonzero(~shapely.is_empty(hidden))
    if not len(some):
        return []
    ends, which = shapely.get_coordinates(shapely.boundary(hidden[some]), return_index=True)
    if not len(ends):
        return []
    u = shapely.line_locate_point(lines[some][which], shapely.points(ends))
    order = np.lexsort((-u, which))  # per lane, the farthest along it first: the stretch's downstream end
    first = order[np.r_[True, which[order][1:] != which[order][:-1]]]
    out = []
    for j in first:
        if np.hypot(*(ends[j] - v.eye)) >= v.radius - 0.5:  # the range's edge, not a shadow's
            continue
        i = int(idx[some[which[j]]])
        u0 = float(u[j]) - length / 2.0
        xy, _ = _along(sight.lanes[i].xy, np.array([u0]))
        out.append((float(xy[0, 0]), float(xy[0, 1]), float(np.hypot(*(xy[0] - v.eye))), i, u0))
    out.sort(key=lambda p: p[2])
    return out[:cfg.max_phantoms]


def _junctions_ahead(route: Any, window: tuple[float, float]) -> set[str]:
    """Ids of the junctions whose internal lanes the ego's path takes within ``window`` [m]."""
    i0, i1 = route.vertex_at(window[0]), route.vertex_at(window[1])
    return {lane[1:].rsplit("_", 2)[0] for lane in route.lane_of_vertex[i0:i1 + 1] if lane.startswith(":")}


def place(v: View, sight: Any, scene: Any, known: AgentStates, cfg: Any, horizon_steps: int, dt: float) -> Phantoms:
    """The phantoms of one planning step (see the module doc): ``v`` the ego's view, ``sight`` the
    :class:`~sumo_ethics.plan.perception.SightMap`, ``scene`` the step's scene (the ego, its path),
    ``known`` the road users the planner knows (their boxes block a phantom pedestrian's walk),
    ``cfg`` the PerceptionConfig; predictions over ``horizon_steps`` steps of ``dt`` [s]."""
    window = _window(scene, cfg)
    opaque = [sight.opaque[i] for i in sight.near("opaque", v.disc())]
    parts = list(boxes(OrientedBoxes(known.x, known.y, known.yaw, known.length, known.width).corners())) if len(known) else []
    walls = np.asarray(parts + opaque, dtype=object)
    t = (np.arange(horizon_steps) + 1) * dt
    rows: dict[str, list[tuple[np.ndarray, np.ndarray, float, float, float]]] = {k: [] for k in KINDS}
    if cfg.pedestrian_existence > 0.0:
        for x, y, yaw, _ in _pedestrians(v, sight, scene, walls, cfg, window):
            heading = np.array([np.cos(yaw), np.sin(yaw)])
            mean = np.array([x, y]) + cfg.pedestrian_speed * t[:, None] * heading
            rows["pedestrian"].append((mean, np.full(horizon_steps, yaw), x, y, cfg.pedestrian_speed))
    lanes = sight.near("lanes", v.disc()) if sight.lanes else np.zeros(0, dtype=np.intp)
    route_edges = set(scene.route.edges)
    if cfg.cyclist_existence > 0.0 and len(lanes):
        bikes = [int(i) for i in lanes if sight.lanes[i].kind == "bike"]
        for x, y, _, i, u0 in _on_lanes(v, sight, bikes, "cyclist", cfg):
            mean, yaws = _along(sight.lanes[i].xy, u0 + cfg.cyclist_speed * t)
            rows["cyclist"].append((mean, yaws, x, y, cfg.cyclist_speed))
    if cfg.vehicle_existence > 0.0 and len(lanes):
        ahead = _junctions_ahead(scene.route, window)
        state = sight.link_state
        roads = [int(i) for i in lanes if sight.lanes[i].kind == "road" and sight.lanes[i].junction in ahead
                 and sight.lanes[i].id.rsplit("_", 1)[0] not in route_edges
                 and not (state is not None and state(sight.lanes[i].id) in STOP)]
        for x, y, _, i, u0 in _on_lanes(v, sight, roads, "vehicle", cfg):
            speed = cfg.vehicle_speed * sight.lanes[i].speed
            mean, yaws = _along(sight.lanes[i].xy, u0 + speed * t)
            rows["vehicle"].append((mean, yaws, x, y, speed))
    return _assemble(rows, cfg, horizon_steps, dt)


def _assemble(rows: dict[str, list[tuple[np.ndarray, np.ndarray, float, float, float]]], cfg: Any,
              horizon_steps: int, dt: float) -> Phantoms:
    ids: list[str] = []
    kinds: list[str] = []
    cols: list[tuple[float, ...]] = []
    preds = []
    masses = MassModel()
    for kind in KINDS:
        cls, length, width = SIZES[kind]
        kind_ids = tuple(f"phantom:{kind}:{i}" for i in range(len(rows[kind])))
        for (_, yaws, x, y, speed) in rows[kind]:
            mass = float(masses.mass(np.array([int(cls)]), np.array([length]), np.array([width]))[0])
            cols.append((x, y, float(yaws[0]), speed, length, width, mass, int(cls)))
        if rows[kind]:
            preds.append(_prediction(kind, [(m, y) for m, y, *_ in rows[kind]], horizon_steps, dt, kind_ids))
        ids += kind_ids
        kinds += [kind] * len(kind_ids)
    a = np.array(cols, dtype=float).reshape(-1, 8)
    agents = AgentStates(tuple(ids), a[:, 0], a[:, 1], a[:, 2], a[:, 3], np.zeros(len(a)), a[:, 4], a[:, 5], a[:, 6],
                         a[:, 7].astype(np.int8), tuple("phantom" for _ in ids))
    if preds:
        pred = Prediction(tuple(ids), dt, np.concatenate([p.mean for p in preds]), np.concatenate([p.cov for p in preds]),
                          np.concatenate([p.yaw for p in preds]))
    else:
        pred = Prediction((), dt, np.zeros((0, horizon_steps, 2)), np.zeros((0, horizon_steps, 2, 2)),
                          np.zeros((0, horizon_steps)))
    existence = np.array([getattr(cfg, f"{k}_existence") for k in kinds], dtype=float)
    return Phantoms(agents, pred, tuple(kinds), existence)


#: [m/s] an ego slower than this has stopped: a phantom walking or riding into it is not counted
STOPPED = 0.1


def contingency(cand: Candidates, ego: AgentStates, reaction: float, decel: float) -> Candidates:
    """Each candidate as the ego would drive it if a phantom stepped out now: along the candidate
    for ``reaction`` seconds (the phantom is seen as it leaves the shadow; the replanning and the
    brakes take this long), then braking at ``decel`` [m/s^2] along the candidate's own path to a
    stop. Steps at which the ego stands (slower than :data:`STOPPED`) are marked invalid: a road
    user who walks or rides into a standing car is not counted against it. Vectorised over (K, T)."""
    K, T = cand.x.shape
    if K == 0 or T == 0:
        return cand
    t = (np.arange(T) + 1) * cand.dt
    x0, y0 = float(ego.x[0]), float(ego.y[0])
    px = np.concatenate([np.full((K, 1), x0), cand.x], axis=1)  # (K, T + 1) the path, from the ego
    py = np.concatenate([np.full((K, 1), y0), cand.y], axis=1)
    arc = np.concatenate([np.zeros((K, 1)), np.cumsum(np.hypot(np.diff(px, axis=1), np.diff(py, axis=1)), axis=1)],
                         axis=1)
    r = min(max(int(round(reaction / cand.dt)), 0), T)  # steps driven as planned
    if r == 0:
        l_r, v_r = np.zeros(K), np.full(K, float(ego.speed[0]))
    else:
        l_r, v_r = arc[:, r], np.maximum(cand.speed[:, r - 1], 0.0)
    tau = np.maximum(t[None, :] - r * cand.dt, 0.0)  # (1, T) time braking
    tb = np.minimum(tau, v_r[:, None] / max(decel, 1e-9))
    braking = t[None, :] > r * cand.dt + 1e-9
    length = np.where(braking, l_r[:, None] + v_r[:, None] * tb - 0.5 * decel * tb**2, arc[:, 1:])
    speed = np.where(braking, np.maximum(v_r[:, None] - decel * tau, 0.0), cand.speed)
    accel = np.where(braking, np.where(speed > 0.0, -decel, 0.0), cand.accel)
    length = np.minimum(length, arc[:, -1:])
    # positions along each candidate's own polyline at those arc lengths (rows offset to search once)
    span = float(arc[:, -1].max()) + 1.0
    flat = (arc + span * np.arange(K)[:, None]).ravel()
    q = length + span * np.arange(K)[:, None]
    j = np.clip(np.searchsorted(flat, q.ravel(), side="right") - 1, 0, flat.size - 2).reshape(K, T)
    j = np.clip(j - (T + 1) * np.arange(K)[:, None], 0, T - 1)  # segment index within its row
    rows = np.arange(K)[:, None]
    a0, a1 = arc[rows, j], arc[rows, j + 1]
    u = np.where(a1 > a0, (length - a0) / np.maximum(a1 - a0, 1e-12), 0.0)
    x = px[rows, j] + u * (px[rows, j + 1] - px[rows, j])
    y = py[rows, j] + u * (py[rows, j + 1] - py[rows, j])
    yaw = np.where(braking, cand.yaw[rows, j], cand.yaw)
    valid = cand.valid & (speed > STOPPED)
    return Candidates(cand.dt, x, y, yaw, speed, accel, cand.curvature, cand.s, cand.d, cand.horizon, valid,
                      cand.road_curvature)


def phantom_risk(cand: Candidates, ph: Phantoms, ego: AgentStates, prob_cfg: ProbabilityConfig,
                 reaction: float, decel: float) -> np.ndarray:
    """(K, P) each candidate's expected risk with each phantom: existence x (the ego's risk + the
    phantom's risk), each P(collision) x harm at its worst step (:func:`~sumo_ethics.ethics.risk.assess_risk`),
    for the candidate as the ego would drive it if the phantom stepped out now (:func:`contingency`:
    ``reaction`` [s], then braking at ``decel`` [m/s^2])."""
    if not len(ph):
        return np.zeros((len(cand), 0))
    braked = contingency(cand, ego, reaction, decel)
    r = assess_risk(braked, ph.prediction, ph.agents, ego_mass=float(ego.mass[0]), ego_cls=int(ego.cls[0]),
                    ego_length=float(ego.length[0]), ego_width=float(ego.width[0]), prob_cfg=prob_cfg, steps=False)
    return (r.ego_risk + r.other_risk) * ph.existence[None, :]
