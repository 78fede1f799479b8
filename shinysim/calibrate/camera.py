"""Camera calibration from images of the hole plate: detection, the solve, its uncertainty.

:func:`find_holes` finds the holes' image points in one image (through
:mod:`shinysim.recon.detect`, matched to the layout by the nominal camera);
:func:`calibrate_camera` solves for the parameter groups asked by least
squares on the reprojection error, from one or more placements of a plate
(:mod:`shinysim.objects.plate`), with the covariance of the result;
:func:`ray_errors` says how far a calibrated camera's rays are from the true
ones and :func:`camera_parameters` puts any camera in the solve's parameters.
numpy, scipy and scikit-image; never a renderer. How it works, and what a
plate on one plane cannot tell: ``docs/calibration.md``, section "The camera
from the hole plate".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage, optimize
from scipy.spatial.distance import pdist

from .._shared import json_safe
from ..conventions import angle_between
from ..errors import CalibrationError, RigError, did_you_mean
from ..objects.plate import HolePlate, PlatePlacement
from ..recon.detect import find_regions
from ..rig import Camera, Rig

__all__ = [
    "ESTIMATE_GROUPS",
    "PARAMETER_NAMES",
    "BLOB_AREA_RANGE",
    "SPECK_FRACTION",
    "DEGENERATE_RATIO",
    "IMPLAUSIBLE_ROTATION_MRAD",
    "find_holes",
    "CameraCalibration",
    "calibrate_camera",
    "camera_parameters",
    "ray_errors",
]

#: The parameter groups :func:`calibrate_camera` can estimate, and their parameters.
ESTIMATE_GROUPS = {
    "pose": ("position_x_mm", "position_y_mm", "position_z_mm", "rotation_x_mrad", "rotation_y_mrad",
             "rotation_z_mrad"),
    "focal": ("field_scale",),
    "principal_point": ("principal_row_px", "principal_col_px"),
    "distortion": ("k1", "k2"),
}
#: Every camera parameter, in the order of the covariance matrix.
PARAMETER_NAMES = tuple(n for group in ESTIMATE_GROUPS.values() for n in group)

_I = {n: i for i, n in enumerate(PARAMETER_NAMES)}
#: Rotation parameters are in milliradians.
_MRAD = 1e-3


# -- the camera model, written for the solver ------------------------------------------------------


def _rotate(omega, v):
    """Rodrigues' rotation of the vectors ``v`` (m, 3) by rotation vectors ``omega`` (..., 3): (..., m, 3).

    Written with analytic functions of ``omega`` only (no ``abs``, no
    conjugate), so that it accepts complex ``omega`` for complex-step
    derivatives.
    """
    t = np.sum(omega * omega, axis=-1)[..., None, None]
    if np.max(np.abs(t)) < 1e-4:  # series: its error is below 1e-22 relative for |omega| < 10 mrad
        sinc = 1 - t / 6 + t**2 / 120 - t**3 / 5040 + t**4 / 362880
        cosc = 0.5 - t / 24 + t**2 / 720 - t**3 / 40320 + t**4 / 3628800
    else:
        theta = np.sqrt(t + 0j) if np.iscomplexobj(t) else np.sqrt(t)
        sinc = np.sin(theta) / theta
        cosc = (1 - np.cos(theta)) / t
    om = omega[..., None, :]
    along = np.sum(v * om, axis=-1, keepdims=True)
    return v * (1 - t * cosc) + np.cross(om, v) * sinc + along * om * cosc


@dataclass(frozen=True)
class _Model:
    """The nominal camera and which parameters are free: maps a parameter vector to pixels and cameras."""

    nominal: Camera
    free: tuple[int, ...]
    #: The full parameter vector whose free parameters a solve varies (default: :meth:`start`).
    base: np.ndarray | None = None

    @property
    def names(self):
        return [PARAMETER_NAMES[i] for i in self.free]

    def start(self):
        """The full parameter vector of the nominal camera."""
        c = self.nominal
        pr, pc = c.principal_point_px
        return np.array([*c.position, 0.0, 0.0, 0.0, 1.0, pr, pc, *c.distortion[:2]])

    def full(self, x_free):
        x = (self.start() if self.base is None else self.base).astype(np.result_type(x_free, float))
        x[list(self.free)] = x_free
        return x

    def project(self, x, points):
        """(..., n, 2) (row, col) of world points (n, 3) for full parameter vectors ``x`` (..., 11), real or complex."""
        c = self.nominal
        x = x[..., None, :]  # against the points' axis
        frame = _rotate(x[..., 0, 3:6] * _MRAD, np.stack([c.right, c.down, c.forward]))
        rel = points - x[..., 0:3]
        a, b, z = (np.sum(rel * frame[..., k:k + 1, :], axis=-1) for k in range(3))
        scale = 2.0 / (c.field_width * x[..., 6])
        if c.projection == "perspective":
            scale = scale * c.distance / z
        u, v = a * scale, b * scale
        r2 = u * u + v * v
        g = 1.0 + x[..., 9] * r2 + x[..., 10] * r2 * r2
        _, _, p1, p2, k3 = c.distortion  # not estimated: the nominal camera's, held
        if k3 != 0.0:
            g = g + k3 * r2 * r2 * r2
        ud, vd = u * g, v * g
        if p1 != 0.0 or p2 != 0.0:
            ud = ud + 2.0 * p1 * u * v + p2 * (r2 + 2.0 * u * u)
            vd = vd + p1 * (r2 + 2.0 * v * v) + 2.0 * p2 * u * v
        half = 0.5 * c.width
        return np.stack([vd * (half * c.aspect) + x[..., 7], ud * half + x[..., 8]], axis=-1)

    def residuals(self, x_free, points, observed):
        return (self.project(self.full(x_free), points) - observed).ravel()

    def jacobian_full(self, x, points):
        """Derivatives of the image points by every parameter of the full vector ``x``, by complex steps.

        A complex step (``Im f(x + ih) / h``) has no subtraction and so no
        rounding loss: the derivatives are exact to the last digits, which
        the covariance of nearly degenerate parameters needs. All steps are
        taken at once, one per row of a batch.
        """
        h = 1e-30
        steps = np.asarray(x, dtype=complex) + 1j * h * np.eye(len(x))
        return (self.project(steps, points).imag / h).reshape(len(x), -1).T

    def jacobian(self, x_free, points):
        """Derivatives of the residuals by the free parameters."""
        return self.jacobian_full(self.full(x_free), points)[:, list(self.free)]

    def camera(self, x):
        """The Camera of the full parameter vector ``x``."""
        c = self.nominal
        omega = np.asarray(x[3:6], float) * _MRAD
        forward, up = _rotate(omega, np.stack([c.forward, c.up]))
        position = np.asarray(x[0:3], float)
        pp = (float(x[7]), float(x[8]))
        return Camera(c.projection, c.width, c.height, position, position + c.distance * forward, up,
                      c.field_width * float(x[6]), c.name, principal_point=pp,
                      distortion=(float(x[9]), float(x[10]), *c.distortion[2:]), aspect=c.aspect)


def camera_parameters(camera: Camera, nominal: Camera) -> dict[str, float]:
    """Every parameter of :data:`PARAMETER_NAMES` of ``camera``, measured from ``nominal``.

    The inverse of the parametrisation :func:`calibrate_camera` fits: the
    position (mm), the rotation (rotation vector about world x, y, z,
    milliradians) that takes the nominal camera's frame into ``camera``'s,
    the field scale (the ratio of angular pixel sizes, ``field_width /
    distance``, for perspective cameras; of ``field_width`` for orthographic
    ones), the principal point (px) and the distortion. An orthographic
    camera's position is first slid along its axis to the nominal one's
    height (along the world axis nearest the nominal axis): the rays stay,
    and the solve holds that coordinate. Use it to compare a calibration
    with a known true camera.
    """
    if camera.projection != nominal.projection or camera.shape != nominal.shape:
        raise CalibrationError(f"camera is {camera.projection} {camera.width}x{camera.height}, the nominal one "
                               f"{nominal.projection} {nominal.width}x{nominal.height}", field="camera")
    m0 = np.stack([nominal.right, nominal.down, nominal.forward])
    m1 = np.stack([camera.right, camera.down, camera.forward])
    r = m1.T @ m0  # r @ m0[k] = m1[k]
    axis = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])  # 2 sin(angle) * unit axis
    angle = math.atan2(0.5 * np.linalg.norm(axis), 0.5 * (np.trace(r) - 1.0))
    omega = 0.5 * axis / (math.sin(angle) / angle if angle > 0 else 1.0)
    if camera.projection == "perspective":
        scale = (camera.field_width / camera.distance) / (nominal.field_width / nominal.distance)
    else:
        scale = camera.field_width / nominal.field_width
    position = camera.position
    if camera.projection == "orthographic":  # the position along the axis is a gauge: put it where the solve holds it
        axis = int(np.argmax(np.abs(nominal.forward)))
        position = position + (nominal.position[axis] - position[axis]) / camera.forward[axis] * camera.forward
    pr, pc = camera.principal_point_px
    values = [*position, *(omega / _MRAD), scale, pr, pc, *camera.distortion[:2]]
    return dict(zip(PARAMETER_NAMES, map(float, values)))


# -- hole detection ----------------------------------------------------------------------------------

#: A blob's area may be this many times smaller or larger than a hole's image
#: before it is refused. Thresholding halfway keeps a blurred disk's area, and
#: a hole 10 % wider than drawn has 1.21 times its area; two holes that touch
#: cover 1.5 to 2 times it.
BLOB_AREA_RANGE = (0.5, 1.5)
#: Blobs smaller than this fraction of a hole's image are noise specks, dropped.
SPECK_FRACTION = 0.1
#: Pixels around a blob that weight its centre (the blurred edge below the threshold).
_EDGE_PX = 2
#: The ring around a blob whose median is its local dark level: (from, to) pixels out.
_RING_PX = (4, 8)


def _expected_holes(plate, placement, camera):
    """Nominal image points (n, 2), image areas (n,) and the least image spacing of the holes, pixels."""
    world = placement.world_holes(plate)
    rows, cols = camera.project(world)
    points = np.column_stack([rows, cols])
    r = 0.5 * plate.hole_diameter
    areas = np.empty(plate.n_holes)
    for j, (x, y) in enumerate(plate.holes_xy):
        ends = placement.to_world([[x + r, y, 0.0], [x - r, y, 0.0], [x, y + r, 0.0], [x, y - r, 0.0]])
        er, ec = camera.project(ends)
        jx = np.array([er[0] - er[1], ec[0] - ec[1]]) / (2 * r)
        jy = np.array([er[2] - er[3], ec[2] - ec[3]]) / (2 * r)
        areas[j] = math.pi * r * r * abs(jx[0] * jy[1] - jx[1] * jy[0])
    return points, areas, float(np.min(pdist(points), initial=np.inf))


def _check_image(image, camera, name):
    img = np.asarray(image)
    if img.ndim != 2:
        raise CalibrationError(f"must be a 2-D (H, W) image, got shape {img.shape}", field=name)
    if not (np.issubdtype(img.dtype, np.floating) or np.issubdtype(img.dtype, np.integer)) or img.dtype == bool:
        raise CalibrationError(f"pixels must be numbers, got {img.dtype}", field=name)
    if img.shape != camera.shape:
        raise CalibrationError(f"is {img.shape[1]}x{img.shape[0]} pixels, the camera's image {camera.width}x"
                               f"{camera.height}", field=name)
    bad = int(np.count_nonzero(~np.isfinite(img)))
    if bad:
        raise CalibrationError(f"{bad} NaN or inf pixel(s)", field=name)
    return img


def find_holes(image, plate: HolePlate, placement: PlatePlacement, camera: Camera, *, name: str = "image",
               threshold: float | None = None, saturation: float | None = None) -> np.ndarray:
    """The image points of a backlit plate's holes: bright blobs on a dark plate, to a fraction of a pixel.

    The paper's procedure (Section IV: binarize, "connectivity", the COG of
    each blob, one-to-one correspondence by the known layout), in steps:

    1. Levels: the dark level is the image's median (the plate covers most
       of the image), the bright level the brightest pixel after a 3 x 3
       median filter (no single hot pixel); the threshold is halfway.
    2. Blobs: connected regions above it (:func:`~shinysim.recon.detect.find_regions`,
       8-connected). Regions under :data:`SPECK_FRACTION` of a hole's
       expected image are noise and dropped; the others must be within
       :data:`BLOB_AREA_RANGE` of it.
    3. Centres: the intensity-weighted centre of gravity of each blob and
       the pixels within 2 pixels of it (its blurred edge), weighted by the
       intensity above the blob's local dark level (the median of a ring 4
       to 8 pixels around it), clipped at 0.
    4. Matching: the nominal ``camera`` projects the holes of ``plate`` at
       ``placement``; after removing the blobs' common shift from those
       points (their mean shift, refined by the median offset of each blob
       from its nearest hole, so that one stray blob does not move it),
       each blob is given the nearest hole, which must be nearer than half
       the least image spacing of two holes, and each hole gets one blob.

    Parameters
    ----------
    image : (H, W) array_like
        Linear intensities, the camera's size.
    plate, placement : HolePlate, PlatePlacement
        What was imaged, and where.
    camera : Camera
        The nominal camera (for the matching and the expected blob size).
    name : str
        Names the image in error messages.
    threshold : float, optional
        An absolute threshold instead of the halfway level.
    saturation : float, optional
        The clip level; default the maximum of an integer image's type (255
        for 8 bits), none for a float image.

    Returns
    -------
    (n, 2) ndarray
        Sub-pixel (row, col) of each hole, in ``plate.holes_xy`` order.

    Raises
    ------
    CalibrationError
        Naming ``name``: not an image of the camera's size, NaN pixels; a
        hole the nominal camera puts outside the frame; no holes found; a
        blob cut by the image border, or too small or too large for a hole;
        a count that differs from the layout's; a saturated blob; a blob
        that matches no hole (how far off), or two blobs for one hole.
    """
    if not isinstance(plate, HolePlate) or not isinstance(placement, PlatePlacement) or not isinstance(camera, Camera):
        raise CalibrationError("needs a HolePlate, a PlatePlacement and a Camera", field=name)
    img = _check_image(image, camera, name)
    if saturation is None and np.issubdtype(img.dtype, np.integer):
        saturation = float(np.iinfo(img.dtype).max)
    img = img.astype(np.float64)
    expected, areas, spacing = _expected_holes(plate, placement, camera)
    if not np.all(np.isfinite(expected)):
        raise CalibrationError("the nominal camera does not see every hole (some are behind it)", field=name)
    outside = np.flatnonzero((expected[:, 0] < -0.5) | (expected[:, 0] > camera.height - 0.5)
                             | (expected[:, 1] < -0.5) | (expected[:, 1] > camera.width - 0.5))
    if outside.size:
        raise CalibrationError(f"hole(s) {', '.join(map(str, outside))} of {plate.name!r} image outside the frame "
                               f"(nominally at {_pts(expected[outside])}); move the plate into the field", field=name)
    dark = float(np.median(img))
    bright = float(np.max(ndimage.median_filter(img, size=3, mode="nearest")))
    if threshold is None:
        if not bright > dark:
            raise CalibrationError(f"no holes found: the image is flat (dark level {dark:.4g}, brightest {bright:.4g})",
                                   field=name)
        level = 0.5 * (dark + bright)
    else:
        if isinstance(threshold, bool) or not isinstance(threshold, (int, float, np.integer, np.floating)) \
                or not math.isfinite(threshold):
            raise CalibrationError(f"threshold must be a finite number, got {threshold!r}", field=name)
        level = float(threshold)
    found = find_regions(img >= level, connectivity=2)
    labels = found.label_image()
    typical = float(np.median(areas))
    regions = np.flatnonzero(found.area >= max(2.0, SPECK_FRACTION * float(np.min(areas))))
    if not len(regions):
        raise CalibrationError(f"no holes found: no blob of a hole's size (about {typical:.0f} px) above the "
                               f"threshold {level:.4g} (dark level {dark:.4g}, bright {bright:.4g})", field=name)
    bbox, centroid, area = found.bbox(), found.centroid(), found.area
    for i in regions:
        r0, c0, r1, c1 = bbox[i]
        if r0 == 0 or c0 == 0 or r1 == img.shape[0] or c1 == img.shape[1]:
            raise CalibrationError(f"the blob at ({centroid[i, 0]:.1f}, {centroid[i, 1]:.1f}) touches the image "
                                   "border: a hole cut by the frame has a biased centre; move the plate into the field",
                                   field=name)
    lo, hi = BLOB_AREA_RANGE
    for i in regions:
        if not lo * np.min(areas) <= area[i] <= hi * np.max(areas):
            what = "small" if area[i] < lo * np.min(areas) else "large"
            raise CalibrationError(
                f"the blob at ({centroid[i, 0]:.1f}, {centroid[i, 1]:.1f}) covers {area[i]:.0f} px, too {what} for a "
                f"{plate.hole_diameter:.4g} mm hole (about {typical:.0f} px here; {lo:g}x to {hi:g}x accepted)"
                + (": holes merged, or glare" if what == "large" else ": a partly covered hole, or noise"), field=name)
    if len(regions) != plate.n_holes:
        raise CalibrationError(f"found {len(regions)} blob(s), the layout {plate.name!r} has {plate.n_holes} holes",
                               field=name)
    if saturation is not None:
        clipped = found.sum(found.values(img) >= saturation)
        for i in regions:
            if clipped[i]:
                raise CalibrationError(
                    f"saturated: the blob at ({centroid[i, 0]:.1f}, {centroid[i, 1]:.1f}) has {clipped[i]} pixel(s) "
                    f"at the clip level {saturation:g}, which biases its centre; lower the exposure or the backlight",
                    field=name)
    centres = np.array([_centre(img, labels, bbox[i], found.label[i], centroid[i], dark) for i in regions])
    # the blobs' common shift from the nominal image (a camera a little off): their mean shift, then made robust
    # to a stray blob by the median offset from each blob's nearest hole
    shift = centres.mean(axis=0) - expected.mean(axis=0)
    for _ in range(3):
        offsets = centres[:, None, :] - shift - expected[None, :, :]
        nearest = np.argmin(np.linalg.norm(offsets, axis=-1), axis=1)
        shift = shift + np.median(offsets[np.arange(len(centres)), nearest], axis=0)
    gaps = np.linalg.norm(centres[:, None, :] - shift - expected[None, :, :], axis=-1)
    nearest = np.argmin(gaps, axis=1)
    radius = 0.5 * spacing
    note = f" (after the blobs' common shift of ({shift[0]:.1f}, {shift[1]:.1f}) px from the nominal camera's image)"
    for i, j in enumerate(nearest):
        if gaps[i, j] > radius:
            raise CalibrationError(
                f"blob {i} at ({centres[i, 0]:.1f}, {centres[i, 1]:.1f}) does not match any hole: it is "
                f"{gaps[i, j]:.1f} px from the nearest (hole {j}), more than half the holes' spacing "
                f"({radius:.1f} px){note}; check the layout, the placement and the nominal camera", field=name)
    counts = np.bincount(nearest, minlength=plate.n_holes)
    if np.any(counts > 1):
        j = int(np.argmax(counts))
        both = np.flatnonzero(nearest == j)
        raise CalibrationError(f"blobs {', '.join(map(str, both))} all match hole {j}{note}; check the layout, the "
                               "placement and the nominal camera", field=name)
    out = np.empty((plate.n_holes, 2))
    out[nearest] = centres
    return out


def _pts(points):
    return ", ".join(f"({r:.0f}, {c:.0f})" for r, c in points)


def _centre(img, labels, bbox, label, centroid, dark):
    """Intensity-weighted centre of a blob (``label`` in ``labels``) and its blurred edge, above its local dark level."""
    r0, c0, r1, c1 = (int(v) for v in bbox)
    pad = _RING_PX[1] + 1
    r0, c0 = max(r0 - pad, 0), max(c0 - pad, 0)
    r1, c1 = min(r1 + pad, img.shape[0]), min(c1 + pad, img.shape[1])
    window = img[r0:r1, c0:c1]
    lab = labels[r0:r1, c0:c1]
    blob = lab == label
    square = np.ones((3, 3), bool)
    edge = ndimage.binary_dilation(blob, square, iterations=_EDGE_PX)
    others = ndimage.binary_dilation((lab > 0) & ~blob, square, iterations=_RING_PX[0])
    ring = (ndimage.binary_dilation(blob, square, iterations=_RING_PX[1])
            & ~ndimage.binary_dilation(blob, square, iterations=_RING_PX[0]) & ~others)
    local = float(np.median(window[ring])) if np.count_nonzero(ring) >= 8 else dark
    weights = np.where(edge, np.clip(window - local, 0.0, None), 0.0)
    total = weights.sum()
    rows, cols = np.mgrid[r0:r1, c0:c1]
    if not total > 0:  # pragma: no cover - a blob above the threshold is above its dark level
        return np.array(centroid)
    return np.array([np.sum(weights * rows) / total, np.sum(weights * cols) / total])


# -- the solve ---------------------------------------------------------------------------------------

#: A parameter combination is degenerate when the smallest singular value of the
#: Jacobian with unit columns is below this fraction of the largest.
DEGENERATE_RATIO = 1e-6

#: A fitted camera turned further than this from the nominal one (mrad, about
#: any axis; 50 mrad is 2.9 degrees) is refused as a wrong input, not taken as
#: a calibration: a rig is not built that far from its design, and at the
#: SHINY field (0.9 degrees) a camera turned even 16 mrad sees none of the
#: object it was aimed at.
IMPLAUSIBLE_ROTATION_MRAD = 50.0


def _check_observations(observations, who):
    if isinstance(observations, (str, bytes, dict)) or not hasattr(observations, "__len__"):
        raise CalibrationError("observations must be a list of (plate, placement, points) tuples, one per image",
                               field=who)
    if len(observations) == 0:
        raise CalibrationError("no observations: give one (plate, placement, points) tuple per image", field=who)
    world, image = [], []
    for i, item in enumerate(observations):
        where = f"{who} observations[{i}]"
        if not isinstance(item, (tuple, list)) or len(item) != 3:
            raise CalibrationError("must be a (plate, placement, points) tuple", field=where)
        plate, placement, points = item
        if not isinstance(plate, HolePlate):
            raise CalibrationError(f"plate must be a HolePlate, got {type(plate).__name__}", field=where)
        if not isinstance(placement, PlatePlacement):
            raise CalibrationError(f"placement must be a PlatePlacement, got {type(placement).__name__}", field=where)
        try:
            pts = np.asarray(points, dtype=float)
            got = f"shape {pts.shape}"
        except (TypeError, ValueError):
            pts, got = np.zeros((0, 0)), "no array of numbers"
        if pts.shape != (plate.n_holes, 2):
            raise CalibrationError(f"points must be ({plate.n_holes}, 2) (row, col), one per hole of the plate, "
                                   f"got {got}", field=where)
        if not np.all(np.isfinite(pts)):
            raise CalibrationError("points must be finite", field=where)
        world.append(placement.world_holes(plate))
        image.append(pts)
    return np.concatenate(world), np.concatenate(image)


def _check_estimate(estimate, who):
    if isinstance(estimate, str):
        estimate = (estimate,)
    try:
        groups = tuple(dict.fromkeys(estimate))
    except TypeError:
        raise CalibrationError(f"estimate must be a list of group names from {', '.join(map(repr, ESTIMATE_GROUPS))}; "
                               f"got {estimate!r}", field=who) from None
    if not groups:
        raise CalibrationError("estimate names no parameter group; choose from "
                               f"{', '.join(map(repr, ESTIMATE_GROUPS))}", field=who)
    for g in groups:
        if g not in ESTIMATE_GROUPS:
            raise CalibrationError(f"unknown parameter group {g!r}{did_you_mean(str(g), ESTIMATE_GROUPS)} in estimate; "
                                   f"choose from {', '.join(map(repr, ESTIMATE_GROUPS))}", field=who)
    return tuple(g for g in ESTIMATE_GROUPS if g in groups)


def _free_parameters(groups, nominal):
    names = [n for g in groups for n in ESTIMATE_GROUPS[g]]
    if nominal.projection == "orthographic" and "pose" in groups:
        axis = "xyz"[int(np.argmax(np.abs(nominal.forward)))]
        names.remove(f"position_{axis}_mm")
    return tuple(_I[n] for n in names)


def _degeneracy(jac, names):
    """None, or (a sentence naming the parameters that trade against each other, their names)."""
    norms = np.linalg.norm(jac, axis=0)
    if np.any(~np.isfinite(norms)):
        return "the model gives no finite image position for some holes (are they behind the camera?)", []
    dead = [n for n, v in zip(names, norms) if v == 0]
    if dead:
        return f"{', '.join(dead)} move(s) no hole image", dead
    _, s, vt = np.linalg.svd(jac / norms, full_matrices=False)
    if s[-1] < DEGENERATE_RATIO * s[0]:
        v = vt[-1]
        order = np.argsort(-np.abs(v))
        involved = [names[k] for k in order if abs(v[k]) >= 0.1 * np.max(np.abs(v))]
        words = ", ".join(involved[:-1]) + (" and " if len(involved) > 1 else "") + involved[-1]
        return f"{words} trade against each other (relative singular value {s[-1] / s[0]:.1e})", involved
    return None


_FIX = ("add a placement at another height (the plate raised on spacers of known height) or tilted by a known "
        "amount")


def _remedy(involved):
    """What would separate the parameters that trade against each other."""
    if {"k1", "k2"} & set(involved):
        return ("the holes image at too few distances from the image centre to tell the radial distortion from the "
                "focal length (a centred seven-hole plate images at two); shift the plate sideways by known amounts "
                "so that its holes cover the field, or use a dot grid (dot_grid())")
    if "field_scale" in involved and any(n.startswith("position_") for n in involved):
        return ("holes on one plane facing the camera do not tell its distance from its focal length; " + _FIX)
    if any(n.startswith("principal_") for n in involved):
        return "the principal point trades against a rotation of the camera; " + _FIX
    return _FIX


@dataclass
class CameraCalibration:
    """A camera calibrated from hole-plate images (:func:`calibrate_camera`).

    Attributes
    ----------
    camera : Camera
        The calibrated camera (the nominal one's size, projection and name).
    parameters : dict of str to float
        Every parameter of :data:`PARAMETER_NAMES`; those not in ``names``
        are held at the nominal camera's values.
    sigma : dict of str to float
        One standard deviation of each estimated parameter (``names``).
    covariance : (k, k) ndarray
        Covariance of the estimated parameters, in the order of ``names``.
    names : list of str
        The estimated parameters.
    rms_px, max_px : float
        Root-mean-square and largest length of the reprojection residuals.
    residuals_px : (n_points, 2) ndarray
        Observed minus modelled (row, col) of every hole image, pixels.
    pixel_sigma : float
        The per-coordinate image noise the covariance assumes, pixels.
    pixel_sigma_source : {"residuals", "given"}
    n_placements, n_points : int
    estimate : tuple of str
        The parameter groups estimated.
    residual_sigma : float
        The noise the residuals show, ``sqrt(sum r^2 / (n - k))`` (NaN
        without spare residuals); equal to ``pixel_sigma`` unless that was
        given.
    """

    camera: Camera
    parameters: dict[str, float]
    sigma: dict[str, float]
    covariance: np.ndarray
    names: list[str]
    rms_px: float
    max_px: float
    residuals_px: np.ndarray
    pixel_sigma: float
    pixel_sigma_source: str
    n_placements: int
    n_points: int
    estimate: tuple[str, ...] = ()
    residual_sigma: float = math.nan

    @property
    def correlation(self) -> np.ndarray:
        """(k, k) correlation matrix of the estimated parameters."""
        sd = np.sqrt(np.diag(self.covariance))
        with np.errstate(invalid="ignore", divide="ignore"):
            return self.covariance / np.outer(sd, sd)

    def strongly_correlated(self, limit: float = 0.99) -> list[tuple[str, str, float]]:
        """Pairs of estimated parameters whose correlation exceeds ``limit`` in size, strongest first."""
        corr = self.correlation
        pairs = [(self.names[i], self.names[j], float(corr[i, j]))
                 for i in range(len(self.names)) for j in range(i + 1, len(self.names)) if abs(corr[i, j]) > limit]
        return sorted(pairs, key=lambda p: -abs(p[2]))

    def to_metadata(self) -> dict:
        """A JSON-safe summary: method, estimated names, values, sigmas, residual statistics."""
        return json_safe({
            "method": "hole plate: reprojection least squares (" + ", ".join(self.estimate) + ")",
            "estimate": list(self.estimate),
            "estimated": list(self.names),
            "values": {n: self.parameters[n] for n in self.names},
            "sigma": dict(self.sigma),
            "fixed": {n: v for n, v in self.parameters.items() if n not in self.names},
            "strongly_correlated": [list(p) for p in self.strongly_correlated()],
            "rms_px": self.rms_px,
            "max_px": self.max_px,
            "pixel_sigma": self.pixel_sigma,
            "pixel_sigma_source": self.pixel_sigma_source,
            "residual_sigma": self.residual_sigma,
            "n_placements": self.n_placements,
            "n_points": self.n_points,
        })

    def apply(self, rig: Rig, index: int = 0) -> Rig:
        """``rig`` with camera ``index`` replaced by the calibrated one and the calibration in its metadata.

        The summary (:meth:`to_metadata`) goes to ``metadata["calibration"]["camera"]``
        (``"camera[i]"`` for camera ``i > 0``); the rest of the metadata is kept.
        """
        if not isinstance(rig, Rig):
            raise CalibrationError(f"must be a Rig, got {type(rig).__name__}", field="rig")
        if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or not 0 <= index < len(rig.cameras):
            raise CalibrationError(f"the rig has cameras 0..{len(rig.cameras) - 1}, got {index!r}", field="index")
        old = rig.cameras[index]
        if old.shape != self.camera.shape or old.projection != self.camera.projection:
            raise CalibrationError(f"the rig's camera {index} is {old.projection} {old.width}x{old.height}, the "
                                   f"calibrated one {self.camera.projection} {self.camera.width}x{self.camera.height}",
                                   field="index")
        out = rig.with_camera(self.camera, int(index))
        key = "camera" if index == 0 else f"camera[{index}]"
        out.metadata["calibration"] = {**(out.metadata.get("calibration") or {}), key: self.to_metadata()}
        return out


def calibrate_camera(observations, nominal: Camera, *, estimate=("pose", "focal"), pixel_sigma: float | None = None,
                     name: str | None = None) -> CameraCalibration:
    """Fit a camera to the image points of known holes, by least squares on the reprojection error.

    Parameters
    ----------
    observations : list of (HolePlate, PlatePlacement, (n, 2) array_like)
        One tuple per image: the plate, where it was, and the (row, col) of
        its holes in plate order (:func:`find_holes`).
    nominal : Camera
        The starting point and the reference of the parameters; its size,
        projection, name, target distance, aspect and distortion terms
        ``p1, p2, k3`` are kept.
    estimate : sequence of str
        Parameter groups of :data:`ESTIMATE_GROUPS`: ``"pose"`` (position,
        3 translations in mm; rotation, 3 small angles about world x, y, z
        through the camera's centre, mrad), ``"focal"`` (``field_scale``:
        the angular pixel size over the nominal one), ``"principal_point"``
        (row, col, px) and ``"distortion"`` (k1, k2). The paper's method is
        ``("pose", "focal")``. An orthographic camera's position along its
        axis (the world axis nearest it) moves no ray and is never estimated.
    pixel_sigma : float, optional
        The image points' noise per coordinate, pixels. Given, it scales
        the covariance; otherwise the residuals do (with ``n - k`` degrees
        of freedom), which needs more residuals than parameters.
    name : str, optional
        Names the calibration in error messages.

    Returns
    -------
    CameraCalibration

    Raises
    ------
    CalibrationError
        Malformed observations or groups; fewer residuals than parameters;
        the principal point with the pose from holes on one plane; a
        degenerate geometry (parameters that trade against each other, named
        with the placement that would separate them); no noise estimate
        (no spare residuals and no ``pixel_sigma``); a solve that fails.

    Examples
    --------
    A camera built 1 mm higher and 0.3 mm, -0.2 mm off its design, with a
    1 % wider field, found again from the exact images of the paper's plate
    on the reference plane and raised 0.5 mm:

    >>> import dataclasses
    >>> import numpy as np
    >>> from shinysim.objects.plate import PlatePlacement, shiny_plate
    >>> from shinysim.rig import shiny_1988
    >>> nominal = shiny_1988(resolution=128).camera
    >>> built = dataclasses.replace(nominal, position=nominal.position + [0.3, -0.2, 1.0],
    ...                             field_width=1.01 * nominal.field_width)
    >>> plate = shiny_plate()
    >>> observations = []
    >>> for placement in (PlatePlacement(), PlatePlacement(offset=(0, 0, 0.5))):
    ...     row, col = built.project(placement.world_holes(plate))
    ...     observations.append((plate, placement, np.column_stack([row, col])))
    >>> cal = calibrate_camera(observations, nominal, pixel_sigma=0.05)
    >>> np.round(cal.camera.position - nominal.position, 6).tolist()
    [0.3, -0.2, 1.0]
    >>> bool(np.abs(cal.residuals_px).max() < 1e-9)
    True
    """
    who = name or "calibrate_camera"
    if not isinstance(nominal, Camera):
        raise CalibrationError(f"nominal must be a Camera, got {type(nominal).__name__}", field=who)
    groups = _check_estimate(estimate, who)
    world, image = _check_observations(observations, who)
    if pixel_sigma is not None:
        if isinstance(pixel_sigma, bool) or not isinstance(pixel_sigma, (int, float, np.integer, np.floating)) \
                or not (math.isfinite(pixel_sigma) and pixel_sigma > 0):
            raise CalibrationError(f"pixel_sigma must be a finite number of pixels > 0, got {pixel_sigma!r}",
                                   field=who)
    model = _Model(nominal, _free_parameters(groups, nominal))
    names = model.names
    n_obs, n_par = image.size, len(names)
    n_pl = len(observations)
    what = f"estimate={groups!r} ({n_par} parameters)"
    if n_obs < n_par:
        raise CalibrationError(f"{len(image)} hole image(s) in {n_pl} placement(s) give {n_obs} numbers, fewer than "
                               f"the {n_par} parameters of {what}; add placements or holes", field=who)
    if nominal.projection == "orthographic" and "pose" in groups and "principal_point" in groups:
        raise CalibrationError(f"{what}: an orthographic camera's principal point is the same as a sideways shift of "
                               "the camera (every ray moves alike); estimate the pose or the principal point, not "
                               "both", field=who)
    centred = world - world.mean(axis=0)
    flat = np.linalg.svd(centred, compute_uv=False)[-1] <= 1e-9 * max(1.0, float(np.abs(centred).max()))
    if flat and "pose" in groups and "principal_point" in groups:
        why = ("a plane's image fixes 8 numbers, the pose, focal length and principal point are 9" if "focal" in groups
               else "only second-order perspective tells them apart at a narrow field")
        raise CalibrationError(
            f"{what} needs holes on two or more planes: with every hole on one plane the principal point trades "
            f"against a rotation of the camera ({why}); {_FIX}", field=who)
    x0 = model.start()[list(model.free)]
    problem = _degeneracy(model.jacobian(x0, world), names)
    if problem is None:
        x, ok = _solve(model, world, image)
        if not ok:
            raise CalibrationError(f"the least-squares solve of {what} did not converge; check the nominal camera and "
                                   "the placements", field=who)
        jac = model.jacobian(x, world)
        problem = _degeneracy(jac, names)
    if problem is not None:
        raise CalibrationError(f"degenerate geometry for {what}: {problem[0]}: {_remedy(problem[1])}, or estimate "
                               "fewer groups", field=who)
    res = model.residuals(x, world, image).reshape(-1, 2)
    dof = n_obs - n_par
    residual_sigma = float(np.sqrt(np.sum(res**2) / dof)) if dof > 0 else math.nan
    if pixel_sigma is not None:
        sigma, source = float(pixel_sigma), "given"
    elif dof > 0:
        sigma, source = residual_sigma, "residuals"
    else:
        raise CalibrationError(f"{what} from {len(image)} hole images leaves no residual to estimate the image noise "
                               "from; give pixel_sigma or add placements", field=who)
    _, s, vt = np.linalg.svd(jac, full_matrices=False)
    cov = sigma**2 * (vt.T / s**2) @ vt
    full = model.full(x)
    try:
        camera = model.camera(full)
    except RigError as exc:
        spread = ", ".join(f"sigma({n}) = {np.sqrt(cov[k, k]):.2g}" for k, n in enumerate(names) if n in ("k1", "k2"))
        raise CalibrationError(f"the fitted camera is not valid ({exc}): the placements barely determine it"
                               + (f" ({spread}): {_remedy(['k1'])}" if spread else f": {_FIX}"), field=who) from None
    # a fit can absorb a wrong input exactly: holes matched to the wrong holes of a symmetric layout, or a
    # placement that is not where it was said to be. No built rig is that far from its design: refuse it.
    params = dict(zip(PARAMETER_NAMES, map(float, full)))
    turn = max(abs(params[f"rotation_{a}_mrad"]) for a in "xyz")
    pr, pc = camera.principal_point_px
    if turn > IMPLAUSIBLE_ROTATION_MRAD or not (0 <= pr <= camera.height - 1 and 0 <= pc <= camera.width - 1):
        raise CalibrationError(
            f"the fitted camera is implausible (turned {turn:.0f} mrad from the nominal one, principal point at "
            f"row {pr:.0f}, col {pc:.0f}): check the placements (each image's plate where it is said to be, "
            "with the stated rotation) and the layout; a symmetric layout turned by more than half its symmetry "
            "matches the wrong holes", field=who)
    lengths = np.hypot(res[:, 0], res[:, 1])
    return CameraCalibration(
        camera=camera,
        parameters=params,
        sigma={n: float(np.sqrt(cov[k, k])) for k, n in enumerate(names)},
        covariance=cov,
        names=list(names),
        rms_px=float(np.sqrt(np.mean(lengths**2))),
        max_px=float(lengths.max()),
        residuals_px=-res,
        pixel_sigma=sigma,
        pixel_sigma_source=source,
        n_placements=n_pl,
        n_points=len(image),
        estimate=groups,
        residual_sigma=residual_sigma,
    )


def _solve(model, world, image):
    """Least squares from the nominal camera: the principal point held first, then everything; Gauss-Newton last.

    The principal point trades almost exactly against a rotation of the
    camera (only the distortion's centre and second-order perspective tell
    them apart), and the cost has secondary minima along that valley, far
    from the truth (a principal point hundreds of pixels off, found by a
    plain Levenberg-Marquardt solve from the nominal camera in about half of
    the noisy synthetic cases). Holding it at its nominal value first lets
    the rotation take up the image shift; the second solve then starts in
    the right valley (no failures in 100 noisy cases).
    """
    x = model.start()
    stages = [model.free]
    held = {_I["principal_row_px"], _I["principal_col_px"]}
    if held <= set(model.free) and len(model.free) > len(held):
        stages.insert(0, tuple(i for i in model.free if i not in held))
    status = 0
    for free in stages:
        stage = _Model(model.nominal, free, x)

        def fun(p):
            r = stage.residuals(p, world, image)
            return np.where(np.isfinite(r), r, 1e6)  # a hole behind the camera: a step the solver rejects

        try:
            sol = optimize.least_squares(fun, x[list(free)], jac=lambda p: stage.jacobian(p, world), method="lm",
                                         x_scale="jac", xtol=1e-15, ftol=1e-15, gtol=1e-15,
                                         max_nfev=200 * (len(free) + 1))
        except (ValueError, np.linalg.LinAlgError):
            return x[list(model.free)], False
        x = stage.full(sol.x)
        status = sol.status
    p = x[list(model.free)]
    cost = float(np.sum(model.residuals(p, world, image) ** 2))
    for _ in range(5):  # Gauss-Newton to the last digits (the solver stops a little short in flat valleys)
        step = np.linalg.lstsq(model.jacobian(p, world), -model.residuals(p, world, image), rcond=None)[0]
        trial = p + step
        trial_cost = float(np.sum(model.residuals(trial, world, image) ** 2))
        if not trial_cost < cost:
            break
        p, cost = trial, trial_cost
    ok = bool(np.all(np.isfinite(p))) and math.isfinite(cost)
    return p, ok and status > 0


# -- how good is it ----------------------------------------------------------------------------------


def ray_errors(calibrated, true: Camera, rows, cols, heights=(-1.0, 0.0, 1.0)) -> dict:
    """How far a calibrated camera's pixel rays are from the true camera's.

    Parameters
    ----------
    calibrated : Camera or CameraCalibration
    true : Camera
        Of the same size.
    rows, cols : array_like
        Pixel coordinates: two 1-D arrays span the grid of all their
        combinations; arrays of any other shape are broadcast together.
    heights : sequence of float, millimetres
        The planes ``z = h`` where the rays are compared.

    Returns
    -------
    dict
        ``position_max_um`` / ``position_rms_um``: the distance between
        where the two rays of a pixel meet each plane, over all pixels and
        planes (and ``..._by_height``, one per plane); ``angle_max_deg`` /
        ``angle_rms_deg``: the angle between the two rays' directions;
        ``n_rays``, ``heights_mm``.
    """
    cam = calibrated.camera if isinstance(calibrated, CameraCalibration) else calibrated
    if not isinstance(cam, Camera) or not isinstance(true, Camera):
        raise CalibrationError("calibrated and true must be Cameras (or a CameraCalibration)", field="ray_errors")
    if cam.shape != true.shape:
        raise CalibrationError(f"the cameras differ in size: {cam.width}x{cam.height} and {true.width}x{true.height}",
                               field="ray_errors")
    rows, cols = np.asarray(rows, float), np.asarray(cols, float)
    if rows.ndim == 1 and cols.ndim == 1:
        rows, cols = np.meshgrid(rows, cols, indexing="ij")
    rows, cols = (a.ravel() for a in np.broadcast_arrays(rows, cols))
    heights = [float(h) for h in np.atleast_1d(np.asarray(heights, float))]
    by_height = [1e3 * np.linalg.norm(cam.backproject_to_plane(rows, cols, h)
                                      - true.backproject_to_plane(rows, cols, h), axis=-1) for h in heights]
    d = np.concatenate(by_height)
    a = np.degrees(angle_between(cam.pixel_rays(rows, cols)[1], true.pixel_rays(rows, cols)[1]))
    return {
        "heights_mm": heights,
        "n_rays": int(rows.size),
        "position_max_um": float(np.max(d)),
        "position_rms_um": float(np.sqrt(np.mean(d**2))),
        "position_max_um_by_height": [float(np.max(e)) for e in by_height],
        "position_rms_um_by_height": [float(np.sqrt(np.mean(e**2))) for e in by_height],
        "angle_max_deg": float(np.max(a)),
        "angle_rms_deg": float(np.sqrt(np.mean(a**2))),
    }
