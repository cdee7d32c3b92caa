"""One entry point for every attitude filter: ``estimate_attitude(method, ...)`` -> a table per sample."""

from __future__ import annotations

import numpy as np
import pandas as pd

from georef.aot import load as load_kernel
from georef.attitude.mekf import run_mekf
from georef.attitude.tilt import accel_tilt
from georef.attitude.ukf import run_ukf
from georef.frames import dcm_to_euler, wrap_360

METHODS = ("complementary", "kf", "mekf", "ukf")


def mag_reference(inclination_deg: float) -> np.ndarray:
    """Unit NED field direction for a magnetic inclination [deg] (yaw is then relative to magnetic north)."""
    inc = np.radians(inclination_deg)
    return np.array([np.cos(inc), 0.0, np.sin(inc)])


def estimate_attitude(method: str, time: np.ndarray, gyro: np.ndarray, accel: np.ndarray,
                      mag: np.ndarray | None = None, inclination_deg: float = 60.0, gain: float = 0.02,
                      gyro_noise: float = 0.01, accel_sigma: float = 0.01, mag_sigma: float = 0.02,
                      accel_gate: float = 0.5, alpha: float = 0.01, beta: float = 2.0,
                      kappa: float = 0.0) -> pd.DataFrame:
    """Attitude from gyro [rad/s], specific force [m/s^2] and optionally magnetometer samples.

    Returns ``time, roll, pitch, yaw`` [deg] (yaw only from mekf/ukf: relative to magnetic north with a
    magnetometer, to the start heading without), estimated gyro biases [deg/s] and sigmas [deg] where the
    method has them. ``gain`` is the complementary filter's accelerometer weight k per sample.
    """
    if method not in METHODS:
        raise ValueError(f"unknown attitude method {method!r}; choose one of {', '.join(METHODS)}")
    time = np.ascontiguousarray(time, float)
    gyro = np.ascontiguousarray(gyro, float)
    accel = np.ascontiguousarray(accel, float)
    out = pd.DataFrame({"time": time})
    if method in ("complementary", "kf"):
        roll_acc, pitch_acc = accel_tilt(accel)
        if method == "complementary":
            angles = load_kernel("tilt").complementary(time, gyro, roll_acc, pitch_acc, gain)
        else:
            angles, biases = load_kernel("tilt").angle_bias_kalman(time, gyro, roll_acc, pitch_acc, 1e-5, 1e-7,
                                                                   accel_sigma**2)
            out["bias_roll_rate"] = np.degrees(biases[:, 0])
            out["bias_pitch_rate"] = np.degrees(biases[:, 1])
        out["roll"], out["pitch"] = np.degrees(angles[:, 0]), np.degrees(angles[:, 1])
        return out
    runner = run_mekf if method == "mekf" else run_ukf
    kwargs = {"alpha": alpha, "beta": beta, "kappa": kappa} if method == "ukf" else {}
    C, biases, sigmas = runner(time, gyro, accel, mag, mag_reference(inclination_deg) if mag is not None else None,
                               gyro_noise=gyro_noise, accel_sigma=accel_sigma, mag_sigma=mag_sigma,
                               accel_gate=accel_gate, **kwargs)
    roll, pitch, yaw = dcm_to_euler(C)
    out["roll"], out["pitch"], out["yaw"] = np.degrees(roll), np.degrees(pitch), wrap_360(np.degrees(yaw))
    for i, axis in enumerate("xyz"):
        out[f"bias_{axis}"] = np.degrees(biases[:, i])
    for i, name in enumerate(("sigma_tilt_x", "sigma_tilt_y", "sigma_tilt_z")):
        out[name] = np.degrees(sigmas[:, i])
    return out
