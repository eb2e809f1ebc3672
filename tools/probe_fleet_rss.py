"""Which part of the process's memory grows in a fleet run? The run of ``tools/bench_fleet.py
--memory`` (urban_grid, penetration 1, baseline planners), sampled every 5 simulated seconds with
cheap probes only, after a garbage collection as there (``--no-collect``: without): RSS; glibc
malloc's bytes in use and free (mallinfo2: C/C++ heaps, libsumo's and numpy's data); Python's
small-object arenas and the bytes of their blocks in use, free in used pools and in unused pools
(sys._debugmallocstats); Arrow's pool (bytes allocated); every memory mapping's resident size
(/proc/self/smaps), so the mapping that grows is named (only the first late sample's and the
last are kept: every sample's were the probe's own growth, 66,000 Python blocks per 100 s). Each series is fitted ~ 1 + egos driving + road users in SUMO + t (bench_fleet.growth_fit)
over the samples after the first 20 %.

    python tools/probe_fleet_rss.py 300

Issue 39 (docs/fleets.md). Not sumo_ethics code.
"""

from __future__ import annotations

import argparse
import ctypes
import os
import re
import tempfile
import time
from pathlib import Path

import numpy as np
from bench_fleet import growth_fit, rss_mb

ROOT = Path(__file__).resolve().parents[1]


class _Mallinfo2(ctypes.Structure):
    _fields_ = [(n, ctypes.c_size_t) for n in ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks",
                                                  "fsmblks", "uordblks", "fordblks", "keepcost")]


_libc = ctypes.CDLL("libc.so.6")
_libc.mallinfo2.restype = _Mallinfo2


def pymalloc_arenas() -> int:
    """Python's small-object arenas allocated now (1 MiB each), from sys._debugmallocstats (C stderr)."""
    return pymalloc_stats()["arenas"]


def pymalloc_stats() -> dict[str, int]:
    """From sys._debugmallocstats (C stderr): Python's small-object arenas allocated now (1 MiB each,
    ``arenas``), and the bytes of their blocks in use (``used``), of the free blocks in pools in use
    (``available``: fragmentation within pools) and of their unused pools (``unused``)."""
    import sys

    with tempfile.TemporaryFile() as f:
        sys.stderr.flush()
        saved = os.dup(2)
        os.dup2(f.fileno(), 2)
        try:
            sys._debugmallocstats()
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        f.seek(0)
        text = f.read()
    out = {}
    for key, pattern in (("arenas", rb"# arenas allocated current\s*=\s*([\d,]+)"),
                         ("used", rb"# bytes in allocated blocks\s*=\s*([\d,]+)"),
                         ("available", rb"# bytes in available blocks\s*=\s*([\d,]+)"),
                         ("unused", rb"unused pools \* \d+ bytes\s*=\s*([\d,]+)")):
        m = re.search(pattern, text)
        out[key] = int(m.group(1).replace(b",", b"")) if m else -1
    return out


def mappings() -> dict[str, float]:
    """Resident MB of every mapping, keyed by 'start-end name'."""
    out: dict[str, float] = {}
    key = ""
    with open("/proc/self/smaps") as f:
        for line in f:
            if re.match(r"^[0-9a-f]+-[0-9a-f]+ ", line):
                p = line.split()
                key = f"{p[0].split('-')[0]} {p[5] if len(p) > 5 else '[anon]'}"
            elif line.startswith("Rss:"):
                out[key] = int(line.split()[1]) / 1024 * 1.048576  # kB -> MB (10^6 bytes)
    return out


def hold_run() -> dict:
    """Make the running FleetRun available as ``holder["run"]`` (FleetRun._loop wrapped); the holder."""
    from sumo_ethics.runner import fleet as F

    holder: dict = {}
    orig = F.FleetRun._loop

    def _loop(self, *args, **kw):  # type: ignore[no-untyped-def]
        holder["run"] = self
        return orig(self, *args, **kw)

    F.FleetRun._loop = _loop  # type: ignore[method-assign]
    return holder


def run_memory_fleet(seconds: float, seed: int, controller):  # type: ignore[no-untyped-def]
    """tools/bench_fleet.py's memory run: urban_grid at penetration 1, every ego driven by
    ``controller()`` (a RouteFollower), into a temporary folder; its RunSummary."""
    from sumo_ethics.config import FleetSpec, RunConfig
    from sumo_ethics.runner import fleet as F

    with tempfile.TemporaryDirectory() as tmp:
        cfg = RunConfig(scenario=ROOT / "scenarios" / "urban_grid" / "urban_grid.sumocfg", out=Path(tmp) / "m",
                        seed=seed, end=seconds, progress=False,
                        fleet=FleetSpec(penetration=1.0, shares=(("baseline", 1.0),)))
        return F.run_fleet(cfg, lambda name, vid: controller())


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("seconds", type=float)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--every", type=float, default=5.0)
    ap.add_argument("--no-collect", dest="collect", action="store_false",
                    help="no gc.collect() before each sample (tools/bench_fleet.py --memory collects)")
    a = ap.parse_args()

    import pyarrow as pa

    import sumo_ethics
    from sumo_ethics.plan.baseline import RouteFollower
    from sumo_ethics.runner import fleet as F
    from sumo_ethics.sim.backend import sumo

    print("sumo_ethics from", sumo_ethics.__file__, "; arrow pool", pa.default_memory_pool().backend_name)
    holder = hold_run()
    import gc
    import sys
    import weakref

    routes: list = []  # weakrefs (a RoutePath is not hashable)
    worlds: list = []
    orig_take = F.FleetRun._maybe_take_over

    def take(self, vid, t, end):  # type: ignore[no-untyped-def]
        n = len(self.agents)
        orig_take(self, vid, t, end)
        if len(self.agents) > n:
            routes.append(weakref.ref(self.agents[-1].world.route))
            worlds.append(weakref.ref(self.agents[-1].world))

    F.FleetRun._maybe_take_over = take  # type: ignore[method-assign]
    rows: list[dict] = []
    # the mappings at the first sample after the build-up and at the last (not every sample's: 1,600-odd
    # mappings each, kept for the run, were 66,000 Python blocks per 100 s of the probe's own growth)
    maps: dict[str, tuple[float, dict[str, float]]] = {}

    class Sampled(RouteFollower):
        def act(self, scene):  # type: ignore[no-untyped-def]
            if not rows or scene.time >= rows[-1]["t"] + a.every - 1e-9:
                if a.collect:
                    gc.collect()  # as tools/bench_fleet.py --memory samples
                m = _libc.mallinfo2()
                run = holder["run"]
                py = pymalloc_stats()
                rows.append({"t": scene.time, "rss": rss_mb(), "malloc_used": (m.uordblks + m.hblkhd) / 1e6,
                             "malloc_mmapped": m.hblkhd / 1e6, "malloc_free": m.fordblks / 1e6,
                             "malloc_arena": m.arena / 1e6, "pymalloc": py["arenas"] * 1.048576,
                             "py_used": py["used"] / 1e6, "py_avail": py["available"] / 1e6,
                             "py_unused": py["unused"] / 1e6,
                             "arrow": pa.total_allocated_bytes() / 1e6,
                             "kblocks": sys.getallocatedblocks() / 1e3,
                             "routes_alive": sum(r() is not None for r in routes) - len(run.active),
                             "worlds_alive": sum(r() is not None for r in worlds) - len(run.active),
                             "egos": len(run.active),
                             "road_users": sumo.vehicle.getIDCount() + sumo.person.getIDCount(),
                             "ended": len(run.agents) - len(run.active)})
                now = (scene.time, mappings())
                maps["last"] = now
                if "first" not in maps and scene.time >= 0.2 * a.seconds:
                    maps["first"] = now
            return super().act(scene)

    t0 = time.perf_counter()
    s = run_memory_fleet(a.seconds, a.seed, Sampled)
    print(f"wall {time.perf_counter() - t0:.0f} s; egos {s.data['fleet']['egos']} {s.data['fleet']['by_status']}")
    keys = [k for k in rows[0] if k not in ("t", "egos", "road_users", "ended", "routes_alive", "worlds_alive")]
    print("routes alive minus egos driving: max", max(r["routes_alive"] for r in rows), "; worlds:",
          max(r["worlds_alive"] for r in rows))
    print("t " + " ".join(keys) + " egos road_users ended")
    for r in rows[::4]:
        print(f"{r['t']:.0f} " + " ".join(f"{r[k]:.1f}" for k in keys) + f" {r['egos']} {r['road_users']} {r['ended']}")
    late = [r for r in rows if r["t"] >= 0.2 * a.seconds]
    t = np.array([r["t"] for r in late])
    cov = [np.array([r["egos"] for r in late], float), np.array([r["road_users"] for r in late], float)]
    print(f"fits over t >= {0.2 * a.seconds:g} s ({len(late)} samples): MB per ego driving, per road user, per 100 s [95 % CI]")
    for k in keys:
        coef, se, resid = growth_fit(np.array([r[k] for r in late]), cov, t)
        print(f"  {k:15s} {coef[1]:7.3f} {coef[2]:7.3f} {coef[3]:7.2f} [{coef[3] - 1.96 * se[3]:.2f}, "
              f"{coef[3] + 1.96 * se[3]:.2f}]  resid sd {resid.std():.2f}")
    # which mappings grew from the first late sample to the last
    m0, m1 = maps["first"][1], maps["last"][1]
    grown = sorted(((k, m1.get(k, 0.0) - m0.get(k, 0.0)) for k in set(m0) | set(m1)), key=lambda kv: -abs(kv[1]))
    print(f"mappings, resident growth from t={0.2 * a.seconds:g} s to the end (top 15; new ones count whole):")
    for k, d in grown[:15]:
        print(f"  {d:+8.2f} MB  now {m1.get(k, 0.0):8.2f}  {k}")
    by_name: dict[str, float] = {}
    for k, d in grown:
        name = k.split(" ", 1)[1]
        by_name[name] = by_name.get(name, 0.0) + d
    print("by name: " + ", ".join(f"{n} {d:+.1f}" for n, d in sorted(by_name.items(), key=lambda kv: -abs(kv[1]))[:8]))


if __name__ == "__main__":
    main()
