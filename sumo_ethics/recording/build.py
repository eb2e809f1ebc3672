"""Prediction datasets recorded from SUMO: every scenario x seed simulated, one libsumo run per fresh
process (:func:`sumo_ethics.processes.run_each`), the trajectories turned into training samples (:mod:`sumo_ethics.predict.samples`).

``build_dataset`` runs every scenario x seed (``--step-length 0.1 --lanechange.duration 2``, demand
scaled with ``--scale`` varying by seed) and the suite scenarios with their hazards, and writes the
dataset folder :mod:`sumo_ethics.predict.samples` describes. While it builds, each finished run is
kept in ``out/partial`` (:mod:`sumo_ethics.recording.runstore`): a build stopped by Ctrl-C, SIGTERM,
a crash or a kill resumes from them when called again with the same arguments, and gives the same
bytes as one never stopped.
"""

from __future__ import annotations

import json
import logging
import signal
from collections.abc import Callable, Iterator, Sequence
from contextlib import closing, contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import NoReturn

import numpy as np
import pandas as pd

from sumo_ethics import __version__
from sumo_ethics.errors import ConfigError
from sumo_ethics.interrupt import signals_held
from sumo_ethics.predict import features as F
from sumo_ethics.predict.graph_files import write_dataset_graphs
from sumo_ethics.predict.samples import SIM_DT, SUITE_SEED0, build_samples, split_counts, split_seeds
from sumo_ethics.processes import run_each
from sumo_ethics.recording.runstore import RunStore
from sumo_ethics.sim.frames import front_to_centre

log = logging.getLogger(__name__)

#: what sim.trajectories writes; a stopped build resumes only with the same (2: no rows without a position)
RECORDER_VERSION = 2

#: what the run processes' forkserver imports once (:func:`sumo_ethics.processes.run_each`)
PRELOAD = ("sumo_ethics.recording.build", "sumo_ethics.sim.trajectories")



def sumo_version() -> str:
    """The installed SUMO's version (its Python package's), without starting SUMO."""
    from importlib.metadata import PackageNotFoundError, version

    for package in ("eclipse-sumo", "libsumo"):
        try:
            return version(package)
        except PackageNotFoundError:
            continue
    return "unknown"
DEFAULT_SCALES = (0.7, 1.0, 1.3)

@dataclass(frozen=True)
class RunSpec:
    run_id: int
    scenario: Path
    seed: int
    scale: float
    sim_seconds: float
    #: folder the run's scratch folder goes in (None: the system's temporary folder)
    scratch_root: str | None = None


def _simulate(spec: RunSpec) -> tuple[pd.DataFrame, F.LaneGraph]:
    """One SUMO run (:func:`sumo_ethics.sim.trajectories.record_run`) -> trajectory rows and the
    network's lane graph (runs inside a worker process). Map context (lane, lane_pos, tls_dist,
    tls_state, next_lane, ...; see :mod:`sumo_ethics.sim.lanes`) is read at the model rate only
    (other rows: lane -1)."""
    import shutil
    import tempfile

    from sumo_ethics.sim.trajectories import record_run
    from sumo_ethics.sim.scenario import read_scenario, redirected
    from sumo_ethics.sim.session import output_args

    cmd = [
        "sumo", "-c", str(spec.scenario), "--seed", str(spec.seed), "--scale", f"{spec.scale:g}",
        "--step-length", f"{SIM_DT}", "--lanechange.duration", "2",
        "--no-step-log", "true", "--no-warnings", "true", "--duration-log.disable", "true",
    ]
    # the scenario's own outputs (output options, dumps of its additional files) go to a scratch
    # folder, as run does: never next to the scenario (eclipse-sumo's tools/game configs would write
    # netstate.xml and tlsstate.xml into the installed package), never shared by parallel runs
    scratch = Path(tempfile.mkdtemp(prefix="run_", dir=spec.scratch_root))
    try:
        cmd += output_args(redirected(read_scenario(spec.scenario), scratch)[0])
        rows, graph = record_run(cmd, spec.sim_seconds, SIM_DT, F.MODEL_DT)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    ids = np.array(rows["agent_id"], dtype=object)
    tinfo = np.array(rows["type"]).reshape(-1, 3)
    length, width, cls = tinfo[:, 0], tinfo[:, 1], tinfo[:, 2].astype(np.int8)
    x, y, yaw = front_to_centre(np.array(rows["x"]), np.array(rows["y"]), np.array(rows["angle"]), length)
    return pd.DataFrame(
        {
            "run_id": np.full(len(ids), spec.run_id, dtype=np.int32),
            "seed": np.full(len(ids), spec.seed, dtype=np.int32),
            "scenario": str(spec.scenario),
            "scale": np.float32(spec.scale),
            "time": np.round(np.array(rows["time"]), 3),
            "agent_id": ids.astype(str),
            "cls": cls,
            "x": x, "y": y, "yaw": yaw,
            "speed": np.array(rows["speed"], dtype=np.float32),
            "length": length.astype(np.float32), "width": width.astype(np.float32),
            "lane": np.array(rows["lane"], dtype=np.int32),
            "lane_pos": np.array(rows["lane_pos"], dtype=np.float32),
            "tls_dist": np.array(rows["tls_dist"], dtype=np.float32),
            "tls_state": np.array(rows["tls_state"], dtype=np.int8),
            "next_lane": np.array(rows["next_lane"], dtype=np.int32),
            "tls_switch": np.array(rows["tls_switch"], dtype=np.float32),
            "blinker": np.array(rows["blinker"], dtype=np.int8),
            "after_lane": np.array(rows["after_lane"], dtype=np.int32),
        }
    ), graph


def _probe(scenario: Path) -> str | None:
    """Start and close SUMO on ``scenario`` (worker process): None, or why it cannot start."""
    import tempfile

    from sumo_ethics.errors import SumoEthicsError
    from sumo_ethics.sim import session
    from sumo_ethics.sim.scenario import read_scenario, redirected

    try:
        files = read_scenario(scenario)
        with tempfile.TemporaryDirectory() as tmp:  # its outputs (written at close) go there too
            session.start(files, seed=1, error_log=Path(tmp) / "errors.log", outputs=redirected(files, Path(tmp))[0])
            session.close()
    except SumoEthicsError as exc:
        return str(exc)
    except Exception as exc:  # noqa: BLE001 - libsumo's own exceptions cannot be pickled back: their text
        return f"SUMO could not start {Path(scenario).name}: {type(exc).__name__}: {exc}"
    return None


def check_scenarios(scenarios: list[Path]) -> None:
    """Load every scenario once in SUMO before any run is simulated: one that cannot start (a
    malformed config, an option plain sumo lacks, e.g. a gui-only ``osg-view``) raises ConfigError
    with SUMO's reason, so nothing is simulated in vain; one that crashes SUMO, too."""

    def crashed(scenario: Path, why: str) -> NoReturn:  # SUMO may crash outright on a broken file
        raise ConfigError(f"dataset: SUMO crashed while loading {scenario} (a malformed network or route file?)")

    for _, problem in run_each(_probe, scenarios, 1, preload=PRELOAD, on_crash=crashed):
        if problem:
            raise ConfigError(f"dataset: {problem}")


@contextmanager
def _failures_named(what: str) -> Iterator[None]:
    """Inside a worker process: any failure but the project's own errors becomes a SimulationError
    naming ``what`` (libsumo's exceptions cannot be pickled back to the parent process)."""
    from sumo_ethics.errors import SimulationError, SumoEthicsError

    try:
        yield
    except SumoEthicsError:
        raise
    except Exception as exc:  # noqa: BLE001 - any failure of the run, named
        raise SimulationError(f"dataset: {what}: {type(exc).__name__}: {exc}") from None


def _run_name(spec: RunSpec) -> str:
    return f"{spec.scenario.name} seed {spec.seed}"


def _simulate_safely(spec: RunSpec) -> tuple[pd.DataFrame, F.LaneGraph]:
    """:func:`_simulate`, its failures as SimulationError naming scenario and seed."""
    with _failures_named(_run_name(spec)):
        return _simulate(spec)


def _crashed_run(name: str) -> NoReturn:
    from sumo_ethics.errors import SimulationError

    raise SimulationError(f"dataset: SUMO crashed while simulating {name}")


@contextmanager
def _scratch_root() -> Iterator[str]:
    """A temporary folder for the scratch folders of a batch of runs, removed on leaving (the
    runs' processes must be gone by then: :func:`~sumo_ethics.processes.run_each` closed first)."""
    import shutil
    import tempfile

    root = tempfile.mkdtemp(prefix="sumo_ethics_dataset_")
    try:
        yield root
    finally:
        shutil.rmtree(root, ignore_errors=True)


def simulate_runs(specs: list[RunSpec], store: RunStore, workers: int = 1) -> None:
    """Run every spec not yet in ``store`` in a fresh process (:func:`~sumo_ethics.processes.run_each`) and
    keep each run's trajectory rows and lane graph there as soon as it ends.

    The runs' scratch folders (the scenarios' own outputs) go in one temporary folder, removed
    when this returns or stops, after the processes are gone: a run terminated on Ctrl-C or
    SIGTERM cannot remove its own."""
    done = store.done()
    todo = [spec for spec in specs if spec.run_id not in done]
    def crashed(spec: RunSpec, why: str) -> NoReturn:
        _crashed_run(_run_name(spec))

    with _scratch_root() as root:
        jobs = [replace(spec, scratch_root=root) for spec in todo]
        with closing(run_each(_simulate_safely, jobs, workers, preload=PRELOAD, on_crash=crashed)) as results:  # closed: no process runs on
            for i, (spec, (df, graph)) in enumerate(results):
                store.put(spec.run_id, df, graph)
                log.info("run %d/%d: %s seed %d scale %.2f -> %d rows", i + 1, len(todo), spec.scenario.name,
                         spec.seed, spec.scale, len(df))


#: manoeuvre labels of a sample (vehicles and cyclists; pedestrians are -1), see :func:`manoeuvre_labels`
def _suite_name(scenario: Path) -> str:
    return f"suite scenario {scenario.name}"


def _simulate_suite(args: tuple[int, Path, str | None]) -> tuple[pd.DataFrame, F.LaneGraph | None]:
    """One suite scenario with its hazards (worker process) -> trajectory rows, lane graph;
    args: run id, scenario folder, folder for its scratch folder."""
    from sumo_ethics.suite.traffic import record_scenario

    run_id, scenario, scratch_root = args
    with _failures_named(_suite_name(scenario)):
        df, graph = record_scenario(scenario, scratch_root=scratch_root)
    if len(df):
        df.insert(0, "run_id", np.int32(run_id))
        df.insert(1, "seed", np.int32(SUITE_SEED0 + run_id))
        df.insert(2, "scenario", str(scenario))
        df.insert(3, "scale", np.float32(1.0))
    return df, graph


def simulate_suite(scenarios: list[Path], first_run_id: int, store: RunStore, workers: int = 1) -> None:
    """Record the suite scenarios not yet in ``store`` (hazards included), one fresh process each
    (:func:`~sumo_ethics.processes.run_each`), numbered from ``first_run_id``; each kept in ``store`` as it ends."""
    done = store.done()
    def crashed(job: tuple, why: str) -> NoReturn:
        _crashed_run(_suite_name(job[1]))

    with _scratch_root() as root:
        jobs = [(first_run_id + i, Path(s).resolve(), root) for i, s in enumerate(scenarios) if first_run_id + i not in done]
        with closing(run_each(_simulate_suite, jobs, workers, preload=PRELOAD, on_crash=crashed)) as results:
            for (run_id, scen, _), (df, graph) in results:
                store.put(run_id, df, graph)
                log.info("suite run %d: %s -> %d rows", run_id, scen.name, len(df))


def build_dataset(
    scenarios: list[Path],
    seeds: list[int],
    out: Path,
    *,
    suite: Sequence[Path] = (),
    suite_anchor_every: float = 0.4,
    scales: tuple[float, ...] = DEFAULT_SCALES,
    sim_seconds: float = 600.0,
    anchor_every: float = 1.0,
    workers: int = 1,
    val_fraction: float = 0.15,
    test_fraction: float = 0.2,
    on_resume: Callable[[int, int], None] | None = None,
) -> Path:
    """Simulate scenarios x seeds (and record the ``suite`` scenarios with their hazards, split
    by scenario, see SUITE_SEED0) and write trajectories.parquet, lane_graphs.json.gz,
    samples.npz, split.json.

    The demand scale of seed s is ``scales[i % len(scales)]`` where i is the seed's rank,
    so every split sees every scale when it has enough seeds. Each finished run is kept in
    ``out``/partial (:class:`RunStore`); a stopped build of the same runs goes on from them
    (``on_resume(kept, planned)`` is told first). Returns ``out``.
    """
    out = Path(out)
    seeds = sorted(set(int(s) for s in seeds))
    split = split_seeds(seeds, val_fraction, test_fraction) if seeds else {"train": [], "val": [], "test": []}
    specs: list[RunSpec] = []
    for scenario in scenarios:
        for i, seed in enumerate(seeds):
            specs.append(RunSpec(len(specs), Path(scenario).resolve(), seed, float(scales[i % len(scales)]), sim_seconds))
    if specs:
        check_scenarios(sorted({s.scenario for s in specs}, key=str))
    suite_dirs = [Path(s).resolve() for s in suite]
    runs = [{"run_id": s.run_id, "scenario": str(s.scenario), "seed": s.seed, "scale": s.scale} for s in specs]
    store = RunStore.open(out, {
        "runs": [{**r, "sim_seconds": sim_seconds} for r in runs],
        "suite": [{"run_id": len(specs) + i, "scenario": str(s)} for i, s in enumerate(suite_dirs)],
        "sumo_ethics": __version__, "recorder": RECORDER_VERSION, "sumo": sumo_version(), "map_version": F.MAP_VERSION,
    })
    kept = store.done()
    if kept and on_resume is not None:  # a stopped build of these very runs
        on_resume(len(kept), len(specs) + len(suite_dirs))
    simulate_runs(specs, store, workers=workers)
    simulate_suite(suite_dirs, len(specs), store, workers=workers)
    # every run read back from its file, a resumed one or not: the dataset is the same bytes either way
    frames: list[pd.DataFrame] = []
    graphs: dict[str, F.LaneGraph] = {}
    for spec in specs:
        df, graph = store.get(spec.run_id)
        frames.append(df)
        graphs.setdefault(str(spec.scenario), graph)
    for i, scen in enumerate(suite_dirs):
        df, graph = store.get(len(specs) + i)
        if len(df) and graph is not None:
            frames.append(df)
            graphs[str(scen)] = graph
        name = "test" if i % 10 == 9 else "val" if i % 10 == 8 else "train"
        split[name].append(SUITE_SEED0 + len(specs) + i)
    traj = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()
    # the samples first: a run too short for any sample stops here, before anything is written
    try:
        samples = build_samples(traj, split, anchor_every=anchor_every, graphs=graphs,
                                suite_anchor_every=suite_anchor_every)
    except ConfigError as exc:  # the same arguments would fail again: say how to start over
        raise ConfigError(f"{exc} (the {len(store.done())} finished runs are kept in {store.folder}; delete {out} "
                          "to simulate with other arguments)") from None
    with signals_held(signal.SIGINT, signal.SIGTERM):  # Ctrl-C or SIGTERM now waits: the folder is written whole
        out.mkdir(parents=True, exist_ok=True)
        traj.to_parquet(out / "trajectories.parquet", index=False)
        write_dataset_graphs(out, graphs)
        np.savez_compressed(out / "samples.npz", **samples)  # type: ignore[arg-type]  # array names, no allow_pickle
        meta = {
            "split": split,
            "scenarios": [str(Path(s)) for s in scenarios],
            "suite": [str(Path(s)) for s in suite],
            "runs": runs,
            "feature_version": F.FEATURE_VERSION,
            "map_version": F.MAP_VERSION,
            "anchor_every": anchor_every,
            "suite_anchor_every": suite_anchor_every,
            "model_dt": F.MODEL_DT,
            "hist_steps": F.HIST_STEPS,
            "fut_steps": F.FUT_STEPS,
            "n_samples": split_counts(samples),
        }
        (out / "split.json").write_text(json.dumps(meta, indent=2))
        store.remove()
    return out


def dataset_main(
    scenarios: Sequence[Path | str],
    out: Path | str,
    seeds: Sequence[int] = tuple(range(1, 8)),
    sim_seconds: float = 600.0,
    anchor_every: float = 2.0,
    scales: Sequence[float] = (0.7, 1.0, 1.3),
    workers: int = 1,
    suite: Sequence[Path | str] = (),
    suite_anchor_every: float = 0.4,
    on_resume: Callable[[int, int], None] | None = None,
) -> Path:
    """Simulate ``scenarios`` (.sumocfg) x ``seeds`` (and record the ``suite`` scenario folders
    with their hazards) and write a prediction dataset folder to ``out``. Each finished run is kept
    in ``out``/partial as it ends (:mod:`sumo_ethics.recording.runstore`), and the same call on the
    same ``out`` resumes from them (``on_resume(kept, planned)`` is told first). SIGTERM stops it as Ctrl-C does
    (:class:`sumo_ethics.errors.Terminated`): its SUMO runs killed, no dataset written (a signal
    while the folder is written waits until it is whole); the interrupt's note says which, and how
    many finished runs are kept."""
    from sumo_ethics.errors import SimulationError, add_note
    from sumo_ethics.interrupt import sigterm_as_interrupt

    with sigterm_as_interrupt():  # without it SIGTERM ended this process alone and its runs went on
        try:
            return build_dataset(
                [Path(s) for s in scenarios], list(seeds), Path(out), scales=tuple(scales),
                sim_seconds=sim_seconds, anchor_every=anchor_every, workers=workers,
                suite=[Path(s) for s in suite], suite_anchor_every=suite_anchor_every, on_resume=on_resume,
            )
        except KeyboardInterrupt as exc:  # the command's one line says what is on disk
            done = (Path(out) / "split.json").is_file()
            add_note(exc, f"the dataset was written whole to {out}" if done else f"no dataset is written{_kept_note(out)}")
            raise
        except SimulationError as exc:  # a SUMO run failed: the others' work is not lost either
            note = _kept_note(out)
            if note:
                raise SimulationError(f"{exc}{note}") from None
            raise


def _kept_note(out: Path | str) -> str:
    """What a stopped dataset build keeps, for its one line: ' (K of N runs finished and are kept in
    OUT/partial: the same command resumes from them)', or '' when no run finished."""
    from sumo_ethics.recording.runstore import PARTIAL, kept_runs

    kept, planned = kept_runs(Path(out))
    return (f" ({kept} of {planned} runs finished and are kept in {Path(out) / PARTIAL}: the same command "
            "resumes from them)" if kept else "")
