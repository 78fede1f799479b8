"""Which sources stand in a camera's view of its field, and the arrays left when they are taken out."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from ..errors import OptionError
from .core import Camera

__all__ = ["sources_in_view", "drop_sources_in_view"]


def sources_in_view(positions: ArrayLike, radii: ArrayLike, camera: Camera) -> np.ndarray:
    """Which near sources would stand in ``camera``'s view of its field.

    A source (a sphere of radius ``radii[k]`` at ``positions[k]``) hides part
    of the object when it enters the pyramid of rays from the camera to the
    square field at its target; the test uses the cone through the field's
    corners (half-diagonal ``field_width / sqrt(2)``), so it errs on the side
    of refusing.

    Returns
    -------
    (n,) bool
    """
    pos = np.asarray(positions, dtype=float)
    radii = np.broadcast_to(np.asarray(radii, dtype=float), pos.shape[:1])
    start = np.asarray(camera.position, float)
    axis = np.asarray(camera.target, float) - start
    length = float(np.linalg.norm(axis))
    axis = axis / length
    rel = pos - start
    along = rel @ axis
    lateral = np.linalg.norm(rel - along[:, None] * axis, axis=1)
    half = camera.field_width / np.sqrt(2.0)
    cone = half if camera.projection == "orthographic" else half * along / length
    return (along > 0) & (along < length) & (lateral - radii < cone)


def drop_sources_in_view(positions: ArrayLike, radii: ArrayLike, cameras: Sequence[Camera], *,
                         what: str = "source") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Near sources left when those standing in any camera's view (:func:`sources_in_view`) are taken out.

    A built array has holes where the cameras look through it.

    Returns
    -------
    positions, radii : ndarray
        The sources kept.
    hidden : (n,) bool
        Which were taken out.

    Raises
    ------
    ValueError
        Every ``what`` stands in a camera's view.
    """
    pos = np.asarray(positions, dtype=float)
    radii = np.broadcast_to(np.asarray(radii, dtype=float), pos.shape[:1])
    hidden = np.zeros(len(pos), bool)
    for cam in cameras:
        hidden |= sources_in_view(pos, radii, cam)
    if hidden.all():
        raise OptionError(f"every {what} lies in {'the' if len(cameras) == 1 else 'a'} camera's view of the object")
    return pos[~hidden], radii[~hidden], hidden
