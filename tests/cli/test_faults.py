"""Fault injection: runs killed by SIGTERM and SIGKILL at several points, then read back; a sweep
whose parent is killed leaves no run process behind; a full disk gives one line."""

from __future__ import annotations

import json
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest

from sumo_ethics.analysis import load
from sumo_ethics.record.reader import read_table, recover_summary
from sumo_ethics.record.writer import chunk_steps

ROOT = Path(__file__).resolve().parents[2]
TESTBED = ROOT / "scenarios" / "testbed" / "testbed.sumocfg"
URBAN = ROOT / "scenarios" / "urban" / "urban.sumocfg"
CHUNK = chunk_steps(0.1)  # the testbed's 0.1 s steps: 20 steps per chunk

# the real CLI on real SUMO, with the baseline controller slowed down to about 4 ms a step so
# that the kill lands where the test wants it
SLOW_RUN = """
import sys, time
import sumo_ethics.runner as runner
from sumo_ethics.cli import main
from sumo_ethics.plan.baseline import RouteFollower

class Slow(RouteFollower):
    def act(self, scene):
        time.sleep(0.004)
        return super().act(scene)

runner.make_controller = lambda cfg: Slow()
sys.exit(main(sys.argv[1:]))
"""


def start_run(out: Path, depart: float = 2.0) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", SLOW_RUN, "run", str(TESTBED), "--controller", "baseline",
                             "--ego-depart", str(depart), "--seed", "1", "--end", "300", "--quiet", "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def wait_for(cond, proc: subprocess.Popen, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        assert proc.poll() is None, f"the run ended before the kill point: {proc.communicate()}"
        assert time.monotonic() < deadline, "kill point not reached"
        time.sleep(0.01)


def chunks(out: Path) -> int:
    """Chunks of steps flushed so far (read while the run writes)."""
    return len(read_table(out, "steps")) // CHUNK if (out / "partial").is_dir() else 0


def assert_contiguous(steps) -> None:
    assert steps.step.tolist() == list(range(1, len(steps) + 1))


@pytest.mark.sumo
@pytest.mark.parametrize("point", [0, 3])  # chunks on disk when the signal arrives (0: before the takeover)
def test_sigterm_writes_everything_and_an_interrupted_summary(tmp_path, point):
    out = tmp_path / "run"
    proc = start_run(out, depart=60.0 if point == 0 else 2.0)
    if point == 0:
        wait_for(lambda: (out / "config.json").exists(), proc)
    else:
        wait_for(lambda: chunks(out) >= point, proc)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143
    lines = err.strip().splitlines()
    assert lines == [f"error: terminated (SIGTERM); the steps so far and a summary (status interrupted) are "
                     f"written to {out}"], err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "interrupted" and "SIGTERM" in summary["message"]
    assert not (out / "partial").exists()
    steps = read_table(out, "steps").to_pandas()
    assert len(steps) == summary["steps"] >= point * CHUNK  # every step, the unflushed ones too
    assert_contiguous(steps)
    assert len(read_table(out, "timings")) == len(steps)
    res = load(out)
    assert res.runs.status.tolist() == ["interrupted"] and not res.runs.incomplete.iloc[0]


@pytest.mark.sumo
@pytest.mark.parametrize("point", [1, 3])
def test_sigkill_leaves_readable_chunks_up_to_the_last_flush(tmp_path, capfd, point):
    out = tmp_path / "run"
    proc = start_run(out)
    wait_for(lambda: chunks(out) >= point, proc)
    proc.kill()
    proc.communicate(timeout=30)
    assert not (out / "summary.json").exists()
    steps = read_table(out, "steps").to_pandas()
    assert len(steps) >= point * CHUNK and len(steps) % CHUNK == 0  # whole chunks: all but the last
    assert_contiguous(steps)
    s = recover_summary(out)
    assert s["status"] == "incomplete" and s["reconstructed"] and s["steps"] == len(steps)
    res = load(out)  # what analysis sees: the rows, and the run marked incomplete
    assert res.runs.status.tolist() == ["incomplete"] and res.runs.incomplete.iloc[0]
    assert len(res.steps) == len(steps)
    from sumo_ethics.cli import main

    capfd.readouterr()
    assert main(["analyze", str(out)]) == 0
    printed = capfd.readouterr().out
    assert "incomplete (killed before it finished)" in printed and f"{len(steps)} steps recorded" in printed
    # a new run into the same folder is refused: the killed run's rows are kept
    assert main(["run", str(TESTBED), "--out", str(out), "--quiet"]) == 2
    assert "--overwrite" in capfd.readouterr().err
    assert len(read_table(out, "steps")) == len(steps)


@pytest.mark.sumo
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_killed_sweep_parent_leaves_no_run_alive(tmp_path, sig):
    out = tmp_path / "sw"
    code = "import sys; from sumo_ethics.cli import main; sys.exit(main(sys.argv[1:]))"
    # the urban scenario's runs drive for about 8 s of wall time each: on the testbed (2.8 s) both
    # runs once finished between their start and the signal in a CI run
    proc = subprocess.Popen([sys.executable, "-c", code, "sweep", str(URBAN), "--omega-u", "1", "--seeds", "0-1",
                             "--end", "120", "--ego-depart", "2", "--predictor", "cv", "--workers", "2", "--quiet",
                             "--out", str(out)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    runs = out / "runs"
    wait_for(lambda: runs.exists() and len(list(runs.glob(".*.tmp-*"))) == 2, proc, timeout=120)
    family = psutil.Process(proc.pid).children(recursive=True)  # the forkserver and the run processes
    run_pids = {int(p.name.split(".tmp-")[1].split("-")[0]) for p in runs.glob(".*.tmp-*")}
    assert run_pids <= {p.pid for p in family}
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=30)
    if sig == signal.SIGTERM:  # handled like Ctrl-C: runs stopped, manifest written, one line
        assert proc.returncode == 143 and err.strip().startswith("error: terminated") and len(err.splitlines()) == 1
        # the runs still going are pending again; one may have finished just before the signal
        counts = json.loads((out / "manifest.json").read_text())["counts"]
        assert counts in ({"pending": 2}, {"completed": 1, "pending": 1}), counts
    deadline = time.monotonic() + 5
    while (alive := [p for p in family if _running(p)]) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not alive, f"still running 5 s after the sweep was killed: {alive}"
    assert list(runs.glob(".*.tmp-*")), list(runs.iterdir())  # the killed runs' temporary folders ...
    (out / ".manifest.json.tmp-99999").write_text("{")  # ... and a manifest temp file of a killed write
    from sumo_ethics.sweep import clean_temporaries

    clean_temporaries(out)  # what the next start does first
    assert not list(runs.glob(".*")) and not list(out.glob(".manifest.json.tmp-*"))


def _running(p: psutil.Process) -> bool:
    try:
        return p.status() != psutil.STATUS_ZOMBIE  # a zombie is dead, only not yet reaped by its new parent
    except psutil.NoSuchProcess:
        return False


def _limit_file_size(nbytes: int):
    def set_limit() -> None:  # Python ignores SIGXFSZ: a write past the limit fails with EFBIG
        resource.setrlimit(resource.RLIMIT_FSIZE, (nbytes, nbytes))
    return set_limit


@pytest.mark.sumo
@pytest.mark.parametrize("command", ["run", "sweep"])
def test_full_disk_gives_one_line(tmp_path, command):
    """Writes fail past 16 kB per file (RLIMIT_FSIZE, no root needed): the merged steps.parquet
    of the run cannot be written."""
    out = tmp_path / "o"
    args = [TESTBED, "--controller", "baseline", "--ego-depart", "2", "--end", "60", "--quiet", "--out", out]
    if command == "sweep":
        args += ["--seeds", "0", "--workers", "1"]
    p = subprocess.run([sys.executable, "-m", "sumo_ethics.cli", command, *map(str, args)], capture_output=True,
                       text=True, timeout=120, preexec_fn=_limit_file_size(16_000))
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 1 and len(lines) == 1 and "Traceback" not in p.stderr, p.stderr
    assert lines[0].startswith("error: ") and "File too large" in lines[0]
