"""The EO table (georef.io.eo_table): written with the ``csv`` module as pandas' ``to_csv`` once wrote it, byte
for byte, on generated tables; ``georef process`` writing it never imports pandas; a table read back."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from georef.io.eo_table import _FORMATS, read_eo_csv, write_eo_csv

DATA = Path(__file__).resolve().parents[2] / "data"


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


def test_eo_table_round_trip(tmp_path):
    table = pd.DataFrame({"frame": ["001", "002"], "time": [1.0, 2.0], "lat": [44.1, np.nan],
                          "lon": [15.6, np.nan], "height": [700.0, np.nan], "flag": ["", "outside navigation span"]})
    write_eo_csv(table, tmp_path / "eo.csv")
    back = read_eo_csv(tmp_path / "eo.csv")
    assert back["frame"].tolist() == ["001", "002"]
    assert np.isnan(back["lat"][1]) and back["flag"][1] == "outside navigation span"
