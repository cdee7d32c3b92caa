"""A simulated flight as its flight controller logs it: the boot clock, GPS time and the samples of every log.

A flight controller stamps each message with the time since it booted, on its own clock; the GNSS receiver tells
the time of each fix as GPS week and time of week (ArduPilot) or UTC (PX4). :class:`BootClock` maps the
simulator's UTC seconds of day onto that boot clock (an offset, a rate that need not be 1, and an extra arrival
jitter of the fix messages); :func:`gps_time` turns UTC seconds of day on a calendar date into GPS week and
milliseconds of week with the leap seconds of :mod:`georef.frames.gpstime`. :func:`logged_flight` gathers what
the log writers (:mod:`georef.sim.ardupilot_log`, :mod:`georef.sim.px4_log`) write: IMU rows, fixes with their
mean-sea-level heights, attitude and magnetometer series, camera events, the GNSS lever arm and lag.
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass

import numpy as np

from georef.frames import dcm_to_euler
from georef.frames.gpstime import GPS_EPOCH, SECONDS_PER_WEEK, gps_minus_utc
from georef.frames.rotations import attitude_at
from georef.imu_errors import imu_preset
from georef.io.logs.gnss_heights import egm96_undulation
from georef.sim.flight import SimulatedFlight

#: the calendar date the simulated UTC seconds of day are put on
DEFAULT_DATE = dt.date(2025, 6, 14)
#: rate of the attitude and magnetometer messages [Hz] (ArduPilot's ATT and MAG at their default 10 Hz)
SERIES_RATE_HZ = 10.0
#: random sub-stream of the second IMU's noise and the fix messages' extra jitter (the simulator uses 101-105)
SECOND_IMU_STREAM, FIX_JITTER_STREAM = 106, 107
_MS_PER_WEEK = int(SECONDS_PER_WEEK * 1000)


@dataclass(frozen=True)
class BootClock:
    """The flight controller's clock: ``boot = (utc - utc_at_boot) * rate`` [s], with ``utc_at_boot`` such that
    the flight's first IMU row is at ``start_offset_s`` after boot.

    ``rate`` is boot seconds per real second (1 + the crystal's error, e.g. 1 + 30e-6; one Linux flight controller
    of 2014 ran at 12/13). ``fix_jitter_s``: each GNSS message's arrival stamp gets a further uniform jitter within
    +-``fix_jitter_s`` [s] (the serial link and the scheduler; the receiver's own latency jitter is the
    simulator's), drawn with ``seed``.
    """

    start_offset_s: float = 20.0
    rate: float = 1.0
    fix_jitter_s: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        if self.start_offset_s < 1.0 or not 0.5 < self.rate < 2.0 or self.fix_jitter_s < 0.0:
            raise ValueError(f"BootClock: start_offset_s must be >= 1 s (the header messages are logged before the "
                             f"first IMU row), rate within (0.5, 2) and fix_jitter_s >= 0; got {self}")

    def boot(self, utc: np.ndarray | float, first_row_utc: float) -> np.ndarray:
        """Boot time [s] of UTC seconds of day ``utc`` for a flight whose first IMU row is at ``first_row_utc``."""
        return self.start_offset_s + (np.asarray(utc, dtype=float) - first_row_utc) * self.rate


@dataclass(frozen=True)
class GpsTime:
    """GPS week numbers (full, not modulo 1024) and milliseconds of week, rounded to the millisecond."""

    week: np.ndarray
    ms_of_week: np.ndarray


def posix_seconds(utc_of_day: np.ndarray | float, date: dt.date) -> np.ndarray:
    """POSIX seconds [s] of UTC seconds of day on ``date``."""
    midnight = dt.datetime(date.year, date.month, date.day, tzinfo=dt.UTC).timestamp()
    return midnight + np.asarray(utc_of_day, dtype=float)


def gps_time(utc_of_day: np.ndarray | float, date: dt.date) -> GpsTime:
    """GPS week and ms of week of UTC seconds of day on ``date`` (GPS = UTC + the leap seconds then)."""
    utc_scale = posix_seconds(utc_of_day, date) - GPS_EPOCH.timestamp()
    gps = utc_scale + gps_minus_utc(utc_scale + gps_minus_utc(utc_scale))
    total_ms = np.round(gps * 1000.0).astype(np.int64)
    return GpsTime(week=total_ms // _MS_PER_WEEK, ms_of_week=total_ms % _MS_PER_WEEK)


@dataclass
class ImuSamples:
    """IMU rows: UTC [s of day] and boot time [s], ``gyro`` [rad/s], ``accel`` [m/s^2] (N, 3) body FRD,
    ``temperature`` [degC]."""

    utc: np.ndarray
    boot: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    temperature: np.ndarray


@dataclass
class FixSamples:
    """GNSS fixes: ``utc`` the fix's own time [s of day], ``sample_boot`` [s] the same on the boot clock and
    ``arrival_boot`` [s] when its message arrived; ``lat``, ``lon``
    [deg], ``height`` (ellipsoidal), ``msl`` (above EGM96) and ``undulation`` (EGM96 N = height - msl) [m],
    ``sigma_h``, ``sigma_v`` [m] the receiver's reported accuracy, ``v_n`` [m/s] (K, 3) NED."""

    utc: np.ndarray
    sample_boot: np.ndarray
    arrival_boot: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    height: np.ndarray
    msl: np.ndarray
    undulation: np.ndarray
    sigma_h: np.ndarray
    sigma_v: np.ndarray
    v_n: np.ndarray


@dataclass
class Series:
    """A body-frame or attitude series at :data:`SERIES_RATE_HZ`: ``boot`` [s], ``values`` (M, 3)."""

    boot: np.ndarray
    values: np.ndarray


@dataclass
class EventMoment:
    """The moments of camera events: UTC [s of day], boot time [s], the vehicle's ``lat``, ``lon`` [deg],
    ``height`` (ellipsoidal) and ``msl`` [m] and attitude ``rpy`` [rad] (K, 3) then."""

    utc: np.ndarray
    boot: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    height: np.ndarray
    msl: np.ndarray
    rpy: np.ndarray


@dataclass
class EventSamples:
    """Camera events numbered ``number`` (1, 2, ...): the ``trigger`` and the camera's ``capture`` feedback."""

    number: np.ndarray
    trigger: EventMoment
    capture: EventMoment


@dataclass
class LoggedFlight:
    """Everything a log writer writes, on the boot clock. ``header_boot`` [s]: when the parameters and version
    messages are logged; ``lever_arm_gnss`` [m, body]; ``gnss_lag_boot_s``: the receiver's mean lag measured on
    the boot clock (what a well-set GPS_DELAY_MS / EKF2_GPS_DELAY states); ``attitude`` rpy [rad] (the
    autopilot's when the flight has it, else the truth); ``mag`` [uT] or None; ``imu2`` a second IMU instance
    or None; ``start_height`` [m] the vehicle's first ellipsoidal height (home)."""

    imu: ImuSamples
    imu2: ImuSamples | None
    fixes: FixSamples
    attitude: Series
    mag: Series | None
    events: EventSamples
    header_boot: float
    lever_arm_gnss: tuple[float, float, float]
    gnss_lag_boot_s: float
    start_height: float


def _imu(flight: SimulatedFlight, clock: BootClock) -> ImuSamples:
    pos = flight.pos
    utc = flight.truth_nav.time
    temperature = flight.imu_temperature_degc if flight.imu_temperature_degc is not None else np.full(len(utc), 25.0)
    return ImuSamples(utc=utc, boot=clock.boot(utc, utc[0]),
                      gyro=np.radians(pos[["OMGS_X", "OMGS_Y", "OMGS_Z"]].to_numpy(float)),
                      accel=pos[["ACCS_X", "ACCS_Y", "ACCS_Z"]].to_numpy(float), temperature=temperature)


def _second_imu(flight: SimulatedFlight, first: ImuSamples) -> ImuSamples:
    """The first IMU plus independent white noise of the flight's IMU preset (angle and velocity random walk)."""
    model = imu_preset(flight.config.imu_preset)
    rate = 1.0 / float(np.median(np.diff(first.utc)))
    gyro_sigma = np.radians(model.gyro_arw_deg_rt_h / 60.0) * np.sqrt(rate)
    accel_sigma = model.accel_vrw_mps_rt_h / 60.0 * np.sqrt(rate)
    rng = np.random.default_rng((flight.config.seed, SECOND_IMU_STREAM))
    n = len(first.utc)
    return ImuSamples(utc=first.utc, boot=first.boot, gyro=first.gyro + gyro_sigma * rng.standard_normal((n, 3)),
                      accel=first.accel + accel_sigma * rng.standard_normal((n, 3)),
                      temperature=first.temperature)


def _fixes(flight: SimulatedFlight, clock: BootClock, first_row_utc: float) -> FixSamples:
    fixes = flight.gnss_fixes
    nav = flight.truth_nav
    lat, lon, height = (fixes[c].to_numpy(float) for c in ("lat", "lon", "height"))
    undulation = egm96_undulation(lat, lon)
    fix_utc = fixes["measured_time"].to_numpy(float)
    jitter = np.random.default_rng((clock.seed, FIX_JITTER_STREAM)).uniform(-1.0, 1.0, len(fixes)) * clock.fix_jitter_s
    v_n = np.stack([np.interp(fix_utc, nav.time, nav.v_n[:, k]) for k in range(3)], -1)
    sigma_h = np.sqrt(0.5 * (fixes["sigma_n"].to_numpy(float) ** 2 + fixes["sigma_e"].to_numpy(float) ** 2))
    arrival = clock.boot(fixes["time"].to_numpy(float), first_row_utc) + jitter
    return FixSamples(utc=fix_utc, sample_boot=clock.boot(fix_utc, first_row_utc), arrival_boot=arrival,
                      lat=lat, lon=lon, height=height, msl=height - undulation, undulation=undulation,
                      sigma_h=sigma_h, sigma_v=fixes["sigma_u"].to_numpy(float), v_n=v_n)


def _series_rows(utc: np.ndarray) -> np.ndarray:
    step = max(1, int(round(1.0 / (SERIES_RATE_HZ * float(np.median(np.diff(utc)))))))
    return np.arange(0, len(utc), step)


def _moment(flight: SimulatedFlight, clock: BootClock, utc: np.ndarray, first_row_utc: float) -> EventMoment:
    nav = flight.truth_nav
    lat = np.degrees(np.interp(utc, nav.time, nav.lat))
    lon = np.degrees(np.interp(utc, nav.time, nav.lon))
    height = np.interp(utc, nav.time, nav.height)
    if len(utc) == 0:
        return EventMoment(utc, clock.boot(utc, first_row_utc), lat, lon, height, height, np.empty((0, 3)))
    rpy = np.stack(dcm_to_euler(attitude_at(nav.time, nav.roll, nav.pitch, nav.yaw, utc)), -1)
    return EventMoment(utc=utc, boot=clock.boot(utc, first_row_utc), lat=lat, lon=lon, height=height,
                       msl=height - egm96_undulation(lat, lon), rpy=rpy)


def _events(flight: SimulatedFlight, clock: BootClock, delay_s: float, first_row_utc: float) -> EventSamples:
    trigger = flight.exposures["time"].to_numpy(float)
    return EventSamples(number=flight.exposures["frame"].to_numpy(np.int64),
                        trigger=_moment(flight, clock, trigger, first_row_utc),
                        capture=_moment(flight, clock, trigger + delay_s, first_row_utc))


def logged_flight(flight: SimulatedFlight, clock: BootClock, capture_delay_s: float = 0.004,
                  second_imu: bool = False) -> LoggedFlight:
    """The samples of ``flight`` on ``clock``; camera captures ``capture_delay_s`` [s] after their trigger;
    ``second_imu`` adds a second IMU instance with independent noise."""
    if flight.config.vehicle != "drone":
        raise ValueError("autopilot logs are written for drone flights (SimConfig.for_vehicle('drone', ...)): "
                         f"this flight is a {flight.config.vehicle}'s")
    if capture_delay_s < 0:
        raise ValueError(f"capture_delay_s must be >= 0, got {capture_delay_s}")
    imu = _imu(flight, clock)
    first = float(imu.utc[0])
    rows = _series_rows(imu.utc)
    nav = flight.truth_nav
    rpy = flight.autopilot_rpy if flight.autopilot_rpy is not None else np.stack([nav.roll, nav.pitch, nav.yaw], -1)
    mag = Series(imu.boot[rows], flight.mag[rows]) if flight.mag is not None else None
    latency_s = flight.config.gnss.latency_s  # a drone's GNSS is a ReceiverGnssModel
    return LoggedFlight(imu=imu, imu2=_second_imu(flight, imu) if second_imu else None,
                        fixes=_fixes(flight, clock, first), attitude=Series(imu.boot[rows], rpy[rows]), mag=mag,
                        events=_events(flight, clock, capture_delay_s, first),
                        header_boot=clock.start_offset_s - 0.5, lever_arm_gnss=flight.config.lever_arm_gnss_m,
                        gnss_lag_boot_s=float(latency_s) * clock.rate,
                        start_height=float(nav.height[0]))
