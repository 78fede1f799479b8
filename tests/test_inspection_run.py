"""The solder-inspection study end to end, at CI size (the full size is benchmarks/solder_inspection.py)."""

import json

import pytest
from conftest import requires_jit

from shinysim.objects.criteria import CLASSES, judge
from shinysim.objects.solder import PAD_THICKNESS, JointParams
from shinysim.studies.inspection import (
    INSPECTION_FILES,
    NUISANCE_RANGES,
    run_inspection,
)


@requires_jit
def test_small_run_is_consistent_resumable_and_reproducible(tmp_path):
    cache = tmp_path / "cache.jsonl"
    rep = run_inspection(tmp_path / "a", n_train=1, n_test=1, resolution=96, spp=1, seed=5, cache=cache)
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == sorted(INSPECTION_FILES)
    joints = rep["joints"]
    assert len(joints) == 2 * len(CLASSES)
    for r in joints:
        # the class is the criteria's verdict on the joint's geometry, whatever generator made it
        assert r["label"] == judge(JointParams.from_dict(r["params"])).label
        for name, (lo, hi) in NUISANCE_RANGES.items():
            assert lo <= r["nuisances"][name] <= hi
        # the reconstruction assumed the design pad thickness, not the joint's
        assert r["score"]["pad_top_z_assumed_mm"] == PAD_THICKNESS
        assert r["score"]["pad_top_z_mm"] == r["params"]["pad_thickness"]
    assert {r["split"] for r in joints} == {"train", "test"}
    assert rep["accuracy"]["n"] == len(CLASSES)
    lo, hi = rep["accuracy"]["ci95"]
    assert lo <= rep["accuracy"]["accuracy"] <= hi
    assert sum(map(sum, rep["confusion_matrix"]["counts"])) == len(CLASSES)
    rows = (tmp_path / "a" / "robustness.csv").read_text().splitlines()
    assert len(rows) == 1 + len(rep["robustness"]) == 1 + 2 * (1 + len(NUISANCE_RANGES))
    # every joint went to the cache; a second run reads it instead of rendering, and the
    # report is byte for byte the one a fresh render gave
    assert len(cache.read_text().splitlines()) == 2 * len(CLASSES)
    run_inspection(tmp_path / "b", n_train=1, n_test=1, resolution=96, spp=1, seed=5, cache=cache)
    assert (tmp_path / "a" / "inspection_report.json").read_bytes() == \
        (tmp_path / "b" / "inspection_report.json").read_bytes()
    # a torn last line (an interrupted write) is ignored: that joint is rendered again
    text = cache.read_text().splitlines()
    cache.write_text("\n".join(text[:-1]) + "\n" + text[-1][: len(text[-1]) // 2])
    run_inspection(tmp_path / "c", n_train=1, n_test=1, resolution=96, spp=1, seed=5, cache=cache)
    assert json.loads((tmp_path / "c" / "inspection_report.json").read_text()) == rep


def test_existing_output_is_refused_before_work(tmp_path):
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "inspection_report.json").write_text("{}\n")
    with pytest.raises(FileExistsError, match="inspection_report.json"):
        run_inspection(tmp_path / "out", n_train=1, n_test=1)
    assert (tmp_path / "out" / "inspection_report.json").read_text() == "{}\n"
