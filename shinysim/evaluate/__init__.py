"""Scoring against ground truth: normals, 3-D points, stereo matches, coded scans, solder profiles.

Every statistic goes through one helper (:func:`summary_stats`) over an
explicit valid set, and the number kept and dropped is reported. The parts:
:mod:`~shinysim.evaluate.stats` (the statistics),
:mod:`~shinysim.evaluate.normals` (normals against truth, the Fig. 10
centre test), :mod:`~shinysim.evaluate.surface` (3-D points against the true
surface), :mod:`~shinysim.evaluate.stereo`, :mod:`~shinysim.evaluate.coded`
and :mod:`~shinysim.evaluate.profile`. numpy, and scipy's k-d tree.
"""

from __future__ import annotations

from .coded import (
    coverage,
    decoding_errors,
    empty_coverage,
    normal_differences,
    pair_highlights,
    part_mask,
    pixel_owner,
    reachable_mask,
    score_heights,
    source_directions,
)
from .normals import (
    angular_error_deg,
    nearest_point_to_lines,
    percent_error,
    sample_truth,
    score_normals,
    score_reconstruction,
)
from .profile import profile_stats, score_profile
from .stats import STATISTICS, distance_stats, error_stats, summary_stats
from .stereo import NEAR_FIELD_ORACLE, normalize_sum, score_stereo
from .surface import TruthSurface, matchable_highlights

__all__ = [
    "STATISTICS",
    "summary_stats",
    "sample_truth",
    "angular_error_deg",
    "error_stats",
    "percent_error",
    "nearest_point_to_lines",
    "score_normals",
    "score_reconstruction",
    "TruthSurface",
    "distance_stats",
    "matchable_highlights",
    "NEAR_FIELD_ORACLE",
    "normalize_sum",
    "score_stereo",
    "coverage",
    "decoding_errors",
    "empty_coverage",
    "normal_differences",
    "pair_highlights",
    "part_mask",
    "pixel_owner",
    "reachable_mask",
    "score_heights",
    "source_directions",
    "profile_stats",
    "score_profile",
]
