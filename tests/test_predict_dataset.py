"""Prediction dataset from a real (short) SUMO run."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from sumo_ethics.predict import features as F
from sumo_ethics.predict.dataset import build_dataset, rebuild_samples, split_seeds

ROOT = Path(__file__).resolve().parents[1]
URBAN = ROOT / "scenarios" / "urban" / "urban.sumocfg"


def test_split_is_by_seed():
    s = split_seeds(list(range(1, 11)))
    assert s == {"train": [1, 2, 3, 4, 5, 6], "val": [7, 8], "test": [9, 10]}
    with pytest.raises(ValueError):
        split_seeds([1, 2])


@pytest.mark.sumo
@pytest.mark.skipif(not URBAN.exists(), reason="bundled urban scenario missing")
def test_build_dataset_from_sumo(tmp_path):
    out = build_dataset([URBAN], [1, 2, 3], tmp_path / "ds", sim_seconds=40.0, anchor_every=1.0)
    traj = pd.read_parquet(out / "trajectories.parquet")
    assert {"run_id", "seed", "scenario", "time", "agent_id", "cls", "x", "y", "yaw", "speed", "length", "width"} <= set(traj.columns)
    assert sorted(traj["seed"].unique()) == [1, 2, 3]
    # 10 Hz, and positions do not jump (lane changes take 2 s)
    one = traj[traj["run_id"] == 0].sort_values(["agent_id", "time"])
    dt = one.groupby("agent_id")["time"].diff().dropna()
    assert np.allclose(dt.median(), 0.1)
    step = np.hypot(one.groupby("agent_id")["x"].diff(), one.groupby("agent_id")["y"].diff()).dropna()
    assert step.quantile(0.999) < 5.0
    meta = json.loads((out / "split.json").read_text())
    assert meta["split"] == {"train": [1], "val": [2], "test": [3]}
    with np.load(out / "samples.npz") as z:
        assert z["tgt_hist"].shape[1:] == (F.HIST_STEPS, 2)
        assert z["fut"].shape[1:] == (F.FUT_STEPS, 2)
        assert z["nbr_ptr"][-1] == len(z["nbr_hist"])
        np.testing.assert_allclose(z["tgt_hist"][:, -1], 0.0, atol=1e-4)  # target frame
        assert set(np.unique(z["split"])) <= {0, 1, 2}
        assert len(z["nbr_yaw"]) == len(z["nbr_hist"]) and np.all(np.abs(z["nbr_yaw"]) <= np.pi + 1e-6)
        first = {k: z[k] for k in z.files}
    # samples derived again from the recorded trajectories (after a layout change) equal the first ones
    again = rebuild_samples(out, tmp_path / "ds2")
    with np.load(again / "samples.npz") as z:
        assert sorted(z.files) == sorted(first) and all(np.array_equal(z[k], first[k]) for k in z.files)
    assert json.loads((again / "split.json").read_text())["split"] == meta["split"]
    with pytest.raises(ValueError, match="out must differ"):
        rebuild_samples(out, out)


def _children(pid: int) -> list[int]:
    """Process ids whose parent is ``pid`` (Linux /proc)."""
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.append(int(stat.parent.name))
    return out


def _children_alive(pids: list[int]) -> list[int]:
    """Those of ``pids`` still running: a zombie has ended (an init that reaps no orphans, as in
    some containers, leaves multiprocessing's resource tracker so)."""
    alive = []
    for pid in pids:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if state != "Z":
            alive.append(pid)
    return alive


def _long_dataset_command(out: Path, env: dict | None = None, suite: bool = False):
    """``sumo-ethics dataset`` of four 900 s urban runs (``suite``: of four suite scenarios) on two
    workers, in its own process group (Ctrl-C restored: background shells start their children
    with it ignored)."""
    import signal
    import subprocess
    import sys

    what = ([str(ROOT / "scenarios" / "urban" / "urban.sumocfg"), "--seeds", "1-4", "--sim-seconds", "900"] if not suite
            else [a for k in range(4) for a in ("--suite", str(ROOT / "scenarios" / "suite" / f"s000{k}"))])
    args = [sys.executable, "-m", "sumo_ethics.cli", "dataset", *what, "--out", str(out), "--workers", "2"]
    return subprocess.Popen(args, start_new_session=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env)


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc")
def test_ctrl_c_while_dataset_workers_start_prints_one_line_and_leaves_no_process(tmp_path):
    """A terminal's Ctrl-C reaches the whole process group. The spawned SUMO workers used to print
    KeyboardInterrupt tracebacks when it came while they were still importing; now they do not see
    it, and the command terminates them and prints one line."""
    import os
    import signal
    import time

    proc = _long_dataset_command(tmp_path / "ds")
    deadline = time.monotonic() + 60
    workers: set[int] = set()
    while time.monotonic() < deadline and proc.poll() is None and not workers:
        workers = _spawned_workers_alive(proc.pid)  # a SUMO worker, not the resource tracker
        time.sleep(0.02)
    assert workers, "no worker process started"
    time.sleep(0.3)  # the worker is importing now
    workers = sorted(workers | set(_children(proc.pid)))
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130 and err.strip() == "error: interrupted; no dataset is written", err[-2000:]
    time.sleep(0.5)
    assert not [p for p in _children_alive(workers)], "a worker outlived the command"
    assert not (tmp_path / "ds").exists()


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc")
@pytest.mark.parametrize("how", ["ctrl-c", "sigterm", "ctrl-c-suite"])
def test_a_dataset_stopped_mid_run_leaves_no_scratch_folder_and_no_worker(tmp_path, how):
    """Ctrl-C (to the process group, as a terminal sends it) or SIGTERM (to the command alone, as
    a batch system sends it) mid-run: one line, every worker terminated, and the runs' scratch
    folders (the scenario's own outputs) removed. A terminated worker cannot remove its own, so the
    command removes them once its workers are gone; they used to stay, one per running worker. And
    SIGTERM used to end the command alone, its workers simulating on."""
    import os
    import signal
    import time

    tmp = tmp_path / "tmp"
    tmp.mkdir()
    proc = _long_dataset_command(tmp_path / "ds", env={**os.environ, "TMPDIR": str(tmp)}, suite=how.endswith("suite"))

    def running() -> bool:  # a worker runs SUMO in its scratch folder
        return any(p.is_dir() for p in tmp.glob("*/*"))

    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and proc.poll() is None and not running():
        time.sleep(0.05)
    assert running(), "no run started"
    time.sleep(1.0)
    workers = sorted(_children(proc.pid))
    if how.startswith("ctrl-c"):
        os.killpg(proc.pid, signal.SIGINT)
    else:
        os.kill(proc.pid, signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    want = (130, "error: interrupted") if how.startswith("ctrl-c") else (143, "error: terminated (SIGTERM)")
    assert proc.returncode == want[0] and err.strip() == f"{want[1]}; no dataset is written", err[-2000:]
    time.sleep(0.5)
    assert not [p for p in _children_alive(workers)], "a worker outlived the command"
    assert sorted(p.name for p in tmp.iterdir()) == [], "scratch folders left behind"
    assert not (tmp_path / "ds").exists()


def _spawned_workers_alive(pid: int) -> set[int]:
    """Live children of ``pid`` that are multiprocessing spawn workers (not its resource tracker)."""
    out = set()
    for child in _children_alive(_children(pid)):
        try:
            if b"spawn_main" in Path(f"/proc/{child}/cmdline").read_bytes():
                out.add(child)
        except OSError:
            continue
    return out


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc")
def test_isolated_map_terminates_its_running_workers_when_interrupted():
    """Two workers sleeping 60 s; an exception in the caller (here from a timer signal, as a
    Ctrl-C) ends them at once: they never see Ctrl-C themselves, so nothing else would."""
    import os
    import signal
    import time

    from sumo_ethics.predict.dataset import isolated_map

    class Stop(Exception):
        pass

    def stop(signum, frame):
        raise Stop

    before = _spawned_workers_alive(os.getpid())
    old = signal.signal(signal.SIGALRM, stop)
    jobs = isolated_map(time.sleep, [60.0, 60.0, 60.0], 2, lambda job: RuntimeError("crashed"))
    t0 = time.monotonic()
    try:
        signal.setitimer(signal.ITIMER_REAL, 4.0)  # the two workers have started by then
        with pytest.raises(Stop):
            next(jobs)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        signal.signal(signal.SIGALRM, old)
    assert time.monotonic() - t0 < 15.0
    assert not _spawned_workers_alive(os.getpid()) - before
