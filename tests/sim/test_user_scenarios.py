"""Scenarios as researchers bring them: begin times, no step length, their own outputs, bridges,
persons with odd vTypes, route files in .gz, vehicles the planner does not model (issue 11).

The networks are built here with netconvert from plain XML: a road passing under a bridge
(node z coordinates 0 and 6 m), and the same crossing without elevation.
"""

from __future__ import annotations

import gzip
import json
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
import sumo

from sumo_ethics.config import RunConfig
from sumo_ethics.errors import ConfigError
from sumo_ethics.runner import run
from sumo_ethics.sim.scenario import redirected_outputs, read_scenario
from sumo_ethics.sumo_options import parse_time

from conftest import Scripted, TESTBED_NET, write_scenario, sumo_binary

BEGIN = 50000.0


def cli(*args: str) -> tuple[subprocess.CompletedProcess, float]:
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "sumo_ethics.cli", *args], capture_output=True, text=True, timeout=300)
    return p, time.perf_counter() - t0


def one_error_line(p: subprocess.CompletedProcess, fragment: str, code: int = 2) -> str:
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert p.returncode == code, p.stderr
    assert len(lines) == 1 and lines[0].startswith("error: "), p.stderr
    assert fragment in lines[0], lines[0]
    assert "Traceback" not in p.stderr + p.stdout
    return lines[0]


# ---- networks built for these tests -----------------------------------------------------------
def build_crossing(folder: Path, bridge_z: float) -> Path:
    """A road W->E (y = 0) and a road S->N (x = 0) crossing at (0, 0) WITHOUT a junction, the
    second at height ``bridge_z`` [m] (0: a flat network, as OSM imports usually are)."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "n.nod.xml").write_text(
        '<nodes><node id="W" x="-100" y="0" z="0"/><node id="E" x="100" y="0" z="0"/>'
        f'<node id="S" x="0" y="-100" z="{bridge_z}"/><node id="N" x="0" y="100" z="{bridge_z}"/></nodes>')
    (folder / "e.edg.xml").write_text(
        '<edges><edge id="road" from="W" to="E" numLanes="1" speed="13.89"/>'
        '<edge id="bridge" from="S" to="N" numLanes="1" speed="13.89"/></edges>')
    net = folder / "x.net.xml"
    subprocess.run([sumo_binary("netconvert"), "-n", "n.nod.xml", "-e", "e.edg.xml",
                    "-o", net.name, "--offset.disable-normalization", "true", "--no-warnings", "true"],
                   cwd=folder, check=True, capture_output=True)
    return net


def crossing_scenario(folder: Path, net: Path, extra_cfg: str = "") -> Path:
    """Ego on ``road`` crossing x = 0 at about t = begin + 6 s at 10 m/s; a car parked on
    ``bridge`` right above the crossing point. Begins at 50000 s, no step length set."""
    (folder / "r.rou.xml").write_text(f"""<routes>
      <vType id="car" vClass="passenger" length="4.5" width="1.8"/>
      <vehicle id="ego" type="car" depart="{BEGIN:g}" departPos="40" departSpeed="10"><route edges="road"/></vehicle>
      <vehicle id="above" type="car" depart="{BEGIN:g}" departPos="101.5" departSpeed="0"><route edges="bridge"/>
        <stop lane="bridge_0" endPos="102" duration="1000"/></vehicle>
    </routes>""")
    cfg = folder / "x.sumocfg"
    cfg.write_text(f'<configuration><input><net-file value="{net}"/><route-files value="r.rou.xml"/></input>'
                   f'<time><begin value="{BEGIN:g}"/><end value="13:53:40"/></time>{extra_cfg}</configuration>')
    return cfg


@pytest.fixture(scope="module")
def bridge_net(tmp_path_factory) -> Path:
    return build_crossing(tmp_path_factory.mktemp("bridge"), 6.0)


@pytest.fixture(scope="module")
def flat_net(tmp_path_factory) -> Path:
    return build_crossing(tmp_path_factory.mktemp("flat"), 0.0)


# ---- times ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("text, seconds", [("50300", 50300.0), ("0.5", 0.5), ("16:0:0", 57600.0),
                                           ("1:02:03:04", 86400 + 2 * 3600 + 3 * 60 + 4.0), ("0:0:2.5", 2.5)])
def test_sumo_time_formats(text, seconds):
    assert parse_time(text, "t") == seconds


@pytest.mark.parametrize("text", ["16:00", "noon", "1:2:3:4:5", ""])
def test_bad_sumo_times(text):
    with pytest.raises(ConfigError, match="is not a SUMO time"):
        parse_time(text, "t")


@pytest.mark.sumo
def test_scenario_times_are_read_in_sumos_formats(tmp_path, bridge_net):
    files = read_scenario(crossing_scenario(tmp_path, bridge_net))
    assert (files.begin, files.end, files.step_length) == (50000.0, 50020.0, None)  # end "13:53:40"


@pytest.mark.sumo
def test_end_before_the_begin_is_refused_at_once(tmp_path, bridge_net):
    cfg = crossing_scenario(tmp_path, bridge_net)
    out = tmp_path / "o"
    p, seconds = cli("run", str(cfg), "--end", "400", "--out", str(out))
    one_error_line(p, "--end 400 s is not after the scenario's begin (50000 s)")
    assert "--end 50400" in p.stderr  # and says what to write instead
    assert seconds < 1.0 and not out.exists()  # no simulation, no heavy imports, nothing written
    p, _ = cli("run", str(cfg), "--ego-depart", "60", "--out", str(out))
    one_error_line(p, "--ego-depart 60 s is before the scenario's begin (50000 s)")
    # the options take SUMO's time formats as the config does: 0:0:1:0 is 60 s, refused the same way
    p, _ = cli("run", str(cfg), "--ego-depart", "0:0:1:0", "--out", str(out))
    one_error_line(p, "--ego-depart 60 s is before the scenario's begin (50000 s)")
    p, _ = cli("run", str(cfg), "--end", "13:53:40x", "--out", str(out))
    one_error_line(p, "Invalid value for '--end': '13:53:40x' is not a SUMO time (seconds, h:m:s or d:h:m:s)")
    assert not out.exists()


@pytest.mark.sumo
def test_begin_50000_without_step_length(tmp_path, bridge_net):
    cfg = crossing_scenario(tmp_path, bridge_net)
    out = tmp_path / "run"
    s = run(RunConfig(cfg, out, ego_id="ego", end=BEGIN + 3, progress=False), controller=Scripted(10.0))
    assert s.status.value == "timeout"
    steps = pd.read_parquet(out / "steps.parquet")
    # the ego was driven from the begin at 50000 s, in 0.1 s steps (not SUMO's default 1 s)
    assert steps.time.iloc[0] < BEGIN + 0.5 and steps.time.iloc[-1] == pytest.approx(BEGIN + 3)
    assert steps.time.diff().dropna().round(6).eq(0.1).all() and len(steps) > 25
    d = s.data
    assert d["step_length"] == 0.1 and d["scenario_step_length"] is None
    assert "the scenario sets none" in d["step_length_source"] and d["begin"] == BEGIN
    # the ego keeps the commanded 10 m/s once taken over (the first row is SUMO's own step)
    assert steps.accel.iloc[1:].abs().max() < 1e-6


@pytest.mark.sumo
def test_step_length_override_and_long_scenario_step(tmp_path, bridge_net):
    cfg = crossing_scenario(tmp_path, bridge_net, '<time><step-length value="1"/></time>')
    s = run(RunConfig(cfg, tmp_path / "a", ego_id="ego", end=BEGIN + 1, progress=False), controller=Scripted(10.0))
    assert s.data["step_length"] == 0.1 and "1 s is above 0.2 s" in s.data["step_length_source"]
    s = run(RunConfig(cfg, tmp_path / "b", ego_id="ego", end=BEGIN + 1, step_length=0.05, progress=False),
            controller=Scripted(10.0))
    assert s.data["step_length"] == 0.05 and s.data["step_length_source"] == "--step-length"
    assert pd.read_parquet(tmp_path / "b" / "steps.parquet").time.diff().dropna().round(6).eq(0.05).all()


# ---- bridges ----------------------------------------------------------------------------------------
@pytest.mark.sumo
def test_no_collision_with_a_car_on_a_bridge_above(tmp_path, bridge_net):
    out = tmp_path / "run"
    s = run(RunConfig(crossing_scenario(tmp_path, bridge_net), out, ego_id="ego", end=BEGIN + 8, progress=False),
            controller=Scripted(10.0))
    steps = pd.read_parquet(out / "steps.parquet")
    assert steps.x.min() < -10 and steps.x.max() > 10  # the ego drove right under the parked car
    assert s.status.value == "timeout" and s.data["collisions"]["ego"] == 0
    assert (steps.n_neighbours == 0).all()  # 6 m above: not in the scene, so not in the planner's either


@pytest.mark.sumo
def test_no_collision_where_roads_cross_without_a_junction(tmp_path, flat_net):
    """A flat network (no elevation): the roads cross without a junction, i.e. on two levels."""
    out = tmp_path / "run"
    s = run(RunConfig(crossing_scenario(tmp_path, flat_net), out, ego_id="ego", end=BEGIN + 8, progress=False),
            controller=Scripted(10.0))
    steps = pd.read_parquet(out / "steps.parquet")
    # the ego (y = -1.6) drove through x = 0.7 ... 2.5 where the parked car covers y = -2.5 ... 2.0:
    # their boxes overlapped in plan view, but the car is on a road crossing without a junction
    assert steps.x.min() < -10 and steps.x.max() > 10 and steps.y.round(3).eq(-1.6).all()
    assert (steps.n_neighbours == 0).all()  # not in the planner's scene either
    assert s.status.value == "timeout" and s.data["collisions"]["ego"] == 0
    assert not (out / "collisions.parquet").exists() or pd.read_parquet(out / "collisions.parquet").empty


# ---- the scenario's own outputs ---------------------------------------------------------------------
@pytest.mark.sumo
def test_output_options_are_pointed_into_the_run_folder(tmp_path, bridge_net):
    cfg = crossing_scenario(tmp_path, bridge_net, '<output><tripinfo-output value="tripinfos.xml"/>'
                            '<summary-output value="sub/summary.xml"/><fcd-output value="/abs/fcd.xml"/></output>'
                            '<report><log value="sim.log"/><error-log value="e.log"/></report>')
    got = redirected_outputs(read_scenario(cfg), tmp_path / "run" / "sumo-outputs")
    o = tmp_path / "run" / "sumo-outputs"
    assert got == {"tripinfo-output": str(o / "tripinfos.xml"), "summary-output": str(o / "sub" / "summary.xml"),
                   "fcd-output": str(o / "fcd.xml"), "log": str(o / "sim.log")}  # error-log: the run's own


@pytest.mark.sumo
def test_tripinfo_and_log_written_into_the_run_folder(tmp_path, bridge_net):
    scen = tmp_path / "scenario"
    scen.mkdir()
    cfg = crossing_scenario(scen, bridge_net, '<output><tripinfo-output value="tripinfos.xml"/></output>'
                            '<report><log value="sim.log"/></report>')
    out = tmp_path / "run"
    run(RunConfig(cfg, out, ego_id="ego", end=BEGIN + 1, progress=False), controller=Scripted(10.0))
    assert sorted(p.name for p in scen.iterdir()) == ["r.rou.xml", "x.sumocfg"]  # nothing next to the scenario
    assert "<tripinfos" in (out / "sumo-outputs" / "tripinfos.xml").read_text()
    assert (out / "sumo-outputs" / "sim.log").is_file()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["scenario_outputs"] == {"tripinfo-output": "tripinfos.xml", "log": "sim.log"}


# ---- persons ---------------------------------------------------------------------------------------
@pytest.mark.sumo
def test_person_with_a_vtype_without_vclass_is_a_pedestrian(scenario_dir, tmp_path):
    # SUMO gives the vType vClass passenger (and warns); the walker walks along the road lane
    cfg = write_scenario(scenario_dir, """
      <vType id="walkertype" length="0.3" width="0.5" maxSpeed="1.5"/>
      <vehicle id="ego" type="car" route="r_main" depart="0" departLane="1" departPos="20" departSpeed="10"/>
      <person id="walker" type="walkertype" depart="0" departPos="100"><walk edges="main_0 main_1"/></person>""")
    out = tmp_path / "run"
    s = run(RunConfig(cfg, out, ego_id="ego", end=20, progress=False), controller=Scripted(10.0, offset=lambda t: -1.0))
    r = pd.read_parquet(out / "collisions.parquet").iloc[0]
    assert s.status.value == "collision" and (r.id_b, r.class_b, r.type_b) == ("walker", "pedestrian", "walkertype")
    assert r.mass_b == 75.0 and r.harm_vru == r.harm_b > 0.2  # booked as VRU harm, not as a car's


# ---- checks that need no simulation -----------------------------------------------------------------
def gz_scenario(folder: Path) -> Path:
    """Testbed network; routes in a .gz file: a car, a flow, a bicycle, a bus with a stop, a person."""
    folder.mkdir(parents=True, exist_ok=True)
    routes = """<routes>
      <vType id="car" vClass="passenger"/><vType id="bike" vClass="bicycle"/>
      <vType id="ped" length="0.3" width="0.5"/>
      <route id="r" edges="main_0 main_1"/>
      <vehicle id="car1" type="car" route="r" depart="0"/>
      <flow id="stream" type="car" route="r" begin="0" end="10" period="2"/>
      <vehicle id="cyclist" type="bike" route="r" depart="0"/>
      <vehicle id="bus1" route="r" depart="0"><stop lane="main_1_1" endPos="50" duration="10"/></vehicle>
      <person id="walker" type="ped" depart="0"><walk edges="main_0 main_1"/></person>
    </routes>"""
    with gzip.open(folder / "r.rou.xml.gz", "wt") as fh:
        fh.write(routes)
    cfg = folder / "g.sumocfg"
    cfg.write_text(f'<configuration><input><net-file value="{TESTBED_NET}"/><route-files value="r.rou.xml.gz"/>'
                   f'</input><time><end value="60"/></time></configuration>')
    return cfg


@pytest.mark.parametrize("ego, fragment", [
    ("car2", "unknown --ego 'car2'"),
    ("stream", "--ego 'stream' is a flow; its vehicles are named 'stream.0', 'stream.1'"),
    ("stream.x", "unknown --ego 'stream.x'"),
    ("cyclist", "--ego 'cyclist' is a bicycle (vClass); the planner models motor road vehicles only"),
    ("bus1", "--ego 'bus1' has stops"),
    ("walker", "--ego 'walker' is a person"),
])
def test_ego_checked_in_gz_route_files_without_simulating(tmp_path, ego, fragment):
    out = tmp_path / "o"
    p, seconds = cli("run", str(gz_scenario(tmp_path / "s")), "--ego", ego, "--out", str(out))
    one_error_line(p, fragment)
    assert seconds < 1.0 and not out.exists()


@pytest.mark.parametrize("args, fragment", [
    (["--sumo-arg", "--step-length 0.5"], "--sumo-arg --step-length: the run sets this SUMO option itself (use --step-length)"),
    (["--sumo-arg", "--end=9"], "the run sets this SUMO option itself (use --end)"),
    (["--sumo-arg", "--x 'open"], "--sumo-arg"),
    (["--step-length", "0"], "--step-length must be a finite positive number"),
])
def test_bad_sumo_args(tmp_path, args, fragment):
    p, seconds = cli("run", str(gz_scenario(tmp_path / "s")), "--out", str(tmp_path / "o"), *args)
    one_error_line(p, fragment)
    assert seconds < 1.0


@pytest.mark.sumo
def test_taxi_ego_refused_when_it_departs(tmp_path):
    cfg = write_scenario(tmp_path / "s", """<vehicle id="taxi1" type="car" route="r_main" depart="1">
        <param key="has.taxi.device" value="true"/></vehicle>""", end=10)
    out = tmp_path / "o"
    with pytest.raises(ConfigError, match="--ego 'taxi1' is a taxi"):
        run(RunConfig(cfg, out, ego_id="taxi1", progress=False), controller=Scripted(5.0))
    assert not out.exists()


@pytest.mark.sumo
def test_flow_vehicle_taken_over(tmp_path):
    cfg = gz_scenario(tmp_path / "s")
    s = run(RunConfig(cfg, tmp_path / "o", ego_id="stream.1", end=4, progress=False), controller=Scripted(5.0))
    assert s.data["ego_id"] == "stream.1" and s.data["takeover_time"] == pytest.approx(2.0, abs=0.15)


# ---- SUMO itself ------------------------------------------------------------------------------------
@pytest.mark.sumo
def test_sumo_start_failure_reason_in_summary(tmp_path):
    cfg = write_scenario(tmp_path / "s", "", end=10)
    cfg.write_text(cfg.read_text().replace("</configuration>", '<gui_only><osg-view value="true"/></gui_only>'
                                                                "</configuration>"))
    out = tmp_path / "o"
    p, _ = cli("run", str(cfg), "--out", str(out), "--controller", "baseline")
    line = one_error_line(p, "SUMO could not start t.sumocfg", code=3)
    assert "No option with the name 'osg-view' exists" in line
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "error" and "No option with the name 'osg-view' exists" in summary["message"]


@pytest.mark.sumo
def test_an_unknown_sumo_arg_is_named_with_sumos_reason(tmp_path):
    """SUMO gives its reason on an indented second line; the error line had only the first
    ("On processing option '--nosuchopt':")."""
    cfg = write_scenario(tmp_path / "s", "", end=10)
    p, _ = cli("run", str(cfg), "--out", str(tmp_path / "o"), "--sumo-arg", "--nosuchopt 1")
    line = one_error_line(p, "SUMO could not start t.sumocfg", code=3)
    assert line.endswith("On processing option '--nosuchopt': No option with the name 'nosuchopt' exists."), line


@pytest.mark.sumo
def test_sumo_arg_reaches_sumo(tmp_path):
    cfg = write_scenario(tmp_path / "s", '<vehicle id="ego" type="car" route="r_main" depart="0"/>', end=10)
    out = tmp_path / "o"
    stats = tmp_path / "stats.xml"
    s = run(RunConfig(cfg, out, ego_id="ego", end=2, sumo_args=("--statistic-output", str(stats)), progress=False),
            controller=Scripted(5.0))
    assert "<statistics" in stats.read_text() and s.data["sumo_args"] == ["--statistic-output", str(stats)]


# ---- suite generate never overwrites ---------------------------------------------------------------
def test_suite_generate_needs_a_new_or_empty_out(tmp_path):
    p, _ = cli("suite", "generate", "--count", "1")
    one_error_line(p, "Missing option '--out'")
    suite = tmp_path / "suite"
    (suite / "old_scenario").mkdir(parents=True)
    (suite / "old_scenario" / "x.sumocfg").write_text("<configuration/>")
    p, seconds = cli("suite", "generate", "--count", "1", "--out", str(suite))
    one_error_line(p, f"--out {suite} is not an empty folder")
    assert [q.name for q in suite.iterdir()] == ["old_scenario"] and seconds < 1.0  # untouched


@pytest.mark.sumo
def test_sweep_refuses_an_end_before_the_begin(tmp_path, bridge_net):
    from sumo_ethics.sweep import make_sweep

    cfg = crossing_scenario(tmp_path, bridge_net)
    with pytest.raises(ConfigError, match=r"--end 400 s is not after the scenario's begin \(50000 s\)"):
        make_sweep(cfg, "0,1000", "0-1", options={"end": 400.0}).validate()
    sw = make_sweep(cfg, "0", "0", options={"end": BEGIN + 5, "step_length": 0.05})
    assert sw.validate()[0].run_config(tmp_path / "r").step_length == 0.05


@pytest.mark.sumo
def test_inserted_ego_does_not_share_its_id_with_a_person(tmp_path):
    """eclipse-sumo's tools/game/hiking names its person 'ego': the merged context subscription
    then returned the person's position for the car (an 82 m jump in one step)."""
    cfg = write_scenario(tmp_path / "s", '<person id="ego" depart="0" departPos="20"><walk edges="main_0"/></person>',
                         end=10)
    out = tmp_path / "o"
    s = run(RunConfig(cfg, out, ego_from="main_0", ego_to="main_1", end=5, controller="baseline", progress=False))
    steps = pd.read_parquet(out / "steps.parquet")
    assert s.data["ego_id"] == "sumo_ethics_ego" and s.status.value == "timeout"
    step_m = (steps.x.diff() ** 2 + steps.y.diff() ** 2) ** 0.5
    assert step_m.max() < 14 * 0.1 + 0.05  # at most one step at the speed limit


# ---- acceleration at the control step ----------------------------------------------------------------
@pytest.mark.parametrize("dt, limit", [(0.1, 3.0 + 0.05), (0.2, 3.0 + 0.1)])
def test_speed_change_per_step_within_the_limit_when_pulling_away_offset(dt, limit):
    """Every feasible candidate, from standstill or slow starts with a lateral offset and rate:
    the speed change over each control step (what SUMO is told) stays at the 3 m/s^2 limit (the
    lateral component adds at most a few %). At SUMO's default 1 s step the same grid asked for
    13.9 m/s^2, which is why such scenarios now run at 0.1 s."""
    from dataclasses import replace
    from types import SimpleNamespace

    import numpy as np

    from sumo_ethics.config import EgoVehicle
    from sumo_ethics.geometry import Polyline
    from sumo_ethics.plan.ethical import PlannerConfig
    from sumo_ethics.plan.feasibility import check
    from sumo_ethics.plan.sampling import FrenetState, sample

    path = Polyline.from_points(np.c_[np.linspace(0, 300, 301), np.zeros(301)])
    route = SimpleNamespace(path=path, left=np.full(301, 3.0), right=np.full(301, -3.0),
                            speed_limit=np.full(301, 13.9))
    grid = replace(PlannerConfig().sampling, dt=dt)
    worst = 0.0
    for v0 in (0.0, 0.5, 2.0, 2.9, 5.0):
        for d0, d_dot in ((0.0, 0.0), (-1.0, 0.0), (-1.6, 0.5), (-1.6, -0.5)):
            c = sample(path, FrenetState(s=10, d=d0, s_dot=v0, s_ddot=0.0, d_dot=d_dot, d_ddot=0.0), grid,
                       v_max=13.9, left=3.0, right=-3.0, margin=0.8)
            ok = check(c, route, EgoVehicle()).feasible
            speed = np.c_[np.full(len(c.speed), np.hypot(v0, d_dot)), c.speed]
            if ok.any():
                worst = max(worst, float((np.diff(speed, axis=1)[ok] / dt).max()))
    assert 2.9 < worst <= limit


@pytest.mark.sumo
def test_no_phantom_collision_on_the_a10_motorway_bridge(tmp_path):
    """eclipse-sumo's tools/game/A10KW (OpenStreetMap, no elevation): veh25's primary road crosses
    the A10 motorway without a junction. The ego used to 'collide' there with a motorway car
    (geometry only, harm 0.78 booked, the run ended at t = 59.5 s)."""
    cfg = Path(sumo.SUMO_HOME) / "tools" / "game" / "A10KW.sumocfg"
    out = tmp_path / "o"
    s = run(RunConfig(cfg, out, seed=1, ego_id="veh25", end=65, controller="baseline", progress=False))
    steps = pd.read_parquet(out / "steps.parquet")
    assert s.status.value == "timeout" and s.data["collisions"]["ego"] == 0
    assert steps.time.max() == pytest.approx(65.0) and steps.speed.iloc[5:].min() > 15  # drove on, no braking


@pytest.mark.sumo
def test_detector_outputs_of_additional_files_go_into_the_run_folder(tmp_path, bridge_net, monkeypatch):
    scen = tmp_path / "scenario"
    scen.mkdir()
    (scen / "det.add.xml").write_text('<additional><edgeData id="dump" file="edges.xml" period="1"/>'
                                      '<timedEvent type="SaveTLSSwitchStates" dest="tls.xml"/></additional>')
    (scen / "vss.add.xml").write_text('<additional><variableSpeedSign id="v" lanes="road_0" file="vss.def.xml"/>'
                                      '<edgeData id="d2" file="kept.xml"/></additional>')
    cfg = crossing_scenario(scen, bridge_net)
    cfg.write_text(cfg.read_text().replace('<route-files value="r.rou.xml"/>',
                                           '<route-files value="r.rou.xml"/><additional-files value="det.add.xml"/>'))
    out = tmp_path / "run"
    s = run(RunConfig(cfg, out, ego_id="ego", end=BEGIN + 2, progress=False), controller=Scripted(10.0))
    assert sorted(p.name for p in scen.iterdir()) == ["det.add.xml", "r.rou.xml", "vss.add.xml", "x.sumocfg"]
    assert "<edge id=\"road\"" in (out / "sumo-outputs" / "edges.xml").read_text()
    copy = (out / "sumo-outputs" / "additional-files" / "0_det.add.xml").read_text()  # what SUMO loaded
    assert f'dest="{out / "sumo-outputs" / "tls.xml"}"' in copy
    assert s.data["outputs_not_redirected"] == {}
    # a run folder given relative to the working directory (SUMO reads a relative output path in
    # an additional file relative to that file, so the copy must name it absolutely)
    monkeypatch.chdir(tmp_path)
    run(RunConfig(cfg, Path("rel") / "run", ego_id="ego", end=BEGIN + 2, progress=False), controller=Scripted(10.0))
    assert "<edge id=\"road\"" in (tmp_path / "rel" / "run" / "sumo-outputs" / "edges.xml").read_text()
    # a file that also names an input by a relative path is not rewritten: its outputs are listed
    from sumo_ethics.sim.scenario import read_scenario, redirected_additionals

    cfg.write_text(cfg.read_text().replace('value="det.add.xml"', 'value="det.add.xml,vss.add.xml"'))
    value, left = redirected_additionals(read_scenario(cfg), tmp_path / "elsewhere")
    assert value.endswith(str(scen / "vss.add.xml")) and left == {str(scen / "vss.add.xml"): ["kept.xml"]}


@pytest.mark.sumo
def test_truck_ego_gets_its_own_size_and_limits(tmp_path):
    cfg = write_scenario(tmp_path / "s", """<vType id="lorry" vClass="truck" length="12" width="2.5" accel="1.1"
        decel="4" emergencyDecel="7" maxSpeed="25"/>
        <vehicle id="t1" type="lorry" route="r_main" depart="0" departPos="20"/>""", end=10)
    s = run(RunConfig(cfg, tmp_path / "o", ego_id="t1", end=3, controller="baseline", progress=False))
    lim = s.data["ego_limits"]
    assert (lim["length"], lim["width"], lim["max_accel"], lim["comfort_decel"], lim["max_decel"]) == (12, 2.5, 1.1, 3.0, 7)
    assert lim["max_speed"] == 25 and lim["max_lat_accel"] == 4.0  # the car's where the vType says nothing
    assert lim["mass"] == 25000.0  # the mass the planner's harm uses: METHOD.md's truck (no mass in the vType)


@pytest.mark.sumo
def test_a_long_vtype_of_the_default_class_is_driven_with_its_own_size(tmp_path):
    """eclipse-sumo's tools/game/ramp.sumocfg has a 12 m 'truck' vType without a vClass (so a
    passenger car to SUMO): taken over, it was planned and checked for collisions as a 4.508 x
    1.610 m car while SUMO simulated 12 m. Now its own size, with a car's limits."""
    cfg = write_scenario(tmp_path / "s", """<vType id="truck" length="12" width="2.4" maxSpeed="25"/>
        <vehicle id="t1" type="truck" route="r_main" depart="0" departPos="20"/>""", end=10)
    s = run(RunConfig(cfg, tmp_path / "o", ego_id="t1", end=3, controller="baseline", progress=False))
    lim = s.data["ego_limits"]
    assert (lim["length"], lim["width"]) == (12, 2.4)
    assert (lim["max_speed"], lim["max_accel"]) == (36.0, 3.0)  # a car's limits
    # and the mass the planner's harm uses: SUMO's 1500 kg default means "unknown", so the car formula
    # of its footprint, -1333.5 + 526.9 (12 x 2.4)^0.8 = 6412 kg (the inserted ego's 1475 kg before)
    assert lim["mass"] == pytest.approx(-1333.5 + 526.9 * (12 * 2.4) ** 0.8) and 6400 < lim["mass"] < 6420
