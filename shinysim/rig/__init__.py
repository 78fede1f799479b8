"""Rig descriptions: light sources, cameras and the reference plane.

Pure data (numpy + dataclasses); no renderer. The parts:
:mod:`~shinysim.rig.core` (:class:`Camera`, :class:`Anchor`, :class:`Rig`
and their JSON form, :func:`load_rig`), :mod:`~shinysim.rig.presets` (the
paper's and other source arrays, and :data:`RIG_PRESETS`, the one registry
of them by name), :mod:`~shinysim.rig.visibility` (sources in a camera's
view) and :mod:`~shinysim.rig.tolerances` (a built rig drawn from a nominal
one). Frames and units are those of :mod:`shinysim.conventions`; the JSON
form is in ``docs/file-format.md``.
"""

from __future__ import annotations

from .core import (
    ANCHOR_KINDS,
    CAMERA_PROJECTIONS,
    MAX_RIG_BYTES,
    RIG_FORMAT,
    RIG_FORMATS_READ,
    RIG_SCHEMA,
    Anchor,
    Camera,
    Rig,
    RigError,
    load_rig,
)
from .presets import (
    DOME_LAYOUTS,
    DOME_RIM_DEG,
    RIG_PRESETS,
    SCAN_RIGS,
    STEREO_FIELD_WIDTH_MM,
    STEREO_RIGS,
    distant_rig,
    dome,
    fibonacci_hemisphere,
    rig_preset,
    ring_layout,
    rings_dome,
    rotating_semicircle,
    shiny_1988,
    shiny_1988_source_angles_deg,
    shiny_stereo,
    stereo_dome,
    stereo_pair,
    stereo_semicircle,
)
from .tolerances import RigTolerances, perturb_rig
from .visibility import drop_sources_in_view, sources_in_view

__all__ = [
    "ANCHOR_KINDS",
    "Anchor",
    "CAMERA_PROJECTIONS",
    "Camera",
    "MAX_RIG_BYTES",
    "RIG_FORMAT",
    "RIG_FORMATS_READ",
    "RIG_SCHEMA",
    "Rig",
    "RigError",
    "RigTolerances",
    "load_rig",
    "perturb_rig",
    "DOME_LAYOUTS",
    "DOME_RIM_DEG",
    "RIG_PRESETS",
    "SCAN_RIGS",
    "STEREO_FIELD_WIDTH_MM",
    "STEREO_RIGS",
    "rig_preset",
    "shiny_1988",
    "shiny_1988_source_angles_deg",
    "distant_rig",
    "dome",
    "rings_dome",
    "ring_layout",
    "fibonacci_hemisphere",
    "stereo_pair",
    "shiny_stereo",
    "stereo_dome",
    "stereo_semicircle",
    "rotating_semicircle",
    "sources_in_view",
    "drop_sources_in_view",
]
