"""Which objects does the fleet's memory growth consist of? The run of ``tools/bench_fleet.py
--memory`` (urban_grid, penetration 1, baseline planners); at ``--at`` times every object
reachable from the gc-tracked ones (untracked containers and atoms too: gc.get_referents) is
counted by type, and by where it hangs from the running FleetRun (``run.active[].conflicts...``,
attribute names; what the run does not reach: ``elsewhere:<type>``), beside Python's allocated
blocks (sys.getallocatedblocks): growth in blocks that no reachable object explains is memory
that no Python object holds (2026-12-02: none; blocks minus objects reached stayed 228,000-236,000
from t=100 to 250 s). The containers that grew most are listed too.

    python tools/probe_fleet_census.py 260 --at 60,100,140,180,220,260

Issue 39 (docs/fleets.md). Not sumo_ethics code.
"""

from __future__ import annotations

import argparse
import gc
import sys
import time
from collections import Counter

from bench_fleet import rss_mb
from probe_fleet_rss import hold_run, run_memory_fleet

CONTAINERS = (dict, list, set, frozenset, tuple)


SKIP = (type, type(sys))  # classes and modules are not walked from the run


def _children(o: object, label: str) -> list[tuple[object, str]]:
    """o's referents with their labels: attribute names for objects with a __dict__ or slots,
    [] for the items of sequences and sets, {} for a dict's values and {key} for its keys."""
    t = type(o)
    if t is dict:
        return [(k, label + "{key}") for k in o] + [(v, label + "{}") for v in o.values()]
    if t in (list, tuple, set, frozenset) or t.__name__ == "deque":
        return [(v, label + "[]") for v in o]
    out: list[tuple[object, str]] = []
    d = getattr(o, "__dict__", None)
    if isinstance(d, dict) and t not in SKIP:
        out += [(v, f"{label}.{k}") for k, v in d.items()]
        out.append((d, label + ".__dict__"))
    for k in getattr(t, "__slots__", ()) if t not in SKIP else ():
        if hasattr(o, k):
            out.append((getattr(o, k), f"{label}.{k}"))
    named = {id(c) for c, _ in out}
    out += [(r, f"{label}/{type(r).__name__}") for r in gc.get_referents(o) if id(r) not in named]
    return out


def _short(label: str) -> str:
    """At most 7 steps of a label (the first 3 and the last 4)."""
    parts = label.replace("/", "\x00/").replace(".", "\x00.").replace("[", "\x00[").replace("{", "\x00{").split("\x00")
    parts = [p for p in parts if p]
    return label if len(parts) <= 7 else "".join(parts[:3]) + "..." + "".join(parts[-4:])


def census(root: object) -> tuple[Counter, Counter, dict[int, tuple[str, int]], int]:
    """(objects by type, by where they hang from ``root`` (others: 'elsewhere:<root type>'), id ->
    (type, length) of containers with more than 200 items, objects reached)."""
    gc.collect()
    seen = {id(root)}
    counts: Counter = Counter()
    where: Counter = Counter()
    big: dict[int, tuple[str, int]] = {}
    seen.update(id(x) for x in (seen, counts, where, big))  # the census's own books are not counted

    def walk(stack: list[tuple[object, str]], labelled: bool) -> None:
        while stack:
            o, label = stack.pop()
            t = type(o)
            counts[t.__name__] += 1
            where[label if labelled else f"elsewhere:{label}"] += 1
            if t in CONTAINERS and len(o) > 200:
                big[id(o)] = (t.__name__, len(o))
            if labelled and t in SKIP:
                continue
            kids = _children(o, label) if labelled else [(r, label) for r in gc.get_referents(o)]
            for r, lab in kids:
                if id(r) not in seen:
                    seen.add(id(r))
                    stack.append((r, _short(lab) if labelled else lab))

    first = [(root, "run")]
    seen.add(id(first))
    walk(first, True)
    roots = gc.get_objects()
    seen.add(id(roots))
    rest = [(o, type(o).__name__) for o in roots if id(o) not in seen]
    seen.add(id(rest))
    seen.update(id(o) for o, _ in rest)
    del roots
    walk(rest, False)
    return counts, where, big, len(seen)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("seconds", type=float)
    ap.add_argument("--at", default="60,100,140,180,220,260")
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args()
    at = [float(x) for x in a.at.split(",")]

    from sumo_ethics.plan.baseline import RouteFollower

    holder = hold_run()
    rows: list[tuple] = []

    class Sampled(RouteFollower):
        def act(self, scene):  # type: ignore[no-untyped-def]
            if len(rows) < len(at) and scene.time >= at[len(rows)] - 1e-9:
                run = holder["run"]
                w = time.perf_counter()
                counts, where, big, reached = census(run)
                rows.append((scene.time, rss_mb(), sys.getallocatedblocks(), reached, counts, big,
                             len(run.active), len(run.agents) - len(run.active), where))
                print(f"t={scene.time:.0f}: rss {rows[-1][1]:.1f} MB, blocks {rows[-1][2]}, reached {reached}, "
                      f"egos {len(run.active)}, ended {len(run.agents) - len(run.active)} "
                      f"(census {time.perf_counter() - w:.1f} s)", flush=True)
            return super().act(scene)

    run_memory_fleet(a.seconds, a.seed, Sampled)
    print("\nt rss blocks reached egos ended")
    for r in rows:
        print(f"{r[0]:.0f} {r[1]:.1f} {r[2]} {r[3]} {r[6]} {r[7]}")
    first, last = rows[0], rows[-1]
    print(f"\nobjects by type, growth from t={first[0]:.0f} to t={last[0]:.0f} (top 25), with every census:")
    grown = sorted(set(first[4]) | set(last[4]), key=lambda k: -(last[4][k] - first[4][k]))
    for k in grown[:25]:
        print(f"  {last[4][k] - first[4][k]:+8d} {k:28s} " + " ".join(str(r[4][k]) for r in rows))
    print(f"\nobjects by where they hang from the FleetRun, growth from t={first[0]:.0f} to t={last[0]:.0f} (top 40):")
    grown = sorted(set(first[8]) | set(last[8]), key=lambda k: -(last[8][k] - first[8][k]))
    for k in grown[:40]:
        print(f"  {last[8][k] - first[8][k]:+8d} " + " ".join(str(r[8][k]) for r in rows) + f"  {k}")
    print("\ncontainers (over 200 items) that grew most, with every census (- absent):")
    ids = sorted(set().union(*(r[5] for r in rows)),
                 key=lambda i: -(last[5].get(i, ("", 0))[1] - first[5].get(i, ("", 0))[1]))
    objs = {id(o): o for o in gc.get_objects()}
    for i in ids[:15]:
        name = next(r[5][i][0] for r in rows if i in r[5])
        o = objs.get(i)
        where = ""
        if o is not None:
            refs = [type(x).__name__ + (f"({sorted(k for k, v in x.items() if v is o)[:3]})" if isinstance(x, dict) else "")
                    for x in gc.get_referrers(o) if x is not objs]
            sample = list(o.items())[:2] if isinstance(o, dict) else list(o)[:2]
            where = f" referrers {refs[:4]} sample {repr(sample)[:160]}"
        print(f"  {name:9s} " + " ".join(str(r[5][i][1]) if i in r[5] else "-" for r in rows) + where)


if __name__ == "__main__":
    main()
