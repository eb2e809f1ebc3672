"""errors.add_note: the note the CLI prints after an interrupt (cli.main reads ``__notes__``), also on
Python 3.10, where BaseException has no add_note (found by mypy with python_version 3.10)."""

from __future__ import annotations

import types

import pytest

from sumo_ethics import errors
from sumo_ethics.errors import Terminated, add_note


@pytest.mark.parametrize("version", [(3, 10, 14), (3, 11, 0)])
def test_add_note_fills_the_notes_the_cli_reads(monkeypatch, version):
    if version >= (3, 11) and not hasattr(BaseException, "add_note"):
        pytest.skip("BaseException.add_note is Python 3.11+")
    monkeypatch.setattr(errors, "sys", types.SimpleNamespace(version_info=version))
    exc = Terminated()
    add_note(exc, "the steps so far are written")
    add_note(exc, "and a summary")
    assert exc.__notes__ == ["the steps so far are written", "and a summary"]
