"""Analysis of sweep folders: tidy DataFrames, tables with bootstrap CIs, plots, a report.

>>> from sumo_ethics.analysis import load
>>> res = load("sweeps/urban")          # Results(runs, collisions, steps)
>>> res.runs.groupby("omega_u").harm_total.mean()

Reads only the files a sweep wrote (``manifest.json`` and ``dataset/``), never the simulator.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from sumo_ethics.analysis.dataset import TABLES, build_dataset, parameter_schema, partition_schema, read_manifest

__all__ = ["Results", "load", "build_dataset"]


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
    data = ds.dataset(folder, format="parquet", partitioning=ds.partitioning(partition_schema(manifest),
                                                                             flavor="hive"))
    df = data.to_table().to_pandas()
    cols = ["run_id", *psch.names]
    df = df[cols + [c for c in df.columns if c not in cols]]
    order = [c for c in ("run_id", "event", "step") if c in df.columns]
    return df.sort_values(order, kind="stable").reset_index(drop=True)


def load(out: str | Path, steps: bool = True) -> Results:
    """Tidy DataFrames of the sweep in ``out`` (builds ``out/dataset`` first if it is missing)."""
    out = Path(out)
    manifest = read_manifest(out)
    if not (out / "dataset" / "schema.json").exists():
        build_dataset(out)
    base = out / "dataset"
    frames = {name: _read(base / name, manifest) for name in TABLES if steps or name != "steps"}
    if not steps:
        frames["steps"] = pd.DataFrame()
    return Results(runs=frames["runs"], collisions=frames["collisions"], steps=frames["steps"],
                   parameters=tuple(parameter_schema(manifest).names), out=out)
