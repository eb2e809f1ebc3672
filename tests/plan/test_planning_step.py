"""One step length: the planner plans on the run's step (--step-length, else the scenario's
<step-length>, else 0.1 s). A ``[planner.sampling] dt`` that differs is refused with one line naming
both; the candidate grid's memory bounds are checked at the run's step, before SUMO starts."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from conftest import SCENARIOS

from sumo_ethics.errors import ConfigError

TESTBED = SCENARIOS / "testbed" / "testbed.sumocfg"  # <step-length value="0.1"/>
SWEEP_FAST = ["--omega-u", "1", "--seeds", "0", "--end", "5", "--quiet"]


def _toml(folder: Path, text: str) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    p = folder / "p.toml"
    p.write_text(text)
    return p


def _cli(args: list[str], capfd) -> tuple[int, list[str]]:
    from sumo_ethics.cli import main

    capfd.readouterr()
    code = main(args)
    out, err = capfd.readouterr()
    assert "Traceback" not in out + err
    return code, [ln for ln in err.splitlines() if ln.strip()]


# ---- [planner.sampling] dt -------------------------------------------------------------------
def test_sampling_dt_that_differs_from_the_step_is_refused_in_one_line(tmp_path):
    """A real process: exit 2, one line on stderr, no traceback, nothing written."""
    cfg = _toml(tmp_path / "c", "[planner.sampling]\ndt = 0.05\n")
    out = tmp_path / "out"
    p = subprocess.run([sys.executable, "-m", "sumo_ethics.cli", "run", str(TESTBED), "--config", str(cfg),
                        "--out", str(out), "--quiet"], capture_output=True, text=True, timeout=300)
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert p.returncode == 2, p.stderr
    assert len(lines) == 1 and "Traceback" not in p.stderr, p.stderr
    assert lines[0] == ("error: [planner.sampling] dt = 0.05 s differs from the run's step of 0.1 s (the scenario's "
                        "<step-length>): the planner plans on the run's step; run with --step-length 0.05 (or set "
                        "the scenario's <step-length>), or drop dt")
    assert not out.exists()


def test_sampling_dt_against_step_length_names_both(tmp_path, capfd):
    cfg = _toml(tmp_path / "c", "[planner.sampling]\ndt = 0.1\n")
    code, lines = _cli(["run", str(TESTBED), "--config", str(cfg), "--step-length", "0.05",
                        "--out", str(tmp_path / "out"), "--quiet"], capfd)
    assert code == 2 and len(lines) == 1, lines
    assert "dt = 0.1 s differs from the run's step of 0.05 s (--step-length)" in lines[0]


def test_sampling_dt_equal_to_the_step_acts_and_the_grid_plans_on_the_step():
    from sumo_ethics.settings import planner_config

    assert planner_config({"sampling": {"dt": 0.05}}, step=0.05, step_source="--step-length").sampling.dt == 0.05
    # not given: the grid takes the run's step (no second source of truth)
    pc = planner_config(None, step=0.04, step_source="scenario")
    assert pc.sampling.dt == 0.04 and pc.sampling.n_steps == 100  # 4 s / 0.04 s
    with pytest.raises(ConfigError, match=r"dt = 0.2 s differs from the run's step of 0.1 s \(the scenario's"):
        planner_config({"sampling": {"dt": 0.2}}, step=0.1, step_source="scenario")


def test_the_runner_puts_the_planner_on_the_run_step(tmp_path):
    """For a PlannerConfig built in Python: its grid is checked and set to the run's step (config.json
    records the step the planner plans on)."""
    from sumo_ethics.config import RunConfig
    from sumo_ethics.plan.ethical import PlannerConfig
    from sumo_ethics.runner.loop import on_run_step

    cfg = RunConfig(TESTBED, tmp_path / "o", planner=PlannerConfig())
    assert on_run_step(cfg, 0.05, "--step-length").planner.sampling.dt == 0.05
    assert cfg.planner.sampling.dt == 0.1  # the caller's config is left as it was
    with pytest.raises(ConfigError, match="400 steps; the limit is 100 steps"):
        on_run_step(cfg, 0.01, "--step-length")
    with pytest.raises(ConfigError, match="400 steps"):  # the defaults' grid too
        on_run_step(RunConfig(TESTBED, tmp_path / "o"), 0.01, "--step-length")
    assert on_run_step(RunConfig(TESTBED, tmp_path / "o", controller="baseline"), 0.01, "x").planner is None
    # the baseline plans nothing: a planner config beside it (a sweep passes one) is not checked
    base = RunConfig(TESTBED, tmp_path / "o", controller="baseline", planner=PlannerConfig())
    assert on_run_step(base, 0.01, "--step-length") == base


# ---- the memory bound at the run's step ---------------------------------------------------------
def test_step_length_001_is_refused_with_the_default_horizon(tmp_path, capfd):
    """The default grid (longest horizon 4 s) is 40 steps at 0.1 s and 400 at 0.01 s: refused before
    SUMO starts, the line naming the step, the steps and the limit."""
    out = tmp_path / "out"
    code, lines = _cli(["run", str(TESTBED), "--step-length", "0.01", "--out", str(out), "--quiet"], capfd)
    assert code == 2 and len(lines) == 1, lines
    assert lines[0] == ("error: the candidate grid at the run's step of 0.01 s (--step-length): the longest horizon "
                        "of 4 s is 400 steps; the limit is 100 steps (a step of at least 0.04 s, or shorter horizons)")
    assert not out.exists()


def test_candidate_steps_are_counted_at_the_run_step(tmp_path, capfd):
    """1 horizon of 1 s x 50 x 50 = 2500 candidates: 10 steps at 0.1 s (25,000 candidate steps, within
    200,000), 100 steps at 0.01 s (250,000: refused)."""
    from sumo_ethics.settings import planner_config

    table = {"sampling": {"horizons": [1.0], "n_speeds": 50, "n_offsets": 50}}
    assert planner_config(table, step=0.1, step_source="scenario").sampling.n_steps == 10
    cfg = _toml(tmp_path / "c", "[planner.sampling]\nhorizons = [1.0]\nn_speeds = 50\nn_offsets = 50\n")
    code, lines = _cli(["run", str(TESTBED), "--config", str(cfg), "--step-length", "0.01",
                        "--out", str(tmp_path / "out"), "--quiet"], capfd)
    assert code == 2 and len(lines) == 1, lines
    assert lines[0] == ("error: the candidate grid at the run's step of 0.01 s (--step-length): 2500 candidates x "
                        "100 steps = 250000 candidate steps; the limit is 200000 (a step of at least 0.0125 s, "
                        "shorter horizons or fewer candidates)")


def test_the_baseline_is_not_held_to_the_planner_grid(tmp_path, capfd):
    """--controller baseline plans no candidates: --step-length 0.01 passes the settings (the sweep's
    validation builds every run's config, so it gets as far as the runs' validation)."""
    from sumo_ethics.sweep.grid import make_sweep

    sweep = make_sweep(TESTBED, "1", "0", options={"controller": "baseline", "step_length": 0.01, "end": 5.0})
    assert sweep.validate()[0].run_config(tmp_path / "r").step_length == 0.01


def test_sweep_checks_the_grid_at_its_step(tmp_path, capfd):
    out = tmp_path / "sw"
    code, lines = _cli(["sweep", str(TESTBED), *SWEEP_FAST, "--step-length", "0.01", "--out", str(out)], capfd)
    assert code == 2 and len(lines) == 1 and "400 steps; the limit is 100 steps" in lines[0], lines
    code, lines = _cli(["sweep", str(TESTBED), *SWEEP_FAST, "--set", "sampling.dt=0.05", "--out", str(out)], capfd)
    assert code == 2 and len(lines) == 1, lines
    assert "dt = 0.05 s differs from the run's step of 0.1 s (the scenario's <step-length>)" in lines[0]
    assert not (out / "runs").exists()
