"""The paper's analytic models, numpy only.

* :mod:`shinysim.theory.reflectance`: the reflectance map (Eqs 5-8) and the
  sharpness/roughness relation;
* :mod:`shinysim.theory.sensitivity`: the camera-model error analysis
  (Eqs 11-17, Figs. 5-6), correct and printed forms;
* :mod:`shinysim.theory.mirror`: exact highlights on a mirror sphere;
* :mod:`shinysim.theory.stereo`: structured-highlight stereo (Eqs 18-45),
  correct and printed forms, with exact synthetic highlights;
* :mod:`shinysim.theory.coding`: coded (multiplexed) source displays: binary,
  Gray and Hadamard codes, and the superposition that makes a coded frame;
* :mod:`shinysim.theory.phase`: phase codes for a dense source array (a
  display): N-step phase shifting at several periods, and its noise law.

Their figures are drawn by :mod:`shinysim.plot.theory` and :mod:`shinysim.plot.stereo`.
"""

from __future__ import annotations

import sys

from . import coding, mirror, phase, reflectance, sensitivity, stereo
from .coding import *  # noqa: F403
from .mirror import *  # noqa: F403
from .phase import *  # noqa: F403
from .reflectance import (COMBINE_METHODS, DISTRIBUTIONS, alpha_from_sharpness, lobe_hwhm, peak_angles,
                          peak_gradient, peak_normal, reflectance_map, sharpness_from_alpha)
from .sensitivity import *  # noqa: F403
from .stereo import *  # noqa: F403

del CONVENTIONS  # noqa: F821 -- each model has its own (sensitivity.CONVENTIONS, ...), reached through its module

#: Names left to their modules: ``reflectance.reflectance`` (the module keeps the name) and each ``CONVENTIONS``.
_HIDDEN = {"reflectance", "CONVENTIONS"}
_PARTS = ("coding", "mirror", "phase", "reflectance", "sensitivity", "stereo")
__all__ = [*_PARTS, *(n for part in _PARTS for n in sys.modules[f"{__name__}.{part}"].__all__ if n not in _HIDDEN)]
