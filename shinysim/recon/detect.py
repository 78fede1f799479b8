"""Highlight detection: threshold, connected regions, centre of gravity.

Paper Section III: "Each image is thresholded relative to I0, and connected
regions greater than some minimum size are stored", and Section IV: "When the
size of a blob is relatively large, it is subdivided into smaller blobs."

Coordinates are continuous (row, col) with pixel centres at integers
(:mod:`shinysim.conventions`). numpy, SciPy and scikit-image only.

This module is the one place that thresholds, labels and measures regions:
:func:`find_regions` labels whole frames (a stack at once, frames never
joined) with :func:`scipy.ndimage.label` and returns :class:`Regions`, whose
per-region sums, maxima and centroids any caller reuses;
:func:`measure_highlights` turns them into highlights (noise islands,
saturation, subdivision). The reference it is held to (scikit-image's
``label`` and ``regionprops``, one region at a time) lives in the tests.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage, special
from skimage import filters

from .._shared import check_choice, check_number, with_overrides
from ..errors import FrameError, OptionError
from ..io.table import HighlightTable

__all__ = [
    "THRESHOLD_MODES",
    "CENTROID_METHODS",
    "FLAG_RULES",
    "SATURATED_POLICIES",
    "AREA_FRACTION",
    "DetectParams",
    "FrameError",
    "estimate_noise",
    "core_regions",
    "HIGHLIGHT_FLOOR",
    "SPARSE_FRACTION",
    "SPECK_MARGIN",
    "speck_level",
    "hot_pixel_k",
    "noise_k",
    "auto_min_area",
    "hot_pixel_mask",
    "replace_hot_pixels",
    "sparse_noise",
    "Regions",
    "find_regions",
    "regions_of_pixels",
    "measure_highlights",
    "threshold_level",
    "check_frame",
    "check_exposure",
    "smoothed_frames",
    "reference_level",
    "detect_highlights",
    "detect_regions",
]

#: How ``threshold`` is read: a fraction of the frame's peak, a level, or a
#: fraction of the scan-wide reference level (the brightest pixel of the
#: whole, smoothed stack; :func:`shinysim.recon.pipeline.detect_stack`).
THRESHOLD_MODES = ("relative", "absolute", "scan", "highlight")

#: ``threshold_mode="highlight"``'s default ``floor``: the faintest highlight looked for, as a fraction of the
#: scan's brightest pixel. A highlight's peak is about the share of its pixel the source's image covers, so
#: 1/64 keeps a source imaged on a sixty-fourth of a pixel (a highlight a fifth of the brightest, the dim
#: one of a 0.5 mm sphere beside larger ones, stands 13 times above it) and drops the lone Monte-Carlo
#: samples of rendered frames (at most 0.007 of the brightest pixel, measured at 4 and 16 spp), which a
#: camera's noise hides from the noise test.
HIGHLIGHT_FLOOR = 2.0 ** -6

#: A frame with at most this fraction of its pixels nonzero (a rendered frame: about 2 %) is read from its
#: nonzero pixels alone: its zeros, the majority, make its median 0 and most of its differences 0; its
#: lone lit pixels are its noise (:func:`speck_level`).
SPARSE_FRACTION = 1 / 8

#: The ``"highlight"`` level stands this many times above the brightest lone sample of rendered frames
#: (two lone samples side by side are no longer alone, and are as bright).
SPECK_MARGIN = 2.0

_NEIGHBOURS = ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1))


def speck_level(shape, pixels, values) -> float:
    """The brightest lone lit pixel of a frame: nonzero, with all 8 neighbours exactly zero (0 for none).

    In a rendered frame the background is exactly zero and a pixel lit alone can only hold a lone
    Monte-Carlo sample (a glossy tail, a caustic): the render's own noise, which no highlight falls below,
    as a highlight lights its neighbours through its lobe. A camera's frame has no exact zeros, so it has no
    lone pixels either; its noise is estimated instead (:func:`estimate_noise`).

    Parameters
    ----------
    shape : (H, W)
    pixels : (P,) int ndarray
        Flat indices of the frame's nonzero pixels, ascending.
    values : (P,) ndarray
    """
    H, W = (int(v) for v in shape)
    pixels = np.asarray(pixels, np.int64)
    if not len(pixels):
        return 0.0
    rows, cols = np.divmod(pixels, W)
    alone = np.ones(len(pixels), bool)
    for dr, dc in _NEIGHBOURS:
        r, c = rows + dr, cols + dc
        inside = (r >= 0) & (r < H) & (c >= 0) & (c < W)
        flat = np.where(inside, r * W + c, -1)
        pos = np.clip(np.searchsorted(pixels, flat), 0, len(pixels) - 1)
        alone &= ~(inside & (pixels[pos] == flat))
    return float(np.max(np.asarray(values, np.float64)[alone])) if alone.any() else 0.0
#: Centre of gravity of the blob's pixels, or weighted by intensity.
CENTROID_METHODS = ("weighted", "plain")
#: Inter-reflection flag rules: ``"dim"`` flags a highlight whose peak is
#: below ``dim_fraction`` of the scan's reference level; ``"none"`` flags nothing.
FLAG_RULES = ("dim", "none")

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
        in (0, 1]), an intensity level (``"absolute"``, > 0), a fraction
        of the scan's reference level (``"scan"``, in (0, 1]: a frame that
        holds only a dim inter-reflection is not promoted to a highlight)
        or a fraction of each highlight's own peak (``"highlight"``, in
        (0, 1]: regions are found at the frame's noise level, and at least
        ``floor`` of the scan's reference, and each is measured over its
        pixels at or above ``threshold`` of its peak, so a dim highlight
        beside a bright one in the same frame is kept).
    threshold_mode : {"relative", "absolute", "scan", "highlight"}
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
        read by :func:`~shinysim.io.frames.read_frame`). None: the
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
    floor : float
        ``"highlight"``: the faintest highlight looked for, a fraction of the
        scan's reference level in [0, 1) (:data:`HIGHLIGHT_FLOOR`, 1/64).
        The level is also kept above twice the brightest lone lit pixel of
        rendered frames (:func:`speck_level`) and above the noise.
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
    floor: float = HIGHLIGHT_FLOOR
    flag_rule: str = "none"
    dim_fraction: float = 0.5

    def __post_init__(self):
        for name, choices in (("threshold_mode", THRESHOLD_MODES), ("centroid", CENTROID_METHODS),
                              ("connectivity", (1, 2)), ("saturated", SATURATED_POLICIES), ("flag_rule", FLAG_RULES),
                              ("hot_pixels", (True, False)), ("subtract_background", (True, False))):
            check_choice(name, getattr(self, name), choices)
        hi = None if self.threshold_mode == "absolute" else 1.0
        check_number(f"{self.threshold_mode} threshold", self.threshold, lo=0, lo_open=True, hi=hi)
        check_number("smooth_px", self.smooth_px, lo=0, hi=100)
        check_number("dim_fraction", self.dim_fraction, lo=0, hi=1)
        check_number("floor", self.floor, lo=0, hi=1, hi_open=True)
        check_number("max_saturated_fraction", self.max_saturated_fraction, lo=0, hi=1)
        check_number("false_alarm", self.false_alarm, lo=0)
        for name, rule in (("min_area", dict(lo=1, integer=True)),
                           ("max_area", dict(lo=max(1, self.min_area or 1), integer=True)),
                           ("saturation", dict(lo=0, lo_open=True)), ("noise_sigma", dict(lo=0))):
            if getattr(self, name) is not None:
                check_number(name, getattr(self, name), **rule)


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


def sparse_noise(shape, nonzero, values):
    """:func:`estimate_noise` of an (H, W) frame from its nonzero pixels, or None where it needs the whole frame.

    ``nonzero``, ``values``: the flat indices (ascending) of the frame's
    only nonzero pixels and their values (> 0). The horizontal differences
    that are not 0 are among the pairs that hold one of them: each
    pixel's pair with its right neighbour, and its pair with a left
    neighbour that is 0. Where more than half of all differences are 0,
    their median and median deviation are 0 and the estimate is the root
    mean square branch: the smallest 99 % of all ``|d|`` are the zeros and
    the smallest of the nonzero ones. That is computed here with plain
    numpy; it equals :func:`estimate_noise` but for the order of the
    summation of the squares (a relative difference of order 1e-15;
    ``tests/test_detect_reference.py`` holds it to 1e-12). None where the
    differences are not mostly zeros.
    """
    H, W = shape
    if W < 2 or len(nonzero) == 0:
        return 0.0
    v = np.asarray(values, np.float64)
    col = np.asarray(nonzero) % W
    follows = np.diff(nonzero) == 1  # the right neighbour is the next nonzero pixel (or the next row's first)
    right = -v
    right[:-1] += np.where(follows, v[1:], 0.0)
    left = np.ones(len(v), bool)  # the left neighbour is 0 (and in the row)
    left[1:] = ~follows
    d = np.concatenate([np.abs(right[col != W - 1]), v[left & (col != 0)]])
    d = d[d != 0]
    n_diffs = H * (W - 1)
    zeros = n_diffs - len(d)
    if 2 * zeros <= n_diffs:
        return None
    m = max(1, int(0.99 * n_diffs))
    if m <= zeros:
        return 0.0
    if m - zeros < len(d):
        d = np.partition(d, m - zeros - 1)[:m - zeros]
    return float(np.sqrt(np.square(d).sum() / m / 2.0))


def noise_k(n_pixels, false_alarm):
    """Noise standard deviations above which ``false_alarm`` pixels of ``n_pixels`` are expected (one-sided Gaussian)."""
    if false_alarm <= 0 or n_pixels <= 0:
        return 0.0
    return float(max(0.0, special.ndtri(1.0 - min(false_alarm / n_pixels, 0.5))))


def hot_pixel_k(n_pixels, false_alarm):
    """The hot-pixel test's ``k`` (:func:`hot_pixel_mask`): detection's :func:`noise_k`, and at least 3."""
    return max(noise_k(n_pixels, false_alarm), 3.0)


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


#: A pixel's eight neighbours and its 3 x 3 box, as (row, col) offsets (the hot-pixel test and its replacement).
_RING = np.array([(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if dr or dc])
_BOX = np.array([(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1)])
_RING_FOOTPRINT = np.ones((3, 3), bool)
_RING_FOOTPRINT[1, 1] = False


def _around(frames, rows, cols, offsets):
    """(n, m, len(offsets)) values of every frame around the pixels (rows, cols), edges replicated."""
    _, H, W = frames.shape
    return frames[:, np.clip(rows[:, None] + offsets[:, 0], 0, H - 1), np.clip(cols[:, None] + offsets[:, 1], 0, W - 1)]


def hot_pixel_mask(frames, sigmas, k, *, candidates=None):
    """Pixels that spike above all eight neighbours in at least half of the frames.

    A highlight moves with its source and is wider than a pixel, so no
    pixel of one is an isolated spike in most frames; a hot (or stuck)
    pixel is, lit or not. A pixel counts in a frame when it exceeds the
    largest of its eight neighbours (edges replicated) by more than ``k``
    times that frame's noise (and by more than 0).

    ``candidates``: flat indices of the only pixels that can be hot, if the
    caller knows them (e.g. from each frame's nonzero pixels): those above
    their frame's level ``max(k * sigma, 0)`` in at least half of the frames
    (neighbours are >= 0). By default they are found here; only they are
    tested against their neighbours.
    """
    frames = np.asarray(frames)
    n, H, W = frames.shape
    if n < 4:
        return np.zeros((H, W), bool)
    level = np.array([max(k * s, 0.0) for s in sigmas], dtype=np.float64)
    if candidates is None:
        count = np.zeros((H, W), np.int64)
        for f, lv in zip(frames, level):
            count += f > lv
        candidates = np.flatnonzero(count >= n / 2)
    rows, cols = np.divmod(np.asarray(candidates, np.int64), W)
    if len(rows) * len(_RING) > H * W:  # most pixels: the ring's maximum over whole frames
        ring = ndimage.maximum_filter(frames, footprint=_RING_FOOTPRINT[None], mode="nearest")[:, rows, cols]
    else:
        ring = _around(frames, rows, cols, _RING).max(axis=2)
    spikes = (frames[:, rows, cols].astype(np.float64) - ring) > level[:, None]
    hot = np.zeros(H * W, bool)
    hot[rows * W + cols] = spikes.sum(axis=0) >= n / 2
    return hot.reshape(H, W)


def replace_hot_pixels(frames, hot):
    """A copy of (n, H, W) ``frames`` with the pixels of the (H, W) mask ``hot`` replaced by their 3 x 3 median.

    Edges are replicated (``scipy.ndimage.median_filter(size=3, mode="nearest")``
    at those pixels); the median of nine values is one of them, so the
    frames keep their dtype exactly. The frames themselves when ``hot`` is empty.
    """
    rows, cols = np.nonzero(hot)
    if not len(rows):
        return frames
    out = np.array(frames, copy=True)
    out[:, rows, cols] = np.median(_around(frames, rows, cols, _BOX), axis=-1)
    return out


def threshold_level(frame, params, *, peak=None, reference=None, floor=None, background=0.0):
    """The absolute level I0 for one frame (inf for an empty frame).

    ``peak``: the frame's largest value, when the caller has it (else read
    from ``frame``). A ``"scan"`` threshold needs the whole stack's
    ``reference`` level (:func:`~shinysim.recon.pipeline.detect_stack`
    passes it); without one it is refused. A ``"highlight"`` threshold's
    level is ``params.floor`` times the reference (the frame's peak
    without one) above the frame's ``background`` (a sensor's dark
    offset), or ``floor`` where that is higher (the frames' lone samples,
    :func:`speck_level`, times :data:`SPECK_MARGIN`).
    """
    if params.threshold_mode == "scan":
        if reference is None:
            raise OptionError("a 'scan' threshold is relative to the whole stack: detect with detect_stack")
        return params.threshold * reference if reference > 0 else np.inf
    if params.threshold_mode == "highlight":  # the regions' level; each is then cut at its own peak
        if reference is None:
            reference = float(np.max(frame)) if frame.size else 0.0
        return max(background + params.floor * reference, floor or 0.0) if reference > 0 else np.inf
    if params.threshold_mode == "absolute":
        return float(params.threshold)
    if peak is None:
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


def detect_highlights(frame, params=None, *, mask=None, name="frame", saturation=None, specks=True, **kwargs):
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
    specks : bool
        In ``"highlight"`` mode, keep the level above twice the brightest
        lone lit pixel of a sparse (rendered) frame (:func:`speck_level`);
        False for a frame that is sparse by construction, whose lone pixels
        are noise of its own making (a background-subtracted signal, e.g.
        :func:`~shinysim.recon.dots.dot_signal`).

    Returns
    -------
    HighlightTable
        ``source`` 0, ``row``, ``col`` (centroid, continuous pixel
        coordinates), ``area`` (pixels), ``peak`` and ``sum`` (intensity),
        ``blob`` (label of the connected region it came from, 1-based),
        ``part`` (0 for a whole region, 1.. for the parts of a subdivided
        one), ``saturated`` (the highlight has a pixel at the clip
        level) and ``cut`` (its region touches the frame's border);
        ``rel_peak`` unknown (NaN), no inter-reflection flags.

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
    floor = None
    if params.threshold_mode == "highlight" and specks:
        flat = np.flatnonzero(frame)
        if len(flat) <= frame.size * SPARSE_FRACTION:  # a rendered frame, as detect_stack reads one
            floor = SPECK_MARGIN * speck_level(frame.shape, flat, frame.reshape(-1)[flat])
    level = threshold_level(frame, params, floor=floor,
                            background=float(np.median(frame)) if params.threshold_mode == "highlight" else 0.0)
    sigma = params.noise_sigma if params.noise_sigma is not None else estimate_noise(frame)
    k = noise_k(frame.size, params.false_alarm)
    found = detect_regions(frame, level, params, mask=mask, name=name, noise=k * sigma, raw=raw,
                           saturation=params.saturation if params.saturation is not None else saturation)
    keep = found.pop("region_area") >= (params.min_area or 1)  # whose connected region is large enough
    found = {k: v[keep] for k, v in found.items()}
    return HighlightTable({"source": np.zeros(len(found["row"]), np.int64), **found})


# -- the engine: connected regions of whole frames, measured by bincount-style sums ----------------

#: Pixel connectivity in a frame (1: 4-connected, 2: 8-connected), as the middle plane of a 3-D
#: structure whose other planes are empty: frames stacked along the first axis are never joined.
_STRUCTURES = {c: np.stack([np.zeros((3, 3), bool), ndimage.generate_binary_structure(2, c), np.zeros((3, 3), bool)])
               for c in (1, 2)}


@dataclass(frozen=True)
class Regions:
    """Connected regions of the pixels above a threshold in a stack of frames, and their pixels.

    Made by :func:`find_regions` (a boolean stack or frame) or
    :func:`regions_of_pixels` (a list of pixels). ``m`` regions, ``P``
    pixels in all; regions are ordered by frame and, within a frame, by
    their first pixel in raster order, so that ``label`` is the label that
    :func:`scipy.ndimage.label` (and :func:`skimage.measure.label`) give the
    region on its frame alone. The pixels are listed region after region,
    in raster order inside each: per-pixel arrays (``P``,) in that order are
    reduced to per-region ones (``m``,) by :meth:`sum`, :meth:`max`,
    :meth:`any` and :meth:`centroid`.

    Attributes
    ----------
    shape : (n, H, W)
        The stack's shape (n = 1 for a single frame).
    frame, label : (m,) int64
        Each region's frame and its 1-based label in that frame.
    start, area : (m,) int64
        Region ``i``'s pixels are ``start[i]`` to ``start[i] + area[i]`` of the pixel arrays.
    index : (P,) int64
        Flat index of each pixel in the (n, H, W) stack.
    row, col : (P,) int64
        Its pixel coordinates in its frame.
    """

    shape: tuple
    frame: np.ndarray
    label: np.ndarray
    start: np.ndarray
    area: np.ndarray
    index: np.ndarray
    row: np.ndarray
    col: np.ndarray

    def __len__(self):
        return len(self.area)

    def values(self, image):
        """(P,) values of an (n, H, W) stack, or of an (H, W) frame, at the regions' pixels."""
        image = np.asarray(image)
        if image.ndim == 2:
            return image[self.row, self.col]
        return image.reshape(-1)[self.index]

    def _reduce(self, ufunc, x):
        return ufunc.reduceat(x, self.start) if len(self.area) else np.zeros(0, x.dtype)

    def sum(self, x):
        """(m,) sum of the per-pixel ``x`` over each region (a count for booleans)."""
        x = np.asarray(x)
        return self._reduce(np.add, x.astype(np.int64) if x.dtype == bool else x)

    def max(self, x):
        """(m,) largest per-pixel ``x`` of each region."""
        return self._reduce(np.maximum, np.asarray(x))

    def any(self, x):
        """(m,) bool: some pixel of the region has ``x``."""
        return self._reduce(np.logical_or, np.asarray(x, bool))

    def centroid(self, weights=None):
        """(m, 2) (row, col) centre of gravity of each region, weighted by the per-pixel ``weights`` or plain."""
        if weights is None:
            w, total = 1.0, self.area.astype(np.float64)
        else:
            w = np.asarray(weights, np.float64)
            total = self.sum(w)
        return np.stack([self.sum(w * self.row) / total, self.sum(w * self.col) / total], axis=-1)

    def bbox(self):
        """(m, 4) int64: ``min_row, min_col, max_row + 1, max_col + 1`` of each region (skimage's ``bbox``)."""
        return np.stack([self._reduce(np.minimum, self.row), self._reduce(np.minimum, self.col),
                         self._reduce(np.maximum, self.row) + 1, self._reduce(np.maximum, self.col) + 1], axis=-1)

    def coords(self, i):
        """(area, 2) int64 (row, col) of region ``i``'s pixels, in raster order."""
        s = slice(int(self.start[i]), int(self.start[i] + self.area[i]))
        return np.stack([self.row[s], self.col[s]], axis=1)

    def label_image(self):
        """(n, H, W) int32 label image (0: background; each frame's regions labelled 1, 2, ...); (H, W) for n = 1."""
        out = np.zeros(self.shape, np.int32)
        out.reshape(-1)[self.index] = np.repeat(self.label, self.area)
        return out[0] if self.shape[0] == 1 else out


def find_regions(above, connectivity=2):
    """:class:`Regions` of a boolean (H, W) frame or (n, H, W) stack, frame by frame (``connectivity``: 1 or 2)."""
    above = np.asarray(above, dtype=bool)
    if above.ndim not in (2, 3):
        raise OptionError(f"need an (H, W) frame or an (n, H, W) stack, got shape {above.shape}")
    shape = (1,) + above.shape if above.ndim == 2 else above.shape
    frame, flat = np.divmod(np.flatnonzero(above), shape[1] * shape[2])
    return regions_of_pixels(frame, flat, shape, connectivity)


def regions_of_pixels(frame, flat, shape, connectivity=2):
    """:class:`Regions` of the pixels ``flat`` (flat indices in their frame) of the frames ``frame`` of an (n, H, W) stack.

    The pixels are labelled in one call of :func:`scipy.ndimage.label` on
    the stack's box that holds them all (a structure that joins no two
    frames; nothing outside the box is above the threshold, so the regions
    are those of the whole frames).
    """
    check_choice("connectivity", connectivity, (1, 2))
    n, H, W = (int(v) for v in shape)
    frame = np.asarray(frame, np.int64).reshape(-1)
    flat = np.asarray(flat, np.int64).reshape(-1)
    index = frame * (H * W) + flat
    if len(index) > 1 and np.any(index[1:] <= index[:-1]):
        index = np.unique(index)
        frame, flat = np.divmod(index, H * W)
    if len(index) == 0:
        none = np.zeros(0, np.int64)
        return Regions((n, H, W), none, none, none, none, none, none, none)
    rows, cols = np.divmod(flat, W)
    f0, r0, c0 = int(frame[0]), int(rows.min()), int(cols.min())
    box = np.zeros((int(frame[-1]) - f0 + 1, int(rows.max()) - r0 + 1, int(cols.max()) - c0 + 1), bool)
    at = (frame - f0, rows - r0, cols - c0)
    box[at] = True
    labels, m = ndimage.label(box, _STRUCTURES[connectivity])
    # labels come in raster order of their first pixel over the box, i.e. by frame, then raster order
    ids = labels[at] - 1
    order = np.argsort(ids, kind="stable")
    area = np.bincount(ids, minlength=m).astype(np.int64)
    start = np.zeros(m, np.int64)
    np.cumsum(area[:-1], out=start[1:])
    region_frame = frame[order[start]]
    first = np.searchsorted(region_frame, region_frame)  # each frame's first region
    label = np.arange(m, dtype=np.int64) - first + 1
    return Regions((n, H, W), region_frame, label, start, area, index[order], rows[order], cols[order])


def core_regions(regions, values, fraction, connectivity=2):
    """The regions of each region's pixels at or above ``fraction`` of that region's peak (``values``, in the
    regions' pixel order): ``threshold_mode="highlight"``, the paper's I0 taken relative to each highlight."""
    if not len(regions):
        return regions
    peak = regions.max(np.asarray(values, np.float64))
    core = np.asarray(values, np.float64) >= fraction * np.repeat(peak, regions.area)
    n, H, W = regions.shape
    return regions_of_pixels(np.repeat(regions.frame, regions.area)[core], regions.index[core] % (H * W),
                             regions.shape, connectivity)


def _centroid(coords, weights, method):
    if method == "plain":
        return coords.mean(axis=0)
    return (weights @ coords) / weights.sum()


_ROW_DTYPES = {"source": int, "row": float, "col": float, "area": int, "peak": float, "sum": float, "blob": int,
               "part": int, "saturated": bool, "cut": bool, "region_area": int, "region": int}


def measure_highlights(regions, values, params, *, level, noise=None, background=None, raw=None, saturation=None,
                       clipped_frames=None, names=None):
    """The highlights of :class:`Regions` of thresholded frames: noise islands dropped, large regions subdivided.

    Parameters
    ----------
    regions : Regions
    values : (P,) float64
        The thresholded (smoothed) pixel values, in the regions' pixel order.
    params : DetectParams
        ``max_area``, ``centroid``, ``saturated`` and ``threshold_mode`` are used.
    level, noise, background : (n,) float64
        Each frame's absolute threshold, ``k`` noise standard deviations
        (0: no noise test) and background level (subtracted from the values
        before they weight the centroid, ``peak`` and ``sum``).
    raw : (P,) ndarray, optional
        The unsmoothed values, for the saturation test (default ``values``).
    saturation : float, optional
        Clip level: a region with a raw pixel at or above it is clipped.
    clipped_frames : (n,) bool, optional
        The frames whose raw peak reaches the clip level: every region of
        one is suspect (with a relative threshold it is relative to an
        unknown peak): refused with ``saturated="refuse"``, flagged with
        ``"flag"`` and a relative threshold.
    names : sequence of str, optional
        Each frame's name for errors (default ``frame <k>``).

    Returns
    -------
    dict of 1-D ndarrays, one entry per highlight
        ``source`` (frame), ``row``, ``col``, ``area``, ``peak``, ``sum``,
        ``blob`` (the region's label), ``part``, ``saturated`` (as
        :func:`detect_highlights`), ``cut`` (the region touches the image's
        border: the highlight may go on beyond it, and its centroid is not
        the mirror point's), ``region_area`` (the whole region's
        pixels) and ``region`` (its index in ``regions``); frame by frame, regions in label order, parts in
        :func:`_split`'s order. Whole regions are measured by per-region
        sums over their pixels (:meth:`Regions.sum`), parts by
        :func:`_split` on the region's own pixels.

    Raises
    ------
    FrameError
        With ``saturated="refuse"``: the first clipped highlight, naming its frame.
    """
    m = len(regions)
    n = regions.shape[0]
    f = regions.frame
    level = np.broadcast_to(np.asarray(level, np.float64), (n,))[f]
    noise = np.zeros(m) if noise is None else np.broadcast_to(np.asarray(noise, np.float64), (n,))[f]
    bg = np.zeros(m) if background is None else np.broadcast_to(np.asarray(background, np.float64), (n,))[f]
    values = np.asarray(values, np.float64)
    weights = values - np.repeat(bg, regions.area)
    weights = np.where(weights > 0, weights, 0.0)
    vmax, wmax = regions.max(values), regions.max(weights)
    # a noise island (its peak is not a noise level above the threshold), or nothing above the background
    keep = ~((noise > 0) & (vmax < level + noise)) & (wmax > 0)
    clipped = np.zeros(m, bool)
    if saturation is not None:
        clipped = regions.any((values if raw is None else np.asarray(raw)) >= saturation)
    frame_clipped = np.zeros(m, bool) if clipped_frames is None else np.asarray(clipped_frames, bool)[f]
    if params.saturated == "refuse":
        refused = np.flatnonzero(keep & (clipped | frame_clipped))
        if len(refused):
            i = int(refused[0])
            r, c = regions.coords(i).mean(axis=0)
            what = ("reaches the clip level" if clipped[i] else
                    "lies in a frame whose peak reaches the clip level (its threshold is relative to an unknown peak)")
            name = names[f[i]] if names is not None else f"frame {int(f[i])}"
            raise FrameError(f"a highlight at ({r:.1f}, {c:.1f}) {what} {saturation:g}; "
                             "lower the exposure or detect with saturated='flag'", field=name)
    flag = (clipped | (frame_clipped & (params.threshold_mode == "relative"))) & (params.saturated == "flag")
    total = regions.sum(weights)
    with np.errstate(invalid="ignore", divide="ignore"):  # regions without weight are dropped (not kept)
        cog = regions.centroid(weights if params.centroid == "weighted" else None)
    kept = np.flatnonzero(keep)
    _, H, W = regions.shape
    cut = regions.any((regions.row == 0) | (regions.col == 0) | (regions.row == H - 1) | (regions.col == W - 1))
    whole = {"source": f, "row": cog[:, 0], "col": cog[:, 1], "area": regions.area, "peak": wmax, "sum": total,
             "blob": regions.label, "part": np.zeros(m, np.int64), "saturated": flag, "cut": cut,
             "region_area": regions.area, "region": np.arange(m)}
    if params.max_area is None or not np.any(regions.area[kept] > params.max_area):
        return {k: np.asarray(v[kept], dtype=_ROW_DTYPES[k]) for k, v in whole.items()}
    out = {k: [] for k in _ROW_DTYPES}
    for i in kept.tolist():
        area = int(regions.area[i])
        parts = [{}]  # a region within max_area: its whole row
        if area > params.max_area:
            coords, w = regions.coords(i).astype(float), weights[int(regions.start[i]):int(regions.start[i]) + area]
            parts = []
            for j, idx in enumerate(_split(coords, w, int(np.ceil(area / params.max_area)))):
                r, c = _centroid(coords[idx], w[idx], params.centroid)
                parts.append({"row": r, "col": c, "area": len(idx), "peak": w[idx].max(), "sum": w[idx].sum(),
                              "part": j + 1})
        for part in parts:
            for k, v in whole.items():
                out[k].append(np.array([part[k]]) if k in part else v[i:i + 1])
    return {k: np.concatenate(v).astype(_ROW_DTYPES[k]) if v else np.zeros(0, _ROW_DTYPES[k])
            for k, v in out.items()}


def detect_regions(frame, level, params, *, mask=None, name="frame", noise=0.0, raw=None, saturation=None,
                   background=0.0):
    """Connected regions of ``frame >= level``, subdivided, with their centroids.

    The core of :func:`detect_highlights` for one frame that is already
    checked (and smoothed) and a threshold already turned into a level:
    :func:`find_regions` and :func:`measure_highlights`. Regions of every
    size are returned, with their ``region_area`` (:func:`detect_highlights`
    applies the minimum).

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
    frame = np.asarray(frame, np.float64)
    raw = frame if raw is None else raw
    if noise > 0 and frame.size:
        level = max(level, float(np.median(frame)) + noise)
    above = frame >= level
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != frame.shape:
            raise FrameError(f"mask shape {mask.shape} differs from frame shape {frame.shape}", field=name)
        above &= mask
    regions = find_regions(above, params.connectivity)
    if params.threshold_mode == "highlight":
        regions = core_regions(regions, regions.values(frame), params.threshold, params.connectivity)
    # a threshold relative to a clipped peak is relative to an unknown level: every
    # highlight of such a frame is suspect, not only the clipped one
    frame_clipped = saturation is not None and raw.size > 0 and float(np.max(raw)) >= saturation
    found = measure_highlights(regions, regions.values(frame), params, level=level, noise=noise,
                               background=background, raw=regions.values(raw), saturation=saturation,
                               clipped_frames=[frame_clipped], names=[name])
    del found["source"], found["region"]
    return found
