"""Trajectory prediction: constant velocity baseline and LSTM predictors (CS-LSTM, attention, map-aware attention).

The predictors by name: :mod:`sumo_ethics.predict.registry` (``registry.names()``, ``registry.make(name)``);
what a predictor and a map source are: :mod:`sumo_ethics.predict.protocols`.

Importing this package is cheap: torch is imported only when an LSTM class or the
training/evaluation code is first used (attributes resolve lazily), or a learned predictor is made.
"""

from __future__ import annotations

import importlib
import sys
from typing import TYPE_CHECKING, Any


class PredictorError(RuntimeError):
    """A predictor cannot be built: missing, corrupt or incompatible weights file."""


_LAZY = {
    "ConstantVelocityPredictor": "sumo_ethics.predict.constant_velocity",
    "LSTMPredictor": "sumo_ethics.predict.predictor",
    "train_model": "sumo_ethics.predict.train",
    "evaluate": "sumo_ethics.predict.accuracy",
    "train_main": "sumo_ethics.predict.commands",
    "evaluate_main": "sumo_ethics.predict.commands",
}

__all__ = ["PredictorError", "one_thread", *_LAZY]


def one_thread(load: bool = False) -> None:
    """torch and the risk kernels (:mod:`sumo_ethics.cores`) on one thread in this process: a
    sweep's or an evaluation's runs share the cores (every executor gives the same numbers);
    ``load=False`` leaves a process that has not imported torch alone, ``load=True`` imports it (a
    no-op without torch)."""
    from sumo_ethics import cores

    cores.set_threads(1)
    if not load and "torch" not in sys.modules:
        return
    try:
        import torch
    except ImportError:
        return
    torch.set_num_threads(1)


if TYPE_CHECKING:  # pragma: no cover - the lazy attributes of _LAZY, for type checkers
    from sumo_ethics.predict.commands import evaluate_main, train_main  # noqa: F401
    from sumo_ethics.predict.constant_velocity import ConstantVelocityPredictor  # noqa: F401
    from sumo_ethics.predict.accuracy import evaluate  # noqa: F401
    from sumo_ethics.predict.predictor import LSTMPredictor  # noqa: F401
    from sumo_ethics.predict.train import train_model  # noqa: F401


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'sumo_ethics.predict' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value
