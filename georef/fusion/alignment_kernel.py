"""Compiled body-frame preintegration for optimisation-based alignment (:mod:`georef.fusion.alignment`).

From a window's first row, the IMU is integrated in the *initial body frame* b0 with given gyro and
accelerometer biases, without any knowledge of the attitude (Savage's body-frame integrals; the bias Jacobians
as in Forster et al. 2017, "On-manifold preintegration for real-time visual-inertial odometry", IEEE T-RO 33):

* ``ΔC(t)`` = C_b(t)_b0, from the gyro increments ``θ = (½(ω_{k-1} + ω_k) - b_g) Δt``: ``ΔC_k = ΔC_{k-1} exp([θ x])``;
* ``α(t) = ∫ ΔC f dt`` [m/s] and ``β(t) = ∫∫ ΔC f dt dt`` [m], with ``f`` the bias-corrected specific force and the
  rotation taken at the middle of each interval (first-order sculling);
* ``γ(t) = ∫∫ (s - t0) ΔC f ds dt'`` [m s], which carries the Earth's rotation over the window;
* ``λ(t) = ΔC(t) l`` [m] for a body lever arm ``l``;
* Jacobians for a bias change ``δ``: ``ΔC(b_g + δ) ≈ ΔC exp([J δ] x)`` with ``J_k = exp([θ x])ᵀ J_{k-1} - J_r(θ) Δt``,
  and the derivatives of α, β and λ with respect to ``b_g`` and ``b_a``.

Values are returned at arbitrary sample times inside the window (GNSS fix times), by a partial step within the
IMU interval that holds them. The loop works on preallocated 3x3 arrays (no allocation per row).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from georef.frames.kernels import lever_arm_into, skew_into, so3_exp_into, so3_right_jacobian_into


@njit(cache=True)
def _matmul3(A: np.ndarray, B: np.ndarray, out: np.ndarray) -> None:
    for i in range(3):
        for j in range(3):
            out[i, j] = A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j]


# One of the named exceptions to the 100-line rule (README, Development): this is the alignment's innermost loop,
# run for every IMU row of every Gauss-Newton iteration of every start; split into compiled helpers (with the
# trapezoid increment of frames.kernels) it took half as long again on a multi-start alignment
# (docs/performance.md), so its row step stays written out.
@njit(cache=True)
def preintegrate(t, gyro, accel, row0, bias_g, bias_a, lever, sample_t):  # noqa: C901, PLR0915
    """Body-frame integrals from ``row0`` at the increasing ``sample_t`` [s] (all >= t[row0], <= t[-1]).

    Inputs: row times (N,) s, gyro [rad/s] and specific force [m/s^2] (N, 3) in the body frame, the biases
    (3,) subtracted from them, the body lever arm [m] (3,). Returns, per sample (K, ...): ΔC (K, 3, 3),
    α (K, 3), β (K, 3), γ (K, 3), λ (K, 3), J (K, 3, 3), dα/db_g, dα/db_a, dβ/db_g, dβ/db_a, dλ/db_g
    (K, 3, 3 each).
    """
    n = t.shape[0]
    K = sample_t.shape[0]
    out_C = np.zeros((K, 3, 3))
    out_alpha = np.zeros((K, 3))
    out_beta = np.zeros((K, 3))
    out_gamma = np.zeros((K, 3))
    out_lam = np.zeros((K, 3))
    out_J = np.zeros((K, 3, 3))
    out_da_g = np.zeros((K, 3, 3))
    out_da_a = np.zeros((K, 3, 3))
    out_db_g = np.zeros((K, 3, 3))
    out_db_a = np.zeros((K, 3, 3))
    out_dl_g = np.zeros((K, 3, 3))
    # running values
    run = np.zeros(4 * 3)          # alpha, beta, A1 (first moment), gamma
    dC = np.eye(3)
    J = np.zeros((3, 3))
    D = np.zeros((4, 3, 3))        # dα/db_g, dα/db_a, dβ/db_g, dβ/db_a
    # work arrays
    E = np.empty((3, 3))
    Eh = np.empty((3, 3))
    C_mid = np.empty((3, 3))
    Jr = np.empty((3, 3))
    W = np.empty((3, 3))
    nJ = np.empty((3, 3))
    nC = np.empty((3, 3))
    theta = np.empty(3)
    dv = np.empty(3)
    inc = np.empty(3)
    d_inc_g = np.empty((3, 3))
    t0 = t[row0]
    s = 0
    while s < K and sample_t[s] <= t0:
        out_C[s] = dC
        out_lam[s] = lever
        s += 1
    for k in range(row0 + 1, n):
        if s >= K:
            break
        dt_full = t[k] - t[k - 1]
        tau0 = t[k - 1] - t0
        # samples inside (t[k-1], t[k]]: a partial step with the interval's rates, then the full step
        while True:
            full = not (s < K and sample_t[s] <= t[k])
            w = 1.0 if full else (sample_t[s] - t[k - 1]) / dt_full
            dt = w * dt_full
            for i in range(3):
                theta[i] = (0.5 * (gyro[k - 1, i] + gyro[k, i]) - bias_g[i]) * dt
                dv[i] = (0.5 * (accel[k - 1, i] + accel[k, i]) - bias_a[i]) * dt
            so3_exp_into(theta, E)
            for i in range(3):
                theta[i] *= 0.5
            so3_exp_into(theta, Eh)
            for i in range(3):
                theta[i] *= 2.0
            _matmul3(dC, Eh, C_mid)
            for i in range(3):
                inc[i] = C_mid[i, 0] * dv[0] + C_mid[i, 1] * dv[1] + C_mid[i, 2] * dv[2]
            # d inc / d b_g = -C_mid [dv x] J
            skew_into(dv, W)
            _matmul3(W, J, nC)
            _matmul3(C_mid, nC, d_inc_g)
            tau_mid = tau0 + 0.5 * dt
            so3_right_jacobian_into(theta, Jr)
            # new J = Eᵀ J - J_r Δt
            for i in range(3):
                for j in range(3):
                    nJ[i, j] = E[0, i] * J[0, j] + E[1, i] * J[1, j] + E[2, i] * J[2, j] - Jr[i, j] * dt
            _matmul3(dC, E, nC)
            if full:
                for i in range(3):
                    run[3 + i] += run[i] * dt + 0.5 * inc[i] * dt                 # beta
                    run[9 + i] += run[6 + i] * dt + 0.5 * tau_mid * inc[i] * dt  # gamma
                    run[6 + i] += tau_mid * inc[i]                               # A1
                    run[i] += inc[i]                                             # alpha
                    for j in range(3):
                        D[2, i, j] += D[0, i, j] * dt - 0.5 * d_inc_g[i, j] * dt
                        D[3, i, j] += D[1, i, j] * dt - 0.5 * C_mid[i, j] * dt * dt
                        D[0, i, j] -= d_inc_g[i, j]
                        D[1, i, j] -= C_mid[i, j] * dt
                        J[i, j] = nJ[i, j]
                        dC[i, j] = nC[i, j]
                break
            for i in range(3):
                out_beta[s, i] = run[3 + i] + run[i] * dt + 0.5 * inc[i] * dt
                out_gamma[s, i] = run[9 + i] + run[6 + i] * dt + 0.5 * tau_mid * inc[i] * dt
                out_alpha[s, i] = run[i] + inc[i]
                for j in range(3):
                    out_db_g[s, i, j] = D[2, i, j] + D[0, i, j] * dt - 0.5 * d_inc_g[i, j] * dt
                    out_db_a[s, i, j] = D[3, i, j] + D[1, i, j] * dt - 0.5 * C_mid[i, j] * dt * dt
                    out_da_g[s, i, j] = D[0, i, j] - d_inc_g[i, j]
                    out_da_a[s, i, j] = D[1, i, j] - C_mid[i, j] * dt
                    out_J[s, i, j] = nJ[i, j]
                    out_C[s, i, j] = nC[i, j]
            lever_arm_into(nC, lever, out_lam[s])
            # dλ/db_g = -ΔC [l x] J
            skew_into(lever, W)
            _matmul3(W, nJ, Jr)
            _matmul3(nC, Jr, out_dl_g[s])
            for i in range(3):
                for j in range(3):
                    out_dl_g[s, i, j] = -out_dl_g[s, i, j]
            s += 1
    return out_C, out_alpha, out_beta, out_gamma, out_lam, out_J, out_da_g, out_da_a, out_db_g, out_db_a, out_dl_g
