"""Errors a user can cause or meet; the CLI prints each as one line and exits non-zero."""

import math
import numbers
import sys


class SumoEthicsError(Exception):
    """Base class: a problem the user can act on, reported without a traceback."""

    exit_code = 1


class ConfigError(SumoEthicsError):
    """Bad input: a missing or malformed file, a nonsense parameter value, an unknown id."""

    exit_code = 2


class SimulationError(SumoEthicsError):
    """SUMO failed or the simulation could not continue."""

    exit_code = 3


class Terminated(KeyboardInterrupt):
    """The process got SIGTERM: handled like Ctrl-C (outputs and summary written), exit 143."""


class OutputError(SumoEthicsError):
    """The outputs could not be written (a full disk, a file size limit): not the input's fault."""

    exit_code = 1


def add_note(exc: BaseException, note: str) -> None:
    """``exc.add_note(note)``: a line the CLI adds to the error's one line (cli.main reads ``__notes__``).

    BaseException.add_note is Python 3.11+; on 3.10 the note goes into the same ``__notes__`` list by hand.
    """
    if sys.version_info >= (3, 11):
        exc.add_note(note)
    else:
        notes = getattr(exc, "__notes__", None)
        if notes is None:
            notes = []
            setattr(exc, "__notes__", notes)  # noqa: B010 (no such attribute in 3.10's BaseException)
        notes.append(note)


def is_number(value: object, lo: float = -math.inf, hi: float = math.inf, *, lo_open: bool = False,
              hi_open: bool = False, integer: bool = False) -> bool:
    """The package's one test of a number a user gave: a real number (Python or numpy, never a bool),
    finite, an integer type if ``integer``, and within [lo, hi] (``lo_open``/``hi_open``: that end
    excluded). Each caller words its own one-line message."""
    # numpy's scalar types register with the numbers ABCs (numpy's bool does not), so no numpy import here
    if isinstance(value, bool) or not isinstance(value, numbers.Integral if integer else numbers.Real):
        return False
    v = float(value)
    if not math.isfinite(v):
        return False
    return (v > lo if lo_open else v >= lo) and (v < hi if hi_open else v <= hi)
