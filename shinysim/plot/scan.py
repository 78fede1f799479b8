"""Pictures of scans (matplotlib, imported only here and only when called)."""

from __future__ import annotations

import numpy as np

from .caption import new_figure

__all__ = ["scan_figure", "needle_image_axes", "side_view_axes"]


def _source_colours(n):
    from matplotlib import colormaps

    return colormaps["turbo"](np.linspace(0.05, 0.95, n))


def needle_image_axes(ax, stack, recon, model, *, truth=None, needle_px=None):
    """Paper Fig. 9b: normal needles over the image, coloured by source.

    The background is the brightest value of every frame (all highlights of
    the scan at once) over a dim shading of the object, as the paper shows
    its highlights "in an image of the sphere with general background
    illumination". Each needle starts at a highlight centroid; its length is
    the projection of the unit normal onto the image plane (the paper's
    display convention), scaled so a normal lying in the image plane is
    ``needle_px`` pixels long.
    """
    cam = stack.camera
    H, W = cam.shape
    needle_px = needle_px or 0.12 * max(H, W)
    peak = stack.frames.max(axis=0)
    scale = np.percentile(peak[peak > 0], 99.5) if np.any(peak > 0) else 1.0
    img = np.clip(peak / scale, 0, 1)
    if truth is not None:
        shade = np.where(truth.mask, 0.15 + 0.15 * np.nan_to_num(truth.normals[..., 2]), 0.0)
        img = np.clip(np.maximum(img, shade), 0, 1)
    ax.imshow(img, cmap="gray", vmin=0, vmax=1, interpolation="nearest")
    t = recon.table
    n = recon.normals[model]
    colours = _source_colours(stack.n_sources)
    # image-plane components of the normal: +col along camera right, +row along down
    dc = n @ cam.right
    dr = n @ cam.down
    for i in range(len(recon)):
        c = colours[t["source"][i]]
        ax.plot([t["col"][i], t["col"][i] + needle_px * dc[i]], [t["row"][i], t["row"][i] + needle_px * dr[i]],
                color=c, lw=1.2)
        ax.plot(t["col"][i], t["row"][i], "o", ms=2.5, color=c)
    ax.set_title(f"Highlights and normals ({model} model), coloured by source")
    ax.set_xlabel("col (px)")
    ax.set_ylabel("row (px)")


def side_view_axes(ax, recon, model, truth, score, *, sphere_radius, sphere_center=(0.0, 0.0, 0.0)):
    """Paper Fig. 10: recovered normals extended to the sphere centre, side view (x-z)."""
    from ..evaluate import sample_truth

    t = recon.table
    n = recon.normals[model]
    _, p, valid = sample_truth(truth, t["row"], t["col"])
    colours = _source_colours(int(t["source"].max()) + 1 if len(t["source"]) else 1)
    cx, _, cz = sphere_center
    th = np.linspace(0, 2 * np.pi, 361)
    ax.plot(cx + sphere_radius * np.cos(th), cz + sphere_radius * np.sin(th), color="0.5", lw=1)
    ax.axhline(0.0, color="0.7", lw=0.8, ls=":")
    for i in np.flatnonzero(valid):
        # line from the surface point inwards along -n, past the centre
        s = np.linspace(-0.3 * sphere_radius, 1.3 * sphere_radius, 2)
        ax.plot(p[i, 0] - s * n[i, 0], p[i, 2] - s * n[i, 2], color=colours[t["source"][i]], lw=0.8)
    ax.plot([cx], [cz], "k+", ms=12, label="true centre")
    if "centre_estimate_mm" in score:
        ce = score["centre_estimate_mm"]
        ax.plot([ce[0]], [ce[2]], "rx", ms=9,
                label=f"nearest point to normals: {1000 * score['centre_error_mm']:.1f} µm off "
                      f"({score['centre_error_percent_radius']:.2f}% of r)")
    ax.set_aspect("equal")
    ax.set_xlim(cx - 1.4 * sphere_radius, cx + 1.4 * sphere_radius)
    ax.set_ylim(cz - 1.2 * sphere_radius, cz + 1.4 * sphere_radius)
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("z (mm)")
    ax.set_title("Side view: recovered normals through their surface points")
    ax.legend(loc="lower center", fontsize=8)


def scan_figure(stack, recon, truth, score, *, model, sphere_radius=None):
    """The scan picture written by ``shinysim scan``: Figs. 9b and 10 side by side."""
    ncols = 2 if sphere_radius is not None else 1
    fig, (axes,) = new_figure((6.0 * ncols, 6.0), 1, ncols, squeeze=False)
    needle_image_axes(axes[0], stack, recon, model, truth=truth)
    if sphere_radius is not None:
        side_view_axes(axes[1], recon, model, truth, score, sphere_radius=sphere_radius)
    fig.suptitle(
        f"median error {score['median_deg']:.3f}°, p95 {score['p95_deg']:.3f}°, "
        f"max {score['max_deg']:.3f}° over {score['n']} highlights"
    )
    return fig
