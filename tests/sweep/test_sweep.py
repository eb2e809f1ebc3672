"""Sweeps: parsing, bad input, local pool vs Dask, kill-and-resume (real SUMO, short runs)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pyarrow.parquet as pq
import pytest

from sumo_ethics.analysis import load
from sumo_ethics.errors import ConfigError
from sumo_ethics.sweep import (check_out, execute_run, make_sweep, parse_range, parse_seeds, parse_set,
                               run_sweep)

ROOT = Path(__file__).resolve().parents[2]
TESTBED = ROOT / "scenarios" / "testbed" / "testbed.sumocfg"
# the ethical planner with constant-velocity prediction: fast, and w_u changes what it does
FAST = {"end": 12.0, "ego_depart": 2.0, "controller": "ethical", "predictor": "cv"}


# ---- parsing (no SUMO) -------------------------------------------------------------------------
def test_range_inclusive_and_without_float_drift():
    assert parse_range("0:1:0.1") == [0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0]
    assert parse_range("0:1:0.3") == [0.0, 0.3, 0.6, 0.9]  # 1.0 is not on the grid
    assert parse_range("0:1:0.25")[-1] == 1.0
    assert parse_range("0.5") == [0.5]
    assert parse_range("0,0.5,2") == [0.0, 0.5, 2.0]


@pytest.mark.parametrize("text", ["0:1:-0.1", "a:b", "0:1", "0:1:0", "1:0:0.1", "0:1:x", "", "0,0", "nan"])
def test_malformed_range(text):
    with pytest.raises(ConfigError, match="malformed"):
        parse_range(text, "--omega-u")


def test_seeds():
    assert parse_seeds("0-9") == list(range(10))
    assert parse_seeds("0,3,5") == [0, 3, 5]
    assert parse_seeds("0-2,7") == [0, 1, 2, 7]
    for bad in ("3-1", "a", "0,0", "-1", "1.5"):
        with pytest.raises(ConfigError):
            parse_seeds(bad)


def test_set_keys_and_values():
    s = parse_set(["omega_o=0.5,1", "sampling.n_speeds=5,9", "end=20,30", "controller=baseline,ethical",
                   "max_risk=0.01,1"])
    assert s == {"omega_o": [0.5, 1.0], "sampling.n_speeds": [5, 9], "end": [20.0, 30.0],
                 "controller": ["baseline", "ethical"], "max_risk": [0.01, 1.0]}
    with pytest.raises(ConfigError, match=r"unknown --set key 'bogus'; known: .*omega_o.*sampling\.n_speeds"):
        parse_set(["bogus=1"])
    for bad in (["omega_u=0.5"], ["seed=1"], ["end"], ["end=a"], ["end=1", "end=2"]):
        with pytest.raises(ConfigError):
            parse_set(bad)


def test_every_planner_setting_can_be_swept():
    """The keys --set takes are the [planner] table's (one list, settings.PLANNER_KEYS), and that list
    is every field of PlannerConfig and of the cost's own keys: a new field cannot be left out."""
    from dataclasses import fields

    from sumo_ethics.plan.ethical import PlannerConfig
    from sumo_ethics.settings import COST_KEYS, PLANNER_KEYS

    own = {f.name for f in fields(PlannerConfig)} - {"cost", "sampling", "probability", "perception"}
    assert set(PLANNER_KEYS) - set(COST_KEYS) == own
    s = parse_set(["calibrated=true,false", "lateral_prior=0,1.5", "evasive=false"])
    assert s == {"calibrated": [True, False], "lateral_prior": [0.0, 1.5], "evasive": [False]}
    sweep = make_sweep(TESTBED, "0.5", "0", ["calibrated=true,false", "lateral_prior=0,1.5"])
    cfgs = [spec.run_config(Path("/nonexistent")).planner for spec in sweep.specs()]
    assert sorted((c.calibrated, c.lateral_prior) for c in cfgs) == [(False, 0.0), (False, 1.5), (True, 0.0), (True, 1.5)]


def test_bad_values_fail_before_anything_runs(tmp_path):
    out = tmp_path / "sw"
    with pytest.raises(ConfigError, match="predictor"):
        run_sweep(make_sweep(TESTBED, "0.5", "0", ["predictor=nope"]), out, progress=False)
    with pytest.raises(ConfigError, match="max_risk"):
        run_sweep(make_sweep(TESTBED, "0.5", "0", ["max_risk=0,2"]), out, progress=False)
    with pytest.raises(ConfigError, match="not found"):
        make_sweep(tmp_path / "nothing.sumocfg", "0.5", "0")
    with pytest.raises(ConfigError, match="no \\*.sumocfg"):
        make_sweep(tmp_path, "0.5", "0")
    assert not out.exists()


def test_unreachable_scheduler_fails_fast(tmp_path):
    sw = make_sweep(TESTBED, "0.5", "0", options=FAST)
    t0 = time.monotonic()
    with pytest.raises(ConfigError, match="cannot reach Dask scheduler"):
        run_sweep(sw, tmp_path / "sw", scheduler="tcp://127.0.0.1:9", progress=False)
    assert time.monotonic() - t0 < 15
    with pytest.raises(ConfigError, match="malformed --scheduler"):
        run_sweep(sw, tmp_path / "sw", scheduler="localhost", progress=False)
    assert not (tmp_path / "sw" / "runs").exists()


def test_folder_of_another_sweep_is_refused(tmp_path):
    out = tmp_path / "sw"
    out.mkdir()
    a = make_sweep(TESTBED, "0:1:0.5", "0-1", options=FAST)
    (out / "manifest.json").write_text(json.dumps({"definition": a.definition(), "runs": []}))
    check_out(out, a)  # same sweep: fine (resume)
    b = make_sweep(TESTBED, "0:1:0.5", "0-2", options=FAST)
    with pytest.raises(ConfigError, match="different sweep"):
        run_sweep(b, out, progress=False)
    stranger = tmp_path / "other"
    stranger.mkdir()
    (stranger / "notes.txt").write_text("mine")
    with pytest.raises(ConfigError, match="not empty"):
        run_sweep(a, stranger, progress=False)


def test_run_ids_are_unique_and_readable():
    sw = make_sweep(TESTBED, "0:1:0.5", "0-1", ["omega_o=0.5,1"])
    specs = sw.specs()
    assert len(specs) == 12 and len({s.run_id for s in specs}) == 12
    assert specs[0].run_id.startswith("testbed_wu0_s0_omega_o-0.5_")


# ---- real runs ---------------------------------------------------------------------------------
def _summary_numbers(folder: Path) -> dict:
    s = json.loads((folder / "summary.json").read_text())
    return {k: s[k] for k in ("status", "message", "completed", "harm", "collisions", "seed", "steps", "distance",
                              "sim_time", "route_edges", "route_length")}


@pytest.fixture(scope="module")
def local_sweep(tmp_path_factory):
    out = tmp_path_factory.mktemp("sweep") / "local"
    sw = make_sweep(TESTBED, "0:1:1", "0-1", options=FAST)
    res = run_sweep(sw, out, workers=2, progress=False)
    assert (res.total, res.done, res.failed) == (4, 4, 0)
    return sw, out


@pytest.mark.sumo
def test_local_sweep_writes_runs_dataset_and_manifest(local_sweep):
    sw, out = local_sweep
    m = json.loads((out / "manifest.json").read_text())
    assert m["definition"] == sw.definition()
    assert {r["status"] for r in m["runs"]} <= {"completed", "collision", "timeout", "error"}
    for r in m["runs"]:
        assert (out / r["path"] / "summary.json").exists() and (out / r["path"] / "steps.parquet").exists()
        assert json.loads((out / r["path"] / "config.json").read_text())["out"] == str(out / r["path"])
    assert not list((out / "runs").glob(".*"))  # no temporaries left
    assert sorted(p.name for p in (out / "dataset" / "runs").iterdir()) == ["scenario=testbed"]
    assert sorted(p.name for p in (out / "dataset" / "steps" / "scenario=testbed").iterdir()) == \
        ["omega_u=0", "omega_u=1"]
    res = load(out)
    assert list(res.runs.columns[:4]) == ["run_id", "scenario", "omega_u", "seed"]
    assert len(res.runs) == 4 and set(res.runs.omega_u) == {0.0, 1.0} and set(res.runs.seed) == {0, 1}
    assert res.steps.groupby("run_id").size().to_dict() == res.runs.set_index("run_id").steps.to_dict()
    assert {"run_id", "omega_u", "seed", "event", "harm_ego"} <= set(res.collisions.columns)
    # each run's planner got its own w_u and the sweep's predictor
    for r in res.runs.itertuples():
        planner = json.loads((out / r.path / "config.json").read_text())["planner"]
        assert planner["cost"]["omega_u"] == r.omega_u and planner["predictor"] == "cv"


@pytest.mark.sumo
def test_resume_skips_finished_runs(local_sweep):
    sw, out = local_sweep
    before = {p.name: p.stat().st_mtime_ns for p in (out / "runs").iterdir()}
    res = run_sweep(sw, out, workers=2, progress=False)
    assert (res.skipped, res.done, res.failed) == (4, 4, 0)
    assert {p.name: p.stat().st_mtime_ns for p in (out / "runs").iterdir()} == before


@pytest.mark.sumo
def test_dask_cluster_gives_the_same_results(local_sweep, tmp_path):
    distributed = pytest.importorskip("distributed")
    sw, out = local_sweep
    with distributed.LocalCluster(n_workers=2, processes=True, threads_per_worker=1, dashboard_address=None) as lc:
        res = run_sweep(sw, tmp_path / "dask", scheduler=lc.scheduler_address, progress=False)
    assert (res.total, res.done, res.failed) == (4, 4, 0)
    names = sorted(p.name for p in (out / "runs").iterdir())
    assert names == sorted(p.name for p in (tmp_path / "dask" / "runs").iterdir())
    for name in names:
        a, b = out / "runs" / name, tmp_path / "dask" / "runs" / name
        assert _summary_numbers(a) == _summary_numbers(b)
        for table in ("steps", "collisions"):
            ta, tb = pq.read_table(a / f"{table}.parquet"), pq.read_table(b / f"{table}.parquet")
            assert ta.schema.equals(tb.schema, check_metadata=True)
            # bit for bit (NaN == NaN here, unlike pyarrow's Table.equals)
            pd.testing.assert_frame_equal(ta.to_pandas(), tb.to_pandas(), check_exact=True)


def _comparable(res) -> dict[str, pd.DataFrame]:
    runs = res.runs.drop(columns=["wall_time"]).sort_values("run_id").reset_index(drop=True)
    return {"runs": runs, "steps": res.steps, "collisions": res.collisions}


@pytest.mark.sumo
def test_killed_sweep_resumes_to_the_same_dataset(tmp_path):
    args = [str(TESTBED), "--omega-u", "0:1:0.5", "--seeds", "0-1", "--end", "15", "--ego-depart", "2",
            "--predictor", "cv", "--workers", "2", "--quiet"]
    killed = tmp_path / "killed"
    code = "import sys; from sumo_ethics.cli_sweep import sweep; sweep(sys.argv[1:])"
    proc = subprocess.Popen([sys.executable, "-c", code, *args, "--out", str(killed)], start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            runs = killed / "runs"
            if runs.exists() and any(not p.name.startswith(".") for p in runs.iterdir()):
                break
            time.sleep(0.05)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)  # the sweep and all its workers, mid-run
        proc.wait()
    finished = [p for p in (killed / "runs").iterdir() if not p.name.startswith(".")]
    assert 1 <= len(finished) < 6, "the kill should land mid-sweep"
    for p in finished:  # complete folders only
        assert {"summary.json", "config.json", "steps.parquet", "collisions.parquet", "params.json"} <= \
            {f.name for f in p.iterdir()}
    assert not (killed / "dataset").exists()

    sw = make_sweep(TESTBED, "0:1:0.5", "0-1", options={"end": 15.0, "ego_depart": 2.0, "predictor": "cv"})
    res = run_sweep(sw, killed, workers=2, progress=False)
    assert (res.done, res.failed) == (6, 0) and res.skipped == len(finished)
    assert not list((killed / "runs").glob(".*"))
    straight = tmp_path / "straight"
    run_sweep(sw, straight, workers=2, progress=False)
    a, b = _comparable(load(killed)), _comparable(load(straight))
    for name in a:
        pd.testing.assert_frame_equal(a[name], b[name])


@pytest.mark.sumo
def test_a_run_error_is_a_finished_result(tmp_path):
    """SUMO fails on a scenario that passes the pre-flight checks (a route over an edge the net
    does not have): the run ends with status error, recorded with SUMO's message, not retried."""
    from conftest import write_scenario

    cfg = write_scenario(tmp_path / "s", '<vehicle id="late" type="car" depart="3"><route edges="main_0 nowhere"/>'
                                         '</vehicle>', end=10)
    sw = make_sweep(cfg, "0.5", "0", options={"end": 5.0, "controller": "baseline"})
    res = run_sweep(sw, tmp_path / "sw", workers=1, progress=False)
    assert (res.done, res.errors, res.failed) == (1, 1, 0)
    m = json.loads((tmp_path / "sw" / "manifest.json").read_text())
    assert m["runs"][0]["status"] == "error" and "nowhere" in m["runs"][0]["error"]
    assert load(tmp_path / "sw").runs.status.tolist() == ["error"]


def test_input_errors_are_refused_before_any_run(tmp_path):
    """An edge the net does not have: refused at once, nothing written (it used to be stored as
    a permanent 'error' result and never retried)."""
    sw = make_sweep(TESTBED, "0.5", "0", ["ego_from=main_0,nowhere"], options={"ego_to": "main_1", "end": 5.0})
    with pytest.raises(ConfigError, match="unknown edge 'nowhere'"):
        run_sweep(sw, tmp_path / "sw", workers=1, progress=False)
    assert not (tmp_path / "sw").exists()


@pytest.mark.sumo
def test_a_run_refused_for_input_is_retried_not_stored(tmp_path):
    """A ConfigError found only inside a run (here: SUMO finds no route between two edges that
    exist) is not a result: the run leaves no folder, is listed as failed and runs again on the
    next start."""
    sw = make_sweep(TESTBED, "0.5", "0", options={"controller": "baseline", "end": 5.0, "ego_from": "main_1",
                                                   "ego_to": "main_0"})
    res = run_sweep(sw, tmp_path / "sw", workers=1, progress=False)
    assert (res.done, res.failed) == (0, 1) and "no route from edge 'main_1'" in res.failures[0]
    assert not list((tmp_path / "sw" / "runs").iterdir())
    m = json.loads((tmp_path / "sw" / "manifest.json").read_text())
    assert m["runs"][0]["status"] == "failed"


def test_execute_run_propagates_tool_crashes(tmp_path):
    """A crash of the tool (not a sumo-ethics error) leaves no run folder behind."""
    sw = make_sweep(TESTBED, "0.5", "0", options=FAST)
    spec = sw.specs()[0].to_dict()
    spec["options"]["controller"] = "nonexistent"  # bypasses validation: the worker fails
    with pytest.raises(ConfigError):
        execute_run(spec, str(tmp_path))
    assert not list(tmp_path.iterdir())


@pytest.mark.sumo
def test_ctrl_c_stops_cleanly_and_resumes(tmp_path):
    out = tmp_path / "sw"
    code = ("import sys\nfrom sumo_ethics.cli import cli, main\nfrom sumo_ethics.cli_sweep import sweep\n"
            "cli.add_command(sweep) if 'sweep' not in cli.commands else None\nsys.exit(main(sys.argv[1:]))")
    args = ["sweep", str(TESTBED), "--omega-u", "0:1:0.5", "--seeds", "0-1", "--end", "15", "--ego-depart", "2",
            "--predictor", "cv", "--workers", "2", "--quiet", "--out", str(out)]
    # a shell starting pytest in the background (`pytest &`) leaves SIGINT ignored, and Python then
    # installs no Ctrl-C handler in the child: restore the terminal's default first
    proc = subprocess.Popen([sys.executable, "-c", code, *args], start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if (out / "runs").exists() and any(not p.name.startswith(".") for p in (out / "runs").iterdir()):
            break
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGINT)  # what a terminal's Ctrl-C does: the sweep and its runs
    _, err = proc.communicate(timeout=60)
    m = json.loads((out / "manifest.json").read_text())
    finished = [p for p in (out / "runs").iterdir() if not p.name.startswith(".")]
    assert proc.returncode == 130 and err.strip().splitlines() == [
        f"error: interrupted; {len(finished)} of 6 runs are finished in {out}: the same command resumes the others"], err
    assert {r["run_id"] for r in m["runs"] if r["status"] != "pending"} == {p.name for p in finished}
    for p in finished:
        assert json.loads((p / "summary.json").read_text())["status"] in ("completed", "collision", "timeout")
    sw = make_sweep(TESTBED, "0:1:0.5", "0-1", options={"end": 15.0, "ego_depart": 2.0, "predictor": "cv"})
    res = run_sweep(sw, out, workers=2, progress=False)
    assert (res.done, res.failed, res.skipped) == (6, 0, len(finished))
    assert not list((out / "runs").glob(".*"))


@pytest.mark.sumo
def test_a_crashing_run_process_fails_alone(tmp_path):
    """One run's process crashes (here: a controller that does not exist, past validation); the
    other run is unaffected, the crash is reported with its message and leaves no folder."""
    from sumo_ethics.sweep import local_runs

    sw = make_sweep(TESTBED, "0.5", "0-1", options={**FAST, "end": 5.0})
    good, bad = (s.to_dict() for s in sw.specs())
    bad["options"]["controller"] = "nonexistent"
    results = {spec["run_id"]: result for spec, result in
               local_runs([good, bad], str(tmp_path), 2, lambda spec, line: {"status": "failed", "message": line})}
    assert results[good["run_id"]]["status"] == "timeout"
    assert results[bad["run_id"]]["status"] == "failed"
    assert "unknown controller 'nonexistent'" in results[bad["run_id"]]["message"]
    assert [p.name for p in tmp_path.iterdir()] == [good["run_id"]]


def test_report_command_line_round_trips_its_set_values():
    """The report's first line is a command a user can paste: its --set values parse back to the
    sweep's own (a bool as 'true', as typed; Python's 'True' would parse too, but reads oddly)."""
    import shlex

    from sumo_ethics.analysis.report import command_line

    sets = {"penetration": [0.0, 0.1, 1.0], "fleet": ["ethical", "ego"], "conflicts_everyone": [True]}
    line = command_line({"scenarios": ["a.sumocfg"], "omega_u": [0.5], "seeds": [0, 1], "set": sets,
                         "options": {"end": 60.0}}, out="runs/x")
    assert "--set conflicts_everyone=true " in line and "--end 60 " in line
    words = shlex.split(line)
    given = [words[i + 1] for i, w in enumerate(words) if w == "--set"]
    assert parse_set(given) == sets


def test_report_command_line_keeps_workers_and_relative_paths(tmp_path, monkeypatch):
    """The reproduce line repeats --workers (or --scheduler) and names the scenario and the sweep
    folder relative to where the command runs, eclipse-sumo's own scenarios under $SUMO_HOME."""
    import shlex

    import sumo

    from sumo_ethics.analysis.report import command_line

    monkeypatch.chdir(tmp_path)
    d = {"scenarios": [str(tmp_path / "scen" / "a.sumocfg")], "omega_u": [0.5], "seeds": [0], "set": {}, "options": {}}
    words = shlex.split(command_line(d, str(tmp_path / "runs" / "x"), {"workers": 2}))
    assert words[:3] == ["sumo-ethics", "sweep", "scen/a.sumocfg"] and words[-2:] == ["--out", "runs/x"]
    assert words[words.index("--workers") + 1] == "2" and "--scheduler" not in words
    words = shlex.split(command_line(d, "runs/x", {"scheduler": "tcp://h:8786"}))
    assert words[words.index("--scheduler") + 1] == "tcp://h:8786" and "--workers" not in words
    fkk = str(Path(sumo.SUMO_HOME).resolve() / "tools" / "game" / "fkk_in.sumocfg")
    line = command_line(d | {"scenarios": [fkk]}, "/elsewhere/x")
    assert line.startswith("sumo-ethics sweep $SUMO_HOME/tools/game/fkk_in.sumocfg ") and line.endswith("--out /elsewhere/x")


@pytest.mark.sumo
def test_analyze_reproduce_line_of_a_real_sweep(tmp_path, monkeypatch):
    from sumo_ethics.analysis.report import make_report

    monkeypatch.chdir(tmp_path)
    (tmp_path / "s").mkdir()
    (tmp_path / "s" / "testbed.sumocfg").write_text(
        f'<configuration><input><net-file value="{TESTBED.parents[2] / "networks" / "testbed" / "testbed.net.xml"}"/>'
        f'<route-files value="{TESTBED.parent / "testbed.rou.xml"}"/></input></configuration>')
    sw = make_sweep(Path("s/testbed.sumocfg"), "0.5", "0", options={"end": 3.0, "controller": "baseline"})
    run_sweep(sw, Path("runs/sw"), workers=2, progress=False)
    first = make_report(Path("runs/sw")).report.read_text().split("```sh\n", 1)[1].splitlines()[0]
    assert first == ("sumo-ethics sweep s/testbed.sumocfg --omega-u 0.5 --seeds 0 --end 3 --controller baseline "
                     "--workers 2 --out runs/sw"), first
