"""Parameter types shared by the click commands (cli.py, cli_sweep.py)."""

from __future__ import annotations

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
