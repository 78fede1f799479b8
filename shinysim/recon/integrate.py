r"""Heights from surface normals: one family of integrators behind :func:`integrate`.

:func:`integrate` dispatches over :data:`INTEGRATE_METHODS`: heights on the
sparse points' Delaunay triangulation (:func:`integrate_triangulated`, the
circular-arc rise along every edge), the grid integrators (Poisson,
Frankot-Chellappa, robust) on resampled gradients (:func:`grid_gradients`),
the paper's profile rule (:mod:`shinysim.recon.profile`) and the thin-plate
grid (:mod:`shinysim.recon.surface`). The arc rule is
:func:`shinysim.recon.profile.arc_rise` (:func:`edge_rise` along an edge);
:func:`solve_heights` is the one least-squares solve of the graph and grid
methods and of the near-field model. :func:`compare_integrators` runs them
on the same normals against a known height function. How each works, its
limits and its references: ``docs/integration.md``.

Frames, units and gradient conventions are those of
:mod:`shinysim.conventions` (millimetres, ``p = dz/dx``, ``q = dz/dy``,
``n ~ (-p, -q, 1)``); grids are ``(H, W)`` arrays, rows along ``y``,
columns along ``x``. numpy and scipy only.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy import sparse
from scipy.ndimage import binary_erosion, distance_transform_edt
from scipy.sparse import csgraph
from scipy.sparse.linalg import lsqr, spsolve
from scipy.spatial import Delaunay, QhullError, cKDTree

from .._shared import check_choice, check_number, with_overrides
from ..conventions import angle_between, gradient_from_normal, normal_from_gradient
from ..errors import OptionError
from .profile import _check_weights, arc_rise, profile_from_normals
from .surface import surface_from_normals

__all__ = [
    "INTEGRATE_METHODS",
    "integrate",
    "solve_heights",
    "RISE_RULES",
    "IntegrateParams",
    "Component",
    "SparseSurface",
    "GridSurface",
    "integrate_triangulated",
    "edge_rise",
    "grid_gradients",
    "integrate_poisson",
    "integrate_frankot_chellappa",
    "integrate_robust",
    "compare_integrators",
]

#: Rules for the height difference along an edge (``docs/integration.md``).
RISE_RULES = ("arc", "trapezoid")
_INVALID = ("drop", "raise")
_SOLVERS = ("direct", "lsqr")


@dataclass(frozen=True)
class IntegrateParams:
    """Settings of :func:`integrate_triangulated`.

    Parameters
    ----------
    rule : {"arc", "trapezoid"}
        Height difference along an edge. ``"arc"`` (default): the circular
        arc between the two normals, exact on spheres and planes, robust on
        steep slopes; ``"trapezoid"``: the mean gradient times the edge,
        exact on quadratic surfaces. See ``docs/integration.md`` and the tests.
    max_edge_factor : float
        An edge longer than this many times the local spacing of its ends
        (the larger of the two) is dropped as a gap. 3 keeps 99 % of the
        interior Delaunay edges of uniformly random points (their 99th
        percentile is 2.7 local spacings; the few longer ones cross chance
        holes) and drops every edge across a gap wider than three spacings
        on both sides, and about a third of the convex-hull edges (the
        long, skinny ones along the outline).
    spacing_neighbours : int
        The local spacing of a point is the median distance to this many
        nearest neighbours. 6 is the mean number of Delaunay neighbours in
        the plane, so the spacing measures the point's own triangles.
    max_edge_mm : float or None
        Also drop every edge longer than this, millimetres (None: no limit).
    max_angle_deg : float or None
        Also drop edges whose two normals differ by more than this, degrees
        (the paper's angle criterion for a discontinuity). None (default):
        no angle rule, because the arc rule is exact on spheres whatever the
        angle and irregular points on a steep cap have neighbours 20-30
        degrees apart; set it (e.g. 45) to cut at sharp creases.
    anchor_weight : float
        Weight of each anchor row relative to the median edge row. It only
        matters between conflicting anchors of one piece: one anchor per
        piece is met exactly whatever its weight.
    anchor_reach : float
        A point anchor must lie within this many local spacings of its
        nearest point (further, and it does not belong to the points).
    invalid : {"drop", "raise"}
        Rows with a non-finite position or normal, a normal pointing down
        (``nz <= 0``: no gradient) or zero weight are dropped and counted
        (``"drop"``, default: highlights lost to a grazing source are
        ordinary), or raise :class:`~shinysim.errors.OptionError`.
    solver : {"direct", "lsqr"}
        ``"direct"`` (default): the sparse normal equations factorised
        (SuperLU), to round-off; ``"lsqr"``: iterative least squares.
    """

    rule: str = "arc"
    max_edge_factor: float = 3.0
    spacing_neighbours: int = 6
    max_edge_mm: float | None = None
    max_angle_deg: float | None = None
    anchor_weight: float = 100.0
    anchor_reach: float = 3.0
    invalid: str = "drop"
    solver: str = "direct"

    def __post_init__(self):
        check_choice("rule", self.rule, RISE_RULES)
        check_number("max_edge_factor", self.max_edge_factor, lo=0, lo_open=True)
        check_number("spacing_neighbours", self.spacing_neighbours, lo=1, integer=True)
        if self.max_edge_mm is not None:
            check_number("max_edge_mm", self.max_edge_mm, lo=0, lo_open=True)
        if self.max_angle_deg is not None:
            check_number("max_angle_deg", self.max_angle_deg, lo=0, lo_open=True, hi=180)
        check_number("anchor_weight", self.anchor_weight, lo=0, lo_open=True)
        check_number("anchor_reach", self.anchor_reach, lo=0)
        check_choice("invalid", self.invalid, _INVALID)
        check_choice("solver", self.solver, _SOLVERS)


@dataclass(frozen=True)
class Component:
    """One connected piece of the edge graph.

    Attributes
    ----------
    points : (K,) int ndarray
        Indices into :attr:`SparseSurface.xy`.
    anchored_by : {"point", "mean", None}
        What fixes its height: point anchors, the mean-height anchor, or
        nothing (floating: heights NaN in ``z``).
    anchors : int
        Point anchors tied to it.
    """

    points: np.ndarray
    anchored_by: str | None
    anchors: int = 0

    @property
    def floating(self) -> bool:
        return self.anchored_by is None


@dataclass
class SparseSurface:
    """Heights at sparse points, from :func:`integrate_triangulated`.

    Attributes
    ----------
    xy : (N, 2) float, mm
        The points used (invalid rows dropped).
    z : (N,) float, mm
        Heights; NaN on floating components.
    normals : (N, 3) float
        The unit normals used.
    triangles : (T, 3) int
        Delaunay triangles all of whose edges were kept.
    edges : (E, 2) int
        Edges of the integration graph (``i < j``).
    residual_rms_mm : float
        RMS of the edge residuals ``z_j - z_i - rise_ij``, mm.
    components : list of Component
    labels : (N,) int
        Component of each point.
    z_relative : (N,) float, mm
        Heights with each component shifted to zero mean (the shape, known
        even where the offset is not).
    point_residual_mm : (N,) float
        RMS residual of the edges at each point (0 for an isolated point).
    edge_residual_mm : (E,) float
    anchor_residual_mm : (A,) float
        ``z`` minus the anchor's height, at each point anchor.
    index : (N,) int
        Row of each used point in the input arrays.
    dropped : dict
        Counts of input rows dropped, by reason (``nonfinite``,
        ``downward``, ``zero_weight``), and of Delaunay edges dropped
        (``long_edges``, ``angle_edges``).
    params : IntegrateParams
    """

    xy: np.ndarray
    z: np.ndarray
    normals: np.ndarray
    triangles: np.ndarray
    edges: np.ndarray
    residual_rms_mm: float
    components: list
    labels: np.ndarray
    z_relative: np.ndarray
    point_residual_mm: np.ndarray
    edge_residual_mm: np.ndarray
    anchor_residual_mm: np.ndarray
    index: np.ndarray
    dropped: dict
    params: IntegrateParams = field(default_factory=IntegrateParams)
    _tri: Delaunay | None = field(default=None, repr=False)
    _kept_simplex: np.ndarray | None = field(default=None, repr=False)

    @property
    def floating(self) -> list:
        """Components whose height offset is unknown."""
        return [c for c in self.components if c.floating]

    def heights_at(self, xy, *, relative=False, interpolation="linear"):
        """Heights at ``(..., 2)`` points, mm, interpolated on the kept triangles.

        NaN outside the convex hull, in triangles with a dropped edge and on
        floating components (``relative=True``: use :attr:`z_relative`,
        which is finite everywhere).

        ``interpolation``: ``"linear"`` (barycentric; each triangle a plane
        facet, whose chord lies a sag ``~ s^2 / 8R`` off a surface of
        curvature radius ``R`` between points ``s`` apart), or ``"normals"``:
        each vertex's height carried half way along its own tangent plane,
        ``sum_i b_i (z_i + g_i . (p - x_i) / 2)`` with ``g_i`` the gradient of
        its normal. Linear interpolation errs by ``+sum b_i d_i^T H d_i / 2``
        on a surface of Hessian ``H`` (``d_i = x_i - p``) and the tangent
        planes' average by the same amount negated, so the half-way blend is
        exact on every quadratic surface and keeps the vertex heights.
        """
        values = self.z_relative if relative else self.z
        check_choice("interpolation", interpolation, ("linear", "normals"))
        grads = None
        if interpolation == "normals":
            grads = -self.normals[:, :2] / self.normals[:, 2:3]
        return _interpolate(self._tri, self._kept_simplex, values, xy, gradients=grads)

    def height_map(self, grid_x, grid_y, *, relative=False, interpolation="linear"):
        """``(H, W)`` heights on the grid ``grid_x`` (W,) by ``grid_y`` (H,), mm (NaN outside)."""
        gx, gy = np.meshgrid(np.asarray(grid_x, float), np.asarray(grid_y, float))
        return self.heights_at(np.stack([gx, gy], axis=-1), relative=relative, interpolation=interpolation)


@dataclass
class GridSurface:
    """Heights on a grid from a grid integrator.

    Attributes
    ----------
    z : (H, W) float, mm
        NaN outside the nodes integrated.
    mask : (H, W) bool
        Nodes integrated.
    method : str
    residual_rms_mm : float
        RMS of the edge residuals (height difference minus predicted rise)
        over the grid edges, unweighted, mm.
    components : int
        Connected pieces of the mask (each zero-mean unless anchored).
    weights : (H, W - 1), (H - 1, W) float or None
        Final weights of the x and y edges (robust integrator only).
    iterations : int
    """

    z: np.ndarray
    mask: np.ndarray
    method: str
    residual_rms_mm: float = float("nan")
    components: int = 1
    weights: tuple | None = None
    iterations: int = 0


# ----------------------------------------------------------------------------------------------
# input checks


def _as_points(xy, normals, weights, invalid):
    xy = np.asarray(xy, dtype=float)
    normals = np.asarray(normals, dtype=float)
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise OptionError(f"must have shape (N, 2), got {xy.shape}", field="xy")
    if normals.shape != (len(xy), 3):
        raise OptionError(f"must have shape ({len(xy)}, 3) to match xy, got {normals.shape}", field="normals")
    w = _check_weights(weights, len(xy))
    bad_xy = ~np.all(np.isfinite(xy), axis=1)
    bad_n = ~np.all(np.isfinite(normals), axis=1)
    with np.errstate(invalid="ignore"):
        down = ~bad_n & (normals[:, 2] <= 0)
        zero_w = ~np.isfinite(w) | (w <= 0)
    if invalid == "raise":
        for mask, name, what in ((bad_xy, "xy", "is not finite"), (bad_n, "normals", "is not finite"),
                                 (down, "normals", "points down (nz <= 0): no gradient"),
                                 (zero_w, "weights", "is zero or not finite")):
            if np.any(mask):
                k = int(np.flatnonzero(mask)[0])
                raise OptionError(f"row {k} {what} ({int(mask.sum())} such rows)", field=name)
    keep = ~(bad_xy | bad_n | down | zero_w)
    dropped = {"nonfinite": int(np.sum(bad_xy | bad_n)), "downward": int(np.sum(down & ~bad_xy)),
               "zero_weight": int(np.sum(zero_w & ~(bad_xy | bad_n | down)))}
    index = np.flatnonzero(keep)
    n = normals[keep]
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    return xy[keep], n, w[keep], index, dropped


def _triangulate(xy):
    n = len(xy)
    if n < 3:
        raise OptionError(f"need at least 3 points with valid normals to triangulate, got {n}", field="xy")
    centred = xy - xy.mean(axis=0)
    sv = np.linalg.svd(centred, compute_uv=False)
    if sv[0] == 0 or sv[1] <= 1e-10 * sv[0]:
        raise OptionError(f"the {n} points are collinear (or coincide): they span no area to triangulate",
                          field="xy")
    try:
        return Delaunay(xy)
    except QhullError as exc:  # pragma: no cover - the rank test above catches the usual cases
        raise OptionError(f"cannot triangulate the points: {str(exc).splitlines()[0]}", field="xy") from None


def _delaunay_edges(tri):
    s = tri.simplices
    e = np.concatenate([s[:, [0, 1]], s[:, [1, 2]], s[:, [2, 0]]])
    e = np.sort(e, axis=1)
    edges = np.unique(e, axis=0)
    # points qhull left out (duplicates): tie each to its nearest vertex
    if len(tri.coplanar):
        extra = np.sort(tri.coplanar[:, [0, 2]], axis=1)
        edges = np.unique(np.vstack([edges, extra]), axis=0)
    return edges


def _local_spacing(xy, k):
    k = min(int(k), len(xy) - 1)
    d, _ = cKDTree(xy).query(xy, k=k + 1)
    d = np.asarray(d).reshape(len(xy), -1)[:, 1:]
    return np.median(d, axis=1)


# ----------------------------------------------------------------------------------------------
# the rise along an edge


def edge_rise(n_i, n_j, d, rule="arc"):
    """Height change from point i to point j predicted from their normals, mm.

    Parameters
    ----------
    n_i, n_j : (E, 3) array_like
        Unit normals at the two ends (``nz > 0``).
    d : (E, 2) array_like, mm
        Horizontal offsets ``xy_j - xy_i``.
    rule : {"arc", "trapezoid"}
        See ``docs/integration.md``: ``-L tan((phi_i + phi_j) / 2)`` (circular arc,
        exact on spheres) or ``(g_i + g_j) / 2 . d`` (exact on quadratics).

    Returns
    -------
    (E,) ndarray, mm
    """
    check_choice("rule", rule, RISE_RULES)
    n_i = np.atleast_2d(np.asarray(n_i, float))
    n_j = np.atleast_2d(np.asarray(n_j, float))
    d = np.atleast_2d(np.asarray(d, float))
    if rule == "trapezoid":
        p_i, q_i = gradient_from_normal(n_i)
        p_j, q_j = gradient_from_normal(n_j)
        return 0.5 * ((p_i + p_j) * d[:, 0] + (q_i + q_j) * d[:, 1])
    length = np.linalg.norm(d, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.where(length[:, None] > 0, d / length[:, None], 0.0)
    # slope angles along the edge of the normals' projections onto its vertical plane
    return arc_rise(length, np.arctan2(-np.sum(n_i[:, :2] * u, axis=1), n_i[:, 2]),
                    np.arctan2(-np.sum(n_j[:, :2] * u, axis=1), n_j[:, 2]))


# ----------------------------------------------------------------------------------------------
# interpolation on a triangulation


def _interpolate(tri, kept, values, xy, gradients=None):
    """Barycentric interpolation of per-vertex ``values`` on the kept simplices.

    With ``gradients`` (N, 2), each vertex contributes its value moved half
    way along its tangent plane to the point (exact on quadratic surfaces;
    :meth:`SparseSurface.heights_at`).
    """
    xy = np.asarray(xy, dtype=float)
    shape = xy.shape[:-1]
    pts = xy.reshape(-1, 2)
    out = np.full(len(pts), np.nan)
    ok = np.all(np.isfinite(pts), axis=1)
    if tri is None or not np.any(ok):
        return out.reshape(shape)
    s = np.full(len(pts), -1)
    s[ok] = tri.find_simplex(pts[ok])
    inside = s >= 0
    if kept is not None:
        inside[inside] = kept[s[inside]]
    idx = np.flatnonzero(inside)
    if len(idx):
        T = tri.transform[s[idx]]
        b2 = np.einsum("nij,nj->ni", T[:, :2, :], pts[idx] - T[:, 2, :])
        bary = np.column_stack([b2, 1.0 - b2.sum(axis=1)])
        verts = tri.simplices[s[idx]]
        v = values[verts]
        if gradients is not None:
            d = pts[idx][:, None, :] - tri.points[verts]
            v = v + 0.5 * np.einsum("nkj,nkj->nk", gradients[verts], d)
        out[idx] = np.sum(bary * v, axis=1)
    return out.reshape(shape)


# ----------------------------------------------------------------------------------------------
# the sparse solve


def _parse_anchors(anchors):
    """(A, 3) point anchors and the mean height (or None) from the ``anchors`` argument."""
    points = np.zeros((0, 3))
    mean = None
    if anchors is None:
        return points, mean
    if isinstance(anchors, dict):
        unknown = set(anchors) - {"points", "mean"}
        if unknown:
            raise OptionError(f"unknown key(s) {sorted(unknown)}; keys are 'points', 'mean'", field="anchors")
        pts, mean = anchors.get("points"), anchors.get("mean")
    elif np.ndim(anchors) == 0:
        pts, mean = None, anchors
    else:
        pts = anchors
    if mean is not None:
        mean = check_number("anchors mean height", mean)
    if pts is not None:
        points = np.asarray(pts, dtype=float)
        if points.ndim == 1 and points.size == 3:
            points = points[None]
        if points.ndim != 2 or points.shape[1] != 3:
            raise OptionError(f"point anchors must have shape (A, 3): x, y, z in mm; got {points.shape}",
                              field="anchors")
        if not np.all(np.isfinite(points)):
            raise OptionError("point anchors must be finite", field="anchors")
    return points, mean


def solve_heights(n_points, edges, rise, edge_weight, tie_index=(), tie_z=(), tie_weight=(), *,
                  solver="direct"):
    """Least-squares heights at points from height differences along edges and ties to known heights.

    The solve behind every graph and grid integrator of the family (and the
    near-field model's): it minimises ::

        sum_e (w_e (z_j - z_i - rise_e))**2 + sum_t (v_t (z_{k_t} - z_t))**2

    Parameters
    ----------
    n_points : int
    edges : (E, 2) int array_like
        ``(i, j)`` of each edge.
    rise : (E,) array_like, mm
        Predicted ``z_j - z_i`` (:func:`edge_rise`).
    edge_weight : (E,) array_like
        Row weights ``w_e``.
    tie_index, tie_z, tie_weight : (T,) array_like
        Point ``k_t`` tied to height ``z_t`` (mm) with row weight ``v_t``.
    solver : {"direct", "lsqr", "dense"}
        ``"direct"``: the sparse normal equations factorised (SuperLU), to
        round-off; ``"lsqr"``: iterative least squares (tolerance 1e-14);
        ``"dense"``: orthogonal factorisation of the dense matrix
        (``numpy.linalg.lstsq``, to round-off without squaring the condition
        number; its cost grows as the cube of the points).

    Returns
    -------
    (n_points,) ndarray, mm
    """
    check_choice("solver", solver, _SOLVERS + ("dense",))
    edges = np.asarray(edges, int).reshape(-1, 2)
    edge_weight = np.asarray(edge_weight, float)
    tie_weight = np.asarray(tie_weight, float)
    m, t = len(edges), len(tie_weight)
    r_idx = np.concatenate([np.arange(m), np.arange(m), m + np.arange(t)])
    c_idx = np.concatenate([edges[:, 1], edges[:, 0], np.asarray(tie_index, int)]).astype(int)
    A = sparse.csr_matrix((np.concatenate([edge_weight, -edge_weight, tie_weight]), (r_idx, c_idx)),
                          shape=(m + t, n_points))
    b = np.concatenate([edge_weight * np.asarray(rise, float), tie_weight * np.asarray(tie_z, float)])
    if solver == "dense":
        return np.linalg.lstsq(A.toarray(), b, rcond=None)[0]
    if solver == "lsqr":
        return lsqr(A, b, atol=1e-14, btol=1e-14, iter_lim=20 * A.shape[1] + 100)[0]
    return np.asarray(spsolve((A.T @ A).tocsc(), A.T @ b), float)


def _pinned_solve(n, edges, rise, row_w, labels, n_comp, tie_index, tie_z, anchor_weight, solver="direct"):
    """:func:`solve_heights` with the points ``tie_index`` tied to ``tie_z`` at ``anchor_weight`` times the median
    row weight and, as gauge, the first point of every component (``labels``) without a tie pinned at 0 with
    the median row weight."""
    ref = float(np.median(row_w)) if len(row_w) else 1.0
    tied = np.zeros(n_comp, bool)
    tied[labels[np.asarray(tie_index, int)]] = True
    pins = [int(np.flatnonzero(labels == c)[0]) for c in range(n_comp) if not tied[c]]
    return np.asarray(solve_heights(n, edges, rise, row_w, list(tie_index) + pins, list(tie_z) + [0.0] * len(pins),
                                    np.concatenate([np.full(len(tie_index), anchor_weight * ref),
                                                    np.full(len(pins), ref)]), solver=solver), float)


def integrate_triangulated(xy, normals, *, anchors=None, weights=None, params=None, **overrides) -> SparseSurface:
    """Heights at sparse, irregular points from their normals, by least squares on a triangulation.

    Parameters
    ----------
    xy : (N, 2) array_like, mm
        Positions of the normals (world x, y).
    normals : (N, 3) array_like
        Surface normals (need not be unit length).
    anchors : None, float, (A, 3) array_like or dict
        ``(x, y, z)`` rows, mm: points of known height. Each is tied to its
        nearest point ``i`` (within ``anchor_reach`` local spacings) by
        ``z_i = z + g_i . (xy_i - (x, y))``: exact when the anchor is at a
        point or the surface is a plane there. A number: the mean height of
        every component without a point anchor (a pure offset, it changes no
        shape). A dict ``{"points": ..., "mean": ...}``: both.
    weights : (N,) array_like, optional
        Confidence of each normal (e.g. highlight brightness); an edge gets
        the harmonic mean of its ends'. Zero drops the point.
    params : IntegrateParams, optional
        Keyword arguments override single fields.

    Returns
    -------
    SparseSurface

    Raises
    ------
    OptionError
        Shapes that do not match (field ``xy``, ``normals``, ``weights``),
        fewer than 3 valid points or collinear points (``xy``), a malformed
        or far anchor (``anchors``), invalid rows under ``invalid="raise"``.
    """
    params = with_overrides(IntegrateParams, params, overrides)
    xy, n, w, index, dropped = _as_points(xy, normals, weights, params.invalid)
    tri = _triangulate(xy)
    N = len(xy)
    edges = _delaunay_edges(tri)
    i, j = edges[:, 0], edges[:, 1]
    d = xy[j] - xy[i]
    length = np.linalg.norm(d, axis=1)
    spacing = _local_spacing(xy, params.spacing_neighbours)
    limit = params.max_edge_factor * np.maximum(spacing[i], spacing[j])
    if params.max_edge_mm is not None:
        limit = np.minimum(limit, params.max_edge_mm)
    long_edge = length > limit
    angle_edge = np.zeros(len(edges), bool)
    if params.max_angle_deg is not None:
        angle_edge = np.degrees(angle_between(n[i], n[j])) > params.max_angle_deg
    keep = ~(long_edge | angle_edge)
    dropped = dict(dropped, long_edges=int(np.sum(long_edge)), angle_edges=int(np.sum(angle_edge & ~long_edge)))
    edges, d, length = edges[keep], d[keep], length[keep]
    i, j = edges[:, 0], edges[:, 1]
    # a triangle is kept when its three edges are (each edge as the number i * N + j, i < j)
    key = i * N + j
    s = np.sort(tri.simplices, axis=1)
    kept_simplex = np.all([np.isin(s[:, a] * N + s[:, b], key) for a, b in ((0, 1), (1, 2), (0, 2))], axis=0)

    rise = edge_rise(n[i], n[j], d, params.rule)
    floor = 1e-3 * (np.median(length) if len(length) else 1.0)
    w_edge = 2.0 / (1.0 / w[i] + 1.0 / w[j])
    row_w = np.sqrt(w_edge) / np.maximum(length, floor)

    # components of the kept graph
    adj = sparse.coo_matrix((np.ones(len(edges)), (i, j)), shape=(N, N))
    n_comp, labels = csgraph.connected_components(adj, directed=False)

    anchor_pts, mean_height = _parse_anchors(anchors)
    a_idx, a_z = np.zeros(0, int), np.zeros(0)
    if len(anchor_pts):
        dist, a_idx = cKDTree(xy).query(anchor_pts[:, :2])
        reach = params.anchor_reach * spacing[a_idx]
        far = np.flatnonzero(dist > reach)
        if len(far):
            k, a = int(far[0]), anchor_pts[far[0]]
            raise OptionError(f"anchor {k} at ({a[0]:g}, {a[1]:g}) mm is {dist[k]:.4g} mm from the nearest point, "
                              f"more than anchor_reach x local spacing = {reach[k]:.4g} mm", field="anchors")
        p_a, q_a = gradient_from_normal(n[a_idx])
        off = xy[a_idx] - anchor_pts[:, :2]
        a_z = anchor_pts[:, 2] + p_a * off[:, 0] + q_a * off[:, 1]
    anchored_comp = np.bincount(labels[a_idx], minlength=n_comp)
    z = _pinned_solve(N, edges, rise, row_w, labels, n_comp, a_idx, a_z, params.anchor_weight, params.solver)

    z_rel = z.copy()
    components = []
    for c in range(n_comp):
        members = np.flatnonzero(labels == c)
        offset = z[members].mean()
        z_rel[members] -= offset
        if anchored_comp[c]:
            by = "point"
        elif mean_height is not None:
            by = "mean"
            z[members] = z_rel[members] + mean_height
        else:
            by = None
            z[members] = np.nan
        components.append(Component(members, by, int(anchored_comp[c])))

    res = (z_rel[j] - z_rel[i]) - rise
    sq = np.bincount(i, res**2, N) + np.bincount(j, res**2, N)
    cnt = np.bincount(i, minlength=N) + np.bincount(j, minlength=N)
    with np.errstate(invalid="ignore", divide="ignore"):
        point_res = np.where(cnt > 0, np.sqrt(sq / np.maximum(cnt, 1)), 0.0)
    anchor_res = z[a_idx] - a_z
    return SparseSurface(
        xy=xy, z=z, normals=n, triangles=tri.simplices[kept_simplex], edges=edges,
        residual_rms_mm=_rms(res, 0.0),
        components=components, labels=labels, z_relative=z_rel, point_residual_mm=point_res,
        edge_residual_mm=res, anchor_residual_mm=anchor_res, index=index, dropped=dropped, params=params,
        _tri=tri, _kept_simplex=kept_simplex,
    )


# ----------------------------------------------------------------------------------------------
# grids


def grid_gradients(xy, normals, grid_x, grid_y, *, mask=None, drop_gaps=None):
    """Scattered gradients resampled to a grid by linear interpolation.

    Parameters
    ----------
    xy : (N, 2) array_like, mm
    normals : (N, 3) array_like
        Rows with no gradient (NaN, ``nz <= 0``) are left out.
    grid_x : (W,) array_like, mm
    grid_y : (H,) array_like, mm
    mask : (H, W) bool array_like, optional
        Nodes wanted; NaN elsewhere.
    drop_gaps : IntegrateParams, optional
        Also NaN in the triangles :func:`integrate_triangulated` would drop
        with these settings (edges across gaps); default: every Delaunay
        triangle is used, as ``scipy.interpolate.griddata(..., "linear")``.

    Returns
    -------
    p, q : (H, W) ndarray
        ``dz/dx``, ``dz/dy``; NaN outside the convex hull of the points.
    """
    xy, n, _, _, _ = _as_points(xy, normals, None, "drop")
    tri = _triangulate(xy)
    kept = None
    if drop_gaps is not None:
        surf = integrate_triangulated(xy, n, params=drop_gaps)
        kept = surf._kept_simplex
    p, q = gradient_from_normal(n)
    gx, gy = np.meshgrid(np.asarray(grid_x, float), np.asarray(grid_y, float))
    pts = np.stack([gx, gy], axis=-1)
    P = _interpolate(tri, kept, p, pts)
    Q = _interpolate(tri, kept, q, pts)
    if mask is not None:
        mask = np.asarray(mask, bool)
        if mask.shape != P.shape:
            raise OptionError(f"must have shape {P.shape} (len(grid_y), len(grid_x)), got {mask.shape}", field="mask")
        P = np.where(mask, P, np.nan)
        Q = np.where(mask, Q, np.nan)
    return P, Q


def _steps(step_mm):
    s = np.atleast_1d(np.asarray(step_mm, dtype=float))
    if s.size == 1:
        s = np.array([s[0], s[0]])
    if s.size != 2 or not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise OptionError(f"must be a positive number or (dx, dy), got {step_mm!r}", field="step_mm")
    return float(s[0]), float(s[1])


def _rms(values, empty):
    """Root mean square of ``values``; ``empty`` when there are none."""
    return float(np.sqrt(np.mean(values**2))) if len(values) else empty


def _check_grid(p, q, mask):
    p = np.asarray(p, dtype=float)
    q = np.asarray(q, dtype=float)
    if p.ndim != 2 or q.shape != p.shape:
        raise OptionError(f"p and q must be 2-D arrays of one shape, got {p.shape} and {q.shape}", field="q")
    valid = np.isfinite(p) & np.isfinite(q)
    if mask is not None:
        mask = np.asarray(mask, bool)
        if mask.shape != p.shape:
            raise OptionError(f"must have the shape of p, {p.shape}, got {mask.shape}", field="mask")
        valid &= mask
    return p, q, valid


class _GridSystem:
    """Edges of a masked grid, their predicted rises and the difference operator."""

    def __init__(self, p, q, valid, dx, dy):
        H, W = valid.shape
        self.shape = (H, W)
        self.valid = valid
        idx = np.full((H, W), -1)
        idx[valid] = np.arange(int(valid.sum()))
        self.idx = idx
        self.n = int(valid.sum())
        hx = valid[:, :-1] & valid[:, 1:]
        hy = valid[:-1, :] & valid[1:, :]
        rx, cx = np.nonzero(hx)
        ry, cy = np.nonzero(hy)
        self.i = np.concatenate([idx[rx, cx], idx[ry, cy]])
        self.j = np.concatenate([idx[rx, cx + 1], idx[ry + 1, cy]])
        self.rise = np.concatenate([0.5 * dx * (p[rx, cx] + p[rx, cx + 1]), 0.5 * dy * (q[ry, cy] + q[ry + 1, cy])])
        self.length = np.concatenate([np.full(len(rx), dx), np.full(len(ry), dy)])
        self.nx = len(rx)
        self.rx, self.cx, self.ry, self.cy = rx, cx, ry, cy
        m = len(self.i)
        adj = sparse.coo_matrix((np.ones(m), (self.i, self.j)), shape=(self.n, self.n))
        self.n_comp, self.labels = csgraph.connected_components(adj, directed=False)

    def solve(self, edge_w, anchors=None):
        """Weighted least squares; each component zero-mean unless anchored."""
        rows, rhs = [], []
        for r, c, zval in anchors if anchors is not None else ():
            k = self.idx[int(round(r)), int(round(c))]
            if k < 0:
                raise OptionError(f"anchor at node ({r:g}, {c:g}) is outside the mask", field="anchors")
            rows.append(k)
            rhs.append(zval)
        z = _pinned_solve(self.n, np.column_stack([self.i, self.j]), self.rise, np.sqrt(edge_w) / self.length,
                          self.labels, self.n_comp, rows, rhs, 100)
        anchored = np.zeros(self.n_comp, bool)
        anchored[self.labels[np.asarray(rows, int)]] = True
        for c in range(self.n_comp):
            if not anchored[c]:
                members = self.labels == c
                z[members] -= z[members].mean()
        return z

    @classmethod
    def of(cls, p, q, mask, step_mm):
        """The system of the gradients ``p``, ``q`` on ``mask`` (checked) at the grid step ``step_mm``."""
        return cls(*_check_grid(p, q, mask), *_steps(step_mm))

    def surface(self, z, method, weights=None, iterations=1):
        """The :class:`GridSurface` of the heights ``z`` at the system's nodes."""
        return GridSurface(self.to_grid(z), self.valid, method, _rms(self.residual(z), 0.0), self.n_comp, weights,
                           iterations)

    def residual(self, z):
        return z[self.j] - z[self.i] - self.rise

    def to_grid(self, z):
        out = np.full(self.shape, np.nan)
        out[self.valid] = z
        return out

    def split(self, values):
        """Per-edge values as (H, W-1) and (H-1, W) arrays (NaN where no edge)."""
        H, W = self.shape
        ex = np.full((H, W - 1), np.nan)
        ey = np.full((H - 1, W), np.nan)
        ex[self.rx, self.cx] = values[: self.nx]
        ey[self.ry, self.cy] = values[self.nx:]
        return ex, ey

    def curl(self):
        """Loop sum of the predicted rises around each grid cell, mm ((H-1, W-1); NaN where a side is missing)."""
        ex, ey = self.split(self.rise)
        # bottom (+x at row r) + right (+y at col c+1) - top (+x at row r+1) - left (+y at col c)
        return ex[:-1, :] + ey[:, 1:] - ex[1:, :] - ey[:, :-1]


def _grid_anchors(anchors):
    if anchors is None:
        return None
    a = np.asarray(anchors, dtype=float)
    if a.ndim == 1 and a.size == 3:
        a = a[None]
    if a.ndim != 2 or a.shape[1] != 3 or not np.all(np.isfinite(a)):
        raise OptionError(f"must be (A, 3) finite rows of (row, col, z mm), got shape {a.shape}", field="anchors")
    return a


def integrate_poisson(p, q, mask=None, *, step_mm, anchors=None) -> GridSurface:
    """Least-squares (Poisson) integration of a gradient field on a masked grid.

    Minimises, over the grid edges between valid nodes, the squared
    difference between the height step and the trapezoid rise
    ``(g_a + g_b) / 2 * step``. Its normal equations are the discrete
    Poisson equation ``laplacian(z) = div(p, q)`` with natural (Neumann)
    boundary conditions at the border of the mask (Harker & O'Leary 2008;
    Quéau, Durou & Aujol 2018). Solved by a sparse direct factorisation.

    Parameters
    ----------
    p, q : (H, W) array_like
        ``dz/dx`` (along columns) and ``dz/dy`` (along rows); NaN: no data.
    mask : (H, W) bool array_like, optional
        Nodes to integrate (default: where p and q are finite).
    step_mm : float or (float, float)
        Grid spacing ``dx`` (or ``(dx, dy)``), mm.
    anchors : (A, 3) array_like, optional
        ``(row, col, z)``: known heights, mm, at grid nodes. A connected
        piece of the mask without one is shifted to zero mean.

    Returns
    -------
    GridSurface
    """
    sys_ = _GridSystem.of(p, q, mask, step_mm)
    return sys_.surface(sys_.solve(np.ones(len(sys_.i)), _grid_anchors(anchors)) if sys_.n else np.zeros(0),
                        "poisson")


def integrate_robust(p, q, mask=None, *, step_mm, anchors=None, iterations=20, scale=None) -> GridSurface:
    """Discontinuity-preserving integration: iteratively reweighted least squares.

    The weights start from the local integrability residual and are then
    refined by a Cauchy (Lorentzian) M-estimator on the edge residuals
    (Agrawal, Raskar & Chellappa 2006; Durou, Aujol & Courteille 2009;
    Quéau, Durou & Aujol 2018):

    1. the curl of each grid cell, ``c`` = the loop sum of the predicted
       rises around it (mm, zero for an integrable field), gives each edge
       the weight ``1 / (1 + (c_max / s)**2)``, ``c_max`` the larger curl of
       the two cells beside it;
    2. solve the weighted least squares; each edge's residual ``r`` (height
       step minus predicted rise) gives the new weight ``1 / (1 + (r /
       s)**2)``; repeat.

    Where the slopes are consistent (a smooth surface) the weights stay
    near 1 and the result is the Poisson one; edges across a step, whose
    interpolated slopes do not integrate consistently, are down-weighted,
    and the error is not spread over the rest of the surface.

    Parameters
    ----------
    p, q, mask, step_mm, anchors
        As :func:`integrate_poisson`.
    iterations : int
        Most reweighting steps after the curl-weighted solve (it stops
        earlier once no height moves by more than ``scale / 1000``).
    scale : float, optional
        The scale ``s``, mm. Default: ``0.05 * step``, a slope error of
        0.05 (about 3 degrees) over one grid step. Residuals much larger
        than this count as outliers.

    Returns
    -------
    GridSurface
        With the final weights (``weights``) of the x and y edges.
    """
    check_number("iterations", iterations, lo=0, integer=True)
    dx, dy = _steps(step_mm)
    s = 0.05 * min(dx, dy) if scale is None else check_number("scale", scale, lo=0, lo_open=True)
    sys_ = _GridSystem.of(p, q, mask, (dx, dy))
    if sys_.n == 0:
        return sys_.surface(np.zeros(0), "robust", iterations=0)
    anchors = _grid_anchors(anchors)
    c = np.nan_to_num(np.abs(sys_.curl()), nan=0.0)
    H, W = sys_.shape
    cx = np.zeros((H, W - 1))
    cx[:-1, :] = c
    cx[1:, :] = np.maximum(cx[1:, :], c)
    cy = np.zeros((H - 1, W))
    cy[:, :-1] = c
    cy[:, 1:] = np.maximum(cy[:, 1:], c)
    c_edge = np.concatenate([cx[sys_.rx, sys_.cx], cy[sys_.ry, sys_.cy]])
    w = 1.0 / (1.0 + (c_edge / s) ** 2)
    z = sys_.solve(w, anchors)
    done = 0
    for _ in range(int(iterations)):
        r = sys_.residual(z)
        w_new = 1.0 / (1.0 + (r / s) ** 2)
        z_new = sys_.solve(w_new, anchors)
        done += 1
        change = float(np.max(np.abs(z_new - z)))
        z, w = z_new, w_new
        if change < 1e-3 * s:  # converged: no height moved by a thousandth of the scale
            break
    return sys_.surface(z, "robust", sys_.split(w), done + 1)


def integrate_frankot_chellappa(p, q, *, step_mm, mask=None, fill="zero", pad="periodic") -> GridSurface:
    """Frankot & Chellappa (1988): the integrable surface nearest a gradient field, by FFT.

    With ``P, Q`` the Fourier transforms of ``p, q`` and ``(u, v)`` the
    angular frequencies (rad/mm) along x and y, the surface is ``Z = -i (u
    P + v Q) / (u**2 + v**2)``, ``Z(0, 0) = 0`` (zero mean): the least-squares
    projection of ``(p, q)`` onto the gradients of the Fourier basis
    (Frankot & Chellappa 1988, IEEE PAMI 10(4):439-451).

    Limitation: the FFT takes the field as periodic, so the surface's
    opposite borders are joined. A surface whose heights or slopes differ
    at opposite borders (a tilted plane, a bump cut by the border) gets
    errors spread from the borders inwards; it is exact in the spectral
    sense only for fields that vanish smoothly at the border (a bump well
    inside the grid). ``pad="reflect"`` integrates the mirror (even)
    extension instead (2H x 2W; ``p`` changes sign on the x mirror, ``q`` on
    the y mirror), which joins the borders continuously (Simchony,
    Chellappa & Shao 1990: a cosine-transform, Neumann, solution).

    Parameters
    ----------
    p, q : (H, W) array_like
        ``dz/dx``, ``dz/dy``. NaN or masked nodes are filled first.
    step_mm : float or (float, float)
        Grid spacing ``dx`` (or ``(dx, dy)``), mm.
    mask : (H, W) bool array_like, optional
        Nodes with data (default: where p and q are finite).
    fill : {"zero", "poisson"}
        Slopes used outside the mask: ``"zero"``, the surface continued
        flat; ``"poisson"``, the masked Poisson solution continued to the
        nearest node outside, whose slopes are then integrable across the
        mask's border.
    pad : {"periodic", "reflect"}

    Returns
    -------
    GridSurface
        ``z`` zero-mean over the mask, NaN outside it.
    """
    check_choice("fill", fill, ("zero", "poisson"))
    check_choice("pad", pad, ("periodic", "reflect"))
    dx, dy = _steps(step_mm)
    p, q, valid = _check_grid(p, q, mask)
    if fill == "poisson" and not np.all(valid) and np.any(valid):
        zp = integrate_poisson(p, q, valid, step_mm=(dx, dy)).z
        _, (ri, ci) = distance_transform_edt(~valid, return_indices=True)
        ze = zp[ri, ci]
        gy, gx = np.gradient(ze, dy, dx)
        pf = np.where(valid, p, gx)
        qf = np.where(valid, q, gy)
    else:
        pf = np.where(valid, p, 0.0)
        qf = np.where(valid, q, 0.0)
    H, W = pf.shape
    if pad == "reflect":
        pf = np.block([[pf, -pf[:, ::-1]], [pf[::-1, :], -pf[::-1, ::-1]]])
        qf = np.block([[qf, qf[:, ::-1]], [-qf[::-1, :], -qf[::-1, ::-1]]])
    h, w = pf.shape
    u = 2 * np.pi * np.fft.fftfreq(w, dx)[None, :]
    v = 2 * np.pi * np.fft.fftfreq(h, dy)[:, None]
    P = np.fft.fft2(pf)
    Q = np.fft.fft2(qf)
    den = u**2 + v**2
    den[0, 0] = 1.0
    Z = -1j * (u * P + v * Q) / den
    Z[0, 0] = 0.0
    # the Nyquist rows/columns of an even size carry no usable derivative
    if w % 2 == 0:
        Z[:, w // 2] = 0.0
    if h % 2 == 0:
        Z[h // 2, :] = 0.0
    z = np.real(np.fft.ifft2(Z))[:H, :W]
    if np.any(valid):
        z = z - z[valid].mean()
    return _GridSystem(p, q, valid, dx, dy).surface(z[valid], "frankot-chellappa")


# ----------------------------------------------------------------------------------------------
# the family: one entry point over every method


def _thin_plate(xy, normals, **options):
    xy = np.asarray(xy, dtype=float)
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise OptionError(f"the thin-plate method takes (N, 2) points, got shape {xy.shape}", field="points_or_grid")
    return surface_from_normals(xy[:, 0], xy[:, 1], normals, **options)


def _on_grid(solver):
    """A grid integrator of ``(p, q)`` as a method of (grid step, (H, W, 3) normals)."""

    def method(step_mm, normals, **options):
        n = np.asarray(normals, dtype=float)
        if n.ndim != 3 or n.shape[2] != 3:
            raise OptionError(f"a grid method takes (H, W, 3) normals, got shape {n.shape}", field="normals")
        return solver(*gradient_from_normal(n), step_mm=step_mm, **options)

    method.__doc__ = f"{solver.__name__} on the gradients of (H, W, 3) normals; ``points_or_grid`` the step."
    return method


#: The height-from-normals methods of :func:`integrate`: name -> function of
#: ``(points_or_grid, normals, **options)``.
INTEGRATE_METHODS = {
    "triangulated": integrate_triangulated,
    "poisson": _on_grid(integrate_poisson),
    "frankot-chellappa": _on_grid(integrate_frankot_chellappa),
    "robust": _on_grid(integrate_robust),
    "profile": profile_from_normals,
    "thin-plate": _thin_plate,
}


def integrate(points_or_grid, normals, method="triangulated", **options):
    """Heights from surface normals, by one of :data:`INTEGRATE_METHODS`.

    ``"triangulated"`` (default)
        ``(N, 2)`` points, mm, and ``(N, 3)`` normals: :func:`integrate_triangulated`
        (the arc rule along the Delaunay edges), a :class:`SparseSurface`.
    ``"poisson"``, ``"frankot-chellappa"``, ``"robust"``
        The grid step, mm (``dx`` or ``(dx, dy)``), and ``(H, W, 3)`` normals
        (``nz <= 0`` or NaN: no data), rows along ``y``, columns along ``x``:
        :func:`integrate_poisson`, :func:`integrate_frankot_chellappa`,
        :func:`integrate_robust` on their gradients, a :class:`GridSurface`.
    ``"profile"``
        ``(N,)`` positions along one cross-section and ``(N, 3)`` normals: the
        paper's rule, :func:`~shinysim.recon.profile.profile_from_normals`, a
        :class:`~shinysim.recon.profile.Profile`.
    ``"thin-plate"``
        ``(N, 2)`` points and ``(N, 3)`` normals: slopes, a thin-plate term and
        anchors on a grid, :func:`~shinysim.recon.surface.surface_from_normals`,
        a :class:`~shinysim.recon.surface.Surface`.

    ``options`` go to the method's function (anchors, masks, settings).

    Raises
    ------
    OptionError
        An unknown ``method`` (the message lists the valid ones), or input
        the method refuses.

    Examples
    --------
    The plane ``z = 0.5 + 0.1 x - 0.2 y`` from its normals at scattered
    points, anchored at one point of it:

    >>> import numpy as np
    >>> from shinysim.conventions import normal_from_gradient
    >>> xy = np.random.default_rng(0).uniform(-1, 1, (40, 2))
    >>> n = normal_from_gradient(np.full(40, 0.1), np.full(40, -0.2))
    >>> s = integrate(xy, n, anchors=[[xy[0, 0], xy[0, 1], 0.5 + 0.1 * xy[0, 0] - 0.2 * xy[0, 1]]])
    >>> bool(np.allclose(s.z, 0.5 + 0.1 * xy[:, 0] - 0.2 * xy[:, 1], atol=1e-12))
    True

    The same normals on a 4 x 5 grid of 0.1 mm: each step along x rises by 0.01 mm.

    >>> g = integrate(0.1, np.broadcast_to(n[0], (4, 5, 3)), method="poisson")
    >>> np.round(np.diff(g.z[0]), 12).tolist()
    [0.01, 0.01, 0.01, 0.01]
    """
    check_choice("method", method, tuple(INTEGRATE_METHODS))
    return INTEGRATE_METHODS[method](points_or_grid, normals, **options)


# ----------------------------------------------------------------------------------------------
# comparison


def _truth_normals(truth_fn, x, y, h):
    zx = (truth_fn(x + h, y) - truth_fn(x - h, y)) / (2 * h)
    zy = (truth_fn(x, y + h) - truth_fn(x, y - h)) / (2 * h)
    return normal_from_gradient(zx, zy)


def _grid_normals(z, dx, dy):
    gy, gx = np.gradient(z, dy, dx)
    return normal_from_gradient(gx, gy)


def compare_integrators(xy, normals, truth_fn, *, grid_step_mm=None, scale_mm=None, anchors=None,
                        params=None, methods=None, remove_offset=True, max_nodes=250_000) -> dict:
    """Run the sparse and the grid integrators on the same normals and score them against a truth.

    Parameters
    ----------
    xy : (N, 2) array_like, mm
    normals : (N, 3) array_like
    truth_fn : callable
        ``truth_fn(x, y) -> z``, mm, vectorised over arrays; NaN where the
        truth is unknown (such grid nodes are not scored).
    grid_step_mm : float, optional
        Grid spacing for the grid methods and for scoring (default: half the
        median kept edge length of the triangulation).
    scale_mm : float, optional
        Scale for the relative error (e.g. a sphere's radius, a part's
        height); default: the peak-to-peak truth height on the grid.
    anchors : optional
        Passed to :func:`integrate_triangulated`; default: mean height 0
        (every piece is given a mean, so nothing floats).
    params : IntegrateParams, optional
        For the sparse methods (their ``rule`` is set per method).
    methods : sequence of str, optional
        Any of ``"sparse-arc"``, ``"sparse-trapezoid"``, ``"poisson"``,
        ``"frankot-chellappa"``, ``"robust"`` (default: all).
    remove_offset : bool
        Subtract each result's mean error over the scored nodes first (the
        heights of unanchored integration are known only up to a constant).
    max_nodes : int
        Refuse grids larger than this.

    Returns
    -------
    dict
        ``{"grid": {...}, method: {"height_rms_mm", "height_rms_pct",
        "normal_rms_deg", "nodes", ...}}``. Every method is scored on the
        same grid nodes: those inside the kept triangles where every method
        has a height. Normals of a result are its central-difference
        slopes; normal errors are scored on nodes whose four neighbours are
        scored too. Sparse methods also report ``height_rms_at_points_mm``.
    """
    all_methods = ("sparse-arc", "sparse-trapezoid", "poisson", "frankot-chellappa", "robust")
    methods = all_methods if methods is None else tuple(methods)
    for m in methods:
        check_choice("method", m, all_methods)
    params = with_overrides(IntegrateParams, params, {})
    if anchors is None:
        anchors = 0.0
    sparse_res = {m: integrate_triangulated(xy, normals, anchors=anchors, params=replace(params, rule=m[7:]))
                  for m in methods if m.startswith("sparse-")}  # rule "arc" or "trapezoid"
    base = next(iter(sparse_res.values())) if sparse_res else integrate_triangulated(xy, normals, anchors=anchors,
                                                                                   params=params)
    if grid_step_mm is None:
        lengths = np.linalg.norm(base.xy[base.edges[:, 1]] - base.xy[base.edges[:, 0]], axis=1)
        grid_step_mm = 0.5 * float(np.median(lengths))
    step = check_number("grid_step_mm", grid_step_mm, lo=0, lo_open=True)
    lo = base.xy.min(axis=0)
    hi = base.xy.max(axis=0)
    gx = np.arange(lo[0], hi[0] + 0.5 * step, step)
    gy = np.arange(lo[1], hi[1] + 0.5 * step, step)
    if len(gx) < 3 or len(gy) < 3:  # central differences and the scored interior need three nodes a side
        raise OptionError(f"the points span {len(gy)} x {len(gx)} grid nodes at a {step:g} mm step; the grid "
                          "integrators need at least 3 x 3 (are the points along a line?)", field="grid_step_mm")
    if len(gx) * len(gy) > max_nodes:
        raise OptionError(f"{len(gy)} x {len(gx)} grid nodes exceed max_nodes={max_nodes}; use a larger step",
                          field="grid_step_mm")
    X, Y = np.meshgrid(gx, gy)
    truth = np.asarray(truth_fn(X, Y), float)
    n_truth = _truth_normals(truth_fn, X, Y, 1e-5 * max(step, 1e-3))
    mask = np.isfinite(base.height_map(gx, gy, relative=True))
    p, q = grid_gradients(base.xy, base.normals, gx, gy, mask=mask)
    zs = {m: s.height_map(gx, gy) for m, s in sparse_res.items()}
    for m, grid_method in (("poisson", integrate_poisson), ("frankot-chellappa", integrate_frankot_chellappa),
                           ("robust", integrate_robust)):
        if m in methods:
            zs[m] = grid_method(p, q, mask=mask, step_mm=step).z
    scored = mask & np.isfinite(truth)  # a truth known only on part of the grid (a rendered surface) scores there
    for z in zs.values():
        scored &= np.isfinite(z)
    inner = binary_erosion(scored, border_value=0)  # scored, as are its four neighbours (none off the grid)
    if scale_mm is None:
        scale_mm = float(np.ptp(truth[scored])) if np.any(scored) else 1.0
    out = {"grid": {"step_mm": step, "shape": tuple(truth.shape), "nodes": int(scored.sum()),
                    "scale_mm": float(scale_mm)}}
    for m in methods:
        z = zs[m]
        err = (z - truth)[scored]
        if remove_offset and len(err):
            err = err - err.mean()
        rms = _rms(err, float("nan"))
        ang = np.degrees(angle_between(_grid_normals(z, step, step), n_truth))[inner]
        ang = ang[np.isfinite(ang)]
        entry = {"height_rms_mm": rms, "height_rms_pct": 100.0 * rms / scale_mm if scale_mm else float("nan"),
                 "height_max_mm": float(np.max(np.abs(err))) if len(err) else float("nan"),
                 "normal_rms_deg": _rms(ang, float("nan")),
                 "nodes": int(scored.sum())}
        if m in sparse_res:
            s = sparse_res[m]
            e = s.z - np.asarray(truth_fn(s.xy[:, 0], s.xy[:, 1]), float)
            e = e[np.isfinite(e)]
            if remove_offset and len(e):
                e = e - e.mean()
            entry["height_rms_at_points_mm"] = _rms(e, float("nan"))
            entry["components"] = len(s.components)
        out[m] = entry
    return out
