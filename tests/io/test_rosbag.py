"""ROS 1 and ROS 2 bags in (georef.io.rosbag): the same trajectory as from imu.csv + gnss.csv, the axis and
covariance conversions element by element, skipped fixes, topic choice, located errors.

The bags are written here with rosbags' own writers (ROS 1 v2.0; ROS 2 v9, sqlite3 and mcap), the sensor_msgs
definitions of ROS 1 Noetic and ROS 2 Humble, and the FRD -> FLU and NED -> ENU conversions written out by hand
(not with georef.frames.ros, so a sign slip there cannot cancel against itself).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from georef_cli.main import app
from typer.testing import CliRunner

from georef.frames.ros import flu_to_frd, seconds_to_stamp, stamp_to_seconds
from georef.io.errors import InputError
from georef.io.generic import read_gnss_csv, read_imu_csv
from georef.io.rosbag import STATUS_NO_FIX, read_bag

RUNNER = CliRunner()
G = 9.80665


@dataclass
class GnssMsg:
    """One NavSatFix to write: time [s], lat/lon [deg], altitude [m], ENU covariance (9,) [m^2], its type, status."""

    time: float
    lat: float
    lon: float
    alt: float
    cov_enu: np.ndarray
    cov_type: int = 2
    status: int = 0


def _stamp(typestore, seconds: float):
    whole = int(np.floor(seconds))
    nanosec = int(round((seconds - whole) * 1e9))
    if nanosec == 1_000_000_000:
        whole, nanosec = whole + 1, 0
    return typestore.types["builtin_interfaces/msg/Time"](sec=whole, nanosec=nanosec)


def _header(typestore, seconds: float, frame_id: str, ros1: bool):
    header = typestore.types["std_msgs/msg/Header"]
    stamp = _stamp(typestore, seconds)
    return header(seq=0, stamp=stamp, frame_id=frame_id) if ros1 else header(stamp=stamp, frame_id=frame_id)


def imu_message(typestore, ros1: bool, seconds: float, rate_flu, force_flu, orientation: bool = False,
                frame_id: str = "imu_link"):
    t = typestore.types
    vector, quaternion = t["geometry_msgs/msg/Vector3"], t["geometry_msgs/msg/Quaternion"]
    unknown = np.zeros(9)
    absent = np.zeros(9)
    absent[0] = -1.0
    return t["sensor_msgs/msg/Imu"](
        header=_header(typestore, seconds, frame_id, ros1),
        orientation=quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
        orientation_covariance=unknown if orientation else absent,
        angular_velocity=vector(x=float(rate_flu[0]), y=float(rate_flu[1]), z=float(rate_flu[2])),
        angular_velocity_covariance=unknown,
        linear_acceleration=vector(x=float(force_flu[0]), y=float(force_flu[1]), z=float(force_flu[2])),
        linear_acceleration_covariance=unknown)


def fix_message(typestore, ros1: bool, fix: GnssMsg):
    t = typestore.types
    status = t["sensor_msgs/msg/NavSatStatus"](status=fix.status, service=1)
    return t["sensor_msgs/msg/NavSatFix"](
        header=_header(typestore, fix.time, "gps", ros1), status=status, latitude=fix.lat, longitude=fix.lon,
        altitude=fix.alt, position_covariance=np.asarray(fix.cov_enu, float), position_covariance_type=fix.cov_type)


def write_bag(path: Path, imu_rows: list[tuple[float, np.ndarray, np.ndarray]], fixes: list[GnssMsg],
              version: str = "ros1", imu_topics: tuple[str, ...] = ("/imu/data",),
              gnss_topics: tuple[str, ...] = ("/gps/fix",), record_delay: float = 0.004,
              orientation: bool = False, imu_record: list[float] | None = None,
              frame_ids: list[str] | None = None, gnss_record_delay: float | None = None) -> Path:
    """A bag holding the IMU rows (time [s], rate FLU [rad/s], specific force FLU [m/s^2]) on each of
    ``imu_topics`` and the fixes on each of ``gnss_topics``, recorded ``record_delay`` [s] after their stamps
    (the IMU rows: after ``imu_record`` [s] when given, so that stamps can run out of the record order);
    ``frame_ids``: the IMU messages' frame ids (default imu_link); ``gnss_record_delay`` [s]: the fixes' own delay.

    ``version``: "ros1" (path.bag), "ros2" (sqlite3) or "mcap" (ROS 2, mcap storage)."""
    from rosbags.typesys import Stores, get_typestore

    ros1 = version == "ros1"
    typestore = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    if ros1:
        from rosbags.rosbag1 import Writer

        writer = Writer(path)
        serialize = typestore.serialize_ros1
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        plugin = StoragePlugin.MCAP if version == "mcap" else StoragePlugin.SQLITE3
        writer = Writer(path, version=9, storage_plugin=plugin)
        serialize = typestore.serialize_cdr
    imu_type, gnss_type = "sensor_msgs/msg/Imu", "sensor_msgs/msg/NavSatFix"
    records: list[tuple[int, int, str, object]] = []  # (record ns, order, topic, message)
    for k, (seconds, rate, force) in enumerate(imu_rows):
        message = imu_message(typestore, ros1, seconds, rate, force, orientation,
                              "imu_link" if frame_ids is None else frame_ids[k])
        recorded = (seconds if imu_record is None else imu_record[k]) + record_delay
        records += [(int(round(recorded * 1e9)), k, topic, message) for topic in imu_topics]
    for k, fix in enumerate(fixes):
        message = fix_message(typestore, ros1, fix)
        delay = record_delay if gnss_record_delay is None else gnss_record_delay
        records += [(int(round((fix.time + delay) * 1e9)), k, topic, message) for topic in gnss_topics]
    with writer:
        connections = {topic: writer.add_connection(topic, imu_type, typestore=typestore) for topic in imu_topics}
        connections |= {topic: writer.add_connection(topic, gnss_type, typestore=typestore) for topic in gnss_topics}
        for record_ns, _, topic, message in sorted(records, key=lambda r: (r[0], r[1], r[2])):
            writer.write(connections[topic], record_ns, serialize(message, message.__msgtype__))
    return path


def csv_to_bag_rows(imu_csv: Path, gnss_csv: Path) -> tuple[list, list[GnssMsg]]:
    """imu.csv / gnss.csv (FRD, NED sigmas) as bag rows: FLU by hand (y and z negated), the NED sigmas as a
    diagonal ENU covariance (east variance first)."""
    imu = pd.read_csv(imu_csv)
    gnss = pd.read_csv(gnss_csv)
    rows = [(float(r.time), np.array([r.gyro_x, -r.gyro_y, -r.gyro_z]), np.array([r.acc_x, -r.acc_y, -r.acc_z]))
            for r in imu.itertuples()]
    fixes = [GnssMsg(float(r.time), float(r.lat), float(r.lon), float(r.height),
                     np.diag([r.sigma_e**2, r.sigma_n**2, r.sigma_u**2]).ravel(), 2) for r in gnss.itertuples()]
    return rows, fixes


@pytest.fixture(scope="module")
def car(tmp_path_factory) -> Path:
    """A 40 s simulated drive with imu.csv and gnss.csv (time scale moved to Unix seconds, as a ROS clock
    stamps), and their fused trajectory."""
    folder = tmp_path_factory.mktemp("rosbag") / "car"
    result = RUNNER.invoke(app, ["simulate", str(folder), "--vehicle", "car", "--duration", "40", "--seed", "3",
                                 "--generic", "-q"])
    assert result.exit_code == 0, result.output
    # a ROS wall clock: Unix seconds of 2026-11-26 (the times keep 4 decimals, exact on both paths' rounding)
    unix_start = 1_795_996_800.0
    for name in ("imu.csv", "gnss.csv"):
        table = pd.read_csv(folder / name)
        table["time"] = np.round(table["time"] + unix_start, 4)
        if name == "gnss.csv":  # north and east sigmas that differ, so that a swap of the two shows
            table["sigma_e"] = 1.3 * table["sigma_n"]
        table.to_csv(folder / name, index=False, float_format="%.12g")
    traj = RUNNER.invoke(app, ["fuse", "--imu", str(folder / "imu.csv"), "--gnss", str(folder / "gnss.csv"),
                               "--config", str(folder / "flight.toml"), "-o", str(folder / "traj.csv"), "-q"])
    assert traj.exit_code == 0, traj.output
    return folder


def _bag_of(car: Path, version: str) -> Path:
    rows, fixes = csv_to_bag_rows(car / "imu.csv", car / "gnss.csv")
    return write_bag(car / {"ros1": "flight.bag", "ros2": "flight_db3", "mcap": "flight_mcap"}[version], rows,
                     fixes, version)


@pytest.mark.parametrize("version", ["ros1", "ros2", "mcap"])
def test_bag_gives_the_same_trajectory_as_the_csv_pair(car, version, tmp_path):
    bag = car / {"ros1": "flight.bag", "ros2": "flight_db3", "mcap": "flight_mcap"}[version]
    if not bag.exists():
        _bag_of(car, version)
    # the inputs value by value: FRD rates and forces, times, positions, NED sigmas
    read = read_bag(bag)
    time, gyro, accel, _ = read_imu_csv(car / "imu.csv")
    fixes = read_gnss_csv(car / "gnss.csv")
    np.testing.assert_allclose(read.time, time, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(read.gyro, gyro)
    np.testing.assert_array_equal(read.accel, accel)
    np.testing.assert_allclose(read.gnss.time, fixes.time, rtol=0, atol=1e-6)
    for name in ("lat_deg", "lon_deg", "height"):
        np.testing.assert_array_equal(getattr(read.gnss, name), getattr(fixes, name))
    np.testing.assert_allclose(read.gnss.sigma_neu, fixes.sigma_neu, rtol=1e-12)
    assert read.kind == {"ros1": "ROS 1 bag", "ros2": "ROS 2 bag (sqlite3)", "mcap": "ROS 2 bag (mcap)"}[version]
    # the trajectory: fuse --bag against fuse --imu --gnss
    out = tmp_path / "traj.csv"
    result = RUNNER.invoke(app, ["fuse", "--bag", str(bag), "--config", str(car / "flight.toml"), "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert "/imu/data" in result.output and "/gps/fix" in result.output
    a, b = pd.read_csv(car / "traj.csv"), pd.read_csv(out)
    assert len(a) == len(b) > 1500
    np.testing.assert_allclose(b["time"], a["time"], rtol=0, atol=1e-6)
    # traj.csv keeps the stamps' fractions (Unix seconds need 16 digits): every row is an IMU message's time
    nearest = time[np.clip(np.searchsorted(time, b["time"]), 0, len(time) - 1)]
    np.testing.assert_allclose(b["time"], nearest, rtol=0, atol=1e-6)
    metres_per_deg = 111_320.0
    assert np.abs(b["lat"] - a["lat"]).max() * metres_per_deg < 1e-3
    assert np.abs(b["lon"] - a["lon"]).max() * metres_per_deg < 1e-3
    assert np.abs(b["height"] - a["height"]).max() < 1e-3
    for angle in ("roll", "pitch"):
        assert np.abs(b[angle] - a[angle]).max() < 1e-6, angle
    assert np.abs((b["yaw"] - a["yaw"] + 180.0) % 360.0 - 180.0).max() < 1e-6
    for sigma in ("sigma_n", "sigma_e", "sigma_u", "sigma_roll", "sigma_pitch", "sigma_yaw"):
        np.testing.assert_allclose(b[sigma], a[sigma], rtol=1e-6, err_msg=sigma)


def test_process_bag_gives_the_same_eo_table_as_the_csv_files(car, tmp_path):
    bag = car / "flight.bag"
    if not bag.exists():
        _bag_of(car, "ros1")
    imu_time = pd.read_csv(car / "imu.csv")["time"]
    times = np.arange(imu_time.iloc[0] + 10.0, imu_time.iloc[-1] - 5.0, 2.5).round(4)
    events = tmp_path / "events.csv"
    pd.DataFrame({"time": times, "image": [f"IMG_{i:04d}.JPG" for i in range(len(times))]}).to_csv(
        events, index=False, float_format="%.12g")
    common = ["--events", str(events), "--config", str(car / "flight.toml"), "-q"]
    from_csv = RUNNER.invoke(app, ["process", "--imu", str(car / "imu.csv"), "--gnss", str(car / "gnss.csv"),
                                   *common, "-o", str(tmp_path / "csv.csv")])
    from_bag = RUNNER.invoke(app, ["process", "--bag", str(bag), *common, "-o", str(tmp_path / "bag.csv")])
    assert from_csv.exit_code == 0, from_csv.output
    assert from_bag.exit_code == 0, from_bag.output
    a, b = pd.read_csv(tmp_path / "csv.csv"), pd.read_csv(tmp_path / "bag.csv")
    assert list(a.columns) == list(b.columns) and len(a) == len(b) == len(times)
    assert list(b["image"]) == list(a["image"])
    np.testing.assert_allclose(b["time"], times, rtol=0, atol=1e-6)
    for column in a.columns:
        if pd.api.types.is_numeric_dtype(a[column]):
            tolerance = 1e-9 if column in ("lat", "lon") else 1e-6  # deg: 1e-9 deg is 0.1 mm
            np.testing.assert_allclose(b[column], a[column], rtol=0, atol=tolerance, err_msg=column)


# --- the conversions, element by element -----------------------------------------------------------------------

def _level_imu(t0: float = 1_700_000_000.0, n: int = 40, rate_hz: float = 100.0,
               rate_flu=(0.01, 0.02, 0.03), force_flu=(0.1, 0.2, G)) -> list:
    return [(t0 + k / rate_hz, np.array(rate_flu), np.array(force_flu)) for k in range(n)]


def _fix(t: float, status: int = 0, cov_enu=None, cov_type: int = 2, alt: float = 120.0) -> GnssMsg:
    cov = np.diag([0.25, 0.36, 1.0]).ravel() if cov_enu is None else np.asarray(cov_enu, float).ravel()
    return GnssMsg(t, 45.0 + 1e-7 * (t % 100), 16.0, alt, cov, cov_type, status)


def test_flu_rates_and_forces_become_frd(tmp_path):
    # a body rolling right, pitching up and yawing right has FRD rates (+, +, +): in REP 103's FLU the y (left)
    # and z (up) components are negative. A level IMU at rest reads +g on FLU z (REP 145), -g on FRD z.
    rows = _level_imu(rate_flu=(0.1, -0.2, -0.3), force_flu=(0.5, -1.5, G))
    bag = write_bag(tmp_path / "signs.bag", rows, [_fix(rows[0][0] + 0.1), _fix(rows[-1][0])])
    read = read_bag(bag)
    np.testing.assert_array_equal(read.gyro, np.tile([0.1, 0.2, 0.3], (len(rows), 1)))
    np.testing.assert_array_equal(read.accel, np.tile([0.5, 1.5, -G], (len(rows), 1)))
    np.testing.assert_array_equal(flu_to_frd([[1.0, 2.0, 3.0]]), [[1.0, -2.0, -3.0]])
    assert not any("upside down" in str(n) or "orientation" in str(n) for n in read.all_notices)
    # an IMU's own orientation (ENU-referenced, REP 145) is not used, and the notice says so
    oriented = read_bag(write_bag(tmp_path / "oriented.bag", rows, [_fix(rows[0][0] + 0.1)], orientation=True))
    np.testing.assert_array_equal(oriented.gyro, read.gyro)
    assert any(f"{len(rows)} message(s) carry the IMU's own orientation estimate: not used" in str(n)
               for n in oriented.all_notices)
    # a driver that publishes z down (not REP 103) is named, not silently taken
    flipped = write_bag(tmp_path / "ned.bag", _level_imu(force_flu=(0.0, 0.0, -G)), [_fix(1_700_000_000.1)])
    assert any("upside down" in str(n) and "linear_acceleration.z" in str(n) for n in read_bag(flipped).all_notices)


def test_covariance_enu_to_ned(tmp_path):
    t0 = 1_700_000_000.0
    cov_enu = np.array([[4.0, 0.5, 0.3],   # east: var 4, cov(E, N) 0.5, cov(E, U) 0.3
                        [0.5, 9.0, -0.7],  # north: var 9, cov(N, U) -0.7
                        [0.3, -0.7, 16.0]])
    fixes = [_fix(t0 + 0.05, cov_enu=cov_enu, cov_type=3),        # known: every term
             _fix(t0 + 0.10, cov_enu=cov_enu, cov_type=2),        # diagonal known: the cross terms are not
             _fix(t0 + 0.15, cov_enu=cov_enu, cov_type=0),        # unknown: the configured sigma
             _fix(t0 + 0.20, cov_enu=cov_enu, cov_type=1)]        # approximated (DOP): used, with a notice
    read = read_bag(write_bag(tmp_path / "cov", _level_imu(t0), fixes, "mcap"))
    expected = np.array([[9.0, 0.5, 0.7],    # N: var(N), cov(N, E), cov(N, D) = -cov(N, U)
                         [0.5, 4.0, -0.3],   # E: cov(E, D) = -cov(E, U)
                         [0.7, -0.3, 16.0]])
    np.testing.assert_array_equal(read.gnss.cov_ned[0], expected)
    np.testing.assert_array_equal(read.gnss.cov_ned[1], np.diag([9.0, 4.0, 16.0]))
    assert np.isnan(read.gnss.cov_ned[2]).all() and np.isnan(read.gnss.sigma_neu[2]).all()
    np.testing.assert_array_equal(read.gnss.cov_ned[3], expected)
    np.testing.assert_array_equal(read.gnss.sigma_neu[[0, 1, 3]], np.tile([3.0, 2.0, 4.0], (3, 1)))
    text = " | ".join(map(str, read.all_notices))
    assert "1 fix(es) with an approximated covariance" in text
    assert "message 3, field position_covariance_type: 1 fix(es) without a covariance" in text
    # no covariance anywhere: no sigmas at all (the configured gnss_sigma), said so
    none = read_bag(write_bag(tmp_path / "none.bag", _level_imu(t0), [_fix(t0 + 0.1, cov_type=0)]))
    assert none.gnss.sigma_neu is None and none.gnss.cov_ned is None
    assert any("no fix carries a covariance" in str(n) for n in none.all_notices)


def test_no_fix_and_no_altitude_are_skipped_with_a_notice(tmp_path, car):
    t0 = 1_700_000_000.0
    fixes = [_fix(t0 + 0.05), _fix(t0 + 0.10, status=STATUS_NO_FIX), _fix(t0 + 0.15),
             _fix(t0 + 0.20, alt=float("nan")), _fix(t0 + 0.25, status=STATUS_NO_FIX), _fix(t0 + 0.30, status=2)]
    read = read_bag(write_bag(tmp_path / "fix.bag", _level_imu(t0), fixes))
    np.testing.assert_allclose(read.gnss.time, [t0 + 0.05, t0 + 0.15, t0 + 0.30], rtol=0, atol=1e-6)
    np.testing.assert_array_equal(read.gnss.line, [1, 3, 6])  # message numbers in the topic
    text = " | ".join(map(str, read.all_notices))
    assert "/gps/fix, messages 2, 5, field status.status: 2 message(s) without a fix (status -1) skipped" in text
    assert "/gps/fix, message 4, field latitude/longitude/altitude: 1 fix(es) without a full position" in text
    # none left is an error that says why
    nothing = write_bag(tmp_path / "nothing.bag", _level_imu(t0), [_fix(t0 + 0.1, status=STATUS_NO_FIX),
                                                                   _fix(t0 + 0.2, alt=float("nan"))])
    with pytest.raises(InputError, match=r"/gps/fix: no usable fix in 2 message\(s\): 1 without a fix \(status -1\), "
                                         r"1 without a full position"):
        read_bag(nothing)
    # fuse prints them: the car's bag with every 10th fix lost
    rows, car_fixes = csv_to_bag_rows(car / "imu.csv", car / "gnss.csv")
    for fix in car_fixes[5::10]:
        fix.status = STATUS_NO_FIX
    bag = write_bag(tmp_path / "lost.bag", rows, car_fixes)
    result = RUNNER.invoke(app, ["fuse", "--bag", str(bag), "--config", str(car / "flight.toml"), "-o",
                                 str(tmp_path / "traj.csv")])
    assert result.exit_code in (0, 4), result.output
    assert f"{len(car_fixes[5::10])} message(s) without a fix (status -1) skipped" in result.output
    assert f"GNSS {len(car_fixes) - len(car_fixes[5::10])} fixes" in result.output


def test_stamps_are_seconds_and_nanoseconds():
    # float64 steps at 1.8e9 s are 2**-22 s (0.24 us): .25 is exact there, .0125 is not
    unix = np.array([1_795_996_800.25, 1_795_996_800.0125, 1_795_996_800.99999999, 12.5])
    sec, nanosec = seconds_to_stamp(unix)
    np.testing.assert_array_equal(sec, [1_795_996_800, 1_795_996_800, 1_795_996_801, 12])
    np.testing.assert_array_equal(nanosec[[0, 2, 3]], [250_000_000, 0, 500_000_000])
    assert abs(int(nanosec[1]) - 12_500_000) <= 120  # the nearest nanosecond of the float, not 1.8e18 ns rounded
    np.testing.assert_array_equal(stamp_to_seconds(sec[[0, 3]], nanosec[[0, 3]]), [1_795_996_800.25, 12.5])
    assert stamp_to_seconds(7, 999_999_999) == pytest.approx(7.999999999, abs=1e-12)


# --- topics and located errors ---------------------------------------------------------------------------------

def test_topic_choice(tmp_path):
    t0 = 1_700_000_000.0
    bag = write_bag(tmp_path / "two.bag", _level_imu(t0), [_fix(t0 + 0.1)], imu_topics=("/imu/data", "/imu/raw"))
    with pytest.raises(InputError, match=r"holds 2 sensor_msgs/Imu topics: /imu/data \(40 messages\), /imu/raw "
                                         r"\(40 messages\); choose one with --imu-topic"):
        read_bag(bag)
    assert read_bag(bag, imu_topic="/imu/raw").imu_topic == "/imu/raw"
    with pytest.raises(InputError, match=r"--imu-topic /imu: no such topic in the bag \(its sensor_msgs/Imu "
                                         r"topics: /imu/data, /imu/raw\)"):
        read_bag(bag, imu_topic="/imu")
    with pytest.raises(InputError, match="--gnss-topic /imu/raw: the topic holds sensor_msgs/msg/Imu, not "
                                         "sensor_msgs/NavSatFix"):
        read_bag(bag, imu_topic="/imu/raw", gnss_topic="/imu/raw")
    no_gnss = write_bag(tmp_path / "nognss.bag", _level_imu(t0), [], gnss_topics=())
    with pytest.raises(InputError, match=r"holds no sensor_msgs/NavSatFix topic \(it holds /imu/data "
                                         r"\(sensor_msgs/msg/Imu\)\)"):
        read_bag(no_gnss)
    # the CLI: exit 2 with the message; --bag excludes --imu/--gnss; topics need --bag
    result = RUNNER.invoke(app, ["fuse", "--bag", str(bag), "-o", str(tmp_path / "t.csv")])
    assert result.exit_code == 2 and "choose one with --imu-topic" in result.output
    both = RUNNER.invoke(app, ["fuse", "--bag", str(bag), "--imu", "imu.csv", "-o", str(tmp_path / "t.csv")])
    assert both.exit_code == 2 and "--bag takes the place of --imu and --gnss" in both.output
    topic = RUNNER.invoke(app, ["fuse", "--imu", "imu.csv", "--gnss", "g.csv", "--imu-topic", "/imu"])
    assert topic.exit_code == 2 and "--imu-topic picks a topic of --bag" in topic.output
    no_events = RUNNER.invoke(app, ["process", "--bag", str(bag), "--imu-topic", "/imu/raw"])
    assert no_events.exit_code == 2 and "--bag needs --events" in no_events.output
    positional = RUNNER.invoke(app, ["process", str(bag)])
    assert positional.exit_code == 2 and "is a ROS bag: give it as --bag" in positional.output
    # georef info lists the topics and says which one is read
    info = RUNNER.invoke(app, ["info", str(bag)])
    assert info.exit_code == 0, info.output
    assert re.search(r"/imu/raw\s+│ sensor_msgs/msg/Imu, 40 messages", info.output)
    assert re.search(r"sensor_msgs/NavSatFix read\s+│ /gps/fix \(default\)", info.output)
    assert "holds 2 sensor_msgs/Imu topics" in info.output


@pytest.mark.parametrize("version", ["ros1", "ros2"])
def test_stamp_errors_name_bag_topic_message_and_field(tmp_path, version):
    t0 = 1_700_000_000.0
    rows = _level_imu(t0)
    record = [row[0] for row in rows]
    rows[17] = (rows[15][0], rows[17][1], rows[17][2])  # message 18 stamped before message 17
    bag = write_bag(tmp_path / ("back.bag" if version == "ros1" else "back"), rows, [_fix(t0 + 0.1)], version,
                    imu_record=record)
    with pytest.raises(InputError) as caught:
        read_bag(bag)
    assert str(caught.value).startswith(f"{bag}: /imu/data, message 18, field header.stamp: the stamp goes "
                                        f"backwards from {t0 + 0.16:.6f} s (message 17) to {t0 + 0.15:.6f} s")
    rows[17] = (rows[16][0], rows[17][1], rows[17][2])  # the same stamp twice
    bag = write_bag(tmp_path / ("same.bag" if version == "ros1" else "same"), rows, [_fix(t0 + 0.1)], version,
                    imu_record=record)
    with pytest.raises(InputError, match=r"/imu/data, message 18, field header.stamp: the stamp repeats "
                                         rf"{t0 + 0.16:.6f} s \(message 17\)"):
        read_bag(bag)
    unstamped = _level_imu(0.0)  # a driver that leaves header.stamp at 0 on its first message
    bag = write_bag(tmp_path / ("zero.bag" if version == "ros1" else "zero"), unstamped, [_fix(0.1)], version)
    with pytest.raises(InputError, match=r"/imu/data, message 1, field header.stamp: the stamp is 0"):
        read_bag(bag)
    # GNSS stamped on another clock (GPS seconds of the week against Unix time): no overlap is an error
    other = write_bag(tmp_path / ("clock.bag" if version == "ros1" else "clock"), _level_imu(t0), [_fix(400_000.0)],
                      version)
    with pytest.raises(InputError, match="/gps/fix, field header.stamp: the fixes .* lie outside the IMU's span"):
        read_bag(other)
    # GNSS stamped 18 s early (GPS time read as UTC, or the reverse): within the span, but named in a notice
    late = write_bag(tmp_path / ("late.bag" if version == "ros1" else "late"), _level_imu(t0, n=3000),
                     [_fix(t0 + 1.0), _fix(t0 + 2.0)], version, gnss_record_delay=18.0)
    text = " | ".join(map(str, read_bag(late).all_notices))
    assert "/gps/fix, field header.stamp: its stamps lag the record time by 18.000 s but the IMU's by 0.004 s" in text


def test_what_is_not_a_bag(tmp_path):
    (tmp_path / "folder").mkdir()
    with pytest.raises(InputError, match="has no metadata.yaml"):
        read_bag(tmp_path / "folder")
    (tmp_path / "lone.mcap").write_bytes(b"\x89MCAP0\r\n")
    with pytest.raises(InputError, match="read from its folder with metadata.yaml"):
        read_bag(tmp_path / "lone.mcap")
    t0 = 1_700_000_000.0
    ros1 = write_bag(tmp_path / "real.bag", _level_imu(t0), [_fix(t0 + 0.1)])
    renamed = tmp_path / "real.dat"
    renamed.write_bytes(ros1.read_bytes())
    with pytest.raises(InputError, match="a ROS 1 bag, but its name does not end in .bag"):
        read_bag(renamed)
    (tmp_path / "imu.csv").write_text("time,gyro_x\n")
    with pytest.raises(InputError, match="not a ROS bag"):
        read_bag(tmp_path / "imu.csv")
    # a ROS 2 bag given as its .db3 file: read from its folder
    ros2 = write_bag(tmp_path / "r2", _level_imu(t0), [_fix(t0 + 0.1)], "ros2")
    db3 = next(ros2.glob("*.db3"))
    assert len(read_bag(db3).time) == 40
    # a rate that is not reported (covariance[0] = -1) is an error naming the field
    broken = write_bag(tmp_path / "nan.bag", _level_imu(t0, rate_flu=(np.nan, 0.0, 0.0)), [_fix(t0 + 0.1)])
    with pytest.raises(InputError, match=r"/imu/data, message 1, field angular_velocity.x: nan is not a number"):
        read_bag(broken)


def test_ros2_bag_without_message_definitions(tmp_path):
    # a ROS 2 bag recorded before the definitions were stored (SQLite 3, as Humble's rosbag2 wrote): the
    # standard sensor_msgs layouts stand in
    import sqlite3

    t0 = 1_700_000_000.0
    bag = write_bag(tmp_path / "humble", _level_imu(t0, rate_flu=(0.1, 0.2, 0.3)), [_fix(t0 + 0.1)], "ros2")
    with sqlite3.connect(next(bag.glob("*.db3"))) as db:
        assert db.execute("SELECT COUNT(*) FROM message_definitions").fetchone()[0] == 2
        db.execute("DELETE FROM message_definitions")
    metadata = bag / "metadata.yaml"
    text, hashes = re.subn(r"type_description_hash:\s+RIHS01_[0-9a-f]+", "type_description_hash: ''",
                           metadata.read_text())
    assert hashes == 2
    metadata.write_text(text)
    read = read_bag(bag)
    np.testing.assert_array_equal(read.gyro, np.tile([0.1, -0.2, -0.3], (40, 1)))
    np.testing.assert_allclose(read.gnss.time, [t0 + 0.1], rtol=0, atol=1e-6)


@pytest.mark.parametrize("version", ["ros1", "ros2", "mcap"])
def test_fast_imu_parse_equals_the_deserialiser(tmp_path, version):
    # the byte-level reading of the standard layout (one frame_id length) against rosbags' deserialiser, row by
    # row, on rates and forces that differ in every message; then a bag whose frame_id changes length half-way,
    # which the fast reading refuses and the deserialiser reads
    from georef.io.rosbag import _imu_chunk_fast, _imu_chunk_generic, _open

    t0 = 1_700_000_000.0
    rng = np.random.default_rng(5)
    rows = [(t0 + k / 100.0, rng.normal(0, 0.5, 3), rng.normal(0, 3.0, 3) + [0, 0, G]) for k in range(60)]
    name = {"ros1": "fast.bag", "ros2": "fast", "mcap": "fast_mcap"}[version]
    bag = write_bag(tmp_path / name, rows, [_fix(t0 + 0.1)], version, orientation=True)
    with _open(bag) as reader:
        connections = [c for c in reader.connections if c.topic == "/imu/data"]
        raws, records = zip(*((bytes(raw), ns) for _, ns, raw in reader.messages(connections=connections)),
                            strict=True)
        fast = _imu_chunk_fast(reader, list(raws), list(records))
        slow = _imu_chunk_generic(reader, list(raws), list(records))
    assert fast is not None
    for field_name in ("sec", "nanosec", "values", "cov0", "record_ns"):
        np.testing.assert_array_equal(getattr(fast, field_name), getattr(slow, field_name), err_msg=field_name)
    assert fast.frame_ids == slow.frame_ids == {"imu_link"}
    np.testing.assert_array_equal(slow.values[:, :3], [r[1] for r in rows])
    np.testing.assert_array_equal(fast.cov0[:, 0], np.zeros(60))  # orientation given: its covariance[0] is 0
    mixed = write_bag(tmp_path / f"mixed_{name}", rows, [_fix(t0 + 0.1)], version,
                      frame_ids=["imu"] * 30 + ["imu_link_rotated"] * 30)
    with _open(mixed) as reader:
        connections = [c for c in reader.connections if c.topic == "/imu/data"]
        raws = [bytes(raw) for _, _, raw in reader.messages(connections=connections)]
        assert _imu_chunk_fast(reader, raws, list(range(60))) is None
    read = read_bag(mixed)
    np.testing.assert_array_equal(read.gyro, flu_to_frd([r[1] for r in rows]))
    assert any("frame_id 'imu', 'imu_link_rotated'" in str(n) for n in read.all_notices)


def test_a_bag_without_heading_gets_advice_for_bags(tmp_path):
    # a vehicle standing still: no motion shows the heading, and a bag gives no magnetometer: QC fails the
    # heading with the advice for a bag (not POS.txt's)
    t0 = 1_700_000_000.0
    rng = np.random.default_rng(1)
    rows = [(t0 + k / 50.0, rng.normal(0, 1e-3, 3), np.array([0.0, 0.0, G]) + rng.normal(0, 0.02, 3))
            for k in range(50 * 30)]
    bag = write_bag(tmp_path / "still.bag", rows, [_fix(t0 + 0.5 + k) for k in range(29)])
    result = RUNNER.invoke(app, ["fuse", "--bag", str(bag), "-o", str(tmp_path / "traj.csv")])
    assert result.exit_code == 4, result.output
    text = re.sub(r"\s+", " ", result.output)
    assert "QC fail heading" in text and "georef reads no magnetometer or IMU orientation from a bag" in text
    assert "POS unit" not in text


# --- an Emlid/RTKLIB _events.pos with a bag: its times go to Unix seconds ------------------------------------------

#: GPS - UTC in 2026 [s] (IERS Bulletin C: 18 s since 2017-01-01), written out here, not taken from georef
GPS_MINUS_UTC_2026 = 18
EVENTS_POS_HEADER = [
    "% program   : Emlid Studio",
    "% (lat/lon/height=WGS84/ellipsoidal,Q=1:fix,2:float,3:sbas,4:dgps,5:single,6:ppp,ns=# of satellites)",
    "%  GPST                  latitude(deg) longitude(deg)  height(m)   Q  ns   sdn(m)   sde(m)   sdu(m)  sdne(m)  "
    "sdeu(m)  sdun(m) age(s)  ratio",
]


def _events_pos(path: Path, unix_times: np.ndarray, invalid: tuple[int, ...] = ()) -> Path:
    """The time marks of ``unix_times`` [s, UTC, whole milliseconds] as demo5/Emlid Studio writes them: GPS time,
    calendar format; the marks numbered in ``invalid`` as 'Time mark is not valid' lines."""
    import datetime as dt

    lines = [*EVENTS_POS_HEADER]
    for k, t in enumerate(unix_times):
        whole, ms = divmod(int(round((t + GPS_MINUS_UTC_2026) * 1000.0)), 1000)
        stamp = f"{dt.datetime.fromtimestamp(whole, tz=dt.UTC):%Y/%m/%d %H:%M:%S}.{ms:03d}"
        lines.append(f"{stamp}   Q=0, Time mark is not valid" if k in invalid else
                     f"{stamp}   45.000000000   16.000000000   120.0000   1   9   0.0100   0.0100   0.0200   0.0000   "
                     "0.0000   0.0000   0.00    0.0")
    path.write_text("\n".join(lines) + "\n")
    return path


def test_bag_with_an_events_pos_gives_the_eo_of_events_csv(car, tmp_path):
    """``process --bag --events flight_events.pos``: the marks (GPS time) go to Unix seconds, the bag's stamps, and
    the EO table is that of the same times as events.csv. Without the 18 leap seconds every exposure would be
    placed 18 s late, hundreds of metres along the drive."""
    bag = car / "flight.bag"
    if not bag.exists():
        _bag_of(car, "ros1")
    imu_time = pd.read_csv(car / "imu.csv")["time"]
    times = np.arange(imu_time.iloc[0] + 10.0, imu_time.iloc[-1] - 5.0, 2.503).round(3)  # every millisecond digit
    events_csv = tmp_path / "events.csv"
    # a hot-shoe mark's time sigma, which georef gives the _events.pos marks (FEEDBACK_TIME_SIGMA, 2 ms)
    pd.DataFrame({"time": times, "time_sigma": 0.002}).to_csv(events_csv, index=False, float_format="%.6f")
    events_pos = _events_pos(tmp_path / "flight_events.pos", times, invalid=(3,))
    common = ["process", "--bag", str(bag), "--config", str(car / "flight.toml")]
    from_csv = RUNNER.invoke(app, [*common, "--events", str(events_csv), "-q", "-o", str(tmp_path / "csv.csv")])
    from_pos = RUNNER.invoke(app, [*common, "--events", str(events_pos), "-v", "-o", str(tmp_path / "pos.csv")])
    assert from_csv.exit_code == 0, from_csv.output
    assert from_pos.exit_code == 0, from_pos.output
    assert "camera events taken as Unix seconds" in " ".join(from_pos.output.split())
    a, b = pd.read_csv(tmp_path / "csv.csv"), pd.read_csv(tmp_path / "pos.csv")
    assert list(a.columns) == list(b.columns) and len(a) == len(b) == len(times)
    assert list(b["frame"]) == list(a["frame"]) == list(range(1, len(times) + 1))
    np.testing.assert_allclose(b["time"], times, rtol=0, atol=1e-6)
    for column in a.columns:
        if pd.api.types.is_numeric_dtype(a[column]):
            tolerance = 1e-9 if column in ("lat", "lon") else 1e-6  # deg: 1e-9 deg is 0.1 mm
            np.testing.assert_allclose(b[column], a[column], rtol=0, atol=tolerance, err_msg=column)


def test_bag_and_events_pos_on_different_clocks_is_exit_2_naming_both(car, tmp_path):
    """A bag stamped on a simulated clock (seconds since start) cannot take an _events.pos: exit 2 with the bag's
    span and the marks' on every scale. A scale asked for that is not the bag's names the one that fits, and
    --time-scale with an events.csv is refused."""
    t0 = 100.0
    sim_clock = write_bag(tmp_path / "sim.bag", _level_imu(t0), [_fix(t0 + 0.1)])
    unix = 1_795_996_800.0 + np.array([3600.0, 3602.5])  # 2026-11-30 01:00:00 UTC
    events_pos = _events_pos(tmp_path / "flight_events.pos", unix)
    result = RUNNER.invoke(app, ["process", "--bag", str(sim_clock), "--events", str(events_pos), "-o",
                                 str(tmp_path / "eo.csv"), "-q"])
    text = " ".join(result.output.split())
    assert result.exit_code == 2, result.output
    assert "the bag's IMU's times span 100.000 - 100.390 s" in text
    assert f"as Unix seconds (UTC since 1970-01-01) {unix[0]:.3f} - {unix[1]:.3f} s" in text
    assert "as UTC seconds of 2026-11-30 3600.000 - 3602.500 s" in text
    assert "--time-scale" in text
    bag = car / "flight.bag"
    if not bag.exists():
        _bag_of(car, "ros1")
    imu_time = pd.read_csv(car / "imu.csv")["time"]
    marks = _events_pos(tmp_path / "marks.pos", imu_time.iloc[[100, 200]].round(3).to_numpy())
    wrong = RUNNER.invoke(app, ["process", "--bag", str(bag), "--events", str(marks), "--time-scale", "utc-day",
                                "-o", str(tmp_path / "eo.csv"), "-q"])
    assert wrong.exit_code == 2 and "they overlap it as unix: give --time-scale unix" in " ".join(wrong.output.split())
    events_csv = tmp_path / "events.csv"
    pd.DataFrame({"time": imu_time.iloc[[100, 200]]}).to_csv(events_csv, index=False, float_format="%.12g")
    idle = RUNNER.invoke(app, ["process", "--bag", str(bag), "--events", str(events_csv), "--time-scale", "unix"])
    assert idle.exit_code == 2 and "--events hold none" in " ".join(idle.output.split())


def test_events_in_seconds_of_day_against_a_bags_unix_stamps_get_advice_for_bags(car, tmp_path):
    """events.csv in UTC seconds of the day with a bag stamped in Unix seconds: every frame outside the navigation
    span, exit 4 (as POS.txt and autopilot logs with a camera clock that misses the log). The advice must fit a bag
    user: the exposure times are seconds of a day, not Unix time, both spans named; not --camera-utc-offset, which
    is for POS.txt's raw camera logs."""
    bag = car / "flight.bag"
    if not bag.exists():
        _bag_of(car, "ros1")
    unix_day = 1_795_996_800.0  # 2026-11-30 00:00 UTC (20787 days after 1970-01-01), the car fixture's day
    imu_time = pd.read_csv(car / "imu.csv")["time"]
    times = np.arange(imu_time.iloc[0] + 10.0, imu_time.iloc[-1] - 5.0, 2.5).round(4) - unix_day
    events = tmp_path / "events.csv"
    pd.DataFrame({"time": times}).to_csv(events, index=False, float_format="%.12g")
    result = RUNNER.invoke(app, ["process", "--bag", str(bag), "--events", str(events), "--config",
                                 str(car / "flight.toml"), "-o", str(tmp_path / "eo.csv"), "-q"])
    text = " ".join(result.output.split())
    assert result.exit_code == 4, result.output
    frames = text.split("QC fail frames:", 1)[1].split("QC ", 1)[0]
    assert f"{len(times)} of {len(times)} frames lie outside the navigation span" in frames
    assert f"exposure times {times.min():.1f} to {times.max():.1f} s" in frames
    assert "seconds of a day or a GPS week, not Unix time" in frames and "header.stamp" in frames
    assert f"add its 00:00 UTC, {unix_day:.0f} s (2026-11-30), to every time in events.csv" in frames
    assert "--camera-utc-offset" not in frames
