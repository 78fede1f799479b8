"""The sensor model: determinism, quantisation, clipping and noise statistics.

Statistical checks compare a sample variance (or rms) of ``n`` pixels with its
expectation. For near-Gaussian samples the sample variance has relative
standard deviation ``sqrt(2 / n)`` and a sample rms ``sqrt(1 / (2 n))``; each
check allows 5 of those standard deviations (a false failure about once in
two million runs), stated beside it. Everything but the last test is numpy only.
"""

import ast
import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import requires_render

from shinysim.errors import OptionError
from shinysim.io import Stack
from shinysim.rig import Camera, distant_rig
from shinysim.sim.sensor import SENSOR_BITS, SENSOR_PRESETS, Sensor, sensor_preset

#: A quiet sensor (no noise, no fixed pattern) that tests switch single effects on in.
QUIET = Sensor(bits=16, exposure=5_000.0, full_well=10_000.0, read_noise=0.0, shot_noise=False)


def five_sigma_var(n):
    """Allowed relative error of a sample variance of ``n`` near-Gaussian values (5 sigma)."""
    return 5 * math.sqrt(2 / n)


def five_sigma_rms(n):
    """Allowed relative error of a sample rms of ``n`` near-Gaussian values (5 sigma)."""
    return 5 * math.sqrt(1 / (2 * n))


def make_stack(frames):
    frames = np.asarray(frames, np.float32)
    n, h, w = frames.shape
    cam = Camera("orthographic", w, h, [0, 0, 10.0], [0, 0, 0], [0, 1, 0], 2.0)
    dirs = np.tile([0.0, 0.0, 1.0], (n, 1)) + np.linspace(0, 0.5, n)[:, None] * [1, 0, 0]
    return Stack(frames, distant_rig(dirs, cam), 0, {"radiance": 1.0, "seed": 3, "notes": {"a": [1]}})


def ramp(n=3, h=16, w=20):
    return np.linspace(0, 1.2, n * h * w).reshape(n, h, w)


# -- determinism ------------------------------------------------------------------------


def test_same_seed_bit_identical_different_seed_differs():
    s = SENSOR_PRESETS["machine_vision_12bit"]
    a = s.capture(ramp(), seed=7)
    b = s.capture(ramp(), seed=7)
    c = s.capture(ramp(), seed=8)
    assert a.dtype == np.float32 and a.shape == ramp().shape
    assert a.tobytes() == b.tobytes()
    assert (a != c).mean() > 0.5


def test_frame_k_independent_of_frame_count():
    s = SENSOR_PRESETS["tv_1980s_8bit"]
    radiance = ramp(n=5)
    all5 = s.capture(radiance, seed=3)
    first2 = s.capture(radiance[:2], seed=3)
    np.testing.assert_array_equal(all5[:2], first2)
    # a single (H, W) frame is frame 0
    np.testing.assert_array_equal(s.capture(radiance[0], seed=3), all5[0])
    # frames differ from each other (their noise streams are independent)
    assert not np.array_equal(s.capture(np.stack([radiance[0]] * 2), seed=3)[1], all5[0])


def test_rng_instead_of_seed_is_reproducible():
    s = SENSOR_PRESETS["machine_vision_12bit"]
    a = s.capture(ramp(), rng=np.random.default_rng(5))
    b = s.capture(ramp(), rng=np.random.default_rng(5))
    assert a.tobytes() == b.tobytes()
    with pytest.raises(OptionError, match="seed or rng"):
        s.capture(ramp())
    with pytest.raises(OptionError, match="seed or rng"):
        s.capture(ramp(), seed=1, rng=np.random.default_rng(1))


def test_fixed_pattern_from_pattern_seed_only():
    s = Sensor(prnu=0.01, hot_pixel_fraction=0.05)
    np.testing.assert_array_equal(s.prnu_map((32, 32)), s.prnu_map((32, 32)))
    np.testing.assert_array_equal(s.hot_pixels((32, 32)), replace(s, exposure=3.0).hot_pixels((32, 32)))
    other = replace(s, pattern_seed=1)
    assert not np.array_equal(s.prnu_map((32, 32)), other.prnu_map((32, 32)))
    assert not np.array_equal(s.hot_pixels((32, 32)), other.hot_pixels((32, 32)))


# -- stacks -------------------------------------------------------------------------------


def test_expose_keeps_ideal_and_records_sensor():
    ideal = make_stack(ramp())
    before = ideal.frames.copy()
    prov_before = json.dumps(ideal.provenance, sort_keys=True)
    s = SENSOR_PRESETS["tv_1980s_8bit"]
    out = s.expose(ideal, seed=11)
    assert out is not ideal
    np.testing.assert_array_equal(ideal.frames, before)
    assert json.dumps(ideal.provenance, sort_keys=True) == prov_before and ideal.saturation is None
    assert out.saturation == 1.0
    assert out.provenance["sensor"] == s.to_dict() and out.provenance["sensor_seed"] == 11
    assert out.provenance["radiance"] == 1.0 and out.provenance["notes"] == {"a": [1]}
    assert Sensor.from_dict(out.provenance["sensor"]) == s
    json.dumps(out.provenance)  # plain JSON
    np.testing.assert_array_equal(out.frames, s.capture(ideal.frames, seed=11))
    assert out.rig is ideal.rig and out.camera_index == ideal.camera_index


def test_expose_refuses_a_digitised_stack():
    s = SENSOR_PRESETS["machine_vision_12bit"]
    once = s.expose(make_stack(ramp()), seed=1)
    with pytest.raises(OptionError, match="digitised already"):
        s.expose(once, seed=2)
    with pytest.raises(OptionError, match="Stack"):
        s.expose(ramp(), seed=2)


# -- quantisation, clipping, black level ---------------------------------------------------------


@pytest.mark.parametrize("bits", SENSOR_BITS)
def test_only_multiples_of_one_code(bits):
    s = Sensor(bits=bits, exposure=8_000.0, full_well=10_000.0, dark_offset=3.0, prnu=0.01)
    f = s.capture(ramp(), seed=0).astype(np.float64) * (2**bits - 1)
    np.testing.assert_allclose(f, np.rint(f), atol=1e-3)
    assert f.min() >= 0 and f.max() <= 2**bits - 1
    assert len(np.unique(np.rint(f))) > 20


def test_full_well_clips_to_the_top_code():
    s = SENSOR_PRESETS["machine_vision_12bit"]
    frames = np.zeros((2, 9, 9))
    frames[:, 4, 4] = 1e6  # a million times the radiance that fills the well
    frames[1, 0, 0] = 3e38  # near the float32 limit
    out = s.expose(make_stack(frames), seed=0)
    assert out.saturation == 1.0
    assert out.frames[0, 4, 4] == 1.0 and out.frames[1, 4, 4] == 1.0 and out.frames[1, 0, 0] == 1.0
    assert out.frames[0].max() == 1.0 and np.sort(out.frames[0].ravel())[-2] < 0.1
    assert s.capture(np.full((2, 2), 1e300), seed=0).min() == 1.0  # float64 radiance far beyond
    # a full well exactly reads the top code, whatever the black level
    assert QUIET.with_exposure(QUIET.full_well).capture(np.ones((3, 3)), seed=0).min() == 1.0


def test_dark_offset_is_the_black_level():
    dark = np.zeros((4, 128, 128))
    s = Sensor(bits=8, exposure=1.0, full_well=50_000.0, read_noise=0.0, dark_offset=8.0)
    np.testing.assert_array_equal(s.capture(dark, seed=1) * 255, np.full(dark.shape, 8.0, np.float32))
    # with read noise and a non-integer offset, the mean still sits at the offset: 5 sigma of the mean
    s = replace(s, read_noise=200.0, dark_offset=8.3)
    f = s.capture(dark, seed=1).astype(np.float64) * 255
    sigma = s.noise_sigma(0.0)
    assert abs(f.mean() - 8.3) < 5 * sigma / math.sqrt(f.size)


# -- noise statistics ------------------------------------------------------------------------------


def test_shot_noise_variance_is_gain2_n_plus_quantisation():
    # 8 bits, 50 ke- full well: gain 0.0051 DN/e-; 25 ke- gives gain^2 N = 0.650 DN^2, and the
    # 1/12 DN^2 of quantisation is 11% of the total, more than the 2.8% tolerance
    s = Sensor(bits=8, exposure=25_000.0, full_well=50_000.0, read_noise=0.0)
    f = s.capture(np.ones((4, 128, 128)), seed=2).astype(np.float64) * 255
    expected = s.gain**2 * 25_000 + 1 / 12
    measured = f.var(ddof=1)
    assert abs(measured / expected - 1) < five_sigma_var(f.size), (measured, expected)
    assert abs(f.mean() - s.gain * 25_000) < 5 * math.sqrt(expected / f.size)
    # and at 12 bits, where the shot term dominates
    s = Sensor(bits=12, exposure=5_000.0, full_well=10_000.0, read_noise=0.0)
    f = s.capture(np.ones((4, 128, 128)), seed=2).astype(np.float64) * 4095
    expected = s.gain**2 * 5_000 + 1 / 12
    assert abs(f.var(ddof=1) / expected - 1) < five_sigma_var(f.size)


def test_read_noise_variance():
    # no shot noise: 200 e- rms at 0.0047 DN/e- is 0.94 DN rms, plus 1/12 DN^2
    s = Sensor(bits=8, exposure=25_000.0, full_well=50_000.0, read_noise=200.0, dark_offset=20.0,
               shot_noise=False)
    f = s.capture(np.ones((4, 128, 128)), seed=4).astype(np.float64) * 255
    expected = (s.gain * 200.0) ** 2 + 1 / 12
    assert abs(f.var(ddof=1) / expected - 1) < five_sigma_var(f.size), (f.var(ddof=1), expected)


def test_gaussian_shot_noise_above_the_poisson_limit():
    # 4e6 mean electrons in a 5e6 well: Gaussian approximation, variance still gain^2 N (687 DN^2)
    s = Sensor(bits=16, exposure=4e6, full_well=5e6, read_noise=0.0)
    f = s.capture(np.ones((2, 128, 128)), seed=5).astype(np.float64) * 65535
    expected = s.gain**2 * 4e6 + 1 / 12
    assert abs(f.var(ddof=1) / expected - 1) < five_sigma_var(f.size)


@pytest.mark.parametrize("fill", [0.05, 0.3, 0.7])
def test_noise_sigma_matches_measured_temporal_noise(fill):
    s = replace(SENSOR_PRESETS["machine_vision_12bit"], vignetting=0.0).exposed_for(1.0, fill)
    f = s.capture(np.ones((2, 128, 128)), seed=6).astype(np.float64) * s.full_scale
    keep = ~s.hot_pixels((128, 128))
    diff = (f[0] - f[1])[keep]  # the fixed pattern (PRNU) cancels in a frame difference
    measured = diff.std(ddof=1) / math.sqrt(2)
    expected = s.noise_sigma(f.mean() - s.dark_offset)
    assert abs(measured / expected - 1) < five_sigma_rms(diff.size), (measured, expected)


# -- fixed pattern and lens ------------------------------------------------------------------------


def test_prnu_rms_on_a_flat_bright_field():
    s = replace(QUIET, prnu=0.02)
    f = s.capture(np.ones((1, 256, 256)), seed=0)[0].astype(np.float64)
    measured = f.std(ddof=1) / f.mean()
    # 65536 pixels: 5 sigma of an rms is 1.4%; 16-bit quantisation adds 1e-5
    assert abs(measured / 0.02 - 1) < five_sigma_rms(f.size), measured
    np.testing.assert_allclose(f, 0.5 * s.prnu_map((256, 256)), atol=1 / 65535)


def test_hot_pixels_count_and_place():
    s = Sensor(bits=8, exposure=1.0, full_well=50_000.0, read_noise=0.0, dark_offset=8.0,
               hot_pixel_fraction=0.01, hot_pixel_level=0.5)
    n = 256 * 256
    hot = s.hot_pixels((256, 256))
    # binomial: n p = 655 hot pixels expected, sd sqrt(n p (1 - p)) = 25.5; 5 sd allowed
    assert abs(hot.sum() - n * 0.01) < 5 * math.sqrt(n * 0.01 * 0.99)
    f = s.capture(np.zeros((3, 256, 256)), seed=9) * 255
    for k in range(3):
        np.testing.assert_array_equal(f[k] > 100, hot)
    assert set(np.unique(f[:, hot])) == {136.0}  # 8 + rint(127.5)
    assert set(np.unique(f[:, ~hot])) == {8.0}


@pytest.mark.parametrize("vignetting", [0.05, 0.25, 0.6])
def test_vignetting_centre_to_corner(vignetting):
    s = replace(QUIET, vignetting=vignetting)
    f = s.capture(np.ones((65, 65)), seed=0).astype(np.float64)
    corners = f[[0, 0, -1, -1], [0, -1, 0, -1]]
    np.testing.assert_allclose(corners / f[32, 32], 1 - vignetting, atol=1e-4)
    v = s.vignette((40, 51))  # even and odd sides: the centre falls between pixels
    np.testing.assert_allclose(v[[0, 0, -1, -1], [0, -1, 0, -1]], 1 - vignetting, rtol=1e-12)
    assert v.max() < 1 and v.max() > 1 - vignetting / 100
    np.testing.assert_allclose(v, v[::-1, ::-1], rtol=1e-12)
    row = s.vignette((65, 65))[32]
    assert np.all(np.diff(row[32:]) < 0)  # falls off monotonically
    # the cos^4 law: v = cos^4(theta) with tan(theta) proportional to the radius
    theta_c = math.acos((1 - vignetting) ** 0.25)
    theta_half = math.atan(0.5 * math.tan(theta_c))
    rc = math.hypot(32, 32)
    r = rc / 2  # a pixel at half the corner radius, along the diagonal
    i = 32 + round(r / math.sqrt(2))
    assert abs(math.hypot(i - 32, i - 32) - r) < 1e-9
    assert s.vignette((65, 65))[i, i] == pytest.approx(math.cos(theta_half) ** 4, rel=1e-12)
    assert Sensor().vignette((8, 8)).min() == 1.0 and replace(QUIET, vignetting=0.3).vignette((1, 1))[0, 0] == 1.0


# -- presets, exposure, JSON -------------------------------------------------------------------------


def test_presets():
    assert SENSOR_PRESETS["ideal"] is None and sensor_preset("ideal") is None
    tv, mv = sensor_preset("tv_1980s_8bit"), sensor_preset("machine_vision_12bit")
    assert (tv.bits, mv.bits) == (8, 12)
    assert tv.name == "tv_1980s_8bit" and mv.name == "machine_vision_12bit"
    assert tv.read_noise * tv.gain == pytest.approx(0.5, abs=0.05)  # about half a code of analogue noise
    assert mv.read_noise * mv.gain < 1.5
    for s in (tv, mv):
        assert Sensor.from_dict(s.to_dict()) == s
        assert s.exposure == pytest.approx(0.8 * s.full_well)  # radiance 1 at 80% of the full well
    with pytest.raises(OptionError, match="tv_1980s_8bit") as err:
        sensor_preset("tv_1980s")
    assert "did you mean" in str(err.value) and "machine_vision_12bit" in str(err.value)


@pytest.mark.parametrize("name", ["tv_1980s_8bit", "machine_vision_12bit"])
@pytest.mark.parametrize("fraction", [0.5, 0.8])
def test_exposed_for_puts_the_peak_at_the_fraction(name, fraction):
    s = SENSOR_PRESETS[name].exposed_for(np.array([[0.1, 2.5]]), fraction)
    assert s.exposure * 2.5 == pytest.approx(fraction * s.full_well, rel=1e-12)
    assert s.name == name and SENSOR_PRESETS[name].exposure == pytest.approx(0.8 * s.full_well)
    noiseless = replace(s, shot_noise=False, read_noise=0.0, prnu=0.0, vignetting=0.0, hot_pixel_fraction=0.0)
    dn = noiseless.capture(np.full((4, 4), 2.5), seed=0) * s.full_scale
    np.testing.assert_allclose(dn, s.dark_offset + fraction * (s.full_scale - s.dark_offset), atol=0.5)
    with pytest.raises(OptionError, match="peak_radiance"):
        s.exposed_for(0.0)
    with pytest.raises(OptionError, match="fraction"):
        s.exposed_for(1.0, 0.0)


def test_dict_round_trip_and_unknown_keys():
    s = Sensor(name="x", bits=10, exposure=123.0, prnu=0.01, hot_pixel_fraction=1e-3, vignetting=0.1,
               pattern_seed=4, shot_noise=False)
    d = json.loads(json.dumps(s.to_dict()))
    assert Sensor.from_dict(d) == s and hash(Sensor.from_dict(d)) == hash(s)
    assert Sensor.from_dict({"bits": 8}) == Sensor(bits=8)
    with pytest.raises(OptionError, match="did you mean 'read_noise'") as err:
        Sensor.from_dict({**d, "readnoise": 1.0})
    assert err.value.field == "sensor"
    with pytest.raises(OptionError, match="JSON object"):
        Sensor.from_dict([1, 2])
    with pytest.raises(OptionError, match="bits"):
        Sensor.from_dict({**d, "bits": 14})


@pytest.mark.parametrize("field, value", [
    ("bits", 7), ("bits", True), ("bits", 12.5),
    ("read_noise", -1.0), ("full_well", 0.0), ("exposure", float("nan")), ("exposure", 0.0),
    ("dark_offset", 255.0), ("dark_offset", -1.0), ("prnu", -0.1), ("hot_pixel_fraction", 1.5),
    ("hot_pixel_level", 2.0), ("vignetting", 1.0), ("shot_noise", "yes"), ("pattern_seed", -1),
    ("pattern_seed", 1.5), ("name", 3),
])
def test_bad_parameters_name_the_field(field, value):
    kwargs = {"bits": 8} if field == "dark_offset" else {}
    with pytest.raises(OptionError, match=field) as err:
        Sensor(**{**kwargs, field: value})
    assert err.value.field == field


@pytest.mark.parametrize("radiance, words", [
    (-np.ones((2, 3, 3)), "negative"), (np.full((2, 3, 3), np.nan), "NaN"), (np.ones(5), "shape"),
    (np.ones((1, 1, 3, 3)), "shape"), ("bright", "numbers"),
])
def test_bad_radiance(radiance, words):
    with pytest.raises(OptionError, match=words) as err:
        Sensor().capture(radiance, seed=0)
    assert err.value.field == "radiance"


def test_bad_seed_and_signal():
    with pytest.raises(OptionError, match="seed"):
        Sensor().capture(np.ones((2, 2)), seed=-1)
    with pytest.raises(OptionError, match="seed"):
        Sensor().expose(make_stack(ramp()), seed=1.5)
    with pytest.raises(OptionError, match="signal_dn"):
        Sensor().noise_sigma(-1.0)
    assert Sensor(read_noise=0.0, shot_noise=False).noise_sigma(100.0) == pytest.approx(math.sqrt(1 / 12))
    assert Sensor().noise_sigma(np.array([0.0, 100.0])).shape == (2,)


def test_module_imports_no_renderer():
    source = Path(__file__).resolve().parents[1] / "shinysim" / "sim" / "sensor.py"
    tree = ast.parse(source.read_text())
    names = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    names |= {n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    assert not {m for m in names if m.split(".")[0] in ("mitsuba", "drjit", "trimesh")}


# -- with the renderer --------------------------------------------------------------------------------


@requires_render
def test_expose_a_rendered_stack():
    from shinysim.rig import shiny_1988
    from shinysim.sim.render import Simulator
    from shinysim.sim.scene import sphere_object

    ideal = Simulator(shiny_1988(resolution=32, n_sources=3), sphere_object(alpha=0.02)).render_stack(spp=4, seed=0)
    before = ideal.frames.copy()
    s = sensor_preset("machine_vision_12bit").exposed_for(ideal.frames)
    out = s.expose(ideal, seed=1)
    np.testing.assert_array_equal(ideal.frames, before)
    assert out.provenance["radiance"] == ideal.provenance["radiance"]
    assert out.provenance["sensor"]["name"] == "machine_vision_12bit" and out.saturation == 1.0
    assert out.frames.max() <= 1.0 and out.frames.shape == ideal.frames.shape
    # the brightest pixel lands near 80% of the range above the black level
    top = out.frames.max() * s.full_scale
    assert abs(top - (s.dark_offset + 0.8 * (s.full_scale - s.dark_offset))) < 0.15 * s.full_scale
