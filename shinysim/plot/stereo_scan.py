"""The picture of a stereo scan (``stereo.png``): matches in both views and from the side.

Like the paper's Figs. 15-16, from a rendered scan: each camera's view (the
brightest value of every pixel over the stack) with the matched highlights
marked, and a side view (x-z) of the matched 3-D points over the true
surface, beside where the best single-camera model puts the same
highlights. matplotlib is imported inside the function.
"""

from __future__ import annotations

import numpy as np

from .caption import new_figure

__all__ = ["stereo_matches_figure"]


def _view(ax, frames, rows, cols, conf, title):
    img = np.max(frames, axis=0)
    top = float(np.percentile(img[img > 0], 99.5)) if np.any(img > 0) else 1.0
    ax.imshow(np.sqrt(np.clip(img / top, 0, 1)), cmap="gray", interpolation="nearest")
    if len(rows):
        sc = ax.scatter(cols, rows, c=conf, s=6, cmap="viridis", vmin=0, vmax=1, linewidths=0)
    else:
        sc = None
    lit = np.argwhere(img > 0.05 * top)
    if len(lit):  # frame the lit part of the view (the object), with a margin
        (r0, c0), (r1, c1) = lit.min(axis=0), lit.max(axis=0)
        half = 0.6 * max(r1 - r0, c1 - c0, 16) + 4
        rc, cc = 0.5 * (r0 + r1), 0.5 * (c0 + c1)
        ax.set_xlim(cc - half, cc + half)
        ax.set_ylim(rc + half, rc - half)
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("col (px)", fontsize=8)
    ax.set_ylabel("row (px)", fontsize=8)
    ax.tick_params(labelsize=7)
    return sc


def stereo_matches_figure(stacks, matches, truths, score, *, single_points=None, max_surface_points=20000):
    """Figure of a stereo scan.

    Parameters
    ----------
    stacks : (Stack, Stack)
    matches : shinysim.recon.stereo.StereoMatches
    truths : (Truth, Truth)
    score : dict
        ``stereo_score.json``'s content (for the caption numbers).
    single_points : (N, 3) array_like, optional
        Where a single-camera model places camera 0's highlights, drawn in
        the side view.
    """
    fig = new_figure((11.0, 7.5))
    grid = fig.add_gridspec(2, 2, height_ratios=[1.0, 0.9])
    conf = np.asarray(matches.confidence) if len(matches) else np.zeros(0)
    sc = None
    for k in range(2):
        ax = fig.add_subplot(grid[0, k])
        rows = matches.row1 if k == 0 else matches.row2
        cols = matches.col1 if k == 0 else matches.col2
        sc = _view(ax, stacks[k].frames, np.asarray(rows), np.asarray(cols), conf,
                   f"camera {k} ({stacks[k].camera.name}): {len(matches)} matched of "
                   f"{score['n_highlights'][k]} highlights") or sc
    if sc is not None:
        fig.colorbar(sc, ax=fig.axes[:2], shrink=0.8, label="match confidence")
    ax = fig.add_subplot(grid[1, :])
    rng = np.random.default_rng(0)
    for t in truths:
        p = t.positions[t.mask]
        if len(p) > max_surface_points:
            p = p[rng.choice(len(p), max_surface_points, replace=False)]
        ax.scatter(p[:, 0], p[:, 2], s=0.3, color="0.75", linewidths=0, rasterized=True)
    ax.scatter([], [], s=8, color="0.75", label="true surface (both cameras' pixels)")
    if single_points is not None:
        sp = np.asarray(single_points, float)
        ax.scatter(sp[:, 0], sp[:, 2], s=5, marker="x", color="tab:red", linewidths=0.6,
                   label="single camera (best model), camera 0")
    if len(matches):
        pts = np.asarray(matches.point)
        ax.scatter(pts[:, 0], pts[:, 2], s=4, color="tab:blue", linewidths=0, label="stereo matches")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("z (mm)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(loc="upper left", fontsize=8, markerscale=2)
    pe = score["position_error_um"]
    ne = score["normal_error_deg"]
    ax.set_title(f"side view: position error median {pe['median']:.1f} um ({pe['median_px']:.2f} px-eq), "
                 f"normal error median {ne['median']:.3f} deg, false matches {100 * score['false_match_rate']:.2f} %, "
                 f"recall {100 * score['recall']:.1f} %", fontsize=9)
    return fig
