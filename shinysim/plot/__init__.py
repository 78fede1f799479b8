"""Drawing (matplotlib only, imported inside the functions): never rendering.

* :mod:`shinysim.plot.scan`: a scan's highlights and normals (Figs. 9b, 10);
* :mod:`shinysim.plot.theory`: the analytic Figs. 3-6;
* :mod:`shinysim.plot.solder`: a solder joint's cross-section (Fig. 12);
* :mod:`shinysim.plot.stereo`: structured-highlight stereo, Figs. 13, 14, 16-18;
* :mod:`shinysim.plot.caption`: a figure with its caption under it, as PNG.

Importing this package does not import matplotlib.
"""

from .caption import captioned_png
from .scan import needle_image_axes, scan_figure, side_view_axes
from .solder import draw_profile
from .stereo import (
    fig13_stereo_geometry,
    fig14_z_theta,
    fig16_candidates,
    fig17_matching,
    fig18_gradient_loci,
)
from .theory import (
    fig03_reflectance_map,
    fig04_reflectance_map_array,
    fig05_sensitivity,
    fig06_source_error,
    overlay_points,
    save_figures,
)

__all__ = [
    "captioned_png",
    "needle_image_axes",
    "side_view_axes",
    "scan_figure",
    "draw_profile",
    "fig03_reflectance_map",
    "fig04_reflectance_map_array",
    "fig05_sensitivity",
    "fig06_source_error",
    "fig13_stereo_geometry",
    "fig14_z_theta",
    "fig16_candidates",
    "fig17_matching",
    "fig18_gradient_loci",
    "overlay_points",
    "save_figures",
]
