"""A run folder's recorded decisions read back: which steps are kept, the step of a time, collision
or conflict, one decision checked, the run's network and weights (for ``explain`` and ``replay``)."""

from __future__ import annotations

import json
import zipfile
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from sumo_ethics.errors import ConfigError
from sumo_ethics.record import decisions as rec
from sumo_ethics.record.decisions import RecordedDecision

def recorded(run: Path) -> list[int]:
    """The recorded steps of ``run``; ConfigError naming the flag when there are none."""
    run = Path(run)
    if not run.is_dir():
        raise ConfigError(f"run folder not found: {run}")
    steps = rec.recorded_steps(run)
    if not steps:
        mode = record_mode(run)
        if mode in (None, "off"):
            raise ConfigError(f"{run} has no recorded decisions: run it with --record-decisions risky (or all)")
        raise ConfigError(f"{run} kept no decisions with --record-decisions {mode} (no chosen trajectory carried "
                          "risk and the ego did not collide); run it with --record-decisions all for every step")
    return steps


def record_mode(run: Path) -> str | None:
    """The recording mode a run was made with (config.json, else summary.json), or None."""
    for name, key in (("config.json", ("record_decisions",)), ("summary.json", ("decisions", "mode"))):
        try:
            d: Any = json.loads((Path(run) / name).read_text())
            for k in key:
                d = d[k]
            return str(d)
        except (OSError, ValueError, KeyError, TypeError):
            continue
    return None


def resolve_step(run: Path, step: int | None = None, time: float | None = None, collision: int | None = None,
                 conflict: int | None = None) -> int:
    """The recorded step named by exactly one of ``step``, ``time`` [s] (the nearest recorded
    planning time), ``collision`` (an event number of collisions.parquet: its last planning step
    before impact) or ``conflict`` (an event number of conflicts.parquet: the planning step nearest
    its worst moment, ``time_worst``). ConfigError when it is not recorded."""
    if sum(v is not None for v in (step, time, collision, conflict)) != 1:
        raise ConfigError("give exactly one of --step, --time, --collision and --conflict")
    run = Path(run)
    if conflict is not None:
        time = float(_conflict_row(run, conflict)["time_worst"])
    steps = recorded(run)
    if time is not None and not np.isfinite(time):
        raise ConfigError(f"--time must be a finite time in seconds, got {time}")
    if collision is not None:
        from sumo_ethics.record.reader import read_table

        rows = read_table(run, "collisions").to_pylist()
        match = [r for r in rows if r["event"] == collision]
        if not match:
            raise ConfigError(f"{run} has no collision event {collision} (events: "
                              f"{', '.join(str(r['event']) for r in rows) or 'none'})")
        step = int(match[0]["step"])
    if time is not None:
        times = np.array([_time_of(run, s) for s in steps])
        i = int(np.argmin(np.abs(times - time)))
        if abs(times[i] - time) > 0.5:
            raise ConfigError(f"no decision recorded near t={time:g} s; the nearest is at t={times[i]:g} s "
                              f"(recorded: {_spans(times)})")
        return steps[i]
    if step is None:  # exactly one of the four is given: a collision's step, or the step itself
        raise ConfigError("give exactly one of --step, --time, --collision and --conflict")
    if step not in steps:
        near = min(steps, key=lambda s: abs(s - step))
        raise ConfigError(f"step {step} of {run} has no recorded decision; the nearest recorded step is {near}")
    return int(step)


@contextmanager
def readable(run: Path, step: int) -> Iterator[None]:
    """Reading step ``step``'s decision file of ``run``: a file that cannot be read (cut short by
    a full disk, or not a decision file) becomes one ConfigError line."""
    try:
        yield
    except (OSError, ValueError, KeyError, IndexError, EOFError, zipfile.BadZipFile) as exc:
        raise ConfigError(f"{rec.step_path(run, step)} is not a readable decision file (truncated or corrupt: "
                          f"{type(exc).__name__})") from None


def load_checked(run: Path, step: int) -> RecordedDecision:
    """:func:`sumo_ethics.record.decisions.load`, with a ConfigError for an unreadable file."""
    with readable(run, step):
        return rec.load(run, step)


def _conflict_row(run: Path, event: int) -> dict:
    """Conflict ``event`` of conflicts.parquet; ConfigError naming the events there are."""
    from sumo_ethics.record.reader import read_table

    rows = read_table(Path(run), "conflicts").to_pylist()
    match = [r for r in rows if r["event"] == event]
    if not match:
        raise ConfigError(f"{run} has no conflict event {event} (events: "
                          f"{', '.join(str(r['event']) for r in rows[:20]) or 'none'}"
                          f"{' ...' if len(rows) > 20 else ''})")
    return match[0]


def conflict_mark(run: Path, event: int) -> tuple[float, float, str]:
    """Where the other party of conflict ``event`` was at its worst moment, and what the conflict was."""
    r = _conflict_row(run, event)
    what = [f"min TTC {r['min_ttc']:.2f} s" if np.isfinite(r["min_ttc"]) else "",
            f"min PET {r['min_pet']:.2f} s" if np.isfinite(r["min_pet"]) else ""]
    return (float(r["x_b"]), float(r["y_b"]),
            f"conflict {event}: {r['class_b']} '{r['id_b']}', {', '.join(w for w in what if w)}")


def hit_of(run: Path, event: int) -> tuple[float, float, str] | None:
    """Where the other party of collision ``event`` was just before impact, and who it was."""
    from sumo_ethics.record.reader import read_table

    rows = [r for r in read_table(Path(run), "collisions").to_pylist() if r["event"] == event]
    return (float(rows[0]["x_b"]), float(rows[0]["y_b"]), f"hit: {rows[0]['class_b']} '{rows[0]['id_b']}'") if rows else None


def _time_of(run: Path, step: int) -> float:
    with readable(run, step), np.load(rec.step_path(run, step), allow_pickle=False) as z:
        return float(z["meta"][1])


def _spans(times: np.ndarray) -> str:
    return f"{len(times)} steps between t={times.min():g} and {times.max():g} s"


def net_file(run: Path) -> Path | None:
    """The SUMO network of a run's scenario (from config.json), or None if it cannot be found."""
    from sumo_ethics.sim.scenario import read_scenario

    try:
        cfg = json.loads((Path(run) / "config.json").read_text())
        net = Path(cfg.get("resolved", {}).get("net", ""))
        if net.name and net.is_file():  # runs since the network's absolute path was recorded
            return net
        scenario = Path(cfg["scenario"])
        if not scenario.is_absolute():  # the summary names it resolved
            scenario = Path(json.loads((Path(run) / "summary.json").read_text()).get("scenario") or scenario)
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None
    # a relative path is relative to where the run was started: here, or a folder above the run
    bases = [Path.cwd()] if scenario.is_absolute() else [Path.cwd(), *Path(run).resolve().parents]
    for base in bases:
        try:
            return read_scenario(base / scenario).net
        except ConfigError:
            continue
    return None


def weights_of(run: Path) -> dict[str, float] | None:
    """The run's cost weights (``planner.cost.weights`` of config.json), or None."""
    try:
        w = json.loads((Path(run) / "config.json").read_text())["planner"]["cost"]["weights"]
        return {k: float(v) for k, v in w.items()}
    except (OSError, ValueError, KeyError, TypeError):
        return None


def road_of(run: Path) -> Any:
    path = net_file(run)
    if path is None:
        return None
    from sumo_ethics.sim.network import read_road

    return read_road(path)
