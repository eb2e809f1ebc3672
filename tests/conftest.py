"""Shared helpers: small SUMO scenarios on the bundled testbed network, scripted controllers."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sumo_ethics.contract import Decision, EgoCommand, Scene

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


@pytest.fixture
def scenario_dir(tmp_path: Path) -> Path:
    return tmp_path / "scenario"
