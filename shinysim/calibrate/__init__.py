"""Calibration: the camera from hole-plate images, the sources from mirror-sphere scans.

The reconstruction side of the package (numpy, scipy, scikit-image; never a
renderer): it takes images a real rig or the simulator made, plus the
*nominal* rig, and returns a calibrated rig with what was estimated, its
residuals and its uncertainties. ``docs/calibration.md`` describes the
methods and what they need.
"""

__all__: list[str] = []
