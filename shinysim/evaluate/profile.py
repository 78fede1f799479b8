"""Scoring a solder joint's profile and surface against its exact cross-section."""

from __future__ import annotations

import numpy as np

from ..conventions import angle_between
from .stats import summary_stats

__all__ = ["profile_stats", "score_profile"]


def profile_stats(values, *, rms: bool = False) -> dict:
    """``n``, ``mean``, ``median``, ``p95``, ``max`` (and ``rms``) of the finite values; None where there are none."""
    return summary_stats(values, ("n", "mean", "median", "p95", "max") + (("rms",) if rms else ()), empty=None)


def score_profile(analysis, profile_truth):
    """Score one joint's reconstruction against its exact cross-section.

    Parameters
    ----------
    analysis : shinysim.recon.joint.JointAnalysis
    profile_truth : JointProfile (or Joint)
        ``profile_z``, ``profile_normal``, ``visible_x_range``,
        ``fillet_height``.

    Returns
    -------
    dict
        ``height_rms_mm``, ``height_max_mm``, ``height_rms_pct`` and
        ``height_max_pct`` (of the fillet height) over the anchored profile
        grid inside the visible fillet, of heights above the pad top (the
        reconstruction's above the pad top it assumed, the truth's above the
        true one: IPC's fillet heights are measured from the land);
        ``absolute_height_rms_pct`` the same for absolute heights, which
        also carry the error of the assumed pad thickness; ``coverage`` (share of the visible
        x-range reconstructed with known height); ``anchored`` (the profile
        has a segment of known height); ``normal_errors_deg`` at the
        measured points (every band point that entered the profile, at its
        refined position, against the exact normal there; ``mirror_points``
        says which were read as pad bounces) with ``normal_error_*``
        statistics over all, ``direct`` and ``mirror`` points;
        ``profile_normal_rms_deg`` of the interpolated profile; ``surface_*``
        errors of the integrated surface (nodes within 0.015 mm of a
        measurement).
    """
    pr = analysis.profile
    v0, v1 = profile_truth.visible_x_range
    H = float(profile_truth.fillet_height)
    pad_true = float(getattr(profile_truth, "pad_top_z", analysis.params.pad_top_z))
    pad_used = float(analysis.params.pad_top_z)
    out = {"fillet_height_mm": H, "visible_x_range": [float(v0), float(v1)],
           "pad_top_z_mm": pad_true, "pad_top_z_assumed_mm": pad_used}
    za = pr.z_at(pr.x, anchored_only=True) if len(pr.x) else np.zeros(0)
    inside = (pr.x >= v0) & (pr.x <= v1)
    zt = profile_truth.profile_z(pr.x) if len(pr.x) else np.zeros(0)
    err = (za - pad_used) - (zt - pad_true)  # heights above the pad top, as F is measured
    err_abs = za - zt
    ok = inside & np.isfinite(err)
    out["anchored"] = bool(pr.anchored.any()) if len(pr.anchored) else False
    if ok.any():
        rms = float(np.sqrt(np.mean(err[ok] ** 2)))
        mx = float(np.max(np.abs(err[ok])))
        out.update(height_rms_mm=rms, height_max_mm=mx, height_rms_pct=100 * rms / H, height_max_pct=100 * mx / H,
                   height_bias_mm=float(np.mean(err[ok])),
                   absolute_height_rms_pct=100 * float(np.sqrt(np.mean(err_abs[ok] ** 2))) / H)
        out["coverage"] = float(ok.sum() * pr.params.step_mm / max(v1 - v0, 1e-9))
        phi_t = np.arctan(profile_truth.profile_slope(pr.x[ok]))
        out["profile_normal_rms_deg"] = float(np.degrees(np.sqrt(np.mean((pr.phi[ok] - phi_t) ** 2))))
    else:
        out.update(height_rms_mm=None, height_max_mm=None, height_rms_pct=None, height_max_pct=None,
                   height_bias_mm=None, absolute_height_rms_pct=None, coverage=0.0, profile_normal_rms_deg=None)
    g = analysis.points
    used = np.flatnonzero(g["used"])
    x = g["x_refined"][used]
    nt = profile_truth.profile_normal(x, g["y"][used])
    e = np.degrees(angle_between(g["normal_refined"][used], nt))
    mirror = g["reading"][used] == 2
    out["normal_errors_deg"] = [None if not np.isfinite(v) else float(v) for v in e]
    out["mirror_points"] = [bool(v) for v in mirror]
    out["normal_error"] = profile_stats(e)
    out["normal_error_direct"] = profile_stats(e[~mirror])
    out["normal_error_mirror"] = profile_stats(e[mirror])
    s = analysis.surface
    if s is not None:
        X, Y = np.meshgrid(s.x, s.y)
        zt2 = profile_truth.profile_z(X, Y)
        err2 = (s.z - pad_used) - (zt2 - pad_true)
        ok2 = np.isfinite(err2) & (s.support_mm <= 0.015) & (X >= v0) & (X <= v1)
        if ok2.any():
            r2 = float(np.sqrt(np.mean(err2[ok2] ** 2)))
            out.update(surface_rms_mm=r2, surface_rms_pct=100 * r2 / H,
                       surface_max_mm=float(np.max(np.abs(err2[ok2]))), surface_nodes=int(ok2.sum()))
    return out
