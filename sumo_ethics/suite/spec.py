"""The hazard file of a suite scenario (``hazards.json``), loaded and validated.

Everything a hazard does is relative to the ego: positions are Frenet coordinates (s along,
d to the left) on the ego's reference path, and a hazard's *trigger* fires when the ego is
a given distance or time away from the hazard's anchor point or actor.

Format (JSON)::

    {"version": 1, "name": "s0001", "network": "junction_tls", "road_type": "...",
     "seed": 17,
     "ego": {"from": "W_in", "to": "E_out", "depart": 30.0, "end": 75.0},
     "hazards": [
        {"id": "h0", "type": "pedestrian", "anchor": {"edge": "E_out", "pos": 6.0},
         "trigger": {"ttc": 1.6}, "params": {"side": "right", "speed": 1.8}}]}

anchor: ``{"edge": E, "pos": P}`` (P metres along edge E), ``{"junction": J}`` or
``{"xy": [x, y]}``; it is projected onto the ego's path at run time.
trigger: exactly one of ``distance`` (ego front within D m of the anchor), ``ttc`` (ego
front reaches the anchor within T s at its current speed), ``gap`` (ego front within G m
of the hazard actor, along the path) or ``gap_ttc`` (that gap closed within T s at the
current closing speed). ``spawn`` (optional, metres): the actor appears when the ego
front is this far before the anchor (default: at the trigger).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sumo_ethics.errors import ConfigError, is_number

HAZARD_FILE = "hazards.json"

#: hazard type -> (allowed params with defaults). Units: m, s, m/s, m/s^2.
HAZARD_TYPES: dict[str, dict[str, Any]] = {
    # a pedestrian at the kerb (or behind a parked car) runs across the ego's path
    "pedestrian": {"side": "right", "offset": 0.6, "speed": 1.8, "occluder": False, "vtype": "ped"},
    # a vehicle ahead in the ego's lane brakes to a stop, waits, drives off again
    "emergency_stop": {"gap": 14.0, "speed_ratio": 1.0, "decel": 9.0, "hold": 3.0, "vtype": "car"},
    # a vehicle crosses the ego's path at the anchor (a junction), ignoring lights/priority
    "red_light_runner": {"side": "left", "speed": 12.0, "lead": 0.0, "vtype": "car"},
    # an oncoming vehicle in the opposite lane drifts towards/into the ego's lane
    "oncoming_drift": {"lane_offset": 3.5, "drift": 2.5, "duration": 1.5, "hold": 2.0, "speed": 18.0,
                       "vtype": "car"},
    # a vehicle in the adjacent lane changes into the ego's lane close ahead
    "cut_in": {"side": "left", "lane_offset": 3.5, "gap": 10.0, "speed_ratio": 0.75, "duration": 1.5,
               "vtype": "car"},
    # a cyclist riding ahead at the right edge of the ego's lane swerves to the left; it appears
    # where, at both current speeds, the ego would come up to it at the anchor
    # (over ``duration``), rides there for ``hold`` s and swerves back to its line
    "cyclist_swerve": {"offset": -1.0, "swerve": 2.0, "duration": 1.0, "hold": 1.5, "speed": 5.0,
                       "vtype": "bicycle"},
    # a parked vehicle at the kerb (a static obstacle, no trigger)
    "parked": {"side": "right", "intrusion": 0.3, "vtype": "car"},
    # a vehicle in the next lane riding alongside the ego: it appears ``ahead`` metres (centre to
    # centre, along the path) in front of the ego at the ego's speed, keeps that place until the
    # trigger, then holds its speed (its driver has not seen the hazard) for ``hold`` s, then
    # brakes at ``decel`` to a stop; it blocks the ego's escape to that side
    "escort": {"side": "left", "lane_offset": 3.25, "ahead": 0.0, "hold": 1.5, "decel": 4.0, "vtype": "car"},
    # a heavy vehicle close behind the ego: it appears ``gap`` metres (bumper to bumper) behind
    # the ego at its speed and follows it with a reaction time: its speed is the ego's speed
    # ``reaction`` s earlier, reached at no more than ``decel`` (braking) or 2 m/s^2
    "tailgater": {"gap": 6.0, "reaction": 1.0, "decel": 5.0, "vtype": "truck"},
}
#: numeric parameters that must be > 0 (divided by) and >= 0 (durations, distances, speeds)
POSITIVE = {"duration", "decel", "speed"}
NON_NEGATIVE = {"hold", "gap", "swerve", "drift", "lane_offset", "speed_ratio", "reaction"}
TRIGGERS = ("distance", "ttc", "gap", "gap_ttc")
VTYPES = ("car", "truck", "bus", "motorcycle", "bicycle", "ped")


def _num(where: str, value: Any, lo: float = -math.inf, hi: float = math.inf) -> float:
    if not is_number(value):
        raise ConfigError(f"{where} must be a number, got {value!r}")
    if not lo <= value <= hi:
        raise ConfigError(f"{where} must be in [{lo:g}, {hi:g}], got {value!r}")
    return float(value)


def _keys(where: str, d: Any, allowed: set[str] | frozenset[str],
          required: set[str] | frozenset[str] = frozenset()) -> dict[str, Any]:
    if not isinstance(d, dict):
        raise ConfigError(f"{where} must be an object, got {type(d).__name__}")
    unknown = set(d) - allowed
    if unknown:
        raise ConfigError(f"unknown key(s) in {where}: {', '.join(sorted(unknown))}; known: {', '.join(sorted(allowed))}")
    missing = set(required) - set(d)
    if missing:
        raise ConfigError(f"{where} lacks {', '.join(sorted(missing))}")
    return d


@dataclass(frozen=True)
class Anchor:
    edge: str | None = None
    pos: float = 0.0
    junction: str | None = None
    xy: tuple[float, float] | None = None

    @classmethod
    def parse(cls, where: str, d: Any) -> "Anchor":
        d = _keys(where, d, {"edge", "pos", "junction", "xy"})
        kinds = [k for k in ("edge", "junction", "xy") if k in d]
        if len(kinds) != 1:
            raise ConfigError(f"{where} needs exactly one of edge (+pos), junction, xy; got {kinds or 'none'}")
        if "edge" in d:
            if not isinstance(d["edge"], str):
                raise ConfigError(f"{where}.edge must be a string")
            return cls(edge=d["edge"], pos=_num(f"{where}.pos", d.get("pos", 0.0), 0.0))
        if "junction" in d:
            if not isinstance(d["junction"], str):
                raise ConfigError(f"{where}.junction must be a string")
            return cls(junction=d["junction"])
        xy = d["xy"]
        if not isinstance(xy, list) or len(xy) != 2:
            raise ConfigError(f"{where}.xy must be [x, y]")
        return cls(xy=(_num(f"{where}.xy[0]", xy[0]), _num(f"{where}.xy[1]", xy[1])))

    def to_dict(self) -> dict[str, Any]:
        if self.edge is not None:
            return {"edge": self.edge, "pos": self.pos}
        if self.junction is not None:
            return {"junction": self.junction}
        if self.xy is None:  # parse requires one of edge, junction and xy
            raise ValueError("an anchor needs an edge, a junction or xy")
        return {"xy": list(self.xy)}


@dataclass(frozen=True)
class HazardSpec:
    id: str
    type: str
    anchor: Anchor
    trigger_kind: str | None
    trigger_value: float
    spawn: float | None
    params: dict[str, Any]

    @classmethod
    def parse(cls, where: str, d: Any) -> "HazardSpec":
        d = _keys(where, d, {"id", "type", "anchor", "trigger", "spawn", "params"}, {"id", "type", "anchor"})
        kind = d["type"]
        if kind not in HAZARD_TYPES:
            raise ConfigError(f"{where}: unknown hazard type {kind!r}; known: {', '.join(HAZARD_TYPES)}")
        hid = d["id"]
        if not isinstance(hid, str) or not hid:
            raise ConfigError(f"{where}.id must be a non-empty string")
        anchor = Anchor.parse(f"{where}.anchor", d["anchor"])
        trig = d.get("trigger")
        if kind == "parked":
            if trig is not None:
                raise ConfigError(f"{where}: a parked vehicle has no trigger")
            tk, tv = None, 0.0
        else:
            trig = _keys(f"{where}.trigger", trig if trig is not None else {}, set(TRIGGERS))
            if len(trig) != 1:
                raise ConfigError(f"{where}.trigger needs exactly one of {', '.join(TRIGGERS)}")
            tk, raw = next(iter(trig.items()))
            tv = _num(f"{where}.trigger.{tk}", raw, 0.0, 1000.0)
        spawn = d.get("spawn")
        if spawn is not None:
            spawn = _num(f"{where}.spawn", spawn, 0.0, 1000.0)
        defaults = HAZARD_TYPES[kind]
        p = _keys(f"{where}.params", d.get("params", {}), set(defaults))
        params = dict(defaults)
        for k, v in p.items():
            if isinstance(defaults[k], bool):
                if not isinstance(v, bool):
                    raise ConfigError(f"{where}.params.{k} must be true or false")
            elif isinstance(defaults[k], str):
                ok = VTYPES if k == "vtype" else ("left", "right")
                if v not in ok:
                    raise ConfigError(f"{where}.params.{k} must be one of {', '.join(ok)}, got {v!r}")
            else:
                v = _num(f"{where}.params.{k}", v, -100.0, 1000.0)
                if k in POSITIVE and v <= 0:
                    raise ConfigError(f"{where}.params.{k} must be positive, got {v:g}")
                if k in NON_NEGATIVE and v < 0:
                    raise ConfigError(f"{where}.params.{k} must not be negative, got {v:g}")
            params[k] = v
        return cls(hid, kind, anchor, tk, tv, spawn, params)

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"id": self.id, "type": self.type, "anchor": self.anchor.to_dict()}
        if self.trigger_kind is not None:
            d["trigger"] = {self.trigger_kind: self.trigger_value}
        if self.spawn is not None:
            d["spawn"] = self.spawn
        d["params"] = dict(self.params)
        return d


@dataclass(frozen=True)
class EgoSpec:
    """The ego's route (edge ids), departure and end [s], and optionally its departure lane
    (SUMO lane index; None: SUMO's "best")."""

    from_edge: str
    to_edge: str
    depart: float
    end: float
    lane: int | None = None

    @classmethod
    def parse(cls, where: str, d: Any) -> "EgoSpec":
        d = _keys(where, d, {"from", "to", "depart", "end", "lane"}, {"from", "to", "depart", "end"})
        for k in ("from", "to"):
            if not isinstance(d[k], str) or not d[k]:
                raise ConfigError(f"{where}.{k} must be an edge id")
        depart = _num(f"{where}.depart", d["depart"], 0.0)
        end = _num(f"{where}.end", d["end"], 0.0)
        if end <= depart:
            raise ConfigError(f"{where}.end ({end:g}) must be after depart ({depart:g})")
        lane = d.get("lane")
        if lane is not None and not is_number(lane, 0, 64, hi_open=True, integer=True):
            raise ConfigError(f"{where}.lane must be a lane index in [0, 64), got {lane!r}")
        return cls(d["from"], d["to"], depart, end, lane)

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"from": self.from_edge, "to": self.to_edge, "depart": self.depart, "end": self.end}
        return d if self.lane is None else d | {"lane": self.lane}


@dataclass(frozen=True)
class ScenarioSpec:
    name: str
    seed: int
    ego: EgoSpec
    hazards: tuple[HazardSpec, ...]
    network: str = ""
    road_type: str = ""
    info: dict[str, Any] = field(default_factory=dict)
    folder: Path | None = None

    @property
    def sumocfg(self) -> Path:
        assert self.folder is not None
        return self.folder / f"{self.name}.sumocfg"

    def run_config(self, out: Path, planner: Any = None, **options: Any) -> Any:
        """The RunConfig that runs this scenario as the suite defines it: its seed, end and ego
        route, departure and lane; the ethical planner with ``planner`` (a PlannerConfig), the
        baseline controller when it is None; ``options``: further RunConfig fields."""
        from sumo_ethics.config import RunConfig

        return RunConfig(scenario=self.sumocfg, out=Path(out), seed=self.seed, end=self.ego.end,
                         ego_from=self.ego.from_edge, ego_to=self.ego.to_edge, ego_depart=self.ego.depart,
                         ego_depart_lane="best" if self.ego.lane is None else str(self.ego.lane),
                         controller="baseline" if planner is None else "ethical", planner=planner,
                         progress=False, **options)

    @property
    def hazard_types(self) -> tuple[str, ...]:
        return tuple(h.type for h in self.hazards if h.type != "parked")

    @classmethod
    def parse(cls, d: Any, where: str = "hazard file", folder: Path | None = None) -> "ScenarioSpec":
        d = _keys(where, d, {"version", "name", "network", "road_type", "seed", "ego", "hazards", "info"},
                  {"name", "seed", "ego", "hazards"})
        if d.get("version", 1) != 1:
            raise ConfigError(f"{where}: unsupported version {d['version']!r} (expected 1)")
        seed = d["seed"]
        if not is_number(seed, 0, 2**31, hi_open=True, integer=True):
            raise ConfigError(f"{where}.seed must be an integer in [0, 2^31), got {seed!r}")
        if not isinstance(d["hazards"], list):
            raise ConfigError(f"{where}.hazards must be a list")
        hazards = tuple(HazardSpec.parse(f"{where}.hazards[{i}]", h) for i, h in enumerate(d["hazards"]))
        ids = [h.id for h in hazards]
        if len(set(ids)) != len(ids):
            raise ConfigError(f"{where}: hazard ids must be unique, got {ids}")
        return cls(name=str(d["name"]), seed=seed, ego=EgoSpec.parse(f"{where}.ego", d["ego"]), hazards=hazards,
                   network=str(d.get("network", "")), road_type=str(d.get("road_type", "")),
                   info=dict(d.get("info", {})), folder=folder)

    def to_dict(self) -> dict[str, Any]:
        return {"version": 1, "name": self.name, "network": self.network, "road_type": self.road_type,
                "seed": self.seed,
                "ego": self.ego.to_dict(),
                "hazards": [h.to_dict() for h in self.hazards], "info": self.info}


def dumps(spec: ScenarioSpec) -> str:
    return json.dumps(spec.to_dict(), indent=2, sort_keys=False) + "\n"


def load(path: Path) -> ScenarioSpec:
    """A scenario's hazard file (or its folder) -> ScenarioSpec; ConfigError on any problem."""
    path = Path(path)
    if path.is_dir():
        path = path / HAZARD_FILE
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise ConfigError(f"hazard file not found: {path}") from None
    except OSError as exc:
        raise ConfigError(f"cannot read hazard file {path}: {exc.strerror or exc}") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ConfigError(f"malformed JSON in {path}: {exc}") from None
    spec = ScenarioSpec.parse(data, where=str(path), folder=path.parent)
    if not spec.sumocfg.is_file():
        raise ConfigError(f"{path}: scenario config {spec.sumocfg.name} missing beside the hazard file")
    return spec


def load_suite(suite: Path) -> list[ScenarioSpec]:
    """Every scenario of a suite folder (sub-folders holding a hazard file), sorted by name; a
    single scenario's folder (holding the hazard file itself) is a suite of one."""
    suite = Path(suite)
    if not suite.is_dir():
        raise ConfigError(f"suite folder not found: {suite}")
    if (suite / HAZARD_FILE).is_file():
        return [load(suite)]
    files = sorted(suite.glob(f"*/{HAZARD_FILE}"))
    if not files:
        raise ConfigError(f"no scenarios in {suite}: expected sub-folders with {HAZARD_FILE}")
    return [load(f) for f in files]
