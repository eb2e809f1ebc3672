"""Imported only by the sweep's and the evaluation's forkservers (never by a main process).

Every run process forked from them

- ignores Ctrl-C (SIGINT) from its first instruction: a terminal's Ctrl-C reaches the whole
  process group; the parent owns cancellation and terminates its runs, whereas a SIGINT landing
  in a run process printed a traceback;
- dies with its parent (Linux: ``prctl(PR_SET_PDEATHSIG, SIGKILL)`` right after the fork). Its
  parent is the forkserver, which exits when the sweep's process goes away, even by ``kill -9``,
  so no run keeps running (and writing) after its sweep is gone. Its temporary run folder is
  removed when the sweep starts again.
"""

import os
import signal
import sys

signal.signal(signal.SIGINT, signal.SIG_IGN)

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
