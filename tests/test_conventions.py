import numpy as np
import pytest

from shinysim import conventions as cv
from shinysim._shared import (
    EXACT_TOL as TOL,  # identities of float64 trigonometry hold to a few ulps
)


def test_inch_mm_exact():
    assert cv.inch_to_mm(1.7) == pytest.approx(43.18, abs=TOL)
    assert cv.mm_to_inch(25.4) == 1.0


def test_direction_angles_roundtrip_nd(np_rng):
    theta = np_rng.uniform(0, np.pi, (2, 3))
    phi = np_rng.uniform(-np.pi, np.pi, (2, 3))
    v = cv.direction_from_angles(theta, phi)
    assert v.shape == (2, 3, 3)
    t2, p2 = cv.angles_from_direction(v)
    np.testing.assert_allclose(t2, theta, atol=1e-9)
    np.testing.assert_allclose(np.cos(p2 - phi), 1.0, atol=1e-9)


def test_gradient_normal_roundtrip():
    p = np.array([0.3, -1.2, 0.0])
    q = np.array([-0.4, 0.5, 0.0])
    n = cv.normal_from_gradient(p, q)
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=TOL)
    p2, q2 = cv.gradient_from_normal(n)
    np.testing.assert_allclose(p2, p, atol=TOL)
    np.testing.assert_allclose(q2, q, atol=TOL)


def test_surface_slope_sign():
    # z = 0.5 x rises towards +x, so its normal leans towards -x
    n = cv.normal_from_gradient(0.5, 0.0)
    assert n[0] < 0 and n[2] > 0


def test_bisector_is_mirror_law():
    s = cv.direction_from_angles(np.radians(60.0), 0.3)
    n = cv.bisector(s, cv.VIEW_UP)
    # reflecting the view direction about n gives the source direction
    r = 2 * np.dot(n, cv.VIEW_UP) * n - cv.VIEW_UP
    np.testing.assert_allclose(r, s, atol=TOL)
    # and the polar angle is halved (paper Eq 10)
    assert cv.angles_from_direction(n)[0] == pytest.approx(np.radians(30.0), abs=TOL)


def test_angle_between_small_and_nan():
    a = np.array([1.0, 0.0, 0.0])
    b = np.array([np.cos(1e-9), np.sin(1e-9), 0.0])
    assert cv.angle_between(a, b) == pytest.approx(1e-9, rel=1e-6)
    assert np.isnan(cv.angle_between(a, [np.nan, 0, 0]))
    assert np.all(np.isnan(cv.normalize([0.0, 0.0, 0.0])))


def test_elevation_from_x():
    assert cv.elevation_from_x([0, 0, 1]) == pytest.approx(np.pi / 2)
    assert cv.elevation_from_x([1, 0, 1]) == pytest.approx(np.pi / 4)
