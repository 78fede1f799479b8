"""Calibration: the camera from hole-plate images, the sources from mirror-sphere scans.

The reconstruction side of the package (numpy, scipy, scikit-image; never a
renderer): it takes images a real rig or the simulator made, plus the
*nominal* rig, and returns a calibrated rig with what was estimated, its
residuals and its uncertainties. ``docs/calibration.md`` describes the
methods and what they need.
"""

from __future__ import annotations

from ..io.calibration import read_plate_images, read_sphere_scans
from . import camera, from_files, sources
from .camera import *  # noqa: F403
from .from_files import *  # noqa: F403
from .sources import *  # noqa: F403

__all__ = ["camera", "from_files", "sources", *camera.__all__, *from_files.__all__, *sources.__all__,
           "read_plate_images", "read_sphere_scans"]
