"""The "shapes" risk terms by a bounded search over the horizon steps (numba), to a stated tolerance.

The planner needs, per candidate k and road user n (each mode of its prediction apart, w the
mode's weight), four maxima over the steps t at which a collision counts (w P >= p_min, the one
threshold of :class:`~sumo_ethics.ethics.probability.ProbabilityConfig`):

    w max_t P h_ego,  w max_t P h_other,  max_t r(w P) h_ego,  max_t r(w P) h_other,

(r: Maximin's ramp, 0 up to p_min and 1 from p_full on) and whether any step counts at all (the
"at_risk" normalisation). The exhaustive evaluation (:func:`sumo_ethics.ethics.shapes.shapes_sparse`)
integrates every gated (k, n, t). Here two cheap bounds on P (:func:`_box_bounds`) decide which
steps must be integrated:

- along the agent's principal axes its centre's two coordinates are independent normals, so the
  mass of a box aligned with them is a product of two 1-D masses (four normal CDFs): the
  octagon's bounding box gives an upper bound (median 1.1-1.2 x the exact P on the planner
  benchmark's entries), a box inside the octagon a lower bound.
- Each maximum: the steps in decreasing order of upper bound x harm are integrated until the next
  one's bound x harm is no larger than the best value found plus ``tol``; the bound left (less the
  best) is the term's *slack*, how far the exact maximum may lie above the term (at most tol, 0 in
  the exact mode, tol = 0). A step whose lower bound already puts its share of P at p_full or more
  is not integrated for Maximin (its ramp is 1 whatever P is).
- at_risk: with ``need_at_risk`` a pair none of whose integrated steps counts is settled by
  lower bounds and, failing those, integrals in decreasing order of upper bound.

The gate (cut where w P < p_min), the slabs' quick exits (P = 0 or 1) and the integral of a step are
those of the exhaustive path, the same function on the same numbers. The harm is
:func:`_order_harm`'s: :func:`~sumo_ethics.ethics.harm.crash_outcome`'s model within ``_DH``,
the larger of the two areas' harms on an impact-area boundary. In the exact mode the terms are the
exhaustive path's to rounding (1e-12), in the tolerance mode below them by at most their slack
(tests/ethics/test_search.py, tests/ethics/test_risk_tolerance.py).
"""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np

from sumo_ethics.ethics.shapes import _BLOCK, _entry_p, _gate, _phi_pos, _slab_test
from sumo_ethics.types import kernel_input

__all__ = ["bounded_terms", "order_harm", "p_bounds"]

_jit = numba.njit(cache=True, nogil=True)
_PI = math.pi
_TWO_PI = 2.0 * math.pi
_QUARTER = np.pi / 4  # the impact-area thresholds of sumo_ethics.ethics.harm.impact_area
_THREE_QUARTERS = 3 * np.pi / 4
_DH = 1e-14  # bound on |harm here - harm of sumo_ethics.ethics.harm.crash_outcome| (measured: 2.3e-16)
_DP = 1e-15  # absolute slack on the bounds (the normal CDF table's rounding)
_REL = 1.0 + 1e-12  # covers the rounding of a product of two bounds


@_jit
def _wrap(a: float) -> float:
    """Into (-pi, pi], as sumo_ethics.geometry.wrap_angle (Python's float % is numpy's mod)."""
    w = ((a + _PI) % _TWO_PI) - _PI
    return _PI if w == -_PI else w


@_jit
def _area(rel: float) -> int:
    a = abs(_wrap(rel))
    return 0 if a < _QUARTER else (1 if a <= _THREE_QUARTERS else 2)


@_jit
def _harm(dv: float, area: int, vul_self: bool, vul_other: bool, co) -> float:
    """P(MAIS3+) of a party with delta-v dv [m/s] hit in ``area`` (sumo_ethics.ethics.harm's
    models; co: ``HarmCoefficients.as_array()``), the logistic as 1 / (1 + exp(-z)): the same
    function as harm.py's 0.5 (1 + tanh(z / 2)), within a few ulp of it (for ordering only)."""
    if vul_self:
        z = co[8] * dv - co[7]
    elif vul_other:
        z = co[6] * dv - co[5]
    else:
        z = co[0] + co[1] * dv + co[2 + area]
    return 1.0 / (1.0 + math.exp(-z))


@_jit
def _areas_of(fwd: float, lat: float, dx: float, dy: float, yaw: float):
    """The impact area of a party from the other's offset in its frame (fwd, lat): front where
    fwd > |lat|, rear where -fwd > |lat|, else side, as (area, area): within 1e-9 of the front/side
    or side/rear boundary both areas the boundary separates, since numpy's arctan2 (SIMD on some
    processors) and libm's can put an offset exactly on it on either side (crash_outcome decides
    by the bearing); at a zero offset the area of the bearing atan2(0, 0) - yaw, as there."""
    af, al = abs(fwd), abs(lat)
    if af == 0.0 and al == 0.0:
        a = _area(math.atan2(dy, dx) - yaw)
        return a, a
    if abs(af - al) <= 1e-9 * (af + al):
        return (0, 1) if fwd > 0.0 else (1, 2)
    if al >= af:
        return 1, 1
    return (0, 0) if fwd > 0.0 else (2, 2)


@_jit
def _order_harm(dx, dy, ce, se, ca, sa, yawe, yawo, ve, vo, fe, fo, vul_e, vul_o, co):
    """(ego harm low, high, other harm low, high) of a collision: :func:`sumo_ethics.ethics.harm.crash_outcome`'s
    model for the other at offset (dx, dy) [m] from the ego, headings as cos/sin (and the angles,
    for a zero offset), speeds ve, vo [m/s] >= 0, delta-v shares fe = m_o / (m_e + m_o),
    fo = m_e / (m_e + m_o), vul: vulnerable. Low and high differ only on an impact-area boundary
    (:func:`_areas_of`); crash_outcome's harm lies within ``_DH`` of [low, high]. cos(pdof) =
    -cos(yaw_o - yaw_e) from the cosines and sines (no trigonometry per step)."""
    cpd = -(ca * ce + sa * se)
    dv = math.sqrt(max(0.0, ve * ve + vo * vo + 2.0 * ve * vo * cpd))
    e1, e2 = _areas_of(dx * ce + dy * se, dy * ce - dx * se, dx, dy, yawe)
    o1, o2 = _areas_of(-(dx * ca + dy * sa), -(dy * ca - dx * sa), -dx, -dy, yawo)
    he1 = _harm(fe * dv, e1, vul_e, vul_o, co)
    he2 = he1 if e2 == e1 else _harm(fe * dv, e2, vul_e, vul_o, co)
    ho1 = _harm(fo * dv, o1, vul_o, vul_e, co)
    ho2 = ho1 if o2 == o1 else _harm(fo * dv, o2, vul_o, vul_e, co)
    return min(he1, he2), max(he1, he2), min(ho1, ho2), max(ho1, ho2)


@_jit
def _phi(x: float) -> float:
    return _phi_pos(x) if x >= 0.0 else 1.0 - _phi_pos(-x)


@_jit
def _axis_mass(c: float, h: float, sig: float) -> float:
    """Mass of N(0, sig^2) in [c - h, c + h]."""
    return _phi((c + h) / sig) - _phi((c - h) / sig)


@_jit
def _principal(sxx, sxy, syy, oa, ob, ca, sa):
    """The agent's principal axes, u1 = (c, s) and u2 = (-s, c), the standard deviations along
    them [m] and the half-extents of its box (half-sizes oa, ob, heading cos ca, sin sa) along
    them [m]: (c, s, sig1, sig2, ext1, ext2)."""
    th = 0.5 * math.atan2(2.0 * sxy, sxx - syy)
    c, s = math.cos(th), math.sin(th)
    sig1 = math.sqrt(max(c * c * sxx + 2.0 * c * s * sxy + s * s * syy, 1e-300))
    sig2 = math.sqrt(max(s * s * sxx - 2.0 * c * s * sxy + c * c * syy, 1e-300))
    ext1 = oa * abs(c * ca + s * sa) + ob * abs(s * ca - c * sa)
    ext2 = oa * abs(c * sa - s * ca) + ob * abs(c * ca + s * sa)
    return c, s, sig1, sig2, ext1, ext2


@_jit
def _box_bounds(dx, dy, c1, s1, ca, sa, ea, eb, oa, ob, c, s, sig1, sig2, ext1, ext2):
    """(upper, lower) bound on P for the agent's mean at (dx, dy) [m] from the ego centre, ego
    heading (c1, s1), agent heading (ca, sa), half-sizes, and the agent's :func:`_principal`.

    Along the principal axes the two coordinates of the agent's centre are independent normals,
    so its mass in a box aligned with them is a product of two 1-D masses. The octagon lies in
    the box of half-extents (h1, h2), the two boxes' supports along the axes added: the upper
    bound. The box lam (h1, h2) with lam the largest scale that keeps it inside all four slabs of
    the octagon (the boxes' sides: a box is inside a slab when its support along the slab's
    normal is at most the slab's half-width) lies in the octagon: the lower bound."""
    return _upper(dx, dy, c1, s1, ea, eb, c, s, sig1, sig2, ext1, ext2), \
        _lower(dx, dy, c1, s1, ca, sa, ea, eb, oa, ob, c, s, sig1, sig2, ext1, ext2)


@_jit
def _upper(dx, dy, c1, s1, ea, eb, c, s, sig1, sig2, ext1, ext2) -> float:
    """The upper bound of :func:`_box_bounds`."""
    h1 = ea * abs(c * c1 + s * s1) + eb * abs(s * c1 - c * s1) + ext1
    h2 = ea * abs(c * s1 - s * c1) + eb * abs(c * c1 + s * s1) + ext2
    return _axis_mass(dx * c + dy * s, h1, sig1) * _axis_mass(dy * c - dx * s, h2, sig2)


@_jit
def _lower(dx, dy, c1, s1, ca, sa, ea, eb, oa, ob, c, s, sig1, sig2, ext1, ext2) -> float:
    """The lower bound of :func:`_box_bounds`."""
    h1 = ea * abs(c * c1 + s * s1) + eb * abs(s * c1 - c * s1) + ext1
    h2 = ea * abs(c * s1 - s * c1) + eb * abs(c * c1 + s * s1) + ext2
    m1 = dx * c + dy * s
    m2 = dy * c - dx * s
    cr = c1 * ca + s1 * sa
    sr = c1 * sa - s1 * ca
    acr, asr = abs(cr), abs(sr)
    lam = 1.0
    for i in range(4):  # slab normals: the ego's axes, then the agent's
        if i == 0:
            nx, ny, wd = c1, s1, ea + oa * acr + ob * asr
        elif i == 1:
            nx, ny, wd = -s1, c1, eb + oa * asr + ob * acr
        elif i == 2:
            nx, ny, wd = ca, sa, oa + ea * acr + eb * asr
        else:
            nx, ny, wd = -sa, ca, ob + ea * asr + eb * acr
        d = h1 * abs(nx * c + ny * s) + h2 * abs(ny * c - nx * s)
        if d > 0.0:
            lam = min(lam, wd / d)
    return _axis_mass(m1, lam * h1, sig1) * _axis_mass(m2, lam * h2, sig2)


@_jit
def _order_harm_many(xa, ya, yawa, va, ma, vula, xb, yb, yawb, vb, mb, vulb, co):
    n = len(xa)
    out = np.empty((4, n))
    for i in range(n):
        ce, se, ca, sa = math.cos(yawa[i]), math.sin(yawa[i]), math.cos(yawb[i]), math.sin(yawb[i])
        out[0, i], out[1, i], out[2, i], out[3, i] = _order_harm(
            xb[i] - xa[i], yb[i] - ya[i], ce, se, ca, sa, yawa[i], yawb[i], va[i], vb[i], mb[i] / (ma[i] + mb[i]),
            ma[i] / (ma[i] + mb[i]), vula[i], vulb[i], co)
    return out


def order_harm(a, b, coeffs) -> np.ndarray:
    """(4, M) the search's harm intervals (a low, a high, b low, b high) for parties a and b
    (:class:`~sumo_ethics.ethics.harm.Party` of (M,) arrays each; speeds >= 0) under ``coeffs``
    (HarmCoefficients): :func:`~sumo_ethics.ethics.harm.crash_outcome`'s harm_a, harm_b lie
    within ``_DH`` of them (tests/ethics/test_search.py)."""
    from sumo_ethics.types import VULNERABLE

    m = np.broadcast_shapes(np.shape(a.x), np.shape(b.x))

    def arr(v, dtype=float):
        return np.ascontiguousarray(np.broadcast_to(np.asarray(v, dtype=dtype), m))

    vula = arr(VULNERABLE[np.asarray(a.cls, dtype=np.intp)], bool)
    vulb = arr(VULNERABLE[np.asarray(b.cls, dtype=np.intp)], bool)
    return _order_harm_many(arr(a.x), arr(a.y), arr(a.yaw), arr(a.speed), arr(a.mass), vula, arr(b.x), arr(b.y),
                            arr(b.yaw), arr(b.speed), arr(b.mass), vulb, coeffs.as_array())


def p_bounds(dx: float, dy: float, ego_yaw: float, other_yaw: float, ego_length: float, ego_width: float,
             other_length: float, other_width: float, cov: np.ndarray) -> tuple[float, float]:
    """(lower, upper) bound on the shapes P of an agent whose mean is (dx, dy) [m] from the ego
    centre, headings [rad], full sizes [m], covariance (2, 2) [m^2], as the search uses them."""
    ca, sa = math.cos(other_yaw), math.sin(other_yaw)
    oa, ob = other_length / 2.0, other_width / 2.0
    pr = _principal(float(cov[0, 0]), 0.5 * float(cov[0, 1] + cov[1, 0]), float(cov[1, 1]), oa, ob, ca, sa)
    up, low = _box_bounds(dx, dy, math.cos(ego_yaw), math.sin(ego_yaw), ca, sa, ego_length / 2.0, ego_width / 2.0,
                          oa, ob, *pr)
    return float(low), float(up)


@_jit
def _member(p: float, w: float, p_min: float) -> bool:
    return p >= p_min and w * p >= p_min


@_jit
def _ramp(share: float, p_min: float, p_full: float) -> float:
    """Maximin's weight of a party whose mode's share of the collision probability is ``share``:
    0 below p_min, rising linearly to 1 at p_full, 1 above (continuous in P); p_full <= p_min: a
    step, 1 from p_min on (:func:`sumo_ethics.ethics.probability.maximin_ramp`)."""
    if p_full <= p_min:
        return 1.0 if share >= p_min else 0.0
    if share <= p_min:
        return 0.0
    if share >= p_full:
        return 1.0
    return (share - p_min) / (p_full - p_min)


@_jit
def _pop_max(key, g: int) -> int:
    """The index of the largest of key[:g] (ties: the first), -1 if all are below 0 (taken)."""
    j = -1
    top = -0.5
    for i in range(g):
        if key[i] > top:
            top = key[i]
            j = i
    return j


@_jit
def _search_kernel(ex, ey, eyaw, ev, evalid, mx, my, psi, av, sxx, sxy, syy, oa, ob, ea, eb, z, z_in, p_min, p_full,
                   tol, need_at_risk, w, ego_mass, ego_vul, amass, avul, co):
    K, T = ex.shape
    N, tp = mx.shape
    ce = np.full((K, tp), np.nan)
    se = np.empty((K, tp))
    nb, afin, arad, ebox, abox = _gate(ex, ey, evalid, mx, my, psi, sxx, sxy, syy, oa, ob, ea, eb, z)
    # the agents' principal axes (cos, sin of the first), standard deviations along them, and the
    # agent box's half-extent along each: the box bound's per-(n, t) parts
    pc = np.empty((N, tp))
    ps = np.empty((N, tp))
    sg1 = np.empty((N, tp))
    sg2 = np.empty((N, tp))
    ho1 = np.empty((N, tp))
    ho2 = np.empty((N, tp))
    ca = np.cos(psi)
    sa = np.sin(psi)
    for n in range(N):
        for t in range(tp):
            if afin[n, t]:
                pc[n, t], ps[n, t], sg1[n, t], sg2[n, t], ho1[n, t], ho2[n, t] = _principal(
                    sxx[n, t], sxy[n, t], syy[n, t], oa[n], ob[n], ca[n, t], sa[n, t])
    fe = np.empty(N)  # delta-v shares of the ego and agent n (momentum split)
    fo = np.empty(N)
    for n in range(N):
        fe[n] = amass[n] / (ego_mass + amass[n])
        fo[n] = ego_mass / (ego_mass + amass[n])
    buf = np.empty((4, 8))
    cot = (co[0], co[1], co[2], co[3], co[4], co[5], co[6], co[7], co[8])  # by value: no reference counting per call
    # per (k, n): the gated steps, their bounds on P (lower: -1 not yet computed), exact P (-1: not
    # integrated), the harms of the ego and the other, search keys
    gt = np.empty(tp, dtype=np.int64)
    ub = np.empty(tp)
    lb = np.empty(tp)
    full = np.empty(tp, dtype=np.bool_)  # its share of P is at least p_full by its lower bound (not integrated)
    px = np.empty(tp)
    hv = np.empty((2, tp))
    key = np.empty(tp)
    terms = np.zeros((4, K, N))  # max P h_ego, max P h_other (times w), max ramp h_ego, max ramp h_other
    slack = np.zeros((4, K, N))  # how far above its term each maximum may lie (the bound left when the search stopped)
    at_risk = np.zeros((K, N), dtype=np.bool_)
    counts = np.zeros(3, dtype=np.int64)  # gated steps that can count, integrals, (k, n) pairs at risk
    for k in range(K):
        for n in range(N):
            g = int(0)  # (not a literal 0: that would compile a second _pop_max)
            wn = w[n]
            for b in range(nb):
                if (ebox[k, b, 0] > abox[n, b, 1] or ebox[k, b, 1] < abox[n, b, 0]  # shapes._apart, written out
                        or ebox[k, b, 2] > abox[n, b, 3] or ebox[k, b, 3] < abox[n, b, 2]):
                    continue
                for t in range(b * _BLOCK, min((b + 1) * _BLOCK, tp)):
                    # the gate (shapes._near, written out: a call with array arguments costs more than the test)
                    if not (evalid[k, t] and afin[n, t]):
                        continue
                    dx = mx[n, t] - ex[k, t]
                    dy = my[n, t] - ey[k, t]
                    if dx * dx + dy * dy > arad[n, t] * arad[n, t]:
                        continue
                    if math.isnan(ce[k, t]):
                        ce[k, t] = math.cos(eyaw[k, t])
                        se[k, t] = math.sin(eyaw[k, t])
                    c1, s1 = ce[k, t], se[k, t]
                    q = _slab_test(dx, dy, c1, s1, ea, eb, ca[n, t], sa[n, t], oa[n], ob[n], sxx[n, t], sxy[n, t],
                                   syy[n, t], z[n], z_in)[0]
                    if q == 0:  # w P < p_min: never counts
                        continue
                    gt[g] = t
                    lb[g] = -1.0
                    if q == 1:  # P = 1 exactly, as _entry_p gives it
                        px[g], ub[g], lb[g] = 1.0, 1.0, 1.0
                    else:
                        up = _upper(dx, dy, c1, s1, ea, eb, pc[n, t], ps[n, t], sg1[n, t], sg2[n, t], ho1[n, t],
                                    ho2[n, t])
                        px[g], ub[g] = -1.0, min(up * _REL + _DP, 1.0)
                    if not _member(ub[g], wn, p_min):  # cannot count
                        continue
                    # the harms (at an impact-area boundary, the larger of the two areas')
                    _, hv[0, g], _, hv[1, g] = _order_harm(dx, dy, c1, s1, ca[n, t], sa[n, t], eyaw[k, t],
                                                           psi[n, t], ev[k, t], av[n, t], fe[n], fo[n], ego_vul,
                                                           avul[n], cot)
                    full[g] = False
                    g += 1
            if g == 0:
                continue
            counts[0] += g
            found = False
            # four searches sharing one integration, each over the steps by decreasing upper bound
            # of its value until the next cannot beat the best found by more than tol: phases 0, 1
            # the maxima of P x harm of the ego and the other (steps where the share w P reaches
            # p_min), phases 2, 3 those of ramp(w P) x harm (Maximin's harms)
            for phase in range(4):
                h = hv[phase % 2]
                risk = phase < 2
                for i in range(g):
                    if risk:
                        key[i] = ub[i] * h[i]
                    else:
                        key[i] = (1.0 if full[i] else _ramp(wn * ub[i], p_min, p_full)) * h[i]
                best = 0.0  # the largest value found
                left = 0.0  # the largest bound not searched
                while True:
                    j = _pop_max(key, g)
                    if j < 0:
                        break
                    if key[j] <= best + tol:
                        left = key[j]
                        break
                    key[j] = -1.0
                    if px[j] < 0.0:
                        t = gt[j]
                        if not risk and not full[j]:
                            if lb[j] < 0.0:
                                lb[j] = _lower(mx[n, t] - ex[k, t], my[n, t] - ey[k, t], ce[k, t], se[k, t],
                                               ca[n, t], sa[n, t], ea, eb, oa[n], ob[n], pc[n, t], ps[n, t],
                                               sg1[n, t], sg2[n, t], ho1[n, t], ho2[n, t]) / _REL - _DP
                            full[j] = wn * lb[j] >= p_full
                        if not risk and full[j]:  # ramp 1 whatever its P: no integral needed
                            found = True
                            best = max(best, h[j])
                            continue
                        counts[1] += 1
                        px[j] = _entry_p(mx[n, t] - ex[k, t], my[n, t] - ey[k, t], ce[k, t], se[k, t], ea, eb,
                                         ca[n, t], sa[n, t], oa[n], ob[n], sxx[n, t], sxy[n, t], syy[n, t], z[n],
                                         z_in, buf)
                    if _member(px[j], wn, p_min):
                        found = True
                        value = px[j] if risk else _ramp(wn * px[j], p_min, p_full)
                        best = max(best, value * h[j])
                terms[phase, k, n] = wn * best if risk else best
                slack[phase, k, n] = (wn if risk else 1.0) * max(left - best, 0.0)
            if need_at_risk and not found:  # does any step count? by decreasing upper bound
                for i in range(g):
                    key[i] = ub[i]
                while not found:
                    j = _pop_max(key, g)
                    if j < 0:
                        break
                    key[j] = -1.0
                    if px[j] < 0.0:
                        t = gt[j]
                        if lb[j] < 0.0:
                            lb[j] = _lower(mx[n, t] - ex[k, t], my[n, t] - ey[k, t], ce[k, t], se[k, t], ca[n, t],
                                           sa[n, t], ea, eb, oa[n], ob[n], pc[n, t], ps[n, t], sg1[n, t], sg2[n, t],
                                           ho1[n, t], ho2[n, t]) / _REL - _DP
                        if _member(lb[j], wn, p_min):
                            found = True
                            break
                        counts[1] += 1
                        px[j] = _entry_p(mx[n, t] - ex[k, t], my[n, t] - ey[k, t], ce[k, t], se[k, t], ea, eb,
                                         ca[n, t], sa[n, t], oa[n], ob[n], sxx[n, t], sxy[n, t], syy[n, t], z[n],
                                         z_in, buf)
                    found = _member(px[j], wn, p_min)
            if found:
                at_risk[k, n] = True
                counts[2] += 1
    return terms, slack, at_risk, counts


def bounded_terms(ex, ey, eyaw, ev, evalid, mx, my, psi, av, sxx, sxy, syy, other_length, other_width,
                  ego_length: float, ego_width: float, z, z_in: float, p_min: float, p_full: float, tol: float,
                  need_at_risk: bool, weight, ego_mass: float, ego_vulnerable: bool, other_mass, other_vulnerable,
                  coeffs: np.ndarray):
    """The risk terms of one mode: ((4, K, N) weight x max_t P h_ego, weight x max_t P h_other,
    max_t ramp(weight P) h_ego, max_t ramp(weight P) h_other, each to ``tol``; (4, K, N) their
    slack: how far above each term its exact value may lie, at most ``tol`` (the largest bound the
    search left unexamined, less the term; 0 where it examined every step); (K, N) bool
    ``at_risk``: some step counts (with tol > 0 settled exactly only with ``need_at_risk``); (3,)
    counts: gated steps that can count, integrals, pairs at risk).

    ex, ey, eyaw, ev: (K, T) ego centre [m], heading [rad], speed [m/s] (>= 0); evalid: (K, T);
    mx, my, psi, av: (N, Tp) the agents' mean centre [m], heading [rad], speed [m/s]; sxx, sxy,
    syy: (N, Tp) covariance [m^2] (floored by the caller); other_length, other_width: (N,) [m];
    z, z_in, p_min: as :func:`sumo_ethics.ethics.shapes.shapes_sparse` (z (N,)); p_full: the share
    of P at which Maximin's ramp reaches 1; tol: absolute tolerance of each maximum (0: exact);
    weight: (N,) the mode's weight per agent (ones for one mode): a step counts where
    weight P >= p_min; ego_mass [kg]; other_mass: (N,); ego_vulnerable, other_vulnerable: (N,) bool;
    coeffs: ``HarmCoefficients.as_array()``.

    The candidates are split into spans over :func:`sumo_ethics.cores.threads` threads and put
    back in order: the same bytes with any number of threads.
    """
    from sumo_ethics import cores

    f = kernel_input  # one argument type, whatever the caller passes: one compile
    e = [f(ex, dtype=float), f(ey, dtype=float), f(eyaw, dtype=float), f(ev, dtype=float), f(evalid, dtype=np.bool_)]
    rest = (f(mx, dtype=float), f(my, dtype=float), f(psi, dtype=float), f(av, dtype=float), f(sxx, dtype=float),
            f(sxy, dtype=float), f(syy, dtype=float), f(np.asarray(other_length, dtype=float) / 2.0),
            f(np.asarray(other_width, dtype=float) / 2.0), float(ego_length) / 2.0, float(ego_width) / 2.0,
            f(np.broadcast_to(np.asarray(z, dtype=float), (np.shape(mx)[0],))), float(z_in), float(p_min),
            float(p_full), float(tol), bool(need_at_risk), f(weight, dtype=float), float(ego_mass),
            bool(ego_vulnerable), f(other_mass, dtype=float), f(other_vulnerable, dtype=np.bool_),
            f(coeffs, dtype=float))
    kernel: Any = _search_kernel  # a numba dispatcher
    n_threads = cores.threads()
    parts = cores.spans(len(e[0]), 1 if n_threads == 1 else 4 * n_threads)
    if len(parts) <= 1:
        return kernel(*e, *rest)
    outs = cores.map_ordered(kernel, [tuple(a[lo:hi] for a in e) + rest for lo, hi in parts])
    return (np.concatenate([o[0] for o in outs], axis=1), np.concatenate([o[1] for o in outs], axis=1),
            np.concatenate([o[2] for o in outs]), np.sum([o[3] for o in outs], axis=0))
