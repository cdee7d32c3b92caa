"""Attitude filters on synthetic MARG data with a gyro bias of 0.1 rad/s ([A3]'s condition, docs/attitude.md)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from georef_cli.main import app
from typer.testing import CliRunner

from georef.attitude.compare import attitude_rms, yaw_offset
from georef.attitude.mekf import triad, vector_jacobian, vector_measurement
from georef.attitude.run import estimate_attitude
from georef.attitude.tilt import accel_tilt, angle_bias_kalman, complementary
from georef.frames import dcm_to_quat, euler_to_dcm, quat_multiply, rotvec_to_quat, wrap_pi
from georef.sim.marg import MargConfig, simulate_marg

SETTLED = 4000  # samples (20 s at 200 Hz) for the biases to be learnt


@pytest.fixture(scope="module")
def rig():
    return simulate_marg(MargConfig(amplitude_deg=(20.0, 15.0, 90.0)))


@pytest.fixture(scope="module")
def bias_free_rig():
    return simulate_marg(MargConfig(amplitude_deg=(20.0, 15.0, 90.0), gyro_bias=(0.0, 0.0, 0.0)))


def _errors(table: pd.DataFrame, data, axes=("roll", "pitch", "yaw")) -> np.ndarray:
    columns = [np.radians(table[a].to_numpy()) - getattr(data, a) for a in axes]
    return np.degrees(wrap_pi(np.stack(columns, -1)))


@pytest.mark.parametrize("method", ["mekf", "ukf"])
def test_mekf_and_ukf_remove_the_bias_drift(rig, bias_free_rig, method):
    """With the bias they reach the same error level as with a bias-free gyro: the noise level."""
    biased = estimate_attitude(method, rig.time, rig.gyro, rig.accel, rig.mag)
    clean = estimate_attitude(method, bias_free_rig.time, bias_free_rig.gyro, bias_free_rig.accel,
                              bias_free_rig.mag)
    rms_biased = np.sqrt(np.mean(_errors(biased, rig)[SETTLED:] ** 2, axis=0))
    rms_clean = np.sqrt(np.mean(_errors(clean, bias_free_rig)[SETTLED:] ** 2, axis=0))
    assert (rms_biased < 1.3 * rms_clean + 0.01).all(), (rms_biased, rms_clean)
    assert (rms_biased < 0.2).all()
    np.testing.assert_allclose(np.radians(biased[["bias_x", "bias_y", "bias_z"]].to_numpy()[-1]), [0.1, -0.1, 0.1],
                               atol=0.005)


def test_the_gyro_alone_drifts_with_the_bias(rig):
    """What the filters remove: the same gyro integrated alone (the complementary filter with k = 0) is tens of
    degrees off after two minutes (measured RMS 88 / 90 deg roll / pitch; 0.4 / 0.7 deg with a bias-free gyro)."""
    roll_acc, pitch_acc = accel_tilt(rig.accel)
    gyro_only = complementary(rig.time, rig.gyro, roll_acc, pitch_acc, 0.0)
    drift = np.degrees(wrap_pi(gyro_only - np.stack([rig.roll, rig.pitch], -1)))[SETTLED:]
    assert (np.sqrt(np.mean(drift**2, axis=0)) > 30.0).all()


def test_complementary_filter_has_the_theoretical_bias_error(rig):
    k, dt = 0.02, float(np.median(np.diff(rig.time)))
    roll_acc, pitch_acc = accel_tilt(rig.accel)
    angles = complementary(rig.time, rig.gyro, roll_acc, pitch_acc, k)
    mean_error = np.degrees(np.mean(angles[SETTLED:] - np.stack([rig.roll, rig.pitch], -1)[SETTLED:], axis=0))
    theory = np.degrees((1 - k) * np.array([0.1, -0.1]) * dt / k)  # (1-k) b dt / k
    np.testing.assert_allclose(mean_error, theory, rtol=0.25)


def test_angle_bias_kalman_removes_it(rig):
    roll_acc, pitch_acc = accel_tilt(rig.accel)
    angles, biases = angle_bias_kalman(rig.time, rig.gyro, roll_acc, pitch_acc, 1e-5, 1e-7, np.radians(0.3) ** 2)
    error = np.degrees(angles[SETTLED:] - np.stack([rig.roll, rig.pitch], -1)[SETTLED:])
    assert (np.abs(error.mean(axis=0)) < 0.05).all()
    assert (np.sqrt(np.mean(error**2, axis=0)) < 0.3).all()
    np.testing.assert_allclose(biases[-1], [0.1, -0.1], atol=0.01)


def test_measurement_jacobian_against_finite_differences():
    rng = np.random.default_rng(3)
    for _ in range(20):
        q = dcm_to_quat(euler_to_dcm(*rng.uniform(-1.2, 1.2, 3)))
        reference = rng.normal(size=3)
        reference /= np.linalg.norm(reference)
        H = vector_jacobian(q, reference)
        step = 1e-7
        for k in range(3):
            delta = np.zeros(3)
            delta[k] = step
            plus = vector_measurement(quat_multiply(q, rotvec_to_quat(delta)), reference)
            minus = vector_measurement(quat_multiply(q, rotvec_to_quat(-delta)), reference)
            np.testing.assert_allclose((plus - minus) / (2 * step), H[:, k], atol=1e-7)
        np.testing.assert_array_equal(H[:, 3:], 0.0)


def test_mekf_update_is_the_ekf_update_with_the_tested_jacobian():
    """The production update (``_update``, allocation-free) equals a textbook EKF update written with
    :func:`vector_jacobian` (checked against finite differences above): ``K = P Hᵀ (H P Hᵀ + R)⁻¹``,
    ``δx = K (y - Ĉᵀ r)``, ``P - K S Kᵀ``, ``q ⊗ q(δθ)`` normalised, ``b + δb``."""
    from georef.attitude.mekf import _update

    rng = np.random.default_rng(11)
    for _ in range(20):
        q = dcm_to_quat(euler_to_dcm(*rng.uniform(-1.2, 1.2, 3)))
        b = rng.normal(0.0, 0.01, 3)
        A = rng.normal(size=(6, 6)) * 0.05
        P = A @ A.T + np.eye(6) * 1e-4
        reference = rng.normal(size=3)
        reference /= np.linalg.norm(reference)
        y = vector_measurement(q, reference) + rng.normal(0.0, 0.02, 3)
        variance = 0.01**2
        H = vector_jacobian(q, reference)
        S = H @ P @ H.T + variance * np.eye(3)
        K = P @ H.T @ np.linalg.inv(S)
        dx = K @ (y - vector_measurement(q, reference))
        q_expected = quat_multiply(q, rotvec_to_quat(dx[:3]))
        q_expected /= np.linalg.norm(q_expected)
        P_expected = P - K @ S @ K.T
        q_run, b_run, P_run = q.copy(), b.copy(), P.copy()
        work = [np.empty((3, 3)) for _ in range(4)] + [np.empty((6, 3)), np.empty((6, 3)), np.empty(3), np.empty(4),
                                                       np.empty(4)]
        C, H_work, S_work, S_inv, K_work, PHt, v, dq, quat_work = work
        _update(q_run, b_run, P_run, y, reference, variance, C, H_work, S_work, S_inv, K_work, PHt, v, dq, quat_work)
        np.testing.assert_allclose(H_work, H[:, :3], atol=1e-15)
        np.testing.assert_allclose(q_run, q_expected, atol=1e-13)
        np.testing.assert_allclose(b_run, b + dx[3:], atol=1e-13)
        np.testing.assert_allclose(P_run, P_expected, atol=1e-13)


def test_triad_recovers_the_attitude(rig):
    C = triad(rig.accel[0], rig.mag[0], rig.mag_reference)
    C_true = euler_to_dcm(rig.roll[0], rig.pitch[0], rig.yaw[0])
    angle = np.degrees(np.arccos(np.clip((np.trace(C.T @ C_true) - 1) / 2, -1, 1)))
    assert angle < 1.5  # one noisy sample


def test_yaw_offset_between_two_series(rig):
    truth = np.stack([rig.roll, rig.pitch, rig.yaw], -1)
    shifted = truth.copy()
    shifted[:, 2] = wrap_pi(shifted[:, 2] - np.radians(37.0))
    shifted += np.random.default_rng(1).normal(0, np.radians(0.2), shifted.shape)
    found = yaw_offset(shifted, truth)
    assert np.degrees(found.offset) == pytest.approx(37.0, abs=0.02)
    assert np.degrees(found.residual_rms) < 0.5
    assert (np.degrees(attitude_rms(truth, truth)) == 0).all()


def test_attitude_command(tmp_path, rig):
    imu = pd.DataFrame({"time": rig.time, "gyro_x": rig.gyro[:, 0], "gyro_y": rig.gyro[:, 1], "gyro_z": rig.gyro[:, 2],
                        "acc_x": rig.accel[:, 0], "acc_y": rig.accel[:, 1], "acc_z": rig.accel[:, 2],
                        "mag_x": rig.mag[:, 0], "mag_y": rig.mag[:, 1], "mag_z": rig.mag[:, 2]})
    path = tmp_path / "imu.csv"
    imu.to_csv(path, index=False)
    runner = CliRunner()
    for method in ("complementary", "kf", "mekf", "ukf"):
        result = runner.invoke(app, ["attitude", "--imu", str(path), "--method", method, "-o",
                                     str(tmp_path / f"{method}.csv"), "--inclination", "60"])
        assert result.exit_code == 0, result.output
        table = pd.read_csv(tmp_path / f"{method}.csv")
        assert len(table) == len(rig.time)
        error = _errors(table, rig, ("roll", "pitch"))[SETTLED:]
        limit = 2.0 if method == "complementary" else 0.3
        assert (np.sqrt(np.mean(error**2, axis=0)) < limit).all(), method
    result = runner.invoke(app, ["attitude", "--imu", str(path), "--method", "nope"])
    assert result.exit_code == 2 and "'nope' is not one of" in result.output and "'mekf'" in result.output
