"""Tilt from the accelerometer, the complementary filter and the angle + gyro-bias Kalman filter ([A4] in
``docs/attitude.md``).

Roll and pitch each have their own one-dimensional filter. The gyro input of each is the Euler-angle rate
from the body rates, ``roll' = p + (q sin r + r_z cos r) tan p_``, ``pitch' = q cos r - r_z sin r``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from georef.frames.kernels import euler_rate_matrix


def accel_tilt(accel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Roll and pitch [rad] of a non-accelerating body from its specific force (N, 3) [m/s^2], FRD axes.

    At rest ``f_b = C_n_b [0, 0, -g]``, so ``roll = atan2(-f_y, -f_z)``, ``pitch = atan2(f_x, sqrt(f_y² + f_z²))``.
    """
    accel = np.asarray(accel, dtype=float)
    return (np.arctan2(-accel[:, 1], -accel[:, 2]),
            np.arctan2(accel[:, 0], np.hypot(accel[:, 1], accel[:, 2])))


@njit(cache=True)
def _euler_rates(roll: float, pitch: float, w: np.ndarray) -> tuple[float, float]:
    """Roll and pitch rates [rad/s] of body rates ``w`` [rad/s] at roll, pitch [rad] (the first two rows of
    :func:`georef.frames.kernels.euler_rate_matrix`)."""
    E = euler_rate_matrix(roll, pitch)
    return (E[0, 0] * w[0] + E[0, 1] * w[1] + E[0, 2] * w[2],
            E[1, 0] * w[0] + E[1, 1] * w[1] + E[1, 2] * w[2])


@njit(cache=True)
def complementary(t: np.ndarray, gyro: np.ndarray, roll_acc: np.ndarray, pitch_acc: np.ndarray,
                  k: float) -> np.ndarray:
    """``θ_k = k θ_acc + (1 - k)(θ_{k-1} + θ' Δt)`` for roll and pitch; returns (N, 2) [rad].

    With a gyro bias b (in the Euler rate) its steady-state error is ``(1 - k) b Δt / k``.
    """
    n = t.shape[0]
    out = np.empty((n, 2))
    out[0, 0], out[0, 1] = roll_acc[0], pitch_acc[0]
    for i in range(1, n):
        dt = t[i] - t[i - 1]
        rate_r, rate_p = _euler_rates(out[i - 1, 0], out[i - 1, 1], gyro[i - 1])
        out[i, 0] = k * roll_acc[i] + (1.0 - k) * (out[i - 1, 0] + rate_r * dt)
        out[i, 1] = k * pitch_acc[i] + (1.0 - k) * (out[i - 1, 1] + rate_p * dt)
    return out


@njit(cache=True)
def angle_bias_kalman(t: np.ndarray, gyro: np.ndarray, roll_acc: np.ndarray, pitch_acc: np.ndarray,
                      q_angle: float, q_bias: float, r_angle: float) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis angle + rate-bias filter: ``x = [θ, b]``, ``F = [[1, -Δt], [0, 1]]``, ``B = [Δt, 0]``, ``H = [1, 0]``.

    ``q_angle`` [rad²/s] and ``q_bias`` [rad²/s³] are process-noise densities, ``r_angle`` [rad²] the variance
    of the accelerometer angle. Returns angles (N, 2) and estimated biases (N, 2) [rad/s].
    """
    n = t.shape[0]
    angles = np.empty((n, 2))
    biases = np.empty((n, 2))
    x = np.zeros((2, 2))
    P = np.zeros((2, 2, 2))
    x[0, 0], x[1, 0] = roll_acc[0], pitch_acc[0]
    for a in range(2):
        P[a, 0, 0] = r_angle
        P[a, 1, 1] = 0.1
    angles[0, 0], angles[0, 1] = x[0, 0], x[1, 0]
    biases[0] = 0.0
    for i in range(1, n):
        dt = t[i] - t[i - 1]
        rates = _euler_rates(x[0, 0], x[1, 0], gyro[i - 1])
        measured = (roll_acc[i], pitch_acc[i])
        for a in range(2):
            # predict
            x[a, 0] += (rates[a] - x[a, 1]) * dt
            p00 = P[a, 0, 0] - dt * (P[a, 0, 1] + P[a, 1, 0]) + dt * dt * P[a, 1, 1] + q_angle * dt
            p01 = P[a, 0, 1] - dt * P[a, 1, 1]
            p11 = P[a, 1, 1] + q_bias * dt
            # update
            s = p00 + r_angle
            k0, k1 = p00 / s, p01 / s
            y = measured[a] - x[a, 0]
            x[a, 0] += k0 * y
            x[a, 1] += k1 * y
            P[a, 0, 0] = p00 - k0 * p00
            P[a, 0, 1] = p01 - k0 * p01
            P[a, 1, 0] = P[a, 0, 1]
            P[a, 1, 1] = p11 - k1 * p01
            angles[i, a] = x[a, 0]
            biases[i, a] = x[a, 1]
    return angles, biases
