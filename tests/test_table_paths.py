"""The three ways a text table is read, and the EO table's two writers, give the same results.

``georef.io.table`` reads a clean file with its compiled reader (:mod:`georef.io.table_kernel`) or, where that
declines (a number with 16 or more significant digits, say), numpy's ``loadtxt``, and anything else with pandas'
C parser, whose results and messages define the rules; ``georef.io.eo_table`` writes the CSV table with the
``csv`` module where pandas' ``to_csv`` once did. They exist so that ``georef process`` never imports pandas
(0.35-0.4 s of every run) and reads fast. Here generated tables, clean and with the defects users' files have,
are read all three ways, and generated EO tables are written both ways: the values (bit for bit), lines,
notices and error messages, and the bytes, must agree.
"""

from __future__ import annotations

import subprocess
import sys
from contextlib import contextmanager
from pathlib import Path
from unittest import mock

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import georef.io.table as table_module
from georef.io.eo_table import _FORMATS, write_eo_csv
from georef.io.errors import InputError
from georef.io.table import InMemory, read_table

DATA = Path(__file__).resolve().parents[1] / "data"
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


def _pandas_csv(frame: pd.DataFrame) -> str:
    """The EO table as its writer wrote it with pandas (rounded per column, then ``to_csv``)."""
    rounded = frame.copy()
    for column, decimals in _FORMATS.items():
        if column in rounded:
            rounded[column] = rounded[column].round(decimals)
    return rounded.to_csv(index=False, lineterminator="\n")


@st.composite
def eo_tables(draw: st.DrawFn) -> dict[str, np.ndarray]:
    n = draw(st.integers(0, 12))
    floats = st.floats(allow_infinity=False) | st.sampled_from([0.0, -0.0, 1e16, 1e-7, 123456789.123456789])
    text = st.text(st.sampled_from(list("ab ,;\"'\n\r\t;é_-()1")), max_size=10)
    columns = {"frame": np.array(draw(st.lists(text, min_size=n, max_size=n)), dtype=object)}
    if draw(st.booleans()):
        columns["image"] = np.array(draw(st.lists(text, min_size=n, max_size=n)), dtype=object)
    for name in draw(st.lists(st.sampled_from([*_FORMATS, "other"]), unique=True, max_size=8)):
        columns[name] = np.array(draw(st.lists(floats, min_size=n, max_size=n)), dtype=float)
    if draw(st.booleans()):
        columns["count"] = np.array(draw(st.lists(st.integers(-10**6, 10**6), min_size=n, max_size=n)), dtype=int)
    columns["flag"] = np.array(draw(st.lists(text, min_size=n, max_size=n)), dtype=object)
    return columns


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")  # rounding 1e308 to 10 decimals
@settings(max_examples=200, deadline=None)
@given(eo_tables())
def test_the_eo_csv_is_written_as_pandas_wrote_it(columns):
    import tempfile

    frame = pd.DataFrame(columns)
    with tempfile.TemporaryDirectory() as folder:
        for source in (columns, frame):  # columns (the CLI) or a DataFrame (a library user)
            path = write_eo_csv(source, Path(folder) / "eo.csv")
            assert path.read_bytes().decode("utf-8") == _pandas_csv(frame)


def test_process_writing_the_csv_table_never_imports_pandas(tmp_path):
    """``georef process`` on the bundled flight, the CSV table and QC: pandas (0.35-0.4 s) is not loaded; a
    summary on the terminal neither."""
    code = ("import sys\nfrom georef_cli.main import app\ntry:\n"
            f"    app(['process', {str(DATA / 'POS.txt')!r}, {str(DATA / 'Kamera.txt')!r}, '--config', "
            f"{str(DATA / 'flight.toml')!r}, '-o', {str(tmp_path / 'eo.csv')!r}])\n"
            "except SystemExit as exc:\n    assert exc.code in (0, None), exc.code\n"
            "print('pandas' in sys.modules, file=sys.stderr)\n")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False)
    assert run.returncode == 0, run.stderr[-2000:]
    assert run.stderr.strip().splitlines()[-1] == "False", run.stderr[-2000:]
    assert (tmp_path / "eo.csv").stat().st_size > 0
