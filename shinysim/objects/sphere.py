"""The calibration sphere: a polished ball of known radius, and its exact truth.

The paper calibrates on "a 1/16-inch diameter polished sphere" (Section IV,
Figs. 9-10). Its truth is exact: the normal at a surface point is the unit
vector from the centre. The simulator builds its Mitsuba sphere from a
:class:`Sphere` (:func:`shinysim.sim.scene.sphere_object`); scoring and the
mirror-sphere oracle (:mod:`shinysim.theory.mirror`) use the same numbers.
numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..conventions import MM_PER_INCH, normalize
from ..errors import CalibrationError, OptionError
from .plate import _positive_mm
from .shapes import _vector

__all__ = ["SHINY_SPHERE_RADIUS_MM", "Sphere", "CALIBRATION_SPHERE", "SpherePlacement"]

#: Radius of the paper's 1/16 in calibration sphere, millimetres (0.79375).
SHINY_SPHERE_RADIUS_MM = 0.5 * MM_PER_INCH / 16


@dataclass(frozen=True)
class Sphere:
    """A sphere in the world frame.

    Parameters
    ----------
    center : (3,) float, millimetres
    radius : float, millimetres, > 0
    """

    center: tuple = (0.0, 0.0, 0.0)
    radius: float = SHINY_SPHERE_RADIUS_MM

    def __post_init__(self):
        c = _vector("center", self.center)
        if not (isinstance(self.radius, (int, float, np.floating, np.integer)) and self.radius > 0
                and np.isfinite(self.radius)):
            raise OptionError(f"radius must be > 0 mm, got {self.radius!r}")
        object.__setattr__(self, "center", tuple(float(v) for v in c))
        object.__setattr__(self, "radius", float(self.radius))

    def normal_at(self, points):
        """Outward unit normals at ``points``.

        Parameters
        ----------
        points : (..., 3) array_like, millimetres
            Points on (or near) the surface.

        Returns
        -------
        (..., 3) ndarray
            The unit vector from the centre through each point.
        """
        return normalize(np.asarray(points, dtype=float) - np.asarray(self.center))


#: The paper's calibration sphere, centred at the world origin on the reference plane.
CALIBRATION_SPHERE = Sphere()


@dataclass(frozen=True)
class SpherePlacement:
    """A calibration sphere at a known place (what ``spheres.json`` gives each scan).

    Parameters
    ----------
    center : (3,) float, millimetres, world frame
    radius : float, millimetres, > 0
    """

    center: tuple[float, float, float]
    radius: float

    def __post_init__(self):
        try:
            c = np.asarray(self.center, dtype=float)
        except (TypeError, ValueError):
            c = np.zeros(0)
        if c.shape != (3,) or not np.all(np.isfinite(c)):
            raise CalibrationError(f"must be 3 finite numbers, got {self.center!r}", field="center")
        object.__setattr__(self, "center", tuple(float(v) for v in c))
        object.__setattr__(self, "radius", _positive_mm(self.radius, "radius", "radius"))

    def to_dict(self) -> dict:
        return {"center_mm": list(self.center), "radius_mm": self.radius}
