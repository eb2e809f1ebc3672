"""``sumo-ethics evaluate`` on CommonRoad scenarios: a folder of CommonRoad files (``*.xml``,
``*.xml.gz``, searched recursively) imported on the fly, or of folders imported ahead with
``import-commonroad`` (holding ``commonroad.json``).

Every file is imported into ``OUT/imported/<name>-<mode>`` (an import already there, of the same
mode, is reused), one fresh process per file, ``workers`` at a time
(:func:`sumo_ethics.processes.run_each`: one whose process dies is a failed row); a file that does not import is listed in
``OUT/imports.csv`` with its one-line cause and the import time, and the evaluation goes on with
the rest. Each imported folder is then run like a suite scenario (the run detects the import by
its ``commonroad.json``: the planning problem's ego, replayed or SUMO-driven obstacles, completion
= the CommonRoad goal region).
"""

from __future__ import annotations

import json
import re
import time
from pathlib import Path
from typing import Any, Callable

from sumo_ethics.errors import ConfigError, SumoEthicsError

MARKER = "commonroad.json"
SEED = 1  # SUMO's seed for every CommonRoad run (replay draws nothing; reactive drivers do)


def is_input(folder: Path) -> bool:
    """Whether ``folder`` holds CommonRoad files or imported CommonRoad folders (and no suite)."""
    folder = Path(folder)
    return folder.is_dir() and bool(commonroad_files(folder) or imported_folders(folder))


def commonroad_files(folder: Path) -> list[Path]:
    files = [p for p in Path(folder).rglob("*") if p.is_file() and (p.name.endswith(".xml") or p.name.endswith(".xml.gz"))
             and not (p.parent / MARKER).is_file()]
    return sorted(files, key=lambda p: (p.name, str(p)))


def imported_folders(folder: Path) -> list[Path]:
    return sorted(p.parent for p in Path(folder).rglob(MARKER))


def cause_of(message: str) -> str:
    """A failure message reduced to its cause (file names, numbers and details in brackets dropped)."""
    text = re.sub(r"^[^:]*\.xml(\.gz)?: ", "", message.strip())
    text = re.sub(r"\([^)]*\)", "", text)
    text = re.sub(r"-?\d+(\.\d+)?", "N", text)
    return re.sub(r"\s+", " ", text).strip(" :")


def _import_one(args: tuple[str, str, str, str]) -> dict[str, Any]:
    src, dest, mode, completion = args
    row: dict[str, Any] = {"file": src, "folder": dest, "mode": mode, "completion": completion}
    try:  # the packages loaded before the clock starts: the time is the scenario's own
        import commonroad.common.file_reader  # noqa: F401
        import commonroad_sumo.cr2sumo.map_converter.map_converter  # noqa: F401

        import sumo_ethics.sim.crnet  # noqa: F401
        from sumo_ethics.commonroad.importer import import_commonroad  # noqa: F401
    except ImportError:
        pass
    t0 = time.perf_counter()
    try:
        from sumo_ethics.commonroad.importer import import_commonroad

        res = import_commonroad(Path(src), Path(dest), mode, completion)
        row.update(status="imported", cause="", message="", obstacles=res.n_obstacles, replayed=res.n_replayed,
                   driven_by_sumo=res.n_reactive)
    except SumoEthicsError as exc:
        row.update(status="failed", message=str(exc), cause=cause_of(str(exc)))
    except Exception as exc:  # noqa: BLE001 - a bug or an odd file: listed, the others go on
        msg = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
        row.update(status="failed", message=f"internal error: {msg}", cause=f"internal error: {type(exc).__name__}")
    row["seconds"] = round(time.perf_counter() - t0, 3)
    return row


def _crashed_import(args: tuple[str, str, str, str], why: str) -> dict[str, Any]:
    """The row of an import whose process died (the converter crashing): failed, the others go on."""
    src, dest, mode, completion = args
    return {"file": src, "folder": dest, "mode": mode, "completion": completion, "status": "failed",
            "message": f"internal error: {why}", "cause": "internal error: run process died", "seconds": 0.0}


def _kind(marker: Path) -> tuple[Any, Any, Any]:
    """(source, mode, completion rule) of an imported folder's ``commonroad.json``."""
    m = json.loads(marker.read_text())
    return m.get("source"), m.get("mode"), m.get("completion", "commonroad")


def prepare(folder: Path, out: Path, mode: str, workers: int = 2,
            progress: Callable[[str], None] | None = None,
            completion: str = "commonroad") -> tuple[list[Path], list[dict[str, Any]]]:
    """(imported folders to run, one row per file: imported/reused/failed with cause and seconds);
    writes OUT/imports.csv. Folders imported ahead are run when their mode and completion rule are
    the ones asked for."""
    import pandas as pd

    from sumo_ethics.commonroad.importer import MODES, folder_name, require_packages, scenario_name
    from sumo_ethics.goal import COMPLETIONS

    if mode not in MODES:
        raise ConfigError(f"--mode must be one of {', '.join(MODES)}, got {mode!r}")
    if completion not in COMPLETIONS:
        raise ConfigError(f"--completion must be one of {', '.join(COMPLETIONS)}, got {completion!r}")
    folder, out = Path(folder), Path(out)
    ahead = {p: _kind(p / MARKER) for p in imported_folders(folder)}
    ready = [p for p, k in ahead.items() if k[1:] == (mode, completion)]
    rows: list[dict[str, Any]] = [{"file": str(p), "folder": str(p), "mode": mode, "completion": completion,
                                   "status": "imported ahead", "cause": "", "message": "", "seconds": 0.0}
                                  for p in ready]
    files = commonroad_files(folder)
    if not files and not ready and ahead:
        kinds = sorted({f"--mode {k[1]} --completion {k[2]}" for k in ahead.values()})
        raise ConfigError(f"the imported folders in {folder} were imported with {' / '.join(kinds)}, not --mode {mode} "
                          f"--completion {completion}; evaluate them with those options or import the files again")
    if files:
        require_packages()
    todo = []
    for f in files:
        dest = out / "imported" / folder_name(f, mode, completion)
        marker = dest / MARKER
        if marker.is_file() and _kind(marker) == (str(f.resolve()), mode, completion):
            rows.append({"file": str(f), "folder": str(dest), "mode": mode, "completion": completion,
                         "status": "reused", "cause": "", "message": "", "seconds": 0.0})
        else:
            todo.append((str(f), str(dest), mode, completion))
    names = [scenario_name(Path(t[0])) for t in todo]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ConfigError(f"two CommonRoad files named {dup[0]} in {folder}: scenario names must be unique")
    if todo:
        (out / "imported").mkdir(parents=True, exist_ok=True)
        if workers > 1 and len(todo) > 1:  # one fresh process per file, in the files' order
            from contextlib import closing

            from sumo_ethics.processes import run_each

            # the evaluation's modules too: its runs are forked from the same server, started here
            results = run_each(_import_one, todo, workers, preload=("sumo_ethics.suite.preload", __name__),
                               on_crash=_crashed_import, ordered=True)
            with closing(results):  # closed: no import process runs on
                for _, row in results:
                    rows.append(row)
                    if progress is not None:
                        progress(_line(row))
        else:
            for t in todo:
                rows.append(_import_one(t))
                if progress is not None:
                    progress(_line(rows[-1]))
    out.mkdir(parents=True, exist_ok=True)
    pd.DataFrame(rows).to_csv(out / "imports.csv", index=False)
    dirs = sorted((Path(r["folder"]) for r in rows if r["status"] != "failed"), key=lambda p: p.name)
    return dirs, rows


def _line(row: dict[str, Any]) -> str:
    name = Path(row["file"]).name
    if row["status"] == "failed":
        msg = row["message"]
        return f"import failed: {msg if msg.startswith(name) else f'{name}: {msg}'}"
    return f"imported {name} in {row['seconds']:.1f} s"


def run_one(scenario_dir: str, planner: Any, out_dir: str, record_decisions: str = "risky") -> dict[str, Any]:
    """One imported CommonRoad folder with one planner -> a result row for evaluate (never raises)."""
    from sumo_ethics.suite.outcome import read_summary, snapshots_of

    t0 = time.perf_counter()
    folder = Path(scenario_dir)
    row: dict[str, Any] = {"scenario": folder.name, "planner": planner.name}
    try:
        meta = json.loads((folder / MARKER).read_text())
        from sumo_ethics.config import RunConfig
        from sumo_ethics.runner import make_controller, run
        from sumo_ethics.settings import planner_config

        pcfg = planner_config(None, **planner.options) if planner.options is not None else None
        cfg = RunConfig(scenario=next(folder.glob("*.sumocfg")), out=Path(out_dir), seed=SEED,
                        controller="baseline" if planner.options is None else "ethical", planner=pcfg,
                        progress=False, overwrite=True, record_decisions=record_decisions)
        try:
            data = run(cfg, controller=make_controller(cfg)).data
        except Exception as exc:  # noqa: BLE001 - a failed run is a row with status error
            data = read_summary(Path(out_dir)) or {"status": "error", "message": str(exc)}
            if not data.get("message"):
                data["message"] = f"{type(exc).__name__}: {exc}"
        data.update(snapshots_of(Path(out_dir)))
        row.update(_row(meta, Path(out_dir), data))
    except Exception as exc:  # noqa: BLE001
        row.update(status="error", completed=False, total=0.0, ego=0.0, third_party=0.0, vru=0.0,
                   message=f"{type(exc).__name__}: {exc}"[:200], steps=0, hazards_fired="", collided_with="")
    row["wall_s"] = time.perf_counter() - t0
    return row


def row_from_folder(scenario_dir: str, planner: Any, out_dir: str) -> dict[str, Any] | None:
    """The row of a finished run of an imported CommonRoad folder (for ``evaluate --resume``), None
    when ``out_dir`` holds no finished run: no summary, a killed run's chunks, or a run that was
    interrupted or ended in an error (those are run again)."""
    from sumo_ethics.record.reader import is_incomplete
    from sumo_ethics.suite.outcome import read_summary

    out, folder = Path(out_dir), Path(scenario_dir)
    data = read_summary(out)
    if data is None or is_incomplete(out) or data.get("status") in ("interrupted", "error", None):
        return None
    try:
        meta = json.loads((folder / MARKER).read_text())
    except (OSError, ValueError):
        return None
    return {"scenario": folder.name, "planner": planner.name, **_row(meta, out, data),
            "wall_s": float(data.get("wall_time", 0.0) or 0.0)}


def _row(meta: dict[str, Any], out: Path, data: dict[str, Any]) -> dict[str, Any]:
    """The result columns of one run from its import's ``commonroad.json``, its folder and summary."""
    from sumo_ethics.analysis.exante import run_risk_file
    from sumo_ethics.suite.outcome import outcome

    harm = data.get("harm", {})
    cr = data.get("commonroad", {})
    return dict(network=f"commonroad-{meta['mode']}", hazard="", seed=SEED,
                status=data.get("status", "error"), completed=bool(data.get("completed", False)),
                total=float(harm.get("total", 0.0)), ego=float(harm.get("ego", 0.0)),
                third_party=float(harm.get("third_party", 0.0)), vru=float(harm.get("vru", 0.0)),
                message=str(data.get("message", ""))[:200], steps=int(data.get("steps", 0) or 0),
                hazards_fired="", goal_reached=bool(cr.get("goal_reached", False)),
                goal_late=bool(cr.get("goal_late", False)),
                goal_time_step=cr.get("goal_time_step"),
                replay_max_error_m=float(cr.get("replay", {}).get("max_error_m", float("nan"))),
                **outcome(out, data), **run_risk_file(out))


def failure_summary(rows: list[dict[str, Any]]) -> list[tuple[str, int]]:
    """(cause, count) of the failed imports, most frequent first."""
    from collections import Counter

    c = Counter(r["cause"] for r in rows if r["status"] == "failed")
    return sorted(c.items(), key=lambda kv: (-kv[1], kv[0]))
