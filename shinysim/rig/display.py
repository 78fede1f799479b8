"""A display of dots seen in a large mirror (fixed-pattern deflectometry), and its exact geometry.

A screen shows a grid of dots; a camera sees the screen reflected in a mirror
facet, each dot's reflection a structured highlight told apart by its place
in the grid. :class:`Display` is the screen's pattern, :class:`DisplaySetup`
the camera, screen and facet placed in the camera's frame, and
:meth:`DisplaySetup.reflected_dots` the exact image of every dot centre (the
mirror point where the camera ray reflects about the exact normal onto the
dot). :func:`crop_camera` is a window of a camera, and :func:`facet_pose` the
pose that faces a facet to the bisector of camera and screen.

Frames: the *camera frame* is the camera's world frame (its own frame when
it is made by :func:`shinysim.rig.opencv.camera_from_opencv` without a pose:
centre at the origin, +z forward, +x image columns, +y image rows); the
*screen frame* holds the dots, the lit screen being its plane z = 0; the
*facet frame* is the mirror's own (:class:`shinysim.objects.mirror.MirrorFacet`).
Millimetres throughout. numpy and SciPy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike

from ..errors import OptionError
from .core import Camera, Rig

__all__ = ["DISPLAY_POLARITIES", "Display", "DisplaySetup", "REFLECTION_TOLERANCE_MM", "ReflectedDots",
           "SOFAST_DOT_RADIUS_MM", "SOFAST_FACET_CENTRE_MM", "crop_camera", "facet_pose"]

#: What a dot is against the screen around it: dark on bright (SOFAST's fixed pattern) or bright on dark.
DISPLAY_POLARITIES = ("dark", "bright")

#: How close the camera ray through a reflected dot's pixel must come to its mirror point, and its reflection
#: to the dot's centre, for :meth:`DisplaySetup.reflected_dots` to call the dot's reflection found
#: (millimetres; the solution itself is exact to ~1e-9 mm at 10 m).
REFLECTION_TOLERANCE_MM = 1e-6

#: The real NSTTF facet's centre in SOFAST's camera frame, millimetres (its pose in the fixed-pattern measurement:
#: 10.008 m from the screen's origin, as the measurement's ``dist_optic_screen`` says).
SOFAST_FACET_CENTRE_MM = (228.6, 302.8, 9438.3)

#: The dot radius that makes a twin of SOFAST's measurement as dark as its real frame, millimetres. In the real
#: frame the darkness of a dot integrated over it, over the local background, is 10.6 px^2 (the median of 95
#: dots): a black disc 3.67 px across. The twin's reflected screen is 3.68 mm per pixel there (its lattice of
#: 11.18 x 11.24 px per 41.2 mm pitch is the real frame's to 0.03 %), so the disc is 13.5 mm across.
SOFAST_DOT_RADIUS_MM = 6.75


def _number(name, value, *, positive=False, nonnegative=False):
    rule = " > 0" if positive else " >= 0" if nonnegative else ""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not math.isfinite(value) or (positive and not value > 0) or (nonnegative and not value >= 0):
        raise OptionError(f"must be a finite number{rule}, got {value!r}", field=name)
    return float(value)


def _array(name, value, shape_text, ndim=None, last=None):
    try:
        a = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise OptionError(f"must be {shape_text} of numbers, got {value!r}", field=name) from None
    if (ndim is not None and a.ndim != ndim) or (last is not None and a.shape[-1:] != (last,)):
        raise OptionError(f"must be {shape_text}, got shape {a.shape}", field=name)
    return a


def _rotation(name, value):
    R = _array(name, value, "a (3, 3) rotation matrix", ndim=2, last=3)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        raise OptionError(f"must be a finite (3, 3) rotation matrix, got shape {R.shape}", field=name)
    if np.max(np.abs(R.T @ R - np.eye(3))) > 1e-9 or np.linalg.det(R) < 0:
        raise OptionError("is not a proper rotation (R^T R = I within 1e-9, det R = +1)", field=name)
    return R


def _vec(name, value, n=3):
    a = _array(name, value, f"{n} numbers")
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        raise OptionError(f"must be {n} finite numbers, got {value!r}", field=name)
    return a


def _readonly(*arrays):
    for a in arrays:
        a.setflags(write=False)


@dataclass(frozen=True, eq=False)
class Display:
    """A screen showing a grid of round dots.

    Parameters
    ----------
    dots_mm : (ny, nx, 3) float, millimetres
        Dot centres in the screen frame, ``dots_mm[j, i]`` the dot of index
        ``(x_index[i], y_index[j])``. A dot whose three coordinates are all
        NaN is not shown (a dot whose place is not known, as the outer ring
        of SOFAST's measured grid).
    x_index : (nx,) int
    y_index : (ny,) int
        The grid indices (distinct).
    dot_radius_mm : float, millimetres
        Radius of every dot; the dots must not overlap. Default
        :data:`SOFAST_DOT_RADIUS_MM`.
    polarity : {"dark", "bright"}
        Dark dots on a bright screen, or bright dots on a dark one.
    on_radiance, off_radiance : float
        The bright and the dark level (``on_radiance > off_radiance >= 0``).
    size_mm : (width, height), optional, millimetres
        The lit screen rectangle in the plane z = 0, centred at
        ``centre_mm``. Default: the dots' bounding box with one pitch (the
        median spacing of neighbouring dots) to spare on every side.
    centre_mm : (x, y), optional, millimetres
        The rectangle's centre. Default: the centre of the dots' bounding box.

    Examples
    --------
    >>> d = Display.planar_grid(5, 3, 40.0, dot_radius_mm=6.0)
    >>> d.dots_mm.shape, d.x_index.tolist(), d.size_mm
    ((3, 5, 3), [-2, -1, 0, 1, 2], (240.0, 160.0))
    """

    dots_mm: np.ndarray
    x_index: np.ndarray
    y_index: np.ndarray
    dot_radius_mm: float = SOFAST_DOT_RADIUS_MM
    polarity: str = "dark"
    on_radiance: float = 1.0
    off_radiance: float = 0.0
    size_mm: tuple[float, float] | None = None
    centre_mm: tuple[float, float] | None = None

    def __post_init__(self):
        dots = _array("dots_mm", self.dots_mm, "(ny, nx, 3)", ndim=3, last=3)
        nan = np.isnan(dots)
        if np.any(nan.any(-1) != nan.all(-1)) or np.any(np.isinf(dots)):
            raise OptionError("each dot must be three finite numbers or three NaN (no dot)", field="dots_mm")
        shown = ~nan.any(-1)
        if not shown.any():
            raise OptionError("holds no dot (every entry NaN)", field="dots_mm")
        ny, nx = shown.shape
        for name, value, n in (("x_index", self.x_index, nx), ("y_index", self.y_index, ny)):
            idx = np.asarray(value)
            if idx.shape != (n,) or not np.issubdtype(idx.dtype, np.integer) or len(np.unique(idx)) != n:
                raise OptionError(f"must be {n} distinct integers (one per {'column' if name[0] == 'x' else 'row'} "
                                  f"of dots_mm), got {value!r}", field=name)
        xi = np.asarray(self.x_index, dtype=np.int64).copy()
        yi = np.asarray(self.y_index, dtype=np.int64).copy()
        radius = _number("dot_radius_mm", self.dot_radius_mm, positive=True)
        if self.polarity not in DISPLAY_POLARITIES:
            raise OptionError(f"must be one of {', '.join(map(repr, DISPLAY_POLARITIES))}, got {self.polarity!r}",
                              field="polarity")
        on = _number("on_radiance", self.on_radiance, nonnegative=True)
        off = _number("off_radiance", self.off_radiance, nonnegative=True)
        if not on > off:
            raise OptionError(f"the bright level {on!r} must exceed the dark level off_radiance = {off!r}",
                              field="on_radiance")
        spacing = self._spacings(dots)
        if spacing.size and spacing.min() <= 2 * radius:
            raise OptionError(f"{radius!r} mm makes neighbouring dots overlap (the closest are {spacing.min():.4g} mm "
                              "apart)", field="dot_radius_mm")
        xy = dots[shown][:, :2]
        lo, hi = xy.min(0), xy.max(0)
        pitch = float(np.median(spacing)) if spacing.size else 4.0 * radius
        if self.centre_mm is None:
            centre = 0.5 * (lo + hi)
        else:
            centre = _vec("centre_mm", self.centre_mm, 2)
        if self.size_mm is None:
            size = hi - lo + 2.0 * pitch
        else:
            size = _vec("size_mm", self.size_mm, 2)
            if not np.all(size > 0):
                raise OptionError(f"must be a width and a height > 0 mm, got {self.size_mm!r}", field="size_mm")
        _readonly(dots, xi, yi)
        for name, value in (("dots_mm", dots), ("x_index", xi), ("y_index", yi), ("dot_radius_mm", radius),
                            ("on_radiance", on), ("off_radiance", off),
                            ("size_mm", (float(size[0]), float(size[1]))),
                            ("centre_mm", (float(centre[0]), float(centre[1])))):
            object.__setattr__(self, name, value)

    @staticmethod
    def _spacings(dots):
        """Distances between grid neighbours (along both index directions) that are both shown."""
        out = [np.linalg.norm(np.diff(dots, axis=a), axis=-1).ravel() for a in (0, 1)]
        d = np.concatenate(out)
        return d[np.isfinite(d)]

    @classmethod
    def planar_grid(cls, nx: int, ny: int, pitch_mm: float, **kwargs) -> Display:
        """A flat square grid in the plane z = 0, index 0 at the origin.

        Parameters
        ----------
        nx, ny : int
            Dots per row and per column; indices ``arange(n) - n // 2``
            (for 85: -42 ... 42), so an odd grid is centred on the origin.
        pitch_mm : float, millimetres
        **kwargs
            The other fields of :class:`Display`.
        """
        for name, n in (("nx", nx), ("ny", ny)):
            if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, np.integer)) or not 1 <= n <= 4096:
                raise OptionError(f"must be an integer from 1 to 4096, got {n!r}", field=name)
        pitch = _number("pitch_mm", pitch_mm, positive=True)
        xi = np.arange(nx) - nx // 2
        yi = np.arange(ny) - ny // 2
        gx, gy = np.meshgrid(xi * pitch, yi * pitch)
        return cls(np.stack([gx, gy, np.zeros_like(gx)], axis=-1), xi, yi, **kwargs)

    @property
    def shown(self) -> np.ndarray:
        """(ny, nx) bool: the dots the screen shows (not NaN)."""
        return ~np.isnan(self.dots_mm[..., 0])

    @property
    def pitch_mm(self) -> float:
        """The median distance between neighbouring dots."""
        s = self._spacings(self.dots_mm)
        return float(np.median(s)) if s.size else math.nan

    @property
    def is_planar(self) -> bool:
        """Every dot lies in the lit plane z = 0 (to 1e-9 of the screen's size)."""
        z = self.dots_mm[..., 2][self.shown]
        return bool(np.all(np.abs(z) <= 1e-9 * max(self.size_mm)))

    def flattened(self) -> Display:
        """The same display with every dot moved onto the plane z = 0 (its x, y kept)."""
        dots = self.dots_mm.copy()
        dots[..., 2] = np.where(self.shown, 0.0, np.nan)
        return replace(self, dots_mm=dots)

    def index_of(self, ix: int, iy: int) -> tuple[int, int]:
        """``(j, i)``: where dot index ``(ix, iy)`` sits in ``dots_mm``."""
        i = np.flatnonzero(self.x_index == ix)
        j = np.flatnonzero(self.y_index == iy)
        if not i.size or not j.size:
            raise OptionError(f"the display has no dot of index ({ix}, {iy})", field="index")
        return int(j[0]), int(i[0])

    def radiance(self, x: ArrayLike, y: ArrayLike) -> np.ndarray:
        """The exact radiance the screen shows at screen points ``(x, y)`` (0 off the lit rectangle).

        Returns
        -------
        ndarray
        """
        from scipy.spatial import cKDTree

        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        x, y = np.broadcast_arrays(x, y)
        centres = self.dots_mm[self.shown][:, :2]
        dist, _ = cKDTree(centres).query(np.stack([x.ravel(), y.ravel()], -1))
        inside = dist.reshape(x.shape) <= self.dot_radius_mm
        dot, ground = ((self.off_radiance, self.on_radiance) if self.polarity == "dark"
                       else (self.on_radiance, self.off_radiance))
        lit = (np.abs(x - self.centre_mm[0]) <= 0.5 * self.size_mm[0]) & (
            np.abs(y - self.centre_mm[1]) <= 0.5 * self.size_mm[1])
        return np.where(lit, np.where(inside, dot, ground), 0.0)


@dataclass(frozen=True, eq=False)
class ReflectedDots:
    """Where each dot's centre images through the mirror (:meth:`DisplaySetup.reflected_dots`).

    Attributes
    ----------
    row, col : (ny, nx) float
        The exact continuous pixel position of the dot centre's reflection;
        NaN where no point of the facet reflects the dot into the camera.
    points_mm : (ny, nx, 3) float, millimetres
        The mirror point, in the facet frame.
    slopes : (ny, nx, 2) float
        The facet's exact slopes ``(dz/dx, dz/dy)`` there.
    on_facet : (ny, nx) bool
        The dot is reflected (a mirror point on the facet, seen by the camera).
    visible : (ny, nx) bool
        ... and its reflection images inside the camera's frame.
    x_index, y_index : (nx,), (ny,) int
        The display's grid indices.
    """

    row: np.ndarray
    col: np.ndarray
    points_mm: np.ndarray
    slopes: np.ndarray
    on_facet: np.ndarray
    visible: np.ndarray
    x_index: np.ndarray
    y_index: np.ndarray

    def at(self, ix: int, iy: int) -> tuple[float, float]:
        """``(row, col)`` of dot index ``(ix, iy)``'s reflection."""
        i = np.flatnonzero(self.x_index == ix)
        j = np.flatnonzero(self.y_index == iy)
        if not i.size or not j.size:
            raise OptionError(f"the display has no dot of index ({ix}, {iy})", field="index")
        return float(self.row[j[0], i[0]]), float(self.col[j[0], i[0]])


_FACET_METHODS = ("height", "slopes", "normal", "contains", "intersect")


@dataclass(frozen=True, eq=False)
class DisplaySetup:
    """A camera, a dot display and a mirror facet, placed in the camera frame.

    Parameters
    ----------
    display : Display
    camera : shinysim.rig.Camera
        Perspective. Its world frame is the *camera frame* of the poses
        below (a camera from ``camera_from_opencv`` without a pose: its own
        frame).
    screen_rotation : (3, 3) float
    screen_origin_mm : (3,) float, millimetres
        ``x_cam = screen_origin_mm + screen_rotation @ p_screen``: SOFAST's
        ``R(r_cam_screen)^-1`` and ``v_cam_screen_cam`` (in mm).
    facet : shinysim.objects.mirror.MirrorFacet
        (Any object with its ``height``, ``slopes``, ``normal``,
        ``contains`` and ``intersect``.)
    facet_rotation : (3, 3) float
    facet_origin_mm : (3,) float, millimetres
        ``x_cam = facet_rotation @ p_facet + facet_origin_mm``.
    """

    display: Display
    camera: Camera
    screen_rotation: np.ndarray
    screen_origin_mm: np.ndarray
    facet: object
    facet_rotation: np.ndarray
    facet_origin_mm: np.ndarray

    def __post_init__(self):
        if not isinstance(self.display, Display):
            raise OptionError(f"must be a Display, got {type(self.display).__name__}", field="display")
        if not isinstance(self.camera, Camera) or self.camera.projection != "perspective":
            raise OptionError("must be a perspective Camera", field="camera")
        missing = [m for m in _FACET_METHODS if not callable(getattr(self.facet, m, None))]
        if missing:
            raise OptionError(f"must be a mirror facet (a MirrorFacet); {type(self.facet).__name__} has no "
                              f"{', '.join(missing)}", field="facet")
        arrays = {"screen_rotation": _rotation("screen_rotation", self.screen_rotation),
                  "screen_origin_mm": _vec("screen_origin_mm", self.screen_origin_mm),
                  "facet_rotation": _rotation("facet_rotation", self.facet_rotation),
                  "facet_origin_mm": _vec("facet_origin_mm", self.facet_origin_mm)}
        _readonly(*arrays.values())
        for name, value in arrays.items():
            object.__setattr__(self, name, value)

    def rig(self, name: str = "display") -> Rig:
        """The display as the package's :class:`~shinysim.rig.Rig`: one source per shown dot.

        The rig's world frame is the camera frame (the camera at the
        origin, looking along +z); each source is a dot's centre with the
        dot's radius, in raster order of the grid (y index, then x index).
        ``metadata["display"]`` keeps the grid: its shape, the indices of
        every source, the polarity and the radiances, so that a frame's
        sources can be told apart by their place in the grid.

        Returns
        -------
        Rig
        """
        shown = self.display.shown
        jj, ii = np.nonzero(shown)
        pos = self.dots_camera_mm()[jj, ii]
        d = self.display
        meta = {"display": {"shape": list(shown.shape), "x_index": d.x_index[ii].tolist(),
                            "y_index": d.y_index[jj].tolist(), "polarity": d.polarity,
                            "on_radiance": d.on_radiance, "off_radiance": d.off_radiance,
                            "dot_radius_mm": d.dot_radius_mm}}
        return Rig(pos, np.full(len(pos), d.dot_radius_mm), (self.camera,), name=name, metadata=meta)

    # -- frames ------------------------------------------------------------------
    def screen_to_camera(self, points: ArrayLike) -> np.ndarray:
        """(..., 3) screen-frame points in the camera frame."""
        return self.screen_origin_mm + np.asarray(points, dtype=float) @ self.screen_rotation.T

    def facet_to_camera(self, points: ArrayLike) -> np.ndarray:
        """(..., 3) facet-frame points in the camera frame."""
        return self.facet_origin_mm + np.asarray(points, dtype=float) @ self.facet_rotation.T

    def camera_to_facet(self, points: ArrayLike) -> np.ndarray:
        """(..., 3) camera-frame points in the facet frame."""
        return (np.asarray(points, dtype=float) - self.facet_origin_mm) @ self.facet_rotation

    @property
    def camera_centre_facet_mm(self) -> np.ndarray:
        """(3,) the camera's centre of projection in the facet frame."""
        return self.camera_to_facet(self.camera.position)

    @property
    def screen_to_facet(self) -> tuple[np.ndarray, np.ndarray]:
        """``(R, t)`` with ``p_facet = R @ p_screen + t``."""
        R = self.facet_rotation.T @ self.screen_rotation
        return R, self.camera_to_facet(self.screen_origin_mm)

    def dots_camera_mm(self) -> np.ndarray:
        """(ny, nx, 3) the dot centres in the camera frame (NaN where no dot is shown)."""
        return self.screen_to_camera(self.display.dots_mm)

    def dot_position(self, ix: ArrayLike, iy: ArrayLike) -> np.ndarray:
        """(n, 3) the camera-frame centres of the dots of grid indices ``(ix, iy)``; NaN for an index the
        display does not have (the ``dot_position`` of :func:`shinysim.recon.deflect.measure_facet`)."""
        d = self.display
        a = np.asarray(iy, np.int64).ravel() - int(d.y_index[0])
        b = np.asarray(ix, np.int64).ravel() - int(d.x_index[0])
        ok = (a >= 0) & (a < len(d.y_index)) & (b >= 0) & (b < len(d.x_index))
        out = np.full((len(a), 3), np.nan)
        out[ok] = self.dots_camera_mm()[a[ok], b[ok]]
        return out

    def trace_pixels(self, row: ArrayLike, col: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Where the camera rays through pixel positions meet the facet, exactly.

        Parameters
        ----------
        row, col : array_like
            Continuous pixel coordinates (centres at integers).

        Returns
        -------
        points : (..., 3) float, millimetres
            Facet frame; NaN off the facet.
        hit : (...,) bool
        """
        o, d = self.camera.pixel_rays(row, col)
        return self.facet.intersect(self.camera_to_facet(o), d @ self.facet_rotation)

    # -- the exact image of every dot ----------------------------------------------------
    def reflected_dots(self) -> ReflectedDots:
        """The exact pixel where each dot centre's reflection images, with its mirror point and slopes.

        For every dot ``D``: the facet point ``P = (x, y, z(x, y))`` whose
        exact normal bisects the directions to the camera's centre and to
        ``D`` (Newton's method on ``(x, y)`` from the point where the plane
        z = 0 mirrors ``D`` into the camera, with a central-difference
        Jacobian, to 1e-10 mm), then ``P`` projected through the camera
        (lens distortion included). A solution is kept only if it lies on
        the facet, and the camera ray through the returned pixel meets the
        facet at ``P`` and reflects onto ``D`` within
        :data:`REFLECTION_TOLERANCE_MM`.

        Returns
        -------
        ReflectedDots
        """
        disp = self.display
        shape = disp.shown.shape
        C = self.camera_centre_facet_mm
        D = self.camera_to_facet(self.dots_camera_mm()).reshape(-1, 3)
        ok = disp.shown.ravel() & (D[:, 2] > 0) & (C[2] > 0)
        with np.errstate(invalid="ignore", divide="ignore"):
            s = C[2] / (C[2] + D[:, 2])  # the plane's mirror point: on the line from C mirrored to D
            xy = np.column_stack([C[0] + s * (D[:, 0] - C[0]), C[1] + s * (D[:, 1] - C[1])])
        xy[~ok] = np.nan
        h = 1e-3  # mm: the Jacobian's step (the residual is smooth on this scale: its third derivative ~1/L^2)
        converged = np.zeros(len(D), bool)
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            for _ in range(40):
                F = self._bisector_residual(xy, C, D)
                J = np.empty((len(D), 2, 2))
                for k in range(2):
                    e = np.zeros(2)
                    e[k] = h
                    J[:, :, k] = (self._bisector_residual(xy + e, C, D)
                                  - self._bisector_residual(xy - e, C, D)) / (2 * h)
                det = J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]
                step = np.column_stack([(J[:, 1, 1] * F[:, 0] - J[:, 0, 1] * F[:, 1]) / det,
                                        (J[:, 0, 0] * F[:, 1] - J[:, 1, 0] * F[:, 0]) / det])
                xy = xy - step
                size = np.hypot(step[:, 0], step[:, 1])
                converged = size <= 1e-10
                if not np.any(size > 1e-10):
                    break
        on = ok & converged & self.facet.contains(xy[:, 0], xy[:, 1])
        xy[~on] = np.nan
        P = np.column_stack([xy, self.facet.height(xy[:, 0], xy[:, 1])])
        row, col = self.camera.project(self.facet_to_camera(P))
        # the check that makes the answer trustworthy: the ray through the pixel finds P and reflects onto D
        with np.errstate(invalid="ignore"):
            hit_pt, hit = self.trace_pixels(row, col)
            miss = np.linalg.norm(hit_pt - P, axis=-1)
            _, d = self.camera.pixel_rays(row, col)
            d = d @ self.facet_rotation
            n = self.facet.normal(P[:, 0], P[:, 1])
            r = d - 2.0 * np.sum(d * n, axis=-1, keepdims=True) * n
            to_dot = D - P
            off_line = np.linalg.norm(to_dot - np.sum(to_dot * r, -1, keepdims=True) * r, axis=-1)
            good = hit & (miss <= REFLECTION_TOLERANCE_MM) & (off_line <= REFLECTION_TOLERANCE_MM) & (
                np.sum(to_dot * r, -1) > 0)
        on &= good
        P[~on] = np.nan
        row = np.where(on, row, np.nan)
        col = np.where(on, col, np.nan)
        H, W = self.camera.shape
        with np.errstate(invalid="ignore"):
            inside = on & (row >= -0.5) & (row <= H - 0.5) & (col >= -0.5) & (col <= W - 0.5)
        slopes = self.facet.slopes(P[:, 0], P[:, 1])
        out = ReflectedDots(row.reshape(shape), col.reshape(shape), P.reshape(shape + (3,)),
                            slopes.reshape(shape + (2,)), on.reshape(shape), inside.reshape(shape),
                            disp.x_index, disp.y_index)
        _readonly(out.row, out.col, out.points_mm, out.slopes, out.on_facet, out.visible)
        return out

    def _bisector_residual(self, xy, C, D):
        """(n, 2) the bisector's tangential part ``(m_x + p m_z, m_y + q m_z)`` at facet points ``xy``: zero
        where the unit vectors to the camera and to the dot add up along the normal ``(-p, -q, 1)``."""
        P = np.column_stack([xy, self.facet.height(xy[:, 0], xy[:, 1])])
        a = C - P
        b = D - P
        m = a / np.linalg.norm(a, axis=1, keepdims=True) + b / np.linalg.norm(b, axis=1, keepdims=True)
        pq = self.facet.slopes(xy[:, 0], xy[:, 1])
        return np.column_stack([m[:, 0] + pq[:, 0] * m[:, 2], m[:, 1] + pq[:, 1] * m[:, 2]])


def facet_pose(camera_centre_mm: ArrayLike, screen_origin_mm: ArrayLike, facet_centre_mm: ArrayLike,
               camera_right: ArrayLike = (1.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """The pose that faces a facet to the bisector of the camera and the screen.

    Parameters
    ----------
    camera_centre_mm, screen_origin_mm, facet_centre_mm : (3,) array_like, millimetres
        In the camera frame.
    camera_right : (3,) array_like
        The camera's image +col direction (``Camera.right``).

    Returns
    -------
    rotation : (3, 3) ndarray
    origin_mm : (3,) ndarray
        ``x_cam = rotation @ p_facet + origin_mm``: the facet's origin at
        ``facet_centre_mm``, its +z along the bisector of the unit
        directions from there to the camera and to the screen's origin,
        its +x as near ``camera_right`` as that allows, +y = z x x.
    """
    c = _vec("facet_centre_mm", facet_centre_mm)
    to_cam = _vec("camera_centre_mm", camera_centre_mm) - c
    to_screen = _vec("screen_origin_mm", screen_origin_mm) - c
    if not (np.linalg.norm(to_cam) > 0 and np.linalg.norm(to_screen) > 0):
        raise OptionError("the facet's centre coincides with the camera or the screen", field="facet_centre_mm")
    z = to_cam / np.linalg.norm(to_cam) + to_screen / np.linalg.norm(to_screen)
    if not np.linalg.norm(z) > 1e-12:
        raise OptionError("the camera and the screen lie in opposite directions from the facet: no bisector",
                          field="facet_centre_mm")
    z /= np.linalg.norm(z)
    right = _vec("camera_right", camera_right)
    x = right - (right @ z) * z
    if not np.linalg.norm(x) > 1e-9:
        raise OptionError("the bisector is along the camera's +x: the facet's +x is undefined", field="camera_right")
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z]), c


def crop_camera(camera: Camera, row0: float, col0: float, height: int, width: int) -> Camera:
    """The camera of a window of an image: pixel ``(r, c)`` of the window is ``(row0 + r, col0 + c)`` of the whole.

    The same centre, axis, focal length, aspect and lens; the principal
    point shifted by ``(-row0, -col0)`` and the distortion terms rescaled
    to the window's normalisation (shinysim normalises by half the image
    width: ``k1 (w/W)^2``, ``k2 (w/W)^4``, ``k3 (w/W)^6``, ``p (w/W)``).

    Parameters
    ----------
    camera : Camera
    row0, col0 : float
        The window's first row and column in the whole image.
    height, width : int
        The window's size, pixels.

    Returns
    -------
    Camera
        Its rays equal the whole camera's at the shifted pixel positions
        (to rounding).

    Examples
    --------
    >>> cam = Camera("perspective", 400, 300, (0, 0, 0), (0, 0, 1000), (0, -1, 0), 200.0)
    >>> win = crop_camera(cam, 100, 50, 20, 30)
    >>> bool(np.allclose(win.pixel_rays(5, 7)[1], cam.pixel_rays(105, 57)[1], atol=1e-14))
    True
    """
    if not isinstance(camera, Camera):
        raise OptionError(f"must be a Camera, got {type(camera).__name__}", field="camera")
    r0 = _number("row0", row0)
    c0 = _number("col0", col0)
    for name, n in (("height", height), ("width", width)):
        if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, np.integer)) or n < 1:
            raise OptionError(f"must be an integer >= 1 pixels, got {n!r}", field=name)
    s = width / camera.width
    k1, k2, p1, p2, k3 = camera.distortion
    pr, pc = camera.principal_point_px
    return replace(camera, width=int(width), height=int(height), field_width=camera.field_width * s,
                   principal_point=(pr - r0, pc - c0),
                   distortion=(k1 * s**2, k2 * s**4, p1 * s, p2 * s, k3 * s**6))
