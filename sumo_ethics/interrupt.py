"""SIGTERM handled like Ctrl-C: a run writes its outputs and summary, a sweep stops its runs."""

from __future__ import annotations

import signal
import threading
from contextlib import AbstractContextManager, contextmanager, nullcontext
from typing import Any, Iterator

from sumo_ethics.errors import Terminated


@contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """Within: SIGTERM raises :class:`Terminated` (a KeyboardInterrupt). Only in the main thread
    and only when nobody else has set a SIGTERM handler; a second SIGTERM kills at once."""
    if threading.current_thread() is not threading.main_thread() or \
            signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL:
        yield
        return

    def handler(signum: int, frame: Any) -> None:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        raise Terminated()

    signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


@contextmanager
def signals_blocked(*signums: int) -> Iterator[None]:
    """Within: these signals wait (blocked in this thread) until the block is left, then arrive.
    A process started inside inherits the block through fork and exec. On platforms with
    ``pthread_sigmask`` only (elsewhere nothing is blocked)."""
    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, set(signums))
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def sigterm_deferred() -> AbstractContextManager[None]:
    """Within: SIGTERM waits (blocked) until the block is left, so the outputs of a run that is
    ending are written whole. Only in the main thread."""
    if threading.current_thread() is not threading.main_thread():
        return nullcontext()
    return signals_blocked(signal.SIGTERM)
