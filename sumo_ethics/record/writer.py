"""Writing run outputs: atomic Parquet and JSON files, and tables written in chunks as the run
goes (:class:`ChunkedTable`), merged into one Parquet file at the end.

While a run is going (and after it was killed) its rows live under ``RUN/partial/``::

    partial/steps/000000.parquet ...     one complete Parquet file per chunk of CHUNK_SECONDS
    partial/timings/000000.parquet ...   (a fixed number of steps: the same seed gives the same chunks)
    partial/collisions.parquet           every collision event so far (rewritten at a flush when changed)

Each chunk file is written under a temporary name and renamed, so a run killed by any signal,
even ``kill -9``, leaves readable chunks holding every row up to the last flush. When the run
ends, :meth:`~sumo_ethics.record.recorder.RunRecorder.close` merges the chunks into
``steps.parquet`` and ``timings.parquet`` (row groups of ROW_GROUP_ROWS rows, so the bytes
depend only on the rows), writes ``collisions.parquet`` and removes ``partial/``. Memory holds
one chunk, not the run.
:func:`~sumo_ethics.record.reader.read_table` reads either form;
:func:`~sumo_ethics.record.reader.recover_summary` rebuilds a summary for a run that left no
``summary.json``.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

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
    tmp = path.with_name(f".{path.name}.tmp")
    pq.write_table(table, tmp, compression="zstd")
    os.replace(tmp, path)


def write_table(path: Path, rows: list[dict[str, Any]], base: pa.Schema) -> None:
    """Atomically write ``rows`` as Parquet (temp name, then rename)."""
    sch = _extend(base, rows)
    _atomic_parquet(pa.Table.from_pylist(rows, schema=sch) if rows else sch.empty_table(), path)


def write_json(path: Path, data: dict[str, Any]) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(data, indent=2, sort_keys=False, default=str) + "\n")
    os.replace(tmp, path)


def chunk_steps(dt: float) -> int:
    """Steps per chunk for a step length ``dt`` [s]: CHUNK_SECONDS of simulated time, at least 1."""
    return max(1, int(math.ceil(CHUNK_SECONDS / dt - 1e-9)))


class ChunkedTable:
    """One table written as numbered chunk files under ``folder``; :meth:`finish` merges them."""

    def __init__(self, folder: Path, base: pa.Schema) -> None:
        self.folder = folder
        self.base = base
        self.rows: list[dict[str, Any]] = []
        self.n_chunks = 0

    def append(self, row: dict[str, Any]) -> None:
        self.rows.append(row)

    def flush(self) -> None:
        if not self.rows:
            return
        self.folder.mkdir(parents=True, exist_ok=True)
        table = pa.Table.from_pylist(self.rows, schema=_extend(self.base, self.rows))
        _atomic_parquet(table, self.folder / f"{self.n_chunks:06d}.parquet")
        self.n_chunks += 1
        self.rows = []

    def finish(self, path: Path) -> None:
        """Merge every chunk into ``path`` (written under a temporary name, then renamed)."""
        self.flush()
        merge_chunks(sorted(self.folder.glob("[0-9]*.parquet")) if self.folder.is_dir() else [], path, self.base)


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


def merge_chunks(parts: list[Path], path: Path, base: pa.Schema) -> None:
    """Chunk files (in order) -> one Parquet file with fixed-size row groups, one chunk in memory."""
    sch = union_schema(base, [pq.read_schema(p) for p in parts])
    tmp = path.with_name(f".{path.name}.tmp")
    with pq.ParquetWriter(tmp, sch, compression="zstd") as w:
        pending: list[pa.Table] = []
        n = 0
        for p in parts:
            pending.append(conform(pq.read_table(p), sch))
            n += pending[-1].num_rows
            if n >= ROW_GROUP_ROWS:
                t = pa.concat_tables(pending)
                w.write_table(t.slice(0, ROW_GROUP_ROWS), row_group_size=ROW_GROUP_ROWS)
                pending, n = [t.slice(ROW_GROUP_ROWS)], t.num_rows - ROW_GROUP_ROWS
        if n or not parts:
            w.write_table(pa.concat_tables(pending) if pending else sch.empty_table(), row_group_size=ROW_GROUP_ROWS)
    os.replace(tmp, path)
