"""Shared helpers: small SUMO scenarios on the bundled testbed network, scripted controllers."""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from sumo_ethics.contract import Decision, EgoCommand, Scene
from sumo_ethics.sumo_options import NO_SUMO_ENV

ROOT = Path(__file__).resolve().parents[1]
TESTBED_NET = ROOT / "networks" / "testbed" / "testbed.net.xml"
SCENARIOS = ROOT / "scenarios"

VTYPES = """
  <vType id="car" vClass="passenger" length="4.5" width="1.8"/>
  <vType id="slowcar" vClass="passenger" length="4.5" width="1.8" maxSpeed="10"/>
  <vType id="ped" vClass="pedestrian" length="0.3" width="0.5"/>
  <route id="r_main" edges="main_0 main_1"/>
"""


def write_scenario(folder: Path, routes: str, end: float = 120.0, step: float = 0.1) -> Path:
    """A .sumocfg on the testbed network with the given route-file body; returns its path."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "t.rou.xml").write_text(f"<routes>{VTYPES}{routes}</routes>\n")
    cfg = folder / "t.sumocfg"
    cfg.write_text(
        f'<configuration><input><net-file value="{TESTBED_NET}"/><route-files value="t.rou.xml"/></input>'
        f'<time><end value="{end}"/><step-length value="{step}"/></time></configuration>\n'
    )
    return cfg


class Scripted:
    """Drives along the route at a fixed speed, blind to everyone, optionally drifting sideways.

    ``offset(t)`` is the lateral offset [m] (left +) at time t; ``trigger(scene)`` holds the
    ego at a standstill until it returns True once.
    """

    name = "scripted"
    needs_history = False

    def __init__(self, speed: float, offset=lambda t: 0.0, trigger=lambda scene: True) -> None:
        self.speed, self.offset, self.trigger = speed, offset, trigger
        self.started = False

    def act(self, scene: Scene) -> Decision:
        self.started = self.started or bool(self.trigger(scene))
        v = self.speed if self.started else 0.0
        s = scene.s + v * scene.dt
        d = self.offset(scene.time + scene.dt) if self.started else scene.d
        x, y, yaw = scene.route.path.to_xy(np.array(s), np.array(d))
        if v > 0:
            yaw = yaw + np.arctan2(d - scene.d, v * scene.dt)
        return Decision(EgoCommand(float(x), float(y), float(yaw), v))


def sumo_binary(name: str) -> str:
    """The path of SUMO's ``name`` binary (sumo, netconvert) for a test that runs it directly; refused
    like every SUMO start in a test not marked ``sumo``."""
    import sumo

    from sumo_ethics.sumo_options import refuse_if_barred

    refuse_if_barred(name)
    return str(Path(sumo.SUMO_HOME) / "bin" / name)


_NO_SUMO_FLAG = pytest.StashKey[Path]()


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    """A test not marked ``sumo`` may not start SUMO, sumo-gui or netconvert, in this process or in
    any process it starts, nor may the fixtures set up for it (sumo_options.NO_SUMO_ENV, whose
    folder lives as long as the test). A start raises there, and the test fails here even when the
    raise was caught (:func:`pytest_runtest_makereport`)."""
    if item.get_closest_marker("sumo"):
        os.environ.pop(NO_SUMO_ENV, None)
        return
    flag = Path(tempfile.mkdtemp(prefix="no_sumo_")) / "started"
    item.stash[_NO_SUMO_FLAG] = flag
    os.environ[NO_SUMO_ENV] = str(flag)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    flag = item.stash.get(_NO_SUMO_FLAG, None)
    if call.when != "teardown" or flag is None:
        return
    os.environ.pop(NO_SUMO_ENV, None)
    if flag.exists():
        report = outcome.get_result()
        report.outcome = "failed"
        report.longrepr = f"{item.nodeid} is not marked sumo but started: {flag.read_text().strip()}"
    shutil.rmtree(flag.parent, ignore_errors=True)


@pytest.fixture
def scenario_dir(tmp_path: Path) -> Path:
    return tmp_path / "scenario"


def straight_road_scene(others, history, desired_speed: float | None = None, dt: float = 0.1) -> Scene:
    """A planner's scene without SUMO: the ego (4.508 x 1.61 m, 1475 kg) at x = 10 m, 10 m/s, heading
    +x on a straight 500 m road limited to 14 m/s (lanes from y = -1.75 to 5.25 m); ``others``
    (AgentStates) with their ``history`` (N, H, 2) sampled every ``dt`` [s] (all valid)."""
    from sumo_ethics.config import EgoVehicle
    from sumo_ethics.contract import RoutePath
    from sumo_ethics.geometry import Polyline
    from sumo_ethics.types import AgentStates, Observation

    path = Polyline.from_points(np.array([[0.0, 0.0], [500.0, 0.0]]))
    route = RoutePath(edges=("e",), path=path, lane_of_vertex=("e_0", "e_0"), speed_limit=np.full(2, 14.0),
                      left=np.full(2, 5.25), right=np.full(2, -1.75), links=())
    ego = AgentStates(ids=("ego",), x=np.array([10.0]), y=np.zeros(1), yaw=np.zeros(1), speed=np.full(1, 10.0),
                      accel=np.zeros(1), length=np.full(1, 4.508), width=np.full(1, 1.61),
                      mass=np.full(1, 1475.0), cls=np.zeros(1, np.int8))
    hist = np.asarray(history, dtype=float)
    obs = Observation(time=0.0, dt=dt, history=hist, valid=np.ones(hist.shape[:2], bool), current=others, ego=ego)
    return Scene(time=0.0, dt=dt, ego=ego, others=others, route=route, s=10.0, d=0.0, stop_s=None,
                 vehicle=EgoVehicle(), history=obs, desired_speed=desired_speed)


def build_signalised(folder):
    """A road W (-100, 0) -> C (0, 0) -> E (100, 0) with a side road S -> C -> N, C a traffic light
    held red for every link (an additional tlLogic); returns (net, additional file)."""

    folder.mkdir(parents=True, exist_ok=True)
    (folder / "n.nod.xml").write_text(
        '<nodes><node id="W" x="-100" y="0"/><node id="E" x="100" y="0"/><node id="S" x="0" y="-100"/>'
        '<node id="N" x="0" y="100"/><node id="C" x="0" y="0" type="traffic_light"/></nodes>')
    (folder / "e.edg.xml").write_text(
        '<edges><edge id="WC" from="W" to="C" numLanes="1" speed="13.89"/>'
        '<edge id="CE" from="C" to="E" numLanes="1" speed="13.89"/>'
        '<edge id="SC" from="S" to="C" numLanes="1" speed="13.89"/>'
        '<edge id="CN" from="C" to="N" numLanes="1" speed="13.89"/></edges>')
    net = folder / "x.net.xml"
    subprocess.run([sumo_binary("netconvert"), "-n", "n.nod.xml", "-e", "e.edg.xml",
                    "-o", net.name, "--offset.disable-normalization", "true", "--no-turnarounds", "true",
                    "--no-warnings", "true"], cwd=folder, check=True, capture_output=True)
    n_links = len(next(ET.parse(net).getroot().iter("tlLogic")).find("phase").get("state"))
    add = folder / "red.add.xml"
    add.write_text(f'<additional><tlLogic id="C" type="static" programID="red" offset="0">'
                   f'<phase duration="1000" state="{"r" * n_links}"/></tlLogic></additional>')
    return net, add
