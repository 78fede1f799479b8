"""The near-field normal model against exact mirror-sphere geometry (no renderer).

Exact highlights of point sources on a mirror sphere
(:func:`shinysim.theory.mirror.mirror_sphere_highlight`) are projected into
the camera; the model, given only those image points, the rig and an
anchor, must recover the exact normals up to its integration error, where
the paper's models keep their plane bias.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from shinysim._shared import EXACT_DEG_TOL, EXACT_MM_TOL
from shinysim.conventions import angle_between
from shinysim.errors import OptionError, RigError
from shinysim.objects.sphere import SHINY_SPHERE_RADIUS_MM as R
from shinysim.recon.nearfield import near_field_normals
from shinysim.recon.normals import highlight_normals
from shinysim.io import load_rig
from shinysim.rig import Anchor, Camera, Rig, shiny_1988
from shinysim.theory.mirror import mirror_sphere_highlight

APEX = Anchor.at_point((0.0, 0.0, R), normal=(0.0, 0.0, 1.0))


def exact_highlights(rig):
    cam = rig.camera
    cam_pos = cam.position if cam.projection == "perspective" else None
    points, normals = mirror_sphere_highlight(rig.source_positions, radius=R, camera_position=cam_pos)
    row, col = cam.project(points)
    return row, col, np.arange(rig.n_sources), points, normals


def dome_rig(projection="perspective"):
    """Sources on a hemisphere of radius 43 mm: highlights spread over the sphere in two dimensions."""
    pol, az = np.meshgrid(np.radians([12, 24, 36, 48, 60, 72]), np.radians(np.arange(0, 360, 30)))
    d = np.stack([np.sin(pol) * np.cos(az), np.sin(pol) * np.sin(az), np.cos(pol)], -1).reshape(-1, 3)
    cam = shiny_1988(projection=projection).camera
    return Rig(43.18 * d, np.zeros(len(d)), (cam,))


def errors_deg(n, exact):
    return np.degrees(angle_between(n, exact))


@pytest.mark.parametrize("projection", ["perspective", "orthographic"])
def test_exact_highlights_give_exact_normals_on_the_shiny_rig(projection):
    rig = shiny_1988(projection=projection)
    row, col, src, points, exact = exact_highlights(rig)
    nf = near_field_normals(row, col, src, rig, APEX)
    assert nf.converged and nf.iterations <= 8
    # the circular rule is exact on a sphere and the anchor is the exact apex:
    # what is left is floating-point round-off
    assert errors_deg(nf.normals, exact).max() < EXACT_DEG_TOL
    assert np.abs(nf.points - points).max() < EXACT_MM_TOL  # the surface points are found too
    fixed = errors_deg(highlight_normals(row, col, src, rig, model="fixed"), exact)
    assert fixed.max() > 0.1  # the plane bias the model removes


@pytest.mark.parametrize("anchor", [
    Anchor.at_point((0.0, 0.0, R)),  # apex without its normal: one-sided rule
    Anchor.contour([255.5, 255.5], [255.5 - R / 2.0 * 512, 255.5 + R / 2.0 * 512], 0.0),  # the equator
], ids=["point without normal", "contour on the plane"])
def test_other_anchors(anchor):
    rig = shiny_1988(projection="orthographic")
    row, col, src, _, exact = exact_highlights(rig)
    nf = near_field_normals(row, col, src, rig, anchor)
    assert nf.converged
    if anchor.normal is None and anchor.kind == "point":
        # the one-sided tie to the nearest highlight (x = 0.028 mm from the apex) misplaces
        # the heights by ~x^2 / 2R = 5e-4 mm, which tilts normals by up to
        # 5e-4 mm / 43 mm = 1.2e-5 rad = 7e-4 deg
        assert errors_deg(nf.normals, exact).max() < 1e-3
    else:  # the circular arc to the equator is exact on a sphere
        assert errors_deg(nf.normals, exact).max() < EXACT_DEG_TOL


def test_scattered_highlights_of_a_dome():
    rig = dome_rig()
    row, col, src, _, exact = exact_highlights(rig)
    nf = near_field_normals(row, col, src, rig, APEX)
    assert nf.converged
    # the circular rule is exact along every edge of a sphere, whatever its direction
    assert errors_deg(nf.normals, exact).max() < EXACT_DEG_TOL
    assert errors_deg(highlight_normals(row, col, src, rig, model="perspective"), exact).max() > 0.2


def test_a_wrong_anchor_moves_every_height_and_tilts_normals():
    """The anchor is information: 0.1 mm too high moves all heights by ~0.1 mm."""
    rig = shiny_1988()
    row, col, src, points, exact = exact_highlights(rig)
    nf = near_field_normals(row, col, src, rig, Anchor.at_point((0.0, 0.0, R + 0.1), normal=(0, 0, 1)))
    assert nf.converged
    dz = nf.points[:, 2] - points[:, 2]
    assert np.all(np.abs(dz - 0.1) < 0.02)
    assert errors_deg(nf.normals, exact).max() > 0.01


def test_non_convergence_is_reported():
    rig = shiny_1988()
    row, col, src, _, _ = exact_highlights(rig)
    nf = near_field_normals(row, col, src, rig, APEX, max_iter=1)
    assert not nf.converged and nf.iterations == 1 and nf.last_step_mm > 0.5  # the first step lifts ~0.8 mm


def test_disconnected_highlights_are_joined():
    rig = dome_rig()
    row, col, src, _, exact = exact_highlights(rig)
    keep = (col < 230) | (col > 290)  # two clusters with a gap
    nf = near_field_normals(row[keep], col[keep], src[keep], rig, APEX, neighbours=2)
    assert nf.converged
    assert errors_deg(nf.normals, exact[keep]).max() < EXACT_DEG_TOL


def test_the_model_needs_an_anchor():
    rig = shiny_1988()
    row, col, src, _, _ = exact_highlights(rig)
    with pytest.raises(OptionError, match="anchor: the near-field model needs an anchor"):
        highlight_normals(row, col, src, rig, model="near-field")
    n = highlight_normals(row, col, src, rig.with_anchor(APEX), model="near-field")
    assert np.all(np.isfinite(n))


def test_anchor_in_rig_json(tmp_path):
    rig = shiny_1988().with_anchor(APEX)
    rig.save(tmp_path / "rig.json")
    assert load_rig(tmp_path / "rig.json").anchor == APEX
    doc = json.loads((tmp_path / "rig.json").read_text())
    doc["anchor"] = {"point": [0, 0, 1]}
    (tmp_path / "bad.json").write_text(json.dumps(doc))
    with pytest.raises(RigError, match=r"bad.json: anchor: unknown field 'point' \(did you mean 'point_mm'\?\)"):
        load_rig(tmp_path / "bad.json")
    doc["anchor"] = {"point_mm": [0, 0, "up"]}
    (tmp_path / "bad.json").write_text(json.dumps(doc))
    with pytest.raises(RigError, match="bad.json: anchor"):
        load_rig(tmp_path / "bad.json")


def test_bad_anchors():
    with pytest.raises(RigError, match="anchor point"):
        Anchor.at_point((0, 0))
    with pytest.raises(RigError, match="anchor normal"):
        Anchor.at_point((0, 0, 1), normal=(0, 0, -1))
    with pytest.raises(RigError, match="anchor contour"):
        Anchor.contour([], [])
    cam = Camera("orthographic", 8, 8, [0, 0, 10], [0, 0, 0], [0, 1, 0], 1.0)
    rig = Rig(np.array([[10.0, 0, 40]]), [0.0], (cam,))
    with pytest.raises(OptionError, match="anchor: must be an Anchor"):
        near_field_normals([3.5], [3.5], [0], rig, {"point_mm": [0, 0, 0]})
