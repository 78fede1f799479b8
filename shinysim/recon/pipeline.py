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

import csv
from dataclasses import dataclass, field

import numpy as np

from .._shared import with_overrides, write_text
from ..io import Stack, StackFormatError, source_channel
from .detect import (
    DetectParams,
    check_frame,
    detect_regions,
    reference_level,
    smoothed_frames,
    threshold_level,
)
from .normals import NORMAL_MODELS, highlight_normals

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
    """

    table: dict[str, np.ndarray]
    normals: dict[str, np.ndarray]
    shape: tuple[int, int]
    empty_sources: list[int] = field(default_factory=list)
    params: DetectParams | None = None
    reference: float = 0.0

    def __len__(self):
        return len(self.table["source"])

    @property
    def models(self):
        return tuple(self.normals)

    def normal_map(self, model):
        """Sparse (H, W, 3) normal map and (H, W) valid mask for one model."""
        return sparse_normal_map(self.table["row"], self.table["col"], self.normals[model], self.shape)

    def write_table(self, path, *, overwrite=False):
        """Write the highlight table as CSV, one row per highlight and model."""
        header = ["source", "row", "col", "area", "peak", "sum", "blob", "part", "model", "nx", "ny", "nz"]
        lines = [",".join(header)]
        t = self.table
        for model, n in self.normals.items():
            for i in range(len(self)):
                lines.append(
                    f"{t['source'][i]},{t['row'][i]:.4f},{t['col'][i]:.4f},{t['area'][i]},"
                    f"{t['peak'][i]:.6g},{t['sum'][i]:.6g},{t['blob'][i]},{t['part'][i]},{model},"
                    f"{n[i, 0]:.8f},{n[i, 1]:.8f},{n[i, 2]:.8f}"
                )
        write_text(path, "\n".join(lines) + "\n", overwrite=overwrite)


def read_highlight_table(path):
    """Read a table written by :meth:`Reconstruction.write_table`.

    Returns
    -------
    table : dict of (N,) ndarray
    normals : dict of str -> (N, 3) ndarray
    """
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    models = list(dict.fromkeys(r["model"] for r in rows))
    first = [r for r in rows if r["model"] == models[0]] if models else []
    ints = ("source", "area", "blob", "part")
    table = {
        k: np.array([int(r[k]) if k in ints else float(r[k]) for r in first])
        for k in ("source", "row", "col", "area", "peak", "sum", "blob", "part")
    }
    normals = {
        m: np.array([[float(r["nx"]), float(r["ny"]), float(r["nz"])] for r in rows if r["model"] == m]).reshape(-1, 3)
        for m in models
    }
    return table, normals


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
        A saturated frame (see ``DetectParams.saturation``), naming it.
    """
    if not isinstance(stack, Stack):
        raise TypeError(f"stack must be a shinysim.io.Stack, got {type(stack).__name__}")
    params = with_overrides(DetectParams, params, kwargs)
    frames = stack.frames
    smooth = params.smooth_px > 0
    if smooth:  # check the raw frames (saturation), then detect on the smoothed ones
        for k in range(stack.n_sources):
            check_frame(frames[k], params, source_channel(k))
        frames = smoothed_frames(frames, params.smooth_px)
    reference = reference_level(frames)
    columns = {k: [] for k in ("source",) + _COLUMNS}
    empty = []
    for k in range(stack.n_sources):
        name = source_channel(k)
        frame = frames[k] if smooth else check_frame(frames[k], params, name)
        if params.threshold_mode == "scan":
            level = params.threshold * reference if reference > 0 else np.inf
        else:
            level = threshold_level(frame, params)
        found = detect_regions(frame, level, params, mask=mask, name=name)
        if len(found["row"]) == 0:
            empty.append(k)
        columns["source"].append(np.full(len(found["row"]), k))
        for key in _COLUMNS:
            columns[key].append(found[key])
    table = {k: np.concatenate(v).astype(float if k in _FLOAT_COLUMNS else int) for k, v in columns.items()}
    n = len(table["row"])
    table["rel_peak"] = table["peak"] / reference if reference > 0 else np.zeros(n)
    if params.flag_rule == "dim":
        table["interreflection"] = table["rel_peak"] < params.dim_fraction
    else:
        table["interreflection"] = np.zeros(n, bool)
    return Reconstruction(table, {}, stack.camera.shape, empty, params, reference)


def reconstruct(stack: Stack, params: DetectParams | None = None, *, models: tuple[str, ...] = NORMAL_MODELS,
                mask: np.ndarray | None = None, plane_z: float | None = None, **kwargs) -> Reconstruction:
    """Detect highlights in every frame and compute normals.

    Parameters
    ----------
    stack : Stack
    params : DetectParams, optional
        Detection settings (:func:`detect_stack`); keyword arguments
        override single fields.
    models : sequence of str
        Camera models to compute normals for (see
        :data:`shinysim.recon.normals.NORMAL_MODELS`).
    mask : (H, W) bool, optional
        Region to search (e.g. the object silhouette).
    plane_z : float, optional
        Reference plane height, millimetres (default ``rig.reference_z``).

    Returns
    -------
    Reconstruction

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
        if m not in NORMAL_MODELS:
            raise ValueError(f"model must be one of {NORMAL_MODELS}, got {m!r}")
    if not np.any(stack.frames > 0):
        raise StackFormatError("stack is empty: no frame has any pixel above zero")
    recon = detect_stack(stack, params, mask=mask)
    t = recon.table
    for m in models:
        recon.normals[m] = highlight_normals(
            t["row"], t["col"], t["source"], stack.rig,
            model=m, camera_index=stack.camera_index, plane_z=plane_z,
        ).reshape(-1, 3)
    return recon
