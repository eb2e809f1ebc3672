"""Starting and stopping SUMO (libsumo in this process, or a sumo-gui driven through TraCI),
with the user's config checked first.

The forced options make SUMO report collisions of a moveToXY-driven ego (see SUMO.md):
``--collision.action teleport`` skips vehicles moved in the last 10 s, and the default
mingap factor counts any gap under minGap as a collision.
"""

from __future__ import annotations

import os
import sys
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Iterator

from sumo import SUMO_HOME

from sumo_ethics.errors import ConfigError, SimulationError
from sumo_ethics.sim import backend
from sumo_ethics.sim.backend import sumo
from sumo_ethics.sim.scenario import ScenarioFiles, read_scenario  # noqa: F401 - re-exported

if TYPE_CHECKING:
    from sumo_ethics.sim.gui import GuiOptions

#: SUMO options the run overrides, with the value it sets.
FORCED_OPTIONS: dict[str, str] = {
    "collision.action": "warn",
    "collision.check-junctions": "true",
    "collision.mingap-factor": "0",
    "intermodal-collision.action": "warn",
}


def forced_option_report(files: ScenarioFiles) -> dict[str, dict[str, str | None]]:
    """For each forced option: the scenario's own value (None if unset) and the value forced."""
    return {k: {"scenario": files.options.get(k), "forced": v} for k, v in FORCED_OPTIONS.items()}


def sumo_binary(gui: bool = False) -> str:
    return str(Path(SUMO_HOME) / "bin" / ("sumo-gui" if gui else "sumo"))


def start(files: ScenarioFiles, seed: int, error_log: Path, extra: tuple[str, ...] = (),
          step_length: float | None = None, outputs: dict[str, str] | None = None,
          gui: GuiOptions | None = None) -> None:
    """Start SUMO in this process (libsumo: one simulation per process), or with ``gui`` a
    sumo-gui process driven through TraCI (a ConfigError if it cannot open a display).

    step_length [s]: overrides the scenario's; outputs: option -> file, the scenario's own
    output options redirected (see ``scenario.redirected``); extra: more options
    (``--sumo-arg``), last so they win. A start failure raises SimulationError with SUMO's
    own reason: SUMO prints config errors to stderr before its error log exists, so stderr
    is captured while it starts (passed on if SUMO started; else its reason is in the error).
    """
    # SUMO stays silent on the console whatever the scenario asks for (its verbose loading log and
    # end-of-run statistics, e.g. eclipse-sumo's scenarios with duration-log.statistics): the run
    # prints its own summary, and --quiet means quiet
    cmd = [sumo_binary(gui is not None), "-c", str(files.config), "--seed", str(seed), "--no-step-log", "true",
           "--duration-log.disable", "true", "--duration-log.statistics", "false", "--verbose", "false",
           "--no-warnings", "true", "--error-log", str(error_log)]
    for key, value in FORCED_OPTIONS.items():
        cmd += [f"--{key}", value]
    if step_length is not None:
        cmd += ["--step-length", f"{step_length:g}"]
    cmd += output_args(outputs or {})
    if gui is not None:
        cmd += gui.sumo_args()
    cmd += list(extra)
    with tempfile.TemporaryFile() as captured:
        try:
            if gui is None:
                with _stderr_to(captured):  # SUMO prints the cause of a failed start there, not in the exception
                    sumo.start(cmd)
            else:
                backend.start_gui(cmd, captured)
        except backend.ERRORS as exc:
            captured.seek(0)
            text = captured.read().decode(errors="replace")
            if gui is not None and "openDisplay" in text:  # FXApp::openDisplay: unable to open display :9
                raise ConfigError(f"--gui: sumo-gui cannot open the display {os.environ.get('DISPLAY', '')!r} "
                                  f"({text.strip().splitlines()[0]}); run without --gui, or under xvfb-run") from None
            cause = _first_error(text) or first_line(exc, error_log)
            raise SimulationError(f"SUMO could not start {files.config.name}: {cause}") from None
        captured.seek(0)
        rest = captured.read()
        if gui is not None:  # SUMO's own messages, not the toolkit's (Fontconfig, Mesa, ...)
            rest = b"".join(ln for ln in rest.splitlines(keepends=True) if ln.startswith((b"Error", b"Warning")))
        if rest:  # a start that went through: pass on whatever SUMO printed
            sys.stderr.buffer.write(rest)
            sys.stderr.flush()


def output_args(outputs: dict[str, str]) -> list[str]:
    """SUMO options for ``outputs`` (option -> value, e.g. ``scenario.redirected``), the folder of
    each output file created (``additional-files`` names inputs: left alone)."""
    args: list[str] = []
    for key, value in outputs.items():
        if key != "additional-files":
            Path(value.split()[0]).parent.mkdir(parents=True, exist_ok=True)
        args += [f"--{key}", value]
    return args


@contextmanager
def _stderr_to(f) -> Iterator[None]:
    """File descriptor 2 (SUMO's C++ output) into the open file ``f`` while inside."""
    sys.stderr.flush()
    saved = os.dup(2)
    os.dup2(f.fileno(), 2)
    try:
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def _first_error(text: str) -> str:
    """SUMO's first error in what it printed, with its indented continuation lines (an unknown
    option: "On processing option '--x':" then " No option with the name 'x' exists.")."""
    lines = text.splitlines()
    for i, line in enumerate(lines):
        if line.startswith("Error"):
            parts = [line.removeprefix("Error: ").strip()]
            for more in lines[i + 1:]:
                if not more[:1].isspace():
                    break
                parts.append(more.strip())
            return " ".join(p for p in parts if p)
    return ""


#: what libsumo or TraCI raises when SUMO fails during a run
SUMO_ERRORS = backend.ERRORS


def step_length() -> float:
    """The running simulation's step length [s]."""
    return sumo.simulation.getDeltaT()


def sim_time() -> float:
    """The running simulation's time [s]."""
    return sumo.simulation.getTime()


def close() -> None:
    try:
        backend.close()
    except Exception:  # noqa: BLE001 - closing a dead simulation must not mask the real error
        pass


def version() -> str:
    try:
        return str(sumo.getVersion()[1])
    except Exception:  # noqa: BLE001
        return "unknown"


def first_line(exc: BaseException, error_log: Path | None = None) -> str:
    """SUMO's own message for an exception: the exception text, else the first error in the log."""
    msg = str(exc).strip()
    if backend.is_gui() and isinstance(exc, backend.traci.FatalTraCIError):  # e.g. its window was closed
        return f"the connection to sumo-gui was lost ({msg or 'no reason given'}); was its window closed?"
    generic = not msg or msg.lower().startswith("process error")  # libsumo's text when SUMO's own start failed
    if generic and error_log is not None and error_log.is_file():
        for line in error_log.read_text(errors="replace").splitlines():
            if line.startswith("Error"):
                msg = line.removeprefix("Error: ")
                break
    return (msg.splitlines() or ["unknown SUMO error"])[0]
