"""From a stack of per-source frames to a highlight table and sparse normals."""

from __future__ import annotations

import csv
from dataclasses import dataclass, field

import numpy as np

from .._shared import with_overrides, write_text
from ..io import Stack, StackFormatError, source_channel
from .detect import DetectParams, detect_highlights
from .normals import NORMAL_MODELS, highlight_normals

__all__ = ["Reconstruction", "reconstruct", "sparse_normal_map", "read_highlight_table"]


@dataclass
class Reconstruction:
    """Highlights of a stack and their normals under each camera model.

    Attributes
    ----------
    table : dict of (N,) ndarray
        One row per highlight: ``source``, ``row``, ``col``, ``area``,
        ``peak``, ``sum``, ``blob``, ``part``.
    normals : dict of str -> (N, 3) ndarray
        Unit normals per camera model name.
    shape : (int, int)
        Image shape (H, W).
    empty_sources : list of int
        Sources whose frame had no highlight.
    params : DetectParams
    """

    table: dict
    normals: dict
    shape: tuple
    empty_sources: list = field(default_factory=list)
    params: DetectParams | None = None

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


def reconstruct(stack, params=None, *, models=NORMAL_MODELS, mask=None, plane_z=None, **kwargs):
    """Detect highlights in every frame and compute normals.

    Parameters
    ----------
    stack : Stack
    params : DetectParams, optional
        Detection settings; keyword arguments override single fields.
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
    frames = stack.frames
    if not np.any(frames > 0):
        raise StackFormatError("stack is empty: no frame has any pixel above zero")
    columns = {k: [] for k in ("source", "row", "col", "area", "peak", "sum", "blob", "part")}
    empty = []
    for k in range(stack.n_sources):
        found = detect_highlights(frames[k], params, mask=mask, name=source_channel(k))
        if len(found["row"]) == 0:
            empty.append(k)
            continue
        columns["source"].append(np.full(len(found["row"]), k))
        for key in ("row", "col", "area", "peak", "sum", "blob", "part"):
            columns[key].append(found[key])
    table = {
        k: (np.concatenate(v) if v else np.array([], dtype=float if k in ("row", "col", "peak", "sum") else int))
        for k, v in columns.items()
    }
    normals = {
        m: highlight_normals(
            table["row"], table["col"], table["source"], stack.rig,
            model=m, camera_index=stack.camera_index, plane_z=plane_z,
        ).reshape(-1, 3)
        for m in models
    }
    return Reconstruction(table, normals, stack.camera.shape, empty, params)
