"""Scans through a camera sensor, and the normal error against exposure."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import requires_jit


@requires_jit
def test_scan_through_a_12_bit_sensor(tmp_path):
    from shinysim.io import load_stack
    from shinysim.studies.scan import run_scan

    score = run_scan(tmp_path / "scan", resolution=128, spp=8, plot=False, sensor="machine_vision_12bit",
                     exposure=0.8)
    assert score["sensor"]["name"] == "machine_vision_12bit" and score["exposure"] == 0.8
    stack = load_stack(tmp_path / "scan" / "stack.exr")
    assert stack.saturation == 1.0 and stack.provenance["sensor"]["bits"] == 12
    codes = stack.frames * 4095
    np.testing.assert_allclose(codes, np.rint(codes), atol=1e-3)  # 12-bit codes survive the file (float32)
    # the brightest pixel at 0.8 of the full well: 0.8 * 4095 codes above the 40-code black level,
    # give or take shot noise (sqrt(0.8 * 10500) e- = 92 e-, 3.5 codes) and PRNU (0.5 %)
    assert 0.8 * (4095 - 40) + 40 - 60 < codes.max() < 0.8 * (4095 - 40) + 40 + 60
    assert score["n_highlights"] == 21


@requires_jit
def test_quick_exposure_table(tmp_path):
    from shinysim.studies.exposure import run_exposure

    result = run_exposure(tmp_path / "exp", quick=True)
    rows = result["rows"]
    assert json.loads((tmp_path / "exp" / "exposure.json").read_text())["rows"] == json.loads(json.dumps(rows))
    assert {(r["preset"], r["centroid"]) for r in rows} == {
        (p, c) for p in ("machine_vision_12bit", "tv_1980s_8bit") for c in ("weighted", "plain")}
    # above full scale the brightest highlights clip, and are flagged
    assert all(r["mean_saturated"] == 21 for r in rows if r["exposure"] == 5.0)
    assert all(r["mean_saturated"] == 0 for r in rows if r["exposure"] < 1.0)
    # the background-subtracted weighted centroid beats the paper's plain one on noisy frames
    def med(c):
        return np.mean([r["models"]["near-field"]["median_deg"] for r in rows if r["centroid"] == c])
    assert med("weighted") < med("plain")


@pytest.mark.slow
@requires_jit
def test_default_scan_through_both_presets():
    """Issue targets at a sensible exposure (0.8 of full well), default scan, three noise seeds."""
    from shinysim.studies.exposure import exposure_sweep

    result = exposure_sweep(exposures=(0.8,), centroids=("weighted",))
    rows = {r["preset"]: r for r in result["rows"]}
    assert rows["machine_vision_12bit"]["models"]["near-field"]["worst_median_deg"] <= 0.08
    tv = rows["tv_1980s_8bit"]
    assert tv["exactly_21"] == tv["runs"]
    assert tv["models"]["near-field"]["worst_median_deg"] <= 0.2
