"""ω, φ, κ covariance and grid-axis position sigmas against finite differences, Monte Carlo with scipy's
``Rotation`` and positions projected by PROJ — none of them through georef's own rotation code."""

from __future__ import annotations

import numpy as np
import pytest
from pyproj import Geod, Proj, Transformer
from scipy.spatial.transform import Rotation

from georef.frames.opk_covariance import grid_position_covariance, opk_covariance, opk_jacobian

SWAP = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # NED <-> ENU, and image <-> camera axes


def _grid_rotation(gamma_deg):
    """ENU -> grid (east, north, up turned so that a true azimuth a has the grid azimuth a - gamma)."""
    return Rotation.from_euler("z", gamma_deg, degrees=True).as_matrix()


def _opk(C_c_n, gamma_deg):
    """ω, φ, κ [rad] by scipy: R_i_m = G C_n_enu C_c_n C_i_c = Rx(ω) Ry(φ) Rz(κ) (intrinsic XYZ)."""
    return Rotation.from_matrix(_grid_rotation(gamma_deg) @ SWAP @ C_c_n @ SWAP).as_euler("XYZ")


CASES = [  # camera yaw, pitch, roll [deg] (ZYX to NED), convergence [deg]
    (21.2, 0.5, -0.5, 0.0), (135.0, 4.0, 12.0, -3.7), (270.0, -8.0, 25.0, 4.3), (3.0, 30.0, -5.0, 1.0),
]


@pytest.mark.parametrize(("yaw", "pitch", "roll", "gamma"), CASES)
def test_jacobian_against_finite_differences(yaw, pitch, roll, gamma):
    C = Rotation.from_euler("ZYX", [yaw, pitch, roll], degrees=True).as_matrix()
    omega, phi, _ = _opk(C, gamma)
    J = opk_jacobian(omega, phi, gamma)
    step = 1e-6
    numeric = np.empty((3, 3))
    for k in range(3):
        d = np.zeros(3)
        d[k] = step
        plus = _opk(Rotation.from_rotvec(d).as_matrix() @ C, gamma)  # C' = exp([d x]) C, d in NED
        minus = _opk(Rotation.from_rotvec(-d).as_matrix() @ C, gamma)
        numeric[:, k] = (plus - minus) / (2 * step)
    np.testing.assert_allclose(J, numeric, atol=1e-6)


@pytest.mark.parametrize(("yaw", "pitch", "roll", "gamma"), CASES)
def test_covariance_against_monte_carlo(yaw, pitch, roll, gamma):
    rng = np.random.default_rng(7)
    sigma = np.radians([0.05, 0.02, 0.3])  # north, east, down tilt: a yaw much worse than roll/pitch
    A = rng.normal(size=(3, 3))
    corr = np.corrcoef(A @ A.T + 3 * np.eye(3))
    P = corr * np.outer(sigma, sigma)
    C = Rotation.from_euler("ZYX", [yaw, pitch, roll], degrees=True).as_matrix()
    omega, phi, _ = _opk(C, gamma)
    n = 200_000
    d = rng.multivariate_normal(np.zeros(3), P, size=n)
    samples = Rotation.from_matrix(_grid_rotation(gamma) @ SWAP @ Rotation.from_rotvec(d).as_matrix() @ C
                                   @ SWAP).as_euler("XYZ")
    samples[:, 2] = np.unwrap(samples[:, 2])
    empirical = np.cov(samples.T)
    predicted = opk_covariance(omega, phi, gamma, P)
    np.testing.assert_allclose(np.sqrt(np.diag(predicted)), np.sqrt(np.diag(empirical)), rtol=0.01)
    r_pred = predicted / np.sqrt(np.outer(np.diag(predicted), np.diag(predicted)))
    r_emp = empirical / np.sqrt(np.outer(np.diag(empirical), np.diag(empirical)))
    np.testing.assert_allclose(r_pred, r_emp, atol=0.01)


def test_omega_is_about_the_pitch_axis_on_north_south_lines():
    """The reported case: ω and φ sigmas equal the roll and pitch sigmas only on east-west lines. Roll σ 0.01°,
    pitch σ 0.05° about the body axes: flying north, ω (about the map's east axis) gets the pitch σ."""
    body = np.diag(np.radians([0.01, 0.05, 0.2]) ** 2)  # roll, pitch, yaw axes of the body
    for yaw, expect in ((0.0, (0.05, 0.01)), (90.0, (0.01, 0.05)), (180.0, (0.05, 0.01)), (270.0, (0.01, 0.05))):
        C = Rotation.from_euler("ZYX", [yaw, 0.0, 0.0], degrees=True).as_matrix()
        P = C @ body @ C.T  # the body-axis covariance as NED small rotations
        omega, phi, _ = _opk(C, 0.0)
        sd = np.degrees(np.sqrt(np.diag(opk_covariance(omega, phi, 0.0, P))))
        np.testing.assert_allclose(sd, (*expect, 0.2), atol=1e-9)


def test_grid_position_sigmas_against_proj_monte_carlo():
    """σ north 1 m, σ east 0.2 m at 21° E in SWEREF99 TM (convergence about 4.3°): offsets along the
    geodesic (pyproj.Geod), projected by PROJ, give the grid sigmas predicted, not σ_e and σ_n."""
    lat, lon = 64.0, 21.0
    proj = Proj("EPSG:3006")
    factors = proj.get_factors(lon, lat)
    gamma, k = factors.meridian_convergence, np.sqrt(factors.meridional_scale * factors.parallel_scale)
    assert abs(gamma) > 4.0
    rng = np.random.default_rng(3)
    n = 100_000
    dn, de = rng.normal(0, 1.0, n), rng.normal(0, 0.2, n)
    geod = Geod(ellps="GRS80")
    lon1, lat1, _ = geod.fwd(np.full(n, lon), np.full(n, lat), np.zeros(n), dn)
    lon2, lat2, _ = geod.fwd(lon1, lat1, np.full(n, 90.0), de)
    e, nn = Transformer.from_crs("EPSG:4326", "EPSG:3006", always_xy=True).transform(lon2, lat2)
    empirical = np.cov(np.vstack([e, nn]))
    var_x, var_y, cov_xy = grid_position_covariance(1.0, 0.04, gamma, k)
    np.testing.assert_allclose([np.sqrt(var_x), np.sqrt(var_y)], np.sqrt(np.diag(empirical)), rtol=0.01)
    assert cov_xy == pytest.approx(empirical[0, 1], abs=0.01)
    assert np.sqrt(var_x) > 0.2 * 1.05  # the rotation shows: easting sigma larger than sigma east
