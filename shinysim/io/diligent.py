"""DiLiGenT folders: the photometric-stereo benchmark layout, written and read.

DiLiGenT (Shi et al., CVPR 2016) is the layout most photometric-stereo code
reads: one folder per object, ``001.png ... NNN.png`` (one 16-bit RGB image
per light), ``filenames.txt``, ``light_directions.txt``,
``light_intensities.txt``, ``mask.png``, ``Normal_gt.mat`` and
``normal.txt``, in the frame x image right, y image *up*, z towards the
viewer. ``docs/diligent.md`` specifies every file, what
:func:`export_diligent` (and :func:`export_scan_folder`) write beside them
(``shinysim.json``, ``coverage.png``) and what :func:`read_diligent`
accepts. A bad folder gives :class:`~shinysim.errors.DiligentError` naming
the file and the field (``light_directions.txt: row 7: not 3 numbers``).
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .. import __version__
from .._shared import (
    check_number,
    json_safe,
    output_folder,
    write_file,
    write_json,
    write_text,
)
from ..errors import DiligentError, OptionError, StackFormatError
from ..rig import Camera, Rig, distant_rig
from .document import parse_json, read_text
from .rig import load_rig
from .stack import MAX_PIXELS, Stack, Truth, load_stack, load_truth

__all__ = [
    "DILIGENT_FILES",
    "DILIGENT_FORMAT",
    "DiligentError",
    "DiligentSet",
    "camera_frame",
    "world_frame",
    "export_diligent",
    "export_scan_folder",
    "read_diligent",
    "image_names",
]

#: ``format`` of the ``shinysim.json`` an export writes beside the DiLiGenT files.
DILIGENT_FORMAT = "shinysim-diligent/1"

#: The fixed files of an exported folder (besides the numbered images); ``Normal_gt.mat``,
#: ``normal.txt`` and ``coverage.png`` only when there is a truth (with coverage).
DILIGENT_FILES = (
    "filenames.txt",
    "light_directions.txt",
    "light_intensities.txt",
    "mask.png",
    "Normal_gt.mat",
    "normal.txt",
    "coverage.png",
    "shinysim.json",
)

#: What the frame of light directions and normals is, as ``shinysim.json`` states it.
FRAME_STATEMENT = ("DiLiGenT camera frame: x = image right, y = image up, z = towards the viewer (the camera); "
                   "light_directions.txt, Normal_gt.mat and normal.txt use it; world vectors map to it by the "
                   "rows of world_to_diligent")

#: Decimal places of the light files (and of normal.txt).
DECIMALS = 8

_NUMBERED = re.compile(r"^(\d+)\.png$", re.IGNORECASE)


def _png():
    try:
        import png
    except ImportError:  # pragma: no cover - a dependency of the package
        raise ModuleNotFoundError("reading and writing DiLiGenT images needs pypng (pip install pypng)") from None
    return png


# -- frames ----------------------------------------------------------------------------


def _frame_matrix(camera: Camera) -> np.ndarray:
    """Rows: the world directions of DiLiGenT x (image right), y (image up), z (towards the camera)."""
    if not isinstance(camera, Camera):
        raise OptionError(f"camera must be a shinysim Camera, got {type(camera).__name__}")
    return np.stack([camera.right, -camera.down, -camera.forward])


def camera_frame(vectors_world, camera: Camera) -> np.ndarray:
    """World vectors in a camera's DiLiGenT frame: ``(v . right, -v . down, -v . forward)``.

    x is image right, y image up, z towards the viewer (for a perspective
    camera: along its optical axis, the same frame for every pixel).

    Parameters
    ----------
    vectors_world : (..., 3) array_like
    camera : shinysim.rig.Camera

    Returns
    -------
    (..., 3) ndarray of float64 (NaN stays NaN)
    """
    return np.asarray(vectors_world, dtype=float) @ _frame_matrix(camera).T


def world_frame(vectors_cam, camera: Camera) -> np.ndarray:
    """The inverse of :func:`camera_frame`: DiLiGenT-frame vectors in the world."""
    return np.asarray(vectors_cam, dtype=float) @ _frame_matrix(camera)


def image_names(n: int) -> list[str]:
    """``001.png`` ... : DiLiGenT's image names (more digits from 1000 images on)."""
    width = max(3, len(str(int(n))))
    return [f"{k + 1:0{width}d}.png" for k in range(int(n))]


# -- writing -----------------------------------------------------------------------------


def _write_png(path: Path, array: np.ndarray, *, bitdepth: int) -> None:
    """An (H, W) grey or (H, W, 3) RGB integer image as PNG (pypng: exact 16-bit)."""
    png = _png()
    a = np.ascontiguousarray(array)
    grey = a.ndim == 2
    H, W = a.shape[:2]
    rows = a.reshape(H, -1)

    def write(tmp):
        with open(tmp, "wb") as fh:
            png.Writer(W, H, greyscale=grey, bitdepth=bitdepth, compression=6).write(fh, rows)

    write_file(path, write)


def _rows_text(rows: np.ndarray) -> str:
    fmt = f"%.{DECIMALS}f"
    return "".join(" ".join(fmt % v for v in row) + "\n" for row in np.asarray(rows, float))


def _normal_txt(normals: np.ndarray) -> str:
    """One pixel a line, rows top to bottom, each left to right: what ``reshape(H, W, 3)`` reads."""
    flat = np.asarray(normals, float).reshape(-1, 3)
    fmt = f"%.{DECIMALS}f"
    # one format per line, joined: 0.4 s for a 612 x 512 image (np.savetxt: 0.7 s)
    line = f"{fmt} {fmt} {fmt}\n"
    return "".join(line % tuple(v) for v in flat.tolist())


def _origin(stack: Stack, truth: Truth | None, origin_mm) -> tuple[np.ndarray, str]:
    if origin_mm is not None:
        try:
            o = np.asarray(origin_mm, dtype=float)
        except (TypeError, ValueError):
            o = np.full(1, np.nan)
        if o.shape != (3,) or not np.all(np.isfinite(o)):
            raise OptionError(f"origin_mm must be 3 finite numbers (x, y, z in mm), got {origin_mm!r}")
        return o, "given (origin_mm)"
    if truth is not None and truth.mask.any():
        p = truth.positions[truth.mask].astype(float)
        p = p[np.all(np.isfinite(p), axis=1)]
        if len(p):
            return p.mean(axis=0), "mean of the truth's surface points over the mask"
    return stack.camera.target.copy(), "the camera's target"


def _light_table(rig: Rig, origin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World unit directions from ``origin`` to each source and their relative irradiance there.

    Irradiance at normal incidence under the renderer's convention (every
    source the same radiance L): a near sphere of radius r at distance d
    gives ``pi r^2 / d^2 L`` (exact for a sphere), a point source ``L / d^2``,
    a distant one ``L``; divided by the largest.
    """
    dirs = np.empty((rig.n_sources, 3))
    irr = np.empty(rig.n_sources)
    for k in range(rig.n_sources):
        p = rig.source_positions[k]
        if rig.source_distant[k]:
            dirs[k] = p / np.linalg.norm(p)
            irr[k] = 1.0
            continue
        d = p - origin
        dist = float(np.linalg.norm(d))
        if not dist > 0:
            raise OptionError(f"source {k} lies at the origin {origin.tolist()} mm: it has no direction from there; "
                              "give another origin_mm")
        dirs[k] = d / dist
        r = float(rig.source_radii[k])
        irr[k] = math.pi * r * r / dist**2 if r > 0 else 1.0 / dist**2
    return dirs, irr / irr.max()


def _stale_files(out: Path, names: list[str]) -> list[str]:
    """DiLiGenT files in ``out`` that this export would not replace (they would no longer match)."""
    if not out.is_dir():
        return []
    keep = set(names)
    return sorted(p.name for p in out.iterdir()
                  if p.name not in keep and (p.name in DILIGENT_FILES or _NUMBERED.match(p.name)))


def export_diligent(stack: Stack, out, *, truth: Truth | None = None, origin_mm=None,
                    overwrite: bool = False) -> dict:
    """Write one stack (and its truth) as a DiLiGenT object folder.

    Parameters
    ----------
    stack : shinysim.io.Stack
        One image per source, in source order.
    out : path-like
        The folder to write (created; written through a hidden temporary
        folder, so a failed or interrupted export leaves nothing).
    truth : shinysim.io.Truth, optional
        The stack camera's truth: gives ``mask.png``, ``Normal_gt.mat``,
        ``normal.txt`` (and ``coverage.png`` when it has coverage). Without
        it, ``mask.png`` holds the pixels that are above zero in at least
        one image, and no normal files are written.
    origin_mm : (3,) array_like, optional
        The point the light directions and intensities are taken from (near
        sources only). Default: the mean of the truth's surface points over
        its mask, else the camera's target.
    overwrite : bool
        Replace the files of an earlier export in ``out``.

    Returns
    -------
    dict
        ``folder``, ``scale`` (16-bit code per stack unit), ``n_images``,
        ``files`` (names written), ``origin_mm``, ``mask_from``.

    Raises
    ------
    FileExistsError
        ``out`` holds files of this layout and ``overwrite`` is False; or,
        whatever ``overwrite`` says, DiLiGenT files this export would not
        replace (more numbered images, normals an export without truth
        does not write), which would leave a folder that contradicts itself.
    OptionError
        A stack or truth of the wrong type or size, a bad ``origin_mm``.
    """
    if not isinstance(stack, Stack):
        raise OptionError(f"stack must be a shinysim.io.Stack, got {type(stack).__name__}")
    if truth is not None and not isinstance(truth, Truth):
        raise OptionError(f"truth must be a shinysim.io.Truth or None, got {type(truth).__name__}")
    cam = stack.camera
    H, W = cam.shape
    if truth is not None and truth.mask.shape != (H, W):
        raise OptionError(f"truth is {truth.mask.shape[0]}x{truth.mask.shape[1]} (H x W) but camera "
                          f"{cam.name!r} of the stack is {H}x{W}")
    out = Path(out)
    n = stack.n_sources
    names = image_names(n)
    fixed = ["filenames.txt", "light_directions.txt", "light_intensities.txt", "mask.png"]
    if truth is not None:
        fixed += ["Normal_gt.mat", "normal.txt"] + (["coverage.png"] if truth.coverage is not None else [])
    fixed.append("shinysim.json")
    files = names + fixed
    stale = _stale_files(out, files)
    if stale:
        shown = ", ".join(stale[:8]) + (" ..." if len(stale) > 8 else "")
        raise FileExistsError(f"{out} holds {shown} from an earlier export that this one would not replace; "
                              "remove them or choose another folder")

    origin, origin_from = _origin(stack, truth, origin_mm)
    dirs_world, intensities = _light_table(stack.rig, origin)
    dirs = camera_frame(dirs_world, cam)

    frames = stack.frames
    peak = float(frames.max()) if frames.size else 0.0
    scale = 65535.0 / peak if peak > 0 else 1.0
    codes = [np.clip(np.rint(frames[k].astype(np.float64) * scale), 0, 65535).astype(np.uint16) for k in range(n)]
    if truth is not None:
        mask = truth.mask
        mask_from = "truth (pixel-centre rays that hit the object)"
    else:
        mask = np.logical_or.reduce([c > 0 for c in codes])
        mask_from = "images (pixels above zero in at least one image)"

    normals = None
    if truth is not None:
        normals = camera_frame(truth.normals, cam)
        normals[~truth.mask] = 0.0
        normals = np.nan_to_num(normals, nan=0.0)  # a NaN inside the mask would be the truth's own gap

    sat = stack.saturation
    info = {
        "format": DILIGENT_FORMAT,
        "generator": f"shinysim {__version__}",
        "frame": FRAME_STATEMENT,
        "world_to_diligent": _frame_matrix(cam),
        "scale": scale,
        "scale_means": "16-bit image code = round(scale * stack value), grey replicated in R, G, B; "
                       "stack value = code / scale",
        "peak": peak,
        "saturation": sat,
        "saturation_code": None if sat is None else min(65535.0, sat * scale),
        "origin_mm": origin,
        "origin_from": origin_from,
        "light_intensities": "irradiance each source gives at the origin at normal incidence, relative to the "
                             "strongest (equal radiance: near sphere pi r^2 / d^2, point 1 / d^2, distant 1), "
                             "the same in R, G and B",
        "light_irradiance_relative": intensities,
        "mask_from": mask_from,
        "normals": None if truth is None else "truth normals at pixel centres, unfiltered; zeros outside the mask",
        "coverage": None if truth is None or truth.coverage is None else "coverage.png: fraction of each pixel "
                    "covering the object, 16-bit grey, code = round(coverage * 65535)",
        "sources": stack.rig.to_dict()["sources"],
        "rig_name": stack.rig.name,
        "camera": cam.to_dict(),
        "camera_index": int(stack.camera_index),
        "provenance": stack.provenance,
        "filenames": names,
        "n_images": n,
        "files": files,
    }
    needed = int(n * H * W * 6 * 1.1) + (H * W * 100 if truth is not None else 0) + (1 << 20)
    with output_folder(out, files, overwrite=overwrite, needed_bytes=needed, last="shinysim.json") as tmp:
        for name, code in zip(names, codes):
            _write_png(tmp / name, np.repeat(code[..., None], 3, axis=2), bitdepth=16)
        write_text(tmp / "filenames.txt", "".join(f"{nm}\n" for nm in names))
        write_text(tmp / "light_directions.txt", _rows_text(dirs))
        write_text(tmp / "light_intensities.txt", _rows_text(np.repeat(intensities[:, None], 3, axis=1)))
        _write_png(tmp / "mask.png", np.where(mask, 255, 0).astype(np.uint8), bitdepth=8)
        if truth is not None:
            from scipy.io import savemat

            def write_mat(path):
                with open(path, "wb") as fh:  # a file object: savemat would add ".mat" to a temporary name
                    savemat(fh, {"Normal_gt": normals.astype(np.float64)}, do_compression=True)

            write_file(tmp / "Normal_gt.mat", write_mat)
            write_text(tmp / "normal.txt", _normal_txt(normals))
            if truth.coverage is not None:
                cov = np.clip(np.rint(truth.coverage.astype(np.float64) * 65535), 0, 65535).astype(np.uint16)
                _write_png(tmp / "coverage.png", cov, bitdepth=16)
        write_json(tmp / "shinysim.json", info)
    return {"folder": str(out), "scale": scale, "n_images": n, "files": files, "origin_mm": origin.tolist(),
            "mask_from": mask_from}


def _scan_file(stem: str, camera: int) -> str:
    return f"{stem}.exr" if camera == 0 else f"{stem}.camera{camera}.exr"


def export_scan_folder(folder, out, *, camera: int = 0, overwrite: bool = False) -> dict:
    """Export one camera of a scan folder as a DiLiGenT folder (:func:`export_diligent`).

    Reads ``rig.json``, ``stack.exr`` (camera 0) or ``stack.cameraK.exr``
    (camera K), and ``truth.exr`` / ``truth.cameraK.exr`` when present.

    Raises
    ------
    OptionError
        ``camera`` is not one of the rig's cameras.
    StackFormatError, RigError
        The scan folder's files (naming them); a stack of another camera.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise StackFormatError("no such scan folder", path=folder)
    rig = load_rig(folder / "rig.json")
    camera = check_number("camera", camera, lo=0, hi=len(rig.cameras) - 1, integer=True)
    stack_path = folder / _scan_file("stack", camera)
    stack = load_stack(stack_path, rig)
    if stack.camera_index != camera:
        raise StackFormatError(f"holds camera {stack.camera_index}, not camera {camera}", path=stack_path,
                               field="camera_index")
    truth_path = folder / _scan_file("truth", camera)
    truth = load_truth(truth_path, stack.camera) if truth_path.exists() else None
    summary = export_diligent(stack, out, truth=truth, overwrite=overwrite)
    summary["scan"] = str(folder)
    summary["camera"] = camera
    return summary


# -- reading -----------------------------------------------------------------------------


@dataclass
class DiligentSet:
    """One DiLiGenT object folder, read (:func:`read_diligent`).

    Attributes
    ----------
    stack : shinysim.io.Stack
        One frame per light: the mean over R, G, B of each channel divided
        by the light's intensity in it (the image scaled to [0, 1] by its
        bit depth first), float32. Its rig holds the lights as distant
        sources under an orthographic top camera (looking down -z, image up
        +y), so the world frame *is* the DiLiGenT frame. ``saturation`` is
        the frames' common clip level (None when the lights' intensities
        give each frame its own; they are in ``provenance["clip_levels"]``).
    mask : (H, W) bool
        ``mask.png`` non-zero (all True without one).
    normals : (H, W, 3) ndarray or None
        True normals in the DiLiGenT frame from ``Normal_gt.mat``, else
        ``normal.txt``; NaN outside the mask and where zero. None without
        either file.
    truth : shinysim.io.Truth or None
        The same normals as a truth of the stack's camera (world frame =
        DiLiGenT frame), positions unknown (NaN), for scoring.
    light_directions : (N, 3) ndarray
        As read, normalised.
    light_intensities : (N, 3) ndarray
        As read (all ones without ``light_intensities.txt``).
    filenames : list of str
    """

    stack: Stack
    mask: np.ndarray
    normals: np.ndarray | None
    truth: Truth | None
    light_directions: np.ndarray
    light_intensities: np.ndarray
    filenames: list[str] = field(default_factory=list)


def _read_text(path: Path) -> str:
    return read_text(path, error=DiligentError, what="DiLiGenT text")


def _read_rows(path: Path, what: str, n: int, names_from: str) -> tuple[np.ndarray, list[int]]:
    """Rows of three numbers (space, tab or comma separated; blank lines skipped), one per image of the ``n``
    (listed by ``names_from``), and their line numbers."""
    rows, lines = [], []
    for i, line in enumerate(_read_text(path).splitlines(), 1):
        s = line.strip()
        if not s:
            continue
        parts = s.replace(",", " ").split()
        try:
            if len(parts) != 3:
                raise ValueError
            values = [float(p) for p in parts]
        except ValueError:
            shown = s if len(s) <= 60 else s[:57] + "..."
            raise DiligentError(f"not 3 numbers ({what}): {shown!r}", path=path, field=f"row {i}") from None
        if not all(math.isfinite(v) for v in values):
            raise DiligentError(f"not finite: {s!r}", path=path, field=f"row {i}")
        rows.append(values)
        lines.append(i)
    if not rows:
        raise DiligentError(f"holds no rows; one row of 3 numbers ({what}) per image", path=path, field="rows")
    if len(rows) != n:
        raise DiligentError(f"has {len(rows)} rows but there are {n} images ({names_from})", path=path, field="rows")
    return np.asarray(rows, dtype=float), lines


def _read_png(path: Path, field_name: str) -> tuple[np.ndarray, int]:
    """(H, W, planes) unsigned integers without alpha, and the largest code of the bit depth."""
    png = _png()
    try:
        fh = open(path, "rb")
    except FileNotFoundError:
        raise DiligentError("no such file", path=path, field=field_name) from None
    except IsADirectoryError:
        raise DiligentError("is a folder, not a PNG image", path=path, field=field_name) from None
    except OSError as exc:
        raise DiligentError(f"cannot read the file: {exc.strerror or exc}", path=path, field=field_name) from None
    with fh:
        try:
            width, height, rows, info = png.Reader(file=fh).asDirect()
        except Exception as exc:  # pypng raises FormatError, ChunkError, ProtocolError, OSError, ...
            raise DiligentError(f"not a readable PNG image: {exc}", path=path, field=field_name) from None
        if width * height > MAX_PIXELS:
            raise DiligentError(f"image of {width} x {height} pixels is larger than shinysim reads "
                                f"({MAX_PIXELS} pixels)", path=path, field=field_name)
        planes, depth = int(info["planes"]), int(info["bitdepth"])
        try:
            arr = np.vstack([np.asarray(r, dtype=np.uint16 if depth > 8 else np.uint8)[None] for r in rows])
        except Exception as exc:  # a truncated or corrupt data stream shows only while the rows are read
            raise DiligentError(f"not a readable PNG image (truncated or corrupt?): {exc}", path=path,
                                field=field_name) from None
    if arr.shape != (height, width * planes):
        raise DiligentError(f"holds {arr.shape[0]} rows of {arr.shape[1]} values for a {width} x {height} image "
                            f"of {planes} plane(s)", path=path, field=field_name)
    arr = arr.reshape(height, width, planes)
    if info.get("alpha"):
        arr = arr[..., :-1]
    return arr, (1 << depth) - 1


def _safe_name(name: str, line: int, path: Path) -> str:
    p = Path(name)
    if p.is_absolute() or ".." in p.parts or not p.parts:
        raise DiligentError(f"{name!r} is not a file of the folder", path=path, field=f"line {line}")
    return name


def _image_list(folder: Path) -> tuple[list[str], str]:
    listing = folder / "filenames.txt"
    if listing.exists():
        names = []
        for i, line in enumerate(_read_text(listing).splitlines(), 1):
            s = line.strip()
            if s:
                names.append(_safe_name(s, i, listing))
        if not names:
            raise DiligentError("lists no images", path=listing, field="rows")
        return names, "filenames.txt"
    numbered = sorted((int(m.group(1)), p.name) for p in folder.iterdir()
                      if (m := _NUMBERED.match(p.name)) and p.is_file())
    if not numbered:
        raise DiligentError("has no filenames.txt and no numbered images (001.png, 002.png, ...)", path=folder)
    return [nm for _, nm in numbered], "numbered images (no filenames.txt)"


def _read_export_info(folder: Path) -> dict | None:
    path = folder / "shinysim.json"
    if not path.exists():
        return None
    doc = parse_json(_read_text(path), error=DiligentError, path=path)
    if not isinstance(doc, dict) or doc.get("format") != DILIGENT_FORMAT:
        return None  # someone else's file of that name: not ours to interpret
    sat = doc.get("saturation_code")
    if sat is not None and (isinstance(sat, bool) or not isinstance(sat, (int, float)) or not
                            (math.isfinite(sat) and sat > 0)):
        raise DiligentError(f"must be a code > 0 or null, got {sat!r}", path=path, field="saturation_code")
    return doc


def _read_normals(folder: Path, shape: tuple[int, int]) -> tuple[np.ndarray | None, str | None]:
    H, W = shape
    mat = folder / "Normal_gt.mat"
    if mat.exists():
        from scipy.io import loadmat

        try:
            doc = loadmat(str(mat))
        except NotImplementedError:
            raise DiligentError("is a MATLAB v7.3 (HDF5) file, which is not read; save it with -v7",
                                path=mat) from None
        except Exception as exc:  # scipy raises ValueError, TypeError, MatReadError, OSError, ...
            raise DiligentError(f"not a readable MATLAB file: {exc}", path=mat) from None
        if "Normal_gt" not in doc:
            keys = ", ".join(k for k in doc if not k.startswith("__")) or "none"
            raise DiligentError(f"has no variable Normal_gt (found {keys})", path=mat, field="Normal_gt")
        n = doc["Normal_gt"]
        if not (isinstance(n, np.ndarray) and np.issubdtype(n.dtype, np.number)
                and not np.issubdtype(n.dtype, np.complexfloating)):
            raise DiligentError(f"must be a real numeric array, got {getattr(n, 'dtype', type(n).__name__)}",
                                path=mat, field="Normal_gt")
        if n.shape != (H, W, 3):
            raise DiligentError(f"has shape {n.shape}; the images need ({H}, {W}, 3)", path=mat, field="Normal_gt")
        n, path, where = n.astype(np.float64), mat, "Normal_gt"
    elif (txt := folder / "normal.txt").exists():
        lines = [s for s in _read_text(txt).splitlines() if s.strip()]
        if len(lines) != H * W:
            raise DiligentError(f"has {len(lines)} rows; the {H}x{W} images need {H * W} (one pixel a row, rows "
                                "top to bottom)", path=txt, field="rows")
        try:
            flat = np.array(" ".join(lines).replace(",", " ").split(), dtype=float)
        except ValueError:
            flat = np.empty(0)
        if flat.size != 3 * H * W:  # find the first bad row to name it
            for i, s in enumerate(_read_text(txt).splitlines(), 1):
                parts = s.replace(",", " ").split()
                try:
                    ok = not parts or (len(parts) == 3 and len([float(v) for v in parts]) == 3)
                except ValueError:
                    ok = False
                if not ok:
                    raise DiligentError(f"not 3 numbers: {s.strip()[:60]!r}", path=txt, field=f"row {i}")
            raise DiligentError("not 3 numbers per row", path=txt, field="rows")  # pragma: no cover
        n, path, where = flat.reshape(H, W, 3), txt, "rows"
    else:
        return None, None
    if np.isinf(n).any():
        raise DiligentError(f"{int(np.isinf(n).any(axis=-1).sum())} pixel(s) hold infinite values", path=path,
                            field=where)
    return n, path.name


def read_diligent(folder, *, pixel_pitch_mm: float = 0.01) -> DiligentSet:
    """Read a DiLiGenT object folder.

    Accepts what DiLiGenT and the folders users make in its layout hold:
    8- or 16-bit PNG images (RGB, grey, with or without alpha, palette),
    light files with blank lines (rows of 3 numbers, space, tab or comma
    separated), ``filenames.txt`` absent (then the numbered ``NNN.png`` in
    number order), ``light_intensities.txt`` absent (all ones),
    ``mask.png`` absent (every pixel), normals from ``Normal_gt.mat`` or
    ``normal.txt`` or none. A ``shinysim.json`` of an export restores the
    frames' clip level (the stack's saturation) and goes into the
    provenance.

    Parameters
    ----------
    folder : path-like
    pixel_pitch_mm : float
        Pixel size given to the orthographic camera (DiLiGenT does not say
        one; it only scales surface positions).

    Returns
    -------
    DiligentSet

    Raises
    ------
    DiligentError
        Naming the file and field: a missing folder, light file or image; a
        row that is not 3 numbers, a zero or non-finite direction, a
        negative or zero intensity; counts that disagree between
        ``filenames.txt``, the light files and the images; images of
        different sizes; an unreadable PNG or MATLAB file; ``Normal_gt``
        missing or of the wrong shape; a ``normal.txt`` of the wrong length.
    OptionError
        A bad ``pixel_pitch_mm``.
    """
    pitch = check_number("pixel_pitch_mm", pixel_pitch_mm, lo=0, lo_open=True)
    try:
        folder = Path(folder)
    except TypeError:
        raise OptionError(f"folder must be a path, got {folder!r}") from None
    if not folder.exists():
        raise DiligentError("no such folder", path=folder)
    if not folder.is_dir():
        raise DiligentError("is not a folder (a DiLiGenT object is a folder of images and light files)",
                            path=folder)
    names, names_from = _image_list(folder)
    n = len(names)

    ld_path = folder / "light_directions.txt"
    directions, ld_lines = _read_rows(ld_path, "a light direction x y z", n, names_from)
    norms = np.linalg.norm(directions, axis=1)
    for k in range(n):
        if not (norms[k] > 0 and np.all(np.isfinite(directions[k] / norms[k]))):
            raise DiligentError(f"zero vector {directions[k].tolist()}: not a direction", path=ld_path,
                                field=f"row {ld_lines[k]}")
    directions = directions / norms[:, None]

    li_path = folder / "light_intensities.txt"
    if li_path.exists():
        intensities, li_lines = _read_rows(li_path, "an intensity R G B", n, names_from)
        for k in range(n):
            if np.any(intensities[k] < 0):
                raise DiligentError(f"negative intensity {intensities[k].tolist()}", path=li_path,
                                    field=f"row {li_lines[k]}")
            if np.any(intensities[k] == 0):
                raise DiligentError(f"zero intensity {intensities[k].tolist()}: the image cannot be divided by it",
                                    path=li_path, field=f"row {li_lines[k]}")
        intensities_from = "light_intensities.txt"
    else:
        intensities = np.ones((n, 3))
        intensities_from = "none (light_intensities.txt absent): all ones"

    export = _read_export_info(folder)
    frames = None
    first = None
    depths = set()
    for k, name in enumerate(names):
        path = folder / name
        if not path.exists():
            raise DiligentError(f"no such file (image {k + 1} of {n}, listed by {names_from})", path=path,
                                field="image")
        if path.suffix.lower() != ".png":
            raise DiligentError("is not a PNG file; DiLiGenT images are PNG", path=path, field="image")
        img, top = _read_png(path, "image")
        depths.add(top)
        if frames is None:
            H, W = img.shape[:2]
            first = name
            if n * H * W > 16 * MAX_PIXELS:  # the limit of io's stack reader: 4 GiB of float32 frames
                raise DiligentError(f"{n} images of {W} x {H} pixels are more than shinysim reads "
                                    f"({16 * MAX_PIXELS} pixels in all)", path=folder, field="images")
            frames = np.empty((n, H, W), np.float32)
        elif img.shape[:2] != frames.shape[1:]:
            raise DiligentError(f"is {img.shape[0]}x{img.shape[1]} (H x W) but {first} is "
                                f"{frames.shape[1]}x{frames.shape[2]}", path=path, field="size")
        value = img.astype(np.float64) / top
        if value.shape[2] == 1:  # grey: the same value in R, G and B
            frames[k] = value[..., 0] * np.mean(1.0 / intensities[k])
        else:
            frames[k] = np.mean(value[..., :3] / intensities[k], axis=-1)
    H, W = frames.shape[1:]

    mask_path = folder / "mask.png"
    if mask_path.exists():
        m, _ = _read_png(mask_path, "mask")
        if m.shape[:2] != (H, W):
            raise DiligentError(f"is {m.shape[0]}x{m.shape[1]} (H x W) but the images are {H}x{W}", path=mask_path,
                                field="size")
        mask = m[..., 0] > 0
        mask_from = "mask.png"
    else:
        mask = np.ones((H, W), bool)
        mask_from = "none (mask.png absent): every pixel"

    raw_normals, normals_from = _read_normals(folder, (H, W))
    normals = truth = None
    if raw_normals is not None:
        length = np.linalg.norm(np.nan_to_num(raw_normals), axis=-1)
        known = mask & (length > 0) & np.all(np.isfinite(raw_normals), axis=-1)
        normals = np.where(known[..., None], raw_normals, np.nan)

    field_width = W * pitch
    cam = Camera("orthographic", W, H, [0.0, 0.0, max(1000.0, 10.0 * field_width)], [0.0, 0.0, 0.0],
                 [0.0, 1.0, 0.0], field_width, name="diligent")
    rig = distant_rig(directions, cam, name=folder.name or "diligent")

    # clip level of each frame: the largest code (or the exported stack's clip) through the same division
    clip_value = 1.0
    if export is not None:
        sat = export.get("saturation_code")
        clip_value = None if sat is None else float(sat) / 65535.0
    clips = None if clip_value is None else clip_value * np.mean(1.0 / intensities, axis=1)
    saturation = None
    if clips is not None and np.allclose(clips, clips[0], rtol=1e-9, atol=0):
        saturation = float(clips[0])
    provenance: dict[str, Any] = {
        "source": "DiLiGenT folder",
        "folder": os.fspath(folder),
        "filenames": names,
        "filenames_from": names_from,
        "bit_depths": sorted(int(math.log2(d + 1)) for d in depths),
        "frame_value": "mean over R, G, B of (code / largest code) / light intensity of the channel",
        "light_intensities_from": intensities_from,
        "mask_from": mask_from,
        "normals_from": normals_from,
        "pixel_pitch_mm": pitch,
    }
    if clips is not None and saturation is None:
        provenance["clip_levels"] = clips.tolist()
    if export is not None:
        provenance["export"] = {k: export.get(k) for k in ("scale", "origin_mm", "origin_from", "provenance",
                                                            "camera", "camera_index", "generator")}
    stack = Stack(frames, rig, 0, json_safe(provenance), saturation)
    if normals is not None:
        world = world_frame(normals, cam).astype(np.float32)
        known = np.all(np.isfinite(normals), axis=-1)
        truth = Truth(world, np.full((H, W, 3), np.nan, np.float32), known,
                      metadata={"source": normals_from, "positions": "unknown (DiLiGenT gives normals only)"})
    return DiligentSet(stack=stack, mask=mask, normals=normals, truth=truth, light_directions=directions,
                       light_intensities=intensities, filenames=names)
