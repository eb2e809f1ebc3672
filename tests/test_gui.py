"""``sumo-ethics run --gui``: the run in sumo-gui through TraCI, under a virtual display (Xvfb).

The screenshot comes from sumo-gui's own call (``gui.screenshot``, through tools/gui_screenshot.py,
which runs ``runner.run(..., gui=...)`` as ``run --gui`` does); its pixels must show the ego
(painted cyan) at the centre, since the view tracks it, and the chosen trajectory (magenta)
ahead of it. The same run without --gui must write the same steps.parquet and collisions.parquet,
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
    ego = _pixels(image, gui.EGO_COLOUR)
    line = _pixels(image, gui.TRAJECTORY_COLOUR)
    # the ego: a car of 4.5 x 1.8 m at about 8 px/m is a few hundred pixels, at the centre (tracked)
    assert len(ego) >= 50, f"{len(ego)} ego pixels"
    assert np.linalg.norm(ego.mean(axis=0) - centre) < 0.1 * w, (ego.mean(axis=0), centre)
    # the trajectory: a 0.5 m wide line from the ego's front bumper along its heading
    assert len(line) >= 50, f"{len(line)} trajectory pixels"
    steps = pd.read_parquet(run / "steps.parquet")
    yaw = float(steps.loc[(steps.time - AT).abs().idxmin(), "yaw"])  # counter-clockwise from east
    ahead = line.mean(axis=0) - ego.mean(axis=0)
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


def test_only_the_backend_imports_libsumo_or_traci():
    """The layering: sumo_ethics reaches SUMO's APIs only through sumo_ethics/sim/backend.py."""
    pattern = re.compile(r"^\s*(import|from)\s+(libsumo|traci)\b", re.M)
    found = [str(p.relative_to(ROOT)) for p in (ROOT / "sumo_ethics").rglob("*.py") if pattern.search(p.read_text())]
    assert found == ["sumo_ethics/sim/backend.py"]
