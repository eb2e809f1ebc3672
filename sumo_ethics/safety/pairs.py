"""Conflict events among the road users that are not egos, network-wide (``[conflicts] everyone``).

:class:`PairConflictBook` is called once per step with every road user of the simulation
(:class:`sumo_ethics.sim.everyone.Everyone`) and the ids to leave out (the egos whose own
:class:`~sumo_ethics.safety.conflicts.ConflictBook` measured them this step), so each pair is
measured by one book. Measures, thresholds and events are those of the ego's book (TTC, DRAC,
distance, PET over footprint trails, :mod:`sumo_ethics.safety.measures`; one event per pair and
run of conflict steps), for pairs instead of ego x road user, vectorised over pairs:

1. candidate pairs from a k-d tree (``scipy.spatial.cKDTree.query_pairs``): road user i can be
   within TTC ``ttc`` or PET ``pet`` of j only if their centres are closer than R_i + R_j, with
   R = r + max(v ttc, D) (r: half the box diagonal, v: speed, D: the farthest its centre was
   over the PET trail from where it is now); the tree returns the pairs closer than 2 max R,
   which are then cut to those closer than R_i + R_j, on one level (|dz| <= 3 m) and not two
   pedestrians (SUMO's pedestrian model lets walkers overlap while they wait at a crossing and
   pass within centimetres: 65 of 148 events, 41 of them with contact, in 5 minutes of
   fokr_bs_demo, none of them a traffic conflict);
2. exact box TTC for the pairs whose bounding circles could meet within ``ttc`` at their
   relative speed, PET for the pairs where one's trail circle touches the other's circle now;
3. a Python loop over the pairs in conflict only (few), into events.

Party a of a pair is the one whose class comes first (car, truck, bus, motorcycle, bicycle,
pedestrian, other), then by id, so a car-pedestrian pair is always ``car``, ``pedestrian``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from sumo_ethics.config import ConflictConfig
from sumo_ethics.geometry import OrientedBoxes
from sumo_ethics.safety.conflicts import oldest_slot, book_event, boxes_of, event_counts
from sumo_ethics.safety.measures import box_distance, box_ttc, drac, pet_from_trail, ttc_with_turns, yaw_rates
from sumo_ethics.types import AgentStates, RoadUserClass

_LABELS = tuple(c.label for c in RoadUserClass)
#: pairs more than this apart in elevation [m] are on different levels (as sim.world's scene)
VERTICAL_CLEARANCE = 3.0


class PairConflictBook:
    """The conflicts among the non-ego road users of one run. :meth:`observe` once per step;
    rows go to ``sink`` (``add_conflict(row) -> index``, ``update_conflict(index, **changes)``)."""

    def __init__(self, sink: Any, cfg: ConflictConfig, dt: float) -> None:
        self.sink = sink
        self.cfg = cfg
        self.min_angle = math.radians(cfg.crossing_angle)
        self.n_trail = math.ceil(cfg.pet / dt - 1e-9) + 1  # trail instants W, as the ego's book
        # footprint trails, a ring buffer of the last W instants (in no order): (5, W, S) x, y, yaw,
        # length, width per slot S (one slot per road user present, reused once it left; NaN: empty)
        self.trail = np.full((5, self.n_trail, 0), np.nan)
        self.times = np.full(self.n_trail, np.nan)
        self.pushed = 0
        self.slot: dict[str, int] = {}
        self.open: dict[tuple[str, str], int] = {}  # pair -> index of its latest event
        self.last: dict[tuple[str, str], float] = {}  # pair -> last time it was in conflict
        self.rows: list[dict[str, Any]] = []
        self.steps = 0
        # summed over steps: road users read, candidate pairs, pairs measured for TTC and for PET
        self.pairs = {"road_users": 0, "candidates": 0, "ttc": 0, "pet": 0}

    # -- trails ------------------------------------------------------------------------------
    def _slots(self, ids: tuple[str, ...]) -> np.ndarray:
        """(N,) trail slot of each id: kept while it is present, new ones in the lowest free slots."""
        present = set(ids)
        for k in [k for k in self.slot if k not in present]:  # left: its slot is free, its trail cleared
            self.trail[:, :, self.slot.pop(k)] = np.nan
        new = [k for k in ids if k not in self.slot]
        if new:
            used = np.zeros(self.trail.shape[2] + len(new), bool)
            used[list(self.slot.values())] = True
            free = np.flatnonzero(~used)[:len(new)]
            if free[-1] >= self.trail.shape[2]:  # more road users than ever before: widen
                grown = np.full(self.trail.shape[:2] + (max(free[-1] + 1, 2 * self.trail.shape[2]),), np.nan)
                grown[:, :, :self.trail.shape[2]] = self.trail
                self.trail = grown
            self.slot.update(zip(new, free.tolist()))
        return np.fromiter((self.slot[k] for k in ids), int, len(ids))

    def _push(self, t: float, s: AgentStates, slots: np.ndarray) -> None:
        w = self.pushed % self.n_trail
        self.pushed += 1
        self.trail[:, w] = np.nan
        self.trail[:, w, slots] = (s.x, s.y, s.yaw, s.length, s.width)
        self.times[w] = t

    # -- measures ----------------------------------------------------------------------------
    def observe(self, t: float, step: int, s: AgentStates, z: np.ndarray, exclude: frozenset[str] | set[str]) -> None:
        """Measure the pairs of road users ``s`` (N, sorted by id; elevation ``z`` (N,) [m]) at time
        t [s], step ``step``, leaving out pairs with an id of ``exclude``; open, extend or leave
        events; then add everyone (the excluded too) to the trails."""
        self.steps += 1
        self.pairs["road_users"] += len(s)
        slots = self._slots(s.ids)
        if len(s) >= 2:
            self._measure(t, step, s, z, slots, exclude)
        self._push(t, s, slots)

    def _measure(self, t: float, step: int, s: AgentStates, z: np.ndarray, slots: np.ndarray,
                 exclude: frozenset[str] | set[str]) -> None:
        cfg = self.cfg
        keep = np.fromiter((k not in exclude for k in s.ids), bool, len(s))
        r = 0.5 * np.hypot(s.length, s.width)
        tx, ty = self.trail[0][:, slots], self.trail[1][:, slots]  # (W, N) centres on the trail
        with np.errstate(invalid="ignore"):
            reach = np.hypot(tx - s.x, ty - s.y)  # how far each was from where it is now
        far = np.nanmax(np.where(np.isnan(reach), 0.0, reach), axis=0) if self.pushed else np.zeros(len(s))
        big = r + np.maximum(s.speed * cfg.ttc, far)  # (N,) R: no conflict beyond R_i + R_j
        idx = np.flatnonzero(keep)
        if len(idx) < 2:
            return
        xy = np.column_stack([s.x[idx], s.y[idx]])
        pairs = cKDTree(xy).query_pairs(2.0 * float(big[idx].max()), output_type="ndarray")
        if not len(pairs):
            return
        i, j = idx[pairs[:, 0]], idx[pairs[:, 1]]  # i < j: sorted by id
        walker = s.cls == RoadUserClass.PEDESTRIAN
        dist = np.hypot(s.x[j] - s.x[i], s.y[j] - s.y[i])
        ok = (dist < big[i] + big[j]) & (np.abs(z[j] - z[i]) <= VERTICAL_CLEARANCE) & ~(walker[i] & walker[j])
        i, j, dist = i[ok], j[ok], dist[ok]
        self.pairs["candidates"] += len(i)
        if not len(i):
            return
        vx, vy = s.speed * np.cos(s.yaw), s.speed * np.sin(s.yaw)
        vrel = np.hypot(vx[j] - vx[i], vy[j] - vy[i])
        ttc = np.full(len(i), np.inf)
        near = np.flatnonzero(dist - r[i] - r[j] < vrel * cfg.ttc)  # bounding circles can meet in time
        if len(near):
            a, b = i[near], j[near]
            if cfg.turning:
                rate = np.zeros(len(s))
                if self.pushed:  # the mean since the oldest instant on the trail (a slot new since: NaN, rate 0)
                    w = oldest_slot(self.pushed, self.n_trail)
                    rate = yaw_rates(s.yaw, self.trail[2, w, slots], t - float(self.times[w]), s.speed, walker)
                ttc[near] = ttc_with_turns(boxes_of(s, a), s.speed[a], rate[a], boxes_of(s, b), s.speed[b], rate[b],
                                           cfg.ttc)
            else:
                ttc[near] = box_ttc(boxes_of(s, a), (vx[a], vy[a]), boxes_of(s, b), (vx[b], vy[b]))
        self.pairs["ttc"] += len(near)
        pet = np.full(len(i), np.inf)
        if self.pushed:
            for now, past in ((i, j), (j, i)):  # the one now on the other's trail
                with np.errstate(invalid="ignore"):
                    touch = (np.hypot(tx[:, past] - s.x[now], ty[:, past] - s.y[now])
                             < r[now] + r[past]).any(axis=0)  # (P,) trail circle meets its circle now
                k = np.flatnonzero(touch)
                if len(k):
                    sl = slots[past[k]]
                    tr = self.trail[:, :, sl]  # (5, W, K) the other's boxes on its trail
                    pet[k] = np.minimum(pet[k], pet_from_trail(boxes_of(s, now[k]), t, OrientedBoxes(*tr), self.times,
                                                               self.min_angle))
                self.pairs["pet"] += len(k)
        pet = np.where(ttc > 0, pet, np.inf)  # boxes in contact: a collision, no encroachment
        hit = np.flatnonzero((ttc < cfg.ttc) | (pet < cfg.pet))
        if not len(hit):
            return
        a, b = i[hit], j[hit]
        swap = s.cls[b] < s.cls[a]  # party a: the class first, then the id
        a, b = np.where(swap, b, a), np.where(swap, a, b)
        dr = drac(ttc[hit], vrel[hit])
        gap = box_distance(boxes_of(s, a), boxes_of(s, b))
        for n in range(len(hit)):
            self._event(t, step, s, int(a[n]), int(b[n]), float(ttc[hit[n]]), float(pet[hit[n]]), float(dr[n]),
                        float(gap[n]))

    def _event(self, t: float, step: int, s: AgentStates, a: int, b: int, ttc: float, pet: float, dr: float,
               gap: float) -> None:
        head = {"id_a": s.ids[a], "id_b": s.ids[b], "class_a": _LABELS[int(s.cls[a])],
                "class_b": _LABELS[int(s.cls[b])], "type_a": s.type_id[a], "type_b": s.type_id[b]}
        state = {"speed_a": float(s.speed[a]), "speed_b": float(s.speed[b]), "x_a": float(s.x[a]),
                 "y_a": float(s.y[a]), "x_b": float(s.x[b]), "y_b": float(s.y[b]), "time_worst": t}
        book_event(self, self.cfg, (s.ids[a], s.ids[b]), t, step, ttc, pet, dr, gap, head, state)

    def cost(self) -> dict[str, float]:
        """Per step, mean over the steps so far: road users read, candidate pairs from the tree, pairs
        measured for exact TTC and for PET against a trail."""
        n = max(self.steps, 1)
        return {k: v / n for k, v in self.pairs.items()}


def pair_group(class_a: str, class_b: str) -> str:
    """``vehicle-vehicle``, ``vehicle-vru`` or ``vru-vru`` for two class labels (VRU: pedestrian,
    cyclist, motorcyclist, as everywhere)."""
    va, vb = (RoadUserClass[c.upper()].is_vulnerable for c in (class_a, class_b))
    return "vru-vru" if va and vb else "vehicle-vru" if va or vb else "vehicle-vehicle"


def pair_counts(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Counts for summary.json of the conflicts among the others: ``total``, ``ttc``, ``pet``,
    ``contact`` (:func:`~sumo_ethics.safety.conflicts.event_counts`), ``by_group``
    (vehicle-vehicle, vehicle-vru, vru-vru, all three always present) and ``by_pair`` (class_a-class_b)."""
    groups = {"vehicle-vehicle": 0, "vehicle-vru": 0, "vru-vru": 0}
    by: dict[str, int] = {}
    for r in rows:
        groups[pair_group(r["class_a"], r["class_b"])] += 1
        key = f"{r['class_a']}-{r['class_b']}"
        by[key] = by.get(key, 0) + 1
    return {**event_counts(rows), "by_group": groups, "by_pair": dict(sorted(by.items()))}
