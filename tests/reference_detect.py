"""The simple reference the detection engine is held to: scikit-image's ``label`` and ``regionprops``.

Every statistic over whole float64 frames, one region at a time, as
detection was written before it became one vectorised path
(:mod:`shinysim.recon.detect`): the noise estimate over every pixel
difference, hot pixels by a 3 x 3 maximum filter over whole frames and a
median filter, each frame labelled by :func:`skimage.measure.label` and each
region measured from its own ``regionprops`` pixels. Used by the tests only.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage
from skimage import measure

from shinysim.io import source_channel
from shinysim.recon.detect import (
    SPECK_MARGIN,
    _RING_FOOTPRINT,
    FrameError,
    _centroid,
    _split,
    check_frame,
    estimate_noise,
    noise_k,
    reference_level,
    smoothed_frames,
    threshold_level,
)
from shinysim.recon.pipeline import SPARSE_FRACTION, _finish

_COLUMNS = ("row", "col", "area", "peak", "sum", "blob", "part")


def reference_hot_pixel_mask(frames, sigmas, k):
    """Pixels that exceed all eight neighbours by more than ``k`` sigma in at least half of the frames."""
    frames = np.asarray(frames, dtype=np.float64)
    n = len(frames)
    if n < 4:
        return np.zeros(frames.shape[1:], bool)
    count = np.zeros(frames.shape[1:], int)
    for f, sigma in zip(frames, sigmas):
        count += (f - ndimage.maximum_filter(f, footprint=_RING_FOOTPRINT, mode="nearest")) > max(k * sigma, 0.0)
    return count >= n / 2


def reference_regions(frame, level, params, *, mask=None, name="frame", noise=0.0, raw=None, saturation=None,
                      background=0.0):
    """:func:`shinysim.recon.detect.detect_regions` written with regionprops, region by region."""
    raw = frame if raw is None else raw
    if noise > 0 and frame.size:
        level = max(level, float(np.median(frame)) + noise)
    above = frame >= level
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != frame.shape:
            raise FrameError(f"mask shape {mask.shape} differs from frame shape {frame.shape}", field=name)
        above &= mask
    out = {k: [] for k in _COLUMNS + ("saturated", "cut", "region_area")}
    frame_clipped = saturation is not None and raw.size > 0 and float(raw.max()) >= saturation
    if above.any() and params.threshold_mode == "highlight":
        # each region's pixels at or above the threshold fraction of its own peak, labelled again
        core = np.zeros_like(above)
        for region in measure.regionprops(measure.label(above, connectivity=params.connectivity)):
            rr, cc = region.coords[:, 0], region.coords[:, 1]
            keep = frame[rr, cc] >= params.threshold * frame[rr, cc].max()
            core[rr[keep], cc[keep]] = True
        above = core
    if above.any():
        labels = measure.label(above, connectivity=params.connectivity)
        for region in measure.regionprops(labels):
            coords = region.coords.astype(float)
            values = frame[region.coords[:, 0], region.coords[:, 1]]
            if noise > 0 and values.max() < level + noise:
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
            for j, idx in enumerate(_split(coords, weights, n_parts)):
                r, c = _centroid(coords[idx], weights[idx], params.centroid)
                out["row"].append(r)
                out["col"].append(c)
                out["area"].append(len(idx))
                out["peak"].append(weights[idx].max())
                out["sum"].append(weights[idx].sum())
                out["blob"].append(region.label)
                out["part"].append(0 if n_parts == 1 else j + 1)
                out["saturated"].append(clipped and params.saturated == "flag")
                r0, c0, r1, c1 = region.bbox
                out["cut"].append(r0 == 0 or c0 == 0 or r1 == frame.shape[0] or c1 == frame.shape[1])
                out["region_area"].append(int(region.area))
    dtypes = {"row": float, "col": float, "peak": float, "sum": float, "saturated": bool, "cut": bool}
    return {k: np.asarray(v, dtype=dtypes.get(k, int)) for k, v in out.items()}


def reference_detect_stack(stack, params, mask=None):
    """:func:`shinysim.recon.pipeline.detect_stack` over whole float64 frames, region by region."""
    saturation = params.saturation if params.saturation is not None else stack.saturation
    raw = np.stack([check_frame(stack.frames[k], params, source_channel(k), saturation)
                    for k in range(stack.n_sources)])
    k_noise = noise_k(raw[0].size, params.false_alarm)
    n_hot = 0
    frames = raw

    def noise_of(frames):
        return [params.noise_sigma if params.noise_sigma is not None else estimate_noise(f) for f in frames]

    sigmas = None
    if params.hot_pixels:
        sigmas = noise_of(raw)
        hot = reference_hot_pixel_mask(raw, sigmas, max(k_noise, 3.0))
        n_hot = int(hot.sum())
        if n_hot:
            frames = raw.copy()
            for f in frames:
                f[hot] = ndimage.median_filter(f, size=3, mode="nearest")[hot]
    if params.smooth_px > 0:
        frames = smoothed_frames(frames, params.smooth_px)
    reference = reference_level(frames)
    if sigmas is None or frames is not raw:
        sigmas = noise_of(frames)
    backgrounds = [float(np.median(f)) if params.subtract_background else 0.0 for f in frames]
    per_frame = []
    # the lone lit pixels of the frames with exact-zero backgrounds (more than half of them zero), by filter
    lit = frames > 0
    alone = lit & ~ndimage.maximum_filter(lit, footprint=np.array([[[1, 1, 1], [1, 0, 1], [1, 1, 1]]], bool),
                                          mode="constant")
    sparse = [np.count_nonzero(f) <= f.size * SPARSE_FRACTION for f in frames]
    specks = max((float(f[a].max()) for f, a, sp in zip(frames, alone, sparse) if sp and a.any()), default=0.0)
    for k in range(stack.n_sources):
        frame = frames[k]
        if params.threshold_mode == "scan":
            level = params.threshold * reference if reference > 0 else np.inf
        elif params.threshold_mode == "highlight":
            level = threshold_level(frame, params, reference=reference, floor=SPECK_MARGIN * specks,
                                    background=float(np.median(frame)))
        else:
            level = threshold_level(frame, params)
        per_frame.append(reference_regions(frame, level, params, mask=mask, name=source_channel(k),
                                           noise=k_noise * sigmas[k], raw=raw[k], saturation=saturation,
                                           background=backgrounds[k]))
    rows = {k: np.concatenate([f[k] for f in per_frame]) for k in _COLUMNS + ("saturated", "cut", "region_area")}
    rows["source"] = np.concatenate([np.full(len(f["row"]), k) for k, f in enumerate(per_frame)])
    return _finish(stack, params, rows, reference, k_noise, sigmas, backgrounds, n_hot, saturation)
