"""The README stays short and the documentation site stays whole: every relative link resolves,
the CLI reference matches the commands, and ``mkdocs build --strict`` passes (when MkDocs is
installed: ``pip install -e '.[docs]'``, also part of the ``test`` extra)."""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path
from urllib.parse import unquote

import pytest

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
DOCS = ROOT / "docs"
MAX_README_LINES = 200

#: [text](target) and ![alt](target); the target ends at whitespace or the closing parenthesis
LINK = re.compile(r"!?\[(?:[^\]\[]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
FENCE = re.compile(r"^(\s*)(```|~~~).*?^\1\2\s*$", re.M | re.S)
CODE_SPAN = re.compile(r"(`+)(?:(?!\1).)+?\1", re.S)


def _markdown_files() -> list[Path]:
    return [README, *sorted(DOCS.rglob("*.md"))]


def relative_links(path: Path) -> list[str]:
    """The relative link targets of a Markdown file (outside code), without their #anchor."""
    text = CODE_SPAN.sub("", FENCE.sub("", path.read_text(encoding="utf-8")))
    out = []
    for target in LINK.findall(text):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I) or target.startswith(("#", "//")):
            continue  # http(s), mailto, an anchor on the same page
        target = unquote(target.split("#", 1)[0].split("?", 1)[0])
        if target:
            out.append(target)
    return out


def test_link_parser_finds_links_and_skips_code():
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        page = Path(tmp) / "p.md"
        page.write_text("see [a](a.md#x), ![img](f/b.png \"t\"), [web](https://e.org), [here](#y)\n"
                        "`[no](code.md)`\n```sh\n[no](fenced.md)\n```\n[after](c.md)\n", encoding="utf-8")
        assert relative_links(page) == ["a.md", "f/b.png", "c.md"]


def test_readme_is_short():
    n = len(README.read_text(encoding="utf-8").splitlines())
    assert n <= MAX_README_LINES, f"README.md has {n} lines (at most {MAX_README_LINES}): move detail to docs/"


@pytest.mark.parametrize("page", _markdown_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_point_to_files(page: Path):
    broken = [t for t in relative_links(page) if not (page.parent / t).is_file()]
    assert not broken, f"{page.relative_to(ROOT)} links to missing files: {broken}"


def test_readme_links_to_docs_pages():
    links = relative_links(README)
    pages = [t for t in links if t.startswith("docs/") and t.endswith(".md")]
    assert len(pages) >= 10, f"README.md should send the reader to the documentation pages, links: {links}"


def test_site_home_has_the_readme_commands():
    """docs/index.md is the README with site-relative links: its commands must not drift apart."""
    def blocks(path: Path) -> list[str]:
        return re.findall(r"^```\w*\n(.*?)^```", path.read_text(encoding="utf-8"), re.M | re.S)

    assert blocks(DOCS / "index.md") == blocks(README)


def _missing_docs_packages() -> list[str]:
    missing = []
    for name in ("mkdocs", "material", "mkdocstrings", "mkdocstrings_handlers.python"):
        try:
            found = importlib.util.find_spec(name) is not None
        except ModuleNotFoundError:
            found = False
        if not found:
            missing.append(name)
    return missing


def test_mkdocs_build_strict(tmp_path: Path):
    missing = _missing_docs_packages()
    if missing:
        pytest.skip(f"the docs extra is not installed ({', '.join(missing)} missing): pip install -e '.[docs]'")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file",
                           str(ROOT / "mkdocs.yml"), "--site-dir", str(tmp_path / "site")],
                          cwd=ROOT, capture_output=True, text=True, timeout=600, env=env)
    assert proc.returncode == 0, f"mkdocs build --strict failed:\n{proc.stdout}\n{proc.stderr}"
    assert (tmp_path / "site" / "index.html").is_file()
    assert (tmp_path / "site" / "outputs" / "index.html").is_file()


def test_test_extra_brings_the_docs_packages():
    """CI installs '.[test]' only: it builds the site because the test extra holds the docs packages."""
    tomllib = pytest.importorskip("tomllib", reason="tomllib is in the standard library from Python 3.11")
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]["optional-dependencies"]
    assert set(extras["docs"]) <= set(extras["test"])
