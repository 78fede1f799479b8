"""SOFAST readers (shinysim.io.sofast): the real Sandia files read to their documented values, the
frames they state agree across files, and every class of bad file gives one SofastError naming the
file and the dataset or key."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from shinysim.errors import OptionError, SofastError
from shinysim.io import sofast
from shinysim.io.sofast import (
    read_calculation,
    read_camera,
    read_display_shape,
    read_dot_locations,
    read_ensemble_definition,
    read_facet_definition,
    read_fixed_measurement,
    read_fringe_measurement,
    read_image_calibration,
    read_sofast_folder,
    read_spatial_orientation,
)

h5py = pytest.importorskip("h5py", reason="the SOFAST readers need the sofast extra (h5py)")

SOFAST = Path(__file__).resolve().parents[2] / "shared" / "data" / "sofast"
real = pytest.mark.skipif(not SOFAST.is_dir(), reason=f"the SOFAST data set is not at {SOFAST}")

CAMERA = SOFAST / "common" / "camera_sofast.h5"
POSE = SOFAST / "common" / "spatial_orientation.h5"
FACET_JSON = SOFAST / "common" / "Facet_NSTTF.json"
DOTS = SOFAST / "fixed" / "fixed_pattern_dot_locations.h5"
FIXED = SOFAST / "fixed" / "measurement_facet.h5"
FIXED_CALC = SOFAST / "fixed" / "expected_calculation_facet.h5"
FRINGE = SOFAST / "fringe" / "measurement_facet.h5"
FRINGE_CAMERA = SOFAST / "fringe" / "camera_sofast_downsampled.h5"
CALIBRATION = SOFAST / "fringe" / "image_calibration.h5"
DISPLAY = SOFAST / "fringe" / "display_distorted_2d.h5"
FRINGE_CALC = SOFAST / "fringe" / "expected_data.h5"
FACET_POSE = "DataSofastCalculation/facet/facet_000/CalculationDataGeometryFacet"

#: Exact to float64 rounding of lengths of metres to 10 m, in millimetres (1e4 mm * 1e-16 ~ 1e-12).
ROUNDING_MM = 1e-9


def write_h5(path: Path, datasets: dict) -> Path:
    """A small HDF5 file of ``{"Group/name": value}`` (str values as variable-length strings)."""
    with h5py.File(path, "w") as f:
        for name, value in datasets.items():
            f[name] = value
    return path


def camera_datasets(**override):
    d = {"Camera/intrinsic_mat": np.array([[1000.0, 0, 320], [0, 1000, 240], [0, 0, 1]]),
         "Camera/distortion_coef": np.array([[0.1, -0.2, 0.001, 0.002, 0.0]]),
         "Camera/image_shape_xy": np.array([[640], [480]], dtype=np.int32),
         "Camera/name": np.array([b"test camera"])}
    d.update(override)
    return {k: v for k, v in d.items() if v is not None}


def fixed_datasets(**override):
    d = {"MeasurementSofastFixed/image": np.full((8, 10), 100, np.uint8),
         "MeasurementSofastFixed/origin": np.array([4.5, 3.5]),
         "MeasurementSofastFixed/dist_optic_screen": 10.0,
         "MeasurementSofastFixed/v_measure_point_facet": np.zeros(3),
         "MeasurementSofastFixed/name": "facet", "MeasurementSofastFixed/date": "2024-01-01T00:00:00"}
    d.update(override)
    return {k: v for k, v in d.items() if v is not None}


def dots_datasets(xyz=None, x=(-1, 0, 1), y=(-1, 0, 1, 2)):
    if xyz is None:
        gx, gy = np.meshgrid(np.array(x) * 0.04, np.array(y) * 0.04)
        xyz = np.stack([gx, gy, np.zeros_like(gx)], axis=-1)
    return {"DotLocationsFixedPattern/x_dot_index": np.array(x, np.int32),
            "DotLocationsFixedPattern/y_dot_index": np.array(y, np.int32),
            "DotLocationsFixedPattern/xyz_dot_loc": xyz}


def raises(match, field, call, *args, **kwargs):
    """``call`` raises SofastError matching ``match`` and naming ``field``; the message starts with the file."""
    with pytest.raises(SofastError, match=match) as info:
        call(*args, **kwargs)
    assert info.value.field == field
    if args:
        assert str(info.value).startswith(str(args[0]))
    return info.value


# ------------------------------------------------------------------------------------------ real files

@real
def test_camera_reads_the_documented_intrinsics():
    cam = read_camera(CAMERA)
    # SOURCE.md: fx ~ 5492, fy ~ 5486, cx 812.5, cy 617.5 px, image 1626 x 1236 (stored (1, 5) and (2, 1))
    assert cam.matrix[0, 0] == pytest.approx(5492, abs=1)
    assert cam.matrix[1, 1] == pytest.approx(5486, abs=1)
    assert (cam.matrix[0, 2], cam.matrix[1, 2]) == (812.5, 617.5)
    assert cam.image_size == (1626, 1236)
    assert cam.distortion.shape == (5,) and cam.name.startswith("Basler")
    assert not cam.matrix.flags.writeable


@real
def test_downsampled_camera_is_the_full_one_over_8_and_the_one_the_fringe_result_used():
    full, small = read_camera(CAMERA), read_camera(FRINGE_CAMERA)
    # the stored matrix is K / 8 entirely (last row 0, 0, 1/8): OpenCV reads fx, cx as stored
    assert small.matrix[0, 0] == pytest.approx(full.matrix[0, 0] / 8, rel=1e-12)
    assert small.matrix[2, 2] == 1.0
    assert small.image_size == (203, 154)
    np.testing.assert_array_equal(read_camera(FRINGE_CALC).matrix, small.matrix)
    np.testing.assert_array_equal(small.distortion, full.distortion)


@real
def test_spatial_orientation_maps_the_screen_origin_to_v_cam_screen_cam():
    pose = read_spatial_orientation(POSE)
    np.testing.assert_allclose(pose.screen_to_camera([0.0, 0.0, 0.0]), pose.v_cam_screen_cam_mm, atol=ROUNDING_MM)
    # SOURCE.md: v_cam_screen_cam ~ (4.45, 0.06, 0.37) m, a rotation of about 20.4 degrees (stated to 0.1)
    np.testing.assert_allclose(pose.v_cam_screen_cam_mm, [4450, 60, 370], atol=10)
    assert np.degrees(np.linalg.norm(pose.r_cam_screen)) == pytest.approx(20.4, abs=0.1)
    assert pose.r_cam_optic is None


@real
def test_spatial_orientation_is_rigid_and_inverts_on_any_shape():
    pose = read_spatial_orientation(POSE)
    p = np.random.default_rng(3).normal(scale=2000.0, size=(2, 5, 3))
    q = pose.screen_to_camera(p)
    assert q.shape == (2, 5, 3)
    np.testing.assert_allclose(pose.camera_to_screen(q), p, atol=ROUNDING_MM)
    np.testing.assert_allclose(np.linalg.norm(q[0, 0] - q[1, 4]), np.linalg.norm(p[0, 0] - p[1, 4]), rtol=1e-12)
    assert np.isnan(pose.screen_to_camera([np.nan, 0, 0])).all()
    with pytest.raises(OptionError, match="points in millimetres"):
        pose.screen_to_camera([1.0, 2.0])


@real
def test_dot_locations_are_85_by_85_at_a_4_cm_pitch():
    dots = read_dot_locations(DOTS)
    assert dots.xyz_mm.shape == (85, 85, 3)
    np.testing.assert_array_equal(dots.x_index, np.arange(-42, 43))
    np.testing.assert_array_equal(dots.y_index, np.arange(-42, 43))
    # SOURCE.md: pitch about 4 cm, dots within about +-1.7 m
    for axis in (0, 1):
        step = np.linalg.norm(np.diff(dots.xyz_mm, axis=axis), axis=-1)
        assert 35 < np.nanmedian(step) < 45
    assert 1500 < np.nanmax(np.abs(dots.xyz_mm[..., :2])) < 1900
    # dots the calibration did not locate are NaN in all three coordinates, and only those
    assert dots.valid.any() and not dots.valid.all()
    assert np.isnan(dots.xyz_mm[~dots.valid]).all() and np.isfinite(dots.xyz_mm[dots.valid]).all()


@real
def test_dot_position_by_index_with_nan_outside():
    dots = read_dot_locations(DOTS)
    np.testing.assert_array_equal(dots.position_mm(0, 0), dots.xyz_mm[42, 42])
    np.testing.assert_array_equal(dots.position_mm(3, -5), dots.xyz_mm[42 - 5, 42 + 3])
    got = dots.position_mm(np.array([[0, 43], [-43, 0]]), np.array([[0, 0], [0, 0.5]]))
    assert got.shape == (2, 2, 3)
    assert np.isfinite(got[0, 0]).all() and np.isnan(got[0, 1]).all() and np.isnan(got[1]).all()


@real
def test_fixed_measurement_reads_the_documented_frame():
    m = read_fixed_measurement(FIXED)
    assert m.image.shape == (1236, 1626) and m.image.dtype == np.uint8
    assert m.image.shape[::-1] == read_camera(CAMERA).image_size
    np.testing.assert_allclose(m.origin_px, [960.59, 796.39], atol=0.005)
    assert m.dist_optic_screen_mm == pytest.approx(10008.0, abs=ROUNDING_MM)
    np.testing.assert_array_equal(m.measure_point_mm, [0, 0, 0])
    assert m.name == "NSTTF Facet" and m.date.startswith("2024-04-01")


@real
def test_fringe_measurement_reads_y_then_x_sets():
    m = read_fringe_measurement(FRINGE)
    assert m.fringe_images.shape == (154, 203, 32) and m.fringe_images.dtype == np.uint8
    np.testing.assert_array_equal(m.periods_x, [0.9, 3.9, 15.9, 63.9])
    np.testing.assert_array_equal(m.periods_y, [0.9, 3.9, 15.9, 63.9])
    assert m.fringe_images_y.shape[2] == 16 and m.fringe_images_x.shape[2] == 16
    assert m.mask_images.shape == (154, 203, 2)
    assert m.mask_images[..., 1].mean() > 10 * m.mask_images[..., 0].mean()  # (dark, bright)
    assert m.dist_optic_screen_mm == pytest.approx(10232.0, abs=ROUNDING_MM)
    assert m.fringe_images.shape[1::-1] == read_camera(FRINGE_CAMERA).image_size


@real
def test_image_calibration_is_a_rising_response():
    cal = read_image_calibration(CALIBRATION)
    assert cal.kind == "ImageCalibrationScaling"
    assert cal.camera_values.shape == cal.display_values.shape == (27,)
    assert cal.display_values[0] == 0 and cal.display_values[-1] == 255
    assert (np.diff(cal.camera_values) > 0).all() and (np.diff(cal.display_values) > 0).all()


@real
def test_display_shape_interpolates_its_grid():
    d = read_display_shape(DISPLAY)
    assert d.model == "distorted2D" and d.xy_screen_fraction.shape == d.xy_screen_coords_mm.shape == (121, 2)
    at_nodes = d.fraction_to_screen_mm(d.xy_screen_fraction)
    np.testing.assert_allclose(at_nodes[:, :2], d.xy_screen_coords_mm, atol=1e-6)
    np.testing.assert_array_equal(at_nodes[:, 2], 0)
    assert np.isnan(d.fraction_to_screen_mm([[2.0, 2.0]])).all()
    same = read_display_shape(FRINGE_CALC)
    np.testing.assert_array_equal(same.xy_screen_coords_mm, d.xy_screen_coords_mm)


@real
def test_facet_json_and_the_calculations_facet_agree():
    facet = read_facet_definition(FACET_JSON)
    # SOURCE.md: a 1.212 m square, corners (+-0.606, +-0.606, 0), centroid at the origin
    np.testing.assert_allclose(np.abs(facet.corners_mm), [[606, 606, 0]] * 4, atol=ROUNDING_MM)
    np.testing.assert_array_equal(facet.centroid_mm, [0, 0, 0])
    for path in (FIXED_CALC, FRINGE_CALC):
        (stored,) = read_calculation(path).facet_definitions
        np.testing.assert_allclose(stored.corners_mm, facet.corners_mm, atol=ROUNDING_MM)
        again = read_facet_definition(path, prefix="DataSofastInput/optic_definition/facet_000")
        np.testing.assert_array_equal(again.corners_mm, stored.corners_mm)


@real
def test_fixed_calculation_holds_3782_slopes_on_the_facet():
    calc = read_calculation(FIXED_CALC)
    assert calc.kind == "fixed" and len(calc.facets) == 1
    facet = calc.facets[0]
    assert facet.slopes.shape == (3782, 2) and facet.surface_points_mm.shape == (3782, 3)
    # the points lie on the 1212 mm square facet, a few mm from its plane (f = 150 m start, sag < 2 mm)
    assert np.abs(facet.surface_points_mm[:, :2]).max() < 606 + 5
    assert np.abs(facet.surface_points_mm[:, 2]).max() < 5
    assert np.abs(facet.slopes).max() < 0.05  # a near-flat mirror: slopes of mrad, not radians
    assert calc.params["optic_definition/facet_000/ParamsSurface/surface_type"] == "parabolic"
    assert calc.params["optic_definition/facet_000/ParamsSurface/initial_focal_lengths_xy"] == (150.0, 150.0)
    assert calc.params["ParamsSofastFixed/ParamsMaskCalculation/keep_largest_area"] is False


@real
def test_fringe_calculation_holds_7105_slopes_one_per_processed_pixel():
    calc = read_calculation(FRINGE_CALC)
    assert calc.kind == "fringe"
    facet = calc.facets[0]
    assert facet.slopes.shape == (7105, 2) and facet.surface_points_mm.shape == (7105, 3)
    assert facet.extras["mask_processed"].dtype == bool and facet.extras["mask_processed"].sum() == 7105
    frac = facet.extras["v_screen_points_fractional_screens"]
    assert frac.shape == (7105, 2) and ((frac > 0) & (frac < 1)).all()
    t = facet.extras["trans_alignment_mm"]
    np.testing.assert_allclose(t[:3, :3] @ t[:3, :3].T, np.eye(3), atol=1e-9)  # a rotation
    assert "v_cam_optic_cam_exp_mm" in calc.general and calc.general["mask_raw"].shape == (154, 203)


@real
def test_fringe_result_follows_the_display_and_pose_conventions():
    """SOFAST's stored screen points, rebuilt from the display shape and both poses read here: the
    fractional screen position through the display model, screen -> camera with r_cam_screen,
    camera -> facet with r_cam_optic. Float64 rounding of 10 m lengths is ~1e-12 mm."""
    extras = read_calculation(FRINGE_CALC).facets[0].extras
    display = read_display_shape(FRINGE_CALC)
    screen = display.fraction_to_screen_mm(extras["v_screen_points_fractional_screens"])
    np.testing.assert_allclose(screen, extras["v_screen_points_screen_mm"], atol=ROUNDING_MM)
    pose = read_spatial_orientation(FRINGE_CALC, prefix=FACET_POSE)
    from scipy.spatial.transform import Rotation

    camera = pose.screen_to_camera(screen)
    facet = Rotation.from_rotvec(np.array(pose.r_cam_optic)).apply(camera - pose.v_cam_optic_cam_mm)
    np.testing.assert_allclose(facet, extras["v_screen_points_facet_mm"], atol=ROUNDING_MM)
    # SOFAST scales the facet pose so the measure point (the facet origin) is dist_optic_screen from the
    # screen origin; its own error for that is 1.8e-15 m
    distance = np.linalg.norm(pose.v_cam_screen_cam_mm - pose.v_cam_optic_cam_mm)
    assert distance == pytest.approx(read_fringe_measurement(FRINGE).dist_optic_screen_mm, abs=1e-6)
    np.testing.assert_array_equal(pose.r_cam_screen, read_spatial_orientation(POSE).r_cam_screen)


@real
def test_sofast_folder_finds_every_file():
    folder = read_sofast_folder(SOFAST)
    assert folder.camera == CAMERA and folder.spatial_orientation == POSE and folder.facet_definition == FACET_JSON
    assert folder.dot_locations == DOTS and folder.fixed_measurement == FIXED and folder.fixed_calculation == FIXED_CALC
    assert folder.fringe_measurement == FRINGE and folder.fringe_camera == FRINGE_CAMERA
    assert folder.image_calibration == CALIBRATION and folder.display_shape == DISPLAY
    assert folder.fringe_calculation == FRINGE_CALC and folder.ensemble_definition is None


@real
def test_flat_sofast_folder_tells_measurements_apart_by_content(tmp_path):
    for path in (CAMERA, POSE, FACET_JSON, FRINGE, DISPLAY, FRINGE_CALC):
        (tmp_path / path.name).symlink_to(path)
    folder = read_sofast_folder(tmp_path)
    assert folder.fringe_measurement == tmp_path / "measurement_facet.h5" and folder.fixed_measurement is None
    assert folder.camera == tmp_path / "camera_sofast.h5" and folder.display_shape == tmp_path / DISPLAY.name
    assert folder.dot_locations is None and folder.fringe_camera is None
    (tmp_path / "Facet_other.json").symlink_to(FACET_JSON)
    folder = read_sofast_folder(tmp_path)  # two facet definitions: which is meant is for the caller to say
    assert folder.facet_definition is None
    assert folder.ambiguous["facet_definition"] == (tmp_path / "Facet_NSTTF.json", tmp_path / "Facet_other.json")


# --------------------------------------------------------------------------------------- small files

def test_camera_shapes_as_openCSP_writes_them(tmp_path):
    a = read_camera(write_h5(tmp_path / "a.h5", camera_datasets()))
    b = read_camera(write_h5(tmp_path / "b.h5", camera_datasets(**{
        "Camera/distortion_coef": np.array([0.1, -0.2, 0.001, 0.002]),
        "Camera/image_shape_xy": np.array([640, 480]), "Camera/name": "test camera"})))
    for cam in (a, b):
        assert cam.image_size == (640, 480) and cam.name == "test camera"
        np.testing.assert_array_equal(cam.distortion, [0.1, -0.2, 0.001, 0.002, 0.0])


def test_not_hdf5(tmp_path):
    path = tmp_path / "camera.h5"
    path.write_bytes(np.random.default_rng(0).bytes(4096))
    raises("is not an HDF5 file", None, read_camera, path)
    raises("is not an HDF5 file", None, read_calculation, path)


def test_truncated_hdf5(tmp_path):
    whole = write_h5(tmp_path / "whole.h5", camera_datasets()).read_bytes()
    path = tmp_path / "cut.h5"
    path.write_bytes(whole[: len(whole) // 2])
    with pytest.raises(SofastError, match=r"cut\.h5: .*HDF5"):
        read_camera(path)


def test_not_a_file(tmp_path):
    raises("no such file", None, read_camera, tmp_path / "absent.h5")
    raises("not a file: is a folder", None, read_fixed_measurement, tmp_path)


def test_another_kind_of_file(tmp_path):
    path = write_h5(tmp_path / "camera.h5", camera_datasets())
    raises(r"is not a SOFAST fixed-pattern measurement \(no MeasurementSofastFixed group\)",
           "MeasurementSofastFixed", read_fixed_measurement, path)
    raises(r"no DataSofastCalculation group", "DataSofastCalculation", read_calculation, path)
    raises(r"no DotLocationsFixedPattern group", "DotLocationsFixedPattern", read_dot_locations, path)


def test_missing_dataset(tmp_path):
    path = write_h5(tmp_path / "m.h5", fixed_datasets(**{"MeasurementSofastFixed/origin": None}))
    raises("missing dataset", "MeasurementSofastFixed/origin", read_fixed_measurement, path)
    path = write_h5(tmp_path / "c.h5", camera_datasets(**{"Camera/intrinsic_mat": None}))
    raises("missing dataset", "Camera/intrinsic_mat", read_camera, path)


def test_name_and_date_may_be_absent(tmp_path):
    path = write_h5(tmp_path / "m.h5", fixed_datasets(**{"MeasurementSofastFixed/name": None,
                                                          "MeasurementSofastFixed/date": None}))
    m = read_fixed_measurement(path)
    assert m.name == m.date == "" and m.dist_optic_screen_mm == 10000.0


def test_wrong_shape_dtype_and_values(tmp_path):
    cases = [
        ("Camera/intrinsic_mat", np.eye(4), r"must have shape \(3, 3\), got \(4, 4\)"),
        ("Camera/intrinsic_mat", np.array([[1000.0, 0, 320], [0, np.inf, 240], [0, 0, 1]]), "NaN or infinite"),
        ("Camera/intrinsic_mat", np.array([[-5.0, 0, 320], [0, 1000, 240], [0, 0, 1]]), "focal lengths"),
        ("Camera/intrinsic_mat", np.array([[1000.0, 0, 320], [0, 1000, 240], [1, 0, 1]]), r"\[0, fy, cy\]"),
        ("Camera/distortion_coef", np.zeros((2, 5)), "must hold 4 or 5 numbers"),
        ("Camera/image_shape_xy", np.array([640.5, 480]), "must hold integers, got 640.5"),
        ("Camera/image_shape_xy", np.array([640, 0]), "must be > 0 px"),
        ("Camera/intrinsic_mat", np.array([b"abc"] * 9).reshape(3, 3), "must hold numbers, got text"),
        ("Camera/name", 3.0, "must hold text"),
    ]
    for i, (name, value, match) in enumerate(cases):
        path = write_h5(tmp_path / f"c{i}.h5", camera_datasets(**{name: value}))
        raises(match, name, read_camera, path)


def test_empty_or_non_numeric_image(tmp_path):
    key = "MeasurementSofastFixed/image"
    raises("is empty", key, read_fixed_measurement, write_h5(tmp_path / "a.h5", fixed_datasets(**{
        key: np.zeros((0, 5), np.uint8)})))
    raises("must hold pixel values", key, read_fixed_measurement, write_h5(tmp_path / "b.h5", fixed_datasets(**{
        key: np.array([b"x"] * 4)})))
    raises("must be a 2-D image", key, read_fixed_measurement, write_h5(tmp_path / "c.h5", fixed_datasets(**{
        key: np.zeros((2, 3, 4), np.uint8)})))
    raises("distance > 0", "MeasurementSofastFixed/dist_optic_screen", read_fixed_measurement,
           write_h5(tmp_path / "d.h5", fixed_datasets(**{"MeasurementSofastFixed/dist_optic_screen": -1.0})))


def test_a_dataset_too_large_is_refused_before_it_is_read(tmp_path):
    path = tmp_path / "big.h5"
    with h5py.File(path, "w") as f:
        for name, value in fixed_datasets(**{"MeasurementSofastFixed/image": None}).items():
            f[name] = value
        f.create_dataset("MeasurementSofastFixed/image", shape=(16385, 16385), dtype=np.uint8)  # never written
    assert path.stat().st_size < 2**20
    raises(f"holds {16385 ** 2} elements; a SOFAST dataset is read up to {2 ** 28}", "MeasurementSofastFixed/image",
           read_fixed_measurement, path)


def test_dot_table_of_wrong_shape(tmp_path):
    d = dots_datasets()
    d["DotLocationsFixedPattern/xyz_dot_loc"] = d["DotLocationsFixedPattern/xyz_dot_loc"][:, :2]
    raises(r"must have shape \(len\(y_dot_index\), len\(x_dot_index\), 3\) = \(4, 3, 3\), got \(4, 2, 3\)",
           "DotLocationsFixedPattern/xyz_dot_loc", read_dot_locations, write_h5(tmp_path / "d.h5", d))


def test_dot_table_with_nan_or_inf(tmp_path):
    d = dots_datasets()
    xyz = d["DotLocationsFixedPattern/xyz_dot_loc"].copy()
    xyz[2, 0, 1] = np.nan  # one coordinate of dot (x -1, y 1)
    d["DotLocationsFixedPattern/xyz_dot_loc"] = xyz
    raises(r"dot \(x -1, y 1\) has coordinates", "DotLocationsFixedPattern/xyz_dot_loc", read_dot_locations,
           write_h5(tmp_path / "a.h5", d))
    xyz[2, 0, 1] = np.inf
    raises(r"dot \(x -1, y 1\)", "DotLocationsFixedPattern/xyz_dot_loc", read_dot_locations,
           write_h5(tmp_path / "b.h5", d))
    xyz[2, 0] = np.nan  # the whole dot: not located, which is allowed
    dots = read_dot_locations(write_h5(tmp_path / "c.h5", d))
    assert not dots.valid[2, 0] and dots.valid.sum() == 11
    assert np.isnan(dots.position_mm(-1, 1)).all()
    np.testing.assert_allclose(dots.position_mm(1, 2), [40, 80, 0])
    d["DotLocationsFixedPattern/xyz_dot_loc"] = np.full((4, 3, 3), np.nan)
    raises("locates no dot", "DotLocationsFixedPattern/xyz_dot_loc", read_dot_locations,
           write_h5(tmp_path / "e.h5", d))


def test_dot_indices_must_be_consecutive(tmp_path):
    raises("must be consecutive increasing integers, got 0 then 2", "DotLocationsFixedPattern/x_dot_index",
           read_dot_locations, write_h5(tmp_path / "d.h5", dots_datasets(x=(-1, 0, 2))))


def fringe_datasets(n_frames=32, **override):
    d = {"MeasurementSofastFringe/fringe_images": np.zeros((6, 5, n_frames), np.uint8),
         "MeasurementSofastFringe/mask_images": np.zeros((6, 5, 2), np.uint8),
         "MeasurementSofastFringe/fringe_periods_x": np.array([0.9, 3.9, 15.9, 63.9]),
         "MeasurementSofastFringe/fringe_periods_y": np.array([0.9, 3.9, 15.9, 63.9]),
         "MeasurementSofastFringe/dist_optic_screen": 10.0,
         "MeasurementSofastFringe/v_measure_point_facet": np.zeros(3)}
    d.update(override)
    return {k: v for k, v in d.items() if v is not None}


def test_fringe_frame_count_and_masks(tmp_path):
    assert read_fringe_measurement(write_h5(tmp_path / "ok.h5", fringe_datasets())).fringe_images.shape[2] == 32
    raises(r"must hold 4 x \(4 y \+ 4 x periods\) = 32 frames, got 31", "MeasurementSofastFringe/fringe_images",
           read_fringe_measurement, write_h5(tmp_path / "a.h5", fringe_datasets(31)))
    raises("dark, bright", "MeasurementSofastFringe/mask_images", read_fringe_measurement,
           write_h5(tmp_path / "b.h5", fringe_datasets(**{
               "MeasurementSofastFringe/mask_images": np.zeros((6, 5, 3), np.uint8)})))
    raises("periods > 0", "MeasurementSofastFringe/fringe_periods_y", read_fringe_measurement,
           write_h5(tmp_path / "c.h5", fringe_datasets(**{
               "MeasurementSofastFringe/fringe_periods_y": np.array([0.9, 0.0, 15.9, 63.9])})))


def test_display_models(tmp_path):
    rect = read_display_shape(write_h5(tmp_path / "r.h5", {
        "DisplayShape/screen_model": "rectangular2D", "DisplayShape/name": "lcd",
        "DisplayShape/screen_x": 1.2, "DisplayShape/screen_y": 0.8}))
    np.testing.assert_allclose(rect.screen_size_mm, [1200, 800])
    np.testing.assert_allclose(rect.fraction_to_screen_mm([[0.5, 0.5], [1.0, 0.0]]), [[0, 0, 0], [600, -400, 0]])
    frac = np.array([[0.0, 1, 0, 1], [0, 0, 1, 1]])
    d3 = read_display_shape(write_h5(tmp_path / "d3.h5", {
        "DisplayShape/screen_model": "distorted3D", "DisplayShape/xy_screen_fraction": frac,
        "DisplayShape/xyz_screen_coords": np.array([[-1.0, 1, -1, 1], [-1, -1, 1, 1], [0, 0.1, 0.1, 0.2]])}))
    np.testing.assert_allclose(d3.fraction_to_screen_mm([0.5, 0.5]), [0, 0, 100], atol=1e-9)
    raises(r"unknown screen model 'distorted2d' \(did you mean 'distorted2D'\?\)", "DisplayShape/screen_model",
           read_display_shape, write_h5(tmp_path / "u.h5", {"DisplayShape/screen_model": "distorted2d"}))
    raises(r"one point per screen fraction \(4\), got 3", "DisplayShape/xy_screen_coords", read_display_shape,
           write_h5(tmp_path / "n.h5", {"DisplayShape/screen_model": "distorted2D",
                                        "DisplayShape/xy_screen_fraction": frac,
                                        "DisplayShape/xy_screen_coords": np.zeros((2, 3))}))


def test_image_calibration_lengths(tmp_path):
    raises(r"one value per camera value \(3\), got 2", "ImageCalibration/display_values", read_image_calibration,
           write_h5(tmp_path / "c.h5", {"ImageCalibration/calibration_type": "ImageCalibrationGlobal",
                                        "ImageCalibration/camera_values": np.array([1.0, 2, 3]),
                                        "ImageCalibration/display_values": np.array([0.0, 255])}))


def test_calculation_without_facets(tmp_path):
    path = write_h5(tmp_path / "c.h5", {"DataSofastCalculation/general/x": 1.0})
    raises("missing group", "DataSofastCalculation/facet", read_calculation, path)
    path = write_h5(tmp_path / "d.h5", {"DataSofastCalculation/facet/other": 1.0})
    raises("holds no facet result", "DataSofastCalculation/facet", read_calculation, path)


def test_calculation_of_two_facets_in_order(tmp_path):
    d = {}
    for n in (1, 0):  # written out of order
        g = f"DataSofastCalculation/facet/facet_00{n}/SlopeSolverData/"
        d[g + "slopes_facet_xy"] = np.full((2, 3 + n), 0.001 * (n + 1))
        d[g + "v_surf_points_facet"] = np.full((3, 3 + n), 0.5 * n)
    calc = read_calculation(write_h5(tmp_path / "c.h5", d))
    assert [f.index for f in calc.facets] == [0, 1] and calc.facets[1].slopes.shape == (4, 2)
    np.testing.assert_array_equal(calc.facets[1].surface_points_mm, np.full((4, 3), 500.0))
    assert calc.params == {} and calc.facet_definitions == () and calc.kind is None
    d["DataSofastCalculation/facet/facet_001/SlopeSolverData/v_surf_points_facet"] = np.zeros((3, 5))
    raises(r"must have shape \(3, 4\), got \(3, 5\)",
           "DataSofastCalculation/facet/facet_001/SlopeSolverData/v_surf_points_facet",
           read_calculation, write_h5(tmp_path / "bad.h5", d))


def test_without_h5py(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "h5py", None)
    raises(r"reading SOFAST files needs h5py: pip install 'shinysim\[sofast\]'", None, read_camera,
           tmp_path / "camera.h5")


# ------------------------------------------------------------------------------------------------ JSON

FACET = {"v_facet_corners": {"x": [0.5, -0.5, -0.5, 0.5], "y": [-0.5, -0.5, 0.5, 0.5], "z": [0, 0, 0, 0]},
         "v_centroid_facet": {"x": [0.0], "y": [0.0], "z": [0.01]}}
ENSEMBLE = {"v_facet_locations": {"x": [-0.32, 0.32], "y": [0.0, 0.0], "z": [0.0, 0.01]},
            "r_facet_ensemble": {"0": [0.0, 0.01, 0.0], "1": [0.0, -0.01, 0.0]},
            "ensemble_perimeter": {"facet_indices": [1, 0, 0, 1], "corner_indices": [0, 1, 2, 3]},
            "v_centroid_ensemble": {"x": [0.0], "y": [0.0], "z": [0.0]}}


def write_json(path: Path, doc) -> Path:
    path.write_text(json.dumps(doc) if not isinstance(doc, str) else doc)
    return path


def edited(doc, edit):
    doc = json.loads(json.dumps(doc))
    edit(doc)
    return doc


def test_facet_json_in_millimetres(tmp_path):
    facet = read_facet_definition(write_json(tmp_path / "facet.json", FACET))
    np.testing.assert_allclose(facet.corners_mm, [[500, -500, 0], [-500, -500, 0], [-500, 500, 0], [500, 500, 0]])
    np.testing.assert_allclose(facet.centroid_mm, [0, 0, 10])


def test_facet_json_faults(tmp_path):
    path = tmp_path / "facet.json"
    raises("missing required field", "v_facet_corners", read_facet_definition, write_json(
        path, edited(FACET, lambda d: d["v_facet_corners"].pop("z"))))
    raises("must hold 4 numbers like x, got 3", "v_facet_corners.y", read_facet_definition, write_json(
        path, edited(FACET, lambda d: d["v_facet_corners"]["y"].pop())))
    raises(r"must hold 1 point \(x, y, z lists of 1\), got 2", "v_centroid_facet.x", read_facet_definition,
           write_json(path, edited(FACET, lambda d: d["v_centroid_facet"].update(x=[0, 0], y=[0, 0], z=[0, 0]))))
    raises("must be finite numbers, got nan", "v_facet_corners.x[1]", read_facet_definition, write_json(
        path, json.dumps(FACET).replace("-0.5, -0.5, 0.5", "NaN, -0.5, 0.5", 1)))
    raises("must be a list", "v_facet_corners.x", read_facet_definition, write_json(
        path, edited(FACET, lambda d: d["v_facet_corners"].update(x=0.5))))
    raises(r"unknown field 'v_centroid' \(did you mean 'v_centroid_facet'\?\)", "v_centroid", read_facet_definition,
           write_json(path, edited(FACET, lambda d: d.update(v_centroid=d.pop("v_centroid_facet")))))
    raises("not valid JSON", None, read_facet_definition, write_json(path, "{"))


def test_ensemble_json_in_millimetres(tmp_path):
    ens = read_ensemble_definition(write_json(tmp_path / "Ensemble_test.json", ENSEMBLE))
    np.testing.assert_allclose(ens.facet_positions_mm, [[-320, 0, 0], [320, 0, 10]])
    np.testing.assert_allclose(ens.facet_rotations, [[0, 0.01, 0], [0, -0.01, 0]])
    np.testing.assert_array_equal(ens.perimeter, [[1, 0], [0, 1], [0, 2], [1, 3]])
    np.testing.assert_array_equal(ens.centroid_mm, [0, 0, 0])
    # the same ensemble in the HDF5 form OpenCSP writes (locations (3, n), rotations (n, 3))
    h5 = write_h5(tmp_path / "ensemble.h5", {
        "DefinitionEnsemble/v_facet_locations": np.array([[-0.32, 0.32], [0, 0], [0, 0.01]]),
        "DefinitionEnsemble/r_facet_ensemble": np.array([[0, 0.01, 0], [0, -0.01, 0]]),
        "DefinitionEnsemble/ensemble_perimeter": ens.perimeter,
        "DefinitionEnsemble/v_centroid_ensemble": np.zeros((3, 1))})
    again = read_ensemble_definition(h5)
    np.testing.assert_allclose(again.facet_positions_mm, ens.facet_positions_mm)
    np.testing.assert_array_equal(again.perimeter, ens.perimeter)


def test_ensemble_json_faults(tmp_path):
    path = tmp_path / "Ensemble_test.json"
    raises(r"one rotation per facet location \(2\), got 1", "r_facet_ensemble", read_ensemble_definition,
           write_json(path, edited(ENSEMBLE, lambda d: d["r_facet_ensemble"].pop("1"))))
    renumbered = edited(ENSEMBLE, lambda d: d["r_facet_ensemble"].update({"2": d["r_facet_ensemble"].pop("1")}))
    raises("must be keyed '0' to '1'", "r_facet_ensemble", read_ensemble_definition, write_json(path, renumbered))
    raises("must be 3 finite numbers", "r_facet_ensemble.0", read_ensemble_definition,
           write_json(path, edited(ENSEMBLE, lambda d: d["r_facet_ensemble"].update({"0": [0, 0]}))))
    raises(r"entry 0 \(facet 2, corner 0\) names no corner", "ensemble_perimeter", read_ensemble_definition,
           write_json(path, edited(ENSEMBLE, lambda d: d["ensemble_perimeter"]["facet_indices"].__setitem__(0, 2))))
    raises("one corner per facet index", "ensemble_perimeter.corner_indices", read_ensemble_definition,
           write_json(path, edited(ENSEMBLE, lambda d: d["ensemble_perimeter"]["corner_indices"].pop())))
    raises("missing required field", "v_centroid_ensemble", read_ensemble_definition,
           write_json(path, edited(ENSEMBLE, lambda d: d.pop("v_centroid_ensemble"))))


def test_folder_faults(tmp_path):
    raises("no such folder", None, read_sofast_folder, tmp_path / "absent")
    raises("not a folder", None, read_sofast_folder, write_json(tmp_path / "x.json", {}))
    empty = tmp_path / "empty"
    empty.mkdir()
    raises("holds no SOFAST file", None, read_sofast_folder, empty)


def test_every_public_name_is_exported():
    assert set(sofast.__all__) <= set(dir(sofast))
