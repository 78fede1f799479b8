"""The simulated twin of display deflectometry against exact answers.

The facet's heights, slopes and ray hits against finite differences and the
ray's own equation; every dot's reflection against the reflection law it
must obey; the twin's reflected lattice against the real SOFAST frame's; and
one small render whose dark dots must lie where the exact reflections say.
The rig is SOFAST's fixed-pattern measurement: its camera, its camera-screen
pose and its measured dot grid (a planar 85 x 85 grid at 40 mm pitch when
the data are absent).
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import replace

import numpy as np
import pytest
from conftest import SHARED_DATA, requires_jit

from shinysim.errors import OptionError
from shinysim.objects.mirror import MirrorFacet
from shinysim.recon.dots import detect_dots, index_dots
from shinysim.rig.display import SOFAST_FACET_CENTRE_MM, Display, crop_camera, facet_pose
from shinysim.rig.opencv import camera_from_opencv, rvec_to_matrix
from shinysim.sim.display import pattern_texture, render_display_frame, sofast_facet, sofast_like_setup

SOFAST = SHARED_DATA / "sofast"
K = [[5492.06, 0.0, 812.5], [0.0, 5486.27, 617.5], [0.0, 0.0, 1.0]]
DIST = [-0.14416, 1.60974, 2.5035e-5, -1.8990e-3, 0.0]
R_CAM_SCREEN = [-0.03629624, 0.35523602, -0.01208407]
V_CAM_SCREEN_MM = [4451.838, 57.105, 368.329]


def sofast_camera():
    return camera_from_opencv(K, DIST, (1626, 1236))


def sofast_dots():
    """SOFAST's measured dot grid (mm), or a planar 85 x 85 grid at 40 mm pitch without the data."""
    path = SOFAST / "fixed" / "fixed_pattern_dot_locations.h5"
    if path.is_file():
        import h5py

        with h5py.File(path, "r") as h:
            g = h["DotLocationsFixedPattern"]
            return g["xyz_dot_loc"][()] * 1000.0, g["x_dot_index"][()], g["y_dot_index"][()]
    d = Display.planar_grid(85, 85, 40.0)
    return d.dots_mm, d.x_index, d.y_index


def setup_with(facet=None):
    # SOFAST's r_cam_screen takes camera vectors into the screen frame: the screen-to-camera rotation is its inverse
    return sofast_like_setup(sofast_camera(), rvec_to_matrix(R_CAM_SCREEN).T, V_CAM_SCREEN_MM, *sofast_dots(),
                             facet=facet)


@pytest.fixture(scope="module")
def setup():
    return setup_with()


@pytest.fixture(scope="module")
def reflected(setup):
    return setup.reflected_dots()


# -- the facet -------------------------------------------------------------------

def test_slopes_and_curvatures_are_the_heights_derivatives(np_rng):
    f = sofast_facet()
    x, y = np_rng.uniform(-606, 606, (2, 500))
    h = 1e-3  # central differences: truncation h^2 z''' / 6 < 1e-14, rounding eps |z| / h ~ 3e-13
    fd = np.stack([(f.height(x + h, y) - f.height(x - h, y)) / (2 * h),
                   (f.height(x, y + h) - f.height(x, y - h)) / (2 * h)], -1)
    np.testing.assert_allclose(f.slopes(x, y), fd, rtol=0, atol=1e-9)
    s = f.slopes
    fd2 = np.stack([(s(x + h, y)[:, 0] - s(x - h, y)[:, 0]) / (2 * h),
                    (s(x, y + h)[:, 0] - s(x, y - h)[:, 0]) / (2 * h),
                    (s(x, y + h)[:, 1] - s(x, y - h)[:, 1]) / (2 * h)], -1)
    np.testing.assert_allclose(f.curvatures(x, y), fd2, rtol=0, atol=1e-11)
    # the ripple is there: 0.02 mm at period 400 mm is 3.1e-4 of slope beyond the paraboloid
    bare = replace(f, ripple_mm=0.0)
    assert np.max(np.linalg.norm(f.slopes(x, y) - bare.slopes(x, y), axis=-1)) == pytest.approx(0.02 * 2 * np.pi / 400,
                                                                                   rel=0.01)
    n = f.normal(x, y)
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-15)
    np.testing.assert_allclose(-n[:, :2] / n[:, 2:], f.slopes(x, y), atol=1e-15)


def test_facet_takes_any_shape_and_nan_quietly():
    f = sofast_facet()
    x = np.linspace(-500, 500, 24).reshape(2, 3, 4)
    assert f.height(x, 0.5 * x).shape == (2, 3, 4)
    assert f.slopes(x, 0.5 * x).shape == (2, 3, 4, 2)
    assert f.normal(x, 3.0).shape == (2, 3, 4, 3)
    assert np.isnan(f.height(np.nan, 0.0)) and np.all(np.isnan(f.slopes(0.0, np.nan)))
    assert not f.contains(np.nan, 0.0) and f.contains(606.0, -606.0) and not f.contains(606.001, 0.0)
    flat = MirrorFacet(10.0, 20.0)
    assert flat.height(3.0, 4.0) == 0.0 and flat.slopes(3.0, 4.0).tolist() == [0.0, 0.0]


def test_intersect_is_exact(np_rng):
    f = sofast_facet()
    camera = setup_with().camera_centre_facet_mm
    target = np_rng.uniform(-600, 600, (1000, 2))
    on_surface = np.column_stack([target, f.height(target[:, 0], target[:, 1])])
    d = on_surface - camera
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    points, hit = f.intersect(np.broadcast_to(camera, d.shape), d)
    assert hit.all()
    # on the surface and on the ray, to 1e-9 mm (the Newton steps stop at 1e-11 mm)
    assert np.max(np.abs(points[:, 2] - f.height(points[:, 0], points[:, 1]))) < 1e-9
    rel = points - camera
    assert np.max(np.linalg.norm(rel - np.sum(rel * d, 1, keepdims=True) * d, axis=1)) < 1e-9
    np.testing.assert_allclose(points, on_surface, rtol=0, atol=1e-9)
    # misses: off the rectangle, behind the origin, parallel to the plane
    o = np.array([[0.0, 0.0, 1000.0], [0.0, 0.0, 1000.0], [0.0, 0.0, 1000.0]])
    dirs = np.array([[0.7, 0.0, -0.7], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    points, hit = f.intersect(o, dirs)
    assert not hit.any() and np.isnan(points).all()


def test_corners_come_in_sofast_order_on_the_surface():
    f = sofast_facet()
    path = SOFAST / "common" / "Facet_NSTTF.json"
    if path.is_file():
        c = json.loads(path.read_text())["v_facet_corners"]
        design = np.column_stack([c["x"], c["y"]]) * 1000.0
    else:
        design = np.array([[606, -606], [-606, -606], [-606, 606], [606, 606]], float)
    corners = f.corners_mm()
    np.testing.assert_allclose(corners[:, :2], design, atol=1e-9)
    np.testing.assert_array_equal(corners[:, 2], f.height(design[:, 0], design[:, 1]))
    # the sag at a corner of a (-136 m, -146 m) facet: 606^2 / 4 (1/136e3 + 1/146e3) below the centre's plane
    assert corners[2, 2] == pytest.approx(-606**2 / 4 * (1 / 136e3 + 1 / 146e3), abs=0.021)


@pytest.mark.parametrize("kwargs, field", [
    ({"half_width_mm": 0.0}, "half_width_mm"), ({"half_height_mm": np.nan}, "half_height_mm"),
    ({"focal_mm": (0.0, 1e5)}, "focal_mm"), ({"focal_mm": (np.nan, 1e5)}, "focal_mm"), ({"focal_mm": 3.0}, "focal_mm"),
    ({"ripple_mm": np.inf}, "ripple_mm"), ({"ripple_period_mm": 0.0}, "ripple_period_mm"),
    ({"ripple_angle_rad": "0.5"}, "ripple_angle_rad")])
def test_bad_facets_are_refused(kwargs, field):
    args = {"half_width_mm": 606.0, "half_height_mm": 606.0, **kwargs}
    with pytest.raises(OptionError) as e:
        MirrorFacet(**args)
    assert e.value.field == field


def test_mesh_stays_within_its_bound(np_rng):
    f = sofast_facet()
    mesh = f.triangle_mesh()
    bound = mesh.params["error_bound_mm"]
    assert bound < 1e-4
    faces = mesh.faces[np_rng.integers(0, mesh.n_faces, 100_000)]
    w = np_rng.dirichlet([1, 1, 1], len(faces))
    p = np.einsum("nk,nkd->nd", w, mesh.vertices[faces])
    err = np.abs(p[:, 2] - f.height(p[:, 0], p[:, 1]))
    # within the bound, and the bound is a tight one (a paraboloid's interpolation error reaches most of it)
    assert err.max() <= bound and err.max() > 0.5 * bound
    e1 = mesh.vertices[mesh.faces[:, 1]] - mesh.vertices[mesh.faces[:, 0]]
    e2 = mesh.vertices[mesh.faces[:, 2]] - mesh.vertices[mesh.faces[:, 0]]
    assert np.all(np.cross(e1, e2)[:, 2] > 0)  # counter-clockwise seen from the mirror side
    np.testing.assert_allclose(mesh.normals, f.normal(mesh.vertices[:, 0], mesh.vertices[:, 1]), atol=1e-15)


# -- the display and the rig ------------------------------------------------------

def test_display_grid_levels_and_refusals():
    d = Display.planar_grid(5, 3, 40.0, dot_radius_mm=6.0)
    assert d.dots_mm[1, 2].tolist() == [0.0, 0.0, 0.0] and d.pitch_mm == 40.0 and d.is_planar
    assert d.radiance([0.0, 5.9, 6.1, 20.0, 500.0], 0.0).tolist() == [0.0, 0.0, 1.0, 1.0, 0.0]
    bright = replace(d, polarity="bright", on_radiance=2.0, off_radiance=0.5)
    assert bright.radiance([0.0, 20.0], 0.0).tolist() == [2.0, 0.5]
    with pytest.raises(OptionError, match="overlap") as e:
        Display.planar_grid(5, 3, 40.0, dot_radius_mm=20.0)
    assert e.value.field == "dot_radius_mm"
    dots = d.dots_mm.copy()
    dots[0, 0, 1] = np.nan
    with pytest.raises(OptionError) as e:
        Display(dots, d.x_index, d.y_index)
    assert e.value.field == "dots_mm"
    for kwargs, field in (({"polarity": "grey"}, "polarity"), ({"on_radiance": 0.0}, "on_radiance"),
                          ({"x_index": [0, 0, 1, 2, 3]}, "x_index"), ({"size_mm": (0.0, 1.0)}, "size_mm")):
        with pytest.raises(OptionError) as e:
            replace(d, **kwargs)
        assert e.value.field == field
    dots[0, 0] = np.nan  # a dot not shown
    assert Display(dots, d.x_index, d.y_index).shown.sum() == 14


def test_texture_keeps_every_dot_centred():
    d = Display.planar_grid(3, 3, 40.0, dot_radius_mm=6.0, centre_mm=(0.3, -0.2))
    texel = 1.2
    tex = pattern_texture(d, texel)
    H, W = tex.shape
    w, h = d.size_mm
    x = d.centre_mm[0] - w / 2 + (np.arange(W) + 0.5) * w / W
    y = d.centre_mm[1] - h / 2 + (np.arange(H) + 0.5) * h / H
    dark = 1.0 - tex
    for centre in d.dots_mm.reshape(-1, 3):
        near = (np.abs(x - centre[0]) < 20)[None, :] & (np.abs(y - centre[1]) < 20)[:, None]
        m = dark * near
        # the disc's area and centre, to a small fraction of a texel (the edge ramp is symmetric)
        assert m.sum() * (w / W) * (h / H) == pytest.approx(np.pi * 36.0, rel=0.01)
        assert abs((m.sum(0) @ x) / m.sum() - centre[0]) < 0.02 * texel
        assert abs((m.sum(1) @ y) / m.sum() - centre[1]) < 0.02 * texel


def test_crop_camera_sees_the_whole_cameras_rays(np_rng):
    cam = sofast_camera()
    win = crop_camera(cam, 690, 845, 200, 210)
    assert win.shape == (200, 210)
    r, c = np_rng.uniform(-0.5, 199.5, 300), np_rng.uniform(-0.5, 209.5, 300)
    o1, d1 = win.pixel_rays(r, c)
    o2, d2 = cam.pixel_rays(r + 690, c + 845)
    np.testing.assert_allclose(d1, d2, rtol=0, atol=1e-13)
    np.testing.assert_array_equal(o1, o2)
    row, col = win.project(1e4 * d2)
    np.testing.assert_allclose(np.column_stack([row, col]), np.column_stack([r, c]), rtol=0, atol=1e-8)
    with pytest.raises(OptionError) as e:
        crop_camera(cam, 0, 0, 0, 10)
    assert e.value.field == "height"


def test_facet_faces_the_bisector(setup):
    R, t = setup.facet_rotation, setup.facet_origin_mm
    np.testing.assert_array_equal(t, SOFAST_FACET_CENTRE_MM)
    to_cam = -t / np.linalg.norm(t)
    to_screen = (setup.screen_origin_mm - t) / np.linalg.norm(setup.screen_origin_mm - t)
    np.testing.assert_allclose(R[:, 2], (to_cam + to_screen) / np.linalg.norm(to_cam + to_screen), atol=1e-15)
    # +x as near the camera's +x as can be: in the plane of the normal and the camera's +x
    assert abs(R[:, 0] @ np.cross(R[:, 2], [1.0, 0.0, 0.0])) < 1e-15 and R[0, 0] > 0.97
    # the real measurement's distance from the facet's centre to the screen's origin: 10.008 m
    assert np.linalg.norm(setup.screen_origin_mm - t) == pytest.approx(10008.0, abs=1.0)
    with pytest.raises(OptionError):
        facet_pose((0, 0, 0), (0, 0, 2000.0), (0, 0, 1000.0))  # camera and screen on opposite sides


def test_reflected_dots_obey_the_reflection_law(setup, reflected):
    ok = reflected.visible
    # about 3800 of SOFAST's 85 x 85 dots reflect in the 1.212 m facet (its own result holds 3782)
    assert 3000 < ok.sum() < 4500
    assert np.array_equal(ok, reflected.on_facet)  # the whole facet is in the frame
    row, col, P = reflected.row[ok], reflected.col[ok], reflected.points_mm[ok]
    dots = setup.camera_to_facet(setup.dots_camera_mm())[ok]
    # the camera ray through the pixel meets the facet at the mirror point ...
    hit_points, hit = setup.trace_pixels(row, col)
    assert hit.all() and np.max(np.linalg.norm(hit_points - P, axis=1)) < 1e-6
    # ... and, reflected about the exact normal there, passes through the dot's centre
    _, d = setup.camera.pixel_rays(row, col)
    d = d @ setup.facet_rotation
    n = setup.facet.normal(P[:, 0], P[:, 1])
    r = d - 2 * np.sum(d * n, 1, keepdims=True) * n
    v = dots - P
    assert np.max(np.linalg.norm(v - np.sum(v * r, 1, keepdims=True) * r, axis=1)) < 1e-6
    np.testing.assert_array_equal(reflected.slopes[ok], setup.facet.slopes(P[:, 0], P[:, 1]))
    assert np.isnan(reflected.row[~ok]).all() and np.isnan(reflected.points_mm[~ok]).all()
    # dot index +x runs with image columns, +y with image rows (SOFAST's frame seen in the facet)
    j, i = setup.display.index_of(0, 0)
    assert reflected.col[j, i + 1] - reflected.col[j, i] > 10 and reflected.row[j + 1, i] - reflected.row[j, i] > 10


def test_flat_mirror_images_the_mirror_image(setup):
    """A flat facet: each dot images where its mirror image across the plane does (a closed form)."""
    flat = replace(setup, facet=MirrorFacet(606.0, 606.0))
    got = flat.reflected_dots()
    dots = flat.camera_to_facet(flat.dots_camera_mm())
    image = flat.facet_to_camera(dots * [1.0, 1.0, -1.0])
    row, col = flat.camera.project(image)
    ok = got.visible
    assert ok.sum() > 3000
    np.testing.assert_allclose(got.row[ok], row[ok], rtol=0, atol=1e-7)
    np.testing.assert_allclose(got.col[ok], col[ok], rtol=0, atol=1e-7)


def test_dots_off_a_small_facet_are_not_reflected(setup, reflected):
    small = replace(setup, facet=MirrorFacet(100.0, 60.0, focal_mm=(-136e3, -146e3)))
    got = small.reflected_dots()
    assert 20 < got.on_facet.sum() < 100
    pts = reflected.points_mm  # the big facet's mirror points differ little from the small one's
    inside = (np.abs(pts[..., 0]) < 100 - 10) & (np.abs(pts[..., 1]) < 60 - 10)
    outside = (np.abs(pts[..., 0]) > 100 + 10) | (np.abs(pts[..., 1]) > 60 + 10)
    assert got.on_facet[inside].all() and not got.on_facet[outside].any()
    assert np.all(np.abs(got.points_mm[got.on_facet][:, :2]) <= [100.0, 60.0])


def test_twin_lattice_is_the_real_frames():
    """The twin's reflected lattice has the real frame's pitch along both index directions, to 0.5 %.

    A flat facet would give 3.7 % more, a concave one of the same focal lengths 7.7 % more: this holds the
    camera, the camera-screen pose, the dot grid and the curvature's sign together. The real lattice is turned
    by 0.013 rad from the twin's; no facet tilt turns it by more than ~0.001 rad for the 3 mrad that moves
    dot (0, 0) by the 16 px it is off the twin's (the bisector pose). The turn is what the antisymmetric part of
    SOFAST's own fitted slope gradients gives (d(dz/dx)/dy = 1.55e-3 /m, d(dz/dy)/dx = -1.42e-3 /m: 0.014 rad
    at 10 m from the screen), a part no surface has."""
    path = SOFAST / "fixed" / "measurement_facet.h5"
    if not path.is_file():
        pytest.skip(f"the real SOFAST frame is not available ({path} absent)")
    import h5py

    with h5py.File(path, "r") as h:
        frame = h["MeasurementSofastFixed/image"][()]
        origin_xy = h["MeasurementSofastFixed/origin"][()]
    table = detect_dots(frame)
    found = index_dots(table["row"], table["col"], (origin_xy[1], origin_xy[0]))
    ok = found.identified
    design = np.column_stack([np.ones(ok.sum()), found.index[ok]])
    real = np.linalg.lstsq(design, np.column_stack([table["row"][ok], table["col"][ok]]), rcond=None)[0]
    setup = setup_with()
    ref = setup.reflected_dots()
    vis = ref.visible
    ix, iy = np.meshgrid(setup.display.x_index, setup.display.y_index)
    design = np.column_stack([np.ones(vis.sum()), ix[vis], iy[vis]])
    twin = np.linalg.lstsq(design, np.column_stack([ref.row[vis], ref.col[vis]]), rcond=None)[0]
    for k in (1, 2):  # the x- and the y-index step, (drow, dcol) pixels
        assert np.linalg.norm(twin[k]) == pytest.approx(np.linalg.norm(real[k]), rel=0.005), (twin[k], real[k])
        a, b = twin[k], real[k]
        turn = math.asin((a[0] * b[1] - a[1] * b[0]) / np.linalg.norm(a) / np.linalg.norm(b))
        assert abs(turn) < 0.02
    assert np.linalg.norm(twin[0] - real[0]) < 30  # dot (0, 0): the real facet is a few mrad off the bisector


def test_setup_refuses_what_is_not_a_rig(setup):
    with pytest.raises(OptionError) as e:
        replace(setup, screen_rotation=2 * np.eye(3))
    assert e.value.field == "screen_rotation"
    with pytest.raises(OptionError) as e:
        replace(setup, facet="mirror")
    assert e.value.field == "facet"
    with pytest.raises(OptionError) as e:
        setup.display.index_of(99, 0)
    assert e.value.field == "index"


# -- the render ---------------------------------------------------------------------

def test_render_refuses_bad_options(setup):
    for kwargs, field in (({"spp": 0}, "spp"), ({"alpha": -1.0}, "alpha"), ({"rows": slice(0, 10, 2)}, "rows"),
                          ({"cols": slice(20, 10)}, "cols"), ({"distribution": "phong"}, "distribution"),
                          ({"texels_per_dot": 4}, "texels_per_dot")):
        with pytest.raises(OptionError) as e:
            render_display_frame(setup, **kwargs)
        assert e.value.field == field
    bumpy = setup.display.dots_mm.copy()
    bumpy[..., 2] += 1.0
    with pytest.raises(OptionError, match="flat") as e:
        render_display_frame(replace(setup, display=replace(setup.display, dots_mm=bumpy)))
    assert e.value.field == "setup.display"


@requires_jit
def test_rendered_dots_lie_where_their_reflections_are():
    """A 200 x 200 window around dot (0, 0) in a 240 mm facet: each dark dot's centroid is the exact image of
    its centre.

    The tolerance, 0.3 px: a dot's image is the reflection of a 13.5 mm disc through a mirror whose
    magnification changes by ~1e-3 across it, so its centroid is its centre's image to ~1e-3 px (measured
    with a fixed 5 px window at 1024 spp: 0.01 px rms); the detector's background (a 9 px closing, narrower
    than a blurred dot) and its cut at 10 % of the peak move centroids by ~0.04 px rms per axis; at 256
    samples per pixel the noise adds ~0.03 px per axis. The largest of 132 dots is 0.13 px (seeds 0 and 3).
    """
    facet = MirrorFacet(120.0, 120.0, focal_mm=(-136e3, -146e3), ripple_mm=0.02, ripple_period_mm=400.0,
                        ripple_angle_rad=0.5)
    setup = setup_with(facet)
    r0, c0 = (int(round(v)) - 100 for v in setup.reflected_dots().at(0, 0))
    start = time.perf_counter()
    frame = render_display_frame(setup, spp=256, seed=3, rows=slice(r0, r0 + 200), cols=slice(c0, c0 + 200))
    seconds = time.perf_counter() - start
    assert frame.image.shape == (200, 200) and frame.offset_rc == (r0, c0)
    assert frame.origin_rc == frame.reflected.at(0, 0)
    assert abs(frame.origin_rc[0] - 100) < 1 and abs(frame.origin_rc[1] - 100) < 1
    ref = frame.reflected
    truth = np.column_stack([ref.row[ref.visible], ref.col[ref.visible]])
    assert len(truth) > 120  # the facet spans ~140 px: ~12 x 12 dots

    table = detect_dots(frame.image)
    keep = ~np.asarray(table["cut"])
    found = np.column_stack([table["row"], table["col"]])[keep]
    dist = np.linalg.norm(found[:, None] - truth[None], axis=-1)
    nearest = dist.min(1)
    assert np.all(nearest < 0.3), np.sort(nearest)[-5:]
    assert len(set(dist.argmin(1))) == len(found)  # one detection per dot
    # every dot whose image is clear of the facet's edge (by more than a dot's blurred radius) is found
    hit = ~np.isnan(frame.truth_points_mm[..., 0])
    from scipy import ndimage

    depth = ndimage.distance_transform_edt(hit)
    clear = depth[np.round(truth[:, 0]).astype(int).clip(0, 199), np.round(truth[:, 1]).astype(int).clip(0, 199)] > 8
    assert np.all(np.linalg.norm(truth[clear][:, None] - found[None], axis=-1).min(1) < 0.3)

    # the render itself, measured without the detector: a fixed 5 px window of darkness around each exact
    # position (it holds the blurred dot; its centroid moves by the noise alone, ~0.025 px rms per axis at
    # 256 spp, so 0.15 px is 6 sigma of the radial error)
    rows, cols = np.indices(frame.image.shape)
    dark = 1.0 - frame.image
    for r, c in truth[clear]:
        w = dark * ((rows - r) ** 2 + (cols - c) ** 2 <= 25.0)
        assert math.hypot((w * rows).sum() / w.sum() - r, (w * cols).sum() / w.sum() - c) < 0.15
    # the bright screen, seen in a mirror of reflectance 1, away from every dot
    far = hit & (depth > 3)
    for r, c in truth:
        far &= (rows - r) ** 2 + (cols - c) ** 2 > 49.0
    assert np.median(frame.image[far]) == pytest.approx(1.0, abs=0.01)
    # pixels whose whole neighbourhood misses the facet see nothing
    assert np.all(frame.image[ndimage.binary_dilation(hit, iterations=2) == 0] == 0.0)
    assert np.all(np.isnan(frame.truth_slopes[~hit])) and not np.isnan(frame.truth_slopes[hit]).any()
    assert seconds < 60, f"the 200 x 200, 256 spp window took {seconds:.1f} s"
