"""Wrap a controller so that a scenario's hazards are injected every step before it acts.

The runner has per-step hooks (``runner.loop.StepHook``), but they get the raw snapshot before
the scene is built; the hazard injector (``sim.hazards.HazardInjector.on_step``) reads the
:class:`Scene`: the ego's route, its arc length ``s`` on it, its speed, the time and step. So
the hazards come in through the controller: the runner calls ``act(scene)`` once per ego step,
after the hooks and the scene are read and before it applies the ego's command and steps SUMO,
which is when the injector commands its actors for the next step (t + dt). ``evaluate`` wraps
the controller in this class; ``suite.traffic`` does the same in a wrapper of its own that also
records the traffic.
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
