"""The ``sumo-ethics`` command: thin click commands over the Python API.

Every user-facing failure is printed as one line ``error: ...`` with a non-zero exit code
(2 bad input, 3 simulation failure), never a traceback.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any

import click

from sumo_ethics.cli_types import SUMO_TIME, LazyChoice
from sumo_ethics.errors import ConfigError, SumoEthicsError, Terminated
from sumo_ethics.predict import PredictorError, registry


def _console():
    from rich.console import Console

    return Console(stderr=False, highlight=False, soft_wrap=True)


class _Interrupted(Exception):
    """Ctrl-C or SIGTERM inside a command, passed through click (which would print a blank line)."""


class _Group(click.Group):
    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except KeyboardInterrupt as exc:
            raise _Interrupted(exc) from None


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="sumo-ethics")
def cli() -> None:
    """Ethical decision-making of automated vehicles in SUMO."""


@cli.command()
@click.argument("scenario", type=click.Path(path_type=Path))
@click.option("--ego", "ego_ids", multiple=True, help="Take over this vehicle of the scenario's route files when it "
              "departs (repeatable: several egos).")
@click.option("--ego-from", help="Insert our own ego on a route from this edge ...")
@click.option("--ego-to", help="... to this edge.")
@click.option("--ego-depart", type=SUMO_TIME,
              help="Departure time of the inserted ego, a simulation time in seconds or SUMO's h:m:s "
                   "(default: the scenario's begin).")
@click.option("--seed", type=int, default=42, show_default=True, help="SUMO and route seed.")
@click.option("--end", type=SUMO_TIME, help="Simulation time limit, a simulation time like SUMO's --end "
                                        "(default: the scenario's end, else its begin + 3600).")
@click.option("--step-length", type=float, help="SUMO step [s] (default: the scenario's if it sets one of at most "
                                                "0.2 s, else 0.1).")
@click.option("--sumo-arg", "sumo_arg", multiple=True, metavar="'--OPTION VALUE'",
              help="Extra SUMO options, passed through (repeatable), e.g. --sumo-arg '--time-to-teleport -1'.")
@click.option("--out", type=click.Path(path_type=Path), help="Run folder (default runs/<scenario>-seed<N>).")
@click.option("--controller", type=click.Choice(["ethical", "baseline"]), default="ethical", show_default=True,
              help="Ego controller: the ethical planner, or the naive route-following baseline.")
@click.option("--omega-u", type=float, help="Weight w_u of the utility term J_utility, from 0 to 1 (default 0.5, see "
              "docs/method.md).")
@click.option("--omega-o", type=float, help="Weight w_o of Origin's cost J_origin (default 1.0).")
@click.option("--weights", help="J_origin principle weights: ethical (default), standard, ego, bayes, maximin "
              "or responsible.")
@click.option("--selection", type=click.Choice(["cost", "validity", "validity_ttc"]),
              help="Selection rule (default cost: the ethical cost decides unavoidable harms; validity: Origin's).")
@click.option("--utility", type=click.Choice(["candidate_mean", "literal"]),
              help="Reading of J_mean in J_utility (default candidate_mean).")
@click.option("--normalise", type=click.Choice(["in_range", "at_risk"]),
              help="What Bayes, equality and responsibility divide by: every road user in range (default, Origin's) "
                   "or the road users at risk from the candidate.")
@click.option("--predictor", type=LazyChoice(registry.names),
              help="Neighbour prediction (default map: the paper's attention LSTM reading lanes and signals "
                   "too; map_cslstm: the same without the attention).")
@click.option("--predictor-weights", type=click.Path(path_type=Path),
              help="Weights file for the LSTM predictor (default: the one shipped in the package).")
@click.option("--config", "config_file", type=click.Path(path_type=Path),
              help="TOML file with a [planner] table and optionally [conflicts] and [perception] tables.")
@click.option("--continue-after-collision", is_flag=True, help="Keep running after the ego's first collision.")
@click.option("--radius", type=float, default=80.0, show_default=True, help="Sensing radius around the ego [m].")
@click.option("--overwrite", is_flag=True, help="Replace the earlier run in --out as a whole, its figures too (refused "
              "otherwise, and for a folder holding anything no run writes).")
@click.option("--record-decisions", type=click.Choice(["off", "collisions", "risky", "all"]), default="off",
              show_default=True, help="Keep what the planner weighed, for 'explain' and 'replay': every step, the "
              "steps with any risk (at most one per 0.5 s of simulated time) and the 5 s before each ego collision, only those 5 s, or nothing but the last step "
              "before each ego collision (a fleet: of each ego, in decisions/<ego>/).")
@click.option("--egos", type=int, help="Fleet: insert this many egos of ours, departing evenly over the first half of "
              "the run on routes drawn with --seed.")
@click.option("--penetration", type=float, help="Fleet: take over each eligible vehicle of the scenario (a motor road "
              "vehicle without stops) with this probability, 0..1, drawn with --seed when it departs.")
@click.option("--fleet", "fleet_shares", metavar="NAME=SHARE,...", help="Fleet: each ego's planner drawn by share, e.g. "
              "ethical=0.5,ego=0.5 (J_origin weight presets, baseline, or [planners.NAME] tables of --config); "
              "default all ethical.")
@click.option("--gui", is_flag=True, help="Watch the run in sumo-gui: the view follows the ego, with its chosen "
              "trajectory, the predictions of the road users at risk and its collisions drawn (single ego; needs a "
              "display; the same outputs as without).")
@click.option("--gui-delay", type=float, metavar="MS", help="With --gui: sumo-gui's pause between steps [ms] "
              "(default 0).")
@click.option("--threads", default="auto", show_default=True, metavar="N|auto",
              help="Threads the planner's risk kernels use (auto: the cores this process may run on); the results "
                   "are the same bytes with any number. evaluate and sweep keep one per run.")
@click.option("--quiet", is_flag=True, help="No progress display.")
def run(scenario: Path, ego_ids: tuple[str, ...], egos: int | None, penetration: float | None,
        fleet_shares: str | None, ego_from: str | None, ego_to: str | None, ego_depart: float | None,
        seed: int, end: float | None, step_length: float | None, sumo_arg: tuple[str, ...], out: Path | None,
        controller: str, omega_u: float | None, omega_o: float | None, weights: str | None, selection: str | None,
        utility: str | None, normalise: str | None, predictor: str | None, predictor_weights: Path | None, config_file: Path | None,
        continue_after_collision: bool, radius: float, overwrite: bool, record_decisions: str, gui: bool,
        gui_delay: float | None, threads: str, quiet: bool) -> None:
    """Run SCENARIO (a .sumocfg) with one vehicle taken over by the ego controller, or a fleet of them
    (--egos, --penetration, several --ego, --fleet)."""
    from dataclasses import replace

    from sumo_ethics import cores

    from sumo_ethics.config import FleetSpec, RunConfig
    from sumo_ethics.sim import scenario as scenario_files
    from sumo_ethics.sumo_options import parse_sumo_args

    if threads != "auto" and not (threads.isdigit() and int(threads) >= 1):
        raise ConfigError(f"--threads must be a whole number of at least 1 or auto, got {threads!r}")
    cores.set_threads(threads if threads == "auto" else int(threads))
    if gui_delay is not None and not gui:
        raise ConfigError("--gui-delay is sumo-gui's pause between steps: give --gui too")
    if gui_delay is not None and not gui_delay >= 0:
        raise ConfigError(f"--gui-delay must be 0 or more milliseconds, got {gui_delay:g}")
    fleet = None
    if egos is not None or penetration is not None or fleet_shares is not None or len(ego_ids) > 1:
        if ego_from is not None or ego_depart is not None:
            raise ConfigError("--ego-from/--ego-to/--ego-depart place the single inserted ego; a fleet's egos "
                              "(--egos) depart evenly over the run on routes drawn with --seed")
        if controller != "ethical":
            raise ConfigError("--controller sets the single ego's; a fleet names its planners with --fleet, "
                              "e.g. --fleet ethical=0.5,baseline=0.5")
        if gui:
            raise ConfigError("--gui shows a single ego; drop the fleet options (--egos, --penetration, "
                              "several --ego, --fleet)")
        fleet = FleetSpec(egos=egos or 0, penetration=penetration or 0.0, ids=ego_ids,
                          shares=FleetSpec.parse_shares(fleet_shares) if fleet_shares is not None
                          else FleetSpec().shares)
        ego_ids = ()
    ego_id = ego_ids[0] if ego_ids else None

    # input checks that need no simulation, before the heavy imports (numpy, libsumo, torch)
    out = out or Path("runs") / f"{scenario.stem}-seed{seed}"
    cfg = RunConfig(scenario=scenario, out=out, seed=seed, end=end, ego_id=ego_id, ego_from=ego_from, ego_to=ego_to,
                    ego_depart=ego_depart, stop_at_collision=not continue_after_collision, controller=controller,
                    sensing_radius=radius, progress=not quiet, overwrite=overwrite, step_length=step_length,
                    sumo_args=parse_sumo_args(sumo_arg), record_decisions=record_decisions,
                    fleet=fleet)
    times = scenario_files.plan(cfg.scenario, cfg.end, cfg.ego_depart, cfg.step_length, cfg.ego_id,
                                tuple(e for e in (ego_from, ego_to) if e is not None))
    # the planner plans on the run's step (a fleet's egos too: a fleet needs --controller ethical)
    on_step: dict[str, Any] = {"step": times.step_length, "step_source": times.step_source} \
        if controller == "ethical" else {}
    scenario_files.check_out(out)
    if gui and not os.environ.get("DISPLAY"):
        raise ConfigError("--gui needs a display and DISPLAY is not set; run without --gui, or under a virtual "
                          "display: xvfb-run sumo-ethics run ... --gui")
    if step_length is not None and step_length > scenario_files.MAX_TRUSTED_STEP and controller == "ethical":
        click.echo(f"note: --step-length {step_length:g} s: above {scenario_files.MAX_TRUSTED_STEP:g} s the planner's "
                   f"speed changes per step exceed its acceleration limits", err=True)

    if controller == "ethical" or fleet is not None:  # the planner's kernels compile while SUMO loads
        from sumo_ethics.plan import warmup

        warmup.start()
    from sumo_ethics import notes
    from sumo_ethics.runner import make_controller, run as run_scenario
    from sumo_ethics.settings import conflicts_config, load_run_toml, planner_config

    table, conflicts = load_run_toml(config_file) if config_file is not None else (None, conflicts_config(None))
    planner = planner_config(table, omega_u=omega_u, omega_o=omega_o, weights=weights, utility=utility,
                             normalise=normalise, predictor=predictor, predictor_weights=predictor_weights,
                             selection=selection, **on_step)
    if (scenario.parent / "hazards.json").is_file():  # a suite scenario: run does not inject hazards
        click.echo(f"note: {scenario.parent / 'hazards.json'} is not used by 'run' (no hazards, your ego); "
                   f"'sumo-ethics evaluate {scenario.parent}' runs the scenario as the suite defines it", err=True)
    cfg = replace(cfg, planner=planner, conflicts=conflicts)
    if fleet is not None:
        from sumo_ethics.runner.fleet import check_fleet_names, make_fleet_controllers, run_fleet
        from sumo_ethics.settings import named_planners

        named = named_planners(config_file) if config_file is not None else {}
        used = [n for n, _ in fleet.shares if n in named]
        spec = replace(fleet, planners=tuple(
            (n, planner_config({**(table or {}), **named[n]}, omega_u=omega_u, omega_o=omega_o, weights=weights,
                               utility=utility, normalise=normalise, predictor=predictor,
                               predictor_weights=predictor_weights, selection=selection, **on_step)) for n in used))
        cfg = replace(cfg, fleet=spec)
        check_fleet_names(spec)

        _print_fleet(_drawn(lambda: run_fleet(cfg, make_fleet_controllers(cfg)), cfg.out))
        return
    # built before SUMO starts, so a bad weights file or setting fails at once
    view = None
    if gui:
        from sumo_ethics.sim.gui import GuiOptions

        view = GuiOptions(delay_ms=gui_delay or 0.0)
    summary = _drawn(lambda: run_scenario(cfg, controller=make_controller(cfg), gui=view), cfg.out)
    d = summary.data
    con = _console()
    h = d["harm"]
    con.print(f"[bold]{d['status']}[/bold]: {d['message']}")
    if "step_length" in d:
        con.print(f"  step {d['step_length']:g} s ({d['step_length_source']})")
    con.print(f"  ego '{d['ego_id']}' on {len(d['route_edges'])} edges ({d['route_length']:.0f} m), "
              f"drove {d['distance']:.0f} m in {d['steps']} steps, wall {d['wall_time']:.1f} s")
    con.print(f"  collisions: ego {d['collisions']['ego']}, others {d['collisions']['others']}; harm total "
              f"{h['total']:.3f} = ego {h['ego']:.3f} + third party {h['third_party']:.3f} (VRU {h['vru']:.3f})")
    if d["collisions"]["ego"]:
        con.print("  fault of the ego collisions: " + ", ".join(f"{k} {v}" for k, v in d["collisions"]["fault"].items()))
    if "conflicts" in d:
        c = d["conflicts"]
        con.print(f"  conflicts: {c['total']} (TTC below threshold {c['ttc']}, PET {c['pet']}, with contact "
                  f"{c['contact']}; VRU {c['vru']}) in {summary.out / 'conflicts.parquet'}")
    if "conflicts_others" in d:
        con.print("  " + _others_line(d["conflicts_others"], summary.out))
    if d.get("decisions", {}).get("steps"):
        con.print(f"  decisions: {d['decisions']['steps']} steps kept ({d['decisions']['mode']}, "
                  f"{d['decisions']['bytes'] / 1e6:.1f} MB) in {summary.out / 'decisions'}: sumo-ethics explain / replay")
    for snap in d.get("snapshots", []):
        con.print(f"  collision snapshot: {summary.out / snap}")
    for line in notes.lines(d):  # tight bends, a lonely standstill
        con.print(f"  {line}", markup=False)
    con.print(f"  outputs in {summary.out}")


def _drawn(run_it: Any, out: Path) -> Any:
    """``run_it()`` (a run), then the collision snapshot figures drawn from its folder and listed in
    summary.json and the summary's data (:func:`sumo_ethics.analysis.explain.draw_snapshots`; the run
    itself draws none); after a run that failed too, not after Ctrl-C (``explain --snapshots`` draws them)."""
    from sumo_ethics.record.reader import collided

    def draw() -> dict[str, Any]:
        if not collided(out):
            return {}
        from sumo_ethics.analysis.explain import draw_snapshots

        return draw_snapshots(out)

    try:
        summary = run_it()
    except (KeyboardInterrupt, ConfigError):  # stopped, or bad input (nothing was run)
        raise
    except Exception:
        draw()
        raise
    summary.data.update(draw())
    return summary


def _others_line(c: dict, out: Path) -> str:
    """The run's line for the conflicts among road users other than the egos ([conflicts] everyone)."""
    g = c["by_group"]
    return (f"conflicts among the others: {c['total']} (vehicle-vehicle {g['vehicle-vehicle']}, vehicle-VRU "
            f"{g['vehicle-vru']}, VRU-VRU {g['vru-vru']}; with contact {c['contact']}) in "
            f"{out / 'conflicts_others.parquet'}")


#: the egos' outcomes in the order a fleet run's first line counts them (others follow)
EGO_OUTCOMES = ("completed", "collision", "timeout", "error")


def fleet_outcome_line(d: dict[str, Any]) -> str:
    """A fleet run's first line: how its egos ended, then how the run itself ended, e.g. ``12 egos: 0
    completed, 0 collision, 12 timeout; the run ended: time limit 30 s reached``. The run's own
    status (``completed`` when it reached its end) says nothing of the egos, so it comes last."""
    f = d["fleet"]
    by = dict(f["by_status"])
    parts = [f"{by.pop(k, 0)} {k}" for k in EGO_OUTCOMES] + [f"{v} {k}" for k, v in by.items()]
    n = f["egos"]
    who = f"{n} ego{'s' if n != 1 else ''}: " + ", ".join(parts) if n else "no ego was taken over"
    return f"{who}; the run ended: {d['message']}"


def _print_fleet(summary: Any) -> None:
    """What ``run`` prints at the end of a fleet run."""
    d = summary.data
    con = _console()
    f, h, e, c = d["fleet"], d["harm"], d["harm_everyone"], d["collisions"]
    con.print(fleet_outcome_line(d), markup=False)
    con.print("  planners: " + (", ".join(f"{k} {v}" for k, v in f["by_planner"].items()) or "none")
              + f"; drove {d['distance'] / 1e3:.2f} km, {d['steps']} steps, wall {d['wall_time']:.1f} s")
    con.print(f"  ego collisions {c['ego']} (ego-ego {c['ego_ego']}), others {c['others']}; harm booked to egos "
              f"{h['ego']:.3f}, third parties {h['third_party']:.3f} (VRU {h['vru']:.3f}); everyone's harm {e['total']:.3f}")
    if "traffic" in d:
        t = d["traffic"]
        con.print(f"  trips: {t['vehicle_trips']} vehicles ({t['vehicle_km']:.1f} km), {t['person_trips']} persons "
                  f"({t['person_km']:.1f} km) in {summary.out / 'trips.parquet'}")
    if f["teleported"]:
        con.print(f"  SUMO teleported {len(f['teleported'])} egos (handed back): {', '.join(f['teleported'][:5])}")
    if "conflicts_others" in d:
        con.print("  " + _others_line(d["conflicts_others"], summary.out))
    if d.get("decisions", {}).get("steps"):
        k = d["decisions"]
        con.print(f"  decisions: {k['steps']} steps of {k['egos']} egos kept ({k['mode']}, {k['bytes'] / 1e6:.1f} MB) in "
                  f"{summary.out / 'decisions'}: sumo-ethics explain / replay --ego ID")
    for snap in d.get("snapshots", []):
        con.print(f"  collision snapshot: {summary.out / snap}")
    con.print(f"  outputs in {summary.out}")


@cli.command()
@click.argument("run_dir", type=click.Path(path_type=Path))
@click.option("--step", type=int, help="The steps.parquet step the decision led to (also a collision's step).")
@click.option("--time", "at_time", type=float, help="The planning time [s] (the nearest recorded decision).")
@click.option("--collision", type=int, help="A collision event of collisions.parquet: its last decision before impact.")
@click.option("--conflict", type=int, help="A conflict event of conflicts.parquet: the decision nearest its worst moment.")
@click.option("--ego", "ego", metavar="ID", help="Whose decision, in a fleet run (required there): an ego's SUMO id; "
              "--collision and --conflict then need it to be a party.")
@click.option("--out", type=click.Path(path_type=Path), help="Figure path without suffix; .png and .svg are written "
              "(default RUN_DIR/explain/step_NNNNNN; a fleet ego's in RUN_DIR/explain/<ego>/).")
@click.option("--snapshots", is_flag=True, help="Draw the collision snapshots of RUN_DIR instead "
              "(RUN_DIR/snapshots/collision_<event>.png and .svg, listed in summary.json), as 'run' does when a run "
              "ends: e.g. for a run stopped by Ctrl-C, or drawn again.")
def explain(run_dir: Path, step: int | None, at_time: float | None, collision: int | None, conflict: int | None,
            ego: str | None, out: Path | None, snapshots: bool) -> None:
    """Draw one recorded planning step of RUN_DIR: the scene, predictions, candidates and the cost terms of the choice.

    Every run keeps the last decision before each ego collision (--collision K); other steps need a run made with
    --record-decisions risky, all or collisions. --time picks the nearest recorded step within 0.5 s.
    """
    from sumo_ethics.analysis.recorded import conflict_mark, decisions_of, hit_of, resolve_step
    from sumo_ethics.analysis.explain import explain as draw

    if snapshots:
        _draw_snapshots_of(run_dir, (step, at_time, collision, conflict, ego, out))
        return

    who = decisions_of(run_dir, ego)
    k = resolve_step(run_dir, step=step, time=at_time, collision=collision, conflict=conflict, ego=who)
    mark = hit_of(run_dir, collision, who) if collision is not None else conflict_mark(run_dir, conflict, who) \
        if conflict is not None else None
    res = draw(run_dir, k, out, hit=mark, ego=who)
    d = res.decision
    click.echo(f"{'' if who is None else f'ego {who!r}, '}step {d.step} (t={d.time:g} s): chose candidate {d.chosen} "
               f"of {d.n_candidates}; figure {res.paths[0]} (+ .svg)")


def _draw_snapshots_of(run_dir: Path, others: tuple[Any, ...]) -> None:
    """``explain RUN_DIR --snapshots``: the run's collision snapshot figures."""
    from sumo_ethics.analysis.explain import draw_snapshots
    from sumo_ethics.runner.loop import is_run_folder

    if any(v is not None for v in others):
        raise click.BadParameter("--snapshots draws every collision's figure: drop --step, --time, --collision, "
                                 "--conflict, --ego and --out")
    if not run_dir.is_dir() or not is_run_folder(run_dir):
        raise click.BadParameter(f"{run_dir} is not a run folder (no config.json or summary.json of a run)")
    got = draw_snapshots(run_dir)
    if "snapshot_error" in got:
        raise click.ClickException(f"the snapshots could not be drawn: {got['snapshot_error']}")
    if not got.get("snapshots"):
        click.echo(f"{run_dir}: no ego collision with a recorded decision: no snapshot to draw")
    for snap in got.get("snapshots", []):
        click.echo(f"collision snapshot: {run_dir / snap} (+ .svg)")


@cli.command()
@click.argument("scenarios", nargs=-1, type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option("--out", type=click.Path(path_type=Path), required=True,
              help="Dataset folder, new or empty; each finished run is kept in OUT/partial as it ends, and the same "
                   "command on an OUT holding only that folder resumes a stopped build.")
@click.option("--seeds", default="1-7", show_default=True,
              help="Run seeds, e.g. 1-7 or 1,4,9 (split by seed into train/validation/test: at least 3).")
@click.option("--sim-seconds", type=float, default=600.0, show_default=True, help="Simulated time per run [s].")
@click.option("--workers", type=int, default=1, show_default=True, help="Parallel SUMO processes.")
@click.option("--suite", "suite_dirs", multiple=True, type=click.Path(exists=True, file_okay=False, path_type=Path),
              help="A suite scenario folder to record with its hazards (repeat; split by scenario).")
@click.option("--samples-from", type=click.Path(exists=True, file_okay=False, path_type=Path),
              help="Derive the samples again from this dataset's recorded trajectories into --out, without "
                   "simulating (after a change of the sample layout, e.g. for datasets older than nbr_yaw).")
def dataset(scenarios: tuple[Path, ...], out: Path, seeds: str, sim_seconds: float, workers: int,
            suite_dirs: tuple[Path, ...], samples_from: Path | None) -> None:
    """Record trajectories of vehicles, cyclists and pedestrians (with their lanes and signals) from SUMO runs
    into a prediction dataset."""
    from sumo_ethics.recording.build import dataset_main
    from sumo_ethics.sweep import parse_seeds

    if samples_from is not None:
        from sumo_ethics.predict.samples import rebuild_samples

        if scenarios or suite_dirs:
            raise click.BadParameter("--samples-from takes no scenarios or --suite: it simulates nothing")
        from sumo_ethics.predict.graph_files import DATASET_GRAPHS, has_graphs

        missing = [f for f in ("trajectories.parquet", "split.json") if not (samples_from / f).is_file()]
        missing += [] if has_graphs(samples_from) else [DATASET_GRAPHS]
        if missing:
            raise click.BadParameter(f"{samples_from} has no {', '.join(missing)}: not a dataset folder")
        if out.exists() and out.resolve() == samples_from.resolve():
            raise click.BadParameter("--out must be a new folder, not the --samples-from dataset")
    from sumo_ethics.recording.runstore import PARTIAL

    # a stopped build: its kept runs and, if it was stopped while writing the dataset, some of the
    # dataset's files (split.json is written last), which the resumed build writes again
    names = {p.name for p in out.iterdir()} if out.is_dir() else set()
    resumable = samples_from is None and PARTIAL in names and names <= {
        PARTIAL, "trajectories.parquet", "lane_graphs.json.gz", "samples.npz"}
    if out.exists() and (not out.is_dir() or names) and not resumable:
        raise click.BadParameter(f"--out {out} is not an empty folder: give a new one (nothing is overwritten)")
    if samples_from is not None:
        _dataset_written(rebuild_samples(samples_from, out))
        return
    if not scenarios and not suite_dirs:
        raise click.BadParameter("give scenarios (.sumocfg), --suite folders or --samples-from")
    if scenarios and len(set(parse_seeds(seeds))) < 3:
        raise click.BadParameter(f"--seeds {seeds}: the split is by seed (train, validation, test), so it needs "
                                 "at least 3 seeds, e.g. --seeds 1-3")
    if not sim_seconds > 0:
        raise click.BadParameter(f"--sim-seconds {sim_seconds:g}: give a positive number of seconds")
    if workers < 1:
        raise click.BadParameter(f"--workers {workers}: give at least 1")
    if scenarios and sim_seconds < 10.0:
        raise click.BadParameter(f"--sim-seconds {sim_seconds:g}: a sample needs 3 s of history and 4 s ahead "
                                 "of agents already on the road, so simulate at least 10 s")
    def resuming(kept: int, planned: int) -> None:
        click.echo(f"resuming: {kept} of {planned} runs finished before and are kept in {out / PARTIAL}", err=True)

    _dataset_written(dataset_main(scenarios, out, seeds=parse_seeds(seeds), sim_seconds=sim_seconds,
                                  workers=workers, suite=suite_dirs, on_resume=resuming))


def _dataset_written(path: Path) -> None:
    """The one line ``dataset`` ends with: where, and how many samples per split."""
    import json

    n = json.loads((Path(path) / "split.json").read_text()).get("n_samples", {})
    counts = ", ".join(f"{k} {v}" for k, v in n.items())
    click.echo(f"dataset written to {path}: {sum(n.values())} samples ({counts})")


def _dataset_folder(path: Path) -> Path:
    """A folder written by ``sumo-ethics dataset`` (ConfigError otherwise)."""
    from sumo_ethics.errors import ConfigError

    missing = [f for f in ("samples.npz", "split.json") if not (path / f).is_file()]
    if missing:
        raise ConfigError(f"{path} is not a prediction dataset (no {', '.join(missing)}); "
                          "build one with 'sumo-ethics dataset'")
    return path


@cli.command()
@click.argument("dataset_dir", metavar="DATASET", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--model", type=click.Choice(["map_cslstm", "map", "attention", "cslstm"]), default="map",
              show_default=True, help="map: the paper's attention with lanes and signals (the planner's default); "
                                      "map_cslstm: the same without the attention.")
@click.option("--out", type=click.Path(path_type=Path), required=True, help="Weights file to write (.pt).")
@click.option("--max-minutes", type=float, default=14.0, show_default=True, help="CPU-time budget [min].")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--hazard-repeat", type=int, default=1, show_default=True,
              help="Use each hazard actor's training sample this many times per epoch.")
@click.option("--nbr-frame", type=click.Choice(["agent", "target"]), default=None,
              help="Neighbour encoding: once per agent in its own frame (default of map and map_cslstm) or per "
                   "target in the target's frame (default of the others, as CS-LSTM).")
@click.option("--modes", type=click.IntRange(1, 8), default=None,
              help="Gaussian trajectory modes per agent (1: a single Gaussian; default: 3 for map and "
                   "map_cslstm, 1 for the others, as shipped).")
@click.option("--decoder-size", type=click.IntRange(8, 512), default=None,
              help="Decoder LSTM states (default: 64 for map and map_cslstm, 128 for the others, as shipped).")
@click.option("--decoder-steps", type=click.Choice(["1", "2", "4", "5", "10", "20"]), default=None,
              help="Decoder LSTM steps over the 4 s horizon; each emits 20 / N output steps of 0.2 s (default: 20, "
                   "one per output step; fewer are faster at run time).")
@click.option("--cv-mode/--no-cv-mode", default=None,
              help="Make the last mode's mean the constant-velocity rollout, its weight and spread learned "
                   "(pedestrians, decoded in absolute positions, get 'stands still' there; default: off, as "
                   "shipped; the earlier default map_cslstm_v3 had it).")
@click.option("--one-mode-pedestrians/--all-modes-pedestrians", default=None,
              help="Give pedestrians the first mode only, with weight 1 (default: on for map and map_cslstm with "
                   "several modes, as shipped).")
@click.option("--stay-mode-pedestrians/--no-stay-mode-pedestrians", default=None,
              help="Give pedestrians two modes: the first and one that stays where it is (mean 0, spread "
                   "sigma_min), only the two weights learned (instead of one mode).")
@click.option("--stay-mode-cyclists/--no-stay-mode-cyclists", default=None,
              help="Give cyclists the first mode and the stay mode only (as --stay-mode-pedestrians).")
@click.option("--stay-speed", type=float, default=None,
              help="The stay mode only for road users slower than this [m/s] over the last 0.2 s; the faster "
                   "ones get the first mode alone (default: the stay mode for all of its classes).")
@click.option("--map-version", type=int, default=None,
              help="Map features a map model reads (default: the dataset's; an earlier one trains a file of "
                   "that version again, e.g. 3 for the shipped default).")
@click.option("--pedestrian-speed-scale", type=float, nargs=2, default=None, metavar="LO HI",
              help="Each time a pedestrian's sample is used, scale its history and future about its current "
                   "position by a factor drawn log-uniformly from [LO, HI]: it walks that much faster or slower "
                   "along the same path (the bundled scenarios' pedestrians walk 1.0-1.45 m/s; default: as recorded).")
@click.option("--ema", type=float, default=None, metavar="DECAY",
              help="Validate and write an exponential moving average of the weights, updated after every "
                   "optimiser step with this decay, e.g. 0.999 (default: the weights as trained, as shipped).")
@click.option("--extra-dataset", type=click.Path(path_type=Path), default=None, metavar="DIR",
              help="Also train on this dataset's training-split samples (of --extra-groups); validation stays "
                   "DATASET's (the shipped default adds the long-red runs' cyclists and pedestrians).")
@click.option("--extra-groups", default=None, metavar="GROUPS",
              help="Comma-separated classes of --extra-dataset to train on: vehicle, cyclist, pedestrian "
                   "(default: all).")
def train(dataset_dir: Path, model: str, out: Path, max_minutes: float, seed: int, hazard_repeat: int,
          nbr_frame: str | None, modes: int | None, decoder_size: int | None, decoder_steps: str | None,
          cv_mode: bool | None, one_mode_pedestrians: bool | None, stay_mode_pedestrians: bool | None,
          stay_mode_cyclists: bool | None, stay_speed: float | None, map_version: int | None,
          pedestrian_speed_scale: tuple[float, float] | None, ema: float | None, extra_dataset: Path | None,
          extra_groups: str | None) -> None:
    """Train a predictor (MSE warm-up, then Gaussian NLL, early stopping on validation; with several modes the
    warm-up is winner-takes-all and the NLL that of the mixture)."""
    from sumo_ethics.predict import train_main
    from sumo_ethics.predict.features import GROUP_CYCLIST, GROUP_NAMES, GROUP_PEDESTRIAN
    from sumo_ethics.predict.models import default_modes

    if not max_minutes > 0:
        raise click.BadParameter("--max-minutes must be positive")
    if hazard_repeat < 1:
        raise click.BadParameter("--hazard-repeat must be at least 1")
    if (cv_mode or one_mode_pedestrians or stay_mode_pedestrians or stay_mode_cyclists) and (modes or default_modes(model)) < 2:
        raise click.BadParameter(f"--cv-mode, --one-mode-pedestrians and --stay-mode-* need --modes 2 or "
                                 f"more ({model} has {default_modes(model)} mode(s) unless --modes says otherwise)")
    if one_mode_pedestrians and stay_mode_pedestrians:
        raise click.BadParameter("--one-mode-pedestrians and --stay-mode-pedestrians exclude each other")
    single = None if one_mode_pedestrians is None else ((GROUP_PEDESTRIAN,) if one_mode_pedestrians else ())
    if stay_speed is not None and not (stay_mode_pedestrians or stay_mode_cyclists):
        raise click.BadParameter("--stay-speed needs --stay-mode-pedestrians or --stay-mode-cyclists")
    if stay_speed is not None and not stay_speed > 0:
        raise click.BadParameter("--stay-speed must be positive")
    if pedestrian_speed_scale is not None and not 0 < pedestrian_speed_scale[0] <= pedestrian_speed_scale[1]:
        raise click.BadParameter("--pedestrian-speed-scale needs 0 < LO <= HI")
    if ema is not None and not 0.0 < ema < 1.0:
        raise click.BadParameter("--ema needs a decay between 0 and 1, e.g. 0.999")
    groups = None
    if extra_groups is not None:
        if extra_dataset is None:
            raise click.BadParameter("--extra-groups needs --extra-dataset")
        names = [g.strip() for g in extra_groups.split(",") if g.strip()]
        unknown = [g for g in names if g not in GROUP_NAMES]
        if unknown or not names:
            raise click.BadParameter(f"--extra-groups {extra_groups!r}: give classes out of {', '.join(GROUP_NAMES)}")
        groups = tuple(sorted({GROUP_NAMES.index(g) for g in names}))
    stay = None
    if stay_mode_pedestrians is not None or stay_mode_cyclists is not None:
        stay = (GROUP_CYCLIST,) * bool(stay_mode_cyclists) + (GROUP_PEDESTRIAN,) * bool(stay_mode_pedestrians)
    result = train_main(_dataset_folder(dataset_dir), model, out, max_minutes=max_minutes, seed=seed,
                        hazard_repeat=hazard_repeat, nbr_frame=nbr_frame, modes=modes, dec=decoder_size,
                        dec_steps=None if decoder_steps is None else int(decoder_steps),
                        cv_mode=cv_mode, single_mode_groups=single, stay_mode_groups=stay, stay_speed=stay_speed,
                        map_version=map_version, ped_speed_scale=pedestrian_speed_scale, ema=ema,
                        extra_dataset=None if extra_dataset is None else _dataset_folder(extra_dataset),
                        extra_groups=groups)
    click.echo(f"weights written to {out}: {result['kind']}, best epoch {result['best_epoch']} "
               f"(validation NLL {result['best_val_nll']:.3f}), stopped by {result['stopped']} after "
               f"{result['cpu_minutes']:.1f} CPU-minutes; the training log is {Path(out).with_suffix('.json')}")


@cli.command("evaluate-predictor")
@click.argument("dataset_dir", metavar="DATASET", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--out", type=click.Path(path_type=Path), default=Path("prediction_eval"), show_default=True)
@click.option("--model", "models", multiple=True, metavar="NAME=FILE",
              help="A weights file to evaluate under NAME (repeat; default: the shipped map, map_cslstm, "
                   "attention and cslstm; constant velocity is always evaluated).")
@click.option("--split", type=click.Choice(["test", "val", "train", "all"]), default="test", show_default=True,
              help="Samples evaluated: a split of the seeds/scenarios, or all (a dataset never trained on).")
@click.option("--calibrated", is_flag=True,
              help="Also a row NAME_calibrated for every model with a covariance calibration beside its weights "
                   "(<stem>.calibration.json): the same means, calibrated spreads.")
def evaluate_predictor(dataset_dir: Path, out: Path, models: tuple[str, ...], split: str, calibrated: bool) -> None:
    """RMSE at 1-4 s, ADE, FDE, NLL and 1-/2-sigma calibration of constant velocity and the learned models,
    per agent class and per manoeuvre."""
    from sumo_ethics.predict import evaluate_main

    weights: dict[str, Path | str] = {}
    for text in models:
        name, sep, path = text.partition("=")
        if not sep or not name or not path:
            raise click.BadParameter(f"--model expects NAME=FILE, got {text!r}")
        weights[name] = Path(path)
    table = evaluate_main(_dataset_folder(dataset_dir), out, weights=weights or None, split=split,
                          calibrated=calibrated)
    click.echo(table.to_string(index=False))
    extra = " (and prediction_eval_by_scenario.csv and .md)" if (Path(out) / "prediction_eval_by_scenario.csv").is_file() \
        and split == "all" else ""
    click.echo(f"written to {out}/prediction_eval.csv and .md{extra}")


@cli.command()
@click.argument("run_dir", type=click.Path(path_type=Path))
@click.option("--out", type=click.Path(path_type=Path), required=True,
              help="Animation to write: .mp4 (needs ffmpeg; a .gif of the same name without it) or .gif.")
@click.option("--every", type=int, default=1, show_default=True,
              help="Draw every N-th recorded step (and always the step of each ego collision).")
@click.option("--fps", type=float,
              help="Frames per second, at most 50 (default: real time, capped at 10 for a GIF and 30 for an MP4).")
@click.option("--ego", "ego", metavar="ID", help="Whose decisions, in a fleet run (required there): an ego's SUMO id.")
@click.option("--quiet", is_flag=True, help="No progress display.")
def replay(run_dir: Path, out: Path, every: int, fps: float | None, ego: str | None, quiet: bool) -> None:
    """Animate RUN_DIR's recorded decisions: an ego-centred view per planning step with the road users,
    their predictions, the candidates and the chosen trajectory.

    The run must have been made with --record-decisions (all for every step).
    """
    from sumo_ethics.analysis.replay import check_out, replay as animate

    check_out(out)
    res = animate(run_dir, out, every=every, fps=fps, progress=not quiet, ego=ego)
    for note in res.notes:
        click.echo(f"note: {note}", err=True)
    size = res.path.stat().st_size
    shown = f"{size / 1e6:.1f} MB" if size >= 1e5 else f"{size / 1e3:.0f} kB"
    click.echo(f"wrote {res.path}: {res.playback}, {shown}")


@cli.command("import-commonroad")
@click.argument("scenario", type=click.Path(path_type=Path))
@click.option("--out", type=click.Path(path_type=Path),
              help="Scenario folder to write, new or empty (default commonroad/<name>-<mode>).")
@click.option("--mode", type=click.Choice(["replay", "reactive"]), default="replay", show_default=True,
              help="replay: every recorded road user follows its recorded states exactly; reactive: they start "
                   "as recorded and SUMO drives them along their recorded route (those it cannot, e.g. parked "
                   "cars, are replayed).")
@click.option("--completion", type=click.Choice(["commonroad", "origin"]), default="commonroad", show_default=True,
              help="commonroad: completed in the goal region within its time window, the run ends at the window's "
                   "last step; origin: as the paper's evaluation counted it, arriving after the window completes too "
                   "(late), the run lasts twice the goal's last time step (default folder <name>-<mode>-late).")
def import_commonroad_cmd(scenario: Path, out: Path | None, mode: str, completion: str) -> None:
    """Import a CommonRoad scenario (.xml or .xml.gz) into a SUMO scenario folder for run, sweep and evaluate.

    Needs the optional packages: pip install 'sumo-ethics[commonroad]'.
    """
    from sumo_ethics.commonroad.importer import import_commonroad

    res = import_commonroad(scenario, out, mode, completion)
    click.echo(f"imported {scenario.name} ({mode}) in {res.seconds:.1f} s: {res.n_obstacles} road users "
               f"({res.n_replayed} replayed, {res.n_reactive} driven by SUMO)"
               + (f", {len(res.skipped)} not imported" if res.skipped else ""))
    click.echo(f"run it: sumo-ethics run {res.sumocfg}")


from sumo_ethics.cli_sweep import analyze, sweep  # noqa: E402

cli.add_command(sweep)
cli.add_command(analyze)

from sumo_ethics.cli_suite import evaluate_cmd, suite  # noqa: E402

cli.add_command(suite)
cli.add_command(evaluate_cmd)


def main(argv: list[str] | None = None) -> int:
    """Entry point: runs the CLI and turns every expected failure into one line."""
    try:
        cli.main(args=argv, prog_name="sumo-ethics", standalone_mode=False)
    except click.exceptions.Exit as exc:
        return exc.exit_code
    except _Interrupted as exc:
        notes = "; ".join(getattr(exc.args[0], "__notes__", ()))  # e.g. what train kept
        if isinstance(exc.args[0], Terminated):
            click.echo(f"error: terminated (SIGTERM); {notes or 'the outputs written so far are kept'}", err=True)
            return 143
        click.echo("error: interrupted" + (f"; {notes}" if notes else ""), err=True)
        return 130
    except click.exceptions.Abort:
        click.echo("error: aborted", err=True)
        return 130
    except click.ClickException as exc:
        click.echo(f"error: {exc.format_message()}", err=True)
        return exc.exit_code
    except SumoEthicsError as exc:
        click.echo(f"error: {exc}", err=True)
        return exc.exit_code
    except PredictorError as exc:
        click.echo(f"error: {exc}", err=True)
        return 2
    except OSError as exc:  # a full disk, a file size limit, a folder that vanished
        where = f" ({exc.filename})" if getattr(exc, "filename", None) else ""
        click.echo(f"error: cannot write or read a file{where}: {exc.strerror or exc}", err=True)
        return 1
    except Terminated:
        click.echo("error: terminated (SIGTERM); the outputs written so far are kept", err=True)
        return 143
    except KeyboardInterrupt:
        click.echo("error: interrupted", err=True)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
