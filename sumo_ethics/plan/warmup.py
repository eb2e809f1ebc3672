"""The planner's numba kernels compiled before its first step, in a background process.

numba compiles a kernel the first time it is called and keeps the machine code in its cache
(``__pycache__`` beside the source, or numba's user cache where that is not writable), from which
later processes load it in a fraction of a second. On a fresh install the first planning step
would spend about 9 s compiling :mod:`sumo_ethics.ethics.search`, the envelope kernel of
:mod:`sumo_ethics.ethics.shapes`, the feasibility check of :mod:`sumo_ethics.plan.feasibility` and the
candidates' kernel of :mod:`sumo_ethics.plan.sampling`.

So ``sumo-ethics run``, ``evaluate`` and ``sweep`` call :func:`start` first thing: two separate
processes (a second core where there is one) compile the kernels for the argument types the planner
calls them with (:func:`compile_kernels`, :func:`compile_helpers`), while the main process loads the
scenario, the predictor and SUMO and simulates up to the takeover. The planner's first step calls :func:`wait` and then
loads the compiled kernels from the cache. Where the cache is already warm the process only loads
them. Nothing depends on it: if it fails, the first step compiles as before; the code is the same
either way, so the results are too.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np

__all__ = ["compile_kernels", "compile_helpers", "start", "wait"]

_pending: list[subprocess.Popen] = []


def compile_helpers() -> None:
    """Compile (or load) the search kernel's late helpers, then the envelope and feasibility kernels
    on their own: the second of :func:`start`'s two processes (the first: the candidates' kernels,
    then the search kernel). The search kernel's compile, in the
    first, then finds these in the cache instead of compiling them itself (numba caches every
    function apart)."""
    from sumo_ethics.ethics import search, shapes

    buf = np.empty((4, 8))
    shapes._entry_p(1.0, 0.5, 1.0, 0.0, 2.25, 0.9, 1.0, 0.0, 2.25, 0.9, 0.5, 0.0, 0.5, 3.0, 6.0, buf)
    search._order_harm(1.0, 0.5, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 10.0, 5.0, 0.5, 0.5, False, False,
                       tuple(float(c) for c in _coefficients()))
    search._upper(1.0, 0.5, 1.0, 0.0, 2.25, 0.9, 1.0, 0.0, 0.5, 0.5, 2.25, 0.9)
    search._lower(1.0, 0.5, 1.0, 0.0, 1.0, 0.0, 2.25, 0.9, 2.25, 0.9, 1.0, 0.0, 0.5, 0.5, 2.25, 0.9)
    compile_kernels(search_kernel=False, sampling=False)


def _coefficients() -> np.ndarray:
    from sumo_ethics.ethics.harm import HarmCoefficients

    return HarmCoefficients().as_array()


def compile_kernels(search_kernel: bool = True, sampling: bool = True) -> None:
    """Call every kernel the planner uses once on a tiny input (types as in a planning step):
    numba compiles them, or loads them from its cache (``search_kernel=False``: not the risk's
    search kernel; ``sampling=False``: not the candidates' kernels). The candidates' kernels come
    first: in :func:`start`'s first process they compile while the second compiles the search
    kernel's helpers, which the search kernel then loads."""
    from sumo_ethics.config import EgoVehicle
    from sumo_ethics.contract import RoutePath
    from sumo_ethics.ethics.harm import HarmCoefficients
    from sumo_ethics.ethics.search import bounded_terms
    from sumo_ethics.ethics.shapes import envelope_first_hit
    from sumo_ethics.geometry import Polyline
    from sumo_ethics.plan.feasibility import check
    from sumo_ethics.plan.sampling import FrenetState, SamplingConfig, sample
    from sumo_ethics.types import Candidates

    K, T, N = 2, 3, 1
    t = np.arange(1, T + 1) * 0.1
    ex = np.stack([10.0 * t, 10.0 * t + 0.5])
    ey, eyaw, ev = np.zeros((K, T)), np.zeros((K, T)), np.full((K, T), 10.0)
    valid = np.ones((K, T), bool)
    mx, my, psi, av = np.full((N, T), 4.0), np.full((N, T), 1.0), np.zeros((N, T)), np.zeros((N, T))
    var = np.full((N, T), 0.25)
    one = np.ones(N)
    path = Polyline.from_points(np.array([[0.0, 0.0], [100.0, 0.0]]))
    if sampling:
        sample(path, FrenetState(s=1.0, d=0.0, s_dot=5.0), SamplingConfig(horizons=(0.2,), n_speeds=2, n_offsets=2),
               10.0)
    if search_kernel:
        bounded_terms(ex, ey, eyaw, ev, valid, mx, my, psi, av, var, np.zeros((N, T)), var, np.full(N, 4.5),
                      np.full(N, 1.8), 4.5, 1.8, np.full(N, 3.0), 6.0, 1e-3, 1e-2, 1e-4, False, one, 1475.0, False,
                      np.full(N, 1400.0), np.zeros(N, bool), HarmCoefficients().as_array())
    envelope_first_hit(ex, ey, eyaw, ev, valid, mx, my, psi, np.full(N, 5.5), np.full(N, 2.3), 4.5, 1.8, 8.0)
    route = RoutePath(edges=("e",), path=path, lane_of_vertex=("e_0", "e_0"), speed_limit=np.full(2, 14.0),
                      left=np.full(2, 3.0), right=np.full(2, -3.0), links=())
    z = np.zeros((K, T))
    check(Candidates(0.1, ex, ey, eyaw, ev, z, z, ex, z, np.full(K, 0.3), valid, road_curvature=z), route, EgoVehicle())


def start() -> None:
    """Compile the kernels in two background processes (once per process; a no-op while they
    run): one compiles the search kernel, the other the envelope and feasibility kernels and the
    search kernel's late helpers, which the first then loads from the cache (about a quarter less
    time than one process compiling all, measured with tools/bench_first_run.py)."""
    global _pending
    if _pending:
        return
    root = str(Path(__file__).resolve().parents[2])  # the folder holding this sumo_ethics
    env = dict(os.environ, PYTHONSAFEPATH="1",
               PYTHONPATH=os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH", "")) if p))
    for call in ("compile_kernels()", "compile_helpers()"):
        try:
            _pending.append(subprocess.Popen(
                [sys.executable, "-c", f"from sumo_ethics.plan.warmup import compile_kernels, compile_helpers; {call}"],
                env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        except OSError:  # no process to be had: the first step compiles
            break


def wait(timeout: float = 300.0) -> None:
    """Wait for :func:`start`'s processes, if any (at most ``timeout`` s each; then the first
    step compiles whatever is not cached)."""
    global _pending
    procs, _pending = _pending, []
    for proc in procs:
        try:
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
