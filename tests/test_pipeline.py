"""reconstruct() on whole stacks: tables, normal maps, and bad stacks named."""

import numpy as np
import pytest

from shinysim.io import Stack, StackFormatError
from shinysim.recon import FrameError, reconstruct, sparse_normal_map
from shinysim.rig import Camera, distant_rig


def rig3():
    cam = Camera("orthographic", 40, 30, [0, 0, 100], [0, 0, 0], [0, 1, 0], 40.0)
    return distant_rig([[0, 0, 1], [0.5, 0, 1], [-0.5, 0.2, 1]], cam)


def spot(r0, c0, amp=1.0, shape=(30, 40)):
    rows, cols = np.indices(shape)
    return amp * np.exp(-((rows - r0) ** 2 + (cols - c0) ** 2) / 3.0)


def test_table_and_normal_maps():
    frames = np.stack([spot(10, 10), spot(20, 30) + spot(5, 35, 0.9), np.zeros((30, 40))])
    rec = reconstruct(Stack(frames, rig3()), threshold=0.5)
    assert list(rec.table["source"]) == [0, 1, 1]
    assert rec.empty_sources == [2]
    nmap, valid = rec.normal_map("fixed")
    assert valid.sum() == 3
    assert np.all(np.isnan(nmap[~valid]))
    np.testing.assert_allclose(nmap[10, 10], [0, 0, 1], atol=1e-12)


def test_empty_stack_is_an_error():
    with pytest.raises(StackFormatError, match="stack is empty"):
        reconstruct(Stack(np.zeros((3, 30, 40)), rig3()))


def test_saturated_frame_is_named():
    frames = np.stack([spot(10, 10), np.ones((30, 40)), spot(3, 3)])
    with pytest.raises(FrameError, match="S001: frame is over-exposed"):
        reconstruct(Stack(frames, rig3()), saturation=1.0)


def test_sparse_map_averages_collisions():
    n = np.array([[1.0, 0, 0], [0, 1.0, 0]])
    m, valid = sparse_normal_map([2.2, 1.8], [3.0, 3.1], n, (5, 5))
    assert valid.sum() == 1
    np.testing.assert_allclose(m[2, 3], np.array([1, 1, 0]) / np.sqrt(2), atol=1e-6)


def test_one_pipeline_behind_reconstruct_and_find_highlights():
    """find_highlights (solder) is detect_stack with scan-relative threshold, smoothing, subdivision and flags."""
    from shinysim.recon import HighlightParams, detect_stack, find_highlights
    from shinysim.rig import shiny_1988

    rig = shiny_1988(resolution=40)
    f = np.zeros((21, 40, 40), np.float32)
    f[0] = spot(10, 10, shape=(40, 40)) + spot(25, 25, 0.3, (40, 40))  # a direct and a dim highlight
    f[1, 5:9, 5:30] = 1.0                                              # a long blob that max_area subdivides
    f[2] = spot(20, 20, 0.2, (40, 40))                                 # a frame holding only a dim highlight
    stack = Stack(f, rig)
    hp = HighlightParams(smooth_px=0.7, threshold=0.1, max_area=12)
    det = hp.detect_params()
    t = find_highlights(stack, hp, plane_z=0.035)
    rec = reconstruct(stack, det, models=(hp.model,), plane_z=0.035)
    table = detect_stack(stack, det).table
    for k in ("source", "row", "col", "area", "peak", "sum", "blob", "part", "rel_peak", "interreflection"):
        np.testing.assert_array_equal(t[k], rec.table[k], err_msg=k)
        np.testing.assert_array_equal(t[k], table[k], err_msg=k)
    np.testing.assert_array_equal(t["normal"], rec.normals[hp.model])
    assert t.reference == rec.reference > 0
    # what each option did: several per frame, a subdivided blob, dim highlights flagged
    assert len(set(t["blob"][t["source"] == 0])) == 2
    assert np.count_nonzero(t["source"] == 1) >= 8 and set(t["part"][t["source"] == 1]) >= {1, 2}
    assert t["interreflection"].tolist() == [bool(r < 0.5) for r in t["rel_peak"]]
    assert t["interreflection"][t["source"] == 2].all() and not t["interreflection"][t["source"] == 1].any()


def test_a_scan_threshold_needs_the_whole_stack():
    from shinysim.recon import DetectParams, detect_highlights

    with pytest.raises(ValueError, match="detect_stack"):
        detect_highlights(spot(10, 10), DetectParams(threshold=0.5, threshold_mode="scan"))
    with pytest.raises(ValueError, match=r"scan threshold must be in \(0, 1\]"):
        DetectParams(threshold=2.0, threshold_mode="scan")
