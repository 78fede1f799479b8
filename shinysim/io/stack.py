"""Stack and truth files: the contract between simulation and reconstruction.

A *scan folder* holds::

    rig.json     the rig (sources, cameras) plus provenance   (shinysim-rig/2)
    stack.exr    one channel per source, S000 ... S{n-1}       (shinysim-stack/1)
    truth.exr    normals, positions, mask at pixel centres     (shinysim-truth/1)
                 (simulated scans only)

``docs/file-format.md`` specifies the files so that they can be written from
real camera frames. Readers check everything they rely on and raise
:class:`StackFormatError` naming the file and the problem. Writers never
replace an existing file unless asked to (``overwrite=True``), and write
through a temporary file so a failed write leaves nothing half-written
(:func:`shinysim._shared.write_file`, the package's one writer).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._shared import check_choice, refuse_existing, write_file, write_text
from ..errors import OptionError, StackFormatError
from ..rig import Camera, Rig
from .rig import load_rig

__all__ = [
    "StackFormatError",
    "Stack",
    "Truth",
    "STACK_FORMAT",
    "TRUTH_FORMAT",
    "STACK_DTYPES",
    "MAX_PIXELS",
    "source_channel",
    "choose_stack_dtype",
    "save_frame",
    "read_exr_header",
    "read_exr_channels",
    "exr_channel_names",
    "save_stack",
    "load_stack",
    "save_truth",
    "load_truth",
    "check_frames",
]

STACK_FORMAT = "shinysim-stack/1"
TRUTH_FORMAT = "shinysim-truth/1"


def source_channel(k):
    """EXR channel name of source ``k``'s frame: ``S000``, ``S001``, ..."""
    return f"S{k:03d}"


# -- data ------------------------------------------------------------------------


@dataclass
class Stack:
    """Per-source highlight images of one camera.

    Parameters
    ----------
    frames : (n_sources, H, W) float32
        Linear intensity, one frame per source, in source order.
    rig : Rig
    camera_index : int
        Which of ``rig.cameras`` took the frames.
    provenance : dict
        How the frames were made (renderer versions, variant, spp, seed) or
        captured; free JSON.
    saturation : float or None
        The pixel value at which the sensor clips (1.0 for frames read from
        8- or 16-bit image files, which are scaled to [0, 1]); None when
        there is no known clip level (float renders). Detection flags or
        refuses highlights that reach it (``DetectParams.saturated``).
    """

    frames: np.ndarray
    rig: Rig
    camera_index: int = 0
    provenance: dict[str, Any] = field(default_factory=dict)
    saturation: float | None = None

    def __post_init__(self):
        self.frames = np.asarray(self.frames, dtype=np.float32)
        check_frames(self.frames, self.rig, self.camera_index)
        if self.saturation is not None:
            sat = self.saturation
            if isinstance(sat, bool) or not isinstance(sat, (int, float, np.number)) or not (np.isfinite(sat) and sat > 0):
                raise StackFormatError(f"must be a finite level > 0 or None, got {sat!r}", field="saturation")
            self.saturation = float(sat)

    @property
    def camera(self) -> Camera:
        return self.rig.cameras[self.camera_index]

    @property
    def n_sources(self) -> int:
        return self.frames.shape[0]


@dataclass
class Truth:
    """Ground truth at pixel centres of one camera.

    Parameters
    ----------
    normals : (H, W, 3) float32
        Unit surface normals, NaN off the object.
    positions : (H, W, 3) float32, millimetres
        Surface points hit by the pixel-centre rays, NaN off the object.
    mask : (H, W) bool
        Pixel-centre ray hits the object.
    part : (H, W) int32
        Part id per pixel (0 = background/none); names in ``part_names``.
    part_names : list of str
    metadata : dict
    coverage : (H, W) float32 in [0, 1], optional
        Fraction of each pixel's area that images the object (from a grid of
        sub-pixel rays): 1 inside, 0 outside, between at silhouettes. None
        when not rendered.
    """

    normals: np.ndarray
    positions: np.ndarray
    mask: np.ndarray
    part: np.ndarray | None = None
    part_names: list[str] = field(default_factory=lambda: ["background", "object"])
    metadata: dict[str, Any] = field(default_factory=dict)
    coverage: np.ndarray | None = None

    def __post_init__(self):
        self.mask = np.asarray(self.mask, dtype=bool)
        shape = self.mask.shape
        if len(shape) != 2:
            raise StackFormatError(f"truth mask must be (H, W), got shape {shape}")
        self.normals = np.asarray(self.normals, dtype=np.float32)
        self.positions = np.asarray(self.positions, dtype=np.float32)
        for name in ("normals", "positions"):
            arr = getattr(self, name)
            if arr.shape != shape + (3,):
                raise StackFormatError(f"truth {name} must have shape {shape + (3,)}, got {arr.shape}")
        if self.part is None:
            self.part = self.mask.astype(np.int32)
        self.part = np.asarray(self.part, dtype=np.int32)
        if self.part.shape != shape:
            raise StackFormatError(f"truth part must have shape {shape}, got {self.part.shape}")
        if self.coverage is not None:
            self.coverage = np.asarray(self.coverage, dtype=np.float32)
            if self.coverage.shape != shape:
                raise StackFormatError(f"truth coverage must have shape {shape}, got {self.coverage.shape}")
            if not np.all((self.coverage >= 0) & (self.coverage <= 1)):
                raise StackFormatError("truth coverage must lie in [0, 1]")


def check_frames(frames, rig, camera_index=0, *, what="stack"):
    """Check that frames agree with their rig; raise StackFormatError if not.

    Checks the array rank, the number of frames against the number of
    sources, the frame size against the camera, and that every pixel is
    finite and >= 0 (intensities are linear and non-negative): NaN/inf and
    negative pixels are named with the frames that hold them and their count.
    """
    if not isinstance(rig, Rig):
        raise StackFormatError(f"rig must be a shinysim Rig, got {type(rig).__name__}", field=what)
    if isinstance(camera_index, bool) or not isinstance(camera_index, (int, np.integer)) \
            or not 0 <= camera_index < len(rig.cameras):
        raise StackFormatError(f"is {camera_index!r} but the rig has {len(rig.cameras)} camera(s)",
                               field="camera_index")
    if frames.ndim != 3:
        raise StackFormatError(f"frames must be (n_sources, H, W), got shape {frames.shape}", field=what)
    if frames.shape[0] != rig.n_sources:
        raise StackFormatError(f"has {frames.shape[0]} frames but the rig has {rig.n_sources} sources", field=what)
    cam = rig.cameras[camera_index]
    if frames.shape[1:] != cam.shape:
        raise StackFormatError(
            f"frames are {frames.shape[1]}x{frames.shape[2]} (H x W) but camera "
            f"{cam.name!r} is {cam.height}x{cam.width}", field=what)
    flat = frames.reshape(len(frames), -1)
    for test, words in ((lambda f: ~np.isfinite(f), "NaN or inf"), (lambda f: f < 0, "negative")):
        with np.errstate(invalid="ignore"):
            bad = test(flat)
        if bad.any():
            counts = bad.sum(axis=1)
            which = np.flatnonzero(counts)
            shown = ", ".join(f"{source_channel(k)} ({counts[k]})" for k in which[:8])
            raise StackFormatError(
                f"{int(counts.sum())} {words} pixel(s) in frame(s) {shown}{' ...' if len(which) > 8 else ''}"
                + ("; intensities are linear and >= 0" if words == "negative" else ""), field=what)


# -- EXR ----------------------------------------------------------------------------

#: Largest image a reader allocates, pixels per channel (a hostile header can
#: claim any size; 2**26 = 8192 x 8192 is four times the largest frame a
#: 2-core renderer writes in a day).
MAX_PIXELS = 2**26
#: float16 range that ``save_stack`` stores without loss of its ~3 digits:
#: the largest finite half (65504) and the smallest normal one (2**-14);
#: a pixel below it keeps fewer than 11 significant bits.
FLOAT16_MAX = 65504.0
FLOAT16_MIN_NORMAL = 2.0**-14
#: Pixels at or above this fraction of a stack's peak must keep float16's
#: full precision (below it, subnormal rounding error stays < 1e-3 of the peak).
FLOAT16_KEEP_FRACTION = 1e-3


def _write_exr(path, channels, attrs, overwrite):
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    header.update(attrs)

    def write(tmp):
        with OpenEXR.File(header, channels) as f:
            f.write(tmp)

    write_file(path, write, overwrite=overwrite)


def save_frame(frame: np.ndarray, path: str | os.PathLike, *, overwrite: bool = False,
               attributes: dict[str, str] | None = None) -> None:
    """Write one grey float32 image as an OpenEXR file (channel ``Y``), atomically.

    What ``shinysim.io.frames.read_frame`` and ``shinysim reconstruct
    --frames`` read back bit for bit; e.g. a rendered hole-plate image.

    Parameters
    ----------
    frame : (H, W) array_like, finite
    attributes : dict of str -> str, optional
        Extra header attributes (e.g. ``{"shinysim.placement": json}``).
    """
    arr = np.ascontiguousarray(frame, dtype=np.float32)
    if arr.ndim != 2 or arr.size == 0:
        raise StackFormatError(f"a frame must be a non-empty 2-D image, got shape {arr.shape}", path=path)
    if not np.all(np.isfinite(arr)):
        raise StackFormatError("a frame must be finite (NaN or inf pixels)", path=path)
    _write_exr(path, {"Y": arr}, dict(attributes or {}), overwrite)


def _window(header, key, path):
    try:
        (x0, y0), (x1, y1) = header[key]
        x0, y0, x1, y1 = (int(v) for v in (x0, y0, x1, y1))
    except (KeyError, TypeError, ValueError) as exc:
        raise StackFormatError(f"header has no valid {key}: {exc}", path=path, field=key) from None
    if x1 < x0 or y1 < y0:
        raise StackFormatError(f"{key} ({x0}, {y0})-({x1}, {y1}) is empty", path=path, field=key)
    return x0, y0, x1, y1


def read_exr_header(path: str | os.PathLike) -> dict[str, Any]:
    """The header of a single-part, flat OpenEXR file (no pixels are read).

    Raises
    ------
    StackFormatError
        Missing, unreadable, truncated, multi-part or deep files.
    """
    import OpenEXR

    path = Path(path)
    if not path.exists():
        raise StackFormatError("no such file", path=path)
    if not path.is_file():
        raise StackFormatError("not a file", path=path)
    try:
        with OpenEXR.File(str(path), header_only=True) as f:
            n_parts = len(f.parts)
            header = dict(f.header())
    except Exception as exc:  # OpenEXR raises RuntimeError (and others) for any corruption
        raise StackFormatError(f"not a readable OpenEXR file (corrupt or truncated?): {exc}", path=path) from None
    if n_parts != 1:
        raise StackFormatError(f"has {n_parts} parts; shinysim reads single-part files", path=path)
    for key, value in header.items():
        try:  # OpenEXR decodes channel names and attribute type names only when they are shown
            repr(value)
        except UnicodeDecodeError:
            raise StackFormatError("holds a name that is not UTF-8 text (corrupt header?)", path=path,
                                   field=key) from None
    storage = str(header.get("type", ""))
    if "deep" in storage.lower():
        raise StackFormatError(f"is a deep image ({storage}); shinysim reads flat images", path=path, field="type")
    return header


def exr_channel_names(header: dict[str, Any]) -> list[str]:
    """Channel names listed in an EXR header."""
    return [getattr(ch, "name", str(ch)) for ch in header.get("channels", [])]


def read_exr_channels(path: str | os.PathLike, *, shape: tuple[int, int] | None = None,
                      fmt: str | None = None, header: dict[str, Any] | None = None
                      ) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Header and channels of a single-part, flat OpenEXR file (scanline or tiled).

    The image is the file's *display window*: every channel comes back as a
    (H, W) float32 array of the display window's size, with the stored
    pixels (the *data window*) placed at their offset. Display-window pixels
    outside the data window are 0, as OpenEXR defines them; stored pixels
    outside the display window (overscan) are not part of the image and are
    dropped.

    Parameters
    ----------
    path : path-like
    shape : (H, W), optional
        The size the image must have (a camera's): checked before any pixel
        is read, naming both sizes.
    fmt : str, optional
        Expected ``shinysim_format`` header attribute, when the file has one.
    header : dict, optional
        The file's header if already read (:func:`read_exr_header`).

    Raises
    ------
    StackFormatError
        Missing, unreadable, truncated, multi-part or deep files, sub-sampled
        channels, an empty or oversized display window, a data window that
        misses the display window, a display window that disagrees with
        ``shape``, a wrong ``shinysim_format``.
    """
    import OpenEXR

    path = Path(path)
    if header is None:
        header = read_exr_header(path)
    found = header.get("shinysim_format")
    if fmt is not None and found is not None and (not isinstance(found, str) or found != fmt):
        raise StackFormatError(f"file format is {found!r}, expected {fmt!r}", path=path, field="shinysim_format")
    dx0, dy0, dx1, dy1 = _window(header, "displayWindow", path)
    x0, y0, x1, y1 = _window(header, "dataWindow", path)
    H, W = dy1 - dy0 + 1, dx1 - dx0 + 1
    if H * W > MAX_PIXELS or (x1 - x0 + 1) * (y1 - y0 + 1) > MAX_PIXELS:
        raise StackFormatError(f"image of {W} x {H} pixels is larger than shinysim reads ({MAX_PIXELS} pixels)",
                               path=path, field="displayWindow")
    if shape is not None and (H, W) != tuple(shape):
        raise StackFormatError(
            f"display window is {H}x{W} (H x W) but the camera is {shape[0]}x{shape[1]}", path=path,
            field="displayWindow")
    if x1 < dx0 or x0 > dx1 or y1 < dy0 or y0 > dy1:
        raise StackFormatError(
            f"data window ({x0}, {y0})-({x1}, {y1}) lies outside the display window "
            f"({dx0}, {dy0})-({dx1}, {dy1}): no pixel of the image is stored", path=path, field="dataWindow")
    n_channels = len(header.get("channels", []))
    if n_channels * max(H * W, (x1 - x0 + 1) * (y1 - y0 + 1)) > 16 * MAX_PIXELS:
        raise StackFormatError(f"{n_channels} channels of {W} x {H} pixels are more than shinysim reads "
                               f"({16 * MAX_PIXELS} pixels in all)", path=path, field="channels")
    for ch in header.get("channels", []):
        xs, ys = getattr(ch, "xSampling", 1), getattr(ch, "ySampling", 1)
        if (xs, ys) != (1, 1):
            raise StackFormatError(f"is sub-sampled ({xs} x {ys}); shinysim reads full-resolution channels",
                                   path=path, field=f"channel {getattr(ch, 'name', '?')}")
    try:
        # one 2-D array per channel, as the header lists them (not R, G, B merged into "RGB")
        with OpenEXR.File(str(path), separate_channels=True) as f:
            stored = {name: np.asarray(ch.pixels) for name, ch in f.channels().items()}
    except Exception as exc:
        raise StackFormatError(f"not a readable OpenEXR file (corrupt or truncated?): {exc}", path=path) from None
    channels = {}
    # the overlap of data and display windows, in display-window and data-window indices
    ox0, oy0, ox1, oy1 = max(x0, dx0), max(y0, dy0), min(x1, dx1), min(y1, dy1)
    for name, pix in stored.items():
        if pix.shape != (y1 - y0 + 1, x1 - x0 + 1):
            raise StackFormatError(f"holds {pix.shape} pixels for a data window of "
                                   f"{y1 - y0 + 1}x{x1 - x0 + 1}", path=path, field=f"channel {name}")
        if not (np.issubdtype(pix.dtype, np.floating) or np.issubdtype(pix.dtype, np.integer)):
            raise StackFormatError(f"has pixel type {pix.dtype}", path=path, field=f"channel {name}")
        img = np.zeros((H, W), np.float32)
        img[oy0 - dy0:oy1 - dy0 + 1, ox0 - dx0:ox1 - dx0 + 1] = pix[oy0 - y0:oy1 - y0 + 1, ox0 - x0:ox1 - x0 + 1]
        channels[name] = img
    return header, channels


def _int_attr(header, key, path, default):
    value = header.get(key, default)
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise StackFormatError(f"header attribute must be an integer, got {value!r}", path=path, field=key)
    return int(value)


def _json_attr(header, key, path, default):
    """A JSON-valued string attribute, parsed, or ``default`` when absent."""
    value = header.get(key)
    if value is None:
        return default
    if isinstance(value, bytes):
        try:
            value = value.decode("utf-8")
        except UnicodeDecodeError:
            raise StackFormatError("header attribute is not UTF-8 text", path=path, field=key) from None
    if not isinstance(value, str):
        raise StackFormatError(f"header attribute must be a JSON string, got {type(value).__name__}",
                               path=path, field=key)
    try:
        parsed = json.loads(value)
    except (ValueError, RecursionError) as exc:  # ValueError: also a number too long to convert
        raise StackFormatError(f"header attribute is not valid JSON: {str(exc).split(';')[0]}", path=path,
                               field=key) from None
    if not isinstance(parsed, type(default)):
        raise StackFormatError(f"header attribute must hold a JSON {type(default).__name__}, "
                               f"got {type(parsed).__name__}", path=path, field=key)
    return parsed


def _layer_frame(channels, name, path):
    """Source ``name``'s frame: channel ``name``, or its layer ``name.Y`` / ``name.R,G,B[,A]``.

    A colour layer is reduced by the maximum over R, G, B (as
    :func:`shinysim.io.frames.read_frame` does by default); an alpha
    channel is never intensity. None when the source has no channel.
    """
    if name in channels:
        return channels[name]
    layer = {c.split(".", 1)[1]: v for c, v in channels.items() if c.split(".", 1)[0] == name and "." in c}
    if not layer:
        return None
    if "Y" in layer:
        return layer["Y"]
    if {"R", "G", "B"} <= set(layer):
        return np.maximum(np.maximum(layer["R"], layer["G"]), layer["B"])
    colour = [c for c in layer if c not in ("A", "alpha")]
    if len(colour) == 1:
        return layer[colour[0]]
    raise StackFormatError(
        f"layer {name} has channels {', '.join(sorted(layer))}; expected one channel, Y, or R, G, B (alpha ignored)",
        path=path, field=f"channel {name}")


def choose_stack_dtype(frames: np.ndarray, *, exact: bool = False) -> tuple[str, str]:
    """The pixel type a stack needs, and why.

    float16 when every pixel fits (peak <= 65504) and every pixel at or above
    :data:`FLOAT16_KEEP_FRACTION` of the peak is a normal half (>= 2**-14),
    keeping its 11 significant bits; float32 otherwise. With ``exact`` (a
    digitised stack, whose pixels are codes of a sensor: 12- and 16-bit
    codes need more than float16's 11 bits), float16 only when no two
    different pixel values become one.

    Returns
    -------
    dtype : {"float16", "float32"}
    reason : str
        One line, for logs.
    """
    peak = float(np.max(frames)) if np.size(frames) else 0.0
    if peak > FLOAT16_MAX:
        return "float32", f"peak {peak:.4g} is above float16's largest value {FLOAT16_MAX:g}"
    if 0 < peak * FLOAT16_KEEP_FRACTION < FLOAT16_MIN_NORMAL:
        return "float32", (f"peak {peak:.4g} is so small that float16 would lose precision below "
                           f"{FLOAT16_MIN_NORMAL:.3g} (its smallest normal value)")
    if exact:
        values = np.unique(np.asarray(frames, np.float32))
        if len(np.unique(values.astype(np.float16))) < len(values):
            return "float32", "float16 would merge neighbouring sensor codes (more than its 11 significant bits)"
        return "float16", "float16 keeps every sensor code apart"
    return "float16", f"peak {peak:.4g} fits float16"


# -- stack -------------------------------------------------------------------------

#: Pixel types :func:`save_stack` accepts ("auto" picks with :func:`choose_stack_dtype`).
STACK_DTYPES = ("auto", "float16", "float32")


def save_stack(stack: Stack, path: str | os.PathLike, *, rig_path: str | os.PathLike | None = None,
               dtype: str = "auto", overwrite: bool = False) -> tuple[str, str]:
    """Write a stack EXR and its rig JSON.

    Parameters
    ----------
    stack : Stack
    path : path-like
        The ``.exr`` file to write.
    rig_path : path-like, optional
        Rig JSON to write beside it; default ``rig.json`` in the same folder.
    dtype : {"auto", "float16", "float32"}
        Pixel type. float16 with ZIP keeps about 3 significant digits
        (relative error < 1e-3 of the peak) in a fraction of the size, but
        only over its range; "auto" (default) takes float16 where the stack
        fits it and float32 where it does not (:func:`choose_stack_dtype`).
        An explicit "float16" for a stack that does not fit is refused.
    overwrite : bool
        Replace existing files. Without it nothing existing is touched: both
        targets are checked before either is written.

    Returns
    -------
    dtype, reason : str
        The pixel type written and why (one line, for the log).
    """
    check_choice("dtype", dtype, STACK_DTYPES)
    path = Path(path)
    rig_path = path.with_name("rig.json") if rig_path is None else Path(rig_path)
    for p in (path, rig_path):
        refuse_existing(p, overwrite)
    needed, reason = choose_stack_dtype(stack.frames, exact=stack.saturation is not None)
    if dtype == "float16" and needed != "float16":
        raise OptionError(f"dtype 'float16' cannot hold this stack: {reason}; use dtype 'auto' or 'float32'")
    chosen = needed if dtype == "auto" else dtype
    channels = {source_channel(k): stack.frames[k].astype(chosen) for k in range(stack.n_sources)}
    attrs = {
        "shinysim_format": STACK_FORMAT,
        "n_sources": int(stack.n_sources),
        "camera_index": int(stack.camera_index),
        "provenance": json.dumps(stack.provenance, sort_keys=True),
    }
    if stack.saturation is not None:
        attrs["saturation"] = float(stack.saturation)
    doc = stack.rig.to_dict()
    doc["provenance"] = stack.provenance
    write_text(rig_path, json.dumps(doc, indent=2) + "\n", overwrite=overwrite)
    _write_exr(path, channels, attrs, overwrite)
    return chosen, reason


def load_stack(path: str | os.PathLike, rig: Rig | str | os.PathLike | None = None) -> Stack:
    """Read a stack EXR and check it against its rig.

    Parameters
    ----------
    path : path-like
        The stack ``.exr``.
    rig : Rig or path-like, optional
        The rig, or its JSON file; default ``rig.json`` beside the stack.

    Raises
    ------
    StackFormatError
        Unreadable or truncated file, missing ``S###`` channels, a frame
        count or size that disagrees with the rig, NaN/inf or negative
        pixels, a malformed header attribute; :class:`RigError` for an
        invalid rig file (naming it).
    """
    path = Path(path)
    provenance = {}
    if not isinstance(rig, Rig):
        rig_path = path.with_name("rig.json") if rig is None else Path(rig)
        rig, doc = load_rig(rig_path, with_document=True)
        provenance = doc.get("provenance", {})
    header = read_exr_header(path)
    n = rig.n_sources
    camera_index = _int_attr(header, "camera_index", path, 0)
    if not 0 <= camera_index < len(rig.cameras):
        raise StackFormatError(f"is {camera_index} but the rig has {len(rig.cameras)} camera(s)", path=path,
                               field="camera_index")
    names = [source_channel(k) for k in range(n)]
    listed = exr_channel_names(header)
    heads = {c.split(".", 1)[0] for c in listed}  # a source's channel, or its layer's name
    missing = [nm for nm in names if nm not in heads]
    if missing:
        shown = ", ".join(sorted(listed)[:12]) + (" ..." if len(listed) > 12 else "")
        raise StackFormatError(
            f"missing channel(s) {', '.join(missing[:12])}{' ...' if len(missing) > 12 else ''} for the rig's "
            f"{n} sources (found {shown or 'none'})", path=path, field="channels")
    extra = sorted(h for h in heads - set(names) if h[:1] == "S" and h[1:].isdigit())
    if extra:
        raise StackFormatError(f"has frames {', '.join(extra[:12])} beyond the rig's {n} sources", path=path,
                               field="channels")
    n_header = _int_attr(header, "n_sources", path, n)
    if n_header != n:
        raise StackFormatError(f"header says {n_header} sources but the rig has {n}", path=path, field="n_sources")
    header, channels = read_exr_channels(path, shape=rig.cameras[camera_index].shape, fmt=STACK_FORMAT,
                                         header=header)
    frames = np.stack([_layer_frame(channels, nm, path) for nm in names]).astype(np.float32)
    provenance = _json_attr(header, "provenance", path, provenance)
    saturation = header.get("saturation")
    if saturation is not None and (isinstance(saturation, bool) or not isinstance(saturation, (int, float))
                                   or not (math.isfinite(saturation) and saturation > 0)):
        raise StackFormatError(f"must be a finite level > 0, got {saturation!r}", path=path, field="saturation")
    try:
        return Stack(frames, rig, camera_index, provenance, saturation)
    except StackFormatError as exc:
        raise StackFormatError(exc.problem, path=path, field=exc.field) from None


# -- truth ------------------------------------------------------------------------

_TRUTH_CHANNELS = ["normal.X", "normal.Y", "normal.Z", "position.X", "position.Y", "position.Z", "mask"]


def save_truth(truth: Truth, path: str | os.PathLike, *, overwrite: bool = False) -> None:
    """Write a truth EXR (float32 normals and positions, mask, part ids)."""
    channels = {f"{name}.{a}": values[..., i] for name, values in (("normal", truth.normals), ("position", truth.positions))
                for i, a in enumerate("XYZ")}
    channels.update(mask=truth.mask.astype(np.float32), part=truth.part.astype(np.float32))
    if truth.coverage is not None:
        channels["coverage"] = truth.coverage
    channels = {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in channels.items()}
    attrs = {
        "shinysim_format": TRUTH_FORMAT,
        "part_names": json.dumps(list(truth.part_names)),
        "metadata": json.dumps(truth.metadata),
    }
    _write_exr(path, channels, attrs, overwrite)


def load_truth(path: str | os.PathLike, camera: Camera | None = None) -> Truth:
    """Read a truth EXR; optionally check its size against a camera.

    Raises
    ------
    StackFormatError
        Unreadable file, missing channels, a size that disagrees with the
        camera, normals that are not finite unit vectors inside the mask,
        malformed ``part_names`` or ``metadata`` attributes.
    """
    path = Path(path)
    header, channels = read_exr_channels(path, shape=None if camera is None else camera.shape, fmt=TRUTH_FORMAT)
    missing = [c for c in _TRUTH_CHANNELS if c not in channels]
    if missing:
        raise StackFormatError(f"missing truth channel(s) {', '.join(missing)}", path=path, field="channels")
    normals = np.stack([channels[f"normal.{a}"] for a in "XYZ"], axis=-1)
    positions = np.stack([channels[f"position.{a}"] for a in "XYZ"], axis=-1)
    mask = channels["mask"] > 0.5
    part = None
    if "part" in channels:
        p = channels["part"]
        if not np.all(np.isfinite(p)) or np.any(p < 0) or np.any(p != np.round(p)) or np.any(p >= 2.0**31):
            raise StackFormatError("part ids must be whole numbers from 0 to 2**31 - 1", path=path,
                                   field="channel part")
        part = p.astype(np.int32)
    n_in = normals[mask]
    if not np.all(np.isfinite(n_in)):
        raise StackFormatError(f"{int((~np.isfinite(n_in).all(axis=1)).sum())} normal(s) inside the mask are not "
                               "finite", path=path, field="normal")
    length = np.linalg.norm(n_in.astype(np.float64), axis=1)
    # float32 storage keeps unit length to ~1e-7; 1e-3 allows half-precision writers too
    if np.any(np.abs(length - 1) > 1e-3):
        raise StackFormatError(f"{int((np.abs(length - 1) > 1e-3).sum())} normal(s) inside the mask are not unit "
                               "vectors", path=path, field="normal")
    if not np.all(np.isfinite(positions[mask])):
        raise StackFormatError("positions inside the mask are not finite", path=path, field="position")
    part_names = _json_attr(header, "part_names", path, ["background", "object"])
    if not all(isinstance(nm, str) for nm in part_names):
        raise StackFormatError("must be a JSON list of strings", path=path, field="part_names")
    if part is not None and part.size and part.max() >= len(part_names):
        raise StackFormatError(f"part id {int(part.max())} has no name (part_names has {len(part_names)})",
                               path=path, field="channel part")
    metadata = _json_attr(header, "metadata", path, {})
    coverage = channels.get("coverage")
    if coverage is not None and not np.all((coverage >= 0) & (coverage <= 1)):
        raise StackFormatError("coverage must lie in [0, 1]", path=path, field="channel coverage")
    try:
        return Truth(normals, positions, mask, part, part_names, metadata, coverage)
    except StackFormatError as exc:
        raise StackFormatError(exc.problem, path=path, field=exc.field) from None
