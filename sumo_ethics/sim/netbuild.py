"""Building SUMO networks from plain XML with netconvert: the one builder behind the bundled
networks (``tools/build_networks.py``) and the suite's base networks (``suite/networks.py``).

:class:`PlainNet` collects nodes, edges, connections and crossings and writes
``<name>.nod.xml``, ``.edg.xml``, ``.con.xml``, runs netconvert (options :data:`OPTIONS` plus
the network's own) and writes ``<name>.net.xml``. Coordinates are kept as written
(``--offset.disable-normalization``); the run-dependent part of netconvert's header (the date,
the temporary file name) is removed, so a rebuild gives identical files.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path
from typing import Any, Iterable
from xml.sax.saxutils import quoteattr

from sumo_ethics.errors import ConfigError

#: netconvert options of every network built here
OPTIONS = {
    "offset.disable-normalization": "true",
    "no-turnarounds": "true",
    "walkingareas": "true",
    "junctions.corner-detail": "5",
    "default.crossing-width": "4",
    "tls.default-type": "static",
}


def fmt(x: float) -> str:
    """A coordinate as written in plain XML: at most 2 decimals, no trailing zeros, no -0."""
    s = f"{x:.2f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def attrs(d: dict[str, Any]) -> str:
    """XML attributes of ``d`` in its order, None values left out."""
    return " ".join(f"{k}={quoteattr(str(v))}" for k, v in d.items() if v is not None)


def shape(points: Iterable[tuple[float, float]]) -> str:
    return " ".join(f"{fmt(x)},{fmt(y)}" for x, y in points)


def netconvert() -> Path:
    """The netconvert binary of the installed eclipse-sumo package."""
    import sumo  # the eclipse-sumo package: only its SUMO_HOME

    from sumo_ethics.sumo_options import refuse_if_barred

    refuse_if_barred("netconvert")
    exe = Path(sumo.SUMO_HOME) / "bin" / "netconvert"
    return exe if exe.exists() else exe.with_suffix(".exe")


def write_if_changed(path: Path, text: str) -> None:
    """Write ``text`` unless the file already holds it (a rebuild leaves file times alone)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    if not (path.exists() and path.read_text() == text):
        path.write_text(text)


class PlainNet:
    """A network in plain XML. ``options``: netconvert options on top of :data:`OPTIONS`."""

    def __init__(self, name: str, options: dict[str, str] | None = None) -> None:
        self.name = name
        self.options = {**OPTIONS, **(options or {})}
        self.nodes: list[dict] = []
        self.edges: list[dict] = []
        self.connections: list[dict] = []
        self.crossings: list[dict] = []

    def node(self, id: str, x: float, y: float, type: str | None = None, **kw: Any) -> None:
        self.nodes.append({"id": id, "x": fmt(x), "y": fmt(y), "type": type, **kw})

    def edge(self, id: str, fr: str, to: str, shape: Iterable[tuple[float, float]] | None = None, **kw: Any) -> None:
        """An edge fr -> to; ``shape``: its centre line as points [m] (default: straight)."""
        self.edges.append({"id": id, "from": fr, "to": to, "shape": _shape_or_none(shape), **kw})

    def two_way(self, fwd: str, bwd: str, fr: str, to: str, shape: list | None = None, **kw: Any) -> None:
        """A two-way road: edge fwd fr -> to and edge bwd to -> fr on the same centre line."""
        self.edge(fwd, fr, to, shape=shape, **kw)
        self.edge(bwd, to, fr, shape=shape[::-1] if shape else None, **kw)

    def connection(self, fr: str, to: str, fromLane: int, toLane: int) -> None:
        self.connections.append({"from": fr, "to": to, "fromLane": fromLane, "toLane": toLane})

    def crossing(self, node: str, edges: list[str], priority: str | None = None) -> None:
        self.crossings.append({"node": node, "edges": " ".join(edges), "priority": priority})

    def build(self, folder: Path, config_file: bool = False) -> Path:
        """Write the plain files into ``folder``, run netconvert, return ``<name>.net.xml``.

        config_file: also write ``<name>.netccfg`` (the options as a netconvert configuration,
        so a user can rebuild with ``netconvert -c``) and build from it. ConfigError if
        netconvert fails; its other messages are returned in :attr:`messages`.
        """
        folder = Path(folder)
        n = self.name
        write_if_changed(folder / f"{n}.nod.xml",
                         "<nodes>\n" + "".join(f"    <node {attrs(x)}/>\n" for x in self.nodes) + "</nodes>\n")
        write_if_changed(folder / f"{n}.edg.xml",
                         "<edges>\n" + "".join(f"    <edge {attrs(x)}/>\n" for x in self.edges) + "</edges>\n")
        con = "".join(f"    <connection {attrs(x)}/>\n" for x in self.connections)
        con += "".join(f"    <crossing {attrs(x)}/>\n" for x in self.crossings)
        write_if_changed(folder / f"{n}.con.xml", f"<connections>\n{con}</connections>\n")
        tmp = folder / f".{n}.net.xml.tmp"
        if config_file:
            write_if_changed(folder / f"{n}.netccfg", self._netccfg())
            cmd = [str(netconvert()), "-c", f"{n}.netccfg", "--output-file", tmp.name]
        else:
            cmd = [str(netconvert()), "--node-files", f"{n}.nod.xml", "--edge-files", f"{n}.edg.xml",
                   "--connection-files", f"{n}.con.xml", "--output-file", tmp.name]
            for k, v in self.options.items():
                cmd += [f"--{k}", v]
        proc = subprocess.run(cmd, cwd=folder, capture_output=True, text=True)
        out = (proc.stdout + proc.stderr).strip()
        if proc.returncode != 0:
            tmp.unlink(missing_ok=True)
            raise ConfigError(f"netconvert failed for {n}: {out}")
        self.messages = "" if out == "Success." else out
        text = tmp.read_text()
        tmp.unlink()
        # the run-dependent parts of the header: the date and the temporary file name
        text = re.sub(r"<!-- generated on [^\n]*? by ", "<!-- generated by ", text, count=1)
        text = text.replace(tmp.name, f"{n}.net.xml")
        net = folder / f"{n}.net.xml"
        write_if_changed(net, text)
        return net

    def _netccfg(self) -> str:
        n = self.name
        opts = "".join(f"        <{k} value={quoteattr(v)}/>\n" for k, v in self.options.items())
        return ("<configuration>\n"
                "    <input>\n"
                f"        <node-files value=\"{n}.nod.xml\"/>\n"
                f"        <edge-files value=\"{n}.edg.xml\"/>\n"
                f"        <connection-files value=\"{n}.con.xml\"/>\n"
                "    </input>\n"
                "    <output>\n"
                f"        <output-file value=\"{n}.net.xml\"/>\n"
                "    </output>\n"
                "    <processing>\n"
                f"{opts}"
                "    </processing>\n"
                "    <report>\n"
                "        <verbose value=\"false\"/>\n"
                "    </report>\n"
                "</configuration>\n")


def _shape_or_none(points: Iterable[tuple[float, float]] | None) -> str | None:
    return shape(points) if points else None
