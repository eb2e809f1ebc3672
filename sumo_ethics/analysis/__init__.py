"""Analysis of sweep folders: tidy DataFrames, tables with bootstrap CIs, plots, a report.

>>> from sumo_ethics.analysis import load
>>> res = load("sweeps/urban")          # Results(runs, collisions, steps)
>>> res.runs.groupby("omega_u").harm_total.mean()

Reads only the files a sweep wrote (``manifest.json`` and ``dataset/``), never the simulator.
``load`` also reads a single run folder, finished or killed (``kill -9``): then the runs table
has one row, with status ``incomplete`` and ``incomplete = True`` when the run did not finish
writing, and the steps and collisions are the rows written up to its last flush.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from sumo_ethics.analysis.sweep_tables import TABLES, build_dataset, parameter_schema, partition_schema, read_manifest

__all__ = ["Results", "load", "load_run", "build_dataset"]


@dataclass(frozen=True)
class Results:
    """Tidy tables of a sweep; each has ``run_id`` and the sweep parameters as columns.

    runs: one row per finished run (status, completed, harm_ego/third_party/vru/total, ...);
    collisions: one row per collision event (the columns of collisions.parquet);
    steps: one row per ego step (the columns of steps.parquet).
    """

    runs: pd.DataFrame
    collisions: pd.DataFrame
    steps: pd.DataFrame
    parameters: tuple[str, ...]  # scenario, omega_u, seed, then the --set keys
    out: Path


def _read(folder: Path, manifest: dict, steps: bool = True) -> pd.DataFrame:
    import pyarrow.dataset as ds

    psch = parameter_schema(manifest)
    if not folder.exists() or not any(folder.rglob("*.parquet")):
        return pd.DataFrame({"run_id": pd.Series(dtype=str), **{f.name: pd.Series(dtype=f.type.to_pandas_dtype())
                                                                   for f in psch}})
    import pyarrow as pa

    try:
        data = ds.dataset(folder, format="parquet", partitioning=ds.partitioning(partition_schema(manifest),
                                                                                 flavor="hive"))
        df = data.to_table().to_pandas()
    except (OSError, pa.ArrowException) as exc:
        from sumo_ethics.errors import ConfigError

        detail = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise ConfigError(f"the dataset {folder} is unreadable ({detail}); remove {folder.parent} and it is "
                          "rebuilt from the run folders") from None
    cols = ["run_id", *psch.names]
    df = df[cols + [c for c in df.columns if c not in cols]]
    order = [c for c in ("run_id", "event", "step") if c in df.columns]
    return df.sort_values(order, kind="stable").reset_index(drop=True)


def load(out: str | Path, steps: bool = True) -> Results:
    """Tidy DataFrames of the sweep in ``out`` (builds ``out/dataset`` first if it is missing)."""
    out = Path(out)
    if not (out / "manifest.json").exists() and any((out / n).exists() for n in ("summary.json", "config.json",
                                                                                 "partial")):
        return load_run(out, steps=steps)
    manifest = read_manifest(out)
    if not (out / "dataset" / "schema.json").exists():
        build_dataset(out)
    base = out / "dataset"
    frames = {name: _read(base / name, manifest) for name in TABLES if steps or name != "steps"}
    if not steps:
        frames["steps"] = pd.DataFrame()
    return Results(runs=frames["runs"], collisions=frames["collisions"], steps=frames["steps"],
                   parameters=tuple(parameter_schema(manifest).names), out=out)


def load_run(folder: str | Path, steps: bool = True) -> Results:
    """Tidy DataFrames of one run folder, finished or killed (see the module docstring)."""
    from sumo_ethics.record.reader import is_incomplete, read_table, recover_summary

    folder = Path(folder)
    s = recover_summary(folder)
    incomplete = is_incomplete(folder)
    harm = s.get("harm", {})
    run_id = folder.name
    runs = pd.DataFrame([{
        "run_id": run_id, "status": "incomplete" if incomplete else s.get("status", "error"),
        "incomplete": incomplete, "message": s.get("message", ""), "completed": bool(s.get("completed", False)),
        **{f"harm_{k}": float(harm.get(k, 0.0)) for k in ("ego", "third_party", "vru", "total")},
        "collisions_ego": int(s.get("collisions", {}).get("ego", 0)),
        "collisions_others": int(s.get("collisions", {}).get("others", 0)),
        "steps": int(s.get("steps", 0) or 0), "sim_time": s.get("sim_time"), "seed": s.get("seed"),
        "controller": s.get("controller"), "path": str(folder)}])

    def table(name: str) -> pd.DataFrame:
        df = read_table(folder, name).to_pandas()
        df.insert(0, "run_id", run_id)
        return df

    return Results(runs=runs, collisions=table("collisions"), steps=table("steps") if steps else pd.DataFrame(),
                   parameters=(), out=folder)
