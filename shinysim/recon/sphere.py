"""Calibration with a sphere of known geometry.

* :func:`sphere_from_mask`: centre and radius of a sphere's silhouette.
* :func:`sphere_normals`: the true normals of that sphere at image points
  (orthographic view), the reference for real photographs.
* :func:`lights_from_highlights`: the inverse use of a structured-highlight
  scan, recovering each distant light's direction from its highlight on a
  mirror sphere (mirror law ``l = 2 (n . v) n - v``).

numpy + scikit-image only.
"""

from __future__ import annotations

import numpy as np

from ..conventions import normalize
from ..errors import OptionError

__all__ = ["sphere_from_mask", "sphere_normals", "lights_from_highlights"]


def sphere_from_mask(mask):
    """Centre (row, col) and radius (pixels) of a sphere's silhouette.

    The centre is the mask's centroid and the radius ``sqrt(area / pi)``:
    both use every pixel, so they are far less noisy than a boundary fit
    (sub-pixel for a radius of ~100 px). Soft (anti-aliased) masks are
    read as coverage fractions.

    Parameters
    ----------
    mask : (H, W) bool or float in [0, 1]

    Returns
    -------
    center : (2,) ndarray, (row, col)
    radius : float, pixels
    """
    m = np.asarray(mask, dtype=float)
    if m.ndim != 2:
        raise OptionError(f"mask must be 2-D, got shape {m.shape}")
    if m.max() > 1:
        m = m / m.max()
    area = m.sum()
    if area <= 0:
        raise OptionError("mask is empty: no sphere pixels")
    rows, cols = np.indices(m.shape)
    center = np.array([(m * rows).sum() / area, (m * cols).sum() / area])
    return center, float(np.sqrt(area / np.pi))


def sphere_normals(rows, cols, center, radius, camera):
    """True normals of a sphere at image points, orthographic camera.

    Parameters
    ----------
    rows, cols : (N,) array_like
    center : (2,) (row, col) of the sphere centre, pixels
    radius : float, pixels
    camera : shinysim.rig.Camera
        Orthographic; fixes which world directions image +col/+row are.

    Returns
    -------
    (N, 3) ndarray
        NaN for points outside the silhouette.
    """
    rows = np.asarray(rows, float)
    cols = np.asarray(cols, float)
    u = (cols - center[1]) / radius
    v = (rows - center[0]) / radius
    with np.errstate(invalid="ignore"):
        w = np.sqrt(1.0 - u**2 - v**2)
    n = u[..., None] * camera.right + v[..., None] * camera.down + w[..., None] * (-camera.forward)
    return normalize(n)


def lights_from_highlights(normals, camera):
    """Distant light directions from highlight normals (mirror law).

    ``l = 2 (n . v) n - v`` with ``v`` the direction to an orthographic
    camera: a mirror sphere of known geometry calibrates the lights.

    Returns
    -------
    (N, 3) ndarray of unit vectors
    """
    n = normalize(normals)
    v = -camera.forward
    return normalize(2.0 * (n @ v)[..., None] * n - v)
