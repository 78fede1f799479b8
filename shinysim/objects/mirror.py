"""A large mirror facet of known shape: a paraboloid with a known ripple, and its exact truth.

The mirror of display deflectometry (a heliostat facet a metre across, seen
from metres away): a rectangle in its own frame, centred at the origin, +z its
design normal, with the height

``z = x^2 / (4 fx) + y^2 / (4 fy) + a sin(2 pi (x cos t + y sin t) / P)``

(focal lengths ``fx``, ``fy``, infinite for flat, negative for a surface
that falls away from +z; a ripple of amplitude ``a``, period ``P`` and
direction ``t``, the known small error a measurement should find). Heights,
slopes, normals and ray intersections are exact (analytic, or Newton's method
to rounding); :mod:`shinysim.sim.display` renders the facet and
:mod:`shinysim.rig.display` places it in a rig. numpy only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ..errors import OptionError
from .shapes import TriangleMesh

__all__ = ["INTERSECT_TOLERANCE_MM", "MESH_TOLERANCE_MM", "MirrorFacet"]

#: How close :meth:`MirrorFacet.intersect` brings a ray's point to the surface, millimetres (the Newton
#: iteration stops when its step is below this; a float64 height near 1e3 mm is exact to ~1e-13).
INTERSECT_TOLERANCE_MM = 1e-11

#: The default bound on how far :meth:`MirrorFacet.triangle_mesh`'s triangles stray from the surface, millimetres
#: (a slope error of 1e-4 mm over a 5 mm triangle is 2e-5 rad, a tenth of a SOFAST measurement's noise).
MESH_TOLERANCE_MM = 1e-4


def _positive(name, value):
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not (math.isfinite(value) and value > 0):
        raise OptionError(f"must be a finite number > 0 mm, got {value!r}", field=name)
    return float(value)


def _finite(name, value):
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not math.isfinite(value):
        raise OptionError(f"must be a finite number, got {value!r}", field=name)
    return float(value)


@dataclass(frozen=True)
class MirrorFacet:
    """A rectangular mirror: a paraboloid with a sinusoidal ripple, in its own frame.

    Parameters
    ----------
    half_width_mm, half_height_mm : float, millimetres
        Half sides along x and y; the facet is ``|x| <= half_width_mm``,
        ``|y| <= half_height_mm``, centred at the origin.
    focal_mm : (fx, fy), millimetres
        Focal lengths of the paraboloid ``x^2 / (4 fx) + y^2 / (4 fy)``;
        ``inf`` is flat along that axis, a negative one falls away from +z
        (SOFAST reports its heliostat facet as about (-136, -146) m in a
        frame whose +z faces the camera). Not 0, not NaN.
    ripple_mm : float, millimetres
        Amplitude ``a`` of the ripple ``a sin(2 pi (x cos t + y sin t) / P)``
        (0: none).
    ripple_period_mm : float, millimetres
        Its period ``P``, > 0.
    ripple_angle_rad : float, radians
        Its direction ``t`` in the facet plane, from +x towards +y.

    Examples
    --------
    >>> f = MirrorFacet(606.0, 606.0, focal_mm=(1000.0, np.inf))
    >>> float(f.height(100.0, 50.0)), f.slopes(100.0, 50.0).tolist()
    (2.5, [0.05, 0.0])
    """

    half_width_mm: float
    half_height_mm: float
    focal_mm: tuple[float, float] = (math.inf, math.inf)
    ripple_mm: float = 0.0
    ripple_period_mm: float = 400.0
    ripple_angle_rad: float = 0.0

    def __post_init__(self):
        object.__setattr__(self, "half_width_mm", _positive("half_width_mm", self.half_width_mm))
        object.__setattr__(self, "half_height_mm", _positive("half_height_mm", self.half_height_mm))
        try:
            f = tuple(float(v) for v in self.focal_mm)
        except (TypeError, ValueError):
            f = ()
        if len(f) != 2 or any(math.isnan(v) or v == 0.0 for v in f) or any(
                isinstance(v, (bool, np.bool_)) for v in self.focal_mm):
            raise OptionError(f"must be two focal lengths (fx, fy) in mm, non-zero (inf: flat), got "
                              f"{self.focal_mm!r}", field="focal_mm")
        object.__setattr__(self, "focal_mm", f)
        object.__setattr__(self, "ripple_mm", _finite("ripple_mm", self.ripple_mm))
        object.__setattr__(self, "ripple_period_mm", _positive("ripple_period_mm", self.ripple_period_mm))
        object.__setattr__(self, "ripple_angle_rad", _finite("ripple_angle_rad", self.ripple_angle_rad))

    # -- the surface -------------------------------------------------------------
    @property
    def curvature(self) -> tuple[float, float]:
        """``(1 / (2 fx), 1 / (2 fy))``: the paraboloid's second derivatives d2z/dx2, d2z/dy2 (1/mm)."""
        return (0.5 / self.focal_mm[0], 0.5 / self.focal_mm[1])

    def _phase(self, x, y):
        k = 2.0 * math.pi / self.ripple_period_mm
        c, s = math.cos(self.ripple_angle_rad), math.sin(self.ripple_angle_rad)
        return k * (x * c + y * s), k, c, s

    def height(self, x: ArrayLike, y: ArrayLike) -> np.ndarray:
        """The surface height ``z(x, y)``, millimetres.

        Parameters
        ----------
        x, y : array_like, millimetres
            Facet-frame coordinates (broadcast together). Points off the
            facet get the height of the surface's continuation.

        Returns
        -------
        ndarray, millimetres
        """
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        cx, cy = self.curvature
        z = 0.5 * cx * x * x + 0.5 * cy * y * y
        if self.ripple_mm != 0.0:
            phase, _, _, _ = self._phase(x, y)
            z = z + self.ripple_mm * np.sin(phase)
        return z

    def slopes(self, x: ArrayLike, y: ArrayLike) -> np.ndarray:
        """Exact slopes ``(dz/dx, dz/dy)``.

        Returns
        -------
        (..., 2) ndarray
        """
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        cx, cy = self.curvature
        p = cx * x
        q = cy * y
        if self.ripple_mm != 0.0:
            phase, k, c, s = self._phase(x, y)
            g = self.ripple_mm * k * np.cos(phase)
            p = p + g * c
            q = q + g * s
        p, q = np.broadcast_arrays(p, q)
        return np.stack([p, q], axis=-1)

    def curvatures(self, x: ArrayLike, y: ArrayLike) -> np.ndarray:
        """Exact second derivatives ``(z_xx, z_xy, z_yy)``, 1/mm.

        Returns
        -------
        (..., 3) ndarray
        """
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        cx, cy = self.curvature
        zxx = np.full(np.broadcast(x, y).shape, cx)
        zyy = np.full(zxx.shape, cy)
        zxy = np.zeros(zxx.shape)
        if self.ripple_mm != 0.0:
            phase, k, c, s = self._phase(x, y)
            g = -self.ripple_mm * k * k * np.sin(phase)
            zxx, zxy, zyy = zxx + g * c * c, zxy + g * c * s, zyy + g * s * s
        return np.stack([zxx, zxy, zyy], axis=-1)

    def normal(self, x: ArrayLike, y: ArrayLike) -> np.ndarray:
        """Unit normals ``(-p, -q, 1) / |(-p, -q, 1)|`` (the +z side).

        Returns
        -------
        (..., 3) ndarray
        """
        pq = self.slopes(x, y)
        n = np.concatenate([-pq, np.ones(pq.shape[:-1] + (1,))], axis=-1)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    def contains(self, x: ArrayLike, y: ArrayLike) -> np.ndarray:
        """Whether ``(x, y)`` lies on the facet (edges included); False for NaN.

        Returns
        -------
        ndarray of bool
        """
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        with np.errstate(invalid="ignore"):
            return (np.abs(x) <= self.half_width_mm) & (np.abs(y) <= self.half_height_mm)

    def corners_mm(self) -> np.ndarray:
        """The facet's four corners on its surface, in SOFAST's order.

        Returns
        -------
        (4, 3) ndarray, millimetres
            ``(+x, -y), (-x, -y), (-x, +y), (+x, +y)`` (the order of SOFAST's
            ``Facet_NSTTF.json``), each at the surface's height there (the
            design corners of that file lie at z = 0; a curved facet's real
            corners are off that plane by its sag).
        """
        w, h = self.half_width_mm, self.half_height_mm
        xy = np.array([[w, -h], [-w, -h], [-w, h], [w, h]])
        return np.column_stack([xy, self.height(xy[:, 0], xy[:, 1])])

    def max_sag_mm(self) -> float:
        """The largest ``|z|`` over the facet (an upper bound: paraboloid at a corner plus the ripple's amplitude)."""
        w, h = self.half_width_mm, self.half_height_mm
        cx, cy = self.curvature
        return 0.5 * abs(cx) * w * w + 0.5 * abs(cy) * h * h + abs(self.ripple_mm)

    def hessian_bound(self) -> float:
        """An upper bound on ``|d2z/ds2|`` along any direction anywhere, 1/mm: ``max(|z_xx|, |z_yy|)`` of the
        paraboloid plus the ripple's ``a (2 pi / P)^2``."""
        cx, cy = self.curvature
        return max(abs(cx), abs(cy)) + abs(self.ripple_mm) * (2.0 * math.pi / self.ripple_period_mm) ** 2

    def mesh_error_bound_mm(self, nx: int, ny: int) -> float:
        """The farthest an ``nx`` x ``ny``-cell :meth:`triangle_mesh` strays from the surface, at most, mm.

        Linear interpolation on a triangle errs by at most ``M rho^2 / 2``
        with ``M`` :meth:`hessian_bound` and ``rho`` the radius of the
        triangle's smallest enclosing circle; a grid cell's right triangle
        has ``rho`` half its diagonal: ``M (hx^2 + hy^2) / 8``.
        """
        hx = 2.0 * self.half_width_mm / nx
        hy = 2.0 * self.half_height_mm / ny
        return self.hessian_bound() * (hx * hx + hy * hy) / 8.0

    def triangle_mesh(self, tolerance_mm: float = MESH_TOLERANCE_MM) -> TriangleMesh:
        """The facet as a triangle mesh: a grid of vertices on the exact surface with its exact normals.

        Parameters
        ----------
        tolerance_mm : float, millimetres
            The grid is the coarsest (equal cells along each axis, square
            where the sides allow) whose :meth:`mesh_error_bound_mm` is below it.

        Returns
        -------
        shinysim.objects.shapes.TriangleMesh
            Two triangles per cell, counter-clockwise seen from +z (the
            mirror side); ``params`` holds the facet, the grid and the bound.
        """
        tol = _positive("tolerance_mm", tolerance_mm)
        M = self.hessian_bound()
        h = math.inf if M == 0.0 else math.sqrt(4.0 * tol / M)  # 2 h^2 M / 8 = tol
        nx = max(1, math.ceil(2.0 * self.half_width_mm / h))
        ny = max(1, math.ceil(2.0 * self.half_height_mm / h))
        if (nx + 1) * (ny + 1) > 2**24:
            raise OptionError(f"needs a {nx} x {ny} grid to stay within {tol!r} mm of the surface: more than 2**24 "
                              "vertices", field="tolerance_mm")
        xs = np.linspace(-self.half_width_mm, self.half_width_mm, nx + 1)
        ys = np.linspace(-self.half_height_mm, self.half_height_mm, ny + 1)
        gx, gy = np.meshgrid(xs, ys)  # vertex (j, i) at index j (nx + 1) + i
        vertices = np.column_stack([gx.ravel(), gy.ravel(), self.height(gx, gy).ravel()])
        normals = self.normal(gx, gy).reshape(-1, 3)
        v00 = (np.arange(ny)[:, None] * (nx + 1) + np.arange(nx)[None, :]).ravel()
        v10, v01 = v00 + 1, v00 + nx + 1
        v11 = v01 + 1
        faces = np.concatenate([np.column_stack([v00, v10, v11]), np.column_stack([v00, v11, v01])])
        params = {"half_width_mm": self.half_width_mm, "half_height_mm": self.half_height_mm,
                  "focal_mm": list(self.focal_mm), "ripple_mm": self.ripple_mm,
                  "ripple_period_mm": self.ripple_period_mm, "ripple_angle_rad": self.ripple_angle_rad,
                  "cells": [nx, ny], "error_bound_mm": self.mesh_error_bound_mm(nx, ny)}
        return TriangleMesh(vertices, faces.astype(np.int32), normals, "mirror", params)

    # -- rays --------------------------------------------------------------------
    def intersect(self, origins: ArrayLike, directions: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Where rays meet the surface, exactly.

        From the ray's point on the plane z = 0, Newton's method on the ray
        parameter ``t`` of ``o_z + t d_z = z(o_x + t d_x, o_y + t d_y)``
        until its step is below :data:`INTERSECT_TOLERANCE_MM`.

        Parameters
        ----------
        origins : (..., 3) array_like, millimetres
            Facet frame (broadcast against ``directions``).
        directions : (..., 3) array_like
            Need not be unit vectors.

        Returns
        -------
        points : (..., 3) ndarray, millimetres
            NaN where there is no hit.
        hit : (...,) ndarray of bool
            The ray meets the surface in front of its origin (``t > 0``),
            within the facet's rectangle.
        """
        o = np.asarray(origins, dtype=float)
        d = np.asarray(directions, dtype=float)
        if o.shape[-1:] != (3,) or d.shape[-1:] != (3,):
            raise OptionError(f"origins and directions must have 3 components on their last axis, got shapes "
                              f"{o.shape} and {d.shape}", field="origins")
        o, d = np.broadcast_arrays(o, d)
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            t = -o[..., 2] / d[..., 2]
            for _ in range(60):
                x = o[..., 0] + t * d[..., 0]
                y = o[..., 1] + t * d[..., 1]
                f = o[..., 2] + t * d[..., 2] - self.height(x, y)
                pq = self.slopes(x, y)
                df = d[..., 2] - pq[..., 0] * d[..., 0] - pq[..., 1] * d[..., 1]
                step = f / df
                t = t - step
                # the step in millimetres along the ray: NaN lanes (no hit) do not hold the others back
                moved = np.abs(step) * np.linalg.norm(d, axis=-1)
                if not np.any(moved > INTERSECT_TOLERANCE_MM):
                    break
            points = o + t[..., None] * d
            hit = np.isfinite(t) & (t > 0) & self.contains(points[..., 0], points[..., 1])
        points = np.where(hit[..., None], points, np.nan)
        return points, hit
