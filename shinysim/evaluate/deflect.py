"""Mirror slopes against a reference: another tool's result at matched points, or the exact surface.

A slope difference is the length of the 2-D difference of (dz/dx, dz/dy),
in milliradians (the stricter of the usual figures: a per-axis RMS is
``1/sqrt(2)`` of it when the two axes err alike). Two comparisons are
reported, because a deflectometry result without an absolute reference
carries no absolute tilt: as computed (both aligned alike, e.g. SOFAST's
centre alignment on both sides), and ``detilted``: the difference less its
least-squares constant + linear part in (x, y) (an overall tilt and a
focal-length-like bend, which is what a pose error leaves).

numpy, and scipy's k-d tree.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .stats import summary_stats

__all__ = ["compare_matched", "compare_slopes", "detilt", "match_points", "slope_stats"]


def detilt(points_mm, values) -> np.ndarray:
    """``values`` (n, k) less their least-squares constant + linear (in x, y) part over ``points_mm`` (n, >= 2)."""
    pts = np.asarray(points_mm, float)
    v = np.asarray(values, float)
    design = np.column_stack([np.ones(len(pts)), pts[:, 0], pts[:, 1]])
    return v - design @ np.linalg.lstsq(design, v, rcond=None)[0]


def slope_stats(difference) -> dict:
    """``rms_mrad``, ``p95_mrad``, ``max_mrad``, ``n_over_1mrad`` of (n, 2) slope differences (radians)."""
    mag = 1e3 * np.linalg.norm(np.asarray(difference, float), axis=1)
    s = summary_stats(mag, ("n", "rms", "p95", "max"), key="{}_mrad")
    s.pop("n")
    s["n_over_1mrad"] = int(np.sum(mag >= 1.0))
    return s


def match_points(points_mm, ref_points_mm, match_mm: float | None = None):
    """Each point's nearest reference point in (x, y), if within ``match_mm``.

    Returns
    -------
    matched : (n,) bool
    nearest : (n,) int
        Index of the nearest finite reference point (meaningful where ``matched``).
    match_mm : float
        The radius used: given, or a quarter of the reference points' median
        nearest-neighbour spacing (two measurements of one dot lie a fraction
        of a millimetre apart; neighbouring dots a whole spacing).
    """
    p = np.asarray(points_mm, float)[:, :2]
    rp = np.asarray(ref_points_mm, float)[:, :2]
    finite = np.all(np.isfinite(p), axis=1)
    rfin = np.flatnonzero(np.all(np.isfinite(rp), axis=1))
    tree = cKDTree(rp[rfin])
    if match_mm is None:
        match_mm = 0.25 * float(np.median(tree.query(rp[rfin], k=2)[0][:, 1])) if len(rfin) > 1 else 0.0
    d, j = tree.query(np.where(finite[:, None], p, 0.0))
    return finite & (d <= match_mm), rfin[j], float(match_mm)


def compare_matched(points_mm, slopes, ref_slopes) -> dict:
    """:func:`compare_slopes`'s figures for slopes already paired one to one (the same pixels of two tools).

    Returns
    -------
    dict
        ``matched`` and the :func:`slope_stats` of the differences, and ``detilted``.
    """
    p = np.asarray(points_mm, float)
    diff = np.asarray(slopes, float) - np.asarray(ref_slopes, float)
    ok = np.all(np.isfinite(diff), axis=1) & np.all(np.isfinite(p[:, :2]), axis=1)
    out = {"matched": int(ok.sum()), **slope_stats(diff[ok])}
    out["detilted"] = slope_stats(detilt(p[ok], diff[ok])) if ok.sum() >= 3 else slope_stats(np.zeros((0, 2)))
    return out


def compare_slopes(points_mm, slopes, ref_points_mm, ref_slopes, *, match_mm: float | None = None) -> dict:
    """Slopes at points against reference slopes at the nearest reference points.

    Parameters
    ----------
    points_mm : (n, 3) or (n, 2)
        Where the slopes were measured (facet frame; x, y are used).
    slopes : (n, 2)
        dz/dx, dz/dy.
    ref_points_mm, ref_slopes : (m, 3) or (m, 2), (m, 2)
        The reference (another tool's points and slopes in the same frame,
        or exact slopes at the same points).
    match_mm : float, optional
        A point is matched to the nearest reference point within this
        distance (default: :func:`match_points`'s).

    Returns
    -------
    dict
        ``matched`` (count), ``unmatched`` (points with no reference within
        ``match_mm``), ``match_mm``, the :func:`slope_stats` of the matched
        differences, and ``detilted``: the same four after :func:`detilt`.
    """
    p = np.asarray(points_mm, float)[:, :2]
    s = np.asarray(slopes, float)
    rs = np.asarray(ref_slopes, float)
    m, j, match_mm = match_points(points_mm, ref_points_mm, match_mm)
    m &= np.all(np.isfinite(s), axis=1) & np.all(np.isfinite(rs[j]), axis=1)
    diff = s[m] - rs[j[m]]
    out = {"matched": int(m.sum()), "unmatched": int((~m).sum()), "match_mm": float(match_mm), **slope_stats(diff)}
    out["detilted"] = slope_stats(detilt(p[m], diff)) if m.sum() >= 3 else slope_stats(np.zeros((0, 2)))
    return out
