"""sumo_ethics.fileio: a file is written whole under its final name or not at all."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from sumo_ethics import fileio


def test_written_under_a_temporary_name_then_renamed(tmp_path):
    target = tmp_path / "steps.parquet"
    with fileio.replacing(target) as tmp:
        assert tmp == tmp_path / ".steps.parquet.tmp"
        tmp.write_bytes(b"abc")
        assert not target.exists()  # nothing under the final name while writing
    assert target.read_bytes() == b"abc"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["steps.parquet"]


@pytest.mark.parametrize("exc", [OSError("No space left on device"), KeyboardInterrupt()])
def test_a_failed_write_keeps_the_old_file_and_no_temporary(tmp_path, exc):
    target = tmp_path / "manifest.json"
    target.write_text("old")
    with pytest.raises(type(exc)):
        with fileio.replacing(target, tmp_name=".manifest.json.tmp-123") as tmp:
            tmp.write_text("half")
            raise exc
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["manifest.json"]


def test_a_temporary_name_of_the_callers_choice(tmp_path):
    """replay's writer picks the format by the suffix, so its temporary name keeps it."""
    target = tmp_path / "run.gif"
    with fileio.replacing(target, ".run.part.gif") as tmp:
        assert tmp.name == ".run.part.gif"
        tmp.write_bytes(b"GIF89a")
    assert target.read_bytes() == b"GIF89a"


def test_durable_syncs_the_file_and_then_the_folder(tmp_path, monkeypatch):
    synced: list[str] = []
    real = os.fsync

    def spy(fd: int) -> None:
        synced.append(os.readlink(f"/proc/self/fd/{fd}"))
        real(fd)

    monkeypatch.setattr(os, "fsync", spy)
    target = tmp_path / "run_000000.parquet"
    fileio.write_bytes(target, b"rows", tmp_name="run_000000.parquet.part", durable=True)
    assert synced == [str(tmp_path / "run_000000.parquet.part"), str(tmp_path)]
    assert target.read_bytes() == b"rows"
    synced.clear()
    fileio.write_bytes(tmp_path / "plain.bin", b"x")  # not durable: no sync
    assert synced == []


def test_write_json_bytes(tmp_path):
    target = tmp_path / "summary.json"
    fileio.write_json(target, {"status": "goal", "out": Path("/r/run"), "n": [1, 2]})
    assert target.read_text() == '{\n  "status": "goal",\n  "out": "/r/run",\n  "n": [\n    1,\n    2\n  ]\n}\n'
