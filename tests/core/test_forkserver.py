"""forkserver_context: the run processes import the ``sumo_ethics`` the parent imports, also when the
command is started from a folder holding another ``sumo_ethics`` (Python 3.11's forkserver put the
current directory first on its sys.path, so every run process imported that one)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="needs the forkserver start method")

# run by path: the parent's sys.path starts with the script's folder, not the current directory
PROBE = '''
import json
import sys

import sumo_ethics


def report(conn):
    import sumo_ethics
    conn.send(sumo_ethics.__file__)
    conn.close()


if __name__ == "__main__":
    if sys.argv[1] == "fixed":
        from sumo_ethics.processes import forkserver_context
        ctx = forkserver_context(["sumo_ethics"])
    else:
        import multiprocessing
        ctx = multiprocessing.get_context("forkserver")
        ctx.set_forkserver_preload(["sumo_ethics"])
    recv, send = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=report, args=(send,), daemon=True)
    proc.start()
    send.close()
    child = recv.recv() if recv.poll(60) else None
    proc.join(10)
    if proc.is_alive():
        proc.kill()
        proc.join(5)
    print(json.dumps({"parent": sumo_ethics.__file__, "child": child}))
'''


def _files(tmp_path: Path, how: str) -> tuple[Path, Path]:
    shadow = tmp_path / "shadow"
    (shadow / "sumo_ethics").mkdir(parents=True, exist_ok=True)
    (shadow / "sumo_ethics" / "__init__.py").write_text("SHADOW = True\n")
    script = tmp_path / "run" / "probe.py"
    script.parent.mkdir(exist_ok=True)
    script.write_text(PROBE)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONSAFEPATH"}
    out = subprocess.run([sys.executable, str(script), how], cwd=shadow, env=env, capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    files = json.loads(out.stdout.strip().splitlines()[-1])
    assert files["child"] is not None, "the run process sent nothing back"
    return Path(files["parent"]).resolve(), Path(files["child"]).resolve()


@pytest.mark.skipif(sys.version_info < (3, 11), reason="PYTHONSAFEPATH is Python 3.11+")
def test_run_processes_import_the_parents_package_not_the_cwds(tmp_path):
    parent, child = _files(tmp_path, "fixed")
    shadow = (tmp_path / "shadow").resolve()
    assert not parent.is_relative_to(shadow)
    assert child == parent
    assert not child.is_relative_to(shadow)


def test_a_plain_forkserver_imports_the_cwds_package(tmp_path):
    """The case above without forkserver_context: the run process imports the folder's copy (Python
    3.11; a Python whose forkserver uses the parent's sys.path would not, and the test says so)."""
    parent, child = _files(tmp_path, "plain")
    shadow = (tmp_path / "shadow").resolve()
    assert not parent.is_relative_to(shadow)
    if child == parent:
        pytest.skip(f"Python {sys.version.split()[0]}'s forkserver imports what the parent imports")
    assert child == shadow / "sumo_ethics" / "__init__.py"
