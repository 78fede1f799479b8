"""The deflectometry figure: a facet's slope maps, a reference's, and their difference.

matplotlib is imported inside the function.
"""

from __future__ import annotations

import numpy as np

from .caption import captioned_png, new_figure

__all__ = ["deflect_figure", "fringe_figure", "real_vs_render_figure", "twin_figure"]


def _panel(fig, ax, pts_m, values_mrad, title, cmap, limits):
    size = float(np.clip(12000 / max(len(pts_m), 1), 3, 30))
    sc = ax.scatter(pts_m[:, 0], pts_m[:, 1], c=values_mrad, s=size, cmap=cmap, vmin=limits[0], vmax=limits[1],
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


def real_vs_render_figure(real, rendered, origin_rc, caption) -> bytes:
    """PNG bytes: a real frame beside a render of its reconstruction, whole and around ``origin_rc``.

    Each image is shown scaled to its own 99.5th percentile (a camera's counts against linear radiance).
    """
    fig, axes = new_figure((9.0, 7.4), 2, 2)
    r0, c0 = int(round(origin_rc[0])), int(round(origin_rc[1]))
    half = 40
    for col, (img, name) in enumerate(((real, "real frame"), (rendered, "render of the reconstruction"))):
        img = np.asarray(img, float)
        top = float(np.percentile(img, 99.5)) or 1.0
        axes[0, col].imshow(img / top, cmap="gray", vmin=0, vmax=1, interpolation="nearest")
        axes[0, col].set_title(name, fontsize=9)
        axes[0, col].add_patch(_box(c0 - half, r0 - half, 2 * half))
        window = img[max(0, r0 - half):r0 + half, max(0, c0 - half):c0 + half]
        axes[1, col].imshow(window / top, cmap="gray", vmin=0, vmax=1, interpolation="nearest",
                            extent=(c0 - half - 0.5, c0 + half - 0.5, r0 + half - 0.5, r0 - half - 0.5))
        axes[1, col].set_title(f"{name}, around dot (0, 0)", fontsize=9)
        for ax in axes[:, col]:
            ax.tick_params(labelsize=7)
    return captioned_png(fig, caption)


def _box(x, y, size):
    from matplotlib.patches import Rectangle

    return Rectangle((x, y), size, size, fill=False, edgecolor="C3", lw=1)


def twin_figure(frame, measurement, score) -> bytes:
    """PNG bytes: the twin's rendered frame with its identified dots, and the slope error against exact truth."""
    from ..evaluate.deflect import detilt

    fig, axes = new_figure((10.5, 3.6), 1, 3)
    img = np.asarray(frame.image, float)
    axes[0].imshow(img, cmap="gray", interpolation="nearest")
    m = measurement
    axes[0].plot(m.dots["col"][m.used], m.dots["row"][m.used], "+", color="C1", ms=4, mew=0.8)
    axes[0].set_title("twin frame, identified dots", fontsize=9)
    axes[0].tick_params(labelsize=7)
    sol = m.solution
    truth = frame.setup.facet.slopes(sol.points_mm[:, 0], sol.points_mm[:, 1])
    diff = detilt(sol.points_mm, sol.slopes - truth) * 1e3
    span = float(max(np.percentile(np.abs(diff), 99), 1e-4))
    for k, name in enumerate(("dz/dx", "dz/dy")):
        _panel(fig, axes[k + 1], sol.points_mm / 1e3, diff[:, k], f"{name} - exact, detilted (mrad)", "RdBu_r",
               (-span, span))
    g, c = score["given_pose"], score["from_corners"]
    side = 2 * score["facet"]["half_sides_mm"][0]
    text = (f"The simulated twin of SOFAST's rig ({score['geometry']} geometry): a {side:.0f} mm facet, a paraboloid of focal lengths {score['facet']['focal_mm'][0] / 1e3:.0f} m, "
            f"{score['facet']['focal_mm'][1] / 1e3:.0f} m with a {score['facet']['ripple_mm']} mm ripple of period "
            f"{score['facet']['ripple_period_mm']:.0f} mm, rendered at {score['spp']} samples per pixel. "
            f"{c['identification']['identified']} dots identified, {c['identification']['wrong']} wrongly; "
            f"centroids {c['centroid_px']['rms']:.3f} px RMS from the exact reflections. Slopes against the exact "
            f"slopes: with the true pose {g['slopes']['rms_mrad']:.4f} mrad RMS (max {g['slopes']['max_mrad']:.4f}); "
            f"posed from the corners and centre-aligned, with constant + linear terms removed (shown) "
            f"{c['slopes']['detilted']['rms_mrad']:.4f} mrad RMS (max {c['slopes']['detilted']['max_mrad']:.4f}).")
    return captioned_png(fig, text)


def fringe_figure(result) -> bytes:
    """PNG bytes: a fringe measurement's decoded screen positions and slopes, SOFAST's, and the differences.

    ``result`` is a :class:`~shinysim.studies.deflect.FringeResult`; each row is a map over the camera's
    pixels: decoded x and y screen fractions, then slopes dz/dx and dz/dy (mrad); the columns are shinysim's,
    the reference's at its pixels, and shinysim minus the reference where both decoded.
    """
    pm = result.measurement
    H, W = pm.mask.shape
    ref = result.expected

    def grid(rows, cols, values):
        g = np.full((H, W), np.nan)
        g[rows, cols] = values
        return g

    quantities = [("screen x (fraction)", pm.fraction[:, 0], None, 1.0),
                  ("screen y (fraction)", pm.fraction[:, 1], None, 1.0),
                  ("dz/dx (mrad)", pm.solution.slopes[:, 0], 0, 1e3),
                  ("dz/dy (mrad)", pm.solution.slopes[:, 1], 1, 1e3)]
    ncol = 3 if ref is not None else 1
    fig, axes = new_figure((3.3 * ncol + 0.6, 2.6 * 4), 4, ncol, squeeze=False)
    for i, (name, ours, k, scale) in enumerate(quantities):
        mine = grid(pm.rows, pm.cols, ours * scale)
        lo, hi = np.nanpercentile(mine, [1, 99])
        im = axes[i, 0].imshow(mine, cmap="viridis", vmin=lo, vmax=hi, interpolation="nearest")
        fig.colorbar(im, ax=axes[i, 0], shrink=0.8).ax.tick_params(labelsize=7)
        axes[i, 0].set_title(f"shinysim: {name}", fontsize=8)
        if ref is not None:
            rr, cc = result.expected_pixels
            if k is None:
                theirs_v = np.asarray(ref.extras["v_screen_points_fractional_screens"], float)[:, i]
            else:
                theirs_v = ref.slopes[:, k]
            theirs = grid(rr, cc, theirs_v * scale)
            im = axes[i, 1].imshow(theirs, cmap="viridis", vmin=lo, vmax=hi, interpolation="nearest")
            fig.colorbar(im, ax=axes[i, 1], shrink=0.8).ax.tick_params(labelsize=7)
            axes[i, 1].set_title(f"SOFAST: {name}", fontsize=8)
            diff = mine - theirs
            if k is None:
                diff = diff * 1e6
                label = "difference (1e-6 of a screen)"
            else:
                label = "difference (mrad)"
            span = float(np.nanpercentile(np.abs(diff), 99)) if np.isfinite(diff).any() else 1.0
            im = axes[i, 2].imshow(diff, cmap="RdBu_r", vmin=-span, vmax=span, interpolation="nearest")
            fig.colorbar(im, ax=axes[i, 2], shrink=0.8).ax.tick_params(labelsize=7)
            axes[i, 2].set_title(label, fontsize=8)
        for ax in axes[i]:
            ax.tick_params(labelsize=6)
    s = result.score
    text = (f"Fringe deflectometry: {s['measurement']['frames']} frames of phase-shifted sinusoids "
            f"({len(s['measurement']['periods_x'])} periods x 4 shifts, in x and y) decoded to the screen point "
            f"each camera pixel sees; {s['pixels_valid']} pixels decoded of {s['pixels_region']} on the facet "
            f"({s['pixels_low_modulation']} below the noise, {s['pixels_unwrap_inconsistent']} inconsistently "
            f"unwrapped, left out). Slopes by the bisector rule on the fitted paraboloid, {s['alignment']}-aligned "
            f"(surface fit: {s['surface_fit']['from']}).")
    if ref is not None:
        sv, vs = s.get("screen_vs_expected"), s["vs_expected"]
        if sv is not None:
            text += (f" Decoded positions against SOFAST's at its {sv['matched']} pixels: "
                     f"{sv['rms_screen_widths']:.1e} screen widths RMS, {sv['unwrap_errors']} unwrapping errors.")
        text += (f" Slopes at the {vs['matched']} pixels both decoded: |difference| RMS {vs['rms_mrad']:.3f} mrad, "
                 f"max {vs['max_mrad']:.3f}; detilted RMS {vs['detilted']['rms_mrad']:.4f}, max "
                 f"{vs['detilted']['max_mrad']:.3f} mrad.")
    return captioned_png(fig, text)
