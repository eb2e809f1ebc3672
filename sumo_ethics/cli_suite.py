"""``sumo-ethics suite generate`` and ``sumo-ethics evaluate`` (registered by cli.py).

Errors are SumoEthicsError (ConfigError: exit 2), printed as one line by ``cli.main``.
"""

from __future__ import annotations

from pathlib import Path

import click


@click.group("suite")
def suite() -> None:
    """Scenario suites with injected hazards."""


@suite.command("generate")
@click.option("--count", type=int, default=200, show_default=True, help="Number of scenarios.")
@click.option("--seed", type=int, default=2024, show_default=True, help="Suite seed (same seed, same files).")
@click.option("--out", type=click.Path(path_type=Path), required=True,
              help="Suite folder: new or empty (an existing suite is never overwritten).")
@click.option("--family", type=click.Choice(["hazard", "dilemma"]), default="hazard", show_default=True,
              help="hazard: one hazard on one of six road types; dilemma: unavoidable harm with a choice "
                   "of victims (checked by construction).")
def generate_cmd(count: int, seed: int, out: Path, family: str) -> None:
    """Generate COUNT scenarios reproducibly from SEED into OUT."""
    from collections import Counter

    from sumo_ethics.errors import ConfigError

    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ConfigError(f"--out {out} is not an empty folder; choose a new one (an existing suite is never "
                          f"overwritten: old and new scenarios would mix)")

    from sumo_ethics.suite.generate import generate

    specs = generate(count, seed, out, family)
    nets = Counter(s.network for s in specs)
    kinds = Counter(k for s in specs for k in s.hazard_types)
    click.echo(f"{len(specs)} scenarios in {out}")
    click.echo("  networks: " + ", ".join(f"{k} {v}" for k, v in sorted(nets.items())))
    click.echo("  hazards:  " + ", ".join(f"{k} {v}" for k, v in sorted(kinds.items())))


@click.command("evaluate")
@click.argument("suite_dir", metavar="SUITE", type=click.Path(path_type=Path))
@click.option("--planner", "planners", multiple=True, default=("origin", "paper"), show_default=True,
              help="origin | paper | ours (= default: what run and sweep use) | baseline | NAME=key=value;key=value (planner options over "
                   "paper's settings, e.g. fast=predictor=cv;omega_u=0.3, or over ours' or origin's with base=: "
                   "mm=base=ours;weights=maximin). Repeat for several.")
@click.option("--workers", type=int, default=2, show_default=True, help="Parallel processes (one run each).")
@click.option("--out", type=click.Path(path_type=Path), default=Path("runs/evaluate"), show_default=True,
              help="Output folder: table1.csv, table1.md, paired.csv, results.csv, runs/.")
@click.option("--limit", type=int, help="Only the first N scenarios (1 or more).")
@click.option("--reference", help="Planner the others are compared with (default origin, else the first).")
@click.option("--resume", is_flag=True, help="Keep finished runs found in OUT/runs, run only the rest.")
@click.option("--record-decisions", type=click.Choice(["off", "collisions", "risky", "all"]), default="risky",
              show_default=True, help="Decisions each run keeps for 'explain'/'replay' (risky: the steps whose choice "
                                      "carries risk, at most one per 0.5 s, and the 5 s before every ego collision).")
@click.option("--mode", type=click.Choice(["replay", "reactive"]), default="replay", show_default=True,
              help="For a folder of CommonRoad files: how the recorded road users are driven (see import-commonroad).")
@click.option("--completion", type=click.Choice(["commonroad", "origin"]), default="commonroad", show_default=True,
              help="For a folder of CommonRoad files: commonroad = the goal region within its time window (the run "
                   "ends at the window's last step); origin = as the paper's evaluation counted it: arriving after "
                   "the window completes too (late), runs last twice the goal's last time step.")
@click.option("--quiet", is_flag=True, help="No per-run progress lines.")
def evaluate_cmd(suite_dir: Path, planners: tuple[str, ...], workers: int, out: Path, limit: int | None,
                 reference: str | None, resume: bool, record_decisions: str, mode: str, completion: str,
                 quiet: bool) -> None:
    """Run every scenario of SUITE with each planner and write the paper's Table 1.

    SUITE is a generated suite, or a folder of CommonRoad files (.xml, .xml.gz; imported on the fly into
    OUT/imported in --mode, each failed import listed with its cause in OUT/imports.csv while the rest
    go on) or of folders written by import-commonroad.
    """
    from sumo_ethics.plan import warmup
    from sumo_ethics.suite.evaluate import evaluate

    warmup.start()  # the planner's kernels compiled once, before the run processes load them
    warmup.wait()

    def progress(n: int, total: int, row: dict) -> None:
        if not quiet:
            click.echo(f"[{n}/{total}] {row['scenario']} {row['planner']}: {row.get('status')} "
                       f"({row.get('wall_s', 0):.1f} s)")

    def imported(line: str) -> None:
        if not quiet or line.startswith("import failed"):
            click.echo(line, err=line.startswith("import failed"))

    csv, md = evaluate(suite_dir, list(planners), out, workers=workers, limit=limit, reference=reference,
                       progress=progress, resume=resume, record_decisions=record_decisions, mode=mode,
                       on_import=imported, completion=completion)
    click.echo(md.read_text())
    click.echo(f"tables: {csv}, {md}" + (f"; imports: {md.parent / 'imports.csv'}"
                                         if (md.parent / "imports.csv").is_file() else ""))
    if (md.parent / "risk.md").is_file():
        click.echo(f"ex-ante risk: {md.parent / 'risk.md'}, {md.parent / 'risk_paired.csv'}, "
                   f"{md.parent / 'figures' / 'exante_risk.png'}")


evaluate = evaluate_cmd
