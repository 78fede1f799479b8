"""Structured-highlight stereo matching (shinysim.recon.stereo) on exact mirror geometry, no renderer.

Highlights come from analytic geometry: either chosen surface elements with,
for each camera, a source placed by reflection (``E + L reflect(view, n)``),
or a mirror sphere under a dense dome of sources
(:func:`shinysim.theory.mirror.mirror_sphere_highlight`, exact to rounding),
projected with :meth:`Camera.project`.
"""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest

from shinysim.errors import OptionError, StereoError
from shinysim.recon.stereo import (
    STEREO_COLUMNS,
    StereoParams,
    candidate_pairs,
    candidate_pairs_naive,
    highlight_rays,
    match_highlights,
)
from shinysim.rig import Camera, Rig, fibonacci_hemisphere, stereo_pair
from shinysim.theory.mirror import mirror_sphere_highlight

R_SPHERE = 0.794  # the SHINY calibration sphere (1/16 in across)
L_SOURCE = 43.18  # the SHINY array radius


def _camera(projection="perspective", position=(0.0, 0.0, 127.0), field=6.0):
    return Camera(projection, 512, 512, list(position), [0.0, 0.0, 0.0], [0.0, 1.0, 0.0], field)


def _pair(beta, projection="perspective"):
    base = Rig(np.array([[0.0, 0.0, L_SOURCE]]), np.zeros(1), (_camera(projection),))
    return stereo_pair(base, beta_deg=beta).cameras


def _mirror_sources(cameras, elements, normals):
    """For each camera, a source that element k reflects into it: S = E + L reflect(view, n)."""
    out = []
    for cam, E, n in zip(cameras, elements, normals):
        v = cam.view_directions(E)
        out.append(E + L_SOURCE * (2 * np.sum(n * v, 1)[:, None] * n - v))
    return out


def _rays_from_elements(cameras, elements, normals):
    """Rig (one source per element per camera) and both cameras' HighlightRays."""
    srcs = _mirror_sources(cameras, elements, normals)
    rig = Rig(np.concatenate(srcs), np.zeros(sum(len(s) for s in srcs)), tuple(cameras))
    rays, offset = [], 0
    for k, (cam, E) in enumerate(zip(cameras, elements)):
        row, col = cam.project(E)
        rays.append(highlight_rays(row, col, offset + np.arange(len(E)), rig, k))
        offset += len(E)
    return rig, rays


def _cap_normals(step_deg, cap_deg):
    g = np.radians(np.arange(-cap_deg, cap_deg + 1e-9, step_deg))
    tx, ty = np.meshgrid(g, g)
    keep = np.hypot(tx, ty) <= np.radians(cap_deg) + 1e-12
    n = np.column_stack([np.tan(tx[keep]), np.tan(ty[keep]), np.ones(keep.sum())])
    return n / np.linalg.norm(n, axis=1)[:, None]


# -- exact pairs -------------------------------------------------------------------------------------


@pytest.mark.parametrize("projection", ["perspective", "orthographic"])
@pytest.mark.parametrize("beta", [15.0, 30.0, 45.0])
def test_exact_pairs_recovered_to_rounding(beta, projection):
    cams = _pair(beta, projection)
    centre = np.array([0.3, -0.2, -0.5])
    rng = np.random.default_rng(int(beta))
    th, ph = np.radians(rng.uniform(0, 30, 40)), rng.uniform(0, 2 * np.pi, 40)
    n = np.column_stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)])
    E = centre + R_SPHERE * n
    rig, (r1, r2) = _rays_from_elements(cams, (E, E), (n, n))
    # the construction is the sphere's own highlight: the exact solver puts it on E (rounding of an
    # 80-step bisection of the angle, ~1e-16 rad times 0.8 mm)
    for k, cam in enumerate(cams):
        S = rig.source_positions[k * len(E):(k + 1) * len(E)]
        if projection == "perspective":
            P, _ = mirror_sphere_highlight(S, center=centre, radius=R_SPHERE, camera_position=cam.position)
        else:
            P, _ = mirror_sphere_highlight(S, center=centre, radius=R_SPHERE, view_direction=-cam.forward)
        assert np.max(np.abs(P - E)) < 1e-9
    res = match_highlights(r1, r2, rig, StereoParams(d0_mm=0.02, max_normal_gap_deg=1.0))
    # every element is matched to itself: the elements' normals differ by >= ~1 deg (random), the real pair
    # has D = 0 and gap = 0, so it wins every competition
    assert len(res) == len(E) and res.reason == ""
    assert np.array_equal(res.index1, np.arange(len(E))) and np.array_equal(res.index2, np.arange(len(E)))
    # numerical precision: rays rebuilt from projected pixels pass E to ~1e-13 mm (127 mm * 1e-15)
    assert np.max(np.linalg.norm(res.point - E, axis=1)) <= 1e-9
    ang = np.arctan2(np.linalg.norm(np.cross(res.normal, n), axis=1), np.sum(res.normal * n, 1))
    assert np.max(ang) <= 1e-9
    assert np.max(res.d_mm) <= 1e-9 and np.max(res.normal_gap_deg) <= 1e-7
    assert np.max(np.abs(res.e1_mm)) <= 1e-9 and np.max(np.abs(res.delta_z_mm)) <= 1e-9
    assert np.all((res.confidence >= 0) & (res.confidence <= 1))


def test_rays_from_a_highlight_table_are_the_rays_of_its_columns():
    """HighlightRays.from_table reads the table's row, col and source columns; anything else is refused."""
    from shinysim.io.table import HighlightTable
    from shinysim.recon.stereo import HighlightRays

    cams = _pair(20.0, "perspective")
    E = np.array([[0.1, 0.0, -0.4], [-0.2, 0.3, -0.5], [0.0, -0.1, -0.45]])
    n = np.tile([0.0, 0.0, 1.0], (3, 1))
    rig, (r1, _) = _rays_from_elements(cams, (E, E), (n, n))
    table = HighlightTable({"source": r1.sources, "row": r1.rows, "col": r1.cols, "area": np.ones(3, int),
                            "peak": np.ones(3), "sum": np.ones(3), "blob": np.ones(3, int), "part": np.ones(3, int)})
    got = HighlightRays.from_table(table, rig, 0)
    for name in ("rows", "cols", "sources", "origins", "directions"):
        assert np.array_equal(getattr(got, name), getattr(r1, name)), name
    with pytest.raises(StereoError, match="table: must be a HighlightTable, got dict"):
        HighlightRays.from_table(dict(table), rig, 0)


def test_reflectance_matching_planar_reduces_to_equal_offsets():
    """Orthographic cameras in the source plane: n* lies between n1 and n2 and E1 = E2 (Eq 32)."""
    cams = _pair(20.0, "orthographic")
    # camera 2 sees an element 0.01 mm beside camera 1's on a sphere, in the plane y = 0
    t = np.radians(np.array([-20.0, -5.0, 10.0, 25.0]))
    n1 = np.column_stack([np.sin(t), np.zeros_like(t), np.cos(t)])
    t2 = t + 0.01 / R_SPHERE
    n2 = np.column_stack([np.sin(t2), np.zeros_like(t2), np.cos(t2)])
    c = np.array([0.0, 0.0, -R_SPHERE])
    rig, (r1, r2) = _rays_from_elements(cams, (c + R_SPHERE * n1, c + R_SPHERE * n2), (n1, n2))
    res = match_highlights(r1, r2, rig, StereoParams(d0_mm=0.05, max_normal_gap_deg=2.0, relax=False))
    assert len(res) == 4
    # planar: all normals stay in the x-z plane, so does n*
    assert np.max(np.abs(res.normal[:, 1])) < 1e-12
    # the bracketing solve reaches E1 = E2 to its 1e-10 mm stop (or the arc's end with no root)
    has_root = np.abs(res.delta_z_mm) <= 1e-9
    assert np.all(np.abs(res.e1_mm[has_root] - res.e2_mm[has_root]) <= 1e-9)
    # with a root, n* lies on the arc between the normals at P1*, P2* (here 0.72 deg apart)
    assert np.all(res.normal_gap_deg > 0.5)


# -- the index equals the paper's O(N^2) search --------------------------------------------------------


def _random_scene(rng, cams, m=500, extra=150):
    """Elements of a random smooth surface seen by both cameras, plus elements seen by one only."""
    def surface(k):
        c, s, a = rng.uniform(-2, 2, (4, 2)), rng.uniform(0.5, 1.5, 4), rng.uniform(-0.3, 0.3, 4)
        xy = rng.uniform(-2, 2, (k, 2))
        dx = xy[:, None, :] - c[None]
        g = a * np.exp(-np.sum(dx**2, -1) / (2 * s**2))
        grad = np.sum((-dx / (s**2)[:, None]) * g[..., None], 1)
        n = np.column_stack([-grad, np.ones(k)])
        return np.column_stack([xy, g.sum(1)]), n / np.linalg.norm(n, axis=1)[:, None]

    E, n = surface(m)
    X1, m1 = surface(extra)
    X2, m2 = surface(extra)
    rig, (r1, r2) = _rays_from_elements(cams, (np.concatenate([E, X1]), np.concatenate([E, X2])),
                                        (np.concatenate([n, m1]), np.concatenate([n, m2])))
    # centroid noise of 0.2 pixel: nothing is exact
    jitter = lambda r, k: highlight_rays(r.rows + rng.normal(0, 0.2, len(r)), r.cols + rng.normal(0, 0.2, len(r)),
                                         r.sources, rig, k)
    return rig, jitter(r1, 0), jitter(r2, 1)


@pytest.mark.parametrize("kind", ["perspective", "orthographic", "mixed"])
def test_indexed_candidates_equal_naive(kind):
    rng = np.random.default_rng({"perspective": 1, "orthographic": 2, "mixed": 3}[kind])
    if kind == "perspective":
        cams = (_camera(position=(33, 0, 120)), _camera(position=(-33, 4, 120)))
    elif kind == "orthographic":
        cams = (_camera("orthographic", (60, 5, 110)), _camera("orthographic", (-50, 0, 110)))
    else:
        cams = (_camera("orthographic", (33, 0, 120)), _camera(position=(-40, 20, 120)))
    rig, r1, r2 = _random_scene(rng, cams)
    for zr in (None, (-0.5, 0.5)):
        # loose limits, so that thousands of pairs pass and the comparison has something to compare
        p = StereoParams(d0_mm=0.08, max_normal_gap_deg=8.0, depth_range_mm=zr)
        ni, nj = candidate_pairs_naive(r1, r2, rig, p)
        ii, jj = candidate_pairs(r1, r2, rig, p)
        assert len(ni) > 1000
        assert np.array_equal(ni, ii) and np.array_equal(nj, jj)


# -- a sphere under a dense dome -----------------------------------------------------------------------


def _dome_sphere(beta, centre):
    S = L_SOURCE * fibonacci_hemisphere(1000)
    base = Rig(S, np.zeros(len(S)), (_camera(),))
    rig = stereo_pair(base, beta_deg=beta)
    rays, elems = [], []
    for k, cam in enumerate(rig.cameras):
        P, _ = mirror_sphere_highlight(S, center=centre, radius=R_SPHERE, camera_position=cam.position)
        row, col = cam.project(P)
        rays.append(highlight_rays(row, col, np.arange(len(S)), rig, k))
        elems.append(P)
    return rig, rays, elems


@pytest.mark.parametrize("beta", [15.0, 30.0])
def test_dense_dome_sphere_accuracy_false_matches_recall(beta):
    centre = np.array([0.35, -0.25, -R_SPHERE + 0.1])
    rig, (r1, r2), (E1, E2) = _dome_sphere(beta, centre)
    gap0 = 1.5
    d0 = 0.02
    res = match_highlights(r1, r2, rig, StereoParams(d0_mm=d0, max_normal_gap_deg=gap0,
                                                     depth_range_mm=(-1.5, 0.5)))
    assert len(res) > 300
    # 1000 sources over an 80 deg cap are ~4 deg apart, so the elements of one camera are ~2 deg of normal
    # (0.028 mm on the sphere) apart and those of the other camera fall between them: a real pair is
    # delta <= ~0.02 mm apart. The normal test admits delta <= r * gap0 (normals differ by delta / r on a
    # sphere); two rays through points delta apart along the epipolar line cross delta / (2 tan beta)
    # off the surface, and the closest points are D / 2 <= D0 / 2 from their midpoint.
    tol = R_SPHERE * math.radians(gap0) / (2 * math.tan(math.radians(beta))) + d0 / 2
    off = np.abs(np.linalg.norm(res.point - centre, axis=1) - R_SPHERE)
    false_rate = float(np.mean(off > tol))
    assert false_rate == 0.0, (false_rate, off.max(), tol)
    # the two elements behind each match are within the normal test's reach (plus the 1/R term's ~1e-3 mm)
    sep = np.linalg.norm(E1[res.index1] - E2[res.index2], axis=1)
    assert sep.max() <= R_SPHERE * math.radians(gap0) * 1.05
    # recall: camera-1 highlights whose nearest camera-2 element is within eps = 0.006 mm (a fifth of the
    # element spacing: such a pair passes D < D0 and the normal test with a wide margin) are matched
    from scipy.spatial import cKDTree

    eps = 0.006
    d12, _ = cKDTree(E2).query(E1)
    matchable = d12 < eps
    matched = np.zeros(len(E1), bool)
    matched[res.index1] = True
    assert matchable.sum() > 40
    recall = float(np.mean(matched[matchable]))
    assert recall >= 0.95, recall


# -- ghosts: three identical spheres -------------------------------------------------------------------


def _ghost_scene():
    """Three identical spheres whose highlight rays cross: rig, both cameras' rays, the sphere of each
    element and the camera-1 normals."""
    cams = _pair(15.0)
    # offsets along the baseline (x) and in height: the rays of the same point on two spheres cross
    centres = np.array([[-1.2, 0.0, -R_SPHERE], [0.0, 0.0, -R_SPHERE + 0.3], [1.2, 0.0, -R_SPHERE - 0.3]])
    n = _cap_normals(3.0, 30.0)
    C = np.repeat(centres, len(n), 0)
    N1 = np.tile(n, (3, 1))
    sphere = np.repeat(np.arange(3), len(n))
    # camera 2 sees a neighbouring element of each camera-1 element (normal up to 0.4 deg away, as discrete
    # sources leave them), so real pairs are not exact and ghosts are not told apart by a zero residual
    rng = np.random.default_rng(3)
    a = rng.normal(size=N1.shape)
    a -= np.sum(a * N1, 1)[:, None] * N1
    a /= np.linalg.norm(a, axis=1)[:, None]
    N2 = N1 + np.radians(0.4) * np.sqrt(rng.random(len(N1)))[:, None] * a
    N2 /= np.linalg.norm(N2, axis=1)[:, None]
    rig, (r1, r2) = _rays_from_elements(cams, (C + R_SPHERE * N1, C + R_SPHERE * N2), (N1, N2))
    return rig, r1, r2, sphere, N1


def test_ghosts_of_identical_spheres_lose_in_relaxation():
    rig, r1, r2, sphere, N1 = _ghost_scene()
    p = StereoParams(d0_mm=0.02, max_normal_gap_deg=1.0)
    i, j = candidate_pairs(r1, r2, rig, p)
    ghost = sphere[i] != sphere[j]
    # before relaxation: every real pair, and ghosts on many highlights (measured: 951 real, 703 ghosts)
    assert np.sum(i == j) == len(N1)
    assert ghost.sum() > 300
    res = match_highlights(r1, r2, rig, p)
    final_ghost = float(np.mean(sphere[res.index1] != sphere[res.index2]))
    assert len(res) >= 0.99 * len(N1)
    assert final_ghost <= 0.01, final_ghost
    # uniqueness alone keeps ghosts (measured: 152 of 951); the relaxation is what removes them
    alone = match_highlights(r1, r2, rig, StereoParams(d0_mm=0.02, max_normal_gap_deg=1.0, relax=False))
    assert np.mean(sphere[alone.index1] != sphere[alone.index2]) > 0.05


# -- bad input -----------------------------------------------------------------------------------------


def _small_rig():
    cams = _pair(15.0)
    return Rig(np.array([[0.0, 0.0, L_SOURCE], [10.0, 0.0, 40.0]]), np.zeros(2), cams)


@pytest.mark.parametrize("args, field", [
    (([1.0, 2.0], [1.0], [0, 1], 0), "cols"),
    (([1.0, 2.0], [1.0, 2.0], [0], 0), "sources"),
    (([1.0], [1.0], [2], 0), "sources"),
    (([1.0], [1.0], [-1], 0), "sources"),
    (([np.nan], [1.0], [0], 0), "rows"),
    (([1.0], [1.0], [0], 2), "camera_index"),
    (([1.0], [1.0], [0], -1), "camera_index"),
])
def test_bad_input_names_the_field(args, field):
    rows, cols, sources, cam = args
    with pytest.raises(StereoError) as err:
        highlight_rays(rows, cols, sources, _small_rig(), cam)
    assert err.value.field == field


def test_one_camera_rig_and_same_camera_are_refused():
    rig = _small_rig()
    one = Rig(rig.source_positions, rig.source_radii, (rig.cameras[0],))
    with pytest.raises(StereoError) as err:
        highlight_rays([1.0], [1.0], [0], one, 0)
    assert err.value.field == "cameras"
    r = highlight_rays([1.0], [1.0], [0], rig, 0)
    with pytest.raises(StereoError) as err:
        match_highlights(r, r, rig)
    assert err.value.field == "rays2.camera"
    with pytest.raises(StereoError) as err:
        match_highlights(r, highlight_rays([1.0], [1.0], [0], rig, 1), one)
    assert err.value.field == "cameras"


def test_no_candidates_gives_empty_matches_with_reason():
    rig = _small_rig()
    # opposite image corners: the rays are far apart across the epipolar planes
    r1 = highlight_rays([0.0], [0.0], [0], rig, 0)
    r2 = highlight_rays([511.0], [511.0], [1], rig, 1)
    res = match_highlights(r1, r2, rig)
    assert len(res) == 0 and "D0" in res.reason
    # the index rules the pair out untested; whatever it examined failed the distance test
    assert res.n_candidates == 0 and res.n_rejected_distance == res.n_examined <= 1
    empty = match_highlights(highlight_rays([], [], [], rig, 0), r2, rig)
    assert len(empty) == 0 and "no highlights" in empty.reason


def test_to_csv_reads_back(tmp_path):
    cams = _pair(30.0)
    n = _cap_normals(6.0, 24.0)
    E = np.array([0.1, 0.2, -R_SPHERE]) + R_SPHERE * n
    rig, (r1, r2) = _rays_from_elements(cams, (E, E), (n, n))
    res = match_highlights(r1, r2, rig, StereoParams(d0_mm=0.02))
    path = res.to_csv(tmp_path / "matches.csv")
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    assert tuple(rows[0]) == STEREO_COLUMNS == res.columns()
    assert len(rows) == len(res) + 1 > 10
    table = np.array(rows[1:], dtype=float)
    d = res.as_dict()
    for k, name in enumerate(STEREO_COLUMNS):
        # floats written with repr read back exactly (NaN: a radius not observed)
        assert np.array_equal(table[:, k], np.asarray(d[name], float), equal_nan=True), name
    with pytest.raises(FileExistsError):
        res.to_csv(path)


# -- the fast paths change no result -------------------------------------------------------------------


def test_sweep_equals_brute_force_windows():
    """The sort-and-sweep finds every pair within its epipolar window (modulo 2 pi) and bin reach."""
    from shinysim.recon.stereo.candidates import _sweep

    rng = np.random.default_rng(7)
    uq, ut = rng.uniform(-np.pi, np.pi, 300), rng.uniform(-np.pi, np.pi, 400)
    uq[:5] = [-np.pi, np.pi, -3.14, 3.14, 0.0]  # windows that wrap around +-pi
    aq = rng.uniform(0.0, 0.3, 300)
    aq[10:13] = [np.inf, np.pi, 4.0]  # no bound
    sq, st = rng.uniform(-5, 5, 300), rng.uniform(-5, 5, 400)
    rq = rng.uniform(0.1, 1.0, 300)
    qi, pos, order = _sweep(uq, aq, ut, True, sq, rq, st)
    found = set(zip(qi.tolist(), order[pos].tolist()))
    assert len(found) == len(qi)  # no pair twice
    du = np.abs((uq[:, None] - ut[None] + np.pi) % (2 * np.pi) - np.pi)
    want = (du <= aq[:, None]) & (np.abs(sq[:, None] - st[None]) <= rq[:, None])
    assert set(zip(*map(np.ndarray.tolist, np.nonzero(want)))) <= found
    # the offset (two orthographic cameras) kind: no wrap
    qi, pos, order = _sweep(sq, rq, st, False)
    want = np.abs(sq[:, None] - st[None]) <= rq[:, None]
    assert set(zip(*map(np.ndarray.tolist, np.nonzero(want)))) <= set(zip(qi.tolist(), order[pos].tolist()))


def _relax_reference(a0, gvec, W, i, j, n1, n2, gap0, iterations, tol):
    """The relaxation of docs/stereo-matching.md written plainly: every candidate, every step, always half way."""
    steps = 0

    def excite(act):
        support = W @ act
        gbar = (gvec + W @ (act[:, None] * gvec)) / (1.0 + support)[:, None]
        bias = (1.0 + support) * np.sum(gbar * gbar, 1) / gap0**2
        return a0 * np.exp(-bias) * (1.0 + support), support

    def best(x):
        best_i, best_j = np.full(n1, -np.inf), np.full(n2, -np.inf)
        np.maximum.at(best_i, i, x)
        np.maximum.at(best_j, j, x)
        return np.maximum(best_i[i], best_j[j])

    x, _ = excite(np.ones_like(a0))
    act = x / best(x)
    for steps in range(1, iterations + 1):
        x, _ = excite(act)
        new = 0.5 * (act + x / best(x))
        change = float(np.max(np.abs(new - act)))
        act = new
        if change <= tol:
            break
    return (*excite(act), steps)


def test_relaxation_in_spatial_order_is_bitwise_the_plain_one():
    """Spatial order with rows summed in (i, j) order: the same bits as the relaxation on the candidates
    in (i, j) order; and the same fixed point as the plain relaxation, which steps every candidate every
    time and always half way (the fast one steps only the candidates with competitors, and near the end
    only those still moving, their competitors and their neighbours; and 0.8 of the way unless a
    candidate's pull turned)."""
    from scipy.spatial import cKDTree

    from shinysim.recon.stereo.relaxation import (
        _greedy_fast,
        _median_nn,
        _relax,
        _spatial_order,
        _support_matrix,
    )

    rng = np.random.default_rng(11)
    k, n1, n2 = 3000, 1400, 1500
    i, j = rng.integers(0, n1, k), rng.integers(0, n2, k)
    P = np.column_stack([rng.uniform(0, 5, k), rng.uniform(0, 5, k), rng.normal(0, 0.05, k)])
    N = np.column_stack([rng.normal(0, 0.1, (k, 2)), np.ones(k)])
    N /= np.linalg.norm(N, axis=1)[:, None]
    gvec = rng.normal(0, 0.003, (k, 3))
    a0 = np.exp(-rng.uniform(0, 2, k))
    gap0 = math.radians(0.5)
    radius = 4.0 * float(np.median(cKDTree(P).query(P, k=2)[0][:, 1]))
    perm = _spatial_order(P)
    Ps = np.ascontiguousarray(P[perm])
    assert 4.0 * _median_nn(cKDTree(Ps), Ps) == radius
    W = _support_matrix(P, N, i, j, radius, 0.03, gap0)
    Wp = _support_matrix(Ps, N[perm], i[perm], j[perm], radius, 0.03, gap0, cols=perm)
    x = rng.random(k)
    assert np.array_equal((W @ x)[perm], Wp @ x[perm])
    x0, _, s0, steps0 = _relax(a0, gvec, W, i, j, n1, n2, gap0, 200, 1e-4)
    x1, _, s1, steps1 = _relax(a0[perm], gvec[perm], Wp, i[perm], j[perm], n1, n2, gap0, 200, 1e-4)
    assert steps1 == steps0 > 3
    assert np.array_equal(x1, x0[perm]) and np.array_equal(s1, s0[perm])
    xr, sr, steps_r = _relax_reference(a0, gvec, W, i, j, n1, n2, gap0, 200, 1e-4)
    # both stop where a full step moves no activation by more than 1e-4; x is about a0 (1 + support) with
    # support a sum of activations, so the two fixed points agree to a few 1e-4 relative
    assert np.max(np.abs(x0 / xr - 1)) <= 1e-3 and np.max(np.abs(s0 - sr) / (1 + sr)) <= 1e-3
    assert np.array_equal(_greedy_fast(x0, i, j, n1, n2), _greedy_fast(xr, i, j, n1, n2))


def test_stage_seconds_are_reported():
    cams = _pair(30.0)
    n = _cap_normals(6.0, 24.0)
    E = np.array([0.1, 0.2, -R_SPHERE]) + R_SPHERE * n
    rig, (r1, r2) = _rays_from_elements(cams, (E, E), (n, n))
    res = match_highlights(r1, r2, rig, StereoParams(d0_mm=0.02))
    assert set(res.seconds) == {"candidates", "tests", "relaxation", "uniqueness", "reflectance", "refinement"}
    assert all(v >= 0 for v in res.seconds.values())


@pytest.mark.parametrize("beta", [15.0, 30.0])
def test_umbilic_refinement_places_both_elements_exactly_on_a_sphere(beta):
    """Camera 2 sees an element up to 8 um from camera 1's: the crossing stands off the sphere, the refinement does not."""
    cams = _pair(beta)
    centre = np.array([0.3, -0.2, -0.5])
    rng = np.random.default_rng(7)
    # elements 5 deg apart in normal: no other element's pair passes the 1 deg normal test
    n1 = _cap_normals(5.0, 25.0)
    m = len(n1)
    # camera 2's element: turned by up to 0.6 deg (8 um on the 0.794 mm sphere), as between two
    # sources' highlights of a dense dome
    turn = rng.normal(size=(m, 3))
    turn -= np.sum(turn * n1, axis=1)[:, None] * n1
    turn *= np.radians(rng.uniform(0.1, 0.6, m))[:, None] / np.linalg.norm(turn, axis=1)[:, None]
    n2 = n1 + turn
    n2 /= np.linalg.norm(n2, axis=1)[:, None]
    E1, E2 = centre + R_SPHERE * n1, centre + R_SPHERE * n2
    rig, (r1, r2) = _rays_from_elements(cams, (E1, E2), (n1, n2))
    d0 = 0.02
    res = match_highlights(r1, r2, rig, StereoParams(d0_mm=d0, max_normal_gap_deg=1.0))
    assert len(res) == m and np.array_equal(res.index1, res.index2)
    assert res.refined.all()
    mid = 0.5 * (E1 + E2)[res.index1]
    n_mid = (n1 + n2)[res.index1]
    n_mid /= np.linalg.norm(n_mid, axis=1)[:, None]
    # the model E2 - E1 = rho (n2 - n1) is exact on a sphere: the elements come back to the
    # iteration's stop (steps below 1e-10 mm) times the solve's condition number (~1 / |n2 - n1|,
    # 600 at 0.1 deg): 1e-8 mm; most to 1e-13
    assert np.max(np.linalg.norm(res.point - mid, axis=1)) < 1e-8
    assert np.max(np.linalg.norm(res.normal - n_mid, axis=1)) < 1e-9  # radians, to first order
    assert np.allclose(res.radius_mm, R_SPHERE, rtol=1e-6)
    # the paper's crossing is microns off the surface
    off = np.abs(np.linalg.norm(res.crossing - centre, axis=1) - R_SPHERE)
    assert np.median(off) > 1e-4


def test_competitor_max_against_its_definition():
    """Largest value among the candidates sharing i or j, with and without the candidate itself, ties
    included (integer values tie often), against a brute-force loop."""
    from shinysim.recon.stereo.relaxation import _competitor_max

    rng = np.random.default_rng(5)
    for t in range(60):
        k, n1, n2 = int(rng.integers(1, 80)), int(rng.integers(1, 20)), int(rng.integers(1, 20))
        i, j = rng.integers(0, n1, k), rng.integers(0, n2, k)
        v = rng.integers(0, 4, k).astype(float) if t % 2 else rng.random(k)
        best, other = _competitor_max(v, i, j, n1, n2)
        for c in range(k):
            rivals = (i == i[c]) | (j == j[c])
            assert best[c] == v[rivals].max()
            others = rivals.copy()
            others[c] = False
            assert other[c] == (v[others].max() if others.any() else -np.inf)


def test_threads_change_no_bit(monkeypatch):
    """The per-pair work in pieces on threads gives the same bits as one thread: the ghost scene of three
    spheres (ghosts, relaxation with competitors, reflectance ends and roots), cut into 64-pair pieces."""
    import shinysim.recon.stereo._base as stereo

    rig, r1, r2, _, _ = _ghost_scene()
    one = match_highlights(r1, r2, rig, StereoParams(d0_mm=0.02, max_normal_gap_deg=1.0, workers=1,
                                                     max_delta_z_mm=1.0))
    monkeypatch.setattr(stereo, "_PIECE", 64)
    assert len(stereo._pieces(one.n_candidates, 3)) == 3
    three = match_highlights(r1, r2, rig, StereoParams(d0_mm=0.02, max_normal_gap_deg=1.0, workers=3,
                                                       max_delta_z_mm=1.0))
    assert len(one) > 900 and one.relax_iterations > 3
    for name, col in one.as_dict().items():
        assert np.array_equal(col, three.as_dict()[name], equal_nan=True), name
    with pytest.raises(OptionError, match="workers"):
        StereoParams(workers=0)
