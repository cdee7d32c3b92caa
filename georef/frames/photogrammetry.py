"""Photogrammetric omega, phi, kappa in a projected CRS.

Frames (``docs/conventions.md``):

* camera ``c``: x forward, y right, z down (the body frame turned by the boresight);
* image ``i``: x right, y up in the image (towards the flight direction for a standard mount), z out of the
  lens (away from the ground): ``x_i = y_c``, ``y_i = x_c``, ``z_i = -z_c``;
* mapping ``m``: easting, northing, up of the projected CRS at the camera: local ENU turned by the meridian
  convergence γ (a true azimuth α has the grid azimuth α − γ).

``R_i_m = Rx(ω) Ry(φ) Rz(κ)`` rotates image-frame vectors into the mapping frame — the "omega, phi, kappa"
of Agisoft Metashape, Pix4D and ArcGIS (camera-to-world, x-y-z order). Then the collinearity equations read
``[x, y, -c] ∝ R_i_mᵀ (X_ground - X_camera)``.

What is and is not modelled: the rotation is exact at the camera (its own ENU frame and convergence). Across
a block, grid coordinates are not a Cartesian frame: horizontal distances carry the projection's scale factor
k and refer to the ellipsoid, not to the point's height ((R + h)/R, 1.2e-4 at 760 m), and the grid's vertical
is not the local normal (Earth curvature: a point d away lies d²/2R below the camera's tangent plane, 7.8 cm
at 1 km). Software that treats grid coordinates as Cartesian inherits these;
:func:`grid_to_camera_local` removes both for a ground point, and the tests quantify them.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from georef.frames.earth import gaussian_radius

Array = NDArray[np.float64]

#: image-frame axes expressed in the camera frame (columns): x_i = y_c, y_i = x_c, z_i = -z_c
C_i_c = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
#: NED -> ENU
C_n_enu = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def enu_to_grid(convergence_deg: ArrayLike) -> Array:
    """Rotation (..., 3, 3) from local ENU (true north) to the grid frame (grid north) for convergence γ [deg]."""
    gamma = np.radians(np.asarray(convergence_deg, dtype=float))
    c, s = np.cos(gamma), np.sin(gamma)
    zero, one = np.zeros_like(gamma), np.ones_like(gamma)
    return np.stack([np.stack([c, -s, zero], -1), np.stack([s, c, zero], -1), np.stack([zero, zero, one], -1)], -2)


def image_to_map(C_c_n: ArrayLike, convergence_deg: ArrayLike) -> Array:
    """``R_i_m`` (..., 3, 3): image-frame vectors to the mapping frame (E, N, U of the grid)."""
    return enu_to_grid(convergence_deg) @ C_n_enu @ np.asarray(C_c_n, dtype=float) @ C_i_c


def rotation_to_opk(R_i_m: ArrayLike) -> tuple[Array, Array, Array]:
    """ω, φ, κ [rad] of ``R = Rx(ω) Ry(φ) Rz(κ)``; φ in [-90°, 90°]."""
    R = np.asarray(R_i_m, dtype=float)
    phi = np.arcsin(np.clip(R[..., 0, 2], -1.0, 1.0))
    omega = np.arctan2(-R[..., 1, 2], R[..., 2, 2])
    kappa = np.arctan2(-R[..., 0, 1], R[..., 0, 0])
    return omega, phi, kappa


def opk_to_rotation(omega: ArrayLike, phi: ArrayLike, kappa: ArrayLike) -> Array:
    """``Rx(ω) Ry(φ) Rz(κ)`` (..., 3, 3) from angles [rad]."""
    omega, phi, kappa = np.broadcast_arrays(np.asarray(omega, float), np.asarray(phi, float),
                                            np.asarray(kappa, float))
    co, so = np.cos(omega), np.sin(omega)
    cp, sp = np.cos(phi), np.sin(phi)
    ck, sk = np.cos(kappa), np.sin(kappa)
    rows = [[cp * ck, -cp * sk, sp],
            [co * sk + so * sp * ck, co * ck - so * sp * sk, -so * cp],
            [so * sk - co * sp * ck, so * ck + co * sp * sk, co * cp]]
    return np.stack([np.stack(row, -1) for row in rows], -2)


def collinearity(R_i_m: ArrayLike, camera_m: ArrayLike, ground_m: ArrayLike, focal: float = 1.0) -> Array:
    """Image coordinates (..., 2) of ground points: ``[x, y, -c] ∝ R_i_mᵀ (X_ground - X_camera)``."""
    d = np.einsum("...ji,...j->...i", np.asarray(R_i_m, float), np.asarray(ground_m, float) - np.asarray(camera_m))
    return -focal * d[..., :2] / d[..., 2:3]


def grid_to_camera_local(d_easting: ArrayLike, d_northing: ArrayLike, d_height: ArrayLike, scale: ArrayLike,
                         lat_rad: ArrayLike, point_height: ArrayLike) -> Array:
    """A ground point's grid offsets from the camera [m] as a Cartesian vector in the camera's grid-aligned
    local frame: horizontal offsets divided by the projection's scale k and raised from the ellipsoid to the
    point's height ``(R + h)/R``, height lowered by the Earth's curvature ``d² / 2R`` (R the Gaussian radius
    at the camera)."""
    radius = gaussian_radius(lat_rad)
    factor = (radius + np.asarray(point_height, float)) / (radius * np.asarray(scale, float))
    de = np.asarray(d_easting, float) * factor
    dn = np.asarray(d_northing, float) * factor
    drop = (de**2 + dn**2) / (2.0 * radius)
    return np.stack([de, dn, np.asarray(d_height, float) - drop], -1)
