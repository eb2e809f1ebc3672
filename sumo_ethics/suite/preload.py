"""Imported once by the evaluation's forkserver, so each per-run worker forks with these loaded
(libsumo through the SUMO adapter, torch through the predictor: their only importers)."""

import pandas  # noqa: F401

import sumo_ethics.predict.predictor  # noqa: F401
import sumo_ethics.runner  # noqa: F401
import sumo_ethics.sim.hazards  # noqa: F401
import sumo_ethics.sim.session  # noqa: F401
