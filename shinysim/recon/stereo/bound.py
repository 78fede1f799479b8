"""The source array's bound on what stereo can match: how far apart the two cameras' highlights fall
(:func:`lattice_gaps`), and the matcher's figure of it.

See ``docs/stereo.md``, "Why the sources must be dense".
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ...conventions import normalize
from ._base import _unit

__all__ = ["lattice_gaps"]


#: Sources whose gaps the matcher's bound looks at, at most (evenly spread over the array): a median and a
#: share need no more.
_BOUND_SAMPLE = 4096


def lattice_gaps(source_directions, view1, view2, *, sample=None):
    """For each source, the angle from camera 1's element normal to the nearest element normal of camera 2.

    With distant sources and cameras (directions ``l_k`` to the sources, ``v1``, ``v2`` to the cameras), camera
    ``c`` sees the element of normal ``n = normalize(l_k + v_c)`` lit by source ``k``: each camera's highlights
    sample a lattice of normals set by the source array. A stereo pair stands for one element only where the
    two lattices nearly meet; on a surface whose normal turns by ``phi`` per pixel, camera 1's highlight of
    source ``k`` has camera 2's nearest highlight ``gap_k / phi`` pixels away. ``docs/stereo.md``, "Why the
    sources must be dense", derives the planar case: a semicircle of spacing ``s`` with both cameras in its
    plane at ``+-beta`` gives gaps of ``dist(2 beta, s Z) / 2`` for every fiber.

    Parameters
    ----------
    source_directions : (K, 3) array_like
        Unit directions to the sources.
    view1, view2 : (3,) array_like
        Unit directions to the cameras.

    sample : int, optional
        Give the gaps of at most this many sources, evenly spread over the array (each against all of
        camera 2's elements).

    Returns
    -------
    gap : (K,) ndarray, radians
        NaN for a source whose camera-1 element faces away from camera 2 (with ``sample``: one per
        sampled source).

    >>> a = np.radians(np.arange(-80.0, 81.0, 8.0))
    >>> fibers = np.stack([np.sin(a), 0 * a, np.cos(a)], 1)
    >>> b = np.radians(15.0)
    >>> gaps = lattice_gaps(fibers, [np.sin(b), 0, np.cos(b)], [-np.sin(b), 0, np.cos(b)])
    >>> round(float(np.degrees(np.nanmin(gaps))), 6)  # dist(30, 8 Z) / 2 = 1 degree
    1.0
    """
    lights = normalize(np.asarray(source_directions, float).reshape(-1, 3))
    v1, v2 = normalize(np.asarray(view1, float)), normalize(np.asarray(view2, float))
    n1, n2 = normalize(lights + v1), normalize(lights + v2)
    if not len(lights):
        return np.zeros(0)
    if sample is not None and len(n1) > sample:
        n1 = n1[np.linspace(0, len(n1) - 1, int(sample)).round().astype(int)]
    chord, _ = cKDTree(n2).query(n1)  # the nearest unit normal by chord, O(K log K) for any array
    gap = 2.0 * np.arcsin(np.clip(0.5 * chord, 0.0, 1.0))
    gap[chord < 1e-12] = 0.0  # the same normal, to the rounding of unit vectors
    return np.where(n1 @ v2 > 0, gap, np.nan)


def _spacing_bound(s1, s2, rig):
    """The source array's bound on what can be matched (:func:`lattice_gaps`), for the normal turn per pixel
    the highlights show."""
    phi = np.concatenate([s.phi for s in (s1, s2) if s.phi is not None and len(s.phi)]) if len(s1.o) + len(
        s2.o) else np.zeros(0)
    phi = float(np.median(phi)) if len(phi) else float("nan")
    out = {"normal_turn_deg_per_px": float(np.degrees(phi)), "lattice_gap_px": float("nan"),
           "expected_matchable": float("nan")}
    if not phi > 0:
        return out
    cams = (s1.camera, s2.camera)
    target = 0.5 * (np.asarray(cams[0].target, float) + np.asarray(cams[1].target, float))
    views = [_unit(c.position - target) if c.projection == "perspective" else -c.forward for c in cams]
    lights = np.where(rig.source_distant[:, None], rig.source_positions, rig.source_positions - target)
    gap_px = lattice_gaps(lights, *views, sample=_BOUND_SAMPLE) / phi
    gap_px = gap_px[np.isfinite(gap_px)]
    if len(gap_px):
        out.update(lattice_gap_px=float(np.median(gap_px)), expected_matchable=float(np.mean(gap_px <= 1.0)))
    return out
