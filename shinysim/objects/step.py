"""The machined part of the coded scans: two crowned plateaus joined by a smooth step, exact heights and normals."""

from __future__ import annotations

import numpy as np

from ..conventions import normalize
from .shapes import _grid_mesh

__all__ = ["STEP_PART", "step_height", "step_gradient", "step_mesh"]


#: The machined part: ``z = z0 - (x^2 + y^2) / (2 crown) + step (1 + tanh(x / flank)) / 2``, mm. Two
#: crowned plateaus (a flat plateau has one normal and so mirrors at most one source of a dome;
#: a slight crown, radius 2.5 mm, shows it the dome) joined along x = 0 by a smooth flank 0.2 mm
#: high whose steepest slope, ``step / (2 flank)``, is 34 degrees: inside the 40 degrees an 80
#: degree dome reaches, so the flank is measured, not a gap.
STEP_PART = {"size_mm": 1.8, "z0_mm": 0.4, "crown_mm": 2.5, "step_mm": 0.2, "flank_mm": 0.15, "vertices": 241}


def step_height(x, y, part=STEP_PART):
    """Height of the machined part (:data:`STEP_PART`), mm."""
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    return (part["z0_mm"] - (x * x + y * y) / (2 * part["crown_mm"])
            + 0.5 * part["step_mm"] * (1 + np.tanh(x / part["flank_mm"])))


def step_gradient(x, y, part=STEP_PART):
    """The part's height gradient ``(dz/dx, dz/dy)`` at ``(x, y)``."""
    sech2 = 1.0 / np.cosh(x / part["flank_mm"]) ** 2
    return (-x / part["crown_mm"] + 0.5 * part["step_mm"] * sech2 / part["flank_mm"], -y / part["crown_mm"])


def step_mesh(part=STEP_PART):
    """The machined part as a :class:`~shinysim.objects.shapes.TriangleMesh` with analytic normals."""
    def surface(x, y):
        p, q = step_gradient(x, y, part)
        return step_height(x, y, part), normalize(np.stack([-p, -q, np.ones_like(p)], axis=1))

    return _grid_mesh(part["size_mm"], int(part["vertices"]), surface, "mesh", {"step_part": dict(part)})
