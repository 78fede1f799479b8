r"""Profiles ``z(x)`` from sparse surface normals: the paper's procedure (Section IV).

:func:`profile_from_normals` maps the normals of one cross-section into a
1-D array sorted by x, merges near-duplicates, joins neighbours close in
distance and angle by the **circular arc** tangent to both normals (its rise
is :func:`arc_rise`, the rule every integrator of the package uses; the arc
itself :func:`circular_arc`), starts a new segment of unknown relative
height at a discontinuity, smooths on a regular grid, and pins the segment
nearest an anchor ``(x_a, z_a)`` by circular extrapolation. A circle, a line
and any profile made of them sampled at its ends is reproduced exactly. The
paper's words, each step and its settings: ``docs/solder.md``, "Profile
reconstruction". It is the ``"profile"`` method of
:func:`shinysim.recon.integrate.integrate`.

Frames, units and gradient conventions are those of
:mod:`shinysim.conventions` (millimetres, radians, ``n ~ (-p, -q, 1)``).
numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._shared import check_number, with_overrides
from ..conventions import normal_from_gradient
from ..errors import OptionError

__all__ = [
    "ProfileParams",
    "Profile",
    "slope_angle_from_normal",
    "arc_rise",
    "circular_arc",
    "profile_from_normals",
    "predict_slope_angle",
    "arc_from_curvature",
    "end_curvature",
]


def slope_angle_from_normal(normals):
    """Slope angle ``phi = atan(dz/dx)`` in the x-z plane of (..., 3) normals.

    The y component is ignored (the normal is projected onto the x-z plane):
    ``phi = atan2(-nx, nz)``, radians, in (-pi/2, pi/2) for normals facing
    up; NaN where ``nz <= 0`` or the normal is NaN.
    """
    n = np.asarray(normals, dtype=float)
    nx, nz = n[..., 0], n[..., 2]
    with np.errstate(invalid="ignore"):
        phi = np.arctan2(-nx, nz)
    return np.where(nz > 0, phi, np.nan)


def arc_rise(run, phi0, phi1):
    """Height change along the circular arc between two tangents: the paper's circular rule.

    The one home of the rule; every integrator that joins two normals by an
    arc calls it (:func:`shinysim.recon.integrate.edge_rise`, the
    near-field model, :func:`profile_from_normals`).

    Parameters
    ----------
    run : array_like, mm
        Horizontal distance from the first point to the second.
    phi0, phi1 : array_like, radians
        Slope angles (``tan(phi) = dz/ds`` along the run) at the two ends.

    Returns
    -------
    ndarray, mm
        ``run * tan((phi0 + phi1) / 2)``: the rise of the arc whose tangent
        angle runs linearly with arc length from ``phi0`` to ``phi1``. Exact
        on circles and lines (and so along every vertical section of a
        sphere or a plane), second-order accurate on any smooth curve.
    """
    return np.asarray(run, float) * np.tan(0.5 * (np.asarray(phi0, float) + np.asarray(phi1, float)))


def circular_arc(x0, z0, phi0, x1, phi1, x):
    """Height and slope angle on the circular arc between two tangents.

    Parameters
    ----------
    x0, z0 : float, mm
        Start point.
    phi0, phi1 : float, radians
        Slope angles (tangent elevations) at ``x0`` and ``x1``.
    x1 : float, mm
        End abscissa (may be less than ``x0``).
    x : array_like, mm
        Where to evaluate (may lie outside ``[x0, x1]``: extrapolation along
        the same circle, NaN where the circle has no point at that x).

    Returns
    -------
    z : ndarray, mm
    phi : ndarray, radians
    """
    x = np.asarray(x, dtype=float)
    dx = x1 - x0
    s0, s1 = np.sin(phi0), np.sin(phi1)
    kappa = 0.0 if dx == 0 else (s1 - s0) / dx
    if abs(kappa) * max(abs(dx), 1e-12) < 1e-12 or abs(s1 - s0) < 1e-12:
        # a straight line (or a zero-length pair)
        phi = np.full_like(x, 0.5 * (phi0 + phi1))
        return z0 + (x - x0) * np.tan(phi), phi
    return arc_from_curvature(x0, z0, phi0, kappa, x)


def arc_from_curvature(x0, z0, phi0, kappa, x):
    """Height and slope angle along the circle through ``(x0, z0)`` with slope
    angle ``phi0`` and ``d(sin phi)/dx = kappa`` (its curvature, signed).

    Returns ``(z, phi)`` at ``x``; NaN where the circle has no point at that x.
    """
    x = np.asarray(x, dtype=float)
    if abs(kappa) < 1e-12:
        return z0 + (x - x0) * np.tan(phi0), np.full_like(x, phi0)
    s = np.sin(phi0) + kappa * (x - x0)
    ok = np.abs(s) < 1.0
    phi = np.where(ok, np.arcsin(np.clip(s, -1.0, 1.0)), np.nan)
    return z0 + (np.cos(phi0) - np.cos(phi)) / kappa, phi


def end_curvature(x, phi, end, n_fit):
    """Curvature ``d(sin phi)/dx`` of the circle fitted to a segment's end.

    Least squares over the ``n_fit`` points nearest the ``end`` ("left" or
    "right") of sorted ``x``: on a circle ``sin phi`` is linear in x, so
    the slope of that line is the curvature. One point gives 0 (a line).
    """
    x = np.asarray(x, float)
    phi = np.asarray(phi, float)
    if len(x) < 2:
        return 0.0
    k = min(max(2, int(n_fit)), len(x))
    sl = slice(0, k) if end == "left" else slice(len(x) - k, len(x))
    xs, ss = x[sl], np.sin(phi[sl])
    if np.ptp(xs) <= 0:
        return 0.0
    return float(np.polyfit(xs, ss, 1)[0])


@dataclass(frozen=True)
class ProfileParams:
    """Settings of :func:`profile_from_normals`.

    Parameters
    ----------
    max_gap_mm : float
        Neighbours further apart along x are not joined (discontinuity).
    max_angle_deg : float
        Neighbours whose normals differ by more are not joined.
    merge_mm : float
        Points closer than this along x (and within ``max_angle_deg``) are
        merged into their weighted mean (several highlights of one surface
        patch, e.g. the parts of a subdivided blob in one cross-section band).
    smooth_mm : float
        Width of the local smoothing window for ``z`` on the grid (0: none).
        Windows shrink symmetrically at segment ends, so a straight or
        circular profile is not pulled at its ends.
    step_mm : float
        Grid spacing of the output.
    anchor_gap_mm : float or None
        Largest distance from the anchor to the nearest segment end for the
        anchor to pin it (None: ``max_gap_mm``).
    end_fit_points : int
        Points at a segment's end that fix the circle continued beyond it
        (to the anchor, or for :func:`predict_slope_angle`): least squares
        of ``sin(phi)`` against x; 2 is the circle through the end pair.
    """

    max_gap_mm: float = 0.06
    max_angle_deg: float = 15.0
    merge_mm: float = 0.002
    smooth_mm: float = 0.0
    step_mm: float = 0.001
    anchor_gap_mm: float | None = None
    end_fit_points: int = 3

    def __post_init__(self):
        for name in ("max_gap_mm", "max_angle_deg", "step_mm"):
            check_number(name, getattr(self, name), lo=0, lo_open=True)
        for name in ("merge_mm", "smooth_mm"):
            check_number(name, getattr(self, name), lo=0)
        if self.anchor_gap_mm is not None:
            check_number("anchor_gap_mm", self.anchor_gap_mm, lo=0)
        check_number("end_fit_points", self.end_fit_points, lo=2, integer=True)


@dataclass
class Profile:
    """A reconstructed cross-section.

    Attributes
    ----------
    x : (M,) float, mm
        Regular grid (``step_mm``) from the first to the last reconstructed x.
    z : (M,) float, mm
        Height; NaN in gaps (discontinuities) and outside the segments.
    phi : (M,) float, radians
        Slope angle of the interpolated profile; NaN where ``z`` is.
    segment : (M,) int
        Segment index per grid point, -1 in gaps.
    extrapolated : (M,) bool
        Grid points reached only by the circular extrapolation to the anchor.
    anchored : (S,) bool
        Per segment: True when its absolute height is known (pinned by the
        anchor); False when only its shape is (relative height unknown; its
        first point is put at ``z = 0``).
    points : dict of (K,) ndarray
        The merged measured points: ``x``, ``phi``, ``z``, ``weight``,
        ``segment``, ``count`` (measurements merged into each).
    segments : (S, 2) float, mm
        ``[x_start, x_end]`` of each segment (including extrapolation).
    anchor : tuple or None
        ``(x_a, z_a)`` as given.
    params : ProfileParams
    """

    x: np.ndarray
    z: np.ndarray
    phi: np.ndarray
    segment: np.ndarray
    extrapolated: np.ndarray
    anchored: np.ndarray
    points: dict
    segments: np.ndarray
    anchor: tuple | None = None
    params: ProfileParams = field(default_factory=ProfileParams)

    @property
    def n_segments(self):
        return len(self.anchored)

    @property
    def gaps(self):
        """(G, 2) float, mm: x-intervals between consecutive segments."""
        if len(self.segments) < 2:
            return np.zeros((0, 2))
        s = self.segments[np.argsort(self.segments[:, 0])]
        return np.column_stack([s[:-1, 1], s[1:, 0]])

    def z_at(self, x, *, anchored_only=False):
        """Height at ``x`` by linear interpolation on the grid; NaN in gaps.

        ``anchored_only=True`` also gives NaN on segments whose absolute
        height is unknown.
        """
        x = np.asarray(x, dtype=float)
        z = self.z
        if anchored_only and len(self.anchored):
            seg_ok = np.zeros(len(z), bool)
            good = self.segment >= 0
            seg_ok[good] = self.anchored[self.segment[good]]
            z = np.where(seg_ok, z, np.nan)
        if len(self.x) == 0:
            return np.full(x.shape, np.nan)
        out = np.interp(x, self.x, z, left=np.nan, right=np.nan)
        # no interpolation across a gap: both neighbours must be valid
        if len(self.x) > 1:
            i = np.clip(np.searchsorted(self.x, x), 1, len(self.x) - 1)
        else:  # a one-point profile: both neighbours are that point
            i = np.ones(x.shape, int)
        below = i - 1
        i = np.minimum(i, len(self.x) - 1)
        both = np.isfinite(z[below]) & np.isfinite(z[i])
        out = np.where(both, out, np.nan)
        # within one grid step of a segment's last grid point: continue along its slope
        step = self.params.step_mm
        for j in (below, i):
            near = ~np.isfinite(out) & np.isfinite(z[j]) & (np.abs(x - self.x[j]) <= step)
            out = np.where(near, z[j] + (x - self.x[j]) * np.tan(self.phi[j]), out)
        return out

    def normal_at(self, x):
        """(..., 3) unit normals of the interpolated profile at ``x`` (NaN in gaps)."""
        x = np.asarray(x, dtype=float)
        if len(self.x) == 0:
            return np.full(x.shape + (3,), np.nan)
        phi = np.interp(x, self.x, self.phi, left=np.nan, right=np.nan)
        return normal_from_gradient(np.tan(phi), np.zeros_like(phi))


def _check_weights(weights, n):
    """(n,) float weights (None: all 1), or OptionError naming ``weights`` for another shape or a negative one."""
    w = np.ones(n) if weights is None else np.asarray(weights, dtype=float).reshape(-1)
    if w.shape != (n,):
        raise OptionError(f"must have shape ({n},), got {w.shape}", field="weights")
    if np.any(w[np.isfinite(w)] < 0):
        raise OptionError("must be >= 0", field="weights")
    return w


def _merge(x, phi, w, merge_mm, max_angle):
    """Greedy clustering of sorted points: weighted means of x and phi."""
    groups = []
    start = 0
    for i in range(1, len(x) + 1):
        if i == len(x) or x[i] - x[start] > merge_mm or abs(phi[i] - phi[start]) > max_angle:
            groups.append(np.arange(start, i))
            start = i
    mx = np.array([np.average(x[g], weights=w[g]) for g in groups])
    mp = np.array([np.average(phi[g], weights=w[g]) for g in groups])
    mw = np.array([w[g].sum() for g in groups])
    count = np.array([len(g) for g in groups])
    return mx, mp, mw, count


def _smooth(z, half):
    """Symmetric moving average with windows shrinking at the ends."""
    n = len(z)
    if half <= 0 or n < 3:
        return z
    c = np.concatenate([[0.0], np.cumsum(z)])
    i = np.arange(n)
    h = np.minimum(half, np.minimum(i, n - 1 - i))
    return (c[i + h + 1] - c[i - h]) / (2 * h + 1)


def profile_from_normals(x, normals, *, weights=None, anchor=None, params=None, **kwargs):
    """Reconstruct one cross-section profile from sparse normals (paper Sec. IV).

    Parameters
    ----------
    x : (N,) array_like, mm
        Position of each measured normal along the cross-section.
    normals : (N, 3) array_like
        Unit surface normals (world frame); only their x-z components count
        (:func:`slope_angle_from_normal`). Non-finite rows are dropped.
    weights : (N,) array_like, optional
        Weights for merging (e.g. highlight intensity sums); default 1.
    anchor : (float, float), optional
        ``(x_a, z_a)``: a point of known height, mm (``docs/solder.md``,
        "Profile reconstruction", anchoring).
    params : ProfileParams, optional
        Keyword arguments override single fields.

    Returns
    -------
    Profile

    Raises
    ------
    OptionError
        On mismatched shapes, negative weights or a malformed anchor.
    """
    params = with_overrides(ProfileParams, params, kwargs)
    x = np.asarray(x, dtype=float).reshape(-1)
    normals = np.asarray(normals, dtype=float)
    if normals.shape != (len(x), 3):
        raise OptionError(f"must have shape ({len(x)}, 3) to match x, got {normals.shape}", field="normals")
    w = _check_weights(weights, len(x))
    if anchor is not None:
        anchor = tuple(float(a) for a in anchor)
        if len(anchor) != 2 or not all(np.isfinite(anchor)):
            raise OptionError(f"must be (x_a, z_a), two finite numbers, got {anchor!r}", field="anchor")
    phi = slope_angle_from_normal(normals)
    keep = np.isfinite(x) & np.isfinite(phi) & np.isfinite(w) & (w > 0)
    x, phi, w = x[keep], phi[keep], w[keep]
    max_angle = np.radians(params.max_angle_deg)
    empty = Profile(np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0, int), np.zeros(0, bool),
                    np.zeros(0, bool),
                    {k: np.zeros(0) for k in ("x", "phi", "z", "weight", "segment", "count")},
                    np.zeros((0, 2)), anchor, params)
    if len(x) == 0:
        return empty
    order = np.argsort(x, kind="stable")
    px, pphi, pw, count = _merge(x[order], phi[order], w[order], params.merge_mm, max_angle)
    # segments: break where neighbours are too far apart in x or in angle
    brk = (np.diff(px) > params.max_gap_mm) | (np.abs(np.diff(pphi)) > max_angle)
    seg_of_point = np.concatenate([[0], np.cumsum(brk)])
    n_seg = int(seg_of_point[-1]) + 1
    # heights: the arc rule between neighbours, summed along each segment from 0 at its first point
    rise = arc_rise(np.diff(px), pphi[:-1], pphi[1:])
    pz = np.zeros(len(px))
    for s in range(n_seg):
        idx = np.flatnonzero(seg_of_point == s)
        pz[idx[1:]] = np.cumsum(rise[idx[:-1]])
    # anchoring: the segment end nearest to the anchor
    anchored = np.zeros(n_seg, bool)
    extent = np.array([[px[seg_of_point == s].min(), px[seg_of_point == s].max()] for s in range(n_seg)])
    extra = None  # (segment, x_from, x_to, z-function)
    if anchor is not None:
        xa, za = anchor
        gap_ok = params.max_gap_mm if params.anchor_gap_mm is None else params.anchor_gap_mm
        dist = np.minimum(np.abs(extent[:, 0] - xa), np.abs(extent[:, 1] - xa))
        inside = (extent[:, 0] <= xa) & (xa <= extent[:, 1])
        dist = np.where(inside, 0.0, dist)
        s = int(np.argmin(dist))
        if dist[s] <= gap_ok:
            idx = np.flatnonzero(seg_of_point == s)
            if inside[s]:
                za_rel = np.interp(xa, px[idx], pz[idx])
                extra = (s, None, None)
            else:
                left = xa < extent[s, 0]
                e = idx[0] if left else idx[-1]
                kappa = end_curvature(px[idx], pphi[idx], "left" if left else "right", params.end_fit_points)
                za_rel = float(arc_from_curvature(px[e], pz[e], pphi[e], kappa, xa)[0])
                if not np.isfinite(za_rel):  # the circle turns before x_a: go straight
                    kappa = 0.0
                    za_rel = float(pz[e] + (xa - px[e]) * np.tan(pphi[e]))
                extra = (s, e, kappa)
                extent[s] = [min(extent[s, 0], xa), max(extent[s, 1], xa)]
            pz[seg_of_point == s] += za - za_rel
            anchored[s] = True
    # grid
    step = params.step_mm
    x0 = extent[:, 0].min()
    n = int(np.floor((extent[:, 1].max() - x0) / step + 1e-9)) + 1
    gx = x0 + step * np.arange(n)
    gz = np.full(n, np.nan)
    gphi = np.full(n, np.nan)
    gseg = np.full(n, -1)
    gext = np.zeros(n, bool)
    for s in range(n_seg):
        idx = np.flatnonzero(seg_of_point == s)
        lo, hi = np.searchsorted(gx, extent[s, 0] - 1e-12), np.searchsorted(gx, extent[s, 1] + 1e-12)
        sel = np.arange(lo, hi)
        if len(idx) == 1:
            near = sel[np.abs(gx[sel] - px[idx[0]]) <= 0.5 * step + 1e-12] if extra is None or extra[0] != s else sel
            gz[near] = pz[idx[0]] + (gx[near] - px[idx[0]]) * np.tan(pphi[idx[0]])
            gphi[near] = pphi[idx[0]]
            gseg[near] = s
        else:
            for a, b in zip(idx[:-1], idx[1:]):
                m = sel[(gx[sel] >= px[a] - 1e-12) & (gx[sel] <= px[b] + 1e-12)]
                zz, pp = circular_arc(px[a], pz[a], pphi[a], px[b], pphi[b], gx[m])
                gz[m], gphi[m], gseg[m] = zz, pp, s
        if extra is not None and extra[0] == s and extra[1] is not None:
            _, e, kappa = extra
            m = sel[np.isnan(gz[sel])]
            zz, pp = arc_from_curvature(px[e], pz[e], pphi[e], kappa, gx[m])
            bad = ~np.isfinite(zz)
            if np.any(bad):  # beyond the circle's reach: straight continuation
                zz[bad] = pz[e] + (gx[m][bad] - px[e]) * np.tan(pphi[e])
                pp[bad] = pphi[e]
            gz[m], gphi[m], gseg[m], gext[m] = zz, pp, s, True
    if params.smooth_mm > 0:
        half = int(round(0.5 * params.smooth_mm / step))
        for s in range(n_seg):
            m = np.flatnonzero(gseg == s)
            if len(m) > 2:
                gz[m] = _smooth(gz[m], half)
    points = {"x": px, "phi": pphi, "z": pz, "weight": pw, "segment": seg_of_point, "count": count}
    return Profile(gx, gz, gphi, gseg, gext, anchored, points, extent, anchor, params)


def predict_slope_angle(profile, x, *, min_points=2):
    """Slope angle the reconstruction predicts at ``x``, radians.

    Inside a segment: the interpolated profile's slope angle. Outside every
    segment: the circle fitted to the nearest segment's end
    (:func:`end_curvature`, ``params.end_fit_points``), continued to ``x``,
    as the anchoring does. Segments with fewer than ``min_points`` points
    predict nothing.

    Returns
    -------
    phi : ndarray, radians
        NaN where no segment predicts or the circle does not reach.
    distance : ndarray, mm
        How far ``x`` lies outside the predicting segment (0 inside; inf
        where none predicts).
    """
    x = np.atleast_1d(np.asarray(x, dtype=float))
    phi = np.full(x.shape, np.nan)
    dist = np.full(x.shape, np.inf)
    pts = profile.points
    if len(pts["x"]) == 0:
        return phi, dist
    for s in range(profile.n_segments):
        idx = np.flatnonzero(pts["segment"] == s)
        if len(idx) < max(1, int(min_points)):
            continue
        xs, ps = pts["x"][idx], pts["phi"][idx]
        lo, hi = xs[0], xs[-1]
        d = np.where(x < lo, lo - x, np.where(x > hi, x - hi, 0.0))
        better = d < dist
        if not better.any():
            continue
        inside = better & (d == 0)
        if inside.any():
            phi[inside] = np.interp(x[inside], xs, ps)
            if len(profile.x):
                gp = np.interp(x[inside], profile.x, profile.phi)
                phi[inside] = np.where(np.isfinite(gp), gp, phi[inside])
        for side, sel in (("left", better & (x < lo)), ("right", better & (x > hi))):
            if sel.any():
                e = 0 if side == "left" else len(xs) - 1
                kappa = end_curvature(xs, ps, side, profile.params.end_fit_points)
                phi[sel] = arc_from_curvature(xs[e], 0.0, ps[e], kappa, x[sel])[1]
        dist = np.where(better, d, dist)
    return phi, dist
