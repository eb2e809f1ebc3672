"""Training: MSE warm-up, then bivariate Gaussian NLL; Adam, early stopping on validation NLL.

Deterministic for a given seed on CPU (torch.manual_seed, deterministic algorithms,
shuffling from a seeded numpy Generator). One torch thread by default (shared machines).
"""

from __future__ import annotations

import logging
import math
import signal
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, cast

import numpy as np
import torch
from torch.optim import swa_utils

from sumo_ethics import fileio
from sumo_ethics.errors import Terminated, add_note
from sumo_ethics.interrupt import signals_held
from sumo_ethics.predict import PredictorError
from sumo_ethics.predict import features as F
from sumo_ethics.predict.samples import add_train_samples, load_samples, map_version_of, require_nbr_yaw, subset
from sumo_ethics.predict.models import (
    TrajectoryLSTM,
    batch_to_tensors,
    bivariate_nll,
    MAP_KINDS,
    default_modes,
    default_options,
    default_nbr_frame,
    masked_mse,
    mixture_nll,
    save_model,
    winner_mse,
)

SPLITS = {"train": 0, "val": 1, "test": 2}
log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TrainConfig:
    """epochs: maximum epochs in all; mse_epochs: warm-up epochs with the MSE loss;
    patience: NLL epochs without validation improvement before stopping; lr_decay: factor
    applied to the learning rate after each NLL epoch without improvement; max_minutes:
    time budget [min], measured as this process's CPU time (budget_clock="cpu": the same
    amount of work however loaded the machine is, so runs are reproducible) or wall time
    ("wall"); max_wall_minutes: hard wall-clock cap (default 3 x max_minutes);
    max_train/max_val: caps on sample counts (random subset); hazard_repeat: each training
    sample of a hazard actor (manoeuvre "hazard") is used this many times per epoch (they are
    rare and the planner's risk depends on them most); nbr_frame: the model's neighbour
    encoding (models.NBR_FRAMES; None: models.default_nbr_frame); modes: Gaussian trajectory modes
    per target (1: a single Gaussian as before; > 1: winner-takes-all MSE warm-up, then the mixture
    NLL, see models.mixture_nll; None: models.default_modes); dec: decoder LSTM size; dec_steps: its
    steps (None: one per output step); cv_mode: the
    last mode's mean is the constant-velocity rollout; single_mode_groups: class groups
    (features.GROUP_*) that get mode 0 only (weight 1); stay_mode_groups: class groups that get
    mode 0 and a last mode that stays where it is (models.TrajectoryLSTM); stay_speed [m/s]: that
    mode only for targets slower than it (None: for all); residual_groups: class
    groups decoded as corrections to the constant-velocity rollout; each None:
    models.default_options; map_version: the map features a map model reads (features.MAP_VERSIONS,
    at most the dataset's; None: the dataset's), so a file of an earlier version can be trained
    again from a newer dataset; ped_speed_scale (lo, hi): each time a pedestrian's training sample
    is used, its history and future are scaled about its current position by a factor drawn
    log-uniformly from [lo, hi], so it walks that much faster or slower along the same path (the
    map rows and neighbours stay; None: as recorded); ema: decay of an exponential moving average of
    the weights, updated after every optimiser step (torch.optim.swa_utils); validation, early
    stopping and the written file then use the averaged weights (None: the weights as trained);
    extra_dataset: a second dataset folder (same map version) whose training-split samples of the
    class groups ``extra_groups`` (None: all) join the training samples (dataset.add_train_samples;
    validation stays the first dataset's)."""

    epochs: int = 40
    mse_epochs: int = 4
    batch_size: int = 128
    lr: float = 1e-3
    patience: int = 6
    lr_decay: float = 0.5
    grad_clip: float = 10.0
    seed: int = 0
    threads: int = 1
    max_minutes: float = 14.0
    budget_clock: str = "cpu"
    max_wall_minutes: float | None = None
    max_train: int | None = None
    max_val: int | None = 8000
    hazard_repeat: int = 1
    nbr_frame: str | None = None
    modes: int | None = None
    dec: int | None = None
    dec_steps: int | None = None
    cv_mode: bool | None = None
    single_mode_groups: tuple[int, ...] | None = None
    stay_mode_groups: tuple[int, ...] | None = None
    stay_speed: float | None = None
    residual_groups: tuple[int, ...] | None = None
    map_version: int | None = None
    ped_speed_scale: tuple[float, float] | None = None
    ema: float | None = None
    extra_dataset: str | None = None
    extra_groups: tuple[int, ...] | None = None


def _split_index(samples: dict[str, np.ndarray], name: str, cap: int | None, rng: np.random.Generator) -> np.ndarray:
    idx = np.flatnonzero(samples["split"] == SPLITS[name])
    if cap is not None and len(idx) > cap:
        idx = np.sort(rng.choice(idx, size=cap, replace=False))
    return idx


def speed_factors(group: np.ndarray, scale: tuple[float, float], rng: np.random.Generator) -> np.ndarray:
    """(S,) factors for TrainConfig.ped_speed_scale: log-uniform in ``scale`` for pedestrians, 1 for the others."""
    lo, hi = np.log(scale[0]), np.log(scale[1])
    k = np.exp(rng.uniform(lo, hi, len(group)))
    return np.where(group == F.GROUP_PEDESTRIAN, k, 1.0)


def _loss(model: TrajectoryLSTM, samples: dict[str, np.ndarray], index: np.ndarray, use_nll: bool,
          factor: np.ndarray | None = None) -> torch.Tensor:
    """Training loss of the samples ``index``; ``factor`` (S,): their target's history, future and
    speed scaled about its current position (:func:`speed_factors`)."""
    batch = subset(samples, index)
    if factor is not None:
        f32 = factor.astype(np.float32)
        batch["tgt_hist"] = batch["tgt_hist"] * f32[:, None, None]
        batch["fut"] = batch["fut"] * f32[:, None, None]
        batch["tgt_speed"] = batch["tgt_speed"] * f32
    x = batch_to_tensors(batch, model.pos_scale, with_map=model.kind in MAP_KINDS, map_version=model.map_version)
    scale = model.scale(x["tgt_group"])
    y = torch.as_tensor(batch["fut"], dtype=torch.float32) / scale[:, None, None]
    mask = torch.as_tensor(batch["fut_valid"]) if "fut_valid" in batch else None
    if model.modes > 1:
        params, log_w = model(**x, all_modes=True)
        return mixture_nll(params, log_w, y, mask) if use_nll else winner_mse(params, log_w, y, mask)
    out = model(**x)
    return bivariate_nll(out, y, mask) if use_nll else masked_mse(out, y, mask)


@torch.no_grad()
def validate(model: TrajectoryLSTM, samples: dict[str, np.ndarray], index: np.ndarray, batch_size: int = 512) -> dict[str, float]:
    """Validation NLL (normalised units; the mixture NLL of whole trajectories per point for a
    multi-modal model) and ADE [m] of the (most likely) mode over ``index``."""
    model.eval()
    nll_sum, ade_sum, n = 0.0, 0.0, 0
    for start in range(0, len(index), batch_size):
        idx = index[start: start + batch_size]
        batch = subset(samples, idx)
        x = batch_to_tensors(batch, model.pos_scale, with_map=model.kind in MAP_KINDS, map_version=model.map_version)
        scale = model.scale(x["tgt_group"])
        fut = torch.as_tensor(batch["fut"], dtype=torch.float32)
        mask = torch.as_tensor(batch["fut_valid"]) if "fut_valid" in batch else torch.ones(fut.shape[:2], dtype=torch.bool)
        if model.modes > 1:
            params, log_w = model(**x, all_modes=True)
            out = params[torch.arange(len(idx)), log_w.argmax(-1)]
            nll = mixture_nll(params, log_w, fut / scale[:, None, None], mask)
        else:
            out = model(**x)
            nll = bivariate_nll(out, fut / scale[:, None, None], mask)
        nll_sum += float(nll) * len(idx)
        err = (out[..., :2] * scale[:, None, None] - fut).norm(dim=-1)
        ade_sum += float((err * mask).sum() / mask.sum().clamp_min(1)) * len(idx)
        n += len(idx)
    model.train()
    return {"nll": nll_sum / max(n, 1), "ade": ade_sum / max(n, 1)}


def interrupted_path(out: Path) -> Path:
    """Where an interrupted training writes when ``out`` already exists: the first free one of
    NAME.interrupted.pt, NAME.interrupted-2.pt, ... (with its .json log beside it)."""
    for k in range(1, 10_000):
        path = out.with_name(f"{out.stem}.interrupted{'' if k == 1 else f'-{k}'}{out.suffix or '.pt'}")
        if not path.exists() and not path.with_suffix(".json").exists():
            return path
    raise FileExistsError(f"no free name beside {out} for an interrupted training")


def train_model(
    dataset: Path,
    kind: str,
    out: Path,
    config: TrainConfig = TrainConfig(),
    progress: bool = True,
) -> dict[str, Any]:
    """Train one model on ``dataset`` (folder with samples.npz) and save it to ``out`` (.pt).

    Returns a summary dict (also stored in the weights header under ``info``).
    """
    torch.set_num_threads(max(1, config.threads))
    torch.manual_seed(config.seed)
    torch.use_deterministic_algorithms(True)
    rng = np.random.default_rng(config.seed)
    data_version = map_version_of(dataset)  # the map features its samples were built with
    map_version = data_version if config.map_version is None else int(config.map_version)
    if config.map_version is not None and kind not in MAP_KINDS:
        raise PredictorError(f"--map-version {config.map_version}: {kind} reads no map")
    if map_version not in F.MAP_VERSIONS or map_version > data_version:
        raise PredictorError(f"map version {map_version}: dataset {dataset} has map version {data_version}, so a "
                             f"model of it reads {' to '.join(map(str, (min(F.MAP_VERSIONS), data_version)))}")
    samples = load_samples(dataset)
    if config.extra_dataset is not None:
        extra = Path(config.extra_dataset)
        if not (extra / "samples.npz").is_file():
            raise PredictorError(f"extra dataset {extra}: no samples.npz (not a dataset folder)")
        extra_version = map_version_of(extra)
        if extra_version != data_version:
            raise PredictorError(f"extra dataset {extra} has map version {extra_version}, {dataset} has "
                                 f"{data_version}: build both with the same sumo-ethics")
        try:
            samples = add_train_samples(samples, load_samples(extra), config.extra_groups)
        except ValueError as exc:
            raise PredictorError(f"extra dataset {extra}: {exc}") from None
    nbr_frame = config.nbr_frame or default_nbr_frame(kind)
    if nbr_frame == "agent":
        require_nbr_yaw(samples, dataset)
    train_idx = _split_index(samples, "train", config.max_train, rng)
    if config.hazard_repeat > 1 and "manoeuvre" in samples:
        hz = train_idx[samples["manoeuvre"][train_idx] == 4]
        train_idx = np.sort(np.concatenate([train_idx] + [hz] * (config.hazard_repeat - 1)))
    val_idx = _split_index(samples, "val", config.max_val, rng)
    if len(train_idx) == 0 or len(val_idx) == 0:
        raise ValueError(f"dataset {dataset} has no train or no validation samples")
    modes = config.modes or default_modes(kind)
    options = {k: v if getattr(config, k) is None else getattr(config, k) for k, v in default_options(kind, modes).items()}
    for given, default in (("stay_mode_groups", "single_mode_groups"), ("single_mode_groups", "stay_mode_groups")):
        if getattr(config, given) is not None and getattr(config, default) is None:  # a group asked for one way
            options[default] = tuple(g for g in options[default] if g not in options[given])  # leaves the other
    config = replace(config, nbr_frame=nbr_frame, modes=modes, **options)  # as trained, in the log
    model = TrajectoryLSTM(kind=kind, nbr_frame=nbr_frame, modes=modes, dec=options["dec"], cv_mode=options["cv_mode"],
                           dec_steps=config.dec_steps,
                           single_mode_groups=tuple(options["single_mode_groups"]),
                           stay_mode_groups=tuple(options["stay_mode_groups"]), stay_speed=config.stay_speed,
                           residual_groups=tuple(options["residual_groups"]),
                           map_version=map_version)  # the options as resolved into config above
    opt = torch.optim.Adam(model.parameters(), lr=config.lr)
    averaged = None if config.ema is None else swa_utils.AveragedModel(
        model, multi_avg_fn=swa_utils.get_ema_multi_avg_fn(config.ema))
    # the weights validated and written; AveragedModel holds a deep copy of the model (typed nn.Module)
    judged = model if averaged is None else cast(TrajectoryLSTM, averaged.module)
    n_batches = math.ceil(len(train_idx) / config.batch_size)
    best, best_state, best_epoch, bad = math.inf, None, -1, 0
    history: list[dict[str, float | str]] = []  # numbers, and the phase's name
    t0 = time.monotonic()
    clock = time.process_time if config.budget_clock == "cpu" else time.monotonic
    c0 = clock()
    p0 = time.process_time()
    wall_cap = t0 + 60.0 * (config.max_wall_minutes or 3 * config.max_minutes)

    def over_budget() -> bool:
        return clock() - c0 > 60.0 * config.max_minutes or time.monotonic() > wall_cap

    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    with Progress(
        TextColumn("[bold]{task.description}"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
        TextColumn("{task.fields[info]}"), TimeElapsedColumn(), disable=not progress,
    ) as bar:
        task = bar.add_task(f"{kind}", total=config.epochs * n_batches, info="")
        stopped = "max epochs"
        interrupted: KeyboardInterrupt | None = None
        try:
            for epoch in range(config.epochs):
                use_nll = epoch >= config.mse_epochs
                perm = rng.permutation(train_idx)
                running = 0.0
                for b in range(n_batches):
                    idx = np.sort(perm[b * config.batch_size: (b + 1) * config.batch_size])
                    factor = None if config.ped_speed_scale is None else speed_factors(
                        samples["tgt_group"][idx], config.ped_speed_scale, rng)
                    loss = _loss(model, samples, idx, use_nll, factor)
                    opt.zero_grad()
                    loss.backward()
                    torch.nn.utils.clip_grad_norm_(model.parameters(), config.grad_clip)
                    opt.step()
                    if averaged is not None:
                        averaged.update_parameters(model)
                    running += loss.item()
                    bar.update(task, advance=1, info=f"ep {epoch} {'nll' if use_nll else 'mse'} {running / (b + 1):.3f}")
                    if over_budget():
                        break
                val = validate(judged, samples, val_idx)
                history.append({"epoch": epoch, "loss": running / max(b + 1, 1), "val_nll": val["nll"], "val_ade": val["ade"],
                                "phase": "nll" if use_nll else "mse", "minutes": (time.monotonic() - t0) / 60})
                bar.update(task, info=f"ep {epoch} val nll {val['nll']:.3f} ade {val['ade']:.2f} m")
                log.info("%s epoch %d (%s): train loss %.4f, val nll %.4f, val ade %.3f m, %.1f min", kind, epoch,
                         history[-1]["phase"], history[-1]["loss"], val["nll"], val["ade"], history[-1]["minutes"])
                if use_nll:
                    if val["nll"] < best - 1e-4:
                        state = {k: v.detach().clone() for k, v in judged.state_dict().items()}
                        best_state, best, best_epoch, bad = state, val["nll"], epoch, 0  # together, for an interrupt
                    else:
                        bad += 1
                        for group in opt.param_groups:
                            group["lr"] *= config.lr_decay
                        if bad >= config.patience:
                            stopped = "early stopping"
                            break
                if over_budget():
                    stopped = "time budget"
                    break
        except KeyboardInterrupt as exc:  # Ctrl-C or SIGTERM (errors.Terminated): the best epoch so far is kept
            interrupted = exc
            stopped = "interrupted (SIGTERM)" if isinstance(exc, Terminated) else "interrupted (Ctrl-C)"
    if interrupted is not None and best_state is None:  # no NLL epoch ended: nothing worth a file
        raise interrupted
    if best_state is not None:
        model.load_state_dict(best_state)
    info = {
        "kind": kind,
        "dataset": str(dataset),
        "config": asdict(config),
        "n_train": int(len(train_idx)),
        "n_val": int(len(val_idx)),
        "best_epoch": best_epoch,
        "best_val_nll": best,
        "stopped": stopped,
        "minutes": (time.monotonic() - t0) / 60,
        "cpu_minutes": (time.process_time() - p0) / 60,
        "history": history,
        "feature_version": F.FEATURE_VERSION,
    }
    if interrupted is not None and Path(out).exists():  # the file that was there stays: a cut-short one goes beside it
        out = interrupted_path(Path(out))
    try:
        with signals_held(signal.SIGINT, signal.SIGTERM):  # the file and its log are written whole
            save_model(model, Path(out), info)
            fileio.write_json(Path(out).with_suffix(".json"), info)  # whole or not at all, as the weights
    except KeyboardInterrupt:  # one more held while writing: the first, with its note, is the one raised
        if interrupted is None:
            raise
    if interrupted is not None:
        add_note(interrupted, f"the best epoch so far ({best_epoch}, validation NLL {best:.3f}) is written to {out}")
        raise interrupted
    return info
