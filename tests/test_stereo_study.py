"""Structured-highlight stereo end to end: rendered scenes, matched, scored, and the command line."""

from __future__ import annotations

import csv
import json

import pytest
from conftest import requires_jit

from shinysim.errors import OptionError, StereoError
from shinysim.recon.stereo import StereoParams, highlight_rays, match_highlights, match_stacks
from shinysim.rig import dome
from shinysim.studies.stereo import (
    STEREO_FILES,
    check_stereo_inputs,
    stereo_rig,
)


def test_options_are_checked_before_any_work():
    ok = dict(scene="sphere", rig="dome", beta_deg=15.0, alpha=0.02, resolution=128, spp=4, n_sources=200, seed=0)
    check_stereo_inputs(**ok)
    for field, bad in (("scene", "cube"), ("rig", "ring"), ("beta_deg", 0.0), ("beta_deg", 60.0), ("alpha", 0.0),
                       ("resolution", 8), ("spp", 0), ("n_sources", 5), ("seed", -1)):
        with pytest.raises(OptionError) as exc:
            check_stereo_inputs(**{**ok, field: bad})
        assert field in str(exc.value)


def test_one_camera_rig_is_refused():
    rig = dome(n_sources=40, resolution=64)
    with pytest.raises(StereoError, match="camera"):
        highlight_rays([1.0], [1.0], [0], rig, 0)


def test_shiny_stereo_rig_drops_the_fibers_in_the_cameras_view():
    rig = stereo_rig("shiny", resolution=64)
    # the 6 mm field's view pyramid at the fibers is 2.8 mm wide: the +-12 deg fibers
    # stand in the +-15 deg cameras' views and are removed; the other 19 stay
    assert rig.n_sources == 19
    assert sorted(rig.metadata["sources_removed_for_cameras"]) == [9, 12]


def test_no_candidate_pairs_is_an_empty_result_that_says_why():
    rig = stereo_rig("dome", resolution=64, n_sources=100)
    # two highlights whose rays pass far apart (opposite image corners)
    r1 = highlight_rays([2.0], [2.0], [0], rig, 0)
    r2 = highlight_rays([60.0], [60.0], [1], rig, 1)
    m = match_highlights(r1, r2, rig, StereoParams())
    assert len(m) == 0 and m.reason


@requires_jit
def test_stacks_that_do_not_share_sources_are_refused():
    from shinysim.recon import reconstruct
    from shinysim.sim.render import Simulator
    from shinysim.studies.stereo import stereo_scene

    rig = stereo_rig("dome", resolution=48, n_sources=60)
    objects, _ = stereo_scene("sphere")
    sim = Simulator(rig, objects)
    stacks = []
    for k in range(2):
        sim.use_camera(k)
        stacks.append(sim.render_stack(spp=2, seed=k))
    recons = [reconstruct(s, models=()) for s in stacks]
    with pytest.raises(StereoError, match="both stacks come from camera 0"):
        match_stacks(stacks[0], stacks[0], tables=[recons[0].table, recons[0].table])
    # a stack of fewer frames: the cameras must see the same sources
    from shinysim.io import Stack

    fewer = Stack(stacks[1].frames[:-1], _drop_last_source(rig), camera_index=1)
    with pytest.raises(StereoError, match="frames"):
        match_stacks(stacks[0], fewer)
    moved = Stack(stacks[1].frames, _shifted_sources(rig), camera_index=1)
    with pytest.raises(StereoError, match="different sources"):
        match_stacks(stacks[0], moved, tables=[recons[0].table, recons[1].table])


def _drop_last_source(rig):
    from shinysim.rig import Rig

    return Rig(source_positions=rig.source_positions[:-1], source_radii=rig.source_radii[:-1], cameras=rig.cameras)


def _shifted_sources(rig):
    from shinysim.rig import Rig

    return Rig(source_positions=rig.source_positions + [0.1, 0.0, 0.0], source_radii=rig.source_radii,
               cameras=rig.cameras)


@requires_jit
def test_stereo_command_end_to_end(tmp_path, capsys):
    from shinysim.cli import main

    out = tmp_path / "st"
    rc = main(["stereo", "--out", str(out), "--resolution", "160", "--n-sources", "400", "--spp", "4", "--quiet"])
    text = capsys.readouterr().out
    assert rc == 0, text
    assert sorted(p.name for p in out.iterdir()) == sorted(STEREO_FILES)
    score = json.loads((out / "stereo_score.json").read_text())
    for key in ("position_error_um", "normal_error_deg"):
        assert set(score[key]) >= {"median", "p95", "max"}
    for model in ("perspective", "orthographic", "fixed", "near-field"):
        assert set(score["single_camera"][model]["normal_error_deg"]) >= {"median", "p95", "max"}
    # scored against the exact highlights of the sphere: every one in view is detected, and the issue's
    # targets hold at this small size (measured: 100 % detected, recall 90.9 % of 317, no false match)
    assert min(score["detection_recall"]) >= 0.95
    assert score["matchable_truth"] > 200
    assert score["recall"] >= 0.8 and score["false_match_rate"] <= 0.01
    assert 0 <= score["recall_detected"] <= 1
    with open(out / "matches.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == score["n_matches"] > 0
    # the match points are where the stereo pair says; a single camera puts the same
    # highlights on the reference plane, 0.8 mm and more below the raised sphere
    assert score["position_error_um"]["median"] < 0.1 * score["single_camera"]["perspective"]["position_error_um"][
        "median"]
    assert "stereo" in text and "recall" in text
    # never replaced without --overwrite
    assert main(["stereo", "--out", str(out), "--resolution", "160", "--n-sources", "400", "--spp", "4",
                 "--quiet"]) != 0


def _run_scene(tmp_path, scene, rig="dome", **kw):
    from shinysim.studies.stereo import run_stereo

    return run_stereo(tmp_path / scene, scene=scene, rig=rig, plot=False, **kw)


@requires_jit
@pytest.mark.parametrize("scene", ["sphere", "three_spheres"])
def test_rendered_semicircle_pair_at_small_size(tmp_path, scene):
    """The dense semicircle (2.5 deg fibers: 2 beta is 12 spacings) at 256 px, 8 spp, with the normal limits
    derived from the highlights (at 23 um pixels one pixel of the calibration sphere is 1.7 deg of normal);
    the normal target belongs to the full-size test below."""
    score = _run_scene(tmp_path, scene, rig="semicircle", resolution=256, spp=8)
    assert score["n_matches"] >= 30
    assert score["position_error_um"]["median_px"] <= 2.0
    assert score["false_match_rate"] <= 0.01
    assert score["recall"] >= 0.8
    # a single camera puts the highlights on the reference plane, the height of the raised spheres away
    best = score["single_camera"][score["best_single_camera"]]["on_matched_highlights"]
    assert best["position_error_um"]["median"] > 20 * score["position_error_um"]["median"]


@pytest.mark.slow
@requires_jit
@pytest.mark.parametrize("scene,rig", [("sphere", "dome"), ("three_sizes", "dome"), ("sphere", "crossing_arcs"),
                                       ("three_sizes", "crossing_arcs")])
def test_rendered_targets(tmp_path, scene, rig):
    """The stereo issue's targets at full size (512 px, 16 spp; the dome of 1000 sources, or the two crossing
    21-fiber arcs), scored against the exact highlights and surface: recall of the exact matchable highlights
    >= 80 %, false matches <= 1 %, position <= 2 px-eq and normal <= 0.3 deg (medians)."""
    score = _run_scene(tmp_path, scene, rig=rig)
    assert min(score["detection_recall"]) >= 0.95
    if score["matchable_truth"]:
        assert score["recall"] >= 0.8
    assert score["false_match_rate"] <= 0.01
    assert score["position_error_um"]["median_px"] <= 2.0
    assert score["normal_error_deg"]["median"] <= 0.3
    best = score["best_single_camera"]
    on = score["single_camera"][best]["on_matched_highlights"]
    assert on["normal_error_deg"]["median"] > score["normal_error_deg"]["median"]
