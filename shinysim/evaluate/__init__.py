"""Scoring against ground truth: normals, 3-D points, stereo matches, coded scans, solder profiles.

Every statistic goes through one helper (:func:`summary_stats`) over an
explicit valid set, and the number kept and dropped is reported. The parts:
:mod:`~shinysim.evaluate.stats` (the statistics),
:mod:`~shinysim.evaluate.normals` (normals against truth, the Fig. 10
centre test), :mod:`~shinysim.evaluate.surface` (3-D points against the true
surface), :mod:`~shinysim.evaluate.mirror` (exact highlights of analytic objects),
:mod:`~shinysim.evaluate.stereo`, :mod:`~shinysim.evaluate.coded`,
:mod:`~shinysim.evaluate.profile` and :mod:`~shinysim.evaluate.deflect` (mirror slopes against a
reference). numpy, and scipy's k-d tree.
"""

from __future__ import annotations

from . import stats, normals, surface, mirror, stereo, coded, profile, deflect
from .stats import *  # noqa: F403
from .normals import *  # noqa: F403
from .surface import *  # noqa: F403
from .mirror import *  # noqa: F403
from .stereo import *  # noqa: F403
from .coded import *  # noqa: F403
from .profile import *  # noqa: F403
from .deflect import *  # noqa: F403

__all__ = [*stats.__all__, *normals.__all__, *surface.__all__, *mirror.__all__, *stereo.__all__, *coded.__all__, *profile.__all__,
           *deflect.__all__]
