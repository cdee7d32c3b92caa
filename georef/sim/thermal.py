"""Temperature-driven IMU biases: a board that warms up after power-on, biases that follow its temperature.

Consumer MEMS IMUs (autopilots, phones) are seldom calibrated over temperature: their gyro bias moves by
0.01-0.05 deg/s and their accelerometer bias by 1-5 mg per degree Celsius, and the board warms by 10-20 degC
in the first minutes after power-on. Any vehicle's IMU can carry it (``SimConfig.thermal``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from georef.imu_errors import G0


@dataclass
class ThermalBiasModel:
    """Board temperature after power-on and the biases that follow it.

    ``T(t) = ambient_degc + warmup_degc (1 - exp(-(t + powered_before_s) / time_constant_s))`` [degC], ``t`` [s]
    from the log start; ``powered_before_s``: how long the board was on before the log started (0: the log starts
    at power-on; a drone already hovering: minutes). The biases gain ``coefficient x (T - ambient_degc)`` per
    body axis (x forward, y right, z down): ``gyro_deg_s_per_degc`` [deg/s per degC] and ``accel_mg_per_degc``
    [mg per degC], on top of the IMU's turn-on bias (its bias at power-on, at ambient temperature) and
    Gauss-Markov instability.
    """

    ambient_degc: float = 20.0
    warmup_degc: float = 15.0
    time_constant_s: float = 180.0
    powered_before_s: float = 0.0
    gyro_deg_s_per_degc: tuple[float, float, float] = (0.02, -0.03, 0.015)
    accel_mg_per_degc: tuple[float, float, float] = (2.0, -1.5, 3.0)

    def __post_init__(self) -> None:
        if self.time_constant_s <= 0 or self.powered_before_s < 0:
            raise ValueError("thermal model: time_constant_s must be positive and powered_before_s >= 0")
        for name in ("gyro_deg_s_per_degc", "accel_mg_per_degc"):
            if np.shape(getattr(self, name)) != (3,):
                raise ValueError(f"thermal model: {name} needs three numbers (body x, y, z)")

    def temperature(self, t: np.ndarray) -> np.ndarray:
        """Board temperature [degC] at ``t`` [s] from the log start."""
        t = np.asarray(t, dtype=float)
        return self.ambient_degc + self.warmup_degc * (1.0 - np.exp(-(t + self.powered_before_s)
                                                                    / self.time_constant_s))

    def gyro_bias(self, t: np.ndarray) -> np.ndarray:
        """Temperature part of the gyro bias [rad/s] (N, 3), body axes, at ``t`` [s] from the log start."""
        rise = self.temperature(t) - self.ambient_degc
        return rise[:, None] * np.radians(np.asarray(self.gyro_deg_s_per_degc, float))

    def accel_bias(self, t: np.ndarray) -> np.ndarray:
        """Temperature part of the accelerometer bias [m/s^2] (N, 3), body axes, at ``t`` [s] from the log start."""
        rise = self.temperature(t) - self.ambient_degc
        return rise[:, None] * np.asarray(self.accel_mg_per_degc, float) * 1e-3 * G0


def add_thermal_bias(model: ThermalBiasModel, t: np.ndarray, gyro: np.ndarray, accel: np.ndarray,
                     gyro_bias: np.ndarray, accel_bias: np.ndarray) -> np.ndarray:
    """Add the temperature part of the biases in place to the measurements and to the recorded true biases
    (all (N, 3): gyro [rad/s], accelerometer [m/s^2]) at ``t`` [s] from the log start; returns the board
    temperature [degC] (N,)."""
    gyro_part, accel_part = model.gyro_bias(t), model.accel_bias(t)
    gyro += gyro_part
    gyro_bias += gyro_part
    accel += accel_part
    accel_bias += accel_part
    return model.temperature(t)
