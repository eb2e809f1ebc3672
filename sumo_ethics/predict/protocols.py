"""The predictor's seams: what the planner calls (:class:`Predictor`) and what a map-aware predictor
reads lanes and signals from (:class:`MapSource`, made per map version by a :data:`MapSourceFactory`).

numpy only: the planner (``plan/``), the fleet (``runner/fleet.py``) and the registry
(:mod:`sumo_ethics.predict.registry`) import these without torch or libsumo.
"""

from __future__ import annotations

from typing import Any, Callable, Protocol

import numpy as np

from sumo_ethics.types import Observation, Prediction

__all__ = ["Predictor", "MapSource", "MapSourceFactory"]


class Predictor(Protocol):
    """Predicts every road user of ``obs.current``: ``horizon_steps`` steps of ``dt`` [s] after
    ``obs.time``, one row per agent in the order of ``obs.current.ids`` (means (N, T, 2) [m],
    covariances (N, T, 2, 2) [m^2], headings (N, T) [rad]; optional further modes with weights)."""

    def predict(self, obs: Observation, horizon_steps: int, dt: float) -> Prediction: ...


class MapSource(Protocol):
    """The map context of agents for a map-aware predictor: (ids, is_person (N,)) ->
    (LaneGraph | None, MapContext) of those agents (:mod:`sumo_ethics.predict.features`); in a run
    :class:`sumo_ethics.sim.lanes.SumoMapSource` reads them from the running simulation."""

    def __call__(self, ids: tuple[str, ...], person: np.ndarray, /) -> tuple[Any, Any]: ...


#: map version of the model (its weights file's ``map_version``) -> the map source it reads
#: (in a run: ``sim.lanes.SumoMapSource``, which looks up only what that version reads)
MapSourceFactory = Callable[[int], MapSource]
