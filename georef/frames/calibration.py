"""Conventions of the boresight / camera lever-arm calibration (``docs/boresight.md``).

Frames: body ``b`` (x forward, y right, z down), camera ``c`` (``C_c_b = Rz(yaw_b) Ry(pitch_b) Rx(roll_b)``),
local NED ``n``, image ``i`` and mapping frame ``m`` (grid easting, northing, up) of
:mod:`georef.frames.photogrammetry`, and OpenSfM's camera frame ``o`` (x right, y down, z along the optical axis,
OpenSfM ``doc/source/geometry.rst``).

* A camera's attitude error is a small rotation ``rho`` of the *camera* frame: ``C_c_n_adjusted = C_c_n_eo
  exp([rho x])`` (:func:`camera_rotation_residual`). A boresight correction ``b`` [rad, camera frame] changes the
  boresight to ``C_c_b exp([b x])`` (:func:`corrected_boresight`), and an INS attitude error ``eps`` [rad, NED]
  (``C_b_n_true = exp([eps x]) C_b_n_eo``) appears as ``C_n_c eps`` in the camera frame, so
  ``rho = b + C_n_c eps`` to first order.
* A position difference ``d_n`` [m, NED] between the adjusted camera and the EO's appears in the body frame as
  ``C_n_b d_n`` (:func:`body_offset`); a lever-arm correction ``dl`` [m, body] gives ``d_n = C_b_n dl``.
* Grid offsets [grid m] become local east and north through the meridian convergence ``gamma`` and the point
  scale factor ``k``: ``[dE, dN] = G(gamma)^T [dX, dY] / k`` (:func:`grid_offset_to_ned`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from georef.frames.photogrammetry import C_i_c, C_n_enu, enu_to_grid
from georef.frames.rotations import dcm_to_euler, dcm_to_quat, euler_error_jacobian, quat_to_rotvec, rotvec_to_dcm

Array = NDArray[np.float64]

#: image-frame axes in OpenSfM's camera frame: x_o = x_i (right), y_o = -y_i (down), z_o = -z_i (into the scene)
C_i_o = np.diag([1.0, -1.0, -1.0])


def camera_rotation_residual(C_c_n_eo: ArrayLike, C_c_n_adjusted: ArrayLike) -> Array:
    """``rho`` [rad, camera frame] (..., 3) with ``C_c_n_adjusted = C_c_n_eo exp([rho x])``."""
    relative = np.swapaxes(np.asarray(C_c_n_eo, float), -1, -2) @ np.asarray(C_c_n_adjusted, float)
    return quat_to_rotvec(dcm_to_quat(relative))


def body_offset(C_b_n: ArrayLike, d_n: ArrayLike) -> Array:
    """A NED offset [m] (..., 3) expressed in the body frame: ``C_n_b d_n``."""
    return np.einsum("...ji,...j->...i", np.asarray(C_b_n, float), np.asarray(d_n, float))


def map_to_ned(convergence_deg: ArrayLike) -> Array:
    """``C_m_n`` (..., 3, 3): mapping-frame (grid E, N, up) vectors to local NED at convergence γ [deg]."""
    M = enu_to_grid(convergence_deg) @ C_n_enu  # NED -> grid
    return np.swapaxes(M, -1, -2)


def image_to_ned(R_i_m: ArrayLike, convergence_deg: ArrayLike) -> Array:
    """``C_c_n`` (..., 3, 3) of a camera whose image-to-map rotation is ``R_i_m`` (ω, φ, κ of Metashape/Pix4D):
    the inverse of :func:`georef.frames.photogrammetry.image_to_map` (``C_i_c`` is its own inverse)."""
    return map_to_ned(convergence_deg) @ np.asarray(R_i_m, float) @ C_i_c


def opensfm_to_image_map(rotation_rodrigues: ArrayLike) -> Array:
    """``R_i_m`` (..., 3, 3) from an OpenSfM/ODM shot rotation (an angle-axis vector [rad] of ``R`` with
    ``x_o = R X_world + t``, world = grid E, N, up): ``R_i_m = Rᵀ C_i_o``."""
    R = rotvec_to_dcm(np.asarray(rotation_rodrigues, float))
    return np.swapaxes(R, -1, -2) @ C_i_o


def grid_offset_to_ned(d_easting: ArrayLike, d_northing: ArrayLike, d_up: ArrayLike, convergence_deg: ArrayLike,
                       scale: ArrayLike) -> Array:
    """Local NED offset [m] (..., 3) of grid offsets [grid m] and a height offset [m] at convergence γ [deg] and
    point scale factor k: ``[dE, dN] = G(γ)ᵀ [dX, dY] / k``, ``dD = -dU``."""
    G = enu_to_grid(convergence_deg)[..., :2, :2]
    grid = np.stack([np.asarray(d_easting, float), np.asarray(d_northing, float)], -1) / np.asarray(scale,
                                                                                                       float)[..., None]
    east_north = np.einsum("...ji,...j->...i", G, grid)
    return np.stack([east_north[..., 1], east_north[..., 0], -np.asarray(d_up, float)], -1)


def corrected_boresight(boresight_rad: ArrayLike, correction_c: ArrayLike) -> Array:
    """Boresight angles (roll_b, pitch_b, yaw_b) [rad] of ``C_c_b exp([b x])``: the configured boresight [rad]
    turned by the correction ``b`` [rad, camera frame]."""
    from georef.frames.mounting import boresight_dcm

    C = boresight_dcm(boresight_rad) @ rotvec_to_dcm(np.asarray(correction_c, float))
    return np.array(dcm_to_euler(C), dtype=float)


def boresight_angle_jacobian(boresight_rad: ArrayLike) -> Array:
    """d(roll_b, pitch_b, yaw_b) / d b (3, 3) at the boresight [rad] for a camera-frame correction ``b``:
    ``C exp([b x]) = exp([(C b) x]) C``, so it is the Euler Jacobian of a left rotation times ``C_c_b``."""
    from georef.frames.mounting import boresight_dcm

    roll_b, pitch_b, yaw_b = np.asarray(boresight_rad, float)
    return euler_error_jacobian(roll_b, pitch_b, yaw_b) @ boresight_dcm(boresight_rad)


def accel_bias_body_tilt(accel_bias_error_b: ArrayLike, gravity_m_s2: float) -> Array:
    """The INS tilt error [rad] (..., 3) about the body x (roll), y (pitch), z axes that an accelerometer-bias
    error ``δb_a = b̂_a - b_a`` [m/s^2, body] (..., 3) holds in level, unaccelerated flight: ``(δb_y / g,
    -δb_x / g, 0)``.

    Why: level, the accelerometers measure ``f_b = (g θ, -g φ, -g)`` for a roll ``φ`` and pitch ``θ`` (``C_n_b``
    applied to ``f_n = (0, 0, -g)``). The filter corrects them to ``f_b - δb_a`` and levels on that, so its roll
    is ``φ + δb_y / g`` and its pitch ``θ - δb_x / g``: an error fixed in the *body* frame that turns with the
    vehicle, which a heading change separates from a NED tilt but never from a boresight misalignment
    (the levelling error of an accelerometer bias, Titterton and Weston 2004, Strapdown Inertial Navigation
    Technology, 2nd ed., IET)."""
    d = np.asarray(accel_bias_error_b, float)
    return np.stack([d[..., 1] / gravity_m_s2, -d[..., 0] / gravity_m_s2, np.zeros_like(d[..., 0])], -1)


def accel_bias_tilt_covariance_camera(accel_bias_sigma_b: ArrayLike, gravity_m_s2: float, C_c_b: ArrayLike
                                      ) -> Array:
    """Covariance [rad^2] (3, 3) in the camera frame of the body-fixed tilt (:func:`accel_bias_body_tilt`) of
    independent accelerometer-bias errors with 1-sigma ``accel_bias_sigma_b`` [m/s^2, body x, y, z]:
    ``C_b_c diag(σ_y², σ_x², 0) / g² C_c_b`` (a body vector ``v_b`` is ``C_c_bᵀ v_b`` in the camera frame; the
    signs of the mapping drop out of the variances, its axes do not: the y bias tilts about x and vice versa)."""
    sigma = np.asarray(accel_bias_sigma_b, float)
    var_b = np.diag([(sigma[1] / gravity_m_s2) ** 2, (sigma[0] / gravity_m_s2) ** 2, 0.0])
    C = np.asarray(C_c_b, float)
    return C.T @ var_b @ C
