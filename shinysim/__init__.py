"""shinysim: simulate and invert structured-highlight inspection of shiny surfaces.

The package is in two halves that meet at the stack files (:mod:`shinysim.io`):

* :mod:`shinysim.sim` renders rigs with Mitsuba 3 (the ``render`` extra);
* :mod:`shinysim.recon` inverts frames into normals with numpy and
  scikit-image only, and never imports a renderer.

Around them: :mod:`shinysim.rig` describes the hardware,
:mod:`shinysim.objects` what is scanned and its exact truth,
:mod:`shinysim.evaluate` scores recovered normals against truth,
:mod:`shinysim.theory` holds the paper's analytic models, :mod:`shinysim.plot`
draws, and :mod:`shinysim.studies` holds the drivers behind the command
line (:mod:`shinysim.cli`). Frames and units: :mod:`shinysim.conventions`.
Which part may import which is written in ``tests/test_layering.py``.
"""

import importlib

__version__ = "0.1.0"

#: The parts, imported when first used (``shinysim.recon`` after ``import shinysim``), as
#: :func:`shinysim._shared.lazy_face` does for the packages (this floor imports nothing of the package).
_PARTS = ("errors", "conventions", "rig", "objects", "theory", "evaluate", "io", "plot",
         "sim", "recon", "calibrate", "studies", "datasets", "cli")

__all__ = ["__version__", *_PARTS]


def __getattr__(name):
    if name in _PARTS:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted({*__all__, *globals()})
