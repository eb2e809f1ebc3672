"""Table 1 with conflict rates and harm by fault (issue 38): numbers by hand."""

from __future__ import annotations

import math

import pytest

from sumo_ethics.record import schema
from sumo_ethics.record.writer import write_json, write_table
from sumo_ethics.suite.evaluate import safety_markdown, safety_table
from sumo_ethics.suite.outcome import outcome


def _row(planner, km, total, vru, **harm):
    return {"planner": planner, "distance": 1000.0 * km, "conflicts_total": float(total), "conflicts_vru": float(vru),
            **{f"harm_fault_{f}": harm.get(f, 0.0) for f in ("ego", "other", "shared", "unknown")}}


def test_rates_and_fault_sums_by_hand():
    rows = [_row("a", 0.5, 3, 1, ego=0.2), _row("a", 1.5, 1, 0, other=0.05),
            _row("b", 2.0, 0, 0), {**_row("b", 1.0, 0, 0, ego=0.4), "conflicts_total": math.nan}]  # not measured
    a, b = safety_table(rows, ["a", "b"], n_boot=500)
    assert (a["runs"], a["ego_km"], a["conflicts_total"], a["conflicts_vru"]) == (2, 2.0, 4.0, 1.0)
    assert a["conflicts_total_per_100km"] == pytest.approx(200.0) and a["conflicts_vru_per_100km"] == pytest.approx(50.0)
    assert a["conflicts_total_per_100km_lo"] <= 200.0 <= a["conflicts_total_per_100km_hi"]
    assert (a["harm_fault_ego"], a["harm_fault_other"]) == (0.2, 0.05)
    # b: only the measured run counts for the rates; its harm by fault counts every run
    assert (b["runs"], b["ego_km"], b["conflicts_total_per_100km"]) == (1, 2.0, 0.0) and b["harm_fault_ego"] == 0.4
    text = "\n".join(safety_markdown([a, b]))
    assert "| a | 2.0 | 200.0 [" in text and "Harm, fault ego" in text


def test_a_run_folder_gives_its_conflicts_and_harm_by_fault(tmp_path):
    base = {f.name: (0.0 if str(f.type) == "double" else 0 if str(f.type) == "int32" else "") for f in schema.COLLISIONS}
    rows = [{**base, "event": 0, "involves_ego": True, "detector": "both", "harm_ego": 0.1, "harm_third_party": 0.3,
             "fault": "ego"},
            {**base, "event": 1, "involves_ego": True, "detector": "sumo_unconfirmed", "harm_ego": 0.5, "fault": "other"},
            {**base, "event": 2, "involves_ego": False, "detector": "sumo", "harm_ego": 0.0, "fault": "unknown"},
            {**base, "event": 3, "involves_ego": True, "detector": "geometry", "harm_ego": 0.02, "harm_third_party": 0.01,
             "fault": "other"}]
    write_table(tmp_path / "collisions.parquet", rows, schema.COLLISIONS)
    summary = {"distance": 250.0, "sim_time": 40.0, "takeover_time": 10.0, "conflicts": {"total": 3, "vru": 1}}
    write_json(tmp_path / "summary.json", summary)
    s = outcome(tmp_path, summary)
    assert (s["distance"], s["drive_time"], s["conflicts_total"], s["conflicts_vru"]) == (250.0, 30.0, 3.0, 1.0)
    # unconfirmed contacts and collisions without the ego book nothing
    assert s["harm_fault_ego"] == pytest.approx(0.4) and s["harm_fault_other"] == pytest.approx(0.03)
    assert s["harm_fault_shared"] == s["harm_fault_unknown"] == 0.0
    assert math.isnan(outcome(tmp_path, {"distance": 1.0})["conflicts_total"])  # conflicts off: not 0


def test_overcautious_brakings_by_hand():
    import numpy as np
    import pandas as pd

    from sumo_ethics.suite.outcome import overcautious_brakings

    t = np.round(np.arange(0, 100) * 0.1, 1)
    accel = np.full(100, -1.0)
    accel[(t >= 1.0) & (t <= 1.2)] = -4.0  # 1: nothing near it: over-cautious
    accel[t == 5.0] = -4.0  # 2: a conflict starts 0.5 s later: warranted
    accel[t == 8.0] = -4.0  # 3: a red light ahead: warranted
    accel[t == 9.5] = -2.9  # above -0.3 g: not hard
    stop = np.where(t == 8.0, 50.0, np.nan)
    steps = pd.DataFrame({"time": t, "accel": accel, "stop_s": stop})
    conflicts = pd.DataFrame({"start": [5.5], "end": [6.0]})
    assert overcautious_brakings(steps, conflicts) == 1
    assert overcautious_brakings(steps, None) == 2  # without the conflict, braking 2 is over-cautious too
    later = pd.DataFrame({"start": [8.5], "end": [9.0]})  # 3.5 s after braking 2: too late to warrant it
    assert overcautious_brakings(steps, later) == 2
