"""A drone's GNSS receiver as its autopilot logs it: correlated errors, reported accuracy, arrival time tags, gaps.

Unlike :class:`georef.sim.sensors.GnssModel` (white errors, fixes tagged with their measurement time), a small
receiver (u-blox class) on an autopilot gives

* position errors that wander slowly: a first-order Gauss-Markov process per axis (correlation time 20-120 s,
  0.5-1.5 m horizontally, 1-3 m vertically) plus a little white noise;
* its own accuracy estimate (hAcc / vAcc-like ``sigma_n, sigma_e, sigma_u``), which is not the true error sigma:
  the true sigma times a factor that wanders slowly within 0.7-1.5;
* time tags of *arrival*: the autopilot stamps a fix when it has received it, ``latency_s`` (0.05-0.2 s, a few ms
  of jitter) after the receiver measured it;
* at 1 Hz logging, missing fixes: single ones and runs of 2-5.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from georef.frames import C_n_e, ecef_to_geodetic, geodetic_to_ecef
from georef.frames.mounting import lever_arm_ecef
from georef.sim.sensors import gauss_markov
from georef.sim.trajectory import Trajectory

#: shortest and longest run of missing fixes
_RUN_MIN, _RUN_MAX = 2, 5


@dataclass
class ReceiverGnssModel:
    """A logged GNSS receiver. Units: Hz, m, s; ``sigma_neu_m`` and ``white_sigma_neu_m`` are north, east, up.

    * ``rate_hz``: measurement rate (1, 5, 10 Hz or any; epochs fall on the IMU rows nearest to a regular grid);
      ``first_fix_s``: the first measurement after the log start;
    * errors: Gauss-Markov with steady-state sigma ``sigma_neu_m`` and time constant ``correlation_time_s``, plus
      white noise ``white_sigma_neu_m``;
    * reported accuracy: ``sqrt(sigma^2 + white^2)`` per axis times a factor in ``reported_scale`` (lognormal
      Gauss-Markov, time constant ``reported_scale_corr_s``, clipped to the range), rounded to 1 mm;
    * time tag = measurement time + ``latency_s`` + uniform jitter within ``+-latency_jitter_s``;
    * missing fixes: about ``drop_fraction`` of all, a share ``drop_run_share`` of the gaps being runs of 2-5;
      ``outages`` (start, length) [s from the log start] remove fixes, ``outliers`` (time [s from the log
      start], size [m]) displace the fix nearest in time by ``size`` in a random direction.
    """

    rate_hz: float = 5.0
    sigma_neu_m: tuple[float, float, float] = (0.9, 0.9, 2.0)
    correlation_time_s: float = 60.0
    white_sigma_neu_m: tuple[float, float, float] = (0.05, 0.05, 0.1)
    latency_s: float = 0.12
    latency_jitter_s: float = 0.004
    reported_scale: tuple[float, float] = (0.7, 1.5)
    reported_scale_corr_s: float = 120.0
    first_fix_s: float = 1.0
    drop_fraction: float = 0.0
    drop_run_share: float = 0.3
    outages: list[tuple[float, float]] = field(default_factory=list)
    outliers: list[tuple[float, float]] = field(default_factory=list)

    def __post_init__(self) -> None:
        if self.rate_hz <= 0 or self.correlation_time_s <= 0 or self.reported_scale_corr_s <= 0:
            raise ValueError("GNSS receiver: rate and correlation times must be positive")
        if not 0.0 <= self.latency_s <= 1.0 or not 0.0 <= self.latency_jitter_s < 0.5 / self.rate_hz:
            raise ValueError(f"GNSS receiver: latency must be 0-1 s and its jitter below half a period, got "
                             f"{self.latency_s} s +- {self.latency_jitter_s} s at {self.rate_hz} Hz")
        low, high = self.reported_scale
        if not 0.0 < low <= high:
            raise ValueError(f"GNSS receiver: reported_scale needs 0 < low <= high, got {self.reported_scale}")
        if not 0.0 <= self.drop_fraction < 0.5 or not 0.0 <= self.drop_run_share <= 1.0:
            raise ValueError("GNSS receiver: drop_fraction must be in [0, 0.5) and drop_run_share in [0, 1]")

    @classmethod
    def logged_1hz_with_gaps(cls, drop_fraction: float = 0.03, **changes: object) -> ReceiverGnssModel:
        """Fixes logged at 1 Hz with about ``drop_fraction`` of them missing, some in runs of 2-5."""
        return cls(**{"rate_hz": 1.0, "drop_fraction": drop_fraction, **changes})  # type: ignore[arg-type]

    @property
    def total_sigma_neu_m(self) -> tuple[float, float, float]:
        """The true 1-sigma of a fix's error per axis (north, east, up) [m]: Gauss-Markov and white together."""
        total = np.hypot(np.asarray(self.sigma_neu_m, float), np.asarray(self.white_sigma_neu_m, float))
        return float(total[0]), float(total[1]), float(total[2])


def receiver_fixes(model: ReceiverGnssModel, nav: Trajectory, lever_arm_gnss_m: tuple[float, float, float],
                   rng: np.random.Generator) -> pd.DataFrame:
    """The logged fixes of the antenna for the IMU-row truth ``nav`` (``nav.time`` on the log's time scale [s]).

    Columns: ``time`` (the logged time tag: arrival) and ``measured_time`` [s], ``lat, lon`` [deg], ``height``
    [m] (measured antenna), ``sigma_n, sigma_e, sigma_u`` (the receiver's reported accuracy) [m], ``is_outlier``.
    Every random number is drawn for every epoch before any fix is dropped, so gaps do not shift the errors.
    """
    t0 = nav.time[0]
    row_rate = 1.0 / float(np.median(np.diff(nav.time)))
    period = 1.0 / model.rate_hz
    last = nav.time[-1] - model.latency_s - model.latency_jitter_s
    epochs = t0 + model.first_fix_s + np.arange(max(0, int(np.floor((last - t0 - model.first_fix_s) / period)) + 1)) \
        * period
    idx = np.unique(np.clip(np.round((epochs - t0) * row_rate).astype(int), 0, len(nav.time) - 1))
    n = len(idx)
    slow = gauss_markov(n, period, 1.0, model.correlation_time_s, rng) * np.asarray(model.sigma_neu_m, float)
    white = rng.standard_normal((n, 3)) * np.asarray(model.white_sigma_neu_m, float)
    scale_drive = gauss_markov(n, period, 1.0, model.reported_scale_corr_s, rng, 1)[:, 0]
    jitter = rng.uniform(-model.latency_jitter_s, model.latency_jitter_s, n)
    dropped = _dropped(n, model, rng)
    error_n = (slow + white) * np.array([1.0, 1.0, -1.0])  # north, east, up -> NED
    rel = nav.time[idx] - t0
    outlier = np.zeros(n, bool)
    for when, size in model.outliers:
        k = int(np.argmin(np.abs(rel - when)))
        direction = rng.standard_normal(3)
        error_n[k] += size * direction / np.linalg.norm(direction)
        outlier[k] = True
    for start, length in model.outages:
        dropped |= (rel >= start) & (rel < start + length)

    lat, lon = nav.lat[idx], nav.lon[idx]
    r_ant = geodetic_to_ecef(lat, lon, nav.height[idx]) + lever_arm_ecef(lat, lon, nav.C_b_n[idx], lever_arm_gnss_m)
    r_fix = r_ant + np.einsum("nij,nj->ni", C_n_e(lat, lon), error_n)
    fix_lat, fix_lon, fix_h = ecef_to_geodetic(r_fix)
    low, high = model.reported_scale
    log_spread = np.log(high / low) / 4.0 if high > low else 0.0
    factor = np.clip(np.sqrt(low * high) * np.exp(log_spread * scale_drive), low, high)
    reported = np.round(factor[:, None] * np.asarray(model.total_sigma_neu_m)[None, :], 3)
    measured = nav.time[idx]
    keep = ~dropped
    return pd.DataFrame({
        "time": (measured + model.latency_s + jitter)[keep], "measured_time": measured[keep],
        "lat": np.degrees(fix_lat)[keep], "lon": np.degrees(fix_lon)[keep], "height": fix_h[keep],
        "sigma_n": reported[keep, 0], "sigma_e": reported[keep, 1], "sigma_u": reported[keep, 2],
        "is_outlier": outlier[keep],
    })


def _dropped(n: int, model: ReceiverGnssModel, rng: np.random.Generator) -> np.ndarray:
    """Which of ``n`` epochs are missing: gaps start with a probability chosen so that about ``drop_fraction``
    of all epochs go missing (a gap is one epoch, or a run of 2-5 with probability ``drop_run_share``). A gap
    cannot start inside or right after another, so no gap is longer than 5."""
    start_draw = rng.random(n)
    run_draw = rng.random(n)
    run_length = rng.integers(_RUN_MIN, _RUN_MAX + 1, n)
    mean_length = 1.0 + model.drop_run_share * ((_RUN_MIN + _RUN_MAX) / 2.0 - 1.0)
    dropped = np.zeros(n, bool)
    free_from = 0
    for k in np.flatnonzero(start_draw < model.drop_fraction / mean_length):
        if k < free_from:
            continue
        length = int(run_length[k]) if run_draw[k] < model.drop_run_share else 1
        dropped[k:k + length] = True
        free_from = k + length + 1
    return dropped
