"""Compiled single-sample forms of georef's conventions, for numba recursions.

These are the same equations as :mod:`georef.frames.earth`, :mod:`georef.frames.rotations` and
:mod:`georef.frames.mounting` (which are vectorised over arrays for module boundaries), written per sample so
compiled loops can call them. ``tests/frames/test_kernels.py`` checks that both forms agree to rounding error;
nothing outside ``georef/frames`` writes these formulas again.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from georef.frames.earth import GAMMA_E, OMEGA_IE, SOMIGLIANA_K, WGS84_A, WGS84_B, WGS84_E2, WGS84_F, WGS84_GM

_M_GRAV = OMEGA_IE**2 * WGS84_A**2 * WGS84_B / WGS84_GM


@njit(cache=True)
def trapezoid_increment(prev: np.ndarray, cur: np.ndarray, bias: np.ndarray, dt: float, out: np.ndarray) -> None:
    """Bias-corrected increment (3,) over an interval of ``dt`` [s] from the point samples at its ends, by the
    trapezoid rule: ``out = (½(prev + cur) - bias) dt``; gyro samples and bias [rad/s] give the angle increment
    [rad], accelerometer ones [m/s^2] the velocity increment [m/s] (body frame)."""
    for i in range(3):
        out[i] = (0.5 * (prev[i] + cur[i]) - bias[i]) * dt


@njit(cache=True)
def radii(lat: float) -> tuple[float, float]:
    """Meridian and prime-vertical radii of curvature M, N [m] at latitude [rad]."""
    s = math.sin(lat)
    w2 = 1.0 - WGS84_E2 * s * s
    return WGS84_A * (1.0 - WGS84_E2) / w2**1.5, WGS84_A / math.sqrt(w2)


@njit(cache=True)
def gravity(lat: float, height: float) -> float:
    """Normal gravity [m/s^2] (Somigliana + second-order height term), down in NED."""
    s2 = math.sin(lat) ** 2
    g0 = GAMMA_E * (1.0 + SOMIGLIANA_K * s2) / math.sqrt(1.0 - WGS84_E2 * s2)
    return g0 * (1.0 - 2.0 / WGS84_A * (1.0 + WGS84_F + _M_GRAV - 2.0 * WGS84_F * s2) * height
                 + 3.0 * height * height / WGS84_A**2)


@njit(cache=True)
def gravity_gradient(lat: float, height: float) -> tuple[float, float]:
    """Horizontal and vertical gradient of normal gravity [1/s^2]: ``g / (R + h)`` and ``2 g / (R + h)`` with the
    Gaussian radius ``R = sqrt(M N)`` (see :func:`georef.frames.earth.normal_gravity_gradient`)."""
    M, N = radii(lat)
    g = gravity(lat, height)
    radius = math.sqrt(M * N) + height
    return g / radius, 2.0 * g / radius


@njit(cache=True)
def ned_to_lat_lon(d_north: float, d_east: float, lat: float, height: float) -> tuple[float, float]:
    """Latitude and longitude increments [rad] of north and east displacements [m] at ``lat`` [rad], ``height``
    [m]: ``d_north / (M + h)``, ``d_east / ((N + h) cos lat)``."""
    M, N = radii(lat)
    return d_north / (M + height), d_east / ((N + height) * math.cos(lat))


@njit(cache=True)
def lat_lon_to_ned(d_lat: float, d_lon: float, lat: float, height: float) -> tuple[float, float]:
    """North and east displacements [m] of latitude and longitude increments [rad] at ``lat`` [rad], ``height``
    [m]: ``d_lat (M + h)``, ``d_lon (N + h) cos lat``."""
    M, N = radii(lat)
    return d_lat * (M + height), d_lon * (N + height) * math.cos(lat)


@njit(cache=True)
def earth_rate(lat: float, out: np.ndarray) -> None:
    """omega_ie_n [rad/s] into ``out`` (3,)."""
    out[0] = OMEGA_IE * math.cos(lat)
    out[1] = 0.0
    out[2] = -OMEGA_IE * math.sin(lat)


@njit(cache=True)
def transport_rate(lat: float, height: float, v: np.ndarray, out: np.ndarray) -> None:
    """omega_en_n [rad/s] into ``out`` (3,) for NED velocity ``v`` [m/s]."""
    M, N = radii(lat)
    out[0] = v[1] / (N + height)
    out[1] = -v[0] / (M + height)
    out[2] = -v[1] * math.tan(lat) / (N + height)


@njit(cache=True)
def quat_mul_into(p: np.ndarray, q: np.ndarray, r: np.ndarray) -> None:
    """Hamilton product p ⊗ q of scalar-first quaternions into ``r`` (4,), which must not be ``p`` or ``q``."""
    r[0] = p[0] * q[0] - p[1] * q[1] - p[2] * q[2] - p[3] * q[3]
    r[1] = p[0] * q[1] + p[1] * q[0] + p[2] * q[3] - p[3] * q[2]
    r[2] = p[0] * q[2] - p[1] * q[3] + p[2] * q[0] + p[3] * q[1]
    r[3] = p[0] * q[3] + p[1] * q[2] - p[2] * q[1] + p[3] * q[0]


@njit(cache=True)
def quat_mul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product p ⊗ q of scalar-first quaternions."""
    r = np.empty(4)
    quat_mul_into(p, q, r)
    return r


@njit(cache=True)
def quat_from_rotvec_into(v: np.ndarray, q: np.ndarray) -> None:
    """Rotation vector [rad] (3,) to a scalar-first quaternion ``[cos(a/2), sin(a/2) u]`` into ``q`` (4,)."""
    a = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    q[0] = math.cos(0.5 * a)
    f = math.sin(0.5 * a) / a if a > 1e-8 else 0.5 - a * a / 48.0
    q[1] = f * v[0]
    q[2] = f * v[1]
    q[3] = f * v[2]


@njit(cache=True)
def quat_from_rotvec(v: np.ndarray) -> np.ndarray:
    """Rotation vector [rad] to a scalar-first quaternion ``[cos(a/2), sin(a/2) u]``."""
    q = np.empty(4)
    quat_from_rotvec_into(v, q)
    return q


@njit(cache=True)
def quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    """Rotation vector [rad] (3,) of a unit scalar-first quaternion, angle in [0, pi] (the shorter way round)."""
    sign = 1.0 if q[0] >= 0.0 else -1.0
    x, y, z = sign * q[1], sign * q[2], sign * q[3]
    norm = math.sqrt(x * x + y * y + z * z)
    angle = 2.0 * math.atan2(norm, sign * q[0])
    f = angle / norm if norm > 1e-12 else 2.0
    return np.array([f * x, f * y, f * z])


@njit(cache=True)
def quat_to_dcm(q: np.ndarray, C: np.ndarray) -> None:
    """Unit quaternion to the rotation matrix it describes (q_b_n -> C_b_n), written into ``C``."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    C[0, 0] = 1 - 2 * (y * y + z * z)
    C[0, 1] = 2 * (x * y - w * z)
    C[0, 2] = 2 * (x * z + w * y)
    C[1, 0] = 2 * (x * y + w * z)
    C[1, 1] = 1 - 2 * (x * x + z * z)
    C[1, 2] = 2 * (y * z - w * x)
    C[2, 0] = 2 * (x * z - w * y)
    C[2, 1] = 2 * (y * z + w * x)
    C[2, 2] = 1 - 2 * (x * x + y * y)


@njit(cache=True)
def quat_normalise(q: np.ndarray) -> None:
    """Scale the quaternion ``q`` (4,) to unit norm in place."""
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    for i in range(4):
        q[i] /= n


@njit(cache=True)
def cross(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """out = a x b (3-vectors)."""
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]


@njit(cache=True)
def dcm_to_euler(C: np.ndarray) -> tuple[float, float, float]:
    """ZYX Euler angles (roll, pitch, yaw) [rad] of C_b_n; yaw in (-pi, pi]."""
    pitch = -math.asin(min(1.0, max(-1.0, C[2, 0])))
    return math.atan2(C[2, 1], C[2, 2]), pitch, math.atan2(C[1, 0], C[0, 0])


@njit(cache=True)
def euler_rate_matrix(roll: float, pitch: float) -> np.ndarray:
    """``E`` (3, 3): ZYX Euler-angle rates ``= E w_b`` of body rates ``w_b`` [rad/s] at roll, pitch [rad]."""
    sr, cr = math.sin(roll), math.cos(roll)
    tp, cp = math.tan(pitch), math.cos(pitch)
    return np.array([[1.0, sr * tp, cr * tp], [0.0, cr, -sr], [0.0, sr / cp, cr / cp]])


@njit(cache=True)
def euler_error_jacobian(C: np.ndarray) -> np.ndarray:
    """d(roll, pitch, yaw)/d(phi) = E C^T for a small NED rotation phi, C = C_b_n (3x3)."""
    roll, pitch, _ = dcm_to_euler(C)
    return euler_rate_matrix(roll, pitch) @ C.T


@njit(cache=True)
def add_skew(v: np.ndarray, M: np.ndarray, r0: int, c0: int, sign: float) -> None:
    """Add ``sign * [v x]`` (the cross-product matrix of the 3-vector ``v``) into ``M[r0:r0+3, c0:c0+3]``."""
    M[r0 + 0, c0 + 1] -= sign * v[2]
    M[r0 + 0, c0 + 2] += sign * v[1]
    M[r0 + 1, c0 + 0] += sign * v[2]
    M[r0 + 1, c0 + 2] -= sign * v[0]
    M[r0 + 2, c0 + 0] -= sign * v[1]
    M[r0 + 2, c0 + 1] += sign * v[0]


@njit(cache=True)
def skew_into(v: np.ndarray, out: np.ndarray) -> None:
    """``out = [v x]`` (3, 3), the cross-product matrix of the 3-vector ``v``: ``[v x] u = v x u``."""
    out[:, :] = 0.0
    add_skew(v, out, 0, 0, 1.0)


@njit(cache=True)
def lever_arm_into(C: np.ndarray, lever: np.ndarray, out: np.ndarray) -> None:
    """Offset ``C lever`` [m] (3,) of a body-frame lever arm [m] in the frame ``C`` (3, 3) rotates the body into
    (NED, the initial body frame, a tangent plane), into ``out``; the compiled twin of
    :func:`georef.frames.mounting.lever_arm_offset`."""
    for i in range(3):
        out[i] = C[i, 0] * lever[0] + C[i, 1] * lever[1] + C[i, 2] * lever[2]


@njit(cache=True)
def _so3_into(v: np.ndarray, a: float, b: float, out: np.ndarray) -> None:
    """``out = I + a [v x] + b [v x]^2`` (3, 3)."""
    x, y, z = v[0], v[1], v[2]
    out[0, 0] = 1.0 - b * (y * y + z * z)
    out[1, 1] = 1.0 - b * (x * x + z * z)
    out[2, 2] = 1.0 - b * (x * x + y * y)
    out[0, 1] = -a * z + b * x * y
    out[1, 0] = a * z + b * x * y
    out[0, 2] = a * y + b * x * z
    out[2, 0] = -a * y + b * x * z
    out[1, 2] = -a * x + b * y * z
    out[2, 1] = a * x + b * y * z


@njit(cache=True)
def so3_exp_into(v: np.ndarray, out: np.ndarray) -> None:
    """Rotation matrix ``exp([v x])`` of a rotation vector ``v`` [rad] (Rodrigues) into ``out`` (3, 3)."""
    a2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
    a = math.sqrt(a2)
    if a < 1e-6:
        _so3_into(v, 1.0 - a2 / 6.0, 0.5 - a2 / 24.0, out)
    else:
        _so3_into(v, math.sin(a) / a, (1.0 - math.cos(a)) / a2, out)


@njit(cache=True)
def so3_exp(v: np.ndarray) -> np.ndarray:
    """Rotation matrix ``exp([v x])`` (3, 3) of a rotation vector ``v`` [rad]."""
    out = np.empty((3, 3))
    so3_exp_into(v, out)
    return out


@njit(cache=True)
def so3_right_jacobian_into(v: np.ndarray, out: np.ndarray) -> None:
    """Right Jacobian ``J_r(v)`` of SO(3) into ``out`` (3, 3):
    ``exp([(v + d) x]) ≈ exp([v x]) exp([(J_r(v) d) x])`` for small d."""
    a2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
    a = math.sqrt(a2)
    if a < 1e-6:
        _so3_into(v, -(0.5 - a2 / 24.0), 1.0 / 6.0 - a2 / 120.0, out)
    else:
        _so3_into(v, -(1.0 - math.cos(a)) / a2, (a - math.sin(a)) / (a2 * a), out)
