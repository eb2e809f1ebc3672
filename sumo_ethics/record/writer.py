"""Buffers rows in memory and writes Parquet at the end (also after a failure)."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from sumo_ethics.record import schema


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


def write_table(path: Path, rows: list[dict[str, Any]], base: pa.Schema) -> None:
    """Atomically write ``rows`` as Parquet (temp name, then rename)."""
    sch = _extend(base, rows)
    table = pa.Table.from_pylist(rows, schema=sch) if rows else sch.empty_table()
    tmp = path.with_name(path.name + ".tmp")
    pq.write_table(table, tmp, compression="zstd")
    os.replace(tmp, path)


def write_json(path: Path, data: dict[str, Any]) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=2, sort_keys=False, default=str) + "\n")
    os.replace(tmp, path)


class RunRecorder:
    """Collects the rows of one run; :meth:`flush` writes everything recorded so far."""

    def __init__(self, out: Path) -> None:
        self.out = out
        self.steps: list[dict[str, Any]] = []
        self.timings: list[dict[str, Any]] = []
        self.collisions: list[dict[str, Any]] = []

    def flush(self) -> None:
        write_table(self.out / "steps.parquet", self.steps, schema.STEPS_BASE)
        write_table(self.out / "timings.parquet", self.timings, schema.TIMINGS_BASE)
        write_table(self.out / "collisions.parquet", self.collisions, schema.COLLISIONS)
