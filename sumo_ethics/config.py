"""Frozen, self-validating run configuration. Units in the field comments."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from sumo_ethics.errors import ConfigError, is_number
from sumo_ethics.sumo_options import check_sumo_args


def require_number(name: str, value: Any, allow_zero: bool = False) -> float:
    """``value`` as a float if it is a finite positive (or, with allow_zero, non-negative) number."""
    if not is_number(value, 0.0, lo_open=not allow_zero):
        raise ConfigError(f"{name} must be a finite {'non-negative' if allow_zero else 'positive'} number, "
                          f"got {value!r}")
    return float(value)


@dataclass(frozen=True)
class EgoVehicle:
    """The ego's body and limits. Defaults: Origin's BMW 320i body, realistic limits."""

    length: float = 4.508  # m
    width: float = 1.610  # m
    mass: float = 1475.0  # kg
    max_speed: float = 36.0  # m/s
    max_accel: float = 3.0  # m/s^2, longitudinal
    comfort_decel: float = 3.0  # m/s^2
    max_decel: float = 8.0  # m/s^2, emergency braking
    max_lat_accel: float = 4.0  # m/s^2
    max_curvature: float = 0.2  # 1/m (about a 5 m turning radius)

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            require_number(f"ego.{name}", value)


@dataclass(frozen=True)
class ConflictConfig:
    """Conflicts (near misses) measured every step between the ego and each road user in range
    (:mod:`sumo_ethics.safety.conflicts`). A pair is in conflict while its box time to collision
    is below ``ttc`` or its post-encroachment time below ``pet``; TOML table ``[conflicts]``.
    ``everyone``: also every pair of road users of the network that involves no ego
    (:mod:`sumo_ethics.safety.pairs`, ``conflicts_others.parquet``), with the same thresholds.
    ``turning``: TTC with each road user's turn rate (:func:`sumo_ethics.safety.measures.ttc_with_turns`)
    instead of at constant heading (docs/conflicts.md says what each counts wrongly)."""

    enabled: bool = True  # measure and write conflicts.parquet
    ttc: float = 1.5  # s, time-to-collision threshold (SUMO's SSM device default, 3 s there)
    pet: float = 1.0  # s, post-encroachment-time threshold
    gap: float = 1.0  # s, a pair back in conflict within this time continues its event
    crossing_angle: float = 30.0  # deg, PET counts only where the headings differ by at least this
    everyone: bool = False  # also the pairs without an ego, network-wide (conflicts_others.parquet)
    turning: bool = False  # TTC at constant speed and turn rate where a party turns (else constant heading)

    def __post_init__(self) -> None:
        for name in ("enabled", "everyone", "turning"):
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(f"conflicts.{name} must be true or false, got {getattr(self, name)!r}")
        if self.everyone and not self.enabled:
            raise ConfigError("conflicts.everyone = true needs conflicts.enabled = true")
        for name in ("ttc", "pet", "gap"):
            require_number(f"conflicts.{name}", getattr(self, name))
        if require_number("conflicts.crossing_angle", self.crossing_angle, allow_zero=True) > 90.0:
            raise ConfigError(f"conflicts.crossing_angle must be at most 90 degrees, got {self.crossing_angle!r}")


#: what ``--fleet`` names besides the J_origin weight presets: the route-following baseline
FLEET_CONTROLLERS = ("baseline",)
#: --record-decisions: which steps keep the planner's whole decision (:mod:`sumo_ethics.record.decisions`)
DECISION_MODES = ("off", "collisions", "risky", "all")


@dataclass(frozen=True)
class FleetSpec:
    """Several egos in one run (:mod:`sumo_ethics.runner.fleet`).

    egos: inserted egos, departures spread over the first half of the run, routes drawn with the
    seed; penetration: share of the scenario's own eligible vehicles taken over when they depart
    (each by its own seeded draw, so the egos at 0.1 are among those at 0.25); ids: vehicles of the
    scenario taken over; shares: (planner name, share) pairs, each ego drawing its planner by share
    (a J_origin weight preset such as ``ethical`` or ``ego``, or ``baseline``), shares summing to 1.
    """

    egos: int = 0
    penetration: float = 0.0
    ids: tuple[str, ...] = ()
    shares: tuple[tuple[str, float], ...] = (("ethical", 1.0),)
    planners: tuple[tuple[str, Any], ...] = ()  # named PlannerConfigs ([planners.NAME] of --config)

    def __post_init__(self) -> None:
        if not is_number(self.egos, 0, 10_000, integer=True):
            raise ConfigError(f"--egos must be a whole number from 0 to 10000, got {self.egos!r}")
        object.__setattr__(self, "egos", int(self.egos))
        p = self.penetration
        if not is_number(p, 0.0, 1.0):
            raise ConfigError(f"--penetration must be a share from 0 to 1, got {p!r}")
        object.__setattr__(self, "penetration", float(p))
        if len(set(self.ids)) != len(self.ids):
            raise ConfigError("--ego names the same vehicle twice")
        if not self.shares:
            raise ConfigError("--fleet needs at least one planner")
        names = [n for n, _ in self.shares]
        if len(set(names)) != len(names):
            raise ConfigError(f"--fleet names a planner twice: {','.join(names)}")
        for name, share in self.shares:
            if not is_number(share, 0.0, 1.0):
                raise ConfigError(f"--fleet share of '{name}' must be from 0 to 1, got {share!r}")
        total = sum(s for _, s in self.shares)
        if abs(total - 1.0) > 1e-6:
            raise ConfigError(f"--fleet shares must sum to 1, got {total:g}")

    @staticmethod
    def parse_shares(text: str) -> tuple[tuple[str, float], ...]:
        """``"ethical=0.5,ego=0.5"`` -> (("ethical", 0.5), ("ego", 0.5)); a single name means all egos."""
        out = []
        for part in (p.strip() for p in text.split(",")):
            if not part:
                continue
            name, eq, value = part.partition("=")
            name = name.strip()
            if not name:
                raise ConfigError(f"--fleet: '{part}' names no planner (expected NAME=SHARE, e.g. ethical=0.5,ego=0.5)")
            if not eq:
                out.append((name, 1.0))
                continue
            try:
                out.append((name, float(value)))
            except ValueError:
                raise ConfigError(f"--fleet: share '{value.strip()}' of '{name}' is not a number") from None
        return tuple(out)


@dataclass(frozen=True)
class RunConfig:
    """Everything one run needs. ``end`` and ``ego_depart`` are simulation times [s] (absolute,
    like SUMO's own ``--end``; times before the scenario's begin are refused)."""

    scenario: Path
    out: Path
    seed: int = 42
    end: float | None = None  # s; default: the scenario's own end, else 3600
    ego_id: str | None = None  # take over this vehicle of the user's route files
    ego_from: str | None = None  # else insert our own ego on a route from this edge ...
    ego_to: str | None = None  # ... to this edge (both or neither); else a seeded random route
    ego_depart: float | None = None  # s; when the inserted ego departs (default: the scenario's begin)
    ego_depart_lane: str = "best"  # the inserted ego's departLane (a SUMO lane index or keyword)
    min_route_length: float = 300.0  # m; for the random route
    stop_at_collision: bool = True  # end the run at the ego's first collision
    controller: str = "ethical"  # or "baseline"
    sensing_radius: float = 80.0  # m; neighbours read around the ego each step
    collision_gap: float = 1.0  # s; a pair apart for longer than this collides anew
    ego: EgoVehicle = field(default_factory=EgoVehicle)
    sumo_args: tuple[str, ...] = ()  # extra SUMO command-line options, one token each
    step_length: float | None = None  # s; default: the scenario's if it sets one <= 0.2 s, else 0.1
    progress: bool = True
    overwrite: bool = False  # replace the outputs of an earlier run in ``out`` (refused otherwise)
    planner: Any = None  # sumo_ethics.plan.ethical.PlannerConfig for the "ethical" controller (None: defaults)
    record_decisions: str = "off"  # off | collisions | risky | all (sumo_ethics.record.decisions)
    conflicts: ConflictConfig = field(default_factory=ConflictConfig)  # near misses (conflicts.parquet)
    fleet: FleetSpec | None = None  # several egos (sumo_ethics.runner.fleet); None: the single-ego run

    def __post_init__(self) -> None:
        if self.record_decisions not in DECISION_MODES:
            raise ConfigError(f"--record-decisions must be one of {', '.join(DECISION_MODES)}, got {self.record_decisions!r}")
        object.__setattr__(self, "scenario", Path(self.scenario))
        object.__setattr__(self, "out", Path(self.out))
        if not is_number(self.seed, 0, 2**31, hi_open=True, integer=True):
            raise ConfigError(f"seed must be an integer in [0, 2^31), got {self.seed!r}")
        object.__setattr__(self, "seed", int(self.seed))  # a numpy integer too, as a plain int (config.json)
        if self.end is not None:
            require_number("--end", self.end)
        if self.ego_depart is not None:
            require_number("--ego-depart", self.ego_depart, allow_zero=True)
        if self.step_length is not None:
            require_number("--step-length", self.step_length)
        object.__setattr__(self, "sumo_args", check_sumo_args(tuple(self.sumo_args)))
        require_number("--radius", self.sensing_radius)
        require_number("collision_gap", self.collision_gap)
        require_number("min_route_length", self.min_route_length)
        if (self.ego_from is None) != (self.ego_to is None):
            raise ConfigError("--ego-from and --ego-to go together: give both or neither")
        if self.ego_id is not None and self.ego_from is not None:
            raise ConfigError("--ego takes over an existing vehicle; it cannot be combined with --ego-from/--ego-to")

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["scenario"] = str(self.scenario)
        d["out"] = str(self.out)
        d["sumo_args"] = list(self.sumo_args)
        d["planner"] = _plain(d["planner"])
        p = d["planner"]
        if isinstance(p, dict) and not p.get("occlusion") and not p.get("phantoms"):
            for key in ("occlusion", "phantoms", "perception"):  # off: config.json keeps its bytes
                p.pop(key, None)
        if isinstance(p, dict) and not p.get("keep_side"):  # off: config.json keeps its bytes
            p.pop("keep_side", None)
        if isinstance(p, dict) and isinstance(p.get("cost"), dict) and p["cost"].get("price") == "preset":
            p["cost"].pop("price")  # so does the default price level
        if self.fleet is None:  # the single-ego run's config.json keeps its bytes
            del d["fleet"]
        else:
            d["fleet"] = _plain(d["fleet"])
        if not self.conflicts.everyone:  # so does a run's without conflicts among the others
            del d["conflicts"]["everyone"]
        return d


def _plain(value: Any) -> Any:
    """JSON-ready copy: enums by value, tuples as lists."""
    import enum

    if isinstance(value, dict):  # a CostConfig without registered terms' weights: config.json keeps its bytes
        return {k: _plain(v) for k, v in value.items() if not (k == "term_weights" and not v)}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, enum.Enum):
        return value.value
    return value
