"""The compiled window solve of the yaw-origin recovery (georef.fusion.yaw_offset_kernel) against its model: a
synthetic window built from known parameters, and scipy.optimize.least_squares on the same nonlinear model as
the independent reference for the estimate and its sigma."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from georef.aot import load
from georef.fusion.yaw_offset import HUBER_K

SIG = np.array([0.8, 1.1])  # north, east sigmas [m]


def _rotate(d: float, v: np.ndarray) -> np.ndarray:
    c, s = np.cos(d), np.sin(d)
    return np.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1]], -1)


def _window(rng: np.random.Generator, d: float, noise: float):
    """A 41-s window of a turning track: (r_n, tau, A, B) and the true parameters (p0, v0, b_n, b)."""
    tau = np.arange(-20.0, 21.0)
    heading = 0.05 * tau + 0.002 * tau**2
    A = np.stack([60.0 * np.sin(heading) + 3.0 * tau, 60.0 * (1.0 - np.cos(heading))], -1)
    # double integrals of the body x, y columns of C_b_u: the body turns with the heading
    cols = np.stack([np.stack([np.cos(heading), -np.sin(heading)], -1),
                     np.stack([np.sin(heading), np.cos(heading)], -1)], -1)  # (n, 2 [N, E], 2 [x, y])
    B = cols * (tau**2 / 2.0)[:, None, None]
    p0, v0, b_n, b = np.array([5.0, -3.0]), np.array([40.0, 12.0]), np.array([0.01, -0.02]), np.array([0.03, 0.02])
    r_n = (p0 + v0 * tau[:, None] + b_n * tau[:, None] ** 2 / 2.0
           + _rotate(d, A - np.einsum("nij,j->ni", B, b)))
    r_n += noise * SIG * rng.standard_normal(r_n.shape)
    return r_n, tau, A, B


def _model_residual(params: np.ndarray, r_n, tau, A, B) -> np.ndarray:
    p0, v0, b_n, b, d = params[0:2], params[2:4], params[4:6], params[6:8], params[8]
    model = p0 + v0 * tau[:, None] + b_n * tau[:, None] ** 2 / 2.0 + _rotate(d, A - np.einsum("nij,j->ni", B, b))
    return ((r_n - model) / SIG).T.reshape(-1)


@pytest.mark.parametrize("d_true", [0.3, 2.5, -1.9, -3.0])
def test_noise_free_window_gives_the_true_offset(d_true):
    r_n, tau, A, B = _window(np.random.default_rng(1), d_true, noise=0.0)
    d, sigma = load("yaw").window_solve(r_n, tau, A, B, SIG, HUBER_K)
    assert np.angle(np.exp(1j * (d - d_true))) == pytest.approx(0.0, abs=1e-9)
    # the formal sigma (unit-variance observations; the variance factor is floored at 1): sqrt((JᵀJ)⁻¹) at the truth
    truth = np.r_[5.0, -3.0, 40.0, 12.0, 0.01, -0.02, 0.03, 0.02, d_true]
    jac = np.empty((2 * len(tau), 9))
    for i in range(9):
        step = np.zeros(9)
        step[i] = 1e-6
        ahead, behind = (_model_residual(truth + sign * step, r_n, tau, A, B) for sign in (1.0, -1.0))
        jac[:, i] = (ahead - behind) / 2e-6
    assert sigma == pytest.approx(np.sqrt(np.linalg.inv(jac.T @ jac)[8, 8]), rel=1e-6)


@pytest.mark.parametrize("seed", [2, 3, 4])
def test_noisy_window_matches_scipy_least_squares(seed):
    """Noise of a tenth of the sigmas: every normalised residual stays under Huber's threshold, so the estimate
    is the plain least-squares one, and its sigma sqrt((JᵀJ)⁻¹) (the variance factor is below 1). Gauss-Newton
    stops once a step is below a thousandth of the window's sigma: that is the agreement asked for."""
    rng = np.random.default_rng(seed)
    d_true = rng.uniform(-np.pi, np.pi)
    r_n, tau, A, B = _window(rng, d_true, noise=0.1)
    d, sigma = load("yaw").window_solve(r_n, tau, A, B, SIG, HUBER_K)
    start = np.zeros(9)
    start[8] = d_true + 0.05
    ref = least_squares(_model_residual, start, args=(r_n, tau, A, B), method="lm", xtol=1e-15, ftol=1e-15,
                        gtol=1e-15)
    assert np.max(np.abs(ref.fun)) < HUBER_K
    assert np.angle(np.exp(1j * (d - ref.x[8]))) == pytest.approx(0.0, abs=1e-3 * sigma)
    ref_sigma = np.sqrt(np.linalg.inv(ref.jac.T @ ref.jac)[8, 8])
    assert sigma == pytest.approx(ref_sigma, rel=1e-6)


def test_outlier_is_down_weighted():
    """One fix 40 sigma off: Huber's weights keep the offset within a few of its sigmas of the truth."""
    rng = np.random.default_rng(5)
    r_n, tau, A, B = _window(rng, 1.0, noise=1.0)
    d_clean, sigma = load("yaw").window_solve(r_n, tau, A, B, SIG, HUBER_K)
    r_n[30] += 40.0 * SIG
    d, _ = load("yaw").window_solve(r_n, tau, A, B, SIG, HUBER_K)
    plain = least_squares(_model_residual, np.r_[np.zeros(8), 1.0], args=(r_n, tau, A, B), method="lm").x[8]
    assert abs(d - 1.0) < 4.0 * sigma
    assert abs(d - d_clean) < abs(plain - d_clean)


def test_huber_lstsq_against_ordinary_and_robust_references():
    """The compiled Huber fit (the windows' linear start and the flight's offset and drift fit): on clean
    unit-variance data it is ordinary least squares, with numpy's solution and covariance ``(AᵀA)⁻¹`` times the
    a-posteriori variance factor when above 1; with gross outliers it lands where scipy's Huber loss puts the
    minimum (six reweightings: to a hundredth of the clean fit's sigma) and far from ordinary least squares."""
    rng = np.random.default_rng(5)
    t = np.linspace(-60.0, 60.0, 41)
    design = np.ascontiguousarray(np.stack([np.ones_like(t), t / 60.0], -1))
    truth = np.array([0.3, -0.8])
    clean = design @ truth + 0.5 * rng.standard_normal(len(t))   # noise below the stated 1: factor stays 1
    solution, covariance = load("yaw").huber_lstsq(design, clean, HUBER_K)
    ordinary, *_ = np.linalg.lstsq(design, clean, rcond=None)
    residual = clean - design @ ordinary
    assert np.all(np.abs(residual) <= HUBER_K)   # every weight stays 1
    np.testing.assert_allclose(solution, ordinary, rtol=0, atol=1e-12)
    factor = max(1.0, residual @ residual / (len(t) - 2))
    np.testing.assert_allclose(covariance, np.linalg.inv(design.T @ design) * factor, rtol=1e-10, atol=1e-15)
    noisy = design @ truth + 2.0 * rng.standard_normal(len(t))     # noisier than stated: the factor inflates
    _, inflated = load("yaw").huber_lstsq(design, noisy, HUBER_K)
    assert np.all(np.diag(inflated) > 1.5 * np.diag(np.linalg.inv(design.T @ design)))
    outliers = clean.copy()
    outliers[[3, 17, 30]] += [40.0, -25.0, 60.0]
    robust, _ = load("yaw").huber_lstsq(design, outliers, HUBER_K)
    reference = least_squares(lambda x: design @ x - outliers, np.zeros(2), loss="huber", f_scale=HUBER_K).x
    sigma = np.sqrt(np.diag(np.linalg.inv(design.T @ design)))
    assert np.all(np.abs(robust - reference) < 0.01 * sigma)
    assert np.all(np.abs(robust - truth) < 3.0 * sigma)
    ordinary_outliers, *_ = np.linalg.lstsq(design, outliers, rcond=None)
    assert np.abs(ordinary_outliers - truth).max() > 5.0 * np.abs(robust - truth).max()
