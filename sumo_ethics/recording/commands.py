"""``sumo-ethics dataset``: the plain function behind the command (wired into click by sumo_ethics.cli)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path


def dataset_main(
    scenarios: Sequence[Path | str],
    out: Path | str,
    seeds: Sequence[int] = tuple(range(1, 8)),
    sim_seconds: float = 600.0,
    anchor_every: float = 2.0,
    scales: Sequence[float] = (0.7, 1.0, 1.3),
    workers: int = 1,
    suite: Sequence[Path | str] = (),
    suite_anchor_every: float = 0.4,
    on_resume: Callable[[int, int], None] | None = None,
) -> Path:
    """Simulate ``scenarios`` (.sumocfg) x ``seeds`` (and record the ``suite`` scenario folders
    with their hazards) and write a prediction dataset folder to ``out``. Each finished run is kept
    in ``out``/partial as it ends (:mod:`sumo_ethics.recording.runstore`), and the same call on the
    same ``out`` resumes from them (``on_resume(kept, planned)`` is told first). SIGTERM stops it as Ctrl-C does
    (:class:`sumo_ethics.errors.Terminated`): its SUMO runs killed, no dataset written (a signal
    while the folder is written waits until it is whole); the interrupt's note says which, and how
    many finished runs are kept."""
    from sumo_ethics.errors import SimulationError, add_note
    from sumo_ethics.interrupt import sigterm_as_interrupt
    from sumo_ethics.recording.build import build_dataset

    with sigterm_as_interrupt():  # without it SIGTERM ended this process alone and its runs went on
        try:
            return build_dataset(
                [Path(s) for s in scenarios], list(seeds), Path(out), scales=tuple(scales),
                sim_seconds=sim_seconds, anchor_every=anchor_every, workers=workers,
                suite=[Path(s) for s in suite], suite_anchor_every=suite_anchor_every, on_resume=on_resume,
            )
        except KeyboardInterrupt as exc:  # the command's one line says what is on disk
            done = (Path(out) / "split.json").is_file()
            add_note(exc, f"the dataset was written whole to {out}" if done else f"no dataset is written{_kept_note(out)}")
            raise
        except SimulationError as exc:  # a SUMO run failed: the others' work is not lost either
            note = _kept_note(out)
            if note:
                raise SimulationError(f"{exc}{note}") from None
            raise


def _kept_note(out: Path | str) -> str:
    """What a stopped dataset build keeps, for its one line: ' (K of N runs finished and are kept in
    OUT/partial: the same command resumes from them)', or '' when no run finished."""
    from sumo_ethics.recording.runstore import PARTIAL, kept_runs

    kept, planned = kept_runs(Path(out))
    return (f" ({kept} of {planned} runs finished and are kept in {Path(out) / PARTIAL}: the same command "
            "resumes from them)" if kept else "")
