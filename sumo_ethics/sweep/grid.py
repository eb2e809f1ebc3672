"""The grid of a sweep: parsing ``--omega-u``, ``--seeds`` and ``--set``, the runs it holds
(:class:`RunSpec`), and :class:`Sweep`, the definition a manifest stores and compares.

Range syntax: ``start:stop:step`` is inclusive of ``stop`` when it lands on the grid
(``0:1:0.25`` -> 0, 0.25, 0.5, 0.75, 1; ``0:1:0.3`` -> 0, 0.3, 0.6, 0.9); values are rounded to
10 decimals, so ``0:1:0.1`` gives exactly 0.0, 0.1, ..., 1.0. A comma list (``0,0.5,1``) or a
single number also work. Seeds: ``0-9`` (inclusive), ``0,3,5`` or ``7``, or mixed ``0-3,8``.
Sizes are bounded before anything is built: MAX_VALUES per axis, MAX_RUNS in the grid.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

from sumo_ethics.errors import ConfigError, is_number
from sumo_ethics.settings import SET_PLANNER_KEYS

#: bounds checked before a grid is built: values per swept axis (--omega-u, --seeds, each --set)
#: and runs in the whole grid
MAX_VALUES = 10_000
MAX_RUNS = 100_000

# ---- --set keys --------------------------------------------------------------------------------
#: run keys: --set name -> (RunConfig field, type)
RUN_KEYS: dict[str, tuple[str, type]] = {
    "end": ("end", float),
    "ego_depart": ("ego_depart", float),
    "controller": ("controller", str),
    "radius": ("sensing_radius", float),
    "stop_at_collision": ("stop_at_collision", bool),
    "min_route_length": ("min_route_length", float),
    "collision_gap": ("collision_gap", float),
    "ego_from": ("ego_from", str),
    "ego_to": ("ego_to", str),
    "step_length": ("step_length", float),
    "record_decisions": ("record_decisions", str),
    # a fleet (sumo_ethics.runner.fleet): any of these makes each run a fleet run
    "egos": ("fleet.egos", int),
    "penetration": ("fleet.penetration", float),
    "fleet": ("fleet.shares", str),
    # conflicts among the road users that are not egos (conflicts_others.parquet)
    "conflicts_everyone": ("conflicts.everyone", bool),
    # TTC with the road users' turn rates (safety.measures.ttc_with_turns)
    "conflicts_turning": ("conflicts.turning", bool),
}
#: decisions a sweep's runs keep unless --record-decisions says otherwise (not part of the
#: sweep's definition then, so sweeps made before it resume as they were); a fleet run's egos keep
#: only the step before each collision (SWEEP_FLEET_RECORD_DECISIONS): per-ego risky steps would make
#: a penetration sweep's disk use and encoding time grow with its egos
SWEEP_RECORD_DECISIONS = "risky"
SWEEP_FLEET_RECORD_DECISIONS = "off"
PLANNER_SIMPLE = SET_PLANNER_KEYS


def planner_keys() -> list[str]:
    """Every planner key ``--set`` accepts (sub-table fields dotted: ``sampling.n_speeds``)."""
    from dataclasses import fields

    from sumo_ethics.ethics.cost import PrincipleWeights
    from sumo_ethics.ethics.probability import ProbabilityConfig
    from sumo_ethics.plan.perception import PerceptionConfig
    from sumo_ethics.plan.sampling import SamplingConfig

    keys = list(PLANNER_SIMPLE)
    for prefix, cls in (("sampling", SamplingConfig), ("probability", ProbabilityConfig),
                        ("principles", PrincipleWeights), ("perception", PerceptionConfig)):
        keys += [f"{prefix}.{f.name}" for f in fields(cls)]
    return keys


def known_set_keys() -> list[str]:
    return sorted(RUN_KEYS) + planner_keys()


# ---- parsing -----------------------------------------------------------------------------------
def _number(text: str, what: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise ConfigError(f"malformed {what}: '{text}' is not a number") from None
    if not math.isfinite(v):
        raise ConfigError(f"malformed {what}: '{text}' is not a finite number")
    return v


def parse_range(text: str, what: str = "range") -> list[float]:
    """``start:stop:step`` (inclusive of stop when on the grid), ``a,b,c`` or a single number."""
    text = text.strip()
    if not text:
        raise ConfigError(f"malformed {what}: empty")
    if ":" in text:
        parts = text.split(":")
        if len(parts) != 3:
            raise ConfigError(f"malformed {what} '{text}': expected start:stop:step, e.g. 0:1:0.1")
        start, stop, step = (_number(p, f"{what} '{text}'") for p in parts)
        if step <= 0:
            raise ConfigError(f"malformed {what} '{text}': step must be positive")
        if stop < start:
            raise ConfigError(f"malformed {what} '{text}': stop is below start")
        n = int(math.floor((stop - start) / step + 1e-9))
        if n + 1 > MAX_VALUES:
            raise ConfigError(f"{what} '{text}' has {n + 1:.3g} values; the limit is {MAX_VALUES}")
        values = [round(start + i * step, 10) for i in range(n + 1)]
    else:
        if text.count(",") + 1 > MAX_VALUES:
            raise ConfigError(f"{what} has {text.count(',') + 1} values; the limit is {MAX_VALUES}")
        values = [round(_number(p.strip(), f"{what} '{text}'"), 10) for p in text.split(",")]
    if len(set(values)) != len(values):
        raise ConfigError(f"malformed {what} '{text}': repeated values")
    return values


def parse_seeds(text: str) -> list[int]:
    """``0-9`` (inclusive), ``0,3,5``, ``7`` or mixed ``0-3,8``."""
    seeds: list[int] = []
    for part in text.split(","):
        part = part.strip()
        m = re.fullmatch(r"(\d+)(?:-(\d+))?", part)
        if not m:
            raise ConfigError(f"malformed --seeds '{text}': expected e.g. 0-9 or 0,3,5")
        a = int(m.group(1))
        b = int(m.group(2)) if m.group(2) is not None else a
        if b < a:
            raise ConfigError(f"malformed --seeds '{text}': {part} runs backwards")
        if b >= 2**31:
            raise ConfigError(f"malformed --seeds '{text}': seeds must be below 2^31")
        if len(seeds) + b - a + 1 > MAX_VALUES:
            raise ConfigError(f"--seeds '{text}' has more than {MAX_VALUES} seeds; the limit is {MAX_VALUES}")
        seeds += range(a, b + 1)
    if len(set(seeds)) != len(seeds):
        raise ConfigError(f"malformed --seeds '{text}': repeated seeds")
    if any(s >= 2**31 for s in seeds):
        raise ConfigError(f"malformed --seeds '{text}': seeds must be below 2^31")
    return seeds


def _scalar(text: str) -> Any:
    low = text.strip().lower()
    if low in ("true", "false"):
        return low == "true"
    if low in ("none", "null"):
        return None
    try:
        return int(text)
    except ValueError:
        pass
    try:
        return float(text)
    except ValueError:
        return text.strip()


def parse_set(items: Iterable[str]) -> dict[str, list[Any]]:
    """``["key=v1,v2", ...]`` -> ``{key: [v1, v2]}`` with checked keys and typed values."""
    known = known_set_keys()
    out: dict[str, list[Any]] = {}
    for item in items:
        if "=" not in item:
            raise ConfigError(f"malformed --set '{item}': expected key=v1,v2")
        key, _, vals = item.partition("=")
        key = key.strip().replace("-", "_")
        if key == "omega_u":
            raise ConfigError("omega_u is swept with --omega-u, not --set")
        if key == "seed":
            raise ConfigError("seeds are swept with --seeds, not --set")
        if key not in known:
            raise ConfigError(f"unknown --set key '{key}'; known: {', '.join(known)}")
        if key in out:
            raise ConfigError(f"--set {key} given twice")
        if vals.count(",") + 1 > MAX_VALUES:
            raise ConfigError(f"--set {key} has {vals.count(',') + 1} values; the limit is {MAX_VALUES}")
        values = [_scalar(v) for v in vals.split(",")] if vals.strip() else []
        if not values:
            raise ConfigError(f"malformed --set '{item}': no values")
        if key in RUN_KEYS:
            typ = RUN_KEYS[key][1]
            conv: list[float | int | str | bool] = []
            for v in values:
                if typ is float and isinstance(v, (int, float)) and not isinstance(v, bool):
                    conv.append(float(v))
                elif typ is str and v is not None:
                    conv.append(str(v))
                elif typ is bool and isinstance(v, bool):
                    conv.append(v)
                elif typ is int and isinstance(v, (int, float)) and not isinstance(v, bool) and float(v).is_integer():
                    conv.append(int(v))
                else:
                    raise ConfigError(f"--set {key}: {v!r} is not a {typ.__name__}")
            values = conv
        elif all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values) and \
                any(isinstance(v, float) for v in values):
            values = [float(v) for v in values]
        if len(set(map(repr, values))) != len(values):
            raise ConfigError(f"--set {key}: repeated values")
        if key == "predictor":  # the names of the predictor registry, checked before any run is built
            from sumo_ethics.predict import registry

            for v in values:
                try:
                    registry.get(v if isinstance(v, str) else repr(v))
                except ConfigError as exc:
                    raise ConfigError(f"--set predictor: {exc}") from None
        out[key] = values
    return out


# ---- the grid ----------------------------------------------------------------------------------
def find_scenarios(path: Path) -> list[Path]:
    """A .sumocfg, or every *.sumocfg below a folder (sorted)."""
    path = Path(path)
    if path.is_file():
        if path.suffix != ".sumocfg":
            raise ConfigError(f"{path} is not a .sumocfg file")
        return [path.resolve()]
    if path.is_dir():
        found = sorted(p.resolve() for p in path.rglob("*.sumocfg"))
        if not found:
            raise ConfigError(f"no *.sumocfg found under {path}")
        return found
    raise ConfigError(f"scenario or suite not found: {path}")


def scenario_names(paths: list[Path]) -> list[str]:
    """Short unique names: the file stem, or the path below the common folder when stems clash."""
    stems = [p.stem for p in paths]
    if len(set(stems)) == len(stems):
        return stems
    common = Path(os.path.commonpath([str(p.parent) for p in paths]))
    return [str(p.relative_to(common).with_suffix("")).replace(os.sep, "__") for p in paths]


@dataclass(frozen=True)
class RunSpec:
    """One run of the grid. ``params``: the sweep parameters (scenario name, omega_u, seed, --set keys)."""

    run_id: str
    scenario: str  # absolute path of the .sumocfg
    params: dict[str, Any]
    options: dict[str, Any]  # run options shared by the sweep (end, ego_depart, controller, ...)
    planner: dict[str, Any]  # base [planner] table shared by the sweep

    def to_dict(self) -> dict[str, Any]:
        return {"run_id": self.run_id, "scenario": self.scenario, "params": self.params, "options": self.options,
                "planner": self.planner}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "RunSpec":
        return cls(d["run_id"], d["scenario"], d["params"], d["options"], d["planner"])

    def run_config(self, out: Path):
        """The RunConfig of this run writing into ``out`` (validated; ConfigError otherwise)."""
        from sumo_ethics.config import RunConfig
        from sumo_ethics.settings import planner_config
        from sumo_ethics.sim import scenario as scenario_files

        opts = dict(self.options)
        table = json.loads(json.dumps(self.planner))  # deep copy
        overrides: dict[str, Any] = {"omega_u": self.params["omega_u"]}
        for key, value in self.params.items():
            if key in ("scenario", "omega_u", "seed"):
                continue
            if key in RUN_KEYS:
                opts[key] = value
            elif "." in key:
                sub, name = key.split(".", 1)
                table.setdefault(sub, {})[name] = value
            else:
                overrides[key] = value
        if opts.get("predictor") is not None and "predictor" not in overrides:
            overrides["predictor"] = opts["predictor"]
        kw = {RUN_KEYS[k][0]: v for k, v in opts.items() if k in RUN_KEYS}
        # the planner plans on the run's step: --step-length (or a step_length axis), else the scenario's
        step: float | None = None
        source: str | None = None
        if kw.get("controller", "ethical") == "ethical":  # the baseline plans nothing
            given = kw.get("step_length")
            step, source = scenario_files.resolve_step(scenario_files.read_scenario(Path(self.scenario)),
                                                       given if is_number(given, 0.0, lo_open=True) else None)
        planner = planner_config(table, step=step, step_source=source, **overrides)
        fleet = {k.removeprefix("fleet."): kw.pop(k) for k in list(kw) if k.startswith("fleet.")}
        if fleet:
            from sumo_ethics.config import FleetSpec

            if "shares" in fleet:
                fleet["shares"] = FleetSpec.parse_shares(fleet["shares"])
            kw["fleet"] = FleetSpec(**fleet)
        conflicts = {k.split(".", 1)[1]: kw.pop(k) for k in [k for k in kw if k.startswith("conflicts.")]}
        if conflicts:
            from sumo_ethics.config import ConflictConfig

            kw["conflicts"] = ConflictConfig(**conflicts)
        kw.setdefault("record_decisions", SWEEP_FLEET_RECORD_DECISIONS if "fleet" in kw else SWEEP_RECORD_DECISIONS)
        return RunConfig(scenario=Path(self.scenario), out=out, seed=int(self.params["seed"]), planner=planner,
                         progress=False, **kw)


def _fmt(v: Any) -> str:
    s = f"{v:g}" if isinstance(v, float) else str(v)
    return re.sub(r"[^A-Za-z0-9.+-]", "", s)


def make_run_id(params: dict[str, Any]) -> str:
    """Readable and unique: ``urban_wu0.5_s3[_key-value...]_<hash6>``."""
    head = f"{params['scenario']}_wu{_fmt(params['omega_u'])}_s{params['seed']}"
    extra = "".join(f"_{k.split('.')[-1]}-{_fmt(v)}" for k, v in params.items()
                    if k not in ("scenario", "omega_u", "seed"))
    digest = hashlib.sha1(json.dumps(params, sort_keys=True).encode()).hexdigest()[:6]
    name = re.sub(r"[^A-Za-z0-9._+-]", "-", head + extra)[:120]
    return f"{name}_{digest}"


@dataclass(frozen=True)
class Sweep:
    """The definition of a sweep (what ``manifest.json`` stores and compares)."""

    scenarios: tuple[str, ...]
    omega_u: tuple[float, ...]
    seeds: tuple[int, ...]
    sets: dict[str, list[Any]] = field(default_factory=dict)
    options: dict[str, Any] = field(default_factory=dict)  # end, ego_depart, controller, predictor, radius, ...
    planner: dict[str, Any] = field(default_factory=dict)  # base [planner] table (from --config)

    def definition(self) -> dict[str, Any]:
        return json.loads(json.dumps({
            "scenarios": list(self.scenarios), "omega_u": list(self.omega_u), "seeds": list(self.seeds),
            "set": self.sets, "options": self.options, "planner": self.planner}))

    @property
    def parameters(self) -> list[str]:
        """The sweep parameter columns: scenario, omega_u, seed, then the --set keys."""
        return ["scenario", "omega_u", "seed", *self.sets]

    def specs(self) -> list[RunSpec]:
        import itertools

        paths = [Path(s) for s in self.scenarios]
        names = scenario_names(paths)
        keys = list(self.sets)
        out = []
        for (path, name), wu, seed, *vals in itertools.product(
                zip(paths, names), self.omega_u, self.seeds, *(self.sets[k] for k in keys)):
            params = {"scenario": name, "omega_u": float(wu), "seed": int(seed), **dict(zip(keys, vals))}
            out.append(RunSpec(make_run_id(params), str(path), params, dict(self.options), dict(self.planner)))
        ids = [s.run_id for s in out]
        if len(set(ids)) != len(ids):  # pragma: no cover - the hash makes this practically impossible
            raise ConfigError("two runs of the grid got the same run id")
        return out

    def validate(self) -> list[RunSpec]:
        """Every distinct parameter set's RunConfig is built once here, and every distinct scenario
        (with each ego route) goes through the pre-flight checks, so bad input fails before anything
        runs. Cheap: XML parsing, no SUMO."""
        from sumo_ethics.runner import resolved_end
        from sumo_ethics.sim import preflight, session

        specs = self.specs()
        seen: set[str] = set()
        nets: dict[str, Any] = {}
        for spec in specs:
            key = json.dumps({k: v for k, v in spec.params.items() if k != "seed"}, sort_keys=True)
            if key in seen:
                continue
            seen.add(key)
            cfg = spec.run_config(Path("/nonexistent/validation-only"))
            if spec.scenario not in nets:
                files = session.read_scenario(cfg.scenario)
                nets[spec.scenario] = (files, preflight.check_scenario(files))
            try:
                files, checked = nets[spec.scenario]
                preflight.check_ego_edges(checked.net, cfg.ego_from, cfg.ego_to)
                resolved_end(cfg, files)
            except ConfigError as exc:
                raise ConfigError(f"{spec.params['scenario']}: {exc}") from None
        return specs


def make_sweep(scenario: Path, omega_u: str, seeds: str, sets: Iterable[str] = (), options: dict | None = None,
               planner: dict | None = None) -> Sweep:
    """Parse the command-line forms into a :class:`Sweep` (ConfigError on bad input)."""
    options = {k: v for k, v in (options or {}).items() if v is not None}
    unknown = set(options) - set(RUN_KEYS) - {"predictor"}
    if unknown:
        raise ConfigError(f"unknown run option(s): {', '.join(sorted(unknown))}")
    parsed = parse_set(sets)
    both = (set(parsed) & set(options)) - {"predictor"}
    if "predictor" in parsed and "predictor" in options:
        both.add("predictor")
    if both:
        raise ConfigError(f"{', '.join(sorted(both))} given both as an option and with --set")
    paths = find_scenarios(scenario)
    wu, sd = parse_range(omega_u, "--omega-u"), parse_seeds(seeds)
    n = len(paths) * len(wu) * len(sd) * math.prod(len(v) for v in parsed.values())
    if n > MAX_RUNS:
        raise ConfigError(f"the sweep has {n} runs ({len(paths)} scenarios x {len(wu)} omega_u x {len(sd)} seeds"
                          f"{''.join(f' x {len(v)} {k}' for k, v in parsed.items())}); the limit is {MAX_RUNS}")
    return Sweep(scenarios=tuple(str(p) for p in paths), omega_u=tuple(wu),
                 seeds=tuple(sd), sets=parsed, options=options, planner=dict(planner or {}))
