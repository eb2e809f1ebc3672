"""Where does a fleet run's memory grow? The run of ``tools/bench_fleet.py --memory`` (urban_grid,
penetration 1, baseline planners), shorter, with object censuses at a few simulated times instead of a
fit: gc object counts by type, the deep size of every attribute of the FleetRun (and its recorder and
collision book), glibc malloc's bytes in use (mallinfo2) against RSS, optionally a tracemalloc window.

    python tools/probe_fleet_objects.py 150 --at 60,100,150 [--trace 60]

Issue 39 (docs/fleets.md). Not sumo_ethics code.
"""

from __future__ import annotations

import argparse
import collections
import ctypes
import gc
import sys
import time
import types
from pathlib import Path

import numpy as np
from bench_fleet import rss_mb
from probe_fleet_rss import hold_run, run_memory_fleet

ROOT = Path(__file__).resolve().parents[1]


class _Mallinfo2(ctypes.Structure):
    _fields_ = [(n, ctypes.c_size_t) for n in ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks",
                                                  "fsmblks", "uordblks", "fordblks", "keepcost")]


def malloc_in_use_mb() -> tuple[float, float]:
    """(bytes in use by malloc incl. mmapped chunks, free bytes held in arenas) [MB]."""
    libc = ctypes.CDLL("libc.so.6")
    libc.mallinfo2.restype = _Mallinfo2
    m = libc.mallinfo2()
    return (m.uordblks + m.hblkhd) / 1e6, m.fordblks / 1e6


_SKIP = (types.ModuleType, type, types.FunctionType, types.BuiltinFunctionType, types.CodeType, types.FrameType)


def deep(obj: object, seen: set[int]) -> tuple[int, int]:
    """(bytes, objects) reachable from obj (sys.getsizeof, numpy data included), not through
    modules, classes, functions or frames; ``seen`` shared across calls to count objects once."""
    total = n = 0
    stack = [obj]
    while stack:
        o = stack.pop()
        if id(o) in seen or isinstance(o, _SKIP):
            continue
        seen.add(id(o))
        n += 1
        try:
            total += sys.getsizeof(o)
        except TypeError:
            pass
        if isinstance(o, np.ndarray) and o.base is not None:
            stack.append(o.base)
        stack.extend(gc.get_referents(o))
    return total, n


def census(run: object, label: str, prev: dict | None) -> dict:
    gc.collect()
    objs = gc.get_objects()
    counts = collections.Counter(type(o).__name__ for o in objs)
    arrays = [o for o in objs if isinstance(o, np.ndarray)]
    in_use, free = malloc_in_use_mb()
    out: dict = {"label": label, "rss": rss_mb(), "gc_objects": len(objs), "counts": counts, "malloc": in_use,
                 "malloc_free": free}
    print(f"\n=== {label}: RSS {out['rss']:.1f} MB, gc objects {len(objs)}, malloc in use {in_use:.1f} MB "
          f"(free in arenas {free:.1f}), gc-tracked ndarrays {len(arrays)}", flush=True)
    sizes: dict[str, tuple[int, int]] = {}
    parts = {"run." + k: v for k, v in vars(run).items()}
    for holder in ("rec", "book", "union_history", "pairs"):
        h = getattr(run, holder, None)
        if h is not None and hasattr(h, "__dict__"):
            parts.update({f"{holder}.{k}": v for k, v in vars(h).items()})
    # each part on its own, not through the run or its holders (which are parts themselves)
    stop = {id(run)} | {id(getattr(run, h, None)) for h in ("rec", "book", "union_history", "pairs")}
    for k in parts:
        if k.startswith("run.") and k[4:] in ("rec", "book", "union_history", "pairs"):
            continue
        sizes[k] = deep(parts[k], set(stop))
    ended = [a for a in run.agents if a.status != "driving"]  # type: ignore[attr-defined]
    sizes["(ended agents, fresh)"] = deep(ended, set())
    sizes["(all gc objects, fresh)"] = deep(objs, set())
    out["sizes"] = sizes
    out["agents"] = (len(run.agents), len(ended))  # type: ignore[attr-defined]
    print(f"agents {len(run.agents)}, ended {len(ended)}, active {len(run.active)}")  # type: ignore[attr-defined]
    rows = sorted(sizes.items(), key=lambda kv: -kv[1][0])
    for k, (b, n) in rows[:40]:
        d = ""
        if prev is not None and k in prev["sizes"]:
            pb, pn = prev["sizes"][k]
            d = f"   (+{(b - pb) / 1e6:.3f} MB, {n - pn:+d} objects)"
        print(f"  {k:40s} {b / 1e6:9.3f} MB {n:9d} objects{d}")
    if prev is not None:
        diff = counts.copy()
        diff.subtract(prev["counts"])
        print(f"  gc objects {len(objs) - prev['gc_objects']:+d}; RSS {out['rss'] - prev['rss']:+.1f} MB; "
              f"malloc in use {in_use - prev['malloc']:+.1f} MB; top type changes:")
        for name, dn in sorted(diff.items(), key=lambda kv: -abs(kv[1]))[:25]:
            print(f"    {name:35s} {dn:+8d}  (now {counts[name]})")
        sz = {k: v for k, v in sizes.items()}
        grown = sorted(((k, sz[k][0] - prev["sizes"][k][0]) for k in sz if k in prev["sizes"]), key=lambda kv: -kv[1])
        print("  most grown parts: " + ", ".join(f"{k} {b / 1e6:+.3f} MB" for k, b in grown[:10]))
    del objs, arrays
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("seconds", type=float)
    ap.add_argument("--at", default="60,100,150")
    ap.add_argument("--trace", type=float, default=-1.0, help="start tracemalloc at this time (s), snapshot at --at")
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args()
    at = [float(x) for x in a.at.split(",")]

    import tracemalloc

    from sumo_ethics.plan.baseline import RouteFollower

    import sumo_ethics
    print("sumo_ethics from", sumo_ethics.__file__)
    holder = hold_run()
    state: dict = {"prev": None, "snap": None, "next": 0, "traced": False}
    rss_track: list[tuple[float, float]] = []
    t_wall = time.perf_counter()

    class Sampled(RouteFollower):
        def act(self, scene):  # type: ignore[no-untyped-def]
            if not rss_track or scene.time >= rss_track[-1][0] + 5.0:
                rss_track.append((scene.time, rss_mb()))
            if a.trace >= 0 and not state["traced"] and scene.time >= a.trace:
                tracemalloc.start(1)
                state["traced"] = True
                print(f"tracemalloc started at t={scene.time:.1f}", flush=True)
            if state["next"] < len(at) and scene.time >= at[state["next"]]:
                print(f"[wall {time.perf_counter() - t_wall:.0f} s]")
                state["prev"] = census(holder["run"], f"t={scene.time:.1f}", state["prev"])
                if state["traced"]:
                    snap = tracemalloc.take_snapshot().filter_traces(
                        [tracemalloc.Filter(False, tracemalloc.__file__)])
                    if state["snap"] is not None:
                        print("  tracemalloc, compared to the last census, by line:")
                        for st in snap.compare_to(state["snap"], "lineno")[:25]:
                            print("   ", st)
                    state["snap"] = snap
                state["next"] += 1
            return super().act(scene)

    s = run_memory_fleet(a.seconds, a.seed, Sampled)
    print(f"\nwall {time.perf_counter() - t_wall:.0f} s; egos {s.data['fleet']['egos']} {s.data['fleet']['by_status']}")
    print("RSS every 5 s: " + " ".join(f"{t:.0f}:{r:.0f}" for t, r in rss_track))


if __name__ == "__main__":
    main()
