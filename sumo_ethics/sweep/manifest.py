"""``DIR/manifest.json`` (the sweep's definition and the state of every run), the checks of an
output folder and of finished run folders, and the cleaning of a killed start's leftovers."""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path
from typing import Any

from sumo_ethics import fileio
from sumo_ethics.errors import ConfigError
from sumo_ethics.sweep.grid import RunSpec, Sweep

MANIFEST_VERSION = 1
FINISHED = ("completed", "collision", "timeout", "error")  # run statuses kept as results
FAILED = "failed"  # the tool itself crashed on this run, or its input was refused: no folder, retried
PENDING = "pending"


def result_from_folder(run_id: str, folder: Path, skipped: bool = False) -> dict[str, Any]:
    """The result dict of a finished run folder (from its summary)."""
    data = json.loads((folder / "summary.json").read_text())
    status = data.get("status", "error")
    return {"run_id": run_id, "status": status, "message": data.get("message", ""),
            "error": data.get("message") if status == "error" else None, "wall": data.get("wall_time"),
            "path": str(folder), "skipped": skipped}


class Manifest:
    """``DIR/manifest.json``: the definition and the state of every run."""

    def __init__(self, out: Path, sweep: Sweep, specs: list[RunSpec], execution: dict[str, Any] | None = None) -> None:
        self.path = out / "manifest.json"
        self.out = out
        self.sweep = sweep
        #: how the last start ran it (``workers``, or a Dask ``scheduler``): not part of the definition, as
        #: it changes no result, but the report's command line repeats it
        self.execution = dict(execution or {})
        self.runs: dict[str, dict[str, Any]] = {}
        for s in specs:
            self.runs[s.run_id] = {"run_id": s.run_id, "params": s.params, "status": PENDING, "error": None,
                                   "message": "", "path": f"runs/{s.run_id}", "attempts": 0}

    def load_previous(self) -> None:
        if not self.path.exists():
            return
        try:
            old = json.loads(self.path.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise ConfigError(f"{self.path} is unreadable ({exc}); remove it or choose another --out") from None
        if old.get("definition") != self.sweep.definition():
            raise ConfigError(f"{self.out} holds a different sweep (manifest definition differs); "
                              f"choose another --out or remove it")
        for r in old.get("runs", []):
            if r.get("run_id") in self.runs:
                self.runs[r["run_id"]]["attempts"] = r.get("attempts", 0)

    def update(self, result: dict[str, Any]) -> None:
        r = self.runs[result["run_id"]]
        r.update(status=result["status"], error=result.get("error"), message=result.get("message", ""))
        if result.get("wall") is not None:
            r["wall_time"] = result["wall"]

    def sync(self, runs_dir: Path) -> None:
        """Record runs whose folder was completed while their result was not received (Ctrl-C)."""
        for r in self.runs.values():
            folder = runs_dir / r["run_id"]
            if r["status"] in (PENDING, FAILED) and (folder / "summary.json").exists():
                self.update(result_from_folder(r["run_id"], folder))

    def write(self) -> None:
        counts: dict[str, int] = {}
        for r in self.runs.values():
            counts[r["status"]] = counts.get(r["status"], 0) + 1
        fileio.write_json(self.path, {
            "version": MANIFEST_VERSION, "definition": self.sweep.definition(),
            "parameters": self.sweep.parameters, "counts": counts, "execution": self.execution,
            "updated": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "runs": list(self.runs.values())},
            tmp_name=f".manifest.json.tmp-{os.getpid()}")  # workers of several processes may write it


def check_out(out: Path, sweep: Sweep) -> None:
    """ConfigError unless ``out`` is new, empty, or holds this same sweep."""
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out} exists and is not a folder")
    m = out / "manifest.json"
    if m.exists():
        try:
            old = json.loads(m.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise ConfigError(f"{m} is unreadable ({exc}); remove it or choose another --out") from None
        if old.get("definition") != sweep.definition():
            raise ConfigError(f"{out} holds a different sweep (manifest definition differs); "
                              f"choose another --out or remove it")
    elif out.is_dir() and any(p.name not in ("runs", "dataset") for p in out.iterdir()):
        raise ConfigError(f"--out {out} is not empty and holds no sweep manifest; choose another folder")


def clean_temporaries(out: Path) -> None:
    """Leftovers of an earlier start that was killed: temporary run folders (their runs were
    not finished and run again), the manifest's and the dataset's temporary files."""
    for p in [*(out / "runs").glob(".*.tmp-*"), *out.glob(".manifest.json.tmp-*"), *out.glob(".dataset.tmp-*"),
              *out.glob(".dataset.old-*")]:
        shutil.rmtree(p, ignore_errors=True) if p.is_dir() else p.unlink(missing_ok=True)


def check_finished(folder: Path) -> None:
    """ConfigError when a finished run folder is corrupt (unreadable summary or Parquet footer)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    what = "summary.json"
    try:
        if not isinstance(json.loads((folder / "summary.json").read_text()), dict):
            raise ValueError("not a JSON object")
        for name in ("steps", "timings", "collisions"):
            what = f"{name}.parquet"
            if (folder / what).exists():
                pq.read_metadata(folder / what)
    except (OSError, ValueError, pa.ArrowException) as exc:
        raise ConfigError(f"run folder {folder} is corrupt ({what}: {str(exc).splitlines()[0] if str(exc) else exc}); "
                          f"remove that folder and start the same sweep again to redo the run") from None
