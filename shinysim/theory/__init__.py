"""The paper's analytic models, numpy only.

* :mod:`shinysim.theory.reflectance`: the reflectance map (Eqs 5-8) and the
  sharpness/roughness relation;
* :mod:`shinysim.theory.sensitivity`: the camera-model error analysis
  (Eqs 11-17, Figs. 5-6), correct and printed forms;
* :mod:`shinysim.theory.mirror`: exact highlights on a mirror sphere;
* :mod:`shinysim.theory.stereo`: structured-highlight stereo (Eqs 18-45),
  correct and printed forms, with exact synthetic highlights;
* :mod:`shinysim.theory.coding`: coded (multiplexed) source displays: binary,
  Gray and Hadamard codes, and the superposition that makes a coded frame.

Their figures are drawn by :mod:`shinysim.plot.theory` and :mod:`shinysim.plot.stereo`.
"""

from . import coding, mirror, reflectance, sensitivity, stereo

__all__ = ["coding", "mirror", "reflectance", "sensitivity", "stereo"]
