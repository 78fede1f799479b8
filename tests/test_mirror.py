"""The exact mirror-sphere solution (ERRATA) against independent checks."""

import numpy as np
import pytest

from shinysim.conventions import angle_between, normalize
from shinysim.theory.mirror import (
    distant_source_error,
    mirror_sphere_highlight,
    orthographic_highlight_angle,
)

R, r = 43.18, 0.79375  # SHINY array radius and calibration sphere radius, mm


@pytest.mark.parametrize("camera", [None, [0.0, 0.0, 127.0], [5.0, -3.0, 60.0]])
def test_mirror_law_holds(camera, np_rng):
    src = normalize(np_rng.normal(size=(20, 3)) + [0, 0, 2.0]) * R
    p, n = mirror_sphere_highlight(src, radius=r, camera_position=camera)
    np.testing.assert_allclose(np.linalg.norm(p, axis=-1), r, atol=1e-12)
    to_cam = np.array([0, 0, 1.0]) if camera is None else normalize(np.asarray(camera) - p)
    # incidence = reflection: the normal bisects source and camera directions
    bis = normalize(normalize(src - p) + to_cam)
    assert np.max(angle_between(bis, n)) < 1e-10


def test_orthographic_closed_form_and_limits():
    alpha = np.radians(np.arange(1, 86, 4.0))
    t = orthographic_highlight_angle(alpha, R, r)
    np.testing.assert_allclose(R * np.sin(2 * t - alpha), r * np.sin(t), atol=1e-12)
    src = R * np.stack([np.sin(alpha), 0 * alpha, np.cos(alpha)], axis=1)
    _, n = mirror_sphere_highlight(src, radius=r)
    np.testing.assert_allclose(np.arctan2(n[:, 0], n[:, 2]), t, atol=1e-12)
    # far source: Eq 10, t -> alpha / 2
    t_far = orthographic_highlight_angle(alpha, 1e9, r)
    np.testing.assert_allclose(t_far, alpha / 2, atol=1e-9)


def test_first_order_error_matches_errata():
    # ERRATA: "about 0.34 deg at alpha = 80 deg for the SHINY geometry"
    a = np.radians(80.0)
    exact = orthographic_highlight_angle(a, R, r) - a / 2
    assert np.degrees(distant_source_error(a, R, r)) == pytest.approx(0.34, abs=0.005)
    # first order in r/R: the neglected terms are O((r/R)^2) ~ 3e-4 relative... but
    # also O(r/R * angle), so agreement to within 2 % of the error itself
    assert exact == pytest.approx(distant_source_error(a, R, r), rel=0.02)


def test_mirror_sphere_highlight_takes_a_radius_per_source():
    """An array of radii (one per source) gives each sphere's own highlight, as one radius at a time does."""
    import numpy as np

    from shinysim.theory.mirror import mirror_sphere_highlight

    sources = np.array([[30.0, 0.0, 30.0], [-20.0, 5.0, 40.0], [0.0, 25.0, 35.0]])
    radii = np.array([0.5, 0.8, 1.2])
    p, n = mirror_sphere_highlight(sources, radius=radii, camera_position=(0, 0, 127))
    for k in range(3):
        pk, nk = mirror_sphere_highlight(sources[k], radius=radii[k], camera_position=(0, 0, 127))
        np.testing.assert_allclose(p[k], pk, atol=1e-12)
        np.testing.assert_allclose(n[k], nk, atol=1e-12)
