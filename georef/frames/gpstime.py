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
