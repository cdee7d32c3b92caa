"""PX4 ULog (``.ulg``), read with pyulog: IMU, GNSS, attitude, magnetometer, camera events, parameters.

Topics and fields as PX4 defines them (``msg/*.msg`` of PX4-Autopilot), over the generations met in the field:

* ``sensor_combined``: ``gyro_rad[3]`` [rad/s] and ``accelerometer_m_s2[3]`` [m/s^2] in the body frame (FRD),
  each the mean over its integration interval ``gyro_integral_dt`` [us] ending at ``timestamp``: the sample is
  placed at the interval's middle. ``vehicle_imu`` instances (``delta_angle``, ``delta_velocity`` over
  ``delta_angle_dt``) are the other IMUs, chosen with ``imu_instance``.
* ``vehicle_gps_position`` (else ``sensor_gps``): ``fix_type`` (3 3D, 4 DGPS, 5 RTK float, 6 RTK fixed),
  ``lat``/``lon`` [1e-7 deg] or ``latitude_deg``/``longitude_deg``, ellipsoidal height ``alt_ellipsoid`` [mm] or
  ``altitude_ellipsoid_m`` (mean sea level ``alt`` / ``altitude_msl_m`` when that is missing), ``eph``/``epv``
  [m] (PX4's EKF takes eph as each horizontal axis's sigma, and so does georef), ``time_utc_usec`` (the fix's
  UTC), ``timestamp`` (its arrival) and, in newer logs, ``timestamp_sample`` (the fix's own instant on the boot
  clock; 0 when unknown).
* ``vehicle_attitude.q[4]`` (Hamilton, body to NED), ``vehicle_magnetometer.magnetometer_ga[3]`` or
  ``sensor_mag.x/y/z`` [gauss, body].
* ``camera_capture`` (the capture) and ``camera_trigger`` (the trigger): one exposure each, numbered ``seq``.
* Parameters: ``EKF2_GPS_POS_X/Y/Z`` - ``EKF2_IMU_POS_X/Y/Z`` [m, body] the GNSS lever arm; ``EKF2_GPS_DELAY``
  [ms] the lag of the fix messages.
"""

from __future__ import annotations

import contextlib
import io
from collections import Counter
from pathlib import Path

import numpy as np

from georef.frames import dcm_to_euler, quat_to_dcm
from georef.frames.gpstime import utc_day_start
from georef.io.camera import FEEDBACK_TIME_SIGMA, TRIGGER_TIME_SIGMA, Exposures
from georef.io.errors import InputError, InputNotice, excerpt
from georef.io.logs.clock import ClockFit, fit_clock
from georef.io.logs.flightlog import (
    FlightLog,
    GnssReport,
    ImuStream,
    LeverArmParameter,
    Series,
    imu_notice,
    lever_arm_parameter,
    numeric_params,
    usable_imu,
    whole_numbers,
)
from georef.io.logs.gnss_heights import ellipsoidal_heights
from georef.timing import GnssEpochs

TOPICS = ["sensor_combined", "vehicle_imu", "vehicle_gps_position", "sensor_gps", "vehicle_attitude",
          "vehicle_magnetometer", "sensor_mag", "camera_capture", "camera_trigger"]
FIX_NAMES = {0: "no fix", 1: "no fix", 2: "2D", 3: "3D", 4: "DGPS", 5: "RTK float", 6: "RTK fixed",
             8: "extrapolated"}
GOOD_FIXES = (3, 4, 5, 6)
US = 1e-6
#: pyulog can read a damaged ULog's bytes over and over without end (it seeks back past a broken message's start
#: and meets it again): reading this many times the file's bytes (or 4 read calls per byte) stops it
READ_BUDGET = 16


def _field(topic, name: str, path: Path) -> np.ndarray:
    """Field ``name`` of every message of ``topic`` as floats; an error naming topic and field when the topic's
    format (its F message) has no such field, or not as a number."""
    values = topic.data.get(name)
    if values is None or np.asarray(values).dtype.kind not in "biuf":
        what = "no field" if values is None else "no number in field"
        raise InputError(path, None, f"{topic.name}.{name}", f"the log's format of {topic.name} (its F message) has "
                         f"{what} {name}")
    with np.errstate(invalid="ignore"):  # a signalling NaN (any bit pattern may be one) is NaN all the same
        return np.asarray(values, dtype=float)


def _vector(topic, name: str, path: Path) -> np.ndarray:
    return np.stack([_field(topic, f"{name}[{k}]", path) for k in range(3)], -1)


def _topic(ulog, name: str, multi_id: int = 0):
    for d in ulog.data_list:
        if d.name == name and d.multi_id == multi_id:
            return d
    return None


def _imu(ulog, path: Path, instance: int | None, clock: ClockFit,
         day: float) -> tuple[ImuStream, list[str], list[InputNotice]]:
    """The IMU stream (default sensor_combined, else vehicle_imu ``instance``), the streams the log has, and a
    notice of the samples left out (not finite, repeated or out of time order)."""
    streams: dict[str, object] = {}
    combined = _topic(ulog, "sensor_combined")
    if combined is not None:
        streams["sensor_combined"] = combined
    for d in ulog.data_list:
        if d.name == "vehicle_imu":
            streams[f"vehicle_imu[{d.multi_id}]"] = d
    if not streams:
        raise InputError(path, None, "sensor_combined", "the log has no IMU topic (sensor_combined, vehicle_imu)")
    names = sorted(streams)
    name = "sensor_combined" if instance is None and combined is not None else f"vehicle_imu[{instance or 0}]"
    if name not in streams:
        raise InputError(path, None, "vehicle_imu", f"no IMU stream {name}; the log has {', '.join(names)}")
    topic = streams[name]
    stamp = _field(topic, "timestamp", path) * US
    if name == "sensor_combined":
        gyro = _vector(topic, "gyro_rad", path)
        accel = _vector(topic, "accelerometer_m_s2", path)
        dt = _field(topic, "gyro_integral_dt", path) * US if "gyro_integral_dt" in topic.data else 0.0 * stamp
    else:
        dt = _field(topic, "delta_angle_dt", path) * US
        dt_v = _field(topic, "delta_velocity_dt", path) * US
        gyro = _vector(topic, "delta_angle", path) / np.maximum(dt, 1e-6)[:, None]
        accel = _vector(topic, "delta_velocity", path) / np.maximum(dt_v, 1e-6)[:, None]
    boot = stamp - 0.5 * dt  # the mean over the interval belongs to its middle
    keep, non_finite = usable_imu(boot, gyro, accel)
    if not keep.any():
        raise InputError(path, None, name, f"{name} has no usable sample ({len(keep)} logged, {non_finite} of them "
                         "with a value that is not a finite number)")
    where = np.arange(len(boot))
    notice = imu_notice(path, name, keep, non_finite, where, "message")
    return (ImuStream(name, clock.utc(boot[keep]) - day, gyro[keep], accel[keep], where[keep]), names,
            [notice] if notice else [])


def _gps_topic(ulog, path: Path):
    topic = _topic(ulog, "vehicle_gps_position") or _topic(ulog, "sensor_gps")
    if topic is None:
        raise InputError(path, None, "vehicle_gps_position", "the log has no GNSS topic (vehicle_gps_position, "
                         "sensor_gps)")
    return topic


def _lat_lon_heights(topic, path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]:
    """(lat, lon [deg], ellipsoidal height or None, mean-sea-level height [m]) of every fix."""
    data = topic.data
    if "latitude_deg" in data:
        lat, lon = _field(topic, "latitude_deg", path), _field(topic, "longitude_deg", path)
        msl = _field(topic, "altitude_msl_m", path)
        ell = _field(topic, "altitude_ellipsoid_m", path) if "altitude_ellipsoid_m" in data else None
    else:
        lat, lon = _field(topic, "lat", path) * 1e-7, _field(topic, "lon", path) * 1e-7
        msl = _field(topic, "alt", path) * 1e-3
        ell = _field(topic, "alt_ellipsoid", path) * 1e-3 if "alt_ellipsoid" in data else None
    if ell is not None and not np.any(ell != 0):
        ell = None  # a receiver that does not report it leaves it 0
    return lat, lon, ell, msl


def _params(ulog, path: Path) -> tuple[dict[str, float], list[InputNotice]]:
    """The parameters (initial, then changed), and a notice of those whose value is no finite number."""
    items = [*ulog.initial_parameters.items(), *((name, value) for _, name, value in ulog.changed_parameters)]
    return numeric_params(items, path)


def _lever_arm(params: dict[str, float]) -> LeverArmParameter | None:
    names = [f"EKF2_GPS_POS_{a}" for a in "XYZ"]
    if not all(n in params for n in names):
        return None
    return lever_arm_parameter(params, names, [f"EKF2_IMU_POS_{a}" for a in "XYZ"])


def _clock(path: Path, topic, good: np.ndarray, params: dict[str, float]) -> ClockFit:
    """The boot clock against the fixes' UTC: at each fix's own instant (``timestamp_sample``) where the log has
    it, else at its arrival less EKF2_GPS_DELAY."""
    arrival = _field(topic, "timestamp", path) * US
    utc = _field(topic, "time_utc_usec", path) * US
    usable = good & (utc > 0)
    sample = _field(topic, "timestamp_sample", path) * US if "timestamp_sample" in topic.data else None
    if sample is not None and np.all(sample[usable] > 0):
        return fit_clock(path, sample[usable], utc[usable], 0.0, "timestamp_sample: the fix's own instant",
                         f"{topic.name}.time_utc_usec")
    delay = params.get("EKF2_GPS_DELAY", 110.0) * 1e-3
    source = "EKF2_GPS_DELAY" if "EKF2_GPS_DELAY" in params else "PX4's default EKF2_GPS_DELAY"
    return fit_clock(path, arrival[usable], utc[usable], delay, f"{source} = {delay * 1e3:.0f} ms",
                     f"{topic.name}.time_utc_usec")


def _gnss(path: Path, topic, good: np.ndarray, clock: ClockFit, day: float) -> tuple[GnssEpochs, GnssReport]:
    data = topic.data
    fix = whole_numbers(_field(topic, "fix_type", path))
    counts = Counter(FIX_NAMES.get(int(f), f"fix type {int(f)}") for f in fix)
    utc = _field(topic, "time_utc_usec", path) * US
    boot = _field(topic, "timestamp", path) * US - clock.lag_s
    if clock.lag_source.startswith("timestamp_sample"):
        # the clock was tied to the fixes' own instants: a fix without a UTC time has one too
        sample = _field(topic, "timestamp_sample", path) * US
        boot = np.where(sample > 0, sample, boot)
    fitted = clock.utc(boot)
    time = np.where((utc > 0) & (np.abs(utc - fitted) < 0.5), utc, fitted)
    lat, lon, ell, msl = _lat_lon_heights(topic, path)
    usable = np.flatnonzero(good & np.isfinite(time) & (np.abs(lat) <= 90) & (np.abs(lon) <= 180)
                            & ~((lat == 0) & (lon == 0)) & np.isfinite(msl if ell is None else ell))
    usable = usable[np.argsort(time[usable], kind="stable")]
    usable = usable[np.concatenate([[True], np.diff(time[usable]) > 0])[:len(usable)]]
    if len(usable) < 2:
        field = "latitude_deg" if "latitude_deg" in data else "lat"
        raise InputError(path, None, f"{topic.name}.{field}", f"{len(usable)} of the {int(good.sum())} fixes of type "
                         "3D or better have a time, a position in range and a height: nothing to georeference with")
    if ell is not None:
        height, height_source = ell[usable], f"{topic.name} ellipsoidal height"
    else:
        height, height_source = ellipsoidal_heights(lat[usable], lon[usable], msl[usable], None, f"{topic.name}.alt")
    sigma = None
    sigma_source = None
    if "eph" in data and "epv" in data:
        h, v = _field(topic, "eph", path)[usable], _field(topic, "epv", path)[usable]
        if np.all(np.isfinite(h) & (h > 0)) and np.all(np.isfinite(v) & (v > 0)):
            sigma, sigma_source = np.stack([h, h, v], -1), f"{topic.name}.eph/epv"
    gnss = GnssEpochs(time=time[usable] - day, lat_deg=lat[usable], lon_deg=lon[usable], height=height,
                      line=usable.astype(np.int64), repeated=np.zeros(len(usable), bool), sigma_neu=sigma)
    message = (f"{len(usable)} of {len(fix)} {topic.name} fixes used (3D, DGPS or RTK): "
               + ", ".join(f"{name} {n}" for name, n in counts.most_common()))
    return gnss, GnssReport(dict(counts), len(usable), height_source, sigma_source, message)


def _events(ulog, path: Path, clock: ClockFit, day: float) -> tuple[Exposures | None, list[InputNotice]]:
    """Exposures from camera_capture and camera_trigger: one per sequence number, the capture's where both
    record it."""
    found: dict[int, tuple[float, int, str, float]] = {}
    present = []
    for name in ("camera_trigger", "camera_capture"):  # the capture replaces the trigger of the same number
        topic = _topic(ulog, name)
        if topic is None or not len(_field(topic, "timestamp", path)):
            continue
        present.append(name)
        boot = _field(topic, "timestamp", path) * US
        seq = whole_numbers(_field(topic, "seq", path))
        # a capture, or a trigger with the camera's feedback (hotshoe), is the exposure; a bare trigger, or one of
        # a PX4 whose camera_trigger has no feedback field, only the command
        if name == "camera_capture":
            feedback = np.ones(len(seq), bool)
        elif "feedback" in topic.data:
            feedback = _field(topic, "feedback", path) != 0
        else:
            feedback = np.zeros(len(seq), bool)
        for k, (number, t, fed) in enumerate(zip(seq, clock.utc(boot), feedback, strict=True)):
            found[int(number)] = (float(t) - day, k, name, FEEDBACK_TIME_SIGMA if fed else TRIGGER_TIME_SIGMA)
    if not found:
        return None, []
    frames = np.array(sorted(found))
    sources = Counter(found[k][2] for k in frames)
    notices = []
    if len(present) == 2:
        notices.append(InputNotice(path, [], "camera_capture/camera_trigger", f"{len(frames)} exposures "
                                   f"({sources['camera_capture']} captures, {sources['camera_trigger']} trigger "
                                   "commands alone); a capture and a trigger with one sequence number are one "
                                   "exposure"))
    return Exposures(path=path, frame=frames.astype(str), time=np.array([found[k][0] for k in frames]),
                     lines=np.array([found[k][1] for k in frames]), notices=[],
                     time_sigma=np.array([found[k][3] for k in frames])), notices


def _vehicle(ulog) -> str:
    info = ulog.msg_info_dict
    parts = [str(info[k]) for k in ("sys_name", "ver_hw") if k in info]
    release = info.get("ver_sw_release")
    if isinstance(release, int) and release:
        parts.append(f"v{(release >> 24) & 0xFF}.{(release >> 16) & 0xFF}.{(release >> 8) & 0xFF}")
    return " ".join(parts) or "PX4"


class _ReadLoopError(RuntimeError):
    """pyulog went round in circles (not one of the exceptions pyulog catches itself)."""


class _BoundedStream(io.BytesIO):
    """A ULog's bytes as pyulog reads them, with a budget of bytes read and of read calls (:data:`READ_BUDGET`)."""

    def __init__(self, data: bytes) -> None:
        super().__init__(data)
        self._bytes_left = READ_BUDGET * len(data) + (64 << 20)
        self._calls_left = 4 * len(data) + 100_000

    def read(self, size: int | None = -1) -> bytes:
        out = super().read(size)
        self._bytes_left -= len(out)
        self._calls_left -= 1
        if self._bytes_left < 0 or self._calls_left < 0:
            raise _ReadLoopError("it went back over the same bytes again and again: damaged message headers there")
        return out


def _parse(path: Path, data: bytes):
    from pyulog import ULog

    captured = io.StringIO()
    stream = _BoundedStream(data)
    try:
        with contextlib.redirect_stdout(captured):
            ulog = ULog(stream, TOPICS, disable_str_exceptions=True)
    except Exception as exc:  # pyulog raises bare exceptions of several kinds on a damaged file
        raise InputError(path, None, None, f"not a readable ULog: pyulog stopped at byte {stream.tell()}: "
                         f"{excerpt(exc, 160)}") from None
    warnings = [line.strip() for line in captured.getvalue().splitlines() if line.strip()]
    return ulog, warnings


def read_px4(path: Path, data: bytes, imu_instance: int | None = None) -> FlightLog:
    """A PX4 ULog held in ``data``."""
    ulog, warnings = _parse(path, data)
    notices = [InputNotice(path, [], None, f"pyulog: {w}") for w in warnings[:5]]
    if ulog.dropouts:
        lost = sum(d.duration for d in ulog.dropouts) * 1e-3
        notices.append(InputNotice(path, [], None, f"{len(ulog.dropouts)} logging dropout(s), {lost:.2f} s in all: "
                                   "the logger could not keep up; IMU samples are missing there"))
    params, param_notices = _params(ulog, path)
    notices += param_notices
    topic = _gps_topic(ulog, path)
    fix = whole_numbers(_field(topic, "fix_type", path))
    good = np.isin(fix, GOOD_FIXES)
    if good.sum() < 2:
        raise InputError(path, None, f"{topic.name}.fix_type", f"{int(good.sum())} fixes of type 3D or better "
                         f"among {len(fix)}: nothing to georeference with")
    clock = _clock(path, topic, good, params)
    day = utc_day_start(clock.first_utc)
    imu, streams, imu_notices = _imu(ulog, path, imu_instance, clock, day)
    notices += imu_notices
    gnss, report = _gnss(path, topic, good, clock, day)
    attitude = None
    att = _topic(ulog, "vehicle_attitude")
    if att is not None:
        q = np.stack([_field(att, f"q[{k}]", path) for k in range(4)], -1)
        norm = np.linalg.norm(q, axis=1)
        unit = np.isfinite(norm) & (norm > 0.5) & (norm < 2.0)  # else not a rotation: a damaged sample
        roll, pitch, yaw = dcm_to_euler(quat_to_dcm(q[unit] / norm[unit, None]))
        attitude = Series("vehicle_attitude", clock.utc(_field(att, "timestamp", path)[unit] * US) - day,
                          np.stack([roll, pitch, yaw], -1))
    mag = None
    vm = _topic(ulog, "vehicle_magnetometer")
    sm = _topic(ulog, "sensor_mag")
    if vm is not None:
        mag = Series("vehicle_magnetometer", clock.utc(_field(vm, "timestamp", path) * US) - day,
                     _vector(vm, "magnetometer_ga", path))
    elif sm is not None:
        mag = Series("sensor_mag", clock.utc(_field(sm, "timestamp", path) * US) - day,
                     np.stack([_field(sm, a, path) for a in "xyz"], -1))
    events, event_notices = _events(ulog, path, clock, day)
    notices += event_notices
    notices.append(InputNotice(path, [], f"{topic.name}.time_utc_usec", clock.describe()))
    return FlightLog(path=path, kind="PX4 ULog", vehicle=_vehicle(ulog), day_start_utc=day, imu=imu,
                     imu_streams=streams, gnss=gnss, gnss_report=report, clock=clock, attitude=attitude, mag=mag,
                     events=events, lever_arm=_lever_arm(params), params=params, notices=notices,
                     position_unit="message")
