"""Prediction dataset from a real (short) SUMO run."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from sumo_ethics.predict import features as F
from sumo_ethics.predict.samples import rebuild_samples, split_seeds
from sumo_ethics.recording.build import build_dataset

ROOT = Path(__file__).resolve().parents[2]
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


def _family(pid: int) -> list[int]:
    """Every descendant of ``pid``: its forkserver and the run processes forked from it, too."""
    out, todo = [], _children(pid)
    while todo:
        child = todo.pop()
        out.append(child)
        todo += _children(child)
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


@pytest.mark.sumo
@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc")
def test_ctrl_c_while_dataset_workers_start_prints_one_line_and_leaves_no_process(tmp_path):
    """A terminal's Ctrl-C reaches the whole process group. The SUMO run processes used to print
    KeyboardInterrupt tracebacks when it came while they were still importing; now they do not see
    it, and the command terminates them and prints one line."""
    import os
    import signal
    import time

    proc = _long_dataset_command(tmp_path / "ds")
    deadline = time.monotonic() + 60
    workers: set[int] = set()
    while time.monotonic() < deadline and proc.poll() is None and not workers:
        workers = _run_processes_alive(proc.pid)  # a SUMO run process, not the forkserver or resource tracker
        time.sleep(0.02)
    assert workers, "no worker process started"
    time.sleep(0.3)  # the worker is importing now
    workers = sorted(workers | set(_family(proc.pid)))
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130 and err.strip() == "error: interrupted; no dataset is written", err[-2000:]
    time.sleep(0.5)
    assert not [p for p in _children_alive(workers)], "a worker outlived the command"
    assert not (tmp_path / "ds").exists()


@pytest.mark.sumo
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
        # A temporary folder (a library's own, or a finished run's) can vanish between listing
        # `tmp` and looking inside it; that is not a failure, only a folder to skip.
        for folder in list(tmp.iterdir()):
            try:
                if any(p.is_dir() for p in folder.iterdir()):
                    return True
            except (FileNotFoundError, NotADirectoryError):
                continue
        return False

    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and proc.poll() is None and not running():
        time.sleep(0.05)
    assert running(), f"no run started (exit {proc.poll()}: {proc.stderr.read()[-800:] if proc.poll() is not None else ''})"
    time.sleep(1.0)
    workers = sorted(_family(proc.pid))
    if how.startswith("ctrl-c"):
        os.killpg(proc.pid, signal.SIGINT)
    else:
        os.kill(proc.pid, signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    want = (130, "error: interrupted") if how.startswith("ctrl-c") else (143, "error: terminated (SIGTERM)")
    # a run that finished before the signal (the suite's are short) is kept for a resume, and said so
    line, base = err.strip(), f"{want[1]}; no dataset is written"
    kept = line.startswith(f"{base} (") and "runs finished and are kept in" in line
    assert proc.returncode == want[0] and (line == base or kept), err[-2000:]
    time.sleep(0.5)
    assert not [p for p in _children_alive(workers)], "a worker outlived the command"
    assert sorted(p.name for p in tmp.iterdir()) == [], "scratch folders left behind"
    if kept:
        assert sorted(p.name for p in (tmp_path / "ds").iterdir()) == ["partial"]
    else:
        assert not (tmp_path / "ds").exists()


def _run_processes_alive(pid: int) -> set[int]:
    """Live run processes of ``pid``: the children of its forkserver (not the server, not its
    resource tracker)."""
    out = set()
    for child in _children_alive(_children(pid)):
        try:
            if b"forkserver" in Path(f"/proc/{child}/cmdline").read_bytes():
                out |= set(_children_alive(_children(child)))
        except OSError:
            continue
    return out


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc")
def test_run_each_kills_its_running_processes_when_interrupted():
    """Two workers sleeping 60 s; an exception in the caller (here from a timer signal, as a
    Ctrl-C) ends them at once: they never see Ctrl-C themselves, so nothing else would."""
    import os
    import signal
    import time

    from sumo_ethics.processes import run_each

    class Stop(Exception):
        pass

    def stop(signum, frame):
        raise Stop

    before = _run_processes_alive(os.getpid())
    old = signal.signal(signal.SIGALRM, stop)
    jobs = run_each(time.sleep, [60.0, 60.0, 60.0], 2)
    t0 = time.monotonic()
    try:
        signal.setitimer(signal.ITIMER_REAL, 4.0)  # the two workers have started by then
        with pytest.raises(Stop):
            next(jobs)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        signal.signal(signal.SIGALRM, old)
    assert time.monotonic() - t0 < 15.0
    assert not _run_processes_alive(os.getpid()) - before


def test_run_store_keeps_finished_runs_whole_and_refuses_another_plan(tmp_path):
    """The partial folder of a dataset build: nothing until a run ends; a run's rows and lane graph
    come back as given; a write cut short (a .part file) is not a finished run and is cleared; the
    finished runs of another build are refused in one line, never mixed or deleted."""
    from sumo_ethics.errors import ConfigError
    from sumo_ethics.recording.runstore import RunStore, kept_runs

    out = tmp_path / "ds"
    plan = {"runs": [{"run_id": 0, "seed": 1, "scale": 0.7}, {"run_id": 1, "seed": 2, "scale": 1.0}], "suite": []}
    store = RunStore.open(out, plan)
    assert store.done() == set() and not out.exists() and kept_runs(out) == (0, 0)
    rows = pd.DataFrame({"run_id": np.int32([1, 1]), "agent_id": ["a", "b"], "x": [0.5, -1.25],
                         "speed": np.float32([3.0, 0.0]), "cls": np.int8([0, 5])})
    from sumo_ethics.predict.features import LaneGraph

    lane_graph = LaneGraph.build(["e_0", "e_1"], [np.array([[0.0, 0.0], [50.0, 0.1]]), np.array([[0.0, 3.2], [50.0, 3.2]])],
                                 [13.89, 13.89], [(), ()])
    store.put(1, rows, lane_graph)
    assert store.done() == {1} and kept_runs(out) == (1, 2)
    back, graph = RunStore.open(out, plan).get(1)
    pd.testing.assert_frame_equal(back, rows)
    assert list(back.dtypes) == list(rows.dtypes) and graph.ids == ("e_0", "e_1")
    assert np.array_equal(graph.shapes[0], lane_graph.shapes[0]) and graph.left.tolist() == [1, -1]
    (store.folder / "run_000000.parquet.part").write_bytes(b"cut short")
    assert RunStore.open(out, plan).done() == {1}
    assert not list(store.folder.glob("*.part"))
    other = {**plan, "runs": plan["runs"][:1]}
    with pytest.raises(ConfigError, match="holds the finished runs of another dataset build"):
        RunStore.open(out, other)
    assert store.done() == {1}
    (store.folder / "run_000001.parquet").write_bytes(b"")  # a disk that lost the file
    with pytest.raises(ConfigError, match="the kept run .*run_000001.parquet cannot be read .*delete it"):
        store.get(1)
    store.remove()
    assert not store.folder.exists() and sorted(p.name for p in out.iterdir()) == []


@pytest.mark.sumo
@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc")
def test_a_stopped_dataset_keeps_its_finished_runs_and_the_same_command_resumes_them(tmp_path, monkeypatch, capsys):
    """SIGTERM after the first of three runs has finished: the line says it is kept, the build of
    other runs into that folder is refused, and the same command simulates only the two others and
    writes the very bytes of a build never stopped."""
    import os
    import signal
    import subprocess
    import sys
    import time

    import sumo_ethics.recording.build as D
    from sumo_ethics.cli import main

    out = tmp_path / "ds"
    args = ["dataset", str(URBAN), "--seeds", "1-3", "--sim-seconds", "60", "--out"]
    proc = subprocess.Popen([sys.executable, "-m", "sumo_ethics.cli", *args, str(out)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    first = out / "partial" / "run_000000.parquet"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None and not first.exists():
        time.sleep(0.05)
    assert first.exists(), "the first run did not finish"
    os.kill(proc.pid, signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143 and err.strip() == (
        f"error: terminated (SIGTERM); no dataset is written (1 of 3 runs finished and are kept in {out / 'partial'}: "
        "the same command resumes from them)"), err[-2000:]
    kept = first.read_bytes()
    assert sorted(p.name for p in out.iterdir()) == ["partial"]
    (out / "trajectories.parquet").write_bytes(b"cut short")  # as if stopped while the dataset was written

    assert main([*args[:3], "1-4", *args[4:], str(out)]) == 2  # another build (seeds 1-4) into that folder
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "holds the finished runs of another dataset build" in err[0], err
    assert first.read_bytes() == kept

    simulated: list[int] = []
    real_run_each = D.run_each

    def watched(fn, jobs, workers, **kw):
        simulated.extend(job.run_id for job in jobs if isinstance(job, D.RunSpec))
        return real_run_each(fn, jobs, workers, **kw)

    monkeypatch.setattr(D, "run_each", watched)
    assert main([*args, str(out)]) == 0
    assert simulated == [1, 2] and not (out / "partial").exists()
    assert capsys.readouterr().err.strip() == f"resuming: 1 of 3 runs finished before and are kept in {out / 'partial'}"
    assert main([*args, str(tmp_path / "fresh")]) == 0
    assert simulated == [1, 2, 0, 1, 2]
    for name in ("trajectories.parquet", "lane_graphs.json.gz"):
        assert (out / name).read_bytes() == (tmp_path / "fresh" / name).read_bytes(), name
    with np.load(out / "samples.npz") as a, np.load(tmp_path / "fresh" / "samples.npz") as b:
        assert sorted(a.files) == sorted(b.files) and all(np.array_equal(a[k], b[k]) for k in a.files)


def test_a_failed_run_names_the_finished_runs_it_keeps(tmp_path, monkeypatch):
    """A SUMO run failing after another one finished: the one line names what is kept and how to
    go on (the kept run is not lost with the failure); with nothing finished, the failure alone."""
    import sumo_ethics.recording.build as D
    from sumo_ethics.errors import SimulationError
    from sumo_ethics.recording.build import dataset_main
    from sumo_ethics.recording.runstore import RunStore

    out = tmp_path / "ds"

    def failing_build(scenarios, seeds, out, finished=1, **kw):
        store = RunStore.open(out, {"runs": [{"run_id": i} for i in range(3)], "suite": []})
        for run_id in range(finished):
            store.put(run_id, pd.DataFrame({"x": [1.0]}), None)
        raise SimulationError("dataset: urban.sumocfg seed 2: SUMO stopped")

    monkeypatch.setattr(D, "build_dataset", failing_build)
    with pytest.raises(SimulationError) as err:
        dataset_main([URBAN], out)
    assert str(err.value) == (f"dataset: urban.sumocfg seed 2: SUMO stopped (1 of 3 runs finished and are kept in "
                              f"{out / 'partial'}: the same command resumes from them)")
    monkeypatch.setattr(D, "build_dataset", lambda *a, **kw: failing_build(*a, finished=0, **kw))
    with pytest.raises(SimulationError, match=r"^dataset: urban.sumocfg seed 2: SUMO stopped$"):
        dataset_main([URBAN], tmp_path / "other")


def test_rows_without_a_position_are_steps_not_seen():
    """Datasets recorded before sim.recorder.on_road hold SUMO's INVALID_DOUBLE_VALUE (-2^30 m) as
    the position of a road user SUMO had not placed yet (a suite hazard's first step, a car leaving
    a parking area): their samples are those of the track without those rows, not a 1.5e9 m jump."""
    from sumo_ethics.predict.samples import samples_from_run

    t = np.round(np.arange(0.0, 20.0, 0.1), 1)
    rows = []
    for k, (y, v) in enumerate(((0.0, 10.0), (3.5, 8.0))):
        rows.append(pd.DataFrame({"time": t, "agent_id": f"v{k}", "cls": np.int8(0), "x": v * t, "y": y,
                                  "yaw": 0.0, "speed": v}))
    clean = pd.concat(rows, ignore_index=True)
    clean = clean[~((clean.agent_id == "v1") & (clean.time < 8.0))]  # v1 appears at 8.0 s
    invalid = -(2.0 ** 30)
    # 8 s without a position (long enough for samples of its own, standing at -2^30 m, were it kept)
    unplaced = pd.DataFrame({"time": np.round(np.arange(0.0, 8.0, 0.1), 1), "agent_id": "v1", "cls": np.int8(0),
                             "x": invalid, "y": invalid, "yaw": 0.0, "speed": invalid})
    a = samples_from_run(clean, anchor_every=1.0)
    b = samples_from_run(pd.concat([unplaced, clean], ignore_index=True), anchor_every=1.0)
    assert len(a["tgt_hist"]) > 0 and sorted(a) == sorted(b)
    assert all(np.array_equal(a[k], b[k]) for k in a)
    assert np.abs(b["tgt_hist"]).max() < 200.0


def test_the_first_worker_of_a_fresh_process_holds_ctrl_c_and_sigterm_too():
    """multiprocessing starts its resource tracker at a process's first worker start, and that
    unblocked SIGINT and SIGTERM just before the worker was spawned: the first worker (the
    dataset's scenario check) printed a KeyboardInterrupt traceback on a terminal's Ctrl-C."""
    import subprocess
    import sys

    code = ("import functools, signal\n"
            "from sumo_ethics.processes import run_each\n"
            "mask = functools.partial(signal.pthread_sigmask, signal.SIG_BLOCK)\n"
            "print(sorted(int(s) for _, blocked in run_each(mask, [[], []], 1) for s in blocked))\n"
            "print(sorted(int(s) for s in signal.pthread_sigmask(signal.SIG_BLOCK, [])))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    workers, caller = out.stdout.split("\n")[:2]
    assert workers == "[2, 2, 15, 15]" and caller == "[]"  # both workers block SIGINT (2) and SIGTERM (15)


def test_a_track_is_cut_where_the_road_user_was_not_seen_or_jumped():
    """A pedestrian who rides a bus (not seen as a pedestrian meanwhile) or whom SUMO places 100 m
    away: its samples after the gap start a new track, instead of a history that bridges the gap
    (in the shipped data: 66 samples with histories reaching 2.5 km back)."""
    from sumo_ethics.predict.samples import samples_from_run, track_pieces

    ids = np.array(["a", "b", "a", "b", "a", "a", "c"], dtype=object)
    codes, names = track_pieces(ids, np.array([0, 0, 1, 1, 3, 4, 2]), np.array([0, 0, 1, 1, 2, 100, 5.0]), np.zeros(7))
    # a: frames 0-1, then after a gap frame 3, then 98 m further at frame 4: three pieces
    assert codes.tolist() == [0, 1, 0, 1, 2, 3, 4] and list(names) == ["a", "b", "a", "a", "c"]
    t = np.round(np.arange(0.0, 20.0, 0.1), 1)
    walk = pd.DataFrame({"time": t, "agent_id": "p", "cls": np.int8(5), "x": 1.2 * t, "y": 0.0, "yaw": 0.0, "speed": 1.2})
    rode = walk[(walk.time < 5.0) | (walk.time >= 8.0)].copy()  # on a bus from 5 to 8 s ...
    rode.loc[rode.time >= 8.0, "x"] += 150.0  # ... that took it 150 m further than walking would
    s = samples_from_run(rode, anchor_every=0.2)
    assert np.abs(s["tgt_hist"]).max() < 1.2 * 3.0 + 0.01  # at most 3 s of walking back
    steps = np.hypot(*np.diff(s["tgt_hist"], axis=1).transpose(2, 0, 1))
    assert steps.max() < 1.2 * 0.2 + 1e-3  # no step of any history faster than the walk


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc")
def test_a_worker_dies_with_its_killed_parent():
    """A dataset killed with kill -9 (or by the OOM killer) left its SUMO workers simulating on:
    they hold SIGINT and SIGTERM blocked, and nothing told them. Now the kernel kills them too."""
    import os
    import signal
    import subprocess
    import sys
    import time

    code = ("import time\nfrom sumo_ethics.processes import run_each\n"
            "list(run_each(time.sleep, [60.0], 1))\n")
    parent = subprocess.Popen([sys.executable, "-c", code])
    deadline = time.monotonic() + 60
    workers: set[int] = set()
    while time.monotonic() < deadline and not workers:
        workers = _run_processes_alive(parent.pid)
        time.sleep(0.05)
    assert workers, "no worker started"
    time.sleep(1.0)  # the worker is in its job now
    os.kill(parent.pid, signal.SIGKILL)
    parent.wait(timeout=10)
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and _children_alive(sorted(workers)):
        time.sleep(0.05)
    assert not _children_alive(sorted(workers)), "a worker outlived its killed parent"
