"""Simulation against theory (paper Figs. 5-6) and the sharpness-study metrics."""

import numpy as np
import pytest
from conftest import requires_jit

# float64 geometry through two independent code paths (closed-form atan2 in
# theory.sensitivity; bisection + projection + back-projection in
# theory.mirror and recon.normals): agreement to well below a microdegree.
from shinysim._shared import EXACT_DEG_TOL as EXACT_DEG
from shinysim.conventions import (
    MM_PER_INCH,
    bisector,
    direction_from_angles,
    elevation_from_x,
)
from shinysim.io import Stack, Truth
from shinysim.objects.sphere import SHINY_SPHERE_RADIUS_MM
from shinysim.recon import PAPER_MODELS, DetectParams
from shinysim.rig import Camera, Rig, shiny_1988_source_angles_deg
from shinysim.sim.scene import facet_object
from shinysim.studies import camera_models, sharpness
from shinysim.theory import sensitivity as sens
from shinysim.theory.reflectance import lobe_hwhm

# -- pure parts (no renderer) ------------------------------------------------------


def test_facet_object_places_a_square_with_the_given_normal():
    n = np.array([0.3, 0.0, 0.9])
    d = facet_object((0.5, 0.0, 1.0), n, 0.2, alpha=0.003)["object"]
    m = np.array(d["to_world"])
    assert d["type"] == "rectangle" and d["bsdf"]["alpha"] == 0.003
    np.testing.assert_allclose(m[:3, 3], [0.5, 0.0, 1.0])
    np.testing.assert_allclose(m[:3, 2], n / np.linalg.norm(n), atol=1e-15)  # local +z -> normal
    # the local square [-1, 1]^2 maps to side 0.2, edges perpendicular to the normal
    np.testing.assert_allclose(np.linalg.norm(m[:3, :2], axis=0), [0.1, 0.1])
    np.testing.assert_allclose(m[:3, :2].T @ m[:3, 2], [0.0, 0.0], atol=1e-15)
    # right-handed: u x v along the normal (the rectangle's front side faces it)
    assert np.cross(m[:3, 0], m[:3, 1]) @ n > 0
    # an in-plane normal tilts the square about y only
    assert m[1, 0] == 0.0 and m[1, 2] == 0.0


@pytest.mark.parametrize("bad, match", [
    ({"center": (0, 0)}, "center"), ({"normal": (0, 0, 0)}, "normal"), ({"size": 0.0}, "size"),
])
def test_facet_object_rejects_bad_input(bad, match):
    kw = {"center": (0.0, 0.0, 0.0), "normal": (0.0, 0.0, 1.0), "size": 0.2, **bad}
    with pytest.raises(ValueError, match=match):
        facet_object(kw["center"], kw["normal"], kw["size"])


def test_within_tolerance_is_the_issue_criterion():
    # 10 % relative or 0.02 deg, whichever is larger
    ok = camera_models.within_tolerance([1.09, 1.11, 0.055, 0.075, np.nan], [1.0, 1.0, 0.07, 0.05, 1.0])
    assert ok.tolist() == [True, False, True, False, False]


def test_lobe_radius_at_half_maximum_is_the_hwhm():
    alpha = np.array([0.005, 0.02, 0.1, 0.4])
    for dist in ("ggx", "beckmann"):
        np.testing.assert_allclose(sharpness.lobe_radius_deg(alpha, 0.5, distribution=dist),
                                   np.degrees(lobe_hwhm(alpha=alpha, distribution=dist)), rtol=1e-12)
    assert sharpness.lobe_radius_deg(0.1, 1.0) == 0.0
    with pytest.raises(ValueError, match="distribution"):
        sharpness.lobe_radius_deg(0.1, 0.5, distribution="phong")


def test_correct_form_across_the_atan2_branch_cut():
    """A source below the element on its -x side (the -84 deg fiber, sphere raised 0.2 in)."""
    x, dh, a, b, f = 0.5, 5.7, -42.94, 4.51, 127.0
    P, S, C = np.array([x, 0, dh]), np.array([a, 0, b]), np.array([0, 0, f])
    theta_true = elevation_from_x(bisector(S - P, C - P))
    # averaging the two atan2 angles of Eq 14 would land pi away here; bisecting
    # the directions does not
    assert sens.theta_models(x, dh, a, b, f)["actual"] == pytest.approx(theta_true, abs=1e-12)
    err, act = camera_models._correct_errors_deg(x, dh, a, b, f, image_x="projected")
    assert act == pytest.approx(theta_true, abs=1e-12)
    xs = x * f / (f - dh)  # where the perspective camera reports the element
    Q = np.array([xs, 0.0, 0.0])
    theta_p = elevation_from_x(bisector(S - Q, C - Q))
    assert err["perspective"] == pytest.approx(np.degrees(theta_true - theta_p), abs=1e-9)


def test_spacing_rig_spans_the_semicircle():
    rig = sharpness.spacing_rig(8.0, resolution=32)
    assert rig.n_sources == 21
    np.testing.assert_allclose(rig.metadata["source_angles_deg"], shiny_1988_source_angles_deg())
    for spacing, n in ((4.0, 41), (6.0, 27), (12.0, 13), (16.0, 9)):
        angles = sharpness.spacing_rig(spacing, resolution=32).metadata["source_angles_deg"]
        assert len(angles) == n and max(np.abs(angles)) <= 84.0 + 1e-9
    with pytest.raises(ValueError, match="spacing_deg"):
        sharpness.spacing_rig(0.0)


def test_highlight_metrics_on_a_known_scene():
    """Two square highlights on a surface whose in-plane tilt grows 0.5 deg per column."""
    H, W, R = 11, 41, 43.18
    angles = np.radians([-4.0, 4.0])
    cam = Camera("orthographic", W, H, [0, 0, 10], [0, 0, 0], [0, 1, 0], field_width=0.01 * W)
    rig = Rig(R * direction_from_angles(angles, 0.0), np.full(2, 0.5), (cam,))
    tilt = np.radians((np.arange(W) - 20) * 0.5)
    normals = np.broadcast_to(np.stack([np.sin(tilt), 0 * tilt, np.cos(tilt)], -1), (H, W, 3))
    truth = Truth(normals, np.zeros((H, W, 3)), np.ones((H, W), bool))
    frames = np.zeros((2, H, W), np.float32)
    frames[0, 4:7, 18:23] = 1.0  # tilt -1 ... +1 deg, centroid at tilt 0
    frames[1, 4:7, 26:29] = 1.0  # tilt 3 ... 4 deg, centroid at tilt 3.5
    m = sharpness.highlight_metrics(Stack(frames, rig), truth, DetectParams(threshold=0.5))
    assert (m["n_highlights"], m["n_sources_found"], m["n_sources"]) == (2, 2, 2)
    assert m["area_px"] == 12.0  # median of 15 and 9
    # pooled RMS of the pixels' angles to their centroid normal: (7.5 + 1.5) / 24 deg^2
    assert m["orientation_spread_deg"] == pytest.approx(np.sqrt(9.0 / 24.0), rel=1e-5)
    # peak normals at -2 and +2 deg, widened by a quarter spacing: [-4, 4]; covered: [-1, 1] and [3, 4]
    assert m["coverage"] == pytest.approx(3.0 / 8.0, rel=1e-5)
    # fixed model: normals at -2 and +2 deg against true 0 and 3.5 deg
    assert m["median_error_deg"]["fixed"] == pytest.approx(1.75, abs=1e-4)
    assert set(m["pixel_error_deg"]) == set(PAPER_MODELS)


# -- renders --------------------------------------------------------------------------


@pytest.fixture(scope="module")
def fig05_points():
    """Three corners of the Fig. 5 range and the axis, 192 px, 8 spp (about 2 s)."""
    x = np.array([-0.03, 0.03, 0.0, 0.03]) * MM_PER_INCH
    dh = np.array([0.05, 0.2, 0.0, 0.0]) * MM_PER_INCH
    return camera_models.facet_errors(x, dh, resolution=192, spp=8)


@pytest.mark.render
@requires_jit
def test_rendered_facets_agree_with_corrected_eqs_11_17(fig05_points):
    r = fig05_points
    for m in PAPER_MODELS:
        assert camera_models.within_tolerance(r["measured_deg"][m], r["analytic_deg"][m]).all(), m
        # in fact far closer: the model normals hardly depend on where the
        # centroid falls (0.5 deg per mm for the source term)
        np.testing.assert_allclose(r["measured_deg"][m], r["analytic_deg"][m], atol=0.005)
        # the exact mirror-sphere path reproduces the closed form
        np.testing.assert_allclose(r["exact_deg"][m], r["analytic_deg"][m], atol=EXACT_DEG)
        # errors are in the x-z plane: the 3-D angle is the in-plane one
        np.testing.assert_allclose(r["measured_angle_deg"][m], np.abs(r["measured_deg"][m]), atol=1e-3)
    assert np.all(r["centroid_offset_px"] < 0.5)
    # the test measures something: errors of up to several degrees
    assert np.max(np.abs(r["analytic_deg"]["fixed"])) > 1.5
    # on the reference plane at x = 0 every model is exact
    for m in PAPER_MODELS:
        assert abs(r["measured_deg"][m][2]) < 0.005


@pytest.mark.render
@requires_jit
def test_rendered_facets_reject_the_paper_readings(fig05_points):
    """The simulation tells the candidate forms of Eqs 11-14 apart."""
    r = fig05_points
    # printed camera term: off by about 90 deg for x < 0 (orthographic model)
    assert abs(r["measured_deg"]["orthographic"][0] - r["printed_deg"]["orthographic"][0]) > 80
    # models told the true x (the paper's reading) instead of the projected one:
    # off for raised elements (0.08 deg, 3 %, at x = 0.03 in, dh = 0.2 in: inside the
    # issue's 10 % but twenty times the simulation's own discrepancy), exact at dh = 0
    p = "perspective"
    gap = np.abs(r["measured_deg"][p] - r["analytic_reference_deg"][p])
    assert gap[1] > 0.05 and gap[1] > 20 * abs(r["measured_deg"][p][1] - r["analytic_deg"][p][1])
    assert gap[3] < 0.005


@pytest.mark.render
@requires_jit
def test_rendered_facets_fig06_and_orthographic_camera():
    # Fig. 6: the source is 0.1 rad higher than the models believe
    r = camera_models.facet_errors(0.02 * MM_PER_INCH, 0.1 * MM_PER_INCH, source_error=0.1, resolution=192, spp=8)
    for m in PAPER_MODELS:
        assert camera_models.within_tolerance(r["measured_deg"][m], r["analytic_deg"][m]).all(), m
        np.testing.assert_allclose(r["exact_deg"][m], r["analytic_deg"][m], atol=EXACT_DEG)
    assert abs(r["analytic_deg"]["fixed"][0]) > 1.0
    # orthographic camera: Eqs 11-14 with f -> infinity; perspective and orthographic models coincide
    r = camera_models.facet_errors(-0.5, 2.0, projection="orthographic", resolution=192, spp=8)
    for m in PAPER_MODELS:
        assert camera_models.within_tolerance(r["measured_deg"][m], r["analytic_deg"][m]).all(), m
        np.testing.assert_allclose(r["exact_deg"][m], r["analytic_deg"][m], atol=EXACT_DEG)
    assert r["measured_deg"]["perspective"][0] == pytest.approx(r["measured_deg"]["orthographic"][0], abs=1e-9)


@pytest.mark.render
@requires_jit
def test_raised_sphere_against_theory_and_the_exact_solution():
    """The calibration sphere raised by 0.05 in: 21 surface elements at once."""
    r = camera_models.raised_sphere_errors(0.05 * MM_PER_INCH, resolution=512, spp=16)
    assert len(r["source"]) == 21
    pitch, radius = r["settings"]["pixel_pitch_mm"], r["settings"]["radius_mm"]
    # a centroid offset of d pixels moves the true normal at the centroid by
    # d * pitch / (r cos t): on a sphere n_x = x / r, so dn = dx / (r cos t) at polar angle t
    cos_t = np.sqrt(1.0 - (r["x_mm"] / radius) ** 2)
    centroid_term = np.degrees(r["centroid_offset_px"] * pitch / (radius * cos_t))
    for m in PAPER_MODELS:
        # the closed form at the exact highlight point is the exact solution
        np.testing.assert_allclose(r["analytic_deg"][m], r["exact_deg"][m], atol=EXACT_DEG)
        # the recovered normal against the exact normal: the camera-model error alone
        assert camera_models.within_tolerance(r["measured_exact_normal_deg"][m], r["analytic_deg"][m]).all(), m
        # against the truth at the centroid, the centroid's offset adds its own term
        excess = np.abs(r["measured_deg"][m] - r["measured_exact_normal_deg"][m])
        assert np.all(excess <= 1.05 * centroid_term + 0.005), m
    assert np.max(r["centroid_offset_px"]) < 0.5
    assert np.max(np.abs(r["analytic_deg"]["perspective"])) > 0.5


@pytest.mark.render
@requires_jit
def test_sharpness_sweep_shows_the_tradeoff():
    r = sharpness.sharpness_sweep([0.01, 0.1], [0.2, 0.8], resolution=96, spp=8)
    assert r["diameter_um"].shape == (2, 2)
    # rougher -> bigger highlights, more coverage, less specific normals
    assert np.all(r["diameter_um"][1] > r["diameter_um"][0])
    assert np.all(r["orientation_spread_deg"][1] > r["orientation_spread_deg"][0])
    assert np.all(r["coverage"][1] >= r["coverage"][0])
    # lower I0 -> the same: the paper's trade-off
    assert np.all(r["diameter_um"][:, 0] >= r["diameter_um"][:, 1])
    assert np.all(r["coverage"][:, 0] > r["coverage"][:, 1])
    assert np.all(r["orientation_spread_deg"][:, 0] > r["orientation_spread_deg"][:, 1])
    assert r["coverage"][1, 0] == pytest.approx(1.0)
    # while the normal at the centroid stays within what centroid quantisation allows: at 96 px
    # over 2 mm a centroid half a pixel off moves the true normal by 0.5 pitch / r = 0.75 deg
    # on the 1/16 in sphere (I0 = 0.8 keeps highlights of one or two pixels at alpha = 0.01)
    half_pixel_deg = np.degrees(0.5 * (2.0 / 96) / SHINY_SPHERE_RADIUS_MM)
    assert np.all(r["median_error_deg"]["fixed"] < half_pixel_deg)


@pytest.mark.render
@requires_jit
def test_rig_sweeps():
    r = sharpness.rig_sweep("spacing_deg", [6.0, 12.0], alpha=0.05, thresholds=[0.3], resolution=96, spp=8)
    assert r["n_sources_rig"].tolist() == [27, 13]
    assert r["coverage"][0, 0] > r["coverage"][1, 0]  # closer sources sample more of the range
    r = sharpness.rig_sweep("fiber_diameter_mm", [0.3, 3.0], alpha=0.005, thresholds=[0.5], resolution=160, spp=8)
    # bigger fiber, bigger mirror image: wider highlights that cover more orientations
    assert r["diameter_um"][1, 0] > r["diameter_um"][0, 0]
    assert r["coverage"][1, 0] > r["coverage"][0, 0]
    with pytest.raises(ValueError, match="kind"):
        sharpness.rig_sweep("radius", [1.0])
