"""Scoring recovered normals against ground truth.

Every statistic is reduced over an explicit valid set: highlights whose image
point lies on the object (all four pixel centres around it inside the truth
mask) and whose recovered normal is finite. Nothing outside it is averaged
in, and the number kept and dropped is reported.

numpy, and scipy's k-d tree for distances to a truth surface.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .conventions import angle_between, elevation_from_x, normalize

__all__ = [
    "sample_truth",
    "angular_error_deg",
    "error_stats",
    "percent_error",
    "nearest_point_to_lines",
    "score_normals",
    "score_reconstruction",
    "TruthSurface",
    "distance_stats",
    "matchable_highlights",
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


def error_stats(errors_deg):
    """Summary statistics of angular errors over the finite entries.

    Returns
    -------
    dict
        ``n``, ``mean_deg``, ``median_deg``, ``p95_deg``, ``max_deg``, ``rms_deg``
        (NaN statistics when ``n == 0``).
    """
    e = np.asarray(errors_deg, dtype=float)
    e = e[np.isfinite(e)]
    if e.size == 0:
        nan = float("nan")
        return {"n": 0, "mean_deg": nan, "median_deg": nan, "p95_deg": nan, "max_deg": nan, "rms_deg": nan}
    return {
        "n": int(e.size),
        "mean_deg": float(e.mean()),
        "median_deg": float(np.median(e)),
        "p95_deg": float(np.percentile(e, 95)),
        "max_deg": float(e.max()),
        "rms_deg": float(np.sqrt(np.mean(e**2))),
    }


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
    pct = pct[np.isfinite(pct)]
    out["percent_mean"] = float(pct.mean()) if pct.size else float("nan")
    out["percent_median"] = float(np.median(pct)) if pct.size else float("nan")
    out["percent_max"] = float(pct.max()) if pct.size else float("nan")
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
    """
    t = recon.table
    return {m: score_normals(t["row"], t["col"], n, truth, **kwargs) for m, n in recon.normals.items()}


# -- scoring 3-D points (structured-highlight stereo) ------------------------------

class TruthSurface:
    """The visible true surface as dense samples: every on-object pixel centre of one or more truths.

    Used to score reconstructed 3-D points: :meth:`nearest` gives each
    point's distance to the surface and the true normal at its foot.

    Parameters
    ----------
    truths : sequence of shinysim.io.Truth
        Truth of each camera (their samples are pooled, so a point seen by
        either camera is near a sample).
    spacing_mm : float
        Largest distance between neighbouring samples on the surface (about
        one pixel-equivalent, more on surfaces seen at a grazing angle).
    """

    def __init__(self, truths, *, spacing_mm: float):
        pts, nrm, part = [], [], []
        for t in truths:
            m = t.mask & np.all(np.isfinite(t.positions), axis=-1) & np.all(np.isfinite(t.normals), axis=-1)
            pts.append(t.positions[m].astype(float))
            nrm.append(normalize(t.normals[m].astype(float)))
            names = list(t.part_names)
            part.append(np.array([names[i] for i in t.part[m]], dtype=object))
        self.points = np.concatenate(pts) if pts else np.zeros((0, 3))
        self.normals = np.concatenate(nrm) if nrm else np.zeros((0, 3))
        self.parts = np.concatenate(part) if part else np.zeros(0, dtype=object)
        self.spacing_mm = float(spacing_mm)
        self._tree = cKDTree(self.points) if len(self.points) else None

    def nearest(self, points):
        """Distance of each point to the surface, and the surface normal and part at its foot.

        The distance is measured to the tangent plane of the nearest sample
        (exact to second order in the sample spacing on a smooth surface)
        while the foot lies within two sample spacings of that sample, and
        to the sample itself beyond that (a point off the edge of the
        visible surface, or far from it).

        Returns
        -------
        distance : (N,) ndarray, millimetres (NaN for non-finite points)
        normal : (N, 3) ndarray
        part : (N,) object ndarray (part name; None where no sample)
        """
        p = np.asarray(points, float).reshape(-1, 3)
        n = len(p)
        dist = np.full(n, np.nan)
        normal = np.full((n, 3), np.nan)
        part = np.full(n, None, dtype=object)
        ok = np.all(np.isfinite(p), axis=1)
        if self._tree is None or not ok.any():
            return dist, normal, part
        _, j = self._tree.query(p[ok])
        d = p[ok] - self.points[j]
        along = np.einsum("ij,ij->i", d, self.normals[j])
        tangential = np.sqrt(np.clip(np.einsum("ij,ij->i", d, d) - along**2, 0.0, None))
        dist[ok] = np.where(tangential <= 2.0 * self.spacing_mm, np.abs(along), np.linalg.norm(d, axis=1))
        normal[ok] = self.normals[j]
        part[ok] = self.parts[j]
        return dist, normal, part


def distance_stats(distances_mm, pixel_mm):
    """Median, 95th percentile and maximum of point distances, in micrometres and pixel-equivalents.

    Returns
    -------
    dict
        ``n``, ``median``, ``p95``, ``max`` (micrometres) and ``median_px``,
        ``p95_px``, ``max_px`` (in units of ``pixel_mm``, the camera's pixel
        pitch at its target).
    """
    d = np.asarray(distances_mm, float)
    d = d[np.isfinite(d)]
    out = {"n": int(d.size)}
    for name, f in (("median", np.median), ("p95", lambda x: np.percentile(x, 95)), ("max", np.max)):
        v = float(f(d)) if d.size else float("nan")
        out[name] = 1e3 * v
        out[f"{name}_px"] = v / pixel_mm
    return out


def matchable_highlights(points1, parts1, points2, parts2, *, eps_mm):
    """Which highlights of camera 1 have a highlight of camera 2 on (nearly) the same surface element.

    A highlight's element is the true surface point at its centroid. A
    camera-1 highlight is *matchable* when some camera-2 highlight's
    element lies within ``eps_mm`` of its own on the same part: only then
    can a stereo pair of highlights stand for one surface element.

    Parameters
    ----------
    points1, points2 : (N1, 3), (N2, 3) array_like, millimetres
        True elements (NaN where a centroid is off the object).
    parts1, parts2 : (N1,), (N2,) array_like
        Part of each element.
    eps_mm : float

    Returns
    -------
    matchable : (N1,) bool
    partner : (N1,) int
        Index of the nearest same-part camera-2 element (-1 when none).
    gap_mm : (N1,) float
        Distance to it.
    """
    p1 = np.asarray(points1, float).reshape(-1, 3)
    p2 = np.asarray(points2, float).reshape(-1, 3)
    parts1 = np.asarray(parts1, dtype=object)
    parts2 = np.asarray(parts2, dtype=object)
    n1 = len(p1)
    partner = np.full(n1, -1)
    gap = np.full(n1, np.inf)
    ok2 = np.all(np.isfinite(p2), axis=1)
    ok1 = np.all(np.isfinite(p1), axis=1)
    for name in set(parts1[ok1].tolist()):
        sel2 = np.flatnonzero(ok2 & (parts2 == name))
        sel1 = np.flatnonzero(ok1 & (parts1 == name))
        if not len(sel2) or not len(sel1):
            continue
        d, j = cKDTree(p2[sel2]).query(p1[sel1])
        gap[sel1] = d
        partner[sel1] = sel2[j]
    return gap <= eps_mm, partner, gap
