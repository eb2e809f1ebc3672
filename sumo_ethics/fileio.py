"""Files written whole or not at all: a temporary name beside the file, then one rename.

Every file a command finishes (run outputs, a sweep's manifest, a decisions trace, weights, a
replay, a dataset build's kept runs) is written through :func:`replacing`, so a reader, a kill
or a full disk never leaves half a file under the final name. ``durable=True`` also syncs the
file and the folder before returning (the rename survives a power cut), for files that count
as finished work on the next start.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any


@contextmanager
def replacing(path: Path, tmp_name: str | None = None, durable: bool = False) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (``tmp_name``, default ``.<name>.tmp``) to write
    to; on a normal exit rename it to ``path``, on an exception remove it and re-raise."""
    path = Path(path)
    tmp = path.with_name(tmp_name or f".{path.name}.tmp")
    try:
        yield tmp
        if durable:
            _fsync(tmp)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    if durable:
        _fsync(path.parent)  # the rename itself


def _fsync(path: Path) -> None:
    """A file's or a folder's data on the disk (a read-only descriptor serves for both)."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_bytes(path: Path, data: bytes, tmp_name: str | None = None, durable: bool = False) -> None:
    """``data`` to ``path`` through :func:`replacing`."""
    with replacing(path, tmp_name, durable) as tmp:
        tmp.write_bytes(data)


def write_json(path: Path, data: Any, tmp_name: str | None = None) -> None:
    """``data`` as indented JSON (one trailing newline; unknown types as ``str``) through :func:`replacing`."""
    write_bytes(path, (json.dumps(data, indent=2, default=str) + "\n").encode(), tmp_name)
