"""The calibration plate: its default layout, JSON form, bad layouts, and placements that move it."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from shinysim.errors import CalibrationError
from shinysim.objects.plate import (
    HOLE_DIAMETER_MM,
    MIN_SPACING_DIAMETERS,
    HolePlate,
    PlatePlacement,
    dot_grid,
    shiny_plate,
)


def test_hole_diameter_is_the_papers_drill():
    assert HOLE_DIAMETER_MM == pytest.approx(0.2032, abs=1e-15)  # 0.008 in, exactly


def test_default_layout_is_centre_and_hexagon():
    plate = shiny_plate()
    assert plate.n_holes == 7
    assert plate.hole_diameter == HOLE_DIAMETER_MM
    np.testing.assert_array_equal(plate.holes_xy[0], [0.0, 0.0])
    ring = plate.holes_xy[1:]
    np.testing.assert_allclose(np.linalg.norm(ring, axis=1), 0.6, atol=1e-15)  # closed form, a few ulps
    angles = np.degrees(np.arctan2(ring[:, 1], ring[:, 0])) % 360
    np.testing.assert_allclose(angles, [0, 60, 120, 180, 240, 300], atol=1e-12)  # atan2 of exact cos/sin
    assert plate.min_spacing == pytest.approx(0.6, abs=1e-15)  # hexagon side = radius
    # the whole plate sits inside the preset camera's 2 mm field with room to spare
    assert np.abs(plate.holes_xy).max() + plate.hole_diameter / 2 < 1.0
    assert shiny_plate(0.5).holes_xy[1].tolist() == [0.5, 0.0]


def test_dot_grid_layout():
    grid = dot_grid()
    assert grid.n_holes == 25
    np.testing.assert_allclose(grid.holes_xy[0], [-0.7, -0.7], atol=1e-15)  # (i - 2) * 0.35, a product of exact-ish floats
    np.testing.assert_allclose(grid.holes_xy[1], [-0.35, -0.7], atol=1e-15)
    np.testing.assert_allclose(grid.holes_xy[5], [-0.7, -0.35], atol=1e-15)  # row by row, y outer
    np.testing.assert_allclose(grid.holes_xy[12], [0.0, 0.0], atol=1e-15)
    assert grid.min_spacing == pytest.approx(0.35, abs=1e-15)
    assert dot_grid(3, 0.5).n_holes == 9


def test_json_round_trip():
    for plate in (shiny_plate(), dot_grid(4, 0.4), HolePlate([[0, 0], [1, 0], [0, 1.5]], 0.1, "mine")):
        text = json.dumps(plate.to_dict())
        back = HolePlate.from_dict(json.loads(text))
        assert back == plate
        np.testing.assert_array_equal(back.holes_xy, plate.holes_xy)  # JSON floats round-trip exactly
    d = shiny_plate().to_dict()
    assert set(d) == {"holes_xy_mm", "hole_diameter_mm", "name"}
    assert HolePlate.from_dict({"holes_xy_mm": [[0, 0], [1, 0], [0, 1]]}).hole_diameter == HOLE_DIAMETER_MM


@pytest.mark.parametrize("bad, field, words", [
    ({"holes_xy_mm": [[0, 0], [1, 0]]}, "holes_xy_mm", "at least 3 holes"),
    ({"holes_xy_mm": [[0, 0], [1, 0], [2, 0], [3, 0]]}, "holes_xy_mm", "one line"),
    ({"holes_xy_mm": [[0, 0], [0.25, 0], [0, 1]]}, "holes_xy_mm", "holes 0 and 1 are 0.25 mm apart"),
    ({"holes_xy_mm": [[0, 0], [1, float("nan")], [0, 1]]}, "holes_xy_mm", "finite"),
    ({"holes_xy_mm": [[0, 0, 0], [1, 0, 0], [0, 1, 0]]}, "holes_xy_mm", "[x, y]"),
    ({"holes_xy_mm": [[0, 0], [1, "a"], [0, 1]]}, "holes_xy_mm", "[x, y]"),
    ({"holes_xy_mm": "holes"}, "holes_xy_mm", "[x, y]"),
    ({"holes_xy_mm": [[0, 0], [1, 0], [0, 1]], "hole_diameter_mm": -0.2}, "hole_diameter_mm", "> 0"),
    ({"holes_xy_mm": [[0, 0], [1, 0], [0, 1]], "hole_diameter_mm": "0.2"}, "hole_diameter_mm", "number"),
    ({"holes_xy_mm": [[0, 0], [1, 0], [0, 1]], "name": 3}, "name", "string"),
    ({"holes_xy_mm": [[0, 0], [1, 0], [0, 1]], "hole_diameter": 0.2}, "plate", "did you mean 'hole_diameter_mm'"),
    ({"hole_diameter_mm": 0.2}, "plate", "missing required field(s): holes_xy_mm"),
    ([[0, 0], [1, 0], [0, 1]], "plate", "JSON object"),
])
def test_bad_layouts_are_refused_naming_the_field(bad, field, words):
    with pytest.raises(CalibrationError) as info:
        HolePlate.from_dict(bad)
    assert info.value.field == field
    assert words in str(info.value)


def test_spacing_rule_is_in_hole_diameters():
    HolePlate([[0, 0], [0.31, 0], [0, 0.31]])  # 1.53 diameters: accepted
    with pytest.raises(CalibrationError, match="less than 1.5 hole diameters"):
        HolePlate([[0, 0], [MIN_SPACING_DIAMETERS * 0.1 - 1e-6, 0], [0, 1]], 0.1)


def test_default_placement_is_the_reference_plane():
    plate = shiny_plate()
    placement = PlatePlacement()
    np.testing.assert_array_equal(placement.matrix(), np.eye(4))
    np.testing.assert_array_equal(placement.world_holes(plate), np.column_stack([plate.holes_xy, np.zeros(7)]))


def test_offset_moves_every_hole():
    plate = shiny_plate()
    world = PlatePlacement(offset=(0.1, -0.2, 1.0)).world_holes(plate)
    np.testing.assert_allclose(world, plate.holes_xyz + [0.1, -0.2, 1.0], atol=1e-15)  # one addition each


def test_rotation_about_the_normal_comes_first():
    plate = HolePlate([[1, 0], [0, 1], [-1, -1]], 0.1)
    world = PlatePlacement(rotation_deg=90).world_holes(plate)
    np.testing.assert_array_equal(world, [[0, 1, 0], [-1, 0, 0], [1, -1, 0]])  # quarter turns are exact


def test_tilts_are_about_world_x_then_world_y():
    plate = HolePlate([[1, 0], [0, 1], [-1, -1]], 0.1)
    # about x by 90: +y goes to +z (the +y side rises), x stays
    np.testing.assert_array_equal(PlatePlacement(tilt_deg=(30, 0)).world_holes(plate)[0], [1, 0, 0])
    tx = PlatePlacement(tilt_deg=(30, 0)).world_holes(plate)
    np.testing.assert_allclose(tx[1], [0, math.cos(math.radians(30)), math.sin(math.radians(30))], atol=1e-15)
    # about y by 30: +x goes down (right-handed: z x x = y, so x turns towards -z)
    ty = PlatePlacement(tilt_deg=(0, 30)).world_holes(plate)
    np.testing.assert_allclose(ty[0], [math.cos(math.radians(30)), 0, -math.sin(math.radians(30))], atol=1e-15)
    # both: x first, then y, then the offset; checked against the matrices written out
    a, b = math.radians(20), math.radians(-15)
    rx = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    ry = np.array([[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]])
    rz = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]])
    placement = PlatePlacement((0.5, 0.25, -1.0), (20, -15), 90)
    expected = plate.holes_xyz @ (ry @ rx @ rz).T + [0.5, 0.25, -1.0]
    np.testing.assert_allclose(placement.world_holes(plate), expected, atol=1e-15)  # same products, other order
    np.testing.assert_allclose(placement.matrix()[:3, :3], ry @ rx @ rz, atol=1e-16)
    np.testing.assert_allclose(placement.normal, (ry @ rx)[:, 2], atol=1e-16)


def test_placement_json_round_trip_and_bad_fields():
    placement = PlatePlacement((0.5, 0.25, -1.0), (20, -15), 12.5)
    assert PlatePlacement.from_dict(json.loads(json.dumps(placement.to_dict()))) == placement
    assert PlatePlacement.from_dict({}) == PlatePlacement()
    for bad, field in [({"offset_mm": [0, 0]}, "offset_mm"), ({"tilt_deg": [0, 85]}, "tilt_deg"),
                       ({"rotation_deg": "x"}, "rotation_deg"), ({"tilt": [0, 0]}, "placement"),
                       ({"offset_mm": [0, 0, float("inf")]}, "offset_mm")]:
        with pytest.raises(CalibrationError) as info:
            PlatePlacement.from_dict(bad)
        assert info.value.field == field
