"""The drone's whole log (georef/sim/drone*.py, rotor.py, thermal.py, receiver.py, trigger.py).

Each feature is checked against an independent reference: the ideal IMU against georef's own strapdown, the
ground phase against exact stillness and the datasheet noise, the rotor lines against their aliases and the
Butterworth magnitude, the GNSS errors against the Gauss-Markov autocorrelation, the time tags against the truth
at the measurement and exposure times, the thermal bias against a regression of the logged IMU on the logged
temperature. The figures measured are quoted beside each bound.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest
from georef_cli.main import app
from scipy.signal import butter, periodogram, sosfreqz
from typer.testing import CliRunner

from georef.frames import C_e_n, dcm_to_euler, dcm_to_quat, geodetic_to_ecef, quat_to_dcm, wrap_pi
from georef.frames.mounting import lever_arm_ecef
from georef.fusion.strapdown import run_free_inertial
from georef.imu_errors import imu_preset
from georef.io.generic import read_gnss_csv, read_marg_csv
from georef.sim.car import CarPlan
from georef.sim.drone import DronePlan, drone_schedule, fly_drone
from georef.sim.drone_config import drone_settings
from georef.sim.files import write_flight, write_generic
from georef.sim.flight import SimConfig, simulate
from georef.sim.multicopter import MulticopterPlan
from georef.sim.receiver import ReceiverGnssModel, receiver_fixes
from georef.sim.rotor import RotorVibrationModel, rotor_vibration
from georef.sim.sensors import AutopilotModel, GnssModel, MagnetometerModel
from georef.sim.thermal import ThermalBiasModel
from georef.sim.trajectory import Trajectory

FINE = 400.0
#: a short ground-start flight with a landing: 10 s on the ground, lift-off at 15.3 s, three 80 m legs at 10 m/s
SURVEY = MulticopterPlan(duration_s=150.0, hover_height_m=30.0, hover_s=4.0,
                         leg_heights_m=(30.0, 35.0, 35.0, 40.0, 30.0), leg_length_m=80.0, speed_mps=10.0,
                         second_hover_after_leg=-1)
PLAN = DronePlan(survey=SURVEY, ground_s=10.0, land=True, after_landing_s=5.0)


@pytest.fixture(scope="module")
def flight():
    cfg = SimConfig.for_vehicle("drone", seed=5, randomize=False, with_magnetometer=True, with_autopilot=True,
                                plan=PLAN)
    return simulate(cfg)


def _log_time(flight) -> np.ndarray:
    return flight.truth_nav.time - flight.config.start_utc_s


# --- kinematics ---------------------------------------------------------------------------------------------------

def _strapdown_errors(truth: Trajectory, rate_hz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Time [s], position [m], velocity [m/s] and attitude [deg] error of georef's strapdown on the ideal IMU."""
    idx = np.arange(0, len(truth.time), int(FINE / rate_hz))
    x0 = np.zeros(16)
    x0[:3] = truth.lat[0], truth.lon[0], truth.height[0]
    x0[3:6] = truth.v_n[0]
    x0[6:10] = dcm_to_quat(truth.C_b_n[0])
    out = run_free_inertial(x0, truth.time[idx], truth.omega_ib_b[idx], truth.f_ib_b[idx])
    r_ins = geodetic_to_ecef(out[:, 0], out[:, 1], out[:, 2])
    r_true = geodetic_to_ecef(truth.lat[idx], truth.lon[idx], truth.height[idx])
    position = np.abs(np.einsum("nij,nj->ni", C_e_n(truth.lat[idx], truth.lon[idx]), r_ins - r_true)).max(axis=1)
    velocity = np.abs(out[:, 3:6] - truth.v_n[idx]).max(axis=1)
    angles = dcm_to_euler(quat_to_dcm(out[:, 6:10]))
    attitude = np.max([np.degrees(np.abs(wrap_pi(est - ref[idx])))
                       for est, ref in zip(angles, (truth.roll, truth.pitch, truth.yaw), strict=True)], axis=0)
    return truth.time[idx], position, velocity, attitude


@pytest.mark.parametrize("start", ["ground", "hover"])
def test_strapdown_follows_the_drone(start):
    """georef's strapdown at 200 Hz on the ideal IMU stays on the truth through lift-off, legs and landing.

    Measured (ground start): 8 mm, 8.8e-5 m/s after the lift-off jolt, 3.3e-3 m/s during its 50 ms (a 200 Hz
    strapdown sampling a 25 m/s^2 pulse), attitude 4.0e-3 deg; hover start 1.4 mm, 1.7e-5 m/s, 2.4e-3 deg.
    Leaving the jolt's acceleration out of ``a_n`` (checked by mutation) gives 0.67 m/s and 0.22 m.
    """
    truth = fly_drone(dataclasses.replace(PLAN, start=start), FINE)
    sched = truth.schedule
    t, position, velocity, attitude = _strapdown_errors(truth.trajectory, 200.0)
    assert t[-1] == pytest.approx(150.0)
    jolt = np.zeros(len(t), bool) if sched.liftoff_s is None else (t >= sched.liftoff_s) & (t < sched.liftoff_s + 0.1)
    assert position.max() < 0.02
    assert velocity[~jolt].max() < 2e-4
    assert velocity.max() < 6e-3
    assert attitude.max() < 8e-3


def test_ground_phase_is_still(flight):
    """Before lift-off and after touchdown the drone stands still: velocity and acceleration exactly zero, attitude
    exactly constant, the ideal IMU gravity and Earth rate only (measured ptp of f_ib_b exactly 0)."""
    sched = drone_schedule(PLAN)
    t, nav = _log_time(flight), flight.truth_nav
    assert sched.liftoff_s == pytest.approx(15.3) and sched.touchdown_s is not None
    for still in (t < sched.liftoff_s, t > sched.touchdown_s + 0.31):
        assert still.sum() > 1000
        assert np.all(nav.v_n[still] == 0.0) and np.all(nav.a_n[still] == 0.0)
        for angle in (nav.roll, nav.pitch, nav.yaw):
            assert np.ptp(angle[still]) == 0.0
        assert np.ptp(nav.f_ib_b[still], axis=0).max() < 1e-9
        assert np.linalg.norm(nav.omega_ib_b[still][0]) == pytest.approx(7.292115e-5, rel=1e-9)
    # it stands on its take-off tilt, then on its landing spot's (both in the plan) at the take-off height
    first, last = t < sched.liftoff_s, t > sched.touchdown_s + 0.31
    np.testing.assert_allclose(np.degrees([nav.roll[first][0], nav.pitch[first][0]]), PLAN.takeoff_tilt_deg)
    np.testing.assert_allclose(np.degrees([nav.roll[last][0], nav.pitch[last][0]]), PLAN.landing_tilt_deg)
    assert abs(nav.height[-1] - SURVEY.start_height_m) < 1e-3  # measured 3e-14 m


def test_motors_off_means_no_vibration(flight):
    """With the motors off the IMU error is the datasheet's white noise only; with them on, rotor vibration.

    Measured residual (IMU - ideal - true bias) std, motors off: 0.047 m/s^2 and 0.14 deg/s per axis (datasheet
    0.0471 and 0.141); at idle (43 Hz) 0.27-0.47 m/s^2; in the hover (110 Hz) 0.49-0.83 m/s^2, 0.21-0.37 deg/s.
    """
    sched = drone_schedule(PLAN)
    t = _log_time(flight)
    nav = flight.truth_nav
    gyro = np.radians(flight.pos[["OMGS_X", "OMGS_Y", "OMGS_Z"]].to_numpy()) - nav.omega_ib_b - flight.gyro_bias
    accel = flight.pos[["ACCS_X", "ACCS_Y", "ACCS_Z"]].to_numpy() - nav.f_ib_b - flight.accel_bias
    model = imu_preset("mems-consumer")
    motors_off = sched.motors_off(t)
    for off in (motors_off & (t < sched.liftoff_s), motors_off & (t > sched.touchdown_s)):
        assert off.sum() > 1000 and np.all(flight.motor_thrust_ratio[off] == 0.0)
        np.testing.assert_allclose(accel[off].std(axis=0), np.sqrt(model.accel_white_psd * 200.0), rtol=0.1)
        np.testing.assert_allclose(gyro[off].std(axis=0), np.sqrt(model.gyro_white_psd * 200.0), rtol=0.1)
    hover = (t > sched.hover_start_s) & (t < sched.hover_start_s + 4.0)
    assert (accel[hover].std(axis=0) > 0.3).all() and (np.degrees(gyro[hover].std(axis=0)) > 0.15).all()
    # the vibration itself is exactly zero before the spin-up, and starts with it
    vibration = rotor_vibration(nav.time, nav.time, flight.motor_thrust_ratio, RotorVibrationModel(),
                                np.random.default_rng(0))
    assert np.all(vibration.accel[t < sched.motors_on_s] == 0.0) and np.all(vibration.gyro[t < sched.motors_on_s] == 0)
    assert np.abs(vibration.accel[(t > sched.motors_on_s) & (t < sched.motors_on_s + 0.5)]).max() > 0.0


def test_liftoff_jolt_and_climb(flight):
    """At lift-off the specific force along body -z peaks at the plan's 35 m/s^2 (3.6 g) for a few tens of ms;
    the climb ends at the hover height. Measured: 35.003 m/s^2 on the 400 Hz truth, 34.5 m/s^2 at the 200 Hz
    rows, above 2 g for 30 ms, 2.1 deg off body z (the tilt going from the ground's to the thrust attitude);
    hover height within 0.09 m (the wander)."""
    truth = fly_drone(PLAN, FINE)
    sched, traj = truth.schedule, truth.trajectory
    magnitude = np.linalg.norm(traj.f_ib_b, axis=1)
    peak = int(np.argmax(magnitude))
    assert magnitude[peak] == pytest.approx(PLAN.liftoff_peak_mps2, rel=0.01)
    assert sched.liftoff_s < traj.time[peak] < sched.liftoff_s + PLAN.liftoff_pulse_s
    above_2g = traj.time[magnitude > 2 * 9.81]
    assert 0.01 < np.ptp(above_2g) < 0.06
    assert np.degrees(np.arccos(-traj.f_ib_b[peak, 2] / magnitude[peak])) < 3.0
    at_hover = np.searchsorted(traj.time, sched.hover_start_s)
    assert abs(traj.height[at_hover] - SURVEY.start_height_m - SURVEY.hover_height_m) < 0.3
    # the rotors do not see the jolt: thrust stays at hover thrust (measured 1.000-1.003; 0.85-1.14 in the climb)
    jolt = (traj.time > sched.liftoff_s) & (traj.time < sched.liftoff_s + 0.1)
    assert 0.95 < truth.thrust_ratio[jolt].min() and truth.thrust_ratio[jolt].max() < 1.2
    # and the flight seen by the IMU rows has the same jolt
    assert np.linalg.norm(flight.truth_nav.f_ib_b, axis=1).max() > 3.0 * 9.81


# --- rotor vibration ----------------------------------------------------------------------------------------------

def _butterworth_gain(freq: float, model: RotorVibrationModel) -> float:
    """|H| of the digital Butterworth low-pass at the internal rate (bilinear transform, as an autopilot's)."""
    sos = butter(model.lowpass_order, model.lowpass_hz, fs=model.internal_rate_hz, output="sos")
    return float(np.abs(sosfreqz(sos, worN=[freq], fs=model.internal_rate_hz)[1][0]))


def _analogue_gain(freq: float, model: RotorVibrationModel) -> float:
    return 1.0 / np.sqrt(1.0 + (freq / model.lowpass_hz) ** (2 * model.lowpass_order))


@pytest.mark.parametrize("thrust, aliases", [(1.0, [90.0, 20.0, 70.0]), (1.44, [68.0, 64.0, 4.0])])
def test_rotor_lines_follow_thrust_and_alias(thrust, aliases):
    """One motor at 110 Hz x sqrt(thrust) and harmonics, low-passed at 50 Hz, logged at 200 Hz: lines at the
    aliases |h f - k 200| with amplitudes thrust x w_h |H(h f)|.

    Measured: the three largest bins at the aliases; amplitudes equal to the digital filter's gain to 1e-6
    (each line on a periodogram bin), 0.4-6 % below the analogue Butterworth magnitude (bilinear warping).
    """
    model = RotorVibrationModel(n_motors=1, motor_spread=0.0, harmonic_weights=(1.0, 0.5, 0.25),
                                accel_rms_mps2=1.0, gyro_rms_deg_s=1.0, internal_rate_hz=4000.0)
    rows = np.arange(4000) / 200.0
    vibration = rotor_vibration(rows, np.array([0.0, 100.0]), np.full(2, thrust), model, np.random.default_rng(3))
    freq, power = periodogram(vibration.accel, fs=200.0, axis=0, window="boxcar")
    top = np.sort(freq[np.argsort(power[:, 2])[-3:]])
    np.testing.assert_allclose(top, np.sort(aliases))
    fundamental = 110.0 * np.sqrt(thrust)
    np.testing.assert_allclose(vibration.rotor_hz, fundamental)
    scale = thrust * 1.0 / np.sqrt(np.sum(np.square(model.harmonic_weights)) / 2.0)  # RMS 1 at hover thrust
    for h, (weight, alias) in enumerate(zip(model.harmonic_weights, aliases, strict=True), start=1):
        k = int(np.argmin(np.abs(freq - alias)))
        amplitude = np.sqrt(2.0 * power[k, 2] * (freq[1] - freq[0]))
        expected = scale * weight * _butterworth_gain(h * fundamental, model)
        assert amplitude == pytest.approx(expected, rel=1e-4)
        assert amplitude < scale * weight * _analogue_gain(h * fundamental, model)


def test_rotor_vibration_rms_of_four_motors():
    """Four motors spread +-3 % at hover: logged variance = sum over motors and harmonics of (A w_h |H|)^2 / 2.

    Measured ratio 1.000 per axis over 60 s (the motors' lines 2.2 Hz apart, each on a bin of the record).
    """
    model = RotorVibrationModel(internal_rate_hz=4000.0)
    rows = np.arange(12000) / 200.0
    vibration = rotor_vibration(rows, np.array([0.0, 100.0]), np.ones(2), model, np.random.default_rng(8))
    weights = np.asarray(model.harmonic_weights)
    scale = model.rms() / np.sqrt(model.n_motors * np.sum(weights**2) / 2.0)
    gain2 = sum(_butterworth_gain(h * 110.0 * factor, model) ** 2 * weights[h - 1] ** 2
                for factor in model.motor_factors() for h in range(1, len(weights) + 1))
    expected = scale**2 * gain2 / 2.0
    logged = np.concatenate([vibration.accel, vibration.gyro], axis=1).var(axis=0)
    np.testing.assert_allclose(logged / expected, 1.0, atol=0.05)


# --- thermal bias -------------------------------------------------------------------------------------------------

def test_thermal_bias_follows_the_temperature(flight):
    """Regressing the logged IMU error (1-s means of IMU - ideal) on the logged board temperature gives the
    model's coefficients; the temperature is the model's warm-up curve.

    The consumer preset's own bias instability (15 deg/h Gauss-Markov, 100 s) moves such a fit by up to 10 %
    over a 150 s flight (measured 0.0135 deg/s per degC for 0.015), so the fit runs on the same flight with a
    tactical IMU (0.3 deg/h) and the same thermal model. Measured (8.5 degC of warm-up, three seeds): slopes
    within 0.4 % of (0.02, -0.03, 0.015) deg/s and (2, -1.5, 3) mg per degC, intercepts at the turn-on biases
    within 5e-6 rad/s and 6e-4 m/s^2; rotor vibration on.
    """
    flight = simulate(dataclasses.replace(flight.config, imu_preset="tactical-fog"))
    cfg = flight.config
    nav = flight.truth_nav
    t = nav.time - cfg.start_utc_s
    logged_temperature = flight.pos["IMU_TEMP"].to_numpy()
    np.testing.assert_allclose(logged_temperature, 20.0 + 15.0 * (1.0 - np.exp(-t / 180.0)), atol=1e-9)
    gyro_error = np.radians(flight.pos[["OMGS_X", "OMGS_Y", "OMGS_Z"]].to_numpy()) - nav.omega_ib_b
    accel_error = flight.pos[["ACCS_X", "ACCS_Y", "ACCS_Z"]].to_numpy() - nav.f_ib_b
    windows = len(t) // 200

    def means(x: np.ndarray) -> np.ndarray:
        return x[:windows * 200].reshape(windows, 200, -1).mean(axis=1)

    design = np.column_stack([means(logged_temperature[:, None])[:, 0] - 20.0, np.ones(windows)])
    gyro_fit = np.linalg.lstsq(design, means(gyro_error), rcond=None)[0]
    accel_fit = np.linalg.lstsq(design, means(accel_error), rcond=None)[0]
    np.testing.assert_allclose(np.degrees(gyro_fit[0]), cfg.thermal.gyro_deg_s_per_degc, rtol=0.01)
    np.testing.assert_allclose(accel_fit[0] / 9.80665e-3, cfg.thermal.accel_mg_per_degc, rtol=0.01)
    turn_on_gyro = flight.gyro_bias[0] - cfg.thermal.gyro_bias(t[:1])[0]
    np.testing.assert_allclose(gyro_fit[1], turn_on_gyro, atol=2e-5)
    turn_on_accel = flight.accel_bias[0] - cfg.thermal.accel_bias(t[:1])[0]
    np.testing.assert_allclose(accel_fit[1], turn_on_accel, atol=2e-3)


def test_thermal_bias_on_any_vehicle():
    """``SimConfig.thermal`` warms any IMU: the car's recorded bias gains the model's part, POS.txt's IMU_TEMP
    follows the model, and nothing else changes (the thermal part draws no random numbers)."""
    thermal = ThermalBiasModel(powered_before_s=30.0)
    plain = simulate(SimConfig.for_vehicle("car", duration_s=30.0, seed=2))
    warm = simulate(SimConfig.for_vehicle("car", duration_s=30.0, seed=2, thermal=thermal))
    t = warm.truth_nav.time - warm.config.start_utc_s
    np.testing.assert_allclose(warm.gyro_bias - plain.gyro_bias, thermal.gyro_bias(t), atol=1e-15)
    np.testing.assert_allclose(warm.accel_bias - plain.accel_bias, thermal.accel_bias(t), atol=1e-13)
    np.testing.assert_allclose(warm.pos["IMU_TEMP"], thermal.temperature(t))
    pd.testing.assert_frame_equal(warm.gnss_fixes, plain.gnss_fixes)


# --- GNSS receiver ------------------------------------------------------------------------------------------------

def _static_nav(duration_s: float, rate_hz: float) -> Trajectory:
    """An antenna standing still at the IMU (no lever arm), level, for the receiver's errors alone."""
    n = int(duration_s * rate_hz)
    zeros = np.zeros(n)
    return Trajectory(time=1000.0 + np.arange(n) / rate_hz, lat=np.full(n, np.radians(44.0)),
                      lon=np.full(n, np.radians(15.6)), height=np.full(n, 300.0), v_n=np.zeros((n, 3)),
                      a_n=np.zeros((n, 3)), roll=zeros, pitch=zeros, yaw=zeros, omega_ib_b=np.zeros((n, 3)),
                      f_ib_b=np.zeros((n, 3)))


def _errors_neu(fixes: pd.DataFrame, nav: Trajectory) -> np.ndarray:
    """Fix minus the truth at its measurement time, north, east, up [m] (static truth)."""
    r_fix = geodetic_to_ecef(np.radians(fixes["lat"]), np.radians(fixes["lon"]), fixes["height"].to_numpy())
    r_true = geodetic_to_ecef(nav.lat[:1], nav.lon[:1], nav.height[:1])
    err = np.einsum("ij,nj->ni", C_e_n(nav.lat[0], nav.lon[0]), r_fix - r_true)
    return err * np.array([1.0, 1.0, -1.0])


def test_gnss_errors_are_gauss_markov():
    """Errors of a 1 Hz receiver over 11 h: autocorrelation at lag tau = exp(-1) x the Gauss-Markov share of the
    variance, sigma as configured, reported sigma 0.7-1.5 x the true one and wandering.

    Measured: autocorrelation 0.349-0.387 for 0.362 expected (tau 20 s), sigma within 2.3 %, reported / true
    0.70-1.50 (median 1.04), lag-1 s correlation of the reported factor 0.99.
    """
    model = ReceiverGnssModel(rate_hz=1.0, sigma_neu_m=(0.8, 0.8, 2.0), correlation_time_s=20.0,
                              white_sigma_neu_m=(0.1, 0.1, 0.25), latency_s=0.1)
    nav = _static_nav(40000.0, 10.0)
    fixes = receiver_fixes(model, nav, (0.0, 0.0, 0.0), np.random.default_rng(11))
    err = _errors_neu(fixes, nav)
    np.testing.assert_allclose(err.std(axis=0), model.total_sigma_neu_m, rtol=0.05)
    lag = 20
    share = np.square(model.sigma_neu_m) / np.square(model.total_sigma_neu_m)
    centred = err - err.mean(axis=0)
    autocorr = (centred[:-lag] * centred[lag:]).mean(axis=0) / centred.var(axis=0)
    np.testing.assert_allclose(autocorr, np.exp(-1.0) * share, atol=0.06)
    assert (np.abs(centred[:-1] * centred[1:]).mean(axis=0) / centred.var(axis=0) > 0.8).all()  # not white
    factor = fixes["sigma_n"].to_numpy() / model.total_sigma_neu_m[0]
    assert 0.69 < factor.min() and factor.max() < 1.51 and np.ptp(factor) > 0.5
    np.testing.assert_allclose(fixes["sigma_u"] / fixes["sigma_n"],
                               model.total_sigma_neu_m[2] / model.total_sigma_neu_m[0], rtol=2e-3)
    assert np.corrcoef(factor[:-1], factor[1:])[0, 1] > 0.95


def test_gnss_logged_at_arrival(flight):
    """gnss.csv's time = measurement time + latency (+- jitter); the fix is the antenna at the measurement time.

    With a near-perfect receiver on the flight's truth: fix - antenna at the measurement time within 0.06 m
    (measured 0.033 m), at the logged time up to speed x latency off (measured 1.27 m at 10 m/s, 0.12 s).
    """
    cfg = flight.config
    nav = flight.truth_nav
    fixes = flight.gnss_fixes
    lag = fixes["time"] - fixes["measured_time"]
    assert np.abs(lag - cfg.gnss.latency_s).max() <= cfg.gnss.latency_jitter_s + 1e-9
    assert lag.std() > 0.3 * cfg.gnss.latency_jitter_s  # jitter, not a constant
    np.testing.assert_allclose(np.diff(fixes["measured_time"]), 1.0 / cfg.gnss.rate_hz, atol=1e-9)
    exact = ReceiverGnssModel(sigma_neu_m=(0.01, 0.01, 0.01), white_sigma_neu_m=(0.001, 0.001, 0.001),
                              latency_s=0.12)
    clean = receiver_fixes(exact, nav, cfg.lever_arm_gnss_m, np.random.default_rng(2))
    r_fix = geodetic_to_ecef(np.radians(clean["lat"]), np.radians(clean["lon"]), clean["height"].to_numpy())

    def antenna(times: np.ndarray) -> np.ndarray:
        k = np.clip(np.round((times - nav.time[0]) * 200.0).astype(int), 0, len(nav.time) - 1)
        return geodetic_to_ecef(nav.lat[k], nav.lon[k], nav.height[k]) + \
            lever_arm_ecef(nav.lat[k], nav.lon[k], nav.C_b_n[k], cfg.lever_arm_gnss_m)

    at_measurement = np.linalg.norm(r_fix - antenna(clean["measured_time"].to_numpy()), axis=1)
    at_log = np.linalg.norm(r_fix - antenna(clean["time"].to_numpy()), axis=1)
    assert at_measurement.max() < 0.06
    assert at_log.max() > 0.9 * 10.0 * 0.12


def test_gnss_1hz_with_gaps():
    """1 Hz logging with 3 % missing: about 3 % gone, single gaps and runs of 2-5, never longer.

    Measured over 3 h: 3.0 % missing, 196 gaps of which 52 runs, the longest 5.
    """
    model = ReceiverGnssModel.logged_1hz_with_gaps(0.03)
    nav = _static_nav(10800.0, 10.0)
    fixes = receiver_fixes(model, nav, (0.0, 0.0, 0.0), np.random.default_rng(4))
    steps = np.round(np.diff(fixes["measured_time"].to_numpy())).astype(int)
    expected = int(np.floor((nav.time[-1] - nav.time[0] - model.first_fix_s - model.latency_s
                             - model.latency_jitter_s) / 1.0)) + 1
    missing = 1.0 - len(fixes) / expected
    assert 0.02 < missing < 0.04
    gaps = steps[steps > 1] - 1
    assert (gaps == 1).sum() > 50 and (gaps >= 2).sum() > 20 and gaps.max() <= 5
    assert np.all(np.diff(fixes["time"]) > 0)


# --- camera -------------------------------------------------------------------------------------------------------

def test_events_and_exposure_truth(flight, tmp_path):
    """events.csv holds the logged trigger times; truth.csv the camera at the real exposure, latency later.

    Measured: 18 events, 14.95-15.04 m of flight apart within a leg (the first row past each 15 m), all inside
    the legs; truth time - event time = 0.15 s +- 2 ms; the camera moves 1.47-1.53 m between an event and its
    exposure.
    """
    cfg = flight.config
    paths = write_generic(flight, tmp_path)
    assert {"events.csv", "truth.csv"} <= set(paths)
    events, truth = pd.read_csv(paths["events.csv"]), pd.read_csv(paths["truth.csv"])
    assert list(events.columns) == ["time", "image"] and len(events) == len(truth) >= 15
    assert list(truth.columns) == ["frame", "time", "lat", "lon", "height", "roll", "pitch", "yaw", "body_roll",
                                   "body_pitch", "body_yaw", "track"]
    np.testing.assert_array_equal(truth["frame"], np.arange(1, len(truth) + 1))
    assert events["image"].iloc[0] == "IMG_0001.JPG" and events["image"].iloc[-1] == f"IMG_{len(events):04d}.JPG"
    delay = truth["time"] - events["time"]
    assert np.abs(delay - cfg.camera_trigger.latency_s).max() <= cfg.camera_trigger.latency_jitter_s + 1e-9
    legs = [(cfg.start_utc_s + a, cfg.start_utc_s + b) for a, b, _, _ in drone_schedule(PLAN).survey.legs]
    assert all(any(a <= e <= b for a, b in legs) for e in events["time"])
    nav = flight.truth_nav
    flown = np.concatenate([[0.0], np.cumsum(np.hypot(*(0.5 * (nav.v_n[1:, :2] + nav.v_n[:-1, :2])).T) * 0.005)])
    at_event = np.interp(events["time"], nav.time, flown)
    spacing = np.diff(at_event)
    within = spacing[spacing < 2.0 * cfg.camera_trigger.distance_m]  # consecutive events of one leg
    assert len(within) >= len(events) - 3
    # each event is the first row past a multiple of 15 m from the leg start: within a row's travel (11 m/s)
    assert np.abs(within - cfg.camera_trigger.distance_m).max() <= 11.0 * 0.005
    # the exposure is 1.5 m further along than the logged time: compare with the camera truth at the event time
    at_event = simulate_frame_truth(flight, events["time"].to_numpy())
    shift = np.linalg.norm(geodetic_to_ecef(np.radians(truth["lat"]), np.radians(truth["lon"]), truth["height"])
                           - at_event, axis=1)
    np.testing.assert_allclose(shift, SURVEY.speed_mps * cfg.camera_trigger.latency_s, rtol=0.05)
    # the generic readers take the files
    time, _, _, mag, _ = read_marg_csv(paths["imu.csv"])
    assert mag is not None and len(time) == len(flight.pos)
    gnss = read_gnss_csv(paths["gnss.csv"])
    np.testing.assert_allclose(gnss.sigma_neu[:, 0], flight.gnss_fixes["sigma_n"])
    with pytest.raises(ValueError, match="no POS.txt"):
        write_flight(flight, tmp_path / "pos")


def simulate_frame_truth(flight, times: np.ndarray) -> np.ndarray:
    """The camera's true ECEF position at ``times`` [s] from the IMU-row truth (linear between 200 Hz rows)."""
    nav = flight.truth_nav
    r = geodetic_to_ecef(nav.lat, nav.lon, nav.height)
    k = np.searchsorted(nav.time, times)
    w = ((times - nav.time[k - 1]) / (nav.time[k] - nav.time[k - 1]))[:, None]
    r_imu = (1.0 - w) * r[k - 1] + w * r[k]
    return r_imu + lever_arm_ecef(nav.lat[k], nav.lon[k], nav.C_b_n[k], flight.config.lever_arm_camera_m)


# --- magnetometer, autopilot --------------------------------------------------------------------------------------

def test_magnetometer_sees_the_motors_and_autopilot_its_trim(flight):
    """The motor currents' field appears with the spin-up; the autopilot reports the attitude of its own frame,
    turned by the mounting offset. Measured: field residual 0.29-0.30 uT RMS, mean below 0.01 uT with the
    motors off; in the hover the mean residual is the model's (1.5, -1.0, 4.0) uT x load^1.5 within 0.015 uT;
    the autopilot's roll and pitch within 1.02 deg of the offset-turned truth (its Gauss-Markov error, 0.3 deg),
    its roll 0.51 deg off the IMU body's on average (offset 0.8 deg)."""
    cfg = flight.config
    nav = flight.truth_nav
    t = _log_time(flight)
    residual = flight.mag - np.einsum("nji,j->ni", nav.C_b_n, cfg.magnetometer.field_n()) - \
        np.asarray(cfg.magnetometer.hard_iron_ut)
    sched = drone_schedule(PLAN)
    off = t < sched.motors_on_s
    np.testing.assert_allclose(residual[off].mean(axis=0), 0.0, atol=0.05)
    hover = (t > sched.hover_start_s) & (t < sched.hover_start_s + 4.0)
    load = flight.motor_thrust_ratio[hover] ** 1.5
    np.testing.assert_allclose(residual[hover].mean(axis=0),
                               np.asarray(cfg.magnetometer.motor_interference_ut) * load.mean(), atol=0.1)
    from georef.frames import euler_to_dcm

    turned = dcm_to_euler(nav.C_b_n @ euler_to_dcm(*np.radians(cfg.autopilot.mounting_offset_deg)))
    level_error = np.degrees(flight.autopilot_rpy[:, :2] - np.column_stack(turned[:2]))
    assert np.abs(level_error).max() < 1.5
    plain_error = np.degrees(flight.autopilot_rpy[:, 0] - nav.roll)
    assert 0.3 < plain_error.mean() < 1.3


# --- configurations -----------------------------------------------------------------------------------------------

def test_monte_carlo_configurations_differ_by_seed():
    """Fifty seeds draw fifty different flights within the documented ranges; the same seed, the same flight;
    the options start/with_magnetometer change nothing else."""
    settings = [drone_settings(seed) for seed in range(50)]
    plans = [s["plan"] for s in settings]
    for name, low, high in (("ground_s", 8.0, 40.0), ("spinup_s", 1.5, 3.5), ("liftoff_pulse_s", 0.03, 0.08)):
        values = np.array([getattr(p, name) for p in plans])
        assert len(set(values)) == 50 and low <= values.min() and values.max() <= high
    peaks = np.array([p.liftoff_peak_mps2 for p in plans]) / 9.80665
    assert 2.0 <= peaks.min() and peaks.max() <= 4.5
    for name, low, high in (("hover_s", 3.0, 20.0), ("heading_deg", 0.0, 360.0), ("speed_mps", 4.0, 12.0)):
        values = np.array([getattr(p.survey, name) for p in plans])
        assert len(set(values)) == 50 and low <= values.min() and values.max() <= high
    assert {p.survey.heading_policy for p in plans} == {"fixed", "track", "rotating"}
    assert 10 < sum(p.land for p in plans) < 40
    for key, attribute, low, high in (("gnss", "latency_s", 0.05, 0.2), ("gnss", "correlation_time_s", 20.0, 120.0),
                                      ("vibration", "hover_rotor_hz", 80.0, 150.0),
                                      ("camera_trigger", "latency_s", 0.1, 0.2),
                                      ("thermal", "warmup_degc", 8.0, 20.0)):
        values = np.array([getattr(s[key], attribute) for s in settings])
        assert len(set(values)) == 50 and low <= values.min() and values.max() <= high, (key, attribute)
    gyro_coefficients = np.abs([s["thermal"].gyro_deg_s_per_degc for s in settings])
    assert 0.01 <= gyro_coefficients.min() and gyro_coefficients.max() <= 0.05
    assert drone_settings(7) == drone_settings(7)
    with_extras = drone_settings(7, with_magnetometer=True, with_autopilot=True)
    assert {k: v for k, v in with_extras.items() if k not in ("magnetometer", "autopilot")} == \
        {k: v for k, v in drone_settings(7).items() if k not in ("magnetometer", "autopilot")}
    assert 0.0 < np.abs(with_extras["autopilot"].mounting_offset_deg[:2]).max() <= 2.0
    hover = drone_settings(7, start="hover")
    assert hover["plan"].start == "hover" and hover["thermal"].powered_before_s >= 60.0
    cfg = SimConfig.for_vehicle("drone", duration_s=100.0, seed=3, start="hover")
    assert cfg.plan.duration_s == 100.0 and cfg.vehicle == "drone"


def test_hover_start_is_airborne_and_warm():
    """A hover start: airborne at the hover height from the first row, motors at hover thrust, vibration from
    the start, the board already warm; the same survey as the ground start's, shifted. Measured: 0.07 m above
    the hover height (the wander), 7.3 degC warm at the first row (two minutes powered), 42 events."""
    cfg = SimConfig.for_vehicle("drone", seed=5, randomize=False, start="hover",
                                plan=dataclasses.replace(PLAN, start="hover", land=False))
    flight = simulate(cfg)
    nav = flight.truth_nav
    assert abs(nav.height[0] - SURVEY.start_height_m - SURVEY.hover_height_m) < 0.3
    assert np.linalg.norm(nav.v_n[:400], axis=1).max() < 0.5
    assert 0.98 < flight.motor_thrust_ratio[:400].min() and flight.motor_thrust_ratio[:400].max() < 1.02
    accel = flight.pos[["ACCS_X", "ACCS_Y", "ACCS_Z"]].to_numpy()[:400] - nav.f_ib_b[:400] - flight.accel_bias[:400]
    assert (accel.std(axis=0) > 0.3).all()
    assert flight.imu_temperature_degc[0] > cfg.thermal.ambient_degc + 5.0
    hover_legs = drone_schedule(cfg.plan).survey.legs
    ground = drone_schedule(PLAN)
    shifted = [(a - ground.hover_start_s, b - ground.hover_start_s, track, heading)
               for a, b, track, heading in ground.survey.legs]
    np.testing.assert_allclose(np.array(hover_legs[:3]), np.array(shifted[:3]), atol=1e-9)
    assert len(flight.exposures) > 10


def test_configuration_errors_name_the_drone_models():
    """The drone's models on another vehicle, or another vehicle's on the drone, are refused with a reason."""
    with pytest.raises(ValueError, match="ReceiverGnssModel"):
        SimConfig(plan=DronePlan())
    with pytest.raises(ValueError, match="drone's GNSS"):
        SimConfig(plan=CarPlan(), gnss=ReceiverGnssModel(), unit=None)
    with pytest.raises(ValueError, match="camera_trigger"):
        SimConfig.for_vehicle("multicopter", camera_trigger=drone_settings(1)["camera_trigger"])
    with pytest.raises(ValueError, match="motors"):
        SimConfig.for_vehicle("car", magnetometer=MagnetometerModel(motor_interference_ut=(1.0, 0.0, 0.0)))
    with pytest.raises(ValueError, match="start"):
        DronePlan(start="air")


#: Values of the multicopter and car flights computed with the simulator *before* the drone was added (git HEAD
#: 01ff104, unmodified georef/sim, exported with ``git archive``): the refactored multicopter schedule and the new
#: options leave the other vehicles' flights as they were.
_BEFORE = {
    "multicopter": {0: (0.12764399619992886, -9.7773423383198, 1.361493487114466, 0.036605442430423255),
                    1500: (0.7835068329322203, -10.2043471281746, -2.897555065518174, 0.30831468772340276),
                    2999: (0.319977775960649, -9.37345552052359, 2.1548383820473984, 0.22014350443551656),
                    "fix": (44.04699289118248, 210.2107191393152),
                    "frame": (24529.003, 44.047004200240345, 209.90853904932737, 2.608018928741957,
                              0.4869553911730264),
                    "mag": (25.085615404640517, 0.7616663983312404, 42.277116286719),
                    "autopilot": (0.0025210475267210407, 0.009481598215868461, -0.018119668271503464)},
    "car": {0: (0.4341279371114177, -9.837466301913508, -0.26205752821711314, 0.0819956503006929),
            1500: (0.1646139681003761, -9.901493039896897, -0.5583862610038958, 0.23645190279307607),
            2999: (0.5467925421725209, -9.946498117962921, -0.07089591855363007, 0.07427375191271915),
            "fix": (44.04699686199366, 149.9326581209898),
            "frame": (24528.996, 44.047152914954815, 151.40064900554717, 1.2635453405138937, 20.793530590293667)},
}


@pytest.mark.parametrize("vehicle", ["multicopter", "car"])
def test_other_vehicles_unchanged(vehicle):
    """The multicopter (with magnetometer and autopilot) and the car give the values they gave before."""
    extras = {"magnetometer": MagnetometerModel(), "autopilot": AutopilotModel()} if vehicle == "multicopter" else \
        {"gnss": GnssModel(rate_hz=5)}
    flight = simulate(SimConfig.for_vehicle(vehicle, duration_s=60.0, seed=3, **extras))
    before = _BEFORE[vehicle]
    for row in (0, 1500, 2999):
        np.testing.assert_allclose(flight.pos[["ACCS_X", "ACCS_Z", "OMGS_Y", "OMGS_Z"]].iloc[row], before[row],
                                   rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(flight.gnss_fixes[["lat", "height"]].iloc[20], before["fix"], rtol=1e-12)
    np.testing.assert_allclose(flight.truth_frames[["time", "lat", "height", "roll", "yaw"]].iloc[30], before["frame"],
                               rtol=1e-10)
    if vehicle == "multicopter":
        np.testing.assert_allclose(flight.mag[1500], before["mag"], rtol=1e-10)
        np.testing.assert_allclose(flight.autopilot_rpy[1500], before["autopilot"], rtol=1e-9, atol=1e-12)
    assert flight.imu_temperature_degc is None and flight.motor_thrust_ratio is None


# --- command line -------------------------------------------------------------------------------------------------

def test_cli_simulates_a_drone(tmp_path):
    """georef simulate --vehicle drone writes the generic files, events.csv, truth.csv and flight.toml."""
    result = CliRunner().invoke(app, [
        "simulate", str(tmp_path), "--vehicle", "drone", "--duration", "100", "--seed", "2", "--start", "hover",
        "--gnss-rate", "1", "--gnss-drop", "0.05", "--magnetometer", "--quiet"])
    assert result.exit_code == 0, result.output
    names = {p.name for p in tmp_path.iterdir()}
    assert {"imu.csv", "gnss.csv", "events.csv", "truth.csv", "truth_traj.csv", "flight.toml"} <= names
    assert "POS.txt" not in names
    imu = pd.read_csv(tmp_path / "imu.csv")
    assert {"mag_x", "temperature"} <= set(imu.columns) and "roll" not in imu.columns
    np.testing.assert_allclose(np.diff(imu["time"]), 0.005, atol=1e-9)
    gnss = pd.read_csv(tmp_path / "gnss.csv")
    steps = np.round(np.diff(gnss["time"])).astype(int)
    assert steps.min() == 1 and steps.max() <= 6
    assert (gnss["sigma_n"] > 0).all()
    toml = (tmp_path / "flight.toml").read_text()
    assert "gnss_latency" in toml and "camera_time_offset" in toml
    for bad, message in ((["--vehicle", "car", "--start", "ground"], "drone only"),
                         (["--vehicle", "drone", "--vibration", "white"], "only none")):
        wrong = CliRunner().invoke(app, ["simulate", str(tmp_path / "x"), *bad, "--quiet"])
        assert wrong.exit_code == 2 and message in wrong.output
