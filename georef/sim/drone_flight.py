"""A drone's whole log as a :class:`~georef.sim.flight.SimulatedFlight`: IMU, GNSS receiver, camera events, extras.

``simulate(cfg)`` comes here when ``cfg.plan`` is a :class:`~georef.sim.drone.DronePlan`. The IMU rows (at
``cfg.pos_rate_hz``) carry the preset's errors (:func:`georef.sim.sensors.corrupt_imu`), the temperature-driven
biases (``cfg.thermal``) and the rotor vibration (``cfg.vibration``, zero with the motors off); the GNSS
receiver's fixes are tagged at arrival (:mod:`georef.sim.receiver`); the camera events are logged at the
trigger and the truth is at the exposure a latency later (:mod:`georef.sim.trigger`); the magnetometer sees
the motor currents. Every source draws from its own random stream, seeded ``(seed, stream)``, except the IMU
noise (``seed``): switching one on or off changes nothing else.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from georef.imu_errors import imu_preset
from georef.sim.drone import DronePlan, DroneTruth, fly_drone
from georef.sim.flight import (
    AUTOPILOT_STREAM,
    MAG_STREAM,
    SimConfig,
    SimulatedFlight,
    fine_grid_rate,
    frame_truth,
)
from georef.sim.receiver import ReceiverGnssModel, receiver_fixes
from georef.sim.rotor import rotor_vibration
from georef.sim.sensors import autopilot_attitude, corrupt_imu, magnetometer
from georef.sim.thermal import add_thermal_bias
from georef.sim.trajectory import Trajectory
from georef.sim.trigger import CameraEvents, camera_events

#: sub-streams of the drone's own sources
VIBRATION_STREAM, GNSS_STREAM, CAMERA_STREAM = 103, 104, 105
#: motor current ~ thrust^1.5 (power of an ideal rotor), so the magnetometer's motor field goes with it
_CURRENT_EXPONENT = 1.5


def simulate_drone(cfg: SimConfig) -> SimulatedFlight:
    """The drone flight of ``cfg`` (see the module doc). Times are ``cfg.start_utc_s`` + seconds of the log."""
    assert isinstance(cfg.plan, DronePlan) and isinstance(cfg.gnss, ReceiverGnssModel)
    fine_rate, oversample = fine_grid_rate(cfg.pos_rate_hz)
    truth = fly_drone(cfg.plan, float(fine_rate))
    fine = truth.trajectory
    fine_time = cfg.start_utc_s + np.arange(len(fine.time)) / fine_rate
    rows = np.arange(int(round(cfg.first_row_offset_s * fine_rate)), len(fine.time), oversample)
    nav = fine.subsample(rows)
    nav.time = fine_time[rows]
    thrust = truth.thrust_ratio[rows]

    gyro, accel, gyro_bias, accel_bias = corrupt_imu(
        nav.omega_ib_b, nav.f_ib_b, nav.time, imu_preset(cfg.imu_preset), None, np.random.default_rng(cfg.seed),
        gyro_turn_on=cfg.gyro_bias_rad_s, accel_turn_on=cfg.accel_bias_mps2,
        gyro_scale=np.asarray(cfg.gyro_scale_ppm) * 1e-6, accel_scale=np.asarray(cfg.accel_scale_ppm) * 1e-6)
    temperature = None
    if cfg.thermal is not None:
        temperature = add_thermal_bias(cfg.thermal, nav.time - cfg.start_utc_s, gyro, accel, gyro_bias, accel_bias)
    if cfg.vibration is not None:
        vibration = rotor_vibration(nav.time, fine_time, truth.thrust_ratio, cfg.vibration,
                                    _stream(cfg, VIBRATION_STREAM))
        gyro += vibration.gyro
        accel += vibration.accel

    fixes = receiver_fixes(cfg.gnss, nav, cfg.lever_arm_gnss_m, _stream(cfg, GNSS_STREAM))
    exposures, truth_frames = _camera(cfg, truth, fine, fine_time, nav)
    mag = autopilot = None
    if cfg.magnetometer is not None:
        mag = magnetometer(nav.C_b_n, cfg.magnetometer, _stream(cfg, MAG_STREAM), motor_load=thrust**_CURRENT_EXPONENT)
    if cfg.autopilot is not None:
        autopilot = autopilot_attitude(nav.time, nav.roll, nav.pitch, nav.yaw, cfg.autopilot,
                                       _stream(cfg, AUTOPILOT_STREAM))
    pos = pd.DataFrame({"ACCS_X": accel[:, 0], "ACCS_Y": accel[:, 1], "ACCS_Z": accel[:, 2],
                        "OMGS_X": np.degrees(gyro[:, 0]), "OMGS_Y": np.degrees(gyro[:, 1]),
                        "OMGS_Z": np.degrees(gyro[:, 2])})
    if temperature is not None:
        pos["IMU_TEMP"] = temperature
    return SimulatedFlight(config=cfg, pos=pos, exposures=exposures, truth_frames=truth_frames, truth_nav=nav,
                           gnss_fixes=fixes, gyro_bias=gyro_bias, accel_bias=accel_bias, mag=mag,
                           autopilot_rpy=autopilot, imu_temperature_degc=temperature, motor_thrust_ratio=thrust)


def _stream(cfg: SimConfig, stream: int) -> np.random.Generator:
    return np.random.default_rng((cfg.seed, stream))


def _camera(cfg: SimConfig, truth: DroneTruth, fine: Trajectory, fine_time: np.ndarray,
            nav: Trajectory) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The logged events (frame, time, image) and the truth at each exposure (empty without a camera)."""
    if cfg.camera_trigger is None:
        events = CameraEvents(trigger_time=np.empty(0), exposure_time=np.empty(0), image=[])
    else:
        legs = [(cfg.start_utc_s + start, cfg.start_utc_s + end) for start, end, _, _ in truth.schedule.survey.legs]
        events = camera_events(cfg.camera_trigger, legs, nav.time, nav.v_n, _stream(cfg, CAMERA_STREAM))
    frames = np.arange(1, len(events.trigger_time) + 1)
    exposures = pd.DataFrame({"frame": frames, "time": events.trigger_time, "image": events.image})
    table = frame_truth(cfg, fine, fine_time, events.exposure_time, None)
    table.insert(0, "frame", frames)
    return exposures, table
