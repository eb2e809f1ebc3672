"""Installs that reproduce (issue 42): every dependency the project names is pinned to one exact
version in constraints.txt, which .ci/run installs from."""

from __future__ import annotations

import re
try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10: the same parser as a package (a dependency there)
    import tomli as tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _name(req: str) -> str:
    return re.split(r"[\s\[<>=!~;]", req.strip(), maxsplit=1)[0].lower().replace("_", "-")


def test_every_dependency_is_pinned_exactly_in_the_constraints():
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    wanted = {_name(r) for r in meta["dependencies"] + meta["optional-dependencies"]["test"]}
    pins = {}
    for line in (ROOT / "constraints.txt").read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            name, sep, version = line.partition("==")
            assert sep and re.fullmatch(r"[0-9][0-9A-Za-z.]*", version), f"not an exact pin: {line!r}"
            pins[_name(name)] = version
    assert wanted <= set(pins), f"not pinned: {sorted(wanted - set(pins))}"
    assert "constraints.txt" in (ROOT / ".ci" / "run").read_text()
    assert pins["torch"] == "2.13.0"  # the public version: it matches the CPU build 2.13.0+cpu
