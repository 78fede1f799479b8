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
    "did_you_mean",
    "check_fields",
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
        prefix = ""
        if self.path is not None:
            prefix += f"{self.path}: "
        if field is not None:
            prefix += f"{field}: "
        super().__init__(prefix + message)

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


def check_fields(d, known: Iterable[str], *, required: Iterable[str] = (), error: type = ShinysimError,
                 field: str | None = None, path: str | os.PathLike | None = None, what: str | None = None) -> dict:
    """``d`` if it is a JSON object with only ``known`` fields and every ``required`` one, else ``error``.

    The messages: ``must be a JSON object, got list``; ``unknown field 'x'
    (did you mean 'y'?); [what] fields are ...``; ``missing required
    field(s): ...``, each naming ``path`` and ``field``.
    """
    known = list(known)
    if not isinstance(d, dict):
        raise error(f"must be a JSON object, got {type(d).__name__}", path=path, field=field)
    for key in d:
        if key not in known:
            raise error(f"unknown field {key!r}{did_you_mean(key, known)}; {what + ' ' if what else ''}fields are "
                        f"{', '.join(known)}", path=path, field=field)
    missing = [k for k in required if k not in d]
    if missing:
        raise error(f"missing required field(s): {', '.join(missing)}", path=path, field=field)
    return d


class DiligentError(ShinysimError):
    """A DiLiGenT photometric-stereo folder is malformed: a missing or unreadable file, a light file
    row that is not three numbers, counts or image sizes that disagree (:mod:`shinysim.io.diligent`)."""



class StereoError(ShinysimError):
    """Structured-highlight stereo cannot run: a rig with one camera, cameras whose stacks do not share
    the same sources, stacks of different source counts, or highlight arrays that disagree."""
