"""Writing run outputs: atomic Parquet and JSON files, and tables appended as the run goes
(:class:`ChunkedTable`), turned into one Parquet file at the end.

While a run is going (and after it was killed) its rows live under ``RUN/partial/``::

    partial/steps.000.arrows         Arrow IPC streams, one record batch appended per chunk of
    partial/timings.000.arrows       CHUNK_SECONDS (a fixed number of steps: the same seed gives the
                                     same chunks); a new segment (.001, ...) when columns are added
    partial/collisions.parquet       every collision event so far (rewritten at a flush when changed)
    partial/conflicts.parquet        every conflict event so far, the open ones as far as they went (the same)
    partial/conflicts_others.parquet the same for the pairs without an ego ([conflicts] everyone)

The file is flushed after each batch, so a run killed by any signal, even ``kill -9``, leaves
streams holding every row up to the last flush (a batch cut off by the kill is dropped when
reading); an append writes one batch, not a Parquet file per chunk (the cost of each: the
opening paragraph of docs/outputs.md). When the
run ends, :meth:`~sumo_ethics.record.recorder.RunRecorder.close` writes ``steps.parquet`` and
``timings.parquet`` from the streams (row groups of ROW_GROUP_ROWS rows, so the bytes depend
only on the rows), writes ``collisions.parquet`` and removes ``partial/``. Memory holds one
chunk, not the run. :func:`~sumo_ethics.record.reader.read_table` reads either form;
:func:`~sumo_ethics.record.reader.recover_summary` rebuilds a summary for a run that left no
``summary.json``.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import IO, Any, Iterator

import pyarrow as pa
import pyarrow.parquet as pq

from sumo_ethics import fileio
from sumo_ethics.record import schema

#: simulated seconds per chunk: a killed run loses at most this much of its rows
CHUNK_SECONDS = 2.0
#: rows per row group of the finished steps/timings files
ROW_GROUP_ROWS = 16384
PARTIAL = "partial"
STREAMED = {"steps": schema.STEPS_BASE, "timings": schema.TIMINGS_BASE}


def _extend(base: pa.Schema, rows: list[dict[str, Any]]) -> pa.Schema:
    """``base`` plus float64 columns for extra keys (controller info), in first-seen order."""
    names = set(base.names)
    extra: list[str] = []
    for r in rows:
        for k in r:
            if k not in names:
                names.add(k)
                extra.append(k)
    return pa.schema(list(base) + [(k, pa.float64()) for k in extra])


def _atomic_parquet(table: pa.Table, path: Path) -> None:
    with fileio.replacing(path) as tmp:
        pq.write_table(table, tmp, compression="zstd")


def write_table(path: Path, rows: list[dict[str, Any]], base: pa.Schema) -> None:
    """Atomically write ``rows`` as Parquet (temp name, then rename)."""
    sch = _extend(base, rows)
    _atomic_parquet(pa.Table.from_pylist(rows, schema=sch) if rows else sch.empty_table(), path)


def write_json(path: Path, data: dict[str, Any]) -> None:
    fileio.write_json(path, data)


def chunk_steps(dt: float) -> int:
    """Steps per chunk for a step length ``dt`` [s]: CHUNK_SECONDS of simulated time, at least 1."""
    return max(1, int(math.ceil(CHUNK_SECONDS / dt - 1e-9)))


class ChunkedTable:
    """One table appended as Arrow IPC stream segments ``folder/<name>.<k>.arrows``, one record
    batch per :meth:`flush`; :meth:`finish` turns them into one Parquet file."""

    def __init__(self, folder: Path, name: str, base: pa.Schema) -> None:
        self.folder = folder
        self.name = name
        self.base = base
        self.rows: list[dict[str, Any]] = []
        self.schema: pa.Schema | None = None  # of the open segment
        self.segment = -1
        self._file: IO[bytes] | None = None
        self._writer: Any = None

    def append(self, row: dict[str, Any]) -> None:
        self.rows.append(row)

    def flush(self) -> None:
        if not self.rows:
            return
        sch = _extend(self.schema or self.base, self.rows)  # columns so far first, new ones appended
        if self._writer is None or not sch.equals(self.schema):
            self._open(sch)
        self._writer.write_batch(pa.RecordBatch.from_pylist(self.rows, schema=sch))
        if self._file is None:  # opened with the writer
            raise RuntimeError(f"{self.name}: no segment is open to flush")
        self._file.flush()  # to the OS: survives the process being killed
        self.rows = []

    def _open(self, sch: pa.Schema) -> None:
        self.close()
        self.segment += 1
        self.folder.mkdir(parents=True, exist_ok=True)
        self._file = open(self.folder / f"{self.name}.{self.segment:03d}.arrows", "wb")
        self._writer = pa.ipc.new_stream(self._file, sch)
        self.schema = sch

    def close(self) -> None:
        """Close the open segment (the rows not flushed stay buffered)."""
        if self._writer is not None:
            try:
                self._writer.close()
                if self._file is not None:  # opened with the writer
                    self._file.close()
            finally:
                self._writer = self._file = None

    def finish(self, path: Path) -> None:
        """Write every row into the Parquet file ``path`` (temporary name, then renamed)."""
        self.flush()
        self.close()
        write_batches(path, self.base, segments(self.folder, self.name))


def segments(folder: Path, name: str) -> list[Path]:
    """The stream segments of table ``name`` in ``folder``, in order."""
    return sorted(folder.glob(f"{name}.[0-9][0-9][0-9].arrows")) if folder.is_dir() else []


def iter_segment(path: Path) -> Iterator[pa.RecordBatch]:
    """The complete record batches of a stream segment; a batch cut off by a kill (and anything
    after it) is dropped."""
    try:
        with open(path, "rb") as f:
            reader = pa.ipc.open_stream(f)
            while True:
                try:
                    batch = reader.read_next_batch()
                except StopIteration:
                    return
                yield batch
    except (OSError, pa.ArrowInvalid):
        return


def read_segment(path: Path) -> tuple[pa.Schema | None, list[pa.RecordBatch]]:
    """Schema and complete record batches of a stream segment (see :func:`iter_segment`)."""
    return read_segment_schema(path), list(iter_segment(path))


def union_schema(base: pa.Schema, schemas: list[pa.Schema]) -> pa.Schema:
    fields = list(base)
    names = set(base.names)
    for s in schemas:
        for f in s:
            if f.name not in names:
                names.add(f.name)
                fields.append(f)
    return pa.schema(fields)


def conform(table: pa.Table, sch: pa.Schema) -> pa.Table:
    n = table.num_rows
    cols = [table[f.name] if f.name in table.column_names else pa.nulls(n, f.type) for f in sch]
    return pa.Table.from_arrays(cols, schema=sch)


def write_batches(path: Path, base: pa.Schema, paths: list[Path]) -> None:
    """Stream segments (in order) -> one Parquet file with fixed-size row groups, holding about
    one row group in memory at a time."""
    sch = union_schema(base, [s for p in paths if (s := read_segment_schema(p)) is not None])
    with fileio.replacing(path) as tmp, pq.ParquetWriter(tmp, sch, compression="zstd") as w:
        carry: pa.Table | None = None  # rows short of a full row group

        def emit(batches: list[pa.RecordBatch], seg_schema: pa.Schema) -> None:
            nonlocal carry
            t = conform(pa.Table.from_batches(batches, schema=seg_schema), sch)
            t = pa.concat_tables([carry, t]) if carry is not None else t
            while t.num_rows >= ROW_GROUP_ROWS:
                w.write_table(t.slice(0, ROW_GROUP_ROWS), row_group_size=ROW_GROUP_ROWS)
                t = t.slice(ROW_GROUP_ROWS)
            carry = t

        for p in paths:
            seg_schema = read_segment_schema(p)
            group: list[pa.RecordBatch] = []
            for b in iter_segment(p):  # streamed: a few thousand rows in memory at a time
                group.append(b)
                if len(group) == 256:
                    emit(group, seg_schema)
                    group = []
            if group:
                emit(group, seg_schema)
        if carry is not None and carry.num_rows or not paths:
            w.write_table(carry if carry is not None else sch.empty_table(), row_group_size=ROW_GROUP_ROWS)


def read_segment_schema(path: Path) -> pa.Schema | None:
    try:
        with open(path, "rb") as f:
            return pa.ipc.open_stream(f).schema
    except (OSError, pa.ArrowInvalid):
        return None
