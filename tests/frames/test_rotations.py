"""Rotations against scipy's independent implementation, and interpolation on the rotation group."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from georef.frames import (
    dcm_to_euler,
    dcm_to_quat,
    euler_to_dcm,
    quat_multiply,
    quat_to_dcm,
    rotvec_to_quat,
    skew,
    slerp_euler,
    wrap_360,
    wrap_pi,
)
from georef.frames.mounting import boresight_dcm, camera_attitude, lever_arm_ecef

RNG = np.random.default_rng(42)
N = 2000
ROLL = RNG.uniform(-np.pi, np.pi, N)
PITCH = RNG.uniform(-np.pi / 2 + 1e-3, np.pi / 2 - 1e-3, N)
YAW = RNG.uniform(-np.pi, np.pi, N)


def test_euler_to_dcm_matches_scipy_intrinsic_zyx():
    ours = euler_to_dcm(ROLL, PITCH, YAW)
    ref = Rotation.from_euler("ZYX", np.stack([YAW, PITCH, ROLL], -1)).as_matrix()
    np.testing.assert_allclose(ours, ref, atol=1e-14)


def test_dcm_to_euler_inverts_and_matches_scipy():
    roll, pitch, yaw = dcm_to_euler(euler_to_dcm(ROLL, PITCH, YAW))
    np.testing.assert_allclose(np.stack([roll, pitch, yaw]), np.stack([ROLL, PITCH, YAW]), atol=1e-9)
    ref = Rotation.from_matrix(euler_to_dcm(ROLL, PITCH, YAW)).as_euler("ZYX")
    np.testing.assert_allclose(yaw, ref[:, 0], atol=1e-9)


def test_quaternions_match_scipy_scalar_first():
    C = euler_to_dcm(ROLL, PITCH, YAW)
    q = dcm_to_quat(C)
    ref = Rotation.from_matrix(C).as_quat(scalar_first=True)
    ref = np.where(ref[:, :1] < 0, -ref, ref)
    np.testing.assert_allclose(q, ref, atol=1e-12)
    np.testing.assert_allclose(quat_to_dcm(q), C, atol=1e-12)


def test_hamilton_product_composes_like_matrices():
    q1 = dcm_to_quat(euler_to_dcm(ROLL, PITCH, YAW))
    q2 = dcm_to_quat(euler_to_dcm(YAW, -PITCH / 2, ROLL / 3))
    np.testing.assert_allclose(quat_to_dcm(quat_multiply(q1, q2)), quat_to_dcm(q1) @ quat_to_dcm(q2), atol=1e-12)


def test_rotvec_to_quat_matches_scipy_including_tiny_angles():
    rotvec = np.concatenate([RNG.normal(size=(100, 3)), RNG.normal(size=(5, 3)) * 1e-10, np.zeros((1, 3))])
    ref = Rotation.from_rotvec(rotvec).as_quat(scalar_first=True)
    np.testing.assert_allclose(rotvec_to_quat(rotvec), ref, atol=1e-15)


def test_skew_is_the_cross_product():
    a, b = RNG.normal(size=(10, 3)), RNG.normal(size=(10, 3))
    np.testing.assert_allclose(np.einsum("nij,nj->ni", skew(a), b), np.cross(a, b), atol=1e-15)


@settings(max_examples=200, deadline=None)
@given(st.floats(-1e4, 1e4, allow_nan=False))
def test_wrapping_ranges(angle):
    assert -np.pi < wrap_pi(angle) <= np.pi
    assert np.isclose(np.cos(wrap_pi(angle)), np.cos(angle), atol=1e-9)
    assert 0.0 <= wrap_360(angle) < 360.0


def test_slerp_across_the_yaw_wrap():
    """Between yaw 179 deg and -179 deg the aircraft turns 2 deg, not 358 deg."""
    times = np.array([0.0, 1.0])
    roll, pitch, yaw = slerp_euler(times, np.zeros(2), np.zeros(2), np.radians([179.0, -179.0]), [0.25, 0.5])
    np.testing.assert_allclose(np.degrees(wrap_pi(yaw - np.pi)), [-0.5, 0.0], atol=1e-9)
    np.testing.assert_allclose(roll, 0.0, atol=1e-12)
    np.testing.assert_allclose(pitch, 0.0, atol=1e-12)


def test_slerp_matches_scipy_slerp():
    from scipy.spatial.transform import Slerp

    times = np.linspace(0, 10, 11)
    r, p, y = ROLL[:11] * 0.2, PITCH[:11] * 0.2, YAW[:11]
    new = np.linspace(0, 10, 57)
    ours = euler_to_dcm(*slerp_euler(times, r, p, y, new))
    ref = Slerp(times, Rotation.from_matrix(euler_to_dcm(r, p, y)))(new).as_matrix()
    np.testing.assert_allclose(ours, ref, atol=1e-12)


def test_boresight_and_lever_arm_conventions():
    # heading east (yaw 90 deg): a forward lever arm points east
    C_b_n = euler_to_dcm(0.0, 0.0, np.pi / 2)
    offset_e = lever_arm_ecef(0.0, 0.0, C_b_n, [2.0, 0.0, 0.0])
    np.testing.assert_allclose(offset_e, [0.0, 2.0, 0.0], atol=1e-12)  # east at (0, 0) is +Y in ECEF
    bore = np.radians([1.0, -2.0, 3.0])
    np.testing.assert_allclose(boresight_dcm(bore), Rotation.from_euler("ZYX", bore[::-1]).as_matrix(), atol=1e-15)
    np.testing.assert_allclose(camera_attitude(C_b_n, bore), C_b_n @ boresight_dcm(bore), atol=1e-15)


@pytest.mark.parametrize("pitch", [np.pi / 2, -np.pi / 2])
def test_gimbal_lock_is_finite(pitch):
    roll, p, yaw = dcm_to_euler(euler_to_dcm(0.3, pitch, 0.2))
    assert np.isfinite([roll, p, yaw]).all()
    assert p == pytest.approx(pitch)


def test_euler_error_jacobian_by_finite_differences():
    from georef.frames.rotations import euler_error_jacobian

    for r, p, y in [(0.1, -0.2, 2.5), (-0.4, 0.3, -3.0), (0.0, 0.0, 0.0)]:
        J = euler_error_jacobian(r, p, y)
        C = euler_to_dcm(r, p, y)
        step = 1e-7
        for k in range(3):
            phi = np.zeros(3)
            phi[k] = step
            rotated = Rotation.from_rotvec(phi).as_matrix() @ C
            plus = np.array(dcm_to_euler(rotated))
            rotated = Rotation.from_rotvec(-phi).as_matrix() @ C
            minus = np.array(dcm_to_euler(rotated))
            np.testing.assert_allclose(wrap_pi(plus - minus) / (2 * step), J[:, k], atol=1e-6)


def test_quat_to_rotvec_matches_scipy():
    from georef.frames.rotations import quat_to_rotvec

    rotvec = np.concatenate([RNG.normal(size=(200, 3)), RNG.normal(size=(5, 3)) * 1e-9, np.zeros((1, 3))])
    rotvec = rotvec[np.linalg.norm(rotvec, axis=1) < np.pi]
    q = Rotation.from_rotvec(rotvec).as_quat(scalar_first=True)
    np.testing.assert_allclose(quat_to_rotvec(q), rotvec, atol=1e-12)
    np.testing.assert_allclose(quat_to_rotvec(-q), rotvec, atol=1e-12)
