"""A run folder's recorded decisions read back: whose they are (the one ego's, or a fleet ego's:
:func:`decisions_of`), which steps are kept, the step of a time, collision or conflict, one decision
checked, the run's network and weights (for ``explain`` and ``replay``).

Every function taking ``ego`` reads fleet ego ``ego``'s decisions (``RUN/decisions/<ego folder>/``),
or with None the single ego's (``RUN/decisions/``)."""

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

#: egos named at most in a one-line error
LISTED = 12


def recorded(run: Path, ego: str | None = None) -> list[int]:
    """The recorded steps of ``run``; ConfigError naming the flag when there are none."""
    run = Path(run)
    if not run.is_dir():
        raise ConfigError(f"run folder not found: {run}")
    steps = rec.recorded_steps(run, ego)
    if not steps:
        mode = record_mode(run)
        who = "" if ego is None else f" of ego '{ego}'"
        if mode in (None, "off"):
            raise ConfigError(f"{run} has no recorded decisions{who}: run it with --record-decisions risky (or all)")
        if mode == "all":  # a route follower (baseline) decides without weighing candidates
            raise ConfigError(f"{run} kept no decisions{who} with --record-decisions all: its controller weighed "
                              "no candidates (the baseline, or emergency braking only)")
        raise ConfigError(f"{run} kept no decisions{who} with --record-decisions {mode} (no chosen trajectory carried "
                          "risk and the ego did not collide); run it with --record-decisions all for every step")
    return steps


def _json(run: Path, name: str) -> dict[str, Any]:
    """``name`` (config.json, summary.json) of ``run`` as a dict, {} when it cannot be read."""
    try:
        d = json.loads((Path(run) / name).read_text())
    except (OSError, ValueError):
        return {}
    return d if isinstance(d, dict) else {}


def is_fleet(run: Path) -> bool:
    """Whether ``run`` is a fleet run (config.json names a fleet, or its decisions are per ego)."""
    return _json(run, "config.json").get("fleet") is not None or bool(rec.recorded_egos(run))


def fleet_egos(run: Path) -> dict[str, str]:
    """The egos of fleet run ``run`` -> their fleet planner names (summary.json's ``egos``, else the
    ``ego_id`` and ``planner`` columns of steps.parquet: a killed run's too)."""
    egos = _json(run, "summary.json").get("egos")
    if isinstance(egos, list) and all(isinstance(e, dict) and "id" in e for e in egos):
        return {str(e["id"]): str(e.get("planner", "")) for e in egos}
    from sumo_ethics.record.reader import read_table

    t = read_table(Path(run), "steps")
    if "ego_id" not in t.column_names:
        return {}
    ids, planners = t.column("ego_id").to_pylist(), t.column("planner").to_pylist()
    return dict(zip(ids, planners))


def _listed(ids: list[str]) -> str:
    """At most LISTED ids, quoted, and how many there are in all."""
    shown = ", ".join(f"'{k}'" for k in ids[:LISTED])
    return shown + (f" ... ({len(ids)} in all)" if len(ids) > LISTED else "") if ids else "none"


def decisions_of(run: Path, ego: str | None = None) -> str | None:
    """Whose decisions of ``run`` to read, from ``--ego`` (``ego``): in a fleet run with per-ego
    decisions that ego (it is required), in a single-ego run None (``ego`` may only name the run's
    ego). ConfigError, one line, for anything else: no ``--ego`` in a fleet run (naming the egos
    with decisions), a vehicle that is not an ego, an ego that kept no decisions."""
    run = Path(run)
    if not run.is_dir():
        raise ConfigError(f"run folder not found: {run}")
    kept = rec.recorded_egos(run)
    if not is_fleet(run):
        if ego is not None:
            own = _json(run, "config.json").get("resolved", {}).get("ego_id") or _json(run, "summary.json").get("ego_id")
            if own is None:
                raise ConfigError(f"--ego '{ego}': {run} is a single-ego run that does not name its ego; drop --ego")
            if ego != own:
                raise ConfigError(f"--ego '{ego}': {run} is a single-ego run of ego '{own}'; drop --ego or name '{own}'")
        return None
    if ego is None:
        if not kept:
            recorded(run)  # the line saying how to record them
        raise ConfigError(f"{run} is a fleet run: give --ego ID; egos with recorded decisions: {_listed(kept)}")
    if ego not in kept:
        egos = fleet_egos(run)
        if ego not in egos:
            raise ConfigError(f"--ego '{ego}' is not an ego of {run} (egos with recorded decisions: {_listed(kept)})")
        recorded(run, ego)  # the line saying why it kept none
    return ego


def record_mode(run: Path) -> str | None:
    """The recording mode a run was made with (config.json, else summary.json), or None."""
    mode = _json(run, "config.json").get("record_decisions")
    if mode is None:
        kept = _json(run, "summary.json").get("decisions")
        mode = kept.get("mode") if isinstance(kept, dict) else None
    return None if mode is None else str(mode)


def resolve_step(run: Path, step: int | None = None, time: float | None = None, collision: int | None = None,
                 conflict: int | None = None, ego: str | None = None) -> int:
    """The recorded step named by exactly one of ``step``, ``time`` [s] (the nearest recorded
    planning time), ``collision`` (an event number of collisions.parquet: its last planning step
    before impact) or ``conflict`` (an event number of conflicts.parquet: the planning step nearest
    its worst moment, ``time_worst``), among fleet ego ``ego``'s decisions (it must be a party of the
    collision or conflict). ConfigError when it is not recorded."""
    if sum(v is not None for v in (step, time, collision, conflict)) != 1:
        raise ConfigError("give exactly one of --step, --time, --collision and --conflict")
    run = Path(run)
    if conflict is not None:
        time = float(_conflict_row(run, conflict, ego)["time_worst"])
    steps = recorded(run, ego)
    if time is not None and not np.isfinite(time):
        raise ConfigError(f"--time must be a finite time in seconds, got {time}")
    if collision is not None:
        from sumo_ethics.record.reader import read_table

        rows = read_table(run, "collisions").to_pylist()
        match = [r for r in rows if r["event"] == collision]
        if not match:
            raise ConfigError(f"{run} has no collision event {collision} (events: "
                              f"{', '.join(str(r['event']) for r in rows) or 'none'})")
        _party(match[0], ego, f"collision {collision}")
        step = int(match[0]["step"])
    if time is not None:
        times = np.array([_time_of(run, s, ego) for s in steps])
        i = int(np.argmin(np.abs(times - time)))
        if abs(times[i] - time) > 0.5:
            raise ConfigError(f"no decision{'' if ego is None else f' of ego {ego!r}'} recorded near t={time:g} s; "
                              f"the nearest is at t={times[i]:g} s (recorded: {_spans(times)})")
        return steps[i]
    if step is None:  # exactly one of the four is given: a collision's step, or the step itself
        raise ConfigError("give exactly one of --step, --time, --collision and --conflict")
    if step not in steps:
        near = min(steps, key=lambda s: abs(s - step))
        raise ConfigError(f"step {step} of {run} has no recorded decision{'' if ego is None else f' of ego {ego!r}'}; "
                          f"the nearest recorded step is {near}")
    return int(step)


def _party(row: dict[str, Any], ego: str | None, what: str) -> None:
    """ConfigError unless fleet ego ``ego`` (None: the single ego, always) is a party of ``row``."""
    if ego is not None and ego not in (row["id_a"], row["id_b"]):
        raise ConfigError(f"ego '{ego}' is not a party of {what} (parties: '{row['id_a']}' and '{row['id_b']}')")


def other_party(row: dict[str, Any], ego: str | None) -> str:
    """The party of ``row`` that is not ``ego``: "a" or "b" (b for the single ego, party a)."""
    return "a" if ego is not None and row["id_b"] == ego else "b"


@contextmanager
def readable(run: Path, step: int, ego: str | None = None) -> Iterator[None]:
    """Reading step ``step``'s decision file of ``run``: a file that cannot be read (cut short by
    a full disk, or not a decision file) becomes one ConfigError line."""
    try:
        yield
    except (OSError, ValueError, KeyError, IndexError, EOFError, zipfile.BadZipFile) as exc:
        raise ConfigError(f"{rec.step_path(run, step, ego)} is not a readable decision file (truncated or corrupt: "
                          f"{type(exc).__name__})") from None


def load_checked(run: Path, step: int, ego: str | None = None) -> RecordedDecision:
    """:func:`sumo_ethics.record.decisions.load`, with a ConfigError for an unreadable file."""
    with readable(run, step, ego):
        return rec.load(run, step, ego)


def _conflict_row(run: Path, event: int, ego: str | None = None) -> dict:
    """Conflict ``event`` of conflicts.parquet; ConfigError naming the events there are, or the
    parties when fleet ego ``ego`` is not one of them."""
    from sumo_ethics.record.reader import read_table

    rows = read_table(Path(run), "conflicts").to_pylist()
    match = [r for r in rows if r["event"] == event]
    if not match:
        raise ConfigError(f"{run} has no conflict event {event} (events: "
                          f"{', '.join(str(r['event']) for r in rows[:20]) or 'none'}"
                          f"{' ...' if len(rows) > 20 else ''})")
    _party(match[0], ego, f"conflict {event}")
    return match[0]


def party_label(row: dict[str, Any], p: str) -> str:
    """Party ``p`` ('a' or 'b') of a collisions/conflicts row as a figure names it: its class, id and
    SUMO vType, ``car 'veh3' (vType truck/trailer)``. The class follows the vType's vClass as SUMO
    types it (a vType without a vClass is SUMO's default, passenger: a car, whatever its id or
    shape), so the vType is named beside it, as the row's ``type_a``/``type_b`` holds it, unless it
    is the class's own name."""
    vtype, cls = row.get(f"type_{p}") or "", row[f"class_{p}"]
    return f"{cls} '{row[f'id_{p}']}'" + (f" (vType {vtype})" if vtype and vtype.lower() != cls else "")


def conflict_mark(run: Path, event: int, ego: str | None = None) -> tuple[float, float, str]:
    """Where the other party of conflict ``event`` (other than fleet ego ``ego``) was at its worst
    moment, and what the conflict was."""
    r = _conflict_row(run, event, ego)
    p = other_party(r, ego)
    what = [f"min TTC {r['min_ttc']:.2f} s" if np.isfinite(r["min_ttc"]) else "",
            f"min PET {r['min_pet']:.2f} s" if np.isfinite(r["min_pet"]) else ""]
    return (float(r[f"x_{p}"]), float(r[f"y_{p}"]),
            f"conflict {event}: {party_label(r, p)}, {', '.join(w for w in what if w)}")


def hit_of(run: Path, event: int, ego: str | None = None) -> tuple[float, float, str] | None:
    """Where the other party of collision ``event`` (other than fleet ego ``ego``) was just before
    impact, and who it was."""
    from sumo_ethics.record.reader import read_table

    rows = [r for r in read_table(Path(run), "collisions").to_pylist() if r["event"] == event]
    if not rows:
        return None
    return collision_mark(rows[0], ego)


def collision_mark(row: dict[str, Any], ego: str | None = None) -> tuple[float, float, str]:
    """Where the other party of collision ``row`` (other than fleet ego ``ego``) was just before
    impact, and who it was."""
    p = other_party(row, ego)
    return float(row[f"x_{p}"]), float(row[f"y_{p}"]), f"hit: {party_label(row, p)}"


def _time_of(run: Path, step: int, ego: str | None = None) -> float:
    with readable(run, step, ego), np.load(rec.step_path(run, step, ego), allow_pickle=False) as z:
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


def weights_of(run: Path, ego: str | None = None) -> dict[str, float] | None:
    """The run's cost weights (``planner.cost.weights`` of config.json, and the registered terms'
    ``planner.cost.term_weights``), or those of fleet ego
    ``ego``'s planner (a ``[planners.NAME]`` table of the fleet, else the preset of its name, as
    :func:`sumo_ethics.runner.fleet.make_fleet_controllers` builds it); None when unknown."""
    try:
        cfg = json.loads((Path(run) / "config.json").read_text())
        from dataclasses import asdict

        from sumo_ethics.ethics.cost import PRESETS, PrincipleWeights, principle_scale

        cost = cfg["planner"]["cost"]
        w = {**cost["weights"], **cost.get("term_weights", {})}
        if ego is not None:
            name = fleet_egos(run)[ego]
            named = {n: pc for n, pc in cfg["fleet"].get("planners", [])}
            if name in named:
                cost = named[name]["cost"]
                w = {**cost["weights"], **cost.get("term_weights", {})}
            else:  # a preset under the run's price level
                w = asdict(PRESETS[name])  # KeyError for baseline: no weights
        w = {k: float(v) for k, v in w.items()}
        principles = PrincipleWeights(**{k: w[k] for k in asdict(PrincipleWeights())})
        w["risk"] *= principle_scale(principles, cost.get("price", "preset"))  # price "equal": the principles scaled
        return w
    except (OSError, ValueError, KeyError, TypeError, AttributeError, ConfigError):
        return None


def road_of(run: Path) -> Any:
    path = net_file(run)
    if path is None:
        return None
    from sumo_ethics.sim.network import read_road

    return read_road(path)
