"""``sumo-ethics import-commonroad``: a CommonRoad scenario (XML, or gzip-compressed XML) to a
SUMO scenario folder that ``run``, ``sweep`` and ``evaluate`` take like any other.

The folder (``--out``)::

    <name>.net.xml        the lanelet network, converted by commonroad-sumo (CR2SumoMapConverter,
                          netconvert without offset normalisation: CommonRoad's coordinates)
    <name>.rou.xml        one vType per obstacle (its class and size), the ego (departing at the
                          begin, on a route from its start lane to the goal's lanes) and, in
                          reactive mode, the obstacles SUMO drives (departing at their recorded start)
    <name>.sumocfg        step = the scenario's dt; end = the goal's last time step (``--completion
                          origin``: twice that step, as the paper's evaluation)
    obstacles.parquet     the recorded states the replay follows: one row per obstacle and time step
    commonroad.json       the planning problem (the ego's initial state and goal region), the mode,
                          the completion rule (:meth:`sumo_ethics.goal.Goal.completes`)
                          and how each obstacle is driven; its presence marks the folder as imported

Only commonroad-io and commonroad-sumo (the ``commonroad`` extra) are used here; the net is read
with sumolib in ``sumo_ethics.sim.crnet`` and the run side is ``sumo_ethics.sim.commonroad_run``.
Everything that goes wrong with the input is a ConfigError (one line, exit 2); the folder is built
in a temporary sibling and moved into place at the end, so a failed import leaves nothing behind
and deletes nothing.
"""

from __future__ import annotations

import gzip
import io
import json
import logging
import math
import os
import re
import shutil
import tempfile
import time
import warnings
import zlib
from contextlib import contextmanager, redirect_stdout
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator
from xml.sax.saxutils import quoteattr

import numpy as np

from sumo_ethics.goal import COMPLETIONS, ORIGIN_TIME_FACTOR, Goal, GoalState
from sumo_ethics.errors import ConfigError

MODES = ("replay", "reactive")
MARKER = "commonroad.json"
OBSTACLES = "obstacles.parquet"
FORMAT = 1
INSTALL_HINT = "pip install 'sumo-ethics[commonroad]' (or: pip install commonroad-sumo 'eclipse-sumo==1.28.*')"

#: the ego's body: CommonRoad's default vehicle (vehicle model 2, a BMW 320i), as the project's ego
EGO_LENGTH, EGO_WIDTH = 4.508, 1.610
#: SUMO simulation steps between the begin and the first step the ego is controlled (the ego
#: departs in the first step, the runner takes it over and steps once more before reading)
TAKEOVER_STEPS = 2

#: CommonRoad obstacle type -> SUMO vClass (static obstacles of other types are 'passenger'
#: bodies, parked or standing, as CommonRoad's own SUMO interface treats them)
VCLASS = {"car": "passenger", "truck": "truck", "bus": "bus", "motorcycle": "motorcycle", "bicycle": "bicycle",
          "pedestrian": "pedestrian", "priorityVehicle": "emergency", "taxi": "taxi", "train": "rail",
          "parkedVehicle": "passenger", "unknown": "passenger"}
#: SUMO's default vehicle (a passenger car) for the rest; road boundaries and buildings are not
#: road users and are not imported (listed in commonroad.json)
NOT_ROAD_USERS = ("roadBoundary", "building", "pillar", "medianStrip", "constructionZone")


def require_packages() -> None:
    """ConfigError naming what to install when commonroad-io or commonroad-sumo is missing."""
    missing = []
    for mod, pkg in (("commonroad", "commonroad-io"), ("commonroad_sumo", "commonroad-sumo")):
        try:
            __import__(mod)
        except ImportError:
            missing.append(pkg)
    if missing:
        raise ConfigError(f"import-commonroad needs {' and '.join(missing)}: {INSTALL_HINT}")


def scenario_name(path: Path) -> str:
    name = path.name
    for suffix in (".gz", ".xml"):
        name = name.removesuffix(suffix)
    return name


@contextmanager
def plain_xml(path: Path) -> Iterator[Path]:
    """``path`` as a plain XML file (commonroad-io wants a path): .gz decompressed to a temporary file."""
    if not path.is_file():
        raise ConfigError(f"{path}: no such file")
    with open(path, "rb") as f:
        gz = f.read(2) == b"\x1f\x8b"
    if not gz:
        yield path
        return
    with tempfile.TemporaryDirectory(prefix="sumo-ethics-cr-") as tmp:
        plain = Path(tmp) / (scenario_name(path) + ".xml")
        try:
            with gzip.open(path, "rb") as src, open(plain, "wb") as dst:
                shutil.copyfileobj(src, dst)
        except (OSError, EOFError, zlib.error) as exc:
            raise ConfigError(f"{path.name}: not a readable gzip file ({exc})") from None
        yield plain


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0]}" if text else type(exc).__name__


def read(path: Path) -> tuple[Any, Any]:
    """(Scenario, PlanningProblemSet) of a CommonRoad file; ConfigError for anything unreadable."""
    require_packages()
    from commonroad.common.file_reader import CommonRoadFileReader

    with plain_xml(path) as plain:
        with open(plain, "rb") as f:
            head = f.read(4096).lstrip()
        if not head.startswith(b"<") or b"commonRoad" not in head:
            raise ConfigError(f"{path.name}: not a CommonRoad scenario (no <commonRoad> root element)")
        try:
            with warnings.catch_warnings(), redirect_stdout(io.StringIO()):
                warnings.simplefilter("ignore")
                scenario, problems = CommonRoadFileReader(str(plain)).open()
        except Exception as exc:  # noqa: BLE001 - the reader raises anything on malformed input
            raise ConfigError(f"{path.name}: CommonRoad could not read it ({_one_line(exc)})") from None
    if problems is None or not problems.planning_problem_dict:
        raise ConfigError(f"{path.name}: unsupported: no planning problem (nothing says where the ego starts)")
    return scenario, problems


# ---- the goal region ----------------------------------------------------------------------------
def _interval(v: Any) -> tuple[float, float] | None:
    if v is None:
        return None
    if hasattr(v, "start") and hasattr(v, "end"):
        return float(v.start), float(v.end)
    return float(v), float(v)


def _shapes(shape: Any) -> tuple[list[Any], list[tuple[float, float, float]]]:
    from commonroad.geometry.shape import Circle, ShapeGroup
    from shapely.geometry import Polygon

    if isinstance(shape, ShapeGroup):
        polys, circles = [], []
        for s in shape.shapes:
            p, c = _shapes(s)
            polys += p
            circles += c
        return polys, circles
    if isinstance(shape, Circle):
        return [], [(float(shape.center[0]), float(shape.center[1]), float(shape.radius))]
    if hasattr(shape, "vertices"):
        return [Polygon(np.asarray(shape.vertices, dtype=float).round(6))], []
    raise ConfigError(f"unsupported goal position shape {type(shape).__name__}")


def goal_of(problem: Any) -> Goal:
    """The planning problem's goal region as :class:`Goal` (what ``GoalRegion.is_reached`` checks)."""
    states = []
    for s in problem.goal.state_list:
        polys: list[Any] = []
        circles: list[tuple[float, float, float]] = []
        if s.has_value("position"):
            polys, circles = _shapes(s.position)
        ts = s.time_step
        steps = (int(ts.start), int(ts.end)) if hasattr(ts, "start") else (int(ts), int(ts)) if ts is not None else None
        states.append(GoalState(time_step=steps,
                                velocity=_interval(s.velocity) if s.has_value("velocity") else None,
                                orientation=_interval(s.orientation) if s.has_value("orientation") else None,
                                polygons=tuple(polys), circles=tuple(circles)))
    return Goal(tuple(states))


# ---- obstacles ----------------------------------------------------------------------------------
def _size(shape: Any) -> tuple[float, float]:
    if hasattr(shape, "length") and hasattr(shape, "width"):
        return float(shape.length), float(shape.width)
    if hasattr(shape, "radius"):
        return 2.0 * float(shape.radius), 2.0 * float(shape.radius)
    if hasattr(shape, "vertices"):  # a polygon: its extent along and across its own axes (rough)
        v = np.asarray(shape.vertices, dtype=float)
        ext = v.max(axis=0) - v.min(axis=0)
        return float(max(ext)), float(max(min(ext), 0.3))
    raise ConfigError(f"unsupported obstacle shape {type(shape).__name__}")


def _exact(v: Any, state: Any = None, attr: str | None = None) -> float:
    """A state value as a number: an interval (an uncertain value) by its middle; NaN if absent."""
    if attr is not None and not state.has_value(attr):
        return float("nan")
    if hasattr(v, "start") and hasattr(v, "end"):
        return 0.5 * (float(v.start) + float(v.end))
    return float(v)


def obstacle_rows(scenario: Any, first_step: int, last_step: int) -> tuple[list[dict[str, Any]], dict[str, Any], list[str]]:
    """Recorded states of every road user: (rows of obstacles.parquet, per-obstacle info, skipped).

    A dynamic obstacle's states are its initial state and its trajectory; a missing speed is the
    displacement over the step. A static obstacle stands at its initial state from ``first_step``
    to ``last_step``. States before ``first_step`` (the ego's start) are left out."""
    rows: list[dict[str, Any]] = []
    info: dict[str, Any] = {}
    skipped: list[str] = []
    dt = float(scenario.dt)
    obstacles = [(o, "dynamic") for o in scenario.dynamic_obstacles] + [(o, "static") for o in scenario.static_obstacles]
    for obs, kind in sorted(obstacles, key=lambda p: p[0].obstacle_id):
        ctype = obs.obstacle_type.value
        if ctype in NOT_ROAD_USERS:
            skipped.append(f"{obs.obstacle_id} ({ctype})")
            continue
        length, width = _size(obs.obstacle_shape)
        if kind == "static":
            s0 = obs.initial_state
            states = [(k, float(s0.position[0]), float(s0.position[1]), float(s0.orientation), 0.0)
                      for k in range(first_step, last_step + 1)]
        else:
            raw = [obs.initial_state] + (list(obs.prediction.trajectory.state_list)
                                         if obs.prediction is not None and hasattr(obs.prediction, "trajectory") else [])
            pts = []
            for s in raw:
                pos = s.position if s.has_value("position") else None
                if pos is not None and not hasattr(pos, "__len__"):  # an uncertain position: its shape's centre
                    pos = getattr(pos, "center", None)
                if pos is None:
                    raise ConfigError(f"unsupported: obstacle {obs.obstacle_id} has a state without a position")
                pts.append([int(_exact(s.time_step)), float(pos[0]), float(pos[1]), _exact(s.orientation, s, "orientation"),
                            _exact(s.velocity, s, "velocity")])
            a = np.array(pts, dtype=float)
            for col in (3, 4):  # missing orientation / speed from the displacement
                bad = ~np.isfinite(a[:, col])
                if bad.any():
                    d = np.diff(a[:, 1:3], axis=0)
                    d = np.vstack([d[:1], d]) if len(d) else np.zeros((1, 2))
                    est = np.arctan2(d[:, 1], d[:, 0]) if col == 3 else np.hypot(d[:, 0], d[:, 1]) / dt
                    a[bad, col] = est[bad]
            states = [(int(r[0]), r[1], r[2], r[3], r[4]) for r in a if r[0] >= first_step]
        if not states:
            skipped.append(f"{obs.obstacle_id} (gone before the ego starts)")
            continue
        sid = f"cr_{obs.obstacle_id}"
        info[sid] = {"obstacle_id": int(obs.obstacle_id), "kind": kind, "type": ctype,
                     "vclass": VCLASS.get(ctype, "passenger"), "length": length, "width": width,
                     "first_step": states[0][0], "last_step": states[-1][0]}
        for k, x, y, yaw, v in states:
            rows.append({"sumo_id": sid, "obstacle_id": int(obs.obstacle_id), "step": k, "x": x, "y": y,
                         "yaw": yaw, "speed": v, "length": length, "width": width})
    return rows, info, skipped


# ---- the SUMO net and lanes ---------------------------------------------------------------------
@contextmanager
def _sumo_on_path() -> Iterator[None]:
    """netconvert from the eclipse-sumo package first on PATH and as SUMO_HOME (commonroad-sumo
    looks only there) while converting."""
    import sumo

    home = str(sumo.SUMO_HOME)
    saved = {k: os.environ.get(k) for k in ("PATH", "SUMO_HOME")}
    os.environ["SUMO_HOME"] = home
    os.environ["PATH"] = str(Path(home) / "bin") + os.pathsep + (saved["PATH"] or "")
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def convert_net(scenario: Any, folder: Path, name: str) -> tuple[Path, dict[str, str]]:
    """The lanelet network as ``folder/<name>.net.xml`` (CommonRoad's coordinates), and which SUMO lane
    each lanelet became (lanelet id -> lane id, as the converter reports it)."""
    from commonroad_sumo.cr2sumo.map_converter.map_converter import CR2SumoMapConverter, CR2SumoMapConverterConfig

    work = folder / ".netconvert"
    work.mkdir()
    conf = CR2SumoMapConverterConfig.from_scenario(scenario)
    for logger in ("commonroad_sumo", "commonroad"):
        logging.getLogger(logger).setLevel(logging.ERROR)
    try:
        with _sumo_on_path(), warnings.catch_warnings(), redirect_stdout(io.StringIO()):
            warnings.simplefilter("ignore")
            converter = CR2SumoMapConverter(scenario, conf)
            project = converter.create_sumo_files(work)
    except Exception as exc:  # noqa: BLE001 - the converter raises anything on odd networks
        raise ConfigError(f"the lanelet network could not be converted ({_one_line(exc)})") from None
    nets = sorted(work.glob("*.net.xml"))
    if project is None or not nets:
        raise ConfigError("the lanelet network could not be converted (netconvert failed)")
    net = folder / f"{name}.net.xml"
    # netconvert's header names the time and the temporary folder: without it, the same input gives the same bytes
    text = nets[0].read_text()
    head = re.match(r"(<\?xml[^>]*>\s*)<!-- generated on .*?-->\s*", text, flags=re.S)
    if head:
        text = head.group(1) + "<!-- converted by commonroad-sumo (CR2SumoMapConverter) and netconvert for " \
            "sumo-ethics import-commonroad -->\n\n" + text[head.end():]
    net.write_text(text)
    shutil.rmtree(work, ignore_errors=True)
    lanes = {str(k): str(v) for k, v in sorted(converter.lanelet_id2lane_id.items())}
    return net, lanes


# ---- the folder ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class ImportResult:
    folder: Path
    sumocfg: Path
    mode: str
    n_obstacles: int
    n_replayed: int
    n_reactive: int
    seconds: float
    skipped: tuple[str, ...]


def folder_name(path: Path, mode: str, completion: str = "commonroad") -> str:
    """``<name>-<mode>``, and ``-late`` under the ``origin`` completion rule."""
    return f"{scenario_name(path)}-{mode}" + ("-late" if completion == "origin" else "")


def default_out(path: Path, mode: str, completion: str = "commonroad") -> Path:
    return Path("commonroad") / folder_name(path, mode, completion)


def check_out(out: Path) -> None:
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ConfigError(f"--out {out} exists and is not an empty folder; choose a new one (nothing is overwritten)")


def import_commonroad(path: Path, out: Path | None = None, mode: str = "replay",
                      completion: str = "commonroad") -> ImportResult:
    """Import the CommonRoad file ``path`` into the folder ``out`` (new or empty); see the module doc."""
    if mode not in MODES:
        raise ConfigError(f"--mode must be one of {', '.join(MODES)}, got {mode!r}")
    if completion not in COMPLETIONS:
        raise ConfigError(f"--completion must be one of {', '.join(COMPLETIONS)}, got {completion!r}")
    path = Path(path)
    out = Path(out) if out is not None else default_out(path, mode, completion)
    check_out(out)
    t0 = time.perf_counter()
    scenario, problems = read(path)
    name = scenario_name(path)
    tmp = Path(tempfile.mkdtemp(prefix=f".{name}.import-", dir=_existing_parent(out)))
    try:
        try:
            result = _build(path, scenario, problems, tmp, name, mode, completion)
        except ConfigError as exc:  # every cause names the file, once
            raise (exc if str(exc).startswith(f"{path.name}: ") else ConfigError(f"{path.name}: {exc}")) from None
        if out.exists():  # an empty folder (checked above): its place is taken by the new one
            out.rmdir()
        else:
            out.parent.mkdir(parents=True, exist_ok=True)
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return ImportResult(out, out / f"{name}.sumocfg", mode, result[0], result[1], result[2],
                        time.perf_counter() - t0, tuple(result[3]))


def _existing_parent(out: Path) -> Path:
    p = out.absolute().parent
    while not p.exists():
        p = p.parent
    return p


def _build(path: Path, scenario: Any, problems: Any, folder: Path, name: str,
           mode: str, completion: str = "commonroad") -> tuple[int, int, int, list[str]]:
    from sumo_ethics.sim.crnet import ego_route, from_lane, match_lane, obstacle_route, read_net, replay_edge

    dt = float(scenario.dt)
    if not (dt > 0 and math.isfinite(dt)):
        raise ConfigError(f"{path.name}: unsupported time step dt={dt}")
    pid = min(problems.planning_problem_dict)
    problem = problems.planning_problem_dict[pid]
    init = problem.initial_state
    for attr in ("position", "orientation", "velocity"):
        if not init.has_value(attr):
            raise ConfigError(f"{path.name}: unsupported: the planning problem's initial state has no {attr}")
    ex, ey = (float(v) for v in init.position)
    eyaw, espeed = float(init.orientation), float(init.velocity)
    k_start = int(init.time_step) if init.time_step is not None else 0
    goal = goal_of(problem)
    k_end = goal.last_step
    if k_end is None:  # no time window: as long as the longest recorded obstacle, at least 10 s
        k_end = max([k_start + int(round(10.0 / dt))] + [
            int(o.prediction.final_time_step) for o in scenario.dynamic_obstacles
            if o.prediction is not None and hasattr(o.prediction, "final_time_step")])
    if k_end < k_start:
        raise ConfigError(f"{path.name}: unsupported: the goal's time window ends (step {k_end}) before the ego starts "
                          f"(step {k_start})")
    if completion == "origin" and goal.last_step is not None:  # Origin's evaluation runs twice the goal's time
        k_end = max(k_end, int(goal.last_step * ORIGIN_TIME_FACTOR))
    rows, info, skipped = obstacle_rows(scenario, k_start, k_end)
    net_path, lanelet_lanes = convert_net(scenario, folder, name)
    net = read_net(net_path)
    # lanelets inside junctions become netconvert's junction lanes: their lanes are gone from the net
    in_junctions = sorted((k for k, v in lanelet_lanes.items() if not net.hasEdge(v.rsplit("_", 1)[0])), key=int)
    lanelet_lanes = {k: v for k, v in lanelet_lanes.items() if k not in set(in_junctions)}
    m = match_lane(net, ex, ey, eyaw, "passenger", junctions=True)
    if m is None:
        near = match_lane(net, ex, ey, eyaw, "passenger", radius=50.0, junctions=True)
        anyway = sorted(net.getNeighboringLanes(ex, ey, 4.0, includeJunctions=True), key=lambda p: (p[1], p[0].getID()))
        why = (f"the nearest lane heading its way is {near[0].getClosestLanePosAndDist((ex, ey))[1]:.1f} m off"
               if near is not None else "no lane heading its way within 50 m")
        if anyway:
            why += f"; lane {anyway[0][0].getID()} passes {anyway[0][1]:.1f} m off in another direction"
        raise ConfigError(f"{path.name}: unsupported: the ego's start ({ex:.1f}, {ey:.1f}) is on no lane of the "
                          f"converted network heading its way ({why})")
    start_lane, start_pos = m
    if start_lane.getID().startswith(":"):  # on a junction: depart at the end of the lane leading into it
        start_lane = from_lane(net, start_lane.getID())
        start_pos = start_lane.getLength() - EGO_LENGTH / 2.0 - 0.1
    route, goal_edges, goal_lanes = ego_route(net, start_lane.getEdge(), goal)
    t0 = TAKEOVER_STEPS * dt  # simulation time of the ego's first controlled step = CommonRoad step k_start

    def sim_time(k: int) -> float:
        return round(t0 + (k - k_start) * dt, 6)

    # reactive: obstacles SUMO can drive (on a lane heading their way, with a route) depart as recorded
    routes: dict[str, list[str]] = {}
    departs: dict[str, tuple[str, float, int, float]] = {}
    if mode == "reactive":
        by_id: dict[str, list[dict[str, Any]]] = {}
        for r in rows:
            by_id.setdefault(r["sumo_id"], []).append(r)
        for sid, meta in info.items():
            if meta["kind"] != "dynamic" or meta["vclass"] in ("pedestrian", "rail"):
                continue
            st = by_id[sid]
            if math.hypot(st[-1]["x"] - st[0]["x"], st[-1]["y"] - st[0]["y"]) < 1.0 and max(r["speed"] for r in st) < 0.5:
                continue  # standing all along (parked, waiting): SUMO would drive it off
            found = obstacle_route(net, st, meta["vclass"])
            if found is None:
                continue
            lane, pos, edges = found
            routes[sid] = edges
            departs[sid] = (lane.getID(), min(pos + meta["length"] / 2.0, lane.getLength()), lane.getIndex(),
                            max(0.0, float(st[0]["speed"])))
    for sid, meta in list(info.items()):
        meta["driven_by"] = "sumo" if sid in routes else "replay"
        if meta["driven_by"] == "replay":  # SUMO inserts it on an edge its class may use, then moves it
            placed = replay_edge(net, meta["vclass"])
            if placed is None:
                skipped.append(f"{meta['obstacle_id']} ({meta['type']}: no lane of the network allows a "
                               f"{meta['vclass']} or a class of the same kind)")
                del info[sid]
                continue
            meta["vclass"], meta["edge"] = placed
    rows = [r for r in rows if r["sumo_id"] in info]

    _write_routes(folder / f"{name}.rou.xml", info, routes, departs, sim_time, start_lane, start_pos, espeed, route, dt)
    end = sim_time(k_end) + dt / 2.0
    _write_sumocfg(folder / f"{name}.sumocfg", name, dt, end)
    _write_obstacles(folder / OBSTACLES, rows)
    import commonroad
    import commonroad_sumo  # noqa: F401

    meta = {
        "format": FORMAT, "source": str(path.resolve()), "scenario_id": str(scenario.scenario_id), "mode": mode,
        "completion": completion, "dt": dt, "takeover_steps": TAKEOVER_STEPS, "first_step": k_start, "last_step": k_end,
        "planning_problem_id": int(pid), "n_planning_problems": len(problems.planning_problem_dict),
        "ego": {"x": ex, "y": ey, "yaw": eyaw, "speed": espeed, "time_step": k_start, "length": EGO_LENGTH,
                "width": EGO_WIDTH, "lane": start_lane.getID(), "route": route},
        "goal": goal.to_list(), "goal_edges": goal_edges, "goal_lanes": goal_lanes, "lanelet_lanes": lanelet_lanes,
        "lanelets_in_junctions": in_junctions,
        "obstacles": {"file": OBSTACLES, "count": len(info),
                      "replayed": sorted(s for s, m in info.items() if m["driven_by"] == "replay"),
                      "driven_by_sumo": sorted(routes), "not_imported": skipped, "info": info},
        "versions": {"commonroad-io": _version("commonroad-io"), "commonroad-sumo": _version("commonroad-sumo"),
                     "commonroad_module": getattr(commonroad, "__version__", None)},
    }
    (folder / MARKER).write_text(json.dumps(meta, indent=1, sort_keys=True) + "\n")
    n_sumo = len(routes)
    return len(info), len(info) - n_sumo, n_sumo, skipped


def _version(dist: str) -> str | None:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(dist)
    except PackageNotFoundError:
        return None


def _write_routes(path: Path, info: dict[str, Any], routes: dict[str, list[str]],
                  departs: dict[str, tuple[str, float, int, float]], sim_time: Any, start_lane: Any,
                  start_pos: float, speed: float, ego_edges: list[str], step: float) -> None:
    lines = ['<?xml version="1.0" encoding="UTF-8"?>', "<!-- written by sumo-ethics import-commonroad -->",
             "<routes>",
             f'    <vType id="cr_ego_type" vClass="passenger" length="{EGO_LENGTH}" width="{EGO_WIDTH}" '
             f'maxSpeed="70" accel="11.5" decel="11.5" emergencyDecel="11.5"/>']
    for sid in sorted(info, key=lambda s: info[s]["obstacle_id"]):
        m = info[sid]
        lines.append(f'    <vType id="{sid}_type" vClass="{m["vclass"]}" length="{m["length"]:.4f}" '
                     f'width="{m["width"]:.4f}" minGap="0.5"><param key="commonroad_type" value={quoteattr(m["type"])}/></vType>')
    # the ego departs at the begin with its front at its start position; the run places it exactly
    front = min(start_pos + EGO_LENGTH / 2.0, start_lane.getLength())
    lines.append(f'    <route id="cr_ego_route" edges="{" ".join(ego_edges)}"/>')
    items = [(0.0, "ego", f'    <vehicle id="ego" type="cr_ego_type" route="cr_ego_route" depart="0" '
                          f'departLane="{start_lane.getIndex()}" departPos="{front:.3f}" departSpeed="{speed:.3f}" '
                          f'insertionChecks="none"/>')]
    for sid, edges in routes.items():
        lane, pos, idx, v = departs[sid]
        # SUMO shows a vehicle departing at d from the step after d on: depart one step early, so that
        # it stands at its recorded start in the step of its first record
        dep = round(sim_time(info[sid]["first_step"]) - step, 6)
        items.append((dep, sid, f'    <vehicle id="{sid}" type="{sid}_type" depart="{dep:.3f}" departLane="{idx}" '
                                f'departPos="{pos:.3f}" departSpeed="{v:.3f}" insertionChecks="none">\n'
                                f'        <route edges="{" ".join(edges)}"/>\n    </vehicle>'))
    items.sort(key=lambda i: (i[0], i[1] != "ego", i[1]))
    lines += [i[2] for i in items]
    lines.append("</routes>")
    path.write_text("\n".join(lines) + "\n")


def _write_sumocfg(path: Path, name: str, dt: float, end: float) -> None:
    path.write_text(f"""<?xml version="1.0" encoding="UTF-8"?>
<!-- written by sumo-ethics import-commonroad; commonroad.json beside it marks the folder as imported -->
<configuration>
    <input>
        <net-file value="{name}.net.xml"/>
        <route-files value="{name}.rou.xml"/>
    </input>
    <time>
        <begin value="0"/>
        <end value="{end:g}"/>
        <step-length value="{dt:g}"/>
    </time>
    <processing>
        <time-to-teleport value="-1"/>
        <ignore-route-errors value="true"/>
    </processing>
</configuration>
""")


def _write_obstacles(path: Path, rows: list[dict[str, Any]]) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    cols = {"sumo_id": pa.string(), "obstacle_id": pa.int64(), "step": pa.int64(), "x": pa.float64(),
            "y": pa.float64(), "yaw": pa.float64(), "speed": pa.float64(), "length": pa.float64(),
            "width": pa.float64()}
    table = pa.table({k: pa.array([r[k] for r in rows], type=t) for k, t in cols.items()})
    pq.write_table(table, path, compression="zstd")
