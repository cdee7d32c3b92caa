"""An RTKLIB/Emlid ``.pos`` and ``_events.pos`` put on the IMU's time scale (``georef fuse/process --time-scale``).

A solution file's times are absolute (a calendar date and time, or a GPS week and time of week, on GPST, UTC or
JST: :mod:`georef.io.rtklib` turns them into UTC), while ``imu.csv``'s ``time`` is seconds of any epoch and a ROS
bag's stamps are Unix seconds for a wall clock. The scales a .pos can be put on (:data:`SCALES`):

* ``utc-day``: UTC seconds from 00:00 UTC of the first time's day, going on past 86400 s (georef's scale for
  POS.txt, autopilot logs and what ``georef simulate --generic`` writes);
* ``gps-week``: GPS seconds (no leap seconds) from the start of the first time's GPS week, going on past 604800 s;
* ``unix``: UTC seconds since 1970-01-01 (POSIX time, which counts no leap seconds: a ROS wall clock).

``auto`` chooses the scale on which the file's times overlap the IMU's span (:func:`choose_time_scale`): the
file's absolute times make that unambiguous except on a Sunday, when GPS seconds of the week and UTC seconds of
the day differ only by the leap seconds (18 s since 2017), and then it asks. The leap seconds are those of
:mod:`georef.frames.gpstime`.
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from georef.frames.gpstime import (
    SECONDS_PER_DAY,
    SECONDS_PER_WEEK,
    gps_minus_utc,
    gps_week_of,
    solution_times,
    utc_day_start,
    utc_to_gps_seconds,
)
from georef.io.errors import InputError, InputNotice
from georef.io.rtklib import (
    PosSolution,
    check_events_file,
    check_not_headerless,
    is_rtklib_pos,
    read_pos_solution,
    read_rtklib_events,
    read_rtklib_gnss,
)

if TYPE_CHECKING:
    from georef.align import GnssEpochs
    from georef.io.camera import Exposures
    from georef.io.image_names import ImageNames

#: the scales, by their command-line names, and the name :func:`georef.io.rtklib.solution_times` takes
SCALES: dict[str, str] = {"utc-day": "utc-day", "gps-week": "gps-week", "unix": "utc-posix"}
#: choose the scale from the IMU's span
AUTO = "auto"
#: what ``--time-scale`` takes
CHOICES = (AUTO, *SCALES)
#: how long each scale's count runs before it is restarted by the receiver's or logger's clock [s]; a file may
#: start one such period before or after the IMU's (a flight across 00:00 UTC, or the Saturday/Sunday midnight of
#: GPS time, whose first GNSS time lies on the other side of it than the IMU's first row)
_PERIOD = {"utc-day": SECONDS_PER_DAY, "gps-week": SECONDS_PER_WEEK, "unix": None}


@dataclass
class TimeScaleNotice(InputNotice):
    """The notice saying which scale a solution file's times were put on, with the choice as data for the run's
    summary (:func:`time_scale_summaries`): ``what`` (GNSS fixes, camera events), ``scale`` (a key of
    :data:`SCALES`), ``counted_from`` (the day or GPS week in words), ``time_system`` (the file's: GPST, UTC,
    JST), ``gps_minus_utc_s`` (the leap seconds at the file's first time), ``requested`` (``--time-scale``)."""

    what: str = ""
    scale: str = ""
    counted_from: str = ""
    time_system: str = ""
    gps_minus_utc_s: int = 0
    requested: str = AUTO

    def to_dict(self) -> dict[str, object]:
        return {"file": str(self.path), "what": self.what, "scale": self.scale, "counted_from": self.counted_from,
                "time_system": self.time_system, "gps_minus_utc_s": self.gps_minus_utc_s,
                "requested": self.requested}


def time_scale_summaries(notices: list[InputNotice]) -> list[dict[str, object]]:
    """The time-scale choices among ``notices`` (:class:`TimeScaleNotice`), as dicts for a run's summary."""
    return [notice.to_dict() for notice in notices if isinstance(notice, TimeScaleNotice)]


def time_scale_lines(notices: list[InputNotice]) -> list[str]:
    """The time-scale choices among ``notices`` in words, one line each, for a command's normal output."""
    return [f"{notice.path}: {notice.message}" for notice in notices if isinstance(notice, TimeScaleNotice)]


def _leap_text(time_system: str, leap: int) -> str:
    return {"GPST": f"GPST: UTC = GPST - {leap} s, the leap seconds", "UTC": "UTC",
            "JST": "JST: UTC = JST - 9 h"}.get(time_system, time_system)


def _scale_notice(choice: ScaleChoice, solution: PosSolution, what: str, requested: str, first_utc: float
                  ) -> TimeScaleNotice:
    """``choice``'s notice, with the file's time system and leap seconds named (GPST and UTC differ by them: an
    IMU on the other one puts every fix that many seconds along the track)."""
    leap = int(gps_minus_utc(utc_to_gps_seconds(np.array([first_utc])))[0])
    system = solution.header.time_system
    message = f"{choice.notice.message}; the file's times are {_leap_text(system, leap)}"
    if choice.scale != "unix":
        other = "gps-week" if choice.scale == "utc-day" else "utc-day"
        message += (f" (if the IMU's clock is GPS time rather than UTC or the other way round, every time is {leap} s "
                    f"off: --time-scale {other})")
    return TimeScaleNotice(choice.notice.path, choice.notice.lines, system, message, what=what, scale=choice.scale,
                           counted_from=describe_scale(choice.scale, choice.reference_utc), time_system=system,
                           gps_minus_utc_s=leap, requested=scale_name(requested))


@dataclass(frozen=True)
class ScaleChoice:
    """The scale a solution file's times were put on: ``scale`` (a key of :data:`SCALES`), ``reference_utc``
    [POSIX s] a time in the day or GPS week they count from, ``times`` [s] on that scale, and ``notice``
    saying how it was chosen."""

    scale: str
    reference_utc: float
    times: np.ndarray
    notice: InputNotice

    @property
    def reader_scale(self) -> str:
        """The name :mod:`georef.io.rtklib`'s readers take."""
        return SCALES[self.scale]


def scale_name(name: str) -> str:
    """``name`` as a key of :data:`SCALES` or :data:`AUTO` (``utc-posix``, the reader's name, is ``unix``)."""
    name = {"utc-posix": "unix"}.get(name, name)
    if name not in CHOICES:
        raise ValueError(f"time scale must be one of {', '.join(CHOICES)}, got {name!r}")
    return name


def describe_scale(scale: str, reference_utc: float) -> str:
    """What the times of ``scale`` counted from ``reference_utc``'s day or week are, in words."""
    if scale == "utc-day":
        day = dt.datetime.fromtimestamp(utc_day_start(reference_utc), tz=dt.UTC).date()
        return f"UTC seconds of {day.isoformat()}"
    if scale == "gps-week":
        return f"GPS seconds of week {gps_week_of(float(utc_to_gps_seconds(reference_utc)))}"
    return "Unix seconds (UTC since 1970-01-01)"


def _utc_text(posix: float) -> str:
    return dt.datetime.fromtimestamp(posix, tz=dt.UTC).strftime("%Y-%m-%d %H:%M:%S")


def _span(times: np.ndarray) -> str:
    return f"{float(np.min(times)):.3f} - {float(np.max(times)):.3f} s"


def _overlaps(times: np.ndarray, imu_start: float, imu_end: float) -> bool:
    return bool(np.any((times >= imu_start) & (times <= imu_end)))


def choose_time_scale(path: Path | str, utc: np.ndarray, imu_time: np.ndarray, requested: str = AUTO,
                      imu_label: str = "imu.csv", what: str = "times", bag: bool = False) -> ScaleChoice:
    """The scale of :data:`SCALES` on which the UTC times ``utc`` [POSIX s] of the solution file ``path`` overlap
    the IMU's times ``imu_time`` [s] (at least one of them inside the IMU's span): ``requested``, or with
    :data:`AUTO` the only scale that does.

    Each scale counts from the day (GPS week) of the file's first time; when no scale overlaps so, one day (week)
    earlier or later is tried, for a file whose first time lies across 00:00 UTC (the GPS week's start) from the
    IMU's first row. An :class:`InputError` (exit 2) names the IMU's span and the file's on every scale when none
    overlaps, and when two do (a Sunday's UTC seconds of day and GPS seconds of week, 18 s apart) with ``auto``.
    ``imu_label`` names the IMU's source, ``what`` the file's times (fixes, events) in the messages. With ``bag``
    (the IMU is a ROS bag's, stamped in Unix seconds by a wall clock) :data:`AUTO` is ``unix``."""
    requested = scale_name(requested)
    asked = f"--time-scale {requested}"
    if bag and requested == AUTO:
        requested, asked = "unix", "a bag's wall-clock stamps; --time-scale sets another"
    utc = np.asarray(utc, dtype=float)
    imu_time = np.asarray(imu_time, dtype=float)
    if not len(utc):
        raise InputError(path, None, None, f"no {what} to place on the IMU's time scale")
    imu_start, imu_end = float(imu_time[0]), float(imu_time[-1])
    candidates = list(SCALES) if requested == AUTO else [requested]
    first = float(utc[0])

    def times_of(scale: str, shift: int) -> tuple[float, np.ndarray]:
        period = _PERIOD[scale] or 0.0
        reference = first + shift * period
        return reference, solution_times(utc, SCALES[scale], reference)

    found: list[tuple[str, float, np.ndarray]] = []
    for shifts in ((0,), (-1, 1)):  # the file's own day first: a shifted one only when that fits nowhere
        found = [(scale, *times_of(scale, shift)) for scale in candidates for shift in shifts
                 if _PERIOD[scale] is not None or shift == 0]
        found = [(scale, reference, times) for scale, reference, times in found
                 if _overlaps(times, imu_start, imu_end)]
        if found:
            break
    imu_span = f"{imu_label}'s times span {imu_start:.3f} - {imu_end:.3f} s"
    utc_span = f"{len(utc)} {what}, {_utc_text(first)} - {_utc_text(float(utc[-1]))}"
    if not found:
        on_each = ", ".join(f"as {describe_scale(scale, first)} {_span(times_of(scale, 0)[1])}" for scale in SCALES)
        others = [scale for scale in SCALES if scale != requested and any(
            _overlaps(times_of(scale, shift)[1], imu_start, imu_end) for shift in (0, -1, 1))]
        if requested == AUTO:
            advice = ("on none of these scales do they overlap it: the IMU's clock is another (time since power-on, "
                      "a simulated clock) or the files are of different flights")
        elif others:
            advice = (f"they overlap it as {' or '.join(others)}: give --time-scale "
                      f"{' or '.join(others)} if that is the IMU's clock")
        else:
            advice = ("they overlap it on no other scale either: the IMU's clock is another (time since power-on, a "
                      "simulated clock) or the files are of different flights")
        scale_asked = "" if requested == AUTO else f" as {requested} ({asked})"
        raise InputError(path, None, None, f"the {what} do not overlap the IMU's time span{scale_asked}: "
                         f"{imu_span}; the file's {utc_span} UTC, are {on_each}; {advice}. The IMU's times must be "
                         "UTC seconds of the day, GPS seconds of the week or Unix seconds (--time-scale utc-day, "
                         "gps-week, unix; docs/rtklib.md)")
    if len(found) > 1:
        on_each = "; ".join(f"as {describe_scale(scale, reference)} {_span(times)}"
                            for scale, reference, times in found)
        raise InputError(path, None, None, f"cannot tell the IMU's time scale: {imu_span}, and the file's "
                         f"{utc_span} UTC, overlap it on {len(found)} scales: {on_each}. On a Sunday UTC seconds "
                         "of the day and GPS seconds of the week differ only by the leap seconds: give --time-scale "
                         "utc-day or gps-week (docs/rtklib.md)")
    scale, reference, times = found[0]
    how = (f"on {imu_label}'s scale ({asked})" if requested != AUTO else
           f"on {imu_label}'s scale, the only one on which they overlap its span ({imu_start:.3f} - {imu_end:.3f} s; "
           "--time-scale sets it)")
    notice = InputNotice(path, [], None, f"{what} taken as {describe_scale(scale, reference)} ({_span(times)}), "
                         f"{how}")
    return ScaleChoice(scale=scale, reference_utc=reference, times=times, notice=notice)


def read_gnss_on_imu_scale(path: Path | str, imu_time: np.ndarray, requested: str = AUTO,
                           imu_label: str = "imu.csv") -> GnssEpochs:
    """``--gnss``: gnss.csv as it is (on the IMU's clock by definition), or an RTKLIB/Emlid .pos with its fixes on
    the IMU's time scale (:func:`choose_time_scale`), with a notice saying which."""
    from georef.io.generic import read_gnss_csv

    if not is_rtklib_pos(path):
        check_not_headerless(path)
        return read_gnss_csv(path)
    solution = read_pos_solution(path)
    if not len(solution):  # only time marks: read_rtklib_gnss says it is an events file
        return read_rtklib_gnss(path, solution=solution)
    choice = choose_time_scale(path, solution.utc, imu_time, requested, imu_label, "GNSS fixes")
    fixes = read_rtklib_gnss(path, choice.reader_scale, reference_utc=choice.reference_utc, solution=solution)
    fixes.notices.append(_scale_notice(choice, solution, "GNSS fixes", requested, float(solution.utc[0])))
    return fixes


def read_events_on_imu_scale(path: Path | str, imu_time: np.ndarray, requested: str = AUTO,
                             imu_label: str = "imu.csv", bag: bool = False) -> tuple[Exposures, ImageNames | None]:
    """``--events``: events.csv as it is (on the IMU's clock by definition), or an Emlid/RTKLIB demo5
    ``_events.pos`` with its exposure times on the IMU's time scale (:func:`choose_time_scale`; ``bag``: the IMU
    is a ROS bag's, and ``auto`` is ``unix``), with a notice."""
    from georef.io.events import read_events

    if not is_rtklib_pos(path):
        check_not_headerless(path)
        return read_events(path)
    solution = read_pos_solution(path)
    check_events_file(solution)  # before the scale: a solution's span would only say it overlaps
    marks = np.sort(np.concatenate([solution.utc, solution.invalid_mark_utc]))
    choice = choose_time_scale(path, marks, imu_time, requested, imu_label, "camera events", bag)
    exposures, names = read_rtklib_events(path, choice.reader_scale, reference_utc=choice.reference_utc,
                                          solution=solution)
    exposures.notices.append(_scale_notice(choice, solution, "camera events", requested, float(marks[0])))
    return exposures, names


def is_solution_file(path: Path | str | None) -> bool:
    """Whether ``path`` is an RTKLIB/Emlid solution file (what ``--time-scale`` acts on)."""
    return path is not None and is_rtklib_pos(path)
