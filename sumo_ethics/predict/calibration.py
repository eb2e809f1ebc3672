"""Post-hoc calibration of the predictors' Gaussians (numpy only; no torch here).

The learned predictors output, per agent, mode and 0.2 s step, a bivariate Gaussian in the
agent's heading frame now (x along its heading, y to its left): mean (mu_x, mu_y), standard
deviations (sigma_x, sigma_y) and correlation rho. Those spreads are too wide in the core and
too narrow exactly when a road user moves sideways (issue 37; the coverage of the ellipses before
and after: docs/prediction-accuracy.md, "Calibrated uncertainty").

The calibration leaves the means, the correlations and the mode weights as they are and
multiplies the two standard deviations:

    sigma_x' = c_lon(g, s, t) * sigma_x,   sigma_y' = c_lat(g, s, t) * sigma_y

per class group g (vehicle, cyclist, pedestrian: ``features.GROUP_NAMES``), horizon t and a
manoeuvre state s that is known when the prediction is made (never the future's label):

- ``lateral_extent`` [m]: the largest lateral offset |mu_y| over the horizon of any mode whose
  weight is at least ``MODE_WEIGHT_MIN`` (the most likely mode always counts). It is large when
  the model itself foresees a turn, a lane change or a swerve, or keeps one as a real
  alternative; it is about 0 for a road user the model expects to go straight on.
- s = ``steady`` below STATE_EDGES[0], ``lateral`` up to STATE_EDGES[1], ``strong_lateral`` above;
  and ``standing``: steady, and slower than STAND_SPEED (0.5 m/s) now.

STANDING (version 2). Version 1 had no ``standing`` state: a car parked at the kerb shared the
``steady`` factors of moving traffic, whose lateral errors (drifts, lane changes at speed) are
far larger than a standing vehicle's own, and the ethical planner waited behind parked cars
(issue 37; the figures: docs/prediction-accuracy.md, "Calibrated uncertainty", its paragraph
"Standing road users"). They now get their own cell, fitted by the same rule as every other.

Fit (:func:`fit`), per (g, s, horizon bin) on held-out samples (the validation split), from the
standardised errors z_x = (x - mu_x) / sigma_x, z_y = (y - mu_y) / sigma_y of the most likely mode:
1. the ratio of the two factors from the (weighted) 90th percentile of |z_x| and of |z_y| (each
   divided by the normal's 1.645), so the ellipse gets the shape of the errors' tails;
2. one common factor so that a share FIT_LEVEL of the (weighted) points lies inside the 2-sigma
   ellipse (closed form: the squared Mahalanobis distance scales as 1 / factor^2).
The points are weighted so that each future manoeuvre of a class group (straight, turn, stop at
a light, lane change, hazard: ``samples.manoeuvre_labels``, at least 500 samples' worth each)
weighs as much as any other (:func:`balanced_weights`). The label is used only to weight the fit;
which factors an agent gets depends only on what is known when it is predicted (its class and
its modes). Without the weights, the rare lane changes (no observable state in which they are
the majority) are outvoted by straight driving.

FAVOURING THE TAIL. SUMO's lane changes are a lateral jump of a lane width at a moment the
histories, blinkers and modes mostly do not announce: the lateral errors
are a mixture of "stays in lane" (centimetres) and "changed lane" (3 m). One Gaussian per mode
cannot fit both core and tail. The fit favours the tail, by choice: FIT_LEVEL = 0.91 instead of
the nominal 0.865 on the balanced points, the smallest level (0.865, 0.90, 0.91 tried, before the
cap below) at which the lane changes of the validation split reached 80 % inside the 2-sigma
ellipse. The price: the
inner ellipses of straight driving hold far more than nominal (1-sigma well above 39 %) and the
mixture NLL per point rises (docs/predictor_calibration/coverage.md has the numbers).

A cap keeps a factor from blowing up a spread the model already made wide: a calibrated sigma is
at most the CAP_QUANTILE (99.5 %) of the absolute validation errors along that axis, for the class
group and horizon bin (so no 1-sigma band is wider than what 99.5 % of the errors needed), or
the model's own sigma where that is larger (the cap never narrows a spread):
``sigma' = min(c sigma, max(sigma, cap))``. Without it, factors fitted on the common case (a
lateral sigma at its floor) could spread a fast car's Gaussian so thin that the collision
probability near its mean falls: wider is not always safer (docs/prediction-accuracy.md,
"Calibrated uncertainty", has the case).

A cell with fewer than ``min_points`` points takes the pooled fit of its group and bin over
all states, and with fewer still the factor 1. Factors are clipped to
[SCALE_MIN, SCALE_MAX]. Between bin centres the factors are interpolated linearly in t (held
beyond the first and last centre). Every mode of an agent gets that agent's factors (the fit
sees the most likely mode only).

A calibration is stored beside its weights file as ``<stem>.calibration.json``
(:func:`calibration_path`) with the SHA-256 of the weights it was fitted for;
``LSTMPredictor.from_file`` applies it unless ``calibrated=False`` (a file whose hash does not
match is not applied, with a warning).
"""

from __future__ import annotations

import hashlib
import json
import logging
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import overload

import numpy as np

from sumo_ethics.predict import features as F

log = logging.getLogger(__name__)

FORMAT = "sumo-ethics-calibration"
VERSION = 2
STATES = ("steady", "lateral", "strong_lateral", "standing")
#: [m] lateral_extent edges between the STATES
STATE_EDGES = (0.5, 2.0)
#: [m/s] an agent slower than this now, with steady modes, is ``standing``
STAND_SPEED = 0.5
#: index of ``standing`` in STATES
STANDING = STATES.index("standing")
#: a mode counts for lateral_extent when its weight is at least this (the most likely always counts)
MODE_WEIGHT_MIN = 0.1
#: horizon bins as model steps (1-based, 0.2 s each): [first, last] of each bin
BINS = ((1, 3), (4, 7), (8, 12), (13, 16), (17, 20))
#: nominal mass of the 2-sigma ellipse of a bivariate Gaussian, 1 - exp(-2)
TARGET = float(1.0 - np.exp(-2.0))
#: share of the (balanced) fitting points the fitted 2-sigma ellipse holds: above TARGET, for the tail
FIT_LEVEL = 0.91
#: a future manoeuvre weighs as if it had at least this many samples (balanced_weights)
BALANCE_MIN = 500
#: normal quantile of the marginal percentile that sets the ellipse's shape (90 %: 1.6449)
SHAPE_Q, SHAPE_Z = 0.9, 1.6448536269514722
SCALE_MIN, SCALE_MAX = 0.25, 50.0
#: quantile of the absolute validation errors that caps a calibrated sigma
CAP_QUANTILE = 0.995
MIN_POINTS = 300


def ellipse_mass(k: float | np.ndarray) -> float | np.ndarray:
    """Mass of a bivariate Gaussian inside its k-sigma ellipse: 1 - exp(-k^2 / 2)."""
    return 1.0 - np.exp(-0.5 * np.asarray(k, dtype=float) ** 2)


@overload
def ellipse_k(p: float) -> float: ...
@overload
def ellipse_k(p: np.ndarray) -> np.ndarray: ...
def ellipse_k(p: float | np.ndarray) -> float | np.ndarray:
    """The k whose k-sigma ellipse holds mass p: sqrt(-2 ln(1 - p))."""
    return np.sqrt(-2.0 * np.log1p(-np.asarray(p, dtype=float)))


def bin_centres() -> np.ndarray:
    """(len(BINS),) centre time of each horizon bin [s]."""
    return np.array([(a + b) / 2.0 * F.MODEL_DT for a, b in BINS])


def lateral_extent(mu_y: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """(S,) [m] the largest |mu_y| over the horizon of the modes of weight >= MODE_WEIGHT_MIN
    (and of mode 0, the most likely): mu_y (S, M, T) lateral means in the heading frame now,
    weight (S, M), modes by falling weight."""
    mu_y = np.asarray(mu_y, dtype=float)
    w = np.asarray(weight, dtype=float)
    counts = w >= MODE_WEIGHT_MIN
    counts[:, 0] = True
    ext = np.abs(mu_y).max(axis=-1)  # (S, M)
    return np.where(counts, ext, 0.0).max(axis=1)


def state_of(mu_y: np.ndarray, weight: np.ndarray, speed: np.ndarray | None = None) -> np.ndarray:
    """(S,) index into STATES of each agent (see :func:`lateral_extent`); ``speed`` (S,) [m/s] now
    (None: no agent is ``standing``)."""
    state = np.searchsorted(np.asarray(STATE_EDGES), lateral_extent(mu_y, weight), side="right").astype(np.int64)
    if speed is not None:
        state[(state == 0) & (np.asarray(speed, dtype=float) < STAND_SPEED)] = STANDING
    return state


def mahalanobis2(params: np.ndarray, fut: np.ndarray) -> np.ndarray:
    """Squared Mahalanobis distance of true points fut (..., 2) from Gaussians params (..., 5)."""
    mux, muy, sx, sy, rho = np.moveaxis(np.asarray(params, dtype=float), -1, 0)
    dx, dy = (fut[..., 0] - mux) / sx, (fut[..., 1] - muy) / sy
    return (dx**2 + dy**2 - 2 * rho * dx * dy) / (1.0 - rho**2)


@dataclass(frozen=True)
class Calibration:
    """Factors on sigma_x (lon) and sigma_y (lat): scale (N_GROUPS, len(STATES), len(BINS), 2),
    n_points (the same without the last axis: points the cell was fitted on; 0 = fallback), cap
    (N_GROUPS, len(BINS), 2) [m] the largest sigma a factor may raise a spread to (inf: none)."""

    scale: np.ndarray
    n_points: np.ndarray
    weights_sha256: str | None = None
    meta: dict | None = None
    cap: np.ndarray | None = None

    def _interp(self, table: np.ndarray) -> np.ndarray:
        """(..., len(BINS), 2) values at the bin centres -> (..., FUT_STEPS, 2) at the model's steps."""
        t = (np.arange(F.FUT_STEPS) + 1) * F.MODEL_DT
        c = bin_centres()
        flat = table.reshape(-1, len(BINS), 2)
        out = np.empty((len(flat), F.FUT_STEPS, 2))
        for i in range(len(flat)):
            for a in range(2):
                out[i, :, a] = np.interp(t, c, flat[i, :, a])
        return out.reshape(table.shape[:-2] + (F.FUT_STEPS, 2))

    @cached_property
    def _tables(self) -> tuple[np.ndarray, np.ndarray]:
        cap = np.full((F.N_GROUPS, len(BINS), 2), np.inf) if self.cap is None else self.cap
        return self._interp(self.scale), self._interp(cap)

    def per_step(self) -> np.ndarray:
        """(N_GROUPS, len(STATES), FUT_STEPS, 2) factors at the model's steps (0.2 ... 4 s)."""
        return self._tables[0]

    def factors(self, group: np.ndarray, mu_y: np.ndarray, weight: np.ndarray, speed: np.ndarray) -> np.ndarray:
        """(S, FUT_STEPS, 2) factors on (sigma_x, sigma_y) of each agent: group (S,) class group,
        mu_y (S, M, FUT_STEPS) lateral means in its heading frame, weight (S, M), speed (S,) [m/s] now."""
        return self._tables[0][np.asarray(group, dtype=np.int64), state_of(mu_y, weight, speed)]

    def sigmas(self, group: np.ndarray, mu_y: np.ndarray, weight: np.ndarray, speed: np.ndarray,
               sx: np.ndarray, sy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Calibrated (sigma_x, sigma_y), each (S, M, FUT_STEPS) [m], of agents with class ``group``
        (S,), lateral means mu_y (S, M, FUT_STEPS) in their heading frame now, mode weights (S, M)
        and speed (S,) [m/s] now: ``min(c sigma, max(sigma, cap))``."""
        g = np.asarray(group, dtype=np.int64)
        f = self.factors(g, mu_y, weight, speed)[:, None]  # (S, 1, T, 2)
        cap = self._tables[1][g][:, None]
        return (np.minimum(sx * f[..., 0], np.maximum(sx, cap[..., 0])),
                np.minimum(sy * f[..., 1], np.maximum(sy, cap[..., 1])))

    def apply(self, params: np.ndarray, weight: np.ndarray, group: np.ndarray, speed: np.ndarray) -> np.ndarray:
        """Calibrated copy of params (S, M, FUT_STEPS, 5) in each agent's heading frame [m]
        (modes by falling weight, weight (S, M), speed (S,) [m/s] now); means, rho and weights untouched."""
        out = np.array(params, dtype=float, copy=True)
        out[..., 2], out[..., 3] = self.sigmas(group, params[..., 1], weight, speed, out[..., 2], out[..., 3])
        return out

    # ---------------------------------------------------------------- file
    def to_dict(self) -> dict:
        return {
            "format": FORMAT, "version": VERSION,
            "groups": list(F.GROUP_NAMES), "states": list(STATES), "state_edges_m": list(STATE_EDGES),
            "mode_weight_min": MODE_WEIGHT_MIN, "stand_speed_mps": STAND_SPEED, "bins_steps": [list(b) for b in BINS],
            "bin_centres_s": [round(float(v), 6) for v in bin_centres()], "step_s": F.MODEL_DT,
            "scale_lon": np.round(self.scale[..., 0], 4).tolist(), "scale_lat": np.round(self.scale[..., 1], 4).tolist(),
            "n_points": self.n_points.astype(int).tolist(),
            "cap_lon_m": None if self.cap is None else np.round(self.cap[..., 0], 4).tolist(),
            "cap_lat_m": None if self.cap is None else np.round(self.cap[..., 1], 4).tolist(),
            "weights_sha256": self.weights_sha256, "meta": self.meta or {},
        }

    @classmethod
    def from_dict(cls, d: dict) -> "Calibration":
        if d.get("format") != FORMAT or d.get("version") not in (1, VERSION):
            raise ValueError(f"not a version-1 or -{VERSION} {FORMAT} file")
        if d["version"] == 1:  # no ``standing`` cell: standing agents keep the steady factors, as then
            d = {**d, "states": list(STATES), "stand_speed_mps": STAND_SPEED,
                 **{k: [[*rows, rows[0]] for rows in d[k]] for k in ("scale_lon", "scale_lat")},
                 "n_points": [[*rows, [0] * len(rows[0])] for rows in d["n_points"]]}
        if (tuple(d["states"]) != STATES or d.get("stand_speed_mps") != STAND_SPEED or tuple(d["groups"]) != F.GROUP_NAMES
                or tuple(d["state_edges_m"]) != STATE_EDGES or [tuple(b) for b in d["bins_steps"]] != list(BINS)
                or d["mode_weight_min"] != MODE_WEIGHT_MIN):
            raise ValueError("calibration file was written for other states, groups or horizon bins")
        scale = np.stack([np.asarray(d["scale_lon"], dtype=float), np.asarray(d["scale_lat"], dtype=float)], -1)
        if scale.shape != (F.N_GROUPS, len(STATES), len(BINS), 2) or not np.all(np.isfinite(scale) & (scale > 0)):
            raise ValueError(f"calibration factors of shape {scale.shape} or not finite and positive")
        cap = None
        if d.get("cap_lon_m") is not None:
            cap = np.stack([np.asarray(d["cap_lon_m"], dtype=float), np.asarray(d["cap_lat_m"], dtype=float)], -1)
            if cap.shape != (F.N_GROUPS, len(BINS), 2) or not np.all(cap > 0):
                raise ValueError(f"calibration caps of shape {cap.shape} or not positive")
        return cls(scale, np.asarray(d["n_points"], dtype=np.int64), d.get("weights_sha256"), d.get("meta") or {}, cap)

    def write(self, path: Path | str) -> Path:
        path = Path(path)
        path.write_text(json.dumps(self.to_dict(), indent=1, sort_keys=True) + "\n")
        return path

    @classmethod
    def read(cls, path: Path | str) -> "Calibration":
        return cls.from_dict(json.loads(Path(path).read_text()))

    @classmethod
    def identity(cls) -> "Calibration":
        shape = (F.N_GROUPS, len(STATES), len(BINS))
        return cls(np.ones(shape + (2,)), np.zeros(shape, dtype=np.int64))


def calibration_path(weights: Path | str) -> Path:
    """``<dir>/<stem>.calibration.json`` beside a weights file ``<dir>/<stem>.pt``."""
    w = Path(weights)
    return w.with_name(w.stem + ".calibration.json")


def file_sha256(path: Path | str) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def load_for(weights: Path | str) -> Calibration | None:
    """The calibration shipped beside ``weights`` (None: there is none, or it was fitted for other
    weights, which is logged as a warning)."""
    p = calibration_path(weights)
    if not p.is_file():
        return None
    try:
        cal = Calibration.read(p)
    except (ValueError, KeyError, json.JSONDecodeError) as exc:
        log.warning("calibration %s not applied: %s", p, exc)
        return None
    if cal.weights_sha256 is not None and cal.weights_sha256 != file_sha256(weights):
        log.warning("calibration %s was fitted for other weights than %s: not applied", p, weights)
        return None
    return cal


# -------------------------------------------------------------------- fit
def weighted_quantile(x: np.ndarray, w: np.ndarray, q: float) -> float:
    """The smallest x whose cumulative weight (x sorted, ties in input order) reaches q of the total."""
    order = np.argsort(x, kind="stable")
    cum = np.cumsum(np.asarray(w, dtype=float)[order])
    i = min(int(np.searchsorted(cum, q * cum[-1], side="left")), len(x) - 1)
    return float(np.asarray(x)[order][i])


def balanced_weights(group: np.ndarray, manoeuvre: np.ndarray, min_count: int = BALANCE_MIN) -> np.ndarray:
    """(S,) sample weights for :func:`fit`: 1 / max(n, min_count), n the samples of the same class
    group and future manoeuvre label, so every manoeuvre of a group weighs the same in total (one
    with fewer than min_count samples proportionally less)."""
    group = np.asarray(group, dtype=np.int64)
    manoeuvre = np.asarray(manoeuvre, dtype=np.int64)
    out = np.ones(len(group))
    for g in np.unique(group):
        for m in np.unique(manoeuvre[group == g]):
            sel = (group == g) & (manoeuvre == m)
            out[sel] = 1.0 / max(int(sel.sum()), min_count)
    return out


def fit_cell(params: np.ndarray, fut: np.ndarray, w: np.ndarray | None = None,
             level: float = FIT_LEVEL) -> tuple[float, float]:
    """(c_lon, c_lat) for points params (P, 5), fut (P, 2) with weights w (P,) (default equal): the
    2-sigma ellipse then holds a share ``level`` of the weight (see the module docstring); unclipped."""
    w = np.ones(len(fut)) if w is None else np.asarray(w, dtype=float)
    zx = np.abs(fut[:, 0] - params[:, 0]) / params[:, 2]
    zy = np.abs(fut[:, 1] - params[:, 1]) / params[:, 3]
    a = max(weighted_quantile(zx, w, SHAPE_Q) / SHAPE_Z, 1e-6)
    b = max(weighted_quantile(zy, w, SHAPE_Q) / SHAPE_Z, 1e-6)
    shaped = np.array(params, dtype=float, copy=True)
    shaped[:, 2] *= a
    shaped[:, 3] *= b
    lam = np.sqrt(weighted_quantile(mahalanobis2(shaped, fut), w, level) / 4.0)
    return a * lam, b * lam


def fit(params: np.ndarray, weight: np.ndarray, group: np.ndarray, speed: np.ndarray, fut: np.ndarray,
        valid: np.ndarray | None = None, sample_weight: np.ndarray | None = None, level: float = FIT_LEVEL,
        min_points: int = MIN_POINTS, meta: dict | None = None, weights_sha256: str | None = None) -> Calibration:
    """Fit a :class:`Calibration` on held-out samples: params (S, M, FUT_STEPS, 5) in each agent's
    heading frame [m] (modes by falling weight), weight (S, M), group (S,), speed (S,) [m/s] now,
    fut (S, FUT_STEPS, 2) the true positions, valid (S, FUT_STEPS) the observed ones; sample_weight
    (S,) (default equal; the shipped files: :func:`balanced_weights`); level: the weighted share the
    2-sigma ellipse holds."""
    params = np.asarray(params, dtype=float)
    if params.ndim == 3:
        params, weight = params[:, None], np.ones((len(params), 1))
    fut = np.asarray(fut, dtype=float)
    valid = np.ones(fut.shape[:2], dtype=bool) if valid is None else np.asarray(valid, dtype=bool)
    group = np.asarray(group, dtype=np.int64)
    main = params[:, 0]
    sw = np.ones(len(fut)) if sample_weight is None else np.asarray(sample_weight, dtype=float)
    sw = np.broadcast_to(sw[:, None], valid.shape)
    state = state_of(params[..., 1], weight, speed)
    shape = (F.N_GROUPS, len(STATES), len(BINS))
    scale = np.ones(shape + (2,))
    n_points = np.zeros(shape, dtype=np.int64)
    cap = np.full((F.N_GROUPS, len(BINS), 2), np.inf)
    for g in range(F.N_GROUPS):
        for b, (first, last) in enumerate(BINS):
            steps = np.zeros(F.FUT_STEPS, dtype=bool)
            steps[first - 1:last] = True
            sel_g = (group == g)[:, None] & valid & steps[None, :]
            pooled = (1.0, 1.0)
            if sel_g.sum() >= min_points:
                pooled = fit_cell(main[sel_g], fut[sel_g], sw[sel_g], level)
                err = np.abs(fut[sel_g] - main[sel_g][:, :2])
                cap[g, b] = np.maximum(np.quantile(err, CAP_QUANTILE, axis=0), 1e-3)
            for s in range(len(STATES)):
                sel = sel_g & (state == s)[:, None]
                n = int(sel.sum())
                if n >= min_points:
                    scale[g, s, b] = fit_cell(main[sel], fut[sel], sw[sel], level)
                    n_points[g, s, b] = n
                else:
                    scale[g, s, b] = pooled
    scale = np.clip(scale, SCALE_MIN, SCALE_MAX)
    cap = np.where(np.isfinite(cap), np.round(cap, 4), 1e6)
    return Calibration(np.round(scale, 4), n_points, weights_sha256, {"fit_level": level, **(meta or {})}, cap)


# ----------------------------------------------------------------- coverage
#: nominal levels of the coverage curve
LEVELS = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.865, 0.9, 0.95)


def coverage(params: np.ndarray, fut: np.ndarray, valid: np.ndarray | None = None,
             levels: tuple[float, ...] = LEVELS) -> np.ndarray:
    """(len(levels),) share of the valid true points fut (S, T, 2) inside the ellipse of nominal
    mass p of their Gaussians params (S, T, 5) (the k-sigma ellipse with k = ellipse_k(p))."""
    m2 = mahalanobis2(params, fut)
    m2 = m2[np.ones(m2.shape, dtype=bool) if valid is None else np.asarray(valid, dtype=bool)]
    if m2.size == 0:
        return np.full(len(levels), np.nan)
    k2 = ellipse_k(np.asarray(levels)) ** 2
    return (m2[:, None] <= k2[None, :]).mean(axis=0)
