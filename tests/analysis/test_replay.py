"""``sumo-ethics replay``: an animation of a recorded run, one frame per recorded planning step."""

from __future__ import annotations

import json
import math
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from PIL import Image

from conftest import SCENARIOS
from sumo_ethics.cli import main
from sumo_ethics.record import decisions as rec

URBAN = SCENARIOS / "urban" / "urban.sumocfg"


def cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "sumo_ethics.cli", *args], capture_output=True, text=True,
                          timeout=300)


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    """A real 5 s urban run with every decision recorded (SUMO in its own process)."""
    out = tmp_path_factory.mktemp("replay") / "run"
    p = cli("run", str(URBAN), "--ego-depart", "60", "--seed", "1", "--end", "65", "--out", str(out),
            "--record-decisions", "all", "--quiet")
    assert p.returncode == 0, p.stderr
    assert len(rec.recorded_steps(out)) >= 20
    return out


def frames(path: Path) -> tuple[int, list[int]]:
    with Image.open(path) as im:
        durations = []
        for i in range(im.n_frames):
            im.seek(i)
            durations.append(im.info["duration"])
        return im.n_frames, durations


@pytest.mark.sumo
def test_gif_has_one_frame_per_recorded_step(run, tmp_path, capsys):
    out = tmp_path / "run.gif"
    assert main(["replay", str(run), "--out", str(out)]) == 0
    n = len(rec.recorded_steps(run))
    count, durations = frames(out)
    assert count == n  # no two frames merged: the title's time differs on every frame
    assert durations == [100] * n  # real time at dt = 0.1 s
    said = capsys.readouterr()
    assert f"wrote {out}: {n} frames at 10 frames/s" in said.out and "real time" in said.out
    assert said.err == ""  # every step recorded, a GIF asked for: nothing to note
    assert not list(tmp_path.glob(".*part*"))  # the temporary file was renamed


@pytest.mark.sumo
def test_every_third_step(run, tmp_path):
    out = tmp_path / "every3.gif"
    assert main(["replay", str(run), "--out", str(out), "--every", "3", "--quiet"]) == 0
    count, durations = frames(out)
    assert count == math.ceil(len(rec.recorded_steps(run)) / 3)
    assert set(durations) == {300}  # still real time: one frame per 0.3 s of run


@pytest.mark.sumo
def test_mp4_without_ffmpeg_writes_a_gif(run, tmp_path, capsys, monkeypatch):
    from matplotlib import animation

    monkeypatch.setattr(animation.writers, "is_available", lambda name: False)
    assert main(["replay", str(run), "--out", str(tmp_path / "run.mp4"), "--every", "10", "--fps", "4"]) == 0
    assert not (tmp_path / "run.mp4").exists()
    count, durations = frames(tmp_path / "run.gif")
    assert count == math.ceil(len(rec.recorded_steps(run)) / 10) and set(durations) == {250}
    said = capsys.readouterr()
    assert "note: ffmpeg not found" in said.err and "run.gif instead of" in said.err
    assert "4x real time" in said.out


def ffmpeg() -> bool:
    from matplotlib import animation

    return animation.writers.is_available("ffmpeg")


@pytest.mark.sumo
@pytest.mark.skipif(not ffmpeg(), reason="no ffmpeg on PATH")
def test_mp4_with_ffmpeg(run, tmp_path, capsys):
    out = tmp_path / "run.mp4"
    assert main(["replay", str(run), "--out", str(out), "--every", "5", "--quiet"]) == 0
    assert out.stat().st_size > 0 and not (tmp_path / "run.gif").exists()
    probe = subprocess.run(["ffmpeg", "-i", str(out), "-map", "0:v", "-c", "copy", "-f", "null", "-"],
                           capture_output=True, text=True, check=False)
    assert "yuv420p" in probe.stderr  # plays in browsers (matplotlib adds it for codec h264)
    assert int(re.findall(r"frame=\s*(\d+)", probe.stderr)[-1]) == math.ceil(len(rec.recorded_steps(run)) / 5)
    assert capsys.readouterr().err == ""


@pytest.mark.sumo
def test_partly_recorded_run_says_so(run, tmp_path, capsys):
    part = tmp_path / "risky"
    shutil.copytree(run, part)
    steps = rec.recorded_steps(part)
    for s in steps[1::2]:
        rec.step_path(part, s).unlink()
    cfg = json.loads((part / "config.json").read_text())
    (part / "config.json").write_text(json.dumps({**cfg, "record_decisions": "risky"}))
    kept = len(rec.recorded_steps(part))
    assert main(["replay", str(part), "--out", str(tmp_path / "r.gif"), "--every", "4", "--quiet"]) == 0
    assert frames(tmp_path / "r.gif")[0] == math.ceil(kept / 4)
    err = capsys.readouterr().err
    assert f"{kept} of {len(steps)} steps recorded; run with --record-decisions all for every step" in err


@pytest.mark.sumo
def test_an_ego_collision_is_always_a_frame(run, tmp_path):
    import pyarrow as pa
    import pyarrow.parquet as pq

    from sumo_ethics.record.schema import COLLISIONS

    crash = tmp_path / "crash"
    shutil.copytree(run, crash)
    steps = rec.recorded_steps(crash)
    hit = next(s for s in reversed(steps) if s not in steps[::3])  # a step --every 3 would skip
    default = {pa.bool_(): False, pa.string(): ""}
    row = {f.name: default.get(f.type, 0) for f in COLLISIONS}
    row.update(event=0, step=hit, time=60.0 + hit / 10, involves_ego=True, detector="geometry", id_a="ego",
               id_b="p0", class_a="car", class_b="pedestrian", harm_third_party=0.5)
    pq.write_table(pa.Table.from_pylist([row], schema=COLLISIONS), crash / "collisions.parquet")
    assert main(["replay", str(crash), "--out", str(tmp_path / "c.gif"), "--every", "3", "--quiet"]) == 0
    assert frames(tmp_path / "c.gif")[0] == math.ceil(len(steps) / 3) + 1


def one_line_error(p: subprocess.CompletedProcess, fragment: str) -> None:
    assert p.returncode == 2, p.stderr
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and fragment in lines[0], p.stderr
    assert "Traceback" not in p.stderr + p.stdout


@pytest.mark.sumo
def test_run_without_decisions_names_the_flag(run, tmp_path):
    bare = tmp_path / "bare"
    shutil.copytree(run, bare, ignore=shutil.ignore_patterns(rec.FOLDER))
    p = cli("replay", str(bare), "--out", str(tmp_path / "x.gif"))
    one_line_error(p, "--record-decisions")
    assert not (tmp_path / "x.gif").exists()


@pytest.mark.sumo
@pytest.mark.parametrize("name", ["run.avi", "run", "run.png"])
def test_wrong_suffix(run, tmp_path, name):
    one_line_error(cli("replay", str(run), "--out", str(tmp_path / name)), ".mp4 or .gif")


@pytest.mark.sumo
@pytest.mark.parametrize(("option", "value"), [("--every", "0"), ("--fps", "0"), ("--fps", "60"), ("--fps", "nan")])
def test_bad_rate(run, tmp_path, capsys, option, value):
    assert main(["replay", str(run), "--out", str(tmp_path / "x.gif"), option, value]) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and err[0].startswith(f"error: {option} ") and not (tmp_path / "x.gif").exists()
