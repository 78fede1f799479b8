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
from scipy import ndimage, special
from skimage import filters, measure

from .._shared import check_choice, check_number, with_overrides
from ..errors import FrameError

__all__ = [
    "THRESHOLD_MODES",
    "CENTROID_METHODS",
    "FLAG_RULES",
    "SATURATED_POLICIES",
    "AREA_FRACTION",
    "DetectParams",
    "FrameError",
    "estimate_noise",
    "noise_k",
    "auto_min_area",
    "hot_pixel_mask",
    "threshold_level",
    "check_frame",
    "check_exposure",
    "smoothed_frames",
    "reference_level",
    "detect_highlights",
    "detect_regions",
    "keep_areas",
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


#: What detection does with a highlight that reaches the sensor's clip level:
#: mark it in the table's ``saturated`` column (and warn), refuse the frame, or
#: neither.
SATURATED_POLICIES = ("flag", "refuse", "ignore")
#: A region smaller than this fraction of the stack's median highlight area
#: is noise (see :func:`auto_min_area`).
AREA_FRACTION = 1 / 8


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
    min_area : int or None
        Connected regions with fewer pixels are dropped (noise). None
        (default): derived from the expected image size of a source
        (:func:`auto_min_area`); the value used is stated in the output.
    max_area : int or None
        Regions with more pixels are subdivided into ``ceil(area / max_area)``
        parts by recursive halving along their principal axis at the
        intensity-weighted median; None keeps every region whole.
    centroid : {"weighted", "plain"}
        Intensity-weighted or plain centre of gravity.
    connectivity : {1, 2}
        4- or 8-connected regions.
    saturation : float or None
        Pixel value at which the sensor clips (e.g. 1.0 for 8-bit frames
        read by :func:`~shinysim.recon.frames.read_frame`). None: the
        stack's own clip level (``Stack.saturation``) when it has one.
    max_saturated_fraction : float
        A frame with more than this fraction of its pixels at or above
        ``saturation`` is refused as over-exposed, whatever ``saturated`` says.
    saturated : {"flag", "refuse", "ignore"}
        A highlight with a pixel at the clip level, or found with a relative
        threshold in a frame whose peak is clipped (relative to an unknown
        peak): marked in the table's ``saturated`` column, or its frame
        refused, or neither.
    noise_sigma : float or None
        Standard deviation of the frames' noise; None (default): estimated
        per frame (:func:`estimate_noise`).
    false_alarm : float
        Expected number of highlights per frame that Gaussian noise alone
        may produce: the threshold is raised to at least ``k`` noise
        standard deviations above the frame's background, and a region whose
        peak is less than ``k`` standard deviations above the threshold is
        dropped as a noise island, with ``k`` the one-sided Gaussian quantile
        of ``false_alarm / n_pixels`` (:func:`noise_k`; 5.4 for a 512 x 512
        frame at 0.01). 0 turns the noise test off.
    hot_pixels : bool
        Replace hot pixels (isolated pixels that stand out of their
        neighbourhood in at least half of the frames, which no moving
        highlight does) by their neighbourhood's median before detection
        (stacks only).
    subtract_background : bool
        Subtract each frame's background (its median: a sensor's dark
        offset, stray light) from the pixel values that weight the centroid
        (stacks only).
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
    min_area: int | None = None
    max_area: int | None = None
    centroid: str = "weighted"
    connectivity: int = 2
    saturation: float | None = None
    max_saturated_fraction: float = 0.05
    saturated: str = "flag"
    noise_sigma: float | None = None
    false_alarm: float = 0.01
    hot_pixels: bool = True
    subtract_background: bool = True
    flag_rule: str = "none"
    dim_fraction: float = 0.5

    def __post_init__(self):
        check_choice("threshold_mode", self.threshold_mode, THRESHOLD_MODES)
        check_choice("centroid", self.centroid, CENTROID_METHODS)
        check_choice("connectivity", self.connectivity, (1, 2))
        check_choice("saturated", self.saturated, SATURATED_POLICIES)
        check_choice("flag_rule", self.flag_rule, FLAG_RULES)
        check_choice("hot_pixels", self.hot_pixels, (True, False))
        check_choice("subtract_background", self.subtract_background, (True, False))
        hi = None if self.threshold_mode == "absolute" else 1.0
        check_number(f"{self.threshold_mode} threshold", self.threshold, lo=0, lo_open=True, hi=hi)
        check_number("smooth_px", self.smooth_px, lo=0, hi=100)
        check_number("dim_fraction", self.dim_fraction, lo=0, hi=1)
        check_number("max_saturated_fraction", self.max_saturated_fraction, lo=0, hi=1)
        check_number("false_alarm", self.false_alarm, lo=0)
        if self.min_area is not None:
            check_number("min_area", self.min_area, lo=1, integer=True)
        if self.max_area is not None:
            check_number("max_area", self.max_area, lo=max(1, self.min_area or 1), integer=True)
        if self.saturation is not None:
            check_number("saturation", self.saturation, lo=0, lo_open=True)
        if self.noise_sigma is not None:
            check_number("noise_sigma", self.noise_sigma, lo=0)


def estimate_noise(frame):
    """Standard deviation of a frame's pixel noise, robustly (0 for a noiseless frame).

    From horizontal pixel differences, in which highlights and edges touch
    few pixel pairs: their median absolute deviation, scaled to a Gaussian's
    standard deviation (1.4826 / sqrt(2)). Where more than half of the
    differences are 0 (a dark, quantised frame: noise below one code) that
    is 0, and the root mean square of the differences without their largest
    1 % (the highlights' edges), over sqrt(2), is used instead.
    """
    frame = np.asarray(frame, dtype=np.float64)
    if frame.shape[-1] < 2:
        return 0.0
    d = np.diff(frame, axis=-1).ravel()
    mad = float(np.median(np.abs(d - np.median(d))))
    if mad > 0:
        return 1.4826 / np.sqrt(2.0) * mad
    a = np.sort(np.abs(d))[: max(1, int(0.99 * d.size))]
    return float(np.sqrt(np.mean(a**2) / 2.0))


def noise_k(n_pixels, false_alarm):
    """Noise standard deviations above which ``false_alarm`` pixels of ``n_pixels`` are expected (one-sided Gaussian)."""
    if false_alarm <= 0 or n_pixels <= 0:
        return 0.0
    return float(max(0.0, special.ndtri(1.0 - min(false_alarm / n_pixels, 0.5))))


def auto_min_area(areas, floor=1):
    """The minimum highlight area derived from the expected image size of a source.

    Every source of a rig is the same small sphere seen in the same object,
    so its highlights have similar image sizes (on the calibration sphere
    they differ by less than 2x across the 21 sources); the median area of a
    stack's significant highlights measures that size. Regions smaller than
    :data:`AREA_FRACTION` of it are noise islands or hot pixels, not an image
    of the source. ``floor`` is the least area at all (1 pixel, or a rig's
    own bound).
    """
    areas = np.asarray(areas, float)
    if areas.size == 0:
        return int(floor)
    return int(max(floor, np.floor(AREA_FRACTION * np.median(areas))))


#: A pixel's eight neighbours (the footprint of the largest neighbour, edges replicated, in the hot-pixel test).
_RING_FOOTPRINT = np.ones((3, 3), bool)
_RING_FOOTPRINT[1, 1] = False


def hot_pixel_mask(frames, sigmas, k):
    """Pixels that spike above all eight neighbours in at least half of the frames.

    A highlight moves with its source and is wider than a pixel, so no
    pixel of one is an isolated spike in most frames; a hot (or stuck)
    pixel is, lit or not. A pixel counts in a frame when it exceeds the
    largest of its eight neighbours by more than ``k`` times that frame's
    noise (and by more than 0).
    """
    frames = np.asarray(frames, dtype=np.float64)
    n = len(frames)
    if n < 4:
        return np.zeros(frames.shape[1:], bool)
    count = np.zeros(frames.shape[1:], int)
    for f, sigma in zip(frames, sigmas):
        count += (f - ndimage.maximum_filter(f, footprint=_RING_FOOTPRINT, mode="nearest")) > max(k * sigma, 0.0)
    return count >= n / 2


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


def check_frame(frame, params, name, saturation=None):
    """One frame as float64, or :class:`FrameError` naming it.

    Refuses a frame that is not 2-D, has NaN/inf or negative pixels
    (naming their count), or is over-exposed: more than
    ``params.max_saturated_fraction`` of its pixels at or above the clip
    level (``params.saturation``, else ``saturation``).
    """
    frame = np.asarray(frame)
    if frame.ndim != 2:
        raise FrameError(f"a frame must be 2-D (H, W), got shape {frame.shape}", field=name)
    if not (np.issubdtype(frame.dtype, np.floating) or np.issubdtype(frame.dtype, np.integer)):
        raise FrameError(f"pixels must be numbers, got {frame.dtype}", field=name)
    bad = int(np.count_nonzero(~np.isfinite(frame)))
    if bad:
        raise FrameError(f"{bad} NaN or inf pixel(s)", field=name)
    neg = int(np.count_nonzero(frame < 0))
    if neg:
        raise FrameError(f"{neg} negative pixel(s) (min {float(frame.min()):.4g}); intensities are linear and >= 0",
                         field=name)
    level = params.saturation if params.saturation is not None else saturation
    if level is not None and frame.size:
        check_exposure(frame, params, name, level)
    return frame.astype(np.float64, copy=False)


def check_exposure(frame, params, name, level):
    """Raise :class:`FrameError` if more than ``params.max_saturated_fraction`` of ``frame`` is at or above ``level``.

    The over-exposure test of :func:`check_frame`, on the frame as given
    (its own dtype: a float32 frame is compared with ``level`` in float32).
    """
    frac = np.count_nonzero(frame >= level) / frame.size
    if frac > params.max_saturated_fraction:
        raise FrameError(
            f"frame is over-exposed ({100 * frac:.1f}% of pixels at or above the clip level "
            f"{level:g}, more than {100 * params.max_saturated_fraction:g}%); lower the exposure",
            field=name)


def _split(coords, weights, n_parts):
    """Recursive halving of a pixel set along its principal axis.

    Returns a list of index arrays into ``coords``, ``n_parts`` of them
    (fewer only if a part is a single pixel), each in projection order.
    The parts are a function of the pixel set alone, whatever the order of
    its pixels, and the same with any LAPACK or numpy: the pixels are taken
    in raster order; the axis is the covariance's major eigenvector in
    closed form, its larger component positive (the row axis where the
    covariance is isotropic to 1e-9); projections are compared to 1e-9 px,
    equal ones in raster order; and the cut is the pixel boundary whose
    cumulative weight is nearest the left part's share of the total
    (``n_parts // 2`` of ``n_parts``), compared as sums of the weights, not
    ratios, so that an exact share stays exact; a pixel that straddles the
    share by exactly half goes to the left. A mirrored set splits mirrored
    into a power of two of parts, but for such half-pixel ties (into 3
    parts, the low end's third is cut first, and the rest halved).
    """
    n = len(coords)
    if n_parts <= 1 or n < 2:
        return [np.arange(n)]
    canon = np.lexsort((coords[:, 1], coords[:, 0]))
    xy, w = coords[canon], weights[canon]
    if not w.sum() > 0:  # a weightless part: split by pixel count
        w = np.ones(n)
    d = xy - (w[:, None] * xy).sum(axis=0) / w.sum()
    a, c, b = (w * d[:, 0] ** 2).sum(), (w * d[:, 1] ** 2).sum(), (w * d[:, 0] * d[:, 1]).sum()
    half, r = (a - c) / 2, np.hypot((a - c) / 2, b)
    if r <= 1e-9 * (a + c):
        axis = (1.0, 0.0)
    else:  # (lambda_max - c, b) or (b, lambda_max - a): the larger component is the positive one
        axis = (half + r, b) if a >= c else (b, r - half)
    proj = (d[:, 0] * axis[0] + d[:, 1] * axis[1]) / np.hypot(*axis)
    order = np.argsort(np.rint(proj * 1e9), kind="stable")
    n_left = n_parts // 2
    cum = np.concatenate([[0.0], np.cumsum(w[order])])
    excess = n_parts * cum - n_left * cum[-1]  # n_parts x (prefix weight - left share)
    k = int(np.argmax(excess >= 0))  # the first prefix that reaches the share
    cut = k if excess[k] <= -excess[k - 1] else k - 1
    cut = min(max(cut, 1), n - 1)
    left, right = canon[order[:cut]], canon[order[cut:]]
    out = []
    for idx, m in ((left, n_left), (right, n_parts - n_left)):
        for sub in _split(coords[idx], weights[idx], m):
            out.append(idx[sub])
    return out


def _centroid(coords, weights, method):
    if method == "plain":
        return coords.mean(axis=0)
    return (weights @ coords) / weights.sum()


def detect_highlights(frame, params=None, *, mask=None, name="frame", saturation=None, **kwargs):
    """Find the highlights in one frame.

    Parameters
    ----------
    frame : (H, W) array_like
        Linear intensity.
    params : DetectParams, optional
        Settings; keyword arguments override single fields. Without a stack
        there is no median highlight size: an automatic ``min_area`` is 1,
        and hot pixels (a property of a stack) are not looked for.
    mask : (H, W) bool, optional
        Only pixels inside are considered (e.g. the object's silhouette).
    name : str
        Used in error messages.
    saturation : float, optional
        The sensor's clip level when ``params.saturation`` is None.

    Returns
    -------
    dict of 1-D ndarrays, one entry per highlight
        ``row``, ``col`` (centroid, continuous pixel coordinates), ``area``
        (pixels), ``peak`` and ``sum`` (intensity), ``blob`` (label of the
        connected region it came from, 1-based), ``part`` (0 for a whole
        region, 1.. for the parts of a subdivided one) and ``saturated``
        (the highlight has a pixel at the clip level).

    Raises
    ------
    FrameError
        Non-2-D frame, NaN/inf or negative pixels, an over-exposed frame,
        or a saturated highlight with ``saturated="refuse"``.
    ValueError
        A ``"scan"`` threshold (it needs the whole stack).
    """
    params = with_overrides(DetectParams, params, kwargs)
    raw = check_frame(frame, params, name, saturation)
    frame = smoothed_frames(raw[None], params.smooth_px)[0] if params.smooth_px > 0 else raw
    level = threshold_level(frame, params)
    sigma = params.noise_sigma if params.noise_sigma is not None else estimate_noise(frame)
    k = noise_k(frame.size, params.false_alarm)
    found = detect_regions(frame, level, params, mask=mask, name=name, noise=k * sigma, raw=raw,
                           saturation=params.saturation if params.saturation is not None else saturation)
    return keep_areas(found, params.min_area or 1)


def keep_areas(found, min_area):
    """The highlights of ``found`` whose connected region has at least ``min_area`` pixels."""
    keep = found["region_area"] >= min_area
    return {k: v[keep] for k, v in found.items() if k != "region_area"}


def detect_regions(frame, level, params, *, mask=None, name="frame", noise=0.0, raw=None, saturation=None,
                   background=0.0):
    """Connected regions of ``frame >= level``, subdivided, with their centroids.

    The core of :func:`detect_highlights` and of
    :func:`~shinysim.recon.pipeline.detect_stack`, for a frame that is
    already checked (and smoothed) and a threshold already turned into a
    level. Regions of every size are returned, with their ``region_area``
    (:func:`keep_areas` applies the minimum).

    Parameters
    ----------
    frame : (H, W) float64 ndarray
    level : float
        Absolute threshold (inf: nothing is detected).
    params : DetectParams
        ``max_area``, ``centroid``, ``connectivity`` and ``saturated`` are used.
    mask : (H, W) bool, optional
    name : str
    noise : float
        ``k`` noise standard deviations (see ``DetectParams.false_alarm``):
        the level is raised to at least the frame's median plus ``noise``,
        and a region whose peak is not ``noise`` above the level is dropped.
    raw : (H, W) ndarray, optional
        The unsmoothed frame, for the saturation test (default ``frame``).
    saturation : float, optional
        Clip level: highlights with a pixel at or above it are ``saturated``.
    background : float
        The frame's background level (a sensor's dark offset, stray light),
        subtracted from the pixel values before they weight the centroid,
        ``peak`` and ``sum``: a pedestal under a highlight pulls its
        weighted centroid towards the middle of the thresholded region.

    Returns
    -------
    dict of 1-D ndarrays
        As :func:`detect_highlights`, plus ``region_area``.
    """
    raw = frame if raw is None else raw
    if noise > 0 and frame.size:
        level = max(level, float(np.median(frame)) + noise)
    above = frame >= level
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != frame.shape:
            raise FrameError(f"mask shape {mask.shape} differs from frame shape {frame.shape}", field=name)
        above &= mask
    out = {k: [] for k in _COLUMNS + ("saturated", "region_area")}
    # a threshold relative to a clipped peak is relative to an unknown level: every
    # highlight of such a frame is suspect, not only the clipped one
    frame_clipped = saturation is not None and raw.size > 0 and float(raw.max()) >= saturation
    if above.any():
        labels = measure.label(above, connectivity=params.connectivity)
        for region in measure.regionprops(labels):
            coords = region.coords.astype(float)
            values = frame[region.coords[:, 0], region.coords[:, 1]]
            if noise > 0 and values.max() < level + noise:  # a noise island: its peak is not above the level
                continue
            weights = values - background
            weights = np.where(weights > 0, weights, 0.0)
            if weights.sum() <= 0:
                continue
            clipped = saturation is not None and bool(np.any(raw[region.coords[:, 0], region.coords[:, 1]]
                                                             >= saturation))
            if (clipped or frame_clipped) and params.saturated == "refuse":
                what = ("reaches the clip level" if clipped else
                        "lies in a frame whose peak reaches the clip level (its threshold is relative to an "
                        "unknown peak)")
                raise FrameError(
                    f"a highlight at ({region.centroid[0]:.1f}, {region.centroid[1]:.1f}) {what} {saturation:g}; "
                    "lower the exposure or detect with saturated='flag'", field=name)
            clipped = clipped or (frame_clipped and params.threshold_mode == "relative")
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
                out["saturated"].append(clipped and params.saturated == "flag")
                out["region_area"].append(int(region.area))
    dtypes = {"row": float, "col": float, "peak": float, "sum": float, "saturated": bool}
    return {k: np.asarray(v, dtype=dtypes.get(k, int)) for k, v in out.items()}


# -- exact statistics of a mostly-zero frame from its nonzero part -------------------
#
# detect_stack's fast path (shinysim.recon.pipeline) reads each frame once and
# keeps only its nonzero pixels; the statistics below give, from those, the very
# numbers that estimate_noise and np.median give on the whole frame: order
# statistics are picked by rank with the zeros counted, and a mean over a sorted
# array that starts with zeros is summed in numpy's own pairwise order.

#: numpy's pairwise summation: blocks of at most this many elements are summed
#: with 8 interleaved accumulators, larger ones split in two (multiples of 8).
_PW_BLOCK = 128


def _pairwise_sum_zero_prefix(tail, n):
    """``np.add.reduce`` of the ``n``-long float64 array ``zeros(n - len(tail)) ++ tail``, without building it.

    Bit for bit numpy's pairwise sum (``tests/test_detect_fast.py`` checks it
    against ``np.add.reduce``): a block splits into halves (the first a
    multiple of 8 long) down to leaves of at most 128; a half of zeros adds
    exactly 0.0, a half inside ``tail`` is summed by numpy itself, and the
    one leaf that straddles the boundary is built. ``tail`` must be >= 0.
    """
    if not (isinstance(tail, np.ndarray) and tail.dtype == np.float64 and tail.flags.c_contiguous):
        tail = np.ascontiguousarray(tail, dtype=np.float64)
    z = n - len(tail)
    if z < 0:
        raise ValueError("tail longer than the array")
    if n <= 0:
        return 0.0
    lo, count, rights = 0, n, []
    while True:
        hi = lo + count
        if hi <= z:
            total = 0.0
            break
        if lo >= z:
            total = float(np.add.reduce(tail[lo - z:hi - z]))
            break
        if count <= _PW_BLOCK:
            leaf = np.zeros(count)
            leaf[z - lo:] = tail[:hi - z]
            total = float(np.add.reduce(leaf))
            break
        half = count // 2
        half -= half % 8
        if lo + half <= z:  # the first half is zeros: the block's sum is the second half's
            lo, count = lo + half, count - half
        else:  # the second half lies inside the tail: its sum is added once the first half's is known
            rights.append(float(np.add.reduce(tail[lo + half - z:hi - z])))
            count = half
    for right in reversed(rights):
        total = total + right
    return total


def _order_stat(s, q, c, rank):
    """The ``rank``-th smallest (0-based) of the sorted array ``s`` with ``c`` copies of ``q`` added."""
    j = int(np.searchsorted(s, q))
    if rank < j:
        return float(s[rank])
    if rank < j + c:
        return float(q)
    return float(s[rank - c])


def _median_with_block(s, q, c):
    """``float(np.median(x))`` for ``x`` = sorted ``s`` plus ``c`` copies of ``q``, exactly as numpy computes it."""
    size = len(s) + c
    half = size // 2
    if size % 2:
        return (0.0 + _order_stat(s, q, c, half)) / 1
    return ((0.0 + _order_stat(s, q, c, half - 1)) + _order_stat(s, q, c, half)) / 2


def _rms_noise(abs_sorted, n_diffs):
    """:func:`estimate_noise`'s root-mean-square branch from the sorted nonzero ``|d|`` (the rest are zeros)."""
    m = max(1, int(0.99 * n_diffs))
    kept = m - (n_diffs - len(abs_sorted))
    if kept <= 0:
        return 0.0
    total = _pairwise_sum_zero_prefix(np.square(abs_sorted[:kept]), m)
    return float(np.sqrt(total / m / 2.0))


def _noise_from_nonzero_diffs(d, n_diffs):
    """:func:`estimate_noise` of a frame from its nonzero horizontal differences ``d`` (``n_diffs`` in all).

    The other ``n_diffs - len(d)`` differences are 0. Equal, bit for bit, to
    :func:`estimate_noise` on the whole frame.
    """
    if n_diffs <= 0:
        return 0.0
    d = np.sort(np.asarray(d, dtype=np.float64))
    zeros = n_diffs - len(d)
    med = _median_with_block(d, 0.0, zeros)
    if med == 0.0:
        dev, dev_zero = np.abs(d), 0.0
    else:
        dev, dev_zero = np.abs(d - med), float(np.abs(0.0 - med))
    mad = _median_with_block(np.sort(dev), dev_zero, zeros)
    if mad > 0:
        return 1.4826 / np.sqrt(2.0) * mad
    return _rms_noise(np.sort(np.abs(d)), n_diffs)
