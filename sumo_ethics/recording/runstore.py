"""The finished runs of a prediction dataset being built, kept on disk so a stopped build resumes.

``OUT/partial/`` holds ``plan.json`` (every run of the build: id, scenario, seed, demand scale,
simulated seconds; the package, recorder, SUMO and map versions) and, per finished run, ``run_NNNNNN.parquet``
(its trajectory rows, the columns of ``trajectories.parquet``) and ``run_NNNNNN.graph.json.gz`` (its
network's lane graph as gzip-compressed JSON, None for a suite run that recorded nothing; a build
stopped by an older version kept ``.graph.pkl`` files, which are not read: those runs are simulated again). Each run's pair is written
whole and synced to the disk (a ``.part`` file renamed) as soon as the run ends, so Ctrl-C, SIGTERM, a crashed SUMO run
or a killed machine loses only the runs still simulating. The same command on the same ``OUT``
goes on from them; a build of other runs is refused; the finished dataset removes the folder.
"""

from __future__ import annotations

import io
import json
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from sumo_ethics import fileio
from sumo_ethics.errors import ConfigError
from sumo_ethics.predict.graph_files import decode_graph, encode_graph

PARTIAL = "partial"
PLAN_FORMAT = "sumo-ethics dataset runs"


@dataclass(frozen=True)
class RunStore:
    """The ``partial`` folder of a dataset folder (see the module docstring); made by the first
    :meth:`put`, so a build stopped before any run ends leaves nothing."""

    folder: Path
    plan: dict[str, Any]

    @classmethod
    def open(cls, out: Path, plan: dict[str, Any]) -> RunStore:
        """The store of ``out`` for ``plan`` (a JSON-able dict of the runs).

        ConfigError if ``out`` already holds the finished runs of another plan: its runs are
        never mixed with this one's (and never deleted)."""
        folder = Path(out) / PARTIAL
        plan = json.loads(json.dumps({"format": PLAN_FORMAT, **plan}))  # as read back from plan.json
        plan_file = folder / "plan.json"
        if plan_file.is_file():
            try:
                old = json.loads(plan_file.read_text())
            except ValueError:
                raise ConfigError(f"{plan_file} cannot be read: delete {folder} to start the build over") from None
            if old != plan:
                raise ConfigError(f"{out} holds the finished runs of another dataset build ({plan_file}: other "
                                  "scenarios, seeds or --sim-seconds, or another recorder or SUMO version); give a "
                                  "new --out, or the same arguments to resume that build")
            for stale in folder.glob("*.part"):  # a write cut short by a kill
                stale.unlink()
        return cls(folder, plan)

    def _paths(self, run_id: int) -> tuple[Path, Path]:
        stem = self.folder / f"run_{run_id:06d}"
        return stem.with_suffix(".parquet"), stem.with_suffix(".graph.json.gz")

    def done(self) -> set[int]:
        """Run ids whose rows and lane graph are on disk."""
        if not self.folder.is_dir():
            return set()
        ids = (int(p.stem.removeprefix("run_")) for p in self.folder.glob("run_*.parquet"))
        return {i for i in ids if self._paths(i)[1].is_file()}

    def put(self, run_id: int, rows: pd.DataFrame, graph: Any) -> None:
        """Keep a finished run: its lane graph first, then its rows (the rows mark it done)."""
        if not (self.folder / "plan.json").is_file():
            self.folder.mkdir(parents=True, exist_ok=True)
            _write_whole(self.folder / "plan.json", json.dumps(self.plan, indent=2).encode())
        table, graph_file = self._paths(run_id)
        _write_whole(graph_file, encode_graph(graph))
        buf = io.BytesIO()
        rows.to_parquet(buf, index=False)
        _write_whole(table, buf.getvalue())

    def get(self, run_id: int) -> tuple[pd.DataFrame, Any]:
        """A finished run's rows and lane graph, as :meth:`put` was given them; ConfigError if
        they cannot be read (a disk that lost them)."""
        table, graph_file = self._paths(run_id)
        try:
            return pd.read_parquet(table), decode_graph(graph_file.read_bytes())
        except Exception as exc:  # noqa: BLE001 - pyarrow's and the graph file's errors: the files are damaged
            raise ConfigError(f"the kept run {table} cannot be read ({type(exc).__name__}: {exc}); delete it and "
                              "its .graph.json.gz, then run the same command again to simulate that run anew") from None

    def remove(self) -> None:
        """Delete the folder (its runs are in the written dataset): renamed first, so a kill
        half-way leaves no partial folder that looks like a stopped build."""
        if self.folder.is_dir():
            gone = self.folder.with_name(f".{PARTIAL}-done")
            os.replace(self.folder, gone)
            shutil.rmtree(gone, ignore_errors=True)


def kept_runs(out: Path) -> tuple[int, int]:
    """(finished runs kept, runs planned) in ``out``'s partial folder; (0, 0) without one."""
    plan_file = Path(out) / PARTIAL / "plan.json"
    try:
        plan = json.loads(plan_file.read_text())
    except (OSError, ValueError):
        return 0, 0
    return len(RunStore(plan_file.parent, plan).done()), len(plan.get("runs", [])) + len(plan.get("suite", []))


def _write_whole(path: Path, data: bytes) -> None:
    """``data`` to ``path``, whole or not at all, and on the disk (not only in the page cache)
    before the name appears: a power cut cannot leave an empty file that counts as a run."""
    fileio.write_bytes(path, data, tmp_name=f"{path.name}.part", durable=True)  # stale *.part: cut short by a kill
