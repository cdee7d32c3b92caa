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

import numpy as np
from numba import njit

from georef.frames.kernels import (
    cross,
    earth_rate,
    gravity,
    ned_to_lat_lon,
    quat_from_rotvec_into,
    quat_mul_into,
    quat_normalise,
    quat_to_dcm,
    transport_rate,
    trapezoid_increment,
)
from georef.fusion.ins_layout import X_BA, X_BG, X_HGT, X_LAT, X_LON, X_QUAT, X_VEL


@njit(cache=True)
def increments(gyro_prev: np.ndarray, gyro: np.ndarray, accel_prev: np.ndarray, accel: np.ndarray, dt: float,
               x: np.ndarray, dtheta: np.ndarray, dvel: np.ndarray) -> None:
    """Angle [rad] and velocity [m/s] increments of an interval from point samples (trapezoid), corrected by the
    biases of the nominal state ``x`` (:func:`georef.frames.kernels.trapezoid_increment`)."""
    trapezoid_increment(gyro_prev, gyro, x[X_BG:X_BG + 3], dt, dtheta)
    trapezoid_increment(accel_prev, accel, x[X_BA:X_BA + 3], dt, dvel)


@njit(cache=True)
def add_two_sample_corrections(dtheta: np.ndarray, dvel: np.ndarray, dtheta_prev: np.ndarray,
                               dvel_prev: np.ndarray, phi: np.ndarray, dv_b: np.ndarray) -> None:
    """Add the two-sample corrections of an interval to ``phi`` [rad] and ``dv_b`` [m/s] (3,) in place:

    * coning, ``phi += (1/12) dθ_{k-1} x dθ_k``;
    * rotation and sculling, ``dv_b = dv_b + ½ dθ_k x dv_k + (1/12)(dθ_{k-1} x dv_k + dv_{k-1} x dθ_k)``

    from the bias-corrected increments ``dtheta``, ``dvel`` of the interval and those of the previous one (body
    frame). With ``phi = dθ_k``, ``dv_b = dv_k`` on entry they become the strapdown's body rotation vector and
    velocity increment (:func:`mechanise`); with zeros, the corrections alone
    (:func:`two_sample_corrections`)."""
    t1 = np.empty(3)
    t2 = np.empty(3)
    t3 = np.empty(3)
    cross(dtheta, dvel, t1)
    cross(dtheta_prev, dvel, t2)
    cross(dvel_prev, dtheta, t3)
    for i in range(3):
        dv_b[i] = dv_b[i] + 0.5 * t1[i] + (t2[i] + t3[i]) / 12.0
    cross(dtheta_prev, dtheta, t1)
    for i in range(3):
        phi[i] = phi[i] + t1[i] / 12.0


@njit(cache=True)
def two_sample_corrections(dtheta: np.ndarray, dvel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The strapdown's coning correction [rad] and rotation + sculling correction [m/s] ((N, 3) each) of
    consecutive intervals' bias-corrected increments ``dtheta`` [rad] and ``dvel`` [m/s] (N, 3, body frame), as
    :func:`mechanise` applies them (:func:`add_two_sample_corrections`); the first interval is its own previous
    one, as in :func:`run_free_inertial` and the filter."""
    n = dtheta.shape[0]
    d_phi = np.zeros((n, 3))
    d_vel = np.zeros((n, 3))
    for k in range(n):
        j = k - 1 if k > 0 else 0
        add_two_sample_corrections(dtheta[k], dvel[k], dtheta[j], dvel[j], d_phi[k], d_vel[k])
    return d_phi, d_vel


#: rows of the work buffer :func:`mechanise_into` takes, (MECHANISE_WORK, 4)
MECHANISE_WORK = 15


@njit(cache=True)
def mechanise(x: np.ndarray, dtheta: np.ndarray, dvel: np.ndarray, dtheta_prev: np.ndarray,
              dvel_prev: np.ndarray, dt: float, C: np.ndarray) -> None:
    """Advance the nominal state ``x`` in place by one IMU interval; ``C`` receives the new C_b_n
    (:func:`mechanise_into` with a work buffer of its own)."""
    mechanise_into(x, dtheta, dvel, dtheta_prev, dvel_prev, dt, C, np.empty((MECHANISE_WORK, 4)))


@njit(cache=True)
def mechanise_into(x: np.ndarray, dtheta: np.ndarray, dvel: np.ndarray, dtheta_prev: np.ndarray,
                   dvel_prev: np.ndarray, dt: float, C: np.ndarray, work: np.ndarray) -> None:
    """Advance the nominal state ``x`` in place by one IMU interval; ``C`` receives the new C_b_n.

    ``work`` (MECHANISE_WORK, 4) holds the intermediate vectors and quaternions: a loop over every IMU row passes
    the same buffer each time instead of allocating some twenty small arrays per row (they were a quarter
    of the forward filter's time). The arithmetic is written out element by element in the order the array
    expressions evaluated it, so the states are the same to the bit."""
    lat, lon, h = x[X_LAT], x[X_LON], x[X_HGT]
    v, w_ie, w_en, zeta, phi, dv_b, dv_n, t1 = work[0], work[1], work[2], work[3], work[4], work[5], work[6], work[7]
    v_new, t2, v_mid = work[8], work[9], work[10]
    q_body, q_nav, q_prod, q_new = work[11], work[12], work[13], work[14]
    for i in range(3):
        v[i] = x[X_VEL + i]
    earth_rate(lat, w_ie)
    transport_rate(lat, h, v, w_en)
    for i in range(3):
        zeta[i] = (w_ie[i] + w_en[i]) * dt
        phi[i] = dtheta[i]
        dv_b[i] = dvel[i]

    # velocity, with the body rotation vector (coning) for the attitude below
    add_two_sample_corrections(dtheta, dvel, dtheta_prev, dvel_prev, phi, dv_b)
    quat_to_dcm(x[X_QUAT:X_QUAT + 4], C)
    np.dot(C, dv_b[:3], dv_n[:3])
    cross(zeta, dv_n, t1)
    for i in range(3):
        dv_n[i] = dv_n[i] - 0.5 * t1[i]
        t2[i] = 2.0 * w_ie[i] + w_en[i]
    cross(t2, v, t1)  # Coriolis and transport: (2 ω_ie + ω_en) x v
    for i in range(3):
        v_new[i] = v[i] + dv_n[i] - t1[i] * dt
    v_new[2] += gravity(lat, h) * dt

    # position (trapezoidal velocity): latitude at the start's radius, longitude at the midpoint's
    h_new = h - 0.5 * (v[2] + v_new[2]) * dt
    h_mid = 0.5 * (h + h_new)
    d_lat, _ = ned_to_lat_lon(0.5 * (v[0] + v_new[0]) * dt, 0.0, lat, h_mid)
    lat_new = lat + d_lat
    lat_mid = 0.5 * (lat + lat_new)
    _, d_lon = ned_to_lat_lon(0.0, 0.5 * (v[1] + v_new[1]) * dt, lat_mid, h_mid)
    lon_new = lon + d_lon

    # attitude: body coning and the rotation of the navigation frame at the interval's midpoint
    quat_from_rotvec_into(phi, q_body)
    for i in range(3):
        v_mid[i] = 0.5 * (v[i] + v_new[i])
    earth_rate(lat_mid, w_ie)
    transport_rate(lat_mid, h_mid, v_mid, w_en)
    for i in range(3):
        t2[i] = -(w_ie[i] + w_en[i]) * dt
    quat_from_rotvec_into(t2, q_nav)
    quat_mul_into(q_nav, x[X_QUAT:X_QUAT + 4], q_prod)
    quat_mul_into(q_prod, q_body, q_new)
    quat_normalise(q_new)

    x[X_LAT], x[X_LON], x[X_HGT] = lat_new, lon_new, h_new
    for i in range(3):
        x[X_VEL + i] = v_new[i]
    for i in range(4):
        x[X_QUAT + i] = q_new[i]
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
    work = np.empty((MECHANISE_WORK, 4))
    for k in range(1, n):
        dt = t[k] - t[k - 1]
        increments(gyro[k - 1], gyro[k], accel[k - 1], accel[k], dt, x, dtheta, dvel)
        if k == 1:
            dtheta_prev[:] = dtheta
            dvel_prev[:] = dvel
        mechanise_into(x, dtheta, dvel, dtheta_prev, dvel_prev, dt, C, work)
        dtheta_prev[:] = dtheta
        dvel_prev[:] = dvel
        out[k] = x
    return out
