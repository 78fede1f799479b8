"""The drivers: experiments that render, reconstruct, score and write.

Each study is a module of its own; :mod:`shinysim.cli` imports them inside
its commands. Rendering needs the ``render`` extra; the reading and scoring
halves (:func:`~shinysim.studies.scan.reconstruct_folder`,
:func:`~shinysim.studies.scan.score_folder`) need only numpy and
scikit-image.

* :mod:`shinysim.studies.scan`: the sphere scan (``shinysim scan``,
  ``reconstruct``, ``score``);
* :mod:`shinysim.studies.camera_models`: rendered facets and raised spheres
  against Eqs 11-17 (Figs. 5-6);
* :mod:`shinysim.studies.sharpness`: the specularity-sharpness study;
* :mod:`shinysim.studies.solder`: the paper's solder study, one generator per
  class (``shinysim solder``);
* :mod:`shinysim.studies.inspection`: solder inspection with classes decided
  by acceptance criteria and nuisances in every draw (``shinysim inspect``);
* :mod:`shinysim.studies.figures`: the paper's figures (``shinysim figures``);
* :mod:`shinysim.studies.stereo`: structured-highlight stereo (``shinysim stereo``);
* :mod:`shinysim.studies.coded`: coded dome scans (``shinysim scan --rig dome ...``);
* :mod:`shinysim.studies.calibration`: what miscalibration costs
  (``shinysim calibrate study``);
* :mod:`shinysim.studies.exposure`: normal error against exposure for real
  camera sensors (``shinysim exposure``);
* :mod:`shinysim.studies.deflect`: display deflectometry, a SOFAST
  fixed-pattern measurement to slopes (``shinysim deflect``).

Each study is imported when first used, so ``import shinysim.studies`` is cheap.
"""

from .._shared import lazy_face

__all__ = lazy_face(__name__, (
    "scan", "camera_models", "sharpness", "solder", "inspection", "figures", "stereo", "coded", "calibration",
    "exposure", "deflect"))
