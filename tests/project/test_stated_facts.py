"""Facts the README and the set-up pages state stay true, or at least dated and the same everywhere:
the test suite's size and time, the replay's size, the CUDA build of torch, the first run's compile."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
DOCS = ROOT / "docs"
DATE = r"20\d\d-\d\d-\d\d"


def _text(path: Path) -> str:
    return " ".join(path.read_text(encoding="utf-8").split())  # one line: sentences wrap anywhere


def test_the_suites_size_and_time_are_dated_and_the_same_on_every_page():
    """A test count or time is stated with the date it was measured, never bare (the README once
    said 15 minutes and installation.md 773 tests long after both had changed)."""
    found = {}
    for page in (README, DOCS / "index.md", DOCS / "installation.md"):
        text = _text(page)
        m = re.search(r"(\d[\d,]*) tests took about (\d+) minutes \(\d+ s\) on 2 cores shared with other work, "
                      rf"measured on ({DATE})", text)
        assert m, f"{page.name}: the test suite's size and time, with the date they were measured"
        found[page.name] = m.groups()
        assert not re.search(r"\d+ tests(?! took)", text.replace(m.group(0), "")), f"{page.name}: an undated count"
        assert "15 minutes" not in text and "773 tests" not in text
    assert len(set(found.values())) == 1, found


def test_the_replay_of_the_tour_is_described_alike():
    readme = re.search(r"animates the whole run \((\d+) frames, ([\d.]+) MB; (\d+) s of CPU here\)", _text(README))
    explain = re.search(r"the GIF has (\d+) frames, ([\d.]+) MB \(about \d+ kB per frame\), drawn in \d+ s of wall "
                        rf"time, (\d+) s of CPU \(measured {DATE}", _text(DOCS / "explain.md"))
    assert readme and explain
    assert readme.groups() == explain.groups()


def test_the_set_up_says_which_torch_it_installs_and_that_the_first_run_compiles():
    for page in (README, DOCS / "index.md", DOCS / "installation.md"):
        text = _text(page)
        assert "CUDA build" in text and "pip install torch==2.13.0 --index-url https://download.pytorch.org/whl/cpu" \
            in text, page.name
        assert "the first time and" in text and "compil" in text and "background processes" in text, page.name
    assert "torch==2.13.0" in (ROOT / "pyproject.toml").read_text(encoding="utf-8")  # the pin the pages name
