"""The rig, stack and truth readers under fuzzing: shinysim's own errors only, naming the file.

Every case writes a broken file (bit flips, truncation, splices, random
bytes, random JSON values and keys, deep nesting, EXR headers, channels and
pixels rewritten with OpenEXR itself) and calls ``load_rig``, ``load_stack``
or ``load_truth``. Allowed: a valid ``Rig``/``Stack``/``Truth``, or a
:class:`~shinysim.errors.ShinysimError` whose message starts with the path of
the file at fault. Anything else (another exception, a warning: warnings are
errors in this suite, a case over 5 s) fails. Hypothesis runs derandomized,
so the cases are the same on every run; ``scripts/fuzz_readers.py`` runs
thousands more in child processes, where a crash of the OpenEXR library is
counted instead of ending the run.
"""

from __future__ import annotations

import contextlib
import importlib.util
import json
import math
import signal
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from shinysim.errors import RigError, ShinysimError, StackFormatError
from shinysim.io import Stack, Truth, load_stack, load_truth, save_stack, save_truth
from shinysim.io import load_rig
from shinysim.rig import Rig

# the JSON walking helpers are the fuzz script's (scripts/fuzz_readers.py)
_spec = importlib.util.spec_from_file_location(
    "fuzz_readers", Path(__file__).resolve().parents[1] / "scripts" / "fuzz_readers.py")
FUZZ = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(FUZZ)

H, W, N = 8, 10, 3


def fuzz_settings(n):
    return settings(max_examples=n, deadline=None, derandomize=True, database=None,
                    suppress_health_check=list(HealthCheck))


# -- valid inputs -------------------------------------------------------------------------


def rig_doc():
    """A valid rig: two near sources and a distant one, two cameras of 8 x 10 pixels."""
    cam = {"projection": "orthographic", "width": W, "height": H, "position_mm": [0.0, 0.0, 10.0],
           "target_mm": [0.0, 0.0, 0.0], "up": [0.0, 1.0, 0.0], "field_width_mm": 2.0, "name": "top"}
    side = dict(cam, projection="perspective", position_mm=[30.0, 0.0, 30.0], up=[0.0, 0.0, 1.0], name="side")
    return {"format": "shinysim-rig/1", "name": "fuzz", "units": "mm", "reference_z_mm": 0.0,
            "sources": [{"position_mm": [-10.0, 0.0, 40.0], "radius_mm": 0.5},
                        {"position_mm": [10.0, 0.0, 40.0]}, {"direction": [0.0, 0.6, 0.8]}],
            "cameras": [cam, side], "metadata": {"note": "fuzz", "list": [1, 2.5, None]},
            "provenance": {"seed": 7}}


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    folder = tmp_path_factory.mktemp("fuzz_base")
    rig = Rig.from_dict(rig_doc())
    rng = np.random.default_rng(0)
    frames = rng.uniform(0, 1, (N, H, W)).astype(np.float32)
    save_stack(Stack(frames, rig, 0, {"seed": 7}), folder / "stack.exr")
    save_stack(Stack(frames, rig, 1, {"seed": 7}), folder / "stack32.exr", rig_path=folder / "rig32.json",
               dtype="float32")
    mask = np.zeros((H, W), bool)
    mask[2:6, 3:8] = True
    normals = np.full((H, W, 3), np.nan, np.float32)
    normals[mask] = [0.0, 0.6, 0.8]
    positions = np.full((H, W, 3), np.nan, np.float32)
    positions[mask] = rng.uniform(-1, 1, (int(mask.sum()), 3))
    truth = Truth(normals, positions, mask, np.where(mask, 1, 0), ["background", "pad"], {"scene": "fuzz"})
    save_truth(truth, folder / "truth.exr")
    work = tmp_path_factory.mktemp("fuzz_cases")
    return SimpleNamespace(
        rig=rig, frames=frames, truth=truth, work=work, rig_text=json.dumps(rig_doc(), indent=1),
        stack_rig_json=(folder / "rig.json").read_bytes(),
        bytes={n: (folder / n).read_bytes() for n in ("stack.exr", "stack32.exr", "truth.exr")},
    )


# -- what a reader may do -------------------------------------------------------------------


class ReaderHang(BaseException):
    """A reader ran past its time (a BaseException, so no ``except Exception`` inside a reader hides it)."""


@contextlib.contextmanager
def time_limit(seconds=5):
    if not hasattr(signal, "SIGALRM"):  # pragma: no cover - Windows: inputs are small, no guard
        yield
        return

    def on_alarm(signum, frame):
        raise ReaderHang(f"a reader took more than {seconds} s")

    old = signal.signal(signal.SIGALRM, on_alarm)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def read(call, *paths):
    """The reader's result, or the ShinysimError it raised (checked to name one of ``paths``).

    Any other exception or warning propagates and fails the test.
    """
    try:
        with time_limit():
            obj = call()
    except ShinysimError as exc:
        assert any(str(exc).startswith(f"{p}: ") for p in paths), f"error does not start with the file: {exc}"
        return exc
    if isinstance(obj, Rig):
        assert np.isfinite(obj.source_positions).all() and (obj.source_radii >= 0).all()
        for cam in obj.cameras:
            assert np.isfinite(np.concatenate([cam.forward, cam.right, cam.down])).all() and cam.pixel_pitch > 0
    elif isinstance(obj, Stack):
        assert obj.frames.shape == (obj.rig.n_sources,) + obj.camera.shape
        assert np.isfinite(obj.frames).all() and (obj.frames >= 0).all()
        assert isinstance(obj.provenance, dict)
    elif isinstance(obj, Truth):
        n = obj.normals[obj.mask].astype(float)
        assert np.isfinite(n).all() and np.allclose(np.linalg.norm(n, axis=1), 1, atol=1e-3)
        assert obj.part.min() >= 0 and obj.part.max() < len(obj.part_names)
    else:  # pragma: no cover - a reader returning something else is a bug
        raise AssertionError(f"reader returned {type(obj).__name__}")
    return obj


# -- strategies -----------------------------------------------------------------------------

KEYS = ["format", "name", "units", "reference_z_mm", "sources", "cameras", "metadata", "provenance",
        "position_mm", "radius_mm", "direction", "projection", "width", "height", "target_mm", "up",
        "field_width_mm", "positon_mm", "Sources", ""]
SPECIAL = [0, -1, 1, 2**31, 2**63, 10**30, 10**400, -10**400, 5e-324, 1e-300, 1e308, -1e308, "mm", "in",
           "perspective", "orthographic", "shinysim-rig/1", "shinysim-rig/2", "\x00", "a" * 3000]
scalars = (st.none() | st.booleans() | st.integers() | st.floats(allow_nan=True, allow_infinity=True)
           | st.text(max_size=12) | st.sampled_from(SPECIAL))
vectors = st.lists(st.floats(allow_nan=True, allow_infinity=True) | st.integers() | st.sampled_from(SPECIAL),
                   min_size=2, max_size=4)
json_values = st.recursive(scalars | vectors, lambda inner: st.lists(inner, max_size=4)
                           | st.dictionaries(st.sampled_from(KEYS) | st.text(max_size=6), inner, max_size=4),
                           max_leaves=10)


def nodes(doc):
    """Every path in a JSON document, the root first (the fuzz script's walk)."""
    return (path for path, _ in FUZZ.json_nodes(doc))


put = FUZZ.json_set  # set the value at a path (the whole document for the root)


def mutate_bytes(data, blob, donors):
    """Bit flips, a truncation, a splice or random bytes, drawn from ``data`` (hypothesis)."""
    kind = data.draw(st.sampled_from(["bitflip", "truncate", "splice", "random"]), label="kind")
    hot = min(len(blob), 600)  # the header: where a flip does more than break the compressed pixels
    if kind == "bitflip":
        out = bytearray(blob)
        for _ in range(data.draw(st.integers(1, 16), label="flips")):
            i = data.draw(st.integers(0, (hot if data.draw(st.booleans()) else len(blob)) - 1))
            out[i] ^= 1 << data.draw(st.integers(0, 7))
        return bytes(out)
    if kind == "truncate":
        return blob[:data.draw(st.integers(0, len(blob) - 1), label="cut")]
    if kind == "splice":
        donor = data.draw(st.sampled_from(donors + [blob]))
        a = data.draw(st.integers(0, len(donor) - 1))
        piece = donor[a:a + data.draw(st.sampled_from([1, 4, 16, 64, 512]))]
        c = data.draw(st.integers(0, len(blob)))
        repeat = data.draw(st.integers(1, 20))
        return blob[:c] + piece * repeat + blob[c + data.draw(st.sampled_from([0, len(piece)])):]
    head = blob[:data.draw(st.integers(0, hot))]
    return head + data.draw(st.binary(max_size=300), label="noise")


# -- rig.json ---------------------------------------------------------------------------------


def load_rig_file(base, blob):
    path = base.work / "rig.json"
    path.write_bytes(blob)
    return read(lambda: load_rig(path), path)


@fuzz_settings(100)
@given(data=st.data())
def test_rig_random_values_at_random_places(base, data):
    doc = rig_doc()
    for _ in range(data.draw(st.integers(1, 3))):
        path = data.draw(st.sampled_from(list(nodes(doc))), label="path")
        doc = put(doc, path, data.draw(json_values, label="value"))
    load_rig_file(base, json.dumps(doc, allow_nan=True).encode())


@fuzz_settings(60)
@given(data=st.data())
def test_rig_keys_renamed_deleted_inserted(base, data):
    doc = rig_doc()
    for _ in range(data.draw(st.integers(1, 3))):
        dicts = [p for p in nodes(doc) if isinstance(put_get(doc, p), dict)]
        d = put_get(doc, data.draw(st.sampled_from(dicts)))
        op = data.draw(st.sampled_from(["delete", "rename", "insert"]))
        if op == "insert" or not d:
            d[data.draw(st.sampled_from(KEYS) | st.text(max_size=8))] = data.draw(json_values)
        elif op == "delete":
            del d[data.draw(st.sampled_from(sorted(d)))]
        else:
            k = data.draw(st.sampled_from(sorted(d)))
            d[data.draw(st.sampled_from([k.upper(), k[:-1], k + "s", k.replace("_", "")]) | st.text(max_size=8))] \
                = d.pop(k)
    load_rig_file(base, json.dumps(doc, allow_nan=True).encode())


def put_get(doc, path):
    for p in path:
        doc = doc[p]
    return doc


@fuzz_settings(100)
@given(data=st.data())
def test_rig_bytes_flipped_truncated_spliced(base, data):
    blob = base.rig_text.encode()
    load_rig_file(base, mutate_bytes(data, blob, [base.stack_rig_json]))


TEXT_EDITS = ["1" * 5000, "1" * 4000, "1e999", "-1e999", "NaN", "Infinity", "1" + "0" * 400, "0.1e-400", "00",
              "1.", "0x10", '"\\ud800"', '"\\u0000"', "null", "[]", "{}", "'a'"]


@fuzz_settings(60)
@given(data=st.data())
def test_rig_text_edits_and_encodings(base, data):
    text = base.rig_text
    i = data.draw(st.integers(0, len(text) - 1))
    j = data.draw(st.integers(i, min(len(text), i + 20)))
    text = text[:i] + data.draw(st.sampled_from(TEXT_EDITS) | st.text(max_size=5)) + text[j:]
    encoding = data.draw(st.sampled_from(["utf-8", "utf-8-sig", "utf-16", "latin-1"]))
    load_rig_file(base, text.encode(encoding, errors="surrogatepass" if encoding.startswith("utf") else "replace"))


@fuzz_settings(20)
@given(data=st.data())
def test_rig_nested_deeply(base, data):
    doc = rig_doc()
    limit = sys.getrecursionlimit()
    depth = data.draw(st.sampled_from([10, 500, limit - 60, limit - 20, limit, limit + 20, 100000]))
    depth += data.draw(st.integers(-5, 5))
    doc = put(doc, data.draw(st.sampled_from(list(nodes(doc)))), "__DEEP__")
    deep = data.draw(st.sampled_from(["[" * depth + "]" * depth, '{"a":' * depth + "1" + "}" * depth]))
    load_rig_file(base, json.dumps(doc).replace('"__DEEP__"', deep).encode())


# -- stack.exr and truth.exr ----------------------------------------------------------------


def write_exr(path, header, channels):
    import OpenEXR

    path.unlink(missing_ok=True)
    with OpenEXR.File({"type": OpenEXR.scanlineimage, "compression": OpenEXR.ZIP_COMPRESSION, **header},
                      channels) as f:
        f.write(str(path))


def attr_values():
    """Random EXR attribute values of the types OpenEXR's Python binding writes."""
    texts = (st.builds(lambda v: json.dumps(v, allow_nan=True), json_values)
             | st.sampled_from(["", "{", "null", '"text"', "[1, 2]", "{}", "NaN", "1" * 5000, "[" * 50000,
                                '["background"]', '["a", 1]', "shinysim-stack/1", "shinysim-truth/1"])
             | st.text(max_size=20))
    return (st.integers(-2**31, 2**31 - 1) | st.sampled_from([math.nan, math.inf, -math.inf, 0.0, -1.0, 1e-45, 1.0])
            | st.floats(-1e6, 1e6) | texts | st.lists(texts, max_size=3)
            | st.sampled_from([np.array([1, 2], np.int32), np.array([1.0, 2.0, 3.0], np.float32),
                               np.eye(3, dtype=np.float32)]))


CHANNEL_NAMES = ["S000.R", "S000.G", "S000.B", "S000.Y", "S000.A", "S003", "S0", "s000", "S000.", "S999",
                 "S001.R.G", "normal.x", "N.X", "mask.Y", "part.R", "R", "x" * 100]


def rewrite_exr(data, path, header, channels, attrs):
    """Draw attribute values, windows, channel edits and pixel values; write with OpenEXR."""
    for _ in range(data.draw(st.integers(0, 2), label="attribute edits")):
        key = data.draw(st.sampled_from(attrs))
        if data.draw(st.booleans()):
            header[key] = data.draw(attr_values(), label=key)
        else:
            header.pop(key, None)
    if data.draw(st.booleans()):
        x0, y0 = data.draw(st.tuples(st.integers(-20, 20), st.integers(-20, 20)), label="display origin")
        w, h = data.draw(st.tuples(st.sampled_from([1, W - 1, W, W + 1, 2**13]), st.sampled_from([1, H, H + 1])))
        header["displayWindow"] = ((x0, y0), (x0 + w - 1, y0 + h - 1))
    if data.draw(st.booleans()):
        x0, y0 = data.draw(st.tuples(st.integers(-12, 12), st.integers(-12, 12)), label="data origin")
        header["dataWindow"] = ((x0, y0), (x0 + W - 1, y0 + H - 1))
    for _ in range(data.draw(st.integers(0, 2), label="channel edits")):
        names = sorted(channels)
        op = data.draw(st.sampled_from(["drop", "rename", "extra", "dtype", "layer"]))
        if not names or op == "extra":
            channels[data.draw(st.sampled_from(CHANNEL_NAMES))] = np.ones((H, W), np.float32)
            continue
        k = data.draw(st.sampled_from(names))
        if op == "drop":
            del channels[k]
        elif op == "rename":
            channels[data.draw(st.sampled_from(CHANNEL_NAMES))] = channels.pop(k)
        elif op == "dtype":
            dtype = data.draw(st.sampled_from([np.float16, np.float32, np.uint32]))
            with np.errstate(all="ignore"):
                channels[k] = np.nan_to_num(channels[k]).astype(dtype)
        else:
            v = channels.pop(k)
            for c in data.draw(st.sampled_from([("R", "G", "B"), ("Y", "A"), ("A",), ("R", "G")])):
                channels[f"{k}.{c}"] = v
    for _ in range(data.draw(st.integers(0, 3), label="pixel edits")):
        if not channels:
            break
        k = data.draw(st.sampled_from(sorted(channels)))
        arr = channels[k].copy()
        if arr.dtype.kind == "u":
            value = data.draw(st.sampled_from([0, 3, 2**31, 2**32 - 1]))
        else:
            value = data.draw(st.sampled_from([math.nan, math.inf, -1.0, -1e-8, 0.5, 2.0, 65504.0, 1e38, 2.0**31]))
        idx = (data.draw(st.integers(0, H - 1)), data.draw(st.integers(0, W - 1)))
        with np.errstate(all="ignore"):
            arr[idx if data.draw(st.booleans()) else Ellipsis] = value
        channels[k] = arr
    try:
        write_exr(path, header, channels)
    except Exception:  # OpenEXR refuses to write it (e.g. mixed shapes): nothing to read
        return False
    return True


def stack_case(base, data, blob=None, rig_beside=None):
    path = base.work / "stack.exr"
    rig_path = base.work / "rig.json"
    path.unlink(missing_ok=True)
    if blob is not None:
        path.write_bytes(blob)
    if rig_beside is not None:
        rig_path.write_bytes(rig_beside)
        return read(lambda: load_stack(path), path, rig_path)
    if data.draw(st.booleans(), label="rig.json beside"):
        rig_path.write_bytes(base.stack_rig_json)
        return read(lambda: load_stack(path), path, rig_path)
    return read(lambda: load_stack(path, base.rig), path)


def truth_case(base, data, blob=None):
    path = base.work / "truth.exr"
    if blob is not None:
        path.write_bytes(blob)
    camera = data.draw(st.sampled_from([None, 0, 1]), label="camera")
    return read(lambda: load_truth(path, None if camera is None else base.rig.cameras[camera]), path)


@fuzz_settings(50)
@given(data=st.data())
def test_stack_bytes_flipped_truncated_spliced(base, data):
    name = data.draw(st.sampled_from(["stack.exr", "stack32.exr"]))
    donors = [b for n, b in base.bytes.items() if n != name]
    stack_case(base, data, mutate_bytes(data, base.bytes[name], donors))


@fuzz_settings(50)
@given(data=st.data())
def test_truth_bytes_flipped_truncated_spliced(base, data):
    donors = [base.bytes["stack.exr"], base.bytes["stack32.exr"]]
    truth_case(base, data, mutate_bytes(data, base.bytes["truth.exr"], donors))


@fuzz_settings(60)
@given(data=st.data())
def test_stack_headers_channels_pixels_rewritten(base, data):
    dtype = data.draw(st.sampled_from([np.float16, np.float32]))
    channels = {f"S{k:03d}": base.frames[k].astype(dtype) for k in range(N)}
    header = {"shinysim_format": "shinysim-stack/1", "n_sources": N, "camera_index": 0, "provenance": '{"seed": 7}'}
    attrs = ["shinysim_format", "n_sources", "camera_index", "provenance", "saturation"]
    if rewrite_exr(data, base.work / "stack.exr", header, channels, attrs):
        stack_case(base, data)


@fuzz_settings(60)
@given(data=st.data())
def test_truth_headers_channels_pixels_rewritten(base, data):
    t = base.truth
    channels = {f"normal.{a}": t.normals[..., i] for i, a in enumerate("XYZ")}
    channels.update({f"position.{a}": t.positions[..., i] for i, a in enumerate("XYZ")})
    channels.update(mask=t.mask.astype(np.float32), part=t.part.astype(np.float32))
    header = {"shinysim_format": "shinysim-truth/1", "part_names": json.dumps(t.part_names),
              "metadata": json.dumps(t.metadata)}
    if rewrite_exr(data, base.work / "truth.exr", header, channels, ["shinysim_format", "part_names", "metadata"]):
        truth_case(base, data)


@fuzz_settings(40)
@given(data=st.data())
def test_stack_with_broken_rig_beside(base, data):
    doc = json.loads(base.stack_rig_json)
    path = data.draw(st.sampled_from(list(nodes(doc))), label="path")
    blob = json.dumps(put(doc, path, data.draw(json_values)), allow_nan=True).encode()
    if data.draw(st.booleans()):
        blob = mutate_bytes(data, blob, [base.rig_text.encode()])
    stack_case(base, data, base.bytes["stack.exr"], rig_beside=blob)


# -- what fuzzing found, pinned ---------------------------------------------------------------


@pytest.mark.parametrize("edit, words", [
    (lambda d: d["sources"][0].update(radius_mm=10**400), "sources[0].radius_mm: must be a number within"),
    (lambda d: d.update(reference_z_mm=-10**400), "rig.reference_z_mm: must be a number within the float range"),
    (lambda d: d["cameras"][0].update(up=[0, 10**400, 0]), "cameras[0].up: must be 3 finite numbers"),
    (lambda d: d["cameras"][1].update(target_mm=[0, 0, -1e308], position_mm=[0, 0, 1e308]),
     "cameras[1]: position_mm, target_mm and up are too large or too small"),
    (lambda d: d["cameras"][0].update(up=[0, 1e-300, 0]), "cameras[0]: position_mm, target_mm and up are too large or too small"),
    (lambda d: d["cameras"][1].update(field_width_mm=5e-324), "cameras[1].field_width_mm: 5e-324 mm is too small"),
    (lambda d: d["sources"][2].update(direction=[1e200, 1e200, 0]), "sources[2].direction: must be a non-zero vector of finite length"),
])
def test_rig_numbers_beyond_float_and_deep_values_refused(base, edit, words):
    doc = rig_doc()
    edit(doc)
    text = json.dumps(doc)
    exc = load_rig_file(base, text.encode())
    assert isinstance(exc, RigError)
    assert exc.field is not None
    assert f"rig.json: {words}" in str(exc), str(exc)


def test_rig_nested_to_the_recursion_limit(base):
    # a value nested just shallow enough to parse is still shown in the error without a RecursionError
    limit = sys.getrecursionlimit()
    seen = set()
    for depth in range(limit - 150, limit + 10):
        doc = rig_doc()
        doc["cameras"][0]["name"] = "__DEEP__"
        text = json.dumps(doc).replace('"__DEEP__"', "[" * depth + "]" * depth)
        exc = load_rig_file(base, text.encode())
        assert isinstance(exc, RigError)
        seen.add(next(w for w in ("nested too deeply", "must be a string, got [[[", "must be a string, got a list")
                      if w in str(exc)))
    assert seen == {"nested too deeply", "must be a string, got [[[", "must be a string, got a list"}


def test_rig_huge_integers(base):
    doc = rig_doc()
    doc["cameras"][0]["field_width_mm"] = "__N__"
    text = json.dumps(doc)
    exc = load_rig_file(base, text.replace('"__N__"', "1" * 5000).encode())
    assert isinstance(exc, RigError) and "not valid JSON: a number is too long" in str(exc)
    rig = load_rig_file(base, text.replace('"__N__"', "1" + "0" * 30).encode())  # large, but a float
    assert rig.camera.field_width == 1e30


def test_stack_header_corruptions_named(base):
    path = base.work / "stack.exr"
    blob = base.bytes["stack.exr"]
    # a channel name and an attribute type name that are not UTF-8 (one bit flip each)
    for old, new, field in ((b"S002\0", b"S\xb202\0", "channels"), (b"camera_index\0int\0", b"camera_index\0i\xeet\0",
                                                                      "camera_index")):
        assert blob.count(old) == 1
        path.write_bytes(blob.replace(old, new))
        exc = read(lambda: load_stack(path, base.rig), path)
        assert isinstance(exc, StackFormatError) and exc.field == field, exc
    header = {"shinysim_format": np.array([1.0, 2.0, 3.0], np.float32), "n_sources": N}
    write_exr(path, header, {f"S{k:03d}": base.frames[k] for k in range(N)})
    exc = read(lambda: load_stack(path, base.rig), path)
    assert isinstance(exc, StackFormatError) and exc.field == "shinysim_format"
    write_exr(path, {"provenance": '{"n": ' + "1" * 5000 + "}"}, {f"S{k:03d}": base.frames[k] for k in range(N)})
    exc = read(lambda: load_stack(path, base.rig), path)
    assert isinstance(exc, StackFormatError) and exc.field == "provenance" and "not valid JSON" in str(exc)


def test_stack_colour_layers_read(base):
    path = base.work / "stack.exr"
    channels = {"S000": base.frames[0], "S002.Y": base.frames[2]}
    channels.update({f"S001.{c}": base.frames[1] * s for c, s in zip("RGB", (0.5, 1.0, 0.25))})
    write_exr(path, {}, channels)
    stack = read(lambda: load_stack(path, base.rig), path)
    assert isinstance(stack, Stack), stack
    np.testing.assert_array_equal(stack.frames, base.frames)


def test_truth_part_ids_beyond_int32_refused(base):
    t = base.truth
    path = base.work / "truth.exr"
    channels = {f"normal.{a}": t.normals[..., i] for i, a in enumerate("XYZ")}
    channels.update({f"position.{a}": t.positions[..., i] for i, a in enumerate("XYZ")})
    channels.update(mask=t.mask.astype(np.float32), part=np.full((H, W), 2.0**31, np.float32))
    write_exr(path, {"part_names": json.dumps(["x"] * 3)}, channels)
    exc = read(lambda: load_truth(path), path)
    assert isinstance(exc, StackFormatError) and exc.field == "channel part"


@pytest.mark.slow
def test_fuzz_script_default_run():
    """The many-case run (6000 cases, child processes): no exception but shinysim's, no crash, no hang."""
    import subprocess
    from pathlib import Path

    script = Path(__file__).resolve().parents[1] / "scripts" / "fuzz_readers.py"
    done = subprocess.run([sys.executable, str(script)], check=False, capture_output=True, text=True,
                          timeout=900)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert "6000 cases" in done.stdout
