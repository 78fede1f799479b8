"""Highlights of complex objects on synthetic frames: several per source, subdivision, flags, toe."""

import numpy as np
import pytest

from shinysim.conventions import bisector, normalize
from shinysim.io import Stack
from shinysim.recon.detect import _split
from shinysim.recon.highlights import (
    HighlightParams,
    blob_area,
    find_highlights,
    find_toe,
    normals_at_points,
    select_band,
)
from shinysim.rig import shiny_1988

RES = 64


@pytest.fixture
def rig():
    return shiny_1988(resolution=RES)


def stack_with(rig, frames):
    return Stack(np.asarray(frames, np.float32), rig)


def test_several_highlights_per_source_and_the_dim_flag(rig):
    f = np.zeros((21, RES, RES), np.float32)
    f[0, 20:40, 20] = 1.0   # a bright (direct) highlight
    f[0, 20:40, 40] = 0.3   # a dim one in the same frame (an inter-reflection)
    f[5, 30:33, 30:33] = 0.1  # a frame holding only a dim highlight stays dim
    t = find_highlights(stack_with(rig, f), smooth_px=0, threshold=0.05, max_area=None, dim_fraction=0.5)
    assert t.reference == pytest.approx(1.0)
    k0 = t["source"] == 0
    assert k0.sum() == 2
    order = np.argsort(t["col"][k0])
    assert np.allclose(t["col"][k0][order], [20, 40])
    assert t["interreflection"][k0][order].tolist() == [False, True]
    k5 = t["source"] == 5
    assert k5.sum() == 1 and t["interreflection"][k5].all()
    assert t["rel_peak"][k5] == pytest.approx(0.1)
    # the flag rule can be switched off
    t2 = find_highlights(stack_with(rig, f), smooth_px=0, threshold=0.05, max_area=None, flag_rule="none")
    assert not t2["interreflection"].any()


def test_large_highlights_are_subdivided(rig):
    f = np.zeros((21, RES, RES), np.float32)
    f[3, 10:40, 31] = 1.0  # 30 pixels
    t = find_highlights(stack_with(rig, f), smooth_px=0, max_area=8)
    assert len(t["row"]) == 4  # ceil(30 / 8)
    assert (t["blob"] == t["blob"][0]).all() and sorted(t["part"].tolist()) == [1, 2, 3, 4]
    assert (blob_area(t) == 30).all()
    assert np.mean(t["row"]) == pytest.approx(24.5, abs=0.5)


def test_a_streak_is_cut_at_its_weight_quantiles_whatever_its_direction(rig):
    f = np.zeros((21, RES, RES), np.float32)
    f[3, 10:40, 31] = 1.0
    f[4, 31, 10:40] = 1.0  # the same streak along the rows
    t = find_highlights(stack_with(rig, f), smooth_px=0, max_area=8)
    # 30 equal pixels in 4 parts: halves of 15 (an exact share, whatever the rounding of 1/30), then 8 + 7 each
    # (a pixel that straddles a share by exactly half goes to the part nearer the streak's start)
    for source, along in ((3, "row"), (4, "col")):
        k = t["source"] == source
        assert t["area"][k].tolist() == [8, 7, 8, 7] and t["part"][k].tolist() == [1, 2, 3, 4]
        assert t[along][k].tolist() == [13.5, 21.0, 28.5, 36.0]


def _parts(coords, weights, n_parts):
    """The parts of detect._split as sets of pixels, in the order it gives them."""
    return [frozenset(map(tuple, coords[idx].astype(int).tolist())) for idx in _split(coords, weights, n_parts)]


def test_subdivision_is_the_same_for_any_order_of_the_pixels(np_rng):
    # a tilted streak two pixels wide, weights rising along it: parts depend on the pixel set alone
    rows = np.repeat(np.arange(10, 40), 2)
    cols = rows // 3 + np.tile([0, 1], 30)
    coords = np.stack([rows, cols], 1).astype(float)
    weights = 1.0 + 0.1 * (rows - 10) + 0.01 * np.tile([0, 1], 30)
    expect = _parts(coords, weights, 7)
    assert len(expect) == 7 and sum(map(len, expect)) == 60
    for _ in range(5):
        order = np_rng.permutation(60)
        assert _parts(coords[order], weights[order], 7) == expect
    # a square of equal pixels (no principal axis: the row axis), and the tie within each row: raster order
    sq = np.stack(np.meshgrid(np.arange(4), np.arange(4), indexing="ij"), -1).reshape(-1, 2).astype(float)
    halves = _parts(sq, np.ones(16), 2)
    assert halves == [frozenset((r, c) for r in (0, 1) for c in range(4)),
                      frozenset((r, c) for r in (2, 3) for c in range(4))]
    assert _parts(sq[::-1], np.ones(16), 2) == halves


def test_a_mirrored_streak_splits_mirrored():
    rows = np.arange(10, 40)
    coords = np.stack([rows, np.full(30, 31)], 1).astype(float)
    weights = np.arange(1.0, 31.0)  # a ramp: no part of 4 is the mirror of another (4: a power of two of parts)
    parts = _parts(coords, weights, 4)
    mirrored = _parts(np.stack([49 - rows, np.full(30, 31)], 1).astype(float), weights, 4)
    assert sorted(map(sorted, mirrored)) == sorted(sorted((49 - r, c) for r, c in p) for p in parts)
    # each cut at the pixel boundary nearest its share: halves of 231 and 234 (of 465; the next boundary gives
    # 253), then quarters of 120 + 111 and 120 + 114
    assert [sorted(r for r, _ in p) for p in parts] == [list(range(10, 25)), list(range(25, 31)),
                                                         list(range(31, 36)), list(range(36, 40))]


def test_normals_and_positions_on_the_plane(rig):
    f = np.zeros((21, RES, RES), np.float32)
    f[7, 31:33, 31:33] = 1.0
    t = find_highlights(stack_with(rig, f), smooth_px=0, plane_z=0.035)
    assert len(t["row"]) == 1
    p = rig.camera.backproject_to_plane(t["row"], t["col"], 0.035).reshape(-1, 3)
    assert np.allclose([t["x"][0], t["y"][0]], p[0, :2])
    s = normalize(rig.source_positions[7] - p[0])
    v = normalize(rig.camera.position - p[0])
    assert np.allclose(t["normal"][0], bisector(s, v), atol=1e-12)
    band = select_band(t, 0.0, 0.1)
    assert band.tolist() == [0]
    with pytest.raises(ValueError, match="half_width must be > 0"):
        select_band(t, 0.0, 0.0)


def test_mirror_normals_use_the_source_image_below_the_pad(rig):
    stack = stack_with(rig, np.zeros((21, RES, RES)))
    pts = np.array([[0.1, 0.0, 0.2], [-0.3, 0.05, 0.1]])
    src = np.array([0, 4])
    n = normals_at_points(pts, src, stack, mirror_z=0.035)
    for i in range(2):
        s = rig.source_positions[src[i]].copy()
        s[2] = 2 * 0.035 - s[2]
        expect = bisector(s - pts[i], rig.camera.position - pts[i])
        assert np.allclose(n[i], expect, atol=1e-12)
    # a source 84 deg off axis: the direct normal tilts ~42 deg, the bounce normal ~48 deg
    d = normals_at_points(np.zeros((1, 3)), [0], stack)
    m = normals_at_points(np.zeros((1, 3)), [0], stack, mirror_z=0.0)
    assert np.degrees(np.arccos(d[0, 2])) == pytest.approx(42.0, abs=0.2)
    assert np.degrees(np.arccos(m[0, 2])) == pytest.approx(48.0, abs=0.2)


def test_find_toe_is_subpixel_exact(rig):
    f = np.zeros((21, RES, RES), np.float32)
    for k in (10, 11):  # the sources nearest the axis light the pad
        f[k, :, 5:30] = 1.0
        f[k, :, 30] = 0.5
    stack = stack_with(rig, f)
    x = find_toe(stack, smooth_px=0, plane_z=0.035, min_run_mm=0.1)
    expect = rig.camera.backproject_to_plane(31.5, 30.0, 0.035)[0]
    assert x == pytest.approx(expect, abs=1e-9)
    # given the first fillet point, the pad run ending before it
    assert find_toe(stack, x_before=expect + 0.01, smooth_px=0, plane_z=0.035) == pytest.approx(x, abs=1e-12)
    # the first fillet point may lie up to two pixels before the edge (a shallow foot), not more
    px = rig.camera.pixel_pitch
    assert find_toe(stack, x_before=expect - 1.5 * px, smooth_px=0, plane_z=0.035) == pytest.approx(x, abs=1e-12)
    assert np.isnan(find_toe(stack, x_before=expect - 2.5 * px, smooth_px=0, plane_z=0.035))
    # nothing lit: no toe
    assert np.isnan(find_toe(stack_with(rig, np.zeros((21, RES, RES))), smooth_px=0))
    with pytest.raises(ValueError, match="level must be in"):
        find_toe(stack, level=1.5)


def test_highlight_params_checks():
    with pytest.raises(ValueError, match="threshold must be in"):
        HighlightParams(threshold=0)
    with pytest.raises(ValueError, match="flag_rule must be one of"):
        HighlightParams(flag_rule="bright")
    with pytest.raises(ValueError, match="model must be one of"):
        HighlightParams(model="pinhole")
    with pytest.raises(ValueError, match="max_area must be >= 4"):
        HighlightParams(min_area=4, max_area=2)
    with pytest.raises(TypeError, match="stack must be a shinysim.io.Stack"):
        find_highlights(np.zeros((21, 4, 4)))


def test_empty_stack_gives_an_empty_table(rig):
    t = find_highlights(stack_with(rig, np.zeros((21, RES, RES))))
    assert len(t["row"]) == 0 and t["normal"].shape == (0, 3) and t.reference == 0.0
