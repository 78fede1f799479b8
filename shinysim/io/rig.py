"""``rig.json``: a rig read from its file (the document's fields are :meth:`shinysim.rig.Rig.from_dict`'s)."""

from __future__ import annotations

import os

from ..errors import RigError
from ..rig import Rig
from .document import parse_json, read_text

__all__ = ["MAX_RIG_BYTES", "load_rig"]

#: Largest rig file read, bytes (a 10000-source rig is about 1 MB).
MAX_RIG_BYTES = 16 * 2**20


def load_rig(path: str | os.PathLike, *, with_document: bool = False) -> Rig | tuple[Rig, dict]:
    """Read a rig JSON file, with errors that name the file and the field.

    Parameters
    ----------
    path : path-like
    with_document : bool
        Also return the parsed JSON document (e.g. for its ``provenance``).

    Raises
    ------
    RigError
        Only this (a ``ValueError``): a missing or unreadable file, bytes
        that are not UTF-8, invalid or too deeply nested JSON, and every
        schema violation of :meth:`Rig.from_dict`.
    """
    # parsed here, not through read_document: one frame fewer under a document nested to Python's limit
    doc = parse_json(read_text(path, error=RigError, max_bytes=MAX_RIG_BYTES, what="rig"), error=RigError, path=path)
    try:
        rig = Rig.from_dict(doc)
    except RigError as exc:
        raise RigError(exc.problem, path=path, field=exc.field) from None
    return (rig, doc) if with_document else rig
