"""Imported once by the evaluation's forkserver, so each per-run worker forks with these loaded."""

import libsumo  # noqa: F401
import pandas  # noqa: F401

try:
    import torch  # noqa: F401

    torch.set_num_threads(1)
except ImportError:  # pragma: no cover
    pass

import sumo_ethics.predict  # noqa: F401
import sumo_ethics.runner  # noqa: F401
import sumo_ethics.sim.hazards  # noqa: F401
