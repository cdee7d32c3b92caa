"""Compiled solve of one window of the yaw-origin recovery (:mod:`georef.fusion.yaw_offset`, its docstring has the
model).

The same steps as written there, in the same floating-point order: the linear start by Huber IRLS, then
variable projection on the offset ``d`` by Gauss-Newton with Huber reweighting, the covariance from the full
Jacobian at the solution. Least squares and the pseudo-inverse go through LAPACK's ``gelsd`` and ``gesdd``
as numpy's ``lstsq`` and ``pinv`` do (numpy's default cut-offs), so the offsets and sigmas equal those of the
numpy version of these steps bit for bit on the flights measured (docs/method-ins.md, "Speed"). Compiled, the
54 windows of a 15-minute flight take 0.04 s of CPU instead of 0.19 s: each window solves about twenty small
least-squares problems, and numpy's per-call overhead was most of their cost.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

#: float64 machine epsilon: numpy's default ``lstsq`` cut-off is ``EPS * max(rows, columns)``
EPS = 2.220446049250313e-16
#: Gauss-Newton steps at most, and the largest step in ``d`` [rad]
GN_ITERATIONS = 12
GN_MAX_STEP = 0.2
#: windows whose linear start has a sigma above this [rad] are not refined (no usable acceleration)
REFINE_MAX_SIGMA = math.radians(20.0)


@njit(cache=True)
def _lstsq_weighted(design: np.ndarray, obs: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Least-squares solution of ``design x = obs`` with rows scaled by ``sqrt(weights)``."""
    m, p = design.shape
    a = np.empty((m, p))
    b = np.empty(m)
    for r in range(m):
        s = math.sqrt(weights[r])
        for c in range(p):
            a[r, c] = design[r, c] * s
        b[r] = obs[r] * s
    return np.linalg.lstsq(a, b, rcond=EPS * max(m, p))[0]


@njit(cache=True)
def _huber_weights(residual: np.ndarray, k: float, weights: np.ndarray) -> None:
    """Huber weights (threshold ``k``) of normalised residuals, written into ``weights``."""
    for r in range(residual.shape[0]):
        size = abs(residual[r])
        weights[r] = 1.0 if size <= k else k / max(size, 1e-12)


@njit(cache=True)
def _pinv(a: np.ndarray) -> np.ndarray:
    """numpy.linalg.pinv's steps: SVD, singular values at or below 1e-15 of the largest dropped."""
    u, s, vt = np.linalg.svd(a, full_matrices=False)
    cutoff = 1e-15 * np.max(s)
    scaled = np.empty((s.shape[0], u.shape[0]))
    for i in range(s.shape[0]):
        inverse = 1.0 / s[i] if s[i] > cutoff else 0.0
        for j in range(u.shape[0]):
            scaled[i, j] = inverse * u[j, i]
    return np.ascontiguousarray(vt.T) @ scaled


@njit(cache=True)
def _covariance(design: np.ndarray, residual: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Covariance of a weighted fit, inflated by the a-posteriori variance factor when it exceeds 1."""
    m, p = design.shape
    normal = design.T @ (design * weights.reshape(m, 1))
    variance_factor = max(1.0, np.dot(weights, residual**2) / max(1, m - p))
    return _pinv(normal) * variance_factor


@njit(cache=True)
def _jacobian_and_residual(d: float, weights: np.ndarray, A: np.ndarray, B: np.ndarray, obs: np.ndarray,
                           sig: np.ndarray, jac: np.ndarray, target: np.ndarray, residual: np.ndarray) -> None:
    """At offset ``d`` [rad]: the linear parameters solved exactly; fills the bias columns (6, 7) and the d column
    (8) of ``jac`` (2n, 9; columns 0-5 hold the affine part), the target and the residual (2n,)."""
    n = A.shape[0]
    c, s = math.cos(d), math.sin(d)
    for k in range(n):
        for j in range(2):
            x, y = B[k, 0, j], B[k, 1, j]
            jac[k, 6 + j] = -((c * x - s * y) / sig[0])
            jac[n + k, 6 + j] = -((s * x + c * y) / sig[1])
        x, y = A[k, 0], A[k, 1]
        target[k] = obs[k] - (c * x - s * y) / sig[0]
        target[n + k] = obs[n + k] - (s * x + c * y) / sig[1]
    design = np.ascontiguousarray(jac[:, :8])
    solution = _lstsq_weighted(design, target, weights)
    fitted = design @ solution
    for r in range(2 * n):
        residual[r] = target[r] - fitted[r]
    # d/dd R(d) v = R(d + 90 deg) v
    c, s = math.cos(d + math.pi / 2), math.sin(d + math.pi / 2)
    for k in range(n):
        x = A[k, 0] - (B[k, 0, 0] * solution[6] + B[k, 0, 1] * solution[7])
        y = A[k, 1] - (B[k, 1, 0] * solution[6] + B[k, 1, 1] * solution[7])
        jac[k, 8] = (c * x - s * y) / sig[0]
        jac[n + k, 8] = (s * x + c * y) / sig[1]


@njit(cache=True)
def huber_lstsq(design: np.ndarray, obs: np.ndarray, huber_k: float) -> tuple[np.ndarray, np.ndarray]:
    """Huber IRLS (six reweighted solves, threshold ``huber_k``) of ``design x = obs`` for unit-variance
    observations: the solution and its covariance, inflated by the a-posteriori variance factor when that
    exceeds 1 (observations noisier than their stated sigma). The window's linear start and the flight's offset
    and drift fit both use it."""
    m = design.shape[0]
    weights = np.ones(m)
    residual = np.empty(m)
    solution = np.zeros(design.shape[1])
    for _ in range(6):
        solution = _lstsq_weighted(design, obs, weights)
        fitted = design @ solution
        for r in range(m):
            residual[r] = abs(obs[r] - fitted[r])
        _huber_weights(residual, huber_k, weights)
    fitted = design @ solution
    for r in range(m):
        residual[r] = obs[r] - fitted[r]
    return solution, _covariance(design, residual, weights)


@njit(cache=True)
def window_solve(r_n: np.ndarray, tau: np.ndarray, A: np.ndarray, B: np.ndarray, sig: np.ndarray,
                 huber_k: float) -> np.ndarray:
    """Yaw offset ``d`` [rad, not wrapped] and its 1-sigma [rad] of one window.

    Inputs (n fixes): the antenna track ``r_n`` (n, 2) [m, north and east from the centre fix], the times from the
    centre fix ``tau`` (n,) [s], the double integral of the unit's level-frame acceleration plus the horizontal
    lever arm ``A`` (n, 2) [m], the double integrals of the body x and y columns of ``C_b_u`` ``B`` (n, 2, 2)
    [s^2], the north and east sigmas ``sig`` (2,) [m], Huber's threshold on the normalised residuals. Returns
    ``(d, sigma)`` (2,).
    """
    n = tau.shape[0]
    m = 2 * n
    obs = np.empty(m)
    # 1. linear start: columns p0N p0E v0N v0E bN bE c s, rows north then east, each divided by its sigma
    start = np.zeros((m, 8))
    for k in range(n):
        obs[k] = r_n[k, 0] / sig[0]
        obs[n + k] = r_n[k, 1] / sig[1]
        half = tau[k] ** 2 / 2
        start[k, 0], start[k, 2], start[k, 4] = 1.0 / sig[0], tau[k] / sig[0], half / sig[0]
        start[k, 6], start[k, 7] = A[k, 0] / sig[0], -A[k, 1] / sig[0]
        start[n + k, 1], start[n + k, 3], start[n + k, 5] = 1.0 / sig[1], tau[k] / sig[1], half / sig[1]
        start[n + k, 6], start[n + k, 7] = A[k, 1] / sig[1], A[k, 0] / sig[1]
    solution, cov = huber_lstsq(start, obs, huber_k)
    weights = np.ones(m)
    residual = np.empty(m)
    out = np.empty(2)
    d = math.atan2(solution[7], solution[6])
    norm2 = max(solution[6] ** 2 + solution[7] ** 2, 1e-12)
    g0, g1 = -solution[7] / norm2, solution[6] / norm2
    # gradᵀ C grad, as (grad C) grad
    v0 = g0 * cov[6, 6] + g1 * cov[7, 6]
    v1 = g0 * cov[6, 7] + g1 * cov[7, 7]
    sigma0 = math.sqrt(max(v0 * g0 + v1 * g1, 0.0))
    if sigma0 > REFINE_MAX_SIGMA:
        out[0], out[1] = d, sigma0
        return out
    # 2. variable projection in d: columns p0N p0E v0N v0E bN bE bx by, d
    jac = np.zeros((m, 9))
    for r in range(m):
        for c in range(6):
            jac[r, c] = start[r, c]
    target = np.empty(m)
    # Reweighting makes convergence linear; steps below a thousandth of the window's sigma change nothing.
    converged = max(1e-3 * sigma0, 1e-8)
    weights[:] = 1.0
    for iteration in range(GN_ITERATIONS):
        _jacobian_and_residual(d, weights, A, B, obs, sig, jac, target, residual)
        step = _lstsq_weighted(jac, residual, weights)
        d += min(max(step[8], -GN_MAX_STEP), GN_MAX_STEP)
        if iteration >= 1:
            _huber_weights(residual, huber_k, weights)
        if abs(step[8]) < converged and iteration >= 2:
            break
    _jacobian_and_residual(d, weights, A, B, obs, sig, jac, target, residual)
    cov = _covariance(jac, residual, weights)
    out[0], out[1] = d, math.sqrt(max(cov[8, 8], 0.0))
    return out
