"""The registry of scanned objects: names the studies and the CLI offer, and exact truths that agree with themselves."""

import numpy as np
import pytest

from shinysim.errors import OptionError
from shinysim.objects.registry import (
    CODED_OBJECTS,
    DATASET_OBJECT_KINDS,
    OBJECT_NAMES,
    PART_SHAPES,
    STEREO_OBJECTS,
    scanned_object,
)


def test_the_studies_and_the_cli_offer_registry_names():
    from shinysim.cli import build_parser
    from shinysim.datasets.spec import OBJECT_KINDS
    from shinysim.studies.coded.scene import CODED_OBJECTS as coded
    from shinysim.studies.stereo import STEREO_PLACEMENT, STEREO_SCENES

    assert set(STEREO_OBJECTS) <= set(OBJECT_NAMES) and set(CODED_OBJECTS) <= set(OBJECT_NAMES)
    assert tuple(STEREO_SCENES) == STEREO_OBJECTS and set(STEREO_PLACEMENT) <= set(STEREO_OBJECTS)
    assert coded == CODED_OBJECTS
    assert OBJECT_KINDS == DATASET_OBJECT_KINDS
    stereo = next(a for a in build_parser()._subparsers._group_actions[0].choices["stereo"]._actions
                  if a.dest == "scene")
    assert tuple(stereo.choices) == STEREO_OBJECTS


@pytest.mark.parametrize("name", OBJECT_NAMES)
def test_datum_lies_on_the_exact_surface_with_a_unit_normal(name):
    obj = scanned_object(name)
    assert obj.parts and all(p.shape in PART_SHAPES for p in obj.parts.values())
    if obj.datum is None:  # several parts at different heights: no one datum
        assert obj.height is None
        return
    assert np.linalg.norm(obj.datum_normal) == pytest.approx(1.0, abs=1e-12)
    if obj.height is not None:
        # the datum is built from the same formula: agreement to rounding (a few ulps of ~1 mm)
        assert float(obj.height(obj.datum[0], obj.datum[1])) == pytest.approx(obj.datum[2], abs=1e-12)
    if obj.profile is not None:  # the joint: its datum is on the exact fillet profile
        assert float(obj.profile.profile_z(obj.datum[0], 0.0, ripple=False)) == pytest.approx(obj.datum[2], abs=1e-12)


def test_tilted_plane_height_and_normal_agree():
    obj = scanned_object("tilted_plane")
    x, y, h = 0.7, -0.4, 1e-6
    # the plane's gradient by central differences (exact for a plane up to rounding, ~1e-10 at h = 1e-6)
    p = (obj.height(x + h, y) - obj.height(x - h, y)) / (2 * h)
    q = (obj.height(x, y + h) - obj.height(x, y - h)) / (2 * h)
    n = np.array([-p, -q, 1.0]) / np.hypot(np.hypot(p, q), 1.0)
    np.testing.assert_allclose(n, obj.datum_normal, atol=1e-8)


def test_placement_moves_the_truth():
    obj = scanned_object("sphere", center_mm=(1.5, 0.0, 0.8), part="sphere")
    r = obj.sphere[1]
    assert obj.truth_parts == ("sphere",)
    np.testing.assert_array_equal(obj.datum, [1.5, 0.0, 0.8 + r])
    assert float(obj.height(1.5, 0.0)) == 0.8 + r
    lifted, flat = scanned_object("solder", lift_mm=0.5), scanned_object("solder")
    assert lifted.datum[2] - flat.datum[2] == pytest.approx(0.5, abs=1e-12)


def test_unknown_object_names_the_choices():
    with pytest.raises(OptionError, match="three_spheres"):
        scanned_object("three_sphere")
