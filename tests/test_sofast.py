"""Display deflectometry on a real measurement no one here made: Sandia's SOFAST fixed-pattern facet.

``../shared/data/sofast/`` holds OpenCSP's fixed-pattern measurement of a
1.2 m heliostat facet (one frame of an 85 x 85 dot grid reflected in it) and
SOFAST's own result on it (``SOURCE.md`` there). shinysim reads the files,
finds and indexes the dots, poses the facet from its corners and solves the
slopes; here they are held against SOFAST's at matched dots. Skipped, saying
why, when the folder is absent.

The bounds are the issue's, from an independent reconstruction of the same
data (0.034 mrad RMS, 0.11 mrad max): the two tools differ in their dot
centroids (SOFAST thresholds binary blobs; shinysim weights background-
subtracted dots), in the facet's corners and so in the pose, all of which
the centre alignment mostly absorbs. One wrong dot index would cost one
screen pitch, about 2 mrad: ``n_over_1mrad == 0`` says none was assigned.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from shinysim.cli import main

SOFAST = Path(__file__).resolve().parents[2] / "shared" / "data" / "sofast"
pytestmark = pytest.mark.skipif(not (SOFAST / "fixed" / "measurement_facet.h5").is_file(),
                                reason=f"SOFAST's fixed-pattern measurement is not at {SOFAST}")
pytest.importorskip("h5py", reason="reading SOFAST files needs h5py (the sofast extra)")

#: SOFAST's own count of the dots it used (its calculation file has one slope per dot).
SOFAST_DOTS = 3782


@pytest.fixture(scope="module")
def result():
    from shinysim.studies.deflect import measure_sofast_fixed

    return measure_sofast_fixed(SOFAST)


def test_slopes_agree_with_sofasts_own_result(result):
    vs = result.score["vs_expected"]
    assert vs["expected_points"] == SOFAST_DOTS
    assert vs["matched"] >= 0.98 * SOFAST_DOTS
    for figures in (vs, vs["detilted"]):  # SOFAST's centre alignment on both sides, and tilt + bend removed
        assert figures["rms_mrad"] <= 0.05
        assert figures["p95_mrad"] <= 0.1
        assert figures["max_mrad"] <= 0.3
        assert figures["n_over_1mrad"] == 0


def test_dots_found_and_focal_lengths_match_sofast(result):
    s = result.score
    assert abs(s["dots_found"] - SOFAST_DOTS) <= 0.01 * SOFAST_DOTS
    assert abs(s["dots_identified"] - SOFAST_DOTS) <= 0.01 * SOFAST_DOTS
    assert s["inconsistent"] == 0
    np.testing.assert_allclose(s["focal_lengths_m"], s["vs_expected"]["expected_focal_lengths_m"], rtol=0.02)


def test_no_index_is_off_by_a_pitch(result):
    # every identified dot's index is where its neighbours' indices say: a whole-pitch jump between grid
    # neighbours (dot spacing ~10.4 px) would show as a spacing near 0 or 2 pitches
    m = result.measurement
    idx = m.index.index[m.used]
    pos = np.column_stack([m.dots["row"][m.used], m.dots["col"][m.used]])
    at = {tuple(v): k for k, v in enumerate(idx)}
    gaps = [np.linalg.norm(pos[at[(i + 1, j)]] - pos[k]) for k, (i, j) in enumerate(idx) if (i + 1, j) in at]
    gaps = np.asarray(gaps) / m.index.pitch_px
    assert gaps.min() > 0.6 and gaps.max() < 1.4


def test_the_command_writes_the_contract(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["deflect", "--sofast", str(SOFAST), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "detilted (mrad)" in printed
    header = (out / "slopes.csv").read_text().splitlines()[0]
    assert header == "x_m,y_m,z_m,slope_x,slope_y"
    table = np.loadtxt(out / "slopes.csv", delimiter=",", skiprows=1)
    score = json.loads((out / "score.json").read_text())
    assert table.shape == (score["dots_identified"], 5)
    assert np.all(np.abs(table[:, :2]) < 0.62)  # on the 1.212 m square facet, metres
    assert np.all(np.abs(table[:, 3:]) < 0.01)  # slopes of a heliostat facet: a few mrad, radians
    for key in ("dots_found", "dots_identified", "focal_lengths_m"):
        assert key in score
    vs = score["vs_expected"]
    for key in ("matched", "rms_mrad", "p95_mrad", "max_mrad", "n_over_1mrad"):
        assert key in vs
        assert key == "matched" or key in vs["detilted"]
    with np.load(out / "slopes.npz") as z:
        np.testing.assert_allclose(z["points_mm"] / 1e3, table[:, :3], rtol=1e-8, atol=1e-12)
    assert (out / "deflect.png").stat().st_size > 10_000
    # the same folder again is refused, naming what is there
    assert main(["deflect", "--sofast", str(SOFAST), "--out", str(out)]) == 1
    assert "already holds slopes.csv" in capsys.readouterr().err


def test_a_folder_without_the_measurement_is_named(tmp_path, capsys):
    (tmp_path / "common").mkdir()
    shutil.copy(SOFAST / "common" / "camera_sofast.h5", tmp_path / "common")
    assert main(["deflect", "--sofast", str(tmp_path), "--out", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert "no fixed-pattern or fringe measurement" in err and "Traceback" not in err
    assert not (tmp_path / "out").exists()


def test_a_camera_of_another_image_size_is_refused(tmp_path, capsys):
    folder = tmp_path / "sofast"
    shutil.copytree(SOFAST, folder, ignore=shutil.ignore_patterns("fringe"))
    import h5py

    with h5py.File(folder / "common" / "camera_sofast.h5", "r+") as h:
        h["Camera/image_shape_xy"][...] = np.array([[800], [600]])
    assert main(["deflect", "--sofast", str(folder), "--out", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert "800 x 600" in err and "camera_sofast.h5" in err


def test_a_calculation_of_the_other_kind_is_refused(tmp_path, capsys):
    assert main(["deflect", "--sofast", str(SOFAST), "--expected", str(SOFAST / "fringe" / "expected_data.h5"),
                 "--out", str(tmp_path / "a")]) == 1
    assert "result of a fringe measurement" in capsys.readouterr().err
    assert main(["deflect", "--sofast", str(SOFAST), "--mode", "fringe", "--expected",
                 str(SOFAST / "fixed" / "expected_calculation_facet.h5"), "--out", str(tmp_path / "b")]) == 1
    assert "result of a fixed-pattern measurement" in capsys.readouterr().err
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
