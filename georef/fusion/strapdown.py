"""Strapdown INS mechanisation in NED with geodetic position (compiled).

Nominal state ``x`` (16,): ``[lat, lon, h, v_N, v_E, v_D, q_w, q_x, q_y, q_z, b_g(3), b_a(3)]`` —
radians, metres, m/s, the body-to-NED quaternion (Hamilton, scalar first), gyro bias [rad/s] and
accelerometer bias [m/s^2].

One step from t_{k-1} to t_k uses the bias-corrected increments ``dtheta`` [rad] and ``dvel`` [m/s] of
the interval and those of the previous interval (for the two-sample corrections):

* attitude: body rotation vector ``phi = dθ_k + (1/12) dθ_{k-1} x dθ_k`` (coning),
  navigation-frame rotation ``zeta = (ω_ie + ω_en) dt``; ``q_k = q(-zeta) ⊗ q_{k-1} ⊗ q(phi)``;
* velocity: ``dv_b = dv_k + ½ dθ_k x dv_k + (1/12)(dθ_{k-1} x dv_k + dv_{k-1} x dθ_k)`` (rotation and
  sculling), ``v_k = v_{k-1} + (I - ½[zeta x]) C_b_n dv_b + (g_n - (2ω_ie + ω_en) x v) dt``
  with normal gravity ``g_n = [0, 0, g(lat, h)]``;
* position: trapezoidal velocity, ``h -= v_D dt``, ``lat += v_N dt/(M+h)``, ``lon += v_E dt/((N+h) cos lat)``.

After Savage (1998) "Strapdown inertial navigation integration algorithm design" and Shin (2005); the
same structure as KF-GINS.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from georef.frames.kernels import (
    earth_rate,
    gravity,
    quat_from_rotvec,
    quat_mul,
    quat_normalise,
    quat_to_dcm,
    radii,
    transport_rate,
)


@njit(cache=True)
def increments(gyro_prev: np.ndarray, gyro: np.ndarray, accel_prev: np.ndarray, accel: np.ndarray, dt: float,
               x: np.ndarray, dtheta: np.ndarray, dvel: np.ndarray) -> None:
    """Bias-corrected angle and velocity increments of an interval from point samples (trapezoid)."""
    for i in range(3):
        dtheta[i] = (0.5 * (gyro_prev[i] + gyro[i]) - x[10 + i]) * dt
        dvel[i] = (0.5 * (accel_prev[i] + accel[i]) - x[13 + i]) * dt


@njit(cache=True)
def mechanise(x: np.ndarray, dtheta: np.ndarray, dvel: np.ndarray, dtheta_prev: np.ndarray,
              dvel_prev: np.ndarray, dt: float, C: np.ndarray) -> None:
    """Advance the nominal state ``x`` in place by one IMU interval; ``C`` receives the new C_b_n.

    Written per component, with one 3-vector scratch array: this runs for every IMU row, and the array
    temporaries of the vector form (a dozen allocations per row, and a BLAS call for ``C dv_b``) took more time
    than the arithmetic. The operations and their order are those of the vector form.
    """
    lat, lon, h = x[0], x[1], x[2]
    v0, v1, v2 = x[3], x[4], x[5]
    w = np.empty(3)  # scratch: Earth rate, then transport rate, at the start and then at the midpoint
    earth_rate(lat, w)
    wie0, wie1, wie2 = w[0], w[1], w[2]
    transport_rate(lat, h, x[3:6], w)
    wen0, wen1, wen2 = w[0], w[1], w[2]
    z0, z1, z2 = (wie0 + wen0) * dt, (wie1 + wen1) * dt, (wie2 + wen2) * dt

    # velocity: rotation and sculling corrections in the body frame
    a0, a1, a2 = dtheta[0], dtheta[1], dtheta[2]
    b0, b1, b2 = dvel[0], dvel[1], dvel[2]
    p0, p1, p2 = dtheta_prev[0], dtheta_prev[1], dtheta_prev[2]
    d0, d1, d2 = dvel_prev[0], dvel_prev[1], dvel_prev[2]
    dvb0 = b0 + 0.5 * (a1 * b2 - a2 * b1) + ((p1 * b2 - p2 * b1) + (d1 * a2 - d2 * a1)) / 12.0
    dvb1 = b1 + 0.5 * (a2 * b0 - a0 * b2) + ((p2 * b0 - p0 * b2) + (d2 * a0 - d0 * a2)) / 12.0
    dvb2 = b2 + 0.5 * (a0 * b1 - a1 * b0) + ((p0 * b1 - p1 * b0) + (d0 * a1 - d1 * a0)) / 12.0
    quat_to_dcm(x[6:10], C)
    dv = np.empty(3)
    dv[0], dv[1], dv[2] = dvb0, dvb1, dvb2
    dvn = np.empty(3)
    np.dot(C, dv, dvn)
    n0, n1, n2 = dvn[0], dvn[1], dvn[2]
    # navigation-frame rotation over the interval: dv_n - 1/2 zeta x dv_n
    dvn0 = n0 - 0.5 * (z1 * n2 - z2 * n1)
    dvn1 = n1 - 0.5 * (z2 * n0 - z0 * n2)
    dvn2 = n2 - 0.5 * (z0 * n1 - z1 * n0)
    # Coriolis: (2 omega_ie + omega_en) x v
    c0, c1, c2 = 2.0 * wie0 + wen0, 2.0 * wie1 + wen1, 2.0 * wie2 + wen2
    vn0 = v0 + dvn0 - (c1 * v2 - c2 * v1) * dt
    vn1 = v1 + dvn1 - (c2 * v0 - c0 * v2) * dt
    vn2 = v2 + dvn2 - (c0 * v1 - c1 * v0) * dt
    vn2 += gravity(lat, h) * dt

    # position (trapezoidal velocity)
    M, N = radii(lat)
    h_new = h - 0.5 * (v2 + vn2) * dt
    h_mid = 0.5 * (h + h_new)
    lat_new = lat + 0.5 * (v0 + vn0) * dt / (M + h_mid)
    lat_mid = 0.5 * (lat + lat_new)
    _, N_mid = radii(lat_mid)
    lon_new = lon + 0.5 * (v1 + vn1) * dt / ((N_mid + h_mid) * math.cos(lat_mid))

    # attitude: body coning and the rotation of the navigation frame at the interval's midpoint
    phi = np.empty(3)
    phi[0] = a0 + (p1 * a2 - p2 * a1) / 12.0
    phi[1] = a1 + (p2 * a0 - p0 * a2) / 12.0
    phi[2] = a2 + (p0 * a1 - p1 * a0) / 12.0
    q_body = quat_from_rotvec(phi)
    x[3], x[4], x[5] = 0.5 * (v0 + vn0), 0.5 * (v1 + vn1), 0.5 * (v2 + vn2)  # the midpoint velocity, for now
    earth_rate(lat_mid, w)
    wie0, wie1, wie2 = w[0], w[1], w[2]
    transport_rate(lat_mid, h_mid, x[3:6], w)
    phi[0] = -(wie0 + w[0]) * dt
    phi[1] = -(wie1 + w[1]) * dt
    phi[2] = -(wie2 + w[2]) * dt
    q_nav = quat_from_rotvec(phi)
    q_new = quat_mul(quat_mul(q_nav, x[6:10]), q_body)
    quat_normalise(q_new)

    x[0], x[1], x[2] = lat_new, lon_new, h_new
    x[3], x[4], x[5] = vn0, vn1, vn2
    x[6:10] = q_new
    quat_to_dcm(q_new, C)


@njit(cache=True)
def run_free_inertial(x0: np.ndarray, t: np.ndarray, gyro: np.ndarray, accel: np.ndarray) -> np.ndarray:
    """Free-running INS from ``x0`` over IMU samples (rates [rad/s], specific force [m/s^2]); states (N, 16)."""
    n = t.shape[0]
    out = np.empty((n, 16))
    x = x0.copy()
    out[0] = x
    dtheta = np.zeros(3)
    dvel = np.zeros(3)
    dtheta_prev = np.zeros(3)
    dvel_prev = np.zeros(3)
    C = np.empty((3, 3))
    for k in range(1, n):
        dt = t[k] - t[k - 1]
        increments(gyro[k - 1], gyro[k], accel[k - 1], accel[k], dt, x, dtheta, dvel)
        if k == 1:
            dtheta_prev[:] = dtheta
            dvel_prev[:] = dvel
        mechanise(x, dtheta, dvel, dtheta_prev, dvel_prev, dt, C)
        dtheta_prev[:] = dtheta
        dvel_prev[:] = dvel
        out[k] = x
    return out
