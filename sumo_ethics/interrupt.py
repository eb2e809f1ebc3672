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
def signals_held(*signums: int) -> Iterator[None]:
    """Within: these signals wait until the block is left, then arrive (their handlers run then).

    They are blocked in this thread, and a process started inside inherits the block through fork
    and exec (it never sees them). A process-directed signal can still be taken by another thread
    that does not block it (numpy's BLAS threads do not), and Python would then run the handler in
    the main thread inside the block: so in the main thread the handlers are also replaced by a
    recorder for the block, and each held signal is raised again after it. Elsewhere only the
    block; on platforms without ``pthread_sigmask``, only the recorder."""
    main = threading.current_thread() is threading.main_thread()
    held: list[int] = []
    old_handlers = {s: signal.signal(s, lambda signum, frame: held.append(signum)) for s in signums} if main else {}
    old_mask = signal.pthread_sigmask(signal.SIG_BLOCK, set(signums)) if hasattr(signal, "pthread_sigmask") else None
    try:
        yield
    finally:
        if old_mask is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, old_mask)  # a pending one is recorded now
        for s, handler in old_handlers.items():
            signal.signal(s, handler)
        for s in dict.fromkeys(held):  # each once, in order: the original handler takes it
            signal.raise_signal(s)


def sigterm_deferred() -> AbstractContextManager[None]:
    """Within: SIGTERM waits until the block is left (:func:`signals_held`), so the outputs of a
    run that is ending are written whole. Only in the main thread."""
    if threading.current_thread() is not threading.main_thread():
        return nullcontext()
    return signals_held(signal.SIGTERM)
