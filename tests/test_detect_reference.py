"""detect_stack (one vectorised engine) against the simple reference of tests/reference_detect.py.

The reference is scikit-image's ``label`` and ``regionprops``, every
statistic over whole float64 frames, one region at a time. The engine
labels whole frames with ``scipy.ndimage.label`` and measures regions by
per-region sums in another order, and estimates a mostly-zero frame's noise
from its nonzero pixels. Held to: the same highlights (count, areas, labels,
parts, flags, peaks: exactly), empty sources, reference level and errors
(type, message, field) exactly; centroids to 1e-9 px and sums and noise
estimates to a relative 1e-12 (the same float64 sums in another order
differ by a few units in the last place, 1e-16 relative, i.e. ~1e-13 px on
a 512-px coordinate; the margins are far below any use). Stacks are drawn
with numpy (no renderer): rendered-like frames (a compact highlight with a
halo that fades to exact zeros, scattered Monte Carlo fireflies),
camera-like frames (noise, dark offsets, 8-bit quantisation, hot pixels,
clipping), several highlights per frame, empty frames, highlights at the
border; and random stacks and settings (hypothesis).
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from conftest import requires_jit
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from shinysim._shared import with_overrides
from shinysim.errors import ShinysimError
from shinysim.io import Stack
from shinysim.recon import DetectParams, reconstruct
from shinysim.recon.detect import estimate_noise, sparse_noise
from shinysim.recon.pipeline import detect_stack
from shinysim.rig import Camera, distant_rig

from reference_detect import reference_detect_stack

#: Centroids are the same sums in another order (see the module docstring); 1e-9 px
#: is far below any use and far above a last-bit difference of a 512-px coordinate.
CENTROID_ATOL = 1e-9
#: Sums of weights and noise estimates: the same float64 sums in another order.
SUM_RTOL = 1e-12


def rig_for(n, H, W):
    cam = Camera("orthographic", W, H, [0, 0, 100], [0, 0, 0], [0, 1, 0], 40.0)
    angles = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return distant_rig(np.stack([0.3 * np.cos(angles), 0.3 * np.sin(angles), np.ones(n)], axis=1), cam)


def rendered_like(n=21, H=128, W=128, seed=0, fireflies=300, peak=0.1):
    """Frames as a renderer leaves them: one compact highlight per frame with a halo, fireflies, exact zeros.

    The profile follows a rendered sphere scan (alpha 0.02, 64 spp): a
    core of about 2 px, a tail that is 3e-3 of the peak at 15 px and fully
    lit to 20 px, thinning out (Monte Carlo) beyond; scattered single-pixel
    fireflies at 1e-5 to 1e-3 of the peak; every other pixel exactly 0.
    """
    rng = np.random.default_rng(seed)
    rows, cols = np.indices((H, W), dtype=float)
    frames = np.zeros((n, H, W), np.float32)
    angles = np.linspace(0, 2 * np.pi, n, endpoint=False)
    for k in range(n):
        r0 = H / 2 + 0.3 * H * np.sin(angles[k]) + rng.uniform(-0.5, 0.5)
        c0 = W / 2 + 0.3 * W * np.cos(angles[k]) + rng.uniform(-0.5, 0.5)
        d = np.hypot(rows - r0, cols - c0)
        p = peak * rng.uniform(0.8, 1.0)
        f = p * (0.8 * np.exp(-d**2 / (2 * 1.8**2)) + 0.35 / (1 + (d / 3) ** 3))
        shape = 4.0 + 400.0 * f / p  # Monte Carlo noise: about 5 % in the core, 50 % in the tail
        f *= rng.gamma(shape, 1.0 / shape)
        keep = rng.random(f.shape) < np.where(d < 20, 1.0, np.where(d < 30, 0.8, np.where(d < 60, 0.13, 0.0)))
        f = np.where(keep, f, 0.0)
        m = rng.integers(0, H * W, fireflies)
        f.reshape(-1)[m] = p * 10 ** rng.uniform(-5, -3, fireflies)
        frames[k] = f
    return frames


def camera_like(frames, noise=0.03, offset=0.0, seed=0, bits=8):
    """The frames as a camera gives them: scaled to full scale, a dark offset, Gaussian noise, quantised, clipped."""
    rng = np.random.default_rng(seed)
    scaled = frames / frames.max() + offset + rng.normal(0.0, noise, frames.shape)
    levels = 2**bits - 1
    return (np.clip(np.rint(scaled * levels), 0, levels) / levels).astype(np.float32)


class Outcome:
    """detect_stack's result or the error it raised (type, message, field), and the warnings it gave."""

    def __init__(self, stack, method, **kwargs):
        self.result, self.error = None, None
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                if method == "reference":
                    given = dict(kwargs)
                    mask, params = given.pop("mask", None), given.pop("params", None)
                    self.result = reference_detect_stack(stack, with_overrides(DetectParams, params, given), mask)
                else:
                    self.result = detect_stack(stack, **kwargs)
            except (ShinysimError, ValueError) as exc:
                self.error = (type(exc), str(exc), getattr(exc, "field", None))
        self.warnings = [(w.category, str(w.message)) for w in caught]


def outcome(stack, method, **kwargs):
    return Outcome(stack, method, **kwargs)


def assert_same(fast, ref):
    """The engine's outcome is the reference's (see the module docstring)."""
    if isinstance(fast, Outcome):
        # a subdivided part with no weight above the background gets a NaN centroid and numpy's
        # warning, in both alike
        assert fast.warnings == ref.warnings
        assert fast.error == ref.error
        if ref.error is not None:
            return
        fast, ref = fast.result, ref.result
    assert list(fast.table) == list(ref.table)
    for key in ref.table:
        a, b = fast.table[key], ref.table[key]
        assert a.dtype == b.dtype and a.shape == b.shape, key
        if key in ("row", "col"):
            np.testing.assert_allclose(a, b, rtol=0, atol=CENTROID_ATOL, err_msg=key)
        elif key == "sum":
            np.testing.assert_allclose(a, b, rtol=SUM_RTOL, atol=0, err_msg=key)
        else:
            np.testing.assert_array_equal(a, b, err_msg=key)
    assert fast.detection.keys() == ref.detection.keys()
    for key in ref.detection:
        if key == "noise_sigma":
            np.testing.assert_allclose(fast.detection[key], ref.detection[key], rtol=SUM_RTOL, atol=0)
        else:
            assert fast.detection[key] == ref.detection[key], key
    assert [type(v) for v in fast.detection.values()] == [type(v) for v in ref.detection.values()]
    assert fast.empty_sources == ref.empty_sources
    assert fast.reference == ref.reference and math.copysign(1, fast.reference) == math.copysign(1, ref.reference)
    assert fast.shape == ref.shape and fast.params == ref.params and fast.notes == ref.notes


def check(frames, saturation=None, rig=None, **kwargs):
    frames = np.asarray(frames, np.float32)
    stack = Stack(frames, rig or rig_for(*frames.shape), saturation=saturation)
    fast, ref = outcome(stack, "fast", **kwargs), outcome(stack, "reference", **kwargs)
    assert_same(fast, ref)
    return fast if fast.error is not None else fast.result


# -- the exact statistics --------------------------------------------------------------------------


@pytest.mark.parametrize("shape", [(1, 1), (1, 2), (3, 1), (5, 2), (17, 23), (64, 64)])
def test_noise_from_the_nonzero_pixels_is_estimate_noise(shape):
    """sparse_noise: estimate_noise's root-mean-square branch from the nonzero pixels, or None where it does not apply."""
    rng = np.random.default_rng(shape[0] * 100 + shape[1])
    H, W = shape
    tested = 0
    for trial in range(40):
        frame = np.zeros(shape, np.float32)
        m = rng.integers(0, H * W // 4 + 2)
        frame.reshape(-1)[rng.integers(0, H * W, m)] = rng.exponential(size=m) * 10.0 ** rng.uniform(-8, 1)
        if trial % 4 == 0:
            frame[:, 0] = frame[:, -1] = 1e-3  # nonzero first and last columns: rows end there
        if trial % 5 == 0:
            frame[frame > 0] = 0.25  # runs of equal values
        idx = np.flatnonzero(frame)
        got = sparse_noise(frame.shape, idx, frame.reshape(-1)[idx])
        if got is None:  # not mostly zero differences: the whole frame's estimate is used
            d = np.diff(frame.astype(np.float64), axis=-1)
            assert 2 * np.count_nonzero(d == 0) <= d.size
            continue
        tested += 1
        assert got == pytest.approx(estimate_noise(frame), rel=SUM_RTOL, abs=0), trial
    assert tested >= 10


# -- whole stacks -------------------------------------------------------------------------------


def test_rendered_like_sphere_stack():
    rec = check(rendered_like())
    assert sorted(rec.table["source"].tolist()) == list(range(21))  # one highlight per source
    assert rec.detection["hot_pixels"] == 0 and rec.detection["min_area"] >= 2
    assert all(s > 0 for s in rec.detection["noise_sigma"])  # the root-mean-square branch, from the nonzero pixels


@pytest.mark.slow
def test_rendered_like_sphere_stack_full_size():
    check(rendered_like(H=512, W=512, fireflies=1400))


@pytest.mark.parametrize("kwargs", [
    {},
    {"threshold": 0.05},
    {"threshold": 0.002, "threshold_mode": "absolute"},
    {"threshold": 0.2, "threshold_mode": "scan", "flag_rule": "dim"},
    {"smooth_px": 0.7},
    {"max_area": 5},
    {"centroid": "plain", "connectivity": 1},
    {"min_area": 3, "false_alarm": 0},
    {"noise_sigma": 1e-4},
    {"hot_pixels": False, "subtract_background": False},
])
def test_rendered_like_stack_under_each_setting(kwargs):
    check(rendered_like(n=9, H=64, W=80, seed=3, fireflies=150), **kwargs)


@pytest.mark.parametrize("noise, offset", [(0.03, 0.0), (0.01, 0.05), (0.0, 0.02)])
def test_camera_like_frames(noise, offset):
    """Noise everywhere (dense frames: the reference's statistics per frame), dark offsets, 8 bits."""
    frames = camera_like(rendered_like(n=9, H=48, W=64, seed=2, fireflies=60), noise=noise, offset=offset)
    rec = check(frames, saturation=1.0)
    if offset:
        assert min(rec.detection["background"]) > 0


def test_hot_pixels_in_rendered_and_camera_frames():
    frames = rendered_like(n=9, H=48, W=64, seed=4, fireflies=60)
    rng = np.random.default_rng(7)
    r, c = rng.integers(1, 47, 12), rng.integers(1, 63, 12)
    frames[:, r, c] = rng.uniform(0.01, 0.05, 12)[None]
    rec = check(frames)
    assert rec.detection["hot_pixels"] == len(set(zip(r.tolist(), c.tolist())))
    check(camera_like(frames, noise=0.02))
    check(frames, hot_pixels=False, min_area=1)
    lit = frames.copy()
    lit[:, 10:30, 10:30] += 1e-6  # a glow lit in every frame
    check(lit)


def test_frames_lit_everywhere_with_a_hot_pixel(monkeypatch):
    """Every pixel above its frame's noise level in every frame (a lit board under a joint): every pixel is a
    hot-pixel candidate, and the engine takes the ring's maximum over whole frames instead of gathering
    each candidate's ring; the same outcome as the reference, hot pixel found."""
    import shinysim.recon.detect as detect

    rng = np.random.default_rng(21)
    rows, cols = np.indices((48, 64))
    frames = np.empty((8, 48, 64), np.float32)
    for k in range(8):
        r, c = rng.uniform(8, 40), rng.uniform(8, 56)
        glow = 0.2 + 0.05 * np.sin(rows / 7.0 + k) + rng.normal(0, 0.002, rows.shape)
        frames[k] = glow + np.exp(-((rows - r) ** 2 + (cols - c) ** 2) / 6)
    frames[:, 30, 11] += np.float32(0.3)  # a hot pixel
    gathered = []
    real_around = detect._around
    monkeypatch.setattr(detect, "_around", lambda f, r, c, o: gathered.append(len(o)) or real_around(f, r, c, o))
    rec = check(frames)
    assert rec.detection["hot_pixels"] == 1
    assert len(detect._RING) not in gathered  # the whole-frame branch ran


def test_a_glow_in_every_frame_and_hundreds_of_frames():
    """Many pixels nonzero in most frames (hot-pixel candidates narrowed by the noise level); 256 frames."""
    rng = np.random.default_rng(14)
    rows, cols = np.indices((128, 128))
    frames = np.zeros((9, 128, 128), np.float32)
    for k in range(9):
        r, c = rng.uniform(10, 118, 2)
        frames[k] = np.where(np.hypot(rows - r, cols - c) < 6, np.exp(-((rows - r) ** 2 + (cols - c) ** 2) / 8), 0)
        frames[k].reshape(-1)[rng.integers(0, 128 * 128, 200)] += rng.uniform(1e-6, 1e-4, 200).astype(np.float32)
    frames[:, 40:72, 30:70] += np.float32(1e-7)  # 1280 pixels lit in every frame, far below the noise level
    frames[:, 50, 50] += np.float32(0.02)  # and one hot pixel among them
    rec = check(frames)
    assert rec.detection["hot_pixels"] == 1 and all(s > 0 for s in rec.detection["noise_sigma"])
    many = np.zeros((256, 8, 8), np.float32)
    many[:, 3, 4] = 0.5  # hot in every frame: the nonzero counts pass 255
    many[np.arange(256), np.arange(256) % 8, np.arange(256) // 32] += 1.0
    check(many)


def test_a_level_that_underflows_to_zero():
    """A relative threshold so small that threshold * peak is 0: every pixel is above it, zeros too."""
    check(rendered_like(n=4, H=24, W=24, seed=15, fireflies=5), threshold=5e-324, false_alarm=0)


@pytest.mark.parametrize("policy", ["flag", "refuse", "ignore"])
def test_clipped_highlights(policy):
    frames = rendered_like(n=6, H=48, W=48, seed=5, fireflies=40)
    over = np.minimum(frames / frames.max() * 3.0, 1.0)
    for kwargs in ({}, {"threshold": 0.01, "threshold_mode": "absolute"}):
        rec = check(over, saturation=1.0, saturated=policy, **kwargs)
        if policy == "refuse":
            assert "reaches the clip level" in rec.error[1]
        else:
            assert (rec.detection["n_saturated"] > 0) == (policy == "flag")
    half = frames / frames.max()  # the peak frame reaches the clip level, the others do not
    check(half, saturation=1.0, saturated=policy)
    check(half, saturation=0.3, saturated=policy, max_saturated_fraction=0.5)


def test_over_exposed_frames_are_refused_alike():
    frames = rendered_like(n=5, H=32, W=32, seed=6, fireflies=20)
    frames /= frames.max()
    frames[3] = 1.0
    fast = check(frames, saturation=1.0)
    assert fast.error[0].__name__ == "FrameError" and "S003: frame is over-exposed" in fast.error[1]
    check(frames, saturation=0.9999)  # a level that float32 rounds


def test_several_highlights_empty_frames_and_the_border():
    H, W = 40, 50
    rows, cols = np.indices((H, W))
    spot = lambda r, c, a=1.0: a * np.exp(-((rows - r) ** 2 + (cols - c) ** 2) / 3.0)  # noqa: E731
    frames = np.zeros((6, H, W))
    frames[0] = spot(10, 10) + spot(25, 40, 0.8) + spot(33, 5, 0.6)  # several highlights
    frames[1] = spot(0, 0) + spot(H - 1, W - 1, 0.9)  # at the corners
    frames[2, :, 0] = 1.0  # a first column lit: rows end there
    frames[2, :, W - 1] = 0.5
    frames[3] = spot(20, 25)
    frames[3, 20:22, 24:27] = frames[3, 20, 25]  # a flat top
    # frame 4 empty, frame 5 a single pixel
    frames[5, 7, 9] = 0.3
    for kwargs in ({}, {"min_area": 1}, {"threshold": 0.1}, {"connectivity": 1}, {"max_area": 4},
                   {"threshold": 0.3, "threshold_mode": "absolute", "centroid": "plain"}):
        rec = check(frames, **kwargs)
        assert 4 in rec.empty_sources


def test_one_wide_frame():
    """Pixels above the level spread over the frame, a streak across it."""
    rng = np.random.default_rng(8)
    frames = np.zeros((4, 200, 220), np.float32)
    for k in range(4):
        for r, c in rng.integers(0, 200, (25, 2)):
            frames[k, r:r + 3, c:c + 4] = rng.uniform(0.5, 1.0)
        frames[k, 50, 10:200] = 0.8  # a streak across many tiles
    check(frames, min_area=1)
    check(frames, min_area=1, connectivity=1, max_area=20)


def test_mask():
    frames = rendered_like(n=5, H=40, W=40, seed=9, fireflies=30)
    mask = np.zeros((40, 40), bool)
    mask[5:35, 8:30] = True
    check(frames, mask=mask)
    check(frames, mask=np.ones((40, 41), bool))  # refused alike, naming the first frame


@pytest.mark.parametrize("value, where", [(np.nan, (2, 3, 4)), (np.inf, (0, 0, 0)), (-1e-3, (1, 5, 5)),
                                          (-np.inf, (4, 39, 39)), (-0.0, (3, 10, 10))])
def test_bad_pixels_are_refused_alike(value, where):
    frames = rendered_like(n=5, H=40, W=40, seed=10, fireflies=30)
    stack = Stack(frames, rig_for(5, 40, 40))
    stack.frames[where] = value  # past the Stack's own checks
    assert_same(outcome(stack, "fast"), outcome(stack, "reference"))
    stack.frames[(where[0] + 2) % 5, 1, 1] = np.nan  # a second bad frame: the first is named
    assert_same(outcome(stack, "fast"), outcome(stack, "reference"))


def test_negative_zeros_read_as_zeros():
    """-0.0 equals 0: the same results, down to the sign of a zero reference level."""
    frames = rendered_like(n=4, H=24, W=24, seed=16, fireflies=5)
    frames[1, 3:9, 2:7] = -0.0
    check(frames)
    check(np.full((4, 24, 24), -0.0, np.float32))
    zeros = np.zeros((4, 24, 24), np.float32)
    zeros[2, 5, 5] = -0.0
    check(zeros)


def test_reconstruct_detects_as_detect_stack():
    frames = rendered_like(n=7, H=48, W=48, seed=11, fireflies=40)
    stack = Stack(frames, rig_for(7, 48, 48))
    rec = reconstruct(stack)
    assert_same(detect_stack(stack), reference_detect_stack(stack, DetectParams()))
    np.testing.assert_array_equal(rec.table["row"], detect_stack(stack).table["row"])
    assert rec.normals.keys() and all(len(v) == len(rec) for v in rec.normals.values())
    empty = Stack(np.zeros((7, 48, 48), np.float32), rig_for(7, 48, 48))
    with pytest.raises(ShinysimError, match="stack is empty"):
        reconstruct(empty)
    empty.frames[2, 3, 3] = np.nan  # no pixel above zero: the empty stack is named first
    with pytest.raises(ShinysimError, match="stack is empty"):
        reconstruct(empty)


def test_stacks_that_are_not_float32_or_contiguous():
    frames = rendered_like(n=5, H=40, W=60, seed=12, fireflies=30)
    stack = Stack(frames, rig_for(5, 40, 60))
    stack.frames = np.asarray(frames, np.float64)  # replaced after construction
    assert_same(outcome(stack, "fast"), outcome(stack, "reference"))
    stack.frames = np.zeros((5, 40, 60))
    with pytest.raises(ShinysimError, match="stack is empty"):
        reconstruct(stack)
    wide = np.zeros((5, 40, 120), np.float32)
    wide[:, :, ::2] = frames
    stack = Stack(wide[:, :, ::2], rig_for(5, 40, 60))
    assert not stack.frames.flags.c_contiguous
    assert_same(outcome(stack, "fast"), outcome(stack, "reference"))


@requires_jit
def test_a_rendered_sphere_stack_and_its_camera_frames():
    """A real render (the default sphere, smaller and with fewer samples), then as an 8-bit camera with hot pixels."""
    from shinysim.rig import shiny_1988
    from shinysim.sim.render import Simulator
    from shinysim.sim.scene import sphere_object

    stack = Simulator(shiny_1988(resolution=160), sphere_object(alpha=0.02)).render_stack(spp=16, seed=0)
    assert np.count_nonzero(stack.frames) < stack.frames.size / 8  # read sparsely
    rec = check(stack.frames, rig=stack.rig)
    assert len(rec) >= stack.n_sources - 2
    frames = camera_like(stack.frames, noise=0.03, seed=1)
    frames[:, 40, 50] = frames[:, 90, 120] = 0.8  # hot pixels
    assert check(frames, saturation=1.0, rig=stack.rig).detection["hot_pixels"] == 2


def test_solder_like_frames():
    """find_highlights' settings (scan threshold, smoothing, subdivision, dim flags) on several highlights a frame."""
    from shinysim.recon import HighlightParams

    frames = np.zeros((8, 60, 60), np.float32)
    rng = np.random.default_rng(13)
    rows, cols = np.indices((60, 60))
    for k in range(8):
        for _ in range(4):
            r, c = rng.uniform(3, 57, 2)
            frames[k] += rng.uniform(0.05, 1.0) * np.exp(-((rows - r) ** 2 + (cols - c) ** 2) / rng.uniform(2, 20))
        frames[k, 20:23, 5:45] = rng.uniform(0.3, 1.0)
    frames[frames < 1e-4] = 0
    check(frames, params=HighlightParams().detect_params())


# -- random stacks and settings ----------------------------------------------------------------------


@st.composite
def stacks_and_settings(draw, rendered=False):
    """A small random stack (mostly zeros, as rendered frames are, or noise everywhere) and random settings.

    ``rendered``: frames of at least 32 x 32 with zeros or fireflies around
    their highlights, so that most are read sparsely.
    """
    n = draw(st.integers(1, 8))
    if rendered:
        H, W = draw(st.sampled_from([32, 48, 64])), draw(st.sampled_from([32, 48, 64]))
    else:
        H, W = draw(st.sampled_from([48, 32, 64, 5, 1, 2])), draw(st.sampled_from([64, 24, 48, 8, 1, 3]))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    rows, cols = np.indices((H, W))
    frames = np.zeros((n, H, W))
    for k in range(n):
        floors = ["zero", "fireflies"] if rendered else ["zero", "zero", "zero", "fireflies", "fireflies", "noise", "8bit"]
        floor = draw(st.sampled_from(floors))
        if floor == "fireflies":
            lit = rng.random((H, W)) < rng.choice([0.002, 0.02, 0.1])
            frames[k][lit] = 10.0 ** rng.uniform(-40, -2, lit.sum())
        elif floor == "noise":
            frames[k] = np.abs(rng.normal(rng.uniform(0, 0.1), rng.uniform(0, 0.05), (H, W)))
        elif floor == "8bit":
            frames[k] = rng.integers(0, 4, (H, W)) / 255
        for _ in range(draw(st.integers(0, 3))):  # highlights, most cut off to exact zeros
            r, c, s = rng.uniform(-2, H + 2), rng.uniform(-2, W + 2), rng.choice([0.4, 0.8, 0.8, 1.5, 3.0])
            d2 = ((rows - r) ** 2 + (cols - c) ** 2) / (s * s)
            blob = rng.uniform(0.01, 2) * np.exp(-d2 / 2)
            frames[k] += np.where(d2 < rng.choice([2.0, 6.0, 6.0, np.inf]), blob, 0.0)
        if draw(st.booleans()):  # a flat top or a streak
            r, c = rng.integers(0, H), rng.integers(0, W)
            frames[k, r:r + rng.integers(1, 4), c:c + rng.integers(1, 12)] = rng.choice([0.3, 1.0, 1.5])
    for _ in range(draw(st.integers(0, 2))):  # hot pixels: lit in most frames
        frames[:, rng.integers(0, H), rng.integers(0, W)] += np.where(rng.random(n) < 0.8, rng.uniform(0.05, 1), 0)
    if draw(st.booleans()):
        frames = np.minimum(frames, 1.0)  # clipped
    frames = frames.astype(np.float32)
    mode = draw(st.sampled_from(["relative", "absolute", "scan", "highlight"]))
    kwargs = {
        "threshold_mode": mode,
        "threshold": draw(st.sampled_from([0.05, 0.5, 1.0] if mode != "absolute" else [1e-6, 0.05, 0.5, 3.0])),
        "smooth_px": draw(st.sampled_from([0.0, 0.0, 0.8])),
        "min_area": draw(st.sampled_from([None, None, 1, 4])),
        "max_area": draw(st.sampled_from([None, None, 3, 10])),
        "centroid": draw(st.sampled_from(["weighted", "plain"])),
        "connectivity": draw(st.sampled_from([1, 2])),
        "saturation": draw(st.sampled_from([None, None, 1.0, 0.5])),
        "saturated": draw(st.sampled_from(["flag", "refuse", "ignore"])),
        "max_saturated_fraction": draw(st.sampled_from([0.05, 0.5])),
        "noise_sigma": draw(st.sampled_from([None, None, 0.0, 0.01])),
        "false_alarm": draw(st.sampled_from([0.01, 0.01, 0.0, 5.0])),
        "hot_pixels": draw(st.booleans()),
        "subtract_background": draw(st.booleans()),
        "flag_rule": draw(st.sampled_from(["none", "dim"])),
    }
    if kwargs["max_area"] is not None and kwargs["min_area"] is not None:
        kwargs["max_area"] = max(kwargs["max_area"], kwargs["min_area"])
    mask = None
    if draw(st.booleans()):
        mask = rng.random((H, W)) < 0.7
    stack_saturation = draw(st.sampled_from([None, 1.0]))
    return frames, stack_saturation, mask, kwargs


@settings(max_examples=250, deadline=None, derandomize=True, database=None, suppress_health_check=list(HealthCheck))
@given(case=stacks_and_settings())
def test_engine_is_the_reference_on_random_stacks(case):
    check_case(case)


@settings(max_examples=250, deadline=None, derandomize=True, database=None, suppress_health_check=list(HealthCheck))
@given(case=stacks_and_settings(rendered=True))
def test_engine_is_the_reference_on_random_rendered_like_stacks(case):
    check_case(case)


def check_case(case):
    frames, saturation, mask, kwargs = case
    n, H, W = frames.shape
    stack = Stack(frames, rig_for(n, H, W), saturation=saturation)
    params = DetectParams(**kwargs)
    assert_same(outcome(stack, "fast", params=params, mask=mask), outcome(stack, "reference", params=params, mask=mask))
