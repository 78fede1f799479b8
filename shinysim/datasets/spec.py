"""Data-set specs: what to draw, validated, and every item resolved from (spec, index, seed).

A spec is JSON (``shinysim-dataset/1``): groups of items, each merged over
the spec's ``defaults`` and :data:`GROUP_DEFAULTS`, whose parameters are fixed
values or draws (``uniform``, ``loguniform``, ``choice``), with an optional
``grid`` of combinations. Item ``i`` is drawn from
``numpy.random.default_rng([seed, i])`` alone (:func:`resolve_item`); the rig
is fixed within a group. ``docs/datasets.md`` specifies the format, with an
example. Errors are :class:`~shinysim.errors.SpecError` naming the file and
the field (``spec.json: groups[1].material.alpha.uniform: ...``).
"""

from __future__ import annotations

import copy
import hashlib
import json
import math
import os
from itertools import product
from pathlib import Path
from typing import Any

import numpy as np

from .._shared import derive_seed
from ..errors import OptionError, SpecError, check_fields, did_you_mean
from ..io.document import read_document
from ..objects.registry import DATASET_OBJECT_KINDS

__all__ = ["SPEC_FORMAT", "GROUP_DEFAULTS", "DatasetSpec", "load_spec", "parse_spec", "resolve_item", "spec_diff",
           "RIG_PRESETS", "OBJECT_KINDS", "build_rig", "MATERIAL_KINDS", "MAX_ITEMS"]

SPEC_FORMAT = "shinysim-dataset/1"
#: Largest data set one spec may describe (item folders are numbered with 8 digits).
MAX_ITEMS = 10**8
#: Largest spec file read, bytes.
MAX_SPEC_BYTES = 16 * 2**20
#: The data sets' rig presets (each a :data:`shinysim.rig.RIG_PRESETS` entry), and "file": a rig file as it is.
_PRESET_OF = {"shiny_1988": "shiny_1988", "dome": "dome", "stereo": "stereo_pair"}
RIG_PRESETS = (*_PRESET_OF, "file")
OBJECT_KINDS = DATASET_OBJECT_KINDS
MATERIAL_KINDS = ("conductor", "hybrid", "diffuse")
DRAWS = ("uniform", "loguniform", "choice")

#: What a group is when the spec does not say.
GROUP_DEFAULTS: dict[str, Any] = {
    "rig": {"preset": "shiny_1988", "projection": "perspective"},
    "object": {"kind": "sphere"},
    "material": {"kind": "conductor", "alpha": 0.02, "distribution": "ggx"},
    "sensor": {"preset": "ideal", "exposure": 0.8},
    # resolution None: 512 for the presets, a rig file's own cameras
    "render": {"resolution": None, "spp": 64, "method": None, "coverage": 4, "max_depth": None},
}

# fields of each section, by kind; None marks a value that may be a draw
_RIG_FIELDS = {
    "shiny_1988": {"projection", "field_width_mm"},
    "dome": {"projection", "field_width_mm", "n_sources", "layout", "rings", "max_polar_deg", "radius_mm"},
    "stereo": {"projection", "field_width_mm", "beta_deg"},
    "file": {"path"},
}
_OBJECT_FIELDS = {
    "sphere": {"radius_mm", "center_mm"},
    "solder": {"class"},
    "blob": {"size_mm", "center_mm"},
    "superquadric": {"size_mm", "center_mm"},
    "heightfield": {"size_mm"},
    "mesh": {"path", "fit_mm", "center_mm"},
}
_MATERIAL_FIELDS = {
    "conductor": {"alpha", "distribution"},
    "hybrid": {"k", "sharpness", "distribution"},
    "diffuse": {"reflectance"},
}
# numeric ranges: (lo, hi, why)
_RANGES = {
    "alpha": (1e-4, 1.0, "a rough-conductor alpha: 0 is a perfect mirror, which a sampled renderer cannot image"),
    "k": (0.0, 1.0, "Eq 5's Lambertian weight"),
    "sharpness": (1e-3, 1e6, "Eq 5's exponent"),
    "reflectance": (0.0, 1.0, "an albedo"),
    "exposure": (1e-6, 1e3, "a fraction of the sensor's full well"),
    "radius_mm": (1e-3, 100.0, "a radius in mm"),
    "size_mm": (1e-3, 100.0, "a size in mm"),
    "fit_mm": (1e-3, 100.0, "a size in mm"),
    "center_mm": (-100.0, 100.0, "a position in mm"),
    "beta_deg": (0.0, 80.0, "the stereo angle"),
}


class _Checker:
    def __init__(self, path):
        self.path = path

    def fail(self, field, problem):
        raise SpecError(problem, path=self.path, field=field or None)

    def fields(self, d, known, field, *, required=()):
        check_fields(d, known, required=required, error=SpecError, field=field or None, path=self.path)

    def kind(self, section, field, key, fields_by_kind, what):
        """The section's kind (fixed within a group), after checking the section's fields for that kind."""
        self.fields(section, (key,) + tuple(sorted(set().union(*fields_by_kind.values()))), field, required=(key,))
        kind = self.drawable(section[key], f"{field}.{key}", key, choices=tuple(fields_by_kind))
        if isinstance(kind, dict):
            self.fail(f"{field}.{key}", f"{what} is fixed within a group (its scene is loaded once and reused); "
                                        f"make one group per {key}")
        self.fields(section, (key,) + tuple(fields_by_kind[kind]), field)
        return kind

    def file(self, value, field, base_dir, what, suffixes):
        """A path relative to the spec's folder, to an existing file with one of ``suffixes``."""
        if not isinstance(value, str) or not value:
            self.fail(field, f"must be a path to a {what} file ({', '.join(suffixes)})")
        p = Path(base_dir) / value
        if not p.is_file():
            self.fail(field, f"no {what} file {str(p)!r}")
        if p.suffix.lower() not in suffixes:
            self.fail(field, f"must be a {', '.join(suffixes)} {what} file, got {p.suffix or 'no extension'!r}")
        return value

    def number(self, value, field, name, *, integer=False, lo=None, hi=None):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(field, f"must be a number, got {json.dumps(value)}")
        if integer and not float(value).is_integer():
            self.fail(field, f"must be a whole number, got {value}")
        if not math.isfinite(value):
            self.fail(field, "must be finite")
        if name in _RANGES and lo is None:
            lo, hi, why = _RANGES[name]
        else:
            why = None
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            self.fail(field, f"{value} is outside [{lo}, {hi}]" + (f" ({why})" if why else ""))
        return int(value) if integer else float(value)

    def drawable(self, value, field, name, *, choices=None, integer=False):
        """A fixed value or a draw; returns the normalised form."""
        if isinstance(value, dict):
            if len(value) != 1 or next(iter(value)) not in DRAWS:
                keys = ", ".join(value) or "nothing"
                hint = did_you_mean(next(iter(value)), DRAWS) if len(value) == 1 else ""
                self.fail(field, f"a draw is one of {{{', '.join(DRAWS)}: ...}}, got {keys}{hint}")
            (how, args), = value.items()
            if how == "choice":
                if not isinstance(args, list) or not args:
                    self.fail(f"{field}.choice", "must be a non-empty list of values")
                return {"choice": [self.drawable(a, f"{field}.choice[{i}]", name, choices=choices, integer=integer)
                                   for i, a in enumerate(args)]}
            if choices is not None:
                self.fail(field, f"must be one of {', '.join(map(str, choices))} or a choice of them")
            if not isinstance(args, list) or len(args) != 2:
                self.fail(f"{field}.{how}", "must be [lo, hi]")
            lo, hi = (self.number(a, f"{field}.{how}[{i}]", name) for i, a in enumerate(args))
            if not lo <= hi:
                self.fail(f"{field}.{how}", f"lo {lo} is above hi {hi}")
            if how == "loguniform" and lo <= 0:
                self.fail(f"{field}.loguniform", "needs lo > 0")
            return {how: [lo, hi]}
        if choices is not None:
            if value not in choices:
                self.fail(field, f"must be one of {', '.join(map(str, choices))}, got {json.dumps(value)}"
                                 f"{did_you_mean(str(value), [str(c) for c in choices])}")
            return value
        return self.number(value, field, name, integer=integer)


def _merge(base, over):
    out = copy.deepcopy(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict) and not (set(v) & set(DRAWS)):
            # a section's kind (or preset) changing starts from that section afresh
            if ("kind" in v and v["kind"] != out[k].get("kind")) or ("preset" in v and v["preset"] != out[k].get(
                    "preset")):
                out[k] = copy.deepcopy(v)
            else:
                out[k] = _merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


class DatasetSpec:
    """A validated spec: its normalised document and the groups' item ranges.

    Attributes
    ----------
    document : dict
        The spec as normalised (defaults merged into every group): what a
        data-set folder records, and compares against on a rerun.
    groups : list of dict
    n_items : int
    base_dir : pathlib.Path
        Folder that relative file paths (rigs, meshes) are read from.
    """

    def __init__(self, document, groups, base_dir, path):
        self.document = document
        self.groups = groups
        self.base_dir = Path(base_dir)
        self.path = path
        self._offsets = np.cumsum([0] + [g["n_items"] for g in groups])
        self.n_items = int(self._offsets[-1])

    @property
    def seed(self) -> int:
        return int(self.document["seed"])

    @property
    def sha256(self) -> str:
        return hashlib.sha256(canonical_json(self.document).encode()).hexdigest()

    def group_of(self, index: int) -> tuple[int, int]:
        """(group number, index within the group) of item ``index``."""
        if not 0 <= index < self.n_items:
            raise SpecError(f"item {index} does not exist (the spec has {self.n_items} items, 0..{self.n_items - 1})",
                            path=self.path, field="index")
        g = int(np.searchsorted(self._offsets, index, side="right") - 1)
        return g, int(index - self._offsets[g])


def canonical_json(d) -> str:
    return json.dumps(d, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False)


def load_spec(path: str | os.PathLike) -> DatasetSpec:
    """Read and validate a spec file; relative paths inside it are relative to its folder."""
    path = Path(path)
    doc = read_document(path, error=SpecError, max_bytes=MAX_SPEC_BYTES, what="spec", obj=False)
    return parse_spec(doc, base_dir=path.parent, path=path)


def parse_spec(doc: Any, *, base_dir: str | os.PathLike = ".", path: str | os.PathLike | None = None) -> DatasetSpec:
    """Validate a spec document (a dict, as read from JSON)."""
    c = _Checker(path)
    c.fields(doc, ("format", "name", "seed", "defaults", "groups"), "", required=("format", "groups"))
    if doc["format"] != SPEC_FORMAT:
        c.fail("format", f"must be {SPEC_FORMAT!r}, got {json.dumps(doc['format'])}")
    name = doc.get("name", "dataset")
    if not isinstance(name, str) or not name.strip():
        c.fail("name", "must be a non-empty string")
    seed = c.number(doc.get("seed", 0), "seed", "seed", integer=True, lo=0, hi=2**32 - 1)
    defaults = doc.get("defaults", {})
    c.fields(defaults, tuple(GROUP_DEFAULTS), "defaults")
    groups = doc["groups"]
    if not isinstance(groups, list) or not groups:
        c.fail("groups", "must be a non-empty list of groups")
    base = _merge(GROUP_DEFAULTS, defaults)
    out_groups = []
    total = 0
    for gi, g in enumerate(groups):
        where = f"groups[{gi}]"
        c.fields(g, ("name", "count", "grid") + tuple(GROUP_DEFAULTS), where)
        merged = _merge(base, {k: v for k, v in g.items() if k in GROUP_DEFAULTS})
        group = {"name": g.get("name", f"group{gi}")}
        if not isinstance(group["name"], str) or not group["name"]:
            c.fail(f"{where}.name", "must be a non-empty string")
        group["count"] = c.number(g.get("count", 1), f"{where}.count", "count", integer=True, lo=1, hi=MAX_ITEMS)
        group.update(_check_sections(c, merged, where, base_dir))
        _check_rig_builds(c, group, where, base_dir)
        grid = g.get("grid", {})
        group["grid"] = _check_grid(c, grid, group, f"{where}.grid")
        n_comb = int(np.prod([len(v) for v in group["grid"].values()])) if group["grid"] else 1
        group["n_items"] = group["count"] * n_comb
        total += group["n_items"]
        if total > MAX_ITEMS:
            c.fail(f"{where}.count", f"the spec would make {total} items, more than {MAX_ITEMS}")
        out_groups.append(group)
    document = {"format": SPEC_FORMAT, "name": name, "seed": seed,
                "groups": [{k: v for k, v in g.items() if k != "n_items"} for g in out_groups]}
    return DatasetSpec(document, out_groups, base_dir, path)


def _section(c, m, where, name, key, fields, what):
    """Section ``name`` of group ``m``: its checked ``key`` (the kind), and its other fields as
    ``(field, value, location)``."""
    section = m[name]
    kind = c.kind(section, f"{where}.{name}", key, fields, what)
    return kind, [(k, v, f"{where}.{name}.{k}") for k, v in section.items() if k != key]


def _check_sections(c, m, where, base_dir):
    out = {}
    # rig: fixed per group
    preset, fields = _section(c, m, where, "rig", "preset", _RIG_FIELDS, "the rig")
    r = {"preset": preset}
    for k, v, f in fields:
        if isinstance(v, dict):
            c.fail(f, "the rig is fixed within a group (its scene is loaded once and reused); make one group per rig")
        if k == "path":
            r[k] = c.file(v, f, base_dir, "rig", (".json",))
        elif k == "rings":
            if not isinstance(v, list) or not v or not all(isinstance(x, list) and len(x) == 2 for x in v):
                c.fail(f, "must be a list of [polar_deg, count] pairs")
            r[k] = [[c.number(a, f"{f}[{i}][0]", "polar", lo=0, hi=90),
                     c.number(b, f"{f}[{i}][1]", "count", integer=True, lo=1, hi=10000)] for i, (a, b) in enumerate(v)]
        else:
            r[k] = _fixed(c, k, v, f)
    out["rig"] = r
    # object
    kind, fields = _section(c, m, where, "object", "kind", _OBJECT_FIELDS, "the object kind")
    o = {"kind": kind}
    for k, v, f in fields:
        if k == "path":
            o[k] = c.file(v, f, base_dir, "mesh", (".ply", ".obj"))
        else:
            o[k] = _check_param(c, "object", k, v, f)
    if kind == "mesh" and "path" not in o:
        c.fail(f"{where}.object.path", "a mesh object needs a path")
    if kind == "solder":
        o.setdefault("class", "good")
    out["object"] = o
    # material
    mkind, fields = _section(c, m, where, "material", "kind", _MATERIAL_FIELDS, "the material kind")
    mt = {"kind": mkind}
    for k, v, f in fields:
        mt[k] = _check_param(c, "material", k, v, f)
    if mkind == "hybrid":
        for k in ("k", "sharpness"):
            if k not in mt:
                c.fail(f"{where}.material.{k}", "the Eq 5 hybrid needs k and sharpness")
    if kind == "solder" and mkind != "conductor":
        c.fail(f"{where}.material.kind", "solder joints have their own part materials; only the solder's "
                                         "conductor alpha may be set")
    out["material"] = mt
    # sensor
    sen = m["sensor"]
    c.fields(sen, ("preset", "exposure"), f"{where}.sensor")
    out["sensor"] = {k: _check_param(c, "sensor", k, sen.get(k, default), f"{where}.sensor.{k}")
                     for k, default in (("preset", "ideal"), ("exposure", 0.8))}
    # render
    ren = m["render"]
    c.fields(ren, tuple(GROUP_DEFAULTS["render"]), f"{where}.render")
    rd = {}
    for k, v in ren.items():
        f = f"{where}.render.{k}"
        if isinstance(v, dict):
            c.fail(f, "render settings are fixed within a group")
        rd[k] = _fixed(c, k, v, f)
    out["render"] = rd
    return out


# the settings fixed within a group (rig and render): the choices, or the number's bounds (_Checker.number's
# keywords; none: _RANGES or any number); _NULLABLE may be null (a distant dome; the defaults of "render")
_FIXED = {
    "projection": ("perspective", "orthographic"), "layout": ("fibonacci", "rings"), "method": ("one-pass", "per-source"),
    "n_sources": dict(integer=True, lo=1, hi=10000), "max_polar_deg": dict(lo=1.0, hi=90.0),
    "field_width_mm": dict(lo=1e-3, hi=1e3), "resolution": dict(integer=True, lo=16, hi=4096),
    "spp": dict(integer=True, lo=1, hi=65536), "coverage": dict(integer=True, lo=0, hi=16),
    "max_depth": dict(integer=True, lo=2, hi=16),
}
_NULLABLE = ("radius_mm", "resolution", "max_depth", "method")


def _fixed(c, name, value, field):
    rule = _FIXED.get(name, {})
    if value is None and name in _NULLABLE:
        return None
    if isinstance(rule, tuple):
        return c.drawable(value, field, name, choices=rule)
    return c.number(value, field, name, **rule)


def build_rig(rig_spec: dict, resolution: int, base_dir: str | os.PathLike = "."):
    """The rig of a group: a preset at ``resolution`` pixels (None: 512), or a rig file as it is."""
    from ..io import load_rig
    from ..rig import rig_preset

    kw = {k: rig_spec[k] for k in ("projection", "field_width_mm") if k in rig_spec}
    preset = rig_spec["preset"]
    if preset != "file":
        kw["resolution"] = 512 if resolution is None else int(resolution)
    if preset == "dome":
        kw.update({k: rig_spec[k] for k in ("n_sources", "layout", "max_polar_deg", "radius_mm") if k in rig_spec})
        if "rings" in rig_spec:
            kw["rings"] = [tuple(r) for r in rig_spec["rings"]]
    if preset == "stereo":
        kw["beta_deg"] = rig_spec.get("beta_deg", 15.0)
    if preset != "file":
        return rig_preset(_PRESET_OF[preset], **kw)
    rig = load_rig(Path(base_dir) / rig_spec["path"])
    if resolution is not None and any(c.width != int(resolution) for c in rig.cameras):
        raise OptionError(f"a rig file keeps its own cameras ({', '.join(f'{c.width} x {c.height}' for c in rig.cameras)}"
                         f" pixels); leave render.resolution out, or make it the cameras' width")
    return rig


def _check_rig_builds(c, group, where, base_dir):
    """Build the group's rig now (cheap, numpy only), so a rig that cannot exist is refused before any work."""
    from ..errors import ShinysimError

    try:
        build_rig(group["rig"], group["render"]["resolution"], base_dir)
    except ShinysimError as exc:
        c.fail(f"{where}.rig", f"{exc.path + ': ' if exc.path else ''}{exc.problem}")
    except ValueError as exc:
        c.fail(f"{where}.rig", str(exc))


def _check_param(c, section, name, value, field):
    """One drawable parameter of the object, material or sensor section, normalised."""
    if name == "center_mm":
        if not isinstance(value, list) or len(value) != 3:
            c.fail(field, "must be [x, y, z], each a number or a draw")
        return [c.drawable(x, f"{field}[{i}]", name) for i, x in enumerate(value)]
    if name == "class":
        from ..objects.solder import JOINT_KINDS

        return c.drawable(value, field, name, choices=JOINT_KINDS)
    if name == "distribution":
        return c.drawable(value, field, name, choices=("ggx", "beckmann"))
    if section == "sensor" and name == "preset":
        from ..sim.sensor import SENSOR_PRESETS

        return c.drawable(value, field, name, choices=tuple(SENSOR_PRESETS))
    return c.drawable(value, field, name)


def _check_grid(c, grid, group, where):
    if not isinstance(grid, dict):
        c.fail(where, "must be a JSON object of 'section.key': [values]")
    out = {}
    for key, values in grid.items():
        f = f"{where}.{key}"
        parts = key.split(".")
        if len(parts) != 2 or parts[0] not in ("object", "material", "sensor"):
            c.fail(f, "grid keys are 'object.KEY', 'material.KEY' or 'sensor.KEY' (rig and render settings are "
                      "fixed within a group)")
        section, name = parts
        fields = {"object": _OBJECT_FIELDS[group["object"]["kind"]], "material": _MATERIAL_FIELDS[
            group["material"]["kind"]], "sensor": {"preset", "exposure"}}[section] - {"path"}
        if name not in fields:
            c.fail(f, f"the group's {section} has no parameter {name!r}{did_you_mean(name, fields)}"
                      f" (it has {', '.join(sorted(fields)) or 'none'})")
        if not isinstance(values, list) or not values:
            c.fail(f, "must be a non-empty list of values")
        out[key] = [_check_param(c, section, name, v, f"{f}[{i}]") for i, v in enumerate(values)]
    return out


# -- items ---------------------------------------------------------------------------

def _draw(value, rng):
    if isinstance(value, dict) and len(value) == 1:
        (how, args), = value.items()
        if how == "uniform":
            return float(rng.uniform(args[0], args[1]))
        if how == "loguniform":
            return float(np.exp(rng.uniform(np.log(args[0]), np.log(args[1]))))
        if how == "choice":
            return _draw(args[int(rng.integers(len(args)))], rng)
    if isinstance(value, list):
        return [_draw(v, rng) for v in value]
    return value


def resolve_item(spec: DatasetSpec, index: int) -> dict:
    """Item ``index`` with every draw made: a plain JSON dict the worker renders from.

    Draws come from ``numpy.random.default_rng([spec.seed, index])`` in a
    fixed order (object, material, sensor, then the object's shape), so an
    item depends on nothing but the spec and its index.
    """
    g, j = spec.group_of(index)
    group = spec.groups[g]
    rng = np.random.default_rng([spec.seed, int(index)])
    sections = {s: copy.deepcopy(group[s]) for s in ("rig", "object", "material", "sensor", "render")}
    if group["grid"]:
        keys = list(group["grid"])
        combo = list(product(*(group["grid"][k] for k in keys)))[j // group["count"]]
        for key, v in zip(keys, combo):
            s, name = key.split(".")
            sections[s][name] = v
    item = {"index": int(index), "group": g, "group_name": group["name"],
            "seed": derive_seed(spec.seed, "item", int(index))}
    for s in ("object", "material", "sensor"):
        item[s] = {k: _draw(v, rng) for k, v in sections[s].items()}
    item["rig"] = sections["rig"]
    item["render"] = sections["render"]
    obj = item["object"]
    # shapes drawn here too, so that the item dict alone rebuilds the object
    if obj["kind"] == "solder":
        obj["params"] = _draw_joint(obj["class"], rng, index)
    elif obj["kind"] in ("blob", "superquadric", "heightfield"):
        from ..objects.shapes import random_shape

        kw = {k: obj[k] for k in ("size_mm", "center_mm") if k in obj}
        mesh = random_shape(obj["kind"], rng, **kw)
        obj["params"] = mesh.params
    return item


#: Redraws of a joint whose parameters the mesher cannot build, before the item is refused.
JOINT_REDRAWS = 50


def _draw_joint(kind, rng, index):
    """A joint of the class that the mesher can build: its parameters as a dict.

    ``sample_params`` keeps to each class's ranges and validity rules, but a
    few per cent of its draws (5 % of 'insufficient' joints) still fail in
    the mesher (a fillet column that is not x-monotone); those are drawn
    again from the same generator, so the item stays a function of (seed,
    index).
    """
    from ..objects.solder import sample_params
    from ..sim.solder import make_joint

    for _ in range(JOINT_REDRAWS):
        params = sample_params(kind, rng)
        try:
            make_joint(params)
        except RuntimeError:
            continue
        return params.to_dict()
    raise SpecError(f"item {index}: no {kind!r} joint the mesher can build in {JOINT_REDRAWS} draws", field="object")


def spec_diff(old: dict, new: dict, prefix: str = "") -> list[str]:
    """Readable differences between two normalised spec documents (``field: old -> new``)."""
    out = []
    if isinstance(old, dict) and isinstance(new, dict):
        for k in sorted(set(old) | set(new), key=str):
            f = f"{prefix}.{k}" if prefix else str(k)
            if k not in old:
                out.append(f"{f}: added ({json.dumps(new[k])})")
            elif k not in new:
                out.append(f"{f}: removed (was {json.dumps(old[k])})")
            else:
                out += spec_diff(old[k], new[k], f)
    elif isinstance(old, list) and isinstance(new, list) and len(old) == len(new):
        for i, (a, b) in enumerate(zip(old, new)):
            out += spec_diff(a, b, f"{prefix}[{i}]")
    elif old != new:
        out.append(f"{prefix}: {json.dumps(old)} -> {json.dumps(new)}")
    return out
