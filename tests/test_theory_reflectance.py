"""Tests for shinysim.theory.reflectance (paper Eqs 5-8, Figs 3-4) and the
Eq 5 material of shinysim.sim.materials."""

import numpy as np
import pytest

# Identities evaluated in float64 with a handful of operations: round-off is a
# few ulp of O(1) numbers, so 1e-12 leaves a wide margin and still catches
# any real error.
from shinysim._shared import EXACT_TOL as EXACT
from shinysim.conventions import (
    angles_from_direction,
    direction_from_angles,
    gradient_from_normal,
    normal_from_gradient,
    normalize,
)
from shinysim.sim.materials import blend_weight, paper_material
from shinysim.theory import reflectance as R

Z = np.array([0.0, 0.0, 1.0])


# -- reflectance (Eq 5) -----------------------------------------------------

def test_reflectance_reference_values():
    # n = s = z: Lambertian 1, bracket 2*1*1 - 1 = 1 -> A k + A (1 - k) / 2.
    assert R.reflectance(Z, Z, k=0.3, sharpness=7, A=2.0) == pytest.approx(2.0 * 0.3 + 1.0 * 0.7, abs=EXACT)
    # Source at 60 deg, normal = z: n.s = 1/2, bracket = 2*(1/2) - 1/2 = 1/2.
    s = direction_from_angles(np.pi / 3, 0.0)
    assert R.reflectance(Z, s, k=0.5, sharpness=3) == pytest.approx(0.25 + 0.25 * 0.125, abs=EXACT)


def test_specular_term_is_mirror_direction_power():
    # Eq 5's bracket is r.z with r = 2 (n.s) n - s the mirror of s about n.
    rng = np.random.default_rng(1)
    n = normalize(rng.normal(size=(50, 3)) + [0, 0, 2])
    s = normalize(rng.normal(size=(50, 3)) + [0, 0, 2])
    r = 2 * np.sum(n * s, -1, keepdims=True) * n - s
    expected = 0.5 * np.maximum(r[:, 2], 0) ** 5
    np.testing.assert_allclose(R.reflectance(n, s, k=0.0, sharpness=5), expected, rtol=0, atol=EXACT)


def test_reflectance_clamps_both_terms():
    # Source behind the patch: no Lambertian light; negative bracket with a
    # fractional exponent must give 0, not NaN.
    n = Z
    s = direction_from_angles(np.deg2rad(120.0), 0.0)
    assert R.reflectance(n, s, k=1.0, sharpness=2.5) == 0.0
    assert R.reflectance(n, s, k=0.0, sharpness=2.5) == 0.0


def test_reflectance_peak_at_peak_normal_and_eq6_not_sufficient():
    s = direction_from_angles(np.deg2rad(50.0), np.deg2rad(20.0))
    n_peak = R.peak_normal(s)
    # At the bisector the mirror direction is z: the specular term is A/2.
    assert R.reflectance(n_peak, s, k=0.0, sharpness=40) == pytest.approx(0.5, abs=EXACT)
    # Nearby normals are darker.
    for d in ([1e-2, 0, 0], [0, 1e-2, 0], [-1e-2, 0, 0]):
        assert R.reflectance(normalize(n_peak + d), s, k=0.0, sharpness=40) < 0.5
    # A normal perpendicular to both s and z satisfies Eq 6 (n.z = n.s = 0)
    # yet gets no specular light: Eq 6 is necessary, not sufficient.
    n_eq6 = normalize(np.cross(s, Z))
    assert np.dot(n_eq6, Z) == pytest.approx(np.dot(n_eq6, s), abs=EXACT)
    assert R.reflectance(n_eq6, s, k=0.0, sharpness=40) == 0.0


def test_reflectance_nd_shapes():
    rng = np.random.default_rng(2)
    n = normalize(rng.normal(size=(3,)) + [0, 0, 2])
    s = normalize(rng.normal(size=(3,)) + [0, 0, 2])
    ref = R.reflectance(n, s, k=0.2, sharpness=9)
    tiled = R.reflectance(np.tile(n, (6, 1)), s, k=0.2, sharpness=9)
    assert tiled.shape == (6,)
    np.testing.assert_array_equal(tiled, ref)
    reshaped = R.reflectance(np.tile(n, (6, 1)).reshape(2, 3, 3), np.tile(s, (6, 1)).reshape(2, 3, 3), k=0.2,
                             sharpness=9)
    assert reshaped.shape == (2, 3)
    np.testing.assert_array_equal(reshaped, ref)


def test_reflectance_scale():
    # Brightness is linear in A, and unit-free in the length of the vectors.
    n = normalize([0.1, 0.2, 1.0])
    s = normalize([0.5, -0.1, 1.0])
    e1 = R.reflectance(n, s, k=0.4, sharpness=6, A=1.0)
    assert R.reflectance(3 * n, 7 * s, k=0.4, sharpness=6, A=5.0) == pytest.approx(5 * e1, abs=EXACT)


def test_reflectance_nan_does_not_raise():
    out = R.reflectance([[np.nan, 0, 1], [0, 0, 1]], Z, k=0.5, sharpness=3)
    assert np.isnan(out[0]) and np.isfinite(out[1])
    out = R.reflectance([np.inf, 0, 1], Z, k=0.5, sharpness=3)
    assert np.isnan(out)


def test_reflectance_rejects_bad_parameters():
    with pytest.raises(ValueError, match=r"k must lie in \[0, 1\]"):
        R.reflectance(Z, Z, k=1.5, sharpness=1)
    with pytest.raises(ValueError, match="sharpness must be >= 0"):
        R.reflectance(Z, Z, k=0.5, sharpness=-1)


# -- peak normal, Eqs 6-8 and 10 ------------------------------------------

def test_peak_gradient_matches_peak_normal_both_conventions():
    rng = np.random.default_rng(3)
    radius, azimuth = rng.uniform(0.1, 3, size=40), rng.uniform(-np.pi, np.pi, size=40)
    ps, qs = radius * np.cos(azimuth), radius * np.sin(azimuth)
    ps[0], qs[0] = 0.5, 0.0
    p_ref, q_ref = gradient_from_normal(R.peak_normal(normal_from_gradient(ps, qs)))
    for conv in R.CONVENTIONS:
        p, q = R.peak_gradient(ps, qs, convention=conv)
        # ps^2 + qs^2 >= 0.01 here, so the printed form's cancellation in
        # sqrt(1 + r^2) - 1 costs at most ~2 digits: 1e-12 still holds.
        np.testing.assert_allclose(p, p_ref, rtol=0, atol=EXACT)
        np.testing.assert_allclose(q, q_ref, rtol=0, atol=EXACT)


def test_peak_gradient_sign_flips_only_with_mixed_mapping():
    # Source mapped as s ~ (ps, qs, 1) while normals use (-p, -q, 1): the
    # peak gradient is the negative of Eqs 7-8.
    ps, qs = 0.8, -0.3
    s_mixed = normalize([ps, qs, 1.0])
    p_mixed, q_mixed = gradient_from_normal(R.peak_normal(s_mixed))
    p, q = R.peak_gradient(ps, qs)
    assert p_mixed == pytest.approx(-p, abs=EXACT) and q_mixed == pytest.approx(-q, abs=EXACT)


def test_peak_gradient_on_camera_axis():
    p, q = R.peak_gradient(0.0, 0.0)
    assert p == 0.0 and q == 0.0
    p, q = R.peak_gradient(0.0, 0.0, convention="printed")  # 0/0 as printed
    assert np.isnan(p) and np.isnan(q)


def test_peak_gradient_half_angle_formula():
    # p = -tan(theta/2) cos(phi), q = -tan(theta/2) sin(phi) (ERRATA).
    theta = np.deg2rad([10.0, 45.0, 80.0])
    phi = np.deg2rad([0.0, 120.0, -60.0])
    p, q = R.peak_gradient(-np.tan(theta) * np.cos(phi), -np.tan(theta) * np.sin(phi))
    np.testing.assert_allclose(p, -np.tan(theta / 2) * np.cos(phi), rtol=0, atol=EXACT)
    np.testing.assert_allclose(q, -np.tan(theta / 2) * np.sin(phi), rtol=0, atol=EXACT)


def test_peak_gradient_nd_and_nan():
    p, q = R.peak_gradient(np.full((2, 3), 0.4), np.full((2, 3), -0.2))
    assert p.shape == q.shape == (2, 3)
    assert np.all(p == p[0, 0])
    p, q = R.peak_gradient([np.nan, 1.0], 0.0)
    assert np.isnan(p[0]) and np.isfinite(p[1])


def test_peak_angles_conventions():
    theta, phi = np.deg2rad(70.0), np.deg2rad(40.0)
    t_ref, f_ref = angles_from_direction(R.peak_normal(direction_from_angles(theta, phi)))
    t, f = R.peak_angles(theta, phi)
    assert t == pytest.approx(t_ref, abs=EXACT) and f == pytest.approx(f_ref, abs=EXACT)
    t, f = R.peak_angles(theta, phi, convention="printed")
    assert (t, f) == (pytest.approx(theta, abs=EXACT), pytest.approx(phi / 2, abs=EXACT))
    assert abs(t - t_ref) > 0.1  # the printed sentence is wrong


def test_bad_convention_lists_choices():
    with pytest.raises(ValueError, match="convention must be one of 'correct', 'printed'"):
        R.peak_gradient(0.1, 0.1, convention="paper")
    with pytest.raises(ValueError, match="convention must be one of 'correct', 'printed'"):
        R.peak_angles(0.1, 0.1, convention="paper")


# -- reflectance maps (Figs 3-4) -------------------------------------------

def test_reflectance_map_single_source_peak_location():
    theta, phi = np.deg2rad(40.0), np.deg2rad(30.0)
    s = direction_from_angles(theta, phi)
    E, p, q = R.reflectance_map(s, k=0.1, sharpness=200, p_range=(-1, 1), q_range=(-0.8, 0.8), shape=(161, 201))
    assert E.shape == p.shape == q.shape == (161, 201)
    assert p[0, 0] == -1 and p[0, -1] == 1 and q[0, 0] == -0.8 and q[-1, 0] == 0.8
    i, j = np.unravel_index(np.argmax(E), E.shape)
    pp, qp = R.peak_gradient(-np.tan(theta) * np.cos(phi), -np.tan(theta) * np.sin(phi))
    # The brightest grid point is the one nearest the analytic peak (grid step 0.01).
    assert abs(p[i, j] - pp) <= 0.005 + EXACT and abs(q[i, j] - qp) <= 0.005 + EXACT


def test_reflectance_map_combine():
    src = direction_from_angles(np.deg2rad([-30.0, 30.0]), 0.0)
    kw = dict(k=0.2, sharpness=30, shape=(11, 13))
    Emax, *_ = R.reflectance_map(src, combine="max", **kw)
    Esum, *_ = R.reflectance_map(src, combine="sum", **kw)
    E0, *_ = R.reflectance_map(src[0], **kw)
    E1, *_ = R.reflectance_map(src[1], **kw)
    np.testing.assert_array_equal(Emax, np.maximum(E0, E1))
    np.testing.assert_allclose(Esum, E0 + E1, rtol=0, atol=EXACT)
    with pytest.raises(ValueError, match="combine must be one of 'max', 'sum'"):
        R.reflectance_map(src, combine="mean", **kw)
    with pytest.raises(ValueError, match="sources must have shape"):
        R.reflectance_map(np.zeros((2, 2)), **kw)


# -- sharpness <-> alpha ------------------------------------------------------

def _bisect_half(fn, lo, hi, n=200):
    """delta in [lo, hi] where the decreasing fn(delta) = 1/2."""
    lo = np.full(np.shape(fn(lo)), lo, dtype=float)
    hi = np.full(lo.shape, hi, dtype=float)
    for _ in range(n):
        mid = 0.5 * (lo + hi)
        big = fn(mid) > 0.5
        lo = np.where(big, mid, lo)
        hi = np.where(big, hi, mid)
    return 0.5 * (lo + hi)


@pytest.mark.parametrize("distribution", ["ggx", "beckmann"])
def test_sharpness_matches_hwhm(distribution):
    alpha = np.array([0.005, 0.02, 0.1, 0.3, 0.8])
    n = R.sharpness_from_alpha(alpha, distribution)

    def micro(d):  # slope-space shape of D, 1 at the peak
        t2 = np.tan(d) ** 2
        return (alpha**2 / (alpha**2 + t2)) ** 2 if distribution == "ggx" else np.exp(-t2 / alpha**2)

    def phong(d):  # Eq 5 specular term against the normal-to-half-vector angle
        return np.cos(2 * d) ** n

    h_micro = _bisect_half(micro, 0.0, np.pi / 4)
    h_phong = _bisect_half(phong, 0.0, np.pi / 4)
    # Bisection to float64 resolution on both sides: agreement to 1e-12 rad.
    np.testing.assert_allclose(h_phong, h_micro, rtol=0, atol=EXACT)
    np.testing.assert_allclose(R.lobe_hwhm(sharpness=n), h_phong, rtol=0, atol=EXACT)
    np.testing.assert_allclose(R.lobe_hwhm(alpha=alpha, distribution=distribution), h_micro, rtol=0, atol=EXACT)


def test_sharpness_small_alpha_limits():
    # Beckmann: n -> 1 / (2 alpha^2); GGX: n -> ln2 / (2 (sqrt2 - 1) alpha^2).
    # The relative correction is O((c alpha^2)^2) = O(1e-12) at alpha = 1e-3.
    a = 1e-3
    assert R.sharpness_from_alpha(a, "beckmann") * 2 * a**2 == pytest.approx(1.0, rel=1e-9)
    ggx = np.log(2) / (2 * (np.sqrt(2) - 1) * a**2)
    assert R.sharpness_from_alpha(a, "ggx") / ggx == pytest.approx(1.0, rel=1e-9)


@pytest.mark.parametrize("distribution", ["ggx", "beckmann"])
def test_alpha_sharpness_roundtrip_and_domain(distribution):
    alpha = np.array([[1e-3, 0.05], [0.4, 1.0]])
    back = R.alpha_from_sharpness(R.sharpness_from_alpha(alpha, distribution), distribution)
    assert back.shape == (2, 2)
    np.testing.assert_allclose(back, alpha, rtol=1e-12, atol=0)  # closed forms, a few ulp
    assert np.isinf(R.sharpness_from_alpha(0.0, distribution))
    assert R.alpha_from_sharpness(np.inf, distribution) == 0.0
    out = R.sharpness_from_alpha([np.nan, -0.1, 2.0], distribution)  # NaN, negative, too rough
    assert np.all(np.isnan(out))
    assert np.all(np.isnan(R.alpha_from_sharpness([np.nan, 0.0, -2.0], distribution)))


def test_distribution_choice_checked():
    with pytest.raises(ValueError, match="distribution must be one of 'ggx', 'beckmann'"):
        R.sharpness_from_alpha(0.1, "phong")
    with pytest.raises(ValueError, match="exactly one of sharpness or alpha"):
        R.lobe_hwhm()


# -- Eq 5 as a Mitsuba blend --------------------------------------------------

def test_paper_material_dict():
    d = paper_material(0.2, 300.0)
    alpha = R.alpha_from_sharpness(300.0, "ggx")
    assert d["type"] == "blendbsdf"
    assert d["bsdf_0"]["type"] == "diffuse" and d["bsdf_1"]["type"] == "roughconductor"
    assert d["bsdf_1"]["distribution"] == "ggx" and d["bsdf_1"]["material"] == "none"
    assert d["bsdf_1"]["alpha"] == pytest.approx(alpha, abs=EXACT)
    w = d["weight"]
    # Peak specular / diffuse slope of the blend equals Eq 5's (1-k)/(2k):
    # w D(0) / 4 over (1-w) rho / pi, D(0) = 1 / (pi alpha^2).
    ratio = (w / (4 * np.pi * alpha**2)) / ((1 - w) / np.pi)
    assert ratio == pytest.approx((1 - 0.2) / (2 * 0.2), rel=EXACT)


def test_blend_weight_limits_and_errors():
    np.testing.assert_allclose(blend_weight([0.0, 1.0], 100.0), [1.0, 0.0], rtol=0, atol=EXACT)
    with pytest.raises(ValueError, match=r"k must lie in \[0, 1\]"):
        blend_weight(-0.1, 100.0)
    with pytest.raises(ValueError, match="sharpness must be finite and > 0"):
        paper_material(0.5, 0.0)


# -- figures (smoke test: labelled axes, no warnings) ------------------------

def test_fig03_and_fig04_build():
    pytest.importorskip("matplotlib")
    from shinysim.plot import theory as plots

    fig = plots.fig03_reflectance_map(shape=(41, 41))
    ax = fig.axes[0]
    assert ax.get_xlabel().startswith("p") and ax.get_ylabel().startswith("q")
    fig = plots.fig04_reflectance_map_array(layout="semicircle", shape=(41, 41))
    assert "21 SHINY fibers" in fig.axes[0].get_title()
    assert plots.shiny_source_directions().shape == (21, 3)
    with pytest.raises(ValueError, match="layout must be one of 'semicircle', 'dome'"):
        plots.fig04_reflectance_map_array(layout="ring")
