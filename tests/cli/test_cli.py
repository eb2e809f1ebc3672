"""The command line: bad input gives one clear line and a non-zero exit, never a traceback."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from conftest import SCENARIOS, write_scenario

URBAN = SCENARIOS / "urban" / "urban.sumocfg"


def cli(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "sumo_ethics.cli", *args], capture_output=True, text=True,
                          cwd=cwd, timeout=300)


def assert_one_line_error(p: subprocess.CompletedProcess, fragment: str, code: int | None = None) -> None:
    assert p.returncode != 0
    if code is not None:
        assert p.returncode == code
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert lines == [lines[0]] and lines[0].startswith("error: "), p.stderr
    assert fragment in lines[0], lines[0]
    assert "Traceback" not in p.stderr + p.stdout


def test_missing_scenario(tmp_path):
    assert_one_line_error(cli("run", str(tmp_path / "nope.sumocfg"), "--out", str(tmp_path / "o")),
                          "scenario file not found", 2)


def test_malformed_scenario(tmp_path):
    bad = tmp_path / "bad.sumocfg"
    bad.write_text("<configuration><input><net-file value='x.net.xml'/></input")
    assert_one_line_error(cli("run", str(bad), "--out", str(tmp_path / "o")), "malformed SUMO config", 2)


def test_missing_network(tmp_path):
    cfg = tmp_path / "c.sumocfg"
    cfg.write_text('<configuration><input><net-file value="gone.net.xml"/></input></configuration>')
    assert_one_line_error(cli("run", str(cfg), "--out", str(tmp_path / "o")), "net-file does not exist", 2)


def test_unknown_ego(tmp_path):
    assert_one_line_error(cli("run", str(URBAN), "--ego", "nobody", "--out", str(tmp_path / "o")),
                          "unknown --ego 'nobody'", 2)


@pytest.mark.parametrize("value", ["0", "-5", "abc", "nan", "inf"])
def test_end_must_be_positive(tmp_path, value):
    assert_one_line_error(cli("run", str(URBAN), "--end", value, "--out", str(tmp_path / "o")), "--end")


def test_unwritable_out(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert_one_line_error(cli("run", str(URBAN), "--out", str(blocker / "sub")), "cannot write to --out", 2)


def test_unknown_edges_and_no_route(tmp_path):
    assert_one_line_error(cli("run", str(URBAN), "--ego-from", "W_in", "--ego-to", "nowhere", "--out",
                              str(tmp_path / "o")), "unknown edge 'nowhere'", 2)
    assert not (tmp_path / "o").exists()  # a run refused for bad input leaves no folder behind
    assert_one_line_error(cli("run", str(URBAN), "--ego-from", "W_in", "--out", str(tmp_path / "o")),
                          "--ego-from and --ego-to go together", 2)


def test_ego_depart_after_the_end(tmp_path):
    assert_one_line_error(cli("run", str(URBAN), "--ego-depart", "700", "--out", str(tmp_path / "o")),
                          "--ego-depart 700 s is not before the end of the simulation (600 s)", 2)


@pytest.mark.sumo
def test_ego_that_never_departs(tmp_path):
    cfg = write_scenario(tmp_path / "s", '<vehicle id="late" type="car" route="r_main" depart="500"/>', end=50)
    assert_one_line_error(cli("run", str(cfg), "--ego", "late", "--out", str(tmp_path / "o")), "never departed", 2)


@pytest.mark.sumo
def test_run_bundled_scenario_prints_summary(tmp_path):
    out = tmp_path / "o"
    p = cli("run", str(URBAN), "--end", "90", "--ego-depart", "20", "--out", str(out), "--seed", "3")
    assert p.returncode == 0, p.stderr
    assert "completed" in p.stdout or "timeout" in p.stdout or "collision" in p.stdout
    summary = json.loads((out / "summary.json").read_text())
    assert summary["seed"] == 3 and summary["forced_sumo_options"]["collision.action"]["forced"] == "warn"
    assert set(summary["harm"]) == {"ego", "third_party", "vru", "total"}
    steps = pd.read_parquet(out / "steps.parquet")
    # the ego's speed is the commanded one, and SUMO reports it too (other drivers see it)
    assert (steps.speed == steps.speed_cmd).all()
    assert (steps.speed_sumo - steps.speed_cmd).abs().max() < 1e-6
    assert json.loads((out / "config.json").read_text())["resolved"]["end"] == 90.0


# ---- planner settings: rejected before SUMO starts -------------------------------------------
@pytest.mark.parametrize("args, fragment", [
    (["--weights", "kantian"], "unknown principle-weight preset 'kantian'"),
    (["--omega-u", "-0.5"], "omega_u"),
    (["--omega-u", "nan"], "omega_u"),
    (["--omega-o", "inf"], "omega_o"),
    (["--controller", "telepathic"], "--controller"),
])
def test_bad_planner_settings(tmp_path, args, fragment):
    out = tmp_path / "o"
    p = cli("run", str(URBAN), "--out", str(out), *args)
    assert_one_line_error(p, fragment)
    assert not (out / "summary.json").exists()  # nothing ran


@pytest.mark.parametrize("toml, fragment", [
    ("[planner]\nomega_u = 0.3\nflavour = 'x'\n", "unknown key(s) in [planner]: flavour"),
    ("[planner.sampling]\nhorizons = [0.05]\n", "horizon"),
    ("[planner]\nweights = 'ego'\n[planner.principles]\nmaximin = -1\n", "principles.maximin"),
    ("[planner\n", "malformed TOML"),
])
def test_bad_toml(tmp_path, toml, fragment):
    f = tmp_path / "p.toml"
    f.write_text(toml)
    assert_one_line_error(cli("run", str(URBAN), "--config", str(f), "--out", str(tmp_path / "o")), fragment, 2)


def test_corrupt_predictor_weights(tmp_path):
    bad = tmp_path / "broken.pt"
    bad.write_bytes(b"this is not a torch file")
    p = cli("run", str(URBAN), "--predictor-weights", str(bad), "--out", str(tmp_path / "o"))
    assert_one_line_error(p, str(bad), 2)


@pytest.mark.sumo
def test_toml_settings_reach_the_run(tmp_path):
    f = tmp_path / "p.toml"
    f.write_text("[planner]\nomega_u = 0.25\nweights = 'standard'\nutility = 'literal'\npredictor = 'cv'\n")
    out = tmp_path / "o"
    p = cli("run", str(URBAN), "--config", str(f), "--omega-o", "2", "--end", "25", "--ego-depart", "15",
            "--out", str(out))
    assert p.returncode == 0, p.stderr
    planner = json.loads((out / "config.json").read_text())["planner"]
    assert planner["cost"]["omega_u"] == 0.25 and planner["cost"]["omega_o"] == 2.0  # CLI overrides TOML
    assert planner["cost"]["utility"] == "literal" and planner["cost"]["weights"]["bayes"] == 0.0
    steps = pd.read_parquet(out / "steps.parquet")
    assert (steps.utility_literal == 1.0).all()
    # grid keys not set keep the planner's default grid: 4 horizons x 15 x 17 + 3 brake profiles + the
    # evasive ones (horizons 1, 2, 4 s x 5 end speeds x 9 offsets)
    assert planner["sampling"]["horizons"] == [1.0, 2.0, 3.0, 4.0] and planner["sampling"]["n_offsets"] == 17
    assert planner["evasive"] is True
    assert steps.n_candidates.max() == 4 * 15 * 17 + 3 + 3 * 5 * 9


def test_settings_keep_the_planners_default_grid():
    from sumo_ethics.plan.ethical import PlannerConfig
    from sumo_ethics.settings import planner_config

    assert planner_config(None).sampling == PlannerConfig().sampling
    grid = planner_config({"sampling": {"n_offsets": 5}}).sampling
    assert grid.n_offsets == 5 and grid.horizons == PlannerConfig().sampling.horizons


def test_detector_labels_merge():
    from sumo_ethics.collision import merged_detector

    assert merged_detector("geometry", "sumo") == merged_detector("sumo", "geometry") == "both"
    assert merged_detector("sumo_unconfirmed", "sumo") == "sumo"  # confirmed by SUMO alone later
    assert merged_detector("sumo_unconfirmed", "geometry") == "both"
    assert merged_detector("both", "geometry") == "both"


def test_run_and_sweep_offer_every_predictor_the_planner_knows(tmp_path, capsys):
    """sweep --predictor offered only attention, cslstm and cv (a list older than the map models),
    so the default map_cslstm was refused there though --set predictor=map_cslstm worked."""
    from sumo_ethics.cli import cli, main
    from sumo_ethics.plan.ethical import PlannerConfig

    for command in ("run", "sweep"):
        option = next(p for p in cli.commands[command].params if p.name == "predictor")
        assert tuple(option.type.choices) == ("map_cslstm", "map", "attention", "cslstm", "cv"), command
    for kind in ("map_cslstm", "map", "attention", "cslstm", "cv"):
        PlannerConfig(predictor=kind)  # each is a predictor the planner accepts
    assert main(["sweep", str(SCENARIOS / "urban" / "urban.sumocfg"), "--predictor", "kalman", "--out", str(tmp_path / "s")]) == 2
    assert "'kalman' is not one of 'map_cslstm', 'map', 'attention', 'cslstm', 'cv'" in capsys.readouterr().err


@pytest.mark.sumo
def test_sumo_stays_silent_whatever_the_scenario_asks(tmp_path):
    """A config asking for SUMO's verbose loading log and end-of-run statistics (eclipse-sumo's and
    DLR's scenarios do) printed 20-60 lines into a --quiet run; the run's own summary is all now."""
    cfg = write_scenario(tmp_path / "s", '<vehicle id="v" type="car" route="r_main" depart="0"/>', end=8)
    cfg.write_text(cfg.read_text().replace(
        "</configuration>", '<report><verbose value="true"/><duration-log.statistics value="true"/></report>'
                            "</configuration>"))
    p = cli("run", str(cfg), "--controller", "baseline", "--quiet", "--out", str(tmp_path / "o"))
    assert p.returncode == 0, p.stderr
    for sumo_says in ("Loading net-file", "Statistics (avg", "Performance:", "Vehicles:"):
        assert sumo_says not in p.stdout + p.stderr
    assert "timeout: time limit 8 s reached" in p.stdout


def test_times_from_one_hour_on_are_printed_in_sumos_clock_form_too():
    from sumo_ethics.sumo_options import format_time, parse_time

    assert format_time(8.0) == "8 s" and format_time(3599.5) == "3599.5 s"
    assert format_time(parse_time("15:07:00", "--end")) == "54420 s (15:07:00)"  # as the user gave it
    assert format_time(parse_time("1:01:01:01", "--end")) == "90061 s (1:01:01:01)"
    assert format_time(54420.5) == "54420.5 s (15:07:00.50)"
