"""Trajectories of a suite scenario's road users, hazard actors included, for the predictor's
training and evaluation data (``sumo-ethics dataset --suite``).

The scenario runs as the suite defines it (its seed, ego route and hazards) with the ethical planner
(constant-velocity prediction) driving the ego; a :class:`~sumo_ethics.sim.trajectories.TrafficRecorder` reads every road
user but the ego each step, so cut-ins, drifts, emergency stops, red-light runners and
pedestrians stepping out appear in the data as they appear to the planner.
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from sumo_ethics.contract import Scene, StepHook


class _Recording(StepHook):
    """A run hook: every step, after the hazards (the hook before it) and before the controller
    acts, record every road user but the ego."""

    def __init__(self) -> None:
        self.recorder: Any = None

    def before_act(self, scene: Scene) -> None:
        from sumo_ethics.sim.trajectories import TrafficRecorder

        if self.recorder is None:
            self.recorder = TrafficRecorder(skip=tuple(scene.ego.ids))
        self.recorder.step()


def record_scenario(scenario_dir: Path | str, scratch_root: str | None = None) -> tuple[pd.DataFrame, Any]:
    """Run one suite scenario (ethical planner with constant velocity, its hazards) -> (trajectory rows, lane graph).

    Rows have the columns of ``predict.samples``' trajectories but run_id/seed/scenario/scale,
    which the caller adds. Runs SUMO in this process (call it in a worker process); the run's
    outputs go to a temporary folder inside ``scratch_root`` (None: the system's)."""
    from sumo_ethics.runner import make_controller, run
    from sumo_ethics.settings import planner_config
    from sumo_ethics.sim.hazards import HazardInjector
    from sumo_ethics.suite.spec import load

    spec = load(Path(scenario_dir))
    with tempfile.TemporaryDirectory(dir=scratch_root) as tmp:
        # the ethical planner with constant-velocity prediction: it avoids most hazards, so the
        # run (and the hazard actors' tracks) goes on after them; it is fast
        cfg = spec.run_config(Path(tmp) / "run", planner_config(None, predictor="cv"), overwrite=True)
        traffic = _Recording()
        try:
            run(cfg, controller=make_controller(cfg), hooks=(HazardInjector(spec.hazards), traffic))
        except Exception:  # noqa: BLE001 - a run that ends in an error still leaves its trajectories
            pass
    if traffic.recorder is None:
        return pd.DataFrame(), None
    c = traffic.recorder.cols
    df = pd.DataFrame({
        "time": np.array(c["time"]), "agent_id": np.array(c["agent_id"], dtype=str),
        "cls": np.array(c["cls"], dtype=np.int8), "x": np.array(c["x"]), "y": np.array(c["y"]),
        "yaw": np.array(c["yaw"]), "speed": np.array(c["speed"], dtype=np.float32),
        "length": np.array(c["length"], dtype=np.float32), "width": np.array(c["width"], dtype=np.float32),
        "lane": np.array(c["lane"], dtype=np.int32), "lane_pos": np.array(c["lane_pos"], dtype=np.float32),
        "tls_dist": np.array(c["tls_dist"], dtype=np.float32), "tls_state": np.array(c["tls_state"], dtype=np.int8),
        "next_lane": np.array(c["next_lane"], dtype=np.int32),
        "tls_switch": np.array(c["tls_switch"], dtype=np.float32),
        "blinker": np.array(c["blinker"], dtype=np.int8),
        "after_lane": np.array(c["after_lane"], dtype=np.int32),
    })
    return df, traffic.recorder.graph
