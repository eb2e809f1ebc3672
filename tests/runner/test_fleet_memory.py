"""Memory of long fleet runs (issue 39): what the egos that came and went freed goes back to the system."""

from __future__ import annotations

import pytest

from conftest import SCENARIOS
from sumo_ethics import heap
from sumo_ethics.config import FleetSpec, RunConfig
from sumo_ethics.runner import fleet
from sumo_ethics.runner.fleet import run_fleet


def _resident_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * 4096 / 1e6


@pytest.mark.skipif(not heap.available(), reason="the C library cannot trim its heap (not glibc)")
def test_trim_gives_the_heap_freed_around_pinned_chunks_back():
    # 40 MB of 2 kB chunks (over pymalloc's 512 bytes: glibc's heap), one in 50 kept: the rest is
    # free heap that glibc keeps resident, its top pinned, until it is trimmed
    chunks = [bytes(2000) for _ in range(20_000)]
    kept = chunks[::50]
    del chunks
    before = _resident_mb()
    assert heap.trim()
    assert before - _resident_mb() > 15.0
    assert len(kept) == 400


@pytest.mark.sumo
def test_a_fleet_run_trims_the_heap_as_it_goes(tmp_path, monkeypatch):
    calls: list[float] = []
    trim = heap.trim

    def counted() -> bool:
        calls.append(fleet.session.sim_time())
        return trim()

    monkeypatch.setattr(fleet.heap, "trim", counted)
    rc = RunConfig(scenario=SCENARIOS / "urban_grid" / "urban_grid.sumocfg", out=tmp_path / "run", progress=False,
                   end=25.0, fleet=FleetSpec(penetration=1.0, shares=(("baseline", 1.0),)))
    summary = run_fleet(rc)
    assert summary.data["fleet"]["egos"] > 5
    # every TRIM_EVERY simulated seconds from the takeover on: twice in 25 s
    assert len(calls) == 2
    assert calls[1] - calls[0] == pytest.approx(fleet.TRIM_EVERY)
