"""Surface normals from highlights under the paper's three camera models.

A highlight at image point (row, col) due to source ``k`` means the surface
normal there bisects the directions to the source and to the viewer. What
the reconstruction does not know is the height of the surface point, so
each model fixes it differently (paper Section III, Eqs 10-14; see
``docs/camera-models.md``):

``"perspective"``
    The surface point is where the pixel's ray meets the reference plane;
    source and viewer directions are taken from that point (the viewer is
    the camera's centre of projection). Paper Eq 12.
``"orthographic"``
    Same point on the reference plane, but the viewing direction is the
    camera axis (parallel rays). Paper Eq 11.
``"fixed"``
    Every normal is computed from one reference point, the origin of the
    reference plane, with the viewing direction along the camera axis: the
    distant-source estimate of paper Eq 10 (the normal halves the source's
    polar angle). Paper Eq 13.

For an orthographic camera, "perspective" and "orthographic" coincide; for
distant sources (known by direction), "orthographic" and "fixed" coincide.

``"near-field"``
    Not the paper's: surface points and normals refined together along the
    pixel rays until the integrated normals and the heights agree, from an
    anchor that fixes the height (:mod:`shinysim.recon.nearfield`). It
    removes the three models' bias of placing highlights on the plane.
"""

from __future__ import annotations

import numpy as np

from .._shared import check_choice
from ..conventions import bisector
from ..errors import OptionError

__all__ = ["PAPER_MODELS", "NORMAL_MODELS", "surface_points", "highlight_normals"]

#: The paper's three camera models, best-informed first.
PAPER_MODELS = ("perspective", "orthographic", "fixed")
#: Every normal model: the paper's three and the near-field model (which needs an anchor).
NORMAL_MODELS = PAPER_MODELS + ("near-field",)


def surface_points(rows, cols, rig, *, model="perspective", camera_index=0, plane_z=None):
    """The surface point each model assumes for highlights at (rows, cols).

    Returns
    -------
    (N, 3) ndarray, millimetres
    """
    check_choice("model", model, PAPER_MODELS)
    cam = rig.cameras[camera_index]
    z = rig.reference_z if plane_z is None else float(plane_z)
    rows = np.asarray(rows, dtype=float)
    if model == "fixed":
        return np.broadcast_to(np.array([0.0, 0.0, z]), rows.shape + (3,)).copy()
    return cam.backproject_to_plane(rows, cols, z)


def highlight_normals(rows, cols, sources, rig, *, model="perspective", camera_index=0, plane_z=None, anchor=None):
    """Unit surface normals at highlights.

    Parameters
    ----------
    rows, cols : (N,) array_like
        Highlight centroids, continuous pixel coordinates.
    sources : (N,) int array_like
        Index of the source that made each highlight.
    rig : Rig
    model : {"perspective", "orthographic", "fixed", "near-field"}
    camera_index : int
    plane_z : float, optional
        Reference plane height (default ``rig.reference_z``), millimetres.
    anchor : shinysim.rig.Anchor, optional
        ``"near-field"`` only: what fixes the height (default ``rig.anchor``).

    Returns
    -------
    (N, 3) ndarray
        Unit normals in the world frame; NaN where the pixel ray misses the
        reference plane.
    """
    check_choice("model", model, NORMAL_MODELS)
    if model == "near-field":
        from .nearfield import near_field_normals

        anchor = anchor if anchor is not None else rig.anchor
        if anchor is None:
            raise OptionError("the near-field model needs an anchor (a known surface point or contour): give one, "
                              "or set the rig's 'anchor'", field="anchor")
        return near_field_normals(rows, cols, sources, rig, anchor, camera_index=camera_index,
                                  plane_z=plane_z).normals
    cam = rig.cameras[camera_index]
    points = surface_points(rows, cols, rig, model=model, camera_index=camera_index, plane_z=plane_z)
    to_source = rig.source_directions(points, sources)
    if model == "perspective":
        to_viewer = cam.view_directions(points)
    else:
        to_viewer = np.broadcast_to(-cam.forward, points.shape)
    return bisector(to_source, to_viewer)
