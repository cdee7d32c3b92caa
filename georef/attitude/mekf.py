"""Multiplicative EKF for attitude ([A1] in ``docs/attitude.md``, rederived): quaternion + gyro bias, TRIAD start.

* Nominal state: ``q`` (body-to-NED, Hamilton scalar first) and gyro bias ``b`` [rad/s].
* Error state (6): ``δθ`` with ``q_true = q̂ ⊗ q(δθ)`` (body-frame rotation) and ``δb = b_true - b̂``.
* Propagation with the mean of consecutive rates, ``ω̄ = (ω_k + ω_{k-1})/2 - b̂``, ``q ← q ⊗ q(ω̄ Δt)``;
  ``F = [[R(ω̄ Δt)ᵀ, -I Δt], [0, I]]``, ``Q = diag(σ_g² Δt² I, σ_b² Δt I)``.
* Measurements: unit vectors in the body frame of known NED references ``r`` — gravity down ``[0, 0, 1]``
  from ``-f/|f|`` and the magnetic field ``[cos I, 0, sin I]`` from ``m/|m|``. Model ``h = Ĉᵀ r``; since
  ``C_true = Ĉ (I + [δθ x])``, ``H = [[(Ĉᵀ r) x], 0]`` (derived here; the printed Jacobians of [A1] are copy
  errors). The accelerometer's variance is inflated when ``|f|`` departs from g (linear acceleration).
* Update ``P = P⁻ - K S Kᵀ``; inject ``q ← q ⊗ q(δθ)``, ``b ← b + δb``; reset.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from georef.aot import load as load_kernel
from georef.attitude.tilt import accel_tilt
from georef.frames import STANDARD_GRAVITY, dcm_to_quat, euler_to_dcm
from georef.frames import quat_to_dcm as quats_to_dcm
from georef.frames.kernels import (
    add_skew,
    quat_from_rotvec_into,
    quat_mul_into,
    quat_normalise,
    quat_to_dcm,
    trapezoid_increment,
)

#: the specific-force magnitude [m/s^2] an unaccelerated IMU reads, against which the accelerometer gate is set
GRAVITY = STANDARD_GRAVITY
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
def _measurement_into(C: np.ndarray, reference: np.ndarray, v: np.ndarray, H: np.ndarray) -> None:
    """The vector measurement at attitude ``C`` (= C_b_n): its prediction ``v = Cᵀ r`` (3,) of the NED
    reference ``r`` and the attitude block ``H = [v x]`` (3, 3) of its Jacobian (the bias block is zero)."""
    for i in range(3):
        v[i] = C[0, i] * reference[0] + C[1, i] * reference[1] + C[2, i] * reference[2]
    H[:, :] = 0.0
    add_skew(v, H, 0, 0, 1.0)


@njit(cache=True)
def vector_measurement(q: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Predicted body-frame unit vector ``Ĉᵀ r`` of a NED reference ``r``."""
    C = np.empty((3, 3))
    quat_to_dcm(q, C)
    v = np.empty(3)
    _measurement_into(C, reference, v, np.empty((3, 3)))
    return v


@njit(cache=True)
def vector_jacobian(q: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """d(Cᵀ r)/d(δθ, δb) = [[(Ĉᵀ r) x], 0] (3 x 6), as :func:`_update` builds it."""
    C = np.empty((3, 3))
    quat_to_dcm(q, C)
    H = np.zeros((3, 6))
    _measurement_into(C, reference, np.empty(3), H[:, :3])
    return H


@njit(cache=True, inline="always")
def _inv3(S: np.ndarray, out: np.ndarray) -> None:
    a, b, c = S[0, 0], S[0, 1], S[0, 2]
    d, e, f = S[1, 0], S[1, 1], S[1, 2]
    g, h, i = S[2, 0], S[2, 1], S[2, 2]
    det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
    out[0, 0], out[0, 1], out[0, 2] = (e * i - f * h) / det, (c * h - b * i) / det, (b * f - c * e) / det
    out[1, 0], out[1, 1], out[1, 2] = (f * g - d * i) / det, (a * i - c * g) / det, (c * d - a * f) / det
    out[2, 0], out[2, 1], out[2, 2] = (d * h - e * g) / det, (b * g - a * h) / det, (a * e - b * d) / det


@njit(cache=True)
def _update(q, b, P, y, reference, variance, C, H, S, S_inv, K, PHt, v, dq, work):
    """One vector-measurement update in place, with preallocated work arrays (no allocation per step): ``v`` (3,)
    holds the prediction, then the attitude correction; ``dq``, ``work`` (4,) the quaternion product."""
    quat_to_dcm(q, C)
    # H = [[v x], 0]: only the first three columns are non-zero, held in H (3, 3)
    _measurement_into(C, reference, v, H)
    z0, z1, z2 = y[0] - v[0], y[1] - v[1], y[2] - v[2]
    for r in range(6):
        for c in range(3):
            PHt[r, c] = P[r, 0] * H[c, 0] + P[r, 1] * H[c, 1] + P[r, 2] * H[c, 2]
    for r in range(3):
        for c in range(3):
            S[r, c] = H[r, 0] * PHt[0, c] + H[r, 1] * PHt[1, c] + H[r, 2] * PHt[2, c]
        S[r, r] += variance
    _inv3(S, S_inv)
    for r in range(6):
        for c in range(3):
            K[r, c] = PHt[r, 0] * S_inv[0, c] + PHt[r, 1] * S_inv[1, c] + PHt[r, 2] * S_inv[2, c]
    # P -= K S K^T = K PHt^T (since S K^T = PHt^T)
    for r in range(6):
        for c in range(r, 6):
            value = P[r, c] - (K[r, 0] * PHt[c, 0] + K[r, 1] * PHt[c, 1] + K[r, 2] * PHt[c, 2])
            P[r, c] = value
            P[c, r] = value
    for i in range(3):
        v[i] = K[i, 0] * z0 + K[i, 1] * z1 + K[i, 2] * z2  # the attitude correction δθ
        b[i] += K[3 + i, 0] * z0 + K[3 + i, 1] * z1 + K[3 + i, 2] * z2
    _right_multiply(q, v, dq, work)


@njit(cache=True)
def _right_multiply(q: np.ndarray, rotvec: np.ndarray, dq: np.ndarray, work: np.ndarray) -> None:
    """q ← normalise(q ⊗ q(rotvec)) for a body rotation vector [rad] (3,), in place; ``dq``, ``work`` (4,)."""
    quat_from_rotvec_into(rotvec, dq)
    quat_mul_into(q, dq, work)
    quat_normalise(work)
    q[:] = work


@njit(cache=True)
def _propagate_covariance(P, R, dt, gyro_noise, bias_walk, A, C):
    """The error covariance (6, 6) over one step, in place: ``F = [[R^T, -dt I], [0, I]]`` with ``R`` the step's
    rotation, plus the gyro noise [rad/s] per sample and the bias walk [rad/s/sqrt(s)] over ``dt`` [s]; ``A``,
    ``C`` (3, 3): work arrays."""
    # P_aa' = R^T P_aa R - dt (R^T P_ab + P_ba R) + dt^2 P_bb ; P_ab' = R^T P_ab - dt P_bb
    for i in range(3):
        for j in range(3):
            A[i, j] = R[0, i] * P[0, j] + R[1, i] * P[1, j] + R[2, i] * P[2, j] - dt * P[3 + i, j]
    for i in range(3):
        for j in range(3):
            P_ab = R[0, i] * P[0, 3 + j] + R[1, i] * P[1, 3 + j] + R[2, i] * P[2, 3 + j] - dt * P[3 + i, 3 + j]
            C[i, j] = P_ab  # temporarily hold the new cross block
    for i in range(3):
        for j in range(i, 3):
            value = (A[i, 0] * R[0, j] + A[i, 1] * R[1, j] + A[i, 2] * R[2, j]) - dt * C[i, j]
            if i == j:
                value += gyro_noise * gyro_noise * dt * dt
            P[i, j] = value
            P[j, i] = value
    for i in range(3):
        for j in range(3):
            P[i, 3 + j] = C[i, j]
            P[3 + j, i] = C[i, j]
        P[3 + i, 3 + i] += bias_walk * bias_walk * dt


@njit(cache=True)
def mekf(t, gyro, accel, mag, mag_reference, q0, b0, P0, gyro_noise, bias_walk, accel_sigma, mag_sigma,
         accel_gate, use_mag, rate_gate):
    """Run the MEKF over all samples (no allocation inside the loop).

    ``gyro`` rad/s, ``accel`` m/s^2, ``mag`` any unit (normalised), (N, 3); ``gyro_noise`` [rad/s] per sample,
    ``bias_walk`` [rad/s/sqrt(s)], ``accel_sigma``/``mag_sigma`` unit-vector noise [-]; accelerometer updates
    are skipped when ``| |f| - g | > accel_gate`` [m/s^2] or the rotation rate exceeds ``rate_gate`` [rad/s]
    (turns, where the apparent vertical is not gravity). Returns quaternions (N, 4), biases (N, 3) and the
    error-state standard deviations (N, 6).
    """
    n = t.shape[0]
    quats = np.empty((n, 4))
    biases = np.empty((n, 3))
    sigmas = np.empty((n, 6))
    q = q0.copy()
    b = b0.copy()
    P = P0.copy()
    R = np.empty((3, 3))
    A = np.empty((3, 3))
    y = np.empty(3)
    C = np.empty((3, 3))
    H = np.empty((3, 3))
    S = np.empty((3, 3))
    S_inv = np.empty((3, 3))
    K = np.empty((6, 3))
    PHt = np.empty((6, 3))
    v = np.empty(3)
    step = np.empty(3)
    dq = np.empty(4)
    work = np.empty(4)
    for k in range(n):
        if k > 0:
            dt = t[k] - t[k - 1]
            trapezoid_increment(gyro[k - 1], gyro[k], b, dt, step)
            # R(step); F = [[R^T, -dt I], [0, I]]
            quat_from_rotvec_into(step, dq)
            quat_to_dcm(dq, R)
            _propagate_covariance(P, R, dt, gyro_noise, bias_walk, A, C)
            _right_multiply(q, step, dq, work)
        norm_f = math.sqrt(accel[k, 0] ** 2 + accel[k, 1] ** 2 + accel[k, 2] ** 2)
        rate = math.sqrt(gyro[k, 0] ** 2 + gyro[k, 1] ** 2 + gyro[k, 2] ** 2)
        if abs(norm_f - GRAVITY) < accel_gate and rate < rate_gate:
            for i in range(3):
                y[i] = -accel[k, i] / norm_f
            _update(q, b, P, y, DOWN, accel_sigma * accel_sigma, C, H, S, S_inv, K, PHt, v, dq, work)
        if use_mag:
            norm_m = math.sqrt(mag[k, 0] ** 2 + mag[k, 1] ** 2 + mag[k, 2] ** 2)
            if norm_m > 0.0:
                for i in range(3):
                    y[i] = mag[k, i] / norm_m
                _update(q, b, P, y, mag_reference, mag_sigma * mag_sigma, C, H, S, S_inv, K, PHt, v, dq, work)
        quats[k] = q
        biases[k] = b
        for i in range(6):
            sigmas[k, i] = math.sqrt(max(P[i, i], 0.0))
    return quats, biases, sigmas


def initial_state(t: np.ndarray, gyro: np.ndarray, accel: np.ndarray, mag: np.ndarray | None,
                  mag_reference: np.ndarray | None, initial_bias_sigma: float) -> tuple:
    """Contiguous inputs, the starting quaternion and error covariance of the MEKF and the UKF.

    TRIAD with a magnetometer; without one, accelerometer levelling and yaw 0 held fixed (unobservable).
    """
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
        mag, mag_reference, yaw_sigma = np.zeros((1, 3)), np.array([1.0, 0.0, 0.0]), 1e-6
    P0 = np.diag([0.05**2, 0.05**2, yaw_sigma**2] + [initial_bias_sigma**2] * 3)
    return t, gyro, accel, mag, np.asarray(mag_reference, float), dcm_to_quat(C0), P0, use_mag


def run_mekf(t: np.ndarray, gyro: np.ndarray, accel: np.ndarray, mag: np.ndarray | None = None,
             mag_reference: np.ndarray | None = None, gyro_noise: float = 0.01, bias_walk: float = 1e-4,
             accel_sigma: float = 0.01, mag_sigma: float = 0.02, accel_gate: float = 0.5,
             initial_bias_sigma: float = 0.2, rate_gate: float = np.inf) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """MEKF with TRIAD initialisation (or accelerometer levelling and yaw 0 without a magnetometer).

    Returns ``C_b_n`` (N, 3, 3), gyro biases (N, 3) [rad/s] and error sigmas (N, 6) [rad, rad/s].
    """
    t, gyro, accel, mag, mag_reference, q0, P0, use_mag = initial_state(t, gyro, accel, mag, mag_reference,
                                                                        initial_bias_sigma)
    quats, biases, sigmas = load_kernel("mekf").mekf(t, gyro, accel, mag, mag_reference, q0, np.zeros(3), P0,
                                                     gyro_noise, bias_walk, accel_sigma, mag_sigma, accel_gate,
                                                     use_mag, rate_gate)
    return quats_to_dcm(quats), biases, sigmas
