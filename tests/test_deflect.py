"""Display deflectometry's reconstruction against exact answers: the lattice walk, the pose, the slopes.

Every case here is made analytically (no renderer): a lattice of dots with
a known index, a facet of known shape and pose, the exact screen point each
camera ray sees. ``tests/test_sofast.py`` holds the same code against
SOFAST's real measurement.
"""

from __future__ import annotations

import numpy as np
import pytest

from shinysim.errors import OptionError
from shinysim.evaluate.deflect import compare_slopes, detilt
from shinysim.recon.deflect import (SlopeParams, facet_corners, pose_from_points, rotation_matrix, solve_slopes,
                                    _intersect)
from shinysim.recon.dots import DotParams, index_dots
from shinysim.rig import Camera


def own_frame_camera(width=800, height=600, fx=2000.0):
    """A perspective camera whose world frame is its own (at the origin, +z forward, +x columns, +y rows)."""
    return Camera("perspective", width, height, position=(0, 0, 0), target=(0, 0, 1000.0), up=(0, -1, 0),
                  field_width=width * 1000.0 / fx)


def warped_lattice(n=40, pitch=10.0, seed=0, noise=0.03):
    """Dot image positions (row, col) of an n x n index grid under a smooth warp, and their indices."""
    rng = np.random.default_rng(seed)
    ix, iy = np.meshgrid(np.arange(n) - n // 2, np.arange(n) - n // 2)
    ix, iy = ix.ravel(), iy.ravel()
    col = 400 + pitch * ix + 0.8 * np.sin(ix / 6.0) * pitch * 0.3 + 0.002 * pitch * ix * iy
    row = 300 + pitch * iy * 1.05 + 0.25 * pitch * np.cos(iy / 5.0 + ix / 9.0)
    return row + rng.normal(0, noise, row.shape), col + rng.normal(0, noise, col.shape), np.column_stack([ix, iy])


def test_lattice_walk_places_every_dot_at_its_index_through_gaps_and_clutter():
    row, col, truth = warped_lattice()
    rng = np.random.default_rng(1)
    keep = rng.random(len(row)) > 0.05  # 5 % of the dots missing
    keep[np.flatnonzero((truth[:, 0] == 0) & (truth[:, 1] == 0))] = True
    row, col, truth = row[keep], col[keep], truth[keep]
    origin = int(np.flatnonzero((truth[:, 0] == 0) & (truth[:, 1] == 0))[0])
    found = index_dots(row, col, (row[origin] + 1.0, col[origin] - 1.0))
    right = np.all(found.index == truth, axis=1)
    # a wrong index is never assigned; and the walk reaches (almost) every dot across 1-dot gaps
    assert not np.any(found.identified & ~right)
    assert found.identified.mean() > 0.97


def test_lattice_walk_assigns_no_wrong_index_across_a_seam():
    # two facets: beyond col 400 the reflected grid jumps by exactly one pitch, so the lattice continues
    # seamlessly to a wrong index; the walk limited to the first facet's region never enters it
    row, col, truth = warped_lattice(noise=0.0)
    beyond = col > 400
    col = np.where(beyond, col + 10.0 * 1.0 + 4.0, col)  # a gap of 4 px and one pitch: indices shift by one
    region = np.zeros((600, 1000), bool)
    region[:, :402] = True
    origin = int(np.flatnonzero((truth[:, 0] == -5) & (truth[:, 1] == 0))[0])
    found = index_dots(row, col, (row[origin], col[origin]), (-5, 0), region=region)
    assert not np.any(found.identified & beyond)
    assert np.all(found.index[found.identified] == truth[found.identified])


def test_lattice_walk_leaves_out_a_dot_that_sits_between_two_sites():
    row, col, truth = warped_lattice(noise=0.0)
    k = int(np.flatnonzero((truth[:, 0] == 3) & (truth[:, 1] == 3))[0])
    j = int(np.flatnonzero((truth[:, 0] == 4) & (truth[:, 1] == 3))[0])
    col[k] = 0.5 * (col[k] + col[j])  # dot (3, 3) moved half-way to (4, 3): it is not where either belongs
    origin = int(np.flatnonzero((truth[:, 0] == 0) & (truth[:, 1] == 0))[0])
    found = index_dots(row, col, (row[origin], col[origin]))
    assert not np.any(found.identified & ~np.all(found.index == truth, axis=1))
    assert not found.identified[k]


def test_lattice_walk_refuses_an_origin_with_no_dot():
    row, col, _ = warped_lattice()
    with pytest.raises(OptionError, match="no dot within a pitch"):
        index_dots(row, col, (-100.0, -100.0))
    with pytest.raises(OptionError, match="check"):
        DotParams(check=0.9)


def _facet_geometry(seed=0, focal=(-136e3, -146e3), n=400):
    """Exact rays and screen points of a paraboloid facet 9.4 m from the camera (SOFAST-like)."""
    rng = np.random.default_rng(seed)
    coefs = np.array([0.0, 0.0, 1 / (4 * focal[0]), 0.0, 0.0, 1 / (4 * focal[1])])
    cam = np.array([-1660.0, -24.0, 9300.0])  # camera centre in the facet frame
    xy = rng.uniform(-600, 600, (n, 2))
    z = coefs[2] * xy[:, 0] ** 2 + coefs[5] * xy[:, 1] ** 2
    pts = np.column_stack([xy, z])
    slopes = np.column_stack([2 * coefs[2] * xy[:, 0], 2 * coefs[5] * xy[:, 1]])
    normal = np.column_stack([-slopes, np.ones(n)])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    inc = pts - cam
    inc /= np.linalg.norm(inc, axis=1, keepdims=True)
    out = inc - 2 * np.sum(inc * normal, axis=1, keepdims=True) * normal
    screen = pts + out * rng.uniform(9000, 11000, (n, 1))
    return cam, inc, screen, pts, slopes


def test_slopes_of_an_exact_paraboloid_are_exact_with_the_pose_known():
    cam, rays, screen, pts, slopes = _facet_geometry()
    sol = solve_slopes(cam, rays, screen, screen_origin_mm=screen.mean(axis=0), measure_ray=-cam, distance_mm=1e4,
                       params=SlopeParams(align="none", loops=(1, 30)))
    # the loop's fixed point is the true surface: rounding only (slopes ~1e-3, float64)
    assert np.max(np.abs(sol.slopes - slopes)) < 1e-12
    assert np.max(np.abs(sol.points_mm - pts)) < 1e-6
    np.testing.assert_allclose(sol.focal_lengths_mm, (-136e3, -146e3), rtol=1e-9)


def test_ray_meets_a_flat_paraboloid_exactly():
    dirs = np.array([[0.1, -0.2, -1.0], [0.0, 0.0, -1.0]])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    p = _intersect(np.array([5.0, 0, 0, 0, 0, 0]), np.array([1.0, 2.0, 100.0]), dirs)
    np.testing.assert_allclose(p[:, 2], 5.0, atol=1e-12)


def test_centre_alignment_removes_a_pose_tilt_and_keeps_the_shape():
    cam, rays, screen, pts, slopes = _facet_geometry(seed=2)
    tilt = rotation_matrix([0.02, -0.03, 0.0])  # the scene seen through a pose 36 mrad off
    sol = solve_slopes(cam @ tilt.T, rays @ tilt.T, screen @ tilt.T, screen_origin_mm=screen.mean(axis=0) @ tilt.T,
                       measure_ray=-(cam @ tilt.T), distance_mm=float(np.linalg.norm(screen.mean(axis=0))))
    # the alignment turns the fitted centre normal onto +z: the slope field's constant part is gone and its
    # shape (the focal lengths) is kept to the second order of the tilt (36 mrad: ~0.1 %)
    fit = np.linalg.lstsq(np.column_stack([np.ones(len(pts)), sol.points_mm[:, :2]]), sol.slopes, rcond=None)[0]
    assert np.max(np.abs(fit[0])) < 1e-9
    np.testing.assert_allclose(sol.focal_lengths_mm, (-136e3, -146e3), rtol=5e-3)
    angle = np.arccos((np.trace(sol.alignment) - 1) / 2)
    assert angle == pytest.approx(np.hypot(0.02, 0.03), rel=0.05)


def test_pose_from_four_corners_is_exact_and_corners_from_a_mask_are_close():
    cam = own_frame_camera()
    corners = np.array([[300.0, -300, 0], [-300, -300, 0], [-300, 300, 0], [300, 300, 0]])
    R = rotation_matrix([0.05, 0.3, 0.02])
    t = np.array([40.0, -30.0, 6000.0])
    r, c = cam.project(corners @ R.T + t)
    R1, t1, rms = pose_from_points(cam, np.column_stack([r, c]), corners, rotation_matrix([0, 0.25, 0]),
                                   t + (100, 50, -300))
    assert rms < 1e-6
    np.testing.assert_allclose(R1, R, atol=1e-9)
    np.testing.assert_allclose(t1, t, atol=1e-5)
    # a mask of the facet's image: the corners from its edges within a pixel's tenth of the projection
    # the facet's image, anti-aliased (each pixel's covered fraction, 8 x 8 samples): its edge at level 0.5
    # is the true edge to ~1/16 px, and the corners from lines fitted to it well within 0.2 px
    sub = (np.arange(8) + 0.5) / 8 - 0.5
    rr = np.arange(cam.height)[:, None, None, None] + sub[None, None, :, None]
    cc = np.arange(cam.width)[None, :, None, None] + sub[None, None, None, :]
    side = [(r[(k + 1) % 4] - r[k]) * (cc - c[k]) - (c[(k + 1) % 4] - c[k]) * (rr - r[k]) for k in range(4)]
    inside = np.all(np.array(side) <= 0, axis=0) | np.all(np.array(side) >= 0, axis=0)
    image = inside.mean(axis=(2, 3))
    found, side_rms = facet_corners(image, cam, np.column_stack([r, c]) + 3.0)
    assert np.max(np.abs(found - np.column_stack([r, c]))) < 0.2
    assert np.all(side_rms < 0.5)


def test_compare_slopes_matches_points_and_detilts():
    rng = np.random.default_rng(3)
    pts = rng.uniform(-500, 500, (300, 3))
    ref = rng.normal(0, 1e-3, (300, 2))
    tilted = ref + 1e-4 + 2e-7 * pts[:, :2]  # 0.1 mrad tilt and a linear bend
    c = compare_slopes(pts + 0.1, tilted, pts, ref)
    assert c["matched"] == 300 and c["unmatched"] == 0
    assert c["rms_mrad"] > 0.1
    assert c["detilted"]["rms_mrad"] < 1e-9
    np.testing.assert_allclose(detilt(pts, tilted - ref), 0, atol=1e-15)


def test_a_display_is_a_rig_of_one_source_per_dot():
    from shinysim.objects.mirror import MirrorFacet
    from shinysim.rig import Rig
    from shinysim.rig.display import SOFAST_FACET_CENTRE_MM, Display, DisplaySetup, facet_pose
    from shinysim.studies.deflect import sofast_geometry

    cam, rot, origin, dots, xi, yi, _ = sofast_geometry(None)  # the built-in 85 x 85 grid
    R, t = facet_pose(cam.position, origin, SOFAST_FACET_CENTRE_MM, cam.right)
    setup = DisplaySetup(Display(dots, xi, yi), cam, rot, origin, MirrorFacet(606.0, 606.0), R, t)
    rig = setup.rig()
    assert rig.n_sources == 85 * 85
    back = Rig.from_json(rig.to_json())
    np.testing.assert_array_equal(back.source_positions, rig.source_positions)
    assert back.cameras[0].distortion == cam.distortion and back.cameras[0].aspect == cam.aspect
    meta = back.metadata["display"]
    k = meta["x_index"].index(3)  # the first source of x index 3 is in the first grid row
    assert meta["y_index"][k] == yi[0]
    np.testing.assert_allclose(rig.source_positions[k], setup.dots_camera_mm()[0, 3 - xi[0]])


@pytest.mark.parametrize("argv, words", [
    (["--twin", "--mode", "fringe", "--size", "full"], "small facet only"),
    (["--sofast", "nowhere", "--sensor", "tv_1980s_8bit"], "are for the fringe twin"),
    (["--sofast", "nowhere", "--size", "full"], "is for the twin"),
    (["--sofast", "nowhere"], "no such folder"),
])
def test_deflect_refuses_options_that_would_be_ignored(tmp_path, capsys, argv, words):
    from shinysim.cli import main

    assert main(["deflect", *argv, "--out", str(tmp_path / "out")]) == 1
    assert words in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
