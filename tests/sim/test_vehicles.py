"""The broadened simulator: multicopter and car kinematics, vibration characters, forced biases, extra outputs.

Every vehicle's ideal IMU is checked against georef's own strapdown; the other tests check that each vehicle,
vibration kind and option does what docs/simulator.md says, with the figures measured quoted beside each bound.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from georef_cli.main import app
from scipy.signal import periodogram, welch
from typer.testing import CliRunner

from georef.frames import C_e_n, dcm_to_euler, dcm_to_quat, geodetic_to_ecef, quat_to_dcm, wrap_pi
from georef.fusion.strapdown import run_free_inertial
from georef.imu_errors import ImuErrorModel, imu_preset
from georef.io.generic import read_marg_csv
from georef.io.pos import read_pos
from georef.sim.car import CarPlan, car_schedule, drive
from georef.sim.files import write_flight, write_generic
from georef.sim.flight import UNIT_COLUMNS, SimConfig, simulate
from georef.sim.multicopter import MulticopterPlan, fly_multicopter, multicopter_schedule
from georef.sim.sensors import (
    AutopilotModel,
    GnssModel,
    MagnetometerModel,
    VibrationModel,
    corrupt_imu,
    vibration_samples,
)
from georef.sim.trajectory import FlightPlan, Trajectory, fly, imu_from_kinematics

FINE = 400.0
#: An IMU without any error of its own, so that only the vibration remains.
PERFECT_IMU = ImuErrorModel(0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)


@pytest.fixture(scope="module")
def multicopter() -> tuple[MulticopterPlan, Trajectory]:
    plan = MulticopterPlan()
    return plan, fly_multicopter(plan, FINE)


@pytest.fixture(scope="module")
def car() -> tuple[CarPlan, Trajectory]:
    plan = CarPlan()
    return plan, drive(plan, FINE)


def _free_inertial_errors(truth: Trajectory, rate_hz: float) -> tuple[float, float, float]:
    """Max position [m], velocity [m/s] and attitude [deg] error of georef's strapdown on the ideal IMU."""
    idx = np.arange(0, len(truth.time), int(FINE / rate_hz))
    x0 = np.zeros(16)
    x0[:3] = truth.lat[0], truth.lon[0], truth.height[0]
    x0[3:6] = truth.v_n[0]
    x0[6:10] = dcm_to_quat(truth.C_b_n[0])
    out = run_free_inertial(x0, truth.time[idx], truth.omega_ib_b[idx], truth.f_ib_b[idx])
    r_ins = geodetic_to_ecef(out[:, 0], out[:, 1], out[:, 2])
    r_true = geodetic_to_ecef(truth.lat[idx], truth.lon[idx], truth.height[idx])
    err_n = np.einsum("nij,nj->ni", C_e_n(truth.lat[idx], truth.lon[idx]), r_ins - r_true)
    angles = dcm_to_euler(quat_to_dcm(out[:, 6:10]))
    attitude = max(np.degrees(np.abs(wrap_pi(est - ref[idx]))).max()
                   for est, ref in zip(angles, (truth.roll, truth.pitch, truth.yaw), strict=True))
    return float(np.abs(err_n).max()), float(np.abs(out[:, 3:6] - truth.v_n[idx]).max()), float(attitude)


# --- 1. kinematics -> ideal IMU -----------------------------------------------------------------------------

@pytest.mark.parametrize("vehicle", ["multicopter-fixed", "multicopter-track", "multicopter-rotating", "car"])
def test_strapdown_follows_each_vehicle(vehicle):
    """Two minutes of free inertial navigation at 200 Hz on the ideal IMU stay on the truth.

    Measured (multicopter at 10 m/s): fixed / track / rotating heading 0.8 / 1.6 / 0.8 mm, <= 4.2e-5 m/s,
    1.9e-4 deg; car 0.15 mm, 4.4e-6 m/s, 2.3e-5 deg. Without the Coriolis and transport terms in the specific
    force (2 omega_ie x v is 1.5e-3 m/s^2 at 10 m/s) the fixed-heading multicopter ends 1.5 m and 0.03 m/s off
    (checked by mutation), far outside these bounds.
    """
    if vehicle == "car":
        truth = drive(CarPlan(), FINE)
    else:
        truth = fly_multicopter(MulticopterPlan(heading_policy=vehicle.split("-")[1], speed_mps=10.0), FINE)
    assert truth.time[-1] == pytest.approx(120.0)
    position, velocity, attitude = _free_inertial_errors(truth, 200.0)
    assert position < 0.02
    assert velocity < 1e-3
    assert attitude < 2e-3


def test_imu_from_kinematics_is_the_back_half_of_fly():
    """``fly`` is the helicopter's kinematics through the shared step: re-running it on fly's truth agrees."""
    traj = fly(FlightPlan(duration_s=30.0), FINE)
    again = imu_from_kinematics(traj.time, traj.lat, traj.lon, traj.height, traj.v_n, traj.a_n, traj.roll,
                                traj.pitch, traj.yaw)
    np.testing.assert_allclose(again.omega_ib_b, traj.omega_ib_b, atol=1e-12)
    np.testing.assert_allclose(again.f_ib_b, traj.f_ib_b, atol=1e-12)


# --- 2. multicopter -------------------------------------------------------------------------------------------

def test_multicopter_starts_hovering(multicopter):
    """Hover: horizontal and vertical speed stay at the position-hold wander (measured 0.18 m/s)."""
    plan, truth = multicopter
    hover = truth.time < plan.hover_s
    assert np.linalg.norm(truth.v_n[hover], axis=1).max() < 0.5
    assert np.ptp(truth.height[hover]) < 1.0
    assert abs(truth.height[0] - plan.start_height_m - plan.hover_height_m) < 1e-9
    # and it does fly afterwards, within the plan's speeds and heights (measured 8.19 m/s, 60-100 m)
    speed = np.hypot(truth.v_n[:, 0], truth.v_n[:, 1])
    assert 7.5 < speed.max() < 8.5
    above_start = truth.height - plan.start_height_m
    assert 50.0 < above_start.min() and above_start.max() < 120.0 and np.ptp(above_start) > 30.0


@pytest.mark.parametrize("wobble_deg, bound_deg", [(0.8, 1.2), (0.0, 1e-6)])
def test_multicopter_thrust_along_body_z(wobble_deg, bound_deg):
    """The specific force lies along body -z within the wobble (measured max 1.04 deg for 0.8 deg; 0 without)."""
    truth = fly_multicopter(MulticopterPlan(wobble_deg=wobble_deg, duration_s=90.0), FINE)
    f = truth.f_ib_b
    angle = np.degrees(np.arccos(np.clip(-f[:, 2] / np.linalg.norm(f, axis=1), -1.0, 1.0)))
    assert angle.max() < bound_deg
    # the tilt is real: up to 9-12 deg when accelerating at 2 m/s^2, so body z is not simply vertical
    assert np.degrees(np.abs(truth.pitch)).max() > 5.0 and np.degrees(np.abs(truth.roll)).max() > 5.0


def test_multicopter_flies_sideways_with_heading_held(multicopter):
    """Fixed heading (north, then east after the second hover): track - yaw = the leg's intended sideways angle.

    Measured: within 0.8-1.3 deg of 90, 0, -90 and -90 deg in the four legs (the position-hold wander).
    """
    plan, truth = multicopter
    legs = multicopter_schedule(plan).legs
    track = np.arctan2(truth.v_n[:, 1], truth.v_n[:, 0])
    sideways_seen = []
    for start, end, track_deg, heading_deg in legs:
        inside = (truth.time > start) & (truth.time < end)
        if not inside.any():
            continue
        intended = (track_deg - heading_deg + 180.0) % 360.0 - 180.0
        sideways = np.degrees(wrap_pi(track[inside] - truth.yaw[inside]))
        assert np.abs((sideways - intended + 180.0) % 360.0 - 180.0).max() < 2.0
        sideways_seen.append(intended)
    assert {90.0, 0.0, -90.0} <= set(sideways_seen)
    # the heading is held: yaw stays at the held value in each leg
    for start, end, _, heading_deg in legs:
        inside = (truth.time > start) & (truth.time < end)
        if inside.any():
            assert np.degrees(np.abs(wrap_pi(truth.yaw[inside] - np.radians(heading_deg)))).max() < 1e-6


def test_multicopter_heading_policies():
    """track: yaw = track in the legs (measured within 1.3 deg); rotating: yaw turns at 6 deg/s."""
    plan = MulticopterPlan(heading_policy="track", duration_s=90.0)
    truth = fly_multicopter(plan, FINE)
    track = np.arctan2(truth.v_n[:, 1], truth.v_n[:, 0])
    for start, end, _, _ in multicopter_schedule(plan).legs:
        inside = (truth.time > start) & (truth.time < end)
        if inside.any():
            assert np.degrees(np.abs(wrap_pi(track[inside] - truth.yaw[inside]))).max() < 2.0
    plan = MulticopterPlan(heading_policy="rotating", duration_s=90.0)
    truth = fly_multicopter(plan, FINE)
    rate = np.degrees(np.gradient(np.unwrap(truth.yaw), truth.time))
    for start, end, _, _ in multicopter_schedule(plan).legs:
        inside = (truth.time > start) & (truth.time < end)
        if inside.any():
            np.testing.assert_allclose(rate[inside].mean(), 6.0, rtol=1e-6)


# --- 3. car -----------------------------------------------------------------------------------------------------

def test_car_has_no_sideslip_and_follows_the_road(car):
    """Heading = track while moving (measured 5e-14 deg); pitch = road grade at constant speed (1.4e-7 deg)."""
    plan, truth = car
    speed = np.linalg.norm(truth.v_n, axis=1)
    moving = speed > 0.5
    track = np.arctan2(truth.v_n[:, 1], truth.v_n[:, 0])
    assert np.degrees(np.abs(wrap_pi(truth.yaw[moving] - track[moving]))).max() < 1e-8
    assert speed.max() <= 15.0 and speed.max() == pytest.approx(plan.cruise_speed_mps)
    grade = np.arctan2(-truth.v_n[:, 2], np.hypot(truth.v_n[:, 0], truth.v_n[:, 1]))
    cruising = np.abs(speed - plan.cruise_speed_mps) < 1e-9
    assert cruising.sum() > 0.25 * len(speed)  # measured 30 % of the drive at cruising speed
    assert np.degrees(np.abs(truth.pitch[cruising] - grade[cruising])).max() < 1e-5
    assert 1.5 < np.degrees(np.abs(grade)).max() <= 2.0  # the road climbs and falls by the plan's 2 deg
    # junction turns: the heading changes by the plan's turns
    turns = car_schedule(plan).turns
    assert len(turns) >= 2
    first = (truth.time > turns[0][1]) & (truth.time < turns[0][1] + 1.0)
    np.testing.assert_allclose(np.degrees(truth.yaw[first]), plan.start_heading_deg + plan.turns_deg[0], atol=1e-9)


def test_car_standstills_are_still(car):
    """At every standstill (start and a traffic light) velocity is exactly zero and attitude constant."""
    plan, truth = car
    standstills = car_schedule(plan).standstills
    assert standstills[0] == (0.0, plan.start_standstill_s) and len(standstills) >= 2
    dt = 1.0 / FINE
    for start, end in standstills:
        inside = (truth.time > start + 2 * dt) & (truth.time < min(end, truth.time[-1]) - 2 * dt)
        assert inside.sum() > 100
        assert np.all(truth.v_n[inside] == 0.0) and np.all(truth.a_n[inside] == 0.0)
        for angle in (truth.roll, truth.pitch, truth.yaw):
            assert np.ptp(angle[inside]) == 0.0
        # the ideal IMU at rest: Earth rate and gravity only, constant (measured ptp 1e-13 m/s^2, 1e-17 rad/s)
        assert np.ptp(truth.f_ib_b[inside], axis=0).max() < 1e-9
        assert np.ptp(truth.omega_ib_b[inside], axis=0).max() < 1e-12
        assert np.linalg.norm(truth.omega_ib_b[inside][0]) == pytest.approx(7.292115e-5, rel=1e-9)


# --- 4. vibration ----------------------------------------------------------------------------------------------

ROW_RATE = 50.0
ROW_TIME = np.arange(20_000) / ROW_RATE


@pytest.mark.parametrize("level", [0.5, 1.0, 2.0])
@pytest.mark.parametrize("sampling, divisor", [("average", 4.0), ("point", 1.0)])
def test_white_vibration_is_flat_at_the_stated_level(level, sampling, divisor):
    """200 Hz white vibration averaged (or point-sampled) to 50 Hz: flat spectrum, variance level^2 sigma^2 / m.

    Measured: variance / (sigma^2 / m) 0.998-1.011 per axis; Welch PSD / (2 sigma^2 / (m fs)) in five 5-Hz
    bands 0.977-1.043.
    """
    vibration = VibrationModel.of_kind("white", level=level, sampling=sampling)
    gyro, accel = vibration_samples(ROW_TIME, vibration, np.random.default_rng(4))
    accel_sigma, gyro_sigma = vibration.amplitudes()
    np.testing.assert_allclose(accel_sigma, level * np.array([0.25, 0.25, 0.4]))
    np.testing.assert_allclose(accel.var(axis=0), accel_sigma**2 / divisor, rtol=0.05)
    np.testing.assert_allclose(gyro.var(axis=0), gyro_sigma**2 / divisor, rtol=0.05)
    freq, psd = welch(accel, fs=ROW_RATE, nperseg=256, axis=0)
    expected = 2.0 * accel_sigma**2 / divisor / ROW_RATE
    for low in (0.5, 5.0, 10.0, 15.0, 20.0):
        band = (freq >= low) & (freq < low + 5.0)
        np.testing.assert_allclose(psd[band].mean(axis=0) / expected, 1.0, atol=0.1)


def test_rotor_vibration_has_lines_at_blade_pass_and_alias():
    """16 Hz and its 32 Hz harmonic point-sampled at 50 Hz: the two largest bins at 16 and 18 Hz (the alias).

    Measured: the 16 Hz bin holds 86 % of the power, 18 Hz holds 0.4^2 of that; variance A^2 (1 + 0.16) / 2.
    """
    vibration = VibrationModel()
    gyro, accel = vibration_samples(ROW_TIME, vibration, np.random.default_rng(4))
    freq, power = periodogram(accel, fs=ROW_RATE, axis=0)
    for axis in range(3):
        top = np.sort(freq[np.argsort(power[:, axis])[-2:]])
        np.testing.assert_allclose(top, [16.0, 18.0])
    np.testing.assert_allclose(accel.var(axis=0), 0.4**2 * 1.16 / 2.0, rtol=1e-3)
    np.testing.assert_allclose(gyro.var(axis=0), np.radians(0.2) ** 2 * 1.16 / 2.0, rtol=1e-3)
    assert (power.max(axis=0) / power.sum(axis=0) > 0.8).all()  # a line, not a band


@pytest.mark.parametrize("level", [0.5, 2.0])
def test_narrowband_vibration_fills_its_band(level):
    """Random 20 +- 2 Hz vibration at 200 Hz averaged to 50 Hz: >= 98 % of the power in 17-23 Hz, spread over
    the band (no bin above 2 %), variance RMS^2 times the boxcar's power gain at 20 Hz (0.592).

    Measured: 99.1 % in band, largest bin 0.4 %, variance / RMS^2 0.588-0.592 (accel), 0.563-0.604 (gyro).
    """
    vibration = VibrationModel.of_kind("narrowband", level=level)
    gyro, accel = vibration_samples(ROW_TIME, vibration, np.random.default_rng(4))
    rms, gyro_rms = vibration.amplitudes()
    freq, psd = welch(accel, fs=ROW_RATE, nperseg=256, axis=0)
    in_band = (freq >= 17.0) & (freq <= 23.0)
    assert (psd[in_band].sum(axis=0) / psd.sum(axis=0) > 0.98).all()
    _, power = periodogram(accel, fs=ROW_RATE, axis=0)
    assert (power.max(axis=0) / power.sum(axis=0) < 0.02).all()
    m, f_internal = 4, 200.0
    boxcar = (np.sin(np.pi * 20.0 * m / f_internal) / (m * np.sin(np.pi * 20.0 / f_internal))) ** 2
    np.testing.assert_allclose(accel.var(axis=0) / rms**2, boxcar, rtol=0.05)
    np.testing.assert_allclose(gyro.var(axis=0) / gyro_rms**2, boxcar, rtol=0.1)
    # point-sampled instead: the full RMS (measured 0.993-1.002)
    _, accel_point = vibration_samples(ROW_TIME, VibrationModel.of_kind("narrowband", level=level, sampling="point"),
                                       np.random.default_rng(4))
    np.testing.assert_allclose(accel_point.var(axis=0) / rms**2, 1.0, rtol=0.05)


def test_no_vibration_leaves_only_the_sensor_noise():
    """``kind="none"`` is the same as no vibration model: identical samples, noise at the datasheet's level."""
    model = imu_preset("mems-ivru")
    zeros = np.zeros((len(ROW_TIME), 3))
    none = corrupt_imu(zeros, zeros, ROW_TIME, model, VibrationModel.of_kind("none"), np.random.default_rng(1))
    off = corrupt_imu(zeros, zeros, ROW_TIME, model, None, np.random.default_rng(1))
    for a, b in zip(none, off, strict=True):
        np.testing.assert_array_equal(a, b)
    gyro, accel, gyro_bias, accel_bias = none
    np.testing.assert_allclose((gyro - gyro_bias).std(axis=0), np.sqrt(model.gyro_white_psd * ROW_RATE), rtol=0.05)
    np.testing.assert_allclose((accel - accel_bias).std(axis=0), np.sqrt(model.accel_white_psd * ROW_RATE),
                               rtol=0.05)
    # and through corrupt_imu a vibration kind adds exactly vibration_samples on a perfect IMU
    vibration = VibrationModel.of_kind("white")
    gyro, accel, _, _ = corrupt_imu(zeros, zeros, ROW_TIME, PERFECT_IMU, vibration, np.random.default_rng(2))
    rng = np.random.default_rng(2)
    rng.standard_normal(3 + 3 + 3 * len(ROW_TIME) * 2)  # the perfect IMU's (zero-scaled) draws
    expected_gyro, expected_accel = vibration_samples(ROW_TIME, vibration, rng)
    np.testing.assert_allclose(gyro, expected_gyro, atol=1e-15)
    np.testing.assert_allclose(accel, expected_accel, atol=1e-15)


# --- 5. forced biases, consumer IMU -----------------------------------------------------------------------------

GYRO_BIAS = (0.01, -0.02, 0.07)   # rad/s: a phone's 0.07 rad/s z bias
ACCEL_BIAS = (0.3, -0.2, 0.5)     # m/s^2


@pytest.mark.parametrize("vehicle", ["car", "multicopter"])
def test_forced_biases_show_in_the_still_segment(vehicle):
    """A consumer-phone IMU with forced biases: the mean error over the start standstill / hover is the bias.

    Measured (8 s standstill / 15 s hover at 50 Hz, with the vehicle's vibration): gyro within 2.7e-4 rad/s,
    accelerometer within 0.011 m/s^2 (car: its white vibration is 0.2 m/s^2 per row on z, so the mean of 400
    rows scatters by 0.01) and 0.004 m/s^2 (multicopter) of the forced values. Bounds: about 4 sigma.
    """
    cfg = SimConfig.for_vehicle(vehicle, duration_s=30.0, seed=5, imu_preset="consumer-phone",
                                gyro_bias_rad_s=GYRO_BIAS, accel_bias_mps2=ACCEL_BIAS)
    flight = simulate(cfg)
    nav = flight.truth_nav
    still_s = cfg.plan.start_standstill_s if vehicle == "car" else cfg.plan.hover_s
    still = nav.time - nav.time[0] < still_s
    gyro = np.radians(flight.pos[["OMGS_X", "OMGS_Y", "OMGS_Z"]].to_numpy())
    accel = flight.pos[["ACCS_X", "ACCS_Y", "ACCS_Z"]].to_numpy()
    np.testing.assert_allclose((gyro - nav.omega_ib_b)[still].mean(axis=0), GYRO_BIAS, atol=1e-3)
    np.testing.assert_allclose((accel - nav.f_ib_b)[still].mean(axis=0), ACCEL_BIAS, atol=0.04)
    # the flight's own record of the bias starts at the forced value (plus the Gauss-Markov part, 1e-4 rad/s)
    np.testing.assert_allclose(flight.gyro_bias[0], GYRO_BIAS, atol=5e-4)
    np.testing.assert_allclose(flight.accel_bias[0], ACCEL_BIAS, atol=0.01)


def test_forcing_biases_changes_nothing_else():
    """The forced bias replaces the turn-on draw but keeps the draws: the rest of the flight is the same."""
    plain = simulate(SimConfig(seed=4, plan=FlightPlan(duration_s=30.0)))
    forced = simulate(SimConfig(seed=4, plan=FlightPlan(duration_s=30.0), gyro_bias_rad_s=GYRO_BIAS,
                                accel_bias_mps2=ACCEL_BIAS))
    shift = forced.gyro_bias[0] - plain.gyro_bias[0]
    np.testing.assert_allclose(forced.gyro_bias - plain.gyro_bias, np.tile(shift, (len(plain.gyro_bias), 1)),
                               atol=1e-15)
    np.testing.assert_allclose(np.radians(forced.pos["OMGS_Z"] - plain.pos["OMGS_Z"]), shift[2], atol=1e-12)
    pd.testing.assert_frame_equal(forced.gnss_fixes, plain.gnss_fixes)
    assert imu_preset("consumer-phone").gyro_turn_on_sigma == pytest.approx(np.radians(1.0), rel=1e-9)


# --- 6. files without a POS unit, GNSS rates, extra outputs ------------------------------------------------------

@pytest.mark.parametrize("vehicle", ["multicopter", "car"])
def test_pos_without_unit_columns_is_read(tmp_path, vehicle):
    """No POS unit: POS.txt lacks ROLL/PITCH/YAW/IACC, and read_pos still reads the raw IMU and the fixes."""
    flight = simulate(SimConfig.for_vehicle(vehicle, duration_s=40.0, seed=2))
    assert not set(UNIT_COLUMNS) & set(flight.pos.columns)
    assert "unit_yaw_offset" not in flight.truth_frames.columns
    paths = write_flight(flight, tmp_path)
    log = read_pos(paths["POS.txt"], required_roles=("gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z"))
    assert "roll" not in log.data and "iacc_x" not in log.data
    assert len(log.gnss) == len(flight.gnss_fixes)
    np.testing.assert_allclose(log.time, flight.truth_nav.time, atol=1e-9)
    np.testing.assert_allclose(log.vector("gyro"), flight.pos[["OMGS_X", "OMGS_Y", "OMGS_Z"]], atol=1e-5)


@pytest.mark.parametrize("rate_hz", [5.0, 10.0])
def test_gnss_rate(rate_hz):
    """Fixes every 1/rate s, each held in POS.txt from a later row, in order (latency below one period)."""
    flight = simulate(SimConfig.for_vehicle("car", duration_s=30.0, seed=3, gnss=GnssModel(rate_hz=rate_hz)))
    times = flight.gnss_fixes["time"].to_numpy()
    np.testing.assert_allclose(np.diff(times), 1.0 / rate_hz, atol=1e-9)
    lat = flight.pos["LATITUDE"].to_numpy()
    changes = np.flatnonzero(np.diff(lat) != 0) + 1
    held = lat[changes]
    np.testing.assert_array_equal(held, flight.gnss_fixes["lat"].to_numpy()[:len(held)])
    assert len(held) >= len(times) - 2


def test_magnetometer_and_autopilot_columns(tmp_path):
    """imu.csv gets mag_x..z [uT] and roll/pitch/yaw [deg] on request, read by read_marg_csv; off by default.

    The field back in NED matches 48 uT at 60 deg dip, 4 deg declination (measured residual std 0.3 uT, the
    noise); the autopilot's yaw is off by a constant of a few degrees (this seed: measured mean 2.0 deg, std
    0.4 deg) and its roll/pitch by at most 1.0 deg.
    """
    cfg = SimConfig.for_vehicle("multicopter", duration_s=60.0, seed=7, magnetometer=MagnetometerModel(),
                                autopilot=AutopilotModel())
    flight = simulate(cfg)
    paths = write_generic(flight, tmp_path)
    time, _, _, mag, _ = read_marg_csv(paths["imu.csv"])
    assert mag is not None and len(mag) == len(time)
    nav = flight.truth_nav
    field_n = np.einsum("nij,nj->ni", nav.C_b_n, mag - np.asarray(cfg.magnetometer.hard_iron_ut))
    np.testing.assert_allclose(field_n.mean(axis=0), cfg.magnetometer.field_n(), atol=0.05)
    np.testing.assert_allclose((field_n - cfg.magnetometer.field_n()).std(axis=0), 0.3, rtol=0.1)
    assert np.linalg.norm(cfg.magnetometer.field_n()) == pytest.approx(48.0)
    table = pd.read_csv(paths["imu.csv"])
    yaw_error = (table["yaw"] - np.degrees(nav.yaw) + 180.0) % 360.0 - 180.0
    assert 0.5 < abs(yaw_error.mean()) < 10.0 and yaw_error.std() < 2.0
    for name, truth in (("roll", nav.roll), ("pitch", nav.pitch)):
        assert np.abs(table[name] - np.degrees(truth)).max() < 2.0
    assert table["yaw"].between(0.0, 360.0).all()
    # the extras draw from their own streams: the POS table is the same without them
    plain = simulate(SimConfig.for_vehicle("multicopter", duration_s=60.0, seed=7))
    pd.testing.assert_frame_equal(plain.pos, flight.pos)
    assert list(pd.read_csv(write_generic(plain, tmp_path / "plain")["imu.csv"]).columns) == [
        "time", "gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z"]


def test_cli_simulates_other_vehicles(tmp_path):
    """georef simulate --vehicle car with the new options writes POS.txt without unit columns and imu.csv."""
    result = CliRunner().invoke(app, [
        "simulate", str(tmp_path), "--vehicle", "car", "--duration", "40", "--imu", "consumer-phone",
        "--gyro-bias", "0,0,4", "--accel-bias", "0.3,-0.2,0.5", "--vibration", "narrowband",
        "--vibration-level", "2", "--gnss-rate", "5", "--magnetometer", "--autopilot", "--speed", "14", "--quiet"])
    assert result.exit_code == 0, result.output
    header = (tmp_path / "POS.txt").read_text().splitlines()[0].split("\t")
    assert "OMGS_Z" in header and "ROLL" not in header and "IACC_X" not in header
    imu = pd.read_csv(tmp_path / "imu.csv")
    assert {"mag_x", "mag_y", "mag_z", "roll", "pitch", "yaw"} <= set(imu.columns)
    truth = pd.read_csv(tmp_path / "truth_traj.csv")
    assert np.hypot(truth["vn"], truth["ve"]).max() == pytest.approx(14.0, abs=1e-6)
    still = (imu["time"] - imu["time"].iloc[0]) < 8.0
    assert imu.loc[still, "gyro_z"].mean() == pytest.approx(np.radians(4.0), abs=2e-3)
    gnss = pd.read_csv(tmp_path / "gnss.csv")
    np.testing.assert_allclose(np.diff(gnss["time"]), 0.2, atol=1e-9)
    bad = CliRunner().invoke(app, ["simulate", str(tmp_path / "x"), "--vehicle", "car", "--hover", "3"])
    assert bad.exit_code == 2 and "multicopter only" in bad.output
