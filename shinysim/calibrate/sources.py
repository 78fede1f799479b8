"""Source calibration from mirror spheres.

A mirror-like sphere of known radius, scanned at one or more known places,
calibrates the sources: the camera ray through each highlight's centre of
gravity, reflected at the sphere, passes through its source.
:func:`reflected_rays` (pixel ray to sphere point, normal and reflected
direction), :func:`distant_directions` (the same as distant light
directions), :func:`observe_sphere` (one highlight per source frame) and
:func:`calibrate_sources` (each source's position or direction, its
uncertainty and its radius). numpy + scipy (+ the package's reconstruction
detection); never a renderer. How it works (the fit, finite sources, the
uncertainty, the fiber radius): ``docs/calibration.md``, section "The fibers
from a mirror sphere".
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from scipy import ndimage, optimize, sparse

from .._shared import check_number, json_safe, with_overrides
from ..conventions import normalize
from ..errors import CalibrationError, OptionError
from ..io import Stack, source_channel
from ..io.table import HighlightTable
from ..objects.sphere import SpherePlacement
from ..recon.detect import (
    DetectParams,
    estimate_noise,
    hot_pixel_k,
    hot_pixel_mask,
    replace_hot_pixels,
)
from ..recon.pipeline import detect_stack
from ..rig import Camera, Rig
from ..rig.core import _vec3
from ..theory.mirror import mirror_sphere_highlight

__all__ = [
    "SpherePlacement",
    "SphereObservation",
    "SourceCalibration",
    "SOLVED_KINDS",
    "SOURCE_RADIUS_MODELS",
    "OBSERVE_THRESHOLD",
    "reflected_rays",
    "distant_directions",
    "observe_sphere",
    "calibrate_sources",
]

#: What was solved for each source: its 3-D position; its direction with the
#: distance held (near source, too few or degenerate placements); its
#: direction at infinity (distant source); nothing (no placement saw it).
SOLVED_KINDS = ("position", "direction", "distant", "none")

#: Default relative detection threshold of :func:`observe_sphere` (the noise
#: floor of detection still applies).
OBSERVE_THRESHOLD = 0.05
#: A distant source is placed this many sphere radii away (parallax 1e-12 rad).
_FAR = 1e12
#: Second moments of a box pixel, px^2.
_PIXEL_MOMENT = 1.0 / 12.0
#: Relative finite-difference steps (central differences: truncation ~1e-10,
#: rounding ~1e-8 of a derivative).
_STEP_REL = 1e-5
_STEP_RAD = 1e-5
#: Points on a finite source's silhouette whose highlights outline its image
#: (the polygon's centroid is exact for the linear part of the mirror map).
_BOUNDARY_POINTS = 64
#: Samples per pixel side when a small highlight is rendered into box pixels
#: (each weighted by its signed distance to the edge: the centre of gravity
#: then to about 5e-4 px, and continuous in the highlight's position).
_SUBPIXELS = 12
#: Highlights whose semi-axis is at least this many pixels have no pixel-locking correction.
_PIXEL_LOCKING_PX = 16.0
#: Rounds of the finite-source model (offsets, refit) and the change that ends them.
_FINITE_ROUNDS = 3
_OFFSET_SETTLED_PX = 1e-4
#: What ``source_radius`` of :func:`calibrate_sources` may name.
SOURCE_RADIUS_MODELS = ("nominal", "estimated")


def _error(name, message, field=None):
    return CalibrationError(message, path=name, field=field)


def _tangent_basis(u):
    """Two unit vectors perpendicular to the unit vector(s) ``u`` (..., 3) and to each other."""
    u = np.asarray(u, dtype=float)
    a = np.where((np.abs(u[..., 0]) < 0.9)[..., None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    e1 = normalize(a - np.sum(a * u, axis=-1, keepdims=True) * u)
    return e1, np.cross(u, e1)


# -- data ----------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class SphereObservation:
    """The highlights of one sphere placement, one per source at most.

    Parameters
    ----------
    placement : SpherePlacement
    rows, cols : (n,) float
        Centre of gravity of each highlight, continuous pixel coordinates.
    sources : (n,) int
        The source (frame) index of each highlight; each at most once.
    moments : (n, 3) float or None
        Intensity-weighted central second moments ``(rr, rc, cc)`` of each
        highlight, px^2 (NaN rows where not measured), or None.
    threshold : float
        The relative detection threshold (fraction of each highlight's peak)
        below which pixels were left out of the centres of gravity; used by
        the finite-source model of :func:`calibrate_sources` (0: none, or
        unknown).
    """

    placement: SpherePlacement
    rows: np.ndarray
    cols: np.ndarray
    sources: np.ndarray
    moments: np.ndarray | None = None
    threshold: float = 0.0

    def __post_init__(self):
        if not isinstance(self.placement, SpherePlacement):
            raise CalibrationError(f"must be a SpherePlacement, got {type(self.placement).__name__}",
                                   field="placement")
        try:
            rows = np.array(self.rows, dtype=float).reshape(-1)
            cols = np.array(self.cols, dtype=float).reshape(-1)
            sources = np.array(self.sources).reshape(-1)
        except (TypeError, ValueError) as exc:
            raise CalibrationError(f"rows, cols and sources must be numbers: {exc}") from None
        if not (rows.shape == cols.shape == sources.shape):
            raise CalibrationError(f"rows, cols and sources differ in length ({rows.size}, {cols.size}, "
                                   f"{sources.size})")
        if not (np.all(np.isfinite(rows)) and np.all(np.isfinite(cols))):
            raise CalibrationError("rows and cols must be finite (leave unseen sources out)")
        if sources.size and not (np.issubdtype(sources.dtype, np.integer)
                                 or (np.issubdtype(sources.dtype, np.floating) and np.all(np.isfinite(sources))
                                     and np.all(sources == np.round(sources)))):
            raise CalibrationError(f"must be integer source indices, got {sources[:5]!r}", field="sources")
        sources = sources.astype(np.int64)
        if np.any(sources < 0):
            raise CalibrationError(f"source index {int(sources.min())} is negative", field="sources")
        values, counts = np.unique(sources, return_counts=True)
        if np.any(counts > 1):
            raise CalibrationError(f"source {int(values[counts > 1][0])} appears {int(counts.max())} times; "
                                   "one highlight per source and placement", field="sources")
        moments = self.moments
        if moments is not None:
            try:
                moments = np.array(moments, dtype=float)
            except (TypeError, ValueError):
                raise CalibrationError("must be an (n, 3) array of numbers", field="moments") from None
            if moments.shape != (rows.size, 3):
                raise CalibrationError(f"must have shape ({rows.size}, 3), got {moments.shape}", field="moments")
        t = self.threshold
        if isinstance(t, (bool, np.bool_)) or not isinstance(t, (int, float, np.integer, np.floating)) \
                or not 0 <= t < 1:
            raise CalibrationError(f"must be a relative threshold in [0, 1), got {t!r}", field="threshold")
        object.__setattr__(self, "threshold", float(t))
        for key, arr in (("rows", rows), ("cols", cols), ("sources", sources), ("moments", moments)):
            if arr is not None:
                arr.flags.writeable = False
            object.__setattr__(self, key, arr)

    def __len__(self):
        return int(self.sources.size)

    @classmethod
    def from_table(cls, placement: SpherePlacement, table: HighlightTable, moments=None, *,
                   threshold: float = 0.0) -> SphereObservation:
        """The observation of a :class:`~shinysim.io.table.HighlightTable`'s highlights (its ``row``, ``col`` and
        ``source`` columns; one highlight per source) of the sphere at ``placement``."""
        if not isinstance(table, HighlightTable):
            raise CalibrationError(f"must be a HighlightTable, got {type(table).__name__}", field="table")
        return cls(placement, table["row"], table["col"], table["source"], moments, threshold=threshold)


@dataclass
class SourceCalibration:
    """Calibrated sources: positions or directions, uncertainties, radii.

    Attributes
    ----------
    positions : (n, 3) ndarray, mm
        NaN rows for sources with too few (or degenerate) placements for 3-D.
    directions : (n, 3) ndarray
        Unit directions from ``reference_point`` towards each source (the
        direction itself for a distant source); NaN for unseen sources.
    reference_point : (3,) ndarray, mm
    position_cov : (n, 3, 3) ndarray, mm^2
        NaN where the position is not solved.
    direction_sigma_deg : (n,) ndarray
        ``sqrt(trace(direction_cov))`` in degrees: the RMS angle between
        estimated and true direction.
    radius_mm, radius_sigma_mm : (n,) ndarray
        Fiber radius from the highlights' second moments and its standard
        error (NaN without moments; sigma NaN with one observation).
    n_observations : (n,) int ndarray
        Placements that saw each source.
    rms_residual_px : (n,) ndarray
        RMS image distance between observed and refitted highlights.
    pixel_sigma : float
        Pixel noise used for the covariances.
    pixel_sigma_source : {"residuals", "given"}
    direction_cov : (n, 3, 3) ndarray
        Covariance of the unit direction (rank 2, radians^2).
    solved : (n,) str ndarray
        One of :data:`SOLVED_KINDS` per source.
    dof : int
        Spare degrees of freedom of the fit (residuals minus parameters).
    pixel_sigma_residuals : float
        The pooled residual estimate (NaN without spare degrees of freedom).
    centroid_model : str
        ``"point"``, or ``"finite (nominal radii)"``, ``"finite (estimated
        radii)"``, ``"finite (given radii)"``: what a centre of gravity was
        taken to be (``source_radius`` of :func:`calibrate_sources`).
    notes : list of str
        Fallbacks taken (a degenerate set fitted as a direction, ...).
    """

    positions: np.ndarray
    directions: np.ndarray
    reference_point: np.ndarray
    position_cov: np.ndarray
    direction_sigma_deg: np.ndarray
    radius_mm: np.ndarray
    radius_sigma_mm: np.ndarray
    n_observations: np.ndarray
    rms_residual_px: np.ndarray
    pixel_sigma: float
    pixel_sigma_source: str
    direction_cov: np.ndarray | None = None
    solved: np.ndarray | None = None
    dof: int = 0
    pixel_sigma_residuals: float = float("nan")
    centroid_model: str = "point"
    notes: list = field(default_factory=list)

    @property
    def n_sources(self) -> int:
        return int(self.positions.shape[0])

    def to_metadata(self) -> dict:
        """JSON-safe summary: the method, the noise used and per-source estimates with sigmas."""
        sources = []
        for i in range(self.n_sources):
            kind = str(self.solved[i]) if self.solved is not None else "position"
            entry = {"index": i, "solved": kind, "n_observations": int(self.n_observations[i])}
            if kind == "position":
                entry["position_mm"] = self.positions[i]
                entry["position_sigma_mm"] = np.sqrt(np.diag(self.position_cov[i]))
            entry["direction"] = self.directions[i]
            for key in ("direction_sigma_deg", "radius_mm", "radius_sigma_mm", "rms_residual_px"):
                entry[key] = getattr(self, key)[i]
            sources.append(entry)
        return json_safe({
            "method": "mirror-sphere source calibration: reflected-ray intersection, then least squares on "
                      "the reprojection error (pixels) of the exact highlights; covariance sigma^2 (J^T J)^-1; "
                      "fiber radius from the highlights' second moments",
            "reference_point_mm": self.reference_point,
            "pixel_sigma_px": self.pixel_sigma,
            "pixel_sigma_source": self.pixel_sigma_source,
            "pixel_sigma_residuals_px": self.pixel_sigma_residuals,
            "dof": int(self.dof),
            "centroid_model": self.centroid_model,
            "notes": list(self.notes),
            "sources": sources,
        })

    def apply(self, rig: Rig) -> Rig:
        """The rig with calibrated sources.

        Position-solved sources get their position; direction-solved near
        sources keep their distance from ``reference_point`` along the new
        direction; distant sources get the new direction; radii are replaced
        where estimated; unseen sources are unchanged.
        ``metadata["calibration"]["sources"]`` holds :meth:`to_metadata`.

        Raises
        ------
        CalibrationError
            The rig has a different number of sources.
        """
        if not isinstance(rig, Rig):
            raise TypeError(f"rig must be a shinysim Rig, got {type(rig).__name__}")
        if rig.n_sources != self.n_sources:
            raise CalibrationError(f"the rig has {rig.n_sources} sources but the calibration {self.n_sources}",
                                   field="sources")
        pos = rig.source_positions.copy()
        radii = rig.source_radii.copy()
        ref = np.asarray(self.reference_point, float)
        for i in range(self.n_sources):
            kind = str(self.solved[i]) if self.solved is not None else "position"
            if kind == "none" or not np.all(np.isfinite(self.directions[i])):
                continue
            if rig.source_distant[i]:
                pos[i] = self.directions[i]
                continue
            if kind == "position":
                pos[i] = self.positions[i]
            else:
                pos[i] = ref + np.linalg.norm(rig.source_positions[i] - ref) * self.directions[i]
            if np.isfinite(self.radius_mm[i]):
                radii[i] = self.radius_mm[i]
        metadata = dict(rig.metadata)
        metadata["calibration"] = {**(metadata.get("calibration") or {}), "sources": self.to_metadata()}
        return replace(rig, source_positions=pos, source_radii=radii, metadata=metadata)


# -- geometry ------------------------------------------------------------------------


def reflected_rays(rows, cols, camera: Camera, center, radius):
    """Pixel rays reflected at a mirror sphere (exact).

    The ray of ``camera`` through each continuous pixel coordinate meets the
    sphere (nearest hit in front of a perspective camera; the nearer hit of
    an orthographic camera's line) and is reflected by the mirror law.

    Parameters
    ----------
    rows, cols : array_like
        Continuous image coordinates (pixel centres at integers).
    camera : shinysim.rig.Camera
    center : (3,) array_like, millimetres
    radius : float, millimetres

    Returns
    -------
    points, normals, directions : (..., 3) ndarray
        Sphere points, their unit normals, and unit reflected directions
        (from the point towards the source). NaN where a ray misses the
        sphere.
    """
    center = _vec3(center, "center", CalibrationError)
    radius = check_number("radius", radius, lo=0, lo_open=True)
    origins, d = camera.pixel_rays(rows, cols)
    rel = origins - center
    b = np.sum(rel * d, axis=-1)
    perp = rel - b[..., None] * d
    disc = radius * radius - np.sum(perp * perp, axis=-1)
    hit = disc >= 0
    t = -b - np.sqrt(np.where(hit, disc, 0.0))
    if camera.projection == "perspective":
        hit &= t > 0
    points = origins + t[..., None] * d
    normals = normalize(points - center)
    directions = normalize(d - 2.0 * np.sum(normals * d, axis=-1)[..., None] * normals)
    nan = np.where(hit, 1.0, np.nan)[..., None]
    return points * nan, normals * nan, directions * nan


def distant_directions(rows, cols, camera: Camera, center, radius):
    """Light directions from highlights on a mirror sphere, each light at infinity.

    The reflected ray of :func:`reflected_rays`. For an orthographic camera
    the direction is the same whatever the light's distance (the sphere at
    any depth along the camera's rays gives it), and it is the mirror law
    ``l = 2 (n . v) n - v`` of
    :func:`~shinysim.recon.sphere.lights_from_highlights`; for a perspective
    camera it is the direction at the highlight point.

    Returns
    -------
    (..., 3) ndarray of unit vectors, NaN where a ray misses the sphere.
    """
    return reflected_rays(rows, cols, camera, center, radius)[2]


def _highlights(sources, centers, radii, camera, distant=False):
    """Exact highlight points of sources on spheres and their image coordinates.

    ``sources`` (N, 3) are positions, or unit directions where ``distant`` (N,);
    ``centers`` (N, 3) and ``radii`` (N,) the sphere of each. Solved in each
    sphere's frame scaled to unit radius, all in one call.

    Returns
    -------
    points : (N, 3) ndarray
    rc : (N, 2) ndarray, (row, col)
    """
    S = np.asarray(sources, float).reshape(-1, 3)
    O = np.asarray(centers, float).reshape(-1, 3)
    r = np.asarray(radii, float).reshape(-1, 1)
    if S.shape[0] == 0:
        return np.zeros((0, 3)), np.zeros((0, 2))
    rel = np.where(np.asarray(distant, bool).reshape(-1, 1), _FAR * S, (S - O) / r)
    with np.errstate(invalid="ignore", divide="ignore"):
        view = ({"camera_position": (camera.position - O) / r} if camera.projection == "perspective"
                else {"view_direction": -camera.forward})
        _, normal = mirror_sphere_highlight(rel, center=np.zeros(3), radius=1.0, **view)
        points = O + r * normal
        row, col = camera.project(points)
    return points, np.stack([row, col], axis=-1)


def _sphere_mask(camera, placement):
    """Pixels whose centre ray meets the sphere, grown by one pixel (the limb's partial pixels)."""
    rows, cols = np.indices(camera.shape)
    pts = reflected_rays(rows, cols, camera, placement.center, placement.radius)[0]
    mask = np.isfinite(pts[..., 0])
    return ndimage.binary_dilation(mask, structure=np.ones((3, 3), bool)) if mask.any() else mask


# -- observing a stack ---------------------------------------------------------------


def observe_sphere(stack: Stack, placement: SpherePlacement, *, params: DetectParams | None = None,
                   camera_index: int | None = None, name: str | None = None) -> SphereObservation:
    """The highlights of a stack of a sphere at a known place.

    Detection is :func:`~shinysim.recon.pipeline.detect_stack` with
    ``params`` (whole regions: ``max_area`` is ignored), searched only on
    the sphere's image (the pixels whose rays meet it, grown by one pixel).
    Per source frame: one intensity-weighted centre of gravity, and the
    intensity-weighted central second moments of the same region measured
    on the frame before smoothing (hot pixels replaced, background
    subtracted as detection does).

    Parameters
    ----------
    stack : shinysim.io.Stack
        Rendered or real frames, one per source of ``stack.rig``.
    placement : SpherePlacement
    params : DetectParams, optional
        Default: :class:`~shinysim.recon.detect.DetectParams` with a relative
        threshold of :data:`OBSERVE_THRESHOLD`, not detection's 0.5: a high
        threshold keeps only the few brightest pixels of a highlight 2-3 px
        across, whose centre of gravity then jumps by up to 0.3 px with the
        highlight's sub-pixel position.
    camera_index : int, optional
        The camera of ``stack.rig`` that took the frames (default the
        stack's own ``camera_index``).
    name : str, optional
        Names the stack in error messages.

    Returns
    -------
    SphereObservation
        Its ``threshold`` is the relative threshold used (0 for an absolute
        or scan threshold). Frames without a highlight on the sphere are left out. A frame with
        several regions keeps the one nearest the highlight predicted for
        the rig's (nominal) source. Moments (of the pixels of the region
        detection measured) are NaN for a region without light above the
        background.

    Raises
    ------
    CalibrationError
        The sphere is outside the image, no frame shows a highlight on it
        ("sphere not found"), or a frame has several highlights and the
        rig's source predicts none on this sphere.
    FrameError
        As :func:`~shinysim.recon.pipeline.detect_stack`.
    """
    if not isinstance(stack, Stack):
        raise TypeError(f"stack must be a shinysim.io.Stack, got {type(stack).__name__}")
    if not isinstance(placement, SpherePlacement):
        raise TypeError(f"placement must be a SpherePlacement, got {type(placement).__name__}")
    label = name if name is not None else f"stack of rig {stack.rig.name!r}"
    if camera_index is None:
        camera_index = stack.camera_index
    camera_index = check_number("camera_index", camera_index, lo=0, hi=len(stack.rig.cameras) - 1, integer=True)
    camera = stack.rig.cameras[camera_index]
    if camera.shape != stack.frames.shape[1:]:
        raise _error(label, f"camera {camera_index} images {camera.shape} but the frames are "
                            f"{stack.frames.shape[1:]}", "camera_index")
    if params is None:
        params = DetectParams(threshold=OBSERVE_THRESHOLD)
    params = with_overrides(DetectParams, params, {"max_area": None})
    where = f"sphere at {list(placement.center)} mm, radius {placement.radius:g} mm"
    mask = _sphere_mask(camera, placement)
    if not mask.any():
        raise _error(label, f"sphere not found: the {where} is outside camera {camera.name!r}'s image")
    recon = detect_stack(stack, params, mask=mask)
    table = recon.table
    if len(table) == 0:
        raise _error(label, f"sphere not found: no frame of {stack.n_sources} shows a highlight on the {where}")

    # the frames detection thresholded (hot pixels replaced, smoothed) and the unsmoothed ones
    raw = np.asarray(stack.frames, dtype=np.float64)
    fixed = raw
    if params.hot_pixels:
        sigmas = [params.noise_sigma if params.noise_sigma is not None else estimate_noise(f) for f in raw]
        fixed = replace_hot_pixels(raw, hot_pixel_mask(raw, sigmas, hot_pixel_k(raw[0].size, params.false_alarm)))

    picked = []  # one highlight per source
    for k in np.unique(table["source"]):
        idx = np.flatnonzero(table["source"] == k)
        if idx.size > 1:
            src = stack.rig.source_positions[k]
            _, rc = _highlights(src[None], np.asarray(placement.center)[None], np.array([placement.radius]), camera,
                                stack.rig.source_distant[k:k + 1])
            if not np.all(np.isfinite(rc)):
                raise _error(label, f"{idx.size} highlights on the sphere and the rig's source {k} predicts none "
                                    "there to choose between them", source_channel(int(k)))
            d = np.hypot(table["row"][idx] - rc[0, 0], table["col"][idx] - rc[0, 1])
            idx = idx[[int(np.argmin(d))]]
        picked.append(int(idx[0]))
    seen = table.select(picked)
    moments = np.array([_highlight_moments(fixed[k], params, recon, j) for j, k in zip(picked, seen["source"])])
    threshold = params.threshold if params.threshold_mode == "relative" else 0.0
    return SphereObservation.from_table(placement, seen, moments, threshold=threshold)


def _highlight_moments(fixed, params, recon, j):
    """Second moments of highlight ``j``'s region (the pixels detection measured) on the unsmoothed frame, or NaN."""
    coords = recon.regions.coords(recon.region[j])
    base = float(np.median(fixed)) if params.subtract_background else 0.0
    w = fixed[coords[:, 0], coords[:, 1]] - base
    w = np.where(w > 0, w, 0.0)
    if w.sum() <= 0:
        return np.full(3, np.nan)
    w, rc = w / w.sum(), coords.astype(float)
    d = rc - w @ rc
    return np.array([w @ (d[:, 0] ** 2), w @ (d[:, 0] * d[:, 1]), w @ (d[:, 1] ** 2)])


# -- calibration ---------------------------------------------------------------------


@dataclass
class _Fit:
    """One source's fitting problem."""

    index: int
    kind: str
    centers: np.ndarray  # (m, 3)
    radii: np.ndarray  # (m,)
    observed: np.ndarray  # (m, 2)
    moments: np.ndarray  # (m, 3), NaN where missing
    thresholds: np.ndarray  # (m,) relative detection thresholds
    ref: np.ndarray
    x: np.ndarray = None
    u0: np.ndarray = None
    e1: np.ndarray = None
    e2: np.ndarray = None
    hold: float = math.nan
    offset: np.ndarray = None  # (m, 2): finite-source centroid minus the centre's highlight, px

    @property
    def target(self):
        """The observed centres of gravity, less the finite-source offset: what the point model must meet."""
        return self.observed if self.offset is None else self.observed - self.offset

    @property
    def m(self):
        return len(self.radii)

    @property
    def k(self):
        return 3 if self.kind == "position" else 2

    def set_direction(self, u):
        self.u0 = normalize(u)
        self.e1, self.e2 = _tangent_basis(self.u0)
        self.x = np.zeros(2)

    def source(self, x):
        """The source position (or unit direction, distant) for parameters ``x``."""
        if self.kind == "position":
            return np.asarray(x, float)
        u = normalize(self.u0 + x[0] * self.e1 + x[1] * self.e2)
        return u if self.kind == "distant" else self.ref + self.hold * u

    def step(self, x):
        if self.kind == "position":
            return _STEP_REL * max(float(np.linalg.norm(x - self.centers.mean(axis=0))), 1e-3)
        return _STEP_RAD


def _predict(fits, xs, camera):
    """Predicted (m_i, 2) image coordinates of each fit's highlights, one solve for all."""
    if not fits:
        return []
    counts = [f.m for f in fits]
    S = np.repeat(np.array([f.source(x) for f, x in zip(fits, xs)]).reshape(-1, 3), counts, axis=0)
    distant = np.repeat([f.kind == "distant" for f in fits], counts)
    _, rc = _highlights(S, np.concatenate([f.centers for f in fits]), np.concatenate([f.radii for f in fits]), camera,
                        distant)
    return np.split(rc, np.cumsum(counts)[:-1])


def _jacobians(fits, xs, camera):
    """Central-difference Jacobians (2 m_i x k_i, pixels per parameter), one solve for all."""
    hs = [fit.step(x) for fit, x in zip(fits, xs)]
    cases = [(fit, np.asarray(x, float) + sign * h * e) for fit, x, h in zip(fits, xs, hs)
             for e in np.eye(fit.k) for sign in (1.0, -1.0)]
    preds = _predict([fit for fit, _ in cases], [x for _, x in cases], camera)
    out, at = [], 0
    for fit, h in zip(fits, hs):
        out.append(np.stack([(preds[at + 2 * q] - preds[at + 2 * q + 1]).ravel() / (2.0 * h) for q in range(fit.k)],
                            axis=1))
        at += 2 * fit.k
    return out


def _refine(fits, camera, name):
    """Least squares on the reprojection error; each fit's ``x`` set to its solution.

    The sources are independent, so one problem holds them all (its Jacobian
    block-diagonal and sparse): each evaluation solves every highlight at
    once, which is what costs.
    """
    if not fits:
        return
    cuts = np.cumsum([f.k for f in fits])[:-1]

    def fun(x):
        preds = _predict(fits, np.split(x, cuts), camera)
        return np.concatenate([(p - f.target).ravel() for p, f in zip(preds, fits)])

    def jac(x):
        return sparse.block_diag(_jacobians(fits, np.split(x, cuts), camera), format="csr")

    x0 = np.concatenate([f.x for f in fits])
    if not np.all(np.isfinite(fun(x0))):
        bad = [f.index for f, p in zip(fits, _predict(fits, [f.x for f in fits], camera)) if not np.all(np.isfinite(p))]
        raise _error(name, f"source(s) {bad}: the initial estimate predicts no highlight on a sphere "
                           "(check the placements and the camera)")
    res = optimize.least_squares(fun, x0, jac=jac, method="trf", tr_solver="lsmr", x_scale="jac",
                                 ftol=1e-12, xtol=1e-12, gtol=1e-12, max_nfev=100,
                                 tr_options={"atol": 1e-14, "btol": 1e-14})
    for f, x in zip(fits, np.split(res.x, cuts)):
        f.x = x
    for f in fits:  # re-centre the angles at the solution: the covariance is then that of the tangent plane
        if f.kind != "position":
            f.set_direction(f.source(f.x) if f.kind == "distant" else f.source(f.x) - f.ref)


def _as_observations(observations):
    if isinstance(observations, SphereObservation):
        return [observations]
    if not isinstance(observations, Sequence) and not hasattr(observations, "__iter__"):
        raise TypeError("observations must be SphereObservation objects")
    obs = list(observations)
    for j, o in enumerate(obs):
        if not isinstance(o, SphereObservation):
            raise TypeError(f"observations[{j}] must be a SphereObservation, got {type(o).__name__}")
    return obs


def calibrate_sources(observations, camera: Camera, *, nominal: Rig | None = None, reference_point=(0.0, 0.0, 0.0),
                      pixel_sigma: float | None = None, require_positions: bool = False,
                      source_radius=None, max_condition: float = 1e6,
                      name: str | None = None) -> SourceCalibration:
    """Source positions (or directions) from highlights on mirror spheres at known places.

    Parameters
    ----------
    observations : SphereObservation or sequence of them
        One per sphere placement (the same sphere or different ones).
    camera : shinysim.rig.Camera
        The camera that imaged them (its pixel coordinates).
    nominal : Rig, optional
        The nominal rig: its number of sources bounds the indices; its
        distant sources are fitted as directions; a near source seen by too
        few placements keeps its distance from ``reference_point``.
    reference_point : (3,) array_like, mm
        Where directions are measured from (the working volume's centre).
    pixel_sigma : float, optional
        Centroid noise, px: used only when the fit has no spare degrees of
        freedom to estimate it from the residuals.
    require_positions : bool
        Refuse (rather than fit a direction) a near source that fewer than
        two placements saw, or whose placements are degenerate.
    source_radius : None, "nominal", "estimated", float or (n,) array_like
        The sources' radii (mm) for the finite-source centroid model. None
        (default): point sources, the observed centre of gravity is taken as
        the highlight of the source's centre. Otherwise the predicted centre
        of gravity is the centroid of the finite source's image
        rendered into box pixels and thresholded at each observation's
        ``threshold`` (``docs/calibration.md``, "Finite sources"): ``"nominal"`` takes the
        nominal rig's radii, ``"estimated"`` the radii from the highlights'
        moments (re-estimated each round; the nominal radius, or 0, where
        moments are missing). For the SHINY fiber (0.508 mm, 2.4 px across)
        the offsets reach 0.03 px at a threshold of 0.05, about 0.02 degrees
        of direction.
    max_condition : float
        Largest condition number of the lines' normal matrix
        ``sum(I - l l^T)`` for a 3-D solution (about ``4 / theta^2`` for two
        lines at an angle ``theta``: 1e6 is 0.11 degrees).
    name : str, optional
        Names the data in error messages.

    Returns
    -------
    SourceCalibration

    Raises
    ------
    CalibrationError
        No highlights; a source index out of range of ``nominal``; a
        highlight that misses its sphere; with ``require_positions``, too
        few placements or a degenerate set (naming the source); no spare
        degrees of freedom and no ``pixel_sigma``.
    """
    obs = _as_observations(observations)
    if not isinstance(camera, Camera):
        raise TypeError(f"camera must be a shinysim Camera, got {type(camera).__name__}")
    if nominal is not None and not isinstance(nominal, Rig):
        raise TypeError(f"nominal must be a shinysim Rig or None, got {type(nominal).__name__}")
    ref = _vec3(reference_point, "reference_point", CalibrationError, name)
    if pixel_sigma is not None:
        pixel_sigma = check_number("pixel_sigma", pixel_sigma, lo=0, lo_open=True)
    max_condition = check_number("max_condition", max_condition, lo=1)
    if isinstance(source_radius, str):
        if source_radius not in SOURCE_RADIUS_MODELS:
            raise OptionError(f"source_radius must be None, one of {', '.join(map(repr, SOURCE_RADIUS_MODELS))}, "
                              f"a radius in mm or one per source; got {source_radius!r}")
        if source_radius == "nominal" and nominal is None:
            raise OptionError("source_radius='nominal' needs the nominal rig (nominal=...)")
    if source_radius is not None and not isinstance(source_radius, str) and np.ndim(source_radius) == 0:
        _radius_model(source_radius, nominal, 1)  # a bad radius is refused before any work
    if not obs or sum(len(o) for o in obs) == 0:
        raise _error(name, f"no highlights: none of the {len(obs)} observation(s) has one (sphere not found?)")
    for j, o in enumerate(obs):
        if nominal is not None and len(o) and o.sources.max() >= nominal.n_sources:
            raise _error(name, f"source index {int(o.sources.max())} is out of range: the nominal rig "
                               f"{nominal.name!r} has {nominal.n_sources} sources (0..{nominal.n_sources - 1})",
                         f"observations[{j}].sources")
    n = nominal.n_sources if nominal is not None else int(max(o.sources.max() for o in obs if len(o))) + 1
    rho = _radius_model(source_radius, nominal, n)

    # every highlight: its source, sphere, image point and reflected ray
    src = np.concatenate([o.sources for o in obs])
    which = np.concatenate([np.full(len(o), j) for j, o in enumerate(obs)])
    centers = np.concatenate([np.tile(o.placement.center, (len(o), 1)) for o in obs]).reshape(-1, 3)
    radii = np.concatenate([np.full(len(o), o.placement.radius) for o in obs])
    rc = np.stack([np.concatenate([o.rows for o in obs]), np.concatenate([o.cols for o in obs])], axis=1)
    mom = np.concatenate([o.moments if o.moments is not None else np.full((len(o), 3), np.nan) for o in obs])
    thr = np.concatenate([np.full(len(o), o.threshold) for o in obs])
    rays = [reflected_rays(o.rows, o.cols, camera, o.placement.center, o.placement.radius) for o in obs]
    points, lines = (np.concatenate([r[k] for r in rays]) for k in (0, 2))
    miss = ~np.isfinite(lines[:, 0])
    if miss.any():
        i = int(np.flatnonzero(miss)[0])
        raise _error(name, f"the highlight of source {int(src[i])} at (row {rc[i, 0]:.2f}, col {rc[i, 1]:.2f}) "
                           f"misses its sphere (centre {list(centers[i])} mm, radius {radii[i]:g} mm): a wrong "
                           "placement, camera or highlight", f"observations[{int(which[i])}]")

    notes = []
    fits = []
    n_obs = np.bincount(src, minlength=n)
    for s in range(n):
        sel = src == s
        m = int(sel.sum())
        distant = nominal is not None and bool(nominal.source_distant[s])
        if m < 2 and require_positions and not distant:
            raise _error(name, f"source {s}: seen by {m or 'no'} sphere placement: too few sphere positions for a "
                               "3-D solution (need 2 or more)")
        if m == 0:
            continue
        fit = _Fit(s, "position", centers[sel], radii[sel], rc[sel], mom[sel], thr[sel], ref)
        P, L = points[sel], lines[sel]
        if distant:
            fit.kind = "distant"
        elif m < 2:
            fit.kind = "direction"
        else:
            proj = np.eye(3)[None] - L[:, :, None] * L[:, None, :]
            A = proj.sum(axis=0)
            ev = np.linalg.eigvalsh(A)
            cond = ev[-1] / ev[0] if ev[0] > 0 else math.inf
            if cond > max_condition:
                message = (f"source {s}: the reflected rays of its {m} placements are nearly parallel (condition "
                           f"number {cond:.3g} > {max_condition:g}): degenerate geometry, the distance along them "
                           "is ill-conditioned; move the sphere farther between placements")
                if require_positions:
                    raise _error(name, message)
                notes.append(message + "; fitted as a direction")
                fit.kind = "direction"
            else:
                fit.x = np.linalg.solve(A, np.einsum("nij,nj->i", proj, P))
        if fit.kind == "direction":
            hold = float(np.linalg.norm(nominal.source_positions[s] - ref)) if nominal is not None else 0.0
            if hold > 0:
                fit.hold = hold
                relp = P - ref
                b = np.sum(L * relp, axis=1)
                disc = b * b - (np.sum(relp * relp, axis=1) - hold * hold)
                t = np.where(disc >= 0, -b + np.sqrt(np.maximum(disc, 0.0)), np.maximum(-b, 0.0))
                fit.set_direction(normalize(P + t[:, None] * L - ref).mean(axis=0))
            else:  # no distance to hold: the source at infinity
                fit.kind = "distant"
        if fit.kind == "distant":
            fit.set_direction(L.mean(axis=0))
        fits.append(fit)

    _refine(fits, camera, name)
    if rho is not None or source_radius == "estimated":
        # the offsets move little with the source: refit until they settle (a few rounds)
        for _ in range(_FINITE_ROUNDS):
            if source_radius == "estimated":
                rho = _radius_model("nominal", nominal, n) if nominal is not None else np.zeros(n)
                est = _fiber_radii(fits, n, camera)[0]
                rho = np.where(np.isfinite(est), est, rho)
            before = [f.offset for f in fits]
            _centroid_offsets(fits, rho, camera)
            _refine(fits, camera, name)
            change = max((float(np.max(np.abs((f.offset if f.offset is not None else 0.0)
                                               - (b if b is not None else 0.0))))
                          for f, b in zip(fits, before)), default=0.0)
            if change < _OFFSET_SETTLED_PX:
                break
        else:
            notes.append(f"finite-source model: the centroid offsets still changed by up to {change:.2g} px in the "
                         f"last of {_FINITE_ROUNDS} rounds (a threshold cut makes the centre of gravity of a small "
                         "highlight jump with its sub-pixel position; the fit is uncertain by about that much)")

    # residuals, noise, covariances
    preds = _predict(fits, [f.x for f in fits], camera)
    jacs = _jacobians(fits, [f.x for f in fits], camera)
    ss = sum(float(np.sum((p - f.target) ** 2)) for p, f in zip(preds, fits))
    dof = sum(2 * f.m - f.k for f in fits)
    sigma_res = math.sqrt(ss / dof) if dof > 0 else math.nan
    if dof > 0:
        sigma, sigma_source = sigma_res, "residuals"
    elif pixel_sigma is not None:
        sigma, sigma_source = pixel_sigma, "given"
    else:
        raise _error(name, "the pixel noise cannot be estimated: every source has as many parameters as "
                           "measurements (one placement fits a direction to one highlight exactly); pass "
                           "pixel_sigma, or add sphere placements")

    positions = np.full((n, 3), np.nan)
    directions = np.full((n, 3), np.nan)
    position_cov = np.full((n, 3, 3), np.nan)
    direction_cov = np.full((n, 3, 3), np.nan)
    rms = np.full(n, np.nan)
    solved = np.full(n, "none", dtype=object)
    for fit, p, J in zip(fits, preds, jacs):
        s = fit.index
        solved[s] = fit.kind
        rms[s] = math.sqrt(float(np.mean(np.sum((p - fit.target) ** 2, axis=1))))
        try:
            cov = sigma * sigma * np.linalg.inv(J.T @ J)
        except np.linalg.LinAlgError:
            cov = np.full((fit.k, fit.k), np.inf)
        if fit.kind == "position":
            positions[s] = fit.x
            position_cov[s] = cov
            d = fit.x - ref
            dist = float(np.linalg.norm(d))
            u = d / dist
            directions[s] = u
            G = (np.eye(3) - np.outer(u, u)) / dist
            direction_cov[s] = G @ cov @ G.T
        else:
            directions[s] = fit.u0
            E = np.stack([fit.e1, fit.e2], axis=1)
            direction_cov[s] = E @ cov @ E.T
    direction_sigma = np.degrees(np.sqrt(np.trace(direction_cov, axis1=1, axis2=2)))
    radius, radius_sigma = _fiber_radii(fits, n, camera)
    return SourceCalibration(
        positions=positions, directions=directions, reference_point=ref, position_cov=position_cov,
        direction_sigma_deg=direction_sigma, radius_mm=radius, radius_sigma_mm=radius_sigma,
        n_observations=n_obs, rms_residual_px=rms, pixel_sigma=float(sigma), pixel_sigma_source=sigma_source,
        direction_cov=direction_cov, solved=solved.astype(str), dof=int(dof), pixel_sigma_residuals=sigma_res,
        centroid_model="point" if source_radius is None else
        f"finite ({source_radius if isinstance(source_radius, str) else 'given'} radii)",
        notes=notes,
    )


def _radius_model(source_radius, nominal, n):
    """The radii (n,) of the finite-source model, or None for point sources (and for "estimated")."""
    if source_radius is None or isinstance(source_radius, str) and source_radius == "estimated":
        return None
    if isinstance(source_radius, str):
        return np.asarray(nominal.source_radii, float)
    try:
        rho = np.broadcast_to(np.asarray(source_radius, dtype=float), (n,)).copy()
    except (TypeError, ValueError):
        raise OptionError(f"source_radius must be a radius in mm or one per source ({n}); got "
                          f"{source_radius!r}") from None
    if not np.all(np.isfinite(rho)) or np.any(rho < 0):
        raise OptionError(f"source_radius must be finite and >= 0 mm; got {source_radius!r}")
    return rho


def _mirror_jacobians(sources, centers, radii, camera):
    """J (N, 2, 2): image motion (row, col) of the highlight per mm of source motion perpendicular to
    the reflected ray (along the two perpendicular unit vectors ``basis`` (N, 2, 3)), by central differences
    of the exact highlight; also the highlights ``rc`` (N, 2). Returns ``J, rc, basis``."""
    S = np.asarray(sources, float).reshape(-1, 3)
    N = S.shape[0]
    P, c0 = _highlights(S, centers, radii, camera)
    basis = np.stack(_tangent_basis(normalize(S - P)), axis=1)
    h = _STEP_REL * np.linalg.norm(S - P, axis=1)
    variants = np.concatenate([S + sign * h[:, None] * basis[:, q] for q in (0, 1) for sign in (1.0, -1.0)])
    _, rc = _highlights(variants, np.tile(centers, (4, 1)), np.tile(radii, 4), camera)
    rc = rc.reshape(4, N, 2)
    J = np.stack([(rc[0] - rc[1]) / (2 * h[:, None]), (rc[2] - rc[3]) / (2 * h[:, None])], axis=2)
    return J, c0, basis


def _centroid_offsets(fits, rho, camera):
    """Set each fit's ``offset``: the finite source's detected centre of gravity minus the centre's highlight.

    A uniform spherical source of radius ``rho[index]`` images on a mirror
    sphere as a uniformly lit region bounded by the image of its silhouette
    (the circle of radius ``rho`` perpendicular to the reflected ray). Its
    centroid is that of the polygon of ``_BOUNDARY_POINTS`` exact highlights
    of the circle (the mirror map's curvature). A centre of gravity of box
    pixels is not that centroid when the region spans a few pixels (pixel
    locking): the region, the ellipse ``d^T (rho^2 J J^T)^-1 d <= 1`` of the
    linear map about that centroid, is rendered into box pixels by
    ``_SUBPIXELS^2`` samples per pixel, pixels below the observation's
    ``threshold`` times the brightest dropped, and its centre of
    gravity taken with pixel centres, as detection does. Optical blur, noise
    and surface roughness are not modelled. Distant sources and ``rho = 0``
    get no offset.
    """
    todo = [f for f in fits if f.kind != "distant" and rho[f.index] > 0]
    for f in fits:
        f.offset = None
    if not todo:
        return
    S = np.concatenate([np.broadcast_to(f.source(f.x), (f.m, 3)) for f in todo])
    O = np.concatenate([f.centers for f in todo])
    r = np.concatenate([f.radii for f in todo])
    rr = np.concatenate([np.full(f.m, rho[f.index]) for f in todo])
    thresholds = np.concatenate([f.thresholds for f in todo])
    N = len(r)
    J, c0, basis = _mirror_jacobians(S, O, r, camera)
    phi = 2 * np.pi * np.arange(_BOUNDARY_POINTS) / _BOUNDARY_POINTS
    ring = np.cos(phi)[:, None, None] * basis[None, :, 0] + np.sin(phi)[:, None, None] * basis[None, :, 1]
    B = (S[None] + rr[None, :, None] * ring).reshape(-1, 3)
    _, rc = _highlights(B, np.tile(O, (_BOUNDARY_POINTS, 1)), np.tile(r, _BOUNDARY_POINTS), camera)
    x = rc.reshape(_BOUNDARY_POINTS, N, 2) - c0[None]  # relative to the centre's highlight, for precision
    x1 = np.roll(x, -1, axis=0)
    cross = x[..., 0] * x1[..., 1] - x1[..., 0] * x[..., 1]
    area = 0.5 * cross.sum(axis=0)
    offset = np.sum((x + x1) * cross[..., None], axis=0) / (6.0 * area[:, None])
    # pixel locking: the ellipse rendered into box pixels and centred as detection does
    shape = rr[:, None, None] ** 2 * J @ np.swapaxes(J, 1, 2)  # ellipse: d^T shape^-1 d <= 1
    semi = np.sqrt(np.linalg.eigvalsh(shape)[:, -1])
    small = np.flatnonzero(semi < _PIXEL_LOCKING_PX)
    side = (2 * int(np.ceil(semi[small].max(initial=0.0))) + 3) * _SUBPIXELS
    per_part = max(1, int(1e6 // side**2))  # samples held at once (a few temporaries of this size)
    for part in np.array_split(small, max(1, int(np.ceil(small.size / per_part)))):
        if part.size:
            offset[part] += _pixelated_centroid(c0[part] + offset[part], shape[part], semi[part], thresholds[part]) \
                - (c0[part] + offset[part])
    for f, part in zip(todo, np.split(offset, np.cumsum([f.m for f in todo])[:-1])):
        f.offset = part


def _pixelated_centroid(centre, shape, semi, threshold):
    """Centre of gravity (N, 2) of uniform ellipses rendered into box pixels, thresholded relative to their peak.

    Each pixel's coverage is the mean over ``_SUBPIXELS^2`` samples, each
    weighted by how much of its own small square lies inside the ellipse
    (its signed distance to the boundary, to first order): the coverage
    then moves continuously with the ellipse, not in steps of one sample.
    """
    w = int(np.ceil(semi.max())) + 1
    g = np.arange(-w, w + 1, dtype=float)
    sub = (np.arange(_SUBPIXELS) + 0.5) / _SUBPIXELS - 0.5
    base = np.rint(centre)
    # sample offsets from the ellipse centre along each axis: (N, pixels, subsamples)
    dr = (base[:, 0, None, None] + g[None, :, None] + sub[None, None, :] - centre[:, 0, None, None])[..., None, None]
    dc = (base[:, 1, None, None] + g[None, :, None] + sub[None, None, :] - centre[:, 1, None, None])[:, None, None]
    inv = np.linalg.inv(shape)
    a, b, c = (inv[:, i, j, None, None, None, None] for i, j in ((0, 0), (0, 1), (1, 1)))
    q = a * dr**2 + 2 * b * dr * dc + c * dc**2  # (N, rows, sub, cols, sub)
    grad = 2 * np.sqrt((a * dr + b * dc) ** 2 + (b * dr + c * dc) ** 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        distance = np.where(grad > 0, (q - 1.0) / grad, -np.inf)  # > 0 outside, pixels
    inside = np.clip(0.5 - distance * _SUBPIXELS, 0.0, 1.0)
    cover = inside.mean(axis=(2, 4))  # (N, rows, cols)
    cover = np.where(cover >= threshold[:, None, None] * cover.max(axis=(1, 2), keepdims=True), cover, 0.0)
    total = cover.sum(axis=(1, 2))
    rows = base[:, 0, None] + g[None, :]
    cols = base[:, 1, None] + g[None, :]
    return np.stack([np.einsum("nij,ni->n", cover, rows) / total, np.einsum("nij,nj->n", cover, cols) / total], axis=1)


def _fiber_radii(fits, n, camera):
    """Per-source fiber radius (mean over placements) and its standard error; one highlight solve for all."""
    radius = np.full(n, np.nan)
    sigma = np.full(n, np.nan)
    rows = [(fit, np.all(np.isfinite(fit.moments), axis=1)) for fit in fits if fit.kind != "distant"]
    rows = [(fit, ok) for fit, ok in rows if ok.any()]  # (fit, mask of its observations with moments)
    if not rows:
        return radius, sigma
    S = np.concatenate([np.broadcast_to(f.source(f.x), (int(ok.sum()), 3)) for f, ok in rows])
    J = _mirror_jacobians(S, np.concatenate([f.centers[ok] for f, ok in rows]),
                          np.concatenate([f.radii[ok] for f, ok in rows]), camera)[0]
    C = np.concatenate([f.moments[ok] for f, ok in rows])
    excess = C[:, 0] + C[:, 2] - 2.0 * _PIXEL_MOMENT
    rho_all = np.sqrt(np.maximum(4.0 * excess / np.einsum("nij,nij->n", J, J), 0.0))
    for (f, _), rho in zip(rows, np.split(rho_all, np.cumsum([ok.sum() for _, ok in rows])[:-1])):
        radius[f.index] = float(rho.mean())
        if rho.size > 1:
            sigma[f.index] = float(rho.std(ddof=1) / math.sqrt(rho.size))
    return radius, sigma
