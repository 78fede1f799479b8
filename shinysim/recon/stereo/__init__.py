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
umbilic refinement (:mod:`~shinysim.recon.stereo.refine`), and the source
array's bound on what can be matched (:mod:`~shinysim.recon.stereo.bound`). Every definition
and bound is in ``docs/stereo-matching.md``.
"""

from __future__ import annotations

from . import rays, candidates, matches, matching, bound, _base
from .rays import *  # noqa: F403
from .candidates import *  # noqa: F403
from .matches import *  # noqa: F403
from .matching import *  # noqa: F403
from .bound import *  # noqa: F403
from ._base import *  # noqa: F403

__all__ = [*rays.__all__, *candidates.__all__, *matches.__all__, *matching.__all__, *bound.__all__, *_base.__all__]
