"""Every bad input, at every stage, in one table: exit code, exactly one line on stderr that
starts with ``error:``, no traceback, and whatever was in --out before is still there."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import sumo

from conftest import SCENARIOS, TESTBED_NET

TESTBED = SCENARIOS / "testbed" / "testbed.sumocfg"
RAIL = Path(sumo.SUMO_HOME) / "tools" / "game" / "rail" / "test.sumocfg"  # edge -E0 is rail only

# an earlier run's files (and a figure drawn from it) in --out: a refused run must leave them all
PREVIOUS = {"config.json": '{"scenario": "old.sumocfg", "resolved": {}}\n', "sumo-errors.log": "old log\n",
            "summary.json": '{"status": "old", "message": "", "seed": 1}\n', "explain/step_000010.png": "old figure\n",
            "replay.gif": "old animation\n"}


def _previous_run(out: Path) -> None:
    for name, text in PREVIOUS.items():
        (out / name).parent.mkdir(parents=True, exist_ok=True)
        (out / name).write_text(text)


def _scenario(folder: Path, net: str | None = None, routes: str | None = None) -> Path:
    """A copy of the testbed scenario with the net or the routes file replaced by ``net``/``routes``."""
    folder.mkdir(parents=True, exist_ok=True)
    shutil.copy(SCENARIOS / "testbed" / "testbed.rou.xml", folder / "r.rou.xml")
    net_path = folder / "n.net.xml" if net is not None else TESTBED_NET
    if net is not None:
        net_path.write_text(net)
    if routes is not None:
        (folder / "r.rou.xml").write_text(routes)
    cfg = folder / "s.sumocfg"
    cfg.write_text(f'<configuration><input><net-file value="{net_path}"/><route-files value="r.rou.xml"/></input>'
                   '<time><end value="30"/></time></configuration>')
    return cfg


def _toml(folder: Path, text: str) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    p = folder / "p.toml"
    p.write_text(text)
    return p


def _fake_sweep(folder: Path, damage: str) -> Path:
    """A one-run sweep folder without SUMO, then damaged: a truncated Parquet file of the run
    ('steps', 'collisions'), of the dataset ('dataset'), or a garbage summary ('summary')."""
    from sumo_ethics.analysis import build_dataset
    from sumo_ethics.record import schema
    from sumo_ethics.record.writer import write_json, write_table
    from sumo_ethics.sweep import Manifest, make_sweep

    sw = make_sweep(TESTBED, "1", "0", options={"end": 5.0, "controller": "baseline"})
    spec = sw.specs()[0]
    run = folder / "runs" / spec.run_id
    run.mkdir(parents=True)
    write_table(run / "steps.parquet", [{"step": k, "time": 0.1 * k, "speed": 5.0} for k in range(50)],
                schema.STEPS_BASE)
    write_table(run / "collisions.parquet", [], schema.COLLISIONS)
    write_json(run / "summary.json", {"status": "timeout", "message": "", "completed": False, "steps": 50})
    man = Manifest(folder, sw, [spec])
    man.update({"run_id": spec.run_id, "status": "timeout"})
    man.write()
    if damage == "none":
        return folder
    if damage == "dataset":
        build_dataset(folder)
        target = next((folder / "dataset" / "runs").rglob("*.parquet"))
    elif damage == "summary":
        (run / "summary.json").write_text("{not json")
        return folder
    else:
        target = run / f"{damage}.parquet"
    data = target.read_bytes()
    target.write_bytes(data[: len(data) // 2])
    return folder


SWEEP_FAST = ["--omega-u", "1", "--seeds", "0", "--end", "5", "--controller", "baseline", "--quiet"]

# (id, command builder(tmp) -> args, exit code, fragment of the error line)
CASES = [
    ("missing-scenario", lambda t: ["run", str(t / "nope.sumocfg")], 2, "scenario file not found"),
    ("scenario-folder", lambda t: ["run", str(_scenario(t / "s").parent)], 2, "is a folder, not a SUMO config: give the "
     ".sumocfg file; it holds"),
    ("net-malformed", lambda t: ["run", str(_scenario(t / "s", net=TESTBED_NET.read_text()[:3000]))], 2,
     "malformed net file"),
    ("net-empty-file", lambda t: ["run", str(_scenario(t / "s", net=""))], 2, "malformed net file"),
    ("net-without-edges", lambda t: ["run", str(_scenario(t / "s", net="<net/>"))], 2, "has no edges"),
    ("net-not-a-net", lambda t: ["run", str(_scenario(t / "s", net="<routes/>"))], 2, "not a SUMO net file"),
    ("routes-malformed", lambda t: ["run", str(_scenario(t / "s", routes="<routes><vType id='a'"))], 2,
     "malformed route file"),
    ("ego-edge-unknown", lambda t: ["run", str(TESTBED), "--ego-from", "main_0", "--ego-to", "nowhere"], 2,
     "unknown edge 'nowhere'"),
    ("ego-edge-forbidden", lambda t: ["run", str(RAIL), "--ego-from", "-E0", "--ego-to", "E0"], 2,
     "no lane a passenger car may use"),
    ("config-is-a-folder", lambda t: ["run", str(TESTBED), "--config", str(t)], 2, "is a folder"),
    ("fleet-unknown-planner", lambda t: ["run", str(TESTBED), "--egos", "2", "--fleet", "ethical=0.5,kind=0.5"], 2,
     "--fleet: unknown planner 'kind'"),
    ("fleet-shares-sum", lambda t: ["run", str(TESTBED), "--egos", "2", "--fleet", "ethical=0.5,ego=0.2"], 2,
     "--fleet shares must sum to 1"),
    ("fleet-penetration", lambda t: ["run", str(TESTBED), "--penetration", "1.5"], 2, "--penetration must be a share"),
    ("fleet-with-ego-from", lambda t: ["run", str(TESTBED), "--egos", "2", "--ego-from", "main_0", "--ego-to", "main_1"],
     2, "place the single inserted ego"),
    ("fleet-unknown-ego", lambda t: ["run", str(TESTBED), "--ego", "nobody", "--ego", "none"], 2, "nobody"),
    ("gui-with-fleet", lambda t: ["run", str(TESTBED), "--gui", "--egos", "2"], 2, "--gui shows a single ego"),
    ("gui-delay-without-gui", lambda t: ["run", str(TESTBED), "--gui-delay", "100"], 2, "give --gui too"),
    ("gui-delay-negative", lambda t: ["run", str(TESTBED), "--gui", "--gui-delay", "-5"], 2,
     "--gui-delay must be 0 or more"),
    ("toml-planner-not-a-table", lambda t: ["run", str(TESTBED), "--config", str(_toml(t / "c", "planner = 3"))], 2,
     "'planner' must be a table"),
    ("toml-sampling-not-a-table", lambda t: ["run", str(TESTBED), "--config",
                                             str(_toml(t / "c", "[planner]\nsampling = 5"))], 2, "must be a table"),
    ("too-many-candidates", lambda t: ["run", str(TESTBED), "--config",
                                       str(_toml(t / "c", "[planner.sampling]\nn_speeds = 100000"))], 2,
     "the limit is 5000"),
    ("candidate-steps-too-many", lambda t: ["run", str(TESTBED), "--config",
                                            str(_toml(t / "c", "[planner.sampling]\nhorizons = [10.0]\n"
                                                                "n_speeds = 50\nn_offsets = 50"))], 2,
     "the limit is 200000"),
    ("horizon-too-long", lambda t: ["run", str(TESTBED), "--config",
                                    str(_toml(t / "c", "[planner.sampling]\nhorizons = [1e5]"))], 2,
     "beyond the limit of 10 s"),
    ("end-negative", lambda t: ["run", str(TESTBED), "--end", "-5"], 2, "--end"),
    # a clock time is read per field (SUMO itself would add 15:99:00 up to 16:39:00)
    ("ego-depart-minutes-99", lambda t: ["run", str(TESTBED), "--ego-depart", "15:99:00"], 2,
     "'15:99:00' has minutes 99; a clock time's minutes are below 60 (SUMO would add the fields up to 59940 s"),
    ("end-seconds-99", lambda t: ["run", str(TESTBED), "--end", "0:01:99"], 2,
     "'0:01:99' has seconds 99; a clock time's seconds are below 60 (SUMO would add the fields up to 159 s)"),
    ("end-hours-24-after-a-day", lambda t: ["run", str(TESTBED), "--end", "1:24:00:00"], 2, "hours are below 24"),
    ("end-fractional-minutes", lambda t: ["run", str(TESTBED), "--end", "0:1.5:00"], 2,
     "only the seconds of a clock time may have a fraction"),
    ("sweep-end-clock", lambda t: ["sweep", str(TESTBED), *SWEEP_FAST, "--end", "0:00:60"], 2, "seconds are below 60"),
    # bounded parameters: one line outside the documented range
    ("omega-u-above-1", lambda t: ["run", str(TESTBED), "--omega-u", "5"], 2, "omega_u (w_u) must be from 0 to 1"),
    ("omega-u-toml-above-1", lambda t: ["run", str(TESTBED), "--config", str(_toml(t / "c", "[planner]\nomega_u = 1.5"))],
     2, "omega_u (w_u) must be from 0 to 1"),
    ("sweep-omega-u-above-1", lambda t: ["sweep", str(TESTBED), *SWEEP_FAST, "--omega-u", "0:2:0.5"], 2,
     "omega_u (w_u) must be from 0 to 1"),
    ("evaluate-omega-u-above-1", lambda t: ["evaluate", str(SCENARIOS / "suite"), "--planner", "x=omega_u=7", "--out",
                                            str(t / "ev")], 2, "omega_u (w_u) must be from 0 to 1"),
    ("evaluate-limit-0", lambda t: ["evaluate", str(SCENARIOS / "suite"), "--planner", "baseline", "--limit", "0",
                                    "--out", str(t / "ev")], 2, "--limit must be a whole number of scenarios, 1 or more"),
    ("evaluate-limit-negative", lambda t: ["evaluate", str(SCENARIOS / "suite"), "--planner", "baseline", "--limit",
                                           "-3", "--out", str(t / "ev")], 2, "--limit must be a whole number"),
    ("sweep-omega-grid-too-large", lambda t: ["sweep", str(TESTBED), *SWEEP_FAST, "--omega-u", "0:1:1e-9"], 2,
     "the limit is 10000"),
    ("sweep-seeds-too-many", lambda t: ["sweep", str(TESTBED), *SWEEP_FAST, "--seeds", "0-100000000"], 2,
     "the limit is 10000"),
    ("sweep-workers-0", lambda t: ["sweep", str(TESTBED), *SWEEP_FAST, "--workers", "0"], 2,
     "--workers must be at least 1"),
    ("sweep-ego-edge-unknown", lambda t: ["sweep", str(TESTBED), *SWEEP_FAST, "--ego-to", "main_1",
                                          "--set", "ego_from=main_0,nowhere"], 2, "unknown edge 'nowhere'"),
    ("sweep-routes-malformed", lambda t: ["sweep", str(_scenario(t / "s", routes="<routes><x")), *SWEEP_FAST], 2,
     "malformed route file"),
    ("sweep-candidates", lambda t: ["sweep", str(TESTBED), *SWEEP_FAST, "--set", "sampling.n_speeds=15,100000"], 2,
     "the limit is 5000"),
    ("sweep-resumed-over-corrupt-run", lambda t: ["sweep", str(TESTBED), "--omega-u", "1", "--seeds", "0",
                                                  "--end", "5", "--controller", "baseline", "--quiet"], 2,
     "is corrupt (summary.json"),
    ("analyze-n-boot-0", lambda t: ["analyze", str(_fake_sweep(t / "sw", "none")), "--n-boot", "0"], 2,
     "--n-boot must be between 1"),
    ("analyze-n-boot-negative", lambda t: ["analyze", str(_fake_sweep(t / "sw", "none")), "--n-boot", "-5"], 2,
     "--n-boot must be between 1"),
    ("analyze-out-is-a-file", lambda t: ["analyze", str(_fake_sweep(t / "sw", "none")), "--out",
                                         str(t / "sw" / "manifest.json")], 2, "exists and is not a folder"),
    ("analyze-truncated-run-steps", lambda t: ["analyze", str(_fake_sweep(t / "sw", "steps"))], 2, "is corrupt"),
    ("analyze-truncated-run-collisions", lambda t: ["analyze", str(_fake_sweep(t / "sw", "collisions"))], 2,
     "is corrupt"),
    ("analyze-truncated-dataset", lambda t: ["analyze", str(_fake_sweep(t / "sw", "dataset"))], 2,
     "is unreadable"),
]


def _cli(args: list[str], capfd) -> subprocess.CompletedProcess:
    """The command line in this process (every case is refused before SUMO starts; a process
    per case would cost a second of imports each)."""
    from sumo_ethics.cli import main

    capfd.readouterr()
    code = main(args)
    out, err = capfd.readouterr()
    return subprocess.CompletedProcess(args, code, out, err)


@pytest.mark.parametrize("build, code, fragment", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_input_gives_one_line_and_keeps_what_was_there(tmp_path, capfd, build, code, fragment):
    args = build(tmp_path)
    out = tmp_path / "out"
    if args[0] == "run":  # an earlier run in --out, replaced only if this one is accepted
        out.mkdir()
        _previous_run(out)
        args += ["--out", str(out), "--overwrite", "--quiet"]
    elif args[0] == "sweep":
        if "corrupt" in fragment:
            _fake_sweep(out, "summary")
        args += ["--out", str(out)]
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    p = _cli(args, capfd)
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert p.returncode == code, p.stderr
    assert len(lines) == 1 and lines[0].startswith("error: "), p.stderr
    assert fragment in lines[0], lines[0]
    assert "Traceback" not in p.stderr + p.stdout
    after = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    assert {k: v for k, v in after.items() if k in before} == before  # nothing changed or deleted
    if args[0] == "run":
        assert set(after) == set(before)  # and nothing left behind
    if args[0] == "sweep" and "corrupt" not in fragment:
        assert not (out / "runs").exists()  # refused before any run started


def test_existing_run_folder_is_refused_without_overwrite(tmp_path, capfd):
    out = tmp_path / "out"
    out.mkdir()
    (out / "summary.json").write_text('{"status": "old"}')
    p = _cli(["run", str(TESTBED), "--end", "3", "--quiet", "--out", str(out)], capfd)
    assert p.returncode == 2 and "already holds a run" in p.stderr and "--overwrite" in p.stderr
    assert json.loads((out / "summary.json").read_text()) == {"status": "old"}


@pytest.mark.sumo
def test_sumo_start_failure_gives_exit_3_with_the_cause(tmp_path):
    """Input that passes the pre-flight checks but SUMO refuses (a bus stop on a lane the net does
    not have): exit 3, SUMO's own reason in the one error line and in summary.json (libsumo says
    only 'Process Error'). In its own process: libsumo cannot start again after such a failure."""
    (tmp_path / "a.add.xml").write_text('<additional><busStop id="b" lane="nowhere_0" startPos="0" endPos="10"/>'
                                        '</additional>')
    cfg = tmp_path / "a.sumocfg"
    cfg.write_text(f'<configuration><input><net-file value="{TESTBED_NET}"/><additional-files value="a.add.xml"/>'
                   '</input><time><end value="20"/></time></configuration>')
    out = tmp_path / "out"
    p = subprocess.run([sys.executable, "-m", "sumo_ethics.cli", "run", str(cfg), "--controller", "baseline", "--quiet",
                        "--out", str(out)], capture_output=True, text=True, timeout=120)
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert p.returncode == 3 and len(lines) == 1 and "Traceback" not in p.stderr, p.stderr
    assert "lane nowhere_0" in lines[0] and "Process Error" not in lines[0]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "error" and "lane nowhere_0" in summary["message"]


@pytest.mark.sumo
def test_overwrite_replaces_the_run_folder_as_a_whole(tmp_path):
    """The earlier run's figures (explain/, a replay beside the outputs) go with its data: nothing of
    the earlier run is left beside the new one."""
    from sumo_ethics.config import RunConfig
    from sumo_ethics.runner import run

    out = tmp_path / "out"
    out.mkdir()
    _previous_run(out)
    (out / ".replaced-1").mkdir()  # left by an overwriting run that was killed
    run(RunConfig(TESTBED, out, end=3.0, controller="baseline", progress=False, overwrite=True))
    assert json.loads((out / "summary.json").read_text())["status"] == "timeout"
    assert sorted(p.name for p in out.iterdir()) == sorted(["collisions.parquet", "conflicts.parquet", "config.json",
                                                            "steps.parquet", "sumo-errors.log", "summary.json",
                                                            "timings.parquet"])


@pytest.mark.parametrize("case", ["foreign file", "foreign folder", "not a run"])
def test_overwrite_never_deletes_what_is_not_a_run(tmp_path, capfd, case):
    """--overwrite replaces a run folder only: a folder with anything no run writes there, or whose
    config.json and summary.json are not a run's, is refused with one line and left as it was."""
    out = tmp_path / "out"
    out.mkdir()
    _previous_run(out)
    if case == "foreign file":
        (out / "notes.txt").write_text("mine\n")
    elif case == "foreign folder":
        (out / "src").mkdir()
        (out / "src" / "main.py").write_text("print()\n")
    else:
        (out / "config.json").write_text('{"some": "other tool"}\n')
        (out / "summary.json").write_text('{"status": "other tool"}\n')
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    p = _cli(["run", str(TESTBED), "--controller", "baseline", "--end", "1", "--quiet", "--out", str(out),
              "--overwrite"], capfd)
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert p.returncode == 2 and len(lines) == 1 and lines[0].startswith("error: --out"), p.stderr
    assert ("not a run folder" if case == "not a run" else "which no run writes") in lines[0]
    if case != "not a run":
        assert ("notes.txt" if case == "foreign file" else "src") in lines[0]
    assert {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == before


