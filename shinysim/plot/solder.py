"""Solder-joint cross-sections (the paper's Fig. 12): drawing only.

matplotlib is imported inside the functions that need it.
"""

from __future__ import annotations

import numpy as np

from ..conventions import MM_PER_INCH

__all__ = ["draw_profile"]


def draw_profile(ax, analysis, truth_profile=None, *, title=None, legend=True):
    """Draw a reconstructed cross-section, over the exact one when given.

    Parameters
    ----------
    ax : matplotlib Axes
    analysis : shinysim.recon.joint.JointAnalysis
    truth_profile : JointProfile, optional
        The exact cross-section (and its lead) to draw underneath.
    title : str, optional
    legend : bool
    """
    pr = analysis.profile
    zp = analysis.params.pad_top_z
    fin = np.isfinite(pr.z)
    if truth_profile is not None:
        v0, v1 = truth_profile.visible_x_range
    elif fin.any():
        v0, v1 = float(pr.x[fin].min()), float(pr.x[fin].max())
    else:
        v0, v1 = -0.5, 0.5
    lo = min(analysis.toe_x if np.isfinite(analysis.toe_x) else v0, v0) - 0.08
    hi = max(v1, float(pr.x[fin].max()) if fin.any() else v1) + 0.08
    top = float(np.nanmax(pr.z)) if fin.any() else zp + 0.1
    ax.axhline(zp, color="0.6", lw=1.0)
    if truth_profile is not None:
        xt = np.linspace(lo, hi, 800)
        zt = truth_profile.profile_z(xt)
        ax.plot(xt, zt, color="0.3", lw=2.5, alpha=0.45, label="true solder surface")
        if np.isfinite(zt).any():
            top = max(top, float(np.nanmax(zt)))
        lead = getattr(truth_profile, "lead", None)
        if lead is not None:
            top = np.nanmax(zt) if np.isfinite(zt).any() else zp
            zl = np.linspace(lead.bottom_z, min(lead.top_z, 1.2 * top + 0.1), 100)
            ax.plot(lead.outer_x(zl), zl, color="0.55", lw=1.5, ls=":", label="lead (outer face)")
    anchored = np.zeros(len(pr.x), bool)
    ok = pr.segment >= 0
    if len(pr.anchored):
        anchored[ok] = pr.anchored[pr.segment[ok]]
    z_anch = np.where(anchored, pr.z, np.nan)
    z_rel = np.where(~anchored & ok, pr.z, np.nan)
    ax.plot(pr.x, z_anch, color="C3", lw=1.6, label="reconstructed z(x)")
    if np.isfinite(z_rel).any():
        ax.plot(pr.x, z_rel, color="C1", lw=1.4, ls="--", label="segment of unknown height")
    for g0, g1 in pr.gaps:
        ax.axvspan(g0, g1, color="C1", alpha=0.12, lw=0)
    g = analysis.points
    used = np.flatnonzero(g["used"])
    xm, zm, nm = g["x_refined"][used], g["z_refined"][used], g["normal_refined"][used]
    mir = g["reading"][used] == 2
    L = 0.025
    for sel, col, lab in ((~mir, "C0", "measured normals (direct)"), (mir, "C2", "measured normals (pad bounce)")):
        if sel.any():
            ax.quiver(xm[sel], zm[sel], nm[sel, 0], nm[sel, 2], color=col, angles="xy", scale_units="xy",
                      scale=1 / L, width=0.004, label=lab)
    if np.isfinite(analysis.toe_x):
        ax.plot([analysis.toe_x], [zp], marker="v", color="k", ms=7, ls="none", label="toe (anchor)")
    ax.set_xlim(lo, hi)
    ax.set_ylim(zp - 0.03, top + 0.05)
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("z (mm)")
    sec = ax.secondary_xaxis("top", functions=(lambda v: v / MM_PER_INCH, lambda v: v * MM_PER_INCH))
    sec.set_xlabel("x (in)")
    from matplotlib.ticker import MaxNLocator

    sec.xaxis.set_major_locator(MaxNLocator(4))
    if legend:
        ax.legend(fontsize=7, loc="upper left")
    if title:
        ax.set_title(title, fontsize=9)
