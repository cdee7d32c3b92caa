"""Simulated flights written as autopilot logs (georef/sim/autopilot_logs.py) and read back.

References: pymavlink's DFReader (binary and text) and pyulog read every message and field written, so the logs are
valid for the libraries the field uses; pymavlink is also the independent reference for georef's own binary
DataFlash parser. georef's readers (georef/io/logs/ardupilot.py, px4.py) must give back the simulated flight: IMU
rows on UTC within 1 ms with the values written, the fixes at their own times with their heights and sigmas, the
lever arm from the parameters, one camera event per exposure, and the boot clock's rate.

The test flight's receiver measures on whole milliseconds of GPS time, as real receivers do (the simulator's rows
sit at .5 ms by default), with a lag of whole milliseconds that GPS_DELAY_MS states exactly: the readers' times are
then the truth but for the fix messages' arrival jitter.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
from pymavlink.DFReader import DFReader_binary, DFReader_text
from pyulog import ULog

from georef.frames.gpstime import GPS_EPOCH
from georef.io.camera import FEEDBACK_TIME_SIGMA, TRIGGER_TIME_SIGMA
from georef.io.logs.ardupilot import DEFAULT_GPS_LAG_S, read_ardupilot
from georef.io.logs.dataflash import read_binary
from georef.io.logs.px4 import read_px4
from georef.sim.autopilot_logs import BootClock, write_dataflash, write_ulog
from georef.sim.dataflash_writer import FORMAT_CHARS, MessageBlock
from georef.sim.flight import SimConfig, simulate
from georef.sim.log_samples import gps_time

CAPTURE_DELAY_S = 0.004
#: a date with GPS - UTC = 16 s (the 3.x logs), against 18 s for the default date of 2025
DATE_2014 = dt.date(2014, 8, 14)


@pytest.fixture(scope="module")
def flight():
    """45 s from a hover: 220 fixes at 5 Hz, 16 exposures on the first legs, magnetometer and autopilot attitude."""
    cfg = SimConfig.for_vehicle("drone", seed=1, duration_s=45, start="hover", with_magnetometer=True,
                                with_autopilot=True, first_row_offset_s=0.01)
    gnss = dataclasses.replace(cfg.gnss, latency_s=round(cfg.gnss.latency_s, 3))
    return simulate(dataclasses.replace(cfg, gnss=gnss))


@pytest.fixture(scope="module")
def logs(flight, tmp_path_factory) -> dict[str, tuple[Path, object]]:
    """Every kind of log of the flight: name -> (path, what the writer returned)."""
    folder = tmp_path_factory.mktemp("autopilot")
    out: dict[str, tuple[Path, object]] = {}
    for name, text, generation, date in (("4x.bin", False, "4.x", dt.date(2025, 6, 14)),
                                         ("4x.log", True, "4.x", dt.date(2025, 6, 14)),
                                         ("3x.bin", False, "3.x", DATE_2014), ("3x.log", True, "3.x", DATE_2014)):
        path = folder / name
        out[name] = (path, write_dataflash(flight, path, text=text, generation=generation, date=date,
                                           second_imu=True, capture_delay_s=CAPTURE_DELAY_S))
    for generation in ("new", "old"):
        path = folder / f"{generation}.ulg"
        out[f"{generation}.ulg"] = (path, write_ulog(flight, path, generation=generation,
                                                     capture_delay_s=CAPTURE_DELAY_S))
    return out


def _read(path: Path):
    return read_ardupilot(path, path.read_bytes()) if path.suffix in (".bin", ".log") else read_px4(path,
                                                                                                   path.read_bytes())


# --- the formats: pymavlink and pyulog read back everything written ------------------------------------------------

def _by_type(blocks: list[MessageBlock]) -> dict[str, list[tuple[MessageBlock, int]]]:
    """Written messages per type in log order: by boot time, ties in the order the blocks were given."""
    rows: dict[str, list[tuple[float, int, int, MessageBlock]]] = defaultdict(list)
    for k, b in enumerate(blocks):
        rows[b.kind.name] += [(float(t), k, r, b) for r, t in enumerate(b.time)]
    return {name: [(b, r) for _, _, r, b in sorted(items, key=lambda x: x[:3])] for name, items in rows.items()}


def _pymavlink_messages(path: Path) -> dict[str, list]:
    reader = DFReader_text(str(path)) if path.suffix == ".log" else DFReader_binary(str(path))
    out: dict[str, list] = defaultdict(list)
    while (m := reader.recv_msg()) is not None:
        out[m.get_type()].append(m)
    return out


def _assert_field(read: list, expected: np.ndarray, char: str, where: str) -> None:
    scale = FORMAT_CHARS[char][1]
    if scale is None:
        assert list(read) == [e.decode() for e in expected], where
    elif char in "fd":  # the stored float, exactly (float32 widened)
        np.testing.assert_array_equal(np.array(read, dtype=float), expected.astype(float), err_msg=where)
    elif scale == 1.0:
        assert [int(v) for v in read] == expected.astype(np.int64).tolist(), where
    else:
        np.testing.assert_allclose(np.array(read, dtype=float), expected / round(1.0 / scale), rtol=1e-15,
                                   atol=0.0, err_msg=where)


@pytest.mark.parametrize("name", ["4x.bin", "4x.log", "3x.bin", "3x.log"])
def test_pymavlink_reads_back_every_message_field_for_field(logs, name):
    path, blocks = logs[name]
    read = _pymavlink_messages(path)
    written = _by_type(blocks)
    assert set(read) == set(written)
    for kind, messages in written.items():
        assert len(read[kind]) == len(messages), kind
        for column, char in zip(messages[0][0].kind.columns, messages[0][0].kind.format, strict=True):
            expected = np.array([b.stored[column][r] for b, r in messages])
            _assert_field([getattr(m, column) for m in read[kind]], expected, char, f"{name} {kind}.{column}")


@pytest.mark.parametrize("name", ["new.ulg", "old.ulg"])
def test_pyulog_reads_back_the_ulog(logs, name):
    path, written = logs[name]
    read = ULog(str(path))
    assert read.msg_info_dict == written.msg_info_dict
    assert read.initial_parameters == {k: np.float32(v) if isinstance(v, float) else v
                                       for k, v in written.initial_parameters.items()}
    assert read.message_formats == written.message_formats
    assert {d.name for d in read.data_list} == {d.name for d in written.data_list}
    for data in written.data_list:
        again = read.get_dataset(data.name)
        assert [(f.field_name, f.type_str) for f in again.field_data] == \
            [(f.field_name, f.type_str) for f in data.field_data]
        for field, values in data.data.items():
            np.testing.assert_array_equal(again.data[field], values, err_msg=f"{name} {data.name}.{field}")
    assert not read.file_corruption and not read.dropouts


def test_gps_time_carries_the_leap_seconds_of_the_date():
    """GPS week and ms of week against datetime arithmetic with IERS's GPS - UTC: 18 s in 2025, 16 s in 2014."""
    for date, leap in ((dt.date(2025, 6, 14), 18), (DATE_2014, 16)):
        utc = np.array([0.0, 24513.01, 86399.999])
        got = gps_time(utc, date)
        midnight = dt.datetime(date.year, date.month, date.day, tzinfo=dt.UTC)
        for k, seconds in enumerate(utc):
            gps = (midnight - GPS_EPOCH).total_seconds() + seconds + leap
            assert got.week[k] == int(gps // 604800)
            assert got.ms_of_week[k] == round((gps % 604800) * 1000)


def test_mean_sea_level_heights_are_the_fixes_less_egm96_from_proj(logs, flight):
    """GPS.Alt + EGM96 N == the fix's ellipsoidal height, N from PROJ called here (WGS 84 3D to WGS 84 + EGM96
    height), not through georef's egm96_undulation that the writer and the reader share: about +44 m at the
    flight's place (the geoid above the ellipsoid in Croatia)."""
    from pyproj import Transformer, datadir

    for folder in ("/usr/share/proj", "/usr/local/share/proj"):  # Debian's proj-data, where the EGM96 grid is
        if Path(folder).is_dir() and folder not in datadir.get_data_dir().split(":"):
            datadir.append_data_dir(folder)
    gps = _pymavlink_messages(logs["4x.bin"][0])["GPS"]
    lat, lon, alt = (np.array([getattr(m, f) for m in gps]) for f in ("Lat", "Lng", "Alt"))
    # no ballpark: without the grid PROJ would leave the heights unchanged
    to_egm96 = Transformer.from_crs("EPSG:4979", "EPSG:4326+5773", always_xy=True, allow_ballpark=False)
    undulation = -to_egm96.transform(lon, lat, np.zeros(len(lat)))[2]
    assert 40.0 < undulation.mean() < 48.0
    np.testing.assert_allclose(alt + undulation, flight.gnss_fixes["height"], rtol=0, atol=0.005 + 1e-4)


# --- georef's readers give back the flight -------------------------------------------------------------------------

def _assert_imu(log, flight, shift: float = 0.0, tolerance: float = 1e-3) -> None:
    """IMU rows at the truth's UTC (less ``shift`` [s]) within ``tolerance``, values the float32 written."""
    assert len(log.imu.time) == len(flight.truth_nav.time)
    np.testing.assert_allclose(log.imu.time, flight.truth_nav.time - shift, rtol=0, atol=tolerance)
    gyro = np.radians(flight.pos[["OMGS_X", "OMGS_Y", "OMGS_Z"]].to_numpy(float))
    accel = flight.pos[["ACCS_X", "ACCS_Y", "ACCS_Z"]].to_numpy(float)
    np.testing.assert_array_equal(log.imu.gyro, gyro.astype(np.float32).astype(float))
    np.testing.assert_array_equal(log.imu.accel, accel.astype(np.float32).astype(float))


def _assert_fixes(log, flight, height_tolerance: float | None, sigma_tolerance: float) -> None:
    """Fixes at their own (whole-ms) times, positions to 1e-7 deg (the coarsest field's resolution), ellipsoidal
    heights (unless ``height_tolerance`` is None), sigmas."""
    fixes = flight.gnss_fixes
    np.testing.assert_allclose(log.gnss.time, fixes["measured_time"], rtol=0, atol=1e-6)
    np.testing.assert_allclose(log.gnss.lat_deg, fixes["lat"], rtol=0, atol=0.5e-7 + 1e-12)
    np.testing.assert_allclose(log.gnss.lon_deg, fixes["lon"], rtol=0, atol=0.5e-7 + 1e-12)
    if height_tolerance is not None:
        np.testing.assert_allclose(log.gnss.height, fixes["height"], rtol=0, atol=height_tolerance)
    sigma = fixes[["sigma_n", "sigma_e", "sigma_u"]].to_numpy(float)
    np.testing.assert_allclose(log.gnss.sigma_neu, sigma, rtol=0, atol=sigma_tolerance)


def _assert_events(log, flight, times: np.ndarray, tolerance: float) -> None:
    count = len(flight.exposures)
    assert count > 0
    assert log.events.frame.tolist() == [str(k) for k in range(1, count + 1)]
    np.testing.assert_allclose(log.events.time, times, rtol=0, atol=tolerance)


@pytest.mark.parametrize("name", ["4x.bin", "4x.log"])
def test_ardupilot_4x_reader_gives_back_the_flight(logs, flight, name):
    log = _read(logs[name][0])
    assert log.kind.endswith("(binary)" if name.endswith(".bin") else "(text)")
    assert "ArduCopter V4.5.7" in log.vehicle and "QUAD/X" in log.vehicle
    assert log.imu_streams == ["IMU[0]", "IMU[1]"]
    _assert_imu(log, flight)
    _assert_fixes(log, flight, height_tolerance=None, sigma_tolerance=0.005 + 1e-9)  # HAcc/VAcc hold centimetres
    assert log.gnss_report.sigma_source == "GPA.HAcc/VAcc"
    np.testing.assert_allclose(log.lever_arm.lever_arm, flight.config.lever_arm_gnss_m, rtol=0, atol=1e-7)
    assert log.clock.lag_s == pytest.approx(flight.config.gnss.latency_s, abs=1e-9)
    _assert_events(log, flight, flight.exposures["time"].to_numpy() + CAPTURE_DELAY_S, 1e-3)
    # TRIG and CAM: a feedback pin, so CAM is the exposure
    assert np.all(log.events.time_sigma == FEEDBACK_TIME_SIGMA)


def test_ardupilot_4x_heights_are_ellipsoidal(logs, flight):
    """GPA.Und is ArduPilot's hMSL - height = -N (AP_GPS_UBLOX.cpp; ArduPilot issue #29199, PR #29904): read as
    +N it put every height 2N (88 m here) low."""
    log = _read(logs["4x.bin"][0])
    np.testing.assert_allclose(log.gnss.height, flight.gnss_fixes["height"], rtol=0, atol=0.01)


@pytest.mark.parametrize("name", ["3x.bin", "3x.log"])
def test_ardupilot_3x_reader_gives_back_the_flight(logs, flight, name):
    """ArduCopter 3.2: no GPS_DELAY_MS, so the reader's default lag; heights through EGM96; UBX3 sigmas; CAM
    events at their GPS time; GPS - UTC = 16 s on the log's date."""
    log = _read(logs[name][0])
    assert "ArduCopter V3.2.1" in log.vehicle
    assert log.imu_streams == ["IMU[0]", "IMU[1]"]
    # the clock is tied to the fixes taken DEFAULT_GPS_LAG_S after their fix: every time is off by the difference
    _assert_imu(log, flight, shift=flight.config.gnss.latency_s - DEFAULT_GPS_LAG_S)
    assert log.clock.lag_s == DEFAULT_GPS_LAG_S
    _assert_fixes(log, flight, height_tolerance=0.005 + 1e-6, sigma_tolerance=1e-6)  # Alt in cm; float32 sigmas
    assert log.gnss_report.sigma_source == "UBX3.hAcc/vAcc"
    assert log.lever_arm is None
    _assert_events(log, flight, flight.exposures["time"].to_numpy(), 1e-6)
    # CAM alone: no feedback pin, so ArduPilot logged it at the trigger command, and says so
    assert np.all(log.events.time_sigma == TRIGGER_TIME_SIGMA)
    assert any("without a camera feedback pin" in n.message for n in log.notices)


@pytest.mark.parametrize("name", ["new.ulg", "old.ulg"])
def test_px4_reader_gives_back_the_flight(logs, flight, name):
    log = _read(logs[name][0])
    new = name == "new.ulg"
    assert log.vehicle == ("PX4 PX4_FMU_V5X v1.14.3" if new else "PX4 PX4_FMU_V5 v1.10.2")
    # new: timestamp_sample ties the clock exactly; old: arrival less EKF2_GPS_DELAY, the arrival jitter remains
    _assert_imu(log, flight, tolerance=2e-6 if new else 1e-3)
    # float64 heights (new) or whole mm (old); float32 eph/epv
    _assert_fixes(log, flight, height_tolerance=1e-9 if new else 0.0005 + 1e-9, sigma_tolerance=1e-6)
    np.testing.assert_allclose(log.lever_arm.lever_arm, flight.config.lever_arm_gnss_m, rtol=0, atol=1e-7)
    _assert_events(log, flight, flight.exposures["time"].to_numpy() + CAPTURE_DELAY_S, 2e-6 if new else 1e-3)
    assert np.all(log.events.time_sigma == FEEDBACK_TIME_SIGMA)   # camera_capture: the exposure


@pytest.fixture(scope="module")
def steady_flight(flight):
    """The test flight with fix messages arriving exactly their lag after the fix (no jitter): what decides the
    fitted rate is then the reader, not the noise (3 ms rms of jitter over 45 s leave 15 ppm of slope error)."""
    cfg = flight.config
    return simulate(dataclasses.replace(cfg, gnss=dataclasses.replace(cfg.gnss, latency_jitter_s=0.0)))


def _write(flight, path: Path, clock: BootClock) -> None:
    if path.suffix == ".bin":
        write_dataflash(flight, path, boot_clock=clock)
    else:
        write_ulog(flight, path, generation=path.stem, boot_clock=clock)


@pytest.mark.parametrize("rate", [12 / 13, 1 + 40e-6])
@pytest.mark.parametrize("kind", ["4x.bin", "old.ulg", "new.ulg"])
def test_the_boot_clock_rate_is_recovered(steady_flight, tmp_path, rate, kind):
    """A clock at 12/13 of real time (a 2014 board) or a crystal 40 ppm fast, started 35 s before the log: the
    readers fit its rate within 1 ppm and put the IMU rows on UTC within 1 ms."""
    path = tmp_path / kind
    _write(steady_flight, path, BootClock(start_offset_s=35.0, rate=rate))
    log = _read(path)
    assert abs(log.clock.rate * rate - 1.0) < 1e-6
    _assert_imu(log, steady_flight)


@pytest.mark.parametrize("kind", ["4x.bin", "old.ulg"])
def test_a_slow_clock_with_jittered_fix_messages(flight, tmp_path, kind):
    """The 12/13 clock with 2 ms more arrival jitter on the receiver's 4.5 ms: the rate within 4 standard errors
    of a line's slope through the jittered arrivals (60 ppm here; the clock itself is 77000 ppm off), the IMU
    rows within 1 ms."""
    clock = BootClock(start_offset_s=35.0, rate=12 / 13, fix_jitter_s=0.002, seed=4)
    path = tmp_path / kind
    _write(flight, path, clock)
    log = _read(path)
    sigma = np.sqrt((flight.config.gnss.latency_jitter_s ** 2 + clock.fix_jitter_s ** 2) / 3.0)  # both uniform
    t = flight.gnss_fixes["measured_time"].to_numpy()
    assert abs(log.clock.rate * clock.rate - 1.0) < 4.0 * sigma / np.sqrt(np.sum((t - t.mean()) ** 2))
    _assert_imu(log, flight)


# --- georef's binary parser against pymavlink; damaged logs --------------------------------------------------------

@pytest.mark.parametrize("name, types", [("4x.bin", ["IMU", "GPS", "GPA", "ATT", "CAM", "TRIG", "MAG", "PARM"]),
                                         ("3x.bin", ["IMU", "IMU2", "GPS", "UBX3", "ATT", "CAM", "MAG"])])
def test_georef_binary_parser_agrees_with_pymavlink(logs, name, types):
    path = logs[name][0]
    data = path.read_bytes()
    ours = read_binary(path, data, types)
    reference = DFReader_binary(str(path))
    messages = _pymavlink_messages(path)
    assert ours.skipped == []
    for kind in types:
        table = ours.messages[kind]
        fmt = ours.formats[kind]
        assert table.where.tolist() == reference.offsets[fmt.type_id]
        assert set(table.columns) == set(fmt.columns)
        for column in fmt.columns:
            theirs = [getattr(m, column) for m in messages[kind]]
            if table.columns[column].dtype == object:
                assert table.columns[column].tolist() == theirs, f"{kind}.{column}"
            else:
                np.testing.assert_allclose(table.columns[column], np.array(theirs, dtype=float), rtol=1e-15, atol=0,
                                           err_msg=f"{kind}.{column}")


def test_a_run_of_garbage_is_skipped_with_a_notice_and_the_rest_read(logs, flight, tmp_path):
    """700 bytes of garbage (no message header in them) between two IMU messages in the middle of the log."""
    path = logs["4x.bin"][0]
    data = path.read_bytes()
    imu_offsets = DFReader_binary(str(path)).offsets[read_binary(path, data, []).formats["IMU"].type_id]
    at = imu_offsets[len(imu_offsets) // 2]
    garbage = np.random.default_rng(7).integers(0, 0xA3, 700, dtype=np.uint8).tobytes()  # never 0xA3: no header
    damaged = tmp_path / "damaged.bin"
    damaged.write_bytes(data[:at] + garbage + data[at:])
    log = read_ardupilot(damaged, damaged.read_bytes())
    clean = read_ardupilot(path, data)
    messages = [n.message for n in log.notices]
    assert any("700 byte(s) in 1 run(s)" in m and f"first at byte {at}" in m for m in messages), messages
    np.testing.assert_array_equal(log.imu.time, clean.imu.time)
    np.testing.assert_array_equal(log.imu.gyro, clean.imu.gyro)
    np.testing.assert_array_equal(log.imu.where[log.imu.where >= at] - 700, clean.imu.where[clean.imu.where >= at])
    np.testing.assert_array_equal(log.gnss.time, clean.gnss.time)
    assert len(log.events.time) == len(flight.exposures)


def test_a_log_cut_inside_its_last_message_keeps_every_whole_message(logs, tmp_path):
    path = logs["4x.bin"][0]
    data = path.read_bytes()
    cut = tmp_path / "cut.bin"
    cut.write_bytes(data[:-10])
    names = list(read_binary(path, data, []).formats)
    ours = read_binary(cut, cut.read_bytes(), names)
    whole = read_binary(path, data, names)
    last_length = ours.formats[_last_type(whole)].length
    assert ours.skipped == [(len(data) - last_length, last_length - 10)]
    assert sum(len(ours.messages[k]) for k in ours.messages) == sum(len(whole.messages[k]) for k in whole.messages) - 1


def _last_type(log) -> str:
    """The type of the log's last message."""
    return max(log.messages, key=lambda name: log.messages[name].where.max())


# --- the writer refuses what it cannot write -----------------------------------------------------------------------

def test_the_writers_refuse_what_they_cannot_write(flight, tmp_path):
    with pytest.raises(ValueError, match="generation must be one of 4.x, 3.x"):
        write_dataflash(flight, tmp_path / "x.bin", generation="2.x")
    with pytest.raises(ValueError, match="generation must be one of new, old"):
        write_ulog(flight, tmp_path / "x.ulg", generation="1.8")
    with pytest.raises(ValueError, match="rate within"):
        BootClock(rate=0.0)
    car = dataclasses.replace(flight, config=SimConfig.for_vehicle("car"))
    with pytest.raises(ValueError, match="drone flights"):
        write_dataflash(car, tmp_path / "x.bin")
    assert not list(tmp_path.iterdir())
