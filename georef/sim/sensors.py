"""Sensor models of the simulator: IMU errors, vibration, the POS unit's own outputs, GNSS, magnetometer, autopilot."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.signal import butter, lfilter, sosfilt

from georef.frames import dcm_to_euler, euler_to_dcm, wrap_pi
from georef.imu_errors import ImuErrorModel

VIBRATION_KINDS = ("none", "rotor", "white", "narrowband")
VIBRATION_SAMPLING = ("average", "point")


@dataclass
class VibrationModel:
    """Vibration added to the IMU's rates and specific forces, of one of :data:`VIBRATION_KINDS`.

    Amplitudes are per body axis (x forward, y right, z down): a number for all three axes or a 3-tuple,
    accelerometer [m/s^2] and gyro [deg/s], all multiplied by ``level`` [-] (so a test can draw several
    levels of the same character). What each ``kind`` does, seen at the POS row rate ``fs`` (Nyquist
    ``fs/2``):

    * ``none``: nothing; only the sensor's own noise remains.
    * ``rotor`` (the default, the helicopter's): sinusoids at the blade-pass frequency ``blade_pass_hz``
      (Mi-8: main rotor 3.2 Hz x five blades, about 16 Hz) with peak amplitude A and at its harmonic with
      ``harmonic_weight`` x A, random phases, *point-sampled* at the row times. The periodogram at the row
      rate shows two lines, at each frequency's alias ``|f - k fs|`` folded into [0, fs/2] (at 50 Hz:
      16 Hz and 32 -> 18 Hz); variance A^2 (1 + w^2) / 2.
    * ``white``: independent Gaussian samples on every axis at ``internal_rate_hz`` (default 200 Hz) with
      standard deviation A; with ``sampling="average"`` (default) each row holds the mean of the
      ``m = round(internal_rate_hz / fs)`` samples of its interval ``(t - 1/fs, t]``, as an IMU that
      integrates over its output interval. The spectrum at the row rate is flat with variance ``A^2 / m``
      (one-sided PSD ``2 A^2 / (m fs)``); with ``"point"`` every m-th sample is kept: flat, variance A^2.
    * ``narrowband``: random vibration, not a fixed sinusoid: Gaussian noise at ``internal_rate_hz``, band-pass
      filtered (Butterworth, 8th order, band ``blade_pass_hz +- bandwidth_hz / 2``) and scaled to RMS A,
      then averaged (default) or point-sampled to the row rate as for ``white``. At the row rate its power sits
      in the band if the band lies below fs/2, otherwise in the band's alias; averaging multiplies the power
      by the boxcar's ``(sin(pi f m / f_i) / (m sin(pi f / f_i)))^2`` (0.59 at 20 Hz for 200 -> 50 Hz)
      and suppresses aliases near multiples of fs.

    :meth:`of_kind` gives typical amplitudes for each kind. When the row rate is at or above the internal
    rate, ``m = 1`` and averaging equals point sampling.
    """

    blade_pass_hz: float = 16.0
    accel_amplitude_mps2: float | tuple[float, float, float] = 0.4
    gyro_amplitude_deg_s: float | tuple[float, float, float] = 0.2
    kind: str = "rotor"
    level: float = 1.0
    harmonic_weight: float = 0.4
    internal_rate_hz: float = 200.0
    bandwidth_hz: float = 4.0
    sampling: str = "average"

    def __post_init__(self) -> None:
        if self.kind not in VIBRATION_KINDS:
            raise ValueError(f"vibration kind must be one of {', '.join(VIBRATION_KINDS)}, got {self.kind!r}")
        if self.sampling not in VIBRATION_SAMPLING:
            raise ValueError(f"vibration sampling must be 'average' or 'point', got {self.sampling!r}")
        if self.level < 0:
            raise ValueError(f"vibration level must be >= 0, got {self.level}")
        if self.kind == "narrowband" and (self.bandwidth_hz <= 0 or self.blade_pass_hz - self.bandwidth_hz / 2 <= 0
                                          or self.blade_pass_hz + self.bandwidth_hz / 2 >= self.internal_rate_hz / 2):
            raise ValueError(f"narrowband vibration: band {self.blade_pass_hz} +- {self.bandwidth_hz / 2} Hz must "
                             f"lie inside (0, {self.internal_rate_hz / 2}) Hz")

    @classmethod
    def of_kind(cls, kind: str, level: float = 1.0, **changes: object) -> VibrationModel:
        """Typical vibration of ``kind`` at ``level`` x its amplitudes; ``changes`` override any field.

        ``rotor``: 16 Hz, 0.4 m/s^2, 0.2 deg/s (peak); ``white``: 0.25/0.25/0.4 m/s^2 and 0.1 deg/s per
        axis (standard deviation at 200 Hz, averaged to the row rate); ``narrowband``: 20 +- 2 Hz,
        0.3/0.3/0.5 m/s^2 and 0.15 deg/s RMS at 200 Hz, averaged; ``none``: no vibration.
        """
        typical: dict[str, dict[str, object]] = {
            "none": {"accel_amplitude_mps2": 0.0, "gyro_amplitude_deg_s": 0.0},
            "rotor": {},
            "white": {"accel_amplitude_mps2": (0.25, 0.25, 0.4), "gyro_amplitude_deg_s": 0.1},
            "narrowband": {"blade_pass_hz": 20.0, "bandwidth_hz": 4.0, "accel_amplitude_mps2": (0.3, 0.3, 0.5),
                           "gyro_amplitude_deg_s": 0.15},
        }
        if kind not in typical:
            raise ValueError(f"vibration kind must be one of {', '.join(VIBRATION_KINDS)}, got {kind!r}")
        return cls(kind=kind, level=level, **{**typical[kind], **changes})  # type: ignore[arg-type]

    def amplitudes(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-axis amplitudes times ``level``: accelerometer [m/s^2] (3,), gyro [rad/s] (3,)."""
        accel = self.level * np.broadcast_to(np.asarray(self.accel_amplitude_mps2, float), (3,))
        gyro = self.level * np.radians(np.broadcast_to(np.asarray(self.gyro_amplitude_deg_s, float), (3,)))
        return accel, gyro


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
    """GNSS fixes of the antenna with white noise, outages, outliers and logging latency.

    ``rate_hz``: 1 (default), 5, 10 Hz or any rate; fixes fall on multiples of the period. ``latency_s``: the
    range [s] of the uniform delay before a fix appears in the POS log, capped at 0.5 and 0.9 periods so the
    fixes appear in order at high rates. Outages (start, length) and outliers (time, size) in seconds from the
    flight start and metres. ``time_offset_s``: each fix is the antenna's position this long before its time tag
    (a receiver's time-tag error; what georef calls the GNSS latency, ``gnss_latency``), at most 1 s.
    """

    sigma_neu_m: tuple[float, float, float] = (1.0, 1.0, 2.0)
    rate_hz: float = 1.0
    outages: list[tuple[float, float]] = field(default_factory=list)  # (start s from flight start, length s)
    outliers: list[tuple[float, float]] = field(default_factory=list)  # (time s from start, size m)
    latency_s: tuple[float, float] = (0.05, 0.3)
    time_offset_s: float = 0.0


@dataclass
class MagnetometerModel:
    """A three-axis magnetometer in body axes (x forward, y right, z down), microtesla.

    ``m_b = C_n_b m_n + hard_iron + motor + noise``: a constant Earth field ``m_n`` of ``field_ut`` [uT] with
    ``inclination_deg`` (dip, positive down) and ``declination_deg`` (east of true north), a constant
    hard-iron offset [uT] per body axis and white noise [uT, 1 sigma per sample]. Defaults: central Croatia.
    ``motor_interference_ut`` [uT, body axes]: the field of the motor currents at hover thrust, scaled by the
    motor load (current ~ thrust^1.5, 0 with the motors off); only a vehicle with motors (the drone) has a load,
    so it must stay zero for the others.
    """

    field_ut: float = 48.0
    inclination_deg: float = 60.0
    declination_deg: float = 4.0
    hard_iron_ut: tuple[float, float, float] = (1.5, -0.8, 0.6)
    noise_ut: float = 0.3
    motor_interference_ut: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def field_n(self) -> np.ndarray:
        """Earth field in NED [uT]: ``Rz(declination) Ry(-inclination) [F, 0, 0]``."""
        return euler_to_dcm(0.0, -np.radians(self.inclination_deg), np.radians(self.declination_deg)) @ \
            np.array([self.field_ut, 0.0, 0.0])


@dataclass
class AutopilotModel:
    """An autopilot's (flight controller's, phone's) own attitude estimate: roll, pitch, yaw with errors.

    Yaw is absolute (from true north): a constant error drawn once per flight with ``yaw_bias_sigma_deg``
    (magnetic model, declination, hard iron) plus a Gauss-Markov error (``yaw_error_deg``,
    ``yaw_error_corr_s``). Roll and pitch carry a Gauss-Markov error (``level_error_deg``,
    ``level_error_corr_s``). All three have white noise ``noise_deg``. Degrees and seconds.
    ``mounting_offset_deg`` (roll, pitch, yaw): the constant rotation of the autopilot's own frame from the IMU
    body frame (its board mounting and level trim, up to 1-2 deg on a real drone): it reports the attitude of
    ``C_b_n C_a_b`` with ``C_a_b = euler_to_dcm(*offset)``.
    """

    yaw_bias_sigma_deg: float = 3.0
    yaw_error_deg: float = 1.0
    yaw_error_corr_s: float = 120.0
    level_error_deg: float = 0.3
    level_error_corr_s: float = 30.0
    noise_deg: float = 0.05
    mounting_offset_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)


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
                vibration: VibrationModel | None, rng: np.random.Generator,
                gyro_turn_on: np.ndarray | None = None,
                accel_turn_on: np.ndarray | None = None, gyro_scale: np.ndarray | None = None,
                accel_scale: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
    """Measured rates [rad/s] and specific forces [m/s^2] at times ``t`` [s], and the true biases (N, 3).

    Point samples: white noise with the datasheet PSD over the sample interval, turn-on bias,
    Gauss-Markov bias instability and vibration (:func:`vibration_samples`). ``gyro_turn_on`` [rad/s] and
    ``accel_turn_on`` [m/s^2] (body axes, (3,)) force the turn-on biases instead of the preset's random
    draw; the draw is still made, so the rest of the noise is the same as without forcing. ``gyro_scale`` and
    ``accel_scale`` (unitless, body x, y, z): scale-factor errors, each true rate and specific force measured as
    (1 + s) times itself.
    """
    n = len(t)
    dt = float(np.median(np.diff(t)))
    gyro_on = rng.standard_normal(3) * model.gyro_turn_on_sigma
    if gyro_turn_on is not None:
        gyro_on = np.asarray(gyro_turn_on, dtype=float).reshape(3)
    gyro_bias = gyro_on + gauss_markov(n, dt, model.gyro_markov_sigma, model.gyro_bias_corr_time_s, rng)
    accel_on = rng.standard_normal(3) * model.accel_turn_on_sigma
    if accel_turn_on is not None:
        accel_on = np.asarray(accel_turn_on, dtype=float).reshape(3)
    accel_bias = accel_on + gauss_markov(n, dt, model.accel_markov_sigma, model.accel_bias_corr_time_s, rng)
    if gyro_scale is not None:
        omega_ib_b = omega_ib_b * (1.0 + np.asarray(gyro_scale, float).reshape(3))
    if accel_scale is not None:
        f_ib_b = f_ib_b * (1.0 + np.asarray(accel_scale, float).reshape(3))
    gyro = omega_ib_b + gyro_bias + rng.standard_normal((n, 3)) * np.sqrt(model.gyro_white_psd / dt)
    accel = f_ib_b + accel_bias + rng.standard_normal((n, 3)) * np.sqrt(model.accel_white_psd / dt)
    if vibration is not None:
        add_vibration(t, vibration, rng, gyro, accel)
    return gyro, accel, gyro_bias, accel_bias


def vibration_samples(t: np.ndarray, vibration: VibrationModel,
                      rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Vibration alone at the row times ``t`` [s]: gyro [rad/s] and accelerometer [m/s^2], each (N, 3).

    Body axes. See :class:`VibrationModel` for what each kind does to the spectrum at the row rate.
    """
    gyro, accel = np.zeros((len(t), 3)), np.zeros((len(t), 3))
    add_vibration(t, vibration, rng, gyro, accel)
    return gyro, accel


def add_vibration(t: np.ndarray, vibration: VibrationModel, rng: np.random.Generator, gyro: np.ndarray,
                  accel: np.ndarray) -> None:
    """Add vibration in place to ``gyro`` [rad/s] and ``accel`` [m/s^2], (N, 3) at the row times ``t`` [s]."""
    n = len(t)
    accel_amp, gyro_amp = vibration.amplitudes()
    if vibration.kind == "none":
        return
    if vibration.kind == "rotor":
        for harmonic, weight in ((1.0, 1.0), (2.0, vibration.harmonic_weight)):
            freq = vibration.blade_pass_hz * harmonic
            phase = rng.uniform(0, 2 * np.pi, (2, 3))
            accel += weight * accel_amp * np.sin(2 * np.pi * freq * t[:, None] + phase[0])
            gyro += weight * gyro_amp * np.sin(2 * np.pi * freq * t[:, None] + phase[1])
        return
    dt = float(np.median(np.diff(t)))
    m = max(1, int(round(vibration.internal_rate_hz * dt)))
    internal_rate = m / dt
    warm_up = 0
    if vibration.kind == "narrowband":
        warm_up = int(np.ceil(20.0 / vibration.bandwidth_hz * internal_rate))  # filter settling, discarded
    samples = rng.standard_normal((warm_up + n * m, 6))
    if vibration.kind == "narrowband":
        half = vibration.bandwidth_hz / 2.0
        sos = butter(4, [vibration.blade_pass_hz - half, vibration.blade_pass_hz + half], btype="bandpass",
                     fs=internal_rate, output="sos")
        impulse = np.zeros(max(warm_up, 64))
        impulse[0] = 1.0
        gain = np.sqrt(np.sum(sosfilt(sos, impulse) ** 2))  # RMS of filtered unit-variance white noise
        samples = sosfilt(sos, samples, axis=0)[warm_up:] / gain
    samples = samples.reshape(n, m, 6)
    rows = samples.mean(axis=1) if vibration.sampling == "average" else samples[:, -1]
    gyro += rows[:, :3] * gyro_amp
    accel += rows[:, 3:] * accel_amp


def magnetometer(C_b_n: np.ndarray, model: MagnetometerModel, rng: np.random.Generator,
                 motor_load: np.ndarray | None = None) -> np.ndarray:
    """Magnetometer samples [uT] (N, 3), body axes, for attitudes ``C_b_n`` (N, 3, 3).

    ``motor_load`` (N,) [-]: motor current / current at hover (0 with the motors off) for the model's
    ``motor_interference_ut``; None for a vehicle without motors, whose model must then have none.
    """
    field_b = np.einsum("nji,j->ni", C_b_n, model.field_n())
    measured = field_b + np.asarray(model.hard_iron_ut, float) + model.noise_ut * rng.standard_normal(field_b.shape)
    if motor_load is None:
        if any(model.motor_interference_ut):
            raise ValueError("magnetometer motor interference needs a vehicle with motors (the drone)")
        return measured
    return measured + np.asarray(motor_load, float)[:, None] * np.asarray(model.motor_interference_ut, float)


def autopilot_attitude(t: np.ndarray, roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray, model: AutopilotModel,
                       rng: np.random.Generator) -> np.ndarray:
    """The autopilot's roll, pitch, yaw [rad] (N, 3) at times ``t`` [s] from the true angles [rad].

    The mounting offset turns the attitude first (when there is one); errors are added to the Euler angles;
    yaw is wrapped to (-pi, pi].
    """
    if any(model.mounting_offset_deg):
        C_a_b = euler_to_dcm(*np.radians(np.asarray(model.mounting_offset_deg, float)))
        roll, pitch, yaw = dcm_to_euler(euler_to_dcm(roll, pitch, yaw) @ C_a_b)
    n = len(t)
    dt = float(np.median(np.diff(t)))
    level = gauss_markov(n, dt, np.radians(model.level_error_deg), model.level_error_corr_s, rng, 2)
    heading = gauss_markov(n, dt, np.radians(model.yaw_error_deg), model.yaw_error_corr_s, rng, 1)[:, 0]
    heading += np.radians(model.yaw_bias_sigma_deg) * rng.standard_normal()
    noise = np.radians(model.noise_deg) * rng.standard_normal((n, 3))
    return np.column_stack([roll + level[:, 0] + noise[:, 0], pitch + level[:, 1] + noise[:, 1],
                            wrap_pi(yaw + heading + noise[:, 2])])
