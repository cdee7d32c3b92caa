"""Compiled loosely coupled INS/GNSS error-state EKF, its RTS smoother, and the noise statistics of an EM step.

Layouts: :mod:`georef.fusion.ins_layout` (named indices, one order for the error and the nominal state).

The forward filter (:func:`ekf_forward`) mechanises every IMU row and propagates the covariance at *covariance
epochs* (every ``stride`` rows and at every update): :func:`propagate` builds F at the epoch's mean attitude and
specific force and discretises it to third order. At an epoch it may fuse the unit's attitude
(:func:`unit_attitude_innovation`) and GNSS fixes (:func:`gnss_innovation`), each through :func:`kalman_update`
with a chi-square gate, and feeds the correction back (closed loop). When ``max_rejects`` fixes in a row are
rejected it stops and reports the first of them, so that the caller can re-align there (divergence recovery).

The smoother (:func:`rts_backward`) runs over the epochs of one or more filter segments and, when asked, adds up
for every noise block the statistics of an expectation-maximisation step (Shumway & Stoffer 1982): the smoothed
process-noise and measurement residuals normalised by their modelled covariance, and the trace terms of their
posterior covariance.
"""

from __future__ import annotations

import math

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
from georef.fusion.ins_layout import (  # noqa: F401  (the kernel's public names, as before)
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
    N_NOISE,
    NHC_GATE,
    NHC_LEVER,
    NS,
    NX_CAL,
    NX_NAV,
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
from georef.fusion.strapdown import (  # noqa: F401  (exported)
    MECHANISE_WORK,
    increments,
    mechanise,
    mechanise_into,
    two_sample_corrections,
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
    lat, h = x[X_LAT], x[X_HGT]
    vn, ve, vd = x[X_VEL], x[X_VEL + 1], x[X_VEL + 2]
    M, N = radii(lat)
    Mh, Nh = M + h, N + h
    tl = math.tan(lat)
    sl, cl = math.sin(lat), math.cos(lat)
    w_ie = np.empty(3)
    earth_rate(lat, w_ie)
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
    # biases: the mechanisation subtracts the estimated bias, so f_est - f = -C db_a, w_est - w = -db_g
    for i in range(3):
        for j in range(3):
            F[VEL + i, BA + j] = -C[i, j]
            F[ATT + i, BG + j] = C[i, j]
    # attitude
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
    for i in range(3):
        F[BG + i, BG + i] = -noise[INV_TAU_G]
        F[BA + i, BA + i] = -noise[INV_TAU_A]
    # the unit's attitude errors: Gauss-Markov roll/pitch, yaw origin with a drift rate
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


@njit(cache=True)
def aux_update(x, P, P_next, z, H, r, gate, C, dx_total, work, n_ep, kind, n_aux, aux_epoch, aux_kind, aux_z, aux_H,
               aux_status, aux_r):
    """Record an auxiliary update (ZUPT, ZARU, the unit's attitude: 3 rows, diagonal noise ``r``) in slot
    ``n_aux`` and apply it unless its normalised innovation squared exceeds ``gate``.

    Returns the covariance and the spare buffer (swapped when applied) and the normalised innovation squared."""
    S = innovation_covariance(P, H, r)
    S_inv = np.linalg.inv(S)
    d2 = z @ S_inv @ z
    aux_epoch[n_aux] = n_ep
    aux_kind[n_aux] = kind
    aux_z[n_aux] = z + H @ dx_total
    aux_H[n_aux] = H
    aux_r[n_aux] = r
    if d2 <= gate:
        aux_status[n_aux] = FIX_USED
        kalman_update(x, P, H, z, S_inv, C, dx_total, work, P_next)
        return P_next, P, d2
    aux_status[n_aux] = FIX_REJECTED
    return P, P_next, d2


@njit(cache=True)
def ekf_forward(t, gyro, accel, start_row, x0, P0, fix_row, fix_lag, z_fix, r_fix, rho_fix, noise, q_scale, stride,
                gate_chi2, max_rejects, max_gap, outage_s, unit_rpy, unit_aiding, nhc, still, nav):
    """One segment of the forward error-state EKF, from ``start_row`` until the end or a divergence.

    Inputs: row times ``t`` (N,) s; ``gyro`` rad/s and ``accel`` m/s^2 (N, 3) body frame; the start row, its
    nominal state ``x0`` (NS,) and covariance ``P0`` (nx, nx) with nx = NX_NAV or NX_CAL; per GNSS fix: the row
    at or after it ``fix_row``, ``fix_lag`` = t[row] - t_fix [s], antenna ``z_fix`` (lat, lon [rad], h [m]) and
    NED variances ``r_fix`` [m^2] (before the R_SCALE factors) and correlation coefficients ``rho_fix`` (M, 3):
    north-east, north-down, east-down (zeros: independent axes; R = D^1/2 C D^1/2 with D the scaled
    variances, so the R_SCALE factors keep the correlations); the noise vector (N_NOISE,); factors on the
    process noise of the interval ending at each row ``q_scale`` (N, 2): on the white specific force and angular
    rate, and on the bias and unit-error drives; covariance epochs every ``stride`` rows; the chi-square gate;
    ``max_rejects`` consecutive rejected fixes stop the segment (0: never), and so do DRIFT_REJECTS of them
    starting within DRIFT_WINDOW fixes after a GNSS outage longer than ``outage_s`` [s] or an IMU gap
    (STOP_DRIFT: the inertial drift over the outage or gap exceeded the model, not a divergence); an IMU gap
    longer than ``max_gap`` [s] stops it at the row before the gap (STOP_GAP). With ``unit_aiding`` the unit's
    roll, pitch, yaw ``unit_rpy`` (N, 3) [rad] are fused at every GNSS epoch and at least once a second; with
    ``nhc`` the non-holonomic constraint of a ground vehicle at every covariance epoch; at every covariance epoch
    on a row where ``still`` (N,) is set, a zero-velocity update with variance R_ZUPT and a zero angular-rate update
    of the epoch's mean rate with variance R_ZARU over the epoch's rows.
    The nominal state of every row is written into ``nav`` (N, NS).

    Returns per covariance epoch: row, interval [s], P⁻, P⁺, Φ, the feedback correction; per fix: epoch,
    innovation relative to the epoch's pre-update error, H, innovation covariance, normalised innovation
    squared, status; per auxiliary update (unit attitude, NHC): epoch, kind, innovation, H, status, the
    measurement variances used (AUX_UNIT, AUX_NHC, AUX_ZUPT); ``stop`` =
    (last row, first fix of the rejected run, STOP_END, STOP_DIVERGED, STOP_GAP or STOP_DRIFT); and per epoch
    the innovation log-likelihood of its GNSS fixes, unit and NHC updates, rejected ones included (E, 3).
    """
    n = t.shape[0]
    m = fix_row.shape[0]
    nx = P0.shape[0]
    max_epochs = (n - start_row) // max(stride, 1) + m + 2
    ep_row = np.zeros(max_epochs, dtype=np.int64)
    ep_dT = np.zeros(max_epochs)
    # the epochs' matrices are written epoch by epoch and returned up to the last one written: left unfilled
    # (filling these three, 22 MB for a 15-minute flight at 2 Hz, took a quarter of the pass's time)
    ep_Pm = np.empty((max_epochs, nx, nx))
    ep_Pp = np.empty((max_epochs, nx, nx))
    ep_Phi = np.empty((max_epochs, nx, nx))
    ep_dx = np.zeros((max_epochs, nx))
    fix_epoch = np.full(m, -1, dtype=np.int64)
    fix_z = np.full((m, 3), np.nan)
    fix_H = np.zeros((m, 3, nx))
    fix_S = np.full((m, 3, 3), np.nan)
    fix_d2 = np.full(m, np.nan)
    fix_status = np.full(m, FIX_UNUSED, dtype=np.int64)
    # written update by update, returned up to the last one written
    aux_epoch = np.empty(4 * max_epochs, dtype=np.int64)
    aux_kind = np.empty(4 * max_epochs, dtype=np.int64)
    aux_z = np.empty((4 * max_epochs, 3))
    aux_H = np.empty((4 * max_epochs, 3, nx))
    aux_status = np.empty(4 * max_epochs, dtype=np.int64)
    aux_r = np.empty((4 * max_epochs, 3))
    n_aux = 0
    stop = np.array([n - 1, -1, STOP_END], dtype=np.int64)
    # innovation log-likelihood of the GNSS fixes, unit and NHC updates at each epoch:
    # -1/2 sum(log det S + zᵀS⁻¹z + m log 2π)
    ep_loglik = np.zeros((max_epochs, 3))

    x = x0.copy()
    P = P0.copy()
    nav[start_row] = x
    ep_row[0] = start_row
    ep_Pm[0] = P
    ep_Pp[0] = P
    ep_Phi[0] = 0.0
    for i in range(nx):
        ep_Phi[0, i, i] = 1.0
    n_ep = 1
    dtheta = np.zeros(3)
    dvel = np.zeros(3)
    dtheta_prev = np.zeros(3)
    dvel_prev = np.zeros(3)
    C = np.empty((3, 3))
    quat_to_dcm(x[X_QUAT:X_QUAT + 4], C)
    C_start = np.empty((3, 3))
    C_mid = np.empty((3, 3))
    u = np.empty(3)
    f_row = np.empty(3)
    C_sum = np.zeros((3, 3))
    f_sum = np.zeros(3)
    count = 0
    x_epoch = x.copy()
    t_epoch = t[start_row]
    k_fix = 0
    while k_fix < m and fix_row[k_fix] <= start_row:
        k_fix += 1
    rejects = 0
    first_rejected = -1
    after_outage = False
    gap_since_fix = False   # an IMU gap (raised navigation noise) since the last fix
    fixes_since_outage = DRIFT_WINDOW  # fixes processed since the last GNSS outage or IMU gap
    t_last_fix = t[start_row]
    if k_fix > 0:
        t_last_fix = t[fix_row[k_fix - 1]] - fix_lag[k_fix - 1]
    t_unit = t[start_row]
    r_unit = np.array([noise[R_UNIT_LEVEL], noise[R_UNIT_LEVEL], noise[R_UNIT_YAW]])
    r_scale = np.array([noise[R_SCALE_H], noise[R_SCALE_H], noise[R_SCALE_V]])
    r_nhc = np.array([noise[R_NHC], noise[R_NHC], 1.0])
    r_zupt = np.array([noise[R_ZUPT], noise[R_ZUPT], noise[R_ZUPT]])
    w_sum = np.zeros(3)
    F = np.zeros((nx, nx))
    Phi = np.zeros((nx, nx))
    Qd = np.zeros((nx, nx))
    # P and the buffer the next step writes into (swapped after each step), scratch for the products
    P_next = np.empty((nx, nx))
    work = np.empty((9, nx, nx))
    mech_work = np.empty((MECHANISE_WORK, 4))  # the strapdown's scratch, reused at every row
    for k in range(start_row + 1, n):
        dt = t[k] - t[k - 1]
        if dt > max_gap:
            # no IMU data across the gap: close the epoch at the row before it and stop
            if count > 0:
                propagate(P, x_epoch, C_sum / count, f_sum / count, noise, t[k - 1] - t_epoch, q_scale[k - 1],
                          F, Phi, Qd, work, P_next)
                P, P_next = P_next, P
                ep_row[n_ep] = k - 1
                ep_dT[n_ep] = t[k - 1] - t_epoch
                ep_Pm[n_ep] = P
                ep_Pp[n_ep] = P
                ep_Phi[n_ep] = Phi
                n_ep += 1
            stop[0] = k - 1
            stop[2] = STOP_GAP
            break
        if q_scale[k, 0] > 1.0:
            gap_since_fix = True
        increments(gyro[k - 1], gyro[k], accel[k - 1], accel[k], dt, x, dtheta, dvel)
        if k == start_row + 1:
            dtheta_prev[:] = dtheta
            dvel_prev[:] = dvel
        C_start[:, :] = C
        mechanise_into(x, dtheta, dvel, dtheta_prev, dvel_prev, dt, C, mech_work)
        dtheta_prev[:] = dtheta
        dvel_prev[:] = dvel
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
            u[i] = dvel[i] / dt
            for j in range(3):
                C_mid[i, j] = 0.5 * (C_start[i, j] + C[i, j])
                C_sum[i, j] += C_mid[i, j]
        np.dot(C_mid, u, f_row)
        for i in range(3):
            f_sum[i] += f_row[i]
            w_sum[i] += gyro[k, i]
        count += 1
        has_fix = k_fix < m and fix_row[k_fix] == k
        if count >= stride or has_fix or k == n - 1:
            propagate(P, x_epoch, C_sum / count, f_sum / count, noise, t[k] - t_epoch, q_scale[k], F, Phi, Qd, work,
                      P_next)
            P, P_next = P_next, P
            if not math.isfinite(np.trace(P) + np.sum(x)):
                # numerically gone (a wild correction, an absurd lever arm): a divergence, never a NaN passed on
                stop[0] = ep_row[n_ep - 1]
                stop[1] = max(k_fix - 1, 0)
                stop[2] = STOP_DIVERGED
                break
            ep_row[n_ep] = k
            ep_dT[n_ep] = t[k] - t_epoch
            ep_Pm[n_ep] = P
            ep_Phi[n_ep] = Phi
            dx_total = np.zeros(nx)
            if nhc:
                z, H = nhc_innovation(x, C, nx)
                # the constraint holds at the rear axle, up to NHC_LEVER from the IMU: the body's rotation moves
                # the IMU sideways (yaw rate) and up and down (pitch rate) by that much more
                r_turn = r_nhc.copy()
                r_turn[0] += (NHC_LEVER * (gyro[k, 2] - x[X_BG + 2])) ** 2
                r_turn[1] += (NHC_LEVER * (gyro[k, 1] - x[X_BG + 1])) ** 2
                S = innovation_covariance(P, H, r_turn)
                S2 = S[:2, :2]
                S2_inv = np.linalg.inv(S2)
                d2 = z[:2] @ S2_inv @ z[:2]
                ep_loglik[n_ep, 2] -= 0.5 * (math.log(np.linalg.det(S2)) + d2 + 2.0 * math.log(2.0 * math.pi))
                aux_epoch[n_aux] = n_ep
                aux_kind[n_aux] = AUX_NHC
                aux_z[n_aux] = z + H @ dx_total
                aux_H[n_aux] = H
                S_inv = np.zeros((3, 3))
                S_inv[:2, :2] = S2_inv
                # a ground vehicle's constraint is gated only against gross violations (a skid): gating it like a
                # fix would drop it exactly when the heading drifts and it carries the most information
                if d2 <= NHC_GATE:
                    aux_status[n_aux] = FIX_USED
                    kalman_update(x, P, H, z, S_inv, C, dx_total, work[0], P_next)
                    P, P_next = P_next, P
                else:
                    aux_status[n_aux] = FIX_REJECTED
                aux_r[n_aux] = r_turn
                n_aux += 1
            if still[k]:
                # a vehicle read as still that moves after all is refused
                z, H = zupt_innovation(x, nx)
                P, P_next, _ = aux_update(x, P, P_next, z, H, r_zupt, ZUPT_GATE, C, dx_total, work[0], n_ep, AUX_ZUPT,
                                          n_aux, aux_epoch, aux_kind, aux_z, aux_H, aux_status, aux_r)
                n_aux += 1
                # and no rotation: the mean rate over the epoch is the gyro bias (and the Earth's rate)
                z, H = zaru_innovation(x, C, w_sum / count, nx)
                r_zaru = np.full(3, noise[R_ZARU] / count)
                P, P_next, _ = aux_update(x, P, P_next, z, H, r_zaru, ZUPT_GATE, C, dx_total, work[0], n_ep, AUX_ZARU,
                                          n_aux, aux_epoch, aux_kind, aux_z, aux_H, aux_status, aux_r)
                n_aux += 1
            if unit_aiding and (has_fix or t[k] - t_unit >= 1.0):
                t_unit = t[k]
                z, H = unit_attitude_innovation(x, C, unit_rpy[k], nx)
                S = innovation_covariance(P, H, r_unit)
                # every processed update counts, gated or not: a filter that gates its data out must not look good
                ep_loglik[n_ep, 1] -= 0.5 * (math.log(np.linalg.det(S)) + 3.0 * math.log(2.0 * math.pi))
                P, P_next, d2 = aux_update(x, P, P_next, z, H, r_unit, gate_chi2, C, dx_total, work[0], n_ep,
                                           AUX_UNIT, n_aux, aux_epoch, aux_kind, aux_z, aux_H, aux_status, aux_r)
                ep_loglik[n_ep, 1] -= 0.5 * d2
                n_aux += 1
            while k_fix < m and fix_row[k_fix] == k:
                t_fix = t[k] - fix_lag[k_fix]
                if t_fix - t_last_fix > outage_s or gap_since_fix:
                    fixes_since_outage = 0
                z, H = gnss_innovation(x, C, z_fix[k_fix], fix_lag[k_fix], nx)
                r = r_fix[k_fix] * r_scale
                S = innovation_covariance(P, H, r)
                add_fix_correlation(S, r, rho_fix[k_fix])
                S_inv = np.linalg.inv(S)
                d2 = z @ S_inv @ z
                fix_epoch[k_fix] = n_ep
                fix_z[k_fix] = z + H @ dx_total
                fix_H[k_fix] = H
                fix_S[k_fix] = S
                fix_d2[k_fix] = d2
                ep_loglik[n_ep, 0] -= 0.5 * (math.log(np.linalg.det(S)) + d2 + 3.0 * math.log(2.0 * math.pi))
                # re-acquisition: the first fixes after an outage or an IMU gap correct the drift itself; only a
                # gross outlier is gated there
                gate = REACQUIRE_GATE if fixes_since_outage < REACQUIRE_FIXES else gate_chi2
                if d2 <= gate:
                    fix_status[k_fix] = FIX_USED
                    rejects = 0
                    kalman_update(x, P, H, z, S_inv, C, dx_total, work[0], P_next)
                    P, P_next = P_next, P
                else:
                    fix_status[k_fix] = FIX_REJECTED
                    if rejects == 0:
                        first_rejected = k_fix
                        after_outage = fixes_since_outage < DRIFT_WINDOW
                    rejects += 1
                fixes_since_outage += 1
                t_last_fix = t_fix
                gap_since_fix = False
                k_fix += 1
            for i in range(nx):
                for j in range(nx):
                    P_next[i, j] = 0.5 * (P[i, j] + P[j, i])
            P, P_next = P_next, P
            ep_Pp[n_ep] = P
            ep_dx[n_ep] = dx_total
            n_ep += 1
            C_sum[:, :] = 0.0
            w_sum[:] = 0.0
            f_sum[:] = 0.0
            count = 0
            x_epoch[:] = x
            t_epoch = t[k]
            nav[k] = x
            if max_rejects > 0 and after_outage and rejects >= DRIFT_REJECTS:
                stop[0] = k
                stop[1] = first_rejected
                stop[2] = STOP_DRIFT
                break
            if max_rejects > 0 and rejects >= max_rejects:
                stop[0] = k
                stop[1] = first_rejected
                stop[2] = STOP_DIVERGED
                break
        else:
            nav[k] = x
    return (ep_row[:n_ep], ep_dT[:n_ep], ep_Pm[:n_ep], ep_Pp[:n_ep], ep_Phi[:n_ep], ep_dx[:n_ep], fix_epoch,
            fix_z, fix_H, fix_S, fix_d2, fix_status, aux_epoch[:n_aux], aux_kind[:n_aux], aux_z[:n_aux],
            aux_H[:n_aux], aux_status[:n_aux], aux_r[:n_aux], stop, ep_loglik[:n_ep])


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


@njit(cache=True)
def rts_backward(ep_dT, ep_Pm, ep_Pp, ep_Phi, ep_dx, seg_start, ep_outage, noise, fix_epoch, fix_z, fix_H, r_fix,
                 fix_status, aux_epoch, aux_kind, aux_z, aux_H, aux_status, aux_r, want_stats, m_plus):
    """RTS smoother over the covariance epochs of the closed-loop filter, segment by segment, in place.

    ``seg_start[j]`` marks an epoch where the filter was restarted: no information crosses it; the process noise
    of the interval ending at an epoch with ``ep_outage[j]`` (inside a GNSS outage) counts towards B_OUTAGE, all
    blocks pooled, instead of its own blocks. ``m_plus`` (E, nx) is the filter's error mean after each epoch's
    updates beyond the zero the closed loop leaves (:func:`prior_shift`: a prior mean other than the nominal
    start); zeros for none. Returns per
    epoch the smoothed error of the post-update nominal (E, nx) and of the pre-update nominal (E, nx);
    ``ep_Pp`` then holds the smoothed covariances. With ``want_stats``, also the EM statistics (N_BLOCKS, 3):
    per noise block the sum of squared normalised smoothed residuals, the sum of the normalised posterior
    variances (trace terms) and the number of scalar residuals.
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
    blocks = [np.array([POS, POS + 1, VEL, VEL + 1]), np.array([POS + 2, VEL + 2]), np.array([ATT, ATT + 1]),
              np.array([ATT + 2]), np.array([BG, BG + 1, BG + 2]), np.array([BA, BA + 1, BA + 2]),
              np.array([UNIT_LEVEL, UNIT_LEVEL + 1]), np.array([UNIT_YAW, UNIT_DRIFT]),
              np.array([GNSS_GM, GNSS_GM + 1]), np.array([GNSS_GM + 2])]
    block_ids = np.array([B_VEL_H, B_VEL_V, B_ATT_H, B_ATT_V, B_BG, B_BA, B_UNIT_LEVEL, B_UNIT_DRIFT, B_GNSS_GM_H,
                          B_GNSS_GM_V])
    # scratch (no allocation per epoch besides the solve's): Φ P⁺, P_next - P⁻, products, the smoothed P
    PhiPp = np.empty((nx, nx))
    D = np.empty((nx, nx))
    M1 = np.empty((nx, nx))
    M2 = np.empty((nx, nx))
    P_s = np.empty((nx, nx))
    Qd = np.empty((nx, nx))
    cov_w = np.empty((nx, nx))
    w = np.empty(nx)
    m_pred = np.empty(nx)
    post_total = np.empty(nx)
    for j in range(n_ep - 2, -1, -1):
        if seg_start[j + 1]:
            err_post[j] = 0.0
            err_pre[j] = ep_dx[j]
            shift[j] = m_plus[j]
            continue
        Phi = ep_Phi[j + 1]
        P_plus = ep_Pp[j]  # read before ep_Pp[j] receives the smoothed covariance, below
        P_minus = ep_Pm[j + 1]
        # A = P+_j Φᵀ (P-_{j+1})⁻¹, by a solve with the symmetric P-
        np.dot(Phi, P_plus, PhiPp)
        A = np.linalg.solve(P_minus, PhiPp).T
        np.dot(A, err_pre[j + 1], err_post[j])
        for i in range(nx):
            err_pre[j, i] = ep_dx[j, i] + err_post[j, i]
        np.dot(Phi, m_plus[j], m_pred)
        for i in range(nx):
            m_pred[i] = shift[j + 1, i] - m_pred[i]
        np.dot(A, m_pred, shift[j])
        for i in range(nx):
            shift[j, i] += m_plus[j, i]
        P_next = ep_Pp[j + 1]
        for a in range(nx):
            for b in range(nx):
                D[a, b] = P_next[a, b] - P_minus[a, b]
        np.dot(A, D, M1)
        np.dot(M1, A.T, M2)
        for a in range(nx):
            for b in range(nx):
                M1[a, b] = P_plus[a, b] + M2[a, b]
        for a in range(nx):
            for b in range(nx):
                P_s[a, b] = 0.5 * (M1[a, b] + M1[b, a])
        if want_stats:
            # process noise between epochs j and j+1: w = ε⁻_{j+1} - Φ ε⁺_j, its mean and posterior covariance
            for i in range(nx):
                post_total[i] = err_post[j, i] + shift[j, i]
            np.dot(Phi, post_total, w)
            for i in range(nx):
                w[i] = err_pre[j + 1, i] + shift[j + 1, i] - w[i]
            np.dot(PhiPp, Phi.T, M1)  # Φ P⁺ Φᵀ
            for a in range(nx):
                for b in range(nx):
                    Qd[a, b] = P_minus[a, b] - M1[a, b]
            np.dot(P_next, A.T, M1)  # L = Cov(ε⁻_{j+1}, ε⁺_j | all data)
            np.dot(Phi, M1.T, D)  # Φ Lᵀ
            np.dot(Phi, P_s, M1)
            np.dot(M1, Phi.T, M2)  # Φ P_s Φᵀ
            for a in range(nx):
                for b in range(nx):
                    cov_w[a, b] = P_next[a, b] + M2[a, b] - D[a, b] - D[b, a]
            for b in range(len(blocks)):
                _block_statistic(w, cov_w, Qd, blocks[b], stats, B_OUTAGE if ep_outage[j + 1] else block_ids[b])
        ep_Pp[j] = P_s
    for j in range(n_ep):
        for i in range(nx):
            err_post[j, i] += shift[j, i]
            err_pre[j, i] += shift[j, i]
    if want_stats:
        r_scale = np.array([noise[R_SCALE_H], noise[R_SCALE_H], noise[R_SCALE_V]])
        for k in range(fix_epoch.shape[0]):
            if fix_status[k] != FIX_USED:
                continue
            j = fix_epoch[k]
            H = fix_H[k]
            e = fix_z[k] - H @ err_pre[j]
            cov = H @ ep_Pp[j] @ H.T
            # per axis even for a fix with correlated axes (ekf_forward's rho_fix): E[e_i^2 + cov_ii] = s r_i holds
            # whatever the correlations, so the scale s stays a moment estimate, not the exact M-step of R(s)
            r = r_fix[k] * r_scale
            _measurement_statistic(e, cov, r, 0, 2, stats, B_GNSS_H)
            _measurement_statistic(e, cov, r, 2, 3, stats, B_GNSS_V)
        for k in range(aux_epoch.shape[0]):
            if aux_status[k] != FIX_USED:
                continue
            j = aux_epoch[k]
            H = aux_H[k]
            e = aux_z[k] - H @ err_pre[j]
            cov = H @ ep_Pp[j] @ H.T
            if aux_kind[k] == AUX_UNIT:
                _measurement_statistic(e, cov, aux_r[k], 0, 2, stats, B_UNIT_R_LEVEL)
                _measurement_statistic(e, cov, aux_r[k], 2, 3, stats, B_UNIT_R_YAW)
            elif aux_kind[k] == AUX_NHC:
                _measurement_statistic(e, cov, aux_r[k], 0, 2, stats, B_NHC)
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
