"""What is scanned, and its exact truth (numpy only, no renderer).

* :mod:`shinysim.objects.sphere`: the calibration sphere;
* :mod:`shinysim.objects.facet`: the flat mirror facet of the paper's Figs. 5-6;
* :mod:`shinysim.objects.mirror`: a large mirror facet (a paraboloid and a known
  ripple) and its exact truth, for display deflectometry;
* :mod:`shinysim.objects.solder`: procedural solder joints, their classes,
  parameters and exact cross-section profiles;
* :mod:`shinysim.objects.criteria`: acceptance classes of a joint decided by
  criteria on its geometry (IPC-A-610 style);
* :mod:`shinysim.objects.step`: the machined part of the coded scans;
* :mod:`shinysim.objects.plate`: the calibration hole plate;
* :mod:`shinysim.objects.shapes`: smooth random objects for synthetic data
  sets (blobs, superquadrics, height fields) as triangle meshes;
* :mod:`shinysim.objects.registry`: every scanned object by name, with its
  parts and exact truth (what the studies, data sets and CLI offer).

:mod:`shinysim.sim` builds Mitsuba scenes *from* these objects, and the
reconstruction and scoring use the same numbers without the renderer (the
pad height a solder inspection anchors its profile at, for one).
"""

from __future__ import annotations

from . import criteria, facet, mirror, plate, registry, shapes, solder, sphere, step
from .criteria import *  # noqa: F403
from .facet import *  # noqa: F403
from .mirror import *  # noqa: F403
from .plate import *  # noqa: F403
from .registry import *  # noqa: F403
from .shapes import *  # noqa: F403
from .solder import *  # noqa: F403
from .sphere import *  # noqa: F403
from .step import *  # noqa: F403

__all__ = ["criteria", "facet", "mirror", "plate", "registry", "shapes", "solder", "sphere", "step",
           *criteria.__all__, *facet.__all__, *mirror.__all__, *plate.__all__, *registry.__all__, *shapes.__all__, *solder.__all__, *sphere.__all__,
           *step.__all__]
