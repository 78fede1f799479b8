"""Calibration from the files of a real rig: its nominal JSON, hole-plate images, sphere scans.

What ``shinysim calibrate camera`` and ``shinysim calibrate sources`` run:
:func:`camera_from_files` and :func:`sources_from_files` check the output
path before any work, read the inputs (:mod:`shinysim.io.calibration`), find
the holes or highlights, fit, and write the calibrated rig JSON. How the fits
work: ``docs/calibration.md``.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

from ..errors import OptionError
from ..io import load_rig
from ..io.calibration import read_plate_images, read_sphere_scans
from .camera import ESTIMATE_GROUPS, CameraCalibration, calibrate_camera, find_holes
from .sources import SourceCalibration, calibrate_sources, observe_sphere

__all__ = ["camera_from_files", "sources_from_files", "check_rig_output"]


def check_rig_output(out: str | os.PathLike, overwrite: bool) -> Path:
    """The path of the rig JSON file to write, checked before any work (a folder, a missing folder or an existing
    file would otherwise surface only at the end, naming the temporary file)."""
    out = Path(out)
    if out.is_dir():
        raise OptionError(f"--out {out} is a folder; give the path of the rig JSON file to write")
    if not out.parent.is_dir():
        raise OptionError(f"--out {out}: {out.parent} "
                          + ("is not a folder" if out.parent.exists() else "does not exist; create the folder first"))
    if os.path.lexists(out) and not overwrite:  # a dangling link counts
        raise FileExistsError(f"{out} exists; not overwriting it (pass --overwrite)")
    return out


def _start(rig, out, overwrite, pixel_sigma):
    """The checked output path and the nominal rig read from ``rig``, once ``pixel_sigma`` is checked."""
    out = check_rig_output(out, overwrite)
    if pixel_sigma is not None and not (math.isfinite(pixel_sigma) and pixel_sigma > 0):
        raise OptionError(f"--pixel-sigma must be a finite number of pixels > 0, got {pixel_sigma}")
    return out, load_rig(rig)


def camera_from_files(rig, plates, out, *, camera_index: int = 0, estimate: tuple[str, ...] | None = None,
                      pixel_sigma: float | None = None, overwrite: bool = False):
    """Calibrate camera ``camera_index`` of the nominal ``rig`` (a JSON path) from the plate images of ``plates``.

    ``estimate`` names groups of :data:`~shinysim.calibrate.camera.ESTIMATE_GROUPS`;
    None: the pose alone from one image (a flat plate cannot tell distance
    from focal length), every group from several. Writes the calibrated rig
    to ``out``; returns ``(rig, calibration, n_images, estimate)``.
    """
    out, nominal = _start(rig, out, overwrite, pixel_sigma)
    if not 0 <= camera_index < len(nominal.cameras):
        raise OptionError(f"--camera-index {camera_index}: the rig has {len(nominal.cameras)} camera(s), "
                          f"0 to {len(nominal.cameras) - 1}")
    plate, images = read_plate_images(plates)
    cam = nominal.cameras[camera_index]
    observations = [(plate, placement, find_holes(img, plate, placement, cam, name=name))
                    for placement, img, name in images]
    if estimate is None:
        estimate = ("pose",) if len(images) == 1 else tuple(ESTIMATE_GROUPS)
    cal: CameraCalibration = calibrate_camera(observations, cam, estimate=tuple(estimate), pixel_sigma=pixel_sigma,
                                              name=str(plates))
    calibrated = cal.apply(nominal, camera_index)
    calibrated.save(out, overwrite=overwrite)
    return calibrated, cal, len(images), tuple(estimate)


def sources_from_files(rig, spheres, out, *, pixel_sigma: float | None = None, require_positions: bool = False,
                       overwrite: bool = False):
    """Place the sources of ``rig`` (a JSON path, e.g. with a calibrated camera) from the sphere scans of ``spheres``.

    Writes the calibrated rig to ``out``; returns ``(rig, calibration, n_scans)``.
    """
    out, nominal = _start(rig, out, overwrite, pixel_sigma)
    scans = read_sphere_scans(spheres, nominal)
    observations = [observe_sphere(stack, placement, name=name) for placement, stack, name in scans]
    cal: SourceCalibration = calibrate_sources(observations, nominal.camera, nominal=nominal, pixel_sigma=pixel_sigma,
                                               require_positions=require_positions, name=str(spheres))
    calibrated = cal.apply(nominal)
    calibrated.save(out, overwrite=overwrite)
    return calibrated, cal, len(scans)
