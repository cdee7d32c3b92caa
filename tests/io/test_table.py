"""The three ways a text table is read give the same results (georef.io.table), and hex cells are parsed.

``georef.io.table`` reads a clean file with its compiled reader (:mod:`georef.io.table_kernel`) or, where that
declines (a number with 16 or more significant digits, say), numpy's ``loadtxt``, and anything else with pandas'
C parser, whose results and messages define the rules. The first two exist so that ``georef process`` never
imports pandas (0.35-0.4 s of every run) and reads fast. Here generated tables, clean and with the defects users'
files have, are read all three ways: the values (bit for bit), lines, notices and error messages must agree. The
EO table's writer is checked the same way against pandas in tests/io/test_eo_table.py; the readers' bounds on
pipes and over-long lines in tests/io/test_bounded_inputs.py.
"""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path
from unittest import mock

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import georef.io.table as table_module
from georef.io.errors import InputError
from georef.io.table import InMemory, parse_hex, read_table

DATA = Path(__file__).resolve().parents[2] / "data"
SEPARATORS = ["\t", ",", ";", " "]
#: cells users' files hold that the clean path must hand to pandas (or read exactly as pandas does)
DEFECTS = ["nan", "inf", "-Infinity", '"1.5"', "1e999", "", " 2.5", "2.5 ", "1_0", "0x1F", "１２", "é", "1.5e",
           "+.5", "5.", "-0", "1E+3", "\x0b3", "3\x7f"]


@contextmanager
def _pandas_only():
    """Reading with the clean paths (compiled and numpy) switched off."""
    with mock.patch.object(table_module, "_parse_clean", lambda *_args: None):
        yield


@contextmanager
def _no_compiled_reader():
    """Reading with the compiled reader switched off: numpy's ``loadtxt``, then pandas."""
    with mock.patch.object(table_module, "_parse_compiled", lambda *_args: None):
        yield


def _read(data: bytes, wanted: dict[str, str], short_rows: str) -> object:
    """The table read from ``data``, or the error's type and message."""
    try:
        return read_table(InMemory(Path("t.txt"), data), wanted, required=list(wanted), short_rows=short_rows)
    except InputError as exc:
        return ("error", str(exc))


def _same(a: object, b: object) -> None:
    if isinstance(a, tuple) or isinstance(b, tuple):
        assert a == b
        return
    assert a.header == b.header and a.names == b.names and a.dialect == b.dialect
    assert a.notices == b.notices
    np.testing.assert_array_equal(a.lines, b.lines)
    np.testing.assert_array_equal(a.incomplete, b.incomplete)
    np.testing.assert_array_equal(a.fields, b.fields)
    assert a.columns.keys() == b.columns.keys()
    for name in a.columns:
        assert a.columns[name].dtype == b.columns[name].dtype, name
        if a.columns[name].dtype.kind == "f":  # bit for bit, -0.0 and all
            assert a.columns[name].tobytes() == b.columns[name].tobytes(), name
        else:
            np.testing.assert_array_equal(a.columns[name], b.columns[name])


def _float_text(draw: st.DrawFn) -> str:
    value = draw(st.floats(allow_nan=False, allow_infinity=False, min_value=-1e6, max_value=1e6)
                 | st.floats(allow_nan=False, allow_infinity=False))
    # a logger's fixed decimals (the compiled reader's exact range) and full repr (numpy's or pandas' range)
    style = draw(st.sampled_from(["repr", ".3f", ".5f", ".9f", "e", ".17g", "int", "plus"]))
    if style == "repr":
        return repr(value)
    if style == "int":
        return str(draw(st.integers(-10**18, 10**18)))
    if style == "plus":
        return "+" + format(abs(value), ".6f")
    return format(value, style)


@st.composite
def tables(draw: st.DrawFn) -> tuple[bytes, dict[str, str], str]:
    kinds = draw(st.lists(st.sampled_from(["float", "float", "int", "hex", "str"]), min_size=2, max_size=6))
    sep = draw(st.sampled_from(SEPARATORS))
    names = [f"c{i}" for i in range(len(kinds))]
    rows = []
    for _ in range(draw(st.integers(1, 25))):
        row = []
        for kind in kinds:
            if kind == "float":
                row.append(_float_text(draw))
            elif kind == "int":
                row.append(str(draw(st.integers(-10**15, 10**15))))
            elif kind == "hex":
                text = format(draw(st.integers(0, 2**64 - 1)), draw(st.sampled_from(["x", "X"])))
                row.append(draw(st.sampled_from(["", "0x"])) + text)
            else:
                row.append(draw(st.text("abcXYZ019_-.", min_size=1, max_size=12)))
        rows.append(row)
    defects = draw(st.integers(0, 2))
    for _ in range(defects):
        r, c = draw(st.integers(0, len(rows) - 1)), draw(st.integers(0, len(kinds) - 1))
        rows[r][c] = draw(st.sampled_from(DEFECTS))
    lines = [sep.join(names)] + [sep.join(row) for row in rows]
    if draw(st.integers(0, 9)) == 0:  # a blank line inside
        lines.insert(draw(st.integers(2, len(lines))), "")
    if draw(st.integers(0, 9)) == 0 and len(kinds) > 2:  # a logger that lost power: the last line cut short
        lines[-1] = sep.join(rows[-1][:-1])
    end = draw(st.sampled_from(["\n", "\r\n"]))
    text = end.join(lines) + (end if draw(st.booleans()) else "")
    data = text.encode("utf-8")
    if draw(st.integers(0, 9)) == 0:
        data = b"\xef\xbb\xbf" + data
    return data, dict(zip(names, kinds, strict=True)), draw(st.sampled_from(["error", "keep"]))


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(tables())
def test_the_readers_agree_on_generated_tables(case):
    data, wanted, short_rows = case
    compiled_first = _read(data, wanted, short_rows)
    with _no_compiled_reader():
        numpy_first = _read(data, wanted, short_rows)
    with _pandas_only():
        pandas_only = _read(data, wanted, short_rows)
    _same(compiled_first, pandas_only)
    _same(numpy_first, pandas_only)


@pytest.mark.parametrize("name", ["POS.txt", "Kamera.txt"])
def test_the_bundled_files_take_the_compiled_path_and_read_as_pandas_reads_them(name):
    """The compiled path is really used (a test of it that never ran it would pass), on a real file."""
    from georef.io.camera import read_kamera
    from georef.io.pos import read_pos

    taken = []
    original = table_module._parse_compiled

    def spy(*args):
        result = original(*args)
        taken.append(result is not None)
        return result

    reader = (lambda: read_pos(DATA / name)) if name == "POS.txt" else (lambda: read_kamera(DATA / name))
    with mock.patch.object(table_module, "_parse_compiled", spy):
        fast = reader()
    assert taken == [True]
    with _pandas_only():
        slow = reader()
    if name == "POS.txt":
        assert fast.data.keys() == slow.data.keys()
        for role in fast.data:
            assert fast.data[role].tobytes() == slow.data[role].tobytes(), role
        np.testing.assert_array_equal(fast.time, slow.time)
        assert fast.notices == slow.notices
    else:
        np.testing.assert_array_equal(fast.frame, slow.frame)
        np.testing.assert_array_equal(fast.time, slow.time)


def test_hex_parsing():
    values, bad = parse_hex(np.array(["A4", "ff", "0x1F", " 10 ", "DEADBEEF", "G1", ""]))
    assert values[:5].tolist() == [0xA4, 0xFF, 0x1F, 0x10, 0xDEADBEEF]
    assert bad.tolist() == [False, False, False, False, False, True, True]
