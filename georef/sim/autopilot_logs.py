"""Simulated flights written as real autopilot logs: ArduPilot DataFlash (``.bin``, ``.log``) and PX4 ULog (``.ulg``).

A drone flight of the simulator (``SimConfig.for_vehicle("drone", ...)``) becomes the log its flight controller
would have left, with the truth known: every message stamped on the controller's boot clock (:class:`BootClock`:
an offset, a rate that need not be 1, an extra arrival jitter of the fix messages), the fixes with their GPS
time (on ``date``) and mean-sea-level heights, the installation's lever arm in the parameters. georef's readers
(:mod:`georef.io.logs.ardupilot`, :mod:`georef.io.logs.px4`) and ``georef process flight.bin`` can so be tested
end to end.

>>> flight = simulate(SimConfig.for_vehicle("drone", seed=3, start="hover"))
>>> write_dataflash(flight, "flight.bin")                                 # ArduCopter 4.5, binary
>>> write_dataflash(flight, "flight.log", text=True, generation="3.x",
...                 boot_clock=BootClock(rate=12 / 13))                   # ArduCopter 3.2, text, a slow clock
>>> write_ulog(flight, "flight.ulg", generation="old")                    # PX4 v1.10

What each generation holds is in :mod:`georef.sim.ardupilot_log` and :mod:`georef.sim.px4_log`; the samples and
the clock in :mod:`georef.sim.log_samples`; the DataFlash encoding in :mod:`georef.sim.dataflash_writer`.
Files are written atomically (:func:`georef.io.atomic.atomic_write`).
"""

from __future__ import annotations

import datetime as dt
from pathlib import Path

from pyulog import ULog

from georef.io.atomic import atomic_write
from georef.sim.ardupilot_log import ardupilot_blocks
from georef.sim.dataflash_writer import MessageBlock, encode_binary, encode_text
from georef.sim.flight import SimulatedFlight
from georef.sim.log_samples import DEFAULT_DATE, BootClock, logged_flight
from georef.sim.px4_log import build_ulog

__all__ = ["BootClock", "DEFAULT_DATE", "write_dataflash", "write_ulog"]


def write_dataflash(flight: SimulatedFlight, path: Path | str, text: bool = False, generation: str = "4.x",
                    boot_clock: BootClock | None = None, date: dt.date = DEFAULT_DATE, second_imu: bool = False,
                    capture_delay_s: float = 0.004, fix_status: int = 3) -> list[MessageBlock]:
    """Write ``flight`` as an ArduCopter DataFlash log at ``path``: binary, or the text form with ``text``.

    ``generation``: ``"4.x"`` (ArduCopter 4.5) or ``"3.x"`` (3.2); ``boot_clock``: the controller's clock
    (default :class:`BootClock`'s); ``date``: the UTC date of the flight's seconds of day; ``second_imu``: a second
    IMU instance with independent noise; ``capture_delay_s`` [s]: the camera feedback CAM after its trigger TRIG
    (4.x); ``fix_status``: the GPS status of every fix (3 3D, 6 RTK fixed). Returns the messages written (FMT
    first), as stored.
    """
    logged = logged_flight(flight, boot_clock or BootClock(), capture_delay_s, second_imu)
    blocks = ardupilot_blocks(logged, generation, date, fix_status)
    if text:
        with atomic_write(path, "w", encoding="ascii") as handle:
            handle.write(encode_text(blocks))
    else:
        with atomic_write(path, "wb") as handle:
            handle.write(encode_binary(blocks))
    return blocks


def write_ulog(flight: SimulatedFlight, path: Path | str, generation: str = "new",
               boot_clock: BootClock | None = None, date: dt.date = DEFAULT_DATE, capture_delay_s: float = 0.004,
               fix_type: int = 3) -> ULog:
    """Write ``flight`` as a PX4 ULog at ``path``; ``generation`` ``"new"`` (v1.14) or ``"old"`` (v1.10), the
    other arguments as for :func:`write_dataflash`. Returns the ULog written."""
    ulog = build_ulog(logged_flight(flight, boot_clock or BootClock(), capture_delay_s), generation, date, fix_type)
    with atomic_write(path, "wb") as handle:
        ulog.write_ulog(handle)
    return ulog
