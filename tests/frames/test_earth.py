"""Geodesy against PROJ (pyproj) and against closed-form facts of the WGS84 ellipsoid."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pyproj import Transformer

from georef.frames import (
    C_e_n,
    C_n_e,
    ecef_to_geodetic,
    ecef_to_geodetic_iterative,
    gaussian_radius,
    geodetic_to_ecef,
    kernels,
    lat_lon_to_ned,
    ned_to_lat_lon,
    normal_gravity,
    normal_gravity_gradient,
    radii_of_curvature,
)

TO_ECEF = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)


def _globe(n: int = 200_000, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    lat = np.degrees(np.arcsin(rng.uniform(-1, 1, n)))
    lon = rng.uniform(-180, 180, n)
    h = rng.uniform(-5000, 50000, n)
    # poles, equator, date line and the height extremes exactly
    special_lat = np.array([90, -90, 0, 0, 89.9999999, -89.9999999, 45, 0])
    special_lon = np.array([0, 123, 0, 180, -45, 10, -180, 90])
    special_h = np.array([-5000, 50000, 0, -5000, 50000, 0, 50000, 0])
    return (np.concatenate([lat, special_lat]), np.concatenate([lon, special_lon]),
            np.concatenate([h, special_h]))


def test_forward_matches_proj_to_a_millimetre():
    lat, lon, h = _globe()
    x, y, z = TO_ECEF.transform(lon, lat, h)
    ours = geodetic_to_ecef(np.radians(lat), np.radians(lon), h)
    assert np.max(np.abs(ours - np.stack([x, y, z], -1))) < 1e-3


@pytest.mark.parametrize("inverse", [ecef_to_geodetic, ecef_to_geodetic_iterative])
def test_inverse_matches_proj_to_a_millimetre(inverse):
    lat, lon, h = _globe()
    x, y, z = TO_ECEF.transform(lon, lat, h)
    lat_r, lon_r, h_r = inverse(np.stack([x, y, z], -1))
    lon_p, lat_p, h_p = TO_ECEF.transform(x, y, z, direction="INVERSE")
    # compare as positions: 1 mm on the ground, whatever the latitude (longitude is free at the poles)
    back = geodetic_to_ecef(lat_r, lon_r, h_r)
    proj = geodetic_to_ecef(np.radians(lat_p), np.radians(lon_p), h_p)
    assert np.max(np.linalg.norm(back - proj, axis=-1)) < 1e-3
    assert np.max(np.abs(h_r - h_p)) < 1e-3
    M, _ = radii_of_curvature(np.radians(lat_p))
    assert np.max(np.abs(lat_r - np.radians(lat_p)) * (M + h_p)) < 1e-3


def test_seed_roundtrip_reaches_1e_14_relative():
    """Bošnjak (2014) checked llh2xyz/xyz2llh by converting back; differences were about 1e-14."""
    lat, lon, h = np.radians(44.04731), np.radians(15.62164), 760.4
    r = geodetic_to_ecef(lat, lon, h)
    for inverse in (ecef_to_geodetic, ecef_to_geodetic_iterative):
        lat2, lon2, h2 = inverse(r)
        assert abs(lat2 - lat) < 1e-14 and abs(lon2 - lon) < 1e-14 and abs(h2 - h) < 1e-8


@settings(max_examples=300, deadline=None)
@given(st.floats(-90, 90), st.floats(-180, 180), st.floats(-5000, 50000))
def test_roundtrip_property(lat_deg, lon_deg, h):
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    lat2, lon2, h2 = ecef_to_geodetic(geodetic_to_ecef(lat, lon, h))
    assert abs(h2 - h) < 1e-6
    assert abs(lat2 - lat) < 1e-12
    if abs(lat_deg) < 89.999:
        assert abs(np.angle(np.exp(1j * (lon2 - lon)))) < 1e-12


def test_vectorised_million_points():
    lat, lon, h = _globe(1_000_000, seed=3)
    r = geodetic_to_ecef(np.radians(lat), np.radians(lon), h)
    assert ecef_to_geodetic(r)[0].shape == (len(lat),)


def test_C_n_e_columns_are_the_geodetic_directions():
    lat, lon, h = np.radians(44.0), np.radians(15.6), 700.0
    M, N = radii_of_curvature(lat)
    step = 1e-7
    north = (geodetic_to_ecef(lat + step, lon, h) - geodetic_to_ecef(lat - step, lon, h)) / (2 * step * (M + h))
    east = (geodetic_to_ecef(lat, lon + step, h) - geodetic_to_ecef(lat, lon - step, h)) / (
        2 * step * (N + h) * np.cos(lat))
    down = -(geodetic_to_ecef(lat, lon, h + 1) - geodetic_to_ecef(lat, lon, h - 1)) / 2
    C = C_n_e(lat, lon)
    np.testing.assert_allclose(C[:, 0], north, atol=1e-7)
    np.testing.assert_allclose(C[:, 1], east, atol=1e-7)
    np.testing.assert_allclose(C[:, 2], down, atol=1e-9)
    np.testing.assert_allclose(C_e_n(lat, lon) @ C, np.eye(3), atol=1e-15)


def test_normal_gravity_reference_values():
    # WGS84 (NIMA TR8350.2): 9.7803253359 m/s^2 at the equator, 9.8321849378 m/s^2 at the poles
    assert normal_gravity(0.0, 0.0) == pytest.approx(9.7803253359, abs=1e-9)
    assert normal_gravity(np.pi / 2, 0.0) == pytest.approx(9.8321849378, abs=1e-9)
    # free-air gradient about -3.086e-6 s^-2
    gradient = (normal_gravity(np.radians(45), 100.0) - normal_gravity(np.radians(45), 0.0)) / 100.0
    assert gradient == pytest.approx(-3.086e-6, rel=2e-3)


def test_radii_of_curvature_at_equator_and_pole():
    M0, N0 = radii_of_curvature(0.0)
    assert N0 == pytest.approx(6378137.0)
    assert M0 == pytest.approx(6378137.0 * (1 - 0.00669437999014), rel=1e-12)
    M90, N90 = radii_of_curvature(np.pi / 2)
    assert M90 == pytest.approx(N90)


def _proj_ecef(lat: np.ndarray, lon: np.ndarray, h: np.ndarray) -> np.ndarray:
    """ECEF [m] (..., 3) by PROJ from latitude, longitude [rad] and ellipsoidal height [m]."""
    x, y, z = TO_ECEF.transform(np.degrees(lon), np.degrees(lat), h)
    return np.stack([x, y, z], -1)


def _proj_metres_per_radian(lat: np.ndarray, lon: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Metres per radian of latitude and of longitude at (lat, lon, h), measured on PROJ's ECEF: the chord between
    points 1e-6 rad either side (a chord of 13 m: it differs from the arc by 1e-13 relative)."""
    d = 1e-6
    north = np.linalg.norm(_proj_ecef(lat + d, lon, h) - _proj_ecef(lat - d, lon, h), axis=-1) / (2 * d)
    east = np.linalg.norm(_proj_ecef(lat, lon + d, h) - _proj_ecef(lat, lon - d, h), axis=-1) / (2 * d)
    return north, east


def _points(n: int = 2000, seed: int = 5):
    rng = np.random.default_rng(seed)
    return (np.radians(rng.uniform(-85.0, 85.0, n)), np.radians(rng.uniform(-180.0, 180.0, n)),
            rng.uniform(-500.0, 20000.0, n))


def test_lat_lon_increments_match_proj():
    """NED metres <-> latitude/longitude increments against the distances PROJ's ECEF gives, both directions, and
    the compiled twin equal to the vectorised form."""
    lat, lon, h = _points()
    north, east = _proj_metres_per_radian(lat, lon, h)
    d_lat, d_lon = np.full_like(lat, 1e-6), np.full_like(lat, -2e-6)
    d_north, d_east = lat_lon_to_ned(d_lat, d_lon, lat, h)
    np.testing.assert_allclose(d_north, north * d_lat, rtol=1e-9)
    np.testing.assert_allclose(d_east, east * d_lon, rtol=1e-9)
    back_lat, back_lon = ned_to_lat_lon(d_north, d_east, lat, h)
    np.testing.assert_allclose(back_lat, d_lat, rtol=1e-14)
    np.testing.assert_allclose(back_lon, d_lon, rtol=1e-14)
    for i in range(0, len(lat), 97):
        np.testing.assert_allclose(kernels.lat_lon_to_ned(d_lat[i], d_lon[i], lat[i], h[i]),
                                   (d_north[i], d_east[i]), rtol=1e-15)
        np.testing.assert_allclose(kernels.ned_to_lat_lon(d_north[i], d_east[i], lat[i], h[i]),
                                   (back_lat[i], back_lon[i]), rtol=1e-15)


def test_gaussian_radius_is_the_mean_of_proj_meridian_and_prime_vertical():
    lat, lon, _ = _points()
    north, east = _proj_metres_per_radian(lat, lon, np.zeros_like(lat))
    M_proj, N_proj = north, east / np.cos(lat)
    np.testing.assert_allclose(gaussian_radius(lat), np.sqrt(M_proj * N_proj), rtol=1e-9)


def test_gravity_gradient_against_the_height_derivative_and_the_tilt_of_the_normal():
    """The vertical gradient ``2 g / (R + h)`` is the spherical approximation of the derivative of TR8350.2's
    normal gravity with height (measured within 0.35 %: the ellipsoid's own term ``(1 + f + m - 2 f sin^2)``);
    the horizontal one ``g / (R + h)`` is gravity times the turn of the ellipsoid normal per metre, measured on
    PROJ's ECEF (within 0.39 %: the meridian and prime-vertical radii lie up to 0.34 % either side of the
    Gaussian one)."""
    lat, lon, h = _points(300)
    horizontal, vertical = normal_gravity_gradient(lat, h)
    dh = 1.0
    dg_dh = (normal_gravity(lat, h + dh) - normal_gravity(lat, h - dh)) / (2 * dh)
    np.testing.assert_allclose(vertical, -dg_dh, rtol=4e-3)
    # the normal's turn per metre north and east, from PROJ: (up at the moved point) - (up here), over the distance
    north, east = _proj_metres_per_radian(lat, lon, h)
    up = _proj_ecef(lat, lon, h + 1.0) - _proj_ecef(lat, lon, h)
    d = 1e-6
    for moved, metres in (((lat + d, lon), north * d), ((lat, lon + d), east * d)):
        up_moved = _proj_ecef(*moved, h + 1.0) - _proj_ecef(*moved, h)
        turn = np.linalg.norm(up_moved - up, axis=-1) / metres
        g = normal_gravity(lat, h)
        np.testing.assert_allclose(horizontal, g * turn, rtol=4.5e-3)
    for i in range(0, len(lat), 29):
        np.testing.assert_allclose(kernels.gravity_gradient(lat[i], h[i]), (horizontal[i], vertical[i]),
                                   rtol=1e-15)
