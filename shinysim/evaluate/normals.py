"""Scoring recovered normals against ground truth.

Every statistic is reduced over an explicit valid set: highlights whose image
point lies on the object (all four pixel centres around it inside the truth
mask) and whose recovered normal is finite. Nothing outside it is averaged
in, and the number kept and dropped is reported.
"""

from __future__ import annotations

import numpy as np

from ..conventions import angle_between, elevation_from_x, normalize
from .stats import error_stats, summary_stats

__all__ = [
    "sample_truth",
    "angular_error_deg",
    "percent_error",
    "nearest_point_to_lines",
    "score_normals",
    "score_reconstruction",
]


def sample_truth(truth, rows, cols):
    """Bilinearly interpolate truth normals and positions at image points.

    Parameters
    ----------
    truth : shinysim.io.Truth
    rows, cols : (N,) array_like
        Continuous pixel coordinates (pixel centres at integers).

    Returns
    -------
    normals : (N, 3) ndarray
        Unit normals (renormalised after interpolation); NaN where invalid.
    positions : (N, 3) ndarray, millimetres
    valid : (N,) bool
        All four surrounding pixel centres are on the object (and, where the
        truth has parts, on one part), so the interpolation does not mix in
        the background or a different surface.
    """
    rows = np.asarray(rows, dtype=float)
    cols = np.asarray(cols, dtype=float)
    H, W = truth.mask.shape
    r0 = np.floor(rows).astype(int)
    c0 = np.floor(cols).astype(int)
    inside = (r0 >= 0) & (c0 >= 0) & (r0 + 1 < H) & (c0 + 1 < W) & np.isfinite(rows) & np.isfinite(cols)
    r0 = np.where(inside, r0, 0)
    c0 = np.where(inside, c0, 0)
    fr = np.where(inside, rows - r0, 0.0)[:, None]
    fc = np.where(inside, cols - c0, 0.0)[:, None]
    corners = [(r0, c0), (r0, c0 + 1), (r0 + 1, c0), (r0 + 1, c0 + 1)]
    valid = inside.copy()
    parts = [truth.part[r, c] for r, c in corners]
    for (r, c), p in zip(corners, parts):
        valid &= truth.mask[r, c] & (p == parts[0])
    w = [(1 - fr) * (1 - fc), (1 - fr) * fc, fr * (1 - fc), fr * fc]
    n = sum(wi * truth.normals[r, c] for wi, (r, c) in zip(w, corners))
    p = sum(wi * truth.positions[r, c] for wi, (r, c) in zip(w, corners))
    n = normalize(n)
    n[~valid] = np.nan
    p[~valid] = np.nan
    return n, p, valid


def angular_error_deg(estimated, true):
    """Angle between (..., 3) normals, degrees (NaN propagates)."""
    return np.degrees(angle_between(normalize(estimated), normalize(true)))


def percent_error(estimated, true):
    """The paper's percentage error of a normal (Eqs 15-17, Figs. 5-6).

    ``100 * |Theta_est - Theta_true| / Theta_true`` with ``Theta`` the
    angle of the normal in the x-z plane measured from the horizontal +x
    axis (:func:`shinysim.conventions.elevation_from_x`), the angle the
    paper's camera-model analysis uses. A normal pointing straight up has
    ``Theta = 90 deg``, so 1 % there is 0.9 deg.
    """
    te = elevation_from_x(estimated)
    tt = elevation_from_x(true)
    with np.errstate(divide="ignore", invalid="ignore"):
        return 100.0 * np.abs(te - tt) / np.abs(tt)


def nearest_point_to_lines(points, directions):
    """Least-squares point nearest to a set of 3-D lines (paper Fig. 10).

    Minimises the sum of squared perpendicular distances to the lines
    ``points[i] + s * directions[i]``.

    Returns
    -------
    point : (3,) ndarray
    rms_distance : float
        RMS perpendicular distance of the point to the lines.
    """
    p = np.asarray(points, float).reshape(-1, 3)
    d = normalize(np.asarray(directions, float).reshape(-1, 3))
    keep = np.all(np.isfinite(p), axis=1) & np.all(np.isfinite(d), axis=1)
    p, d = p[keep], d[keep]
    if len(p) < 2:
        return np.full(3, np.nan), float("nan")
    proj = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    A = proj.sum(axis=0)
    b = np.einsum("nij,nj->i", proj, p)
    x = np.linalg.lstsq(A, b, rcond=None)[0]
    resid = np.einsum("nij,nj->ni", proj, x - p)
    return x, float(np.sqrt(np.mean(np.sum(resid**2, axis=1))))


def score_normals(rows, cols, normals, truth, *, sphere_center=None, sphere_radius=None):
    """Score one set of recovered normals against truth.

    Parameters
    ----------
    rows, cols : (N,) array_like
        Highlight centroids.
    normals : (N, 3) array_like
        Recovered unit normals.
    truth : shinysim.io.Truth
    sphere_center : (3,) array_like, optional
        With ``sphere_radius``: also run the test of paper Fig. 10, the point
        nearest to all recovered normal lines (each through the true surface
        point of its highlight) against the true centre.
    sphere_radius : float, optional

    Returns
    -------
    dict
        The statistics of :func:`error_stats`, ``n_highlights``,
        ``n_invalid`` (highlights off the object), percentage-error
        statistics ``percent_mean``/``percent_median``/``percent_max``, and
        with a sphere ``centre_error_mm`` and ``centre_error_percent_radius``.
    """
    normals = np.asarray(normals, dtype=float).reshape(-1, 3)
    true_n, true_p, valid = sample_truth(truth, rows, cols)
    valid &= np.all(np.isfinite(normals), axis=1)
    err = angular_error_deg(normals[valid], true_n[valid])
    out = error_stats(err)
    out["n_highlights"] = int(len(normals))
    out["n_invalid"] = int(len(normals) - valid.sum())
    pct = percent_error(normals[valid], true_n[valid])
    out.update(summary_stats(pct, ("mean", "median", "max"), key="percent_{}"))
    if sphere_center is not None and sphere_radius is not None:
        centre, rms = nearest_point_to_lines(true_p[valid], normals[valid])
        dist = float(np.linalg.norm(centre - np.asarray(sphere_center, float)))
        out["centre_estimate_mm"] = centre.tolist()
        out["centre_error_mm"] = dist
        out["centre_error_percent_radius"] = 100.0 * dist / float(sphere_radius)
        out["centre_line_rms_mm"] = rms
    out["errors_deg"] = err.tolist()
    return out


def score_reconstruction(recon, truth, **kwargs):
    """:func:`score_normals` for every camera model of a reconstruction.

    Returns
    -------
    dict of model name -> dict

    Examples
    --------
    The spots of :func:`shinysim.recon.pipeline.reconstruct`'s example,
    scored against the sphere's exact truth (each pixel-centre ray met with
    the sphere). The models put each highlight on the reference plane
    ``z = 0``, 0.6-0.8 mm below the sphere's highlights (and the
    orthographic and fixed models simplify the camera too), hence errors of
    a few tenths of a degree:

    >>> import numpy as np
    >>> from shinysim.io import Stack, Truth
    >>> from shinysim.recon import reconstruct
    >>> from shinysim.rig import shiny_1988
    >>> from shinysim.theory.mirror import mirror_sphere_highlight
    >>> R = 0.79375
    >>> rig = shiny_1988(resolution=128)
    >>> point, _ = mirror_sphere_highlight(rig.source_positions, radius=R, camera_position=rig.camera.position)
    >>> row, col = rig.camera.project(point)
    >>> r, c = np.mgrid[:128, :128]
    >>> frames = np.exp(-((r - row[:, None, None]) ** 2 + (c - col[:, None, None]) ** 2) / 2)
    >>> recon = reconstruct(Stack(frames, rig), threshold=1e-9, false_alarm=0)
    >>> o, d = rig.camera.pixel_rays(r, c)
    >>> b = np.sum(o * d, axis=-1)
    >>> disc = b**2 - np.sum(o * o, axis=-1) + R**2
    >>> hit = disc > 0
    >>> p = np.where(hit[..., None], o - (b + np.sqrt(np.where(hit, disc, 0)))[..., None] * d, np.nan)
    >>> score = score_reconstruction(recon, Truth(p / R, p, hit))
    >>> {m: (s["n"], round(s["max_deg"], 2)) for m, s in score.items()}
    {'perspective': (21, 0.41), 'orthographic': (21, 0.31), 'fixed': (21, 0.24)}
    """
    t = recon.table
    return {m: score_normals(t["row"], t["col"], n, truth, **kwargs) for m, n in recon.normals.items()}
