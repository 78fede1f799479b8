"""Reflectance matching: the common normal of a pair and the paper's residuals E', E'' and Delta z (Eqs 32-34, 43).

See ``docs/stereo-matching.md`` for every definition.
"""

from __future__ import annotations

import numpy as np

from ._base import _dot_c, _unit_c
from .rays import _normal_at_c, _Side, _take

__all__ = []


class _Bundle:
    """Rays ``idx`` of one side, gathered once as components (the residuals iterate on them)."""

    def __init__(self, side: _Side, idx=None, parts=None):
        if parts is not None:
            self.o, self.d, self.S, self.far = parts
        else:
            self.o, self.d, self.S = _take(side.oc, idx), _take(side.dc, idx), _take(side.Sc, idx)
            self.far = side.distant[idx]
        self.anyfar = bool(self.far.any())

    def sub(self, k):
        return _Bundle(None, parts=(_take(self.o, k), _take(self.d, k), _take(self.S, k), self.far[k]))


def _normal_and_rate(b: _Bundle, t):
    """``n(t)`` and ``dn/dt`` (per mm) along the rays of ``b`` (0 for a distant source), as components."""
    o, d, S = b.o, b.d, b.S
    rv = [S[k] - (o[k] + t * d[k]) for k in range(3)]
    r = np.sqrt(_dot_c(rv, rv))
    pos = r > 0
    den = np.where(pos, r, 1.0)
    l = [rv[k] / den for k in range(3)]
    if b.anyfar:
        l = [np.where(b.far, S[k], l[k]) for k in range(3)]
    dd = _dot_c(d, l)
    rinf = np.where(pos, r, np.inf)
    dl = [-(d[k] - dd * l[k]) / rinf for k in range(3)]
    if b.anyfar:
        dl = [np.where(b.far, 0.0, dl[k]) for k in range(3)]
    m = [l[k] - d[k] for k in range(3)]
    mn = np.sqrt(_dot_c(m, m))
    # mn = 0 where the point lies on the line from the camera through the source (a step of the
    # solve that overshoots): no normal there; NaN, which _nearest_t does not step onto
    with np.errstate(divide="ignore", invalid="ignore"):
        n = [m[k] / mn for k in range(3)]
        ndl = _dot_c(n, dl)
        dn = [(dl[k] - ndl * n[k]) / mn for k in range(3)]
    return n, dn


def _nearest_t(b: _Bundle, t, nstar, steps, tol_mm=None):
    """Gauss-Newton on ``|n(t) - n*|^2`` along each ray, from ``t``; with ``tol_mm``, a ray stops once its
    step is no longer (each ray's result then depends on that ray alone)."""
    moving = None
    for _ in range(steps):
        n, dn = _normal_and_rate(b, t)
        g2 = _dot_c(dn, dn)
        with np.errstate(divide="ignore", invalid="ignore"):
            num = _dot_c([nstar[k] - n[k] for k in range(3)], dn)
            step = np.where(g2 > 0, num / g2, 0.0)
        step = np.where(np.isfinite(step), step, 0.0)
        if tol_mm is None:
            t = t + step
            continue
        t = t + (step if moving is None else np.where(moving, step, 0.0))
        moving = np.abs(step) > tol_mm if moving is None else moving & (np.abs(step) > tol_mm)
        if not moving.any():
            break
    return t


def _reflectance(s1, s2, i, j, t1, t2):
    """Common normal n*, E1, E2 and delta_z (``docs/stereo-matching.md``), vectorised.

    A joint Newton step on (lambda, g1, g2) per pair solves the three conditions at once: each ``g``
    the nearest point of its ray to ``n*(lambda)`` (Gauss-Newton's normal equation) and ``E1 = E2``.
    The pairs it leaves unsettled, or settles outside the arc (no root between the two normals), go to
    :func:`_reflectance_bracketed`, which brackets the root on the arc or takes the better end."""
    b1, b2 = _Bundle(s1, i), _Bundle(s2, j)
    n1 = _normal_at_c(s1, i, [b1.o[k] + t1 * b1.d[k] for k in range(3)])
    n2 = _normal_at_c(s2, j, [b2.o[k] + t2 * b2.d[k] for k in range(3)])
    m = len(i)
    lam, g1, g2 = np.full(m, 0.5), t1.copy(), t2.copy()
    settled = np.zeros(m, bool)
    act = np.arange(m)
    r1, r2, c1, dN = b1, b2, n1, [n2[k] - n1[k] for k in range(3)]
    gn = np.sqrt(_dot_c(dN, dN))
    # a step that runs away (overflow, NaN) marks its pair not good: the bracketed solve below takes it
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for _ in range(_NEWTON_STEPS):
            la, u1, u2 = lam[act], g1[act], g2[act]
            v = [c1[k] + la * dN[k] for k in range(3)]
            vn = np.sqrt(_dot_c(v, v))
            ns = [v[k] / vn for k in range(3)]
            nd = _dot_c(ns, dN)
            dns = [(dN[k] - nd * ns[k]) / vn for k in range(3)]
            h1, dh1 = _normal_and_rate(r1, u1)
            h2, dh2 = _normal_and_rate(r2, u2)
            a1 = _dot_c(dh1, dh1)
            a2 = _dot_c(dh2, dh2)
            p1 = _dot_c([h1[k] - ns[k] for k in range(3)], dh1)
            p2 = _dot_c([h2[k] - ns[k] for k in range(3)], dh2)
            q1 = _dot_c(dh1, dns) / a1
            q2 = _dot_c(dh2, dns) / a2
            f = (t1[act] - u1) - (t2[act] - u2)
            dl = (p2 / a2 - p1 / a1 - f) / (q2 - q1)
            d1 = q1 * dl - p1 / a1
            d2 = q2 * dl - p2 / a2
            good = np.isfinite(dl) & np.isfinite(d1) & np.isfinite(d2)
            lam[act] = np.where(good, la + dl, np.nan)
            g1[act] = np.where(good, u1 + d1, u1)
            g2[act] = np.where(good, u2 + d2, u2)
            # settled: n* moves by under 1e-13 rad and each element by under 1e-11 mm along its ray
            ok = good & (np.abs(dl) * gn[act] <= 1e-13) & (np.abs(d1) <= 1e-11) & (np.abs(d2) <= 1e-11)
            settled[act[ok]] = True
            keep = good & ~ok
            act = act[keep]
            if not act.size:
                break
            r1, r2 = r1.sub(keep), r2.sub(keep)
            c1, dN = [c[keep] for c in c1], [c[keep] for c in dN]
    inside = settled & (lam >= 0.0) & (lam <= 1.0)
    nstar = np.stack(_unit_c([n1[k] + lam * (n2[k] - n1[k]) for k in range(3)]), 1)
    e1, e2 = t1 - g1, t2 - g2
    # settled outside the arc: no root between the two normals; the end with the smaller |E1 - E2|
    out = np.flatnonzero(settled & ~inside)
    if out.size:
        o1, o2, u1, u2 = b1.sub(out), b2.sub(out), t1[out], t2[out]
        ends = []
        for c in (n1, n2):
            ce = [v[out] for v in c]
            h1 = _nearest_t(o1, u1, ce, 8, tol_mm=1e-11)
            h2 = _nearest_t(o2, u2, ce, 8, tol_mm=1e-11)
            ends.append((u1 - h1, u2 - h2, ce))
        (a1, a2, ca), (b1e, b2e, cb) = ends
        first = np.abs(a1 - a2) <= np.abs(b1e - b2e)
        e1[out], e2[out] = np.where(first, a1, b1e), np.where(first, a2, b2e)
        nstar[out] = np.stack([np.where(first, ca[k], cb[k]) for k in range(3)], 1)
    rest = np.flatnonzero(~settled)
    if rest.size:
        ns_r, e1_r, e2_r, _ = _reflectance_bracketed(s1, s2, i[rest], j[rest], t1[rest], t2[rest])
        nstar[rest], e1[rest], e2[rest] = ns_r, e1_r, e2_r
    return nstar, e1, e2, e1 - e2


#: Most joint Newton steps of :func:`_reflectance` (it settles in 3-5; the rest go to the bracketing solve).
_NEWTON_STEPS = 8


def _reflectance_bracketed(s1, s2, i, j, t1, t2):
    """:func:`_reflectance` by bracketing: Illinois regula falsi on the arc parameter, the nearest points
    by Gauss-Newton at each step; the end of the arc with the smaller ``|E1 - E2|`` where the two ends
    do not bracket a root."""
    b1, b2 = _Bundle(s1, i), _Bundle(s2, j)
    n1 = _normal_at_c(s1, i, [b1.o[k] + t1 * b1.d[k] for k in range(3)])
    n2 = _normal_at_c(s2, j, [b2.o[k] + t2 * b2.d[k] for k in range(3)])
    m = len(i)

    state = {"g1": t1.copy(), "g2": t2.copy()}

    def evaluate(lam, steps, sub=slice(None)):
        # Gauss-Newton warm-started from the last evaluation (lambda moves little between secant steps);
        # ``sub``: only those pairs (the ones still iterating)
        c1, c2 = [v[sub] for v in n1], [v[sub] for v in n2]
        r1, r2 = b1.sub(sub), b2.sub(sub)
        u1, u2, tt1, tt2 = state["g1"][sub], state["g2"][sub], t1[sub], t2[sub]
        nstar = _unit_c([(1.0 - lam) * c1[k] + lam * c2[k] for k in range(3)])
        g1 = _nearest_t(r1, u1, nstar, steps)
        g2 = _nearest_t(r2, u2, nstar, steps)
        state["g1"][sub], state["g2"][sub] = g1, g2
        e1, e2 = -(g1 - tt1), -(g2 - tt2)
        return e1 - e2, e1, e2, nstar

    f0 = evaluate(np.zeros(m), 6)[0]
    state["g1"], state["g2"] = t1.copy(), t2.copy()
    f1 = evaluate(np.ones(m), 6)[0]
    state["g1"], state["g2"] = state["g1"].copy(), state["g2"].copy()
    lo, hi = np.zeros(m), np.ones(m)
    flo, fhi = f0.copy(), f1.copy()
    bracket = np.sign(flo) * np.sign(fhi) <= 0
    # no sign change: the end of the arc with the smaller |E1 - E2|
    lam = np.where(np.abs(f0) <= np.abs(f1), 0.0, 1.0)
    lam = np.where(bracket & (flo == 0), 0.0, np.where(bracket & (fhi == 0), 1.0, lam))
    act = np.flatnonzero(bracket & (flo != 0) & (fhi != 0))
    with np.errstate(divide="ignore", invalid="ignore"):
        for _ in range(40):
            if not act.size:
                break
            a_lo, a_hi, a_flo, a_fhi = lo[act], hi[act], flo[act], fhi[act]
            x = (a_lo * a_fhi - a_hi * a_flo) / (a_fhi - a_flo)
            x = np.where(np.isfinite(x), np.clip(x, a_lo, a_hi), 0.5 * (a_lo + a_hi))
            fx = evaluate(x, 3, act)[0]
            lam[act] = x
            left = np.sign(fx) == np.sign(a_flo)
            # Illinois: halve the stale end's value so that the bracket shrinks from both sides
            a_fhi = np.where(left, 0.5 * a_fhi, a_fhi)
            a_flo = np.where(left, a_flo, 0.5 * a_flo)
            lo[act] = np.where(left, x, a_lo)
            flo[act] = np.where(left, fx, a_flo)
            hi[act] = np.where(left, a_hi, x)
            fhi[act] = np.where(left, a_fhi, fx)
            # converged: E1 = E2 to 1e-10 mm, or the arc parameter to 1e-12
            act = act[(np.abs(fx) > 1e-10) & (hi[act] - lo[act] > 1e-12)]
    dz, e1, e2, nstar = evaluate(lam, 6)
    return np.stack(nstar, 1), e1, e2, dz
