"""ArduPilot DataFlash logs (``.bin``, ``.log``): IMU, GNSS, attitude, magnetometer, camera events, parameters.

Messages and fields as ArduPilot logs them (``libraries/AP_Logger/LogStructure.h`` and the vehicles' own),
over the generations met in the field:

* ``IMU``: ``GyrX..Z`` [rad/s], ``AccX..Z`` [m/s^2], body frame (the board orientation applied); the instance
  in field ``I`` (4.x) or in the message name (``IMU2``, ``IMU3``, 3.x); boot time ``TimeUS`` [us] or
  ``TimeMS`` [ms].
* ``GPS``: ``Status`` (0 no GPS, 1 no fix, 2 2D, 3 3D, 4 DGPS, 5 RTK float, 6 RTK fixed), the fix's GPS time
  ``GMS``/``GWk`` (4.x) or ``TimeMS``/``Week`` (3.x), ``Lat``/``Lng`` [deg], ``Alt`` [m above mean sea level],
  the boot time of its arrival ``TimeUS`` or ``T`` [ms]; the instance in ``I`` or the name ``GPS2``.
* Accuracy: ``GPA.HAcc``/``VAcc`` [m], or u-blox's ``UBX3.hAcc``/``vAcc`` (3.x). ArduPilot's EKF takes hAcc as
  each horizontal axis's sigma, and so does georef.
* Heights: ``GPA.AEl`` (4.6+) is the receiver's ellipsoidal height [m] itself (INT32_MIN / 100 when unknown).
  Before it, ``GPA.Und`` (4.1-4.5) is what ArduPilot's drivers compute as ``hMSL - h_ellipsoid``, minus the
  geoid undulation, whatever its name (ArduPilot issue 29199; 4.6 replaced it by ``AEl``): the ellipsoidal height
  is ``Alt - Und``. Without either, EGM96 through PROJ.
* ``ATT``: ``Roll``, ``Pitch``, ``Yaw`` [deg] (the autopilot's attitude); ``AHR2`` the same from its backup
  estimator; ``MAG``: ``MagX..Z`` [mGauss, body].
* ``CAM`` (the camera's feedback) and ``TRIG`` (the trigger command): one exposure each, numbered ``Img``.
* ``PARM``: ``GPS_POS1_X/Y/Z`` (4.6+: ``GPS1_POS_X/Y/Z``) and ``INS_POS1_X/Y/Z`` [m, body] give the GNSS lever
  arm; ``GPS_DELAY_MS`` (4.6+: ``GPS1_DELAY_MS``) the lag of the fix messages.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np

from georef.frames.gpstime import gps_week_to_utc, leap_seconds_note, utc_day_start
from georef.io.camera import FEEDBACK_TIME_SIGMA, TRIGGER_TIME_SIGMA, Exposures
from georef.io.errors import InputError, InputNotice, excerpt
from georef.io.logs.clock import ClockFit, fit_clock
from georef.io.logs.dataflash import DataFlashLog, MessageTable, read_binary, read_text
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

WANTED = ("IMU", "IMU2", "IMU3", "GPS", "GPS2", "GPA", "UBX3", "ATT", "AHR2", "MAG", "CAM", "TRIG", "PARM", "MSG",
          "VER")
#: ArduPilot's GPS status values
FIX_NAMES = {0: "no GPS", 1: "no fix", 2: "2D", 3: "3D", 4: "DGPS", 5: "RTK float", 6: "RTK fixed"}
MIN_FIX = 3
#: the lag of a fix message when the log states none (GPS_DELAY_MS 0 or absent) [s]: about what ArduPilot's
#: u-blox driver assumes for its receivers; the filter's calibration pass reports what the data say
DEFAULT_GPS_LAG_S = 0.12


def _column(table: MessageTable, name: str, path: Path, text: bool = False) -> np.ndarray:
    """Field ``name`` of every message of ``table`` (numbers, or ``text``); an error naming message and field when
    the log's format of the message (its FMT message) has no such field, or holds text where a number belongs: a
    damaged FMT, or a generation of ArduPilot this reader lacks."""
    if name not in table.columns:
        raise InputError(path, None, f"{table.name}.{name}", f"the log's format of {table.name} (its FMT message) "
                         f"has no field {name}, only {excerpt(','.join(table.columns), 80)}")
    values = table.columns[name]
    if not text and values.dtype == object:
        raise InputError(path, None, f"{table.name}.{name}", f"the log's format of {table.name} (its FMT message) "
                         f"makes {name} text, not a number")
    return values


def _boot_seconds(table: MessageTable, path: Path) -> np.ndarray:
    """Boot time [s] of every message of ``table``, from TimeUS [us] or TimeMS [ms]."""
    if table.has("TimeUS"):
        return _column(table, "TimeUS", path) * 1e-6
    if table.has("TimeMS"):
        return _column(table, "TimeMS", path) * 1e-3
    raise InputError(path, None, f"{table.name}.TimeUS", f"{table.name} messages carry no boot time (TimeUS or "
                     "TimeMS)")


def _instances(log: DataFlashLog, name: str) -> dict[int, tuple[MessageTable, np.ndarray]]:
    """Instance -> (the messages' table, row mask), from field ``I`` or from numbered names (IMU2 ...)."""
    out: dict[int, tuple[MessageTable, np.ndarray]] = {}
    base = log.messages.get(name)
    if base is not None:
        if base.has("I"):
            numbers = whole_numbers(base.columns["I"])
            for instance in np.unique(numbers):
                out[int(instance)] = (base, numbers == instance)
        else:
            out[0] = (base, np.ones(len(base), bool))
    for k in (2, 3):
        numbered = log.messages.get(f"{name}{k}")
        if numbered is not None and k - 1 not in out:
            out[k - 1] = (numbered, np.ones(len(numbered), bool))
    return out


def _imu(log: DataFlashLog, instance: int | None, clock: ClockFit,
         day: float) -> tuple[ImuStream, list[str], list[InputNotice]]:
    """The IMU stream of ``instance`` (default 0), the streams the log has, and a notice of the samples left out
    (not finite, repeated or out of time order)."""
    streams = _instances(log, "IMU")
    if not streams:
        raise InputError(log.path, None, "IMU", "the log has no IMU messages: set LOG_BITMASK to log IMU data")
    names = [f"IMU[{k}]" for k in sorted(streams)]
    chosen = 0 if instance is None else instance
    if chosen not in streams:
        raise InputError(log.path, None, "IMU.I", f"no IMU instance {chosen}; the log has {', '.join(names)}")
    table, rows = streams[chosen]
    boot = _boot_seconds(table, log.path)[rows]
    gyro = np.stack([_column(table, f"Gyr{a}", log.path)[rows] for a in "XYZ"], -1)
    accel = np.stack([_column(table, f"Acc{a}", log.path)[rows] for a in "XYZ"], -1)
    where = table.where[rows]
    keep, non_finite = usable_imu(boot, gyro, accel)
    name = f"IMU[{chosen}]"
    if not keep.any():
        raise InputError(log.path, None, "IMU.GyrX", f"{name} has no usable sample ({len(keep)} logged, "
                         f"{non_finite} of them with a value that is not a finite number)")
    notice = imu_notice(log.path, name, keep, non_finite, where, "byte" if log.binary else "line")
    time = clock.utc(boot[keep]) - day
    return ImuStream(name, time, gyro[keep], accel[keep], where[keep]), names, [notice] if notice else []


def _gps_times(table: MessageTable, rows: np.ndarray, path: Path) -> tuple[np.ndarray, np.ndarray, str]:
    """(boot arrival [s], UTC [POSIX s], field name) of the fixes."""
    if table.has("GMS", "GWk"):
        week, tow, field = _column(table, "GWk", path)[rows], _column(table, "GMS", path)[rows] * 1e-3, "GPS.GMS"
    else:
        week, tow, field = (_column(table, "Week", path)[rows], _column(table, "TimeMS", path)[rows] * 1e-3,
                            "GPS.TimeMS")
    arrival = _boot_seconds(table, path)[rows] if table.has("TimeUS") else _column(table, "T", path)[rows] * 1e-3
    utc = np.where(week > 0, gps_week_to_utc(week, tow), np.nan)
    return arrival, utc, field


def _accuracy(log: DataFlashLog, table: MessageTable, rows: np.ndarray, arrival: np.ndarray,
              instance: int) -> tuple[np.ndarray | None, np.ndarray | None, str | None]:
    """(sigma_neu (K, 3) [m], the receiver's ellipsoidal minus mean-sea-level height (K,) [m] or None, source)
    from GPA (same boot time) or UBX3 (nearest)."""
    gpa = _instances(log, "GPA").get(instance)
    if gpa is not None and gpa[1].any():
        g_table, g_rows = gpa
        g_time = _boot_seconds(g_table, log.path)[g_rows]
        index = np.clip(np.searchsorted(g_time, arrival - 1e-6), 0, len(g_time) - 1)
        close = np.abs(g_time[index] - arrival) < 1e-3
        h = np.where(close, _column(g_table, "HAcc", log.path)[g_rows][index], np.nan)
        v = np.where(close, _column(g_table, "VAcc", log.path)[g_rows][index], np.nan)
        separation = _receiver_separation(g_table, g_rows, index, close, _column(table, "Alt", log.path)[rows])
        return np.stack([h, h, v], -1), separation, "GPA.HAcc/VAcc"
    ubx = log.messages.get("UBX3")
    if ubx is not None and ubx.has("hAcc", "vAcc") and len(ubx):
        u_rows = ubx.columns["Instance"] == instance if ubx.has("Instance") else np.ones(len(ubx), bool)
        u_time = _boot_seconds(ubx, log.path)[u_rows]
        if len(u_time):
            index = np.clip(np.searchsorted(u_time, arrival), 0, len(u_time) - 1)
            before = np.clip(index - 1, 0, len(u_time) - 1)
            index = np.where(np.abs(u_time[before] - arrival) < np.abs(u_time[index] - arrival), before, index)
            close = np.abs(u_time[index] - arrival) < 0.2
            h = np.where(close, ubx.columns["hAcc"][u_rows][index], np.nan)
            v = np.where(close, ubx.columns["vAcc"][u_rows][index], np.nan)
            return np.stack([h, h, v], -1), None, "UBX3.hAcc/vAcc"
    return None, None, None


#: GPA.AEl's value when the receiver gives no ellipsoidal height: INT32_MIN centimetres
_AEL_UNKNOWN = -2147483648 / 100.0


def _receiver_separation(g_table: MessageTable, g_rows: np.ndarray, index: np.ndarray, close: np.ndarray,
                         msl: np.ndarray) -> np.ndarray | None:
    """Ellipsoidal minus mean-sea-level height [m] the receiver reported with each fix: ``AEl - Alt`` (4.6+) or
    ``-Und`` (4.1-4.5, see the module docstring); NaN where neither is known."""
    if g_table.has("AEl"):
        ellipsoidal = g_table.columns["AEl"][g_rows][index]
        known = close & (ellipsoidal > _AEL_UNKNOWN + 1.0)
        return np.where(known, ellipsoidal - msl, np.nan)
    if g_table.has("Und"):
        return np.where(close, -g_table.columns["Und"][g_rows][index], np.nan)
    return None


def _params(log: DataFlashLog) -> tuple[dict[str, float], list[InputNotice]]:
    """The parameters (the last value of each), and a notice of those whose value is no finite number."""
    table = log.messages.get("PARM")
    if table is None:
        return {}, []
    names, values = _column(table, "Name", log.path, text=True), _column(table, "Value", log.path)
    return numeric_params(list(zip(names, values, strict=True)), log.path)


def _lag(params: dict[str, float]) -> tuple[float, str]:
    for name in ("GPS1_DELAY_MS", "GPS_DELAY_MS"):  # 4.6+ first
        delay = params.get(name, 0.0)
        if delay > 0:
            return delay * 1e-3, f"{name} = {delay:.0f}"
    return DEFAULT_GPS_LAG_S, "GPS_DELAY_MS not set: ArduPilot's usual u-blox lag"


def _lever_arm(params: dict[str, float]) -> LeverArmParameter | None:
    for prefix in ("GPS1_POS_", "GPS_POS1_"):  # 4.6+ first
        names = [f"{prefix}{a}" for a in "XYZ"]
        if all(n in params for n in names):
            return lever_arm_parameter(params, names, [f"INS_POS1_{a}" for a in "XYZ"])
    return None


def _has_feedback_pin(log: DataFlashLog, params: dict[str, float]) -> bool:
    """Whether the camera's feedback pin was set: TRIG messages in the log, or the pin parameter (CAM_FEEDBACK_PIN
    before ArduPilot 4.4, CAM1_FEEDBAK_PIN since) above 0."""
    trig = log.messages.get("TRIG")
    if trig is not None and len(trig):
        return True
    return any(params.get(name, -1.0) > 0 for name in ("CAM_FEEDBACK_PIN", "CAM1_FEEDBAK_PIN", "CAM2_FEEDBAK_PIN"))


def _events(log: DataFlashLog, clock: ClockFit, day: float,
            params: dict[str, float]) -> tuple[Exposures | None, list[InputNotice]]:
    """Exposures from CAM and TRIG: one per image number, the CAM message where both record it; boot times
    through the clock, else the message's GPS time. A CAM is the exposure (sigma FEEDBACK_TIME_SIGMA) only with
    a feedback pin (:func:`_has_feedback_pin`), else the trigger command (TRIGGER_TIME_SIGMA)."""
    notices: list[InputNotice] = []
    found: dict[int, tuple[float, int, str]] = {}
    for name in ("TRIG", "CAM"):  # CAM last: the feedback replaces the trigger command of the same image
        table = log.messages.get(name)
        if table is None or not len(table):
            continue
        if table.has("TimeUS") or table.has("TimeMS"):
            utc = clock.utc(_boot_seconds(table, log.path))
        else:
            utc = gps_week_to_utc(_column(table, "GPSWeek", log.path), _column(table, "GPSTime", log.path) * 1e-3)
        numbers = whole_numbers(table.columns["Img"]) if table.has("Img") else np.arange(1, len(table) + 1)
        for number, t, where in zip(numbers, utc, table.where, strict=True):
            found[int(number)] = (float(t) - day, int(where), name)
    if not found:
        return None, notices
    frames = np.array(sorted(found))
    time = np.array([found[k][0] for k in frames])
    where = np.array([found[k][1] for k in frames])
    sources = Counter(found[k][2] for k in frames)
    # ArduPilot logs TRIG at the trigger command and CAM at the feedback pin's pulse (the exposure) when a
    # feedback pin is set; without one it logs CAM alone, at the command (AP_Camera_Backend::log_picture)
    feedback = _has_feedback_pin(log, params)
    time_sigma = np.array([FEEDBACK_TIME_SIGMA if found[k][2] == "CAM" and feedback else TRIGGER_TIME_SIGMA
                           for k in frames])
    if sources["CAM"] and not feedback:
        notices.append(InputNotice(log.path, [], "CAM", f"{sources['CAM']} CAM messages without a camera feedback "
                                   "pin (no TRIG messages, no CAM_FEEDBACK_PIN): ArduPilot logs them at the trigger "
                                   f"command, so each exposure time is taken to {TRIGGER_TIME_SIGMA:g} s "
                                   "(--camera-time-offset and --camera-time-sigma set the camera's own latency)"))
    both = sum(1 for name in ("CAM", "TRIG") if log.messages.get(name) is not None and len(log.messages[name]))
    if both == 2:
        notices.append(InputNotice(log.path, [], "CAM/TRIG", f"{len(frames)} exposures ({sources['CAM']} from the "
                                   f"camera's feedback CAM, {sources['TRIG']} from trigger commands TRIG alone); "
                                   "a CAM and a TRIG with one image number are one exposure"))
    return Exposures(path=log.path, frame=frames.astype(str), time=time, lines=where, notices=[],
                     time_sigma=time_sigma), notices


def _vehicle(log: DataFlashLog) -> str:
    msg = log.messages.get("MSG")
    texts = [str(t) for t in msg.columns["Message"][:6]] if msg is not None and msg.has("Message") else []
    firmware = next((t for t in texts if any(w in t for w in ("Copter", "Plane", "Rover", "Sub", "APM"))), None)
    frame = next((t for t in texts if t.startswith("Frame")), None)
    return ", ".join(t for t in (firmware, frame) if t) or "ArduPilot"


def read_ardupilot(path: Path, data: bytes, imu_instance: int | None = None) -> FlightLog:
    """An ArduPilot DataFlash log (binary or text, told apart by content) held in ``data``."""
    from georef.io.logs.dataflash import is_binary_dataflash

    binary = is_binary_dataflash(data[:4096])
    log = read_binary(path, data, WANTED) if binary else read_text(path, data.decode("latin-1"), WANTED)
    notices: list[InputNotice] = []
    unit = "byte" if binary else "line"
    if log.skipped:
        where = [int(w) for w, _ in log.skipped]
        total = sum(n for _, n in log.skipped)
        notices.append(InputNotice(path, [], None, f"{total} {unit}(s) in {len(where)} run(s) were not messages and "
                                   f"were skipped (first at {unit} {where[0]}): a log cut short or corrupted there"))
    params, param_notices = _params(log)
    notices += param_notices
    gps = _instances(log, "GPS").get(0)
    if gps is None:
        raise InputError(path, None, "GPS", "the log has no GPS messages")
    table, rows = gps
    status = whole_numbers(_column(table, "Status", path)[rows])
    arrival, utc, time_field = _gps_times(table, rows, path)
    good = status >= MIN_FIX
    if good.sum() < 2:
        raise InputError(path, None, "GPS.Status", f"{int(good.sum())} GPS fixes of type 3D or better among "
                         f"{len(status)}: nothing to georeference with")
    lag, lag_source = _lag(params)
    clock = fit_clock(path, arrival[good], utc[good], lag, lag_source, time_field)
    day = utc_day_start(clock.first_utc)
    note = leap_seconds_note(clock.first_utc)
    if note:
        notices.append(InputNotice(path, [], time_field, note))
    imu, streams, imu_notices = _imu(log, imu_instance, clock, day)
    notices += imu_notices
    gnss, report = _gnss(log, table, rows, status, arrival, utc, clock, day)
    attitude = None
    att = log.messages.get("ATT")
    if att is not None and len(att):
        rpy = np.radians(np.stack([_column(att, a, path) for a in ("Roll", "Pitch", "Yaw")], -1))
        attitude = Series("ATT", clock.utc(_boot_seconds(att, path)) - day, rpy)
    backup = None
    ahr2 = log.messages.get("AHR2")
    if ahr2 is not None and len(ahr2) and ahr2.has("Roll", "Pitch", "Yaw"):
        rpy = np.radians(np.stack([ahr2.columns["Roll"], ahr2.columns["Pitch"], ahr2.columns["Yaw"]], -1))
        backup = Series("AHR2", clock.utc(_boot_seconds(ahr2, path)) - day, rpy)
    mag = None
    m = _instances(log, "MAG").get(0)
    if m is not None:
        m_table, m_rows = m
        mag = Series("MAG", clock.utc(_boot_seconds(m_table, path)[m_rows]) - day,
                     np.stack([_column(m_table, f"Mag{a}", path)[m_rows] for a in "XYZ"], -1))
    events, event_notices = _events(log, clock, day, params)
    notices += event_notices
    notices.append(InputNotice(path, [], time_field, clock.describe()))
    return FlightLog(path=path, kind=f"ArduPilot DataFlash log ({'binary' if binary else 'text'})",
                     vehicle=_vehicle(log), day_start_utc=day, imu=imu, imu_streams=streams, gnss=gnss,
                     gnss_report=report, clock=clock, attitude=attitude, attitude_backup=backup, mag=mag,
                     events=events,
                     lever_arm=_lever_arm(params), params=params, notices=notices, position_unit=unit)


def _gnss(log: DataFlashLog, table: MessageTable, rows: np.ndarray, status: np.ndarray, arrival: np.ndarray,
          utc: np.ndarray, clock: ClockFit, day: float) -> tuple[GnssEpochs, GnssReport]:
    """The fixes of type 3D or better, each at its receiver time (or, where that is missing or repeats a time
    already used, at its arrival through the clock), ellipsoidal heights, per-fix sigmas."""
    lat = _column(table, "Lat", log.path)[rows]
    lon = _column(table, "Lng", log.path)[rows]
    alt = _column(table, "Alt", log.path)[rows]
    sigma, undulation, sigma_source = _accuracy(log, table, rows, arrival, 0)
    counts = Counter(FIX_NAMES.get(int(s), f"status {int(s)}") for s in status)
    good = status >= MIN_FIX
    fitted = clock.utc(arrival - clock.lag_s)
    time = np.where(np.isfinite(utc) & (np.abs(utc - fitted) < 0.5), utc, fitted)
    usable = np.flatnonzero(good & np.isfinite(time) & (np.abs(lat) <= 90) & (np.abs(lon) <= 180)
                            & ~((lat == 0) & (lon == 0)) & np.isfinite(alt))
    usable = usable[np.argsort(time[usable], kind="stable")]
    # a receiver time already used is the receiver repeating itself: the repeat is not a new fix
    usable = usable[np.concatenate([[True], np.diff(time[usable]) > 0])[:len(usable)]]
    if len(usable) < 2:
        raise InputError(log.path, None, "GPS.Lat", f"{len(usable)} of the {int(good.sum())} fixes of type 3D or "
                         "better have a time, a position in range and a height: nothing to georeference with")
    keep = np.zeros(len(status), bool)
    keep[usable] = True
    height, height_source = ellipsoidal_heights(lat[keep], lon[keep], alt[keep],
                                                None if undulation is None else undulation[keep], "GPS.Alt")
    order = np.argsort(time[keep], kind="stable")
    sig = None if sigma is None else sigma[keep][order]
    if sig is not None:  # 0 is what ArduPilot logs when the receiver gives no accuracy: unknown, as NaN is
        sig = np.where(np.isfinite(sig) & (sig > 0), sig, np.nan)
    if sig is not None and not np.isfinite(sig).any():
        sig, sigma_source = None, None
    gnss = GnssEpochs(time=(time[keep] - day)[order], lat_deg=lat[keep][order], lon_deg=lon[keep][order],
                      height=height[order], line=table.where[rows][keep][order],
                      repeated=np.zeros(int(keep.sum()), bool), sigma_neu=sig)
    message = (f"{int(keep.sum())} of {len(status)} GPS fixes used (type 3D or better): "
               + ", ".join(f"{name} {n}" for name, n in counts.most_common()))
    return gnss, GnssReport(dict(counts), int(keep.sum()), height_source, sigma_source, message)
