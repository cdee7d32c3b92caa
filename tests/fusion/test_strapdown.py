"""Strapdown mechanisation and the error model: rest, analytic trajectories, F against finite differences."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from georef.frames import (
    C_e_n,
    dcm_to_euler,
    dcm_to_quat,
    earth_rate_n,
    euler_to_dcm,
    geodetic_to_ecef,
    normal_gravity,
    quat_to_dcm,
    radii_of_curvature,
    wrap_pi,
)
from georef.fusion.ins_kernel import correct_state, system_matrix
from georef.fusion.ins_layout import N_NOISE, NS, NX_NAV
from georef.fusion.strapdown import run_free_inertial
from georef.sim.trajectory import FlightPlan, fly


def _state(lat, lon, h, v_n, C_b_n, size=NS):
    x = np.zeros(size)
    x[0], x[1], x[2] = lat, lon, h
    x[3:6] = v_n
    x[6:10] = dcm_to_quat(C_b_n)
    return x


@pytest.mark.parametrize("lat_deg", [0.0, 44.0, 70.0, -35.0, 89.0])
def test_imu_at_rest_stays_put(lat_deg):
    """Ideal gyro = Earth rate and accelerometer = minus normal gravity: ten minutes without moving."""
    lat, h = np.radians(lat_deg), 350.0
    C = euler_to_dcm(0.05, -0.1, 2.0)
    gyro = C.T @ earth_rate_n(lat)
    accel = C.T @ np.array([0.0, 0.0, -normal_gravity(lat, h)])
    n = 100 * 600
    t = np.arange(n) / 100.0
    out = run_free_inertial(_state(lat, 0.3, h, np.zeros(3), C)[:16], t, np.tile(gyro, (n, 1)), np.tile(accel, (n, 1)))
    M, N = radii_of_curvature(lat)
    assert abs(out[-1, 0] - lat) * M < 1e-4
    assert abs(out[-1, 1] - 0.3) * N * np.cos(lat) < 1e-4
    assert abs(out[-1, 2] - h) < 1e-4
    assert np.abs(out[-1, 3:6]).max() < 1e-6
    np.testing.assert_allclose(quat_to_dcm(out[-1, 6:10]), C, atol=1e-9)


def test_uncompensated_earth_rate_makes_the_ins_move():
    """The same rest test without Earth rate in the gyros must fail: the test above has teeth."""
    lat, h = np.radians(44.0), 350.0
    C = np.eye(3)
    accel = np.array([0.0, 0.0, -normal_gravity(lat, h)])
    n = 100 * 300
    t = np.arange(n) / 100.0
    out = run_free_inertial(_state(lat, 0.3, h, np.zeros(3), C)[:16], t, np.zeros((n, 3)), np.tile(accel, (n, 1)))
    assert np.abs(out[-1, 3:6]).max() > 0.1


@pytest.mark.parametrize("rate_hz, position_tol, attitude_tol_deg", [(200.0, 0.01, 1e-3), (50.0, 0.5, 5e-3)])
def test_follows_turns_and_climbs(rate_hz, position_tol, attitude_tol_deg):
    """Ideal IMU of a flight with coordinated turns, climbs and turbulence, integrated for two minutes."""
    truth = fly(FlightPlan(duration_s=120.0), 400.0)
    idx = np.arange(0, len(truth.time), int(400 / rate_hz))
    x0 = _state(truth.lat[0], truth.lon[0], truth.height[0], truth.v_n[0], truth.C_b_n[0])[:16]
    out = run_free_inertial(x0, truth.time[idx], truth.omega_ib_b[idx], truth.f_ib_b[idx])
    r_ins = geodetic_to_ecef(out[:, 0], out[:, 1], out[:, 2])
    r_true = geodetic_to_ecef(truth.lat[idx], truth.lon[idx], truth.height[idx])
    err_n = np.einsum("nij,nj->ni", C_e_n(truth.lat[idx], truth.lon[idx]), r_ins - r_true)
    assert np.abs(err_n).max() < position_tol
    roll, pitch, yaw = dcm_to_euler(quat_to_dcm(out[:, 6:10]))
    for est, ref in ((roll, truth.roll), (pitch, truth.pitch), (yaw, truth.yaw)):
        assert np.degrees(np.abs(wrap_pi(est - ref[idx]))).max() < attitude_tol_deg


def _error(x_hat, x):
    """Error state (estimate minus truth) between two nominal states, in the filter's coordinates."""
    M, N = radii_of_curvature(x[0])
    d = np.zeros(15)
    d[0] = (x_hat[0] - x[0]) * (M + x[2])
    d[1] = (x_hat[1] - x[1]) * (N + x[2]) * np.cos(x[0])
    d[2] = -(x_hat[2] - x[2])
    d[3:6] = x_hat[3:6] - x[3:6]
    # C_hat = exp(-[phi x]) C
    d[6:9] = -Rotation.from_matrix(quat_to_dcm(x_hat[6:10]) @ quat_to_dcm(x[6:10]).T).as_rotvec()
    d[9:15] = x_hat[10:16] - x[10:16]
    return d


def test_error_dynamics_match_finite_differences():
    """Propagate a true and a perturbed INS through 2 s of a turn; compare with the product of Phi."""
    from georef.fusion.strapdown import increments, mechanise

    truth = fly(FlightPlan(duration_s=70.0, strip_duration_s=40.0), 400.0)
    idx = np.arange(int(42 * 400), int(44 * 400), 8)  # 50 Hz, inside the first turn
    t, gyro, accel = truth.time[idx], truth.omega_ib_b[idx], truth.f_ib_b[idx]
    x_true = _state(truth.lat[idx[0]], truth.lon[idx[0]], truth.height[idx[0]], truth.v_n[idx[0]],
                    truth.C_b_n[idx[0]])
    scales = np.array([1.0] * 3 + [0.05] * 3 + [1e-3] * 3 + [1e-5] * 3 + [1e-3] * 3)
    for k in range(15):
        delta = np.zeros(15)
        delta[k] = scales[k]
        x_hat = x_true.copy()
        correct_state(x_hat, -np.concatenate([delta, np.zeros(NX_NAV - 15)]))
        states = [x_true.copy(), x_hat]
        Phi = np.eye(NX_NAV)
        C = np.empty((3, 3))
        F = np.zeros((NX_NAV, NX_NAV))
        noise = np.zeros(N_NOISE)  # no bias or unit-error decay
        buffers = [[np.zeros(3) for _ in range(4)] for _ in range(2)]
        for j in range(1, len(t)):
            dt = t[j] - t[j - 1]
            C_prev = quat_to_dcm(states[0][6:10])
            for s, x in enumerate(states):
                dth, dv, dth_p, dv_p = buffers[s]
                increments(gyro[j - 1], gyro[j], accel[j - 1], accel[j], dt, x, dth, dv)
                if j == 1:
                    dth_p[:], dv_p[:] = dth, dv
                mechanise(x, dth, dv, dth_p, dv_p, dt, C)
                dth_p[:], dv_p[:] = dth, dv
            C_mid = 0.5 * (C_prev + quat_to_dcm(states[0][6:10]))
            system_matrix(states[0], C_mid, C_mid @ (0.5 * (accel[j - 1] + accel[j])), noise, F)
            Fd = F * dt
            Phi = (np.eye(NX_NAV) + Fd + 0.5 * Fd @ Fd) @ Phi
        measured = _error(states[1], states[0])
        predicted = (Phi @ np.concatenate([delta, np.zeros(NX_NAV - 15)]))[:15]
        scale = np.abs(predicted) / scales + 1e-9
        # first-order agreement for every response that is not negligible
        big = scale > 1e-2 * scale.max()
        np.testing.assert_allclose(measured[big] / scales[big], predicted[big] / scales[big],
                                   rtol=0.05, atol=2e-3 * scale.max(), err_msg=f"column {k}")


def test_two_sample_corrections_are_savages_and_shared_with_the_preintegration():
    """Coning ``(1/12) dθ_{k-1} x dθ_k`` and rotation + sculling ``½ dθ_k x dv_k + (1/12)(dθ_{k-1} x dv_k +
    dv_{k-1} x dθ_k)`` (Savage 1998, parts 1 and 2), written here with numpy's cross product; the strapdown's
    in-place form adds them to the increments; the graph's compensated rates are the trapezoid rates plus the same
    corrections over dt, through the compiled ``ins`` kernel (ahead of time when built)."""
    from georef.fusion.increments import compensated_rates
    from georef.fusion.strapdown import add_two_sample_corrections, two_sample_corrections

    rng = np.random.default_rng(4)
    n = 200
    time = np.cumsum(rng.uniform(0.004, 0.006, n + 1))
    gyro = rng.normal(0.0, 0.5, (n + 1, 3))
    accel = rng.normal(0.0, 3.0, (n + 1, 3)) + [0.0, 0.0, -9.8]
    dt = np.diff(time)[:, None]
    dtheta = 0.5 * (gyro[:-1] + gyro[1:]) * dt
    dvel = 0.5 * (accel[:-1] + accel[1:]) * dt
    prev_theta = np.concatenate([dtheta[:1], dtheta[:-1]])
    prev_vel = np.concatenate([dvel[:1], dvel[:-1]])
    coning = np.cross(prev_theta, dtheta) / 12.0
    sculling = 0.5 * np.cross(dtheta, dvel) + (np.cross(prev_theta, dvel) + np.cross(prev_vel, dtheta)) / 12.0
    d_phi, d_vel = two_sample_corrections(dtheta, dvel)
    np.testing.assert_allclose(d_phi, coning, rtol=0, atol=1e-17)
    np.testing.assert_allclose(d_vel, sculling, rtol=0, atol=1e-16)
    for k in (0, 1, 57):
        phi, dv_b = dtheta[k].copy(), dvel[k].copy()
        add_two_sample_corrections(dtheta[k], dvel[k], prev_theta[k], prev_vel[k], phi, dv_b)
        np.testing.assert_allclose(phi, dtheta[k] + coning[k], rtol=0, atol=1e-17)
        np.testing.assert_allclose(dv_b, dvel[k] + sculling[k], rtol=0, atol=1e-16)
    zero = np.zeros((n + 1, 3))
    accel_rate, gyro_rate = compensated_rates(time, gyro, accel, zero, zero)
    np.testing.assert_allclose(accel_rate, 0.5 * (accel[:-1] + accel[1:]) + sculling / dt, rtol=0, atol=1e-13)
    np.testing.assert_allclose(gyro_rate, 0.5 * (gyro[:-1] + gyro[1:]) + coning / dt, rtol=0, atol=1e-14)
