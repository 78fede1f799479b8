"""Coded dome scans: render once, light several sources per frame, decode, and make surfaces.

A dome of hundreds of sources (or stacked rings, a rotating semicircle) is
lit with a code (:mod:`shinysim.theory.coding`); one render gives every
source's frame and the coded frames are sums of them through a sensor;
decoding (:func:`shinysim.recon.coding.decode`) turns them back into
highlights, whose anchored near-field normals are integrated into a height
map, and everything is scored against the sequential scan and the truth
(:mod:`shinysim.evaluate`). The parts: :mod:`~shinysim.studies.coded.scene`
(objects and rigs), :mod:`~shinysim.studies.coded.scan` (options, the run,
decoding a folder), :mod:`~shinysim.studies.coded.report` (table and
figure), :mod:`~shinysim.studies.coded.pieces` (pieces for notebooks). The
method and the numbers are in ``docs/coded-scanning.md``. Rendering needs
the ``render`` extra; matplotlib is imported only inside the plotting
function.
"""

from __future__ import annotations

from ...evaluate import coverage, decoding_errors, pair_highlights, pixel_owner, reachable_mask
from ...objects.step import STEP_PART, step_height, step_mesh
from ...recon.decode import table_normals
from . import pieces, report, scan, scene
from .pieces import *  # noqa: F403
from .report import *  # noqa: F403
from .scan import *  # noqa: F403
from .scene import *  # noqa: F403

__all__ = [*scene.__all__, *scan.__all__, *report.__all__, *pieces.__all__, "STEP_PART", "step_height", "step_mesh",
           "pixel_owner", "pair_highlights", "decoding_errors", "table_normals", "reachable_mask", "coverage"]
