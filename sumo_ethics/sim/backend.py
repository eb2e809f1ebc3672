"""The SUMO API the sim package drives: libsumo in this process (the default), or TraCI to a
sumo-gui process (``sumo-ethics run --gui``).

Every module of ``sumo_ethics.sim`` calls SUMO through :data:`sumo` (``sumo.vehicle.getSpeed(i)``)
and names constants through :data:`tc`, so the same code drives either API; ``session.start``
picks one with :func:`use` and ``session.close`` returns to libsumo. Nothing outside this package
imports libsumo or traci. Both APIs have the same domains and calls; their constants are one
module (``libsumo.constants is traci.constants``), and importing libsumo imports traci anyway.
"""

from __future__ import annotations

import contextlib
import io
import subprocess
import time
from types import ModuleType
from typing import IO, Any

import libsumo
import traci
from sumolib.miscutils import getFreeSocketPort

from sumo_ethics.sumo_options import refuse_if_barred

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
        for name in ("start", "load"):  # a SUMO start refused where the tests bar it (sumo_options.NO_SUMO_ENV)
            if name in self.__dict__:
                self.__dict__[name] = _barred(self.__dict__[name], f"{module.__name__}.{name}")

    def __getattr__(self, name: str) -> Any:  # only for names the module lacks: say which API
        raise AttributeError(f"{self.__dict__['module'].__name__} has no '{name}'")


def _barred(call: Any, what: str) -> Any:
    """``call``, refused while :data:`sumo_ethics.sumo_options.NO_SUMO_ENV` is set."""

    def guarded(*args: Any, **kwargs: Any) -> Any:
        refuse_if_barred(what)
        return call(*args, **kwargs)

    return guarded


#: the SUMO API every sim module calls
sumo = Api(libsumo)


def use(gui: bool) -> None:
    """Drive SUMO through TraCI (``gui``: a sumo-gui started by ``session.start``) or libsumo."""
    sumo.use(traci if gui else libsumo)


def is_gui() -> bool:
    """Whether SUMO is driven through TraCI (a sumo-gui)."""
    return sumo.module is traci


#: [s] how long a starting sumo-gui may take to accept the connection (it loads the network first)
CONNECT_PATIENCE = 120.0
_process: subprocess.Popen | None = None


def start_gui(cmd: list[str], stderr: IO[bytes]) -> None:
    """Start ``cmd`` (a sumo-gui command line) as a process writing its output to ``stderr``,
    connect to it through TraCI and drive SUMO through it from now on.

    Raises traci's FatalTraCIError if the process ends before it accepts the connection (no
    display, a bad option) or does not accept it within CONNECT_PATIENCE. traci.start is not
    used: it prints its retries and starts a failed SUMO again, up to 60 times.
    """
    global _process
    refuse_if_barred("sumo-gui")
    port = getFreeSocketPort()
    proc = subprocess.Popen([*cmd, "--remote-port", str(port)], stdin=subprocess.DEVNULL,
                            stdout=subprocess.DEVNULL, stderr=stderr)
    deadline = time.monotonic() + CONNECT_PATIENCE
    try:
        while True:
            if proc.poll() is not None:
                raise traci.FatalTraCIError(f"sumo-gui ended (exit code {proc.returncode}) before it could be driven")
            try:
                with contextlib.redirect_stdout(io.StringIO()):  # traci's notes on failed attempts
                    traci.init(port, numRetries=0, proc=proc)
                break
            except traci.FatalTraCIError:  # not listening yet
                if time.monotonic() > deadline:
                    raise traci.FatalTraCIError(f"sumo-gui did not accept a connection within "
                                                f"{CONNECT_PATIENCE:g} s") from None
                time.sleep(0.2)
    except BaseException:
        _stop(proc, 0.0)
        raise
    _process = proc
    use(True)


def close() -> None:
    """End the running simulation (a sumo-gui: its process too) and return to libsumo."""
    global _process
    try:
        sumo.close(**({"wait": False} if is_gui() else {}))
    finally:
        if _process is not None:
            _stop(_process)
            _process = None
        use(False)


def _stop(proc: subprocess.Popen, patience: float = 10.0) -> None:
    """Wait for ``proc`` to end (sumo-gui quits when the connection closes), else kill it."""
    try:
        proc.wait(timeout=patience)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
