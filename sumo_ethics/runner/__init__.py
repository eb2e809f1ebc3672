"""Running a scenario: ``run(config) -> RunSummary``.

:func:`run` starts the one simulation loop (:mod:`sumo_ethics.runner.loop`) with one ego, or with a
fleet of them (:mod:`sumo_ethics.runner.fleet`, which drives each ego as the loop does), and picks
what drives the ego (:func:`make_controller`). Each step: read (``SumoWorld.read`` -> Scene) -> act
(``controller.act`` -> Decision; the run's :class:`~sumo_ethics.contract.StepHook` s around it) -> step (``SumoWorld.step``: moveToXY, simulationStep) -> detect
(``collision.CollisionBook``) -> record (``record.recorder.RunRecorder.step``). Whatever happens (a
SUMO error, the ego leaving the network, Ctrl-C), the rows recorded so far and a summary saying why
the run ended are written to the run folder.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Callable

from sumo_ethics.config import RunConfig
from sumo_ethics.contract import Controller, StepHook, as_hook
from sumo_ethics.errors import ConfigError
from sumo_ethics.runner.loop import OUTPUT_NAMES, Run, RunSummary, execute, prepare_out, resolved_end
from sumo_ethics.sim.gui import GuiOptions
from sumo_ethics.sim.lanes import SumoMapSource
from sumo_ethics.sim.sight import sight_map

__all__ = ["CONTROLLERS", "OUTPUT_NAMES", "Run", "RunSummary", "StepHook", "execute", "make_controller",
           "prepare_out", "resolved_end", "run"]


CONTROLLERS = ("ethical", "baseline")


def make_controller(cfg: RunConfig) -> Controller:
    """The controller named by ``cfg.controller``: "ethical" (the planner) or "baseline"."""
    if cfg.controller == "baseline":
        from sumo_ethics.plan.baseline import RouteFollower

        return RouteFollower()
    if cfg.controller == "ethical":
        from sumo_ethics.plan.ethical import EthicalPlanner, PlannerConfig
        from sumo_ethics.settings import check_grid_size

        planner = cfg.planner or PlannerConfig()
        # also for a PlannerConfig built in Python, not from settings; the bounds that depend on the
        # step are checked at the run's step when the run starts (loop.on_run_step)
        check_grid_size(planner.sampling)
        return EthicalPlanner(planner, maps=SumoMapSource, sight=sight_map)
    raise ConfigError(f"unknown controller '{cfg.controller}'; known: {', '.join(CONTROLLERS)}")


def _imported(cfg: RunConfig, hooks: tuple[StepHook, ...]) -> tuple[RunConfig, tuple[StepHook, ...]]:
    """A folder written by ``import-commonroad`` (``commonroad.json`` beside the sumocfg): its own ego
    (the planning problem's) and the hook that places it, replays the obstacles and checks the goal."""
    from sumo_ethics.sim.commonroad_run import CommonRoadHook, marker_of

    marker = marker_of(cfg.scenario)
    if marker is None:
        return cfg, hooks
    if cfg.ego_id not in (None, "ego") or cfg.ego_from is not None:
        raise ConfigError(f"{cfg.scenario.name} is an imported CommonRoad scenario: its ego is the planning "
                          "problem's; drop --ego/--ego-from/--ego-to")
    return replace(cfg, ego_id="ego"), hooks + (CommonRoadHook(marker),)


def run(cfg: RunConfig, controller: Controller | None = None, hooks: tuple[StepHook | Callable[[Any, Any], None], ...] = (),
        gui: GuiOptions | None = None) -> RunSummary:
    """Run one scenario; writes the run folder and returns the summary.

    hooks: :class:`~sumo_ethics.contract.StepHook` s, called at the loop's phases (start,
    on_read, desired_speed, before_act, after_step, route_end, summary; they may act on SUMO,
    e.g. inject hazards; only code under ``sumo_ethics/sim`` should); a plain callable
    ``hook(snapshot, world)`` is wrapped as :class:`~sumo_ethics.contract.FunctionHook` (its ``on_read``). gui: run in sumo-gui through TraCI, the view following
    the ego and each decision drawn (single ego only; the same outputs as without).

    Raises ConfigError for bad input (the run folder is left as it was). Everything else ends
    with the outputs written so far and a summary saying how the run ended, then raises:
    SimulationError (SUMO failed, status ``error``), OutputError (the outputs could not be
    written, e.g. a full disk), KeyboardInterrupt on Ctrl-C and :class:`Terminated` on SIGTERM
    (status ``interrupted``).
    """
    if cfg.fleet is not None:
        if gui is not None:
            raise ConfigError("--gui shows a single ego; drop the fleet options (--egos, --penetration, "
                              "several --ego, --fleet)")
        if hooks:
            raise ConfigError("a fleet run (--egos, --penetration, several --ego) takes no hooks (hazards)")
        from sumo_ethics.sim.commonroad_run import marker_of

        if marker_of(cfg.scenario) is not None:
            raise ConfigError(f"{cfg.scenario.name} is an imported CommonRoad scenario: its one ego is the planning "
                              "problem's; drop --egos/--penetration/--fleet")
        from sumo_ethics.runner.fleet import run_fleet

        return run_fleet(cfg)
    cfg, hooks = _imported(cfg, tuple(as_hook(h) for h in hooks))
    controller = controller or make_controller(cfg)
    return execute(Run(cfg, controller, tuple(hooks), gui), cfg)


