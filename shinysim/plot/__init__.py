"""Drawing (matplotlib only, imported inside the functions): never rendering.

* :mod:`shinysim.plot.scan`: a scan's highlights and normals (Figs. 9b, 10);
* :mod:`shinysim.plot.theory`: the analytic Figs. 3-6;
* :mod:`shinysim.plot.solder`: a solder joint's cross-section (Fig. 12);
* :mod:`shinysim.plot.stereo`: structured-highlight stereo, Figs. 13, 14, 16-18;
* :mod:`shinysim.plot.stereo_scan`: a stereo scan's matches in both views (Figs. 15-16);
* :mod:`shinysim.plot.calibration`: the calibration study's figure;
* :mod:`shinysim.plot.deflect`: display deflectometry's slope maps against a reference;
* :mod:`shinysim.plot.caption`: a new figure, and a figure with its caption under it, as PNG.

Importing this package imports none of its parts, nor matplotlib.
"""

from .._shared import lazy_face

__all__ = lazy_face(__name__, (
    "calibration", "caption", "deflect", "scan", "solder", "stereo", "stereo_scan", "theory"), {
    "calibration": ("calibration_figure",),
    "caption": ("captioned_png", "new_figure"),
    "deflect": ("deflect_figure", "fringe_figure", "real_vs_render_figure", "twin_figure"),
    "scan": ("scan_figure", "needle_image_axes", "side_view_axes"),
    "solder": ("draw_profile",),
    "stereo": ("fig13_stereo_geometry", "fig14_z_theta", "fig16_candidates", "fig17_matching",
               "fig18_gradient_loci", "fig16_scene"),
    "stereo_scan": ("stereo_matches_figure",),
    "theory": ("dome_source_directions", "fig03_reflectance_map", "fig04_reflectance_map_array",
               "fig05_sensitivity", "fig06_source_error", "overlay_points", "save_figures",
               "shiny_source_directions"),
})
