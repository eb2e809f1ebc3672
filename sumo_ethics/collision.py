"""Collisions: detection that does not miss, one event per collision, the harm to each party.

SUMO misses many collisions (pedestrians on shared lanes, sideswipes, an ego off its lane)
and checking only at step instants misses fast crossings (SUMO.md). Between two steps every
nearby road user and the ego are interpolated over sub-steps spaced at most ``spacing``
metres of relative motion apart, and their boxes tested for overlap at each sub-step
(:func:`swept_contacts`). :class:`CollisionBook` merges those contacts with SUMO's own reports
(carried by the snapshot), turns them into events (:class:`PairEvents`) and books each event's
harm per class (:func:`collision_row`); the runner calls :meth:`CollisionBook.detect` once per step.
No simulator handles here: SUMO's side arrives in :class:`~sumo_ethics.sim.world.Snapshot`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from sumo_ethics.ethics.harm import CrashOutcome, ImpactArea, Party, crash_outcome
from sumo_ethics.geometry import OrientedBoxes, boxes_overlap, wrap_angle
from sumo_ethics.safety.fault import FAULTS, FaultContext, fault
from sumo_ethics.types import AgentStates, RoadUserClass

#: at most this much relative motion [m] between two tested sub-steps
SUBSTEP_SPACING = 0.2
MAX_SUBSTEPS = 64


def previous_of(now: AgentStates, before: AgentStates) -> np.ndarray:
    """(N, 3) x, y, yaw of each agent of ``now`` at the earlier snapshot; its current pose
    where it was not seen before."""
    pose = np.stack([now.x, now.y, now.yaw], axis=-1)
    if len(before) and len(now):
        where = before.index
        j = np.array([where.get(k, -1) for k in now.ids])
        seen = j >= 0
        pose[seen] = np.stack([before.x[j[seen]], before.y[j[seen]], before.yaw[j[seen]]], axis=-1)
    return pose


def swept_contacts(ego_before: AgentStates, ego_now: AgentStates, others_now: AgentStates,
                   others_before_pose: np.ndarray) -> np.ndarray:
    """Which neighbours the ego's box touched at any time between two snapshots.

    ego_before, ego_now: the ego (1 agent) at t and t + dt; others_now: N agents at t + dt;
    others_before_pose: (N, 3) their x, y, yaw at t. Returns (N,) bool.
    Poses are interpolated linearly (yaw along the shorter arc).
    """
    n = len(others_now)
    hit = np.zeros(n, dtype=bool)
    if n == 0:
        return hit
    o0 = others_before_pose
    # cheap conservative filter: bounding circles over the whole motion (1-D arrays: this runs
    # every step, the exact test below only when something is close)
    r_ego = 0.5 * np.hypot(ego_now.length[0], ego_now.width[0])
    r_oth = 0.5 * np.hypot(others_now.length, others_now.width)
    rx0, ry0 = o0[:, 0] - ego_before.x[0], o0[:, 1] - ego_before.y[0]  # relative to the ego, before
    rx1, ry1 = others_now.x - ego_now.x[0], others_now.y - ego_now.y[0]  # and now
    d_min = np.minimum(np.hypot(rx0, ry0), np.hypot(rx1, ry1))
    reach = r_ego + r_oth + np.hypot(rx1 - rx0, ry1 - ry0)
    near = d_min <= reach
    if not near.any():
        return hit
    idx = np.flatnonzero(near)
    motion = float(np.max(np.hypot(rx1[idx] - rx0[idx], ry1[idx] - ry0[idx])))
    n_sub = min(max(int(np.ceil(motion / SUBSTEP_SPACING)), 1), MAX_SUBSTEPS)
    e0 = np.array([ego_before.x[0], ego_before.y[0], ego_before.yaw[0]])
    e1 = np.array([ego_now.x[0], ego_now.y[0], ego_now.yaw[0]])
    o1 = np.stack([others_now.x, others_now.y, others_now.yaw], axis=-1)
    f = np.linspace(0.0, 1.0, n_sub + 1)[:, None]  # (S, 1), includes both end points

    def lerp(p0: np.ndarray, p1: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return (p0[..., 0] + f * (p1[..., 0] - p0[..., 0]),
                p0[..., 1] + f * (p1[..., 1] - p0[..., 1]),
                p0[..., 2] + f * wrap_angle(p1[..., 2] - p0[..., 2]))

    ex, ey, eyaw = lerp(e0[None], e1[None])  # (S, 1)
    ox, oy, oyaw = lerp(o0[idx], o1[idx])  # (S, n)
    overlap = boxes_overlap(
        OrientedBoxes(ex, ey, eyaw, ego_now.length[0], ego_now.width[0]),
        OrientedBoxes(ox, oy, oyaw, others_now.length[idx], others_now.width[idx]),
    )
    hit[idx] = overlap.any(axis=0)
    return hit


@dataclass
class PairEvents:
    """Turns contacts reported every step into one event per collision of a pair.

    A pair in contact again within ``gap`` seconds of its last contact continues the same
    event; roles (collider/victim) do not matter.
    """

    gap: float
    _last_seen: dict[frozenset[str], float] = field(default_factory=dict)
    _event_of: dict[frozenset[str], int] = field(default_factory=dict)

    def observe(self, time: float, a: str, b: str) -> tuple[bool, int | None]:
        """Record a contact; returns (is_new_event, index of the pair's current event or None)."""
        pair = frozenset((a, b))
        last = self._last_seen.get(pair)
        self._last_seen[pair] = time
        if last is not None and time - last <= self.gap + 1e-9:
            return False, self._event_of.get(pair)
        return True, None

    def bind(self, a: str, b: str, event_index: int) -> None:
        self._event_of[frozenset((a, b))] = event_index


# ---- harm of a collision --------------------------------------------------------------------
def _party(s: AgentStates, i: int) -> Party:
    return Party(x=s.x[i], y=s.y[i], yaw=s.yaw[i], speed=s.speed[i], mass=s.mass[i], cls=s.cls[i])


def collision_row(event: int, t: float, step: int, a: AgentStates, b: AgentStates, involves_ego: bool,
                  detector: str, sumo_type: str, ctx: FaultContext | None = None) -> dict[str, Any]:
    """One collisions.parquet row for parties a and b (1 agent each, states before impact); the
    fault from :func:`sumo_ethics.safety.fault.fault` with ``ctx`` (ego collisions only)."""
    out: CrashOutcome = crash_outcome(_party(a, 0), _party(b, 0))
    harm_a, harm_b = float(out.harm_a), float(out.harm_b)
    area_a, area_b = ImpactArea(int(out.area_a)).name.lower(), ImpactArea(int(out.area_b)).name.lower()
    who, why = fault(float(a.speed[0]), area_a, b.ids[0], int(b.cls[0]), float(b.speed[0]), area_b, ctx) \
        if involves_ego else ("unknown", "the ego was not involved")
    return {
        "event": event, "time": t, "step": step, "involves_ego": involves_ego, "detector": detector,
        "sumo_type": sumo_type, "id_a": a.ids[0], "id_b": b.ids[0],
        "class_a": RoadUserClass(int(a.cls[0])).label, "class_b": RoadUserClass(int(b.cls[0])).label,
        "type_a": a.type_id[0], "type_b": b.type_id[0],
        "x_a": float(a.x[0]), "y_a": float(a.y[0]), "x_b": float(b.x[0]), "y_b": float(b.y[0]),
        "speed_a": float(a.speed[0]), "speed_b": float(b.speed[0]),
        "yaw_a": float(a.yaw[0]), "yaw_b": float(b.yaw[0]),
        "mass_a": float(a.mass[0]), "mass_b": float(b.mass[0]),
        "delta_v": float(out.delta_v), "dv_a": float(out.dv_a), "dv_b": float(out.dv_b),
        "area_a": area_a, "area_b": area_b,
        "harm_a": harm_a, "harm_b": harm_b,
    } | booking({"harm_a": harm_a, "harm_b": harm_b, "class_b": RoadUserClass(int(b.cls[0])).label},
                is_booked({"involves_ego": involves_ego, "detector": detector})) | {"fault": who, "fault_reason": why}


def booking(row: dict[str, Any], book: bool) -> dict[str, float]:
    """Harm booked per class for a row: to the ego, the third party and (its share) to VRUs."""
    vru = RoadUserClass[row["class_b"].upper()].is_vulnerable
    return {"harm_ego": row["harm_a"] if book else 0.0, "harm_third_party": row["harm_b"] if book else 0.0,
            "harm_vru": row["harm_b"] if book and vru else 0.0}


def is_booked(row: dict[str, Any]) -> bool:
    """An ego collision that counts: not a SUMO report our boxes did not confirm."""
    return row["involves_ego"] and row["detector"] != "sumo_unconfirmed"


def booked_outcome(rows: list[dict[str, Any]]) -> tuple[list[dict[str, Any]], dict[str, float], dict[str, int]]:
    """Of a run's collision rows: the ego collisions that count (:func:`is_booked`), their harm per
    class (``ego``, ``third_party``, ``vru``, ``total`` = ego + third party) and their count per fault
    (summary.json's ``harm`` and ``collisions.fault``)."""
    booked = [r for r in rows if is_booked(r)]
    harm = {k: float(sum(r.get(f"harm_{k}") or 0.0 for r in booked)) for k in ("ego", "third_party", "vru")}
    harm["total"] = harm["ego"] + harm["third_party"]
    return booked, harm, {f: sum(r.get("fault") == f for r in booked) for f in FAULTS}


def merged_detector(old: str, new: str) -> str:
    """Detector label of an event seen first as ``old`` and again as ``new`` (a confirmed label)."""
    seen: set[str] = set()
    for d in (old, new):
        seen |= {"geometry", "sumo"} if d == "both" else {d.removesuffix("_unconfirmed")}
    return "both" if len(seen) == 2 else seen.pop()


#: SUMO-only ego reports count when the true boxes come at least this close [m]. SUMO without
#: the sublane model reports two cars on one lane as colliding even when they pass side by side
#: (a car parked at the kerb): the swept box check is exact, so the tolerance is small.
CONFIRM_TOLERANCE = 0.1


def near_contact(a: AgentStates, b: AgentStates, tol: float = CONFIRM_TOLERANCE) -> np.ndarray:
    """(n,) bool: the boxes of a and b, each grown by ``tol`` on every side, overlap."""
    return boxes_overlap(OrientedBoxes(a.x, a.y, a.yaw, a.length + 2 * tol, a.width + 2 * tol),
                         OrientedBoxes(b.x, b.y, b.yaw, b.length + 2 * tol, b.width + 2 * tol))


def _with_speed(s: AgentStates, speed: float) -> AgentStates:
    return AgentStates(s.ids, s.x, s.y, s.yaw, np.array([speed]), s.accel, s.length, s.width, s.mass, s.cls,
                       s.type_id)




#: a SUMO collision report: (collider, victim, colliderType, victimType, colliderSpeed, victimSpeed, type, lane)
SumoReport = tuple[str, str, str, str, float, float, str, str]


class CollisionBook:
    """The collisions of one run. :meth:`detect` once per step; its rows go to ``sink`` (the run's
    :class:`~sumo_ethics.record.recorder.RunRecorder`: ``collisions``, ``add_collision``,
    ``update_collision``). ``lookup(id)`` gives the state of a party outside the ego's range."""

    def __init__(self, sink: Any, gap: float, lookup: Callable[[str], AgentStates | None]) -> None:
        self.sink = sink
        self.events = PairEvents(gap)
        self.lookup = lookup

    def _book(self, row: dict[str, Any], a: str, b: str) -> None:
        self.events.bind(a, b, self.sink.add_collision(row))

    def _party_before(self, other: str, before: Any, now: Any) -> AgentStates | None:
        """The state of ``other`` just before impact (at ``before``, else now, else looked up)."""
        if other in before.others.index:
            return before.others.take([before.others.index[other]])
        if other in now.others.index:
            return now.others.take([now.others.index[other]])
        return self.lookup(other)

    def first_booked(self) -> dict[str, Any] | None:
        """The first ego collision that counts (see :func:`is_booked`), or None."""
        return next((r for r in self.sink.collisions if is_booked(r)), None)

    def detect(self, before: Any, now: Any, step: int, ctx: FaultContext | None = None) -> bool:
        """Log the collisions between snapshots ``before`` and ``now`` (ego step ``step``), the
        ego's from the swept boxes and SUMO's reports, the others' from SUMO's reports (the
        harm from the parties' states just before impact, the fault with ``ctx``). True if the
        ego had a new one."""
        ego_new = self.detect_ego(before, now, step, ctx)
        self.detect_others(now.time, now.collisions, step, frozenset(now.ego.ids))
        return ego_new

    def detect_ego(self, before: Any, now: Any, step: int, ctx: FaultContext | None = None) -> bool:
        """The ego's collisions of :meth:`detect` (a fleet calls this per ego: a pair of egos is
        one event, booked by the first); True if the ego had a new one."""
        rows = self.sink.collisions
        ego_id = now.ego.ids[0]
        t = now.time
        hits = swept_contacts(before.ego, now.ego, now.others, previous_of(now.others, before.others))
        geo = {now.others.ids[i] for i in np.flatnonzero(hits)}
        reports = _by_pair(now.collisions)
        ego_new = False
        now_index = now.others.index
        sumo_ego = {next(iter(p - {ego_id})) for p in reports if ego_id in p and len(p) == 2}
        for other in sorted(geo | sumo_ego):
            report = reports.get(frozenset((ego_id, other)))
            if other in geo:
                detector = "both" if other in sumo_ego else "geometry"
            else:  # SUMO alone: its junction check uses lane shapes, wrong for an ego moved off its lane
                confirmed = other not in now_index or bool(near_contact(now.ego, now.others.take([now_index[other]])))
                detector = "sumo" if confirmed else "sumo_unconfirmed"
            is_new, idx = self.events.observe(t, ego_id, other)
            row = rows[idx] if not is_new and idx is not None else None
            if not is_new and row is not None and is_booked(row):
                if row["detector"] != detector and detector != "sumo_unconfirmed":
                    self.sink.update_collision(idx, detector=merged_detector(row["detector"], detector))
                    if report and not row["sumo_type"]:
                        self.sink.update_collision(idx, sumo_type=report[6])
                continue
            if not is_new and (row is None or detector == "sumo_unconfirmed"):
                continue
            b = self._party_before(other, before, now)
            if b is None:
                continue
            new = collision_row(len(rows) if row is None or idx is None else idx, t, step, before.ego, b, True, detector,
                                report[6] if report else "", ctx)
            if row is None:
                self._book(new, ego_id, other)
            else:  # SUMO reported the pair earlier, unconfirmed by the boxes: the impact is now
                new.update(event=row["event"], detector=merged_detector(row["detector"], detector),
                           sumo_type=row["sumo_type"] or new["sumo_type"])
                self.sink.update_collision(idx, **new)
            ego_new = ego_new or detector != "sumo_unconfirmed"
        return ego_new

    def detect_others(self, t: float, collisions: tuple, step: int, egos: frozenset[str]) -> None:
        """Book SUMO's reports at time ``t`` [s] of collisions between road users none of which is
        in ``egos``."""
        rows = self.sink.collisions
        for pair, c in sorted(_by_pair(collisions).items(), key=lambda kv: sorted(kv[0])):
            if pair & egos or len(pair) != 2:
                continue
            is_new, _ = self.events.observe(t, c[0], c[1])
            if not is_new:
                continue
            a, b = self.lookup(c[0]), self.lookup(c[1])
            if a is None or b is None:
                continue
            a, b = _with_speed(a, c[4]), _with_speed(b, c[5])
            self._book(collision_row(len(rows), t, step, a, b, False, "sumo", c[6]), c[0], c[1])


def _by_pair(collisions: tuple) -> dict[frozenset[str], SumoReport]:
    """SUMO's reports of a step by the pair of parties (the first report of a pair)."""
    reports: dict[frozenset[str], SumoReport] = {}
    for c in collisions:
        reports.setdefault(frozenset((c[0], c[1])), c)
    return reports
