"""Compiled loosely coupled INS/GNSS error-state EKF and its RTS smoother.

Error state (19): ``δr`` NED position error [m] (0-2), ``δv`` NED velocity error [m/s] (3-5), ``φ`` attitude
error [rad] with ``Ĉ_b_n = (I - [φ x]) C_b_n`` (6-8), ``δb_g`` [rad/s] (9-11), ``δb_a`` [m/s^2] (12-14), and
four states of the POS unit's own attitude output, used only when it aids the filter: its roll and pitch
errors (Gauss-Markov, 15-16), the offset ``d`` of its yaw origin (17) and that offset's drift rate (18).
Errors are estimate minus truth. The nominal state (20) is the strapdown state (16) followed by
``d``, ``d_dot``, the unit's roll error and pitch error.

* The nominal state is mechanised at every IMU row (:mod:`georef.fusion.strapdown`).
* The covariance is propagated at *covariance epochs*: every ``stride`` rows and at every GNSS update, with
  ``Φ = I + F Δt + (F Δt)^2 / 2`` where F uses the interval's mean ``C_b_n`` and ``f_n`` (so fast attitude
  changes within the interval are averaged, not sampled).
* GNSS antenna position updates through the lever arm, at the fix's own time (the row after the fix, moved
  back along the velocity), with a chi-square innovation gate; the error state is fed back (closed loop).
* The RTS smoother runs backwards over the covariance epochs and corrects every row by interpolating the
  smoothed error between epochs.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from georef.frames.kernels import (
    dcm_to_euler,
    earth_rate,
    euler_error_jacobian,
    quat_from_rotvec,
    quat_mul,
    quat_normalise,
    quat_to_dcm,
    radii,
    transport_rate,
)
from georef.fusion.strapdown import increments, mechanise

NX = 19
NS = 20


@njit(cache=True)
def _skew_into(v: np.ndarray, F: np.ndarray, r0: int, c0: int, sign: float) -> None:
    F[r0 + 0, c0 + 1] += -sign * v[2]
    F[r0 + 0, c0 + 2] += sign * v[1]
    F[r0 + 1, c0 + 0] += sign * v[2]
    F[r0 + 1, c0 + 2] += -sign * v[0]
    F[r0 + 2, c0 + 0] += -sign * v[1]
    F[r0 + 2, c0 + 1] += sign * v[0]


@njit(cache=True)
def system_matrix(x: np.ndarray, C: np.ndarray, f_n: np.ndarray, inv_tau_g: float, inv_tau_a: float,
                  inv_tau_unit: float) -> np.ndarray:
    """Continuous-time error dynamics F (19x19) at nominal state ``x`` with C_b_n and f_n [m/s^2].

    Blocks as in Shin (2005) / KF-GINS: position in local metres, the phi-angle attitude model.
    """
    F = np.zeros((NX, NX))
    lat, h = x[0], x[2]
    vn, ve, vd = x[3], x[4], x[5]
    M, N = radii(lat)
    Mh, Nh = M + h, N + h
    tl = math.tan(lat)
    sl, cl = math.sin(lat), math.cos(lat)
    w = 7.292115e-5
    g = 9.780325 * (1.0 + 0.0053024 * sl * sl)  # only in the small vertical-gravity gradient term
    # position
    F[0, 0] = -vd / Mh
    F[0, 2] = vn / Mh
    F[1, 0] = ve * tl / Nh
    F[1, 1] = -(vd + vn * tl) / Nh
    F[1, 2] = ve / Nh
    F[0, 3] = 1.0
    F[1, 4] = 1.0
    F[2, 5] = 1.0
    # velocity
    F[3, 0] = -2.0 * ve * w * cl / Mh - ve * ve / (Mh * Nh * cl * cl)
    F[3, 2] = vn * vd / Mh**2 - ve * ve * tl / Nh**2
    F[4, 0] = 2.0 * w * (vn * cl - vd * sl) / Mh + vn * ve / (Mh * Nh * cl * cl)
    F[4, 2] = (ve * vd + vn * ve * tl) / Nh**2
    F[5, 0] = 2.0 * w * ve * sl / Mh
    F[5, 2] = -ve * ve / Nh**2 - vn * vn / Mh**2 + 2.0 * g / (math.sqrt(M * N) + h)
    F[3, 3] = vd / Mh
    F[3, 4] = -2.0 * (w * sl + ve * tl / Nh)
    F[3, 5] = vn / Mh
    F[4, 3] = 2.0 * w * sl + ve * tl / Nh
    F[4, 4] = (vd + vn * tl) / Nh
    F[4, 5] = 2.0 * w * cl + ve / Nh
    F[5, 3] = -2.0 * vn / Mh
    F[5, 4] = -2.0 * (w * cl + ve / Nh)
    _skew_into(f_n, F, 3, 6, 1.0)
    # biases: the mechanisation subtracts the estimated bias, so f_est - f = -C db_a, w_est - w = -db_g
    for i in range(3):
        for j in range(3):
            F[3 + i, 12 + j] = -C[i, j]
            F[6 + i, 9 + j] = C[i, j]
    # attitude
    F[6, 0] = -w * sl / Mh
    F[6, 2] = ve / Nh**2
    F[7, 2] = -vn / Mh**2
    F[8, 0] = -w * cl / Mh - ve / (Mh * Nh * cl * cl)
    F[8, 2] = -ve * tl / Nh**2
    F[6, 4] = 1.0 / Nh
    F[7, 3] = -1.0 / Mh
    F[8, 4] = -tl / Nh
    w_in = np.empty(3)
    w_en = np.empty(3)
    earth_rate(lat, w_in)
    transport_rate(lat, h, x[3:6], w_en)
    w_in += w_en
    _skew_into(w_in, F, 6, 6, -1.0)
    for i in range(3):
        F[9 + i, 9 + i] = -inv_tau_g
        F[12 + i, 12 + i] = -inv_tau_a
    # the unit's attitude errors: Gauss-Markov roll/pitch, yaw origin with a drift rate
    F[15, 15] = -inv_tau_unit
    F[16, 16] = -inv_tau_unit
    F[17, 18] = 1.0
    return F


@njit(cache=True)
def correct_state(x: np.ndarray, dx: np.ndarray) -> None:
    """Remove the estimated error ``dx`` (estimate minus truth) from the nominal state ``x`` in place."""
    M, N = radii(x[0])
    h = x[2]
    x[0] -= dx[0] / (M + h)
    x[1] -= dx[1] / ((N + h) * math.cos(x[0]))
    x[2] += dx[2]
    for i in range(3):
        x[3 + i] -= dx[3 + i]
        x[10 + i] -= dx[9 + i]
        x[13 + i] -= dx[12 + i]
    x[18] -= dx[15]
    x[19] -= dx[16]
    x[16] -= dx[17]
    x[17] -= dx[18]
    q = quat_mul(quat_from_rotvec(dx[6:9]), x[6:10])
    quat_normalise(q)
    x[6:10] = q


@njit(cache=True)
def _process_noise(q_vel: float, q_att: float, q_bg: float, q_ba: float, q_unit: float, q_drift: float,
                   dt: float) -> np.ndarray:
    Q = np.zeros((NX, NX))
    for i in range(3):
        Q[i, i] = q_vel * dt**3 / 3.0
        Q[i, 3 + i] = q_vel * dt**2 / 2.0
        Q[3 + i, i] = q_vel * dt**2 / 2.0
        Q[3 + i, 3 + i] = q_vel * dt
        Q[6 + i, 6 + i] = q_att * dt
        Q[9 + i, 9 + i] = q_bg * dt
        Q[12 + i, 12 + i] = q_ba * dt
    Q[15, 15] = q_unit * dt
    Q[16, 16] = q_unit * dt
    Q[18, 18] = q_drift * dt
    return Q


@njit(cache=True)
def _apply_update(x, P, H, z, R, S_inv, C, dx_total):
    """Kalman update in Joseph form, fed back into the nominal state; returns the new covariance."""
    K = P @ H.T @ S_inv
    dx = K @ z
    IKH = np.eye(P.shape[0]) - K @ H
    correct_state(x, dx)
    quat_to_dcm(x[6:10], C)
    dx_total += dx
    return IKH @ P @ IKH.T + K @ R @ K.T


@njit(cache=True)
def ekf_forward(t, gyro, accel, start_row, x0, P0, fix_row, fix_lag, z_fix, r_fix, lever, noise, stride,
                gate_chi2, max_rejects, unit_rpy, unit_aiding, keep_predicted):
    """Forward error-state EKF.

    Inputs: row times ``t`` (N,) s; ``gyro`` rad/s and ``accel`` m/s^2 (N, 3) body frame; the start row and
    its nominal state ``x0`` (16,) and covariance ``P0`` (15, 15); per GNSS fix: the row at or after it
    ``fix_row``, ``fix_lag`` = t[row] - t_fix [s], antenna ``z_fix`` (lat, lon [rad], h [m]), NED variances
    ``r_fix`` [m^2]; body lever arm IMU -> antenna [m]; ``noise`` = (q_vel [m^2/s^3], q_att [rad^2/s],
    q_bg [rad^2/s^3], q_ba [m^2/s^5], 1/tau_g, 1/tau_a [1/s], q_unit [rad^2/s], 1/tau_unit [1/s],
    q_drift [rad^2/s^3], unit roll/pitch white variance, unit yaw white variance [rad^2]).
    With ``unit_aiding``, the unit's roll, pitch and yaw ``unit_rpy`` (N, 3) [rad] are fused at every GNSS
    update row and at least once a second (also in GNSS outages): ``roll_u = roll + e_r``,
    ``pitch_u = pitch + e_p``, ``yaw_u = yaw - d``.

    Returns the nominal state at every row (N, 20) and, per covariance epoch: row, interval [s], P⁻ (only
    with ``keep_predicted``; the smoother recomputes it), P⁺, Φ, the feedback correction; per fix: innovation
    (NED m), its variance, status (1 used, 0 rejected, 2 forced, -1 unused).
    """
    n = t.shape[0]
    m = fix_row.shape[0]
    nav = np.full((n, NS), np.nan)
    max_epochs = (n - start_row) // stride + m + 2
    ep_row = np.zeros(max_epochs, dtype=np.int64)
    ep_dT = np.zeros(max_epochs)
    ep_Pm = np.zeros((max_epochs if keep_predicted else 1, NX, NX))
    ep_Pp = np.zeros((max_epochs, NX, NX))
    ep_Phi = np.zeros((max_epochs, NX, NX))
    ep_dx = np.zeros((max_epochs, NX))
    innov = np.full((m, 3), np.nan)
    innov_var = np.full((m, 3), np.nan)
    status = np.full(m, -1, dtype=np.int64)

    x = x0.copy()
    P = P0.copy()
    nav[start_row] = x
    ep_row[0] = start_row
    ep_Pm[0] = P
    ep_Pp[0] = P
    for i in range(NX):
        ep_Phi[0, i, i] = 1.0
    n_ep = 1
    dtheta = np.zeros(3)
    dvel = np.zeros(3)
    dtheta_prev = np.zeros(3)
    dvel_prev = np.zeros(3)
    C = np.empty((3, 3))
    quat_to_dcm(x[6:10], C)
    C_sum = np.zeros((3, 3))
    f_sum = np.zeros(3)
    count = 0
    x_epoch = x.copy()
    t_epoch = t[start_row]
    k_fix = 0
    while k_fix < m and fix_row[k_fix] <= start_row:
        k_fix += 1
    rejects = 0
    t_unit = t[start_row]
    q_vel, q_att, q_bg, q_ba, inv_tau_g, inv_tau_a = noise[0], noise[1], noise[2], noise[3], noise[4], noise[5]
    q_unit, inv_tau_unit, q_drift, r_level, r_yaw = noise[6], noise[7], noise[8], noise[9], noise[10]
    eye = np.eye(NX)
    for k in range(start_row + 1, n):
        dt = t[k] - t[k - 1]
        increments(gyro[k - 1], gyro[k], accel[k - 1], accel[k], dt, x, dtheta, dvel)
        if k == start_row + 1:
            dtheta_prev[:] = dtheta
            dvel_prev[:] = dvel
        C_start = C.copy()
        mechanise(x, dtheta, dvel, dtheta_prev, dvel_prev, dt, C)
        dtheta_prev[:] = dtheta
        dvel_prev[:] = dvel
        # the unit's nominal attitude errors
        x[16] += x[17] * dt
        decay = math.exp(-dt * inv_tau_unit)
        x[18] *= decay
        x[19] *= decay
        C_mid = 0.5 * (C_start + C)
        C_sum += C_mid
        f_sum += C_mid @ (dvel / dt)
        count += 1
        has_fix = k_fix < m and fix_row[k_fix] == k
        if count >= stride or has_fix or k == n - 1:
            dT = t[k] - t_epoch
            F = system_matrix(x_epoch, C_sum / count, f_sum / count, inv_tau_g, inv_tau_a, inv_tau_unit)
            Fd = F * dT
            Phi = eye + Fd + 0.5 * (Fd @ Fd)
            Q = _process_noise(q_vel, q_att, q_bg, q_ba, q_unit, q_drift, dT)
            P = Phi @ P @ Phi.T + Q
            ep_row[n_ep] = k
            ep_dT[n_ep] = dT
            if keep_predicted:
                ep_Pm[n_ep] = P
            ep_Phi[n_ep] = Phi
            dx_total = np.zeros(NX)
            if unit_aiding and (has_fix or t[k] - t_unit >= 1.0):
                t_unit = t[k]
                roll, pitch, yaw = dcm_to_euler(C)
                z = np.empty(3)
                z[0] = roll + x[18] - unit_rpy[k, 0]
                z[1] = pitch + x[19] - unit_rpy[k, 1]
                z[2] = yaw - x[16] - unit_rpy[k, 2]
                z[2] = (z[2] + math.pi) % (2.0 * math.pi) - math.pi
                H = np.zeros((3, NX))
                # Ĉ = exp(-[φ x]) C, so the estimated Euler angles exceed the true ones by -J φ
                H[:, 6:9] = -euler_error_jacobian(C)
                H[0, 15] = 1.0
                H[1, 16] = 1.0
                H[2, 17] = -1.0
                R = np.diag(np.array([r_level, r_level, r_yaw]))
                S = H @ P @ H.T + R
                S_inv = np.linalg.inv(S)
                if z @ S_inv @ z <= gate_chi2:
                    P = _apply_update(x, P, H, z, R, S_inv, C, dx_total)
            while k_fix < m and fix_row[k_fix] == k:
                # predicted antenna position at the fix time, innovation in NED metres
                M, N = radii(x[0])
                lever_n = C @ lever
                lag = fix_lag[k_fix]
                d_north = (x[0] - z_fix[k_fix, 0]) * (M + x[2]) + lever_n[0] - x[3] * lag
                d_east = (x[1] - z_fix[k_fix, 1]) * (N + x[2]) * math.cos(x[0]) + lever_n[1] - x[4] * lag
                d_down = -(x[2] - z_fix[k_fix, 2]) + lever_n[2] - x[5] * lag
                z = np.array([d_north, d_east, d_down])
                H = np.zeros((3, NX))
                for i in range(3):
                    H[i, i] = 1.0
                # (C l) x  ->  columns 6..8
                H[0, 7] = -lever_n[2]
                H[0, 8] = lever_n[1]
                H[1, 6] = lever_n[2]
                H[1, 8] = -lever_n[0]
                H[2, 6] = -lever_n[1]
                H[2, 7] = lever_n[0]
                R = np.diag(r_fix[k_fix])
                S = H @ P @ H.T + R
                S_inv = np.linalg.inv(S)
                d2 = z @ S_inv @ z
                for i in range(3):
                    innov[k_fix, i] = z[i]
                    innov_var[k_fix, i] = S[i, i]
                if d2 <= gate_chi2 or rejects >= max_rejects:
                    status[k_fix] = 1 if d2 <= gate_chi2 else 2
                    rejects = 0
                    P = _apply_update(x, P, H, z, R, S_inv, C, dx_total)
                else:
                    status[k_fix] = 0
                    rejects += 1
                k_fix += 1
            P = 0.5 * (P + P.T)
            ep_Pp[n_ep] = P
            ep_dx[n_ep] = dx_total
            n_ep += 1
            C_sum[:] = 0.0
            f_sum[:] = 0.0
            count = 0
            x_epoch[:] = x
            t_epoch = t[k]
        nav[k] = x
    return (nav, ep_row[:n_ep], ep_dT[:n_ep], ep_Pm[:n_ep] if keep_predicted else ep_Pm, ep_Pp[:n_ep],
            ep_Phi[:n_ep], ep_dx[:n_ep], innov, innov_var, status)


@njit(cache=True)
def rts_backward(ep_dT, ep_Pp, ep_Phi, ep_dx, noise):
    """RTS smoother over covariance epochs of the closed-loop filter, in place.

    ``P⁻_{j+1} = Φ P⁺_j Φ^T + Q`` is recomputed rather than stored, and the smoothed covariance overwrites
    ``ep_Pp``. Returns per epoch the smoothed error of the post-update nominal (E, NX) and of the pre-update
    nominal (E, NX); ``ep_Pp`` then holds the smoothed covariances.
    """
    n_ep = ep_Pp.shape[0]
    err_post = np.zeros((n_ep, NX))
    err_pre = np.zeros((n_ep, NX))
    err_pre[n_ep - 1] = ep_dx[n_ep - 1]
    for j in range(n_ep - 2, -1, -1):
        Phi = ep_Phi[j + 1]
        Q = _process_noise(noise[0], noise[1], noise[2], noise[3], noise[6], noise[8], ep_dT[j + 1])
        P_plus = ep_Pp[j].copy()
        P_minus = Phi @ P_plus @ Phi.T + Q
        # A = P+_j Phi^T (P-_{j+1})^-1, via a solve with the symmetric P-
        A = np.linalg.solve(P_minus, Phi @ P_plus).T
        err_post[j] = A @ err_pre[j + 1]
        err_pre[j] = ep_dx[j] + err_post[j]
        P_s = P_plus + A @ (ep_Pp[j + 1] - P_minus) @ A.T
        ep_Pp[j] = 0.5 * (P_s + P_s.T)
    return err_post, err_pre


@njit(cache=True)
def apply_row_corrections(t, nav, ep_row, err_post, err_pre, P_post, P_pre):
    """Correct every row between covariance epochs by the linearly interpolated error; per-row covariance.

    At epoch j the row carries ``err_post[j]`` and ``P_post[j]``; just before epoch j+1 the error tends to
    ``err_pre[j+1]`` and the covariance to ``P_pre[j+1]``. For the smoother pass its smoothed errors and
    ``P_post = P_pre = P_s``; for the forward filter zero errors, ``P_post = P+`` and ``P_pre = P-``.
    Returns the states (N, 20), corrected in place, position and velocity variances (N, 3) and
    attitude-error covariances (N, 3, 3).
    """
    n = nav.shape[0]
    out = nav  # corrected in place
    pos_var = np.full((n, 3), np.nan)
    vel_var = np.full((n, 3), np.nan)
    att_cov = np.full((n, 3, 3), np.nan)
    n_ep = ep_row.shape[0]
    e = np.empty(NX)
    for j in range(n_ep):
        r0 = ep_row[j]
        r1 = ep_row[j + 1] if j + 1 < n_ep else r0 + 1
        for r in range(r0, r1):
            w = 0.0 if r == r0 else (t[r] - t[r0]) / (t[r1] - t[r0])
            jn = j + 1 if r != r0 else j
            # interpolate only what is used: the error, position/velocity variances, attitude covariance
            for i in range(NX):
                e[i] = err_post[j, i] if r == r0 else (1.0 - w) * err_post[j, i] + w * err_pre[jn, i]
            correct_state(out[r], e)
            for i in range(3):
                pos_var[r, i] = (1.0 - w) * P_post[j, i, i] + w * P_pre[jn, i, i]
                vel_var[r, i] = (1.0 - w) * P_post[j, 3 + i, 3 + i] + w * P_pre[jn, 3 + i, 3 + i]
                for c in range(3):
                    att_cov[r, i, c] = (1.0 - w) * P_post[j, 6 + i, 6 + c] + w * P_pre[jn, 6 + i, 6 + c]
    return out, pos_var, vel_var, att_cov


@njit(cache=True)
def attitude_outputs(states: np.ndarray, att_cov: np.ndarray, valid: np.ndarray):
    """Per row: ZYX roll, pitch, yaw [rad] of the body and their 1-sigma from the NED tilt covariance."""
    n = states.shape[0]
    angles = np.full((n, 3), np.nan)
    sigma = np.full((n, 3), np.nan)
    C = np.empty((3, 3))
    for r in range(n):
        if not valid[r]:
            continue
        quat_to_dcm(states[r, 6:10], C)
        roll, pitch, yaw = dcm_to_euler(C)
        angles[r, 0], angles[r, 1], angles[r, 2] = roll, pitch, yaw
        J = euler_error_jacobian(C)
        S = J @ att_cov[r] @ J.T
        for i in range(3):
            sigma[r, i] = math.sqrt(max(S[i, i], 0.0))
    return angles, sigma


@njit(cache=True)
def run_ins(t, gyro, accel, start_row, x0, P0, fix_row, fix_lag, z_fix, r_fix, lever, noise, stride, gate_chi2,
            max_rejects, unit_rpy, unit_aiding, smooth):
    """The whole compiled path in one call (one cache load per process): filter, smoother if ``smooth``,
    per-row corrections and attitude outputs. Returns states (N, 20), position and velocity variances,
    attitude-error covariances, angles and their sigmas, epoch rows and sigmas, innovations and status."""
    nav, ep_row, ep_dT, ep_Pm, ep_Pp, ep_Phi, ep_dx, innov, innov_var, status = ekf_forward(
        t, gyro, accel, start_row, x0, P0, fix_row, fix_lag, z_fix, r_fix, lever, noise, stride, gate_chi2,
        max_rejects, unit_rpy, unit_aiding, not smooth)
    if smooth:
        err_post, err_pre = rts_backward(ep_dT, ep_Pp, ep_Phi, ep_dx, noise)
        states, pos_var, vel_var, att_cov = apply_row_corrections(t, nav, ep_row, err_post, err_pre, ep_Pp, ep_Pp)
    else:
        zeros = np.zeros((ep_row.shape[0], NX))
        states, pos_var, vel_var, att_cov = apply_row_corrections(t, nav, ep_row, zeros, zeros, ep_Pp, ep_Pm)
    valid = np.zeros(t.shape[0], dtype=np.bool_)
    for r in range(t.shape[0]):
        valid[r] = not math.isnan(states[r, 0])
    angles, att_sigma = attitude_outputs(states, att_cov, valid)
    epoch_sigma = np.empty((ep_row.shape[0], NX))
    for j in range(ep_row.shape[0]):
        for i in range(NX):
            epoch_sigma[j, i] = math.sqrt(max(ep_Pp[j, i, i], 0.0))
    return (states, pos_var, vel_var, att_cov, valid, angles, att_sigma, ep_row, epoch_sigma, innov, innov_var,
            status)
