"""The deflectometry figure: a facet's slope maps, a reference's, and their difference.

matplotlib is imported inside the function.
"""

from __future__ import annotations

import numpy as np

from .caption import captioned_png, new_figure

__all__ = ["deflect_figure"]


def _panel(fig, ax, pts_m, values_mrad, title, cmap, limits):
    sc = ax.scatter(pts_m[:, 0], pts_m[:, 1], c=values_mrad, s=3, cmap=cmap, vmin=limits[0], vmax=limits[1],
                    linewidths=0)
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("x (m)", fontsize=8)
    ax.set_ylabel("y (m)", fontsize=8)
    ax.tick_params(labelsize=7)
    fig.colorbar(sc, ax=ax, shrink=0.85).ax.tick_params(labelsize=7)


def deflect_figure(result) -> bytes:
    """PNG bytes: slopes x and y (mrad) of ``result`` (a :class:`~shinysim.studies.deflect.DeflectResult`),
    the reference's at the matched dots and the difference, with a caption stating the numbers."""
    m = result.measurement
    sol = m.solution
    pts = sol.points_mm / 1e3
    ours = sol.slopes * 1e3
    ref = result.expected
    rows = 2 if ref is None else 3
    fig, axes = new_figure((8.6, 3.2 * rows), rows, 2)
    lim = [np.percentile(ours[:, k], [1, 99]) for k in range(2)]
    lim = [(float(lo), float(hi)) for lo, hi in lim]
    for k, name in enumerate(("dz/dx", "dz/dy")):
        _panel(fig, axes[0, k], pts, ours[:, k], f"shinysim: {name} (mrad)", "viridis", lim[k])
    score = result.score
    text = (f"Slopes of the facet from one frame of the display's dots: {score['dots_identified']} dots identified "
            f"of {score['dots_found']} found on the facet ({score['dots_cut']} cut by its edge left out); each "
            "dot's camera ray meets the fitted paraboloid and the bisector of the directions to the camera and to "
            f"the dot gives dz/dx, dz/dy in the facet frame, {score['alignment']}-aligned. Fitted focal lengths "
            f"{score['focal_lengths_m'][0]:.2f} m, {score['focal_lengths_m'][1]:.2f} m.")
    if ref is not None:
        vs = score["vs_expected"]
        hit, j = result.pairs
        theirs = ref.slopes * 1e3
        for k, name in enumerate(("dz/dx", "dz/dy")):
            _panel(fig, axes[1, k], ref.surface_points_mm / 1e3, theirs[:, k], f"SOFAST: {name} (mrad)", "viridis",
                   lim[k])
            diff = ours[hit, k] - theirs[j[hit], k]
            span = float(max(np.percentile(np.abs(diff), 99), 1e-3))
            _panel(fig, axes[2, k], pts[hit], diff, f"difference {name} (mrad)", "RdBu_r", (-span, span))
        dt = vs["detilted"]
        text += (f" Middle: SOFAST's own result ({vs['expected_points']} points; focal lengths "
                 f"{vs['expected_focal_lengths_m'][0]:.2f} m, {vs['expected_focal_lengths_m'][1]:.2f} m). Bottom: "
                 f"shinysim minus SOFAST at {vs['matched']} matched dots (nearest point within "
                 f"{vs['match_mm']:.1f} mm): |difference| RMS {vs['rms_mrad']:.3f} mrad, p95 {vs['p95_mrad']:.3f}, "
                 f"max {vs['max_mrad']:.3f}, {vs['n_over_1mrad']} over 1 mrad; with constant + linear terms "
                 f"removed RMS {dt['rms_mrad']:.3f}, p95 {dt['p95_mrad']:.3f}, max {dt['max_mrad']:.3f} mrad.")
    else:
        for k in range(2):
            axes[1, k].hist(ours[:, k], bins=60, color="C0")
            axes[1, k].set_title(f"{('dz/dx', 'dz/dy')[k]} histogram (mrad)", fontsize=9)
            axes[1, k].tick_params(labelsize=7)
        text += " No reference result was given: bottom, the slopes' histograms."
    return captioned_png(fig, text)
