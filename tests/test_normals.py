"""The three camera models against geometry with known answers."""

import numpy as np
import pytest

from shinysim._shared import EXACT_TOL as TOL
from shinysim.conventions import angle_between, bisector
from shinysim.recon import PAPER_MODELS, highlight_normals, surface_points
from shinysim.rig import Camera, distant_rig, shiny_1988


@pytest.mark.parametrize("projection", ["orthographic", "perspective"])
def test_fixed_model_is_eq10(projection):
    """'fixed' halves each source's polar angle and keeps its azimuth (Eq 10)."""
    rig = shiny_1988(projection=projection)
    angles = np.radians(rig.metadata["source_angles_deg"])
    rows = np.full(21, 100.0)
    cols = np.linspace(50, 450, 21)
    n = highlight_normals(rows, cols, np.arange(21), rig, model="fixed")
    expect = np.stack([np.sin(angles / 2), np.zeros(21), np.cos(angles / 2)], axis=1)
    np.testing.assert_allclose(n, expect, atol=TOL)


@pytest.mark.parametrize("projection", ["orthographic", "perspective"])
def test_models_exact_for_points_on_the_plane(projection, np_rng):
    """A mirror facet *on* the reference plane: the perspective model is exact."""
    rig = shiny_1988(projection=projection)
    cam = rig.camera
    rows = np_rng.uniform(0, 511, 30)
    cols = np_rng.uniform(0, 511, 30)
    src = np_rng.integers(0, 21, 30)
    p = cam.backproject_to_plane(rows, cols)
    truth = bisector(rig.source_positions[src] - p, cam.view_directions(p))
    n = highlight_normals(rows, cols, src, rig, model="perspective")
    np.testing.assert_allclose(n, truth, atol=TOL)
    if projection == "orthographic":
        # parallel rays: the orthographic model is the perspective one
        n_o = highlight_normals(rows, cols, src, rig, model="orthographic")
        np.testing.assert_allclose(n_o, truth, atol=TOL)
    else:
        # ignoring the perspective tilts the view direction by atan(|x| / H); the
        # half vector of s and v moves by at most that over 2 cos(theta / 2),
        # theta the angle between source and view (|s + v| = 2 cos(theta / 2))
        n_o = highlight_normals(rows, cols, src, rig, model="orthographic")
        err = angle_between(n_o, truth)
        view = np.arctan(np.linalg.norm(p[:, :2], axis=1) / cam.position[2])
        theta = angle_between(rig.source_positions[src] - p, cam.view_directions(p))
        assert np.all(err <= view / (2 * np.cos(theta / 2)) + 1e-9)
        assert np.all(err > 0)


def test_distant_sources_make_models_agree(np_rng):
    cam = Camera("orthographic", 64, 48, [0, 0, 100], [0, 0, 0], [0, 1, 0], 6.0)
    dirs = np_rng.normal(size=(5, 3))
    dirs[:, 2] = np.abs(dirs[:, 2]) + 0.5
    rig = distant_rig(dirs, cam)
    rows = np_rng.uniform(0, 47, 5)
    cols = np_rng.uniform(0, 63, 5)
    ns = [highlight_normals(rows, cols, np.arange(5), rig, model=m) for m in PAPER_MODELS]
    for n in ns[1:]:
        np.testing.assert_allclose(n, ns[0], atol=TOL)
    np.testing.assert_allclose(ns[0], bisector(dirs, [0, 0, 1]), atol=TOL)


def test_surface_points_and_bad_model():
    rig = shiny_1988()
    p = surface_points([255.5], [255.5], rig, model="orthographic")
    np.testing.assert_allclose(p, [[0, 0, 0]], atol=TOL)
    p = surface_points([0.0], [0.0], rig, model="fixed", plane_z=0.2)
    np.testing.assert_allclose(p, [[0, 0, 0.2]], atol=TOL)
    with pytest.raises(ValueError, match="model must be one of"):
        highlight_normals([1.0], [1.0], [0], rig, model="weak-perspective")
