"""A simulated drone flight as PX4 logs it: a ULog of two generations, built in memory for pyulog's writer.

Topics and fields as PX4 defines them (``msg/*.msg`` of PX4-Autopilot), in the order its message generator lays
them out (by field size, largest first):

* ``sensor_combined``: ``gyro_rad[3]``, ``accelerometer_m_s2[3]``, each the mean over its integration interval
  ``gyro_integral_dt`` / ``accelerometer_integral_dt`` [us] that ends at ``timestamp``: an IMU row at boot time
  ``t`` is logged at ``timestamp = t + dt/2`` with ``dt`` the row interval;
* ``vehicle_gps_position``: ``"new"`` (v1.14, SensorGps.msg): ``latitude_deg``, ``longitude_deg``,
  ``altitude_msl_m``, ``altitude_ellipsoid_m`` as float64 and the fix's own instant ``timestamp_sample``;
  ``"old"`` (v1.10): ``lat``/``lon`` [1e-7 deg], ``alt``/``alt_ellipsoid`` [mm] as int32, no ``timestamp_sample``;
  both: ``timestamp`` the message's arrival, ``time_utc_usec`` the fix's UTC, ``eph``/``epv`` the accuracy;
* ``vehicle_attitude.q[4]`` (Hamilton, body FRD to NED), ``vehicle_magnetometer.magnetometer_ga[3]`` [gauss];
* ``camera_trigger`` (the trigger) and ``camera_capture`` (the capture feedback) with one ``seq`` per image.

Parameters: ``EKF2_GPS_POS_X/Y/Z`` (the antenna) and ``EKF2_IMU_POS_X/Y/Z`` (the IMU, at the body origin)
[m, body], ``EKF2_GPS_DELAY`` [ms] the receiver's lag on the board's clock.

pyulog writes a :class:`pyulog.ULog` (``ULog.write_ulog``) but has no builder for one: the object is filled
through its own message-format and subscription parsers (``ULog.MessageFormat``, ``ULog._MessageAddLogged``),
so the data are laid out exactly as pyulog would have read them.
"""

from __future__ import annotations

import datetime as dt
import struct
from dataclasses import dataclass

import numpy as np
from pyulog import ULog

from georef.frames import dcm_to_quat, euler_to_dcm
from georef.sim.log_samples import LoggedFlight, posix_seconds

GENERATIONS = ("new", "old")
FIX_TYPES = (3, 4, 5, 6)

_SENSOR_COMBINED = ("uint64_t timestamp; float[3] gyro_rad; uint32_t gyro_integral_dt; "
                    "int32_t accelerometer_timestamp_relative; float[3] accelerometer_m_s2; "
                    "uint32_t accelerometer_integral_dt; uint8_t accelerometer_clipping; uint8_t gyro_clipping; "
                    "uint8_t accel_calibration_count; uint8_t gyro_calibration_count")
_GPS_NEW = ("uint64_t timestamp; uint64_t timestamp_sample; double latitude_deg; double longitude_deg; "
            "double altitude_msl_m; double altitude_ellipsoid_m; uint64_t time_utc_usec; uint32_t device_id; "
            "float s_variance_m_s; float c_variance_rad; float eph; float epv; float hdop; float vdop; "
            "int32_t noise_per_ms; int32_t jamming_indicator; float vel_m_s; float vel_n_m_s; float vel_e_m_s; "
            "float vel_d_m_s; float cog_rad; int32_t timestamp_time_relative; float heading; float heading_offset; "
            "float heading_accuracy; float rtcm_injection_rate; uint16_t automatic_gain_control; uint8_t fix_type; "
            "uint8_t jamming_state; uint8_t spoofing_state; bool vel_ned_valid; uint8_t satellites_used; "
            "uint8_t selected_rtcm_instance")
_GPS_OLD = ("uint64_t timestamp; uint64_t time_utc_usec; int32_t lat; int32_t lon; int32_t alt; "
            "int32_t alt_ellipsoid; float s_variance_m_s; float c_variance_rad; float eph; float epv; float hdop; "
            "float vdop; int32_t noise_per_ms; int32_t jamming_indicator; float vel_m_s; float vel_n_m_s; "
            "float vel_e_m_s; float vel_d_m_s; float cog_rad; int32_t timestamp_time_relative; float heading; "
            "float heading_offset; uint8_t fix_type; bool vel_ned_valid; uint8_t satellites_used")
_ATTITUDE = {"new": "uint64_t timestamp; uint64_t timestamp_sample; float[4] q; float[4] delta_q_reset; "
                    "uint8_t quat_reset_counter",
             "old": "uint64_t timestamp; float[4] q; float[4] delta_q_reset; uint8_t quat_reset_counter"}
_MAGNETOMETER = {"new": "uint64_t timestamp; uint64_t timestamp_sample; uint32_t device_id; "
                        "float[3] magnetometer_ga; uint8_t calibration_count",
                 "old": "uint64_t timestamp; float[3] magnetometer_ga"}
_TRIGGER = "uint64_t timestamp; uint64_t timestamp_utc; uint32_t seq; bool feedback"
_CAPTURE = ("uint64_t timestamp; uint64_t timestamp_utc; double lat; double lon; uint32_t seq; float alt; "
            "float ground_distance; float[4] q; int8_t result")
#: info messages of each generation: (hardware, release as PX4 encodes it: major, minor, patch, 255 = release)
_VERSION = {"new": ("PX4_FMU_V5X", (1, 14, 3)), "old": ("PX4_FMU_V5", (1, 10, 2))}
_GPS_DEVICE_ID = 11207430
_SATELLITES, _HDOP, _VDOP = 16, 0.7, 1.1


@dataclass
class Topic:
    """One logged topic: its name, its fields (``"type name; ..."``, arrays as ``type[n] name``) and the values
    of every field (arrays flattened to ``name[k]``, as pyulog names them)."""

    name: str
    fields: str
    values: dict[str, object]


def _us(seconds: np.ndarray) -> np.ndarray:
    return np.round(np.asarray(seconds, dtype=float) * 1e6).astype(np.uint64)


def _vector(name: str, values: np.ndarray) -> dict[str, np.ndarray]:
    return {f"{name}[{k}]": values[:, k] for k in range(values.shape[1])}


def _quaternions(rpy: np.ndarray) -> np.ndarray:
    return dcm_to_quat(euler_to_dcm(rpy[:, 0], rpy[:, 1], rpy[:, 2])) if len(rpy) else np.empty((0, 4))


def _sensor_combined(logged: LoggedFlight) -> Topic:
    imu = logged.imu
    dt_us = int(round(float(np.median(np.diff(imu.boot))) * 1e6))
    return Topic("sensor_combined", _SENSOR_COMBINED, {
        "timestamp": np.round(imu.boot * 1e6 + 0.5 * dt_us).astype(np.uint64), **_vector("gyro_rad", imu.gyro),
        "gyro_integral_dt": dt_us, "accelerometer_timestamp_relative": 0,
        **_vector("accelerometer_m_s2", imu.accel), "accelerometer_integral_dt": dt_us,
        "accelerometer_clipping": 0, "gyro_clipping": 0, "accel_calibration_count": 1, "gyro_calibration_count": 1})


def _gps(logged: LoggedFlight, generation: str, date: dt.date, fix_type: int) -> Topic:
    fixes = logged.fixes
    v_n = fixes.v_n
    common = {"timestamp": _us(fixes.arrival_boot), "time_utc_usec": _us(posix_seconds(fixes.utc, date)),
              "s_variance_m_s": 0.3, "c_variance_rad": 0.5, "eph": fixes.sigma_h, "epv": fixes.sigma_v,
              "hdop": _HDOP, "vdop": _VDOP, "noise_per_ms": 90, "jamming_indicator": 20,
              "vel_m_s": np.hypot(v_n[:, 0], v_n[:, 1]), "vel_n_m_s": v_n[:, 0], "vel_e_m_s": v_n[:, 1],
              "vel_d_m_s": v_n[:, 2], "cog_rad": np.arctan2(v_n[:, 1], v_n[:, 0]), "timestamp_time_relative": 0,
              "heading": np.nan, "heading_offset": np.nan, "fix_type": fix_type, "vel_ned_valid": 1,
              "satellites_used": _SATELLITES}
    if generation == "old":
        return Topic("vehicle_gps_position", _GPS_OLD, {
            **common, "lat": np.round(fixes.lat * 1e7), "lon": np.round(fixes.lon * 1e7),
            "alt": np.round(fixes.msl * 1e3), "alt_ellipsoid": np.round(fixes.height * 1e3)})
    return Topic("vehicle_gps_position", _GPS_NEW, {
        **common, "timestamp_sample": _us(fixes.sample_boot), "latitude_deg": fixes.lat, "longitude_deg": fixes.lon,
        "altitude_msl_m": fixes.msl, "altitude_ellipsoid_m": fixes.height, "device_id": _GPS_DEVICE_ID,
        "heading_accuracy": 0.0, "rtcm_injection_rate": 0.0, "automatic_gain_control": 1200, "jamming_state": 1,
        "spoofing_state": 1, "selected_rtcm_instance": 0})


def _attitude_mag(logged: LoggedFlight, generation: str) -> list[Topic]:
    stamp = _us(logged.attitude.boot)
    sample = {"timestamp_sample": stamp} if generation == "new" else {}
    topics = [Topic("vehicle_attitude", _ATTITUDE[generation], {
        "timestamp": stamp, **sample, **_vector("q", _quaternions(logged.attitude.values)),
        **_vector("delta_q_reset", np.zeros((len(stamp), 4))), "quat_reset_counter": 0})]
    if logged.mag is not None:
        stamp = _us(logged.mag.boot)
        extra = {"timestamp_sample": stamp, "device_id": 396809, "calibration_count": 1} if generation == "new" else {}
        topics.append(Topic("vehicle_magnetometer", _MAGNETOMETER[generation], {
            "timestamp": stamp, **extra, **_vector("magnetometer_ga", logged.mag.values * 0.01)}))
    return topics


def _camera(logged: LoggedFlight, date: dt.date) -> list[Topic]:
    events = logged.events
    if len(events.number) == 0:
        return []
    trigger, capture = events.trigger, events.capture
    return [Topic("camera_trigger", _TRIGGER, {
                "timestamp": _us(trigger.boot), "timestamp_utc": _us(posix_seconds(trigger.utc, date)),
                "seq": events.number, "feedback": 0}),
            Topic("camera_capture", _CAPTURE, {
                "timestamp": _us(capture.boot), "timestamp_utc": _us(posix_seconds(capture.utc, date)),
                "lat": capture.lat, "lon": capture.lon, "seq": events.number, "alt": capture.msl,
                "ground_distance": capture.height - logged.start_height, **_vector("q", _quaternions(capture.rpy)),
                "result": 1})]


def px4_topics(logged: LoggedFlight, generation: str, date: dt.date, fix_type: int = 3) -> list[Topic]:
    """Every topic of the log."""
    if generation not in GENERATIONS:
        raise ValueError(f"generation must be one of {', '.join(GENERATIONS)}, got {generation!r}")
    if fix_type not in FIX_TYPES:
        raise ValueError(f"fix_type must be one of {FIX_TYPES} (3D, DGPS, RTK float, RTK fixed), got {fix_type}")
    return ([_sensor_combined(logged), _gps(logged, generation, date, fix_type)] + _attitude_mag(logged, generation)
            + _camera(logged, date))


def _format(topic: Topic) -> ULog.MessageFormat:
    """The topic's format message as pyulog parses it (``name:type field;...``)."""
    fields = "".join(f"{item.strip()};" for item in topic.fields.split(";"))
    return ULog.MessageFormat(f"{topic.name}:{fields}".encode(), None)


def _data(topic: Topic, msg_id: int, formats: dict[str, ULog.MessageFormat]) -> ULog.Data:
    subscription = ULog._MessageAddLogged(struct.pack("<BH", 0, msg_id) + topic.name.encode(), None, formats)
    n = len(topic.values["timestamp"])  # type: ignore[arg-type]
    records = np.zeros(n, dtype=subscription.dtype)
    for field in subscription.field_data:
        if field.field_name not in topic.values:
            raise ValueError(f"{topic.name}.{field.field_name}: no values")
        records[field.field_name] = np.broadcast_to(np.asarray(topic.values[field.field_name]), (n,))
    unknown = set(topic.values) - {f.field_name for f in subscription.field_data}
    if unknown:
        raise ValueError(f"{topic.name}: values for fields it does not have: {sorted(unknown)}")
    subscription.buffer = bytearray(records.tobytes())
    return ULog.Data(subscription)


def px4_params(logged: LoggedFlight) -> dict[str, float | int]:
    """The logged parameters: the GNSS lever arm (antenna at EKF2_GPS_POS, IMU at EKF2_IMU_POS = the body
    origin), the lag EKF2_GPS_DELAY [ms] and a few of the usual others (int32 or float, as PX4 defines them)."""
    arm = logged.lever_arm_gnss
    return {"SYS_AUTOSTART": 4001, "EKF2_GPS_POS_X": float(arm[0]), "EKF2_GPS_POS_Y": float(arm[1]),
            "EKF2_GPS_POS_Z": float(arm[2]), "EKF2_IMU_POS_X": 0.0, "EKF2_IMU_POS_Y": 0.0, "EKF2_IMU_POS_Z": 0.0,
            "EKF2_GPS_DELAY": float(logged.gnss_lag_boot_s * 1000.0), "EKF2_GPS_CTRL": 7, "TRIG_MODE": 4,
            "CAM_CAP_FBACK": 1}


def build_ulog(logged: LoggedFlight, generation: str, date: dt.date, fix_type: int = 3) -> ULog:
    """The ULog of ``logged``: info messages, :func:`px4_params` as initial parameters and every topic."""
    topics = px4_topics(logged, generation, date, fix_type)
    ulog = ULog(None)
    ulog._file_version = 1
    ulog._start_timestamp = int(round(logged.header_boot * 1e6))
    ulog._message_formats = {t.name: _format(t) for t in topics}
    ulog._data_list = [_data(t, k, ulog._message_formats) for k, t in enumerate(topics)]
    hardware, (major, minor, patch) = _VERSION[generation]
    texts = {"sys_name": "PX4", "ver_hw": hardware, "ver_sw": "georef simulator"}
    info: dict[str, tuple[str, object]] = {key: (f"char[{len(text)}]", text) for key, text in texts.items()}
    info["ver_sw_release"] = ("uint32_t", (major << 24) | (minor << 16) | (patch << 8) | 255)
    ulog._msg_info_dict = {key: value for key, (_, value) in info.items()}
    ulog._msg_info_dict_types = {key: kind for key, (kind, _) in info.items()}
    ulog._initial_parameters = px4_params(logged)
    return ulog
