"""The files a calibration reads: plate images with their placements, sphere scans with their centres.

Two small JSON documents, each beside (or naming) its images; paths inside
them are relative to the JSON file's folder.

``placements.json`` (camera calibration)::

    {"plate": {"holes_xy_mm": [[0, 0], [0.6, 0], ...], "hole_diameter_mm": 0.2032},   (optional; default 7 holes)
     "images": [{"file": "plate_00.exr", "placement": {"offset_mm": [0, 0, 0], "tilt_deg": [0, 0]}}, ...]}

``spheres.json`` (source calibration)::

    {"radius_mm": 0.79375,
     "scans": [{"folder": "sphere_00", "center_mm": [0, 0, 0]},               (a scan folder with stack.exr)
               {"frames": ["s1/f00.png", ...], "center_mm": [0.25, 0, 0]}]}  (or one image per source)

Errors name the file and the field (``spheres.json: scans[2].center_mm: ...``).
"""

from __future__ import annotations

import json
import math
import os
import sys
from pathlib import Path

import numpy as np

from ..errors import CalibrationError, ShinysimError, check_fields
from .document import read_document

__all__ = ["read_plate_images", "read_sphere_scans"]

#: Largest calibration JSON read, bytes.
MAX_JSON_BYTES = 4 * 2**20


def _int(text):
    """A JSON integer; one beyond the float range reads as an infinity, which the checks refuse as not finite."""
    value = int(text)
    return value if abs(value) <= sys.float_info.max else (math.inf if value > 0 else -math.inf)


def _document(path, what):
    path = Path(path)
    doc = read_document(path, error=CalibrationError, max_bytes=MAX_JSON_BYTES, what=what, parse_int=_int)
    return path, doc


def _list(doc, key, path, where=None):
    field = f"{where}.{key}" if where else key
    if key not in doc:
        raise CalibrationError("missing required field: must be a non-empty list", path=path, field=field)
    value = doc[key]
    if not isinstance(value, list) or not value:
        raise CalibrationError(f"must be a non-empty list, got {json.dumps(value)[:60]}", path=path, field=field)
    return value


def _nested(read, value, path, where, kind):
    """``read(value)``, its error naming ``path`` and ``where.field`` (``where`` alone for the reader's own
    ``kind``: an unknown key)."""
    try:
        return read(value)
    except ShinysimError as exc:
        field = f"{where}.{exc.field}" if exc.field and exc.field != kind else where
        raise CalibrationError(exc.problem, path=path, field=field) from None


def read_plate_images(path: str | os.PathLike):
    """The plate and its images from a ``placements.json``.

    Returns
    -------
    plate : HolePlate
    images : list of (PlatePlacement, (H, W) ndarray, str)
        Each image's placement, pixels and a name for messages.
    """
    from ..objects.plate import HolePlate, PlatePlacement, shiny_plate
    from .frames import read_frame

    path, doc = _document(path, "placements")
    check_fields(doc, ("plate", "images"), error=CalibrationError, path=path, field="placements")
    plate = _nested(HolePlate.from_dict, doc["plate"], path, "plate", "plate") if "plate" in doc else shiny_plate()
    images = []
    for i, entry in enumerate(_list(doc, "images", path)):
        where = f"images[{i}]"
        check_fields(entry, ("file", "placement"), error=CalibrationError, path=path, field=where)
        if not isinstance(entry.get("file"), str):
            raise CalibrationError("needs 'file', the image's path", path=path, field=where)
        placement = _nested(PlatePlacement.from_dict, entry.get("placement", {}), path, f"{where}.placement",
                            "placement")
        image, _ = read_frame(path.parent / entry["file"])
        images.append((placement, np.asarray(image, float), f"{path}: {where} ({entry['file']})"))
    return plate, images


def read_sphere_scans(path: str | os.PathLike, rig):
    """The calibration sphere's scans from a ``spheres.json``.

    Parameters
    ----------
    rig : Rig
        The rig the scans are read against (its camera and source count;
        e.g. the nominal rig with a calibrated camera).

    Returns
    -------
    list of (SpherePlacement, Stack, str)
    """
    from ..objects.sphere import SpherePlacement
    from .frames import stack_from_frames
    from .stack import load_stack

    path, doc = _document(path, "spheres")
    check_fields(doc, ("radius_mm", "scans"), error=CalibrationError, path=path, field="spheres")
    radius = doc.get("radius_mm")
    if isinstance(radius, bool) or not isinstance(radius, (int, float)) or not (np.isfinite(radius) and radius > 0):
        raise CalibrationError(f"must be the sphere's radius, a number > 0 mm, got {json.dumps(radius)}",
                               path=path, field="radius_mm")
    out = []
    for i, entry in enumerate(_list(doc, "scans", path)):
        where = f"scans[{i}]"
        check_fields(entry, ("folder", "frames", "center_mm"), error=CalibrationError, path=path, field=where)
        c = entry.get("center_mm")
        if (not isinstance(c, list) or len(c) != 3
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) for v in c)):
            raise CalibrationError(f"must be 3 finite numbers, got {json.dumps(c)[:60]}", path=path,
                                   field=f"{where}.center_mm")
        if ("folder" in entry) == ("frames" in entry):
            raise CalibrationError(("has both 'folder' and 'frames'; give one" if "folder" in entry else
                                    "needs 'folder' (a scan folder with stack.exr) or 'frames' (one image per "
                                    "source)"), path=path, field=where)
        if "folder" in entry:
            if not isinstance(entry["folder"], str) or not entry["folder"]:
                raise CalibrationError(f"must be the scan folder's path, got {json.dumps(entry['folder'])[:60]}",
                                       path=path, field=f"{where}.folder")
            # read against the given rig (its camera is the calibrated one), keeping the stack's camera and clip level
            stack = load_stack(path.parent / str(entry["folder"]) / "stack.exr", rig)
            name = f"{path}: {where} ({entry['folder']})"
        else:
            frames = _list(entry, "frames", path, where)
            for j, f in enumerate(frames):
                if not isinstance(f, str) or not f:
                    raise CalibrationError(f"must be an image file's path, got {json.dumps(f)[:60]}", path=path,
                                           field=f"{where}.frames[{j}]")
            try:
                stack = stack_from_frames([path.parent / f for f in frames], rig)
            except ShinysimError as exc:
                if exc.path is not None:  # names the frame file at fault
                    raise
                raise type(exc)(exc.problem, path=path, field=f"{where}.frames") from None
            name = f"{path}: {where} ({len(frames)} frames)"
        out.append((SpherePlacement(center=tuple(float(v) for v in c), radius=float(radius)), stack, name))
    return out
