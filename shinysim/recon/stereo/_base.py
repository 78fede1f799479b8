"""Shared pieces of stereo matching: the defaults, the CSV columns, work split across threads, vector helpers.

See ``docs/stereo-matching.md`` for every definition.
"""

from __future__ import annotations

import numpy as np

from ..._shared import thread_map
from ...io.matches import MATCH_COLUMNS

__all__ = ["STEREO_COLUMNS", "TOLERANCE_SCALE"]


#: The one scale factor of the derived tolerances (``StereoParams.tolerance_scale``): footprints in normal
#: and position that two highlights of one surface element may lie apart (``docs/stereo-matching.md``).
TOLERANCE_SCALE = 1.5

#: Columns of :meth:`StereoMatches.to_csv`, in order (those of ``matches.csv``: :data:`shinysim.io.matches.MATCH_COLUMNS`).
STEREO_COLUMNS = MATCH_COLUMNS

# pairs tested per chunk (memory: a few hundred bytes per pair)
_CHUNK = 1 << 18
#: Pairs per piece of the support weights' computation.
_PAIR_PIECE = 1 << 17
#: Share of the way to its target that a relaxation step moves an activation (half way where its pull turned).
_STEP = 0.8
#: Fewest pairs or candidates per piece handed to a thread (below it one thread does the whole).
_PIECE = 1 << 14

def _pieces(n: int, workers: int, most: int | None = None) -> list:
    """Slices that cut ``range(n)`` into ``workers`` nearly equal pieces (fewer where a piece would hold
    under :data:`_PIECE`; more where it would hold over ``most``)."""
    k = max(1, min(workers, n // _PIECE))
    if most:
        k = max(k, -(-n // most))
    edges = [round(n * q / k) for q in range(k + 1)]
    return [slice(a, b) for a, b in zip(edges[:-1], edges[1:])]


def _per_piece(fn, n: int, workers: int):
    """``fn(slice)`` over the pieces of ``range(n)`` on threads, each output (a tuple of arrays)
    joined along its first axis."""
    parts = thread_map(fn, _pieces(n, workers), workers)
    return tuple(p[0] if len(parts) == 1 else np.concatenate(p) for p in zip(*parts))


# relative safety margin on the index radii (rounding in the bounds)
_SAFETY = 1e-7


# -- geometry ----------------------------------------------------------------------------------------


def _dot_c(a, b):
    """``a . b`` of vectors given as three components (arrays or floats)."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _cross_c(a, b):
    """``a x b`` of vectors given as three components, as a list of three."""
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def _unit_c(a):
    """``a / |a|`` of vectors given as three components, as a list of three (NaN where ``a`` is zero)."""
    n = np.sqrt(_dot_c(a, a))
    with np.errstate(invalid="ignore", divide="ignore"):
        return [v / n for v in a]


def _angle_c(a, b):
    """:func:`_angle` on components."""
    c = _cross_c(a, b)
    return np.arctan2(np.sqrt(_dot_c(c, c)), _dot_c(a, b))


def _norm(a):
    """Lengths of (..., 3) vectors."""
    a = np.moveaxis(a, -1, 0)
    return np.sqrt(_dot_c(a, a))


def _unit(a):
    with np.errstate(invalid="ignore", divide="ignore"):
        return a / _norm(a)[..., None]


def _angle(a, b):
    """Angles between (..., 3) vectors."""
    return _angle_c(np.moveaxis(a, -1, 0), np.moveaxis(b, -1, 0))
