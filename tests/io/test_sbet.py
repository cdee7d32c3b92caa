"""The SBET and smrmsg export (``--export sbet:FILE``), read back as its consumers read it.

The bundled flight (data/POS.txt, data/Kamera.txt, data/flight.toml; the ``make demo`` run) is processed once,
written as SBET + smrmsg and read back

(a) with a port of PDAL's readers (``readers.sbet``, ``readers.smrmsg``): PDAL/PDAL at commit
    ccf0ab7046072f68cab78734e90d0d3149f3af10, io/SbetCommon.hpp (``fileDimensions``, ``smrmsgFileDimensions``,
    ``isAngularDimension``), io/SbetReader.cpp and io/SbetSmrmsgReader.cpp (``ready``: the file size a non-zero
    multiple of the record; ``processOne``: the record's doubles read little-endian (``ILeStream``) in the
    dimensions' order, angles turned into degrees with ``angles_as_degrees``, PDAL's default true);
(b) with a numpy structured type written here from the format's description (NOAA HSTB drivers ``sbet.py``).

Each value is compared with the trajectory table (:func:`georef.io.generic.trajectory_table`, degrees) and with
times recomputed here from the date and GPS - UTC = 18 s.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import json
import math
import struct
import subprocess
from pathlib import Path

import numpy as np
import pytest
from georef_cli.main import app
from PIL import Image
from typer.testing import CliRunner

from georef.config import load_configs
from georef.frames import euler_to_dcm
from georef.frames.gpstime import utc_of_day_to_gps_week, utc_to_gps_seconds
from georef.io.atomic import OutputError
from georef.io.exports import ExportError, check_exports, parse_export, write_export
from georef.io.generic import trajectory_table
from georef.io.sbet import (
    SbetExportError,
    day_start_of,
    imu_rows_of_log,
    sbet_records,
    smrmsg_path_for,
    write_sbet,
)
from georef.pipeline import process

DATA = Path(__file__).resolve().parents[2] / "data"
RUNNER = CliRunner()
#: the flight's UTC date for these tests: a Saturday, so a shift of the time of day crosses the GPS week's end
DATE = dt.date(2024, 5, 18)
#: GPS - UTC on DATE (IERS Bulletin C: 18 s since 2017-01-01)
LEAP_2024 = 18

# --- (a) PDAL's readers, ported (PDAL/PDAL ccf0ab7046072f68cab78734e90d0d3149f3af10) -------------------------
#: io/SbetCommon.hpp fileDimensions(): the SBET record's dimensions in file order
PDAL_SBET_DIMENSIONS = ("GpsTime", "Y", "X", "Z", "XVelocity", "YVelocity", "ZVelocity", "Roll", "Pitch", "Azimuth",
                        "WanderAngle", "XBodyAccel", "YBodyAccel", "ZBodyAccel", "XBodyAngRate", "YBodyAngRate",
                        "ZBodyAngRate")
#: io/SbetCommon.hpp smrmsgFileDimensions()
PDAL_SMRMSG_DIMENSIONS = ("GpsTime", "NorthPositionRMS", "EastPositionRMS", "DownPositionRMS", "NorthVelocityRMS",
                          "EastVelocityRMS", "DownVelocityRMS", "RollRMS", "PitchRMS", "HeadingRMS")
#: io/SbetCommon.hpp isAngularDimension()
PDAL_ANGULAR = {"X", "Y", "Roll", "Pitch", "Azimuth", "WanderAngle", "XBodyAngRate", "YBodyAngRate", "ZBodyAngRate"}


def pdal_read(path: Path, dimensions: tuple[str, ...], angles_as_degrees: bool = True) -> dict[str, np.ndarray]:
    """SbetReader::ready + processOne (SmrmsgReader's are the same without the degree conversion)."""
    size = path.stat().st_size
    point_size = len(dimensions) * 8  # sizeof(double)
    if size == 0 or size % point_size != 0:
        raise ValueError("Invalid file size.")
    values: dict[str, list[float]] = {name: [] for name in dimensions}
    with path.open("rb") as stream:
        for _ in range(size // point_size):
            for name in dimensions:
                (d,) = struct.unpack("<d", stream.read(8))  # ILeStream >> double
                if angles_as_degrees and name in PDAL_ANGULAR:
                    d = d * 180.0 / math.pi
                values[name].append(d)
    return {name: np.array(column) for name, column in values.items()}


# --- (b) an independent numpy structured read ------------------------------------------------------------------
SBET_DTYPE = np.dtype([(name, "<f8") for name in (
    "time", "lat", "lon", "alt", "vx", "vy", "vz", "roll", "pitch", "heading", "wander", "ax", "ay", "az", "wx",
    "wy", "wz")])
SMRMSG_DTYPE = np.dtype([(name, "<f8") for name in (
    "time", "n_rms", "e_rms", "d_rms", "vn_rms", "ve_rms", "vd_rms", "roll_rms", "pitch_rms", "heading_rms")])


def expected_time_of_week(utc_of_day: np.ndarray, date: dt.date) -> np.ndarray:
    """GPS seconds of the week of UTC times of day on ``date`` (2017-2026: GPS - UTC = 18 s), counted from the
    week of the first time, in integer days plus the time of day (recomputed here, not by georef)."""
    days = (date - dt.date(1980, 1, 6)).days
    first_week = (days * 86400 + int(math.floor(utc_of_day[0])) + LEAP_2024) // 604800
    return (days * 86400 - first_week * 604800 + LEAP_2024) + utc_of_day


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """The bundled flight processed (method rts, flight.toml) and written as SBET + smrmsg, full rate."""
    cfg = load_configs([DATA / "flight.toml"])
    result = process(DATA / "POS.txt", DATA / "Kamera.txt", cfg)
    folder = tmp_path_factory.mktemp("sbet")
    day = dt.datetime(DATE.year, DATE.month, DATE.day, tzinfo=dt.UTC).timestamp()
    export = write_sbet(result.nav, imu_rows_of_log(result.log), folder / "sbet_demo.out", day)
    return result, export, trajectory_table(result.nav), day


def test_files_are_read_by_pdal_and_numpy_alike(demo):
    result, export, table, _ = demo
    assert export.sbet_path.name == "sbet_demo.out" and export.smrmsg_path.name == "smrmsg_demo.out"
    assert export.smrmsg_path.parent == export.sbet_path.parent
    pdal = pdal_read(export.sbet_path, PDAL_SBET_DIMENSIONS, angles_as_degrees=False)
    raw = np.fromfile(export.sbet_path, dtype=SBET_DTYPE)
    assert len(raw) == len(table) == int(result.nav.valid.sum())
    for dim, name in zip(PDAL_SBET_DIMENSIONS, SBET_DTYPE.names, strict=True):
        np.testing.assert_array_equal(pdal[dim], raw[name])
    rms = pdal_read(export.smrmsg_path, PDAL_SMRMSG_DIMENSIONS, angles_as_degrees=False)
    raw_rms = np.fromfile(export.smrmsg_path, dtype=SMRMSG_DTYPE)
    assert len(raw_rms) == len(raw)
    for dim, name in zip(PDAL_SMRMSG_DIMENSIONS, SMRMSG_DTYPE.names, strict=True):
        np.testing.assert_array_equal(rms[dim], raw_rms[name])
    np.testing.assert_array_equal(raw["time"], raw_rms["time"])


def test_times_are_gps_seconds_of_week(demo):
    _, export, table, _ = demo
    raw = np.fromfile(export.sbet_path, dtype=SBET_DTYPE)
    expected = expected_time_of_week(table["time"].to_numpy(), DATE)
    np.testing.assert_allclose(raw["time"], expected, rtol=0, atol=1e-7)
    # Saturday 2024-05-18 06:48 UTC: day 6 of GPS week 2314
    assert export.records.gps_week == 2314
    assert 6 * 86400 < raw["time"][0] < 7 * 86400
    assert np.all(np.diff(raw["time"]) > 0)


def test_positions_velocities_and_attitude_match_the_trajectory(demo):
    _, export, table, _ = demo
    pdal = pdal_read(export.sbet_path, PDAL_SBET_DIMENSIONS)  # degrees, as PDAL gives them by default
    np.testing.assert_allclose(pdal["Y"], table["lat"], rtol=0, atol=1e-10)
    np.testing.assert_allclose(pdal["X"], table["lon"], rtol=0, atol=1e-10)
    np.testing.assert_allclose(pdal["Z"], table["height"], rtol=0, atol=1e-9)
    # the wander frame at wander angle 0: x north, y west, z up
    assert np.abs(table["ve"]).max() > 5 and np.abs(table["vd"]).max() > 0.5  # a sign error cannot hide
    np.testing.assert_allclose(pdal["XVelocity"], table["vn"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(pdal["YVelocity"], -table["ve"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(pdal["ZVelocity"], -table["vd"], rtol=0, atol=1e-9)
    np.testing.assert_array_equal(pdal["WanderAngle"], 0.0)
    np.testing.assert_allclose(pdal["Roll"], table["roll"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(pdal["Pitch"], table["pitch"], rtol=0, atol=1e-9)
    heading = np.mod(pdal["Azimuth"] - pdal["WanderAngle"], 360.0)  # true heading = platform heading - wander
    difference = (heading - table["yaw"] + 180.0) % 360.0 - 180.0
    assert np.abs(difference).max() < 1e-9


def test_rms_file_holds_the_sigmas_in_metres_and_arc_minutes(demo):
    _, export, table, _ = demo
    rms = pdal_read(export.smrmsg_path, PDAL_SMRMSG_DIMENSIONS)
    for dim, column in (("NorthPositionRMS", "sigma_n"), ("EastPositionRMS", "sigma_e"),
                        ("DownPositionRMS", "sigma_u"), ("NorthVelocityRMS", "sigma_vn"),
                        ("EastVelocityRMS", "sigma_ve"), ("DownVelocityRMS", "sigma_vd")):
        np.testing.assert_allclose(rms[dim], table[column], rtol=1e-12, err_msg=dim)
    for dim, column in (("RollRMS", "sigma_roll"), ("PitchRMS", "sigma_pitch"), ("HeadingRMS", "sigma_yaw")):
        np.testing.assert_allclose(rms[dim], table[column] * 60.0, rtol=1e-12, err_msg=dim)  # degrees -> arc-min
    assert np.all(np.isfinite(rms["NorthVelocityRMS"]))
    np.testing.assert_allclose(rms["GpsTime"], expected_time_of_week(table["time"].to_numpy(), DATE), atol=1e-7)


def _window_mean(values: np.ndarray, rows: int) -> np.ndarray:
    """Means over consecutive blocks of ``rows`` (the white noise of a MEMS IMU at 50 Hz averaged out)."""
    count = len(values) // rows
    return values[:count * rows].reshape(count, rows, *values.shape[1:]).mean(axis=1)


def test_body_rates_and_accelerations_agree_with_the_motion(demo):
    """The body acceleration turned into NED is the velocity's rate (gravity removed, not specific force), and the
    body z rate turned into the yaw rate is the heading's rate [rad/s]: checked on 1 s means against the
    trajectory's own derivatives."""
    _, export, table, _ = demo
    raw = np.fromfile(export.sbet_path, dtype=SBET_DTYPE)
    t = table["time"].to_numpy()
    contiguous = np.flatnonzero(np.diff(t) > 0.03)
    stop = contiguous[0] + 1 if len(contiguous) else len(t)  # the first unbroken stretch of rows
    t = t[:stop]
    C_b_n = euler_to_dcm(raw["roll"][:stop], raw["pitch"][:stop], raw["heading"][:stop])
    accel_b = np.stack([raw["ax"], raw["ay"], raw["az"]], -1)[:stop]
    accel_n = np.einsum("nij,nj->ni", C_b_n, accel_b)
    v_n = np.stack([raw["vx"], -raw["vy"], -raw["vz"]], -1)[:stop]
    dv_dt = np.gradient(v_n, t, axis=0)
    error = _window_mean(accel_n - dv_dt, 50)
    assert np.sqrt(np.mean(error**2, axis=0)).max() < 0.15  # specific force would be 9.8 m/s^2 off in down
    assert np.abs(_window_mean(dv_dt, 50)).max() > 0.5  # the flight accelerates: the check has something to see
    rate_b = np.stack([raw["wx"], raw["wy"], raw["wz"]], -1)[:stop]
    roll, pitch = raw["roll"][:stop], raw["pitch"][:stop]
    yaw_rate = (np.sin(roll) * rate_b[:, 1] + np.cos(roll) * rate_b[:, 2]) / np.cos(pitch)
    heading_rate = np.gradient(np.unwrap(raw["heading"][:stop]), t)
    turning = _window_mean(heading_rate, 50)
    assert np.abs(turning).max() > 0.05  # the flight turns [rad/s]
    assert np.sqrt(np.mean((_window_mean(yaw_rate, 50) - turning) ** 2)) < 0.01


def test_rows_without_solution_are_left_out_and_said(demo):
    result, export, _, _ = demo
    invalid = int((~result.nav.valid).sum())
    assert invalid > 0 and export.records.left_out == invalid
    assert any(f"{invalid} IMU row(s) without a navigation solution" in note for note in export.notes)
    raw = np.fromfile(export.sbet_path, dtype=SBET_DTYPE)
    assert len(raw) == len(result.nav.time) - invalid


def test_rate_keeps_one_row_per_interval_of_gps_time(demo, tmp_path):
    result, export, _, day = demo
    slow = write_sbet(result.nav, imu_rows_of_log(result.log), tmp_path / "sbet_slow.out", day, rate_hz=10.0)
    full = np.fromfile(export.sbet_path, dtype=SBET_DTYPE)
    kept = np.fromfile(slow.sbet_path, dtype=SBET_DTYPE)
    assert len(kept) == len(np.unique(np.floor(full["time"] * 10.0 + 1e-5)))
    assert np.all(np.isin(kept["time"], full["time"]))  # IMU rows, not interpolated
    steps = np.diff(kept["time"])
    assert np.median(steps) == pytest.approx(0.1, abs=1e-6) and steps.min() > 0.08
    rows = np.searchsorted(full["time"], kept["time"])
    np.testing.assert_array_equal(kept, full[rows])
    rms = np.fromfile(slow.smrmsg_path, dtype=SMRMSG_DTYPE)
    np.testing.assert_array_equal(rms, np.fromfile(export.smrmsg_path, dtype=SMRMSG_DTYPE)[rows])
    with pytest.raises(SbetExportError, match="above the IMU"):
        write_sbet(result.nav, imu_rows_of_log(result.log), tmp_path / "sbet_fast.out", day, rate_hz=200.0)


def test_a_flight_across_the_end_of_the_gps_week_counts_on(demo):
    """Shifted to straddle Saturday/Sunday: GPS week 2314 ends at 2024-05-18 23:59:42 UTC."""
    result, _, _, day = demo
    nav = result.nav
    shift = 86400.0 - 18.0 - 60.0 - float(nav.time[nav.valid][0])  # the first valid row 60 s before the week ends
    moved = dataclasses.replace(nav, time=nav.time + shift)
    records = sbet_records(moved, imu_rows_of_log(result.log), day)
    times = records.sbet[:, 0]
    assert records.gps_week == 2314
    assert times[0] == pytest.approx(604800.0 - 60.0, abs=1e-6)
    assert times[-1] > 604800.0 + 60.0 and np.all(np.diff(times) > 0)
    np.testing.assert_allclose(times, expected_time_of_week(moved.time[moved.valid], DATE), atol=1e-7)
    assert any("past 604800 s" in note for note in records.notes)


def test_gps_time_conversion_and_leap_seconds():
    def posix(*args):
        return dt.datetime(*args, tzinfo=dt.UTC).timestamp()

    epoch = posix(1980, 1, 6)
    # the leap second at the end of 2016: GPS - UTC 17 s before, 18 s after
    assert utc_to_gps_seconds(posix(2016, 12, 31, 23, 59, 59)) - (posix(2016, 12, 31, 23, 59, 59) - epoch) == 17
    assert utc_to_gps_seconds(posix(2017, 1, 1)) - (posix(2017, 1, 1) - epoch) == 18
    week, seconds = utc_of_day_to_gps_week(posix(2024, 5, 18), np.array([0.0, 0.25]))
    assert week == 2314  # began Sunday 2024-05-12
    np.testing.assert_array_equal(seconds, [6 * 86400 + 18, 6 * 86400 + 18.25])
    # a time of day past midnight belongs to the next day (georef's continuous time of day)
    week, seconds = utc_of_day_to_gps_week(posix(2024, 5, 11), np.array([86400.0 + 3600.0]))
    assert (week, float(seconds[0])) == (2314, 3600.0 + 18.0)


def test_dates_and_names():
    assert smrmsg_path_for("out/sbet_mission1.out") == Path("out/smrmsg_mission1.out")
    assert smrmsg_path_for("traj.sbet") == Path("smrmsg_traj.out")
    day = dt.datetime(2024, 5, 18, tzinfo=dt.UTC).timestamp()
    assert day_start_of("2024-05-18", None) == day
    assert day_start_of(None, day) == day
    assert day_start_of("2024-05-18", day) == day
    with pytest.raises(SbetExportError, match="disagrees"):
        day_start_of("2024-05-19", day)
    with pytest.raises(SbetExportError, match="YYYY-MM-DD"):
        day_start_of("18.5.2024", None)
    with pytest.raises(SbetExportError, match="--utc-date"):
        day_start_of(None, None)


def test_export_spec_and_companion_file(tmp_path):
    spec = parse_export("sbet:" + str(tmp_path / "sbet_a.out"))
    assert spec.fmt == "sbet"
    with pytest.raises(ExportError, match="RMS file"):
        check_exports([spec, parse_export("csv:" + str(tmp_path / "smrmsg_a.out"))], None)
    with pytest.raises(ExportError, match="navigation solution"):
        write_export({}, tmp_path / "sbet_a.out", "sbet")


def test_both_files_or_neither(demo, tmp_path):
    result, _, _, day = demo
    (tmp_path / "smrmsg_blocked.out").mkdir()  # a directory where the RMS file goes: refused
    with pytest.raises(OutputError):
        write_sbet(result.nav, imu_rows_of_log(result.log), tmp_path / "sbet_blocked.out", day)
    assert not (tmp_path / "sbet_blocked.out").exists()


def test_cli_process_export_sbet(tmp_path):
    base = ["process", str(DATA / "POS.txt"), str(DATA / "Kamera.txt"), "--config", str(DATA / "flight.toml"),
            "-o", str(tmp_path / "eo.csv"), "--export", f"sbet:{tmp_path / 'sbet_cli.out'}", "--quiet"]
    refused = RUNNER.invoke(app, base)
    assert refused.exit_code == 2 and "--utc-date" in refused.output
    assert not (tmp_path / "eo.csv").exists()
    done = RUNNER.invoke(app, [*base, "--utc-date", "2024-05-18", "--sbet-rate", "5"])
    assert done.exit_code in (0, 4), done.output
    raw = np.fromfile(tmp_path / "sbet_cli.out", dtype=SBET_DTYPE)
    rms = np.fromfile(tmp_path / "smrmsg_cli.out", dtype=SMRMSG_DTYPE)
    assert len(raw) == len(rms) and 170 * 5 < len(raw) < 181 * 5
    assert np.median(np.diff(raw["time"])) == pytest.approx(0.2, abs=1e-6)
    assert 6 * 86400 + 24513 + LEAP_2024 <= raw["time"][0] < 6 * 86400 + 24700 + LEAP_2024


def test_wander_frame_and_platform_heading_agree_at_any_wander_angle():
    """With a wander angle the platform heading is measured from the wander x axis: the direction of a velocity
    along the nose, read in the wander frame (clockwise from x, y pointing left of x), is the platform heading."""
    from georef.frames.wander import ned_to_wander, platform_heading

    heading = np.radians([30.0, 170.0, -100.0])
    wander = np.radians([10.0, -25.0, 40.0])
    nose = np.stack([np.cos(heading), np.sin(heading), np.full(3, 0.5)], -1)  # NED, descending 0.5 m/s
    v_w = ned_to_wander(nose, wander)
    direction = np.arctan2(-v_w[:, 1], v_w[:, 0])
    np.testing.assert_allclose(np.angle(np.exp(1j * (direction - platform_heading(heading, wander)))), 0, atol=1e-12)
    # true heading = platform heading - wander angle
    np.testing.assert_allclose(platform_heading(heading, wander) - wander, heading, atol=1e-12)
    np.testing.assert_allclose(v_w[:, 2], -0.5)  # z up
    np.testing.assert_allclose(np.hypot(v_w[:, 0], v_w[:, 1]), 1.0)


def test_cli_fuse_export_sbet_matches_its_trajectory(tmp_path):
    import pandas as pd

    sim = tmp_path / "sim"
    made = RUNNER.invoke(app, ["simulate", str(sim), "--duration", "60", "--seed", "4", "--generic", "-q"])
    assert made.exit_code == 0, made.output
    common = ["fuse", "--imu", str(sim / "imu.csv"), "--gnss", str(sim / "gnss.csv"), "--config",
              str(sim / "flight.toml"), "-o", str(tmp_path / "traj.csv"), "-q"]
    wrong = RUNNER.invoke(app, [*common, "--export", f"metashape:{tmp_path / 'ms.csv'}", "--utc-date", "2024-05-18"])
    assert wrong.exit_code == 2 and "sbet:FILE only" in wrong.output
    undated = RUNNER.invoke(app, [*common, "--export", f"sbet:{tmp_path / 'sbet_f.out'}"])
    assert undated.exit_code == 2 and "--utc-date" in undated.output and not (tmp_path / "traj.csv").exists()
    done = RUNNER.invoke(app, [*common, "--export", f"sbet:{tmp_path / 'sbet_f.out'}", "--utc-date", "2024-05-18"])
    assert done.exit_code in (0, 4), done.output
    table = pd.read_csv(tmp_path / "traj.csv")
    raw = np.fromfile(tmp_path / "sbet_f.out", dtype=SBET_DTYPE)
    rms = np.fromfile(tmp_path / "smrmsg_f.out", dtype=SMRMSG_DTYPE)
    assert len(raw) == len(rms) == len(table)
    # traj.csv holds 10 significant digits
    np.testing.assert_allclose(raw["time"], expected_time_of_week(table["time"].to_numpy(), DATE), atol=1e-5)
    np.testing.assert_allclose(np.degrees(raw["lat"]), table["lat"], rtol=0, atol=1e-7)
    np.testing.assert_allclose(np.degrees(raw["lon"]), table["lon"], rtol=0, atol=1e-7)
    np.testing.assert_allclose(raw["alt"], table["height"], rtol=0, atol=1e-5)
    np.testing.assert_allclose(raw["vx"], table["vn"], rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(raw["vy"], -table["ve"], rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(raw["vz"], -table["vd"], rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(np.degrees(raw["roll"]), table["roll"], rtol=0, atol=1e-6)
    np.testing.assert_allclose(rms["n_rms"], table["sigma_n"], rtol=1e-8)
    np.testing.assert_allclose(rms["vd_rms"], table["sigma_vd"], rtol=1e-8)
    np.testing.assert_allclose(rms["heading_rms"], table["sigma_yaw"] * 60.0, rtol=1e-8)


def test_batch_refuses_sbet_folder_exports():
    from georef.io.exports import parse_folder_export

    for text in ("sbet", "sbet:sbet_a.out"):
        with pytest.raises(ExportError, match="does not write SBETs"):
            parse_folder_export(text)


def test_sbet_times_of_a_real_ardupilot_log_are_its_gps_receivers(tmp_path):
    """ArduCopter log171 (tests/data/logs, 2015-11-21, GPS - UTC = 17 s): the log's own date is used, and the SBET's
    time scale put on georef's fix times gives the receiver's GPS.TimeMS [ms of week] read here with pymavlink."""
    import gzip
    import shutil

    from pymavlink import mavutil

    from georef.io.events import read_events
    from georef.io.logs import read_flight_log
    from georef.pipeline import process_flight

    log = Path(__file__).resolve().parents[1] / "data" / "logs" / "ardupilot_copter_log171.bin.gz"
    flight = read_flight_log(log)
    events = tmp_path / "events.csv"
    times = np.arange(flight.gnss.time[0] + 20.0, flight.gnss.time[-1] - 5.0, 5.0)
    events.write_text("time,image\n" + "".join(f"{x:.3f},IMG_{k}.JPG\n" for k, x in enumerate(times, 1)))
    exposures, names = read_events(events)
    result = process_flight(flight, load_configs([]), exposures, names)
    export = write_sbet(result.nav, imu_rows_of_log(result.log), tmp_path / "sbet_log171.out",
                        _sbet_day(result, None))
    raw = np.fromfile(export.sbet_path, dtype=SBET_DTYPE)
    offset = raw["time"] - result.nav.time[result.nav.valid]  # GPS seconds of week minus UTC seconds of day
    assert np.ptp(offset) < 1e-6
    assert offset[0] == pytest.approx(6 * 86400 + 17, abs=1e-6)  # a Saturday, 17 leap seconds in 2015
    plain = tmp_path / "log171.bin"
    with gzip.open(log, "rb") as packed, plain.open("wb") as out:
        shutil.copyfileobj(packed, out)
    reader = mavutil.mavlink_connection(str(plain))
    receiver = []
    while (message := reader.recv_match(type="GPS")) is not None:
        fields = message.to_dict()
        if fields["Status"] >= 3:
            receiver.append(fields["TimeMS"] * 1e-3)
    receiver = np.sort(np.array(receiver))
    mapped = flight.gnss.time + offset[0]
    nearest = np.abs(receiver[np.clip(np.searchsorted(receiver, mapped), 1, len(receiver) - 1)[:, None]
                              + np.array([-1, 0])] - mapped[:, None]).min(axis=1)
    # the log has a stamp glitch (TimeMS not increasing) at three fixes; every other fix agrees to 1 us
    assert np.mean(nearest < 1e-6) > 0.99, np.sort(nearest)[-5:]


def _sbet_day(result, utc_date):
    from georef_cli.handoffs import process_sbet_clock

    return process_sbet_clock(result, utc_date, {"log": Path("log171.bin")}, "auto")


def test_method_axis_says_what_it_cannot_fill(demo):
    """The per-axis method estimates neither biases nor a velocity covariance: the raw IMU goes in, the velocity RMS
    are NaN, and the notes say both."""
    _, _, _, day = demo
    cfg = load_configs([DATA / "flight.toml"]).updated(method="axis")
    result = process(DATA / "POS.txt", DATA / "Kamera.txt", cfg)
    records = sbet_records(result.nav, imu_rows_of_log(result.log), day)
    assert np.isnan(records.smrmsg[:, 4:7]).all() and np.isfinite(records.smrmsg[:, [1, 2, 3, 7, 8, 9]]).all()
    assert any("no velocity covariance" in note for note in records.notes)
    assert any("no sensor biases" in note for note in records.notes)
    valid = result.nav.valid
    np.testing.assert_allclose(records.sbet[:, 14:17], np.radians(result.log.vector("gyro"))[valid])


# --- the run's time scale and its date (trial of issue 25: a bag's Unix stamps, a .pos's dates) ------------------
#: an RTKLIB 2.4.3 llh solution's header (as rnx2rtkp writes it, out-timesys GPST)
RTKLIB_HEADER = [
    "% program   : RTKLIB ver.2.4.3 b34",
    "% (lat/lon/height=WGS84/ellipsoidal,Q=1:fix,2:float,3:sbas,4:dgps,5:single,6:ppp,ns=# of satellites)",
    "%  GPST                  latitude(deg) longitude(deg)  height(m)   Q  ns   sdn(m)   sde(m)   sdu(m)  sdne(m)  "
    "sdeu(m)  sdun(m) age(s)  ratio",
]
#: 00:00 UTC of DATE [POSIX s], and GPS seconds of the week there (DATE is a Saturday: 6 days + the leap seconds)
DAY_POSIX = dt.datetime(DATE.year, DATE.month, DATE.day, tzinfo=dt.UTC).timestamp()
SOW_AT_DATE = 6 * 86400 + LEAP_2024
#: GPS week of DATE: (2024-05-18 - 1980-01-06) = 16204 days = 2314 weeks + 6 days
WEEK_OF_DATE = 2314


def _on_scale(nav, offset: float):
    """``nav`` with ``offset`` [s] added to its UTC seconds of DATE (another scale's times of the same instants)."""
    return dataclasses.replace(nav, time=np.asarray(nav.time, dtype=float) + offset)


def test_the_scale_of_the_times_decides_the_date(demo):
    """The same flight on UTC seconds of DATE, on Unix seconds and on GPS seconds of the week gives the same SBET
    times. Unix stamps and GPS seconds of a week date themselves: no --utc-date needed, one that agrees accepted,
    one that does not refused (the trial read a bag's Unix stamps as seconds of --utc-date's day: 5 days off)."""
    from georef.io.pos_time_scale import ScaleChoice
    from georef.io.sbet import run_clock

    result, export, _, _ = demo
    imu = imu_rows_of_log(result.log)
    want = export.records.sbet[:, 0]
    unix = _on_scale(result.nav, DAY_POSIX)
    clock = run_clock(unix.time, None, bag=True, imu_label="the bag's IMU")
    assert clock.scale == "utc-posix"
    np.testing.assert_allclose(sbet_records(unix, imu, clock).sbet[:, 0], want, rtol=0, atol=1e-6)
    assert run_clock(unix.time, "2024-05-18").scale == "utc-posix"  # the stamps' own date: accepted
    with pytest.raises(SbetExportError, match="start on 2024-05-18"):
        run_clock(unix.time, "2024-05-14", bag=True)
    # GPS seconds of week 2314 (an imu.csv so logged, dated by a .pos whose fixes fell on that week)
    gps = _on_scale(result.nav, SOW_AT_DATE)
    choice = ScaleChoice(scale="gps-week", reference_utc=DAY_POSIX + 43200.0, times=np.array([]), notice=None)
    clock = run_clock(gps.time, None, solution=choice, solution_name="--gnss solution.pos")
    assert (clock.scale, clock.gps_week) == ("gps-week", WEEK_OF_DATE)
    records = sbet_records(gps, imu, clock)
    np.testing.assert_allclose(records.sbet[:, 0], gps.time[gps.valid], rtol=0, atol=1e-9)
    assert records.gps_week == WEEK_OF_DATE and "GPS seconds of week 2314" in records.time_basis
    np.testing.assert_allclose(records.sbet[:, 0], want, rtol=0, atol=1e-6)
    with pytest.raises(SbetExportError, match="disagrees"):
        run_clock(gps.time, "2024-05-19", solution=choice)
    # UTC seconds of a day dated by a .pos: that day, and a --utc-date naming another refused
    day_choice = ScaleChoice(scale="utc-day", reference_utc=DAY_POSIX + 3600.0, times=np.array([]), notice=None)
    assert run_clock(result.nav.time, None, solution=day_choice).day_start_posix == DAY_POSIX
    assert run_clock(result.nav.time, "2024-05-18", solution=day_choice).day_start_posix == DAY_POSIX
    with pytest.raises(SbetExportError, match="disagrees with the .pos"):
        run_clock(result.nav.time, "2024-05-19", solution=day_choice)


def test_times_that_are_no_seconds_of_a_day_are_not_dated_by_utc_date(demo):
    """Without a date of their own, times are taken as UTC seconds of --utc-date only where they can be: GPS
    seconds of the week (542931 s) on a Saturday would be 5 days off, so they are refused with the way out."""
    from georef.io.sbet import run_clock

    result = demo[0]
    with pytest.raises(SbetExportError, match="give --utc-date"):
        run_clock(result.nav.time, None)
    assert run_clock(result.nav.time, "2024-05-18").day_start_posix == DAY_POSIX
    with pytest.raises(SbetExportError, match="not .0 - 172800 s.*RTKLIB/Emlid .pos"):
        run_clock(result.nav.time + SOW_AT_DATE, "2024-05-18")


def test_a_date_before_the_gps_epoch_is_refused(tmp_path):
    from georef.io.sbet import parse_utc_date

    assert parse_utc_date("1980-01-06") == dt.datetime(1980, 1, 6, tzinfo=dt.UTC).timestamp()
    with pytest.raises(SbetExportError, match="before the GPS epoch"):
        parse_utc_date("1980-01-05")
    refused = RUNNER.invoke(app, ["process", str(DATA / "POS.txt"), str(DATA / "Kamera.txt"), "--config",
                                  str(DATA / "flight.toml"), "-o", str(tmp_path / "eo.csv"), "--export",
                                  f"sbet:{tmp_path / 'sbet_old.out'}", "--utc-date", "1975-01-01", "-q"])
    assert refused.exit_code == 2 and "before the GPS epoch" in refused.output
    assert not any(tmp_path.iterdir())


def _pos_file(gnss_csv: Path, out: Path) -> Path:
    """gnss.csv (UTC seconds of DATE) as an RTKLIB solution in GPST calendar time, DGPS, the csv's sigmas."""
    import pandas as pd

    lines = list(RTKLIB_HEADER)
    for r in pd.read_csv(gnss_csv).itertuples():
        t = dt.datetime(DATE.year, DATE.month, DATE.day) + dt.timedelta(seconds=float(r.time) + LEAP_2024)
        lines.append(f"{t:%Y/%m/%d %H:%M:%S}.{round(t.microsecond / 1000):03d}   {r.lat:12.9f}  {r.lon:13.9f}  "
                     f"{r.height:9.4f}   4  9  {r.sigma_n:7.4f}  {r.sigma_e:7.4f}  {r.sigma_u:7.4f}   0.0000   "
                     "0.0000   0.0000   0.00    0.0")
    out.write_text("\n".join(lines) + "\n")
    return out


@pytest.fixture(scope="module")
def sim60(tmp_path_factory) -> Path:
    """A 60 s simulated flight's generic files (UTC seconds of day), its gnss.csv also as solution.pos of DATE."""
    folder = tmp_path_factory.mktemp("sbet_sim") / "sim"
    made = RUNNER.invoke(app, ["simulate", str(folder), "--duration", "60", "--seed", "4", "--generic", "-q"])
    assert made.exit_code == 0, made.output
    _pos_file(folder / "gnss.csv", folder / "solution.pos")
    return folder


def test_fuse_with_a_pos_takes_its_date(sim60, tmp_path):
    """fuse --gnss solution.pos: the .pos dates the flight (the trial was refused without --utc-date, and shifted
    86400 s with a wrong one, exit 0); a --utc-date naming another day is exit 2 and nothing written."""
    import pandas as pd

    common = ["fuse", "--imu", str(sim60 / "imu.csv"), "--gnss", str(sim60 / "solution.pos"), "--config",
              str(sim60 / "flight.toml"), "-o", str(tmp_path / "traj.csv"), "-q"]
    wrong = RUNNER.invoke(app, [*common, "--export", f"sbet:{tmp_path / 'sbet_w.out'}", "--utc-date", "2024-05-19"])
    assert wrong.exit_code == 2 and "disagrees with --gnss solution.pos" in wrong.output, wrong.output
    assert not any(tmp_path.iterdir())
    summary = tmp_path / "s.json"
    done = RUNNER.invoke(app, [*common, "--export", f"sbet:{tmp_path / 'sbet_p.out'}", "--summary-json",
                               str(summary)])
    assert done.exit_code in (0, 4), done.output
    table = pd.read_csv(tmp_path / "traj.csv")
    raw = np.fromfile(tmp_path / "sbet_p.out", dtype=SBET_DTYPE)
    assert len(raw) == len(table) > 1000
    np.testing.assert_allclose(raw["time"], expected_time_of_week(table["time"].to_numpy(), DATE), atol=1e-5)
    import json

    sbet = json.loads(summary.read_text())["summary"]["sbet"][0]
    assert sbet["sbet_gps_week"] == WEEK_OF_DATE and "dated by the dates of --gnss solution.pos" in \
        sbet["sbet_time_basis"]


def test_bag_stamps_are_unix_seconds_for_process_and_fuse(sim60, tmp_path):
    """process --bag --export sbet needs no --utc-date (the trial refused it, asking for one), and a --utc-date
    that is not the stamps' date is refused (the trial read the stamps as seconds of it, exit 0)."""
    import pandas as pd
    from test_rosbag import csv_to_bag_rows, write_bag

    for name in ("imu.csv", "gnss.csv"):  # a ROS wall clock: Unix seconds of DATE
        table = pd.read_csv(sim60 / name)
        table["time"] = np.round(table["time"] + DAY_POSIX, 4)
        table.to_csv(tmp_path / name, index=False, float_format="%.10f")
    camera = pd.read_csv(sim60 / "Kamera.txt", sep="\t")
    exposures = (camera["Time"] + camera["Milliseconds"] / 1000.0).to_numpy() + DAY_POSIX
    events = tmp_path / "events.csv"
    names = [f"IMG_{i + 1:04d}.JPG" for i in range(len(exposures))]
    events.write_text("time,image\n" + "".join(f"{t:.4f},{n}\n" for t, n in zip(exposures, names, strict=True)))
    photos = tmp_path / "photos"  # image copies are dated by the same clock (they were read as 2080 before)
    photos.mkdir()
    for name in names[:5]:
        Image.new("RGB", (32, 24), (90, 120, 60)).save(photos / name, "JPEG")
    bag = write_bag(tmp_path / "flight.bag", *csv_to_bag_rows(tmp_path / "imu.csv", tmp_path / "gnss.csv"))
    out = tmp_path / "out"
    wrong = RUNNER.invoke(app, ["fuse", "--bag", str(bag), "--config", str(sim60 / "flight.toml"), "-o",
                                str(out / "traj.csv"), "--export", f"sbet:{out / 'sbet_f.out'}", "--utc-date",
                                "2024-05-14", "-q"])
    assert wrong.exit_code == 2 and "start on 2024-05-18" in wrong.output and not out.exists()
    done = RUNNER.invoke(app, ["process", "--bag", str(bag), "--events", str(events), "--config",
                               str(sim60 / "flight.toml"), "-o", str(out / "eo.csv"), "--export",
                               f"sbet:{out / 'sbet_b.out'}", "--images", str(photos), "--export",
                               f"images:{out / 'tagged'}", "-q"])
    assert done.exit_code in (0, 4), done.output
    tags = subprocess.run(["exiftool", "-j", "-n", "-GPSDateTime", *sorted(map(str, (out / "tagged").glob("*.JPG")))],
                          capture_output=True, text=True, check=True)
    stamps = [item["GPSDateTime"].rstrip("Z") for item in json.loads(tags.stdout)]
    posix = [dt.datetime.strptime(s, "%Y:%m:%d %H:%M:%S.%f" if "." in s else "%Y:%m:%d %H:%M:%S")
             .replace(tzinfo=dt.UTC).timestamp() for s in stamps]
    np.testing.assert_allclose(posix, exposures[:5], rtol=0, atol=2e-3)
    raw = np.fromfile(out / "sbet_b.out", dtype=SBET_DTYPE)
    imu_time = pd.read_csv(sim60 / "imu.csv")["time"].to_numpy()  # UTC seconds of DATE
    kept = np.isin(np.round(imu_time + SOW_AT_DATE, 4), np.round(raw["time"], 4))
    assert len(raw) > 1000 and kept.sum() == len(raw)
    np.testing.assert_allclose(raw["time"], expected_time_of_week(imu_time[kept], DATE), rtol=0, atol=1e-5)
