"""The SUMO API the sim package drives: libsumo in this process (the default), or TraCI to a
sumo-gui process (``sumo-ethics run --gui``).

Every module of ``sumo_ethics.sim`` calls SUMO through :data:`sumo` (``sumo.vehicle.getSpeed(i)``)
and names constants through :data:`tc`, so the same code drives either API; ``session.start``
picks one with :func:`use` and ``session.close`` returns to libsumo. Nothing outside this package
imports libsumo or traci. Both APIs have the same domains and calls; their constants are one
module (``libsumo.constants is traci.constants``), and importing libsumo imports traci anyway.
"""

from __future__ import annotations

from types import ModuleType
from typing import Any

import libsumo
import traci

#: SUMO's constants (the same module for both APIs)
tc = traci.constants
#: what either API raises when SUMO refuses a call or fails (TraCI: also a lost connection)
ERRORS: tuple[type[BaseException], ...] = (libsumo.TraCIException, libsumo.FatalTraCIError,
                                           traci.TraCIException, traci.FatalTraCIError)


class Api:
    """The API in use: the public names of its module as attributes (plain lookups, no forwarding
    on each call), swapped by :meth:`use`."""

    module: ModuleType

    def __init__(self, module: ModuleType) -> None:
        self.use(module)

    def use(self, module: ModuleType) -> None:
        self.__dict__.clear()
        self.__dict__.update({k: v for k, v in vars(module).items() if not k.startswith("_")})
        self.__dict__["module"] = module

    def __getattr__(self, name: str) -> Any:  # only for names the module lacks: say which API
        raise AttributeError(f"{self.__dict__['module'].__name__} has no '{name}'")


#: the SUMO API every sim module calls
sumo = Api(libsumo)


def use(gui: bool) -> None:
    """Drive SUMO through TraCI (``gui``: a sumo-gui started by ``session.start``) or libsumo."""
    sumo.use(traci if gui else libsumo)


def is_gui() -> bool:
    """Whether SUMO is driven through TraCI (a sumo-gui)."""
    return sumo.module is traci
