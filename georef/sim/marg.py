"""Synthetic MARG (gyro, accelerometer, magnetometer) data for attitude-filter tests: an attitude rig.

The rig turns smoothly about all axes (sums of sinusoids), with small linear accelerations. Sensors carry
white noise and constant biases, as in the test conditions of [A3] in ``docs/attitude.md`` (gyro bias 0.1 rad/s).
Frames: body FRD, navigation NED treated as inertial (Earth rate is far below these sensors' noise).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from georef.frames import STANDARD_GRAVITY, dcm_to_euler, euler_to_dcm


@dataclass
class MargConfig:
    """Rig motion and sensor errors. Units: s, Hz, rad, rad/s, m/s^2, field in units of its magnitude."""

    duration_s: float = 120.0
    rate_hz: float = 200.0
    amplitude_deg: tuple[float, float, float] = (25.0, 20.0, 90.0)  # roll, pitch, yaw swings
    linear_accel: float = 0.02
    gyro_noise: float = 0.01
    gyro_bias: tuple[float, float, float] = (0.1, -0.1, 0.1)
    accel_noise: float = 0.05
    accel_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mag_noise: float = 0.01
    mag_inclination_deg: float = 60.0
    seed: int = 0


@dataclass
class MargData:
    time: np.ndarray
    gyro: np.ndarray        # rad/s (N, 3)
    accel: np.ndarray       # m/s^2 (N, 3), specific force
    mag: np.ndarray         # (N, 3), field in units of its magnitude
    roll: np.ndarray        # truth, rad
    pitch: np.ndarray
    yaw: np.ndarray
    mag_reference: np.ndarray  # NED unit field vector


def simulate_marg(cfg: MargConfig | None = None) -> MargData:
    cfg = cfg or MargConfig()
    rng = np.random.default_rng(cfg.seed)
    fine = 4
    n = int(cfg.duration_s * cfg.rate_hz) + 1
    t_fine = np.arange((n - 1) * fine + 1) / (cfg.rate_hz * fine)
    angles = np.zeros((len(t_fine), 3))
    for axis, amplitude in enumerate(np.radians(cfg.amplitude_deg)):
        for _ in range(3):
            freq = rng.uniform(0.02, 0.3)
            angles[:, axis] += amplitude / 3.0 * np.sin(2 * np.pi * freq * t_fine + rng.uniform(0, 2 * np.pi))
    C_fine = euler_to_dcm(angles[:, 0], angles[:, 1], angles[:, 2])
    rot = Rotation.from_matrix(C_fine)
    omega = np.empty((len(t_fine), 3))
    dt = t_fine[1] - t_fine[0]
    omega[1:-1] = (rot[:-2].inv() * rot[2:]).as_rotvec() / (2 * dt)
    omega[0], omega[-1] = omega[1], omega[-2]
    idx = np.arange(0, len(t_fine), fine)
    C = C_fine[idx]
    t = t_fine[idx]
    lin = cfg.linear_accel * np.sin(2 * np.pi * np.outer(t, [0.11, 0.07, 0.05]) + rng.uniform(0, 6, 3))
    f_n = lin - np.array([0.0, 0.0, STANDARD_GRAVITY])
    C_n_b = np.swapaxes(C, 1, 2)
    accel = np.einsum("nij,nj->ni", C_n_b, f_n) + np.asarray(cfg.accel_bias) + rng.normal(0, cfg.accel_noise, (n, 3))
    gyro = omega[idx] + np.asarray(cfg.gyro_bias) + rng.normal(0, cfg.gyro_noise, (n, 3))
    inc = np.radians(cfg.mag_inclination_deg)
    m_ref = np.array([np.cos(inc), 0.0, np.sin(inc)])
    mag = np.einsum("nij,j->ni", C_n_b, m_ref) + rng.normal(0, cfg.mag_noise, (n, 3))
    roll, pitch, yaw = dcm_to_euler(C)
    return MargData(time=t, gyro=gyro, accel=accel, mag=mag, roll=roll, pitch=pitch, yaw=yaw, mag_reference=m_ref)
