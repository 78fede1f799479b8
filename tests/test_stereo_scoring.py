"""Stereo rigs and the scoring of 3-D points against truth (no renderer)."""

from __future__ import annotations

import numpy as np
import pytest

from shinysim.evaluate import TruthSurface, distance_stats, matchable_highlights
from shinysim.io import Truth
from shinysim.rig import Camera, sources_in_view, stereo_dome, stereo_semicircle


def _sphere_truth(camera: Camera, centre, radius):
    """Pixel-centre truth of a sphere seen by ``camera``, by exact ray-sphere intersection."""
    h, w = camera.shape
    rows, cols = np.meshgrid(np.arange(h, dtype=float), np.arange(w, dtype=float), indexing="ij")
    o, d = camera.pixel_rays(rows, cols)
    oc = o - np.asarray(centre, float)
    b = np.einsum("...i,...i->...", oc, d)
    c = np.einsum("...i,...i->...", oc, oc) - radius**2
    disc = b * b - c
    hit = disc > 0
    t = np.where(hit, -b - np.sqrt(np.where(hit, disc, 0.0)), np.nan)
    p = o + t[..., None] * d
    n = (p - np.asarray(centre, float)) / radius
    p[~hit] = np.nan
    n[~hit] = np.nan
    return Truth(normals=n, positions=p, mask=hit, part=hit.astype(np.int32), part_names=["background", "ball"])


def test_stereo_dome_leaves_the_cameras_views_free():
    rig = stereo_dome(n_sources=1000, resolution=64)
    assert len(rig.cameras) == 2
    removed = rig.metadata["sources_removed_for_cameras"]
    assert removed > 0 and rig.n_sources == 1000 - removed
    for cam in rig.cameras:
        assert not sources_in_view(rig.source_positions, rig.source_radii, cam).any()
    # cameras at +-beta about y, at the SHINY camera's distance
    for cam, sign in zip(rig.cameras, (1, -1)):
        d = np.asarray(cam.position) / np.linalg.norm(cam.position)
        assert np.degrees(np.arctan2(d[0], d[2])) == pytest.approx(sign * 15.0, abs=1e-9)


def test_sources_in_view_flags_a_fiber_on_the_camera_axis():
    rig = stereo_dome(n_sources=50, resolution=64)
    cam = rig.cameras[0]
    axis = np.asarray(cam.position) / np.linalg.norm(cam.position)
    on_axis = 43.18 * axis
    # the view pyramid's half-diagonal shrinks from 4.24 mm at the field to
    # 4.24 * 84 / 127 = 2.8 mm at the fibers, 84 mm from the camera: a fiber of
    # radius 0.5 mm 3 mm off the axis reaches into it, one 4 mm off does not
    beside = [on_axis + np.array([0.0, 3.0, 0.0]), on_axis + np.array([0.0, 4.0, 0.0])]
    flags = sources_in_view(np.stack([on_axis, *beside]), [0.508] * 3, cam)
    assert flags.tolist() == [True, True, False]


def test_stereo_semicircle_spacing_divides_twice_beta():
    rig = stereo_semicircle(spacing_deg=2.5, beta_deg=15.0, resolution=64)
    ang = np.degrees(np.arctan2(rig.source_positions[:, 0], rig.source_positions[:, 2]))
    assert np.allclose(rig.source_positions[:, 1], 0.0)
    # whole spacings between any two fibers, and 2 beta = 12 of them: a fiber at a
    # and one at a + 2 beta reflect into the two cameras from one element
    steps = (ang - ang[0]) / 2.5
    assert np.allclose(steps, np.round(steps), atol=1e-9)
    present = set(np.round(ang, 6).tolist())
    assert sum((round(a + 30.0, 6) in present) for a in ang) > 0.6 * len(ang)


def test_truth_surface_distance_is_second_order_exact_on_a_sphere():
    cam = stereo_dome(n_sources=50, resolution=128).cameras[0]
    centre, r = np.array([0.4, -0.2, 0.6]), 0.8
    truth = _sphere_truth(cam, centre, r)
    pitch = cam.pixel_pitch
    surface = TruthSurface([truth], spacing_mm=pitch)
    rng = np.random.default_rng(3)
    # points at known radial offsets above visible parts of the sphere (normals towards the camera)
    view = np.asarray(cam.position) - centre
    view /= np.linalg.norm(view)
    dirs = rng.normal(size=(200, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    dirs = dirs[dirs @ view > 0.5]
    offsets = rng.uniform(-0.05, 0.05, len(dirs))
    pts = centre + (r + offsets)[:, None] * dirs
    dist, normal, part = surface.nearest(pts)
    # the tangent plane of the nearest sample: exact to (spacing / 2)^2 / (2 r) on a
    # sphere; samples are 47 um apart on the 6 mm field at 128 px, up to twice that
    # at the sphere's slopes, so the bound is (pitch)^2 / (2 r) plus float32 storage
    bound = pitch**2 / (2 * r) + 1e-6
    assert np.max(np.abs(dist - np.abs(offsets))) < bound
    assert np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", normal, dirs), -1, 1))).max() < np.degrees(2 * pitch / r)
    assert set(part.tolist()) == {"ball"}
    # far from the surface: the distance to the sample, not to its tangent plane
    far = surface.nearest([centre + np.array([5.0, 0.0, 0.0])])[0][0]
    assert far > 4.0


def test_distance_stats_in_micrometres_and_pixels():
    s = distance_stats([0.001, 0.002, 0.003, np.nan], pixel_mm=0.002)
    assert s["n"] == 3
    assert s["median"] == pytest.approx(2.0) and s["median_px"] == pytest.approx(1.0)
    assert s["max"] == pytest.approx(3.0) and s["max_px"] == pytest.approx(1.5)


def test_matchable_needs_a_partner_on_the_same_part_within_eps():
    p1 = np.array([[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0], [np.nan, 0, 0]])
    p2 = np.array([[0.005, 0, 0], [1.02, 0, 0], [2.001, 0, 0]])
    ok, partner, gap = matchable_highlights(p1, ["a", "a", "a", None], p2, ["a", "a", "b"], eps_mm=0.01)
    assert ok.tolist() == [True, False, False, False]
    assert partner[0] == 0 and gap[0] == pytest.approx(0.005)
    assert partner[2] == 1  # the nearer element of another part does not count
