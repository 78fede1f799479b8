"""Random smooth objects (shinysim.objects.shapes) and meshes in Mitsuba scenes (shinysim.sim.meshes)."""

import json

import numpy as np
import pytest
from conftest import requires_jit
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from shinysim.errors import OptionError, ShinysimError
from shinysim.objects import shapes
from shinysim.objects.shapes import (
    SHAPE_FAMILIES,
    TriangleMesh,
    blob,
    face_areas,
    heightfield,
    normals_at,
    random_shape,
    rebuild,
    shape_topology_key,
    signed_volume,
    superquadric,
)

CLOSED = ("blob", "superquadric")
#: Coarser resolutions for the many draws of the property tests (same distributions).
COARSE = {"blob": {"subdivisions": 3}, "superquadric": {"resolution": (24, 48)}, "heightfield": {"resolution": 33}}


def angle(a, b):
    """Angle, radians, between unit vectors along the last axis (accurate near 0, unlike arccos of a dot)."""
    return 2.0 * np.arcsin(np.clip(0.5 * np.linalg.norm(np.asarray(a) - np.asarray(b), axis=-1), 0.0, 1.0))


def unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


@pytest.fixture(scope="module")
def members():
    """One default-resolution random member of each family (seeded)."""
    return {f: random_shape(f, np.random.default_rng(7)) for f in SHAPE_FAMILIES}


# -- the parametric surfaces, for finite differences ------------------------------------------

def tangent_basis(u):
    e = np.where(np.abs(u[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t1 = unit(np.cross(u, e))
    return t1, np.cross(u, t1)


def blob_point(mesh, w):
    rel, _ = shapes._blob_surface(unit(w), np.asarray(mesh.params["coefficients"]))
    return np.asarray(mesh.params["center_mm"]) + mesh.params["radius_mm"] * rel[:, None] * unit(w)


def superquadric_point(mesh, eta, omega):
    prm = mesh.params
    p, _ = shapes._superquadric_local(eta, omega, prm["radii_mm"], *prm["exponents"])
    rot = shapes._quaternion_matrix(np.asarray(prm["rotation"]))
    return np.asarray(prm["center_mm"]) + p @ rot.T


def heightfield_point(mesh, x, y):
    z, _ = shapes._heightfield_surface(x, y, np.asarray(mesh.params["bumps"]).reshape(-1, 4))
    return np.stack([x, y, z], axis=-1)


# Central differences: the normal from the difference tangents errs by the truncation, about
# (h^2 / 6) |X'''| / |X'|, plus rounding, about eps / h. On these surfaces the truncation term measures
# at most 2.6 h^2 (it scales as h^2 from h = 1e-3 to 1e-4: 2.6e-6 to 2.6e-8 on the height field, less on
# the others), so at h = 1e-5 both stay below 3e-10. The tolerance leaves a factor 30; a wrong term in
# a normal formula (an exponent, a missing 1 / a) errs by 1e-3 or more.
FD_STEP = 1e-5
FD_TOL = 1e-8  # radians


def test_blob_normals_match_finite_differences(members):
    m = members["blob"]
    rng = np.random.default_rng(0)
    u = unit(rng.standard_normal((500, 3)))
    t1, t2 = tangent_basis(u)
    h = FD_STEP
    d1 = (blob_point(m, u + h * t1) - blob_point(m, u - h * t1)) / (2 * h)
    d2 = (blob_point(m, u + h * t2) - blob_point(m, u - h * t2)) / (2 * h)
    fd = unit(np.cross(d1, d2))  # t1 x t2 = u: outward
    assert angle(fd, normals_at(m, blob_point(m, u))).max() < FD_TOL


def test_superquadric_normals_match_finite_differences(members):
    m = members["superquadric"]
    rng = np.random.default_rng(1)
    # away (>= 0.1 rad) from the lines where Barr's parametrisation is singular (cos or sin = 0)
    eta = rng.choice([-1, 1], 500) * rng.uniform(0.1, 0.5 * np.pi - 0.1, 500)
    omega = rng.integers(0, 4, 500) * 0.5 * np.pi + rng.uniform(0.1, 0.5 * np.pi - 0.1, 500)
    h = FD_STEP
    d_eta = (superquadric_point(m, eta + h, omega) - superquadric_point(m, eta - h, omega)) / (2 * h)
    d_omega = (superquadric_point(m, eta, omega + h) - superquadric_point(m, eta, omega - h)) / (2 * h)
    fd = unit(np.cross(d_omega, d_eta))  # d_omega x d_eta points outwards (at eta = omega = 0: y x z = x)
    assert angle(fd, normals_at(m, superquadric_point(m, eta, omega))).max() < FD_TOL


def test_heightfield_normals_match_finite_differences(members):
    m = members["heightfield"]
    rng = np.random.default_rng(2)
    s = m.params["size_mm"]
    x, y = rng.uniform(-0.5 * s, 0.5 * s, (2, 500))
    h = FD_STEP
    dx = (heightfield_point(m, x + h, y) - heightfield_point(m, x - h, y)) / (2 * h)
    dy = (heightfield_point(m, x, y + h) - heightfield_point(m, x, y - h)) / (2 * h)
    assert angle(unit(np.cross(dx, dy)), normals_at(m, heightfield_point(m, x, y))).max() < FD_TOL


@pytest.mark.parametrize("family", SHAPE_FAMILIES)
def test_vertex_normals_are_the_analytic_ones(members, family):
    """The mesh's normals are those of its smooth surface at each vertex (not face averages)."""
    m = members[family]
    # the same formulas through a different route (a point's parameters recovered from its position)
    np.testing.assert_allclose(normals_at(m, m.vertices), m.normals, rtol=0, atol=1e-12)


def test_harmonics_orthonormal():
    """sqrt(4 pi) Y_lm have unit mean square and are orthogonal: Gauss-Legendre in cos(theta) (12 nodes,
    exact to degree 23) times 24 equal steps in phi (exact for trigonometric degree < 24) integrates
    their products, polynomials of degree <= 8, exactly; what remains is rounding."""
    z, w = np.polynomial.legendre.leggauss(12)
    phi = 2 * np.pi * np.arange(24) / 24
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    r = np.sqrt(1 - zz**2)
    u = np.stack([r * np.cos(pp), r * np.sin(pp), zz], axis=-1).reshape(-1, 3)
    weight = np.repeat(w, 24) * (2 * np.pi / 24) / (4 * np.pi)
    values, grads, degrees = shapes.real_spherical_harmonics(u)
    np.testing.assert_allclose((values * weight[:, None]).T @ values, np.eye(shapes.BLOB_N_COEFFICIENTS),
                               atol=1e-13)
    # homogeneous of degree l (Euler): u . grad Y = l Y
    np.testing.assert_allclose(np.einsum("nkc,nc->nk", grads, u), values * degrees, atol=1e-12)
    assert list(degrees) == [2] * 5 + [3] * 7 + [4] * 9


def test_exact_special_cases():
    """No coefficients: a sphere; exponents 1, 1: an ellipsoid. Both with their exact normals."""
    s = blob(radius_mm=0.5, center_mm=(0.1, -0.2, 0.3), subdivisions=3)
    d = s.vertices - [0.1, -0.2, 0.3]
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 0.5, rtol=1e-15)
    np.testing.assert_allclose(s.normals, d / 0.5, atol=1e-15)
    a, b, c = 0.9, 0.6, 0.4
    e = superquadric(radii_mm=(a, b, c), exponents=(1.0, 1.0), resolution=(16, 32))
    x, y, z = e.vertices.T
    np.testing.assert_allclose((x / a) ** 2 + (y / b) ** 2 + (z / c) ** 2, 1.0, rtol=1e-14)
    np.testing.assert_allclose(e.normals, unit(e.vertices / [a**2, b**2, c**2]), atol=1e-14)
    # the icosphere's volume approaches the ball's as its facets shrink (chord error ~ edge^2 / 8)
    fine = blob(radius_mm=1.0, subdivisions=5)
    assert 0.999 < signed_volume(fine) / (4 / 3 * np.pi) < 1.0


@pytest.mark.parametrize("family", SHAPE_FAMILIES)
def test_orientation(members, family):
    m = members[family]
    np.testing.assert_allclose(np.linalg.norm(m.normals, axis=1), 1.0, rtol=0, atol=1e-12)
    # every face winds the way its vertex normals point (counter-clockwise seen from outside)
    v = m.vertices[m.faces]
    face_n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    assert np.all(np.einsum("ij,ij->i", face_n, m.normals[m.faces].sum(axis=1)) > 0)
    if family in CLOSED:
        # closed and consistently wound: each directed edge once, and its reverse once
        edges = np.concatenate([m.faces[:, [0, 1]], m.faces[:, [1, 2]], m.faces[:, [2, 0]]])
        fwd = {tuple(e) for e in edges.tolist()}
        assert len(fwd) == len(edges) and all((b, a) in fwd for a, b in fwd)
        assert signed_volume(m) > 0
        # convex (superquadric, e <= 1) or star-shaped about the centre (blob): normals point away from it
        centre = np.asarray(m.params["center_mm"])
        assert np.all(np.einsum("ij,ij->i", m.vertices - centre, m.normals) > 0)
    else:
        assert np.all(m.normals[:, 2] > 0)
        assert abs(m.vertices[:, :2]).max() == pytest.approx(0.5 * m.params["size_mm"])


@pytest.mark.parametrize("family", SHAPE_FAMILIES)
def test_fixed_topology_and_reproducible(family):
    a = random_shape(family, np.random.default_rng(1))
    b = random_shape(family, np.random.default_rng(2))
    again = random_shape(family, np.random.default_rng(1))
    assert shape_topology_key(a) == shape_topology_key(b) == (family, a.n_vertices, a.n_faces)
    np.testing.assert_array_equal(a.faces, b.faces)
    assert not np.array_equal(a.vertices, b.vertices)
    for field in ("vertices", "faces", "normals"):
        assert getattr(a, field).tobytes() == getattr(again, field).tobytes()
    assert a.params == again.params
    assert a.vertices.dtype == np.float64 and a.faces.dtype == np.int32
    with pytest.raises(ValueError):
        a.vertices[0, 0] = 1.0  # read-only


@pytest.mark.parametrize("family", SHAPE_FAMILIES)
def test_params_rebuild_exactly(members, family):
    m = members[family]
    params = json.loads(json.dumps(m.params))  # plain JSON, as a data set's item file keeps it
    for again in (rebuild(m.name, params), getattr(shapes, m.name)(**params)):
        for field in ("vertices", "faces", "normals"):
            np.testing.assert_array_equal(getattr(again, field), getattr(m, field))


# The smallest face of any draw, relative to the median face: 0.045 worst over 200 superquadrics (its
# grid cells shrink towards the poles and the boxy edges), ~0.7 for blobs and ~0.9 for height fields; a
# thousandth is far from a degenerate (zero-area) face yet well below what the families give.
MIN_AREA_RATIO = 1e-3


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(family=st.sampled_from(SHAPE_FAMILIES), seed=st.integers(0, 2**63 - 1),
       size=st.floats(0.05, 5.0))
def test_random_shapes_are_valid(family, seed, size):
    m = random_shape(family, np.random.default_rng(seed), size_mm=size, **COARSE[family])
    assert np.all(np.isfinite(m.vertices)) and np.all(np.isfinite(m.normals))
    np.testing.assert_allclose(np.linalg.norm(m.normals, axis=1), 1.0, rtol=0, atol=1e-12)
    areas = face_areas(m)
    assert areas.min() > MIN_AREA_RATIO * np.median(areas)
    if family in CLOSED:
        assert signed_volume(m) > 0
        assert np.all(np.einsum("ij,ij->i", m.vertices - m.params["center_mm"], m.normals) > 0)
        r = np.linalg.norm(m.vertices, axis=1)
        if family == "blob":  # the radius stays within R (1 +- amplitude), amplitude <= 0.4
            assert size * 0.6 * (1 - 1e-12) <= r.min() and r.max() <= size * 1.4 * (1 + 1e-12)
        else:  # inside the box of its semi-axes, the largest of which is the size
            assert r.max() <= size * np.sqrt(3) * (1 + 1e-12)
            assert max(m.params["radii_mm"]) == pytest.approx(size, rel=1e-15)
    else:
        assert np.all(m.normals[:, 2] > 0)
    np.testing.assert_allclose(normals_at(m, m.vertices), m.normals, atol=1e-10)


def test_bad_parameters():
    with pytest.raises(OptionError, match="exponents"):
        superquadric(exponents=(1.5, 1.0))
    with pytest.raises(OptionError, match="< 0.95"):
        blob(coefficients=[0.5] * shapes.BLOB_N_COEFFICIENTS)
    with pytest.raises(OptionError, match="21 finite numbers"):
        blob(coefficients=[0.0] * 3)
    with pytest.raises(OptionError, match="sigma"):
        heightfield(bumps=[(0.0, 0.0, 0.1, 0.0)])
    with pytest.raises(OptionError, match="did you mean 'blob'"):
        random_shape("blobb", np.random.default_rng(0))
    with pytest.raises(OptionError, match="did you mean 'amplitude'"):
        random_shape("blob", np.random.default_rng(0), amplitudes=(0.1, 0.2))
    with pytest.raises(OptionError, match="radius_mm"):
        blob(radius_mm=-1.0)
    with pytest.raises(ValueError, match="unit"):
        TriangleMesh(np.eye(3), [[0, 1, 2]], 2 * np.eye(3), "mesh", {})
    with pytest.raises(OptionError, match="center_mm"):
        random_shape("heightfield", np.random.default_rng(0), center_mm=(1.0, 0.0, 0.0))


@pytest.mark.parametrize("family", CLOSED)
def test_random_shape_centre_takes_no_draws(family):
    """A centre moves the shape and leaves the draws alone."""
    here = random_shape(family, np.random.default_rng(5), **COARSE[family])
    there = random_shape(family, np.random.default_rng(5), center_mm=(0.5, -0.25, 0.125), **COARSE[family])
    np.testing.assert_allclose(there.vertices - here.vertices, np.tile([0.5, -0.25, 0.125], (here.n_vertices, 1)),
                               atol=1e-15)
    np.testing.assert_array_equal(there.normals, here.normals)


# -- users' meshes (trimesh, no renderer) ------------------------------------------------------

def _trimesh():
    return pytest.importorskip("trimesh")


@pytest.mark.parametrize("suffix", [".ply", ".obj"])
def test_user_mesh_round_trip(tmp_path, suffix):
    trimesh = _trimesh()
    from shinysim.sim.meshes import load_user_mesh

    src = random_shape("blob", np.random.default_rng(3), **COARSE["blob"])
    path = tmp_path / f"part{suffix}"
    trimesh.Trimesh(src.vertices, src.faces, process=False).export(path)
    m = load_user_mesh(path, center_mm=None)
    # OBJ keeps about 8 significant digits, PLY float64: the same geometry either way
    np.testing.assert_allclose(m.vertices, src.vertices, atol=1e-7)
    np.testing.assert_array_equal(m.faces, src.faces)
    assert m.name == "mesh" and shape_topology_key(m) == ("mesh", src.n_vertices, src.n_faces)
    # the mesh's own normals (angle-weighted face normals): close to the analytic ones at this resolution
    assert angle(m.normals, src.normals).max() < np.radians(3)
    again = load_user_mesh(**m.params)
    np.testing.assert_array_equal(again.vertices, m.vertices)
    # placed: largest side 2 mm, bounding box bottom centre at (1, 2, 0)
    placed = load_user_mesh(path, fit_mm=2.0, center_mm=(1.0, 2.0, 0.0))
    lo, hi = placed.vertices.min(axis=0), placed.vertices.max(axis=0)
    assert np.max(hi - lo) == pytest.approx(2.0, rel=1e-12)
    np.testing.assert_allclose([*(0.5 * (lo + hi))[:2], lo[2]], [1.0, 2.0, 0.0], atol=1e-12)
    centred = load_user_mesh(path, scale_to_mm=2.0, anchor="center", center_mm=(0, 0, 0))
    np.testing.assert_allclose(0.5 * (centred.vertices.min(0) + centred.vertices.max(0)), 0, atol=1e-12)


def test_user_mesh_turned_outwards(tmp_path):
    """A closed mesh wound inwards is turned outwards, faces and normals."""
    trimesh = _trimesh()
    from shinysim.sim.meshes import load_user_mesh

    src = blob(subdivisions=2)
    path = tmp_path / "inside_out.ply"
    trimesh.Trimesh(src.vertices, src.faces[:, ::-1], process=False).export(path)
    m = load_user_mesh(path, center_mm=None)
    assert signed_volume(m) > 0
    assert np.all(np.einsum("ij,ij->i", m.vertices, m.normals) > 0)


def test_user_mesh_several_parts_and_file_normals(tmp_path):
    """Objects and material groups are concatenated into one mesh; the file's own normals are kept."""
    _trimesh()
    from shinysim.sim.meshes import load_user_mesh

    tri = "v 0 0 {z}\nv 1 0 {z}\nv 0 1 {z}\n"
    for name, text in {"objects.obj": "o a\n" + tri.format(z=0) + "f 1 2 3\no b\n" + tri.format(z=1) + "f 4 5 6\n",
                       "materials.obj": "usemtl red\n" + tri.format(z=0) + "f 1 2 3\nusemtl blue\n"
                                        + tri.format(z=1) + "f 4 5 6\n"}.items():
        (tmp_path / name).write_text(text)
        m = load_user_mesh(tmp_path / name, center_mm=None)
        assert (m.n_vertices, m.n_faces) == (6, 2) and sorted(m.vertices[:, 2]) == [0, 0, 0, 1, 1, 1]
        np.testing.assert_allclose(m.normals, np.tile([0.0, 0.0, 1.0], (6, 1)), atol=1e-12)
    (tmp_path / "tilted.obj").write_text(tri.format(z=0) + "vn 0 0.6 0.8\nf 1//1 2//1 3//1\n")
    np.testing.assert_allclose(load_user_mesh(tmp_path / "tilted.obj").normals, [[0, 0.6, 0.8]] * 3, atol=1e-7)


BAD_MESHES = {
    "missing.ply": (None, "no such mesh file"),
    "part.stl": (b"solid x\nendsolid x\n", "unsupported mesh type"),
    "garbage.ply": (b"ply\nformat binary_little_endian 1.0\nelement vertex 99\nend_header\n\x00\x01",
                    "cannot read|no faces|holds no"),
    "points.ply": ((b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                    b"property float z\nend_header\n0 0 0\n1 0 0\n0 1 0\n"), "no faces|holds no"),
    "nan.obj": (b"v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n", "not finite"),
    "flat.obj": (b"v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n", "zero area"),
    "empty.obj": (b"", "no faces|holds no|cannot read"),
}


@pytest.mark.parametrize("name", sorted(BAD_MESHES))
def test_bad_user_meshes_name_the_file(tmp_path, name):
    _trimesh()
    from shinysim.sim.meshes import load_user_mesh

    content, message = BAD_MESHES[name]
    path = tmp_path / name
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(ShinysimError, match=message) as info:
        load_user_mesh(path)
    assert info.value.path == str(path) and str(info.value).startswith(str(path))


def test_mesh_object_is_plain_data(tmp_path, members):
    """The shape dict needs no renderer, writes its PLY once, and goes into the scene's XML."""
    _trimesh()
    from shinysim.rig import shiny_1988
    from shinysim.sim.meshes import mesh_object
    from shinysim.sim.scene import rough_conductor, scene_dict, scene_xml

    m = members["heightfield"]
    d = mesh_object(m, bsdf=rough_conductor(0.02), folder=tmp_path)
    assert d["type"] == "ply" and d["bsdf"]["alpha"] == 0.02
    assert mesh_object(m, bsdf=rough_conductor(0.05), folder=tmp_path)["filename"] == d["filename"]
    assert len(list(tmp_path.iterdir())) == 1
    xml = scene_xml(scene_dict(shiny_1988(resolution=64), {"object": d}))
    assert '<shape type="ply" id="object">' in xml and d["filename"] in xml


# -- in Mitsuba scenes -------------------------------------------------------------------

RES = 64  # pixels a side: ~1300-2400 hits on the objects, renders of a few tens of ms


@pytest.fixture(scope="module")
def rig():
    from shinysim.rig import shiny_1988

    return shiny_1988(resolution=RES)


def _simulator(rig, mesh):
    from shinysim.sim.meshes import mesh_object
    from shinysim.sim.render import Simulator
    from shinysim.sim.scene import rough_conductor

    return Simulator(rig, {"object": mesh_object(mesh, bsdf=rough_conductor(0.02))})


def _hit_faces(sim, mesh, points):
    """For each point on the mesh: the face Mitsuba finds on the camera ray through it, and the point's
    barycentric coordinates there."""
    import mitsuba as mi

    origin = sim.rig.cameras[sim.camera_index].position
    d = unit(points - origin)
    ray = mi.Ray3f(mi.Point3f(*[np.full(len(points), c, np.float32) for c in origin]),
                   mi.Vector3f(*[np.ascontiguousarray(d[:, k], np.float32) for k in range(3)]))
    si = sim.scene.ray_intersect(ray)
    assert np.all(np.array(si.is_valid()))
    faces = np.array(si.prim_index).astype(np.int64)
    a, b, c = (mesh.vertices[mesh.faces[faces, k]] for k in range(3))
    e1, e2, dp = b - a, c - a, points - a
    d11, d12, d22 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
    p1, p2 = (dp * e1).sum(1), (dp * e2).sum(1)
    den = d11 * d22 - d12**2
    w1, w2 = (d22 * p1 - d12 * p2) / den, (d11 * p2 - d12 * p1) / den
    bary = np.stack([1 - w1 - w2, w1, w2], axis=1)
    off = np.linalg.norm(dp - w1[:, None] * e1 - w2[:, None] * e2, axis=1)
    # on the face, to float32 hit points (1e-7 mm against faces tens of micrometres across)
    assert bary.min() > -1e-4 and off.max() < 1e-5
    return faces, bary


def _face_bounds(mesh, faces, steps=8):
    """Largest angle between the interpolated and the analytic normal on each face, over a barycentric grid."""
    ij = [(i, j) for i in range(steps + 1) for j in range(steps + 1 - i)]
    b = np.array([(i / steps, j / steps, 1 - (i + j) / steps) for i, j in ij])  # (G, 3)
    v = mesh.vertices[mesh.faces[faces]]  # (N, 3, 3)
    n = mesh.normals[mesh.faces[faces]]
    x = np.einsum("gk,nkc->ngc", b, v)
    phong = unit(np.einsum("gk,nkc->ngc", b, n))
    return angle(phong, normals_at(mesh, x)).max(axis=1)


@requires_jit
@pytest.mark.parametrize("family", SHAPE_FAMILIES)
def test_truth_normals_are_the_analytic_ones_up_to_interpolation(rig, members, family):
    """The renderer's normal at a hit is the mesh's vertex normals interpolated across the hit face,
    so it differs from the smooth surface's normal there by at most the interpolation error of
    that face. That error is measured on a barycentric grid of step 1/8 over each hit face; it is a
    smooth function that vanishes at the vertices (largest near the centroid, which the grid misses
    by under 5 %), so 1.25 times the grid's maximum bounds it, plus 2e-5 rad for float32 hit points,
    barycentrics and normals."""
    m = members[family]
    sim = _simulator(rig, m)
    truth = sim.render_truth()
    hit = truth.mask
    assert hit.sum() > 1000
    n = truth.normals[hit].astype(float)
    p = truth.positions[hit].astype(float)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-6)
    faces, bary = _hit_faces(sim, m, p)
    # exactly the mesh's normals, interpolated (Phong), to float32 rounding (normals stored to 6e-8,
    # barycentrics from float32 hit points; 2.5e-7 rad seen)
    phong = unit(np.einsum("nk,nkc->nc", bary, m.normals[m.faces[faces]]))
    assert angle(n, phong).max() < 1e-6
    err = angle(n, normals_at(m, p))
    bound = 1.25 * _face_bounds(m, faces) + 2e-5
    assert np.all(err <= bound), (err.max(), bound[np.argmax(err - bound)])
    # and the default resolutions resolve the surfaces: a blob to a hundredth of a degree, a height field
    # to a few hundredths, a superquadric (whose boxy edges bend fastest) to a few tenths (seen: medians
    # 0.003, 0.008, 0.05 deg, largest 0.01, 0.05, 0.33 deg)
    median_deg, max_deg = {"blob": (0.01, 0.03), "heightfield": (0.03, 0.15), "superquadric": (0.15, 1.0)}[family]
    assert np.degrees(np.median(err)) < median_deg and np.degrees(err.max()) < max_deg


@requires_jit
def test_update_mesh_equals_a_fresh_load(rig):
    """Changing a loaded scene's mesh in place gives the truth and, with the same seed, the stack of
    a freshly loaded scene, bit for bit: what makes reusing one scene for many items safe."""
    from shinysim.sim.meshes import update_mesh

    a = random_shape("blob", np.random.default_rng(11))
    b = random_shape("blob", np.random.default_rng(12))
    sim = _simulator(rig, a)
    truth_a = sim.render_truth()
    sim.render_stack(spp=2, seed=1)  # fills the simulator's caches of the first shape
    update_mesh(sim, "object", b)
    fresh = _simulator(rig, b)
    t_upd, t_new = sim.render_truth(), fresh.render_truth()
    assert not np.array_equal(t_upd.mask, truth_a.mask)
    for field in ("normals", "positions", "mask", "part"):
        np.testing.assert_array_equal(getattr(t_upd, field), getattr(t_new, field))
    s_upd, s_new = sim.render_stack(spp=4, seed=5), fresh.render_stack(spp=4, seed=5)
    assert s_upd.frames.max() > 0
    np.testing.assert_array_equal(s_upd.frames, s_new.frames)
    update_mesh(sim, "object", a)  # and back
    np.testing.assert_array_equal(sim.render_truth().normals, truth_a.normals)


@requires_jit
def test_update_mesh_refuses_another_topology(rig, members):
    from shinysim.sim.meshes import update_mesh

    sim = _simulator(rig, members["blob"])
    with pytest.raises(ValueError, match="10242 vertices and 20480 faces.*different topology"):
        update_mesh(sim, "object", members["superquadric"])
    with pytest.raises(ValueError, match="no mesh 'lid'"):
        update_mesh(sim, "lid", members["blob"])
    coarse = random_shape("blob", np.random.default_rng(0), subdivisions=4)
    with pytest.raises(ValueError, match="different topology"):
        update_mesh(sim, "object", coarse)


@requires_jit
def test_user_mesh_renders_like_the_shape(tmp_path, rig, members):
    """A user's PLY of a blob, read back, images the same silhouette as the blob itself."""
    trimesh = _trimesh()
    from shinysim.sim.meshes import load_user_mesh

    m = members["blob"]
    path = tmp_path / "blob.ply"
    trimesh.Trimesh(m.vertices, m.faces, process=False).export(path)
    user = load_user_mesh(path, center_mm=None)
    t_user, t_blob = _simulator(rig, user).render_truth(), _simulator(rig, m).render_truth()
    np.testing.assert_array_equal(t_user.mask, t_blob.mask)
    # same geometry: the hit points agree to float32; normals differ by the interpolation of face normals
    hit = t_blob.mask
    np.testing.assert_allclose(t_user.positions[hit], t_blob.positions[hit], atol=1e-5)
    assert np.degrees(angle(t_user.normals[hit].astype(float), t_blob.normals[hit].astype(float))).max() < 1.0

