"""Wrap a controller so that a scenario's hazards are injected every step before it acts.

Until the runner has a per-step hook, this is how hazards reach the simulation: the runner
calls ``act(scene)`` once per step, before it applies the ego's command and steps SUMO, which
is exactly when the injector must command its actors for the same step.
"""

from __future__ import annotations

from typing import Any

from sumo_ethics.contract import Controller, Decision, Scene


class HazardController:
    """``inner`` with ``injector.on_step(scene)`` called first, each step."""

    def __init__(self, inner: Controller, injector: Any) -> None:
        self.inner = inner
        self.injector = injector
        self.name = inner.name
        self.needs_history = getattr(inner, "needs_history", False)
        self.needs_rules = getattr(inner, "needs_rules", False)

    def act(self, scene: Scene) -> Decision:
        self.injector.on_step(scene)
        return self.inner.act(scene)
