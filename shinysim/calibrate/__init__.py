"""Calibration: the camera from hole-plate images, the sources from mirror-sphere scans.

The reconstruction side of the package (numpy, scipy, scikit-image; never a
renderer): it takes images a real rig or the simulator made, plus the
*nominal* rig, and returns a calibrated rig with what was estimated, its
residuals and its uncertainties. ``docs/calibration.md`` describes the
methods and what they need.
"""

from .camera import (
    CameraCalibration,
    calibrate_camera,
    camera_parameters,
    find_holes,
    ray_errors,
)
from ..io.calibration import read_plate_images, read_sphere_scans
from .sources import (
    SourceCalibration,
    SphereObservation,
    SpherePlacement,
    calibrate_sources,
    distant_directions,
    observe_sphere,
    reflected_rays,
)

__all__ = [
    "find_holes",
    "calibrate_camera",
    "camera_parameters",
    "ray_errors",
    "CameraCalibration",
    "SpherePlacement",
    "SphereObservation",
    "SourceCalibration",
    "reflected_rays",
    "distant_directions",
    "observe_sphere",
    "calibrate_sources",
    "read_plate_images",
    "read_sphere_scans",
]
