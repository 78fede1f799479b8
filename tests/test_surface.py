"""Surfaces z(x, y) from sparse normals: exact answers, no renderer."""

import numpy as np
import pytest
from conftest import circle

from shinysim.conventions import normal_from_gradient
from shinysim.recon.surface import SurfaceParams, surface_from_normals

# -- surfaces -------------------------------------------------------------------------


def test_surface_of_a_plane_is_exact():
    a, b, c = 0.4, -0.2, 0.05
    rng = np.random.default_rng(2)
    x = rng.uniform(0, 0.2, 60)
    y = rng.uniform(-0.1, 0.1, 60)
    n = normal_from_gradient(np.full(60, a), np.full(60, b))
    anchors = [[0.0, 0.0, c]]
    s = surface_from_normals(x, y, n, anchors=anchors, bounds=(0, 0.2, -0.1, 0.1), step_mm=0.01)
    X, Y = np.meshgrid(s.x, s.y)
    assert np.allclose(s.z, a * X + b * Y + c, atol=1e-8)
    assert s.n_used > 0
    assert s.z_at(0.1, 0.05) == pytest.approx(a * 0.1 + b * 0.05 + c, abs=1e-8)


def test_surface_of_a_swept_arc_is_close():
    z, p = circle(0.1, 0.45, 0.4)
    xs = np.linspace(-0.15, 0.05, 12)
    ys = np.linspace(-0.08, 0.08, 9)
    X, Y = np.meshgrid(xs, ys)
    n = normal_from_gradient(p(X), 0 * X).reshape(-1, 3)
    anchors = np.column_stack([np.full(5, -0.15), np.linspace(-0.08, 0.08, 5), np.full(5, z(-0.15))])
    s = surface_from_normals(X.ravel(), Y.ravel(), n, anchors=anchors, bounds=(-0.15, 0.05, -0.08, 0.08),
                             step_mm=0.005)
    GX, GY = np.meshgrid(s.x, s.y)
    err = s.z - z(GX)
    inner = (np.abs(GY) < 0.07)
    assert np.nanmax(np.abs(err[inner])) < 2e-3  # sparse data, thin-plate gaps: a few micrometres
    assert np.sqrt(np.nanmean(err[inner] ** 2)) < 1e-3


def test_surface_without_anchor_has_zero_mean_and_checks_input():
    x = np.linspace(0, 0.1, 20)
    n = normal_from_gradient(np.full(20, 0.3), np.zeros(20))
    s = surface_from_normals(x, np.zeros(20), n, bounds=(0, 0.1, -0.02, 0.02), step_mm=0.01)
    assert abs(np.nanmean(s.z)) < 1e-12
    with pytest.raises(ValueError, match="nothing to integrate"):
        surface_from_normals([], [], np.zeros((0, 3)))
    with pytest.raises(ValueError, match="more than max_nodes"):
        surface_from_normals(x, np.zeros(20), n, bounds=(0, 1, 0, 1), step_mm=0.001)
    with pytest.raises(ValueError, match="smoothness must be > 0"):
        SurfaceParams(smoothness=0)
