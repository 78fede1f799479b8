"""A facet ensemble measured from one analytic frame: every facet's dots, slopes and pointing against truth.

Two facets side by side with a 20 mm seam (as OpenCSP's split NSTTF facet),
each turned 1 mrad from its design in opposite senses, seen in SOFAST's rig.
The frame is drawn, not rendered: each facet's image is its projected outline
(anti-aliased, 4 x 4 samples per pixel), each dot a dark Gaussian blob at the
exact pixel of its reflection (``DisplaySetup.reflected_dots``), plus noise.
So the dots' places, the facets' outlines and their pointing are exact, and
what is tested is the ensemble's pose, the per-facet walks (which must not
cross the seam), the per-facet slopes and the pointing.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from shinysim.objects.mirror import MirrorFacet
from shinysim.recon.deflect import measure_ensemble, rotation_matrix
from shinysim.rig.display import SOFAST_FACET_CENTRE_MM, Display, DisplaySetup, facet_pose
from shinysim.studies.deflect import sofast_geometry

HALF = (300.0, 600.0)  # each facet's half sides, mm
GAP = 20.0  # the seam between them, mm
TILT = 1e-3  # each facet turned this far about y from its design, opposite senses, rad


def _polygon_coverage(shape, corners_rc, sub=4):
    offs = (np.arange(sub) + 0.5) / sub - 0.5
    r0, c0 = np.floor(corners_rc.min(0)).astype(int) - 2
    r1, c1 = np.ceil(corners_rc.max(0)).astype(int) + 3
    r0, c0 = max(r0, 0), max(c0, 0)
    rr = np.arange(r0, min(r1, shape[0]))[:, None, None, None] + offs[None, None, :, None]
    cc = np.arange(c0, min(c1, shape[1]))[None, :, None, None] + offs[None, None, None, :]
    r, c = corners_rc[:, 0], corners_rc[:, 1]
    side = [(r[(k + 1) % 4] - r[k]) * (cc - c[k]) - (c[(k + 1) % 4] - c[k]) * (rr - r[k]) for k in range(4)]
    inside = np.all(np.array(side) <= 0, axis=0) | np.all(np.array(side) >= 0, axis=0)
    out = np.zeros(shape)
    out[r0:r0 + inside.shape[0], c0:c0 + inside.shape[1]] = inside.mean(axis=(2, 3))
    return out


@pytest.fixture(scope="module")
def scene():
    camera, rot, origin, dots, xi, yi, _ = sofast_geometry(None)
    display = Display(dots, xi, yi, dot_radius_mm=6.75).flattened()
    R_e, t_e = facet_pose(camera.position, origin, SOFAST_FACET_CENTRE_MM, camera.right)
    facet = MirrorFacet(*HALF, focal_mm=(-136e3, -146e3))
    positions = np.array([[-(HALF[0] + GAP / 2), 0.0, 0.0], [HALF[0] + GAP / 2, 0.0, 0.0]])
    tilts = [rotation_matrix([0.0, -TILT, 0.0]), rotation_matrix([0.0, TILT, 0.0])]
    rng = np.random.default_rng(5)
    image = np.zeros(camera.shape)
    setups, origins = [], []
    for pos, tilt in zip(positions, tilts):
        setup = DisplaySetup(display, camera, rot, origin, facet, R_e @ tilt, t_e + R_e @ pos)
        setups.append(setup)
        r, c = camera.project(setup.facet_to_camera(facet.corners_mm()))
        image += 200.0 * _polygon_coverage(camera.shape, np.column_stack([r, c]))
    for setup in setups:
        ref = setup.reflected_dots()
        vis = ref.visible
        rows, cols = ref.row[vis], ref.col[vis]
        for r, c in zip(rows, cols):
            r0, c0 = int(round(r)) - 5, int(round(c)) - 5
            yy, xx = np.mgrid[r0:r0 + 11, c0:c0 + 11]
            image[r0:r0 + 11, c0:c0 + 11] *= 1 - 0.55 * np.exp(-((yy - r) ** 2 + (xx - c) ** 2) / (2 * 1.3 ** 2))
        # a known dot near the facet's middle, as SOFAST's pts_known
        jj, ii = np.nonzero(vis)
        k = int(np.argmin(np.abs(ref.points_mm[jj, ii, 0]) + np.abs(ref.points_mm[jj, ii, 1])))
        origins.append(((float(ref.row[jj[k], ii[k]]), float(ref.col[jj[k], ii[k]])),
                        (int(xi[ii[k]]), int(yi[jj[k]]))))
    image = np.clip(image + rng.normal(0, 1.0, image.shape), 0, None)
    dist = float(np.linalg.norm(t_e - origin))
    m = measure_ensemble(image, camera, dot_position=setups[0].dot_position, screen_origin_mm=origin, distance_mm=dist,
                         corners_mm=[facet.corners_mm()] * 2, centroids_mm=np.zeros((2, 3)),
                         facet_positions_mm=positions, facet_rotations=[np.eye(3), np.eye(3)], origins=origins)
    return m, setups


def test_each_facet_is_walked_inside_its_own_image_with_no_wrong_index(scene):
    m, setups = scene
    for fm, setup in zip(m.facets, setups):
        ref = setup.reflected_dots()
        xi, yi = setup.display.x_index, setup.display.y_index
        idx = fm.index.index[fm.used]
        exact = np.column_stack([ref.row[idx[:, 1] - yi[0], idx[:, 0] - xi[0]],
                                 ref.col[idx[:, 1] - yi[0], idx[:, 0] - xi[0]]])
        seen = np.column_stack([fm.dots["row"][fm.used], fm.dots["col"][fm.used]])
        off = np.linalg.norm(seen - exact, axis=1)
        assert np.all(off < 0.5)  # each dot where the exact reflection of its assigned index is
        assert fm.used.sum() > 0.9 * ref.visible.sum()  # all but the dots cut by an edge or the seam


def test_each_facets_slopes_and_pointing_are_recovered(scene):
    m, setups = scene
    for fm, setup in zip(m.facets, setups):
        sol = fm.solution
        truth = setup.facet.slopes(sol.points_mm[:, 0], sol.points_mm[:, 1])
        # centre-aligned in its own frame: the facet's 1 mrad turn and the pose's error are a tilt of the slopes
        diff = sol.slopes - truth
        from shinysim.evaluate.deflect import detilt
        assert np.sqrt(np.mean(np.sum(detilt(sol.points_mm, diff) ** 2, axis=1))) < 2e-5
    # the two facets point 2 mrad apart about y (the x slope of their normals), nothing about x
    np.testing.assert_allclose(m.pointing_mrad[:, 0], [-1.0, 1.0], atol=0.05)
    np.testing.assert_allclose(m.pointing_mrad[:, 1], [0.0, 0.0], atol=0.05)


def test_an_ensemble_needs_a_known_dot_per_facet(scene):
    m, setups = scene
    from shinysim.errors import OptionError

    with pytest.raises(OptionError, match="2 facets need 2 known dots"):
        measure_ensemble(np.zeros((10, 10)), setups[0].camera, dot_position=None, screen_origin_mm=np.zeros(3),
                         distance_mm=1.0, corners_mm=np.zeros((2, 4, 3)), centroids_mm=np.zeros((2, 3)),
                         facet_positions_mm=np.zeros((2, 3)), facet_rotations=[np.eye(3)] * 2, origins=[])
