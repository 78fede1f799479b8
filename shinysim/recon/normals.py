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
"""

from __future__ import annotations

import numpy as np

from ..conventions import bisector

__all__ = ["NORMAL_MODELS", "surface_points", "highlight_normals"]

#: The camera models, best-informed first.
NORMAL_MODELS = ("perspective", "orthographic", "fixed")


def surface_points(rows, cols, rig, *, model="perspective", camera_index=0, plane_z=None):
    """The surface point each model assumes for highlights at (rows, cols).

    Returns
    -------
    (N, 3) ndarray, millimetres
    """
    if model not in NORMAL_MODELS:
        raise ValueError(f"model must be one of {NORMAL_MODELS}, got {model!r}")
    cam = rig.cameras[camera_index]
    z = rig.reference_z if plane_z is None else float(plane_z)
    rows = np.asarray(rows, dtype=float)
    if model == "fixed":
        return np.broadcast_to(np.array([0.0, 0.0, z]), rows.shape + (3,)).copy()
    return cam.backproject_to_plane(rows, cols, z)


def highlight_normals(rows, cols, sources, rig, *, model="perspective", camera_index=0, plane_z=None):
    """Unit surface normals at highlights.

    Parameters
    ----------
    rows, cols : (N,) array_like
        Highlight centroids, continuous pixel coordinates.
    sources : (N,) int array_like
        Index of the source that made each highlight.
    rig : Rig
    model : {"perspective", "orthographic", "fixed"}
    camera_index : int
    plane_z : float, optional
        Reference plane height (default ``rig.reference_z``), millimetres.

    Returns
    -------
    (N, 3) ndarray
        Unit normals in the world frame; NaN where the pixel ray misses the
        reference plane.
    """
    cam = rig.cameras[camera_index]
    points = surface_points(rows, cols, rig, model=model, camera_index=camera_index, plane_z=plane_z)
    to_source = rig.source_directions(points, sources)
    if model == "perspective":
        to_viewer = cam.view_directions(points)
    else:
        to_viewer = np.broadcast_to(-cam.forward, points.shape)
    return bisector(to_source, to_viewer)
