"""The highlight table: :class:`HighlightTable`, and ``highlights.csv`` written and read back checked.

The file has one row per highlight and camera model under :data:`HIGHLIGHT_COLUMNS`
(files of :data:`LEGACY_COLUMNS` are still read); ``docs/file-format.md``
specifies it. :func:`read_highlight_table` checks everything it reads and
raises only :class:`~shinysim.errors.HighlightTableError`, naming the file,
the line and the column at fault; ``docs/bad-input.md`` lists each class of
bad input.
"""

from __future__ import annotations

import csv
import math
import os
import re
from collections.abc import Iterable, Mapping
from pathlib import Path

import numpy as np

from .._shared import check_number, write_text
from ..errors import HighlightTableError, OptionError, did_you_mean
from .document import read_text

__all__ = [
    "COLUMN_DTYPES",
    "HIGHLIGHT_COLUMNS",
    "HighlightTable",
    "LEGACY_COLUMNS",
    "format_highlight_table",
    "read_highlight_table",
    "write_highlight_table",
]

#: The header of a highlight table, in the order written.
HIGHLIGHT_COLUMNS = (
    "source", "row", "col", "area", "peak", "sum", "blob", "part",
    "rel_peak", "interreflection", "saturated",
    "model", "nx", "ny", "nz",
)
#: The header of tables written before ``rel_peak`` and the flags; still read.
LEGACY_COLUMNS = ("source", "row", "col", "area", "peak", "sum", "blob", "part", "model", "nx", "ny", "nz")

#: Each per-highlight column every table has, with its dtype, in the order of the file.
COLUMN_DTYPES = {"source": np.int64, "row": np.float64, "col": np.float64, "area": np.int64, "peak": np.float64,
                 "sum": np.float64, "blob": np.int64, "part": np.int64, "rel_peak": np.float64,
                 "interreflection": np.bool_, "saturated": np.bool_}
_INT_COLUMNS = tuple(k for k, v in COLUMN_DTYPES.items() if v is np.int64)
_FLOAT_COLUMNS = tuple(k for k, v in COLUMN_DTYPES.items() if v is np.float64)
_NORMAL_COLUMNS = ("nx", "ny", "nz")
#: The per-highlight columns, in the order of the returned table.
_TABLE_COLUMNS = HIGHLIGHT_COLUMNS[:11]
#: Smallest allowed value of each integer column.
_INT_MIN = {"source": 0, "area": 1, "blob": 1, "part": 0}

#: How far a normal's length may differ from 1. The writer rounds each
#: component to 8 decimals, which moves the length by at most
#: sqrt(3) * 5e-9 (about 1e-8); 1e-6 leaves room for a hand-edited file while
#: catching any normal that was never normalised.
NORMAL_LENGTH_TOL = 1e-6

#: The longest line read. A valid row is under 200 characters; anything much
#: longer is not a highlight table, and checking the length before the CSV
#: parser sees the line keeps every field far below ``csv.field_size_limit()``
#: (which is process-wide and therefore left alone), so a huge single line
#: fails at once with a clear message instead of a ``csv.Error``.
_MAX_LINE_CHARS = 10_000
#: Largest table read, bytes (about 10 million highlights).
MAX_TABLE_BYTES = 2**30

_MODEL_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.+-]{0,63}")
_INT_TEXT = re.compile(r"[+-]?[0-9]{1,18}")
_FLOAT_TEXT = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
_NONFINITE_TEXT = re.compile(r"[+-]?(?:nan|inf|infinity)", re.IGNORECASE)
_LINE_BREAK = re.compile(r"\r\n|\r|\n")
_SPACE = re.compile(r"\s")  # what str.strip removes


# -- the table ----------------------------------------------------------------------------


def _column(key: str, value, n: int | None) -> np.ndarray:
    value = np.asarray(value)
    if value.ndim < 1 or (key in COLUMN_DTYPES and value.ndim != 1):
        raise OptionError(f"table[{key!r}] must be one-dimensional, got shape {value.shape}")
    if n is not None and len(value) != n:
        raise OptionError(f"table[{key!r}] has {len(value)} entries, table['source'] has {n}")
    return value


def _integers(key: str, value: np.ndarray) -> np.ndarray:
    if value.dtype.kind == "f" and len(value) and not (np.all(np.isfinite(value)) and np.all(value == np.round(value))):
        raise OptionError(f"table[{key!r}] must hold integers")
    if value.dtype.kind not in "iuf" and len(value):
        raise OptionError(f"table[{key!r}] must hold integers, got dtype {value.dtype}")
    value = value.astype(np.int64) if len(value) else np.zeros(0, np.int64)
    low = _INT_MIN[key]
    if len(value) and value.min() < low:
        i = int(np.argmin(value))
        raise OptionError(f"table[{key!r}] must be >= {low}, got {value[i]} at index {i}")
    return value


def _floats(key: str, value: np.ndarray) -> np.ndarray:
    if value.dtype.kind not in "iuf" and len(value):
        raise OptionError(f"table[{key!r}] must hold numbers, got dtype {value.dtype}")
    value = value.astype(np.float64)
    allow_nan, nonnegative = key == "rel_peak", key not in ("row", "col")
    bad = ~np.isfinite(value)
    if allow_nan:
        bad &= ~np.isnan(value)
    if nonnegative:
        bad |= value < 0
    if np.any(bad):
        i = int(np.argmax(bad))
        need = "finite and >= 0" if nonnegative else "finite"
        raise OptionError(f"table[{key!r}] must be {need}{' or NaN' if allow_nan else ''}, got {value[i]} at index {i}")
    return value


def _flags(key: str, value: np.ndarray) -> np.ndarray:
    if value.dtype.kind != "b" and len(value) and (
            value.dtype.kind not in "iuf" or not np.all((value == 0) | (value == 1))):
        raise OptionError(f"table[{key!r}] must hold booleans (or 0/1)")
    return value.astype(bool)


def _checked(key: str, value, n: int | None) -> np.ndarray:
    """Column ``key`` as its dtype, refused (:class:`OptionError`) where the reader would refuse it."""
    value = _column(key, value, n)
    kind = COLUMN_DTYPES.get(key)
    if kind is np.int64:
        return _integers(key, value)
    if kind is np.float64:
        return _floats(key, value)
    if kind is np.bool_:
        return _flags(key, value)
    return value


class HighlightTable(dict):
    """Highlights, one per row: a dict of named columns of equal length; ``len(t)`` highlights.

    The one highlight table: detection (:func:`~shinysim.recon.pipeline.detect_stack`) and decoding
    (:func:`~shinysim.recon.coding.decode`) make it, :meth:`read_csv` reads it back; normals, stereo rays,
    the joint analysis and calibration take it. Every table has the columns of :data:`COLUMN_DTYPES` with
    those dtypes (``docs/file-format.md`` says what each means; ``rel_peak`` and the flags may be left out:
    NaN, False). A producer may add its own columns (the joint analysis' ``x``, ``y``, ``normal`` (N, 3)),
    each with one entry per highlight. ``reference``: the level ``rel_peak`` is relative to (NaN: unknown).

    Raises
    ------
    OptionError
        A missing column, columns of different lengths, or a value the reader would refuse (negative
        area, non-finite position, ...), here or when a column is set.
    """

    def __init__(self, columns: Mapping | None = None, *, reference: float = math.nan):
        super().__init__()
        self.reference = float(reference)
        if columns is None:
            return  # empty: filled by the module's own functions
        if not isinstance(columns, Mapping):
            raise OptionError(f"table must be a dict of columns, got {type(columns).__name__}")
        if isinstance(columns, HighlightTable):  # checked already
            dict.update(self, columns)
            if math.isnan(self.reference):
                self.reference = columns.reference
            return
        missing = [k for k in LEGACY_COLUMNS[:8] if k not in columns]
        if missing:
            raise OptionError(f"table lacks the column(s) {', '.join(map(repr, missing))}")
        n = len(_column("source", columns["source"], None))
        for key in COLUMN_DTYPES:
            if key in columns:
                dict.__setitem__(self, key, _checked(key, columns[key], n))
            else:  # an optional column: rel_peak NaN, flags False
                dict.__setitem__(self, key, np.full(n, np.nan) if key == "rel_peak" else np.zeros(n, bool))
        for key, value in columns.items():
            if key not in COLUMN_DTYPES:
                dict.__setitem__(self, key, _column(key, value, n))

    def __len__(self) -> int:
        return len(dict.__getitem__(self, "source")) if dict.__contains__(self, "source") else 0

    def __setitem__(self, key: str, value) -> None:
        n = len(self) if dict.__contains__(self, "source") else None
        dict.__setitem__(self, key, _checked(key, value, n))

    def __repr__(self) -> str:
        return f"HighlightTable({len(self)} highlights; columns {', '.join(self)})"

    @classmethod
    def _of(cls, columns: dict, reference: float = math.nan) -> HighlightTable:
        """A table of columns already checked (as this module's own functions make them)."""
        out = cls(reference=reference)
        dict.update(out, columns)
        return out

    def select(self, index) -> HighlightTable:
        """The highlights at ``index`` (a boolean mask or indices), every column, in that order."""
        index = np.asarray(index)
        if index.dtype != bool:
            index = index.astype(np.int64, copy=False)
        return self._of({k: v[index] for k, v in self.items()}, self.reference)

    @classmethod
    def concat(cls, tables) -> HighlightTable:
        """The highlights of ``tables`` one after another (the columns every one of them has)."""
        tables = [t if isinstance(t, HighlightTable) else cls(t) for t in tables]
        if not tables:
            return cls(dict.fromkeys(COLUMN_DTYPES, ()))
        keys = [k for k in tables[0] if all(k in t for t in tables[1:])]
        refs = {t.reference for t in tables if not math.isnan(t.reference)}
        return cls._of({k: np.concatenate([t[k] for t in tables]) for k in keys},
                       refs.pop() if len(refs) == 1 else math.nan)

    def write_csv(self, path: str | os.PathLike, normals: Mapping[str, np.ndarray] | None = None, *,
                  overwrite: bool = False) -> Path:
        """Write ``highlights.csv`` (:func:`write_highlight_table`)."""
        return write_highlight_table(path, self, normals, overwrite=overwrite)

    @classmethod
    def read_csv(cls, path: str | os.PathLike, **kwargs) -> tuple[HighlightTable, dict[str, np.ndarray]]:
        """Read ``highlights.csv``: :func:`read_highlight_table`."""
        return read_highlight_table(path, **kwargs)


# -- writing --------------------------------------------------------------------------


def _unit_normals(model: str, n: np.ndarray) -> np.ndarray:
    bad = ~np.isfinite(n)
    missing = np.all(np.isnan(n), axis=1)  # the documented "no normal": all three NaN
    bad[missing] = False
    if np.any(bad):
        i = int(np.argmax(np.any(bad, axis=1)))
        raise OptionError(f"normals[{model!r}] row {i} is {n[i].tolist()}: finite, or all three NaN")
    length = np.linalg.norm(np.where(missing[:, None], 1.0, n), axis=1)
    length[missing] = 1.0
    off = np.abs(length - 1.0) > NORMAL_LENGTH_TOL
    if np.any(off):
        i = int(np.argmax(off))
        raise OptionError(f"normals[{model!r}] row {i} has length {length[i]:.9g}, not 1")
    return n


def format_highlight_table(table: Mapping[str, np.ndarray], normals: Mapping[str, np.ndarray] | None) -> str:
    """The text of a highlight table: header, then one row per highlight and model.

    Parameters
    ----------
    table : HighlightTable, or a dict of (N,) array_like
        ``source``, ``row``, ``col``, ``area``, ``peak``, ``sum``, ``blob``,
        ``part``, and optionally ``rel_peak`` (default NaN, written empty),
        ``interreflection`` and ``saturated`` (default False). Other keys are
        ignored.
    normals : dict of str -> (N, 3) array_like
        Unit normals per model name, written in the order given; a row of
        three NaN (no normal) is written ``nan,nan,nan``. Empty (or None):
        one row per highlight with the model and the normal left empty.

    Returns
    -------
    str
        :data:`HIGHLIGHT_COLUMNS`, then the rows of each model in turn, each
        model's rows in the order of ``table``; ``\\n`` line endings, a final
        newline. Positions have 4 decimals, ``peak``, ``sum`` and
        ``rel_peak`` 6 significant digits, normals 8 decimals.

    Raises
    ------
    OptionError
        A missing column, columns of different lengths, a value the reader
        would refuse (negative area, non-finite position, a normal that is
        not unit length, ...), or a model name that is not letters, digits
        and ``_.+-``.
    """
    # checked again: a column may have been changed in place since the table was made
    cols = HighlightTable(dict(table) if isinstance(table, HighlightTable) else table)
    normals = {} if normals is None else normals
    if not isinstance(normals, Mapping):
        raise OptionError(f"normals must be a dict of model name -> (N, 3) array, got {type(normals).__name__}")
    n = len(cols)
    blocks = {}
    for model, value in normals.items():
        if not isinstance(model, str) or not _MODEL_NAME.fullmatch(model):
            raise OptionError(f"model name must be 1-64 letters, digits or '_.+-', got {model!r}")
        value = np.asarray(value, dtype=float)
        if value.shape != (n, 3):
            raise OptionError(f"normals[{model!r}] must have shape ({n}, 3), got {value.shape}")
        blocks[model] = _unit_normals(model, value)

    prefix = []
    for i in range(n):
        rp = cols["rel_peak"][i]
        prefix.append(
            f"{cols['source'][i]},{cols['row'][i]:.4f},{cols['col'][i]:.4f},{cols['area'][i]},"
            f"{cols['peak'][i]:.6g},{cols['sum'][i]:.6g},{cols['blob'][i]},{cols['part'][i]},"
            f"{'' if math.isnan(rp) else format(rp, '.6g')},"
            f"{int(cols['interreflection'][i])},{int(cols['saturated'][i])}"
        )
    lines = [",".join(HIGHLIGHT_COLUMNS)]
    if not blocks:
        lines.extend(p + ",,,," for p in prefix)
    for model, value in blocks.items():
        for p, (nx, ny, nz) in zip(prefix, value):
            lines.append(f"{p},{model},{nx:.8f},{ny:.8f},{nz:.8f}")
    return "\n".join(lines) + "\n"


def write_highlight_table(path: str | os.PathLike, table: Mapping[str, np.ndarray],
                          normals: Mapping[str, np.ndarray] | None, *, overwrite: bool = False) -> Path:
    """Write :func:`format_highlight_table` to ``path`` (atomic; never clobbers unless ``overwrite``).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    OptionError
        As :func:`format_highlight_table`.
    FileExistsError
        ``path`` exists and ``overwrite`` is False.
    """
    return write_text(path, format_highlight_table(table, normals), overwrite=overwrite)


# -- reading --------------------------------------------------------------------------


def _show(text: str) -> str:
    """A cell's text for a message: quoted, and cut short when long."""
    return repr(text if len(text) <= 40 else text[:37] + "...")


def _read_text(path: Path) -> str:
    """The file's text: UTF-8, an optional byte-order mark, no NUL."""
    return read_text(path, error=HighlightTableError, max_bytes=MAX_TABLE_BYTES, what="highlight table (CSV)",
                     locate=True)


def _split_cells(line: str, number: int, path: Path) -> list[str]:
    if len(line) > _MAX_LINE_CHARS:
        raise HighlightTableError(
            f"is {len(line)} characters long, more than the {_MAX_LINE_CHARS} a line of a highlight table "
            "ever needs: not a highlight table",
            path=path, field=f"line {number}",
        )
    if '"' not in line:
        cells = line.split(",")
        return [c.strip() for c in cells] if _SPACE.search(line) else cells
    try:
        (cells,) = list(csv.reader([line], strict=True))
    except csv.Error as exc:
        raise HighlightTableError(f"malformed CSV: {exc}", path=path, field=f"line {number}") from None
    return [c.strip() for c in cells]


def _check_header(names: list[str], number: int, path: Path) -> None:
    where = f"line {number} (header)"
    if not any(name in HIGHLIGHT_COLUMNS for name in names):
        raise HighlightTableError(
            f"the first line is not a highlight-table header; expected {','.join(HIGHLIGHT_COLUMNS)}",
            path=path, field=where,
        )
    for i, name in enumerate(names):
        if name == "":
            raise HighlightTableError(f"column {i + 1} of the header has no name", path=path, field=where)
        if name not in HIGHLIGHT_COLUMNS:
            raise HighlightTableError(
                f"unknown column {_show(name)}{did_you_mean(name, HIGHLIGHT_COLUMNS)}; "
                f"the columns are {','.join(HIGHLIGHT_COLUMNS)}",
                path=path, field=where,
            )
    dup = [name for name in dict.fromkeys(names) if names.count(name) > 1]
    if dup:
        raise HighlightTableError(f"column(s) {', '.join(map(repr, dup))} appear more than once",
                                  path=path, field=where)
    missing = [name for name in LEGACY_COLUMNS if name not in names]
    if missing:
        raise HighlightTableError(f"the header lacks the column(s) {', '.join(map(repr, missing))}",
                                  path=path, field=where)


class _Cells:
    """Parses the cells of one row, raising with the line and column named."""

    def __init__(self, path: Path, n_sources: int | None, shape: tuple[int, int] | None, models):
        self.path, self.n_sources, self.shape, self.models = path, n_sources, shape, models

    def fail(self, number: int, column: str, message: str):
        raise HighlightTableError(message, path=self.path, field=f"line {number}, column {column!r}")

    def number(self, text: str, number: int, column: str, *, empty_nan: bool = False) -> float:
        """A float (NaN and infinities included); the caller checks the range."""
        if _FLOAT_TEXT.fullmatch(text) or _NONFINITE_TEXT.fullmatch(text):
            return float(text)
        if text == "":
            if empty_nan:
                return math.nan
            self.fail(number, column, "is empty; a number is needed")
        self.fail(number, column, f"not a number: {_show(text)}")

    def integer(self, text: str, number: int, column: str) -> int:
        if _INT_TEXT.fullmatch(text):
            value = int(text)
        elif re.fullmatch(r"[+-]?[0-9]+", text):
            self.fail(number, column, f"integer {_show(text)} is too large")
        elif _FLOAT_TEXT.fullmatch(text) or _NONFINITE_TEXT.fullmatch(text):
            self.fail(number, column, f"must be an integer, got {_show(text)}")
        else:
            self.number(text, number, column)  # raises: empty or not a number
        low = _INT_MIN[column]
        if value < low:
            self.fail(number, column, f"must be >= {low}, got {value}")
        if column == "source" and self.n_sources is not None and value >= self.n_sources:
            self.fail(number, column, f"source {value} does not exist: there are {self.n_sources} sources "
                                      f"(0 to {self.n_sources - 1})")
        return value

    def real(self, text: str, number: int, column: str) -> float:
        value = self.number(text, number, column, empty_nan=column == "rel_peak")
        if column == "rel_peak" and math.isnan(value):  # rel_peak not recorded
            return value
        if not math.isfinite(value):
            self.fail(number, column, f"must be finite, got {_show(text)}")
        if column in ("peak", "sum", "rel_peak") and value < 0:
            self.fail(number, column, f"must be >= 0, got {_show(text)}")
        if column in ("row", "col") and self.shape is not None:
            size = self.shape[0] if column == "row" else self.shape[1]
            if not -0.5 <= value <= size - 0.5:
                what = "height" if column == "row" else "width"
                self.fail(number, column, f"{value:g} is outside the image: {column} must be in "
                                          f"[-0.5, {size - 0.5:g}] for {what} {size}")
        return value

    def flag(self, text: str, number: int, column: str) -> bool:
        if text not in ("0", "1"):
            self.fail(number, column, f"must be 0 or 1, got {_show(text)}")
        return text == "1"

    def model(self, text: str, number: int) -> str:
        if text == "":
            return text
        if not _MODEL_NAME.fullmatch(text):
            self.fail(number, "model", f"model name must be 1-64 letters, digits or '_.+-', got {_show(text)}")
        if self.models is not None and text not in self.models:
            self.fail(number, "model", f"unknown model {_show(text)}{did_you_mean(text, self.models)}; "
                                       f"known: {', '.join(self.models)}")
        return text

    def normal(self, texts: list[str], number: int, model: str) -> tuple[float, float, float]:
        if model == "":
            for column, text in zip(_NORMAL_COLUMNS, texts):
                if text != "":
                    self.fail(number, column, f"a row without a model has no normal; got {_show(text)}")
            return (math.nan, math.nan, math.nan)
        n = [self.number(t, number, c, empty_nan=True) for c, t in zip(_NORMAL_COLUMNS, texts)]
        for column, text, value in zip(_NORMAL_COLUMNS, texts, n):
            if math.isinf(value):
                self.fail(number, column, f"must be finite, got {_show(text)}")
        nan = [math.isnan(v) for v in n]
        if all(nan):
            return tuple(n)  # no normal (the pixel ray missed the reference plane)
        if any(nan):
            column = _NORMAL_COLUMNS[nan.index(True)]
            self.fail(number, column, f"must be finite, got {_show(texts[nan.index(True)])} "
                                      "(a missing normal has all of nx, ny, nz NaN)")
        length = math.sqrt(n[0] ** 2 + n[1] ** 2 + n[2] ** 2)
        if abs(length - 1.0) > NORMAL_LENGTH_TOL:
            raise HighlightTableError(
                f"normal ({n[0]:.9g}, {n[1]:.9g}, {n[2]:.9g}) is not unit length: |n| = {length:.9g}, "
                f"more than {NORMAL_LENGTH_TOL:g} from 1",
                path=self.path, field=f"line {number}, columns 'nx', 'ny', 'nz'",
            )
        return tuple(n)


def _check_options(n_sources, shape, models):
    if n_sources is not None:
        n_sources = check_number("n_sources", n_sources, lo=1, integer=True)
    if shape is not None:
        if isinstance(shape, (str, bytes)) or not isinstance(shape, Iterable):
            raise OptionError(f"shape must be (height, width), got {shape!r}")
        shape = tuple(shape)
        if len(shape) != 2:
            raise OptionError(f"shape must be (height, width), got {shape!r}")
        shape = (check_number("shape[0]", shape[0], lo=1, integer=True),
                 check_number("shape[1]", shape[1], lo=1, integer=True))
    if models is not None:
        if isinstance(models, str):
            models = (models,)
        models = tuple(models)
        if not all(isinstance(m, str) for m in models):
            raise OptionError(f"models must be model names, got {models!r}")
    return n_sources, shape, models


def read_highlight_table(path: str | os.PathLike, *, n_sources: int | None = None,
                         shape: tuple[int, int] | None = None,
                         models: Iterable[str] | None = None) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Read and check a table written by :func:`write_highlight_table`.

    Also reads files with the older header :data:`LEGACY_COLUMNS`, files with
    Windows (``\\r\\n``) or old Mac (``\\r``) line endings and files that
    start with a UTF-8 byte-order mark. Blank lines are skipped; columns may
    come in any order; cells may be quoted.

    Parameters
    ----------
    path : path-like
    n_sources : int, optional
        The rig's number of sources: refuse a ``source`` outside 0..n_sources-1.
    shape : (int, int), optional
        Image (height, width): refuse a ``row`` outside [-0.5, H - 0.5] or a
        ``col`` outside [-0.5, W - 0.5].
    models : iterable of str, optional
        The model names allowed (e.g. ``NORMAL_MODELS``); any name otherwise.

    Returns
    -------
    table : HighlightTable
        ``source``, ``area``, ``blob``, ``part`` (int64), ``row``, ``col``,
        ``peak``, ``sum``, ``rel_peak`` (float64; ``rel_peak`` NaN when not
        recorded), ``interreflection``, ``saturated`` (bool); its
        ``reference`` is not recorded (NaN).
    normals : dict of str -> (N, 3) ndarray
        Per model, in the order of the file; rows of NaN where no normal was
        computed. Empty for a table written without models.

    Raises
    ------
    HighlightTableError
        Anything wrong with the file, naming the file, the line and the
        column: see ``docs/bad-input.md``.
    OptionError
        ``n_sources``, ``shape`` or ``models`` is not valid.
    """
    if not isinstance(path, (str, os.PathLike)):
        raise OptionError(f"path must be a file name, got {type(path).__name__}")
    n_sources, shape, models = _check_options(n_sources, shape, models)
    path = Path(path)
    index, numbers, rows = _split_rows(_read_text(path), path)
    parse = _Cells(path, n_sources, shape, models)
    # The fast path reads a valid file column by column and gives up at the
    # first doubt; the row-by-row path then finds and names the first error.
    parsed = _parse_fast(rows, index, parse)
    if parsed is None:
        parsed = _parse_rows(rows, numbers, index, parse)
    cols, row_models, row_normals = parsed

    numbers = np.asarray(numbers, dtype=np.int64)
    row_models = np.asarray(row_models, dtype=str)
    names = list(dict.fromkeys(row_models.tolist()))
    blocks = {m: np.flatnonzero(row_models == m) for m in names}
    if "" in blocks and len(blocks) > 1:
        named = next(m for m in names if m)
        raise HighlightTableError(
            f"row has no model, but other rows do (model {named!r} from line {numbers[blocks[named][0]]}); "
            "either every row names a model or none does",
            path=path, field=f"line {numbers[blocks[''][0]]}, column 'model'",
        )
    _check_blocks(blocks, cols, numbers, path)

    first = blocks[names[0]] if names else np.zeros(0, np.int64)
    table = HighlightTable._of({column: cols[column][first] for column in _TABLE_COLUMNS})
    normals = {model: row_normals[idx] for model, idx in blocks.items() if model != ""}
    return table, normals


def _split_rows(text: str, path: Path) -> tuple[dict[str, int], list[int], list[list[str]]]:
    """The header's column positions, and each data row's line number and cells."""
    header = None
    numbers, rows = [], []
    for number, line in enumerate(_LINE_BREAK.split(text), start=1):
        if len(line) <= _MAX_LINE_CHARS and line.strip() == "":
            continue  # blank lines are skipped
        cells = _split_cells(line, number, path)
        if header is None:
            _check_header(cells, number, path)
            header = cells
            continue
        if len(cells) != len(header):
            few = "few" if len(cells) < len(header) else "many"
            raise HighlightTableError(
                f"too {few} cells: {len(cells)}, the header has {len(header)} columns",
                path=path, field=f"line {number}",
            )
        numbers.append(number)
        rows.append(cells)
    if header is None:
        raise HighlightTableError("is empty: no header line", path=path)
    return {name: i for i, name in enumerate(header)}, numbers, rows


def _empty_columns(n: int) -> dict[str, np.ndarray]:
    """The per-highlight columns a file leaves out: ``rel_peak`` NaN, flags False."""
    return {"rel_peak": np.full(n, math.nan), "interreflection": np.zeros(n, bool), "saturated": np.zeros(n, bool)}


def _parse_rows(rows, numbers, index, parse: _Cells):
    """Every cell checked row by row: raises at the first bad cell, in file order."""
    values = {column: [] for column in _TABLE_COLUMNS if column in index}
    row_models, row_normals = [], []
    for number, cells in zip(numbers, rows):
        for column, out in values.items():
            text = cells[index[column]]
            if column in _INT_COLUMNS:
                out.append(parse.integer(text, number, column))
            elif column in _FLOAT_COLUMNS:
                out.append(parse.real(text, number, column))
            else:
                out.append(parse.flag(text, number, column))
        model = parse.model(cells[index["model"]], number)
        row_models.append(model)
        row_normals.append(parse.normal([cells[index[c]] for c in _NORMAL_COLUMNS], number, model))
    cols = _empty_columns(len(rows))
    for column, out in values.items():
        cols[column] = np.array(out, dtype=COLUMN_DTYPES[column])
    return cols, row_models, np.array(row_normals, dtype=np.float64).reshape(-1, 3)


_INT_CHARS = frozenset("0123456789+-")
_FLOAT_CHARS = frozenset("0123456789+-.eE")


def _fast_numbers(cells, convert, dtype, *, empty_nan=False):
    """``cells`` converted, or None.

    Over :data:`_FLOAT_CHARS` ``int`` and ``float`` accept exactly what
    :data:`_INT_TEXT` and :data:`_FLOAT_TEXT` match (no spaces, underscores,
    other scripts' digits or words), so this is as strict as :class:`_Cells`.
    """
    if empty_nan:  # an empty cell, or exactly "nan" (as written), is NaN
        cells = [t or "nan" for t in cells]
        text = "".join(t for t in cells if t != "nan")
    else:
        text = "".join(cells)
    if not set(text) <= (_INT_CHARS if convert is int else _FLOAT_CHARS):
        return None
    try:
        return np.fromiter(map(convert, cells), dtype=dtype, count=len(cells))
    except (ValueError, OverflowError):
        return None


def _parse_fast(rows, index, parse: _Cells):
    """What :func:`_parse_rows` returns, read column by column; None at the first doubt.

    Each check here is at least as strict as the row-by-row one, so a file
    accepted here is read to the same values; anything else is left to the
    row-by-row path, which names the first bad cell.
    """
    n = len(rows)
    columns = list(zip(*rows)) if n else [()] * len(index)
    cols = _empty_columns(n)
    for column in _TABLE_COLUMNS:
        if column not in index:
            continue
        cells = columns[index[column]]
        if column in _INT_COLUMNS:
            v = _fast_numbers(cells, int, np.int64) if not n or max(map(len, cells)) <= 18 else None
        elif column in _FLOAT_COLUMNS:
            v = _fast_numbers(cells, float, np.float64, empty_nan=column == "rel_peak")
        else:
            v = np.fromiter((t == "1" for t in cells), dtype=bool, count=n) if set(cells) <= {"0", "1"} else None
        try:  # the table's own checks: integers' least values, finite (rel_peak: or NaN) and >= 0 but row and col
            v = None if v is None else _checked(column, v, None)
        except OptionError:
            return None
        if v is None or (column == "source" and parse.n_sources is not None and n and v.max() >= parse.n_sources):
            return None
        if column in ("row", "col") and parse.shape is not None:
            size = parse.shape[0] if column == "row" else parse.shape[1]
            if np.any(v < -0.5) or np.any(v > size - 0.5):
                return None
        cols[column] = v
    row_models = list(columns[index["model"]])
    names = set(row_models)
    for name in names:
        if name != "" and not (_MODEL_NAME.fullmatch(name) and (parse.models is None or name in parse.models)):
            return None
    if "" in names:
        if len(names) > 1 or any(set(columns[index[c]]) != {""} for c in _NORMAL_COLUMNS):
            return None
        return cols, row_models, np.full((n, 3), math.nan)
    normal = np.zeros((n, 3))
    for k, column in enumerate(_NORMAL_COLUMNS):
        v = _fast_numbers(columns[index[column]], float, np.float64, empty_nan=True)
        if v is None or np.any(np.isinf(v)):
            return None
        normal[:, k] = v
    missing = np.isnan(normal)
    if np.any(missing.any(axis=1) & ~missing.all(axis=1)):
        return None
    length = np.linalg.norm(normal[~missing.all(axis=1)], axis=1)
    if np.any(np.abs(length - 1.0) > NORMAL_LENGTH_TOL):
        return None
    return cols, row_models, normal


def _check_blocks(blocks: dict[str, np.ndarray], cols: dict[str, np.ndarray], numbers: np.ndarray,
                  path: Path) -> None:
    """Every model's block lists the same highlights, in the same order, as the first."""
    if len(blocks) < 2:
        return
    (ref_model, ref), *others = blocks.items()
    for model, idx in others:
        k = min(len(idx), len(ref))
        differ = np.zeros((len(_TABLE_COLUMNS), k), bool)
        for c, column in enumerate(_TABLE_COLUMNS):
            a, b = cols[column][idx[:k]], cols[column][ref[:k]]
            differ[c] = a != b
            if a.dtype.kind == "f":
                differ[c] &= ~(np.isnan(a) & np.isnan(b))
        if differ.any():
            j = int(np.argmax(differ.any(axis=0)))
            column = _TABLE_COLUMNS[int(np.argmax(differ[:, j]))]
            v, r = cols[column][idx[j]].item(), cols[column][ref[j]].item()
            raise HighlightTableError(
                f"model {model!r} lists a different highlight here than model {ref_model!r} "
                f"on line {numbers[ref[j]]} ({column} {v!r} against {r!r}); every model must list "
                "the same highlights in the same order",
                path=path, field=f"line {numbers[idx[j]]}, column {column!r}",
            )
        if len(idx) != len(ref):
            where = numbers[idx[len(ref)]] if len(idx) > len(ref) else numbers[idx[-1]]
            raise HighlightTableError(
                f"model {model!r} lists {len(idx)} highlights, model {ref_model!r} lists {len(ref)}; "
                "every model must list the same highlights in the same order",
                path=path, field=f"line {where}, column 'model'",
            )
