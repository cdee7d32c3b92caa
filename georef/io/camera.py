"""Readers of exposure times: ``Kamera.txt`` and the camera's raw log (local clock time)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from georef.align import SECONDS_PER_DAY
from georef.io.errors import InputError, InputNotice
from georef.io.table import read_table


@dataclass
class Exposures:
    """Exposure events: frame id as written in the file, time [UTC s of day], file line of each."""

    path: Path
    frame: np.ndarray
    time: np.ndarray
    lines: np.ndarray
    notices: list[InputNotice] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.frame)


def _check_milliseconds(path: Path, ms: np.ndarray, lines: np.ndarray) -> None:
    bad = np.flatnonzero((ms < 0) | (ms > 999) | (ms % 1 != 0))
    if len(bad):
        i = bad[0]
        raise InputError(path, int(lines[i]), "Milliseconds", f"{ms[i]:g} is not a whole number in 0..999")


def _unwrap_midnight(path: Path, seconds: np.ndarray, lines: np.ndarray, notices: list[InputNotice]) -> np.ndarray:
    """Continue times past 86400 s after a drop of more than half a day (a flight across midnight)."""
    drop = np.flatnonzero(np.diff(seconds) < -SECONDS_PER_DAY / 2) + 1
    if len(drop):
        notices.append(InputNotice(path, lines[drop].tolist(), "Time", "midnight roll-over: times continued"))
        days = np.zeros(len(seconds))
        days[drop] = 1
        seconds = seconds + np.cumsum(days) * SECONDS_PER_DAY
    return seconds


def _frame_notices(path: Path, frame: np.ndarray, times: np.ndarray, lines: np.ndarray) -> list[InputNotice]:
    notices = []
    _, first_index, counts = np.unique(frame, return_index=True, return_counts=True)
    if np.any(counts > 1):
        duplicated = np.isin(frame, np.unique(frame)[counts > 1])
        notices.append(InputNotice(path, lines[duplicated].tolist(), "Number",
                                   "frame number used more than once; every row is kept and flagged"))
    back = np.flatnonzero(np.diff(times) < 0) + 1
    if len(back):
        notices.append(InputNotice(path, lines[back].tolist(), "Time",
                                   "exposure time earlier than the previous row; kept and flagged"))
    return notices


def read_kamera(path: Path | str) -> Exposures:
    """``Kamera.txt``: tab separated ``Number  Time  Milliseconds``; time = Time + Milliseconds/1000 [UTC s]."""
    path = Path(path)
    table = read_table(path, {"Number": "str", "Time": "int", "Milliseconds": "int"},
                       required={"Number", "Time", "Milliseconds"})
    ms = table.columns["Milliseconds"]
    _check_milliseconds(path, ms, table.lines)
    seconds = table.columns["Time"]
    notices = list(table.notices)
    seconds = _unwrap_midnight(path, seconds, table.lines, notices)
    frame = np.char.strip(table.columns["Number"])
    times = seconds + ms / 1000.0
    notices += _frame_notices(path, frame, times, table.lines)
    return Exposures(path=path, frame=frame, time=times, lines=table.lines, notices=notices)


def read_camera_log(path: Path | str, utc_offset_hours: float | None) -> Exposures:
    """The camera's raw log; ``Time`` is local clock ``hh:mm:ss`` and ``utc_offset_hours`` is required.

    UTC = local - offset (the seed's summer flights: offset +2 h). Columns beyond the first three
    (exposure, gain, bit depth, shift) are not needed for georeferencing and are ignored.
    """
    path = Path(path)
    if utc_offset_hours is None:
        raise InputError(path, None, "Time", "the camera log holds local clock time; give its UTC offset in "
                         "hours (--camera-utc-offset, e.g. 2 for UTC+2); there is no default")
    table = read_table(path, {"Number": "str", "Time": "str", "Milliseconds": "int"},
                       required={"Number", "Time", "Milliseconds"})
    ms = table.columns["Milliseconds"]
    _check_milliseconds(path, ms, table.lines)
    clock = np.char.strip(table.columns["Time"])
    parts = np.char.partition(clock, ":")
    rest = np.char.partition(parts[:, 2], ":")
    try:
        hh, mm, ss = (parts[:, 0].astype(float), rest[:, 0].astype(float), rest[:, 2].astype(float))
        ok = (hh >= 0) & (hh < 24) & (mm >= 0) & (mm < 60) & (ss >= 0) & (ss < 61) & (parts[:, 1] == ":")
    except ValueError:
        ok = np.array([_is_clock(text) for text in clock])
        hh = mm = ss = np.zeros(len(clock))
    if not np.all(ok):
        i = int(np.argmax(~ok))
        raise InputError(path, int(table.lines[i]), "Time", f"cannot read {clock[i]!r} as hh:mm:ss")
    notices = list(table.notices)
    seconds = hh * 3600 + mm * 60 + ss
    seconds = _unwrap_midnight(path, seconds, table.lines, notices)
    seconds = seconds - utc_offset_hours * 3600.0
    times = seconds + ms / 1000.0
    frame = np.char.strip(table.columns["Number"])
    notices += _frame_notices(path, frame, times, table.lines)
    return Exposures(path=path, frame=frame, time=times, lines=table.lines, notices=notices)


def _is_clock(text: str) -> bool:
    pieces = text.split(":")
    if len(pieces) != 3:
        return False
    try:
        hh, mm, ss = (float(p) for p in pieces)
    except ValueError:
        return False
    return 0 <= hh < 24 and 0 <= mm < 60 and 0 <= ss < 61
