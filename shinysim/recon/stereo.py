r"""Structured-highlight stereo: matching the highlights of two cameras (paper Section V).

One camera sees a highlight along a pixel ray ``P(t) = o + t d`` (``d``
unit, ``t`` millimetres from the ray's origin). Every point of the ray is a
possible surface element, with the normal that reflects the highlight's
source into the camera there::

    n(t) = bisector(S - P(t), -d)        (near source at S)
    n(t) = bisector(s, -d)               (distant source, unit direction s)

(``-d`` is the direction to the camera for a pinhole camera and ``-forward``
for an orthographic one.) Height and orientation stay ambiguous (paper
Fig. 14). A second camera resolves them: an element seen by camera 1 under
source ``s1`` and by camera 2 under source ``s2`` gives two rays that meet
there with equal normals. The paper tests every pair of highlights (Eqs 40,
43); this module does the same tests in vector form for any two cameras
(perspective or orthographic, any source positions), finds the pairs that
can pass them with a spatial index instead of the paper's O(N^2) search, and
resolves what is left ambiguous by uniqueness and a Marr-Poggio style
relaxation (paper Eq 35 and the paragraph after it).

The tests (:func:`candidate_pairs`, :func:`candidate_pairs_naive`)
-------------------------------------------------------------------------
For highlights ``i`` (camera 1) and ``j`` (camera 2), with ``c = d1 . d2``:

* *intersection* (Eq 40): the closest approach of the two rays (as lines),
  ``D = |(o1 - o2) . (d1 x d2)| / |d1 x d2|``, must be below ``D0``; its
  points ``P1* = o1 + t1 d1``, ``P2* = o2 + t2 d2`` must lie in front of both
  cameras (``t1, t2 > 0``); the match's point is their midpoint ``P*``.
* *working volume*: ``P*`` must lie within ``depth_range_mm`` along world z
  when one is given.
* *normals* (reflectance matching): ``normal_gap = angle(n1(t1), n2(t2))``
  must not exceed ``max_normal_gap_deg``.

Pairs passing all three are the *candidates*.

Reflectance matching and the paper's E', E'' (Eqs 32-34, 43)
------------------------------------------------------------
Along ray k the normal ``n_k(t)`` traces a curve on the unit sphere. For a
common normal ``n*`` let ``t_k(n*)`` be where that curve comes nearest to
``n*`` (Gauss-Newton on ``|n_k(t) - n*|^2``) and

    E_k(n*) = -(t_k(n*) - t_k*)      millimetres, positive towards camera k,

the signed distance along ray k from ``P_k*`` to the point whose normal is
``n*``. ``n*`` is chosen on the great-circle arc from ``n1(t1*)`` to
``n2(t2*)`` where ``E_1 = E_2`` (Eq 32 in vector form). It is found by
Newton's method on the three conditions at once, in the arc parameter and
the two points along the rays (each point nearest to ``n*``: Gauss-Newton's
normal equation; and ``E_1 = E_2``), from the middle of the arc; it settles
in three to five steps. Where the root lies off the arc (``E_1 - E_2`` does
not change sign on it), the end of the arc with the smaller ``|E_1 - E_2|``
is taken; the few pairs Newton leaves unsettled are solved by secant steps
kept inside a sign-change bracket (Illinois regula falsi). Reported: ``e1_mm``, ``e2_mm`` (Eqs 33-34) and
``delta_z_mm = e1 - e2`` (Eq 43's Delta z; zero where the arc holds a root).

How this reduces to the paper's planar case: for orthographic cameras at
``+-beta`` whose view directions lie in the plane of the sources (Fig. 15),
every ``n_k(t)`` lies in that plane, so the great circle through ``n1`` and
``n2`` is the plane's own circle of normals, parametrised by ``Theta``; the
nearest point of curve k to ``n*`` is exactly the point with normal
``Theta*``, and ``t`` runs along ``-axis_k``. So ``E_k`` is the height along
camera k's axis at which the ray's normal is ``Theta*`` less the height of
the intersection, ``E' = z'(Theta* - beta) - z'*`` and
``E'' = z''(Theta* + beta) - z''*`` (Eqs 33-34 with the corrected Eqs 24-25
and 29, 31 of the errata), and ``E_1 = E_2`` is Eq 32. In 3-D the paper
picks ``(p*, q*)`` where the tangent loci of Eqs 44-45 cross; the
great-circle arc is used here instead because it always exists and reduces
to the same point in the plane.

Why the normal gap, not ``E``, is the default test: the normal turns slowly
along a ray (about ``dt sin(angle(l, d)) / (2 |S - P|)`` rad per mm, with the
sources ~40 mm away), so ``E ~ gap / (that rate)`` magnifies a normal gap of
0.1 deg into about a millimetre. The two test the same condition; the gap is
the sharper one. ``max_delta_z_mm`` and ``max_e_mm`` apply the paper's form
where wanted.

Search faster than O(N^2) (:func:`candidate_pairs`)
---------------------------------------------------
Each ray gets an *epipolar coordinate*:

* two pinhole cameras (centres ``C1``, ``C2``, baseline ``B = |C2 - C1|``):
  the angle ``phi`` about the baseline of the plane through the baseline and
  the ray. With ``alpha_k`` the angle between ray k and the baseline and
  ``gamma`` the angle between the rays, exactly
  ``D = B sin(alpha1) sin(alpha2) |sin(dphi)| / sin(gamma)``, so
  ``D < D0`` implies ``|sin(dphi)| < D0 / (B sin(alpha1) sin(alpha2))``.
  Rays in opposite half-planes (``|dphi| > pi/2``) cannot pass when
  ``B > D0 (1 + 1/sin(alpha1) + 1/sin(alpha2))`` (their closest points would
  both have to lie within ``D0 / sin(alpha_k)`` of their own camera);
* one orthographic (view ``f``) and one pinhole camera (centre ``C``): the
  angle about the line through ``C`` along ``f``; exactly
  ``D = rho |sin(dphi)|`` with ``rho`` the orthographic ray's distance from
  that line, and rays in opposite half-planes are at least ``rho`` apart;
* two orthographic cameras: the offset ``e = o . m`` along
  ``m = f1 x f2 / |f1 x f2|``; exactly ``D = |e1 - e2|``.

With a depth range, each ray's part in the working volume (z within
``depth_range_mm`` widened by ``D0 / 2``, in front of the camera) is
``t in [t_lo, t_hi]``; its midpoint ``X_ref`` and the normal there ``n_ref``
are indexed as well. A passing pair has ``|X1_ref - X2_ref| <= h1 + h2 + D0``
(``h_k`` half the length of the ray's part: ``X_k_ref = P_k* + (t_k_ref -
t_k) d_k`` with ``|t_k_ref - t_k| <= h_k``, and ``|P1* - P2*| = D``), and so,
along any unit vector ``e``, ``|(X1_ref - X2_ref) . e| <= h1 |d1 . e| +
h2 |d2 . e| + D0``: along the baseline (the epipolar lines) the rays' parts
are short, about a quarter of their length at 15 degrees. The normal at
``P_k*`` differs from ``n_ref`` by at most ``w_k``: the direction to the
source turns by the angle ``psi`` the segment subtends at the source, the
half-vector by ``|dn| <= |dl| / |l + v|``, so
``w <= psi / (2 cos((theta_ref + psi) / 2))`` with ``theta_ref`` the angle
between source and camera directions at ``X_ref`` (0 for a distant source).
So ``angle(n1_ref, n2_ref) <= gap0 + w1 + w2``.

The search is a sort-and-sweep, vectorised: camera 2's rays are sorted by
(bin of ``X_ref . e``, epipolar coordinate), ``e`` the baseline in the
xy-plane and the bins as wide as the bound along it; each highlight of
camera 1 looks up with :func:`numpy.searchsorted` one window of the
epipolar coordinate (``|dphi| <= arcsin(D0 / (B sin(alpha1) sin(alpha2)))``,
modulo 2 pi; ``|de| <= D0``) in each bin its bound reaches. The pairs found
are then filtered by the normal bound (per component, then the chord) and
the ``X_ref`` bound, and every pair left gets the exact tests, so the result
equals :func:`candidate_pairs_naive` (the paper's test of every pair), only
faster: O(N log N) plus the output. All windows and bounds are widened by a
relative ``1e-7`` (and more than the rounding of the sort keys), so
rounding can only add pairs to the exact tests, never drop one. Rays whose
bounds are unbounded (no depth range, a ray parallel to the depth planes, a
source inside the volume) are matched on the epipolar coordinate alone.

Ambiguity: uniqueness and relaxation
------------------------------------
A highlight may keep several candidates: neighbouring elements of a smooth
surface, and *ghosts* (Eq 35: two different elements with the same normal
whose rays cross, as on identical spheres offset along the baseline).
Each candidate starts with a likelihood ``a0 = exp(-((D/D0)^2 + (gap/gap0)^2))``.
Candidates *support* each other when their points lie within the
neighbourhood radius and fit one smooth surface: the rise of the circular
arc between them, ``r = (P_b - P_a) . (n_a + n_b) / 2`` (zero on a circle),
is compared with ``rise_tol = D0 + |P_b - P_a| sin(gap0)`` (two points each
within ``D0 / 2`` of its rays, two normals each good to the gap limit);
weight ``exp(-(r / rise_tol)^2 / 2)``. Candidates sharing a highlight
*compete*. Each iteration sets ``x = a0 exp(-b) (1 + support)``, with
support the weighted sum of the neighbours' activations and
``b = (1 + support) |g_bar|^2 / gap0^2`` where ``g_bar`` is the
support-weighted mean of the gap vectors ``n2 - n1`` over the candidate and
its neighbours: on a real surface the gaps scatter about zero and their mean
shrinks with the number of neighbours, on a ghost surface they share the
smooth 1/R bias. A candidate's activation then moves towards ``x`` over the
largest ``x`` among it and its competitors (divisive inhibition: the
strongest candidate of each highlight tends to 1): 0.8 of the way, or half
way where its pull has turned since its last step (damping: rivals that take
turns would oscillate at full steps), until no activation moves by more than
``tol`` (a fixed point) or ``iterations`` steps. The damping changes the path,
not the fixed point: at 10^5 highlights it settles in 18 steps instead of the
29 of half steps everywhere, with the same accepted matches. Activations
start at the first such target (with every activation at 1), not at 1: the
damping would otherwise spend its first steps shrinking that first move. Once only a few
candidates still move by more than ``tol``, a step updates only those moving
by more than ``tol / 4``, the competitors and support neighbours of those
moving by more than ``tol`` (whose inputs changed), and when none of these
moves by more than ``tol`` a step over every candidate decides whether the
fixed point is reached, so the stopping rule is the plain one (the
candidates are put in a spatial
order for this, so that the sparse products read their neighbours from
cache; each product still sums a candidate's neighbours in the candidates'
(i, j) order, so the reordering changes no bit of the result). Matches are
then accepted greedily by
``x``, each highlight at most once. ``confidence = a0 * margin`` with
``margin = 1 - x_best_competitor / x`` (1 with no competitor).

What it resolves: a ghost competes with the real match on the same highlight
and loses where its normals disagree more (the 1/R term of Eq 35: the
normals at a ghost point, away from either element, differ from the
elements' by about ``offset / (2R)``) or where it has fewer consistent
neighbours. What it cannot resolve: a ghost surface that is larger than the
real one around it, or whose highlights have no real competitor (an element
seen by only one camera), or whose normals agree as well as the real ones.
The last is the rule under a shared dense dome: each highlight then has
many partners within the normal spacing of the sources (about half their
angular spacing), and the test itself picks, among a ghost's possible
partners, the one whose discrete offset cancels the 1/R bias, so the bias
never shows in the gaps. With 1000 sources over an 80 degree cap (normals
~2 deg apart) and identical spheres 1 mm apart along the baseline, the
bias (~0.03 deg on average over a neighbourhood) is far below that spacing
and about a third of the final matches are ghosts; a working volume
(``depth_range_mm``) that excludes the ghost points (here 1.8 mm and more
off the real surfaces) is then the remedy.

Refinement: the two elements of a match
---------------------------------------
With discrete sources the element camera 1 sees (``E1``, on ray 1) and the
one camera 2 sees (``E2``, on ray 2) are rarely the same: they lie a small
``delta`` apart, and the rays then cross off the surface (by about
``delta / (2 tan beta)`` for an element facing up, and displaced along it
by ``(delta / 2) sin 2 theta / sin 2 beta`` for one tilted by ``theta``),
so ``P*`` and ``n*`` describe no surface element exactly. Each element's
own normal is known well (``n_k`` turns slowly along its ray), so the
refinement places the two elements instead: on a surface that is locally
a sphere of radius ``rho`` (umbilic; exact on a sphere, first order on any
smooth surface along the pair's direction) ``E2 - E1 = rho (n2 - n1)``, and
with ``E_k = o_k + t_k d_k`` that is three linear equations in
``(t1, t2, rho)`` once the normals are fixed. The normals depend on the
elements (through the directions to the sources), so the three equations
are solved together by Newton's method from the rays' crossing, with the
normals' rates along the rays in the Jacobian, until the elements move by
less than 1e-10 mm (three or four steps; a fixed-point iteration, solving
the linear equations with the normals of the last pass, diverges where
``rho^2`` exceeds ``|E2 - E1|`` times the source distance). Where ``n1`` and ``n2`` barely differ
(a plane, or an exact lattice match) ``rho`` is not observed and the
solution is the rays' closest approach; where the elements found lie more
than ``D0`` apart the model does not describe the pair (an ill-conditioned
solve, or a surface curved differently across the pair) and the crossing is
kept. The match reports the midpoint of the elements and the mean of their
normals (second-order exact on a sphere), ``radius_mm = rho``, and the
paper's crossing as ``crossing``. On the rendered off-origin calibration
sphere (1000-source dome, 512 px) this halves the normal error's 95th
percentile and brings the points from 0.75 to 0.2 pixel-equivalents of the
surface (median); ``rho`` recovers the sphere's radius to 1 %.
"""

from __future__ import annotations

import csv
import io
import math
import time
from dataclasses import dataclass, field

import numpy as np
from scipy import sparse
from scipy.spatial import cKDTree

from .._shared import check_number, cores, thread_map, write_text
from ..errors import OptionError, StereoError
from ..rig import Rig

__all__ = [
    "HighlightRays",
    "StereoParams",
    "StereoMatches",
    "highlight_rays",
    "candidate_pairs",
    "candidate_pairs_naive",
    "match_highlights",
    "STEREO_COLUMNS",
    "D0_PIXELS",
]

#: Default closest-approach limit, in pixels of the coarser camera (``pixel_pitch``): a centroid good to
#: half a pixel moves its ray by up to half a pitch (about 0.7 with both axes); two rays: about 1.4 pixels,
#: rounded up to 2.
D0_PIXELS = 2.0

#: Columns of :meth:`StereoMatches.to_csv`, in order.
STEREO_COLUMNS = ("x_mm", "y_mm", "z_mm", "nx", "ny", "nz", "row1", "col1", "row2", "col2", "source1", "source2",
                  "index1", "index2", "d_mm", "normal_gap_deg", "e1_mm", "e2_mm", "delta_z_mm", "confidence",
                  "refined", "radius_mm", "cx_mm", "cy_mm", "cz_mm")

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


# -- input ------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class HighlightRays:
    """One camera's highlights, ready for matching (:func:`highlight_rays`).

    Attributes
    ----------
    camera : int
        Index of the camera in the rig.
    rows, cols : (N,) float
        Pixel centroids (continuous image coordinates, pixel centres at integers).
    sources : (N,) int
        Index of the source that made each highlight.
    origins : (N, 3) float, millimetres
        Ray origins: the centre of projection (perspective) or the point on
        the image plane (orthographic).
    directions : (N, 3) float
        Unit ray directions, into the scene (world frame).
    """

    camera: int
    rows: np.ndarray
    cols: np.ndarray
    sources: np.ndarray
    origins: np.ndarray
    directions: np.ndarray

    def __len__(self) -> int:
        return int(self.rows.shape[0])


def _check_rig(rig):
    if not isinstance(rig, Rig):
        raise StereoError(f"must be a Rig, got {type(rig).__name__}", field="rig")
    if len(rig.cameras) < 2:
        raise StereoError(f"stereo needs a rig with two cameras, this one has {len(rig.cameras)}", field="cameras")


def _as_1d(value, name):
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise StereoError(f"must be numbers, got {type(value).__name__}", field=name) from None
    if arr.ndim != 1:
        raise StereoError(f"must be one-dimensional, got shape {arr.shape}", field=name)
    if not np.all(np.isfinite(arr)):
        raise StereoError(f"contains NaN or inf (first at {int(np.flatnonzero(~np.isfinite(arr))[0])})", field=name)
    return arr


def highlight_rays(rows, cols, sources, rig: Rig, camera_index: int) -> HighlightRays:
    """Pixel rays of one camera's highlights.

    Parameters
    ----------
    rows, cols : (N,) array_like
        Highlight centroids, pixels (continuous image coordinates).
    sources : (N,) array_like of int
        Source index of each highlight, into ``rig.source_positions``.
    rig : Rig
        With two or more cameras.
    camera_index : int
        Which of ``rig.cameras`` saw the highlights.

    Returns
    -------
    HighlightRays

    Raises
    ------
    StereoError
        Naming the field: ``rows``/``cols``/``sources`` of different lengths,
        not one-dimensional or not finite; a source index that is not an
        integer in range; a rig with one camera (``cameras``); a camera index
        out of range (``camera_index``).
    """
    _check_rig(rig)
    if isinstance(camera_index, bool) or not isinstance(camera_index, (int, np.integer)):
        raise StereoError(f"must be an integer, got {camera_index!r}", field="camera_index")
    if not 0 <= int(camera_index) < len(rig.cameras):
        raise StereoError(f"{int(camera_index)} is out of range 0..{len(rig.cameras) - 1}", field="camera_index")
    r = _as_1d(rows, "rows")
    c = _as_1d(cols, "cols")
    s = _as_1d(sources, "sources")
    if not (len(r) == len(c) == len(s)):
        bad = "cols" if len(c) != len(r) else "sources"
        raise StereoError(f"has {len(c) if bad == 'cols' else len(s)} entries, rows has {len(r)}", field=bad)
    if np.any(s != np.round(s)):
        raise StereoError("must be integer source indices", field="sources")
    s = s.astype(np.int64)
    if len(s) and (s.min() < 0 or s.max() >= rig.n_sources):
        k = int(np.flatnonzero((s < 0) | (s >= rig.n_sources))[0])
        raise StereoError(f"index {int(s[k])} (entry {k}) is out of range 0..{rig.n_sources - 1}", field="sources")
    cam = rig.cameras[int(camera_index)]
    origins, directions = cam.pixel_rays(r, c)
    origins = np.ascontiguousarray(origins.reshape(-1, 3))
    directions = np.ascontiguousarray(directions.reshape(-1, 3))
    return HighlightRays(int(camera_index), r, c, s, origins, directions)


@dataclass(frozen=True)
class StereoParams:
    """Settings of :func:`match_highlights`.

    Parameters
    ----------
    d0_mm : float or None
        Limit on the closest-approach distance ``D`` of the two rays (Eq 40),
        millimetres. None: :data:`D0_PIXELS` (2) times the coarser camera's
        ``pixel_pitch`` (the centroid error of both images).
    max_normal_gap_deg : float
        Limit on the angle between ``n1(P1*)`` and ``n2(P2*)``, degrees
        (reflectance matching). On a curved surface the two cameras' elements
        lie ``delta`` apart and their normals differ by ``delta`` times the
        curvature: allow for that.
    depth_range_mm : (float, float) or None
        Working volume along world z: ``P*`` must have ``lo <= z <= hi``.
        None: no limit (then the index has only the epipolar coordinate and
        its output grows with the number of pairs on each epipolar line).
    max_delta_z_mm : float or None
        Limit on ``|delta_z|`` (Eq 43); None: not applied (it is zero where
        ``E1 = E2`` has a root on the arc; see the module notes).
    max_e_mm : float or None
        Limit on ``|E1|`` and ``|E2|`` (Eqs 33-34); None: not applied
        (the normal gap tests the same, more sharply).
    relax : bool
        Run the relaxation before uniqueness; False: uniqueness alone,
        greedy by the likelihood ``a0``.
    neighbourhood_mm : float or None
        Support radius of the relaxation. None: four times the median
        distance from a candidate's point to its nearest other candidate
        (enough neighbours to vote, small enough for a circular arc to
        describe the surface between them).
    rise_tol_mm : float or None
        Rise of the circular arc between two supporting candidates that
        halves their support weight at ``|P_b - P_a| = 0``; None: ``D0``.
    iterations : int
        Most relaxation steps. The damped update shrinks a change by a
        fraction per step where real and ghost candidates compete, so a
        fixed point to ``tol`` takes tens of steps; the cap only stops a run
        that does not settle.
    tol : float
        Fixed point: no activation changes by more than this (activations
        lie in [0, 1]; the ranking that uniqueness uses is settled long
        before 1e-4).
    refine : bool
        Place each accepted match's two elements by the locally spherical
        (umbilic) model instead of at the rays' crossing (module notes,
        "Refinement"); False: the paper's crossing ``P*`` and ``n*``.
    workers : int or None
        Threads for the per-pair and per-candidate work (the index's
        queries, the exact tests, the support weights, the relaxation's
        products, reflectance matching, the refinement).
        None: one per core this process may run on. The result does not
        depend on it: each pair or candidate is computed alone, in the same
        order of operations.
    """

    d0_mm: float | None = None
    max_normal_gap_deg: float = 1.0
    depth_range_mm: tuple[float, float] | None = None
    max_delta_z_mm: float | None = None
    max_e_mm: float | None = None
    relax: bool = True
    neighbourhood_mm: float | None = None
    rise_tol_mm: float | None = None
    iterations: int = 200
    tol: float = 1e-4
    refine: bool = True
    workers: int | None = None

    def __post_init__(self):
        for name in ("d0_mm", "max_delta_z_mm", "max_e_mm", "neighbourhood_mm", "rise_tol_mm"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, check_number(name, value, lo=0.0, lo_open=True))
        object.__setattr__(self, "max_normal_gap_deg",
                           check_number("max_normal_gap_deg", self.max_normal_gap_deg, lo=0.0, hi=90.0))
        if self.depth_range_mm is not None:
            try:
                lo, hi = self.depth_range_mm
            except (TypeError, ValueError):
                raise OptionError(f"depth_range_mm must be (lo, hi) or None, got {self.depth_range_mm!r}") from None
            lo = check_number("depth_range_mm[0]", lo)
            hi = check_number("depth_range_mm[1]", hi)
            if not lo <= hi:
                raise OptionError(f"depth_range_mm must have lo <= hi, got {self.depth_range_mm!r}")
            object.__setattr__(self, "depth_range_mm", (lo, hi))
        for name in ("relax", "refine"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise OptionError(f"{name} must be True or False, got {getattr(self, name)!r}")
        object.__setattr__(self, "iterations", check_number("iterations", self.iterations, lo=0, hi=10000,
                                                            integer=True))
        object.__setattr__(self, "tol", check_number("tol", self.tol, lo=0.0))
        if self.workers is not None:
            object.__setattr__(self, "workers", check_number("workers", self.workers, lo=1, hi=1024,
                                                              integer=True))

    @property
    def threads(self) -> int:
        """The threads used: ``workers``, or one per core."""
        return self.workers if self.workers is not None else cores()


# -- geometry ----------------------------------------------------------------------------------------


def _dot(a, b):
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def _cross(a, b):
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
                     a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], axis=-1)


def _norm(a):
    return np.sqrt(_dot(a, a))


def _unit(a):
    with np.errstate(invalid="ignore", divide="ignore"):
        return a / _norm(a)[..., None]


def _angle(a, b):
    return np.arctan2(_norm(_cross(a, b)), _dot(a, b))


@dataclass
class _Side:
    """One camera's rays with their sources, as flat arrays."""

    o: np.ndarray
    d: np.ndarray
    S: np.ndarray        # source position (near) or unit direction (distant), per ray
    distant: np.ndarray  # bool per ray
    pitch: float
    camera: object
    # the same as contiguous components (x, y, z); an origin shared by every ray (a pinhole) as plain floats
    oc: tuple = ()
    dc: tuple = ()
    Sc: tuple = ()


def _components(a, shared=False):
    if shared and len(a) and bool(np.all(a == a[0])):
        return tuple(float(v) for v in a[0])
    return tuple(np.ascontiguousarray(a[:, k]) for k in range(3))


def _side(rays: HighlightRays, rig: Rig) -> _Side:
    cam = rig.cameras[rays.camera]
    S = rig.source_positions[rays.sources]
    return _Side(rays.origins, rays.directions, S, rig.source_distant[rays.sources], cam.pixel_pitch, cam,
                 _components(rays.origins, shared=True), _components(rays.directions), _components(S))


def _take(comps, idx):
    return tuple(c if np.ndim(c) == 0 else c[idx] for c in comps)


def _normal_at(side: _Side, idx, P):
    """Normal that reflects ray ``idx``'s source into its camera at points ``P`` (bisector)."""
    d = side.d[idx]
    S = side.S[idx]
    far = side.distant[idx][:, None]
    l = np.where(far, S, _unit(S - P))
    return _unit(l - d)


def _normal_at_c(side: _Side, idx, P):
    """:func:`_normal_at` on components: the same operations element by element, so the same bits."""
    S = _take(side.Sc, idx)
    d = _take(side.dc, idx)
    v = [S[k] - P[k] for k in range(3)]
    r = np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    with np.errstate(invalid="ignore", divide="ignore"):
        lv = [v[k] / r for k in range(3)]
    far = side.distant[idx]
    if far.any():
        lv = [np.where(far, S[k], lv[k]) for k in range(3)]
    m = [lv[k] - d[k] for k in range(3)]
    mn = np.sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2])
    with np.errstate(invalid="ignore", divide="ignore"):
        return [m[k] / mn for k in range(3)]


def _angle_c(a, b):
    """:func:`_angle` on components."""
    cx = a[1] * b[2] - a[2] * b[1]
    cy = a[2] * b[0] - a[0] * b[2]
    cz = a[0] * b[1] - a[1] * b[0]
    return np.arctan2(np.sqrt(cx * cx + cy * cy + cz * cz), a[0] * b[0] + a[1] * b[1] + a[2] * b[2])


@dataclass
class _Tested:
    """The pairs that passed the tests, with what the tests computed for them."""

    i: np.ndarray
    j: np.ndarray
    n_examined: int
    n_distance: int
    n_depth: int
    n_normal: int
    t1: np.ndarray
    t2: np.ndarray
    D: np.ndarray
    P: np.ndarray        # (K, 3) midpoint of the closest approach
    n1: np.ndarray       # (K, 3) normal of ray i at P1*
    n2: np.ndarray
    gap: np.ndarray

    @staticmethod
    def join(parts):
        cat = lambda name, shape: (np.concatenate([getattr(p, name) for p in parts]) if parts
                                   else np.zeros(shape, np.int64 if name in "ij" else float))
        return _Tested(cat("i", 0), cat("j", 0), sum(p.n_examined for p in parts),
                       sum(p.n_distance for p in parts), sum(p.n_depth for p in parts),
                       sum(p.n_normal for p in parts), cat("t1", 0), cat("t2", 0), cat("D", 0),
                       cat("P", (0, 3)), cat("n1", (0, 3)), cat("n2", (0, 3)), cat("gap", 0))

    def take(self, order):
        return _Tested(self.i[order], self.j[order], self.n_examined, self.n_distance, self.n_depth,
                       self.n_normal, self.t1[order], self.t2[order], self.D[order], self.P[order],
                       self.n1[order], self.n2[order], self.gap[order])


def _exact_tests(s1, s2, i, j, d0, gap0, zr, workers=1):
    """The tests of the module notes on pairs (i, j), in pieces (on ``workers`` threads). Every pair is
    computed element by element, so a pair gets the same verdict (and the same numbers) whichever search
    proposed it and whatever else is tested with it; each test runs only on the pairs that passed the
    ones before."""
    return _Tested.join(thread_map(lambda sl: _exact_piece(s1, s2, i[sl], j[sl], d0, gap0, zr),
                             _pieces(len(i), workers, _CHUNK), workers))


def _exact_piece(s1, s2, ii, jj, d0, gap0, zr):
    """The tests on one piece of pairs (see :func:`_exact_tests`)."""
    m0 = len(ii)
    d1, d2 = _take(s1.dc, ii), _take(s2.dc, jj)
    o1, o2 = _take(s1.oc, ii), _take(s2.oc, jj)
    w0 = [o1[k] - o2[k] for k in range(3)]
    # closest approach (Eq 40): c = d1.d2, D = |w0 . (d1 x d2)| / |d1 x d2|
    c = d1[0] * d2[0] + d1[1] * d2[1] + d1[2] * d2[2]
    den = 1.0 - c * c
    ok = den > 1e-12
    cx = d1[1] * d2[2] - d1[2] * d2[1]
    cy = d1[2] * d2[0] - d1[0] * d2[2]
    cz = d1[0] * d2[1] - d1[1] * d2[0]
    crn = np.sqrt(cx * cx + cy * cy + cz * cz)
    D = np.abs(w0[0] * cx + w0[1] * cy + w0[2] * cz) / np.where(ok, crn, 1.0)
    sel = np.flatnonzero(ok & (D < d0))
    ii, jj, c, den, D = ii[sel], jj[sel], c[sel], den[sel], D[sel]
    d1, d2 = [v[sel] for v in d1], [v[sel] for v in d2]
    w0 = [v if np.ndim(v) == 0 else v[sel] for v in w0]
    o1, o2 = _take(o1, sel), _take(o2, sel)
    b1 = d1[0] * w0[0] + d1[1] * w0[1] + d1[2] * w0[2]
    b2 = d2[0] * w0[0] + d2[1] * w0[1] + d2[2] * w0[2]
    t1 = (c * b2 - b1) / den
    t2 = (b2 - c * b1) / den
    sel = np.flatnonzero((t1 > 0) & (t2 > 0))
    n_dist = m0 - len(sel)
    ii, jj, t1, t2, D = ii[sel], jj[sel], t1[sel], t2[sel], D[sel]
    P1 = [o1[k] + t1 * d1[k][sel] for k in range(3)]
    P2 = [o2[k] + t2 * d2[k][sel] for k in range(3)]
    n_depth = 0
    if zr is not None:
        z = 0.5 * (P1[2] + P2[2])
        inside = np.flatnonzero((z >= zr[0]) & (z <= zr[1]))
        n_depth = len(z) - len(inside)
        ii, jj, t1, t2, D = ii[inside], jj[inside], t1[inside], t2[inside], D[inside]
        P1, P2 = [v[inside] for v in P1], [v[inside] for v in P2]
    n1 = _normal_at_c(s1, ii, P1)
    n2 = _normal_at_c(s2, jj, P2)
    gap = _angle_c(n1, n2)
    good = np.flatnonzero(gap <= gap0)
    n_norm = len(gap) - len(good)
    P = np.stack([0.5 * (P1[k][good] + P2[k][good]) for k in range(3)], 1)
    return _Tested(ii[good], jj[good], m0, n_dist, n_depth, n_norm, t1[good], t2[good], D[good], P,
                   np.stack([v[good] for v in n1], 1), np.stack([v[good] for v in n2], 1), gap[good])


# -- the index --------------------------------------------------------------------------------------


def _perp_frame(b):
    """Two unit vectors completing the unit vector ``b`` to a right-handed frame."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(b[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = _unit(np.cross(b, helper))
    return e1, np.cross(b, e1)


def _epipolar(s1: _Side, s2: _Side, d0: float):
    """Epipolar coordinates of both sides and the bound that links their difference to D.

    Returns ``(kind, u1, u2, k1, k2, K, B)``: for kind ``"angle"``, ``u`` is the angle ``phi`` in
    [-pi, pi] and ``D >= K k1 k2 |sin dphi|``; for ``"offset"`` (two orthographic cameras) ``u`` is
    the offset ``e`` and ``D = |e1 - e2|``.
    """
    c1, c2 = s1.camera, s2.camera
    p1, p2 = c1.projection == "perspective", c2.projection == "perspective"
    if not p1 and not p2:
        m = np.cross(c1.forward, c2.forward)
        if np.linalg.norm(m) < 1e-9:
            raise StereoError("the two orthographic cameras look along the same direction: their rays never "
                              "cross", field="cameras")
        m = m / np.linalg.norm(m)
        return "offset", s1.o @ m, s2.o @ m, None, None, None, None
    if p1 and p2:
        base = c2.position - c1.position
        B = float(np.linalg.norm(base))
        if B < 1e-9:
            raise StereoError("the two cameras share their centre of projection: there is no baseline",
                              field="cameras")
        b = base / B
        origin = c1.position
        K = B
    else:
        pin, ortho = (c1, c2) if p1 else (c2, c1)
        b = ortho.forward
        origin = pin.position
        K = 1.0
        B = None
    f1, f2 = _perp_frame(b)

    def coords(side, pinhole):
        if pinhole:
            u = side.d - np.outer(side.d @ b, b)
        else:
            rel = side.o - origin
            u = rel - np.outer(rel @ b, b)
        k = _norm(u)
        return np.arctan2(u @ f2, u @ f1), k

    x1, k1 = coords(s1, p1)
    x2, k2 = coords(s2, p2)
    if not (p1 and p2):  # a pinhole ray's factor is 1 (only the orthographic ray's distance counts)
        k1 = k1 if not p1 else np.ones_like(k1)
        k2 = k2 if not p2 else np.ones_like(k2)
    return "angle", x1, x2, k1, k2, K, B


def _halfwidth(kind, k1, k2min, K, B, d0, n):
    """Per-query bound on the epipolar-coordinate difference of any pair with D < d0 (inf: no bound)."""
    if kind == "offset":
        return np.full(n, d0 * (1 + _SAFETY) + 1e-12)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = d0 / (K * k1 * k2min)
        ok = (r < 1.0) & (k1 > 0) & (k2min > 0)
        if B is not None:  # two pinholes: the opposite half-planes are excluded only by this
            ok &= B > d0 * (1.0 + 1.0 / k1 + 1.0 / k2min)
        ang = np.arcsin(np.clip(r * (1 + _SAFETY), 0.0, 1.0)) + 1e-12
    return np.where(ok, ang, np.inf)


def _volume(side: _Side, zr, d0):
    """Per ray: t range in the (widened) working volume, reference point, normal there, turn bound.

    Returns ``(valid, bounded, X_ref, n_ref, h, w)``: ``valid`` False where the ray cannot reach the
    volume in front of the camera (no pair with it can pass); ``bounded`` where h and w are finite.
    """
    n = len(side.o)
    if zr is None:
        return np.ones(n, bool), np.zeros(n, bool), None, None, None, None
    lo, hi = zr[0] - 0.5 * d0, zr[1] + 0.5 * d0
    oz, dz = side.o[:, 2], side.d[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        ta = (lo - oz) / dz
        tb = (hi - oz) / dz
    flat = np.abs(dz) < 1e-12
    t_lo = np.maximum(np.minimum(ta, tb), 0.0)
    t_hi = np.maximum(ta, tb)
    valid = np.where(flat, True, t_hi > 0)
    bounded = ~flat & valid
    t_lo = np.where(bounded, t_lo, 0.0)
    t_hi = np.where(bounded, t_hi, 0.0)
    t_ref = 0.5 * (t_lo + t_hi)
    h = 0.5 * (t_hi - t_lo)
    X = side.o + t_ref[:, None] * side.d
    idx = np.arange(n)
    n_ref = _normal_at(side, idx, X)
    # how far the normal can turn over [t_lo, t_hi] from n_ref (module notes)
    far = side.distant
    S = side.S
    P_lo = side.o + t_lo[:, None] * side.d
    P_hi = side.o + t_hi[:, None] * side.d
    psi = np.maximum(_angle(S - X, S - P_lo), _angle(S - X, S - P_hi))
    l_ref = np.where(far[:, None], S, _unit(S - X))
    theta = _angle(l_ref, -side.d)
    top = theta + psi
    with np.errstate(divide="ignore", invalid="ignore"):
        w = np.where(top < np.pi * (1 - 1e-9), psi / (2.0 * np.cos(0.5 * top)), np.inf)
    w = np.where(far, 0.0, w) * (1 + _SAFETY) + 1e-12
    bounded &= np.isfinite(w) & np.all(np.isfinite(n_ref), axis=1) & np.isfinite(h)
    return valid, bounded, X, n_ref, h, w


def _expand(starts, counts):
    """Concatenated ranges ``starts[k] + (0 .. counts[k]-1)`` and the owner ``k`` of each element."""
    counts = np.asarray(counts, np.int64)
    total = int(counts.sum())
    owner = np.repeat(np.arange(len(counts)), counts)
    first = np.cumsum(counts) - counts
    return owner, np.arange(total, dtype=np.int64) + (np.asarray(starts, np.int64) - first)[owner]


def _sweep(uq, aq, ut, periodic, sq=None, rq=None, st=None):
    """Sort-and-sweep on the epipolar coordinate: all pairs ``(q, t)`` with ``|uq - ut| <= aq`` (the
    difference taken modulo 2 pi when ``periodic``; ``aq`` inf: any), and, where ``sq`` is given, whose
    coordinates ``s`` along the epipolar lines may lie within ``rq`` of each other.

    The targets are sorted by (bin of ``st``, ``ut``); each query looks up, with :func:`numpy.searchsorted`,
    one window of ``ut`` per bin that its ``[sq - rq, sq + rq]`` reaches (two or three where its window
    wraps around +-pi). Windows are widened by more than the rounding of the keys, so the result is a
    superset of the exact condition (the exact tests follow).

    Returns ``(q, pos, order)``: ``q`` indexes ``uq`` (queries in sorted order, each query's pairs
    together), ``pos`` the sorted targets, whose indices into ``ut`` are ``order``.
    """
    if len(uq) == 0 or len(ut) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64)
    targets = _sweep_targets(ut, periodic, st, None if sq is None else _sweep_cell(rq, st))
    q, pos = _sweep_queries(targets, uq, aq, sq, rq)
    return q, pos, targets["order"]


def _sweep_cell(rq, st):
    """Width of the sweep's bins along the epipolar lines: the median reach (not below 1e-5 of the span)."""
    return max(float(np.median(rq)), (float(np.max(st)) - float(np.min(st))) * 1e-5, 1e-9)


def _sweep_targets(ut, periodic, st=None, cell=None):
    """The targets of :func:`_sweep` sorted by (bin of ``st``, ``ut``), with what the queries need."""
    if periodic:
        umin, umax = -np.pi, np.pi
    else:
        umin, umax = float(np.min(ut)), float(np.max(ut))
    span = (umax - umin) * (1 + 1e-6) + 1.0
    T = {"periodic": periodic, "umin": umin, "umax": umax, "span": span, "binned": st is not None}
    if st is None:
        bt = np.zeros(len(ut), np.int64)
    else:
        smin, smax = float(np.min(st)), float(np.max(st))
        bt = np.floor((st - smin) / cell).astype(np.int64)
        T.update(smin=smin, smax=smax, cell=cell, nb=int(bt.max()) + 1)
    key = bt * span + (ut - umin)
    order = np.argsort(key, kind="stable")
    key = key[order]
    T.update(order=order, key=key, eps=16.0 * float(np.spacing(np.max(np.abs(key)))) + 1e-12)
    return T


def _sweep_queries(T, uq, aq, sq=None, rq=None):
    """``(q, pos)`` of :func:`_sweep` for queries against targets prepared by :func:`_sweep_targets`."""
    nq = len(uq)
    if nq == 0 or len(T["key"]) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    umin, umax, span = T["umin"], T["umax"], T["span"]
    # bins along the epipolar lines
    if not T["binned"]:
        blo = bhi = np.zeros(nq, np.int64)
    else:
        smin, smax, cell, nb = T["smin"], T["smax"], T["cell"], T["nb"]
        rw = rq * (1 + 1e-9) + 1e-12 * (1.0 + abs(smin) + abs(smax))
        with np.errstate(invalid="ignore"):
            blo = np.clip(np.floor((sq - rw - smin) / cell), 0, nb - 1).astype(np.int64)
            bhi = np.clip(np.floor((sq + rw - smin) / cell), -1, nb - 1).astype(np.int64)
        bhi = np.where((sq + rw < smin) | (sq - rw > smax), blo - 1, bhi)
    # queries in the targets' order, so that neighbouring queries read neighbouring targets
    qorder = np.argsort(blo * span + (np.clip(uq, umin, umax) - umin), kind="stable")
    uq, aq, blo, bhi = uq[qorder], aq[qorder], blo[qorder], bhi[qorder]
    # query windows on u: (owner, lo, hi)
    if T["periodic"]:
        full = ~(aq < np.pi)
        lo = np.where(full, umin, uq - aq)
        hi = np.where(full, umax, uq + aq)
        wl = np.flatnonzero(~full & (lo < umin))  # wraps below -pi: also [lo + 2 pi, pi]
        wh = np.flatnonzero(~full & (hi > umax))  # wraps above pi: also [-pi, hi - 2 pi]
        owner = np.concatenate([np.arange(nq), wl, wh])
        plo = np.concatenate([lo, lo[wl] + 2 * np.pi, np.full(len(wh), umin)])
        phi = np.concatenate([hi, np.full(len(wl), umax), hi[wh] - 2 * np.pi])
        if len(wl) or len(wh):
            srt = np.argsort(owner, kind="stable")
            owner, plo, phi = owner[srt], plo[srt], phi[srt]
    else:
        owner, plo, phi = np.arange(nq), uq - aq, uq + aq
    plo, phi = np.maximum(plo, umin), np.minimum(phi, umax)
    keep = plo <= phi
    owner, plo, phi = owner[keep], plo[keep], phi[keep]
    key, eps = T["key"], T["eps"]
    piece, b = _expand(blo[owner], np.maximum(bhi[owner] - blo[owner] + 1, 0))
    base = b * span - umin
    first = np.searchsorted(key, base + plo[piece] - eps, side="left")
    last = np.searchsorted(key, base + phi[piece] + eps, side="right")
    which, pos = _expand(first, np.maximum(last - first, 0))
    return qorder[owner[piece[which]]], pos


def _resolve(s1, s2, params):
    d0 = params.d0_mm if params.d0_mm is not None else D0_PIXELS * max(s1.pitch, s2.pitch)
    gap0 = math.radians(params.max_normal_gap_deg)
    return d0, gap0, params.depth_range_mm


def _along_axis(s1: _Side, s2: _Side):
    """A horizontal unit vector along the epipolar lines, roughly (the cameras' baseline in the xy-plane):
    the coordinate the index bins on besides the epipolar one (any direction is correct; this one is fast)."""
    base = np.asarray(s2.camera.position, float) - np.asarray(s1.camera.position, float)
    base[2] = 0.0
    nb = float(np.linalg.norm(base))
    return base / nb if nb > 1e-9 else np.array([1.0, 0.0, 0.0])


def _proposals(s1: _Side, s2: _Side, params: StereoParams, workers: int = 1):
    """Pairs that may pass the tests: a superset of the passing pairs (module notes)."""
    d0, gap0, zr = _resolve(s1, s2, params)
    n1, n2 = len(s1.o), len(s2.o)
    if n1 == 0 or n2 == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    kind, u1, u2, k1, k2, K, B = _epipolar(s1, s2, d0)
    periodic = kind != "offset"
    v1, b1, X1, nr1, h1, w1 = _volume(s1, zr, d0)
    v2, b2, X2, nr2, h2, w2 = _volume(s2, zr, d0)
    out_i, out_j = [], []
    # loose rays (no finite bound on depth or normal): the epipolar coordinate alone
    loose1 = np.flatnonzero(v1 & ~b1)
    loose2 = np.flatnonzero(v2 & ~b2)
    all2 = np.flatnonzero(v2)
    tight1 = np.flatnonzero(b1)
    tight2 = np.flatnonzero(b2)
    for q, t in ((loose1, all2), (tight1, loose2)):
        if len(q) and len(t):
            a = _halfwidth(kind, None if kind == "offset" else k1[q],
                           None if kind == "offset" else float(np.min(k2[t])), K, B, d0, len(q))
            qi, pos, order = _sweep(u1[q], a, u2[t], periodic)
            out_i.append(q[qi])
            out_j.append(t[order[pos]])
    if len(tight1) and len(tight2):
        q, t = tight1, tight2
        a = _halfwidth(kind, None if kind == "offset" else k1[q],
                       None if kind == "offset" else float(np.min(k2[t])), K, B, d0, len(q))
        # along the epipolar lines: |(X1_ref - X2_ref) . e| <= h1 |d1 . e| + h2 |d2 . e| + D0 (module notes)
        e = _along_axis(s1, s2)
        reach2 = float(np.max(h2[t] * np.abs(s2.d[t] @ e)))
        reach_q = (h1[q] * np.abs(s1.d[q] @ e) + reach2 + d0) * (1 + _SAFETY) + 1e-12
        sq, st = X1[q] @ e, X2[t] @ e
        targets = _sweep_targets(u2[t], periodic, st, _sweep_cell(reach_q, st))
        w2max = float(np.max(w2[t]))
        t = t[targets["order"]]  # the targets in the sweep's order: pos indexes them
        # the bounds of the module notes, pair by pair: angle(n1_ref, n2_ref) <= gap0 + w1 + w2 (as a chord;
        # first each component against the query's largest bound, then the chord) and
        # |X1_ref - X2_ref| <= h1 + h2 + D0, each widened by the safety margin
        cn_q = 2.0 * np.sin(0.5 * np.minimum((gap0 + w1[q] + w2max) * (1 + _SAFETY), np.pi)) + 1e-12
        nq_c = [np.ascontiguousarray(nr1[q, k]) for k in range(3)]
        nt_c = [np.ascontiguousarray(nr2[t, k]) for k in range(3)]
        u1q = u1[q]

        def piece(sl):
            # the queries in pieces on threads, against the one sorted target list
            qi, pos = _sweep_queries(targets, u1q[sl], a[sl], sq[sl], reach_q[sl])
            qi = qi + sl.start
            chord = np.zeros(len(qi))
            for k in range(3):
                dn = nq_c[k][qi] - nt_c[k][pos]
                ok = np.abs(dn) <= cn_q[qi]
                qi, pos, chord = qi[ok], pos[ok], chord[ok] + dn[ok] * dn[ok]
            qi, tj = q[qi], t[pos]
            cn = 2.0 * np.sin(0.5 * np.minimum((gap0 + w1[qi] + w2[tj]) * (1 + _SAFETY), np.pi)) + 1e-12
            ok = chord <= cn * cn
            qi, tj = qi[ok], tj[ok]
            cx = (h1[qi] + h2[tj] + d0) * (1 + _SAFETY) + 1e-12
            dx2 = np.zeros(len(qi))
            for k in range(3):
                dx = X1[:, k][qi] - X2[:, k][tj]
                dx2 += dx * dx
            ok = dx2 <= cx * cx
            return qi[ok], tj[ok]

        for qi, tj in thread_map(piece, _pieces(len(q), workers), workers):
            out_i.append(qi)
            out_j.append(tj)
    if not out_i:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(out_i), np.concatenate(out_j)


def _check_pair(rays1, rays2, rig):
    _check_rig(rig)
    for name, r in (("rays1", rays1), ("rays2", rays2)):
        if not isinstance(r, HighlightRays):
            raise StereoError(f"must be HighlightRays (see highlight_rays), got {type(r).__name__}", field=name)
        if not 0 <= r.camera < len(rig.cameras):
            raise StereoError(f"camera {r.camera} is out of range 0..{len(rig.cameras) - 1}", field=name)
        if len(r.sources) and (r.sources.min() < 0 or r.sources.max() >= rig.n_sources):
            raise StereoError(f"a source index is out of range 0..{rig.n_sources - 1}", field=f"{name}.sources")
    if rays1.camera == rays2.camera:
        raise StereoError(f"both sets of highlights come from camera {rays1.camera}; stereo needs two cameras",
                          field="rays2.camera")


def _candidates(rays1, rays2, rig, params, naive=False, seconds=None):
    """Sides, the pairs that passed the tests (sorted by i then j, with what the tests computed) and the
    limits; ``seconds``: a dict that gets the time of the index (``candidates``) and of the tests."""
    params = StereoParams() if params is None else params
    if not isinstance(params, StereoParams):
        raise OptionError(f"params must be StereoParams, got {type(params).__name__}")
    _check_pair(rays1, rays2, rig)
    seconds = {} if seconds is None else seconds
    start = time.perf_counter()
    s1, s2 = _side(rays1, rig), _side(rays2, rig)
    d0, gap0, zr = _resolve(s1, s2, params)
    if naive:
        n1, n2 = len(s1.o), len(s2.o)
        parts = []
        rows = max(1, _CHUNK // max(n2, 1))
        for a in range(0, n1, rows):
            i = np.repeat(np.arange(a, min(a + rows, n1)), n2)
            j = np.tile(np.arange(n2), min(a + rows, n1) - a)
            parts.append(_exact_tests(s1, s2, i, j, d0, gap0, zr, params.threads))
        res = _Tested.join(parts)  # row by row: already sorted
        seconds["candidates"], seconds["tests"] = 0.0, time.perf_counter() - start
        return s1, s2, res, (d0, gap0, zr)
    pi, pj = _proposals(s1, s2, params, params.threads)
    mid = time.perf_counter()
    res = _exact_tests(s1, s2, pi, pj, d0, gap0, zr, params.threads)
    res = res.take(np.argsort(res.i * np.int64(max(len(s2.o), 1)) + res.j, kind="stable"))  # by i, then j
    seconds["candidates"], seconds["tests"] = mid - start, time.perf_counter() - mid
    return s1, s2, res, (d0, gap0, zr)


def candidate_pairs(rays1: HighlightRays, rays2: HighlightRays, rig: Rig, params: StereoParams | None = None):
    """Highlight pairs that pass the intersection, volume and normal tests, found with a spatial index.

    The same pairs as :func:`candidate_pairs_naive` (every proposal of the
    index gets the same exact tests, and the index provably proposes every
    pair that can pass: module notes), in O(N log N) plus the output.

    Parameters
    ----------
    rays1, rays2 : HighlightRays
        The two cameras' highlights (:func:`highlight_rays`).
    rig : Rig
    params : StereoParams, optional
        Uses ``d0_mm``, ``max_normal_gap_deg`` and ``depth_range_mm``.

    Returns
    -------
    i, j : (K,) int ndarray
        Indices into ``rays1`` and ``rays2``, sorted by ``i`` then ``j``.
    """
    res = _candidates(rays1, rays2, rig, params)[2]
    return res.i, res.j


def candidate_pairs_naive(rays1: HighlightRays, rays2: HighlightRays, rig: Rig, params: StereoParams | None = None):
    """The paper's O(N^2) search: the tests of :func:`candidate_pairs` on every pair (Section V).

    The baseline, and the reference the indexed search must equal; chunked
    so that memory stays bounded (about 2**18 pairs at a time).

    Returns
    -------
    i, j : (K,) int ndarray
        Sorted by ``i`` then ``j``.
    """
    res = _candidates(rays1, rays2, rig, params, naive=True)[2]
    return res.i, res.j


# -- residuals --------------------------------------------------------------------------------------


class _Bundle:
    """Rays ``idx`` of one side, gathered once as components (the residuals iterate on them)."""

    def __init__(self, side: _Side, idx=None, parts=None):
        if parts is not None:
            self.o, self.d, self.S, self.far = parts
        else:
            self.o, self.d, self.S = _take(side.oc, idx), _take(side.dc, idx), _take(side.Sc, idx)
            self.far = side.distant[idx]
        self.anyfar = bool(self.far.any())

    def sub(self, k):
        return _Bundle(None, parts=(_take(self.o, k), _take(self.d, k), _take(self.S, k), self.far[k]))


def _normal_and_rate(b: _Bundle, t):
    """``n(t)`` and ``dn/dt`` (per mm) along the rays of ``b`` (0 for a distant source), as components."""
    o, d, S = b.o, b.d, b.S
    rv = [S[k] - (o[k] + t * d[k]) for k in range(3)]
    r = np.sqrt(rv[0] * rv[0] + rv[1] * rv[1] + rv[2] * rv[2])
    pos = r > 0
    den = np.where(pos, r, 1.0)
    l = [rv[k] / den for k in range(3)]
    if b.anyfar:
        l = [np.where(b.far, S[k], l[k]) for k in range(3)]
    dd = d[0] * l[0] + d[1] * l[1] + d[2] * l[2]
    rinf = np.where(pos, r, np.inf)
    dl = [-(d[k] - dd * l[k]) / rinf for k in range(3)]
    if b.anyfar:
        dl = [np.where(b.far, 0.0, dl[k]) for k in range(3)]
    m = [l[k] - d[k] for k in range(3)]
    mn = np.sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2])
    # mn = 0 where the point lies on the line from the camera through the source (a step of the
    # solve that overshoots): no normal there; NaN, which _nearest_t does not step onto
    with np.errstate(divide="ignore", invalid="ignore"):
        n = [m[k] / mn for k in range(3)]
        ndl = n[0] * dl[0] + n[1] * dl[1] + n[2] * dl[2]
        dn = [(dl[k] - ndl * n[k]) / mn for k in range(3)]
    return n, dn


def _nearest_t(b: _Bundle, t, nstar, steps, tol_mm=None):
    """Gauss-Newton on ``|n(t) - n*|^2`` along each ray, from ``t``; with ``tol_mm``, a ray stops once its
    step is no longer (each ray's result then depends on that ray alone)."""
    moving = None
    for _ in range(steps):
        n, dn = _normal_and_rate(b, t)
        g2 = dn[0] * dn[0] + dn[1] * dn[1] + dn[2] * dn[2]
        with np.errstate(divide="ignore", invalid="ignore"):
            num = (nstar[0] - n[0]) * dn[0] + (nstar[1] - n[1]) * dn[1] + (nstar[2] - n[2]) * dn[2]
            step = np.where(g2 > 0, num / g2, 0.0)
        step = np.where(np.isfinite(step), step, 0.0)
        if tol_mm is None:
            t = t + step
            continue
        t = t + (step if moving is None else np.where(moving, step, 0.0))
        moving = np.abs(step) > tol_mm if moving is None else moving & (np.abs(step) > tol_mm)
        if not moving.any():
            break
    return t


def _reflectance(s1, s2, i, j, t1, t2):
    """Common normal n*, E1, E2 and delta_z (module notes), vectorised.

    A joint Newton step on (lambda, g1, g2) per pair solves the three conditions at once: each ``g``
    the nearest point of its ray to ``n*(lambda)`` (Gauss-Newton's normal equation) and ``E1 = E2``.
    The pairs it leaves unsettled, or settles outside the arc (no root between the two normals), go to
    :func:`_reflectance_bracketed`, which brackets the root on the arc or takes the better end."""
    b1, b2 = _Bundle(s1, i), _Bundle(s2, j)
    n1 = _normal_at_c(s1, i, [b1.o[k] + t1 * b1.d[k] for k in range(3)])
    n2 = _normal_at_c(s2, j, [b2.o[k] + t2 * b2.d[k] for k in range(3)])
    m = len(i)
    lam, g1, g2 = np.full(m, 0.5), t1.copy(), t2.copy()
    settled = np.zeros(m, bool)
    act = np.arange(m)
    r1, r2, c1, dN = b1, b2, n1, [n2[k] - n1[k] for k in range(3)]
    gn = np.sqrt(dN[0] * dN[0] + dN[1] * dN[1] + dN[2] * dN[2])
    with np.errstate(divide="ignore", invalid="ignore"):
        for _ in range(_NEWTON_STEPS):
            la, u1, u2 = lam[act], g1[act], g2[act]
            v = [c1[k] + la * dN[k] for k in range(3)]
            vn = np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
            ns = [v[k] / vn for k in range(3)]
            nd = ns[0] * dN[0] + ns[1] * dN[1] + ns[2] * dN[2]
            dns = [(dN[k] - nd * ns[k]) / vn for k in range(3)]
            h1, dh1 = _normal_and_rate(r1, u1)
            h2, dh2 = _normal_and_rate(r2, u2)
            a1 = dh1[0] * dh1[0] + dh1[1] * dh1[1] + dh1[2] * dh1[2]
            a2 = dh2[0] * dh2[0] + dh2[1] * dh2[1] + dh2[2] * dh2[2]
            p1 = (h1[0] - ns[0]) * dh1[0] + (h1[1] - ns[1]) * dh1[1] + (h1[2] - ns[2]) * dh1[2]
            p2 = (h2[0] - ns[0]) * dh2[0] + (h2[1] - ns[1]) * dh2[1] + (h2[2] - ns[2]) * dh2[2]
            q1 = (dh1[0] * dns[0] + dh1[1] * dns[1] + dh1[2] * dns[2]) / a1
            q2 = (dh2[0] * dns[0] + dh2[1] * dns[1] + dh2[2] * dns[2]) / a2
            f = (t1[act] - u1) - (t2[act] - u2)
            dl = (p2 / a2 - p1 / a1 - f) / (q2 - q1)
            d1 = q1 * dl - p1 / a1
            d2 = q2 * dl - p2 / a2
            good = np.isfinite(dl) & np.isfinite(d1) & np.isfinite(d2)
            lam[act] = np.where(good, la + dl, np.nan)
            g1[act] = np.where(good, u1 + d1, u1)
            g2[act] = np.where(good, u2 + d2, u2)
            # settled: n* moves by under 1e-13 rad and each element by under 1e-11 mm along its ray
            ok = good & (np.abs(dl) * gn[act] <= 1e-13) & (np.abs(d1) <= 1e-11) & (np.abs(d2) <= 1e-11)
            settled[act[ok]] = True
            keep = good & ~ok
            act = act[keep]
            if not act.size:
                break
            r1, r2 = r1.sub(keep), r2.sub(keep)
            c1, dN = [c[keep] for c in c1], [c[keep] for c in dN]
    inside = settled & (lam >= 0.0) & (lam <= 1.0)
    v = [n1[k] + lam * (n2[k] - n1[k]) for k in range(3)]
    vn = np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    with np.errstate(invalid="ignore", divide="ignore"):
        nstar = np.stack([v[k] / vn for k in range(3)], 1)
    e1, e2 = t1 - g1, t2 - g2
    # settled outside the arc: no root between the two normals; the end with the smaller |E1 - E2|
    out = np.flatnonzero(settled & ~inside)
    if out.size:
        o1, o2, u1, u2 = b1.sub(out), b2.sub(out), t1[out], t2[out]
        ends = []
        for c in (n1, n2):
            ce = [v[out] for v in c]
            h1 = _nearest_t(o1, u1, ce, 8, tol_mm=1e-11)
            h2 = _nearest_t(o2, u2, ce, 8, tol_mm=1e-11)
            ends.append((u1 - h1, u2 - h2, ce))
        (a1, a2, ca), (b1e, b2e, cb) = ends
        first = np.abs(a1 - a2) <= np.abs(b1e - b2e)
        e1[out], e2[out] = np.where(first, a1, b1e), np.where(first, a2, b2e)
        nstar[out] = np.stack([np.where(first, ca[k], cb[k]) for k in range(3)], 1)
    rest = np.flatnonzero(~settled)
    if rest.size:
        ns_r, e1_r, e2_r, _ = _reflectance_bracketed(s1, s2, i[rest], j[rest], t1[rest], t2[rest])
        nstar[rest], e1[rest], e2[rest] = ns_r, e1_r, e2_r
    return nstar, e1, e2, e1 - e2


#: Most joint Newton steps of :func:`_reflectance` (it settles in 3-5; the rest go to the bracketing solve).
_NEWTON_STEPS = 8


def _reflectance_bracketed(s1, s2, i, j, t1, t2):
    """:func:`_reflectance` by bracketing: Illinois regula falsi on the arc parameter, the nearest points
    by Gauss-Newton at each step; the end of the arc with the smaller ``|E1 - E2|`` where the two ends
    do not bracket a root."""
    b1, b2 = _Bundle(s1, i), _Bundle(s2, j)
    n1 = _normal_at_c(s1, i, [b1.o[k] + t1 * b1.d[k] for k in range(3)])
    n2 = _normal_at_c(s2, j, [b2.o[k] + t2 * b2.d[k] for k in range(3)])
    m = len(i)

    state = {"g1": t1.copy(), "g2": t2.copy()}

    def evaluate(lam, steps, sub=None):
        # Gauss-Newton warm-started from the last evaluation (lambda moves little between secant steps);
        # ``sub``: only those pairs (the ones still iterating)
        if sub is None:
            c1, c2, r1, r2, u1, u2, tt1, tt2 = n1, n2, b1, b2, state["g1"], state["g2"], t1, t2
        else:
            c1, c2 = [v[sub] for v in n1], [v[sub] for v in n2]
            r1, r2 = b1.sub(sub), b2.sub(sub)
            u1, u2, tt1, tt2 = state["g1"][sub], state["g2"][sub], t1[sub], t2[sub]
        v = [(1.0 - lam) * c1[k] + lam * c2[k] for k in range(3)]
        vn = np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
        with np.errstate(invalid="ignore", divide="ignore"):
            nstar = [v[k] / vn for k in range(3)]
        g1 = _nearest_t(r1, u1, nstar, steps)
        g2 = _nearest_t(r2, u2, nstar, steps)
        if sub is None:
            state["g1"], state["g2"] = g1, g2
        else:
            state["g1"][sub], state["g2"][sub] = g1, g2
        e1, e2 = -(g1 - tt1), -(g2 - tt2)
        return e1 - e2, e1, e2, nstar

    f0 = evaluate(np.zeros(m), 6)[0]
    state["g1"], state["g2"] = t1.copy(), t2.copy()
    f1 = evaluate(np.ones(m), 6)[0]
    state["g1"], state["g2"] = state["g1"].copy(), state["g2"].copy()
    lo, hi = np.zeros(m), np.ones(m)
    flo, fhi = f0.copy(), f1.copy()
    bracket = np.sign(flo) * np.sign(fhi) <= 0
    # no sign change: the end of the arc with the smaller |E1 - E2|
    lam = np.where(np.abs(f0) <= np.abs(f1), 0.0, 1.0)
    lam = np.where(bracket & (flo == 0), 0.0, np.where(bracket & (fhi == 0), 1.0, lam))
    act = np.flatnonzero(bracket & (flo != 0) & (fhi != 0))
    with np.errstate(divide="ignore", invalid="ignore"):
        for _ in range(40):
            if not act.size:
                break
            a_lo, a_hi, a_flo, a_fhi = lo[act], hi[act], flo[act], fhi[act]
            x = (a_lo * a_fhi - a_hi * a_flo) / (a_fhi - a_flo)
            x = np.where(np.isfinite(x), np.clip(x, a_lo, a_hi), 0.5 * (a_lo + a_hi))
            fx = evaluate(x, 3, act)[0]
            lam[act] = x
            left = np.sign(fx) == np.sign(a_flo)
            # Illinois: halve the stale end's value so that the bracket shrinks from both sides
            a_fhi = np.where(left, 0.5 * a_fhi, a_fhi)
            a_flo = np.where(left, a_flo, 0.5 * a_flo)
            lo[act] = np.where(left, x, a_lo)
            flo[act] = np.where(left, fx, a_flo)
            hi[act] = np.where(left, a_hi, x)
            fhi[act] = np.where(left, a_fhi, fx)
            # converged: E1 = E2 to 1e-10 mm, or the arc parameter to 1e-12
            act = act[(np.abs(fx) > 1e-10) & (hi[act] - lo[act] > 1e-12)]
    dz, e1, e2, nstar = evaluate(lam, 6)
    return np.stack(nstar, 1), e1, e2, dz


# -- relaxation -------------------------------------------------------------------------------------


def _competitor_max(values, i, j, n1, n2):
    """For each candidate: the largest value among the candidates sharing its i or its j (itself included),
    and the largest among those other than itself."""
    idx = np.arange(len(values))

    def per_group(key, n):
        best = np.full(n, -np.inf)
        np.maximum.at(best, key, values)
        # one holder of each group's best (the last), then the best of the rest of the group
        holder = np.full(n, -1)
        top = values >= best[key]
        np.maximum.at(holder, key[top], idx[top])
        rest = idx != holder[key]
        second = np.full(n, -np.inf)
        np.maximum.at(second, key[rest], values[rest])
        return best[key], np.where(rest, best[key], second[key])

    best_i, other_i = per_group(i, n1)
    best_j, other_j = per_group(j, n2)
    return np.maximum(best_i, best_j), np.maximum(other_i, other_j)


def _spatial_order(P):
    """A permutation that puts nearby points near each other in memory: strips a few point spacings
    wide across the two widest axes, sorted along each strip (the sparse products of the relaxation
    then read their neighbours from cache)."""
    k = len(P)
    lo, hi = P.min(axis=0), P.max(axis=0)
    ext = hi - lo
    a0, a1 = np.argsort(-ext)[:2]
    cell = 8.0 * math.sqrt(max(ext[a0] * ext[a1], 1e-300) / max(k, 1))
    if not (np.isfinite(cell) and cell > 0):
        return np.arange(k)
    strip = np.floor((P[:, a1] - lo[a1]) / cell)
    # one sort key: the strip, then the place along it (any order serves; results do not depend on it)
    return np.argsort(strip * (2.0 * ext[a0] + 1.0) + (P[:, a0] - lo[a0]))


#: Points whose nearest-neighbour distances :func:`_median_nn` takes the median of, at most.
_NN_SAMPLE = 16384


def _median_nn(tree, P):
    """Median distance from each point to its nearest other point (0 with fewer than two points).

    Beyond :data:`_NN_SAMPLE` points, the median over every ``s``-th point (``s`` the smallest stride
    that keeps the sample within it; each still searched against all the points): a sample of 16384
    puts the median within about 1 % of the whole set's (its standard error is about 1.25 sigma / sqrt(n)
    with sigma, the spread of the distances, below their median), and the support radius it sets is a
    rule of thumb (:class:`StereoParams`), not a measurement.

    The nearest neighbours are searched within a bound first (a few times the median spacing that the
    points' spread suggests, then four times wider): once more than half of the points have theirs
    within it, the middle of the sorted distances is known exactly, and the others (marked infinite)
    cannot change it; a full search otherwise."""
    k = len(P)
    if k < 2:
        return 0.0
    ext = np.sort(P.max(axis=0) - P.min(axis=0))[::-1]
    guess = math.sqrt(max(ext[0] * ext[1], 1e-300) / k)
    if k > _NN_SAMPLE:
        P = P[::-(-k // _NN_SAMPLE)]
        k = len(P)
    for bound in (guess, 4.0 * guess, None):
        if bound is None or not (np.isfinite(bound) and bound > 0):
            dist, _ = tree.query(P, k=2)
            nn = dist[:, 1][np.isfinite(dist[:, 1])]
            return float(np.median(nn)) if nn.size else 0.0
        dist, _ = tree.query(P, k=2, distance_upper_bound=bound)
        if np.count_nonzero(np.isfinite(dist[:, 1])) >= k // 2 + 1:
            return float(np.median(dist[:, 1]))
    return 0.0


def _support_matrix(P, N, i, j, radius, rise_tol, gap0, tree=None, cols=None, workers=1):
    """Sparse symmetric weights between candidates that fit one smooth surface (module notes).

    ``cols`` (optional): a label per candidate (a permutation); each row's entries are then stored in
    increasing ``cols`` (the order in which the products sum), the column indices staying those of ``P``."""
    k = len(P)
    if k < 2 or radius <= 0:
        return sparse.csr_matrix((k, k))
    tree = cKDTree(P) if tree is None else tree
    pairs = tree.query_pairs(radius, output_type="ndarray")
    if len(pairs) == 0:
        return sparse.csr_matrix((k, k))
    cols = np.arange(k) if cols is None else cols
    index = np.int32 if k < 2**31 - 1 else np.int64
    lab = cols.astype(index)
    Pc = [np.ascontiguousarray(P[:, c]) for c in range(3)]
    Nc = [np.ascontiguousarray(N[:, c]) for c in range(3)]
    m = len(pairs)
    sin_gap = math.sin(gap0)

    def piece(sl):
        # component by component (the same operations as on (K, 3) rows, so the same bits)
        a, b = pairs[sl, 0], pairs[sl, 1]
        distinct = (i[a] != i[b]) & (j[a] != j[b])
        a, b = a[distinct], b[distinct]
        dP = [v[b] - v[a] for v in Pc]
        h = [0.5 * (v[a] + v[b]) for v in Nc]
        rise = np.abs(dP[0] * h[0] + dP[1] * h[1] + dP[2] * h[2])
        tol = rise_tol + np.sqrt(dP[0] * dP[0] + dP[1] * dP[1] + dP[2] * dP[2]) * sin_gap
        wgt = np.exp(-0.5 * (rise / tol) ** 2)
        return (np.concatenate([a, b]).astype(index), np.concatenate([lab[b], lab[a]]),
                np.concatenate([wgt, wgt]))

    # in pieces (small temporaries, on threads); the pieces' order does not matter: each row is sorted below
    parts = thread_map(piece, [slice(a, a + _PAIR_PIECE) for a in range(0, m, _PAIR_PIECE)], workers)
    rows, labels, data = (np.concatenate(v) for v in zip(*parts))
    # canonical CSR: each row's entries sorted by label
    W = sparse.coo_matrix((data, (rows, labels)), shape=(k, k)).tocsr()
    W.sort_indices()
    inv = np.empty(k, index)
    inv[cols] = np.arange(k, dtype=index)
    return sparse.csr_matrix((W.data, inv[W.indices], W.indptr), shape=(k, k))


def _relax(a0, gvec, W, i, j, n1, n2, gap0, iterations, tol, workers=1):
    """Relaxation to a fixed point (module notes); returns the final x, activations, support, steps.

    A candidate without competitors keeps activation 1 exactly (``x / x``) as long as its ``x`` is
    positive and finite, which holds when no candidate has 700 neighbours or more (``x >= a0 exp(-bias)``
    with ``a0 >= exp(-2)`` and ``bias <= 1 + support``): the steps then update only the candidates with
    competitors, and every candidate gets its final ``x`` and support at the end."""
    act = np.ones_like(a0)
    steps = 0
    k = len(a0)
    g = [np.ascontiguousarray(gvec[:, c]) for c in range(3)]
    rows = np.arange(k)
    if k and int(np.max(np.diff(W.indptr))) < 700:
        ni = np.bincount(i, minlength=n1)
        nj = np.bincount(j, minlength=n2)
        rows = np.flatnonzero((ni[i] > 1) | (nj[j] > 1))
    Wr = W if len(rows) == k else W[rows]

    def excite(act, M, own_g, own_a0):
        support = M @ act
        one = 1.0 + support
        # the neighbourhood's mean normal gap: zero-mean scatter on a real surface, a smooth bias on a ghost
        gb = [(own_g[c] + M @ (act * g[c])) / one for c in range(3)]
        if gap0 > 0:
            bias = one * (gb[0] * gb[0] + gb[1] * gb[1] + gb[2] * gb[2]) / gap0**2
        else:
            bias = np.zeros_like(one)
        return own_a0 * np.exp(-bias) * one, support

    ir, jr, g_r, a0_r = i[rows], j[rows], [v[rows] for v in g], a0[rows]
    nr = len(rows)
    # the rows in blocks, one per thread (a row's sums are the same whichever block holds it)
    blocks = {sl.start: Wr[sl] for sl in _pieces(nr, workers)}

    def step_all(act):
        return _per_piece(lambda sl: excite(act, blocks[sl.start], [v[sl] for v in g_r], a0_r[sl]), nr,
                          workers)[0]

    def step_some(act, sub):
        return _per_piece(lambda sl: excite(act, Wr[sub[sl]], [v[sub[sl]] for v in g_r], a0_r[sub[sl]]),
                          len(sub), workers)[0]
    best_i, best_j = np.empty(n1), np.empty(n2)

    def group_best(x):
        # the largest x among each row's competitors (the rows sharing its i or its j), itself included
        best_i.fill(-np.inf)
        best_j.fill(-np.inf)
        np.maximum.at(best_i, ir, x)
        np.maximum.at(best_j, jr, x)
        return np.maximum(best_i[ir], best_j[jr])

    local = np.full(k, -1, np.int64)
    local[rows] = np.arange(nr)
    x_r = np.zeros(nr)
    last_pull = np.zeros(nr)  # each row's last pull towards its target (the damping's memory)
    sub = None  # None: every row; else the rows (local indices) that this step updates
    if nr:
        # the start: every activation at its first target, x over the largest x of its competitors
        x = step_all(act)
        act[rows] = x / group_best(x)
    for steps in range(1, iterations + 1):
        if sub is None:
            x = step_all(act)
            x_r[:] = x
        else:
            x = step_some(act, sub)
            x_r[sub] = x
        best = group_best(x_r)
        idx = rows if sub is None else rows[sub]
        # damped: a candidate's activation moves _STEP of the way to its new value, half way where its pull
        # turned since its last update (rivals taking turns: the half step keeps them from oscillating)
        old = act[idx]
        pull = x / (best if sub is None else best[sub]) - old
        at = slice(None) if sub is None else sub
        new = old + np.where(pull * last_pull[at] < 0, 0.5, _STEP) * pull
        last_pull[at] = pull
        moved = np.abs(new - old)
        act[idx] = new
        change = float(np.max(moved)) if len(moved) else 0.0
        if sub is None:
            if change <= tol:
                break
            if np.count_nonzero(moved > tol) * 8 > nr:
                continue
        elif change <= tol:
            # the rows left out moved by at most tol / 4 when last updated: a step over every
            # row says whether this is the fixed point
            sub = None
            continue
        # the next step updates only the rows still moving, their competitors and their support neighbours
        # (the rows whose inputs moved); a full step ends the run, so the stopping rule is the plain one
        warm = np.flatnonzero(moved > tol / 4)
        hot = np.flatnonzero(moved > tol)
        if sub is not None:
            warm, hot = sub[warm], sub[hot]
        near = local[Wr[hot].indices]
        mark_i = np.zeros(n1, bool)
        mark_j = np.zeros(n2, bool)
        mark_i[ir[hot]] = True
        mark_j[jr[hot]] = True
        touched = mark_i[ir] | mark_j[jr]
        touched[near[near >= 0]] = True
        touched[warm] = True
        sub = np.flatnonzero(touched)
    x, support = _per_piece(lambda sl: excite(act, W[sl], [v[sl] for v in g], a0[sl]), k, workers)
    return x, act, support, steps


def _greedy_fast(score, i, j, n1, n2):
    """Greedy uniqueness: repeatedly accept every candidate that is the best of its i and of its j."""
    alive = np.ones(len(score), bool)
    take = np.zeros(len(score), bool)
    key = score.astype(float)
    # ties broken by (i, j) so that the result does not depend on the candidates' order
    rank = np.empty(len(key), np.int64)
    rank[np.lexsort((j, i, -key))] = np.arange(len(key))
    prio = -rank.astype(float)  # larger is better, all distinct
    while np.any(alive):
        idx = np.flatnonzero(alive)
        best_i = np.full(n1, -np.inf)
        best_j = np.full(n2, -np.inf)
        np.maximum.at(best_i, i[idx], prio[idx])
        np.maximum.at(best_j, j[idx], prio[idx])
        win = idx[(prio[idx] >= best_i[i[idx]]) & (prio[idx] >= best_j[j[idx]])]
        take[win] = True
        used1 = np.zeros(n1, bool)
        used2 = np.zeros(n2, bool)
        used1[i[win]] = True
        used2[j[win]] = True
        alive[idx] = ~(used1[i[idx]] | used2[j[idx]])
    return take


# -- result -----------------------------------------------------------------------------------------


@dataclass
class StereoMatches:
    """Accepted stereo matches, one row each (:func:`match_highlights`).

    Attributes
    ----------
    point : (M, 3) float, millimetres
        The match's surface point, world frame: the midpoint of its two
        elements placed by the umbilic refinement where ``refined``, else
        ``crossing``.
    normal : (M, 3) float
        Unit normal there: the mean of the two elements' normals where
        ``refined``, else ``n*``, the common normal of reflectance matching
        (module notes).
    crossing : (M, 3) float, millimetres
        ``P*``: midpoint of the rays' closest approach (Eq 40), the paper's
        point.
    refined : (M,) bool
        The umbilic refinement placed the elements (module notes).
    radius_mm : (M,) float
        Its local radius of curvature ``rho`` (signed: positive where the
        surface is convex towards the cameras); NaN where not refined.
    row1, col1, row2, col2 : (M,) float
        The two highlights' centroids, pixels.
    source1, source2 : (M,) int
        Their sources.
    index1, index2 : (M,) int
        Their positions in the two :class:`HighlightRays`.
    d_mm : (M,) float
        Closest-approach distance ``D`` (Eq 40), millimetres.
    normal_gap_deg : (M,) float
        ``angle(n1(P1*), n2(P2*))``, degrees.
    e1_mm, e2_mm : (M,) float
        ``E'``, ``E''`` of Eqs 33-34 in vector form: signed distance along
        each ray, from ``P_k*`` towards the camera, to where the ray's normal
        is nearest ``n*``.
    delta_z_mm : (M,) float
        ``e1 - e2`` (Eq 43's Delta z); zero where ``E1 = E2`` has a root on
        the arc from ``n1`` to ``n2``.
    confidence : (M,) float in [0, 1]
        ``a0 * margin``: the likelihood of the residuals times the margin
        over the best competitor (module notes).
    support : (M,) float
        Relaxation support (weighted count of consistent neighbours; 0
        without relaxation).
    n_examined : int
        Pairs that got the exact tests (``N1 * N2`` for the naive search).
    n_rejected_distance, n_rejected_depth, n_rejected_normal : int
        Examined pairs dropped by each test, in that order (``D >= D0`` or
        behind a camera; outside the depth range; normal gap too large).
    n_candidates : int
        Pairs that passed them.
    n_rejected_delta_z, n_rejected_e : int
        Candidates dropped by the optional Eq 43 / Eq 33-34 limits.
    n_rejected_uniqueness : int
        Candidates that lost to a competitor (relaxation and uniqueness).
    relax_iterations : int
    d0_mm, max_normal_gap_deg, neighbourhood_mm : float
        The limits used (after defaults were resolved).
    reason : str
        Why there are no matches (empty when there are some).
    seconds : dict
        Wall-clock seconds of each stage: ``candidates`` (the index),
        ``tests`` (the exact tests), ``relaxation`` (support weights and
        the relaxation), ``uniqueness`` and ``reflectance`` (reflectance
        matching of the accepted pairs); stages not reached are absent.
    """

    point: np.ndarray
    normal: np.ndarray
    row1: np.ndarray
    col1: np.ndarray
    row2: np.ndarray
    col2: np.ndarray
    source1: np.ndarray
    source2: np.ndarray
    index1: np.ndarray
    index2: np.ndarray
    d_mm: np.ndarray
    normal_gap_deg: np.ndarray
    e1_mm: np.ndarray
    e2_mm: np.ndarray
    delta_z_mm: np.ndarray
    confidence: np.ndarray
    support: np.ndarray
    crossing: np.ndarray | None = None
    refined: np.ndarray | None = None
    radius_mm: np.ndarray | None = None
    n_examined: int = 0
    n_rejected_distance: int = 0
    n_rejected_depth: int = 0
    n_rejected_normal: int = 0
    n_candidates: int = 0
    n_rejected_delta_z: int = 0
    n_rejected_e: int = 0
    n_rejected_uniqueness: int = 0
    relax_iterations: int = 0
    d0_mm: float = float("nan")
    max_normal_gap_deg: float = float("nan")
    neighbourhood_mm: float = float("nan")
    reason: str = ""
    counts: dict = field(default_factory=dict, repr=False)
    seconds: dict = field(default_factory=dict, repr=False)

    def __post_init__(self):
        m = self.point.shape[0]
        if self.crossing is None:
            self.crossing = self.point.copy()
        if self.refined is None:
            self.refined = np.zeros(m, bool)
        if self.radius_mm is None:
            self.radius_mm = np.full(m, np.nan)

    def __len__(self) -> int:
        return int(self.point.shape[0])

    @staticmethod
    def columns() -> tuple[str, ...]:
        """Column names of :meth:`as_dict` and :meth:`to_csv` (:data:`STEREO_COLUMNS`)."""
        return STEREO_COLUMNS

    def as_dict(self) -> dict[str, np.ndarray]:
        """One (M,) array per column of :meth:`columns`."""
        return {"x_mm": self.point[:, 0], "y_mm": self.point[:, 1], "z_mm": self.point[:, 2],
                "nx": self.normal[:, 0], "ny": self.normal[:, 1], "nz": self.normal[:, 2],
                "row1": self.row1, "col1": self.col1, "row2": self.row2, "col2": self.col2,
                "source1": self.source1, "source2": self.source2, "index1": self.index1, "index2": self.index2,
                "d_mm": self.d_mm, "normal_gap_deg": self.normal_gap_deg, "e1_mm": self.e1_mm,
                "e2_mm": self.e2_mm, "delta_z_mm": self.delta_z_mm, "confidence": self.confidence,
                "refined": self.refined, "radius_mm": self.radius_mm, "cx_mm": self.crossing[:, 0],
                "cy_mm": self.crossing[:, 1], "cz_mm": self.crossing[:, 2]}

    def to_csv(self, path, *, overwrite: bool = False):
        """Write the matches as CSV: a header of :meth:`columns`, one row per match.

        Floats are written with ``repr`` (they read back exactly), integers as
        integers. Refuses to replace an existing file unless ``overwrite``.

        Returns
        -------
        Path
        """
        cols = self.as_dict()
        buf = io.StringIO()
        writer = csv.writer(buf, lineterminator="\n")
        writer.writerow(STEREO_COLUMNS)
        ints = {"source1", "source2", "index1", "index2", "refined"}
        data = [cols[c].tolist() for c in STEREO_COLUMNS]
        for row in zip(*data):
            writer.writerow([str(int(v)) if c in ints else repr(float(v)) for c, v in zip(STEREO_COLUMNS, row)])
        return write_text(path, buf.getvalue(), overwrite=overwrite)


def _cramer(a, b, c, r):
    """Per row, ``(x, y, z)`` with ``x a + y b + z c = r`` (each a list of three component arrays) by
    Cramer's rule, and where the system is solvable.

    In the refinement ``a`` and ``b`` are near the two rays' unit directions and ``c`` the difference of
    two normals: where ``c`` has (almost) no part across the plane of the rays the system is singular
    (rho is not observed: a plane, an exact lattice match). Its smallest singular value is about
    ``|det| / |a x b|``; below 1e-6 of the largest (about 1.4) the row is left to the caller. Above it
    the condition number stays under about 1e6, so Cramer's rule loses at most six of the sixteen
    digits."""
    def cross(u, v):
        return [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]

    def dot(u, v):
        return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]

    bc, ca, ab = cross(b, c), cross(c, a), cross(a, b)
    det = dot(a, bc)
    ok = np.abs(det) > 1.4e-6 * np.sqrt(dot(ab, ab))
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(ok, 1.0 / det, 0.0)
    return dot(r, bc) * inv, dot(r, ca) * inv, dot(r, ab) * inv, ok


def _umbilic(s1, s2, i, j, P, d0, passes=8, tol_mm=1e-10):
    """Place each pair's two elements on a locally spherical surface (module notes, "Refinement").

    Newton's method on ``F = E1(t1) - E2(t2) + rho (n2(E2) - n1(E1)) = 0`` in ``(t1, t2, rho)``, from the
    rays' crossing: its first step, with ``rho = 0`` in the Jacobian, solves the three linear equations
    with the normals held at the crossing; the next ones add the normals' rates
    along the rays (``dn/dt``, through the directions to the sources), which a fixed-point iteration
    cannot follow where ``rho^2`` exceeds ``|E2 - E1|`` times the source distance. A pair stops when its
    elements move by no more than ``tol_mm``, after at most ``passes`` steps; a pair whose system is
    singular (``rho`` not observed: a plane) keeps the rays' closest approach and ``rho = 0``.

    Returns
    -------
    point, normal : (M, 3)
        Midpoint of the two elements and the mean of their normals (NaN where
        not refined).
    refined : (M,) bool
    radius : (M,) float, millimetres (NaN where not refined)
    """
    m = len(i)
    b1, b2 = _Bundle(s1, i), _Bundle(s2, j)
    Pc = [P[:, k] for k in range(3)]
    t1 = sum((Pc[k] - b1.o[k]) * b1.d[k] for k in range(3))
    t2 = sum((Pc[k] - b2.o[k]) * b2.d[k] for k in range(3))
    rho = np.zeros(m)
    act = np.arange(m)
    r1, r2 = b1, b2
    with np.errstate(invalid="ignore"):
        for step in range(passes):
            u1, u2, rr = t1[act], t2[act], rho[act]
            h1, dh1 = _normal_and_rate(r1, u1)
            h2, dh2 = _normal_and_rate(r2, u2)
            dn = [h2[k] - h1[k] for k in range(3)]
            F = [(r1.o[k] + u1 * r1.d[k]) - (r2.o[k] + u2 * r2.d[k]) + rr * dn[k] for k in range(3)]
            A = [r1.d[k] - rr * dh1[k] for k in range(3)]
            B = [rr * dh2[k] - r2.d[k] for k in range(3)]
            x, y, z, ok = _cramer(A, B, dn, [-v for v in F])
            if step == 0 and not ok.all():
                # rho not observed: the closest approach of o1 + t1 d1 and o2 + t2 d2
                nb = ~ok
                d1, d2 = [v[nb] for v in r1.d], [v[nb] for v in r2.d]
                bo = [np.broadcast_to(r2.o[k], u2.shape)[nb] - np.broadcast_to(r1.o[k], u1.shape)[nb]
                      for k in range(3)]
                c = d1[0] * d2[0] + d1[1] * d2[1] + d1[2] * d2[2]
                e1 = d1[0] * bo[0] + d1[1] * bo[1] + d1[2] * bo[2]
                e2 = d2[0] * bo[0] + d2[1] * bo[1] + d2[2] * bo[2]
                den = np.where(1.0 - c * c > 0, 1.0 - c * c, np.nan)
                t1[act[nb]], t2[act[nb]] = (e1 - c * e2) / den, (c * e1 - e2) / den
            t1[act] = np.where(ok, u1 + x, t1[act])
            t2[act] = np.where(ok, u2 + y, t2[act])
            rho[act] = np.where(ok, rr + z, rr)
            more = ok & ((np.abs(x) > tol_mm) | (np.abs(y) > tol_mm))
            act = act[more]
            if not act.size:
                break
            r1, r2 = r1.sub(more), r2.sub(more)
    E1 = np.stack([b1.o[k] + t1 * b1.d[k] for k in range(3)], 1)
    E2 = np.stack([b2.o[k] + t2 * b2.d[k] for k in range(3)], 1)
    n1, n2 = _normal_at(s1, i, E1), _normal_at(s2, j, E2)
    ok = np.all(np.isfinite(E1), axis=1) & np.all(np.isfinite(E2), axis=1) & (_norm(E2 - E1) <= d0)
    point = np.where(ok[:, None], 0.5 * (E1 + E2), np.nan)
    normal = np.where(ok[:, None], _unit(n1 + n2), np.nan)
    return point, normal, ok, np.where(ok, rho, np.nan)


def _empty(reason, **counts):
    z = np.zeros(0)
    zi = np.zeros(0, np.int64)
    return StereoMatches(np.zeros((0, 3)), np.zeros((0, 3)), z, z, z, z, zi, zi, zi, zi, z, z, z, z, z, z, z,
                         reason=reason, **counts)


def match_highlights(rays1: HighlightRays, rays2: HighlightRays, rig: Rig,
                     params: StereoParams | None = None) -> StereoMatches:
    """Structured-highlight stereo: match two cameras' highlights into surface points and normals.

    Candidates from :func:`candidate_pairs` (intersection Eq 40, working
    volume, normal gap), optional Eq 43 / Eqs 33-34 limits, then relaxation
    and uniqueness (each highlight in at most one match); residuals and the
    common normal by reflectance matching (Eqs 32-34 in vector form). See
    the module notes for every definition.

    Parameters
    ----------
    rays1, rays2 : HighlightRays
        Highlights of two different cameras of ``rig``.
    rig : Rig
    params : StereoParams, optional

    Returns
    -------
    StereoMatches
        Empty, with ``reason`` saying why, when nothing is accepted (not an
        exception).

    Raises
    ------
    StereoError
        Highlights of the same camera, a camera or source index out of range,
        a rig with one camera, cameras with no baseline.
    OptionError
        ``params`` not a :class:`StereoParams`.
    """
    params = StereoParams() if params is None else params
    seconds = {}
    s1, s2, res, (d0, gap0, zr) = _candidates(rays1, rays2, rig, params, seconds=seconds)
    i, j = res.i, res.j
    stats = dict(examined=res.n_examined, distance=res.n_distance, depth=res.n_depth, normal=res.n_normal)
    n1, n2 = len(s1.o), len(s2.o)
    counts = dict(n_examined=int(stats["examined"]), n_rejected_distance=int(stats["distance"]),
                  n_rejected_depth=int(stats["depth"]), n_rejected_normal=int(stats["normal"]),
                  n_candidates=int(len(i)), d0_mm=float(d0), max_normal_gap_deg=float(np.degrees(gap0)))
    if n1 == 0 or n2 == 0:
        return _empty(f"no highlights in camera {rays1.camera if n1 == 0 else rays2.camera}", **counts)
    if len(i) == 0:
        if stats["examined"] == stats["distance"]:
            why = f"no pair of rays passes within D0 = {d0:.4g} mm of each other in front of both cameras"
        elif stats["examined"] == stats["distance"] + stats["depth"]:
            why = f"no ray crossing within D0 lies in the depth range {zr}"
        else:
            why = (f"no pair passed the normal test (max_normal_gap_deg = {np.degrees(gap0):.4g}); "
                   f"{stats['normal']} crossing pairs had normals further apart")
        return _empty(why, **counts)
    t1, t2, D, P, n1v, n2v, gap = res.t1, res.t2, res.D, res.P, res.n1, res.n2, res.gap
    keep = np.ones(len(i), bool)
    nz_rej = ne_rej = 0
    if params.max_delta_z_mm is not None or params.max_e_mm is not None:
        _, e1, e2, dz = _per_piece(lambda sl: _reflectance(s1, s2, i[sl], j[sl], t1[sl], t2[sl]), len(i),
                                   params.threads)
        if params.max_delta_z_mm is not None:
            bad = np.abs(dz) > params.max_delta_z_mm
            nz_rej = int(np.count_nonzero(bad))
            keep &= ~bad
        if params.max_e_mm is not None:
            bad = keep & ((np.abs(e1) > params.max_e_mm) | (np.abs(e2) > params.max_e_mm))
            ne_rej = int(np.count_nonzero(bad))
            keep &= ~bad
    counts.update(n_rejected_delta_z=nz_rej, n_rejected_e=ne_rej)
    if not np.any(keep):
        return _empty("no candidate passed the reflectance-matching limits "
                      f"(max_delta_z_mm = {params.max_delta_z_mm}, max_e_mm = {params.max_e_mm})", **counts)
    sel = np.flatnonzero(keep)
    i, j, t1, t2, D, P, gap = i[sel], j[sel], t1[sel], t2[sel], D[sel], P[sel], gap[sel]
    nmean = _unit(n1v[sel] + n2v[sel])
    with np.errstate(divide="ignore", invalid="ignore"):
        q = (D / d0) ** 2 + np.where(gap0 > 0, (gap / gap0) ** 2, 0.0)
    a0 = np.exp(-q)
    radius = float("nan")
    iters = 0
    t_start = time.perf_counter()
    if params.relax and len(i) > 1:
        # the relaxation runs on the candidates in a spatial order (cache); every result is per candidate,
        # and each sparse product sums its terms in the candidates' (i, j) order, as without the reordering
        perm = _spatial_order(P)
        Ps = np.ascontiguousarray(P[perm])
        tree = cKDTree(Ps, balanced_tree=False, compact_nodes=False)
        if params.neighbourhood_mm is not None:
            radius = params.neighbourhood_mm
        else:
            radius = 4.0 * _median_nn(tree, Ps)
        rise_tol = params.rise_tol_mm if params.rise_tol_mm is not None else d0
        W = _support_matrix(Ps, nmean[perm], i[perm], j[perm], radius, rise_tol, gap0, tree=tree, cols=perm,
                            workers=params.threads)
        xs, _, ss, iters = _relax(a0[perm], (n2v[sel] - n1v[sel])[perm], W, i[perm], j[perm], n1, n2, gap0,
                                  params.iterations, params.tol, params.threads)
        x, support = np.empty_like(xs), np.empty_like(ss)
        x[perm], support[perm] = xs, ss
    else:
        x, support = a0, np.zeros_like(a0)
    seconds["relaxation"] = time.perf_counter() - t_start
    t_start = time.perf_counter()
    take = _greedy_fast(x, i, j, n1, n2)
    _, other = _competitor_max(x, i, j, n1, n2)
    with np.errstate(divide="ignore", invalid="ignore"):
        margin = np.where(np.isfinite(other), 1.0 - other / x, 1.0)
    margin = np.clip(np.nan_to_num(margin, nan=0.0), 0.0, 1.0)
    conf = np.clip(a0 * margin, 0.0, 1.0)
    counts.update(n_rejected_uniqueness=int(len(i) - np.count_nonzero(take)), relax_iterations=int(iters),
                  neighbourhood_mm=float(radius))
    w = np.flatnonzero(take)
    i, j, t1, t2 = i[w], j[w], t1[w], t2[w]
    seconds["uniqueness"] = time.perf_counter() - t_start
    t_start = time.perf_counter()
    nstar, e1, e2, dz = _per_piece(lambda sl: _reflectance(s1, s2, i[sl], j[sl], t1[sl], t2[sl]), len(i),
                                   params.threads)
    order = np.lexsort((j, i))
    w, i, j, nstar, e1, e2, dz = w[order], i[order], j[order], nstar[order], e1[order], e2[order], dz[order]
    seconds["reflectance"] = time.perf_counter() - t_start
    point, normal = P[w], nstar
    refined, rho = np.zeros(len(w), bool), np.full(len(w), np.nan)
    if params.refine and len(w):
        t_start = time.perf_counter()
        Pw = P[w]
        rp, rn, refined, rho = _per_piece(lambda sl: _umbilic(s1, s2, i[sl], j[sl], Pw[sl], d0), len(w),
                                          params.threads)
        point = np.where(refined[:, None], rp, point)
        normal = np.where(refined[:, None], rn, normal)
        seconds["refinement"] = time.perf_counter() - t_start
    return StereoMatches(
        point=point, normal=normal, row1=rays1.rows[i], col1=rays1.cols[i], row2=rays2.rows[j],
        col2=rays2.cols[j], source1=rays1.sources[i], source2=rays2.sources[j], index1=i, index2=j, d_mm=D[w],
        normal_gap_deg=np.degrees(gap[w]), e1_mm=e1, e2_mm=e2, delta_z_mm=dz, confidence=conf[w],
        support=support[w], crossing=P[w], refined=refined, radius_mm=rho, seconds=seconds, **counts)
