"""What is scanned, and its exact truth (numpy only, no renderer).

* :mod:`shinysim.objects.sphere`: the calibration sphere;
* :mod:`shinysim.objects.facet`: the flat mirror facet of the paper's Figs. 5-6;
* :mod:`shinysim.objects.solder`: procedural solder joints, their classes,
  parameters and exact cross-section profiles;
* :mod:`shinysim.objects.criteria`: acceptance classes of a joint decided by
  criteria on its geometry (IPC-A-610 style);
* :mod:`shinysim.objects.step`: the machined part of the coded scans;
* :mod:`shinysim.objects.registry`: every scanned object by name, with its
  parts and exact truth (what the studies, data sets and CLI offer).

:mod:`shinysim.sim` builds Mitsuba scenes *from* these objects, and the
reconstruction and scoring use the same numbers without the renderer (the
pad height a solder inspection anchors its profile at, for one).
"""

from . import criteria, facet, solder, sphere, step
from .facet import FACET_SIZE_MM, Facet, facet_normal
from .solder import JOINT_KINDS, PAD_THICKNESS, JointParams, JointProfile, sample_params
from .sphere import CALIBRATION_SPHERE, SHINY_SPHERE_RADIUS_MM, Sphere

__all__ = [
    "criteria",
    "facet",
    "solder",
    "sphere",
    "step",
    "FACET_SIZE_MM",
    "Facet",
    "facet_normal",
    "JOINT_KINDS",
    "PAD_THICKNESS",
    "JointParams",
    "JointProfile",
    "sample_params",
    "CALIBRATION_SPHERE",
    "SHINY_SPHERE_RADIUS_MM",
    "Sphere",
]
