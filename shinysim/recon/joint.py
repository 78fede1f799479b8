r"""Solder-joint analysis from a highlight stack: highlights, profile, surface, features.

:func:`analyse_joint` (settings :class:`JointAnalysisParams`, result
:class:`JointAnalysis`) finds the highlights, builds the paper's profile of
the cross-section band anchored at the toe (with a second look at flagged
highlights as pad bounces), integrates all normals into a surface, and
:func:`joint_features` summarises it for :mod:`shinysim.recon.classify`.
Image and rig information only (numpy + scikit-image), plus the pad top
height and the layout from the board's design. The steps and their reasons:
``docs/solder.md``, section "Profile reconstruction".
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._shared import check_number, with_overrides
from ..errors import OptionError
from ..io import Stack
from ..io.table import HighlightTable
from ..objects.solder import PAD_THICKNESS
from .highlights import (
    HighlightParams,
    blob_area,
    find_highlights,
    find_toe,
    normals_at_points,
)
from .profile import (
    Profile,
    ProfileParams,
    predict_slope_angle,
    profile_from_normals,
    slope_angle_from_normal,
)
from .surface import SurfaceParams, surface_from_normals

__all__ = [
    "JointAnalysisParams",
    "JointAnalysis",
    "FEATURE_NAMES",
    "analyse_joint",
    "joint_features",
]


@dataclass(frozen=True)
class JointAnalysisParams:
    """Settings of :func:`analyse_joint`.

    Parameters
    ----------
    highlight : HighlightParams
        Detection and flagging; ``max_area`` is given for a 256-pixel, 2 mm
        field and scaled with the pixel area (``scale_max_area``).
    profile : ProfileParams
    surface : SurfaceParams or None
        None skips the surface integration.
    pad_top_z : float, mm
        Height of the pad top: the plane the highlight points are put on
        and the toe's height.
    band_half_width_mm : float
        Half width of the cross-section band around ``y = 0``.
    use_mirror : bool
        Read flagged highlights on the fillet as second bounces off the pad.
    refine : bool
        Move points to their reconstructed heights and rebuild once.
    scale_max_area : bool
        Scale ``highlight.max_area`` by ``(pixels per mm / 128)^2``.
    between_band_mm : (float, float)
        y-range (of ``|y|``) between the joint's pad and its neighbour's
        (bridges) for the features: clear of both pads at every pitch and
        pad width of the classes.
    surface_half_width_mm : float
        Half width in y of the region integrated into a surface.
    flat_area_mm2 : float
        A highlight whose whole connected region covers more than this, and
        whose normal is within ``flat_max_slope_deg`` of vertical, is a flat
        surface (the pad, the lead's foot), not part of a fillet.
    flat_max_slope_deg : float
        Largest slope angle of such a flat surface. A straight but inclined
        fillet (contact angles on pad and lead alike) also lights up as one
        large region, and is kept.
    toe_margin_mm : float
        Highlights more than this on the pad side of the toe are left out.
    extend_mm : float
        Flagged highlights up to this far beyond the last direct one are
        considered for a second reading.
    reading_tol_deg, reading_tol_deg_per_mm : float
        A flagged highlight is read as direct or as a pad bounce when that
        reading's slope angle lies within ``reading_tol_deg`` (plus
        ``reading_tol_deg_per_mm`` per mm outside the profile) of the slope
        the profile of the points taken so far predicts there.
    reading_step_mm : float
        Flagged highlights are taken one at a time, nearest first, and only
        within this distance of the profile so far (each continuation of
        the end circle stays short).
    """

    highlight: HighlightParams = field(default_factory=HighlightParams)
    profile: ProfileParams = field(default_factory=lambda: ProfileParams(
        max_gap_mm=0.1, max_angle_deg=20.0, merge_mm=0.003, smooth_mm=0.004, anchor_gap_mm=0.06, end_fit_points=5))
    surface: SurfaceParams | None = field(default_factory=lambda: SurfaceParams(step_mm=0.01, smoothness=1e-3))
    pad_top_z: float = PAD_THICKNESS
    band_half_width_mm: float = 0.02
    use_mirror: bool = True
    refine: bool = True
    scale_max_area: bool = True
    between_band_mm: tuple = (0.25, 0.35)
    surface_half_width_mm: float = 0.06
    flat_area_mm2: float = 0.04
    flat_max_slope_deg: float = 10.0
    toe_margin_mm: float = 0.005
    extend_mm: float = 0.1
    reading_tol_deg: float = 6.0
    reading_tol_deg_per_mm: float = 200.0
    reading_step_mm: float = 0.12

    def __post_init__(self):
        check_number("pad_top_z", self.pad_top_z)
        check_number("band_half_width_mm", self.band_half_width_mm, lo=0, lo_open=True)
        lo, hi = self.between_band_mm
        if not hi > lo:
            raise OptionError(f"between_band_mm must be (low, high) with high > low, got {self.between_band_mm!r}")


@dataclass
class JointAnalysis:
    """What :func:`analyse_joint` found.

    Attributes
    ----------
    table : HighlightTable
        All highlights (:func:`~shinysim.recon.highlights.find_highlights`),
        plus ``mirror_normal`` ((N, 3): the normal if the light came off the
        pad), ``flat`` (part of a large flat region) and ``used`` (a member
        of a band point that entered the profile).
    points : dict
        The cross-section's 1-D array: one point per highlight region (source
        and connected region) met by the band, at the weighted mean of its
        parts in the band. Columns ``row``, ``col``, ``source``, ``sum``,
        ``rel_peak``, ``x``, ``y``, ``normal``, ``mirror_normal``,
        ``flagged`` (an inter-reflection by the flag rule), ``flat``,
        ``reading`` (0 left out, 1 direct, 2 pad bounce), ``used`` (entered
        the profile), ``x_refined``, ``z_refined``, ``normal_refined`` (at
        the reconstructed height, with the normal of its reading) and
        ``members`` (list of index arrays into ``table``).
    toe_x : float, mm
        NaN when not found (the profile is then not anchored).
    profile : Profile
    surface : Surface or None
    features : dict of str -> float
    params : JointAnalysisParams
    """

    table: HighlightTable
    points: dict
    toe_x: float
    profile: Profile
    surface: object
    features: dict
    params: JointAnalysisParams

    @property
    def band(self):
        """Indices into ``table`` of the highlights of the cross-section band."""
        return np.flatnonzero(np.abs(self.table["y"]) <= self.params.band_half_width_mm)


def _profile_pass(x, normals, weights, is_mirror, toe, params):
    """Profile from direct + mirror points; mirror points only in segments with direct ones."""
    anchor = (toe, params.pad_top_z) if np.isfinite(toe) else None
    pr = profile_from_normals(x, normals, weights=weights, anchor=anchor, params=params.profile)
    keep = np.isfinite(x) & np.isfinite(slope_angle_from_normal(normals))
    if not is_mirror.any():
        return pr, keep
    seg = np.full(len(x), -1)
    if len(pr.points["x"]):
        j = np.abs(x[keep, None] - pr.points["x"][None, :]).argmin(axis=1)
        seg[keep] = pr.points["segment"][j]
    has_direct = np.zeros(pr.n_segments, bool)
    has_direct[np.unique(seg[keep & ~is_mirror])] = True
    use = keep & (~is_mirror | ((seg >= 0) & has_direct[np.maximum(seg, 0)]))
    if use.sum() == keep.sum():
        return pr, use
    pr = profile_from_normals(x[use], normals[use], weights=weights[use], anchor=anchor, params=params.profile)
    return pr, use


def _band_points(t, band, stack, zp, dim_fraction):
    """One point per (source, region) of the band: weighted mean of its parts."""
    key = t["source"][band].astype(np.int64) * (1 << 32) + t["blob"][band].astype(np.int64)
    uniq, inv = np.unique(key, return_inverse=True)
    m = len(uniq)
    w = t["sum"][band]
    wsum = np.bincount(inv, weights=w, minlength=m)
    g = {
        "row": np.bincount(inv, weights=w * t["row"][band], minlength=m) / np.maximum(wsum, 1e-300),
        "col": np.bincount(inv, weights=w * t["col"][band], minlength=m) / np.maximum(wsum, 1e-300),
        "sum": wsum,
        "source": (uniq >> 32).astype(int),
        "members": [band[inv == i] for i in range(m)],
    }
    g["rel_peak"] = np.array([t["rel_peak"][mb].max() for mb in g["members"]]) if m else np.zeros(0)
    g["flagged"] = g["rel_peak"] < dim_fraction if m else np.zeros(0, bool)
    g["flat"] = np.array([bool(t["flat"][mb].any()) for mb in g["members"]], bool) if m else np.zeros(0, bool)
    cam = stack.camera
    p3 = cam.backproject_to_plane(g["row"], g["col"], zp).reshape(-1, 3)
    g["x"], g["y"] = p3[:, 0], p3[:, 1]
    g["normal"] = normals_at_points(p3, g["source"], stack) if m else np.zeros((0, 3))
    g["mirror_normal"] = normals_at_points(p3, g["source"], stack, mirror_z=zp) if m else np.zeros((0, 3))
    return g


def _readings(phi_pred, dist, phi_d, phi_m, params):
    """1 (direct), 2 (pad bounce) or 0 per candidate, by agreement with a prediction."""
    tol = np.radians(params.reading_tol_deg + params.reading_tol_deg_per_mm * np.where(np.isfinite(dist), dist, 0))
    ed, em = (np.abs(phi - phi_pred) for phi in (phi_d, phi_m))
    ed, em = (np.where(np.isfinite(e), e, np.inf) for e in (ed, em))
    out = np.zeros(len(phi_d), int)
    out[(ed <= em) & (ed < tol)] = 1
    out[(em < ed) & (em < tol)] = 2
    return out


def _continues_monotone(profile, x, phi, slack=np.radians(1.0)):
    """True where ``phi`` at ``x`` keeps the slope trend of the nearest segment end.

    A fillet or ball is a circle-like arc: its slope angle changes one way
    along it. A point beyond a segment's end must continue that change (a
    point inside a segment passes).
    """
    pts = profile.points
    ok = np.ones(len(x), bool)
    if len(pts["x"]) == 0:
        return ok
    best = np.full(len(x), np.inf)
    for s in range(profile.n_segments):
        idx = np.flatnonzero(pts["segment"] == s)
        if len(idx) < 2:
            continue
        xs, ps = pts["x"][idx], pts["phi"][idx]
        for e, nb, sel in ((0, 1, x < xs[0]), (len(xs) - 1, len(xs) - 2, x > xs[-1])):
            d = np.abs(x - xs[e])
            use = sel & (d < best)
            if use.any():
                trend = ps[e] - ps[nb]
                ok[use] = (phi[use] - ps[e]) * np.sign(trend) >= -slack
                best[use] = d[use]
        inside = (x >= xs[0]) & (x <= xs[-1])
        ok[inside] = True
        best[inside] = 0.0
    return ok


def analyse_joint(stack, params=None, **kwargs):
    """Highlights, profile, surface and features of one joint's stack.

    Parameters
    ----------
    stack : shinysim.io.Stack
    params : JointAnalysisParams, optional
        Keyword arguments override single fields.

    Returns
    -------
    JointAnalysis
    """
    if not isinstance(stack, Stack):
        raise TypeError(f"stack must be a shinysim.io.Stack, got {type(stack).__name__}")
    params = with_overrides(JointAnalysisParams, params, kwargs)
    hp = params.highlight
    cam = stack.camera
    if params.scale_max_area and hp.max_area is not None:
        scale = (1.0 / cam.pixel_pitch / 128.0) ** 2
        hp = HighlightParams(**{**hp.__dict__, "max_area": max(hp.min_area, int(round(hp.max_area * scale)))})
    zp = params.pad_top_z
    t = find_highlights(stack, hp, plane_z=zp)
    n = len(t["row"])
    pts = np.column_stack([t["x"], t["y"], t["z_plane"]])
    t["mirror_normal"] = normals_at_points(pts, t["source"], stack, mirror_z=zp) if n else np.zeros((0, 3))
    t["flat"] = ((blob_area(t) * cam.pixel_pitch ** 2 > params.flat_area_mm2)
                 & (np.abs(slope_angle_from_normal(t["normal"])) < np.radians(params.flat_max_slope_deg)))
    band = np.flatnonzero(np.abs(t["y"]) <= params.band_half_width_mm)
    g = _band_points(t, band, stack, zp, hp.dim_fraction if hp.flag_rule == "dim" else 0.0)
    m = len(g["x"])
    first = g["x"][~g["flagged"] & ~g["flat"]]
    toe = float("nan")
    if len(first):
        toe = find_toe(stack, x_before=float(first.min()), half_width=params.band_half_width_mm, plane_z=zp,
                       smooth_px=hp.smooth_px)
    on_joint = np.ones(m, bool) if not np.isfinite(toe) else g["x"] >= toe - params.toe_margin_mm
    direct = on_joint & ~g["flagged"] & ~g["flat"]
    anchor = (toe, zp) if np.isfinite(toe) else None
    g["reading"] = np.where(direct, 1, 0)
    if direct.any():
        # flagged points: read as direct or as a pad bounce where that reading
        # continues the profile of the points taken so far, nearest first
        cand = list(np.flatnonzero(on_joint & g["flagged"] & ~g["flat"]
                                   & (g["x"] <= g["x"][direct].max() + params.extend_mm)))
        phi_d_all = slope_angle_from_normal(g["normal"])
        phi_m_all = slope_angle_from_normal(g["mirror_normal"]) if params.use_mirror else np.full(m, np.nan)
        while cand:
            take = np.flatnonzero(g["reading"] > 0)
            mir = g["reading"][take] == 2
            nn = np.where(mir[:, None], g["mirror_normal"][take], g["normal"][take])
            pr0 = profile_from_normals(g["x"][take], nn, weights=g["sum"][take], anchor=anchor, params=params.profile)
            c = np.asarray(cand)
            pred, dist = predict_slope_angle(pr0, g["x"][c])
            # one normal per reading and source: a source that already has a point of a
            # reading elsewhere on the profile cannot light a second place the same way
            phi_d, phi_m = (np.where(np.isin(g["source"][c], g["source"][take[own]])
                                     | ~_continues_monotone(pr0, g["x"][c], phi[c]), np.nan, phi[c])
                            for own, phi in ((~mir, phi_d_all), (mir, phi_m_all)))
            r = _readings(pred, dist, phi_d, phi_m, params)
            ok = (r > 0) & (dist <= params.reading_step_mm)
            if not ok.any():
                break
            best = np.flatnonzero(ok)[np.argmin(dist[ok])]
            g["reading"][c[best]] = r[best]
            cand.remove(c[best])
    idx = np.flatnonzero(g["reading"] > 0)
    is_mirror = g["reading"][idx] == 2
    normals = np.where(is_mirror[:, None], g["mirror_normal"][idx], g["normal"][idx]) if len(idx) else np.zeros((0, 3))
    x = g["x"][idx]
    w = g["sum"][idx]
    pr, use = _profile_pass(x, normals, w, is_mirror, toe, params)
    x_ref, z_ref, n_ref = x.copy(), np.full(len(idx), np.nan), normals.copy()
    if params.refine and len(idx) and len(pr.x):
        z_pts = pr.z_at(x)
        ok = np.isfinite(z_pts)
        if ok.any():
            p3 = cam.backproject_to_plane(g["row"][idx][ok], g["col"][idx][ok], z_pts[ok]).reshape(-1, 3)
            src = g["source"][idx][ok]
            n_ref[ok] = np.where(is_mirror[ok][:, None], normals_at_points(p3, src, stack, mirror_z=zp),
                                 normals_at_points(p3, src, stack))
            x_ref[ok] = p3[:, 0]
            pr, use = _profile_pass(x_ref, n_ref, w, is_mirror, toe, params)
    if len(idx) and len(pr.x):
        z_ref = pr.z_at(x_ref)
    g["used"] = np.zeros(m, bool)
    g["used"][idx[use]] = True
    g["reading"][idx[~use]] = 0
    for name, start, value in (("x_refined", g["x"], x_ref), ("z_refined", np.full(m, np.nan), z_ref),
                               ("normal_refined", g["normal"], n_ref)):
        g[name] = start.copy()
        g[name][idx] = value
    t["used"] = np.zeros(n, bool)
    for i in np.flatnonzero(g["used"]):
        t["used"][g["members"][i]] = True
    surface = None
    if params.surface is not None and np.isfinite(toe) and np.isfinite(pr.z).any():
        surface = _joint_surface(stack, t, toe, pr, params)
    feats = joint_features(t, g, pr, toe, params)
    return JointAnalysis(t, g, toe, pr, surface, feats, params)


def _joint_surface(stack, t, toe, pr, params):
    """All normals of the joint's rows, read as in the band, integrated."""
    zp = params.pad_top_z
    hw = params.surface_half_width_mm
    x_end = float(np.nanmax(pr.x[np.isfinite(pr.z)]))
    sel = (np.abs(t["y"]) <= hw) & (t["x"] >= toe - params.toe_margin_mm) & (t["x"] <= x_end + 1e-9) & ~t["flat"]
    direct = sel & ~t["interreflection"]
    reading = np.where(direct, 1, 0)
    flagged = np.flatnonzero(sel & t["interreflection"])
    if len(flagged):
        pred, dist = predict_slope_angle(pr, t["x"][flagged])
        phi_m = (slope_angle_from_normal(t["mirror_normal"][flagged]) if params.use_mirror
                 else np.full(len(flagged), np.nan))
        reading[flagged] = _readings(pred, dist, slope_angle_from_normal(t["normal"][flagged]), phi_m, params)
    # direct points must also agree with the band profile (the joint is one fillet across its width)
    d_idx = np.flatnonzero(reading == 1)
    if len(d_idx):
        pred, dist = predict_slope_angle(pr, t["x"][d_idx])
        keep = _readings(pred, dist, slope_angle_from_normal(t["normal"][d_idx]), np.full(len(d_idx), np.nan), params)
        reading[d_idx[keep == 0]] = 0
    idx = np.flatnonzero(reading > 0)
    if len(idx) < 3:
        return None
    normals = np.where((reading[idx] == 2)[:, None], t["mirror_normal"][idx], t["normal"][idx])
    ys = np.linspace(-hw, hw, 9)
    anchors = np.column_stack([np.full(len(ys), toe), ys, np.full(len(ys), zp)])
    try:
        return surface_from_normals(t["x"][idx], t["y"][idx], normals, anchors=anchors, weights=t["sum"][idx],
                                    bounds=(toe, x_end, -hw, hw), params=params.surface)
    except ValueError:
        return None


#: Names of :func:`joint_features`, in order (the classifier's columns).
FEATURE_NAMES = (
    "n_points",
    "phi_min_deg",
    "phi_max_deg",
    "phi_first_deg",
    "phi_last_deg",
    "curvature_per_mm",
    "length_mm",
    "height_mm",
    "height_max_mm",
    "rise_mm",
    "n_segments",
    "mirror_fraction",
    "n_flagged_band",
    "between_highlights",
    "toe_found",
)


def joint_features(table, points, profile, toe_x, params):
    """Numbers that describe a joint's profile and highlights.

    Parameters
    ----------
    table : HighlightTable
        All highlights (:attr:`JointAnalysis.table`).
    points : dict
        The band points (:attr:`JointAnalysis.points`).
    profile : Profile
    toe_x : float, mm
    params : JointAnalysisParams

    Returns
    -------
    dict of str -> float, keys :data:`FEATURE_NAMES`
        ``n_points``: merged measured points of the profile;
        ``phi_*``: slope angles (deg) of the measured points: smallest,
        largest, nearest the toe, furthest from it;
        ``curvature_per_mm``: the slope of ``-sin(phi)`` against x over the
        points (the curvature of a circle through them; > 0 convex);
        ``length_mm``: x-extent of the reconstructed profile;
        ``height_mm``: height above the pad top of the last anchored point;
        ``height_max_mm``: the highest reconstructed point above the pad top;
        ``rise_mm``: the largest rise within one segment (known even where
        the height is not anchored);
        ``n_segments``: discontinuities + 1;
        ``mirror_fraction``: share of pad-bounce points;
        ``n_flagged_band``: flagged band points (log1p);
        ``between_highlights``: highlights, flagged or not, between this
        joint's pad and its neighbour's (log1p; solder bridges: only solder
        can shine there, the board is a dull diffuser);
        ``toe_found``: 1 or 0.
    """
    pts = profile.points
    phi = np.degrees(pts["phi"])
    f = dict.fromkeys(FEATURE_NAMES, 0.0)
    f["n_points"] = float(len(phi))
    if len(phi):
        f["phi_min_deg"] = float(phi.min())
        f["phi_max_deg"] = float(phi.max())
        f["phi_first_deg"] = float(phi[0])
        f["phi_last_deg"] = float(phi[-1])
    if len(phi) >= 2 and np.ptp(pts["x"]) > 0:
        f["curvature_per_mm"] = float(-np.polyfit(pts["x"], np.sin(pts["phi"]), 1)[0])
    zp = params.pad_top_z
    good = np.isfinite(profile.z)
    if good.any():
        f["length_mm"] = float(np.ptp(profile.x[good]))
    anchored = profile.anchored[pts["segment"]] if len(phi) else np.zeros(0, bool)
    if anchored.any():
        f["height_mm"] = float(pts["z"][anchored][-1] - zp)
        za = profile.z_at(profile.x, anchored_only=True)
        f["height_max_mm"] = float(np.nanmax(za) - zp) if np.isfinite(za).any() else 0.0
    if len(profile.x):
        rises = [np.ptp(profile.z[profile.segment == s]) for s in range(profile.n_segments)
                 if np.isfinite(profile.z[profile.segment == s]).any()]
        f["rise_mm"] = float(max(rises)) if rises else 0.0
    f["n_segments"] = float(profile.n_segments)
    used = points["used"]
    f["mirror_fraction"] = float(np.sum(used & (points["reading"] == 2)) / used.sum()) if used.sum() else 0.0
    f["n_flagged_band"] = float(np.log1p(np.sum(points["flagged"])))
    lo, hi = params.between_band_mm
    between = (np.abs(table["y"]) >= lo) & (np.abs(table["y"]) <= hi)
    f["between_highlights"] = float(np.log1p(between.sum()))
    f["toe_found"] = float(np.isfinite(toe_x))
    return f
