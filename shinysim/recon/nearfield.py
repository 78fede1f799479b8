"""Near-field normals: surface points and normals refined together, from one anchor.

The paper's camera models place every highlight on the reference plane
(:mod:`shinysim.recon.normals`); on a real object it sits above it, which
biases the normals. :func:`near_field_normals` iterates: surface points on
the highlights' pixel rays at the current heights, normals bisecting the
directions to source and camera from there, heights from those normals
integrated over a graph of neighbouring highlights by the integrator
family's arc rule and least-squares solve
(:func:`~shinysim.recon.integrate.edge_rise`,
:func:`~shinysim.recon.integrate.solve_heights`) and tied to one stated
:class:`~shinysim.rig.Anchor` (a known point, or an occluding contour on a
plane), until no height moves by more than ``tol_mm``; it says whether it
converged. Why one camera needs the anchor, what the model assumes and what
it measures: ``docs/camera-models.md``, "The near-field model".
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph
from scipy.spatial import cKDTree

from .._shared import check_number
from ..conventions import bisector
from ..errors import OptionError
from ..rig import ANCHOR_KINDS, Anchor, Rig
from .integrate import edge_rise, solve_heights

__all__ = ["NEAR_FIELD", "ANCHOR_KINDS", "Anchor", "NearField", "near_field_normals"]

#: The model's name in tables, score.json and on the command line.
NEAR_FIELD = "near-field"

# the anchor's rows outweigh the integration's by this much: it is a
# constraint, not a measurement to be averaged with the gradients
_ANCHOR_WEIGHT = 1e3


@dataclass
class NearField:
    """Result of :func:`near_field_normals`.

    Attributes
    ----------
    normals : (N, 3) ndarray
        Unit normals (NaN where a pixel ray never reaches its height).
    points : (N, 3) ndarray, millimetres
        Surface points on the highlights' pixel rays.
    converged : bool
    iterations : int
    last_step_mm : float
        Largest height change of the last iteration.
    edges : int
        Edges of the integration graph.
    """

    normals: np.ndarray
    points: np.ndarray
    converged: bool
    iterations: int
    last_step_mm: float
    edges: int
    history_mm: list[float] = field(default_factory=list)


def _graph(xy, neighbours):
    """Edges (i, j) of a connected neighbour graph over 2-D points."""
    n = len(xy)
    if n < 2:
        return np.zeros((0, 2), int)
    k = min(neighbours, n - 1)
    tree = cKDTree(xy)
    _, idx = tree.query(xy, k=k + 1)
    pairs = {(min(i, j), max(i, j)) for i in range(n) for j in np.atleast_1d(idx[i])[1:] if i != j}
    edges = np.array(sorted(pairs), int).reshape(-1, 2)
    # join the pieces by their shortest gaps until one component is left
    while True:
        adj = sparse.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
        n_comp, labels = csgraph.connected_components(adj, directed=False)
        if n_comp <= 1:
            return edges
        inside = np.flatnonzero(labels == labels[0])
        outside = np.flatnonzero(labels != labels[0])
        d, j = cKDTree(xy[outside]).query(xy[inside])
        best = int(np.argmin(d))
        a, b = int(inside[best]), int(outside[j[best]])
        edges = np.vstack([edges, [min(a, b), max(a, b)]])


def _anchor_rows(anchor, xy, g, normals, cam):
    """Rows (index, coefficient 1 on z_index, right-hand side) tying highlights to the anchor."""
    rows = []
    if anchor.kind == "point":
        p0 = np.asarray(anchor.point)
        i = int(np.argmin(np.sum((xy - p0[:2]) ** 2, axis=1)))
        d = xy[i] - p0[:2]
        length = float(np.linalg.norm(d))
        if anchor.normal is None or length == 0:
            # the anchor's normal unknown: the highlight's gradient alone (first order)
            rise = -float(g[i] @ d)
        else:  # the circular rule between the anchor and the highlight
            rise = float(edge_rise(np.asarray(anchor.normal)[None], normals[i][None], d[None])[0])
        rows.append((i, p0[2] + rise))
        return rows
    contour = cam.backproject_to_plane(np.asarray(anchor.rows), np.asarray(anchor.cols), anchor.plane_z)[:, :2]
    tree = cKDTree(xy)
    _, nearest = tree.query(contour)
    for c_xy, i in zip(contour, nearest):
        du_vec = c_xy - xy[i]
        du = float(np.linalg.norm(du_vec))
        if not np.isfinite(du) or du == 0:
            continue
        u = du_vec / du
        if float(normals[i, :2] @ u) <= 0:  # the highlight's normal does not turn towards this contour point
            continue
        # the circular arc from the highlight to a horizontal normal at the contour
        rows.append((int(i), anchor.plane_z - float(edge_rise(normals[i][None], np.append(u, 0.0)[None],
                                                              du_vec[None])[0])))
    if not rows:
        raise OptionError("no highlight's normal turns towards the anchor contour; the contour cannot anchor "
                          "these highlights", field="anchor contour")
    return rows


def near_field_normals(rows, cols, sources, rig: Rig, anchor: Anchor, *, camera_index: int = 0,
                       plane_z: float | None = None, max_iter: int = 50, tol_mm: float = 1e-9,
                       neighbours: int = 4) -> NearField:
    """Normals and surface points of highlights, refined together from an anchor.

    Parameters
    ----------
    rows, cols : (N,) array_like
        Highlight centroids, continuous pixel coordinates.
    sources : (N,) int array_like
    rig : Rig
    anchor : Anchor
    camera_index : int
    plane_z : float, optional
        Starting height, millimetres (default ``rig.reference_z``).
    max_iter : int
    tol_mm : float
        Converged when no height moves by more than this in one step.
    neighbours : int
        Each highlight's nearest neighbours in the integration graph.

    Returns
    -------
    NearField
        ``converged`` False when ``max_iter`` steps did not bring the
        largest height change under ``tol_mm`` (or a height became NaN);
        the normals are then those of the last step.
    """
    if not isinstance(anchor, Anchor):
        raise OptionError(f"must be an Anchor, got {type(anchor).__name__}", field="anchor")
    check_number("max_iter", max_iter, lo=1, integer=True)
    check_number("tol_mm", tol_mm, lo=0, lo_open=True)
    check_number("neighbours", neighbours, lo=1, integer=True)
    cam = rig.cameras[camera_index]
    rows = np.asarray(rows, float).ravel()
    cols = np.asarray(cols, float).ravel()
    sources = np.asarray(sources, int).ravel()
    n = len(rows)
    if n == 0:
        empty = np.zeros((0, 3))
        return NearField(empty, empty, True, 0, 0.0, 0)
    origins, directions = cam.pixel_rays(rows, cols)
    origins = origins.reshape(-1, 3)
    directions = directions.reshape(-1, 3)

    def at(z):
        """The points on the pixel rays at heights ``z`` (NaN where a ray never gets there), and their normals."""
        dz = directions[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (z - origins[:, 2]) / dz
        points = origins + np.where((dz != 0) & (t > 0), t, np.nan)[:, None] * directions
        return points, bisector(rig.source_directions(points, sources), cam.view_directions(points))

    z = np.full(n, rig.reference_z if plane_z is None else float(plane_z))
    history = []
    edges = np.zeros((0, 2), int)
    converged = False
    points, normals = at(z)
    for it in range(1, int(max_iter) + 1):
        xy = points[:, :2]
        if not np.all(np.isfinite(points)):
            break
        g = normals[:, :2] / normals[:, 2:3]
        if it == 1:
            edges = _graph(xy, int(neighbours))
        i, j = edges[:, 0], edges[:, 1]
        d = xy[j] - xy[i]
        length = np.linalg.norm(d, axis=1)
        w = 1.0 / np.maximum(length, 1e-12) ** 0.5  # shorter edges are integrated more accurately
        anchor_rows = _anchor_rows(anchor, xy, g, normals, cam)
        # dense least squares up to 400 highlights (orthogonal factorisation: to round-off; its cost grows
        # as n^3, seconds per iteration at 2000), above that the sparse normal equations, definite by the anchor
        z_new = solve_heights(n, edges, edge_rise(normals[i], normals[j], d), w, [a for a, _ in anchor_rows],
                              [v for _, v in anchor_rows], np.full(len(anchor_rows), _ANCHOR_WEIGHT),
                              solver="dense" if n <= 400 else "direct")
        step = float(np.max(np.abs(z_new - z)))
        history.append(step)
        z = z_new
        points, normals = at(z)
        if not np.isfinite(step):
            break
        if step <= tol_mm:
            converged = True
            break
    return NearField(normals, points, converged, len(history), history[-1] if history else float("nan"),
                     len(edges), history)
