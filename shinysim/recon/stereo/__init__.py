"""Structured-highlight stereo: matching the highlights of two cameras (paper Section V).

Each highlight is a ray on which every point is a possible surface element
with the normal that reflects its source into the camera; a second camera
resolves the height: the rays of one element meet there with equal normals.
:func:`match_stacks` runs the whole path from two stacks, and
:func:`match_highlights` from two cameras' highlight rays
(:func:`highlight_rays`): candidate pairs by an indexed search equal to
the paper's test of every pair (:mod:`~shinysim.recon.stereo.candidates`),
reflectance matching (:mod:`~shinysim.recon.stereo.reflectance`),
relaxation and uniqueness (:mod:`~shinysim.recon.stereo.relaxation`) and the
umbilic refinement (:mod:`~shinysim.recon.stereo.refine`). Every definition
and bound is in ``docs/stereo-matching.md``.
"""

from __future__ import annotations

from ._base import D0_PIXELS, STEREO_COLUMNS
from .candidates import candidate_pairs, candidate_pairs_naive
from .matches import StereoMatches
from .matching import match_highlights, match_stacks
from .rays import HighlightRays, StereoParams, highlight_rays

__all__ = [
    "HighlightRays",
    "StereoParams",
    "StereoMatches",
    "highlight_rays",
    "candidate_pairs",
    "candidate_pairs_naive",
    "match_highlights",
    "match_stacks",
    "STEREO_COLUMNS",
    "D0_PIXELS",
]
