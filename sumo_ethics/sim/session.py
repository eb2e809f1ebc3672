"""Starting and stopping SUMO through libsumo, with the user's config checked first.

The forced options make SUMO report collisions of a moveToXY-driven ego (see SUMO.md):
``--collision.action teleport`` skips vehicles moved in the last 10 s, and the default
mingap factor counts any gap under minGap as a collision.
"""

from __future__ import annotations

import os
import sys
import tempfile
import xml.etree.ElementTree as ET
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import libsumo
import sumo

from sumo_ethics.errors import ConfigError, SimulationError

#: SUMO options the run overrides, with the value it sets.
FORCED_OPTIONS: dict[str, str] = {
    "collision.action": "warn",
    "collision.check-junctions": "true",
    "collision.mingap-factor": "0",
    "intermodal-collision.action": "warn",
}

TraCIException = libsumo.TraCIException


@dataclass(frozen=True)
class ScenarioFiles:
    """What a .sumocfg names, resolved against its folder, and the options it sets."""

    config: Path
    net: Path
    routes: tuple[Path, ...]
    additionals: tuple[Path, ...]
    options: dict[str, str]

    @property
    def end(self) -> float | None:
        value = self.options.get("end")
        try:
            return float(value) if value is not None else None
        except ValueError:
            return None


def _file_list(value: str | None, base: Path) -> tuple[Path, ...]:
    if not value:
        return ()
    return tuple((base / p).resolve() for p in value.replace(",", " ").split())


def read_scenario(path: Path) -> ScenarioFiles:
    """Parse a .sumocfg and check that every file it names exists (ConfigError otherwise)."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"scenario file not found: {path}")
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise ConfigError(f"malformed SUMO config {path}: {exc}") from None
    if root.tag not in ("configuration", "sumoConfiguration"):
        raise ConfigError(f"{path} is not a SUMO config: root element <{root.tag}>, expected <configuration> or <sumoConfiguration>")
    options: dict[str, str] = {}
    for section in root:
        for opt in section:
            if "value" in opt.attrib:
                options[opt.tag] = opt.attrib["value"]
    base = path.resolve().parent
    nets = _file_list(options.get("net-file"), base)
    if len(nets) != 1:
        raise ConfigError(f"{path} names no net-file" if not nets else f"{path} names several net-files")
    files = ScenarioFiles(
        config=path.resolve(),
        net=nets[0],
        routes=_file_list(options.get("route-files"), base),
        additionals=_file_list(options.get("additional-files"), base),
        options=options,
    )
    for kind, paths in (("net-file", (files.net,)), ("route-file", files.routes), ("additional-file", files.additionals)):
        for p in paths:
            if not p.is_file():
                raise ConfigError(f"{path}: {kind} does not exist: {p}")
    return files


def route_vehicle_ids(files: ScenarioFiles) -> tuple[set[str], set[str]] | None:
    """Vehicle ids and flow ids declared in the route files (None if a file cannot be read)."""
    vehicles: set[str] = set()
    flows: set[str] = set()
    try:
        for p in files.routes + files.additionals:
            if p.suffix == ".gz":
                return None
            for _, el in ET.iterparse(p):
                if el.tag in ("vehicle", "trip"):
                    vehicles.add(el.attrib.get("id", ""))
                elif el.tag == "flow":
                    flows.add(el.attrib.get("id", ""))
                el.clear()
    except (ET.ParseError, OSError):
        return None
    return vehicles, flows


def forced_option_report(files: ScenarioFiles) -> dict[str, dict[str, str | None]]:
    """For each forced option: the scenario's own value (None if unset) and the value forced."""
    return {k: {"scenario": files.options.get(k), "forced": v} for k, v in FORCED_OPTIONS.items()}


def sumo_binary() -> str:
    return str(Path(sumo.SUMO_HOME) / "bin" / "sumo")


def start(files: ScenarioFiles, seed: int, error_log: Path, extra: tuple[str, ...] = ()) -> None:
    """Start SUMO in this process (libsumo: one simulation per process)."""
    cmd = [sumo_binary(), "-c", str(files.config), "--seed", str(seed), "--no-step-log", "true",
           "--duration-log.disable", "true", "--no-warnings", "true", "--error-log", str(error_log)]
    for key, value in FORCED_OPTIONS.items():
        cmd += [f"--{key}", value]
    cmd += list(extra)
    with tempfile.TemporaryFile() as captured:
        try:
            with _stderr_to(captured):  # SUMO prints the cause of a failed start there, not in the exception
                libsumo.start(cmd)
        except TraCIException as exc:
            captured.seek(0)
            cause = _first_error(captured.read().decode(errors="replace")) or first_line(exc, error_log)
            raise SimulationError(f"SUMO could not start {files.config.name}: {cause}") from None
        captured.seek(0)
        rest = captured.read()
        if rest:  # a start that went through: pass on whatever SUMO printed
            sys.stderr.buffer.write(rest)
            sys.stderr.flush()


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
    for line in text.splitlines():
        if line.startswith("Error"):
            return line.removeprefix("Error: ").strip()
    return ""


def close() -> None:
    try:
        libsumo.close()
    except Exception:  # noqa: BLE001 - closing a dead simulation must not mask the real error
        pass


def version() -> str:
    try:
        return str(libsumo.getVersion()[1])
    except Exception:  # noqa: BLE001
        return "unknown"


def first_line(exc: BaseException, error_log: Path | None = None) -> str:
    """SUMO's own message for an exception: the exception text, else the first error in the log."""
    msg = str(exc).strip()
    generic = not msg or msg.lower().startswith("process error")  # libsumo's text when SUMO's own start failed
    if generic and error_log is not None and error_log.is_file():
        for line in error_log.read_text(errors="replace").splitlines():
            if line.startswith("Error"):
                msg = line.removeprefix("Error: ")
                break
    return (msg.splitlines() or ["unknown SUMO error"])[0]
