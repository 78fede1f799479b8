"""The paper's profile procedure from sparse normals: exact answers, no renderer."""

import numpy as np
import pytest
from conftest import circle

from shinysim._shared import EXACT_MM_TOL as TOL
from shinysim.conventions import normal_from_gradient
from shinysim.errors import OptionError
from shinysim.recon.profile import (
    ProfileParams,
    arc_from_curvature,
    circular_arc,
    end_curvature,
    predict_slope_angle,
    profile_from_normals,
    slope_angle_from_normal,
)


def normals_of(p, x):
    return normal_from_gradient(p(x), np.zeros_like(x))


# -- circular interpolation -------------------------------------------------------


def test_circular_arc_quarter_circle():
    """From the bottom of a unit circle (slope 0) to 60 deg: the exact arc."""
    z, phi = circular_arc(0.0, 0.0, 0.0, np.sin(np.radians(60)), np.radians(60), [0.0, 0.5, np.sin(np.radians(60))])
    assert np.allclose(z, [0.0, 1 - np.sqrt(0.75), 0.5], atol=TOL)
    assert np.allclose(phi, [0.0, np.arcsin(0.5), np.radians(60)], atol=TOL)


def test_circular_arc_straight_line_and_far_point():
    z, phi = circular_arc(1.0, 2.0, 0.3, 3.0, 0.3, [1.0, 2.0, 5.0])
    assert np.allclose(z, 2.0 + np.tan(0.3) * np.array([0.0, 1.0, 4.0]), atol=TOL)
    assert np.allclose(phi, 0.3)
    # beyond the circle's reach the answer is NaN, not an exception
    z, _ = circular_arc(0.0, 0.0, 0.0, 0.5, np.radians(30), [10.0])
    assert np.isnan(z).all()


def test_arc_from_curvature_matches_circular_arc():
    x0, phi0, x1, phi1 = 0.1, 0.2, 0.3, 0.9
    kappa = (np.sin(phi1) - np.sin(phi0)) / (x1 - x0)
    xs = np.linspace(0.0, 0.35, 9)
    za, pa = arc_from_curvature(x0, 0.5, phi0, kappa, xs)
    zb, pb = circular_arc(x0, 0.5, phi0, x1, phi1, xs)
    assert np.allclose(za, zb, atol=TOL, equal_nan=True)
    assert np.allclose(pa, pb, atol=TOL, equal_nan=True)


def test_end_curvature_of_circle_points():
    z, p = circle(0.2, 0.6, 0.5)
    x = np.array([-0.1, 0.0, 0.05, 0.1, 0.2])
    phi = np.arctan(p(x))
    # on a circle of radius R, sin(phi) runs linearly in x with slope 1/R
    assert end_curvature(x, phi, "left", 3) == pytest.approx(1 / 0.5, abs=1e-9)
    assert end_curvature(x, phi, "right", 5) == pytest.approx(1 / 0.5, abs=1e-9)
    assert end_curvature(x[:1], phi[:1], "left", 3) == 0.0


def test_slope_angle_from_normal():
    phi = np.radians([-60.0, 0.0, 30.0, 80.0])
    n = normal_from_gradient(np.tan(phi), 0 * phi)
    assert np.allclose(slope_angle_from_normal(n), phi, atol=1e-12)
    # n-dimensional input, and normals facing down give NaN without raising
    nd = np.tile(n, (2, 1)).reshape(2, 4, 3)
    assert slope_angle_from_normal(nd).shape == (2, 4)
    assert np.isnan(slope_angle_from_normal([[0.0, 0.0, -1.0], [np.nan, 0, 1]])).all()


# -- profiles ---------------------------------------------------------------------


@pytest.mark.parametrize("sign", [-1, 1], ids=["concave", "convex"])
def test_circle_profile_is_exact(sign):
    """Sparse exact normals of a circular fillet, anchored outside the data: exact z(x)."""
    R, xc = 0.4, 0.1
    z, p = circle(xc, 0.45 if sign < 0 else -0.2, R, sign)
    rng = np.random.default_rng(1)
    x = np.sort(rng.uniform(-0.2, 0.05, 12))
    xa = -0.23
    pr = profile_from_normals(x, normals_of(p, x), anchor=(xa, z(xa)), max_gap_mm=0.1, max_angle_deg=30,
                              anchor_gap_mm=0.1)
    assert pr.n_segments == 1 and pr.anchored.all()
    # exact on the grid nodes ...
    on = np.isfinite(pr.z)
    assert pr.x[on].min() == pytest.approx(xa) and on.sum() > 250
    assert np.max(np.abs(pr.z[on] - z(pr.x[on]))) < 1e-9
    # ... and between them up to linear interpolation, |z''| h^2 / 8
    xx = np.linspace(xa, x.max(), 301)
    err = pr.z_at(xx) - z(xx)
    assert np.all(np.isfinite(err))
    zpp = np.max(np.abs(np.gradient(p(xx), xx)))
    assert np.max(np.abs(err)) <= zpp * pr.params.step_mm**2 / 8 * 1.01
    assert np.allclose(pr.points["z"], z(pr.points["x"]), atol=1e-8)
    # slopes of the interpolated profile are exact too
    nz = pr.normal_at(xx[1:-1])
    assert np.allclose(nz, normals_of(p, xx[1:-1]), atol=1e-7)
    # the extrapolated part is marked
    assert pr.extrapolated[pr.x < x.min() - 1e-6].all()
    assert not pr.extrapolated[(pr.x > x.min() + 1e-6) & np.isfinite(pr.z)].any()


def test_line_profile_is_exact_with_and_without_smoothing():
    a, b = 0.7, 0.05
    x = np.array([0.0, 0.013, 0.02, 0.05, 0.051, 0.09])
    n = normal_from_gradient(np.full(6, a), np.zeros(6))
    for smooth in (0.0, 0.01):
        pr = profile_from_normals(x, n, anchor=(0.0, b), smooth_mm=smooth, max_gap_mm=0.05)
        assert np.allclose(pr.z_at(np.linspace(0, 0.09, 50)), b + a * np.linspace(0, 0.09, 50), atol=TOL)


def test_smoothing_barely_moves_an_arc():
    z, p = circle(0.0, 0.5, 0.5)
    x = np.linspace(-0.2, 0.2, 9)
    exact = profile_from_normals(x, normals_of(p, x), anchor=(x[0], z(x[0])), max_gap_mm=0.1)
    smooth = profile_from_normals(x, normals_of(p, x), anchor=(x[0], z(x[0])), max_gap_mm=0.1, smooth_mm=0.01)
    d = smooth.z - exact.z
    # a moving average of width w on curvature k changes z by about k w^2 / 24
    assert np.nanmax(np.abs(d)) < 2.0 * 0.01**2 / 24 / 0.5 * 1.5


def test_step_is_a_discontinuity_with_unknown_height():
    """Two flat terraces with no sample on the riser: two segments, the second floating."""
    x = np.concatenate([np.linspace(0, 0.1, 6), np.linspace(0.3, 0.4, 6)])
    n = normal_from_gradient(np.zeros(12), np.zeros(12))
    pr = profile_from_normals(x, n, anchor=(0.0, 0.035), max_gap_mm=0.05)
    assert pr.n_segments == 2
    assert pr.anchored.tolist() == [True, False]
    assert np.allclose(pr.gaps, [[0.1, 0.3]])
    inside_gap = (pr.x > 0.1 + 1e-6) & (pr.x < 0.3 - 1e-6)
    assert np.isnan(pr.z[inside_gap]).all() and (pr.segment[inside_gap] == -1).all()
    assert np.allclose(pr.z_at([0.0, 0.05, 0.1]), 0.035, atol=TOL)
    # the upper terrace's shape is known (flat), its height is not
    assert np.isnan(pr.z_at([0.35], anchored_only=True)).all()
    assert np.allclose(pr.z_at([0.3, 0.35, 0.4]), 0.0, atol=TOL)


def test_angle_jump_breaks_the_profile():
    """A ridge: neighbours close in x but 40 deg apart in normal are not joined."""
    x = np.array([0.0, 0.01, 0.02, 0.03, 0.04, 0.05])
    phi = np.radians([20, 20, 20, -20, -20, -20])
    n = normal_from_gradient(np.tan(phi), 0 * phi)
    pr = profile_from_normals(x, n, max_angle_deg=15, max_gap_mm=0.05)
    assert pr.n_segments == 2
    assert not pr.anchored.any()


def test_merging_weights_duplicate_measurements():
    x = np.array([0.0, 0.0005, 0.05])
    phi = np.radians([10.0, 20.0, 10.0])
    n = normal_from_gradient(np.tan(phi), 0 * phi)
    pr = profile_from_normals(x, n, weights=[3.0, 1.0, 1.0], merge_mm=0.002)
    assert len(pr.points["x"]) == 2
    assert pr.points["x"][0] == pytest.approx(0.000125)
    assert np.degrees(pr.points["phi"][0]) == pytest.approx(12.5)
    assert pr.points["count"].tolist() == [2, 1]


def test_nan_rows_are_dropped_and_empty_input_gives_an_empty_profile():
    x = np.array([0.0, np.nan, 0.02])
    n = normal_from_gradient(np.array([0.1, 0.1, 0.1]), np.zeros(3))
    n[2] = np.nan
    pr = profile_from_normals(x, n)
    assert len(pr.points["x"]) == 1
    empty = profile_from_normals([], np.zeros((0, 3)))
    assert empty.n_segments == 0 and len(empty.x) == 0
    assert np.isnan(empty.z_at([0.0])).all()


def test_profile_input_checks():
    n = normal_from_gradient(np.zeros(3), np.zeros(3))
    with pytest.raises(OptionError, match=r"normals: must have shape \(2, 3\)"):
        profile_from_normals([0.0, 1.0], n)
    with pytest.raises(OptionError, match="weights: must have shape"):
        profile_from_normals([0, 1, 2], n, weights=[1, 2])
    with pytest.raises(OptionError, match="weights: must be >= 0"):
        profile_from_normals([0, 1, 2], n, weights=[1, -2, 1])
    with pytest.raises(OptionError, match="anchor: must be"):
        profile_from_normals([0, 1, 2], n, anchor=(0.0, np.nan))
    with pytest.raises(OptionError, match="max_gap_mm must be > 0"):
        ProfileParams(max_gap_mm=0)
    with pytest.raises(OptionError, match="end_fit_points must be >= 2"):
        ProfileParams(end_fit_points=1)


def test_predict_slope_angle_inside_and_beyond():
    z, p = circle(0.1, 0.45, 0.4)
    x = np.linspace(-0.15, 0.0, 6)
    pr = profile_from_normals(x, normals_of(p, x), max_gap_mm=0.1)
    q = np.array([-0.2, -0.1, 0.03])
    phi, dist = predict_slope_angle(pr, q)
    assert np.allclose(phi, np.arctan(p(q)), atol=1e-9)
    assert np.allclose(dist, [0.05, 0.0, 0.03])
    # a one-point segment predicts nothing
    single = profile_from_normals([0.0], normals_of(p, np.array([0.0])))
    phi, dist = predict_slope_angle(single, [0.01])
    assert np.isnan(phi).all() and np.isinf(dist).all()


def test_one_point_profile_heights():
    # a profile of a single measured point (a joint that shows one highlight):
    # its own height there, its slope within one grid step, NaN further out
    n = normal_from_gradient(np.array([0.5]), np.array([0.0]))
    pr = profile_from_normals(np.array([0.1]), n, anchor=(0.1, 0.035))
    step = pr.params.step_mm
    z = pr.z_at(np.array([pr.x[0], pr.x[0] + step / 2, pr.x[0] + 10 * step]))
    assert len(pr.x) == 1
    assert z[0] == pytest.approx(pr.z[0], abs=TOL)
    assert z[1] == pytest.approx(pr.z[0] + 0.5 * step / 2, abs=TOL)
    assert np.isnan(z[2])
