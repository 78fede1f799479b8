"""shinysim: simulate and invert structured-highlight inspection of shiny surfaces.

The package is in two halves that meet at the stack files (:mod:`shinysim.io`):

* :mod:`shinysim.sim` renders rigs with Mitsuba 3 (the ``render`` extra);
* :mod:`shinysim.recon` inverts frames into normals with numpy and
  scikit-image only, and never imports a renderer.

:mod:`shinysim.rig` describes the hardware, :mod:`shinysim.evaluate` scores
recovered normals against truth and :mod:`shinysim.theory` holds the paper's
analytic models. Frames and units: :mod:`shinysim.conventions`.
"""

__version__ = "0.1.0"
