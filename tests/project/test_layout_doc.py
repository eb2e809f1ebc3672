"""docs/layout.md's floors list the rooms tools/import_graph.py's FLOORS puts there, floor by floor."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _floors() -> list[tuple[str, ...]]:
    spec = importlib.util.spec_from_file_location("import_graph", ROOT / "tools" / "import_graph.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.FLOORS


def _rooms_of(path_cell: str) -> set[str]:
    """`config.py` -> config, `plan/` -> plan, `__init__.py` -> the package itself."""
    out = set()
    for name in re.findall(r"`([^`]+)`", path_cell):
        room = name.removesuffix(".py").removesuffix("/")
        out.add("sumo_ethics" if room == "__init__" else room)
    return out


def test_every_floor_of_the_layout_page_lists_its_rooms():
    documented: dict[int, set[str]] = {}
    for line in (ROOT / "docs" / "layout.md").read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) >= 3 and cells[0].isdigit():
            documented.setdefault(int(cells[0]), set()).update(_rooms_of(cells[1]))
    floors = _floors()
    assert sorted(documented) == list(range(len(floors)))
    for i, rooms in enumerate(floors):
        assert documented[i] == set(rooms), (i, documented[i] ^ set(rooms))


def test_every_room_on_a_floor_exists():
    pkg = ROOT / "sumo_ethics"
    for rooms in _floors():
        for room in rooms:
            assert room == "sumo_ethics" or (pkg / f"{room}.py").is_file() or (pkg / room).is_dir(), room
