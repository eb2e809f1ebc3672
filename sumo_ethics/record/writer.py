"""Run outputs written as the run goes: steps and timings in fixed-size chunks, collisions and
the summary as small whole files.

While a run is going (and after it was killed) its rows live under ``RUN/partial/``::

    partial/steps/000000.parquet ...     one complete Parquet file per chunk of CHUNK_SECONDS
    partial/timings/000000.parquet ...   (a fixed number of steps: the same seed gives the same chunks)
    partial/collisions.parquet           every collision event so far (rewritten at a flush when changed)

Each chunk file is written under a temporary name and renamed, so a run killed by any signal,
even ``kill -9``, leaves readable chunks holding every row up to the last flush. When the run
ends, :meth:`RunRecorder.close` merges the chunks into ``steps.parquet`` and ``timings.parquet``
(row groups of ROW_GROUP_ROWS rows, so the bytes depend only on the rows), writes
``collisions.parquet`` and removes ``partial/``. Memory holds one chunk, not the run.
:func:`read_table` reads either form; :func:`recover_summary` rebuilds a summary for a run
that left no ``summary.json``.
"""

from __future__ import annotations

import json
import math
import os
import shutil
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


def _union_schema(base: pa.Schema, schemas: list[pa.Schema]) -> pa.Schema:
    fields = list(base)
    names = set(base.names)
    for s in schemas:
        for f in s:
            if f.name not in names:
                names.add(f.name)
                fields.append(f)
    return pa.schema(fields)


def _conform(table: pa.Table, sch: pa.Schema) -> pa.Table:
    n = table.num_rows
    cols = [table[f.name] if f.name in table.column_names else pa.nulls(n, f.type) for f in sch]
    return pa.Table.from_arrays(cols, schema=sch)


def merge_chunks(parts: list[Path], path: Path, base: pa.Schema) -> None:
    """Chunk files (in order) -> one Parquet file with fixed-size row groups, one chunk in memory."""
    sch = _union_schema(base, [pq.read_schema(p) for p in parts])
    tmp = path.with_name(f".{path.name}.tmp")
    with pq.ParquetWriter(tmp, sch, compression="zstd") as w:
        pending: list[pa.Table] = []
        n = 0
        for p in parts:
            pending.append(_conform(pq.read_table(p), sch))
            n += pending[-1].num_rows
            if n >= ROW_GROUP_ROWS:
                t = pa.concat_tables(pending)
                w.write_table(t.slice(0, ROW_GROUP_ROWS), row_group_size=ROW_GROUP_ROWS)
                pending, n = [t.slice(ROW_GROUP_ROWS)], t.num_rows - ROW_GROUP_ROWS
        if n or not parts:
            w.write_table(pa.concat_tables(pending) if pending else sch.empty_table(), row_group_size=ROW_GROUP_ROWS)
    os.replace(tmp, path)


class RunRecorder:
    """The run's recording callback: :meth:`step` once per ego step, :meth:`add_collision` per event.

    Rows of steps and timings are flushed every ``chunk`` steps (a fixed count, so the files do
    not depend on wall-clock time); collision rows stay in memory (events are few, and one is
    updated while it lasts) and are rewritten at a flush when they changed.
    """

    def __init__(self, out: Path, chunk: int = 20) -> None:
        self.out = out
        self.chunk = chunk
        self.partial = out / PARTIAL
        self.tables = {name: ChunkedTable(self.partial / name, base) for name, base in STREAMED.items()}
        self.collisions: list[dict[str, Any]] = []
        self._collisions_dirty = False
        self.n_steps = 0
        self.first_step: dict[str, Any] | None = None
        self.last_step: dict[str, Any] | None = None

    # -- the callback --
    def step(self, row: dict[str, Any], timing: dict[str, Any]) -> None:
        self.tables["steps"].append(row)
        self.tables["timings"].append(timing)
        self.n_steps += 1
        if self.first_step is None:
            self.first_step = row
        self.last_step = row
        if self.n_steps % self.chunk == 0:
            self.flush()

    def add_collision(self, row: dict[str, Any]) -> int:
        self.collisions.append(row)
        self._collisions_dirty = True
        return len(self.collisions) - 1

    def update_collision(self, index: int, **changes: Any) -> None:
        self.collisions[index].update(changes)
        self._collisions_dirty = True

    # -- files --
    def flush(self) -> None:
        """Write what is buffered as chunk files (and the collisions, if they changed)."""
        for t in self.tables.values():
            t.flush()
        if self._collisions_dirty:
            self.partial.mkdir(parents=True, exist_ok=True)
            write_table(self.partial / "collisions.parquet", self.collisions, schema.COLLISIONS)
            self._collisions_dirty = False

    def close(self) -> None:
        """Write the finished files and remove ``partial/``."""
        for name, t in self.tables.items():
            t.finish(self.out / f"{name}.parquet")
        write_table(self.out / "collisions.parquet", self.collisions, schema.COLLISIONS)
        shutil.rmtree(self.partial, ignore_errors=True)


# ---- reading a run folder, finished or not ------------------------------------------------------
BASES = {"steps": schema.STEPS_BASE, "timings": schema.TIMINGS_BASE, "collisions": schema.COLLISIONS}


def is_incomplete(folder: Path) -> bool:
    """True when the run in ``folder`` did not finish writing (killed): no summary, or chunks left."""
    folder = Path(folder)
    return not (folder / "summary.json").is_file() or (folder / PARTIAL).is_dir()


def _readable(path: Path) -> pa.Table | None:
    try:
        return pq.read_table(path)
    except (OSError, pa.ArrowException):
        return None


def read_table(folder: Path, name: str) -> pa.Table:
    """Table ``name`` (steps, timings, collisions) of a run folder: the finished file, else the
    chunks a killed run left in ``partial/`` (unreadable chunks are skipped), else empty."""
    folder = Path(folder)
    base = BASES[name]
    final = folder / f"{name}.parquet"
    if final.is_file() and not (folder / PARTIAL).is_dir():
        t = _readable(final)
        if t is None:
            from sumo_ethics.errors import ConfigError

            raise ConfigError(f"{final} is not a readable Parquet file (truncated or corrupt)")
        return t
    if name == "collisions":
        t = _readable(folder / PARTIAL / "collisions.parquet")
        return t if t is not None else base.empty_table()
    parts = [t for p in sorted((folder / PARTIAL / name).glob("[0-9]*.parquet"))
             if (t := _readable(p)) is not None] if (folder / PARTIAL / name).is_dir() else []
    if not parts:
        return base.empty_table()
    sch = _union_schema(base, [t.schema for t in parts])
    return pa.concat_tables([_conform(t, sch) for t in parts])


def recover_summary(folder: Path) -> dict[str, Any]:
    """``summary.json`` of a run folder, or one rebuilt from its rows (status ``incomplete``) when
    the run was killed before writing it."""
    folder = Path(folder)
    path = folder / "summary.json"
    if path.is_file():
        try:
            data = json.loads(path.read_text())
            if isinstance(data, dict):
                return data
        except (OSError, ValueError):
            pass
    steps = read_table(folder, "steps").select(["step", "time", "s"]).to_pylist()
    coll = read_table(folder, "collisions").to_pylist()
    booked = [r for r in coll if r.get("involves_ego") and r.get("detector") != "sumo_unconfirmed"]
    harm = {k: float(sum(r.get(f"harm_{k}") or 0.0 for r in booked)) for k in ("ego", "third_party", "vru")}
    harm["total"] = harm["ego"] + harm["third_party"]
    cfg: dict[str, Any] = {}
    try:
        cfg = json.loads((folder / "config.json").read_text())
    except (OSError, ValueError):
        pass
    return {
        "status": "incomplete",
        "message": "the run was killed before it finished; rebuilt from the rows written so far "
                   f"(up to t={steps[-1]['time']:g} s)" if steps else "the run was killed before it wrote any step",
        "completed": False, "collided": bool(booked), "harm": harm,
        "collisions": {"ego": len(booked), "ego_unconfirmed": sum(r.get("detector") == "sumo_unconfirmed" for r in coll),
                       "others": sum(not r.get("involves_ego") for r in coll)},
        "seed": cfg.get("seed"), "steps": len(steps),
        "distance": float(steps[-1]["s"] - steps[0]["s"]) if steps else 0.0,
        "sim_time": float(steps[-1]["time"]) if steps else None,
        "controller": cfg.get("controller"), "reconstructed": True,
    }
