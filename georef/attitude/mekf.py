"""Multiplicative EKF for attitude (reference 000, rederived): quaternion + gyro bias, TRIAD start.

* Nominal state: ``q`` (body-to-NED, Hamilton scalar first) and gyro bias ``b`` [rad/s].
* Error state (6): ``δθ`` with ``q_true = q̂ ⊗ q(δθ)`` (body-frame rotation) and ``δb = b_true - b̂``.
* Propagation with the mean of consecutive rates, ``ω̄ = (ω_k + ω_{k-1})/2 - b̂``, ``q ← q ⊗ q(ω̄ Δt)``;
  ``F = [[R(ω̄ Δt)ᵀ, -I Δt], [0, I]]``, ``Q = diag(σ_g² Δt² I, σ_b² Δt I)``.
* Measurements: unit vectors in the body frame of known NED references ``r`` — gravity down ``[0, 0, 1]``
  from ``-f/|f|`` and the magnetic field ``[cos I, 0, sin I]`` from ``m/|m|``. Model ``h = Ĉᵀ r``; since
  ``C_true = Ĉ (I + [δθ x])``, ``H = [[(Ĉᵀ r) x], 0]`` (derived here; the printed Jacobians of reference 000
  are copy errors). The accelerometer's variance is inflated when ``|f|`` departs from g (linear acceleration).
* Update ``P = P⁻ - K S Kᵀ``; inject ``q ← q ⊗ q(δθ)``, ``b ← b + δb``; reset.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from georef.frames.kernels import cross, quat_from_rotvec, quat_mul, quat_normalise, quat_to_dcm

GRAVITY = 9.81
DOWN = np.array([0.0, 0.0, 1.0])


def triad(accel: np.ndarray, mag: np.ndarray, mag_reference: np.ndarray) -> np.ndarray:
    """``C_b_n`` from one specific-force and one magnetometer sample (TRIAD, gravity as the primary vector)."""
    def frame(v1: np.ndarray, v2: np.ndarray) -> np.ndarray:
        t1 = v1 / np.linalg.norm(v1)
        t2 = np.cross(t1, v2)
        t2 /= np.linalg.norm(t2)
        return np.stack([t1, t2, np.cross(t1, t2)], axis=-1)

    body = frame(-np.asarray(accel, float), np.asarray(mag, float))
    nav = frame(DOWN, np.asarray(mag_reference, float))
    return nav @ body.T


@njit(cache=True)
def vector_measurement(q: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Predicted body-frame unit vector ``Ĉᵀ r`` of a NED reference ``r``."""
    C = np.empty((3, 3))
    quat_to_dcm(q, C)
    return C.T @ reference


@njit(cache=True)
def vector_jacobian(q: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """d(Cᵀ r)/d(δθ, δb) = [[(Ĉᵀ r) x], 0] (3 x 6)."""
    v = vector_measurement(q, reference)
    H = np.zeros((3, 6))
    H[0, 1], H[0, 2] = -v[2], v[1]
    H[1, 0], H[1, 2] = v[2], -v[0]
    H[2, 0], H[2, 1] = -v[1], v[0]
    return H


@njit(cache=True)
def _rotation(v: np.ndarray) -> np.ndarray:
    C = np.empty((3, 3))
    quat_to_dcm(quat_from_rotvec(v), C)
    return C


@njit(cache=True)
def _update(q, b, P, y, reference, variance):
    """One vector measurement update; returns the normalised innovation squared."""
    H = vector_jacobian(q, reference)
    z = y - vector_measurement(q, reference)
    S = H @ P @ H.T + variance * np.eye(3)
    K = P @ H.T @ np.linalg.inv(S)
    dx = K @ z
    P[:, :] = P - K @ S @ K.T
    P[:, :] = 0.5 * (P + P.T)
    q[:] = quat_mul(q, quat_from_rotvec(dx[:3]))
    quat_normalise(q)
    for i in range(3):
        b[i] += dx[3 + i]
    return z @ np.linalg.solve(S, z)


@njit(cache=True)
def mekf(t, gyro, accel, mag, mag_reference, q0, b0, P0, gyro_noise, bias_walk, accel_sigma, mag_sigma,
         accel_gate, use_mag):
    """Run the MEKF over all samples.

    ``gyro`` rad/s, ``accel`` m/s^2, ``mag`` any unit (normalised), (N, 3); ``gyro_noise`` [rad/s] per sample,
    ``bias_walk`` [rad/s/sqrt(s)], ``accel_sigma``/``mag_sigma`` unit-vector noise [-]; accelerometer updates
    are skipped when ``| |f| - g | > accel_gate`` [m/s^2]. Returns quaternions (N, 4), biases (N, 3) and the
    error-state standard deviations (N, 6).
    """
    n = t.shape[0]
    quats = np.empty((n, 4))
    biases = np.empty((n, 3))
    sigmas = np.empty((n, 6))
    q = q0.copy()
    b = b0.copy()
    P = P0.copy()
    F = np.eye(6)
    Q = np.zeros((6, 6))
    y = np.empty(3)
    for k in range(n):
        if k > 0:
            dt = t[k] - t[k - 1]
            w = 0.5 * (gyro[k] + gyro[k - 1]) - b
            step = w * dt
            R = _rotation(step)
            for i in range(3):
                for j in range(3):
                    F[i, j] = R[j, i]
                F[i, 3 + i] = -dt
                Q[i, i] = gyro_noise * gyro_noise * dt * dt
                Q[3 + i, 3 + i] = bias_walk * bias_walk * dt
            q = quat_mul(q, quat_from_rotvec(step))
            quat_normalise(q)
            P = F @ P @ F.T + Q
        norm_f = math.sqrt(accel[k, 0] ** 2 + accel[k, 1] ** 2 + accel[k, 2] ** 2)
        if abs(norm_f - GRAVITY) < accel_gate:
            for i in range(3):
                y[i] = -accel[k, i] / norm_f
            _update(q, b, P, y, DOWN, accel_sigma * accel_sigma)
        if use_mag:
            norm_m = math.sqrt(mag[k, 0] ** 2 + mag[k, 1] ** 2 + mag[k, 2] ** 2)
            if norm_m > 0.0:
                for i in range(3):
                    y[i] = mag[k, i] / norm_m
                _update(q, b, P, y, mag_reference, mag_sigma * mag_sigma)
        quats[k] = q
        biases[k] = b
        for i in range(6):
            sigmas[k, i] = math.sqrt(max(P[i, i], 0.0))
    return quats, biases, sigmas


def run_mekf(t: np.ndarray, gyro: np.ndarray, accel: np.ndarray, mag: np.ndarray | None = None,
             mag_reference: np.ndarray | None = None, gyro_noise: float = 0.01, bias_walk: float = 1e-4,
             accel_sigma: float = 0.01, mag_sigma: float = 0.02, accel_gate: float = 0.5,
             initial_bias_sigma: float = 0.2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """MEKF with TRIAD initialisation (or accelerometer levelling and yaw 0 without a magnetometer).

    Returns ``C_b_n`` (N, 3, 3), gyro biases (N, 3) [rad/s] and error sigmas (N, 6) [rad, rad/s].
    """
    from georef.frames import dcm_to_quat, euler_to_dcm, quat_to_dcm
    from georef.attitude.tilt import accel_tilt

    t = np.ascontiguousarray(t, float)
    gyro = np.ascontiguousarray(gyro, float)
    accel = np.ascontiguousarray(accel, float)
    use_mag = mag is not None
    if use_mag:
        if mag_reference is None:
            raise ValueError("a magnetometer needs its NED reference direction (mag_reference)")
        C0 = triad(accel[0], mag[0], mag_reference)
        mag = np.ascontiguousarray(mag, float)
        yaw_sigma = 0.1
    else:
        roll, pitch = accel_tilt(accel[:1])
        C0 = euler_to_dcm(roll[0], pitch[0], 0.0)
        mag = np.zeros((1, 3))
        mag_reference = np.array([1.0, 0.0, 0.0])
        yaw_sigma = 1e-6  # unobservable without a magnetometer: hold the arbitrary origin
    P0 = np.diag([0.05**2, 0.05**2, yaw_sigma**2] + [initial_bias_sigma**2] * 3)
    quats, biases, sigmas = mekf(t, gyro, accel, mag, np.asarray(mag_reference, float), dcm_to_quat(C0),
                                 np.zeros(3), P0, gyro_noise, bias_walk, accel_sigma, mag_sigma, accel_gate, use_mag)
    return quat_to_dcm(quats), biases, sigmas
