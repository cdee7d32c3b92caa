"""Readers of exposure times: ``Kamera.txt`` and the camera's raw log (local clock time).

Columns are found by header name, ignoring case. Each has a *role* (``number``, ``time``, ``milliseconds``);
a user can remap any role in flight.toml (``[camera_columns]``), as for POS.txt.

Every line with a frame id becomes a row: a line cut short (a logger that lost power, a field lost) is kept
with ``time`` NaN and its reason in ``Exposures.problem``, so the EO table gets a flagged row for it.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from georef.io.errors import InputError, InputNotice, excerpt
from georef.io.table import Source, Table, peek_header, read_table, snapshot, source_path
from georef.timing import SECONDS_PER_DAY

#: role -> default header name
CAMERA_ROLES: dict[str, str] = {"number": "Number", "time": "Time", "milliseconds": "Milliseconds"}
#: a header column that marks the camera's raw log (local clock ``hh:mm:ss``) rather than Kamera.txt
RAW_LOG_COLUMN = "Exposition"
#: 1-sigma [s] of an exposure time that is a camera's feedback (hot shoe, capture message), and of one that is the
#: command to trigger: a camera exposes some 0.05-0.3 s after it, unknown unless measured
FEEDBACK_TIME_SIGMA = 0.002
TRIGGER_TIME_SIGMA = 0.1
#: the flag of a frame whose line was cut short (followed by what is missing)
FLAG_INCOMPLETE = "exposure line cut short"


@dataclass
class Exposures:
    """Exposure events: frame id as written in the file, time [UTC s of day], file line of each.

    ``problem`` holds, per row, why it has no usable time ("" when it has one); such rows have ``time`` NaN.
    ``time_sigma`` [s] per row: how well the time is the exposure's (None: exactly).
    """

    path: Path
    frame: np.ndarray
    time: np.ndarray
    lines: np.ndarray
    notices: list[InputNotice] = field(default_factory=list)
    problem: np.ndarray | None = None
    #: per row, the 1-sigma [s] of its time as the exposure's (a trigger command's latency is unknown); None: 0
    time_sigma: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.frame)


def resolve_camera_columns(overrides: Mapping[str, str] | None = None) -> dict[str, str]:
    """Role -> header name, the default names with the user's ``[camera_columns]`` remapping applied."""
    names = dict(CAMERA_ROLES)
    for role, name in (overrides or {}).items():
        if role not in CAMERA_ROLES:
            raise ValueError(f"unknown camera column role {role!r}; known roles: {', '.join(CAMERA_ROLES)}")
        names[role] = name
    return names


def _check_milliseconds(path: Path, ms: np.ndarray, lines: np.ndarray, column: str) -> None:
    with np.errstate(invalid="ignore"):
        bad = np.flatnonzero(np.isfinite(ms) & ((ms < 0) | (ms > 999) | (ms % 1 != 0)))
    if len(bad):
        i = bad[0]
        raise InputError(path, int(lines[i]), column, f"{ms[i]:.10g} is not a whole number in 0..999")


def _unwrap_midnight(path: Path, seconds: np.ndarray, lines: np.ndarray, notices: list[InputNotice],
                     column: str) -> np.ndarray:
    """Continue times past 86400 s after a drop of more than half a day (a flight across midnight)."""
    valid = np.flatnonzero(np.isfinite(seconds))
    drop = valid[1:][np.diff(seconds[valid]) < -SECONDS_PER_DAY / 2]
    if len(drop):
        notices.append(InputNotice(path, lines[drop].tolist(), column, "midnight roll-over: times continued"))
        days = np.zeros(len(seconds))
        days[drop] = 1
        seconds = seconds + np.cumsum(days) * SECONDS_PER_DAY
    return seconds


def repeated_frames(frame: np.ndarray) -> np.ndarray:
    """Per row: whether its frame id is used by another row too. The ids are counted by hashing: sorting them
    (``np.unique``) copies them at the width of the longest one, for every row."""
    ids = frame.tolist()
    counts = Counter(ids)
    return np.fromiter((counts[i] > 1 for i in ids), dtype=bool, count=len(ids))


def _frame_notices(path: Path, frame: np.ndarray, times: np.ndarray, lines: np.ndarray,
                   names: Mapping[str, str]) -> list[InputNotice]:
    notices = []
    duplicated = repeated_frames(frame)
    if duplicated.any():
        notices.append(InputNotice(path, lines[duplicated].tolist(), names["number"],
                                   "frame number used more than once; every row is kept and flagged"))
    back = np.flatnonzero(np.diff(times) < 0) + 1
    if len(back):
        notices.append(InputNotice(path, lines[back].tolist(), names["time"],
                                   "exposure time earlier than the previous row; kept and flagged"))
    return notices


def _incomplete(path: Path, table: Table, names: Mapping[str, str], frame: np.ndarray,
                notices: list[InputNotice]) -> np.ndarray:
    """Per row: why a cut-short line has no time ("" for complete rows); checks each has a frame id."""
    problem = np.full(len(table), "", dtype=object)
    rows = np.flatnonzero(table.incomplete)
    if not len(rows):
        return problem
    order = [names["number"], names["time"], names["milliseconds"]]
    for row in rows.tolist():
        if not frame[row]:
            raise InputError(path, int(table.lines[row]), table.names.get(names["number"], names["number"]),
                             "the line is cut short and has no frame id")
        missing = [table.names.get(name, name) for name in order
                   if table.header.index(table.names.get(name, name)) >= table.fields[row]]
        problem[row] = (f"{FLAG_INCOMPLETE} (line {int(table.lines[row])}: {', '.join(missing)} missing): "
                        "not georeferenced")
    notices.append(InputNotice(path, table.lines[rows].tolist(), None,
                               f"{len(rows)} line(s) cut short (fewer fields than the header): each kept as a "
                               "flagged row without a time"))
    return problem


def read_kamera(source: Source, column_names: Mapping[str, str] | None = None) -> Exposures:
    """``Kamera.txt``: ``Number  Time  Milliseconds``; time = Time + Milliseconds/1000 [UTC s of day].

    ``Time`` must be a whole second of the day (0..86400), ``Milliseconds`` 0..999.
    """
    path = source_path(source)
    names = resolve_camera_columns(column_names)
    table = read_table(source, {names["number"]: "str", names["time"]: "int", names["milliseconds"]: "int"},
                       required=set(names.values()), short_rows="keep")
    spelled = {role: table.names.get(name, name) for role, name in names.items()}
    ms = table.columns[names["milliseconds"]]
    _check_milliseconds(path, ms, table.lines, spelled["milliseconds"])
    seconds = table.columns[names["time"]]
    outside = np.flatnonzero(np.isfinite(seconds) & ((seconds < 0) | (seconds > SECONDS_PER_DAY)))
    if len(outside):
        i = outside[0]
        raise InputError(path, int(table.lines[i]), spelled["time"],
                         f"{seconds[i]:.10g} is not a second of a day (0..86400)")
    notices = list(table.notices)
    frame = np.char.strip(table.columns[names["number"]])
    problem = _incomplete(path, table, names, frame, notices)
    times = seconds + ms / 1000.0
    times[problem != ""] = np.nan
    times = _unwrap_midnight(path, times, table.lines, notices, spelled["time"])
    notices += _frame_notices(path, frame, times, table.lines, spelled)
    return Exposures(path=path, frame=frame, time=times, lines=table.lines, notices=notices, problem=problem)


def read_camera_log(source: Source, utc_offset_hours: float | None,
                    column_names: Mapping[str, str] | None = None) -> Exposures:
    """The camera's raw log; ``Time`` is local clock ``hh:mm:ss`` and ``utc_offset_hours`` is required.

    UTC = local - offset (the summer flights of Bošnjak 2014: offset +2 h). Columns beyond the first three
    (exposure, gain, bit depth, shift) are not needed for georeferencing and are ignored.
    """
    path = source_path(source)
    names = resolve_camera_columns(column_names)
    if utc_offset_hours is None:
        raise InputError(path, None, names["time"], "the camera log holds local clock time; give its UTC offset in "
                         "hours (--camera-utc-offset, e.g. 2 for UTC+2); there is no default")
    table = read_table(source, {names["number"]: "str", names["time"]: "str", names["milliseconds"]: "int"},
                       required=set(names.values()), short_rows="keep")
    spelled = {role: table.names.get(name, name) for role, name in names.items()}
    ms = table.columns[names["milliseconds"]]
    _check_milliseconds(path, ms, table.lines, spelled["milliseconds"])
    notices = list(table.notices)
    frame = np.char.strip(table.columns[names["number"]])
    problem = _incomplete(path, table, names, frame, notices)
    clock = np.char.strip(table.columns[names["time"]])
    seconds = np.full(len(clock), np.nan)
    for i in np.flatnonzero(problem == "").tolist():
        value = _clock_seconds(str(clock[i]))
        if value is None:
            raise InputError(path, int(table.lines[i]), spelled["time"], f"cannot read {excerpt(clock[i])} as hh:mm:ss")
        seconds[i] = value
    seconds = _unwrap_midnight(path, seconds, table.lines, notices, spelled["time"])
    seconds = seconds - utc_offset_hours * 3600.0
    times = seconds + ms / 1000.0
    times[problem != ""] = np.nan
    notices += _frame_notices(path, frame, times, table.lines, spelled)
    return Exposures(path=path, frame=frame, time=times, lines=table.lines, notices=notices, problem=problem)


def _clock_seconds(text: str) -> float | None:
    """``hh:mm:ss`` (ASCII digits, seconds may have a fraction) -> seconds of the day, or None."""
    pieces = text.split(":")
    if len(pieces) != 3 or not all(p and p.isascii() for p in pieces):
        return None
    try:
        hh, mm, ss = int(pieces[0]), int(pieces[1]), float(pieces[2])
    except ValueError:
        return None
    if not (0 <= hh < 24 and 0 <= mm < 60 and 0 <= ss < 61):
        return None
    return hh * 3600 + mm * 60 + ss


def is_camera_log(source: Source) -> bool:
    """Whether ``source`` is the camera's raw log: its header has an ``Exposition`` column (any case)."""
    header = peek_header(source)
    return RAW_LOG_COLUMN.casefold() in {name.casefold() for name in header}


def read_exposures(path: Path | str, utc_offset_hours: float | None = None,
                   column_names: Mapping[str, str] | None = None) -> Exposures:
    """Kamera.txt or the camera's raw log, told apart by the raw log's ``Exposition`` header column.

    The file is read twice (header, then table), so a pipe is first read into memory (:func:`snapshot`).
    """
    source = snapshot(path)
    if is_camera_log(source):
        return read_camera_log(source, utc_offset_hours, column_names)
    return read_kamera(source, column_names)
