"""The fringe twin: a phase code shown on SOFAST's screen, seen in a small facet, decoded against exact truth.

Where each pixel centre sees the screen against the reflection law; the frames
of any pattern as exact means over one trace's samples; and SOFAST's code
rendered, decoded and scored in display pixels (a 1920 x 1080 display over
the lit screen): the decoded position is the pixel centre's up to Monte-Carlo
noise, with no systematic error above 0.01 px; under an 8-bit 1980s sensor,
the noise follows the noise law; the display's gamma biases the phase as its
harmonics say.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from conftest import requires_jit

from shinysim.errors import OptionError
from shinysim.recon.phase import DisplayResponse, decode_phase
from shinysim.sim.display import (MAX_SCREEN_HITS, ScreenHits, mask_frames, pattern_frames, render_fringe_frames,
                                  screen_fraction_truth, sofast_like_setup, trace_screen_hits)
from shinysim.sim.sensor import SENSOR_PRESETS, Sensor
from shinysim.studies.deflect import sofast_geometry, twin_facet
from shinysim.theory.phase import PhaseCode, position_noise

#: Display pixels per screen width and height: decoded errors are reported in them.
DISPLAY_PX = np.array([1920.0, 1080.0])
#: The twin's facet mesh, 1e-5 mm from the exact surface. At the package's default (1e-4 mm, 3.2 mm cells) the
#: mesh's interpolated normals err by ~(k h)^2 / 12 of the ripple's slope (1.3e-6 rad), which moves the decoded
#: position by 0.019 display px in step with the ripple; at 1e-5 mm (1 mm cells) that is ten times less.
MESH_TOLERANCE_MM = 1e-5
SPP = 64


def twin_setup():
    camera, rot, origin, dots, xi, yi, _ = sofast_geometry(None)
    return sofast_like_setup(camera, rot, origin, dots, xi, yi, facet=twin_facet("small"))


def twin_window(setup, margin_px=6):
    """The window that holds the facet's image and ``margin_px`` around it (as render_twin chooses it)."""
    camera = setup.camera
    r, c = camera.project(setup.facet_to_camera(setup.facet.corners_mm()))
    r0 = max(0, int(np.floor(r.min())) - margin_px)
    c0 = max(0, int(np.floor(c.min())) - margin_px)
    r1 = min(camera.height, int(np.ceil(r.max())) + margin_px + 1)
    c1 = min(camera.width, int(np.ceil(c.max())) + margin_px + 1)
    return {"rows": slice(r0, r1), "cols": slice(c0, c1)}


def rms(e):
    return np.sqrt(np.mean(np.square(e), axis=0))


@pytest.fixture(scope="module")
def setup():
    return twin_setup()


# -- the truth ------------------------------------------------------------------

def test_truth_fraction_obeys_the_reflection_law(setup, np_rng):
    """Each sub-pixel position's fraction is where the camera centre's mirror image across the facet's exact
    tangent plane, seen through the facet point, meets the screen (an independent construction), to 1e-9."""
    win = twin_window(setup, margin_px=0)
    r = np_rng.uniform(win["rows"].start, win["rows"].stop, 2000)
    c = np_rng.uniform(win["cols"].start, win["cols"].stop, 2000)
    fraction, points = screen_fraction_truth(setup, r, c)
    on = np.isfinite(fraction[:, 0])
    assert 1500 < on.sum() < 2000  # the window is the facet's bounding box; its edges miss the facet
    np.testing.assert_array_equal(on, np.isfinite(points[:, 0]))  # the whole reflected facet sees the lit screen
    P = points[on]
    n = setup.facet.normal(P[:, 0], P[:, 1])
    C = setup.camera_centre_facet_mm
    image = C - 2 * np.sum((C - P) * n, axis=1, keepdims=True) * n  # the camera centre mirrored in the tangent plane
    R, t = setup.screen_to_facet
    a = (image - t) @ R  # screen frame
    b = (P - t) @ R
    s = a[:, 2] / (a[:, 2] - b[:, 2])  # the line from the image through P, where z = 0
    x = a[:, 0] + s * (b[:, 0] - a[:, 0])
    y = a[:, 1] + s * (b[:, 1] - a[:, 1])
    (w, h), (cx, cy) = setup.display.size_mm, setup.display.centre_mm
    expected = np.column_stack([(x - (cx - w / 2)) / w, (y - (cy - h / 2)) / h])
    # float64 over ~1e4 mm: rounding is ~1e-12 mm; 1e-9 of the 3.4 m screen is 3.4e-6 mm
    np.testing.assert_allclose(fraction[on], expected, rtol=0, atol=1e-9)
    # the unit vectors from P to the camera and to the screen point add up along the normal (the law itself)
    S = setup.camera_to_facet(setup.screen_to_camera(np.column_stack([x, y, np.zeros_like(x)])))
    m = (C - P) / np.linalg.norm(C - P, axis=1, keepdims=True) + (S - P) / np.linalg.norm(S - P, axis=1,
                                                                                           keepdims=True)
    assert np.max(np.linalg.norm(np.cross(m, n), axis=1) / np.linalg.norm(m, axis=1)) < 1e-12
    assert np.all((fraction[on] > 0) & (fraction[on] < 1)) and np.isnan(fraction[~on]).all()


def test_truth_is_nan_off_the_facet(setup):
    r, c = setup.camera.project(setup.facet_to_camera([[130.0, 0.0, 0.0], [0.0, 0.0, 0.0]]))
    fraction, points = screen_fraction_truth(setup, r, c)
    assert np.isnan(fraction[0]).all() and np.isnan(points[0]).all()
    assert np.isfinite(fraction[1]).all() and abs(points[1, 0]) < 1e-6 and abs(points[1, 1]) < 1e-6
    with pytest.raises(OptionError) as e:
        screen_fraction_truth("setup", 0.0, 0.0)
    assert e.value.field == "setup"


# -- frames of any pattern from one set of samples --------------------------------

def synthetic_hits(rng, shape=(3, 4, 16)):
    """Samples as a trace leaves them: fractions in [0, 1] with a quarter missing the screen (NaN, weight 0)."""
    frac = rng.uniform(0, 1, shape + (2,))
    weight = rng.uniform(0.5, 1.5, shape)
    miss = rng.random(shape) < 0.25
    frac[miss] = np.nan
    weight[miss] = 0.0
    return ScreenHits(frac, weight, None)


def test_pattern_frames_are_means_over_the_samples(np_rng):
    hits = synthetic_hits(np_rng)
    dark, light = mask_frames(hits, on_radiance=2.0, off_radiance=0.1)
    half = pattern_frames(hits, lambda fx, fy: np.full((1,) + fx.shape, 0.5), on_radiance=2.0, off_radiance=0.1)
    # a constant 0.5 on a linear display: halfway between the dark and the light frame; 0.5 off an off level of 0
    np.testing.assert_allclose(half[..., 0], 0.5 * (dark + light), rtol=1e-14)
    np.testing.assert_allclose(pattern_frames(hits, lambda fx, fy: np.full((1,) + fx.shape, 0.5))[..., 0],
                               0.5 * mask_frames(hits)[1], rtol=1e-14)
    np.testing.assert_allclose(dark, 0.05 * light, rtol=1e-14)
    # a gamma display: 0.5 shows 0.5 ** gamma of the way up
    g = pattern_frames(hits, lambda fx, fy: np.full((1,) + fx.shape, 0.5), on_radiance=2.0, off_radiance=0.1,
                       gamma=2.2)
    np.testing.assert_allclose(g[..., 0], dark + 0.5**2.2 * (light - dark), rtol=1e-14)
    # linear in the pattern (gamma 1, off 0), frame by frame
    code = PhaseCode()
    a = pattern_frames(hits, code.intensity)
    b = pattern_frames(hits, lambda fx, fy: 1.0 - code.intensity(fx, fy))
    np.testing.assert_allclose(a + b, np.repeat(mask_frames(hits)[1][..., None], code.n_frames, -1), rtol=1e-13)
    # against the definition, sample by sample
    H, W, spp = hits.weight.shape
    brute = np.zeros((H, W, code.n_frames))
    for i in range(H):
        for j in range(W):
            for s in range(spp):
                fx, fy = hits.fraction[i, j, s]
                if not math.isnan(fx):
                    brute[i, j] += hits.weight[i, j, s] * (0.1 + 1.9 * code.intensity(fx, fy) ** 1.8) / spp
    np.testing.assert_allclose(pattern_frames(hits, code.intensity, on_radiance=2.0, off_radiance=0.1, gamma=1.8),
                               brute, rtol=1e-13)


def test_pattern_frames_refuse_bad_patterns(np_rng):
    hits = synthetic_hits(np_rng)
    for pattern, match in ((lambda fx, fy: fx, "shape"), (lambda fx, fy: 1.5 * np.ones((2,) + fx.shape), "within"),
                           (lambda fx, fy: np.full((1,) + fx.shape, np.nan), "within"), ("stripes", "callable")):
        with pytest.raises(OptionError, match=match) as e:
            pattern_frames(hits, pattern)
        assert e.value.field == "pattern"
    for kwargs, field in (({"gamma": 0.0}, "gamma"), ({"on_radiance": -1.0}, "on_radiance"),
                          ({"off_radiance": np.nan}, "off_radiance")):
        with pytest.raises(OptionError) as e:
            pattern_frames(hits, PhaseCode().intensity, **kwargs)
        assert e.value.field == field
    with pytest.raises(OptionError) as e:
        pattern_frames(np.zeros((2, 2, 2, 2)), PhaseCode().intensity)
    assert e.value.field == "hits"


def test_fringe_render_refuses_bad_options(setup):
    for kwargs, field in (({"code": "sofast"}, "code"), ({"sensor": "tv_1990s"}, "sensor"), ({"gamma": 20}, "gamma"),
                          ({"sensor": "tv_1980s_8bit", "exposure": 0.0}, "exposure"),
                          ({"sensor": "tv_1980s_8bit", "sensor_seed": -1}, "sensor_seed"),
                          ({"spp": 0}, "spp"), ({"rows": slice(5, 5)}, "rows")):
        args = {"code": PhaseCode(), **kwargs}
        with pytest.raises(OptionError) as e:
            render_fringe_frames(setup, args.pop("code"), **args)
        assert e.value.field == field
    with pytest.raises(OptionError, match="window") as e:
        trace_screen_hits(setup, spp=4096)  # the whole 1626 x 1236 image at 4096 samples
    assert e.value.field == "spp" and 1626 * 1236 * 4096 > MAX_SCREEN_HITS


# -- the render ------------------------------------------------------------------

@pytest.fixture(scope="module")
def hits(setup):
    return trace_screen_hits(setup, spp=SPP, seed=0, mesh_tolerance_mm=MESH_TOLERANCE_MM, **twin_window(setup))


@pytest.fixture(scope="module")
def ideal(setup):
    start = time.perf_counter()
    frames = render_fringe_frames(setup, PhaseCode(), spp=SPP, seed=0, mesh_tolerance_mm=MESH_TOLERANCE_MM,
                                  **twin_window(setup))
    return frames, time.perf_counter() - start


def interior(frames):
    """Pixels whose every sample reaches the screen through the facet: clear of its edge, where a pixel that sees
    the facet in part decodes the centroid of that part, not its centre."""
    return (frames.coverage == 1) & np.isfinite(frames.truth_fraction[..., 0])


@requires_jit
def test_decoded_positions_are_the_pixel_centres(setup, hits, ideal):
    """SOFAST's code on the twin, ideal sensor, 64 spp: the decoded position is where the pixel centre's ray sees
    the screen, up to Monte-Carlo noise; no systematic error of 0.01 display px; no unwrapping error.

    The blur of a rough mirror is symmetric, so a blurred sinusoid keeps the phase of the pixel centre's ray to
    first order; the mirror's curvature over the blur (5.7 mm rms on the screen) and over the pixel's footprint
    move it at second order, ~0.002 px. What is left is the noise of 64 samples: their spread on the screen
    (3.2 display px rms per axis, the Beckmann lobe of alpha 4e-4 at 10 m) leaves the sampled centroid of each
    pixel's lobe ~0.16 px (x) and 0.09 px (y) rms from its mean (it falls as 1/sqrt(spp): 0.07 and 0.04 px at
    256). All frames of a pixel share its samples, so the noise is in the phase only, never in the frames' fit.
    """
    frames, seconds = ideal
    code = PhaseCode()
    H, W = frames.coverage.shape
    assert frames.frames.shape == (H, W, code.n_frames) and frames.frames.dtype == np.float64
    # one trace, every frame: the same samples as the trace of the same seed
    np.testing.assert_array_equal(frames.frames, pattern_frames(hits, code.intensity))
    np.testing.assert_array_equal(frames.light, mask_frames(hits)[1])
    assert not frames.dark.any()  # the display's off level is 0
    rr, cc = np.indices((H, W))
    truth, points = screen_fraction_truth(frames.setup, rr, cc)
    np.testing.assert_array_equal(frames.truth_fraction, truth)
    np.testing.assert_array_equal(frames.truth_slopes, setup.facet.slopes(points[..., 0], points[..., 1]))

    dec = decode_phase(frames.frames, code)
    seen = dec.valid & np.isfinite(frames.truth_fraction[..., 0])
    inner = interior(frames)
    assert inner.sum() > 0.95 * np.isfinite(truth[..., 0]).sum() and dec.valid[inner].all()
    error = (dec.fraction - frames.truth_fraction) * DISPLAY_PX
    # no unwrapping error anywhere on the facet: a wrong multiple moves a point by a whole finest period
    half_period = 0.5 / np.array([code.periods_x[-1], code.periods_y[-1]]) * DISPLAY_PX
    assert np.all(np.abs(error[seen]) < half_period), np.abs(error[seen]).max(0)
    e = error[inner]
    total = rms(e)  # ~(0.16, 0.09) px: the noise of 64 samples
    # the systematic part: what the error has in common with the surface (a quadratic across the facet and the
    # ripple's first two harmonics at the facet point), fitted over ~18,000 pixels; the fit's own noise is
    # sqrt(10 / n) of the pixel noise, 0.004 px
    P = frames.truth_points_mm[inner]
    f = setup.facet
    phase = 2 * np.pi * (P[:, 0] * math.cos(f.ripple_angle_rad) + P[:, 1] * math.sin(f.ripple_angle_rad)) \
        / f.ripple_period_mm
    u, v = P[:, 0] / f.half_width_mm, P[:, 1] / f.half_height_mm
    basis = np.column_stack([np.ones_like(u), u, v, u * u, u * v, v * v, np.sin(phase), np.cos(phase),
                             np.sin(2 * phase), np.cos(2 * phase)])
    systematic = basis @ np.linalg.lstsq(basis, e, rcond=None)[0]
    assert np.all(rms(systematic) < 0.01), (rms(systematic), total)
    assert np.all(np.abs(e.mean(0)) < 0.005), e.mean(0)  # 4 sigma of the mean of 18,000 noisy pixels
    # the rest is noise: another seed's samples give an error uncorrelated with this one's
    other = trace_screen_hits(setup, spp=SPP, seed=1, mesh_tolerance_mm=MESH_TOLERANCE_MM, **twin_window(setup))
    e1 = ((decode_phase(pattern_frames(other, code.intensity), code).fraction - frames.truth_fraction)
          * DISPLAY_PX)[inner]
    ok = np.isfinite(e1[:, 0])
    for k in (0, 1):
        assert abs(np.corrcoef(e[ok, k], e1[ok, k])[0, 1]) < 0.1
    assert seconds < 30, f"the {H} x {W} window at {SPP} spp took {seconds:.1f} s"


@requires_jit
def test_eight_bit_sensor_follows_the_noise_law(setup, hits, ideal):
    """The 1980s 8-bit camera behind a gamma 2.2 display: one exposure for all frames, the light frame's peak at
    0.8 of full well; the decoded positions' noise is the noise law's, and undoing the gamma costs noise.

    The noise is measured against the noise-free frames of the same samples (decoded the same way), so the
    Monte-Carlo noise common to both cancels. The law ``sigma / B sqrt(2 / N) / (2 pi P)`` is exact for noise
    whose variance is linear in the signal on a sinusoid; the gamma frames are not quite sinusoids (their
    harmonics change each frame's noise weight by ~10 %), hence 25 %.
    """
    code = PhaseCode()
    start = time.perf_counter()
    cam = render_fringe_frames(setup, code, spp=SPP, seed=0, gamma=2.2, sensor="tv_1980s_8bit",
                               mesh_tolerance_mm=MESH_TOLERANCE_MM, **twin_window(setup))
    seconds = time.perf_counter() - start
    meta = cam.metadata["sensor"]
    preset = SENSOR_PRESETS["tv_1980s_8bit"]
    dark, light = mask_frames(hits)
    assert meta["exposure"] == pytest.approx(0.8 * preset.full_well / light.max(), rel=1e-12)
    s = Sensor.from_dict({k: meta[k] for k in Sensor().to_dict()})
    for a in (cam.frames, cam.dark, cam.light):
        assert a.dtype == np.float32 and np.array_equal(np.rint(a * 255.0), a * 255.0)
    inner = interior(cam)
    # the light frame: the whole image's vignetting at the window, 0.8 of full well at radiance 1 (interior: 1)
    H0, W0 = setup.camera.shape
    r0, c0 = cam.offset_rc
    vig = s.vignette((H0, W0))[r0:r0 + inner.shape[0], c0:c0 + inner.shape[1]]
    expected = (s.exposure * light * vig * s.gain + s.dark_offset) / s.full_scale
    assert np.median(cam.light[inner] / expected[inner]) == pytest.approx(1.0, abs=0.005)  # PRNU 2 %, shot 0.5 %
    assert np.median(cam.dark[inner]) == pytest.approx(s.dark_offset / s.full_scale, abs=0.5 / 255)

    # the mask frames normalise each pixel (its gain, vignetting and black level): 0 to 1 between dark and light
    span = np.where(cam.light > cam.dark, cam.light - cam.dark, 1.0)
    x = (cam.frames - cam.dark[..., None]) / span[..., None]
    clean = pattern_frames(hits, code.intensity, gamma=2.2) / np.where(light > 0, light, 1.0)[..., None]
    given = {"noise_sigma": 1e-3}  # no pixel of the interior flagged: the comparison is over all of them
    finest = [k for k, (_, p, _) in enumerate(code.frame_table()) if p == code.periods_x[-1]]
    # the sensor's own noise at each finest frame's mean signal, relative to the pixel's span (PRNU left out: 2 %)
    span_dn = (s.exposure * s.gain * vig)[inner][:, None]
    sigma = float(np.sqrt(np.mean((s.noise_sigma(clean[inner][:, finest] * span_dn) / span_dn) ** 2)))
    noisy = decode_phase(x, code, region=inner, **given)
    calm = decode_phase(clean, code, region=inner, **given)
    assert noisy.valid[inner].all() and calm.valid[inner].all()
    noise = rms((noisy.fraction - calm.fraction)[inner] * DISPLAY_PX)
    law = rms(position_noise(sigma, noisy.modulation[inner], code.periods_x[-1], code.shifts) * DISPLAY_PX)
    np.testing.assert_allclose(noise / law, 1.0, atol=0.25)
    # through the inverse gamma the dark frames' noise is magnified: more noise than with the gamma left in
    response = DisplayResponse.from_gamma(2.2)
    noisy_r = decode_phase(x, code, region=inner, response=response, **given)
    calm_r = decode_phase(clean, code, region=inner, response=response, **given)
    noise_r = rms((noisy_r.fraction - calm_r.fraction)[inner] * DISPLAY_PX)
    assert np.all(noise_r > 1.05 * noise), (noise_r, noise)
    assert np.all(noise < 0.1)  # ~0.04 px: the 8-bit camera's noise, well under the ideal twin's 64-sample noise
    # no unwrapping error under the sensor: the decoded points are the truth's within a small fraction of a period
    dec = decode_phase(x, code, region=inner, response=response)
    err = ((dec.fraction - cam.truth_fraction) * DISPLAY_PX)[dec.valid]
    assert dec.valid[inner].mean() > 0.99 and np.all(np.abs(err) < 2.0), np.abs(err).max(0)
    assert seconds < 30


@requires_jit
@pytest.mark.parametrize("alpha, response_helps", [(1e-4, True), (4e-4, False)])
def test_gamma_harmonics_bias_the_phase(setup, hits, alpha, response_helps):
    """A gamma display's fringes carry harmonics; four shifts alias the 3rd and 5th onto the phase. The error is
    measured without noise, against the linear display's decoding of the same samples.

    A sharp mirror (alpha 1e-4, Mitsuba's floor: a blur of 0.2 rad of the finest period) keeps the harmonics, and
    undoing the gamma (the inverse response on each pixel's values) removes most of the error. SOFAST's
    roughness (alpha 4e-4, 0.65 rad) has already cut the 3rd harmonic to 18 % of its share, and the inverse
    response, applied after a blur comparable with the period, distorts the blurred fringe more than the gamma
    did: there the gamma is better left in (or undone on the display, before the blur).
    """
    code = PhaseCode()
    if alpha == 4e-4:
        samples = hits
    else:
        samples = trace_screen_hits(setup, spp=SPP, seed=0, alpha=alpha, mesh_tolerance_mm=MESH_TOLERANCE_MM,
                                    **twin_window(setup))
    inner = samples.coverage == 1
    given = {"noise_sigma": 1e-3, "region": inner}
    linear = decode_phase(pattern_frames(samples, code.intensity), code, **given)
    gamma = pattern_frames(samples, code.intensity, gamma=2.2)
    left_in = rms(((decode_phase(gamma, code, **given).fraction - linear.fraction) * DISPLAY_PX)[inner])
    undone = rms(((decode_phase(gamma, code, response=DisplayResponse.from_gamma(2.2), **given).fraction
                   - linear.fraction) * DISPLAY_PX)[inner])
    assert np.all(left_in > 0.001) and np.all(undone > 0.001)  # each is a real error, not rounding
    if response_helps:
        assert np.all(left_in > 2 * undone), (left_in, undone)
    else:
        assert np.all(undone > 2 * left_in), (left_in, undone)
