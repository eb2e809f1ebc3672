"""The sweep's Parquet dataset: run folders -> ``DIR/dataset/{runs,collisions,steps}``.

Each table is one pyarrow dataset, hive-partitioned by the swept parameters except the seed
(``DIR/dataset/runs/scenario=urban/omega_u=0.5/part-0.parquet``); every row carries ``run_id``
and all sweep parameters (the partition keys come back as columns when read with
:func:`sumo_ethics.analysis.load`). The dataset is built under a temporary name and swapped in,
so a reader never sees half of it.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

import pandas as pd
import pyarrow as pa
import pyarrow.dataset as ds
import pyarrow.parquet as pq

from sumo_ethics.analysis.exante import COLUMNS as RISK_COLUMNS, INPUTS as RISK_INPUTS, run_risk

TABLES = ("runs", "collisions", "steps")
FINISHED = ("completed", "collision", "timeout", "error")


def read_manifest(out: Path) -> dict[str, Any]:
    from sumo_ethics.errors import ConfigError

    path = Path(out) / "manifest.json"
    if not path.exists():
        raise ConfigError(f"{out} is not a sweep folder (no manifest.json)")
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ConfigError(f"{path} is unreadable: {exc}") from None


def _arrow_type(values: list[Any]) -> pa.DataType:
    vals = [v for v in values if v is not None]
    if vals and all(isinstance(v, bool) for v in vals):
        return pa.bool_()
    if vals and all(isinstance(v, int) and not isinstance(v, bool) for v in vals):
        return pa.int64()
    if vals and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in vals):
        return pa.float64()
    return pa.string()


def parameter_schema(manifest: dict[str, Any]) -> pa.Schema:
    """Arrow types of the sweep parameters (scenario, omega_u, seed, --set keys)."""
    d = manifest["definition"]
    fields = [("scenario", pa.string()), ("omega_u", pa.float64()), ("seed", pa.int64())]
    fields += [(k, _arrow_type(v)) for k, v in d.get("set", {}).items()]
    return pa.schema(fields)


def partition_schema(manifest: dict[str, Any]) -> pa.Schema:
    sch = parameter_schema(manifest)
    return pa.schema([f for f in sch if f.name != "seed"])


def _corrupt(folder: Path, what: str, exc: BaseException):
    from sumo_ethics.errors import ConfigError

    detail = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    return ConfigError(f"run folder {folder} is corrupt ({what}: {detail}); remove that folder and start the "
                       "same sweep again to redo the run")


def _run_table(folder: Path, name: str) -> pa.Table:
    from sumo_ethics.errors import ConfigError
    from sumo_ethics.record.reader import read_table

    try:
        return read_table(folder, name)
    except (ConfigError, OSError, pa.ArrowException) as exc:
        raise _corrupt(folder, f"{name}.parquet", exc) from None


def drive_time(summary: dict[str, Any]) -> float | None:
    """Seconds the ego was driven (summary.json's sim_time - takeover_time), None if unknown."""
    if summary.get("sim_time") is None or summary.get("takeover_time") is None:
        return None
    return float(summary["sim_time"]) - float(summary["takeover_time"])


#: a fleet run's traffic outcomes (NaN for a single-ego run): egos, everyone's harm by party
#: (summed over every confirmed collision of the run), kilometres driven and walked by all
#: trips, mean time loss per trip by party (sumo_ethics.runner.fleet, trips.parquet)
FLEET_COLUMNS = ("fleet_egos", "harm_all_egos", "harm_all_other_vehicles", "harm_all_vru", "harm_all_total",
                 "vehicle_km", "person_km", "time_loss_egos", "time_loss_other_vehicles", "time_loss_persons")


def fleet_columns(s: dict[str, Any]) -> dict[str, float]:
    """The FLEET_COLUMNS of a run's summary.json (all NaN for a single-ego run)."""
    nan = float("nan")
    if "fleet" not in s:
        return dict.fromkeys(FLEET_COLUMNS, nan)
    everyone, traffic = s.get("harm_everyone", {}), s.get("traffic", {})
    loss = traffic.get("time_loss_mean_s", {})

    def num(v: Any) -> float:
        return float(v) if v is not None else nan

    return {"fleet_egos": float(s["fleet"].get("egos", 0)),
            **{f"harm_all_{k}": num(everyone.get(k)) for k in ("egos", "other_vehicles", "vru", "total")},
            "vehicle_km": num(traffic.get("vehicle_km")), "person_km": num(traffic.get("person_km")),
            **{f"time_loss_{k}": num(loss.get(k)) for k in ("egos", "other_vehicles", "persons")}}


def _run_row(run: dict[str, Any], folder: Path, steps: pa.Table | None) -> dict[str, Any]:
    """The runs-table row of a finished run folder; ``steps``: its steps table (for the ex-ante
    risk summary, read once by the caller), None if it has none."""
    try:
        s = json.loads((folder / "summary.json").read_text())
        if not isinstance(s, dict):
            raise ValueError("not a JSON object")
    except (OSError, ValueError) as exc:
        raise _corrupt(folder, "summary.json", exc) from None
    harm = s.get("harm", {})
    coll = s.get("collisions", {})
    conf = s.get("conflicts")  # absent: conflicts were not measured (NaN, not 0)
    others = s.get("conflicts_others")  # absent: the pairs without an ego were not measured
    wall = s.get("wall_time")
    if (folder / "params.json").exists():
        wall = json.loads((folder / "params.json").read_text()).get("wall_time", wall)
    return {
        "run_id": run["run_id"], **run["params"],
        "status": s.get("status", "error"), "message": s.get("message", ""),
        "completed": bool(s.get("completed", False)),
        "harm_ego": float(harm.get("ego", 0.0)), "harm_third_party": float(harm.get("third_party", 0.0)),
        "harm_vru": float(harm.get("vru", 0.0)), "harm_total": float(harm.get("total", 0.0)),
        "collisions_ego": int(coll.get("ego", 0)), "collisions_others": int(coll.get("others", 0)),
        "steps": int(s.get("steps", 0) or 0), "distance": float(s.get("distance", 0.0) or 0.0),
        "sim_time": float(s["sim_time"]) if s.get("sim_time") is not None else None,
        "route_length": float(s["route_length"]) if s.get("route_length") is not None else None,
        "drive_time": drive_time(s),
        "conflicts_total": float(conf["total"]) if conf else float("nan"),
        "conflicts_vru": float(conf["vru"]) if conf else float("nan"),
        "conflicts_others": float(others["total"]) if others else float("nan"),
        "conflicts_others_vru": float(others["by_group"]["vehicle-vru"] + others["by_group"]["vru-vru"])
        if others else float("nan"),
        "controller": s.get("controller"), "wall_time": float(wall) if wall is not None else None,
        **fleet_columns(s),
        "path": f"runs/{run['run_id']}",
        **run_risk(steps.select([c for c in RISK_INPUTS if c in steps.column_names]).to_pandas()
                   if steps is not None else pd.DataFrame()),
    }


RUN_COLUMNS = pa.schema([
    ("run_id", pa.string()), ("status", pa.string()), ("message", pa.string()), ("completed", pa.bool_()),
    ("harm_ego", pa.float64()), ("harm_third_party", pa.float64()), ("harm_vru", pa.float64()),
    ("harm_total", pa.float64()), ("collisions_ego", pa.int64()), ("collisions_others", pa.int64()),
    ("steps", pa.int64()), ("distance", pa.float64()), ("sim_time", pa.float64()), ("route_length", pa.float64()),
    ("drive_time", pa.float64()), ("conflicts_total", pa.float64()), ("conflicts_vru", pa.float64()),
    ("conflicts_others", pa.float64()), ("conflicts_others_vru", pa.float64()),
    ("controller", pa.string()), ("wall_time", pa.float64()),
    *((c, pa.float64()) for c in FLEET_COLUMNS), ("path", pa.string()),
    *((c, pa.float64()) for c in RISK_COLUMNS),
])


def _with_params(table: pa.Table, run_id: str, params: dict[str, Any], psch: pa.Schema) -> pa.Table:
    n = table.num_rows
    cols = [pa.array([run_id] * n, pa.string())] + [pa.array([params.get(f.name)] * n, f.type) for f in psch]
    names = ["run_id"] + psch.names
    for name in table.column_names:
        if name not in names:
            cols.append(table[name])
            names.append(name)
    return pa.Table.from_arrays(cols, names=names)


def build_dataset(out: Path) -> dict[str, int]:
    """(Re)build ``out/dataset`` from the finished run folders listed in the manifest; row counts."""
    out = Path(out)
    manifest = read_manifest(out)
    psch = parameter_schema(manifest)
    part = partition_schema(manifest)
    run_rows: list[dict[str, Any]] = []
    tables: dict[str, list[pa.Table]] = {"collisions": [], "steps": []}
    for run in sorted(manifest["runs"], key=lambda r: r["run_id"]):
        folder = out / "runs" / run["run_id"]
        if not (folder / "summary.json").exists():
            continue
        read = {name: _run_table(folder, name) for name in tables if (folder / f"{name}.parquet").exists()}
        run_rows.append(_run_row(run, folder, read.get("steps")))
        for name, table in read.items():
            tables[name].append(_with_params(table, run["run_id"], run["params"], psch))
    schema = pa.schema([RUN_COLUMNS.field("run_id"), *psch, *[f for f in RUN_COLUMNS if f.name != "run_id"]])
    built = {"runs": pa.Table.from_pylist(run_rows, schema=schema)}
    for name, parts in tables.items():
        if parts:
            built[name] = pa.concat_tables(parts, promote_options="permissive")
        else:
            built[name] = pa.schema([("run_id", pa.string()), *psch]).empty_table()
    tmp = out / f".dataset.tmp-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    partitioning = ds.partitioning(part, flavor="hive")
    for name, table in built.items():
        if table.num_rows:
            ds.write_dataset(table, tmp / name, format="parquet", partitioning=partitioning,
                             basename_template="part-{i}.parquet", existing_data_behavior="overwrite_or_ignore")
        else:  # keep the columns: one empty file at the root (partition keys are ordinary columns there)
            (tmp / name).mkdir()
            pq.write_table(table, tmp / name / "empty.parquet")
    (tmp / "schema.json").write_text(json.dumps({"partitioning": part.names, "parameters": psch.names,
                                                 "rows": {k: v.num_rows for k, v in built.items()}}, indent=2) + "\n")
    final = out / "dataset"
    old = out / f".dataset.old-{os.getpid()}"
    if final.exists():
        os.rename(final, old)
    os.rename(tmp, final)
    shutil.rmtree(old, ignore_errors=True)
    return {k: v.num_rows for k, v in built.items()}
