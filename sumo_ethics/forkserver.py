"""The forkserver context the sweep's and the evaluation's run processes are started from.

Python 3.11's forkserver is started as ``python -c ...``, which puts the current directory first on
its ``sys.path``, and it ignores the parent's ``sys.path``: started from a folder holding another
``sumo_ethics`` (a checkout of another version), every run process imported that one while the
parent ran the installed package. So the server is started here, at once, with ``PYTHONSAFEPATH=1``
(the current directory is not put on ``sys.path``): it imports what the parent imports. Python 3.10
knows no ``PYTHONSAFEPATH``; there the current directory still comes first.
"""

from __future__ import annotations

import multiprocessing
import multiprocessing.forkserver
import os
from typing import TYPE_CHECKING

from sumo_ethics.sumo_options import NO_SUMO_ENV

if TYPE_CHECKING:
    from multiprocessing.context import ForkServerContext  # defined on POSIX only


def forkserver_context(preload: list[str]) -> ForkServerContext:
    """The forkserver context with ``preload`` preloaded, its server already started (with
    ``PYTHONSAFEPATH=1`` for that start alone; the variable stays in the server's environment, so
    in the run processes' too). A server already running in this process is reused as it is."""
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(preload)
    before = os.environ.get("PYTHONSAFEPATH")
    os.environ["PYTHONSAFEPATH"] = "1"
    # the server outlives the test that starts it: it does not keep the tests' bar on SUMO starts
    barred = os.environ.pop(NO_SUMO_ENV, None)
    try:
        multiprocessing.forkserver.ensure_running()
    finally:
        if before is None:
            os.environ.pop("PYTHONSAFEPATH", None)
        else:
            os.environ["PYTHONSAFEPATH"] = before
        if barred is not None:
            os.environ[NO_SUMO_ENV] = barred
    return ctx
