"""The recent past of the ego's neighbours, kept per agent, for a predictor's Observation."""

from __future__ import annotations

import math

import numpy as np

from sumo_ethics.types import AgentStates, Observation


class History:
    """Ring buffers of each neighbour's centre over the last ``seconds`` (one row per step).

    Agents out of sight for longer than the buffer are forgotten; an agent seen again after a
    gap keeps its old rows (its track is interrupted, not invented: rows of the gap are invalid).
    """

    def __init__(self, dt: float, seconds: float = 3.0) -> None:
        self.dt = dt
        self.h = int(math.ceil(seconds / dt - 1e-9)) + 1  # H rows, the last is "now"
        self._xy: dict[str, np.ndarray] = {}  # id -> (H, 2)
        self._valid: dict[str, np.ndarray] = {}  # id -> (H,)
        self._last: dict[str, int] = {}  # id -> step index of the last sighting
        self._step = -1

    def push(self, others: AgentStates) -> None:
        """Append one step's sightings."""
        self._step += 1
        for i, k in enumerate(others.ids):
            xy, valid = self._xy.get(k), self._valid.get(k)
            gap = self._step - self._last.get(k, self._step - self.h)
            if xy is None or valid is None or gap >= self.h:  # the two are kept together
                xy, valid = np.zeros((self.h, 2)), np.zeros(self.h, dtype=bool)
                self._xy[k], self._valid[k] = xy, valid
            else:
                xy[:-gap], valid[:-gap] = xy[gap:].copy(), valid[gap:].copy()
                valid[-gap:] = False
            xy[-1] = others.x[i], others.y[i]
            valid[-1] = True
            self._last[k] = self._step
        stale = [k for k, s in self._last.items() if self._step - s >= self.h]
        for k in stale:
            del self._xy[k], self._valid[k], self._last[k]

    def observation(self, time: float, ego: AgentStates, others: AgentStates) -> Observation:
        """Observation of the agents in ``others`` (pushed this step), history (N, H, 2)."""
        n = len(others)
        hist = np.zeros((n, self.h, 2))
        valid = np.zeros((n, self.h), dtype=bool)
        for i, k in enumerate(others.ids):
            hist[i], valid[i] = self._xy[k], self._valid[k]
        return Observation(time=time, dt=self.dt, history=hist, valid=valid, current=others, ego=ego)
