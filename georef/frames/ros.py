"""ROS conventions meeting georef's: body axes (REP 103), GNSS covariances (sensor_msgs/NavSatFix), time stamps.

* REP 103 body frames are x forward, y left, z up (FLU); georef's body frame ``b`` is x forward, y right, z down
  (FRD). ``C_flu_b = diag(1, -1, -1)`` rotates FLU vectors into FRD: the rotation by 180 deg about x (det +1, so
  angular rates, a pseudo-vector, turn exactly like specific force). It is its own inverse.
* sensor_msgs/NavSatFix ``position_covariance`` [m^2] is row-major in the ENU tangent plane at the fix; georef
  works in NED: :func:`georef.frames.position_covariance.enu_to_ned_covariance` (north and east swapped, up
  negated, so the variances swap north/east and the cross terms with up change sign).
* builtin_interfaces/Time (``sec``, ``nanosec``) is a count of seconds and nanoseconds since the clock's epoch
  (for a wall clock the Unix epoch, UTC): one float [s] per stamp.

References: REP 103 "Standard Units of Measure and Coordinate Conventions"; REP 145 "Conventions for IMU
Sensor Drivers"; the sensor_msgs/NavSatFix message definition (common_msgs, ROS 1 Noetic; common_interfaces,
ROS 2).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

#: REP 103 body axes (forward, left, up) -> georef's body axes ``b`` (forward, right, down)
C_flu_b = np.diag([1.0, -1.0, -1.0])
#: nanoseconds in a second (builtin_interfaces/Time.nanosec counts up to this, exclusive)
NANOSECONDS = 1_000_000_000


def flu_to_frd(v_flu: ArrayLike) -> Array:
    """Vectors (..., 3) on REP 103 body axes (FLU) -> georef's body axes (FRD): ``C_flu_b @ v``.

    For an IMU's angular velocity [rad/s] and specific force [m/s^2] alike."""
    return np.asarray(v_flu, dtype=float) @ C_flu_b.T


def stamp_to_seconds(sec: ArrayLike, nanosec: ArrayLike) -> Array:
    """builtin_interfaces/Time fields -> seconds [s] since the clock's epoch (float64: 0.24 us steps at 1.7e9 s)."""
    return np.asarray(sec, dtype=np.int64).astype(float) + np.asarray(nanosec, dtype=np.int64) * 1e-9


def seconds_to_stamp(seconds: ArrayLike) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Seconds [s] -> builtin_interfaces/Time ``(sec, nanosec)``, rounded to the nearest nanosecond, ``nanosec``
    in [0, 1e9)."""
    seconds = np.asarray(seconds, dtype=float)
    whole = np.floor(seconds)
    # the fraction first: seconds * 1e9 alone would lose the nanoseconds of a Unix time (1.7e18 ns > 2^53)
    nanosec = np.round((seconds - whole) * 1e9).astype(np.int64)
    carry = nanosec // NANOSECONDS
    return whole.astype(np.int64) + carry, nanosec - carry * NANOSECONDS
