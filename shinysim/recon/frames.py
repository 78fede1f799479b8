"""Stacks from ordinary camera frames (PNG, TIFF, TGA, ... or EXR).

A user with a real rig has one image per source and a rig description; this
module turns them into a :class:`~shinysim.io.Stack` the reconstruction
reads. Integer images are scaled to [0, 1] by their type's maximum, so the
sensor's clipping level is 1.0.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..io import Stack, StackFormatError

__all__ = ["CHANNEL_REDUCTIONS", "read_frame", "stack_from_frames"]

#: How colour frames become one intensity.
CHANNEL_REDUCTIONS = ("max", "mean", "luminance")


def read_frame(path, *, channel="max"):
    """One image file as a (H, W) float32 array, row 0 at the top.

    Parameters
    ----------
    path : path-like
    channel : {"max", "mean", "luminance"}
        Colour reduction (Rec. 709 weights for "luminance").

    Returns
    -------
    frame : (H, W) float32
    clip : float
        The value at which the sensor saturates (1.0 for integer images,
        inf for float images).
    """
    if channel not in CHANNEL_REDUCTIONS:
        raise ValueError(f"channel must be one of {CHANNEL_REDUCTIONS}, got {channel!r}")
    path = Path(path)
    if not path.is_file():
        raise StackFormatError(f"{path}: no such file")
    try:
        from skimage import io as skio

        img = np.asarray(skio.imread(str(path)))
    except Exception as exc:
        raise StackFormatError(f"{path}: cannot read image: {exc}") from exc
    clip = np.inf
    if np.issubdtype(img.dtype, np.integer):
        clip = 1.0
        img = img.astype(np.float32) / np.iinfo(img.dtype).max
    img = img.astype(np.float32)
    if img.ndim == 3:
        rgb = img[..., :3]
        if channel == "max":
            img = rgb.max(axis=-1)
        elif channel == "mean":
            img = rgb.mean(axis=-1)
        else:
            img = rgb @ np.array([0.2126, 0.7152, 0.0722], np.float32)
    if img.ndim != 2:
        raise StackFormatError(f"{path}: expected a 2-D grey or colour image, got shape {img.shape}")
    return img, clip


def stack_from_frames(paths, rig, *, camera_index=0, channel="max", provenance=None):
    """A :class:`~shinysim.io.Stack` from one image file per source.

    The files are taken in source order; their number and size must match
    the rig (errors name the mismatch).
    """
    paths = [Path(p) for p in paths]
    if len(paths) != rig.n_sources:
        raise StackFormatError(f"{len(paths)} frame files given but the rig has {rig.n_sources} sources")
    frames = []
    clip = np.inf
    for p in paths:
        f, c = read_frame(p, channel=channel)
        frames.append(f)
        clip = min(clip, c)
    shapes = {f.shape for f in frames}
    if len(shapes) != 1:
        raise StackFormatError(f"frame files differ in size: {sorted(shapes)}")
    prov = {"frames": [p.name for p in paths], "channel": channel, "clip": None if np.isinf(clip) else clip}
    prov.update(provenance or {})
    return Stack(np.stack(frames), rig, camera_index, prov)
