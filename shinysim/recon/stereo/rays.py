"""One camera's highlights as rays (:func:`highlight_rays`), the matcher's settings (:class:`StereoParams`), and the per-side arrays the tests use.

See ``docs/stereo-matching.md`` for every definition.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..._shared import check_attributes, check_number, cores
from ...errors import OptionError, StereoError
from ...io.table import HighlightTable
from ...rig import Rig
from ._base import TOLERANCE_SCALE, _unit_c

__all__ = ["HighlightRays", "StereoParams", "highlight_rays"]


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
    usable : (N,) bool or None
        Highlights the matcher may pair (None: all). :meth:`from_table` leaves out those whose region is
        ``cut`` by the image's border: their centroids are not their mirror points'.
    """

    camera: int
    rows: np.ndarray
    cols: np.ndarray
    sources: np.ndarray
    origins: np.ndarray
    directions: np.ndarray
    usable: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.rows.shape[0])

    @classmethod
    def from_table(cls, table, rig: Rig, camera_index: int) -> HighlightRays:
        """The rays of a :class:`~shinysim.io.table.HighlightTable`'s highlights (its ``row``, ``col`` and
        ``source`` columns), seen by camera ``camera_index``: :func:`highlight_rays`."""
        if not isinstance(table, HighlightTable):
            raise StereoError(f"must be a HighlightTable, got {type(table).__name__}", field="table")
        rays = highlight_rays(table["row"], table["col"], table["source"], rig, camera_index)
        if "cut" in table:
            rays = replace(rays, usable=~np.asarray(table["cut"], bool))
        return rays


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
    origins, directions = (np.ascontiguousarray(a.reshape(-1, 3))
                           for a in rig.cameras[int(camera_index)].pixel_rays(r, c))
    return HighlightRays(int(camera_index), r, c, s, origins, directions)


@dataclass(frozen=True)
class StereoParams:
    """Settings of :func:`match_highlights`.

    Parameters
    ----------
    d0_mm : float or None
        Limit on the closest-approach distance ``D`` of the two rays (Eq 40),
        millimetres. None: from the pixels' footprints, ``tolerance_scale *
        sqrt(p1**2 + p2**2)`` with ``p`` each camera's ``pixel_pitch``
        (``docs/stereo-matching.md``, "Tolerances").
    max_normal_gap_deg : float or None
        Limit on the angle between ``n1(P1*)`` and ``n2(P2*)``, degrees
        (reflectance matching), the same for every pair. None: per pair, from
        each highlight's footprint in normal (the turn of the normal per
        pixel seen between neighbouring highlights, ``phi``, and the turn of
        the bisector itself across one pixel, ``f``):
        ``tolerance_scale * sqrt(phi1**2 + phi2**2 + f1**2 + f2**2)``
        (``docs/stereo-matching.md``, "Tolerances").
    tolerance_scale : float
        The one scale factor of the derived tolerances: how many footprints
        two highlights of one surface element may lie apart. 1.5: two
        elements one pixel apart whose centroids are each off by 0.4 pixel
        (the largest centroid error measured on rendered spheres) pass.
    depth_range_mm : (float, float) or None
        Working volume along world z: ``P*`` must have ``lo <= z <= hi``.
        None: no limit (then the index has only the epipolar coordinate and
        its output grows with the number of pairs on each epipolar line).
    max_delta_z_mm : float or None
        Limit on ``|delta_z|`` (Eq 43); None: not applied (it is zero where
        ``E1 = E2`` has a root on the arc; ``docs/stereo-matching.md``, "Reflectance
        matching").
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
        (umbilic) model instead of at the rays' crossing
        (``docs/stereo-matching.md``, "Refinement"); False: the paper's crossing ``P*`` and ``n*``.
    workers : int or None
        Threads for the per-pair and per-candidate work (the index's
        queries, the exact tests, the support weights, the relaxation's
        products, reflectance matching, the refinement).
        None: one per core this process may run on. The result does not
        depend on it: each pair or candidate is computed alone, in the same
        order of operations.
    """

    d0_mm: float | None = None
    max_normal_gap_deg: float | None = None
    tolerance_scale: float = TOLERANCE_SCALE
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
        positive = dict(lo=0.0, lo_open=True, optional=True)
        check_attributes(self, {**dict.fromkeys(("d0_mm", "max_delta_z_mm", "max_e_mm", "neighbourhood_mm",
                                                 "rise_tol_mm"), positive),
                                "max_normal_gap_deg": dict(lo=0.0, hi=90.0, optional=True),
                                "tolerance_scale": dict(lo=0.0, lo_open=True, hi=100.0)})
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
        check_attributes(self, {"iterations": dict(lo=0, hi=10000, integer=True), "tol": dict(lo=0.0),
                                "workers": dict(lo=1, hi=1024, integer=True, optional=True)})

    @property
    def threads(self) -> int:
        """The threads used: ``workers``, or one per core."""
        return self.workers if self.workers is not None else cores()


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
    # per ray: the turn of the normal per pixel seen between neighbouring highlights, and the bisector's own
    # turn per pixel of ray displacement (radians): the footprints the derived limits and the bound use
    phi: np.ndarray | None = None
    floor: np.ndarray | None = None
    convex: np.ndarray | None = None  # +1 convex, -1 concave, 0 not seen (no neighbours)


def _components(a, shared=False):
    if shared and len(a) and bool(np.all(a == a[0])):
        return tuple(float(v) for v in a[0])
    return tuple(np.ascontiguousarray(a[:, k]) for k in range(3))


def _side(rays: HighlightRays, rig: Rig, footprints: bool = False, workers: int = 1) -> _Side:
    cam = rig.cameras[rays.camera]
    S = rig.source_positions[rays.sources]
    side = _Side(rays.origins, rays.directions, S, rig.source_distant[rays.sources], cam.pixel_pitch, cam,
                 _components(rays.origins, shared=True), _components(rays.directions), _components(S))
    if footprints:
        side.phi, side.floor, side.convex = _normal_footprints(side, rays, rig, workers)
    return side


#: Neighbouring highlights (of other sources) whose normals give a highlight's normal turn per pixel.
NEIGHBOURS = 4


def _normal_footprints(side: _Side, rays: HighlightRays, rig: Rig, workers: int = 1):
    """Per highlight: the normal's turn per pixel of the surface seen (radians), that of the bisector alone,
    and the sign of the curvature (+1 convex: the normal turns the way the point moves; -1 concave; 0 unseen).

    The turn per pixel is the median, over the :data:`NEIGHBOURS` nearest highlights of other sources
    at least half a pixel away in the image, of the angle between the two highlights' normals (each the
    bisector at its ray's point level with the camera's target) over their distance in pixels: the
    surface's curvature as the image shows it, whatever the object. A highlight with no such neighbour
    takes the median of the others (0 where none has one: a flat mirror's few highlights)."""
    from scipy.spatial import cKDTree

    n = len(side.o)
    cam = side.camera
    if cam.projection == "perspective":
        t = float(np.linalg.norm(np.asarray(cam.target, float) - cam.position)) / np.maximum(side.d @ cam.forward,
                                                                                               1e-9)
    else:
        t = (np.asarray(cam.target, float) - side.o) @ cam.forward
    X = side.o + np.asarray(t, float).reshape(-1, 1) * side.d
    normal = _normal_at(side, np.arange(n), X)
    # one pixel of ray displacement turns the bisector by half the angle it subtends at the source and at
    # the camera: the floor where the surface does not turn the normal (a flat mirror)
    far = side.distant
    to_source = np.where(far, np.inf, np.linalg.norm(side.S - X, axis=1))
    to_camera = np.inf if cam.projection != "perspective" else np.linalg.norm(X - cam.position, axis=1)
    floor = 0.5 * side.pitch * (1.0 / to_source + 1.0 / to_camera)
    phi = np.full(n, np.nan)
    sign = np.zeros(n)
    if n > 1:
        pix = np.stack([rays.rows, rays.cols], 1)
        k = min(n, 2 * NEIGHBOURS + 1)
        d_px, nb = cKDTree(pix, balanced_tree=False, compact_nodes=False).query(pix, k=k, workers=workers)
        d_px, nb = d_px.reshape(n, k), np.minimum(nb.reshape(n, k), n - 1)  # a missing neighbour is refused below
        use = (d_px >= 0.5) & np.isfinite(d_px) & (rays.sources[nb] != rays.sources[:, None])
        if rays.usable is not None:
            use &= np.asarray(rays.usable, bool)[nb]
        # the first NEIGHBOURS usable neighbours of each highlight
        use &= np.cumsum(use, axis=1) <= NEIGHBOURS
        nbc = np.where(use, nb, 0)
        dn = normal[nbc] - normal[:, None, :]
        # the angle between unit normals from their chord; convex where the normal turns the way the point
        # moves (a sphere seen from outside)
        chord = np.sqrt(np.einsum("mki,mki->mk", dn, dn))
        turn = np.einsum("mki,mki->mk", dn, X[nbc] - X[:, None, :])
        with np.errstate(invalid="ignore", divide="ignore"):
            rate = 2.0 * np.arcsin(np.clip(0.5 * chord, 0.0, 1.0)) / d_px
        count = use.sum(axis=1)
        has = count > 0
        phi[has] = _row_median(np.where(use, rate, np.inf), count)[has]
        sign[has] = np.sign(_row_median(np.where(use, np.sign(turn) * rate, np.inf), count))[has]
    fill = float(np.nanmedian(phi)) if np.isfinite(phi).any() else 0.0
    return np.where(np.isfinite(phi), phi, fill), floor, sign


def _row_median(values, count):
    """Median of the first ``count[r]`` smallest entries of each row, the others +inf (no NaN handling)."""
    srt = np.sort(values, axis=1)
    r = np.arange(len(srt))
    lo, hi = np.maximum(count - 1, 0) // 2, np.maximum(count, 1) // 2
    return 0.5 * (srt[r, np.minimum(lo, srt.shape[1] - 1)] + srt[r, np.minimum(hi, srt.shape[1] - 1)])


def _take(comps, idx):
    return tuple(c if np.ndim(c) == 0 else c[idx] for c in comps)


def _normal_at(side: _Side, idx, P):
    """Normal that reflects ray ``idx``'s source into its camera at points ``P`` (bisector), (M, 3)."""
    return np.stack(_normal_at_c(side, idx, [P[:, k] for k in range(3)]), 1)


def _normal_at_c(side: _Side, idx, P):
    """:func:`_normal_at` on components (P and the result: three component arrays)."""
    S, d = _take(side.Sc, idx), _take(side.dc, idx)
    lv = _unit_c([S[k] - P[k] for k in range(3)])
    far = side.distant[idx]
    if far.any():
        lv = [np.where(far, S[k], lv[k]) for k in range(3)]
    return _unit_c([lv[k] - d[k] for k in range(3)])
