"""The full OpenCV pinhole model of Camera (tangential terms, k3, aspect) and the converters to and from
OpenCV's (K, dist, rvec, tvec), against an independent numpy writing of cv2.projectPoints."""

import json

import numpy as np
import pytest
from conftest import requires_jit
from scipy.spatial.transform import Rotation

from shinysim.errors import RigError
from shinysim.rig import (
    Camera,
    OpenCVCamera,
    Rig,
    camera_from_opencv,
    camera_to_opencv,
    matrix_to_rvec,
    rvec_to_matrix,
    shiny_1988,
)

#: The SOFAST camera (Sandia OpenCSP, ``sofast_common/camera_sofast.h5``): K, (k1, k2, p1, p2, k3), (W, H).
SOFAST_K = np.array([[5492.06, 0.0, 812.5], [0.0, 5486.27, 617.5], [0.0, 0.0, 1.0]])
SOFAST_DIST = np.array([-0.1442, 1.6097, 2.5e-5, -1.9e-3, 0.0])
SOFAST_SIZE = (1626, 1236)
#: A plausible SOFAST pose: the camera about 9.4 m from the facet, turned by a few degrees.
SOFAST_RVEC = np.array([0.02, -0.35, 0.01])
SOFAST_TVEC = np.array([150.0, -80.0, 9400.0])

#: Round trips of the converters: closed forms both ways, so only rounding (~1e-16 per operation) is left.
ROUND_TRIP = 1e-12
#: Pixel agreement in float64: coordinates of ~1e3 px carry ~1e-13 px of rounding; 1e-9 leaves room for the
#: conditioning of the pose (points metres away, a frame rebuilt from target - position).
PX = 1e-9


def random_opencv(rng):
    """An OpenCV calibration of a moderate lens (fx >= 3000 px on <= 2000 px: |r| <= 0.45 in OpenCV's
    normalisation over 1.5 times the image, where these terms cannot fold it), pose and distance."""
    w, h = int(rng.integers(300, 2000)), int(rng.integers(300, 2000))
    fx = rng.uniform(3000, 8000)
    fy = fx * rng.uniform(0.9, 1.1)
    cx, cy = (w - 1) / 2 + rng.normal(0, 20), (h - 1) / 2 + rng.normal(0, 20)
    dist = np.array([rng.uniform(-0.2, 0.2), rng.uniform(-0.3, 0.3), rng.uniform(-5e-3, 5e-3),
                     rng.uniform(-5e-3, 5e-3), rng.uniform(-0.3, 0.3)])
    axis = rng.normal(size=3)
    rvec = axis / np.linalg.norm(axis) * rng.uniform(0.05, 3.0)  # below pi: rvec is then unique
    tvec = rng.normal(size=3) * rng.uniform(1, 2000)
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    return K, dist, (w, h), rvec, tvec, rng.uniform(200, 5000)


def cases(n=40, seed=20240601):
    rng = np.random.default_rng(seed)
    return [(SOFAST_K, SOFAST_DIST, SOFAST_SIZE, SOFAST_RVEC, SOFAST_TVEC, 9400.0)] + [
        random_opencv(rng) for _ in range(n)]


def project_points(points, K, dist, rvec, tvec):
    """cv2.projectPoints written out (OpenCV's documented pinhole + Brown-Conrady model): (n, 2) (x, y) px."""
    R = Rotation.from_rotvec(rvec).as_matrix()
    pc = points @ R.T + tvec
    x, y = pc[:, 0] / pc[:, 2], pc[:, 1] / pc[:, 2]
    k1, k2, p1, p2, k3 = dist
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.column_stack([K[0, 0] * xd + K[0, 2], K[1, 1] * yd + K[1, 2]])


def points_in_view(K, size, rvec, tvec, rng, n=300):
    """World points whose undistorted image lies over the image, at depths 0.3 to 3 m (built from the
    camera frame, not through the camera under test)."""
    w, h = size
    x = (rng.uniform(-0.5, w - 0.5, n) - K[0, 2]) / K[0, 0]
    y = (rng.uniform(-0.5, h - 0.5, n) - K[1, 2]) / K[1, 1]
    z = rng.uniform(300, 3000, n)
    pc = np.column_stack([x * z, y * z, z])
    R = Rotation.from_rotvec(rvec).as_matrix()
    return (pc - tvec) @ R  # R^T (pc - t), row by row


# -- (a) the converters are inverse to rounding -------------------------------------------------------


@pytest.mark.parametrize("case", range(41))
def test_opencv_round_trip(case):
    K, dist, size, rvec, tvec, distance = cases()[case]
    cam = camera_from_opencv(K, dist, size, rvec, tvec, distance_mm=distance)
    o = camera_to_opencv(cam)
    assert isinstance(o, OpenCVCamera) and o.image_size == size
    np.testing.assert_allclose(o.matrix, K, rtol=ROUND_TRIP, atol=0)  # the zeros and K[2, 2] = 1 exactly
    np.testing.assert_allclose(o.distortion, dist, rtol=ROUND_TRIP, atol=0)
    # the pose: relative to its own size (a small component of a large vector carries the vector's rounding)
    assert np.linalg.norm(o.rvec - rvec) <= ROUND_TRIP * np.linalg.norm(rvec)
    assert np.linalg.norm(o.tvec_mm - tvec) <= ROUND_TRIP * np.linalg.norm(tvec)
    # what the conversion means: the documented frame, field width, principal point, aspect and terms
    R = Rotation.from_rotvec(rvec).as_matrix()
    np.testing.assert_allclose(cam.position, -R.T @ tvec, rtol=0, atol=1e-12 * np.linalg.norm(tvec))
    # the frame is rebuilt from target - position: rounding grows with |position| / distance (up to ~35 here)
    np.testing.assert_allclose(np.stack([cam.right, cam.down, cam.forward]), R, rtol=0, atol=1e-13)
    assert cam.distance == pytest.approx(distance, rel=1e-13)
    assert cam.field_width == pytest.approx(size[0] * distance / K[0, 0], rel=1e-14)
    assert cam.aspect == pytest.approx(K[1, 1] / K[0, 0], rel=1e-15)
    np.testing.assert_allclose(cam.principal_point_px, [K[1, 2], K[0, 2]], rtol=1e-15)
    t = size[0] / (2 * K[0, 0])
    np.testing.assert_allclose(cam.distortion, dist * [t**2, t**4, t, t, t**6], rtol=1e-14)


def test_sofast_camera_defaults_to_the_camera_frame():
    """Without a pose the camera frame is the world frame: at the origin, looking down +z, image +col along +x."""
    cam = camera_from_opencv(SOFAST_K, SOFAST_DIST, SOFAST_SIZE)
    np.testing.assert_array_equal(cam.position, 0.0)
    np.testing.assert_array_equal(np.stack([cam.right, cam.down, cam.forward]), np.eye(3))
    o = camera_to_opencv(cam)
    np.testing.assert_array_equal(o.rvec, 0.0)
    np.testing.assert_array_equal(o.tvec_mm, 0.0)
    np.testing.assert_allclose(o.matrix, SOFAST_K, rtol=ROUND_TRIP)
    assert not o.matrix.flags.writeable
    # four terms are (k1, k2, p1, p2) with k3 = 0; a (1, 5) array, as cv2.calibrateCamera returns, reads too
    four = camera_from_opencv(SOFAST_K, SOFAST_DIST[:4], SOFAST_SIZE)
    assert four == cam == camera_from_opencv(SOFAST_K, SOFAST_DIST[None, :], SOFAST_SIZE)
    # K[2, 2] is not read (cv2.projectPoints ignores it)
    K = SOFAST_K.copy()
    K[2, 2] = 2.0
    assert camera_from_opencv(K, SOFAST_DIST, SOFAST_SIZE) == cam


def test_rotation_vectors_agree_with_scipy(np_rng):
    axes = np_rng.normal(size=(200, 3))
    angles = np.concatenate([np_rng.uniform(0, np.pi, 195), [0.0, 1e-12, 1e-6, np.pi - 1e-9, np.pi]])
    rvecs = axes / np.linalg.norm(axes, axis=1, keepdims=True) * angles[:, None]
    R = rvec_to_matrix(rvecs)
    np.testing.assert_allclose(R, Rotation.from_rotvec(rvecs).as_matrix(), rtol=0, atol=1e-15)
    back = matrix_to_rvec(R)
    # the same rotation; the vector itself for angles below pi (at pi, rvec and -rvec are one rotation)
    np.testing.assert_allclose(rvec_to_matrix(back), R, rtol=0, atol=1e-15)
    below = angles < np.pi - 1e-6
    np.testing.assert_allclose(back[below], rvecs[below], rtol=0, atol=1e-14)
    np.testing.assert_allclose(back[below], Rotation.from_matrix(R[below]).as_rotvec(), rtol=0, atol=1e-14)
    assert np.all(np.linalg.norm(back, axis=1) <= np.pi + 1e-15)
    assert rvec_to_matrix([0.0, 0.0, 0.0]).tolist() == np.eye(3).tolist()
    assert matrix_to_rvec(np.eye(3)).shape == (3,)


# -- (b) Camera.project is cv2.projectPoints -------------------------------------------------------------


@pytest.mark.parametrize("case", range(0, 41, 4))
def test_project_matches_opencv_formula(case, np_rng):
    K, dist, size, rvec, tvec, distance = cases()[case]
    cam = camera_from_opencv(K, dist, size, rvec, tvec, distance_mm=distance)
    points = points_in_view(K, size, rvec, tvec, np_rng)
    want = project_points(points, K, dist, rvec, tvec)
    row, col = cam.project(points)
    np.testing.assert_allclose(col, want[:, 0], rtol=0, atol=PX)
    np.testing.assert_allclose(row, want[:, 1], rtol=0, atol=PX)
    # n-dimensional input keeps its shape
    r2, c2 = cam.project(points[:12].reshape(2, 6, 3))
    np.testing.assert_array_equal(r2.ravel(), row[:12])
    np.testing.assert_array_equal(c2.ravel(), col[:12])


# -- (c) pixel -> ray -> pixel with tangential terms and aspect != 1 -----------------------------------


@pytest.mark.parametrize("case", range(0, 41, 4))
def test_pixel_rays_reproject_to_their_pixels(case, np_rng):
    K, dist, size, rvec, tvec, distance = cases()[case]
    cam = camera_from_opencv(K, dist, size, rvec, tvec, distance_mm=distance)
    assert cam.aspect != 1.0 and cam.distortion[2] != 0.0 and cam.distortion[3] != 0.0
    w, h = size
    corners_r, corners_c = np.array([-0.5, -0.5, h - 0.5, h - 0.5]), np.array([-0.5, w - 0.5, -0.5, w - 0.5])
    rows = np.concatenate([np_rng.uniform(-0.5, h - 0.5, 300), corners_r])
    cols = np.concatenate([np_rng.uniform(-0.5, w - 0.5, 300), corners_c])
    origins, directions = cam.pixel_rays(rows, cols)
    points = origins + np_rng.uniform(100, 5000, rows.shape)[:, None] * directions
    r2, c2 = cam.project(points)
    np.testing.assert_allclose(r2, rows, rtol=0, atol=PX)  # 2-D Newton undistortion converges to rounding
    np.testing.assert_allclose(c2, cols, rtol=0, atol=PX)
    # and the rays are OpenCV's: projectPoints of them lands on the same pixels
    np.testing.assert_allclose(project_points(points, K, dist, rvec, tvec), np.column_stack([cols, rows]),
                               rtol=0, atol=PX)


@pytest.mark.parametrize("projection", ["perspective", "orthographic"])
def test_strong_tangential_distortion_inverts(projection, np_rng):
    """Tangential terms 30 times a real lens's, k3 and aspect 1.2: distort(undistort(.)) is the identity to
    rounding over 1.5 times the image, and pixel -> ray -> pixel holds for both projections."""
    d = shiny_1988(projection=projection).camera.to_dict()
    d.update(principal_point_px=[240.0, 270.0], distortion=[0.02, -0.01, 0.03, -0.02, 0.005], aspect=1.2)
    cam = Camera.from_dict(d)
    ud, vd = np_rng.uniform(-1.5, 1.5, (2, 1000))
    u, v = cam.undistort(ud, vd)
    back = cam.distort(u, v)
    np.testing.assert_allclose(back[0], ud, rtol=0, atol=1e-14)  # |u| <= 2: rounding is ~1e-16 a step
    np.testing.assert_allclose(back[1], vd, rtol=0, atol=1e-14)
    rows, cols = np_rng.uniform(-0.5, 511.5, (2, 500))
    for z in (-1.0, 0.0, 1.0):
        r2, c2 = cam.project(cam.backproject_to_plane(rows, cols, plane_z=z))
        np.testing.assert_allclose(r2, rows, rtol=0, atol=PX)
        np.testing.assert_allclose(c2, cols, rtol=0, atol=PX)
    # rows are aspect times denser: a point one pixel pitch below the target is aspect rows down
    ideal = Camera.from_dict(d | {"distortion": [0.0, 0.0]})
    r, c = ideal.project(ideal.target + ideal.pixel_pitch * ideal.down)
    assert (r - 240.0, c - 270.0) == (pytest.approx(1.2, rel=1e-12), pytest.approx(0.0, abs=1e-12))
    # NaN in, NaN out, the others unaffected
    u, v = cam.undistort([np.nan, 0.3], [0.1, -0.2])
    assert np.isnan(u[0]) and np.isnan(v[0]) and np.allclose(cam.distort(u[1:], v[1:]), [[0.3], [-0.2]])


# -- (d) radial-only cameras: bit for bit as before -------------------------------------------------------


def old_offsets(cam, k1, k2, row, col):
    """The radial-only pixel -> undistorted offset map as it was written before the full model."""
    pr, pc = cam.principal_point_px
    half = 0.5 * cam.width
    ud, vd = (np.asarray(col, float) - pc) / half, (np.asarray(row, float) - pr) / half
    if k1 == 0.0 and k2 == 0.0:
        u, v = ud, vd
    else:
        rd = np.hypot(ud, vd)
        r = rd.copy()
        for _ in range(20):
            r2 = r * r
            step = (r * (1.0 + k1 * r2 + k2 * r2 * r2) - rd) / (1.0 + 3.0 * k1 * r2 + 5.0 * k2 * r2 * r2)
            r = r - step
            if np.all(np.abs(step) <= 1e-15 * np.maximum(r, 1e-300)):
                break
        with np.errstate(invalid="ignore", divide="ignore"):
            scale = np.where(rd > 0, r / rd, 1.0)
        u, v = ud * scale, vd * scale
    half_mm = 0.5 * cam.field_width
    return u * half_mm, v * half_mm


def old_project(cam, k1, k2, points):
    rel = np.asarray(points, dtype=float) - cam.position
    x, y = rel @ cam.right, rel @ cam.down
    if cam.projection == "perspective":
        depth = rel @ cam.forward
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = np.where(depth > 0, cam.distance / depth, np.nan)
        x, y = x * scale, y * scale
    half_mm = 0.5 * cam.field_width
    u, v = x / half_mm, y / half_mm
    r2 = u * u + v * v
    f = 1.0 + k1 * r2 + k2 * r2 * r2
    pr, pc = cam.principal_point_px
    half = 0.5 * cam.width
    return v * f * half + pr, u * f * half + pc


@pytest.mark.parametrize("projection", ["perspective", "orthographic"])
@pytest.mark.parametrize("k", [(0.0, 0.0), (2e-3, -5e-4), (0.05, -0.01)])
def test_radial_cameras_unchanged_bit_for_bit(projection, k, np_rng):
    d = shiny_1988(projection=projection).camera.to_dict()
    d.update(principal_point_px=[250.25, 262.75], distortion=list(k))
    cam = Camera.from_dict(d)
    assert cam.distortion == (*k, 0.0, 0.0, 0.0) and cam.aspect == 1.0
    assert Camera.from_dict(d | {"distortion": [*k, 0.0, 0.0, 0.0]}) == cam  # five terms with zeros: the same
    rows, cols = np_rng.uniform(-0.5, 511.5, (2, 500))
    np.testing.assert_array_equal(np.stack(cam._offsets(rows, cols)), np.stack(old_offsets(cam, *k, rows, cols)))
    points = cam.backproject_to_plane(rows, cols, plane_z=0.5)
    np.testing.assert_array_equal(np.stack(cam.project(points)), np.stack(old_project(cam, *k, points)))


# -- (e) JSON --------------------------------------------------------------------------------------------


def test_json_round_trip_with_five_terms_and_aspect():
    cam = camera_from_opencv(SOFAST_K, SOFAST_DIST, SOFAST_SIZE, SOFAST_RVEC, SOFAST_TVEC, distance_mm=9400.0)
    rig = shiny_1988().with_camera(cam)
    doc = json.loads(rig.to_json())
    c = doc["cameras"][0]
    assert len(c["distortion"]) == 5 and c["aspect"] == cam.aspect
    back = Rig.from_json(rig.to_json())
    assert back == rig and back.to_json() == rig.to_json()
    assert back.camera.distortion == cam.distortion and back.camera.aspect == cam.aspect  # exact: repr floats
    np.testing.assert_allclose(camera_to_opencv(back.camera).matrix, SOFAST_K, rtol=ROUND_TRIP)
    # k3 alone is written as five terms too, and aspect alone without distortion
    radial3 = Camera.from_dict(shiny_1988().camera.to_dict() | {"distortion": [1e-3, 0.0, 0.0, 0.0, 2e-4]})
    assert radial3.to_dict()["distortion"] == [1e-3, 0.0, 0.0, 0.0, 2e-4]
    square = Camera.from_dict(shiny_1988().camera.to_dict() | {"aspect": 1.25})
    assert "distortion" not in square.to_dict() and square.to_dict()["aspect"] == 1.25
    assert not square.is_ideal


def test_old_two_term_json_reads_and_writes_unchanged():
    """A rig file written before the full model (two radial terms, no aspect): read, it is the same camera;
    written again, the same bytes."""
    d = shiny_1988().camera.to_dict()
    d.update(principal_point_px=[250.25, 262.75], distortion=[2e-3, -5e-4])
    text = json.dumps(shiny_1988().to_dict() | {"cameras": [d]}, indent=2)
    rig = Rig.from_json(text)
    assert rig.to_json() == text
    assert rig.camera.distortion == (2e-3, -5e-4, 0.0, 0.0, 0.0) and rig.camera.aspect == 1.0
    ideal = shiny_1988()
    assert "distortion" not in ideal.to_dict()["cameras"][0] and "aspect" not in ideal.to_dict()["cameras"][0]
    assert ideal.camera.is_ideal


# -- the calibrator holds the terms it does not estimate ------------------------------------------------


def test_calibration_keeps_tangential_terms_and_aspect():
    """A true camera with tangential terms, k3 and aspect; a nominal camera that knows them but not the pose,
    focal length, principal point, k1, k2: the solve recovers the rest exactly and keeps the held terms."""
    from shinysim.calibrate.camera import calibrate_camera
    from shinysim.objects.plate import PlatePlacement, dot_grid

    held = dict(distortion=[0.0, 0.0, 2e-3, -1e-3, 1e-4], aspect=1.02)
    nominal = Camera.from_dict(shiny_1988().camera.to_dict() | held)
    rot = Rotation.from_rotvec(np.radians([0.03, -0.04, 0.0]))
    position = nominal.position + [0.03, 0.0, -0.04]
    true = Camera("perspective", 512, 512, position, position + nominal.distance * rot.apply(nominal.forward),
                  rot.apply(nominal.up), nominal.field_width / 1.005, principal_point=(258.5, 251.5),
                  distortion=(1e-3, -2e-4, 2e-3, -1e-3, 1e-4), aspect=1.02)
    plate = dot_grid()
    obs = []
    for z in (-1.0, 0.0, 1.0):
        placement = PlatePlacement((0.0, 0.0, z))
        obs.append((plate, placement, np.column_stack(true.project(placement.world_holes(plate)))))
    cal = calibrate_camera(obs, nominal, estimate=("pose", "focal", "principal_point", "distortion"))
    assert cal.camera.distortion[2:] == true.distortion[2:] and cal.camera.aspect == 1.02
    assert cal.rms_px < 1e-9  # noise-free points: the solve ends at rounding (~1e-13 px)
    # noise-free: 1e-8 of the terms' 1e-3 scale, as the calibration tests allow (2e-16 measured)
    np.testing.assert_allclose(cal.camera.distortion[:2], true.distortion[:2], rtol=0, atol=1e-11)
    np.testing.assert_allclose(cal.camera.principal_point_px, true.principal_point_px, rtol=0, atol=1e-8)


# -- (f) bad input -----------------------------------------------------------------------------------------


@pytest.mark.parametrize("change, field, message", [
    (dict(matrix=[[5492.06, 3.0, 812.5], [0, 5486.27, 617.5], [0, 0, 1]]), "matrix[0, 1]", "skew"),
    (dict(matrix=[[5492.06, 0, 812.5], [0.5, 5486.27, 617.5], [0, 0, 1]]), "matrix[1, 0]", "not 0"),
    (dict(matrix=[[5492.06, 0, 812.5], [0, 5486.27, 617.5], [0, 1e-3, 1]]), "matrix[2, 1]", "not 0"),
    (dict(matrix=[[-5492.06, 0, 812.5], [0, 5486.27, 617.5], [0, 0, 1]]), "matrix[0, 0]", "> 0"),
    (dict(matrix=[[5492.06, 0, 812.5], [0, 5486.27 * 3, 617.5], [0, 0, 1]]), "matrix[1, 1]", "outside"),
    (dict(matrix=[[5492.06, 0, np.nan], [0, 5486.27, 617.5], [0, 0, 1]]), "matrix", "finite"),
    (dict(matrix=np.eye(2)), "matrix", r"\(3, 3\)"),
    (dict(distortion=[-0.1442, 1.6097, 2.5e-5, -1.9e-3, 0.0, 0.1, 0.0, 0.0]), "distortion", "rational model"),
    (dict(distortion=[0.0] * 12), "distortion", "thin-prism"),
    (dict(distortion=[-0.1442, 1.6097, 2.5e-5]), "distortion", "4 or 5"),
    (dict(distortion=[-0.1442, np.inf, 0, 0]), "distortion", "4 or 5"),
    (dict(distortion=[-40.0, 0, 0, 0, 0]), "distortion",
     r"\(-40.0, 0.0, 0.0, 0.0, 0.0\) \(OpenCV's normalisation\) folds the image; in shinysim's"),
    (dict(distortion=[0, 0, 3.0, 0, 0]), "distortion", "Jacobian determinant"),
    (dict(image_size=(1626.0, 1236)), "image_size", "integers"),
    (dict(image_size=(1626,)), "image_size", "width, height"),
    (dict(rvec=[0.1, 0.2]), "rvec", "3 finite"),
    (dict(tvec_mm=[0.1, np.nan, 0]), "tvec_mm", "3 finite"),
    (dict(distance_mm=0.0), "distance_mm", "> 0"),
])
def test_bad_opencv_input_names_the_field(change, field, message):
    args = dict(matrix=SOFAST_K, distortion=SOFAST_DIST, image_size=SOFAST_SIZE) | change
    with pytest.raises(RigError, match=message) as exc:
        camera_from_opencv(**args)
    assert exc.value.field == field


@pytest.mark.parametrize("change, message", [
    (dict(aspect=0.0), "finite number > 0"),
    (dict(aspect=float("nan")), "finite number > 0"),
    (dict(aspect=True), "finite number > 0"),
    (dict(aspect=2.0), r"outside \(0.5, 2.0\)"),
    (dict(aspect=0.5), r"outside \(0.5, 2.0\)"),
    (dict(distortion=(1e-3, 0.0, 0.0)), "2 finite numbers .* or 5"),
    (dict(distortion=(1e-3, 0.0, 0.0, 0.0, np.nan)), "2 finite numbers .* or 5"),
    (dict(distortion=(0.0, 0.0, 0.2, 0.2, 0.0)), "folds the image .* Jacobian"),  # tangential: folds
    (dict(distortion=(0.0, 0.0, 0.0, 0.0, -0.05)), "folds the image .* radial"),  # k3 alone: folds
])
def test_bad_camera_terms_name_the_field(change, message):
    d = dict(projection="perspective", width=512, height=512, position=[0, 0, 127], target=[0, 0, 0], up=[0, 1, 0],
             field_width=25.6) | change
    with pytest.raises(RigError, match=message) as exc:
        Camera(**d)
    assert exc.value.field == ("aspect" if "aspect" in change else "distortion")


def test_bad_rig_json_lens_fields():
    doc = json.loads(shiny_1988().to_json())
    doc["cameras"][0]["aspect"] = 0.0
    with pytest.raises(RigError, match=r"cameras\[0\]\.aspect: must be a finite number > 0"):
        Rig.from_dict(doc)
    doc["cameras"][0]["aspect"] = "1.0"
    with pytest.raises(RigError, match=r"cameras\[0\]\.aspect"):
        Rig.from_dict(doc)
    doc["cameras"][0]["aspect"] = 1.1
    doc["format"] = "shinysim-rig/1"
    with pytest.raises(RigError, match=r"cameras\[0\]\.aspect: aspect needs format 'shinysim-rig/2'"):
        Rig.from_dict(doc)


def test_orthographic_camera_has_no_opencv_model():
    with pytest.raises(RigError, match="perspective") as exc:
        camera_to_opencv(shiny_1988(projection="orthographic").camera)
    assert exc.value.field == "projection"
    with pytest.raises(RigError, match="proper rotation"):
        matrix_to_rvec(np.diag([1.0, 1.0, -1.0]))


# -- the renderer's rays --------------------------------------------------------------------------------


@requires_jit
def test_rendered_rays_follow_the_full_model():
    """The renderer's own rays (float32, a fixed Newton count) with tangential terms, k3 and aspect: truth
    hit positions project back to their pixel centres."""
    from shinysim.sim.render import Simulator
    from shinysim.sim.scene import sphere_object

    rig = shiny_1988(resolution=64)
    d = rig.camera.to_dict()
    # strong, to be visible at 64 px
    d.update(principal_point_px=[30.0, 34.5], distortion=[0.05, -0.01, 0.01, -0.008, 0.004], aspect=1.1)
    cam = Camera.from_dict(d)
    t = Simulator(rig.with_camera(cam), sphere_object()).render_truth()
    rows, cols = np.nonzero(t.mask)
    assert rows.size > 100
    r2, c2 = cam.project(t.positions[rows, cols].astype(float))
    # float32 rays and hit points: 2e-3 px is ~8 nm at this pitch, far below anything measured
    np.testing.assert_allclose(r2, rows, atol=2e-3)
    np.testing.assert_allclose(c2, cols, atol=2e-3)
