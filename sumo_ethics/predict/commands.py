"""Plain functions behind the CLI commands (wired into click by sumo_ethics.cli)."""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from pathlib import Path

log = logging.getLogger(__name__)


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
    in ``out``/partial as it ends (:mod:`sumo_ethics.predict.runstore`), and the same call on the
    same ``out`` resumes from them (``on_resume(kept, planned)`` is told first). SIGTERM stops it as Ctrl-C does
    (:class:`sumo_ethics.errors.Terminated`): its SUMO runs killed, no dataset written (a signal
    while the folder is written waits until it is whole); the interrupt's note says which, and how
    many finished runs are kept."""
    from sumo_ethics.errors import SimulationError
    from sumo_ethics.interrupt import sigterm_as_interrupt
    from sumo_ethics.predict.dataset import build_dataset

    with sigterm_as_interrupt():  # without it SIGTERM ended this process alone and its runs went on
        try:
            return build_dataset(
                [Path(s) for s in scenarios], list(seeds), Path(out), scales=tuple(scales),
                sim_seconds=sim_seconds, anchor_every=anchor_every, workers=workers,
                suite=[Path(s) for s in suite], suite_anchor_every=suite_anchor_every, on_resume=on_resume,
            )
        except KeyboardInterrupt as exc:  # the command's one line says what is on disk
            done = (Path(out) / "split.json").is_file()
            exc.add_note(f"the dataset was written whole to {out}" if done else f"no dataset is written{_kept_note(out)}")
            raise
        except SimulationError as exc:  # a SUMO run failed: the others' work is not lost either
            note = _kept_note(out)
            if note:
                raise SimulationError(f"{exc}{note}") from None
            raise


def _kept_note(out: Path | str) -> str:
    """What a stopped dataset build keeps, for its one line: ' (K of N runs finished and are kept in
    OUT/partial: the same command resumes from them)', or '' when no run finished."""
    from sumo_ethics.predict.runstore import PARTIAL, kept_runs

    kept, planned = kept_runs(Path(out))
    return (f" ({kept} of {planned} runs finished and are kept in {Path(out) / PARTIAL}: the same command "
            "resumes from them)" if kept else "")


def train_main(
    dataset: Path | str,
    model: str,
    out: Path | str,
    epochs: int = 40,
    mse_epochs: int = 1,
    max_minutes: float = 14.0,
    max_wall_minutes: float | None = None,
    max_train: int | None = 200_000,
    seed: int = 0,
    threads: int = 1,
    progress: bool = True,
    hazard_repeat: int = 1,
    nbr_frame: str | None = None,
    modes: int | None = None,
    dec: int | None = None,
    dec_steps: int | None = None,
    cv_mode: bool | None = None,
    single_mode_groups: tuple[int, ...] | None = None,
    stay_mode_groups: tuple[int, ...] | None = None,
    stay_speed: float | None = None,
    residual_groups: tuple[int, ...] | None = None,
    map_version: int | None = None,
    ped_speed_scale: tuple[float, float] | None = None,
    ema: float | None = None,
    extra_dataset: Path | None = None,
    extra_groups: tuple[int, ...] | None = None,
) -> dict:
    """Train ``model`` ("map", "map_cslstm", "attention" or "cslstm") on a dataset folder; write weights to ``out`` (.pt).

    max_minutes is a CPU-time budget (one thread); max_wall_minutes caps wall time (default 3x);
    map_version: the map features a map model reads (None: the dataset's); ema: decay of the
    weights' moving average that is validated and written (None: none, as shipped); extra_dataset,
    extra_groups: a second dataset whose training samples of those class groups (None: all) are
    trained on as well (TrainConfig).
    """
    from sumo_ethics.predict.train import TrainConfig, train_model

    cfg = TrainConfig(epochs=epochs, mse_epochs=mse_epochs, max_minutes=max_minutes, max_train=max_train,
                      seed=seed, threads=threads, max_wall_minutes=max_wall_minutes, hazard_repeat=hazard_repeat,
                      nbr_frame=nbr_frame, modes=modes, dec=dec, dec_steps=dec_steps, cv_mode=cv_mode,
                      single_mode_groups=None if single_mode_groups is None else tuple(single_mode_groups),
                      stay_mode_groups=None if stay_mode_groups is None else tuple(stay_mode_groups),
                      stay_speed=stay_speed,
                      residual_groups=None if residual_groups is None else tuple(residual_groups),
                      map_version=map_version,
                      ped_speed_scale=None if ped_speed_scale is None else tuple(ped_speed_scale), ema=ema,
                      extra_dataset=None if extra_dataset is None else str(extra_dataset),
                      extra_groups=None if extra_groups is None else tuple(extra_groups))
    from sumo_ethics.interrupt import sigterm_as_interrupt

    with sigterm_as_interrupt():  # as Ctrl-C: the best epoch so far is written, then the interrupt goes on
        return train_model(Path(dataset), model, Path(out), cfg, progress=progress)


def evaluate_main(
    dataset: Path | str,
    out: Path | str,
    weights: dict[str, Path | str] | None = None,
    max_samples: int | None = 50_000,
    seed: int = 0,
    split: str = "test",
    calibration_dataset: Path | str | None = None,
    title: str | None = None,
    calibrated: bool = False,
) -> "object":
    """Evaluate constant velocity and the LSTM models on the test seeds of ``dataset``.

    ``weights`` maps model name -> weights file (default: the shipped map, attention and
    cslstm); split "all" evaluates every sample (a dataset of scenarios never trained on). Writes ``out``/prediction_eval.csv and .md; returns the DataFrame.
    """
    from sumo_ethics.predict.evaluate import evaluate

    return evaluate(Path(dataset), Path(out), weights=weights, max_samples=max_samples, seed=seed, split=split,
                    calibration_dataset=None if calibration_dataset is None else Path(calibration_dataset), title=title,
                    calibrated=calibrated)
