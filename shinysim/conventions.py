"""Coordinate frames, units and angle conventions used everywhere in shinysim.

Every other module refers to this one; nothing else defines a frame. The
frames are drawn in ``docs/conventions.md``: world frame in millimetres, +z
up towards the camera, the SHINY sources in the x-z plane; image (row, col)
with pixel (r, c) centred at (r, c); a camera's ``right`` =
normalize(forward x up) is +col and ``down`` = forward x right is +row.
Polar angle ``theta`` from +z, azimuth ``phi`` from +x towards +y (paper
Eq 10); gradient space ``p = dz/dx``, ``q = dz/dy``, ``n ~ (-p, -q, 1)``
(paper Eqs 1-2); the paper's ``Theta`` of Eqs 11-17 through
:func:`elevation_from_x`. Millimetres and radians inside, degrees in
reports, inches at the edges through :data:`MM_PER_INCH`. Vectors keep their
components on the last axis.
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
