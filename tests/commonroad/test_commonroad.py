"""CommonRoad scenarios: import (net, ego, goal, obstacles), replay exactness, the goal check,
refusals. The bundled scenarios and their sources: tests/data/commonroad/README.md.

Tests that import need the optional packages (``pip install -e '.[commonroad]'``) and are skipped
without them; the goal check by hand and the refusal without the packages run everywhere.
"""

from __future__ import annotations

import gzip
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from shapely.geometry import Polygon

from sumo_ethics.cli import main
from sumo_ethics.goal import Goal, GoalState

DATA = Path(__file__).resolve().parents[1] / "data" / "commonroad"
ZAM = DATA / "ZAM_Tutorial-1_1_T-1.xml.gz"
BEL = DATA / "BEL_Putte-1_1_T-1.xml.gz"


def _have_commonroad() -> bool:
    try:
        import commonroad  # noqa: F401
        import commonroad_sumo  # noqa: F401
    except ImportError:
        return False
    return True


# commonroad-io's generated protobuf modules warn on import (protobuf 3.20)
pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")

needs_cr = pytest.mark.skipif(not _have_commonroad(), reason="commonroad-io/commonroad-sumo not installed "
                                                             "(pip install -e '.[commonroad]')")


# ---- the goal check by hand (no commonroad packages needed) ------------------------------------
def test_goal_by_hand() -> None:
    # a 10 m x 4 m box from x=100, steps 35-40, 10-20 m/s, heading within +-0.5 rad of pi (crossing +-pi)
    box = Polygon([(100, -2), (110, -2), (110, 2), (100, 2)])
    g = Goal((GoalState(time_step=(35, 40), velocity=(10.0, 20.0), orientation=(math.pi - 0.5, math.pi + 0.5),
                        polygons=(box,)),))
    assert g.is_reached(35, 105.0, 0.0, math.pi, 15.0)
    assert g.is_reached(40, 110.0, 2.0, -math.pi + 0.4, 10.0)  # on the boundary; the heading wraps
    assert not g.is_reached(34, 105.0, 0.0, math.pi, 15.0)  # too early
    assert not g.is_reached(41, 105.0, 0.0, math.pi, 15.0)  # too late
    assert not g.is_reached(36, 99.9, 0.0, math.pi, 15.0)  # outside the box
    assert not g.is_reached(36, 105.0, 0.0, 0.0, 15.0)  # facing the other way
    assert not g.is_reached(36, 105.0, 0.0, math.pi - 0.6, 15.0)
    assert not g.is_reached(36, 105.0, 0.0, math.pi, 20.5)  # too fast
    # several goal states: any of them; a circle; a state giving only a time window
    g2 = Goal((GoalState(time_step=(0, 10), circles=((0.0, 0.0, 2.0),)), GoalState(time_step=(50, 60))))
    assert g2.is_reached(5, 1.2, 1.6, 0.0, 0.0)  # |(1.2, 1.6)| = 2.0: on the circle
    assert not g2.is_reached(5, 1.3, 1.6, 0.0, 0.0)
    assert g2.is_reached(55, 1e4, 1e4, 1.0, 99.0)
    assert g2.last_step == 60
    # a run completes in the circle at once, but on the time-only goal state only at its window's end
    assert g2.completes(5, 1.2, 1.6, 0.0, 0.0)
    assert not g2.completes(55, 1e4, 1e4, 1.0, 99.0) and g2.completes(60, 1e4, 1e4, 1.0, 99.0)
    assert g.completes(35, 105.0, 0.0, math.pi, 15.0)
    # the paper's evaluation (rule "origin"): reached after the window completes too, late; before it does
    # not; a time-only goal state counts as soon as its window opens
    assert not g.completes(41, 105.0, 0.0, math.pi, 15.0)
    assert g.completes(41, 105.0, 0.0, math.pi, 15.0, rule="origin") and g.late(41) and not g.late(40)
    assert g.completes(900, 105.0, 0.0, math.pi, 15.0, rule="origin")
    assert not g.completes(34, 105.0, 0.0, math.pi, 15.0, rule="origin")
    assert not g.completes(41, 99.9, 0.0, math.pi, 15.0, rule="origin")  # late, but outside the box
    assert g2.completes(50, 1e4, 1e4, 1.0, 99.0, rule="origin") and not g2.completes(49, 1e4, 1e4, 1.0, 99.0, rule="origin")
    assert not g2.late(60) and g2.late(61)
    # the serialised form round-trips
    assert Goal.from_list(json.loads(json.dumps(g.to_list()))).is_reached(35, 105.0, 0.0, math.pi, 15.0)


@needs_cr
@pytest.mark.parametrize("path", [ZAM, BEL], ids=["ZAM", "BEL"])
def test_goal_equals_commonroad_io(path: Path) -> None:
    """Our check against commonroad-io's GoalRegion.is_reached on 3000 states around the goal."""
    from commonroad.scenario.state import CustomState

    from sumo_ethics.commonroad.importer import goal_of, read

    _, problems = read(path)
    problem = next(iter(problems.planning_problem_dict.values()))
    goal = goal_of(problem)
    region = goal.region()
    rng = np.random.default_rng(7)
    if region is not None:
        x0, y0, x1, y1 = region.bounds
    else:
        x0 = y0 = -50.0
        x1 = y1 = 50.0
    steps = [s.time_step for s in goal.states if s.time_step]
    k0, k1 = min(s[0] for s in steps), max(s[1] for s in steps)
    hits = 0
    for _ in range(3000):
        st = CustomState(position=np.array([rng.uniform(x0 - 5, x1 + 5), rng.uniform(y0 - 5, y1 + 5)]),
                         orientation=float(rng.uniform(-math.pi, math.pi)), velocity=float(rng.uniform(0, 40)),
                         time_step=int(rng.integers(k0 - 3, k1 + 4)))
        ours = goal.is_reached(st.time_step, *st.position, st.orientation, st.velocity)
        assert ours == bool(problem.goal.is_reached(st)), st
        hits += ours
    assert hits > 30  # the sample reaches the goal often enough to compare both answers


# ---- refusals -----------------------------------------------------------------------------------
def test_refused_without_packages(tmp_path: Path) -> None:
    code = ("import sys; sys.modules['commonroad'] = None; sys.modules['commonroad_sumo'] = None\n"
            "from sumo_ethics.cli import main\n"
            f"sys.exit(main(['import-commonroad', {str(ZAM)!r}, '--out', {str(tmp_path / 'x')!r}]))")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert p.returncode == 2, p.stderr
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and "pip install 'sumo-ethics[commonroad]'" in lines[0], p.stderr
    assert not (tmp_path / "x").exists()


def _no_problem(tmp_path: Path) -> Path:
    text = gzip.open(ZAM, "rt").read()
    start, end = text.index("<planningProblem"), text.rindex("</planningProblem>") + len("</planningProblem>")
    p = tmp_path / "noproblem.xml"
    p.write_text(text[:start] + text[end:])
    return p


@needs_cr
@pytest.mark.parametrize("kind", ["garbage", "not_commonroad", "truncated_xml", "truncated_gz", "no_problem",
                                  "missing", "out_not_empty"])
def test_malformed_refused(kind: str, tmp_path: Path, capsys) -> None:
    src = tmp_path / "in.xml"
    out = tmp_path / "out"
    if kind == "garbage":
        src.write_bytes(b"\x00\x01 not xml at all")
    elif kind == "not_commonroad":
        src.write_text('<?xml version="1.0"?><routes><vehicle id="a"/></routes>')
    elif kind == "truncated_xml":
        src.write_text(gzip.open(ZAM, "rt").read()[:3000])
    elif kind == "truncated_gz":
        src = tmp_path / "in.xml.gz"
        src.write_bytes(ZAM.read_bytes()[:3000])
    elif kind == "no_problem":
        src = _no_problem(tmp_path)
    elif kind == "missing":
        src = tmp_path / "nothing.xml"
    elif kind == "out_not_empty":
        src = ZAM
        out.mkdir()
        (out / "mine.txt").write_text("keep me")
    capsys.readouterr()
    assert main(["import-commonroad", str(src), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: "), err
    if kind == "out_not_empty":
        assert (out / "mine.txt").read_text() == "keep me" and sorted(p.name for p in out.iterdir()) == ["mine.txt"]
    else:
        assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary folder left


# ---- import ---------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def imported(tmp_path_factory) -> dict[tuple[str, str], Path]:
    if not _have_commonroad():
        pytest.skip("commonroad-io/commonroad-sumo not installed (pip install -e '.[commonroad]')")
    from sumo_ethics.commonroad.importer import import_commonroad

    base = tmp_path_factory.mktemp("cr")
    out = {}
    for name, path in (("ZAM", ZAM), ("BEL", BEL)):
        for mode in ("replay", "reactive"):
            out[name, mode] = import_commonroad(path, base / f"{name}-{mode}", mode).sumocfg
    return out


@needs_cr
@pytest.mark.parametrize("name,path", [("ZAM", ZAM), ("BEL", BEL)])
def test_net_coordinates_equal_commonroad(name: str, path: Path, imported) -> None:
    """Every lanelet that became a lane: its centre line lies on the SUMO lane's shape within 2 cm."""
    import sumolib
    from shapely.geometry import LineString, Point

    from sumo_ethics.commonroad.importer import read

    cfg = imported[name, "replay"]
    meta = json.loads((cfg.parent / "commonroad.json").read_text())
    scenario, _ = read(path)
    net = sumolib.net.readNet(str(next(cfg.parent.glob("*.net.xml"))), withInternal=True)
    assert len(meta["lanelet_lanes"]) + len(meta["lanelets_in_junctions"]) == len(scenario.lanelet_network.lanelets)
    assert len(meta["lanelet_lanes"]) >= 3
    for lid, lane_id in meta["lanelet_lanes"].items():
        centre = scenario.lanelet_network.find_lanelet_by_id(int(lid)).center_vertices
        shape = LineString([p[:2] for p in net.getLane(lane_id).getShape()])
        n = len(centre)
        inner = centre[n // 4: n - n // 4] if n >= 4 else centre[[n // 2]]  # ends are cut to the junctions
        worst = max(shape.distance(Point(p)) for p in inner)
        assert worst < 0.02, (lid, lane_id, worst)


@needs_cr
def test_import_writes_the_planning_problem(imported) -> None:
    from sumo_ethics.commonroad.importer import read

    cfg = imported["BEL", "replay"]
    meta = json.loads((cfg.parent / "commonroad.json").read_text())
    _, problems = read(BEL)
    init = next(iter(problems.planning_problem_dict.values())).initial_state
    assert (meta["ego"]["x"], meta["ego"]["y"]) == (float(init.position[0]), float(init.position[1]))
    assert (meta["ego"]["yaw"], meta["ego"]["speed"]) == (float(init.orientation), float(init.velocity))
    # the route leads through the goal's lanes
    assert set(meta["goal_edges"]) & set(meta["ego"]["route"]) or not meta["goal_edges"]
    obs = pd.read_parquet(cfg.parent / "obstacles.parquet")
    assert obs.sumo_id.nunique() == meta["obstacles"]["count"] == 10
    assert sorted(meta["obstacles"]["replayed"]) == sorted(obs.sumo_id.unique())
    react = json.loads((imported["BEL", "reactive"].parent / "commonroad.json").read_text())
    assert react["obstacles"]["driven_by_sumo"] and react["obstacles"]["replayed"]  # on lanes / on the junction


@needs_cr
def test_same_input_same_bytes(imported, tmp_path: Path) -> None:
    from sumo_ethics.commonroad.importer import import_commonroad

    again = import_commonroad(BEL, tmp_path / "again", "reactive").folder
    first = imported["BEL", "reactive"].parent
    names = sorted(p.name for p in first.iterdir())
    assert names == sorted(p.name for p in again.iterdir())
    for n in names:
        assert (first / n).read_bytes() == (again / n).read_bytes(), n


# ---- runs -----------------------------------------------------------------------------------------
class _Probe:
    """Reads every CommonRoad road user and the ego straight from libsumo at every step."""

    def __init__(self) -> None:
        self.rows: list[tuple[float, str, float, float]] = []
        self.ego: list[tuple[float, float, float, float, float]] = []

    def __call__(self, snap, world) -> None:
        import libsumo

        from sumo_ethics.sim.frames import front_to_centre

        for vid in libsumo.vehicle.getIDList():
            if vid.startswith("cr_"):
                fx, fy = libsumo.vehicle.getPosition(vid)
                x, y, _ = front_to_centre(np.array(fx), np.array(fy), np.array(libsumo.vehicle.getAngle(vid)),
                                          np.array(libsumo.vehicle.getLength(vid)))
                self.rows.append((round(snap.time, 6), vid, float(x), float(y)))
        e = snap.ego
        self.ego.append((snap.time, float(e.x[0]), float(e.y[0]), float(e.yaw[0]), float(e.speed[0])))


def _run(cfg: Path, out: Path, controller: str = "baseline", probe: _Probe | None = None):
    from sumo_ethics.config import RunConfig
    from sumo_ethics.runner import run

    return run(RunConfig(scenario=cfg, out=out, controller=controller, progress=False),
               hooks=(probe,) if probe is not None else ())


@needs_cr
@pytest.mark.sumo
@pytest.mark.parametrize("name", ["ZAM", "BEL"])
def test_replay_follows_the_record(name: str, imported, tmp_path: Path) -> None:
    cfg = imported[name, "replay"]
    meta = json.loads((cfg.parent / "commonroad.json").read_text())
    rec = pd.read_parquet(cfg.parent / "obstacles.parquet")
    probe = _Probe()
    summary = _run(cfg, tmp_path / "run", probe=probe)
    cr = summary.data["commonroad"]
    t0, dt, k0 = cr["time_offset"], meta["dt"], meta["first_step"]
    # the ego starts at the planning problem's initial state
    t, x, y, yaw, v = probe.ego[0]
    assert abs(t - t0) < 1e-9
    e = meta["ego"]
    assert math.hypot(x - e["x"], y - e["y"]) < 0.01 and abs(yaw - e["yaw"]) < 1e-3 and abs(v - e["speed"]) < 1e-6
    # every recorded obstacle, at every step of the run: there exactly when recorded, where recorded
    seen = pd.DataFrame(probe.rows, columns=["time", "sumo_id", "x", "y"])
    seen["step"] = np.round((seen.time - t0) / dt).astype(int) + k0
    last = int(round((probe.ego[-1][0] - t0) / dt)) + k0
    want = rec[(rec.step >= k0) & (rec.step <= last)]
    both = want.merge(seen, on=["sumo_id", "step"], how="outer", suffixes=("_rec", "_sumo"), indicator=True)
    assert (both["_merge"] == "both").all(), both[both["_merge"] != "both"].head()
    err = np.hypot(both.x_rec - both.x_sumo, both.y_rec - both.y_sumo)
    assert err.max() < 0.01, both.loc[err.idxmax()]
    assert len(both) == cr["replay"]["checked"] and cr["replay"]["missing"] == 0
    assert cr["replay"]["max_error_m"] < 0.01
    assert seen.sumo_id.nunique() == meta["obstacles"]["count"]


@needs_cr
@pytest.mark.sumo
def test_goal_ends_the_run(imported, tmp_path: Path) -> None:
    """ZAM_Tutorial: the goal is lanelet 1 between time steps 35 and 40; the run ends at the first step the
    ego's state lies in the goal region, and not before."""
    cfg = imported["ZAM", "replay"]
    meta = json.loads((cfg.parent / "commonroad.json").read_text())
    goal = Goal.from_list(meta["goal"])
    probe = _Probe()
    s = _run(cfg, tmp_path / "run", probe=probe)
    cr = s.data["commonroad"]
    assert s.data["completed"] and cr["goal_reached"] and s.status.value == "completed"
    assert 35 <= cr["goal_time_step"] <= 40
    t0, dt = cr["time_offset"], meta["dt"]
    reached = [goal.completes(int(round((t - t0) / dt)), x, y, yaw, v) for t, x, y, yaw, v in probe.ego]
    assert reached[-1] and not any(reached[:-1])
    assert abs(probe.ego[-1][0] - cr["goal_time"]) < 1e-9
    assert json.loads((tmp_path / "run" / "summary.json").read_text())["commonroad"]["goal_reached"] is True


@needs_cr
@pytest.mark.sumo
def test_reactive_starts_as_recorded(imported, tmp_path: Path) -> None:
    cfg = imported["BEL", "reactive"]
    meta = json.loads((cfg.parent / "commonroad.json").read_text())
    rec = pd.read_parquet(cfg.parent / "obstacles.parquet")
    probe = _Probe()
    summary = _run(cfg, tmp_path / "run", probe=probe)
    t0, dt = summary.data["commonroad"]["time_offset"], meta["dt"]
    seen = pd.DataFrame(probe.rows, columns=["time", "sumo_id", "x", "y"])
    for sid in meta["obstacles"]["driven_by_sumo"]:
        mine = seen[seen.sumo_id == sid]
        first = rec[rec.sumo_id == sid].iloc[0]
        assert abs(mine.time.iloc[0] - (t0 + (first.step - meta["first_step"]) * dt)) < 1e-6  # departs on time
        # where recorded, up to the lane centre SUMO puts it on
        assert math.hypot(mine.x.iloc[0] - first.x, mine.y.iloc[0] - first.y) < 2.0
    for sid in meta["obstacles"]["replayed"]:  # those SUMO cannot drive (here: starting on the junction)
        r = rec[rec.sumo_id == sid].set_index("step")
        for _, row in seen[seen.sumo_id == sid].iterrows():
            k = int(round((row.time - t0) / dt)) + meta["first_step"]
            assert math.hypot(row.x - r.x[k], row.y - r.y[k]) < 0.01


@pytest.mark.sumo
@needs_cr
def test_cli_import_then_run(tmp_path: Path, capsys) -> None:
    """The command line end to end on the gz file: import, then run with the default planner."""
    out = tmp_path / "zam"
    assert main(["import-commonroad", str(ZAM), "--out", str(out), "--mode", "replay"]) == 0
    assert "run it: sumo-ethics run" in capsys.readouterr().out
    assert main(["run", str(out / "ZAM_Tutorial-1_1_T-1.sumocfg"), "--out", str(tmp_path / "run"), "--quiet"]) == 0
    d = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert d["controller"] == "ethical" and d["ego_id"] == "ego"
    assert d["commonroad"]["goal_reached"] == d["completed"]
    assert main(["run", str(out / "ZAM_Tutorial-1_1_T-1.sumocfg"), "--ego", "x", "--out", str(tmp_path / "r2")]) == 2


@needs_cr
@pytest.mark.sumo
def test_evaluate_a_folder_of_commonroad_files(tmp_path: Path, capsys) -> None:
    """Imported on the fly; a file that does not import is listed with its cause and the rest run."""
    src = tmp_path / "in"
    (src / "sub").mkdir(parents=True)
    (src / "ZAM_Tutorial-1_1_T-1.xml.gz").write_bytes(ZAM.read_bytes())
    (src / "sub" / "BEL_Putte-1_1_T-1.xml.gz").write_bytes(BEL.read_bytes())
    (src / "broken.xml").write_text('<?xml version="1.0"?><commonRoad><foo></commonRoad>')
    _no_problem(src)  # noproblem.xml: no planning problem
    out = tmp_path / "ev"
    assert main(["evaluate", str(src), "--planner", "baseline", "--out", str(out), "--workers", "1", "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "import failed: broken.xml" in err and "import failed: noproblem.xml" in err
    imports = pd.read_csv(out / "imports.csv")
    assert sorted(imports.status) == ["failed", "failed", "imported", "imported"]
    assert imports.seconds.notna().all() and (imports.seconds < 60).all()
    failed = imports[imports.status == "failed"].set_index("file")
    assert "no planning problem" in failed.loc[str(src / "noproblem.xml"), "cause"]
    res = pd.read_csv(out / "results.csv")
    assert sorted(res.scenario) == ["BEL_Putte-1_1_T-1-replay", "ZAM_Tutorial-1_1_T-1-replay"]
    assert res.goal_reached.tolist() == res.completed.tolist()
    assert (res.replay_max_error_m < 0.01).all()
    assert "2 of 4 files imported" in (out / "table1.md").read_text()

    # --resume reads the finished runs back instead of running them again; a killed run (no
    # summary) is run again
    runs = out / "runs" / "baseline"
    kept = runs / "BEL_Putte-1_1_T-1-replay" / "summary.json"
    mtime = kept.stat().st_mtime_ns
    (runs / "ZAM_Tutorial-1_1_T-1-replay" / "summary.json").unlink()
    assert main(["evaluate", str(src), "--planner", "baseline", "--out", str(out), "--workers", "1", "--quiet",
                 "--resume"]) == 0
    assert kept.stat().st_mtime_ns == mtime
    assert (runs / "ZAM_Tutorial-1_1_T-1-replay" / "summary.json").is_file()
    again = pd.read_csv(out / "results.csv")
    cols = [c for c in res.columns if c != "wall_s"]
    pd.testing.assert_frame_equal(again[cols], res[cols])

    # Origin's completion rule: imported again into their own folders, and said in the table
    late = tmp_path / "late"
    assert main(["evaluate", str(src), "--planner", "baseline", "--out", str(late), "--workers", "1", "--quiet",
                 "--completion", "origin"]) == 0
    assert sorted(p.name for p in (late / "imported").iterdir()) == ["BEL_Putte-1_1_T-1-replay-late",
                                                                    "ZAM_Tutorial-1_1_T-1-replay-late"]
    table = (late / "table1.md").read_text()
    assert "--completion origin" in table and "Completed late: baseline " in table
    assert "goal_late" in pd.read_csv(late / "results.csv")


@needs_cr
@pytest.mark.sumo
def test_the_ego_changes_to_the_goal_lane(tmp_path: Path) -> None:
    """ZAM_Tutorial with its goal moved one lanelet to the left: the ego starts on lane 1_0 and the
    reference path takes it to the goal's lane 1_1 (lanelet 2), where the run completes."""
    from sumo_ethics.commonroad.importer import import_commonroad

    text = gzip.open(ZAM, "rt").read()
    goal = text.index("<goalState>")
    src = tmp_path / "ZAM_left.xml"
    src.write_text(text[:goal] + text[goal:].replace('<lanelet ref="1"/>', '<lanelet ref="2"/>', 1))
    cfg = import_commonroad(src, tmp_path / "imp").sumocfg
    meta = json.loads((cfg.parent / "commonroad.json").read_text())
    assert meta["goal_lanes"] == ["1_1"] and meta["ego"]["lane"] == "1_0"
    s = _run(cfg, tmp_path / "run")
    assert s.data["commonroad"]["goal_reached"], s.message
    steps = pd.read_parquet(tmp_path / "run" / "steps.parquet")
    assert steps.lane.iloc[0] == "1_0" and steps.lane.iloc[-1] == "1_1"


@needs_cr
@pytest.mark.sumo
@pytest.mark.parametrize("velocity", [None, (10.0, 30.0)], ids=["window", "window+speed"])
def test_the_ego_waits_for_the_goal_window(velocity, tmp_path: Path) -> None:
    """ZAM_Tutorial with its goal window moved from steps [35, 40] to [100, 110] (10-11 s) and without
    its car (which cuts in behind the ego at 23 m/s: a test of timing, not of traffic): the goal,
    lanelet 1, runs from x = 0 to 199 m; the ego starts at x = 15 m at 22 m/s and the road's limit is
    36.1 m/s, so at the limit it leaves the region long before the window opens (before the pace: the
    end of the route at step 64, 67 with the goal speed's 30 m/s as the lane's limit). Paced, it aims at the region's middle (99.5 m) as the window opens:
    (99.5 - 15) / 10 = 8.45 m/s, or the goal's lowest speed where that is higher, and completes in
    the window."""
    from sumo_ethics.commonroad.importer import import_commonroad

    text = gzip.open(ZAM, "rt").read()
    text = text[:text.index("<dynamicObstacle")] + text[text.index("</dynamicObstacle>") + len("</dynamicObstacle>"):]
    goal = text.index("<goalState>")
    late = text[goal:].replace("<intervalStart>35</intervalStart>", "<intervalStart>100</intervalStart>", 1)
    late = late.replace("<intervalEnd>40</intervalEnd>", "<intervalEnd>110</intervalEnd>", 1)
    if velocity is not None:
        late = late.replace("<time>", f"<velocity><intervalStart>{velocity[0]}</intervalStart><intervalEnd>"
                                      f"{velocity[1]}</intervalEnd></velocity><time>", 1)
    src = tmp_path / "ZAM_late.xml"
    src.write_text(text[:goal] + late)
    cfg = import_commonroad(src, tmp_path / "imp").sumocfg
    s = _run(cfg, tmp_path / "run", controller="ethical")
    cr = s.data["commonroad"]
    assert s.data["completed"] and cr["goal_reached"], s.message
    assert 100 <= cr["goal_time_step"] <= 110
    steps = pd.read_parquet(tmp_path / "run" / "steps.parquet")
    first = steps.desired_speed.iloc[0]  # asked at the first step: x = 15 m, 10 s before the window opens
    assert first == pytest.approx(8.45 if velocity is None else 10.0, abs=0.01)
    assert steps.speed.max() < 22.5  # never sped up towards the limit
    if velocity is None:  # halfway through the region as the window opens
        assert cr["goal_time_step"] == 100 and abs(steps.x.iloc[-1] - 99.5) < 2.0
    else:  # at the goal's lowest speed, through the middle before the window opens
        assert 99.5 < steps.x.iloc[-1] < 199.0 and velocity[0] <= steps.speed.iloc[-1] <= velocity[1]


def test_evaluate_refuses_folders_imported_another_way(tmp_path: Path, capsys) -> None:
    """A folder of imports made in replay mode, evaluated as reactive (or under another completion
    rule): one line naming the options they were imported with, exit 2."""
    (tmp_path / "in" / "a").mkdir(parents=True)
    (tmp_path / "in" / "a" / "commonroad.json").write_text(json.dumps({"mode": "replay", "source": "x.xml"}))
    assert main(["evaluate", str(tmp_path / "in"), "--mode", "reactive", "--out", str(tmp_path / "ev")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--mode replay --completion commonroad" in err, err


@needs_cr
@pytest.mark.sumo
def test_late_arrival_counts_only_under_the_origin_rule(tmp_path: Path) -> None:
    """ZAM_Tutorial without its car and with the goal a 15 m x 3.5 m box centred at x = 187.5 m on the
    ego's lane, window steps [35, 40] (3.5-4 s): the ego starts at x = 15 m at 22 m/s, so even at the
    road's 36.1 m/s it is at most 15 + 36.1 * 4 = 159 m far by the window's end, and its centre reaches
    the box (x >= 180 m) only after it. Under the CommonRoad rule the run ends at step 40 without
    the goal; under Origin's it goes on to step 80 (twice 40) and completes, late, in the box."""
    from sumo_ethics.commonroad.importer import default_out, import_commonroad

    text = gzip.open(ZAM, "rt").read()
    text = text[:text.index("<dynamicObstacle")] + text[text.index("</dynamicObstacle>") + len("</dynamicObstacle>"):]
    box = ("<rectangle><length>15</length><width>3.5</width><orientation>0</orientation>"
           "<center><x>187.5</x><y>0</y></center></rectangle>")
    goal = text.index("<goalState>")
    src = tmp_path / "ZAM_far.xml"
    src.write_text(text[:goal] + text[goal:].replace('<lanelet ref="1"/>', box, 1))
    strict = import_commonroad(src, tmp_path / "cr")
    late = import_commonroad(src, tmp_path / "origin", completion="origin")
    assert json.loads((late.folder / "commonroad.json").read_text())["completion"] == "origin"
    assert default_out(src, "replay", "origin").name == "ZAM_far-replay-late"
    a = _run(strict.sumocfg, tmp_path / "run_cr")
    assert a.data["status"] == "timeout" and not a.data["commonroad"]["goal_reached"], a.message
    assert pd.read_parquet(tmp_path / "run_cr" / "steps.parquet").x.max() < 160.0
    b = _run(late.sumocfg, tmp_path / "run_origin")
    cr = b.data["commonroad"]
    assert b.data["completed"] and cr["goal_reached"] and cr["goal_late"] and cr["completion"] == "origin", b.message
    assert 40 < cr["goal_time_step"] <= 80 and "late" in b.message
    x = pd.read_parquet(tmp_path / "run_origin" / "steps.parquet").x.iloc[-1]
    assert 180.0 <= x <= 195.0


@needs_cr
@pytest.mark.sumo
def test_same_seed_same_bytes(imported, tmp_path: Path) -> None:
    """Two runs of an imported scenario with the same seed write the same steps and collisions."""
    cfg = imported["BEL", "reactive"]
    for name in ("a", "b"):
        _run(cfg, tmp_path / name)
    for f in ("steps.parquet", "collisions.parquet"):
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes(), f


@needs_cr
@pytest.mark.sumo
def test_a_pedestrian_on_a_highway_is_replayed(tmp_path: Path) -> None:
    """ZAM_Tutorial's car made a pedestrian: the highway's lanes disallow pedestrians, so it is replayed as
    a vehicle of class wheelchair (booked as a pedestrian), exactly where recorded."""
    from sumo_ethics.commonroad.importer import import_commonroad
    from sumo_ethics.types import RoadUserClass

    src = tmp_path / "ZAM_ped.xml"
    src.write_text(gzip.open(ZAM, "rt").read().replace("<type>car</type>", "<type>pedestrian</type>"))
    cfg = import_commonroad(src, tmp_path / "imp").sumocfg
    meta = json.loads((cfg.parent / "commonroad.json").read_text())
    assert meta["obstacles"]["info"]["cr_42"]["vclass"] == "wheelchair"
    seen: list[int] = []

    def classes(snap, world) -> None:
        seen.extend(int(c) for i, c in zip(snap.others.ids, snap.others.cls) if i == "cr_42")

    s = run_with(cfg, tmp_path / "run", classes)
    assert s.data["commonroad"]["replay"]["missing"] == 0 and s.data["commonroad"]["replay"]["max_error_m"] < 0.01
    assert seen and set(seen) == {int(RoadUserClass.PEDESTRIAN)}


def run_with(cfg: Path, out: Path, hook):
    from sumo_ethics.config import RunConfig
    from sumo_ethics.runner import run

    return run(RunConfig(scenario=cfg, out=out, controller="baseline", progress=False), hooks=(hook,))


@needs_cr
def test_importing_on_two_workers_gives_the_rows_of_one(tmp_path: Path) -> None:
    """The imports of evaluate's CommonRoad folders on several workers (one fresh process per file,
    sumo_ethics.processes.run_each): the same rows in the same order as on one."""
    from sumo_ethics.suite import commonroad

    src = tmp_path / "in"
    src.mkdir()
    (src / "ZAM_Tutorial-1_1_T-1.xml.gz").write_bytes(ZAM.read_bytes())
    (src / "BEL_Putte-1_1_T-1.xml.gz").write_bytes(BEL.read_bytes())
    (src / "broken.xml").write_text('<?xml version="1.0"?><commonRoad><foo></commonRoad>')
    runs = [commonroad.prepare(src, tmp_path / f"out{n}", "replay", n) for n in (1, 2)]
    (one_dirs, one), (two_dirs, two) = runs
    assert [(Path(r["file"]).name, r["status"], r["cause"]) for r in one] == \
        [(Path(r["file"]).name, r["status"], r["cause"]) for r in two]
    assert [r["status"] for r in two] == ["imported", "imported", "failed"]
    assert [p.name for p in one_dirs] == [p.name for p in two_dirs]
