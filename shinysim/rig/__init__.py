"""Rig descriptions: light sources, cameras and the reference plane.

Pure data (numpy + dataclasses); no renderer. The parts:
:mod:`~shinysim.rig.core` (:class:`Camera`, :class:`Anchor`, :class:`Rig`
and their JSON form; :func:`shinysim.io.load_rig` reads a file), :mod:`~shinysim.rig.presets` (the
paper's and other source arrays, and :data:`RIG_PRESETS`, the one registry
of them by name), :mod:`~shinysim.rig.visibility` (sources in a camera's
view), :mod:`~shinysim.rig.tolerances` (a built rig drawn from a nominal
one), :mod:`~shinysim.rig.opencv` (a camera to and from OpenCV's
``K, dist, rvec, tvec``) and :mod:`~shinysim.rig.display` (a display's dots as a
source array, and the geometry of a display-deflectometry setup). Frames and units are those of
:mod:`shinysim.conventions`; the JSON form is in ``docs/file-format.md``.
"""

from __future__ import annotations

from . import core, display, opencv, presets, tolerances, visibility
from .core import *  # noqa: F403
from .display import *  # noqa: F403
from .opencv import *  # noqa: F403
from .presets import *  # noqa: F403
from .tolerances import *  # noqa: F403
from .visibility import *  # noqa: F403

__all__ = [*core.__all__, *display.__all__, *opencv.__all__, *presets.__all__, *tolerances.__all__, *visibility.__all__]
