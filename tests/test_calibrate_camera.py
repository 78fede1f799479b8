"""Camera calibration from the hole plate: exact synthetic solves, honest covariances, detection, bad input."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from conftest import draw_disks
from scipy.spatial.transform import Rotation

from shinysim.calibrate.camera import (
    PARAMETER_NAMES,
    calibrate_camera,
    camera_parameters,
    find_holes,
    ray_errors,
)
from shinysim.errors import CalibrationError
from shinysim.objects.plate import HolePlate, PlatePlacement, dot_grid, shiny_plate
from shinysim.rig import Camera, shiny_1988

ALL = ("pose", "focal", "principal_point", "distortion")
NOMINAL = shiny_1988().camera
#: The targets of the rendered study: rays within 1 um at z = -1, 0, 1 mm and 0.02 degree.
RAY_UM, RAY_DEG = 1.0, 0.02
GRID = np.linspace(0, 511, 18)  # pixel grid over the whole image, corners included
#: The rotation of the true cameras: 0.05 degree about an axis in the x-y plane.
ROTVEC_DEG = 0.05 * np.array([0.6, -0.8, 0.0])


def make_camera(nominal=NOMINAL, rotvec_deg=ROTVEC_DEG, shift=(0.03, 0.0, -0.04), scale=1 / 1.005,
                pp_offset=(3.0, -4.0), distortion=(1e-3, -2e-4), distance=None):
    """The nominal camera turned, moved, its field width scaled, its principal point moved: built independently
    of the solver (scipy's rotation), keeping the target distance unless ``distance`` is given."""
    rot = Rotation.from_rotvec(np.radians(rotvec_deg))
    position = nominal.position + np.asarray(shift)
    forward = rot.apply(nominal.forward)
    d = nominal.distance if distance is None else distance
    return Camera(nominal.projection, nominal.width, nominal.height, position, position + d * forward,
                  rot.apply(nominal.up), nominal.field_width * scale * d / nominal.distance,
                  principal_point=tuple(nominal.principal_point_px + np.asarray(pp_offset)), distortion=distortion)


def truth_of(camera, nominal=NOMINAL, rotvec_deg=ROTVEC_DEG, scale=1 / 1.005):
    """The solver's parameters of ``make_camera``'s camera, written out by hand."""
    pr, pc = camera.principal_point_px
    values = [*camera.position, *(1e3 * np.radians(rotvec_deg)), scale, pr, pc, *camera.distortion]
    return dict(zip(PARAMETER_NAMES, values))


def observe(camera, placements, rng=None, sigma=0.0):
    obs = []
    for plate, placement in placements:
        rows, cols = camera.project(placement.world_holes(plate))
        points = np.column_stack([rows, cols])
        if rng is not None:
            points = points + rng.normal(0.0, sigma, points.shape)
        obs.append((plate, placement, points))
    return obs


def heights(plate, zs=(-1.0, 0.0, 1.0)):
    return [(plate, PlatePlacement((0.0, 0.0, z))) for z in zs]


#: Scale of each parameter, for tolerances relative to it (a rotation of 0 has no size of its own).
SCALE = {"position_x_mm": 1.0, "position_y_mm": 1.0, "position_z_mm": 127.0, "rotation_x_mrad": 1.0,
         "rotation_y_mrad": 1.0, "rotation_z_mrad": 1.0, "field_scale": 1.0, "principal_row_px": 256.0,
         "principal_col_px": 256.0, "k1": 1e-3, "k2": 1e-3}


# -- the parametrisation ------------------------------------------------------------------------------


def test_camera_parameters_of_a_known_camera():
    true = make_camera()
    got = camera_parameters(true, NOMINAL)
    want = truth_of(true)
    for name in PARAMETER_NAMES:
        assert got[name] == pytest.approx(want[name], abs=1e-12 * SCALE[name])  # closed form both ways
    # the target distance is a gauge: the same rays from another distance give the same parameters
    far = camera_parameters(make_camera(distance=300.0), NOMINAL)
    for name in PARAMETER_NAMES:
        assert far[name] == pytest.approx(want[name], abs=1e-12 * SCALE[name])  # the same closed forms


# -- exact synthetic solves ---------------------------------------------------------------------------


@pytest.mark.parametrize("placements", [
    heights(dot_grid()),
    [(shiny_plate(), PlatePlacement((sx, sy, 0.0))) for sx in (-0.25, 0.25) for sy in (-0.25, 0.25)]
    + [(shiny_plate(), PlatePlacement((0.0, 0.0, 1.0), (5.0, -3.0), 15.0))],
], ids=["dot grid at three heights", "seven holes at four corners and raised, tilted"])
def test_every_parameter_recovered_exactly(placements):
    true = make_camera()
    want = truth_of(true)
    cal = calibrate_camera(observe(true, placements), NOMINAL, estimate=ALL)
    assert cal.names == list(PARAMETER_NAMES)
    for name in PARAMETER_NAMES:
        # noise-free: the solve ends at rounding level (7e-13 of each scale measured)
        assert cal.parameters[name] == pytest.approx(want[name], abs=1e-8 * SCALE[name]), name
    assert cal.rms_px < 1e-9  # pixel coordinates of ~256 carry ~1e-13 of rounding
    assert cal.pixel_sigma_source == "residuals"
    errors = ray_errors(cal, true, GRID, GRID)
    assert errors["position_max_um"] < 1e-6  # the same camera, up to rounding (1e-12 um measured)
    assert errors["angle_max_deg"] < 1e-9  # 3e-15 degree measured
    assert cal.n_points == sum(p.n_holes for p, _ in placements)
    assert cal.n_placements == len(placements)


def test_the_papers_one_placement_solve_is_exact_on_a_tilted_plate():
    """Pose and focal from one image: exact when the plate is tilted (a plate facing the camera is degenerate)."""
    true = make_camera(pp_offset=(0.0, 0.0), distortion=(0.0, 0.0))
    want = truth_of(true)
    placement = [(shiny_plate(), PlatePlacement(tilt_deg=(10.0, 0.0)))]
    cal = calibrate_camera(observe(true, placement), NOMINAL, estimate=("pose", "focal"))
    assert cal.names == list(PARAMETER_NAMES[:7])
    for name in cal.names:
        # noise-free; the distance is 5e3 times less determined than the rest here (relative singular
        # value 1.7e-4), yet 7e-13 of each scale is measured: 1e-8 has room for other BLAS and platforms
        assert cal.parameters[name] == pytest.approx(want[name], abs=1e-8 * SCALE[name]), name
    assert cal.camera.is_ideal
    # the paper's own placement, flat on the reference plane, cannot tell distance from focal length
    with pytest.raises(CalibrationError, match=r"position_z_mm and field_scale trade against each other.*"
                                               r"do not tell its distance from its focal length.*spacers"):
        calibrate_camera(observe(true, [(shiny_plate(), PlatePlacement())]), NOMINAL, estimate=("pose", "focal"))


def test_orthographic_camera_leaves_out_the_position_along_its_axis():
    nominal = shiny_1988(projection="orthographic").camera
    true = make_camera(nominal, pp_offset=(0.0, 0.0))
    # the position along the axis is not seen: slid along it to the nominal height, the rays are the same
    slid = true.position + (nominal.position[2] - true.position[2]) / true.forward[2] * true.forward
    want = truth_of(true) | dict(zip(("position_x_mm", "position_y_mm", "position_z_mm"), slid))
    cal = calibrate_camera(observe(true, heights(dot_grid())), nominal, estimate=("pose", "focal", "distortion"))
    assert "position_z_mm" not in cal.names and len(cal.names) == 8
    for name in cal.names:
        assert cal.parameters[name] == pytest.approx(want[name], abs=1e-8 * SCALE[name]), name  # as above
    assert cal.parameters["position_z_mm"] == nominal.position[2]  # held
    assert ray_errors(cal, true, GRID, GRID)["position_max_um"] < 1e-6  # the same rays up to rounding
    with pytest.raises(CalibrationError, match="orthographic camera's principal point is the same as a sideways"):
        calibrate_camera(observe(true, heights(dot_grid())), nominal, estimate=ALL)


# -- noise: honest covariances and the ray targets ----------------------------------------------------


def test_covariance_is_honest_and_rays_meet_the_targets():
    """50 noisy solves (0.02 px) of a 6 x 6 grid at three heights: >= 95 % of parameters within 3 sigma, every
    seed's rays within the targets (the default 5 x 5 grid leaves more of the image corners to extrapolation,
    and reaches the targets in all but a few per cent of the seeds: see the module's table)."""
    true = make_camera()
    want = truth_of(true)
    rng = np.random.default_rng(20240611)
    inside = within_1 = total = 0
    worst_um = worst_deg = 0.0
    for _ in range(50):
        cal = calibrate_camera(observe(true, heights(dot_grid(6, 0.34)), rng, 0.02), NOMINAL, estimate=ALL)
        for name in cal.names:
            z = abs(cal.parameters[name] - want[name]) / cal.sigma[name]
            inside += z <= 3
            within_1 += z <= 1
            total += 1
        errors = ray_errors(cal, true, GRID, GRID)
        worst_um = max(worst_um, errors["position_max_um"])
        worst_deg = max(worst_deg, errors["angle_max_deg"])
    assert inside / total >= 0.95  # the target (a Gaussian gives 99.7 %; 99.6 % measured)
    assert 0.55 <= within_1 / total <= 0.80  # nor inflated (68 % for a Gaussian, 72 % measured; 550 correlated draws)
    assert worst_um <= RAY_UM  # the target; measured 0.21 um, the worst of 50 (in an image corner)
    assert worst_deg <= RAY_DEG  # the target; measured 0.003 degree
    # the distance is barely determined and says so: sigma 0.17 mm (of 127), tied to the field scale
    assert 0.05 < cal.sigma["position_z_mm"] < 1.0
    pairs = {(a, b): r for a, b, r in cal.strongly_correlated()}
    assert pairs[("position_z_mm", "field_scale")] < -0.999


def test_given_pixel_sigma_scales_the_covariance():
    true = make_camera()
    obs = observe(true, heights(dot_grid()), np.random.default_rng(3), 0.02)
    a = calibrate_camera(obs, NOMINAL, estimate=ALL)
    b = calibrate_camera(obs, NOMINAL, estimate=ALL, pixel_sigma=0.04)
    assert a.pixel_sigma_source == "residuals" and b.pixel_sigma_source == "given"
    assert b.residual_sigma == pytest.approx(a.pixel_sigma, rel=1e-12)  # the same residuals
    np.testing.assert_allclose(b.covariance, a.covariance * (0.04 / a.pixel_sigma) ** 2, rtol=1e-9)  # linear in sigma^2


# -- detection on analytic images ---------------------------------------------------------------------


def draw(camera, plate, placement, *, bright=1.0, dark=0.0, supersample=8):
    """Anti-aliased disks of the hole diameter (at each hole's depth) centred on the projected holes."""
    image = np.full(camera.shape, dark, float)
    points = draw_disks(image, camera, placement.world_holes(plate), plate.hole_diameter, bright - dark, supersample)
    return image, points


@pytest.mark.parametrize("plate, placement", [
    (shiny_plate(), PlatePlacement()),
    (dot_grid(), PlatePlacement((0.05, -0.03, 1.0), rotation_deg=3.0)),
    (shiny_plate(), PlatePlacement((0.2, 0.1, -1.0), rotation_deg=12.0)),
])
def test_find_holes_gives_the_projected_centres(plate, placement):
    true = make_camera()
    image, points = draw(true, plate, placement)
    found = find_holes(image, plate, placement, NOMINAL)
    # 8 x 8 supersampling quantises the disks' edges: 0.003 px measured (halving with each doubling)
    np.testing.assert_allclose(found, points, atol=0.01)
    noisy = 0.05 + 0.8 * image + np.random.default_rng(1).normal(0.0, 0.01, image.shape)
    # 1 % noise and a 0.05 pedestal: the COG's noise is 0.004 px rms (0.014 px the worst of 20 seeds measured)
    np.testing.assert_allclose(find_holes(noisy, plate, placement, NOMINAL), points, atol=0.03)


def test_images_to_calibrated_camera():
    """Detected hole centres of a dot grid at two heights calibrate the camera to the ray targets."""
    true = make_camera()
    obs = []
    for plate, placement in heights(dot_grid(), (0.0, 1.0)):
        image, _ = draw(true, plate, placement)
        obs.append((plate, placement, find_holes(image, plate, placement, NOMINAL, name=f"z={placement.offset[2]}")))
    cal = calibrate_camera(obs, NOMINAL, estimate=ALL)
    assert cal.rms_px < 0.01  # the drawing's 0.003 px quantisation, nothing else (0.002 px measured)
    errors = ray_errors(cal, true, GRID, GRID)
    # the study's targets (measured 0.007 um and 0.0001 degree: detection without noise is nearly exact)
    assert errors["position_max_um"] < RAY_UM and errors["angle_max_deg"] < RAY_DEG


# -- results ------------------------------------------------------------------------------------------


def test_apply_writes_the_camera_and_metadata():
    rig = shiny_1988()
    rig.metadata["calibration"] = {"sources": {"kept": True}}
    true = make_camera()
    cal = calibrate_camera(observe(true, heights(dot_grid())), NOMINAL, estimate=ALL)
    out = cal.apply(rig)
    assert out.camera == cal.camera
    meta = out.metadata["calibration"]
    assert meta["sources"] == {"kept": True}
    cam = meta["camera"]
    assert cam["estimated"] == list(PARAMETER_NAMES)
    assert set(cam["values"]) == set(cam["sigma"]) == set(PARAMETER_NAMES)
    assert cam["n_placements"] == 3 and cam["n_points"] == 75 and cam["pixel_sigma_source"] == "residuals"
    assert "camera" not in rig.metadata["calibration"]  # the input rig is untouched
    json.loads(out.to_json())  # JSON-safe
    with pytest.raises(CalibrationError, match="cameras 0..0"):
        cal.apply(rig, index=1)


def test_ray_errors_of_a_shifted_camera():
    cam = NOMINAL
    moved = Camera(cam.projection, cam.width, cam.height, cam.position + [0.001, 0, 0], cam.target + [0.001, 0, 0],
                   cam.up, cam.field_width)
    e = ray_errors(moved, cam, GRID, GRID)
    assert e["n_rays"] == 18 * 18 and e["heights_mm"] == [-1.0, 0.0, 1.0]
    assert e["position_max_um"] == pytest.approx(1.0, abs=1e-9)  # every ray moved by 1 um, parallel
    assert e["position_rms_um"] == pytest.approx(1.0, abs=1e-9)
    assert e["angle_max_deg"] < 1e-12  # directions unchanged, up to rounding
    turned = make_camera(rotvec_deg=(0.0, 0.0, 0.0), shift=(0, 0, 0), scale=1.0, pp_offset=(0, 0), distortion=(0, 0))
    assert ray_errors(turned, cam, GRID, GRID)["position_max_um"] < 1e-9  # the same camera, built anew


# -- bad input ----------------------------------------------------------------------------------------


def test_find_holes_refuses_bad_images():
    plate, placement = shiny_plate(), PlatePlacement()
    image, points = draw(NOMINAL, plate, placement)
    bad = [
        (np.zeros(NOMINAL.shape), "no holes found: the image is flat"),
        (np.random.default_rng(0).normal(1.0, 0.01, NOMINAL.shape), "no holes found: no blob of a hole's size"),
        (np.zeros((100, 100)), "is 100x100 pixels, the camera's image 512x512"),
        (np.where(np.arange(512) == 7, np.nan, image), r"512 NaN or inf pixel\(s\)"),
    ]
    world = placement.world_holes(plate)
    for holes, diameter, message in [
        (world[:6], plate.hole_diameter, r"found 6 blob\(s\), the layout 'shiny_1988 seven holes' has 7 holes"),
        (np.vstack([world[:6], [[0.6, 0.85, 0.0]]]), plate.hole_diameter,
         r"blob \d at \(\d+\.\d, \d+\.\d\) does not match any hole: it is \d+\.\d px from the nearest \(hole \d\), "
         r"more than half the holes' spacing \(76\.\d px\)"),
        (np.vstack([world, [[0.45, 0.0, 0.0]]]), plate.hole_diameter, "covers .* px, too large for a 0.2032 mm hole"),
        (world, 0.1, "too small for a 0.2032 mm hole"),
        (np.vstack([world[:6], [[0.99, 0.0, 0.0]]]), plate.hole_diameter, "touches the image border"),
    ]:
        img = np.zeros(NOMINAL.shape)
        draw_disks(img, NOMINAL, holes, diameter)
        bad.append((img, message))
    bad.append(((255 * np.clip(1.5 * image, 0, 1)).astype(np.uint8), "saturated: the blob at .* clip level 255"))
    for img, message in bad:
        with pytest.raises(CalibrationError, match=message) as info:
            find_holes(img, plate, placement, NOMINAL, name="plate.exr")
        assert str(info.value).startswith("plate.exr: ")
    with pytest.raises(CalibrationError, match="clip level 1"):
        find_holes(np.clip(1.5 * image, 0, 1), plate, placement, NOMINAL, saturation=1.0)
    with pytest.raises(CalibrationError, match=r"hole\(s\) 0, 1, 2, 3, 4, 5, 6 .* image outside the frame"):
        find_holes(image, plate, PlatePlacement((3.0, 0.0, 0.0)), NOMINAL)
    # an 8-bit image below its clip level is fine
    found = find_holes((200 * image).astype(np.uint8), plate, placement, NOMINAL)
    np.testing.assert_allclose(found, points, atol=0.01)  # 8-bit quantisation: 0.002 px measured


def test_calibrate_refuses_what_cannot_be_solved():
    true = make_camera()
    flat = observe(true, [(shiny_plate(), PlatePlacement())])
    three = HolePlate([[0.0, 0.0], [0.5, 0.0], [0.0, 0.5]])
    cases = [
        (observe(true, [(three, PlatePlacement())]), ALL, None,
         r"3 hole image\(s\) in 1 placement\(s\) give 6 numbers, fewer than the 11 parameters"),
        (flat, ALL, None, "needs holes on two or more planes: with every hole on one plane the principal point "
                          "trades against a rotation.*spacers"),
        (observe(true, heights(shiny_plate())), ALL, None,
         "degenerate geometry.*k1.*too few distances from the image centre.*dot_grid"),
        (flat, ("pose", "focal"), None, "position_z_mm and field_scale trade against each other"),
        (observe(true, [(three, PlatePlacement(tilt_deg=(10, 5)))]), ("pose",), None,
         "leaves no residual to estimate the image noise from; give pixel_sigma"),
        (flat, ("pose", "focus"), None, "unknown parameter group 'focus'.*did you mean 'focal'"),
        (flat, (), None, "estimate names no parameter group"),
        (flat, ("pose",), -1.0, "pixel_sigma must be a finite number of pixels > 0"),
        ([], ("pose",), None, "no observations"),
        ([(shiny_plate(), PlatePlacement(), np.zeros((6, 2)))], ("pose",), None,
         r"observations\[0\]: points must be \(7, 2\)"),
        ([(shiny_plate(), PlatePlacement())], ("pose",), None, r"observations\[0\]: must be a \(plate, placement"),
    ]
    for obs, estimate, sigma, message in cases:
        with pytest.raises(CalibrationError, match=message):
            calibrate_camera(obs, NOMINAL, estimate=estimate, pixel_sigma=sigma, name="cal")
    # with the noise given, the exactly determined case solves
    cal = calibrate_camera(observe(true, [(three, PlatePlacement(tilt_deg=(10, 5)))]), NOMINAL, estimate=("pose",),
                           pixel_sigma=0.02)
    assert cal.pixel_sigma_source == "given" and math.isnan(cal.residual_sigma)


def test_a_misstated_placement_is_refused_not_absorbed():
    """The seven-hole plate turned 25 degrees from its stated placement matches the wrong holes (the layout's
    60-degree symmetry) and a free fit would absorb it as a camera turned ~440 mrad: refused, saying why."""
    true = make_camera()
    plate = shiny_plate()
    obs = []
    for z in (-1.0, 0.0, 1.0):
        stated = PlatePlacement((0.0, 0.0, z))
        image, _ = draw(true, plate, PlatePlacement((0.0, 0.0, z), rotation_deg=25.0 if z == 0.0 else 0.0))
        obs.append((plate, stated, find_holes(image, plate, stated, NOMINAL)))
    with pytest.raises(CalibrationError, match="implausible .* check the placements"):
        calibrate_camera(obs, NOMINAL, estimate=("pose", "focal"))
