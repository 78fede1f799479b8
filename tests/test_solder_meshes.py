"""Procedural solder-joint meshes (shinysim.sim.solder) and their exact profiles."""

import json
import math
import subprocess
import sys

import numpy as np
import pytest

trimesh = pytest.importorskip("trimesh")

from conftest import assert_default_modes  # noqa: E402

from shinysim.conventions import angle_between, normal_from_gradient  # noqa: E402
from shinysim.objects.solder import (  # noqa: E402
    COMMON_RANGES,
    FIELD_HALF_WIDTH,
    JOINT_KINDS,
    LEAD_TYPES,
    NOMINAL_PARAMS,
    PAD_THICKNESS,
    PARAM_RANGES,
    JointParams,
    JointProfile,
)
from shinysim.sim.solder import (  # noqa: E402
    MAX_FACET_LENGTH,
    TESSELLATION_BOUND,
    load_joint,
    main,
    make_joint,
    sample_params,
    save_joint,
)

N_SAMPLED = 4  # random joints per class, on top of the nominal one per lead type


@pytest.fixture(scope="module")
def nominal_joints():
    return {(k, t): make_joint(JointParams(kind=k, lead_type=t)) for k in JOINT_KINDS for t in LEAD_TYPES}


@pytest.fixture(scope="module")
def sampled_params():
    rng = np.random.default_rng(1234)
    return {k: [sample_params(k, rng) for _ in range(N_SAMPLED)] for k in JOINT_KINDS}


@pytest.fixture(scope="module")
def sampled_joints(sampled_params):
    return {k: [make_joint(p) for p in ps] for k, ps in sampled_params.items()}


@pytest.fixture(scope="module")
def all_joints(nominal_joints, sampled_joints):
    return list(nominal_joints.values()) + [j for js in sampled_joints.values() for j in js]


def _pseudo_normals(mesh):
    """Angle-weighted vertex pseudo-normals (sum of incident face normals times
    the face's angle at the vertex); they point out of a closed, consistently
    wound mesh whatever its triangulation."""
    acc = np.zeros((len(mesh.vertices), 3))
    for k in range(3):
        np.add.at(acc, mesh.faces[:, k], mesh.face_normals * mesh.face_angles[:, k : k + 1])
    return acc / np.linalg.norm(acc, axis=1, keepdims=True)


def _on_surface(vertices, surface):
    return np.abs(vertices[:, 2] - surface.z(vertices[:, 0])) < 1e-12


def _surface_facets(mesh, surface):
    """Swept facets of ``mesh`` lying on the exact ``surface``.

    A swept wall quad (two triangles) spans one chord of the sampled profile.
    Returns the chords' (x, z) end points, (S, 2, 2) sorted by x, and the
    normals of the triangles on each chord, (S, 2, 3).
    """
    v = np.asarray(mesh.vertices)
    on = _on_surface(v, surface)
    fn = mesh.face_normals
    sel = np.all(on[mesh.faces], axis=1) & (np.abs(fn[:, 1]) < 1e-9)
    xz = v[mesh.faces[sel]][:, :, [0, 2]]
    order = np.argsort(xz[:, :, 0], axis=1)
    xz = np.take_along_axis(xz, order[:, :, None], axis=1)
    ends = xz[:, [0, 2]]  # the two distinct (x, z) of the triangle
    key = np.round(ends[:, 0, 0], 12)
    idx = np.argsort(key, kind="stable")
    ends, normals, key = ends[idx], fn[sel][idx], key[idx]
    assert np.all(key[0::2] == key[1::2])  # two triangles per chord
    return ends[0::2], np.stack([normals[0::2], normals[1::2]], axis=1)


def _surface_cases(joint):
    yield "solder", joint.meshes["solder"], 0.0, joint.profile.fillet
    if joint.kind == "bridge":
        yield "bridge", joint.meshes["bridge"], joint.params.neighbour_pitch / 2, joint.profile.bridge


# -- mesh validity ------------------------------------------------------------


def test_parts_watertight_consistent_positive_volume(all_joints):
    for joint in all_joints:
        expected = {"board", "pad", "lead", "solder"}
        if joint.kind == "bridge":
            expected |= {"neighbour_pad", "neighbour_lead", "neighbour_solder", "bridge"}
        assert set(joint.meshes) == expected
        assert set(joint.materials) == expected
        for name, mesh in joint.meshes.items():
            assert mesh.is_watertight, (joint.kind, name)
            assert mesh.is_winding_consistent, (joint.kind, name)
            assert mesh.volume > 0, (joint.kind, name)
            assert len(np.unique(mesh.vertices, axis=0)) == len(mesh.vertices), (joint.kind, name)


def test_vertex_normals_unit_and_outward(all_joints):
    for joint in all_joints:
        for name, mesh in joint.meshes.items():
            vn = np.asarray(mesh.vertex_normals)
            np.testing.assert_allclose(np.linalg.norm(vn, axis=1), 1.0, atol=1e-12)
            # outward: on the same side as the faces around the vertex
            assert np.all(np.sum(vn * _pseudo_normals(mesh), axis=1) > 0), (joint.kind, name)


def test_vertex_normals_on_smooth_faces_within_bound(all_joints):
    # On the exact curved surfaces (fillet/ball, bridge, lead bends) the vertex
    # normals are the exact ones, so the angle between each of them and the
    # face normal is the facet-vs-exact-normal error at the vertices; it must
    # be within the tessellation bound. Flat faces must carry their own normal.
    for joint in all_joints:
        surfaces = {"solder": joint.profile.fillet, "neighbour_solder": joint.profile.fillet,
                    "bridge": joint.profile.bridge}
        for name, mesh in joint.meshes.items():
            fn = mesh.face_normals
            vn = np.asarray(mesh.vertex_normals)[mesh.faces]
            wall = np.abs(fn[:, 1]) < 1e-9  # swept walls (the y-caps reuse wall normals)
            if name in surfaces:
                sel = wall & np.all(_on_surface(np.asarray(mesh.vertices), surfaces[name])[mesh.faces], axis=1)
            else:
                # leave out the shading bevels at creases (vertex normals of one
                # face that differ by more than a tessellation step)
                spread = np.max(
                    [angle_between(vn[:, a], vn[:, b]) for a, b in ((0, 1), (1, 2), (0, 2))], axis=0
                )
                sel = wall & (spread < 4 * TESSELLATION_BOUND)
            assert sel.sum() > 0
            err = angle_between(vn[sel], fn[sel][:, None, :])
            assert err.max() <= TESSELLATION_BOUND + 1e-9, (joint.kind, name, math.degrees(err.max()))


# -- mesh vs exact profile ----------------------------------------------------


def test_fillet_mesh_matches_profile_z(all_joints):
    rng = np.random.default_rng(7)
    for joint in all_joints:
        for _, mesh, y, surface in _surface_cases(joint):
            xz, _ = _surface_facets(mesh, surface)
            # the facets on the surface tile its whole x-range
            np.testing.assert_allclose(xz[0, 0, 0], surface.x_start, atol=1e-12)
            np.testing.assert_allclose(xz[-1, 1, 0], surface.x_end, atol=1e-12)
            np.testing.assert_allclose(xz[1:, 0, 0], xz[:-1, 1, 0], atol=1e-12)
            d = xz[:, 1] - xz[:, 0]
            length = np.hypot(d[:, 0], d[:, 1])
            assert length.max() <= MAX_FACET_LENGTH * (1 + 1e-9)
            t = rng.uniform(size=(len(xz), 8))
            x = xz[:, 0, :1] + t * d[:, :1]
            z_mesh = xz[:, 0, 1:] + t * d[:, 1:]
            err = np.abs(z_mesh - joint.profile_z(x, y))
            # Tolerance: on a facet whose exact tangent stays within B of the
            # chord direction (B = TESSELLATION_BOUND), a point at arc distance
            # s from the nearer end lies at most s*sin(B) <= (L/2) sin(B) off
            # the chord (L = facet length). Measured vertically that grows by
            # 1/cos of the steepest tangent on the facet, at most the chord's
            # slope angle plus B.
            chord = np.abs(np.arctan2(d[:, 1], d[:, 0]))
            tol = 0.5 * length * math.sin(TESSELLATION_BOUND) / np.cos(chord + TESSELLATION_BOUND)
            assert np.all(err <= tol[:, None] + 1e-12), (joint.kind, float((err / tol[:, None]).max()))


def test_facet_normals_within_bound_of_exact(all_joints):
    worst = 0.0
    for joint in all_joints:
        for _, mesh, y, surface in _surface_cases(joint):
            xz, facet_normals = _surface_facets(mesh, surface)
            d = xz[:, 1] - xz[:, 0]
            t = np.linspace(0.0, 1.0, 33)
            x = xz[:, 0, :1] + t * d[:, :1]
            exact = joint.profile_normal(x, y)[:, None]  # (S, 1, 33, 3)
            err = angle_between(exact, facet_normals[:, :, None, :])
            worst = max(worst, err.max())
    assert worst <= TESSELLATION_BOUND, math.degrees(worst)
    assert worst > 0.25 * TESSELLATION_BOUND  # the facets are not needlessly fine


def test_fillet_vertex_normals_are_exact(all_joints):
    for joint in all_joints:
        mesh = joint.meshes["solder"]
        v = np.asarray(mesh.vertices)
        x0, x1 = joint.fillet_x_range
        on = (np.abs(v[:, 2] - joint.profile_z(v[:, 0], 0.0)) < 1e-12) & (v[:, 0] >= x0) & (v[:, 0] <= x1)
        assert on.sum() == 2 * len(joint.fillet_points)
        np.testing.assert_allclose(
            np.asarray(mesh.vertex_normals)[on], joint.profile_normal(v[on, 0], 0.0), atol=1e-12
        )


# -- exact profile ---------------------------------------------------------------


def test_profile_normal_matches_finite_difference(all_joints):
    h = 1e-6
    for joint in all_joints:
        x0, x1 = joint.fillet_x_range
        x = np.linspace(x0 + 2e-4, x1 - 2e-4, 301)
        slope_fd = (joint.profile_z(x + h) - joint.profile_z(x - h)) / (2 * h)
        np.testing.assert_allclose(joint.profile_slope(x), slope_fd, rtol=1e-5, atol=1e-6)
        n_fd = normal_from_gradient(slope_fd, 0.0)
        assert angle_between(joint.profile_normal(x), n_fd).max() < 1e-5
        z2_fd = (joint.profile_z(x + 1e-4) - 2 * joint.profile_z(x) + joint.profile_z(x - 1e-4)) / 1e-8
        kappa_fd = -z2_fd / (1 + slope_fd**2) ** 1.5
        np.testing.assert_allclose(joint.profile_curvature(x), kappa_fd, rtol=1e-2, atol=1e-2)


def test_profile_shapes_nan_and_contact_points(nominal_joints):
    joint = nominal_joints[("good", "gull-wing")]
    x0, x1 = joint.fillet_x_range
    x = np.linspace(x0, x1, 6).reshape(2, 3)
    assert joint.profile_z(x).shape == (2, 3)
    assert joint.profile_normal(x).shape == (2, 3, 3)
    assert joint.profile_normal(x, np.zeros((4, 1, 1))).shape == (4, 2, 3, 3)
    # off the solder: NaN, never an exception (incl. NaN / inf input)
    off = joint.profile_z(np.array([x0 - 0.01, x1 + 0.01, np.nan, np.inf]))
    assert np.all(np.isnan(off))
    assert np.all(np.isnan(joint.profile_z(0.5 * (x0 + x1), 0.5)))
    assert np.all(np.isnan(joint.profile_normal(x0 - 0.01)))
    # the fillet starts on the pad and ends on the lead at fillet_height
    p = joint.params
    np.testing.assert_allclose(joint.profile_z(x0), PAD_THICKNESS, atol=1e-12)
    np.testing.assert_allclose(joint.profile_z(x1), PAD_THICKNESS + p.fillet_height, atol=1e-12)
    np.testing.assert_allclose(np.arctan(joint.profile_slope(x0)), p.contact_angle_pad, atol=1e-9)
    np.testing.assert_allclose(np.arctan(joint.profile_slope(x1)), p.lead_slope_angle, atol=1e-9)
    np.testing.assert_allclose(joint.profile.lead.outer_x(joint.profile_z(x1)), x1, atol=1e-12)


def test_fillet_inside_camera_field(all_joints):
    f = FIELD_HALF_WIDTH
    for joint in all_joints:
        x0, x1 = joint.fillet_x_range
        assert -f < x0 < x1 < f
        v0, v1 = joint.visible_x_range
        assert x0 == v0 < v1 <= x1
        for name, mesh in joint.meshes.items():
            if name == "board":
                assert np.all(mesh.bounds[0, :2] <= -f) and np.all(mesh.bounds[1, :2] >= f)
                continue
            assert np.all(np.abs(mesh.bounds[:, :2]) < f), (joint.kind, name)


# -- classes ------------------------------------------------------------------


def test_sampled_params_lie_in_documented_ranges(sampled_params):
    for kind, params in sampled_params.items():
        ranges = {**COMMON_RANGES, **PARAM_RANGES[kind]}
        for p in params:
            assert p.kind == kind and p.lead_type in LEAD_TYPES
            for name, value in p.to_dict().items():
                if name in ("kind", "lead_type"):
                    continue
                if name in ranges:
                    lo, hi = ranges[name]
                    assert lo <= value <= hi, (kind, name, value)
                elif name in NOMINAL_PARAMS[kind]:  # not varied by sample_params: the nominal value
                    assert value == NOMINAL_PARAMS[kind][name], (kind, name)
                else:
                    assert value is None, (kind, name)


def test_sampling_is_seeded_and_varies():
    a = [sample_params("good", np.random.default_rng(5)) for _ in range(2)]
    assert a[0] == a[1]
    rng = np.random.default_rng(5)
    b = [sample_params("good", rng) for _ in range(12)]
    assert len({p.fillet_height for p in b}) == 12
    assert {p.lead_type for p in b} == set(LEAD_TYPES)
    assert sample_params("excess", 3) == sample_params("excess", np.random.default_rng(3))


def test_classes_differ_in_their_defining_property(sampled_joints, nominal_joints):
    joints = {k: list(v) for k, v in sampled_joints.items()}
    for (k, _), j in nominal_joints.items():
        joints[k].append(j)
    top_insufficient = max(PARAM_RANGES["insufficient"]["fillet_height"])
    for kind, js in joints.items():
        for j in js:
            x0, x1 = j.fillet_x_range
            x = np.linspace(x0, x1, 2001)
            kappa = j.profile_curvature(x, ripple=False)
            lead = j.profile.lead
            lift = lead.bottom_z - PAD_THICKNESS
            gap_y = j.profile_z(x, 0.5 * 0.65)
            if kind in ("good", "insufficient", "bridge"):
                assert np.all(kappa < 0), kind  # concave meniscus
                assert j.profile.contact_point is not None and lift <= 0.02
            if kind in ("good", "bridge"):
                assert j.fillet_height > top_insufficient
            if kind == "insufficient":
                assert j.fillet_height <= top_insufficient
            if kind == "excess":
                assert np.all(kappa > 0)  # bulging
                assert np.any(j.profile_curvature(x) > 0)
                assert j.fillet_height >= min(PARAM_RANGES["excess"]["fillet_height"])
            if kind == "lifted":
                assert np.any(j.profile_curvature(x) > 0)
                assert lift >= 0.05 and j.profile.contact_point is None
                assert x1 < lead.min_x  # the solder does not reach the lead
                assert np.isnan(j.profile_z(0.5 * (x1 + lead.min_x)))
            if kind == "bridge":
                yb = j.params.neighbour_pitch / 2
                assert np.nanmax(j.profile_z(np.linspace(-1, 1, 2001), yb)) > PAD_THICKNESS
            else:
                assert np.all(np.isnan(gap_y))


# -- input checking -------------------------------------------------------------


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(kind="cold"), "kind must be one of"),
        (dict(lead_type="butt"), "lead_type must be one of"),
        (dict(fillet_height=-0.1), "fillet_height must lie in"),
        (dict(fillet_height=float("nan")), "fillet_height must be finite"),
        (dict(contact_angle_pad=math.radians(95)), "contact_angle_pad must lie in"),
        (dict(lead_lift="0.1"), "lead_lift must be a real number"),
        (dict(ripple_amplitude=True), "ripple_amplitude must be a real number"),
        (dict(lead_width=0.5, pad_width=0.4), "lead_width"),
        (dict(lead_thickness=0.13, lead_type="gull-wing"), "lead_thickness"),
        (dict(ball_clearance=0.05), "ball_clearance applies only to"),
        (dict(kind="lifted", lead_slope_angle=0.5), "lead_slope_angle applies only to"),
        (dict(kind="bridge", neighbour_pitch=0.42), "neighbour_pitch"),
        (dict(kind="bridge", bridge_height=0.2, bridge_length=0.3), "bridge_height"),
    ],
)
def test_bad_params_raise(kwargs, match):
    with pytest.raises(ValueError, match=match):
        JointParams(**kwargs)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(fillet_height=0.3, contact_angle_pad=0.1, lead_slope_angle=0.3, pad_length=1.0), "fillet foot"),
        (dict(fillet_height=0.01, lead_lift=0.02), "fillet_height"),
        (dict(contact_angle_pad=0.03, lead_slope_angle=0.03), "contact_angle_pad \\+ lead_slope_angle"),
        (dict(kind="excess", fillet_height=0.3, lead_slope_angle=math.radians(-60)), "lead_slope_angle"),
        (dict(kind="lifted", fillet_height=0.3, contact_angle_pad=0.5), "solder ball"),
        (dict(lead_offset=0.2), "lead_offset"),
        (
            dict(kind="insufficient", fillet_height=0.035, contact_angle_pad=0.02, lead_slope_angle=0.4,
                 lead_lift=0.0, ripple_amplitude=0.01, ripple_wavelength=0.2, ripple_phase=4.1),
            "ripple_amplitude",
        ),
    ],
)
def test_bad_combinations_raise(kwargs, match):
    params = JointParams(**kwargs)
    with pytest.raises(ValueError, match=match):
        JointProfile(params)
    with pytest.raises(ValueError, match=match):
        make_joint(params)


def test_bad_arguments_raise():
    with pytest.raises(ValueError, match="kind must be one of"):
        sample_params("cold", np.random.default_rng(0))
    with pytest.raises(ValueError, match="rng must be"):
        sample_params("good", rng="seed")
    with pytest.raises(ValueError, match="params must be a JointParams"):
        make_joint({"kind": "good"})
    with pytest.raises(ValueError, match="bound must lie in"):
        make_joint(JointParams(), bound=0.0)
    with pytest.raises(ValueError, match="unknown JointParams fields"):
        JointParams.from_dict({"kind": "good", "colour": "grey"})


# -- files ------------------------------------------------------------------------


def test_save_writes_ply_json_and_refuses_overwrite(tmp_path, nominal_joints):
    joint = nominal_joints[("bridge", "j-lead")]
    files = save_joint(joint, tmp_path / "j")
    assert set(files) == set(joint.meshes) | {"json"}
    for name, mesh in joint.meshes.items():
        path = files[name]
        assert path.stat().st_size < 1_000_000
        with open(path, "rb") as fh:
            assert fh.read(64).startswith(b"ply\nformat binary_little_endian 1.0\n")
        loaded = trimesh.load(path, process=False)
        assert loaded.is_watertight and loaded.is_winding_consistent
        np.testing.assert_array_equal(loaded.faces, mesh.faces)
        np.testing.assert_allclose(loaded.vertices, mesh.vertices, atol=1e-6)
        np.testing.assert_allclose(loaded.vertex_normals, mesh.vertex_normals, atol=1e-6)
    doc = json.loads(files["json"].read_text())
    assert doc["kind"] == "bridge" and doc["units"] == {"length": "mm", "angle": "rad"}
    assert JointParams.from_dict(doc["params"]) == joint.params
    assert doc["parts"]["solder"]["material"] == "roughconductor"
    before = files["solder"].read_bytes()
    with pytest.raises(FileExistsError, match="overwrite=True"):
        save_joint(joint, tmp_path / "j")
    other = make_joint(JointParams(kind="bridge", lead_type="j-lead", fillet_height=0.25))
    with pytest.raises(FileExistsError):
        save_joint(other, tmp_path / "j")
    assert files["solder"].read_bytes() == before  # nothing was touched
    save_joint(other, tmp_path / "j", overwrite=True)
    assert files["solder"].read_bytes() != before
    assert load_joint(tmp_path / "j").params == other.params
    assert_default_modes(tmp_path / "j")


def test_cli_writes_one_joint_per_kind(tmp_path, capsys):
    assert main(["--out", str(tmp_path), "--seed", "0", "--kinds", "good", "lifted"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["good", "lifted"]
    assert (tmp_path / "lifted" / "solder.ply").is_file()
    with pytest.raises(FileExistsError):
        main(["--out", str(tmp_path), "--seed", "0", "--kinds", "good"])
    assert "good" in capsys.readouterr().out


def test_profiles_module_does_not_import_trimesh():
    code = (
        "import sys; import shinysim.objects.solder as s; "
        "s.JointProfile(s.JointParams(kind='excess', lead_type='j-lead')); "
        "assert 'trimesh' not in sys.modules and 'mitsuba' not in sys.modules"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
