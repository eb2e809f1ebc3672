"""A finished run's outcome read back from its folder, for the evaluation tables: completion, ego
collisions and the harm to each party, harm by fault, conflicts and over-cautious brakings
(the suite's Table 1 and the CommonRoad evaluation share it)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

def read_summary(out: Path) -> dict[str, Any] | None:
    try:
        return json.loads((out / "summary.json").read_text())
    except (OSError, ValueError):
        return None


def snapshots_of(out: Path) -> dict[str, Any]:
    """The collision snapshot figures of the run in ``out``, drawn from the folder when it booked an
    ego collision (:func:`sumo_ethics.analysis.explain.draw_snapshots`: the run draws none; listed in
    summary.json); the summary keys written ({} when there was nothing to draw)."""
    from sumo_ethics.record.reader import collided

    if not collided(out):
        return {}
    from sumo_ethics.analysis.explain import draw_snapshots

    return draw_snapshots(out)


def _ego_collisions(out: Path) -> Any:
    """The run's booked ego collisions (collisions.parquet without the unconfirmed SUMO reports), None
    if the file cannot be read."""
    try:
        import pandas as pd

        c = pd.read_parquet(out / "collisions.parquet")
        return c[c.involves_ego & (c.detector != "sumo_unconfirmed")]
    except Exception:  # noqa: BLE001 - no or a damaged file
        return None


def _victims(c: Any) -> dict[str, Any]:
    """``collided_with`` (class and origin of the ego's first victim, '' if none) and
    ``harm_worst`` (the largest harm booked to a single party, the ego included, 0 if none) of the
    booked ego collisions ``c`` (:func:`_ego_collisions`; None: unreadable)."""
    if c is None:
        return {"collided_with": "", "harm_worst": float("nan")}
    try:
        if not len(c):
            return {"collided_with": "", "harm_worst": 0.0}
        r = c.iloc[0]
        return {"collided_with": f"{r['class_b']}:{'hazard' if str(r['id_b']).startswith('hazard_') else 'traffic'}",
                "harm_worst": float(max(c.harm_ego.max(), c.harm_third_party.max()))}
    except Exception:  # noqa: BLE001
        return {"collided_with": "", "harm_worst": float("nan")}


def outcome(out: Path, summary: dict[str, Any]) -> dict[str, Any]:
    """:func:`_victims` and :func:`_safety` of a run folder, collisions.parquet read once."""
    c = _ego_collisions(out)
    return {**_victims(c), **_safety(out, summary, c)}


#: fault values of collisions.parquet, in the order the tables list them
FAULTS = ("ego", "other", "shared", "unknown")
#: over-caution: a hard braking (below -HARD_BRAKE m/s^2, 0.3 g, the harsh-braking threshold common
#: in naturalistic driving studies) with no conflict under way or starting from WARRANT_BEFORE s
#: before it to WARRANT_AFTER s after it, and no red light ahead
HARD_BRAKE = 0.3 * 9.81
WARRANT_BEFORE, WARRANT_AFTER = 1.0, 3.0


def overcautious_brakings(steps: Any, conflicts: Any) -> int:
    """Number of hard-braking episodes (consecutive steps with accel < -HARD_BRAKE) of a run with
    no conflict (``conflicts.parquet``: ``start``, ``end``) overlapping [t0 - WARRANT_BEFORE,
    t0 + WARRANT_AFTER] around the episode's first step t0 and no red/yellow stop line ahead
    (``stop_s``) at t0."""
    import pandas as pd

    if steps is None or len(steps) == 0 or "accel" not in steps:
        return 0
    hard = (steps["accel"].to_numpy(float) < -HARD_BRAKE)
    first = np.flatnonzero(hard & ~np.r_[False, hard[:-1]])
    t = steps["time"].to_numpy(float)
    red = steps["stop_s"].notna().to_numpy() if "stop_s" in steps else np.zeros(len(steps), bool)
    c = conflicts if conflicts is not None else pd.DataFrame({"start": [], "end": []})
    n = 0
    for i in first:
        lo, hi = t[i] - WARRANT_BEFORE, t[i] + WARRANT_AFTER
        warranted = bool(((c["start"] <= hi) & (c["end"] >= lo)).any()) if len(c) else False
        n += int(not warranted and not red[i])
    return n


def _safety(out: Path, summary: dict[str, Any], c: Any) -> dict[str, Any]:
    """Per run: ``distance`` [m] and ``drive_time`` [s] of the ego, ``conflicts_total``,
    ``conflicts_vru`` and ``overcautious`` (NaN where conflicts were not measured) and
    ``harm_fault_<f>``: the harm (ego + third party) of the booked ego collisions ``c``
    (:func:`_ego_collisions`) whose ``fault`` is f (docs/conflicts.md)."""
    from sumo_ethics.analysis.sweep_tables import drive_time

    conf = summary.get("conflicts")
    driven = drive_time(summary)
    row: dict[str, Any] = {
        "distance": float(summary.get("distance", 0.0) or 0.0),
        "drive_time": float("nan") if driven is None else driven,
        "conflicts_total": float(conf["total"]) if conf else float("nan"),
        "conflicts_vru": float(conf["vru"]) if conf else float("nan"),
        **{f"harm_fault_{f}": 0.0 for f in FAULTS}, "overcautious": float("nan")}
    if conf:  # conflicts were measured: a braking without one under way is over-cautious
        try:
            import pandas as pd

            steps = pd.read_parquet(out / "steps.parquet", columns=["time", "accel", "stop_s"])
            cpath = out / "conflicts.parquet"
            row["overcautious"] = float(overcautious_brakings(steps, pd.read_parquet(cpath) if cpath.exists() else None))
        except Exception:  # noqa: BLE001 - no steps: nothing to count
            pass
    if c is None or "fault" not in c.columns:  # no collisions file, or one from before fault: nothing booked
        return row
    for f in FAULTS:
        sel = c[c.fault == f]
        row[f"harm_fault_{f}"] = float(sel.harm_ego.sum() + sel.harm_third_party.sum())
    return row
