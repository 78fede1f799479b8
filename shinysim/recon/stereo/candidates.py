"""The tests of a pair of highlights (intersection, working volume, normal gap) and the indexed search that finds the pairs able to pass them (:func:`candidate_pairs`; :func:`candidate_pairs_naive` tests every pair).

See ``docs/stereo-matching.md`` for every definition.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from ..._shared import thread_map
from ...errors import OptionError, StereoError
from ...rig import Rig
from ._base import _CHUNK, _SAFETY, _angle, _angle_c, _cross_c, _dot_c, _norm, _pieces, _unit
from .rays import HighlightRays, StereoParams, _check_rig, _normal_at, _normal_at_c, _side, _Side, _take

__all__ = ["candidate_pairs", "candidate_pairs_naive"]


@dataclass
class _Tested:
    """The pairs that passed the tests, with what the tests computed for them."""

    i: np.ndarray
    j: np.ndarray
    n_examined: int
    n_distance: int
    n_depth: int
    n_normal: int
    t1: np.ndarray
    t2: np.ndarray
    D: np.ndarray
    P: np.ndarray        # (K, 3) midpoint of the closest approach
    n1: np.ndarray       # (K, 3) normal of ray i at P1*
    n2: np.ndarray
    gap: np.ndarray
    tol: np.ndarray      # (K,) the pair's normal limit, radians

    @staticmethod
    def join(parts):
        cat = lambda name, shape: (np.concatenate([getattr(p, name) for p in parts]) if parts
                                   else np.zeros(shape, np.int64 if name in "ij" else float))
        return _Tested(cat("i", 0), cat("j", 0), sum(p.n_examined for p in parts),
                       sum(p.n_distance for p in parts), sum(p.n_depth for p in parts),
                       sum(p.n_normal for p in parts), cat("t1", 0), cat("t2", 0), cat("D", 0),
                       cat("P", (0, 3)), cat("n1", (0, 3)), cat("n2", (0, 3)), cat("gap", 0), cat("tol", 0))

    def take(self, order):
        """The pairs ``order`` (the counts stay)."""
        return _Tested(*(v if np.ndim(v) == 0 else v[order] for v in vars(self).values()))


def _exact_tests(s1, s2, i, j, d0, gap0, zr, scale=None, workers=1):
    """The tests of ``docs/stereo-matching.md`` on pairs (i, j), in pieces (on ``workers`` threads). Every pair is
    computed element by element, so a pair gets the same verdict (and the same numbers) whichever search
    proposed it and whatever else is tested with it; each test runs only on the pairs that passed the
    ones before."""
    return _Tested.join(thread_map(lambda sl: _exact_piece(s1, s2, i[sl], j[sl], d0, gap0, zr, scale),
                             _pieces(len(i), workers, _CHUNK), workers))


def _exact_piece(s1, s2, ii, jj, d0, gap0, zr, scale=None):
    """The tests on one piece of pairs (see :func:`_exact_tests`)."""
    m0 = len(ii)
    d1, d2 = _take(s1.dc, ii), _take(s2.dc, jj)
    o1, o2 = _take(s1.oc, ii), _take(s2.oc, jj)
    w0 = [o1[k] - o2[k] for k in range(3)]
    # closest approach (Eq 40): c = d1.d2, D = |w0 . (d1 x d2)| / |d1 x d2|
    c = _dot_c(d1, d2)
    den = 1.0 - c * c
    ok = den > 1e-12
    cr = _cross_c(d1, d2)
    D = np.abs(_dot_c(w0, cr)) / np.where(ok, np.sqrt(_dot_c(cr, cr)), 1.0)
    sel = np.flatnonzero(ok & (D < d0))
    ii, jj, c, den, D = ii[sel], jj[sel], c[sel], den[sel], D[sel]
    d1, d2 = [v[sel] for v in d1], [v[sel] for v in d2]
    w0, o1, o2 = _take(w0, sel), _take(o1, sel), _take(o2, sel)
    b1, b2 = _dot_c(d1, w0), _dot_c(d2, w0)
    t1 = (c * b2 - b1) / den
    t2 = (b2 - c * b1) / den
    sel = np.flatnonzero((t1 > 0) & (t2 > 0))
    n_dist = m0 - len(sel)
    ii, jj, t1, t2, D = ii[sel], jj[sel], t1[sel], t2[sel], D[sel]
    P1 = [o1[k] + t1 * d1[k][sel] for k in range(3)]
    P2 = [o2[k] + t2 * d2[k][sel] for k in range(3)]
    n_depth = 0
    if zr is not None:
        z = 0.5 * (P1[2] + P2[2])
        inside = np.flatnonzero((z >= zr[0]) & (z <= zr[1]))
        n_depth = len(z) - len(inside)
        ii, jj, t1, t2, D = ii[inside], jj[inside], t1[inside], t2[inside], D[inside]
        P1, P2 = [v[inside] for v in P1], [v[inside] for v in P2]
    n1 = _normal_at_c(s1, ii, P1)
    n2 = _normal_at_c(s2, jj, P2)
    gap = _angle_c(n1, n2)
    tol = _gap_limit(s1, s2, ii, jj, gap0, scale)
    good = np.flatnonzero(gap <= tol)
    n_norm = len(gap) - len(good)
    P = np.stack([0.5 * (P1[k][good] + P2[k][good]) for k in range(3)], 1)
    return _Tested(ii[good], jj[good], m0, n_dist, n_depth, n_norm, t1[good], t2[good], D[good], P,
                   np.stack([v[good] for v in n1], 1), np.stack([v[good] for v in n2], 1), gap[good],
                   tol[good])


def _gap_limit(s1, s2, i, j, gap0, scale=None):
    """Each pair's normal limit (radians): the fixed ``gap0`` (``scale`` None), or ``scale * sqrt(phi_i^2 + phi_j^2 + f_i^2 +
    f_j^2)`` from the two highlights' footprints in normal (``docs/stereo-matching.md``, "Tolerances")."""
    if scale is None:
        return np.full(len(i), gap0)
    return scale * np.sqrt(s1.phi[i] ** 2 + s2.phi[j] ** 2 + s1.floor[i] ** 2 + s2.floor[j] ** 2)


# -- the index --------------------------------------------------------------------------------------


def _perp_frame(b):
    """Two unit vectors completing the unit vector ``b`` to a right-handed frame."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(b[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = _unit(np.cross(b, helper))
    return e1, np.cross(b, e1)


def _epipolar(s1: _Side, s2: _Side, d0: float):
    """Epipolar coordinates of both sides and the bound that links their difference to D.

    Returns ``(kind, u1, u2, k1, k2, K, B)``: for kind ``"angle"``, ``u`` is the angle ``phi`` in
    [-pi, pi] and ``D >= K k1 k2 |sin dphi|``; for ``"offset"`` (two orthographic cameras) ``u`` is
    the offset ``e`` and ``D = |e1 - e2|``.
    """
    c1, c2 = s1.camera, s2.camera
    p1, p2 = c1.projection == "perspective", c2.projection == "perspective"
    if not p1 and not p2:
        m = np.cross(c1.forward, c2.forward)
        if np.linalg.norm(m) < 1e-9:
            raise StereoError("the two orthographic cameras look along the same direction: their rays never "
                              "cross", field="cameras")
        m = m / np.linalg.norm(m)
        return "offset", s1.o @ m, s2.o @ m, None, None, None, None
    if p1 and p2:
        base = c2.position - c1.position
        B = float(np.linalg.norm(base))
        if B < 1e-9:
            raise StereoError("the two cameras share their centre of projection: there is no baseline",
                              field="cameras")
        b, origin, K = base / B, c1.position, B
    else:
        pin, ortho = (c1, c2) if p1 else (c2, c1)
        b, origin, K, B = ortho.forward, pin.position, 1.0, None
    f1, f2 = _perp_frame(b)

    def coords(side, pinhole):
        if pinhole:
            u = side.d - np.outer(side.d @ b, b)
        else:
            rel = side.o - origin
            u = rel - np.outer(rel @ b, b)
        k = _norm(u)
        if pinhole and not (p1 and p2):
            k = np.ones_like(k)  # a pinhole ray's factor is 1 (only the orthographic ray's distance counts)
        return np.arctan2(u @ f2, u @ f1), k

    x1, k1 = coords(s1, p1)
    x2, k2 = coords(s2, p2)
    return "angle", x1, x2, k1, k2, K, B


def _halfwidth(kind, k1, k2min, K, B, d0, n):
    """Per-query bound on the epipolar-coordinate difference of any pair with D < d0 (inf: no bound)."""
    if kind == "offset":
        return np.full(n, d0 * (1 + _SAFETY) + 1e-12)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = d0 / (K * k1 * k2min)
        ok = (r < 1.0) & (k1 > 0) & (k2min > 0)
        if B is not None:  # two pinholes: the opposite half-planes are excluded only by this
            ok &= B > d0 * (1.0 + 1.0 / k1 + 1.0 / k2min)
        ang = np.arcsin(np.clip(r * (1 + _SAFETY), 0.0, 1.0)) + 1e-12
    return np.where(ok, ang, np.inf)


def _volume(side: _Side, zr, d0):
    """Per ray: t range in the (widened) working volume, reference point, normal there, turn bound.

    Returns ``(valid, bounded, X_ref, n_ref, h, w)``: ``valid`` False where the ray cannot reach the
    volume in front of the camera (no pair with it can pass); ``bounded`` where h and w are finite.
    """
    n = len(side.o)
    if zr is None:
        return np.ones(n, bool), np.zeros(n, bool), None, None, None, None
    lo, hi = zr[0] - 0.5 * d0, zr[1] + 0.5 * d0
    oz, dz = side.o[:, 2], side.d[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        ta = (lo - oz) / dz
        tb = (hi - oz) / dz
    flat = np.abs(dz) < 1e-12
    t_lo = np.maximum(np.minimum(ta, tb), 0.0)
    t_hi = np.maximum(ta, tb)
    valid = np.where(flat, True, t_hi > 0)
    bounded = ~flat & valid
    t_lo = np.where(bounded, t_lo, 0.0)
    t_hi = np.where(bounded, t_hi, 0.0)
    t_ref = 0.5 * (t_lo + t_hi)
    h = 0.5 * (t_hi - t_lo)
    X = side.o + t_ref[:, None] * side.d
    n_ref = _normal_at(side, np.arange(n), X)
    # how far the normal can turn over [t_lo, t_hi] from n_ref (``docs/stereo-matching.md``)
    far = side.distant
    S = side.S
    P_lo = side.o + t_lo[:, None] * side.d
    P_hi = side.o + t_hi[:, None] * side.d
    psi = np.maximum(_angle(S - X, S - P_lo), _angle(S - X, S - P_hi))
    l_ref = np.where(far[:, None], S, _unit(S - X))
    theta = _angle(l_ref, -side.d)
    top = theta + psi
    with np.errstate(divide="ignore", invalid="ignore"):
        w = np.where(top < np.pi * (1 - 1e-9), psi / (2.0 * np.cos(0.5 * top)), np.inf)
    w = np.where(far, 0.0, w) * (1 + _SAFETY) + 1e-12
    bounded &= np.isfinite(w) & np.all(np.isfinite(n_ref), axis=1) & np.isfinite(h)
    return valid, bounded, X, n_ref, h, w


def _expand(starts, counts):
    """Concatenated ranges ``starts[k] + (0 .. counts[k]-1)`` and the owner ``k`` of each element."""
    counts = np.asarray(counts, np.int64)
    total = int(counts.sum())
    owner = np.repeat(np.arange(len(counts)), counts)
    first = np.cumsum(counts) - counts
    return owner, np.arange(total, dtype=np.int64) + (np.asarray(starts, np.int64) - first)[owner]


def _sweep(uq, aq, ut, periodic, sq=None, rq=None, st=None):
    """Sort-and-sweep on the epipolar coordinate: all pairs ``(q, t)`` with ``|uq - ut| <= aq`` (the
    difference taken modulo 2 pi when ``periodic``; ``aq`` inf: any), and, where ``sq`` is given, whose
    coordinates ``s`` along the epipolar lines may lie within ``rq`` of each other.

    The targets are sorted by (bin of ``st``, ``ut``); each query looks up, with :func:`numpy.searchsorted`,
    one window of ``ut`` per bin that its ``[sq - rq, sq + rq]`` reaches (two or three where its window
    wraps around +-pi). Windows are widened by more than the rounding of the keys, so the result is a
    superset of the exact condition (the exact tests follow).

    Returns ``(q, pos, order)``: ``q`` indexes ``uq`` (queries in sorted order, each query's pairs
    together), ``pos`` the sorted targets, whose indices into ``ut`` are ``order``.
    """
    if len(uq) == 0 or len(ut) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64)
    targets = _sweep_targets(ut, periodic, st, None if sq is None else _sweep_cell(rq, st))
    q, pos = _sweep_queries(targets, uq, aq, sq, rq)
    return q, pos, targets["order"]


def _sweep_cell(rq, st):
    """Width of the sweep's bins along the epipolar lines: the median reach (not below 1e-5 of the span)."""
    return max(float(np.median(rq)), (float(np.max(st)) - float(np.min(st))) * 1e-5, 1e-9)


def _sweep_targets(ut, periodic, st=None, cell=None):
    """The targets of :func:`_sweep` sorted by (bin of ``st``, ``ut``), with what the queries need."""
    if periodic:
        umin, umax = -np.pi, np.pi
    else:
        umin, umax = float(np.min(ut)), float(np.max(ut))
    span = (umax - umin) * (1 + 1e-6) + 1.0
    T = {"periodic": periodic, "umin": umin, "umax": umax, "span": span, "binned": st is not None}
    if st is None:
        bt = np.zeros(len(ut), np.int64)
    else:
        smin, smax = float(np.min(st)), float(np.max(st))
        bt = np.floor((st - smin) / cell).astype(np.int64)
        T.update(smin=smin, smax=smax, cell=cell, nb=int(bt.max()) + 1)
    key = bt * span + (ut - umin)
    order = np.argsort(key, kind="stable")
    key = key[order]
    T.update(order=order, key=key, eps=16.0 * float(np.spacing(np.max(np.abs(key)))) + 1e-12)
    return T


def _sweep_queries(T, uq, aq, sq=None, rq=None):
    """``(q, pos)`` of :func:`_sweep` for queries against targets prepared by :func:`_sweep_targets`."""
    nq = len(uq)
    if nq == 0 or len(T["key"]) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    umin, umax, span = T["umin"], T["umax"], T["span"]
    # bins along the epipolar lines
    if not T["binned"]:
        blo = bhi = np.zeros(nq, np.int64)
    else:
        smin, smax, cell, nb = T["smin"], T["smax"], T["cell"], T["nb"]
        rw = rq * (1 + 1e-9) + 1e-12 * (1.0 + abs(smin) + abs(smax))
        with np.errstate(invalid="ignore"):
            blo = np.clip(np.floor((sq - rw - smin) / cell), 0, nb - 1).astype(np.int64)
            bhi = np.clip(np.floor((sq + rw - smin) / cell), -1, nb - 1).astype(np.int64)
        bhi = np.where((sq + rw < smin) | (sq - rw > smax), blo - 1, bhi)
    # queries in the targets' order, so that neighbouring queries read neighbouring targets
    qorder = np.argsort(blo * span + (np.clip(uq, umin, umax) - umin), kind="stable")
    uq, aq, blo, bhi = uq[qorder], aq[qorder], blo[qorder], bhi[qorder]
    # query windows on u: (owner, lo, hi)
    if T["periodic"]:
        full = ~(aq < np.pi)
        lo = np.where(full, umin, uq - aq)
        hi = np.where(full, umax, uq + aq)
        wl = np.flatnonzero(~full & (lo < umin))  # wraps below -pi: also [lo + 2 pi, pi]
        wh = np.flatnonzero(~full & (hi > umax))  # wraps above pi: also [-pi, hi - 2 pi]
        owner = np.concatenate([np.arange(nq), wl, wh])
        plo = np.concatenate([lo, lo[wl] + 2 * np.pi, np.full(len(wh), umin)])
        phi = np.concatenate([hi, np.full(len(wl), umax), hi[wh] - 2 * np.pi])
        if len(wl) or len(wh):
            srt = np.argsort(owner, kind="stable")
            owner, plo, phi = owner[srt], plo[srt], phi[srt]
    else:
        owner, plo, phi = np.arange(nq), uq - aq, uq + aq
    plo, phi = np.maximum(plo, umin), np.minimum(phi, umax)
    keep = plo <= phi
    owner, plo, phi = owner[keep], plo[keep], phi[keep]
    key, eps = T["key"], T["eps"]
    piece, b = _expand(blo[owner], np.maximum(bhi[owner] - blo[owner] + 1, 0))
    base = b * span - umin
    first = np.searchsorted(key, base + plo[piece] - eps, side="left")
    last = np.searchsorted(key, base + phi[piece] + eps, side="right")
    which, pos = _expand(first, np.maximum(last - first, 0))
    return qorder[owner[piece[which]]], pos


def _resolve(s1, s2, params):
    """``(d0, gap0, depth range)``: ``gap0`` is the fixed normal limit, or the largest derived one (the bound the
    index works with; each pair is tested against its own)."""
    k = params.tolerance_scale
    d0 = params.d0_mm if params.d0_mm is not None else k * math.hypot(s1.pitch, s2.pitch)
    if params.max_normal_gap_deg is not None:
        gap0 = math.radians(params.max_normal_gap_deg)
    else:
        top = [float(np.max(a)) if len(a) else 0.0 for a in (s1.phi, s2.phi, s1.floor, s2.floor)]
        gap0 = k * math.sqrt(sum(v * v for v in top))
    return d0, gap0, params.depth_range_mm


def _along_axis(s1: _Side, s2: _Side):
    """A horizontal unit vector along the epipolar lines, roughly (the cameras' baseline in the xy-plane):
    the coordinate the index bins on besides the epipolar one (any direction is correct; this one is fast)."""
    base = np.asarray(s2.camera.position, float) - np.asarray(s1.camera.position, float)
    base[2] = 0.0
    nb = float(np.linalg.norm(base))
    return base / nb if nb > 1e-9 else np.array([1.0, 0.0, 0.0])


def _proposals(s1: _Side, s2: _Side, params: StereoParams, workers: int = 1):
    """Pairs that may pass the tests: a superset of the passing pairs (``docs/stereo-matching.md``)."""
    d0, gap0, zr = _resolve(s1, s2, params)
    n1, n2 = len(s1.o), len(s2.o)
    if n1 == 0 or n2 == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    kind, u1, u2, k1, k2, K, B = _epipolar(s1, s2, d0)
    periodic = kind != "offset"
    v1, b1, X1, nr1, h1, w1 = _volume(s1, zr, d0)
    v2, b2, X2, nr2, h2, w2 = _volume(s2, zr, d0)
    out_i, out_j = [], []
    # loose rays (no finite bound on depth or normal): the epipolar coordinate alone
    loose1 = np.flatnonzero(v1 & ~b1)
    loose2 = np.flatnonzero(v2 & ~b2)
    all2 = np.flatnonzero(v2)
    tight1 = np.flatnonzero(b1)
    tight2 = np.flatnonzero(b2)
    for q, t in ((loose1, all2), (tight1, loose2)):
        if len(q) and len(t):
            a = _halfwidth(kind, None if kind == "offset" else k1[q],
                           None if kind == "offset" else float(np.min(k2[t])), K, B, d0, len(q))
            qi, pos, order = _sweep(u1[q], a, u2[t], periodic)
            out_i.append(q[qi])
            out_j.append(t[order[pos]])
    if len(tight1) and len(tight2):
        q, t = tight1, tight2
        a = _halfwidth(kind, None if kind == "offset" else k1[q],
                       None if kind == "offset" else float(np.min(k2[t])), K, B, d0, len(q))
        # along the epipolar lines: |(X1_ref - X2_ref) . e| <= h1 |d1 . e| + h2 |d2 . e| + D0 (``docs/stereo-matching.md``)
        e = _along_axis(s1, s2)
        reach2 = float(np.max(h2[t] * np.abs(s2.d[t] @ e)))
        reach_q = (h1[q] * np.abs(s1.d[q] @ e) + reach2 + d0) * (1 + _SAFETY) + 1e-12
        sq, st = X1[q] @ e, X2[t] @ e
        targets = _sweep_targets(u2[t], periodic, st, _sweep_cell(reach_q, st))
        w2max = float(np.max(w2[t]))
        t = t[targets["order"]]  # the targets in the sweep's order: pos indexes them
        # the bounds of docs/stereo-matching.md ("Search"), pair by pair: angle(n1_ref, n2_ref) <= gap0 + w1 + w2 (as a chord;
        # first each component against the query's largest bound, then the chord) and
        # |X1_ref - X2_ref| <= h1 + h2 + D0, each widened by the safety margin
        cn_q = 2.0 * np.sin(0.5 * np.minimum((gap0 + w1[q] + w2max) * (1 + _SAFETY), np.pi)) + 1e-12
        nq_c = [np.ascontiguousarray(nr1[q, k]) for k in range(3)]
        nt_c = [np.ascontiguousarray(nr2[t, k]) for k in range(3)]
        u1q = u1[q]

        def piece(sl):
            # the queries in pieces on threads, against the one sorted target list
            qi, pos = _sweep_queries(targets, u1q[sl], a[sl], sq[sl], reach_q[sl])
            qi = qi + sl.start
            chord = np.zeros(len(qi))
            for k in range(3):
                dn = nq_c[k][qi] - nt_c[k][pos]
                ok = np.abs(dn) <= cn_q[qi]
                qi, pos, chord = qi[ok], pos[ok], chord[ok] + dn[ok] * dn[ok]
            qi, tj = q[qi], t[pos]
            cn = 2.0 * np.sin(0.5 * np.minimum((gap0 + w1[qi] + w2[tj]) * (1 + _SAFETY), np.pi)) + 1e-12
            ok = chord <= cn * cn
            qi, tj = qi[ok], tj[ok]
            cx = (h1[qi] + h2[tj] + d0) * (1 + _SAFETY) + 1e-12
            dx2 = np.zeros(len(qi))
            for k in range(3):
                dx = X1[:, k][qi] - X2[:, k][tj]
                dx2 += dx * dx
            ok = dx2 <= cx * cx
            return qi[ok], tj[ok]

        for qi, tj in thread_map(piece, _pieces(len(q), workers), workers):
            out_i.append(qi)
            out_j.append(tj)
    if not out_i:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(out_i), np.concatenate(out_j)


def _usable_pairs(rays1, rays2, i, j):
    """The pairs whose two highlights are both :attr:`HighlightRays.usable`."""
    keep = np.ones(len(i), bool)
    for rays, idx in ((rays1, i), (rays2, j)):
        if rays.usable is not None:
            keep &= np.asarray(rays.usable, bool)[idx]
    return (i, j) if keep.all() else (i[keep], j[keep])


def _check_pair(rays1, rays2, rig):
    _check_rig(rig)
    for name, r in (("rays1", rays1), ("rays2", rays2)):
        if not isinstance(r, HighlightRays):
            raise StereoError(f"must be HighlightRays (see highlight_rays), got {type(r).__name__}", field=name)
        if not 0 <= r.camera < len(rig.cameras):
            raise StereoError(f"camera {r.camera} is out of range 0..{len(rig.cameras) - 1}", field=name)
        if len(r.sources) and (r.sources.min() < 0 or r.sources.max() >= rig.n_sources):
            raise StereoError(f"a source index is out of range 0..{rig.n_sources - 1}", field=f"{name}.sources")
    if rays1.camera == rays2.camera:
        raise StereoError(f"both sets of highlights come from camera {rays1.camera}; stereo needs two cameras",
                          field="rays2.camera")


def _candidates(rays1, rays2, rig, params, naive=False, seconds=None):
    """Sides, the pairs that passed the tests (sorted by i then j, with what the tests computed) and the
    limits; ``seconds``: a dict that gets the time of the index (``candidates``) and of the tests."""
    params = StereoParams() if params is None else params
    if not isinstance(params, StereoParams):
        raise OptionError(f"params must be StereoParams, got {type(params).__name__}")
    _check_pair(rays1, rays2, rig)
    seconds = {} if seconds is None else seconds
    start = time.perf_counter()
    s1, s2 = (_side(r, rig, footprints=True, workers=params.threads) for r in (rays1, rays2))
    # the tolerance scale where each pair's normal limit is derived from the footprints; None: one fixed limit
    scale = params.tolerance_scale if params.max_normal_gap_deg is None else None
    d0, gap0, zr = _resolve(s1, s2, params)
    if naive:
        n1, n2 = len(s1.o), len(s2.o)
        parts = []
        rows = max(1, _CHUNK // max(n2, 1))
        for a in range(0, n1, rows):
            i = np.repeat(np.arange(a, min(a + rows, n1)), n2)
            j = np.tile(np.arange(n2), min(a + rows, n1) - a)
            i, j = _usable_pairs(rays1, rays2, i, j)
            parts.append(_exact_tests(s1, s2, i, j, d0, gap0, zr, scale, params.threads))
        res = _Tested.join(parts)  # row by row: already sorted
        seconds["candidates"], seconds["tests"] = 0.0, time.perf_counter() - start
        return s1, s2, res, (d0, gap0, zr)
    pi, pj = _proposals(s1, s2, params, params.threads)
    pi, pj = _usable_pairs(rays1, rays2, pi, pj)
    mid = time.perf_counter()
    res = _exact_tests(s1, s2, pi, pj, d0, gap0, zr, scale, params.threads)
    res = res.take(np.argsort(res.i * np.int64(max(len(s2.o), 1)) + res.j, kind="stable"))  # by i, then j
    seconds["candidates"], seconds["tests"] = mid - start, time.perf_counter() - mid
    return s1, s2, res, (d0, gap0, zr)


def candidate_pairs(rays1: HighlightRays, rays2: HighlightRays, rig: Rig, params: StereoParams | None = None):
    """Highlight pairs that pass the intersection, volume and normal tests, found with a spatial index.

    The same pairs as :func:`candidate_pairs_naive` (every proposal of the
    index gets the same exact tests, and the index provably proposes every
    pair that can pass: ``docs/stereo-matching.md``, "Search"), in O(N log N) plus the output.

    Parameters
    ----------
    rays1, rays2 : HighlightRays
        The two cameras' highlights (:func:`highlight_rays`).
    rig : Rig
    params : StereoParams, optional
        Uses ``d0_mm``, ``max_normal_gap_deg``, ``tolerance_scale`` and ``depth_range_mm``.

    Returns
    -------
    i, j : (K,) int ndarray
        Indices into ``rays1`` and ``rays2``, sorted by ``i`` then ``j``.
    """
    res = _candidates(rays1, rays2, rig, params)[2]
    return res.i, res.j


def candidate_pairs_naive(rays1: HighlightRays, rays2: HighlightRays, rig: Rig, params: StereoParams | None = None):
    """The paper's O(N^2) search: the tests of :func:`candidate_pairs` on every pair (Section V).

    The baseline, and the reference the indexed search must equal; chunked
    so that memory stays bounded (about 2**18 pairs at a time).

    Returns
    -------
    i, j : (K,) int ndarray
        Sorted by ``i`` then ``j``.
    """
    res = _candidates(rays1, rays2, rig, params, naive=True)[2]
    return res.i, res.j
