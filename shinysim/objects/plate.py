"""The camera calibration plate: backlit holes in an opaque plate, and where it is put.

The paper (Section IV) calibrates its camera on "a calibration plate [with]
seven 0.008 inch holes drilled through its face, ... mounted such that its
upper surface lies on the reference plane", lit from behind so that every
hole images as a bright blob on a dark plate. The paper gives neither the
layout of the holes nor their spacing: :func:`shiny_plate` is an assumed
layout (one hole at the centre, six on a hexagon around it), and any other
layout is a :class:`HolePlate` of its own (:func:`dot_grid` is a larger grid
of holes, for lens distortion).

A :class:`PlatePlacement` is where the plate is during one image: a known
rigid motion of the plate's own frame into the world (the plate raised on
spacers of known height, shifted on a stage, tilted on a wedge). Its
:meth:`PlatePlacement.world_holes` are what :mod:`shinysim.calibrate.camera`
fits the camera to, and what the simulator renders.

Frames: the plate's own frame has its top face at ``z = 0`` and its holes at
``(x, y, 0)``; world frame and units as :mod:`shinysim.conventions`
(millimetres, +z towards the camera). numpy only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..conventions import MM_PER_INCH
from ..errors import CalibrationError, check_fields

__all__ = [
    "HOLE_DIAMETER_MM",
    "MIN_SPACING_DIAMETERS",
    "HolePlate",
    "shiny_plate",
    "dot_grid",
    "PlatePlacement",
]

#: Diameter of the paper's drilled holes: 0.008 in = 0.2032 mm.
HOLE_DIAMETER_MM = 0.008 * MM_PER_INCH

#: Least centre-to-centre distance of two holes, in hole diameters. At 1.5
#: diameters the plate between two holes is half a hole wide (0.1 mm for the
#: paper's holes, about 26 pixels of the preset camera), so their blobs stay
#: apart even when blurred, and a blob can never be nearer another hole's
#: centre than its own. (:func:`dot_grid`'s default 0.35 mm spacing is 1.72
#: diameters of the paper's holes.)
MIN_SPACING_DIAMETERS = 1.5

_PLATE_FIELDS = ("holes_xy_mm", "hole_diameter_mm", "name")
_PLACEMENT_FIELDS = ("offset_mm", "tilt_deg", "rotation_deg")


def _is_number(value):
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


def _positive_mm(value, field, what):
    """``value`` as a float if it is a finite number > 0, else CalibrationError: ``must be a finite {what} > 0 mm``."""
    if not _is_number(value) or not (math.isfinite(value) and value > 0):
        raise CalibrationError(f"must be a finite {what} > 0 mm, got {value!r}", field=field)
    return float(value)


def _floats(value, shape, field, what):
    """``value`` as a float array of ``shape`` (None: any length on the first axis), or CalibrationError."""
    try:
        arr = np.array(value)
        ok = arr.dtype.kind in "iuf"  # not strings, booleans, None or ragged lists
        arr = arr.astype(float)
    except (TypeError, ValueError, OverflowError):
        ok = False
    ok = ok and arr.ndim == len(shape) and all(s is None or a == s for a, s in zip(arr.shape, shape))
    if not ok:
        raise CalibrationError(f"must be {what}, got {_short(value)}", field=field)
    if not np.all(np.isfinite(arr)):
        raise CalibrationError(f"must be finite numbers, got {_short(value)}", field=field)
    return arr


def _short(value):
    text = repr(value.tolist() if isinstance(value, np.ndarray) else value)
    return text if len(text) <= 60 else text[:57] + "..."


@dataclass(frozen=True, eq=False)
class HolePlate:
    """A flat opaque plate with round through-holes, lit from behind.

    Parameters
    ----------
    holes_xy : (n, 2) float, millimetres
        Hole centres in the plate's own frame (its top face is ``z = 0``).
        Three or more, not all on one line, finite, no two centres closer
        than :data:`MIN_SPACING_DIAMETERS` hole diameters. The order is the
        order of the image points :func:`~shinysim.calibrate.camera.find_holes`
        returns.
    hole_diameter : float, millimetres, > 0
        The paper's 0.008 in drill by default.
    name : str

    Raises
    ------
    CalibrationError
        Naming the field (``holes_xy_mm``, ``hole_diameter_mm``, ``name``).
    """

    holes_xy: np.ndarray
    hole_diameter: float = HOLE_DIAMETER_MM
    name: str = "plate"

    def __post_init__(self):
        holes = _floats(self.holes_xy, (None, 2), "holes_xy_mm", "a list of [x, y] hole centres (mm)")
        d = _positive_mm(self.hole_diameter, "hole_diameter_mm", "diameter")
        if not isinstance(self.name, str):
            raise CalibrationError(f"must be a string, got {self.name!r}", field="name")
        n = len(holes)
        if n < 3:
            raise CalibrationError(f"needs at least 3 holes (not on one line), got {n}", field="holes_xy_mm")
        gaps = np.linalg.norm(holes[:, None, :] - holes[None, :, :], axis=-1)
        gaps[np.diag_indices(n)] = np.inf
        i, j = np.unravel_index(np.argmin(gaps), gaps.shape)
        if gaps[i, j] < MIN_SPACING_DIAMETERS * d:
            raise CalibrationError(
                f"holes {min(i, j)} and {max(i, j)} are {gaps[i, j]:.4g} mm apart, less than "
                f"{MIN_SPACING_DIAMETERS:g} hole diameters ({MIN_SPACING_DIAMETERS * d:.4g} mm): their images "
                "would merge", field="holes_xy_mm")
        centred = holes - holes.mean(axis=0)
        sv = np.linalg.svd(centred, compute_uv=False)
        if sv[1] <= 1e-9 * max(sv[0], d):
            raise CalibrationError("all holes lie on one line; a plate needs holes that span a plane",
                                   field="holes_xy_mm")
        holes.setflags(write=False)
        object.__setattr__(self, "holes_xy", holes)
        object.__setattr__(self, "hole_diameter", d)

    @property
    def n_holes(self) -> int:
        """Number of holes."""
        return len(self.holes_xy)

    @property
    def min_spacing(self) -> float:
        """Least centre-to-centre distance of two holes, millimetres."""
        gaps = np.linalg.norm(self.holes_xy[:, None, :] - self.holes_xy[None, :, :], axis=-1)
        return float(np.min(gaps[~np.eye(self.n_holes, dtype=bool)]))

    @property
    def holes_xyz(self) -> np.ndarray:
        """(n, 3) hole centres in the plate's own frame (``z = 0``)."""
        return np.column_stack([self.holes_xy, np.zeros(self.n_holes)])

    def to_dict(self) -> dict:
        """The plate as JSON: ``{"holes_xy_mm": [[x, y], ...], "hole_diameter_mm": d, "name": s}``."""
        return {"holes_xy_mm": self.holes_xy.tolist(), "hole_diameter_mm": self.hole_diameter, "name": self.name}

    @classmethod
    def from_dict(cls, d) -> HolePlate:
        """A plate from its JSON form (:meth:`to_dict`); errors name the field."""
        check_fields(d, _PLATE_FIELDS, required=("holes_xy_mm",), error=CalibrationError, field="plate", what="plate")
        diameter = d.get("hole_diameter_mm", HOLE_DIAMETER_MM)
        if not _is_number(diameter):
            raise CalibrationError(f"must be a number, got {_short(diameter)}", field="hole_diameter_mm")
        return cls(d["holes_xy_mm"], float(diameter), d.get("name", "plate"))

    def __eq__(self, other):
        return isinstance(other, HolePlate) and self.to_dict() == other.to_dict()

    __hash__ = None


def shiny_plate(spacing_mm: float = 0.6) -> HolePlate:
    """The paper's seven-hole plate, in an assumed layout.

    The paper gives seven holes of 0.008 in but not where they are. Here:
    hole 0 at the centre and holes 1-6 on a regular hexagon of radius
    ``spacing_mm`` around it, hole ``k`` at the angle ``60 (k - 1)`` degrees
    from +x towards +y. The default 0.6 mm keeps every hole 0.4 mm inside
    the preset camera's 2 mm field, with room for a shifted or tilted
    placement, and every two holes at least 0.6 mm (about 154 pixels) apart.
    """
    _positive_mm(spacing_mm, "spacing_mm", "distance")
    angles = np.radians(60.0 * np.arange(6))
    ring = spacing_mm * np.column_stack([np.cos(angles), np.sin(angles)])
    ring[np.abs(ring) < 1e-15 * spacing_mm] = 0.0
    return HolePlate(np.vstack([[0.0, 0.0], ring]), HOLE_DIAMETER_MM, "shiny_1988 seven holes")


def dot_grid(n: int = 5, spacing_mm: float = 0.35) -> HolePlate:
    """A square ``n x n`` grid of the paper's holes, centred on the plate origin.

    More holes over more of the field than :func:`shiny_plate`, for lens
    distortion and the principal point. Holes are ordered row by row: ``y``
    from -extent to +extent, and within a row ``x`` from -extent to +extent
    (hole ``i * n + j`` at ``((j - (n - 1) / 2) s, (i - (n - 1) / 2) s)``).
    The default (5 x 5, 0.35 mm) spans 1.4 mm of the preset's 2 mm field;
    ``dot_grid(6, 0.34)`` (1.7 mm) is the largest grid of these holes that
    stays inside the field at 1 mm above the reference plane, and reaches
    nearer the image corners, where the lens distortion is largest (see
    :mod:`shinysim.calibrate.camera` for what each grid achieves).
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 2:
        raise CalibrationError(f"must be an integer >= 2, got {n!r}", field="n")
    _positive_mm(spacing_mm, "spacing_mm", "distance")
    ticks = (np.arange(n) - 0.5 * (n - 1)) * spacing_mm
    y, x = np.meshgrid(ticks, ticks, indexing="ij")
    return HolePlate(np.column_stack([x.ravel(), y.ravel()]), HOLE_DIAMETER_MM, f"dot grid {n}x{n}")


def _rotation(axis, degrees):
    c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
    if degrees % 90 == 0:  # exact quarter turns
        c, s = float(round(c)), float(round(s))
    i, j = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[axis]
    r = np.eye(3)
    r[i, i] = c
    r[j, j] = c
    r[i, j] = -s
    r[j, i] = s
    return r


@dataclass(frozen=True)
class PlatePlacement:
    """Where the plate is during one image: a rigid motion of its frame into the world.

    A hole at ``(x, y, 0)`` in the plate frame lands at
    ``offset + Ry(tilt_y) Rx(tilt_x) Rz(rotation) (x, y, 0)``: first the
    plate is turned by ``rotation_deg`` about its normal, then tilted about
    the world x axis by ``tilt_deg[0]``, then about the world y axis by
    ``tilt_deg[1]`` (all three about the plate origin, right-handed:
    a positive ``tilt_x`` raises the plate's +y side), and then moved by
    ``offset``. The default is the paper's: the plate's top face on the
    reference plane ``z = 0``, its origin at the world origin.

    Parameters
    ----------
    offset : (3,) float, millimetres
        The plate origin in the world; ``offset[2]`` is the height of its
        top face there (e.g. the plate raised on spacers).
    tilt_deg : (2,) float, degrees
        Rotations about world x, then world y; each within (-80, 80).
    rotation_deg : float, degrees
        Rotation about the plate normal, applied first.
    """

    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    tilt_deg: tuple[float, float] = (0.0, 0.0)
    rotation_deg: float = 0.0

    def __post_init__(self):
        offset = _floats(self.offset, (3,), "offset_mm", "3 numbers (x, y, z) in mm")
        tilt = _floats(self.tilt_deg, (2,), "tilt_deg", "2 angles (about x, about y) in degrees")
        if np.any(np.abs(tilt) >= 80):
            raise CalibrationError(f"must be within (-80, 80) degrees, got {tilt.tolist()}: the camera would see "
                                   "the plate edge-on", field="tilt_deg")
        rot = self.rotation_deg
        if not _is_number(rot) or not math.isfinite(rot):
            raise CalibrationError(f"must be a finite angle in degrees, got {rot!r}", field="rotation_deg")
        object.__setattr__(self, "offset", tuple(float(v) for v in offset))
        object.__setattr__(self, "tilt_deg", tuple(float(v) for v in tilt))
        object.__setattr__(self, "rotation_deg", float(rot))

    @property
    def rotation_matrix(self) -> np.ndarray:
        """(3, 3) rotation of the plate frame into the world: ``Ry Rx Rz``."""
        tx, ty = self.tilt_deg
        return _rotation("y", ty) @ _rotation("x", tx) @ _rotation("z", self.rotation_deg)

    @property
    def normal(self) -> np.ndarray:
        """(3,) unit normal of the plate's top face in the world (up for an untilted plate)."""
        return self.rotation_matrix[:, 2].copy()

    def matrix(self) -> np.ndarray:
        """(4, 4) homogeneous transform from plate coordinates to world coordinates."""
        m = np.eye(4)
        m[:3, :3] = self.rotation_matrix
        m[:3, 3] = self.offset
        return m

    def to_world(self, points_plate) -> np.ndarray:
        """(..., 3) world coordinates of (..., 3) points given in the plate frame."""
        p = np.asarray(points_plate, dtype=float)
        return p @ self.rotation_matrix.T + np.asarray(self.offset)

    def world_holes(self, plate: HolePlate) -> np.ndarray:
        """(n, 3) world centres of the holes' top openings, in ``plate.holes_xy`` order."""
        return self.to_world(plate.holes_xyz)

    def to_dict(self) -> dict:
        """The placement as JSON: ``{"offset_mm": [x, y, z], "tilt_deg": [a, b], "rotation_deg": r}``."""
        return {"offset_mm": list(self.offset), "tilt_deg": list(self.tilt_deg), "rotation_deg": self.rotation_deg}

    @classmethod
    def from_dict(cls, d) -> PlatePlacement:
        """A placement from its JSON form (every field optional); errors name the field."""
        check_fields(d, _PLACEMENT_FIELDS, error=CalibrationError, field="placement", what="placement")
        rot = d.get("rotation_deg", 0.0)
        if not _is_number(rot):
            raise CalibrationError(f"must be a number, got {_short(rot)}", field="rotation_deg")
        return cls(d.get("offset_mm", (0.0, 0.0, 0.0)), d.get("tilt_deg", (0.0, 0.0)), rot)
