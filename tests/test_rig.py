import json

import numpy as np
import pytest

from shinysim.io import load_rig
from shinysim.rig import (
    Camera,
    Rig,
    RigError,
    distant_rig,
    shiny_1988,
    shiny_1988_source_angles_deg,
)


def test_shiny_preset_geometry():
    rig = shiny_1988()
    assert rig.n_sources == 21
    np.testing.assert_allclose(np.linalg.norm(rig.source_positions, axis=1), 43.18, atol=1e-12)
    np.testing.assert_allclose(rig.source_radii, 0.508, atol=1e-12)
    np.testing.assert_allclose(rig.source_positions[:, 1], 0.0)
    angles = shiny_1988_source_angles_deg()
    np.testing.assert_allclose(np.diff(angles), 8.0)
    assert angles[0] == -84 and angles[-1] == 76
    assert rig.camera.shape == (512, 512)


@pytest.mark.parametrize("projection", ["orthographic", "perspective"])
def test_no_fiber_blocks_the_view(projection):
    """Every ray from the camera to the sphere passes clear of every fiber."""
    rig = shiny_1988(projection=projection)
    cam = rig.camera
    r_sphere = 0.79375
    # rays through a dense grid of image points covering the sphere
    rows, cols = np.meshgrid(np.linspace(0, 511, 64), np.linspace(0, 511, 64), indexing="ij")
    o, d = cam.pixel_rays(rows, cols)
    hits = cam.backproject_to_plane(rows, cols)
    on_sphere = np.linalg.norm(hits, axis=-1) <= r_sphere
    o, d = o[on_sphere], d[on_sphere]
    for c, r in zip(rig.source_positions, rig.source_radii):
        t = np.sum((c - o) * d, axis=-1)
        closest = np.linalg.norm(o + t[:, None] * d - c, axis=-1)
        assert np.all(closest > r), "a fiber blocks the camera's view of the sphere"


@pytest.mark.parametrize("projection", ["orthographic", "perspective"])
def test_project_backproject_roundtrip(projection, np_rng):
    cam = shiny_1988(projection=projection).camera
    rows = np_rng.uniform(0, 511, 50)
    cols = np_rng.uniform(0, 511, 50)
    pts = cam.backproject_to_plane(rows, cols, plane_z=0.3)
    np.testing.assert_allclose(pts[:, 2], 0.3, atol=1e-12)
    r2, c2 = cam.project(pts)
    np.testing.assert_allclose(r2, rows, atol=1e-9)
    np.testing.assert_allclose(c2, cols, atol=1e-9)


def test_image_axes_follow_conventions():
    cam = shiny_1988(projection="orthographic").camera
    r0, c0 = cam.project([0.0, 0.0, 0.0])
    assert (r0, c0) == pytest.approx((255.5, 255.5))
    r, c = cam.project([0.5, 0.0, 0.0])  # +x is image right
    assert c > c0 and r == pytest.approx(r0)
    r, c = cam.project([0.0, 0.5, 0.0])  # +y is image up
    assert r < r0 and c == pytest.approx(c0)
    assert cam.pixel_pitch == pytest.approx(2.0 / 512)


def test_json_roundtrip(tmp_path):
    rig = shiny_1988()
    path = tmp_path / "rig.json"
    rig.save(path)
    assert load_rig(path) == rig
    with pytest.raises(FileExistsError, match="not overwriting"):
        rig.save(path)
    # any layout works, including distant sources
    cam = Camera("orthographic", 40, 30, [0, 0, 10], [0, 0, 0], [0, 1, 0], 4.0)
    d = distant_rig([[0, 0, 1], [0.3, 0, 1]], cam)
    assert Rig.from_json(d.to_json()) == d
    np.testing.assert_allclose(np.linalg.norm(d.source_positions, axis=1), 1.0)


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda d: d.pop("sources"), "missing required field"),
        (lambda d: d["cameras"][0].pop("width"), "missing required field"),
        (lambda d: d["sources"][0].update(position_mm=[1, 2]), "must be 3 finite numbers"),
        (lambda d: d["sources"][0].update(position_mm=[1, "x", 2]), "must be 3 finite numbers"),
        (lambda d: d["cameras"][0].update(projection="fisheye"), "is not one of"),
        (lambda d: d["cameras"][0].update(width=0), "integer from 1 to 65536"),
        (lambda d: d["cameras"][0].update(field_width_mm=-1), "field_width"),
        (lambda d: d.update(units="inch"), "units: must be 'mm'"),
        (lambda d: d.update(sources=[]), "sources: must list 1 to 10000"),
        (lambda d: d["sources"].__setitem__(0, {"radius_mm": 1}), "needs 'position_mm'"),
        (lambda d: d.update(format="other/9"), "not supported"),
    ],
)
def test_invalid_rig_json(tmp_path, mutate, message):
    d = json.loads(shiny_1988().to_json())
    mutate(d)
    path = tmp_path / "rig.json"
    path.write_text(json.dumps(d))
    with pytest.raises(RigError, match=message):
        load_rig(path)


def test_unreadable_rig_files(tmp_path):
    with pytest.raises(RigError, match="no such file"):
        load_rig(tmp_path / "nope.json")
    bad = tmp_path / "bad.json"
    bad.write_text('{"sources": [')
    with pytest.raises(RigError, match="not valid JSON"):
        load_rig(bad)


def test_source_directions():
    rig = shiny_1988()
    p = np.array([[0.1, 0.0, 0.2]])
    d_all = rig.source_directions(p)
    assert d_all.shape == (1, 21, 3)
    d5 = rig.source_directions(p, [5])
    np.testing.assert_allclose(d5[0], d_all[0, 5])
    expect = rig.source_positions[5] - p[0]
    np.testing.assert_allclose(d5[0], expect / np.linalg.norm(expect), atol=1e-15)
    with pytest.raises(IndexError):
        rig.source_directions(p, [21])


def _lens_camera(projection="perspective", k=(2e-3, -5e-4), pp=(250.25, 262.75)):
    cam = shiny_1988(projection=projection).camera
    d = cam.to_dict()
    d.update(principal_point_px=list(pp), distortion=list(k))
    return Camera.from_dict(d)


@pytest.mark.parametrize("projection", ["perspective", "orthographic"])
def test_lens_model_roundtrip_and_definition(projection, np_rng):
    """Principal point and radial distortion: pixel -> ray -> pixel is exact, and the map is the documented one."""
    cam = _lens_camera(projection)
    rows, cols = np_rng.uniform(0, 511, (2, 200))
    for z in (-1.0, 0.0, 1.0):
        r2, c2 = cam.project(cam.backproject_to_plane(rows, cols, plane_z=z))
        np.testing.assert_allclose(r2, rows, atol=1e-9)  # Newton undistortion to rounding
        np.testing.assert_allclose(c2, cols, atol=1e-9)
    # the optical axis images at the principal point
    np.testing.assert_allclose(np.ravel(cam.project(cam.target)), [250.25, 262.75], atol=1e-9)
    # a point half the field width off the axis (r = 1) moves by k1 + k2 of its offset, outwards
    ideal = shiny_1988(projection=projection).camera
    x = cam.target + 0.5 * cam.field_width * cam.right
    _, c_ideal = ideal.project(x)
    _, c = cam.project(x)
    assert c - 262.75 == pytest.approx((c_ideal - 255.5) * (1 + 2e-3 - 5e-4), rel=1e-12)


def test_lens_model_json_versions(tmp_path):
    cam = _lens_camera()
    rig = shiny_1988().with_camera(cam)
    doc = json.loads(rig.to_json())
    assert doc["format"] == "shinysim-rig/2"
    assert doc["cameras"][0]["distortion"] == [2e-3, -5e-4]
    assert Rig.from_json(rig.to_json()) == rig
    # a version-1 file (no lens fields) still reads, as the ideal camera
    old = json.loads(shiny_1988().to_json())
    old["format"] = "shinysim-rig/1"
    v1 = Rig.from_dict(old)
    assert v1 == shiny_1988() and v1.camera.is_ideal
    # the image centre given explicitly is the default, not a different camera
    d = shiny_1988().camera.to_dict()
    d["principal_point_px"] = [255.5, 255.5]
    assert Camera.from_dict(d) == shiny_1988().camera


def test_perturbed_rig_applies_the_stated_errors():
    from shinysim.rig import RigTolerances, perturb_rig

    nominal = shiny_1988()
    tol = RigTolerances(fiber_position_mm=0.5, camera_rotation_deg=0.05, camera_translation_mm=0.05,
                        focal_fraction=0.005, principal_point_px=3.0, distortion=(1e-3, -2e-4))
    true = perturb_rig(nominal, tol, seed=7)
    a, b = nominal.camera, true.camera
    # exact magnitudes: rotation of the frame, translation, focal, principal point
    cos = np.clip(np.dot(a.forward, b.forward), -1, 1)
    assert np.degrees(np.arccos(cos)) <= 0.05 + 1e-9  # the axis tilt is at most the rotation angle
    R = np.stack([b.right, b.down, b.forward]).T @ np.stack([a.right, a.down, a.forward])
    assert np.degrees(np.arccos((np.trace(R) - 1) / 2)) == pytest.approx(0.05, rel=1e-6)
    assert np.linalg.norm(b.position - a.position) == pytest.approx(0.05, rel=1e-12)
    assert b.distance == pytest.approx(a.distance, rel=1e-12)
    assert a.field_width / b.field_width == pytest.approx(1.005, rel=1e-12)
    assert np.linalg.norm(b.principal_point_px - a.principal_point_px) == pytest.approx(3.0, rel=1e-12)
    assert b.distortion == (1e-3, -2e-4, 0.0, 0.0, 0.0)
    # fibers: sigma 0.5 mm per axis (63 draws: the sample sd within 30 % of it)
    d = true.source_positions - nominal.source_positions
    assert 0.35 < d.std() < 0.65
    # recorded, reproducible from the seed, different for another seed, and survives JSON
    meta = true.metadata["perturbation"]
    assert meta["seed"] == 7 and meta["tolerances"]["camera_rotation_deg"] == 0.05
    np.testing.assert_allclose(meta["source_offsets_mm"], d, atol=1e-12)
    assert perturb_rig(nominal, tol, seed=7) == true
    assert perturb_rig(nominal, tol, seed=8) != true
    assert Rig.from_json(true.to_json()) == true
    # zero tolerances: the nominal rig's geometry unchanged
    same = perturb_rig(nominal, RigTolerances(), seed=3)
    np.testing.assert_array_equal(same.source_positions, nominal.source_positions)
    assert same.camera == nominal.camera


def test_tolerances_refuse_bad_values():
    from shinysim.errors import OptionError
    from shinysim.rig import RigTolerances

    with pytest.raises(OptionError, match="fiber_position_mm"):
        RigTolerances(fiber_position_mm=-1)
    with pytest.raises(RigError, match="unknown field 'fiber_postion_mm'.*did you mean 'fiber_position_mm'"):
        RigTolerances.from_dict({"fiber_postion_mm": 0.5})


# -- dome and stereo presets -------------------------------------------------------

def test_fibonacci_hemisphere_is_even_and_inside_the_cap():
    from shinysim.rig import fibonacci_hemisphere

    d = fibonacci_hemisphere(400, max_polar_deg=80.0)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    polar = np.degrees(np.arccos(d[:, 2]))
    assert polar.min() > 0 and polar.max() < 80.0
    # equal solid angle per point: the count inside polar angle t grows as 1 - cos t
    for t in (30.0, 50.0, 70.0):
        expected = 400 * (1 - np.cos(np.radians(t))) / (1 - np.cos(np.radians(80.0)))
        assert abs(np.sum(polar < t) - expected) <= 1.0
    # evenly spread: every point's nearest neighbour lies within a factor 2 of the mean spacing
    cos = d @ d.T
    np.fill_diagonal(cos, -1)
    nearest = np.degrees(np.arccos(cos.max(axis=1)))
    assert nearest.max() < 2 * nearest.mean() and nearest.min() > 0.5 * nearest.mean()


def test_dome_preset_near_and_distant_and_rings():
    from shinysim.rig import Rig, dome

    near = dome(n_sources=200)
    assert near.n_sources == 200 and not near.source_distant.any()
    np.testing.assert_allclose(np.linalg.norm(near.source_positions, axis=1), 1.7 * 25.4)
    far = dome(n_sources=50, radius_mm=None)
    assert far.source_distant.all()
    rings = dome(layout="rings", rings=[(30, 8), (60, 12)])
    assert rings.n_sources == 20
    np.testing.assert_allclose(np.degrees(np.arccos(rings.source_positions[:8, 2] / (1.7 * 25.4))), 30.0)
    again = Rig.from_json(near.to_json())
    np.testing.assert_allclose(again.source_positions, near.source_positions)
    # so many sources that the first sits in the camera's view of the object: refused
    with pytest.raises(ValueError, match="view of the object"):
        dome(n_sources=5000)
    with pytest.raises(ValueError, match="rings"):
        dome(layout="rings")


def test_stereo_pair_turns_the_camera_about_y():
    from shinysim.rig import shiny_1988, stereo_pair

    base = shiny_1988()
    rig = stereo_pair(base, beta_deg=30.0)
    assert len(rig.cameras) == 2
    np.testing.assert_array_equal(rig.source_positions, base.source_positions)
    for cam, sign in zip(rig.cameras, (1, -1)):
        # the axis makes beta with the vertical, in the x-z plane, and the target is kept
        assert np.degrees(np.arccos(-cam.forward[2])) == pytest.approx(30.0)
        assert np.sign(cam.position[0]) == sign and cam.position[1] == 0
        assert cam.distance == pytest.approx(base.camera.distance)
        row, col = cam.project(np.zeros((1, 3)))
        assert row[0] == pytest.approx((cam.height - 1) / 2) and col[0] == pytest.approx((cam.width - 1) / 2)
