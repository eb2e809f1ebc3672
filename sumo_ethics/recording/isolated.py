"""Jobs in fresh spawned processes, one process per job (libsumo: one simulation per process).

:func:`isolated_map` owns its processes (``multiprocessing.Process`` and a one-way pipe each):
it knows at once when one dies without a result (SUMO crashing), and it kills the running ones
itself when it stops, on Ctrl-C, SIGTERM, a failure or a caller that stops early.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import pickle
import signal
import sys
from collections.abc import Callable, Generator
from multiprocessing import resource_tracker
from multiprocessing.connection import wait
from typing import Any, TypeVar

from sumo_ethics.interrupt import signals_held

T = TypeVar("T")
R = TypeVar("R")


PR_SET_PDEATHSIG = 1  # linux/prctl.h


def _die_with(parent: int) -> None:
    """In a worker: be killed (SIGKILL) when ``parent`` dies, even by ``kill -9`` (Linux; the
    worker holds SIGINT and SIGTERM blocked, so nothing else would end it, and an orphan would
    simulate on beside the resumed build)."""
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        except (OSError, AttributeError):  # pragma: no cover - no prctl
            pass
    if os.getppid() != parent:  # the parent died before that took effect
        os._exit(1)


def _work(fn: Callable[[Any], Any], job: Any, conn: Any, parent: int) -> None:
    """Inside the worker process: ``("ok", fn(job))`` or ``("error", exception)`` down the pipe."""
    _die_with(parent)
    try:
        reply = ("ok", fn(job))
    except BaseException as exc:  # noqa: BLE001 - every failure goes back to the caller, which raises it
        reply = ("error", exc)
    try:
        conn.send(reply)
    except (pickle.PicklingError, TypeError, AttributeError) as exc:  # a result that cannot be pickled
        conn.send(("error", RuntimeError(f"{type(reply[1]).__name__} cannot be sent back from the worker: {exc}")))
    except OSError:  # the caller is gone (its end of the pipe closed): nobody to tell
        os._exit(1)
    conn.close()


def _kill(proc: mp.process.BaseProcess) -> None:
    """SIGKILL a worker and reap it: workers hold SIGINT and SIGTERM blocked, so nothing else ends them."""
    if proc.pid is not None:
        proc.kill()
        proc.join(timeout=5)


def isolated_map(fn: Callable[[T], R], jobs: list[T], workers: int, crashed: Callable[[T], Exception]) -> Generator[tuple[T, R], None, None]:
    """``(job, fn(job))`` for every job, each in a fresh spawned process, at most ``workers`` at a
    time, in the order they finish (of those finished, the first started), so a finished result is
    never held back behind a longer job. A worker's exception is raised here; a process that dies
    without a result (SUMO crashing) raises ``crashed(job)`` instead of being waited for forever,
    which is what ``multiprocessing.Pool`` does. The next job starts when a result has been taken,
    so a caller that stops at a result starts nothing more. The processes do not see Ctrl-C or
    SIGTERM: this process gets them and kills the running ones (also after a failure or when the
    caller stops)."""
    ctx = mp.get_context("spawn")
    todo = iter(jobs)
    running: list[tuple[T, Any, Any]] = []  # (job, process, receiving end of its pipe), by start

    def start() -> None:
        job = next(todo, None)
        if job is None:
            return
        recv, send = ctx.Pipe(duplex=False)
        proc = ctx.Process(target=_work, args=(fn, job, send, os.getpid()), daemon=True)
        # multiprocessing starts its resource tracker at the first process start, and that unblocks
        # SIGINT and SIGTERM in this thread: started here, outside the block below, it cannot
        resource_tracker.ensure_running()
        # the process inherits SIGINT and SIGTERM blocked: a terminal's Ctrl-C (to the whole process
        # group) printed KeyboardInterrupt tracebacks from workers still starting. This process gets
        # either when the block ends, with the process started and listed, so it is stopped
        with signals_held(signal.SIGINT, signal.SIGTERM):
            running.append((job, proc, recv))
            try:
                proc.start()
            finally:
                send.close()  # the worker's end: the pipe reads EOF once the worker is gone

    try:
        for _ in range(max(1, workers)):
            start()
        while running:
            ready = set(wait([recv for _, _, recv in running] + [proc.sentinel for _, proc, _ in running]))
            k = next(i for i, (_, proc, recv) in enumerate(running) if recv in ready or proc.sentinel in ready)
            job, proc, recv = running[k]
            try:
                status, value = recv.recv()
            except (EOFError, OSError):  # gone without a reply: the process died
                raise crashed(job) from None
            del running[k]
            recv.close()
            proc.join()
            proc.close()
            if status == "error":
                raise value
            yield job, value
            start()
    finally:
        with signals_held(signal.SIGINT, signal.SIGTERM):  # a second Ctrl-C does not cut the stopping short
            for _, proc, recv in running:  # after a failure or an interrupt: nothing new starts, nothing runs on
                _kill(proc)
                recv.close()
