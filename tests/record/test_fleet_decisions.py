"""Decisions in fleet runs (issue 39): one log and folder per ego, its collision snapshots, and
``explain`` / ``replay`` with ``--ego``.

Small fleets on the bundled testbed network (two egos and one SUMO car, 6 s, constant-velocity
prediction): the same seed twice, a single-ego run for the layout it keeps, and an ego-ego
collision driven on purpose.
"""

from __future__ import annotations

import json
import re
import math
import shutil
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from conftest import Scripted, write_scenario
from sumo_ethics.cli import main
from sumo_ethics.config import FleetSpec, RunConfig
from sumo_ethics.contract import Decision, Scene
from sumo_ethics.plan.ethical import VALIDITY, EthicalPlanner, PlannerConfig
from sumo_ethics.record import decisions as rec
from sumo_ethics.record.schema import COLLISIONS, CONFLICTS
from sumo_ethics.runner.fleet import planner_of, run_fleet

#: an ego whose SUMO id needs encoding as a folder name (SUMO refuses spaces in vehicle ids)
LEAD = "lead/1:a#b"
SHARES = (("ethical", 0.5), ("ego", 0.5))
CV = PlannerConfig(predictor="cv")
ROUTES = (f'<vehicle id="{LEAD}" type="car" route="r_main" depart="0" departPos="60" departLane="1" departSpeed="8"/>'
          '<vehicle id="b" type="car" route="r_main" depart="0" departPos="20" departLane="1" departSpeed="10"/>'
          '<vehicle id="c" type="car" route="r_main" depart="0" departPos="40" departLane="2" departSpeed="8"/>')


def _fleet(cfg: Path, out: Path, mode: str = "all") -> RunConfig:
    return RunConfig(scenario=cfg, out=out, seed=1, end=6.0, progress=False, planner=CV, record_decisions=mode,
                     fleet=FleetSpec(ids=(LEAD, "b"), shares=SHARES))


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Path]:
    """The two-ego fleet with every decision recorded, twice with the same seed; one single-ego run."""
    from sumo_ethics.runner import run

    base = tmp_path_factory.mktemp("fleet_decisions")
    cfg = write_scenario(base / "scenario", ROUTES, end=6.0)
    out = {"fleet": base / "fleet", "again": base / "again", "single": base / "single"}
    run_fleet(_fleet(cfg, out["fleet"]))
    run_fleet(_fleet(cfg, out["again"]))
    run(RunConfig(scenario=cfg, out=out["single"], ego_id="b", end=2.0, progress=False, planner=CV,
                  record_decisions="all"))
    return out


def _one_line_error(capsys, code: int, expected: int, fragment: str) -> str:
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == expected and len(lines) == 1 and lines[0].startswith("error: "), err
    assert fragment in lines[0], lines[0]
    return lines[0]


# ---- what a fleet run keeps ----------------------------------------------------------------------
@pytest.mark.sumo
def test_each_ego_keeps_one_file_per_step_it_planned(runs):
    run = runs["fleet"]
    steps = pd.read_parquet(run / "steps.parquet")
    summary = json.loads((run / "summary.json").read_text())
    assert rec.recorded_egos(run) == sorted([LEAD, "b"])
    # the ego folder is the id percent-encoded: no '/' to nest folders, and it decodes to the id
    assert sorted(p.name for p in (run / rec.FOLDER).iterdir()) == ["b", "lead%2F1%3Aa%23b"]
    assert not list((run / rec.FOLDER).glob("*.npz"))  # nothing in the single-ego place
    kept = {e["id"]: e["decisions"] for e in summary["egos"]}
    for ego in (LEAD, "b"):
        own = steps[steps["ego_id"] == ego]
        # every step it planned, i.e. each of its rows but the emergency brakes (no candidates weighed)
        planned = own.loc[own["validity"] != VALIDITY.index("emergency"), "step"].tolist()
        assert len(planned) > 50  # 6 s at 0.1 s, from the step after its takeover
        assert rec.recorded_steps(run, ego) == planned
        folder = run / rec.FOLDER / rec.ego_folder(ego)
        assert kept[ego] == {"mode": "all", "steps": len(planned), "bytes": sum(p.stat().st_size for p in folder.iterdir()),
                             "thinned": 0, "folder": f"decisions/{rec.ego_folder(ego)}"}
    assert summary["decisions"] == {"mode": "all", "steps": kept[LEAD]["steps"] + kept["b"]["steps"],
                                    "bytes": kept[LEAD]["bytes"] + kept["b"]["bytes"], "thinned": 0, "egos": 2}


@pytest.mark.sumo
def test_the_recorded_choice_is_where_that_ego_went(runs):
    """The chosen candidate's first point is the ego's pose in steps.parquet at the step the decision
    led to: SUMO places the ego exactly there (moveToXY), and the file keeps it in float16 relative
    to the ego's centre at planning time. Those offsets are under 2 m (one step at under 20 m/s),
    where float16's spacing is 2^-9 m: at most 2^-10 m off per axis, 2^-10 * sqrt(2) = 1.4 mm.
    The decision is that ego's own: its J_risk is the cost_j_risk of that ego's row."""
    run = runs["fleet"]
    steps = pd.read_parquet(run / "steps.parquet")
    tol = 2.0 ** -10 * math.sqrt(2) + 1e-9
    for ego in (LEAD, "b"):
        own = steps[steps["ego_id"] == ego].set_index("step")
        for k in rec.recorded_steps(run, ego):
            d, row = rec.load(run, k, ego), own.loc[k]
            assert d.time == pytest.approx(row["time"] - d.dt, abs=1e-9)
            first = d.cand_xy[d.chosen, 0]
            assert np.abs(first - d.ego[:2]).max() < 2.0
            assert np.hypot(first[0] - row["x"], first[1] - row["y"]) <= tol, (ego, k)
            assert float(d.j_risk[d.chosen]) == pytest.approx(row["cost_j_risk"], rel=1e-6, abs=1e-6)


@pytest.mark.sumo
def test_the_same_seed_gives_the_same_decision_files(runs):
    a, b = runs["fleet"] / rec.FOLDER, runs["again"] / rec.FOLDER
    files = sorted(p.relative_to(a) for p in a.rglob("*.npz"))
    assert files == sorted(p.relative_to(b) for p in b.rglob("*.npz")) and len(files) > 100
    assert all((a / f).read_bytes() == (b / f).read_bytes() for f in files)


@pytest.mark.sumo
def test_a_single_ego_run_keeps_its_layout(runs, tmp_path, capsys):
    run = runs["single"]
    steps = pd.read_parquet(run / "steps.parquet")
    assert rec.recorded_steps(run) == steps["step"].tolist() and len(steps) >= 15
    assert [p.suffix for p in (run / rec.FOLDER).iterdir()] == [".npz"] * len(steps)  # no ego folders
    assert rec.recorded_egos(run) == []
    from sumo_ethics.analysis.recorded import decisions_of

    assert decisions_of(run, None) is None and decisions_of(run, "b") is None  # its ego: its one folder
    code = main(["explain", str(run), "--step", str(steps["step"].iloc[3]), "--ego", LEAD])
    _one_line_error(capsys, code, 2, "single-ego run of ego 'b'")


# ---- explain and replay with --ego ------------------------------------------------------------------
@pytest.mark.sumo
def test_explain_with_ego_draws_that_egos_decision(runs, capsys):
    import matplotlib

    run = runs["fleet"]
    k = rec.recorded_steps(run, LEAD)[20]
    d = rec.load(run, k, LEAD)
    with matplotlib.rc_context({"svg.fonttype": "none"}):  # the title as text, to be read back
        assert main(["explain", str(run), "--ego", LEAD, "--step", str(k)]) == 0
    png = run / "explain" / rec.ego_folder(LEAD) / f"step_{k:06d}.png"
    assert png.stat().st_size > 10_000 and png.with_suffix(".svg").stat().st_size > 10_000
    assert f"ego '{LEAD}', step {k} " in capsys.readouterr().out
    title = f"fleet: step {k}, planning time t = {d.time:.2f} s, ego '{LEAD}' at {d.ego[3]:.1f} m/s"
    assert title in png.with_suffix(".svg").read_text()


@pytest.mark.sumo
def test_explain_reads_the_weights_of_the_egos_planner(runs, tmp_path):
    """With seed 1 the fleet's draw gives LEAD the `ego` preset and b `ethical`: each one's figure
    weighs its terms by its own planner's weights; a [planners.NAME] table of the fleet wins over
    the preset of that name."""
    from sumo_ethics.analysis.recorded import weights_of
    from sumo_ethics.ethics.cost import PRESETS

    run = runs["fleet"]
    assert (planner_of(1, LEAD, SHARES), planner_of(1, "b", SHARES)) == ("ego", "ethical")
    assert weights_of(run, LEAD) == asdict(PRESETS["ego"]) != weights_of(run, "b") == asdict(PRESETS["ethical"])
    named = tmp_path / "named"
    named.mkdir()
    shutil.copy(run / "summary.json", named)
    cfg = json.loads((run / "config.json").read_text())
    own = json.loads(json.dumps(cfg["planner"]))
    own["cost"]["weights"] = asdict(replace(PRESETS["ego"], ego=7.0))
    cfg["fleet"]["planners"] = [["ego", own]]
    (named / "config.json").write_text(json.dumps(cfg))
    assert weights_of(named, LEAD)["ego"] == 7.0 and weights_of(named, "b") == asdict(PRESETS["ethical"])


@pytest.mark.sumo
def test_a_fleet_run_needs_ego_and_an_ego(runs, tmp_path, capsys):
    run = str(runs["fleet"])
    k = str(rec.recorded_steps(runs["fleet"], "b")[5])
    line = _one_line_error(capsys, main(["explain", run, "--step", k]), 2, "is a fleet run: give --ego ID")
    assert f"'b', '{LEAD}'" in line  # the egos with decisions, named
    _one_line_error(capsys, main(["replay", run, "--out", str(tmp_path / "r.gif")]), 2, "give --ego ID")
    _one_line_error(capsys, main(["explain", run, "--step", k, "--ego", "c"]), 2, "--ego 'c' is not an ego of")
    _one_line_error(capsys, main(["explain", run, "--step", "0", "--ego", "b"]), 2,  # before anyone planned
                    f"step 0 of {run} has no recorded decision of ego 'b'")


@pytest.mark.sumo
def test_time_collision_and_conflict_look_at_that_egos_decisions(runs, tmp_path, capsys):
    """b's decisions after step k removed: --time finds LEAD's there, not b's. A hand-written
    collisions table (event 0: LEAD and the SUMO car c; event 1: c and another SUMO car) and
    conflicts table (0: b measured LEAD, who is party b; 1: b and c): --collision and --conflict
    take an ego's decision only for an event it is a party of, marking the other party."""
    from sumo_ethics.analysis.recorded import conflict_mark, hit_of, resolve_step

    run = tmp_path / "run"
    shutil.copytree(runs["fleet"], run)
    k = rec.recorded_steps(run, LEAD)[30]
    for s in rec.recorded_steps(run, "b"):
        if s > k:
            rec.step_path(run, s, "b").unlink()
    late = rec.load(run, k + 10, LEAD)
    assert resolve_step(run, time=late.time, ego=LEAD) == k + 10
    code = main(["explain", str(run), "--ego", "b", "--time", f"{late.time:g}"])
    _one_line_error(capsys, code, 2, f"no decision of ego 'b' recorded near t={late.time:g} s; the nearest is at "
                                     f"t={rec.load(run, k, 'b').time:g} s")
    blank = {pa.bool_(): False, pa.string(): "", pa.float64(): 0.0}
    base = {f.name: blank.get(f.type, 0) for f in COLLISIONS}
    coll = [base | dict(event=0, step=k, time=k / 10, involves_ego=True, detector="geometry", id_a=LEAD, id_b="c",
                        class_a="car", class_b="car", x_a=1.0, y_a=2.0, x_b=3.0, y_b=4.0),
            base | dict(event=1, step=k, time=k / 10, involves_ego=False, detector="sumo", id_a="c", id_b="d",
                        class_a="car", class_b="car")]
    pq.write_table(pa.Table.from_pylist(coll, schema=COLLISIONS), run / "collisions.parquet")
    d = rec.load(run, k, LEAD)
    base = {f.name: blank.get(f.type, 0) for f in CONFLICTS}
    conf = [base | dict(event=0, id_a="b", id_b=LEAD, class_a="car", class_b="car", min_ttc=1.2, min_pet=float("nan"),
                        x_a=5.0, y_a=6.0, x_b=7.0, y_b=8.0, time_worst=d.time),
            base | dict(event=1, id_a="b", id_b="c", class_a="car", class_b="car", min_ttc=2.0, time_worst=d.time)]
    pq.write_table(pa.Table.from_pylist(conf, schema=CONFLICTS), run / "conflicts.parquet")

    assert resolve_step(run, collision=0, ego=LEAD) == k
    assert hit_of(run, 0, LEAD) == (3.0, 4.0, "hit: car 'c'")
    _one_line_error(capsys, main(["explain", str(run), "--ego", "b", "--collision", "0"]), 2,
                    f"ego 'b' is not a party of collision 0 (parties: '{LEAD}' and 'c')")
    _one_line_error(capsys, main(["explain", str(run), "--ego", "b", "--collision", "1"]), 2,
                    "ego 'b' is not a party of collision 1 (parties: 'c' and 'd')")
    # LEAD is party b of conflict 0: the mark is party a, b, where it was
    assert conflict_mark(run, 0, LEAD) == (5.0, 6.0, "conflict 0: car 'b', min TTC 1.20 s")
    assert resolve_step(run, conflict=0, ego=LEAD) == k
    _one_line_error(capsys, main(["explain", str(run), "--ego", LEAD, "--conflict", "1"]), 2,
                    f"ego '{LEAD}' is not a party of conflict 1 (parties: 'b' and 'c')")


@pytest.mark.sumo
def test_replay_one_ego(runs, tmp_path, capsys):
    from PIL import Image

    out = tmp_path / "lead.gif"
    assert main(["replay", str(runs["fleet"]), "--ego", LEAD, "--out", str(out), "--every", "10", "--quiet"]) == 0
    with Image.open(out) as im:
        assert im.n_frames == math.ceil(len(rec.recorded_steps(runs["fleet"], LEAD)) / 10)
    assert capsys.readouterr().err == ""  # every step of LEAD recorded: nothing to note


def test_a_collision_found_after_the_step_keeps_what_add_would_have(tmp_path):
    """DecisionLog.collided(step) after add(step, collided=False) keeps what add(collided=True) keeps:
    with off the step itself, with collisions the 5 s (10 steps of 0.5 s) up to it; settled() then
    lets go of what no later collision keeps (off: the step's trace), and only that."""
    from test_decisions import _trace

    logs = {m: rec.DecisionLog(tmp_path / m, m, dt=0.5, ego="e/1") for m in ("off", "collisions")}
    for k in range(1, 13):
        for log in logs.values():
            log.add(k, k * 0.5, _trace(0.0), collided=False)
            if k == 12:  # found by another ego's check, after this ego's step was added
                log.collided(12)
            log.settled()
    assert logs["off"].written == [12] and logs["collisions"].written == list(range(3, 13))
    assert rec.recorded_steps(tmp_path / "off", "e/1") == [12] and (tmp_path / "off" / "decisions" / "e%2F1").is_dir()
    logs["off"].add(13, 6.5, _trace(0.0), collided=False)
    logs["off"].settled()
    logs["off"].collided(13)  # too late: settled said every collision of step 13 was known
    assert logs["off"].written == [12]


# ---- an ego-ego collision draws both egos' snapshots --------------------------------------------
class Forced:
    """The ethical planner weighs each step (its decision is recorded), but the ego is driven at a
    fixed speed, blind (conftest.Scripted): a collision on purpose."""

    name = "forced"
    needs_history = True

    def __init__(self, speed: float) -> None:
        self.planner, self.script = EthicalPlanner(CV), Scripted(speed)

    def act(self, scene: Scene) -> Decision:
        return replace(self.planner.act(scene), command=self.script.act(scene).command)


@pytest.mark.sumo
def test_an_ego_ego_collision_keeps_and_draws_both_egos_last_decision(tmp_path):
    """Default --record-decisions off: each ego keeps nothing but its decision of the step of impact,
    party b's too (the collision was found by party a's check), and each gets its own snapshot."""
    routes = ('<vehicle id="front" type="car" route="r_main" depart="0" departPos="60" departLane="1" departSpeed="3"/>'
              '<vehicle id="back" type="car" route="r_main" depart="0" departPos="10" departLane="1" departSpeed="12"/>')
    cfg = write_scenario(tmp_path / "scenario", routes, end=20.0)
    speeds = {"front": 3.0, "back": 12.0}
    out = tmp_path / "run"
    summary = run_fleet(RunConfig(scenario=cfg, out=out, progress=False, planner=CV,
                                  fleet=FleetSpec(ids=("front", "back"))), lambda name, vid: Forced(speeds[vid]))
    col = pd.read_parquet(out / "collisions.parquet")
    ev = col[col["involves_ego"]]
    assert len(ev) == 1 and ev.iloc[0]["ego_a"] and ev.iloc[0]["ego_b"]
    event, step = int(ev.iloc[0]["event"]), int(ev.iloc[0]["step"])
    assert {k: rec.recorded_steps(out, k) for k in speeds} == {"front": [step], "back": [step]}
    names = sorted(f"snapshots/collision_{event}_{k}.png" for k in speeds)
    assert "snapshots" not in summary.data and not (out / "snapshots").exists()  # the run draws none (issue 58)
    from sumo_ethics.analysis.explain import draw_snapshots

    drawn = draw_snapshots(out)
    assert sorted(drawn["snapshots"]) == names and "snapshot_error" not in drawn
    assert all((out / n).stat().st_size > 10_000 and (out / n).with_suffix(".svg").is_file() for n in names)
    assert summary.data["decisions"] == {"mode": "off", "steps": 2, "bytes": summary.data["decisions"]["bytes"],
                                         "thinned": 0, "egos": 2}


def test_a_sweeps_fleet_runs_keep_only_the_step_before_a_collision_unless_asked(tmp_path):
    """A sweep's single-ego runs keep `risky`, its fleet runs `off` (per-ego risky steps would grow
    with the egos), and --record-decisions sets both."""
    from sumo_ethics.sweep.grid import make_sweep

    cfg = write_scenario(tmp_path / "scenario", ROUTES, end=6.0)
    for omegas, grid, options, want in (("0.5", ["egos=0,2"], {}, "off"),
                                        ("0.5", ["egos=0,2"], {"record_decisions": "all"}, "all"),
                                        ("0,1", [], {}, "risky")):
        specs = make_sweep(cfg, omegas, "1", grid, options=options).specs()
        got = [s.run_config(tmp_path / s.run_id) for s in specs]
        fleet = bool(grid)
        assert [(c.fleet is not None, c.record_decisions) for c in got] == [(fleet, want), (fleet, want)]


def test_analyze_links_each_egos_snapshot(tmp_path):
    """A sweep's report links a fleet collision's figure of each ego party; the link target escapes
    the folder name's '%' once more, so that it decodes to the file's name."""
    from urllib.parse import unquote

    from sumo_ethics.analysis.report import snapshot_links

    snaps = tmp_path / "runs" / "r1" / "snapshots"
    snaps.mkdir(parents=True)
    (tmp_path / "report").mkdir()
    for name in (f"collision_0_{rec.ego_folder(LEAD)}.png", "collision_0_b.png"):
        (snaps / name).write_bytes(b"png")
    coll = pd.DataFrame([{"run_id": "r1", "event": 0, "time": 4.2, "involves_ego": True, "detector": "geometry",
                          "id_a": "b", "id_b": LEAD, "class_b": "car", "ego_a": True, "ego_b": True,
                          "harm_ego": 0.3, "harm_third_party": 0.0}])
    rows = [ln for ln in snapshot_links(tmp_path, tmp_path / "report", coll) if ln.startswith("| r1 ")]
    assert len(rows) == 1
    targets = [unquote(t) for t in re.findall(r"\]\(([^)]+)\)", rows[0])]
    assert targets == ["../runs/r1/snapshots/collision_0_b.png",
                       f"../runs/r1/snapshots/collision_0_{rec.ego_folder(LEAD)}.png"]
    assert all((tmp_path / "report" / t).resolve().is_file() for t in targets)
    assert "[png: ego 'b']" in rows[0] and f"[png: ego '{LEAD}']" in rows[0]
