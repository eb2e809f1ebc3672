"""Leaked or fragmented? The run of ``tools/bench_fleet.py --memory`` (urban_grid, penetration 1,
baseline planners): every 5 simulated seconds Python's allocated blocks (sys.getallocatedblocks),
its small-object arenas and the gc-tracked objects; with ``--trace T`` tracemalloc from T on, its
snapshots at ``--at`` compared by line (top 25) and by traceback for the top lines.

    python tools/probe_fleet_trace.py 150 --trace 60 --at 90,150

Issue 39 (docs/fleets.md). Not sumo_ethics code.
"""

from __future__ import annotations

import argparse
import gc
import sys
import time
import tracemalloc
from pathlib import Path

from bench_fleet import rss_mb
from probe_fleet_rss import hold_run, pymalloc_arenas, run_memory_fleet

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("seconds", type=float)
    ap.add_argument("--trace", type=float, default=-1.0)
    ap.add_argument("--at", default="")
    ap.add_argument("--frames", type=int, default=1)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--dump", default="", help="also dump each snapshot to DUMP.<t>.snap (tracemalloc.Snapshot.load)")
    a = ap.parse_args()
    at = [float(x) for x in a.at.split(",") if x]

    from sumo_ethics.plan.baseline import RouteFollower

    holder = hold_run()
    rows: list[tuple] = []
    st: dict = {"traced": False, "snap": None, "next": 0}
    filt = [tracemalloc.Filter(False, tracemalloc.__file__), tracemalloc.Filter(False, __file__)]

    class Sampled(RouteFollower):
        def act(self, scene):  # type: ignore[no-untyped-def]
            if not rows or scene.time >= rows[-1][0] + 5.0 - 1e-9:
                run = holder["run"]
                rows.append((scene.time, rss_mb(), sys.getallocatedblocks(), pymalloc_arenas(),
                             len(gc.get_objects()), len(run.active), len(run.agents)))
            if a.trace >= 0 and not st["traced"] and scene.time >= a.trace:
                tracemalloc.start(a.frames)
                st["traced"] = True
                st["snap"] = tracemalloc.take_snapshot().filter_traces(filt)
                print(f"tracemalloc started at t={scene.time:.1f}", flush=True)
            if st["traced"] and st["next"] < len(at) and scene.time >= at[st["next"]]:
                snap = tracemalloc.take_snapshot().filter_traces(filt)
                cur, peak = tracemalloc.get_traced_memory()
                run = holder["run"]
                print(f"\n=== t={scene.time:.1f}: traced {cur / 1e6:.1f} MB (peak {peak / 1e6:.1f}); "
                      f"active {len(run.active)}, agents {len(run.agents)}; by line against the last snapshot:")
                stats = snap.compare_to(st["snap"], "lineno")
                for s in stats[:25]:
                    print("   ", s)
                if a.frames > 1:
                    for s in snap.compare_to(st["snap"], "traceback")[:6]:
                        print(f"  {s.size_diff / 1e6:+.3f} MB, {s.count_diff:+d} blocks:")
                        for line in s.traceback.format():
                            print("     ", line)
                if a.dump:
                    snap.dump(f"{a.dump}.{scene.time:.0f}.snap")
                st["snap"] = snap
                st["next"] += 1
                sys.stdout.flush()
            return super().act(scene)

    t0 = time.perf_counter()
    s = run_memory_fleet(a.seconds, a.seed, Sampled)
    print(f"\nwall {time.perf_counter() - t0:.0f} s; egos {s.data['fleet']['egos']} {s.data['fleet']['by_status']}")
    print("t rss blocks pymalloc_arenas gc_objects active agents")
    for r in rows[::2]:
        print(" ".join(f"{x:.0f}" if isinstance(x, float) else str(x) for x in r))


if __name__ == "__main__":
    main()
