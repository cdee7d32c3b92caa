"""Compiled recursion of the per-axis [position, velocity] Kalman filter (numba, cached)."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _predict(p, v, Ppp, Ppv, Pvv, acc, dt, q_white, s_cont):
    """Propagate the three independent [p, v] filters over ``dt`` [s] with input acceleration ``acc``.

    F = [[1, dt], [0, 1]], G = [dt^2/2, dt]; Q = q_white G G^T + s_cont [[dt^3/3, dt^2/2], [dt^2/2, dt]].
    """
    for j in range(3):
        p[j] += v[j] * dt + 0.5 * acc[j] * dt * dt
        v[j] += acc[j] * dt
        pp = Ppp[j] + 2.0 * dt * Ppv[j] + dt * dt * Pvv[j]
        pv = Ppv[j] + dt * Pvv[j]
        g0 = 0.5 * dt * dt
        Ppp[j] = pp + q_white[j] * g0 * g0 + s_cont[j] * dt**3 / 3.0
        Ppv[j] = pv + q_white[j] * g0 * dt + s_cont[j] * dt * dt / 2.0
        Pvv[j] = Pvv[j] + q_white[j] * dt * dt + s_cont[j] * dt


@njit(cache=True)
def axis_filter(t_imu, acc_e, t_fix, z_fix, r_fix, v_init, q_white, s_cont, gate_chi2, max_rejects):
    """Run three per-axis [p, v] Kalman filters over IMU rows with GNSS position updates.

    Inputs: ``t_imu`` (N,) s; ``acc_e`` (N, 3) m/s^2; ``t_fix`` (M,) s; ``z_fix`` (M, 3) m, IMU position
    measurements; ``r_fix`` (M, 3) m^2 measurement variances; ``v_init`` (3,) m/s starting velocity;
    ``q_white`` (3,) (m/s^2)^2 per-sample input noise; ``s_cont`` (3,) m^2/s^3 acceleration-error PSD.

    Returns per row: position, velocity, var(p), cov(p, v), var(v) (NaN before the first fix), and per fix:
    innovations (M, 3), innovation variances (M, 3), status (1 used, 0 rejected by the gate,
    2 accepted after ``max_rejects`` consecutive rejections, -1 outside the IMU span).
    """
    n = t_imu.shape[0]
    m = t_fix.shape[0]
    pos = np.full((n, 3), np.nan)
    vel = np.full((n, 3), np.nan)
    var_p = np.full((n, 3), np.nan)
    cov_pv = np.full((n, 3), np.nan)
    var_v = np.full((n, 3), np.nan)
    innov = np.full((m, 3), np.nan)
    innov_var = np.full((m, 3), np.nan)
    status = np.full(m, -1, dtype=np.int64)
    p = np.zeros(3)
    v = np.zeros(3)
    Ppp = np.zeros(3)
    Ppv = np.zeros(3)
    Pvv = np.zeros(3)
    started = False
    k = 0
    while k < m and t_fix[k] < t_imu[0]:
        k += 1
    rejects = 0
    t_now = t_imu[0]
    for i in range(n):
        acc = acc_e[i - 1] if i > 0 else acc_e[0]
        if i > 0:
            acc = 0.5 * (acc_e[i - 1] + acc_e[i])
        # fixes inside (t_now, t_imu[i]]
        while k < m and t_fix[k] <= t_imu[i]:
            if started:
                _predict(p, v, Ppp, Ppv, Pvv, acc, t_fix[k] - t_now, q_white, s_cont)
                d2 = 0.0
                for j in range(3):
                    innov[k, j] = z_fix[k, j] - p[j]
                    innov_var[k, j] = Ppp[j] + r_fix[k, j]
                    d2 += innov[k, j] ** 2 / innov_var[k, j]
                if d2 <= gate_chi2 or rejects >= max_rejects:
                    status[k] = 1 if d2 <= gate_chi2 else 2
                    rejects = 0
                    for j in range(3):
                        s = innov_var[k, j]
                        kp = Ppp[j] / s
                        kv = Ppv[j] / s
                        p[j] += kp * innov[k, j]
                        v[j] += kv * innov[k, j]
                        pp, pv, vv = Ppp[j], Ppv[j], Pvv[j]
                        Ppp[j] = pp - kp * pp
                        Ppv[j] = pv - kp * pv
                        Pvv[j] = vv - kv * pv
                else:
                    status[k] = 0
                    rejects += 1
            else:
                started = True
                status[k] = 1
                for j in range(3):
                    p[j] = z_fix[k, j]
                    v[j] = v_init[j]
                    Ppp[j] = r_fix[k, j]
                    Ppv[j] = 0.0
                    Pvv[j] = 100.0
            t_now = t_fix[k]
            k += 1
        if started:
            _predict(p, v, Ppp, Ppv, Pvv, acc, t_imu[i] - t_now, q_white, s_cont)
            for j in range(3):
                pos[i, j] = p[j]
                vel[i, j] = v[j]
                var_p[i, j] = Ppp[j]
                cov_pv[i, j] = Ppv[j]
                var_v[i, j] = Pvv[j]
        t_now = t_imu[i]
    return pos, vel, var_p, cov_pv, var_v, innov, innov_var, status
