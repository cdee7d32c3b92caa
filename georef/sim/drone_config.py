"""The drone's installation and flight, nominal or drawn from realistic ranges by seed (for Monte-Carlo runs).

:func:`drone_settings` returns the :class:`~georef.sim.flight.SimConfig` fields of a drone flight;
``SimConfig.for_vehicle("drone", duration_s, seed, **changes)`` builds the configuration from them. With
``randomize=True`` (the default) every parameter below is drawn uniformly from its range with a generator
seeded by ``(seed, 201)``, always in the same order and all of them whatever the options, so a different
option changes nothing else:

* flight: log length 240-480 s (unless given), ground 8-40 s, spin-up 1.5-3.5 s, idle 0.5-4 s, throttle-up
  0.4-1.2 s, idle thrust 0.08-0.25, ground tilts +-3 deg, take-off climb 1.5-4 m/s at 1-3 m/s^2, lift-off peak
  2-4.5 g in 0.03-0.08 s settled in 0.3-1 s, lift-off oscillation 0.5-3 deg at 2-6 Hz decaying in 0.2-0.8 s,
  hover 3-20 s at 30-100 m, a landing in half the flights (descent 0.8-2.5 m/s, spin-down 1-3 s, 3-15 s on
  the ground after it), survey speed 4-12 m/s, acceleration 1.5-3 m/s^2, legs of 60-200 m in a lawn-mower
  pattern from a random direction at -15..+25 m from the hover height, heading 0-360 deg held / along the track
  / rotating (60 / 30 / 10 %), a second hover after leg 1-3 in half the flights, wander 0.1-0.5 m, wobble
  0.3-1.5 deg;
* IMU (``mems-consumer`` at 200 Hz): board warm-up 8-20 degC with time constant 120-400 s from an ambient
  5-35 degC, powered 3-30 s before the log (ground start) or 60-400 s (hover start); thermal coefficients
  0.01-0.05 deg/s and 1-5 mg per degC of random sign per axis;
* rotor vibration: hover rotor frequency 80-150 Hz, harmonics 1 / 0.3-0.8 / 0.1-0.4, RMS 1.5-5 m/s^2
  (x, y) and 2.5-8 m/s^2 (z), 0.8-3 deg/s (x, y) and 0.4-1.5 deg/s (z) before the on-board low-pass of
  30-80 Hz, first or second order; motor spread 1-5 %;
* GNSS at 5 Hz: Gauss-Markov 0.5-1.5 m horizontal, 1-3 m vertical, correlation time 20-120 s, white
  0.02-0.1 m / 0.04-0.2 m, latency 0.05-0.2 s with 1-5 ms jitter, reported accuracy 0.7-1.5 x the truth
  (wandering with time constant 60-300 s);
* camera: every 8-25 m (75 %) or every 1-3 s, latency 0.1-0.2 s (2 ms jitter);
* lever arms within a few cm to 25 cm, boresight within 1-2 deg;
* magnetometer (``with_magnetometer``): hard iron +-8 uT, motor interference +-5 uT per axis at hover;
  autopilot attitude (``with_autopilot``): mounting offset +-2 deg (roll, pitch), +-1 deg (yaw).

With ``randomize=False`` the nominal values are the models' defaults (:class:`~georef.sim.drone.DronePlan`,
:class:`~georef.sim.rotor.RotorVibrationModel`, ...), a 300 s log, and the lever arms of the multicopter.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from georef.frames import STANDARD_GRAVITY
from georef.sim.drone import START_MODES, DronePlan, drone_schedule
from georef.sim.multicopter import MulticopterPlan
from georef.sim.receiver import ReceiverGnssModel
from georef.sim.rotor import RotorVibrationModel
from georef.sim.sensors import AutopilotModel, MagnetometerModel
from georef.sim.thermal import ThermalBiasModel
from georef.sim.trigger import CameraTriggerModel

#: the drone-only keywords of ``SimConfig.for_vehicle("drone", ...)``
DRONE_OPTIONS = ("start", "randomize", "with_magnetometer", "with_autopilot")
#: sub-stream of the parameter draws
_CONFIG_STREAM = 201
_NOMINAL_DURATION_S = 300.0


def drone_settings(seed: int = 1, duration_s: float | None = None, start: str = "ground", randomize: bool = True,
                   with_magnetometer: bool = False, with_autopilot: bool = False) -> dict[str, object]:
    """:class:`~georef.sim.flight.SimConfig` fields of a drone flight (see the module doc for the ranges).

    ``start``: ``ground`` (log from power-on on the ground) or ``hover`` (the drone already hovering);
    ``duration_s`` [s]: the log length (None: drawn, or 300 s when not randomized); ``seed`` seeds the
    parameter draws, the plan's own randomness and the sensors'.
    """
    if start not in START_MODES:
        raise ValueError(f"start must be one of {', '.join(START_MODES)}, got {start!r}")
    if not randomize:
        return _nominal(seed, duration_s, start, with_magnetometer, with_autopilot)
    rng = np.random.default_rng((seed, _CONFIG_STREAM))
    uniform = _Uniform(rng)
    length = uniform(240.0, 480.0)
    plan = _random_plan(rng, uniform, seed, duration_s if duration_s is not None else length, start)
    thermal = ThermalBiasModel(
        ambient_degc=uniform(5.0, 35.0), warmup_degc=uniform(8.0, 20.0), time_constant_s=uniform(120.0, 400.0),
        powered_before_s=uniform(3.0, 30.0) if start == "ground" else uniform(60.0, 400.0),
        gyro_deg_s_per_degc=_signed(rng, uniform.triple(0.01, 0.05)),
        accel_mg_per_degc=_signed(rng, uniform.triple(1.0, 5.0)))
    xy_accel, z_accel, xy_gyro, z_gyro = uniform(1.5, 5.0), uniform(2.5, 8.0), uniform(0.8, 3.0), uniform(0.4, 1.5)
    vibration = RotorVibrationModel(
        hover_rotor_hz=uniform(80.0, 150.0), harmonic_weights=(1.0, uniform(0.3, 0.8), uniform(0.1, 0.4)),
        accel_rms_mps2=(xy_accel, xy_accel, z_accel), gyro_rms_deg_s=(xy_gyro, xy_gyro, z_gyro),
        motor_spread=uniform(0.01, 0.05), lowpass_hz=uniform(30.0, 80.0), lowpass_order=int(rng.integers(1, 3)))
    horizontal, vertical, white_h, white_v = uniform(0.5, 1.5), uniform(1.0, 3.0), uniform(0.02, 0.1), \
        uniform(0.04, 0.2)
    gnss = ReceiverGnssModel(
        sigma_neu_m=(horizontal, horizontal, vertical), correlation_time_s=uniform(20.0, 120.0),
        white_sigma_neu_m=(white_h, white_h, white_v), latency_s=uniform(0.05, 0.2),
        latency_jitter_s=uniform(0.001, 0.005), reported_scale_corr_s=uniform(60.0, 300.0))
    camera = CameraTriggerModel(mode="distance" if rng.random() < 0.75 else "time", distance_m=uniform(8.0, 25.0),
                                interval_s=uniform(1.0, 3.0), latency_s=uniform(0.1, 0.2))
    lever_arm_gnss = (uniform(-0.05, 0.1), uniform(-0.03, 0.03), uniform(-0.25, -0.08))
    lever_arm_camera = (uniform(0.03, 0.15), uniform(-0.03, 0.03), uniform(0.04, 0.15))
    boresight = (uniform(-1.0, 1.0), uniform(-1.0, 1.0), uniform(-2.0, 2.0))
    mag = MagnetometerModel(hard_iron_ut=uniform.triple(-8.0, 8.0), motor_interference_ut=uniform.triple(-5.0, 5.0))
    autopilot = AutopilotModel(mounting_offset_deg=(uniform(-2.0, 2.0), uniform(-2.0, 2.0), uniform(-1.0, 1.0)))
    return {"plan": plan, "seed": seed, "imu_preset": "mems-consumer", "pos_rate_hz": 200.0, "unit": None,
            "trig_quirk_seconds": [], "vibration": vibration, "thermal": thermal, "gnss": gnss,
            "camera_trigger": camera, "lever_arm_gnss_m": lever_arm_gnss, "lever_arm_camera_m": lever_arm_camera,
            "boresight_deg": boresight, "magnetometer": mag if with_magnetometer else None,
            "autopilot": autopilot if with_autopilot else None}


def _nominal(seed: int, duration_s: float | None, start: str, with_magnetometer: bool,
             with_autopilot: bool) -> dict[str, object]:
    """The models' default values (a hover start: the board powered for two minutes before the log)."""
    survey = MulticopterPlan(duration_s=duration_s if duration_s is not None else _NOMINAL_DURATION_S, hover_s=8.0,
                             seed=seed)
    return {"plan": DronePlan(survey=survey, start=start), "seed": seed, "imu_preset": "mems-consumer",
            "pos_rate_hz": 200.0, "unit": None, "trig_quirk_seconds": [], "vibration": RotorVibrationModel(),
            "thermal": ThermalBiasModel(powered_before_s=0.0 if start == "ground" else 120.0),
            "gnss": ReceiverGnssModel(), "camera_trigger": CameraTriggerModel(),
            "lever_arm_gnss_m": (0.02, 0.0, -0.12), "lever_arm_camera_m": (0.08, 0.0, 0.10),
            "boresight_deg": (0.2, -0.3, 0.5),
            "magnetometer": MagnetometerModel(hard_iron_ut=(4.0, -2.5, 3.0), motor_interference_ut=(1.5, -1.0, 4.0))
            if with_magnetometer else None,
            "autopilot": AutopilotModel(mounting_offset_deg=(0.8, -1.2, 0.5)) if with_autopilot else None}


class _Uniform:
    """Uniform draws from one generator: ``uniform(low, high)`` a float, ``uniform.triple(low, high)`` three."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng

    def __call__(self, low: float, high: float) -> float:
        return float(self.rng.uniform(low, high))

    def triple(self, low: float, high: float) -> tuple[float, float, float]:
        a, b, c = self.rng.uniform(low, high, 3)
        return float(a), float(b), float(c)


def _signed(rng: np.random.Generator, magnitudes: tuple[float, float, float]) -> tuple[float, float, float]:
    """The magnitudes with random signs."""
    a, b, c = rng.choice([-1.0, 1.0], 3) * np.asarray(magnitudes)
    return float(a), float(b), float(c)


def _random_plan(rng: np.random.Generator, uniform: _Uniform, seed: int, duration_s: float, start: str) -> DronePlan:
    """A drone plan with the ranges of the module doc (a landing only when it fits into the log)."""
    hover_height = uniform(30.0, 100.0)
    base = uniform(0.0, 360.0)
    directions = tuple(float((base + turn) % 360.0) for turn in (0.0, 90.0, 180.0, 90.0, 0.0))
    heights = tuple(float(max(20.0, hover_height + dh)) for dh in rng.uniform(-15.0, 25.0, 5))
    policy = str(rng.choice(["fixed", "track", "rotating"], p=[0.6, 0.3, 0.1]))
    second_hover = int(rng.integers(1, 4)) if rng.random() < 0.5 else -1
    survey = MulticopterPlan(
        duration_s=duration_s, hover_height_m=hover_height, hover_s=uniform(3.0, 20.0),
        leg_directions_deg=directions, leg_heights_m=heights, leg_length_m=uniform(60.0, 200.0),
        speed_mps=uniform(4.0, 12.0), max_accel_mps2=uniform(1.5, 3.0), heading_policy=policy,
        heading_deg=uniform(0.0, 360.0), second_hover_after_leg=second_hover, second_hover_s=uniform(4.0, 10.0),
        second_hover_yaw_turn_deg=float(rng.choice([0.0, 90.0, -90.0, 180.0])), wobble_deg=uniform(0.3, 1.5),
        position_hold_m=uniform(0.1, 0.5), seed=seed)
    takeoff_tilt = (uniform(-3.0, 3.0), uniform(-3.0, 3.0))
    landing_tilt = (uniform(-3.0, 3.0), uniform(-3.0, 3.0))
    plan = DronePlan(
        survey=survey, start=start, ground_s=uniform(8.0, 40.0), spinup_s=uniform(1.5, 3.5),
        idle_s=uniform(0.5, 4.0), throttle_up_s=uniform(0.4, 1.2), idle_thrust=uniform(0.08, 0.25),
        takeoff_tilt_deg=takeoff_tilt, landing_tilt_deg=landing_tilt, takeoff_climb_mps=uniform(1.5, 4.0),
        takeoff_accel_mps2=uniform(1.0, 3.0), liftoff_peak_mps2=STANDARD_GRAVITY * uniform(2.0, 4.5),
        liftoff_pulse_s=uniform(0.03, 0.08), liftoff_settle_s=uniform(0.3, 1.0), liftoff_wobble_deg=uniform(0.5, 3.0),
        liftoff_wobble_hz=uniform(2.0, 6.0), liftoff_wobble_decay_s=uniform(0.2, 0.8), land=bool(rng.random() < 0.5),
        landing_descent_mps=uniform(0.8, 2.5), spindown_s=uniform(1.0, 3.0), after_landing_s=uniform(3.0, 15.0))
    if plan.land:
        try:
            drone_schedule(plan)
        except ValueError:  # too short a log for a landing: fly on to the end instead
            plan = dataclasses.replace(plan, land=False)
    return plan
