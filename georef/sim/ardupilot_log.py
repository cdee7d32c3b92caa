"""A simulated drone flight as ArduCopter logs it: the DataFlash messages of two firmware generations.

Message layouts are ArduPilot's (``libraries/AP_Logger/LogStructure.h``, ``libraries/AP_GPS/LogStructure.h``,
``libraries/AP_Camera/LogStructure.h`` and the vehicles' own, of the versions named):

* ``"4.x"`` (ArduCopter 4.5, boot time ``TimeUS`` [us] everywhere): PARM (with ``Default``), MSG, IMU (instance
  in ``I``), GPS (fix time ``GMS``/``GWk``, height ``Alt`` above mean sea level), GPA (``HAcc``/``VAcc`` and the
  undulation ``Und``, a float after ``Delta``: logged from its introduction in 2022 until 4.6), ATT, MAG, CAM (the
  camera's feedback) and TRIG (the trigger), numbered ``Img``.
* ``"3.x"`` (ArduCopter 3.2, boot time ``TimeMS`` [ms]): IMU and IMU2, GPS with ``TimeMS`` = GPS ms of week,
  ``Week`` and the arrival ``T`` [boot ms], u-blox accuracy in UBX3, CAM without boot time or image number, no
  TRIG, parameters without the GNSS lever arm or lag (which 3.2 did not have).

``GPA.Und`` carries ArduPilot's own undulation, whose sign is the opposite of the geodetic convention: its u-blox
driver sets ``undulation = hMSL - height`` (``AP_GPS_UBLOX.cpp``), so ``Und = -N``; ArduPilot issue #29199 and PR
#29904 (4.6 logs the ellipsoidal height ``GPA.AEl`` instead, "always flip GPA.Und sign to match the accepted
convention" for older logs). The writer logs what the firmware logs.

Message type numbers are the writer's: ArduPilot numbers them per build, and readers learn them from FMT.
"""

from __future__ import annotations

import datetime as dt

import numpy as np

from georef.frames import wrap_360
from georef.sim.dataflash_writer import MessageBlock, MessageType, block, format_block
from georef.sim.log_samples import EventMoment, LoggedFlight, Series, gps_time

GENERATIONS = ("4.x", "3.x")
FIX_STATUSES = (3, 4, 5, 6)
_SATELLITES, _HDOP, _VDOP, _SPEED_ACC = 16, 0.7, 1.1, 0.3

MESSAGES_4X = {kind.name: kind for kind in (
    MessageType("PARM", 64, "QNff", ("TimeUS", "Name", "Value", "Default")),
    MessageType("MSG", 91, "QZ", ("TimeUS", "Message")),
    MessageType("ATT", 35, "QccccCCCCB", ("TimeUS", "DesRoll", "Roll", "DesPitch", "Pitch", "DesYaw", "Yaw", "ErrRP",
                                         "ErrYaw", "AEKF")),
    MessageType("IMU", 93, "QBffffffIIfBBHH", ("TimeUS", "I", "GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ", "EG",
                                              "EA", "T", "GH", "AH", "GHz", "AHz")),
    MessageType("GPS", 129, "QBBIHBcLLeffffB", ("TimeUS", "I", "Status", "GMS", "GWk", "NSats", "HDop", "Lat", "Lng",
                                               "Alt", "Spd", "GCrs", "VZ", "Yaw", "U")),
    MessageType("GPA", 130, "QBCCCCfBIHf", ("TimeUS", "I", "VDop", "HAcc", "VAcc", "SAcc", "YAcc", "VV", "SMS",
                                           "Delta", "Und")),
    MessageType("MAG", 134, "QBhhhhhhhhhBI", ("TimeUS", "I", "MagX", "MagY", "MagZ", "OfsX", "OfsY", "OfsZ", "MOX",
                                             "MOY", "MOZ", "Health", "S")),
    MessageType("CAM", 146, "QBHIHLLeeeccC", ("TimeUS", "I", "Img", "GPSTime", "GPSWeek", "Lat", "Lng", "Alt",
                                             "RelAlt", "GPSAlt", "R", "P", "Y")),
    MessageType("TRIG", 147, "QBHIHLLeeeccC", ("TimeUS", "I", "Img", "GPSTime", "GPSWeek", "Lat", "Lng", "Alt",
                                              "RelAlt", "GPSAlt", "R", "P", "Y")),
)}
_IMU_3X = ("TimeMS", "GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ", "ErrG", "ErrA")
MESSAGES_3X = {kind.name: kind for kind in (
    MessageType("ATT", 1, "IccccCC", ("TimeMS", "DesRoll", "Roll", "DesPitch", "Pitch", "DesYaw", "Yaw")),
    MessageType("MAG", 15, "Ihhhhhhhhh", ("TimeMS", "MagX", "MagY", "MagZ", "OfsX", "OfsY", "OfsZ", "MOfsX",
                                          "MOfsY", "MOfsZ")),
    MessageType("PARM", 129, "Nf", ("Name", "Value")),
    MessageType("GPS", 130, "BIHBcLLeeEefI", ("Status", "TimeMS", "Week", "NSats", "HDop", "Lat", "Lng", "RelAlt",
                                              "Alt", "Spd", "GCrs", "VZ", "T")),
    MessageType("IMU", 131, "IffffffII", _IMU_3X),
    MessageType("MSG", 132, "Z", ("Message",)),
    MessageType("IMU2", 135, "IffffffII", _IMU_3X),
    MessageType("CAM", 148, "IHLLeeccC", ("GPSTime", "GPSWeek", "Lat", "Lng", "Alt", "RelAlt", "Roll", "Pitch",
                                          "Yaw")),
    MessageType("UBX3", 153, "IBfff", ("TimeMS", "Instance", "hAcc", "vAcc", "sAcc")),
)}
FIRMWARE = {"4.x": ("ArduCopter V4.5.7 (georef simulator)", "Frame: QUAD/X"),
            "3.x": ("ArduCopter V3.2.1 (georef simulator)", "Frame: QUAD")}


def _params(logged: LoggedFlight, generation: str) -> list[tuple[str, float]]:
    """(name, value) of the logged parameters: the 4.x GNSS lever arm (antenna at GPS_POS1, IMU at INS_POS1 =
    the body origin) and lag (GPS_DELAY_MS, whole ms on the board's clock), and a few of the usual others."""
    if generation == "3.x":
        return [("SYSID_SW_TYPE", 10.0), ("FRAME", 1.0), ("LOG_BITMASK", 26622.0), ("CAM_TRIGG_TYPE", 1.0),
                ("INS_MPU6K_FILTER", 20.0)]
    arm = logged.lever_arm_gnss
    return [("FRAME_CLASS", 1.0), ("FRAME_TYPE", 1.0), ("AHRS_EKF_TYPE", 3.0), ("LOG_BITMASK", 176126.0),
            ("INS_GYRO_FILTER", 20.0), ("INS_ACCEL_FILTER", 20.0), ("GPS_TYPE", 2.0),
            ("GPS_DELAY_MS", float(round(logged.gnss_lag_boot_s * 1000.0))),
            ("GPS_POS1_X", arm[0]), ("GPS_POS1_Y", arm[1]), ("GPS_POS1_Z", arm[2]),
            ("INS_POS1_X", 0.0), ("INS_POS1_Y", 0.0), ("INS_POS1_Z", 0.0), ("CAM1_TYPE", 1.0)]


def _header(logged: LoggedFlight, generation: str, kinds: dict[str, MessageType]) -> list[MessageBlock]:
    params = _params(logged, generation)
    names = [name for name, _ in params]
    values = [value for _, value in params]
    when = np.full(len(params), logged.header_boot)
    texts = FIRMWARE[generation]
    text_time = np.full(len(texts), logged.header_boot)
    if generation == "3.x":
        return [block(kinds["MSG"], text_time, Message=list(texts)),
                block(kinds["PARM"], when, Name=names, Value=values)]
    defaults = [0.0 if name.startswith(("GPS_POS", "INS_POS", "GPS_DELAY")) else value for name, value in params]
    return [block(kinds["MSG"], text_time, TimeUS=text_time * 1e6, Message=list(texts)),
            block(kinds["PARM"], when, TimeUS=when * 1e6, Name=names, Value=values, Default=defaults)]


def _imu_4x(logged: LoggedFlight) -> list[MessageBlock]:
    out = []
    for instance, imu in enumerate(i for i in (logged.imu, logged.imu2) if i is not None):
        rate = round(1.0 / float(np.median(np.diff(imu.utc))))
        out.append(block(MESSAGES_4X["IMU"], imu.boot, TimeUS=imu.boot * 1e6, I=instance,
                         **{f"Gyr{a}": imu.gyro[:, k] for k, a in enumerate("XYZ")},
                         **{f"Acc{a}": imu.accel[:, k] for k, a in enumerate("XYZ")},
                         EG=0, EA=0, T=imu.temperature, GH=1, AH=1, GHz=rate, AHz=rate))
    return out


def _imu_3x(logged: LoggedFlight) -> list[MessageBlock]:
    out = []
    for name, imu in (("IMU", logged.imu), ("IMU2", logged.imu2)):
        if imu is not None:
            out.append(block(MESSAGES_3X[name], imu.boot, TimeMS=imu.boot * 1e3,
                             **{f"Gyr{a}": imu.gyro[:, k] for k, a in enumerate("XYZ")},
                             **{f"Acc{a}": imu.accel[:, k] for k, a in enumerate("XYZ")}, ErrG=0, ErrA=0))
    return out


def _motion(logged: LoggedFlight) -> dict[str, np.ndarray]:
    """Ground speed [m/s], course [deg, 0-360) and down speed [m/s] of the fixes."""
    v_n = logged.fixes.v_n
    return {"speed": np.hypot(v_n[:, 0], v_n[:, 1]),
            "course": np.round(wrap_360(np.degrees(np.arctan2(v_n[:, 1], v_n[:, 0]))), 2) % 360.0,
            "down": v_n[:, 2]}


def _gnss_4x(logged: LoggedFlight, date: dt.date, status: int) -> list[MessageBlock]:
    fixes = logged.fixes
    when = gps_time(fixes.utc, date)
    arrival_ms = np.round(fixes.arrival_boot * 1e3)
    motion = _motion(logged)
    gps = block(MESSAGES_4X["GPS"], fixes.arrival_boot, TimeUS=fixes.arrival_boot * 1e6, I=0, Status=status,
                GMS=when.ms_of_week, GWk=when.week, NSats=_SATELLITES, HDop=_HDOP, Lat=fixes.lat, Lng=fixes.lon,
                Alt=fixes.msl, Spd=motion["speed"], GCrs=motion["course"], VZ=motion["down"], Yaw=0.0, U=1)
    # ArduPilot's undulation (hMSL - height), see the module doc; Delta: ms since the previous fix, saturated
    gpa = block(MESSAGES_4X["GPA"], fixes.arrival_boot, TimeUS=fixes.arrival_boot * 1e6, I=0, VDop=_VDOP,
                HAcc=fixes.sigma_h, VAcc=fixes.sigma_v, SAcc=_SPEED_ACC, YAcc=0.0, VV=1, SMS=arrival_ms,
                Delta=np.minimum(np.diff(arrival_ms, prepend=arrival_ms[0]), 65535), Und=fixes.msl - fixes.height)
    return [gps, gpa]


def _gnss_3x(logged: LoggedFlight, date: dt.date, status: int) -> list[MessageBlock]:
    fixes = logged.fixes
    when = gps_time(fixes.utc, date)
    motion = _motion(logged)
    gps = block(MESSAGES_3X["GPS"], fixes.arrival_boot, Status=status, TimeMS=when.ms_of_week, Week=when.week,
                NSats=_SATELLITES, HDop=_HDOP, Lat=fixes.lat, Lng=fixes.lon, RelAlt=fixes.height - logged.start_height,
                Alt=fixes.msl, Spd=motion["speed"], GCrs=motion["course"], VZ=motion["down"],
                T=fixes.arrival_boot * 1e3)
    ubx = block(MESSAGES_3X["UBX3"], fixes.arrival_boot, TimeMS=fixes.arrival_boot * 1e3, Instance=0,
                hAcc=fixes.sigma_h, vAcc=fixes.sigma_v, sAcc=_SPEED_ACC)
    return [gps, ubx]


def _angles(series: Series) -> dict[str, np.ndarray]:
    deg = np.degrees(series.values)
    return {"Roll": deg[:, 0], "Pitch": deg[:, 1], "Yaw": np.round(wrap_360(deg[:, 2]), 2) % 360.0}


def _attitude_mag(logged: LoggedFlight, generation: str) -> list[MessageBlock]:
    """ATT (the autopilot's attitude, the demand equal to it) and MAG [milligauss]."""
    att_t = logged.attitude.boot
    a = _angles(logged.attitude)
    if generation == "3.x":
        kinds, stamp = MESSAGES_3X, {"TimeMS": att_t * 1e3}
        extra: dict[str, object] = {}
    else:
        kinds, stamp = MESSAGES_4X, {"TimeUS": att_t * 1e6}
        extra = {"ErrRP": 0.0, "ErrYaw": 0.0, "AEKF": 3}
    out = [block(kinds["ATT"], att_t, **stamp, DesRoll=a["Roll"], Roll=a["Roll"], DesPitch=a["Pitch"],
                 Pitch=a["Pitch"], DesYaw=a["Yaw"], Yaw=a["Yaw"], **extra)]
    if logged.mag is None:
        return out
    mag_t = logged.mag.boot
    milligauss = {f"Mag{a}": logged.mag.values[:, k] * 10.0 for k, a in enumerate("XYZ")}
    offsets = {f"Ofs{a}": 0 for a in "XYZ"}
    if generation == "3.x":
        out.append(block(kinds["MAG"], mag_t, TimeMS=mag_t * 1e3, **milligauss, **offsets,
                         **{f"MOfs{a}": 0 for a in "XYZ"}))
    else:
        out.append(block(kinds["MAG"], mag_t, TimeUS=mag_t * 1e6, I=0, **milligauss, **offsets,
                         **{f"MO{a}": 0 for a in "XYZ"}, Health=1, S=np.round(mag_t * 1e6) % 2**32))
    return out


def _event_fields(moment: EventMoment, date: dt.date, start_height: float) -> dict[str, object]:
    when = gps_time(moment.utc, date)
    deg = np.degrees(moment.rpy)
    return {"GPSTime": when.ms_of_week, "GPSWeek": when.week, "Lat": moment.lat, "Lng": moment.lon,
            "Alt": moment.msl, "RelAlt": moment.height - start_height, "roll": deg[:, 0], "pitch": deg[:, 1],
            "yaw": np.round(wrap_360(deg[:, 2]), 2) % 360.0}


def _camera(logged: LoggedFlight, date: dt.date, generation: str) -> list[MessageBlock]:
    """4.x: TRIG at the trigger and CAM at the capture, with one image number; 3.x: CAM at the trigger."""
    events = logged.events
    if generation == "3.x":
        f = _event_fields(events.trigger, date, logged.start_height)
        return [block(MESSAGES_3X["CAM"], events.trigger.boot, GPSTime=f["GPSTime"], GPSWeek=f["GPSWeek"],
                      Lat=f["Lat"], Lng=f["Lng"], Alt=f["Alt"], RelAlt=f["RelAlt"], Roll=f["roll"],
                      Pitch=f["pitch"], Yaw=f["yaw"])]
    out = []
    for name, moment in (("TRIG", events.trigger), ("CAM", events.capture)):
        f = _event_fields(moment, date, logged.start_height)
        out.append(block(MESSAGES_4X[name], moment.boot, TimeUS=moment.boot * 1e6, I=0, Img=events.number,
                         GPSTime=f["GPSTime"], GPSWeek=f["GPSWeek"], Lat=f["Lat"], Lng=f["Lng"], Alt=f["Alt"],
                         RelAlt=f["RelAlt"], GPSAlt=f["Alt"], R=f["roll"], P=f["pitch"], Y=f["yaw"]))
    return out


def ardupilot_blocks(logged: LoggedFlight, generation: str, date: dt.date, fix_status: int = 3) -> list[MessageBlock]:
    """Every message of the log, the FMT messages first (encode with :mod:`georef.sim.dataflash_writer`)."""
    if generation not in GENERATIONS:
        raise ValueError(f"generation must be one of {', '.join(GENERATIONS)}, got {generation!r}")
    if fix_status not in FIX_STATUSES:
        raise ValueError(f"fix_status must be one of {FIX_STATUSES} (3D, DGPS, RTK float, RTK fixed), got {fix_status}")
    kinds = MESSAGES_3X if generation == "3.x" else MESSAGES_4X
    imu = _imu_3x(logged) if generation == "3.x" else _imu_4x(logged)
    gnss = (_gnss_3x if generation == "3.x" else _gnss_4x)(logged, date, fix_status)
    blocks = _header(logged, generation, kinds) + imu + gnss + _attitude_mag(logged, generation)
    blocks += _camera(logged, date, generation)
    used = sorted({b.kind.name for b in blocks}, key=lambda name: kinds[name].type_id)
    return [format_block([kinds[name] for name in used])] + blocks
