"""Acceptance classes by criteria on the joint geometry, and the inspection study's numpy parts."""

import math

import numpy as np
import pytest

from shinysim.errors import OptionError
from shinysim.objects.criteria import CLASSES, AcceptanceCriteria, judge, measure_joint
from shinysim.objects.solder import PAD_THICKNESS, JointParams, JointProfile
from shinysim.studies.inspection import (
    INSPECTION_FEATURES,
    NUISANCE_RANGES,
    SENSORS,
    draw_inspection_joint,
    robustness_table,
    wilson_interval,
)

D = math.radians


def test_nominal_joints_get_their_classes():
    for kind in ("good", "insufficient", "lifted", "bridge"):
        assert judge(JointParams(kind=kind)).label == kind, kind
    # the paper-setting "excess" generator's nominal joint (lead slope +10 deg on an 85 deg leg)
    # wets the lead at 85 deg: a class is what the criteria say, not the generator's name
    v = judge(JointParams(kind="excess"))
    assert v.measurements["wetting_angle_lead_deg"] == pytest.approx(85.0) and v.label == "good"


def test_heel_fillet_boundary_is_g_plus_half_t():
    # F_min = G + 0.5 T = 0.005 + 0.05 = 0.055 mm; the label flips across it
    base = dict(kind="good", lead_lift=0.005, lead_thickness=0.10, contact_angle_pad=D(6.0),
                lead_slope_angle=D(25.0))
    below = judge(JointParams(fillet_height=0.054, **base))
    above = judge(JointParams(fillet_height=0.056, **base))
    assert below.label == "insufficient" and above.label == "good"
    assert below.margins["heel_fillet"] == pytest.approx((0.054 - 0.055) / 0.055)
    assert below.near_boundary and above.near_boundary
    # IPC class 3 asks for F >= G + T: the same joint is insufficient there
    strict = AcceptanceCriteria(heel_fillet_fraction=1.0)
    assert judge(JointParams(fillet_height=0.09, **base), strict).label == "insufficient"
    assert judge(JointParams(fillet_height=0.09, **base)).label == "good"


def test_wetting_angle_boundary_at_90_degrees():
    # a vertical J-lead leg: wetting angle on the lead = 90 deg - lead_slope_angle
    base = dict(kind="good", lead_type="j-lead", fillet_height=0.2, contact_angle_pad=D(40.0))
    for slope, label in ((1.0, "good"), (-1.0, "excess")):
        v = judge(JointParams(lead_slope_angle=D(slope), **base))
        assert v.measurements["wetting_angle_lead_deg"] == pytest.approx(90.0 - slope, abs=1e-9)
        assert v.label == label
    # the gull-wing leg leans back 5 deg: the same slope wets at 95 deg
    gull = judge(JointParams(lead_slope_angle=0.0, **{**base, "lead_type": "gull-wing"}))
    assert gull.measurements["wetting_angle_lead_deg"] == pytest.approx(95.0, abs=1e-9)
    assert gull.label == "excess"


def test_order_of_the_criteria():
    # a bridge over an insufficient fillet is a bridge; an insufficient convex one is insufficient
    v = judge(JointParams(kind="bridge", fillet_height=0.04, lead_lift=0.0, contact_angle_pad=D(6.0),
                          lead_slope_angle=D(25.0)))
    assert v.label == "bridge" and v.violated == ("bridge", "insufficient")
    lifted = judge(JointParams(kind="lifted"))
    assert lifted.label == "lifted" and lifted.margins == {} and not lifted.near_boundary
    assert measure_joint(JointParams(kind="lifted"))["heel_fillet_mm"] == 0.0


def test_criteria_are_checked():
    with pytest.raises(OptionError, match="max_wetting_angle_deg"):
        AcceptanceCriteria(max_wetting_angle_deg=0.0)
    with pytest.raises(OptionError, match="heel_fillet_fraction"):
        AcceptanceCriteria(heel_fillet_fraction=float("nan"))
    with pytest.raises(ValueError, match="JointParams"):
        judge("good")


def test_pad_thickness_and_offset_move_the_joint():
    a = JointProfile(JointParams(kind="good"))
    b = JointProfile(JointParams(kind="good", pad_thickness=PAD_THICKNESS + 0.01, pad_offset=0.03))
    assert b.pad_top_z == pytest.approx(PAD_THICKNESS + 0.01)
    assert b.pad_x_range[0] - a.pad_x_range[0] == pytest.approx(0.03)
    # the lead stands on the thicker pad: the whole fillet rises by 10 um, same shape
    x = np.linspace(*a.visible_x_range, 50)
    np.testing.assert_allclose(b.profile_z(x), a.profile_z(x) + 0.01, atol=1e-12)
    assert b.lead.bottom_z - a.lead.bottom_z == pytest.approx(0.01)


@pytest.mark.parametrize("label", CLASSES)
def test_drawn_joints_have_the_asked_class_and_nuisances_in_range(label):
    rng = np.random.default_rng(3)
    for _ in range(3):
        params, nuis, verdict = draw_inspection_joint(label, rng)
        assert verdict.label == label == judge(params).label
        assert nuis["sensor"] in SENSORS
        for name, (lo, hi) in NUISANCE_RANGES.items():
            assert lo <= nuis[name] <= hi, name
        assert params.pad_thickness == nuis["pad_thickness"]
        assert params.lead_offset == nuis["lead_offset"] and params.pad_offset == nuis["pad_offset"]
    a = draw_inspection_joint(label, np.random.default_rng(11))
    b = draw_inspection_joint(label, np.random.default_rng(11))
    assert a[0] == b[0] and a[1] == b[1]


def test_wilson_interval_matches_scipy():
    stats = pytest.importorskip("scipy.stats")
    for k, n in ((95, 100), (500, 500), (0, 20), (37, 41)):
        ci = stats.binomtest(k, n).proportion_ci(confidence_level=0.95, method="wilson")
        assert wilson_interval(k, n) == pytest.approx((ci.low, ci.high), abs=1e-12)
    assert all(math.isnan(v) for v in wilson_interval(0, 0))


def _record(split, label, sensor, value, rng):
    f = dict.fromkeys(INSPECTION_FEATURES, 0.0)
    f["height_max_mm"] = CLASSES.index(label) + 0.1 * rng.normal()  # separable by one feature
    return {"split": split, "label": label, "lead_type": "gull-wing", "features": f,
            "nuisances": {"sensor": sensor, **{k: (lo + hi) / 2 for k, (lo, hi) in NUISANCE_RANGES.items()},
                          "solder_alpha": value}}


def test_robustness_table_trains_on_one_part_and_tests_on_the_other():
    rng = np.random.default_rng(0)
    lo, hi = NUISANCE_RANGES["solder_alpha"]
    recs = [_record(split, label, SENSORS[i % 2], lo + (hi - lo) * (i % 4 + 0.5) / 4, rng)
            for split in ("train", "test") for label in CLASSES for i in range(8)]
    rows = robustness_table(recs)
    alpha = [r for r in rows if r["nuisance"] == "solder_alpha"]
    assert len(alpha) == 2 and alpha[0]["train_range"] == alpha[1]["test_range"]
    for r in alpha:
        assert r["n_train"] == 4 * len(CLASSES)
        assert r["in_range"]["n"] == r["shifted"]["n"] == 4 * len(CLASSES)
        assert r["shifted"]["accuracy"] == 1.0 and r["missing"] == []
    # a part that holds a single class cannot train a classifier: reported, not guessed
    one = [dict(r, label="good") if r["nuisances"]["sensor"] == SENSORS[0] else r for r in recs]
    row = next(r for r in robustness_table(one) if r["nuisance"] == "sensor" and r["train_range"] == SENSORS[0])
    assert row["in_range"] is None and set(row["missing"]) == set(CLASSES) - {"good"}


def test_inspection_features_columns():
    from shinysim.recon.joint import FEATURE_NAMES
    from shinysim.studies.inspection import inspection_features

    f = dict.fromkeys(FEATURE_NAMES, 0.0)
    f.update(phi_last_deg=3.0, phi_min_deg=-2.0, height_mm=0.05, height_max_mm=0.1, n_points=4.0)
    recs = [{"features": f, "lead_type": "j-lead"}, {"features": f, "lead_type": "gull-wing"}]
    X = inspection_features(recs)
    assert X.shape == (2, len(INSPECTION_FEATURES))
    col = dict(zip(INSPECTION_FEATURES, X.T))
    # the wetting angle on the leg is 90 deg where the end slope is 90 deg - leg angle:
    # 0 deg on the vertical J-lead leg, 5 deg on the gull-wing's 85 deg leg
    np.testing.assert_allclose(col["end_slope_margin_deg"], [3.0, -2.0])
    np.testing.assert_allclose(col["min_slope_margin_deg"], [-2.0, -7.0])
    np.testing.assert_allclose(col["end_to_max_height"], [0.5, 0.5])
    np.testing.assert_allclose(col["j_lead"], [1.0, 0.0])
    np.testing.assert_allclose(col["height_max_mm*n_points"], [0.4, 0.4])
    assert inspection_features([]).shape == (0, len(INSPECTION_FEATURES))
