"""The surface element of the paper's Figs. 5-6: a small flat mirror facet.

A square facet of side ``size`` centred at ``center`` with unit normal
``normal``. Turned by :func:`facet_normal` so that it reflects one source
into the camera, it is the "surface element" whose camera-model errors Eqs
11-17 predict; :func:`shinysim.sim.scene.facet_object` renders it and
:mod:`shinysim.studies.camera_models` holds the two against each other.
numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..conventions import bisector
from ..errors import OptionError
from .shapes import _vector

__all__ = ["FACET_SIZE_MM", "Facet", "facet_normal"]

#: Side of the simulated surface element (facet), millimetres. It is smaller
#: than the reflection of a 1.016 mm fiber in a flat mirror seen from the
#: camera (radius about 0.28 mm at f = 2.115 in, 0.38 mm at 5 in), so the
#: whole facet lights up and the highlight's centroid is the facet's centre.
FACET_SIZE_MM = 0.2


@dataclass(frozen=True)
class Facet:
    """A flat square facet.

    Parameters
    ----------
    center : (3,) float, millimetres
    normal : (3,) float
        Normalised here; must be non-zero.
    size : float, millimetres
        Side of the square, > 0.
    """

    center: tuple
    normal: tuple
    size: float = FACET_SIZE_MM

    def __post_init__(self):
        c = _vector("center", self.center)
        n = np.asarray(self.normal, dtype=float)
        norm = np.linalg.norm(n) if n.shape == (3,) else 0.0
        if not (np.isfinite(norm) and norm > 0):
            raise OptionError(f"normal must be a non-zero 3-vector, got {self.normal!r}")
        if not (np.isfinite(self.size) and self.size > 0):
            raise OptionError(f"size must be > 0 mm, got {self.size!r}")
        object.__setattr__(self, "center", tuple(float(v) for v in c))
        object.__setattr__(self, "normal", tuple(float(v) for v in n / norm))
        object.__setattr__(self, "size", float(self.size))

    def to_world(self):
        """(4, 4) float: maps the square [-1, 1]^2 (normal +z) onto the facet.

        One in-plane edge runs along ``y x normal``, so a facet whose normal
        lies in the x-z plane is tilted about the y axis only (the surface
        element of the paper's Figs. 5-6).
        """
        n = np.asarray(self.normal)
        u = np.cross([0.0, 1.0, 0.0], n)
        if np.linalg.norm(u) < 1e-9:  # normal along +-y: take the x axis instead
            u = np.cross(n, [0.0, 0.0, 1.0])
        u /= np.linalg.norm(u)
        v = np.cross(n, u)  # u x v = n: the square's +z lands on the normal
        m = np.eye(4)
        m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = 0.5 * self.size * u, 0.5 * self.size * v, n, self.center
        return m


def facet_normal(center, source, camera):
    """Unit normal that reflects ``source`` into ``camera`` at ``center``.

    Parameters
    ----------
    center, source : (..., 3) array_like, millimetres
    camera : shinysim.rig.Camera
        Perspective: towards its centre of projection; orthographic: along
        ``-forward``.

    Returns
    -------
    (..., 3) ndarray
    """
    center = np.asarray(center, dtype=float)
    to_source = np.asarray(source, dtype=float) - center
    return bisector(to_source, camera.view_directions(center))
