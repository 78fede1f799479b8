"""Rig descriptions: light sources, cameras and the reference plane, and their JSON form.

Pure data (numpy + dataclasses); no renderer. Frames and units are those of
:mod:`shinysim.conventions`: millimetres, world +z towards the camera, image
(row, col) with pixel centres at integer coordinates.

A rig is what a user with real hardware writes down about it (and what the
simulator renders): where each source is and how big it is, and how each
camera maps world points to pixels. It reads and writes as JSON
(:func:`Rig.to_json`, :func:`shinysim.io.load_rig`); see ``docs/file-format.md``.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from .._shared import check_choice, check_number, write_text
from ..conventions import normalize
from ..errors import RigError, check_schema, did_you_mean, short_json

__all__ = [
    "ANCHOR_KINDS",
    "ASPECT_RANGE",
    "Anchor",
    "CAMERA_PROJECTIONS",
    "Camera",
    "RIG_FORMAT",
    "RIG_FORMATS_READ",
    "RIG_SCHEMA",
    "Rig",
    "RigError",
]

#: The projections a :class:`Camera` can have.
CAMERA_PROJECTIONS = ("orthographic", "perspective")

RIG_FORMAT = "shinysim-rig/2"
#: Formats still read: version 1 has no principal point, lens distortion or
#: aspect (a version-1 camera is a version-2 camera with all at their defaults).
RIG_FORMATS_READ = ("shinysim-rig/1", RIG_FORMAT)
#: The open interval a camera's ``aspect`` (fy / fx) must lie in.
ASPECT_RANGE = (0.5, 2.0)


def _vec3(value, name, error=RigError, path=None):
    """``value`` as a (3,) float array, else ``error`` (naming ``path`` and field ``name``)."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        arr = np.zeros(0)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise error(f"must be 3 finite numbers, got {value!r}", path=path, field=name)
    return arr


def _distortion_terms(k):
    """The distortion as written: ``[k1, k2]`` when ``p1 = p2 = k3 = 0``, else all five (a list of floats)."""
    k = [float(x) for x in k]
    return k[:2] if k[2] == k[3] == k[4] == 0.0 else k


def _distortion_jacobian(k, u, v):
    """``(du_d/du, du_d/dv, dv_d/dv)`` of the distortion ``k`` (5 terms) at ``(u, v)``; the map is symmetric
    (``dv_d/du = du_d/dv``)."""
    k1, k2, p1, p2, k3 = k
    r2 = u * u + v * v
    g = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
    dg = 2.0 * (k1 + 2.0 * k2 * r2 + 3.0 * k3 * r2 * r2)  # d g / d (r^2), twice
    a12 = dg * u * v + 2.0 * p1 * u + 2.0 * p2 * v
    return g + dg * u * u + 2.0 * p1 * v + 6.0 * p2 * u, a12, g + dg * v * v + 6.0 * p1 * v + 2.0 * p2 * u


@dataclass(frozen=True, eq=False)
class Camera:
    """A camera looking at the scene.

    Parameters
    ----------
    projection : {"orthographic", "perspective"}
        How rays leave the camera.
    width, height : int
        Image size in pixels (columns, rows).
    position : (3,) float, millimetres
        Perspective: the centre of projection. Orthographic: the centre of
        the image plane (its rays start there and run along ``forward``).
    target : (3,) float, millimetres
        The point the optical axis passes through; it images at the image
        centre ``((height - 1) / 2, (width - 1) / 2)``.
    up : (3,) float
        World direction that appears as image "up" (towards row 0).
    field_width : float, millimetres
        Width of the imaged field, measured perpendicular to the axis at
        ``target`` (for a perspective camera; anywhere for an orthographic
        one). Pixel pitch (across) = ``field_width / width``; pixels are
        square unless ``aspect`` says otherwise.
    name : str
        Free label.
    principal_point : (row, col), optional
        Where the optical axis (the ray through ``target``) images, pixels.
        Default: the image centre ``((height - 1) / 2, (width - 1) / 2)``.
    distortion : (k1, k2) or (k1, k2, p1, p2, k3)
        Lens distortion: OpenCV's Brown-Conrady terms, in its order and with
        its formulas, but in shinysim's normalisation. With normalised image
        coordinates ``u = x / (field_width / 2)`` (``x`` the offset in the
        image plane at the target distance, along ``right``; ``v`` the same
        along ``down``) and ``r^2 = u^2 + v^2``, a point images at
        ``u_d = u g + 2 p1 u v + p2 (r^2 + 2 u^2)`` and
        ``v_d = v g + p1 (r^2 + 2 v^2) + 2 p2 u v`` with
        ``g = 1 + k1 r^2 + k2 r^4 + k3 r^6``. ``r = 1`` is half the image
        width from the principal point, so ``k1 = 1e-3`` moves the edge of
        the field by 0.1 % of its half width. Two numbers are ``(k1, k2)``
        with ``p1 = p2 = k3 = 0``; it is stored as five floats. OpenCV
        normalises by the focal length instead: with
        ``t = field_width / (2 distance) = width / (2 fx)``,
        ``k1_opencv = k1 / t^2``, ``k2_opencv = k2 / t^4``,
        ``k3_opencv = k3 / t^6`` and ``p_opencv = p / t``
        (:mod:`shinysim.rig.opencv` converts both ways). Refused if it folds
        the image. Default: none.
    aspect : float
        ``fy / fx``: the pixel's width over its height. Rows are pixels of
        height ``pixel_pitch / aspect``: a point images at
        ``col = u_d width / 2 + principal_col`` and
        ``row = v_d (width / 2) aspect + principal_row``. Finite, in
        (0.5, 2); default 1 (square pixels).

    Notes
    -----
    The camera frame is ``forward = normalize(target - position)``,
    ``right = normalize(forward x up)`` (image +col) and
    ``down = forward x right`` (image +row); see
    :mod:`shinysim.conventions`.
    """

    projection: str
    width: int
    height: int
    position: np.ndarray
    target: np.ndarray
    up: np.ndarray
    field_width: float
    name: str = "camera"
    principal_point: tuple[float, float] | None = None
    distortion: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)
    aspect: float = 1.0

    def __post_init__(self):
        if self.projection not in CAMERA_PROJECTIONS:
            raise RigError(f"{self.projection!r} is not one of {', '.join(map(repr, CAMERA_PROJECTIONS))}"
                           f"{did_you_mean(self.projection, CAMERA_PROJECTIONS)}", field="projection")
        for attr in ("width", "height"):
            value = getattr(self, attr)
            if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or not 1 <= value <= 65536:
                raise RigError(f"must be an integer from 1 to 65536 pixels, got {value!r}", field=attr)
            object.__setattr__(self, attr, int(value))
        if self.width * self.height > 2**26:
            raise RigError(f"{self.width} x {self.height} pixels is more than the 2**26 shinysim handles",
                           field="width")
        for attr in ("position", "target", "up"):
            object.__setattr__(self, attr, _vec3(getattr(self, attr), f"{attr}_mm" if attr != "up" else attr))
        fw = self.field_width
        if isinstance(fw, bool) or not isinstance(fw, (int, float, np.number)) or not (np.isfinite(fw) and fw > 0):
            raise RigError(f"must be a finite width > 0 mm, got {fw!r}", field="field_width_mm")
        object.__setattr__(self, "field_width", float(self.field_width))
        if not isinstance(self.name, str):
            raise RigError(f"must be a string, got {self.name!r}", field="name")
        axis = self.target - self.position
        if np.linalg.norm(axis) == 0:
            raise RigError("position_mm and target_mm coincide: the camera has no optical axis", field="target_mm")
        if np.linalg.norm(np.cross(axis, self.up)) < 1e-9 * np.linalg.norm(axis) * np.linalg.norm(self.up):
            raise RigError("is zero or parallel to the optical axis", field="up")
        pp = self.principal_point
        if pp is not None:
            pp = _floats_or_empty(pp)
            if pp.shape != (2,) or not np.all(np.isfinite(pp)):
                raise RigError(f"must be 2 finite numbers (row, col), got {self.principal_point!r}",
                               field="principal_point_px")
            centre = np.array([0.5 * (self.height - 1), 0.5 * (self.width - 1)])
            pp = None if np.array_equal(pp, centre) else (float(pp[0]), float(pp[1]))
        object.__setattr__(self, "principal_point", pp)
        a = self.aspect
        if isinstance(a, (bool, np.bool_)) or not isinstance(a, (int, float, np.integer, np.floating)) \
                or not (math.isfinite(a) and a > 0):
            raise RigError(f"must be a finite number > 0 (fy / fx), got {a!r}", field="aspect")
        if not ASPECT_RANGE[0] < a < ASPECT_RANGE[1]:
            raise RigError(f"{float(a)!r} is outside {ASPECT_RANGE}: a real sensor's pixels are within a few "
                           "per cent of square", field="aspect")
        object.__setattr__(self, "aspect", float(a))
        k = _floats_or_empty(self.distortion)
        if k.shape not in ((2,), (5,)) or not np.all(np.isfinite(k)):
            raise RigError(f"must be 2 finite numbers (k1, k2) or 5 (k1, k2, p1, p2, k3), got {self.distortion!r}",
                           field="distortion")
        k = np.concatenate([k, np.zeros(5 - k.size)])
        # the distortion must not fold the image: the map stays one-to-one out to the image corner
        # farthest from the principal point, with half as much again to spare
        pr, pc = self.principal_point_px
        corner = max(math.hypot((r - pr) / self.aspect, c - pc)
                     for r in (-0.5, self.height - 0.5) for c in (-0.5, self.width - 0.5))
        reach = 1.5 * corner / (0.5 * self.width)
        if k[2] == 0.0 and k[3] == 0.0:  # radial: r (1 + k1 r^2 + k2 r^4 + k3 r^6) increases
            r = np.linspace(0.0, reach, 257)
            slope = 1.0 + 3.0 * k[0] * r**2 + 5.0 * k[1] * r**4
            if k[4] != 0.0:
                slope = slope + 7.0 * k[4] * r**6
            if np.any(slope <= 0.05):
                raise RigError(f"{tuple(_distortion_terms(k))} folds the image (the radial map stops increasing within "
                               "the field); |k1|, |k2| of a real lens are far below 0.1", field="distortion")
        else:  # with tangential terms: the Jacobian determinant of the map stays positive over the field
            g = np.linspace(-reach, reach, 257)
            a11, a12, a22 = _distortion_jacobian(k, g[:, None], g[None, :])
            if np.any(~(a11 * a22 - a12 * a12 > 0.05)):
                raise RigError(f"{tuple(_distortion_terms(k))} folds the image (the Jacobian determinant of the map "
                               "falls to 0.05 or below within the field); |k1|, |k2| of a real lens are far "
                               "below 0.1 and |p1|, |p2| below 0.01", field="distortion")
        object.__setattr__(self, "distortion", tuple(float(x) for x in k))

    # -- frame ---------------------------------------------------------------
    @property
    def forward(self) -> np.ndarray:
        """(3,) unit optical axis, from the camera into the scene."""
        return normalize(self.target - self.position)

    @property
    def right(self) -> np.ndarray:
        """(3,) unit world direction of image +col."""
        return normalize(np.cross(self.forward, self.up))

    @property
    def down(self) -> np.ndarray:
        """(3,) unit world direction of image +row."""
        return np.cross(self.forward, self.right)

    @property
    def pixel_pitch(self) -> float:
        """Pixel width (along ``right``) in millimetres, at the target distance for perspective; a pixel's
        height is ``pixel_pitch / aspect``."""
        return self.field_width / self.width

    @property
    def distance(self) -> float:
        """Distance from ``position`` to ``target``, millimetres."""
        return float(np.linalg.norm(self.target - self.position))

    @property
    def shape(self) -> tuple[int, int]:
        """Image shape ``(height, width)``."""
        return (self.height, self.width)

    @property
    def fov_x_deg(self) -> float:
        """Horizontal field of view in degrees (perspective cameras)."""
        return math.degrees(2 * math.atan(0.5 * self.field_width / self.distance))

    @property
    def principal_point_px(self) -> np.ndarray:
        """(row, col) where the optical axis images (the image centre by default)."""
        if self.principal_point is None:
            return np.array([0.5 * (self.height - 1), 0.5 * (self.width - 1)])
        return np.array(self.principal_point)

    @property
    def is_ideal(self) -> bool:
        """No lens distortion, the principal point at the image centre and square pixels."""
        return self.principal_point is None and not any(self.distortion) and self.aspect == 1.0

    # -- mapping -------------------------------------------------------------
    def distort(self, u: ArrayLike, v: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Normalised image coordinates through the lens distortion (see the class notes).

        Parameters
        ----------
        u, v : array_like
            Undistorted normalised coordinates (along ``right``, ``down``).

        Returns
        -------
        u_d, v_d : ndarray
        """
        u = np.asarray(u, dtype=float)
        v = np.asarray(v, dtype=float)
        k1, k2, p1, p2, k3 = self.distortion
        r2 = u * u + v * v
        f = 1.0 + k1 * r2 + k2 * r2 * r2
        if k3 != 0.0:
            f = f + k3 * r2 * r2 * r2
        if p1 == 0.0 and p2 == 0.0:
            return u * f, v * f
        uv = u * v
        return u * f + 2.0 * p1 * uv + p2 * (r2 + 2.0 * u * u), v * f + p1 * (r2 + 2.0 * v * v) + 2.0 * p2 * uv

    def undistort(self, ud: ArrayLike, vd: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """The inverse of :meth:`distort`, to rounding.

        Radial distortion: Newton's method on the radius. With tangential
        terms: Newton's method in two dimensions, on the map's Jacobian.
        """
        ud = np.asarray(ud, dtype=float)
        vd = np.asarray(vd, dtype=float)
        k1, k2, p1, p2, k3 = self.distortion
        if p1 != 0.0 or p2 != 0.0:
            return self._undistort_2d(ud, vd)
        if k1 == 0.0 and k2 == 0.0 and k3 == 0.0:
            return ud, vd
        rd = np.hypot(ud, vd)
        r = rd.copy()
        for _ in range(20):
            r2 = r * r
            g = 1.0 + k1 * r2 + k2 * r2 * r2
            slope = 1.0 + 3.0 * k1 * r2 + 5.0 * k2 * r2 * r2
            if k3 != 0.0:
                g = g + k3 * r2 * r2 * r2
                slope = slope + 7.0 * k3 * r2 * r2 * r2
            step = (r * g - rd) / slope
            r = r - step
            if np.all(np.abs(step) <= 1e-15 * np.maximum(r, 1e-300)):
                break
        with np.errstate(invalid="ignore", divide="ignore"):
            scale = np.where(rd > 0, r / rd, 1.0)
        return ud * scale, vd * scale

    def _undistort_2d(self, ud, vd):
        """:meth:`undistort` with tangential terms: Newton's method on ``distort(u, v) = (ud, vd)``."""
        ud, vd = np.broadcast_arrays(ud, vd)
        u, v = ud.copy(), vd.copy()
        for _ in range(30):
            fu, fv = self.distort(u, v)
            ru, rv = fu - ud, fv - vd
            a11, a12, a22 = _distortion_jacobian(self.distortion, u, v)
            with np.errstate(invalid="ignore", divide="ignore"):
                det = a11 * a22 - a12 * a12
                su = (a22 * ru - a12 * rv) / det
                sv = (a11 * rv - a12 * ru) / det
            u = u - su
            v = v - sv
            # NaN (no inverse, or a NaN input) does not hold the others back
            if not np.any(np.hypot(su, sv) > 1e-15 * np.maximum(np.hypot(u, v), 1e-300)):
                break
        return u, v

    def _offsets(self, row, col):
        """Undistorted offsets (mm, in the image plane at the target distance) of pixel coordinates."""
        row = np.asarray(row, dtype=float)
        col = np.asarray(col, dtype=float)
        pr, pc = self.principal_point_px
        half = 0.5 * self.width
        u, v = self.undistort((col - pc) / half, (row - pr) / (half * self.aspect))
        half_mm = 0.5 * self.field_width
        return u * half_mm, v * half_mm

    def pixel_rays(self, row: ArrayLike, col: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Rays through continuous pixel coordinates.

        Parameters
        ----------
        row, col : array_like
            Continuous image coordinates (pixel centres at integers).

        Returns
        -------
        origins, directions : (..., 3) ndarray, millimetres / unit
        """
        du, dv = self._offsets(row, col)
        lateral = du[..., None] * self.right + dv[..., None] * self.down
        if self.projection == "orthographic":
            origins = self.position + lateral
            directions = np.broadcast_to(self.forward, origins.shape).copy()
        else:
            on_plane = self.position + self.distance * self.forward + lateral
            directions = normalize(on_plane - self.position)
            origins = np.broadcast_to(self.position, directions.shape).copy()
        return origins, directions

    def project(self, points: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Continuous (row, col) of world points.

        Parameters
        ----------
        points : (..., 3) array_like, millimetres

        Returns
        -------
        row, col : ndarray
            NaN for points behind a perspective camera.
        """
        rel = np.asarray(points, dtype=float) - self.position
        x = rel @ self.right
        y = rel @ self.down
        if self.projection == "perspective":
            depth = rel @ self.forward
            with np.errstate(divide="ignore", invalid="ignore"):
                scale = np.where(depth > 0, self.distance / depth, np.nan)
            x = x * scale
            y = y * scale
        half_mm = 0.5 * self.field_width
        u, v = self.distort(x / half_mm, y / half_mm)
        pr, pc = self.principal_point_px
        half = 0.5 * self.width
        return v * (half * self.aspect) + pr, u * half + pc

    def backproject_to_plane(self, row: ArrayLike, col: ArrayLike, plane_z: float = 0.0) -> np.ndarray:
        """Where pixel rays meet the horizontal plane ``z = plane_z``.

        Returns
        -------
        (..., 3) ndarray, millimetres
            NaN where a ray is parallel to the plane or meets it behind the
            camera.
        """
        origins, directions = self.pixel_rays(row, col)
        dz = directions[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (plane_z - origins[..., 2]) / dz
        t = np.where((dz != 0) & (t > 0), t, np.nan)
        return origins + t[..., None] * directions

    def view_directions(self, points: ArrayLike) -> np.ndarray:
        """Unit directions from world points towards the camera.

        For an orthographic camera this is ``-forward`` everywhere.
        """
        points = np.asarray(points, dtype=float)
        if self.projection == "orthographic":
            return np.broadcast_to(-self.forward, points.shape).copy()
        return normalize(self.position - points)

    # -- serialisation -------------------------------------------------------
    def to_dict(self):
        return {
            "name": self.name,
            "projection": self.projection,
            "width": self.width,
            "height": self.height,
            "position_mm": self.position.tolist(),
            "target_mm": self.target.tolist(),
            "up": self.up.tolist(),
            "field_width_mm": self.field_width,
            **({"principal_point_px": list(self.principal_point)} if self.principal_point is not None else {}),
            **({"distortion": _distortion_terms(self.distortion)} if any(self.distortion) else {}),
            **({"aspect": self.aspect} if self.aspect != 1.0 else {}),
        }

    @classmethod
    def from_dict(cls, d, where="camera"):
        """A camera from its JSON object, validated against :data:`RIG_SCHEMA` (errors name ``where``)."""
        d = _validate(d, "camera", where)
        try:
            # coordinates near the float limits overflow (or underflow to zero) in the frame's
            # products: refuse them here rather than return a camera with a NaN frame
            with np.errstate(over="raise", invalid="raise"):
                camera = cls(
                    projection=d["projection"],
                    width=int(d["width"]),
                    height=int(d["height"]),
                    position=d["position_mm"],
                    target=d["target_mm"],
                    up=d["up"],
                    field_width=float(d["field_width_mm"]),  # a JSON integer may be too large for numpy
                    name=d.get("name", "camera"),
                    principal_point=d.get("principal_point_px"),
                    distortion=d.get("distortion", (0.0, 0.0)),
                    aspect=d.get("aspect", 1.0),
                )
                frame = np.concatenate([camera.forward, camera.right, camera.down])
        except RigError as exc:
            raise RigError(exc.problem, field=f"{where}.{exc.field}" if exc.field else where) from None
        except FloatingPointError:
            frame = None
        if frame is None or not np.all(np.isfinite(frame)):
            raise RigError("position_mm, target_mm and up are too large or too small to give a camera frame "
                           "(the arithmetic overflows or underflows)", field=where)
        if not camera.pixel_pitch > 0:  # a subnormal width: field_width_mm / width underflows to 0
            raise RigError(f"{camera.field_width!r} mm is too small: its pixel pitch (field_width_mm / width) is 0",
                           field=f"{where}.field_width_mm")
        return camera

    def __eq__(self, other):
        return isinstance(other, Camera) and self.to_dict() == other.to_dict()


#: The rig JSON schema, written once: for each kind of object, its fields as
#: ``name: (type, required, rule)``. Types are JSON Schema's (``"number"`` a
#: number within the float range, not a boolean or a string; ``"integer"``,
#: ``"string"``, ``"object"``, ``"array"``) and ``"vec3"`` (three finite
#: numbers). :data:`RIG_SCHEMA` is the same as JSON Schema, checked by
#: :func:`shinysim.errors.check_schema`; the rules are checked after it.
#: ``docs/file-format.md`` shows the same table.
RIG_FIELDS = {
    "rig": {
        "format": ("string", False, f"'{RIG_FORMAT}' (or the older '{RIG_FORMATS_READ[0]}')"),
        "name": ("string", False, ""),
        "units": ("string", False, "'mm'"),
        "reference_z_mm": ("number", False, "finite"),
        "sources": ("array", True, "1 to 10000 source objects"),
        "cameras": ("array", True, "1 to 16 camera objects"),
        "metadata": ("object", False, "free JSON"),
        "provenance": ("object", False, "free JSON (how a stack was made)"),
        "anchor": ("object", False, "where the object is, for near-field normals (point_mm or contour)"),
    },
    "source": {
        "position_mm": ("vec3", False, "near source: its centre"),
        "radius_mm": ("number", False, ">= 0, near sources only"),
        "direction": ("vec3", False, "distant source: non-zero direction towards it"),
    },
    "anchor": {
        "point_mm": ("vec3", False, "a known surface point"),
        "normal": ("vec3", False, "its known normal (z > 0)"),
        "contour_rows": ("array", False, "image rows of an occluding contour on a plane"),
        "contour_cols": ("array", False, "their image columns"),
        "plane_z_mm": ("number", False, "the contour's plane"),
    },
    "camera": {
        "name": ("string", False, ""),
        "projection": ("string", True, " or ".join(map(repr, CAMERA_PROJECTIONS))),
        "width": ("integer", True, "1 to 65536; width x height <= 2**26"),
        "height": ("integer", True, "1 to 65536; width x height <= 2**26"),
        "position_mm": ("vec3", True, "not equal to target_mm"),
        "target_mm": ("vec3", True, ""),
        "up": ("vec3", True, "not parallel to the optical axis"),
        "field_width_mm": ("number", True, "> 0"),
        "principal_point_px": ("array", False, "(row, col) of the optical axis in the image (version 2)"),
        "distortion": ("array", False, "(k1, k2) or (k1, k2, p1, p2, k3), OpenCV's terms in shinysim's "
                       "normalisation, that do not fold the image (version 2)"),
        "aspect": ("number", False, "fy / fx (pixel width over height), in (0.5, 2) (version 2)"),
    },
}

RIG_SCHEMA = {kind: {"type": "object", "additionalProperties": False,
                     "required": [k for k, (_, required, _) in fields.items() if required],
                     "properties": {k: {"type": t, "description": rule} for k, (t, _, rule) in fields.items()}}
              for kind, fields in RIG_FIELDS.items()}


def _validate(d, kind, where):
    """Check a JSON object against ``RIG_SCHEMA[kind]``: its type, unknown keys
    (with a did-you-mean), missing required keys and each field's JSON type."""
    return check_schema(d, RIG_SCHEMA[kind], error=RigError, field=where, what=kind)


def _anchor_from_dict(d):
    """A rig's ``anchor`` field, with errors naming it."""
    from ..errors import ShinysimError

    _validate(d, "anchor", "anchor")
    try:
        return Anchor.from_dict(d)
    except ShinysimError as exc:
        raise RigError(exc.problem, field=f"anchor ({exc.field})" if exc.field else "anchor") from None


def _floats_or_empty(value):
    """``value`` as a float array, or an empty one when it is not numbers (the caller names the field)."""
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError, OverflowError):
        return np.zeros(0)


#: What can fix the height a single camera cannot see (:class:`Anchor`).
ANCHOR_KINDS = ("point", "contour")


@dataclass(frozen=True)
class Anchor:
    """What fixes the height a single camera cannot see.

    Use :meth:`point` or :meth:`contour`; ``to_dict`` / ``from_dict`` read
    and write the form a rig's ``anchor`` field holds.
    """

    kind: str
    point: tuple[float, float, float] | None = None
    normal: tuple[float, float, float] | None = None
    rows: tuple[float, ...] = ()
    cols: tuple[float, ...] = ()
    plane_z: float = 0.0

    def __post_init__(self):
        check_choice("anchor kind", self.kind, ANCHOR_KINDS)
        if self.kind == "point":
            object.__setattr__(self, "point", tuple(float(v) for v in _vec3(self.point, "anchor point")))
            if self.normal is not None:
                n = _floats_or_empty(self.normal)
                if n.shape != (3,) or not np.all(np.isfinite(n)) or not np.linalg.norm(n) > 0 or n[2] <= 0:
                    raise RigError(f"must be 3 finite numbers with z > 0, got {self.normal!r}",
                                      field="anchor normal")
                object.__setattr__(self, "normal", tuple(float(v) for v in n / np.linalg.norm(n)))
        else:
            r = _floats_or_empty(self.rows).ravel()
            c = _floats_or_empty(self.cols).ravel()
            if r.shape != c.shape or r.size == 0 or not (np.all(np.isfinite(r)) and np.all(np.isfinite(c))):
                raise RigError("needs one or more finite (row, col) image points", field="anchor contour")
            object.__setattr__(self, "rows", tuple(r.tolist()))
            object.__setattr__(self, "cols", tuple(c.tolist()))
            object.__setattr__(self, "plane_z", check_number("anchor plane_z", self.plane_z))

    @classmethod
    def at_point(cls, point, normal=None) -> Anchor:
        """A known surface point (millimetres), optionally with its known unit normal."""
        return cls("point", point=point, normal=normal)

    @classmethod
    def contour(cls, rows, cols, plane_z=0.0) -> Anchor:
        """Image points of an occluding contour that lies on the plane ``z = plane_z``."""
        return cls("contour", rows=tuple(np.ravel(rows)), cols=tuple(np.ravel(cols)), plane_z=plane_z)

    def to_dict(self) -> dict:
        if self.kind == "point":
            d = {"point_mm": list(self.point)}
            if self.normal is not None:
                d["normal"] = list(self.normal)
            return d
        return {"contour_rows": list(self.rows), "contour_cols": list(self.cols), "plane_z_mm": self.plane_z}

    @classmethod
    def from_dict(cls, d) -> Anchor:
        if not isinstance(d, dict):
            raise RigError(f"must be a JSON object, got {type(d).__name__}", field="anchor")
        if "point_mm" in d:
            return cls.at_point(d["point_mm"], d.get("normal"))
        if "contour_rows" in d:
            return cls.contour(d["contour_rows"], d.get("contour_cols", ()), d.get("plane_z_mm", 0.0))
        raise RigError("needs 'point_mm' (a known surface point) or 'contour_rows'/'contour_cols'",
                          field="anchor")


@dataclass(frozen=True, eq=False)
class Rig:
    """Light sources, cameras and reference plane of a structured-highlight rig.

    Parameters
    ----------
    source_positions : (n_sources, 3) float, millimetres
        Centre of each source. For a *distant* source (``source_distant``
        True) the row is instead the unit direction towards it.
    source_radii : (n_sources,) float, millimetres
        Radius of each (spherical) source; 0 for an ideal point source.
    cameras : tuple of Camera
        One camera, or more (structured-highlight stereo).
    source_distant : (n_sources,) bool, optional
        Sources at infinity (e.g. lights known only by direction).
    reference_z : float, millimetres
        Height of the reference plane (paper Section III).
    name : str
    metadata : dict
        Free JSON-serialisable notes (preset parameters, provenance).
    anchor : Anchor, optional
        What fixes the height of the object under the camera for the
        near-field normal model (:mod:`shinysim.recon.nearfield`): a known
        surface point, or an occluding contour on a known plane.
    """

    source_positions: np.ndarray
    source_radii: np.ndarray
    cameras: tuple[Camera, ...]
    source_distant: np.ndarray | None = None
    reference_z: float = 0.0
    name: str = "rig"
    metadata: dict = field(default_factory=dict)
    anchor: Anchor | None = None

    def __post_init__(self):
        pos = np.asarray(self.source_positions, dtype=float)
        if pos.ndim != 2 or pos.shape[1] != 3 or pos.shape[0] < 1:
            raise RigError(f"source_positions must have shape (n_sources, 3), got {pos.shape}")
        if not np.all(np.isfinite(pos)):
            raise RigError("source_positions contain NaN or inf")
        n = pos.shape[0]
        radii = np.broadcast_to(np.asarray(self.source_radii, dtype=float), (n,)).copy()
        if not np.all(np.isfinite(radii)) or np.any(radii < 0):
            raise RigError("source_radii must be finite and >= 0 mm")
        distant = self.source_distant
        distant = np.zeros(n, bool) if distant is None else np.broadcast_to(np.asarray(distant, bool), (n,)).copy()
        if np.any(distant):
            norms = np.linalg.norm(pos[distant], axis=1)
            if np.any(norms == 0):
                raise RigError("a distant source needs a non-zero direction")
            # normalise, leaving unit vectors bit-identical (exact JSON round trips)
            scale = np.where(np.abs(norms - 1.0) > 1e-12, norms, 1.0)
            pos[distant] = pos[distant] / scale[:, None]
        cams = tuple(self.cameras)
        if not cams or not all(isinstance(c, Camera) for c in cams):
            raise RigError("a rig needs at least one Camera")
        if self.anchor is not None and not isinstance(self.anchor, Anchor):
            raise RigError(f"must be an Anchor or None, got {type(self.anchor).__name__}", field="anchor")
        if not np.isfinite(self.reference_z):
            raise RigError("reference_z must be finite")
        object.__setattr__(self, "source_positions", pos)
        object.__setattr__(self, "source_radii", radii)
        object.__setattr__(self, "source_distant", distant)
        object.__setattr__(self, "cameras", cams)
        object.__setattr__(self, "reference_z", float(self.reference_z))

    @property
    def n_sources(self) -> int:
        return self.source_positions.shape[0]

    @property
    def camera(self) -> Camera:
        """The first (or only) camera."""
        return self.cameras[0]

    def source_directions(self, points: ArrayLike, sources: ArrayLike | None = None) -> np.ndarray:
        """Unit directions from surface points towards sources.

        Parameters
        ----------
        points : (..., 3) array_like, millimetres
        sources : (...,) int array_like, optional
            Source index for each point (broadcast against ``points[..., 0]``).
            Without it, directions to every source are returned with a new
            axis: shape (..., n_sources, 3).
        """
        points = np.asarray(points, dtype=float)
        if sources is None:
            sources, points = slice(None), points[..., None, :]
        else:
            sources = np.asarray(sources, dtype=int)
            if np.any((sources < 0) | (sources >= self.n_sources)):
                raise IndexError(f"source index out of range 0..{self.n_sources - 1}")
        pos = self.source_positions[sources]
        return np.where(self.source_distant[sources][..., None], pos, normalize(pos - points))

    def with_camera(self, camera: Camera, index: int = 0) -> Rig:
        """A copy with camera ``index`` replaced."""
        cams = list(self.cameras)
        cams[index] = camera
        return replace(self, cameras=tuple(cams), metadata=dict(self.metadata))

    def with_anchor(self, anchor: Anchor | None) -> Rig:
        """A copy with the anchor of the near-field model replaced."""
        return replace(self, metadata=dict(self.metadata), anchor=anchor)

    # -- serialisation -------------------------------------------------------
    def to_dict(self):
        sources = [{"direction": p.tolist()} if d else {"position_mm": p.tolist(), "radius_mm": float(r)}
                   for p, r, d in zip(self.source_positions, self.source_radii, self.source_distant)]
        return {
            "format": RIG_FORMAT,
            "name": self.name,
            "units": "mm",
            "reference_z_mm": self.reference_z,
            "sources": sources,
            "cameras": [c.to_dict() for c in self.cameras],
            "metadata": self.metadata,
            **({"anchor": self.anchor.to_dict()} if self.anchor is not None else {}),
        }

    def to_json(self, **kwargs):
        kwargs.setdefault("indent", 2)
        return json.dumps(self.to_dict(), **kwargs)

    @classmethod
    def from_dict(cls, d):
        """A rig from its JSON document, validated against :data:`RIG_SCHEMA`.

        Raises
        ------
        RigError
            Naming the field (``sources[3].radius_mm``, ``cameras[0]``, ...)
            for unknown keys (with a did-you-mean), missing keys, wrong JSON
            types, out-of-range values and an unknown format or unit.
        """
        d = _validate(d, "rig", "rig")
        fmt = d.get("format", RIG_FORMAT)
        if fmt not in RIG_FORMATS_READ:
            raise RigError(f"{fmt!r} is not supported (expected one of "
                           f"{', '.join(map(repr, RIG_FORMATS_READ))})", field="format")
        if fmt == RIG_FORMATS_READ[0]:
            for i, c in enumerate(d["cameras"]):
                extra = [k for k in ("principal_point_px", "distortion", "aspect") if isinstance(c, dict) and k in c]
                if extra:
                    raise RigError(f"{', '.join(extra)} needs format {RIG_FORMAT!r} (the file says {fmt!r})",
                                   field=f"cameras[{i}].{extra[0]}")
        if d.get("units", "mm") != "mm":
            raise RigError(f"must be 'mm', got {d.get('units')!r}", field="units")
        if not 1 <= len(d["sources"]) <= 10000:
            raise RigError(f"must list 1 to 10000 sources, got {len(d['sources'])}", field="sources")
        if not 1 <= len(d["cameras"]) <= 16:
            raise RigError(f"must list 1 to 16 cameras, got {len(d['cameras'])}", field="cameras")
        pos, radii, distant = [], [], []
        for i, src in enumerate(d["sources"]):
            where = f"sources[{i}]"
            src = _validate(src, "source", where)
            far = "direction" in src
            if far and ("position_mm" in src or "radius_mm" in src):
                raise RigError("has both 'direction' (distant) and 'position_mm'/'radius_mm' (near); "
                               "give one", field=where)
            if not far and "position_mm" not in src:
                raise RigError("needs 'position_mm' (near source) or 'direction' (distant source)", field=where)
            pos.append(np.asarray(src["direction" if far else "position_mm"], float))
            if far:
                with np.errstate(over="ignore"):
                    length = np.linalg.norm(pos[-1])
                if not 0 < length < math.inf:  # zero, or so large that its length overflows
                    raise RigError(f"must be a non-zero vector of finite length, got {short_json(src['direction'])}",
                                   field=f"{where}.direction")
            radius = src.get("radius_mm", 0.0)  # 0 for a distant source
            if not (math.isfinite(radius) and radius >= 0):
                raise RigError(f"must be >= 0 mm, got {radius!r}", field=f"{where}.radius_mm")
            radii.append(float(radius))
            distant.append(far)
        cams = tuple(Camera.from_dict(c, f"cameras[{i}]") for i, c in enumerate(d["cameras"]))
        z = d.get("reference_z_mm", 0.0)
        if not math.isfinite(z):
            raise RigError(f"must be finite, got {z!r}", field="reference_z_mm")
        return cls(
            source_positions=np.array(pos),
            source_radii=np.array(radii),
            cameras=cams,
            source_distant=np.array(distant),
            reference_z=float(z),
            name=d.get("name", "rig"),
            metadata=dict(d.get("metadata", {})),
            anchor=_anchor_from_dict(d["anchor"]) if "anchor" in d else None,
        )

    @classmethod
    def from_json(cls, text: str) -> Rig:
        """A rig from JSON text (see :meth:`from_dict`; :func:`shinysim.io.load_rig` reads a file)."""
        try:
            doc = json.loads(text)
        except (ValueError, RecursionError) as exc:  # bad syntax, too deep, a number too long
            raise RigError(f"not valid JSON: {str(exc) or 'nested too deeply'}") from None
        return cls.from_dict(doc)

    def save(self, path: str | os.PathLike, *, overwrite: bool = False) -> Path:
        """Write the rig as JSON; refuses to replace an existing file."""
        return write_text(path, self.to_json() + "\n", overwrite=overwrite)

    def __eq__(self, other):
        return isinstance(other, Rig) and self.to_dict() == other.to_dict()


