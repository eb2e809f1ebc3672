"""SUMO's command-line values read and checked without SUMO: simulation times and the extra options
a user passes with ``--sumo-arg`` (standard library only; the command line, the TOML settings and the
scenario reader share them)."""

from __future__ import annotations

import math

from sumo_ethics.errors import ConfigError

#: SUMO options that write files (besides every ``*-output``/``*.output`` option)
_OUTPUT_OPTIONS = frozenset({"netstate-dump", "ndump", "netstate", "log", "l", "message-log", "save-state.files",
                             "save-state.prefix", "save-configuration", "save-template", "save-schema"})
#: options the run sets itself (``--sumo-arg`` may not change them)
_RESERVED_ARGS = frozenset({"c", "configuration-file", "seed", "error-log", "step-length", "collision.action",
                            "collision.check-junctions", "collision.mingap-factor",
                            "intermodal-collision.action", "begin", "b", "end", "e", "remote-port", "save-configuration"})


def parse_time(value: str, what: str, strict: bool = False) -> float:
    """A SUMO time [s]: ``50300``, ``0.5``, ``16:0:0`` (h:m:s) or ``1:02:03:04`` (d:h:m:s).

    SUMO itself adds the fields of a clock time up as they come (``15:99:00`` is 16:39:00), so a
    scenario file is read that way too. ``strict`` (the command line's ``--end``, ``--ego-depart``)
    refuses a clock time whose fields are not a clock's: a negative field, a fractional day, hour or
    minute, minutes or seconds of 60 or more, or hours of 24 or more after a day."""
    text = str(value).strip()
    parts = text.split(":")
    try:
        if len(parts) == 1:
            seconds = float(text)
        elif len(parts) in (3, 4):
            nums = [float(p) for p in parts]
            if strict:
                _check_clock(nums, value, what)
            seconds = sum(n * f for n, f in zip(reversed(nums), (1.0, 60.0, 3600.0, 86400.0)))
        else:
            raise ValueError(text)
    except ValueError:
        raise ConfigError(f"{what}: '{value}' is not a SUMO time (seconds, h:m:s or d:h:m:s)") from None
    if not math.isfinite(seconds):
        raise ConfigError(f"{what}: '{value}' is not a finite time")
    return seconds


def _check_clock(nums: list[float], value: str, what: str) -> None:
    """ConfigError unless h:m:s / d:h:m:s fields ``nums`` are a clock's (see :func:`parse_time`)."""
    names = ("days", "hours", "minutes", "seconds")[4 - len(nums):]
    for name, n in zip(names, nums):
        if not math.isfinite(n) or n < 0:
            raise ConfigError(f"{what}: '{value}' has {name} {n:g}: every field of a clock time is 0 or more")
        if name != "seconds" and n != int(n):
            raise ConfigError(f"{what}: '{value}' has {name} {n:g}: only the seconds of a clock time may have "
                              f"a fraction")
        limit = 24 if name == "hours" and len(nums) == 4 else 60 if name in ("minutes", "seconds") else None
        if limit is not None and n >= limit:
            read = sum(x * f for x, f in zip(reversed(nums), (1.0, 60.0, 3600.0, 86400.0)))
            raise ConfigError(f"{what}: '{value}' has {name} {n:g}; a clock time's {name} are below {limit} "
                              f"(SUMO would add the fields up to {format_time(read)})")


def format_time(seconds: float) -> str:
    """A simulation time for messages: ``75 s``; from one hour on with SUMO's clock form too,
    ``54420 s (15:07:00)`` (d:hh:mm:ss from a day), as a user gives --end or --ego-depart."""
    text = f"{seconds:g} s"
    if not math.isfinite(seconds) or seconds < 3600.0:
        return text
    whole = int(seconds)
    days, rest = divmod(whole, 86400)
    h, rest = divmod(rest, 3600)
    m, sec = divmod(rest, 60)
    frac = seconds - whole
    clock = f"{h:02d}:{m:02d}:{sec:02d}" + (f"{frac:.2f}".lstrip("0") if frac >= 0.005 else "")
    return f"{text} ({days}:{clock})" if days else f"{text} ({clock})"


def is_output_option(key: str) -> bool:
    """True for SUMO options that name a file SUMO writes (tripinfo-output, log, ...)."""
    return key.endswith("-output") or key.endswith(".output") or key in _OUTPUT_OPTIONS


def parse_sumo_args(args: tuple[str, ...]) -> tuple[str, ...]:
    """Each ``--sumo-arg`` split like a shell would (``"--time-to-teleport -1"``), then checked."""
    import shlex

    tokens: list[str] = []
    for a in args:
        try:
            tokens += shlex.split(a)
        except ValueError as exc:
            raise ConfigError(f"--sumo-arg {a!r}: {exc}") from None
    return check_sumo_args(tuple(tokens))


def check_sumo_args(tokens: tuple[str, ...]) -> tuple[str, ...]:
    """ConfigError for SUMO options the run sets itself (the config file, seed, step, times,
    collision handling, error log)."""
    for t in tokens:
        if t.startswith("-") and not _is_number(t):
            key = t.lstrip("-").split("=", 1)[0]
            if key in _RESERVED_ARGS:
                raise ConfigError(f"--sumo-arg {t}: the run sets this SUMO option itself"
                                  + {"step-length": " (use --step-length)", "end": " (use --end)",
                                     "e": " (use --end)", "seed": " (use --seed)"}.get(key, ""))
    return tokens


def _is_number(t: str) -> bool:
    try:
        float(t)
        return True
    except ValueError:
        return False


#: an environment variable: when it holds the path of a file in a folder that exists, every start of
#: SUMO, sumo-gui or netconvert is refused (RuntimeError) and the file is written; the test suite sets
#: it for the tests not marked ``sumo`` (tests/conftest.py), so that ``pytest -m "not sumo"`` starts no
#: SUMO, and removes the folder after each test (a process that outlives the test, such as a
#: forkserver started in it, keeps the variable but is no longer barred). Unset in normal use.
NO_SUMO_ENV = "SUMO_ETHICS_NO_SUMO"


def refuse_if_barred(what: str) -> None:
    """Raise RuntimeError (after writing ``what`` to the file it names) when :data:`NO_SUMO_ENV` names
    a file in a folder that exists."""
    import os

    flag = os.environ.get(NO_SUMO_ENV)
    if flag and os.path.isdir(os.path.dirname(flag)):
        with open(flag, "a", encoding="utf-8") as f:
            f.write(f"{what} (process {os.getpid()})\n")
        raise RuntimeError(f"{what} refused: {NO_SUMO_ENV} is set (a test not marked sumo)")
