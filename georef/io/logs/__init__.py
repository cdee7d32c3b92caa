"""Autopilot logs in: the format told from the content, gzip read through, one typed result.

>>> from georef.io.logs import read_flight_log
>>> log = read_flight_log("flight.ulg")       # or .bin / .log (ArduPilot), each also gzipped
>>> log.imu, log.gnss, log.events, log.lever_arm, log.clock.describe()

:func:`log_kind` tells a PX4 ULog (its magic), an ArduPilot DataFlash log, binary (the FMT message of FMT) or
text (a ``FMT, 128, 89, FMT`` line), from anything else (None: a text table such as POS.txt), whatever the file's
name. :class:`~georef.io.logs.flightlog.FlightLog` is what every reader returns.
"""

from __future__ import annotations

from pathlib import Path

from georef.io.logs.dataflash import is_binary_dataflash, is_text_dataflash
from georef.io.logs.flightlog import FlightLog

#: the first bytes of a ULog file: "ULog" and the file magic
ULOG_MAGIC = b"ULog\x01\x12\x35"
#: how much of a file's start the format is told from [bytes]
SNIFF_BYTES = 4096


def log_kind(head: bytes) -> str | None:
    """``"ulog"``, ``"dataflash"`` or None (not an autopilot log) from a file's first bytes (decompressed)."""
    if head.startswith(ULOG_MAGIC):
        return "ulog"
    if is_binary_dataflash(head) or is_text_dataflash(head):
        return "dataflash"
    return None


def sniff(path: Path | str) -> str | None:
    """:func:`log_kind` of a file (gzip read through); None also for a file that cannot be read (the table reader
    then says why) and for a named pipe, which can be read only once: a pipe is taken for a text table (POS.txt);
    an autopilot log is given as a file (gzipped or not)."""
    import os
    import stat

    from georef.io.errors import InputError
    from georef.io.table import _open_source

    try:
        if stat.S_ISFIFO(os.stat(path).st_mode):
            return None
    except OSError:
        return None
    try:
        with _open_source(Path(path)) as handle:
            return log_kind(handle.read(SNIFF_BYTES))
    except InputError:
        return None


def read_flight_log(path: Path | str, imu_instance: int | None = None) -> FlightLog:
    """An ArduPilot or PX4 log, whichever the content is. ``imu_instance``: the IMU stream to use (default the
    primary: ArduPilot's IMU 0, PX4's sensor_combined; an integer picks ArduPilot's IMU instance or PX4's
    vehicle_imu instance)."""
    from georef.io.errors import InputError
    from georef.io.table import read_bytes

    path = Path(path)
    data = read_bytes(path)
    kind = log_kind(data[:SNIFF_BYTES])
    if kind == "ulog":
        from georef.io.logs.px4 import read_px4

        return read_px4(path, data, imu_instance)
    if kind == "dataflash":
        from georef.io.logs.ardupilot import read_ardupilot

        return read_ardupilot(path, data, imu_instance)
    raise InputError(path, None, None, "not an autopilot log: neither a PX4 ULog (its magic at byte 0) nor an "
                     f"ArduPilot DataFlash log (binary or text: a FMT message in the first {SNIFF_BYTES} bytes)")
