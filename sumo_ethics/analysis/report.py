"""``sumo-ethics analyze``: tables (CSV + Markdown), figures (PNG + SVG) and a Markdown report."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

from sumo_ethics.analysis import load
from sumo_ethics.analysis.stats import (CONFLICT_CLASSES, TRAFFIC_HARM, TRAFFIC_LOSS, check_groups, collision_table,
                                        conflict_table, status_table, summary_table, to_markdown, traffic_table)


@dataclass
class Report:
    folder: Path
    report: Path
    tables: dict[str, Path] = field(default_factory=dict)
    figures: dict[str, list[Path]] = field(default_factory=dict)
    unfinished: int = 0  # runs of the sweep not finished (pending, failed, or killed with the sweep)


def shown_path(path: str, cwd: Path | None = None) -> str:
    """A path as a command line to copy shows it: ``$SUMO_HOME/...`` below SUMO's own folder,
    relative to ``cwd`` (default: the current folder) below it, else as it is."""
    p = Path(path)
    if p.is_absolute():
        try:
            import sumo

            return "$SUMO_HOME/" + p.relative_to(Path(sumo.SUMO_HOME).resolve()).as_posix()
        except (ImportError, ValueError):
            pass
        try:
            return p.relative_to((cwd or Path.cwd()).resolve()).as_posix()
        except ValueError:
            pass
    return str(path)


def command_line(definition: dict[str, Any], out: str = "OUT", execution: dict[str, Any] | None = None,
                 cwd: Path | None = None) -> str:
    """A ``sumo-ethics sweep`` command that reproduces ``definition`` (the report's first line;
    the sweep definition is :mod:`sumo_ethics.sweep.grid`'s), run as ``execution`` says
    (``workers`` or ``scheduler``, manifest.json's), the paths relative to ``cwd`` (:func:`shown_path`)."""
    flags = {"end": "--end", "ego_depart": "--ego-depart", "ego_from": "--ego-from", "ego_to": "--ego-to",
             "controller": "--controller", "predictor": "--predictor", "radius": "--radius",
             "step_length": "--step-length"}
    scen = definition["scenarios"]
    parts = ["sumo-ethics sweep", shown_path(scen[0] if len(scen) == 1 else os.path.commonpath(scen), cwd),
             "--omega-u", ",".join(f"{v:g}" for v in definition["omega_u"]),
             "--seeds", ",".join(map(str, definition["seeds"]))]

    def value(x: Any) -> str:  # as typed: 0.5, true (not Python's True)
        return f"{x:g}" if isinstance(x, float) else str(x).lower() if isinstance(x, bool) else str(x)

    for k, v in definition["set"].items():
        parts += ["--set", f"{k}=" + ",".join(value(x) for x in v)]
    for k, v in definition["options"].items():
        if k == "stop_at_collision":
            parts += ["--continue-after-collision"] if v is False else []
        elif k in flags:
            parts += [flags[k], value(v)]
    if definition.get("planner"):
        parts += ["--config", "PLANNER.toml"]
    execution = execution or {}
    if execution.get("scheduler"):
        parts += ["--scheduler", str(execution["scheduler"])]
    elif execution.get("workers"):
        parts += ["--workers", str(execution["workers"])]
    return " ".join(parts + ["--out", shown_path(out, cwd)])


def make_report(sweep_dir: Path | str, by: Sequence[str] = ("omega_u",), out: Path | None = None,
                n_boot: int = 2000, seed: int = 0) -> Report:
    """Write ``out`` (default ``sweep_dir/report``): summary/status/collision tables, plots, report.md."""
    from sumo_ethics.analysis import plots
    from sumo_ethics.errors import ConfigError

    sweep_dir = Path(sweep_dir)
    res = load(sweep_dir, steps=False)
    if res.runs.empty:
        raise ConfigError(f"{sweep_dir} holds no finished runs yet")
    by = check_groups(res.runs, list(by) or ["omega_u"])
    folder = Path(out) if out is not None else sweep_dir / "report"
    if folder.exists() and not folder.is_dir():
        raise ConfigError(f"--out {folder} exists and is not a folder")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"cannot write to --out {folder}: {exc.strerror or exc}") from None
    rep = Report(folder=folder, report=folder / "report.md")

    tables = {"summary": summary_table(res.runs, by, n_boot=n_boot, seed=seed),
              "status": status_table(res.runs, by),
              "collisions_by_class": collision_table(res.collisions)}
    conflicts = conflict_table(res.runs, by, n_boot=n_boot, seed=seed)
    if len(conflicts):
        tables["conflicts"] = conflicts
    traffic = traffic_table(res.runs, by, n_boot=n_boot, seed=seed)
    if len(traffic):
        tables["traffic"] = traffic
    for name, df in tables.items():
        df.to_csv(folder / f"{name}.csv", index=False)
        (folder / f"{name}.md").write_text(to_markdown(df))
        rep.tables[name] = folder / f"{name}.csv"

    figs = folder / "figures"
    rep.figures["harm"] = plots.harm_vs_parameter(tables["summary"], by, figs)
    rep.figures["completion"] = plots.completion_vs_parameter(tables["summary"], by, figs)
    rep.figures["harm_per_collision"] = plots.harm_per_collision(res.collisions, figs)
    rep.figures["tradeoff"] = plots.tradeoff(res.runs, figs, by)
    if "traffic" in tables:
        rep.figures["traffic"] = plots.traffic_vs_parameter(tables["traffic"], by, figs)
    has_risk = "risk_total_mean" in res.runs and res.runs["risk_total_mean"].notna().any()
    if has_risk:
        from sumo_ethics.analysis.exante import risk_boxplot, risk_table

        tables["exante_risk"] = risk_table(res.runs, by, n_boot=n_boot, seed=seed)
        tables["exante_risk"].to_csv(folder / "exante_risk.csv", index=False)
        (folder / "exante_risk.md").write_text(to_markdown(tables["exante_risk"]))
        rep.tables["exante_risk"] = folder / "exante_risk.csv"
        rep.figures["exante_risk"] = risk_boxplot(res.runs, by[0], figs)

    manifest = json.loads((sweep_dir / "manifest.json").read_text())
    rep.unfinished = len(manifest["runs"]) - len(res.runs)
    d = manifest["definition"]
    compact = tables["summary"][[*by, "n_runs", "completion_rate", "collision_rate", "harm_ego_mean",
                                 "harm_third_party_mean", "harm_vru_mean", "harm_total_mean",
                                 "harm_total_ci_lo", "harm_total_ci_hi"]]
    lines = [
        f"# Sweep report: {sweep_dir.name}",
        "",
        "```sh",
        command_line(d, str(sweep_dir), manifest.get("execution")),
        f"sumo-ethics analyze {shown_path(str(sweep_dir))} --by {','.join(by)}",
        "```",
        "",
        f"- scenarios: {', '.join(Path(s).name for s in d['scenarios'])}",
        f"- w_u: {', '.join(f'{v:g}' for v in d['omega_u'])}; seeds: {', '.join(map(str, d['seeds']))}",
        f"- swept with --set: {json.dumps(d['set']) if d['set'] else 'nothing'}; options: {json.dumps(d['options'])}",
        f"- runs: {len(res.runs)} finished of {len(manifest['runs'])} "
        f"({', '.join(f'{k} {v}' for k, v in sorted(res.runs['status'].value_counts().items()))})",
        *([f"- **incomplete sweep**: {len(manifest['runs']) - len(res.runs)} runs have not finished (not run yet, "
           "failed, or killed with the sweep) and are not in these tables; start the same sweep again to finish them"]
          if len(manifest["runs"]) > len(res.runs) else []),
        f"- grouped by: {', '.join(by)}; 95% CIs: percentile bootstrap over runs ({n_boot} resamples, seed {seed})",
        "",
        "Harm is P(MAIS 3+) of the harm model, summed per run over the ego's collisions and",
        "booked per class: ego, third party (every other party, VRU included) and VRU (pedestrians,",
        "cyclists, motorcyclists).",
        "",
        "## Summary",
        "",
        to_markdown(compact),
        "Full table with sums and every CI: [summary.csv](summary.csv) ([md](summary.md)).",
        "",
        "## Run outcomes",
        "",
        to_markdown(tables["status"]),
        "## Ego collisions by class of the other party",
        "",
        "`n_collisions`: the ego collisions booked (confirmed by the boxes' geometry, by SUMO, or both), with "
        "their mean delta-v and harm per class; `n_unconfirmed`: SUMO's collision reports whose boxes do not "
        "overlap at the recorded poses, listed in `collisions.parquet` (`detector` = `sumo_unconfirmed`) "
        "and booked as no harm (docs/outputs.md).",
        "",
        to_markdown(tables["collisions_by_class"]) if len(tables["collisions_by_class"]) else "No ego collisions.\n",
    ]
    if "conflicts" in tables:
        c = tables["conflicts"]
        cols = [*by, "n_runs", "ego_km", "ego_hours"] + [f"{n}_{u}" for n, _ in CONFLICT_CLASSES
                                                        for u in ("per_100km", "per_hour")]
        lines += ["## Conflicts (near misses) per class", "",
                  "Conflicts of the ego with another road user (TTC below its threshold or PET below its; "
                  "`conflicts.parquet`, docs/conflicts.md) per 100 ego-km and per ego-hour: each group's sum of "
                  "conflicts over its sum of distance / driving time; 95 % bootstrap CIs over runs in "
                  "[conflicts.csv](conflicts.csv).", "", to_markdown(c[cols])]
    if "traffic" in tables:
        t = tables["traffic"]
        others = [f"conflicts_{n}_per_100vkm" for n in ("others", "others_vru", "everyone")]
        others = others if t[others[0]].notna().any() else []
        cols = [*by, "n_runs", "egos", "vehicle_km", *(f"harm_{n}_per_Mvkm" for n, _ in TRAFFIC_HARM),
                "conflicts_per_100km", *others, *(f"time_loss_{n}" for n, _ in TRAFFIC_LOSS)]
        lines += ["## Traffic (fleet runs)", "",
                  "Everyone's harm by party (egos, other vehicles, VRUs: every confirmed collision of the run, the "
                  "egos' and SUMO's own) per 10^6 vehicle-km of all trips; the egos' conflicts per 100 ego-km; "
                  + ("the conflicts among road users that are not egos (`conflicts_others.parquet`), all of them and "
                     "those with a VRU, and every conflict of the run (the egos' and the others'), per 100 vehicle-km "
                     "of all trips; " if others else "")
                  + "mean time loss per trip [s] by party, from SUMO's tripinfo (`trips.parquet`). 95 % bootstrap CIs "
                  "over runs in [traffic.csv](traffic.csv).", "", to_markdown(t[cols])]
    if has_risk:
        lines += ["## Ex-ante risk per class", "",
                  "Per run, the mean over planning steps of the risk (P x harm) the chosen trajectory puts on",
                  "each class (summed over its parties); mean over runs [95 % bootstrap CI], median, and the",
                  "median per-run peak risk of a single party.", "",
                  to_markdown(tables["exante_risk"])]
    lines += snapshot_links(sweep_dir, folder, res.collisions)
    lines += ["## Figures", ""]
    captions = {"harm": "Harm per class vs the swept parameter (mean over runs, 95% CI band)",
                "completion": "Completion and ego-collision rate",
                "harm_per_collision": "Harm per ego collision by class",
                "tradeoff": "Ego vs third-party harm per run",
                "exante_risk": "Ex-ante risk of the chosen trajectory per class (per-run mean)",
                "traffic": "Traffic outcomes of the fleet runs: harm, conflicts and time loss by party"}
    for key, paths in rep.figures.items():
        png, svg = (p.relative_to(folder).as_posix() for p in paths)
        lines += [f"### {captions[key]}", "", f"![{captions[key]}]({png})", "", f"[SVG]({svg})", ""]
    rep.report.write_text("\n".join(lines))
    return rep


def snapshot_links(sweep_dir: Path, folder: Path, collisions: Any, limit: int = 200) -> list[str]:
    """report.md lines linking the snapshot figure of every booked ego collision (the last decision
    before impact, written by the run into runs/<run_id>/snapshots/; in a fleet run one per ego
    party, collision_<event>_<ego folder>.png)."""
    import os
    from urllib.parse import quote

    import pandas as pd

    from sumo_ethics.record.decisions import ego_folder

    if collisions is None or len(collisions) == 0 or "run_id" not in collisions:
        return []
    booked = collisions[collisions["involves_ego"] & (collisions["detector"] != "sumo_unconfirmed")]
    rows = []
    for r in booked.sort_values(["run_id", "event"]).itertuples():
        snaps = sweep_dir / "runs" / r.run_id / "snapshots"
        names = [(f"collision_{r.event}.png", "png")]
        for p in "ab":  # a fleet run's ego parties (ego_a, ego_b: missing in the rows of single-ego runs)
            flag = getattr(r, f"ego_{p}", None)
            if pd.notna(flag) and bool(flag):
                who = getattr(r, f"id_{p}")
                names.append((f"collision_{r.event}_{ego_folder(who)}.png", f"png: ego '{who}'"))
        # an ego folder's '%' escaped once more: a link's target is URL-decoded ('%2F' would be '/')
        links = [f"[{label}]({quote(Path(os.path.relpath(snaps / n, folder)).as_posix())})" for n, label in names
                 if (snaps / n).is_file()]
        if links:
            rows.append(f"| {r.run_id} | {r.event} | {r.time:.1f} | {r.class_b} | {r.harm_ego:.3f} | "
                        f"{r.harm_third_party:.3f} | {', '.join(links)} |")
    if not rows:
        return []
    lines = ["## Collision snapshots", "",
             "The last planning step before each ego collision: the scene, the predictions, every candidate",
             "by validity class and by J_risk, and the chosen candidate's cost terms beside the best one of",
             "another validity class (`sumo-ethics explain RUN --collision EVENT` redraws one; a fleet ego's with",
             "`--ego ID`).", "",
             "| run | event | t [s] | other party | harm ego | harm third party | figure |",
             "| --- | --- | --- | --- | --- | --- | --- |", *rows[:limit]]
    if len(rows) > limit:
        lines.append(f"\n... and {len(rows) - limit} more in runs/*/snapshots/.")
    return lines + [""]
