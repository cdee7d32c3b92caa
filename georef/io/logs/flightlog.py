"""What an autopilot log holds for georeferencing, on one time scale, and its hand-over to the pipeline.

Every reader (:mod:`georef.io.logs.ardupilot`, :mod:`georef.io.logs.px4`) returns a :class:`FlightLog`: times are
UTC seconds of the day of the first GNSS fix (continuing past 86400 s across midnight), as POS.txt's are;
angles in radians, rates in rad/s, specific force in m/s^2, body axes x forward, y right, z down; positions
WGS 84 with ellipsoidal heights. :func:`to_pos_log` and :attr:`FlightLog.exposures` give the pipeline the same
typed inputs a POS.txt and a Kamera.txt give it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from georef.frames.rotations import wrap_pi
from georef.io.camera import Exposures
from georef.io.errors import InputNotice, excerpt
from georef.io.logs.clock import ClockFit
from georef.io.pos import PosLog
from georef.timing import GnssEpochs, TimeRepairReport


@dataclass
class ImuStream:
    """IMU samples: ``time`` [s] (N,), ``gyro`` [rad/s] and ``accel`` [m/s^2] (N, 3) in the body frame;
    ``where`` each sample's position in the log (byte or line), ``name`` the message or topic and instance."""

    name: str
    time: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    where: np.ndarray

    @property
    def rate_hz(self) -> float:
        return float(1.0 / np.median(np.diff(self.time))) if len(self.time) > 1 else float("nan")


@dataclass
class Series:
    """A vector signal of the log: ``time`` [s] (M,), ``values`` (M, 3); ``name`` the message or topic."""

    name: str
    time: np.ndarray
    values: np.ndarray


@dataclass
class GnssReport:
    """How the fixes were chosen: ``fix_types`` counts every logged fix by its type's name, ``kept`` the ones
    used; ``height_source`` says how ellipsoidal heights were made, ``sigma_source`` where the per-fix sigmas
    came from (None: no accuracy logged, the configured sigmas apply)."""

    fix_types: dict[str, int]
    kept: int
    height_source: str
    sigma_source: str | None
    message: str


@dataclass
class LeverArmParameter:
    """The GNSS lever arm [m, body: IMU -> antenna] the autopilot was configured with, and from which
    parameters."""

    lever_arm: tuple[float, float, float]
    source: str


@dataclass
class FlightLog:
    """An autopilot log's contents for georeferencing (see the module docstring for units and frames)."""

    path: Path
    kind: str
    vehicle: str
    day_start_utc: float
    imu: ImuStream
    imu_streams: list[str]
    gnss: GnssEpochs
    gnss_report: GnssReport
    clock: ClockFit
    attitude: Series | None = None
    #: the autopilot's second attitude estimate (ArduPilot's AHR2), to see whether its own estimators agree
    attitude_backup: Series | None = None
    mag: Series | None = None
    events: Exposures | None = None
    lever_arm: LeverArmParameter | None = None
    params: dict[str, float] = field(default_factory=dict)
    notices: list[InputNotice] = field(default_factory=list)
    #: where a message position in this log is counted: "byte" (binary logs) or "line" (text)
    position_unit: str = "byte"


def lever_arm_parameter(params: dict[str, float], antenna: list[str], imu: list[str]) -> LeverArmParameter:
    """The lever arm IMU -> antenna [m, body] from the autopilot's antenna and IMU position parameters (an IMU
    parameter the log lacks counts as 0)."""
    arm = np.array([params[n] for n in antenna]) - np.array([params.get(n, 0.0) for n in imu])
    text = f"{antenna[0][:-1]}X/Y/Z - {imu[0][:-1]}X/Y/Z"
    return LeverArmParameter(tuple(float(v) for v in arm), text)


def in_time_order(time: np.ndarray) -> np.ndarray:
    """Mask of the samples that make ``time`` [s] strictly increase: all of them when it already does; a sample
    logged twice with one time stamp (a logger's repeat) is kept once; else the longest strictly increasing run of
    samples, so that a time stamp that went back, or a lone one far ahead (a damaged log), loses that sample and
    not the ones after it. Non-finite times are left out."""
    time = np.asarray(time, dtype=float)
    finite = np.isfinite(time)
    if finite.all():
        steps = np.diff(time)
        if np.all(steps >= 0):
            return np.concatenate([[True], steps > 0])[:len(time)]
    return _longest_increasing(time, np.flatnonzero(finite))


def _longest_increasing(time: np.ndarray, candidates: np.ndarray) -> np.ndarray:
    """Mask of a longest strictly increasing subsequence of ``time[candidates]`` (patience sorting, O(n log n))."""
    from bisect import bisect_left

    tails: list[float] = []           # the smallest last time of an increasing run of each length
    ends: list[int] = []              # the index (into candidates) where that run ends
    previous = np.full(len(candidates), -1, dtype=np.int64)
    for k, t in enumerate(time[candidates].tolist()):
        j = bisect_left(tails, t)
        if j == len(tails):
            tails.append(t)
            ends.append(k)
        else:
            tails[j], ends[j] = t, k
        previous[k] = ends[j - 1] if j else -1
    keep = np.zeros(len(time), bool)
    k = ends[-1] if ends else -1
    while k >= 0:
        keep[candidates[k]] = True
        k = previous[k]
    return keep


def rows_of(series: Series, time: np.ndarray, angles: bool = False) -> np.ndarray:
    """``series`` interpolated linearly onto ``time`` [s] (N, 3); NaN outside its span (all NaN when the series
    is empty). ``angles``: radians, interpolated on their unwrapped values and wrapped to (-pi, pi]. Samples out
    of time order are left out (:func:`in_time_order`)."""
    keep = in_time_order(series.time)
    if not keep.any():
        return np.full((len(time), 3), np.nan)
    values = np.unwrap(series.values[keep], axis=0) if angles else series.values[keep]
    out = np.stack([np.interp(time, series.time[keep], values[:, k], left=np.nan, right=np.nan)
                    for k in range(3)], -1)
    return wrap_pi(out) if angles else out


def whole_numbers(values: np.ndarray) -> np.ndarray:
    """Whole numbers (int64) of a field: its values rounded towards zero, -1 where a value is not a finite number
    below 2^62 (a damaged format can make an integer field a float one)."""
    values = np.asarray(values, dtype=float)
    good = np.isfinite(values) & (np.abs(values) < 2.0**62)
    return np.where(good, values, -1.0).astype(np.int64)


def numeric_params(items: list[tuple[object, object]], path: Path) -> tuple[dict[str, float], list[InputNotice]]:
    """The parameters (name, value) that are finite numbers, and a notice naming the others (damaged parameter
    messages): they are left out, as if the log did not set them."""
    params: dict[str, float] = {}
    bad: list[str] = []
    for name, value in items:
        if isinstance(value, int | float | np.integer | np.floating) and np.isfinite(value):
            params[str(name)] = float(value)
        else:
            bad.append(str(name))
    if not bad:
        return params, []
    return params, [InputNotice(path, [], None, f"{len(bad)} parameter(s) whose value is no finite number left out "
                                f"(damaged parameter messages): {excerpt(', '.join(bad), 120)}")]


def usable_imu(boot: np.ndarray, gyro: np.ndarray, accel: np.ndarray) -> tuple[np.ndarray, int]:
    """(mask of the IMU samples to use, how many of them were left out for a non-finite value) of samples at boot
    times ``boot`` [s]: finite ones, in time order (:func:`in_time_order`)."""
    finite = np.isfinite(gyro).all(axis=1) & np.isfinite(accel).all(axis=1)
    keep = np.zeros(len(boot), bool)
    keep[finite] = in_time_order(boot[finite])
    return keep, int((~finite).sum())


def imu_notice(path: Path, name: str, keep: np.ndarray, non_finite: int, where: np.ndarray,
               unit: str) -> InputNotice | None:
    """The notice of the IMU samples :func:`usable_imu` left out (None: none); ``where`` each sample's position in
    the log, counted in ``unit`` ("byte", "line", "message")."""
    out = np.flatnonzero(~keep)
    if len(out) == 0:
        return None
    first = f"first at {unit} {int(where[out[0]])}"
    return InputNotice(path, [], name, f"{len(out)} of {len(keep)} samples left out ({non_finite} with a value "
                       f"that is not a finite number, the others repeated or out of time order; {first})")


def to_pos_log(log: FlightLog) -> PosLog:
    """The pipeline's typed input: the IMU rows (``data`` in POS.txt's units: deg/s, m/s^2), the GNSS fixes,
    the magnetometer and the autopilot's own attitude on the IMU rows."""
    imu = log.imu
    gyro_deg = np.degrees(imu.gyro)
    data = {f"gyro_{a}": gyro_deg[:, k] for k, a in enumerate("xyz")}
    data.update({f"acc_{a}": imu.accel[:, k] for k, a in enumerate("xyz")})
    names = {f"gyro_{a}": f"{imu.name}.gyro_{a}" for a in "xyz"}
    names.update({f"acc_{a}": f"{imu.name}.acc_{a}" for a in "xyz"})
    mag = rows_of(log.mag, imu.time) if log.mag is not None else None
    rpy = rows_of(log.attitude, imu.time, angles=True) if log.attitude is not None else None
    return PosLog(path=log.path, time=imu.time, data=data, lines=imu.where, gnss=log.gnss,
                  time_repairs=TimeRepairReport(), notices=list(log.notices), column_names=names,
                  kind=log.kind, mag=mag, autopilot_rpy=rpy)


def describe(log: FlightLog) -> list[tuple[str, str]]:
    """What the log holds, as (what, value) rows for ``georef info``: vehicle, span, IMU streams, GNSS fixes and
    their accuracy, the clock, attitude, magnetometer, camera events, the lever-arm parameters."""
    imu = log.imu
    span = imu.time[-1] - imu.time[0]
    rows = [("format", log.kind), ("vehicle", log.vehicle),
            ("time span", f"{imu.time[0]:.3f} - {imu.time[-1]:.3f} s UTC of day {_utc_date(log)} ({span:.1f} s)"),
            ("IMU", f"{imu.name}: {len(imu.time)} samples at {imu.rate_hz:.1f} Hz (streams: "
                    f"{', '.join(log.imu_streams)})"),
            ("GNSS fixes", log.gnss_report.message),
            ("GNSS rate", f"{1.0 / float(np.median(np.diff(log.gnss.time))):.1f} Hz" if len(log.gnss) > 1 else "-"),
            ("GNSS accuracy", log.gnss_report.sigma_source or "not logged: the configured sigma applies"),
            ("GNSS heights", log.gnss_report.height_source),
            ("clock", log.clock.describe()),
            ("attitude", f"{log.attitude.name}, {len(log.attitude.time)} samples" if log.attitude is not None
             else "not logged"),
            ("magnetometer", f"{log.mag.name}, {len(log.mag.time)} samples" if log.mag is not None
             else "not logged"),
            ("camera events", f"{len(log.events)} exposures" if log.events is not None else "none"),
            ("GNSS lever arm", f"{', '.join(f'{v:.3f}' for v in log.lever_arm.lever_arm)} m ({log.lever_arm.source})"
             if log.lever_arm is not None else "no parameters in the log")]
    return rows


def _utc_date(log: FlightLog) -> str:
    import datetime as dt

    return dt.datetime.fromtimestamp(log.day_start_utc, tz=dt.UTC).date().isoformat()
