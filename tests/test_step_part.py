"""The coded-scan study's machined step part (``scan_object("step")``): its mesh, and its sequential
scan under the 200-source dome against the truth.

The part's normals tilt at most ~20 degrees towards +x and +-y (34 towards -x, on the flank), so of the
dome's sources (normals to 40 degrees) about half have no mirror point on it. Their frames hold only
glossy tails and render noise; thresholding each frame at half of its *own* peak turned that into
dozens of false highlights per frame, each with the wrong normal (10-17 degrees median, height maps
12-20 % of the step off). The part's detection (``STEP_DETECT``) thresholds at half of the scan's
brightest pixel instead. The rendered test uses 128 x 128 pixels and 8 samples per pixel (~2 s).
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import requires_jit

from shinysim.conventions import angle_between
from shinysim.evaluate import sample_truth
from shinysim.studies.coded import (
    STEP_DETECT,
    STEP_PART,
    render_scan,
    scan_object,
    step_height,
    step_mesh,
    surface_scores,
)

ALPHA_DEG = np.degrees(0.02)  # the part's GGX roughness, 1.15 deg: the angular width of a highlight's lobe


def test_step_mesh_normals_are_the_height_functions():
    mesh = step_mesh()
    v, n, f = mesh.vertices, mesh.normals, mesh.faces
    # the vertices lie on step_height, and the normals are its gradient's (central differences, h = 1 um:
    # error ~ h^2 z''' / 6, far below 1e-4 rad even on the flank)
    assert np.allclose(v[:, 2], step_height(v[:, 0], v[:, 1]), atol=1e-12)
    h = 1e-3
    p = (step_height(v[:, 0] + h, v[:, 1]) - step_height(v[:, 0] - h, v[:, 1])) / (2 * h)
    q = (step_height(v[:, 0], v[:, 1] + h) - step_height(v[:, 0], v[:, 1] - h)) / (2 * h)
    fd = np.stack([-p, -q, np.ones_like(p)], 1)
    fd /= np.linalg.norm(fd, axis=1, keepdims=True)
    assert np.max(angle_between(n, fd)) < 1e-4
    # the part spans size_mm in x and y, the flank along x = 0 (the upper plateau at x > 0)
    half = STEP_PART["size_mm"] / 2
    assert np.allclose(v[:, :2].min(0), -half) and np.allclose(v[:, :2].max(0), half)
    assert step_height(0.5, 0.0) - step_height(-0.5, 0.0) == pytest.approx(STEP_PART["step_mm"], rel=0.01)
    # faces wind counter-clockwise seen from the side the normals point to
    t = v[f]
    face_n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    assert np.all(np.sum(face_n * n[f].mean(axis=1), axis=1) > 0)


def test_step_part_is_detected_against_the_scan_not_each_frame():
    obj = scan_object("step")
    assert obj.detect == STEP_DETECT and STEP_DETECT.threshold_mode == "scan"
    # the datum is a point of the upper plateau with its true normal
    x0, y0, z0 = obj.datum
    assert z0 == pytest.approx(float(step_height(x0, y0))) and x0 > 3 * STEP_PART["flank_mm"]
    assert scan_object("sphere").detect.threshold_mode == "relative"  # every frame of the sphere holds a highlight


@pytest.fixture(scope="module")
def step_scan():
    return render_scan("step", resolution=128, spp=8)


@requires_jit
def test_step_truth_is_the_analytic_part(step_scan):
    tr = step_scan.truth
    p = tr.positions[tr.mask].astype(float)
    n = tr.normals[tr.mask].astype(float)
    x, y = p[:, 0], p[:, 1]
    h = 1e-4
    gx = (step_height(x + h, y) - step_height(x - h, y)) / (2 * h)
    gy = (step_height(x, y + h) - step_height(x, y - h)) / (2 * h)
    a = np.stack([-gx, -gy, np.ones_like(gx)], 1)
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    err = np.degrees(angle_between(n, a))
    # shading normals interpolated across 7.5 um facets from exact vertex normals: measured 0.004 deg median,
    # 0.03 deg at most; a sign, an x/y swap or a wrong gradient would give degrees
    assert np.median(err) < 0.01 and err.max() < 0.1
    # the rendered surface is step_height to the facets' sag (measured 20 nm)
    assert np.max(np.abs(p[:, 2] - step_height(x, y))) < 1e-4


@requires_jit
def test_step_scan_normals_and_surface_follow_the_truth(step_scan):
    sc = step_scan
    e = sc.sequential_errors()
    # centroids on their mirror points: measured median 0.28 deg at 128 px (a pixel is 0.36 deg of the
    # crown's normal); half a lobe width is allowed. False highlights of frames without a mirror point
    # gave 10 deg
    assert e["n"] > 100 and e["median_deg"] < 0.5 * ALPHA_DEG
    # highlights cut by the part's edge move by up to about a lobe width: measured p95 0.86 deg
    assert e["p95_deg"] < 2 * ALPHA_DEG
    # with the normals right, the height map is limited by how densely the highlights sample the
    # part, not by their normals: the true normals at the same points give the floor (3.2 % of the step
    # here); allow 0.5 % of the step (1 um) beyond it (measured: 0.0 %). Frame-relative detection: 20 %
    t = sc.sequential.table
    n = sc.normals
    tn, tp, ok = sample_truth(sc.truth, t["row"], t["col"])
    methods = ("sparse-arc", "robust")
    got = surface_scores(n["points"][ok, :2], n["normals"][n["best"]][ok], sc.truth, sc.obj, sc.rig, methods=methods)
    floor = surface_scores(tp[ok, :2], tn[ok], sc.truth, sc.obj, sc.rig, methods=methods)
    assert got["anchored"]["height_rms_pct"] < floor["anchored"]["height_rms_pct"] + 0.5
    for m in methods:
        assert got["integrators"][m]["height_rms_pct"] < floor["integrators"][m]["height_rms_pct"] + 0.5, m
    # the highlights' triangles cover most of the part (every normal of it is reachable): measured 85 %
    assert got["coverage"]["reachable_of_visible"] == pytest.approx(1.0)
    assert got["coverage"]["visible"] > 0.75


@requires_jit
def test_coded_step_scan_decodes_only_the_mirror_highlights(step_scan):
    """Binary-coded frames of the same render, decoded with the part's settings (the scan's brightest
    decoded pixel as the reference, ``ScanObject.decode_settings``): the decoder keeps the sequential
    highlights and no glossy tail, which a threshold against each source's own peak turns into regions."""
    from shinysim.recon.coding import decode
    from shinysim.sim.coded import coded_stack
    from shinysim.studies.coded import pair_highlights, study_code

    sc = step_scan
    code = study_code("binary", sc.rig)
    coded = coded_stack(sc.stack, code)
    own = decode(coded, **sc.obj.decode_settings(sc.rig.camera))
    p = pair_highlights(own.table, sc.sequential.table)
    assert p["errors"] == 0 and p["missed"] == 0
    # at 8 spp a few single pixels of render noise sit just above the threshold; the sequential
    # detection drops them as noise islands (a peak within one noise sigma of the level), the decoder
    # of ideal frames has no noise estimate to do so (the 512 px, 16 spp scan has none)
    spurious = own.table["area"][p["partner"] < 0]
    assert np.all(spurious == 1) and len(spurious) <= 0.05 * p["paired"]
    per_source = decode(coded)  # each source's own peak: the tails of sources the part cannot mirror
    q = pair_highlights(per_source.table, sc.sequential.table)
    assert q["spurious"] > 5 * max(1, len(spurious)) and np.max(per_source.table["area"][q["partner"] < 0]) > 1
