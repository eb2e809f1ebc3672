"""tools/: every script starts and prints its usage, docs/tools.md lists every one, and no test
imports a script as a library (what tests need lives in the package)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
TOOLS = sorted(p.name for p in (ROOT / "tools").glob("*.py"))

# every script's --help, in one interpreter (runpy as ``__main__``): the exit code and what it printed
HELP = """
import contextlib, io, json, runpy, sys
sys.path.insert(0, "tools")
out = {}
for name in sys.argv[1:]:
    sys.argv = [name, "--help"]
    buf = io.StringIO()
    try:
        with contextlib.redirect_stdout(buf):
            runpy.run_path("tools/" + name, run_name="__main__")
        code = None
    except SystemExit as exc:
        code = exc.code
    out[name] = [code, buf.getvalue()]
print(json.dumps(out))
"""


def test_every_tool_prints_its_usage():
    scripts = [t for t in TOOLS if not t.startswith("_")]
    res = subprocess.run([sys.executable, "-c", HELP, *scripts], capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    import json

    got = json.loads(res.stdout.strip().splitlines()[-1])
    for name in scripts:
        code, text = got[name]
        assert code == 0 and text.startswith("usage: "), (name, code, text[:200])


def test_docs_list_every_tool_and_no_other():
    page = (ROOT / "docs" / "tools.md").read_text(encoding="utf-8")
    listed = set(re.findall(r"`([A-Za-z0-9_]+\.py)`", page))
    assert listed == set(TOOLS), (sorted(set(TOOLS) - listed), sorted(listed - set(TOOLS)))


def test_no_test_imports_a_tool():
    tests = [p for p in Path(__file__).resolve().parents[1].rglob("*.py") if p.name != Path(__file__).name]
    for path in tests:
        text = path.read_text(encoding="utf-8")
        assert not re.search(r'sys\.path\.(insert|append)\([^)]*"tools"', text), path
        assert "syspath_prepend(" not in text or '"tools"' not in text, path


def test_cli_reference_is_current():
    res = subprocess.run([sys.executable, str(ROOT / "tools" / "cli_reference.py"), "--check"], capture_output=True,
                         text=True, cwd=ROOT, timeout=120)
    assert res.returncode == 0, res.stderr
