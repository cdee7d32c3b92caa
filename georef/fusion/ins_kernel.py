"""Compiled loosely coupled INS/GNSS error-state EKF, its RTS smoother, and the noise statistics of an EM step.

Layouts: :mod:`georef.fusion.ins_layout` (named indices, one order for the error and the nominal state).

The forward filter (:func:`ekf_forward`) mechanises every IMU row and propagates the covariance at *covariance
epochs* (every ``stride`` rows and at every update): :func:`propagate` builds F at the epoch's mean attitude and
specific force and discretises it to third order. At an epoch it may fuse the unit's attitude
(:func:`unit_attitude_innovation`), GNSS fixes (:func:`gnss_innovation`), a ground vehicle's non-holonomic
constraint and a still vehicle's zero velocity and rate, each through the one chi-square-gated update
(:func:`gated_update`), and feeds the correction back (closed loop). The pass is written as step functions
(:func:`_strapdown_row`, :func:`_propagate_to`, the updates, :func:`_close_epoch`) over named records
(:class:`ForwardRecords`), scratch (:class:`Scratch`) and counters. When OPT_MAX_REJECTS fixes in a row are
rejected it stops and reports the first of them, so that the caller can re-align there (divergence recovery).

The smoother (:func:`rts_backward`) runs over the epochs of one or more filter segments and, when asked, adds up
for every noise block the statistics of an expectation-maximisation step (Shumway & Stoffer 1982): the smoothed
process-noise and measurement residuals normalised by their modelled covariance, and the trace terms of their
posterior covariance.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from georef.frames.earth import OMEGA_IE
from georef.frames.kernels import (
    add_skew,
    cross,
    dcm_to_euler,
    earth_rate,
    euler_error_jacobian,
    gravity_gradient,
    lat_lon_to_ned,
    lever_arm_into,
    ned_to_lat_lon,
    quat_from_rotvec,
    quat_mul,
    quat_normalise,
    quat_to_dcm,
    radii,
    transport_rate,
)
from georef.fusion.ins_layout import (
    ATT,
    AUX_NHC,
    AUX_UNIT,
    AUX_ZARU,
    AUX_ZUPT,
    B_ATT_H,
    B_ATT_V,
    B_BA,
    B_BG,
    B_GNSS_GM_H,
    B_GNSS_GM_V,
    B_GNSS_H,
    B_GNSS_V,
    B_NHC,
    B_OUTAGE,
    B_UNIT_DRIFT,
    B_UNIT_LEVEL,
    B_UNIT_R_LEVEL,
    B_UNIT_R_YAW,
    B_VEL_H,
    B_VEL_V,
    BA,
    BG,
    DRIFT_REJECTS,
    DRIFT_WINDOW,
    FIX_REJECTED,
    FIX_UNUSED,
    FIX_USED,
    GAP_STEP_S,
    GNSS_GM,
    INV_TAU_A,
    INV_TAU_G,
    INV_TAU_GNSS,
    INV_TAU_UNIT,
    LATENCY,
    LEVER,
    N_BLOCKS,
    NHC_GATE,
    NHC_LEVER,
    OPT_GATE,
    OPT_MAX_GAP,
    OPT_MAX_REJECTS,
    OPT_NHC,
    OPT_OUTAGE_S,
    OPT_STRIDE,
    OPT_UNIT_AIDING,
    POS,
    Q_ATT_H,
    Q_ATT_V,
    Q_BA,
    Q_BG,
    Q_GNSS_GM_H,
    Q_GNSS_GM_V,
    Q_UNIT_DRIFT,
    Q_UNIT_LEVEL,
    Q_VEL_H,
    Q_VEL_V,
    R_NHC,
    R_SCALE_H,
    R_SCALE_V,
    R_UNIT_LEVEL,
    R_UNIT_YAW,
    R_ZARU,
    R_ZUPT,
    REACQUIRE_FIXES,
    REACQUIRE_GATE,
    STEP_S,
    STOP_DIVERGED,
    STOP_DRIFT,
    STOP_END,
    STOP_GAP,
    UNIT_DRIFT,
    UNIT_LEVEL,
    UNIT_YAW,
    VEL,
    X_BA,
    X_BG,
    X_GNSS_GM,
    X_HGT,
    X_LAT,
    X_LATENCY,
    X_LEVER,
    X_LON,
    X_QUAT,
    X_UNIT_DRIFT,
    X_UNIT_LEVEL,
    X_UNIT_YAW,
    X_VEL,
    ZUPT_GATE,
)
from georef.fusion.strapdown import (
    MECHANISE_WORK,
    increments,
    mechanise_into,
    two_sample_corrections,  # noqa: F401  (exported by the "ins" kernel, georef/aot.py)
)


@njit(cache=True)
def continuous_noise(noise: np.ndarray, nx: int, nav_scale: float, bias_scale: float) -> np.ndarray:
    """Diagonal of the continuous-time process-noise density (nx,) from the noise vector; the white specific
    force and angular rate scaled by ``nav_scale``, the bias and unit-error drives by ``bias_scale``."""
    q = np.zeros(nx)
    for i in range(2):
        q[VEL + i] = noise[Q_VEL_H] * nav_scale
        q[ATT + i] = noise[Q_ATT_H] * nav_scale
        q[UNIT_LEVEL + i] = noise[Q_UNIT_LEVEL] * bias_scale
    q[VEL + 2] = noise[Q_VEL_V] * nav_scale
    q[ATT + 2] = noise[Q_ATT_V] * nav_scale
    for i in range(3):
        q[BG + i] = noise[Q_BG] * bias_scale
        q[BA + i] = noise[Q_BA] * bias_scale
    q[UNIT_DRIFT] = noise[Q_UNIT_DRIFT] * bias_scale
    # the receiver's correlated error does not change with the vehicle's dynamics: no scale
    q[GNSS_GM] = noise[Q_GNSS_GM_H]
    q[GNSS_GM + 1] = noise[Q_GNSS_GM_H]
    q[GNSS_GM + 2] = noise[Q_GNSS_GM_V]
    return q


@njit(cache=True)
def system_matrix(x: np.ndarray, C: np.ndarray, f_n: np.ndarray, noise: np.ndarray, F: np.ndarray) -> None:
    """Continuous-time error dynamics into ``F`` (nx, nx) at nominal state ``x`` with C_b_n and f_n [m/s^2].

    Blocks as in Shin (2005) / KF-GINS: position in local metres, the phi-angle attitude model; the gravity
    gradient, Earth rate and transport rate from :mod:`georef.frames.kernels`.
    """
    F[:, :] = 0.0
    _position_velocity_rows(x, f_n, F)
    # biases: the mechanisation subtracts the estimated bias, so f_est - f = -C db_a, w_est - w = -db_g
    for i in range(3):
        for j in range(3):
            F[VEL + i, BA + j] = -C[i, j]
            F[ATT + i, BG + j] = C[i, j]
    _attitude_rows(x, F)
    _random_process_rows(noise, F)


@njit(cache=True)
def _position_velocity_rows(x: np.ndarray, f_n: np.ndarray, F: np.ndarray) -> None:
    """The position and velocity error rows of F against position, velocity and attitude (f_n [m/s^2])."""
    lat, h = x[X_LAT], x[X_HGT]
    vn, ve, vd = x[X_VEL], x[X_VEL + 1], x[X_VEL + 2]
    M, N = radii(lat)
    Mh, Nh = M + h, N + h
    tl = math.tan(lat)
    sl, cl = math.sin(lat), math.cos(lat)
    w = OMEGA_IE
    # position
    F[POS, POS] = -vd / Mh
    F[POS, POS + 2] = vn / Mh
    F[POS + 1, POS] = ve * tl / Nh
    F[POS + 1, POS + 1] = -(vd + vn * tl) / Nh
    F[POS + 1, POS + 2] = ve / Nh
    for i in range(3):
        F[POS + i, VEL + i] = 1.0
    # velocity
    F[VEL, POS] = -2.0 * ve * w * cl / Mh - ve * ve / (Mh * Nh * cl * cl)
    F[VEL, POS + 2] = vn * vd / Mh**2 - ve * ve * tl / Nh**2
    F[VEL + 1, POS] = 2.0 * w * (vn * cl - vd * sl) / Mh + vn * ve / (Mh * Nh * cl * cl)
    F[VEL + 1, POS + 2] = (ve * vd + vn * ve * tl) / Nh**2
    F[VEL + 2, POS] = 2.0 * w * ve * sl / Mh
    F[VEL + 2, POS + 2] = -ve * ve / Nh**2 - vn * vn / Mh**2 + gravity_gradient(lat, h)[1]
    F[VEL, VEL] = vd / Mh
    F[VEL, VEL + 1] = -2.0 * (w * sl + ve * tl / Nh)
    F[VEL, VEL + 2] = vn / Mh
    F[VEL + 1, VEL] = 2.0 * w * sl + ve * tl / Nh
    F[VEL + 1, VEL + 1] = (vd + vn * tl) / Nh
    F[VEL + 1, VEL + 2] = 2.0 * w * cl + ve / Nh
    F[VEL + 2, VEL] = -2.0 * vn / Mh
    F[VEL + 2, VEL + 1] = -2.0 * (w * cl + ve / Nh)
    add_skew(f_n, F, VEL, ATT, 1.0)


@njit(cache=True)
def _attitude_rows(x: np.ndarray, F: np.ndarray) -> None:
    """The attitude error rows of F against position, velocity and attitude (the navigation frame's rotation)."""
    lat, h = x[X_LAT], x[X_HGT]
    vn, ve = x[X_VEL], x[X_VEL + 1]
    M, N = radii(lat)
    Mh, Nh = M + h, N + h
    tl = math.tan(lat)
    sl, cl = math.sin(lat), math.cos(lat)
    w = OMEGA_IE
    w_ie = np.empty(3)
    earth_rate(lat, w_ie)
    F[ATT, POS] = -w * sl / Mh
    F[ATT, POS + 2] = ve / Nh**2
    F[ATT + 1, POS + 2] = -vn / Mh**2
    F[ATT + 2, POS] = -w * cl / Mh - ve / (Mh * Nh * cl * cl)
    F[ATT + 2, POS + 2] = -ve * tl / Nh**2
    F[ATT, VEL + 1] = 1.0 / Nh
    F[ATT + 1, VEL] = -1.0 / Mh
    F[ATT + 2, VEL + 1] = -tl / Nh
    w_en = np.empty(3)
    transport_rate(lat, h, x[X_VEL:X_VEL + 3], w_en)
    add_skew(w_ie + w_en, F, ATT, ATT, -1.0)


@njit(cache=True)
def _random_process_rows(noise: np.ndarray, F: np.ndarray) -> None:
    """The Gauss-Markov and random-walk rows of F: the IMU biases, the unit's attitude errors (Gauss-Markov roll
    and pitch, a yaw origin with a drift rate) and the correlated GNSS error."""
    for i in range(3):
        F[BG + i, BG + i] = -noise[INV_TAU_G]
        F[BA + i, BA + i] = -noise[INV_TAU_A]
    F[UNIT_LEVEL, UNIT_LEVEL] = -noise[INV_TAU_UNIT]
    F[UNIT_LEVEL + 1, UNIT_LEVEL + 1] = -noise[INV_TAU_UNIT]
    F[UNIT_YAW, UNIT_DRIFT] = 1.0
    for i in range(3):
        F[GNSS_GM + i, GNSS_GM + i] = -noise[INV_TAU_GNSS]


@njit(cache=True)
def discretise(F: np.ndarray, q: np.ndarray, dT: float, Phi: np.ndarray, Qd: np.ndarray,
               work: np.ndarray) -> None:
    """Transition matrix and process-noise covariance of an interval ``dT`` [s], to third order in ``F dT``.

    ``Φ = I + A + A²/2 + A³/6`` with ``A = F dT``; ``Q_d = ∫ Φ(s) diag(q) Φ(s)ᵀ ds`` by its Taylor series
    ``Q dT + (FQ + QFᵀ) dT²/2 + (F²Q + 2FQFᵀ + QF²ᵀ) dT³/6`` (exact for the double integrator of white
    specific force, and it carries attitude noise into velocity over long intervals). ``work`` (5, n, n) holds
    A, A², A³, F diag(q) and F diag(q) Fᵀ (no allocation: this runs at every covariance epoch).
    """
    n = F.shape[0]
    A, A2, A3, FQ, FQF = work[0], work[1], work[2], work[3], work[4]
    for i in range(n):
        for j in range(n):
            A[i, j] = F[i, j] * dT
            FQ[i, j] = F[i, j] * q[j]  # F diag(q): columns scaled
    np.dot(A, A, A2)
    np.dot(A2, A, A3)
    np.dot(FQ, F.T, FQF)
    for i in range(n):
        for j in range(n):
            Phi[i, j] = A[i, j] + 0.5 * A2[i, j] + A3[i, j] / 6.0
            F2Q = A2[i, j] * q[j] / (dT * dT)
            F2Qt = A2[j, i] * q[i] / (dT * dT)
            Qd[i, j] = ((FQ[i, j] + FQ[j, i]) * dT * dT / 2.0
                        + (F2Q + F2Qt + 2.0 * FQF[i, j]) * dT * dT * dT / 6.0)
        Phi[i, i] += 1.0
        Qd[i, i] += q[i] * dT


@njit(cache=True)
def correct_state(x: np.ndarray, dx: np.ndarray) -> None:
    """Remove the estimated error ``dx`` (estimate minus truth, NX_NAV or NX_CAL entries) from ``x`` in place."""
    d_lat, d_lon = ned_to_lat_lon(dx[POS], dx[POS + 1], x[X_LAT], x[X_HGT])
    x[X_LAT] -= d_lat
    x[X_LON] -= d_lon
    x[X_HGT] += dx[POS + 2]
    for i in range(3):
        x[X_VEL + i] -= dx[VEL + i]
        x[X_BG + i] -= dx[BG + i]
        x[X_BA + i] -= dx[BA + i]
    x[X_UNIT_LEVEL] -= dx[UNIT_LEVEL]
    x[X_UNIT_LEVEL + 1] -= dx[UNIT_LEVEL + 1]
    x[X_UNIT_YAW] -= dx[UNIT_YAW]
    x[X_UNIT_DRIFT] -= dx[UNIT_DRIFT]
    for i in range(3):
        x[X_GNSS_GM + i] -= dx[GNSS_GM + i]
    if dx.shape[0] > LEVER:
        for i in range(3):
            x[X_LEVER + i] -= dx[LEVER + i]
        x[X_LATENCY] -= dx[LATENCY]
    q = quat_mul(quat_from_rotvec(dx[ATT:ATT + 3]), x[X_QUAT:X_QUAT + 4])
    quat_normalise(q)
    x[X_QUAT:X_QUAT + 4] = q


@njit(cache=True)
def corrected(x: np.ndarray, dx: np.ndarray) -> np.ndarray:
    """A copy of the nominal state ``x`` with the error ``dx`` removed (see :func:`correct_state`)."""
    out = x.copy()
    correct_state(out, dx)
    return out


@njit(cache=True)
def propagate(P: np.ndarray, x_epoch: np.ndarray, C_mean: np.ndarray, f_mean: np.ndarray, noise: np.ndarray,
              dT: float, q_scale: np.ndarray, F: np.ndarray, Phi: np.ndarray, Qd: np.ndarray, work: np.ndarray,
              out: np.ndarray) -> None:
    """Covariance propagation over one epoch interval ``dT`` [s] with the process noise scaled by ``q_scale`` =
    (navigation white noise factor, bias drive factor); fills F, Φ and Q_d, writes P⁻ = Φ P Φᵀ + Q_d into ``out``
    (not ``P``). ``work`` (9, nx, nx): scratch.

    An interval longer than its step (:func:`propagation_steps`) is taken in equal steps with the same F and
    noise, Φ and Q_d composed: the third-order series of :func:`discretise` drops the dT⁵ term that carries
    attitude noise into position, and over a long interval with raised noise (an IMU gap bridged with the noise
    of unknown motion) the truncated Q_d, and P⁻ with it, stopped being positive semi-definite."""
    system_matrix(x_epoch, C_mean, f_mean, noise, F)
    q = continuous_noise(noise, P.shape[0], q_scale[0], q_scale[1])
    steps = propagation_steps(dT, q_scale[0])
    n = P.shape[0]
    PhiP = work[5]
    if steps == 1:
        discretise(F, q, dT, Phi, Qd, work)
    else:
        Phi_step, Qd_step, product = work[6], work[7], work[8]
        discretise(F, q, dT / steps, Phi_step, Qd_step, work)
        Phi[:, :] = Phi_step
        Qd[:, :] = Qd_step
        for _ in range(steps - 1):
            np.dot(Phi_step, Phi, product)
            Phi[:, :] = product
            np.dot(Phi_step, Qd, product)
            np.dot(product, Phi_step.T, PhiP)
            for i in range(n):
                for j in range(n):
                    Qd[i, j] = PhiP[i, j] + Qd_step[i, j]
    np.dot(Phi, P, PhiP)
    np.dot(PhiP, Phi.T, out)
    for i in range(n):
        for j in range(n):
            out[i, j] += Qd[i, j]


@njit(cache=True)
def propagation_steps(dT: float, nav_noise_scale: float) -> int:
    """How many equal steps an epoch interval of ``dT`` [s] is propagated in: steps of at most STEP_S, or
    GAP_STEP_S when the navigation noise is raised (an IMU gap)."""
    step = GAP_STEP_S if nav_noise_scale > 1.0 else STEP_S
    return max(1, int(math.ceil(dT / step - 1e-9)))


@njit(cache=True)
def unit_attitude_innovation(x: np.ndarray, C: np.ndarray, unit_rpy: np.ndarray, nx: int):
    """Innovation (predicted minus logged unit roll, pitch, yaw [rad]) and its H (3, nx).

    Model: ``roll_u = roll + e_r``, ``pitch_u = pitch + e_p``, ``yaw_u = yaw - d``.
    """
    roll, pitch, yaw = dcm_to_euler(C)
    z = np.empty(3)
    z[0] = roll + x[X_UNIT_LEVEL] - unit_rpy[0]
    z[1] = pitch + x[X_UNIT_LEVEL + 1] - unit_rpy[1]
    z[2] = yaw - x[X_UNIT_YAW] - unit_rpy[2]
    z[2] = (z[2] + math.pi) % (2.0 * math.pi) - math.pi
    H = np.zeros((3, nx))
    # Ĉ = exp(-[φ x]) C, so the estimated Euler angles exceed the true ones by -J φ
    J = euler_error_jacobian(C)
    for i in range(3):
        for j in range(3):
            H[i, ATT + j] = -J[i, j]
    H[0, UNIT_LEVEL] = 1.0
    H[1, UNIT_LEVEL + 1] = 1.0
    H[2, UNIT_YAW] = -1.0
    return z, H


@njit(cache=True)
def gnss_innovation(x: np.ndarray, C: np.ndarray, fix: np.ndarray, lag: float, nx: int):
    """Innovation (predicted minus measured antenna position, NED metres) and its H (3, nx).

    ``fix`` = (lat, lon [rad], h [m]); the fix was measured ``lag + latency`` seconds before the nominal
    state's time, so the prediction is moved back along the velocity. The predicted fix carries the estimated
    correlated GNSS error (GNSS_GM) on top of the antenna position.
    """
    lever_n = np.empty(3)
    lever_arm_into(C, x[X_LEVER:X_LEVER + 3], lever_n)
    back = lag + x[X_LATENCY]
    d_north, d_east = lat_lon_to_ned(x[X_LAT] - fix[0], x[X_LON] - fix[1], x[X_LAT], x[X_HGT])
    z = np.empty(3)
    z[0] = d_north + lever_n[0] - x[X_VEL] * back
    z[1] = d_east + lever_n[1] - x[X_VEL + 1] * back
    z[2] = -(x[X_HGT] - fix[2]) + lever_n[2] - x[X_VEL + 2] * back
    H = np.zeros((3, nx))
    for i in range(3):
        z[i] += x[X_GNSS_GM + i]
        H[i, POS + i] = 1.0
        H[i, VEL + i] = -back
        H[i, GNSS_GM + i] = 1.0
    # Ĉ l = C l + (C l) x φ
    add_skew(lever_n, H, 0, ATT, 1.0)
    if nx > LEVER:
        for i in range(3):
            for j in range(3):
                H[i, LEVER + j] = C[i, j]
            H[i, LATENCY] = -x[X_VEL + i]
    return z, H


@njit(cache=True)
def nhc_innovation(x: np.ndarray, C: np.ndarray, nx: int):
    """Non-holonomic constraint of a ground vehicle: the body's lateral and vertical velocity [m/s] are zero.

    Returns the innovation (the predicted body y and z velocity; the third entry is 0 and unused) and its H
    (3, nx; the third row zero): ``v_b = C_n_b v_n`` and, with ``Ĉ_b_n = (I - [φ x]) C_b_n``,
    ``∂v_b/∂φ = -C_n_b [v_n x]``, ``∂v_b/∂δv = C_n_b``.
    """
    v = x[X_VEL:X_VEL + 3]
    z = np.zeros(3)
    H = np.zeros((3, nx))
    c = np.empty(3)
    row_att = np.empty(3)
    for i in range(2):
        row = i + 1
        # row of C_n_b = column of C_b_n
        for j in range(3):
            c[j] = C[j, row]
        z[i] = c[0] * v[0] + c[1] * v[1] + c[2] * v[2]
        # -cᵀ[v x] = (v x c)ᵀ
        cross(v, c, row_att)
        for j in range(3):
            H[i, VEL + j] = c[j]
            H[i, ATT + j] = row_att[j]
    return z, H


@njit(cache=True)
def zupt_innovation(x: np.ndarray, nx: int):
    """Zero-velocity update of a vehicle standing still: the innovation is the predicted NED velocity [m/s],
    ``H`` (3, nx) picks the velocity error."""
    z = np.empty(3)
    H = np.zeros((3, nx))
    for i in range(3):
        z[i] = x[X_VEL + i]
        H[i, VEL + i] = 1.0
    return z, H


@njit(cache=True)
def zaru_innovation(x: np.ndarray, C: np.ndarray, rate_mean: np.ndarray, nx: int):
    """Zero angular-rate update of a vehicle standing still: the innovation is the epoch's mean measured rate less
    the estimated gyro bias and the Earth's rate in the body [rad/s]; with ``δb = b_est - b_true`` it is ``-δb``
    plus noise, so ``H`` (3, nx) is minus the identity on the gyro bias."""
    w_ie = np.empty(3)
    earth_rate(x[X_LAT], w_ie)
    z = np.empty(3)
    H = np.zeros((3, nx))
    for i in range(3):
        earth_b = C[0, i] * w_ie[0] + C[1, i] * w_ie[1] + C[2, i] * w_ie[2]  # C_n_b w_ie = (C_b_n)^T w_ie
        z[i] = rate_mean[i] - x[X_BG + i] - earth_b
        H[i, BG + i] = -1.0
    return z, H


@njit(cache=True)
def kalman_update(x: np.ndarray, P: np.ndarray, H: np.ndarray, z: np.ndarray, S_inv: np.ndarray, C: np.ndarray,
                  dx_total: np.ndarray, work: np.ndarray, out: np.ndarray) -> None:
    """Kalman update with the inverse innovation covariance ``S_inv``, fed back into ``x``; writes the new P
    into ``out`` (not ``P``); ``work`` (nx, nx): scratch.

    ``P - K S Kᵀ`` (symmetrised by the caller) rather than the Joseph form: with the optimal gain they are
    equal, and this costs O(n²) instead of two n³ products; in double precision with symmetrisation it stays
    positive definite for these state sizes.
    """
    n = P.shape[0]
    PHt = np.empty((n, 3))
    np.dot(P, H.T, PHt)
    K = np.empty((n, 3))
    np.dot(PHt, S_inv, K)
    dx = np.empty(n)
    np.dot(K, z, dx)
    correct_state(x, dx)
    quat_to_dcm(x[X_QUAT:X_QUAT + 4], C)
    dx_total += dx
    np.dot(K, PHt.T, work)
    for i in range(n):
        for j in range(n):
            out[i, j] = P[i, j] - work[i, j]


@njit(cache=True)
def innovation_covariance(P: np.ndarray, H: np.ndarray, r: np.ndarray) -> np.ndarray:
    """S = H P Hᵀ + diag(r) (3, 3)."""
    HP = np.empty((3, P.shape[0]))
    np.dot(H, P, HP)
    S = np.empty((3, 3))
    np.dot(HP, H.T, S)
    for i in range(3):
        S[i, i] += r[i]
    return S


@njit(cache=True)
def add_fix_correlation(S: np.ndarray, r: np.ndarray, rho: np.ndarray) -> None:
    """Add a fix's correlated noise to the innovation covariance ``S`` (3, 3) that holds its variances ``r`` (3,)
    [m^2, NED] on the diagonal: ``R = D^1/2 C D^1/2`` with ``D = diag(r)`` and the correlation coefficients
    ``rho`` = (north-east, north-down, east-down) off the diagonal (zeros: a diagonal R, S unchanged)."""
    ne = rho[0] * math.sqrt(r[0] * r[1])
    nd = rho[1] * math.sqrt(r[0] * r[2])
    ed = rho[2] * math.sqrt(r[1] * r[2])
    S[0, 1] += ne
    S[1, 0] += ne
    S[0, 2] += nd
    S[2, 0] += nd
    S[1, 2] += ed
    S[2, 1] += ed


class UpdateLog(NamedTuple):
    """Where :func:`gated_update` records each update, one slot per update: the covariance epoch it was made at,
    its innovation relative to the epoch's pre-update error (3,), H (3, nx) and FIX_USED or FIX_REJECTED."""

    epoch: np.ndarray
    z: np.ndarray
    H: np.ndarray
    status: np.ndarray


@njit(cache=True)
def gated_update(x: np.ndarray, P: np.ndarray, P_next: np.ndarray, z: np.ndarray, H: np.ndarray, S: np.ndarray,
                 rows: int, gate: float, C: np.ndarray, dx_total: np.ndarray, work: np.ndarray, log: UpdateLog,
                 slot: int, epoch: int) -> tuple[np.ndarray, np.ndarray, float, bool]:
    """One chi-square-gated measurement update of the first ``rows`` (2 or 3) rows of innovation ``z`` (3,)
    with ``H`` (3, nx) and innovation covariance ``S`` (3, 3), recorded in ``log`` at ``slot`` (at covariance
    epoch ``epoch``) and applied (:func:`kalman_update`, closed loop into ``x``, ``C`` and ``dx_total``) unless
    its normalised innovation squared ``d2 = zᵀ S⁻¹ z`` exceeds ``gate``.

    Returns the covariance and the spare buffer (swapped when the update was applied), ``d2`` and whether it was
    applied. With fewer rows the gain's inverse has zeros beyond them (the NHC's third row is unused)."""
    log.epoch[slot] = epoch
    log.z[slot] = z + H @ dx_total
    log.H[slot] = H
    if rows == S.shape[0]:
        S_inv = np.linalg.inv(S)
        d2 = z @ S_inv @ z
        if d2 <= gate:
            log.status[slot] = FIX_USED
            kalman_update(x, P, H, z, S_inv, C, dx_total, work, P_next)
            return P_next, P, d2, True
    else:
        S_rows_inv = np.linalg.inv(S[:rows, :rows])
        d2 = z[:rows] @ S_rows_inv @ z[:rows]
        if d2 <= gate:
            S_pad = np.zeros((3, 3))
            S_pad[:rows, :rows] = S_rows_inv
            log.status[slot] = FIX_USED
            kalman_update(x, P, H, z, S_pad, C, dx_total, work, P_next)
            return P_next, P, d2, True
    log.status[slot] = FIX_REJECTED
    return P, P_next, d2, False


# ---- the forward pass: its inputs, records, scratch and bookkeeping ----------------------------------------
class ImuRows(NamedTuple):
    """The forward pass's per-row inputs: times [s] (N,), gyro [rad/s] and accelerometer [m/s^2] samples (N, 3,
    body), the process-noise factors (N, 2), the still flags (N,) and the unit's roll, pitch, yaw [rad] (N, 3)."""

    t: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    q_scale: np.ndarray
    still: np.ndarray
    unit_rpy: np.ndarray


class FixInputs(NamedTuple):
    """The GNSS fixes (M,): row at or after each, lag behind it [s], antenna (lat, lon [rad], h [m]) (M, 3), NED
    variances [m^2] (M, 3) and correlation coefficients (north-east, north-down, east-down) (M, 3)."""

    row: np.ndarray
    lag: np.ndarray
    z: np.ndarray
    r: np.ndarray
    rho: np.ndarray


class ForwardRecords(NamedTuple):
    """What :func:`ekf_forward` returns, written as it goes (see there); ``fixes`` and ``aux`` are the
    :class:`UpdateLog` of the GNSS fixes and of the auxiliary updates."""

    ep_row: np.ndarray
    ep_dT: np.ndarray
    ep_Pm: np.ndarray
    ep_Pp: np.ndarray
    ep_Phi: np.ndarray
    ep_dx: np.ndarray
    ep_loglik: np.ndarray
    fixes: UpdateLog
    fix_S: np.ndarray
    fix_d2: np.ndarray
    aux: UpdateLog
    aux_kind: np.ndarray
    aux_r: np.ndarray
    stop: np.ndarray


class Scratch(NamedTuple):
    """The forward pass's work buffers, allocated once per segment (nothing is allocated per IMU row): F, Φ,
    Q_d, products (9, nx, nx), the strapdown's (MECHANISE_WORK, 4), this row's and the previous row's increments,
    the nominal C_b_n, the interval's start and mean attitude, its specific force in the body and NED frames, and
    the epoch's sums of C_b_n, specific force and measured rate."""

    F: np.ndarray
    Phi: np.ndarray
    Qd: np.ndarray
    work: np.ndarray
    mech: np.ndarray
    dtheta: np.ndarray
    dvel: np.ndarray
    dtheta_prev: np.ndarray
    dvel_prev: np.ndarray
    C: np.ndarray
    C_start: np.ndarray
    C_mid: np.ndarray
    u: np.ndarray
    f_row: np.ndarray
    C_sum: np.ndarray
    f_sum: np.ndarray
    w_sum: np.ndarray


# the pass's counters (int64) and times (float64), by name
N_EP, N_AUX, K_FIX, COUNT, REJECTS, FIRST_REJECTED, AFTER_OUTAGE, GAP_SINCE_FIX, FIXES_SINCE_OUTAGE = range(9)
T_EPOCH, T_LAST_FIX, T_UNIT = range(3)


@njit(cache=True)
def _allocate_records(n: int, start_row: int, stride: int, m: int, nx: int) -> ForwardRecords:
    """Records for a pass over rows ``start_row..n-1`` with ``m`` fixes: every epoch at most, four auxiliary
    updates an epoch at most; ``stop`` = (last row, first rejected fix, STOP_END)."""
    max_epochs = (n - start_row) // max(stride, 1) + m + 2
    # the epochs' matrices are written epoch by epoch and returned up to the last one written: left unfilled
    # (filling these three, 22 MB for a 15-minute flight at 2 Hz, took a quarter of the pass's time)
    fixes = UpdateLog(np.full(m, -1, dtype=np.int64), np.full((m, 3), np.nan), np.zeros((m, 3, nx)),
                      np.full(m, FIX_UNUSED, dtype=np.int64))
    # written update by update, returned up to the last one written
    n_aux = 4 * max_epochs
    aux = UpdateLog(np.empty(n_aux, dtype=np.int64), np.empty((n_aux, 3)), np.empty((n_aux, 3, nx)),
                    np.empty(n_aux, dtype=np.int64))
    # ep_loglik: innovation log-likelihood of the GNSS fixes, unit and NHC updates at each epoch,
    # -1/2 sum(log det S + zᵀS⁻¹z + m log 2π)
    return ForwardRecords(np.zeros(max_epochs, dtype=np.int64), np.zeros(max_epochs),
                          np.empty((max_epochs, nx, nx)), np.empty((max_epochs, nx, nx)),
                          np.empty((max_epochs, nx, nx)), np.zeros((max_epochs, nx)), np.zeros((max_epochs, 3)),
                          fixes, np.full((m, 3, 3), np.nan), np.full(m, np.nan), aux,
                          np.empty(n_aux, dtype=np.int64), np.empty((n_aux, 3)),
                          np.array([n - 1, -1, STOP_END], dtype=np.int64))


@njit(cache=True)
def _allocate_scratch(nx: int) -> Scratch:
    """Work buffers of a pass with ``nx`` error states (:class:`Scratch`)."""
    return Scratch(np.zeros((nx, nx)), np.zeros((nx, nx)), np.zeros((nx, nx)), np.empty((9, nx, nx)),
                   np.empty((MECHANISE_WORK, 4)), np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3),
                   np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3)), np.empty(3), np.empty(3),
                   np.zeros((3, 3)), np.zeros(3), np.zeros(3))


@njit(cache=True)
def _start_bookkeeping(t: np.ndarray, start_row: int, fixes: FixInputs) -> tuple[np.ndarray, np.ndarray]:
    """The counters and times at ``start_row``: one epoch, the first fix after the start, no rejects, no gap, the
    last fix's time (the start's when none was before it)."""
    book = np.zeros(9, dtype=np.int64)
    book[N_EP] = 1
    m = fixes.row.shape[0]
    while book[K_FIX] < m and fixes.row[book[K_FIX]] <= start_row:
        book[K_FIX] += 1
    book[FIRST_REJECTED] = -1
    book[FIXES_SINCE_OUTAGE] = DRIFT_WINDOW  # fixes processed since the last GNSS outage or IMU gap
    clock = np.full(3, t[start_row])
    if book[K_FIX] > 0:
        clock[T_LAST_FIX] = t[fixes.row[book[K_FIX] - 1]] - fixes.lag[book[K_FIX] - 1]
    return book, clock


@njit(cache=True)
def _open_first_epoch(start_row: int, P: np.ndarray, rec: ForwardRecords) -> None:
    """The first epoch's record: the start row, P⁻ = P⁺ = P0, Φ = I."""
    rec.ep_row[0] = start_row
    rec.ep_Pm[0] = P
    rec.ep_Pp[0] = P
    rec.ep_Phi[0] = np.eye(P.shape[0])


@njit(cache=True)
def _strapdown_row(k: int, imu: ImuRows, first: bool, x: np.ndarray, noise: np.ndarray, s: Scratch,
                   book: np.ndarray) -> None:
    """Advance the nominal state ``x`` to row ``k`` (the strapdown, the unit's and the receiver's nominal
    errors) and add the interval's mean attitude, specific force and rate to the epoch's sums."""
    dt = imu.t[k] - imu.t[k - 1]
    if imu.q_scale[k, 0] > 1.0:
        book[GAP_SINCE_FIX] = 1  # an IMU gap (raised navigation noise) since the last fix
    increments(imu.gyro[k - 1], imu.gyro[k], imu.accel[k - 1], imu.accel[k], dt, x, s.dtheta, s.dvel)
    if first:
        s.dtheta_prev[:] = s.dtheta
        s.dvel_prev[:] = s.dvel
    s.C_start[:, :] = s.C
    mechanise_into(x, s.dtheta, s.dvel, s.dtheta_prev, s.dvel_prev, dt, s.C, s.mech)
    s.dtheta_prev[:] = s.dtheta
    s.dvel_prev[:] = s.dvel
    # the unit's nominal attitude errors
    x[X_UNIT_YAW] += x[X_UNIT_DRIFT] * dt
    decay = math.exp(-dt * noise[INV_TAU_UNIT])
    x[X_UNIT_LEVEL] *= decay
    x[X_UNIT_LEVEL + 1] *= decay
    decay = math.exp(-dt * noise[INV_TAU_GNSS])
    for i in range(3):
        x[X_GNSS_GM + i] *= decay
    # the interval's mean attitude and specific force, for F; per component (no temporaries: every row)
    for i in range(3):
        s.u[i] = s.dvel[i] / dt
        for j in range(3):
            s.C_mid[i, j] = 0.5 * (s.C_start[i, j] + s.C[i, j])
            s.C_sum[i, j] += s.C_mid[i, j]
    np.dot(s.C_mid, s.u, s.f_row)
    for i in range(3):
        s.f_sum[i] += s.f_row[i]
        s.w_sum[i] += imu.gyro[k, i]
    book[COUNT] += 1


@njit(cache=True)
def _propagate_to(row: int, imu: ImuRows, x_epoch: np.ndarray, P: np.ndarray, P_next: np.ndarray,
                  noise: np.ndarray, rec: ForwardRecords, s: Scratch, book: np.ndarray,
                  clock: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Propagate the covariance from the last epoch to ``row`` with the epoch's mean attitude and specific
    force, and open the epoch's record there (row, interval, P⁻, Φ). Returns P⁻ and the spare buffer."""
    count = book[COUNT]
    dT = imu.t[row] - clock[T_EPOCH]
    propagate(P, x_epoch, s.C_sum / count, s.f_sum / count, noise, dT, imu.q_scale[row], s.F, s.Phi, s.Qd, s.work,
              P_next)
    n_ep = book[N_EP]
    rec.ep_row[n_ep] = row
    rec.ep_dT[n_ep] = dT
    rec.ep_Pm[n_ep] = P_next
    rec.ep_Phi[n_ep] = s.Phi
    return P_next, P


@njit(cache=True)
def _stop(rec: ForwardRecords, row: int, first_rejected: int, reason: int) -> None:
    """Record why and where the pass stopped."""
    rec.stop[0] = row
    rec.stop[1] = first_rejected
    rec.stop[2] = reason


@njit(cache=True)
def _log_aux(rec: ForwardRecords, book: np.ndarray, kind: int, r: np.ndarray) -> None:
    """Complete the auxiliary update just logged by :func:`gated_update` (its kind and variances) and move on."""
    rec.aux_kind[book[N_AUX]] = kind
    rec.aux_r[book[N_AUX]] = r
    book[N_AUX] += 1


@njit(cache=True)
def _nhc_update(k: int, imu: ImuRows, x: np.ndarray, P: np.ndarray, P_next: np.ndarray, dx_total: np.ndarray,
                noise: np.ndarray, rec: ForwardRecords, s: Scratch, book: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The non-holonomic constraint at row ``k``'s epoch (a ground vehicle)."""
    z, H = nhc_innovation(x, s.C, P.shape[0])
    # the constraint holds at the rear axle, up to NHC_LEVER from the IMU: the body's rotation moves the IMU
    # sideways (yaw rate) and up and down (pitch rate) by that much more
    r_turn = np.array([noise[R_NHC], noise[R_NHC], 1.0])
    r_turn[0] += (NHC_LEVER * (imu.gyro[k, 2] - x[X_BG + 2])) ** 2
    r_turn[1] += (NHC_LEVER * (imu.gyro[k, 1] - x[X_BG + 1])) ** 2
    S = innovation_covariance(P, H, r_turn)
    n_ep = book[N_EP]
    # a ground vehicle's constraint is gated only against gross violations (a skid): gating it like a fix would
    # drop it exactly when the heading drifts and it carries the most information
    P, P_next, d2, _ = gated_update(x, P, P_next, z, H, S, 2, NHC_GATE, s.C, dx_total, s.work[0], rec.aux,
                                    book[N_AUX], n_ep)
    rec.ep_loglik[n_ep, 2] -= 0.5 * (math.log(np.linalg.det(S[:2, :2])) + d2 + 2.0 * math.log(2.0 * math.pi))
    _log_aux(rec, book, AUX_NHC, r_turn)
    return P, P_next


@njit(cache=True)
def _still_updates(x: np.ndarray, P: np.ndarray, P_next: np.ndarray, dx_total: np.ndarray, noise: np.ndarray,
                   rec: ForwardRecords, s: Scratch, book: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The zero-velocity and zero angular-rate updates of a vehicle standing still at this epoch."""
    nx = P.shape[0]
    # a vehicle read as still that moves after all is refused
    z, H = zupt_innovation(x, nx)
    r_zupt = np.array([noise[R_ZUPT], noise[R_ZUPT], noise[R_ZUPT]])
    S = innovation_covariance(P, H, r_zupt)
    P, P_next, _, _ = gated_update(x, P, P_next, z, H, S, 3, ZUPT_GATE, s.C, dx_total, s.work[0], rec.aux,
                                   book[N_AUX], book[N_EP])
    _log_aux(rec, book, AUX_ZUPT, r_zupt)
    # and no rotation: the mean rate over the epoch is the gyro bias (and the Earth's rate)
    z, H = zaru_innovation(x, s.C, s.w_sum / book[COUNT], nx)
    r_zaru = np.full(3, noise[R_ZARU] / book[COUNT])
    S = innovation_covariance(P, H, r_zaru)
    P, P_next, _, _ = gated_update(x, P, P_next, z, H, S, 3, ZUPT_GATE, s.C, dx_total, s.work[0], rec.aux,
                                   book[N_AUX], book[N_EP])
    _log_aux(rec, book, AUX_ZARU, r_zaru)
    return P, P_next


@njit(cache=True)
def _unit_update(k: int, imu: ImuRows, x: np.ndarray, P: np.ndarray, P_next: np.ndarray, dx_total: np.ndarray,
                 noise: np.ndarray, gate: float, rec: ForwardRecords, s: Scratch,
                 book: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The unit's roll, pitch and yaw at row ``k``'s epoch."""
    r_unit = np.array([noise[R_UNIT_LEVEL], noise[R_UNIT_LEVEL], noise[R_UNIT_YAW]])
    z, H = unit_attitude_innovation(x, s.C, imu.unit_rpy[k], P.shape[0])
    S = innovation_covariance(P, H, r_unit)
    n_ep = book[N_EP]
    # every processed update counts, gated or not: a filter that gates its data out must not look good
    rec.ep_loglik[n_ep, 1] -= 0.5 * (math.log(np.linalg.det(S)) + 3.0 * math.log(2.0 * math.pi))
    P, P_next, d2, _ = gated_update(x, P, P_next, z, H, S, 3, gate, s.C, dx_total, s.work[0], rec.aux, book[N_AUX],
                                    n_ep)
    rec.ep_loglik[n_ep, 1] -= 0.5 * d2
    _log_aux(rec, book, AUX_UNIT, r_unit)
    return P, P_next


@njit(cache=True)
def _fix_updates(k: int, t: np.ndarray, fixes: FixInputs, x: np.ndarray, P: np.ndarray, P_next: np.ndarray,
                 dx_total: np.ndarray, noise: np.ndarray, options: np.ndarray, rec: ForwardRecords, s: Scratch,
                 book: np.ndarray, clock: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The GNSS fixes at row ``k``, each gated (loosely for the first after an outage or an IMU gap), with the
    count of rejected fixes in a row and where the run began."""
    r_scale = np.array([noise[R_SCALE_H], noise[R_SCALE_H], noise[R_SCALE_V]])
    n_ep = book[N_EP]
    while book[K_FIX] < fixes.row.shape[0] and fixes.row[book[K_FIX]] == k:
        k_fix = book[K_FIX]
        t_fix = t[k] - fixes.lag[k_fix]
        if t_fix - clock[T_LAST_FIX] > options[OPT_OUTAGE_S] or book[GAP_SINCE_FIX] != 0:
            book[FIXES_SINCE_OUTAGE] = 0
        z, H = gnss_innovation(x, s.C, fixes.z[k_fix], fixes.lag[k_fix], P.shape[0])
        r = fixes.r[k_fix] * r_scale
        S = innovation_covariance(P, H, r)
        add_fix_correlation(S, r, fixes.rho[k_fix])
        # re-acquisition: the first fixes after an outage or an IMU gap correct the drift itself; only a gross
        # outlier is gated there
        gate = REACQUIRE_GATE if book[FIXES_SINCE_OUTAGE] < REACQUIRE_FIXES else options[OPT_GATE]
        P, P_next, d2, used = gated_update(x, P, P_next, z, H, S, 3, gate, s.C, dx_total, s.work[0], rec.fixes,
                                           k_fix, n_ep)
        rec.fix_S[k_fix] = S
        rec.fix_d2[k_fix] = d2
        rec.ep_loglik[n_ep, 0] -= 0.5 * (math.log(np.linalg.det(S)) + d2 + 3.0 * math.log(2.0 * math.pi))
        if used:
            book[REJECTS] = 0
        else:
            if book[REJECTS] == 0:
                book[FIRST_REJECTED] = k_fix
                book[AFTER_OUTAGE] = book[FIXES_SINCE_OUTAGE] < DRIFT_WINDOW
            book[REJECTS] += 1
        book[FIXES_SINCE_OUTAGE] += 1
        clock[T_LAST_FIX] = t_fix
        book[GAP_SINCE_FIX] = 0
        book[K_FIX] += 1
    return P, P_next


@njit(cache=True)
def _close_epoch(k: int, t: np.ndarray, x: np.ndarray, x_epoch: np.ndarray, P: np.ndarray, P_next: np.ndarray,
                 dx_total: np.ndarray, nav: np.ndarray, rec: ForwardRecords, s: Scratch, book: np.ndarray,
                 clock: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Symmetrise P⁺, record it and the epoch's feedback correction, and start the next epoch at row ``k``."""
    nx = P.shape[0]
    for i in range(nx):
        for j in range(nx):
            P_next[i, j] = 0.5 * (P[i, j] + P[j, i])
    P, P_next = P_next, P
    rec.ep_Pp[book[N_EP]] = P
    rec.ep_dx[book[N_EP]] = dx_total
    book[N_EP] += 1
    s.C_sum[:, :] = 0.0
    s.w_sum[:] = 0.0
    s.f_sum[:] = 0.0
    book[COUNT] = 0
    x_epoch[:] = x
    clock[T_EPOCH] = t[k]
    nav[k] = x
    return P, P_next


@njit(cache=True)
def _stopped_by_rejects(k: int, options: np.ndarray, rec: ForwardRecords, book: np.ndarray) -> bool:
    """Whether the rejected fixes in a row stop the pass at row ``k`` (recorded in ``rec.stop``): DRIFT_REJECTS
    of them soon after an outage or a gap (STOP_DRIFT), or ``max_rejects`` anywhere (STOP_DIVERGED)."""
    max_rejects = int(options[OPT_MAX_REJECTS])
    if max_rejects > 0 and book[AFTER_OUTAGE] != 0 and book[REJECTS] >= DRIFT_REJECTS:
        _stop(rec, k, book[FIRST_REJECTED], STOP_DRIFT)
        return True
    if max_rejects > 0 and book[REJECTS] >= max_rejects:
        _stop(rec, k, book[FIRST_REJECTED], STOP_DIVERGED)
        return True
    return False


@njit(cache=True)
def _aid_epoch(k: int, imu: ImuRows, fixes: FixInputs, has_fix: bool, x: np.ndarray, P: np.ndarray,
               P_next: np.ndarray, dx_total: np.ndarray, noise: np.ndarray, options: np.ndarray, rec: ForwardRecords,
               s: Scratch, book: np.ndarray, clock: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The updates of row ``k``'s epoch, in this order: the NHC, the still vehicle's, the unit's attitude (at a
    fix's epoch and at least once a second), the GNSS fixes."""
    if options[OPT_NHC] > 0.5:
        P, P_next = _nhc_update(k, imu, x, P, P_next, dx_total, noise, rec, s, book)
    if imu.still[k]:
        P, P_next = _still_updates(x, P, P_next, dx_total, noise, rec, s, book)
    if options[OPT_UNIT_AIDING] > 0.5 and (has_fix or imu.t[k] - clock[T_UNIT] >= 1.0):
        clock[T_UNIT] = imu.t[k]
        P, P_next = _unit_update(k, imu, x, P, P_next, dx_total, noise, options[OPT_GATE], rec, s, book)
    return _fix_updates(k, imu.t, fixes, x, P, P_next, dx_total, noise, options, rec, s, book, clock)


@njit(cache=True)
def ekf_forward(t, gyro, accel, q_scale, still, unit_rpy, start_row, x0, P0, fix_row, fix_lag, z_fix, r_fix,
                rho_fix, noise, options, nav):
    """One segment of the forward error-state EKF, from ``start_row`` until the end or a stop.

    Inputs: the IMU rows (:class:`ImuRows`: the still flags ask for a zero-velocity and a zero angular-rate update
    at every epoch on such a row); the start row, its nominal state ``x0`` (NS,) and covariance ``P0`` (nx, nx),
    nx = NX_NAV or NX_CAL; the GNSS fixes (:class:`FixInputs`; variances before the R_SCALE factors, which keep
    the correlations: R = D^1/2 C D^1/2); the noise vector (N_NOISE,); ``options`` (N_OPTIONS,), named OPT_* in
    :mod:`~georef.fusion.ins_layout`. The pass stops after OPT_MAX_REJECTS fixes rejected in a row (STOP_DIVERGED;
    0: never), after DRIFT_REJECTS of them within DRIFT_WINDOW fixes after a GNSS outage longer than OPT_OUTAGE_S
    or an IMU gap (STOP_DRIFT: the drift exceeded the model), at the row before an IMU gap longer than OPT_MAX_GAP
    (STOP_GAP). ``nav`` (N, NS) receives the nominal state of every row.

    Returns per covariance epoch: row, interval [s], P⁻, P⁺, Φ, the feedback correction; per fix: epoch,
    innovation relative to the epoch's pre-update error, H, innovation covariance, normalised innovation squared,
    status; per auxiliary update: epoch, kind (AUX_*), innovation, H, status, variances; ``stop`` = (last row,
    first fix of the rejected run, STOP_*); per epoch the innovation log-likelihood of its GNSS fixes, unit and NHC
    updates, rejected ones included (E, 3). ``ForwardOutputs`` in :mod:`georef.fusion.ins` names them.
    """
    n, nx = t.shape[0], P0.shape[0]
    imu = ImuRows(t, gyro, accel, q_scale, still, unit_rpy)
    fixes = FixInputs(fix_row, fix_lag, z_fix, r_fix, rho_fix)
    stride = int(options[OPT_STRIDE])
    rec = _allocate_records(n, start_row, stride, fix_row.shape[0], nx)
    s = _allocate_scratch(nx)
    book, clock = _start_bookkeeping(t, start_row, fixes)
    x = x0.copy()
    P = P0.copy()
    P_next = np.empty((nx, nx))  # the buffer the next step writes into (swapped after each step)
    nav[start_row] = x
    _open_first_epoch(start_row, P, rec)
    quat_to_dcm(x[X_QUAT:X_QUAT + 4], s.C)
    x_epoch = x.copy()
    for k in range(start_row + 1, n):
        if t[k] - t[k - 1] > options[OPT_MAX_GAP]:
            # no IMU data across the gap: close the epoch at the row before it and stop
            if book[COUNT] > 0:
                P, P_next = _propagate_to(k - 1, imu, x_epoch, P, P_next, noise, rec, s, book, clock)
                rec.ep_Pp[book[N_EP]] = P
                book[N_EP] += 1
            _stop(rec, k - 1, rec.stop[1], STOP_GAP)
            break
        _strapdown_row(k, imu, k == start_row + 1, x, noise, s, book)
        has_fix = book[K_FIX] < fix_row.shape[0] and fix_row[book[K_FIX]] == k
        if not (book[COUNT] >= stride or has_fix or k == n - 1):
            nav[k] = x
            continue
        P, P_next = _propagate_to(k, imu, x_epoch, P, P_next, noise, rec, s, book, clock)
        if not math.isfinite(np.trace(P) + np.sum(x)):
            # numerically gone (a wild correction, an absurd lever arm): a divergence, never a NaN passed on
            _stop(rec, rec.ep_row[book[N_EP] - 1], max(book[K_FIX] - 1, 0), STOP_DIVERGED)
            break
        dx_total = np.zeros(nx)
        P, P_next = _aid_epoch(k, imu, fixes, has_fix, x, P, P_next, dx_total, noise, options, rec, s, book, clock)
        P, P_next = _close_epoch(k, t, x, x_epoch, P, P_next, dx_total, nav, rec, s, book, clock)
        if _stopped_by_rejects(k, options, rec, book):
            break
    e, a = book[N_EP], book[N_AUX]
    return (rec.ep_row[:e], rec.ep_dT[:e], rec.ep_Pm[:e], rec.ep_Pp[:e], rec.ep_Phi[:e], rec.ep_dx[:e],
            rec.fixes.epoch, rec.fixes.z, rec.fixes.H, rec.fix_S, rec.fix_d2, rec.fixes.status, rec.aux.epoch[:a],
            rec.aux_kind[:a], rec.aux.z[:a], rec.aux.H[:a], rec.aux.status[:a], rec.aux_r[:a], rec.stop,
            rec.ep_loglik[:e])


@njit(cache=True)
def _block_statistic(w: np.ndarray, cov: np.ndarray, Q: np.ndarray, idx: np.ndarray, out: np.ndarray,
                     block: int) -> None:
    """Add ``wᵀQ⁻¹w``, ``tr(Q⁻¹ cov)`` and the dimension of the sub-block ``idx`` to ``out[block]``."""
    k = idx.shape[0]
    Qs = np.empty((k, k))
    cs = np.empty((k, k))
    ws = np.empty(k)
    for a in range(k):
        ws[a] = w[idx[a]]
        if Q[idx[a], idx[a]] <= 0.0:
            return
        for b in range(k):
            Qs[a, b] = Q[idx[a], idx[b]]
            cs[a, b] = cov[idx[a], idx[b]]
    Qi = np.linalg.inv(Qs)
    out[block, 0] += ws @ Qi @ ws
    out[block, 1] += np.trace(Qi @ cs)
    out[block, 2] += k


@njit(cache=True)
def _measurement_statistic(e: np.ndarray, cov: np.ndarray, r: np.ndarray, lo: int, hi: int, out: np.ndarray,
                           block: int) -> None:
    """Add the normalised residual and posterior-trace terms of measurement components ``lo..hi-1``."""
    for i in range(lo, hi):
        out[block, 0] += e[i] * e[i] / r[i]
        out[block, 1] += cov[i, i] / r[i]
        out[block, 2] += 1.0


@njit(cache=True)
def prior_shift(ep_Pm, ep_Pp, ep_Phi, seg_start, mu):
    """The forward filter's error mean (E, nx) after (``m⁺``) and before (``m⁻``) each epoch's updates had its
    first segment started with the error mean ``mu`` (nx,) instead of zero, the gains and the linearisation
    unchanged.

    Each epoch's updates map a pre-update error mean through ``I - K H``, which for the optimal gain is
    ``P⁺ (P⁻)⁻¹`` whatever the updates were (none: the identity); the propagation maps it through ``Φ``. Zero
    from the first restart on (``seg_start``): a restart takes a fresh prior."""
    n_ep = ep_Pp.shape[0]
    nx = ep_Pp.shape[1]
    m_plus = np.zeros((n_ep, nx))
    m_minus = np.zeros((n_ep, nx))
    m_minus[0] = mu
    m_plus[0] = mu
    m_pred = np.empty(nx)
    for j in range(1, n_ep):
        if seg_start[j]:
            break
        np.dot(ep_Phi[j], m_plus[j - 1], m_pred)
        m_minus[j] = m_pred
        np.dot(ep_Pp[j], np.linalg.solve(ep_Pm[j], m_pred), m_plus[j])
    return m_plus, m_minus


class SmootherScratch(NamedTuple):
    """The smoother's work buffers (nx, nx) and (nx,), allocated once: Φ P⁺, P_next - P⁻ and two products, the
    smoothed P, the process noise Q_d and its posterior covariance; the process noise, a predicted mean and a
    post-update error."""

    PhiPp: np.ndarray
    D: np.ndarray
    M1: np.ndarray
    M2: np.ndarray
    P_s: np.ndarray
    Qd: np.ndarray
    cov_w: np.ndarray
    w: np.ndarray
    m_pred: np.ndarray
    post_total: np.ndarray


@njit(cache=True)
def _smooth_epoch(j: int, ep_Pm: np.ndarray, ep_Pp: np.ndarray, ep_Phi: np.ndarray, ep_dx: np.ndarray,
                  m_plus: np.ndarray, err_post: np.ndarray, err_pre: np.ndarray, shift: np.ndarray,
                  s: SmootherScratch) -> np.ndarray:
    """One RTS step back from epoch j+1 to j: the smoothed errors ``err_post[j]``, ``err_pre[j]``, the shift
    ``shift[j]`` and the smoothed covariance (into ``s.P_s``; ``ep_Pp[j]`` still holds P⁺). Returns the gain
    A = P⁺_j Φᵀ (P⁻_{j+1})⁻¹."""
    nx = ep_Pp.shape[1]
    Phi = ep_Phi[j + 1]
    P_plus = ep_Pp[j]
    P_minus = ep_Pm[j + 1]
    # A by a solve with the symmetric P-
    np.dot(Phi, P_plus, s.PhiPp)
    A = np.linalg.solve(P_minus, s.PhiPp).T
    np.dot(A, err_pre[j + 1], err_post[j])
    for i in range(nx):
        err_pre[j, i] = ep_dx[j, i] + err_post[j, i]
    np.dot(Phi, m_plus[j], s.m_pred)
    for i in range(nx):
        s.m_pred[i] = shift[j + 1, i] - s.m_pred[i]
    np.dot(A, s.m_pred, shift[j])
    for i in range(nx):
        shift[j, i] += m_plus[j, i]
    P_next = ep_Pp[j + 1]
    for a in range(nx):
        for b in range(nx):
            s.D[a, b] = P_next[a, b] - P_minus[a, b]
    np.dot(A, s.D, s.M1)
    np.dot(s.M1, A.T, s.M2)
    for a in range(nx):
        for b in range(nx):
            s.M1[a, b] = P_plus[a, b] + s.M2[a, b]
    for a in range(nx):
        for b in range(nx):
            s.P_s[a, b] = 0.5 * (s.M1[a, b] + s.M1[b, a])
    return A


@njit(cache=True)
def _noise_blocks() -> tuple[list, np.ndarray]:
    """The error-state indices of every process-noise block whose EM statistics are added up, and its B_* id."""
    blocks = [np.array([POS, POS + 1, VEL, VEL + 1]), np.array([POS + 2, VEL + 2]), np.array([ATT, ATT + 1]),
              np.array([ATT + 2]), np.array([BG, BG + 1, BG + 2]), np.array([BA, BA + 1, BA + 2]),
              np.array([UNIT_LEVEL, UNIT_LEVEL + 1]), np.array([UNIT_YAW, UNIT_DRIFT]),
              np.array([GNSS_GM, GNSS_GM + 1]), np.array([GNSS_GM + 2])]
    block_ids = np.array([B_VEL_H, B_VEL_V, B_ATT_H, B_ATT_V, B_BG, B_BA, B_UNIT_LEVEL, B_UNIT_DRIFT, B_GNSS_GM_H,
                          B_GNSS_GM_V])
    return blocks, block_ids


@njit(cache=True)
def _process_noise_statistics(j: int, A: np.ndarray, ep_Pm: np.ndarray, ep_Pp: np.ndarray, ep_Phi: np.ndarray,
                              err_post: np.ndarray, err_pre: np.ndarray, shift: np.ndarray, pooled: bool,
                              blocks: list, block_ids: np.ndarray, s: SmootherScratch, stats: np.ndarray) -> None:
    """Add the EM statistics of the process noise between epochs j and j+1 (after :func:`_smooth_epoch`, before
    ``ep_Pp[j]`` receives the smoothed covariance), per block, or all to B_OUTAGE when ``pooled``:
    w = ε⁻_{j+1} - Φ ε⁺_j, its mean and posterior covariance."""
    nx = ep_Pp.shape[1]
    Phi = ep_Phi[j + 1]
    P_minus = ep_Pm[j + 1]
    P_next = ep_Pp[j + 1]
    for i in range(nx):
        s.post_total[i] = err_post[j, i] + shift[j, i]
    np.dot(Phi, s.post_total, s.w)
    for i in range(nx):
        s.w[i] = err_pre[j + 1, i] + shift[j + 1, i] - s.w[i]
    np.dot(s.PhiPp, Phi.T, s.M1)  # Φ P⁺ Φᵀ
    for a in range(nx):
        for b in range(nx):
            s.Qd[a, b] = P_minus[a, b] - s.M1[a, b]
    np.dot(P_next, A.T, s.M1)  # L = Cov(ε⁻_{j+1}, ε⁺_j | all data)
    np.dot(Phi, s.M1.T, s.D)  # Φ Lᵀ
    np.dot(Phi, s.P_s, s.M1)
    np.dot(s.M1, Phi.T, s.M2)  # Φ P_s Φᵀ
    for a in range(nx):
        for b in range(nx):
            s.cov_w[a, b] = P_next[a, b] + s.M2[a, b] - s.D[a, b] - s.D[b, a]
    for b in range(len(blocks)):
        _block_statistic(s.w, s.cov_w, s.Qd, blocks[b], stats, B_OUTAGE if pooled else block_ids[b])


@njit(cache=True)
def _measurement_statistics(fixes: UpdateLog, r_fix: np.ndarray, noise: np.ndarray, aux: UpdateLog,
                            aux_kind: np.ndarray, aux_r: np.ndarray, err_pre: np.ndarray, ep_P: np.ndarray,
                            stats: np.ndarray) -> None:
    """Add the EM statistics of the applied GNSS fixes and auxiliary updates: their smoothed residuals against
    the pre-update errors ``err_pre`` (E, nx) with the smoothed covariances ``ep_P`` (E, nx, nx)."""
    r_scale = np.array([noise[R_SCALE_H], noise[R_SCALE_H], noise[R_SCALE_V]])
    for k in range(fixes.epoch.shape[0]):
        if fixes.status[k] != FIX_USED:
            continue
        j = fixes.epoch[k]
        H = fixes.H[k]
        e = fixes.z[k] - H @ err_pre[j]
        cov = H @ ep_P[j] @ H.T
        # per axis even for a fix with correlated axes (ekf_forward's rho_fix): E[e_i^2 + cov_ii] = s r_i holds
        # whatever the correlations, so the scale s stays a moment estimate, not the exact M-step of R(s)
        r = r_fix[k] * r_scale
        _measurement_statistic(e, cov, r, 0, 2, stats, B_GNSS_H)
        _measurement_statistic(e, cov, r, 2, 3, stats, B_GNSS_V)
    for k in range(aux.epoch.shape[0]):
        if aux.status[k] != FIX_USED:
            continue
        j = aux.epoch[k]
        H = aux.H[k]
        e = aux.z[k] - H @ err_pre[j]
        cov = H @ ep_P[j] @ H.T
        if aux_kind[k] == AUX_UNIT:
            _measurement_statistic(e, cov, aux_r[k], 0, 2, stats, B_UNIT_R_LEVEL)
            _measurement_statistic(e, cov, aux_r[k], 2, 3, stats, B_UNIT_R_YAW)
        elif aux_kind[k] == AUX_NHC:
            _measurement_statistic(e, cov, aux_r[k], 0, 2, stats, B_NHC)


@njit(cache=True)
def rts_backward(ep_dT, ep_Pm, ep_Pp, ep_Phi, ep_dx, seg_start, ep_outage, noise, fix_epoch, fix_z, fix_H, r_fix,
                 fix_status, aux_epoch, aux_kind, aux_z, aux_H, aux_status, aux_r, want_stats, m_plus):
    """RTS smoother over the covariance epochs of the closed-loop filter, segment by segment, in place.

    ``seg_start[j]`` marks an epoch where the filter was restarted: no information crosses it; the process noise
    of the interval ending at an epoch with ``ep_outage[j]`` (inside a GNSS outage) counts towards B_OUTAGE, all
    blocks pooled, instead of its own blocks. ``m_plus`` (E, nx) is the filter's error mean after each epoch's
    updates beyond the zero the closed loop leaves (:func:`prior_shift`: a prior mean other than the nominal
    start); zeros for none. The fix and auxiliary records are :func:`ekf_forward`'s (``r_fix`` its variances
    before the R_SCALE factors); ``ep_dT`` is not used. Returns per epoch the smoothed error of the post-update
    nominal (E, nx) and of the pre-update nominal (E, nx); ``ep_Pp`` then holds the smoothed covariances. With
    ``want_stats``, also the EM statistics (N_BLOCKS, 3): per noise block the sum of squared normalised smoothed
    residuals, the sum of the normalised posterior variances (trace terms) and the number of scalar residuals.
    """
    n_ep = ep_Pp.shape[0]
    nx = ep_Pp.shape[1]
    err_post = np.zeros((n_ep, nx))
    err_pre = np.zeros((n_ep, nx))
    # the smoothed part of the error that m_plus brings: s_j = m⁺_j + A_j (s_{j+1} - Φ m⁺_j)
    shift = np.zeros((n_ep, nx))
    shift[n_ep - 1] = m_plus[n_ep - 1]
    stats = np.zeros((N_BLOCKS, 3))
    err_pre[n_ep - 1] = ep_dx[n_ep - 1]
    blocks, block_ids = _noise_blocks()
    s = SmootherScratch(np.empty((nx, nx)), np.empty((nx, nx)), np.empty((nx, nx)), np.empty((nx, nx)),
                        np.empty((nx, nx)), np.empty((nx, nx)), np.empty((nx, nx)), np.empty(nx), np.empty(nx),
                        np.empty(nx))
    for j in range(n_ep - 2, -1, -1):
        if seg_start[j + 1]:
            err_post[j] = 0.0
            err_pre[j] = ep_dx[j]
            shift[j] = m_plus[j]
            continue
        A = _smooth_epoch(j, ep_Pm, ep_Pp, ep_Phi, ep_dx, m_plus, err_post, err_pre, shift, s)
        if want_stats:
            _process_noise_statistics(j, A, ep_Pm, ep_Pp, ep_Phi, err_post, err_pre, shift, ep_outage[j + 1],
                                      blocks, block_ids, s, stats)
        ep_Pp[j] = s.P_s
    for j in range(n_ep):
        for i in range(nx):
            err_post[j, i] += shift[j, i]
            err_pre[j, i] += shift[j, i]
    if want_stats:
        _measurement_statistics(UpdateLog(fix_epoch, fix_z, fix_H, fix_status), r_fix, noise,
                                UpdateLog(aux_epoch, aux_z, aux_H, aux_status), aux_kind, aux_r, err_pre, ep_Pp, stats)
    return err_post, err_pre, stats


@njit(cache=True)
def finish_rows(t, nav, ep_row, err_post, err_pre, P_post, P_pre):
    """Correct every row between covariance epochs by the linearly interpolated error; per-row outputs.

    At epoch j the row carries ``err_post[j]`` and ``P_post[j]``; just before epoch j+1 the error tends to
    ``err_pre[j+1]`` and the covariance to ``P_pre[j+1]``. For the smoother pass its smoothed errors and
    ``P_post = P_pre = P_s``; for the forward filter zero errors, ``P_post = P+`` and ``P_pre = P-``. Epochs on
    the same row (a restart) cover no rows but the last. ``nav`` (N, NS) is corrected in place.

    Returns: valid rows (N,), position and velocity variances (N, 3) [m^2, m^2/s^2], attitude-error
    covariances (N, 3, 3) [rad^2], ZYX roll, pitch, yaw [rad] (N, 3) and their 1-sigma (N, 3), and the
    1-sigma of every error state at every epoch (E, nx).
    """
    n = nav.shape[0]
    nx = P_post.shape[1]
    pos_var = np.full((n, 3), np.nan)
    vel_var = np.full((n, 3), np.nan)
    att_cov = np.full((n, 3, 3), np.nan)
    n_ep = ep_row.shape[0]
    e = np.empty(nx)
    for j in range(n_ep):
        r0 = ep_row[j]
        r1 = ep_row[j + 1] if j + 1 < n_ep else r0 + 1
        for r in range(r0, r1):
            w = 0.0 if r == r0 else (t[r] - t[r0]) / (t[r1] - t[r0])
            jn = j + 1 if r != r0 else j
            for i in range(nx):
                e[i] = err_post[j, i] if r == r0 else (1.0 - w) * err_post[j, i] + w * err_pre[jn, i]
            correct_state(nav[r], e)
            for i in range(3):
                pos_var[r, POS + i] = (1.0 - w) * P_post[j, POS + i, POS + i] + w * P_pre[jn, POS + i, POS + i]
                vel_var[r, i] = (1.0 - w) * P_post[j, VEL + i, VEL + i] + w * P_pre[jn, VEL + i, VEL + i]
                for c in range(3):
                    att_cov[r, i, c] = (1.0 - w) * P_post[j, ATT + i, ATT + c] + w * P_pre[jn, ATT + i, ATT + c]
    valid = np.zeros(n, dtype=np.bool_)
    angles = np.full((n, 3), np.nan)
    sigma = np.full((n, 3), np.nan)
    C = np.empty((3, 3))
    JP = np.empty((3, 3))
    S = np.empty((3, 3))
    for r in range(n):
        valid[r] = not math.isnan(nav[r, X_LAT]) and not math.isnan(pos_var[r, 0])
        if not valid[r]:
            continue
        quat_to_dcm(nav[r, X_QUAT:X_QUAT + 4], C)
        roll, pitch, yaw = dcm_to_euler(C)
        angles[r, 0], angles[r, 1], angles[r, 2] = roll, pitch, yaw
        J = euler_error_jacobian(C)
        np.dot(J, att_cov[r], JP)
        np.dot(JP, J.T, S)
        for i in range(3):
            sigma[r, i] = math.sqrt(max(S[i, i], 0.0))
    epoch_sigma = np.empty((n_ep, nx))
    for j in range(n_ep):
        for i in range(nx):
            epoch_sigma[j, i] = math.sqrt(max(P_post[j, i, i], 0.0))
    return valid, pos_var, vel_var, att_cov, angles, sigma, epoch_sigma
