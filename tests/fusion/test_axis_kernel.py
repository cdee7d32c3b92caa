"""The compiled per-axis filter against a plain matrix Kalman filter written independently here."""

from __future__ import annotations

import numpy as np

from georef.fusion.axis_kernel import axis_filter


def _reference(t_imu, acc, t_fix, z_fix, r_fix, v_init, q_white, s_cont):
    """Textbook KF per axis with explicit F, G, Q, H matrices (no gating)."""
    n = len(t_imu)
    out = np.full((n, 3), np.nan)
    var = np.full((n, 3), np.nan)
    for j in range(3):
        x = None
        P = None
        t_now = t_imu[0]
        k = 0
        events = sorted([(t, 0, i) for i, t in enumerate(t_imu)] + [(t, -1, i) for i, t in enumerate(t_fix)])
        for t, kind, i in events:
            row = np.searchsorted(t_imu, t, side="left") if kind == -1 else i
            a = 0.5 * (acc[max(row - 1, 0), j] + acc[row, j]) if row > 0 else acc[0, j]
            if x is not None:
                dt = t - t_now
                F = np.array([[1, dt], [0, 1]])
                G = np.array([0.5 * dt**2, dt])
                Q = q_white[j] * np.outer(G, G) + s_cont[j] * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
                x = F @ x + G * a
                P = F @ P @ F.T + Q
            if kind == -1:
                if x is None:
                    x = np.array([z_fix[i, j], v_init[j]])
                    P = np.diag([r_fix[i, j], 100.0])
                else:
                    H = np.array([[1.0, 0.0]])
                    S = H @ P @ H.T + r_fix[i, j]
                    K = P @ H.T / S
                    x = x + (K * (z_fix[i, j] - x[0])).ravel()
                    P = (np.eye(2) - K @ H) @ P
                k += 1
            else:
                if x is not None:
                    out[i, j] = x[0]
                    var[i, j] = P[0, 0]
            t_now = t
    return out, var


def test_compiled_filter_equals_textbook_filter():
    rng = np.random.default_rng(5)
    t_imu = 10.0 + 0.013 + np.arange(400) / 50.0
    acc = rng.normal(0, 0.5, (400, 3))
    t_fix = np.arange(11.0, 18.0, 1.0)
    z_fix = rng.normal(0, 2.0, (len(t_fix), 3))
    r_fix = np.tile([1.0, 2.0, 4.0], (len(t_fix), 1))
    args = (t_imu, acc, t_fix, z_fix, r_fix, np.array([1.0, -1.0, 0.5]), np.array([0.1, 0.2, 0.3]),
            np.array([0.01, 0.02, 0.03]))
    pos, _, var_p, _, _, _, _, status = axis_filter(*args, 1e9, 5)
    ref_pos, ref_var = _reference(*args)
    np.testing.assert_allclose(pos, ref_pos, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(var_p, ref_var, rtol=1e-10, atol=1e-12)
    assert np.isnan(pos[t_imu < 11.0]).all() and np.isfinite(pos[t_imu >= 11.0]).all()
    assert (status == 1).all()


def test_gate_rejects_an_outlier_and_recovers():
    t_imu = np.arange(0, 30, 0.02)
    acc = np.zeros((len(t_imu), 3))
    t_fix = np.arange(0.0, 30.0, 1.0)
    z_fix = np.zeros((len(t_fix), 3))
    z_fix[12] += [30.0, 0, 0]
    r_fix = np.ones((len(t_fix), 3))
    *_, innov, _, status = axis_filter(t_imu, acc, t_fix, z_fix, r_fix, np.zeros(3), np.full(3, 1e-4),
                                               np.full(3, 1e-3), 16.27, 5)
    assert status[12] == 0 and (np.delete(status, 12) == 1).all()
    assert innov[12, 0] > 25.0
