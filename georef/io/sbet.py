"""Applanix SBET (smoothed best estimate of trajectory) and its ``smrmsg`` RMS file, for LiDAR and pushbroom
software (``--export sbet:FILE``; docs/sbet.md).

* SBET: records of 17 little-endian float64, no header, in the order of PDAL's ``readers.sbet``
  (``io/SbetCommon.hpp``): GPS seconds of the week, latitude, longitude [rad], ellipsoidal height [m], x, y, z
  velocity [m/s] in the wander frame, roll, pitch, platform heading, wander angle [rad], x, y, z body acceleration
  [m/s^2], x, y, z body angular rate [rad/s]. Conventions: :mod:`georef.frames.wander`.
* smrmsg: records of 10 little-endian float64: GPS seconds of the week, north, east, down position RMS [m],
  north, east, down velocity RMS [m/s], roll, pitch, heading RMS [arc-minutes] (PDAL's ``readers.smrmsg``,
  the same file; the units from NOAA's HSTB drivers ``sbet.py`` and JALBTCX ``FileRMSOutput.h``). Written beside
  the SBET as ``smrmsg_<name>.out`` (``sbet_<name>.out`` -> ``smrmsg_<name>.out``, as POSPac names the pair).

What georef writes: the IMU's navigation at the IMU rows (or every row that starts a new ``1/rate`` second of GPS
time, ``rate_hz``), rows without a solution left out and counted (SBET has no flag field: a filler row would be
read as a position). The body rates and accelerations are the raw IMU's, less the biases the filter estimated
(the full-state methods; the per-axis method estimates none), the accelerations with gravity removed. The RMS are
the solution's 1-sigma; the velocity RMS NaN where the method estimates no velocity covariance (``axis``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from georef.frames import euler_to_dcm
from georef.frames.gpstime import (
    GPS_EPOCH,
    SECONDS_PER_DAY,
    gps_week_of,
    leap_seconds_note,
    scale_to_gps_week,
    scale_to_utc,
    utc_date,
    utc_day_start,
    utc_to_gps_seconds,
)
from georef.frames.wander import ARCMIN_PER_RAD, body_acceleration, ned_to_wander, platform_heading
from georef.io.atomic import atomic_group, atomic_write

if TYPE_CHECKING:
    from georef.fusion.solution import NavSolution
    from georef.io.pos_time_scale import ScaleChoice

#: the SBET record's fields, in file order (PDAL io/SbetCommon.hpp ``fileDimensions``, commit ccf0ab70)
SBET_FIELDS = ("gps_time", "latitude", "longitude", "height", "x_velocity", "y_velocity", "z_velocity", "roll",
               "pitch", "platform_heading", "wander_angle", "x_body_accel", "y_body_accel", "z_body_accel",
               "x_body_angular_rate", "y_body_angular_rate", "z_body_angular_rate")
#: the smrmsg record's fields, in file order (PDAL io/SbetCommon.hpp ``smrmsgFileDimensions``)
SMRMSG_FIELDS = ("gps_time", "north_position_rms", "east_position_rms", "down_position_rms", "north_velocity_rms",
                 "east_velocity_rms", "down_velocity_rms", "roll_rms", "pitch_rms", "heading_rms")
#: the files' byte order and value type: little-endian IEEE 754 double
RECORD_TYPE = "<f8"


class SbetExportError(ValueError):
    """An SBET that cannot be written from this run (no date for the time of day, no raw IMU, no solution)."""


#: times from this on [s] are Unix seconds (2001-09-09 and later): no count of a day's or a week's seconds gets
#: there, and a clock since power-on or a simulated clock rarely does
UNIX_FROM_S = 1e9
#: UTC seconds of a day reach at most this [s]: a flight that crosses midnight goes on past 86400 s, and none
#: lasts another day
MAX_SECONDS_OF_DAY = 2 * SECONDS_PER_DAY


@dataclass(frozen=True)
class RunClock:
    """What a run's times [s] are, so that they become GPS seconds of the week: ``scale`` one of
    :data:`georef.frames.gpstime.TIME_SCALES` (``utc-day``: UTC seconds from the midnight ``day_start_posix``
    [POSIX s]; ``utc-posix``: Unix seconds; ``gps-week``: GPS seconds from the start of week ``gps_week``), and
    ``source``, where the date came from (for messages and the summary)."""

    scale: str
    day_start_posix: float = 0.0
    gps_week: int | None = None
    source: str = ""

    def gps_week_times(self, times: np.ndarray) -> tuple[int, np.ndarray]:
        """GPS week of the first time, and GPS seconds of that week [s] (on past 604800 s)."""
        return scale_to_gps_week(times, self.scale, self.day_start_posix, self.gps_week)

    def utc(self, times: np.ndarray | float) -> np.ndarray:
        """UTC [POSIX s] of ``times``."""
        return scale_to_utc(np.atleast_1d(np.asarray(times, dtype=float)), self.scale, self.day_start_posix,
                            self.gps_week)

    def describe(self) -> str:
        """The scale in words (``UTC seconds of 2025-06-14``)."""
        if self.scale == "utc-day":
            return f"UTC seconds of {utc_date(self.day_start_posix).isoformat()}"
        if self.scale == "gps-week":
            return f"GPS seconds of week {self.gps_week}"
        return "Unix seconds (UTC)"


def _as_clock(clock: RunClock | float) -> RunClock:
    """A bare number is the POSIX second of the UTC midnight the times count from (``utc-day``)."""
    return clock if isinstance(clock, RunClock) else RunClock("utc-day", float(clock))


@dataclass
class ImuRows:
    """The raw IMU at the navigation rows: ``gyro`` angular rate [rad/s] and ``accel`` specific force [m/s^2]
    (N, 3), body axes x forward, y right, z down."""

    gyro: np.ndarray
    accel: np.ndarray


@dataclass
class SbetRecords:
    """The records of the two files: ``sbet`` (R, 17) and ``smrmsg`` (R, 10), file order and units; the GPS week
    their times count from (``gps_week``; times past 604800 s belong to the next week); ``left_out``: IMU rows
    without a solution that are not in the files; ``notes`` for the user."""

    sbet: np.ndarray
    smrmsg: np.ndarray
    gps_week: int
    left_out: int
    notes: list[str] = field(default_factory=list)
    #: what the run's times were and where their date came from, in words
    time_basis: str = ""


@dataclass
class SbetExport:
    """What :func:`write_sbet` wrote: the two files and their records."""

    sbet_path: Path
    smrmsg_path: Path
    records: SbetRecords

    @property
    def notes(self) -> list[str]:
        return self.records.notes

    def summary(self) -> dict[str, object]:
        """Figures for the run's summary (units in the keys)."""
        sbet = self.records.sbet
        return {"sbet_path": str(self.sbet_path), "smrmsg_path": str(self.smrmsg_path), "sbet_records": len(sbet),
                "sbet_gps_week": self.records.gps_week, "sbet_rows_left_out": self.records.left_out,
                "sbet_time_basis": self.records.time_basis,
                "sbet_first_time_of_week_s": float(sbet[0, 0]) if len(sbet) else None,
                "sbet_last_time_of_week_s": float(sbet[-1, 0]) if len(sbet) else None}


def smrmsg_path_for(sbet_path: Path | str) -> Path:
    """The RMS file beside an SBET: ``sbet_<name>.out`` -> ``smrmsg_<name>.out`` (POSPac's pair), any other name
    ``<stem>.sbet`` -> ``smrmsg_<stem>.out``."""
    path = Path(sbet_path)
    stem = path.stem
    if stem.lower().startswith("sbet_"):
        stem = stem[len("sbet_"):]
    return path.with_name(f"smrmsg_{stem}.out")


def _rows_at_rate(gps_time: np.ndarray, rate_hz: float | None, imu_rate_hz: float) -> np.ndarray:
    """Indices into ``gps_time`` (increasing) of the rows kept: all, or the first row of every ``1/rate_hz``
    interval of GPS time (so the kept rows line up on whole GPS seconds, as POSPac's exports at a set interval)."""
    if rate_hz is None:
        return np.arange(len(gps_time))
    if not np.isfinite(rate_hz) or rate_hz <= 0:
        raise SbetExportError(f"the SBET rate must be a positive number of Hz, not {rate_hz}")
    if rate_hz > imu_rate_hz * 1.001:
        raise SbetExportError(f"the SBET rate {rate_hz:g} Hz is above the IMU's {imu_rate_hz:.6g} Hz; georef writes "
                              "the IMU rows and does not interpolate between them")
    # a tolerance of a microsecond, so a row logged at 12.9999999 s counts as the tick at 13 s
    tick = np.floor(gps_time * rate_hz + 1e-6 * rate_hz)
    return np.flatnonzero(np.r_[True, np.diff(tick) > 0])


def sbet_records(nav: NavSolution, imu: ImuRows, clock: RunClock | float, rate_hz: float | None = None
                 ) -> SbetRecords:
    """The SBET and smrmsg records of ``nav`` (at every IMU row with a solution, or at ``rate_hz`` [Hz]).

    ``nav.time`` is on ``clock``'s scale (:func:`run_clock`; a number: UTC seconds of the day that starts at that
    POSIX second, georef's time scale, continuous across midnight); UTC becomes GPS time with the leap seconds of
    :mod:`georef.frames.gpstime` at each row's UTC date."""
    clock = _as_clock(clock)
    valid = np.asarray(nav.valid, bool) & np.isfinite(nav.lat) & np.isfinite(nav.yaw)
    notes: list[str] = []
    rows = np.flatnonzero(valid)
    left_out = int(len(valid) - len(rows))
    if not len(rows):
        raise SbetExportError("the navigation solution has no valid row: no SBET to write")
    note = leap_seconds_note(float(clock.utc(float(nav.time[rows[-1]]))[0]))
    if note:
        notes.append(f"SBET times: {note}")
    week, time_of_week = clock.gps_week_times(np.asarray(nav.time, dtype=float)[rows])
    imu_rate = float(1.0 / np.median(np.diff(nav.time))) if len(nav.time) > 1 else float("inf")
    kept = _rows_at_rate(time_of_week, rate_hz, imu_rate)
    rows, time_of_week = rows[kept], time_of_week[kept]
    if time_of_week[-1] >= 604800.0:
        notes.append(f"the flight crosses the end of GPS week {week}: the SBET times go on past 604800 s "
                     f"(up to {time_of_week[-1]:.3f} s) rather than restarting at 0")
    if left_out:
        notes.append(f"{left_out} IMU row(s) without a navigation solution are not in the SBET (it has no flag "
                     "field to mark them)")

    lat, lon, height = nav.lat[rows], nav.lon[rows], nav.height[rows]
    roll, pitch, yaw = nav.roll[rows], nav.pitch[rows], nav.yaw[rows]
    wander = np.zeros(len(rows))
    v_w = ned_to_wander(nav.v_n[rows], wander)
    gyro, accel = np.asarray(imu.gyro, float)[rows], np.asarray(imu.accel, float)[rows]
    info = nav.ins_info
    if info is not None:
        # the mechanisation subtracts the estimated biases from the raw measurements (georef.fusion.ins_kernel)
        gyro = gyro - np.nan_to_num(info.gyro_bias[rows])
        accel = accel - np.nan_to_num(info.accel_bias[rows])
    else:
        notes.append(f"method {nav.method} estimates no sensor biases: the SBET body rates and accelerations are "
                     "the raw IMU's")
    C_b_n = euler_to_dcm(roll, pitch, yaw)
    accel_b = body_acceleration(accel, C_b_n, lat, height)
    sbet = np.column_stack([time_of_week, lat, lon, height, v_w, roll, pitch, platform_heading(yaw, wander), wander,
                            accel_b, gyro])

    pos_sigma = np.sqrt(nav.pos_var_n[rows])
    if info is not None:
        vel_sigma = np.sqrt(info.vel_var_n[rows])
    else:
        vel_sigma = np.full((len(rows), 3), np.nan)
        notes.append(f"method {nav.method} estimates no velocity covariance: the smrmsg velocity RMS are NaN")
    att_arcmin = np.asarray(nav.att_sigma, float)[rows] * ARCMIN_PER_RAD
    smrmsg = np.column_stack([time_of_week, pos_sigma, vel_sigma, att_arcmin])
    basis = clock.describe() + (f", dated by {clock.source}" if clock.source else "")
    return SbetRecords(sbet=sbet, smrmsg=smrmsg, gps_week=week, left_out=left_out, notes=notes, time_basis=basis)


def write_sbet(nav: NavSolution, imu: ImuRows, path: Path | str, clock: RunClock | float,
               rate_hz: float | None = None) -> SbetExport:
    """Write the SBET ``path`` and its smrmsg file (:func:`smrmsg_path_for`) together, all or nothing; ``clock``
    as :func:`sbet_records` takes it."""
    path = Path(path)
    records = sbet_records(nav, imu, clock, rate_hz)
    rms_path = smrmsg_path_for(path)
    with atomic_group():
        for target, values in ((path, records.sbet), (rms_path, records.smrmsg)):
            with atomic_write(target, "wb", encoding=None) as handle:
                handle.write(np.ascontiguousarray(values, dtype=RECORD_TYPE).tobytes())
    return SbetExport(sbet_path=path, smrmsg_path=rms_path, records=records)


def imu_rows_of_log(log: object) -> ImuRows:
    """The raw IMU of a :class:`georef.io.pos.PosLog` in SI units (its ``gyro`` roles are deg/s)."""
    data = getattr(log, "data", {})
    missing = [f"{kind}_{axis}" for kind in ("gyro", "acc") for axis in "xyz" if f"{kind}_{axis}" not in data]
    if missing:
        raise SbetExportError("an SBET holds the body rates and accelerations, and the log has no "
                              f"{', '.join(missing)}")
    return ImuRows(gyro=np.radians(log.vector("gyro")), accel=log.vector("acc"))  # type: ignore[attr-defined]


def parse_utc_date(date_text: str) -> float:
    """POSIX seconds of 00:00 UTC of ``--utc-date`` ``YYYY-MM-DD``; a date before the GPS epoch (1980-01-06), which
    has no GPS week, is refused."""
    import datetime as dt

    try:
        day = dt.date.fromisoformat(date_text)
    except ValueError:
        raise SbetExportError(f"--utc-date {date_text!r}: write the UTC date as YYYY-MM-DD") from None
    if day < GPS_EPOCH.date():
        raise SbetExportError(f"--utc-date {date_text}: before the GPS epoch ({GPS_EPOCH.date().isoformat()}), "
                              "where GPS time has no week; give the flight's UTC date")
    return dt.datetime(day.year, day.month, day.day, tzinfo=dt.UTC).timestamp()


def day_start_of(date_text: str | None, flight_day_start: float | None) -> float:
    """POSIX seconds of 00:00 UTC of the day georef's times count from: the autopilot log's own, or ``date_text``
    (``YYYY-MM-DD``, the UTC date of a POS.txt's or an imu.csv's time of day). Both given and different: error."""
    given = None if date_text is None else parse_utc_date(date_text)
    if flight_day_start is not None:
        if given is not None and abs(given - flight_day_start) > 0.5:
            logged = utc_date(flight_day_start).isoformat()
            raise SbetExportError(f"--utc-date {date_text} disagrees with the log's own date {logged}")
        return float(flight_day_start)
    if given is None:
        raise SbetExportError("an SBET counts GPS seconds of the week, and this log's times are UTC seconds of a day "
                              "it does not name: give --utc-date YYYY-MM-DD")
    return given


def run_clock(imu_time: np.ndarray, date_text: str | None, *, log_day_start: float | None = None,
              solution: ScaleChoice | None = None, solution_name: str = "the .pos", bag: bool = False,
              imu_label: str = "imu.csv") -> RunClock:
    """The scale of a run's times ``imu_time`` [s] and their date, for GPS time; ``date_text`` is ``--utc-date``.

    What decides, first that applies: an autopilot log's own date (``log_day_start`` [POSIX s]); the scale an
    RTKLIB/Emlid solution file ``solution_name`` put the IMU's times on (:mod:`georef.io.pos_time_scale`), whose
    dates name the day or the GPS week; times from :data:`UNIX_FROM_S` on, Unix seconds (a bag's wall clock, an
    imu.csv so logged); else UTC seconds of ``--utc-date`` (POS.txt, imu.csv with gnss.csv, a bag's simulated
    clock), which must then lie within :data:`MAX_SECONDS_OF_DAY`. A ``--utc-date`` the inputs date themselves must
    agree: on UTC seconds of a day it is that day, on Unix seconds or GPS seconds of a week the UTC date of the
    first IMU row. Raises :class:`SbetExportError` with what to do."""
    times = np.asarray(imu_time, dtype=float)
    first, last = float(times[0]), float(times[-1])
    if log_day_start is not None:
        return RunClock("utc-day", day_start_of(date_text, log_day_start), source="the log's own date")
    if solution is not None:
        source = f"the dates of {solution_name}"
        if solution.reader_scale == "utc-day":
            day = utc_day_start(solution.reference_utc)
            if date_text is not None and abs(parse_utc_date(date_text) - day) > 0.5:
                raise SbetExportError(f"--utc-date {date_text} disagrees with {solution_name}: its dates put "
                                      f"{imu_label}'s times on UTC seconds of {utc_date(day).isoformat()}; leave "
                                      "--utc-date out (the .pos dates the flight)")
            return RunClock("utc-day", day, source=source)
        week = gps_week_of(float(utc_to_gps_seconds(solution.reference_utc)))
        clock = RunClock(solution.reader_scale, gps_week=week if solution.reader_scale == "gps-week" else None,
                         source=source)
        _check_date(clock, date_text, first, f"{imu_label}'s times, put on {clock.describe()} by {solution_name},")
        return clock
    if first >= UNIX_FROM_S:
        clock = RunClock("utc-posix", source=f"{imu_label}'s Unix time stamps")
        _check_date(clock, date_text, first, f"{imu_label}'s times ({first:.3f} s on) are Unix seconds and")
        return clock
    span = f"{imu_label}'s times run {first:.3f} - {last:.3f} s"
    scales = ("if they are GPS seconds of the week, give the GNSS as the receiver's RTKLIB/Emlid .pos (--gnss), "
              "whose dates georef takes (docs/sbet.md)" if not bag else
              "a bag's stamps are Unix seconds when they come from a wall clock")
    if date_text is None:
        raise SbetExportError(f"an SBET counts GPS seconds of the week, and {span}, which do not say their date: "
                              f"give --utc-date YYYY-MM-DD if they are UTC seconds of that day; {scales}")
    if first < 0.0 or last >= MAX_SECONDS_OF_DAY:
        raise SbetExportError(f"--utc-date {date_text} takes the times as UTC seconds of that day, and {span}, which "
                              f"are not (0 - {MAX_SECONDS_OF_DAY:.0f} s): {scales}")
    return RunClock("utc-day", parse_utc_date(date_text), source=f"--utc-date {date_text}")


def _check_date(clock: RunClock, date_text: str | None, first: float, what: str) -> None:
    """A ``--utc-date`` given with times that carry their date must be the UTC date of the first time."""
    if date_text is None:
        return
    given = parse_utc_date(date_text)
    start = float(clock.utc(first)[0])
    if abs(given - utc_day_start(start)) > 0.5:
        raise SbetExportError(f"--utc-date {date_text} disagrees with the inputs: {what} start on "
                              f"{utc_date(start).isoformat()} (UTC); leave --utc-date out, the times carry their "
                              "date")
