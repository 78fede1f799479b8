"""Smooth random objects for synthetic data sets: blobs, superquadrics and height fields.

:func:`blob`, :func:`superquadric` and :func:`heightfield` build a
:class:`TriangleMesh` in the world frame (millimetres, +z up) whose vertex
normals are the smooth surface's analytic ones; :func:`random_shape` draws a
member of a family, :func:`rebuild` makes it again bit for bit from
``mesh.params``, :func:`shape_topology_key` says when two members share a
topology (so a loaded scene can be updated in place) and :func:`normals_at`
gives the analytic normal near the surface. numpy only. The families:
``docs/datasets.md``, section "object".
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from .._shared import check_number
from ..conventions import normalize
from ..errors import OptionError, did_you_mean

__all__ = [
    "BLOB_DEGREES",
    "BLOB_N_COEFFICIENTS",
    "RANDOM_DEFAULTS",
    "SHAPE_FAMILIES",
    "SUPERQUADRIC_EXPONENTS",
    "TriangleMesh",
    "blob",
    "face_areas",
    "heightfield",
    "normals_at",
    "random_shape",
    "real_spherical_harmonics",
    "rebuild",
    "shape_topology_key",
    "signed_volume",
    "superquadric",
]

#: The random shape families, each a builder function of this module.
SHAPE_FAMILIES = ("blob", "superquadric", "heightfield")

#: Spherical-harmonic degrees that perturb a blob: 0 would only scale it and 1
#: (to first order) only move it, so both are left out; 2..4 give smooth
#: lobes, dents and saddles a few per circumference.
BLOB_DEGREES = (2, 3, 4)
#: Number of blob coefficients: 2 l + 1 per degree (5 + 7 + 9).
BLOB_N_COEFFICIENTS = sum(2 * deg + 1 for deg in BLOB_DEGREES)

#: Allowed range of the superquadric exponents. At ``e <= 1`` the implicit
#: function's terms ``|x|^(2/e)`` have bounded second derivatives
#: (``2/e >= 2``), so the surface has continuous normals and bounded curvature
#: everywhere (``e = 1, 1`` is the ellipsoid). For ``1 < e < 2`` the normals
#: stay continuous but the curvature is unbounded along the coordinate
#: planes, a crease-like line that a mirror's highlight resolves and a mesh
#: cannot; ``e = 2`` is a sharp octahedral edge and ``e > 2`` pinches into
#: cusps. Below 0.3 the shape is a box whose rounded edges are so tight
#: (radius of curvature a few per cent of the size) that no affordable mesh
#: samples their normals well.
SUPERQUADRIC_EXPONENTS = (0.3, 1.0)

#: Distribution settings of :func:`random_shape` per family; any of them can
#: be overridden by keyword. Lengths are fractions of ``size_mm`` (blob,
#: superquadric) or of the patch side ``2 size_mm`` (height field).
RANDOM_DEFAULTS = {
    "blob": {
        "amplitude": (0.1, 0.4),   # bound on |r / R - 1|, uniform in this range
        "falloff": 2.0,            # coefficient scale of degree l: l ** -falloff
        "subdivisions": 5,         # icosphere: 10242 vertices, 20480 faces
    },
    "superquadric": {
        "aspect": (0.5, 1.0),      # each semi-axis / the largest, before rescaling
        "exponents": (0.4, 1.0),   # e1, e2 uniform in this range
        "rotate": True,            # a uniformly random orientation
        "resolution": (72, 144),   # latitude bands, longitude steps: 10226 vertices, 20448 faces
    },
    "heightfield": {
        "n_bumps": (2, 6),         # number of bumps, uniform integer (inclusive)
        "height": (0.03, 0.12),    # |height| / side
        "sigma": (0.1, 0.25),      # sigma / side
        "spread": 0.35,            # bump centres uniform in [-spread, spread]^2 * side
        "dimples": 0.3,            # probability that a bump is a dimple (negative height)
        "resolution": 101,         # vertices a side: 10201 vertices, 20000 faces
    },
}


# -- the mesh ------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class TriangleMesh:
    """A triangle mesh with unit vertex normals, in millimetres, world frame.

    Attributes
    ----------
    vertices : (V, 3) float64 ndarray
    faces : (F, 3) int32 ndarray
        Counter-clockwise seen from outside (the side the normals point to).
    normals : (V, 3) float64 ndarray
        Unit vertex normals: for the random families the analytic normal of
        the smooth surface at each vertex; for a user's mesh those of the
        file or of trimesh (:func:`shinysim.sim.meshes.load_user_mesh`).
    name : str
        The family (one of :data:`SHAPE_FAMILIES`), or ``"mesh"`` for a
        user's mesh.
    params : dict
        JSON-serialisable keyword arguments that rebuild the mesh (the
        family's builder, or ``load_user_mesh`` for ``"mesh"``).

    The arrays are read-only copies.
    """

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    name: str
    params: dict

    def __post_init__(self):
        v = np.array(self.vertices, dtype=np.float64)
        f = np.array(self.faces)
        n = np.array(self.normals, dtype=np.float64)
        if v.ndim != 2 or v.shape[1] != 3 or len(v) < 3:
            raise OptionError(f"vertices must be (V >= 3, 3), got shape {v.shape}")
        if not np.all(np.isfinite(v)):
            raise OptionError("vertices must be finite")
        if f.ndim != 2 or f.shape[1] != 3 or len(f) < 1 or not np.issubdtype(f.dtype, np.integer):
            raise OptionError(f"faces must be (F >= 1, 3) integers, got shape {f.shape}, dtype {f.dtype}")
        if f.min() < 0 or f.max() >= len(v):
            raise OptionError(f"face indices must lie in 0..{len(v) - 1}")
        if n.shape != v.shape or not np.all(np.isfinite(n)):
            raise OptionError(f"normals must be finite and shaped like vertices {v.shape}, got {n.shape}")
        if np.max(np.abs(np.linalg.norm(n, axis=1) - 1.0)) > 1e-9:
            raise OptionError("normals must be unit vectors")
        for name, a in (("vertices", v), ("faces", f.astype(np.int32)), ("normals", n)):
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        object.__setattr__(self, "name", str(self.name))
        object.__setattr__(self, "params", dict(self.params))

    @property
    def n_vertices(self) -> int:
        return len(self.vertices)

    @property
    def n_faces(self) -> int:
        return len(self.faces)


def shape_topology_key(mesh: TriangleMesh) -> tuple:
    """``(family, V, F)``: a loaded scene of one mesh can be updated in place to another of equal key.

    Random members of a family drawn with equal resolution settings share
    one key and identical faces arrays.
    :func:`shinysim.sim.meshes.update_mesh` itself needs only equal vertex
    and face counts (it writes the faces too), so equal keys are enough
    even where two resolutions give equal counts (a superquadric's
    ``(n_lat, n_lon)`` of ``(5, 8)`` and ``(9, 4)``).
    """
    return (mesh.name, mesh.n_vertices, mesh.n_faces)


def face_areas(mesh: TriangleMesh) -> np.ndarray:
    """(F,) area of each face, mm^2."""
    v = mesh.vertices[mesh.faces]
    return 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)


def signed_volume(mesh: TriangleMesh) -> float:
    """Enclosed volume, mm^3, by the divergence theorem: > 0 when a closed mesh's faces wind outwards."""
    v = mesh.vertices[mesh.faces]
    return float(np.sum(np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2]))) / 6.0)


def _vector(name, value, n=3, *, positive=False):
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise OptionError(f"{name} must be {n} numbers, got {value!r}") from None
    if a.shape != (n,) or not np.all(np.isfinite(a)) or (positive and not np.all(a > 0)):
        raise OptionError(f"{name} must be {n} finite{' positive' if positive else ''} numbers, got {value!r}")
    return a


# -- real spherical harmonics ------------------------------------------------------

def _mul(*polys):
    """The product of polynomials in x, y, z, each ``{(i, j, k): coefficient}``."""
    out = {(0, 0, 0): 1.0}
    for p in polys:
        new = {}
        for e1, c1 in out.items():
            for e2, c2 in p.items():
                e = (e1[0] + e2[0], e1[1] + e2[1], e1[2] + e2[2])
                new[e] = new.get(e, 0.0) + c1 * c2
        out = new
    return out


def _add(*pairs):
    """sum of coefficient * polynomial."""
    out = {}
    for coef, p in pairs:
        for e, c in p.items():
            out[e] = out.get(e, 0.0) + coef * c
    return {e: c for e, c in out.items() if c != 0.0}


@lru_cache(maxsize=1)
def _sh_table():
    """The real spherical harmonics of degrees 2..4 as homogeneous polynomials.

    Each entry is ``(l, m, exponents (T, 3) int, coefficients (T,))`` of
    ``sqrt(4 pi) Y_lm``: scaled to unit mean square over the sphere, so a
    blob coefficient is the RMS relative change of radius it brings. The
    normalisation constants are the standard ones (orthonormal real
    harmonics); a test checks orthonormality by exact quadrature.
    """
    x, y, z = {(1, 0, 0): 1.0}, {(0, 1, 0): 1.0}, {(0, 0, 1): 1.0}
    x2, y2, z2 = _mul(x, x), _mul(y, y), _mul(z, z)
    r2 = _add((1, x2), (1, y2), (1, z2))
    pi = math.pi
    s = math.sqrt
    entries = [
        (2, -2, 0.5 * s(15 / pi), _mul(x, y)),
        (2, -1, 0.5 * s(15 / pi), _mul(y, z)),
        (2, 0, 0.25 * s(5 / pi), _add((3, z2), (-1, r2))),
        (2, 1, 0.5 * s(15 / pi), _mul(x, z)),
        (2, 2, 0.25 * s(15 / pi), _add((1, x2), (-1, y2))),
        (3, -3, 0.25 * s(35 / (2 * pi)), _mul(y, _add((3, x2), (-1, y2)))),
        (3, -2, 0.5 * s(105 / pi), _mul(x, y, z)),
        (3, -1, 0.25 * s(21 / (2 * pi)), _mul(y, _add((5, z2), (-1, r2)))),
        (3, 0, 0.25 * s(7 / pi), _mul(z, _add((5, z2), (-3, r2)))),
        (3, 1, 0.25 * s(21 / (2 * pi)), _mul(x, _add((5, z2), (-1, r2)))),
        (3, 2, 0.25 * s(105 / pi), _mul(z, _add((1, x2), (-1, y2)))),
        (3, 3, 0.25 * s(35 / (2 * pi)), _mul(x, _add((1, x2), (-3, y2)))),
        (4, -4, 0.75 * s(35 / pi), _mul(x, y, _add((1, x2), (-1, y2)))),
        (4, -3, 0.75 * s(35 / (2 * pi)), _mul(y, z, _add((3, x2), (-1, y2)))),
        (4, -2, 0.75 * s(5 / pi), _mul(x, y, _add((7, z2), (-1, r2)))),
        (4, -1, 0.75 * s(5 / (2 * pi)), _mul(y, z, _add((7, z2), (-3, r2)))),
        (4, 0, 3 / 16 * s(1 / pi), _add((35, _mul(z2, z2)), (-30, _mul(z2, r2)), (3, _mul(r2, r2)))),
        (4, 1, 0.75 * s(5 / (2 * pi)), _mul(x, z, _add((7, z2), (-3, r2)))),
        (4, 2, 3 / 8 * s(5 / pi), _mul(_add((1, x2), (-1, y2)), _add((7, z2), (-1, r2)))),
        (4, 3, 0.75 * s(35 / (2 * pi)), _mul(x, z, _add((1, x2), (-3, y2)))),
        (4, 4, 3 / 16 * s(35 / pi), _add((1, _mul(x2, x2)), (-6, _mul(x2, y2)), (1, _mul(y2, y2)))),
    ]
    table = []
    for deg, m, norm, p in entries:
        p = {e: c for e, c in p.items() if c != 0.0}
        exps = np.array(sorted(p), dtype=np.int64)
        coefs = np.array([p[tuple(e)] for e in exps]) * norm * math.sqrt(4 * pi)
        table.append((deg, m, exps, coefs))
    assert [t[0] for t in table] == [deg for deg in BLOB_DEGREES for _ in range(2 * deg + 1)]
    return tuple(table)


def real_spherical_harmonics(u):
    """Values and gradients of the blob basis at unit vectors.

    Parameters
    ----------
    u : (N, 3) float
        Unit vectors.

    Returns
    -------
    values : (N, K) float
        ``sqrt(4 pi) Y_lm(u)`` for the :data:`BLOB_N_COEFFICIENTS` harmonics,
        ordered by degree (2, 3, 4), then order ``m = -l..l``.
    gradients : (N, K, 3) float
        Gradients of the homogeneous polynomials at ``u`` (their tangential
        part is the gradient on the sphere: ``grad - l Y u``).
    degrees : (K,) int
    """
    u = np.asarray(u, dtype=float)
    powers = np.stack([u[:, None, :] ** p for p in range(5)], axis=0)  # (5, N, 1, 3)
    table = _sh_table()
    n = len(u)
    values = np.zeros((n, len(table)))
    grads = np.zeros((n, len(table), 3))
    for k, (_, _, exps, coefs) in enumerate(table):
        p = [powers[exps[:, c], :, 0, c] for c in range(3)]  # x^i, y^j, z^k of each term: (T, N)
        d = [powers[np.maximum(exps[:, c] - 1, 0), :, 0, c] for c in range(3)]  # one power less
        values[:, k] = coefs @ (p[0] * p[1] * p[2])
        for c in range(3):  # d/dx, d/dy, d/dz: the one factor differentiated
            q = [d[i] if i == c else p[i] for i in range(3)]
            grads[:, k, c] = (coefs * exps[:, c]) @ (q[0] * q[1] * q[2])
    degrees = np.array([t[0] for t in table])
    return values, grads, degrees


# -- blob ----------------------------------------------------------------------------

@lru_cache(maxsize=8)
def _icosphere(subdivisions):
    """Unit vertices and outward CCW faces of an icosphere (read-only arrays)."""
    t = (1.0 + math.sqrt(5.0)) / 2.0
    v = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t],
                  [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], dtype=float)
    v = normalize(v)
    f = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
                  [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
                  [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]], dtype=np.int64)
    for _ in range(subdivisions):
        edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        uniq, inv = np.unique(edges, axis=0, return_inverse=True)
        mid = normalize(v[uniq[:, 0]] + v[uniq[:, 1]])
        m = inv.reshape(3, -1).T + len(v)
        a, b, c = f.T
        ab, bc, ca = m.T
        f = np.concatenate([np.stack(s, axis=1) for s in
                            ((a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca))])
        v = np.concatenate([v, mid])
    f = f.astype(np.int32)
    v.setflags(write=False)
    f.setflags(write=False)
    return v, f


def _blob_coefficients(coefficients):
    if coefficients is None:
        return np.zeros(BLOB_N_COEFFICIENTS)
    a = np.asarray(coefficients, dtype=float) if not isinstance(coefficients, str) else None
    if a is None or a.shape != (BLOB_N_COEFFICIENTS,) or not np.all(np.isfinite(a)):
        raise OptionError(f"coefficients must be {BLOB_N_COEFFICIENTS} finite numbers (degrees 2, 3, 4; "
                          f"m = -l..l), got {coefficients!r}")
    return a


def _blob_bound(a):
    """Upper bound of ``|r / R - 1|``: sum |a_k| sqrt(2 l + 1) (|sqrt(4 pi) Y_lm| <= sqrt(2 l + 1))."""
    degrees = np.array([t[0] for t in _sh_table()])
    return float(np.sum(np.abs(a) * np.sqrt(2 * degrees + 1)))


def _blob_surface(u, a):
    """Relative radius ``1 + s(u)`` and outward unit normals at unit directions ``u``."""
    values, grads, degrees = real_spherical_harmonics(u)
    s = values @ a
    grad = np.einsum("nkc,k->nc", grads, a)
    # tangential gradient on the unit sphere: grad P - l P u (Euler: u . grad P = l P)
    tangential = grad - ((values * degrees) @ a)[:, None] * u
    rel = 1.0 + s
    return rel, normalize(u - tangential / rel[:, None])


def blob(*, radius_mm=0.79375, center_mm=(0.0, 0.0, 0.0), coefficients=None, subdivisions=5) -> TriangleMesh:
    """A smooth perturbed sphere ``x = c + R (1 + sum_k a_k Y_k(u)) u``.

    Parameters
    ----------
    radius_mm : float
        ``R``, > 0 (default: the paper's 1/16 in sphere).
    center_mm : (3,) float
    coefficients : sequence of 21 floats, optional
        ``a_k`` of the harmonics ``sqrt(4 pi) Y_lm`` (unit mean square over
        the sphere), ordered by degree 2, 3, 4 and order ``m = -l..l``
        (:func:`real_spherical_harmonics`); default all zero, a sphere.
        ``sum_k |a_k| sqrt(2 l_k + 1)``, a bound on ``|r / R - 1|``, must be
        below 0.95, so that the radius stays positive (the surface is then
        star-shaped about the centre and cannot intersect itself).
    subdivisions : int
        Of the icosahedron, 0..7: ``10 4^s + 2`` vertices, ``20 4^s`` faces
        (5: 10242 and 20480, edges about 2 degrees of arc).

    Normals are analytic: the surface is the zero set of
    ``|x - c| - R (1 + s(u))``, whose gradient is ``u - grad_S s(u) / (1 + s)``
    with ``grad_S`` the gradient on the unit sphere.
    """
    radius = check_number("radius_mm", radius_mm, lo=0.0, lo_open=True)
    center = _vector("center_mm", center_mm)
    subdivisions = check_number("subdivisions", subdivisions, lo=0, hi=7, integer=True)
    a = _blob_coefficients(coefficients)
    bound = _blob_bound(a)
    if bound >= 0.95:
        raise OptionError(f"coefficients: sum |a_k| sqrt(2 l + 1) = {bound:.3g} must be < 0.95 (a positive radius)")
    u, faces = _icosphere(subdivisions)
    rel, normals = _blob_surface(u, a)
    vertices = center + (radius * rel)[:, None] * u
    params = {"radius_mm": radius, "center_mm": center.tolist(), "coefficients": a.tolist(),
              "subdivisions": subdivisions}
    return TriangleMesh(vertices, faces, normals, "blob", params)


# -- superquadric ---------------------------------------------------------------------

def _spow(c, e):
    """Signed power sign(c) |c|^e."""
    return np.sign(c) * np.abs(c) ** e


def _quaternion_matrix(q):
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def _superquadric_local(eta, omega, radii, e1, e2):
    """Points and unit normals of a superellipsoid in its own frame, at latitudes ``eta`` and longitudes ``omega``."""
    a, b, c = radii
    ce, se = np.cos(eta), np.sin(eta)
    cw, sw = np.cos(omega), np.sin(omega)
    p = np.stack([a * _spow(ce, e1) * _spow(cw, e2), b * _spow(ce, e1) * _spow(sw, e2), c * _spow(se, e1)], axis=-1)
    # Barr: n ~ (cos^(2-e1) eta cos^(2-e2) omega / a, cos^(2-e1) eta sin^(2-e2) omega / b, sin^(2-e1) eta / c)
    n = np.stack([_spow(ce, 2 - e1) * _spow(cw, 2 - e2) / a, _spow(ce, 2 - e1) * _spow(sw, 2 - e2) / b,
                  _spow(se, 2 - e1) / c], axis=-1)
    return p, normalize(n)


@lru_cache(maxsize=8)
def _latlong_faces(n_lat, n_lon):
    """Faces of a sphere grid: ``n_lat - 1`` rings of ``n_lon`` vertices, then the south and north poles."""
    ring = np.arange(n_lon)
    nxt = (ring + 1) % n_lon
    faces = []
    for i in range(n_lat - 2):  # bands between rings i (lower) and i + 1
        lo, hi = i * n_lon, (i + 1) * n_lon
        faces.append(np.stack([lo + ring, lo + nxt, hi + nxt], axis=1))
        faces.append(np.stack([lo + ring, hi + nxt, hi + ring], axis=1))
    south, north = (n_lat - 1) * n_lon, (n_lat - 1) * n_lon + 1
    top = (n_lat - 2) * n_lon
    faces.append(np.stack([np.full(n_lon, south), nxt, ring], axis=1))
    faces.append(np.stack([np.full(n_lon, north), top + ring, top + nxt], axis=1))
    f = np.concatenate(faces).astype(np.int32)
    f.setflags(write=False)
    return f


def _superquadric_resolution(resolution):
    try:
        n_lat, n_lon = resolution
    except (TypeError, ValueError):
        raise OptionError(f"resolution must be (latitude bands, longitude steps), got {resolution!r}") from None
    n_lat = check_number("resolution[0] (latitude bands)", n_lat, lo=4, hi=4096, integer=True)
    n_lon = check_number("resolution[1] (longitude steps)", n_lon, lo=6, hi=8192, integer=True)
    return n_lat, n_lon


def _superquadric_exponents(exponents):
    e = _vector("exponents", exponents, 2)
    lo, hi = SUPERQUADRIC_EXPONENTS
    if not np.all((e >= lo) & (e <= hi)):
        raise OptionError(f"exponents must lie in [{lo}, {hi}] (smooth, bounded curvature), got {exponents!r}")
    return e


def superquadric(*, radii_mm=(0.79375, 0.79375, 0.79375), exponents=(1.0, 1.0), center_mm=(0.0, 0.0, 0.0),
                 rotation=(1.0, 0.0, 0.0, 0.0), resolution=(72, 144)) -> TriangleMesh:
    """Barr's superellipsoid ``(|x/a|^(2/e2) + |y/b|^(2/e2))^(e2/e1) + |z/c|^(2/e1) = 1``.

    Parameters
    ----------
    radii_mm : (a, b, c) float
        Semi-axes, > 0.
    exponents : (e1, e2) float
        Latitude (e1) and longitude (e2) exponents in
        :data:`SUPERQUADRIC_EXPONENTS` (see there why): 1, 1 is the
        ellipsoid, smaller is boxier.
    center_mm : (3,) float
    rotation : (w, x, y, z) float
        A quaternion (normalised here) turning the shape's own axes into the
        world's: ``x_world = center + R(q) x_local``.
    resolution : (n_lat, n_lon) int
        Latitude bands and longitude steps of the grid in Barr's angles
        ``eta``, ``omega``: ``(n_lat - 1) n_lon + 2`` vertices (one at each
        pole, so no degenerate triangles) and ``2 n_lon (n_lat - 1)`` faces.

    Normals are analytic (Barr's normal formula, continuous for e <= 1,
    at the poles too).
    """
    radii = _vector("radii_mm", radii_mm, positive=True)
    e1, e2 = _superquadric_exponents(exponents)
    center = _vector("center_mm", center_mm)
    q = _vector("rotation", rotation, 4)
    if not np.linalg.norm(q) > 0:
        raise OptionError(f"rotation must be a non-zero quaternion (w, x, y, z), got {rotation!r}")
    n_lat, n_lon = _superquadric_resolution(resolution)
    eta = -0.5 * np.pi + np.pi * np.arange(1, n_lat) / n_lat
    omega = -np.pi + 2.0 * np.pi * np.arange(n_lon) / n_lon
    ee, ww = np.meshgrid(eta, omega, indexing="ij")
    p, n = _superquadric_local(ee.ravel(), ww.ravel(), radii, e1, e2)
    poles_p = np.array([[0.0, 0.0, -radii[2]], [0.0, 0.0, radii[2]]])
    poles_n = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]])
    rot = _quaternion_matrix(q)
    vertices = center + np.concatenate([p, poles_p]) @ rot.T
    normals = normalize(np.concatenate([n, poles_n]) @ rot.T)
    params = {"radii_mm": radii.tolist(), "exponents": [float(e1), float(e2)], "center_mm": center.tolist(),
              "rotation": q.tolist(), "resolution": [n_lat, n_lon]}
    return TriangleMesh(vertices, _latlong_faces(n_lat, n_lon), normals, "superquadric", params)


# -- height field ---------------------------------------------------------------------

def _bumps(bumps):
    try:
        b = np.asarray(bumps, dtype=float).reshape(-1, 4) if len(bumps) else np.zeros((0, 4))
    except (TypeError, ValueError):
        raise OptionError(f"bumps must be a list of (x_mm, y_mm, height_mm, sigma_mm), got {bumps!r}") from None
    if not np.all(np.isfinite(b)) or not np.all(b[:, 3] > 0) or (len(bumps) and np.ndim(bumps[0]) != 1):
        raise OptionError(f"bumps must be finite (x_mm, y_mm, height_mm, sigma_mm > 0), got {bumps!r}")
    return b


def _heightfield_surface(x, y, b):
    """Heights and unit normals (-z_x, -z_y, 1) / norm of a sum of Gaussian bumps."""
    z = np.zeros_like(x)
    zx = np.zeros_like(x)
    zy = np.zeros_like(x)
    for bx, by, h, sig in b:
        dx, dy = x - bx, y - by
        g = h * np.exp(-(dx * dx + dy * dy) / (2.0 * sig * sig))
        z += g
        zx -= g * dx / (sig * sig)
        zy -= g * dy / (sig * sig)
    return z, normalize(np.stack([-zx, -zy, np.ones_like(z)], axis=-1))


def _grid_mesh(size, n, surface, name, params) -> TriangleMesh:
    """A mesh of a height field over a square of side ``size`` centred at the origin, ``n`` vertices a side.

    ``surface(x, y) -> (z, unit normals)`` at the (n^2,) vertex coordinates;
    the faces are those of :func:`heightfield`.
    """
    t = size * (np.arange(n) / (n - 1) - 0.5)
    yy, xx = np.meshgrid(t, t, indexing="ij")
    z, normals = surface(xx.ravel(), yy.ravel())
    return TriangleMesh(np.stack([xx.ravel(), yy.ravel(), z], axis=-1), _grid_faces(n), normals, name, params)


@lru_cache(maxsize=8)
def _grid_faces(n):
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    v00 = (i * n + j).ravel()
    v01, v10, v11 = v00 + 1, v00 + n, v00 + n + 1
    f = np.concatenate([np.stack([v00, v01, v11], axis=1), np.stack([v00, v11, v10], axis=1)]).astype(np.int32)
    f.setflags(write=False)
    return f


def heightfield(*, size_mm=1.6, bumps=(), resolution=101) -> TriangleMesh:
    """A square patch ``z(x, y) = sum_i h_i exp(-|(x, y) - (x_i, y_i)|^2 / (2 sigma_i^2))``.

    Centred at the origin on the reference plane (z = 0 where there are no
    bumps), an open sheet facing +z (the camera).

    Parameters
    ----------
    size_mm : float
        Side of the square, > 0.
    bumps : sequence of (x_mm, y_mm, height_mm, sigma_mm)
        Gaussian bumps (negative height: a dimple), sigma > 0. Their number
        changes only z, never the topology.
    resolution : int
        Vertices a side, 2..4096: ``n^2`` vertices, ``2 (n - 1)^2`` faces
        (each grid cell split along the same diagonal).

    Normals are analytic, ``(-dz/dx, -dz/dy, 1)`` normalised.
    """
    size = check_number("size_mm", size_mm, lo=0.0, lo_open=True)
    b = _bumps(bumps)
    n = check_number("resolution", resolution, lo=2, hi=4096, integer=True)
    params = {"size_mm": size, "bumps": b.tolist(), "resolution": n}
    return _grid_mesh(size, n, lambda x, y: _heightfield_surface(x, y, b), "heightfield", params)


# -- rebuilding, analytic normals -------------------------------------------------

_BUILDERS = {"blob": blob, "superquadric": superquadric, "heightfield": heightfield}


def _family(name):
    if name not in _BUILDERS:
        raise OptionError(f"shape family must be one of {', '.join(SHAPE_FAMILIES)}; got {name!r}"
                          f"{did_you_mean(name, SHAPE_FAMILIES)}")
    return name


def rebuild(name: str, params: dict) -> TriangleMesh:
    """The mesh of family ``name`` built from ``params`` (``mesh.name``, ``mesh.params``)."""
    return _BUILDERS[_family(name)](**params)


def normals_at(mesh: TriangleMesh, points) -> np.ndarray:
    """Analytic unit normals of a random family's smooth surface at (or near) ``points``.

    Each point is carried onto the surface along the family's
    parametrisation, and the normal there is returned: a blob along the ray
    from its centre, a superquadric along Barr's angles (the point's
    ``eta, omega``; scale-invariant, so points off the surface map as their
    radial projection does), a height field vertically (the point's x, y).
    For points on a mesh facet this is the normal of the smooth surface the
    facet approximates, the truth to compare interpolated normals with.

    Parameters
    ----------
    mesh : TriangleMesh
        A member of one of :data:`SHAPE_FAMILIES`.
    points : (..., 3) float, millimetres

    Returns
    -------
    (..., 3) float
    """
    name = _family(mesh.name)
    p = np.asarray(points, dtype=float)
    shape = p.shape
    p = p.reshape(-1, 3)
    prm = mesh.params
    if name == "blob":
        u = normalize(p - np.asarray(prm["center_mm"]))
        _, n = _blob_surface(u, np.asarray(prm["coefficients"], dtype=float))
    elif name == "superquadric":
        rot = _quaternion_matrix(np.asarray(prm["rotation"], dtype=float))
        local = (p - np.asarray(prm["center_mm"])) @ rot
        a, b, c = prm["radii_mm"]
        e1, e2 = prm["exponents"]
        qx, qy, qz = local[:, 0] / a, local[:, 1] / b, local[:, 2] / c
        omega = np.arctan2(_spow(qy, 1 / e2), _spow(qx, 1 / e2))
        rho = (np.abs(qx) ** (2 / e2) + np.abs(qy) ** (2 / e2)) ** (e2 / 2)
        eta = np.arctan2(_spow(qz, 1 / e1), rho ** (1 / e1))
        _, n = _superquadric_local(eta, omega, (a, b, c), e1, e2)
        n = n @ rot.T
    else:
        _, n = _heightfield_surface(p[:, 0], p[:, 1], np.asarray(prm["bumps"], dtype=float).reshape(-1, 4))
    return n.reshape(shape)


# -- random members ---------------------------------------------------------------

def _range(family, name, value, *, lo=None, hi=None, integer=False):
    try:
        a, b = value
    except (TypeError, ValueError):
        raise OptionError(f"{family} {name} must be a range (low, high), got {value!r}") from None
    a = check_number(f"{family} {name}[0]", a, lo=lo, hi=hi, integer=integer)
    b = check_number(f"{family} {name}[1]", b, lo=lo, hi=hi, integer=integer)
    if a > b:
        raise OptionError(f"{family} {name} must be a range (low <= high), got {value!r}")
    return a, b


def random_shape(family: str, rng: np.random.Generator, *, size_mm=0.79375, center_mm=None,
                 **ranges) -> TriangleMesh:
    """A smooth random member of a family, drawn from ``rng``.

    The same generator state gives the same mesh, bit for bit; the
    topology depends only on the resolution setting, never on the draw.
    ``size_mm`` is half the object's extent: a blob's mean radius ``R``, a
    superquadric's largest semi-axis, half a height field's side. Each
    distribution setting of :data:`RANDOM_DEFAULTS` can be overridden by
    keyword (``amplitude=(0.2, 0.3)``, ``resolution=51``, ...).

    Distributions, drawn in this order:

    * **blob**: ``g_k ~ N(0, 1)`` for the 21 harmonics, weighted
      ``l^-falloff`` (smaller, finer detail at higher degree), then scaled
      so that the bound ``sum |a_k| sqrt(2 l + 1)`` on ``|r / R - 1|``
      equals an amplitude ``~ U(amplitude)``: the radius stays in
      ``R (1 +- amplitude)``. The harmonics' random mix already has a
      uniformly random orientation.
    * **superquadric**: semi-axes ``size * t_i / max(t)``, ``t_i ~
      U(aspect)``; ``e1, e2 ~ U(exponents)``; with ``rotate``, a uniformly
      random orientation (a normalised 4-vector of ``N(0, 1)``, a uniform
      unit quaternion).
    * **heightfield**: side ``2 size``; ``n ~ U{n_bumps}`` bumps, each with
      centre ``~ U(-spread, spread)^2 * side``, ``sigma ~ U(sigma) * side``,
      ``|height| ~ U(height) * side``, a dimple (negative) with
      probability ``dimples``. With the defaults a single bump's steepest
      slope is below ``0.61 * 0.12 / 0.1 = 0.73`` (36 degrees).

    Parameters
    ----------
    family : one of :data:`SHAPE_FAMILIES`
    rng : numpy.random.Generator
    size_mm : float
    center_mm : (3,) float, optional
        Centre of a blob or superquadric (default the origin; it takes no
        draws from ``rng``). A height field's patch is always centred at
        the origin on z = 0.
    **ranges
        Overrides of :data:`RANDOM_DEFAULTS` ``[family]``.
    """
    family = _family(family)
    size = check_number("size_mm", size_mm, lo=0.0, lo_open=True)
    if not isinstance(rng, np.random.Generator):
        raise OptionError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    defaults = RANDOM_DEFAULTS[family]
    for key in ranges:
        if key not in defaults:
            raise OptionError(f"unknown {family} setting {key!r}{did_you_mean(key, defaults)}; "
                              f"settings are {', '.join(defaults)}")
    cfg = {**defaults, **ranges}
    if center_mm is not None and family == "heightfield":
        raise OptionError("center_mm: a height field's patch is centred at the origin on z = 0; "
                          "center_mm places blobs and superquadrics")
    center = [0.0, 0.0, 0.0] if center_mm is None else _vector("center_mm", center_mm).tolist()
    if family == "blob":
        amp = _range(family, "amplitude", cfg["amplitude"], lo=0.0, hi=0.9)
        falloff = check_number("blob falloff", cfg["falloff"], lo=0.0, hi=10.0)
        degrees = np.array([t[0] for t in _sh_table()], dtype=float)
        g = rng.standard_normal(BLOB_N_COEFFICIENTS) * degrees ** -falloff
        amplitude = rng.uniform(*amp)
        bound = _blob_bound(g)
        a = g * (amplitude / bound) if bound > 0 else g * 0.0
        return blob(radius_mm=size, center_mm=center, coefficients=a.tolist(), subdivisions=cfg["subdivisions"])
    if family == "superquadric":
        aspect = _range(family, "aspect", cfg["aspect"], lo=0.0, hi=1.0)
        if aspect[0] <= 0:
            raise OptionError(f"superquadric aspect must be > 0, got {cfg['aspect']!r}")
        lo, hi = SUPERQUADRIC_EXPONENTS
        ex = _range(family, "exponents", cfg["exponents"], lo=lo, hi=hi)
        t = rng.uniform(*aspect, size=3)
        radii = size * t / t.max()
        exps = rng.uniform(*ex, size=2)
        q = (1.0, 0.0, 0.0, 0.0)
        if cfg["rotate"]:
            q = rng.standard_normal(4)
            q = (q / np.linalg.norm(q)).tolist()
        return superquadric(radii_mm=radii.tolist(), exponents=exps.tolist(), center_mm=center, rotation=q,
                            resolution=cfg["resolution"])
    side = 2.0 * size
    nb = _range(family, "n_bumps", cfg["n_bumps"], lo=0, hi=1000, integer=True)
    heights = _range(family, "height", cfg["height"], lo=0.0)
    sigmas = _range(family, "sigma", cfg["sigma"], lo=0.0)
    if sigmas[0] <= 0:
        raise OptionError(f"heightfield sigma must be > 0, got {cfg['sigma']!r}")
    spread = check_number("heightfield spread", cfg["spread"], lo=0.0, hi=0.5)
    dimples = check_number("heightfield dimples", cfg["dimples"], lo=0.0, hi=1.0)
    n = int(rng.integers(nb[0], nb[1], endpoint=True))
    xy = rng.uniform(-spread, spread, size=(n, 2)) * side
    sig = rng.uniform(*sigmas, size=n) * side
    h = rng.uniform(*heights, size=n) * side
    h = np.where(rng.random(n) < dimples, -h, h)
    bumps = np.column_stack([xy, h, sig]).tolist()
    return heightfield(size_mm=side, bumps=bumps, resolution=cfg["resolution"])
