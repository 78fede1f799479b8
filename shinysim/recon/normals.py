"""Surface normals from highlights under the paper's three camera models.

A highlight says the surface normal bisects the directions to its source and
to the viewer; each model of :data:`NORMAL_MODELS` fixes the unknown height
of the surface point differently: ``"perspective"`` (Eq 12) and
``"orthographic"`` (Eq 11) put it where the pixel's ray meets the reference
plane, ``"fixed"`` (Eqs 10, 13) at the plane's origin, and ``"near-field"``
(not the paper's, :mod:`shinysim.recon.nearfield`) refines points and
normals together from an anchor. :func:`highlight_normals` and
:func:`surface_points` apply them. The models compared: ``docs/camera-models.md``.
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
