"""The predictors by name: every place that offers or builds a predictor reads this registry.

    from sumo_ethics.predict import registry

    registry.register("ca", ConstantAccelerationPredictor)       # one line per predictor
    registry.names()                                             # ('map_cslstm', 'map', ..., 'cv', 'ca')
    registry.make("ca")                                          # a new predictor

Readers: the command line's ``--predictor`` choices (``run``, ``sweep``), the planner
configuration's check of ``predictor`` and ``predictor_weights`` and the planner's predictor
(:class:`sumo_ethics.plan.ethical.PlannerConfig`, :func:`sumo_ethics.plan.ethical.make_predictor`),
hence the ``[planner]`` table of ``--config``, ``sweep --set predictor=...`` and ``evaluate
--planner 'x=predictor=...'``; and the fleet, which shares one predictor among its egos when the
entry says it may (:func:`sumo_ethics.runner.fleet.make_fleet_controllers`).

A factory is a callable or a ``"module:attribute"`` string imported on the first :func:`make`, so
naming the learned predictors imports no torch. The shipped predictors are registered at the end
of this module, one line each. Another package adds its own through the entry point group
:data:`GROUP` (``[project.entry-points."sumo_ethics.predictors"]`` in its pyproject.toml, ``ca =
"my_package.ca"``): the first :func:`names` of a process, or :func:`get` of a name not registered
yet, imports each such module, whose ``register(...)`` line then runs; so its predictor is a choice
of the command line and known to every run, sweep and evaluation process without an import of it
anywhere.
"""

from __future__ import annotations

import importlib
import warnings
from dataclasses import dataclass, field
from typing import Any, Callable

from sumo_ethics.errors import ConfigError
from sumo_ethics.predict.protocols import MapSourceFactory, Predictor

__all__ = ["GROUP", "Entry", "RegistryError", "register", "unregister", "get", "names", "check", "make"]


class RegistryError(ValueError):
    """A registration the registry refuses: a name taken, a bad name or factory."""


@dataclass(frozen=True)
class Entry:
    """One registered predictor.

    factory: builds it, called with ``options`` and, by the flags, ``weights`` and ``calibrated``
    (learned) and ``maps`` (needs_map); a callable or ``"module:attribute"``.
    learned: reads a weights file (``predictor_weights``; None: its shipped one) and a calibration
    beside it (``calibrated``); a predictor that is not learned refuses a weights file.
    needs_map: given the run's map source factory (``maps``: map version -> :class:`MapSource`).
    shareable: a fleet's egos may share one instance, predicting all their neighbours in one
    batched call per step (:class:`sumo_ethics.runner.fleet.SharedPrediction`); False for a
    predictor that keeps state of one ego between calls: each ego gets its own, called in the
    thread its planner runs on (so a map-aware predictor, which reads SUMO, must be shareable).
    summary: one line for the documentation and error messages.
    options: keyword arguments always passed to the factory (e.g. the LSTM's ``kind``).
    """

    name: str
    factory: Callable[..., Predictor] | str
    learned: bool = False
    needs_map: bool = False
    shareable: bool = True
    summary: str = ""
    options: dict[str, Any] = field(default_factory=dict)

    def resolve(self) -> Callable[..., Predictor]:
        """The factory itself (a ``"module:attribute"`` string imported now)."""
        if not isinstance(self.factory, str):
            return self.factory
        module, _, attr = self.factory.partition(":")
        return getattr(importlib.import_module(module), attr)


#: the entry point group of other packages' predictor modules (imported once per process, see above)
GROUP = "sumo_ethics.predictors"

_ENTRIES: dict[str, Entry] = {}
_plugins_loaded = False


def _load_plugins() -> None:
    """Import the modules of the :data:`GROUP` entry points once (each registers its predictors);
    one that fails to import is skipped with a warning naming it (the shipped predictors still work)."""
    global _plugins_loaded
    if _plugins_loaded:
        return
    _plugins_loaded = True
    from importlib.metadata import entry_points

    for ep in entry_points(group=GROUP):
        try:
            ep.load()
        except Exception as exc:  # noqa: BLE001 - another package's bug must not stop the shipped predictors
            warnings.warn(f"predictor plugin {ep.name!r} ({ep.value}) failed to load: {exc!r}", RuntimeWarning,
                          stacklevel=2)


def register(name: str, factory: Callable[..., Predictor] | str, *, learned: bool = False, needs_map: bool = False,
             shareable: bool = True, summary: str = "", **options: Any) -> Entry:
    """Register predictor ``name`` (letters, digits, ``_``; the value of ``--predictor`` and of the
    planner's ``predictor`` key), built by ``factory`` (see :class:`Entry`); ``options`` are passed
    to the factory at every :func:`make`. A name already registered is refused (:class:`RegistryError`:
    :func:`unregister` it first to replace it)."""
    if not (isinstance(name, str) and name and name.replace("_", "").isalnum() and name.isascii()):
        raise RegistryError(f"a predictor's name must be letters, digits or '_', got {name!r}")
    if name in _ENTRIES:
        raise RegistryError(f"predictor {name!r} is already registered (by {_describe(_ENTRIES[name].factory)}); "
                            f"unregister it first to replace it")
    if needs_map and not shareable:
        raise RegistryError(f"predictor {name!r}: a map-aware predictor must be shareable (a fleet's egos plan on "
                            "several threads, and only the fleet's own thread may read SUMO's map: it predicts "
                            "for them all there)")
    if not (callable(factory) or (isinstance(factory, str) and factory.count(":") == 1)):
        raise RegistryError(f"predictor {name!r}: the factory must be a callable or 'module:attribute', got {factory!r}")
    entry = Entry(name, factory, learned=bool(learned), needs_map=bool(needs_map), shareable=bool(shareable),
                  summary=summary, options=dict(options))
    _ENTRIES[name] = entry
    return entry


def unregister(name: str) -> Entry:
    """Remove predictor ``name`` (a ConfigError if it is not registered) and return its entry."""
    entry = get(name)
    del _ENTRIES[name]
    return entry


def get(name: str) -> Entry:
    """The entry of predictor ``name``; a ConfigError naming the known ones if there is none."""
    try:
        return _ENTRIES[name]
    except (KeyError, TypeError):
        pass
    _load_plugins()  # only for a name not registered yet: PlannerConfig() at import time loads no plugin
    try:
        return _ENTRIES[name]
    except (KeyError, TypeError):
        raise ConfigError(f"unknown predictor '{name}'; known: {', '.join(_ENTRIES)}") from None


def names(*, learned: bool | None = None) -> tuple[str, ...]:
    """The registered names in the order of registration (the shipped ones first); ``learned``:
    only the learned (True) or the other (False) predictors."""
    _load_plugins()
    return tuple(n for n, e in _ENTRIES.items() if learned is None or e.learned == learned)


def check(name: str, weights: str | None = None) -> Entry:
    """ConfigError for an unknown ``name`` or a weights file given to a predictor that reads none."""
    entry = get(name)
    if weights and not entry.learned:
        what = f" ({entry.summary})" if entry.summary else ""
        raise ConfigError(f"predictor_weights is a weights file for a learned predictor "
                          f"({', '.join(names(learned=True))}); predictor '{name}'{what} has none")
    return entry


def make(name: str, *, weights: str | None = None, calibrated: bool = True, maps: MapSourceFactory | None = None,
         **options: Any) -> Predictor:
    """A new predictor ``name``: its factory called with the entry's options and ``options``, a
    learned one's with ``weights`` (None: the shipped file) and ``calibrated``, a map-aware one's
    with ``maps`` (None: it predicts without map context)."""
    entry = check(name, weights)
    kwargs = {**entry.options, **options}
    if entry.learned:
        kwargs.update(weights=weights, calibrated=calibrated)
    if entry.needs_map:
        kwargs["maps"] = maps
    return entry.resolve()(**kwargs)


def _describe(factory: Callable[..., Any] | str) -> str:
    if isinstance(factory, str):
        return factory
    return f"{getattr(factory, '__module__', '?')}:{getattr(factory, '__qualname__', repr(factory))}"


# ---- the shipped predictors, one line each (the first learned one, "map", is the planner's default) ----
_LSTM = "sumo_ethics.predict.predictor:lstm"
register("map_cslstm", _LSTM, learned=True, needs_map=True, kind="map_cslstm", summary="CS-LSTM reading lanes and signals")
register("map", _LSTM, learned=True, needs_map=True, kind="map", summary="the attention LSTM reading lanes and signals")
register("attention", _LSTM, learned=True, kind="attention", summary="the paper's attention LSTM")
register("cslstm", _LSTM, learned=True, kind="cslstm", summary="CS-LSTM")
register("cv", "sumo_ethics.predict.constant_velocity:ConstantVelocityPredictor", summary="constant velocity")
