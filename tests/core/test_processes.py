"""processes.run_each: the one process-per-run executor of evaluate, sweeps and dataset recording."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from functools import partial

import psutil
import pytest

from sumo_ethics.processes import died, one_line, run_each

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="needs the forkserver start method")


def _job(n: int) -> int:
    """A job: n squared after a short sleep that makes the later jobs finish first; -1 dies with exit
    code 3, -2 raises."""
    if n == -1:
        os._exit(3)
    if n == -2:
        raise ValueError("no square for -2")
    time.sleep(0.05 * (4 - n % 4))
    return n * n


def _row(job: int, why: str) -> dict:
    return {"job": job, "failed": why}


def test_a_crashed_child_is_a_row_naming_its_exit_code_and_the_others_finish():
    results = dict(run_each(_job, [1, -1, 2, -2, 3], 2, on_crash=_row,
                            on_error=lambda job, exc: _row(job, one_line(exc))))
    assert results == {1: 1, 2: 4, 3: 9, -1: {"job": -1, "failed": "run process died (exit code 3)"},
                       -2: {"job": -2, "failed": "ValueError: no square for -2"}}
    assert died(-9) == "run process died (killed by signal 9)"


def test_the_results_are_the_same_with_one_and_two_workers_and_ordered_keeps_the_jobs_order():
    jobs = list(range(8))
    one = list(run_each(_job, jobs, 1, ordered=True))
    two = list(run_each(_job, jobs, 2, ordered=True))
    assert one == two == [(n, n * n) for n in jobs]
    as_finished = [job for job, _ in run_each(_job, [0, 3], 2)]  # 0 sleeps 0.2 s, 3 sleeps 0.05 s
    assert as_finished == [3, 0]


def test_without_callbacks_a_crash_or_an_error_is_raised_and_the_other_processes_are_killed():
    with pytest.raises(RuntimeError, match=r"^run process died \(exit code 3\)$"):
        list(run_each(_job, [-1], 1))
    before = _run_processes(os.getpid())
    with pytest.raises(ValueError, match="no square for -2"):
        list(run_each(partial(_slow_or_raise, 30.0), [0, -2], 2))  # 0 sleeps 30 s: killed when -2 raises
    assert not _alive(_run_processes(os.getpid()) - before)


def _slow_or_raise(seconds: float, n: int) -> int:
    if n == -2:
        time.sleep(0.5)  # the other one is running by then
        raise ValueError("no square for -2")
    time.sleep(seconds)
    return n


def _run_processes(pid: int) -> set[int]:
    """The live children of ``pid``'s forkserver."""
    out: set[int] = set()
    for child in psutil.Process(pid).children():
        try:
            if any("forkserver" in part for part in child.cmdline()):
                out |= {p.pid for p in child.children()}
        except psutil.Error:
            continue
    return out


def _alive(pids: set[int]) -> set[int]:
    alive = set()
    for pid in pids:
        try:
            if psutil.Process(pid).status() != psutil.STATUS_ZOMBIE:
                alive.add(pid)
        except psutil.NoSuchProcess:
            continue
    return alive


CTRL_C_WHILE_STARTING = '''
import multiprocessing.forkserver, os, signal, sys, time
from sumo_ethics.processes import run_each

signal.signal(signal.SIGINT, signal.default_int_handler)  # a terminal's Ctrl-C, even under a background shell
real = multiprocessing.forkserver.connect_to_new_process

def forked_then_ctrl_c(fds):  # the server has forked the child; its job is not written yet
    out = real(fds)
    os.kill(os.getpid(), signal.SIGINT)
    time.sleep(0.2)  # a Ctrl-C not held is raised in here, and the child reads an empty pipe
    return out

multiprocessing.forkserver.connect_to_new_process = forked_then_ctrl_c
try:
    list(run_each(time.sleep, [30.0], 1))
except KeyboardInterrupt:
    print("interrupted", flush=True)
time.sleep(1.0)  # a child that got no job prints its traceback by now
'''


def test_a_ctrl_c_while_a_process_starts_waits_until_it_has_started():
    """Starting from the forkserver is two steps (fork, then the job written to the child): a Ctrl-C
    between them left the child printing ``EOFError: Ran out of input``. Held, it is raised once
    the process is started and listed, and the process is killed."""
    out = subprocess.run([sys.executable, "-c", CTRL_C_WHILE_STARTING], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "interrupted", out.stderr
    assert "Error" not in out.stderr and "Traceback" not in out.stderr, out.stderr


def _started(parent: subprocess.Popen, count: int) -> set[int]:
    deadline = time.monotonic() + 60
    children: set[int] = set()
    while time.monotonic() < deadline and len(children) < count and parent.poll() is None:
        children = _run_processes(parent.pid)
        time.sleep(0.05)
    assert len(children) == count, "the run processes did not start"
    time.sleep(0.5)  # in their jobs now
    return children


def _gone(children: set[int]) -> None:
    deadline = time.monotonic() + 10
    while _alive(children) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not _alive(children), "a run process outlived its parent"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the parent-death signal is Linux's")
def test_the_children_die_with_a_parent_killed_with_kill_9():
    parent = subprocess.Popen([sys.executable, "-c", "import time\nfrom sumo_ethics.processes import run_each\n"
                               "list(run_each(time.sleep, [60.0, 60.0], 2))\n"])
    children = _started(parent, 2)
    parent.kill()
    parent.wait(timeout=10)
    _gone(children)


def test_sigterm_stops_the_parent_as_ctrl_c_does_and_kills_its_children():
    """The children never see SIGTERM (nor Ctrl-C): sent to the whole process group, only the
    parent takes it, as Terminated, and kills them."""
    code = ("import time\nfrom sumo_ethics.errors import Terminated\nfrom sumo_ethics.processes import run_each\n"
            "try:\n    list(run_each(time.sleep, [60.0, 60.0], 2))\nexcept Terminated:\n    print('terminated')\n")
    parent = subprocess.Popen([sys.executable, "-c", code], start_new_session=True, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True)
    children = _started(parent, 2)
    os.killpg(parent.pid, signal.SIGTERM)
    out, err = parent.communicate(timeout=30)
    assert parent.returncode == 0 and out.strip() == "terminated" and not err, err
    _gone(children)


@pytest.mark.sumo
def test_an_evaluation_keeps_a_row_for_a_run_whose_process_is_killed(tmp_path):
    """evaluate through run_each: the run process of the first scenario killed with SIGKILL (as the
    OOM killer would) is an error row naming the signal; the second scenario runs on."""
    import threading
    from pathlib import Path

    from sumo_ethics.suite.evaluate import parse_planners, run_suite

    suite = Path(__file__).resolve().parents[2] / "scenarios" / "suite"
    rows: list[dict] = []
    before = _run_processes(os.getpid())
    worker = threading.Thread(target=lambda: rows.extend(run_suite([suite / "s0000", suite / "s0001"],
                                                                   parse_planners(["baseline"]), tmp_path, workers=1)))
    worker.start()
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and not (_alive(_run_processes(os.getpid())) - before):
        time.sleep(0.02)
    (first,) = _alive(_run_processes(os.getpid())) - before
    os.kill(first, signal.SIGKILL)
    worker.join(timeout=300)
    assert [(r["scenario"], r["planner"]) for r in rows] == [("s0000", "baseline"), ("s0001", "baseline")]
    assert rows[0]["status"] == "error" and rows[0]["message"] == "run process died (killed by signal 9)"
    assert rows[0]["network"] and rows[1]["status"] in ("completed", "collision", "timeout"), rows


def test_a_long_temporary_folder_does_not_stop_the_forkserver(tmp_path):
    """The forkserver listens on a Unix socket made in the temporary folder, and an AF_UNIX path holds
    at most 107 bytes: under a TMPDIR of 150 characters the socket goes to /tmp, and the jobs still
    see TMPDIR as theirs."""
    long_tmp = tmp_path / ("t" * 60) / ("u" * 60)
    long_tmp.mkdir(parents=True)
    assert len(str(long_tmp)) > 120
    code = ("import tempfile\nfrom sumo_ethics.processes import run_each\n"  # a folder the job makes in its TMPDIR
            "print(list(run_each(tempfile.mkdtemp, ['-job'], 1))[0][1])\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         env={**os.environ, "TMPDIR": str(long_tmp)})
    assert out.returncode == 0, out.stderr[-1000:]
    made = out.stdout.strip()
    assert os.path.dirname(made) == str(long_tmp) and made.endswith("-job"), made
