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


def parse_time(value: str, what: str) -> float:
    """A SUMO time [s]: ``50300``, ``0.5``, ``16:0:0`` (h:m:s) or ``1:02:03:04`` (d:h:m:s)."""
    text = str(value).strip()
    parts = text.split(":")
    try:
        if len(parts) == 1:
            seconds = float(text)
        elif len(parts) in (3, 4):
            nums = [float(p) for p in parts]
            seconds = sum(n * f for n, f in zip(reversed(nums), (1.0, 60.0, 3600.0, 86400.0)))
        else:
            raise ValueError(text)
    except ValueError:
        raise ConfigError(f"{what}: '{value}' is not a SUMO time (seconds, h:m:s or d:h:m:s)") from None
    if not math.isfinite(seconds):
        raise ConfigError(f"{what}: '{value}' is not a finite time")
    return seconds


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
