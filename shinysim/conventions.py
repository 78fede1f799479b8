r"""Coordinate frames, units and angle conventions used everywhere in shinysim.

Every other module refers to this one; nothing else defines a frame.

World frame (millimetres)::

              +z  (towards the camera)
               ^
               |      camera (perspective centre at (0, 0, H),
               |       or orthographic rays parallel to -z)
               |
        S_k *  |  * S_j     sources on a semicircle of radius R in the
             \ | /          x-z plane (SHINY preset)
              \|/
    ----------(O)----------> +x      reference plane z = 0, object at O
              /
             /
           +y  (out of the page; right-handed: x cross y = z)

Image frame (continuous pixel coordinates, scikit-image style)::

    (0, 0) ----------------> col   (increases with +x for the default camera)
      |
      |     pixel (r, c) has its centre at (r, c) and covers
      |     [r - 0.5, r + 0.5] x [c - 0.5, c + 0.5]
      v
     row                   (increases with -y for the default camera)

A camera's own frame: ``forward`` points along its optical axis (from the
camera towards the scene), ``right`` = normalize(forward x up) is the image
+col direction and ``down`` = forward x right is the image +row direction.
For the default camera (forward = -z, up = +y): right = +x, down = -y.

Angles:

* polar angle ``theta`` is measured from +z, azimuth ``phi`` from +x towards
  +y: ``v(theta, phi) = (sin t cos p, sin t sin p, cos t)`` (paper Eq 10).
* In the plane of the SHINY semicircle (y = 0) a source's *signed* polar angle
  is positive towards +x.
* Gradient space: ``p = dz/dx``, ``q = dz/dy`` and the surface normal is
  ``n ~ (-p, -q, 1)`` (paper Eqs 1-2). The same mapping is used for source
  directions (see the ERRATA notes in ``docs/paper-errata.md``).
* The paper's camera-model analysis (Eqs 11-17) measures its angle
  ``Theta`` from the horizontal +x axis, not from +z; use
  :func:`elevation_from_x` for that reading.

Units: millimetres and radians inside the library; degrees only in reports,
inches only at the edges (presets, paper figures) through :data:`MM_PER_INCH`.

Arrays: vectors keep their components on the last axis, so every function
here accepts a single vector, a list of vectors or an image of them.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "MM_PER_INCH",
    "VIEW_UP",
    "inch_to_mm",
    "mm_to_inch",
    "normalize",
    "direction_from_angles",
    "angles_from_direction",
    "normal_from_gradient",
    "gradient_from_normal",
    "bisector",
    "angle_between",
    "elevation_from_x",
]

#: Exact definition of the inch.
MM_PER_INCH = 25.4

#: Unit vector from the object towards a camera looking straight down (-z).
VIEW_UP = np.array([0.0, 0.0, 1.0])


def inch_to_mm(value):
    """Convert inches to millimetres (exact, 25.4 mm per inch)."""
    return np.asarray(value, dtype=float) * MM_PER_INCH


def mm_to_inch(value):
    """Convert millimetres to inches (exact, 25.4 mm per inch)."""
    return np.asarray(value, dtype=float) / MM_PER_INCH


def normalize(v):
    """Unit vectors along the last axis.

    Parameters
    ----------
    v : (..., 3) array_like
        Vectors. Zero vectors give NaN (not a silent zero).

    Returns
    -------
    (..., 3) ndarray of float64
    """
    v = np.asarray(v, dtype=float)
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = v / norm
    return np.where(norm > 0, out, np.nan)


def direction_from_angles(theta, phi=0.0):
    """Unit vector ``v(theta, phi)`` of paper Eq 10.

    Parameters
    ----------
    theta : array_like, radians
        Polar angle from +z.
    phi : array_like, radians
        Azimuth from +x towards +y.

    Returns
    -------
    (..., 3) ndarray
    """
    theta, phi = np.broadcast_arrays(np.asarray(theta, float), np.asarray(phi, float))
    st = np.sin(theta)
    return np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta)], axis=-1)


def angles_from_direction(v):
    """Polar angle from +z and azimuth from +x, radians, of (..., 3) vectors."""
    v = normalize(v)
    theta = np.arccos(np.clip(v[..., 2], -1.0, 1.0))
    phi = np.arctan2(v[..., 1], v[..., 0])
    return theta, phi


def normal_from_gradient(p, q):
    """Unit normal ``(-p, -q, 1) / sqrt(1 + p^2 + q^2)`` from gradient (p, q)."""
    p, q = np.broadcast_arrays(np.asarray(p, float), np.asarray(q, float))
    return normalize(np.stack([-p, -q, np.ones_like(p)], axis=-1))


def gradient_from_normal(n):
    """Gradient ``(p, q) = (-nx/nz, -ny/nz)`` of (..., 3) normals.

    Normals with ``nz <= 0`` have no gradient and give NaN.
    """
    n = np.asarray(n, dtype=float)
    nz = n[..., 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        p = np.where(nz > 0, -n[..., 0] / nz, np.nan)
        q = np.where(nz > 0, -n[..., 1] / nz, np.nan)
    return p, q


def bisector(a, b):
    """Unit half-vector of two (..., 3) directions (normalised first).

    This is the mirror law solved for the normal: a surface whose normal
    bisects the directions to the source and to the viewer reflects one into
    the other.
    """
    return normalize(normalize(a) + normalize(b))


def angle_between(a, b):
    """Angle in radians between (..., 3) vectors, robust near 0 and pi.

    Uses ``atan2(|a x b|, a . b)``; NaN where either input is NaN.
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    cross = np.linalg.norm(np.cross(a, b), axis=-1)
    dot = np.sum(a * b, axis=-1)
    return np.arctan2(cross, dot)


def elevation_from_x(n):
    """The paper's in-plane angle ``Theta`` of Eqs 11-17, radians.

    Measured in the x-z plane from the horizontal +x axis towards +z, so a
    normal pointing straight up has ``Theta = pi/2``.
    """
    n = np.asarray(n, dtype=float)
    return np.arctan2(n[..., 2], n[..., 0])
