"""Rotations: ZYX Euler angles, direction cosine matrices, Hamilton quaternions, SLERP.

Conventions (see ``docs/conventions.md``):

* ``euler_to_dcm(roll, pitch, yaw) = Rz(yaw) @ Ry(pitch) @ Rx(roll) = C_b_n`` rotates body vectors into
  NED (yaw about z, then pitch about the new y, then roll about the new x);
* quaternions are Hamilton, scalar first ``q = [w, x, y, z]``, and ``quat_to_dcm(q)`` is the matrix that
  rotates vectors of the frame ``q`` describes into the reference frame (``q_b_n -> C_b_n``);
* angles in radians; yaw clockwise from north.

All functions are vectorised over leading axes.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]


def wrap_pi(angle: ArrayLike) -> Array:
    """Wrap angles [rad] to (-pi, pi]."""
    angle = np.asarray(angle, dtype=float)
    wrapped = np.mod(angle + np.pi, 2.0 * np.pi) - np.pi
    return np.where(wrapped == -np.pi, np.pi, wrapped)


def wrap_360(angle_deg: ArrayLike) -> Array:
    """Wrap angles [deg] to [0, 360)."""
    wrapped = np.mod(np.asarray(angle_deg, dtype=float), 360.0)
    return np.where(wrapped >= 360.0, 0.0, wrapped)


def skew(v: ArrayLike) -> Array:
    """Skew-symmetric cross-product matrix ``[v x]`` of (..., 3) vectors, shape (..., 3, 3)."""
    v = np.asarray(v, dtype=float)
    zero = np.zeros(v.shape[:-1])
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    return np.stack(
        [np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1), np.stack([-y, x, zero], -1)], axis=-2
    )


def euler_to_dcm(roll: ArrayLike, pitch: ArrayLike, yaw: ArrayLike) -> Array:
    """ZYX Euler angles [rad] to ``C_b_n = Rz(yaw) Ry(pitch) Rx(roll)``, shape (..., 3, 3)."""
    roll, pitch, yaw = np.broadcast_arrays(
        np.asarray(roll, float), np.asarray(pitch, float), np.asarray(yaw, float)
    )
    sr, cr = np.sin(roll), np.cos(roll)
    sp, cp = np.sin(pitch), np.cos(pitch)
    sy, cy = np.sin(yaw), np.cos(yaw)
    rows = [
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ]
    return np.stack([np.stack(row, axis=-1) for row in rows], axis=-2)


def dcm_to_euler(C_b_n: ArrayLike) -> tuple[Array, Array, Array]:
    """``C_b_n`` (..., 3, 3) to ZYX Euler angles roll, pitch, yaw [rad]; yaw in (-pi, pi].

    Pitch is clipped to [-pi/2, pi/2]; at gimbal lock (|pitch| = 90 deg) roll is returned as 0.
    """
    C = np.asarray(C_b_n, dtype=float)
    pitch = -np.arcsin(np.clip(C[..., 2, 0], -1.0, 1.0))
    roll = np.arctan2(C[..., 2, 1], C[..., 2, 2])
    yaw = np.arctan2(C[..., 1, 0], C[..., 0, 0])
    return roll, pitch, wrap_pi(yaw)


def quat_to_dcm(q: ArrayLike) -> Array:
    """Hamilton scalar-first quaternion(s) (..., 4) to rotation matrices (..., 3, 3); q is normalised."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    return np.stack([np.stack(row, axis=-1) for row in rows], axis=-2)


def dcm_to_quat(C: ArrayLike) -> Array:
    """Rotation matrices (..., 3, 3) to Hamilton scalar-first unit quaternions (..., 4), w >= 0.

    Shepperd's method: the largest of the four squared components is taken first for stability.
    """
    C = np.asarray(C, dtype=float)
    tr = np.trace(C, axis1=-2, axis2=-1)
    diag = np.stack([tr, C[..., 0, 0], C[..., 1, 1], C[..., 2, 2]], axis=-1)
    choice = np.argmax(diag, axis=-1)
    q = np.empty(C.shape[:-2] + (4,))
    with np.errstate(divide="ignore", invalid="ignore"):  # unchosen cases may divide by 0
        # case 0: w largest
        s = np.sqrt(np.maximum(1.0 + tr, 0.0)) * 2.0
        q0 = np.stack([0.25 * s, (C[..., 2, 1] - C[..., 1, 2]) / s, (C[..., 0, 2] - C[..., 2, 0]) / s,
                       (C[..., 1, 0] - C[..., 0, 1]) / s], axis=-1)
        s = np.sqrt(np.maximum(1.0 + C[..., 0, 0] - C[..., 1, 1] - C[..., 2, 2], 0.0)) * 2.0
        q1 = np.stack([(C[..., 2, 1] - C[..., 1, 2]) / s, 0.25 * s, (C[..., 0, 1] + C[..., 1, 0]) / s,
                       (C[..., 0, 2] + C[..., 2, 0]) / s], axis=-1)
        s = np.sqrt(np.maximum(1.0 - C[..., 0, 0] + C[..., 1, 1] - C[..., 2, 2], 0.0)) * 2.0
        q2 = np.stack([(C[..., 0, 2] - C[..., 2, 0]) / s, (C[..., 0, 1] + C[..., 1, 0]) / s, 0.25 * s,
                       (C[..., 1, 2] + C[..., 2, 1]) / s], axis=-1)
        s = np.sqrt(np.maximum(1.0 - C[..., 0, 0] - C[..., 1, 1] + C[..., 2, 2], 0.0)) * 2.0
        q3 = np.stack([(C[..., 1, 0] - C[..., 0, 1]) / s, (C[..., 0, 2] + C[..., 2, 0]) / s,
                       (C[..., 1, 2] + C[..., 2, 1]) / s, 0.25 * s], axis=-1)
    for k, candidate in enumerate((q0, q1, q2, q3)):
        mask = choice == k
        q[mask] = candidate[mask]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0.0, -q, q)


def quat_multiply(p: ArrayLike, q: ArrayLike) -> Array:
    """Hamilton product ``p ⊗ q`` of scalar-first quaternions (..., 4)."""
    p = np.asarray(p, dtype=float)
    q = np.asarray(q, dtype=float)
    pw, px, py, pz = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    qw, qx, qy, qz = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ],
        axis=-1,
    )


def rotvec_to_quat(rotvec: ArrayLike) -> Array:
    """Rotation vector [rad] (..., 3) to a scalar-first quaternion ``[cos(a/2), sin(a/2) u]``."""
    rotvec = np.asarray(rotvec, dtype=float)
    angle = np.linalg.norm(rotvec, axis=-1, keepdims=True)
    half = 0.5 * angle
    # sin(a/2)/a with its series near zero
    with np.errstate(invalid="ignore", divide="ignore"):
        factor = np.where(angle > 1e-8, np.sin(half) / np.where(angle > 0, angle, 1.0), 0.5 - angle**2 / 48.0)
    return np.concatenate([np.cos(half), factor * rotvec], axis=-1)


def rotvec_to_dcm(rotvec: ArrayLike) -> Array:
    """Rotation vector(s) [rad] (..., 3) to the rotation matrix ``exp([v x])`` (..., 3, 3)."""
    return quat_to_dcm(rotvec_to_quat(rotvec))


def quat_to_rotvec(q: ArrayLike) -> Array:
    """Unit scalar-first quaternion(s) (..., 4) to rotation vectors [rad] (..., 3), angle in [0, pi]."""
    q = np.asarray(q, dtype=float)
    q = np.where(q[..., :1] < 0.0, -q, q)
    vector = q[..., 1:]
    norm = np.linalg.norm(vector, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(norm, q[..., :1])
    with np.errstate(invalid="ignore", divide="ignore"):
        factor = np.where(norm > 1e-12, angle / np.where(norm > 0, norm, 1.0), 2.0)
    return factor * vector


def slerp_dcm(times: ArrayLike, C: ArrayLike, new_times: ArrayLike) -> Array:
    """Interpolate rotation matrices (N, 3, 3) given at increasing ``times`` [s] to ``new_times`` on SO(3).

    Spherical linear interpolation between the bracketing samples: ``q = q0 ⊗ exp(s log(q0* ⊗ q1))`` on
    Hamilton quaternions, the shorter way round. ``new_times`` must lie inside ``[times[0], times[-1]]``.
    Equal to scipy's ``Slerp`` (``tests/frames/test_rotations.py``); written on georef's quaternions so that the
    command line does not pay scipy.spatial's import time.
    """
    times = np.asarray(times, dtype=float)
    new_times = np.atleast_1d(np.asarray(new_times, dtype=float))
    C = np.asarray(C, dtype=float)
    upper = np.clip(np.searchsorted(times, new_times, side="right"), 1, len(times) - 1)
    lower = upper - 1
    q0 = dcm_to_quat(C[lower])
    q1 = dcm_to_quat(C[upper])
    q1 = np.where(np.sum(q0 * q1, axis=-1, keepdims=True) < 0.0, -q1, q1)
    q0_conj = q0 * np.array([1.0, -1.0, -1.0, -1.0])
    relative = quat_to_rotvec(quat_multiply(q0_conj, q1))
    fraction = ((new_times - times[lower]) / (times[upper] - times[lower]))[:, None]
    return quat_to_dcm(quat_multiply(q0, rotvec_to_quat(fraction * relative)))


def attitude_at(times: ArrayLike, roll: ArrayLike, pitch: ArrayLike, yaw: ArrayLike,
                new_times: ArrayLike) -> Array:
    """``C_b_n`` (K, 3, 3) at ``new_times`` [s] from ZYX Euler angles [rad] at increasing ``times``, by SLERP.

    Only the samples bracketing a new time are converted to matrices.
    """
    times = np.asarray(times, dtype=float)
    new_times = np.atleast_1d(np.asarray(new_times, dtype=float))
    upper = np.clip(np.searchsorted(times, new_times, side="right"), 1, len(times) - 1)
    needed = np.unique(np.concatenate([upper - 1, upper]))
    C = euler_to_dcm(np.asarray(roll)[needed], np.asarray(pitch)[needed], np.asarray(yaw)[needed])
    return slerp_dcm(times[needed], C, new_times)


def slerp_euler(
    times: ArrayLike, roll: ArrayLike, pitch: ArrayLike, yaw: ArrayLike, new_times: ArrayLike
) -> tuple[Array, Array, Array]:
    """Interpolate ZYX Euler angles [rad] from ``times`` to ``new_times`` [s] on the rotation group.

    Unlike a linear interpolation of the angles, this is correct across the +-180 deg yaw wrap.
    """
    return dcm_to_euler(attitude_at(times, roll, pitch, yaw, new_times))


def euler_rate_matrix(roll: ArrayLike, pitch: ArrayLike) -> Array:
    """``E`` (..., 3, 3) mapping body rates [rad/s] to ZYX Euler-angle rates: ``(roll', pitch', yaw') = E w_b``,
    ``E = [[1, sin r tan p, cos r tan p], [0, cos r, -sin r], [0, sin r / cos p, cos r / cos p]]`` (roll, pitch
    [rad]; singular at |pitch| = 90 deg)."""
    roll, pitch = np.broadcast_arrays(np.asarray(roll, float), np.asarray(pitch, float))
    sr, cr = np.sin(roll), np.cos(roll)
    tp, cp = np.tan(pitch), np.cos(pitch)
    zero, one = np.zeros_like(roll), np.ones_like(roll)
    return np.stack([np.stack([one, sr * tp, cr * tp], -1), np.stack([zero, cr, -sr], -1),
                     np.stack([zero, sr / cp, cr / cp], -1)], -2)


def euler_error_jacobian(roll: ArrayLike, pitch: ArrayLike, yaw: ArrayLike) -> Array:
    """d(roll, pitch, yaw) / d(phi) (..., 3, 3) for a small NED rotation ``phi`` [rad]: ``C' = exp([phi x]) C``.

    A NED rotation is a body rotation ``C^T phi``, and body rates map to ZYX Euler rates through
    :func:`euler_rate_matrix` ``E``, so the Jacobian is ``E C^T`` (``C = C_b_n`` of the given angles).
    """
    roll, pitch, yaw = np.broadcast_arrays(np.asarray(roll, float), np.asarray(pitch, float),
                                           np.asarray(yaw, float))
    return euler_rate_matrix(roll, pitch) @ np.swapaxes(euler_to_dcm(roll, pitch, yaw), -1, -2)

