"""Sensor models of the simulator: MEMS IMU errors, helicopter vibration, the POS unit's own outputs, GNSS."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.signal import lfilter

from georef.imu_errors import ImuErrorModel


@dataclass
class VibrationModel:
    """Rotor vibration as sinusoids at the blade-pass frequency and its harmonic (point-sampled).

    Mi-8: main rotor 3.2 Hz with five blades, so about 16 Hz blade-pass. Amplitudes per axis.
    """

    blade_pass_hz: float = 16.0
    accel_amplitude_mps2: float = 0.4
    gyro_amplitude_deg_s: float = 0.2


@dataclass
class UnitModel:
    """The POS unit's own attitude and level-frame acceleration outputs.

    ``YAW = true yaw - (yaw_offset + yaw_drift * t)``: an unknown initial azimuth plus a drift.
    Roll and pitch carry a slowly varying error (Gauss-Markov) and white noise.
    """

    yaw_offset_deg: float = 57.0
    yaw_drift_deg_min: float = 0.5
    level_error_deg: float = 0.05
    level_error_corr_s: float = 60.0
    angle_noise_deg: float = 0.01
    iacc_bias_mps2: float = 0.01


@dataclass
class GnssModel:
    """1 Hz GNSS fixes of the antenna with white noise, outages, outliers and logging latency."""

    sigma_neu_m: tuple[float, float, float] = (1.0, 1.0, 2.0)
    rate_hz: float = 1.0
    outages: list[tuple[float, float]] = field(default_factory=list)  # (start s from flight start, length s)
    outliers: list[tuple[float, float]] = field(default_factory=list)  # (time s from start, size m)
    latency_s: tuple[float, float] = (0.05, 0.3)


def gauss_markov(n: int, dt: float, sigma: float, corr_time: float, rng: np.random.Generator,
                 dims: int = 3) -> np.ndarray:
    """First-order Gauss-Markov sequences (n, dims) with steady-state std ``sigma`` and time constant [s]."""
    if sigma <= 0:
        return np.zeros((n, dims))
    phi = np.exp(-dt / corr_time)
    drive = rng.standard_normal((n, dims)) * sigma * np.sqrt(1.0 - phi**2)
    drive[0] = rng.standard_normal(dims) * sigma
    return lfilter([1.0], [1.0, -phi], drive, axis=0)


def corrupt_imu(omega_ib_b: np.ndarray, f_ib_b: np.ndarray, t: np.ndarray, model: ImuErrorModel,
                vibration: VibrationModel | None, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    """Measured rates [rad/s] and specific forces [m/s^2] at times ``t``, and the true biases.

    Point samples: white noise with the datasheet PSD over the sample interval, turn-on bias,
    Gauss-Markov bias instability and vibration sinusoids.
    """
    n = len(t)
    dt = float(np.median(np.diff(t)))
    gyro_bias = rng.standard_normal(3) * model.gyro_turn_on_sigma + gauss_markov(
        n, dt, model.gyro_markov_sigma, model.gyro_bias_corr_time_s, rng)
    accel_bias = rng.standard_normal(3) * model.accel_turn_on_sigma + gauss_markov(
        n, dt, model.accel_markov_sigma, model.accel_bias_corr_time_s, rng)
    gyro = omega_ib_b + gyro_bias + rng.standard_normal((n, 3)) * np.sqrt(model.gyro_white_psd / dt)
    accel = f_ib_b + accel_bias + rng.standard_normal((n, 3)) * np.sqrt(model.accel_white_psd / dt)
    if vibration is not None:
        for harmonic, weight in ((1.0, 1.0), (2.0, 0.4)):
            freq = vibration.blade_pass_hz * harmonic
            phase = rng.uniform(0, 2 * np.pi, (2, 3))
            wave = np.sin(2 * np.pi * freq * t[:, None] + phase[0])
            accel += weight * vibration.accel_amplitude_mps2 * wave
            wave = np.sin(2 * np.pi * freq * t[:, None] + phase[1])
            gyro += weight * np.radians(vibration.gyro_amplitude_deg_s) * wave
    return gyro, accel, gyro_bias, accel_bias
