"""Executing runs: :func:`execute_run` (one grid point into its run folder), local processes
(:class:`LocalPool`, a fresh process per run from a forkserver) and a Dask cluster
(:class:`DaskPool`, each run in a fresh subprocess on a worker)."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import traceback
import uuid
from contextlib import AbstractContextManager
from pathlib import Path
from typing import Any, Iterable

from sumo_ethics.errors import ConfigError
from sumo_ethics.interrupt import signals_held
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


def ctrl_c_after() -> AbstractContextManager[None]:
    """Hold a Ctrl-C (SIGINT) that arrives inside the block until the block is done, then raise it
    (:func:`sumo_ethics.interrupt.signals_held`).

    Starting a process from the forkserver is two steps: the forkserver forks the child, then this
    process writes it what to run. A KeyboardInterrupt between the two left the child reading an
    empty pipe, and it printed ``EOFError: Ran out of input`` under the sweep's one error line."""
    return signals_held(signal.SIGINT)


class RunProcess:
    """One run in its own process; ``result()`` like a Future's (raises RuntimeError on a crash)."""

    def __init__(self, ctx: Any, spec: dict[str, Any], runs_dir: str) -> None:
        self.conn, child = ctx.Pipe(duplex=False)
        self.proc = ctx.Process(target=_child, args=(child, spec, runs_dir), name=f"run-{spec['run_id']}",
                                daemon=True)
        with ctrl_c_after():  # the child gets what to run even when Ctrl-C comes now
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
        from sumo_ethics.forkserver import forkserver_context

        self.workers = workers
        self.ctx = forkserver_context(["sumo_ethics._worker_signals", "sumo_ethics.sweep", "sumo_ethics.runner",
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


def main_one() -> int:
    """``python -m sumo_ethics.sweep RUNS_DIR`` with a run spec (JSON) on stdin: one isolated run."""
    spec = json.loads(sys.stdin.read())
    result = execute_run(spec, sys.argv[1])
    sys.stdout.write("\n" + json.dumps(result) + "\n")
    return 0
