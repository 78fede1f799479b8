"""Structured-highlight stereo, paper Eqs 18-45: exact geometry first, then the printed forms.

Every synthetic highlight here comes from the mirror law solved exactly
(sources placed along the reflected ray, or highlights found by bisection),
so the correct equations must give the truth to float64 round-off.
Tolerances: ``EPS_MM`` is a few hundred ulps of the largest length involved
(the source distance R = 43.18 mm: ulp 7e-15 mm); angles are compared at
1e-12 rad (a few hundred ulps of 1 rad).
"""

from __future__ import annotations

import numpy as np
import pytest

from shinysim.conventions import gradient_from_normal, normalize
from shinysim.errors import OptionError
from shinysim.theory import stereo as st

R = 43.18  # SHINY source semicircle, 1.7 in, mm
#: round-off budget for lengths of order R: 43.18 mm has an ulp of 7.1e-15 mm; the chains below
#: (trig of angles, a division by sin 2(T - beta)) lose at most a few hundred ulps
EPS_MM = 1e-12
#: the brief's bar for the planar recovery, far above round-off but far below any geometric error
RECOVER = 1e-9
BETAS_DEG = (15.0, 30.0, 45.0)


# ------------------------------------------------------------------ one camera, Eqs 18-23

def _physical(theta, x, alpha):
    """Orientations that see the source on their camera side (the other branch of Eq 20 is the mirror
    condition for a ray leaving the element away from the source)."""
    return np.sign(np.sin(2 * theta)) == np.sign(R * np.sin(alpha) - x)


def test_eq20_and_eq23_are_the_exact_mirror_condition():
    theta = np.deg2rad(np.linspace(-44.0, 44.0, 89))
    theta = theta[np.abs(theta) > 1e-6]
    T, X, A = np.meshgrid(theta, [-6.0, 0.0, 2.5, 9.0], np.deg2rad([-70.0, -25.0, 8.0, 45.0, 80.0]), indexing="ij")
    z = st.z_of_theta(T, X, A, R)
    ok = _physical(T, X, A)
    assert ok.sum() > 500
    # an element at (x, z(Theta)) with orientation Theta sends the source into the vertical camera
    res = st.planar_mirror_residual(X, z, T, A, R)
    assert np.abs(res[ok]).max() < 1e-12
    # Eq 23 is Eq 20 with p = -tan(Theta): the same heights (relative round-off, |z| up to ~2e3 mm)
    zp = st.z_of_p(-np.tan(T), X, A, R)
    assert np.allclose(zp, z, rtol=1e-12, atol=EPS_MM)


def test_eq18_19_parabola_family_is_the_eq20_curve():
    # the parabola with focus at the source through an element: the camera ray x meets the family
    # member of parameter a at the height Eq 20 gives for the orientation -atan(p) of Eq 19
    alpha = np.deg2rad(35.0)
    xs, zs = R * np.sin(alpha), R * np.cos(alpha)
    x = 4.0
    a = np.array([0.5, 2.0, 10.0, 30.0, 80.0])
    z, p = st.parabola_family(x, xs, zs, a)
    assert np.allclose(st.z_of_theta(-np.arctan(p), x, alpha, R), z, rtol=0, atol=EPS_MM)
    assert np.abs(st.planar_mirror_residual(x, z, -np.arctan(p), alpha, R)).max() < 1e-12
    assert np.allclose(st.parabola_parameter(x, z, xs, zs), a, rtol=1e-13)


def test_printed_eq20_to_23_miss_the_mirror_condition_by_stated_amounts():
    # R = 43.18 mm, source at 30 deg, highlight at x = 5 mm, element at 10 deg
    alpha, x, theta = np.deg2rad(30.0), 5.0, np.deg2rad(10.0)
    z = st.z_of_theta(theta, x, alpha, R)
    z_printed = st.z_of_theta(theta, x, alpha, R, convention="printed")
    assert z == pytest.approx(-8.185673453340, abs=1e-9)
    # Eq 22's x_hat = R cos(alpha) puts the element 4.42 m away, where its reflection misses the
    # camera by 159.8 degrees
    assert z_printed - z == pytest.approx(4422.6559, abs=1e-3)
    miss = np.rad2deg(st.planar_mirror_residual(x, z_printed, theta, alpha, R))
    assert miss == pytest.approx(159.78, abs=0.01)
    # printed Eq 23 (its sign and Eq 22) is off by 4.3 m
    p = -np.tan(theta)
    assert st.z_of_p(p, x, alpha, R, convention="printed") - z == pytest.approx(-4331.49, abs=0.01)
    # Eq 23's printed sign alone is the mirror image p -> -p: 83.0 mm instead of -8.2 mm here
    sign_only = R * (np.cos(alpha) - 0.5 * (x / R - np.sin(alpha)) * (p - 1 / p))
    assert sign_only == pytest.approx(st.z_of_p(-p, x, alpha, R), abs=EPS_MM)
    assert sign_only - z == pytest.approx(91.1613, abs=1e-3)


# ------------------------------------------------------------------ two cameras, Eqs 24-34

def _elements(n=13, centre=(3.0, -2.0), r=4.0, spread=30.0):
    """Elements on an off-origin circle, orientations every few degrees."""
    theta = np.deg2rad(np.linspace(-spread, spread, n))
    return centre[0] + r * np.sin(theta), centre[1] + r * np.cos(theta), theta


def _stereo_view(x, z, theta, beta):
    """Each camera's highlight of each element, lit by its own exactly placed source."""
    a1 = st.place_source(x, z, theta, beta, R, camera="'")
    a2 = st.place_source(x, z, theta, beta, R, camera='"')
    x1 = st.planar_observation(x, z, beta, camera="'")[0]
    x2 = st.planar_observation(x, z, beta, camera='"')[0]
    assert np.all(np.isfinite(a1)) and np.all(np.isfinite(a2))
    return x1, a1, x2, a2


@pytest.mark.parametrize("beta_deg", BETAS_DEG)
def test_placed_sources_reflect_into_their_cameras(beta_deg):
    beta = np.deg2rad(beta_deg)
    x, z, theta = _elements()
    x1, a1, x2, a2 = _stereo_view(x, z, theta, beta)
    assert np.abs(st.planar_mirror_residual(x, z, theta, a1, R, view_angle=beta)).max() < 1e-12
    assert np.abs(st.planar_mirror_residual(x, z, theta, a2, R, view_angle=-beta)).max() < 1e-12
    # Eqs 24-25: each camera's height of the element from its orientation and its highlight alone
    _, zc1 = st.planar_observation(x, z, beta, camera="'")
    _, zc2 = st.planar_observation(x, z, beta, camera='"')
    ok1, ok2 = np.abs(theta - beta) > 1e-9, np.abs(theta + beta) > 1e-9  # tan 2(T -+ b) = 0: no height
    assert np.allclose(st.z_camera(theta, x1, a1, beta, R, camera="'")[ok1], zc1[ok1], rtol=0, atol=EPS_MM)
    assert np.allclose(st.z_camera(theta, x2, a2, beta, R, camera='"')[ok2], zc2[ok2], rtol=0, atol=EPS_MM)
    # printed (no normalisation by R) is the correct form only at R = 1
    zp = st.z_camera(theta, x1, a1, beta, R, camera="'", convention="printed")
    assert np.abs(zp - zc1)[ok1].min() > 1.0
    assert np.allclose(st.z_camera(theta, x1 / R, a1, beta, 1.0, camera="plus"),
                       st.z_camera(theta, x1 / R, a1, beta, 1.0, camera="'", convention="printed"))


@pytest.mark.parametrize("beta_deg", BETAS_DEG)
def test_planar_stereo_recovers_elements_and_rejects_false_pairs(beta_deg):
    beta = np.deg2rad(beta_deg)
    x, z, theta = _elements()
    x1, a1, x2, a2 = _stereo_view(x, z, theta, beta)
    m = st.reflectance_match(x1, a1, x2, a2, beta, R, tol_mm=1e-6)
    assert m.converged.all() and m.accepted.all()
    assert np.abs(m.x - x).max() <= RECOVER
    assert np.abs(m.z - z).max() <= RECOVER
    assert np.abs(m.theta - theta).max() <= RECOVER
    # E' = E'' = 0 at the truth, to round-off
    assert max(np.abs(m.e1).max(), np.abs(m.e2).max()) < EPS_MM
    # every pair of two different elements: a candidate point that no orientation explains;
    # tol_mm = 1e-6 mm is 1e6 times the round-off of the true pairs above
    full = st.reflectance_match(x1[:, None], a1[:, None], x2[None, :], a2[None, :], beta, R, tol_mm=1e-6)
    assert np.array_equal(full.accepted, np.eye(len(x), dtype=bool))
    false = ~np.eye(len(x), dtype=bool) & full.converged
    assert false.sum() > 10  # the false pairs with a root of Eq 32 (Fig 17's curves crossing off the axis)
    assert np.nanmin(np.maximum(np.abs(full.e1), np.abs(full.e2))[false]) > 1e-3
    # every converged pair is a root of Eq 32, E' = E'', except where a highlight's source lies on its
    # own camera ray (the element at Theta = +-beta), which fixes Theta = +-beta alone
    on_ray = np.isclose(theta, beta)[:, None] | np.isclose(theta, -beta)[None, :]
    c = full.converged & ~on_ray
    assert np.allclose(full.e1[c], full.e2[c], rtol=1e-9, atol=EPS_MM)
    nc = ~full.converged
    # curves that never cross (no root of Eq 32; some at 15 deg): theta NaN and the pair rejected
    assert np.all(np.isnan(full.theta[nc])) and not full.accepted[nc].any()


@pytest.mark.parametrize("beta_deg", BETAS_DEG)
def test_printed_eq27_puts_the_candidate_at_minus_z(beta_deg):
    beta = np.deg2rad(beta_deg)
    x, z, theta = _elements()
    x1, a1, x2, a2 = _stereo_view(x, z, theta, beta)
    xs, zs = st.ray_intersection(x1, x2, beta)
    xp, zp = st.ray_intersection(x1, x2, beta, convention="printed")
    assert np.allclose(xs, x, atol=EPS_MM) and np.allclose(zs, z, atol=EPS_MM)
    assert np.allclose(xp, x, atol=EPS_MM)  # Eq 26 read as /(2 cos beta) is right
    assert np.allclose(zp, -z, atol=EPS_MM)  # Eq 27 as printed mirrors the height
    assert np.abs(zp - z).max() == pytest.approx(2 * np.abs(z).max(), rel=1e-12)  # 4 mm here
    # and the printed chain (Eqs 24-27) accepts none of the true pairs
    m = st.reflectance_match(x1, a1, x2, a2, beta, R, tol_mm=1e-6, convention="printed")
    assert not m.accepted.any()


def test_bracketing_fallback_alone_recovers_the_true_pairs():
    beta = np.deg2rad(30.0)
    x, z, theta = _elements()
    x1, a1, x2, a2 = _stereo_view(x, z, theta, beta)
    m = st.reflectance_match(x1, a1, x2, a2, beta, R, tol_mm=1e-6, max_iter=0)
    assert (m.iterations == 0).all() and m.accepted.all()
    assert np.abs(m.theta - theta).max() <= RECOVER and np.abs(m.z - z).max() <= RECOVER


def test_two_circles_every_highlight_matched_only_to_itself():
    # a scene as in Fig 16: two circles, sources placed for a few elements of each and every source
    # lighting everything; a candidate is a true match when one surface point made both highlights
    beta = np.deg2rad(20.0)
    circles = [(-3.0, 0.0, 2.5), (3.5, 1.0, 2.0)]
    alphas = []
    for xc, zc, r in circles:
        t = np.deg2rad(np.array([-12.0, 0.0, 14.0]))
        for cam in ("'", '"'):
            alphas.append(st.place_source(xc + r * np.sin(t), zc + r * np.cos(t), t, beta, R, camera=cam))
    alphas = np.sort(np.concatenate(alphas))
    h1 = st.planar_scene(circles, alphas, R, beta, camera="'")
    h2 = st.planar_scene(circles, alphas, R, beta, camera='"')
    assert len(h1.x) > 8 and len(h2.x) > 8
    same = np.hypot(h1.x[:, None] - h2.x[None, :], h1.z[:, None] - h2.z[None, :]) < 1e-9
    assert same.sum() >= 6  # the six placed elements at least
    m = st.reflectance_match(h1.x_cam[:, None], h1.alpha[:, None], h2.x_cam[None, :], h2.alpha[None, :],
                             beta, R, tol_mm=1e-6)
    assert np.array_equal(m.accepted, same)
    assert np.abs(m.theta[same] - np.broadcast_to(h1.theta[:, None], same.shape)[same]).max() <= RECOVER


def test_curve_highlights_of_a_general_curve():
    # an ellipse given as a parametrised curve; a circle through the same solver agrees with
    # the closed mirror-sphere solution
    beta = np.deg2rad(25.0)
    alphas = np.deg2rad(np.linspace(-60.0, 60.0, 7))

    def circle(t):
        return 1.0 + 3.0 * np.sin(t), -1.0 + 3.0 * np.cos(t), t

    t = np.linspace(-np.pi, np.pi, 721)
    tr, ai, x, z, th, xc = st.curve_highlights(circle, t, alphas, R, beta, camera='"')
    xe, ze, the, xce = st.circle_highlights(alphas, R, 1.0, -1.0, 3.0, beta, camera='"')
    assert np.array_equal(ai, np.arange(len(alphas)))  # one highlight per source on a circle
    assert np.allclose(x, xe, atol=EPS_MM) and np.allclose(z, ze, atol=EPS_MM)
    assert np.allclose(th, the, atol=1e-12) and np.allclose(xc, xce, atol=EPS_MM)

    def ellipse(t):  # x = 4 sin t, z = 1.5 cos t, outward normal ~ (1.5 sin t, 4 cos t)
        return 4.0 * np.sin(t), 1.5 * np.cos(t), np.arctan2(1.5 * np.sin(t), 4.0 * np.cos(t))

    tr, ai, x, z, th, xc = st.curve_highlights(ellipse, t, alphas, R, beta, camera="'")
    assert len(tr) >= len(alphas)
    res = st.planar_mirror_residual(x, z, th, alphas[ai], R, view_angle=beta)
    assert np.abs(res).max() < 1e-12
    assert np.allclose(xc, st.planar_observation(x, z, beta)[0])


# ------------------------------------------------------------------ three dimensions, Eqs 36-45

def _sphere_elements(n=24, seed=3):
    rng = np.random.default_rng(seed)
    normal = normalize(np.stack([rng.uniform(-0.5, 0.5, n), rng.uniform(-0.5, 0.5, n), np.ones(n)], axis=-1))
    centre, radius = np.array([1.0, 0.5, -1.0]), 3.0
    return centre + radius * normal, normal


@pytest.mark.parametrize("beta_deg", BETAS_DEG)
@pytest.mark.parametrize("distance", [None, 127.0])
def test_rays_through_a_point_meet_and_give_its_depths(beta_deg, distance):
    beta = np.deg2rad(beta_deg)
    P, _ = _sphere_elements()
    v1, u1, d1 = st.observe_3d(P, beta, camera="'", distance=distance)
    v2, u2, d2 = st.observe_3d(P, beta, camera='"', distance=distance)
    scale = EPS_MM if distance is None else 1e-12 * distance  # round-off of lengths up to 127 mm
    assert np.abs(st.closest_approach(v1, u1, v2, u2)).max() < scale
    z1, z2 = st.ray_depths(v1, u1, v2, u2)
    assert np.abs(z1 - d1).max() < scale and np.abs(z2 - d2).max() < scale
    assert np.abs(st.ray_midpoint(v1, u1, v2, u2) - P).max() < scale
    if distance is None:
        # printed Eqs 41-42: exact for perpendicular axes (beta = 45 deg) only
        p1, p2 = st.ray_depths(v1, u1, v2, u2, convention="printed")
        err = max(np.abs(p1 - d1).max(), np.abs(p2 - d2).max())
        if beta_deg == 45.0:
            assert err < EPS_MM
        else:
            # (v'' - v').u' = z' - c z'' with c = cos 2 beta: off by c z'', here 0.8 mm (30 deg), 1.5 mm (15 deg)
            assert err > 0.5
            assert np.allclose(p1 - d1, -np.cos(2 * beta) * d2, atol=EPS_MM)


def _brute_distance(v1, u1, v2, u2):
    """Smallest distance between two lines by nested grid search over the two ray parameters."""
    u1, u2 = normalize(u1), normalize(u2)
    s0, t0, half = 0.0, 0.0, 200.0
    for _ in range(60):
        g = np.linspace(-half, half, 41)
        S, T = np.meshgrid(s0 + g, t0 + g, indexing="ij")
        d = np.linalg.norm(v1 + S[..., None] * u1 - v2 - T[..., None] * u2, axis=-1)
        i, j = np.unravel_index(np.argmin(d), d.shape)
        s0, t0, best = S[i, j], T[i, j], d[i, j]
        half *= 0.25
    return best


def test_skew_rays_distance_against_brute_force():
    rng = np.random.default_rng(7)
    v1, v2 = rng.normal(size=(2, 8, 3)) * 5.0
    u1, u2 = rng.normal(size=(2, 8, 3))
    D = st.closest_approach(v1, u1, v2, u2)
    brute = np.array([_brute_distance(*a) for a in zip(v1, u1, v2, u2)])
    # the grid search ends with cells of 200 * 4^-60 mm; its distance is quadratic in the parameter
    # error near the minimum, so it meets the exact formula to round-off
    assert np.allclose(D, brute, rtol=0, atol=1e-9)
    assert D.min() > 0.1
    printed = st.closest_approach(v1, u1, v2, u2, convention="printed")
    assert np.allclose(np.abs(printed), D)
    # the printed Eq 40 is signed: D < D0 would accept these skew pairs however far apart they pass
    assert (printed < -0.1).sum() >= 2
    # parallel rays: the correct form falls back to the point-line distance
    assert st.closest_approach([0, 0, 0], [0, 0, 1], [3, 4, 0], [0, 0, 2]) == pytest.approx(5.0)


@pytest.mark.parametrize("beta_deg", BETAS_DEG)
def test_gradient_loci_cross_at_the_true_gradient(beta_deg):
    beta = np.deg2rad(beta_deg)
    P, n = _sphere_elements()
    S1 = st.place_source_3d(P, n, beta, R, camera="'")
    S2 = st.place_source_3d(P, n, beta, R, camera='"')
    rel1 = (P - S1) @ st.camera_axes(beta, camera="'").T
    rel2 = (P - S2) @ st.camera_axes(beta, camera='"').T
    p_true, q_true = gradient_from_normal(n)
    # Eqs 38-39 in each camera's frame, origin at its source
    for rel, cam in ((rel1, "'"), (rel2, '"')):
        pc, qc = st.gradient_to_camera(p_true, q_true, beta, camera=cam)
        assert np.allclose(qc / pc, rel[:, 1] / rel[:, 0], rtol=1e-12)
        assert np.allclose(st.gradient_height(rel[:, 0], rel[:, 1], pc, qc), rel[:, 2], rtol=0, atol=EPS_MM)
        a = np.hypot(rel[:, 0], rel[:, 1]) / (2 * np.hypot(pc, qc))
        zf, pf, qf = st.paraboloid_family(rel[:, 0], rel[:, 1], a)
        assert np.allclose(zf, rel[:, 2], atol=EPS_MM) and np.allclose(pf, pc) and np.allclose(qf, qc)
        # the true gradient lies on the camera's locus, Eq 44 / 45
        assert np.allclose(st.gradient_locus(p_true, rel[:, 0], rel[:, 1], beta, camera=cam), q_true, atol=1e-12)
    p, q = st.gradient_loci(rel1[:, 0], rel1[:, 1], rel2[:, 0], rel2[:, 1], beta)
    assert np.abs(p - p_true).max() < 1e-12 and np.abs(q - q_true).max() < 1e-12
    # printed: slopes y/x without cos(beta). Scaling both slopes alike keeps p* and makes q* = q / cos(beta):
    # 3.5 % too large at 15 deg, 15.5 % at 30 deg, 41 % at 45 deg
    pp, qp = st.gradient_loci(rel1[:, 0], rel1[:, 1], rel2[:, 0], rel2[:, 1], beta, convention="printed")
    assert np.allclose(pp, p_true, atol=1e-12)
    assert np.allclose(qp, q_true / np.cos(beta), rtol=1e-12)
    assert np.abs(qp - q_true).max() > 0.01
    # Eq 43 on the true pairs: zero
    M = st.ray_midpoint(*st.observe_3d(P, beta, camera="'")[:2], *st.observe_3d(P, beta, camera='"')[:2])
    assert np.abs(st.delta_z(p, q, M, S1, S2, beta)).max() < 1e-10  # heights ~40 mm, divisions by |grad|


@pytest.mark.parametrize("beta_deg", BETAS_DEG)
def test_delta_z_rejects_false_pairs(beta_deg):
    # two different elements at the same y: orthographic rays turned about y stay in the plane of
    # constant y, so the rays of C' at one and C'' at the other meet (D = 0) at a point off the surface
    beta = np.deg2rad(beta_deg)
    centre, radius = np.array([0.0, 0.0, -1.0]), 3.0
    y = 0.9
    xs = np.array([-1.5, -0.5, 0.6, 1.7])
    zs = centre[2] + np.sqrt(radius**2 - xs**2 - y**2)
    P = np.stack([xs, np.full_like(xs, y), zs], axis=-1)
    n = normalize(P - centre)
    S1 = st.place_source_3d(P, n, beta, R, camera="'")
    S2 = st.place_source_3d(P, n, beta, R, camera='"')
    v1, u1, _ = st.observe_3d(P, beta, camera="'")
    v2, u2, _ = st.observe_3d(P, beta, camera='"')
    i, j = np.meshgrid(np.arange(4), np.arange(4), indexing="ij")
    D = st.closest_approach(v1[i], u1[i], v2[j], u2[j])
    assert np.abs(D).max() < EPS_MM
    M = st.ray_midpoint(v1[i], u1[i], v2[j], u2[j])
    rel1 = np.einsum("...k,lk->...l", M - S1[i], st.camera_axes(beta, camera="'"))
    rel2 = np.einsum("...k,lk->...l", M - S2[j], st.camera_axes(beta, camera='"'))
    p, q = st.gradient_loci(rel1[..., 0], rel1[..., 1], rel2[..., 0], rel2[..., 1], beta)
    dz = st.delta_z(p, q, M, S1[i], S2[j], beta)
    true = i == j
    assert np.abs(dz[true]).max() < 1e-10
    assert np.abs(dz[~true]).min() > 1e-2  # mm; the elements are 1 mm or more apart


# ------------------------------------------------------------------ bad arguments

@pytest.mark.parametrize("beta", [0.0, -0.1, np.pi / 2, 2.0, float("nan"), "30"])
def test_beta_out_of_range_is_refused(beta):
    with pytest.raises(OptionError, match="beta"):
        st.ray_intersection(1.0, 2.0, beta)
    with pytest.raises(OptionError, match="beta"):
        st.reflectance_match(1.0, 0.2, 2.0, 0.3, beta, R, tol_mm=1e-6)
    with pytest.raises(OptionError, match="beta"):
        st.camera_axes(beta)


def test_bad_arguments_name_themselves():
    with pytest.raises(OptionError, match=r"x_p \(3,\).*x_pp \(4,\)"):
        st.reflectance_match(np.zeros(3), 0.1, np.zeros(4), 0.2, 0.3, R, tol_mm=1e-6)
    with pytest.raises(OptionError, match="theta"):
        st.z_of_theta(np.zeros(3), np.zeros(2), 0.1, R)
    with pytest.raises(OptionError, match="u2"):
        st.closest_approach(np.zeros(3), np.ones(3), np.zeros(3), np.ones(2))
    with pytest.raises(OptionError, match="v1.*v2"):
        st.ray_depths(np.zeros((2, 3)), np.ones(3), np.zeros((3, 3)), np.ones(3))
    with pytest.raises(OptionError, match="convention"):
        st.z_of_p(0.5, 1.0, 0.1, R, convention="paper")
    with pytest.raises(OptionError, match="camera"):
        st.z_camera(0.1, 1.0, 0.2, 0.3, R, camera="left")
    with pytest.raises(OptionError, match="R"):
        st.z_of_theta(0.1, 1.0, 0.2, -1.0)
    with pytest.raises(OptionError, match="tol_mm"):
        st.reflectance_match(1.0, 0.2, 2.0, 0.3, 0.3, R, tol_mm=0.0)
    with pytest.raises(OptionError, match="circles"):
        st.planar_scene([(0.0, 1.0)], [0.1], R, 0.3)
