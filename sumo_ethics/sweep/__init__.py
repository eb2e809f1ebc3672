"""Sweeps: a grid of runs (scenarios x omega_u x seeds x ``--set`` values), one SUMO per process.

Layout of a sweep folder ``DIR``::

    DIR/manifest.json            sweep definition + every run (id, parameters, status, error, path)
    DIR/runs/<run_id>/           one complete run folder each (summary.json, config.json, params.json,
                                 steps/collisions/timings.parquet, sumo-errors.log)
    DIR/dataset/runs/...         one Parquet dataset per table, hive-partitioned by the swept
    DIR/dataset/collisions/...   parameters except the seed (``scenario=urban/omega_u=0.5/part-0.parquet``);
    DIR/dataset/steps/...        every row carries ``run_id`` and the sweep parameters

Executors. Locally one fresh process per run, at most ``--workers`` at a time
(:func:`sumo_ethics.processes.run_each`, which evaluate and dataset recording use too: started
from a forkserver with the package preloaded, so starting one costs milliseconds, not the
imports): a fatal SUMO error never leaks into the next run and a crashing run takes down only
itself (a ``ProcessPoolExecutor`` with ``max_tasks_per_child=1`` breaks every run in flight when
one worker dies, and hangs at exit after Ctrl-C on Python 3.11). With a Dask scheduler the
same :func:`execute_run` runs in a fresh Python subprocess started by the Dask task
(long-lived Dask workers must not start a second libsumo simulation).

Finished runs. A run is *finished* when ``runs/<run_id>/summary.json`` exists. A run folder
is built under a temporary name (``runs/.<run_id>.tmp-<pid>-<hex>``) and renamed only when the
run ended on its own: ``completed``, ``collision``, ``timeout`` or ``error`` (SUMO failed, the ego
could not be inserted or left the network...: a result of that configuration, kept). Bad input
is refused before any run starts (:meth:`Sweep.validate`); input refused only inside a run, an
output that could not be written, a crash of the tool itself (a Python exception that is not a
sumo-ethics error, a killed worker, Ctrl-C, SIGTERM) leave no run folder; the run is listed as
``failed`` in the manifest and runs again when the same sweep is started again. Run processes
die with the sweep (see :mod:`sumo_ethics._worker_signals`); the temporary folders and manifest
files of a killed start are removed at the next start.

Modules: :mod:`~sumo_ethics.sweep.grid` (parsing, the grid, bounds), :mod:`~sumo_ethics.sweep.manifest`
(manifest.json, folder checks, leftovers), :mod:`~sumo_ethics.sweep.executors` (one run, local
processes, Dask); this module runs a sweep. The sweep's Parquet dataset is built by
:func:`sumo_ethics.analysis.sweep_tables.build_dataset`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import closing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sumo_ethics.errors import ConfigError, add_note
from sumo_ethics.sweep.executors import DaskPool, execute_run, execute_run_isolated, local_runs, main_one
from sumo_ethics.sweep.grid import (MAX_RUNS, MAX_VALUES, PLANNER_SIMPLE, RUN_KEYS, RunSpec, Sweep,
                                    find_scenarios, known_set_keys, make_run_id, make_sweep, parse_range,
                                    parse_seeds, parse_set, planner_keys, scenario_names)
from sumo_ethics.sweep.manifest import (FAILED, FINISHED, MANIFEST_VERSION, PENDING, Manifest, check_finished,
                                        check_out, clean_temporaries, result_from_folder)

__all__ = ["DaskPool", "execute_run", "execute_run_isolated", "local_runs", "main_one", "MAX_RUNS",
           "MAX_VALUES", "PLANNER_SIMPLE", "RUN_KEYS", "RunSpec", "Sweep", "find_scenarios",
           "known_set_keys", "make_run_id", "make_sweep", "parse_range", "parse_seeds", "parse_set",
           "planner_keys", "scenario_names", "FAILED", "FINISHED", "MANIFEST_VERSION", "PENDING", "Manifest",
           "check_finished", "check_out", "clean_temporaries", "result_from_folder", "SweepResult", "run_sweep"]

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
        except KeyboardInterrupt as exc:  # the command's one line says what is kept
            finished = sum(1 for p in (Path(out) / "runs").glob("*/summary.json") if not p.parent.name.startswith("."))
            add_note(exc, f"{finished} of {len(sweep.specs())} runs are finished in {out}: the same command "
                           "resumes the others")
            raise


def _start(sweep: Sweep, out: Path, specs: list[RunSpec],
           execution: dict[str, Any] | None = None) -> tuple[float, Path, Manifest, list[RunSpec], int]:
    """Create the folders, clean a killed start's leftovers, check the finished runs and write the
    manifest; the runs still to do."""
    t0 = time.perf_counter()
    runs_dir = out / "runs"
    try:
        runs_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"cannot write to --out {out}: {exc.strerror or exc}") from None
    clean_temporaries(out)
    manifest = Manifest(out, sweep, specs, execution)
    manifest.load_previous()
    todo: list[RunSpec] = []
    skipped = 0
    for s in specs:
        folder = runs_dir / s.run_id
        if (folder / "summary.json").exists():
            check_finished(folder)
            manifest.update(result_from_folder(s.run_id, folder, skipped=True))
            skipped += 1
        else:
            todo.append(s)
    manifest.write()
    return t0, runs_dir, manifest, todo, skipped


def _run_sweep(sweep: Sweep, out: Path, workers: int, scheduler: str | None, progress: bool,
               on_result: Callable[[dict[str, Any]], None] | None) -> SweepResult:
    if workers < 1:
        raise ConfigError(f"--workers must be at least 1, got {workers}")
    specs = sweep.validate()
    check_out(out, sweep)
    dask = DaskPool(scheduler) if scheduler else None
    try:
        t0, runs_dir, manifest, todo, skipped = _start(sweep, out, specs,
                                                       {"scheduler": scheduler} if scheduler else {"workers": workers})
    except BaseException:
        if dask is not None:
            dask.close()
        raise
    failed = errors = 0
    failures: list[str] = []

    def started() -> Iterator[dict[str, Any]]:  # each run counted as its process starts
        for s in todo:
            manifest.runs[s.run_id]["attempts"] += 1
            yield s.to_dict()

    def crashed(spec: dict[str, Any], line: str) -> dict[str, Any]:  # a crash of the tool on this run
        return {"run_id": spec["run_id"], "status": FAILED, "error": line, "message": line}

    results = dask.runs(started(), str(runs_dir), crashed) if dask is not None else \
        local_runs(started(), str(runs_dir), workers, crashed)
    with _progress(progress, len(specs)) as bar:
        task = bar.add_task("runs", total=len(specs), completed=skipped, failed=0, errors=0)
        try:
            with closing(results):  # closed: no run process runs on
                for _, result in results:
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
        except BaseException:
            manifest.sync(runs_dir)
            manifest.write()
            raise
        finally:
            if dask is not None:
                dask.close()
    manifest.write()
    from sumo_ethics.analysis.sweep_tables import build_dataset

    build_dataset(out)
    done = sum(1 for r in manifest.runs.values() if r["status"] in FINISHED)
    return SweepResult(out=out, total=len(specs), done=done, failed=failed, skipped=skipped, errors=errors,
                       wall=time.perf_counter() - t0, failures=failures)
