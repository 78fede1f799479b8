"""The paper's figures, regenerated: ``shinysim figures OUT``.

:func:`make_figures` writes one captioned PNG per figure (names in
:data:`FIGURE_FILES`), with the captions also in ``captions.json`` and
``README.md``; existing files are never replaced unless ``overwrite=True``.
matplotlib is imported inside the functions; Figs. 5, 6, 9b, 10 and 12 need
the ``render`` extra, the stereo Figs. 13-18 are analytic. Which file shows
what: ``docs/paper-map.md``, section "Quick index of figure files".
"""

from __future__ import annotations

import os
from functools import cache
from types import SimpleNamespace

import numpy as np

from .._shared import (
    Progress,
    check_choice,
    output_folder,
    write_bytes,
    write_json,
    write_text,
)
from ..conventions import MM_PER_INCH
from ..plot import stereo as stereo_plot
from ..plot.caption import captioned_png, new_figure
from ..plot.scan import needle_image_axes, side_view_axes
from ..plot.theory import fig03_reflectance_map, fig04_reflectance_map_array, fig05_sensitivity, fig06_source_error
from ..plot.theory import overlay_points
from ..theory.sensitivity import MODELS

__all__ = ["FIGURE_FILES", "make_figures"]

#: What :func:`make_figures` draws into each PNG, in order: ``job(run)`` returns the figure and its caption;
#: ``run`` holds ``quick``, ``progress``, and ``scan()`` and ``scene()``, each made once, when first asked for.
_JOBS = {
    "fig03_reflectance_map.png": lambda run: _fig03(),
    "fig04_reflectance_map_array.png": lambda run: _fig04(),
    "fig05_sensitivity.png": lambda run: _fig05(run.quick, run.progress)[:2],
    "fig05_printed.png": lambda run: _fig05_printed(),
    "fig06_source_error.png": lambda run: _fig06(run.quick, run.progress)[:2],
    "fig06_printed.png": lambda run: _fig06_printed(),
    "fig09b_highlights.png": lambda run: _fig09b(run.scan()),
    "fig10_side_view.png": lambda run: _fig10(run.scan()),
    "fig12_solder_profile.png": lambda run: _fig12(run.quick),
    "fig13_stereo_geometry.png": lambda run: stereo_plot.fig13_stereo_geometry(),
    "fig14_z_theta.png": lambda run: stereo_plot.fig14_z_theta(),
    "fig16_candidates.png": lambda run: stereo_plot.fig16_candidates(run.scene()),
    "fig17_matching.png": lambda run: stereo_plot.fig17_matching(run.scene()),
    "fig18_gradient_loci.png": lambda run: stereo_plot.fig18_gradient_loci(),
}

#: The files :func:`make_figures` writes, in order.
FIGURE_FILES = (*_JOBS, "captions.json", "README.md")


def _fig12(quick):
    from .solder import fig12_solder_profile

    fig, ax = new_figure((7.0, 5.0), 1, 1)
    cap = fig12_solder_profile(ax, quick=quick)
    return fig, cap


def _fig03():
    fig = fig03_reflectance_map()
    cap = ("Fig. 3 (analytic). Reflectance map of the paper's Eq 5 (clamped, exponent 'sharpness') for one distant "
           "source at polar angle 40°, azimuth 30°, k = 0.3, sharpness 20, seen along +z. Gradient space "
           "p = dz/dx, q = dz/dy, normal ∝ (−p, −q, 1), the same mapping for the source (S, cyan star). "
           "P (red cross) is the specular peak, the normal bisecting source and viewer; orange lines are "
           "brightness contours at 0.3-0.9 of the peak (the paper's near-ellipses).")
    return fig, cap


def _fig04():
    fig, (a1, a2) = new_figure((12.5, 5.2), 1, 2)
    fig04_reflectance_map_array(a1, layout="semicircle")
    fig04_reflectance_map_array(a2, layout="dome")
    cap = ("Fig. 4 (analytic). Reflectance map of a whole source array, Eq 5 with k = 0.05 and sharpness 500 "
           "(half-width 1.5°, the GGX roughness alpha = 0.041), each source's map combined by maximum (sources lit "
           "one at a time). Left: the 21 SHINY fibers at signed polar angles −84°…+76°, 8° apart in the x-z plane: "
           "their peaks (cyan dots) lie on q = 0 at p = −tan(θ/2). Right: a hemispherical dome of sources 8° apart, "
           "the paper's 'spherical array'. Scanning the sources samples the reflectance map at these peaks.")
    return fig, cap


def _stage(progress, stage):
    """``progress(done, total)`` of a sub-step reported as ``progress(stage, done, total)``."""
    return (lambda done, total: progress(stage, done, total)) if progress else None


def _overlay_facets(fig, xs, r):
    """Mark the rendered facets of ``r`` on Fig. 5 or 6; the largest |measured - analytic|, degrees."""
    overlay_points(fig, xs, r["dh_mm"] / MM_PER_INCH, r["measured_percent"])
    return np.max([np.abs(r["measured_deg"][m] - r["analytic_deg"][m]) for m in MODELS])


def _fig05(quick, progress):
    from .camera_models import fig05_comparison, within_tolerance

    r = fig05_comparison(quick=quick, progress=_stage(progress, "fig05 facets"))
    fig = fig05_sensitivity(convention="correct", image_x="projected")
    diff = _overlay_facets(fig, r["x_mm"] / MM_PER_INCH, r)
    ok = all(within_tolerance(r["measured_deg"][m], r["analytic_deg"][m]).all() for m in MODELS)
    s = r["settings"]
    cap = ("Fig. 5 (analytic, with simulation). Percentage error 100 (Θ_act − Θ_model)/Θ_act of the three camera "
           "models against the surface element's position x and height Δh, from Eqs 11-14 in their geometrically "
           "correct form (ERRATA: camera term atan2(f, −x), f − Δh in Eq 14), with the models told the position a "
           "camera calibrated on the reference plane reports, x f/(f − Δh). Source at R = 1.7 in, 46.67° above the "
           "horizontal, focal point f = 2.115 in: the parameters under which the printed equations give the "
           "paper's quoted 1.25, 0.85, 0.91 %. "
           f"Circles (labelled in %): {len(r['x_mm'])} rendered mirror facets {s['facet_mm']:g} mm across at "
           f"(x, Δh), alpha = {s['alpha']:g}, each turned to reflect the source into the camera; Mitsuba "
           f"{s['resolution']} px, {s['spp']} spp; highlight centroid -> shinysim's three camera models -> "
           f"error against the facet's normal. Largest |measured − analytic| = {diff:.4f}°"
           f"{' (all within 10 % or 0.02°)' if ok else ''}.")
    return fig, cap, r


def _fig05_printed():
    fig = fig05_sensitivity(convention="printed")
    cap = ("Fig. 5 as published (analytic): Eqs 11-17 exactly as printed (camera term atan(f/x), f + Δh in Eq 14), "
           "models told the element's true x, at the fitted source elevation 46.67° and f = 2.115 in. x < 0 is "
           "blank: the printed camera term jumps by π at x = 0. These equations reproduce the quoted 1.25, 0.85 "
           "and 0.91 % at x = 0.02 in, Δh = 0.05 in; the rendered facets follow the correct form "
           "(fig05_sensitivity.png), not this one (docs/theory.md).")
    return fig, cap


def _fig06(quick, progress):
    from .camera_models import fig06_comparison

    r = fig06_comparison(quick=quick, progress=_stage(progress, "fig06 facets"))
    fig = fig06_source_error(convention="correct", image_x="projected")
    diff = _overlay_facets(fig, r["source_error"], r)
    s = r["settings"]
    cap = ("Fig. 6 (analytic, with simulation). Percentage error of the three camera models when the source is "
           "really at elevation 46.67° + δ but the models believe 46.67° (same R = 1.7 in), against δ and the "
           "element height Δh, at x = 0.02 in, f = 2.115 in; correct Eqs 11-14 with the projected image position. "
           f"Circles: {len(r['x_mm'])} rendered mirror facets ({s['facet_mm']:g} mm, alpha = {s['alpha']:g}, "
           f"{s['resolution']} px, {s['spp']} spp) lit by the displaced source and reconstructed with the "
           f"believed one. Largest |measured − analytic| = {diff:.4f}°. The paper asks for source errors "
           "below 0.1 rad.")
    return fig, cap, r


def _fig06_printed():
    fig = fig06_source_error(convention="printed")
    cap = ("Fig. 6 as published (analytic): the printed Eqs 11-17 at x = 0.02 in, source elevation 46.67° + δ "
           "(believed 46.67°), f = 2.115 in.")
    return fig, cap


def _scan(quick, progress):
    from ..evaluate import score_reconstruction
    from ..objects.sphere import SHINY_SPHERE_RADIUS_MM
    from ..recon import reconstruct
    from ..rig import shiny_1988
    from ..sim.render import Simulator
    from ..sim.objects import scene_objects

    res, spp, alpha = (160, 8, 0.02) if quick else (512, 64, 0.02)
    rig = shiny_1988(resolution=res)
    sim = Simulator(rig, scene_objects("sphere", alpha=alpha))
    truth = sim.render_truth()
    stack = sim.render_stack(spp=spp, seed=0,
                             progress=_stage(progress, "fig09b/10 scan"))
    recon = reconstruct(stack, threshold=0.5)
    score = score_reconstruction(recon, truth, sphere_center=(0.0, 0.0, 0.0), sphere_radius=SHINY_SPHERE_RADIUS_MM)
    return {"stack": stack, "truth": truth, "recon": recon, "score": score, "resolution": res, "spp": spp,
            "alpha": alpha, "radius": SHINY_SPHERE_RADIUS_MM}


def _scores_line(score):
    return "; ".join(f"{m} median {score[m]['median_deg']:.3f}°, max {score[m]['max_deg']:.3f}°" for m in MODELS)


def _fig09b(scan):
    fig, ax = new_figure((6.4, 6.2), 1, 1)
    needle_image_axes(ax, scan["stack"], scan["recon"], "fixed", truth=scan["truth"])
    sc = scan["score"]
    cap = ("Fig. 9b (simulation where the paper photographed). The 1/16 in calibration sphere (GGX alpha = "
           f"{scan['alpha']:g}) rendered under the SHINY rig: 21 fibers 1.016 mm across on a 1.7 in semicircle, "
           f"perspective camera 5 in above, {scan['resolution']} px over 2 mm, {scan['spp']} spp, one frame per "
           "fiber. Background: the brightest value of all frames over a dim shading of the sphere. Dots: highlight "
           "centroids (threshold I0 = 0.5 of each frame's peak); needles: the image-plane projection of the "
           f"normal recovered by the fixed model (Eq 10/13), coloured by fiber. {len(scan['recon'])} highlights. "
           f"Angular error against the rendered truth: {_scores_line(sc)}.")
    return fig, cap


def _fig10(scan):
    fig, ax = new_figure((6.4, 6.0), 1, 1)
    s = scan["score"]["fixed"]
    side_view_axes(ax, scan["recon"], "fixed", scan["truth"], s, sphere_radius=scan["radius"])
    cen = {m: 1000 * scan["score"][m]["centre_error_mm"] for m in MODELS}
    cap = ("Fig. 10 (simulation where the paper measured). Side view (x-z) of the same simulated scan: each "
           "recovered normal (fixed model) drawn as a line through the true surface point of its highlight. For "
           "a sphere every true normal passes through the centre; the least-squares point nearest to all lines "
           f"lies {cen['fixed']:.1f} µm from the true centre ({s['centre_error_percent_radius']:.2f} % of the "
           f"radius; perspective {cen['perspective']:.1f} µm, orthographic {cen['orthographic']:.1f} µm). "
           f"{scan['resolution']} px, {scan['spp']} spp, alpha = {scan['alpha']:g}.")
    return fig, cap


def make_figures(out_dir: str | os.PathLike, *, quick: bool = False, overwrite: bool = False,
                 progress: Progress | None = None) -> dict[str, str]:
    """Write the paper's Figs. 3, 4, 5, 6, 9b, 10, 12, 13, 14, 16, 17 and 18 as captioned PNG files.

    Parameters
    ----------
    out_dir : str or path-like
        Created if missing.
    quick : bool
        Small renders (a 160 px scan at 8 spp, four facets per figure at 192
        px; about 10 s) for tests; the default is the 512 px, 64 spp scan,
        the 5 x 5 Fig. 5 grid and the 3 x 3 Fig. 6 grid of facets at 256 px
        (under a minute on two cores).
    overwrite : bool
        Replace existing files. Without it, any of :data:`FIGURE_FILES`
        already in ``out_dir`` stops the run before anything is rendered.
    progress : callable, optional
        ``progress(stage, done, total)``.

    Returns
    -------
    dict of str -> str
        File name -> caption, for the PNG files written.

    Raises
    ------
    FileExistsError
        ``out_dir`` already holds one of the files and ``overwrite`` is False.
    """
    check_choice("quick", quick, (True, False))
    with output_folder(out_dir, FIGURE_FILES, overwrite=overwrite, needed_bytes=32 * 2**20, last="README.md") as tmp:
        return _write_figures(tmp, quick, progress)


def _write_figures(out, quick, progress):
    """Make the figures into the (new, empty) folder ``out``."""
    run = SimpleNamespace(quick=quick, progress=progress, scan=cache(lambda: _scan(quick, progress)),
                          scene=cache(stereo_plot.fig16_scene))
    captions = {}
    for done, (name, job) in enumerate(_JOBS.items(), 1):
        fig, captions[name] = job(run)
        write_bytes(out / name, captioned_png(fig, captions[name]))
        if progress:
            progress("figures", done, len(_JOBS))
    settings = "quick (small renders)" if quick else "full"
    write_json(out / "captions.json", {"settings": settings, "figures": captions}, ensure_ascii=False)
    md = ["# Figures of Sanderson, Weiss & Nayar (1988), regenerated by shinysim", "",
          f"Made by `shinysim figures` ({settings} settings). Each PNG carries its caption.", ""]
    for name, cap in captions.items():
        md += [f"## {name}", "", f"![{name}]({name})", "", cap, ""]
    write_text(out / "README.md", "\n".join(md))
    return captions
