"""Large mirrors from a display's dots: pose, ray-surface intersection and slopes.

The paper's rule, that the normal at a highlight bisects the directions to
its source and to the camera, applied to a mirror metres across seen from
metres away (display deflectometry). Where the paper knows the height of its
small object, here the facet's pose comes from its corners in the image and
its surface is found in a loop:

1. :func:`initial_pose`: the facet where the mask's centroid ray is at the
   measured distance from the screen, facing the bisector of camera and
   screen; :func:`facet_corners`: the corners of the facet's image, by lines
   fitted to the mask's edges (in undistorted image coordinates);
   :func:`pose_from_points`: the pose that projects the facet's design
   corners onto them through the distorted camera (a PnP by least squares);
   :func:`scale_to_distance`: the pose moved along its line of sight so the
   measure point is the measured distance from the screen.
2. :func:`solve_slopes`: every identified dot's camera ray meets the current
   surface (first the design plane, then a paraboloid
   ``z = c0 + c1 x + c2 x^2 + c3 y + c4 x y + c5 y^2``), the bisector there
   gives its slopes, a linear fit of the slopes gives the next paraboloid, and
   so on; with ``align="centre"`` each outer loop turns the scene about the
   align point so that the fitted normal there is the design normal and moves
   it so that the measure point is the measured distance from the screen
   (SOFAST's alignment: its slopes carry no absolute tilt).

All lengths in millimetres; frames: the camera frame (OpenCV's: +x image
columns, +y image rows, +z forward) and the facet frame (the facet's design
coordinates, +z its design normal towards the camera); a pose ``(R, t)`` maps
facet to camera, ``x_cam = R x_facet + t``.

numpy + SciPy + scikit-image.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage
from scipy.optimize import least_squares, minimize_scalar

from .._shared import check_choice, check_number, with_overrides
from ..errors import OptionError
from ..rig.opencv import matrix_to_rvec as rotation_vector  # re-exported: the package's one conversion
from ..rig.opencv import rvec_to_matrix as rotation_matrix

__all__ = ["ALIGNMENTS", "EnsembleMeasurement", "FacetMeasurement", "PARTIAL_FRACTION", "PixelMeasurement",
           "SlopeParams", "SlopeSolution", "camera_rays", "facet_corners", "facet_pose_from_image", "initial_pose",
           "measure_ensemble", "measure_facet", "measure_pixels", "pose_from_points", "rotation_matrix",
           "rotation_vector", "scale_to_distance", "solve_slopes"]

#: What fixes the facet's tilt: ``"centre"`` turns the fitted normal at the align point onto the design
#: normal (SOFAST's alignment); ``"none"`` keeps the pose from the corners (uncertain by tens of mrad at 10 m).
ALIGNMENTS = ("centre", "none")


def camera_rays(camera, rows, cols) -> np.ndarray:
    """(n, 3) unit directions, in the camera frame, of pixels' rays.

    ``camera`` is a :class:`~shinysim.rig.Camera` whose world frame is its
    own frame (made by :func:`shinysim.rig.opencv.camera_from_opencv`
    without a pose): position at the origin, looking along +z.
    """
    _, d = camera.pixel_rays(np.asarray(rows, float), np.asarray(cols, float))
    return d


def _project(camera, points_cam):
    r, c = camera.project(points_cam)
    return np.column_stack([r, c])


def initial_pose(camera, mask, screen_origin_mm, distance_mm: float, centroid_mm=(0.0, 0.0, 0.0)):
    """A first facet pose from the mask alone (SOFAST's expected pose).

    Parameters
    ----------
    camera : Camera
        In its own frame (see :func:`camera_rays`).
    mask : (H, W) bool
        The facet's region in the image.
    screen_origin_mm : (3,)
        The screen's origin in the camera frame.
    distance_mm : float
        Measured distance from the facet's centroid to the screen's origin.
    centroid_mm : (3,)
        The centroid in facet coordinates.

    Returns
    -------
    R : (3, 3), t : (3,)
        The facet where the ray through the mask's centroid is
        ``distance_mm`` from the screen's origin, its +z along the bisector
        of the directions to the camera and to the screen, its +x as near the
        camera's +x as that allows.
    """
    mask = np.asarray(mask, bool)
    if not mask.any():
        raise OptionError("the facet's mask is empty: no mirror region in the image")
    rc = ndimage.center_of_mass(mask)
    u = camera_rays(camera, [rc[0]], [rc[1]])[0]
    s0 = np.asarray(screen_origin_mm, float)
    b = float(u @ s0)
    disc = b * b - float(s0 @ s0) + distance_mm ** 2
    if disc < 0:
        raise OptionError(f"no point on the mask centroid's ray is {distance_mm:g} mm from the screen's origin")
    c = (b + np.sqrt(disc)) * u
    to_screen = (s0 - c) / np.linalg.norm(s0 - c)
    z = -u + to_screen
    z /= np.linalg.norm(z)
    x = np.array([1.0, 0.0, 0.0]) - z[0] * z
    x /= np.linalg.norm(x)
    R = np.column_stack([x, np.cross(z, x), z])
    return R, c - R @ np.asarray(centroid_mm, float)


def _line(points, floor):
    """Total-least-squares line (centre, unit direction) of (n, 2) points, trimmed of outliers.

    Points farther from the line than 3 MADs, and than ``floor`` (a pixel: a binary edge's staircase is
    within half a pixel of the true line, and its MAD can be zero), are left out and the line refitted.
    """
    keep = np.ones(len(points), bool)
    for _ in range(5):
        q = points[keep]
        m = q.mean(axis=0)
        d = np.linalg.svd(q - m)[2][0]
        off = np.abs((points - m) @ np.array([-d[1], d[0]]))
        mad = float(np.median(off[keep])) * 1.4826
        new = off <= max(3 * mad, floor)
        if new.sum() < 2 or np.array_equal(new, keep):
            break
        keep = new
    return m, d, float(np.sqrt(np.mean(off[keep] ** 2))), int(keep.sum())


def facet_corners(image, camera, expected_rc, *, level: float = 0.5, keep: float = 0.5, search_px: float = 50.0):
    """The facet's corners in the image, from straight lines fitted to the edges of its image.

    Parameters
    ----------
    image : (H, W) array_like
        The facet bright on a dark surround: a grey image (the frame's
        background, :func:`~shinysim.recon.dots.dot_signal`), whose edge at
        ``level`` is found to a fraction of a pixel, or a mask (a binary
        edge is a staircase: its lines are good to about half a pixel).
    camera : Camera
        In its own frame; the edges are straightened by its lens model
        before the lines are fitted (a straight edge images as a curve).
    expected_rc : (4, 2)
        Expected corners (row, col) in order around the facet (from the
        design corners through :func:`initial_pose`).
    level : float
        The edge's level in ``image`` (midway between facet and surround).
    keep : float
        Fraction of each side, about its middle, whose edge points are
        used (away from the corners' rounding).
    search_px : float
        Edge points farther than this from the expected side are ignored.

    Returns
    -------
    corners_rc : (4, 2)
        Intersections of adjacent fitted sides, pixels.
    side_rms_px : (4,)
        RMS distance of the kept edge points from their line, pixels.
    """
    from skimage import measure

    check_number("keep", keep, lo=0, lo_open=True, hi=1)
    image = np.asarray(image, float)
    contours = measure.find_contours(image, level)
    if not contours:
        raise OptionError(f"the facet's image has no edge at level {level:g}")
    edge = np.concatenate(contours)
    grad = np.stack([ndimage.map_coordinates(g, edge.T, order=1, mode="nearest") for g in np.gradient(image)], -1)
    rays = camera_rays(camera, edge[:, 0], edge[:, 1])
    und = rays[:, :2] / rays[:, 2:]
    exp = np.asarray(expected_rc, float)
    er = camera_rays(camera, exp[:, 0], exp[:, 1])
    ex = er[:, :2] / er[:, 2:]
    scale = float(np.linalg.norm(ex[1] - ex[0]) / max(np.linalg.norm(exp[1] - exp[0]), 1e-9))  # rad per px
    centre = exp.mean(axis=0)
    lines, rms = [], []
    for k in range(4):
        a, b = ex[k], ex[(k + 1) % 4]
        length = float(np.linalg.norm(b - a))
        d = (b - a) / length
        along = (und - a) @ d / length
        perp = np.abs((und - a) @ np.array([-d[1], d[0]]))
        # only edge points where the image brightens towards this facet's inside: a neighbouring facet's
        # edge across a narrow gap faces the other way
        side = exp[(k + 1) % 4] - exp[k]
        inward = np.array([-side[1], side[0]])
        inward *= np.sign(inward @ (centre - exp[k])) or 1.0
        sel = (np.abs(along - 0.5) <= keep / 2) & (perp <= search_px * scale) & (grad @ inward > 0)
        if sel.sum() < 10:
            raise OptionError(f"side {k} of the facet has {int(sel.sum())} edge points near where it is expected; "
                              "is the facet in view and the mask right?")
        m, dirn, r, _ = _line(und[sel], scale)
        lines.append((m, dirn))
        rms.append(r / scale)
    corners = []
    for k in range(4):
        (m1, d1), (m2, d2) = lines[k - 1], lines[k]
        st = np.linalg.solve(np.column_stack([d1, -d2]), m2 - m1)
        corners.append(m1 + st[0] * d1)
    corners = np.asarray(corners)
    return _project(camera, np.column_stack([corners, np.ones(4)])), np.asarray(rms)


def pose_from_points(camera, image_rc, object_mm, R0, t0):
    """The pose that projects object points onto their image points (PnP, by least squares).

    Parameters
    ----------
    camera : Camera
        In its own frame.
    image_rc : (n, 2)
        Observed (row, col), pixels.
    object_mm : (n, 3)
        The points in the object's (facet's) frame.
    R0, t0 :
        Starting pose (facet to camera).

    Returns
    -------
    R : (3, 3), t : (3,), rms_px : float
    """
    img = np.asarray(image_rc, float)
    obj = np.asarray(object_mm, float)
    scale = float(np.linalg.norm(t0))

    def residual(x):
        pts = obj @ rotation_matrix(x[:3]).T + x[3:] * scale
        return (_project(camera, pts) - img).ravel()

    x0 = np.concatenate([rotation_vector(R0), np.asarray(t0, float) / scale])
    out = least_squares(residual, x0, method="lm" if img.size >= 6 else "trf")
    return rotation_matrix(out.x[:3]), out.x[3:] * scale, float(np.sqrt(np.mean(out.fun ** 2)))


def scale_to_distance(R, t, measure_point_mm, screen_origin_mm, distance_mm: float) -> np.ndarray:
    """``t`` scaled along the line of sight so the measure point is ``distance_mm`` from the screen's origin."""
    t = np.asarray(t, float)
    mp = np.asarray(R, float) @ np.asarray(measure_point_mm, float)
    s0 = np.asarray(screen_origin_mm, float)

    def err(s):
        return abs(float(np.linalg.norm(s * t + mp - s0)) - distance_mm)

    return minimize_scalar(err, bracket=(0.9, 1.1)).x * t


@dataclass(frozen=True)
class SlopeParams:
    """Settings of :func:`solve_slopes`.

    Parameters
    ----------
    initial_focal_mm : (fx, fy)
        Focal lengths of the first paraboloid (SOFAST's default 150 m for
        a heliostat facet; the loop forgets it).
    loops : (outer, inner)
        Alignment steps, and surface fits within each (SOFAST's 4 x 3).
    align : {"centre", "none"}
        See :data:`ALIGNMENTS`.
    downsample : int
        The surface is fitted to every ``downsample``-th ray (the final slopes
        are at all of them): SOFAST's ``ParamsSurface.downsample``.
    robust : bool
        Fit the slopes with Tukey's biweight (iteratively reweighted least
        squares, scale from the median absolute deviation of the leverage-
        adjusted residuals, tuning constant 4.685; a ray's weight is the
        smaller of its x and y weights and is carried from fit to fit):
        SOFAST's ``robust_least_squares``.
    """

    initial_focal_mm: tuple[float, float] = (150e3, 150e3)
    loops: tuple[int, int] = (4, 3)
    align: str = "centre"
    downsample: int = 1
    robust: bool = False

    def __post_init__(self):
        check_choice("align", self.align, ALIGNMENTS)
        for f in self.initial_focal_mm:
            check_number("initial_focal_mm", f)
            if f == 0:
                raise OptionError("initial_focal_mm must be non-zero (use a large value for a flat mirror)")
        for n in self.loops:
            check_number("loops", n, lo=1, hi=50, integer=True)
        check_number("downsample", self.downsample, lo=1, hi=1000, integer=True)
        check_choice("robust", self.robust, (True, False))


@dataclass(frozen=True)
class SlopeSolution:
    """Slopes of a facet at its identified dots (:func:`solve_slopes`).

    Attributes
    ----------
    points_mm : (n, 3)
        Where each dot's camera ray meets the fitted surface, facet frame.
    slopes : (n, 2)
        dz/dx, dz/dy there (the bisector rule), facet frame.
    coefs : (6,)
        The fitted paraboloid, ``c0 + c1 x + c2 x^2 + c3 y + c4 x y + c5 y^2``
        (mm).
    focal_lengths_mm : (2,)
        ``1 / (4 c2)``, ``1 / (4 c5)`` (signed as the surface bends; inf for
        a flat fit).
    camera_mm : (3,)
        The camera's centre in the (aligned) facet frame.
    alignment : (3, 3)
        The rotation the alignment applied about the align point (identity
        for ``align="none"``); its angle is the pointing error of the pose
        from the corners, or of the facet.
    """

    points_mm: np.ndarray
    slopes: np.ndarray
    coefs: np.ndarray
    focal_lengths_mm: np.ndarray
    camera_mm: np.ndarray
    alignment: np.ndarray = field(default_factory=lambda: np.eye(3))


def _intersect(coefs, origin, dirs):
    """Where rays from ``origin`` along ``dirs`` first meet the paraboloid ``coefs``."""
    F, D, A, E, C, B = coefs
    q, r, s = dirs[:, 0], dirs[:, 1], dirs[:, 2]
    x0, y0, z0 = origin
    a = A * q * q + B * r * r + C * q * r
    b = 2 * A * x0 * q + 2 * B * y0 * r + C * (x0 * r + y0 * q) + D * q + E * r - s
    c = A * x0 * x0 + B * y0 * y0 + C * x0 * y0 + D * x0 + E * y0 + F - z0
    with np.errstate(invalid="ignore", divide="ignore"):
        # the root nearer the camera, in the form that stays exact as a -> 0 (a plane)
        t = 2 * c / (-b - np.sign(b) * np.sqrt(b * b - 4 * a * c))
    return origin + t[:, None] * dirs


def _bisector_slopes(points, camera, screen):
    to_screen = screen - points
    to_screen /= np.linalg.norm(to_screen, axis=1, keepdims=True)
    to_camera = camera - points
    to_camera /= np.linalg.norm(to_camera, axis=1, keepdims=True)
    n = to_screen + to_camera
    return np.column_stack([-n[:, 0] / n[:, 2], -n[:, 1] / n[:, 2]])


def _biweight(design, values, weights, *, c=4.685, tol=1e-9, max_iter=200):
    """Tukey's biweight fit of ``values`` on ``design`` from starting ``weights``: (coefficients, weights)."""
    w = weights.astype(float).copy()
    previous = None
    coef = np.zeros(design.shape[1])
    for _ in range(max_iter):
        sw = np.sqrt(w)
        coef = np.linalg.lstsq(design * sw[:, None], values * sw, rcond=None)[0]
        res = values - design @ coef
        size = float(np.linalg.norm(res) / len(res))
        if previous is not None and abs(previous - size) < tol:
            break
        previous = size
        # leverage of each point in the weighted fit, to adjust its residual
        q, _ = np.linalg.qr(design * sw[:, None])
        hat = np.clip(np.sum(q * q, axis=1), 0.0, 1.0 - 1e-12)
        adj = res / np.sqrt(1.0 - hat)
        scale = float(np.median(np.abs(adj - np.median(adj)))) / 0.6745
        if scale <= 0:
            break
        u = adj / (c * scale)
        w = np.where(np.abs(u) < 1, (1 - u * u) ** 2, 0.0)
    return coef, w


def _fit(points, slopes, align_point, weights=None):
    """The paraboloid whose slopes fit ``slopes`` (linear in x, y), through ``align_point``; with ``weights``,
    by Tukey's biweight from them (and the new weights)."""
    design = np.column_stack([np.ones(len(points)), points[:, 0], points[:, 1]])
    if weights is None:
        sx = np.linalg.lstsq(design, slopes[:, 0], rcond=None)[0]
        sy = np.linalg.lstsq(design, slopes[:, 1], rcond=None)[0]
    else:
        sx, wx = _biweight(design, slopes[:, 0], weights)
        sy, wy = _biweight(design, slopes[:, 1], weights)
        weights = np.minimum(wx, wy)
    coefs = np.array([0.0, sx[0], sx[1] / 2, sy[0], (sx[2] + sy[1]) / 2, sy[2] / 2])
    x, y, z = align_point
    coefs[0] = z - (coefs[1] * x + coefs[2] * x * x + coefs[3] * y + coefs[4] * x * y + coefs[5] * y * y)
    return coefs, sx, sy, weights


def _turn_onto(a, b):
    """The rotation taking direction ``a`` onto ``b`` about their common normal."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    axis = np.cross(a, b)
    s = float(np.linalg.norm(axis))
    if s < 1e-15:
        return np.eye(3)
    return rotation_matrix(axis / s * np.arctan2(s, float(a @ b)))


def solve_slopes(camera_mm, rays, screen_mm, *, screen_origin_mm, measure_ray, distance_mm: float,
                 align_point_mm=(0.0, 0.0, 0.0), params: SlopeParams | None = None, **kwargs) -> SlopeSolution:
    """Slopes of a mirror from camera rays and the screen points they see (all in the facet frame).

    Parameters
    ----------
    camera_mm : (3,)
        Camera centre.
    rays : (n, 3)
        Unit directions of the identified dots' camera rays.
    screen_mm : (n, 3)
        The screen point (dot centre) each ray sees in the mirror.
    screen_origin_mm : (3,)
        The screen's origin.
    measure_ray : (3,)
        Direction of the camera ray through the measure point.
    distance_mm : float
        Measured distance from the measure point to the screen's origin.
    align_point_mm : (3,)
        Where the design normal is known (the facet's centroid); the design
        surface is taken flat there (normal +z).
    params : SlopeParams, optional

    Returns
    -------
    SlopeSolution
    """
    p = with_overrides(SlopeParams, params, kwargs)
    cam = np.asarray(camera_mm, float).copy()
    u = np.asarray(rays, float).copy()
    scr = np.asarray(screen_mm, float).copy()
    if u.ndim != 2 or u.shape[1] != 3 or scr.shape != u.shape or len(u) < 6:
        raise OptionError(f"solve_slopes needs at least 6 rays and as many screen points, got {u.shape}, {scr.shape}")
    s0 = np.asarray(screen_origin_mm, float).copy()
    mu = np.asarray(measure_ray, float) / np.linalg.norm(measure_ray)
    ap = np.asarray(align_point_mm, float)
    f0 = p.initial_focal_mm
    coefs = np.array([ap[2], 0.0, 1 / (4 * f0[0]), 0.0, 0.0, 1 / (4 * f0[1])])
    total = np.eye(3)
    sub = slice(None, None, p.downsample)
    weights = np.ones(len(u[sub])) if p.robust else None
    for _ in range(p.loops[0]):
        for _ in range(p.loops[1]):
            pts = _intersect(coefs, cam, u[sub])
            coefs, sx, sy, weights = _fit(pts, _bisector_slopes(pts, cam, scr[sub]), ap, weights)
        if p.align == "none":
            continue
        mp = _intersect(coefs, cam, mu[None])[0]
        fitted = np.array([-(sx[0] + sx[1] * ap[0] + sx[2] * ap[1]), -(sy[0] + sy[1] * ap[0] + sy[2] * ap[1]), 1.0])
        turn = _turn_onto(fitted, np.array([0.0, 0.0, 1.0]))
        total = turn @ total
        cam = (cam - ap) @ turn.T + ap
        scr = (scr - ap) @ turn.T + ap
        s0 = (s0 - ap) @ turn.T + ap
        u = u @ turn.T
        mu = turn @ mu
        axis = cam - ap
        s = minimize_scalar(lambda k: abs(float(np.linalg.norm(s0 + axis * (k - 1) - mp)) - distance_mm),
                            bracket=(0.9, 1.1)).x
        shift = axis * (s - 1)
        cam, scr, s0 = cam + shift, scr + shift, s0 + shift
    pts = _intersect(coefs, cam, u)
    slopes = _bisector_slopes(pts, cam, scr)
    with np.errstate(divide="ignore"):
        focal = 1.0 / (4.0 * coefs[[2, 5]])
    return SlopeSolution(points_mm=pts, slopes=slopes, coefs=coefs, focal_lengths_mm=focal, camera_mm=cam,
                         alignment=total)



def _edge_level(background, mask):
    """Midway between the facet's brightness near its edge and the surround's."""
    inner = mask & ~ndimage.binary_erosion(mask, iterations=15) & ndimage.binary_erosion(mask, iterations=5)
    outer = ndimage.binary_dilation(mask, iterations=15) & ~ndimage.binary_dilation(mask, iterations=5)
    if not inner.any() or not outer.any():
        return 0.5 * (float(background[mask].min()) + float(background[mask].max()))
    return 0.5 * (float(np.median(background[inner])) + float(np.median(background[outer])))


@dataclass(frozen=True)
class _PosedFacet:
    """What every facet measurement holds: its region, how it was posed, and its slopes (attributes below)."""

    mask: np.ndarray
    corners_rc: np.ndarray | None
    side_rms_px: np.ndarray | None
    pose_rms_px: float
    rotation: np.ndarray
    translation_mm: np.ndarray
    solution: SlopeSolution


@dataclass(frozen=True)
class FacetMeasurement(_PosedFacet):
    """One facet measured from one frame of a display's dots (:func:`measure_facet`).

    Attributes
    ----------
    dots : HighlightTable
        Every dot detected in the frame (:func:`~shinysim.recon.dots.detect_dots`).
    index : DotIndex
        Their grid indices.
    used : (n_dots,) bool
        Identified, not cut by the facet's edge, on the screen: the dots the
        slopes are computed at (in this order in ``solution``).
    mask : (H, W) bool
        The facet's region.
    corners_rc : (4, 2) or None
        The facet's corners found in the image (None when the pose was given).
    side_rms_px : (4,) or None
        Scatter of the mask's edge points about each fitted side.
    pose_rms_px : float
        Reprojection RMS of the corners under the pose from them (NaN when given).
    rotation, translation_mm :
        The facet's pose (facet to camera) the slopes start from.
    solution : SlopeSolution
    """

    dots: object
    index: object
    used: np.ndarray

    @property
    def counts(self) -> dict:
        """Dots found (complete, on the facet), cut by its edge, identified and left out, by reason."""
        cut = np.asarray(self.dots["cut"], bool)
        return {"dots_detected": len(self.dots), "dots_cut": int(cut.sum()), "dots_found": int((~cut).sum()),
                "dots_identified": int(self.used.sum()), "ambiguous": self.index.n_ambiguous,
                "inconsistent": self.index.n_inconsistent, "unreached": self.index.n_unreached,
                "left_out": int((~cut).sum() - self.used.sum())}


def measure_facet(image, camera, *, dot_position, screen_origin_mm, origin_rc, distance_mm: float,
                  corners_mm=None, centroid_mm=(0.0, 0.0, 0.0), measure_point_mm=(0.0, 0.0, 0.0),
                  origin_index=(0, 0), pose=None, mask=None, dot_params=None, slope_params=None) -> FacetMeasurement:
    """Slopes of one mirror facet from one frame of a display's dots.

    Parameters
    ----------
    image : (H, W) array_like
    camera : Camera
        In its own frame (:func:`camera_rays`).
    dot_position : callable
        ``dot_position(ix, iy) -> (n, 3)``: the dots' centres in the camera
        frame, mm (NaN for an index not on the screen).
    screen_origin_mm : (3,)
        The screen's origin in the camera frame.
    origin_rc : (row, col)
        Where the dot ``origin_index`` images.
    distance_mm : float
        Measured distance from the measure point to the screen's origin.
    corners_mm : (4, 3), optional
        The facet's corners in its frame, in order around it (needed unless
        ``pose`` is given).
    centroid_mm, measure_point_mm : (3,)
        The align point and the measure point, facet frame.
    pose : (R, t), optional
        The facet's pose, if known (a simulation's truth): no corners, no PnP,
        no distance scaling.
    mask : (H, W) bool, optional
        The facet's region (default: :func:`~shinysim.recon.dots.optic_mask`).
    dot_params : DotParams, optional
    slope_params : SlopeParams, optional

    Returns
    -------
    FacetMeasurement
    """
    from .dots import detect_dots, dot_signal, index_dots, optic_mask

    dp = dot_params
    background = dot_signal(image, dp)[1]
    if mask is None:
        mask = optic_mask(background)
    dots = detect_dots(image, dp, mask=mask)
    if len(dots) < 6:
        raise OptionError(f"only {len(dots)} dots were found in the facet's region")
    index = index_dots(dots["row"], dots["col"], origin_rc, origin_index, params=dp)
    screen = np.asarray(dot_position(index.index[:, 0], index.index[:, 1]), float)
    used = index.identified & ~np.asarray(dots["cut"], bool) & np.all(np.isfinite(screen), axis=1)
    s0 = np.asarray(screen_origin_mm, float)
    R, t, corners_rc, side_rms, rms = _pose(pose, background, mask, camera, corners_mm, centroid_mm,
                                            measure_point_mm, s0, distance_mm)
    solution = _solve_facet(camera, dots["row"][used], dots["col"][used], screen[used], R, t, s0, distance_mm,
                            centroid_mm, measure_point_mm, slope_params)
    return FacetMeasurement(dots=dots, index=index, used=used, mask=np.asarray(mask, bool), corners_rc=corners_rc,
                            side_rms_px=side_rms, pose_rms_px=rms, rotation=R, translation_mm=t, solution=solution)


def facet_pose_from_image(image, mask, camera, *, corners_mm, centroid_mm=(0.0, 0.0, 0.0),
                          measure_point_mm=(0.0, 0.0, 0.0), screen_origin_mm, distance_mm: float):
    """A facet's pose from its image: the first pose, the corners, the PnP and the distance (the module's step 1).

    Parameters
    ----------
    image : (H, W) array_like
        The facet bright on a dark surround (a background, or the light minus
        the dark frame); its edge halfway between the two is fitted.
    mask : (H, W) bool
        The facet's region.
    camera, corners_mm, centroid_mm, measure_point_mm, screen_origin_mm, distance_mm :
        As :func:`measure_facet`.

    Returns
    -------
    R : (3, 3), t : (3,)
        Facet to camera.
    corners_rc : (4, 2), side_rms_px : (4,), rms_px : float
        The corners found, their sides' scatter, and the corners' reprojection RMS.
    """
    if corners_mm is None:
        raise OptionError("the facet's pose from its image needs its corners_mm")
    corners_mm = np.asarray(corners_mm, float)
    image = np.asarray(image, float)
    mask = np.asarray(mask, bool)
    s0 = np.asarray(screen_origin_mm, float)
    R0, t0 = initial_pose(camera, mask, s0, distance_mm, centroid_mm)
    expected = _project(camera, corners_mm @ R0.T + t0)
    corners_rc, side_rms = facet_corners(image, camera, expected, level=_edge_level(image, mask))
    R, t, rms = pose_from_points(camera, corners_rc, corners_mm, R0, t0)
    t = scale_to_distance(R, t, measure_point_mm, s0, distance_mm)
    return R, t, corners_rc, side_rms, rms


#: A decoded pixel under this fraction of the facet's median brightness (light minus dark) sees the facet only
#: in part and is left out (:func:`measure_pixels`).
PARTIAL_FRACTION = 0.9


@dataclass(frozen=True)
class PixelMeasurement(_PosedFacet):
    """A facet measured pixel by pixel from a coded display (:func:`measure_pixels`): fringe deflectometry.

    Attributes
    ----------
    rows, cols : (n,) int
        The pixels used, in the order of ``solution``.
    fraction : (n, 2)
        Where each sees the screen, screen fractions (decoded).
    decoding : PhaseDecoding or None
        The whole frame's decoding.
    mask : (H, W) bool
        The facet's region (inside its fitted outline, on the lit mirror).
    corners_rc, side_rms_px, pose_rms_px, rotation, translation_mm, solution :
        As :class:`FacetMeasurement`.
    """

    rows: np.ndarray
    cols: np.ndarray
    fraction: np.ndarray
    decoding: object
    n_partial: int = 0

    @property
    def counts(self) -> dict:
        d = self.decoding
        n_region = int(self.mask.sum())
        out = {"pixels_region": n_region, "pixels_partial": self.n_partial, "pixels_valid": int(len(self.rows))}
        if d is not None:
            out["pixels_low_modulation"] = int((d.low_modulation & self.mask).sum())
            out["pixels_unwrap_inconsistent"] = int((d.unwrap_inconsistent & self.mask).sum())
        return out


def measure_pixels(decoding, edge_image, camera, *, screen_position, screen_origin_mm, distance_mm: float,
                   corners_mm=None, centroid_mm=(0.0, 0.0, 0.0), measure_point_mm=(0.0, 0.0, 0.0), pose=None,
                   mask=None, slope_params=None) -> PixelMeasurement:
    """Slopes of one facet from a decoded display position per pixel (fringe deflectometry).

    Parameters
    ----------
    decoding : PhaseDecoding
        :func:`~shinysim.recon.phase.decode_phase` of the frames.
    edge_image : (H, W) array_like
        The facet bright on a dark surround (the light minus the dark frame):
        its region and, unless ``pose`` is given, its corners.
    camera : Camera
        In its own frame.
    screen_position : callable
        ``screen_position(fraction (n, 2)) -> (n, 3)``: the display point of
        screen fractions in the camera frame, mm (NaN off the measured
        display).
    screen_origin_mm, distance_mm, corners_mm, centroid_mm, measure_point_mm, pose, slope_params :
        As :func:`measure_facet`.
    mask : (H, W) bool, optional
        The lit mirror (default :func:`~shinysim.recon.dots.optic_mask` of ``edge_image``).

    Returns
    -------
    PixelMeasurement
        The pixels used are those inside the facet's fitted outline (or
        the mask, with a given pose), on the mask, at least
        :data:`PARTIAL_FRACTION` of the facet's median brightness in
        ``edge_image`` (a pixel that sees the facet only in part is
        *partial*), validly decoded, and whose screen point
        is on the measured display.
    """
    from .dots import optic_mask

    edge_image = np.asarray(edge_image, float)
    if mask is None:
        mask = optic_mask(edge_image)
    mask = np.asarray(mask, bool)
    s0 = np.asarray(screen_origin_mm, float)
    R, t, corners_rc, side_rms, rms = _pose(pose, edge_image, mask, camera, corners_mm, centroid_mm,
                                            measure_point_mm, s0, distance_mm)
    region = mask if corners_rc is None else mask & _inside_quad(mask.shape, corners_rc)
    # a pixel that sees the facet only in part (its edge, a gap) decodes the mix it sees, off its centre (a
    # pixel 3/4 covered at a 14 mm footprint sits ~2 mm off: ~0.2 mrad at 10 m): one under 90 % of the
    # facet's median brightness is left out (partial); vignetting across a facet is a few per cent
    bright = edge_image >= PARTIAL_FRACTION * float(np.median(edge_image[region])) if region.any() else region
    partial = region & ~bright
    region = region & bright
    use = region & decoding.valid
    rows, cols = np.nonzero(use)
    frac = decoding.fraction[rows, cols]
    screen = np.asarray(screen_position(frac), float)
    ok = np.all(np.isfinite(screen), axis=1)
    rows, cols, frac, screen = rows[ok], cols[ok], frac[ok], screen[ok]
    if len(rows) < 6:
        raise OptionError(f"only {len(rows)} pixels of the facet were decoded; nothing to solve")
    sol = _solve_facet(camera, rows, cols, screen, R, t, s0, distance_mm, centroid_mm, measure_point_mm,
                       slope_params)
    return PixelMeasurement(rows=rows, cols=cols, fraction=frac, decoding=decoding, mask=region,
                            corners_rc=corners_rc, side_rms_px=side_rms, pose_rms_px=rms, rotation=R,
                            translation_mm=t, solution=sol, n_partial=int(partial.sum()))


def _solve_facet(camera, rows, cols, screen_mm, R, t, s0, distance_mm, centroid_mm, measure_point_mm,
                 slope_params):
    """The slope solution of one facet posed at ``(R, t)`` from pixels and the screen points (camera frame) they see."""
    cam_f = -R.T @ t
    rays = camera_rays(camera, rows, cols) @ R
    mp = np.asarray(measure_point_mm, float)
    return solve_slopes(cam_f, rays, (screen_mm - t) @ R, screen_origin_mm=R.T @ (s0 - t), measure_ray=mp - cam_f,
                        distance_mm=distance_mm, align_point_mm=centroid_mm, params=slope_params)


def _pose(pose, image, mask, camera, corners_mm, centroid_mm, measure_point_mm, s0, distance_mm):
    """A given pose, or the pose from the facet's image: ``R, t, corners_rc, side_rms_px, rms_px``."""
    if pose is not None:
        R, t = (np.asarray(v, float) for v in pose)
        return R, t, None, None, float("nan")
    return facet_pose_from_image(image, mask, camera, corners_mm=corners_mm, centroid_mm=centroid_mm,
                                 measure_point_mm=measure_point_mm, screen_origin_mm=s0, distance_mm=distance_mm)


def _inside_quad(shape, corners_rc):
    """(H, W) bool: pixel centres inside the convex quadrilateral ``corners_rc`` (4, 2)."""
    rr, cc = np.mgrid[:shape[0], :shape[1]]
    r, c = corners_rc[:, 0], corners_rc[:, 1]
    side = np.array([(r[(k + 1) % 4] - r[k]) * (cc - c[k]) - (c[(k + 1) % 4] - c[k]) * (rr - r[k])
                     for k in range(4)])
    return np.all(side <= 0, axis=0) | np.all(side >= 0, axis=0)


@dataclass(frozen=True)
class EnsembleMeasurement:
    """Several facets measured from one frame (:func:`measure_ensemble`).

    Attributes
    ----------
    facets : tuple of FacetMeasurement
        Each facet's dots (its own ``used``), region, corners, pose and slopes
        in its own frame.
    rotation, translation_mm :
        The ensemble's pose (ensemble to camera) from all facets' corners.
    pose_rms_px : float
        Reprojection RMS of all the corners.
    pointing_mrad : (n_facets, 2)
        Each facet's fitted centre normal against its design normal, as the
        small angles about the ensemble's y and -x axes (the x and y slope of
        the normal's tilt), less the mean over the facets: the ensemble's own
        tilt is not measured (it rests on the corners), the facets' relative
        pointing is.
    """

    facets: tuple
    rotation: np.ndarray
    translation_mm: np.ndarray
    pose_rms_px: float
    pointing_mrad: np.ndarray


def measure_ensemble(image, camera, *, dot_position, screen_origin_mm, distance_mm: float, corners_mm,
                     centroids_mm, facet_positions_mm, facet_rotations, origins, ensemble_centroid_mm=(0.0, 0.0, 0.0),
                     measure_point_mm=(0.0, 0.0, 0.0), mask=None, dot_params=None,
                     slope_params=None) -> EnsembleMeasurement:
    """Slopes of each facet of an ensemble (a heliostat of several facets) from one frame.

    Parameters
    ----------
    image, camera, dot_position, screen_origin_mm :
        As :func:`measure_facet`.
    distance_mm : float
        Measured distance from ``measure_point_mm`` (ensemble frame) to the
        screen's origin.
    corners_mm : (n, 4, 3)
        Each facet's corners in its own frame, in order around it.
    centroids_mm : (n, 3)
        Each facet's align point (centroid) in its own frame.
    facet_positions_mm : (n, 3)
        Each facet's origin in the ensemble frame.
    facet_rotations : (n, 3, 3)
        Each facet's rotation, facet frame to ensemble frame.
    origins : sequence of ((row, col), (ix, iy))
        For each facet, the image position of one of its dots and that dot's
        index (SOFAST's known points): the lattice walk of each facet starts
        there and stays inside the facet's image.

    Returns
    -------
    EnsembleMeasurement
    """
    from .dots import detect_dots, dot_signal, index_dots, optic_mask

    corners_mm = np.asarray(corners_mm, float)
    n = len(corners_mm)
    pos = np.asarray(facet_positions_mm, float).reshape(n, 3)
    rot = np.asarray(facet_rotations, float).reshape(n, 3, 3)
    cents = np.asarray(centroids_mm, float).reshape(n, 3)
    if len(origins) != n:
        raise OptionError(f"{n} facets need {n} known dots (origins), got {len(origins)}")
    background = dot_signal(image, dot_params)[1]
    if mask is None:
        mask = optic_mask(background)
    level = _edge_level(background, mask)
    ens_corners = np.einsum("fij,fkj->fki", rot, corners_mm) + pos[:, None, :]  # (n, 4, 3), ensemble frame
    s0 = np.asarray(screen_origin_mm, float)
    R, t = initial_pose(camera, mask, s0, distance_mm, ensemble_centroid_mm)
    found = None
    for search in (50.0, 10.0):  # from the rough pose, then from the pose of the first pass
        found = []
        for f in range(n):
            expected = _project(camera, ens_corners[f] @ R.T + t)
            found.append(facet_corners(background, camera, expected, level=level, search_px=search))
        R, t, rms = pose_from_points(camera, np.concatenate([c for c, _ in found]), ens_corners.reshape(-1, 3), R, t)
    t = scale_to_distance(R, t, measure_point_mm, s0, distance_mm)
    dots = detect_dots(image, dot_params, mask=mask)
    facets = []
    normals = []
    for f in range(n):
        region = _inside_quad(mask.shape, found[f][0]) & mask
        (orow, ocol), oindex = origins[f]
        index = index_dots(dots["row"], dots["col"], (orow, ocol), oindex, region=region, params=dot_params)
        screen = np.asarray(dot_position(index.index[:, 0], index.index[:, 1]), float)
        r = np.clip(np.round(dots["row"]).astype(int), 0, mask.shape[0] - 1)
        c = np.clip(np.round(dots["col"]).astype(int), 0, mask.shape[1] - 1)
        used = index.identified & ~np.asarray(dots["cut"], bool) & np.all(np.isfinite(screen), axis=1) & region[r, c]
        Rf = R @ rot[f]
        tf = t + R @ pos[f]
        dist_f = float(np.linalg.norm(Rf @ cents[f] + tf - s0))
        sol = _solve_facet(camera, dots["row"][used], dots["col"][used], screen[used], Rf, tf, s0, dist_f, cents[f],
                           cents[f], slope_params)
        facets.append(FacetMeasurement(dots=dots, index=index, used=used, mask=region, corners_rc=found[f][0],
                                       side_rms_px=found[f][1], pose_rms_px=rms, rotation=Rf, translation_mm=tf,
                                       solution=sol))
        normals.append(rot[f] @ (sol.alignment.T @ np.array([0.0, 0.0, 1.0])))  # fitted normal, ensemble frame
    design = rot @ np.array([0.0, 0.0, 1.0])
    normals = np.asarray(normals)
    # tilt of each fitted normal from its design normal, in the ensemble's x and y
    tilt = np.column_stack([normals[:, 0] / normals[:, 2] - design[:, 0] / design[:, 2],
                            normals[:, 1] / normals[:, 2] - design[:, 1] / design[:, 2]])
    pointing = 1e3 * (tilt - tilt.mean(axis=0))
    return EnsembleMeasurement(facets=tuple(facets), rotation=R, translation_mm=t, pose_rms_px=rms,
                               pointing_mrad=pointing)
