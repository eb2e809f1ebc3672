"""Reading a run folder, finished or killed: the finished Parquet files, else the chunks in
``partial/``; a summary rebuilt when a killed run left none."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from sumo_ethics.record import schema
from sumo_ethics.record.writer import PARTIAL, conform, read_segment, segments, union_schema

BASES = {"steps": schema.STEPS_BASE, "timings": schema.TIMINGS_BASE, "collisions": schema.COLLISIONS,
         "conflicts": schema.CONFLICTS, "conflicts_others": schema.CONFLICTS_OTHERS}


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
    """Table ``name`` (steps, timings, collisions, conflicts, conflicts_others) of a run folder: the finished file, else the
    rows a killed run left in ``partial/`` (up to its last flush), else empty."""
    folder = Path(folder)
    base = BASES.get(name, pa.schema([]))
    final = folder / f"{name}.parquet"
    if final.is_file() and not (folder / PARTIAL).is_dir():
        t = _readable(final)
        if t is None:
            from sumo_ethics.errors import ConfigError

            raise ConfigError(f"{final} is not a readable Parquet file (truncated or corrupt)")
        return t
    if name in ("collisions", "conflicts", "conflicts_others"):  # rewritten whole at each flush
        t = _readable(folder / PARTIAL / f"{name}.parquet")
        return t if t is not None else base.empty_table()
    parts = [(sch, batches) for p in segments(folder / PARTIAL, name) for sch, batches in [read_segment(p)]
             if sch is not None]
    if not parts:
        return base.empty_table()
    sch = union_schema(base, [s for s, _ in parts])
    return pa.concat_tables([conform(pa.Table.from_batches(b, schema=s), sch) for s, b in parts])


def recover_summary(folder: Path) -> dict[str, Any]:
    """``summary.json`` of a run folder, or one rebuilt from its rows (status ``incomplete``) when
    the run was killed before writing it."""
    from sumo_ethics.collision import booked_outcome
    from sumo_ethics.safety.conflicts import conflict_counts
    from sumo_ethics.safety.pairs import pair_counts

    folder = Path(folder)
    path = folder / "summary.json"
    if path.is_file():
        try:
            data = json.loads(path.read_text())
            if isinstance(data, dict):
                return data
        except (OSError, ValueError):
            pass
    table = read_table(folder, "steps")
    fleet = "ego_id" in table.column_names  # a fleet run: one row per ego per step
    steps = table.select(["step", "time", "s"] + (["ego_id"] if fleet else [])).to_pylist()
    if fleet:  # each ego's distance from its first row to its last
        first: dict[str, float] = {}
        last: dict[str, float] = {}
        for r in steps:
            first.setdefault(r["ego_id"], r["s"])
            last[r["ego_id"]] = r["s"]
        distance = float(sum(last[k] - first[k] for k in last))
    else:
        distance = float(steps[-1]["s"] - steps[0]["s"]) if steps else 0.0
    coll = read_table(folder, "collisions").to_pylist()
    booked, harm, faults = booked_outcome(coll)
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
                       "others": sum(not r.get("involves_ego") for r in coll), "fault": faults},
        **({"conflicts": conflict_counts(read_table(folder, "conflicts").to_pylist())}
           if cfg.get("conflicts", {}).get("enabled") else {}),
        **({"conflicts_others": pair_counts(read_table(folder, "conflicts_others").to_pylist())}
           if cfg.get("conflicts", {}).get("everyone") else {}),
        "seed": cfg.get("seed"), "steps": len(steps), "distance": distance,
        **({"fleet": {"spec": cfg.get("fleet"), "egos": len({r["ego_id"] for r in steps})}} if fleet else {}),
        "sim_time": float(steps[-1]["time"]) if steps else None,
        "controller": cfg.get("controller"), "reconstructed": True,
    }


def collided(folder: Path) -> bool:
    """Whether the run in ``folder`` booked an ego collision (summary.json's ``collided``): whether it
    has collision snapshots to draw (:func:`sumo_ethics.analysis.explain.draw_snapshots`, which
    callers import only then: the analysis package loads pandas)."""
    try:
        data = json.loads((Path(folder) / "summary.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(data, dict) and bool(data.get("collided"))

