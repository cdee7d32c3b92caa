"""The smoother's prior mean stays the prior's whatever point a pass linearises about (issue: re-linearisation
without moving the prior).

On a linear-Gaussian model the closed-loop filter started at a nominal point other than the prior mean, with the
start's error carried by ``prior_shift`` into the RTS smoother, must give exactly the smoother of the filter
started at the prior mean; started there without the carried error (what every pass after the first did before)
it gives something else."""

from __future__ import annotations

import numpy as np
import pytest

from georef import aot
from georef.fusion import ins_layout as layout

NX = layout.NX_NAV


def _model(rng: np.random.Generator, n_ep: int):
    """A random stable linear model with a weakly observed direction: measurements see 3 of NX states."""
    Phi = np.eye(NX) + 0.02 * rng.standard_normal((n_ep, NX, NX))
    Q = np.diag(rng.uniform(1e-4, 1e-2, NX))
    H = np.zeros((3, NX))
    H[:, :3] = np.eye(3)
    H[:, 3:6] += 0.3 * rng.standard_normal((3, 3))
    R = np.diag([0.5, 0.5, 1.0])
    P0 = np.diag(rng.uniform(0.5, 4.0, NX))
    truth = np.zeros((n_ep, NX))
    truth[0] = rng.multivariate_normal(np.zeros(NX), P0)
    for k in range(1, n_ep):
        truth[k] = Phi[k] @ truth[k - 1] + rng.multivariate_normal(np.zeros(NX), Q)
    y = truth[:, :3] @ np.eye(3).T + np.einsum("ij,kj->ki", H[:, 3:6], truth[:, 3:6]) + \
        rng.multivariate_normal(np.zeros(3), R, size=n_ep)
    return Phi, Q, H, R, P0, y


def _closed_loop(Phi, Q, H, R, P0, y, start):
    """The closed-loop filter's records (as ``ekf_forward`` writes them) from the nominal start ``start``: the
    nominal after and before each epoch's update, P⁻, P⁺, and the injected correction (estimate minus truth)."""
    n_ep = len(y)
    x_post, x_pre = np.zeros((n_ep, NX)), np.zeros((n_ep, NX))
    Pm, Pp, dx = np.zeros((n_ep, NX, NX)), np.zeros((n_ep, NX, NX)), np.zeros((n_ep, NX))
    x, P = start.copy(), P0.copy()
    for k in range(n_ep):
        if k:
            x, P = Phi[k] @ x, Phi[k] @ P @ Phi[k].T + Q
        x_pre[k], Pm[k] = x, P
        if k:  # no update at the start epoch, as in the kernel
            S = H @ P @ H.T + R
            K = P @ H.T @ np.linalg.inv(S)
            correction = K @ (y[k] - H @ x)
            x = x + correction
            P = (np.eye(NX) - K @ H) @ P
            P = 0.5 * (P + P.T)
            dx[k] = -correction
        x_post[k], Pp[k] = x, P
    return x_post, x_pre, Pm, Pp, dx


def _smoothed(kernel, Phi, Pm, Pp, dx, m_plus):
    n_ep = len(Pm)
    seg = np.zeros(n_ep, dtype=bool)
    seg[0] = True
    i0, f2, f3 = np.zeros(0, dtype=np.int64), np.zeros((0, 3)), np.zeros((0, 3, NX))
    return kernel.rts_backward(np.full(n_ep, 0.5), Pm, Pp.copy(), Phi, dx, seg, np.zeros(n_ep, dtype=bool),
                               np.ones(layout.N_NOISE), i0, f2, f3, f2, i0, i0, i0, f2, f3, i0, f2, False, m_plus)


@pytest.mark.parametrize("seed", [0, 1])
def test_a_pass_linearised_elsewhere_keeps_the_prior_mean(seed):
    rng = np.random.default_rng(seed)
    kernel = aot.load("ins")
    Phi, Q, H, R, P0, y = _model(rng, 60)
    prior_mean = np.zeros(NX)
    reference = _closed_loop(Phi, Q, H, R, P0, y, prior_mean)
    err_post, err_pre, _ = _smoothed(kernel, Phi, reference[2], reference[3], reference[4], np.zeros((60, NX)))
    smoothed = reference[0] - err_post
    np.testing.assert_allclose(reference[1] - err_pre, smoothed, atol=1e-9)

    start = prior_mean + rng.multivariate_normal(np.zeros(NX), 4.0 * P0)  # a pass's other linearisation point
    moved = _closed_loop(Phi, Q, H, R, P0, y, start)
    seg = np.zeros(60, dtype=bool)
    seg[0] = True
    m_plus, m_minus = kernel.prior_shift(moved[2], moved[3], Phi, seg, start - prior_mean)
    np.testing.assert_allclose(moved[0] - m_plus, reference[0], atol=1e-8)   # the filter's own mean, too
    np.testing.assert_allclose(moved[1] - m_minus, reference[1], atol=1e-8)
    err_post, err_pre, _ = _smoothed(kernel, Phi, moved[2], moved[3], moved[4], m_plus)
    np.testing.assert_allclose(moved[0] - err_post, smoothed, atol=1e-8)
    np.testing.assert_allclose(moved[1] - err_pre, smoothed, atol=1e-8)

    # without the carried error the start moves the smoothed states where the data see them weakly
    err_post, _, _ = _smoothed(kernel, Phi, moved[2], moved[3], moved[4], np.zeros((60, NX)))
    assert np.max(np.abs(moved[0] - err_post - smoothed)) > 0.1


def test_no_shift_after_a_restart():
    rng = np.random.default_rng(2)
    kernel = aot.load("ins")
    Phi, Q, H, R, P0, y = _model(rng, 30)
    moved = _closed_loop(Phi, Q, H, R, P0, y, np.ones(NX))
    seg = np.zeros(30, dtype=bool)
    seg[[0, 20]] = True
    m_plus, m_minus = kernel.prior_shift(moved[2], moved[3], Phi, seg, np.ones(NX))
    assert np.all(m_plus[20:] == 0.0) and np.all(m_minus[20:] == 0.0)
    assert np.all(np.abs(m_plus[19]) > 0.0)
