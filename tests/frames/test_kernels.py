"""The compiled single-sample forms in georef.frames.kernels equal the vectorised forms."""

from __future__ import annotations

import numpy as np

from georef.frames import (
    earth_rate_n,
    kernels,
    normal_gravity,
    quat_multiply,
    quat_to_dcm,
    radii_of_curvature,
    rotvec_to_quat,
    transport_rate_n,
)

RNG = np.random.default_rng(8)


def test_earth_model_forms_agree():
    for lat, h in zip(RNG.uniform(-1.5, 1.5, 50), RNG.uniform(-5000, 50000, 50), strict=True):
        M, N = kernels.radii(lat)
        np.testing.assert_allclose((M, N), radii_of_curvature(lat), rtol=1e-15)
        assert abs(kernels.gravity(lat, h) - normal_gravity(lat, h)) < 1e-14
        out = np.empty(3)
        kernels.earth_rate(lat, out)
        np.testing.assert_allclose(out, earth_rate_n(lat), atol=1e-20)
        v = RNG.normal(0, 50, 3)
        kernels.transport_rate(lat, h, v, out)
        np.testing.assert_allclose(out, transport_rate_n(lat, h, v), rtol=1e-13, atol=1e-20)


def test_rotation_forms_agree():
    for _ in range(50):
        p, q = RNG.normal(size=4), RNG.normal(size=4)
        np.testing.assert_allclose(kernels.quat_mul(p, q), quat_multiply(p, q), atol=1e-15)
        v = RNG.normal(size=3) * RNG.choice([1e-10, 1e-3, 1.0])
        np.testing.assert_allclose(kernels.quat_from_rotvec(v), rotvec_to_quat(v), atol=1e-15)
        u = q / np.linalg.norm(q)
        C = np.empty((3, 3))
        kernels.quat_to_dcm(u, C)
        np.testing.assert_allclose(C, quat_to_dcm(u), atol=1e-15)
        out = np.empty(3)
        kernels.cross(v, p[:3], out)
        np.testing.assert_allclose(out, np.cross(v, p[:3]), atol=1e-15)


def test_euler_forms_agree():
    from georef.frames import dcm_to_euler, euler_to_dcm
    from georef.frames.rotations import euler_error_jacobian

    for r, p, y in RNG.uniform(-1.2, 1.2, (20, 3)):
        C = euler_to_dcm(r, p, 2.5 * y)
        np.testing.assert_allclose(kernels.dcm_to_euler(C), dcm_to_euler(C), atol=1e-14)
        np.testing.assert_allclose(kernels.euler_error_jacobian(C), euler_error_jacobian(r, p, 2.5 * y), atol=1e-12)


def test_so3_exponential_and_right_jacobian_against_scipy():
    """exp([v x]) against scipy's rotation vectors; the right Jacobian against finite differences."""
    from scipy.spatial.transform import Rotation

    for scale in (1e-9, 1e-4, 0.3, 2.5):
        for v in RNG.normal(size=(10, 3)) * scale:
            np.testing.assert_allclose(kernels.so3_exp(v), Rotation.from_rotvec(v).as_matrix(), atol=1e-14)
            Jr = np.empty((3, 3))
            kernels.so3_right_jacobian_into(v, Jr)
            for i in range(3):
                d = np.zeros(3)
                d[i] = 1e-7
                # exp(v + d) = exp(v) exp(Jr d)  ->  log(exp(v)^T exp(v + d)) / 1e-7 = Jr[:, i]
                rel = Rotation.from_matrix(kernels.so3_exp(v).T @ kernels.so3_exp(v + d)).as_rotvec() / 1e-7
                np.testing.assert_allclose(rel, Jr[:, i], atol=1e-6)


def test_in_place_quaternion_forms_against_scipy():
    """The allocation-free Hamilton product and rotation-vector exponential the MEKF uses, and the rotation-vector
    logarithm the UKF uses, against scipy's rotations (scipy is scalar last) and the vectorised forms."""
    from scipy.spatial.transform import Rotation

    from georef.frames.rotations import quat_to_rotvec

    def scipy_quat(q: np.ndarray) -> Rotation:
        return Rotation.from_quat(np.roll(q, -1))

    out = np.empty(4)
    for scale in (1e-10, 1e-4, 0.5, 3.0):
        for _ in range(10):
            p, q = RNG.normal(size=4), RNG.normal(size=4)
            p, q = p / np.linalg.norm(p), q / np.linalg.norm(q)
            kernels.quat_mul_into(p, q, out)
            np.testing.assert_allclose((scipy_quat(out)).as_matrix(), (scipy_quat(p) * scipy_quat(q)).as_matrix(),
                                       atol=1e-14)
            np.testing.assert_array_equal(out, kernels.quat_mul(p, q))
            v = RNG.normal(size=3)
            v *= scale / np.linalg.norm(v)
            kernels.quat_from_rotvec_into(v, out)
            np.testing.assert_allclose(np.roll(out, -1), Rotation.from_rotvec(v).as_quat(), atol=1e-15)
            np.testing.assert_array_equal(out, kernels.quat_from_rotvec(v))
            # the logarithm takes the shorter way round, whichever sign the quaternion has
            for sign in (1.0, -1.0):
                np.testing.assert_allclose(kernels.quat_to_rotvec(sign * out), v, atol=1e-14)
                np.testing.assert_allclose(kernels.quat_to_rotvec(sign * out), quat_to_rotvec(sign * out),
                                           atol=1e-15)
            np.testing.assert_allclose(kernels.quat_to_rotvec(q), scipy_quat(q).as_rotvec(), atol=1e-13)


def test_skew_and_lever_arm_forms_against_cross_products_and_scipy():
    from scipy.spatial.transform import Rotation

    from georef.frames import euler_to_dcm, skew
    from georef.frames.mounting import lever_arm_offset

    S = np.empty((3, 3))
    out = np.empty(3)
    for _ in range(30):
        v, u = RNG.normal(size=3), RNG.normal(size=3)
        kernels.skew_into(v, S)
        np.testing.assert_allclose(S @ u, np.cross(v, u), atol=1e-14)
        np.testing.assert_array_equal(S, skew(v))
        roll, pitch, yaw = RNG.uniform(-3.0, 3.0, 3) * [1.0, 0.5, 1.0]
        C = euler_to_dcm(roll, pitch, yaw)
        lever = RNG.normal(0.0, 2.0, 3)
        reference = Rotation.from_euler("ZYX", [yaw, pitch, roll]).apply(lever)
        np.testing.assert_allclose(lever_arm_offset(C, lever), reference, atol=1e-14)
        kernels.lever_arm_into(C, lever, out)
        np.testing.assert_allclose(out, lever_arm_offset(C, lever), rtol=0, atol=1e-14)


def test_euler_rate_matrix_by_finite_differences_and_forms_agree():
    """``E w`` is the rate of the ZYX angles of ``C exp([w dt] x)`` (a body rate w), by central differences."""
    from scipy.spatial.transform import Rotation

    from georef.frames import dcm_to_euler, euler_to_dcm
    from georef.frames.rotations import euler_rate_matrix

    dt = 1e-6
    for roll, pitch, yaw in RNG.uniform(-1.3, 1.3, (20, 3)):
        C = euler_to_dcm(roll, pitch, yaw)
        E = euler_rate_matrix(roll, pitch)
        np.testing.assert_allclose(kernels.euler_rate_matrix(roll, pitch), E, rtol=1e-15, atol=1e-16)
        w = RNG.normal(size=3)
        plus = np.array(dcm_to_euler(C @ Rotation.from_rotvec(w * dt).as_matrix()))
        minus = np.array(dcm_to_euler(C @ Rotation.from_rotvec(-w * dt).as_matrix()))
        np.testing.assert_allclose((plus - minus) / (2 * dt), E @ w, atol=1e-7)
