"""Refinement: the two elements of a match placed on a locally spherical surface (the umbilic model).

See ``docs/stereo-matching.md`` for every definition.
"""

from __future__ import annotations

import numpy as np

from ._base import _cross_c, _dot_c, _norm, _unit
from .rays import _normal_at
from .reflectance import _Bundle, _normal_and_rate

__all__ = []


def _cramer(a, b, c, r):
    """Per row, ``(x, y, z)`` with ``x a + y b + z c = r`` (each a list of three component arrays) by
    Cramer's rule, and where the system is solvable.

    In the refinement ``a`` and ``b`` are near the two rays' unit directions and ``c`` the difference of
    two normals: where ``c`` has (almost) no part across the plane of the rays the system is singular
    (rho is not observed: a plane, an exact lattice match). Its smallest singular value is about
    ``|det| / |a x b|``; below 1e-6 of the largest (about 1.4) the row is left to the caller. Above it
    the condition number stays under about 1e6, so Cramer's rule loses at most six of the sixteen
    digits."""
    bc, ca, ab = _cross_c(b, c), _cross_c(c, a), _cross_c(a, b)
    det = _dot_c(a, bc)
    ok = np.abs(det) > 1.4e-6 * np.sqrt(_dot_c(ab, ab))
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(ok, 1.0 / det, 0.0)
    return _dot_c(r, bc) * inv, _dot_c(r, ca) * inv, _dot_c(r, ab) * inv, ok


def _image_radius(s1, s2, i, j):
    """The local radius the image shows at each pair: ``(p1 / phi1 + p2 / phi2) / 2``, signed by the curvature
    the neighbours show (0 where the two cameras' signs differ or are unseen)."""
    sign = np.where((s1.convex[i] != 0) & (s1.convex[i] == s2.convex[j]), s1.convex[i], 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return sign * 0.5 * (s1.pitch / s1.phi[i] + s2.pitch / s2.phi[j])


#: How far a pair's own rho may lie from the image's radius (a factor, either way, same sign) and be used.
RADIUS_AGREEMENT = 2.0


def _agrees_with_image(rho, s1, s2, i, j):
    """Whether each pair's own ``rho`` has the image's sign and lies within :data:`RADIUS_AGREEMENT` of it."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = rho / _image_radius(s1, s2, i, j)
    return np.isfinite(ratio) & (ratio >= 1.0 / RADIUS_AGREEMENT) & (ratio <= RADIUS_AGREEMENT)


def _held_radius(s1, s2, i, j, P, d0, passes=8, tol_mm=1e-10):
    """The umbilic model with ``rho`` held at the radius the image shows: for pairs whose own system is
    singular (both rays in the plane of the sources, the paper's planar geometry) or whose own ``rho``
    disagrees with the image's (:func:`_agrees_with_image`).

    ``rho = (p1 / phi1 + p2 / phi2) / 2`` with the sign of the curvature the neighbours show
    (:func:`~shinysim.recon.stereo.rays._normal_footprints`); Gauss-Newton on
    ``F = E1(t1) - E2(t2) + rho (n2(E2) - n1(E1))`` in ``(t1, t2)`` from the rays' crossing. Returns the
    elements' midpoint and mean normal and where they were placed (the model met to within
    D0, as the rays' own closest approach is; the elements within ``d0``); NaN and False elsewhere, and where
    the curvature was not seen."""
    m = len(i)
    b1, b2 = _Bundle(s1, i), _Bundle(s2, j)
    rho = _image_radius(s1, s2, i, j)
    sign = np.sign(np.nan_to_num(rho))
    Pc = [P[:, k] for k in range(3)]
    t1 = sum((Pc[k] - b1.o[k]) * b1.d[k] for k in range(3))
    t2 = sum((Pc[k] - b2.o[k]) * b2.d[k] for k in range(3))
    F = [np.zeros(m)] * 3
    with np.errstate(invalid="ignore", divide="ignore"):
        for _ in range(passes):
            h1, dh1 = _normal_and_rate(b1, t1)
            h2, dh2 = _normal_and_rate(b2, t2)
            F = [(b1.o[k] + t1 * b1.d[k]) - (b2.o[k] + t2 * b2.d[k]) + rho * (h2[k] - h1[k]) for k in range(3)]
            A = [b1.d[k] - rho * dh1[k] for k in range(3)]
            B = [rho * dh2[k] - b2.d[k] for k in range(3)]
            aa, ab, bb = _dot_c(A, A), _dot_c(A, B), _dot_c(B, B)
            fa, fb = -_dot_c(F, A), -_dot_c(F, B)
            det = aa * bb - ab * ab
            x, y = (fa * bb - fb * ab) / det, (aa * fb - ab * fa) / det
            t1, t2 = t1 + np.where(np.isfinite(x), x, 0.0), t2 + np.where(np.isfinite(y), y, 0.0)
            if np.all(~np.isfinite(x) | (np.abs(x) <= tol_mm)) and np.all(~np.isfinite(y) | (np.abs(y) <= tol_mm)):
                break
    E1 = np.stack([b1.o[k] + t1 * b1.d[k] for k in range(3)], 1)
    E2 = np.stack([b2.o[k] + t2 * b2.d[k] for k in range(3)], 1)
    n1, n2 = _normal_at(s1, i, E1), _normal_at(s2, j, E2)
    resid = np.sqrt(_dot_c(F, F))
    ok = ((sign != 0) & np.isfinite(rho) & np.all(np.isfinite(E1), axis=1) & np.all(np.isfinite(E2), axis=1)
          & (_norm(E2 - E1) <= d0) & (resid <= d0))
    point = np.where(ok[:, None], 0.5 * (E1 + E2), np.nan)
    normal = np.where(ok[:, None], _unit(n1 + n2), np.nan)
    return point, normal, ok


def _umbilic(s1, s2, i, j, P, d0, passes=8, tol_mm=1e-10):
    """Place each pair's two elements on a locally spherical surface (``docs/stereo-matching.md``, "Refinement").

    Newton's method on ``F = E1(t1) - E2(t2) + rho (n2(E2) - n1(E1)) = 0`` in ``(t1, t2, rho)``, from the
    rays' crossing: its first step, with ``rho = 0`` in the Jacobian, solves the three linear equations
    with the normals held at the crossing; the next ones add the normals' rates
    along the rays (``dn/dt``, through the directions to the sources), which a fixed-point iteration
    cannot follow where ``rho^2`` exceeds ``|E2 - E1|`` times the source distance. A pair stops when its
    elements move by no more than ``tol_mm``, after at most ``passes`` steps; a pair whose system is
    singular (``rho`` not observed: a plane, or both rays in one plane with the sources) is not refined: the
    caller keeps the rays' crossing.

    Returns
    -------
    point, normal : (M, 3)
        Midpoint of the two elements and the mean of their normals (NaN where
        not refined).
    refined : (M,) bool
    radius : (M,) float, millimetres (NaN where not refined)
    elements, normals : (M, 6)
        The two elements ``E1, E2`` and their normals, side by side.
    """
    m = len(i)
    b1, b2 = _Bundle(s1, i), _Bundle(s2, j)
    Pc = [P[:, k] for k in range(3)]
    t1 = sum((Pc[k] - b1.o[k]) * b1.d[k] for k in range(3))
    t2 = sum((Pc[k] - b2.o[k]) * b2.d[k] for k in range(3))
    rho = np.zeros(m)
    solved = np.ones(m, bool)  # rho observed: the system was not singular at the start
    act = np.arange(m)
    r1, r2 = b1, b2
    with np.errstate(invalid="ignore"):
        for step in range(passes):
            u1, u2, rr = t1[act], t2[act], rho[act]
            h1, dh1 = _normal_and_rate(r1, u1)
            h2, dh2 = _normal_and_rate(r2, u2)
            dn = [h2[k] - h1[k] for k in range(3)]
            F = [(r1.o[k] + u1 * r1.d[k]) - (r2.o[k] + u2 * r2.d[k]) + rr * dn[k] for k in range(3)]
            A = [r1.d[k] - rr * dh1[k] for k in range(3)]
            B = [rr * dh2[k] - r2.d[k] for k in range(3)]
            x, y, z, ok = _cramer(A, B, dn, [-v for v in F])
            if step == 0 and not ok.all():
                # rho not observed: the closest approach of o1 + t1 d1 and o2 + t2 d2
                nb = ~ok
                d1, d2 = [v[nb] for v in r1.d], [v[nb] for v in r2.d]
                bo = [np.broadcast_to(r2.o[k], u2.shape)[nb] - np.broadcast_to(r1.o[k], u1.shape)[nb]
                      for k in range(3)]
                c, e1, e2 = _dot_c(d1, d2), _dot_c(d1, bo), _dot_c(d2, bo)
                den = np.where(1.0 - c * c > 0, 1.0 - c * c, np.nan)
                t1[act[nb]], t2[act[nb]] = (e1 - c * e2) / den, (c * e1 - e2) / den
                solved[act[nb]] = False
            t1[act] = np.where(ok, u1 + x, t1[act])
            t2[act] = np.where(ok, u2 + y, t2[act])
            rho[act] = np.where(ok, rr + z, rr)
            more = ok & ((np.abs(x) > tol_mm) | (np.abs(y) > tol_mm))
            act = act[more]
            if not act.size:
                break
            r1, r2 = r1.sub(more), r2.sub(more)
    E1 = np.stack([b1.o[k] + t1 * b1.d[k] for k in range(3)], 1)
    E2 = np.stack([b2.o[k] + t2 * b2.d[k] for k in range(3)], 1)
    n1, n2 = _normal_at(s1, i, E1), _normal_at(s2, j, E2)
    ok = solved & np.all(np.isfinite(E1), axis=1) & np.all(np.isfinite(E2), axis=1) & (_norm(E2 - E1) <= d0)
    point = np.where(ok[:, None], 0.5 * (E1 + E2), np.nan)
    normal = np.where(ok[:, None], _unit(n1 + n2), np.nan)
    return point, normal, ok, np.where(ok, rho, np.nan), np.concatenate([E1, E2], 1), np.concatenate([n1, n2], 1)


#: Matches (the match and its nearest refined neighbours) that one local radius is fitted to.
PATCH = 8
#: Largest relative standard error of a local radius that is reported (else NaN: not identifiable): two
#: standard errors within 5 % of the radius.
RADIUS_REL_ERROR = 0.025


def _patch_radius(point, elements, normals, refined, k=PATCH, max_rel=RADIUS_REL_ERROR):
    """Local radius of curvature at each match from the elements of its ``k`` nearest refined matches (itself
    included): both elements of each, with their own normals (``elements``, ``normals``: (M, 6), as
    :func:`_umbilic` gives them).

    On a locally spherical (umbilic) surface every element satisfies ``E = c + r n``: linear least squares in
    the centre ``c`` and radius ``r`` over the patch's ``2 k`` elements, exact on a sphere. ``r`` is reported
    where its standard error (from the fit's residuals) is at most ``max_rel`` of it; NaN elsewhere (a patch
    too flat or too small for its normals to spread, or one that is not a sphere)."""
    from scipy.spatial import cKDTree

    m = len(point)
    radius = np.full(m, np.nan)
    use = np.flatnonzero(refined & np.all(np.isfinite(elements), axis=1) & np.all(np.isfinite(normals), axis=1))
    if len(use) < max(k, 3):
        return radius
    _, nb = cKDTree(point[use]).query(point[use], k=k)
    P = elements[use][nb].reshape(len(use), 2 * k, 3)
    N = normals[use][nb].reshape(len(use), 2 * k, 3)
    q = 2 * k
    # normal equations of min sum |E - c - r n|^2 over (c, r): [[q I, sum n], [sum n^T, sum n.n]]
    A = np.zeros((len(use), 4, 4))
    A[:, :3, :3] = q * np.eye(3)
    A[:, :3, 3] = A[:, 3, :3] = N.sum(axis=1)
    A[:, 3, 3] = np.einsum("mki,mki->m", N, N)
    b = np.concatenate([P.sum(axis=1), np.einsum("mki,mki->m", P, N)[:, None]], axis=1)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        det_ok = np.abs(np.linalg.det(A)) > 1e-300
        x = np.full((len(use), 4), np.nan)
        x[det_ok] = np.linalg.solve(A[det_ok], b[det_ok][..., None])[..., 0]
        res = P - x[:, None, :3] - x[:, 3, None, None] * N
        s2 = np.einsum("mki,mki->m", res, res) / (3 * q - 4)
        var_r = np.full(len(use), np.inf)
        var_r[det_ok] = s2[det_ok] * np.linalg.inv(A[det_ok])[:, 3, 3]
        good = det_ok & (np.sqrt(var_r) <= max_rel * np.abs(x[:, 3]))
    radius[use[good]] = x[good, 3]
    return radius
