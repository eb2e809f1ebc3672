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


def lateral_check(runs: Path, slack: float = 0.5) -> pd.DataFrame:
    """One row per run folder under ``runs`` (any depth; single-ego runs): ``run`` (its path below
    ``runs``), ``limit`` (its max_lat_accel), ``max_lateral`` [m/s^2] and ``turn_deg`` (the heading change
    of that step), ``speed`` there, ``steps_over`` (steps beyond the limit + ``slack``), ``steps``."""
    rows = []
    for path in sorted(Path(runs).rglob("steps.parquet")):
        summary = path.parent / "summary.json"
        if not summary.is_file():
            continue
        limit = float(json.loads(summary.read_text(encoding="utf-8")).get("ego_limits", {}).get("max_lat_accel", np.nan))
        steps = pd.read_parquet(path, columns=["time", "yaw", "speed"])
        if len(steps) < 2:
            continue
        lateral, turn = step_lateral_accel(steps)
        k = int(np.nanargmax(lateral))
        rows.append({"run": str(path.parent.relative_to(runs)), "limit": limit, "max_lateral": float(lateral[k]),
                     "turn_deg": float(np.degrees(turn[k])), "speed": float(steps["speed"].iloc[k + 1]),
                     "steps_over": int(np.sum(lateral > limit + slack)), "steps": int(len(lateral))})
    return pd.DataFrame(rows, columns=["run", "limit", "max_lateral", "turn_deg", "speed", "steps_over", "steps"])
