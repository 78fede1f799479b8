"""Figures 3-6 of the paper, regenerated from the analytic models.

Each function returns a :class:`matplotlib.figure.Figure` built directly
(no pyplot, no global backend switch); matplotlib is imported inside the
functions, so importing this module does not need it. Save with
``fig.savefig(path)``, or all four with :func:`save_figures`;
:func:`overlay_points` marks rendered measurements on Figs. 5-6.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._shared import check_choice, check_free, write_file
from ..conventions import direction_from_angles
from ..theory import reflectance as refl
from ..theory import sensitivity as sens
from .caption import new_figure

__all__ = [
    "dome_source_directions",
    "fig03_reflectance_map",
    "fig04_reflectance_map_array",
    "fig05_sensitivity",
    "fig06_source_error",
    "overlay_points",
    "save_figures",
    "shiny_source_directions",
]

_MODEL_LABELS = {"orthographic": "orthographic (Eq 11)", "perspective": "perspective (Eq 12)", "fixed": "fixed (Eq 13)"}


def _new_axes(ax, figsize):
    return (ax.figure, ax) if ax is not None else new_figure(figsize, 1, 1)


def shiny_source_directions():
    """Directions of the 21 SHINY fibers (semicircle in the x-z plane).

    Signed polar angles -84, -76, ..., -4, +4, ..., +76 degrees
    (:func:`shinysim.rig.shiny_1988_source_angles_deg`), positive towards +x.

    Returns
    -------
    (21, 3) ndarray
    """
    from ..rig import shiny_1988_source_angles_deg

    theta = np.deg2rad(shiny_1988_source_angles_deg())
    return direction_from_angles(theta, 0.0)


def dome_source_directions(spacing=np.deg2rad(8.0), max_polar=np.deg2rad(84.0)):
    """Directions of a hemispherical dome of sources about ``spacing`` apart.

    Rings at polar angles ``spacing/2, 3 spacing/2, ...`` up to ``max_polar``;
    each ring has ``round(2 pi sin(theta) / spacing)`` sources, evenly spaced
    in azimuth (odd rings rotated by half a step).

    Parameters
    ----------
    spacing : float, radians
    max_polar : float, radians

    Returns
    -------
    (n_sources, 3) ndarray
    """
    dirs = []
    for i, theta in enumerate(np.arange(0.5 * spacing, max_polar + 1e-9, spacing)):
        m = max(1, int(round(2 * np.pi * np.sin(theta) / spacing)))
        phi = 2 * np.pi * (np.arange(m) + 0.5 * (i % 2)) / m
        dirs.append(direction_from_angles(np.full(m, theta), phi))
    return np.concatenate(dirs, axis=0)


def fig03_reflectance_map(
    ax=None,
    *,
    source_theta=np.deg2rad(40.0),
    source_phi=np.deg2rad(30.0),
    k=0.3,
    sharpness=20.0,
    extent=1.2,
    shape=(301, 301),
):
    """Fig 3: reflectance map of Eq 5 for one distant source.

    Parameters
    ----------
    ax : matplotlib Axes, optional
        Draw here; by default a new figure.
    source_theta, source_phi : float, radians
        Source polar angle and azimuth.
    k, sharpness : float
        Eq 5 parameters.
    extent : float
        The map covers ``-extent <= p, q <= extent``.
    shape : (2,) tuple of int

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig, ax = _new_axes(ax, (5.6, 5.0))
    s = direction_from_angles(source_theta, source_phi)
    E, p, q = refl.reflectance_map(
        s, k=k, sharpness=sharpness, p_range=(-extent, extent), q_range=(-extent, extent), shape=shape
    )
    im = ax.imshow(E, origin="lower", extent=(-extent, extent, -extent, extent), cmap="gray", interpolation="bilinear")
    levels = np.array([0.3, 0.45, 0.6, 0.75, 0.9]) * np.nanmax(E)
    cs = ax.contour(p, q, E, levels=levels, colors="tab:orange", linewidths=0.8)
    ax.clabel(cs, fontsize=7, fmt="%.2f")
    ps, qs = -np.tan(source_theta) * np.cos(source_phi), -np.tan(source_theta) * np.sin(source_phi)
    pp, qp = refl.peak_gradient(ps, qs)
    ax.plot([pp], [qp], "r+", ms=12, mew=2)
    ax.annotate("P", (pp, qp), xytext=(6, 6), textcoords="offset points", color="r")
    if abs(ps) <= extent and abs(qs) <= extent:
        ax.plot([ps], [qs], "c*", ms=10)
        ax.annotate("S", (ps, qs), xytext=(6, 6), textcoords="offset points", color="c")
    ax.set_xlabel("p = dz/dx")
    ax.set_ylabel("q = dz/dy")
    ax.set_aspect("equal")
    ax.set_title(
        "Fig. 3: reflectance map, one distant source\n"
        f"source polar {np.rad2deg(source_theta):.0f}°, azimuth {np.rad2deg(source_phi):.0f}°; "
        f"k = {k:g}, sharpness = {sharpness:g}",
        fontsize=9,
    )
    fig.colorbar(im, ax=ax, label="brightness E / A", shrink=0.8)
    return fig


def fig04_reflectance_map_array(
    ax=None,
    *,
    layout="semicircle",
    k=0.05,
    sharpness=500.0,
    extent=1.0,
    shape=(301, 301),
    combine="max",
):
    """Fig 4: reflectance map of a whole array of distant sources.

    Parameters
    ----------
    ax : matplotlib Axes, optional
    layout : {"semicircle", "dome"}
        ``"semicircle"``: the 21 SHINY fibers (:func:`shiny_source_directions`);
        ``"dome"``: a hemisphere of sources 8 degrees apart
        (:func:`dome_source_directions`), as the paper's "spherical array".
    k, sharpness : float
        Eq 5 parameters.
    extent : float
        The map covers ``-extent <= p, q <= extent``.
    shape : (2,) tuple of int
    combine : {"max", "sum"}

    Returns
    -------
    matplotlib.figure.Figure
    """
    layouts = {"semicircle": shiny_source_directions, "dome": dome_source_directions}
    src = layouts[check_choice("layout", layout, tuple(layouts))]()
    fig, ax = _new_axes(ax, (5.6, 5.0))
    E, p, q = refl.reflectance_map(
        src, k=k, sharpness=sharpness, p_range=(-extent, extent), q_range=(-extent, extent), shape=shape,
        combine=combine,
    )
    im = ax.imshow(E, origin="lower", extent=(-extent, extent, -extent, extent), cmap="magma", interpolation="bilinear")
    pn = refl.peak_normal(src)
    pk, qk = -pn[:, 0] / pn[:, 2], -pn[:, 1] / pn[:, 2]
    ax.plot(pk, qk, "c.", ms=2)
    ax.set_xlabel("p = dz/dx")
    ax.set_ylabel("q = dz/dy")
    ax.set_aspect("equal")
    what = "21 SHINY fibers, polar -84°...+76° in the x-z plane" if layout == "semicircle" else (
        f"dome of {len(src)} sources 8° apart")
    ax.set_title(f"Fig. 4: reflectance map of a source array ({combine})\n{what}; k = {k:g}, sharpness = {sharpness:g}",
                 fontsize=9)
    fig.colorbar(im, ax=ax, label="brightness E / A", shrink=0.8)
    return fig


def _three_panels(X, Y, data, xlabel, ylabel, title, limit, note):
    fig, axes = new_figure((12.0, 4.2), 1, 3, sharey=True)
    finite = np.concatenate([np.abs(data[m][np.isfinite(data[m])]).ravel() for m in sens.MODELS])
    vmax = min(limit, float(finite.max())) if finite.size else 1.0
    levels = np.linspace(-vmax, vmax, 25)
    for ax, m in zip(axes, sens.MODELS):
        z = np.clip(data[m], -vmax, vmax)
        cf = ax.contourf(X, Y, z, levels=levels, cmap="RdBu_r", extend="both")
        cs = ax.contour(X, Y, data[m], levels=np.arange(-10.0, 10.5, 0.5), colors="k", linewidths=0.5)
        ax.clabel(cs, fontsize=6, fmt="%.1f")
        ax.set_title(_MODEL_LABELS[m], fontsize=9)
        ax.set_xlabel(xlabel)
        if note:
            ax.text(0.03, 0.5, note, transform=ax.transAxes, fontsize=7, va="center", color="0.3")
    axes[0].set_ylabel(ylabel)
    fig.colorbar(cf, ax=list(axes), label="error 100 (Θ_act − Θ_model) / Θ_act  [%]", shrink=0.9)
    fig.suptitle(title, fontsize=10)
    return fig


def fig05_sensitivity(*, convention="correct", image_x="reference", R=sens.PAPER_R_IN, elevation=None, f=None,
                      limit=6.0):
    """Fig 5: percentage error of the three camera models against x and Δh.

    Parameters
    ----------
    convention : {"correct", "printed"}
        Which form of Eqs 11-14.
    image_x : {"reference", "projected"}
        Which x the models see (:func:`shinysim.theory.sensitivity.theta_models`).
    R : float, inches
    elevation : float, radians, optional
        Source elevation; default the fit to the paper's quoted numbers.
    f : float, inches, optional
        Focal-point height; default the fit.
    limit : float, percent
        Colour scale clipped at ``+-limit`` (the printed equations give about
        100 percent at x < 0, where their camera term has jumped by pi).

    Returns
    -------
    matplotlib.figure.Figure
    """
    d = sens.fig05_data(R=R, elevation=elevation, f=f, convention=convention, image_x=image_x)
    note = None
    if convention == "printed":
        # atan(f/x) jumps by pi at x = 0: about 100 percent error at x < 0.
        for m in sens.MODELS:
            d[m] = np.where(d["x"] < 0, np.nan, d[m])
        note = "x < 0 not shown: the printed\ncamera term atan(f/x) jumps by π"
    title = (f"Fig. 5 ({convention} Eqs 11-17, models see {image_x} x): error vs element position x and height Δh\n"
             f"R = {d['R']:g} in, source elevation {np.rad2deg(d['elevation']):.2f}° "
             f"(polar {90 - np.rad2deg(d['elevation']):.2f}°), focal point f = {d['f']:.3f} in")
    return _three_panels(d["x"], d["dh"], d, "x [in]", "Δh [in]", title, limit, note)


def fig06_source_error(*, convention="correct", image_x="reference", x=None, R=sens.PAPER_R_IN, elevation=None,
                       f=None, limit=15.0):
    """Fig 6: percentage error against source angular error δ and height Δh.

    The models believe the source is at ``elevation``; it is at
    ``elevation + δ``.

    Parameters
    ----------
    convention, image_x, R, elevation, f, limit
        As in :func:`fig05_sensitivity`.
    x : float, inches, optional
        Element position; default the fitted reading of the paper's example,
        0.02 in (at x = 0 the three models coincide).

    Returns
    -------
    matplotlib.figure.Figure
    """
    d = sens.fig06_data(x=x, R=R, elevation=elevation, f=f, convention=convention, image_x=image_x)
    title = (f"Fig. 6 ({convention} Eqs 11-17): error vs source angular error δ and element height Δh\n"
             f"x = {d['x']:g} in, R = {d['R']:g} in, believed source elevation {np.rad2deg(d['elevation']):.2f}°, "
             f"f = {d['f']:.3f} in")
    return _three_panels(d["delta"], d["dh"], d, "source angular error δ [rad]", "Δh [in]", title, limit, None)


def overlay_points(fig, xs, ys, values, *, fmt="{:+.2f}"):
    """Mark measured points on the three model panels of Figs. 5-6, coloured on the contour scale.

    Parameters
    ----------
    fig : matplotlib Figure
        As returned by :func:`fig05_sensitivity` or :func:`fig06_source_error`.
    xs, ys : (n,) array_like
        Positions in the panels' axis units.
    values : dict of str -> (n,) array_like
        The value at each point per model (e.g. percentage error), labelled.
    fmt : str
        Label format.
    """
    for ax, m in zip(fig.axes[:3], sens.MODELS):
        y_lo, y_hi = ax.get_ylim()
        cs = ax.collections[0]  # the filled contours
        ax.scatter(xs, ys, c=np.clip(values[m], cs.norm.vmin, cs.norm.vmax), cmap=cs.cmap, norm=cs.norm, s=46,
                   edgecolors="k", linewidths=0.9, zorder=5, clip_on=False)
        for x, y, v in zip(xs, ys, values[m]):
            below = y > y_lo + 0.85 * (y_hi - y_lo)  # keep labels of the top row inside the panel
            ax.annotate(fmt.format(v), (x, y), xytext=(0, -7 if below else 6), textcoords="offset points",
                        ha="center", va="top" if below else "bottom", fontsize=6, color="k", zorder=6,
                        annotation_clip=False,
                        bbox={"boxstyle": "round,pad=0.1", "fc": "white", "ec": "none", "alpha": 0.6})


def save_figures(outdir, *, dpi=110, overwrite=False):
    """Write Figs 3-6 (both conventions for 5 and 6, both layouts for 4) as PNG.

    Parameters
    ----------
    outdir : str or path-like
        Created if missing.
    dpi : int
    overwrite : bool
        Replace existing files (else ``FileExistsError`` before any is written).

    Returns
    -------
    list of pathlib.Path
    """
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    figs = {
        "fig03_reflectance_map.png": fig03_reflectance_map(),
        "fig04_semicircle.png": fig04_reflectance_map_array(layout="semicircle"),
        "fig04_dome.png": fig04_reflectance_map_array(layout="dome"),
        "fig05_correct.png": fig05_sensitivity(convention="correct"),
        "fig05_printed.png": fig05_sensitivity(convention="printed"),
        "fig05_correct_projected.png": fig05_sensitivity(convention="correct", image_x="projected"),
        "fig06_correct.png": fig06_source_error(convention="correct"),
        "fig06_printed.png": fig06_source_error(convention="printed"),
    }
    check_free(outdir, figs, overwrite)
    paths = []
    for name, fig in figs.items():
        paths.append(write_file(outdir / name, lambda tmp, fig=fig: fig.savefig(tmp, dpi=dpi, format="png"),
                                overwrite=overwrite))
    return paths
