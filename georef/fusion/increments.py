"""IMU point samples as per-interval rates with the strapdown's two-sample corrections, for an integrator that
holds the attitude at the start of each interval (GTSAM's IMU preintegration).

GTSAM's preintegration (``TangentPreintegration``/``ManifoldPreintegration::update``) takes a constant body
specific force ``a`` and rate ``ω`` over each step and adds ``R_start a dt`` to the velocity and
``R_start Exp(ω dt)`` to the attitude: the rotation during the step is left out of the velocity (an error of
``½ dθ × dv`` per step, i.e. a specific-force error ``½ ω × f dt``: 1 mg for a 0.1 rad/s roll at 50 Hz), and the
rates' variation between samples (coning and sculling) is ignored. georef's strapdown
(:func:`georef.fusion.strapdown.mechanise`, after Savage 1998, "Strapdown inertial navigation integration
algorithm design, part 1: attitude algorithms" and "part 2: velocity and position algorithms", J. Guidance,
Control, and Dynamics 21(1), 19-28 and 21(2), 208-221) applies, per interval ``k`` with the bias-corrected
trapezoid increments ``dθ_k`` [rad] and ``dv_k`` [m/s]:

* attitude: ``dθ_k + (1/12) dθ_{k-1} × dθ_k`` (coning);
* velocity: ``dv_k + ½ dθ_k × dv_k + (1/12)(dθ_{k-1} × dv_k + dv_{k-1} × dθ_k)`` (rotation and sculling).

:func:`compensated_rates` returns the trapezoid rates plus these corrections divided by ``dt``, so that the
preintegration of GTSAM integrates the same increments as the EKF + RTS; the corrections are the strapdown's own
(:func:`georef.fusion.strapdown.two_sample_corrections`, served compiled with the ``ins`` kernel). They are
computed with the best bias estimate available (the EKF + RTS's, per row); the integrator then removes its own
bias estimate from the trapezoid part as usual (the corrections' dependence on the bias is second order).
"""

from __future__ import annotations

import numpy as np

from georef.aot import load as load_kernel


def compensated_rates(time: np.ndarray, gyro: np.ndarray, accel: np.ndarray, gyro_bias: np.ndarray,
                      accel_bias: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-interval specific force [m/s^2] and angular rate [rad/s] (both (N-1, 3), body frame) between the
    point samples ``accel`` [m/s^2] and ``gyro`` [rad/s] at ``time`` [s] ((N,) and (N, 3)): the trapezoid mean
    of the two samples plus the strapdown's rotation, sculling and coning corrections over ``dt`` (see the
    module). ``gyro_bias`` [rad/s] and ``accel_bias`` [m/s^2] (N, 3) are the bias estimates used inside the
    corrections (NaN rows count as zero bias). The first interval uses itself as its previous one, as the
    strapdown does."""
    dt = np.diff(time)[:, None]
    gyro_mid = 0.5 * (gyro[:-1] + gyro[1:])
    accel_mid = 0.5 * (accel[:-1] + accel[1:])
    dtheta = (gyro_mid - np.nan_to_num(gyro_bias[:-1])) * dt
    dvel = (accel_mid - np.nan_to_num(accel_bias[:-1])) * dt
    dtheta_fix, dvel_fix = load_kernel("ins").two_sample_corrections(dtheta, dvel)
    return accel_mid + dvel_fix / dt, gyro_mid + dtheta_fix / dt
