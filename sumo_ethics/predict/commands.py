"""Plain functions behind the CLI commands (wired into click by sumo_ethics.cli)."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # pragma: no cover - pandas is imported by the command itself, not by the CLI's start
    import pandas as pd

log = logging.getLogger(__name__)


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
                      ped_speed_scale=None if ped_speed_scale is None else (ped_speed_scale[0], ped_speed_scale[1]), ema=ema,
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
) -> pd.DataFrame:
    """Evaluate constant velocity and the LSTM models on the test seeds of ``dataset``.

    ``weights`` maps model name -> weights file (default: the shipped map, attention and
    cslstm); split "all" evaluates every sample (a dataset of scenarios never trained on). Writes ``out``/prediction_eval.csv and .md; returns the DataFrame.
    """
    from sumo_ethics.predict.accuracy import evaluate

    return evaluate(Path(dataset), Path(out), weights=weights, max_samples=max_samples, seed=seed, split=split,
                    calibration_dataset=None if calibration_dataset is None else Path(calibration_dataset), title=title,
                    calibrated=calibrated)
