"""Data-set specs, items and folders (``shinysim dataset``)."""

from __future__ import annotations

import json
import re
import socket
import warnings
from pathlib import Path

import numpy as np
import pytest
from conftest import HAS_JIT, skip_without_render

from shinysim.datasets.spec import (
    SPEC_FORMAT,
    load_spec,
    parse_spec,
    resolve_item,
    spec_diff,
)
from shinysim.errors import OptionError, SpecError


def spec_doc(**group):
    g = {"name": "spheres", "count": 5}
    g.update(group)
    return {"format": SPEC_FORMAT, "name": "t", "seed": 7, "groups": [g]}


def write_spec(tmp_path, doc, name="spec.json"):
    p = tmp_path / name
    p.write_text(json.dumps(doc) if not isinstance(doc, str) else doc)
    return p


# -- the spec ------------------------------------------------------------------------

def test_defaults_groups_and_grid_count_items():
    doc = {"format": SPEC_FORMAT, "seed": 1, "defaults": {"render": {"spp": 8}},
           "groups": [{"count": 3},
                      {"count": 2, "grid": {"material.alpha": [0.01, 0.02, 0.04], "sensor.preset": ["ideal",
                                                                                                   "tv_1980s_8bit"]}}]}
    spec = parse_spec(doc)
    assert spec.n_items == 3 + 2 * 3 * 2
    g0 = spec.groups[0]
    assert g0["render"]["spp"] == 8 and g0["object"] == {"kind": "sphere"} and g0["rig"]["preset"] == "shiny_1988"
    assert spec.group_of(0) == (0, 0) and spec.group_of(3) == (1, 0) and spec.group_of(14) == (1, 11)
    # the grid: every combination, each `count` times, in order
    combos = [(resolve_item(spec, i)["material"]["alpha"], resolve_item(spec, i)["sensor"]["preset"])
              for i in range(3, 15)]
    assert combos[0] == combos[1] == (0.01, "ideal") and combos[2] == (0.01, "tv_1980s_8bit")
    assert sorted(set(combos)) == sorted({(a, s) for a in (0.01, 0.02, 0.04) for s in ("ideal", "tv_1980s_8bit")})
    with pytest.raises(SpecError, match="item 15 does not exist"):
        resolve_item(spec, 15)


def test_items_are_drawn_from_seed_and_index_alone():
    doc = spec_doc(count=50, object={"kind": "sphere", "center_mm": [{"uniform": [-0.2, 0.2]}, 0, 0]},
                   material={"kind": "conductor", "alpha": {"loguniform": [0.005, 0.05]}},
                   sensor={"preset": {"choice": ["ideal", "machine_vision_12bit"]}, "exposure": 0.8})
    spec = parse_spec(doc)
    items = [resolve_item(spec, i) for i in range(50)]
    # the same item again, and in a spec with more items: the same draws
    assert resolve_item(spec, 17) == items[17]
    bigger = parse_spec(spec_doc(**{**doc["groups"][0], "count": 500}))
    assert resolve_item(bigger, 17)["material"] == items[17]["material"]
    alphas = np.array([it["material"]["alpha"] for it in items])
    xs = np.array([it["object"]["center_mm"][0] for it in items])
    assert alphas.min() >= 0.005 and alphas.max() <= 0.05 and xs.min() >= -0.2 and xs.max() <= 0.2
    # log-uniform: the median sits near the geometric mean (sqrt(0.005 * 0.05) = 0.0158), not the arithmetic 0.0275
    assert 0.009 < np.median(alphas) < 0.025
    assert {it["sensor"]["preset"] for it in items} == {"ideal", "machine_vision_12bit"}
    assert len({it["seed"] for it in items}) == 50
    # another spec seed, other draws
    other = parse_spec({**doc, "seed": 8})
    assert resolve_item(other, 17)["material"] != items[17]["material"]


@skip_without_render  # a joint's draw is checked by the mesher (trimesh)
def test_random_shapes_and_joints_are_resolved_to_parameters():
    spec = parse_spec({"format": SPEC_FORMAT, "groups": [
        {"count": 2, "object": {"kind": "blob", "size_mm": 0.5}},
        {"count": 2, "object": {"kind": "solder", "class": {"choice": ["good", "bridge"]}}}]})
    blob = resolve_item(spec, 0)["object"]
    from shinysim.objects import shapes

    mesh = shapes.blob(**blob["params"])  # the item dict alone rebuilds the shape
    assert mesh.vertices.shape[0] > 1000
    joint = resolve_item(spec, 2)["object"]
    from shinysim.objects.solder import JointParams

    assert JointParams.from_dict(joint["params"]).kind == joint["class"]
    json.dumps(resolve_item(spec, 3))  # plain JSON


@pytest.mark.parametrize("doc, field, words", [
    ({"format": "shinysim-dataset/9", "groups": [{}]}, "format", "must be"),
    ({"format": SPEC_FORMAT, "groups": []}, "groups", "non-empty"),
    ({"format": SPEC_FORMAT, "group": [{}]}, None, "did you mean 'groups'"),
    (spec_doc(count=0), "groups[0].count", "outside"),
    (spec_doc(count=2.5), "groups[0].count", "whole number"),
    (spec_doc(material={"kind": "conductor", "alpha": {"uniform": [0.05, 0.01]}}), "groups[0].material.alpha.uniform",
     "above hi"),
    (spec_doc(material={"kind": "conductor", "alpha": {"loguniform": [0, 0.01]}}),
     "groups[0].material.alpha.loguniform[0]", "outside"),
    (spec_doc(material={"kind": "conductor", "alpha": {"gaussian": [0, 1]}}), "groups[0].material.alpha", "draw"),
    (spec_doc(material={"kind": "conductor", "alpha": 2.0}), "groups[0].material.alpha", "outside"),
    (spec_doc(material={"kind": "conductor", "alfa": 0.1}), "groups[0].material", "alpha"),
    (spec_doc(material={"kind": "plastic"}), "groups[0].material.kind", "must be one of"),
    (spec_doc(material={"kind": "hybrid", "k": 0.5}), "groups[0].material.sharpness", "needs k and sharpness"),
    (spec_doc(rig={"preset": "dome", "n_sources": {"choice": [20, 40]}}), "groups[0].rig.n_sources",
     "fixed within a group"),
    (spec_doc(rig={"preset": "dome", "n_sources": 5000}), "groups[0].rig", "view of the object"),
    (spec_doc(rig={"preset": "file", "path": "nowhere.json"}), "groups[0].rig.path", "no rig file"),
    (spec_doc(object={"kind": "mesh", "path": "part.stl"}), "groups[0].object.path", "no mesh file"),
    (spec_doc(object={"kind": "solder", "class": "cold"}), "groups[0].object.class", "must be one of"),
    (spec_doc(object={"kind": "solder"}, material={"kind": "diffuse"}), "groups[0].material.kind", "solder"),
    (spec_doc(sensor={"preset": "ideall"}), "groups[0].sensor.preset", "ideal"),
    (spec_doc(render={"spp": 0}), "groups[0].render.spp", "outside"),
    (spec_doc(render={"resolution": 8}), "groups[0].render.resolution", "outside"),
    (spec_doc(grid={"rig.n_sources": [1, 2]}), "groups[0].grid.rig.n_sources", "fixed within a group"),
    (spec_doc(grid={"material.roughness": [0.1]}), "groups[0].grid.material.roughness", "no parameter"),
    (spec_doc(grid={"material.alpha": []}), "groups[0].grid.material.alpha", "non-empty"),
    (spec_doc(grid={"material.alpha": [0.01, -1]}), "groups[0].grid.material.alpha[1]", "outside"),
])
def test_bad_specs_name_the_file_and_field(tmp_path, doc, field, words):
    path = write_spec(tmp_path, doc)
    with pytest.raises(SpecError) as e:
        load_spec(path)
    msg = str(e.value)
    assert msg.startswith(str(path)) and e.value.field == field and words in msg, msg


def test_unreadable_spec_files(tmp_path):
    for text, words in (("{", "not valid JSON (line 1"), ("\xff", "not UTF-8")):
        p = tmp_path / "bad.json"
        p.write_bytes(text.encode("latin-1"))
        with pytest.raises(SpecError, match=re.escape(words)):
            load_spec(p)
    with pytest.raises(SpecError, match="no such file"):
        load_spec(tmp_path / "missing.json")


def test_spec_diff_names_each_difference():
    a = parse_spec(spec_doc()).document
    b = parse_spec(spec_doc(count=6, material={"kind": "conductor", "alpha": 0.03})).document
    d = spec_diff(a, b, "spec")
    assert "spec.groups[0].count: 5 -> 6" in d and "spec.groups[0].material.alpha: 0.02 -> 0.03" in d
    assert spec_diff(a, a) == []


def test_the_documented_example_specs_are_valid():
    examples = sorted((Path(__file__).resolve().parents[1] / "docs" / "examples").glob("dataset-*.json"))
    assert len(examples) >= 2
    for path in examples:
        spec = load_spec(path)
        assert spec.n_items > 0 and resolve_item(spec, spec.n_items - 1)["index"] == spec.n_items - 1


# -- the folder ------------------------------------------------------------------------

def test_manifest_torn_row_is_dropped_and_a_bad_row_refused(tmp_path):
    from shinysim.datasets.engine import MANIFEST, read_manifest

    rows = [{"index": i, "status": "done", "path": f"items/00000/{i:08d}"} for i in range(3)]
    text = "".join(json.dumps(r) + "\n" for r in rows)
    (tmp_path / MANIFEST).write_text(text + '{"index": 3, "sta')  # killed while appending row 3
    assert sorted(read_manifest(tmp_path)) == [0, 1, 2]
    assert (tmp_path / MANIFEST).read_text().endswith('"sta')  # read alone changes nothing
    read_manifest(tmp_path, repair=True)
    repaired = (tmp_path / MANIFEST).read_text()
    assert repaired.count("\n") == 3 and repaired.endswith("}\n") and '"index": 3' not in repaired
    (tmp_path / MANIFEST).write_text(text.replace('"index": 1', '"indx": 1'))
    with pytest.raises(SpecError, match="line 2 is not a manifest row"):
        read_manifest(tmp_path)


def test_folder_made_from_another_spec_is_refused_with_the_difference(tmp_path):
    from shinysim.datasets.engine import prepare_folder

    fp = {"format": "shinysim-dataset-folder/1", "spec": parse_spec(spec_doc()).document, "inputs": {},
          "renderer": {"variant": "llvm_ad_mono"}}
    prepare_folder(tmp_path / "ds", fp)
    prepare_folder(tmp_path / "ds", fp)  # the same spec: accepted (a resume)
    other = dict(fp, spec=parse_spec(spec_doc(count=9)).document)
    with pytest.raises(SpecError, match=r"groups\[0\]\.count: 5 -> 9"):
        prepare_folder(tmp_path / "ds", other)
    with pytest.raises(SpecError, match="variant"):
        prepare_folder(tmp_path / "ds", dict(fp, renderer={"variant": "cuda_ad_mono"}))
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "notes.txt").write_text("mine")
    with pytest.raises(OptionError, match="not empty and holds no dataset.json"):
        prepare_folder(tmp_path / "busy", fp)


def test_a_second_run_on_the_same_folder_is_refused_while_the_first_holds_it(tmp_path):
    from shinysim.datasets.engine import _Lock

    with _Lock(tmp_path):
        with pytest.raises(OptionError, match="being written by another run"):
            with _Lock(tmp_path):
                pass
    with _Lock(tmp_path):  # released
        pass


# -- rendered items -----------------------------------------------------------------------

ALL_KINDS = {
    "format": SPEC_FORMAT, "name": "all kinds", "seed": 2,
    "defaults": {"render": {"resolution": 48, "spp": 4, "coverage": 2}},
    "groups": [
        {"name": "spheres", "count": 2, "object": {"kind": "sphere", "radius_mm": {"uniform": [0.5, 0.8]}},
         "sensor": {"preset": "machine_vision_12bit", "exposure": 0.8}},
        {"name": "blobs", "count": 2, "object": {"kind": "blob", "size_mm": 0.6}},
        {"name": "hybrid superquadric", "count": 1, "object": {"kind": "superquadric", "size_mm": 0.6},
         "material": {"kind": "hybrid", "k": 0.3, "sharpness": 200}},
        {"name": "lambertian heightfield", "count": 1, "object": {"kind": "heightfield", "size_mm": 0.8},
         "rig": {"preset": "dome", "n_sources": 12, "radius_mm": None}, "material": {"kind": "diffuse"}},
        {"name": "user mesh", "count": 1, "object": {"kind": "mesh", "path": "part.ply", "fit_mm": 1.2}},
        {"name": "joint", "count": 1, "object": {"kind": "solder", "class": "bridge"},
         "render": {"coverage": 0, "max_depth": 3}},
        {"name": "stereo", "count": 1, "rig": {"preset": "stereo", "beta_deg": 20}},
        {"name": "bad mesh", "count": 1, "object": {"kind": "mesh", "path": "broken.ply"}},
    ],
}


@pytest.fixture(scope="module")
def all_kinds(tmp_path_factory):
    pytest.importorskip("dask.distributed")
    if not HAS_JIT:
        pytest.skip("needs a JIT Mitsuba variant")
    import trimesh

    from shinysim.datasets.engine import run_dataset

    root = tmp_path_factory.mktemp("dataset")
    trimesh.creation.capsule(height=1.0, radius=0.3).export(root / "part.ply")
    (root / "broken.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\nend_header\n1 2\n")
    spec = write_spec(root, ALL_KINDS)
    summary = run_dataset(spec, root / "ds", workers=2, retries=1)
    return root, spec, summary


def test_the_local_cluster_takes_no_fixed_port(tmp_path):
    """Port 8787 (Dask's default dashboard port) held, as by a dashboard of another cluster: the local cluster's
    HTTP server takes a free port, so the run starts and warns of nothing (distributed warns where its port is
    taken and falls back; with ``dashboard_address=None`` the scheduler still asks for 8787)."""
    pytest.importorskip("dask.distributed")
    if not HAS_JIT:
        pytest.skip("needs a JIT Mitsuba variant")
    from shinysim.datasets.engine import run_dataset

    holder = socket.socket()
    try:
        holder.bind(("127.0.0.1", 8787))
        holder.listen()
    except OSError:  # something else holds it already: the case under test
        pass
    doc = dict(spec_doc(count=1), defaults={"render": {"resolution": 16, "spp": 1}})
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            summary = run_dataset(write_spec(tmp_path, doc), tmp_path / "ds", workers=1, retries=0)
    finally:
        holder.close()
    assert summary["done"] == 1 and summary["failed"] == [], summary


def test_every_kind_renders_and_a_failing_item_is_recorded(all_kinds):
    from shinysim.datasets.engine import read_manifest
    from shinysim.datasets.items import file_digests
    from shinysim.io import load_stack, load_truth

    root, spec, summary = all_kinds
    assert summary["n_items"] == 10 and summary["done"] == 9 and summary["failed"] == [9], summary
    rows = read_manifest(root / "ds")
    assert list(rows) == list(range(10))  # rewritten in index order
    bad = rows[9]
    assert bad["status"] == "failed" and "broken.ply" in bad["error"], bad
    for i in range(9):
        row = rows[i]
        folder = root / "ds" / row["path"]
        assert file_digests(folder) == row["files"]  # the manifest's checksums are the files'
        stack = load_stack(folder / "stack.exr")
        truth = load_truth(folder / "truth.exr", stack.camera)
        assert truth.mask.any(), i
        n = truth.normals[truth.mask]
        # unit normals at pixel centres, never averaged over a pixel (float32 storage)
        np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-5)
        if row["item"]["render"]["coverage"]:
            assert truth.coverage is not None
            # a curved silhouette crosses sub-pixel samples somewhere (a square height field's straight,
            # axis-aligned edges can miss every sample of a 2 x 2 grid)
            if row["item"]["object"]["kind"] in ("sphere", "blob", "superquadric"):
                assert ((truth.coverage > 0) & (truth.coverage < 1)).any(), i
        assert stack.frames.max() > 0, i
        item = json.loads((folder / "item.json").read_text())
        assert item["index"] == i and item["object"] == row["item"]["object"]
    stereo = root / "ds" / rows[8]["path"]
    assert (stereo / "stack.camera1.exr").is_file() and (stereo / "truth.camera1.exr").is_file()
    # the digitised group carries its sensor's clip level
    assert load_stack(root / "ds" / rows[0]["path"] / "stack.exr").saturation is not None


def test_an_item_rebuilt_alone_has_the_same_bytes(all_kinds, tmp_path):
    from shinysim.datasets.engine import build_one, read_manifest

    root, spec, _ = all_kinds
    rows = read_manifest(root / "ds")
    for index in (3, 7, 8):  # a random shape (a reused scene), a joint, the stereo pair
        names = build_one(spec, index, tmp_path / str(index))
        for name in names:
            assert (tmp_path / str(index) / name).read_bytes() == (root / "ds" / rows[index]["path"] / name
                                                                   ).read_bytes(), (index, name)


def test_rerun_finishes_nothing_new_and_a_changed_spec_is_refused(all_kinds):
    from shinysim.datasets.engine import run_dataset

    root, spec, _ = all_kinds
    before = sorted(p for p in (root / "ds").rglob("*") if p.is_file())
    again = run_dataset(spec, root / "ds", workers=1, retries=0, items=[0, 1, 2])
    assert again["rendered"] == 0
    assert sorted(p for p in (root / "ds").rglob("*") if p.is_file()) == before
    changed = dict(ALL_KINDS, seed=3)
    with pytest.raises(SpecError, match="seed: 2 -> 3"):
        run_dataset(write_spec(root, changed, "changed.json"), root / "ds", workers=1)


def test_export_of_a_dataset_reads_back(all_kinds, tmp_path):
    from shinysim.datasets.export import export_diligent_folders
    from shinysim.io.diligent import read_diligent

    root, _, _ = all_kinds
    written = export_diligent_folders(root / "ds", tmp_path / "dil")
    assert [p.name for p in written] == [f"{i:08d}" for i in range(9)]
    lamb = read_diligent(written[5])
    assert lamb.stack.n_sources == 12 and lamb.normals is not None
    with pytest.raises(OptionError, match="neither dataset.json nor stack.exr"):
        export_diligent_folders(tmp_path, tmp_path / "x")


def test_cli_dataset_bad_input_is_one_line(tmp_path, capsys):
    from shinysim.cli import main

    spec = write_spec(tmp_path, spec_doc(material={"kind": "conductor", "alpha": -1}))
    assert main(["dataset", str(spec), "--out", str(tmp_path / "ds")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("shinysim dataset: error: ") and "material.alpha" in err[0]
    assert not (tmp_path / "ds").exists()
    assert main(["dataset", "item", str(spec), "0", "--out", str(tmp_path / "one")]) == 1
    assert "shinysim dataset item: error:" in capsys.readouterr().err
    assert main(["dataset", "export", "--format", "diligent", str(tmp_path / "nothing"), "--out",
                 str(tmp_path / "x")]) == 1
    assert "not a folder" in capsys.readouterr().err


def test_cli_reconstructs_an_exported_item_as_diligent(all_kinds, tmp_path, capsys):
    from shinysim.cli import main
    from shinysim.datasets.engine import read_manifest

    root, _, _ = all_kinds
    item = root / "ds" / read_manifest(root / "ds")[0]["path"]  # a mirror-like sphere, 12-bit sensor
    assert main(["dataset", "export", "--format", "diligent", str(item), "--out", str(tmp_path / "dil")]) == 0
    assert main(["reconstruct", "--diligent", str(tmp_path / "dil"), "--out", str(tmp_path / "rec")]) == 0
    score = json.loads((tmp_path / "rec" / "score.json").read_text())
    fixed = score["models"]["fixed"]
    assert fixed["n"] >= 15  # most of the 21 fibers light a highlight on the sphere
    # the exported lights are the fibers' directions from the sphere's middle (DiLiGenT has no near
    # sources): up to ~1 deg off across the object, plus centroid noise of ~0.5 px at 48 px, where a
    # pixel spans ~4 deg of normal on a 0.6 mm sphere; a flipped axis would put errors in the tens of degrees
    assert fixed["median_deg"] < 5.0, fixed
    assert "highlights" in capsys.readouterr().out
