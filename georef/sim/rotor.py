"""Rotor-harmonic vibration of a multicopter: lines that follow the thrust, low-passed on board, aliased in the log.

A multicopter's rotors shake the frame at their rotation frequency (imbalance) and its harmonics (blade pass of
two-blade propellers at twice it, ...). Rotor speed goes as the square root of thrust, so the lines move with the
thrust: about 80-150 Hz at hover for a small quad, lower at idle, higher in a climb. The IMU samples the physical
vibration at its internal rate, the autopilot low-pass filters it (30-80 Hz, first or second order) and logs every
m-th sample at 200-400 Hz, where what is left above half the log rate appears at its alias ``|f - k fs|``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import butter, sosfilt

#: internal samples per block of the vibration synthesis (bounds the memory for long logs)
_BLOCK = 1 << 17


@dataclass
class RotorVibrationModel:
    """Vibration of ``n_motors`` rotors following the thrust, filtered on board, sampled at the log rate.

    * Rotor k turns at ``f_k(t) = hover_rotor_hz (1 + d_k) sqrt(thrust_ratio(t))`` [Hz], thrust ratio = thrust /
      hover thrust; the ``d_k`` spread evenly over ``+-motor_spread`` (the motors of a real drone differ by a few
      per cent, so the lines beat).
    * Each rotor shakes the frame at ``h f_k`` for the harmonics ``h = 1, 2, ...`` with weights
      ``harmonic_weights``, amplitude proportional to the rotor speed squared (the thrust ratio), random phase per
      rotor, harmonic and axis. ``accel_rms_mps2`` [m/s^2] and ``gyro_rms_deg_s`` [deg/s] (a number or body
      x, y, z) are the RMS per axis of the physical vibration at hover thrust, before the filter; ``level``
      multiplies both.
    * The sensor samples it at ``internal_rate_hz`` (rounded to a whole multiple m of the log rate), the on-board
      Butterworth low-pass of ``lowpass_order`` (1 or 2) at ``lowpass_hz`` filters it, and every m-th sample is
      logged (point sampling, so the log aliases what the filter leaves above its Nyquist frequency).

    Only the vibration goes through the filter; the rigid-body motion is logged ideal (the filter's few ms of
    group delay on it are not modelled). With the motors off (thrust ratio 0) the vibration is exactly zero.
    """

    hover_rotor_hz: float = 110.0
    harmonic_weights: tuple[float, ...] = (1.0, 0.6, 0.3)
    accel_rms_mps2: float | tuple[float, float, float] = (3.0, 3.0, 5.0)
    gyro_rms_deg_s: float | tuple[float, float, float] = (2.0, 2.0, 1.0)
    motor_spread: float = 0.03
    n_motors: int = 4
    lowpass_hz: float = 50.0
    lowpass_order: int = 2
    internal_rate_hz: float = 2000.0
    level: float = 1.0

    def __post_init__(self) -> None:
        if self.hover_rotor_hz <= 0 or self.n_motors < 1 or not self.harmonic_weights or self.level < 0:
            raise ValueError("rotor vibration needs a positive rotor frequency, at least one motor and one harmonic, "
                             "and a level >= 0")
        if self.lowpass_order not in (1, 2):
            raise ValueError(f"rotor vibration low-pass order must be 1 or 2, got {self.lowpass_order}")
        if not 0.0 < self.lowpass_hz < self.internal_rate_hz / 2.0:
            raise ValueError(f"rotor vibration low-pass {self.lowpass_hz} Hz must lie in (0, "
                             f"{self.internal_rate_hz / 2.0}) Hz")
        if not 0.0 <= self.motor_spread < 0.5:
            raise ValueError(f"motor_spread is a fraction in [0, 0.5), got {self.motor_spread}")

    def motor_factors(self) -> np.ndarray:
        """``1 + d_k`` of each motor (n_motors,): evenly spread over ``1 +- motor_spread``."""
        if self.n_motors == 1:
            return np.ones(1)
        return 1.0 + self.motor_spread * np.linspace(-1.0, 1.0, self.n_motors)

    def rms(self) -> np.ndarray:
        """Physical RMS per axis at hover thrust (6,): accelerometer x, y, z [m/s^2], gyro x, y, z [rad/s]."""
        accel = np.broadcast_to(np.asarray(self.accel_rms_mps2, float), (3,))
        gyro = np.radians(np.broadcast_to(np.asarray(self.gyro_rms_deg_s, float), (3,)))
        return self.level * np.concatenate([accel, gyro])


@dataclass
class RotorVibration:
    """The logged vibration at the row times: gyro [rad/s] and accelerometer [m/s^2] (N, 3), body axes, and the
    mean rotor frequency [Hz] (N,) (0 with the motors off)."""

    gyro: np.ndarray
    accel: np.ndarray
    rotor_hz: np.ndarray


def rotor_vibration(row_time: np.ndarray, thrust_time: np.ndarray, thrust_ratio: np.ndarray,
                    model: RotorVibrationModel, rng: np.random.Generator) -> RotorVibration:
    """The vibration the log holds at ``row_time`` [s] for the thrust ratio ``thrust_ratio`` [-] given on the
    uniform grid ``thrust_time`` [s] (interpolated linearly to the internal rate, on the grid's sample index so
    that a row on a grid sample takes its value exactly; held outside the grid).

    The filter starts 0.25 s before the first row from rest, so a log that starts with the motors running has
    settled by its first row. Random draws: one start phase per motor, one phase per motor, harmonic and axis.
    """
    dt = float(np.median(np.diff(row_time)))
    m = max(1, int(round(model.internal_rate_hz * dt)))
    rate = m / dt
    pad = m * int(np.ceil(0.25 / dt))
    n_internal = pad + (len(row_time) - 1) * m + 1
    t_internal = row_time[0] + (np.arange(n_internal) - pad) / rate
    step = (thrust_time[-1] - thrust_time[0]) / (len(thrust_time) - 1)
    if not np.allclose(np.diff(thrust_time), step, rtol=1e-6, atol=0.0):
        raise ValueError("rotor vibration: the thrust ratio must be given on a uniform time grid")
    # the sample index on the thrust grid, rounded to 1e-6 so that rounding in the times cannot leak a motor's
    # first thrust into the row before it
    position = np.round((t_internal - thrust_time[0]) / step, 6)
    thrust = np.maximum(np.interp(position, np.arange(len(thrust_time)), thrust_ratio), 0.0)
    speed = np.sqrt(thrust)  # rotor speed / hover rotor speed

    weights = np.asarray(model.harmonic_weights, float)
    start_phase = rng.uniform(0.0, 2.0 * np.pi, model.n_motors)
    axis_phase = rng.uniform(0.0, 2.0 * np.pi, (model.n_motors, len(weights), 6))
    # sin(x + psi) = sin x cos psi + cos x sin psi: one (sin, cos) pair per rotor and harmonic, mixed into 6 axes
    scale = model.rms() / np.sqrt(model.n_motors * np.sum(weights**2) / 2.0)
    amplitude = weights[None, :, None] * scale[None, None, :]
    mixing = np.concatenate([(amplitude * np.cos(axis_phase)).reshape(-1, 6),
                             (amplitude * np.sin(axis_phase)).reshape(-1, 6)])
    factors = model.motor_factors()

    sos = butter(model.lowpass_order, model.lowpass_hz, fs=rate, output="sos")
    state = np.zeros((sos.shape[0], 2, 6))
    logged = np.empty((len(row_time), 6))
    angle_end = 0.0
    for begin in range(0, n_internal, _BLOCK):
        block = slice(begin, min(begin + _BLOCK, n_internal))
        angle = angle_end + 2.0 * np.pi * model.hover_rotor_hz * np.cumsum(speed[block]) / rate
        angle_end = float(angle[-1])
        sines, cosines = _harmonic_pairs(angle[:, None] * factors[None, :] + start_phase[None, :], len(weights))
        physical = (np.concatenate([sines, cosines], axis=1) @ mixing) * thrust[block, None]
        filtered, state = sosfilt(sos, physical, axis=0, zi=state)
        index = np.arange(block.start, block.stop)
        keep = (index >= pad) & ((index - pad) % m == 0)
        logged[(index[keep] - pad) // m] = filtered[keep]
    rotor_hz = model.hover_rotor_hz * speed[pad::m]
    return RotorVibration(gyro=logged[:, 3:], accel=logged[:, :3], rotor_hz=rotor_hz)


def _harmonic_pairs(x: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """``sin(h x)`` and ``cos(h x)`` for ``h = 1..count`` of angles ``x`` (L, M) [rad], each (L, M * count) ordered
    ``m * count + h - 1``, by the angle-addition recurrence (one sine and cosine per angle)."""
    s1, c1 = np.sin(x), np.cos(x)
    sines, cosines = [s1], [c1]
    for _ in range(count - 1):
        s, c = sines[-1], cosines[-1]
        sines.append(s * c1 + c * s1)
        cosines.append(c * c1 - s * s1)
    return (np.stack(sines, axis=-1).reshape(len(x), -1), np.stack(cosines, axis=-1).reshape(len(x), -1))
