"""Stacks from ordinary camera frames (PNG, TIFF, TGA, JPEG, BMP or OpenEXR).

A user with a real rig has one image per source and a rig description;
:func:`stack_from_frames` turns them into a :class:`~shinysim.io.Stack` the
reconstruction reads. The kinds, layouts, alpha, colour and clip level read
are specified in ``docs/file-format.md`` (camera frames). Every problem with
a frame file raises :class:`~shinysim.errors.FrameError` naming the file and
what is wrong; no other exception escapes, whatever the file holds.
"""

from __future__ import annotations

import io
import itertools
import math
import os
import stat
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._shared import check_choice, check_number
from ..errors import FrameError, OptionError, ShinysimError, StackFormatError
from .stack import Stack, read_exr_channels
from ..rig import Rig

__all__ = ["CHANNEL_REDUCTIONS", "read_frame", "stack_from_frames"]

#: How colour frames become one intensity.
CHANNEL_REDUCTIONS = ("max", "mean", "luminance")

#: Rec. 709 luminance weights of R, G, B.
_LUMINANCE = np.array([0.2126, 0.7152, 0.0722], np.float32)

_TGA_SUFFIXES = (".tga", ".tpic", ".icb", ".vda", ".vst")

#: The most pixels a frame may declare (16,384 x 16,384): larger than any camera's
#: frame, and small enough that decoding it cannot exhaust a machine's memory.
MAX_FRAME_PIXELS = 2**28

#: The most image directories (IFDs) a TIFF's chain may hold: a frame is one page,
#: perhaps with reduced-resolution copies. A corrupt offset can make the chain run
#: on (tifffile then walks millions of pages of a 2 kB file).
_TIFF_MAX_IFDS = 64


class _FrameRigError(FrameError, StackFormatError):
    """Frame files that disagree with their rig (count or size): both a frame and a stack problem."""


@dataclass
class _Layout:
    """What a file declares: its format, size, layout and sample type."""

    fmt: str  # "PNG", "TIFF", "TGA", "JPEG", "BMP", "EXR"
    height: int | None = None
    width: int | None = None
    layout: str = ""  # "grey", "grey+alpha", "RGB", "RGBA", "palette", or "" (see the decoded array)
    bits: int | None = None  # declared bits per sample, where it matters
    sample: str = "uint"  # "uint", "float"
    invert: bool = False  # TIFF min-is-white
    page: int = 0  # TIFF: the index of the full-resolution page


@dataclass
class _Frame:
    frame: np.ndarray
    clip: float
    kind: str
    alpha_dropped: bool


# -- public -------------------------------------------------------------------------


def read_frame(path, *, channel="max"):
    """One image file as a (H, W) float32 array, row 0 at the top.

    Parameters
    ----------
    path : path-like
    channel : {"max", "mean", "luminance"}
        Colour reduction (Rec. 709 weights for "luminance"); grey frames
        are read as they are. Alpha is never intensity.

    Returns
    -------
    frame : (H, W) float32
    clip : float
        The value at which the sensor saturates (1.0 for integer images,
        scaled to [0, 1] by their type's maximum; inf for float images).

    Raises
    ------
    FrameError
        Missing, empty, unreadable, truncated or unsupported file; an
        unsupported layout; NaN, inf or negative pixels in a float frame.
    OptionError
        ``channel`` is not one of :data:`CHANNEL_REDUCTIONS`.
    """
    f = _read(path, check_choice("channel", channel, CHANNEL_REDUCTIONS))
    return f.frame, f.clip


def stack_from_frames(paths, rig, *, camera_index=0, channel="max", provenance=None):
    """A :class:`~shinysim.io.Stack` from one image file per source.

    The files are taken in source order; their number must match the rig's
    sources and their size the camera's. They must all be integer images
    (the stack's ``saturation`` is then 1.0) or all float images (no clip
    level, ``saturation`` None). The provenance records the file names, the
    colour reduction, each file's kind and whether an alpha channel was
    dropped; ``provenance`` adds to it.

    Raises
    ------
    FrameError
        Any frame that :func:`read_frame` refuses; a wrong number of files
        or a size that disagrees with the camera (these are also
        :class:`~shinysim.errors.StackFormatError`); frames of mixed sizes
        or of mixed integer and float kinds.
    OptionError
        A bad ``channel``, ``camera_index`` or ``paths``.
    """
    check_choice("channel", channel, CHANNEL_REDUCTIONS)
    if isinstance(paths, (str, bytes, os.PathLike)):
        raise OptionError(f"paths must be a list of frame files, one per source; got the single path {paths!r}")
    try:
        paths = [Path(p) for p in paths]
    except TypeError as exc:
        raise OptionError(f"paths must be a list of frame file paths: {exc}") from None
    if not isinstance(rig, Rig):
        raise OptionError(f"rig must be a shinysim Rig, got {type(rig).__name__}")
    camera_index = check_number("camera_index", camera_index, lo=0, hi=len(rig.cameras) - 1, integer=True)
    cam = rig.cameras[camera_index]
    if len(paths) != rig.n_sources:
        raise _FrameRigError(
            f"{len(paths)} frame files given but the rig has {rig.n_sources} sources "
            "(one frame per source, in source order)",
            field="frames",
        )
    read = [_read(p, channel) for p in paths]

    first = read[0]
    for p, f in zip(paths[1:], read[1:]):
        if f.frame.shape != first.frame.shape:
            raise FrameError(
                f"frames differ in size: this one is {_hw(f.frame.shape)} but {paths[0].name} is "
                f"{_hw(first.frame.shape)} (camera {cam.name!r} is {cam.height}x{cam.width})",
                path=p, field="size",
            )
    if first.frame.shape != cam.shape:
        raise _FrameRigError(
            f"frame is {_hw(first.frame.shape)} but camera {cam.name!r} is {cam.height}x{cam.width} "
            f"(H x W; all {len(paths)} frames are {_hw(first.frame.shape)})",
            path=paths[0], field="size",
        )
    integer = [math.isfinite(f.clip) for f in read]
    if any(integer) and not all(integer):
        i, j = integer.index(True), integer.index(False)
        raise FrameError(
            f"frames mix integer and float images, whose scales differ: {paths[i].name} is "
            f"{read[i].kind} (scaled to [0, 1], clips at 1.0) but {paths[j].name} is {read[j].kind} "
            "(linear, no clip level); convert them to one kind",
            path=paths[j], field="kind",
        )
    clip = 1.0 if all(integer) else None
    prov = {
        "frames": [p.name for p in paths],
        "channel": channel,
        "kinds": [f.kind for f in read],
        "alpha_dropped": [f.alpha_dropped for f in read],
        "clip": clip,
    }
    prov.update(provenance or {})
    return Stack(np.stack([f.frame for f in read]), rig, camera_index, prov, saturation=clip)


# -- reading ------------------------------------------------------------------------


def _hw(shape):
    return f"{shape[0]}x{shape[1]}"


def _check_size(path, shape):
    if shape[0] == 0 or shape[1] == 0:
        raise FrameError(f"image has zero width or height ({_hw(shape)}, H x W)", path=path, field="size")


def _read(path, channel) -> _Frame:
    try:
        path = Path(path)
    except TypeError:
        raise OptionError(f"a frame must be a file path, got {path!r}") from None
    try:
        st = path.stat()
    except FileNotFoundError:
        raise FrameError("no such file", path=path, field="file") from None
    except OSError as exc:
        raise FrameError(f"cannot access the file: {exc.strerror or exc}", path=path, field="file") from None
    if stat.S_ISDIR(st.st_mode):
        raise FrameError("is a directory, not an image file", path=path, field="file")
    if not stat.S_ISREG(st.st_mode):
        raise FrameError("is not a regular file", path=path, field="file")
    if st.st_size == 0:
        raise FrameError("empty file (0 bytes), not an image", path=path, field="file")
    try:
        with open(path, "rb") as fh:
            decl = _declared(fh, path)
    except ShinysimError:
        raise
    except OSError as exc:
        raise FrameError(f"cannot read the file: {exc.strerror or exc}", path=path, field="file") from None
    except Exception as exc:  # any malformed header: never let it escape as anything but FrameError
        raise FrameError(f"malformed image header: {_exc_text(exc)}", path=path, field="header") from None
    _check_size(path, (decl.height, decl.width))
    if decl.height is not None and decl.height * decl.width > MAX_FRAME_PIXELS:
        raise FrameError(
            f"image declares {decl.height}x{decl.width} pixels (H x W), more than the "
            f"{MAX_FRAME_PIXELS:,} a frame may have: a corrupt header?",
            path=path, field="size",
        )
    _check_name(path, decl)
    if decl.fmt == "EXR":
        return _from_exr(path, channel)
    arr = _decode(path, decl)
    return _to_frame(path, arr, decl, channel)


#: The format each usual file name promises (the decoder goes by the name).
_SUFFIX_FORMATS = {".png": "PNG", ".tif": "TIFF", ".tiff": "TIFF", ".jpg": "JPEG", ".jpeg": "JPEG",
                   ".bmp": "BMP", ".exr": "EXR", **{s: "TGA" for s in _TGA_SUFFIXES}}


def _check_name(path, decl):
    """The name must not promise another format than the content (the decoder would go by the name)."""
    named = _SUFFIX_FORMATS.get(path.suffix.lower())
    if (named is not None and named != decl.fmt) or (decl.fmt == "TIFF" and named is None):
        want = ".tif" if decl.fmt == "TIFF" else f"a {decl.fmt} name"
        raise FrameError(
            f"the file holds {decl.fmt} data but is named {path.suffix or 'without a suffix'}; "
            f"rename it ({want})",
            path=path, field="format",
        )


def _exc_text(exc):
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0]}" if text else type(exc).__name__


def _decode(path, decl):
    """The file's pixels: pypng for 16-bit colour PNG (exact), tifffile for the TIFF page the header
    check chose, else imageio/Pillow (through scikit-image) by content.

    Pillow reads from bytes in memory, so a decoder that fails half-way
    leaves no file open behind it.
    """
    try:
        if decl.fmt == "PNG" and decl.bits == 16 and decl.layout != "grey":
            return _png_pixels(path)
        if decl.fmt == "TIFF":
            import tifffile

            with tifffile.TiffFile(path) as tif:
                arr = np.asarray(tif.pages[decl.page].asarray())
            if arr.ndim == 3 and arr.shape[-1] not in (3, 4) and arr.shape[0] in (3, 4):
                arr = np.moveaxis(arr, 0, -1)  # planar RGB(A) to interleaved, as scikit-image's imread does
        else:
            from skimage import io as skio

            arr = np.asarray(skio.imread(io.BytesIO(path.read_bytes())))
    except Exception as exc:  # PIL, imageio and tifffile raise many kinds for corrupt data
        raise FrameError(
            f"cannot decode the {decl.fmt} image (corrupt or truncated?): {_exc_text(exc)}",
            path=path, field="file",
        ) from None
    if arr.dtype == object or arr.ndim < 2:
        raise FrameError(f"decoded to no image (shape {arr.shape}, {arr.dtype})", path=path, field="file")
    return arr


def _declared(fh, path) -> _Layout:
    """What the file's header declares, read by the format's own library (pypng, tifffile, Pillow)."""
    head = fh.read(32)
    if head.startswith(b"\x89PNG\r\n\x1a\n"):
        fh.seek(0, os.SEEK_END)
        fh.seek(max(0, fh.tell() - 4096))
        if b"IEND" not in fh.read():  # pixels cut short can still decode; a missing end is proof
            raise FrameError("truncated PNG: no IEND chunk at its end", path=path, field="file")
        return _png_header(path)
    if head[:4] in (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+"):
        return _tiff_header(path)
    if head[:4] == b"\x76\x2f\x31\x01":
        return _Layout("EXR")
    if head[:3] == b"\xff\xd8\xff":
        return _pillow_header(path, "JPEG")
    if head[:2] == b"BM" and len(head) >= 26:
        return _pillow_header(path, "BMP")
    if path.suffix.lower() in _TGA_SUFFIXES:
        return _pillow_header(path, "TGA")
    raise FrameError(
        "not an image in a supported format (PNG, TIFF, TGA, JPEG, BMP or OpenEXR; "
        "recognised by content, TGA by its .tga name)",
        path=path, field="format",
    )


_PNG_LAYOUTS = {0: "grey", 2: "RGB", 3: "palette", 4: "grey+alpha", 6: "RGBA"}


def _png_header(path):
    import png

    reader = png.Reader(bytes=path.read_bytes())
    try:
        reader.preamble()  # the chunks before the pixels: IHDR (checked), PLTE, tRNS, ...
    except Exception as exc:  # pypng raises FormatError, ChunkError, ProtocolError, ...
        raise FrameError(f"truncated or malformed PNG header: {_exc_text(exc)}", path=path, field="header") from None
    return _Layout("PNG", reader.height, reader.width, _PNG_LAYOUTS[reader.color_type], reader.bitdepth)


def _png_pixels(path):
    """A 16-bit colour or grey+alpha PNG's samples, exactly (Pillow keeps only 8 of their 16 bits)."""
    import png

    width, height, rows, info = png.Reader(bytes=path.read_bytes()).read()
    arr = np.vstack([np.asarray(r, np.uint16)[None] for r in rows])
    return arr.reshape(height, width, int(info["planes"]))


#: Pillow's modes: the layout each declares.
_PILLOW_LAYOUTS = {"1": "grey", "L": "grey", "LA": "grey+alpha", "P": "palette", "RGB": "RGB", "RGBA": "RGBA"}


def _pillow_header(path, fmt):
    from PIL import Image

    try:
        with Image.open(io.BytesIO(path.read_bytes()), formats=[fmt]) as img:
            mode, (width, height), bits = img.mode, img.size, getattr(img, "bits", 8)
    except Exception as exc:  # Pillow raises SyntaxError, OSError, ValueError, ... for a bad header
        raise FrameError(f"not a valid {fmt} header: {_exc_text(exc)}", path=path, field="header") from None
    if fmt == "JPEG" and mode not in ("L", "RGB"):
        raise FrameError(f"JPEG with {len(mode)} components ({mode}); only grey or colour JPEG is read",
                         path=path, field="layout")
    # a BMP's layout, and whether a TGA is RGB or RGBA, is decided by the decoded channels
    layout = "" if fmt == "BMP" or (fmt == "TGA" and mode in ("RGB", "RGBA")) else _PILLOW_LAYOUTS.get(mode, "")
    return _Layout(fmt, height, width, layout, bits)


_TIFF_PHOTOMETRIC = {0: "min-is-white", 1: "min-is-black", 2: "RGB", 3: "palette", 4: "mask", 5: "CMYK",
                     6: "YCbCr", 8: "CIELab"}


def _tiff_header(path):
    import tifffile

    with tifffile.TiffFile(path) as tif:
        ifds = list(itertools.islice(tif.pages, _TIFF_MAX_IFDS + 1))
        if len(ifds) > _TIFF_MAX_IFDS:
            raise FrameError(f"TIFF's chain of image directories runs past {_TIFF_MAX_IFDS} (corrupt offsets?)",
                             path=path, field="pages")
        full = [i for i, p in enumerate(ifds) if not int(p.subfiletype) & 1]  # reduced-resolution pages do not count
        if not full:
            raise FrameError("TIFF holds no image", path=path, field="pages")
        if len(full) > 1:
            raise FrameError(f"TIFF holds {len(full)} pages (a multi-page stack); give one frame per file",
                             path=path, field="pages")
        page = ifds[full[0]]
        width, height, spp = page.imagewidth, page.imagelength, page.samplesperpixel
        bits, fmt, photometric = page.bitspersample, int(page.sampleformat), int(page.photometric)
    if isinstance(bits, tuple):
        raise FrameError(f"TIFF samples of mixed bit depths {bits}", path=path, field="layout")
    sample = {1: "uint", 3: "float"}.get(fmt)
    if sample is None:
        what = {2: "signed integer"}.get(fmt, f"sample format {fmt}")
        raise FrameError(
            f"TIFF of {bits}-bit {what} samples; only unsigned integer or float samples are read",
            path=path, field="layout",
        )
    if bits not in {"uint": (1, 8, 16, 32), "float": (16, 32, 64)}[sample]:
        raise FrameError(f"TIFF of {bits}-bit {sample} samples is not supported", path=path, field="layout")
    if photometric not in (0, 1, 2):
        raise FrameError(
            f"TIFF with {_TIFF_PHOTOMETRIC.get(photometric, f'photometric {photometric}')} pixels; only grey "
            "(min-is-black or min-is-white) and RGB are read",
            path=path, field="layout",
        )
    layout = {1: "grey", 2: "grey+alpha"}.get(spp) if photometric < 2 else {3: "RGB", 4: "RGBA"}.get(spp)
    if layout is None:
        raise FrameError(
            f"TIFF with {spp} samples per pixel ({_TIFF_PHOTOMETRIC[photometric]}); expected grey, grey+alpha, "
            "RGB or RGBA",
            path=path, field="layout",
        )
    if photometric == 0 and sample == "float":
        raise FrameError("float TIFF with min-is-white pixels is not supported", path=path, field="layout")
    return _Layout("TIFF", height, width, layout, bits, sample, invert=photometric == 0, page=full[0])


# -- from pixels to one intensity ---------------------------------------------------


def _colour_layout(path, arr, decl):
    """The layout of the decoded array, checked against the declared one."""
    shape = arr.shape
    if decl.height is not None and shape[:2] != (decl.height, decl.width):
        raise FrameError(
            f"decoded image is {_hw(shape)} but its header says {decl.height}x{decl.width} (H x W)",
            path=path, field="size",
        )
    if arr.ndim == 2:
        found = "grey"
    elif arr.ndim == 3 and shape[2] in (2, 3, 4):
        found = {2: "grey+alpha", 3: "RGB", 4: "RGBA"}[shape[2]]
    else:
        raise FrameError(
            f"unsupported layout: decoded shape {shape}; expected (H, W) grey, or (H, W, 2), "
            "(H, W, 3) or (H, W, 4) for grey+alpha, RGB or RGBA",
            path=path, field="layout",
        )
    want = decl.layout
    ok = want in ("", found) or (want == "palette" and found in ("RGB", "RGBA"))
    if not ok:
        raise FrameError(
            f"decoded as {found} (shape {shape}) but the file declares {want}", path=path, field="layout"
        )
    return found


def _to_frame(path, arr, decl, channel) -> _Frame:
    if (decl.fmt == "TIFF" and arr.ndim == 3 and arr.shape[1:] == (decl.height, decl.width)
            and arr.shape[0] == 2 and arr.shape[:2] != (decl.height, decl.width)):
        arr = np.moveaxis(arr, 0, -1)  # planar grey+alpha (planar RGB(A) arrives interleaved)
    layout = _colour_layout(path, arr, decl)
    _check_size(path, arr.shape)
    alpha = layout in ("grey+alpha", "RGBA")
    if alpha:
        arr = arr[..., :-1]
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[..., 0]

    if arr.dtype == bool:
        bits, clip = 1, 1.0
        values = arr.astype(np.float32)
    elif np.issubdtype(arr.dtype, np.unsignedinteger):
        bits = decl.bits if decl.fmt == "TIFF" else np.iinfo(arr.dtype).bits
        scale = 2**bits - 1
        if bits > np.iinfo(arr.dtype).bits or int(arr.max()) > scale:
            raise FrameError(
                f"pixel values up to {int(arr.max())} exceed the declared {bits}-bit range",
                path=path, field="pixels",
            )
        values = arr.astype(np.float32) / np.float32(scale)
        clip = 1.0
    elif np.issubdtype(arr.dtype, np.floating) and decl.sample == "float":
        bits, clip = arr.dtype.itemsize * 8, math.inf
        with np.errstate(over="ignore"):
            values = arr.astype(np.float32)
        _check_float(path, values)
    else:
        raise FrameError(
            f"unsupported pixel type {arr.dtype} for a {decl.fmt} file", path=path, field="layout"
        )
    if decl.invert:
        values = 1.0 - values
    colour = "palette" if decl.layout == "palette" else layout
    depth = f"float{bits}" if clip == math.inf else f"{bits}-bit"
    kind = f"{depth} {colour} {decl.fmt}" + (" (min-is-white)" if decl.invert else "")
    return _Frame(_reduce(values, channel), clip, kind, alpha)


def _check_float(path, values):
    """Float frames must be finite and non-negative (the channels used, not alpha)."""
    per_pixel = (lambda m: m.any(axis=-1)) if values.ndim == 3 else (lambda m: m)
    bad = int(per_pixel(~np.isfinite(values)).sum())
    if bad:
        raise FrameError(
            f"{bad} pixel(s) are NaN or inf; a float frame must be finite", path=path, field="pixels"
        )
    n_neg = int(per_pixel(values < 0).sum())
    if n_neg:
        raise FrameError(
            f"{n_neg} pixel(s) are negative (most negative {float(values.min()):.6g}); "
            "light intensity cannot be negative",
            path=path, field="pixels",
        )


def _reduce(values, channel):
    """One (H, W) contiguous float32 intensity from grey or colour values."""
    if values.ndim == 3:
        if channel == "max":
            values = values.max(axis=-1)
        elif channel == "mean":
            values = values.mean(axis=-1, dtype=np.float32)
        else:
            values = values @ _LUMINANCE
    return np.ascontiguousarray(values, dtype=np.float32)


# -- EXR ----------------------------------------------------------------------------


def _exr_layer(path, names):
    """(prefix, layout, [channel names in R, G, B or Y order], alpha name or None) of one layer."""
    split = {}
    for name in names:
        prefix, _, base = name.rpartition(".")
        split.setdefault(prefix, {})[base] = name
    found = ", ".join(sorted(names))
    if len(split) == 1:
        prefix, bases = next(iter(split.items()))
        keys = set(bases)
        if len(keys) == 1 and keys != {"A"}:
            return prefix, "grey", [bases[next(iter(keys))]], None
        if keys == {"R", "G", "B"}:
            return prefix, "RGB", [bases[c] for c in "RGB"], None
        if keys == {"R", "G", "B", "A"}:
            return prefix, "RGBA", [bases[c] for c in "RGB"], bases["A"]
        if keys == {"Y", "A"}:
            return prefix, "grey+alpha", [bases["Y"]], bases["A"]
    raise FrameError(
        f"channels {found} are not one grey or colour layer; a frame EXR holds one channel, "
        "or R, G, B (and A), or Y, A, optionally under one layer prefix (rgba.R, ...)",
        path=path, field="channels",
    )


def _from_exr(path, channel) -> _Frame:
    try:
        _header, channels = read_exr_channels(path)
    except ShinysimError as exc:
        raise FrameError(f"not a readable OpenEXR frame: {exc.problem}", path=path, field="file") from None
    except Exception as exc:  # pragma: no cover - the reader wraps its own errors
        raise FrameError(f"not a readable OpenEXR frame: {_exc_text(exc)}", path=path, field="file") from None
    if not channels:
        raise FrameError("EXR holds no channels", path=path, field="channels")
    prefix, layout, used, alpha = _exr_layer(path, list(channels))
    arrays = [np.asarray(channels[n]) for n in used]
    shapes = {a.shape for a in arrays + ([np.asarray(channels[alpha])] if alpha else [])}
    if len(shapes) != 1 or len(next(iter(shapes))) != 2:
        raise FrameError(f"EXR channels {', '.join(used)} differ in shape: {sorted(shapes)}",
                         path=path, field="channels")
    _check_size(path, next(iter(shapes)))
    with np.errstate(over="ignore"):
        values = arrays[0].astype(np.float32) if len(arrays) == 1 else np.stack(arrays, -1).astype(np.float32)
    _check_float(path, values)
    layer = f", layer {prefix!r}" if prefix else ""
    kind = f"float {layout} EXR ({', '.join(used + ([alpha] if alpha else []))}{layer})"
    return _Frame(_reduce(values, channel), math.inf, kind, alpha is not None)
