"""Bad input never produces a traceback or a silently missing frame.

Each case gets either a message naming the file, line and column, or a flagged row.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from georef_cli.main import app
from typer.testing import CliRunner

from georef.io.errors import GeorefError, InputError
from georef.io.pos import read_pos
from georef.pipeline import process

RUNNER = CliRunner()


@pytest.fixture()
def files(flight_dir, tmp_path) -> dict[str, Path]:
    _, paths = flight_dir
    out = {}
    for name in ("POS.txt", "Kamera.txt", "flight.toml"):
        out[name] = tmp_path / name
        shutil.copy(paths[name], out[name])
    return out


def _lines(path: Path) -> list[str]:
    return path.read_text().splitlines(keepends=True)


def _set_cell(path: Path, index: int, column: int, text: str) -> None:
    """Overwrite one tab-separated cell (0-based line index, 0-based column) of a file."""
    lines = _lines(path)
    cells = lines[index].rstrip("\n").split("\t")
    cells[column] = text
    lines[index] = "\t".join(cells) + "\n"
    path.write_text("".join(lines))


def _cli(files: dict[str, Path], *extra: str):
    result = RUNNER.invoke(app, ["process", str(files["POS.txt"]), str(files["Kamera.txt"]), "--config",
                                 str(files["flight.toml"]), "-o", str(files["POS.txt"].parent / "eo.csv"),
                                 *extra])
    assert "Traceback" not in result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)
    return result


@pytest.mark.parametrize("method, column", [("rts", "ACCS_Y"), ("ekf", "OMGS_Z"), ("axis", "IACC_Y")])
def test_missing_column(files, flight_config, method, column):
    frame = pd.read_csv(files["POS.txt"], sep="\t", dtype=str).drop(columns=[column])
    frame.to_csv(files["POS.txt"], sep="\t", index=False)
    with pytest.raises(InputError) as info:
        process(files["POS.txt"], files["Kamera.txt"], flight_config.updated(method=method))
    assert info.value.line == 1 and info.value.column == column
    result = _cli(files, "--method", method)
    assert result.exit_code == 2
    assert f"POS.txt, line 1, column '{column}'" in result.output and "missing" in result.output


def test_non_numeric_cell(files, flight_config):
    _set_cell(files["POS.txt"], 500, 4, "1.2.3")  # IACC_X
    with pytest.raises(InputError) as info:
        process(files["POS.txt"], files["Kamera.txt"], flight_config)
    assert (info.value.line, info.value.column) == (501, "IACC_X")
    assert "'1.2.3'" in str(info.value)
    result = _cli(files)
    assert result.exit_code == 2 and "line 501, column 'IACC_X'" in result.output


def test_non_numeric_hex_cell(files, flight_config):
    _set_cell(files["POS.txt"], 42, 0, "G7")  # CNT[HEX]
    with pytest.raises(InputError) as info:
        process(files["POS.txt"], files["Kamera.txt"], flight_config)
    assert (info.value.line, info.value.column) == (43, "CNT[HEX]")


def test_truncated_last_line_is_dropped_with_a_notice(files, flight_config):
    text = files["POS.txt"].read_text()
    files["POS.txt"].write_text(text[: len(text) - 40])  # cut inside the last line, no newline
    n_lines = len(_lines(files["POS.txt"]))
    result = process(files["POS.txt"], files["Kamera.txt"], flight_config)
    assert len(result.log) == n_lines - 2
    notes = [str(n) for n in result.notices if "truncated" in str(n)]
    assert notes and f"line {n_lines}" in notes[0]
    assert len(result.table) == len(pd.read_csv(files["Kamera.txt"], sep="\t"))


@pytest.mark.parametrize("name", ["POS.txt", "Kamera.txt"])
def test_empty_file(files, flight_config, name):
    files[name].write_text("")
    with pytest.raises(InputError) as info:
        process(files["POS.txt"], files["Kamera.txt"], flight_config)
    assert info.value.line == 1 and "empty" in str(info.value) and name in str(info.value)
    result = _cli(files)
    assert result.exit_code == 2 and "empty" in result.output


def test_header_only_file(files, flight_config):
    files["Kamera.txt"].write_text("Number\tTime\tMilliseconds\n")
    with pytest.raises(InputError, match="no data rows"):
        process(files["POS.txt"], files["Kamera.txt"], flight_config)


def test_time_going_backwards(files, flight_config):
    lines = _lines(files["POS.txt"])
    lines[3000], lines[3001] = lines[3001], lines[3000]
    files["POS.txt"].write_text("".join(lines))
    with pytest.raises(InputError) as info:
        read_pos(files["POS.txt"])
    assert info.value.line == 3002 and "TRIG_TIME" in info.value.column
    assert "backwards" in str(info.value)
    result = _cli(files)
    assert result.exit_code == 2 and "line 3002" in result.output


def test_duplicate_rows_are_dropped_and_reported(files, flight_config):
    lines = _lines(files["POS.txt"])
    lines.insert(1001, lines[1000])
    files["POS.txt"].write_text("".join(lines))
    result = process(files["POS.txt"], files["Kamera.txt"], flight_config)
    notes = [str(n) for n in result.notices if "duplicate row" in str(n)]
    assert notes and "line 1002" in notes[0]
    assert len(result.log) == len(lines) - 2


def test_same_time_different_values_is_an_error(files):
    lines = _lines(files["POS.txt"])
    cells = lines[1000].split("\t")
    cells[1] = "9.99"
    lines.insert(1001, "\t".join(cells))
    files["POS.txt"].write_text("".join(lines))
    with pytest.raises(InputError, match="same time stamp"):
        read_pos(files["POS.txt"])


def test_no_gnss_fix_at_all(files, flight_config):
    frame = pd.read_csv(files["POS.txt"], sep="\t", dtype=str)
    for column in ("LATITUDE", "LONGITUDE", "ALTITUDE"):
        frame[column] = "0"
    frame.to_csv(files["POS.txt"], sep="\t", index=False)
    with pytest.raises(GeorefError, match="no usable GNSS fix"):
        process(files["POS.txt"], files["Kamera.txt"], flight_config)
    result = _cli(files)
    assert result.exit_code == 2 and "LATITUDE" in result.output


def test_camera_times_outside_the_pos_span_get_flagged_rows(files, flight_config):
    kamera = pd.read_csv(files["Kamera.txt"], sep="\t")
    first, last = kamera["Time"].min(), kamera["Time"].max()
    extra = pd.DataFrame({"Number": [9001, 9002, 9003], "Time": [first - 60, last + 30, last + 3600],
                          "Milliseconds": [0, 500, 250]})
    pd.concat([extra.iloc[:1], kamera, extra.iloc[1:]]).to_csv(files["Kamera.txt"], sep="\t", index=False)
    result = process(files["POS.txt"], files["Kamera.txt"], flight_config)
    table = result.table
    assert len(table) == len(kamera) + 3
    outside = table[table["frame"].isin(["9001", "9002", "9003"])]
    assert outside["flag"].str.contains("outside navigation span").all()
    assert outside[["lat", "lon", "height", "roll", "pitch", "yaw"]].isna().all().all()
    assert result.summary()["frames_outside_span"] == 3
    cli = _cli(files)
    assert cli.exit_code == 0 and "outside nav span" in cli.output


def test_camera_milliseconds_out_of_range(files, flight_config):
    _set_cell(files["Kamera.txt"], 10, 2, "1200")
    with pytest.raises(InputError) as info:
        process(files["POS.txt"], files["Kamera.txt"], flight_config)
    assert (info.value.line, info.value.column) == (11, "Milliseconds")


def test_duplicate_frame_numbers_are_kept_and_flagged(files, flight_config):
    lines = _lines(files["Kamera.txt"])
    lines.insert(21, lines[20])
    files["Kamera.txt"].write_text("".join(lines))
    result = process(files["POS.txt"], files["Kamera.txt"], flight_config)
    assert len(result.table) == len(lines) - 1
    assert (result.table["flag"].str.contains("duplicate frame number")).sum() == 2


def test_empty_cell_in_required_column(files, flight_config):
    _set_cell(files["POS.txt"], 700, 15, "")  # YAW
    with pytest.raises(InputError) as info:
        process(files["POS.txt"], files["Kamera.txt"], flight_config)
    assert (info.value.line, info.value.column) == (701, "YAW")


def test_missing_file_and_bad_option_values(files, tmp_path):
    result = RUNNER.invoke(app, ["process", str(tmp_path / "nope.txt"), str(files["Kamera.txt"])])
    assert result.exit_code == 2 and "file not found" in result.output
    result = _cli(files, "--gnss-lever-arm", "1,2")
    assert result.exit_code == 2 and "three comma-separated numbers" in result.output
    result = _cli(files, "--crs", "EPSG:4326")
    assert result.exit_code == 2 and "not a projected CRS" in result.output


def test_raw_camera_log_requires_utc_offset(files, flight_config, tmp_path):
    kamera = pd.read_csv(files["Kamera.txt"], sep="\t")
    local = kamera["Time"] + 7200
    raw = pd.DataFrame({
        "Number": kamera["Number"],
        "Time": [f"{s // 3600:02d}:{s // 60 % 60:02d}:{s % 60:02d}" for s in local],
        "Milliseconds": kamera["Milliseconds"], "Exposition": 10, "Exposition unit": "ms", "Gain": 1,
        "Bit depth": 12, "Shift": 0,
    })
    raw_path = tmp_path / "camera_raw.txt"
    raw.to_csv(raw_path, sep="\t", index=False)
    with pytest.raises(InputError, match="UTC offset"):
        process(files["POS.txt"], raw_path, flight_config)
    result = process(files["POS.txt"], raw_path, flight_config.updated(camera_utc_offset=2.0))
    reference = process(files["POS.txt"], files["Kamera.txt"], flight_config)
    np.testing.assert_allclose(result.table["time"], reference.table["time"])
    np.testing.assert_allclose(result.table["lat"], reference.table["lat"])
