"""``sumo-ethics sweep`` and ``sumo-ethics analyze``: thin click commands over sweep.py / analysis.

Registered on the main group in cli.py::

    from sumo_ethics.cli_sweep import analyze, sweep
    cli.add_command(sweep)
    cli.add_command(analyze)
"""

from __future__ import annotations

import os
from pathlib import Path

import click

from sumo_ethics.cli_types import SUMO_TIME, LazyChoice
from sumo_ethics.predict import registry
from sumo_ethics.settings import SET_PLANNER_KEYS


@click.command()
@click.argument("scenario_or_suite", type=click.Path(path_type=Path))
@click.option("--omega-u", "omega_u", default="0.5", show_default=True,
              help="Utility weights w_u, each from 0 to 1: start:stop:step (stop included when on the grid), a,b,c or one "
                   "value.")
@click.option("--seeds", default="0", show_default=True, help="Seeds: 0-9 (inclusive), 0,3,5 or mixed 0-3,8.")
@click.option("--set", "sets", multiple=True, metavar="KEY=V1,V2",
              help=f"Sweep one more key over values (repeatable): planner keys ({', '.join(SET_PLANNER_KEYS)}, "
                   "sampling.*, probability.*, principles.*, perception.*) or run keys (end, ego_depart, penetration, "
                   "fleet, controller, radius, stop_at_collision, ...).")
@click.option("--out", type=click.Path(path_type=Path), required=True, help="Sweep folder (resumed if it exists).")
@click.option("--workers", type=int, default=None, help="Local processes (default: the number of CPUs).")
@click.option("--scheduler", metavar="tcp://HOST:PORT", help="Run on an existing Dask distributed cluster.")
@click.option("--end", type=SUMO_TIME, help="Simulation time limit of every run, a simulation time in seconds or h:m:s.")
@click.option("--ego-depart", type=SUMO_TIME, help="Departure time of the inserted ego in seconds or h:m:s "
                                                   "(default: the scenario's begin).")
@click.option("--step-length", type=float, help="SUMO step [s] (default: the scenario's if at most 0.2 s, else 0.1).")
@click.option("--ego-from", help="Route of the inserted ego: from this edge ...")
@click.option("--ego-to", help="... to this edge.")
@click.option("--controller", type=click.Choice(["ethical", "baseline"]), help="Ego controller (default ethical).")
@click.option("--predictor", type=LazyChoice(registry.names),
              help="Neighbour prediction (default map, as for run).")
@click.option("--radius", type=float, help="Sensing radius around the ego [m].")
@click.option("--continue-after-collision", is_flag=True, help="Keep running after the ego's first collision.")
@click.option("--config", "config_file", type=click.Path(path_type=Path), help="TOML file with a [planner] table.")
@click.option("--record-decisions", type=click.Choice(["off", "collisions", "risky", "all"]),
              help="Decisions each run keeps for 'explain'/'replay' (default risky: the steps whose choice carries "
                   "risk and the 5 s before every ego collision; a fleet run's default off: each ego's step "
                   "before its collisions).")
@click.option("--quiet", is_flag=True, help="No progress bar.")
def sweep(scenario_or_suite: Path, omega_u: str, seeds: str, sets: tuple[str, ...], out: Path, workers: int | None,
          scheduler: str | None, end: float | None, ego_depart: float | None, step_length: float | None,
          ego_from: str | None,
          ego_to: str | None, controller: str | None, predictor: str | None, radius: float | None,
          continue_after_collision: bool, config_file: Path | None, record_decisions: str | None,
          quiet: bool) -> None:
    """Run the grid SCENARIO(S) x omega_u x seeds x --set values, one SUMO process per run.

    SCENARIO_OR_SUITE is a .sumocfg or a folder searched for *.sumocfg. Running the same
    command again resumes: finished runs are kept, the others run.
    """
    from rich.console import Console

    from sumo_ethics.errors import ConfigError
    from sumo_ethics.settings import load_toml
    from sumo_ethics.sweep import make_sweep, run_sweep

    if workers is not None and workers < 1:
        raise ConfigError(f"--workers must be at least 1, got {workers}")
    if workers is not None and scheduler:
        raise ConfigError("--workers and --scheduler exclude each other")
    options = {"end": end, "ego_depart": ego_depart, "step_length": step_length, "ego_from": ego_from, "ego_to": ego_to,
               "controller": controller, "predictor": predictor, "radius": radius,
               "stop_at_collision": False if continue_after_collision else None,
               "record_decisions": None if record_decisions == "risky" else record_decisions}
    planner = load_toml(config_file) if config_file is not None else None
    from sumo_ethics.plan import warmup

    warmup.start()  # the planner's kernels compiled once, while the grid is checked
    sw = make_sweep(scenario_or_suite, omega_u, seeds, sets, options=options, planner=planner)
    warmup.wait()
    res = run_sweep(sw, out, workers=workers or os.cpu_count() or 1, scheduler=scheduler, progress=not quiet)
    con = Console(highlight=False, soft_wrap=True)
    con.print(f"[bold]sweep[/bold] {res.total} runs: {res.done} finished ({res.skipped} from before, "
              f"{res.errors} ended with a SUMO/run error), {res.failed} failed; {res.wall:.1f} s")
    con.print(f"  manifest {out / 'manifest.json'}, dataset {out / 'dataset'}")
    if res.failed:
        from sumo_ethics.errors import SumoEthicsError

        first = res.failures[0] if res.failures else ""
        raise SumoEthicsError(f"{res.failed} run(s) failed ({first}); they are listed in manifest.json and run "
                              "again when the same command is started again")


@click.command()
@click.argument("sweep_dir", type=click.Path(path_type=Path))
@click.option("--by", default="omega_u", show_default=True,
              help="Comma-separated grouping columns: sweep parameters (scenario, omega_u, seed, --set keys) "
                   "or run columns such as controller.")
@click.option("--out", "report_dir", type=click.Path(path_type=Path),
              help="Report folder (default SWEEP_DIR/report).")
@click.option("--n-boot", type=int, default=2000, show_default=True, help="Bootstrap resamples for the 95% CI.")
@click.option("--seed", type=int, default=0, show_default=True, help="Bootstrap seed.")
def analyze(sweep_dir: Path, by: str, report_dir: Path | None, n_boot: int, seed: int) -> None:
    """Tables (CSV, Markdown), plots (PNG, SVG) and report.md of the sweep in SWEEP_DIR."""
    from rich.console import Console

    from sumo_ethics.analysis.report import make_report

    from sumo_ethics.analysis.stats import MAX_BOOT
    from sumo_ethics.errors import ConfigError

    if not 1 <= n_boot <= MAX_BOOT:
        raise ConfigError(f"--n-boot must be between 1 and {MAX_BOOT}, got {n_boot}")
    con = Console(highlight=False, soft_wrap=True)
    if not (sweep_dir / "manifest.json").exists() and (sweep_dir / "config.json").exists():
        _print_run(sweep_dir, con)  # a single run folder, finished or killed
        return
    groups = [b.strip() for b in by.split(",") if b.strip()]
    rep = make_report(sweep_dir, groups, report_dir, n_boot=n_boot, seed=seed)
    con.print(f"[bold]report[/bold] {rep.report}: {len(rep.tables)} tables, {len(rep.figures)} figures")
    if rep.unfinished:
        con.print(f"  {rep.unfinished} runs have not finished (not run yet, failed or killed) and are not in the "
                  "report; start the same sweep again to finish them")


def _print_run(folder: Path, con) -> None:
    """``analyze RUN_FOLDER``: what the run wrote, marked incomplete when it was killed."""
    from sumo_ethics.analysis import load_run

    res = load_run(folder)
    r = res.runs.iloc[0]
    con.print(f"[bold]run[/bold] {folder}: {r.status}{' (killed before it finished)' if r.incomplete else ''}: "
              f"{r.message}")
    con.print(f"  {len(res.steps)} steps recorded, {len(res.collisions)} collisions; harm total {r.harm_total:.3f} = "
              f"ego {r.harm_ego:.3f} + third party {r.harm_third_party:.3f} (VRU {r.harm_vru:.3f})")
