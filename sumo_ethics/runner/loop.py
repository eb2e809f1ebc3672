"""The one simulation loop, one ego (:class:`Run`, :func:`execute`); several: :mod:`sumo_ethics.runner.fleet`.

Each step: read (``SumoWorld.read``; hooks' ``on_read`` -> Scene; hooks' ``before_act``) -> act
(``controller.act`` -> Decision) -> step (``SumoWorld.step``: moveToXY, simulationStep) -> detect
(``collision.CollisionBook``) -> record (``record.recorder.RunRecorder.step``: the step's rows and the
decision, kept by ``--record-decisions``; hooks' ``after_step``). The hooks are
:class:`~sumo_ethics.contract.StepHook` s. The run draws no figures: the collision snapshots are
drawn from the run folder afterwards (:func:`sumo_ethics.analysis.explain.draw_snapshots`). The ego
is brought in by ``sim.ego``; no libsumo here. Whatever
happens (a SUMO error, the ego leaving the network, Ctrl-C), the rows recorded so far and a
summary saying why the run ended are written to the run folder.
"""

from __future__ import annotations

import os
import platform
import shutil
import time as wallclock
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from types import MappingProxyType
from typing import Any, Iterable

import numpy as np

from sumo_ethics import __version__
from sumo_ethics.collision import CollisionBook, booked_outcome
from sumo_ethics.interrupt import sigterm_as_interrupt, sigterm_deferred
from sumo_ethics.config import RunConfig
from sumo_ethics.errors import ConfigError, OutputError, SimulationError, SumoEthicsError, Terminated, add_note
from sumo_ethics.notes import RunNotes, blocker_ahead, held
from sumo_ethics.contract import Controller, Scene, StepHook, StopRun
from sumo_ethics.plan.feasibility import ROAD_CURVATURE_TOL
from sumo_ethics.plan.history import History
from sumo_ethics.record.recorder import RunRecorder
from sumo_ethics.record.decisions import FOLDER as DECISIONS, SNAPSHOTS
from sumo_ethics.record.writer import PARTIAL, write_json
from sumo_ethics.safety.conflicts import ConflictBook, conflict_counts
from sumo_ethics.safety.fault import FaultContext
from sumo_ethics.safety.pairs import PairConflictBook, pair_counts
from sumo_ethics.sim import preflight, scenario as scenario_files, session
from sumo_ethics.sim.ego import start_ego
from sumo_ethics.sim.gui import GuiOptions, View
from sumo_ethics.sim.route import tight_bends
from sumo_ethics.sim.rules import RuleMonitor
from sumo_ethics.sumo_options import format_time
from sumo_ethics.sim.world import STOP_STATES, Snapshot, SumoWorld
from sumo_ethics.types import VULNERABLE, RoadUserClass, RunStatus

# the run's per-step hooks are :class:`sumo_ethics.contract.StepHook` (re-exported here and by
# sumo_ethics.runner; its phases: start, on_read, desired_speed, before_act, after_step, route_end,
# summary): the loop calls nothing else of them


@dataclass(frozen=True)
class RunSummary:
    status: RunStatus
    message: str
    out: Path
    data: dict[str, Any] = field(default_factory=dict)


#: every file or folder a run writes into its --out folder
OUTPUT_NAMES = ("summary.json", "config.json", "steps.parquet", "timings.parquet", "collisions.parquet",
                "conflicts.parquet", "conflicts_others.parquet", "trips.parquet", "sumo-errors.log", "sumo-outputs",
                PARTIAL, DECISIONS, SNAPSHOTS)
#: what the other commands write into a run folder: ``explain``'s figures (RUN/explain/), and a
#: ``replay`` or ``explain --out`` put beside the outputs (any file with these suffixes)
DERIVED_NAMES = ("explain",)
DERIVED_SUFFIXES = (".png", ".svg", ".gif", ".mp4")


def is_run_folder(out: Path) -> bool:
    """True if ``out`` holds the ``config.json`` a run writes first (its ``scenario`` and ``resolved``
    settings), or a run's ``summary.json`` (``status``, ``message``, ``seed``)."""
    import json

    for name, keys in (("config.json", ("scenario", "resolved")), ("summary.json", ("status", "message", "seed"))):
        try:
            data = json.loads((out / name).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        if isinstance(data, dict) and all(k in data for k in keys):
            return True
    return False


def foreign_entries(out: Path) -> list[str]:
    """The names in run folder ``out`` that no sumo-ethics command writes there (sorted)."""
    return sorted(p.name for p in out.iterdir()
                  if p.name not in OUTPUT_NAMES and p.name not in DERIVED_NAMES
                  and not p.name.startswith((".replaced-", ".write-test"))
                  and not (p.is_file() and p.suffix.lower() in DERIVED_SUFFIXES))


def prepare_out(out: Path, overwrite: bool = False) -> tuple[bool, Path | None]:
    """Create the run folder and prove it is writable (ConfigError otherwise).

    A folder holding a run's outputs is refused unless ``overwrite``; then the earlier run is
    replaced as a whole: everything in the folder (its outputs and the figures and animations made
    from them) is moved into ``out/.replaced-<pid>/``, put back if this run is refused for bad input
    and deleted when it ends. Only a run folder is replaced (:func:`is_run_folder`), and only one
    holding nothing but what sumo-ethics writes there: a folder with any other file or folder
    (:func:`foreign_entries`) is refused, so nothing else is ever deleted.
    Returns (whether the folder was created, the folder holding the replaced run or None).
    """
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out} exists and is not a folder")
    old = [n for n in OUTPUT_NAMES if (out / n).exists()] if out.is_dir() else []
    if old and not overwrite:
        raise ConfigError(f"--out {out} already holds a run ({', '.join(old)}); give --overwrite to replace it "
                          "or choose another folder")
    if old:
        if not is_run_folder(out):
            raise ConfigError(f"--out {out} holds {', '.join(old)} but is not a run folder (no config.json or "
                              "summary.json of a run); --overwrite replaces run folders only: choose another folder")
        foreign = foreign_entries(out)
        if foreign:
            shown = ", ".join(foreign[:5]) + (f" and {len(foreign) - 5} more" if len(foreign) > 5 else "")
            raise ConfigError(f"--out {out} holds a run and {shown}, which no run writes; --overwrite replaces "
                              "the run folder as a whole: move them out or choose another folder")
    created = not out.exists()
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / ".write-test"
        probe.write_text("ok")
        probe.unlink()
        backup = None
        if overwrite:  # an earlier run an overwriting run moved aside and was killed before deleting
            for stale in out.glob(".replaced-*"):
                shutil.rmtree(stale, ignore_errors=True)
        if old:  # --overwrite: the previous run as a whole (foreign_entries found nothing else)
            backup = out / f".replaced-{os.getpid()}"
            backup.mkdir()
            for p in list(out.iterdir()):
                if p != backup:
                    os.rename(p, backup / p.name)
    except OSError as exc:
        raise ConfigError(f"cannot write to --out {out}: {exc.strerror or exc}") from None
    return created, backup


def discard_outputs(out: Path, created: bool, written: Iterable[str] = ("config.json", "sumo-errors.log"),
                    replaced: Path | None = None) -> None:
    """Remove what a run refused for bad input wrote (only the files it wrote itself) and put back
    the earlier run's outputs it was to replace, so the folder is as it was."""
    for name in written:
        p = out / name
        if p.is_dir():
            shutil.rmtree(p, ignore_errors=True)
        else:
            p.unlink(missing_ok=True)
    if replaced is not None and replaced.is_dir():
        for p in replaced.iterdir():
            os.replace(p, out / p.name)  # this run's own files with those names are gone by now
        shutil.rmtree(replaced, ignore_errors=True)
    if created:
        try:
            out.rmdir()
        except OSError:
            pass


def resolved_end(cfg: RunConfig, files: session.ScenarioFiles) -> float:
    """The run's time limit [s]: --end, else the scenario's end, else its begin + 3600 s;
    ConfigError for times before the scenario's begin or an inserted ego departing at or after
    the end (``sim.scenario.plan``)."""
    return scenario_files.plan(files.config, cfg.end, cfg.ego_depart, cfg.step_length, cfg.ego_id).end


def on_run_step(cfg: RunConfig, step: float, source: str) -> RunConfig:
    """``cfg`` with its planners on the run's ``step`` [s]: the planner plans on the simulation's step
    (``EthicalPlanner.plan`` samples at the scene's dt), so each PlannerConfig's grid is checked
    against the memory bounds at that step (ConfigError before SUMO starts) and its ``sampling.dt``
    set to it (config.json records the step the planner plans on). A configured ``[planner.sampling]
    dt`` that differs is refused earlier, where the settings are read (``settings.planner_config``)."""
    from sumo_ethics.plan.ethical import PlannerConfig
    from sumo_ethics.settings import planning_step

    def at_step(planner: Any) -> Any:  # no [planner.sampling] table here: its dt was checked where it was read
        return replace(planner, sampling=planning_step(planner.sampling, {}, step, source))

    if cfg.controller != "ethical" and cfg.fleet is None:  # the baseline plans nothing
        return cfg
    if cfg.planner is not None:
        cfg = replace(cfg, planner=at_step(cfg.planner))
    elif cfg.controller == "ethical":
        at_step(PlannerConfig())  # the defaults' grid: checked, left unset in config.json
    if cfg.fleet is not None and cfg.fleet.planners:
        cfg = replace(cfg, fleet=replace(cfg.fleet, planners=tuple((n, at_step(p)) for n, p in cfg.fleet.planners)))
    return cfg


# ---- the run ----------------------------------------------------------------------------------
class Run:
    """State of one run; :meth:`execute` is the loop."""

    def __init__(self, cfg: RunConfig, controller: Controller | None, hooks: tuple[StepHook, ...] = (),
                 gui: GuiOptions | None = None) -> None:
        self.cfg = cfg
        self.controller = controller  # None: a fleet's (FleetRun: one controller per ego)
        self.hooks = hooks
        self.gui = gui  # run in sumo-gui, the decisions drawn (sim.gui.View)
        self.view: View | None = None
        self.rec = RunRecorder(cfg.out)
        self.status = RunStatus.ERROR
        self.message = ""
        self.written: list[str] = []  # files of the run folder this run wrote (removed on bad input)
        self.created_out = False
        self.replaced: Path | None = None  # an earlier run's outputs moved aside by --overwrite
        self.meta: dict[str, Any] = {}
        self.notes: RunNotes | None = None  # tight bends and a lonely standstill (sumo_ethics.notes)
        self.step = 0
        self.n_fallback = 0  # predicted agents replaced by constant velocity (non-finite prediction), summed
        self.conflicts: ConflictBook | None = None
        self.pairs: PairConflictBook | None = None  # conflicts among the others ([conflicts] everyone)
        self.everyone: Any = None  # sim.everyone.Everyone: every road user, for self.pairs
        self.pairs_wall = 0.0  # s spent reading everyone and measuring their pairs
        self.red_s: float | None = None  # arc length of the red stop line ahead at the last read
        self.ran_red_at = -float("inf")  # s, when the ego last passed a stop line at red
        self.t_start = wallclock.perf_counter()

    def stop_line(self, s_front: float) -> float | None:
        """Arc length of the next red/yellow stop line within 100 m ahead of the ego's front (and
        in ``red_s`` that line's arc length if it shows red, else None)."""
        line, self.red_s = stop_line(self.world, s_front)
        return line

    def execute(self) -> None:
        cfg = self.cfg
        plan = scenario_files.plan(cfg.scenario, cfg.end, cfg.ego_depart, cfg.step_length, cfg.ego_id)
        files, end = plan.files, plan.end
        self.cfg = cfg = on_run_step(cfg, plan.step_length, plan.step_source)
        preflight.check_scenario(files, cfg.ego_from, cfg.ego_to)  # what SUMO reports badly or crashes on
        ego_id = cfg.ego_id or "ego"
        declared = scenario_files.declared(files)
        # a person named "ego" too: context subscriptions of both domains come back merged by id
        if cfg.ego_id is None and declared is not None and (ego_id in declared.vehicles or ego_id in declared.persons):
            ego_id = "sumo_ethics_ego"
        # every check that needs no SUMO has passed: only now is the run folder touched
        self.created_out, self.replaced = prepare_out(cfg.out, cfg.overwrite)
        # the scenario's own outputs (tripinfo, log, ...) go into the run folder, never next to it
        if not (cfg.out / "sumo-outputs").exists():
            self.written.append("sumo-outputs")
        outputs, left = scenario_files.redirected(files, cfg.out / "sumo-outputs")
        if cfg.fleet is not None:  # every trip of the run, for trips.parquet
            outputs.setdefault("tripinfo-output", str(cfg.out / "sumo-outputs" / "tripinfo.xml"))
            outputs["tripinfo-output.write-unfinished"] = "true"
            self.meta["tripinfo"] = outputs["tripinfo-output"]
        recorded_ego = None if cfg.fleet is not None else ego_id  # a fleet has no one ego
        self.meta.update(scenario=str(files.config), ego_id=recorded_ego, **plan.record(),
                         forced_sumo_options=session.forced_option_report(files), redirected_outputs=outputs,
                         outputs_not_redirected=left, sumo_args=list(cfg.sumo_args))
        write_json(cfg.out / "config.json", cfg.to_dict() | {"resolved": {
            "scenario": str(files.config.resolve()), "net": str(files.net.resolve()),
            "end": end, "ego_id": recorded_ego, "begin": plan.begin, "ego_depart": plan.ego_depart,
            "step_length": plan.step_length}})
        self.written.append("config.json")
        if not (cfg.out / "sumo-errors.log").exists():
            self.written.append("sumo-errors.log")
        session.start(files, cfg.seed, cfg.out / "sumo-errors.log", cfg.sumo_args, step_length=plan.step_length,
                      outputs=outputs, gui=self.gui)
        if self.gui is not None:
            self.meta["gui"] = asdict(self.gui)
        self.meta["sumo_version"] = session.version()
        try:
            self._loop(ego_id, end, plan.ego_depart)
        except session.SUMO_ERRORS as exc:
            raise SimulationError(f"SUMO failed at t={self.meta.get('last_time', 0):g} s: "
                                  f"{session.first_line(exc, cfg.out / 'sumo-errors.log')}") from None
        finally:
            session.close()

    def _loop(self, ego_id: str, end: float, depart: float) -> None:
        controller = self.controller
        if controller is None:
            raise ValueError("a run needs a controller (a fleet is run by FleetRun)")
        dt = session.step_length()
        self.rec.start(dt, self.cfg.record_decisions)
        ego, edges = start_ego(self.cfg, ego_id, end, depart)
        self.cfg = cfg = replace(self.cfg, ego=ego)
        self.world = world = SumoWorld(ego_id, cfg.sensing_radius)
        route = world.takeover()
        if self.gui is not None:
            self.view = View(ego_id)
        for hook in self.hooks:  # may return another reference path for the ego
            route = hook.start(world) or route
        self.notes = notes = RunNotes(tight_bends(route, cfg.ego.max_curvature), cfg.ego.max_curvature,
                                      ROAD_CURVATURE_TOL)
        self.meta.update(step_length=dt, route_edges=list(edges), route_length=route.length,
                         takeover_time=session.sim_time(), controller=controller.name,
                         predictor=getattr(controller, "predictor_info", None),
                         takeover_wall=wallclock.perf_counter() - self.t_start)
        world.step()  # subscription results arrive with the next step
        snap = world.read()
        if snap is None:
            raise SimulationError(f"the ego '{ego_id}' left the simulation right after the takeover")
        # the limits drive with the mass the planner and the harm model read off the scene: a taken-over
        # vehicle's own (its vType's, or the class estimate where the vType leaves SUMO's default)
        self.cfg = cfg = replace(cfg, ego=replace(cfg.ego, mass=float(snap.ego.mass[0])))
        self.meta["ego_limits"] = asdict(cfg.ego)
        collisions = CollisionBook(self.rec, cfg.collision_gap, world.party_state)
        if cfg.conflicts.enabled:
            self.conflicts = ConflictBook(self.rec, cfg.conflicts, dt)
            self.rec.record_conflicts()
        self._start_pairs(world, dt)
        half = float(snap.ego.length[0]) / 2
        s, d = route.path.project_point(float(snap.ego.x[0]), float(snap.ego.y[0]))
        progress = _progress(cfg.progress, snap.time, end)
        history = History(dt) if getattr(controller, "needs_history", False) else None
        rules = RuleMonitor() if getattr(controller, "needs_rules", False) else None
        hooks = self.hooks + ((rules,) if rules is not None else ())  # the rule breakers of this step: a hook too
        try:
            while True:
                t = snap.time
                self.meta["last_time"] = t
                if t >= end - 1e-9:
                    self.status, self.message = RunStatus.TIMEOUT, f"time limit {format_time(end)} reached"
                    self._held(snap, route, s, half)
                    return
                w0 = wallclock.perf_counter()
                try:
                    for hook in hooks:  # e.g. a CommonRoad replay; the rule breakers
                        hook.on_read(snap, world)
                except StopRun as stop:
                    self._stopped(stop, snap, route, s, half)
                    return
                # read
                obs = None
                if history is not None:
                    history.push(snap.others)
                    obs = history.observation(t, snap.ego, snap.others)
                scene = Scene(time=t, dt=dt, ego=snap.ego, others=snap.others, route=route, s=s, d=d,
                              stop_s=self.stop_line(s + half), vehicle=cfg.ego, history=obs,
                              rule_breakers=rules.current if rules is not None else frozenset(),
                              desired_speed=self._desired_speed(t, s))
                for hook in hooks:  # e.g. hazards injected relative to the ego, for this step
                    hook.before_act(scene)
                # act
                decision = controller.act(scene)
                self.n_fallback += int(decision.info.get("n_fallback", 0))
                w1 = wd = wallclock.perf_counter()
                if self.view is not None:  # drawn before the step that carries it out
                    self.view.decided(decision)
                    wd = wallclock.perf_counter()
                # step
                world.step(decision.command)
                w2 = wallclock.perf_counter()
                self.step += 1
                new = world.read()
                if new is None:
                    # SUMO removes a vehicle that passes its route's end: within one step of travel
                    # of our goal that is arrival, anywhere else a failure
                    reach = s + half + max(float(snap.ego.speed[0]), decision.command.speed) * dt + 1.0
                    if reach >= route.length - 0.5:
                        self.status, self.message = self._route_end(t + dt)
                        return
                    raise SimulationError(f"the ego '{world.ego_id}' left the simulation at t={t + dt:g} s "
                                          f"{route.length - s - half:.1f} m before its goal")
                w3 = wallclock.perf_counter()
                # detect
                ctx = FaultContext.of_step(decision.info, float(snap.ego.speed[0]), float(new.ego.speed[0]), dt,
                                           cfg.ego.max_decel, scene.rule_breakers, new.time, self.ran_red_at)
                ego_hit = collisions.detect(snap, new, self.step, ctx)
                if ego_hit and self.view is not None:
                    self.view.collided(self.rec.collisions)
                w4 = wallclock.perf_counter()
                if self.conflicts is not None:
                    self.conflicts.observe(new, self.step)
                w5 = wallclock.perf_counter()
                others_ms = (self._observe_pairs(self.pairs, new.time, frozenset((world.ego_id,)))
                             if self.pairs is not None else None)
                # record
                s, d = route.path.project_point(float(new.ego.x[0]), float(new.ego.y[0]),
                                                near=(s - 5.0, s + 5.0 + 50.0 * dt))
                if self.red_s is not None and s + half > self.red_s + 0.5:  # passed a stop line showing red
                    self.ran_red_at = new.time  # (known from the next step's collisions on)
                row, timing = self._rows(new, snap, decision, s, d, dt, (w1 - w0, w2 - wd, w3 - w2, w4 - w3),
                                         scene.stop_s)
                timing["record_ms"] = 1e3 * (wallclock.perf_counter() - w5) - (others_ms or 0.0)
                if self.conflicts is not None:
                    timing["conflict_ms"] = 1e3 * (w5 - w4)
                if others_ms is not None:
                    timing["conflict_others_ms"] = others_ms
                # flushes a chunk every CHUNK_SECONDS of simulated time; keeps the decision by mode
                self.rec.step(row, timing, decision.trace, t, ego_hit)
                notes.step(row["time"], s, row["speed"], row["n_neighbours"], row["stop_s"], row["lane"],
                           row.get("validity", float("nan")))
                try:
                    seen = MappingProxyType(row)  # read only: the row is recorded already
                    for hook in hooks:
                        hook.after_step(new, world, seen)
                except StopRun as stop:
                    self._stopped(stop, new, route, s, half)
                    return
                snap = new
                if progress is not None and self.step % 50 == 0:
                    progress[0].update(progress[1], completed=min(snap.time, end))
                if ego_hit and cfg.stop_at_collision:
                    first = collisions.first_booked()
                    if first is None:  # ego_hit: detect booked the ego's collision
                        raise RuntimeError("the ego's collision is not in the collision book")
                    self.status = RunStatus.COLLISION
                    self.message = f"ego collided with {first['class_b']} '{first['id_b']}' at t={format_time(first['time'])}"
                    return
                if s + half >= route.length - 0.5:
                    self.status, self.message = self._route_end(snap.time)
                    return
        finally:
            self.meta["loop_wall"] = wallclock.perf_counter() - self.t_start  # s, before outputs are written
            if progress is not None:
                progress[0].stop()

    def _stopped(self, stop: StopRun, snap: Snapshot, route: Any, s: float, half: float) -> None:
        """A hook ended the run (:class:`StopRun`): its status and message, and at a timeout what
        held the ego."""
        self.status, self.message = stop.status, stop.message
        if stop.status is RunStatus.TIMEOUT:  # e.g. a CommonRoad goal's last time step
            self._held(snap, route, s, half)

    def _held(self, snap: Snapshot, route: Any, s: float, half: float) -> None:
        """A timeout: what held the ego (summary.json ``held``, sumo_ethics.notes.held), the words
        appended to the run's message."""
        if self.notes is None:
            return
        front = s + half
        line = self.stop_line(front)
        red = None
        if line is not None:
            red = {"distance": max(line - front, 0.0), "phase_ends": self.world.red_phase_end()}
        o = snap.others
        blocker = None
        if len(o):
            ps, pd = route.path.project(np.stack([o.x, o.y], axis=-1))
            blocker = blocker_ahead(s, half, ps, pd, o.speed, o.length, o.ids,
                                    [RoadUserClass(int(c)).label for c in o.cls])
        h = held(self.notes, route.length - front, red, blocker)
        self.meta["held"] = h
        self.message = f"{self.message}; {h['says']}"

    def _start_pairs(self, types: SumoWorld, dt: float) -> None:
        """With ``[conflicts] everyone``: read every road user from the next step on, and book their
        pairs' conflicts (``types``: a world whose vType cache the reads share)."""
        if not self.cfg.conflicts.everyone:
            return
        from sumo_ethics.sim.everyone import Everyone

        self.everyone = Everyone(types)
        self.pairs = PairConflictBook(self.rec.others_sink, self.cfg.conflicts, dt)
        self.rec.record_conflicts_others()

    def _observe_pairs(self, pairs: PairConflictBook, t: float, egos: frozenset[str]) -> float:
        """The conflicts among every road user but ``egos`` after the step to time t [s] into
        ``pairs`` (self.pairs); the wall time it took [ms]."""
        w = wallclock.perf_counter()
        states, z = self.everyone.read()
        pairs.observe(t, self.step, states, z, egos)
        took = wallclock.perf_counter() - w
        self.pairs_wall += took
        return 1e3 * took

    def _pairs_summary(self) -> dict[str, Any]:
        """summary.json's ``conflicts_others``: the counts, and what measuring them cost."""
        if self.rec.conflicts_others is None:
            return {}
        cost = {} if self.pairs is None else {"steps": self.pairs.steps, "pairs_per_step": self.pairs.cost(),
                                              "ms_per_step": 1e3 * self.pairs_wall / max(self.pairs.steps, 1)}
        return {"conflicts_others": pair_counts(self.rec.conflicts_others) | cost}

    def _desired_speed(self, t: float, s: float) -> float | None:
        """The lowest of the speeds [m/s] the hooks ask the ego to aim at now (``desired_speed(t, s)``);
        None when none asks."""
        asked = [v for h in self.hooks if (v := h.desired_speed(t, s)) is not None]
        return min(asked) if asked else None

    def _route_end(self, t: float) -> tuple[RunStatus, str]:
        """How the run ends when the ego passes its route's end at time t: completed, unless a hook
        says otherwise (an imported CommonRoad scenario completes only in its goal region)."""
        for hook in self.hooks:
            ended = hook.route_end(t)
            if ended is not None:
                return ended
        return RunStatus.COMPLETED, f"goal reached at t={format_time(t)}"

    def _rows(self, now: Snapshot, before: Snapshot, decision: Any, s: float, d: float, dt: float,
              w: tuple[float, float, float, float], stop_s: float | None) -> tuple[dict, dict]:
        """This step's steps.parquet and timings.parquet rows."""
        row = step_row(self.step, now, before, decision, s, d, dt, self.world.sumo_lane(), stop_s)
        timing = {"step": self.step, "controller_ms": 1e3 * w[0], "sumo_ms": 1e3 * w[1], "read_ms": 1e3 * w[2],
                  "collision_ms": 1e3 * w[3]}
        timing.update(decision.timings_ms)
        return row, timing

    def finish(self, wall: float, error: BaseException | None) -> tuple[dict[str, Any], BaseException | None]:
        """Write the finished output files and ``summary.json``; the summary and the error to raise
        (an OutputError when the files could not be written)."""
        out = self.cfg.out
        if "config.json" in self.written:  # this run got as far as writing its folder
            try:
                self.rec.close()
            except OSError as exc:  # e.g. a full disk: the chunks written so far stay in partial/
                self.status, self.message = RunStatus.ERROR, f"cannot write the outputs to {out}: {exc.strerror or exc}"
                error = error if isinstance(error, KeyboardInterrupt) else OutputError(self.message)
            if not isinstance(error, KeyboardInterrupt):  # what was kept (the figures: drawn from the folder)
                self._decisions()
            data = self.summary(wall)
            try:
                write_json(out / "summary.json", data)
            except OSError as exc:
                data["message"] = f"cannot write the outputs to {out}: {exc.strerror or exc}"
                error = error if isinstance(error, KeyboardInterrupt) else OutputError(data["message"])
        else:
            data = {"status": self.status.value, "message": self.message}
        if self.replaced is not None and self.replaced.exists():  # the earlier run's outputs, now replaced
            shutil.rmtree(self.replaced, ignore_errors=True)
        return data, error

    def _decisions(self) -> None:
        """summary.json's ``decisions``: what the run kept (mode, steps, bytes, thinned). The run draws
        no figures: the collision snapshots are drawn from the run folder by
        :func:`sumo_ethics.analysis.explain.draw_snapshots` (``sumo-ethics run`` does when a run ends)."""
        log = self.rec.decisions
        if log is None:
            return
        self.meta["decisions"] = {"mode": log.mode, "steps": len(log.written), "bytes": log.bytes,
                                  "thinned": log.thinned}

    def summary(self, wall: float) -> dict[str, Any]:
        ego_rows, harm, faults = booked_outcome(self.rec.collisions)
        first, last = self.rec.first_step, self.rec.last_step
        return {
            "status": self.status.value,
            "message": self.message,
            "completed": self.status is RunStatus.COMPLETED,
            "collided": bool(ego_rows),
            "harm": harm,
            "collisions": {"ego": len(ego_rows),
                           "ego_unconfirmed": sum(r["detector"] == "sumo_unconfirmed" for r in self.rec.collisions),
                           "others": sum(not r["involves_ego"] for r in self.rec.collisions),
                           "fault": faults},
            **({"conflicts": conflict_counts(self.rec.conflicts)} if self.rec.conflicts is not None else {}),
            **self._pairs_summary(),
            "seed": self.cfg.seed,
            "steps": self.rec.n_steps,
            "n_fallback": self.n_fallback,
            "distance": float(last["s"] - first["s"]) if first is not None and last is not None else 0.0,  # set together
            "sim_time": float(last["time"]) if last is not None else None,
            "wall_time": wall,
            **{k: v for k, v in self.meta.items() if k != "last_time"},
            **(self.notes.summary(self.status is RunStatus.COMPLETED) if self.notes is not None else {}),
            **{k: v for h in self.hooks for k, v in h.summary().items()},
            "versions": {"sumo_ethics": __version__, "sumo": self.meta.get("sumo_version", "unknown"),
                         "python": platform.python_version(), "numpy": np.__version__},
        }


def stop_line(world: SumoWorld, s_front: float) -> tuple[float | None, float | None]:
    """(arc length of the next red/yellow stop line within 100 m ahead of the ego's front s_front
    [m] on its route, that arc length again if the line shows red), each None if there is none."""
    if world.route is None:
        raise RuntimeError("stop_line: the ego has no route before the takeover")
    for link in world.route.links:
        if link.s < s_front - 0.5:
            continue
        if link.s - s_front > 100.0:
            return None, None
        state = world.link_state(link)
        if state in STOP_STATES:
            return link.s, link.s if state in "rR" else None
    return None, None


def step_row(step: int, now: Snapshot, before: Snapshot, decision: Any, s: float, d: float, dt: float, lane: str,
             stop_s: float | None) -> dict[str, Any]:
    """One steps.parquet row: the ego after ``step`` (snapshot ``now``; ``before`` the one the
    ``decision`` was taken in), its Frenet s, d [m] on its route and SUMO lane, the step's
    decision's named numbers."""
    e, o = now.ego, now.others
    dist = np.hypot(o.x - e.x[0], o.y - e.y[0]) if len(o) else np.empty(0)
    row = {
        "step": step, "time": now.time, "x": float(e.x[0]), "y": float(e.y[0]), "yaw": float(e.yaw[0]),
        "speed": float(e.speed[0]), "speed_cmd": float(decision.command.speed), "speed_sumo": now.sumo_speed,
        "accel": (float(e.speed[0]) - float(before.ego.speed[0])) / dt, "s": s, "d": d,
        "lane": lane, "n_neighbours": len(o), "n_vru": int(VULNERABLE[o.cls].sum()),
        "min_distance": float(dist.min()) if len(dist) else float("nan"),
        "stop_s": float("nan") if stop_s is None else stop_s,
    }
    row.update(decision.info)
    return row


def _progress(enabled: bool, start: float, end: float) -> Any:
    if not enabled:
        return None
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    prog = Progress(TextColumn("[bold]simulating"), BarColumn(), TextColumn("{task.completed:.0f}/{task.total:.0f} s"),
                    TimeRemainingColumn(), transient=True)
    if not prog.console.is_terminal:
        return None
    task = prog.add_task("sim", total=end, completed=start)  # type: ignore[arg-type]  # rich: int, but a float works (update takes one)
    prog.start()
    return prog, task


def execute(r: Run, cfg: RunConfig) -> RunSummary:
    """Run ``r`` (a :class:`Run`, or a fleet's) to its end: outputs and summary written whatever
    happens, then the error raised (see :func:`run`)."""
    t0 = wallclock.perf_counter()
    error: BaseException | None = None
    with sigterm_as_interrupt():
        try:
            r.execute()
        except ConfigError:  # bad input: nothing was computed, leave the folder as it was
            if cfg.out.is_dir():
                discard_outputs(cfg.out, r.created_out, r.written + ([PARTIAL] if r.written else []),
                                r.replaced)  # partial/ is ours once we wrote
            raise
        except SumoEthicsError as exc:
            r.status, r.message, error = RunStatus.ERROR, str(exc), exc
        except OSError as exc:  # the outputs could not be written (a full disk)
            r.status, r.message = RunStatus.ERROR, f"cannot write the outputs to {cfg.out}: {exc.strerror or exc}"
            error = OutputError(r.message)
        except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM (Terminated)
            r.status, error = RunStatus.INTERRUPTED, exc
            how = "SIGTERM" if isinstance(exc, Terminated) else "Ctrl-C"
            r.message = f"interrupted by {how} at t={format_time(r.meta['last_time'])}" if "last_time" in r.meta else \
                f"interrupted by {how} before the ego's first step"
        except Exception as exc:  # a bug: the outputs and a summary are still written, then it is raised
            r.status, r.message, error = RunStatus.ERROR, f"internal error: {type(exc).__name__}: {exc}", exc
        with sigterm_deferred():  # a SIGTERM now waits until the outputs are whole
            data, error = r.finish(wallclock.perf_counter() - t0, error)
    if isinstance(error, KeyboardInterrupt) and (cfg.out / "summary.json").is_file():  # the command's line says so
        add_note(error, f"the steps so far and a summary (status interrupted) are written to {cfg.out}")
    if error is not None:
        raise error
    return RunSummary(r.status, r.message, cfg.out, data)
