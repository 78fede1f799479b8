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
    the reference's at its points and the difference at the matched dots, with a caption stating the numbers.

    An ensemble's facets are drawn where they sit in the ensemble, each with its own slopes.
    """
    facets = result.facets

    def placed(f, pts_mm):
        return (pts_mm @ f.rotation.T + f.position_mm) / 1e3

    pts = np.concatenate([placed(f, f.measurement.solution.points_mm) for f in facets])
    ours = np.concatenate([f.measurement.solution.slopes for f in facets]) * 1e3
    with_ref = all(f.expected is not None for f in facets)
    rows = 3 if with_ref else 2
    fig, axes = new_figure((8.6, 3.2 * rows), rows, 2)
    lim = [tuple(float(v) for v in np.percentile(ours[:, k], [1, 99])) for k in range(2)]
    for k, name in enumerate(("dz/dx", "dz/dy")):
        _panel(fig, axes[0, k], pts, ours[:, k], f"shinysim: {name} (mrad)", "viridis", lim[k])
    score = result.score
    what = "the facet" if len(facets) == 1 else f"the {len(facets)} facets (each in its own frame, drawn in place)"
    focal = ", ".join(f"{a:.2f} m, {b:.2f} m" for a, b in
                      ([score["focal_lengths_m"]] if len(facets) == 1 else
                       [e["focal_lengths_m"] for e in score["facets"]]))
    text = (f"Slopes of {what} from one frame of the display's dots: {score['dots_identified']} dots identified "
            f"of {score['dots_found']} found ({score['dots_cut']} cut by an edge left out); each dot's camera ray "
            "meets the fitted paraboloid and the bisector of the directions to the camera and to the dot gives "
            f"dz/dx, dz/dy in the facet frame, {score['alignment']}-aligned. Fitted focal lengths {focal}.")
    if with_ref:
        theirs_pts = np.concatenate([placed(f, f.expected.surface_points_mm) for f in facets])
        theirs = np.concatenate([f.expected.slopes for f in facets]) * 1e3
        hit_pts = np.concatenate([placed(f, f.measurement.solution.points_mm[f.pairs[0]]) for f in facets])
        diff = np.concatenate([f.measurement.solution.slopes[f.pairs[0]] - f.expected.slopes[f.pairs[1][f.pairs[0]]]
                               for f in facets]) * 1e3
        for k, name in enumerate(("dz/dx", "dz/dy")):
            _panel(fig, axes[1, k], theirs_pts, theirs[:, k], f"SOFAST: {name} (mrad)", "viridis", lim[k])
            span = float(max(np.percentile(np.abs(diff[:, k]), 99), 1e-3)) if len(diff) else 1e-3
            _panel(fig, axes[2, k], hit_pts, diff[:, k], f"difference {name} (mrad)", "RdBu_r", (-span, span))
        vs = score["vs_expected"]
        dt = vs["detilted"]
        text += (f" Middle: SOFAST's own result ({vs['expected_points']} points). Bottom: shinysim minus SOFAST "
                 f"at {vs['matched']} matched dots: |difference| RMS {vs['rms_mrad']:.3f} mrad, p95 "
                 f"{vs['p95_mrad']:.3f}, max {vs['max_mrad']:.3f}, {vs['n_over_1mrad']} over 1 mrad; with "
                 f"constant + linear terms removed RMS {dt['rms_mrad']:.3f}, p95 {dt['p95_mrad']:.3f}, max "
                 f"{dt['max_mrad']:.3f} mrad.")
        if len(facets) == 1:
            ex = vs["expected_focal_lengths_m"]
            text += f" SOFAST's slopes fitted the same way give focal lengths {ex[0]:.2f} m, {ex[1]:.2f} m."
    else:
        for k in range(2):
            axes[1, k].hist(ours[:, k], bins=60, color="C0")
            axes[1, k].set_title(f"{('dz/dx', 'dz/dy')[k]} histogram (mrad)", fontsize=9)
            axes[1, k].tick_params(labelsize=7)
        text += " No reference result was given: bottom, the slopes' histograms."
    return captioned_png(fig, text)
