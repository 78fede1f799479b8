"""Fuzz the rig, stack and truth readers: only shinysim's own errors, no crash, no hang.

What it checks
--------------
``load_rig``, ``load_stack`` and ``load_truth`` are fed thousands of broken
files, made from small valid ones:

* byte level (all three): bit flips (1-16 bits, half of them in the header),
  truncation, splices (a byte range from another valid file, or the file's
  own bytes, copied, inserted or deleted) and random bytes;
* rig JSON: random JSON values (NaN, inf, huge and non-integral numbers,
  strings, lists, objects) put at random places in a valid document; keys
  renamed, deleted and inserted; textual edits (numbers too long to parse,
  invalid tokens, lone surrogates, a byte-order mark, UTF-16, trailing
  garbage); nesting from 10 levels to far past the interpreter's limit;
* stack and truth EXR, written with OpenEXR itself: header attributes of
  random types and values (``n_sources``, ``camera_index``, ``provenance``,
  ``saturation``, ``part_names``, ``metadata``, ``shinysim_format``),
  display and data windows, tiled and multi-part files, compressions;
  channels missing, extra, renamed, split into layers, stored as float16,
  float32 or uint; NaN, inf, negative and huge pixels, non-unit normals,
  bad masks and part ids; for stacks also a broken ``rig.json`` beside a
  valid stack.

Each case must either return a valid object (a ``Rig``, ``Stack`` or
``Truth`` whose arrays pass the invariants the readers promise) or raise a
:class:`shinysim.errors.ShinysimError` whose message starts with the path of
the file at fault. Warnings are errors, as in the test suite, and a worker
may map at most 8 GiB (a MemoryError is another exception). Cases run in
batches in child processes, so a crash of the OpenEXR library (a signal) or
a hang (a case over ``--timeout`` seconds, default 5) is counted against the
case that was running, and the batch goes on in a fresh process; the
slowest cases are printed under the table. Display windows are drawn up to
2**22 pixels and past the readers' limit of 2**26, not at the limit: a
header may claim 2**26 pixels, which a reader allocates and checks (about
2 GB and 1.5-10 s for a truth file), a cost per case by design, not a hang.

It prints a table, reader x mutation kind: cases, accepted, project errors,
project errors that do not name the file (``unnamed``), other exceptions,
crashes and hangs. Offending inputs (the first few) are written again into
a temporary folder it names, each with a ``repro.txt`` holding the call and
what happened. Exit status 1 if any case was unnamed, another exception, a
crash or a hang. A run is a function of ``--seed`` and ``--cases`` alone.

Run it
------
::

    python scripts/fuzz_readers.py                   # 6000 cases, seed 0: 15-30 s on 2 cores
    python scripts/fuzz_readers.py --cases 30000 --seed 7 --jobs 4
    python scripts/fuzz_readers.py --only stack:header --cases 300
"""

from __future__ import annotations

import argparse
import json
import math
import os
import queue
import random
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
import traceback
import warnings
from pathlib import Path

READERS = ("rig", "stack", "truth")
BYTE_KINDS = ("bitflip", "truncate", "splice", "random_bytes")
KINDS = {
    "rig": BYTE_KINDS + ("json_value", "json_keys", "json_text", "deep_nesting"),
    "stack": BYTE_KINDS + ("header", "channels", "pixels", "rig_beside"),
    "truth": BYTE_KINDS + ("header", "channels", "pixels"),
}
OUTCOMES = ("accepted", "project", "unnamed", "other", "crash", "hang")
BAD = ("unnamed", "other", "crash", "hang")
H, W, N_SOURCES = 8, 10, 3
#: Virtual memory a worker may map: a reader must not need more for a file of a few kilobytes.
WORKER_MEMORY = 8 * 2**30


# -- the valid inputs everything starts from ----------------------------------------------


def base_rig_doc():
    """A valid rig document: two near sources and a distant one, two cameras."""
    return {
        "format": "shinysim-rig/1",
        "name": "fuzz",
        "units": "mm",
        "reference_z_mm": 0.0,
        "sources": [
            {"position_mm": [-10.0, 0.0, 40.0], "radius_mm": 0.5},
            {"position_mm": [10.0, 0.0, 40.0], "radius_mm": 0.0},
            {"direction": [0.0, 0.6, 0.8]},
        ],
        "cameras": [
            {"name": "top", "projection": "orthographic", "width": W, "height": H, "position_mm": [0.0, 0.0, 10.0],
             "target_mm": [0.0, 0.0, 0.0], "up": [0.0, 1.0, 0.0], "field_width_mm": 2.0},
            {"name": "side", "projection": "perspective", "width": W, "height": H,
             "position_mm": [30.0, 0.0, 30.0], "target_mm": [0.0, 0.0, 0.0], "up": [0.0, 0.0, 1.0],
             "field_width_mm": 3.0},
        ],
        "metadata": {"note": "fuzz base", "list": [1, 2.5, None, True]},
        "provenance": {"seed": 7, "renderer": "none"},
    }


class Base:
    """Valid files and arrays in ``folder`` (built identically by every process)."""

    def __init__(self, folder):
        import numpy as np

        from shinysim.io import Stack, Truth, save_stack, save_truth
        from shinysim.rig import Rig, shiny_1988

        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.rig_doc = base_rig_doc()
        self.rig = Rig.from_dict(base_rig_doc())
        self.rig_text = json.dumps(self.rig_doc, indent=2) + "\n"
        self.shiny_text = json.dumps(shiny_1988(resolution=16).to_dict()) + "\n"
        rng = np.random.default_rng(0)
        self.frames = rng.uniform(0, 1, (N_SOURCES, H, W)).astype(np.float32)
        self.provenance = {"seed": 7}
        stack = Stack(self.frames, self.rig, 0, self.provenance)
        save_stack(stack, self.folder / "stack.exr", overwrite=True)
        save_stack(stack, self.folder / "stack32.exr", rig_path=self.folder / "rig32.json", dtype="float32",
                   overwrite=True)
        mask = np.zeros((H, W), bool)
        mask[2:6, 3:8] = True
        normals = np.full((H, W, 3), np.nan, np.float32)
        v = rng.normal(size=(int(mask.sum()), 3))
        v[:, 2] = np.abs(v[:, 2]) + 0.1
        normals[mask] = v / np.linalg.norm(v, axis=1, keepdims=True)
        positions = np.full((H, W, 3), np.nan, np.float32)
        positions[mask] = rng.uniform(-1, 1, (int(mask.sum()), 3))
        part = np.where(mask, 1 + (np.arange(W) >= 5)[None, :], 0).astype(np.int32)
        self.truth = Truth(normals, positions, mask, part, ["background", "pad", "lead"], {"scene": "fuzz"})
        save_truth(self.truth, self.folder / "truth.exr", overwrite=True)
        self.bytes = {name: (self.folder / name).read_bytes() for name in ("stack.exr", "stack32.exr", "truth.exr")}
        self.bytes["rig.json"] = self.rig_text.encode()
        self.bytes["shiny.json"] = self.shiny_text.encode()
        self.stack_rig_json = (self.folder / "rig.json").read_bytes()

    def truth_channels(self):
        t = self.truth
        out = {f"normal.{a}": t.normals[..., i].copy() for i, a in enumerate("XYZ")}
        out.update({f"position.{a}": t.positions[..., i].copy() for i, a in enumerate("XYZ")})
        out["mask"] = t.mask.astype("float32")
        out["part"] = t.part.astype("float32")
        return out


def exr_header_end(data):
    """Byte offset just past a single-part EXR's header and its chunk offset table (a guess for broken files)."""
    pos = 8
    try:
        while data[pos] != 0:
            name_end = data.index(b"\0", pos)
            type_end = data.index(b"\0", name_end + 1)
            size = int.from_bytes(data[type_end + 1:type_end + 5], "little")
            pos = type_end + 5 + size
        return min(len(data), pos + 1 + 8 * H)
    except (IndexError, ValueError):
        return min(len(data), 400)


# -- byte-level mutations ---------------------------------------------------------------


def bitflip(rng, data, hot):
    data = bytearray(data)
    if not data:
        return bytes(data)
    for _ in range(rng.randint(1, 16)):
        end = hot if rng.random() < 0.5 else len(data)
        i = rng.randrange(max(1, end))
        data[i] ^= 1 << rng.randrange(8)
    return bytes(data)


def truncate(rng, data, hot):
    end = hot if rng.random() < 0.5 else len(data)
    return data[:rng.randrange(max(1, end))]


def splice(rng, data, donors):
    donor = rng.choice(donors + [data])
    a = rng.randrange(len(donor))
    piece = donor[a:a + rng.choice([1, 2, 4, 8, 16, 64, 256, 4096])]
    c = rng.randrange(len(data) + 1)
    op = rng.choice(("replace", "insert", "delete", "repeat"))
    if op == "replace":
        return data[:c] + piece + data[c + len(piece):]
    if op == "insert":
        return data[:c] + piece + data[c:]
    if op == "delete":
        return data[:c] + data[c + rng.randint(1, 64):]
    return data[:c] + piece * rng.randint(2, 50) + data[c:]


def random_bytes(rng, data, hot):
    n = rng.choice([0, 1, 3, 8, 64, 512, 4096])
    junk = bytes(rng.getrandbits(8) for _ in range(n))
    style = rng.random()
    if style < 0.35:
        return junk
    if style < 0.7:
        return data[:rng.randrange(1, max(2, hot))] + junk  # a valid start, then noise
    if data[:4] == b"v/1\x01":
        return b"v/1\x01" + bytes([2, rng.choice([0, 2, 4, 8, 16, 255]), 0, 0]) + junk
    return rng.choice([b"{", b"[", b'{"sources": ', b"\xef\xbb\xbf{"]) + junk


def mutate_bytes(rng, kind, data, donors, hot):
    if kind == "bitflip":
        return bitflip(rng, data, hot)
    if kind == "truncate":
        return truncate(rng, data, hot)
    if kind == "splice":
        return splice(rng, data, donors)
    return random_bytes(rng, data, hot)


# -- random JSON --------------------------------------------------------------------------

SCALARS = [None, True, False, 0, 1, -1, 2, 3, 16, 65536, 65537, 2**26, 2**31, 2**63, 10**30, 10**400, -10**400,
           0.0, -0.0, 0.5, 1.5, 2.0, -2.5, 5e-324, 1e-300, 1e300, 1e308, -1e308, math.nan, math.inf, -math.inf,
           "", "mm", "in", "perspective", "orthographic", "Perspective", "shinysim-rig/1", "shinysim-rig/2",
           "position_mm", "\u00e9\u6f22\U0001f600", "\x00", "a" * 5000]
KEYS = ["format", "name", "units", "reference_z_mm", "sources", "cameras", "metadata", "provenance",
        "position_mm", "radius_mm", "direction", "projection", "width", "height", "target_mm", "up",
        "field_width_mm", "positon_mm", "Sources", "camera", "", "x", "\u00e9"]


def rand_scalar(rng):
    r = rng.random()
    if r < 0.7:
        return rng.choice(SCALARS)
    if r < 0.8:
        return rng.uniform(-1e3, 1e3)
    if r < 0.9:
        return rng.randint(-2**70, 2**70)
    return "".join(chr(rng.choice([rng.randrange(32, 127), rng.randrange(0x80, 0xD7FF)])) for _ in range(rng.randrange(12)))


def rand_json(rng, depth=0):
    r = rng.random()
    if depth > 3 or r < 0.55:
        return rand_scalar(rng)
    if r < 0.7:  # a vector: the commonest shape in a rig
        return [rand_scalar(rng) if rng.random() < 0.3 else rng.uniform(-50, 50) for _ in range(rng.choice([0, 2, 3, 3, 4]))]
    if r < 0.85:
        return [rand_json(rng, depth + 1) for _ in range(rng.randrange(5))]
    return {rng.choice(KEYS): rand_json(rng, depth + 1) for _ in range(rng.randrange(5))}


def json_nodes(doc, path=()):
    """Every (path, value) in a JSON document, the root first."""
    yield path, doc
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from json_nodes(v, path + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from json_nodes(v, path + (i,))


def json_set(doc, path, value):
    if not path:
        return value
    node = doc
    for p in path[:-1]:
        node = node[p]
    node[path[-1]] = value
    return doc


def mutate_json_value(rng, doc):
    for _ in range(rng.randint(1, 3)):
        nodes = list(json_nodes(doc))
        path, _ = rng.choice(nodes)
        doc = json_set(doc, path, rand_json(rng))
    return doc


def mutate_json_keys(rng, doc):
    for _ in range(rng.randint(1, 3)):
        dicts = [v for _, v in json_nodes(doc) if isinstance(v, dict)]
        if not dicts:
            return doc
        d = rng.choice(dicts)
        op = rng.choice(("delete", "rename", "insert", "listify", "clear"))
        keys = list(d)
        if op == "delete" and keys:
            del d[rng.choice(keys)]
        elif op == "rename" and keys:
            k = rng.choice(keys)
            new = rng.choice([k.upper(), k[:-1], k + "s", k[1:] + k[:1], rng.choice(KEYS), k + "_mm", k.replace("_", "")])
            d[new] = d.pop(k)
        elif op == "insert":
            d[rng.choice(KEYS + ["extra"])] = rand_json(rng)
        elif op == "listify":
            path = next(p for p, v in json_nodes(doc) if v is d)
            doc = json_set(doc, path, list(d.values()))
        else:
            d.clear()
    return doc


NUMBER = re.compile(r"-?\d+(\.\d+)?([eE][-+]?\d+)?")
STRING = re.compile(r'"(?:[^"\\]|\\.)*"')


def mutate_json_text(rng, text):
    op = rng.choice(("number", "number", "string", "bom", "utf16", "trailing", "duplicate", "token", "latin1"))
    if op == "number":
        spots = list(NUMBER.finditer(text))
        m = rng.choice(spots)
        new = rng.choice(["1" * 5000, "9" * 4301, "1" * 4000, "1e999", "-1e999", "NaN", "Infinity", "-Infinity",
                          "-0", "1E+2", "0.1e-400", "00", "1.", ".5", "0x10", "+1", "1e", "--1", "4e-324",
                          "1" + "0" * 400 + ".0", "65536.0", "3.0", "2.5"])
        return (text[:m.start()] + new + text[m.end():]).encode()
    if op == "string":
        m = rng.choice(list(STRING.finditer(text)))
        new = rng.choice(['"\\ud800"', '"\\udfff\\ud800"', '"\\u0000"', '"' + "x" * 100000 + '"', '"\\x41"',
                          '"\u00e9\U0001f600"', '"a\nb"', '"\\"', 'null', '"\\uZZZZ"'])
        return (text[:m.start()] + new + text[m.end():]).encode()
    if op == "bom":
        return b"\xef\xbb\xbf" + text.encode()
    if op == "utf16":
        return text.encode(rng.choice(["utf-16", "utf-16-le", "utf-32"]))
    if op == "trailing":
        return (text + rng.choice(["x", "{}", "\0", "]", ",", "// comment"])).encode()
    if op == "duplicate":
        i = text.index("{") + 1
        return (text[:i] + rng.choice(['"sources": 1, ', '"cameras": [], ', '"units": "in", ', '"format": null, '])
                + text[i:]).encode()
    if op == "latin1":
        m = rng.choice(list(STRING.finditer(text)))
        return text[:m.start()].encode() + b'"\xe9\xff"' + text[m.end():].encode()
    c = rng.randrange(len(text))
    return (text[:c] + rng.choice(["'", "True", "None", "undefined", "/*", "{", "}", ",,", ":"]) + text[c:]).encode()


def deep_text(rng, depth):
    style = rng.choice(("list", "dict", "mixed"))
    if style == "list":
        return "[" * depth + "]" * depth
    if style == "dict":
        return '{"a":' * depth + "1" + "}" * depth
    return '[{"x":' * (depth // 2) + "0" + "}]" * (depth // 2)


def mutate_deep(rng, doc):
    limit = sys.getrecursionlimit()
    depth = rng.choice([10, 100, 500, limit - 100, limit - 30, limit - 10, limit, limit + 10, 20000, 200000])
    depth = max(1, depth + rng.randint(-5, 5))
    nodes = [p for p, _ in json_nodes(doc)]
    path = rng.choice(nodes)
    doc = json_set(doc, path, "__DEEP__")
    text = json.dumps(doc, allow_nan=True)
    return text.replace('"__DEEP__"', deep_text(rng, depth)).encode()


def make_rig_bytes(rng, kind, base):
    """Bytes of a broken rig.json, by mutation ``kind``."""
    doc = json.loads(base.shiny_text if rng.random() < 0.2 else base.rig_text)
    text = json.dumps(doc, indent=rng.choice([None, 2]))
    data = text.encode()
    if kind in BYTE_KINDS:
        return mutate_bytes(rng, kind, data, [base.bytes["rig.json"], base.bytes["shiny.json"]], len(data))
    if kind == "json_value":
        return json.dumps(mutate_json_value(rng, doc), allow_nan=True).encode()
    if kind == "json_keys":
        return json.dumps(mutate_json_keys(rng, doc), allow_nan=True).encode()
    if kind == "json_text":
        return mutate_json_text(rng, text)
    return mutate_deep(rng, doc)


# -- EXR mutations (written with OpenEXR itself) -------------------------------------------


def rand_attr(rng):
    """A random EXR attribute value of any type OpenEXR's Python binding writes."""
    import numpy as np

    r = rng.random()
    if r < 0.25:
        return rng.choice([-2**31, -1, 0, 1, 2, 3, 4, 7, 255, 2**31 - 1])
    if r < 0.45:
        return rng.choice([math.nan, math.inf, -math.inf, 0.0, -0.0, -1.0, 1e-45, 1e-300, 0.5, 1.0, 65504.0,
                           1e300, rng.uniform(-10, 10)])
    if r < 0.8:
        return rand_attr_text(rng)
    if r < 0.85:
        return [rand_attr_text(rng) for _ in range(rng.randrange(4))]
    return rng.choice([np.array([1, 2], np.int32), np.array([1.0, 2.0, 3.0], np.float32), np.eye(3, dtype=np.float32),
                       np.array([1.5, 2.0], np.float64), np.zeros((4, 4), np.float32)])


def rand_attr_text(rng):
    return rng.choice([
        lambda: json.dumps(rand_json(rng), allow_nan=True),
        lambda: json.dumps(rand_json(rng), allow_nan=True),
        lambda: rng.choice(["", "abc", "{", "{'a': 1}", "null", "true", '"text"', "[1, 2]", "{}", "[]", "NaN",
                            '{"a": NaN}', "1" * 5000, "1" * 4000, "[" * 100000 + "]" * 100000,
                            "[" * (sys.getrecursionlimit() - 20) + "]" * (sys.getrecursionlimit() - 20),
                            "x" * 100000, "shinysim-stack/1", "shinysim-truth/1", "shinysim-stack/2",
                            '["background"]', '["a", 1]', '["background", "object", "more", "four", "five"]',
                            '{"seed": 7}', "\u00e9\U0001f600"]),
    ])()


def rand_channel_name(rng, names):
    base = rng.choice(names)
    return rng.choice([
        base + ".R", base + ".Y", base + ".A", base + ".", base.lower(), base.upper(), base[:-1], base + "0",
        "S003", "S999", "S0", "S00", "S0000", "S\u0663", "S-01", "S000.R.G", "normal.x", "N.X", "normal",
        "position.W", "mask.Y", "part.R", "R", "Y", "A", "x" * 200, base + ".R.G", ".R",
    ])


def exr_write(path, header, channels, parts=None):
    import OpenEXR

    if Path(path).exists():
        Path(path).unlink()
    if parts is not None:
        objs = [OpenEXR.Part(h, c, f"part{i}") for i, (h, c) in enumerate(parts)]
        with OpenEXR.File(objs) as f:
            f.write(str(path))
        return
    with OpenEXR.File(header, channels) as f:
        f.write(str(path))


def header_op(rng, header, channels, keys):
    """One change to an EXR header (in place); may return replacement parts for a multi-part file."""
    import OpenEXR

    op = rng.choice(("set", "set", "set", "delete", "display", "data", "tiled", "compression", "parts"))
    if op == "set":
        header[rng.choice(keys)] = rand_attr(rng)
    elif op == "delete":
        header.pop(rng.choice(keys), None)
    elif op == "display":
        x0, y0 = rng.choice([(0, 0), (-3, -2), (2, 1), (5, 4), (-2**20, 0), (2**30, 2**30), (10, 8)])
        # up to 2**22 pixels, and past the readers' 2**26 limit (refused before anything is allocated);
        # not at the limit itself, where every case costs gigabytes and seconds (see the docstring)
        w, h = rng.choice([(W, H), (W + 1, H), (W, H - 1), (1, 1), (2**11, 2**11), (2**13, 2**13 + 1),
                           (2**16, 2**16), (3, 100), (2**31 - 1, 1)])
        header["displayWindow"] = ((x0, y0), (x0 + w - 1, y0 + h - 1))
    elif op == "data":
        x0, y0 = rng.choice([(0, 0), (1, 0), (0, 1), (-4, -3), (W, H), (W - 1, H - 1), (100, 100), (-W, -H)])
        header["dataWindow"] = ((x0, y0), (x0 + W - 1, y0 + H - 1))
    elif op == "tiled":
        td = OpenEXR.TileDescription()
        td.xSize, td.ySize = rng.choice([1, 2, 3, 4, 16, 64]), rng.choice([1, 2, 3, 4, 16, 64])
        if rng.random() < 0.3:
            td.mode = rng.choice([OpenEXR.MIPMAP_LEVELS, OpenEXR.RIPMAP_LEVELS])
        header["type"] = OpenEXR.tiledimage
        header["tiles"] = td
    elif op == "compression":
        header["compression"] = rng.choice([OpenEXR.NO_COMPRESSION, OpenEXR.RLE_COMPRESSION, OpenEXR.ZIPS_COMPRESSION,
                                            OpenEXR.PIZ_COMPRESSION, OpenEXR.PXR24_COMPRESSION, OpenEXR.B44_COMPRESSION,
                                            OpenEXR.B44A_COMPRESSION, OpenEXR.DWAA_COMPRESSION, OpenEXR.ZSTD_COMPRESSION])
    else:
        return [(dict(header), dict(channels)), (dict(header), dict(channels))]
    return None


def channel_op(rng, channels, names):
    import numpy as np

    op = rng.choice(("drop", "rename", "extra", "dtype", "dtype_all", "layer"))
    keys = list(channels)
    if not keys:
        op = "extra"
    if op == "drop":
        del channels[rng.choice(keys)]
    elif op == "rename":
        k = rng.choice(keys)
        channels[rand_channel_name(rng, names)] = channels.pop(k)
    elif op == "extra":
        channels[rand_channel_name(rng, names)] = np.ones((H, W), rng.choice([np.float16, np.float32, np.uint32]))
    elif op == "dtype":
        k = rng.choice(keys)
        with np.errstate(all="ignore"):
            channels[k] = np.nan_to_num(channels[k]).astype(rng.choice([np.float16, np.float32, np.uint32]))
    elif op == "dtype_all":
        dt = rng.choice([np.float16, np.float32, np.uint32])
        with np.errstate(all="ignore"):
            for k in keys:
                channels[k] = (np.nan_to_num(channels[k]) if dt == np.uint32 else channels[k]).astype(dt)
    else:
        k = rng.choice(keys)
        v = channels.pop(k)
        for c in rng.choice([("R", "G", "B"), ("R", "G", "B", "A"), ("Y",), ("Y", "A"), ("A",), ("R", "G"), ("G",),
                             ("X", "Y", "Z"), ("R", "G", "B", "Y")]):
            channels[f"{k}.{c}"] = v * rng.choice([1, 1, 0.5, 2])


def pixel_op(rng, channels, truth):
    import numpy as np

    keys = list(channels)
    if not keys:
        return
    k = rng.choice(keys)
    if truth and rng.random() < 0.6:
        k = rng.choice([c for c in keys if c.split(".")[0] in ("normal", "mask", "part", "position")] or keys)
    arr = channels[k].copy()
    value = rng.choice([math.nan, math.inf, -math.inf, -1.0, -1e-8, 0.0, 0.5, 0.50001, 2.0, 3.0, 65504.0, 1e38,
                        2.0**24 + 1, 2.0**31, 2.0**31 - 128, 2.0**32, -2.0**31, 1.0001, 0.999, 1e-40])
    if arr.dtype.kind == "u":
        value = rng.choice([0, 1, 2, 3, 2**32 - 1, 2**31])
    with np.errstate(all="ignore"):
        if rng.random() < 0.2:
            arr[...] = value
        else:
            for _ in range(rng.randint(1, 5)):
                arr[rng.randrange(H), rng.randrange(W)] = value
    channels[k] = arr


def make_exr(rng, reader, kind, base, path):
    """Write a broken stack or truth EXR at ``path`` by mutation ``kind``."""
    import numpy as np
    import OpenEXR

    if kind in BYTE_KINDS:
        main = "stack.exr" if reader == "stack" else "truth.exr"
        if reader == "stack" and rng.random() < 0.3:
            main = "stack32.exr"
        data = base.bytes[main]
        donors = [base.bytes[n] for n in ("stack.exr", "stack32.exr", "truth.exr") if n != main]
        Path(path).write_bytes(mutate_bytes(rng, kind, data, donors, exr_header_end(data)))
        return
    for _attempt in range(20):
        if reader == "stack":
            dt = rng.choice([np.float16, np.float16, np.float32])
            channels = {f"S{k:03d}": base.frames[k].astype(dt) for k in range(N_SOURCES)}
            header = {"shinysim_format": "shinysim-stack/1", "n_sources": N_SOURCES, "camera_index": 0,
                      "provenance": json.dumps(base.provenance)}
            if rng.random() < 0.3:
                header["saturation"] = 1.0
            keys = ["shinysim_format", "n_sources", "camera_index", "provenance", "saturation"]
            names = list(channels)
        else:
            channels = base.truth_channels()
            header = {"shinysim_format": "shinysim-truth/1", "part_names": json.dumps(base.truth.part_names),
                      "metadata": json.dumps(base.truth.metadata)}
            keys = ["shinysim_format", "part_names", "metadata"]
            names = ["normal", "position", "mask", "part"]
        header.update({"type": OpenEXR.scanlineimage, "compression": OpenEXR.ZIP_COMPRESSION})
        parts = None
        for _ in range(rng.randint(1, 3)):
            if kind == "header":
                parts = header_op(rng, header, channels, keys) or parts
            elif kind == "channels":
                channel_op(rng, channels, names)
            else:
                pixel_op(rng, channels, reader == "truth")
        try:
            exr_write(path, header, channels, parts)
            return
        except Exception:  # OpenEXR refused to write it: draw another
            continue
    Path(path).write_bytes(base.bytes["stack.exr" if reader == "stack" else "truth.exr"])


def make_case(reader, kind, seed, index, base, folder):
    """Write case ``index`` into ``folder``; returns the call: (function, args, files that may be named)."""
    rng = random.Random(f"{seed}:{reader}:{kind}:{index}")
    folder = Path(folder)
    if reader == "rig":
        path = folder / "rig.json"
        path.write_bytes(make_rig_bytes(rng, kind, base))
        return ("load_rig", [str(path)], [str(path)])
    if reader == "stack":
        path = folder / "stack.exr"
        rig_path = folder / "rig.json"
        if kind == "rig_beside":
            path.write_bytes(base.bytes["stack.exr"])
            rig_path.write_bytes(make_rig_bytes(rng, rng.choice(KINDS["rig"][:-1] + ("json_value",)), base))
            return ("load_stack", [str(path), None], [str(path), str(rig_path)])
        make_exr(rng, reader, kind, base, path)
        mode = rng.choice(("object", "object", "beside", "path"))
        if mode == "object":
            return ("load_stack", [str(path), "<base rig>"], [str(path)])
        rig_path.write_text(base.rig_text if rng.random() < 0.5 else json.dumps(
            json.loads(base.stack_rig_json) | {"provenance": rand_json(rng) if rng.random() < 0.3 else {"seed": 7}},
            allow_nan=True))
        return ("load_stack", [str(path), None if mode == "beside" else str(rig_path)], [str(path), str(rig_path)])
    path = folder / "truth.exr"
    make_exr(rng, reader, kind, base, path)
    cam = rng.choice(("<base camera 0>", "<base camera 1>", None))
    return ("load_truth", [str(path), cam], [str(path)])


# -- running one case ---------------------------------------------------------------------


def check_accepted(obj, func):
    """Why an object a reader returned breaks the readers' promises, or None."""
    import numpy as np

    from shinysim.io import Stack, Truth
    from shinysim.rig import Rig

    if func == "load_rig":
        if not isinstance(obj, Rig):
            return f"returned {type(obj).__name__}"
        problems = []
        if not (np.isfinite(obj.source_positions).all() and np.isfinite(obj.source_radii).all()
                and (obj.source_radii >= 0).all()):
            problems.append("non-finite sources")
        d = obj.source_positions[obj.source_distant]
        if len(d) and not np.allclose(np.linalg.norm(d, axis=1), 1):
            problems.append("distant directions not unit")
        for cam in obj.cameras:
            frame = np.concatenate([cam.forward, cam.right, cam.down])
            if not np.isfinite(frame).all():
                problems.append(f"camera {cam.name!r} has no finite frame")
            if not (math.isfinite(cam.pixel_pitch) and cam.pixel_pitch > 0):
                problems.append(f"camera {cam.name!r} has pixel pitch {cam.pixel_pitch!r}")
        return "; ".join(problems) or None
    if func == "load_stack":
        if not isinstance(obj, Stack):
            return f"returned {type(obj).__name__}"
        f = obj.frames
        if f.dtype != np.float32 or f.shape != (obj.rig.n_sources,) + obj.camera.shape:
            return f"frames {f.dtype} {f.shape}"
        if not (np.isfinite(f).all() and (f >= 0).all()):
            return "non-finite or negative pixels"
        if not isinstance(obj.provenance, dict):
            return "provenance is not a dict"
        if obj.saturation is not None and not (math.isfinite(obj.saturation) and obj.saturation > 0):
            return f"saturation {obj.saturation!r}"
        return None
    if not isinstance(obj, Truth):
        return f"returned {type(obj).__name__}"
    m = obj.mask
    if obj.normals.shape != m.shape + (3,) or obj.positions.shape != m.shape + (3,) or obj.part.shape != m.shape:
        return "shapes disagree"
    n = obj.normals[m].astype(float)
    if not (np.isfinite(n).all() and np.allclose(np.linalg.norm(n, axis=1), 1, atol=1e-3)):
        return "normals in the mask are not finite unit vectors"
    if not np.isfinite(obj.positions[m]).all():
        return "positions in the mask are not finite"
    if obj.part.size and (obj.part.min() < 0 or obj.part.max() >= len(obj.part_names)):
        return f"part ids {obj.part.min()}..{obj.part.max()} for {len(obj.part_names)} names"
    if not (isinstance(obj.metadata, dict) and all(isinstance(s, str) for s in obj.part_names)):
        return "metadata or part_names of the wrong type"
    return None


def call_reader(func, args, base):
    from shinysim.io import load_stack, load_truth
    from shinysim.io import load_rig

    if func == "load_rig":
        return load_rig(args[0])
    if func == "load_stack":
        return load_stack(args[0], base.rig if args[1] == "<base rig>" else args[1])
    cam = None if args[1] is None else base.rig.cameras[int(args[1][-2])]
    return load_truth(args[0], cam)


def run_case(func, args, files, base):
    """(outcome, detail) of one call."""
    from shinysim.errors import ShinysimError

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            obj = call_reader(func, args, base)
            problem = check_accepted(obj, func)
    except ShinysimError as exc:
        text = str(exc)
        if not any(text.startswith(f"{f}: ") for f in files):
            return "unnamed", text[:300]
        return "project", type(exc).__name__
    except BaseException as exc:  # anything else is a finding, even a KeyboardInterrupt-like escape
        if isinstance(exc, KeyboardInterrupt):
            raise
        tb = traceback.extract_tb(exc.__traceback__)
        where = next((f"{Path(fr.filename).name}:{fr.lineno} {fr.name}" for fr in reversed(tb)
                      if "shinysim" in fr.filename), "?")
        return "other", f"{type(exc).__name__}: {str(exc)[:200]} [at {where}]"
    if problem:
        return "other", f"accepted but invalid: {problem}"
    return "accepted", ""


def worker(seed):
    """Run the cases listed on stdin, one JSON line out before and after each."""
    import resource

    try:
        resource.setrlimit(resource.RLIMIT_AS, (WORKER_MEMORY, WORKER_MEMORY))
    except (ValueError, OSError):
        pass
    job = json.loads(sys.stdin.read())
    # results go out on the original stdout; anything a library prints goes to stderr
    proto = os.fdopen(os.dup(1), "w")
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    with tempfile.TemporaryDirectory(prefix="fuzz-worker-") as tmp:
        base = Base(Path(tmp) / "base")
        case_dir = Path(tmp) / "case"
        print(json.dumps({"ready": True}), file=proto, flush=True)
        for reader, kind, index in job["cases"]:
            shutil.rmtree(case_dir, ignore_errors=True)
            case_dir.mkdir()
            print(json.dumps({"start": [reader, kind, index]}), file=proto, flush=True)
            t0 = time.monotonic()
            func, args, files = make_case(reader, kind, seed, index, base, case_dir)
            outcome, detail = run_case(func, args, files, base)
            print(json.dumps({"done": [reader, kind, index], "outcome": outcome, "detail": detail,
                              "seconds": round(time.monotonic() - t0, 3)}), file=proto, flush=True)


# -- the parent: batches, table, offenders -------------------------------------------------


def plan(n_cases, only):
    """The (reader, kind, index) of every case: n_cases split evenly over readers, then kinds."""
    pairs = [(r, k) for r in READERS for k in KINDS[r] if not only or f"{r}:{k}" in only or r in only]
    readers = sorted({r for r, _ in pairs}, key=READERS.index)
    cases = []
    for r in readers:
        kinds = [k for rr, k in pairs if rr == r]
        share = n_cases // len(readers) + (1 if readers.index(r) < n_cases % len(readers) else 0)
        cases += [(r, kinds[i % len(kinds)], i) for i in range(share)]
    return cases


def _pump(stream, lines):
    """Every line of ``stream`` into the queue ``lines``, then None."""
    for line in stream:
        lines.put(line)
    lines.put(None)


def run_batch(cases, seed, timeout, results, seconds, lock):
    """Run ``cases`` in child processes; a crash or hang is charged to its case and the rest go on."""
    pending = list(cases)
    while pending:
        with tempfile.TemporaryFile("w+") as err:
            proc = subprocess.Popen([sys.executable, __file__, "--worker", "--seed", str(seed)], stdin=subprocess.PIPE,
                                    stdout=subprocess.PIPE, stderr=err, text=True, cwd=Path(__file__).resolve().parents[1])
            proc.stdin.write(json.dumps({"cases": pending}))
            proc.stdin.close()
            lines = queue.Queue()
            threading.Thread(target=_pump, args=(proc.stdout, lines), daemon=True).start()
            current, last, ready, done_here = None, None, False, set()
            while True:
                try:
                    line = lines.get(timeout=timeout if ready else 120)
                except queue.Empty:
                    proc.kill()
                    proc.wait()
                    culprit = current or last  # between cases: the case before is still running something
                    if culprit is None:
                        raise RuntimeError("a fuzz worker did not start") from None
                    with lock:
                        results[culprit] = ("hang", f"no result within {timeout} s"
                                            + ("" if current else " (after the case returned)"))
                    done_here.add(culprit)
                    break
                if line is None:
                    rc = proc.wait()
                    if current is None and len(done_here) == len(pending) and rc == 0:
                        break
                    culprit = current or last  # a crash between cases: in what the case before left behind
                    err.seek(0)
                    tail = err.read()[-400:].strip().replace("\n", " | ")
                    if culprit is None:
                        raise RuntimeError(f"a fuzz worker failed before any case (exit status {rc}): {tail}")
                    with lock:
                        results[culprit] = ("crash", f"exit status {rc}" + ("" if current else
                                            " (after the case returned)") + f": {tail}")
                    done_here.add(culprit)
                    break
                msg = json.loads(line)
                if "ready" in msg:
                    ready = True
                elif "start" in msg:
                    current = tuple(msg["start"])
                else:
                    key = tuple(msg["done"])
                    with lock:
                        results[key] = (msg["outcome"], msg["detail"])
                        seconds[key] = msg["seconds"]
                    done_here.add(key)
                    current, last = None, key
            pending = [c for c in pending if c not in done_here]


def save_offenders(offenders, seed, base_dir):
    """Write each offending case's input again, with a repro.txt; returns the folder."""
    out = Path(tempfile.mkdtemp(prefix="fuzz-readers-offenders-"))
    base = Base(base_dir)
    for (reader, kind, index), (outcome, detail) in offenders:
        folder = out / f"{reader}-{kind}-{index}"
        folder.mkdir()
        func, args, _files = make_case(reader, kind, seed, index, base, folder)
        shown = ", ".join(repr(a) for a in args)
        (folder / "repro.txt").write_text(
            f"{func}({shown})\n# <base rig> / <base camera k>: Base() in scripts/fuzz_readers.py\n"
            f"# seed {seed}, case {reader}:{kind}:{index}\n# {outcome}: {detail}\n")
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", type=int, default=6000, help="cases in all, split evenly over readers (default 6000)")
    ap.add_argument("--seed", type=int, default=0, help="seed of every random choice (default 0)")
    ap.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1), help="worker processes at once")
    ap.add_argument("--batch", type=int, default=250, help="cases per worker process (default 250)")
    ap.add_argument("--timeout", type=float, default=5.0, help="seconds a case may take before it is a hang")
    ap.add_argument("--only", nargs="*", default=[], help="readers or reader:kind pairs to run (default all)")
    ap.add_argument("--show", type=int, default=8, help="offending inputs to save and print (default 8)")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        worker(args.seed)
        return 0
    t0 = time.monotonic()
    cases = plan(args.cases, set(args.only))
    batches = [cases[i::max(1, len(cases) // args.batch)] for i in range(max(1, len(cases) // args.batch))]
    results, seconds, lock = {}, {}, threading.Lock()
    todo = queue.Queue()
    for b in batches:
        todo.put(b)
    failures = []

    def runner():
        while True:
            try:
                batch = todo.get_nowait()
            except queue.Empty:
                return
            try:
                run_batch(batch, args.seed, args.timeout, results, seconds, lock)
            except Exception as exc:  # the harness itself failed: report, do not hide
                failures.append(exc)

    threads = [threading.Thread(target=runner) for _ in range(max(1, args.jobs))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    if failures:
        raise failures[0]
    elapsed = time.monotonic() - t0

    table = {}
    for (reader, kind, _i), (outcome, _d) in results.items():
        row = table.setdefault((reader, kind), dict.fromkeys(OUTCOMES, 0))
        row[outcome] += 1
    cols = ("cases",) + OUTCOMES
    print(f"{'reader':<7}{'kind':<14}" + "".join(f"{c:>10}" for c in cols))
    totals = dict.fromkeys(OUTCOMES, 0)
    for reader in READERS:
        sub = dict.fromkeys(OUTCOMES, 0)
        kinds = [k for k in KINDS[reader] if (reader, k) in table]
        for kind in kinds:
            row = table[(reader, kind)]
            print(f"{reader:<7}{kind:<14}" + f"{sum(row.values()):>10}" + "".join(f"{row[o]:>10}" for o in OUTCOMES))
            for o in OUTCOMES:
                sub[o] += row[o]
        if kinds:
            print(f"{reader:<7}{'(all)':<14}" + f"{sum(sub.values()):>10}" + "".join(f"{sub[o]:>10}" for o in OUTCOMES))
        for o in OUTCOMES:
            totals[o] += sub[o]
    print(f"{'total':<21}" + f"{sum(totals.values()):>10}" + "".join(f"{totals[o]:>10}" for o in OUTCOMES))
    print(f"{len(results)} cases, seed {args.seed}, {elapsed:.1f} s")
    slow = sorted(seconds.items(), key=lambda kv: -kv[1])[:3]
    print("slowest cases: " + ", ".join(f"{r}:{k}:{i} {t:.2f} s" for (r, k, i), t in slow))

    offenders = sorted(((k, v) for k, v in results.items() if v[0] in BAD),
                       key=lambda kv: (READERS.index(kv[0][0]), kv[0][2]))
    if not offenders:
        return 0
    print(f"\n{len(offenders)} offending case(s); the first {min(len(offenders), args.show)}:")
    for (reader, kind, index), (outcome, detail) in offenders[:args.show]:
        print(f"  {reader}:{kind}:{index}  {outcome}: {detail}")
    with tempfile.TemporaryDirectory(prefix="fuzz-readers-base-") as tmp:
        out = save_offenders(offenders[:args.show], args.seed, Path(tmp) / "base")
    print(f"inputs written to {out}")
    return 1


if __name__ == "__main__":
    sys.exit(main())
