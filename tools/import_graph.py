"""The package's import graph: files, arrows (every import, function-local ones too), loops and
arrows that run back up the floors.

    python tools/import_graph.py            # rooms (sub-packages and top-level files), loops, arrows up
    python tools/import_graph.py --files    # the same over single files

A *room* is a sub-package (``sumo_ethics/plan``) or a top-level module (``sumo_ethics/config.py``).
The floors below are the house plan: an arrow from a room to a room on a higher floor runs back up.
A loop is a strongly connected component of more than one node (scipy's csgraph).
"""

from __future__ import annotations

import argparse
import ast
import sys
from pathlib import Path

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "sumo_ethics"

# the house plan, ground floor first: a room may import rooms on its own floor or below
FLOORS: list[tuple[str, ...]] = [
    # 0 the ground: the package's __init__ (its version), errors, datatypes (types), geometry, signals (interrupt:
    # Ctrl-C and SIGTERM; _worker_signals: a worker dies with its parent), one process per run from a forkserver
    # (processes), files written whole (fileio), the click parameter types (cli_types), SUMO's option values
    # (sumo_options), the C heap's trim (heap), the kernels' threads (cores)
    ("sumo_ethics", "errors", "types", "geometry", "interrupt", "_worker_signals", "processes", "fileio",
     "cli_types", "sumo_options", "heap", "cores"),
    # 1 configuration (config), the runner/controller contract, the goal region (goal), what a sensor sees
    # (visibility), the ethics and safety maths (ethics, safety), collisions found and booked (collision), a run's
    # notes (notes: tight bends, a lonely standstill, what held the ego)
    ("config", "contract", "goal", "visibility", "ethics", "safety", "collision", "notes"),
    ("predict",),  # 2 the predictors (the only importer of torch)
    ("plan", "settings"),  # 3 the planners, and the TOML settings that build their configs
    ("record",),  # 4 the run's files: schema, writers, readers
    ("sim",),  # 5 the SUMO adapter (sim/backend.py: the only importer of libsumo and traci)
    ("analysis",),  # 6 result folders read, tables, figures, explain and replay
    ("runner",),  # 7 the one simulation loop, a single ego's (runner/loop.py) and a fleet's (runner/fleet.py)
    ("suite", "sweep", "recording", "commonroad"),  # 8 many runs: suites, sweeps, training data, imports
    ("cli", "cli_suite", "cli_sweep"),  # 9 the command line
]


def module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def imports_of(path: Path, name: str, known: set[str]) -> set[str]:
    """Every module of the package ``path`` imports, at module level or inside a function."""
    tree = ast.parse(path.read_text(), str(path))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            # `from pkg import sub` imports the module pkg.sub when that is a module
            targets = [f"{mod}.{a.name}" if f"{mod}.{a.name}" in known else mod for a in node.names]
        else:
            continue
        for t in targets:
            while t and t not in known:
                t = t.rpartition(".")[0]
            if t and t.startswith(PACKAGE) and t != name:
                out.add(t)
    return out


def room_of(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def floor_of(room: str) -> int:
    for i, rooms in enumerate(FLOORS):
        if room in rooms:
            return i
    raise SystemExit(f"room {room!r} is on no floor of tools/import_graph.py's FLOORS")


def graph(files: bool) -> tuple[list[str], set[tuple[str, str]]]:
    paths = sorted((ROOT / PACKAGE).rglob("*.py"))
    names = {module_name(p): p for p in paths}
    known = set(names)
    edges: set[tuple[str, str]] = set()
    for name, path in names.items():
        for target in imports_of(path, name, known):
            a, b = (name, target) if files else (room_of(name), room_of(target))
            # a package's __init__ importing its own modules is no arrow between rooms
            if a != b and not (files and target.startswith(name + ".")):
                edges.add((a, b))
    nodes = sorted(set(names) if files else {room_of(n) for n in names})
    return nodes, edges


def loops(nodes: list[str], edges: set[tuple[str, str]]) -> list[list[str]]:
    index = {n: i for i, n in enumerate(nodes)}
    rows = [index[a] for a, _ in edges]
    cols = [index[b] for _, b in edges]
    m = csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(nodes), len(nodes)))
    _, labels = connected_components(m, directed=True, connection="strong")
    comps: dict[int, list[str]] = {}
    for n, lab in zip(nodes, labels):
        comps.setdefault(int(lab), []).append(n)
    return [sorted(c) for c in comps.values() if len(c) > 1]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--files", action="store_true", help="nodes are single files, not rooms")
    args = ap.parse_args(argv)
    nodes, edges = graph(args.files)
    found = loops(nodes, edges)
    up = sorted((a, b) for a, b in edges if floor_of(room_of(a) if args.files else a)
                < floor_of(room_of(b) if args.files else b))
    print(f"{len(nodes)} {'files' if args.files else 'rooms'}, {len(edges)} arrows, {len(found)} loop(s), "
          f"{len(up)} arrow(s) back up")
    for c in found:
        print(f"loop of {len(c)}: " + ", ".join(c))
    for a, b in up:
        print(f"up: {a} -> {b}")
    return 1 if found or up else 0


if __name__ == "__main__":
    sys.exit(main())
