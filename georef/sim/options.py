"""``georef simulate``'s options: which vehicle each applies to, their values checked, and the simulator's
configuration (:class:`georef.sim.flight.SimConfig`) they make.

Every check runs before anything is simulated; a refusal is an :class:`georef.option_values.OptionError` naming
the option. Units are the options': seconds, Hz, metres, deg/s, m/s^2, deg/h, m/s.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from georef.option_values import OptionError, pairs, triple
from georef.sim.flight import VEHICLES, SimConfig
from georef.sim.sensors import AutopilotModel, GnssModel, MagnetometerModel, UnitModel, VibrationModel


@dataclass(frozen=True)
class SimOptions:
    """What ``georef simulate`` was given (None: not given, the vehicle's default); the triples and pairs are the
    options' text (``gyro_bias`` "X,Y,Z" [deg/s, body], ``accel_bias`` [m/s^2, body], ``gnss_sigma`` "N,E,U" [m],
    ``outage`` "START,LENGTH" [s], ``outlier`` "TIME,SIZE" [s, m])."""

    vehicle: str = "helicopter"
    duration: float | None = None
    rate: float | None = None
    camera_rate: float | None = None
    seed: int = 1
    imu: str | None = None
    gyro_bias: str | None = None
    accel_bias: str | None = None
    vibration: str | None = None
    vibration_level: float = 1.0
    gnss_rate: float | None = None
    gnss_sigma: str | None = None
    unit_yaw_drift: float | None = None
    gnss_drop: float | None = None
    start: str | None = None
    outage: list[str] = field(default_factory=list)
    outlier: list[str] = field(default_factory=list)
    hover: float | None = None
    heading_policy: str | None = None
    speed: float | None = None
    magnetometer: bool = False
    autopilot: bool = False


def check_vehicle_options(options: SimOptions) -> None:
    """Refuse an option the chosen vehicle does not take."""
    vehicle = options.vehicle
    if vehicle not in VEHICLES:
        raise OptionError(f"--vehicle must be one of {', '.join(VEHICLES)}, got {vehicle!r}")
    for name, value in {"hover": options.hover, "heading-policy": options.heading_policy}.items():
        if value is not None and vehicle not in ("multicopter", "drone"):
            raise OptionError(f"--{name} applies to --vehicle multicopter only (and to the drone's survey)")
    if options.speed is not None and vehicle == "helicopter":
        raise OptionError("--speed applies to --vehicle multicopter, drone or car")
    for name, value in {"start": options.start, "gnss-drop": options.gnss_drop}.items():
        if value is not None and vehicle != "drone":
            raise OptionError(f"--{name} applies to --vehicle drone only")
    if options.gnss_sigma is not None and vehicle == "drone":
        raise OptionError("--gnss-sigma applies to --vehicle helicopter, multicopter or car (the drone's receiver "
                          "errors are drawn by --seed)")
    if options.unit_yaw_drift is not None and vehicle != "helicopter":
        raise OptionError("--unit-yaw-drift applies to --vehicle helicopter only (the others have no POS unit)")


def sim_config(options: SimOptions) -> SimConfig:
    """The simulator's configuration of ``options``, every option checked first."""
    check_vehicle_options(options)
    sigma_neu = triple(options.gnss_sigma, "--gnss-sigma", "metres")
    if sigma_neu is not None and not all(np.isfinite(v) and v > 0 for v in sigma_neu):
        raise OptionError(f"--gnss-sigma must be three positive metres N,E,U, got {options.gnss_sigma!r}")
    if options.unit_yaw_drift is not None and not np.isfinite(options.unit_yaw_drift):
        raise OptionError(f"--unit-yaw-drift must be a finite number of deg/h, got {options.unit_yaw_drift!r}")
    if options.vehicle == "drone":
        return _drone_config(options, pairs(options.outage, "--outage"), pairs(options.outlier, "--outlier"))
    return _vehicle_config(options, sigma_neu)


def _imu_changes(options: SimOptions) -> dict[str, Any]:
    """The IMU preset and forced turn-on biases [rad/s, m/s^2] given."""
    changes: dict[str, Any] = {}
    if options.imu is not None:
        changes["imu_preset"] = options.imu
    if options.gyro_bias is not None:
        changes["gyro_bias_rad_s"] = tuple(np.radians(triple(options.gyro_bias, "--gyro-bias", "deg/s")))
    if options.accel_bias is not None:
        changes["accel_bias_mps2"] = triple(options.accel_bias, "--accel-bias", "m/s^2")
    return changes


def _vehicle_config(options: SimOptions, sigma_neu: tuple[float, float, float] | None) -> SimConfig:
    """The helicopter's, multicopter's or car's configuration: the defaults with what the user gave."""
    vehicle = options.vehicle
    rate = 50.0 if options.rate is None else options.rate
    gnss_rate = 1.0 if options.gnss_rate is None else options.gnss_rate
    changes: dict[str, Any] = {
        "pos_rate_hz": rate, "camera_rate_hz": 3.0 if options.camera_rate is None else options.camera_rate,
        "gnss": GnssModel(rate_hz=gnss_rate, outages=pairs(options.outage, "--outage"),
                          outliers=pairs(options.outlier, "--outlier"),
                          **({} if sigma_neu is None else {"sigma_neu_m": sigma_neu})),
    }
    if options.unit_yaw_drift is not None:
        changes["unit"] = UnitModel(yaw_drift_deg_min=options.unit_yaw_drift / 60.0)
    if options.imu is not None:
        changes["imu_preset"] = options.imu
    if options.vibration is not None or options.vibration_level != 1.0:
        kind = options.vibration or {"helicopter": "rotor", "multicopter": "narrowband", "car": "white"}[vehicle]
        changes["vibration"] = VibrationModel.of_kind(kind, level=options.vibration_level)
    changes.update({key: value for key, value in _imu_changes(options).items() if key != "imu_preset"})
    if options.magnetometer:
        changes["magnetometer"] = MagnetometerModel()
    if options.autopilot:
        changes["autopilot"] = AutopilotModel()
    cfg = SimConfig.for_vehicle(vehicle, duration_s=180.0 if options.duration is None else options.duration,
                                seed=options.seed, **changes)
    plan_changes = {"hover_s": options.hover, "heading_policy": options.heading_policy,
                    "speed_mps" if vehicle == "multicopter" else "cruise_speed_mps": options.speed}
    plan_changes = {k: v for k, v in plan_changes.items() if v is not None}
    if plan_changes:
        cfg.plan = dataclasses.replace(cfg.plan, **plan_changes)
    return cfg


def _drone_config(options: SimOptions, outages: list[tuple[float, float]],
                  outliers: list[tuple[float, float]]) -> SimConfig:
    """``--vehicle drone``: the configuration drawn by ``seed``, with what the user gave."""
    changes: dict[str, Any] = {}
    if options.rate is not None:
        changes["pos_rate_hz"] = options.rate
    changes.update(_imu_changes(options))
    cfg = SimConfig.for_vehicle("drone", duration_s=options.duration, seed=options.seed,
                                start=options.start or "ground", with_magnetometer=options.magnetometer,
                                with_autopilot=options.autopilot, **changes)
    gnss_changes: dict[str, Any] = {name: value for name, value in (("rate_hz", options.gnss_rate),
                                                                    ("drop_fraction", options.gnss_drop))
                                    if value is not None}
    gnss_changes.update({name: value for name, value in (("outages", outages), ("outliers", outliers)) if value})
    cfg.gnss = dataclasses.replace(cfg.gnss, **gnss_changes)
    if options.camera_rate is not None:
        cfg.camera_trigger = dataclasses.replace(cfg.camera_trigger, mode="time",
                                                 interval_s=1.0 / options.camera_rate)
    if options.vibration not in (None, "none"):
        raise OptionError("--vibration for the drone: only none (its rotor harmonics follow the thrust; "
                          "--vibration-level scales them)")
    cfg.vibration = (None if options.vibration == "none"
                     else dataclasses.replace(cfg.vibration, level=options.vibration_level))
    survey = {name: value for name, value in (("hover_s", options.hover), ("heading_policy", options.heading_policy),
                                              ("speed_mps", options.speed)) if value is not None}
    if survey:
        cfg.plan = dataclasses.replace(cfg.plan, survey=dataclasses.replace(cfg.plan.survey, **survey))
    return cfg
