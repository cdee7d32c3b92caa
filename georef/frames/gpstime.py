"""GPS time and UTC: the leap seconds between them, explicit.

GPS time runs without leap seconds from its epoch, 1980-01-06 00:00:00 UTC; UTC has had leap seconds inserted
since, so ``UTC = GPS - leap(t)``. Receivers and autopilots log GPS time as a week number and the time of week
(ArduPilot's ``GPS.GWk`` and ``GPS.GMS``); PX4 logs the receiver's UTC (``time_utc_usec``), already corrected.

The table below is IERS Bulletin C's, written out here because neither the standard library nor any of
georef's dependencies carries one (astropy does, a large dependency for eighteen dates). It is valid up to
:data:`LEAP_TABLE_VALID_UNTIL`: no leap second had been announced after 2017-01-01 when it was last checked.
A time after that date is converted with the last entry, and :func:`leap_seconds_note` says so.
"""

from __future__ import annotations

import datetime as dt

import numpy as np

#: the GPS epoch, UTC
GPS_EPOCH = dt.datetime(1980, 1, 6, tzinfo=dt.UTC)
SECONDS_PER_WEEK = 604800.0
SECONDS_PER_DAY = 86400.0

#: (UTC date from which it holds, GPS - UTC [s]), IERS Bulletin C
LEAP_SECONDS: tuple[tuple[dt.date, int], ...] = (
    (dt.date(1981, 7, 1), 1), (dt.date(1982, 7, 1), 2), (dt.date(1983, 7, 1), 3), (dt.date(1985, 7, 1), 4),
    (dt.date(1988, 1, 1), 5), (dt.date(1990, 1, 1), 6), (dt.date(1991, 1, 1), 7), (dt.date(1992, 7, 1), 8),
    (dt.date(1993, 7, 1), 9), (dt.date(1994, 7, 1), 10), (dt.date(1996, 1, 1), 11), (dt.date(1997, 7, 1), 12),
    (dt.date(1999, 1, 1), 13), (dt.date(2006, 1, 1), 14), (dt.date(2009, 1, 1), 15), (dt.date(2012, 7, 1), 16),
    (dt.date(2015, 7, 1), 17), (dt.date(2017, 1, 1), 18),
)
#: the last day the table is known to hold for (IERS Bulletin C announces leap seconds six months ahead)
LEAP_TABLE_VALID_UNTIL = dt.date(2026, 6, 30)


def _gps_seconds_of(date: dt.date) -> float:
    """GPS seconds since the GPS epoch at 00:00 UTC of ``date``, before that day's leap count is applied."""
    return (dt.datetime(date.year, date.month, date.day, tzinfo=dt.UTC) - GPS_EPOCH).total_seconds()


#: GPS seconds at which each entry takes effect (the UTC midnight expressed on the GPS scale)
_STEPS_GPS = np.array([_gps_seconds_of(day) + leap for day, leap in LEAP_SECONDS])
_LEAPS = np.array([leap for _, leap in LEAP_SECONDS], dtype=float)


def gps_minus_utc(gps_seconds: np.ndarray | float) -> np.ndarray:
    """GPS - UTC [s] at GPS times given as seconds since the GPS epoch."""
    index = np.searchsorted(_STEPS_GPS, np.asarray(gps_seconds, dtype=float), side="right") - 1
    return np.where(index >= 0, _LEAPS[np.maximum(index, 0)], 0.0)


def gps_week_to_utc(week: np.ndarray, seconds_of_week: np.ndarray) -> np.ndarray:
    """UTC [s since 1970-01-01, POSIX] of GPS week numbers (full, not modulo 1024) and times of week [s]."""
    gps = np.asarray(week, dtype=float) * SECONDS_PER_WEEK + np.asarray(seconds_of_week, dtype=float)
    return gps - gps_minus_utc(gps) + GPS_EPOCH.timestamp()


def utc_day_start(posix_seconds: float) -> float:
    """POSIX seconds [s] of 00:00 UTC of the day holding ``posix_seconds``."""
    return float(np.floor(posix_seconds / SECONDS_PER_DAY) * SECONDS_PER_DAY)


def utc_date(posix_seconds: float) -> dt.date:
    """The UTC calendar date of POSIX seconds."""
    return dt.datetime.fromtimestamp(posix_seconds, tz=dt.UTC).date()


def leap_seconds_note(posix_seconds: float) -> str | None:
    """A sentence when a UTC time lies after :data:`LEAP_TABLE_VALID_UNTIL` (a leap second announced later would
    make UTC one second off), else None."""
    day = utc_date(posix_seconds)
    if day <= LEAP_TABLE_VALID_UNTIL:
        return None
    return (f"the log is from {day.isoformat()}, after the leap-second table's last check "
            f"({LEAP_TABLE_VALID_UNTIL.isoformat()}); GPS - UTC taken as {int(_LEAPS[-1])} s")


#: UTC midnights of the table's dates on the UTC scale [s since the GPS epoch, leap seconds not counted]
_STEPS_UTC = np.array([_gps_seconds_of(day) for day, _ in LEAP_SECONDS])


def gps_minus_utc_at_utc(posix_seconds: np.ndarray | float) -> np.ndarray:
    """GPS - UTC [s] at UTC times given as POSIX seconds (the table looked up by the UTC date)."""
    utc_scale = np.asarray(posix_seconds, dtype=float) - GPS_EPOCH.timestamp()
    index = np.searchsorted(_STEPS_UTC, utc_scale, side="right") - 1
    return np.where(index >= 0, _LEAPS[np.maximum(index, 0)], 0.0)


def utc_to_gps_seconds(posix_seconds: np.ndarray | float) -> np.ndarray:
    """GPS seconds since the GPS epoch [s] of UTC times given as POSIX seconds: ``GPS = UTC + leap(UTC)``."""
    posix = np.asarray(posix_seconds, dtype=float)
    return posix - GPS_EPOCH.timestamp() + gps_minus_utc_at_utc(posix)


def gps_week_of(gps_seconds: float) -> int:
    """The full GPS week number (not modulo 1024) holding ``gps_seconds`` [s since the GPS epoch]."""
    return int(np.floor(gps_seconds / SECONDS_PER_WEEK))


def utc_of_day_to_gps_week(day_start_posix: float, utc_of_day: np.ndarray) -> tuple[int, np.ndarray]:
    """GPS week and seconds of that week [s] of UTC times given as seconds ``utc_of_day`` since the UTC midnight
    ``day_start_posix`` [POSIX s] (georef's time scale, continuous across midnight).

    The week is that of the first time, and later times count on from it: a flight that crosses the Saturday/Sunday
    midnight of GPS time goes on past 604800 s instead of jumping back to 0, so the times stay increasing (what
    SBET consumers sort and interpolate by). The whole seconds are added apart from the time of day, so the result
    keeps the time of day's resolution (a POSIX time in float64 holds only 0.2 us)."""
    t = np.asarray(utc_of_day, dtype=float)
    leap = gps_minus_utc_at_utc(day_start_posix + t)
    day_gps = float(round(day_start_posix - GPS_EPOCH.timestamp()))  # whole seconds: the day starts at 00:00:00
    week = gps_week_of(day_gps + float(t[0]) + float(leap[0]))
    return week, (day_gps - week * SECONDS_PER_WEEK) + leap + t


#: Japan Standard Time, one of RTKLIB's output time systems (``out-timesys=jst``): UTC + 9 h, no daylight saving
JST_MINUS_UTC = 9 * 3600.0


#: the time scales a solution with absolute times can be put on: UTC seconds of a day, GPS seconds of a week,
#: UTC seconds since 1970 (POSIX)
TIME_SCALES = ("utc-day", "gps-week", "utc-posix")


def solution_times(utc: np.ndarray, scale: str = "utc-day", reference_utc: float | None = None) -> np.ndarray:
    """UTC times [POSIX s] on a scale of :data:`TIME_SCALES`, counted from the day (or GPS week) of
    ``reference_utc`` (default: the first time)."""
    if scale not in TIME_SCALES:
        raise ValueError(f"time scale must be one of {', '.join(TIME_SCALES)}, got {scale!r}")
    utc = np.asarray(utc, dtype=float)
    reference = float(utc[0]) if reference_utc is None else float(reference_utc)
    if scale == "utc-posix":
        return utc.copy()
    if scale == "utc-day":
        return utc - utc_day_start(reference)
    gps = utc_to_gps_seconds(utc)
    week = np.floor(float(utc_to_gps_seconds(reference)) / SECONDS_PER_WEEK)
    return gps - week * SECONDS_PER_WEEK


def scale_to_gps_week(times: np.ndarray, scale: str, day_start_posix: float = 0.0,
                      gps_week: int | None = None) -> tuple[int, np.ndarray]:
    """GPS week and seconds of that week [s] of times [s] on a scale of :data:`TIME_SCALES`: ``utc-day`` UTC
    seconds from the UTC midnight ``day_start_posix`` [POSIX s], ``utc-posix`` Unix seconds (UTC), ``gps-week``
    GPS seconds from the start of GPS week ``gps_week`` (no leap seconds: only the week is carried).

    As :func:`utc_of_day_to_gps_week`: the week is that of the first time and later times count on past
    604800 s. Unix times are split at the first time's UTC midnight so that the seconds of day keep their
    resolution."""
    t = np.asarray(times, dtype=float)
    if scale == "utc-day":
        return utc_of_day_to_gps_week(day_start_posix, t)
    if scale == "utc-posix":
        midnight = utc_day_start(float(t[0]))
        return utc_of_day_to_gps_week(midnight, t - midnight)
    if scale != "gps-week" or gps_week is None:
        raise ValueError(f"time scale must be one of {', '.join(TIME_SCALES)} (gps-week with its week), got {scale!r}")
    carried = int(np.floor(float(t[0]) / SECONDS_PER_WEEK))  # a first time past the week's end: the next week's
    return gps_week + carried, t - carried * SECONDS_PER_WEEK


def scale_to_utc(times: np.ndarray, scale: str, day_start_posix: float = 0.0,
                 gps_week: int | None = None) -> np.ndarray:
    """UTC [POSIX s] of times [s] on a scale of :data:`TIME_SCALES` (the arguments of :func:`scale_to_gps_week`)."""
    t = np.asarray(times, dtype=float)
    if scale == "utc-day":
        return day_start_posix + t
    if scale == "utc-posix":
        return t.copy()
    if scale != "gps-week" or gps_week is None:
        raise ValueError(f"time scale must be one of {', '.join(TIME_SCALES)} (gps-week with its week), got {scale!r}")
    return gps_week_to_utc(np.full(t.shape, gps_week), t)
