"""Executing runs: :func:`execute_run` (one grid point into its run folder), local processes
(:func:`local_runs`, a fresh process per run from the forkserver of :mod:`sumo_ethics.processes`)
and a Dask cluster (:class:`DaskPool`, each run in a fresh subprocess on a worker). Both give
``(spec, result)`` as runs finish, a failed run as the caller's ``failed(spec, line)``."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import time
import uuid
from collections.abc import Callable, Generator, Iterable
from functools import partial
from pathlib import Path
from typing import Any

from sumo_ethics.errors import ConfigError
from sumo_ethics.predict import one_thread
from sumo_ethics.sweep.grid import RunSpec
from sumo_ethics.sweep.manifest import result_from_folder

def execute_run(spec: dict[str, Any], runs_dir: str) -> dict[str, Any]:
    """Run one grid point into ``runs_dir/<run_id>`` (temp folder, renamed when the run ended on its own).

    Returns a result dict: run_id, status, message, error, wall, path. A finished run folder that
    already exists is not run again (status from its summary). Exceptions that are not
    sumo-ethics errors propagate (the caller records the run as failed).
    """
    from sumo_ethics.errors import OutputError, SumoEthicsError
    from sumo_ethics.record.reader import collided
    from sumo_ethics.record.writer import write_json

    s = RunSpec.from_dict(spec)
    runs = Path(runs_dir)
    final = runs / s.run_id
    if (final / "summary.json").exists():
        return result_from_folder(s.run_id, final, skipped=True)
    tmp = runs / f".{s.run_id}.tmp-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    t0, c0 = time.perf_counter(), time.process_time()
    cfg = s.run_config(tmp)
    from sumo_ethics.runner import make_controller, run

    controller = make_controller(cfg) if cfg.fleet is None else None  # a fleet makes one per ego
    one_thread()
    try:
        run(cfg, controller=controller)
    except (ConfigError, OutputError):  # bad input or a full disk: not a result, retried on the next start
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    except SumoEthicsError as exc:  # SUMO failed on valid input: a result of this configuration, kept
        if not (tmp / "summary.json").exists():
            tmp.mkdir(parents=True, exist_ok=True)
            write_json(tmp / "summary.json", {"status": "error", "message": str(exc), "completed": False})
    if collided(tmp):  # the collision snapshots, drawn from the run folder (the run draws none)
        from sumo_ethics.analysis.explain import draw_snapshots

        draw_snapshots(tmp)
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
    return result_from_folder(s.run_id, final)


def execute_run_isolated(spec: dict[str, Any], runs_dir: str, timeout: float | None = None) -> dict[str, Any]:
    """:func:`execute_run` in a fresh Python subprocess (for long-lived workers such as Dask's)."""
    proc = subprocess.run([sys.executable, "-m", "sumo_ethics.sweep", runs_dir], input=json.dumps(spec),
                          capture_output=True, text=True, timeout=timeout)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    if proc.returncode == 0 and lines:
        return json.loads(lines[-1])
    tail = (proc.stderr.strip().splitlines() or [f"exit code {proc.returncode}"])[-1]
    raise RuntimeError(f"run process died (exit code {proc.returncode}): {tail}")


#: what the run processes' forkserver imports once (:func:`sumo_ethics.processes.run_each`)
PRELOAD = ("sumo_ethics.sweep", "sumo_ethics.runner", "sumo_ethics.plan.ethical")


def local_runs(specs: Iterable[dict[str, Any]], runs_dir: str, workers: int,
               failed: Callable[[dict[str, Any], str], dict[str, Any]]) -> Generator[tuple[dict[str, Any], dict[str, Any]], None, None]:
    """``(spec, result)`` of every run, each :func:`execute_run` in a fresh local process, ``workers``
    at a time (:func:`sumo_ethics.processes.run_each`); a run that raised or whose process died is
    ``failed(spec, one line)``."""
    from sumo_ethics.processes import one_line, run_each

    return run_each(partial(execute_run, runs_dir=runs_dir), specs, workers, preload=PRELOAD,
                    on_error=lambda spec, exc: failed(spec, one_line(exc)), on_crash=failed)


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

    def runs(self, specs: Iterable[dict[str, Any]], runs_dir: str,
             failed: Callable[[dict[str, Any], str], dict[str, Any]]) -> Generator[tuple[dict[str, Any], dict[str, Any]], None, None]:
        """``(spec, result)`` of every run as it finishes, as :func:`local_runs` gives them: each
        :func:`execute_run_isolated` on a worker, twice as many submitted as the cluster has threads
        (its queue kept fed); a run that raised or whose process died is ``failed(spec, one line)``."""
        from distributed import as_completed

        from sumo_ethics.processes import one_line

        todo = iter(specs)
        running: dict[Any, dict[str, Any]] = {}
        done = as_completed()

        def fill() -> None:
            while len(running) < 2 * self.workers and (spec := next(todo, None)) is not None:
                key = f"run-{spec['run_id']}-{uuid.uuid4().hex[:6]}"
                fut = self.client.submit(execute_run_isolated, spec, runs_dir, key=key, pure=False, retries=0)
                running[fut] = spec
                done.add(fut)

        fill()
        while running:
            for fut in [next(done), *done.next_batch(block=False)]:
                spec = running.pop(fut)
                try:
                    result = fut.result()
                except RuntimeError as exc:  # the run's process died: execute_run_isolated's own line
                    result = failed(spec, str(exc) or one_line(exc))
                except Exception as exc:  # noqa: BLE001 - a crash of the tool on this run
                    result = failed(spec, one_line(exc))
                yield spec, result
            fill()

    def close(self) -> None:
        self.client.close()


def main_one() -> int:
    """``python -m sumo_ethics.sweep RUNS_DIR`` with a run spec (JSON) on stdin: one isolated run."""
    spec = json.loads(sys.stdin.read())
    result = execute_run(spec, sys.argv[1])
    sys.stdout.write("\n" + json.dumps(result) + "\n")
    return 0
