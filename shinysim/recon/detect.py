"""Highlight detection: threshold, connected regions, centre of gravity.

Paper Section III: "Each image is thresholded relative to I0, and connected
regions greater than some minimum size are stored", and Section IV: "When the
size of a blob is relatively large, it is subdivided into smaller blobs."

Coordinates are continuous (row, col) with pixel centres at integers
(:mod:`shinysim.conventions`). numpy + scikit-image only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from skimage import filters, measure

from .._shared import check_choice, with_overrides
from ..errors import FrameError

__all__ = [
    "THRESHOLD_MODES",
    "CENTROID_METHODS",
    "FLAG_RULES",
    "DetectParams",
    "FrameError",
    "threshold_level",
    "check_frame",
    "smoothed_frames",
    "reference_level",
    "detect_highlights",
    "detect_regions",
]

#: How ``threshold`` is read: a fraction of the frame's peak, a level, or a
#: fraction of the scan-wide reference level (the brightest pixel of the
#: whole, smoothed stack; :func:`shinysim.recon.pipeline.detect_stack`).
THRESHOLD_MODES = ("relative", "absolute", "scan")
#: Centre of gravity of the blob's pixels, or weighted by intensity.
CENTROID_METHODS = ("weighted", "plain")
#: Inter-reflection flag rules: ``"dim"`` flags a highlight whose peak is
#: below ``dim_fraction`` of the scan's reference level; ``"none"`` flags nothing.
FLAG_RULES = ("dim", "none")

_COLUMNS = ("row", "col", "area", "peak", "sum", "blob", "part")


@dataclass(frozen=True)
class DetectParams:
    """Settings of :func:`detect_highlights`.

    Parameters
    ----------
    threshold : float
        I0: a fraction of the frame's peak (``threshold_mode="relative"``,
        in (0, 1]), an intensity level (``"absolute"``, > 0) or a fraction
        of the scan's reference level (``"scan"``, in (0, 1]: a frame that
        holds only a dim inter-reflection is not promoted to a highlight).
    threshold_mode : {"relative", "absolute", "scan"}
    smooth_px : float
        Standard deviation of a Gaussian applied to every frame before
        thresholding, pixels (0: none; against render or sensor noise).
    min_area : int
        Connected regions with fewer pixels are dropped (noise).
    max_area : int or None
        Regions with more pixels are subdivided into ``ceil(area / max_area)``
        parts by recursive halving along their principal axis at the
        intensity-weighted median; None keeps every region whole.
    centroid : {"weighted", "plain"}
        Intensity-weighted or plain centre of gravity.
    connectivity : {1, 2}
        4- or 8-connected regions.
    saturation : float or None
        Pixel value at which the sensor clips (e.g. 255 for 8-bit frames).
        A frame with more than ``max_saturated_fraction`` of its pixels at
        or above it is rejected as saturated.
    max_saturated_fraction : float
    flag_rule : {"none", "dim"}
        Inter-reflection flag (:data:`FLAG_RULES`) of
        :func:`~shinysim.recon.pipeline.detect_stack`.
    dim_fraction : float
        ``"dim"``: highlights whose peak is below this fraction of the
        scan's reference level are flagged.
    """

    threshold: float = 0.5
    threshold_mode: str = "relative"
    smooth_px: float = 0.0
    min_area: int = 1
    max_area: int | None = None
    centroid: str = "weighted"
    connectivity: int = 2
    saturation: float | None = None
    max_saturated_fraction: float = 0.05
    flag_rule: str = "none"
    dim_fraction: float = 0.5

    def __post_init__(self):
        check_choice("threshold_mode", self.threshold_mode, THRESHOLD_MODES)
        check_choice("centroid", self.centroid, CENTROID_METHODS)
        check_choice("connectivity", self.connectivity, (1, 2))
        if self.threshold_mode == "scan" and not (np.isfinite(self.threshold) and 0 < self.threshold <= 1):
            raise ValueError(f"a scan threshold must be in (0, 1], got {self.threshold!r}")
        if not np.isfinite(self.threshold) or self.threshold <= 0:
            raise ValueError(f"threshold must be > 0, got {self.threshold!r}")
        if self.threshold_mode == "relative" and self.threshold > 1:
            raise ValueError(f"a relative threshold must be in (0, 1], got {self.threshold!r}")
        if not (np.isfinite(self.smooth_px) and self.smooth_px >= 0):
            raise ValueError(f"smooth_px must be >= 0, got {self.smooth_px!r}")
        check_choice("flag_rule", self.flag_rule, FLAG_RULES)
        if not (np.isfinite(self.dim_fraction) and 0 <= self.dim_fraction <= 1):
            raise ValueError(f"dim_fraction must be in [0, 1], got {self.dim_fraction!r}")
        if int(self.min_area) < 1:
            raise ValueError(f"min_area must be >= 1, got {self.min_area!r}")
        if self.max_area is not None and int(self.max_area) < max(1, int(self.min_area)):
            raise ValueError(f"max_area must be >= min_area, got {self.max_area!r}")


def threshold_level(frame, params):
    """The absolute level I0 for one frame (inf for an empty frame).

    A ``"scan"`` threshold needs the whole stack: :func:`~shinysim.recon.pipeline.detect_stack`
    turns it into an absolute one.
    """
    if params.threshold_mode == "scan":
        raise ValueError("a 'scan' threshold is relative to the whole stack: detect with detect_stack")
    if params.threshold_mode == "absolute":
        return float(params.threshold)
    peak = float(np.max(frame)) if frame.size else 0.0
    return params.threshold * peak if peak > 0 else np.inf


def smoothed_frames(frames, smooth_px):
    """Gaussian-smoothed copies of (n, H, W) frames (float64); unchanged for 0."""
    frames = np.asarray(frames, dtype=np.float64)
    if smooth_px <= 0:
        return frames
    return np.stack([filters.gaussian(f, sigma=smooth_px, preserve_range=True, mode="nearest") for f in frames])


def reference_level(frames):
    """The scan-wide reference: the brightest pixel of a (smoothed) stack, 0 for none."""
    return float(np.max(frames)) if np.size(frames) else 0.0


def check_frame(frame, params, name):
    """One frame as float64, or :class:`FrameError` naming it.

    Refuses a frame that is not 2-D, has NaN/inf pixels, or is saturated
    (more than ``params.max_saturated_fraction`` of its pixels at or above
    ``params.saturation``).
    """
    frame = np.asarray(frame)
    if frame.ndim != 2:
        raise FrameError(f"{name}: a frame must be 2-D (H, W), got shape {frame.shape}")
    if not np.all(np.isfinite(frame)):
        raise FrameError(f"{name}: frame has NaN or inf pixels")
    if params.saturation is not None and frame.size:
        frac = np.count_nonzero(frame >= params.saturation) / frame.size
        if frac > params.max_saturated_fraction:
            raise FrameError(
                f"{name}: frame is saturated ({100 * frac:.1f}% of pixels at or above "
                f"{params.saturation:g}, more than {100 * params.max_saturated_fraction:g}%)"
            )
    return frame.astype(np.float64, copy=False)


def _split(coords, weights, n_parts):
    """Recursive halving of a pixel set along its principal axis.

    Returns a list of index arrays into ``coords``, ``n_parts`` of them
    (fewer only if a part is a single pixel).
    """
    if n_parts <= 1 or len(coords) < 2:
        return [np.arange(len(coords))]
    w = weights / weights.sum()
    mean = w @ coords
    d = coords - mean
    cov = (d * w[:, None]).T @ d
    _, vecs = np.linalg.eigh(cov)
    axis = vecs[:, -1]
    proj = d @ axis
    order = np.argsort(proj, kind="stable")
    n_left = n_parts // 2
    # cut where the cumulative weight reaches the left share
    cum = np.cumsum(w[order])
    cut = int(np.searchsorted(cum, n_left / n_parts)) + 1
    cut = min(max(cut, 1), len(coords) - 1)
    left, right = order[:cut], order[cut:]
    out = []
    for idx, k in ((left, n_left), (right, n_parts - n_left)):
        for sub in _split(coords[idx], weights[idx], k):
            out.append(idx[sub])
    return out


def _centroid(coords, weights, method):
    if method == "plain":
        return coords.mean(axis=0)
    return (weights @ coords) / weights.sum()


def detect_highlights(frame, params=None, *, mask=None, name="frame", **kwargs):
    """Find the highlights in one frame.

    Parameters
    ----------
    frame : (H, W) array_like
        Linear intensity.
    params : DetectParams, optional
        Settings; keyword arguments override single fields.
    mask : (H, W) bool, optional
        Only pixels inside are considered (e.g. the object's silhouette).
    name : str
        Used in error messages.

    Returns
    -------
    dict of 1-D ndarrays, one entry per highlight
        ``row``, ``col`` (centroid, continuous pixel coordinates), ``area``
        (pixels), ``peak`` and ``sum`` (intensity), ``blob`` (label of the
        connected region it came from, 1-based) and ``part`` (0 for a whole
        region, 1.. for the parts of a subdivided one).

    Raises
    ------
    FrameError
        Non-2-D frame, NaN/inf pixels, or a saturated frame.
    ValueError
        A ``"scan"`` threshold (it needs the whole stack).
    """
    params = with_overrides(DetectParams, params, kwargs)
    frame = check_frame(frame, params, name)
    if params.smooth_px > 0:
        frame = smoothed_frames(frame[None], params.smooth_px)[0]
    return detect_regions(frame, threshold_level(frame, params), params, mask=mask, name=name)


def detect_regions(frame, level, params, *, mask=None, name="frame"):
    """Connected regions of ``frame >= level``, subdivided, with their centroids.

    The core of :func:`detect_highlights` and of
    :func:`~shinysim.recon.pipeline.detect_stack`, for a frame that is
    already checked (and smoothed) and a threshold already turned into a
    level.

    Parameters
    ----------
    frame : (H, W) float64 ndarray
    level : float
        Absolute threshold (inf: nothing is detected).
    params : DetectParams
        ``min_area``, ``max_area``, ``centroid`` and ``connectivity`` are used.
    mask : (H, W) bool, optional
    name : str

    Returns
    -------
    dict of 1-D ndarrays
        As :func:`detect_highlights`.
    """
    above = frame >= level
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != frame.shape:
            raise FrameError(f"{name}: mask shape {mask.shape} differs from frame shape {frame.shape}")
        above &= mask
    out = {k: [] for k in _COLUMNS}
    if not above.any():
        return {k: np.array(v, dtype=float if k in ("row", "col", "peak", "sum") else int) for k, v in out.items()}
    labels = measure.label(above, connectivity=params.connectivity)
    for region in measure.regionprops(labels):
        if region.area < params.min_area:
            continue
        coords = region.coords.astype(float)
        weights = frame[region.coords[:, 0], region.coords[:, 1]]
        weights = np.where(weights > 0, weights, 0.0)
        if weights.sum() <= 0:
            continue
        n_parts = 1
        if params.max_area is not None and region.area > params.max_area:
            n_parts = int(np.ceil(region.area / params.max_area))
        parts = _split(coords, weights, n_parts)
        for j, idx in enumerate(parts):
            r, c = _centroid(coords[idx], weights[idx], params.centroid)
            out["row"].append(r)
            out["col"].append(c)
            out["area"].append(len(idx))
            out["peak"].append(weights[idx].max())
            out["sum"].append(weights[idx].sum())
            out["blob"].append(region.label)
            out["part"].append(0 if n_parts == 1 else j + 1)
    return {
        k: np.asarray(v, dtype=float if k in ("row", "col", "peak", "sum") else int) for k, v in out.items()
    }
