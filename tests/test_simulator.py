"""The simulator makes what it claims: seed-like flight geometry, consistent truth, stated noise levels."""

from __future__ import annotations

import numpy as np
import pytest

from georef.frames import C_e_n, geodetic_to_ecef, normal_gravity, radii_of_curvature
from georef.frames.mounting import lever_arm_ecef
from georef.imu_errors import imu_preset
from georef.sim.flight import SimConfig, simulate
from georef.sim.trajectory import FlightPlan, fly


@pytest.fixture(scope="module")
def flight():
    return simulate(SimConfig(seed=2))


def test_flight_geometry_is_seed_like(flight):
    truth = flight.truth_frames
    speed = np.hypot(flight.truth_nav.v_n[:, 0], flight.truth_nav.v_n[:, 1])
    assert 27.0 < np.median(speed) < 33.0
    crab = (truth["body_yaw"] - truth["track"] + 180) % 360 - 180
    assert 3.0 < np.max(np.abs(crab)) < 5.0
    assert np.ptp(flight.truth_nav.height) > 15.0  # climbs
    assert np.degrees(np.max(np.abs(flight.truth_nav.roll))) > 15.0  # coordinated turns


def test_positions_integrate_the_velocities():
    traj = fly(FlightPlan(duration_s=60.0), 400.0)
    M, N = radii_of_curvature(traj.lat)
    lat_rate = np.gradient(traj.lat, traj.time)
    np.testing.assert_allclose(lat_rate[5:-5] * (M + traj.height)[5:-5], traj.v_n[5:-5, 0], atol=2e-3)


def test_straight_level_specific_force_is_gravity():
    traj = fly(FlightPlan(duration_s=40.0, turbulence_deg=0.0, climb_every_n_strips=0), 400.0)
    straight = traj.time < 45.0
    g = normal_gravity(traj.lat, traj.height)
    magnitude = np.linalg.norm(traj.f_ib_b, axis=1)
    # Coriolis and transport terms at 30 m/s are a few 1e-3 m/s^2
    np.testing.assert_allclose(magnitude[straight][10:-10], g[straight][10:-10], atol=5e-3)


def test_gnss_noise_has_the_stated_sigma():
    flight = simulate(SimConfig(seed=3, plan=FlightPlan(duration_s=900.0)))
    fixes = flight.gnss_fixes
    nav = flight.truth_nav
    idx = np.searchsorted(nav.time, fixes["time"].to_numpy())
    # truth antenna at the fix time (rows are 12.5 ms after the second: interpolate linearly)
    w = ((fixes["time"].to_numpy() - nav.time[idx - 1]) / (nav.time[idx] - nav.time[idx - 1]))[:, None]
    r_imu = (1 - w) * geodetic_to_ecef(nav.lat[idx - 1], nav.lon[idx - 1], nav.height[idx - 1]) + \
        w * geodetic_to_ecef(nav.lat[idx], nav.lon[idx], nav.height[idx])
    r_ant = r_imu + lever_arm_ecef(nav.lat[idx], nav.lon[idx], nav.C_b_n[idx], flight.config.lever_arm_gnss_m)
    r_fix = geodetic_to_ecef(np.radians(fixes["lat"]), np.radians(fixes["lon"]), fixes["height"])
    err_n = np.einsum("nij,nj->ni", C_e_n(nav.lat[idx], nav.lon[idx]), r_fix - r_ant)
    np.testing.assert_allclose(err_n.std(axis=0), [1.0, 1.0, 2.0], rtol=0.1)


def test_imu_white_noise_matches_the_datasheet():
    from georef.sim.sensors import corrupt_imu

    model = imu_preset("mems-ivru")
    rng = np.random.default_rng(0)
    t = np.arange(200_000) / 200.0
    gyro, accel, gyro_bias, accel_bias = corrupt_imu(np.zeros((len(t), 3)), np.zeros((len(t), 3)), t, model,
                                                     None, rng)
    noise = np.diff(gyro - gyro_bias, axis=0).std(axis=0) / np.sqrt(2)
    np.testing.assert_allclose(noise, np.sqrt(model.gyro_white_psd * 200.0), rtol=0.05)
    noise = np.diff(accel - accel_bias, axis=0).std(axis=0) / np.sqrt(2)
    np.testing.assert_allclose(noise, np.sqrt(model.accel_white_psd * 200.0), rtol=0.05)


def test_same_seed_same_files(tmp_path):
    from georef.sim.files import write_flight

    a = write_flight(simulate(SimConfig(seed=9)), tmp_path / "a")
    b = write_flight(simulate(SimConfig(seed=9)), tmp_path / "b")
    for name in ("POS.txt", "Kamera.txt", "truth.csv"):
        assert a[name].read_bytes() == b[name].read_bytes()
