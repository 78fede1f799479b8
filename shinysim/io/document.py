"""The one reader of text files and JSON documents.

Every reader of a text file (rig JSON, calibration and data-set documents,
``code.json``, DiLiGenT's light files, ``highlights.csv``) takes its text
through :func:`read_text`: the bytes are read with a size cap, a UTF-8
byte-order mark is dropped, and the rest must decode as UTF-8. JSON goes on
through :func:`parse_json`. Each error is the caller's own class
(:mod:`shinysim.errors`) and names the file: ``rig.json: is not UTF-8 text
(byte 13: b'\\xff')``, ``spec.json: not valid JSON (line 1 column 2:
Expecting value)``, ``spheres.json: not valid JSON: nested too deeply``.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from ..errors import ShinysimError, json_type

__all__ = ["MAX_DOCUMENT_BYTES", "read_text", "parse_json", "read_document"]

#: Largest text file read, bytes (a 10000-source rig is about 1 MB).
MAX_DOCUMENT_BYTES = 16 * 2**20

_BOM = b"\xef\xbb\xbf"


def read_text(path: str | os.PathLike, *, error: type = ShinysimError, max_bytes: int = MAX_DOCUMENT_BYTES,
              what: str = "text", field: str | None = None, locate: bool = False) -> str:
    """A file's text: at most ``max_bytes``, an optional UTF-8 byte-order mark, UTF-8.

    ``locate`` (line-oriented files such as CSV) also refuses a NUL byte (a
    binary file), and names a bad byte's ``line L, byte B`` as the field. Errors are
    ``error`` naming ``path`` (and ``field``): ``no such file``, ``not a
    file: is a folder``, ``is N bytes; a {what} file is at most M``,
    ``cannot read the file: ...``, ``is not UTF-8 text (byte N: b'\\xff')``.
    """
    path = Path(path)
    try:
        if not path.exists():
            raise error("no such file", path=path, field=field)
        if not path.is_file():
            raise error("not a file: is a folder" if path.is_dir() else "not a file: not a regular file",
                        path=path, field=field)
        size = path.stat().st_size
        if size > max_bytes:
            raise error(f"is {size} bytes; a {what} file is at most {max_bytes}", path=path, field=field)
        data = path.read_bytes()
    except OSError as exc:
        raise error(f"cannot read the file: {exc.strerror or exc}", path=path, field=field) from None
    skip = len(_BOM) if data.startswith(_BOM) else 0
    at = data.find(b"\x00") if locate else -1
    if at >= 0:
        raise error(f"holds a NUL byte: not a text file (a {what} file is UTF-8 text)", path=path,
                    field=f"line {_line_of_offset(data, at)}, byte {at}")
    try:
        return data[skip:].decode("utf-8")
    except UnicodeDecodeError as exc:
        at = exc.start + skip
        line = _line_of_offset(data, at)
        raise error(f"is not UTF-8 text (byte {at}: 0x{data[at]:02x}{'' if locate else f', line {line}'}: "
                    f"{exc.reason})", path=path, field=f"line {line}, byte {at}" if locate else field) from None


def _line_of_offset(data: bytes, offset: int) -> int:
    head = data[:offset]
    return head.count(b"\n") + head.count(b"\r") - head.count(b"\r\n") + 1


def parse_json(text: str, *, error: type = ShinysimError, path: str | os.PathLike | None = None,
               field: str | None = None, parse_int=None) -> Any:
    """``json.loads(text)``, every failure as ``error``: where the syntax breaks, nesting too deep for
    Python, an integer of more digits than Python converts."""
    try:
        return json.loads(text, parse_int=parse_int)
    except json.JSONDecodeError as exc:
        raise error(f"not valid JSON (line {exc.lineno} column {exc.colno}: {exc.msg})", path=path,
                    field=field) from None
    except RecursionError:
        raise error("not valid JSON: nested too deeply", path=path, field=field) from None
    except ValueError as exc:  # an integer of more digits than Python converts (sys.get_int_max_str_digits)
        raise error(f"not valid JSON: a number is too long ({str(exc).split(';')[0]})", path=path,
                    field=field) from None


def read_document(path: str | os.PathLike, *, error: type = ShinysimError, max_bytes: int = MAX_DOCUMENT_BYTES,
                  what: str = "JSON", parse_int=None, obj: bool = True) -> Any:
    """A JSON file's document (:func:`read_text` then :func:`parse_json`); ``obj``: it must be a JSON object."""
    doc = parse_json(read_text(path, error=error, max_bytes=max_bytes, what=what), error=error, path=path,
                     parse_int=parse_int)
    if obj and not isinstance(doc, dict):
        raise error(f"must be a JSON object, got {json_type(doc)}", path=path)
    return doc

