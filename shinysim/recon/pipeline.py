"""From a stack of per-source frames to a highlight table and sparse normals.

The one stack -> highlights path of shinysim: :func:`detect_stack` finds
every highlight of every frame (threshold relative to each frame's peak, an
absolute level or the scan's reference level; optional smoothing; several
highlights per frame; large blobs subdivided; inter-reflection flags), as
set by one :class:`~shinysim.recon.detect.DetectParams`.
:func:`reconstruct` adds the normals under each camera model;
:func:`~shinysim.recon.highlights.find_highlights` (solder joints) is the
same detection with its own defaults and the surface points on a plane.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from .._shared import check_choice, with_overrides
from ..io import Stack, StackFormatError, source_channel
from ..rig import Anchor
from .detect import (
    AREA_FRACTION,
    DetectParams,
    auto_min_area,
    check_frame,
    detect_regions,
    estimate_noise,
    hot_pixel_mask,
    keep_areas,
    noise_k,
    reference_level,
    smoothed_frames,
    threshold_level,
)
from .nearfield import NEAR_FIELD, near_field_normals
from .normals import NORMAL_MODELS, highlight_normals
from .table import read_highlight_table, write_highlight_table

__all__ = ["Reconstruction", "detect_stack", "reconstruct", "sparse_normal_map", "read_highlight_table"]

_COLUMNS = ("row", "col", "area", "peak", "sum", "blob", "part")
_FLOAT_COLUMNS = ("row", "col", "peak", "sum", "rel_peak")


@dataclass
class Reconstruction:
    """Highlights of a stack and their normals under each camera model.

    Attributes
    ----------
    table : dict of (N,) ndarray
        One row per highlight: ``source``, ``row``, ``col``, ``area``,
        ``peak``, ``sum``, ``blob``, ``part`` (as
        :func:`~shinysim.recon.detect.detect_highlights`), ``rel_peak``
        (peak / the scan's reference level) and ``interreflection`` (the
        flag of ``params.flag_rule``).
    normals : dict of str -> (N, 3) ndarray
        Unit normals per camera model name (empty from :func:`detect_stack`).
    shape : (int, int)
        Image shape (H, W).
    empty_sources : list of int
        Sources whose frame had no highlight.
    params : DetectParams
    reference : float
        The scan's reference level: the brightest pixel of the (smoothed) stack.
    detection : dict
        The values detection used where its settings left them automatic:
        ``min_area`` (and its rule), ``noise_k``, each frame's
        ``noise_sigma``, the number of ``hot_pixels`` replaced, the
        ``saturation`` level and ``n_saturated`` highlights.
    near_field : dict
        The near-field model's convergence and anchor (empty without it).
    notes : list of str
        What a user should know: a model left out or not converged.
    """

    table: dict[str, np.ndarray]
    normals: dict[str, np.ndarray]
    shape: tuple[int, int]
    empty_sources: list[int] = field(default_factory=list)
    params: DetectParams | None = None
    reference: float = 0.0
    detection: dict = field(default_factory=dict)
    near_field: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)

    def __len__(self):
        return len(self.table["source"])

    @property
    def models(self):
        return tuple(self.normals)

    def normal_map(self, model):
        """Sparse (H, W, 3) normal map and (H, W) valid mask for one model."""
        return sparse_normal_map(self.table["row"], self.table["col"], self.normals[model], self.shape)

    def write_table(self, path, *, overwrite=False):
        """Write the highlight table as CSV, one row per highlight and model (:mod:`shinysim.recon.table`)."""
        return write_highlight_table(path, self.table, self.normals, overwrite=overwrite)


def sparse_normal_map(rows, cols, normals, shape):
    """Scatter normals into an image at their (rounded) centroid pixels.

    Returns
    -------
    normal_map : (H, W, 3) float32
        NaN where no highlight landed. Where several highlights round to the
        same pixel, their normals are averaged and renormalised.
    valid : (H, W) bool
    """
    H, W = shape
    r = np.rint(np.asarray(rows, float)).astype(int)
    c = np.rint(np.asarray(cols, float)).astype(int)
    n = np.asarray(normals, float).reshape(-1, 3)
    keep = (r >= 0) & (r < H) & (c >= 0) & (c < W) & np.all(np.isfinite(n), axis=1)
    acc = np.zeros((H * W, 3))
    flat = r[keep] * W + c[keep]
    np.add.at(acc, flat, n[keep])
    count = np.bincount(flat, minlength=H * W)
    valid = count > 0
    out = np.full((H * W, 3), np.nan)
    out[valid] = acc[valid] / np.linalg.norm(acc[valid], axis=1, keepdims=True)
    return out.reshape(H, W, 3).astype(np.float32), valid.reshape(H, W)


def detect_stack(stack: Stack, params: DetectParams | None = None, *, mask: np.ndarray | None = None,
                 **kwargs) -> Reconstruction:
    """Every highlight of every frame of a stack: the one detection pipeline.

    Steps: check every frame (finite, >= 0, not over-exposed at the stack's
    clip level); replace hot pixels (:func:`~shinysim.recon.detect.hot_pixel_mask`);
    smooth (``smooth_px``); estimate each frame's noise; threshold each
    frame (relative, absolute or scan level, raised to the noise floor);
    connected regions, noise islands dropped; the minimum area (given, or
    :func:`~shinysim.recon.detect.auto_min_area` of the stack's regions);
    subdivision of large regions; centroids; saturation and
    inter-reflection flags. ``Reconstruction.detection`` states the values
    used.

    Parameters
    ----------
    stack : Stack
    params : DetectParams, optional
        Keyword arguments override single fields.
    mask : (H, W) bool, optional
        Region to search (e.g. the object silhouette).

    Returns
    -------
    Reconstruction
        The highlight table, without normals.

    Raises
    ------
    FrameError
        A frame with NaN/inf or negative pixels, an over-exposed frame, or
        a saturated highlight with ``saturated="refuse"``, naming it.
    """
    if not isinstance(stack, Stack):
        raise TypeError(f"stack must be a shinysim.io.Stack, got {type(stack).__name__}")
    params = with_overrides(DetectParams, params, kwargs)
    saturation = params.saturation if params.saturation is not None else stack.saturation
    raw = np.stack([check_frame(stack.frames[k], params, source_channel(k), saturation)
                    for k in range(stack.n_sources)])
    n_pixels = raw[0].size
    k_noise = noise_k(n_pixels, params.false_alarm)
    n_hot = 0
    frames = raw

    def noise_of(frames):
        return [params.noise_sigma if params.noise_sigma is not None else estimate_noise(f) for f in frames]

    sigmas = None  # each frame's noise, estimated once from the frames detection uses
    if params.hot_pixels:
        sigmas = noise_of(raw)
        hot = hot_pixel_mask(raw, sigmas, max(k_noise, 3.0))
        n_hot = int(hot.sum())
        if n_hot:
            frames = raw.copy()
            for f in frames:
                f[hot] = ndimage.median_filter(f, size=3, mode="nearest")[hot]
    if params.smooth_px > 0:
        frames = smoothed_frames(frames, params.smooth_px)
    reference = reference_level(frames)
    if sigmas is None or frames is not raw:  # no estimate yet, or the frames changed since
        sigmas = noise_of(frames)
    # each frame's background (dark offset, stray light): its median, as highlights cover few pixels
    backgrounds = [float(np.median(f)) if params.subtract_background else 0.0 for f in frames]
    per_frame = []
    for k in range(stack.n_sources):
        frame = frames[k]
        if params.threshold_mode == "scan":
            level = params.threshold * reference if reference > 0 else np.inf
        else:
            level = threshold_level(frame, params)
        per_frame.append(detect_regions(frame, level, params, mask=mask, name=source_channel(k),
                                        noise=k_noise * sigmas[k], raw=raw[k], saturation=saturation,
                                        background=backgrounds[k]))
    if params.min_area is not None:
        min_area = int(params.min_area)
    else:
        min_area = auto_min_area(np.concatenate([f["region_area"][f["part"] <= 1] for f in per_frame]))
    columns = {k: [] for k in ("source",) + _COLUMNS + ("saturated",)}
    empty = []
    for k, found in enumerate(per_frame):
        found = keep_areas(found, min_area)
        if len(found["row"]) == 0:
            empty.append(k)
        columns["source"].append(np.full(len(found["row"]), k))
        for key in _COLUMNS + ("saturated",):
            columns[key].append(found[key])
    table = {k: np.concatenate(v) for k, v in columns.items()}
    for key in table:
        table[key] = table[key].astype(bool if key == "saturated" else float if key in _FLOAT_COLUMNS else int)
    n = len(table["row"])
    table["rel_peak"] = table["peak"] / reference if reference > 0 else np.zeros(n)
    if params.flag_rule == "dim":
        table["interreflection"] = table["rel_peak"] < params.dim_fraction
    else:
        table["interreflection"] = np.zeros(n, bool)
    detection = {
        "min_area": min_area,
        "min_area_rule": "given" if params.min_area is not None else
        f"{AREA_FRACTION:g} of the median highlight area",
        "noise_k": k_noise,
        "noise_sigma": [float(v) for v in sigmas],
        "background": [float(v) for v in backgrounds],
        "hot_pixels": n_hot,
        "saturation": saturation,
        "n_saturated": int(table["saturated"].sum()),
    }
    return Reconstruction(table, {}, stack.camera.shape, empty, params, reference, detection)


def reconstruct(stack: Stack, params: DetectParams | None = None, *, models: tuple[str, ...] = NORMAL_MODELS,
                mask: np.ndarray | None = None, plane_z: float | None = None, anchor: Anchor | None = None,
                **kwargs) -> Reconstruction:
    """Detect highlights in every frame and compute normals.

    Parameters
    ----------
    stack : Stack
    params : DetectParams, optional
        Detection settings (:func:`detect_stack`); keyword arguments
        override single fields.
    models : sequence of str
        Normal models to compute (see :data:`shinysim.recon.normals.NORMAL_MODELS`).
        ``"near-field"`` needs an anchor: without one (``anchor`` or the
        rig's), it is left out and ``Reconstruction.notes`` says so.
    mask : (H, W) bool, optional
        Region to search (e.g. the object silhouette).
    plane_z : float, optional
        Reference plane height, millimetres (default ``rig.reference_z``).
    anchor : shinysim.rig.Anchor, optional
        For the near-field model (default ``stack.rig.anchor``).

    Returns
    -------
    Reconstruction
        ``near_field`` holds the near-field model's convergence
        (``converged``, ``iterations``, ``last_step_mm``); a model that did
        not converge is noted in ``notes``.

    Raises
    ------
    StackFormatError
        When no frame of the stack has any signal (an empty stack).
    FrameError
        A frame with NaN/inf pixels, or a saturated frame (see
        ``DetectParams.saturation``), naming the frame.
    """
    if not isinstance(stack, Stack):
        raise TypeError(f"stack must be a shinysim.io.Stack, got {type(stack).__name__}")
    params = with_overrides(DetectParams, params, kwargs)
    for m in models:
        check_choice("model", m, NORMAL_MODELS)
    if not np.any(stack.frames > 0):
        raise StackFormatError("stack is empty: no frame has any pixel above zero")
    recon = detect_stack(stack, params, mask=mask)
    t = recon.table
    anchor = anchor if anchor is not None else stack.rig.anchor
    for m in models:
        if m == NEAR_FIELD:
            if anchor is None:
                recon.notes.append("near-field model left out: no anchor (give the rig an 'anchor', a known "
                                   "surface point or contour, or pass one)")
                continue
            nf = near_field_normals(t["row"], t["col"], t["source"], stack.rig, anchor,
                                    camera_index=stack.camera_index, plane_z=plane_z)
            recon.normals[m] = nf.normals.reshape(-1, 3)
            recon.near_field = {"converged": nf.converged, "iterations": nf.iterations,
                                "last_step_mm": nf.last_step_mm, "anchor": anchor.to_dict()}
            if not nf.converged:
                recon.notes.append(f"near-field model did not converge in {nf.iterations} iterations (last height "
                                   f"step {nf.last_step_mm:.3g} mm); its normals are those of the last step")
            continue
        recon.normals[m] = highlight_normals(
            t["row"], t["col"], t["source"], stack.rig,
            model=m, camera_index=stack.camera_index, plane_z=plane_z,
        ).reshape(-1, 3)
    return recon
