"""``events.csv``: the exposures of any logger, one CSV away from georef.

Columns (header names, any case): ``time`` [s] on the IMU's time scale (``imu.csv``'s, the same clock the GNSS
fixes are tagged on; for an autopilot log, UTC seconds of the day of its first fix), and optionally ``image`` (the
image file's name), ``frame`` (the frame's id; default 1, 2, ... in row order) and ``time_sigma`` [s] (how well
``time`` is the exposure's; default: a trigger command's, :data:`georef.io.camera.TRIGGER_TIME_SIGMA`). Every row
is an exposure; a row whose time is empty is kept and flagged, as Kamera.txt's cut lines are.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from georef.io.camera import FLAG_INCOMPLETE, TRIGGER_TIME_SIGMA, Exposures
from georef.io.errors import InputError, InputNotice
from georef.io.image_names import ImageNames
from georef.io.table import read_table

EVENT_COLUMNS = ("time", "image", "frame")


def read_events(path: Path | str) -> tuple[Exposures, ImageNames | None]:
    """The exposures of ``events.csv`` and, when it names them, their image files; an Emlid/RTKLIB demo5
    ``_events.pos``, recognised by its content, is read by :func:`georef.io.rtklib.read_rtklib_events`."""
    from georef.io.rtklib import is_rtklib_pos, read_rtklib_events

    if is_rtklib_pos(path):
        return read_rtklib_events(path)
    table = read_table(path, {"time": "float", "image": "str", "frame": "str", "time_sigma": "float"},
                       required={"time"}, short_rows="keep")
    c = table.columns
    time = np.asarray(c["time"], dtype=float)
    lines = np.asarray(table.lines)
    frames = (np.array([str(f).strip() for f in c["frame"]], dtype=object) if "frame" in c
              else np.array([str(k + 1) for k in range(len(time))], dtype=object))
    problem = np.where(np.isfinite(time), "", f"{FLAG_INCOMPLETE}: no time")
    notices: list[InputNotice] = list(table.notices)
    if (~np.isfinite(time)).any():
        notices.append(InputNotice(table.path, lines[~np.isfinite(time)].tolist(), table.names.get("time", "time"),
                                   "exposure without a time: kept as a flagged row"))
    known = np.flatnonzero(np.isfinite(time))
    backwards = known[1:][np.diff(time[known]) < 0]
    if len(backwards):
        raise InputError(table.path, int(lines[backwards[0]]), table.names.get("time", "time"),
                         "exposure times go backwards: events.csv lists them in the order they happened")
    seen: dict[str, int] = {}
    for frame, line in zip(frames, lines, strict=True):
        if frame in seen:
            raise InputError(table.path, int(line), table.names.get("frame", "frame"),
                             f"frame {frame!r} is listed twice (first on line {seen[frame]})")
        seen[frame] = int(line)
    timed = np.isfinite(time)
    names = None
    if "image" in c:
        named = {str(f): str(n).strip() for f, n in zip(frames, c["image"], strict=True) if str(n).strip()}
        unnamed = [int(line) for f, line, ok in zip(frames, lines, timed, strict=True) if ok and str(f) not in named]
        if unnamed:
            raise InputError(table.path, unnamed[0], table.names.get("image", "image"), "an exposure without an "
                             "image name: give every row its image, or leave the column out")
        # a row cut short before its image keeps its flag and an empty name
        named.update({str(f): "" for f in frames if str(f) not in named})
        names = ImageNames(table=named, source=str(table.path))
    if "time_sigma" in c:
        time_sigma = np.asarray(c["time_sigma"], dtype=float)
        negative = np.flatnonzero(timed & ~(time_sigma >= 0))
        if len(negative):
            raise InputError(table.path, int(lines[negative[0]]), table.names.get("time_sigma", "time_sigma"),
                             "a time's sigma must be 0 or positive seconds")
        time_sigma = np.where(timed, time_sigma, TRIGGER_TIME_SIGMA)
    else:
        time_sigma = np.full(len(time), TRIGGER_TIME_SIGMA)
        notices.append(InputNotice(table.path, [], None, f"no time_sigma column: the times are taken as trigger "
                                   f"times, the exposures within {TRIGGER_TIME_SIGMA:g} s (1 sigma) of them "
                                   "(camera_time_sigma in flight.toml sets another)"))
    exposures = Exposures(path=table.path, frame=frames, time=time, lines=lines, notices=notices, problem=problem,
                          time_sigma=time_sigma)
    return exposures, names
