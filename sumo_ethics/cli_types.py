"""Parameter types shared by the click commands (cli.py, cli_sweep.py)."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import click


class _SumoTime(click.ParamType):
    """A simulation time in SUMO's formats: ``50300``, ``0.5``, ``16:0:0`` (h:m:s), ``1:02:03:04`` (d:h:m:s);
    a clock time's minutes and seconds below 60 (``sumo_options.parse_time(strict=True)``)."""

    name = "time"

    def convert(self, value, param, ctx) -> float:
        if isinstance(value, float):
            return value
        from sumo_ethics.errors import ConfigError
        from sumo_ethics.sumo_options import parse_time

        what = param.opts[0] if param is not None else "time"
        try:
            return parse_time(value, what, strict=True)
        except ConfigError as exc:  # click names the option itself
            self.fail(str(exc).removeprefix(f"{what}: "), param, ctx)


#: --end, --ego-depart and the like: seconds or SUMO's h:m:s / d:h:m:s
SUMO_TIME = _SumoTime()


class LazyChoice(click.Choice):
    """A ``click.Choice`` whose choices are asked of ``names()`` whenever click reads them (help, parsing,
    completion), e.g. ``LazyChoice(registry.names)``: what is registered after this module is
    imported is offered too."""

    def __init__(self, names: Callable[[], Sequence[str]], case_sensitive: bool = True) -> None:
        self._names = names
        self.case_sensitive = case_sensitive

    @property
    def choices(self) -> tuple[str, ...]:
        return tuple(self._names())

    @choices.setter
    def choices(self, value: Sequence[str]) -> None:  # click's own __init__ sets it; ours asks names()
        raise AttributeError("LazyChoice reads its choices from names()")
