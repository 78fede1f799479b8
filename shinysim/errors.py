"""The errors shinysim raises for bad input: one family, all ``ValueError``.

Every reader (rig JSON, stack and truth EXR, image frames, highlight CSV,
DiLiGenT folders) and every option check raises a subclass of
:class:`ShinysimError` and nothing else, so a caller can catch the whole
family with one ``except ValueError`` (or ``except ShinysimError``) and a
command line can print one line instead of a traceback. The message names
the file and the field or channel at fault; both are also kept as
attributes (``path``, ``field``). ``docs/bad-input.md`` lists every class
of bad input and what it gives.
"""

from __future__ import annotations

import difflib
import functools
import json
import math
import os
from collections.abc import Iterable

__all__ = [
    "ShinysimError",
    "OptionError",
    "RigError",
    "StackFormatError",
    "FrameError",
    "SpecError",
    "DiligentError",
    "HighlightTableError",
    "CalibrationError",
    "StereoError",
    "SofastError",
    "did_you_mean",
    "check_fields",
    "check_schema",
    "json_type",
    "short_json",
    "TYPE_WORDS",
]


class ShinysimError(ValueError):
    """Bad input to shinysim: a file, a field or an option.

    Parameters
    ----------
    message : str
        What is wrong, in words a user can act on.
    path : path-like, optional
        The file at fault; the message starts with it.
    field : str, optional
        The field, channel, column or option at fault; named after the path.
    """

    def __init__(self, message: str, *, path: str | os.PathLike | None = None, field: str | None = None):
        self.path = None if path is None else os.fspath(path)
        self.field = field
        self.problem = message
        super().__init__("".join(f"{part}: " for part in (self.path, field) if part is not None) + message)

    def __reduce__(self):  # picklable with its keywords (errors cross process boundaries)
        return (_rebuild, (type(self), self.problem, self.path, self.field))


def _rebuild(cls, message, path, field):
    return cls(message, path=path, field=field)


class OptionError(ShinysimError):
    """A parameter or command-line option is out of range or not a valid choice."""


class RigError(ShinysimError):
    """A rig description is invalid or incomplete."""


class StackFormatError(ShinysimError):
    """A stack or truth file is malformed or disagrees with its rig."""


class FrameError(ShinysimError):
    """A frame cannot be read or analysed (format, NaN, negative or saturated pixels, shape)."""


class HighlightTableError(ShinysimError):
    """A highlight table (``highlights.csv``) is malformed."""


class SpecError(ShinysimError):
    """A data-set spec (``shinysim dataset``) that cannot be used, or a data-set folder that does not match it."""


class CalibrationError(ShinysimError):
    """Calibration data cannot give a solution: holes or a sphere not found, a count or layout
    that does not match, too few placements, or a degenerate geometry."""


def did_you_mean(name: str, known: Iterable[str]) -> str:
    """`` (did you mean 'x'?)`` for the closest known name, or ``""`` for none."""
    close = difflib.get_close_matches(str(name), list(known), n=1, cutoff=0.6)
    if not close:
        low = str(name).lower()
        close = [k for k in known if k.lower().startswith(low) or low.startswith(k.lower())][:1]
    return f" (did you mean {close[0]!r}?)" if close else ""


#: What each JSON Schema type is called in a message (``must be 3 finite numbers, got [1, 2]``).
TYPE_WORDS = {"number": "a number", "integer": "an integer", "string": "a string", "vec3": "3 finite numbers",
              "object": "a JSON object", "array": "a list", "boolean": "true or false", "null": "null"}


def _float(value) -> float | None:
    """A JSON number as a float; None for anything else, a boolean, or an integer beyond the float range."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    try:
        return float(value)
    except OverflowError:
        return None


def _vec3(checker, value) -> bool:
    return isinstance(value, list) and len(value) == 3 and all(
        (f := _float(v)) is not None and math.isfinite(f) for v in value)


def _validator(schema):
    return _compiled(json.dumps(schema, sort_keys=True))


@functools.lru_cache(maxsize=512)
def _compiled(schema_json):
    """A jsonschema validator of a schema, whose ``number`` is a number within the float range and whose
    ``vec3`` is 3 finite numbers."""
    from jsonschema import Draft202012Validator, ValidationError, validators

    checker = Draft202012Validator.TYPE_CHECKER.redefine_many({
        "number": lambda checker, v: _float(v) is not None, "vec3": _vec3
    })

    def type_(validator, types, instance, schema):  # jsonschema's own message reprs the value, at any depth
        if not any(validator.is_type(instance, t) for t in ([types] if isinstance(types, str) else types)):
            yield ValidationError("wrong type")

    return validators.extend(Draft202012Validator, validators={"type": type_}, type_checker=checker)(
        json.loads(schema_json))


def json_type(value) -> str:
    """``a list``, ``an object``, ``null``, ...: a JSON value's kind in words."""
    return {dict: "an object", list: "a list", str: "a string", bool: "a boolean", type(None): "null",
            int: "a number", float: "a number"}.get(type(value), type(value).__name__)


def short_json(value) -> str:
    """``value`` as JSON in at most 60 characters (its kind where it cannot be written)."""
    try:
        text = json.dumps(value, allow_nan=True) if not isinstance(value, (set, tuple)) else repr(value)
    except (RecursionError, ValueError):  # nested too deeply, or an integer too long to print
        text = json_type(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _at(field, path) -> str | None:
    for p in path:
        field = f"{field}[{p}]" if isinstance(p, int) else (f"{field}.{p}" if field else str(p))
    return field


def check_schema(doc, schema: dict, *, error: type = ShinysimError, path: str | os.PathLike | None = None,
                 field: str | None = None, what: str | None = None):
    """``doc`` if it fits ``schema``, else ``error`` for its first fault, naming ``path`` and the field.

    ``schema`` is a JSON Schema (draft 2020-12, checked by ``jsonschema``)
    whose ``number`` is a number within the float range and which knows one
    more type, ``vec3`` (3 finite numbers). The fault named is the
    outermost one (an object's own faults before its fields'), in this
    order: not an object (``must be a JSON object, got list``); an unknown
    field (``unknown field 'x' (did you mean 'y'?); [what] fields are
    ...``); missing fields (``missing required field(s): a, b``); a field of
    the wrong type (``field.key: must be 3 finite numbers, got [1, 2]``);
    any other rule (jsonschema's message). Checks JSON Schema cannot state
    (across fields, numeric rules on the values) stay with the caller,
    after this one.
    """
    rank = {"type": 0, "additionalProperties": 1, "required": 2}
    errors = list(_validator(schema).iter_errors(doc))
    if not errors:
        return doc
    e = min(errors, key=lambda e: (len(e.absolute_path), rank.get(e.validator, 3), _order(doc, e.absolute_path)))
    where = _at(field, e.absolute_path)
    value, sub = e.instance, e.schema
    if e.validator == "type" and sub.get("type") == "object":
        raise error(f"must be a JSON object, got {json_type(value)}", path=path, field=where)
    if e.validator == "additionalProperties":
        known = list(sub.get("properties", {}))
        key = next(k for k in value if k not in known)
        raise error(f"unknown field {key!r}{did_you_mean(key, known)}; {what + ' ' if what else ''}fields are "
                    f"{', '.join(known)}", path=path, field=where)
    if e.validator == "required":
        missing = [k for k in sub["required"] if k not in value]
        raise error(f"missing required field(s): {', '.join(missing)}", path=path, field=where)
    if e.validator == "type":
        want = sub["type"]
        beyond = want == "number" and isinstance(value, int) and not isinstance(value, bool)  # |x| > 1.8e308
        raise error(f"must be {TYPE_WORDS.get(want, want)}{' within the float range' if beyond else ''}, "
                    f"got {short_json(value)}", path=path, field=where)
    raise error(e.message, path=path, field=where)


def _order(doc, at) -> int:
    """Where the first key of ``at`` comes in ``doc`` (faults are named in the document's order)."""
    if not at or not isinstance(doc, dict):
        return at[0] if at and isinstance(at[0], int) else 0
    keys = list(doc)
    return keys.index(at[0]) if at[0] in keys else len(keys)


def check_fields(d, known: Iterable[str], *, required: Iterable[str] = (), error: type = ShinysimError,
                 field: str | None = None, path: str | os.PathLike | None = None, what: str | None = None) -> dict:
    """``d`` if it is a JSON object with only ``known`` fields and every ``required`` one, else ``error``
    (:func:`check_schema` of that schema, its messages)."""
    schema = {"type": "object", "properties": {k: {} for k in known}, "required": list(required),
              "additionalProperties": False}
    return check_schema(d, schema, error=error, field=field, path=path, what=what)


class DiligentError(ShinysimError):
    """A DiLiGenT photometric-stereo folder is malformed: a missing or unreadable file, a light file
    row that is not three numbers, counts or image sizes that disagree (:mod:`shinysim.io.diligent`)."""


class StereoError(ShinysimError):
    """Structured-highlight stereo cannot run: a rig with one camera, cameras whose stacks do not share
    the same sources, stacks of different source counts, or highlight arrays that disagree."""


class SofastError(ShinysimError):
    """A SOFAST file (Sandia OpenCSP; HDF5 or JSON) that cannot be read, is of another kind, or is malformed."""
