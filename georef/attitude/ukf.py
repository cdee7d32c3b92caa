"""An attitude unscented Kalman filter on the MEKF's state (quaternion + gyro bias).

Sigma points live in the 6-dimensional error space ``[δθ, δb]`` around the nominal quaternion
(``q_i = q̂ ⊗ q(δθ_i)``), as in Crassidis & Markley's USQUE (2003), so no quaternion is ever averaged.
``2L + 1 = 13`` points with the scaled unscented transform; ``α``, ``β``, ``κ`` configurable ([A3] in
``docs/attitude.md`` used 0.01, 2, 0). Measurements as in :mod:`georef.attitude.mekf`: gravity down from the
accelerometer and the magnetic field, as unit vectors.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from georef.aot import load as load_kernel
from georef.attitude.mekf import DOWN, GRAVITY, initial_state
from georef.frames import quat_to_dcm as quats_to_dcm
from georef.frames.kernels import quat_from_rotvec, quat_mul, quat_normalise, quat_to_dcm, quat_to_rotvec

L = 6


@njit(cache=True)
def _sigma_offsets(P: np.ndarray, scale: float) -> np.ndarray:
    S = np.linalg.cholesky(scale * 0.5 * (P + P.T))
    chi = np.zeros((2 * L + 1, L))
    for i in range(L):
        for j in range(L):
            chi[1 + i, j] = S[j, i]
            chi[1 + L + i, j] = -S[j, i]
    return chi


@njit(cache=True)
def _weights(alpha, beta, kappa):
    """The scaled unscented transform's ``λ`` and its mean and covariance weights (2L + 1 each)."""
    lam = alpha * alpha * (L + kappa) - L
    wm = np.full(2 * L + 1, 1.0 / (2.0 * (L + lam)))
    wc = wm.copy()
    wm[0] = lam / (L + lam)
    wc[0] = wm[0] + 1.0 - alpha * alpha + beta
    return lam, wm, wc


@njit(cache=True)
def _predict(q, b, P, w, dt, lam, wm, wc, gyro_noise, bias_walk):
    """Propagate the sigma points over ``dt`` [s] with the mean body rate ``w`` [rad/s]; returns the predicted
    quaternion, gyro bias [rad/s] and error covariance (6, 6), with the gyro noise and bias walk added."""
    chi = _sigma_offsets(P, L + lam)
    props = np.empty((2 * L + 1, 4))
    for s in range(2 * L + 1):
        q_s = quat_mul(q, quat_from_rotvec(chi[s, :3]))
        props[s] = quat_mul(q_s, quat_from_rotvec((w - (b + chi[s, 3:])) * dt))
    q_mean = props[0].copy()
    conj = np.array([q_mean[0], -q_mean[1], -q_mean[2], -q_mean[3]])
    new_chi = np.empty((2 * L + 1, L))
    mean = np.zeros(L)
    for s in range(2 * L + 1):
        new_chi[s, :3] = quat_to_rotvec(quat_mul(conj, props[s]))
        new_chi[s, 3:] = chi[s, 3:]
        mean += wm[s] * new_chi[s]
    P = np.zeros((L, L))
    for s in range(2 * L + 1):
        d = new_chi[s] - mean
        P += wc[s] * np.outer(d, d)
    for i in range(3):
        P[i, i] += gyro_noise * gyro_noise * dt * dt
        P[3 + i, 3 + i] += bias_walk * bias_walk * dt
    q = quat_mul(q_mean, quat_from_rotvec(mean[:3]))
    quat_normalise(q)
    return q, b + mean[3:], P


@njit(cache=True)
def _measurement(accel, mag, k, norm_f, use_acc, use_mag, accel_sigma, mag_sigma, m_dim):
    """Row ``k``'s measurement: gravity's down direction from the accelerometer (when ``use_acc``) and the magnetic
    field's direction (when ``use_mag``), unit vectors; their noise covariance and which entries are measured."""
    y = np.zeros(m_dim)
    R = np.zeros((m_dim, m_dim))
    active = np.zeros(m_dim, dtype=np.bool_)
    if use_acc:
        for i in range(3):
            y[i] = -accel[k, i] / norm_f
            R[i, i] = accel_sigma * accel_sigma
            active[i] = True
    if use_mag:
        norm_m = math.sqrt(mag[k, 0] ** 2 + mag[k, 1] ** 2 + mag[k, 2] ** 2)
        for i in range(3):
            y[3 + i] = mag[k, i] / norm_m
            R[3 + i, 3 + i] = mag_sigma * mag_sigma
            active[3 + i] = True
    if not use_acc:
        for i in range(3):
            R[i, i] = 1.0
    return y, R, active


@njit(cache=True)
def _update(q, b, P, y, R, active, use_acc, use_mag, mag_reference, lam, wm, wc, C):
    """The unscented measurement update of ``q``, ``b``, ``P`` with ``y`` (:func:`_measurement`); the
    accelerometer's gain is zeroed when it is not used. ``C`` (3, 3): a work array."""
    m_dim = y.shape[0]
    chi = _sigma_offsets(P, L + lam)
    Y = np.zeros((2 * L + 1, m_dim))
    for s in range(2 * L + 1):
        quat_to_dcm(quat_mul(q, quat_from_rotvec(chi[s, :3])), C)
        Y[s, :3] = C.T @ DOWN
        if use_mag:
            Y[s, 3:] = C.T @ mag_reference
    y_mean = np.zeros(m_dim)
    for s in range(2 * L + 1):
        y_mean += wm[s] * Y[s]
    Pyy = R.copy()
    Pxy = np.zeros((L, m_dim))
    for s in range(2 * L + 1):
        d = Y[s] - y_mean
        Pyy += wc[s] * np.outer(d, d)
        Pxy += wc[s] * np.outer(chi[s], d)
    innovation = y - y_mean
    for i in range(m_dim):
        if not active[i]:
            innovation[i] = 0.0
    K = Pxy @ np.linalg.inv(Pyy)
    dx = K @ innovation
    if not use_acc:
        for r in range(L):
            for c in range(3):
                K[r, c] = 0.0
        dx = K @ innovation
    P = P - K @ Pyy @ K.T
    P = 0.5 * (P + P.T)
    q = quat_mul(q, quat_from_rotvec(dx[:3]))
    quat_normalise(q)
    return q, b + dx[3:], P


@njit(cache=True)
def ukf(t, gyro, accel, mag, mag_reference, q0, b0, P0, gyro_noise, bias_walk, accel_sigma, mag_sigma,
        accel_gate, use_mag, alpha, beta, kappa, rate_gate):
    """Run the attitude UKF; inputs and outputs as :func:`georef.attitude.mekf.mekf`."""
    n = t.shape[0]
    quats = np.empty((n, 4))
    biases = np.empty((n, 3))
    sigmas = np.empty((n, 6))
    lam, wm, wc = _weights(alpha, beta, kappa)
    q = q0.copy()
    b = b0.copy()
    P = P0.copy()
    C = np.empty((3, 3))
    m_dim = 6 if use_mag else 3
    for k in range(n):
        if k > 0:
            dt = t[k] - t[k - 1]
            w = 0.5 * (gyro[k] + gyro[k - 1])
            q, b, P = _predict(q, b, P, w, dt, lam, wm, wc, gyro_noise, bias_walk)
        norm_f = math.sqrt(accel[k, 0] ** 2 + accel[k, 1] ** 2 + accel[k, 2] ** 2)
        rate = math.sqrt(gyro[k, 0] ** 2 + gyro[k, 1] ** 2 + gyro[k, 2] ** 2)
        use_acc = abs(norm_f - GRAVITY) < accel_gate and rate < rate_gate
        if use_acc or use_mag:
            y, R, active = _measurement(accel, mag, k, norm_f, use_acc, use_mag, accel_sigma, mag_sigma, m_dim)
            q, b, P = _update(q, b, P, y, R, active, use_acc, use_mag, mag_reference, lam, wm, wc, C)
        quats[k] = q
        biases[k] = b
        for i in range(6):
            sigmas[k, i] = math.sqrt(max(P[i, i], 0.0))
    return quats, biases, sigmas


def run_ukf(t: np.ndarray, gyro: np.ndarray, accel: np.ndarray, mag: np.ndarray | None = None,
            mag_reference: np.ndarray | None = None, gyro_noise: float = 0.01, bias_walk: float = 1e-4,
            accel_sigma: float = 0.01, mag_sigma: float = 0.02, accel_gate: float = 0.5,
            initial_bias_sigma: float = 0.2, alpha: float = 0.01, beta: float = 2.0,
            kappa: float = 0.0, rate_gate: float = np.inf) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Attitude UKF with TRIAD start; returns ``C_b_n`` (N, 3, 3), gyro biases (N, 3), error sigmas (N, 6)."""
    t, gyro, accel, mag, mag_reference, q0, P0, use_mag = initial_state(t, gyro, accel, mag, mag_reference,
                                                                        initial_bias_sigma)
    quats, biases, sigmas = load_kernel("ukf").ukf(t, gyro, accel, mag, mag_reference, q0, np.zeros(3), P0,
                                                   gyro_noise, bias_walk, accel_sigma, mag_sigma, accel_gate, use_mag,
                                                   alpha, beta, kappa, rate_gate)
    return quats_to_dcm(quats), biases, sigmas
