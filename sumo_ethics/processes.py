"""One fresh process per job: the executor of ``evaluate``, local sweeps and dataset recording.

libsumo runs one simulation per process, and none after a fatal SUMO error, so every run gets a
process of its own. :func:`run_each` runs ``fn(job)`` for each job that way, at most ``workers`` at
a time, and hands back ``(job, result)`` as they finish (or in the jobs' order). What it does for
all three callers alike:

- **Quick starts.** The processes are forked from a forkserver (:func:`forkserver_context`) that
  has imported ``preload`` once (torch, libsumo, the package), so a run starts in milliseconds,
  not after the imports.
- **Crashes are rows.** A process that ends without a result (SUMO aborting, a segfault, the OOM
  killer, ``os._exit``) is ``on_crash(job, why)``, ``why`` naming its exit code or signal
  (``run process died (exit code 3)``), instead of a pool that hangs or breaks every run in
  flight; the other jobs go on. An exception of ``fn`` is ``on_error(job, exception)``. Either
  callback returns the job's row, or raises to stop everything; without one, the exception is
  raised here.
- **Ctrl-C and SIGTERM.** The run processes never see either (:mod:`sumo_ethics._worker_signals`):
  a terminal's Ctrl-C reaches the whole process group and printed tracebacks from processes
  still importing. This process gets them (SIGTERM as :class:`~sumo_ethics.errors.Terminated`
  while :func:`run_each` runs) and kills the running processes, also after a failure or when the
  caller stops taking results. A signal that arrives while a process starts waits until it has
  started and is listed (starting from a forkserver is two steps, the fork and then the job
  written to the child; cut in between, the child printed ``EOFError: Ran out of input``).
- **Children die with the parent**, even with ``kill -9``: :mod:`sumo_ethics._worker_signals`.

The Dask executor of sweeps (:class:`sumo_ethics.sweep.executors.DaskPool`) is another thing (a
fresh subprocess per run on long-lived remote workers) with the same callbacks.
"""

from __future__ import annotations

import multiprocessing
import multiprocessing.forkserver
import os
import pickle
import signal
import tempfile
import traceback
from collections.abc import Callable, Generator, Iterable, Sequence
from multiprocessing import resource_tracker
from multiprocessing.connection import wait
from typing import TYPE_CHECKING, Any, TypeVar, cast

from sumo_ethics.errors import SumoEthicsError
from sumo_ethics.interrupt import signals_held, sigterm_as_interrupt

if TYPE_CHECKING:
    from multiprocessing.context import ForkServerContext  # defined on POSIX only

J = TypeVar("J")
R = TypeVar("R")

#: imported first by the forkserver: what every process forked from it does about signals and a dead parent
CHILD_SETUP = ("sumo_ethics._worker_signals", "sumo_ethics.processes")

_END = object()


#: the longest temporary folder the forkserver's socket is made in ([bytes]; its path adds about 32)
MAX_SOCKET_DIR = 70


def forkserver_context(preload: Sequence[str] = ()) -> ForkServerContext:
    """The forkserver context with :data:`CHILD_SETUP` and ``preload`` preloaded, its server already
    started. A server already running in this process is reused as it is.

    Python 3.11's forkserver is started as ``python -c ...``, which puts the current directory first
    on its ``sys.path``, and it ignores the parent's ``sys.path``: started from a folder holding
    another ``sumo_ethics`` (a checkout of another version), every run process imported that one
    while the parent ran the installed package. So the server is started here, at once, with
    ``PYTHONSAFEPATH=1`` (the current directory is not put on ``sys.path``) for that start alone;
    the variable stays in the server's environment, so in the run processes' too. Python 3.10 knows
    no ``PYTHONSAFEPATH``; there the current directory still comes first."""
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload([*CHILD_SETUP, *(m for m in preload if m not in CHILD_SETUP)])
    before = os.environ.get("PYTHONSAFEPATH")
    os.environ["PYTHONSAFEPATH"] = "1"
    # the server listens on a Unix socket in a folder of the temporary folder, and an AF_UNIX path
    # holds at most 107 bytes: under a long TMPDIR (a batch system's, a test's) the socket goes to /tmp
    tmp_before = tempfile.tempdir
    if len(tempfile.gettempdir()) > MAX_SOCKET_DIR and os.path.isdir("/tmp") and os.access("/tmp", os.W_OK):
        tempfile.tempdir = "/tmp"
    try:
        multiprocessing.forkserver.ensure_running()
    finally:
        tempfile.tempdir = tmp_before
        if before is None:
            os.environ.pop("PYTHONSAFEPATH", None)
        else:
            os.environ["PYTHONSAFEPATH"] = before
    return ctx


def one_line(exc: BaseException) -> str:
    """An exception as one line: a sumo-ethics error's own message, else ``Type: message``."""
    if isinstance(exc, SumoEthicsError) and str(exc):
        return str(exc)
    return "".join(traceback.format_exception_only(type(exc), exc)).strip().splitlines()[-1]


def died(exitcode: int | None) -> str:
    """Why a run process gave no result: ``run process died (exit code 3)`` or ``(killed by signal 9)``."""
    how = f"killed by signal {-exitcode}" if exitcode is not None and exitcode < 0 else f"exit code {exitcode}"
    return f"run process died ({how})"


def _child(fn: Callable[[Any], Any], job: Any, conn: Any) -> None:
    """Body of a run process: ``("ok", fn(job))`` or ``("error", exception)`` down the pipe."""
    from sumo_ethics._worker_signals import watch_parent

    watch_parent()  # killed when the process that started this one is gone, even by kill -9
    try:
        reply: tuple[str, Any] = ("ok", fn(job))
    except BaseException as exc:  # noqa: BLE001 - every failure goes back to the parent
        reply = ("error", exc)
    try:
        data = pickle.dumps(reply)
        pickle.loads(data)  # an exception that pickles but cannot be rebuilt would break the parent's recv
    except Exception as exc:  # noqa: BLE001 - a result or exception that cannot travel: its text does
        text = one_line(reply[1]) if reply[0] == "error" else \
            f"{type(reply[1]).__name__} cannot be sent back from the run process: {exc}"
        data = pickle.dumps(("error", RuntimeError(text)))
    try:
        conn.send_bytes(data)
    except OSError:  # the parent is gone (its end of the pipe closed): nobody to tell
        os._exit(1)
    conn.close()


def _stop(proc: Any) -> None:
    """SIGKILL a run process and reap it: it holds SIGINT and SIGTERM blocked, so nothing else ends it."""
    if proc.pid is not None:  # started
        proc.kill()
        proc.join(timeout=5)


def run_each(fn: Callable[[J], R], jobs: Iterable[J], workers: int, *, preload: Sequence[str] = (),
             on_error: Callable[[J, BaseException], R] | None = None,
             on_crash: Callable[[J, str], R] | None = None,
             ordered: bool = False) -> Generator[tuple[J, R], None, None]:
    """``(job, fn(job))`` for every job, each in a fresh process forked from the forkserver (with
    ``preload`` imported), at most ``workers`` at a time.

    ``fn`` and the jobs are pickled (module-level functions, ``functools.partial`` of them). The jobs
    are taken from ``jobs`` one at a time, as a process is free. Results come in the order the jobs
    finish (of those finished, the first started), so a finished result is never held back behind
    a longer job, and the next job starts when a result has been taken: a caller that stops at a
    result starts nothing more. ``ordered``: in the jobs' order instead (a job starts as soon as a
    process ends; finished results wait for the earlier ones).

    An exception raised by ``fn`` is ``on_error(job, exc)``, a process that dies without a result
    ``on_crash(job, why)`` (:func:`died`); what they return is the job's result, what they raise
    stops everything. Without them the exception (a RuntimeError naming the exit code for a crash)
    is raised here. While this runs SIGTERM raises :class:`~sumo_ethics.errors.Terminated` (when no
    one else handles it); on any exception, an interrupt or the generator being closed, the running
    processes are killed before it goes on. Close it (``contextlib.closing``) when not taking every
    result.
    """
    ctx = forkserver_context(preload)
    todo = iter(jobs)
    running: list[tuple[int, J, Any, Any]] = []  # (number, job, process, receiving end of its pipe), by start
    started = 0

    def start() -> None:
        nonlocal started
        item = next(todo, _END)
        if item is _END:
            return
        job = cast(J, item)
        recv, send = ctx.Pipe(duplex=False)
        proc = ctx.Process(target=_child, args=(fn, job, send), daemon=True)
        # multiprocessing starts its resource tracker at the first process start, and that unblocks
        # SIGINT and SIGTERM in this thread: started here, outside the block below, it cannot
        resource_tracker.ensure_running()
        # a Ctrl-C or SIGTERM now is taken when the block ends, with the process started and listed,
        # so it is stopped; and the child always gets its job (no "EOFError: Ran out of input")
        with signals_held(signal.SIGINT, signal.SIGTERM):
            running.append((started, job, proc, recv))
            try:
                proc.start()
            except BaseException:
                running.pop()
                recv.close()
                raise
            finally:
                send.close()  # the child's end: the pipe reads EOF once the child is gone
        started += 1

    def outcome(job: J, proc: Any, recv: Any) -> R:
        try:
            status: str = "crash"
            value: Any = None
            try:
                if recv.poll():
                    status, value = recv.recv()
            except (EOFError, OSError):  # gone without a reply
                status = "crash"
            proc.join(timeout=30)
        finally:
            recv.close()
            _stop(proc)  # one that sent its result and hung on the way out (or an interrupt here)
            code = proc.exitcode
            if code is not None:  # reaped (a process stuck in the kernel is left to the system)
                proc.close()
        if status == "ok":
            return value
        if status == "error":
            if on_error is None:
                raise value
            return on_error(job, value)
        if on_crash is None:
            raise RuntimeError(died(code))
        return on_crash(job, died(code))

    waiting: dict[int, tuple[J, R]] = {}  # ordered: finished results behind an earlier job
    given = 0
    with sigterm_as_interrupt():
        try:
            for _ in range(max(1, workers)):
                start()
            while running:
                ready = set(wait([r for *_, r in running] + [p.sentinel for _, _, p, _ in running]))
                k = next(i for i, (_, _, p, r) in enumerate(running) if r in ready or p.sentinel in ready)
                number, job, proc, recv = running.pop(k)
                result = outcome(job, proc, recv)
                if not ordered:
                    yield job, result
                    start()
                    continue
                waiting[number] = (job, result)
                start()
                while given in waiting:
                    yield waiting.pop(given)
                    given += 1
        finally:
            with signals_held(signal.SIGINT, signal.SIGTERM):  # a second Ctrl-C does not cut the stopping short
                for _, _, proc, recv in running:  # nothing new starts, nothing runs on
                    _stop(proc)
                    recv.close()
