"""The runner's recording callback: one object per run, called once per ego step.

``RunRecorder.step(row, timing)`` appends this step's steps.parquet and timings.parquet rows;
every ``chunk`` steps (CHUNK_SECONDS of simulated time: a fixed count, so the files never
depend on wall-clock time) all tables are flushed to ``partial/``. More per-step tables can be
added with :meth:`RunRecorder.table` (they are flushed and merged with the others).
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path
from typing import Any

import pyarrow as pa

from sumo_ethics.record import schema
from sumo_ethics.record.decisions import DecisionLog
from sumo_ethics.record.writer import PARTIAL, STREAMED, ChunkedTable, chunk_steps, write_table
from sumo_ethics.types import DecisionTrace


class RunRecorder:
    """:meth:`step` once per ego step, :meth:`add_collision` per collision event; :meth:`close` at
    the end writes the finished files.

    Collision rows stay in memory (events are few, and one is updated while it lasts) and are
    rewritten to ``partial/collisions.parquet`` at a flush when they changed; so are conflict
    rows (``partial/conflicts.parquet``, once :meth:`record_conflicts` was called) and the rows of
    conflicts among the other road users (``partial/conflicts_others.parquet``, once
    :meth:`record_conflicts_others` was called; written through :attr:`others_sink`).
    """

    def __init__(self, out: Path, chunk: int = 20) -> None:
        self.out = out
        self.chunk = chunk
        self.partial = out / PARTIAL
        self.tables = {name: ChunkedTable(self.partial, name, base) for name, base in STREAMED.items()}
        self.collisions: list[dict[str, Any]] = []
        self.collision_schema = schema.COLLISIONS  # a fleet's names the ego parties too
        self._collisions_dirty = False
        self.conflicts: list[dict[str, Any]] | None = None  # a list once conflicts are recorded
        self._conflicts_dirty = False
        self.conflicts_others: list[dict[str, Any]] | None = None  # a list once recorded ([conflicts] everyone)
        self._others_dirty = False
        self.others_sink = _OthersSink(self)
        self.n_steps = 0
        self.first_step: dict[str, Any] | None = None
        self.last_step: dict[str, Any] | None = None
        self.decisions: DecisionLog | None = None
        self.dt, self.mode = 0.1, "off"  # s, and the decisions' mode: set by start

    def start(self, dt: float, decisions: str = "off", per_ego: bool = False) -> None:
        """Called once the step length ``dt`` [s] is known: chunks of CHUNK_SECONDS, and the
        decisions kept by mode ``decisions`` (:mod:`sumo_ethics.record.decisions`): the run's one
        log, or with ``per_ego`` none but one per fleet ego (:meth:`ego_log`)."""
        self.chunk = chunk_steps(dt)
        self.dt, self.mode = dt, decisions
        self.decisions = None if per_ego else DecisionLog(self.out, decisions, dt)

    def ego_log(self, ego: str) -> DecisionLog:
        """A new log of fleet ego ``ego``'s decisions (``RUN/decisions/<ego folder>/``) by the run's
        mode; its holder passes it to :meth:`step` and drops it when the ego ends."""
        return DecisionLog(self.out, self.mode, self.dt, ego)

    def table(self, name: str, base: pa.Schema) -> ChunkedTable:
        """A further per-step table ``name`` (file ``name.parquet``), flushed with the others."""
        if name not in self.tables:
            self.tables[name] = ChunkedTable(self.partial, name, base)
        return self.tables[name]

    # -- the callback --
    def step(self, row: dict[str, Any], timing: dict[str, Any], trace: DecisionTrace | None = None,
             plan_time: float | None = None, collided: bool = False, log: DecisionLog | None = None) -> None:
        """This step's rows; the decision that led to it (``trace``, made at ``plan_time`` [s]) and
        whether the step ended in a new ego collision, for the recorded decisions (in ``log``, a
        fleet ego's, else the run's)."""
        log = self.decisions if log is None else log
        if log is not None:
            w = time.perf_counter()
            log.add(int(row["step"]), row["time"] if plan_time is None else plan_time, trace, collided)
            timing["decisions_ms"] = 1e3 * (time.perf_counter() - w)
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

    def record_conflicts(self) -> list[dict[str, Any]]:
        """Write conflicts.parquet (rows from :meth:`add_conflict`) with the other outputs; its rows."""
        if self.conflicts is None:
            self.conflicts = []
        return self.conflicts

    def add_conflict(self, row: dict[str, Any]) -> int:
        rows = self.record_conflicts()
        rows.append(row)
        self._conflicts_dirty = True
        return len(rows) - 1

    def update_conflict(self, index: int, **changes: Any) -> None:
        if self.conflicts is None:
            raise IndexError(f"conflict {index}: no conflicts are recorded")
        self.conflicts[index].update(changes)
        self._conflicts_dirty = True

    def record_conflicts_others(self) -> list[dict[str, Any]]:
        """Write conflicts_others.parquet (rows through :attr:`others_sink`) with the other outputs; its rows."""
        if self.conflicts_others is None:
            self.conflicts_others = []
        return self.conflicts_others

    # -- files --
    def flush(self) -> None:
        """Append what is buffered to the streams in ``partial/`` (and write the collisions, if
        they changed)."""
        for t in self.tables.values():
            t.flush()
        if self._collisions_dirty:
            self.partial.mkdir(parents=True, exist_ok=True)
            write_table(self.partial / "collisions.parquet", self.collisions, self.collision_schema)
            self._collisions_dirty = False
        if self._conflicts_dirty and self.conflicts is not None:  # dirty: rows were added
            self.partial.mkdir(parents=True, exist_ok=True)
            write_table(self.partial / "conflicts.parquet", self.conflicts, schema.CONFLICTS)
            self._conflicts_dirty = False
        if self._others_dirty and self.conflicts_others is not None:
            self.partial.mkdir(parents=True, exist_ok=True)
            write_table(self.partial / "conflicts_others.parquet", self.conflicts_others, schema.CONFLICTS_OTHERS)
            self._others_dirty = False

    def close(self) -> None:
        """Write the finished files and remove ``partial/``."""
        for name, t in self.tables.items():
            t.finish(self.out / f"{name}.parquet")
        write_table(self.out / "collisions.parquet", self.collisions, self.collision_schema)
        if self.conflicts is not None:
            write_table(self.out / "conflicts.parquet", self.conflicts, schema.CONFLICTS)
        if self.conflicts_others is not None:
            write_table(self.out / "conflicts_others.parquet", self.conflicts_others, schema.CONFLICTS_OTHERS)
        shutil.rmtree(self.partial, ignore_errors=True)


class _OthersSink:
    """The sink of :class:`~sumo_ethics.safety.pairs.PairConflictBook`: rows of conflicts_others.parquet."""

    def __init__(self, rec: RunRecorder) -> None:
        self.rec = rec

    def add_conflict(self, row: dict[str, Any]) -> int:
        rows = self.rec.record_conflicts_others()
        rows.append(row)
        self.rec._others_dirty = True
        return len(rows) - 1

    def update_conflict(self, index: int, **changes: Any) -> None:
        rows = self.rec.conflicts_others
        if rows is None:
            raise IndexError(f"conflict {index}: no conflicts among the others are recorded")
        rows[index].update(changes)
        self.rec._others_dirty = True
