"""Surfaces ``z(x, y)`` from sparse, irregular surface normals (beyond the paper).

The paper reconstructs one cross-section at a time
(:mod:`shinysim.recon.profile`). :func:`surface_from_normals` integrates
*all* sparse normals of a region into a height map by least squares:
gradient data at the measured points, a thin-plate smoothness term and
anchors, assembled as a sparse matrix and solved by a sparse direct
factorisation of its normal equations. It is the ``"thin-plate"`` method of
:func:`shinysim.recon.integrate.integrate`.

Frames, units and gradient conventions are those of
:mod:`shinysim.conventions` (millimetres, ``n ~ (-p, -q, 1)``). numpy and
scipy only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.sparse.linalg import spsolve
from scipy.spatial import cKDTree

from .._shared import check_number, with_overrides
from ..conventions import gradient_from_normal
from ..errors import OptionError

__all__ = ["SurfaceParams", "Surface", "surface_from_normals"]


@dataclass(frozen=True)
class SurfaceParams:
    """Settings of :func:`surface_from_normals`.

    Parameters
    ----------
    step_mm : float
        Grid spacing in x and y.
    smoothness : float
        Weight of the thin-plate term (the integral of squared second
        derivatives) against the sum of squared slope residuals.
    anchor_weight : float
        Weight of each anchor equation relative to one slope equation.
    max_nodes : int
        Largest number of grid nodes inside the mask (a guard against a
        step far too fine for the region).
    """

    step_mm: float = 0.005
    smoothness: float = 1e-3
    anchor_weight: float = 100.0
    max_nodes: int = 5000

    def __post_init__(self):
        for name in ("step_mm", "smoothness", "anchor_weight"):
            check_number(name, getattr(self, name), lo=0, lo_open=True)
        check_number("max_nodes", self.max_nodes, lo=4, integer=True)


@dataclass
class Surface:
    """A height map integrated from sparse normals.

    Attributes
    ----------
    x : (nx,) float, mm
    y : (ny,) float, mm
    z : (ny, nx) float, mm
        Heights on the grid (row index = y index); NaN outside ``mask``.
    mask : (ny, nx) bool
        Grid nodes inside the region.
    support_mm : (ny, nx) float
        Distance from each node to the nearest measured normal used.
    n_used : int
        Measured normals that entered the fit.
    """

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    mask: np.ndarray
    support_mm: np.ndarray
    n_used: int = 0

    def z_at(self, x, y):
        """Bilinear height at (x, y); NaN outside the grid or next to masked-out nodes."""
        x = np.asarray(x, float)
        y = np.asarray(y, float)
        h = self.x[1] - self.x[0]
        fx = (x - self.x[0]) / h
        fy = (y - self.y[0]) / h
        i0 = np.clip(np.floor(fx).astype(int), 0, len(self.x) - 2)
        j0 = np.clip(np.floor(fy).astype(int), 0, len(self.y) - 2)
        tx, ty = fx - i0, fy - j0
        inside = (fx >= -1e-9) & (fx <= len(self.x) - 1 + 1e-9) & (fy >= -1e-9) & (fy <= len(self.y) - 1 + 1e-9)
        z = self.z
        out = ((1 - tx) * (1 - ty) * z[j0, i0] + tx * (1 - ty) * z[j0, i0 + 1]
               + (1 - tx) * ty * z[j0 + 1, i0] + tx * ty * z[j0 + 1, i0 + 1])
        return np.where(inside, out, np.nan)


def surface_from_normals(x, y, normals, *, mask_fn=None, bounds=None, anchors=None, weights=None,
                         params=None, **kwargs):
    """Least-squares height map from sparse normals (beyond the paper).

    Minimises over the heights ``z`` of a regular grid::

        sum_i w_i [(dz/dx(x_i, y_i) - p_i)^2 + (dz/dy(x_i, y_i) - q_i)^2]
          + smoothness * integral (z_xx^2 + 2 z_xy^2 + z_yy^2) dx dy
          + anchor_weight * sum_a (z(x_a, y_a) - z_a)^2

    with ``(p, q)`` the gradients of the measured normals. Slopes live on the
    grid's edge midpoints and are interpolated bilinearly to the measured
    points (a quadratic surface is matched exactly); the thin-plate term
    fills the gaps between sparse measurements with the smoothest surface.
    The equations form a sparse matrix whose normal equations are solved by
    a sparse direct factorisation. Without anchors the height is fixed only
    up to a constant: the solution with zero mean is returned.

    Parameters
    ----------
    x, y : (N,) array_like, mm
        Positions of the measured normals.
    normals : (N, 3) array_like
        Unit normals; rows with ``nz <= 0`` or NaN are dropped.
    mask_fn : callable, optional
        ``mask_fn(X, Y) -> (ny, nx) bool``: grid nodes that belong to the
        region (default all). Equations touching other nodes are dropped.
    bounds : (x0, x1, y0, y1), optional
        Grid extent, mm (default: bounding box of points and anchors).
    anchors : (A, 3) array_like, optional
        ``(x, y, z)`` points of known height, mm.
    weights : (N,) array_like, optional
    params : SurfaceParams, optional
        Keyword arguments override single fields.

    Returns
    -------
    Surface

    Raises
    ------
    OptionError
        On mismatched shapes, nothing to integrate, or a grid larger than
        ``max_nodes``.
    """
    params = with_overrides(SurfaceParams, params, kwargs)
    x = np.asarray(x, float).reshape(-1)
    y = np.asarray(y, float).reshape(-1)
    n = np.asarray(normals, float)
    if y.shape != x.shape or n.shape != (len(x), 3):
        raise OptionError(f"x, y and normals must have shapes (N,), (N,), (N, 3); got {x.shape}, {y.shape}, "
                          f"{n.shape}", field="normals")
    w = np.ones(len(x)) if weights is None else np.asarray(weights, float).reshape(-1)
    if w.shape != x.shape:
        raise OptionError(f"weights must have shape {x.shape}, got {w.shape}", field="weights")
    p, q = gradient_from_normal(n)
    keep = np.isfinite(x) & np.isfinite(y) & np.isfinite(p) & np.isfinite(q) & (w > 0)
    x, y, p, q, w = x[keep], y[keep], p[keep], q[keep], w[keep]
    anchors = np.zeros((0, 3)) if anchors is None else np.asarray(anchors, float).reshape(-1, 3)
    h = params.step_mm
    if bounds is None:
        allx = np.concatenate([x, anchors[:, 0]])
        ally = np.concatenate([y, anchors[:, 1]])
        if allx.size == 0:
            raise OptionError("no finite normals and no anchors: nothing to integrate", field="normals")
        bounds = (allx.min(), allx.max(), ally.min(), ally.max())
    x0, x1, y0, y1 = (float(v) for v in bounds)
    nx = max(3, int(np.ceil((x1 - x0) / h - 1e-9)) + 1)
    ny = max(3, int(np.ceil((y1 - y0) / h - 1e-9)) + 1)
    gx = x0 + h * np.arange(nx)
    gy = y0 + h * np.arange(ny)
    GX, GY = np.meshgrid(gx, gy)
    mask = np.ones((ny, nx), bool) if mask_fn is None else np.asarray(mask_fn(GX, GY), bool)
    if mask.shape != (ny, nx):
        raise OptionError(f"must return shape {(ny, nx)}, got {mask.shape}", field="mask_fn")
    n_nodes = int(mask.sum())
    if n_nodes > params.max_nodes:
        raise OptionError(f"the grid has {n_nodes} nodes in the mask, more than max_nodes={params.max_nodes}: "
                          f"raise step_mm (now {h}) or shrink the region", field="step_mm")
    if n_nodes == 0:
        raise OptionError("selects no grid node", field="mask_fn")
    # unknown index of each grid node, -1 outside the mask (equations touching one are dropped)
    number = np.full(ny * nx, -1)
    number[mask.reshape(-1)] = np.arange(n_nodes)
    blocks = []  # (nodes (E, k), weighted coefficients (E, k), weighted right-hand sides (E,))

    def add(flat_nodes, coef, rhs, weight):
        nodes = number[flat_nodes]
        ok = np.all(nodes >= 0, axis=1)
        sw = np.sqrt(np.broadcast_to(np.asarray(weight, float), ok.shape)[ok])
        blocks.append((nodes[ok], coef[ok] * sw[:, None], rhs[ok] * sw))
        return ok

    # slope equations
    fx = (x - x0) / h
    fy = (y - y0) / h
    inside = (fx >= 0.5) & (fx <= nx - 1.5) & (fy >= 0.5) & (fy <= ny - 1.5)
    x, y, p, q, w, fx, fy = (a[inside] for a in (x, y, p, q, w, fx, fy))

    def stencil(f_along, f_across, n_along, n_across, along_is_x):
        u = f_along - 0.5
        k = np.clip(np.floor(u).astype(int), 0, n_along - 3)
        t = u - k
        jj = np.clip(np.floor(f_across).astype(int), 0, n_across - 2)
        s_ = f_across - jj
        nodes, coef = [], []
        for dj, ws in ((0, 1 - s_), (1, s_)):
            for dk, wt in ((0, 1 - t), (1, t)):
                a, c = k + dk, k + dk + 1
                if along_is_x:
                    nodes += [(jj + dj) * nx + a, (jj + dj) * nx + c]
                else:
                    nodes += [a * nx + (jj + dj), c * nx + (jj + dj)]
                coef += [-ws * wt / h, ws * wt / h]
        return np.stack(nodes, axis=1), np.stack(coef, axis=1)

    used = np.zeros(len(x), bool)
    if len(x):
        nodes, coef = stencil(fx, fy, nx, ny, True)
        used |= add(nodes, coef, p, w)
        nodes, coef = stencil(fy, fx, ny, nx, False)
        used |= add(nodes, coef, q, w)
    # anchors (bilinear)
    if len(anchors):
        fa = (anchors[:, 0] - x0) / h
        ga = (anchors[:, 1] - y0) / h
        a_in = (fa >= -1e-9) & (fa <= nx - 1 + 1e-9) & (ga >= -1e-9) & (ga <= ny - 1 + 1e-9)
        fa, ga, za = fa[a_in], ga[a_in], anchors[a_in, 2]
        ia = np.clip(np.floor(fa).astype(int), 0, nx - 2)
        ja = np.clip(np.floor(ga).astype(int), 0, ny - 2)
        ua, va = fa - ia, ga - ja
        nodes = np.stack([ja * nx + ia, ja * nx + ia + 1, (ja + 1) * nx + ia, (ja + 1) * nx + ia + 1], axis=1)
        coef = np.stack([(1 - ua) * (1 - va), ua * (1 - va), (1 - ua) * va, ua * va], axis=1)
        add(nodes, coef, za, params.anchor_weight)
    # thin plate: residuals z_xx h, sqrt(2) z_xy h, z_yy h (their squares sum to the integral)
    J, I = np.meshgrid(np.arange(ny), np.arange(nx), indexing="ij")
    lam = params.smoothness
    for sel, step, stencil_coef, weight in (((I > 0) & (I < nx - 1), [-1, 0, 1], [1.0, -2.0, 1.0], lam),
                                            ((J > 0) & (J < ny - 1), [-nx, 0, nx], [1.0, -2.0, 1.0], lam),
                                            ((J < ny - 1) & (I < nx - 1), [0, 1, nx, nx + 1],
                                             [1.0, -1.0, -1.0, 1.0], 2 * lam)):
        c = J[sel] * nx + I[sel]
        add(c[:, None] + np.array(step), np.tile(np.array(stencil_coef) / h, (len(c), 1)), np.zeros(len(c)), weight)
    rows = np.concatenate([np.repeat(np.arange(len(b)), nd.shape[1]) for nd, _, b in blocks])
    rows += np.repeat(np.cumsum([0] + [len(b) for _, _, b in blocks])[:-1], [nd.size for nd, _, _ in blocks])
    A = sparse.csr_matrix((np.concatenate([cf.ravel() for _, cf, _ in blocks]),
                           (rows, np.concatenate([nd.ravel() for nd, _, _ in blocks]))),
                          shape=(sum(len(b) for _, _, b in blocks), n_nodes))
    M = (A.T @ A).tocsc()
    # a tiny ridge makes the system definite when only slopes fix it (the height then free up to a
    # constant: with no anchor the right-hand side has no constant part, so the solution has zero mean)
    M = M + sparse.identity(n_nodes, format="csc") * (1e-12 * M.diagonal().sum() / n_nodes)
    zsol = spsolve(M, A.T @ np.concatenate([b for _, _, b in blocks]))
    Z = np.full(ny * nx, np.nan)
    Z[mask.reshape(-1)] = zsol
    Z = Z.reshape(ny, nx)
    if not len(anchors):
        Z -= np.nanmean(Z)
    if np.any(used):
        support = cKDTree(np.column_stack([x[used], y[used]])).query(np.stack([GX, GY], axis=-1))[0]
    else:
        support = np.full((ny, nx), np.inf)
    return Surface(gx, gy, Z, mask, support, int(used.sum()))
