"""The INS kernel's measurement models (georef.fusion.ins_kernel): every measurement Jacobian against finite
differences of the measurement itself, and a check that the comparison would catch a wrong one."""

from __future__ import annotations

import numpy as np
import pytest

from georef.frames import dcm_to_quat, euler_to_dcm
from georef.fusion import ins_kernel as kernel
from georef.fusion import ins_layout as layout


# ---- measurement Jacobians against finite differences -----------------------------------------------------------
def _nominal() -> np.ndarray:
    x = np.zeros(layout.NS)
    x[layout.X_LAT], x[layout.X_LON], x[layout.X_HGT] = np.radians(45.0), np.radians(15.0), 300.0
    x[layout.X_VEL:layout.X_VEL + 3] = [7.0, -4.0, 0.5]
    x[layout.X_QUAT:layout.X_QUAT + 4] = dcm_to_quat(euler_to_dcm(0.1, -0.05, 1.2))
    x[layout.X_BG:layout.X_BG + 3] = [1e-4, -2e-4, 3e-4]
    x[layout.X_LEVER:layout.X_LEVER + 3] = [0.5, -0.2, -1.0]
    x[layout.X_LATENCY] = 0.05
    x[layout.X_UNIT_LEVEL:layout.X_UNIT_LEVEL + 2] = [0.001, -0.002]
    x[layout.X_UNIT_YAW] = 0.3
    return x


def _dcm(x: np.ndarray) -> np.ndarray:
    C = np.empty((3, 3))
    kernel.quat_to_dcm(x[layout.X_QUAT:layout.X_QUAT + 4], C)
    return C


FIX = np.array([np.radians(45.0) + 1e-6, np.radians(15.0) - 2e-6, 301.0])
MEASUREMENTS = {
    "gnss": lambda x, C: kernel.gnss_innovation(x, C, FIX, 0.01, layout.NX_CAL),
    "unit attitude": lambda x, C: kernel.unit_attitude_innovation(x, C, np.array([0.1, -0.05, 0.9]), layout.NX_CAL),
    "non-holonomic": lambda x, C: kernel.nhc_innovation(x, C, layout.NX_CAL),
}


def _numeric_column(function, x_hat: np.ndarray, state: int) -> np.ndarray:
    """(z(x_hat) - z(x_true)) / step with x_true the estimate with a small error in ``state`` removed."""
    step = 1e-7 if layout.ATT <= state < layout.ATT + 3 else 1e-6
    error = np.zeros(layout.NX_CAL)
    error[state] = step
    x_true = kernel.corrected(x_hat, error)
    return (function(x_hat, _dcm(x_hat))[0] - function(x_true, _dcm(x_true))[0]) / step


@pytest.mark.parametrize("name", MEASUREMENTS)
def test_measurement_jacobians_match_finite_differences(name):
    """For every error state: the predicted measurement of the truth (the estimate with a small error removed,
    :func:`corrected`) differs from the estimate's by H times that error, to first order."""
    function = MEASUREMENTS[name]
    x_hat = _nominal()
    _, H = function(x_hat, _dcm(x_hat))
    assert H.shape[1] == layout.NX_CAL
    for state in range(layout.NX_CAL):
        numeric = _numeric_column(function, x_hat, state)
        scale = max(1.0, float(np.abs(H[:, state]).max()))
        assert np.abs(numeric - H[:, state]).max() <= 1e-3 * scale, (name, state, numeric, H[:, state])


def test_a_wrong_jacobian_would_be_caught():
    """The check above has teeth: the GNSS position's sensitivity to the attitude (through the lever arm) is
    not zero, so a sign error in that column would be found."""
    x_hat = _nominal()
    _, H = MEASUREMENTS["gnss"](x_hat, _dcm(x_hat))
    for state in (layout.ATT, layout.ATT + 1, layout.ATT + 2):
        numeric = _numeric_column(MEASUREMENTS["gnss"], x_hat, state)
        assert np.abs(numeric).max() > 0.1
        assert np.abs(numeric + H[:, state]).max() > 0.1


# ---- the gated measurement update (GNSS fixes, NHC, unit attitude, ZUPT/ZARU share it) --------------------------
def _update_case(seed: int):
    """A nominal state, its C_b_n, an SPD covariance, a GNSS-like H and innovation, and its S."""
    rng = np.random.default_rng(seed)
    nx = layout.NX_NAV
    B = rng.standard_normal((nx, nx))
    P = 0.1 * B @ B.T + np.eye(nx)
    x = _nominal()
    H = np.zeros((3, nx))
    H[:, layout.POS:layout.POS + 3] = np.eye(3)
    H[:, layout.ATT:layout.ATT + 3] = 0.3 * rng.standard_normal((3, 3))
    z = rng.standard_normal(3)
    S = H @ P @ H.T + np.diag([0.5, 0.7, 1.1])
    return x, P, H, z, S


def _gated(x, P, H, z, S, rows, gate):
    """Run the kernel's gated update on copies; returns its outputs and the state, C, correction and log."""
    nx = P.shape[0]
    x, C, dx_total = x.copy(), _dcm(x), np.zeros(nx)
    dx_total[layout.POS] = 0.25  # an earlier update at the same epoch: the log holds z relative to it
    before = dx_total.copy()
    log = kernel.UpdateLog(np.full(2, -1, dtype=np.int64), np.zeros((2, 3)), np.zeros((2, 3, nx)),
                           np.full(2, layout.FIX_UNUSED, dtype=np.int64))
    P_out, spare, d2, used = kernel.gated_update(x, P.copy(), np.empty((nx, nx)), z, H, S, rows, gate, C, dx_total,
                                                 np.empty((nx, nx)), log, 1, 7)
    assert log.epoch[1] == 7 and log.epoch[0] == -1
    np.testing.assert_array_equal(log.z[1], z + H @ before)
    np.testing.assert_array_equal(log.H[1], H)
    return P_out, d2, used, x, C, dx_total - before, log.status[1]


@pytest.mark.parametrize("rows", [3, 2])
def test_gated_update_is_the_textbook_kalman_update(rows):
    x0, P, H, z, S = _update_case(rows)
    P_out, d2, used, x, C, dx, status = _gated(x0, P, H, z, S, rows, np.inf)
    Hr, Sr, zr = H[:rows], S[:rows, :rows], z[:rows]
    assert d2 == pytest.approx(zr @ np.linalg.solve(Sr, zr), rel=1e-12)
    assert used and status == layout.FIX_USED
    K = P @ Hr.T @ np.linalg.inv(Sr)
    np.testing.assert_allclose(dx, K @ zr, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(P_out, (np.eye(P.shape[0]) - K @ Hr) @ P, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(x, kernel.corrected(x0, K @ zr), rtol=0, atol=1e-15)
    np.testing.assert_allclose(C, _dcm(x), atol=1e-15)  # the nominal attitude follows the corrected state


@pytest.mark.parametrize("rows", [3, 2])
def test_gated_update_accepts_at_the_gate_and_rejects_just_below(rows):
    x0, P, H, z, S = _update_case(10 + rows)
    _, d2, _, _, _, _, _ = _gated(x0, P, H, z, S, rows, np.inf)
    _, _, used, x, _, dx, status = _gated(x0, P, H, z, S, rows, d2)
    assert used and status == layout.FIX_USED and np.any(dx != 0.0)
    P_out, d2_rejected, used, x, C, dx, status = _gated(x0, P, H, z, S, rows, np.nextafter(d2, -np.inf))
    assert not used and status == layout.FIX_REJECTED and d2_rejected == d2
    np.testing.assert_array_equal(P_out, P)  # the covariance, the state and the correction untouched
    np.testing.assert_array_equal(x, x0)
    np.testing.assert_array_equal(dx, 0.0)
