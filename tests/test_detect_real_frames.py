"""Detection defaults that hold on real-looking frames: noise, 8-bit quantisation, hot pixels.

A real camera adds noise and quantises; the default detection must then
still find one highlight per source and nothing else. The frames are the
default scan's (alpha = 0.02, 512 px, 64 spp) made "real" as a careless
8-bit camera would: exposed so that the stack's brightest pixel is full
scale, Gaussian noise of 3 % of full scale added, rounded to 8 bits and
clipped.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import requires_jit

from shinysim.io import Stack
from shinysim.recon import DetectParams
from shinysim.recon.pipeline import detect_stack

N_SOURCES = 21


def eight_bit(frames, noise, seed):
    """Frames as an 8-bit camera with Gaussian noise of ``noise`` x full scale would give them (scaled to [0, 1])."""
    rng = np.random.default_rng(seed)
    scaled = frames / frames.max() + rng.normal(0.0, noise, frames.shape)
    return (np.clip(np.rint(scaled * 255), 0, 255) / 255).astype(np.float32)


@pytest.fixture(scope="module")
def renders():
    from shinysim.rig import shiny_1988
    from shinysim.sim.render import Simulator
    from shinysim.sim.scene import sphere_object

    out = {}
    rig = shiny_1988()
    for alpha, spp in ((0.02, 64), (0.1, 32)):
        out[alpha] = Simulator(rig, sphere_object(alpha=alpha)).render_stack(spp=spp, seed=0)
    return out


def one_per_source(recon):
    return sorted(recon.table["source"].tolist()) == list(range(N_SOURCES))


@requires_jit
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_default_scan_with_3_percent_noise_and_8_bits_gives_the_21_highlights(renders, seed):
    clean = detect_stack(renders[0.02])
    stack = renders[0.02]
    noisy = detect_stack(Stack(eight_bit(stack.frames, 0.03, seed), stack.rig, saturation=1.0))
    assert len(clean) == N_SOURCES and one_per_source(clean)
    assert len(noisy) == N_SOURCES and one_per_source(noisy), noisy.table["area"]
    # same highlights: the centroids move by noise only. A 25-pixel highlight whose
    # pixels carry 3 % noise against peaks of ~0.8 full scale moves its weighted
    # centroid by ~0.05 px (sqrt(25) * 0.03 / (25 * 0.4) * ~2 px lever); 0.5 px is
    # ten times that and far below the 20+ px between neighbouring highlights
    shift = np.hypot(noisy.table["row"] - clean.table["row"], noisy.table["col"] - clean.table["col"])
    assert shift.max() < 0.5
    assert noisy.detection["min_area"] >= 2  # derived from the highlight size, not 1 px


@requires_jit
def test_wide_noisy_highlights_do_not_flood_detection(renders):
    """alpha = 0.1 gives highlights of ~450 px whose noisy rims used to break into dozens of 1-3 px islands."""
    stack = renders[0.1]
    for seed in range(2):
        frames = eight_bit(stack.frames, 0.03, seed)
        recon = detect_stack(Stack(frames, stack.rig, saturation=1.0))
        assert len(recon) == N_SOURCES and one_per_source(recon), np.sort(recon.table["area"])
        # the plain paper detection (1-pixel regions, no noise test) is flooded: the
        # defaults above are what prevents it
        plain = detect_stack(Stack(frames, stack.rig, saturation=1.0), DetectParams(min_area=1, false_alarm=0))
        assert len(plain) > N_SOURCES + 5


@requires_jit
def test_hot_pixels_are_replaced_not_detected(renders):
    stack = renders[0.02]
    frames = eight_bit(stack.frames, 0.03, 5)
    rng = np.random.default_rng(7)
    rows, cols = rng.integers(0, 512, 30), rng.integers(0, 512, 30)
    frames[:, rows, cols] = rng.uniform(0.3, 1.0, 30)[None]
    recon = detect_stack(Stack(frames, stack.rig, saturation=1.0))
    assert len(recon) == N_SOURCES and one_per_source(recon)
    assert recon.detection["hot_pixels"] == len(set(zip(rows.tolist(), cols.tolist())))
    # without the hot-pixel test every hot pixel is a highlight in every frame
    off = detect_stack(Stack(frames, stack.rig, saturation=1.0), DetectParams(hot_pixels=False, min_area=1))
    assert len(off) > N_SOURCES + 10 * N_SOURCES  # the hot pixels above a frame's threshold (most of the 30)


@requires_jit
def test_saturated_highlights_are_flagged_or_refused(renders):
    from shinysim.errors import FrameError

    stack = renders[0.02]
    over = (np.clip(stack.frames / stack.frames.max() * 3.0, 0, 1) * 255).round() / 255  # 3x over-exposed, 8-bit
    recon = detect_stack(Stack(over.astype(np.float32), stack.rig, saturation=1.0))
    assert recon.detection["n_saturated"] == len(recon) > 0
    assert recon.table["saturated"].all()
    with pytest.raises(FrameError, match="S000: .*reaches the clip level 1"):
        detect_stack(Stack(over.astype(np.float32), stack.rig, saturation=1.0), DetectParams(saturated="refuse"))
    ignored = detect_stack(Stack(over.astype(np.float32), stack.rig, saturation=1.0), DetectParams(saturated="ignore"))
    assert not ignored.table["saturated"].any()
