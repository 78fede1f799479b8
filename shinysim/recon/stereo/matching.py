"""Matching two cameras' highlights (:func:`match_highlights`) and two stacks' (:func:`match_stacks`).

See ``docs/stereo-matching.md`` for every definition.
"""

from __future__ import annotations

import time

import numpy as np
from scipy.spatial import cKDTree

from ...errors import StereoError
from ...rig import Rig
from ._base import _per_piece, _unit
from .bound import _spacing_bound
from .candidates import _candidates
from .matches import StereoMatches
from .rays import HighlightRays, StereoParams
from .reflectance import _reflectance
from .refine import _agrees_with_image, _held_radius, _patch_radius, _umbilic
from .relaxation import _competitor_max, _greedy_fast, _median_nn, _relax, _spatial_order, _support_matrix

__all__ = ["match_highlights", "match_stacks"]


def _empty(reason, **counts):
    z = np.zeros(0)
    zi = np.zeros(0, np.int64)
    return StereoMatches(np.zeros((0, 3)), np.zeros((0, 3)), z, z, z, z, zi, zi, zi, zi, z, z, z, z, z, z, z,
                         reason=reason, **counts)


def match_highlights(rays1: HighlightRays, rays2: HighlightRays, rig: Rig,
                     params: StereoParams | None = None) -> StereoMatches:
    """Structured-highlight stereo: match two cameras' highlights into surface points and normals.

    Candidates from :func:`candidate_pairs` (intersection Eq 40, working
    volume, normal gap), optional Eq 43 / Eqs 33-34 limits, then relaxation
    and uniqueness (each highlight in at most one match); residuals and the
    common normal by reflectance matching (Eqs 32-34 in vector form). See
    ``docs/stereo-matching.md`` for every definition.

    Parameters
    ----------
    rays1, rays2 : HighlightRays
        Highlights of two different cameras of ``rig``.
    rig : Rig
    params : StereoParams, optional

    Returns
    -------
    StereoMatches
        Empty, with ``reason`` saying why, when nothing is accepted (not an
        exception).

    Raises
    ------
    StereoError
        Highlights of the same camera, a camera or source index out of range,
        a rig with one camera, cameras with no baseline.
    OptionError
        ``params`` not a :class:`StereoParams`.
    """
    params = StereoParams() if params is None else params
    seconds = {}
    s1, s2, res, (d0, gap0, zr) = _candidates(rays1, rays2, rig, params, seconds=seconds)
    i, j = res.i, res.j
    n1, n2 = len(s1.o), len(s2.o)
    counts = dict(n_examined=int(res.n_examined), n_rejected_distance=int(res.n_distance),
                  n_rejected_depth=int(res.n_depth), n_rejected_normal=int(res.n_normal),
                  n_candidates=int(len(i)), d0_mm=float(d0), max_normal_gap_deg=float(np.degrees(gap0)),
                  **_spacing_bound(s1, s2, rig))
    if n1 == 0 or n2 == 0:
        return _empty(f"no highlights in camera {rays1.camera if n1 == 0 else rays2.camera}", **counts)
    if len(i) == 0:
        if res.n_examined == res.n_distance:
            why = f"no pair of rays passes within D0 = {d0:.4g} mm of each other in front of both cameras"
        elif res.n_examined == res.n_distance + res.n_depth:
            why = f"no ray crossing within D0 lies in the depth range {zr}"
        else:
            limit = ("max_normal_gap_deg" if params.max_normal_gap_deg is not None
                     else "the largest limit derived from the highlights' footprints")
            why = (f"no pair passed the normal test ({limit} = {np.degrees(gap0):.4g} deg); "
                   f"{res.n_normal} crossing pairs had normals further apart")
        if counts["expected_matchable"] < 0.05:
            why += (f"; with these sources the two cameras' highlights lie a median "
                    f"{counts['lattice_gap_px']:.3g} px apart on a surface whose normal turns "
                    f"{counts['normal_turn_deg_per_px']:.3g} deg per pixel: "
                    f"{100 * counts['expected_matchable']:.2g} % are within one pixel (docs/stereo.md)")
        return _empty(why, **counts)
    t1, t2, D, P, n1v, n2v, gap, tol = res.t1, res.t2, res.D, res.P, res.n1, res.n2, res.gap, res.tol
    keep = np.ones(len(i), bool)
    nz_rej = ne_rej = 0
    if params.max_delta_z_mm is not None or params.max_e_mm is not None:
        _, e1, e2, dz = _per_piece(lambda sl: _reflectance(s1, s2, i[sl], j[sl], t1[sl], t2[sl]), len(i),
                                   params.threads)
        if params.max_delta_z_mm is not None:
            bad = np.abs(dz) > params.max_delta_z_mm
            nz_rej = int(np.count_nonzero(bad))
            keep &= ~bad
        if params.max_e_mm is not None:
            bad = keep & ((np.abs(e1) > params.max_e_mm) | (np.abs(e2) > params.max_e_mm))
            ne_rej = int(np.count_nonzero(bad))
            keep &= ~bad
    counts.update(n_rejected_delta_z=nz_rej, n_rejected_e=ne_rej)
    if not np.any(keep):
        return _empty("no candidate passed the reflectance-matching limits "
                      f"(max_delta_z_mm = {params.max_delta_z_mm}, max_e_mm = {params.max_e_mm})", **counts)
    sel = np.flatnonzero(keep)
    i, j, t1, t2, D, P, gap, tol = i[sel], j[sel], t1[sel], t2[sel], D[sel], P[sel], gap[sel], tol[sel]
    nmean = _unit(n1v[sel] + n2v[sel])
    with np.errstate(divide="ignore", invalid="ignore"):
        q = (D / d0) ** 2 + np.where(tol > 0, (gap / tol) ** 2, 0.0)
    a0 = np.exp(-q)
    radius = float("nan")
    iters = 0
    t_start = time.perf_counter()
    if params.relax and len(i) > 1:
        # the relaxation runs on the candidates in a spatial order (cache); every result is per candidate,
        # and each sparse product sums its terms in the candidates' (i, j) order, as without the reordering
        perm = _spatial_order(P)
        Ps = np.ascontiguousarray(P[perm])
        tree = cKDTree(Ps, balanced_tree=False, compact_nodes=False)
        radius = (params.neighbourhood_mm if params.neighbourhood_mm is not None
                  else 4.0 * _median_nn(tree, Ps))
        rise_tol = params.rise_tol_mm if params.rise_tol_mm is not None else d0
        W = _support_matrix(Ps, nmean[perm], i[perm], j[perm], radius, rise_tol, tol[perm], tree=tree, cols=perm,
                            workers=params.threads)
        xs, _, ss, iters = _relax(a0[perm], (n2v[sel] - n1v[sel])[perm], W, i[perm], j[perm], n1, n2, tol[perm],
                                  params.iterations, params.tol, params.threads)
        x, support = np.empty_like(xs), np.empty_like(ss)
        x[perm], support[perm] = xs, ss
    else:
        x, support = a0, np.zeros_like(a0)
    seconds["relaxation"] = time.perf_counter() - t_start
    t_start = time.perf_counter()
    take = _greedy_fast(x, i, j, n1, n2)
    _, other = _competitor_max(x, i, j, n1, n2)
    with np.errstate(divide="ignore", invalid="ignore"):
        margin = np.where(np.isfinite(other), 1.0 - other / x, 1.0)
    margin = np.clip(np.nan_to_num(margin, nan=0.0), 0.0, 1.0)
    conf = np.clip(a0 * margin, 0.0, 1.0)
    counts.update(n_rejected_uniqueness=int(len(i) - np.count_nonzero(take)), relax_iterations=int(iters),
                  neighbourhood_mm=float(radius))
    w = np.flatnonzero(take)
    i, j, t1, t2 = i[w], j[w], t1[w], t2[w]
    seconds["uniqueness"] = time.perf_counter() - t_start
    t_start = time.perf_counter()
    nstar, e1, e2, dz = _per_piece(lambda sl: _reflectance(s1, s2, i[sl], j[sl], t1[sl], t2[sl]), len(i),
                                   params.threads)
    order = np.lexsort((j, i))
    w, i, j, nstar, e1, e2, dz = w[order], i[order], j[order], nstar[order], e1[order], e2[order], dz[order]
    seconds["reflectance"] = time.perf_counter() - t_start
    point, normal = P[w], nstar
    refined, rho = np.zeros(len(w), bool), np.full(len(w), np.nan)
    if params.refine and len(w):
        t_start = time.perf_counter()
        rp, rn, refined, rho_pair, elements, normals = _per_piece(
            lambda sl: _umbilic(s1, s2, i[sl], j[sl], point[sl], d0), len(w), params.threads)
        # the pair's own rho rests on a normal difference of a pixel's turn or less: where it disagrees with
        # the radius the image shows (other sign, or more than a factor 2 off), the image's is taken instead
        refined &= _agrees_with_image(rho_pair, s1, s2, i, j)
        point = np.where(refined[:, None], rp, point)
        normal = np.where(refined[:, None], rn, normal)
        rho = _patch_radius(point, elements, normals, refined)
        # pairs whose own rho is not observed (the planar geometry): rho held at the curvature the image shows
        rest = np.flatnonzero(~refined)
        if len(rest):
            hp, hn, held = _held_radius(s1, s2, i[rest], j[rest], point[rest], d0)
            point[rest[held]], normal[rest[held]] = hp[held], hn[held]
            refined = refined.copy()
            refined[rest[held]] = True
        seconds["refinement"] = time.perf_counter() - t_start
    return StereoMatches(
        point=point, normal=normal, row1=rays1.rows[i], col1=rays1.cols[i], row2=rays2.rows[j],
        col2=rays2.cols[j], source1=rays1.sources[i], source2=rays2.sources[j], index1=i, index2=j, d_mm=D[w],
        normal_gap_deg=np.degrees(gap[w]), e1_mm=e1, e2_mm=e2, delta_z_mm=dz, confidence=conf[w],
        support=support[w], crossing=P[w], refined=refined, radius_mm=rho, seconds=seconds, **counts)


def match_stacks(stack1, stack2, rig: Rig | None = None, *, detect=None, tables=None,
                 params: StereoParams | None = None) -> StereoMatches:
    """Structured-highlight stereo from two stacks: their highlights found, made rays and matched.

    The whole stack-pair path: each stack's highlights
    (:func:`~shinysim.recon.pipeline.reconstruct` with ``detect``, no
    normals; or ``tables``, highlight tables found already), their rays
    (:func:`highlight_rays`, each stack's camera), and
    :func:`match_highlights`.

    Parameters
    ----------
    stack1, stack2 : shinysim.io.Stack
        The two cameras' stacks of one rig, one frame per source each.
    rig : Rig, optional
        The rig the rays are cast in (default: the first stack's).
    detect : DetectParams, optional
    tables : (HighlightTable, HighlightTable), optional
        Each stack's highlights (``row``, ``col``, ``source`` are used); the
        matches index them.
    params : StereoParams, optional

    Raises
    ------
    StereoError
        Stacks of different rigs or source counts, or of the same camera.

    Two cameras at +-15 degrees over a mirror element at the origin facing
    (nearly) up: camera 0 sees it lit by the fiber at -13.75 degrees, camera
    1 by the one at +16.25, each at its image centre.

    >>> from shinysim.io import Stack
    >>> from shinysim.rig import stereo_semicircle
    >>> rig = stereo_semicircle(resolution=64)
    >>> polar = np.degrees(np.arctan2(rig.source_positions[:, 0], rig.source_positions[:, 2]))
    >>> frames = np.zeros((2, rig.n_sources, 64, 64), np.float32)
    >>> frames[0, np.argmin(abs(polar + 13.75)), 31:33, 31:33] = 1.0
    >>> frames[1, np.argmin(abs(polar - 16.25)), 31:33, 31:33] = 1.0
    >>> m = match_stacks(Stack(frames[0], rig, 0), Stack(frames[1], rig, 1))
    >>> len(m), bool(np.abs(m.point).max() < 1e-9)
    (1, True)
    """
    from ..pipeline import reconstruct

    a, b = stack1, stack2
    if a.n_sources != b.n_sources:
        raise StereoError(f"the stacks have {a.n_sources} and {b.n_sources} frames: the cameras must see "
                          "the same sources, one frame each", field="stacks")
    if not (np.array_equal(a.rig.source_positions, b.rig.source_positions)
            and np.array_equal(a.rig.source_distant, b.rig.source_distant)):
        raise StereoError("the two stacks' rigs have different sources: stereo needs one source array "
                          "seen by both cameras", field="rig.source_positions")
    rig = a.rig if rig is None else rig
    if len(rig.cameras) < 2:
        raise StereoError("the rig has one camera; stereo needs two", field="rig.cameras")
    if a.camera_index == b.camera_index:
        raise StereoError(f"both stacks come from camera {a.camera_index}", field="camera_index")
    if tables is None:
        tables = [reconstruct(s, detect, models=()).table for s in (a, b)]
    rays = [HighlightRays.from_table(t, rig, s.camera_index) for t, s in zip(tables, (a, b))]
    return match_highlights(rays[0], rays[1], rig, params)
