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
from .pieces import RenderedScan, code_row, render_scan, snr_gain_measurement
from .report import coded_figure, format_coded_table, print_coded_table
from .scan import CODED_FILES, check_coded_options, decode_folder, run_coded_scan, score_coded, study_code, surface_scores
from .scene import (
    CODED_OBJECTS,
    CODED_RIGS,
    SOLDER_DETECT,
    SOLDER_SUBDIVIDE_MM2,
    STEP_DETECT,
    ScanObject,
    check_rim,
    coded_rig,
    scan_object,
)

__all__ = [
    "CODED_FILES",
    "CODED_OBJECTS",
    "CODED_RIGS",
    "STEP_PART",
    "STEP_DETECT",
    "SOLDER_DETECT",
    "SOLDER_SUBDIVIDE_MM2",
    "ScanObject",
    "check_coded_options",
    "check_rim",
    "coded_rig",
    "scan_object",
    "step_height",
    "step_mesh",
    "study_code",
    "pixel_owner",
    "pair_highlights",
    "decoding_errors",
    "table_normals",
    "reachable_mask",
    "coverage",
    "surface_scores",
    "score_coded",
    "run_coded_scan",
    "decode_folder",
    "format_coded_table",
    "print_coded_table",
    "coded_figure",
    "snr_gain_measurement",
    "RenderedScan",
    "render_scan",
    "code_row",
]
