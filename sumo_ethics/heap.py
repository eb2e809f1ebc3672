"""Giving the C heap's free memory back to the system (glibc's ``malloc_trim``).

A long fleet run frees as much as it allocates (egos come and go), but glibc keeps the freed
chunks of its heap resident: a chunk still in use above them pins the heap's top, and free pages
inside the heap are only returned by ``malloc_trim``. Over 300 s of urban_grid at penetration 1
that was about 6 MB per 100 simulated seconds of free-but-kept heap (issue 39,
docs/fleets.md). :func:`trim` returns those pages; elsewhere than
glibc (musl, macOS) it does nothing.
"""

from __future__ import annotations

import ctypes
from typing import Any

_malloc_trim: Any = None  # the C function, False where the C library has none


def _function() -> Any:
    global _malloc_trim
    if _malloc_trim is None:
        try:
            f = ctypes.CDLL(None).malloc_trim  # the process's own symbols: its C library
            f.argtypes, f.restype = [ctypes.c_size_t], ctypes.c_int
            _malloc_trim = f
        except (OSError, AttributeError):
            _malloc_trim = False
    return _malloc_trim


def available() -> bool:
    """Whether the C library can trim its heap (glibc)."""
    return bool(_function())


def trim() -> bool:
    """Return the C heap's free pages to the system (``malloc_trim(0)``); True if some were
    released, False if none were or the C library cannot trim."""
    f = _function()
    return bool(f and f(0))
