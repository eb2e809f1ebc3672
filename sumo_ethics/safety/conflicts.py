"""Conflict events between the ego and the road users around it, from what the simulation did.

:class:`ConflictBook` is called once per ego step with the snapshot after the step. For the ego
against every road user of the snapshot (those within the sensing radius: vehicles, cyclists,
pedestrians) it measures, with :mod:`sumo_ethics.safety.measures`:

* TTC: box time to collision at constant velocity and heading (exact); with ``turning``, where
  either party turns (its mean yaw rate over the trail, about ``pet`` s, above
  ``measures.TURNING``), at constant speed and yaw rate up to the TTC threshold
  (:func:`~sumo_ethics.safety.measures.ttc_with_turns`: two cars passing on a bend are no
  conflict, a car turning at a junction sweeps its arc on); DRAC from it;
* the box-to-box distance now;
* PET where the paths cross: the ego's box now against the other's boxes of the last
  ``pet`` seconds, and the other's box now against the ego's (each party's footprint trail);

A pair is *in conflict* at a step when TTC < ``ttc`` or PET < ``pet`` (:class:`ConflictConfig`).
Consecutive conflict steps of a pair, with pauses of at most ``gap`` seconds, form one event:
one ``conflicts.parquet`` row (:data:`sumo_ethics.record.schema.CONFLICTS`), kept up to date
in the sink while the event lasts. Only road users that could meet a threshold are measured
exactly (a bounding-circle test first), so a step with nobody close costs a few array ops.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from sumo_ethics.config import ConflictConfig
from sumo_ethics.geometry import OrientedBoxes, boxes_overlap
from sumo_ethics.safety.measures import box_distance, box_ttc, crossing, drac, pet_from_trail, ttc_with_turns, yaw_rates
from sumo_ethics.types import AgentStates, RoadUserClass

_LABELS = tuple(c.label for c in RoadUserClass)


def oldest_slot(pushed: int, n: int) -> int:
    """The slot of the oldest of the instants pushed so far into a ring buffer of ``n`` slots."""
    return pushed % n if pushed >= n else 0


def boxes_of(s: AgentStates, idx: np.ndarray | slice | int = slice(None)) -> OrientedBoxes:
    """The boxes of road users ``idx`` of ``s`` (all by default)."""
    return OrientedBoxes(s.x[idx], s.y[idx], s.yaw[idx], s.length[idx], s.width[idx])


class ConflictBook:
    """The conflicts of one run. :meth:`observe` once per ego step; rows go to ``sink``
    (``add_conflict(row) -> index``, ``update_conflict(index, **changes)``)."""

    def __init__(self, sink: Any, cfg: ConflictConfig, dt: float) -> None:
        self.sink = sink
        self.cfg = cfg
        self.min_angle = math.radians(cfg.crossing_angle)
        n = math.ceil(cfg.pet / dt - 1e-9) + 1  # trail instants W: PET up to the threshold
        # the trails are ring buffers of the last W instants (in no order; NaN rows: not yet filled):
        # the ego's (W, 6) time, x, y, yaw, length, width; the others' centres and half diagonals
        # (W, M) padded with NaN to the most road users seen at once, their times (W,) and states
        self.pushed = 0
        self.ego_trail = np.full((n, 6), np.nan)
        self.others_time = np.full(n, np.nan)
        self.others_xyr = np.full((3, n, 0), np.nan)
        self.others_states: list[AgentStates | None] = [None] * n
        self.open: dict[str, int] = {}  # other id -> index of its latest event
        self.last: dict[str, float] = {}  # other id -> last time its pair was in conflict
        self.rows: list[dict[str, Any]] = []  # this book's rows (also in the sink)

    # -- measures ----------------------------------------------------------------------------
    def _pet_into_ego_trail(self, t: float, o: AgentStates, idx: np.ndarray) -> np.ndarray:
        """(len(idx),) PET [s] of others ``idx`` now entering where the ego was (inf where none)."""
        tr = self.ego_trail
        trail = OrientedBoxes(tr[:, 1:2], tr[:, 2:3], tr[:, 3:4], tr[:, 4:5], tr[:, 5:6])
        return pet_from_trail(boxes_of(o, idx), t, trail, tr[:, 0], self.min_angle)

    def _pet_into_others_trail(self, t: float, e: AgentStates) -> dict[str, float]:
        """PET [s] of the ego now entering where other road users were: id -> PET, for those whose
        trail box of the last ``pet`` seconds overlaps the ego's box now at a crossing angle."""
        x, y, r = self.others_xyr
        if not x.size:
            return {}
        with np.errstate(invalid="ignore"):
            near = np.hypot(x - e.x[0], y - e.y[0]) < r + 0.5 * math.hypot(float(e.length[0]), float(e.width[0]))
        out: dict[str, float] = {}
        if not near.any():
            return out
        eb = boxes_of(e, 0)
        for w, i in zip(*np.nonzero(near)):  # few: those whose bounding circles touch the ego's
            s, tw = self.others_states[w], float(self.others_time[w])
            if t - tw < out.get(s.ids[i], np.inf) and bool(boxes_overlap(eb, boxes_of(s, i))) \
                    and bool(crossing(e.yaw[0], s.yaw[i], self.min_angle)):
                out[s.ids[i]] = t - tw
        return out

    def _push(self, t: float, e: AgentStates, o: AgentStates) -> None:
        """Add this instant to the trails (overwriting the oldest)."""
        w = self.pushed % len(self.others_time)
        self.pushed += 1
        self.ego_trail[w] = (t, e.x[0], e.y[0], e.yaw[0], e.length[0], e.width[0])
        n = len(o)
        if n > self.others_xyr.shape[2]:  # more road users than ever before: widen
            grown = np.full(self.others_xyr.shape[:2] + (max(n, 2 * self.others_xyr.shape[2]),), np.nan)
            grown[:, :, :self.others_xyr.shape[2]] = self.others_xyr
            self.others_xyr = grown
        row = self.others_xyr[:, w]
        row[:, n:] = np.nan
        row[0, :n], row[1, :n], row[2, :n] = o.x, o.y, 0.5 * np.hypot(o.length, o.width)
        self.others_time[w] = t
        self.others_states[w] = o

    def _yaw_rates(self, t: float, e: AgentStates, o: AgentStates, idx: np.ndarray) -> tuple[float, np.ndarray]:
        """The ego's yaw rate and those of road users ``idx`` of ``o`` [rad/s]: their mean since the
        oldest instant on the trails (about ``pet`` seconds ago: a lane's polyline turns in steps, so
        the heading change of one step is no turn rate); 0 for the first instant and for a road user
        not there then."""
        if not self.pushed:
            return 0.0, np.zeros(len(idx))
        w = oldest_slot(self.pushed, len(self.others_time))
        dt = t - float(self.ego_trail[w, 0])
        rate_e = float(yaw_rates(e.yaw[0], self.ego_trail[w, 3], dt, e.speed[0], False))
        before = self.others_states[w]
        yaw_before = np.full(len(idx), np.nan)
        if before is not None and len(before):
            where = {k: n for n, k in enumerate(before.ids)}
            for j, i in enumerate(idx):
                n = where.get(o.ids[i])
                if n is not None:
                    yaw_before[j] = before.yaw[n]
        return rate_e, yaw_rates(o.yaw[idx], yaw_before, dt, o.speed[idx], o.cls[idx] == RoadUserClass.PEDESTRIAN)

    def observe(self, snap: Any, step: int) -> None:
        """Measure the pairs of snapshot ``snap`` (``time``, ``ego``, ``others``) at ego step ``step``;
        open, extend or leave events; then add the snapshot to the trails."""
        cfg = self.cfg
        t, e, o = float(snap.time), snap.ego, snap.others
        evx, evy = float(e.speed[0] * np.cos(e.yaw[0])), float(e.speed[0] * np.sin(e.yaw[0]))
        tr = self.ego_trail
        if len(o):
            ovx, ovy = o.speed * np.cos(o.yaw), o.speed * np.sin(o.yaw)
            dist = np.hypot(o.x - e.x[0], o.y - e.y[0])
            radii = 0.5 * np.hypot(e.length[0], e.width[0]) + 0.5 * np.hypot(o.length, o.width)
            vrel = np.hypot(ovx - evx, ovy - evy)
            near = dist - radii < vrel * cfg.ttc  # TTC below the threshold is possible
            near_trail = np.zeros(len(o), bool)
            if self.pushed:  # within reach of the ego's footprint of the last `pet` seconds
                with np.errstate(invalid="ignore"):
                    near_trail = (np.hypot(o.x - tr[:, 1:2], o.y - tr[:, 2:3]) < radii).any(axis=0)
            near_pet = self._pet_into_others_trail(t, e)
            if near_pet:
                near |= np.fromiter((k in near_pet for k in o.ids), bool, len(o))
            idx = np.flatnonzero(near | near_trail)
        else:  # nobody in range now: nobody to measure (PET counts for road users still in range)
            near_pet, idx = {}, np.empty(0, int)
        if len(idx):
            ob, eb = boxes_of(o, idx), boxes_of(e, 0)  # only the few that could meet a threshold
            if cfg.turning:
                rate_e, rate_o = self._yaw_rates(t, e, o, idx)
                ttc = ttc_with_turns(eb, e.speed[0], rate_e, ob, o.speed[idx], rate_o, cfg.ttc)
            else:
                ttc = box_ttc(eb, (evx, evy), ob, (ovx[idx], ovy[idx]))
            pet = np.full(len(idx), np.inf)
            on_trail = near_trail[idx]
            if on_trail.any():  # PET into the ego's footprint: only those that can reach it
                pet[on_trail] = self._pet_into_ego_trail(t, o, idx[on_trail])
            if near_pet:
                pet = np.minimum(pet, np.array([near_pet.get(o.ids[i], np.inf) for i in idx]))
            pet = np.where(ttc > 0, pet, np.inf)  # boxes in contact: a collision, no encroachment
            hit = np.flatnonzero((ttc < cfg.ttc) | (pet < cfg.pet))
            if len(hit):
                dr = drac(ttc[hit], vrel[idx[hit]])
                gap = box_distance(eb, boxes_of(o, idx[hit]))
                for j, k in enumerate(hit):
                    self._event(t, step, e, o, int(idx[k]), float(ttc[k]), float(pet[k]), float(dr[j]), float(gap[j]))
        self._push(t, e, o)

    # -- events ------------------------------------------------------------------------------
    def _event(self, t: float, step: int, e: AgentStates, o: AgentStates, i: int, ttc: float, pet: float,
               dr: float, gap: float) -> None:
        oid = o.ids[i]
        state = {"speed_a": float(e.speed[0]), "speed_b": float(o.speed[i]), "x_a": float(e.x[0]),
                 "y_a": float(e.y[0]), "x_b": float(o.x[i]), "y_b": float(o.y[i]), "time_worst": t}
        head = {"id_a": e.ids[0], "id_b": oid, "class_a": _LABELS[int(e.cls[0])], "class_b": _LABELS[int(o.cls[i])],
                "type_b": o.type_id[i]}
        book_event(self, self.cfg, oid, t, step, ttc, pet, dr, gap, head, state)

    def counts(self) -> dict[str, Any]:
        """Conflict counts for summary.json: total, by measure and by the other party's class."""
        return conflict_counts(self.rows)


def book_event(book: Any, cfg: ConflictConfig, key: Any, t: float, step: int, ttc: float, pet: float, dr: float,
               gap: float, head: dict[str, Any], state: dict[str, Any]) -> None:
    """One step in conflict of the pair ``key`` at time t [s]: opens an event (a new row: ``head``, the
    parties' ids, classes and types, and the measures) or extends the pair's open one, keeping its
    minima and maxima and the ``state`` (speeds, positions, time) of its worst step. ``book`` holds
    ``open`` (key -> row index), ``last`` (key -> last time in conflict), ``rows`` and ``sink``."""
    finite_ttc = math.isfinite(ttc)
    last = book.last.get(key)
    book.last[key] = t
    if last is None or t - last > cfg.gap + 1e-9:
        row = {"event": len(book.rows), **head,
               "start": t, "end": t, "step_start": step, "n_steps": 1,
               "min_ttc": ttc if finite_ttc else math.nan, "min_pet": pet if math.isfinite(pet) else math.nan,
               "max_drac": dr if finite_ttc and ttc > 0 else 0.0, "min_distance": gap,
               "ttc_below": ttc < cfg.ttc, "pet_below": pet < cfg.pet, "contact": ttc == 0.0} | state
        book.rows.append(row)
        book.open[key] = len(book.rows) - 1
        book.sink.add_conflict(dict(row))
        return
    row = book.rows[book.open[key]]
    ch: dict[str, Any] = {"end": t, "n_steps": row["n_steps"] + 1, "min_distance": min(row["min_distance"], gap)}
    if ttc < cfg.ttc:
        ch["ttc_below"] = True
    if pet < cfg.pet:
        ch["pet_below"] = True
    if ttc == 0.0:
        ch["contact"] = True
    if finite_ttc and ttc > 0:
        ch["max_drac"] = max(row["max_drac"], dr)
    worse = False
    if finite_ttc and not ttc >= row["min_ttc"]:  # also when min_ttc is NaN
        ch["min_ttc"], worse = ttc, True
    if math.isfinite(pet) and not pet >= row["min_pet"]:
        ch["min_pet"] = pet
        worse = worse or math.isnan(row["min_ttc"]) and not finite_ttc
    if worse:
        ch.update(state)
    row.update(ch)
    book.sink.update_conflict(book.open[key], **ch)  # the sink's rows: the same order as ours


def conflict_counts(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """``total``, ``ttc`` and ``pet`` (events whose TTC / PET fell below its threshold), ``contact``
    (events whose boxes touched), ``vru`` and ``by_class`` (of the other party) for conflict rows."""
    by: dict[str, int] = {}
    for r in rows:
        by[r["class_b"]] = by.get(r["class_b"], 0) + 1
    return {**event_counts(rows), "vru": sum(RoadUserClass[r["class_b"].upper()].is_vulnerable for r in rows),
            "by_class": dict(sorted(by.items()))}


def event_counts(rows: list[dict[str, Any]]) -> dict[str, int]:
    """``total``, ``ttc`` and ``pet`` (events whose TTC / PET fell below its threshold) and
    ``contact`` (events whose boxes touched) of conflict rows."""
    return {"total": len(rows), "ttc": sum(bool(r["ttc_below"]) for r in rows),
            "pet": sum(bool(r["pet_below"]) for r in rows), "contact": sum(bool(r["contact"]) for r in rows)}


