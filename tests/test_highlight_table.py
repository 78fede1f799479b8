"""The highlight table (highlights.csv): round trips, and every malformed input named."""

import time

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from shinysim.errors import HighlightTableError, OptionError
from shinysim.io.table import (
    COLUMN_DTYPES,
    HIGHLIGHT_COLUMNS,
    LEGACY_COLUMNS,
    HighlightTable,
    format_highlight_table,
    read_highlight_table,
    write_highlight_table,
)

MODELS = ("perspective", "orthographic", "fixed")


def random_table(rng, n=6, n_sources=4, shape=(24, 32)):
    """A plausible highlight table and unit normals for ``MODELS``."""
    h, w = shape
    table = {
        "source": rng.integers(0, n_sources, n),
        "row": rng.uniform(0, h - 1, n),
        "col": rng.uniform(0, w - 1, n),
        "area": rng.integers(1, 40, n),
        "peak": rng.uniform(0.1, 5.0, n),
        "sum": rng.uniform(1.0, 300.0, n),
        "blob": rng.integers(1, 5, n),
        "part": rng.integers(0, 3, n),
        "rel_peak": rng.uniform(0.0, 1.0, n),
        "interreflection": rng.uniform(size=n) < 0.5,
        "saturated": rng.uniform(size=n) < 0.3,
    }
    normals = {}
    for m in MODELS:
        v = rng.normal(size=(n, 3))
        normals[m] = v / np.linalg.norm(v, axis=1, keepdims=True)
    return table, normals


def valid_text(n=4, seed=3):
    return format_highlight_table(*random_table(np.random.default_rng(seed), n=n))


def write(tmp_path, text, name="highlights.csv"):
    path = tmp_path / name
    path.write_bytes(text.encode("utf-8") if isinstance(text, str) else text)
    return path


def replace_cell(text, line, column, value):
    """``text`` with the cell of ``column`` on (1-based) ``line`` set to ``value``."""
    lines = text.split("\n")
    header = lines[0].split(",")
    cells = lines[line - 1].split(",")
    cells[header.index(column)] = value
    lines[line - 1] = ",".join(cells)
    return "\n".join(lines)


def replace_in_every_block(text, highlight, column, value, n=4):
    """``text`` (``n`` highlights per model) with one highlight's cell changed in every model's block."""
    for line in range(2 + highlight, 2 + n * len(MODELS), n):
        text = replace_cell(text, line, column, value)
    return text


def read_error(path, **kwargs):
    with pytest.raises(HighlightTableError) as info:
        read_highlight_table(path, **kwargs)
    err = info.value
    assert err.path == str(path)
    assert str(err).startswith(str(path))
    return err


# -- round trips ----------------------------------------------------------------------


def test_roundtrip(tmp_path, np_rng):
    table, normals = random_table(np_rng, n=25)
    table["rel_peak"][3] = np.nan
    normals["fixed"][5] = np.nan  # the pixel ray missed the plane: no normal
    path = write_highlight_table(tmp_path / "highlights.csv", table, normals)
    back, back_normals = read_highlight_table(path, n_sources=4, shape=(24, 32), models=MODELS)
    assert list(back) == list(HIGHLIGHT_COLUMNS[:11])
    for k in ("source", "area", "blob", "part"):
        assert back[k].dtype == np.int64
        np.testing.assert_array_equal(back[k], table[k])
    for k in ("interreflection", "saturated"):
        assert back[k].dtype == bool
        np.testing.assert_array_equal(back[k], table[k])
    # 4 decimals: within half a unit of the last written place
    for k in ("row", "col"):
        np.testing.assert_allclose(back[k], table[k], rtol=0, atol=5e-5)
    # 6 significant digits
    for k in ("peak", "sum", "rel_peak"):
        np.testing.assert_allclose(back[k], table[k], rtol=5e-6, atol=0)
    assert np.isnan(back["rel_peak"][3])
    assert list(back_normals) == list(MODELS)
    for m in MODELS:
        assert back_normals[m].shape == (25, 3)
        # 8 decimals
        np.testing.assert_allclose(back_normals[m], normals[m], rtol=0, atol=5e-9)
    assert np.all(np.isnan(back_normals["fixed"][5]))


def test_format_is_deterministic_models_then_highlights(np_rng):
    table, normals = random_table(np_rng, n=3)
    text = format_highlight_table(table, normals)
    assert text == format_highlight_table(table, normals)
    lines = text.splitlines()
    assert lines[0] == ",".join(HIGHLIGHT_COLUMNS)
    assert [line.split(",")[11] for line in lines[1:]] == [m for m in MODELS for _ in range(3)]
    assert text.endswith("\n") and "\r" not in text


def test_missing_optional_columns_written_as_nan_and_zero(tmp_path, np_rng):
    table, normals = random_table(np_rng, n=3)
    for k in ("rel_peak", "interreflection", "saturated"):
        del table[k]
    back, _ = read_highlight_table(write_highlight_table(tmp_path / "h.csv", table, normals))
    assert np.all(np.isnan(back["rel_peak"]))
    assert not back["interreflection"].any() and not back["saturated"].any()


def test_zero_highlights(tmp_path, np_rng):
    table, normals = random_table(np_rng, n=0)
    path = write_highlight_table(tmp_path / "h.csv", table, normals)
    assert path.read_text() == ",".join(HIGHLIGHT_COLUMNS) + "\n"
    back, back_normals = read_highlight_table(path)
    assert all(len(v) == 0 for v in back.values())
    assert back["source"].dtype == np.int64 and back["row"].dtype == np.float64
    assert back_normals == {}


def test_no_models_written_and_read_as_zero_models(tmp_path, np_rng):
    table, _ = random_table(np_rng, n=5)
    path = write_highlight_table(tmp_path / "h.csv", table, {})
    lines = path.read_text().splitlines()
    assert len(lines) == 6 and all(line.endswith(",,,,") for line in lines[1:])
    back, back_normals = read_highlight_table(path)
    assert back_normals == {}
    np.testing.assert_array_equal(back["source"], table["source"])
    np.testing.assert_allclose(back["row"], table["row"], atol=5e-5, rtol=0)


def test_legacy_file_read(tmp_path):
    text = (",".join(LEGACY_COLUMNS) + "\n"
            "2,10.5000,11.2500,7,0.9,5.5,1,0,perspective,0.00000000,0.00000000,1.00000000\n"
            "2,10.5000,11.2500,7,0.9,5.5,1,0,fixed,0.00000000,0.60000000,0.80000000\n")
    table, normals = read_highlight_table(write(tmp_path, text))
    assert np.isnan(table["rel_peak"]).all()
    assert table["interreflection"].dtype == bool and not table["interreflection"].any()
    assert not table["saturated"].any()
    assert list(normals) == ["perspective", "fixed"]
    np.testing.assert_allclose(normals["fixed"], [[0.0, 0.6, 0.8]])


def test_windows_line_endings_read(tmp_path):
    text = valid_text()
    expected = read_highlight_table(write(tmp_path, text, "unix.csv"))
    got = read_highlight_table(write(tmp_path, text.replace("\n", "\r\n"), "windows.csv"))
    for a, b in zip(expected, got):
        assert a.keys() == b.keys()
        for k in a:
            np.testing.assert_array_equal(a[k], b[k])


def test_bom_read(tmp_path):
    text = valid_text()
    plain = read_highlight_table(write(tmp_path, text, "plain.csv"))
    with_bom = read_highlight_table(write(tmp_path, b"\xef\xbb\xbf" + text.encode(), "bom.csv"))
    for k in plain[0]:
        np.testing.assert_array_equal(plain[0][k], with_bom[0][k])


def test_quoted_cells_and_blank_lines_read(tmp_path):
    text = valid_text(n=2).replace(",perspective,", ',"perspective",') + "\n\n"
    _, normals = read_highlight_table(write(tmp_path, text))
    assert list(normals) == list(MODELS)


# -- the writer refuses what the reader would ------------------------------------------


def test_write_refuses_existing_file(tmp_path, np_rng):
    table, normals = random_table(np_rng, n=2)
    path = write_highlight_table(tmp_path / "h.csv", table, normals)
    with pytest.raises(FileExistsError):
        write_highlight_table(path, table, normals)
    write_highlight_table(path, table, normals, overwrite=True)


@pytest.mark.parametrize("change, words", [
    (lambda t, n: t.pop("blob"), "lacks the column(s) 'blob'"),
    (lambda t, n: t.update(row=t["row"][:-1]), "table['row'] has 5 entries"),
    (lambda t, n: n.update(fixed=n["fixed"][:-1]), "must have shape (6, 3)"),
    (lambda t, n: t.update(area=t["area"] * 0), "table['area'] must be >= 1"),
    (lambda t, n: t["col"].__setitem__(0, np.inf), "table['col'] must be finite"),
    (lambda t, n: n["fixed"].__setitem__(0, [1.0, 1.0, 0.0]), "length 1.41421356"),
    (lambda t, n: n["fixed"].__setitem__((0, 0), np.nan), "all three NaN"),
    (lambda t, n: n.update({"bad,name": n["fixed"]}), "model name must be"),
    (lambda t, n: t.update(saturated=np.full(6, 2)), "booleans"),
])
def test_write_rejects_inconsistent_input(np_rng, change, words):
    table, normals = random_table(np_rng)
    change(table, normals)
    with pytest.raises(OptionError) as info:
        format_highlight_table(table, normals)
    assert words in str(info.value)


# -- bad input, one test per class ------------------------------------------------------


def test_missing_file(tmp_path):
    err = read_error(tmp_path / "nothing.csv")
    assert "no such file" in str(err)


def test_directory(tmp_path):
    err = read_error(tmp_path)
    assert "is a folder" in str(err)


def test_not_utf8_names_byte_offset(tmp_path):
    data = valid_text().encode()
    at = data.index(b"\n", data.index(b"\n") + 1) + 3  # third character of line 3
    data = data[:at] + b"\xff" + data[at + 1:]
    err = read_error(write(tmp_path, data))
    assert err.field == f"line 3, byte {at}"
    assert "not UTF-8" in str(err) and "0xff" in str(err)


def test_latin1_file(tmp_path):
    text = valid_text().replace("perspective", "perspéctive")
    err = read_error(write(tmp_path, text.encode("latin-1")))
    assert "not UTF-8" in str(err) and err.field.startswith("line 2, byte ")


def test_empty_file(tmp_path):
    for content in (b"", b"\n\n", b"\xef\xbb\xbf"):
        err = read_error(write(tmp_path, content))
        assert "no header" in str(err)


def test_not_a_header(tmp_path):
    text = valid_text().split("\n", 1)[1]  # the header left out
    err = read_error(write(tmp_path, text))
    assert err.field == "line 1 (header)" and "not a highlight-table header" in str(err)


def test_header_missing_columns(tmp_path):
    lines = [",".join(c for c in LEGACY_COLUMNS if c not in ("blob", "nz"))]
    err = read_error(write(tmp_path, "\n".join(lines) + "\n"))
    assert "lacks the column(s) 'blob', 'nz'" in str(err)
    assert err.field == "line 1 (header)"


def test_header_unknown_column_suggests(tmp_path):
    text = valid_text().replace(",rel_peak,", ",relpeak,", 1)
    err = read_error(write(tmp_path, text))
    assert "unknown column 'relpeak' (did you mean 'rel_peak'?)" in str(err)


def test_header_empty_column_name(tmp_path):
    text = valid_text().replace("\n", ",\n", 1)
    err = read_error(write(tmp_path, text))
    assert "column 16 of the header has no name" in str(err)


def test_header_duplicated_column(tmp_path):
    text = valid_text().replace(",saturated,", ",peak,", 1)
    err = read_error(write(tmp_path, text))
    assert "'peak' appear more than once" in str(err)


def test_row_too_few_cells(tmp_path):
    lines = valid_text().split("\n")
    lines[4] = lines[4].rsplit(",", 1)[0]
    err = read_error(write(tmp_path, "\n".join(lines)))
    assert err.field == "line 5" and "too few cells: 14" in str(err)


def test_row_too_many_cells(tmp_path):
    lines = valid_text().split("\n")
    lines[2] += ",0.5"
    err = read_error(write(tmp_path, "\n".join(lines)))
    assert err.field == "line 3" and "too many cells: 16, the header has 15" in str(err)


def test_malformed_quoting(tmp_path):
    text = valid_text().replace(",perspective,", ',"perspective,', 1)
    err = read_error(write(tmp_path, text))
    assert err.field == "line 2" and "malformed CSV" in str(err)


@pytest.mark.parametrize("column, value", [
    ("row", "abc"), ("peak", ""), ("nx", "0.5.1"), ("sum", "1,5"), ("col", "١٢"), ("rel_peak", "x"),
])
def test_non_numeric_cell(tmp_path, column, value):
    text = replace_cell(valid_text(), 3, column, value)
    if value == "1,5":  # a decimal comma: the cell count is now wrong
        assert "too many cells" in str(read_error(write(tmp_path, text)))
        return
    err = read_error(write(tmp_path, text))
    assert err.field == f"line 3, column {column!r}"
    assert (repr(value) in str(err)) if value else ("is empty" in str(err))


@pytest.mark.parametrize("column, value, words", [
    ("area", "3.5", "must be an integer, got '3.5'"),
    ("source", "1e2", "must be an integer, got '1e2'"),
    ("blob", "nan", "must be an integer, got 'nan'"),
    ("part", "99999999999999999999999", "is too large"),
    ("source", "two", "not a number: 'two'"),
])
def test_non_integer_in_integer_column(tmp_path, column, value, words):
    err = read_error(write(tmp_path, replace_cell(valid_text(), 4, column, value)))
    assert err.field == f"line 4, column {column!r}" and words in str(err)


@pytest.mark.parametrize("column", ["row", "col", "peak", "sum", "rel_peak"])
@pytest.mark.parametrize("value", ["nan", "inf", "-Infinity", "1e999"])
def test_non_finite_value(tmp_path, column, value):
    if column == "rel_peak" and value == "nan":
        return  # rel_peak may be unknown
    err = read_error(write(tmp_path, replace_cell(valid_text(), 2, column, value)))
    assert err.field == f"line 2, column {column!r}"
    assert "must be finite" in str(err) or "must be >= 0" in str(err)


@pytest.mark.parametrize("values, words", [
    (("inf", "0", "0"), "column 'nx'"),
    (("0", "nan", "1"), "a missing normal has all of nx, ny, nz NaN"),
    (("0", "", "1"), "column 'ny'"),
])
def test_non_finite_normal(tmp_path, values, words):
    text = valid_text()
    for column, value in zip(("nx", "ny", "nz"), values):
        text = replace_cell(text, 2, column, value)
    err = read_error(write(tmp_path, text))
    assert err.field.startswith("line 2, column ") and words in str(err)


def test_missing_normal_all_nan_reads_as_nan(tmp_path):
    text = valid_text()
    for column in ("nx", "ny", "nz"):
        text = replace_cell(text, 2, column, "nan")
    _, normals = read_highlight_table(write(tmp_path, text))
    assert np.isnan(normals["perspective"][0]).all()
    assert np.isfinite(normals["perspective"][1:]).all()


@pytest.mark.parametrize("column, value, words", [
    ("area", "0", "must be >= 1, got 0"),
    ("blob", "-1", "must be >= 1, got -1"),
    ("source", "-1", "must be >= 0, got -1"),
    ("part", "-3", "must be >= 0, got -3"),
    ("peak", "-0.5", "must be >= 0, got '-0.5'"),
    ("sum", "-2", "must be >= 0"),
    ("rel_peak", "-0.1", "must be >= 0"),
])
def test_negative_value(tmp_path, column, value, words):
    err = read_error(write(tmp_path, replace_cell(valid_text(), 5, column, value)))
    assert err.field == f"line 5, column {column!r}" and words in str(err)


def test_source_beyond_n_sources(tmp_path):
    path = write(tmp_path, replace_in_every_block(valid_text(), 1, "source", "4"))
    read_highlight_table(path, n_sources=5)
    err = read_error(path, n_sources=4)
    assert err.field == "line 3, column 'source'"
    assert "source 4 does not exist: there are 4 sources (0 to 3)" in str(err)


@pytest.mark.parametrize("column, value", [("row", "23.6"), ("row", "-0.6"), ("col", "31.5001"), ("col", "-1")])
def test_position_outside_image(tmp_path, column, value):
    text = valid_text()
    edge = replace_in_every_block(replace_in_every_block(text, 0, "row", "23.5"), 1, "col", "-0.5")
    read_highlight_table(write(tmp_path, edge, "edge.csv"), shape=(24, 32))  # the image's edges are inside
    path = write(tmp_path, replace_in_every_block(text, 0, column, value))
    read_highlight_table(path)  # no shape given: not checked
    err = read_error(path, shape=(24, 32))
    assert err.field == f"line 2, column {column!r}" and "outside the image" in str(err)


def test_unknown_model_suggests(tmp_path):
    text = valid_text().replace(",orthographic,", ",orthographc,")
    path = write(tmp_path, text)
    assert "orthographc" in read_highlight_table(path)[1]  # any name without ``models``
    err = read_error(path, models=MODELS)
    assert err.field == "line 6, column 'model'"
    assert "unknown model 'orthographc' (did you mean 'orthographic'?)" in str(err)


def test_invalid_model_name(tmp_path):
    err = read_error(write(tmp_path, valid_text().replace(",fixed,", ",fixed model,", 1)))
    assert err.field == "line 10, column 'model'" and "model name must be" in str(err)


def test_normal_not_unit_length(tmp_path):
    text = valid_text()
    for column, value in zip(("nx", "ny", "nz"), ("0.6", "0.6", "0.6")):
        text = replace_cell(text, 7, column, value)
    err = read_error(write(tmp_path, text))
    assert err.field == "line 7, columns 'nx', 'ny', 'nz'"
    assert "not unit length: |n| = 1.03923048" in str(err)


def test_normal_rounded_to_written_decimals_is_unit(tmp_path):
    text = valid_text()
    for column, value in zip(("nx", "ny", "nz"), ("0.57735027", "0.57735027", "0.57735027")):
        text = replace_cell(text, 7, column, value)
    read_highlight_table(write(tmp_path, text))


def test_model_blocks_differ_in_length(tmp_path):
    lines = valid_text().split("\n")
    del lines[8]  # the last orthographic row (lines 6-9 on disk)
    err = read_error(write(tmp_path, "\n".join(lines)))
    assert err.field == "line 8, column 'model'"
    assert "model 'orthographic' lists 3 highlights, model 'perspective' lists 4" in str(err)


def test_model_blocks_differ_in_highlights(tmp_path):
    err = read_error(write(tmp_path, replace_cell(valid_text(), 11, "row", "3.25")))
    assert err.field == "line 11, column 'row'"
    assert "model 'fixed' lists a different highlight here than model 'perspective' on line 3" in str(err)


def test_mixed_empty_and_named_models(tmp_path):
    text = valid_text()
    for column in ("model", "nx", "ny", "nz"):
        text = replace_cell(text, 4, column, "")
    err = read_error(write(tmp_path, text))
    assert err.field == "line 4, column 'model'" and "either every row names a model or none does" in str(err)


def test_row_without_model_has_no_normal(tmp_path, np_rng):
    table, _ = random_table(np_rng, n=2)
    text = format_highlight_table(table, {})
    err = read_error(write(tmp_path, replace_cell(text, 3, "nz", "1")))
    assert err.field == "line 3, column 'nz'" and "a row without a model has no normal" in str(err)


@pytest.mark.parametrize("value", ["2", "true", "", "0.0", "-1"])
def test_flag_not_zero_or_one(tmp_path, value):
    err = read_error(write(tmp_path, replace_cell(valid_text(), 2, "saturated", value)))
    assert err.field == "line 2, column 'saturated'" and "must be 0 or 1" in str(err)


def test_nul_byte(tmp_path):
    data = valid_text().encode()
    at = data.index(b"\n") + 5
    err = read_error(write(tmp_path, data[:at] + b"\x00" + data[at:]))
    assert err.field == f"line 2, byte {at}" and "NUL" in str(err)
    err = read_error(write(tmp_path, valid_text().encode("utf-16")))
    assert "NUL" in str(err)


def test_very_long_line_fails_fast(tmp_path):
    for junk in ("7" * 10_000_000, '"' + "a" * 10_000_000, " " * 10_000_000):
        start = time.perf_counter()
        err = read_error(write(tmp_path, valid_text() + junk + "\n"))
        assert time.perf_counter() - start < 2.0
        assert err.field == "line 14" and "characters long" in str(err)
    err = read_error(write(tmp_path, "a" * 10_000_000))
    assert err.field == "line 1"


def test_bad_options():
    with pytest.raises(OptionError):
        read_highlight_table("h.csv", n_sources=0)
    with pytest.raises(OptionError):
        read_highlight_table("h.csv", shape=(24,))
    with pytest.raises(OptionError):
        read_highlight_table(None)


# -- anything else: only HighlightTableError or a successful read -------------------------

_TRICKY = ["", "nan", "inf", "-1", "0", "1", "2", "1e999", "0.5", "abc", '"', '"x"', "1,2", "\x00",
           "\r", "\n", "١", "\ufeff", "0.60000000", " 3 ", "+4", "-0", "1e-400", "99999999999999999999"]


def _mutated(data):
    lines = valid_text(n=3, seed=data.draw(st.integers(0, 5))).split("\n")
    for _ in range(data.draw(st.integers(0, 3))):
        op = data.draw(st.sampled_from(["delete", "duplicate", "swap", "insert", "truncate", "cell"]))
        i = data.draw(st.integers(0, len(lines) - 1))
        j = data.draw(st.integers(0, len(lines) - 1))
        if op == "delete" and len(lines) > 1:
            del lines[i]
        elif op == "duplicate":
            lines.insert(j, lines[i])
        elif op == "swap":
            lines[i], lines[j] = lines[j], lines[i]
        elif op == "insert":
            lines.insert(i, data.draw(st.text(max_size=40)))
        elif op == "truncate":
            lines[i] = lines[i][: data.draw(st.integers(0, max(0, len(lines[i]))))]
        else:
            cells = lines[i].split(",")
            k = data.draw(st.integers(0, len(cells) - 1))
            cells[k] = data.draw(st.one_of(st.sampled_from(_TRICKY), st.text(max_size=8)))
            lines[i] = ",".join(cells)
    text = "\n".join(lines)
    encoding = data.draw(st.sampled_from(["utf-8", "utf-8-crlf", "utf-8-bom"]))
    if encoding == "utf-8-crlf":
        text = text.replace("\n", "\r\n")
    raw = text.encode("utf-8", "surrogatepass")
    return b"\xef\xbb\xbf" + raw if encoding == "utf-8-bom" else raw


@settings(max_examples=300, deadline=None, database=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_fuzz_only_highlight_table_errors(tmp_path_factory, data):
    kind = data.draw(st.sampled_from(["bytes", "text", "mutated"]))
    if kind == "bytes":
        raw = data.draw(st.binary(max_size=600))
    elif kind == "text":
        raw = data.draw(st.text(max_size=300)).encode("utf-8", "surrogatepass")
    else:
        raw = _mutated(data)
    options = data.draw(st.sampled_from([{}, {"n_sources": 4, "shape": (24, 32), "models": MODELS}]))
    path = tmp_path_factory.getbasetemp() / "fuzz.csv"
    path.write_bytes(raw)
    try:
        table, normals = read_highlight_table(path, **options)
    except HighlightTableError as err:
        assert str(err).startswith(str(path))
        return
    n = len(table["source"])
    assert list(table) == list(HIGHLIGHT_COLUMNS[:11])
    assert all(len(v) == n for v in table.values())
    assert all(v.shape == (n, 3) for v in normals.values())
    assert np.all(table["area"] >= 1) and np.all(np.isfinite(table["row"]))


@settings(max_examples=300, deadline=None, database=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_fuzz_column_reader_agrees_with_row_reader(tmp_path_factory, data):
    # A valid file is read column by column; at the first doubt the reader
    # falls back to checking row by row. Both must accept the same files and
    # give the same values.
    from shinysim.io import table as module

    raw = _mutated(data)
    path = tmp_path_factory.getbasetemp() / "agree.csv"
    options = data.draw(st.sampled_from([(None, None, None), (4, (24, 32), MODELS)]))
    parse = module._Cells(path, *options)
    try:
        index, numbers, rows = module._split_rows(raw.decode("utf-8-sig"), path)
    except (HighlightTableError, UnicodeDecodeError):
        return
    fast = module._parse_fast(rows, index, parse)
    try:
        slow = module._parse_rows(rows, numbers, index, parse)
    except HighlightTableError:
        assert fast is None
        return
    if fast is not None:
        for k in slow[0]:
            assert fast[0][k].dtype == slow[0][k].dtype
            np.testing.assert_array_equal(fast[0][k], slow[0][k])
        assert list(fast[1]) == list(slow[1])
        np.testing.assert_array_equal(fast[2], slow[2])


def test_valid_table_is_read_column_by_column(tmp_path, np_rng):
    # the row-by-row path is for finding errors; a valid file never needs it
    from shinysim.io import table as module

    table, normals = random_table(np_rng, n=50)
    table["rel_peak"][:3] = np.nan
    normals["fixed"][7] = np.nan
    for text in (format_highlight_table(table, normals), format_highlight_table(table, {})):
        index, _, rows = module._split_rows(text, tmp_path / "h.csv")
        parse = module._Cells(tmp_path / "h.csv", 4, (24, 32), MODELS)
        assert module._parse_fast(rows, index, parse) is not None


# -- the table type ------------------------------------------------------------------------


def test_table_fills_optional_columns_and_fixes_dtypes(np_rng):
    table, _ = random_table(np_rng, n=5)
    for k in ("rel_peak", "interreflection", "saturated"):
        del table[k]
    table["area"] = table["area"].astype(float)  # whole numbers of another dtype are taken
    t = HighlightTable(table, reference=2.0)
    assert len(t) == 5 and list(t) == list(HIGHLIGHT_COLUMNS[:11]) and t.reference == 2.0
    assert {k: t[k].dtype for k in t} == {k: np.dtype(v) for k, v in COLUMN_DTYPES.items()}
    assert np.all(np.isnan(t["rel_peak"])) and not t["interreflection"].any() and not t["saturated"].any()
    assert HighlightTable(t).reference == 2.0


def test_table_checks_columns_when_set(np_rng):
    t = HighlightTable(random_table(np_rng, n=4)[0])
    t["x"] = np.zeros(4)
    t["normal"] = np.zeros((4, 3))  # a producer's own column: one entry (of any shape) per highlight
    with pytest.raises(OptionError, match=r"table\['y'\] has 3 entries"):
        t["y"] = np.zeros(3)
    with pytest.raises(OptionError, match=r"table\['area'\] must be >= 1"):
        t["area"] = np.zeros(4)
    with pytest.raises(OptionError, match="one-dimensional"):
        t["row"] = np.zeros((4, 2))
    with pytest.raises(OptionError, match="dict of columns"):
        HighlightTable([1, 2])
    t["col"][0] = np.inf  # changed in place: the writer checks again
    with pytest.raises(OptionError, match=r"table\['col'\] must be finite"):
        format_highlight_table(t, {})


def test_table_select_and_concat(np_rng):
    a = HighlightTable(random_table(np_rng, n=5)[0], reference=3.0)
    a["normal"] = np.arange(15.0).reshape(5, 3)
    b = HighlightTable(random_table(np_rng, n=2)[0], reference=3.0)
    part = a.select(a["source"] == a["source"][0])
    assert len(part) == np.count_nonzero(a["source"] == a["source"][0]) and part.reference == 3.0
    np.testing.assert_array_equal(part["normal"], a["normal"][a["source"] == a["source"][0]])
    np.testing.assert_array_equal(a.select([4, 0])["row"], a["row"][[4, 0]])
    both = HighlightTable.concat([a, b])
    assert len(both) == 7 and "normal" not in both and both.reference == 3.0  # the columns both have
    np.testing.assert_array_equal(both["col"], np.r_[a["col"], b["col"]])
    assert len(HighlightTable.concat([])) == 0


def test_table_pickles_and_writes_as_the_functions_do(tmp_path, np_rng):
    import pickle

    table, normals = random_table(np_rng, n=4)
    t = HighlightTable(table, reference=1.5)
    back = pickle.loads(pickle.dumps(t))
    assert type(back) is HighlightTable and back.reference == 1.5
    np.testing.assert_array_equal(back["row"], t["row"])
    assert format_highlight_table(t, normals) == format_highlight_table(table, normals)
    read, read_normals = HighlightTable.read_csv(t.write_csv(tmp_path / "h.csv", normals))
    assert type(read) is HighlightTable and len(read) == 4 and list(read_normals) == list(MODELS)
