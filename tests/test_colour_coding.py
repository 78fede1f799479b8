"""Colour multiplexing: red, green and blue fibers, a colour camera, an inner code per channel.

Code structure, serialisation and bad input; the colour sensor chain (fiber emission, camera
crosstalk, unmixing) on synthetic frames; the one-pass renderer in an RGB variant (grey and tinted
conductors); decoding of a rendered dome scan against the sequential scan; a deliberate collision of
two differently coloured highlights; a tinted metal under leaky fibers.

The rendered tests share one 60-source dome over the calibration sphere at 128 x 128 pixels and
16 samples per pixel (about a second per render).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from conftest import gaussian_blobs, requires_jit

from shinysim.errors import FrameError, OptionError
from shinysim.io import Stack
from shinysim.recon import DetectParams, reconstruct
from shinysim.recon.coding import DecodeParams, colour_tolerance_bound, decode, unmix
from shinysim.rig import dome, fibonacci_hemisphere
from shinysim.sim.coded import ColourStack, coded_stack, colour_mixing
from shinysim.sim.sensor import (
    CAMERA_CROSSTALK,
    Sensor,
    check_colour_matrix,
    sensor_preset,
)
from shinysim.theory.coding import (
    CODES,
    Code,
    colour_channels,
    encode_colour,
    fiber_emission,
    make_code,
    spatial_order,
)


def _field(exc_info):
    return exc_info.value.field


# -- codes -------------------------------------------------------------------------------


@pytest.mark.parametrize("n", [1, 2, 3, 4, 7, 30, 200])
@pytest.mark.parametrize("name", CODES)
def test_colour_code_takes_the_inner_codes_frames_for_a_third_of_the_sources(name, n):
    code = make_code(name, n, colours=3)
    m = math.ceil(n / 3)
    assert code.colours == 3 and code.n_inner == m
    assert code.n_frames == make_code(name, m).n_frames
    assert np.bincount(code.channels, minlength=3).max() == m  # balanced: at most ceil(N / 3) a channel
    # within a channel every source is lit somewhere and no two in the same frames
    for c in range(3):
        idx = code.channel_sources(c)
        cols = {code.matrix[:, s].tobytes() for s in idx}
        assert len(cols) == len(idx)
    assert code.matrix.sum(axis=0).min() >= 1
    d = code.to_dict()
    assert d["colours"] == 3 and d["channels"] == code.channels.tolist()
    assert Code.from_dict(json.loads(json.dumps(d))) == code
    if name in ("sequential", "hadamard"):
        dm = code.demultiplexer()
        for c in range(3):
            idx = code.channel_sources(c)
            if len(idx):
                np.testing.assert_allclose(dm[idx] @ code.matrix[:, idx], np.eye(len(idx)), rtol=0, atol=1e-12)
    if name in ("binary", "gray"):
        for c in range(3):
            idx = code.channel_sources(c)
            assert code.source_of_codeword(c)[code.codewords[idx]].tolist() == idx.tolist()


def test_colour_codes_save_frames_and_plain_codes_are_unchanged():
    # 200 sources: binary 16 -> 14 frames, sequential 200 -> 67, Hadamard 255 -> 127
    assert [make_code(n, 200, colours=3).n_frames for n in ("binary", "sequential", "hadamard")] == [14, 67, 127]
    for name in CODES:  # a code of one colour serialises exactly as before colour existed
        plain = make_code(name, 20)
        assert plain.channels is None and plain.colours == 1
        assert set(plain.to_dict()) == {"format", "name", "n_sources", "complementary", "order", "n_frames"}
        assert make_code(name, 20, colours=1) == plain
        assert plain != make_code(name, 20, colours=3)


def test_consecutive_sources_of_the_order_differ_in_colour():
    dirs = fibonacci_hemisphere(200)
    order = spatial_order(dirs)
    code = make_code("gray", 200, colours=3, order=order)
    path = code.channels[order]
    assert (path[1:] != path[:-1]).all()
    # within a channel, sources take the inner Gray codewords in path order: one bit apart
    for c in range(3):
        cw = code.codewords[code.channel_sources(c)]
        assert all(bin(int(a) ^ int(b)).count("1") == 1 for a, b in zip(cw[:-1], cw[1:]))


def test_colour_channels_keep_dome_neighbours_apart():
    dirs = fibonacci_hemisphere(200)
    order = spatial_order(dirs)
    greedy = colour_channels(dirs, order=order)
    assert np.bincount(greedy, minlength=3).max() == 67  # ceil(200 / 3): the code keeps its frame count
    along = np.empty(200, np.int64)
    along[order] = np.arange(200) % 3
    cos = dirs @ dirs.T
    np.fill_diagonal(cos, -2)
    nearest = cos.argmax(axis=1)
    # measured: 4 % of sources share their nearest neighbour's colour with the greedy colouring,
    # 22 % with i mod 3 along the path (a third at random); the bounds separate the two
    assert (greedy == greedy[nearest]).mean() < 0.1 < (along == along[nearest]).mean()
    code = make_code("gray", 200, colours=3, order=order, channels=greedy)
    assert Code.from_dict(code.to_dict()) == code and code.n_frames == 14


def test_colour_code_bad_input_names_the_field():
    with pytest.raises(OptionError) as e:
        make_code("gray", 6, colours=2)
    assert _field(e) == "colours"
    with pytest.raises(OptionError) as e:
        make_code("gray", 6, colours=True)
    assert _field(e) == "colours"
    with pytest.raises(OptionError) as e:
        make_code("gray", 6, channels=[0, 1, 2, 0, 1, 2])  # channels without colour
    assert _field(e) == "channels"
    for bad in ([0, 1, 2, 3, 1, 2], [0, 1, 2], [0, 1.5, 2, 0, 1, 2], [-1, 1, 2, 0, 1, 2]):
        with pytest.raises(OptionError) as e:
            make_code("gray", 6, colours=3, channels=bad)
        assert _field(e) == "channels"
    code = make_code("binary", 6, colours=3)
    # two sources of one colour lit in the same frames cannot be told apart
    ch = code.channels.copy()
    same = np.flatnonzero((code.matrix == code.matrix[:, [0]]).all(axis=0) & (ch != ch[0]))[0]
    ch[same] = ch[0]
    with pytest.raises(OptionError, match="same frames") as e:
        Code(code.name, 6, code.matrix, code.codewords, code.complementary, code.order, ch)
    assert _field(e) == "matrix"
    # ... which from_dict catches in a hand-edited file too: there the channels are rebuilt
    d = code.to_dict()
    with pytest.raises(OptionError) as e:
        Code.from_dict({**d, "channels": [0, 0, 0, 0, 0, 0]})  # 6 sources in one channel: 4 frames' worth
    assert _field(e) == "n_frames"
    with pytest.raises(OptionError) as e:
        Code.from_dict({**d, "channels": [0, 1, 2, 0, 1, 7]})
    assert _field(e) == "channels"
    with pytest.raises(OptionError) as e:
        Code.from_dict({**d, "colour": 3})
    assert _field(e) == "code"
    had = make_code("hadamard", 6, colours=3)
    bad = had.matrix.copy()
    bad[:, 0] = 1.0  # every frame: not a column of the S-matrix
    with pytest.raises(OptionError, match="S-matrix") as e:
        Code("hadamard", 6, bad, None, False, had.order, had.channels)
    assert _field(e) == "matrix"
    with pytest.raises(OptionError) as e:
        code.source_of_codeword()  # a colour code has one table per channel
    assert _field(e) == "channel"


# -- the colour chain on synthetic frames -----------------------------------------------------


def _colour_row(cols, size=64, amp=None, tint=(1.0, 1.0, 1.0)):
    """A ColourStack of blobs in a row (white sources on a surface of RGB reflectance ``tint``)."""
    n = len(cols)
    rig = dome(n_sources=n, radius_mm=None, resolution=size, projection="orthographic")
    amp = np.linspace(0.7, 1.0, n) if amp is None else np.asarray(amp, float)
    grey = gaussian_blobs(np.full(n, 31.3), np.asarray(cols, float), amp, size)
    return ColourStack(grey[..., None] * np.asarray(tint, np.float32), rig), grey


def test_encode_colour_is_each_sources_light_through_its_fiber():
    rng = np.random.default_rng(3)
    frames = rng.random((7, 10, 12, 3)).astype(np.float32)
    code = make_code("gray", 7, colours=3, order=rng.permutation(7))
    e = fiber_emission(0.1)
    np.testing.assert_array_equal(e, [[1, 0.1, 0.1], [0.1, 1, 0.1], [0.1, 0.1, 1]])
    coded = encode_colour(frames, code, e)
    explicit = np.zeros(coded.shape)
    for f in range(code.n_frames):
        for s in np.flatnonzero(code.matrix[f]):
            explicit[f] += frames[s].astype(np.float64) * e[:, code.channels[s]]
    # both sum the same float64 products and round once to float32; the order of the sum differs, which
    # moves the float64 result by ~1e-16 relative, far below float32's half ulp (3e-8) except at ties
    np.testing.assert_allclose(coded, explicit.astype(np.float32), rtol=1e-7, atol=0)


def test_unmixing_undoes_camera_crosstalk_and_fiber_leak():
    stack, _ = _colour_row([8, 20, 32, 44, 56])
    code = make_code("binary", 5, colours=3)
    rng = np.random.default_rng(5)
    x = np.eye(3) + rng.uniform(0.0, 0.3, (3, 3)) * (1 - np.eye(3))  # any crosstalk up to 30 %
    coded = coded_stack(stack, code, crosstalk=x, leak=0.07)
    np.testing.assert_allclose(coded.mixing, x @ fiber_emission(0.07), rtol=0, atol=1e-15)
    light = encode_colour(stack.frames, code)  # what pure fibers would give, before the camera
    u = unmix(coded.frames, coded.mixing)
    peak = float(light.max())
    # the camera frames are float32 (relative error 6e-8); the inverse of a matrix of condition ~2
    # at most doubles it, and the unmixed values are rounded to float32 once more: 1e-6 of the peak
    # bounds both with a wide margin
    assert np.abs(np.moveaxis(u, 0, -1) - light).max() < 1e-6 * peak
    # without the unmixing the camera's crosstalk puts tens of per cent in the wrong channel
    assert np.abs(coded.frames - light).max() > 0.05 * peak
    assert (coded.frames >= 0).all()


def test_camera_crosstalk_default_is_a_plausible_colour_camera():
    x = check_colour_matrix(CAMERA_CROSSTALK)
    off = x[~np.eye(3, dtype=bool)]
    assert np.array_equal(np.diag(x), [1.0, 1.0, 1.0]) and 0.01 <= off.min() and off.max() <= 0.2
    with pytest.raises(OptionError) as e:
        check_colour_matrix([[1, 1, 0], [1, 1, 0], [0, 0, 1]])  # red and green indistinguishable
    assert _field(e) == "crosstalk"
    with pytest.raises(OptionError) as e:
        check_colour_matrix(np.eye(2))
    assert _field(e) == "crosstalk"
    with pytest.raises(OptionError) as e:
        check_colour_matrix(-np.eye(3))
    assert _field(e) == "crosstalk"


def test_colour_sensor_digitises_each_channel_with_its_own_noise():
    stack, _ = _colour_row([8, 20, 32, 44, 56])
    code = make_code("gray", 5, colours=3)
    sensor = sensor_preset("machine_vision_12bit")
    a = coded_stack(stack, code, sensor=sensor, seed=4)
    b = coded_stack(stack, code, sensor=sensor, seed=4)
    np.testing.assert_array_equal(a.frames, b.frames)  # same seed, same frames
    assert a.frames.shape == (code.n_frames, 64, 64, 3) and a.saturation == 1.0
    dark = a.frames[0, :20, :20]  # no highlight there: black level plus noise
    level = sensor.dark_offset / sensor.full_scale
    assert abs(float(dark.mean()) - level) < 2.0 / sensor.full_scale
    # the channels' noise is independent: their correlation over 1200 dark pixels is ~1/sqrt(1200) = 0.03
    r = np.corrcoef(dark[..., 0].ravel(), dark[..., 1].ravel())[0, 1]
    assert abs(r) < 0.15
    np.testing.assert_array_equal(a.provenance["colour"]["mixing"], colour_mixing())
    np.testing.assert_array_equal(a.mixing, CAMERA_CROSSTALK)  # pure fibers: the camera's crosstalk alone


# -- decoding synthetic frames -------------------------------------------------------------------


@pytest.mark.parametrize("name", CODES)
def test_colour_decoding_of_separate_highlights_is_exact(name):
    cols = [6, 14, 22, 30, 38, 46, 54]
    stack, grey = _colour_row(cols)
    code = make_code(name, 7, colours=3)
    dec = decode(coded_stack(stack, code))
    truth = np.where((grey > 0).any(axis=0), grey.argmax(axis=0), -1)
    seq = reconstruct(Stack(grey, stack.rig), DetectParams())
    np.testing.assert_array_equal(dec.table["source"], seq.table["source"])
    # the same pixels, each holding one source's light; unmixing in float64 of float32 frames moves a
    # value by ~1e-7 relative, which moves centroids by far less than 1e-4 px
    assert np.abs(dec.table["row"] - seq.table["row"]).max() < 1e-4
    assert np.abs(dec.table["col"] - seq.table["col"]).max() < 1e-4
    lab = dec.labels
    assert ((lab >= 0) & (lab != truth)).sum() == 0
    if name in ("binary", "gray"):
        np.testing.assert_array_equal(lab, truth)  # every lit pixel, none other
    assert dec.counts["colour_collisions"] == 0
    assert (dec.channel[truth >= 0] == code.channels[truth[truth >= 0]]).all()


def _overlap(code_name):
    """Six sources in a row, 12 px apart, except sources 2 and 3 whose blobs are 2 px apart; their
    colours differ (channels along the order: 2 -> B, 3 -> R)."""
    stack, grey = _colour_row([8, 20, 32, 34, 46, 58])
    code = make_code(code_name, 6, colours=3, order=[0, 1, 2, 3, 4, 5])
    assert code.channels[2] != code.channels[3]
    return stack, grey, code


@pytest.mark.parametrize("name", CODES)
def test_overlapping_highlights_of_two_colours_are_reported_never_mislabelled(name):
    stack, grey, code = _overlap(name)
    coded = coded_stack(stack, code, sensor=None)
    dec = decode(coded)
    both = (grey[2] > 0) & (grey[3] > 0)
    tau = dec.noise["colour_tolerance"]
    ratio = np.minimum(grey[2], grey[3]) / np.maximum(grey[2], grey[3], where=both, out=np.ones_like(grey[2]))
    comparable = both & (ratio > tau)
    assert comparable.sum() > 10
    # noiseless: exactly the pixels where the weaker colour holds more than tau of the stronger
    np.testing.assert_array_equal(dec.collision & both, comparable)
    assert (dec.labels[comparable] == -1).all() and dec.counts["colour_collisions"] == comparable.sum()
    truth = np.where((grey > 0).any(axis=0), grey.argmax(axis=0), -1)
    lab = dec.labels
    assert ((lab >= 0) & (lab != truth)).sum() == 0  # never another source than the brightest
    assert any("colour tolerance" in note for note in dec.notes)
    # strict (tolerance 0): any light beyond noise in a second channel is a collision
    strict = decode(coded, colour_tolerance=0.0)
    np.testing.assert_array_equal(strict.collision & both, both)


def test_same_colour_collisions_stay_the_inner_codes():
    """Sources 2 and 5 share a colour (order: 2 -> B, 5 -> B); moved together, the inner Gray code flags them."""
    stack, grey = _colour_row([8, 20, 32, 46, 58, 34])
    code = make_code("gray", 6, colours=3, order=[0, 1, 2, 3, 4, 5])
    assert code.channels[2] == code.channels[5]
    dec = decode(coded_stack(stack, code), crosstalk=0)
    both = (grey[2] > 0) & (grey[5] > 0)
    assert both.sum() > 10
    np.testing.assert_array_equal(dec.collision & both, both)
    assert dec.counts["colour_collisions"] == 0 and (dec.labels[both] == -1).all()
    # within channel B the two are the 1st and 2nd sources: Gray codewords one bit apart, named
    assert {tuple(sorted(p)) for p in dec.pairs[both].tolist()} == {(2, 5)}


def test_tinted_surface_under_leaky_fibers_is_reported():
    """A gold-like tint (R, G, B reflectance 1, 0.8, 0.35) with 20 % fiber leak: the calibration (on a
    white target) unmixes a grey surface exactly but leaves a blue source's highlight light in R."""
    tint = (1.0, 0.8, 0.35)
    stack, grey = _colour_row([8, 20, 32, 44, 56], tint=tint)
    code = make_code("gray", 5, colours=3, order=[0, 1, 2, 3, 4])
    blue = np.flatnonzero(code.channels == 2)
    dec = decode(coded_stack(stack, code, leak=0.2))
    # theory: fiber B's light on the tint, v = (l t_R, l t_G, t_B), unmixed by E^-1 with E = (1 - l) I + l J
    l_, t = 0.2, np.array(tint)
    v = np.array([l_ * t[0], l_ * t[1], t[2]])
    u = np.linalg.solve(fiber_emission(l_), v)
    core = grey[blue[0]] > 0
    measured = dec.light[core][:, 0] / dec.light[core][:, 2]
    # noiseless and without crosstalk between blobs: the ratio is the theory's at every pixel, up to the
    # float32 rounding of frames and unmixing (1e-6 relative)
    np.testing.assert_allclose(measured, u[0] / u[2], rtol=1e-5)
    assert u[0] / u[2] > dec.noise["colour_tolerance"]  # 0.44 against 0.17: beyond the tolerance
    assert dec.collision[core].all() and (dec.labels[core] == -1).all()
    assert blue[0] not in dec.table["source"].tolist()
    truth = np.where((grey > 0).any(axis=0), grey.argmax(axis=0), -1)
    assert ((dec.labels >= 0) & (dec.labels != truth)).sum() == 0
    # the red and green sources' leak stays below the tolerance: decoded as without it
    assert sorted(dec.table["source"].tolist()) == sorted(set(range(5)) - set(blue.tolist()))
    # a grey surface under the same fibers: the calibration knows it all
    flat, _ = _colour_row([8, 20, 32, 44, 56])
    clean = decode(coded_stack(flat, code, leak=0.2))
    assert clean.counts["colour_collisions"] == 0 and sorted(clean.table["source"].tolist()) == list(range(5))


def test_colour_tolerance_is_checked():
    stack, _, code = _overlap("gray")
    coded = coded_stack(stack, code)
    bound = colour_tolerance_bound(code)  # 2 bits, default rho = 0.4: 1 - 0.8 / 1.4 = 0.43
    assert bound == pytest.approx(1 - 2 * 0.4 / 1.4)
    assert decode(coded).noise["colour_tolerance"] == pytest.approx(min(0.2, bound / 2))
    with pytest.raises(OptionError, match="below") as e:
        decode(coded, colour_tolerance=bound)
    assert _field(e) == "colour_tolerance"
    for bad in (-0.1, 1.0, float("nan"), "0.1"):
        with pytest.raises(OptionError) as e:
            DecodeParams(colour_tolerance=bad)
        assert _field(e) == "colour_tolerance"
    assert colour_tolerance_bound(make_code("hadamard", 6, colours=3)) == 1.0


def test_saturated_colour_frames_are_flagged_never_mislabelled():
    stack, grey = _colour_row([8, 20, 32, 44, 56])
    code = make_code("gray", 5, colours=3)
    truth = np.where((grey > 0).any(axis=0), grey.argmax(axis=0), -1)
    coded = coded_stack(stack, code, sensor=sensor_preset("machine_vision_12bit"), exposure=5.0, seed=1)
    dec = decode(coded)
    np.testing.assert_array_equal(dec.saturated, (coded.frames >= 1.0).any(axis=(0, 3)))
    assert dec.counts["saturated"] > 5 * 5  # every highlight's core
    assert dec.table["saturated"].all()
    assert ((dec.labels >= 0) & (dec.labels != truth)).sum() == 0
    assert any("clip level" in note for note in dec.notes)


@pytest.mark.parametrize("name", ["sequential", "hadamard"])
def test_hot_pixels_of_one_colour_channel_make_no_highlights(name):
    """A hot pixel of one camera channel lights every frame of one colour only, a third of the sources."""
    stack, grey = _colour_row(4.0 + 8.0 * np.arange(15), size=128)
    code = make_code(name, 15, colours=3)
    sensor = Sensor(name="hot", bits=12, full_well=10_500.0, read_noise=2.5, dark_offset=40.0,
                    hot_pixel_fraction=5e-4, hot_pixel_level=0.5)
    assert sensor.hot_pixels((128, 128)).sum() >= 3  # the fixed pattern of channel R alone
    dec = decode(coded_stack(stack, code, sensor=sensor, seed=2))
    assert dec.table["source"].tolist() == list(range(15))  # one highlight per source, none at a hot pixel
    assert any("hot pixel" in note for note in dec.notes)


def test_colour_bad_input_names_the_field():
    stack, grey = _colour_row([8, 20, 32, 44, 56])
    code = make_code("gray", 5, colours=3)
    plain = make_code("gray", 5)
    with pytest.raises(OptionError, match="colour code") as e:
        coded_stack(stack, plain)
    assert _field(e) == "code"
    with pytest.raises(OptionError, match="colour code") as e:
        coded_stack(Stack(grey, stack.rig), code)
    assert _field(e) == "code"
    with pytest.raises(OptionError) as e:
        coded_stack(Stack(grey, stack.rig), plain, leak=0.1)
    assert _field(e) == "leak"
    with pytest.raises(OptionError) as e:
        coded_stack(stack, code, leak=1.0)
    assert _field(e) == "leak"
    with pytest.raises(OptionError) as e:
        coded_stack(stack, code, crosstalk=np.ones((3, 3)))
    assert _field(e) == "crosstalk"
    with pytest.raises(OptionError) as e:
        coded_stack(stack, make_code("gray", 4, colours=3))
    assert _field(e) == "code"
    coded = coded_stack(stack, code)
    with pytest.raises(OptionError) as e:
        decode(coded.frames, code=code)  # raw colour frames need the calibration
    assert _field(e) == "mixing"
    with pytest.raises(OptionError) as e:
        decode(coded.frames, code=code, mixing=np.zeros((3, 3)))
    assert _field(e) == "mixing"
    with pytest.raises(FrameError) as e:
        decode(coded.frames[..., 0], code=code, mixing=coded.mixing)
    assert _field(e) == "frames"
    plain_coded = coded_stack(Stack(grey, stack.rig), plain)
    with pytest.raises(OptionError) as e:
        decode(plain_coded, mixing=coded.mixing)
    assert _field(e) == "mixing"
    with pytest.raises(OptionError) as e:
        decode(coded.frames, code=make_code("hadamard", 5, colours=3), mixing=coded.mixing)
    assert _field(e) == "frames"  # 3 Hadamard frames, not 6
    with pytest.raises(OptionError) as e:
        ColourStack(grey, stack.rig)
    assert _field(e) == "frames"
    with pytest.raises(OptionError) as e:
        encode_colour(stack.frames, plain)
    assert _field(e) == "code"
    # the same frames decode alike from the array with the calibration given
    again = decode(coded.frames, code=code, mixing=coded.mixing, noise_sigma=0.0)
    np.testing.assert_array_equal(again.labels, decode(coded).labels)


# -- rendering in colour ------------------------------------------------------------------------

N_SOURCES, RESOLUTION, SPP = 60, 128, 16


@pytest.fixture(scope="module")
def renders():
    """The dome scan rendered in mono and in colour (grey sphere), and the colour render of a tinted one."""
    import mitsuba as mi

    from shinysim.sim.render import Simulator
    from shinysim.studies.coded import coded_rig, scan_object

    obj = scan_object("sphere", alpha=0.02)
    rig = coded_rig("dome", n_sources=N_SOURCES, resolution=RESOLUTION, anchor=obj.anchor)
    mono = Simulator(rig, obj.objects)
    first = mono.render_stack(spp=SPP, seed=0)
    before = mi.variant()
    colour = Simulator(rig, obj.objects, colour=True)
    after = mi.variant()
    rgb = colour.render_colour_stack(spp=SPP, seed=0)
    again = mono.render_stack(spp=SPP, seed=0)
    # a copper-like conductor with RGB eta and k (Mitsuba's Cu values, rounded)
    eta, k = [0.2, 0.92, 1.10], [3.91, 2.45, 2.14]
    tinted = {name: {**shape, "bsdf": {**{key: v for key, v in shape["bsdf"].items() if key != "material"},
                                       "eta": {"type": "rgb", "value": eta}, "k": {"type": "rgb", "value": k}}}
              for name, shape in obj.objects.items()}
    copper = Simulator(rig, tinted, colour=True).render_colour_stack(spp=SPP, seed=0)
    gold = Simulator(rig, scan_object_with(obj, "Au"), colour=True).render_colour_stack(spp=SPP, seed=0)
    return {"rig": rig, "mono": first, "again": again, "rgb": rgb, "copper": copper, "eta": eta, "k": k,
            "gold": gold, "variants": (before, after, colour.variant), "sim": colour}


def scan_object_with(obj, material):
    """The scan object's shapes with a Mitsuba named conductor material."""
    return {name: {**shape, "bsdf": {**shape["bsdf"], "material": material}} for name, shape in obj.objects.items()}


@requires_jit
def test_grey_conductor_renders_three_equal_channels_equal_to_mono(renders):
    rgb, mono = renders["rgb"], renders["mono"]
    assert rgb.frames.shape == (N_SOURCES, RESOLUTION, RESOLUTION, 3)
    # the one-pass renderer draws the same samples in both variants and a grey mirror reflects the three
    # channels alike, with the same float operations: bit for bit the mono render
    for c in range(3):
        np.testing.assert_array_equal(rgb.frames[..., c], mono.frames)
    assert rgb.provenance["variant"].endswith("_rgb") and rgb.provenance["colour"]
    np.testing.assert_array_equal(renders["sim"].render_stack(spp=SPP, seed=0).frames, mono.frames)


@requires_jit
def test_colour_simulator_leaves_the_mono_one_working(renders):
    before, after, colour_variant = renders["variants"]
    assert colour_variant.endswith("_rgb") and not before.endswith("_rgb")
    assert after == before  # the colour Simulator put the active variant back
    np.testing.assert_array_equal(renders["again"].frames, renders["mono"].frames)


def _conductor_reflectance(eta, k, cos_i):
    """Unpolarised Fresnel reflectance of a conductor of complex index eta + i k from air."""
    n = eta + 1j * k
    sin2 = 1 - cos_i**2
    cos_t = np.sqrt(1 - sin2 / n**2)
    rs = (cos_i - n * cos_t) / (cos_i + n * cos_t)
    rp = (n * cos_i - cos_t) / (n * cos_i + cos_t)
    return 0.5 * (abs(rs) ** 2 + abs(rp) ** 2)


@requires_jit
def test_coloured_conductor_tints_the_highlights(renders):
    grey, copper = renders["rgb"].frames, renders["copper"].frames
    sums = copper.astype(np.float64).sum(axis=(0, 1, 2))
    ratio = sums / sums[0]
    # the same samples in every channel: each channel is the geometry weighted by the Fresnel reflectance
    # at each sample's microfacet, so G/R and B/R are weighted means of the per-sample ratio F_c / F_R and
    # lie between its extremes over the incidence angles of the samples. On a mirror sphere under a dome
    # whose rim is at 80 degrees, the microfacet incidence is at most 40 degrees (half the angle between
    # view and source); 45 covers the rough lobe's tails
    angles = np.radians(np.linspace(0.0, 45.0, 46))
    f = np.array([[_conductor_reflectance(e, kk, math.cos(a)) for a in angles]
                  for e, kk in zip(renders["eta"], renders["k"])])
    for c in (1, 2):
        lo, hi = (f[c] / f[0]).min(), (f[c] / f[0]).max()
        assert lo <= ratio[c] <= hi, (c, ratio[c], lo, hi)
    assert ratio[2] < ratio[1] < 0.7  # copper: red, then green, then blue
    # the tint multiplies, it does not move the light: the red channel is the grey render times F_R
    f_r = copper[..., 0].astype(np.float64).sum() / grey[..., 0].astype(np.float64).sum()
    assert f[0].min() <= f_r <= f[0].max()


@pytest.fixture(scope="module")
def sequential(renders):
    from shinysim.studies.coded import pixel_owner

    stack = renders["mono"]
    return reconstruct(stack, DetectParams()), pixel_owner(stack.frames)


@requires_jit
@pytest.mark.parametrize("name", CODES)
@pytest.mark.parametrize("sensor", [None, "machine_vision_12bit"])
def test_rendered_colour_scan_decodes_as_the_sequential_scan(renders, sequential, name, sensor):
    from shinysim.studies.coded import decoding_errors

    rig = renders["rig"]
    order = spatial_order(rig.source_positions)
    code = make_code(name, N_SOURCES, colours=3, order=order,
                     channels=colour_channels(rig.source_positions, order=order))
    coded = coded_stack(renders["rgb"], code, sensor=sensor and sensor_preset(sensor), seed=1)
    dec = decode(coded)
    seq, owner = sequential
    errs = decoding_errors(dec, owner, seq.table)
    assert len(seq.table["source"]) == N_SOURCES
    # every highlight found once, with its source
    assert errs["errors"] == errs["missed"] == errs["spurious"] == 0
    assert sorted(dec.table["source"].tolist()) == list(range(N_SOURCES))
    if name in ("binary", "gray"):
        # complementary codes label a pixel only with its brightest source (the tolerances' guarantee)
        assert errs["pixel_errors"] == 0
    p = np.searchsorted(seq.table["source"], dec.table["source"])
    shift = np.hypot(dec.table["row"] - seq.table["row"][p], dec.table["col"] - seq.table["col"][p])
    if sensor is None and name in ("sequential", "hadamard"):
        # demultiplexing gives each source's own light: the sequential frames up to float32 rounding
        assert shift.max() < 1e-3
    elif sensor is None:
        # a decoded pixel's signal holds the few per cent of crosstalk that shares its codeword: in a highlight
        # of 2-3 px with a pixel at 0.499 of the peak that crosses the 0.5 threshold and moves the centroid
        # 0.26 px (the mono Gray and binary codes do the same on this render); every other highlight stays put
        assert shift.max() < 0.3 and np.median(shift) < 1e-3
    else:
        # noise moves pixels across the 0.5 threshold, as in a sequential scan through the same sensor
        # (test_coding.py: up to 0.29 px); measured here up to 0.33 px, median 0.003 px
        assert shift.max() < 0.5 and np.median(shift) < 0.01


@requires_jit
def test_rendered_gold_under_leaky_fibers_flags_blue_and_decodes_the_rest(renders):
    """Gold reflects blue at about a third of red: with 20 % fiber leak the white-target calibration leaves
    a blue fiber's highlight light in the red channel, beyond the colour tolerance; red and green stay clean."""
    from shinysim.studies.coded import pixel_owner

    rig, gold = renders["rig"], renders["gold"]
    order = spatial_order(rig.source_positions)
    code = make_code("gray", N_SOURCES, colours=3, order=order,
                     channels=colour_channels(rig.source_positions, order=order))
    leak = 0.2
    dec = decode(coded_stack(gold, code, leak=leak))
    tau = dec.noise["colour_tolerance"]
    # the theory's unmixed light of each fiber on the gold's mean tint (channel sums of the render)
    t = gold.frames.astype(np.float64).sum(axis=(0, 1, 2))
    t /= t[0]
    assert t[2] < 0.5 < t[1]  # gold: blue reflected least
    e = fiber_emission(leak)
    u = np.linalg.solve(e, e * t[:, None])  # column c: fiber c's light on the tint, unmixed
    other = np.array([np.delete(u[:, c], c).max() / u[c, c] for c in range(3)])
    # the premise: blue far beyond the tolerance, red and green far below it
    assert other[2] > 2 * tau and other[0] < tau / 2 and other[1] < tau / 2
    own = np.stack([gold.frames[s_, ..., code.channels[s_]] for s_ in range(N_SOURCES)])
    owner = pixel_owner(own)
    lab = dec.labels
    assert ((lab >= 0) & (lab != owner)).sum() == 0  # never mislabelled
    found = set(dec.table["source"].tolist())
    blue = set(np.flatnonzero(code.channels == 2).tolist())
    peak = own.max(axis=(1, 2))
    for s_ in range(N_SOURCES):
        core = (owner == s_) & (own[s_] >= 0.5 * peak[s_])
        if s_ in blue:
            assert dec.collision[core].all(), s_  # reported at its highlight ...
            assert s_ not in found  # ... and not decoded
        else:
            assert s_ in found and not dec.collision[core].any(), s_
    assert dec.counts["colour_collisions"] > 0


@requires_jit
def test_per_source_colour_render_matches_mono():
    """The per-source renderer (Mitsuba's own integrator and film) in colour: R, G and B of a grey mirror
    equal the mono render's luminance."""
    from shinysim.sim.render import Simulator
    from shinysim.studies.coded import coded_rig, scan_object

    obj = scan_object("sphere", alpha=0.02)
    rig = coded_rig("dome", n_sources=6, resolution=48, anchor=obj.anchor)
    mono = Simulator(rig, obj.objects).render_stack(spp=4, seed=3, method="per-source").frames
    rgb = Simulator(rig, obj.objects, colour=True).render_colour_stack(spp=4, seed=3, method="per-source")
    assert rgb.provenance["method"] == "per-source" and mono.max() > 0
    # the same samples; the mono film stores luminance 0.2126 R + 0.7152 G + 0.0722 B of equal channels,
    # which is R up to float32 rounding of that sum (a few 1e-7 relative)
    for c in range(3):
        np.testing.assert_allclose(rgb.frames[..., c], mono, rtol=1e-6, atol=1e-6 * float(mono.max()))
    with pytest.raises(ValueError, match="colour"):
        Simulator(rig, obj.objects).render_colour_stack(spp=1)
    with pytest.raises(OptionError) as e:
        Simulator(rig, obj.objects, colour=True, variant="llvm_ad_mono")
    assert _field(e) == "variant"
