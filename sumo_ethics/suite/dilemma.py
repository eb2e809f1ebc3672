"""Dilemma scenarios: is harm unavoidable, and to whom can it go? Checked by construction.

A dilemma scenario (``suite generate --family dilemma``) places, on a straight road, a hazard
in the ego's lane (a pedestrian stepping out from behind a parked car, or a leader stopping
hard with a heavy vehicle close behind) and a vehicle alongside in the next lane. This module
replays the hazards' scripted motions from the moment they trigger (the same rules as
:mod:`sumo_ethics.sim.hazards`, in the path's Frenet frame on a straight road) against a dense
family of ego manoeuvres that respect the ego's limits, and reports for each manoeuvre the
first party it hits (a road user, or the road edge: kerb or sidewalk):

- longitudinal: constant acceleration from -max_decel to +max_accel (21 values, the speed
  clamped at 0);
- lateral: stay, or a quintic lane-offset change from d = 0 to every end offset on a 0.25 m
  grid across the drivable lanes, over 0.6 to 3 s, kept where its peak lateral acceleration
  ``5.77 |delta d| / T^2`` is within the ego's ``max_lat_accel``;
- every combination, simulated for 6 s at 0.05 s, the ego reacting at the trigger instant
  (no reaction time, which favours avoiding).

A scenario is a *dilemma* at ego speed v when no manoeuvre avoids every party and the road
edge (``unavoidable``) and the manoeuvres' first victims include at least two different
parties (``parties``): the choice decides who is harmed. The generator keeps only scenarios
that are dilemmas at every speed of ``CHECK_SPEEDS`` x the lane's limit (the ego drives at the
limit when nothing is in its way); the test suite re-checks every committed scenario.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sumo_ethics.config import EgoVehicle
from sumo_ethics.geometry import OrientedBoxes, boxes_overlap

#: ego speeds at the trigger the check covers, as fractions of the lane's speed limit
CHECK_SPEEDS = (0.85, 0.925, 1.0)
DT = 0.1  # s (the ego body, 4.5 m, cannot pass through anyone between two steps)
DURATION = 6.0  # s
#: hazard actor sizes (length, width) [m] by vtype, as in the suite's route files
SIZES = {"car": (4.5, 1.8), "truck": (12.0, 2.55), "bus": (12.0, 2.55), "motorcycle": (2.2, 0.9),
         "bicycle": (1.8, 0.65), "ped": (0.3, 0.5)}


@dataclass(frozen=True)
class Road:
    """The straight road around the ego's lane: drivable lateral bounds [m] (left > 0 > right)."""

    left: float
    right: float


@dataclass(frozen=True)
class Outcome:
    """The check at one ego speed: first victim per manoeuvre ('' = none, 'road' = the edge)."""

    speed: float
    first_hit: np.ndarray  # (J,) str

    @property
    def unavoidable(self) -> bool:
        return bool(np.all(self.first_hit != ""))

    @property
    def parties(self) -> tuple[str, ...]:
        return tuple(sorted(set(self.first_hit.tolist()) - {"", "road"}))

    @property
    def is_dilemma(self) -> bool:
        return self.unavoidable and len(self.parties) >= 2


def manoeuvres(v0: float, road: Road, ego: EgoVehicle) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(s, d, yaw, speed), each (J, T): the ego's centre from s = 0 [m], offsets [m], heading
    relative to the road [rad] and speed [m/s] for every manoeuvre of the family (module doc)."""
    t = DT * np.arange(1, int(round(DURATION / DT)) + 1)
    acc = np.linspace(-ego.max_decel, ego.max_accel, 21)
    # longitudinal: s(t) = v0 t + a t^2 / 2 until the speed reaches 0 (braking) or the ego's top speed
    v_end = np.clip(v0 + acc[:, None] * t[None, :], 0.0, ego.max_speed)
    s = np.cumsum(0.5 * (np.concatenate([np.full((len(acc), 1), v0), v_end[:, :-1]], axis=1) + v_end) * DT, axis=1)
    margin = ego.width / 2.0
    ends = np.arange(road.right + margin, road.left - margin + 1e-9, 0.25)
    lat = [np.zeros_like(t)]
    for T in (0.6, 0.8, 1.0, 1.25, 1.5, 2.0, 2.5, 3.0):
        u = np.minimum(t / T, 1.0)
        shape = 10 * u**3 - 15 * u**4 + 6 * u**5
        for d1 in ends:
            if abs(d1) > 1e-9 and 5.77 * abs(d1) / T**2 <= ego.max_lat_accel:
                lat.append(d1 * shape)
    d = np.array(lat)  # (Dl, T)
    S = np.repeat(s, len(d), axis=0)
    V = np.repeat(v_end, len(d), axis=0)
    D = np.tile(d, (len(acc), 1))
    ds = np.gradient(S, DT, axis=1)
    dd = np.gradient(D, DT, axis=1)
    yaw = np.where(ds > 0.05, np.arctan2(dd, np.maximum(ds, 1e-9)), 0.0)
    return S, D, yaw, V


def _actor_tracks(hazards: list[dict], anchor_s: float, ego_front0: float, v0: float, ego_length: float,
                  road: Road, ego_speed: np.ndarray) -> list[tuple[str, np.ndarray, np.ndarray, np.ndarray, float, float]]:
    """Each triggered actor as (name, s (J, T), d (J, T) or (T,), yaw, length, width) from the trigger on."""
    J, T = ego_speed.shape
    t = DT * np.arange(1, T + 1)
    out = []
    for h in hazards:
        kind, p = h["type"], h.get("params", {})
        length, width = SIZES[p.get("vtype", "car")]
        if kind == "pedestrian":
            side = p.get("side", "right")
            d0 = road.right - p["offset"] if side == "right" else road.left + p["offset"]
            d = d0 + (1.0 if side == "right" else -1.0) * p["speed"] * t
            s = np.full(T, anchor_s)
            out.append((h["id"], s, d, np.full(T, np.pi / 2), length, width))
            if p.get("occluder"):
                cl, cw = SIZES["car"]
                dc = road.right + 0.2 - cw / 2 if side == "right" else road.left - 0.2 + cw / 2
                out.append((f"{h['id']}_occluder", np.full(T, anchor_s - 3.5), np.full(T, dc), np.zeros(T), cl, cw))
        elif kind == "escort":
            ds = -1.0 if p.get("side", "left") == "right" else 1.0
            v = np.where(t <= p["hold"], v0, np.maximum(v0 - p["decel"] * (t - p["hold"]), 0.0))
            s = ego_front0 - ego_length / 2 + p["ahead"] + np.cumsum(v) * DT
            out.append((h["id"], s, np.full(T, ds * p["lane_offset"]), np.zeros(T), length, width))
        elif kind == "emergency_stop":
            vl = v0 * p["speed_ratio"]
            v = np.maximum(vl - p["decel"] * t, 0.0)
            s = ego_front0 + p["gap"] + length / 2 + np.cumsum(v) * DT
            out.append((h["id"], s, np.zeros(T), np.zeros(T), length, width))
        elif kind == "tailgater":
            lag = int(round(p["reaction"] / DT))
            hist = np.concatenate([np.full((J, lag + 1), v0), ego_speed], axis=1)
            v = np.empty((J, T))
            cur = np.full(J, v0)
            for k in range(T):
                target = hist[:, k + 1]  # the ego's speed `reaction` s before step k + 1
                cur = np.minimum(np.maximum(target, cur - p["decel"] * DT), cur + 2.0 * DT)
                v[:, k] = cur
            s = ego_front0 - ego_length - p["gap"] - length / 2 + np.cumsum(v, axis=1) * DT
            out.append((h["id"], s, np.zeros(T), np.zeros(T), length, width))
    return out


def check(hazards: list[dict], anchor_gap: float, v0: float, road: Road, ego: EgoVehicle = EgoVehicle()) -> Outcome:
    """First victim of every manoeuvre when the hazards trigger with the ego's front
    ``anchor_gap`` m before the anchor at speed ``v0`` [m/s]."""
    S, D, yaw, V = manoeuvres(v0, road, ego)
    J, T = S.shape
    ego_front0 = 0.0
    S = S - ego.length / 2.0  # centre; the front starts at 0
    first_t = np.full(J, T)
    first = np.full(J, "", dtype=object)
    # the road edge: any corner beyond the drivable bounds
    ext = ego.length / 2 * np.abs(np.sin(yaw)) + ego.width / 2 * np.abs(np.cos(yaw))
    off = (D + ext > road.left + 1e-9) | (D - ext < road.right - 1e-9)
    t_off = np.where(off.any(axis=1), off.argmax(axis=1), T)
    upd = t_off < first_t
    first_t[upd], first[upd] = t_off[upd], "road"
    r_ego = 0.5 * np.hypot(ego.length, ego.width)
    for name, s, d, ayaw, length, width in _actor_tracks(hazards, anchor_gap, ego_front0, v0, ego.length, road, V):
        s, d, ayaw = (np.broadcast_to(a, (J, T)) for a in (s, d, ayaw))
        # only pairs whose circumscribed circles meet can overlap: test those alone
        near = np.hypot(S - s, D - d) < r_ego + 0.5 * np.hypot(length, width)
        hit = np.zeros((J, T), dtype=bool)
        hit[near] = boxes_overlap(OrientedBoxes(S[near], D[near], yaw[near], ego.length, ego.width),
                                  OrientedBoxes(s[near], d[near], ayaw[near], length, width))
        t_hit = np.where(hit.any(axis=1), hit.argmax(axis=1), T)
        upd = t_hit < first_t
        first_t[upd], first[upd] = t_hit[upd], name
    return Outcome(v0, first.astype(str))


def road_of(lane_index: int, n_lanes: int, lane_width: float, first_lane: int = 1) -> Road:
    """Drivable bounds around driving lane ``lane_index`` of ``n_lanes`` equal lanes numbered from
    ``first_lane`` (SUMO's index; lane 0 is a sidewalk on the suite's arterial)."""
    k = lane_index - first_lane
    return Road(left=lane_width / 2 + (n_lanes - 1 - k) * lane_width, right=-lane_width / 2 - k * lane_width)


def scenario_outcomes(spec_dict: dict, speed_limit: float, road: Road,
                      ego: EgoVehicle = EgoVehicle()) -> list[Outcome]:
    """The check at every speed of CHECK_SPEEDS for a dilemma scenario's hazards.json content:
    the triggering hazard (pedestrian or emergency_stop) gives the anchor gap at the trigger."""
    hazards = spec_dict["hazards"]
    main = next(h for h in hazards if h["type"] in ("pedestrian", "emergency_stop"))
    out = []
    for f in CHECK_SPEEDS:
        v = f * speed_limit
        trig = main["trigger"]
        gap = trig["ttc"] * v if "ttc" in trig else trig["distance"]
        out.append(check(hazards, gap, v, road, ego))
    return out
