"""``sumo-ethics run --gui``: the run in sumo-gui through TraCI, under a virtual display (Xvfb).

The screenshot comes from sumo-gui's own call (``gui.screenshot``, through tools/gui_screenshot.py,
which runs ``runner.run(..., gui=...)`` as ``run --gui`` does); its pixels must show the ego (a
yellow car, sumo-gui's default colour, inside its cyan ring) at the centre, since the view tracks
it, and the chosen trajectory (magenta) ahead of it. The same run without --gui must write the same steps.parquet and collisions.parquet,
byte for byte. Without Xvfb (``apt-get install xvfb``) those tests are skipped.
"""

from __future__ import annotations

import math
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from conftest import ROOT, SCENARIOS
from sumo_ethics.sim import gui

XVFB = shutil.which("Xvfb")
needs_xvfb = pytest.mark.skipif(XVFB is None, reason="Xvfb is not installed (apt-get install xvfb): sumo-gui needs "
                                "a display, and the test makes a virtual one")
URBAN = SCENARIOS / "urban_grid" / "urban_grid.sumocfg"
SEED, AT = 3, 5.0


@pytest.fixture(scope="module")
def display():
    """A virtual display on a free number (Xvfb picks it: -displayfd), for this module's tests."""
    proc = subprocess.Popen([XVFB, "-displayfd", "1", "-screen", "0", "1280x1024x24", "-nolisten", "tcp"],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    number = proc.stdout.readline().strip()  # written once the server is ready
    if not number.isdigit():
        proc.kill()
        pytest.fail(f"Xvfb did not start (it printed {number!r})")
    yield f":{number}"
    proc.terminate()
    proc.wait(timeout=10)


def _env(**change: str | None) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in change}
    env.update({k: v for k, v in change.items() if v is not None})
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH")) if p)
    return env


def _cli(args: list[str], **env: str | None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "sumo_ethics.cli", *args], capture_output=True, text=True,
                          timeout=300, env=_env(**env))


def _pixels(image: np.ndarray, rgb: tuple[int, ...], tol: int = 40) -> np.ndarray:
    """(M, 2) x, y of the pixels within ``tol`` (summed over R, G, B) of colour ``rgb``."""
    hit = np.abs(image[..., :3].astype(int) - np.array(rgb[:3])).sum(axis=-1) <= tol
    ys, xs = np.nonzero(hit)
    return np.c_[xs, ys]


@pytest.mark.sumo
@needs_xvfb
def test_gui_screenshot_shows_the_ego_and_its_trajectory_and_outputs_match(tmp_path, display):
    from PIL import Image

    png, run = tmp_path / "gui.png", tmp_path / "gui-run"
    p = subprocess.run([sys.executable, str(ROOT / "tools" / "gui_screenshot.py"), str(URBAN), "--seed", str(SEED),
                        "--at", str(AT), "--png", str(png), "--out", str(run), "--window", "800,700"],
                       capture_output=True, text=True, timeout=300, env=_env(DISPLAY=display))
    assert p.returncode == 0 and png.is_file(), p.stderr
    image = np.asarray(Image.open(png).convert("RGB"))
    h, w = image.shape[:2]
    assert w >= 400 and h >= 300, image.shape
    centre = np.array([w / 2, h / 2])
    ring = _pixels(image, gui.EGO_COLOUR)
    line = _pixels(image, gui.TRAJECTORY_COLOUR)
    # the ego's ring, at the centre (tracked), and inside it the car: 4.5 x 1.8 m at about 8 px/m
    assert len(ring) >= 200, f"{len(ring)} ring pixels"
    ego = ring.mean(axis=0)
    assert np.linalg.norm(ego - centre) < 0.05 * w, (ego, centre)
    inner = np.linalg.norm(ring - ego, axis=1).min()
    car = _pixels(image, (255, 255, 0))
    assert (np.linalg.norm(car - ego, axis=1) < inner).sum() >= 100, "no yellow car inside the ego's ring"
    # the trajectory: a 0.5 m wide line from the ego's front bumper along its heading
    assert len(line) >= 50, f"{len(line)} trajectory pixels"
    steps = pd.read_parquet(run / "steps.parquet")
    yaw = float(steps.loc[(steps.time - AT).abs().idxmin(), "yaw"])  # counter-clockwise from east
    ahead = line.mean(axis=0) - ego
    heading = np.array([math.cos(yaw), -math.sin(yaw)])  # image rows grow downwards
    assert ahead @ heading > 0.9 * np.linalg.norm(ahead), (ahead, yaw)
    assert np.linalg.norm(line - centre, axis=1).min() < 0.1 * w  # it starts at the ego
    # the same run without sumo-gui: the same rows, byte for byte
    plain = tmp_path / "plain"
    p = _cli(["run", str(URBAN), "--seed", str(SEED), "--end", str(AT + 0.5), "--out", str(plain), "--quiet"])
    assert p.returncode == 0, p.stderr
    for name in ("steps.parquet", "collisions.parquet"):
        assert (plain / name).read_bytes() == (run / name).read_bytes(), name
    assert "gui" in pd.read_json(run / "summary.json", typ="series") and \
        "gui" not in pd.read_json(plain / "summary.json", typ="series")


def _one_error_line(p: subprocess.CompletedProcess, fragment: str) -> None:
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert p.returncode == 2, p.stderr
    assert len(lines) == 1 and lines[0].startswith("error: ") and fragment in lines[0], p.stderr
    assert "Traceback" not in p.stderr + p.stdout


def test_gui_without_display_says_so_in_one_line(tmp_path):
    p = _cli(["run", str(URBAN), "--gui", "--end", "5", "--out", str(tmp_path / "out"), "--quiet"], DISPLAY=None)
    _one_error_line(p, "--gui needs a display and DISPLAY is not set")
    assert not (tmp_path / "out").exists()


@pytest.mark.sumo
def test_gui_on_a_display_that_is_not_there_says_so_in_one_line(tmp_path):
    """sumo-gui itself fails to open the display: its reason in one line, the run folder left empty."""
    number = next(n for n in range(300, 400) if not Path(f"/tmp/.X{n}-lock").exists()
                  and not Path(f"/tmp/.X11-unix/X{n}").exists())
    p = _cli(["run", str(URBAN), "--gui", "--end", "5", "--out", str(tmp_path / "out"), "--quiet"],
             DISPLAY=f":{number}")
    _one_error_line(p, "sumo-gui cannot open the display")
    assert not (tmp_path / "out").exists()


def test_decision_shapes_by_hand():
    """A straight chosen candidate along x from an ego at the origin (4 m long): drawn from its
    front bumper (x = 2) on; only the neighbour with risk > 0 gets its mean path and one ellipse
    per whole second (prediction every 0.5 s for 2 s: at 1 s and 2 s, 1-sigma radius 0.5 m)."""
    xs = np.arange(1, 9, dtype=float)[None, :]  # 1 m per step
    cand = SimpleNamespace(x=xs, y=np.zeros_like(xs), valid=np.ones_like(xs, dtype=bool))
    ego = SimpleNamespace(x=np.array([0.0]), y=np.array([0.0]), yaw=np.array([0.0]), length=np.array([4.0]))
    mean = np.stack([np.c_[np.full(4, 10.0), 5.0 + np.arange(1, 5)], np.c_[np.full(4, -10.0), np.zeros(4)]])
    pred = SimpleNamespace(dt=0.5, mean=mean, cov=np.broadcast_to(np.eye(2) * 0.25, (2, 4, 2, 2)))
    agents = SimpleNamespace(x=np.array([10.0, -10.0]), y=np.array([5.0, 0.0]))
    trace = SimpleNamespace(candidates=cand, chosen=0, ego=ego, prediction=pred, agents=agents,
                            agent_risk=np.array([0.01, 0.0]))
    shapes = gui.decision_shapes(trace)
    traj = shapes[f"{gui.PREFIX}trajectory"][0]
    assert traj[0].tolist() == [2.0, 0.0] and traj[1:, 0].tolist() == [3, 4, 5, 6, 7, 8]
    assert sorted(shapes) == sorted([f"{gui.PREFIX}trajectory", f"{gui.PREFIX}risk:0", f"{gui.PREFIX}risk:0:1",
                                     f"{gui.PREFIX}risk:0:3"])
    assert shapes[f"{gui.PREFIX}risk:0"][0][0].tolist() == [10.0, 5.0]  # the path starts where it is
    ring = shapes[f"{gui.PREFIX}risk:0:3"][0]  # at 2 s: centre (10, 9)
    assert np.allclose(np.hypot(ring[:, 0] - 10.0, ring[:, 1] - 9.0), 0.5)
    assert gui.decision_shapes(None) == {}


def test_view_shapes_by_hand():
    """A sensor at the origin, range 20 m, a 2 x 2 m box centred at (5, 0): one shadow, the sector
    behind it (its near corners' bearings +-atan(1/4)), its outline drawn; the range as a ring of radius
    20; a phantom 0.3 x 0.5 m at (8, 3) heading +y as its box (corners 0.15 m along, 0.25 m across)
    and its mean path from where it stands."""
    from sumo_ethics.geometry import OrientedBoxes
    from sumo_ethics.types import AgentStates, Prediction, ViewTrace
    from sumo_ethics.visibility import view

    v = view(np.zeros(2), 20.0, OrientedBoxes(5.0, 0.0, 0.0, 2.0, 2.0).corners()[None])
    ph = AgentStates(("phantom:pedestrian:0",), np.array([8.0]), np.array([3.0]), np.array([np.pi / 2]), np.ones(1),
                     np.zeros(1), np.array([0.3]), np.array([0.5]), np.array([75.0]), np.array([5], np.int8))
    pred = Prediction(ph.ids, 0.1, np.array([[[8.0, 3.1], [8.0, 3.2]]]), np.tile(np.eye(2), (1, 2, 1, 1)),
                      np.full((1, 2), np.pi / 2))
    trace = ViewTrace(np.zeros(2), 20.0, v.visible, v.hidden, (), (), ph, pred, np.array([0.1]), np.array([0.0]))
    shapes = gui.view_shapes(trace)
    assert sorted(shapes) == sorted(f"{gui.PREFIX}{k}" for k in ("hidden:0", "range", "phantom:0", "phantom:0:path"))
    pts, colour, filled, _ = shapes[f"{gui.PREFIX}hidden:0"]
    assert not filled and colour == gui.HIDDEN_COLOUR
    bearing = np.arctan2(pts[:, 1], pts[:, 0])
    assert np.abs(bearing).max() == pytest.approx(np.arctan2(1.0, 4.0))  # through the near corners (4, +-1)
    ring = shapes[f"{gui.PREFIX}range"][0]
    assert np.allclose(np.hypot(ring[:, 0], ring[:, 1]), 20.0)
    box = shapes[f"{gui.PREFIX}phantom:0"][0]
    assert np.allclose(np.sort(box[:4, 0]), [7.75, 7.75, 8.25, 8.25]) and np.allclose(np.sort(box[:4, 1]), [2.85, 2.85, 3.15, 3.15])
    assert shapes[f"{gui.PREFIX}phantom:0:path"][0].tolist() == [[8.0, 3.0], [8.0, 3.1], [8.0, 3.2]]
    assert gui.view_shapes(None) == {}


def test_only_the_backend_imports_libsumo_or_traci():
    """The layering: sumo_ethics reaches SUMO's APIs only through sumo_ethics/sim/backend.py."""
    pattern = re.compile(r"^\s*(import|from)\s+(libsumo|traci)\b", re.M)
    found = [str(p.relative_to(ROOT)) for p in (ROOT / "sumo_ethics").rglob("*.py") if pattern.search(p.read_text())]
    assert found == ["sumo_ethics/sim/backend.py"]


@pytest.mark.sumo
@needs_xvfb
def test_gui_marks_the_ego_collision_with_a_red_ring(tmp_path, display):
    """A blind ego at 10 m/s into a parked car (tests/sim/test_sim_collisions.py's rear-end), kept
    going: a second after the impact the screenshot holds the red ring near the view's centre; five
    seconds before it, that red is not there (sumo-gui draws some red itself: signals, tail lights)."""
    code = f"""
import sys
from pathlib import Path
sys.path.insert(0, {str(ROOT / "tests")!r})
from conftest import Scripted, write_scenario
from sumo_ethics.config import RunConfig
from sumo_ethics.runner import run
from sumo_ethics.sim.backend import sumo
from sumo_ethics.sim.gui import VIEW, GuiOptions

tmp = Path({str(tmp_path)!r})
cfg = write_scenario(tmp / "s", '''
  <vehicle id="parked" type="car" route="r_main" depart="0" departLane="2" departPos="124" departSpeed="0">
    <stop lane="main_0_2" endPos="124.5" duration="1000"/></vehicle>
  <vehicle id="ego" type="car" route="r_main" depart="0" departLane="2" departPos="20" departSpeed="10"/>''')
def shot(snap, world, todo=[(5.0, "before.png"), (11.0, "hit.png")]):
    if todo and snap.time >= todo[0][0]:
        sumo.gui.screenshot(VIEW, str(tmp / todo.pop(0)[1]))
run(RunConfig(cfg, tmp / "run", ego_id="ego", stop_at_collision=False, end=11.5, progress=False,
              sumo_args=("--window-size", "800,700")), controller=Scripted(10.0), hooks=(shot,), gui=GuiOptions())
"""
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                       env=_env(DISPLAY=display))
    assert p.returncode == 0, p.stderr
    from PIL import Image

    rows = pd.read_parquet(tmp_path / "run" / "collisions.parquet")
    assert rows.involves_ego.sum() == 1 and rows.time.iloc[0] < 11.0  # hit before the shot
    image = np.asarray(Image.open(tmp_path / "hit.png").convert("RGB"))
    red = _pixels(image, gui.COLLISION_COLOUR, tol=30)
    before = _pixels(np.asarray(Image.open(tmp_path / "before.png").convert("RGB")), gui.COLLISION_COLOUR, tol=30)
    assert len(red) >= len(before) + 100, f"{len(red)} red pixels, {len(before)} before the collision"
    # the ring (3 m radius) is drawn where the two met: the ego, tracked at the centre, is 1 s past it
    h, w = image.shape[:2]
    assert np.linalg.norm(red.mean(axis=0) - [w / 2, h / 2]) < 0.25 * w
