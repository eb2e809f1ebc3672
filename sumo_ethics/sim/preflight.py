"""Checks of a scenario's files before SUMO starts, by XML parsing alone (no libsumo).

SUMO reports a malformed or empty net or routes file only as "Process Error" after printing
its own lines, and a ``<net/>`` without edges crashes it (segmentation fault, no message).
These checks turn such input into one ConfigError line (exit code 2) and are cheap enough to
run once per distinct scenario of a sweep before any run starts.
"""

from __future__ import annotations

import gzip
import io
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

from sumo_ethics.errors import ConfigError

EGO_CLASS = "passenger"


@dataclass(frozen=True)
class NetInfo:
    """Normal edges of a net (no internal, crossing or walking-area edges) and whether at least
    one lane of each allows a passenger car."""

    path: Path
    passenger: dict[str, bool]


def _open(path: Path) -> gzip.GzipFile | io.BufferedReader:
    return gzip.open(path, "rb") if path.suffix == ".gz" else open(path, "rb")


def _allows(lane: dict[str, str], vclass: str = EGO_CLASS) -> bool:
    allow, disallow = lane.get("allow"), lane.get("disallow")
    if allow is not None:
        names = set(allow.split())
        return vclass in names or "all" in names
    if disallow is not None:
        names = set(disallow.split())
        return not (vclass in names or "all" in names)
    return True


def check_net(path: Path) -> NetInfo:
    """Parse the net file: well-formed XML, root ``<net>``, at least one edge with a lane."""
    path = Path(path)
    edges: dict[str, bool] = {}
    root_tag = None
    current: str | None = None
    try:
        with _open(path) as f:
            for event, el in ET.iterparse(f, events=("start", "end")):
                if event == "start":
                    if root_tag is None:
                        root_tag = el.tag
                        if root_tag != "net":
                            raise ConfigError(f"{path} is not a SUMO net file: root element <{root_tag}>, "
                                              "expected <net>")
                    elif el.tag == "edge" and el.attrib.get("function", "normal") == "normal":
                        current = el.attrib.get("id")
                        if current is not None:
                            edges.setdefault(current, False)
                    continue
                if el.tag == "lane" and current is not None:
                    edges[current] = edges[current] or _allows(el.attrib)
                elif el.tag == "edge":
                    current = None
                    el.clear()
    except ET.ParseError as exc:
        raise ConfigError(f"malformed net file {path}: {exc}") from None
    except (OSError, EOFError) as exc:
        raise ConfigError(f"cannot read net file {path}: {getattr(exc, 'strerror', None) or exc}") from None
    if root_tag is None:
        raise ConfigError(f"net file {path} is empty")
    if not edges:
        raise ConfigError(f"net file {path} has no edges (SUMO cannot run on it)")
    return NetInfo(path, edges)


@dataclass(frozen=True)
class ScenarioCheck:
    """What the checks found: the net's edges, and the vehicle (and trip) and flow ids declared in
    the route and additional files (read in the same pass, so each file is parsed once)."""

    net: NetInfo
    vehicles: frozenset[str]
    flows: frozenset[str]


def check_xml(path: Path, kind: str, vehicles: set[str] | None = None, flows: set[str] | None = None) -> None:
    """A route or additional file: well-formed XML (ConfigError otherwise); the ids of its
    vehicles and trips, and of its flows, are added to ``vehicles`` and ``flows``."""
    try:
        with _open(Path(path)) as f:
            for _, el in ET.iterparse(f):
                if vehicles is not None and el.tag in ("vehicle", "trip"):
                    vehicles.add(el.attrib.get("id", ""))
                elif flows is not None and el.tag == "flow":
                    flows.add(el.attrib.get("id", ""))
                el.clear()
    except ET.ParseError as exc:
        raise ConfigError(f"malformed {kind} {path}: {exc}") from None
    except (OSError, EOFError) as exc:
        raise ConfigError(f"cannot read {kind} {path}: {getattr(exc, 'strerror', None) or exc}") from None


def check_ego_edges(net: NetInfo, ego_from: str | None, ego_to: str | None) -> None:
    """--ego-from/--ego-to: edges of the net on which a passenger car may drive."""
    for flag, edge in (("--ego-from", ego_from), ("--ego-to", ego_to)):
        if edge is None:
            continue
        if edge not in net.passenger:
            raise ConfigError(f"unknown edge '{edge}' in {flag}: the net {net.path.name} has no such edge")
        if not net.passenger[edge]:
            raise ConfigError(f"{flag} edge '{edge}' has no lane a passenger car may use (the ego is a passenger car)")


def check_scenario(files, ego_from: str | None = None, ego_to: str | None = None) -> ScenarioCheck:
    """Every check above for a :class:`~sumo_ethics.sim.session.ScenarioFiles`."""
    net = check_net(files.net)
    vehicles: set[str] = set()
    flows: set[str] = set()
    for p in files.routes:
        check_xml(p, "route file", vehicles, flows)
    for p in files.additionals:
        check_xml(p, "additional file", vehicles, flows)
    check_ego_edges(net, ego_from, ego_to)
    return ScenarioCheck(net, frozenset(vehicles), frozenset(flows))
