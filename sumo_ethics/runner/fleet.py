"""Several egos in one run: ``run_fleet(cfg, controllers) -> RunSummary`` (``sumo-ethics run
--egos N``, ``--penetration P``, ``--ego ID --ego ID2``, ``--fleet ethical=0.5,ego=0.5``).

Which vehicles become egos: ``--egos`` inserts N of ours (departures spread evenly over the first
half of the run, routes drawn with the seed); ``--penetration`` takes over each eligible vehicle of
the scenario (a motor road vehicle without stops, :func:`sumo_ethics.sim.egos.eligible`) when it
departs, by its own seeded draw :func:`draw`: a vehicle's draw does not depend on the others, so
the egos at penetration 0.1 are among those at 0.25 (common random numbers across a sweep);
``--ego`` names vehicles. Each ego's planner is drawn by share (``--fleet``) from a second draw.

Each step every ego is driven as in the single-ego run (:mod:`sumo_ethics.runner`): read its scene
(its own context subscription: other egos are road users to it), act, command; then SUMO steps
once for all. The neighbours of all egos are predicted once per step in one batched call
(:class:`SharedPrediction`, over the union of what the egos see, egos included), each ego's planner
taking its own rows. Collisions are detected per ego with one book for the run: a collision of two
egos is one event (party a is the ego whose check ran first) with the harm to both booked to
egos (:func:`fleet_booking`); collisions of other road users from SUMO's reports. An ego that
reaches its goal is handed back to SUMO for its last metres (its trip ends in SUMO's tripinfo); one
that collides is taken off the road (with ``--continue-after-collision`` it drives on); one SUMO
starts to teleport is handed back and named in the summary. The run ends at ``--end`` (or the
scenario's end, or when SUMO has nobody left). Every trip of the run, egos or not, goes to
``trips.parquet`` from SUMO's tripinfo. Each ego keeps its planner's decisions by
``--record-decisions`` as the single ego does, in its own log and folder
(``RUN/decisions/<ego folder>/``, :func:`sumo_ethics.record.decisions.ego_folder`), dropped when it
ends; each ego party of a collision gets its own snapshot figure (drawn from the folder after the run).
"""

from __future__ import annotations

import threading
import time as wallclock
import zlib
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Hashable

import numpy as np

from sumo_ethics import cores, heap
from sumo_ethics.collision import CollisionBook, booked_outcome, is_booked
from sumo_ethics.config import FLEET_CONTROLLERS, FleetSpec, RunConfig
from sumo_ethics.errors import ConfigError, SumoEthicsError
from sumo_ethics.contract import Controller, Decision, Scene
from sumo_ethics.plan.history import History
from sumo_ethics.record import schema
from sumo_ethics.record.decisions import FOLDER as DECISIONS, DecisionLog, ego_folder
from sumo_ethics.record.writer import ChunkedTable
from sumo_ethics.runner.loop import Run, RunSummary, _progress, execute, step_row, stop_line
from sumo_ethics.safety.conflicts import ConflictBook, conflict_counts
from sumo_ethics.safety.fault import FaultContext
from sumo_ethics.sim import egos as sim_egos, scenario as scenario_files, session
from sumo_ethics.sim.ego import ego_limits
from sumo_ethics.sim.rules import RuleMonitor
from sumo_ethics.sumo_options import format_time
from sumo_ethics.sim.world import Snapshot, SumoWorld
from sumo_ethics.types import AgentStates, Observation, Prediction, RoadUserClass, RunStatus

#: the prefix of inserted egos' ids (``fleet_ego_0`` ...)
INSERTED_PREFIX = "fleet_ego_"
#: simulated seconds between two returns of the C heap's free pages to the system (:func:`sumo_ethics.heap.trim`):
#: without them glibc keeps what the egos that came and went freed, some 6 MB per 100 s (issue 39)
TRIM_EVERY = 10.0
#: collisions.parquet of a fleet run: which parties were egos
COLLISIONS = schema.COLLISIONS.append(schema.pa.field("ego_a", schema.pa.bool_())).append(
    schema.pa.field("ego_b", schema.pa.bool_()))

#: steps.parquet and timings.parquet of a fleet run: one row per ego per step, named by the ego
STEPS = schema.pa.schema([("ego_id", schema.pa.string()), ("planner", schema.pa.string())] + list(schema.STEPS_BASE))
TIMINGS = schema.pa.schema([("ego_id", schema.pa.string())] + list(schema.TIMINGS_BASE))


# ---- who becomes an ego, with which planner -------------------------------------------------------
def draw(seed: int, stream: int, vid: str) -> float:
    """A uniform number in [0, 1) for vehicle ``vid``, fixed by (seed, stream, id) alone; stream 0
    decides penetration, stream 1 the planner."""
    return float(np.random.default_rng([seed, stream, zlib.crc32(vid.encode())]).random())


def planner_of(seed: int, vid: str, shares: tuple[tuple[str, float], ...]) -> str:
    """The fleet planner of ego ``vid``: the share interval its draw falls in (in the order given)."""
    u, acc = draw(seed, 1, vid), 0.0
    for name, share in shares:
        acc += share
        if u < acc:
            return name
    return next(n for n, s in reversed(shares) if s > 0)


def inserted_departs(n: int, begin: float, end: float, dt: float) -> list[float]:
    """Departure times [s] of n inserted egos: evenly over the first half of the run, on steps."""
    return [begin + round(i * (end - begin) / (2 * n) / dt) * dt for i in range(n)]


def check_fleet_names(spec: FleetSpec) -> None:
    """ConfigError for a ``--fleet`` name that is neither a weight preset nor a known controller."""
    from sumo_ethics.ethics.cost import PRESETS

    named = [n for n, _ in spec.planners]
    for name, _ in spec.shares:
        if name not in PRESETS and name not in FLEET_CONTROLLERS and name not in named:
            raise ConfigError(f"--fleet: unknown planner '{name}'; known: "
                              f"{', '.join(sorted(PRESETS) + list(FLEET_CONTROLLERS) + named)} "
                              "(names of [planners.NAME] tables of --config too)")


def make_fleet_controllers(cfg: RunConfig) -> Callable[[str, str], Controller]:
    """A factory: (fleet planner name, ego id) -> a new controller for that ego. The ethical planners share
    one predictor per predictor setting (loaded once), wrapped in a :class:`SharedPrediction`, when the
    predictor registry says it may be shared (:attr:`sumo_ethics.predict.registry.Entry.shareable`);
    else each ego gets its own."""
    from sumo_ethics.ethics.cost import PrincipleWeights
    from sumo_ethics.plan.baseline import RouteFollower
    from sumo_ethics.plan.ethical import EthicalPlanner, PlannerConfig, make_predictor
    from sumo_ethics.predict import registry
    from sumo_ethics.sim.lanes import SumoMapSource
    from sumo_ethics.sim.sight import sight_map

    spec = cfg.fleet
    assert spec is not None
    check_fleet_names(spec)
    base = cfg.planner or PlannerConfig()
    shared: dict[tuple, SharedPrediction] = {}

    named = dict(spec.planners)

    def make(name: str, vid: str = "") -> Controller:
        if name in named:  # a [planners.NAME] table of --config (before the presets of the same name)
            pc = named[name]
        elif name == "baseline":
            return RouteFollower()
        else:
            pc = replace(base, cost=replace(base.cost, weights=PrincipleWeights.preset(name)))
        key = (pc.predictor, pc.predictor_weights, pc.calibrated)
        if not registry.get(pc.predictor).shareable:  # one of its own, outside the step's batched prediction
            return EthicalPlanner(pc, predictor=make_predictor(*key, maps=SumoMapSource), sight=sight_map)
        if key not in shared:
            shared[key] = SharedPrediction(make_predictor(*key, maps=SumoMapSource))
        shared[key].horizons.add(max(pc.sampling.horizons))
        return EthicalPlanner(pc, predictor=shared[key], sight=sight_map)  # each ego its own sensor view

    make.shared = shared  # type: ignore[attr-defined]  # the factory carries its predictions (FleetRun reads them)
    for name, share in spec.shares:  # a bad weights file fails before SUMO starts
        if share > 0 and (name != "baseline" or name in named):
            make(name)
    return make


class SharedPrediction:
    """One batched prediction per step for every ego's neighbours, and the egos' shared plans.

    :meth:`begin` hands it the step's union observation (every road user some ego sees, the egos
    too); the first ``predict`` of a step with a horizon predicts them all at once, every call
    returns the rows of the agents it asks for. Everything else is the wrapped predictor's.

    Plan sharing (``[planner] share_plans``): a planner :meth:`publish` es its committed plan; from
    the next step on, every ego sharing plans predicts that ego by its plan instead of the model:
    one mode, the plan's centre positions and headings from now on (past its end, on at its last
    speed and heading), with a tracking spread of :data:`PLAN_SIGMA0` + :data:`PLAN_SIGMA_RATE` x t
    [m] along and across (the ego may replan within its limits). Plans of the step are used from
    the next step, so the order in which the egos act changes nothing.
    """

    def __init__(self, base: Any) -> None:
        self.base = base
        self.obs: Observation | None = None
        self.index: dict[str, int] = {}
        self.cache: dict[tuple, Any] = {}  # this step's predictions, by horizon, dt, plans (and prepare's key)
        self.calls = 0  # batched predictions made
        self.plans: dict[str, tuple[float, np.ndarray, np.ndarray, np.ndarray]] = {}  # published this step
        self.shared: dict[str, tuple[float, np.ndarray, np.ndarray, np.ndarray]] = {}  # usable this step
        self.horizons: set[float] = set()  # [s] the horizons of the planners using it (see fill)
        self.lock = threading.RLock()  # prepared() computes under it and calls _union, which takes it too

    def __getattr__(self, name: str) -> Any:  # kind, path, model, calibration ...
        return getattr(self.base, name)

    def begin(self, obs: Observation) -> None:
        self.obs, self.index, self.cache = obs, obs.current.index, {}
        self.shared = {k: v for k, v in {**self.shared, **self.plans}.items() if k in self.index}
        self.plans = {}

    def fill(self, dt: float) -> None:
        """Predict the step's union for every horizon of :attr:`horizons` now (in the thread that
        may read SUMO), so the planners' calls only take rows."""
        for h in sorted(self.horizons):
            self._base(int(round(h / dt)), dt)

    def _base(self, horizon_steps: int, dt: float) -> Prediction:
        assert self.obs is not None
        key = (horizon_steps, float(dt), False)
        with self.lock:
            if key not in self.cache:
                self.cache[key] = self.base.predict(self.obs, horizon_steps, dt)
                self.calls += 1
            return self.cache[key]

    def publish(self, ego_id: str, time: float, x: np.ndarray, y: np.ndarray, yaw: np.ndarray) -> None:
        """Ego ``ego_id``'s committed plan, chosen at ``time`` [s]: its centre x, y [m] and heading [rad]
        at time + dt, time + 2 dt, ... (T,) each."""
        self.plans[ego_id] = (float(time), np.asarray(x, float), np.asarray(y, float), np.asarray(yaw, float))

    def predict(self, obs: Observation, horizon_steps: int, dt: float, plans: bool = False) -> Prediction:
        if self.obs is None:
            return self.base.predict(obs, horizon_steps, dt)
        return self._union(horizon_steps, dt, plans).take([self.index[k] for k in obs.current.ids])

    def _union(self, horizon_steps: int, dt: float, plans: bool) -> Prediction:
        """The step's prediction of the whole union (with the shared plans' rows where ``plans``)."""
        pred = self._base(horizon_steps, dt)
        if plans:
            key = (horizon_steps, float(dt), True)
            with self.lock:
                if key not in self.cache:
                    self.cache[key] = self._with_plans(pred, dt)
                pred = self.cache[key]
        return pred

    def prepared(self, obs: Observation, horizon_steps: int, dt: float, plans: bool, key: Hashable,
                 prepare: Callable[[Prediction, Observation], tuple[Prediction, np.ndarray]]) -> tuple[Prediction, int] | None:
        """A planner's prediction after its own per-agent steps (priors, fallbacks), done once per step for
        the whole union: ``prepare`` (union prediction, union observation) -> (prediction, (N,) bool rows it
        replaced), cached under ``key`` (the planner's settings that shape it); returns the rows of
        ``obs``' agents and how many of them were replaced. ``prepare`` must treat each agent on its
        own (the rows are then what the planner's own call would give); None before the first step."""
        if self.obs is None:
            return None
        ck = ("prepared", horizon_steps, float(dt), plans, key)
        with self.lock:
            if ck not in self.cache:
                self.cache[ck] = prepare(self._union(horizon_steps, dt, plans), self.obs)
            pred, replaced = self.cache[ck]
        rows = [self.index[k] for k in obs.current.ids]
        return pred.take(rows), int(replaced[rows].sum())

    def _with_plans(self, pred: Prediction, dt: float) -> Prediction:
        """``pred`` with the rows of the egos whose plans are shared replaced by them (one mode)."""
        rows = [(self.index[k], v) for k, v in sorted(self.shared.items())]
        if not rows:
            return pred
        assert self.obs is not None
        now = self.obs.time
        H = pred.mean.shape[1]
        t = dt * np.arange(1, H + 1)
        sig = PLAN_SIGMA0 + PLAN_SIGMA_RATE * t
        mean, cov, yaw = pred.mean.copy(), pred.cov.copy(), pred.yaw.copy()
        weight = None if pred.weight is None else pred.weight.copy()
        for i, (t0, x, y, h) in rows:
            m = int(round((now - t0) / dt))  # plan step i holds time t0 + (i + 1) dt; now + (j + 1) dt is step m + j
            idx = m + np.arange(H)
            last = len(x) - 1
            inside = np.minimum(idx, last)
            beyond = np.maximum(idx - last, 0) * dt  # [s] past the plan's end
            speed = np.hypot(x[last] - x[last - 1], y[last] - y[last - 1]) / dt if last > 0 else 0.0
            mean[i, :, 0] = x[inside] + beyond * speed * np.cos(h[last])
            mean[i, :, 1] = y[inside] + beyond * speed * np.sin(h[last])
            yaw[i] = h[inside]
            cov[i] = (sig**2)[:, None, None] * np.eye(2)
            if weight is not None:
                weight[i] = 0.0
                weight[i, 0] = 1.0
        main = Prediction(pred.ids, pred.dt, mean, cov, yaw)
        if pred.weight is None:
            return main
        alts = tuple(Prediction(a.ids, a.dt, *_rows_from(a, main, [i for i, _ in rows])) for a in pred.alternatives)
        return Prediction(pred.ids, pred.dt, mean, cov, yaw, alts, weight)


#: a shared plan's tracking spread: standard deviation along and across, sigma0 + rate x t [m, m/s]
PLAN_SIGMA0, PLAN_SIGMA_RATE = 0.1, 0.3


def _rows_from(mode: Prediction, main: Prediction, rows: list[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``mode``'s mean, cov, yaw with ``rows`` taken from ``main`` (a weight-0 mode keeps the plan's shape)."""
    mean, cov, yaw = mode.mean.copy(), mode.cov.copy(), mode.yaw.copy()
    mean[rows], cov[rows], yaw[rows] = main.mean[rows], main.cov[rows], main.yaw[rows]
    return mean, cov, yaw


def union_states(parts: list[AgentStates]) -> AgentStates:
    """The agents of ``parts`` once each (the first state seen of an id), sorted by id."""
    ids = np.array([k for s in parts for k in s.ids], dtype=str)
    if not len(ids):
        return AgentStates.empty()
    uniq, first = np.unique(ids, return_index=True)  # sorted, and where each id is seen first

    def col(name: str) -> np.ndarray:
        return np.concatenate([getattr(s, name) for s in parts])[first]

    types = [t for s in parts for t in s.type_id]
    return AgentStates.trusted(tuple(uniq.tolist()), col("x"), col("y"), col("yaw"), col("speed"), col("accel"),
                               col("length"), col("width"), col("mass"), col("cls"), tuple(types[i] for i in first))


def _decide(ctl: Controller, scene: Scene) -> tuple[Decision | None, float, Exception | None]:
    """(decision, wall time [ms], the exception it raised) of one ego's controller."""
    w = wallclock.perf_counter()
    try:
        return ctl.act(scene), 1e3 * (wallclock.perf_counter() - w), None
    except Exception as exc:  # noqa: BLE001 - reported by the caller, for that ego alone
        return None, 0.0, exc


# ---- booking ------------------------------------------------------------------------------------
def fleet_booking(row: dict[str, Any], egos: set[str] | frozenset[str]) -> dict[str, Any]:
    """Which parties of a collision row were egos, and its harm booked per class for a fleet:
    ``harm_ego`` the harm to every ego party (both of an ego-ego collision, once),
    ``harm_third_party`` to a party that is not an ego, ``harm_vru`` its part to a VRU."""
    ego_a, ego_b = row["id_a"] in egos, row["id_b"] in egos
    if not is_booked(row):
        return {"ego_a": ego_a, "ego_b": ego_b, "harm_ego": 0.0, "harm_third_party": 0.0, "harm_vru": 0.0}
    vru = RoadUserClass[row["class_b"].upper()].is_vulnerable
    return {"ego_a": ego_a, "ego_b": ego_b, "harm_ego": row["harm_a"] + (row["harm_b"] if ego_b else 0.0),
            "harm_third_party": 0.0 if ego_b else row["harm_b"], "harm_vru": row["harm_b"] if vru and not ego_b else 0.0}


class _FleetCollisions:
    """The run recorder as a collision sink whose rows carry the fleet booking."""

    def __init__(self, rec: Any, egos: set[str]) -> None:
        self.rec, self.egos = rec, egos

    @property
    def collisions(self) -> list[dict[str, Any]]:
        return self.rec.collisions

    def add_collision(self, row: dict[str, Any]) -> int:
        return self.rec.add_collision(row | fleet_booking(row, self.egos))

    def update_collision(self, index: int, **changes: Any) -> None:
        self.rec.update_collision(index, **changes)
        self.rec.update_collision(index, **fleet_booking(self.rec.collisions[index], self.egos))


class _ConflictRows:
    """One ego's ConflictBook sink inside the run's: its rows numbered among all egos' rows."""

    def __init__(self, rec: Any) -> None:
        self.rec = rec
        self.where: list[int] = []  # the run's row of each of this ego's conflicts

    def add_conflict(self, row: dict[str, Any]) -> int:
        self.where.append(self.rec.add_conflict(row | {"event": len(self.rec.conflicts or [])}))
        return len(self.where) - 1

    def update_conflict(self, index: int, **changes: Any) -> None:
        self.rec.update_conflict(self.where[index], **changes)


# ---- one ego ------------------------------------------------------------------------------------
@dataclass
class Agent:
    """One ego of the fleet and its driving state."""

    id: str
    planner: str
    inserted: bool
    controller: Controller
    world: SumoWorld
    takeover_time: float
    vehicle: Any = None  # EgoVehicle limits
    route_length: float = 0.0  # m, of its reference path
    speed_factor: float = 1.0  # its own speedFactor before the takeover (given back with it)
    snap: Snapshot | None = None  # None until the first read after the takeover
    s: float = 0.0
    d: float = 0.0
    s0: float = float("nan")  # s at the first read
    half: float = 0.0
    rules: RuleMonitor | None = None
    conflicts: ConflictBook | None = None
    red_s: float | None = None
    ran_red_at: float = -float("inf")
    status: str = "driving"
    message: str = ""
    end_time: float | None = None
    steps: int = 0
    collisions: int = 0
    n_fallback: int = 0
    decision: Decision | None = None
    scene: Scene | None = None
    log: DecisionLog | None = None  # its recorded decisions (None once it ended: ``kept`` says what it kept)
    kept: dict[str, Any] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)

    def decisions(self) -> dict[str, Any]:
        """What its log kept: mode, steps, bytes, risky steps thinned, and the folder if any."""
        log = self.log
        if log is None:
            return self.kept
        return {"mode": log.mode, "steps": len(log.written), "bytes": log.bytes, "thinned": log.thinned,
                **({"folder": f"{DECISIONS}/{ego_folder(self.id)}"} if log.written else {})}

    def record(self) -> dict[str, Any]:
        return {"id": self.id, "planner": self.planner, "inserted": self.inserted, "status": self.status,
                "message": self.message, "takeover_time": self.takeover_time, "end_time": self.end_time,
                "steps": self.steps, "distance": 0.0 if self.s0 != self.s0 else float(self.s - self.s0),
                "route_length": self.route_length,
                "collisions": self.collisions, "n_fallback": self.n_fallback, "decisions": self.decisions()}


class FleetRun(Run):
    """State of one fleet run; :meth:`execute` (Run's) sets up SUMO, :meth:`_loop` drives the egos."""

    def __init__(self, cfg: RunConfig, make: Callable[[str, str], Controller]) -> None:
        super().__init__(cfg, controller=None, hooks=())
        if cfg.fleet is None:
            raise ValueError("FleetRun needs a fleet (RunConfig.fleet)")
        self.make = make
        self.spec: FleetSpec = cfg.fleet
        self.agents: list[Agent] = []
        self.active: list[Agent] = []
        self.egos: set[str] = set()
        self.wanted: dict[str, bool] = {}  # id -> inserted by us (else named by --ego)
        self.considered = 0  # vehicles of the scenario drawn for penetration
        self.eligible = 0
        self.teleported: list[str] = []
        self.refused: dict[str, str] = {}  # vehicles whose takeover failed -> why (SUMO drove them on)

    def _loop(self, ego_id: str, end: float, depart: float) -> None:
        cfg, spec = self.cfg, self.spec
        dt = session.step_length()
        self.rec.start(dt, cfg.record_decisions, per_ego=True)
        self.rec.collision_schema = COLLISIONS
        self.rec.tables["steps"] = ChunkedTable(self.rec.partial, "steps", STEPS)
        self.rec.tables["timings"] = ChunkedTable(self.rec.partial, "timings", TIMINGS)
        sink = _FleetCollisions(self.rec, self.egos)
        types = SumoWorld("", cfg.sensing_radius)  # its vType cache and party_state
        self.book = CollisionBook(sink, cfg.collision_gap, types.party_state)
        if cfg.conflicts.enabled:
            self.rec.record_conflicts()
        self._start_pairs(types, dt)
        t = session.sim_time()
        inserted = [f"{INSERTED_PREFIX}{i}" for i in range(spec.egos)]
        if inserted:
            routes = sim_egos.insert_egos(inserted, inserted_departs(spec.egos, t, end, dt), cfg.seed, cfg.ego,
                                           cfg.min_route_length, cfg.ego_depart_lane)
            self.meta["inserted_routes"] = {k: len(v) for k, v in routes.items()}
        self.wanted = {k: True for k in inserted} | {k: False for k in spec.ids}
        self.union_history = History(dt)
        shared = list(getattr(self.make, "shared", {}).values())
        self.meta.update(step_length=dt, takeover_time=t, controller="fleet",
                         takeover_wall=wallclock.perf_counter() - self.t_start)
        progress = _progress(cfg.progress, t, end)
        next_trim = t + TRIM_EVERY
        try:
            while True:
                t = session.sim_time()
                self.meta["last_time"] = t
                if t >= next_trim - 1e-9:  # the heap the ended egos left free goes back to the system
                    heap.trim()
                    next_trim += TRIM_EVERY
                if t >= end - 1e-9 or (t > self.meta["takeover_time"] and sim_egos.pending() == 0):
                    self.status = RunStatus.COMPLETED
                    self.message = (f"time limit {format_time(end)} reached" if t >= end - 1e-9 else
                                    f"every trip ended at t={format_time(t)}")
                    for a in self.active:
                        a.status, a.message, a.end_time = "timeout", self.message, t
                    return
                w0 = wallclock.perf_counter()
                acting = [a for a in self.active if a.snap is not None]
                self._share_prediction(acting, shared, t, dt)
                self._act_all(acting, t, dt)
                for a in self.active:
                    a.world.command(a.decision.command if a.decision is not None and a.snap is not None else None)
                w1 = wallclock.perf_counter()
                sim_egos.advance()
                self.step += 1
                w2 = wallclock.perf_counter()
                now = session.sim_time()
                self._observe_all(now, dt, (w1 - w0, w2 - w1))
                for vid in sim_egos.departed():
                    self._maybe_take_over(vid, now, end)
                if progress is not None and self.step % 50 == 0:
                    progress[0].update(progress[1], completed=min(now, end))
        finally:
            self.meta["loop_wall"] = wallclock.perf_counter() - self.t_start
            self.meta["shared_predictions"] = sum(p.calls for p in shared)
            self.meta["vclass_of"] = sim_egos.vclasses()
            if progress is not None:
                progress[0].stop()

    # -- per step -----------------------------------------------------------------------------------
    def _share_prediction(self, acting: list[Agent], shared: list[SharedPrediction], t: float, dt: float) -> None:
        """The union of what the acting egos see (and the egos) into the history, every step (an
        empty one when nobody acts: a road user's rows keep their times), and the step's
        observation of it for the shared predictions, predicted here (the map source reads SUMO,
        which only this thread may call)."""
        snaps = [a.snap for a in acting if a.snap is not None]  # all: the acting egos were read
        union = union_states([s.ego for s in snaps] + [s.others for s in snaps])
        self.union_history.push(union)
        self._union_obs = obs = self.union_history.observation(t, AgentStates.empty(), union)
        for p in shared:
            p.begin(obs)
            if acting:
                p.fill(dt)

    def _act_all(self, acting: list[Agent], t: float, dt: float) -> None:
        """Every acting ego's decision: the scenes read here (SUMO: traffic lights), the planners run
        on :func:`sumo_ethics.cores.threads` threads (each ego's planning is its own; they touch no
        SUMO), the results taken in the egos' order: the same outputs with any number of threads."""
        scenes = [self._scene(a, t, dt) for a in acting]
        results = cores.map_ordered(_decide, [(a.controller, sc) for a, sc in zip(acting, scenes)])
        for a, (decision, ms, exc) in zip(acting, results):
            if exc is not None or decision is None:  # one ego's failure must not end everyone's run
                a.decision = None
                self._end(a, "error", f"its planner failed at t={format_time(t)}: {type(exc).__name__}: {exc}; "
                                      "handed back to SUMO", t)
                sim_egos.release(a.id, a.speed_factor)
                continue
            a.decision = decision
            a.extra["controller_ms"] = ms
            a.n_fallback += int(decision.info.get("n_fallback", 0))

    def _scene(self, a: Agent, t: float, dt: float) -> Scene:
        snap, route = a.snap, a.world.route
        if snap is None or route is None:  # only egos read after their takeover act
            raise RuntimeError(f"ego {a.id} acts before its first read")
        obs = None
        if getattr(a.controller, "needs_history", False):
            u = self._union_obs
            idx = [u.current.index[k] for k in snap.others.ids]
            obs = Observation(time=t, dt=dt, history=u.history[idx], valid=u.valid[idx], current=snap.others,
                              ego=snap.ego)
        line, a.red_s = stop_line(a.world, a.s + a.half)
        if a.rules is not None:  # the ego's one hook: its rule breakers (a fleet run takes no others)
            a.rules.on_read(snap, a.world)
        a.scene = Scene(time=t, dt=dt, ego=snap.ego, others=snap.others, route=route, s=a.s, d=a.d,
                        stop_s=line, vehicle=a.vehicle, history=obs,
                        rule_breakers=a.rules.current if a.rules is not None else frozenset())
        return a.scene

    def _observe_all(self, now: float, dt: float, w: tuple[float, float]) -> None:
        """After a step: read every ego, give each ego's own state to the others' views of it, then
        each ego's collisions, conflicts and steps row; the others' collisions; the egos' ends."""
        gone = sim_egos.teleporting() & self.egos
        reports = tuple(sim_egos.sumo_collisions())
        rows_before = len(self.rec.collisions)
        read: list[tuple[Agent, Snapshot]] = []
        for a in list(self.active):
            new = self._read(a, now, dt, gone)
            if new is not None:
                read.append((a, new))
        own = {a.id: new.ego for a, new in read}
        checked: set[str] = set()  # egos whose collisions and conflicts were measured this step
        hit: set[str] = set()
        for a, new in read:
            new = _with_own_states(new, own)
            if self._record(a, new, dt, w, checked):
                hit.add(a.id)
        if self.pairs is not None:  # every pair without an ego measured this step
            self._observe_pairs(self.pairs, now, frozenset(checked))
        # SUMO's reports of everyone else, egos driven by SUMO this step (just taken over, handed back) too
        self.book.detect_others(now, reports, self.step, frozenset(checked))
        for r in self.rec.collisions[rows_before:]:  # a new event names both egos (one detected it)
            if is_booked(r):
                hit.update(k for k in (r["id_a"], r["id_b"]) if k in checked)
        for a, _ in read:
            if a.id in hit:
                a.collisions += 1
                if a.log is not None:  # its decisions before impact, also when the other ego's check found it
                    a.log.collided(self.step)
                if self.cfg.stop_at_collision and a in self.active:
                    row = next(r for r in reversed(self.rec.collisions) if is_booked(r) and a.id in (r["id_a"], r["id_b"]))
                    other = row["id_b"] if row["id_a"] == a.id else row["id_a"]
                    self._end(a, "collision", f"collided with '{other}' at t={format_time(row['time'])}; "
                                              "taken off the road", now)
                    sim_egos.remove(a.id)
            if a.log is not None:  # its collisions are known: mode off lets go of the step's trace
                a.log.settled()
        for a, _ in read:
            if a in self.active and a.snap is not None and a.s + a.half >= a.route_length - 0.5:
                self._end(a, "completed", f"goal reached at t={format_time(now)}; handed back to SUMO", now)
                sim_egos.release(a.id, a.speed_factor)

    def _read(self, a: Agent, now: float, dt: float, gone: frozenset[str]) -> Snapshot | None:
        """Ego ``a``'s snapshot after the step, or None when it ended (teleported, left, arrived)
        or was read for the first time after its takeover."""
        before, decision = a.snap, a.decision
        if a.id in gone:
            self.teleported.append(a.id)
            self._end(a, "teleported", f"SUMO started to teleport it at t={format_time(now)}; handed back", now)
            sim_egos.release(a.id, a.speed_factor)
            return None
        new = a.world.read()
        if new is None:
            if before is None:
                self._end(a, "left", f"left the simulation right after the takeover (t={format_time(now)})", now)
                return None
            if decision is None:  # read before: it has acted since
                raise RuntimeError(f"ego {a.id} has no decision after its first read")
            reach = a.s + a.half + max(float(before.ego.speed[0]), decision.command.speed) * dt + 1.0
            if reach >= a.route_length - 0.5:
                self._end(a, "completed", f"goal reached at t={format_time(now)}", now)
            else:
                self._end(a, "left", f"left the simulation at t={format_time(now)} "
                                     f"{a.route_length - a.s - a.half:.1f} m before its goal", now)
            return None
        if before is None:  # the first read after the takeover
            if a.world.route is None:  # set by its takeover
                raise RuntimeError(f"ego {a.id} has no route after its takeover")
            a.vehicle = replace(a.vehicle, mass=float(new.ego.mass[0]))
            a.half = float(new.ego.length[0]) / 2
            a.s, a.d = a.world.route.path.project_point(float(new.ego.x[0]), float(new.ego.y[0]))
            a.s0 = a.s
            a.snap = new
            if self.cfg.conflicts.enabled:
                a.conflicts = ConflictBook(_ConflictRows(self.rec), self.cfg.conflicts, dt)
            return None
        return new

    def _record(self, a: Agent, new: Snapshot, dt: float, w: tuple[float, float], checked: set[str]) -> bool:
        """Ego ``a``'s collisions (True: a new one), conflicts and steps row of the step to ``new``."""
        before, decision, scene, route = a.snap, a.decision, a.scene, a.world.route
        if before is None or decision is None or scene is None or route is None:  # it acted on its last read
            raise RuntimeError(f"ego {a.id} is recorded without its last snapshot, scene and decision")
        w3 = wallclock.perf_counter()
        ctx = FaultContext.of_step(decision.info, float(before.ego.speed[0]), float(new.ego.speed[0]), dt,
                                   a.vehicle.max_decel, scene.rule_breakers, new.time, a.ran_red_at)
        hit = self.book.detect_ego(before, new, self.step, ctx)
        w4 = wallclock.perf_counter()
        if a.conflicts is not None:  # a pair of egos once: by the ego measured first this step
            keep = [i for i, k in enumerate(new.others.ids) if k not in checked]
            a.conflicts.observe(new if len(keep) == len(new.others) else
                                replace(new, others=new.others.take(keep)), self.step)
        checked.add(a.id)
        w5 = wallclock.perf_counter()
        a.s, a.d = route.path.project_point(float(new.ego.x[0]), float(new.ego.y[0]), near=(a.s - 5.0, a.s + 5.0 + 50.0 * dt))
        if a.red_s is not None and a.s + a.half > a.red_s + 0.5:
            a.ran_red_at = new.time
        row = {"ego_id": a.id, "planner": a.planner} | step_row(self.step, new, before, decision, a.s, a.d, dt,
                                                                  a.world.sumo_lane(), scene.stop_s)
        timing = {"ego_id": a.id, "step": self.step, "controller_ms": a.extra.get("controller_ms", 0.0),
                  "sumo_ms": 1e3 * w[1] / max(len(self.active), 1), "collision_ms": 1e3 * (w4 - w3),
                  "conflict_ms": 1e3 * (w5 - w4), "wall_s": w5 - self.t_start,
                  "fleet_plan_ms": 1e3 * w[0]} | decision.timings_ms
        self.rec.step(row, timing, decision.trace, before.time, hit, log=a.log)
        a.steps += 1
        a.snap = new
        return hit

    def _end(self, a: Agent, status: str, message: str, t: float) -> None:
        """Ego ``a`` is done: its status, and nothing of it kept but its record (memory stays flat
        however many egos come and go)."""
        a.status, a.message, a.end_time = status, message, t
        self.active.remove(a)
        # a finished ego lets go of its planner and world too (they are never read again)
        a.controller = a.world = a.snap = a.decision = a.scene = a.rules = None  # type: ignore[assignment]
        a.conflicts = None  # its rows are in the recorder; its trails go
        a.kept, a.log = a.decisions(), None  # its files are written; what it kept is counted

    def _maybe_take_over(self, vid: str, t: float, end: float) -> None:
        spec = self.spec
        if vid in self.wanted:
            inserted = self.wanted[vid]
        elif spec.penetration > 0.0:
            self.considered += 1
            if not sim_egos.eligible(vid):
                return
            self.eligible += 1
            if draw(self.cfg.seed, 0, vid) >= spec.penetration:
                return
            inserted = False
        else:
            return
        if not inserted and not sim_egos.eligible(vid):  # named by --ego
            self.refused[vid] = "not a motor road vehicle, or it has stops (the rules of --ego)"
            return
        name = planner_of(self.cfg.seed, vid, spec.shares)
        world = SumoWorld(vid, self.cfg.sensing_radius)
        factor = sim_egos.speed_factor(vid)
        refusals: tuple[type[BaseException], ...] = (SumoEthicsError, *session.SUMO_ERRORS)
        try:
            route = world.takeover()
        except refusals as exc:  # e.g. a route the planner cannot follow
            self.refused[vid] = str(exc)
            return
        sim_egos.hold_speed(vid)  # its first step, before its planner acts: no faster than now
        vehicle = self.cfg.ego if inserted else ego_limits(vid, self.cfg.ego)
        ctl = self.make(name, vid)
        a = Agent(vid, name, inserted, ctl, world, t, vehicle=vehicle, route_length=float(route.length),
                  speed_factor=factor, rules=RuleMonitor() if getattr(ctl, "needs_rules", False) else None,
                  log=self.rec.ego_log(vid))
        self.agents.append(a)
        self.active.append(a)
        self.egos.add(vid)

    # -- outputs ----------------------------------------------------------------------------------
    def finish(self, wall: float, error: BaseException | None) -> tuple[dict[str, Any], BaseException | None]:
        if "config.json" in self.written:
            self._trips()
        return super().finish(wall, error)

    def _decisions(self) -> None:
        """What the egos' logs kept (summary.json ``decisions``: the totals; each ego's in ``egos``).
        The figure of each ego party's last decision before each ego collision
        (RUN/snapshots/collision_<event>_<ego folder>.png) is drawn from the run folder afterwards
        (:func:`sumo_ethics.analysis.explain.draw_snapshots`)."""
        kept = [a.decisions() for a in self.agents]
        self.meta["decisions"] = {"mode": self.cfg.record_decisions, "steps": sum(k.get("steps", 0) for k in kept),
                                  "bytes": sum(k.get("bytes", 0) for k in kept),
                                  "thinned": sum(k.get("thinned", 0) for k in kept),
                                  "egos": sum(k.get("steps", 0) > 0 for k in kept)}

    def _trips(self) -> None:
        """trips.parquet from SUMO's tripinfo (written when SUMO closed)."""
        path = self.meta.get("tripinfo")
        if not path or not Path(path).is_file():
            return
        try:
            from sumo_ethics.record.trips import read_tripinfo, write_trips

            df = read_tripinfo(Path(path), self.egos, vclass_of=self.meta.get("vclass_of"))
            write_trips(df, self.cfg.out / "trips.parquet")
            veh = df[df["kind"] == "vehicle"]
            per = df[df["kind"] == "person"]
            self.meta["traffic"] = {
                "trips": int(len(df)), "vehicle_trips": int(len(veh)), "person_trips": int(len(per)),
                "arrived": int(df["arrived"].sum()), "vehicle_km": float(veh["distance"].sum() / 1e3),
                "person_km": float(per["distance"].sum() / 1e3),
                "time_loss_h": {"egos": float(veh.loc[veh["ego"], "time_loss"].sum() / 3600),
                                "other_vehicles": float(veh.loc[~veh["ego"], "time_loss"].sum() / 3600),
                                "persons": float(per["time_loss"].sum() / 3600)},
                # per trip that departed (a trip under way: its time loss so far), NaN for no trips
                "time_loss_mean_s": {"egos": _mean(veh.loc[veh["ego"], "time_loss"]),
                                     "other_vehicles": _mean(veh.loc[~veh["ego"], "time_loss"]),
                                     "persons": _mean(per["time_loss"])},
            }
        except Exception as exc:  # noqa: BLE001 - the trips must never cost the run's other outputs
            self.meta["trips_error"] = f"{type(exc).__name__}: {exc}"

    def summary(self, wall: float) -> dict[str, Any]:
        rows = self.rec.collisions
        booked, harm, faults = booked_outcome(rows)
        everyone = {"egos": 0.0, "other_vehicles": 0.0, "vru": 0.0}
        for r in rows:
            if r["detector"] == "sumo_unconfirmed":
                continue
            for p in "ab":
                who = "egos" if r[f"id_{p}"] in self.egos else "vru" if RoadUserClass[
                    r[f"class_{p}"].upper()].is_vulnerable else "other_vehicles"
                everyone[who] += float(r[f"harm_{p}"])
        everyone["total"] = sum(everyone.values())
        by_planner: dict[str, int] = {}
        for a in self.agents:
            by_planner[a.planner] = by_planner.get(a.planner, 0) + 1
        statuses: dict[str, int] = {}
        for a in self.agents:
            statuses[a.status] = statuses.get(a.status, 0) + 1
        spec = self.spec
        return {
            "status": self.status.value, "message": self.message,
            "completed": self.status is RunStatus.COMPLETED,
            "fleet": {"spec": asdict(spec), "egos": len(self.agents), "by_planner": by_planner, "by_status": statuses,
                      "inserted": sum(a.inserted for a in self.agents), "considered": self.considered,
                      "eligible": self.eligible, "teleported": self.teleported, "refused": self.refused,
                      "not_departed": sorted(k for k in self.wanted if k not in self.egos and k not in self.refused)},
            "harm": harm, "harm_everyone": everyone,
            "collisions": {"ego": len(booked), "ego_ego": sum(bool(r.get("ego_b")) for r in booked),
                           "ego_unconfirmed": sum(r["detector"] == "sumo_unconfirmed" for r in rows),
                           "others": sum(not r["involves_ego"] for r in rows),
                           "fault": faults},
            **({"conflicts": conflict_counts(self.rec.conflicts)} if self.rec.conflicts is not None else {}),
            **self._pairs_summary(),
            "seed": self.cfg.seed, "steps": self.step, "ego_steps": self.rec.n_steps,
            "n_fallback": sum(a.n_fallback for a in self.agents),
            "distance": float(sum(a.record()["distance"] for a in self.agents)),
            "sim_time": self.meta.get("last_time"), "wall_time": wall,
            **{k: v for k, v in self.meta.items() if k not in ("last_time", "vclass_of", "ego_id")},
            "egos": [a.record() for a in self.agents],
        }


def _with_own_states(snap: Snapshot, own: dict[str, AgentStates]) -> Snapshot:
    """``snap`` with each ego among its road users at the speed and acceleration that ego was placed
    with (its own read), not SUMO's re-derived ones (sim.world.SumoWorld.read)."""
    o = snap.others
    idx = [i for i, k in enumerate(o.ids) if k in own]
    if not idx:
        return snap
    speed, accel = o.speed.copy(), o.accel.copy()
    for i in idx:
        e = own[o.ids[i]]
        speed[i], accel[i] = e.speed[0], e.accel[0]
    return replace(snap, others=AgentStates.trusted(o.ids, o.x, o.y, o.yaw, speed, accel, o.length, o.width, o.mass,
                                                    o.cls, o.type_id))


def _mean(values: Any) -> float | None:
    """The mean of the known values, None (JSON null) for none."""
    v = values.dropna()
    return float(v.mean()) if len(v) else None


def run_fleet(cfg: RunConfig, make: Callable[[str, str], Controller] | None = None) -> RunSummary:
    """Run one scenario with the fleet ``cfg.fleet``; writes the run folder (the single-ego run's
    files, with ``ego_id`` and ``planner`` in steps.parquet, ``ego_a``/``ego_b`` in
    collisions.parquet, and trips.parquet) and returns the summary. Errors as :func:`runner.run`."""
    if cfg.fleet is None:
        raise ConfigError("run_fleet needs a fleet (cfg.fleet)")
    make = make or make_fleet_controllers(cfg)
    for k in cfg.fleet.ids:  # a vehicle named by --ego must be in the scenario's files
        scenario_files.check_ego_id(scenario_files.read_scenario(cfg.scenario), k)
    return execute(FleetRun(cfg, make), cfg)

