"""WGS84 Earth model: geodetic <-> ECEF, NED <-> ECEF rotation, radii of curvature, NED metres <-> latitude and
longitude increments, normal gravity and its gradient, the Earth's rotation.

All inputs and outputs are SI: latitude and longitude in radians, heights in metres above the
WGS84 ellipsoid, ECEF coordinates in metres. Every function is vectorised over leading axes.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

#: WGS84 semi-major axis [m]
WGS84_A = 6378137.0
#: WGS84 flattening [-]
WGS84_F = 1.0 / 298.257223563
#: WGS84 semi-minor axis [m]
WGS84_B = WGS84_A * (1.0 - WGS84_F)
#: WGS84 first eccentricity squared [-]
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)
#: WGS84 geocentric gravitational constant [m^3/s^2]
WGS84_GM = 3.986004418e14
#: Earth rotation rate [rad/s]
OMEGA_IE = 7.292115e-5
#: Normal gravity at the equator [m/s^2] and Somigliana's constant k [-] (NIMA TR8350.2)
GAMMA_E = 9.7803253359
SOMIGLIANA_K = 0.00193185265241
#: Standard gravity [m/s^2], the unit "g" of datasheets (mg, g); a unit, not a model of the field (3rd CGPM,
#: 1901). The field is :func:`normal_gravity`.
STANDARD_GRAVITY = 9.80665

Array = NDArray[np.float64]


def radii_of_curvature(lat: ArrayLike) -> tuple[Array, Array]:
    """Meridian radius M and prime-vertical radius N [m] at geodetic latitude ``lat`` [rad]."""
    sin_lat = np.sin(np.asarray(lat, dtype=float))
    w2 = 1.0 - WGS84_E2 * sin_lat**2
    N = WGS84_A / np.sqrt(w2)
    M = WGS84_A * (1.0 - WGS84_E2) / w2**1.5
    return M, N


def gaussian_radius(lat: ArrayLike) -> Array:
    """Gaussian mean radius of curvature ``sqrt(M N)`` [m] at geodetic latitude ``lat`` [rad]: the radius of the
    sphere that osculates the ellipsoid there in every direction on average."""
    M, N = radii_of_curvature(lat)
    return np.sqrt(M * N)


def ned_to_lat_lon(d_north: ArrayLike, d_east: ArrayLike, lat: ArrayLike, height: ArrayLike) -> tuple[Array, Array]:
    """Latitude and longitude increments [rad] of small north and east displacements [m] (or their rates [rad/s]
    of velocities [m/s]) at latitude ``lat`` [rad] and ellipsoidal height [m]: ``d_north / (M + h)`` and
    ``d_east / ((N + h) cos lat)``. The inverse of :func:`lat_lon_to_ned`."""
    lat = np.asarray(lat, dtype=float)
    height = np.asarray(height, dtype=float)
    M, N = radii_of_curvature(lat)
    return np.asarray(d_north, float) / (M + height), np.asarray(d_east, float) / ((N + height) * np.cos(lat))


def lat_lon_to_ned(d_lat: ArrayLike, d_lon: ArrayLike, lat: ArrayLike, height: ArrayLike) -> tuple[Array, Array]:
    """North and east displacements [m] of small latitude and longitude increments [rad] at latitude ``lat``
    [rad] and ellipsoidal height [m]: ``d_lat (M + h)`` and ``d_lon (N + h) cos lat``. The inverse of
    :func:`ned_to_lat_lon`."""
    lat = np.asarray(lat, dtype=float)
    height = np.asarray(height, dtype=float)
    M, N = radii_of_curvature(lat)
    return np.asarray(d_lat, float) * (M + height), np.asarray(d_lon, float) * (N + height) * np.cos(lat)


def geodetic_to_ecef(lat: ArrayLike, lon: ArrayLike, height: ArrayLike) -> Array:
    """Geodetic (lat, lon [rad], ellipsoidal height [m]) to ECEF [m], shape (..., 3).

    ``X = (N+h) cos(lat) cos(lon)``, ``Y = (N+h) cos(lat) sin(lon)``, ``Z = (N(1-e^2)+h) sin(lat)``.
    """
    lat = np.asarray(lat, dtype=float)
    lon = np.asarray(lon, dtype=float)
    height = np.asarray(height, dtype=float)
    _, N = radii_of_curvature(lat)
    cos_lat = np.cos(lat)
    x = (N + height) * cos_lat * np.cos(lon)
    y = (N + height) * cos_lat * np.sin(lon)
    z = (N * (1.0 - WGS84_E2) + height) * np.sin(lat)
    return np.stack(np.broadcast_arrays(x, y, z), axis=-1)


def _height_from_lat(p: Array, z: Array, lat: Array) -> Array:
    """Ellipsoidal height from the distance to the axis p, Z and latitude; stable at the poles."""
    sin_lat, cos_lat = np.sin(lat), np.cos(lat)
    return p * cos_lat + z * sin_lat - WGS84_A * np.sqrt(1.0 - WGS84_E2 * sin_lat**2)


def ecef_to_geodetic(r_e: ArrayLike) -> tuple[Array, Array, Array]:
    """ECEF [m] (..., 3) to geodetic lat, lon [rad] and height [m], closed form.

    Vermeille (2004), "Computing geodetic coordinates from geocentric coordinates", J. Geodesy 78,
    exact for points outside the evolute of the ellipsoid (any point more than ~43 km from the
    Earth's centre), followed by the height formula that stays well conditioned at the poles.
    """
    r_e = np.asarray(r_e, dtype=float)
    x, y, z = r_e[..., 0], r_e[..., 1], r_e[..., 2]
    a2 = WGS84_A**2
    e4 = WGS84_E2**2
    p2 = x**2 + y**2
    p_axis = np.sqrt(p2)
    p = p2 / a2
    q = (1.0 - WGS84_E2) / a2 * z**2
    r = (p + q - e4) / 6.0
    s = e4 * p * q / (4.0 * r**3)
    t = np.cbrt(1.0 + s + np.sqrt(s * (2.0 + s)))
    u = r * (1.0 + t + 1.0 / t)
    v = np.sqrt(u**2 + e4 * q)
    w = WGS84_E2 * (u + v - q) / (2.0 * v)
    k = np.sqrt(u + v + w**2) - w
    D = k * p_axis / (k + WGS84_E2)
    lat = 2.0 * np.arctan2(z, D + np.sqrt(D**2 + z**2))
    lon = np.arctan2(y, x)
    height = _height_from_lat(p_axis, z, lat)
    return lat, lon, height


def ecef_to_geodetic_iterative(
    r_e: ArrayLike, tol: float = 1e-12, max_iter: int = 50
) -> tuple[Array, Array, Array]:
    """ECEF [m] to geodetic lat, lon [rad], height [m] by fixed-point iteration on latitude.

    The method of ``xyz2llh.m`` in Bošnjak (2014; ``docs/method-axis.md``, References): start from h = 0 and
    iterate ``lat = atan2(Z, p (1 - e^2 N / (N + h)))`` until the largest change is below ``tol`` [rad].
    Raises ``RuntimeError`` when ``max_iter`` is reached without convergence.
    """
    r_e = np.asarray(r_e, dtype=float)
    x, y, z = r_e[..., 0], r_e[..., 1], r_e[..., 2]
    p_axis = np.hypot(x, y)
    lat = np.arctan2(z, p_axis * (1.0 - WGS84_E2))
    for _ in range(max_iter):
        _, N = radii_of_curvature(lat)
        height = _height_from_lat(p_axis, z, lat)
        lat_new = np.arctan2(z, p_axis * (1.0 - WGS84_E2 * N / (N + height)))
        change = np.max(np.abs(lat_new - lat), initial=0.0)
        lat = lat_new
        if change < tol:
            break
    else:
        raise RuntimeError(f"ecef_to_geodetic_iterative: no convergence to {tol} rad in {max_iter} steps")
    return lat, np.arctan2(y, x), _height_from_lat(p_axis, z, lat)


def C_n_e(lat: ArrayLike, lon: ArrayLike) -> Array:
    """Rotation matrix NED -> ECEF, shape (..., 3, 3); its columns are north, east, down in ECEF.

    ``r_e = C_n_e @ r_n``. Latitude and longitude in radians.
    """
    lat = np.asarray(lat, dtype=float)
    lon = np.asarray(lon, dtype=float)
    sl, cl = np.sin(lat), np.cos(lat)
    so, co = np.sin(lon), np.cos(lon)
    zero = np.zeros(np.broadcast(sl, so).shape)
    rows = [
        [-sl * co, -so + zero, -cl * co],
        [-sl * so, co + zero, -cl * so],
        [cl + zero, zero, -sl + zero],
    ]
    return np.stack([np.stack(np.broadcast_arrays(*row), axis=-1) for row in rows], axis=-2)


def C_e_n(lat: ArrayLike, lon: ArrayLike) -> Array:
    """Rotation matrix ECEF -> NED, the transpose of :func:`C_n_e`, shape (..., 3, 3)."""
    return np.swapaxes(C_n_e(lat, lon), -1, -2)


def normal_gravity(lat: ArrayLike, height: ArrayLike) -> Array:
    """Magnitude of WGS84 normal gravity [m/s^2] along the ellipsoid normal (pointing down in NED).

    Somigliana's closed formula on the ellipsoid with the second-order height correction of
    NIMA TR8350.2 (eq. 4-3): ``g_h = g_0 (1 - 2/a (1 + f + m - 2 f sin^2 lat) h + 3 h^2 / a^2)``.
    The gravity vector in NED is ``[0, 0, normal_gravity(lat, h)]`` (the north component of normal
    gravity above the ellipsoid, below 1e-5 m/s^2 at 10 km, is neglected).
    """
    lat = np.asarray(lat, dtype=float)
    height = np.asarray(height, dtype=float)
    sin2 = np.sin(lat) ** 2
    gamma_0 = GAMMA_E * (1.0 + SOMIGLIANA_K * sin2) / np.sqrt(1.0 - WGS84_E2 * sin2)
    m = OMEGA_IE**2 * WGS84_A**2 * WGS84_B / WGS84_GM
    return gamma_0 * (
        1.0 - 2.0 / WGS84_A * (1.0 + WGS84_F + m - 2.0 * WGS84_F * sin2) * height + 3.0 * height**2 / WGS84_A**2
    )


def normal_gravity_gradient(lat: ArrayLike, height: ArrayLike) -> tuple[Array, Array]:
    """First-order change of the normal gravity vector in NED [1/s^2] per metre of NED displacement, on the
    sphere of radius ``R + h`` (``R`` the Gaussian radius, :func:`gaussian_radius`): ``(horizontal, vertical)``
    with ``d g_n = [-horizontal d_north, -horizontal d_east, vertical d_down]``, ``horizontal = g / (R + h)``
    (the vertical tilts towards the point of departure) and ``vertical = 2 g / (R + h)`` (gravity grows
    going down). ``lat`` [rad], ``height`` ellipsoidal [m]."""
    g = normal_gravity(lat, height)
    radius = gaussian_radius(lat) + np.asarray(height, dtype=float)
    return g / radius, 2.0 * g / radius


def earth_rate_n(lat: ArrayLike) -> Array:
    """Earth rotation rate resolved in NED, ``omega_ie_n = W [cos lat, 0, -sin lat]`` [rad/s], (..., 3)."""
    lat = np.asarray(lat, dtype=float)
    return np.stack(
        np.broadcast_arrays(OMEGA_IE * np.cos(lat), np.zeros_like(lat), -OMEGA_IE * np.sin(lat)), axis=-1
    )


def transport_rate_n(lat: ArrayLike, height: ArrayLike, v_n: ArrayLike) -> Array:
    """Transport rate ``omega_en_n`` [rad/s] of the NED frame over the ellipsoid, (..., 3).

    ``[v_E/(N+h), -v_N/(M+h), -v_E tan(lat)/(N+h)]`` with ``v_n = [v_N, v_E, v_D]`` [m/s].
    """
    lat = np.asarray(lat, dtype=float)
    height = np.asarray(height, dtype=float)
    v_n = np.asarray(v_n, dtype=float)
    M, N = radii_of_curvature(lat)
    v_north, v_east = v_n[..., 0], v_n[..., 1]
    return np.stack(
        [v_east / (N + height), -v_north / (M + height), -v_east * np.tan(lat) / (N + height)], axis=-1
    )
