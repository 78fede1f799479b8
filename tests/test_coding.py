"""Coded (multiplexed) scanning: codes, coded frames and their decoding.

Synthetic scenes only: each source's highlight is a truncated Gaussian blob
placed where a mirror sphere under an orthographic camera reflects it
(zero elsewhere, as a rendered frame of a shiny object is), so every pixel
sees at most one source unless a test moves two blobs together or adds the
crosstalk of rough highlights' tails.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import gaussian_blobs
from hypothesis import given, settings
from hypothesis import strategies as st

from shinysim.errors import FrameError, OptionError
from shinysim.io import Stack
from shinysim.recon import detect_stack
from shinysim.recon.coding import (
    DecodeParams,
    decode,
    default_crosstalk,
    demultiplex,
    measure_snr_gain,
)
from shinysim.recon.detect import DetectParams
from shinysim.rig import dome, fibonacci_hemisphere
from shinysim.sim.coded import coded_stack, expected_frames
from shinysim.sim.sensor import Sensor, sensor_preset
from shinysim.theory.coding import (
    CODES,
    Code,
    encode,
    gray,
    hadamard_snr_gain,
    make_code,
    s_matrix,
    s_matrix_inverse,
    spatial_order,
)

# -- scenes -------------------------------------------------------------------------


def _blob_positions(rig, size):
    """Where a mirror sphere filling most of the image reflects each distant source (row, col)."""
    s = rig.source_positions / np.linalg.norm(rig.source_positions, axis=1, keepdims=True)
    h = s + np.array([0.0, 0.0, 1.0])  # the normal bisects source and view (+z) directions
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    radius = 0.47 * size / math.sin(math.radians(40.0))  # the 80 deg dome's rim at 0.47 of the image
    centre = (size - 1) / 2
    return centre - radius * h[:, 1], centre + radius * h[:, 0]


def mirror_scene(n=200, size=256, seed=0):
    """An ideal stack of ``n`` highlights on ``size``^2 pixels, amplitudes 0.6..1 (radiance)."""
    rig = dome(n_sources=n, radius_mm=None, resolution=size, projection="orthographic")
    rows, cols = _blob_positions(rig, size)
    amp = np.random.default_rng(seed).uniform(0.6, 1.0, n)
    return Stack(gaussian_blobs(rows, cols, amp, size), rig)


@pytest.fixture(scope="module")
def scene():
    """N = 200 on 256^2: blobs 13 px apart at least (support diameter 7 px), so no two overlap."""
    return mirror_scene()


@pytest.fixture(scope="module")
def sequential(scene):
    return detect_stack(scene)


def owner(frames):
    """The source giving each pixel the most light, -1 for none."""
    return np.where((frames > 0).any(axis=0), frames.argmax(axis=0), -1)


# -- code structure ------------------------------------------------------------------


@pytest.mark.parametrize("n", [1, 2, 3, 20, 200, 500])
@pytest.mark.parametrize("name", ["binary", "gray"])
def test_bit_codes_frame_counts_and_codewords(name, n):
    bits = math.ceil(math.log2(n + 1))
    assert make_code(name, n, complementary=False).n_frames == bits
    code = make_code(name, n)
    assert code.n_frames == 2 * bits
    assert code.complementary and code.n_bits == bits
    cw = code.codewords
    assert len(np.unique(cw)) == n and cw.min() >= 1  # unique, and never the all-dark codeword
    # bit frames followed by their complements; every source lit at least once
    m = code.matrix
    np.testing.assert_array_equal(m[0::2] + m[1::2], 1.0)
    assert m[0::2].sum(axis=0).min() >= 1
    assert Code.from_dict(code.to_dict()) == code


@pytest.mark.parametrize("n", [1, 2, 3, 20, 200, 500])
def test_gray_neighbours_differ_in_one_bit(n):
    order = np.random.default_rng(n).permutation(n)
    code = make_code("gray", n, order=order)
    cw = code.codewords[order]  # codewords in hand-out order
    flips = [bin(int(a) ^ int(b)).count("1") for a, b in zip(cw[:-1], cw[1:])]
    assert all(f == 1 for f in flips)
    np.testing.assert_array_equal(make_code("gray", n).codewords, gray(np.arange(1, n + 1)))


@pytest.mark.parametrize("order", [1, 3, 7, 63, 255])
def test_s_matrix_inverse(order):
    s = s_matrix(order)
    assert s.sum(axis=0).tolist() == [(order + 1) // 2] * order  # each source lit in (n + 1) / 2 frames
    # the closed form 2/(n+1)(2 S^T - J) is exact in exact arithmetic; entries +-2/(n+1) summed over
    # n terms in float64 leave rounding of order n * 1e-16, far inside 1e-12
    np.testing.assert_allclose(s_matrix_inverse(order) @ s, np.eye(order), rtol=0, atol=1e-12)


@pytest.mark.parametrize("n", [1, 2, 20, 63, 200])
def test_hadamard_and_sequential_codes(n):
    had = make_code("hadamard", n)
    assert had.n_frames == 2 ** math.ceil(math.log2(n + 1)) - 1 >= n
    seq = make_code("sequential", n)
    np.testing.assert_array_equal(seq.matrix, np.eye(n))
    for code in (had, seq):
        np.testing.assert_allclose(code.demultiplexer() @ code.matrix, np.eye(n), rtol=0, atol=1e-12)
        assert Code.from_dict(code.to_dict()) == code


@settings(max_examples=40, deadline=None)
@given(n=st.integers(1, 300), name=st.sampled_from(CODES), seed=st.integers(0, 2**31 - 1),
       complementary=st.booleans())
def test_any_code_round_trips_and_separates_sources(n, name, seed, complementary):
    order = np.random.default_rng(seed).permutation(n)
    code = make_code(name, n, complementary=complementary, order=order)
    assert Code.from_dict(code.to_dict()) == code
    # every source lit somewhere, no two lit in the same frames
    assert code.matrix.sum(axis=0).min() >= 1
    assert len({code.matrix[:, s].tobytes() for s in range(n)}) == n
    if name in ("binary", "gray"):
        assert code.source_of_codeword()[code.codewords].tolist() == list(range(n))


def test_spatial_order_puts_dome_neighbours_one_bit_apart():
    dirs = fibonacci_hemisphere(200)
    order = spatial_order(dirs)
    assert sorted(order.tolist()) == list(range(200))
    spatial = make_code("gray", 200, order=order)
    plain = make_code("gray", 200)
    # each source's nearest neighbour on the dome: how many bits apart are their codewords?
    cos = dirs @ dirs.T
    np.fill_diagonal(cos, -2)
    nearest = cos.argmax(axis=1)

    def flips(code):
        return np.array([bin(int(a) ^ int(b)).count("1") for a, b in
                         zip(code.codewords, code.codewords[nearest])])

    # Measured: 48 % of nearest neighbours are one bit apart with the spatial order, mean 2.0 bits;
    # 7 % and 3.6 bits in Fibonacci index order (whose neighbours are 8, 13 or 21 indices apart).
    # The bounds leave room around those numbers but separate the two orders.
    assert (flips(spatial) == 1).mean() > 0.3 > (flips(plain) == 1).mean()
    assert flips(spatial).mean() < 3.0 < flips(plain).mean()


# -- encoding -------------------------------------------------------------------------


@pytest.mark.parametrize("name", CODES)
def test_encode_is_the_sum_of_the_lit_frames(name, monkeypatch):
    rng = np.random.default_rng(1)
    frames = rng.random((13, 40, 24)).astype(np.float32)
    code = make_code(name, 13, order=rng.permutation(13))
    import shinysim.theory.coding as coding
    monkeypatch.setattr(coding, "_BLOCK", 13 * 24 * 3)  # blocks of 3 rows: the chunked path, with a ragged end
    coded = encode(frames, code)
    assert coded.dtype == np.float32 and coded.shape == (code.n_frames, 40, 24)
    explicit = np.stack([frames[code.matrix[f] == 1].astype(np.float64).sum(axis=0)
                         for f in range(code.n_frames)]).astype(np.float32)
    # both sum float32 values exactly in float64 (13 values of 24 bits fit its 53) and round once
    np.testing.assert_array_equal(coded, explicit)


# -- decoding: no noise ------------------------------------------------------------------


@pytest.mark.parametrize("name", ["binary", "gray"])
def test_bit_codes_decode_exactly_without_noise(scene, sequential, name):
    order = spatial_order(scene.rig.source_positions) if name == "gray" else None
    code = make_code(name, 200, order=order)
    dec = decode(coded_stack(scene, code))
    assert code.n_frames == 16  # against 200 sequential frames
    truth = owner(scene.frames)
    np.testing.assert_array_equal(dec.labels, truth)  # every lit pixel, none other
    assert dec.counts["collisions"] == dec.counts["uncertain"] == dec.counts["invalid"] == 0
    t, s = dec.table, sequential.table
    np.testing.assert_array_equal(t["source"], s["source"])
    np.testing.assert_array_equal(t["area"], s["area"])
    # same pixels and weights (each coded pixel holds one source's exact value): the centroids
    # differ only by summation order, ~1e-13 px
    assert np.abs(t["row"] - s["row"]).max() < 1e-6
    assert np.abs(t["col"] - s["col"]).max() < 1e-6


@pytest.mark.parametrize("name", ["binary", "gray"])
def test_bit_codes_subdivide_streaks_as_sequential_detection(scene, name):
    """Streaks (a solder joint's mirror highlights) subdivided by max_area: the decoded parts are the
    sequential detection's parts, pixel for pixel (the same split of the same pixels and weights)."""
    frames = scene.frames.copy()
    for k in (3, 50, 120):  # three sources' blobs become 3 x 25 px streaks, brightest in the middle
        frames[k] = 0
        r, c = np.unravel_index(np.argmax(scene.frames[k]), frames.shape[1:])
        cols = np.arange(c - 12, c + 13)
        for dr in (-1, 0, 1):
            frames[k, r + dr, cols] = 1.0 - 0.01 * np.abs(cols - c) - 0.05 * abs(dr)
    streaky = Stack(frames, scene.rig)
    order = spatial_order(scene.rig.source_positions) if name == "gray" else None
    code = make_code(name, 200, order=order)
    dec = decode(coded_stack(streaky, code), max_area=20)
    seq = detect_stack(streaky, DetectParams(max_area=20))
    t, s = dec.table, seq.table
    for k in (3, 50, 120):
        assert np.count_nonzero(t["source"] == k) == 4  # ceil(75 / 20) parts
    assert len(t["source"]) == len(s["source"]) == 200 + 3 * 3
    np.testing.assert_array_equal(t["source"], s["source"])
    np.testing.assert_array_equal(t["area"], s["area"])
    assert np.abs(t["row"] - s["row"]).max() < 1e-6 and np.abs(t["col"] - s["col"]).max() < 1e-6
    # without max_area one highlight per streak
    whole = decode(coded_stack(streaky, code)).table
    assert len(whole["source"]) == 200
    with pytest.raises(OptionError) as e:
        DecodeParams(max_area=0)
    assert e.value.field == "max_area"


def test_hadamard_demultiplexes_to_the_sequential_stack(scene, sequential):
    code = make_code("hadamard", 200)
    coded = coded_stack(scene, code)
    dec = decode(coded)
    peak = float(scene.frames.max())
    # coded frames are float32-rounded sums (relative 2**-24 of values <= peak, since blobs do not
    # overlap); each demultiplexed value is +-2/(n+1) times n of them, so at most 2**-23 * peak off,
    # plus its own float32 rounding: 4 * 2**-24 * peak bounds both
    x = dec.stack.frames - np.asarray(dec.stack.provenance["pedestal"], np.float32)[:, None, None]
    assert np.abs(x - scene.frames).max() <= 4 * 2.0**-24 * peak
    t, s = dec.table, sequential.table
    np.testing.assert_array_equal(t["source"], s["source"])
    assert np.abs(t["row"] - s["row"]).max() < 1e-6 and np.abs(t["col"] - s["col"]).max() < 1e-6
    seq = decode(coded_stack(scene, make_code("sequential", 200)))
    np.testing.assert_array_equal(seq.stack.frames, scene.frames)


def _overlapping(size=64):
    """Six sources in a row, 12 px apart, except sources 2 and 3 whose blobs are 2 px apart."""
    rig = dome(n_sources=6, radius_mm=None, resolution=size, projection="orthographic")
    cols = np.array([8.0, 20.0, 32.0, 34.0, 46.0, 58.0])
    rows = np.full(6, 31.3)
    frames = gaussian_blobs(rows, cols, np.linspace(0.7, 1.0, 6), size)
    return Stack(frames, rig)


@pytest.mark.parametrize("order", [None, [0, 1, 2, 3, 4, 5], [2, 0, 1, 4, 5, 3]])
@pytest.mark.parametrize("name", ["binary", "gray"])
def test_collisions_are_flagged_never_mislabelled(name, order):
    stack = _overlapping()
    code = make_code(name, 6, order=order)
    coded = coded_stack(stack, code)
    dec = decode(coded, crosstalk=0)
    both = (stack.frames[2] > 0) & (stack.frames[3] > 0)
    assert both.sum() > 10
    np.testing.assert_array_equal(dec.collision, both)  # strict and noiseless: light in both is a collision
    alone = (stack.frames > 0).sum(axis=0) == 1
    np.testing.assert_array_equal(dec.labels[alone], owner(stack.frames)[alone])
    assert (dec.labels[both] == -1).all()
    one_bit = bin(int(code.codewords[2]) ^ int(code.codewords[3])).count("1") == 1
    if one_bit:  # the pair is named: the two codewords that agree in every other bit
        assert {tuple(sorted(p)) for p in dec.pairs[both].tolist()} == {(2, 3)}
    else:
        assert (dec.pairs[both] == -1).all()
    # the default tolerance decodes where one blob's light is far above the other's, to the brighter
    # one, and still flags where they are comparable
    tolerant = decode(coded)
    assert tolerant.collision.sum() > 0 and not (tolerant.collision & ~both).any()
    lab = tolerant.labels
    np.testing.assert_array_equal(lab[alone], owner(stack.frames)[alone])
    assert ((lab >= 0) & (lab != owner(stack.frames))).sum() == 0


@pytest.mark.parametrize("crosstalk", [0.0, None])
def test_spatial_gray_order_names_colliding_neighbours(crosstalk):
    """In path order, sources 2 and 3 are neighbours: their overlap is a one-bit collision."""
    stack = _overlapping()
    dec = decode(coded_stack(stack, make_code("gray", 6, order=[0, 1, 2, 3, 4, 5])), crosstalk=crosstalk)
    assert dec.counts["collisions"] > 0
    assert {tuple(sorted(p)) for p in dec.pairs[dec.collision].tolist()} == {(2, 3)}


# -- decoding: crosstalk of rough highlights' tails -----------------------------------------


def _with_crosstalk(name, share=0.03, size=80):
    """Six highlights in a row, 12 px apart, and source 3 lighting the 7 x 7 px around source 1's
    highlight at ``share`` of that highlight's peak, as a neighbour's rough tail does."""
    rig = dome(n_sources=6, radius_mm=None, resolution=size, projection="orthographic")
    frames = gaussian_blobs(np.full(6, 31.3), 8.0 + 12.0 * np.arange(6), np.linspace(0.7, 1.0, 6), size)
    clean = Stack(frames.copy(), rig)
    frames[3, 28:35, 17:24] += np.float32(share * frames[1].max())
    return Stack(frames, rig), clean, make_code(name, 6)


@pytest.mark.parametrize("name", ["binary", "gray"])
def test_crosstalk_from_a_neighbour_decodes_to_the_brightest_source(name):
    stack, clean, code = _with_crosstalk(name)
    coded = coded_stack(stack, code)
    truth = owner(stack.frames)
    core = stack.frames[1] >= 0.5 * stack.frames[1].max()  # source 1's highlight, 3 % of source 3 in each pixel
    assert (stack.frames[3][core] > 0).all()
    dec = decode(coded)  # 0.8 / 3 bits = 0.27
    assert dec.noise["crosstalk"] == pytest.approx(0.8 / 3) == default_crosstalk(3)
    assert (dec.labels[core] == 1).all() and not dec.collision[core].any()
    assert ((dec.labels >= 0) & (dec.labels != truth)).sum() == 0  # never another source than the brightest
    assert sorted(dec.table["source"].tolist()) == list(range(6))
    one = np.flatnonzero(dec.table["source"] == 1)[0]
    clean = decode(coded_stack(clean, code), crosstalk=0)  # the same highlight without crosstalk
    ref = np.flatnonzero(clean.table["source"] == 1)[0]
    # the crosstalk is flat over the core: the centroid stays put
    assert abs(dec.table["row"][one] - clean.table["row"][ref]) < 0.05
    assert abs(dec.table["col"][one] - clean.table["col"][ref]) < 0.05
    assert any("crosstalk tolerance" in n for n in dec.notes)
    # strict: light in a bit frame and its complement is a collision, so the highlight is lost
    strict = decode(coded, crosstalk=0)
    assert strict.collision[core].all() and (strict.labels[core] == -1).all()
    assert 1 not in strict.table["source"].tolist()
    assert strict.noise["crosstalk"] == 0.0 and not any("crosstalk" in n for n in strict.notes)


@pytest.mark.parametrize("name", ["binary", "gray"])
def test_equally_bright_sources_are_flagged_never_labelled(name):
    """Two sources of equal light at one pixel: far above any tolerance below 1 / bits."""
    stack = mirror_scene(n=9, size=64, seed=1)
    f = stack.frames.copy()
    f[4] += f[3]  # source 4 also lights source 3's highlight, as brightly
    coded = coded_stack(Stack(f, stack.rig), make_code(name, 9))
    both = (f[3] > 0) & (f[4] > 0)
    for crosstalk in (None, 0.0, 0.99 / 4):  # 4 bits: the default, strict and the largest allowed
        dec = decode(coded, crosstalk=crosstalk)
        assert dec.collision[both].all() and (dec.labels[both] == -1).all()
        assert 3 not in dec.table["source"].tolist()


def _tailed_scene(n=40, size=96, tail=0.005, seed=0):
    """Blobs on a grid, each on a pedestal: every pixel gets ``tail`` x peak from every *other*
    source within 30 px, as the tails of rough highlights give. Peaks 0.6..1."""
    rig = dome(n_sources=n, radius_mm=None, resolution=size, projection="orthographic")
    rng = np.random.default_rng(seed)
    side = math.ceil(math.sqrt(n))
    g = (np.arange(side) + 0.5) * size / side
    rows, cols = [a.ravel()[:n] for a in np.meshgrid(g, g, indexing="ij")]
    amp = rng.uniform(0.6, 1.0, n)
    yy, xx = np.mgrid[0:size, 0:size]
    frames = np.zeros((n, size, size), np.float32)
    for k in range(n):
        d2 = (yy - rows[k]) ** 2 + (xx - cols[k]) ** 2
        frames[k] = amp[k] * (np.exp(-d2 / (2 * 1.3**2)) * (d2 <= 16) + tail * (d2 <= 900))
    return Stack(frames, rig)


@pytest.mark.parametrize("sensor", [None, "machine_vision_12bit"])
def test_crosstalk_from_many_tails_decodes_and_never_mislabels(sensor):
    """Every pixel holds tails of the sources within 30 px (up to ~20 % of a core's light, in all)."""
    stack = _tailed_scene()
    coded = coded_stack(stack, make_code("binary", 40), sensor=sensor and sensor_preset(sensor), seed=1)
    truth = owner(stack.frames)
    strict = decode(coded, crosstalk=0)
    # with tails in every pixel the strict rule sees light in a bit frame and its complement
    # nearly everywhere: most highlights are lost (but nothing is mislabelled)
    assert strict.counts["highlights"] < 20
    assert ((strict.labels >= 0) & (strict.labels != truth)).sum() == 0
    tolerant = decode(coded)  # 0.8 / 6 bits = 0.133
    assert tolerant.noise["crosstalk"] == pytest.approx(0.8 / 6)
    lab = tolerant.labels
    assert ((lab >= 0) & (lab != truth)).sum() == 0  # the guarantee: rho < 1 / bits labels the brightest only
    assert sorted(tolerant.table["source"].tolist()) == list(range(40))


def test_crosstalk_tolerance_is_checked():
    stack, _, code = _with_crosstalk("binary")
    coded = coded_stack(stack, code)
    with pytest.raises(OptionError, match=r"below 1 / 3 bits") as e:  # the guarantee's bound
        decode(coded, crosstalk=1.0 / 3)
    assert _field(e) == "crosstalk"
    for bad in (-0.01, 1.0, float("nan"), True, "0.1"):
        with pytest.raises(OptionError) as e:
            DecodeParams(crosstalk=bad)
        assert _field(e) == "crosstalk"
    assert default_crosstalk(8) == pytest.approx(0.1)  # 200 sources
    # demultiplexed codes have no bit pairs: the tolerance is not theirs
    dec = decode(coded_stack(mirror_scene(n=15, size=64), make_code("hadamard", 15)), crosstalk=0.5)
    assert "crosstalk" not in dec.noise


# -- decoding: a 12-bit machine-vision camera ------------------------------------------------


@pytest.mark.parametrize("name", ["binary", "gray"])
def test_bit_codes_with_a_12bit_sensor(scene, sequential, name):
    sensor = sensor_preset("machine_vision_12bit")
    truth = owner(scene.frames)
    code = make_code(name, 200, order=spatial_order(scene.rig.source_positions) if name == "gray" else None)
    wrong = decoded = highlights_wrong = 0
    for seed in range(3):  # 3 x 200 highlights
        dec = decode(coded_stack(scene, code, sensor=sensor, exposure=0.8, seed=seed))
        lab = dec.labels
        wrong += int(((lab >= 0) & (lab != truth)).sum())
        decoded += int((lab >= 0).sum())
        t = dec.table
        highlights_wrong += abs(len(t["source"]) - 200) + int((np.sort(t["source"]) != np.arange(200)).sum()
                                                               if len(t["source"]) == 200 else 200)
        # the hot pixel of the preset's fixed pattern (1 in 10^5 pixels) lights every frame: a collision
        assert dec.counts["collisions"] <= 2
        if len(t["source"]) == 200:
            # measured: at most 0.29 px (rms 0.04) from the noiseless centroids, the sequential scan
            # through the same sensor 0.29 px (rms 0.06): noise moves pixels across the 0.5 threshold
            err = np.hypot(t["row"] - sequential.table["row"], t["col"] - sequential.table["col"])
            assert err.max() < 0.5
    # measured: 0 wrong of 23 187 decoded pixels, every highlight found once with its source;
    # the bound is 0.1 %
    assert wrong <= 1e-3 * decoded
    assert highlights_wrong == 0


def test_saturation_is_flagged(scene):
    sensor = sensor_preset("machine_vision_12bit")
    coded = coded_stack(scene, make_code("binary", 200), sensor=sensor, exposure=5.0)  # 5x the full well
    dec = decode(coded)
    np.testing.assert_array_equal(dec.saturated, (coded.frames >= 1.0).any(axis=0))
    assert dec.counts["saturated"] > 200  # every highlight's core
    assert dec.table["saturated"].sum() == len(dec.table["source"]) == 200
    truth = owner(scene.frames)
    assert ((dec.labels >= 0) & (dec.labels != truth)).sum() == 0  # clipped, but still decoded right
    assert any("clip level" in n for n in dec.notes)


def test_without_complements_decodes_clean_frames(scene):
    code = make_code("binary", 200, complementary=False)
    assert code.n_frames == 8
    dec = decode(coded_stack(scene, code))
    np.testing.assert_array_equal(dec.labels, owner(scene.frames))
    sensor = sensor_preset("machine_vision_12bit")
    dec = decode(coded_stack(scene, code, sensor=sensor, seed=3))
    truth = owner(scene.frames)
    # weaker than complements (notes say why), yet on separate highlights still below 0.1 % wrong
    assert ((dec.labels >= 0) & (dec.labels != truth)).sum() <= 1e-3 * (dec.labels >= 0).sum()
    assert dec.notes


def test_hadamard_with_a_12bit_sensor():
    scene = mirror_scene(n=63, size=128, seed=2)
    dec = decode(coded_stack(scene, make_code("hadamard", 63), sensor=sensor_preset("machine_vision_12bit")))
    assert dec.table["source"].tolist() == list(range(63))


# -- signal to noise ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def snr_scene():
    """N = n = 63 sources on 128^2 pixels: 63 x 16 384 = 1.03 million demultiplexed values."""
    return mirror_scene(n=63, size=128, seed=1)


def _scans(scene, sensor):
    sensor = sensor.exposed_for(1.0, 0.5)  # the brightest blob at half the full well, in both scans
    seq = coded_stack(scene, make_code("sequential", 63), sensor=sensor, exposure=None, seed=1)
    had = coded_stack(scene, make_code("hadamard", 63), sensor=sensor, exposure=None, seed=2)
    return seq, had, expected_frames(scene.frames, sensor), sensor


def test_snr_gain_under_read_noise(snr_scene):
    # read noise 20 DN, far above quantisation (0.29 DN rms); a black level keeps noise off the 0 clip
    sensor = Sensor(name="read", bits=16, full_well=65535.0, read_noise=20.0, dark_offset=1000.0, shot_noise=False)
    seq, had, ideal, _ = _scans(snr_scene, sensor)
    r = measure_snr_gain(seq, had, ideal)
    theory = hadamard_snr_gain(63)
    assert theory == pytest.approx(64 / (2 * math.sqrt(63)))
    # measured 4.030 (theory 4.032) from 1.03e6 values per scan: standard error 0.004, so a
    # 2 % tolerance is 20 standard errors
    assert r["n_samples"] == 63 * 128 * 128
    assert r["stderr"] < 0.01
    assert r["gain"] == pytest.approx(theory, rel=0.02)


def test_snr_gain_under_shot_noise(snr_scene):
    # shot-noise dominated: up to 5e5 photo-electrons, read noise 1 e-; 16 bits over 1e6 e- quantise
    # in 15 e- steps (4.4 e- rms), far below the highlights' photon noise (hundreds of e-). A pixel
    # that no lit source reaches reads the black level exactly (1 e- = 0.065 DN rounds away), so
    # every error comes from light: the pure shot-noise case of the theory
    sensor = Sensor(name="shot", bits=16, full_well=1e6, read_noise=1.0, dark_offset=1000.0, shot_noise=True)
    seq, had, ideal, sensor = _scans(snr_scene, sensor)
    n = 63
    whole = measure_snr_gain(seq, had, ideal, region="all")
    lit = measure_snr_gain(seq, had, ideal, region="lit")
    unlit = measure_snr_gain(seq, had, ideal, region="unlit")
    # measured 0.709 (theory sqrt(64/126) = 0.713): a loss over the whole frame, as theory says;
    # stderr 0.0007 from 1.03e6 values, so 2 % is 20 standard errors
    assert whole["gain"] < 1
    assert whole["gain"] == pytest.approx(hadamard_snr_gain(n, "shot"), rel=0.02)
    # ... but a gain on the highlights themselves: measured 5.67 against sqrt(32) = 5.66; the
    # stderr is 0.12 (2424 lit values), so 10 % is 5 standard errors
    assert lit["gain"] == pytest.approx(hadamard_snr_gain(n, "shot", pixels="lit"), rel=0.1)
    # the highlight's photon noise lands in the other sources' frames, dark in a sequential scan
    assert unlit["gain"] < 0.1 and unlit["sigma_multiplexed"] > 0


def test_shot_gain_formula_limits():
    n = 255
    assert hadamard_snr_gain(n, "shot", signal=0.0, read_noise=3.0, pixels="lit") == pytest.approx(
        hadamard_snr_gain(n))  # no light: pure read noise
    big = hadamard_snr_gain(n, "shot", signal=1e12, read_noise=3.0, pixels="all")
    assert big == pytest.approx(math.sqrt((n + 1) / (2 * n)), rel=1e-6)


# -- bad input ---------------------------------------------------------------------------------


def _field(exc_info):
    return exc_info.value.field


def test_bad_input_names_the_field(scene):
    with pytest.raises(OptionError, match="200 sources") as e:
        coded_stack(scene, make_code("binary", 20))
    assert _field(e) == "code" and "20 sources" in str(e.value)
    with pytest.raises(OptionError) as e:
        make_code("binary", 0)
    assert _field(e) == "n_sources"
    with pytest.raises(OptionError, match="did you mean 'gray'") as e:
        make_code("grey", 5)
    assert _field(e) == "name"
    with pytest.raises(OptionError) as e:
        make_code("gray", 4, order=[0, 1, 1, 3])
    assert _field(e) == "order"
    code = make_code("binary", 200)
    coded = coded_stack(scene, code)
    with pytest.raises(OptionError, match="16 frames but 15") as e:
        decode(coded.frames[:15], code=code)
    assert _field(e) == "frames"
    bad = coded.frames.copy()
    bad[3, 5, 5] = np.nan
    with pytest.raises(FrameError, match="NaN") as e:
        decode(bad, code=code)
    assert _field(e) == "frames"
    with pytest.raises(OptionError) as e:
        decode(coded, DecodeParams(), threshold=2.0)
    assert _field(e) == "threshold"
    with pytest.raises(OptionError) as e:
        decode(coded_stack(scene, make_code("hadamard", 200)).frames, code=make_code("hadamard", 200))
    assert _field(e) == "rig"
    with pytest.raises(OptionError) as e:
        decode(coded.frames, code=code, rig=dome(n_sources=20, radius_mm=None, resolution=256))
    assert _field(e) == "rig"
    with pytest.raises(OptionError) as e:
        encode(scene.frames[:10], code)
    assert _field(e) == "frames"
    with pytest.raises(OptionError) as e:
        demultiplex(coded.frames, code)
    assert _field(e) == "code"
    with pytest.raises(OptionError) as e:
        Code.from_dict({**code.to_dict(), "n_frames": 17})
    assert _field(e) == "n_frames"
    with pytest.raises(OptionError) as e:
        Code.from_dict({**code.to_dict(), "colour": 1})
    assert _field(e) == "code"
    with pytest.raises(OptionError) as e:
        Code("binary", 3, np.eye(3), np.array([1, 2, 3]), False, np.arange(3))  # codewords not the matrix
    assert _field(e) == "codewords"
    with pytest.raises(OptionError) as e:
        Code("sequential", 2, np.ones((1, 2)), None, False, np.arange(2))  # two sources in the same frames
    assert _field(e) == "matrix"
