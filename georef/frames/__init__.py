"""Frames, angles, units and the Earth model: the one place that owns georef's conventions.

Every other module imports its geodesy and rotations from here and derives none of its own.
The conventions are documented in ``docs/conventions.md``:

* body ``b``: x forward, y right, z down (FRD);
* navigation ``n``: local NED at the current position;
* ECEF ``e``: WGS84 earth-centred, earth-fixed;
* camera ``c``: the body frame rotated by the boresight, ``C_c_b = Rz(yaw_b) Ry(pitch_b) Rx(roll_b)``;
* Euler angles are ZYX, ``C_b_n = Rz(yaw) Ry(pitch) Rx(roll)``; yaw is clockwise from north, reported
  in [0, 360) degrees in tables and handled in (-pi, pi] radians inside;
* quaternions are Hamilton, scalar first ``[w, x, y, z]``;
* SI units and radians inside; degrees and metres at every interface a person reads.
"""

from georef.frames.earth import (
    OMEGA_IE,
    STANDARD_GRAVITY,
    WGS84_A,
    WGS84_B,
    WGS84_E2,
    WGS84_F,
    WGS84_GM,
    C_e_n,
    C_n_e,
    earth_rate_n,
    ecef_to_geodetic,
    ecef_to_geodetic_iterative,
    gaussian_radius,
    geodetic_to_ecef,
    lat_lon_to_ned,
    ned_to_lat_lon,
    normal_gravity,
    normal_gravity_gradient,
    radii_of_curvature,
    transport_rate_n,
)
from georef.frames.rotations import (
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

__all__ = [
    "WGS84_A",
    "WGS84_B",
    "WGS84_E2",
    "WGS84_F",
    "WGS84_GM",
    "OMEGA_IE",
    "STANDARD_GRAVITY",
    "C_e_n",
    "C_n_e",
    "earth_rate_n",
    "ecef_to_geodetic",
    "ecef_to_geodetic_iterative",
    "gaussian_radius",
    "geodetic_to_ecef",
    "lat_lon_to_ned",
    "ned_to_lat_lon",
    "normal_gravity",
    "normal_gravity_gradient",
    "radii_of_curvature",
    "transport_rate_n",
    "dcm_to_euler",
    "dcm_to_quat",
    "euler_to_dcm",
    "quat_multiply",
    "quat_to_dcm",
    "rotvec_to_quat",
    "skew",
    "slerp_euler",
    "wrap_pi",
    "wrap_360",
]
