"""Collision probability between candidate ego trajectories and predicted road users.

Two methods (``ProbabilityConfig.method``):

- ``"shapes"`` (the default): the probability that the agent's footprint at its uncertain
  predicted position overlaps the ego's footprint, with both boxes' lengths, widths and
  headings: the Gaussian mass of the agent's centre inside the Minkowski sum of the two
  boxes, exact to 1e-8 (:mod:`sumo_ethics.ethics.shapes`); gated by geometry alone.
- ``"origin"``: Origin's three-point overlap score, below, kept for the faithful baseline.

Origin's fast method (METHOD.md section 1), vectorised over candidates x agents x steps
(K, N, T) and with the ego box integrated in its own rotated frame:

- agent n at step t is three Gaussians N(c_g, Sigma[n, t]) with c_g = mu[n, t] + g * L_n / 2 * h[n, t],
  g in {-1, 0, +1}, h the unit vector of the predicted heading, L_n = length_n + ``length_margin``;
  an all-zero Sigma is replaced by ``zero_cov_var * I``;
- the ego box at step t (centre, yaw of candidate k) is split into three boxes of
  (length / 3) x width at the centre and +/- length / 3 along the yaw;
- P[k, n, t] = 1/3 * sum_g sum_boxes mass(N(c_g, Sigma), box), clipped to [0, 1];
  P = 0 when all three c_g are more than ``gate_radius`` from the ego centre, on candidate
  steps with ``valid`` False and on steps past the prediction horizon.

The three ego boxes tile the full length x width rectangle exactly (they are disjoint and
span [-length/2, length/2]), so the sum over boxes is the Gaussian mass of the whole ego
rectangle: one integral per Gaussian, not three. Each Gaussian's mass is at most 1, so
P <= 1 by construction; the clip only removes rounding. What the formula means: an agent
whose three points all fall inside the ego box gives P = 1; a same-size car sitting on the
ego's centre gives P = 1/3 when crossing it (one point inside) and at most 2/3 when aligned
with it (the points are L / 2 = (length + 1) / 2 apart, so the ego box holds at most two).
P is Origin's overlap score, not a calibrated probability.

The rotated-rectangle mass is integrated, not approximated by an axis-aligned box: the
Gaussian is rotated into the box frame, giving a bivariate normal with correlation rho, and
the rectangle probability is combined from four bivariate-normal orthant probabilities with
Genz's BVNU algorithm (Drezner-Wesolowsky Gauss-Legendre for |rho| < 0.925, Genz's asymptotic
form above). For speed it runs in float32 with fewer nodes than Genz's double-precision
choice and an Abramowitz-Stegun normal CDF; Gaussians more than ``tail_z`` standard deviations
outside (inside) the box along a box axis count as mass 0 (1) without integrating. Error of
a mass: < 3e-6 (tests: against scipy dblquad and 1-D quad references), against METHOD.md's
1e-3 budget.

The other party's width (and METHOD.md's +0.5 m width margin) has no place in the
three-point method: the points lie on the agent's centre line. ``other_width`` enters only
with ``inflate_by_other_width`` (off by default, not Origin's method): the ego box then grows
by the agent's margin-inflated half-width projected on the ego axes.

Speed: the 5 m gate is applied sparsely. Candidates and agents are boxed per block of
``_BLOCK`` steps, only (k, n, block) triples whose boxes come within the gate are expanded to
steps (in chunks of ``_CHUNK`` triples, so that temporaries stay cache-sized), and only the
steps passing the exact three-point gate are integrated. Cost grows with the number of gated
(k, n, t) entries, not with K x N x T.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import cast

import numpy as np
from scipy.special import ndtr

from sumo_ethics.errors import ConfigError, is_number
from sumo_ethics.types import Candidates, Prediction

__all__ = [
    "EthicsConfigError",
    "METHODS",
    "ProbabilityConfig",
    "SparseProbability",
    "collision_probability",
    "sparse_collision_probability",
    "bounded_shapes_terms",
    "shapes_covariances",
    "gate_widths",
    "maximin_ramp",
    "Z_INSIDE",
    "gaussian_box_mass",
    "risk_steps",
]

#: collision probability methods (ProbabilityConfig.method)
METHODS = ("shapes", "origin")
_BLOCK = 8  # horizon steps per block of the coarse gate
_CHUNK = 2048  # coarse (k, n, block) triples per chunk of the exact gate and integration
_TWO_PI = 2.0 * math.pi


class EthicsConfigError(ConfigError, ValueError):
    """A nonsense parameter of an ethics config; a ValueError and the CLI's ConfigError."""


def _check_number(owner: str, name: str, value: object, *, positive: bool = False) -> None:
    if not is_number(value, 0.0, lo_open=positive):
        kind = "a positive" if positive else "a non-negative"
        raise EthicsConfigError(f"{owner}.{name} must be {kind} finite number, got {value!r}")


#: the one threshold of the risk (ProbabilityConfig.p_min; see docs/method.md "One threshold"): a
#: tenth of the planner's max_risk (0.01), inside the peers' 1e-2 to 1e-4
P_MIN = 1e-3
#: Maximin's ramp: 0 at p_min, full at this multiple of it (1e-2 = max_risk)
MAXIMIN_FULL = 10.0
#: Origin's three-point score keeps the threshold it was published with (and a Maximin step there)
ORIGIN_P_MIN = 1e-9
#: the "shapes" P = 1 exit: a mean more than this many standard deviations inside all four slabs
#: of the overlap octagon counts as a certain overlap (P error < 4 Phi(-6) = 4e-9, the integral's own level)
Z_INSIDE = 6.0


@dataclass(frozen=True)
class ProbabilityConfig:
    """Parameters of the collision probability; lengths in m, variances in m^2.

    method: "shapes" (true footprints, the default) or "origin" (Origin's three-point score);
    shape_margin: with "shapes", added to the agent's length and width [m] (0: true sizes);
    p_min: the one threshold of the risk [-]: a step of a road user's mode counts where its share
    of the collision probability (mode weight x P) reaches it, so it decides the "shapes" gate
    (:func:`gate_widths`), the risk terms, the parties Maximin sees and the "at_risk" count; Maximin
    weighs a party's harm by a ramp from 0 at p_min to 1 at ``maximin_full`` x p_min (1: a step at
    p_min). Unset, they are :data:`P_MIN` and :data:`MAXIMIN_FULL` for "shapes"; Origin's score keeps
    its published reading, p_min = 1e-9 with a Maximin step (``origin`` and ``paper`` use it);
    tolerance: with "shapes", the absolute tolerance of each (candidate, road user) risk term and
    harm maximum [-] (0: the exact reference; see :mod:`sumo_ethics.ethics.search`);
    step: with "shapes", P is evaluated at the horizon's first step and then at every multiple of
    ``step`` seconds (0.2: the LSTM predictors' own 5 Hz; see :func:`risk_steps`); 0: every step;
    min_var: the smallest variance along either principal axis of a covariance (floored in its own
    frame, so the floor does not depend on how the scene is turned). The other fields but
    ``zero_cov_var`` are Origin's method's; ``zero_cov_var`` replaces an all-zero covariance in
    Origin's method only ("shapes" floors it like any other: a certain position).
    """

    method: str = "shapes"
    shape_margin: float = 0.0  # [m] "shapes": added to the agent's length and width
    p_min: float | None = None  # [-] the one threshold (None: 1e-3 "shapes", 1e-9 "origin")
    maximin_full: float | None = None  # [-] Maximin's ramp reaches 1 at maximin_full x p_min (None: 10, "origin" 1)
    tolerance: float = 1e-4  # [-] "shapes": absolute tolerance of each risk term (0: exact)
    step: float = 0.2  # [s] "shapes": P at the first step and every step seconds (0: every step)
    length_margin: float = 1.0  # [m] added to the agent's length: Gaussians at +/- (length + margin) / 2
    width_margin: float = 0.5  # [m] added to the agent's width; used only with inflate_by_other_width
    gate_radius: float = 5.0  # [m] P = 0 when all three Gaussian centres are further from the ego centre
    zero_cov_var: float = 0.1  # [m^2] "origin": an all-zero covariance becomes zero_cov_var * I
    min_var: float = 1e-6  # [m^2] floor on the principal variances (singular covariances)
    tail_z: float = 5.0  # [std] Gaussians this far outside / inside the box count as mass 0 / 1 (err < 1.2e-6)
    inflate_by_other_width: bool = False  # grow the ego box by the agent's (width + margin) / 2, projected

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise EthicsConfigError(f"ProbabilityConfig.method must be one of {', '.join(METHODS)}, got {self.method!r}")
        origin = self.method == "origin"
        if self.p_min is None:  # Origin's score keeps what it had, as published
            object.__setattr__(self, "p_min", ORIGIN_P_MIN if origin else P_MIN)
        if self.maximin_full is None:
            object.__setattr__(self, "maximin_full", 1.0 if origin else MAXIMIN_FULL)
        for f in fields(self):
            if f.name == "method":
                continue
            if f.name == "inflate_by_other_width":
                if not isinstance(self.inflate_by_other_width, bool):
                    raise EthicsConfigError(
                        f"ProbabilityConfig.inflate_by_other_width must be a bool, got {self.inflate_by_other_width!r}"
                    )
                continue
            positive = f.name in ("gate_radius", "zero_cov_var", "min_var", "tail_z", "p_min")
            _check_number("ProbabilityConfig", f.name, getattr(self, f.name), positive=positive)
        p_min, full = cast(float, self.p_min), cast(float, self.maximin_full)
        if p_min >= 0.5:
            raise EthicsConfigError(f"ProbabilityConfig.p_min must be below 0.5, got {self.p_min!r}")
        if not (1.0 <= full and full * p_min <= 1.0):
            raise EthicsConfigError("ProbabilityConfig.maximin_full must be at least 1 with maximin_full x p_min <= 1, "
                                    f"got {self.maximin_full!r} (p_min {self.p_min!r})")
        if self.tolerance >= 1.0:
            raise EthicsConfigError(f"ProbabilityConfig.tolerance must be below 1, got {self.tolerance!r}")

    @property
    def threshold(self) -> float:
        """p_min as resolved for the method (a number, never None)."""
        return cast(float, self.p_min)

    @property
    def p_full(self) -> float:
        """The share of P at which Maximin's ramp reaches 1: maximin_full x p_min."""
        return cast(float, self.maximin_full) * cast(float, self.p_min)


def maximin_ramp(share: np.ndarray, p_min: float, p_full: float) -> np.ndarray:
    """Maximin's weight of a party's harm where its mode's share of the collision probability is
    ``share``: 0 up to p_min, linear to 1 at p_full, 1 above; continuous in P, so a party does not
    buy the full Maximin price the moment it crosses the threshold. p_full <= p_min: a step, 1 from
    p_min on."""
    s = np.asarray(share, dtype=float)
    if p_full <= p_min:
        return (s >= p_min).astype(float)
    return np.clip((s - p_min) / (p_full - p_min), 0.0, 1.0)


def gate_widths(p_min: float, weight: np.ndarray) -> np.ndarray:
    """(N,) the "shapes" gate's width per road user [std]: z with Phi(-z) = p_min / weight, so that
    a step cut by the gate (its mean z standard deviations outside the octagon or one of its
    slabs, P < Phi(-z)) has weight x P < p_min and would not count anyway; >= 0."""
    from scipy.special import ndtri

    w = np.asarray(weight, dtype=float)
    ratio = np.clip(p_min / np.maximum(w, 1e-300), 0.0, 0.5)
    return np.maximum(-ndtri(ratio), 0.0)


@dataclass(frozen=True)
class SparseProbability:
    """Non-zero entries of P (K, N, T), sorted by (k, n, t).

    k, n, t: (M,) int indices; p: (M,) in (0, 1]; shape: (K, N, T).
    """

    k: np.ndarray
    n: np.ndarray
    t: np.ndarray
    p: np.ndarray
    shape: tuple[int, int, int]

    @staticmethod
    def none(shape: tuple[int, int, int]) -> "SparseProbability":
        """No entries: P = 0 everywhere in a (K, N, T) array."""
        empty = np.zeros(0, dtype=np.intp)
        return SparseProbability(empty, empty, empty, np.zeros(0), shape)

    def dense(self, values: np.ndarray | None = None) -> np.ndarray:
        """(K, N, T) float array holding ``values`` (default: p) at the entries, 0 elsewhere."""
        out = np.zeros(self.shape)
        out[self.k, self.n, self.t] = self.p if values is None else values
        return out


# ------------------------------------------------------------------ bivariate normal rectangles
# Gauss-Legendre nodes for the Drezner-Wesolowsky integral by |rho| class (upper bounds 0.3,
# 0.75, 0.925; Genz uses 6 / 12 / 20 for double precision). Measured against 40 nodes over
# |h|, |k| <= 7: max error 1e-6, 1.2e-6, 1.9e-6 (3 / 6 / 10 nodes would give 4e-9, 4e-9, 2e-9
# at 1.6x the cost). Genz's |rho| >= 0.925 form: 6 nodes, 5e-11 (rare; float64).
_RHO_CLASSES = ((0.3, 2), (0.75, 4), (0.925, 6))
_HIGH_NODES = 6
_GL = {n: tuple(v.astype(np.float32) for v in np.polynomial.legendre.leggauss(n)) for n in (2, 4, 6)}
_CORNER_SIGN = np.array([1.0, -1.0, -1.0, 1.0], dtype=np.float32)  # U(l1, l2) - U(u1, l2) - U(l1, u2) + U(u1, u2)

# Abramowitz & Stegun 7.1.26: erfc(z) = t (a1 + a2 t + ... + a5 t^4) exp(-z^2), t = 1 / (1 + p z),
# |error| <= 1.5e-7 for z >= 0. About 3x faster than scipy.special.ndtr, plenty for P.
_AS_P = 0.3275911
_AS_A = (0.254829592, -0.284496736, 1.421413741, -1.453152027, 1.061405429)


def _phi(x: np.ndarray) -> np.ndarray:
    """Standard normal CDF, |error| <= 1e-7."""
    z = np.abs(x) * (1.0 / math.sqrt(2.0))
    t = 1.0 / (1.0 + _AS_P * z)
    a1, a2, a3, a4, a5 = _AS_A
    poly = t * (a1 + t * (a2 + t * (a3 + t * (a4 + t * a5))))
    half_erfc = 0.5 * poly * np.exp(-np.minimum(z * z, 60.0))  # clamp: underflowing exp is slow
    return 0.5 + np.copysign(0.5 - half_erfc, x)


def _rect_low_rho(l1, u1, l2, u2, r, x, w) -> np.ndarray:
    """The correlation part of P(l1 < X < u1, l2 < Y < u2), 0 < |r| < 0.925, n-node GL (x, w).

    Upper orthant U(h, k) = Phi(-h) Phi(-k) + 1/(2 pi) int_0^asin r exp(-(h^2 + k^2 - 2 h k sin)/(2 cos^2)):
    the product parts of the four corners combine to the product of the marginal intervals
    (added by the caller); this returns the four integrals, summed with Gauss-Legendre
    (Drezner & Wesolowsky 1990, Genz 2004).
    """
    asr = np.arcsin(r)
    # Layout (corner, node, pair): the long axis last keeps numpy's inner loops long.
    sn = np.sin(((1.0 + x) / 2.0)[:, None] * asr)  # (n, S), float32
    inv = 1.0 / (1.0 - sn * sn)
    a = sn * inv
    h = np.stack([l1, u1, l1, u1])  # (4, S) corners
    k = np.stack([l2, l2, u2, u2])
    e = (h * k)[:, None, :] * a  # (4, n, S)
    e -= (0.5 * (h * h + k * k))[:, None, :] * inv
    np.maximum(e, -60.0, out=e)  # exp(-60) ~ 1e-26; avoids numpy's slow path for underflowing exp
    np.exp(e, out=e)
    return (_CORNER_SIGN @ (w @ e)) * asr * (1.0 / (4.0 * math.pi))


def _bvnu_high(h: np.ndarray, k: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Upper orthant P(X > h, Y > k) for |r| >= 0.925 (Genz 2004: asymptotic series + GL)."""
    x, w = np.polynomial.legendre.leggauss(_HIGH_NODES)
    neg = r < 0.0
    k = np.where(neg, -k, k)
    hk = h * k
    a2 = np.maximum((1.0 - r) * (1.0 + r), 0.0)
    bvn = np.zeros(np.broadcast(h, k, r).shape)
    live = a2 > 0.0  # |r| < 1; at |r| = 1 only the closing terms remain
    if np.any(live):
        hl, hkl, as_ = h[live], hk[live], a2[live]
        kl = k[live]
        a = np.sqrt(as_)
        bs = (hl - kl) ** 2
        c = (4.0 - hkl) / 8.0
        d = (12.0 - hkl) / 80.0
        asr = -(bs / as_ + hkl) / 2.0
        b0 = np.where(
            asr > -100.0,
            a * np.exp(np.maximum(asr, -100.0)) * (1.0 - c * (bs - as_) * (1.0 - d * bs) / 3.0 + c * d * as_ * as_),
            0.0,
        )
        b = np.sqrt(bs)
        # the tail is used only where hkl > -100; elsewhere it may overflow (inf * 0): discarded
        with np.errstate(over="ignore", invalid="ignore"):
            tail = np.exp(-np.minimum(hkl, 200.0) / 2.0) * math.sqrt(_TWO_PI) * ndtr(-b / a) * b
            tail = tail * (1.0 - c * bs * (1.0 - d * bs) / 3.0)
        b0 = b0 - np.where(hkl > -100.0, tail, 0.0)
        ah = a / 2.0
        xs = (ah[:, None] * (1.0 + x)) ** 2  # (S, n)
        asr_i = -(bs[:, None] / xs + hkl[:, None]) / 2.0
        sp = 1.0 + c[:, None] * xs * (1.0 + 5.0 * d[:, None] * xs)
        rs = np.sqrt(1.0 - xs)
        ep = np.exp(-(hkl[:, None] / 2.0) * xs / (1.0 + rs) ** 2) / rs
        terms = np.where(asr_i > -100.0, np.exp(np.maximum(asr_i, -100.0)) * (sp - ep), 0.0)
        bvn[live] = (ah * (terms @ w) - b0) / _TWO_PI
    pos = bvn + ndtr(-np.maximum(h, k))
    lneg = np.where(h < 0.0, ndtr(k) - ndtr(h), ndtr(-h) - ndtr(-k))
    negv = np.where(h >= k, -bvn, lneg - bvn)
    return np.clip(np.where(neg, negv, pos), 0.0, 1.0)


def _rect_mass_std(l1, u1, l2, u2, r) -> np.ndarray:
    """P(l1 < X < u1, l2 < Y < u2), X, Y standard normal with correlation r; flat arrays.

    |error| < 3e-6 (quadrature nodes, CDF approximation, float32).
    """
    out = (_phi(u1) - _phi(l1)) * (_phi(u2) - _phi(l2))
    ar = np.abs(r)
    lower = 0.0
    for upper, n_nodes in _RHO_CLASSES:
        sel = np.flatnonzero(((ar >= lower) if lower else (ar > 0.0)) & (ar < upper))
        lower = upper
        if sel.size:
            x, w = _GL[n_nodes]
            out[sel] += _rect_low_rho(l1[sel], u1[sel], l2[sel], u2[sel], r[sel], x, w)
    sel = np.flatnonzero(ar >= lower)
    if sel.size:
        a, b, c, d, rr = (v[sel].astype(float) for v in (l1, u1, l2, u2, r))
        out[sel] = _bvnu_high(a, c, rr) - _bvnu_high(b, c, rr) - _bvnu_high(a, d, rr) + _bvnu_high(b, d, rr)
    return np.clip(out, 0.0, 1.0)


def _mass_std_units(c1, c2, A, B, r, tail_z: float) -> np.ndarray:
    """Mass in |u1| < A, |u2| < B of bivariate normals with unit variances, correlation r, mean (c1, c2).

    Everything in standard deviations of the respective axis. c1, c2: (G, E), G Gaussians sharing
    the box and covariance of each of E entries; A, B, r: (E,). Returns (G, E). Gaussians
    ``tail_z`` outside the box along an axis give 0, those ``tail_z`` inside along both axes give
    1 (error < 4 Phi(-tail_z)); the rest are integrated.
    """
    E = np.shape(A)[0]
    d1 = np.abs(c1) - A  # > 0: the mean is outside the slab, by d1 std
    d2 = np.abs(c2) - B
    out = np.zeros(np.shape(c1))
    out[(d1 < -tail_z) & (d2 < -tail_z)] = 1.0
    part = np.flatnonzero(((d1 <= tail_z) & (d2 <= tail_z)) & ((d1 >= -tail_z) | (d2 >= -tail_z)))
    if part.size:
        col = part % E
        # float32 from here: twice the SIMD width, half the memory; errors stay ~1e-6.
        c1f, c2f = c1.ravel().take(part).astype(np.float32), c2.ravel().take(part).astype(np.float32)
        Af, Bf = A.take(col).astype(np.float32), B.take(col).astype(np.float32)
        out.ravel()[part] = _rect_mass_std(-Af - c1f, Af - c1f, -Bf - c2f, Bf - c2f, r.take(col).astype(np.float32))
    return out


def _box_frame_mass(m1, m2, v11, v22, v12, a, b, tail_z: float, min_var: float) -> np.ndarray:
    """Mass of N((m1, m2), [[v11, v12], [v12, v22]]) in |u1| < a, |u2| < b; flat arrays (M,).

    Box-frame coordinates [m]; variances [m^2] (floored at ``min_var``).
    """
    inv1 = 1.0 / np.sqrt(np.maximum(v11, min_var))
    inv2 = 1.0 / np.sqrt(np.maximum(v22, min_var))
    r = np.clip(v12 * inv1 * inv2, -1.0, 1.0)
    return _mass_std_units((m1 * inv1)[None], (m2 * inv2)[None], a * inv1, b * inv2, r, tail_z)[0]


def gaussian_box_mass(
    mean: np.ndarray,
    cov: np.ndarray,
    box_xy: np.ndarray,
    box_yaw: np.ndarray,
    box_length: np.ndarray,
    box_width: np.ndarray,
    *,
    tail_z: float = 5.0,
    min_var: float = 1e-6,
) -> np.ndarray:
    """Probability mass of N(mean, cov) inside an oriented rectangle; broadcasts. |error| < 3e-6.

    mean: (..., 2) [m]; cov: (..., 2, 2) [m^2] (symmetric positive semi-definite);
    box_xy: (..., 2) box centre [m]; box_yaw: (...) [rad]; box_length, box_width: (...) full
    extents along / across the yaw [m]. Returns (...) in [0, 1].
    """
    mean = np.asarray(mean, dtype=float)
    cov = np.asarray(cov, dtype=float)
    box_xy = np.asarray(box_xy, dtype=float)
    shape = np.broadcast_shapes(
        mean.shape[:-1], cov.shape[:-2], box_xy.shape[:-1], np.shape(box_yaw), np.shape(box_length), np.shape(box_width)
    )

    def flat(v: np.ndarray) -> np.ndarray:
        return np.broadcast_to(v, shape).ravel()

    c, s = np.cos(flat(box_yaw)), np.sin(flat(box_yaw))
    dx = flat(mean[..., 0] - box_xy[..., 0])
    dy = flat(mean[..., 1] - box_xy[..., 1])
    sxx, sxy, syy = flat(cov[..., 0, 0]), flat(0.5 * (cov[..., 0, 1] + cov[..., 1, 0])), flat(cov[..., 1, 1])
    m1, m2 = c * dx + s * dy, -s * dx + c * dy
    v11, v22, v12 = _rotate_cov(sxx, sxy, syy, c, s)
    a = flat(np.asarray(box_length, dtype=float) / 2.0)
    b = flat(np.asarray(box_width, dtype=float) / 2.0)
    return _box_frame_mass(m1, m2, v11, v22, v12, a, b, tail_z, min_var).reshape(shape)


def _rotate_cov(sxx, sxy, syy, c, s):
    """Covariance entries in a frame rotated by yaw (cos c, sin s): R(-yaw) S R(yaw)."""
    cc, ss, cs = c * c, s * s, c * s
    v11 = cc * sxx + 2.0 * cs * sxy + ss * syy
    v22 = ss * sxx - 2.0 * cs * sxy + cc * syy
    v12 = cs * (syy - sxx) + (cc - ss) * sxy
    return v11, v22, v12


# ------------------------------------------------------------------ (K, N, T) collision probability
def _check_inputs(cand: Candidates, pred: Prediction, other_length, other_width, ego_length, ego_width):
    n = len(pred.ids)
    ol = np.asarray(other_length, dtype=float)
    ow = np.asarray(other_width, dtype=float)
    if ol.shape != (n,) or ow.shape != (n,):
        raise ValueError(f"other_length / other_width must have shape ({n},), got {ol.shape}, {ow.shape}")
    if not (np.all(np.isfinite(ol)) and np.all(ol >= 0) and np.all(np.isfinite(ow)) and np.all(ow >= 0)):
        raise ValueError("other_length / other_width must be finite and non-negative")
    for name, v in (("ego_length", ego_length), ("ego_width", ego_width)):
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be a positive finite number, got {v!r}")
    if np.ndim(pred.mean) != 3 or pred.mean.shape[0] != n or pred.mean.shape[2] != 2:
        raise ValueError(f"Prediction.mean must have shape ({n}, T, 2), got {np.shape(pred.mean)}")
    tp = pred.mean.shape[1]
    if np.shape(pred.cov) != (n, tp, 2, 2) or np.shape(pred.yaw) != (n, tp):
        raise ValueError(f"Prediction.cov / yaw must have shapes ({n}, {tp}, 2, 2) / ({n}, {tp})")
    if n and tp and cand.x.shape[1] and not math.isclose(pred.dt, cand.dt, rel_tol=1e-6):
        raise ValueError(f"Prediction.dt {pred.dt} differs from Candidates.dt {cand.dt}; resample one of them")
    return ol, ow


def sparse_collision_probability(
    cand: Candidates,
    pred: Prediction,
    other_length: np.ndarray,
    other_width: np.ndarray,
    ego_length: float,
    ego_width: float,
    cfg: ProbabilityConfig = ProbabilityConfig(),
) -> SparseProbability:
    """The non-zero entries of :func:`collision_probability`, sorted by (k, n, t)."""
    ol, ow = _check_inputs(cand, pred, other_length, other_width, ego_length, ego_width)
    K, T = cand.x.shape
    N = len(pred.ids)
    tp = min(T, pred.mean.shape[1]) if N else 0
    nothing = SparseProbability.none((K, N, T))
    if K == 0 or N == 0 or tp == 0:
        return nothing
    if cfg.method == "shapes":
        return _shapes(cand, pred, ol, ow, ego_length, ego_width, cfg, tp)

    # ---- agents (N, tp): means, offsets to the end Gaussians, covariances (zero -> zero_cov_var * I)
    mx = np.ascontiguousarray(pred.mean[:, :tp, 0], dtype=float)
    my = np.ascontiguousarray(pred.mean[:, :tp, 1], dtype=float)
    psi = np.asarray(pred.yaw[:, :tp], dtype=float)
    half = (ol + cfg.length_margin) / 2.0
    ox, oy = half[:, None] * np.cos(psi), half[:, None] * np.sin(psi)
    sxx, sxy, syy = _agent_cov(pred, tp, cfg)

    # ---- coarse gate on (K, N, block): boxes around the ego centres and the agents' three points + R
    R = cfg.gate_radius
    nb = -(-tp // _BLOCK)
    pad = nb * _BLOCK - tp
    ex = np.ascontiguousarray(cand.x[:, :tp], dtype=float)
    ey = np.ascontiguousarray(cand.y[:, :tp], dtype=float)
    valid = np.ascontiguousarray(cand.valid[:, :tp], dtype=bool)

    def blocks(v: np.ndarray, reduce: np.ufunc) -> np.ndarray:
        """(rows, nb) min / max of v (rows, tp) over each block of steps (NaN ignored)."""
        if pad:
            v = np.concatenate([v, v[:, -1:].repeat(pad, axis=1)], axis=1)
        out = v[:, 0::_BLOCK].copy()
        for j in range(1, _BLOCK):  # strided slices: numpy is slow at reducing short inner axes
            reduce(out, v[:, j::_BLOCK], out=out)
        return out

    # Invalid steps stay in the ego boxes (conservative; the exact gate drops them).
    ex_lo, ex_hi = blocks(ex, np.fmin), blocks(ex, np.fmax)
    ey_lo, ey_hi = blocks(ey, np.fmin), blocks(ey, np.fmax)
    ax, ay = np.abs(ox), np.abs(oy)
    ax_lo = blocks(mx - ax, np.fmin) - R
    ax_hi = blocks(mx + ax, np.fmax) + R
    ay_lo = blocks(my - ay, np.fmin) - R
    ay_hi = blocks(my + ay, np.fmax) + R
    # near[n, block, k], candidates on the long inner axis (fast broadcasting)
    near = (ex_lo.T <= ax_hi[:, :, None]) & (ex_hi.T >= ax_lo[:, :, None])
    near &= (ey_lo.T <= ay_hi[:, :, None]) & (ey_hi.T >= ay_lo[:, :, None])
    kb, nbk, bb = np.nonzero(near.transpose(2, 0, 1))  # sorted by (k, n, block)
    if kb.size == 0:
        return nothing

    # ---- exact gate and integration, in chunks of coarse blocks (cache blocking: temporaries
    # stay small enough to be reused from the heap instead of page-faulted in afresh)
    yaw = np.asarray(cand.yaw[:, :tp], dtype=np.float32)  # numpy's float64 sin/cos are not vectorised
    flat = _Flat(
        mx=mx.ravel(), my=my.ravel(), ox=ox.ravel(), oy=oy.ravel(), sxx=sxx.ravel(), sxy=sxy.ravel(),
        syy=syy.ravel(), psi=psi.ravel(), ex=ex.ravel(), ey=ey.ravel(), cos=np.cos(yaw).astype(float).ravel(),
        sin=np.sin(yaw).astype(float).ravel(), yaw=np.asarray(cand.yaw[:, :tp], dtype=float).ravel(),
        valid=valid.ravel(), ow=ow, tp=tp,
    )
    parts = [
        _gate_and_integrate(kb[i : i + _CHUNK], nbk[i : i + _CHUNK], bb[i : i + _CHUNK], flat, ego_length, ego_width, cfg)
        for i in range(0, kb.size, _CHUNK)
    ]
    ie = np.concatenate([q[0] for q in parts])
    ia = np.concatenate([q[1] for q in parts])
    p = np.concatenate([q[2] for q in parts])
    return SparseProbability(ie // tp, ia // tp, ia % tp, p, (K, N, T))


def _agent_cov(pred: Prediction, tp: int, cfg: ProbabilityConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(N, tp) sxx, sxy (symmetrised), syy of the agents' covariances; an all-zero one -> zero_cov_var I."""
    cov = np.asarray(pred.cov[:, :tp], dtype=float)
    sxx, syy = cov[..., 0, 0].copy(), cov[..., 1, 1].copy()
    sxy = 0.5 * (cov[..., 0, 1] + cov[..., 1, 0])
    zero = ~np.any(cov.reshape(len(pred.ids), tp, 4), axis=2)
    sxx[zero] = cfg.zero_cov_var
    syy[zero] = cfg.zero_cov_var
    return sxx, sxy, syy


def risk_steps(dt: float, steps: int, step: float) -> np.ndarray:
    """(S,) indices i of the horizon steps (at times (i + 1) dt [s]) the "shapes" P is evaluated
    at: the first, then every one whose time is a multiple of ``step`` [s]. Every step when
    ``step`` is 0, no longer than dt, or not a whole number of steps (e.g. dt = 0.3 s).

    Why 0.2 s: the LSTM predictors predict at 5 Hz and the planner's finer steps interpolate their
    means and covariances linearly, so a finer grid adds no information on the road users (the
    constant-velocity predictor's means are straight lines at any step); the risk is the maximum over the evaluated steps. A collision cannot fall between two of them
    unless the two boxes close by more than their combined length along the closing direction
    in 0.2 s (two cars: 9 m, i.e. 45 m/s closing; a car and a pedestrian crossing its path:
    5 m, 25 m/s), and the envelope test (:func:`sumo_ethics.plan.ethical.first_overlap`) still
    sees every step.
    """
    every = np.arange(steps)
    ratio = step / dt if dt > 0.0 else 0.0
    stride = round(ratio)
    if step <= 0.0 or stride <= 1 or abs(ratio - stride) > 1e-6 * ratio:
        return every
    return every[(every == 0) | ((every + 1) % stride == 0)]


def shapes_covariances(pred: Prediction, dt: float, tp: int,
                       cfg: ProbabilityConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The "shapes" method's inputs: (N, tp) sxx, sxy, syy [m^2] floored in each covariance's own
    principal frame (principal variances >= ``min_var``; an all-zero covariance is a certain
    position, floored like any other) and the (S,) steps P is evaluated at.
    A covariance with a negative principal variance is refused (ValueError): the planner replaces
    such a road user's prediction first (:func:`sumo_ethics.predict.constant_velocity.replace_non_finite`)."""
    from sumo_ethics.geometry import floor_covariance, not_psd

    cov = np.asarray(pred.cov[:, :tp], dtype=float)
    bad = not_psd(cov)
    if bad.any():
        raise ValueError(f"{int(bad.sum())} predicted covariances have a negative principal variance "
                         f"(road users {sorted({pred.ids[i] for i in np.flatnonzero(bad.any(axis=1))})})")
    sxx, sxy, syy = floor_covariance(cov[..., 0, 0], 0.5 * (cov[..., 0, 1] + cov[..., 1, 0]), cov[..., 1, 1],
                                     cfg.min_var)
    return sxx, sxy, syy, risk_steps(dt, tp, cfg.step)


def _shapes(cand: Candidates, pred: Prediction, ol: np.ndarray, ow: np.ndarray, ego_length: float,
            ego_width: float, cfg: ProbabilityConfig, tp: int) -> SparseProbability:
    """The "shapes" method: :func:`sumo_ethics.ethics.shapes.shapes_sparse` on the covariances of
    :func:`shapes_covariances`, every gated step integrated (the exact reference)."""
    from sumo_ethics.ethics.shapes import shapes_sparse

    K, T = cand.x.shape
    N = len(pred.ids)
    sxx, sxy, syy, at = shapes_covariances(pred, cand.dt, tp, cfg)
    k, n, t, p = shapes_sparse(
        cand.x[:, at], cand.y[:, at], cand.yaw[:, at], cand.valid[:, at], pred.mean[:, at, 0],
        pred.mean[:, at, 1], pred.yaw[:, at], sxx[:, at], sxy[:, at], syy[:, at], ol + cfg.shape_margin,
        ow + cfg.shape_margin, ego_length, ego_width, gate_widths(cfg.threshold, np.ones(N)), Z_INSIDE, cfg.threshold,
    )
    return SparseProbability(k.astype(np.intp), n.astype(np.intp), at.take(t).astype(np.intp), p, (K, N, T))


def bounded_shapes_terms(
    cand: Candidates,
    pred: Prediction,
    other_length: np.ndarray,
    other_width: np.ndarray,
    ego_length: float,
    ego_width: float,
    cfg: ProbabilityConfig,
    weight: np.ndarray,
    harm_inputs: tuple,
    need_at_risk: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The "shapes" risk terms of one mode by :mod:`sumo_ethics.ethics.search`'s bounded search,
    to ``cfg.tolerance``: ((4, K, N) weight x max P h_ego, weight x max P h_other, max ramp h_ego,
    max ramp h_other; (4, K, N) their slack, how far above each its exact value may lie; (K, N)
    bool at_risk: some step counts (with a tolerance, settled exactly only with ``need_at_risk``);
    (3,) counts: gated steps, integrals, pairs at risk).

    weight: (N,) the mode's weight per agent (a step counts where weight p >= p_min);
    harm_inputs: (ego speed (K, T) [m/s] >= 0, ego mass [kg], ego vulnerable, agent speed (N, Tp)
    [m/s], agent mass (N,) [kg], agent vulnerable (N,) bool, coefficients (9,)).
    """
    from sumo_ethics.ethics.search import bounded_terms

    if cfg.method != "shapes":
        raise ValueError(f"the bounded search is for the shapes probability, not {cfg.method!r}")
    ol, ow = _check_inputs(cand, pred, other_length, other_width, ego_length, ego_width)
    K, T = cand.x.shape
    N = len(pred.ids)
    tp = min(T, pred.mean.shape[1]) if N else 0
    if K == 0 or N == 0 or tp == 0:
        return np.zeros((4, K, N)), np.zeros((4, K, N)), np.zeros((K, N), bool), np.zeros(3, np.int64)
    ev, ego_mass, ego_vul, av, amass, avul, coeffs = harm_inputs
    sxx, sxy, syy, at = shapes_covariances(pred, cand.dt, tp, cfg)
    return bounded_terms(
        cand.x[:, at], cand.y[:, at], cand.yaw[:, at], ev[:, at], cand.valid[:, at], pred.mean[:, at, 0],
        pred.mean[:, at, 1], pred.yaw[:, at], av[:, at], sxx[:, at], sxy[:, at], syy[:, at], ol + cfg.shape_margin,
        ow + cfg.shape_margin, ego_length, ego_width, gate_widths(cfg.threshold, weight), Z_INSIDE, cfg.threshold, cfg.p_full,
        cfg.tolerance, need_at_risk, weight, ego_mass, ego_vul, amass, avul, coeffs,
    )


@dataclass(frozen=True)
class _Flat:
    """Per-call arrays, raveled: agents (N * tp,), ego (K * tp,); see sparse_collision_probability."""

    mx: np.ndarray
    my: np.ndarray
    ox: np.ndarray
    oy: np.ndarray
    sxx: np.ndarray
    sxy: np.ndarray
    syy: np.ndarray
    psi: np.ndarray
    ex: np.ndarray
    ey: np.ndarray
    cos: np.ndarray
    sin: np.ndarray
    yaw: np.ndarray
    valid: np.ndarray
    ow: np.ndarray
    tp: int


def _gate_and_integrate(kb, nbk, bb, f: _Flat, ego_length: float, ego_width: float, cfg: ProbabilityConfig):
    """Steps of the coarse (k, n, block) triples: exact 5 m gate, then P. Returns flat (k, t), (n, t), p."""
    tp = f.tp
    # Exact gate: some point c_g within R of the ego centre. With d = mean - ego,
    # min over g = +/-1 of |d + g o|^2 = |d|^2 + |o|^2 - 2 |d . o|.
    tt = bb[:, None] * _BLOCK + np.arange(_BLOCK)  # (Q, B), ascending t within a (k, n)
    inside = (tt < tp).ravel()
    tt = np.minimum(tt, tp - 1)
    ia = (nbk[:, None] * tp + tt).ravel()  # flat (n, t)
    ie = (kb[:, None] * tp + tt).ravel()  # flat (k, t)
    dx = f.mx.take(ia) - f.ex.take(ie)
    dy = f.my.take(ia) - f.ey.take(ie)
    oxq, oyq = f.ox.take(ia), f.oy.take(ia)
    d2 = dx * dx + dy * dy
    ends = d2 + (oxq * oxq + oyq * oyq) - 2.0 * np.abs(dx * oxq + dy * oyq)
    R2 = cfg.gate_radius**2
    sel = np.flatnonzero(((d2 <= R2) | (ends <= R2)) & inside & f.valid.take(ie))
    ia, ie = ia.take(sel), ie.take(sel)
    dx, dy, oxe, oye = dx.take(sel), dy.take(sel), oxq.take(sel), oyq.take(sel)

    # Box frame of the ego at (k, t); three Gaussians against the whole ego rectangle (the three
    # ego boxes tile it).
    c, s = f.cos.take(ie), f.sin.take(ie)
    m1, m2 = c * dx + s * dy, c * dy - s * dx
    o1, o2 = c * oxe + s * oye, c * oye - s * oxe
    v11, v22, v12 = _rotate_cov(f.sxx.take(ia), f.sxy.take(ia), f.syy.take(ia), c, s)
    a, b = np.full(ia.shape, ego_length / 2.0), np.full(ia.shape, ego_width / 2.0)
    if cfg.inflate_by_other_width:
        hw = (f.ow.take(ia // tp) + cfg.width_margin) / 2.0
        rel = f.psi.take(ia) - f.yaw.take(ie)
        a = a + hw * np.abs(np.sin(rel))
        b = b + hw * np.abs(np.cos(rel))
    inv1 = 1.0 / np.sqrt(np.maximum(v11, cfg.min_var))
    inv2 = 1.0 / np.sqrt(np.maximum(v22, cfg.min_var))
    r = np.clip(v12 * inv1 * inv2, -1.0, 1.0)
    g = np.array([-1.0, 0.0, 1.0])[:, None]
    mass = _mass_std_units(
        m1 * inv1 + g * (o1 * inv1), m2 * inv2 + g * (o2 * inv2), a * inv1, b * inv2, r, cfg.tail_z
    )  # (3, E)
    p = np.minimum((mass[0] + mass[1] + mass[2]) * (1.0 / 3.0), 1.0)
    keep = np.flatnonzero(p >= cfg.threshold)
    return ie.take(keep), ia.take(keep), p.take(keep)


def collision_probability(
    cand: Candidates,
    pred: Prediction,
    other_length: np.ndarray,
    other_width: np.ndarray,
    ego_length: float,
    ego_width: float,
    cfg: ProbabilityConfig = ProbabilityConfig(),
) -> np.ndarray:
    """P[k, n, t] in [0, 1], shape (K, N, T): ``cfg.method``'s, see the module docstring.

    cand: K candidates over T steps; pred: N agents (same order as other_length / other_width,
    same dt as cand; steps past its horizon give 0); other_length, other_width: (N,) true
    agent sizes [m]; ego_length, ego_width: true ego size [m].
    """
    return sparse_collision_probability(cand, pred, other_length, other_width, ego_length, ego_width, cfg).dense()
