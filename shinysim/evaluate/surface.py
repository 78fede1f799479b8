"""Scoring 3-D points against the true surface (structured-highlight stereo): distances to it, matchable pairs.

numpy, and scipy's k-d tree.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..conventions import normalize
from .normals import sample_truth

__all__ = ["TruthSurface", "matchable_highlights"]


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
    cameras : sequence of Camera, optional
        The camera of each truth. With them the normal at a point's foot is
        interpolated in the truth image it came from (:func:`sample_truth`
        at the foot's projection), not the nearest sample's: on a curved
        surface that removes an error of up to half a pixel's turn of the
        normal.
    """

    def __init__(self, truths, *, spacing_mm: float, cameras=None):
        pts, nrm, part, which = [], [], [], []
        self.truths = list(truths)
        self.cameras = None if cameras is None else list(cameras)[:len(self.truths)]
        for k, t in enumerate(self.truths):
            m = t.mask & np.all(np.isfinite(t.positions), axis=-1) & np.all(np.isfinite(t.normals), axis=-1)
            pts.append(t.positions[m].astype(float))
            nrm.append(normalize(t.normals[m].astype(float)))
            names = list(t.part_names)
            part.append(np.array([names[i] for i in t.part[m]], dtype=object))
            which.append(np.full(int(m.sum()), k))
        self.truth_of = np.concatenate(which) if which else np.zeros(0, int)
        self.points = np.concatenate(pts) if pts else np.zeros((0, 3))
        self.normals = np.concatenate(nrm) if nrm else np.zeros((0, 3))
        self.parts = np.concatenate(part) if part else np.zeros(0, dtype=object)
        self.spacing_mm = float(spacing_mm)
        self._tree = cKDTree(self.points) if len(self.points) else None

    def nearest(self, points, *, with_sample: bool = False):
        """Distance of each point to the surface, and the surface normal and part at its foot.

        The distance is measured to the tangent plane of the nearest sample
        (exact to second order in the sample spacing on a smooth surface; with
        ``cameras``, to that of the truth interpolated at its foot)
        while the foot lies within two sample spacings of that sample, and
        to the sample itself beyond that (a point off the edge of the
        visible surface, or far from it).

        Returns
        -------
        distance : (N,) ndarray, millimetres (NaN for non-finite points)
        normal : (N, 3) ndarray
        part : (N,) object ndarray (part name; None where no sample)
        sample : (N, 3) ndarray
            With ``with_sample``: the nearest sample (NaN where none).
        """
        p = np.asarray(points, float).reshape(-1, 3)
        n = len(p)
        dist = np.full(n, np.nan)
        normal = np.full((n, 3), np.nan)
        part = np.full(n, None, dtype=object)
        sample = np.full((n, 3), np.nan)
        ok = np.all(np.isfinite(p), axis=1)
        if self._tree is None or not ok.any():
            return (dist, normal, part, sample) if with_sample else (dist, normal, part)
        _, j = self._tree.query(p[ok])
        d = p[ok] - self.points[j]
        foot_n = self.normals[j]
        along = np.einsum("ij,ij->i", d, foot_n)
        tangential = np.sqrt(np.clip(np.einsum("ij,ij->i", d, d) - along**2, 0.0, None))
        near = tangential <= 2.0 * self.spacing_mm
        if self.cameras is not None:
            foot_n = foot_n.copy()
            foot = p[ok] - along[:, None] * foot_n
            for k, (truth, cam) in enumerate(zip(self.truths, self.cameras)):
                sel = np.flatnonzero(near & (self.truth_of[j] == k))
                if not len(sel):
                    continue
                n_i, p_i, valid = sample_truth(truth, *cam.project(foot[sel]))
                sel, n_i, p_i = sel[valid], n_i[valid], p_i[valid]
                foot_n[sel] = n_i
                along[sel] = np.einsum("ij,ij->i", p[ok][sel] - p_i, n_i)
        dist[ok] = np.where(near, np.abs(along), np.linalg.norm(d, axis=1))
        normal[ok] = foot_n
        part[ok] = self.parts[j]
        sample[ok] = self.points[j]
        return (dist, normal, part, sample) if with_sample else (dist, normal, part)


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
