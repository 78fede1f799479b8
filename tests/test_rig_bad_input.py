"""rig.json as a careless or hostile user writes it: one named case per class.

Every case raises ``RigError`` (a ``ValueError``) whose message starts with
the file and names the field, and nothing else; a misspelt key is never
silently replaced by its default. Byte-level fuzzing is in
``tests/test_fuzz_readers.py``.
"""

from __future__ import annotations

import copy
import json

import pytest

from shinysim.errors import RigError
from shinysim.io import MAX_RIG_BYTES, load_rig
from shinysim.rig import shiny_1988

DOC = shiny_1988(resolution=64).to_dict()


def edit(fn):
    d = copy.deepcopy(DOC)
    fn(d)
    return json.dumps(d)


def rename(d, old, new):
    d[new] = d.pop(old)


CASES = {
    # misspelt or unknown keys: named, with a suggestion, never defaulted
    "misspelt reference_z_mm": (edit(lambda d: rename(d, "reference_z_mm", "reference_z")),
                                r"rig: unknown field 'reference_z' \(did you mean 'reference_z_mm'\?\)"),
    "misspelt radius_mm": (edit(lambda d: rename(d["sources"][3], "radius_mm", "radius")),
                           r"sources\[3\]: unknown field 'radius' \(did you mean 'radius_mm'\?\)"),
    "misspelt field_width_mm": (edit(lambda d: rename(d["cameras"][0], "field_width_mm", "fieldwidth_mm")),
                                r"cameras\[0\]: unknown field 'fieldwidth_mm' \(did you mean 'field_width_mm'\?\)"),
    "unknown top-level key": (edit(lambda d: d.update(lights=[])), "rig: unknown field 'lights'"),
    "missing required camera field": (edit(lambda d: d["cameras"][0].pop("up")),
                                      r"cameras\[0\]: missing required field\(s\): up"),
    "missing sources": (edit(lambda d: d.pop("sources")), r"rig: missing required field\(s\): sources"),
    # JSON types
    "null number": (edit(lambda d: d["cameras"][0].update(width=None)), r"cameras\[0\].width: must be an integer, got null"),
    "string number": (edit(lambda d: d["cameras"][0].update(field_width_mm="2.0")),
                      r"cameras\[0\].field_width_mm: must be a number, got \"2.0\""),
    "boolean number": (edit(lambda d: d.update(reference_z_mm=True)), "reference_z_mm: must be a number, got true"),
    "fractional width": (edit(lambda d: d["cameras"][0].update(width=64.5)), r"cameras\[0\].width: must be an integer"),
    "vector of two": (edit(lambda d: d["sources"][0].update(position_mm=[1, 2])),
                      r"sources\[0\].position_mm: must be 3 finite numbers"),
    "vector with a string": (edit(lambda d: d["cameras"][0].update(up=[0, "1", 0])), r"cameras\[0\].up: must be 3 finite"),
    "sources not a list": (edit(lambda d: d.update(sources={"a": 1})), "rig.sources: must be a list"),
    "source not an object": (edit(lambda d: d["sources"].__setitem__(2, [0, 0, 1])),
                             r"sources\[2\]: must be a JSON object, got a list"),
    "metadata not an object": (edit(lambda d: d.update(metadata="none")), "rig.metadata: must be a JSON object"),
    "name not a string": (edit(lambda d: d.update(name=5)), "rig.name: must be a string"),
    "top level is a list": ("[1, 2, 3]", "rig: must be a JSON object, got a list"),
    # ranges
    "NaN position": (edit(lambda d: d["sources"][0].update(position_mm=[float("nan"), 0, 1])),
                     r"sources\[0\].position_mm: must be 3 finite numbers"),
    "infinite reference plane": (edit(lambda d: d.update(reference_z_mm=float("inf"))), "reference_z_mm: must be finite"),
    "negative source radius": (edit(lambda d: d["sources"][5].update(radius_mm=-0.5)),
                               r"sources\[5\].radius_mm: must be >= 0 mm, got -0.5"),
    "zero field width": (edit(lambda d: d["cameras"][0].update(field_width_mm=0)),
                         r"cameras\[0\].field_width_mm: must be a finite width > 0 mm"),
    "negative field width": (edit(lambda d: d["cameras"][0].update(field_width_mm=-2)),
                             r"cameras\[0\].field_width_mm: must be a finite width > 0 mm"),
    "zero width": (edit(lambda d: d["cameras"][0].update(width=0)), r"cameras\[0\].width: must be an integer from 1"),
    "huge width": (edit(lambda d: d["cameras"][0].update(width=10**12)), r"cameras\[0\].width: must be an integer from 1"),
    "too many pixels": (edit(lambda d: d["cameras"][0].update(width=65536, height=65536)),
                        r"cameras\[0\].width: 65536 x 65536 pixels is more than"),
    "zero direction": (edit(lambda d: d["sources"].__setitem__(0, {"direction": [0, 0, 0]})),
                       r"sources\[0\].direction: must be a non-zero vector"),
    "direction and position": (edit(lambda d: d["sources"][0].update(direction=[0, 0, 1])),
                               r"sources\[0\]: has both 'direction'"),
    "source without position": (edit(lambda d: d["sources"].__setitem__(0, {"radius_mm": 0.5})),
                                r"sources\[0\]: needs 'position_mm'"),
    "no sources": (edit(lambda d: d.update(sources=[])), "sources: must list 1 to 10000 sources, got 0"),
    "no cameras": (edit(lambda d: d.update(cameras=[])), "cameras: must list 1 to 16 cameras, got 0"),
    "unknown projection": (edit(lambda d: d["cameras"][0].update(projection="perspectiv")),
                           r"cameras\[0\].projection: 'perspectiv' is not one of .* \(did you mean 'perspective'\?\)"),
    "camera at its target": (edit(lambda d: d["cameras"][0].update(target_mm=d["cameras"][0]["position_mm"])),
                             r"cameras\[0\].target_mm: position_mm and target_mm coincide"),
    "up along the axis": (edit(lambda d: d["cameras"][0].update(up=[0, 0, 1])),
                          r"cameras\[0\].up: is zero or parallel to the optical axis"),
    "unknown format version": (edit(lambda d: d.update(format="shinysim-rig/3")),
                               "format: 'shinysim-rig/3' is not supported"),
    "version-2 field in a version-1 file": (
        edit(lambda d: (d.update(format="shinysim-rig/1"), d["cameras"][0].update(distortion=[1e-3, 0]))),
        r"cameras\[0\].distortion: distortion needs format 'shinysim-rig/2'"),
    "distortion that folds the image": (edit(lambda d: d["cameras"][0].update(distortion=[-0.5, 0])),
                                        r"cameras\[0\].distortion: .* folds the image"),
    "principal point not two numbers": (edit(lambda d: d["cameras"][0].update(principal_point_px=[1, 2, 3])),
                                        r"cameras\[0\].principal_point_px: must be 2 finite numbers"),
    "other units": (edit(lambda d: d.update(units="inch")), "units: must be 'mm', got 'inch'"),
    # text and syntax
    "truncated JSON": (edit(lambda d: None)[:200], "not valid JSON"),
    "empty file": ("", "not valid JSON"),
    "deeply nested JSON": ("[" * 100_000 + "]" * 100_000, "not valid JSON: nested too deeply"),
}


@pytest.mark.parametrize("text, message", CASES.values(), ids=CASES.keys())
def test_bad_rig_is_named(tmp_path, text, message):
    path = tmp_path / "rig.json"
    path.write_text(text)
    with pytest.raises(RigError, match=f"^{tmp_path}/rig.json: .*{message}"):
        load_rig(path)


def test_not_utf8(tmp_path):
    path = tmp_path / "rig.json"
    path.write_bytes(b'{"name": "caf\xe9"}')
    with pytest.raises(RigError, match=r"rig.json: is not UTF-8 text \(byte 13"):
        load_rig(path)


def test_utf8_bom_is_read(tmp_path):
    path = tmp_path / "rig.json"
    path.write_bytes(b"\xef\xbb\xbf" + json.dumps(DOC).encode())
    assert load_rig(path).n_sources == 21


def test_missing_file(tmp_path):
    with pytest.raises(RigError, match="nope.json: no such file"):
        load_rig(tmp_path / "nope.json")


def test_a_directory(tmp_path):
    with pytest.raises(RigError, match=": not a file"):
        load_rig(tmp_path)


def test_oversized_file_is_refused_before_reading(tmp_path):
    path = tmp_path / "rig.json"
    with open(path, "wb") as f:
        f.truncate(MAX_RIG_BYTES + 1)
    with pytest.raises(RigError, match=f"is {MAX_RIG_BYTES + 1} bytes; a rig file is at most"):
        load_rig(path)


def test_a_misspelt_key_no_longer_moves_the_plane(tmp_path):
    """The old silent failure: ``reference_z`` was ignored and the plane stayed at 0, shifting normals by up to 0.34 deg."""
    d = copy.deepcopy(DOC)
    d["reference_z"] = 0.5
    (tmp_path / "rig.json").write_text(json.dumps(d))
    with pytest.raises(RigError, match="did you mean 'reference_z_mm'"):
        load_rig(tmp_path / "rig.json")
    d["reference_z_mm"] = d.pop("reference_z")
    (tmp_path / "rig.json").write_text(json.dumps(d))
    assert load_rig(tmp_path / "rig.json").reference_z == 0.5
