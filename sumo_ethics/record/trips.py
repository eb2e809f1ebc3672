"""SUMO's tripinfo output (``--tripinfo-output``, ``.xml`` or ``.xml.gz``) as one row per trip,
``trips.parquet``, for traffic-level studies: travel time, time loss and waiting per class, ego or not.

One row per vehicle (``<tripinfo>``) and per person (``<personinfo>`` with its ``<walk>``,
``<ride>``, ``<stop>``, ... stages) that departed, in the file's order (SUMO writes a trip when it
ends; with ``--tripinfo-output.write-unfinished true`` the trips still under way follow at the
end). Containers (``<containerinfo>``) are no road users and are skipped, and so are entries that
never departed (``depart="-1"``: persons loaded ahead of their departure, vehicles written by
``--tripinfo-output.write-undeparted``). With ``--personinfo-output`` the persons are in that
file: read both and concatenate.

SUMO writes ``-1`` (``-1.00``, ``-00:00:01`` with ``--human-readable-time``, and ``-0.00`` for
the arrival of a stop not yet begun) for a value it does not know; every negative value is read
as unknown: NaN in the frame, null in the Parquet file. Columns (:data:`TRIPS`; str is pandas'
default string dtype, as a Parquet file read back gives it):

=================  ========  ===================================================================
``id``             str       SUMO id
``kind``           str       ``vehicle`` or ``person``
``type_id``        str       vType id as SUMO wrote it (``car@veh`` when TraCI gave the vehicle
                             a type of its own)
``vclass``         str       SUMO vClass (persons ``pedestrian``; empty when not known)
``cls``            str       :class:`~sumo_ethics.types.RoadUserClass` label (``other`` when the
                             vClass is not known)
``ego``            bool      the id is one of ``egos``
``depart``         float64   s, departure time
``arrival``        float64   s, end of the trip; NaN while under way
``duration``       float64   s, ``arrival - depart``; under way: the time so far
``distance``       float64   m, distance travelled (a vehicle under way: so far); SUMO's
                             ``routeLength``
``time_loss``      float64   s, time lost to driving/walking below the ideal speed
``waiting_time``   float64   s, time at (nearly) standstill (persons: also waiting for a ride);
                             under way: so far
``arrived``        bool      reached its destination: arrival known, and a vehicle not removed
                             early (``vaporized`` empty: not by TraCI, a collision, ...)
=================  ========  ===================================================================

A person's values are the sums over its stages (a ride's ``duration`` counts only the time in the
vehicle, so its ``waitingTime`` is added to a person's time so far). SUMO computes a stage's
length and time loss only when the stage ends, so for a person under way ``distance`` and
``time_loss`` are NaN, and a stop under way at the end is missing from its duration so far.

``distance`` means what it means in ``summary.json`` (the distance driven); ``route_length``
there is the length of the ego's whole route.
"""

from __future__ import annotations

import gzip
import io
import math
import xml.etree.ElementTree as ET
import zlib
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import IO, Any

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from sumo_ethics import fileio
from sumo_ethics.types import RoadUserClass

#: the columns of trips.parquet, in order
TRIPS = pa.schema([
    ("id", pa.string()),
    ("kind", pa.string()),          # vehicle | person
    ("type_id", pa.string()),       # SUMO vType id
    ("vclass", pa.string()),        # SUMO vClass
    ("cls", pa.string()),           # RoadUserClass label
    ("ego", pa.bool_()),
    ("depart", pa.float64()),       # s
    ("arrival", pa.float64()),      # s, NaN while under way
    ("duration", pa.float64()),     # s
    ("distance", pa.float64()),     # m, so far
    ("time_loss", pa.float64()),    # s
    ("waiting_time", pa.float64()),  # s
    ("arrived", pa.bool_()),
])
COLUMNS = tuple(TRIPS.names)
_NAN = float("nan")
_GZIP_MAGIC = b"\x1f\x8b"


def _num(value: str | None) -> float:
    """A SUMO number or time (``12.5``, ``00:01:02.50``, ``1:00:00:00``) [s]; NaN when absent,
    unreadable or negative (SUMO's "not known")."""
    if value is None:
        return _NAN
    text = value.strip()
    if not text or text.startswith("-"):
        return _NAN
    try:
        parts = text.split(":")
        if len(parts) == 1:
            v = float(text)
        elif len(parts) in (3, 4):
            v = sum(float(p) * f for p, f in zip(reversed(parts), (1.0, 60.0, 3600.0, 86400.0)))
        else:
            return _NAN
    except ValueError:
        return _NAN
    return v if math.isfinite(v) and v >= 0 else _NAN


def _vclass(type_id: str, vclass_of: Mapping[str, str]) -> str:
    """The vClass of ``type_id``; a vehicle's own type ``base@vehicle`` falls back to ``base``."""
    if type_id in vclass_of:
        return vclass_of[type_id]
    base, at, _ = type_id.rpartition("@")
    return vclass_of.get(base, "") if at else ""


def _vehicle(el: ET.Element, vclass_of: Mapping[str, str]) -> dict[str, Any]:
    a = el.attrib
    type_id = a.get("vType", a.get("vtype", ""))
    vclass = _vclass(type_id, vclass_of)
    arrival = _num(a.get("arrival"))
    return {
        "kind": "vehicle", "type_id": type_id, "vclass": vclass, "cls": RoadUserClass.from_vclass(vclass).label,
        "arrival": arrival, "duration": _num(a.get("duration")), "distance": _num(a.get("routeLength")),
        "time_loss": _num(a.get("timeLoss")), "waiting_time": _num(a.get("waitingTime")),
        "arrived": not math.isnan(arrival) and a.get("vaporized", "") == "",
    }


def _known(values: Iterable[float]) -> float:
    """Sum of the known (not NaN) ``values``."""
    return math.fsum(v for v in values if not math.isnan(v))


def _stage_sum(stages: list[ET.Element], key: str) -> float:
    """Sum of ``key`` over the stages that have it; NaN if one of them has it but not known."""
    return math.fsum(_num(s.attrib[key]) for s in stages if key in s.attrib)


def _person(el: ET.Element, depart: float) -> dict[str, Any]:
    stages = list(el)
    arrival = _num(stages[-1].attrib.get("arrival")) if stages else _NAN
    arrived = not math.isnan(arrival)
    if arrived:
        duration = arrival - depart
        distance, time_loss = _stage_sum(stages, "routeLength"), _stage_sum(stages, "timeLoss")
    else:  # the time so far: the stages' durations, and the waits for rides (not in a ride's duration)
        duration = (_known(_num(s.attrib.get("duration")) for s in stages)
                    + _known(_num(s.attrib.get("waitingTime")) for s in stages if s.tag == "ride"))
        distance = time_loss = _NAN
    return {
        "kind": "person", "type_id": el.attrib.get("type", ""), "vclass": "pedestrian", "cls": "pedestrian",
        "arrival": arrival, "duration": duration, "distance": distance, "time_loss": time_loss,
        "waiting_time": _known(_num(s.attrib.get("waitingTime")) for s in stages), "arrived": arrived,
    }


class _Gunzip(io.RawIOBase):
    """A gzip file's bytes (concatenated members too: SUMO writes many) up to where it is cut off
    or corrupt, without an error (``gzip`` raises EOFError and drops the last bytes it decoded)."""

    def __init__(self, raw: IO[bytes]) -> None:
        self._raw = raw
        self._z = zlib.decompressobj(wbits=31)
        self._buf = b""
        self._done = False

    def readable(self) -> bool:
        return True

    def _feed(self, chunk: bytes) -> bytes:
        out = self._z.decompress(chunk)
        while self._z.eof and self._z.unused_data:  # the next member
            rest, self._z = self._z.unused_data, zlib.decompressobj(wbits=31)
            out += self._z.decompress(rest)
        return out

    def _decode(self, chunk: bytes) -> bytes:
        """``chunk`` decompressed; at corrupt data, what came before it (by halving the chunk)."""
        before = self._z.copy()
        try:
            return self._feed(chunk)
        except zlib.error:
            self._z = before
            if len(chunk) <= 64:
                self._done = True
                return b""
            head = self._decode(chunk[: len(chunk) // 2])
            return head if self._done else head + self._decode(chunk[len(chunk) // 2:])

    def readinto(self, b: Any) -> int:
        while not self._buf and not self._done:
            chunk = self._raw.read(1 << 16)
            self._done = self._done or not chunk
            self._buf = self._decode(chunk) if chunk else b""
        n = min(len(b), len(self._buf))
        b[:n] = self._buf[:n]
        self._buf = self._buf[n:]
        return n

    def close(self) -> None:
        self._raw.close()
        super().close()


def _open(path: Path) -> IO[bytes]:
    """The file's bytes, decompressed when its name ends .gz (BadGzipFile if it is no gzip file)."""
    fh = open(path, "rb")
    if not path.name.endswith(".gz"):
        return fh
    if not _GZIP_MAGIC.startswith(fh.read(2)):  # a cut inside the first header is a truncation
        fh.close()
        raise gzip.BadGzipFile(f"{path}: not a gzip file")
    fh.seek(0)
    return io.BufferedReader(_Gunzip(fh), 1 << 16)


def read_tripinfo(path: Path, egos: Iterable[str] = (), vclass_of: Mapping[str, str] | None = None) -> pd.DataFrame:
    """One row per departed vehicle and person of the tripinfo file ``path`` (``.gz`` too), in
    the file's order, columns :data:`COLUMNS` (see the module docstring); ``egos``: the ids
    flagged ``ego``; ``vclass_of``: vType id -> vClass (e.g.
    ``sumo_ethics.sim.scenario.declared(files).types``), a vehicle of a type not in it gets
    ``vclass`` "" and ``cls`` "other".

    A file cut off (a killed run) or empty gives the rows complete before the cut, no error.
    """
    path = Path(path)
    egos = frozenset(egos)
    vclass_of = vclass_of or {}
    rows: list[dict[str, Any]] = []
    with _open(path) as fh:
        root: ET.Element | None = None
        try:
            for event, el in ET.iterparse(fh, events=("start", "end")):
                if root is None:
                    root = el
                if event == "start" or el.tag not in ("tripinfo", "personinfo", "containerinfo"):
                    continue
                depart = _num(el.attrib.get("depart"))
                if el.tag != "containerinfo" and not math.isnan(depart):  # NaN: never departed
                    ident = el.attrib.get("id", "")
                    row = _vehicle(el, vclass_of) if el.tag == "tripinfo" else _person(el, depart)
                    rows.append({"id": ident, "ego": ident in egos, "depart": depart, **row})
                root.clear()  # the entries are the root's children: keep memory flat
        except ET.ParseError:
            pass  # cut off (a killed run): the rows before the cut
    return _frame(rows)


def _frame(rows: list[dict[str, Any]]) -> pd.DataFrame:
    """The rows with the dtypes of trips.parquet read back (strings as pandas' default string dtype)."""
    return pa.Table.from_pylist(rows, schema=TRIPS).to_pandas()


def write_trips(df: pd.DataFrame, path: Path) -> None:
    """``df`` (columns :data:`COLUMNS`, e.g. from :func:`read_tripinfo`) as Parquet at ``path``
    (written whole or not at all), schema :data:`TRIPS`: the same rows give the same bytes, no
    rows an empty table of that schema."""
    table = pa.Table.from_pandas(df[list(COLUMNS)], schema=TRIPS, preserve_index=False)
    with fileio.replacing(Path(path)) as tmp:
        pq.write_table(table.replace_schema_metadata(None), tmp, compression="zstd")
