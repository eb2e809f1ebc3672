"""How many threads the planner's numba kernels may use in this process, and the pool they run in.

The risk kernels (:mod:`sumo_ethics.ethics.search`) release the GIL (numba ``nogil``), so one
planning step can split its candidates over several threads. Each thread computes whole rows of
candidates, and the rows are put back together in order: the result is the same bytes with any
number of threads.

The number is set once per process: ``sumo-ethics run`` takes the cores it may run on (``--threads``),
while every process of ``evaluate``, ``sweep`` and dataset recording keeps one thread, so that
workers never share a core. The environment variable ``SUMO_ETHICS_THREADS`` gives the default of
a process that sets nothing (1 when unset).
"""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Sequence, TypeVar

__all__ = ["available", "threads", "set_threads", "map_ordered", "spans"]

T = TypeVar("T")
_local = threading.local()  # .inside: this thread is one of the pool's
_threads: int | None = None
_pool: ThreadPoolExecutor | None = None


def available() -> int:
    """The cores this process may run on (its CPU affinity; os.cpu_count() where that is unknown)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def threads() -> int:
    """The threads a kernel may use now (>= 1)."""
    global _threads
    if _threads is None:
        raw = os.environ.get("SUMO_ETHICS_THREADS", "1")
        try:
            _threads = max(1, int(raw)) if raw != "auto" else available()
        except ValueError:
            _threads = 1
    return _threads


def set_threads(n: int | str) -> int:
    """Set the threads of this process: a number >= 1 or "auto" (:func:`available`); returns it."""
    global _threads, _pool
    value = available() if n == "auto" else int(n)
    if value < 1:
        raise ValueError(f"threads must be at least 1 or 'auto', got {n!r}")
    if _pool is not None and value != _threads:
        _pool.shutdown(wait=True)
        _pool = None
    _threads = value
    return value


def spans(rows: int, parts: int) -> list[tuple[int, int]]:
    """``rows`` split into at most ``parts`` contiguous (start, stop) spans of nearly equal size."""
    parts = max(1, min(parts, rows))
    edges = [rows * i // parts for i in range(parts + 1)]
    return [(a, b) for a, b in zip(edges[:-1], edges[1:]) if b > a]


def map_ordered(fn: Callable[..., T], args: Sequence[tuple]) -> list[T]:
    """[fn(*a) for a in args], run on :func:`threads` threads where there is more than one. A call
    from inside one of those threads (a fleet's egos planning in parallel, each splitting its risk
    kernels) runs in that thread: the pool's threads never wait on tasks queued behind them."""
    global _pool
    n = threads()
    if n == 1 or len(args) < 2 or getattr(_local, "inside", False):
        return [fn(*a) for a in args]
    if _pool is None:
        _pool = ThreadPoolExecutor(max_workers=n, thread_name_prefix="sumo-ethics")

    def task(a: tuple) -> T:
        _local.inside = True
        try:
            return fn(*a)
        finally:
            _local.inside = False

    return list(_pool.map(task, args))
