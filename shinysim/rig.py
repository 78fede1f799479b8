"""Rig descriptions: light sources, cameras and the reference plane.

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
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from ._shared import check_choice, check_number, derive_seed, write_text
from .conventions import MM_PER_INCH, normalize
from .errors import RigError, check_fields, check_schema, did_you_mean, short_json

__all__ = [
    "ANCHOR_KINDS",
    "Anchor",
    "CAMERA_PROJECTIONS",
    "Camera",
    "Rig",
    "RigError",
    "RigTolerances",
    "perturb_rig",
    "shiny_1988",
    "shiny_1988_source_angles_deg",
    "distant_rig",
    "dome",
    "fibonacci_hemisphere",
    "stereo_pair",
    "stereo_dome",
    "stereo_semicircle",
    "sources_in_view",
    "drop_sources_in_view",
    "DOME_LAYOUTS",
    "rotating_semicircle",
]

#: The projections a :class:`Camera` can have.
CAMERA_PROJECTIONS = ("orthographic", "perspective")

RIG_FORMAT = "shinysim-rig/2"
#: Formats still read: version 1 has no principal point or lens distortion
#: (a version-1 camera is a version-2 camera with both at their defaults).
RIG_FORMATS_READ = ("shinysim-rig/1", RIG_FORMAT)


def _vec3(value, name):
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise RigError(f"must be 3 finite numbers, got {value!r}", field=name) from None
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise RigError(f"must be 3 finite numbers, got {value!r}", field=name)
    return arr


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
        one). Pixels are square: pixel pitch = ``field_width / width``.
    name : str
        Free label.
    principal_point : (row, col), optional
        Where the optical axis (the ray through ``target``) images, pixels.
        Default: the image centre ``((height - 1) / 2, (width - 1) / 2)``.
    distortion : (k1, k2)
        Radial lens distortion (Brown's model, two terms). With normalised
        image coordinates ``u = x / (field_width / 2)`` (``x`` the offset in
        the image plane at the target distance, along ``right``; ``v`` the
        same along ``down``) and ``r^2 = u^2 + v^2``, a point images at
        ``u (1 + k1 r^2 + k2 r^4)``. ``r = 1`` is half the image width from
        the principal point, so ``k1 = 1e-3`` moves the edge of the field by
        0.1 % of its half width. (OpenCV normalises by the focal length
        instead: ``k1_opencv = k1 / t^2`` and ``k2_opencv = k2 / t^4`` with
        ``t = field_width / (2 distance)``.) Default: none.

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
    distortion: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self):
        if self.projection not in CAMERA_PROJECTIONS:
            raise RigError(f"{self.projection!r} is not one of {', '.join(map(repr, CAMERA_PROJECTIONS))}"
                           f"{did_you_mean(self.projection, CAMERA_PROJECTIONS)}", field="projection")
        for attr in ("width", "height"):
            value = getattr(self, attr)
            if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or not 1 <= value <= 65536:
                raise RigError(f"must be an integer from 1 to 65536 pixels, got {value!r}", field=attr)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
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
        k = _floats_or_empty(self.distortion)
        if k.shape != (2,) or not np.all(np.isfinite(k)):
            raise RigError(f"must be 2 finite numbers (k1, k2), got {self.distortion!r}", field="distortion")
        # the distortion must not fold the image: r (1 + k1 r^2 + k2 r^4) increases out to the image
        # corner farthest from the principal point, with half as much again to spare
        pr, pc = self.principal_point_px
        corner = max(math.hypot(r - pr, c - pc) for r in (-0.5, self.height - 0.5) for c in (-0.5, self.width - 0.5))
        r = np.linspace(0.0, 1.5 * corner / (0.5 * self.width), 257)
        if np.any(1.0 + 3.0 * k[0] * r**2 + 5.0 * k[1] * r**4 <= 0.05):
            raise RigError(f"{tuple(k.tolist())} folds the image (the radial map stops increasing within "
                           "the field); |k1|, |k2| of a real lens are far below 0.1", field="distortion")
        object.__setattr__(self, "distortion", (float(k[0]), float(k[1])))

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
        """Pixel size in millimetres, at the target distance for perspective."""
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
        """No lens distortion and the principal point at the image centre."""
        return self.principal_point is None and self.distortion == (0.0, 0.0)

    # -- mapping -------------------------------------------------------------
    def distort(self, u: ArrayLike, v: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Normalised image coordinates through the lens distortion (see the class notes)."""
        u = np.asarray(u, dtype=float)
        v = np.asarray(v, dtype=float)
        k1, k2 = self.distortion
        r2 = u * u + v * v
        f = 1.0 + k1 * r2 + k2 * r2 * r2
        return u * f, v * f

    def undistort(self, ud: ArrayLike, vd: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """The inverse of :meth:`distort`, by Newton's method on the radius (to rounding)."""
        ud = np.asarray(ud, dtype=float)
        vd = np.asarray(vd, dtype=float)
        k1, k2 = self.distortion
        if k1 == 0.0 and k2 == 0.0:
            return ud, vd
        rd = np.hypot(ud, vd)
        r = rd.copy()
        for _ in range(20):
            r2 = r * r
            step = (r * (1.0 + k1 * r2 + k2 * r2 * r2) - rd) / (1.0 + 3.0 * k1 * r2 + 5.0 * k2 * r2 * r2)
            r = r - step
            if np.all(np.abs(step) <= 1e-15 * np.maximum(r, 1e-300)):
                break
        with np.errstate(invalid="ignore", divide="ignore"):
            scale = np.where(rd > 0, r / rd, 1.0)
        return ud * scale, vd * scale

    def _offsets(self, row, col):
        """Undistorted offsets (mm, in the image plane at the target distance) of pixel coordinates."""
        row = np.asarray(row, dtype=float)
        col = np.asarray(col, dtype=float)
        pr, pc = self.principal_point_px
        half = 0.5 * self.width
        u, v = self.undistort((col - pc) / half, (row - pr) / half)
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
        du = du[..., None]
        dv = dv[..., None]
        lateral = du * self.right + dv * self.down
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
        return v * half + pr, u * half + pc

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
            **({"distortion": list(self.distortion)} if self.distortion != (0.0, 0.0) else {}),
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
        "distortion": ("array", False, "radial (k1, k2), that do not fold the image (version 2)"),
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
    from .errors import ShinysimError

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
            pos = self.source_positions
            distant = self.source_distant[:, None]
            near = pos - points[..., None, :]
            return np.where(distant, pos, normalize(near))
        sources = np.asarray(sources, dtype=int)
        if np.any((sources < 0) | (sources >= self.n_sources)):
            raise IndexError(f"source index out of range 0..{self.n_sources - 1}")
        pos = self.source_positions[sources]
        distant = self.source_distant[sources][..., None]
        return np.where(distant, pos, normalize(pos - points))

    def with_camera(self, camera: Camera, index: int = 0) -> Rig:
        """A copy with camera ``index`` replaced."""
        cams = list(self.cameras)
        cams[index] = camera
        return Rig(self.source_positions, self.source_radii, tuple(cams), self.source_distant,
                   self.reference_z, self.name, dict(self.metadata), self.anchor)

    def with_anchor(self, anchor: Anchor | None) -> Rig:
        """A copy with the anchor of the near-field model replaced."""
        return Rig(self.source_positions, self.source_radii, self.cameras, self.source_distant,
                   self.reference_z, self.name, dict(self.metadata), anchor)

    # -- serialisation -------------------------------------------------------
    def to_dict(self):
        sources = []
        for p, r, d in zip(self.source_positions, self.source_radii, self.source_distant):
            if d:
                sources.append({"direction": p.tolist()})
            else:
                sources.append({"position_mm": p.tolist(), "radius_mm": float(r)})
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
                extra = [k for k in ("principal_point_px", "distortion") if isinstance(c, dict) and k in c]
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
            if "direction" in src:
                if "position_mm" in src or "radius_mm" in src:
                    raise RigError("has both 'direction' (distant) and 'position_mm'/'radius_mm' (near); "
                                   "give one", field=where)
                direction = np.asarray(src["direction"], float)
                with np.errstate(over="ignore"):
                    length = np.linalg.norm(direction)
                if not 0 < length < math.inf:  # zero, or so large that its length overflows
                    raise RigError(f"must be a non-zero vector of finite length, got {short_json(src['direction'])}",
                                   field=f"{where}.direction")
                pos.append(direction)
                radii.append(0.0)
                distant.append(True)
            elif "position_mm" in src:
                radius = src.get("radius_mm", 0.0)
                if not (math.isfinite(radius) and radius >= 0):
                    raise RigError(f"must be >= 0 mm, got {radius!r}", field=f"{where}.radius_mm")
                pos.append(np.asarray(src["position_mm"], float))
                radii.append(float(radius))
                distant.append(False)
            else:
                raise RigError("needs 'position_mm' (near source) or 'direction' (distant source)", field=where)
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
        return cls.from_dict(json.loads(text))

    def save(self, path: str | os.PathLike, *, overwrite: bool = False) -> Path:
        """Write the rig as JSON; refuses to replace an existing file."""
        return write_text(path, self.to_json() + "\n", overwrite=overwrite)

    def __eq__(self, other):
        return isinstance(other, Rig) and self.to_dict() == other.to_dict()


# -- presets -------------------------------------------------------------------

#: Signed polar angles of the 21 SHINY fibers in the x-z plane, degrees.
#: 8 degrees apart, offset by half a step so that no fiber sits on the
#: camera axis (where it would block the view of the object).
def shiny_1988_source_angles_deg(n_sources=21, spacing_deg=8.0):
    """Signed polar angles (degrees) of the preset's fibers.

    ``-84, -76, ..., -4, +4, ..., +76`` for the default 21 fibers: evenly
    spaced, symmetric about the axis except for the last fiber, and never
    on the camera axis.
    """
    first = -spacing_deg * (n_sources // 2) - 0.5 * spacing_deg
    if n_sources % 2 == 0:
        first = -spacing_deg * (n_sources / 2 - 0.5)
    return first + spacing_deg * np.arange(n_sources)


def shiny_1988(
    *,
    projection: str = "perspective",
    resolution: int = 512,
    field_width_mm: float = 2.0,
    camera_height_mm: float = 5.0 * MM_PER_INCH,
    radius_mm: float = 1.7 * MM_PER_INCH,
    fiber_diameter_mm: float = 0.040 * MM_PER_INCH,
    n_sources: int = 21,
    spacing_deg: float = 8.0,
) -> Rig:
    """The SHINY prototype of the paper (Section IV, Fig. 7).

    21 optical fibers 0.040 in (1.016 mm) across on a semicircle of radius
    1.7 in (43.18 mm) in the x-z plane, 8 degrees apart at signed polar
    angles -84 ... +76 degrees (the paper does not give the span; see
    :func:`shiny_1988_source_angles_deg`), and one camera looking down -z at
    the object on the reference plane z = 0.

    Parameters
    ----------
    projection : {"perspective", "orthographic"}
    resolution : int
        Square image size (the paper's camera is 512 x 512).
    field_width_mm : float
        Width of the imaged field at the object; 2.0 mm frames the 1/16 in
        calibration sphere (1.59 mm) with a margin.
    camera_height_mm : float
        Height of the centre of projection above the reference plane (the
        paper gives none; 5 in is a plausible macro working distance).
    """
    angles = np.radians(shiny_1988_source_angles_deg(n_sources, spacing_deg))
    positions = radius_mm * np.stack([np.sin(angles), np.zeros_like(angles), np.cos(angles)], axis=1)
    camera = Camera(
        projection=projection,
        width=resolution,
        height=resolution,
        position=[0.0, 0.0, camera_height_mm],
        target=[0.0, 0.0, 0.0],
        up=[0.0, 1.0, 0.0],
        field_width=field_width_mm,
        name="top",
    )
    return Rig(
        source_positions=positions,
        source_radii=np.full(n_sources, 0.5 * fiber_diameter_mm),
        cameras=(camera,),
        name="shiny_1988",
        metadata={
            "preset": "shiny_1988",
            "source_angles_deg": shiny_1988_source_angles_deg(n_sources, spacing_deg).tolist(),
            "array_radius_mm": radius_mm,
        },
    )


def distant_rig(directions: ArrayLike, camera: Camera, *, name: str = "distant") -> Rig:
    """A rig whose sources are known only by direction (at infinity).

    Parameters
    ----------
    directions : (n_sources, 3) array_like
        Direction towards each light, in the world frame.
    camera : Camera
    """
    directions = np.asarray(directions, dtype=float)
    return Rig(
        source_positions=directions,
        source_radii=np.zeros(len(directions)),
        cameras=(camera,),
        source_distant=np.ones(len(directions), bool),
        name=name,
    )


#: Source layouts of :func:`dome`.
DOME_LAYOUTS = ("fibonacci", "rings")


def fibonacci_hemisphere(n: int, *, max_polar_deg: float = 80.0) -> np.ndarray:
    """``n`` unit directions spread evenly over a spherical cap about +z.

    Beyond 90 degrees the cap reaches below the horizon: the paper's
    "spherical array" (Fig. 1), which a free-standing object needs for
    normals tilted more than 45 degrees from an axial camera.

    The golden-angle (Fibonacci) spiral: equal solid angle per point, polar
    angles from ``acos(1 - (i + 1/2)(1 - cos max) / n)``, azimuths ``i`` times
    the golden angle. No point lies on the axis (the first is at
    ``acos(1 - (1 - cos max) / (2 n))``, 2.3 degrees for 500 points over 80
    degrees), so a dome leaves the camera's view free.

    Parameters
    ----------
    n : int, >= 1
    max_polar_deg : float, in (0, 180)
        Polar angle of the cap's rim.

    Returns
    -------
    (n, 3) ndarray
    """
    n = int(n)
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    if not 0 < max_polar_deg < 180:
        raise ValueError(f"max_polar_deg must lie in (0, 180), got {max_polar_deg}")
    i = np.arange(n) + 0.5
    z = 1.0 - i * (1.0 - np.cos(np.radians(max_polar_deg))) / n
    r = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
    phi = i * np.pi * (3.0 - np.sqrt(5.0))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def _ring_directions(rings) -> np.ndarray:
    dirs = []
    for k, ring in enumerate(rings):
        if len(ring) != 2:
            raise ValueError(f"rings[{k}] must be (polar_deg, count), got {ring!r}")
        polar, count = float(ring[0]), int(ring[1])
        if not 0 <= polar < 180 or count < 1:
            raise ValueError(f"rings[{k}]: polar angle must lie in [0, 180) degrees and count be >= 1, got {ring!r}")
        phi = 2 * np.pi * (np.arange(count) + 0.5 * (k % 2)) / count
        t = np.radians(polar)
        dirs.append(np.stack([np.sin(t) * np.cos(phi), np.sin(t) * np.sin(phi), np.full(count, np.cos(t))], axis=1))
    return np.concatenate(dirs)


def _top_camera(projection, resolution, field_width_mm, camera_height_mm):
    return Camera(projection=projection, width=resolution, height=resolution, position=[0.0, 0.0, camera_height_mm],
                  target=[0.0, 0.0, 0.0], up=[0.0, 1.0, 0.0], field_width=field_width_mm, name="top")


def dome(
    *,
    n_sources: int = 200,
    layout: str = "fibonacci",
    rings: Sequence[tuple[float, int]] | None = None,
    max_polar_deg: float = 80.0,
    radius_mm: float | None = 1.7 * MM_PER_INCH,
    fiber_diameter_mm: float = 0.040 * MM_PER_INCH,
    projection: str = "perspective",
    resolution: int = 512,
    field_width_mm: float = 2.0,
    camera_height_mm: float = 5.0 * MM_PER_INCH,
) -> Rig:
    """A dome of sources about the object: the paper's "spherical array" (Fig. 1).

    With the rim at or below 90 degrees it is a hemispherical dome above the
    object. An axial camera sees a mirror normal only where it bisects the
    view and a source, so a rim at polar angle ``a`` reaches normals up to
    ``a / 2``: ``sin^2(a / 2)`` of a sphere's image (41 % at 80 degrees). A
    rim beyond 90 degrees carries the array below the horizon, as Fig. 1's
    sphere does, for free-standing objects; 90 % of a sphere's image needs
    ``a >= 2 asin(sqrt 0.9) = 143.1`` degrees.

    Parameters
    ----------
    n_sources : int
        Number of sources of the ``fibonacci`` layout (ignored for ``rings``).
    layout : {"fibonacci", "rings"}
        ``fibonacci``: :func:`fibonacci_hemisphere`, even over the cap.
        ``rings``: stacked rings, like the tiered ring lights of solder
        inspection; ``rings`` gives ``(polar_deg, count)`` per ring.
    max_polar_deg : float, in (0, 180)
        Rim of the fibonacci cap, from the camera axis (beyond 90: below the
        horizon).
    radius_mm : float or None
        Distance of the fiber tips from the object (the SHINY array's 1.7 in
        by default); None makes every source distant (a direction only).
    fiber_diameter_mm : float
        Diameter of each near source (the SHINY fibers' 0.040 in).
    projection, resolution, field_width_mm, camera_height_mm
        The camera, as in :func:`shiny_1988`.
    """
    if layout not in DOME_LAYOUTS:
        raise ValueError(f"layout must be one of {DOME_LAYOUTS}, got {layout!r}")
    if layout == "rings":
        if not rings:
            raise ValueError("the rings layout needs rings=[(polar_deg, count), ...]")
        dirs = _ring_directions(rings)
    else:
        dirs = fibonacci_hemisphere(n_sources, max_polar_deg=max_polar_deg)
    camera = _top_camera(projection, resolution, field_width_mm, camera_height_mm)
    distant = radius_mm is None
    if not distant:
        if not radius_mm > 0:
            raise ValueError(f"radius_mm must be > 0 or None, got {radius_mm}")
        # a fiber tip inside the camera's view of the object's field would
        # hide it from above, or shine into the image from below (the view
        # cone reaches the field at the target and widens beyond it)
        half = 0.5 * field_width_mm
        lateral = radius_mm * np.hypot(dirs[:, 0], dirs[:, 1])
        height = radius_mm * dirs[:, 2]
        cone = half * (np.ones_like(height) if projection == "orthographic"
                       else np.clip(1.0 - height / camera_height_mm, 0.0, None))
        blocking = lateral - 0.5 * fiber_diameter_mm < cone
        if np.any(blocking):
            k = int(np.flatnonzero(blocking)[0])
            polar = np.degrees(np.arccos(np.clip(dirs[k, 2], -1, 1)))
            if height[k] < 0:
                raise ValueError(f"source {k} (polar {polar:.2f} deg) lies in the camera's view cone below the "
                                 f"object and would shine into the image; use a smaller max_polar_deg")
            raise ValueError(f"source {k} (polar {polar:.2f} deg) lies "
                             f"in the camera's view of the object; use fewer sources or a ring layout off the axis")
    meta = {"preset": "dome", "layout": layout, "n_sources": int(len(dirs)), "max_polar_deg": float(max_polar_deg),
            "array_radius_mm": None if distant else float(radius_mm)}
    if layout == "rings":
        meta["rings"] = [[float(a), int(c)] for a, c in rings]
    return Rig(
        source_positions=dirs if distant else radius_mm * dirs,
        source_radii=np.zeros(len(dirs)) if distant else np.full(len(dirs), 0.5 * fiber_diameter_mm),
        cameras=(camera,),
        source_distant=np.full(len(dirs), distant),
        name="dome",
        metadata=meta,
    )


def stereo_pair(base: Rig | None = None, *, beta_deg: float = 15.0) -> Rig:
    """Two cameras at +beta and -beta from the vertical in the x-z plane, sharing ``base``'s sources.

    The paper's structured-highlight stereo (Section V, Fig. 15): each
    camera keeps the base camera's distance to its target, field width,
    resolution and projection, and is turned about the y axis (camera 0 at
    +beta towards +x, camera 1 at -beta).

    Parameters
    ----------
    base : Rig, optional
        Sources and camera to start from (default :func:`shiny_1988`).
    beta_deg : float, in (0, 80]
    """
    base = shiny_1988() if base is None else base
    if not 0 < beta_deg <= 80:
        raise ValueError(f"beta_deg must lie in (0, 80], got {beta_deg}")
    cam = base.camera
    target = np.asarray(cam.target, float)
    dist = float(np.linalg.norm(np.asarray(cam.position, float) - target))
    cams = []
    for sign, name in ((1, "plus"), (-1, "minus")):
        b = np.radians(sign * beta_deg)
        pos = target + dist * np.array([np.sin(b), 0.0, np.cos(b)])
        cams.append(Camera(projection=cam.projection, width=cam.width, height=cam.height, position=pos.tolist(),
                           target=target.tolist(), up=[0.0, 1.0, 0.0], field_width=cam.field_width, name=name))
    return Rig(source_positions=base.source_positions, source_radii=base.source_radii, cameras=tuple(cams),
               source_distant=base.source_distant, reference_z=base.reference_z, name=f"{base.name}_stereo",
               metadata={**base.metadata, "stereo_beta_deg": float(beta_deg)}, anchor=base.anchor)


def sources_in_view(positions: ArrayLike, radii: ArrayLike, camera: Camera) -> np.ndarray:
    """Which near sources would stand in ``camera``'s view of its field.

    A source (a sphere of radius ``radii[k]`` at ``positions[k]``) hides part
    of the object when it enters the pyramid of rays from the camera to the
    square field at its target; the test uses the cone through the field's
    corners (half-diagonal ``field_width / sqrt(2)``), so it errs on the side
    of refusing.

    Returns
    -------
    (n,) bool
    """
    pos = np.asarray(positions, dtype=float)
    radii = np.broadcast_to(np.asarray(radii, dtype=float), pos.shape[:1])
    start = np.asarray(camera.position, float)
    axis = np.asarray(camera.target, float) - start
    length = float(np.linalg.norm(axis))
    axis = axis / length
    rel = pos - start
    along = rel @ axis
    lateral = np.linalg.norm(rel - along[:, None] * axis, axis=1)
    half = camera.field_width / np.sqrt(2.0)
    cone = half if camera.projection == "orthographic" else half * along / length
    return (along > 0) & (along < length) & (lateral - radii < cone)


def drop_sources_in_view(positions: ArrayLike, radii: ArrayLike, cameras: Sequence[Camera], *,
                         what: str = "source") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Near sources left when those standing in any camera's view (:func:`sources_in_view`) are taken out.

    A built array has holes where the cameras look through it.

    Returns
    -------
    positions, radii : ndarray
        The sources kept.
    hidden : (n,) bool
        Which were taken out.

    Raises
    ------
    ValueError
        Every ``what`` stands in a camera's view.
    """
    pos = np.asarray(positions, dtype=float)
    radii = np.broadcast_to(np.asarray(radii, dtype=float), pos.shape[:1])
    hidden = np.zeros(len(pos), bool)
    for cam in cameras:
        hidden |= sources_in_view(pos, radii, cam)
    if hidden.all():
        raise ValueError(f"every {what} lies in {'the' if len(cameras) == 1 else 'a'} camera's view of the object")
    return pos[~hidden], radii[~hidden], hidden


def _stereo_cameras(*, beta_deg, projection, resolution, field_width_mm, camera_height_mm):
    if not 0 < beta_deg <= 80:
        raise ValueError(f"beta_deg must lie in (0, 80], got {beta_deg}")
    top = _top_camera(projection, resolution, field_width_mm, camera_height_mm)
    return stereo_pair(Rig(source_positions=[[0.0, 0.0, 1.0]], source_radii=[0.0], cameras=(top,),
                           source_distant=[True]), beta_deg=beta_deg).cameras


def _stereo_rig(dirs, *, name, meta, beta_deg, radius_mm, fiber_diameter_mm, projection, resolution,
                field_width_mm, camera_height_mm):
    cams = _stereo_cameras(beta_deg=beta_deg, projection=projection, resolution=resolution,
                           field_width_mm=field_width_mm, camera_height_mm=camera_height_mm)
    if not radius_mm > 0:
        raise ValueError(f"radius_mm must be > 0, got {radius_mm}")
    pos, radii, hidden = drop_sources_in_view(radius_mm * dirs, 0.5 * fiber_diameter_mm, cams)
    meta = {**meta, "n_sources": int((~hidden).sum()), "sources_removed_for_cameras": int(hidden.sum()),
            "array_radius_mm": float(radius_mm), "stereo_beta_deg": float(beta_deg)}
    return Rig(source_positions=pos, source_radii=radii, cameras=cams, name=name, metadata=meta)


def stereo_dome(
    *,
    n_sources: int = 1000,
    beta_deg: float = 15.0,
    max_polar_deg: float = 80.0,
    radius_mm: float = 1.7 * MM_PER_INCH,
    fiber_diameter_mm: float = 0.040 * MM_PER_INCH,
    projection: str = "perspective",
    resolution: int = 512,
    field_width_mm: float = 6.0,
    camera_height_mm: float = 5.0 * MM_PER_INCH,
) -> Rig:
    """Structured-highlight stereo in three dimensions: a Fibonacci dome and two cameras at +-beta.

    The sources of :func:`fibonacci_hemisphere` at ``radius_mm`` (the SHINY
    array's distance) and the cameras of :func:`stereo_pair` (turned about
    the y axis, camera 0 "plus" towards +x). The dome has holes where the
    cameras look through it: sources that would stand in either camera's
    view of the field (:func:`sources_in_view`) are left out, and
    ``metadata["sources_removed_for_cameras"]`` counts them.

    Why dense: a mirror element reflects a source into one camera only, so a
    stereo match pairs *different* sources whose highlights, one per camera,
    fall on nearly the same surface element. On a dome the two cameras'
    highlight elements form two unrelated lattices of spacing about
    ``r * s / 2`` on a sphere of radius ``r`` (``s`` the angular source
    spacing, ``sqrt(2 pi (1 - cos max_polar) / n)``: 4.1 degrees for 1000
    sources over 80 degrees), and their nearest pairs lie closer than a pixel
    only for a share of highlights that grows with ``n``; see
    ``docs/stereo.md``.

    Parameters
    ----------
    n_sources : int
        Sources of the Fibonacci layout before the camera holes.
    beta_deg : float, in (0, 80]
    field_width_mm : float
        A working volume several millimetres wide (the stereo case: objects
        anywhere in it, not only at the origin).
    Other parameters as in :func:`dome`.
    """
    dirs = fibonacci_hemisphere(n_sources, max_polar_deg=max_polar_deg)
    return _stereo_rig(dirs, name="stereo_dome", meta={"preset": "stereo_dome", "layout": "fibonacci",
                                                        "max_polar_deg": float(max_polar_deg)},
                       beta_deg=beta_deg, radius_mm=radius_mm, fiber_diameter_mm=fiber_diameter_mm,
                       projection=projection, resolution=resolution, field_width_mm=field_width_mm,
                       camera_height_mm=camera_height_mm)


def stereo_semicircle(
    *,
    spacing_deg: float = 2.5,
    max_polar_deg: float = 80.0,
    beta_deg: float = 15.0,
    radius_mm: float = 1.7 * MM_PER_INCH,
    fiber_diameter_mm: float = 0.040 * MM_PER_INCH,
    projection: str = "perspective",
    resolution: int = 512,
    field_width_mm: float = 6.0,
    camera_height_mm: float = 5.0 * MM_PER_INCH,
) -> Rig:
    """Planar structured-highlight stereo (paper Fig. 15): one semicircle of fibers and two cameras in its plane.

    Fibers every ``spacing_deg`` in the x-z plane (signed polar angles
    ``+-spacing/2, +-3 spacing/2, ...`` up to ``max_polar_deg``), cameras at
    ``+-beta_deg`` as in :func:`stereo_pair`, fibers in a camera's view left
    out. For an element in the source plane, camera 0 sees it under the
    source at polar angle ``2 theta - beta`` and camera 1 under ``2 theta +
    beta`` (theta the element's normal), so the two cameras' highlights fall
    on common elements when ``2 beta`` is a whole number of spacings: the
    default 2.5 degrees divides the default 30.
    """
    if not 0 < spacing_deg <= 45:
        raise ValueError(f"spacing_deg must lie in (0, 45], got {spacing_deg}")
    half = np.arange(0.5 * spacing_deg, max_polar_deg + 1e-9, spacing_deg)
    angles = np.radians(np.concatenate([-half[::-1], half]))
    dirs = np.stack([np.sin(angles), np.zeros_like(angles), np.cos(angles)], axis=1)
    return _stereo_rig(dirs, name="stereo_semicircle",
                       meta={"preset": "stereo_semicircle", "spacing_deg": float(spacing_deg),
                             "max_polar_deg": float(max_polar_deg)},
                       beta_deg=beta_deg, radius_mm=radius_mm, fiber_diameter_mm=fiber_diameter_mm,
                       projection=projection, resolution=resolution, field_width_mm=field_width_mm,
                       camera_height_mm=camera_height_mm)


# -- tolerances: a true rig from a nominal one -----------------------------------

@dataclass(frozen=True)
class RigTolerances:
    """How far a built rig may be from its design: what :func:`perturb_rig` draws.

    Random quantities are drawn from the seed; magnitudes marked *exact* are
    applied at exactly that size in a random direction, so that a study can
    say "a rotation of 0.05 degrees" rather than "of about".

    Parameters
    ----------
    fiber_position_mm : float
        Standard deviation of each fiber's position error, per axis (mm).
    fiber_radius_fraction : float
        Standard deviation of each fiber's relative radius error.
    camera_rotation_deg : float
        Exact angle of the camera's rotation about its centre of projection,
        about a random axis (degrees).
    camera_translation_mm : float
        Exact length of the camera's translation, in a random direction (mm).
    focal_fraction : float
        Exact relative change of the focal length: the field width becomes
        ``field_width / (1 + focal_fraction)`` (a longer focal length
        magnifies).
    principal_point_px : float
        Exact distance of the principal point from its nominal place, in a
        random direction (pixels).
    distortion : (k1, k2)
        Radial distortion added to the nominal camera's (exact).
    """

    fiber_position_mm: float = 0.0
    fiber_radius_fraction: float = 0.0
    camera_rotation_deg: float = 0.0
    camera_translation_mm: float = 0.0
    focal_fraction: float = 0.0
    principal_point_px: float = 0.0
    distortion: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self):
        for name in ("fiber_position_mm", "fiber_radius_fraction", "camera_rotation_deg", "camera_translation_mm",
                     "principal_point_px"):
            object.__setattr__(self, name, check_number(name, getattr(self, name), lo=0.0))
        object.__setattr__(self, "focal_fraction", check_number("focal_fraction", self.focal_fraction,
                                                                lo=-0.5, hi=0.5))
        k = _floats_or_empty(self.distortion)
        if k.shape != (2,) or not np.all(np.isfinite(k)):
            raise RigError(f"must be 2 finite numbers (k1, k2), got {self.distortion!r}", field="distortion")
        object.__setattr__(self, "distortion", (float(k[0]), float(k[1])))

    def to_dict(self) -> dict:
        return {"fiber_position_mm": self.fiber_position_mm, "fiber_radius_fraction": self.fiber_radius_fraction,
                "camera_rotation_deg": self.camera_rotation_deg, "camera_translation_mm": self.camera_translation_mm,
                "focal_fraction": self.focal_fraction, "principal_point_px": self.principal_point_px,
                "distortion": list(self.distortion)}

    @classmethod
    def from_dict(cls, d: dict) -> RigTolerances:
        check_fields(d, cls().to_dict(), error=RigError, field="tolerances")
        return cls(**d)


def _rotation(axis, angle):
    """Rotation matrix about a unit ``axis`` by ``angle`` radians (Rodrigues)."""
    a = normalize(np.asarray(axis, float))
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def _random_unit(rng, n=3):
    v = rng.normal(size=n)
    return v / np.linalg.norm(v)


def perturb_rig(nominal: Rig, tolerances: RigTolerances, seed: int = 0) -> Rig:
    """A *true* rig: the nominal one as it might have been built.

    Every draw comes from ``seed`` (per source and per camera, so adding a
    source does not change the others' errors). The result's
    ``metadata["perturbation"]`` records the seed, the tolerances and every
    applied error, so a scan rendered with it says how it differs from the
    rig a reconstruction is given.

    Parameters
    ----------
    nominal : Rig
    tolerances : RigTolerances
    seed : int

    Returns
    -------
    Rig
        Same sources (distant ones keep their direction), cameras moved,
        rotated, refocused, with principal point and distortion as drawn.
    """
    if not isinstance(tolerances, RigTolerances):
        raise RigError(f"must be RigTolerances, got {type(tolerances).__name__}", field="tolerances")
    tol = tolerances
    pos = nominal.source_positions.copy()
    radii = nominal.source_radii.copy()
    offsets = np.zeros_like(pos)
    for i in range(nominal.n_sources):
        rng = np.random.default_rng(derive_seed(seed, "source", i))
        d, f = rng.normal(size=3), rng.normal()
        if not nominal.source_distant[i]:
            offsets[i] = tol.fiber_position_mm * d
            radii[i] = radii[i] * max(0.0, 1.0 + tol.fiber_radius_fraction * f)
    pos = pos + offsets
    cams, applied_cams = [], []
    for j, cam in enumerate(nominal.cameras):
        rng = np.random.default_rng(derive_seed(seed, "camera", j))
        axis, direction, pp_dir = _random_unit(rng), _random_unit(rng), _random_unit(rng, 2)
        R = _rotation(axis, math.radians(tol.camera_rotation_deg))
        shift = tol.camera_translation_mm * direction
        position = cam.position + shift
        target = position + R @ (cam.target - cam.position)
        pp = cam.principal_point_px + tol.principal_point_px * pp_dir
        k = (cam.distortion[0] + tol.distortion[0], cam.distortion[1] + tol.distortion[1])
        cams.append(Camera(cam.projection, cam.width, cam.height, position, target, R @ cam.up,
                           cam.field_width / (1.0 + tol.focal_fraction), cam.name,
                           principal_point=tuple(pp), distortion=k))
        applied_cams.append({"rotation_axis": axis.tolist(), "rotation_deg": tol.camera_rotation_deg,
                             "translation_mm": shift.tolist(), "focal_fraction": tol.focal_fraction,
                             "principal_point_shift_px": (tol.principal_point_px * pp_dir).tolist(),
                             "distortion_added": list(tol.distortion)})
    metadata = dict(nominal.metadata)
    metadata["perturbation"] = {
        "seed": int(seed),
        "nominal": nominal.name,
        "tolerances": tol.to_dict(),
        "source_offsets_mm": offsets.tolist(),
        "source_radius_scale": np.divide(radii, nominal.source_radii, out=np.ones_like(radii),
                                         where=nominal.source_radii > 0).tolist(),
        "cameras": applied_cams,
    }
    return Rig(pos, radii, tuple(cams), nominal.source_distant, nominal.reference_z, f"{nominal.name} (as built)",
               metadata, nominal.anchor)


def rotating_semicircle(
    *,
    positions: int = 10,
    n_fibers: int = 21,
    spacing_deg: float = 8.0,
    radius_mm: float = 1.7 * MM_PER_INCH,
    fiber_diameter_mm: float = 0.040 * MM_PER_INCH,
    projection: str = "perspective",
    resolution: int = 512,
    field_width_mm: float = 2.0,
    camera_height_mm: float = 5.0 * MM_PER_INCH,
) -> Rig:
    """The SHINY semicircle of fibers turned about the vertical axis to ``positions`` azimuths.

    The fibers of :func:`shiny_1988` (signed polar angles
    :func:`shiny_1988_source_angles_deg`, in the x-z plane at azimuth 0)
    turned about +z by ``180 k / positions`` degrees, ``k = 0 .. positions -
    1``: each (position, fiber) pair is one source, ``positions * n_fibers``
    in all, in that order (position-major). Half a turn suffices, as the
    semicircle spans both sides of the axis; a turn of 180 degrees would map
    the fiber at ``+a`` onto the one at ``-a``. Fibers that would stand in
    the camera's view of its field (:func:`sources_in_view`) are left out,
    and ``metadata["sources_removed_for_camera"]`` counts them (none for the
    defaults: the innermost fibers are 4 degrees off the axis).

    Parameters
    ----------
    positions : int, >= 1
        Azimuths of the semicircle.
    n_fibers, spacing_deg, radius_mm, fiber_diameter_mm
        The semicircle, as in :func:`shiny_1988` (all fibers within 90
        degrees of the axis).
    projection, resolution, field_width_mm, camera_height_mm
        The camera, as in :func:`shiny_1988`.
    """
    positions = int(positions)
    if positions < 1:
        raise ValueError(f"positions must be >= 1, got {positions}")
    if not radius_mm > 0:
        raise ValueError(f"radius_mm must be > 0, got {radius_mm}")
    angles_deg = shiny_1988_source_angles_deg(int(n_fibers), spacing_deg)
    if np.any(np.abs(angles_deg) >= 90):
        raise ValueError(f"{n_fibers} fibers {spacing_deg} degrees apart reach {np.abs(angles_deg).max():g} "
                         "degrees from the axis; they must stay above the horizon (< 90)")
    polar = np.radians(angles_deg)
    azimuths = np.pi * np.arange(positions) / positions
    x = np.sin(polar)[None, :] * np.cos(azimuths)[:, None]
    y = np.sin(polar)[None, :] * np.sin(azimuths)[:, None]
    z = np.broadcast_to(np.cos(polar)[None, :], x.shape)
    dirs = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
    camera = _top_camera(projection, resolution, field_width_mm, camera_height_mm)
    pos, radii, hidden = drop_sources_in_view(radius_mm * dirs, 0.5 * fiber_diameter_mm, (camera,), what="fiber")
    meta = {"preset": "rotating_semicircle", "positions": positions, "n_fibers": int(n_fibers),
            "spacing_deg": float(spacing_deg), "azimuths_deg": np.degrees(azimuths).tolist(),
            "source_angles_deg": angles_deg.tolist(), "array_radius_mm": float(radius_mm),
            "n_sources": int((~hidden).sum()), "sources_removed_for_camera": int(hidden.sum())}
    return Rig(source_positions=pos, source_radii=radii, cameras=(camera,), name="rotating_semicircle", metadata=meta)
