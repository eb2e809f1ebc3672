"""One current answer per question: docs/results.md states each suite's current table with its
command, commit and date; every superseded result lives under docs/history/, says so at its top,
is out of the site's navigation and is reached from docs/history.md; and no page calls a
superseded result current."""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

from test_docs import FENCE, relative_links

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
HISTORY = DOCS / "history"
BANNER = "> **Superseded.**"
CURRENT = re.compile(r"\bcurrent\b", re.I)
SUITES = ("Hazard suite", "Held-out suites", "CommonRoad", "Dilemmas", "Fleets")


def blocks(text: str) -> list[str]:
    """A page's prose in the blocks a reader takes as one statement: a paragraph, a list item, a
    table row; a heading goes with the block after it. Fenced code is left out."""
    text = FENCE.sub("\n", text)
    out: list[str] = []
    heading = ""
    for para in re.split(r"\n\s*\n", text):
        lines = para.strip("\n").splitlines()
        if not lines:
            continue
        if len(lines) == 1 and lines[0].startswith("#"):
            heading = lines[0] + "\n"
            continue
        items: list[list[str]] = []
        for ln in lines:
            if ln.lstrip().startswith("|") or re.match(r"\s*([-*+]|\d+\.)\s", ln) or not items:
                items.append([ln])
            else:
                items[-1].append(ln)
        for i, item in enumerate(items):
            out.append((heading if i == 0 else "") + "\n".join(item))
        heading = ""
    return out


def _links_of(block: str) -> list[str]:
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp) / "b.md"
        p.write_text(block, encoding="utf-8")
        return relative_links(p)


def superseded_called_current(pages: dict[Path, str], history: Path) -> list[str]:
    """Where a page calls a superseded result current: a page under ``history`` saying "current"
    outside its banner, or a block of another page saying "current" and linking under ``history``."""
    found = []
    for page, text in pages.items():
        if history in page.parents:
            for ln in text.splitlines():
                if CURRENT.search(ln) and not ln.startswith(BANNER):
                    found.append(f"{page.name}: a superseded page says 'current': {ln.strip()[:100]}")
            continue
        for block in blocks(text):
            if not CURRENT.search(block):
                continue
            for target in _links_of(block):
                if history in (page.parent / target).resolve().parents:
                    found.append(f"{page.name}: calls {target} current: {block.strip()[:100]}")
    return found


def _pages() -> dict[Path, str]:
    return {p.resolve(): p.read_text(encoding="utf-8") for p in [ROOT / "README.md", *sorted(DOCS.rglob("*.md"))]}


def test_no_page_calls_a_superseded_result_current():
    assert superseded_called_current(_pages(), HISTORY.resolve()) == []


def test_the_check_finds_a_superseded_result_called_current(tmp_path):
    history = tmp_path / "history"
    history.mkdir()
    (history / "old.md").write_text("# Old\n")
    pages = {
        tmp_path / "ok.md": "The current table: [new](new.md).\n\nAn earlier one: [old](history/old.md).\n",
        tmp_path / "bad.md": "Intro.\n\n- the current Table 1 is [this one](history/old.md)\n- other\n",
        tmp_path / "heading.md": "## Table 1 (the current one)\n\nFiles in [old](history/old.md).\n",
        tmp_path / "row.md": "| a | b |\n| --- | --- |\n| current | [old](history/old.md) |\n",
        history / "old.md": f"# Old\n\n{BANNER} The current results: [r](../r.md).\n\n# Table 1 (the current one)\n",
    }
    found = superseded_called_current(pages, history)
    assert [f.split(":")[0] for f in found] == ["bad.md", "heading.md", "row.md", "old.md"], found


def test_every_superseded_page_says_so_and_is_out_of_the_navigation():
    yaml = pytest.importorskip("yaml", reason="PyYAML comes with the docs extra (MkDocs)")

    cfg = yaml.safe_load((ROOT / "mkdocs.yml").read_text(encoding="utf-8").replace("!!python/name:", ""))
    assert cfg["not_in_nav"].split() == ["/history/"]
    nav = []

    def walk(item):
        if isinstance(item, dict):
            for v in item.values():
                walk(v)
        elif isinstance(item, list):
            for v in item:
                walk(v)
        else:
            nav.append(item)

    walk(cfg["nav"])
    assert "results.md" in nav and "history.md" in nav and nav.index("results.md") == 1  # right after Home
    assert not [p for p in nav if p.startswith("history/")]
    pages = sorted(HISTORY.rglob("*.md"))
    assert len(pages) >= 20
    for p in pages:
        lines = p.read_text(encoding="utf-8").splitlines()
        assert lines[0].startswith("# ") and lines[2].startswith(BANNER), p
    # every superseded page is reached from history.md through links
    seen, todo = set(), [DOCS / "history.md"]
    while todo:
        page = todo.pop()
        for target in relative_links(page):
            q = Path(os.path.normpath(page.parent / target))
            if q.suffix == ".md" and q.is_file() and HISTORY in q.parents and q not in seen:
                seen.add(q)
                todo.append(q)
    assert [p for p in pages if p not in seen] == []


def test_docs_root_holds_no_superseded_result():
    """The loose Table 1 files and the earlier versions' folders live under docs/history/ now."""
    assert [p.name for p in DOCS.glob("table1*")] == ["table1-tolerance"]


@pytest.mark.parametrize("suite", SUITES)
def test_results_page_states_each_suite_with_command_commit_and_date(suite):
    text = (DOCS / "results.md").read_text(encoding="utf-8")
    sections = {s.split("\n", 1)[0]: s for s in re.split(r"^## ", text, flags=re.M)[1:]}
    title = next((t for t in sections if t.startswith(suite)), None)
    assert title is not None, f"docs/results.md has no section for {suite}: {list(sections)}"
    body = sections[title]
    assert re.search(r"\*\*Measured:\*\* 20\d\d-\d\d-\d\d, .*commit [0-9a-f]{7}", body), body[:300]
    assert "**Command" in body and "sumo-ethics " in body
    assert re.search(r"^\| .* \|$", body, re.M), f"{suite}: no table"


def test_results_page_links_no_superseded_page():
    links = relative_links(DOCS / "results.md")
    assert not [t for t in links if t.startswith("history/")], links
    assert "history.md" in links and "benchmarks.md" in links


def test_readme_answer_quotes_the_results_page():
    """The README's answer to the first question repeats numbers of docs/results.md: they must be
    the same numbers (README and docs/index.md alike)."""
    results = (DOCS / "results.md").read_text(encoding="utf-8")
    for page in (ROOT / "README.md", DOCS / "index.md"):
        text = page.read_text(encoding="utf-8")
        answer = text.split("*Which planner is best on the hazard suite, and by how much?*", 1)[1].split("\n- *", 1)[0]
        numbers = re.findall(r"\d+\.\d+", answer)
        assert len(numbers) >= 4, answer
        assert [n for n in numbers if n not in results] == [], page


def test_benchmarks_have_one_current_table_with_dates():
    text = (DOCS / "benchmarks.md").read_text(encoding="utf-8")
    assert text.count("\n| --- |") == 1, "docs/benchmarks.md holds one table: the current figures"
    rows = [ln for ln in text.split("## Current figures", 1)[1].splitlines() if ln.startswith("| ") and "---" not in ln][1:]
    assert len(rows) >= 8
    for row in rows:
        assert re.search(r"20\d\d-\d\d-\d\d", row), row[:80]
    for what in ("planning step", "fleets", "evaluate", "overhead"):
        assert any(what in row for row in rows), what
