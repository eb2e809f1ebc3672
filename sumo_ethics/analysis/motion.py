"""The ego's recorded motion against its limits: the sideways acceleration of each executed step.

A step's heading change dpsi over dt at speed v pushes the ego sideways at |v dpsi / dt| [m/s^2]
(the turn's centripetal acceleration); the planner's feasibility check keeps every candidate within
``max_lat_accel`` (``summary.json`` ``ego_limits``), so an executed step beyond it is motion no car
makes: a heading snapped within one step. Read from ``steps.parquet`` (``time`` [s], ``yaw`` [rad],
``speed`` [m/s]) of each run.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

__all__ = ["step_lateral_accel", "lateral_check"]


def step_lateral_accel(steps: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """((n-1,) |v dpsi / dt| [m/s^2], (n-1,) |dpsi| [rad]) between consecutive rows of ``steps`` (one
    ego's, in time order): the speed after the step times the wrapped heading change over the time step."""
    yaw = steps["yaw"].to_numpy(dtype=float)
    turn = np.abs(np.angle(np.exp(1j * np.diff(yaw))))
    dt = np.diff(steps["time"].to_numpy(dtype=float))
    speed = steps["speed"].to_numpy(dtype=float)[1:]
    return np.abs(speed) * turn / np.where(dt > 0, dt, np.nan), turn


def _limit(run: Path) -> float:
    """The run's max_lat_accel [m/s^2]: ``summary.json`` ``ego_limits`` (a single ego), else
    ``config.json`` ``ego`` (a fleet: every ego, inserted or taken over, keeps the car's lateral
    limit, sumo_ethics.sim.ego.ego_limits), else NaN."""
    for name, keys in (("summary.json", ("ego_limits",)), ("config.json", ("ego",))):
        try:
            d = json.loads((run / name).read_text(encoding="utf-8"))
            for k in keys:
                d = d[k]
            return float(d["max_lat_accel"])
        except (OSError, ValueError, KeyError, TypeError):
            continue
    return float("nan")


def lateral_check(runs: Path, slack: float = 0.5) -> pd.DataFrame:
    """One row per finished run folder under ``runs`` (any depth; a fleet run's egos each in their own
    time order, by ``ego_id``): ``run`` (its path below ``runs``), ``limit`` (its max_lat_accel),
    ``max_lateral`` [m/s^2] and ``turn_deg`` (the heading change of that step), ``speed`` there,
    ``ego`` (whose step, in a fleet), ``steps_over`` (steps beyond the limit + ``slack``), ``steps``."""
    rows = []
    for path in sorted(Path(runs).rglob("steps.parquet")):
        if not (path.parent / "summary.json").is_file():
            continue
        limit = _limit(path.parent)
        cols = pq_columns(path)
        steps = pd.read_parquet(path, columns=["time", "yaw", "speed"] + (["ego_id"] if "ego_id" in cols else []))
        groups = steps.groupby("ego_id", sort=False) if "ego_id" in steps else [("", steps)]
        best, over, n = None, 0, 0
        for ego, g in groups:
            if len(g) < 2:
                continue
            lateral, turn = step_lateral_accel(g)
            k = int(np.nanargmax(lateral))
            if best is None or lateral[k] > best[0]:
                best = (float(lateral[k]), float(np.degrees(turn[k])), float(g["speed"].iloc[k + 1]), str(ego))
            over += int(np.sum(lateral > limit + slack))
            n += len(lateral)
        if best is None:
            continue
        rows.append({"run": str(path.parent.relative_to(runs)), "limit": limit, "max_lateral": best[0],
                     "turn_deg": best[1], "speed": best[2], "ego": best[3], "steps_over": over, "steps": n})
    return pd.DataFrame(rows, columns=["run", "limit", "max_lateral", "turn_deg", "speed", "ego", "steps_over", "steps"])


def pq_columns(path: Path) -> list[str]:
    """The column names of a Parquet file, read from its schema alone."""
    import pyarrow.parquet as pq

    return list(pq.read_schema(path).names)
