import numpy as np
import pytest

from shinysim.conventions import normalize
from shinysim.evaluate import (
    error_stats,
    nearest_point_to_lines,
    percent_error,
    sample_truth,
    score_normals,
)
from shinysim.io import Truth


def sphere_truth(h=64, w=64, r_px=25.0, pitch=0.01):
    rows, cols = np.indices((h, w), dtype=float)
    x = (cols - (w - 1) / 2) / r_px
    y = -(rows - (h - 1) / 2) / r_px
    mask = x**2 + y**2 < 1
    n = np.full((h, w, 3), np.nan)
    n[mask] = np.stack([x[mask], y[mask], np.sqrt(1 - x[mask] ** 2 - y[mask] ** 2)], axis=1)
    p = n * r_px * pitch
    return Truth(n, p, mask)


def test_nearest_point_exact(np_rng):
    c = np.array([0.3, -0.2, 0.1])
    d = normalize(np_rng.normal(size=(10, 3)))
    pts = c + d * np_rng.uniform(1, 2, (10, 1))
    x, rms = nearest_point_to_lines(pts, d)
    np.testing.assert_allclose(x, c, atol=1e-12)
    assert rms < 1e-12


def test_error_stats():
    s = error_stats([1.0, 2.0, 3.0, np.nan])
    assert s["n"] == 3 and s["mean_deg"] == 2.0 and s["median_deg"] == 2.0 and s["max_deg"] == 3.0
    assert np.isnan(error_stats([])["mean_deg"])


def test_percent_error_paper_angle():
    # 0.9 deg off a vertical normal is 1 % of Theta = 90 deg
    up = np.array([0.0, 0.0, 1.0])
    tilted = np.array([np.sin(np.radians(0.9)), 0.0, np.cos(np.radians(0.9))])
    assert percent_error(tilted, up) == pytest.approx(1.0, rel=1e-9)


def test_sample_truth_and_score():
    t = sphere_truth()
    rows = np.array([31.5, 20.25, 0.0])
    cols = np.array([31.5, 40.75, 0.0])
    n, p, valid = sample_truth(t, rows, cols)
    assert list(valid) == [True, True, False]  # the corner is off the sphere
    np.testing.assert_allclose(n[0], [0, 0, 1], atol=1e-12)
    # bilinear interpolation of a smooth field: error O(h^2 |curvature|) ~ 1e-3 rad here
    x, y = (40.75 - 31.5) / 25, -(20.25 - 31.5) / 25
    exact = [x, y, np.sqrt(1 - x * x - y * y)]
    assert np.degrees(np.arccos(np.clip(n[1] @ exact, -1, 1))) < 0.05
    # recovered normals 1 deg off: score says so, ignores the invalid one
    rot = np.radians(1.0)
    est = np.array([[np.sin(rot), 0, np.cos(rot)], exact, [0, 0, 1]])
    s = score_normals(rows, cols, est, t, sphere_center=(0, 0, 0), sphere_radius=0.25)
    assert s["n"] == 2 and s["n_invalid"] == 1
    assert s["max_deg"] == pytest.approx(1.0, abs=0.05)
