"""Analysis: load, tables with bootstrap CIs, plots and report on a synthetic sweep folder (no SUMO)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from sumo_ethics.analysis import build_dataset, load
from sumo_ethics.analysis.report import make_report
from sumo_ethics.analysis.stats import bootstrap_ci, ego_collision_harm, summary_table
from sumo_ethics.errors import ConfigError
from sumo_ethics.record import schema
from sumo_ethics.record.writer import write_json, write_table
from sumo_ethics.sweep import Manifest, make_sweep

ROOT = Path(__file__).resolve().parents[2]
TESTBED = ROOT / "scenarios" / "testbed" / "testbed.sumocfg"


def _collision(event: int, cls_b: str, harm_ego: float, harm_b: float) -> dict:
    row = {f.name: (0.0 if str(f.type) == "double" else 0 if str(f.type) == "int32" else "")
           for f in schema.COLLISIONS}
    vru = cls_b in ("pedestrian", "bicycle", "motorcycle")
    row.update(event=event, involves_ego=True, class_a="car", class_b=cls_b, delta_v=5.0, harm_a=harm_ego,
               harm_b=harm_b, harm_ego=harm_ego, harm_third_party=harm_b, harm_vru=harm_b if vru else 0.0)
    return row


@pytest.fixture
def fake_sweep(tmp_path: Path) -> Path:
    """3 w_u x 4 seeds x weights {ethical, ego}; harm falls with w_u; one run ended with a SUMO error."""
    out = tmp_path / "sw"
    sw = make_sweep(TESTBED, "0:1:0.5", "0-3", ["weights=ethical,ego"])
    specs = sw.specs()
    man = Manifest(out, sw, specs)
    rng = np.random.default_rng(1)
    for i, s in enumerate(specs):
        folder = out / "runs" / s.run_id
        folder.mkdir(parents=True)
        wu, seed = s.params["omega_u"], s.params["seed"]
        rows = []
        if seed % 2 == 0:
            rows.append(_collision(0, "car", 0.2 * (1 - wu) + 0.01, 0.3 * (1 - wu) + 0.02))
        if seed == 0:
            rows.append(_collision(1, "pedestrian", 0.0, 0.5 * (1 - wu) + 0.05))
        status = "collision" if rows else ("error" if i == 3 else "completed")
        harm = {k: float(sum(r[f"harm_{k}"] for r in rows)) for k in ("ego", "third_party", "vru")}
        harm["total"] = harm["ego"] + harm["third_party"]
        n = 20
        steps = [{"step": k, "time": 0.1 * k, "speed": float(rng.uniform(5, 10))} for k in range(n)]
        write_table(folder / "steps.parquet", steps, schema.STEPS_BASE)
        write_table(folder / "collisions.parquet", rows, schema.COLLISIONS)
        # conflicts: seed + 1 more at w_u = 0, one of them with a VRU at seed 0; none measured in the error run
        n_conf = seed + (1 if wu == 0 else 0)
        conflicts = {} if i == 3 else {"conflicts": {"total": n_conf, "vru": int(seed == 0 and n_conf > 0)}}
        write_json(folder / "summary.json", {"status": status, "message": "synthetic",
                                             "completed": status == "completed", "harm": harm,
                                             "collisions": {"ego": len(rows), "others": 0}, "steps": n,
                                             "distance": 50.0, "sim_time": 2.0, "takeover_time": 0.5,
                                             "wall_time": 1.0, "controller": "ethical", **conflicts})
        man.update({"run_id": s.run_id, "status": status, "message": "synthetic"})
    man.write()
    build_dataset(out)
    return out


def test_bootstrap_ci_contains_the_mean_and_is_seeded():
    rng = np.random.default_rng(0)
    for n in (2, 3, 5, 10, 40):
        for _ in range(20):
            x = rng.exponential(size=n) * (rng.uniform(size=n) < 0.5)
            lo, hi = bootstrap_ci(x, n_boot=1000, seed=3)
            assert lo <= x.mean() <= hi
            assert (lo, hi) == bootstrap_ci(x, n_boot=1000, seed=3)
    assert bootstrap_ci([2.0]) == (2.0, 2.0)
    assert all(np.isnan(bootstrap_ci([])))
    lo, hi = bootstrap_ci(rng.normal(10, 1, 400), n_boot=2000)
    assert 9.7 < lo < 10 < hi < 10.3  # about +/- 1.96 / sqrt(400)


def test_load_gives_tidy_tables_with_parameters(fake_sweep):
    res = load(fake_sweep)
    assert res.parameters == ("scenario", "omega_u", "seed", "weights")
    for df in (res.runs, res.collisions, res.steps):
        assert list(df.columns[:5]) == ["run_id", "scenario", "omega_u", "seed", "weights"]
    assert len(res.runs) == 24 and len(res.steps) == 24 * 20
    assert res.runs.omega_u.dtype == float and res.runs.seed.dtype == np.int64
    assert sorted(res.runs.omega_u.unique()) == [0.0, 0.5, 1.0] and set(res.runs.weights) == {"ethical", "ego"}
    assert len(res.collisions) == 3 * 2 * (2 + 1)
    assert (res.runs.status == "error").sum() == 1


def test_summary_table(fake_sweep):
    runs = load(fake_sweep).runs
    t = summary_table(runs, ["omega_u"], n_boot=500)
    assert list(t.omega_u) == [0.0, 0.5, 1.0] and list(t.n_runs) == [8, 8, 8]
    for cls in ("harm_ego", "harm_third_party", "harm_vru", "harm_total"):
        assert {f"{cls}_mean", f"{cls}_sum", f"{cls}_ci_lo", f"{cls}_ci_hi"} <= set(t.columns)
        assert (t[f"{cls}_ci_lo"] <= t[f"{cls}_mean"]).all() and (t[f"{cls}_mean"] <= t[f"{cls}_ci_hi"]).all()
    assert t.harm_total_mean.is_monotonic_decreasing
    np.testing.assert_allclose(t.harm_ego_sum, runs.groupby("omega_u").harm_ego.sum().to_numpy())
    assert t.collision_rate.tolist() == [0.5, 0.5, 0.5]
    by2 = summary_table(runs, ["omega_u", "weights"], n_boot=200)
    assert len(by2) == 6
    with pytest.raises(ConfigError, match="unknown --by"):
        summary_table(runs, ["nope"])


def test_harm_per_collision_by_class(fake_sweep):
    long = ego_collision_harm(load(fake_sweep).collisions)
    counts = long["class"].value_counts().to_dict()
    assert counts == {"ego": 18, "third party": 12, "VRU": 6}


def test_report_writes_tables_figures_and_markdown(fake_sweep, tmp_path):
    rep = make_report(fake_sweep, ["omega_u", "weights"], tmp_path / "rep", n_boot=200)
    for name in ("summary", "status", "collisions_by_class"):
        assert (tmp_path / "rep" / f"{name}.csv").exists() and (tmp_path / "rep" / f"{name}.md").exists()
    summary = pd.read_csv(tmp_path / "rep" / "summary.csv")
    assert {"omega_u", "weights", "n_runs", "completion_rate", "completion_rate_ci_lo", "harm_vru_mean",
            "harm_ego_ci_hi", "harm_third_party_sum"} <= set(summary.columns)
    assert set(pd.read_csv(tmp_path / "rep" / "status.csv").columns) == {"omega_u", "weights", "completed",
                                                                         "collision", "timeout", "error"}
    names = {p.name for p in (tmp_path / "rep" / "figures").iterdir()}
    for stem in ("harm_vs_omega_u", "completion_vs_omega_u", "harm_per_collision", "tradeoff_ego_vs_third_party"):
        assert {f"{stem}.png", f"{stem}.svg"} <= names
        assert (tmp_path / "rep" / "figures" / f"{stem}.png").stat().st_size > 10_000
    text = rep.report.read_text()
    assert "![" in text and "figures/harm_vs_omega_u.png" in text and "| omega_u | weights |" in text


def test_analyze_cli_on_a_sweep(fake_sweep):
    from click.testing import CliRunner

    from sumo_ethics.cli_sweep import analyze

    r = CliRunner().invoke(analyze, [str(fake_sweep), "--by", "omega_u", "--n-boot", "100"])
    assert r.exit_code == 0, r.output
    assert (fake_sweep / "report" / "report.md").exists()
    r = CliRunner().invoke(analyze, [str(fake_sweep), "--by", "bogus"])
    assert isinstance(r.exception, ConfigError)


def test_load_refuses_a_folder_without_manifest(tmp_path):
    with pytest.raises(ConfigError, match="not a sweep folder"):
        load(tmp_path)


def test_manifest_json_lists_every_run(fake_sweep):
    m = json.loads((fake_sweep / "manifest.json").read_text())
    assert len(m["runs"]) == 24 and m["parameters"] == ["scenario", "omega_u", "seed", "weights"]
    assert all({"run_id", "params", "status", "error", "path"} <= set(r) for r in m["runs"])


def test_a_sweep_without_collisions_gets_one_message_in_the_harm_figure(tmp_path, monkeypatch):
    import sumo_ethics.analysis.plots as P

    figs = []
    monkeypatch.setattr(P, "_save", lambda fig, folder, stem: figs.append(fig) or [])
    P.harm_per_collision(pd.DataFrame(), tmp_path)
    texts = [t.get_text() for t in figs[0].axes[0].texts]
    assert texts == ["no ego collisions in this sweep"]  # not also "none" under each class, over it


def test_conflict_rates_per_class_by_hand(fake_sweep):
    from sumo_ethics.analysis.stats import conflict_table

    res = load(fake_sweep)
    t = conflict_table(res.runs, ["omega_u"], n_boot=500).set_index("omega_u")
    # w_u = 0: 7 runs of 50 m and 1.5 s each (the error run, seed 1 with "ego", measured nothing);
    # conflicts seed + 1: "ethical" 1 + 2 + 3 + 4 = 10, "ego" 1 + 3 + 4 = 8; a VRU at seed 0 in each: 2
    r = t.loc[0.0]
    assert r["n_runs"] == 7 and r["ego_km"] == pytest.approx(0.35) and r["ego_hours"] == pytest.approx(10.5 / 3600)
    assert (r["conflicts_all"], r["conflicts_vru"], r["conflicts_vehicle"]) == (18, 2, 16)
    assert r["all_per_100km"] == pytest.approx(100 * 18 / 0.35) and r["vru_per_100km"] == pytest.approx(200 / 0.35)
    assert r["vehicle_per_hour"] == pytest.approx(16 / (10.5 / 3600))
    # w_u = 0.5: 8 runs, 0 + 1 + 2 + 3 = 6 per preset; seed 0 has none, so no VRU
    r = t.loc[0.5]
    assert r["n_runs"] == 8 and r["conflicts_all"] == 12 and r["conflicts_vru"] == 0
    for name in ("all", "vehicle", "vru"):
        for unit in ("per_100km", "per_hour"):
            row = t.loc[0.0]
            assert row[f"{name}_{unit}_ci_lo"] <= row[f"{name}_{unit}"] <= row[f"{name}_{unit}_ci_hi"]


def test_the_report_has_a_conflicts_section(fake_sweep, tmp_path):
    rep = make_report(fake_sweep, ["omega_u"], tmp_path / "rep", n_boot=100)
    text = rep.report.read_text()
    assert "## Conflicts (near misses) per class" in text and (tmp_path / "rep" / "conflicts.csv").exists()


def test_collision_table_books_only_confirmed_collisions_and_counts_the_rest():
    """Two bicycle reports (one SUMO's alone, its boxes apart: no harm; one confirmed, 0.2 to the
    cyclist), a confirmed car at 3 m/s and a truck SUMO reported alone: the means are over the
    booked ones, the unconfirmed counted beside them; a collision of two others is no ego's."""
    from sumo_ethics.analysis.stats import collision_table

    rows = [("bicycle", "sumo_unconfirmed", True, 4.0, 0.0, 0.0, 0.0),
            ("bicycle", "both", True, 6.0, 0.01, 0.2, 0.2),
            ("car", "geometry", True, 3.0, 0.02, 0.01, 0.0),
            ("truck", "sumo_unconfirmed", True, 2.0, 0.0, 0.0, 0.0),
            ("car", "sumo", False, 9.0, 0.0, 0.5, 0.0)]
    df = pd.DataFrame(rows, columns=["class_b", "detector", "involves_ego", "delta_v", "harm_ego",
                                     "harm_third_party", "harm_vru"])
    df["event"] = range(len(df))
    t = collision_table(df).set_index("class_b")
    assert list(t.index) == ["bicycle", "car", "truck"]
    assert t.n_collisions.tolist() == [1, 1, 0] and t.n_unconfirmed.tolist() == [1, 0, 1]
    assert t.loc["bicycle", "delta_v_mean_m_s"] == 6.0 and t.loc["bicycle", "harm_vru_mean"] == 0.2
    assert t.loc["car", "harm_third_party_mean"] == 0.01
    assert np.isnan(t.loc["truck", "harm_ego_mean"])
