"""Lever arms and boresight: moving from the IMU to the GNSS antenna or the camera.

* Lever arms are body-frame vectors [m] from the IMU centre to the named point. Their offset in any frame x
  the body attitude ``C_b_x`` rotates into (NED, a tangent plane, the initial body frame) is
  ``C_b_x @ lever_arm_b`` (:func:`lever_arm_offset`; compiled twin :func:`georef.frames.kernels.lever_arm_into`),
  and in ECEF ``r_point_e = r_imu_e + C_n_e @ C_b_n @ lever_arm_b`` (:func:`lever_arm_ecef`).
* The boresight ``(roll_b, pitch_b, yaw_b)`` [rad] gives ``C_c_b = Rz(yaw_b) Ry(pitch_b) Rx(roll_b)``, and the
  camera attitude is ``C_c_n = C_b_n @ C_c_b``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from georef.frames.earth import C_n_e
from georef.frames.rotations import euler_to_dcm, skew

Array = NDArray[np.float64]


def boresight_dcm(boresight_rad: ArrayLike) -> Array:
    """``C_c_b`` (3, 3) from the boresight angles ``(roll_b, pitch_b, yaw_b)`` [rad]."""
    roll_b, pitch_b, yaw_b = np.asarray(boresight_rad, dtype=float)
    return euler_to_dcm(roll_b, pitch_b, yaw_b)


def camera_attitude(C_b_n: ArrayLike, boresight_rad: ArrayLike) -> Array:
    """Camera-to-NED rotation ``C_c_n = C_b_n @ C_c_b`` (..., 3, 3) from body attitude and boresight [rad]."""
    return np.asarray(C_b_n, dtype=float) @ boresight_dcm(boresight_rad)


def lever_arm_offset(C_b_x: ArrayLike, lever_arm_b: ArrayLike) -> Array:
    """Offset [m, frame x] (..., 3) of a body-frame lever arm [m] (3,): ``C_b_x @ lever_arm_b``, with ``C_b_x``
    (..., 3, 3) the attitude of the body in frame x (``C_b_n`` for a NED offset)."""
    return np.asarray(C_b_x, dtype=float) @ np.asarray(lever_arm_b, dtype=float)


def lever_arm_ecef(lat: ArrayLike, lon: ArrayLike, C_b_n: ArrayLike, lever_arm_b: ArrayLike) -> Array:
    """ECEF offset [m] (..., 3) of a body-frame lever arm [m]: ``C_n_e @ C_b_n @ lever_arm_b``.

    ``lat``, ``lon`` [rad] give the NED frame in which ``C_b_n`` is expressed.
    """
    lever_n = lever_arm_offset(C_b_n, lever_arm_b)
    return np.einsum("...ij,...j->...i", C_n_e(lat, lon), lever_n)


def lever_arm_rotation_jacobian(C_b_x: ArrayLike, lever_arm_b: ArrayLike) -> Array:
    """Derivative (..., 3, 3) of the lever-arm offset ``C_b_x @ lever_arm_b`` [m, frame x] with respect to a
    body-frame rotation error ``phi`` [rad] applied as ``C_b_x (I + [phi x])``: ``-C_b_x [lever_arm_b x]``."""
    return -np.asarray(C_b_x, dtype=float) @ skew(lever_arm_b)
