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
    from georef.io.camera import Exposures
    from georef.io.image_names import ImageNames
    from georef.timing import GnssEpochs

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


@dataclass(frozen=True)
class _Placement:
    """Solution-file times on one scale: ``scale`` (a key of :data:`SCALES`), ``reference_utc`` [POSIX s] a time
    in the day or GPS week they count from, ``times`` [s] on that scale."""

    scale: str
    reference_utc: float
    times: np.ndarray


@dataclass(frozen=True)
class _ScaleRequest:
    """What :func:`choose_time_scale` places: the file ``path``'s UTC times ``utc`` [POSIX s] (``what`` they are,
    in words), the IMU's span ``imu_start`` - ``imu_end`` [s] (``imu_label`` names its source), ``requested``
    (a key of :data:`SCALES` or :data:`AUTO`) and ``asked`` (how it was asked, for the messages)."""

    path: Path | str
    utc: np.ndarray
    what: str
    imu_label: str
    imu_start: float
    imu_end: float
    requested: str
    asked: str

    def placed(self, scale: str, shift: int) -> _Placement:
        """The times on ``scale`` counted from the day (GPS week) ``shift`` periods after the first time's."""
        reference = float(self.utc[0]) + shift * (_PERIOD[scale] or 0.0)
        return _Placement(scale, reference, solution_times(self.utc, SCALES[scale], reference))

    def overlaps(self, times: np.ndarray) -> bool:
        """Whether one of ``times`` [s] lies in the IMU's span."""
        return _overlaps(times, self.imu_start, self.imu_end)

    def imu_span(self) -> str:
        """The IMU's span in words, for the messages."""
        return f"{self.imu_label}'s times span {self.imu_start:.3f} - {self.imu_end:.3f} s"

    def utc_span(self) -> str:
        """The file's times in words (how many, first and last as UTC dates and times), for the messages."""
        return f"{len(self.utc)} {self.what}, {_utc_text(float(self.utc[0]))} - {_utc_text(float(self.utc[-1]))}"


def _overlapping(request: _ScaleRequest) -> list[_Placement]:
    """The placements on the requested scales whose times overlap the IMU's span: counted from the first time's
    day (GPS week), or when none does so, from the day (week) before or after (a unix count has no period)."""
    candidates = list(SCALES) if request.requested == AUTO else [request.requested]
    found: list[_Placement] = []
    for shifts in ((0,), (-1, 1)):  # the file's own day first: a shifted one only when that fits nowhere
        found = [request.placed(scale, shift) for scale in candidates for shift in shifts
                 if _PERIOD[scale] is not None or shift == 0]
        found = [placement for placement in found if request.overlaps(placement.times)]
        if found:
            break
    return found


def _no_overlap_error(request: _ScaleRequest) -> InputError:
    """The error for times that overlap the IMU's span on no requested scale: the file's span on every scale,
    and the other scales on which they would overlap."""
    requested, first = request.requested, float(request.utc[0])
    on_each = ", ".join(f"as {describe_scale(scale, first)} {_span(request.placed(scale, 0).times)}"
                        for scale in SCALES)
    others = [scale for scale in SCALES if scale != requested and any(
        request.overlaps(request.placed(scale, shift).times) for shift in (0, -1, 1))]
    if requested == AUTO:
        advice = ("on none of these scales do they overlap it: the IMU's clock is another (time since power-on, "
                  "a simulated clock) or the files are of different flights")
    elif others:
        advice = (f"they overlap it as {' or '.join(others)}: give --time-scale "
                  f"{' or '.join(others)} if that is the IMU's clock")
    else:
        advice = ("they overlap it on no other scale either: the IMU's clock is another (time since power-on, a "
                  "simulated clock) or the files are of different flights")
    scale_asked = "" if requested == AUTO else f" as {requested} ({request.asked})"
    return InputError(request.path, None, None, f"the {request.what} do not overlap the IMU's time span{scale_asked}: "
                      f"{request.imu_span()}; the file's {request.utc_span()} UTC, are {on_each}; {advice}. The IMU's "
                      "times must be UTC seconds of the day, GPS seconds of the week or Unix seconds (--time-scale "
                      "utc-day, gps-week, unix; docs/rtklib.md)")


def _ambiguous_error(request: _ScaleRequest, found: list[_Placement]) -> InputError:
    """The error for times that overlap the IMU's span on more than one scale (a Sunday's UTC seconds of day and
    GPS seconds of week)."""
    on_each = "; ".join(f"as {describe_scale(placement.scale, placement.reference_utc)} {_span(placement.times)}"
                        for placement in found)
    return InputError(request.path, None, None, f"cannot tell the IMU's time scale: {request.imu_span()}, and the "
                      f"file's {request.utc_span()} UTC, overlap it on {len(found)} scales: {on_each}. On a Sunday UTC "
                      "seconds of the day and GPS seconds of the week differ only by the leap seconds: give "
                      "--time-scale utc-day or gps-week (docs/rtklib.md)")


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
    request = _ScaleRequest(path=path, utc=utc, what=what, imu_label=imu_label, imu_start=float(imu_time[0]),
                            imu_end=float(imu_time[-1]), requested=requested, asked=asked)
    found = _overlapping(request)
    if not found:
        raise _no_overlap_error(request)
    if len(found) > 1:
        raise _ambiguous_error(request, found)
    placement = found[0]
    how = (f"on {imu_label}'s scale ({asked})" if requested != AUTO else
           f"on {imu_label}'s scale, the only one on which they overlap its span ({request.imu_start:.3f} - "
           f"{request.imu_end:.3f} s; --time-scale sets it)")
    notice = InputNotice(path, [], None, f"{what} taken as {describe_scale(placement.scale, placement.reference_utc)} "
                         f"({_span(placement.times)}), {how}")
    return ScaleChoice(scale=placement.scale, reference_utc=placement.reference_utc, times=placement.times,
                       notice=notice)


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
