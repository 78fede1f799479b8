"""SOFAST files (Sandia OpenCSP deflectometry): calibrations, measurements and results, read checked.

SOFAST stores each object as an HDF5 group named after its OpenCSP class
(``Camera``, ``SpatialOrientation``, ``DotLocationsFixedPattern``,
``MeasurementSofastFixed``, ``MeasurementSofastFringe``, ``ImageCalibration``,
``DisplayShape``, ``DataSofastCalculation``), lengths in metres, and facet and
ensemble definitions as JSON. Each reader returns a frozen dataclass in
millimetres (fields ending ``_mm``) and radians, vectors with their components
on the last axis, images in their stored dtype; every array is read-only. Any
fault gives one :class:`~shinysim.errors.SofastError` naming the file and the
HDF5 dataset or JSON key. Reading HDF5 needs h5py (the ``sofast`` extra).
"""

from __future__ import annotations

import contextlib
import os
import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import OptionError, SofastError, check_schema, did_you_mean
from ..rig.opencv import rvec_to_matrix
from .document import read_document

__all__ = [
    "measurement_kind",
    "MAX_ELEMENTS",
    "PHASE_SHIFTS",
    "DISPLAY_MODELS",
    "METRE_FIELDS",
    "SofastError",
    "SofastCamera",
    "SpatialOrientation",
    "DotLocations",
    "FixedMeasurement",
    "FringeMeasurement",
    "ImageCalibration",
    "DisplayShape",
    "FacetDefinition",
    "EnsembleDefinition",
    "FacetResult",
    "SofastCalculation",
    "SofastFolder",
    "read_camera",
    "read_spatial_orientation",
    "read_dot_locations",
    "read_fixed_measurement",
    "read_fringe_measurement",
    "read_image_calibration",
    "read_display_shape",
    "read_facet_definition",
    "read_ensemble_definition",
    "read_calculation",
    "read_sofast_folder",
]

#: Largest dataset read, in elements (checked before reading; a 4-megapixel stack of 64 frames fits).
MAX_ELEMENTS = 2**28
#: Phase shifts per fringe period in a SOFAST fringe measurement.
PHASE_SHIFTS = 4
#: SOFAST's display models: no distortion (a screen size), a flat distorted screen, a 3-D screen.
DISPLAY_MODELS = ("rectangular2D", "distorted2D", "distorted3D")
#: Datasets of a calculation file that hold lengths in metres: read in millimetres, their key ending ``_mm``.
METRE_FIELDS = frozenset({
    "v_surf_points_facet", "v_screen_points_facet", "v_screen_points_screen", "v_align_point_facet",
    "measure_point_screen_distance", "v_cam_optic_cam", "v_cam_screen_cam", "v_cam_optic_centroid_cam_exp",
    "v_cam_optic_cam_exp", "v_cam_optic_cam_refine_1", "v_cam_optic_cam_refine_2", "v_cam_optic_cam_refine_3",
    "error_dist_optic_screen_1", "error_dist_optic_screen_2", "error_dist_optic_screen_3",
    "v_surf_points_ensemble",
})
#: 4 x 4 homogeneous transforms of a calculation file: their translation is read in millimetres.
_TRANSFORM_FIELDS = frozenset({"trans_alignment", "trans_facet_ensemble"})
#: Name prefixes of OpenCSP's stored vectors (Vxy, Vxyz, Uxyz, LoopXY: components on the first axis).
_VECTOR_PREFIXES = ("v_", "u_", "loop_", "slopes_")
#: Longest vector of processing parameters kept in :attr:`SofastCalculation.params`.
_MAX_PARAM_LENGTH = 64

_FACET_GROUP = re.compile(r"^facet_(\d+)$")
_KIND_WORDS = {"b": "booleans", "i": "integers", "u": "integers", "f": "floats", "c": "complex numbers",
               "S": "text", "U": "text", "O": "objects", "V": "a compound type", "M": "dates", "m": "durations"}


# --------------------------------------------------------------------------------------------- dataclasses

@dataclass(frozen=True, eq=False)
class SofastCamera:
    """A pinhole camera with OpenCV lens distortion, as SOFAST calibrates it.

    Parameters
    ----------
    matrix : (3, 3) float, pixels
        Intrinsic matrix ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]``, the first two rows as stored (the
        stored last row, which OpenCV ignores, may be ``(0, 0, w)``: OpenCSP's downsampled camera
        stores ``w`` = 1/8).
    distortion : (5,) float
        OpenCV coefficients ``k1, k2, p1, p2, k3`` (``k3`` = 0 when the file holds four).
    image_size : (int, int)
        Image width and height, pixels.
    name : str
        The camera's name ("" when the file has none).
    """

    matrix: np.ndarray
    distortion: np.ndarray
    image_size: tuple[int, int]
    name: str = ""


@dataclass(frozen=True, eq=False)
class SpatialOrientation:
    """The camera-screen pose of a SOFAST rig (and the optic's pose, when the file holds it).

    Parameters
    ----------
    r_cam_screen : (3,) float, radians
        Rotation vector taking camera-frame vectors into the screen frame.
    v_cam_screen_cam_mm : (3,) float, millimetres
        The screen origin in the camera frame.
    r_cam_optic : (3,) float, radians, optional
        Rotation vector taking camera-frame vectors into the optic (facet) frame.
    v_cam_optic_cam_mm : (3,) float, millimetres, optional
        The optic origin in the camera frame.

    Examples
    --------
    >>> pose = SpatialOrientation(np.array([0.0, 0.0, np.pi / 2]), np.array([100.0, 0.0, 0.0]))
    >>> pose.screen_to_camera([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0]]).round(6)
    array([[100.,   0.,   0.],
           [100., -10.,   0.]])
    >>> bool(np.allclose(pose.camera_to_screen([100.0, -10.0, 0.0]), [10.0, 0.0, 0.0]))
    True
    """

    r_cam_screen: np.ndarray
    v_cam_screen_cam_mm: np.ndarray
    r_cam_optic: np.ndarray | None = None
    v_cam_optic_cam_mm: np.ndarray | None = None

    def _rotation(self) -> np.ndarray:
        """(3, 3) ``R(r_cam_screen)``: camera-frame vectors into the screen frame."""
        return rvec_to_matrix(self.r_cam_screen)

    def screen_to_camera(self, points_mm) -> np.ndarray:
        """Screen-frame points in the camera frame: ``v_cam_screen_cam + R(r_cam_screen)^-1 p``.

        Parameters
        ----------
        points_mm : (..., 3) array_like, millimetres
            Points in the screen frame.

        Returns
        -------
        (..., 3) float, millimetres
            The same points in the camera frame.
        """
        p = _points(points_mm)
        return self.v_cam_screen_cam_mm + p @ self._rotation()  # R^-1 p = R^T p, in rows

    def camera_to_screen(self, points_mm) -> np.ndarray:
        """Camera-frame points in the screen frame: ``R(r_cam_screen) (p - v_cam_screen_cam)``.

        Parameters
        ----------
        points_mm : (..., 3) array_like, millimetres
            Points in the camera frame.

        Returns
        -------
        (..., 3) float, millimetres
            The same points in the screen frame.
        """
        p = _points(points_mm) - self.v_cam_screen_cam_mm
        return p @ self._rotation().T


@dataclass(frozen=True, eq=False)
class DotLocations:
    """Where each dot of a fixed pattern is on the screen.

    Parameters
    ----------
    x_index : (nx,) int
        Dot indices along x, consecutive and increasing (e.g. -42 ... 42).
    y_index : (ny,) int
        Dot indices along y, consecutive and increasing.
    xyz_mm : (ny, nx, 3) float, millimetres
        ``xyz_mm[j, i]`` is dot ``(x_index[i], y_index[j])`` in the screen frame; NaN for a dot that was
        not located (all three coordinates).

    Examples
    --------
    >>> dots = DotLocations(np.array([-1, 0, 1]), np.array([0, 1]),
    ...                     np.arange(18.0).reshape(2, 3, 3))
    >>> dots.position_mm([1, 5], [1, 0])
    array([[15., 16., 17.],
           [nan, nan, nan]])
    """

    x_index: np.ndarray
    y_index: np.ndarray
    xyz_mm: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        """(ny, nx) bool: the dots that were located."""
        return np.isfinite(self.xyz_mm).all(axis=-1)

    def position_mm(self, ix, iy) -> np.ndarray:
        """Screen positions of dots by index.

        Parameters
        ----------
        ix, iy : array_like of int
            Dot indices (broadcast together).

        Returns
        -------
        (..., 3) float, millimetres
            Each dot in the screen frame; NaN where the index is outside the pattern, not a whole number,
            or the dot was not located.
        """
        try:
            ix, iy = np.broadcast_arrays(np.asarray(ix, dtype=float), np.asarray(iy, dtype=float))
        except (TypeError, ValueError) as exc:
            raise OptionError(f"dot indices must be numbers of one shape: {exc}", field="ix, iy") from None
        jx, jy = ix - self.x_index[0], iy - self.y_index[0]
        ny, nx = self.xyz_mm.shape[:2]
        with np.errstate(invalid="ignore"):
            inside = (jx == np.round(jx)) & (jy == np.round(jy)) & (jx >= 0) & (jx < nx) & (jy >= 0) & (jy < ny)
        out = np.full(ix.shape + (3,), np.nan)
        out[inside] = self.xyz_mm[jy[inside].astype(np.intp), jx[inside].astype(np.intp)]
        return out


@dataclass(frozen=True, eq=False)
class FixedMeasurement:
    """One frame of a fixed-pattern (dot grid) SOFAST measurement.

    Parameters
    ----------
    image : (H, W) ndarray, stored dtype
        The camera frame.
    origin_px : (2,) float, pixels
        Image position ``(x, y)`` = (column, row) of dot index (0, 0).
    dist_optic_screen_mm : float, millimetres
        Distance from the measure point to the screen origin.
    measure_point_mm : (3,) float, millimetres
        The measure point in the facet frame.
    name, date : str
        The measurement's name and ISO date ("" when absent).
    """

    image: np.ndarray
    origin_px: np.ndarray
    dist_optic_screen_mm: float
    measure_point_mm: np.ndarray
    name: str = ""
    date: str = ""


@dataclass(frozen=True, eq=False)
class FringeMeasurement:
    """A fringe (phase-shifted sinusoid) SOFAST measurement.

    Parameters
    ----------
    fringe_images : (H, W, N) ndarray, stored dtype
        ``N = 4 * (len(periods_y) + len(periods_x))`` frames: the y fringes first (4 phase shifts per
        period), then the x fringes.
    periods_x, periods_y : (n,) float
        Fringe periods per screen width / height.
    mask_images : (H, W, 2) ndarray, stored dtype
        The dark and the bright frame.
    dist_optic_screen_mm : float, millimetres
        Distance from the measure point to the screen origin.
    measure_point_mm : (3,) float, millimetres
        The measure point in the facet frame.
    name, date : str
        The measurement's name and ISO date ("" when absent).
    """

    fringe_images: np.ndarray
    periods_x: np.ndarray
    periods_y: np.ndarray
    mask_images: np.ndarray
    dist_optic_screen_mm: float
    measure_point_mm: np.ndarray
    name: str = ""
    date: str = ""

    @property
    def fringe_images_y(self) -> np.ndarray:
        """(H, W, 4 * len(periods_y)): the y fringes."""
        return self.fringe_images[..., : PHASE_SHIFTS * len(self.periods_y)]

    @property
    def fringe_images_x(self) -> np.ndarray:
        """(H, W, 4 * len(periods_x)): the x fringes."""
        return self.fringe_images[..., PHASE_SHIFTS * len(self.periods_y):]


@dataclass(frozen=True, eq=False)
class ImageCalibration:
    """A display's brightness response: camera value against the display value shown.

    Parameters
    ----------
    kind : str
        OpenCSP's calibration class (``ImageCalibrationScaling``, ``ImageCalibrationGlobal``).
    camera_values : (n,) float
        Camera values observed.
    display_values : (n,) float
        Display values shown.
    """

    kind: str
    camera_values: np.ndarray
    display_values: np.ndarray


@dataclass(frozen=True, eq=False)
class DisplayShape:
    """Where a point given in fractional screens is on the screen.

    Parameters
    ----------
    model : str
        One of :data:`DISPLAY_MODELS`.
    xy_screen_fraction : (n, 2) float or None
        Measured grid points in fractional screens (distorted models).
    xy_screen_coords_mm : (n, 2) float, millimetres, or None
        Those points in screen coordinates (``distorted2D``).
    name : str
        The display's name.
    xyz_screen_coords_mm : (n, 3) float, millimetres, or None
        Those points in screen coordinates (``distorted3D``).
    screen_size_mm : (2,) float, millimetres, or None
        Screen width and height (``rectangular2D``).
    """

    model: str
    xy_screen_fraction: np.ndarray | None
    xy_screen_coords_mm: np.ndarray | None
    name: str = ""
    xyz_screen_coords_mm: np.ndarray | None = None
    screen_size_mm: np.ndarray | None = None

    def fraction_to_screen_mm(self, uv) -> np.ndarray:
        """Screen coordinates of points given in fractional screens.

        ``rectangular2D`` centres the screen on its origin; the distorted models interpolate linearly
        between the measured grid points (NaN outside them).

        Parameters
        ----------
        uv : (..., 2) array_like
            Points in fractional screens (0 to 1 across the screen).

        Returns
        -------
        (..., 3) float, millimetres
            The points in the screen frame (z = 0 for the 2-D models).
        """
        uv = np.asarray(uv, dtype=float)
        if uv.ndim == 0 or uv.shape[-1] != 2:
            raise OptionError(f"must be (..., 2) fractional screen points, got shape {uv.shape}", field="uv")
        if self.model == "rectangular2D":
            xy = (uv - 0.5) * self.screen_size_mm
            return np.concatenate([xy, np.zeros(uv.shape[:-1] + (1,))], axis=-1)
        from scipy.interpolate import LinearNDInterpolator

        values = self.xy_screen_coords_mm if self.model == "distorted2D" else self.xyz_screen_coords_mm
        out = LinearNDInterpolator(np.array(self.xy_screen_fraction), np.array(values))(uv.reshape(-1, 2))
        if self.model == "distorted2D":  # z = 0 on the screen, NaN with x and y outside the measured grid
            out = np.concatenate([out, np.where(np.isnan(out[:, :1]), np.nan, 0.0)], axis=1)
        return out.reshape(uv.shape[:-1] + (3,))


@dataclass(frozen=True, eq=False)
class FacetDefinition:
    """A facet's outline in its own frame (+x right, +y up, looking at the mirror).

    Parameters
    ----------
    corners_mm : (n_corners, 3) float, millimetres
        The facet's corners (four for a rectangular facet).
    centroid_mm : (3,) float, millimetres
        The facet's centroid (SOFAST's align point).
    """

    corners_mm: np.ndarray
    centroid_mm: np.ndarray


@dataclass(frozen=True, eq=False)
class EnsembleDefinition:
    """Where each facet of an ensemble (a heliostat of several facets) sits.

    Parameters
    ----------
    facet_positions_mm : (n, 3) float, millimetres
        Each facet's origin in the ensemble frame.
    facet_rotations : (n, 3) float, radians
        Rotation vectors taking each facet's frame vectors into the ensemble frame (OpenCSP's
        ``r_facet_ensemble``: a facet corner ``c`` is at ``position + R c`` in the ensemble).
    centroid_mm : (3,) float, millimetres
        The ensemble's centroid.
    perimeter : (m, 2) int
        ``(facet index, corner index)`` of each corner on the ensemble's outline.
    """

    facet_positions_mm: np.ndarray
    facet_rotations: np.ndarray
    centroid_mm: np.ndarray
    perimeter: np.ndarray = field(default_factory=lambda: _frozen(np.zeros((0, 2), dtype=np.int64)))


@dataclass(frozen=True, eq=False)
class FacetResult:
    """SOFAST's result for one facet.

    Parameters
    ----------
    slopes : (N, 2) float
        ``dz/dx, dz/dy`` at each measured point, facet frame.
    surface_points_mm : (N, 3) float, millimetres
        Where the camera rays meet SOFAST's fitted surface, facet frame.
    extras : dict of str to ndarray or str
        Every other dataset of the facet's group, keyed by its name (by its path inside the facet's
        group where two share a name): names in :data:`METRE_FIELDS` in millimetres with ``_mm``
        added, ``trans_*`` transforms with their translation in millimetres (``_mm`` added), OpenCSP
        vectors (``v_``, ``u_``, ``loop_``) with components last ((d, k) -> (k, d), (d, 1) -> (d,)),
        everything else as stored (``surf_coefs_facet`` and ``slope_coefs_facet`` are coefficients of
        polynomials in metres).
    index : int
        The facet's number (``facet_NNN``).
    """

    slopes: np.ndarray
    surface_points_mm: np.ndarray
    extras: dict[str, Any]
    index: int = 0


@dataclass(frozen=True, eq=False)
class SofastCalculation:
    """A SOFAST calculation file: per-facet results and the inputs used.

    Parameters
    ----------
    facets : tuple of FacetResult
        One per ``DataSofastCalculation/facet/facet_NNN``, in order.
    params : dict
        The processing parameters under ``DataSofastInput`` (scalars, and vectors as tuples) keyed by
        their path below it, text decoded, in the file's own units (OpenCSP: metres and pixels).
    facet_definitions : tuple of FacetDefinition
        ``DataSofastInput/optic_definition/facet_NNN/DefinitionFacet``, in order (empty when absent).
    ensemble_definition : EnsembleDefinition or None
        ``DataSofastInput/optic_definition/DefinitionEnsemble`` when present.
    general : dict of str to ndarray or str
        ``DataSofastCalculation/general``'s datasets, under the rules of :attr:`FacetResult.extras`.
    kind : str or None
        ``"fixed"`` or ``"fringe"`` (from the ``ParamsSofastFixed`` / ``ParamsSofastFringe`` group).
    """

    facets: tuple[FacetResult, ...]
    params: dict[str, Any]
    facet_definitions: tuple[FacetDefinition, ...] = ()
    ensemble_definition: EnsembleDefinition | None = None
    general: dict[str, Any] = field(default_factory=dict)
    kind: str | None = None


@dataclass(frozen=True)
class SofastFolder:
    """The SOFAST files of a folder (None for each one absent); :func:`read_sofast_folder` fills it."""

    root: Path
    camera: Path | None = None
    spatial_orientation: Path | None = None
    facet_definition: Path | None = None
    ensemble_definition: Path | None = None
    dot_locations: Path | None = None
    fixed_measurement: Path | None = None
    fixed_calculation: Path | None = None
    fringe_measurement: Path | None = None
    fringe_camera: Path | None = None
    image_calibration: Path | None = None
    display_shape: Path | None = None
    fringe_calculation: Path | None = None
    #: roles whose name pattern matched more than one file (left None above: which is meant is unknown)
    ambiguous: dict = field(default_factory=dict)


# ------------------------------------------------------------------------------------------------ HDF5

def _h5py(path):
    try:
        import h5py
    except ImportError:
        raise SofastError("reading SOFAST files needs h5py: pip install 'shinysim[sofast]'", path=path) from None
    return h5py


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.array(a)
    a.setflags(write=False)
    return a


def _points(points_mm) -> np.ndarray:
    p = np.array(points_mm, dtype=float)  # a writable copy: scipy refuses read-only arrays
    if p.ndim == 0 or p.shape[-1] != 3:
        raise OptionError(f"must be (..., 3) points in millimetres, got shape {p.shape}", field="points_mm")
    return p


def _join(*parts: str) -> str:
    return "/".join(p.strip("/") for p in parts if p.strip("/"))


def _dtype_words(dtype) -> str:
    return f"{_KIND_WORDS.get(dtype.kind, 'values')} ({dtype})"


def _check_file(path) -> Path:
    p = Path(path)
    try:
        if not p.exists():
            raise SofastError("no such file", path=p)
        if not p.is_file():
            raise SofastError("not a file: is a folder" if p.is_dir() else "not a file: not a regular file", path=p)
    except OSError as exc:
        raise SofastError(f"cannot read the file: {exc.strerror or exc}", path=p) from None
    return p


class _Group:
    """An open group of a SOFAST HDF5 file; each read is checked, each fault names the file and dataset."""

    def __init__(self, h5py, group, path: Path, root=None):
        self.h5py, self.group, self.path = h5py, group, path
        self.root = root if root is not None else self

    def field(self, key: str) -> str:
        return _join(self.group.name, key)

    def fail(self, key: str, message: str):
        raise SofastError(message, path=self.path, field=self.field(key))

    def _get(self, key: str):
        try:
            return self.group.get(key)
        except (KeyError, OSError, RuntimeError, TypeError) as exc:
            self.fail(key, f"cannot read it: {exc}")

    def has(self, key: str) -> bool:
        return self._get(key) is not None

    def sub(self, key: str) -> _Group:
        node = self._get(key)
        if node is None:
            self.fail(key, "missing group")
        if not isinstance(node, self.h5py.Group):
            self.fail(key, "is a dataset, not a group")
        return _Group(self.h5py, node, self.path, self.root)

    def names(self, key: str = "") -> list[str]:
        """The datasets below ``key`` (paths relative to it), in the file's order."""
        group = self.sub(key).group if key else self.group
        found = []
        group.visititems(lambda name, obj: found.append(name) if isinstance(obj, self.h5py.Dataset) else None)
        return found

    def dataset(self, key: str):
        node = self._get(key)
        if node is None:
            self.fail(key, "missing dataset")
        if not isinstance(node, self.h5py.Dataset):
            self.fail(key, "is a group, not a dataset")
        if node.shape is None:
            self.fail(key, "holds no data (an empty HDF5 dataspace)")
        if node.size > MAX_ELEMENTS:
            self.fail(key, f"holds {node.size} elements; a SOFAST dataset is read up to {MAX_ELEMENTS}")
        return node

    def numbers(self, key: str, *, shape: tuple | None = None, kinds: str = "fiu", what: str = "numbers",
                finite: bool = True) -> np.ndarray:
        """A numeric dataset, its dtype and shape checked before it is read, then checked not empty and
        (floats, ``finite``) free of NaN and infinities. ``shape`` holds sizes or None (any)."""
        ds = self.dataset(key)
        if ds.dtype.kind not in kinds:
            got = "text" if self.h5py.check_string_dtype(ds.dtype) is not None else _dtype_words(ds.dtype)
            self.fail(key, f"must hold {what}, got {got}")
        if shape is not None and (len(ds.shape) != len(shape)
                                  or any(w is not None and s != w for s, w in zip(ds.shape, shape, strict=True))):
            want = "(" + ", ".join("n" if w is None else str(w) for w in shape) + ("," if len(shape) == 1 else "")
            self.fail(key, f"must have shape {want}), got {ds.shape}")
        a = np.asarray(ds[()])
        if a.size == 0:
            self.fail(key, f"is empty (shape {a.shape})")
        if finite and a.dtype.kind in "fc" and not np.isfinite(a).all():
            self.fail(key, f"holds {int((~np.isfinite(a)).sum())} NaN or infinite values of {a.size}")
        return a

    def vector(self, key: str, sizes: tuple[int, ...] | int, *, what: str | None = None) -> np.ndarray:
        """A vector of ``sizes`` finite numbers stored as (n,), (n, 1), (1, n) or similar: as (n,) float."""
        sizes = (sizes,) if isinstance(sizes, int) else sizes
        ds = self.dataset(key)
        n = ds.size
        if n not in sizes or sum(s != 1 for s in ds.shape) > 1:
            count = " or ".join(str(s) for s in sizes)
            self.fail(key, f"must hold {count} numbers{f' ({what})' if what else ''} as shape ({sizes[-1]},) "
                           f"or ({sizes[-1]}, 1), got shape {ds.shape}")
        return self.numbers(key).astype(float).reshape(-1)

    def scalar(self, key: str) -> float:
        return float(self.vector(key, 1)[0])

    def integers(self, key: str, *, shape: tuple | None = None) -> np.ndarray:
        """Integers, or floats that are whole numbers: as int64."""
        a = self.numbers(key, shape=shape, what="integers")
        if a.dtype.kind == "f":
            bad = np.flatnonzero((a != np.round(a)) | (np.abs(a) > 2**53))
            if bad.size:
                self.fail(key, f"must hold integers, got {float(a.reshape(-1)[bad[0]])} at position {bad[0]}")
        return a.astype(np.int64)

    def text(self, key: str, *, required: bool = True) -> str:
        """A string dataset (shape () or (1,), fixed or variable length), decoded as UTF-8."""
        if not required and not self.has(key):
            return ""
        ds = self.dataset(key)
        if self.h5py.check_string_dtype(ds.dtype) is None and ds.dtype.kind != "S":
            self.fail(key, f"must hold text, got {_dtype_words(ds.dtype)}")
        if ds.size != 1:
            self.fail(key, f"must hold one string, got shape {ds.shape}")
        value = ds[()]
        value = value.reshape(-1)[0] if isinstance(value, np.ndarray) else value
        if isinstance(value, bytes):
            try:
                value = value.decode("utf-8")
            except UnicodeDecodeError as exc:
                self.fail(key, f"is not UTF-8 text (byte {exc.start}: 0x{value[exc.start]:02x})")
        return str(value)

    def image(self, key: str, ndim: int) -> np.ndarray:
        a = self.numbers(key, kinds="uif", what="pixel values (integers or floats)")
        if a.ndim != ndim:
            self.fail(key, f"must be a {ndim}-D image array, got shape {a.shape}")
        return a


@contextlib.contextmanager
def _opened(path, group: str, what: str, prefix: str = "") -> Iterator[_Group]:
    """The group ``prefix/group`` of the HDF5 file ``path``, open; every failure a :class:`SofastError`."""
    h5py = _h5py(path)
    path = _check_file(path)
    try:
        is_hdf5 = h5py.is_hdf5(path)
    except OSError as exc:
        raise SofastError(f"cannot read the file: {exc.strerror or exc}", path=path) from None
    if not is_hdf5:
        raise SofastError(f"is not an HDF5 file (a SOFAST {what} is HDF5)", path=path)
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise SofastError(f"cannot open the HDF5 file: {exc}", path=path) from None
    try:
        with f:
            root = _Group(h5py, f, path)
            top = _join(prefix, group)
            node = root._get(top)
            if not isinstance(node, h5py.Group):
                raise SofastError(f"is not a SOFAST {what} (no {top} group)", path=path, field=top)
            yield _Group(h5py, node, path, root)
    except SofastError:
        raise
    except (OSError, RuntimeError, KeyError) as exc:
        raise SofastError(f"cannot read the HDF5 file: {exc}", path=path) from None


def _top_groups(path: Path) -> set[str]:
    """The top-level names of an HDF5 file (to tell SOFAST files of one name apart)."""
    h5py = _h5py(path)
    try:
        if not h5py.is_hdf5(path):
            raise SofastError("is not an HDF5 file (a SOFAST measurement is HDF5)", path=path)
        with h5py.File(path, "r") as f:
            return set(f.keys())
    except OSError as exc:
        raise SofastError(f"cannot open the HDF5 file: {exc}", path=path) from None


def measurement_kind(path: str | os.PathLike) -> str:
    """``"fixed"`` or ``"fringe"``: which SOFAST measurement an HDF5 file holds (by its top-level group).

    Raises
    ------
    SofastError
        Not HDF5, or neither kind of measurement.
    """
    path = _check_file(path)
    groups = _top_groups(path)
    kinds = [k for k, g in (("fixed", "MeasurementSofastFixed"), ("fringe", "MeasurementSofastFringe")) if g in groups]
    if len(kinds) != 1:
        raise SofastError("is not a SOFAST measurement (no MeasurementSofastFixed or MeasurementSofastFringe group)"
                          if not kinds else "holds both a fixed-pattern and a fringe measurement", path=path)
    return kinds[0]


# ----------------------------------------------------------------------------------------------- readers

def read_camera(path: str | os.PathLike, *, prefix: str = "") -> SofastCamera:
    """A SOFAST camera (group ``Camera``: ``intrinsic_mat``, ``distortion_coef``, ``image_shape_xy``, ``name``).

    Parameters
    ----------
    path : str or path-like
        An HDF5 file holding ``prefix/Camera``.
    prefix : str
        The group the ``Camera`` group is in ("" for the file's top).

    Returns
    -------
    SofastCamera
    """
    with _opened(path, "Camera", "camera", prefix) as g:
        matrix = g.numbers("intrinsic_mat", shape=(3, 3)).astype(float)
        distortion = g.vector("distortion_coef", (4, 5), what="k1, k2, p1, p2[, k3]")
        size = g.integers("image_shape_xy")
        if size.size != 2 or sum(s != 1 for s in size.shape) > 1:
            g.fail("image_shape_xy", f"must hold 2 integers (width, height), got shape {size.shape}")
        size = size.reshape(-1)
        name = g.text("name", required=False)
        if not (matrix[0, 0] > 0 and matrix[1, 1] > 0):
            g.fail("intrinsic_mat", f"focal lengths fx, fy must be > 0 px, got {matrix[0, 0]}, {matrix[1, 1]}")
        if not (np.allclose((matrix[1, 0], *matrix[2, :2]), 0.0, rtol=0, atol=1e-9) and matrix[2, 2] > 0):
            g.fail("intrinsic_mat", f"must be [[fx, s, cx], [0, fy, cy], [0, 0, w > 0]], got {matrix.tolist()}")
        matrix[2, 2] = 1.0  # OpenCV reads fx, fy, cx, cy and ignores w; a downsampled camera stores 1/8
        if (size <= 0).any():
            g.fail("image_shape_xy", f"width and height must be > 0 px, got {tuple(size.tolist())}")
    return SofastCamera(_frozen(matrix), _frozen(np.pad(distortion, (0, 5 - distortion.size))),
                        (int(size[0]), int(size[1])), name)


def read_spatial_orientation(path: str | os.PathLike, *, prefix: str = "") -> SpatialOrientation:
    """The camera-screen pose (group ``SpatialOrientation``; ``r_cam_optic``, ``v_cam_optic_cam`` too when present).

    Parameters
    ----------
    path : str or path-like
        An HDF5 file holding ``prefix/SpatialOrientation``.
    prefix : str
        The group it is in, e.g.
        ``DataSofastCalculation/facet/facet_000/CalculationDataGeometryFacet`` for the pose a
        calculation found for a facet.

    Returns
    -------
    SpatialOrientation
    """
    with _opened(path, "SpatialOrientation", "spatial orientation", prefix) as g:
        r_screen = g.vector("r_cam_screen", 3, what="a rotation vector")
        v_screen = g.vector("v_cam_screen_cam", 3) * 1000.0
        r_optic = v_optic = None
        if g.has("r_cam_optic") or g.has("v_cam_optic_cam"):
            r_optic = _frozen(g.vector("r_cam_optic", 3, what="a rotation vector"))
            v_optic = _frozen(g.vector("v_cam_optic_cam", 3) * 1000.0)
    return SpatialOrientation(_frozen(r_screen), _frozen(v_screen), r_optic, v_optic)


def _index(g: _Group, key: str) -> np.ndarray:
    idx = g.integers(key)
    if idx.ndim != 1:
        g.fail(key, f"must be a 1-D list of dot indices, got shape {idx.shape}")
    step = np.flatnonzero(np.diff(idx) != 1)
    if step.size:
        k = int(step[0])
        g.fail(key, f"must be consecutive increasing integers, got {idx[k]} then {idx[k + 1]} at position {k + 1}")
    return idx


def read_dot_locations(path: str | os.PathLike, *, prefix: str = "") -> DotLocations:
    """A fixed pattern's dot positions (group ``DotLocationsFixedPattern``).

    Dots not located hold NaN in all three coordinates (kept, see :attr:`DotLocations.valid`); a dot
    with only some coordinates NaN, or any infinity, is a fault.

    Parameters
    ----------
    path : str or path-like
        An HDF5 file holding ``prefix/DotLocationsFixedPattern``.
    prefix : str
        The group it is in ("" for the file's top).

    Returns
    -------
    DotLocations
    """
    with _opened(path, "DotLocationsFixedPattern", "dot-location file", prefix) as g:
        x, y = _index(g, "x_dot_index"), _index(g, "y_dot_index")
        key = "xyz_dot_loc"
        ds = g.dataset(key)
        if ds.shape != (len(y), len(x), 3):
            g.fail(key, f"must have shape (len(y_dot_index), len(x_dot_index), 3) = ({len(y)}, {len(x)}, 3), "
                        f"got {ds.shape}")
        xyz = g.numbers(key, finite=False)
        nan = np.isnan(xyz)
        partial = nan.any(axis=-1) & ~nan.all(axis=-1)
        if np.isinf(xyz).any() or partial.any():
            j, i = np.argwhere(partial | np.isinf(xyz).any(axis=-1))[0]
            g.fail(key, f"dot (x {x[i]}, y {y[j]}) has coordinates {xyz[j, i].tolist()}: a dot is 3 finite "
                        "numbers, or all NaN where it was not located")
        if nan.all():
            g.fail(key, "locates no dot (every coordinate is NaN)")
    return DotLocations(_frozen(x), _frozen(y), _frozen(xyz * 1000.0))


def _distance(g: _Group) -> tuple[float, np.ndarray]:
    dist = g.scalar("dist_optic_screen")
    if not dist > 0:
        g.fail("dist_optic_screen", f"must be a distance > 0 m, got {dist}")
    return dist * 1000.0, _frozen(g.vector("v_measure_point_facet", 3) * 1000.0)


def read_fixed_measurement(path: str | os.PathLike, *, prefix: str = "") -> FixedMeasurement:
    """A fixed-pattern measurement (group ``MeasurementSofastFixed``: ``image``, ``origin``,
    ``dist_optic_screen``, ``v_measure_point_facet``, ``name``, ``date``).

    Parameters
    ----------
    path : str or path-like
        An HDF5 file holding ``prefix/MeasurementSofastFixed``.
    prefix : str
        The group it is in ("" for the file's top).

    Returns
    -------
    FixedMeasurement
    """
    with _opened(path, "MeasurementSofastFixed", "fixed-pattern measurement", prefix) as g:
        image = g.image("image", 2)
        origin = g.vector("origin", 2, what="x, y pixels")
        dist, point = _distance(g)
        name, date = g.text("name", required=False), g.text("date", required=False)
    return FixedMeasurement(_frozen(image), _frozen(origin), dist, point, name, date)


def _periods(g: _Group, key: str) -> np.ndarray:
    p = g.numbers(key).astype(float)
    if p.ndim != 1 or (p <= 0).any():
        g.fail(key, f"must be a 1-D list of periods > 0 (per screen), got {p.tolist()}")
    return p


def read_fringe_measurement(path: str | os.PathLike, *, prefix: str = "") -> FringeMeasurement:
    """A fringe measurement (group ``MeasurementSofastFringe``: ``fringe_images``, ``fringe_periods_x``,
    ``fringe_periods_y``, ``mask_images``, ``dist_optic_screen``, ``v_measure_point_facet``, ``name``, ``date``).

    Parameters
    ----------
    path : str or path-like
        An HDF5 file holding ``prefix/MeasurementSofastFringe``.
    prefix : str
        The group it is in ("" for the file's top).

    Returns
    -------
    FringeMeasurement
    """
    with _opened(path, "MeasurementSofastFringe", "fringe measurement", prefix) as g:
        px, py = _periods(g, "fringe_periods_x"), _periods(g, "fringe_periods_y")
        fringes = g.image("fringe_images", 3)
        masks = g.image("mask_images", 3)
        want = PHASE_SHIFTS * (len(px) + len(py))
        if fringes.shape[2] != want:
            g.fail("fringe_images", f"must hold {PHASE_SHIFTS} x ({len(py)} y + {len(px)} x periods) = {want} "
                                    f"frames, got {fringes.shape[2]}")
        if masks.shape != fringes.shape[:2] + (2,):
            g.fail("mask_images", f"must have shape {fringes.shape[:2] + (2,)} (dark, bright frames of the "
                                  f"fringes' size), got {masks.shape}")
        dist, point = _distance(g)
        name, date = g.text("name", required=False), g.text("date", required=False)
    return FringeMeasurement(_frozen(fringes), _frozen(px), _frozen(py), _frozen(masks), dist, point, name, date)


def read_image_calibration(path: str | os.PathLike, *, prefix: str = "") -> ImageCalibration:
    """A display's brightness calibration (group ``ImageCalibration``: ``calibration_type``,
    ``camera_values``, ``display_values``).

    Parameters
    ----------
    path : str or path-like
        An HDF5 file holding ``prefix/ImageCalibration``.
    prefix : str
        The group it is in ("" for the file's top).

    Returns
    -------
    ImageCalibration
    """
    with _opened(path, "ImageCalibration", "image calibration", prefix) as g:
        kind = g.text("calibration_type")
        cam = g.numbers("camera_values", shape=(None,)).astype(float)
        disp = g.numbers("display_values", shape=(None,)).astype(float)
        if len(cam) < 2:
            g.fail("camera_values", f"must hold at least 2 values, got {len(cam)}")
        if len(disp) != len(cam):
            g.fail("display_values", f"must hold one value per camera value ({len(cam)}), got {len(disp)}")
    return ImageCalibration(kind, _frozen(cam), _frozen(disp))


def read_display_shape(path: str | os.PathLike, *, prefix: str = "") -> DisplayShape:
    """A display's shape (group ``DisplayShape``: ``screen_model``, ``name`` and the model's data:
    ``screen_x``, ``screen_y`` for rectangular2D; ``xy_screen_fraction`` with ``xy_screen_coords``
    (distorted2D) or ``xyz_screen_coords`` (distorted3D), each stored (2 or 3, n)).

    Parameters
    ----------
    path : str or path-like
        An HDF5 file holding ``prefix/DisplayShape``.
    prefix : str
        The group it is in ("" for the file's top).

    Returns
    -------
    DisplayShape
    """
    with _opened(path, "DisplayShape", "display shape", prefix) as g:
        model = g.text("screen_model")
        name = g.text("name", required=False)
        if model not in DISPLAY_MODELS:
            g.fail("screen_model", f"unknown screen model {model!r}{did_you_mean(model, DISPLAY_MODELS)}; "
                                   f"SOFAST's models are {', '.join(DISPLAY_MODELS)}")
        if model == "rectangular2D":
            size = np.array([g.scalar("screen_x"), g.scalar("screen_y")])
            if not (size > 0).all():
                g.fail("screen_x", f"screen width and height must be > 0 m, got {size.tolist()}")
            return DisplayShape(model, None, None, name, screen_size_mm=_frozen(size * 1000.0))
        frac = g.numbers("xy_screen_fraction", shape=(2, None)).astype(float).T
        key, d = ("xy_screen_coords", 2) if model == "distorted2D" else ("xyz_screen_coords", 3)
        coords = g.numbers(key, shape=(d, None)).astype(float).T * 1000.0
        if len(coords) != len(frac):
            g.fail(key, f"must hold one point per screen fraction ({len(frac)}), got {len(coords)}")
        if len(frac) < 3:
            g.fail("xy_screen_fraction", f"must hold at least 3 points to interpolate between, got {len(frac)}")
    if d == 2:
        return DisplayShape(model, _frozen(frac), _frozen(coords), name)
    return DisplayShape(model, _frozen(frac), None, name, xyz_screen_coords_mm=_frozen(coords))


# ------------------------------------------------------------------------------------- facets, ensembles

def _is_hdf5(path, prefix) -> bool:
    return prefix is not None or Path(path).suffix.lower() in (".h5", ".hdf5", ".hdf")


_XYZ = {"type": "object", "properties": {k: {"type": "array", "items": {"type": "number"}} for k in "xyz"},
        "required": ["x", "y", "z"], "additionalProperties": False}
_FACET_SCHEMA = {"type": "object", "properties": {"v_facet_corners": _XYZ, "v_centroid_facet": _XYZ},
                 "required": ["v_facet_corners", "v_centroid_facet"], "additionalProperties": False}
_ENSEMBLE_SCHEMA = {
    "type": "object",
    "properties": {
        "v_facet_locations": _XYZ,
        "r_facet_ensemble": {"type": "object", "additionalProperties": {"type": "vec3"}},
        "ensemble_perimeter": {
            "type": "object",
            "properties": {k: {"type": "array", "items": {"type": "integer"}}
                           for k in ("facet_indices", "corner_indices")},
            "required": ["facet_indices", "corner_indices"], "additionalProperties": False},
        "v_centroid_ensemble": _XYZ,
    },
    "required": ["v_facet_locations", "r_facet_ensemble", "ensemble_perimeter", "v_centroid_ensemble"],
    "additionalProperties": False,
}


def _json(path, schema: dict, what: str) -> dict:
    """A JSON object checked against ``schema``; a fault of a top-level key names that key as the field."""
    doc = read_document(path, error=SofastError, what=f"{what} JSON")
    try:
        return check_schema(doc, schema, error=SofastError, path=path, what=what)
    except SofastError as exc:
        if exc.field is not None:
            raise
        missing = [k for k in schema["required"] if k not in doc]
        unknown = [k for k in doc if k not in schema["properties"]]
        keys = unknown + missing if exc.problem.startswith("unknown field") else missing + unknown
        raise SofastError(exc.problem, path=path, field=keys[0] if keys else None) from None


def _xyz(d: dict, key: str, path, n: int | None = None) -> np.ndarray:
    """A JSON ``{"x": [...], "y": [...], "z": [...]}`` as (n, 3) metres, the lengths and values checked."""
    lengths = [len(d[c]) for c in "xyz"]
    for c, length in zip("yz", lengths[1:], strict=True):
        if length != lengths[0]:
            raise SofastError(f"must hold {lengths[0]} numbers like x, got {length}", path=path, field=f"{key}.{c}")
    if n is not None and lengths[0] != n:
        raise SofastError(f"must hold {n} point{'s' if n != 1 else ''} (x, y, z lists of {n}), got {lengths[0]}",
                          path=path, field=f"{key}.x")
    a = np.array([d[c] for c in "xyz"], dtype=float).T
    bad = np.argwhere(~np.isfinite(a))
    if bad.size:
        raise SofastError(f"must be finite numbers, got {a[tuple(bad[0])]}", path=path,
                          field=f"{key}.{'xyz'[bad[0][1]]}[{bad[0][0]}]")
    return a


def _facet_from_group(g: _Group) -> FacetDefinition:
    corners = g.numbers("v_facet_corners", shape=(3, None)).astype(float).T
    if len(corners) < 3:
        g.fail("v_facet_corners", f"must hold at least 3 corners, got {len(corners)}")
    return FacetDefinition(_frozen(corners * 1000.0), _frozen(g.vector("v_facet_centroid", 3) * 1000.0))


def read_facet_definition(path: str | os.PathLike, *, prefix: str | None = None) -> FacetDefinition:
    """A facet definition: OpenCSP's facet JSON, or the ``DefinitionFacet`` group of an HDF5 file.

    The JSON is ``{"v_facet_corners": {"x": [...], "y": [...], "z": [...]}, "v_centroid_facet":
    {"x": [x], "y": [y], "z": [z]}}`` in metres. The HDF5 form is read when ``prefix`` is given or the
    file ends ``.h5``/``.hdf5``: ``prefix/DefinitionFacet/v_facet_corners`` (3, n) and
    ``v_facet_centroid`` (3, 1).

    Parameters
    ----------
    path : str or path-like
        The JSON or HDF5 file.
    prefix : str, optional
        The HDF5 group holding ``DefinitionFacet``, e.g. ``DataSofastInput/optic_definition/facet_000``.

    Returns
    -------
    FacetDefinition
    """
    if _is_hdf5(path, prefix):
        with _opened(path, "DefinitionFacet", "facet definition", prefix or "") as g:
            return _facet_from_group(g)
    doc = _json(path, _FACET_SCHEMA, "facet definition")
    corners = _xyz(doc["v_facet_corners"], "v_facet_corners", path)
    if len(corners) < 3:
        raise SofastError(f"must hold at least 3 corners, got {len(corners)}", path=path, field="v_facet_corners.x")
    centroid = _xyz(doc["v_centroid_facet"], "v_centroid_facet", path, n=1)[0]
    return FacetDefinition(_frozen(corners * 1000.0), _frozen(centroid * 1000.0))


def _ensemble(positions, rotations, centroid, perimeter, fail) -> EnsembleDefinition:
    if len(rotations) != len(positions):
        fail("r_facet_ensemble", f"must hold one rotation per facet location ({len(positions)}), got {len(rotations)}")
    bad = np.flatnonzero((perimeter[:, 0] < 0) | (perimeter[:, 0] >= len(positions)) | (perimeter[:, 1] < 0))
    if bad.size:
        fail("ensemble_perimeter", f"entry {bad[0]} (facet {perimeter[bad[0], 0]}, corner {perimeter[bad[0], 1]}) "
                                   f"names no corner of the {len(positions)} facets")
    return EnsembleDefinition(_frozen(positions * 1000.0), _frozen(rotations), _frozen(centroid * 1000.0),
                              _frozen(perimeter.astype(np.int64)))


def _ensemble_from_group(g: _Group) -> EnsembleDefinition:
    positions = g.numbers("v_facet_locations", shape=(3, None)).astype(float).T
    rotations = g.numbers("r_facet_ensemble", shape=(None, 3)).astype(float)
    perimeter = g.integers("ensemble_perimeter", shape=(None, 2))
    return _ensemble(positions, rotations, g.vector("v_centroid_ensemble", 3), perimeter, g.fail)


def read_ensemble_definition(path: str | os.PathLike, *, prefix: str | None = None) -> EnsembleDefinition:
    """An ensemble definition: OpenCSP's ensemble JSON, or the ``DefinitionEnsemble`` group of an HDF5 file.

    The JSON (metres, radians) is ``{"v_facet_locations": {"x": [...], "y": [...], "z": [...]},
    "r_facet_ensemble": {"0": [rx, ry, rz], "1": [...], ...}, "ensemble_perimeter": {"facet_indices":
    [...], "corner_indices": [...]}, "v_centroid_ensemble": {"x": [x], "y": [y], "z": [z]}}``; the
    rotations are keyed ``"0"`` to ``"n-1"``. The HDF5 form is read when ``prefix`` is given or the
    file ends ``.h5``/``.hdf5``: ``v_facet_locations`` (3, n), ``r_facet_ensemble`` (n, 3),
    ``ensemble_perimeter`` (m, 2), ``v_centroid_ensemble`` (3,).

    Parameters
    ----------
    path : str or path-like
        The JSON or HDF5 file.
    prefix : str, optional
        The HDF5 group holding ``DefinitionEnsemble``.

    Returns
    -------
    EnsembleDefinition
    """
    if _is_hdf5(path, prefix):
        with _opened(path, "DefinitionEnsemble", "ensemble definition", prefix or "") as g:
            return _ensemble_from_group(g)
    doc = _json(path, _ENSEMBLE_SCHEMA, "ensemble definition")
    positions = _xyz(doc["v_facet_locations"], "v_facet_locations", path)
    rot = doc["r_facet_ensemble"]
    keys = [str(i) for i in range(len(rot))]
    if sorted(rot, key=lambda k: (len(k), k)) != keys:
        raise SofastError(f"must be keyed '0' to '{len(rot) - 1}', got {', '.join(map(repr, rot))}", path=path,
                          field="r_facet_ensemble")
    rotations = np.array([rot[k] for k in keys], dtype=float).reshape(-1, 3)
    per = doc["ensemble_perimeter"]
    if len(per["corner_indices"]) != len(per["facet_indices"]):
        raise SofastError(f"must hold one corner per facet index ({len(per['facet_indices'])}), got "
                          f"{len(per['corner_indices'])}", path=path, field="ensemble_perimeter.corner_indices")
    perimeter = np.array([per["facet_indices"], per["corner_indices"]], dtype=np.int64).T.reshape(-1, 2)
    centroid = _xyz(doc["v_centroid_ensemble"], "v_centroid_ensemble", path, n=1)[0]

    def fail(key, message):
        raise SofastError(message, path=path, field=key)

    return _ensemble(positions, rotations, centroid, perimeter, fail)


# ----------------------------------------------------------------------------------------- calculations

def _numbered(g: _Group, key: str) -> list[tuple[int, str]]:
    """``(N, name)`` of the ``facet_NNN`` groups below ``key``, by number."""
    found = [(int(m.group(1)), name) for name in g.sub(key).group if (m := _FACET_GROUP.match(name))]
    return sorted(found)


def _value(g: _Group, key: str):
    """A dataset of a calculation file as it is returned: text as str, numbers as a read-only array."""
    ds = g.dataset(key)
    if g.h5py.check_string_dtype(ds.dtype) is not None or ds.dtype.kind == "S":
        return g.text(key) if ds.size == 1 else [str(v, "utf-8", "replace") if isinstance(v, bytes) else str(v)
                                                 for v in np.asarray(ds[()]).reshape(-1)]
    return g.numbers(key, kinds="biuf", what="numbers or booleans", finite=False)


def _collect(g: _Group, skip: frozenset[str] = frozenset()) -> dict[str, Any]:
    """Every dataset below ``g`` but ``skip``, converted as :attr:`FacetResult.extras` says."""
    names = [n for n in g.names() if n not in skip]
    base = [n.rsplit("/", 1)[-1] for n in names]
    out = {}
    for name, leaf in zip(names, base, strict=True):
        key = leaf if base.count(leaf) == 1 else name
        value = _value(g, name)
        if isinstance(value, np.ndarray):
            if leaf in METRE_FIELDS:
                value, key = value.astype(float) * 1000.0, key + "_mm"
            elif leaf in _TRANSFORM_FIELDS and value.shape == (4, 4):
                value = value.astype(float)
                value[:3, 3] *= 1000.0
                key += "_mm"
            if leaf.startswith(_VECTOR_PREFIXES) and value.ndim == 2 and value.shape[0] in (2, 3):
                value = value[:, 0] if value.shape[1] == 1 else value.T
            value = _frozen(value)
        out[key] = value
    return out


def _params(g: _Group) -> dict[str, Any]:
    out = {}
    for name in g.names():
        if "DefinitionFacet/" in name or "DefinitionEnsemble/" in name:
            continue
        value = _value(g, name)
        if isinstance(value, np.ndarray):
            if value.size == 1:
                value = value.reshape(-1)[0].item()
            elif value.ndim == 1 and value.size <= _MAX_PARAM_LENGTH:
                value = tuple(v.item() for v in value)
            else:
                continue
        out[name] = value
    return out


def read_calculation(path: str | os.PathLike) -> SofastCalculation:
    """A SOFAST calculation file: every ``DataSofastCalculation/facet/facet_NNN`` and the inputs.

    Each facet needs ``SlopeSolverData/slopes_facet_xy`` (2, N) and ``v_surf_points_facet`` (3, N),
    both finite; they come back as (N, 2) and (N, 3). A fringe calculation also holds the camera,
    display shape, spatial orientation and image calibration it used: the readers above read them
    from the same file, and :func:`read_spatial_orientation` with ``prefix=
    "DataSofastCalculation/facet/facet_000/CalculationDataGeometryFacet"`` the pose found for a facet.

    Parameters
    ----------
    path : str or path-like
        The HDF5 calculation file.

    Returns
    -------
    SofastCalculation
    """
    with _opened(path, "DataSofastCalculation", "calculation", "") as calc:
        numbered = _numbered(calc, "facet")
        if not numbered:
            calc.fail("facet", "holds no facet result (no facet_NNN group)")
        facets = []
        for index, name in numbered:
            g = calc.sub(f"facet/{name}")
            slopes = g.numbers("SlopeSolverData/slopes_facet_xy", shape=(2, None)).astype(float).T
            points = g.numbers("SlopeSolverData/v_surf_points_facet", shape=(3, len(slopes))).astype(float).T
            extras = _collect(g, frozenset({"SlopeSolverData/slopes_facet_xy", "SlopeSolverData/v_surf_points_facet"}))
            facets.append(FacetResult(_frozen(slopes), _frozen(points * 1000.0), extras, index))
        general = _collect(calc.sub("general")) if calc.has("general") else {}
        root = calc.root
        params, definitions, ensemble, kind = {}, (), None, None
        if root.has("DataSofastInput"):
            inp = root.sub("DataSofastInput")
            params = _params(inp)
            kind = "fixed" if inp.has("ParamsSofastFixed") else "fringe" if inp.has("ParamsSofastFringe") else None
            if inp.has("optic_definition"):
                defs = [(i, n) for i, n in _numbered(inp, "optic_definition")
                        if inp.has(f"optic_definition/{n}/DefinitionFacet")]
                definitions = tuple(_facet_from_group(inp.sub(f"optic_definition/{n}/DefinitionFacet"))
                                    for _, n in defs)
                if definitions and [i for i, _ in defs] != [i for i, _ in numbered]:
                    inp.fail("optic_definition", f"defines facets {[i for i, _ in defs]} but the results are of "
                                                 f"facets {[i for i, _ in numbered]}")
                if inp.has("optic_definition/DefinitionEnsemble"):
                    ensemble = _ensemble_from_group(inp.sub("optic_definition/DefinitionEnsemble"))
    return SofastCalculation(tuple(facets), params, definitions, ensemble, general, kind)


# ---------------------------------------------------------------------------------------------- folders

#: Each file of a SOFAST folder: its subfolder in the layout, its names (tried in order; globs allowed)
#: and the top-level HDF5 group that tells it apart where one name serves two files in a flat folder.
_FOLDER_FILES = {
    "camera": ("common", ("camera_sofast.h5",), None),
    "spatial_orientation": ("common", ("spatial_orientation.h5",), None),
    "facet_definition": ("common", ("Facet_*.json",), None),
    "ensemble_definition": ("common", ("Ensemble_*.json",), None),
    "dot_locations": ("fixed", ("fixed_pattern_dot_locations.h5",), None),
    "fixed_measurement": ("fixed", ("measurement_facet.h5", "measurement_*.h5"), "MeasurementSofastFixed"),
    "fixed_calculation": ("fixed", ("expected_calculation_facet.h5", "calculation_facet.h5",
                                    "expected_calculation_*.h5", "calculation_*.h5"), None),
    "fringe_measurement": ("fringe", ("measurement_facet.h5",), "MeasurementSofastFringe"),
    "fringe_camera": ("fringe", ("camera_sofast_downsampled.h5",), None),
    "image_calibration": ("fringe", ("image_calibration.h5",), None),
    "display_shape": ("fringe", ("display_distorted_2d.h5", "display_*.h5"), None),
    "fringe_calculation": ("fringe", ("expected_data.h5", "data.h5"), None),
}
_SUBFOLDERS = ("common", "fixed", "fringe")


def read_sofast_folder(root: str | os.PathLike) -> SofastFolder:
    """The SOFAST files of a folder, found by name (nothing is read but a measurement's top group).

    Two layouts: subfolders ``common/`` (``camera_sofast.h5``, ``spatial_orientation.h5``,
    ``Facet_*.json``, ``Ensemble_*.json``), ``fixed/`` (``fixed_pattern_dot_locations.h5``,
    ``measurement_facet.h5``, ``expected_calculation_facet.h5``) and ``fringe/``
    (``measurement_facet.h5``, ``camera_sofast_downsampled.h5``, ``image_calibration.h5``,
    ``display_distorted_2d.h5``, ``expected_data.h5``); or all of them in one flat folder, where a
    ``measurement_facet.h5`` counts as fixed or fringe by its top-level group. A fixed measurement
    or calculation of another name (``measurement_*.h5``, ``calculation_*.h5``, e.g. OpenCSP's
    facet-ensemble files) is found when the usual name is absent. A role whose pattern matches
    two files is left None and listed in ``ambiguous`` (which one is meant is unknown: the caller
    names it).

    Parameters
    ----------
    root : str or path-like
        The folder.

    Returns
    -------
    SofastFolder
        The paths found, None where absent.
    """
    root = Path(root)
    if not root.exists():
        raise SofastError("no such folder", path=root)
    if not root.is_dir():
        raise SofastError("not a folder (a SOFAST folder holds common/, fixed/, fringe/ or the files)", path=root)
    layout = any((root / sub).is_dir() for sub in _SUBFOLDERS)
    found: dict[str, Path] = {}
    ambiguous: dict[str, tuple[Path, ...]] = {}
    groups: dict[Path, set[str]] = {}
    for role, (sub, patterns, group) in _FOLDER_FILES.items():
        folder = root / sub if layout else root
        for pattern in patterns:
            hits = sorted(p for p in folder.glob(pattern) if p.is_file())
            if group is not None and not layout:
                hits = [p for p in hits if group in groups.setdefault(p, _top_groups(p))]
            if len(hits) > 1:
                ambiguous[role] = tuple(hits)
                break
            if hits:
                found[role] = hits[0]
                break
    if not found and not ambiguous:
        names = sorted({n for _, patterns, _ in _FOLDER_FILES.values() for n in patterns})
        raise SofastError(f"holds no SOFAST file (looked for {', '.join(_SUBFOLDERS)}/ or {', '.join(names)})",
                          path=root)
    return SofastFolder(root, **found, ambiguous=ambiguous)
