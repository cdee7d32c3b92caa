"""ROS 1 and ROS 2 bags in: sensor_msgs/Imu and sensor_msgs/NavSatFix as georef's generic IMU and GNSS inputs.

>>> bag = read_bag("flight.bag")                     # or a ROS 2 bag: its folder (metadata.yaml + .db3 / .mcap)
>>> bag.time, bag.gyro, bag.accel, bag.gnss          # s, rad/s FRD, m/s^2 FRD, GnssEpochs (NED sigmas)

Read with ``rosbags`` (:class:`rosbags.highlevel.AnyReader`), no ROS installation needed. The message types come
from the definitions the bag holds (a ROS 2 bag without them: the ROS 2 Humble definitions).

* ``sensor_msgs/Imu``: ``angular_velocity`` [rad/s] and ``linear_acceleration`` [m/s^2] on the IMU's axes,
  which REP 103 and REP 145 make forward-left-up; REP 145 defines ``linear_acceleration`` as the specific force
  (a level IMU at rest reads +g on its up axis), which is what georef's imu.csv holds. Both are turned to
  georef's forward-right-down by :data:`georef.frames.ros.C_flu_b`. ``orientation`` (an optional estimate
  referenced to an ENU or NED world frame with a magnetic or arbitrary yaw origin) is not used.
* ``sensor_msgs/NavSatFix``: ``latitude``, ``longitude`` [deg], ``altitude`` [m above the WGS 84 ellipsoid],
  the antenna's position; a fix with ``status.status`` -1 (no fix) or without a position is skipped with a
  notice; ``position_covariance`` (ENU, row-major, m^2) is turned to NED
  (:func:`georef.frames.position_covariance.enu_to_ned_covariance`) unless its type is 0 (unknown), and gives the
  fix's covariance ``cov_ned`` and sigmas ``sigma_neu``.
* Time: every message's ``header.stamp`` (the measurement's time as the driver stamped it), not the bag's record
  time; both topics must be on one clock, strictly increasing for the IMU.

Errors name the bag, the topic, the message (1-based, in record order within its topic) and the field. In the
``lines`` of the results (and so in notices and in the summary's rejected fixes) a "line" is that message
number.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from georef.frames.position_covariance import enu_to_ned_covariance
from georef.frames.ros import flu_to_frd, stamp_to_seconds
from georef.io.errors import InputError, InputNotice
from georef.io.plausibility import GENERIC_LIMITS, check_gnss_jumps, check_ranges
from georef.io.pos import PosLog
from georef.timing import GnssEpochs, TimeRepairReport

IMU_TYPE = "sensor_msgs/msg/Imu"
GNSS_TYPE = "sensor_msgs/msg/NavSatFix"
#: NavSatStatus.status of a message without a fix
STATUS_NO_FIX = -1
#: NavSatFix.position_covariance_type values
COVARIANCE_TYPE_UNKNOWN = 0
COVARIANCE_TYPE_APPROXIMATED = 1
COVARIANCE_TYPE_DIAGONAL_KNOWN = 2
COVARIANCE_TYPE_KNOWN = 3
#: a covariance's element 0 set to this says "this quantity is not reported" (sensor_msgs/Imu)
NOT_REPORTED = -1.0
#: the name ending rosbags takes for a ROS 1 bag (anything else is opened as a ROS 2 bag)
ROS1_SUFFIX = ".bag"
#: a level IMU at rest reads +g on REP 103's up axis: a median specific force along "up" below this [m/s^2]
#: means the axes are not FLU (an FRD/NED-type driver, or an IMU mounted upside down)
UPSIDE_DOWN_FORCE = -4.9
#: IMU and GNSS topics whose median record-time-minus-stamp differ by more than this [s] look stamped on different
#: clocks (GPS time vs UTC is 18 s today; a simulated clock vs the wall clock, years)
CLOCK_MISMATCH_S = 1.0


@dataclass
class BagInputs:
    """The IMU and GNSS of a bag on georef's axes: what ``georef fuse --bag`` and ``georef process --bag`` use.

    ``time`` [s, the stamps' clock: for a wall clock Unix seconds, UTC], ``gyro`` (N, 3) [rad/s] and ``accel``
    (N, 3) [m/s^2, specific force] on body axes forward-right-down; ``lines`` the IMU message numbers (1-based);
    ``gnss`` the antenna fixes with NED sigmas [m] (NaN rows where the message gave no covariance)."""

    path: Path
    imu_topic: str
    gnss_topic: str
    time: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    lines: np.ndarray
    gnss: GnssEpochs
    #: "ROS 1 bag" or "ROS 2 bag (sqlite3)" / "ROS 2 bag (mcap)"
    kind: str
    #: what was read, converted or skipped on the IMU topic and the clocks (the GNSS topic's are ``gnss.notices``)
    notices: list[InputNotice] = field(default_factory=list)

    @property
    def all_notices(self) -> list[InputNotice]:
        """The IMU's and the GNSS's notices."""
        return [*self.notices, *self.gnss.notices]

    def to_pos_log(self) -> PosLog:
        """As :class:`georef.io.pos.PosLog` (``data`` in deg/s and m/s^2, like
        :func:`georef.io.generic.read_generic_log`) for :func:`georef.pipeline.process_bag`."""
        data = {f"gyro_{a}": np.degrees(self.gyro[:, i]) for i, a in enumerate("xyz")}
        data.update({f"acc_{a}": self.accel[:, i] for i, a in enumerate("xyz")})
        names = {**{f"gyro_{a}": f"{self.imu_topic} angular_velocity.{a}" for a in "xyz"},
                 **{f"acc_{a}": f"{self.imu_topic} linear_acceleration.{a}" for a in "xyz"}}
        return PosLog(path=self.path, time=self.time, data=data, lines=self.lines, gnss=self.gnss,
                      time_repairs=TimeRepairReport(), notices=self.all_notices, column_names=names,
                      kind=self.kind)


def bag_location(path: Path | str) -> Path:
    """The path rosbags opens: a ROS 1 ``.bag`` file, or a ROS 2 bag's folder (given as the folder or as a
    ``.db3``/``.mcap`` file in it). Anything else is an :class:`InputError` saying what a bag is."""
    path = Path(path)
    if not path.exists():
        raise InputError(path, None, None, "no such file or folder")
    if path.is_dir():
        if not (path / "metadata.yaml").is_file():
            raise InputError(path, None, None, "a ROS 2 bag is a folder with metadata.yaml beside its .db3 or .mcap "
                                               "files; this folder has no metadata.yaml")
        return path
    if path.suffix == ROS1_SUFFIX:
        return path
    if path.suffix in (".db3", ".mcap"):
        if (path.parent / "metadata.yaml").is_file():
            return path.parent
        raise InputError(path, None, None, "a ROS 2 bag is read from its folder with metadata.yaml, which is not "
                                           "beside this file (ros2 bag reindex rebuilds it)")
    with open(path, "rb") as handle:
        head = handle.read(13)
    if head == b"#ROSBAG V2.0\n":
        raise InputError(path, None, None, "a ROS 1 bag, but its name does not end in .bag, which the bag reader "
                                           "needs: rename it (or link it) to a .bag name")
    raise InputError(path, None, None, "not a ROS bag: give a ROS 1 .bag file or a ROS 2 bag's folder (with "
                                       "metadata.yaml)")


def _open(path: Path) -> Any:
    """An :class:`AnyReader` for the bag (not yet opened)."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    # a ROS 2 bag without message definitions (older SQLite 3 bags): the standard ones of Humble stand in
    return AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))


def _bag_errors() -> tuple[type[BaseException], ...]:
    from rosbags.highlevel import AnyReaderError
    from rosbags.rosbag1 import ReaderError as Reader1Error
    from rosbags.rosbag2 import ReaderError as Reader2Error
    from rosbags.serde import SerdeError

    return AnyReaderError, Reader1Error, Reader2Error, SerdeError


def is_bag(path: Path | str) -> bool:
    """Whether ``path`` names a bag (a ``.bag`` file, a folder with metadata.yaml, or a ``.db3``/``.mcap`` file
    beside one): what the commands read with :func:`read_bag` rather than as a table or an autopilot log."""
    path = Path(path)
    if path.is_dir():
        return (path / "metadata.yaml").is_file()
    if path.suffix == ROS1_SUFFIX:
        return path.is_file()
    return path.suffix in (".db3", ".mcap") and (path.parent / "metadata.yaml").is_file()


def describe_bag(path: Path | str) -> list[tuple[str, str]]:
    """(what, value) rows for ``georef info``: every topic with its type and message count, and which topics
    georef reads by default."""
    topics = list_topics(path)
    rows = [(name, f"{kind}, {count} messages") for name, (kind, count) in sorted(topics.items())]
    for msgtype, option in ((IMU_TYPE, "--imu-topic"), (GNSS_TYPE, "--gnss-topic")):
        short = msgtype.replace("/msg/", "/")
        try:
            chosen = f"{choose_topic(path, topics, msgtype, None, option)} (default)"
        except InputError as exc:
            chosen = exc.message.removeprefix("the bag ")
        rows.append((f"{short} read", chosen))
    return rows


def list_topics(path: Path | str) -> dict[str, tuple[str | None, int]]:
    """Topic -> (message type, message count) of every topic in the bag."""
    location = bag_location(path)
    try:
        with _open(location) as reader:
            return {name: (info.msgtype, info.msgcount) for name, info in reader.topics.items()}
    except _bag_errors() as exc:
        raise InputError(path, None, None, f"cannot read the bag: {exc}") from None


def choose_topic(path: Path | str, topics: dict[str, tuple[str | None, int]], msgtype: str, wanted: str | None,
                 option: str) -> str:
    """The topic of ``msgtype`` to read: ``wanted`` (checked), else the only one; none or several are an error
    listing what the bag holds (``option`` names the command-line option that picks one)."""
    short = msgtype.replace("/msg/", "/")
    of_type = sorted(name for name, (kind, _) in topics.items() if kind == msgtype)
    if wanted is not None:
        if wanted not in topics:
            listed = ", ".join(of_type) if of_type else f"none of type {short}"
            raise InputError(path, None, None, f"{option} {wanted}: no such topic in the bag (its {short} topics: "
                                               f"{listed})")
        if topics[wanted][0] != msgtype:
            raise InputError(path, None, None, f"{option} {wanted}: the topic holds {topics[wanted][0]}, not {short}")
        return wanted
    if not of_type:
        others = ", ".join(f"{name} ({kind})" for name, (kind, _) in sorted(topics.items())) or "no topics"
        raise InputError(path, None, None, f"the bag holds no {short} topic (it holds {others})")
    if len(of_type) > 1:
        listed = ", ".join(f"{name} ({topics[name][1]} messages)" for name in of_type)
        raise InputError(path, None, None, f"the bag holds {len(of_type)} {short} topics: {listed}; choose one with "
                                           f"{option}")
    return of_type[0]


def _messages(reader: Any, topic: str) -> Iterator[tuple[int, int, Any]]:
    """(message number from 1, record time [ns], message) of ``topic``, in record order."""
    connections = [c for c in reader.connections if c.topic == topic]
    for number, (connection, record_ns, raw) in enumerate(reader.messages(connections=connections), start=1):
        yield number, record_ns, reader.deserialize(raw, connection.msgtype)


class _Where:
    """Formats the place of a problem: the bag, the topic, the message number and the field."""

    def __init__(self, path: Path | str, topic: str):
        self.path, self.topic = path, topic

    def error(self, number: int | None, fieldname: str | None, message: str) -> InputError:
        where = self.topic if number is None else f"{self.topic}, message {number}"
        if fieldname is not None:
            where += f", field {fieldname}"
        return InputError(self.path, None, None, f"{where}: {message}")

    def notice(self, numbers: list[int], fieldname: str | None, message: str) -> InputNotice:
        shown = ", ".join(str(n) for n in numbers[:8]) + (f", ... ({len(numbers)} messages)" if len(numbers) > 8
                                                          else "")
        where = self.topic + (f", message{'s' if len(numbers) > 1 else ''} {shown}" if numbers else "")
        if fieldname is not None:
            where += f", field {fieldname}"
        return InputNotice(self.path, [], None, f"{where}: {message}")

    def relocated(self, exc: InputError, names: dict[str, str]) -> InputError:
        """A table check's error (line = message number, column = role) in the bag's terms."""
        return self.error(exc.line, names.get(str(exc.column), exc.column), exc.message.replace(" line ", " message "))


def _check_stamps(where: _Where, seconds: np.ndarray, numbers: np.ndarray, strict: bool) -> None:
    """Stamps [s] must be set (not 0) and increasing (``strict``: no repeats either)."""
    unset = np.flatnonzero(seconds == 0.0)
    if len(unset):
        raise where.error(int(numbers[unset[0]]), "header.stamp", "the stamp is 0: the driver did not stamp its "
                          "messages, and georef uses header.stamp (the measurement's time), not the record time")
    step = np.diff(seconds)
    back = np.flatnonzero(step < 0 if not strict else step <= 0)
    if len(back):
        i = int(back[0])
        what = "repeats" if step[i] == 0 else "goes backwards from"
        raise where.error(int(numbers[i + 1]), "header.stamp",
                          f"the stamp {what} {seconds[i]:.6f} s (message {int(numbers[i])}) "
                          f"{'' if step[i] == 0 else f'to {seconds[i + 1]:.6f} s '}"
                          "(header.stamp must increase within a topic)")


@dataclass
class _ImuRows:
    time: np.ndarray
    gyro_flu: np.ndarray
    accel_flu: np.ndarray
    numbers: np.ndarray
    record_s: np.ndarray
    frame_ids: set[str]
    orientation_given: int


#: IMU messages parsed together (bounds the raw bytes held at once: ~330 bytes a message)
IMU_CHUNK = 50_000
#: sensor_msgs/Imu after the header: orientation (4), its covariance (9), angular_velocity (3), its covariance
#: (9), linear_acceleration (3), its covariance (9) float64 = 37; the offsets [float64] of the fields read
IMU_BODY_FLOATS = 37
_ORIENTATION_COV0, _RATE, _RATE_COV0, _FORCE, _FORCE_COV0 = 4, 13, 16, 25, 28


@dataclass
class _ImuChunk:
    """IMU messages in the bag's terms: stamp ``sec``, ``nanosec``; rates and forces (n, 6) FLU; element 0 of
    the orientation, rate and force covariances (n, 3); record time [ns]; frame ids."""

    sec: np.ndarray
    nanosec: np.ndarray
    values: np.ndarray
    cov0: np.ndarray
    record_ns: np.ndarray
    frame_ids: set[str]


def _imu_chunk_generic(reader: Any, raws: list[bytes], record_ns: list[int]) -> _ImuChunk:
    """Every message deserialised with the bag's own definitions (any layout)."""
    n = len(raws)
    sec, nanosec = np.empty(n, np.int64), np.empty(n, np.int64)
    values, cov0 = np.empty((n, 6)), np.empty((n, 3))
    frame_ids: set[str] = set()
    for i, raw in enumerate(raws):
        msg = reader.deserialize(raw, IMU_TYPE)
        w, a = msg.angular_velocity, msg.linear_acceleration
        sec[i], nanosec[i] = msg.header.stamp.sec, msg.header.stamp.nanosec
        values[i] = (w.x, w.y, w.z, a.x, a.y, a.z)
        cov0[i] = (msg.orientation_covariance[0], msg.angular_velocity_covariance[0],
                   msg.linear_acceleration_covariance[0])
        frame_ids.add(msg.header.frame_id)
    return _ImuChunk(sec, nanosec, values, cov0, np.asarray(record_ns, np.int64), frame_ids)


def _imu_chunk_fast(reader: Any, raws: list[bytes], record_ns: list[int]) -> _ImuChunk | None:
    """The standard sensor_msgs/Imu layout read straight from the bytes when every message has the same size
    (one frame_id): ROS 1 serialisation, or little-endian CDR (ROS 2); None when the chunk is anything else.

    Three messages (first, middle, last) are also deserialised with the bag's own definitions and must agree
    value for value, so a bag with another layout falls back on :func:`_imu_chunk_generic`."""
    size = len(raws[0])
    if any(len(raw) != size for raw in raws):
        return None
    buf = np.frombuffer(b"".join(raws), np.uint8).reshape(len(raws), size)

    def uint32(offset: int) -> np.ndarray:
        return buf[:, offset:offset + 4].copy().view("<u4")[:, 0].astype(np.int64)

    if reader.is2:  # CDR: a 4-byte encapsulation header, then int32 sec, uint32 nanosec, string, 8-aligned doubles
        if size < 16 or not ((buf[:, 0] == 0) & (buf[:, 1] == 1)).all():  # CDR_LE
            return None
        length = uint32(12)  # with its NUL
        if not (length == length[0]).all() or length[0] < 1:
            return None
        text_start, text_end = 16, 16 + int(length[0]) - 1
        body = 4 + (12 + int(length[0]) + 7) // 8 * 8
        sec = buf[:, 4:8].copy().view("<i4")[:, 0].astype(np.int64)
    else:  # ROS 1: uint32 seq, uint32 secs, uint32 nsecs, string, doubles, no padding
        length = uint32(12)
        if not (length == length[0]).all():
            return None
        text_start, text_end = 16, 16 + int(length[0])
        body = text_end
        sec = uint32(4)
    if body + 8 * IMU_BODY_FLOATS != size:
        return None
    floats = buf[:, body:].copy().view("<f8")
    values = np.concatenate([floats[:, _RATE:_RATE + 3], floats[:, _FORCE:_FORCE + 3]], axis=1)
    cov0 = floats[:, [_ORIENTATION_COV0, _RATE_COV0, _FORCE_COV0]]
    frame_ids = {bytes(row).decode("utf-8", "replace") for row in np.unique(buf[:, text_start:text_end], axis=0)}
    chunk = _ImuChunk(sec, uint32(8), values, cov0, np.asarray(record_ns, np.int64), frame_ids)
    check = sorted({0, len(raws) // 2, len(raws) - 1})
    if not _same(_imu_chunk_generic(reader, [raws[i] for i in check], [record_ns[i] for i in check]), chunk, check):
        return None
    return chunk


def _same(reference: _ImuChunk, chunk: _ImuChunk, rows: list[int]) -> bool:
    """Whether ``chunk``'s ``rows`` hold exactly ``reference``'s values (NaN equal to NaN)."""
    return (np.array_equal(reference.sec, chunk.sec[rows]) and np.array_equal(reference.nanosec, chunk.nanosec[rows])
            and np.array_equal(reference.values, chunk.values[rows], equal_nan=True)
            and np.array_equal(reference.cov0, chunk.cov0[rows], equal_nan=True)
            and reference.frame_ids <= chunk.frame_ids)


def _read_imu(reader: Any, topic: str, where: _Where) -> _ImuRows:
    connections = [c for c in reader.connections if c.topic == topic]
    chunks: list[_ImuChunk] = []
    raws: list[bytes] = []
    record_ns: list[int] = []

    def parse() -> None:
        chunks.append(_imu_chunk_fast(reader, raws, record_ns) or _imu_chunk_generic(reader, raws, record_ns))
        raws.clear()
        record_ns.clear()

    for _, recorded, raw in reader.messages(connections=connections):
        raws.append(bytes(raw))
        record_ns.append(recorded)
        if len(raws) == IMU_CHUNK:
            parse()
    if raws:
        parse()
    if not chunks:
        return _ImuRows(np.empty(0), np.empty((0, 3)), np.empty((0, 3)), np.empty(0, int), np.empty(0), set(), 0)
    sec, nanosec, record = (np.concatenate([getattr(c, name) for c in chunks]) for name in ("sec", "nanosec",
                                                                                              "record_ns"))
    values = np.concatenate([c.values for c in chunks])
    cov0 = np.concatenate([c.cov0 for c in chunks])
    numbers = np.arange(1, len(sec) + 1)
    for column, fieldname in ((1, "angular_velocity_covariance"), (2, "linear_acceleration_covariance")):
        absent = np.flatnonzero((cov0[:, column] == NOT_REPORTED) | np.isnan(cov0[:, column]))
        if len(absent):
            raise where.error(int(numbers[absent[0]]), f"{fieldname}[0]", f"{cov0[absent[0], column]:g} says the IMU "
                              f"does not report {fieldname.removesuffix('_covariance')}, which georef needs")
    bad = np.flatnonzero(~np.isfinite(values).all(axis=1))
    if len(bad):
        column = int(np.flatnonzero(~np.isfinite(values[bad[0]]))[0])
        fieldname = ("angular_velocity", "linear_acceleration")[column // 3] + "." + "xyz"[column % 3]
        raise where.error(int(numbers[bad[0]]), fieldname, f"{values[bad[0], column]} is not a number")
    orientation_given = int(((cov0[:, 0] != NOT_REPORTED) & ~np.isnan(cov0[:, 0])).sum())
    return _ImuRows(stamp_to_seconds(sec, nanosec), values[:, :3], values[:, 3:], numbers, record * 1e-9,
                    set().union(*(c.frame_ids for c in chunks)), orientation_given)


@dataclass
class _GnssRows:
    time: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    height: np.ndarray
    status: np.ndarray
    cov_enu: np.ndarray
    cov_type: np.ndarray
    numbers: np.ndarray
    record_s: np.ndarray
    frame_ids: set[str]


def _read_gnss(reader: Any, topic: str) -> _GnssRows:
    rows: list[tuple[Any, ...]] = []
    cov: list[np.ndarray] = []
    frame_ids: set[str] = set()
    for number, record_ns, msg in _messages(reader, topic):
        rows.append((msg.header.stamp.sec, msg.header.stamp.nanosec, msg.latitude, msg.longitude, msg.altitude,
                     msg.status.status, msg.position_covariance_type, number, record_ns))
        cov.append(np.asarray(msg.position_covariance, dtype=float))
        frame_ids.add(msg.header.frame_id)
    if not rows:
        empty = np.empty(0)
        return _GnssRows(empty, empty, empty, empty, np.empty(0, int), np.empty((0, 3, 3)), np.empty(0, int),
                         np.empty(0, int), empty, frame_ids)
    columns = (np.asarray(column) for column in zip(*rows, strict=True))
    sec, nsec, lat, lon, alt, status, cov_type, number, record = columns
    return _GnssRows(stamp_to_seconds(sec, nsec), lat.astype(float), lon.astype(float), alt.astype(float),
                     status.astype(int), np.stack(cov).reshape(-1, 3, 3), cov_type.astype(int), number.astype(int),
                     record.astype(np.int64) * 1e-9, frame_ids)


def _gnss_epochs(where: _Where, rows: _GnssRows) -> tuple[GnssEpochs, list[InputNotice]]:
    """The usable fixes with NED sigmas; skipped fixes and covariances not used are notices."""
    notices: list[InputNotice] = []
    k = _usable_fixes(where, rows, notices)
    time, numbers = rows.time[k], rows.numbers[k]
    if len(time):
        _check_stamps(where, time, numbers, strict=False)
    covariance = _fix_covariances(where, rows.cov_type[k], rows.cov_enu[k].copy(), numbers, notices)
    fixes = GnssEpochs(time=time, lat_deg=rows.lat_deg[k], lon_deg=rows.lon_deg[k], height=rows.height[k],
                       line=numbers, repeated=np.zeros(len(k), bool), sigma_neu=covariance.sigma_neu)
    if covariance.sigma_neu is not None:  # the full covariance; NaN rows where the message gave none
        fixes.cov_ned = covariance.cov_ned
    return fixes, notices


def _usable_fixes(where: _Where, rows: _GnssRows, notices: list[InputNotice]) -> np.ndarray:
    """The messages (indices) with a fix and a full position, the others reported in notices added to ``notices``;
    an unknown covariance type, no usable fix at all or a position outside the valid range is an error."""
    unknown_type = np.flatnonzero((rows.cov_type < COVARIANCE_TYPE_UNKNOWN) | (rows.cov_type > COVARIANCE_TYPE_KNOWN))
    if len(unknown_type):
        i = int(unknown_type[0])
        raise where.error(int(rows.numbers[i]), "position_covariance_type", f"{rows.cov_type[i]} is none of 0 "
                          "(unknown), 1 (approximated), 2 (diagonal known), 3 (known)")
    no_fix = rows.status <= STATUS_NO_FIX
    if no_fix.any():
        notices.append(where.notice(rows.numbers[no_fix].tolist(), "status.status",
                                    f"{int(no_fix.sum())} message(s) without a fix (status -1) skipped"))
    no_position = ~no_fix & ~(np.isfinite(rows.lat_deg) & np.isfinite(rows.lon_deg) & np.isfinite(rows.height))
    if no_position.any():
        notices.append(where.notice(rows.numbers[no_position].tolist(), "latitude/longitude/altitude",
                                    f"{int(no_position.sum())} fix(es) without a full position (NaN; an altitude "
                                    "is NaN when the receiver has none) skipped"))
    keep = ~no_fix & ~no_position
    k = np.flatnonzero(keep)
    if not len(k):
        raise where.error(None, None, f"no usable fix in {len(rows.time)} message(s): {int(no_fix.sum())} without a "
                          f"fix (status -1), {int(no_position.sum())} without a full position (an NMEA driver that "
                          "reads RMC only gives no altitude: have it read GGA)")
    bad = k[(np.abs(rows.lat_deg[k]) > 90) | (np.abs(rows.lon_deg[k]) > 180)]
    if len(bad):
        i = int(bad[0])
        raise where.error(int(rows.numbers[i]), "latitude/longitude", f"{rows.lat_deg[i]:g}, {rows.lon_deg[i]:g} deg "
                          "is outside the valid range")
    return k


@dataclass(frozen=True)
class _FixCovariance:
    """The fixes' NED sigmas (K, 3) [m] (None: no fix carries a covariance) and NED covariances (K, 3, 3) [m^2];
    NaN rows where a fix takes the configured ``gnss_sigma``."""

    sigma_neu: np.ndarray | None
    cov_ned: np.ndarray


def _fix_covariances(where: _Where, cov_type: np.ndarray, cov_enu: np.ndarray, numbers: np.ndarray,
                     notices: list[InputNotice]) -> _FixCovariance:
    """The usable fixes' covariances (ENU [m^2] as the messages give them, of type ``cov_type``) in NED; fixes
    without a usable one, or with an approximated one, reported in notices added to ``notices``."""
    diagonal = cov_type == COVARIANCE_TYPE_DIAGONAL_KNOWN
    cov_enu[diagonal] *= np.eye(3)  # type 2: only the variances are known; what stands off the diagonal is not
    cov_enu = 0.5 * (cov_enu + np.swapaxes(cov_enu, -1, -2))
    variances = np.diagonal(cov_enu, axis1=-2, axis2=-1)
    given = cov_type != COVARIANCE_TYPE_UNKNOWN
    unusable = given & ~(np.isfinite(cov_enu).all(axis=(1, 2)) & (variances > 0).all(axis=1))
    if unusable.any():
        notices.append(where.notice(numbers[unusable].tolist(), "position_covariance",
                                    f"{int(unusable.sum())} covariance(s) with a variance not above 0 or not a "
                                    "number: those fixes take the configured gnss_sigma"))
    used = given & ~unusable
    cov_ned = np.full((len(cov_type), 3, 3), np.nan)
    cov_ned[used] = enu_to_ned_covariance(cov_enu[used])
    approximated = used & (cov_type == COVARIANCE_TYPE_APPROXIMATED)
    if approximated.any():
        notices.append(where.notice([], "position_covariance_type", f"{int(approximated.sum())} fix(es) with an "
                                    "approximated covariance (type 1, e.g. from the DOP) used as given"))
    if not used.any():
        if len(cov_type):
            notices.append(where.notice([], "position_covariance_type", "no fix carries a covariance: every fix "
                                        "takes the configured gnss_sigma"))
        return _FixCovariance(sigma_neu=None, cov_ned=cov_ned)
    if (~used).any():
        notices.append(where.notice(numbers[~used].tolist(), "position_covariance_type",
                                    f"{int((~used).sum())} fix(es) without a covariance take the configured "
                                    "gnss_sigma"))
    # NaN rows: the configured gnss_sigma
    return _FixCovariance(sigma_neu=np.sqrt(np.diagonal(cov_ned, axis1=-2, axis2=-1)), cov_ned=cov_ned)


def _clock_notices(where_imu: _Where, where_gnss: _Where, imu: _ImuRows, gnss: _GnssRows,
                   fixes: GnssEpochs) -> list[InputNotice]:
    """How the stamps relate to the record time, and an error when the two topics cannot share a clock."""
    imu_lag = float(np.median(imu.record_s - imu.time))
    notices = [where_imu.notice([], "header.stamp", f"{len(imu.time)} messages (frame_id "
                                f"{', '.join(map(repr, sorted(imu.frame_ids)))}); time from header.stamp, the bag's "
                                f"record time is {1e3 * imu_lag:.1f} ms later (median); axes read as REP 103 "
                                "forward-left-up and turned to forward-right-down")]
    if imu.orientation_given:
        notices.append(where_imu.notice([], "orientation", f"{imu.orientation_given} message(s) carry the IMU's own "
                                        "orientation estimate: not used (georef estimates the attitude)"))
    if len(gnss.time):
        gnss_lag = float(np.median(gnss.record_s - gnss.time))
        notices.append(where_gnss.notice([], "header.stamp", f"{len(fixes)} fixes used of {len(gnss.time)} messages; "
                                         f"the bag's record time is {1e3 * gnss_lag:.1f} ms after header.stamp "
                                         "(median)"))
        if abs(gnss_lag - imu_lag) > CLOCK_MISMATCH_S:
            notices.append(where_gnss.notice([], "header.stamp", f"its stamps lag the record time by {gnss_lag:.3f} s "
                                             f"but the IMU's by {imu_lag:.3f} s: the two topics may be stamped on "
                                             "different clocks (GPS time vs UTC differ by 18 s); georef uses the "
                                             "stamps as they are"))
    if len(fixes) and (fixes.time[-1] < imu.time[0] or fixes.time[0] > imu.time[-1]):
        raise where_gnss.error(None, "header.stamp", f"the fixes ({fixes.time[0]:.3f} .. {fixes.time[-1]:.3f} s) "
                               f"lie outside the IMU's span ({imu.time[0]:.3f} .. {imu.time[-1]:.3f} s, "
                               f"{where_imu.topic}): the two topics are not stamped on one clock")
    return notices


def read_bag(path: Path | str, imu_topic: str | None = None, gnss_topic: str | None = None) -> BagInputs:
    """The IMU and GNSS topics of a ROS 1 or ROS 2 bag as :class:`BagInputs` (see the module docstring).

    ``imu_topic``/``gnss_topic``: the topics to read; None takes the bag's only sensor_msgs/Imu (NavSatFix) topic."""
    location = bag_location(path)
    try:
        with _open(location) as reader:
            topics = {name: (info.msgtype, info.msgcount) for name, info in reader.topics.items()}
            imu_name = choose_topic(path, topics, IMU_TYPE, imu_topic, "--imu-topic")
            gnss_name = choose_topic(path, topics, GNSS_TYPE, gnss_topic, "--gnss-topic")
            where_imu, where_gnss = _Where(path, imu_name), _Where(path, gnss_name)
            imu = _read_imu(reader, imu_name, where_imu)
            gnss = _read_gnss(reader, gnss_name)
            kind = "ROS 1 bag" if not reader.is2 else f"ROS 2 bag ({_storage(location)})"
    except _bag_errors() as exc:
        raise InputError(path, None, None, f"cannot read the bag: {exc}") from None
    if len(imu.time) < 2:
        raise where_imu.error(None, None, f"{len(imu.time)} message(s): too few to fuse")
    _check_stamps(where_imu, imu.time, imu.numbers, strict=True)
    gyro, accel = flu_to_frd(imu.gyro_flu), flu_to_frd(imu.accel_flu)
    names = {**{f"gyro_{a}": f"angular_velocity.{a}" for a in "xyz"},
             **{f"acc_{a}": f"linear_acceleration.{a}" for a in "xyz"}}
    try:
        check_ranges(Path(path), {f"gyro_{a}": gyro[:, i] for i, a in enumerate("xyz")}
                     | {f"acc_{a}": accel[:, i] for i, a in enumerate("xyz")}, imu.numbers, {}, GENERIC_LIMITS)
    except InputError as exc:
        raise where_imu.relocated(exc, names) from None
    fixes, gnss_notices = _gnss_epochs(where_gnss, gnss)
    notices = _clock_notices(where_imu, where_gnss, imu, gnss, fixes)
    up_force = float(np.median(imu.accel_flu[:, 2]))
    if up_force < UPSIDE_DOWN_FORCE:
        notices.append(where_imu.notice([], "linear_acceleration.z", f"the median specific force on the IMU's z axis "
                                        f"is {up_force:.2f} m/s^2, where a level REP 103 (z up) IMU reads +9.8: the "
                                        "driver publishes z down (not REP 103), or the IMU is mounted upside down"))
    try:
        fixes, jump_notices = check_gnss_jumps(Path(path), fixes, "latitude/longitude/altitude")
    except InputError as exc:
        raise where_gnss.relocated(exc, {}) from None
    gnss_notices.extend(where_gnss.notice(n.lines, None, n.message) for n in jump_notices)
    fixes.notices.extend(gnss_notices)
    return BagInputs(path=Path(path), imu_topic=imu_name, gnss_topic=gnss_name, time=imu.time, gyro=gyro,
                     accel=accel, lines=imu.numbers, gnss=fixes, kind=kind, notices=notices)


def _storage(location: Path) -> str:
    """The storage of a ROS 2 bag from its files: "sqlite3", "mcap" (or both)."""
    kinds = sorted({{".db3": "sqlite3", ".mcap": "mcap"}[p.suffix] for p in location.iterdir()
                    if p.suffix in (".db3", ".mcap")})
    return " + ".join(kinds) or "unknown storage"
