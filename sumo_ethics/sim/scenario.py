"""A user's .sumocfg read without starting SUMO: files, times, step length, outputs, vehicles.

Standard library only (no libsumo, numpy or torch), so the command line can refuse bad input
in a fraction of a second, before the heavy imports. ``sim/session.py`` starts SUMO with what
is read here.

Times. ``--end`` and ``--ego-depart`` are SUMO simulation times (absolute, like SUMO's own
``--end``), never offsets from the scenario's begin: a time before the begin is refused with
the begin named in the message. SUMO's time formats are understood: seconds (``50300``,
``0.5``), ``h:m:s`` (``16:0:0``) and ``d:h:m:s`` (``1:02:03:04``).
"""

from __future__ import annotations

import gzip
import io
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

from sumo_ethics.errors import ConfigError
from sumo_ethics.sumo_options import is_output_option, parse_time

#: used when neither --end nor the scenario sets an end: this long after the begin [s]
DEFAULT_DURATION = 3600.0
#: the control step the planner can trust [s]: used when a scenario sets none or a longer one
DEFAULT_STEP = 0.1
MAX_TRUSTED_STEP = 0.2

#: vClasses an ego may have: motor road vehicles. Everything else (bicycles, pedestrians,
#: trams, trains, ships) moves in ways the planner's car model does not describe.
EGO_CLASSES = frozenset({"passenger", "private", "taxi", "evehicle", "delivery", "emergency", "authority", "army",
                         "vip", "hov", "custom1", "custom2", "ignoring", "truck", "trailer", "bus", "coach",
                         "motorcycle", "moped"})
#: SUMO's built-in vTypes and their vClass
_DEFAULT_TYPES = {"DEFAULT_VEHTYPE": "passenger", "DEFAULT_PEDTYPE": "pedestrian", "DEFAULT_BIKETYPE": "bicycle",
                  "DEFAULT_TAXITYPE": "taxi", "DEFAULT_RAILTYPE": "rail", "DEFAULT_CONTAINERTYPE": "ignoring"}


@dataclass(frozen=True)
class ScenarioFiles:
    """What a .sumocfg names, resolved against its folder, and the options it sets."""

    config: Path
    net: Path
    routes: tuple[Path, ...]
    additionals: tuple[Path, ...]
    options: dict[str, str]

    def _time(self, key: str) -> float | None:
        value = self.options.get(key)
        return None if value is None else parse_time(value, f"{self.config.name}: <{key}>")

    @property
    def begin(self) -> float:
        """The scenario's begin [s] (0 when unset)."""
        return self._time("begin") or 0.0

    @property
    def end(self) -> float | None:
        """The scenario's end [s]; None when unset or negative (SUMO's -1: no end)."""
        end = self._time("end")
        return end if end is not None and end >= 0 else None

    @property
    def step_length(self) -> float | None:
        """The scenario's own step length [s] (None: SUMO's default of 1 s applies)."""
        return self._time("step-length")

    def outputs(self) -> dict[str, str]:
        """The output options the scenario sets, with their values as written."""
        return {k: v for k, v in self.options.items() if is_output_option(k) and v.strip()}


def _file_list(value: str | None, base: Path) -> tuple[Path, ...]:
    if not value:
        return ()
    return tuple((base / p).resolve() for p in value.replace(",", " ").split())


def read_scenario(path: Path) -> ScenarioFiles:
    """Parse a .sumocfg and check that every file it names exists and its times are readable
    (ConfigError otherwise)."""
    path = Path(path)
    if path.is_dir():
        found = sorted(path.glob("*.sumocfg")) + sorted(path.glob("*.sumocfg.gz"))
        hint = (f"; it holds {', '.join(p.name for p in found[:3])}{' ...' if len(found) > 3 else ''}" if found
                else "; it holds no .sumocfg")
        raise ConfigError(f"{path} is a folder, not a SUMO config: give the .sumocfg file{hint}")
    if not path.is_file():
        raise ConfigError(f"scenario file not found: {path}")
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise ConfigError(f"malformed SUMO config {path}: {exc}") from None
    if root.tag not in ("configuration", "sumoConfiguration"):
        raise ConfigError(f"{path} is not a SUMO config: root element <{root.tag}>, expected <configuration> or <sumoConfiguration>")
    options: dict[str, str] = {}
    for section in root:
        for opt in section:
            if "value" in opt.attrib:
                options[opt.tag] = opt.attrib["value"]
    base = path.resolve().parent
    nets = _file_list(options.get("net-file"), base)
    if len(nets) != 1:
        raise ConfigError(f"{path} names no net-file" if not nets else f"{path} names several net-files")
    files = ScenarioFiles(
        config=path.resolve(),
        net=nets[0],
        routes=_file_list(options.get("route-files"), base),
        additionals=_file_list(options.get("additional-files"), base),
        options=options,
    )
    for kind, paths in (("net-file", (files.net,)), ("route-file", files.routes), ("additional-file", files.additionals)):
        for p in paths:
            if not p.is_file():
                raise ConfigError(f"{path}: {kind} does not exist: {p}")
    files.begin, files.end, files.step_length  # noqa: B018 - malformed times fail here, before SUMO starts
    if files.step_length is not None and not files.step_length > 0:
        raise ConfigError(f"{path}: <step-length> must be positive, got {options['step-length']!r}")
    return files


# ---- vehicles declared in the route files ------------------------------------------------------
@dataclass(frozen=True)
class Declared:
    """Vehicles, flows, persons and vTypes of a scenario's route and additional files.

    vehicles, flows: id -> (vType id, has stops); types: vType id -> vClass (SUMO's built-in
    types included); distributions: vTypeDistribution ids (their class is known only in SUMO).
    """

    vehicles: dict[str, tuple[str, bool]] = field(default_factory=dict)
    flows: dict[str, tuple[str, bool]] = field(default_factory=dict)
    persons: set[str] = field(default_factory=set)
    types: dict[str, str] = field(default_factory=dict)
    distributions: set[str] = field(default_factory=set)


def _open(p: Path) -> gzip.GzipFile | io.BufferedReader:
    return gzip.open(p, "rb") if p.suffix == ".gz" else open(p, "rb")


_cache: dict[tuple, Declared | None] = {}


def declared(files: ScenarioFiles) -> Declared | None:
    """What the route and additional files declare (.gz files too); None if one cannot be read."""
    paths = files.routes + files.additionals
    key = tuple((str(p), os.stat(p).st_mtime_ns) for p in paths)
    if key in _cache:
        return _cache[key]
    out = Declared(types=dict(_DEFAULT_TYPES))
    try:
        for p in paths:
            with _open(p) as fh:
                stack: list[ET.Element] = []
                for event, el in ET.iterparse(fh, events=("start", "end")):
                    tag = el.tag
                    if event == "start":
                        stack.append(el)
                        continue
                    stack.pop()
                    if tag == "vType":
                        out.types[el.attrib.get("id", "")] = el.attrib.get("vClass", "passenger")
                    elif tag == "vTypeDistribution":
                        out.distributions.add(el.attrib.get("id", ""))
                    elif tag in ("vehicle", "trip", "flow"):
                        stops = el.find("stop") is not None or el.attrib.get("line") is not None
                        entry = (el.attrib.get("type", "DEFAULT_VEHTYPE"), stops)
                        (out.flows if tag == "flow" else out.vehicles)[el.attrib.get("id", "")] = entry
                    elif tag in ("person", "personFlow", "container", "containerFlow"):
                        out.persons.add(el.attrib.get("id", ""))
                    if not stack or stack[-1].tag in ("routes", "additional", "additionals"):
                        el.clear()  # keep memory flat on big demand files
    except (ET.ParseError, OSError, EOFError):
        _cache[key] = None
        return None
    _cache[key] = out
    return out


def check_ego_id(files: ScenarioFiles, ego_id: str) -> None:
    """ConfigError unless ``ego_id`` names a vehicle the route files declare, of a class the
    planner models and without stops (nothing is checked if the files cannot be read)."""
    d = declared(files)
    if d is None:
        return
    entry = d.vehicles.get(ego_id)
    if entry is None:
        head, _, tail = ego_id.rpartition(".")
        if ego_id in d.flows:
            raise ConfigError(f"--ego '{ego_id}' is a flow; its vehicles are named '{ego_id}.0', '{ego_id}.1', ...: "
                              f"pass one of those")
        if head in d.flows and tail.isdigit():
            entry = d.flows[head]
        elif ego_id in d.persons:
            raise ConfigError(f"--ego '{ego_id}' is a person; the ego must be a vehicle")
        else:
            raise ConfigError(f"unknown --ego '{ego_id}': no vehicle, trip or flow of that id in the route files")
    type_id, has_stops = entry
    vclass = d.types.get(type_id)
    if vclass is not None:
        check_ego_class(ego_id, vclass)
    if has_stops:
        refuse_stops(ego_id)


def check_ego_class(ego_id: str, vclass: str) -> None:
    if vclass not in EGO_CLASSES:
        raise ConfigError(f"--ego '{ego_id}' is a {vclass} (vClass); the planner models motor road vehicles only "
                          f"(cars, trucks, buses, motorcycles): choose another vehicle")


def refuse_stops(ego_id: str, what: str = "has stops") -> None:
    raise ConfigError(f"--ego '{ego_id}' {what} (a bus line, taxi or delivery); the planner drives a route "
                      f"and does not serve stops: choose another vehicle")


def net_edges(net: Path) -> set[str] | None:
    """Ids of the network's normal edges (None if the file cannot be read)."""
    edges: set[str] = set()
    try:
        with _open(net) as fh:
            for _, el in ET.iterparse(fh):
                if el.tag == "edge" and el.attrib.get("function") != "internal":
                    edges.add(el.attrib.get("id", ""))
                if el.tag in ("edge", "junction", "connection", "tlLogic"):
                    el.clear()
    except (ET.ParseError, OSError, EOFError):
        return None
    return edges


def check_out(out: Path) -> None:
    """ConfigError unless ``out`` is, or can be made, a writable folder (nothing is created)."""
    p = Path(out).absolute()
    while not p.exists():
        p = p.parent
    if not p.is_dir() or not os.access(p, os.W_OK | os.X_OK):
        raise ConfigError(f"cannot write to --out {out}: {'not a directory' if not p.is_dir() else 'permission denied'}: {p}")


def redirected_outputs(files: ScenarioFiles, folder: Path) -> dict[str, str]:
    """The scenario's output options pointed into ``folder`` (never next to the scenario):
    option -> new value. Relative sub-folders are kept under ``folder``; ``error-log`` is the
    run's own."""
    out: dict[str, str] = {}
    for key, value in files.outputs().items():
        if key == "error-log":
            continue
        names = []
        for part in value.replace(",", " ").split():
            rel = Path(part)
            rel = Path(rel.name) if rel.is_absolute() or ".." in rel.parts else rel
            names.append(str(folder / rel))
        out[key] = " ".join(names) if key != "save-state.prefix" else names[0]
    return out


def redirected(files: ScenarioFiles, folder: Path) -> tuple[dict[str, str], dict[str, list[str]]]:
    """Everything that points the scenario's own outputs into ``folder``: the options of
    :func:`redirected_outputs` plus, under ``additional-files``, the copies of
    :func:`redirected_additionals` (if any); and the additional files' outputs left as they are."""
    outputs = redirected_outputs(files, folder)
    additional, left = redirected_additionals(files, folder)
    if additional is not None:  # copies of the additional files whose detectors write files
        outputs["additional-files"] = additional
    return outputs, left


#: elements of additional files that write a file, and the attribute naming it
_ADDITIONAL_OUTPUTS = {tag: "file" for tag in (
    "e1Detector", "inductionLoop", "instantInductionLoop", "e2Detector", "laneAreaDetector", "e3Detector",
    "entryExitDetector", "edgeData", "laneData", "routeProbe", "vTypeProbe")} | {
    "timedEvent": "dest", "calibrator": "output", "laneCalibrator": "output"}
#: attributes that may name a file (inputs too: a file holding one of these is not rewritten)
_PATH_ATTRS = ("file", "href", "imgFile", "dest", "output")


def redirected_additionals(files: ScenarioFiles, folder: Path) -> tuple[str | None, dict[str, list[str]]]:
    """Additional files whose detectors or dumps write files (``<edgeData file=...>``, ...):
    each is copied into ``folder`` with those outputs pointed into ``folder``. Returns the new
    ``additional-files`` value (None if nothing changed) and, per file that could not be
    rewritten safely (it also names input files by relative path), the outputs left as they are.
    The outputs are written as absolute paths: SUMO reads a relative one in an additional file
    relative to that file, so ``--out runs/a`` once gave runs/a/sumo-outputs/additional-files/runs/a/...
    (eclipse-sumo's A10KW could not start)."""
    folder = Path(folder).resolve()
    paths: list[str] = []
    left: dict[str, list[str]] = {}
    changed = False
    for i, p in enumerate(files.additionals):
        try:
            with _open(p) as fh:
                raw = fh.read()
            if not any(f' {a}="'.encode() in raw for a in _PATH_ATTRS):  # most files: nothing to do
                paths.append(str(p))
                continue
            tree = ET.ElementTree(ET.fromstring(raw))
        except (ET.ParseError, OSError, EOFError):
            paths.append(str(p))
            continue
        outs = [(el, attr) for el in tree.iter() if (attr := _ADDITIONAL_OUTPUTS.get(el.tag)) and el.get(attr)]
        inputs = [el for el in tree.iter() for a in _PATH_ATTRS
                  if el.get(a) and _ADDITIONAL_OUTPUTS.get(el.tag) != a]
        if not outs or inputs:
            if outs:
                left[str(p)] = sorted({el.attrib[a] for el, a in outs})
            paths.append(str(p))
            continue
        for el, attr in outs:
            el.set(attr, str(folder / Path(el.attrib[attr]).name))
        copy = folder / "additional-files" / f"{i}_{p.name.removesuffix('.gz')}"
        copy.parent.mkdir(parents=True, exist_ok=True)
        tree.write(copy, encoding="unicode")
        paths.append(str(copy))
        changed = True
    return (",".join(paths) if changed else None), left


@dataclass(frozen=True)
class Plan:
    """A run's times and step resolved from the scenario and the user's flags, before SUMO starts.

    step_source: why this step: "--step-length", "scenario", or "default (...)": the
    scenario set none or one above MAX_TRUSTED_STEP.
    """

    files: ScenarioFiles
    begin: float
    end: float
    ego_depart: float
    step_length: float
    step_source: str

    def record(self) -> dict[str, object]:
        return {"begin": self.begin, "end": self.end, "ego_depart": self.ego_depart,
                "step_length_requested": self.step_length, "step_length_source": self.step_source,
                "scenario_step_length": self.files.step_length, "scenario_outputs": self.files.outputs()}


def resolve_step(files: ScenarioFiles, step_length: float | None) -> tuple[float, str]:
    """The run's step [s] and why (see :class:`Plan`'s step_source): ``step_length`` (--step-length)
    if given, else the scenario's if it sets one of at most MAX_TRUSTED_STEP, else DEFAULT_STEP.
    The planner plans on this step too (``settings.planner_config``'s ``step``)."""
    if step_length is not None:
        return step_length, "--step-length"
    if files.step_length is not None and files.step_length <= MAX_TRUSTED_STEP + 1e-9:
        return files.step_length, "scenario"
    return DEFAULT_STEP, ("the default: the scenario sets none, SUMO's own default is 1 s" if files.step_length is None
                          else f"the default: the scenario's {files.step_length:g} s is above {MAX_TRUSTED_STEP:g} s")


def plan(scenario: Path, end: float | None, ego_depart: float | None, step_length: float | None,
         ego_id: str | None = None, ego_edges: tuple[str, ...] = ()) -> Plan:
    """Read and check the scenario against the run's times and ego (ConfigError for bad input)."""
    files = read_scenario(scenario)
    begin = files.begin
    if end is None:
        end = files.end if files.end is not None else begin + DEFAULT_DURATION
        if end <= begin:
            raise ConfigError(f"{files.config.name}: its end ({end:g} s) is not after its begin ({begin:g} s)")
    elif end <= begin:
        raise ConfigError(f"--end {end:g} s is not after the scenario's begin ({begin:g} s); --end is a simulation "
                          f"time, e.g. --end {begin + end:g} for {end:g} s of simulation")
    if ego_depart is None:
        ego_depart = begin
    elif ego_depart < begin:
        raise ConfigError(f"--ego-depart {ego_depart:g} s is before the scenario's begin ({begin:g} s); --ego-depart is "
                          f"a simulation time, e.g. --ego-depart {begin + ego_depart:g}")
    if ego_id is None and ego_depart >= end:
        raise ConfigError(f"--ego-depart {ego_depart:g} s is not before the end of the simulation ({end:g} s)")
    step, source = resolve_step(files, step_length)
    if ego_id is not None:
        check_ego_id(files, ego_id)
    if ego_edges:
        known = net_edges(files.net)
        for e in ego_edges:
            if known is not None and e not in known:
                raise ConfigError(f"unknown edge '{e}' in --ego-from/--ego-to")
    return Plan(files, begin, end, ego_depart, step, source)
