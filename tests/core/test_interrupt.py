"""interrupt.signals_held: a signal that arrives inside the block waits until it is left, also
when another thread takes it (numpy's BLAS threads do not block signals); the SIGTERM of a run
that is writing its outputs (sigterm_deferred) likewise."""

from __future__ import annotations

import os
import signal
import threading
import time

import pytest

from sumo_ethics.errors import Terminated
from sumo_ethics.interrupt import signals_held, sigterm_as_interrupt, sigterm_deferred

pytestmark = pytest.mark.skipif(not hasattr(signal, "pthread_kill"), reason="needs POSIX signals")


class Arrived(Exception):
    pass


def _raise_arrived(signum, frame):
    raise Arrived


def _other_thread() -> tuple[threading.Thread, threading.Event]:
    stop = threading.Event()
    t = threading.Thread(target=stop.wait, daemon=True)
    t.start()
    return t, stop


@pytest.mark.parametrize("to_other_thread", [False, True])
def test_a_signal_inside_the_block_arrives_when_it_is_left(to_other_thread):
    old = signal.signal(signal.SIGUSR1, _raise_arrived)
    other, stop = _other_thread()
    reached = []
    try:
        with pytest.raises(Arrived):
            with signals_held(signal.SIGUSR1):
                if to_other_thread:  # as when a BLAS thread takes a process-directed signal
                    signal.pthread_kill(other.ident, signal.SIGUSR1)
                else:
                    os.kill(os.getpid(), signal.SIGUSR1)
                t0 = time.monotonic()
                while time.monotonic() - t0 < 0.2:  # Python checks for signals all along here
                    pass
                reached.append("end of block")
        assert reached == ["end of block"]  # the handler ran after the block, not inside it
        assert signal.getsignal(signal.SIGUSR1) is _raise_arrived  # the handler is back
        assert signal.SIGUSR1 not in signal.pthread_sigmask(signal.SIG_BLOCK, set())  # not blocked any more
    finally:
        stop.set()
        signal.signal(signal.SIGUSR1, old)


def test_nothing_held_nothing_raised():
    old = signal.signal(signal.SIGUSR1, _raise_arrived)
    try:
        with signals_held(signal.SIGUSR1):
            pass
        assert signal.getsignal(signal.SIGUSR1) is _raise_arrived
    finally:
        signal.signal(signal.SIGUSR1, old)


def test_sigterm_while_outputs_are_written_ends_the_run_after_the_writing(tmp_path):
    other, stop = _other_thread()
    reached = []
    try:
        with pytest.raises(Terminated):
            with sigterm_as_interrupt():
                with sigterm_deferred():
                    signal.pthread_kill(other.ident, signal.SIGTERM)
                    (tmp_path / "out.bin").write_bytes(b"x" * 100_000)
                    t0 = time.monotonic()
                    while time.monotonic() - t0 < 0.2:
                        pass
                    reached.append("written")
        assert reached == ["written"] and (tmp_path / "out.bin").stat().st_size == 100_000
    finally:
        stop.set()
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL
