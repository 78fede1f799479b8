"""Coded scans: :class:`CodedStack`, and its files ``coded.npz`` and ``code.json``.

The contract between the two halves of a coded scan, read without the
simulator: :func:`shinysim.sim.coded.coded_stack` makes a coded stack,
:func:`shinysim.recon.coding.decode` reads one. ``code.json`` holds the code
and the settings the scan decoded with, so a folder decodes again as the scan
did; ``docs/file-format.md`` specifies both files.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._shared import json_safe, write_file, write_json
from ..errors import OptionError, StackFormatError
from ..rig import Rig
from ..theory.coding import Code
from .document import parse_json, read_document
from .stack import load_stack

__all__ = ["CodedStack", "write_coded_scan", "read_coded_scan", "DETECT_FIELDS"]

#: The detection settings ``code.json``'s ``decode.detect`` keeps.
DETECT_FIELDS = ("threshold", "threshold_mode", "smooth_px", "max_area")


@dataclass
class CodedStack:
    """The frames of a coded scan of one camera.

    Attributes
    ----------
    frames : (n_frames, H, W) float32
        With a sensor: digital numbers over the top code, in [0, 1] (the
        black level ``dark_offset / (2**bits - 1)`` included). Without:
        ideal radiance (the code's sums of the rendered frames).
    code : Code
    rig : Rig
    camera_index : int
    saturation : float or None
        The clip level (1.0 with a sensor), None for ideal radiance.
    sensor : Sensor or None
        The sensor, with the exposure it was used at (a
        :class:`shinysim.sim.sensor.Sensor`; None for a folder read back,
        whose sensor levels are in its decode settings).
    provenance : dict
        The stack's provenance plus the code (``"code"``) and, with a
        sensor, ``"sensor"`` and ``"sensor_seed"``; colour scans also
        ``"colour"`` (crosstalk, leak, fiber emission, mixing).
    mixing : (3, 3) float64 or None
        Colour scans: :func:`shinysim.sim.coded.colour_mixing` of the scan's
        crosstalk and leak, column ``c`` the camera's response to fiber
        colour ``c`` (the decoder's unmixing matrix). None for scans of one
        colour, whose ``frames`` are (n_frames, H, W); colour frames are
        (n_frames, H, W, 3).
    """

    frames: np.ndarray
    code: Code
    rig: Rig
    camera_index: int = 0
    saturation: float | None = None
    sensor: Any = None
    provenance: dict[str, Any] = field(default_factory=dict)
    mixing: np.ndarray | None = None

    @property
    def n_frames(self) -> int:
        return int(self.frames.shape[0])

    @property
    def n_sources(self) -> int:
        return self.code.n_sources


def _sensor_levels(sensor) -> dict:
    """The decoder's black level and shot gain (frame units) of a sensor (or of its ``to_dict``)."""
    get = sensor.get if isinstance(sensor, dict) else lambda k: getattr(sensor, k)
    top = 2 ** int(get("bits")) - 1
    gain = (top - get("dark_offset")) / get("full_well")
    return {"background": get("dark_offset") / top, "shot_gain": gain / top if get("shot_noise") else 0.0}


def write_coded_scan(folder: str | os.PathLike, coded: CodedStack, detect: dict) -> None:
    """Write ``coded.npz`` and ``code.json`` into ``folder`` (a scan's temporary folder: files are replaced).

    ``detect`` holds the :data:`DETECT_FIELDS` the scan's decoding followed.
    """
    folder = Path(folder)

    def write(f):
        with open(f, "wb") as fh:
            np.savez_compressed(fh, frames=coded.frames, saturation=np.nan if coded.saturation is None
                                else coded.saturation, provenance=json.dumps(json_safe(coded.provenance)))

    write_file(folder / "coded.npz", write)
    settings = {"detect": {k: detect[k] for k in DETECT_FIELDS}}
    if coded.sensor is not None:
        settings.update(_sensor_levels(coded.sensor))
    write_json(folder / "code.json", coded.code.to_dict() | {"decode": settings})


def _settings(folder: Path, decode: dict | None, provenance: dict) -> dict:
    """The decode settings of ``code.json`` or, in a folder written before it held them, of the scan's
    ``score.json`` (``sequential.detect``) and the sensor of ``coded.npz``."""
    if decode is None:
        decode = {}
        score = folder / "score.json"
        if score.exists():
            detect = read_document(score, error=OptionError).get("sequential", {}).get("detect")
            if detect is not None:
                decode["detect"] = detect
        if "sensor" in provenance:
            decode.update(_sensor_levels(provenance["sensor"]))
    where = folder / "code.json"
    if not isinstance(decode, dict) or not isinstance(decode.get("detect", {}), dict):
        raise OptionError("must be an object of decode settings ({'detect': {...}, ...})", path=where,
                          field="decode")
    return decode


def read_coded_scan(folder: str | os.PathLike, *, code: Code | None = None, make_code=None
                    ) -> tuple[CodedStack, dict]:
    """A coded scan folder's coded stack (``sensor`` None: its levels are in the settings) and
    ``code.json``'s decode settings (``detect``; with a sensor ``background`` and ``shot_gain``).

    ``code`` replaces the folder's ``code.json`` code; ``make_code(rig, colours)`` builds one for the
    folder's rig and frames. A code whose colours, frame or source count disagree with the folder is an
    :class:`~shinysim.errors.OptionError` on ``code``; unreadable frames a
    :class:`~shinysim.errors.StackFormatError`.
    """
    folder = Path(folder)
    stack = load_stack(folder / "stack.exr")
    npz = folder / "coded.npz"
    try:
        with np.load(npz) as z:
            frames = z["frames"]
            sat = float(z["saturation"])
            prov = parse_json(str(z["provenance"]), error=StackFormatError, path=npz, field="provenance")
    except (OSError, KeyError, ValueError) as exc:
        if isinstance(exc, StackFormatError):
            raise
        raise StackFormatError(f"not a coded scan's frames ({exc})", path=npz) from None
    colours = 3 if frames.ndim == 4 else 1
    doc = read_document(folder / "code.json", error=OptionError)
    decode = doc.pop("decode", None)
    if make_code is not None:
        code = make_code(stack.rig, colours)
    elif code is None:
        code = Code.from_dict(doc)
    if code.colours != colours:
        raise OptionError(f"is a code of {code.colours} colour(s) but {npz} holds "
                          f"{'RGB' if colours == 3 else 'grey'} frames", field="code")
    if code.n_sources != stack.n_sources:
        raise OptionError(f"is a {code.name} code for {code.n_sources} sources but the stack has "
                          f"{stack.n_sources}", field="code")
    if code.n_frames != len(frames):
        raise OptionError(f"a {code.name} code of {code.n_sources} sources has {code.n_frames} frames but "
                          f"{npz} holds {len(frames)}", field="code")
    mixing = np.array(prov["colour"]["mixing"], float) if colours == 3 and "colour" in prov else None
    if colours == 3 and mixing is None:
        raise OptionError("holds RGB frames but no mixing matrix in its provenance ('colour': {'mixing': ...})",
                          field=str(npz))
    coded = CodedStack(frames, code, stack.rig, stack.camera_index, None if math.isnan(sat) else sat, None, prov,
                       mixing)
    return coded, _settings(folder, decode, prov)
