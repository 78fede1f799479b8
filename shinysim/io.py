"""Stack and truth files: the contract between simulation and reconstruction.

A *scan folder* holds::

    rig.json     the rig (sources, cameras) plus provenance   (shinysim-rig/1)
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
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ._shared import refuse_existing, write_file, write_text
from .errors import StackFormatError
from .rig import Camera, Rig, RigError, load_rig

__all__ = [
    "StackFormatError",
    "Stack",
    "Truth",
    "STACK_FORMAT",
    "TRUTH_FORMAT",
    "source_channel",
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
    """

    normals: np.ndarray
    positions: np.ndarray
    mask: np.ndarray
    part: np.ndarray | None = None
    part_names: list[str] = field(default_factory=lambda: ["background", "object"])
    metadata: dict[str, Any] = field(default_factory=dict)

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


def check_frames(frames, rig, camera_index=0, *, what="stack"):
    """Check that frames agree with their rig; raise StackFormatError if not.

    Checks the array rank, the number of frames against the number of
    sources, the frame size against the camera, and that all pixels are
    finite (NaN/inf are named with the frames that hold them).
    """
    if not isinstance(rig, Rig):
        raise StackFormatError(f"{what}: rig must be a shinysim Rig, got {type(rig).__name__}")
    if not 0 <= camera_index < len(rig.cameras):
        raise StackFormatError(f"{what}: camera_index {camera_index} but the rig has {len(rig.cameras)} camera(s)")
    if frames.ndim != 3:
        raise StackFormatError(f"{what}: frames must be (n_sources, H, W), got shape {frames.shape}")
    if frames.shape[0] != rig.n_sources:
        raise StackFormatError(
            f"{what} has {frames.shape[0]} frames but the rig has {rig.n_sources} sources"
        )
    cam = rig.cameras[camera_index]
    if frames.shape[1:] != cam.shape:
        raise StackFormatError(
            f"{what} frames are {frames.shape[1]}x{frames.shape[2]} (H x W) but camera "
            f"{cam.name!r} is {cam.height}x{cam.width}"
        )
    bad = ~np.isfinite(frames)
    if bad.any():
        which = np.flatnonzero(bad.reshape(len(frames), -1).any(axis=1))
        raise StackFormatError(
            f"{what} has NaN or inf pixels in frame(s) {', '.join(source_channel(k) for k in which)}"
        )


# -- EXR ----------------------------------------------------------------------------


def _write_exr(path, channels, attrs, overwrite):
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    header.update(attrs)

    def write(tmp):
        with OpenEXR.File(header, channels) as f:
            f.write(tmp)

    write_file(path, write, overwrite=overwrite)


def _read_exr(path, fmt):
    """Header and {name: array} of an EXR, or StackFormatError."""
    import OpenEXR

    path = Path(path)
    if not path.is_file():
        raise StackFormatError(f"{path}: no such file")
    try:
        with OpenEXR.File(str(path)) as f:
            header = dict(f.header())
            channels = {name: np.array(ch.pixels) for name, ch in f.channels().items()}
    except Exception as exc:  # OpenEXR raises RuntimeError for any corruption
        raise StackFormatError(
            f"{path}: not a readable OpenEXR file (corrupt or truncated?): {exc}"
        ) from exc
    found = header.get("shinysim_format")
    if found is not None and found != fmt:
        raise StackFormatError(f"{path}: file format is {found!r}, expected {fmt!r}")
    return header, channels


def _json_attr(header, key):
    value = header.get(key)
    if value is None:
        return {}
    try:
        return json.loads(value)
    except (TypeError, json.JSONDecodeError):
        return {}


# -- stack -------------------------------------------------------------------------


def save_stack(stack: Stack, path: str | os.PathLike, *, rig_path: str | os.PathLike | None = None,
               dtype: str = "float16", overwrite: bool = False) -> None:
    """Write a stack EXR and its rig JSON.

    Parameters
    ----------
    stack : Stack
    path : path-like
        The ``.exr`` file to write.
    rig_path : path-like, optional
        Rig JSON to write beside it; default ``rig.json`` in the same folder.
    dtype : {"float16", "float32"}
        Pixel type. float16 with ZIP keeps about 3 significant digits
        (relative error < 1e-3 of the peak) in a fraction of the size.
    overwrite : bool
        Replace existing files. Without it nothing existing is touched: both
        targets are checked before either is written.
    """
    if dtype not in ("float16", "float32"):
        raise ValueError(f"dtype must be 'float16' or 'float32', got {dtype!r}")
    path = Path(path)
    rig_path = path.with_name("rig.json") if rig_path is None else Path(rig_path)
    for p in (path, rig_path):
        refuse_existing(p, overwrite)
    peak = float(np.max(stack.frames)) if stack.frames.size else 0.0
    if dtype == "float16" and peak > 6.0e4:
        raise ValueError(f"stack peak {peak:g} overflows float16; use dtype='float32' or rescale")
    channels = {source_channel(k): stack.frames[k].astype(dtype) for k in range(stack.n_sources)}
    attrs = {
        "shinysim_format": STACK_FORMAT,
        "n_sources": int(stack.n_sources),
        "camera_index": int(stack.camera_index),
        "provenance": json.dumps(stack.provenance),
    }
    doc = stack.rig.to_dict()
    doc["provenance"] = stack.provenance
    write_text(rig_path, json.dumps(doc, indent=2) + "\n", overwrite=overwrite)
    _write_exr(path, channels, attrs, overwrite)


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
        count or size that disagrees with the rig, NaN/inf pixels, or an
        invalid rig file.
    """
    path = Path(path)
    rig_doc = {}
    if not isinstance(rig, Rig):
        rig_path = path.with_name("rig.json") if rig is None else Path(rig)
        try:
            rig = load_rig(rig_path)
        except RigError as exc:
            raise StackFormatError(f"rig for {path.name}: {exc}") from exc
        try:
            rig_doc = json.loads(rig_path.read_text())
        except (OSError, json.JSONDecodeError):
            rig_doc = {}
    header, channels = _read_exr(path, STACK_FORMAT)
    n = rig.n_sources
    names = [source_channel(k) for k in range(n)]
    # accept "S000" or a layer "S000.Y"/"S000.R" (first found) for each source
    frames = []
    missing = []
    for name in names:
        found = name if name in channels else next(
            (c for c in sorted(channels) if c.split(".")[0] == name), None
        )
        if found is None:
            missing.append(name)
        else:
            frames.append(channels[found])
    if missing:
        raise StackFormatError(
            f"{path}: missing channel(s) {', '.join(missing)} for the rig's {n} sources "
            f"(found {', '.join(sorted(channels)) or 'none'})"
        )
    extra = sorted({c.split(".")[0] for c in channels if c.startswith("S") and c.split(".")[0] not in names})
    if extra:
        raise StackFormatError(f"{path}: has frames {', '.join(extra)} beyond the rig's {n} sources")
    if header.get("n_sources") not in (None, n):
        raise StackFormatError(f"{path}: header says {header['n_sources']} sources but the rig has {n}")
    camera_index = int(header.get("camera_index", 0))
    provenance = _json_attr(header, "provenance") or rig_doc.get("provenance", {})
    try:
        return Stack(np.stack(frames).astype(np.float32), rig, camera_index, provenance)
    except StackFormatError as exc:
        raise StackFormatError(f"{path}: {exc}") from exc


# -- truth ------------------------------------------------------------------------

_TRUTH_CHANNELS = ["normal.X", "normal.Y", "normal.Z", "position.X", "position.Y", "position.Z", "mask"]


def save_truth(truth: Truth, path: str | os.PathLike, *, overwrite: bool = False) -> None:
    """Write a truth EXR (float32 normals and positions, mask, part ids)."""
    channels = {
        "normal.X": truth.normals[..., 0],
        "normal.Y": truth.normals[..., 1],
        "normal.Z": truth.normals[..., 2],
        "position.X": truth.positions[..., 0],
        "position.Y": truth.positions[..., 1],
        "position.Z": truth.positions[..., 2],
        "mask": truth.mask.astype(np.float32),
        "part": truth.part.astype(np.float32),
    }
    channels = {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in channels.items()}
    attrs = {
        "shinysim_format": TRUTH_FORMAT,
        "part_names": json.dumps(list(truth.part_names)),
        "metadata": json.dumps(truth.metadata),
    }
    _write_exr(path, channels, attrs, overwrite)


def load_truth(path: str | os.PathLike, camera: Camera | None = None) -> Truth:
    """Read a truth EXR; optionally check its size against a camera."""
    path = Path(path)
    header, channels = _read_exr(path, TRUTH_FORMAT)
    missing = [c for c in _TRUTH_CHANNELS if c not in channels]
    if missing:
        raise StackFormatError(f"{path}: missing truth channel(s) {', '.join(missing)}")
    normals = np.stack([channels[f"normal.{a}"] for a in "XYZ"], axis=-1)
    positions = np.stack([channels[f"position.{a}"] for a in "XYZ"], axis=-1)
    mask = channels["mask"] > 0.5
    part = channels["part"].astype(np.int32) if "part" in channels else None
    if camera is not None and mask.shape != camera.shape:
        raise StackFormatError(f"{path}: truth is {mask.shape} but camera {camera.name!r} is {camera.shape}")
    if not np.all(np.isfinite(normals[mask])):
        raise StackFormatError(f"{path}: truth normals are not finite inside the mask")
    part_names = json.loads(header.get("part_names", '["background", "object"]'))
    return Truth(normals, positions, mask, part, part_names, _json_attr(header, "metadata"))
