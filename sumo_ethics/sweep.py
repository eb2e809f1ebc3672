"""Sweeps: a grid of runs (scenarios x omega_u x seeds x ``--set`` values), one SUMO per process.

Layout of a sweep folder ``DIR``::

    DIR/manifest.json            sweep definition + every run (id, parameters, status, error, path)
    DIR/runs/<run_id>/           one complete run folder each (summary.json, config.json, params.json,
                                 steps/collisions/timings.parquet, sumo-errors.log)
    DIR/dataset/runs/...         one Parquet dataset per table, hive-partitioned by the swept
    DIR/dataset/collisions/...   parameters except the seed (``scenario=urban/omega_u=0.5/part-0.parquet``);
    DIR/dataset/steps/...        every row carries ``run_id`` and the sweep parameters

Executors. Locally one fresh process per run (started from a forkserver with the package
preloaded, so starting one costs milliseconds, not the imports), at most ``--workers`` at a
time: a fatal SUMO error never leaks into the next run and a crashing run takes down only
itself (a ``ProcessPoolExecutor`` with ``max_tasks_per_child=1`` breaks every run in flight when
one worker dies, and hangs at exit after Ctrl-C on Python 3.11). With a Dask scheduler the
same :func:`execute_run` runs in a fresh Python subprocess started by the Dask task
(long-lived Dask workers must not start a second libsumo simulation).

Finished runs. A run is *finished* when ``runs/<run_id>/summary.json`` exists. A run folder
is built under a temporary name (``runs/.<run_id>.tmp-<pid>-<hex>``) and renamed only when the
run ended on its own: ``completed``, ``collision``, ``timeout`` or ``error`` (SUMO failed, the ego
could not be inserted or left the network...: a result of that configuration, kept). A crash of
the tool itself (a Python exception that is not a sumo-ethics error, a killed worker, Ctrl-C)
leaves no run folder; the run is listed as ``failed`` in the manifest and runs again when the
same sweep is started again. Leftover temporary folders are removed at the start of a sweep.

Range syntax: ``start:stop:step`` is inclusive of ``stop`` when it lands on the grid
(``0:1:0.25`` -> 0, 0.25, 0.5, 0.75, 1; ``0:1:0.3`` -> 0, 0.3, 0.6, 0.9); values are rounded to
10 decimals, so ``0:1:0.1`` gives exactly 0.0, 0.1, ..., 1.0. A comma list (``0,0.5,1``) or a
single number also work. Seeds: ``0-9`` (inclusive), ``0,3,5`` or ``7``, or mixed ``0-3,8``.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
import shutil
import subprocess
import sys
import time
import traceback
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable

from sumo_ethics.errors import ConfigError

MANIFEST_VERSION = 1
FINISHED = ("completed", "collision", "timeout", "error")  # run statuses kept as results
FAILED = "failed"  # the tool itself crashed on this run: no run folder, retried on resume
PENDING = "pending"
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
}
PLANNER_SIMPLE = ("omega_o", "weights", "utility", "predictor", "max_risk", "selection", "envelope")


def planner_keys() -> list[str]:
    """Every planner key ``--set`` accepts (sub-table fields dotted: ``sampling.n_speeds``)."""
    from dataclasses import fields

    from sumo_ethics.ethics.cost import PrincipleWeights
    from sumo_ethics.ethics.probability import ProbabilityConfig
    from sumo_ethics.plan.sampling import SamplingConfig

    keys = list(PLANNER_SIMPLE)
    for prefix, cls in (("sampling", SamplingConfig), ("probability", ProbabilityConfig),
                        ("principles", PrincipleWeights)):
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
            conv = []
            for v in values:
                if typ is float and isinstance(v, (int, float)) and not isinstance(v, bool):
                    conv.append(float(v))
                elif typ is str and v is not None:
                    conv.append(str(v))
                elif typ is bool and isinstance(v, bool):
                    conv.append(v)
                else:
                    raise ConfigError(f"--set {key}: {v!r} is not a {typ.__name__}")
            values = conv
        elif all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values) and \
                any(isinstance(v, float) for v in values):
            values = [float(v) for v in values]
        if len(set(map(repr, values))) != len(values):
            raise ConfigError(f"--set {key}: repeated values")
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
        planner = planner_config(table, **overrides)
        kw = {RUN_KEYS[k][0]: v for k, v in opts.items() if k in RUN_KEYS}
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
                files, net = nets[spec.scenario]
                preflight.check_ego_edges(net, cfg.ego_from, cfg.ego_to)
                resolved_end(cfg, files)
            except ConfigError as exc:
                raise ConfigError(f"{spec.params['scenario']}: {exc}") from None
        return specs


def command_line(definition: dict[str, Any], out: str = "OUT") -> str:
    """A ``sumo-ethics sweep`` command that reproduces ``definition`` (for reports)."""
    flags = {"end": "--end", "ego_depart": "--ego-depart", "ego_from": "--ego-from", "ego_to": "--ego-to",
             "controller": "--controller", "predictor": "--predictor", "radius": "--radius"}
    scen = definition["scenarios"]
    parts = ["sumo-ethics sweep", scen[0] if len(scen) == 1 else os.path.commonpath(scen),
             "--omega-u", ",".join(f"{v:g}" for v in definition["omega_u"]),
             "--seeds", ",".join(map(str, definition["seeds"]))]
    for k, v in definition["set"].items():
        parts += ["--set", f"{k}=" + ",".join(f"{x:g}" if isinstance(x, float) else str(x) for x in v)]
    for k, v in definition["options"].items():
        if k == "stop_at_collision":
            parts += ["--continue-after-collision"] if v is False else []
        elif k in flags:
            parts += [flags[k], f"{v:g}" if isinstance(v, float) else str(v)]
    if definition.get("planner"):
        parts += ["--config", "PLANNER.toml"]
    return " ".join(parts + ["--out", out])


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


# ---- one run -----------------------------------------------------------------------------------
def _limit_threads() -> None:
    """One thread per run for torch (2 runs on 2 cores; also the same numbers on every executor)."""
    if "torch" in sys.modules:
        import torch

        torch.set_num_threads(1)


def execute_run(spec: dict[str, Any], runs_dir: str) -> dict[str, Any]:
    """Run one grid point into ``runs_dir/<run_id>`` (temp folder, renamed when the run ended on its own).

    Returns a result dict: run_id, status, message, error, wall, path. A finished run folder that
    already exists is not run again (status from its summary). Exceptions that are not
    sumo-ethics errors propagate (the caller records the run as failed).
    """
    from sumo_ethics.errors import OutputError, SumoEthicsError
    from sumo_ethics.record.writer import write_json

    s = RunSpec.from_dict(spec)
    runs = Path(runs_dir)
    final = runs / s.run_id
    if (final / "summary.json").exists():
        return _result_from_folder(s.run_id, final, skipped=True)
    tmp = runs / f".{s.run_id}.tmp-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    t0, c0 = time.perf_counter(), time.process_time()
    cfg = s.run_config(tmp)
    from sumo_ethics.runner import make_controller, run

    controller = make_controller(cfg)
    _limit_threads()
    try:
        run(cfg, controller=controller)
    except (ConfigError, OutputError):  # bad input or a full disk: not a result, retried on the next start
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    except SumoEthicsError as exc:  # SUMO failed on valid input: a result of this configuration, kept
        if not (tmp / "summary.json").exists():
            tmp.mkdir(parents=True, exist_ok=True)
            write_json(tmp / "summary.json", {"status": "error", "message": str(exc), "completed": False})
    wall = time.perf_counter() - t0
    write_json(tmp / "params.json", {"run_id": s.run_id, "params": s.params, "scenario": s.scenario,
                                     "wall_time": wall, "cpu_time": time.process_time() - c0})
    cfg_file = tmp / "config.json"
    if cfg_file.exists():  # the run was written under the temporary name: record the final one
        data = json.loads(cfg_file.read_text())
        data["out"] = str(final)
        write_json(cfg_file, data)
    try:
        os.rename(tmp, final)
    except OSError:  # another worker finished the same run first: keep theirs
        shutil.rmtree(tmp, ignore_errors=True)
        if not (final / "summary.json").exists():
            raise
    return _result_from_folder(s.run_id, final)


def _result_from_folder(run_id: str, folder: Path, skipped: bool = False) -> dict[str, Any]:
    data = json.loads((folder / "summary.json").read_text())
    status = data.get("status", "error")
    return {"run_id": run_id, "status": status, "message": data.get("message", ""),
            "error": data.get("message") if status == "error" else None, "wall": data.get("wall_time"),
            "path": str(folder), "skipped": skipped}


def execute_run_isolated(spec: dict[str, Any], runs_dir: str, timeout: float | None = None) -> dict[str, Any]:
    """:func:`execute_run` in a fresh Python subprocess (for long-lived workers such as Dask's)."""
    proc = subprocess.run([sys.executable, "-m", "sumo_ethics.sweep", runs_dir], input=json.dumps(spec),
                          capture_output=True, text=True, timeout=timeout)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    if proc.returncode == 0 and lines:
        return json.loads(lines[-1])
    tail = (proc.stderr.strip().splitlines() or [f"exit code {proc.returncode}"])[-1]
    raise RuntimeError(f"run process died (exit code {proc.returncode}): {tail}")


# ---- manifest ----------------------------------------------------------------------------------
def _write_json_atomic(path: Path, data: Any) -> None:
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    tmp.write_text(json.dumps(data, indent=2, default=str) + "\n")
    os.replace(tmp, path)


class Manifest:
    """``DIR/manifest.json``: the definition and the state of every run."""

    def __init__(self, out: Path, sweep: Sweep, specs: list[RunSpec]) -> None:
        self.path = out / "manifest.json"
        self.out = out
        self.sweep = sweep
        self.runs: dict[str, dict[str, Any]] = {}
        for s in specs:
            self.runs[s.run_id] = {"run_id": s.run_id, "params": s.params, "status": PENDING, "error": None,
                                   "message": "", "path": f"runs/{s.run_id}", "attempts": 0}

    def load_previous(self) -> None:
        if not self.path.exists():
            return
        try:
            old = json.loads(self.path.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise ConfigError(f"{self.path} is unreadable ({exc}); remove it or choose another --out") from None
        if old.get("definition") != self.sweep.definition():
            raise ConfigError(f"{self.out} holds a different sweep (manifest definition differs); "
                              f"choose another --out or remove it")
        for r in old.get("runs", []):
            if r.get("run_id") in self.runs:
                self.runs[r["run_id"]]["attempts"] = r.get("attempts", 0)

    def update(self, result: dict[str, Any]) -> None:
        r = self.runs[result["run_id"]]
        r.update(status=result["status"], error=result.get("error"), message=result.get("message", ""))
        if result.get("wall") is not None:
            r["wall_time"] = result["wall"]

    def sync(self, runs_dir: Path) -> None:
        """Record runs whose folder was completed while their result was not received (Ctrl-C)."""
        for r in self.runs.values():
            folder = runs_dir / r["run_id"]
            if r["status"] in (PENDING, FAILED) and (folder / "summary.json").exists():
                self.update(_result_from_folder(r["run_id"], folder))

    def write(self) -> None:
        counts: dict[str, int] = {}
        for r in self.runs.values():
            counts[r["status"]] = counts.get(r["status"], 0) + 1
        _write_json_atomic(self.path, {
            "version": MANIFEST_VERSION, "definition": self.sweep.definition(),
            "parameters": self.sweep.parameters, "counts": counts,
            "updated": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "runs": list(self.runs.values())})


def check_out(out: Path, sweep: Sweep) -> None:
    """ConfigError unless ``out`` is new, empty, or holds this same sweep."""
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out} exists and is not a folder")
    m = out / "manifest.json"
    if m.exists():
        try:
            old = json.loads(m.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise ConfigError(f"{m} is unreadable ({exc}); remove it or choose another --out") from None
        if old.get("definition") != sweep.definition():
            raise ConfigError(f"{out} holds a different sweep (manifest definition differs); "
                              f"choose another --out or remove it")
    elif out.is_dir() and any(p.name not in ("runs", "dataset") for p in out.iterdir()):
        raise ConfigError(f"--out {out} is not empty and holds no sweep manifest; choose another folder")


# ---- executors ---------------------------------------------------------------------------------
def _child(conn: Any, spec: dict[str, Any], runs_dir: str) -> None:
    """Body of one run process: :func:`execute_run`, its result (or error line) sent back."""
    from sumo_ethics._worker_signals import watch_parent

    watch_parent()  # killed when the sweep is gone, even by kill -9
    try:
        result = execute_run(spec, runs_dir)
        conn.send(("ok", result))
    except BaseException as exc:  # noqa: BLE001 - reported to the parent, which records the run as failed
        from sumo_ethics.errors import SumoEthicsError

        line = str(exc) if isinstance(exc, SumoEthicsError) and str(exc) else \
            "".join(traceback.format_exception_only(type(exc), exc)).strip().splitlines()[-1]
        try:
            conn.send(("error", line))
        except OSError:
            pass
    finally:
        conn.close()


class RunProcess:
    """One run in its own process; ``result()`` like a Future's (raises RuntimeError on a crash)."""

    def __init__(self, ctx: Any, spec: dict[str, Any], runs_dir: str) -> None:
        self.conn, child = ctx.Pipe(duplex=False)
        self.proc = ctx.Process(target=_child, args=(child, spec, runs_dir), name=f"run-{spec['run_id']}",
                                daemon=True)
        self.proc.start()
        child.close()
        self._msg: tuple | None = None

    def ready_handles(self) -> list[Any]:
        return [self.conn, self.proc.sentinel]

    def done(self) -> bool:
        if self._msg is None and self.conn.poll():
            try:
                self._msg = self.conn.recv()
            except (EOFError, OSError):
                self._msg = ("died", None)
        if self._msg is None and not self.proc.is_alive():
            self._msg = ("died", None)
        return self._msg is not None

    def result(self) -> dict[str, Any]:
        assert self._msg is not None
        self.proc.join(timeout=30)
        kind, value = self._msg
        if kind == "ok":
            return value
        if kind == "error":
            raise RuntimeError(value)
        code = self.proc.exitcode
        how = f"killed by signal {-code}" if code is not None and code < 0 else f"exit code {code}"
        raise RuntimeError(f"run process died ({how})")

    def stop(self) -> None:
        if self.proc.is_alive():
            self.proc.terminate()
        self.proc.join(timeout=10)
        if self.proc.is_alive():
            self.proc.kill()
            self.proc.join(timeout=5)


class LocalPool:
    """Local processes, one fresh process per run (forkserver with the package preloaded, so a
    run starts in milliseconds; a SUMO crash takes down only its own run)."""

    def __init__(self, workers: int) -> None:
        import multiprocessing as mp

        self.workers = workers
        self.ctx = mp.get_context("forkserver")
        self.ctx.set_forkserver_preload(["sumo_ethics._worker_signals", "sumo_ethics.sweep", "sumo_ethics.runner",
                                         "sumo_ethics.plan.ethical"])
        self.jobs: list[RunProcess] = []

    def submit(self, spec: dict[str, Any], runs_dir: str) -> RunProcess:
        job = RunProcess(self.ctx, spec, runs_dir)
        self.jobs.append(job)
        return job

    def wait(self, running: Iterable[Any]) -> set[Any]:
        from multiprocessing.connection import wait as mp_wait

        jobs = list(running)
        while True:
            done = {j for j in jobs if j.done()}
            if done:
                for j in done:
                    self.jobs.remove(j)
                return done
            mp_wait([h for j in jobs for h in j.ready_handles()], timeout=1.0)

    def close(self, cancel: bool = False) -> None:
        for j in self.jobs:
            if cancel:
                j.stop()
            else:
                j.proc.join()
        self.jobs = []


class DaskPool:
    """An existing Dask distributed cluster; each run in a fresh subprocess on a worker."""

    def __init__(self, address: str, timeout: float = 5.0) -> None:
        if not re.fullmatch(r"(tcp|tls|inproc|ws|wss|ucx)://[^\s]+", address):
            raise ConfigError(f"malformed --scheduler '{address}': expected tcp://HOST:PORT")
        try:
            from distributed import Client
        except ImportError:
            raise ConfigError("--scheduler needs dask's distributed package: pip install 'dask[distributed]'") \
                from None
        import logging

        logging.getLogger("distributed").setLevel(logging.CRITICAL)
        try:
            self.client = Client(address, timeout=timeout)
        except Exception as exc:  # noqa: BLE001 - refused, timed out, or something that is not a scheduler
            msg = str(exc).splitlines()[0][:200] if str(exc) else type(exc).__name__
            raise ConfigError(f"cannot reach Dask scheduler {address} within {timeout:g} s "
                              f"(or it is not a Dask scheduler): {msg}") from None
        self.workers = max(1, sum(self.client.nthreads().values()))

        self._done: Any = None

    def submit(self, spec: dict[str, Any], runs_dir: str) -> Any:
        from distributed import as_completed

        key = f"run-{spec['run_id']}-{uuid.uuid4().hex[:6]}"
        fut = self.client.submit(execute_run_isolated, spec, runs_dir, key=key, pure=False, retries=0)
        if self._done is None:
            self._done = as_completed([fut])
        else:
            self._done.add(fut)
        return fut

    def wait(self, running: Iterable[Any]) -> set[Any]:
        first = next(self._done)
        return {first, *self._done.next_batch(block=False)}

    def close(self, cancel: bool = False) -> None:
        self.client.close()


@dataclass
class SweepResult:
    out: Path
    total: int
    done: int  # finished runs (including status "error")
    failed: int  # tool crashes (retried on the next start)
    skipped: int  # already finished before this start
    errors: int  # finished with status "error"
    wall: float
    failures: list[str] = field(default_factory=list)  # the messages of the failed runs

    @property
    def ok(self) -> bool:
        return self.failed == 0


def _progress(enabled: bool, total: int):
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, \
        TimeRemainingColumn

    return Progress(TextColumn("[bold]sweep"), BarColumn(bar_width=20), MofNCompleteColumn(),
                    TextColumn("done · [red]{task.fields[failed]} failed[/red] · {task.fields[errors]} run errors ·"),
                    TimeElapsedColumn(), TextColumn("· left"), TimeRemainingColumn(), disable=not enabled)


def _clean_temporaries(out: Path) -> None:
    """Leftovers of an earlier start that was killed: temporary run folders (their runs were
    not finished and run again), the manifest's and the dataset's temporary files."""
    for p in [*(out / "runs").glob(".*.tmp-*"), *out.glob(".manifest.json.tmp-*"), *out.glob(".dataset.tmp-*"),
              *out.glob(".dataset.old-*")]:
        shutil.rmtree(p, ignore_errors=True) if p.is_dir() else p.unlink(missing_ok=True)


def check_finished(folder: Path) -> None:
    """ConfigError when a finished run folder is corrupt (unreadable summary or Parquet footer)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    what = "summary.json"
    try:
        if not isinstance(json.loads((folder / "summary.json").read_text()), dict):
            raise ValueError("not a JSON object")
        for name in ("steps", "timings", "collisions"):
            what = f"{name}.parquet"
            if (folder / what).exists():
                pq.read_metadata(folder / what)
    except (OSError, ValueError, pa.ArrowException) as exc:
        raise ConfigError(f"run folder {folder} is corrupt ({what}: {str(exc).splitlines()[0] if str(exc) else exc}); "
                          f"remove that folder and start the same sweep again to redo the run") from None


def run_sweep(sweep: Sweep, out: Path, workers: int = 1, scheduler: str | None = None, progress: bool = True,
              on_result: Callable[[dict[str, Any]], None] | None = None) -> SweepResult:
    """Run every unfinished run of ``sweep`` into ``out``, then build the dataset.

    ConfigError before anything runs for bad input, another sweep in ``out`` or an unreachable
    scheduler. Finished runs are skipped; a run whose process crashed is recorded as failed
    (and runs again on the next start); Ctrl-C or SIGTERM stops the runs in flight and re-raises;
    OutputError when the sweep's own files cannot be written (a full disk).
    """
    from sumo_ethics.errors import OutputError
    from sumo_ethics.interrupt import sigterm_as_interrupt

    with sigterm_as_interrupt():
        try:
            return _run_sweep(sweep, Path(out), workers, scheduler, progress, on_result)
        except OSError as exc:
            raise OutputError(f"cannot write the sweep to {out}: {exc.strerror or exc}") from None


def _run_sweep(sweep: Sweep, out: Path, workers: int, scheduler: str | None, progress: bool,
               on_result: Callable[[dict[str, Any]], None] | None) -> SweepResult:
    if workers < 1:
        raise ConfigError(f"--workers must be at least 1, got {workers}")
    specs = sweep.validate()
    check_out(out, sweep)
    executor: LocalPool | DaskPool = DaskPool(scheduler) if scheduler else LocalPool(workers)
    t0 = time.perf_counter()
    runs_dir = out / "runs"
    try:
        runs_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"cannot write to --out {out}: {exc.strerror or exc}") from None
    _clean_temporaries(out)
    manifest = Manifest(out, sweep, specs)
    manifest.load_previous()
    todo: list[RunSpec] = []
    skipped = 0
    for s in specs:
        folder = runs_dir / s.run_id
        if (folder / "summary.json").exists():
            check_finished(folder)
            manifest.update(_result_from_folder(s.run_id, folder, skipped=True))
            skipped += 1
        else:
            todo.append(s)
    manifest.write()
    failed = errors = 0
    failures: list[str] = []
    with _progress(progress, len(specs)) as bar:
        task = bar.add_task("runs", total=len(specs), completed=skipped, failed=0, errors=0)
        running: dict[Any, RunSpec] = {}
        queue = list(todo)

        def fill() -> None:
            # local: a process per run, so exactly `workers` at a time; Dask: keep its queue fed
            limit = executor.workers if isinstance(executor, LocalPool) else 2 * executor.workers
            while queue and len(running) < limit:
                s = queue.pop(0)
                manifest.runs[s.run_id]["attempts"] += 1
                running[executor.submit(s.to_dict(), str(runs_dir))] = s

        try:
            fill()
            while running:
                done_set = executor.wait(running)
                for fut in done_set:
                    s = running.pop(fut)
                    try:
                        result = fut.result()
                    except Exception as exc:  # noqa: BLE001 - a crash of the tool on this run
                        line = str(exc) if isinstance(exc, RuntimeError) and str(exc) else \
                            "".join(traceback.format_exception_only(type(exc), exc)).strip().splitlines()[-1]
                        result = {"run_id": s.run_id, "status": FAILED, "error": line, "message": line}
                    manifest.update(result)
                    if result["status"] == FAILED:
                        failed += 1
                        failures.append(str(result.get("message") or result.get("error") or ""))
                    elif result["status"] == "error":
                        errors += 1
                    if on_result is not None:
                        on_result(result)
                    manifest.write()
                    bar.update(task, advance=0 if result["status"] == FAILED else 1, failed=failed, errors=errors)
                fill()
        except BaseException:
            executor.close(cancel=True)
            manifest.sync(runs_dir)
            manifest.write()
            raise
    executor.close()
    manifest.write()
    from sumo_ethics.analysis.dataset import build_dataset

    build_dataset(out)
    done = sum(1 for r in manifest.runs.values() if r["status"] in FINISHED)
    return SweepResult(out=out, total=len(specs), done=done, failed=failed, skipped=skipped, errors=errors,
                       wall=time.perf_counter() - t0, failures=failures)


def _main_one() -> int:
    """``python -m sumo_ethics.sweep RUNS_DIR`` with a run spec (JSON) on stdin: one isolated run."""
    spec = json.loads(sys.stdin.read())
    result = execute_run(spec, sys.argv[1])
    sys.stdout.write("\n" + json.dumps(result) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(_main_one())
