"""Bad input to ``shinysim calibrate camera|sources``: one named error line, no traceback, nothing written.

The inputs are drawn with numpy, never rendered: the nominal rig is
``shiny_1988(resolution=128)``; a plate image is anti-aliased disks of the
hole diameter (4 x 4 samples per pixel) at the camera's image of each hole;
a sphere scan is one small Gaussian spot per frame at the exact mirror
highlight of its source. Each command has a positive control (a valid input
that succeeds and writes a rig ``load_rig`` reads, its camera or sources
changed), so that every refusal below is known to come from the one thing
each case breaks. Every refusal is checked as ``tests/test_cli_bad_input.py``
checks the other commands: exit status 1, one ``shinysim calibrate: error:``
line naming the file, field or option, no traceback, and the working folder
(inputs and output location) unchanged: no rig written, none replaced.
"""

from __future__ import annotations

import json
import os
import shutil

import numpy as np
import pytest
from conftest import draw_disks
from test_cli_bad_input import assert_refused, assert_unchanged, run_cli, snapshot

from shinysim.calibrate.camera import ray_errors
from shinysim.conventions import angle_between, normalize
from shinysim.io import Stack, save_frame, save_stack
from shinysim.objects.plate import PlatePlacement, dot_grid, shiny_plate
from shinysim.io import load_rig
from shinysim.rig import Camera, shiny_1988
from shinysim.theory.mirror import mirror_sphere_highlight

R_SPHERE = 0.79375  # the paper's 1/16 in calibration sphere, mm
NOMINAL = shiny_1988(resolution=128)
CAM = NOMINAL.camera
#: The camera the plate images were "taken" with: moved 20 um sideways, its principal point off by (0.5, -2) px.
TRUE_CAM = Camera(CAM.projection, CAM.width, CAM.height, CAM.position + [0.02, -0.01, 0.0],
                  CAM.target + [0.02, -0.01, 0.0], CAM.up, CAM.field_width, CAM.name, principal_point=(64.5, 62.0))
#: The sources the sphere scans were "taken" with: the nominal ones moved 1 mm (about 1.3 degrees).
TRUE_SOURCES = NOMINAL.source_positions + np.array([0.0, 1.0, 0.0])
#: Sphere centres of the scans (mm): one in a folder (stack.exr), one as one frame file per source.
CENTRES = [(0.0, 0.0, 0.0), (0.0, 0.3, 0.2)]
SEVEN = shiny_plate().to_dict()


# -- drawing, without a renderer --------------------------------------------------------------------


def draw_plate(plate, placement, camera=CAM, keep=None, supersample=4):
    """A backlit plate image: disks of the hole diameter at each hole's image (``keep``: only those holes)."""
    image = np.zeros(camera.shape)
    world = placement.world_holes(plate)
    if keep is not None:
        world = world[keep]
    draw_disks(image, camera, world, plate.hole_diameter, supersample=supersample)
    return image


def draw_scan(centre, sources=TRUE_SOURCES, camera=CAM, sigma=1.0):
    """One frame per source: a Gaussian spot of ``sigma`` px at the exact highlight on the mirror sphere."""
    point, _ = mirror_sphere_highlight(sources, center=centre, radius=R_SPHERE, camera_position=camera.position)
    rows, cols = camera.project(point)
    r, c = np.indices(camera.shape)
    return np.stack([np.exp(-((r - r0) ** 2 + (c - c0) ** 2) / (2 * sigma**2)) for r0, c0 in zip(rows, cols)])


def write_json(path, doc):
    path.write_text(doc if isinstance(doc, str) else json.dumps(doc))
    return path


@pytest.fixture(scope="module")
def template(tmp_path_factory):
    """The nominal rig, plate images and sphere scans every test copies."""
    root = tmp_path_factory.mktemp("calibration")
    NOMINAL.save(root / "nominal.json")
    grid, seven = dot_grid(), shiny_plate()
    images = {
        "grid_z0.exr": draw_plate(grid, PlatePlacement(), TRUE_CAM),
        "grid_z1.exr": draw_plate(grid, PlatePlacement((0.0, 0.0, 1.0)), TRUE_CAM),
        "grid_z0_shifted.exr": draw_plate(grid, PlatePlacement((0.05, 0.03, 0.0)), TRUE_CAM),
        "seven_z0.exr": draw_plate(seven, PlatePlacement()),
        "seven_z1.exr": draw_plate(seven, PlatePlacement((0.0, 0.0, 1.0))),
        "six_holes.exr": draw_plate(seven, PlatePlacement(), keep=list(range(6))),
        "dark.exr": np.zeros(CAM.shape),
        "small.exr": draw_plate(seven, PlatePlacement())[32:96, 32:96],
    }
    for name, image in images.items():
        save_frame(image, root / name)
    (root / "sphere_0").mkdir()
    save_stack(Stack(draw_scan(CENTRES[0]), NOMINAL, 0, {}), root / "sphere_0" / "stack.exr")
    frames = draw_scan(CENTRES[1])
    (root / "sphere_1").mkdir()
    for k, frame in enumerate(frames):
        save_frame(frame, root / "sphere_1" / f"f{k:02d}.exr")
    (root / "dark").mkdir()
    save_stack(Stack(np.zeros((NOMINAL.n_sources,) + CAM.shape), NOMINAL, 0, {}), root / "dark" / "stack.exr")
    three = shiny_1988(resolution=128, n_sources=3)
    (root / "three").mkdir()
    save_stack(Stack(draw_scan(CENTRES[0], three.source_positions), three, 0, {}), root / "three" / "stack.exr")
    return root


@pytest.fixture
def work(template, tmp_path):
    """A fresh copy of the template, with the valid placements.json and spheres.json beside its files."""
    root = tmp_path / "work"
    shutil.copytree(template, root)
    write_json(root / "placements.json", {
        "plate": dot_grid().to_dict(),
        "images": [{"file": "grid_z0.exr"}, {"file": "grid_z1.exr", "placement": {"offset_mm": [0, 0, 1]}}],
    })
    write_json(root / "spheres.json", {
        "radius_mm": R_SPHERE,
        "scans": [{"folder": "sphere_0", "center_mm": list(CENTRES[0])},
                  {"frames": [f"sphere_1/f{k:02d}.exr" for k in range(NOMINAL.n_sources)],
                   "center_mm": list(CENTRES[1])}],
    })
    return root


def camera_cli(capsys, work, plates="placements.json", *more, out="calibrated.json"):
    return run_cli(capsys, "calibrate", "camera", "--rig", work / "nominal.json", "--plates", work / plates,
                   "--out", work / out, *more)


def sources_cli(capsys, work, spheres="spheres.json", *more, out="calibrated.json"):
    return run_cli(capsys, "calibrate", "sources", "--rig", work / "nominal.json", "--spheres", work / spheres,
                   "--out", work / out, *more)


def refused(result, work, before, *names):
    """One error line naming everything in ``names``; nothing under ``work`` changed."""
    line = assert_refused(result, "calibrate", *names)
    assert_unchanged(work, before)
    return line


# -- positive controls ------------------------------------------------------------------------------


def test_camera_control_writes_a_calibrated_camera(work, capsys):
    """Two heights of the dot grid, every parameter group (the default for several images): the rays found."""
    code, out, err = camera_cli(capsys, work)
    assert code == 0, err
    assert "camera from 2 plate image(s), 50 holes" in out and "principal_point, distortion" in out
    rig = load_rig(work / "calibrated.json")
    assert rig.camera != CAM and rig.source_positions.tolist() == NOMINAL.source_positions.tolist()
    assert rig.metadata["calibration"]["camera"]["n_placements"] == 2
    grid = np.linspace(0.0, 127.0, 9)
    nominal = ray_errors(CAM, TRUE_CAM, grid, grid, heights=(0.0, 1.0))["position_max_um"]  # 44 um
    found = ray_errors(rig.camera, TRUE_CAM, grid, grid, heights=(0.0, 1.0))["position_max_um"]  # 1.2 um measured
    assert nominal > 40.0 and found < 3.0, (nominal, found)


def test_sources_control_writes_calibrated_sources(work, capsys):
    """Two sphere positions (a scan folder and a list of frames): every fiber placed in 3-D, directions found."""
    code, out, err = sources_cli(capsys, work, "spheres.json", "--require-positions")
    assert code == 0, err
    assert "sources from 2 sphere position(s): 21 of 21 placed in 3-D" in out
    rig = load_rig(work / "calibrated.json")
    assert rig.camera == CAM and "sources" in rig.metadata["calibration"]
    truth = normalize(TRUE_SOURCES)
    before = np.degrees(angle_between(normalize(NOMINAL.source_positions), truth)).max()  # 1.3 degrees
    after = np.degrees(angle_between(normalize(rig.source_positions), truth)).max()
    assert before > 1.0 and after < 0.2 * before, (before, after)


def test_overwrite_replaces_the_output(work, capsys):
    (work / "calibrated.json").write_text("old\n")
    code, _, err = sources_cli(capsys, work, "spheres.json", "--overwrite")
    assert code == 0, err
    assert load_rig(work / "calibrated.json").metadata["calibration"]["sources"]


# -- camera: the plate images -----------------------------------------------------------------------


def plates(work, images, plate=None, name="bad_plates.json"):
    doc = {"images": images} if plate is None else {"plate": plate, "images": images}
    return write_json(work / name, doc).name


def test_no_holes_found(work, capsys):
    doc = plates(work, [{"file": "dark.exr"}], SEVEN)
    before = snapshot(work)
    refused(camera_cli(capsys, work, doc), work, before, r"bad_plates\.json: images\[0\] \(dark\.exr\)",
            r"no holes found: the image is flat")


def test_wrong_hole_count(work, capsys):
    doc = plates(work, [{"file": "six_holes.exr"}], SEVEN)
    before = snapshot(work)
    refused(camera_cli(capsys, work, doc), work, before, r"images\[0\] \(six_holes\.exr\)",
            r"found 6 blob\(s\), the layout 'shiny_1988 seven holes' has 7 holes")


def test_holes_do_not_match_the_layout(work, capsys):
    """The seven-hole plate imaged, but placements.json describes it with hole 5 elsewhere."""
    layout = dict(SEVEN, holes_xy_mm=[list(p) for p in SEVEN["holes_xy_mm"]])
    layout["holes_xy_mm"][5] = [0.75, -0.75]
    doc = plates(work, [{"file": "seven_z0.exr"}], layout)
    before = snapshot(work)
    refused(camera_cli(capsys, work, doc), work, before, r"images\[0\] \(seven_z0\.exr\)",
            r"blob \d at \(.*\) does not match any hole: it is .* px from the nearest \(hole \d\)",
            r"check the layout, the placement and the nominal camera")


def test_plate_outside_the_field(work, capsys):
    doc = plates(work, [{"file": "seven_z0.exr", "placement": {"offset_mm": [3.0, 0.0, 0.0]}}], SEVEN)
    before = snapshot(work)
    refused(camera_cli(capsys, work, doc), work, before, r"images\[0\]", r"image outside the frame")


def test_image_of_another_size(work, capsys):
    doc = plates(work, [{"file": "small.exr"}], SEVEN)
    before = snapshot(work)
    refused(camera_cli(capsys, work, doc), work, before, r"images\[0\] \(small\.exr\)",
            r"is 64x64 pixels, the camera's image 128x128")


def test_degenerate_all_images_at_one_height(work, capsys):
    """Two images of the grid, both at z = 0 (one shifted), every group estimated: the solve refuses it."""
    doc = plates(work, [{"file": "grid_z0.exr"},
                        {"file": "grid_z0_shifted.exr", "placement": {"offset_mm": [0.05, 0.03, 0.0]}}],
                 dot_grid().to_dict())
    before = snapshot(work)
    refused(camera_cli(capsys, work, doc), work, before, r"bad_plates\.json",
            r"needs holes on two or more planes", r"principal point trades against a rotation", r"spacers")


def test_degenerate_seven_holes_cannot_give_distortion(work, capsys):
    """The centred seven-hole plate at two heights images its holes at two radii: k1, k2 against focal length."""
    doc = plates(work, [{"file": "seven_z0.exr"}, {"file": "seven_z1.exr", "placement": {"offset_mm": [0, 0, 1]}}])
    before = snapshot(work)
    refused(camera_cli(capsys, work, doc), work, before, r"bad_plates\.json", r"degenerate geometry",
            r"k1", r"too few distances from the image centre", r"dot_grid")


def test_degenerate_one_flat_image_with_focal_length(work, capsys):
    doc = plates(work, [{"file": "seven_z0.exr"}])
    before = snapshot(work)
    refused(camera_cli(capsys, work, doc, "--estimate", "pose", "focal"), work, before, r"degenerate geometry",
            r"position_z_mm and field_scale trade against each other", r"another height")


@pytest.mark.parametrize("text, names", [
    ("{\"images\": [", [r"not valid JSON"]),
    ("", [r"not valid JSON"]),
    ("[1, 2]", [r"must be a JSON object, got a list"]),
    ({"image": [{"file": "grid_z0.exr"}]}, [r"placements: unknown field 'image' \(did you mean 'images'\?\)"]),
    ({"plate": SEVEN}, [r"images: missing required field"]),
    ({"images": []}, [r"images: must be a non-empty list, got \[\]"]),
    ({"images": ["grid_z0.exr"]}, [r"images\[0\]: must be a JSON object, got a string"]),
    ({"images": [{"placement": {}}]}, [r"images\[0\]: needs 'file'"]),
    ({"images": [{"file": "grid_z0.exr", "placemnt": {}}]},
     [r"images\[0\]: unknown field 'placemnt' \(did you mean 'placement'\?\)"]),
    ({"images": [{"file": "grid_z0.exr", "placement": {"offset": [0, 0, 0]}}]},
     [r"images\[0\]\.placement: unknown field 'offset' \(did you mean 'offset_mm'\?\)"]),
    ({"images": [{"file": "grid_z0.exr", "placement": {"offset_mm": [0, 0]}}]},
     [r"images\[0\]\.placement\.offset_mm: must be 3 numbers"]),
    ({"images": [{"file": "grid_z0.exr", "placement": {"tilt_deg": [85, 0]}}]},
     [r"images\[0\]\.placement\.tilt_deg: must be within \(-80, 80\) degrees"]),
    ({"images": [{"file": "grid_z0.exr", "placement": {"rotation_deg": "10"}}]},
     [r"images\[0\]\.placement\.rotation_deg: must be a number"]),
    ({"images": [{"file": "grid_z0.exr", "placement": [0, 0, 0]}]},
     [r"images\[0\]\.placement: must be a JSON object, got a list"]),
    ({"plate": {"holes": [[0, 0]]}, "images": [{"file": "grid_z0.exr"}]},
     [r"plate: unknown field 'holes' \(did you mean 'holes_xy_mm'\?\)"]),
    ({"plate": {"hole_diameter_mm": 0.2}, "images": [{"file": "grid_z0.exr"}]},
     [r"plate: missing required field\(s\): holes_xy_mm"]),
    ({"plate": {"holes_xy_mm": [[0, 0], [1, 0], [0, 1]], "hole_diameter_mm": -1}, "images": [{"file": "grid_z0.exr"}]},
     [r"plate\.hole_diameter_mm: must be a finite diameter > 0 mm, got -1"]),
    ('{"images": [{"file": "grid_z0.exr", "placement": {"rotation_deg": 1%s}}]}' % ("0" * 400),
     [r"images\[0\]\.placement\.rotation_deg: must be a finite angle in degrees, got inf"]),
    ('{"plate": {"holes_xy_mm": [[0, 0], [1, 0], [0, 1]], "hole_diameter_mm": 1%s}, "images": []}' % ("0" * 400),
     [r"plate\.hole_diameter_mm: must be a finite diameter > 0 mm, got inf"]),
    ({"plate": {"holes_xy_mm": [[0, 0], [0.1, 0], [0, 1]]}, "images": [{"file": "grid_z0.exr"}]},
     [r"plate\.holes_xy_mm: holes 0 and 1 are 0\.1 mm apart"]),
])
def test_bad_placements_file(work, capsys, text, names):
    write_json(work / "bad_plates.json", text)
    before = snapshot(work)
    refused(camera_cli(capsys, work, "bad_plates.json"), work, before, r"bad_plates\.json: ", *names)


def test_placements_file_missing(work, capsys):
    before = snapshot(work)
    refused(camera_cli(capsys, work, "nope.json"), work, before, r"nope\.json: no such file")


def test_placements_file_is_a_folder(work, capsys):
    before = snapshot(work)
    refused(camera_cli(capsys, work, "sphere_1"), work, before, r"sphere_1: not a file")


def test_placements_file_not_utf8(work, capsys):
    (work / "bad_plates.json").write_bytes(b'{"images": [{"file": "caf\xe9.exr"}]}')
    before = snapshot(work)
    refused(camera_cli(capsys, work, "bad_plates.json"), work, before, r"bad_plates\.json: is not UTF-8 text")


@pytest.mark.parametrize("file, names", [
    ("missing.exr", [r"missing\.exr: file: no such file"]),
    ("sphere_1", [r"sphere_1: file: is a directory"]),
    ("nominal.json", [r"nominal\.json: format: not an image"]),
])
def test_image_file_unusable(work, capsys, file, names):
    doc = plates(work, [{"file": "grid_z0.exr"}, {"file": file}])
    before = snapshot(work)
    refused(camera_cli(capsys, work, doc), work, before, *names)


@pytest.mark.parametrize("index", ["1", "-1"])
def test_camera_index_out_of_range(work, capsys, index):
    before = snapshot(work)
    refused(camera_cli(capsys, work, "placements.json", "--camera-index", index), work, before,
            rf"--camera-index {index}: the rig has 1 camera\(s\), 0 to 0")


@pytest.mark.parametrize("cli", ["camera", "sources"])
@pytest.mark.parametrize("sigma", ["-1", "0", "nan", "inf"])
def test_pixel_sigma_not_positive(work, capsys, cli, sigma):
    """Refused before any image is read (it used to be checked only after the detection, without the option's name)."""
    before = snapshot(work)
    result = (camera_cli(capsys, work, "placements.json", "--pixel-sigma", sigma) if cli == "camera" else
              sources_cli(capsys, work, "spheres.json", "--pixel-sigma", sigma))
    refused(result, work, before, rf"--pixel-sigma must be a finite number of pixels > 0, got {sigma}")


def test_camera_unknown_estimate_group(work, capsys):
    before = snapshot(work)
    result = camera_cli(capsys, work, "placements.json", "--estimate", "focus")
    assert_refused(result, "calibrate camera", r"--estimate", r"invalid choice: 'focus'", status=2)
    assert_unchanged(work, before)


# -- sources: the sphere scans ----------------------------------------------------------------------


def spheres(work, scans, radius=R_SPHERE, name="bad_spheres.json"):
    return write_json(work / name, {"radius_mm": radius, "scans": scans}).name


def test_sphere_not_found(work, capsys):
    doc = spheres(work, [{"folder": "dark", "center_mm": [0, 0, 0]}])
    before = snapshot(work)
    refused(sources_cli(capsys, work, doc), work, before, r"bad_spheres\.json: scans\[0\] \(dark\)",
            r"sphere not found: no frame of 21 shows a highlight on the sphere at \[0\.0, 0\.0, 0\.0\] mm")


def test_sphere_outside_the_image(work, capsys):
    doc = spheres(work, [{"folder": "sphere_0", "center_mm": [50, 0, 0]}])
    before = snapshot(work)
    refused(sources_cli(capsys, work, doc), work, before, r"bad_spheres\.json: scans\[0\] \(sphere_0\)",
            r"sphere not found: the sphere at \[50\.0, 0\.0, 0\.0\] mm.* is outside camera 'top''s image")


def test_too_few_sphere_positions_for_3d(work, capsys):
    doc = spheres(work, [{"folder": "sphere_0", "center_mm": [0, 0, 0]}])
    before = snapshot(work)
    refused(sources_cli(capsys, work, doc, "--require-positions"), work, before, r"bad_spheres\.json",
            r"source 0: seen by 1 sphere placement: too few sphere positions for a 3-D solution \(need 2 or more\)")


def test_one_sphere_position_without_pixel_sigma(work, capsys):
    """One position fits each direction exactly: no residual to estimate the noise from, and it says so."""
    doc = spheres(work, [{"folder": "sphere_0", "center_mm": [0, 0, 0]}])
    before = snapshot(work)
    refused(sources_cli(capsys, work, doc), work, before, r"bad_spheres\.json",
            r"the pixel noise cannot be estimated", r"pass pixel_sigma, or add sphere placements")


def test_degenerate_sphere_positions(work, capsys):
    """The same scan listed twice: the reflected rays coincide, the distance along them is unknown."""
    doc = spheres(work, [{"folder": "sphere_0", "center_mm": [0, 0, 0]}] * 2)
    before = snapshot(work)
    refused(sources_cli(capsys, work, doc, "--require-positions"), work, before, r"bad_spheres\.json",
            r"source 0: the reflected rays of its 2 placements are nearly parallel", r"degenerate geometry")


def test_scan_of_another_rig(work, capsys):
    """A scan folder whose stack has 3 frames, against the nominal rig's 21 sources."""
    doc = spheres(work, [{"folder": "three", "center_mm": [0, 0, 0]}])
    before = snapshot(work)
    refused(sources_cli(capsys, work, doc), work, before, r"three/stack\.exr: channels: missing channel\(s\) S003",
            r"for the rig's 21 sources")


def test_wrong_number_of_frames(work, capsys):
    doc = spheres(work, [{"frames": ["sphere_1/f00.exr", "sphere_1/f01.exr"], "center_mm": [0, 0, 0]}])
    before = snapshot(work)
    refused(sources_cli(capsys, work, doc), work, before,
            r"bad_spheres\.json: scans\[0\]\.frames: 2 frame files given but the rig has 21 sources")


@pytest.mark.parametrize("doc, names", [
    ("{\"scans\": ", [r"not valid JSON"]),
    ({"radius_mm": -0.5, "scans": [{"folder": "sphere_0", "center_mm": [0, 0, 0]}]},
     [r"radius_mm: must be the sphere's radius, a number > 0 mm, got -0\.5"]),
    ({"radius_mm": 0, "scans": [{"folder": "sphere_0", "center_mm": [0, 0, 0]}]},
     [r"radius_mm: must be the sphere's radius, a number > 0 mm, got 0"]),
    ({"radius_mm": "0.8", "scans": [{"folder": "sphere_0", "center_mm": [0, 0, 0]}]},
     [r"radius_mm: must be the sphere's radius, a number > 0 mm, got \"0\.8\""]),
    ({"scans": [{"folder": "sphere_0", "center_mm": [0, 0, 0]}]}, [r"radius_mm: .* got null"]),
    ({"radius": R_SPHERE, "scans": []}, [r"spheres: unknown field 'radius' \(did you mean 'radius_mm'\?\)"]),
    ({"radius_mm": R_SPHERE}, [r"scans: missing required field"]),
    ({"radius_mm": R_SPHERE, "scans": {}}, [r"scans: must be a non-empty list, got \{\}"]),
    ({"radius_mm": R_SPHERE, "scans": [{"folder": "sphere_0", "center": [0, 0, 0]}]},
     [r"scans\[0\]: unknown field 'center' \(did you mean 'center_mm'\?\)"]),
    ({"radius_mm": R_SPHERE, "scans": [{"folder": "sphere_0"}]}, [r"scans\[0\]\.center_mm: must be 3 finite numbers"]),
    ({"radius_mm": R_SPHERE, "scans": [{"folder": "sphere_0", "center_mm": [0, 0]}]},
     [r"scans\[0\]\.center_mm: must be 3 finite numbers, got \[0, 0\]"]),
    ({"radius_mm": R_SPHERE, "scans": [{"folder": "sphere_0", "frames": ["sphere_1/f00.exr"], "center_mm": [0, 0, 0]}]},
     [r"scans\[0\]: has both 'folder' and 'frames'; give one"]),
    ({"radius_mm": R_SPHERE, "scans": [{"center_mm": [0, 0, 0]}]},
     [r"scans\[0\]: needs 'folder' \(a scan folder with stack\.exr\) or 'frames'"]),
    ({"radius_mm": R_SPHERE, "scans": [{"folder": None, "center_mm": [0, 0, 0]}]},
     [r"scans\[0\]\.folder: must be the scan folder's path, got null"]),
    ('{"radius_mm": 1%s, "scans": [{"folder": "sphere_0", "center_mm": [0, 0, 0]}]}' % ("0" * 400),
     [r"radius_mm: must be the sphere's radius, a number > 0 mm, got Infinity"]),
    ('{"radius_mm": 0.79375, "scans": [{"folder": "sphere_0", "center_mm": [-1%s, 0, 0]}]}' % ("0" * 400),
     [r"scans\[0\]\.center_mm: must be 3 finite numbers, got \[-Infinity, 0, 0\]"]),
    ({"radius_mm": R_SPHERE, "scans": [{"frames": [], "center_mm": [0, 0, 0]}]},
     [r"scans\[0\]\.frames: must be a non-empty list"]),
    ({"radius_mm": R_SPHERE, "scans": [{"frames": ["sphere_1/f00.exr", 3], "center_mm": [0, 0, 0]}]},
     [r"scans\[0\]\.frames\[1\]: must be an image file's path, got 3"]),
])
def test_bad_spheres_file(work, capsys, doc, names):
    write_json(work / "bad_spheres.json", doc)
    before = snapshot(work)
    refused(sources_cli(capsys, work, "bad_spheres.json"), work, before, r"bad_spheres\.json: ", *names)


def test_spheres_file_missing(work, capsys):
    before = snapshot(work)
    refused(sources_cli(capsys, work, "nope.json"), work, before, r"nope\.json: no such file")


def test_scan_folder_missing(work, capsys):
    doc = spheres(work, [{"folder": "sphere_9", "center_mm": [0, 0, 0]}])
    before = snapshot(work)
    refused(sources_cli(capsys, work, doc), work, before, r"sphere_9/stack\.exr: no such file")


def test_scan_frame_missing(work, capsys):
    frames = [f"sphere_1/f{k:02d}.exr" for k in range(NOMINAL.n_sources)]
    frames[4] = "sphere_1/f99.exr"
    doc = spheres(work, [{"frames": frames, "center_mm": [0, 0, 0]}])
    before = snapshot(work)
    refused(sources_cli(capsys, work, doc), work, before, r"f99\.exr: file: no such file")


# -- both: the rig and the output -------------------------------------------------------------------


@pytest.mark.parametrize("cli", [camera_cli, sources_cli])
def test_output_exists(work, capsys, cli):
    """An existing output is refused before any work, without --overwrite, and left as it was."""
    (work / "calibrated.json").write_text("keep me\n")
    before = snapshot(work)
    doc = "placements.json" if cli is camera_cli else "spheres.json"
    refused(cli(capsys, work, doc), work, before, r"calibrated\.json exists; not overwriting it \(pass --overwrite\)")
    assert (work / "calibrated.json").read_text() == "keep me\n"


@pytest.mark.parametrize("cli", [camera_cli, sources_cli])
def test_output_is_a_dangling_link(work, capsys, cli):
    os.symlink(work / "nowhere.json", work / "calibrated.json")
    before = snapshot(work)
    doc = "placements.json" if cli is camera_cli else "spheres.json"
    refused(cli(capsys, work, doc), work, before, r"calibrated\.json exists; not overwriting it")


@pytest.mark.parametrize("out, names", [
    ("sphere_0", [r"--out .*sphere_0 is a folder"]),
    ("no_folder/calibrated.json", [r"--out .*no_folder/calibrated\.json: .*no_folder does not exist"]),
    ("grid_z0.exr/calibrated.json", [r"--out .*grid_z0\.exr/calibrated\.json: .*grid_z0\.exr is not a folder"]),
])
@pytest.mark.parametrize("overwrite", [[], ["--overwrite"]])
def test_output_cannot_be_written(work, capsys, out, names, overwrite):
    """Refused before any work, with or without --overwrite (not after the solve, naming a temporary file)."""
    before = snapshot(work)
    refused(camera_cli(capsys, work, "placements.json", *overwrite, out=out), work, before, *names)


def test_rig_missing_or_invalid(work, capsys):
    before = snapshot(work)
    result = run_cli(capsys, "calibrate", "sources", "--rig", work / "no_rig.json", "--spheres",
                     work / "spheres.json", "--out", work / "calibrated.json")
    refused(result, work, before, r"no_rig\.json: no such file")
    bad = NOMINAL.to_dict()
    bad["cameras"][0]["fieldwidth_mm"] = bad["cameras"][0].pop("field_width_mm")
    write_json(work / "bad_rig.json", bad)
    before = snapshot(work)
    result = run_cli(capsys, "calibrate", "camera", "--rig", work / "bad_rig.json", "--plates",
                     work / "placements.json", "--out", work / "calibrated.json")
    refused(result, work, before, r"bad_rig\.json: cameras\[0\]: unknown field 'fieldwidth_mm'",
            r"did you mean 'field_width_mm'")


def test_sources_of_a_rig_with_another_source_count(work, capsys):
    """The nominal rig says 3 sources, the scans hold 21 frames."""
    three = shiny_1988(resolution=128, n_sources=3)
    three.save(work / "three.json")
    before = snapshot(work)
    result = run_cli(capsys, "calibrate", "sources", "--rig", work / "three.json", "--spheres",
                     work / "spheres.json", "--out", work / "calibrated.json")
    refused(result, work, before, r"sphere_0/stack\.exr: channels: has frames S003.* beyond the rig's 3 sources")


def test_missing_required_options(work, capsys):
    result = run_cli(capsys, "calibrate", "camera", "--rig", work / "nominal.json", "--out", work / "c.json")
    assert_refused(result, "calibrate camera", r"the following arguments are required: --plates", status=2)
    result = run_cli(capsys, "calibrate", "sources", "--rig", work / "nominal.json", "--spheres", work / "s.json")
    assert_refused(result, "calibrate sources", r"the following arguments are required: --out", status=2)
    result = run_cli(capsys, "calibrate")
    assert_refused(result, "calibrate", r"the following arguments are required", status=2)
