"""Exact specular reflection point on a mirror sphere.

For a sphere and a point source, the highlight seen by a camera lies where
the surface normal bisects the directions to the source and to the camera
(the mirror law). For an orthographic camera this reduces to the closed
equation ``R sin(2t - a) = r sin t`` (``docs/paper-errata.md``); for a
pinhole camera it is Alhazen's problem. Both are solved here exactly (to
float64 round-off) by bisection in the plane that holds the sphere centre,
the source and the camera, and used as the oracle for the simulator and the
reconstruction.

Pure numpy.
"""

from __future__ import annotations

import numpy as np

from ..conventions import normalize

__all__ = ["mirror_sphere_highlight", "orthographic_highlight_angle", "distant_source_error"]


def orthographic_highlight_angle(alpha, source_distance, sphere_radius):
    """Polar angle ``t`` of the normal at the highlight, orthographic camera.

    Solves ``R sin(2t - alpha) = r sin t`` for ``t`` between ``alpha / 2`` and
    ``alpha`` (ERRATA, "Exact highlight on a mirror sphere").

    Parameters
    ----------
    alpha : array_like, radians
        Polar angle of the source from the viewing direction, in [0, pi).
    source_distance : float or array_like, same length unit as radius
        Distance ``R`` from the sphere centre to the source (> radius).
    sphere_radius : float or array_like

    Returns
    -------
    t : ndarray, radians
    """
    alpha, R, r = np.broadcast_arrays(
        np.asarray(alpha, float), np.asarray(source_distance, float), np.asarray(sphere_radius, float)
    )
    lo = 0.5 * alpha
    hi = np.array(alpha, copy=True)
    # f(t) = R sin(2t - a) - r sin t : f(a/2) = -r sin(a/2) <= 0, f(a) = (R - r) sin a >= 0
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        f = R * np.sin(2 * mid - alpha) - r * np.sin(mid)
        neg = f < 0
        lo = np.where(neg, mid, lo)
        hi = np.where(neg, hi, mid)
    return 0.5 * (lo + hi)


def mirror_sphere_highlight(source, *, center=(0.0, 0.0, 0.0), radius, camera_position=None,
                            view_direction=(0.0, 0.0, 1.0)):
    """Exact highlight point and normal of a point source on a mirror sphere.

    Parameters
    ----------
    source : (..., 3) array_like, millimetres
        Source positions.
    center : (3,) array_like, millimetres
    radius : float or (...,) array_like, millimetres
    camera_position : (3,) array_like, optional
        Centre of projection of a pinhole camera. Without it the camera is
        orthographic, looking along ``-view_direction``.
    view_direction : (3,) array_like
        For an orthographic camera: unit direction from the object towards
        the camera.

    Returns
    -------
    point : (..., 3) ndarray
        Highlight point on the sphere.
    normal : (..., 3) ndarray
        Unit normal there.

    Notes
    -----
    The reflection point lies in the plane through the centre, the source
    and the camera. With the polar angle ``t`` of the normal measured from
    the camera direction in that plane, the signed angles from the normal to
    the source and to the camera cancel at the solution, which lies between
    0 and the source's polar angle; bisection on that bracket is exact and
    needs no starting guess.
    """
    S = np.asarray(source, dtype=float)
    O = np.asarray(center, dtype=float)
    rel = S - O
    if camera_position is None:
        e1 = np.broadcast_to(normalize(view_direction), rel.shape)
    else:
        C = np.asarray(camera_position, dtype=float)
        e1 = np.broadcast_to(normalize(C - O), rel.shape)
        c1 = np.sum(np.broadcast_to(C - O, rel.shape) * e1, axis=-1)
    s1 = np.sum(rel * e1, axis=-1)
    perp = rel - s1[..., None] * e1
    s2 = np.linalg.norm(perp, axis=-1)
    # in-plane basis; a source on the axis gives the pole (t = 0)
    e2 = np.where(s2[..., None] > 0, perp / np.where(s2 > 0, s2, 1.0)[..., None], 0.0)

    def f(t):
        n2, n1 = np.sin(t), np.cos(t)
        p2, p1 = radius * n2, radius * n1
        ts2, ts1 = s2 - p2, s1 - p1
        ang_s = np.arctan2(n2 * ts1 - n1 * ts2, n2 * ts2 + n1 * ts1)  # signed angle n -> source
        tc2, tc1 = (np.zeros_like(t), np.ones_like(t)) if camera_position is None else (-p2, c1 - p1)
        ang_c = np.arctan2(n2 * tc1 - n1 * tc2, n2 * tc2 + n1 * tc1)  # signed angle n -> camera
        return ang_s + ang_c

    alpha = np.arctan2(s2, s1)
    lo = np.zeros_like(alpha)
    hi = np.array(alpha, copy=True)
    f_lo = f(lo)
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        fm = f(mid)
        same = np.sign(fm) == np.sign(f_lo)
        lo = np.where(same, mid, lo)
        f_lo = np.where(same, fm, f_lo)
        hi = np.where(same, hi, mid)
    t = 0.5 * (lo + hi)
    normal = np.cos(t)[..., None] * e1 + np.sin(t)[..., None] * e2
    point = O + np.asarray(radius, dtype=float)[..., None] * normal  # a radius per source broadcasts too
    return point, normal


def distant_source_error(alpha, source_distance, sphere_radius, camera_distance=np.inf):
    """First-order error (radians) of the distant-source normal ``alpha/2``.

    ``(r / 2) sin(alpha / 2) (1/R - 1/H)`` (ERRATA): the estimate of paper
    Eq 10 versus the true normal at the highlight of a sphere at the origin.
    """
    alpha = np.asarray(alpha, float)
    return 0.5 * sphere_radius * np.sin(0.5 * alpha) * (1.0 / source_distance - 1.0 / camera_distance)
