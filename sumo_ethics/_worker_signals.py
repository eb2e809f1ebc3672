"""Imported by the run processes' forkserver alone (:func:`sumo_ethics.processes.forkserver_context`
preloads it; never imported by a main process): the one routine by which run processes ignore
Ctrl-C and die with their parent, for evaluate, sweeps and dataset recording alike.

Every run process forked from that server

- never sees Ctrl-C (SIGINT) or SIGTERM: the server ignores SIGINT and holds both blocked, and
  its children inherit that from their first instruction. A terminal's Ctrl-C reaches the whole
  process group, and a SIGTERM may too; the parent owns cancellation and kills its runs (SIGKILL,
  :func:`sumo_ethics.processes.run_each`), whereas a signal landing in a run process printed a
  traceback or ended the run as a crash;
- dies with the process that started it (the evaluation, sweep or dataset build), even when that
  is killed with ``kill -9``: :func:`watch_parent`, called first in the run process, kills the
  process as soon as the starting process's sentinel pipe closes (the forkserver itself stays
  alive while its children hold its pipe, so a parent-death signal alone is not enough); and on
  Linux ``prctl(PR_SET_PDEATHSIG, SIGKILL)`` right after the fork kills it when the forkserver dies.
  A killed sweep's temporary run folders are removed when it starts again; a dataset build keeps
  only finished runs.
"""

import os
import signal
import sys

signal.signal(signal.SIGINT, signal.SIG_IGN)
signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})

FORKSERVER_PID = os.getpid()
PR_SET_PDEATHSIG = 1


def die_with_parent() -> None:
    """In a freshly forked run process: be killed when the forkserver goes away."""
    if not sys.platform.startswith("linux"):
        return
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
    except (OSError, AttributeError):  # pragma: no cover - no prctl: workers are still stopped on Ctrl-C
        return
    if os.getppid() != FORKSERVER_PID:  # the parent died before prctl took effect
        os._exit(1)


os.register_at_fork(after_in_child=die_with_parent)


def watch_parent() -> None:
    """In a run process: a daemon thread that kills this process when the process that started
    it (the sweep) is gone, whichever way it died."""
    import multiprocessing
    import threading
    from multiprocessing.connection import wait

    parent = multiprocessing.parent_process()
    sentinel = getattr(parent, "sentinel", None)
    if sentinel is None:
        return

    def watch() -> None:
        wait([sentinel])
        os.kill(os.getpid(), signal.SIGKILL)

    threading.Thread(target=watch, name="die-with-parent", daemon=True).start()
