"""Collision probability over true shapes, and the envelope test, as numba kernels over (k, n, t).

Two boxes overlap exactly when the other's centre lies in the Minkowski sum of the ego box
and the other box (both centred at the origin; a rectangle is its own reflection). For two
rectangles that sum is a centrally symmetric octagon (a rectangle when they are aligned).
With the other's centre uncertain, N(mu, Sigma), and its heading as predicted,

    P[k, n, t] = mass of N(mu[n, t] - ego[k, t], Sigma[n, t]) inside octagon(ego box, box n),

which is 1 for a certain overlap, 0 for a certain separation, and uses both parties'
lengths, widths and headings (METHOD.md "Collision probability over true shapes").

The mass of a Gaussian inside a convex polygon: whiten the Gaussian (the octagon stays a
convex polygon), then add the signed standard-normal masses of the triangles (mean, v_i,
v_i+1). A triangle is split at the foot of the perpendicular from the mean onto its edge
line; the mass of (mean, foot, foot + t u) at distance h is
``atan(t / h) / (2 pi) - T(h, t / h)`` with Owen's T function, read here from a bicubic Hermite
table after reducing to a <= 1 (error < 2e-9 against scipy's ``owens_t``; 9x faster than 6-node
Gauss-Legendre, which it replaced); the
triangles' angle parts add up to 1 inside the polygon and 0 outside, and an edge further
than 8.3 standard units adds nothing else (error < 1e-16). Quick exits, per entry: the octagon is the intersection of four slabs
(the two boxes' axes, the separating-axis theorem); a mean more than ``z`` standard
deviations outside any slab has P < Phi(-z) and is taken as 0, one more than ``z_in`` inside
all four gives P = 1 (bound 4 Phi(-z_in); z_in = 6: 4e-9). ``z`` comes from the risk's one
threshold (:func:`sumo_ethics.ethics.probability.gate_widths`: Phi(-z) = p_min / mode weight), so
a step taken as 0 could not count. Error of a P that counts: below 4e-8 + 4 Phi(-z_in) = 5e-8.

The geometric gate decides which (k, n, t) are integrated at all: the ego's and the agent's
half-diagonals plus ``z`` times the agent's largest standard deviation, first per block of
steps on bounding boxes, then per step on distances. Nothing is cut by an earlier
probability. Kernels run single-threaded with plain IEEE arithmetic: same inputs, same bytes.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from sumo_ethics.types import kernel_input

__all__ = ["shapes_sparse", "envelope_first_hit", "polygon_mass", "octagon"]

_TWO_PI = 2.0 * math.pi
_H_FAR = 8.3  # standard units: T(h, a) < Phi(-h) / 2 < 1e-16 beyond
_SQRT1_2 = 1.0 / math.sqrt(2.0)
_BLOCK = 8  # horizon steps per block of the coarse gate
_NH, _NA = 256, 48  # cells of the Owen's T table over h in [0, 8.3], a in [0, 1]


def _owen_table(nh: int, na: int) -> np.ndarray:
    """(nh + 1, na + 1, 4) Owen's T on the grid h = i 8.3 / nh, a = j / na with its derivatives
    dT/dh = -phi(h) (Phi(ah) - 1/2), dT/da = exp(-h^2 (1 + a^2) / 2) / (2 pi (1 + a^2)) and
    d2T/dh da = -h phi(h) phi(ah), each scaled to one cell: the nodes of a bicubic Hermite
    interpolation. T from 40-node Gauss-Legendre (error < 1e-15 on the grid)."""
    dh, da = _H_FAR / nh, 1.0 / na
    h = (np.arange(nh + 1) * dh)[:, None]
    a = (np.arange(na + 1) * da)[None, :]
    gx, gw = np.polynomial.legendre.leggauss(40)
    x = (gx + 1.0) * 0.5 * a[..., None]  # (1, na + 1, 40)
    q = 1.0 + x * x
    t = (gw * np.exp(-0.5 * (h * h)[..., None] * q) / q).sum(axis=-1) * a * 0.5 / _TWO_PI
    pdf = np.exp(-0.5 * h * h) / math.sqrt(_TWO_PI)
    pdf_ah = np.exp(-0.5 * (a * h) ** 2) / math.sqrt(_TWO_PI)
    half_erf = 0.5 * np.vectorize(math.erf)(a * h * _SQRT1_2)  # Phi(ah) - 1/2
    return np.ascontiguousarray(np.stack([
        t, -pdf * half_erf * dh, np.exp(-0.5 * h * h * (1.0 + a * a)) / (_TWO_PI * (1.0 + a * a)) * da,
        -h * pdf * pdf_ah * dh * da], axis=-1))


_OWEN = _owen_table(_NH, _NA)  # global arrays are constants to numba (394 kB)
_NP = 2048  # cells of the normal-CDF table over [0, 8.3]
_PHI_DX = _H_FAR / _NP
_PHI_TAB = np.ascontiguousarray(np.stack([
    0.5 * np.vectorize(math.erfc)(-np.arange(_NP + 1) * _PHI_DX * _SQRT1_2),
    np.exp(-0.5 * (np.arange(_NP + 1) * _PHI_DX) ** 2) / math.sqrt(_TWO_PI) * _PHI_DX], axis=-1))

_jit = numba.njit(cache=True, nogil=True)


@_jit
def _phi_pos(x: float) -> float:
    """Phi(x) for x >= 0: cubic Hermite interpolation of a table (error < 1e-12); 1 from 8.3 on
    (1 - Phi(8.3) < 6e-17)."""
    if x >= _H_FAR:
        return 1.0
    y = x * (_NP / _H_FAR)
    i = min(int(y), _NP - 1)
    u = y - i
    u2 = u * u
    c0, c1 = _PHI_TAB[i], _PHI_TAB[i + 1]
    return ((2.0 * u - 3.0) * u2 + 1.0) * c0[0] + ((u - 2.0) * u2 + u) * c0[1] + (3.0 - 2.0 * u) * u2 * c1[0] \
        + (u - 1.0) * u2 * c1[1]


@_jit
def _owen_base(h: float, a: float) -> float:
    """Owen's T(h, a) for 0 <= h <= 8.3, 0 <= a <= 1: bicubic Hermite interpolation of the table
    (error < 2e-9 against scipy's ``owens_t`` on 200,000 random points, tests/ethics/test_shapes.py)."""
    x = h * (_NH / _H_FAR)
    y = a * _NA
    i = min(int(x), _NH - 1)
    j = min(int(y), _NA - 1)
    u = x - i
    v = y - j
    u2, v2 = u * u, v * v
    b0u, b1u = (2.0 * u - 3.0) * u2 + 1.0, (3.0 - 2.0 * u) * u2  # value bases at the cell's two ends
    d0u, d1u = (u - 2.0) * u2 + u, (u - 1.0) * u2  # slope bases
    b0v, b1v = (2.0 * v - 3.0) * v2 + 1.0, (3.0 - 2.0 * v) * v2
    d0v, d1v = (v - 2.0) * v2 + v, (v - 1.0) * v2
    c00, c01, c10, c11 = _OWEN[i, j], _OWEN[i, j + 1], _OWEN[i + 1, j], _OWEN[i + 1, j + 1]
    return (b0v * (b0u * c00[0] + d0u * c00[1] + b1u * c10[0] + d1u * c10[1])
            + d0v * (b0u * c00[2] + d0u * c00[3] + b1u * c10[2] + d1u * c10[3])
            + b1v * (b0u * c01[0] + d0u * c01[1] + b1u * c11[0] + d1u * c11[1])
            + d1v * (b0u * c01[2] + d0u * c01[3] + b1u * c11[2] + d1u * c11[3]))


@_jit
def _owens_t(h: float, a: float, ph: float) -> float:
    """Owen's T(h, a), 0 <= h < 8.3, a >= 0, given ph = Phi(h); above a = 1 by
    T(h, a) + T(ah, 1/a) = (Phi(h) + Phi(ah)) / 2 - Phi(h) Phi(ah) (T(ah, 1/a) < 1e-16 for ah >= 8.3)."""
    if a <= 1.0:
        return _owen_base(h, a)
    ah = a * h
    pah = _phi_pos(ah)
    rest = _owen_base(ah, 1.0 / a) if ah < _H_FAR else 0.0
    return 0.5 * ph + 0.5 * pah - ph * pah - rest


@_jit
def _edge(wx, wy, i: int):
    """Edge i -> i + 1 of the polygon wx, wy as seen from the origin: (length, the origin's signed
    distance inside the edge's line (the polygon counter-clockwise), the along-edge position of
    vertex i measured from the foot of the perpendicular); length < 1e-13: a degenerate edge."""
    j = i + 1 if i + 1 < len(wx) else 0
    ex = wx[j] - wx[i]
    ey = wy[j] - wy[i]
    ln = math.sqrt(ex * ex + ey * ey)
    if ln < 1e-13:
        return ln, 0.0, 0.0
    ux = ex / ln
    uy = ey / ln
    return ln, wx[i] * uy - wy[i] * ux, wx[i] * ux + wy[i] * uy


@_jit
def _angle_sum(wx, wy) -> float:
    """Sum over the polygon's edges (skipping those whose line holds the origin) of the signed
    angle each subtends at the origin [rad]: 2 pi inside, 0 outside, between on the boundary."""
    nv = len(wx)
    angle = 0.0
    for i in range(nv):
        ln, h, ta = _edge(wx, wy, i)
        if ln < 1e-13 or abs(h) < 1e-12:
            continue
        d = math.atan2(ta + ln, abs(h)) - math.atan2(ta, abs(h))
        angle += d if h > 0.0 else -d
    return angle


@_jit
def _poly_mass(vx, vy, wx, wy, mx: float, my: float, sxx: float, sxy: float, syy: float) -> float:
    """Mass of N((mx, my), [[sxx, sxy], [sxy, syy]]) inside the convex polygon vx, vy (CCW);
    wx, wy: scratch arrays of the same length.

    Whitened, the polygon's triangles (mean, v_i, v_i+1) split at the foot of the perpendicular
    (distance h, along-edge positions ta < tb) have masses sign(h) [G(tb) - G(ta)], G(t) =
    sign(t) (atan(|t| / h) / (2 pi) - T(h, |t| / h)); the angle parts add up to the winding number
    (1 inside, 0 outside), so P = [inside] - sum_edges sign(h) [sign(tb) T(h, |tb|/h) - sign(ta) T(h, |ta|/h)],
    and an edge further than 8.3 standard units adds nothing.
    """
    l11 = math.sqrt(sxx)
    l21 = sxy / l11
    l22 = math.sqrt(max(syy - l21 * l21, 1e-12 * syy))
    nv = len(vx)
    for i in range(nv):  # whitened vertices: L^-1 (v - m); det L > 0 keeps them CCW
        z1 = (vx[i] - mx) / l11
        wx[i] = z1
        wy[i] = ((vy[i] - my) - l21 * z1) / l22
    inside = True
    on_line = False  # the mean on an edge's line: the winding number is ambiguous there
    total = 0.0
    for i in range(nv):
        ln, h, ta = _edge(wx, wy, i)
        if ln < 1e-13:
            continue
        ah = abs(h)
        if ah < 1e-12:  # a degenerate triangle (mean, v_i, v_i+1): no mass
            on_line = True
            continue
        if h < 0.0:
            inside = False
        tb = ta + ln
        sh = 1.0 if h > 0.0 else -1.0
        if ah >= _H_FAR:
            continue
        ph = _phi_pos(ah)
        gb = _owens_t(ah, abs(tb) / ah, ph)
        ga = _owens_t(ah, abs(ta) / ah, ph)
        total += sh * ((gb if tb >= 0.0 else -gb) - (ga if ta >= 0.0 else -ga))
    if on_line:  # the triangles' angle parts, summed, instead of the winding number
        p = _angle_sum(wx, wy) / _TWO_PI - total
        return min(max(p, 0.0), 1.0)
    p = (1.0 if inside else 0.0) - total
    return min(max(p, 0.0), 1.0)


@_jit
def _octagon(ea: float, eb: float, oa: float, ob: float, cr: float, sr: float, vx, vy) -> None:
    """Vertices (CCW, into vx, vy (8,)) of the Minkowski sum of the box |x| <= ea, |y| <= eb and
    the box of half-sizes oa, ob turned by the angle of cosine cr, sine sr, in the first box's frame."""
    if cr < 0.0:  # a box turned by pi is the same box
        cr, sr = -cr, -sr
    if sr < 0.0:  # a box turned by pi/2 is the box with its sides swapped
        cr, sr = -sr, cr
        oa, ob = ob, oa
    ux, uy = oa * cr, oa * sr
    px, py = -ob * sr, ob * cr
    # edges by direction: ego 0, other r, ego pi/2, other r + pi/2; then the mirror image
    x0, y0 = -ea - ux - px, -eb - uy - py
    x1, y1 = x0 + 2.0 * ea, y0
    x2, y2 = x1 + 2.0 * ux, y1 + 2.0 * uy
    x3, y3 = x2, y2 + 2.0 * eb
    vx[0], vy[0], vx[1], vy[1], vx[2], vy[2], vx[3], vy[3] = x0, y0, x1, y1, x2, y2, x3, y3
    vx[4], vy[4], vx[5], vy[5], vx[6], vy[6], vx[7], vy[7] = -x0, -y0, -x1, -y1, -x2, -y2, -x3, -y3


@_jit
def _slab_test(dx, dy, ce, se, ea, eb, ca, sa, oa, ob, sxx, sxy, syy, z, z_in):
    """The quick exits of one (k, n, t): world offset (dx, dy) of the agent's mean from the ego
    centre, ego heading (cos ce, sin se), agent heading (ca, sa), half-sizes, the agent's
    covariance (world); a mean more than ``z`` standard deviations outside a slab has P < Phi(-z),
    one more than ``z_in`` inside all four P > 1 - 4 Phi(-z_in). Returns (0: P below Phi(-z),
    taken as 0; 1: P taken as 1; 2: neither; the mean m1, m2 and covariance v11, v12, v22 in the
    ego frame; cos, sin of the agent's heading relative to the ego's)."""
    m1 = ce * dx + se * dy  # ego frame
    m2 = ce * dy - se * dx
    cc, ss, cs = ce * ce, se * se, ce * se
    v11 = cc * sxx + 2.0 * cs * sxy + ss * syy
    v22 = ss * sxx - 2.0 * cs * sxy + cc * syy
    v12 = cs * (syy - sxx) + (cc - ss) * sxy
    cr = ce * ca + se * sa  # the agent's heading relative to the ego's
    sr = ce * sa - se * ca
    acr, asr = abs(cr), abs(sr)
    # four slabs of the octagon: normals (1, 0), (0, 1), (cr, sr), (-sr, cr); half-widths
    inside_all = True
    for i in range(4):
        if i == 0:
            nx, ny, w = 1.0, 0.0, ea + oa * acr + ob * asr
        elif i == 1:
            nx, ny, w = 0.0, 1.0, eb + oa * asr + ob * acr
        elif i == 2:
            nx, ny, w = cr, sr, oa + ea * acr + eb * asr
        else:
            nx, ny, w = -sr, cr, ob + ea * asr + eb * acr
        sig = math.sqrt(nx * nx * v11 + 2.0 * nx * ny * v12 + ny * ny * v22)
        d = abs(nx * m1 + ny * m2) - w
        if d > z * sig:
            return 0, m1, m2, v11, v12, v22, cr, sr
        if d > -z_in * sig:
            inside_all = False
    return (1 if inside_all else 2), m1, m2, v11, v12, v22, cr, sr


@_jit
def _entry_p(dx, dy, ce, se, ea, eb, ca, sa, oa, ob, sxx, sxy, syy, z, z_in, buf) -> float:
    """P for one (k, n, t), the arguments as :func:`_slab_test`'s; buf: (4, 8) scratch."""
    code, m1, m2, v11, v12, v22, cr, sr = _slab_test(dx, dy, ce, se, ea, eb, ca, sa, oa, ob, sxx, sxy, syy, z, z_in)
    if code == 0:
        return 0.0
    if code == 1:
        return 1.0
    _octagon(ea, eb, oa, ob, cr, sr, buf[0], buf[1])
    return _poly_mass(buf[0], buf[1], buf[2], buf[3], m1, m2, v11, v12, v22)


@_jit
def _block_boxes(x, y, valid, rad, nb: int, tp: int):
    """(rows, nb, 4) xmin, xmax, ymin, ymax over each block of steps of the valid points grown by rad."""
    rows = x.shape[0]
    out = np.empty((rows, nb, 4))
    for r in range(rows):
        for b in range(nb):
            x0, x1, y0, y1 = np.inf, -np.inf, np.inf, -np.inf
            for t in range(b * _BLOCK, min((b + 1) * _BLOCK, tp)):
                if not valid[r, t]:
                    continue
                rr = rad[r, t]
                x0 = min(x0, x[r, t] - rr)
                x1 = max(x1, x[r, t] + rr)
                y0 = min(y0, y[r, t] - rr)
                y1 = max(y1, y[r, t] + rr)
            out[r, b, 0] = x0
            out[r, b, 1] = x1
            out[r, b, 2] = y0
            out[r, b, 3] = y1
    return out


@_jit
def _gate(ex, ey, evalid, mx, my, psi, sxx, sxy, syy, oa, ob, ea, eb, z):
    """The geometric gate's parts: (blocks of steps, (N, tp) agent step finite, (N, tp) gate radius
    (both half-diagonals + z[n] sqrt(sxx + syy)) [m], (K, nb, 4) and (N, nb, 4) block boxes);
    z: (N,) gate widths [std] >= 0."""
    K = ex.shape[0]
    N, tp = mx.shape
    nb = (tp + _BLOCK - 1) // _BLOCK
    r_e = math.sqrt(ea * ea + eb * eb)
    arad = np.empty((N, tp))
    afin = np.empty((N, tp), dtype=np.bool_)
    for n in range(N):
        r_o = math.sqrt(oa[n] * oa[n] + ob[n] * ob[n])
        for t in range(tp):
            s2 = sxx[n, t] + syy[n, t]  # >= the largest variance
            ok = (math.isfinite(mx[n, t]) and math.isfinite(my[n, t]) and math.isfinite(psi[n, t])
                  and math.isfinite(s2) and math.isfinite(sxy[n, t]))
            afin[n, t] = ok
            arad[n, t] = r_e + r_o + z[n] * math.sqrt(s2) if ok else 0.0
    zero = np.zeros((K, tp))
    # evalid (read-only, from the caller) copied: _block_boxes compiled once, for afin's type
    return nb, afin, arad, _block_boxes(ex, ey, evalid.copy(), zero, nb, tp), _block_boxes(mx, my, afin, arad, nb, tp)


@_jit
def _apart(ebox, abox, k: int, n: int, b: int) -> bool:
    """Candidate k's and agent n's boxes of block b do not meet."""
    return (ebox[k, b, 0] > abox[n, b, 1] or ebox[k, b, 1] < abox[n, b, 0]
            or ebox[k, b, 2] > abox[n, b, 3] or ebox[k, b, 3] < abox[n, b, 2])


@_jit
def _near(k: int, n: int, t: int, ex, ey, eyaw, evalid, mx, my, afin, arad, ce, se):
    """(step t of candidate k and agent n passes the gate, the agent's mean offset dx, dy [m] from
    the ego centre); fills the cache ce, se (cos, sin of the ego's heading, NaN: not yet) there."""
    if not (evalid[k, t] and afin[n, t]):
        return False, 0.0, 0.0
    dx = mx[n, t] - ex[k, t]
    dy = my[n, t] - ey[k, t]
    if dx * dx + dy * dy > arad[n, t] * arad[n, t]:
        return False, dx, dy
    if math.isnan(ce[k, t]):
        ce[k, t] = math.cos(eyaw[k, t])
        se[k, t] = math.sin(eyaw[k, t])
    return True, dx, dy


@_jit
def _shapes_kernel(ex, ey, eyaw, evalid, mx, my, psi, sxx, sxy, syy, oa, ob, ea, eb, z, z_in, p_min):
    K, T = ex.shape
    N, tp = mx.shape
    ce = np.full((K, tp), np.nan)  # cos, sin of the ego's heading, filled on first use (trig is slow)
    se = np.empty((K, tp))
    nb, afin, arad, ebox, abox = _gate(ex, ey, evalid, mx, my, psi, sxx, sxy, syy, oa, ob, ea, eb, z)
    ok_, on_, ot_, op_ = _entry_buffers(1024)
    m = 0
    ca = np.cos(psi)
    sa = np.sin(psi)
    buf = np.empty((4, 8))
    for k in range(K):
        for n in range(N):
            for b in range(nb):
                if _apart(ebox, abox, k, n, b):
                    continue
                for t in range(b * _BLOCK, min((b + 1) * _BLOCK, tp)):
                    near, dx, dy = _near(k, n, t, ex, ey, eyaw, evalid, mx, my, afin, arad, ce, se)
                    if not near:
                        continue
                    p = _entry_p(dx, dy, ce[k, t], se[k, t], ea, eb, ca[n, t], sa[n, t], oa[n], ob[n],
                                 sxx[n, t], sxy[n, t], syy[n, t], z[n], z_in, buf)
                    if p < p_min:
                        continue
                    ok_, on_, ot_, op_ = _push(ok_, on_, ot_, op_, m, k, n, t, p)
                    m += 1
    return ok_[:m].copy(), on_[:m].copy(), ot_[:m].copy(), op_[:m].copy()


@_jit
def _entry_buffers(cap: int):
    """Empty (k, n, t, p) buffers for ``cap`` entries (see :func:`_push`)."""
    return (np.empty(cap, dtype=np.int32), np.empty(cap, dtype=np.int32), np.empty(cap, dtype=np.int32),
            np.empty(cap))


@_jit
def _push(ok_, on_, ot_, op_, m: int, k: int, n: int, t: int, p: float):
    """Entry m = (k, n, t, p) into the buffers, doubled first when full; the buffers."""
    if m == len(ok_):
        cap = 2 * len(ok_)
        ok_, on_, ot_, op_ = _grow_i(ok_, cap), _grow_i(on_, cap), _grow_i(ot_, cap), _grow_f(op_, cap)
    ok_[m] = k
    on_[m] = n
    ot_[m] = t
    op_[m] = p
    return ok_, on_, ot_, op_


@_jit
def _grow_i(a, cap):
    out = np.empty(cap, dtype=a.dtype)
    out[: len(a)] = a
    return out


@_jit
def _grow_f(a, cap):
    out = np.empty(cap)
    out[: len(a)] = a
    return out


def shapes_sparse(ex, ey, eyaw, evalid, mx, my, psi, sxx, sxy, syy, other_length, other_width,
                  ego_length: float, ego_width: float, z, z_in: float, p_min: float):
    """Non-zero P entries (k, n, t, p), sorted by (k, n, t).

    ex, ey, eyaw: (K, T) ego centre [m] and heading [rad] per candidate step; evalid: (K, T)
    bool; mx, my, psi: (N, Tp) the agents' mean centre and heading (Tp <= T); sxx, sxy, syy:
    (N, Tp) covariance [m^2] (positive definite: the caller floors it); other_length,
    other_width: (N,) full sizes [m]; ego_length, ego_width [m]; z: the gate's and the P = 0 exit's
    width [std], a number or (N,) per agent (:func:`sumo_ethics.ethics.probability.gate_widths`);
    z_in: the P = 1 exit's [std]; p_min: smaller P are dropped. Non-finite agent steps give no entries.
    """
    f = np.ascontiguousarray
    return _shapes_kernel(
        f(ex, dtype=float), f(ey, dtype=float), f(eyaw, dtype=float), f(evalid, dtype=np.bool_),
        f(mx, dtype=float), f(my, dtype=float), f(psi, dtype=float), f(sxx, dtype=float), f(sxy, dtype=float),
        f(syy, dtype=float), f(np.asarray(other_length, dtype=float) / 2.0), f(np.asarray(other_width, dtype=float) / 2.0),
        float(ego_length) / 2.0, float(ego_width) / 2.0,
        f(np.broadcast_to(np.asarray(z, dtype=float), (np.shape(mx)[0],))), float(z_in), float(p_min),
    )


@_jit
def _sat(dx, dy, c1, s1, a1, b1, c2, s2, a2, b2) -> bool:
    """Whether two oriented boxes overlap (separating-axis theorem); d = centre 2 - centre 1."""
    cr = c1 * c2 + s1 * s2  # cos, sin of the relative heading
    sr = c1 * s2 - s1 * c2
    acr, asr = abs(cr), abs(sr)
    if abs(c1 * dx + s1 * dy) > a1 + a2 * acr + b2 * asr:
        return False
    if abs(c1 * dy - s1 * dx) > b1 + a2 * asr + b2 * acr:
        return False
    if abs(c2 * dx + s2 * dy) > a2 + a1 * acr + b1 * asr:
        return False
    if abs(c2 * dy - s2 * dx) > b2 + a1 * asr + b1 * acr:
        return False
    return True


@_jit
def _envelope_kernel(ex, ey, eyaw, ev, evalid, mx, my, psi, oa, ob, ea, eb, brake):
    K, T = ex.shape
    N, tp = mx.shape
    first = np.full(K, T, dtype=np.int64)
    tp = min(tp, T)
    # per (k, t): the heading and the stretched box (half-length, centre, half-diagonal), once
    c1s = np.empty((K, tp))
    s1s = np.empty((K, tp))
    a1s = np.empty((K, tp))
    cxs = np.empty((K, tp))
    cys = np.empty((K, tp))
    r1s = np.empty((K, tp))
    for k in range(K):
        for t in range(tp):
            c1 = math.cos(eyaw[k, t])
            s1 = math.sin(eyaw[k, t])
            ext = ev[k, t] * ev[k, t] / (2.0 * brake) if brake > 0.0 else 0.0
            a1 = ea + 0.5 * ext
            c1s[k, t], s1s[k, t], a1s[k, t] = c1, s1, a1
            cxs[k, t] = ex[k, t] + 0.5 * ext * c1
            cys[k, t] = ey[k, t] + 0.5 * ext * s1
            r1s[k, t] = math.sqrt(a1 * a1 + eb * eb)
    c2s = np.cos(psi)
    s2s = np.sin(psi)
    fin = np.empty((N, tp), dtype=np.bool_)
    for n in range(N):
        for t in range(tp):
            fin[n, t] = math.isfinite(mx[n, t]) and math.isfinite(my[n, t]) and math.isfinite(psi[n, t])
    for k in range(K):
        for n in range(N):
            r_o = math.sqrt(oa[n] * oa[n] + ob[n] * ob[n])
            for t in range(min(tp, first[k])):
                if not evalid[k, t] or not fin[n, t]:
                    continue
                dx = mx[n, t] - cxs[k, t]
                dy = my[n, t] - cys[k, t]
                rr = r1s[k, t] + r_o
                if dx * dx + dy * dy > rr * rr:
                    continue
                if _sat(dx, dy, c1s[k, t], s1s[k, t], a1s[k, t], eb, c2s[n, t], s2s[n, t], oa[n], ob[n]):
                    first[k] = t
                    break
    return first


def envelope_first_hit(ex, ey, eyaw, ev, evalid, mx, my, psi, length, width, ego_length: float,
                       ego_width: float, brake: float | None) -> np.ndarray:
    """(K,) the first step at which the ego box (stretched forward by its stopping distance
    v^2 / (2 brake) when ``brake`` is given) meets an agent's box at its mean (T if never).

    ex, ey, eyaw, ev: (K, T) ego centre [m], heading [rad], speed [m/s]; evalid: (K, T);
    mx, my, psi: (N, Tp) the agents' mean centre and heading; length, width: (N,) [m].
    Gated by distance alone (half-diagonals of both boxes, the stretch included).
    """
    f = kernel_input  # one argument type, whatever the caller passes: one compile
    return _envelope_kernel(
        f(ex), f(ey), f(eyaw), f(np.abs(ev)), f(evalid, dtype=np.bool_), f(mx), f(my), f(psi),
        f(np.asarray(length, dtype=float) / 2.0), f(np.asarray(width, dtype=float) / 2.0),
        float(ego_length) / 2.0, float(ego_width) / 2.0, float(brake) if brake else 0.0,
    )


def octagon(ego_length: float, ego_width: float, other_length: float, other_width: float, rel: float) -> np.ndarray:
    """(8, 2) vertices (CCW) of the region of the other's centre where the two boxes overlap, in
    the ego frame; ``rel`` the other's heading minus the ego's [rad]."""
    vx, vy = np.empty(8), np.empty(8)
    _octagon(ego_length / 2.0, ego_width / 2.0, other_length / 2.0, other_width / 2.0, math.cos(rel), math.sin(rel),
             vx, vy)
    return np.stack([vx, vy], axis=1)


def polygon_mass(vertices: np.ndarray, mean: np.ndarray, cov: np.ndarray) -> float:
    """Mass of N(mean, cov) inside the convex polygon ``vertices`` (V, 2), counter-clockwise."""
    v = np.asarray(vertices, dtype=float)
    c = np.asarray(cov, dtype=float)
    return float(_poly_mass(np.ascontiguousarray(v[:, 0]), np.ascontiguousarray(v[:, 1]), np.empty(len(v)),
                            np.empty(len(v)), float(mean[0]),
                            float(mean[1]), float(c[0, 0]), float(0.5 * (c[0, 1] + c[1, 0])), float(c[1, 1])))
