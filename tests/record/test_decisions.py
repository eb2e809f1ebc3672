"""Recorded decisions, `explain` and collision snapshots (issue 14).

Real SUMO runs on the bundled urban junction and on a committed dilemma; the recording modes
with hand-made traces whose kept steps can be counted by hand.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from sumo_ethics.cli import cli
from sumo_ethics.config import RunConfig
from sumo_ethics.plan.ethical import PlannerConfig
from sumo_ethics.record import decisions as rec
from sumo_ethics.types import AgentStates, Candidates, CostBreakdown, DecisionTrace, Prediction

ROOT = Path(__file__).resolve().parents[2]


def sumo_ethics(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "sumo_ethics.cli", *args], capture_output=True, text=True, timeout=300)


def assert_one_line_error(p: subprocess.CompletedProcess, fragment: str, code: int) -> None:
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert p.returncode == code and len(lines) == 1 and lines[0].startswith("error: "), p.stderr
    assert fragment in lines[0] and "Traceback" not in p.stderr + p.stdout
URBAN = ROOT / "scenarios" / "urban" / "urban.sumocfg"
DILEMMAS = ROOT / "scenarios" / "dilemmas"


def _urban(out: Path, mode: str) -> RunConfig:
    return RunConfig(scenario=URBAN, out=out, seed=1, ego_depart=60, end=68, progress=False, record_decisions=mode,
                     planner=PlannerConfig(predictor="cv"))


@pytest.fixture(scope="module")
def urban_runs(tmp_path_factory):
    """The same seed twice with every decision recorded and once without."""
    from sumo_ethics.runner import run

    base = tmp_path_factory.mktemp("decisions")
    out = {}
    for name, mode in (("all", "all"), ("all2", "all"), ("off", "off")):
        out[name] = base / name
        run(_urban(out[name], mode))
    return out


# ---- recording does not change what is decided; the files are reproducible ------------------------
@pytest.mark.sumo
def test_recording_leaves_steps_byte_identical(urban_runs):
    a, b = (urban_runs[k] / "steps.parquet" for k in ("all", "off"))
    assert a.read_bytes() == b.read_bytes()
    assert not (urban_runs["off"] / rec.FOLDER).exists()  # no collision: nothing kept


@pytest.mark.sumo
def test_every_step_recorded_and_files_reproducible(urban_runs):
    steps = pd.read_parquet(urban_runs["all"] / "steps.parquet")
    recorded = rec.recorded_steps(urban_runs["all"])
    assert recorded == steps["step"].tolist()  # one decision per steps.parquet row, keyed alike
    for k in (recorded[0], recorded[len(recorded) // 2], recorded[-1]):
        assert rec.step_path(urban_runs["all"], k).read_bytes() == rec.step_path(urban_runs["all2"], k).read_bytes()
    summary = json.loads((urban_runs["all"] / "summary.json").read_text())
    assert summary["decisions"]["steps"] == len(recorded)
    assert summary["decisions"]["bytes"] == sum(p.stat().st_size for p in (urban_runs["all"] / rec.FOLDER).iterdir())


@pytest.mark.sumo
def test_recorded_decision_matches_the_step_it_led_to(urban_runs):
    """The chosen candidate's first position is where SUMO put the ego one step later (moveToXY
    places it exactly), and its recorded J_risk is the steps.parquet cost_j_risk."""
    steps = pd.read_parquet(urban_runs["all"] / "steps.parquet").set_index("step")
    for k in rec.recorded_steps(urban_runs["all"])[5::20]:
        d = rec.load(urban_runs["all"], k)
        row = steps.loc[k]
        assert d.time == pytest.approx(row["time"] - d.dt)
        assert float(d.j_risk[d.chosen]) == pytest.approx(row["cost_j_risk"], rel=1e-6, abs=1e-6)
        assert d.validity[d.chosen] == row["validity"]
        # the first stored sample is the next step: where moveToXY put the ego (float16: within 3 cm)
        assert np.hypot(*(d.cand_xy[d.chosen, 0] - [row["x"], row["y"]])) < 0.03


# ---- explain ------------------------------------------------------------------------------------
@pytest.mark.sumo
def test_explain_draws_every_candidate_and_marks_the_chosen(urban_runs, tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.collections import LineCollection

    from sumo_ethics.analysis.recorded import road_of
    from sumo_ethics.analysis.explain import decision_figure, explain

    run = urban_runs["all"]
    k = rec.recorded_steps(run)[40]
    d = rec.load(run, k)
    fig, n, _ = decision_figure(d, road_of(run), "test")
    left = fig.axes[0]
    cands = [c for c in left.collections if isinstance(c, LineCollection) and len(c.get_segments()) == d.n_candidates]
    assert len(cands) == 1 and n == d.n_candidates
    chosen = [ln for ln in left.lines if ln.get_label() == "chosen"]
    assert len(chosen) == 1
    xy = np.column_stack(chosen[0].get_data())
    np.testing.assert_allclose(xy[1:], d.cand_xy[d.chosen], atol=1e-9)  # the chosen index's path
    np.testing.assert_allclose(xy[0], d.ego[:2])
    res = explain(run, k, tmp_path / "fig")
    assert [p.name for p in res.paths] == ["fig.png", "fig.svg"] and all(p.stat().st_size > 10_000 for p in res.paths)
    assert res.decision.chosen == d.chosen and res.n_drawn == d.n_candidates


@pytest.mark.sumo
def test_explain_cli_finds_a_step_by_time_and_refuses_runs_without_decisions(urban_runs, tmp_path):
    runner = CliRunner()
    run = urban_runs["all"]
    d = rec.load(run, rec.recorded_steps(run)[10])
    res = runner.invoke(cli, ["explain", str(run), "--time", f"{d.time + 0.01:.2f}", "--out", str(tmp_path / "x")])
    assert res.exit_code == 0, res.output
    assert f"step {d.step} " in res.output and (tmp_path / "x.png").is_file()
    assert_one_line_error(sumo_ethics("explain", str(urban_runs["off"]), "--step", "3"), "--record-decisions", 2)
    assert_one_line_error(sumo_ethics("explain", str(run), "--step", "100000"), "nearest recorded step", 2)


@pytest.mark.sumo
def test_explain_draws_a_conflict_at_its_worst_moment(urban_runs, tmp_path):
    """explain --conflict K: the decision taken at the conflict's worst moment (the scene then), the other party marked
    with the conflict's measures; an unknown event is one line naming the events there are."""
    import shutil

    from sumo_ethics.record import schema
    from sumo_ethics.record.writer import write_table

    run = tmp_path / "run"
    shutil.copytree(urban_runs["all"], run)
    d = rec.load(run, rec.recorded_steps(run)[12])
    row = {f.name: (0.0 if str(f.type) == "double" else 0 if str(f.type).startswith("int") else False
                    if str(f.type) == "bool" else "") for f in schema.CONFLICTS}
    row.update(event=0, id_a="ego", id_b="walker7", class_a="car", class_b="pedestrian", time_worst=d.time,
               min_ttc=0.84, min_pet=float("nan"), x_b=float(d.ego[0]) + 6.0, y_b=float(d.ego[1]) + 2.0)
    write_table(run / "conflicts.parquet", [row], schema.CONFLICTS)
    res = CliRunner().invoke(cli, ["explain", str(run), "--conflict", "0", "--out", str(tmp_path / "c")])
    assert res.exit_code == 0, res.output
    assert f"step {d.step} " in res.output
    assert (tmp_path / "c.png").is_file() and (tmp_path / "c.svg").is_file()
    from sumo_ethics.analysis.recorded import conflict_mark

    assert conflict_mark(run, 0) == (row["x_b"], row["y_b"], "conflict 0: pedestrian 'walker7', min TTC 0.84 s")
    assert_one_line_error(sumo_ethics("explain", str(run), "--conflict", "5"), "has no conflict event 5 (events: 0)", 2)


# ---- the modes, by hand -------------------------------------------------------------------------
def _trace(chosen_risk: float) -> DecisionTrace:
    one = AgentStates(ids=("ego",), x=np.zeros(1), y=np.zeros(1), yaw=np.zeros(1), speed=np.ones(1),
                      accel=np.zeros(1), length=np.full(1, 4.5), width=np.full(1, 1.8), mass=np.full(1, 1500.0),
                      cls=np.zeros(1, np.int8), type_id=("car",))
    none = AgentStates(ids=(), x=np.zeros(0), y=np.zeros(0), yaw=np.zeros(0), speed=np.zeros(0), accel=np.zeros(0),
                       length=np.zeros(0), width=np.zeros(0), mass=np.zeros(0), cls=np.zeros(0, np.int8), type_id=())
    K, T = 2, 4
    z = np.zeros((K, T))
    cand = Candidates(dt=0.1, x=np.tile(np.arange(1, T + 1, dtype=float), (K, 1)), y=z.copy(), yaw=z.copy(),
                      speed=z.copy(), accel=z.copy(), curvature=z.copy(), s=z.copy(), d=z.copy(),
                      horizon=np.full(K, 0.4), valid=np.ones((K, T), bool))
    pred = Prediction(ids=(), dt=0.1, mean=np.zeros((0, T, 2)), cov=np.zeros((0, T, 2, 2)), yaw=np.zeros((0, T)))
    return DecisionTrace(ego=one, agents=none, prediction=pred, candidates=cand,
                         cost=CostBreakdown(terms={"j_risk": np.array([1.0, 2.0])}, total=np.array([1.0, 2.0])),
                         selection=np.array([1.0, 2.0]), validity=np.array([0, 3], np.int8),
                         eligible=np.ones(K, bool), first_hit=np.full(K, T), risk=np.array([chosen_risk, 0.5]),
                         chosen=0)


@pytest.mark.parametrize("mode, want", [
    # 100 steps at 0.5 s; the chosen candidate carries risk at steps 10-12; an ego collision at step 60.
    # PRE_COLLISION 5 s = 10 steps: steps 51-60 are kept before the collision.
    ("all", list(range(1, 101))),
    ("risky", [10, 11, 12] + list(range(51, 61))),
    ("collisions", list(range(51, 61))),
    ("off", [60]),
])
def test_modes_keep_the_steps_they_promise(tmp_path, mode, want):
    log = rec.DecisionLog(tmp_path, mode, dt=0.5)
    for k in range(1, 101):
        log.add(k, k * 0.5, _trace(1e-4 if k in (10, 11, 12) else 0.0), collided=k == 60)
    assert rec.recorded_steps(tmp_path) == want == log.written
    d = rec.load(tmp_path, want[-1])
    assert d.chosen == 0 and d.n_candidates == 2 and d.step == want[-1] and d.time == want[-1] * 0.5
    # the next step, then every 0.5 s (none within this 0.4 s horizon), and always the horizon's end
    np.testing.assert_allclose(d.cand_t, [0.1, 0.4], rtol=1e-6)
    np.testing.assert_allclose(d.cand_xy[0, :, 0], [1.0, 4.0])


def test_bad_mode_is_one_line_exit_2(tmp_path):
    p = sumo_ethics("run", str(URBAN), "--record-decisions", "some", "--out", str(tmp_path / "r"))
    assert p.returncode == 2 and "--record-decisions" in p.stderr and "Traceback" not in p.stderr
    assert not (tmp_path / "r").exists()


# ---- a collision draws its snapshot ----------------------------------------------------------------
@pytest.mark.sumo
def test_unavoidable_collision_writes_its_snapshot(tmp_path):
    from sumo_ethics.analysis.report import snapshot_links
    from sumo_ethics.plan.ethical import EthicalPlanner
    from sumo_ethics.runner import run
    from sumo_ethics.sim.hazards import HazardInjector
    from sumo_ethics.suite.spec import load

    spec = load(DILEMMAS / "d0000")
    pcfg = PlannerConfig(predictor="cv")
    out = tmp_path / "runs" / "r1"
    summary = run(spec.run_config(out, pcfg, record_decisions="collisions"),
                  controller=EthicalPlanner(pcfg), hooks=(HazardInjector(spec.hazards),))
    assert summary.data["status"] == "collision"
    coll = pd.read_parquet(out / "collisions.parquet")
    ev = coll[coll["involves_ego"]].iloc[0]
    # the run draws no figures (issue 58): they are drawn from the folder, as 'run' and evaluate do when it ends
    assert "snapshots" not in summary.data and not (out / "snapshots").exists()
    from sumo_ethics.analysis.explain import draw_snapshots

    drawn = draw_snapshots(out)
    assert drawn["snapshots"] == [f"snapshots/collision_{ev['event']}.png"] and "snapshot_error" not in drawn
    assert (out / "snapshots" / f"collision_{ev['event']}.svg").is_file()
    assert json.loads((out / "summary.json").read_text())["snapshots"] == drawn["snapshots"]  # listed there too
    png = out / drawn["snapshots"][0]
    first = png.read_bytes()
    # on request: explain RUN --snapshots draws the same figure again
    import shutil

    shutil.rmtree(out / "snapshots")
    res = CliRunner().invoke(cli, ["explain", str(out), "--snapshots"])
    assert res.exit_code == 0, res.output
    assert f"collision snapshot: {png}" in res.output and png.read_bytes() == first
    # the run command draws them when the run returns (cli._drawn around runner.run), into its summary's data
    from sumo_ethics.cli import _drawn
    from sumo_ethics.runner import RunSummary

    shutil.rmtree(out / "snapshots")
    after = _drawn(lambda: RunSummary(summary.status, summary.message, out, dict(summary.data)), out)
    assert after.data["snapshots"] == drawn["snapshots"] and png.read_bytes() == first
    kept = rec.recorded_steps(out)  # the 5 s before impact, ending with the step of the impact
    assert kept[-1] == ev["step"] and len(kept) == 50 and kept == list(range(ev["step"] - 49, ev["step"] + 1))
    # analyze's report links it
    coll["run_id"] = "r1"
    lines = snapshot_links(tmp_path, tmp_path / "report", coll)
    assert any(f"(../runs/r1/snapshots/collision_{ev['event']}.png)" in ln for ln in lines)


def test_risky_past_its_budget_keeps_one_step_per_second(tmp_path, monkeypatch):
    """With a budget of 5 risky steps at 0.1 s and thinning to one per second: steps 1-5
    (t = 0.1-0.5 s) are kept, then one per second after the last kept (15, 25, 35, 45: t = 1.5, 2.5, ...), and the 5 s (50 steps) before
    a collision at step 100 in full."""
    monkeypatch.setattr(rec, "RISKY_BUDGET", 5)
    monkeypatch.setattr(rec, "THIN_SECONDS", 1.0)
    monkeypatch.setattr(rec, "RISKY_SPACING", 0.1)
    log = rec.DecisionLog(tmp_path, "risky", dt=0.1)
    for k in range(1, 101):
        log.add(k, round(k * 0.1, 10), _trace(1e-3), collided=k == 100)
    assert log.written[:9] == [1, 2, 3, 4, 5, 15, 25, 35, 45]
    assert rec.recorded_steps(tmp_path) == [1, 2, 3, 4, 5, 15, 25, 35, 45] + list(range(51, 101))
    assert log.thinned == 100 - 14  # kept as risky: 1-5 and 15, 25, ..., 95


def test_risky_keeps_at_most_one_step_per_half_second_of_simulated_time(tmp_path):
    """Every step risky at 0.05 s steps (fokr_bs_demo's length) for 60 s: one kept every 0.5 s, i.e.
    steps 1, 11, 21, ... (t = 0.05, 0.55, ...), 120 in the simulated minute, the other 1080 thinned;
    a collision at step 1200 still keeps the 5 s (100 steps) before it in full."""
    log = rec.DecisionLog(tmp_path, "risky", dt=0.05)
    for k in range(1, 1201):
        log.add(k, round(k * 0.05, 10), _trace(1e-3), collided=k == 1200)
    spaced = list(range(1, 1201, 10))
    assert log.written[:120] == spaced and log.risky_kept == 120 and log.thinned == 1080
    assert rec.recorded_steps(tmp_path) == sorted(set(spaced) | set(range(1101, 1201)))


@pytest.mark.sumo
def test_unreadable_or_empty_recordings_are_one_line_errors(urban_runs, tmp_path):
    import shutil

    run = tmp_path / "copy"
    shutil.copytree(urban_runs["all"], run)
    k = rec.recorded_steps(run)[3]
    path = rec.step_path(run, k)
    path.write_bytes(path.read_bytes()[:1000])  # a file cut short
    assert_one_line_error(sumo_ethics("explain", str(run), "--step", str(k)), "truncated or corrupt", 2)
    assert_one_line_error(sumo_ethics("explain", str(run), "--time", "nan"), "finite", 2)
    quiet = tmp_path / "quiet"  # a risky run whose choices never carried risk keeps nothing
    quiet.mkdir()
    (quiet / "summary.json").write_text(json.dumps({"decisions": {"mode": "risky", "steps": 0, "bytes": 0}}))
    assert_one_line_error(sumo_ethics("explain", str(quiet), "--step", "1"), "--record-decisions all", 2)


@pytest.mark.sumo
def test_predictions_are_kept_every_half_second_and_ellipses_fall_on_whole_seconds(urban_runs):
    """A 4 s prediction at 0.1 s is kept at 0.5, 1.0, ..., 4.0 s (8 samples, not 40): explain and
    replay draw its ellipses every second, at the samples 1, 2, 3 and 4 s."""
    d = rec.load(urban_runs["all"], rec.recorded_steps(urban_runs["all"])[10])
    np.testing.assert_allclose(d.pred_t, np.arange(1, 9) * 0.5, rtol=1e-6)
    assert d.pred_mean.shape[1] == d.pred_cov.shape[1] == 8
    assert d.whole_seconds().tolist() == [1, 3, 5, 7]


def test_figures_name_a_party_as_sumo_types_it():
    """The class follows SUMO's vClass; the vType is named beside it, as collisions.parquet and
    conflicts.parquet hold it: a vType 'truck/trailer' without a vClass is SUMO's passenger car."""
    from sumo_ethics.analysis.recorded import collision_mark, party_label
    from sumo_ethics.types import RoadUserClass

    assert RoadUserClass.from_vclass("passenger").label == "car"  # SUMO's default vClass
    row = {"id_a": "ego", "id_b": "4_left.3", "class_a": "car", "class_b": "car", "type_a": "ego_type",
           "type_b": "truck/trailer", "x_a": 0.0, "y_a": 0.0, "x_b": 3.0, "y_b": 4.0}
    assert party_label(row, "b") == "car '4_left.3' (vType truck/trailer)"
    assert collision_mark(row) == (3.0, 4.0, "hit: car '4_left.3' (vType truck/trailer)")
    assert party_label(row | {"type_b": ""}, "b") == "car '4_left.3'"  # no vType recorded
    assert party_label(row | {"type_b": "car"}, "b") == "car '4_left.3'"  # a vType named as its class


@pytest.mark.sumo
@pytest.mark.parametrize("excluded, square", [(0, False), (4, False), (1, True), (0, True)])
def test_explain_figure_text_fits(urban_runs, excluded, square):
    """Every title, label, legend entry and cost-table cell of the explain figure lies on the canvas
    and every table text inside its cell, in both layouts (maps side by side or stacked) and with the
    longest note of a hard constraint (under the table, not in its header)."""
    import dataclasses

    import matplotlib.pyplot as plt

    from sumo_ethics.analysis.explain import decision_figure, describe, overflowing_text
    from sumo_ethics.analysis.recorded import road_of, weights_of

    run = urban_runs["all"]
    d = rec.load(run, rec.recorded_steps(run)[40])
    if excluded:
        d = dataclasses.replace(d, excluded=np.full(len(d.validity), excluded, dtype=np.int8))
    hit = (float(d.ego[0]), float(d.ego[1]) + 45.0, "hit: car 'veh' (vType truck/trailer)") if square else None
    fig, _, _ = decision_figure(d, road_of(run), describe(run, d), weights_of(run, None), hit)
    try:
        assert overflowing_text(fig) == []
        notes = [t.get_text() for ax in fig.axes for t in ax.texts if t.get_text().startswith("* excluded: ")]
        assert len(notes) == (1 if excluded else 0), notes
    finally:
        plt.close(fig)


def test_overflowing_text_finds_text_off_the_canvas():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sumo_ethics.analysis.explain import overflowing_text

    fig, ax = plt.subplots(figsize=(4, 3))
    ax.set_title("fits")
    assert overflowing_text(fig) == []
    ax.text(0.9, 0.5, "a long label running off the right edge", transform=ax.transAxes)
    tab = ax.table(cellText=[["a much too long text for its narrow cell"]], colWidths=[0.1], loc="lower left")
    tab.auto_set_font_size(False)
    tab.set_fontsize(8)
    got = overflowing_text(fig)
    plt.close(fig)
    assert "'a long label running off the right edge' beyond the canvas" in got
    assert "'a much too long text for its narrow cell' beyond its table cell" in got
