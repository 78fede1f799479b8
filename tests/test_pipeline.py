"""reconstruct() on whole stacks: tables, normal maps, and bad stacks named."""

import numpy as np
import pytest

from shinysim.io import Stack, StackFormatError
from shinysim.recon import FrameError, reconstruct, sparse_normal_map
from shinysim.rig import Camera, distant_rig


def rig3():
    cam = Camera("orthographic", 40, 30, [0, 0, 100], [0, 0, 0], [0, 1, 0], 40.0)
    return distant_rig([[0, 0, 1], [0.5, 0, 1], [-0.5, 0.2, 1]], cam)


def spot(r0, c0, amp=1.0):
    rows, cols = np.indices((30, 40))
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
    with pytest.raises(FrameError, match="S001: frame is saturated"):
        reconstruct(Stack(frames, rig3()), saturation=1.0)


def test_sparse_map_averages_collisions():
    n = np.array([[1.0, 0, 0], [0, 1.0, 0]])
    m, valid = sparse_normal_map([2.2, 1.8], [3.0, 3.1], n, (5, 5))
    assert valid.sum() == 1
    np.testing.assert_allclose(m[2, 3], np.array([1, 1, 0]) / np.sqrt(2), atol=1e-6)
