"""A whole simulated flight: POS log, exposure times and the truth of every frame.

``simulate(SimConfig(...))`` returns a :class:`SimulatedFlight`; :func:`georef.sim.files.write_flight`
writes it as ``POS.txt``, ``Kamera.txt``, ``truth.csv`` and a ``flight.toml`` that processes it.

The vehicle is chosen by the type of ``SimConfig.plan``: :class:`~georef.sim.trajectory.FlightPlan`
(helicopter survey, the default), :class:`~georef.sim.multicopter.MulticopterPlan`,
:class:`~georef.sim.car.CarPlan` or :class:`~georef.sim.drone.DronePlan` (a drone's whole log, from the ground,
assembled by :mod:`georef.sim.drone_flight`); :meth:`SimConfig.for_vehicle` gives each vehicle's typical
installation (the drone's drawn from realistic ranges by seed, :mod:`georef.sim.drone_config`).
The default configuration draws its random numbers in the same order as it always has (the bundled flight in
``data/`` and the tests depend on it); every optional output (magnetometer, autopilot attitude) draws from
its own random stream, so switching it on changes nothing else.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy.interpolate import CubicHermiteSpline
from scipy.spatial.transform import Rotation, Slerp

from georef.frames import (
    C_n_e,
    dcm_to_euler,
    earth_rate_n,
    ecef_to_geodetic,
    euler_to_dcm,
    geodetic_to_ecef,
    wrap_360,
)
from georef.frames.mounting import camera_attitude, lever_arm_ecef
from georef.imu_errors import imu_preset
from georef.sim.car import CarPlan, drive
from georef.sim.drone import DronePlan, fly_drone
from georef.sim.drone_config import DRONE_OPTIONS, drone_settings
from georef.sim.multicopter import MulticopterPlan, fly_multicopter
from georef.sim.receiver import ReceiverGnssModel
from georef.sim.rotor import RotorVibrationModel
from georef.sim.sensors import (
    AutopilotModel,
    GnssModel,
    MagnetometerModel,
    UnitModel,
    VibrationModel,
    autopilot_attitude,
    corrupt_imu,
    gauss_markov,
    magnetometer,
)
from georef.sim.thermal import ThermalBiasModel, add_thermal_bias
from georef.sim.trajectory import FlightPlan, Trajectory, fly
from georef.sim.trigger import CameraTriggerModel

#: Vehicle name -> plan type (the plan's type selects the vehicle in :func:`simulate`).
VEHICLES: dict[str, type] = {"helicopter": FlightPlan, "multicopter": MulticopterPlan, "car": CarPlan,
                             "drone": DronePlan}
#: POS columns that only a POS unit (``SimConfig.unit``) writes.
UNIT_COLUMNS = ["IACC_X", "IACC_Y", "IACC_Z", "ROLL", "PITCH", "YAW"]
#: Sub-stream numbers of the optional outputs' random generators (seeded with ``(seed, stream)``).
MAG_STREAM, AUTOPILOT_STREAM = 101, 102

POS_HEADER = [
    "CNT[HEX]", "ACCS_X", "ACCS_Y", "ACCS_Z", "IACC_X", "IACC_Y", "IACC_Z", "OMGS_X", "OMGS_Y", "OMGS_Z",
    "IOMG_X", "IOMG_Y", "IOMG_Z", "ROLL", "PITCH", "YAW", "VELX", "ODO_TICKS", "MAGNMTR", "TRIG_TIME",
    "SAMPL_TIME", "IMU_TEMP", "SENS_TEMP", "LONGITUDE", "LATITUDE", "ALTITUDE", "VELOCITY", "STATUS[HEX]",
]


@dataclass
class SimConfig:
    """Everything that defines a simulated flight. Units: s, m, deg, Hz unless a name says otherwise.

    * ``plan``: the vehicle and its path (``FlightPlan``, ``MulticopterPlan``, ``CarPlan`` or ``DronePlan``);
    * ``imu_preset``: a name of :data:`georef.imu_errors.IMU_PRESETS`; ``gyro_bias_rad_s`` [rad/s] and
      ``accel_bias_mps2`` [m/s^2] (body x, y, z) force the turn-on biases (None: drawn from the preset);
      ``gyro_scale_ppm`` and ``accel_scale_ppm`` (body x, y, z) are scale-factor errors, measured = (1 + s) x true
      (the presets have none: zero unless set);
    * ``vibration``: :class:`VibrationModel` (kind none/rotor/white/narrowband) or None; the drone's is a
      :class:`~georef.sim.rotor.RotorVibrationModel` (rotor harmonics following the thrust) or None;
    * ``unit``: the POS unit's own attitude and IACC outputs, or None for a vehicle without one (POS.txt
      then has no ROLL/PITCH/YAW/IACC columns; the drone has none);
    * ``gnss``: :class:`GnssModel`; the drone's is a :class:`~georef.sim.receiver.ReceiverGnssModel`
      (correlated errors, reported accuracy, arrival time tags, gaps);
    * ``pos_rate_hz``: the IMU row rate (the drone's IMU log rate, 200 Hz from ``for_vehicle``);
      ``camera_rate_hz`` and ``camera_jitter_ms``: the exposures of the vehicles other than the drone, whose
      camera is ``camera_trigger`` (:class:`~georef.sim.trigger.CameraTriggerModel`; None: no camera);
    * ``thermal``: a board warming up after power-on and biases following its temperature
      (:class:`~georef.sim.thermal.ThermalBiasModel`, any vehicle; None: off);
    * ``magnetometer``, ``autopilot``: optional extra outputs for the generic files (None: off).
    """

    plan: FlightPlan | MulticopterPlan | CarPlan | DronePlan = field(default_factory=FlightPlan)
    imu_preset: str = "mems-ivru"
    vibration: VibrationModel | RotorVibrationModel | None = field(default_factory=VibrationModel)
    unit: UnitModel | None = field(default_factory=UnitModel)
    gnss: GnssModel | ReceiverGnssModel = field(default_factory=GnssModel)
    pos_rate_hz: float = 50.0
    camera_rate_hz: float = 3.0
    camera_jitter_ms: float = 4.0
    start_utc_s: int = 24513
    first_row_offset_s: float = 0.0125
    lever_arm_gnss_m: tuple[float, float, float] = (0.45, 0.15, -1.65)
    lever_arm_camera_m: tuple[float, float, float] = (1.10, -0.25, 0.55)
    boresight_deg: tuple[float, float, float] = (0.35, -0.6, 1.2)
    trig_quirk_seconds: list[int] = field(default_factory=lambda: [37, 121])
    seed: int = 1
    gyro_bias_rad_s: tuple[float, float, float] | None = None
    accel_bias_mps2: tuple[float, float, float] | None = None
    gyro_scale_ppm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    accel_scale_ppm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    magnetometer: MagnetometerModel | None = None
    autopilot: AutopilotModel | None = None
    thermal: ThermalBiasModel | None = None
    camera_trigger: CameraTriggerModel | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.plan, tuple(VEHICLES.values())):
            raise TypeError(f"plan must be one of {', '.join(t.__name__ for t in VEHICLES.values())}, "
                            f"got {type(self.plan).__name__}")
        for name in ("gyro_bias_rad_s", "accel_bias_mps2", "gyro_scale_ppm", "accel_scale_ppm"):
            value = getattr(self, name)
            if value is not None and np.shape(value) != (3,):
                raise ValueError(f"{name} needs three numbers (body x, y, z), got {value!r}")
        problems = self._drone_problems() if isinstance(self.plan, DronePlan) else self._non_drone_problems()
        if problems:
            raise ValueError(f"{self.vehicle}: " + "; ".join(problems))

    def _drone_problems(self) -> list[str]:
        """What a drone configuration has that the drone cannot fly with."""
        problems = []
        if self.unit is not None:
            problems.append("a drone has no POS unit (unit=None)")
        if not isinstance(self.gnss, ReceiverGnssModel):
            problems.append("its GNSS is a ReceiverGnssModel")
        if self.vibration is not None and not isinstance(self.vibration, RotorVibrationModel):
            problems.append("its vibration is a RotorVibrationModel or None")
        if problems:
            problems.append("SimConfig.for_vehicle('drone', ...) sets all of these")
        return problems

    def _non_drone_problems(self) -> list[str]:
        """The drone's own models in the configuration of another vehicle."""
        problems = []
        if isinstance(self.gnss, ReceiverGnssModel):
            problems.append("ReceiverGnssModel is the drone's GNSS; use GnssModel")
        if isinstance(self.vibration, RotorVibrationModel):
            problems.append("RotorVibrationModel needs the drone's thrust; use VibrationModel")
        if self.camera_trigger is not None:
            problems.append("camera_trigger is the drone's camera; the others use camera_rate_hz")
        if self.magnetometer is not None and any(self.magnetometer.motor_interference_ut):
            problems.append("magnetometer motor interference needs the drone's motors")
        return problems

    @property
    def vehicle(self) -> str:
        """``helicopter``, ``multicopter``, ``car`` or ``drone``, from the plan's type."""
        return next(name for name, kind in VEHICLES.items() if isinstance(self.plan, kind))

    @classmethod
    def for_vehicle(cls, vehicle: str, duration_s: float | None = None, seed: int = 1,
                    **changes: object) -> SimConfig:
        """A configuration with ``vehicle``'s plan (``duration_s`` [s], plan seed = ``seed``) and installation.

        * ``helicopter``: exactly :class:`SimConfig`'s defaults (survey plan, MEMS unit with rotor vibration);
        * ``multicopter``: :class:`MulticopterPlan`, no POS unit, ``mems-consumer`` IMU, narrowband
          vibration (20 +- 2 Hz), a drone's lever arms, no logger quirk;
        * ``car``: :class:`CarPlan`, no POS unit, ``mems-consumer`` IMU, white vibration, roof antenna and
          camera, no logger quirk;
        * ``drone``: :class:`DronePlan` and a drone's sensors (200 Hz IMU with rotor vibration and thermal bias,
          GNSS receiver, camera trigger) with every parameter drawn from realistic ranges by ``seed``
          (:func:`georef.sim.drone_config.drone_settings`); ``changes`` may also hold its options ``start``
          ("ground" or "hover"), ``randomize`` (False: the nominal values), ``with_magnetometer`` and
          ``with_autopilot`` (the drawn magnetometer and autopilot outputs, off by default).

        ``changes`` override any field of the result.
        """
        if vehicle not in VEHICLES:
            raise ValueError(f"vehicle must be one of {', '.join(VEHICLES)}, got {vehicle!r}")
        if vehicle == "drone":
            options = {name: changes.pop(name) for name in DRONE_OPTIONS if name in changes}
            return cls(**{**drone_settings(seed, duration_s, **options), **changes})  # type: ignore[arg-type]
        plan_args: dict[str, object] = {"seed": seed}
        if duration_s is not None:
            plan_args["duration_s"] = duration_s
        typical: dict[str, dict[str, object]] = {
            "helicopter": {},
            "multicopter": {"unit": None, "imu_preset": "mems-consumer", "trig_quirk_seconds": [],
                            "vibration": VibrationModel.of_kind("narrowband"),
                            "lever_arm_gnss_m": (0.02, 0.0, -0.12), "lever_arm_camera_m": (0.08, 0.0, 0.10),
                            "boresight_deg": (0.2, -0.3, 0.5)},
            "car": {"unit": None, "imu_preset": "mems-consumer", "trig_quirk_seconds": [],
                    "vibration": VibrationModel.of_kind("white"),
                    "lever_arm_gnss_m": (-0.6, 0.0, -1.1), "lever_arm_camera_m": (0.9, 0.0, -1.0),
                    "boresight_deg": (0.3, -0.4, 0.8)},
        }
        settings = {"plan": VEHICLES[vehicle](**plan_args), "seed": seed, **typical[vehicle], **changes}
        return cls(**settings)  # type: ignore[arg-type]


@dataclass
class SimulatedFlight:
    """The simulator's output: the POS table, exposures, per-frame truth and the navigation truth.

    A drone's flight (:mod:`georef.sim.drone_flight`) differs: ``pos`` holds only the IMU columns (``ACCS_*``,
    ``OMGS_*``, ``IMU_TEMP``), ``exposures`` the logged camera events (``frame, time, image``) while
    ``truth_frames`` is at the true exposure times, and ``gnss_fixes`` carries each fix's ``measured_time`` and
    the receiver's reported ``sigma_n, sigma_e, sigma_u``.
    """

    config: SimConfig
    pos: pd.DataFrame
    exposures: pd.DataFrame          # frame, time [UTC s]
    truth_frames: pd.DataFrame       # per frame: camera position and attitude, deg / m
    truth_nav: Trajectory            # at POS rows, time in UTC s
    gnss_fixes: pd.DataFrame         # time, measured antenna lat/lon/height, is_outlier
    gyro_bias: np.ndarray
    accel_bias: np.ndarray
    mag: np.ndarray | None = None             # (N, 3) magnetometer at POS rows [uT], body axes
    autopilot_rpy: np.ndarray | None = None   # (N, 3) autopilot roll, pitch, yaw at POS rows [rad]
    imu_temperature_degc: np.ndarray | None = None  # (N,) board temperature at POS rows (SimConfig.thermal)
    motor_thrust_ratio: np.ndarray | None = None    # (N,) drone: thrust / hover thrust at the rows, 0 motors off


def fine_grid_rate(pos_rate_hz: float) -> tuple[int, int]:
    """The truth's grid rate [Hz] (at least 400 Hz, a whole multiple of the row rate) and that multiple."""
    oversample = max(1, int(np.ceil(400.0 / pos_rate_hz)))
    fine = pos_rate_hz * oversample
    if abs(fine - round(fine)) > 1e-9:
        raise ValueError(f"POS rate {pos_rate_hz} Hz must divide a whole-number fine rate")
    return int(round(fine)), oversample


def _ecef_track(traj: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    r_e = geodetic_to_ecef(traj.lat, traj.lon, traj.height)
    v_e = np.einsum("nij,nj->ni", C_n_e(traj.lat, traj.lon), traj.v_n)
    return r_e, v_e


def _unit_outputs(cfg: SimConfig, traj: Trajectory, accel_error_b: np.ndarray,
                  rng: np.random.Generator) -> dict[str, np.ndarray]:
    """ROLL/PITCH/YAW [deg] and IACC [m/s^2] as the unit would log them (unknown yaw origin, drift)."""
    unit = cfg.unit
    assert unit is not None
    n = len(traj.time)
    dt = float(np.median(np.diff(traj.time)))
    t_rel = traj.time - traj.time[0]
    level_error = gauss_markov(n, dt, np.radians(unit.level_error_deg), unit.level_error_corr_s, rng, 2)
    noise = rng.standard_normal((n, 3)) * np.radians(unit.angle_noise_deg)
    yaw_offset = np.radians(unit.yaw_offset_deg + unit.yaw_drift_deg_min * t_rel / 60.0)
    roll = traj.roll + level_error[:, 0] + noise[:, 0]
    pitch = traj.pitch + level_error[:, 1] + noise[:, 1]
    yaw = traj.yaw - yaw_offset + noise[:, 2]
    # Level-frame kinematic acceleration, resolved on the unit's own azimuth reference.
    accel_error_n = np.einsum("nij,nj->ni", traj.C_b_n, accel_error_b)
    a_n = traj.a_n + accel_error_n + unit.iacc_bias_mps2 * rng.standard_normal(3)
    # the unit's azimuth reference is NED turned by the yaw offset about down: IACC = Rz(offset)ᵀ a_n
    iacc = np.einsum("nji,nj->ni", euler_to_dcm(0.0, 0.0, yaw_offset), a_n)
    return {"ROLL": np.degrees(roll), "PITCH": np.degrees(pitch),
            "YAW": (np.degrees(yaw) + 180.0) % 360.0 - 180.0, "IACC": iacc, "yaw_offset": yaw_offset}


def _gnss(cfg: SimConfig, fine: Trajectory, fine_rate: int, row_time: np.ndarray,
          rng: np.random.Generator) -> tuple[pd.DataFrame, np.ndarray]:
    """Measured fixes on whole seconds and, for each POS row, the index of the fix it holds (-1: none)."""
    gnss = cfg.gnss
    if gnss.rate_hz <= 0:
        raise ValueError(f"GNSS rate must be positive Hz, got {gnss.rate_hz}")
    period = 1.0 / gnss.rate_hz
    first = np.ceil(row_time[0] + 2.0)
    fix_time = np.arange(first, row_time[-1] - 0.5, period)
    rel = fix_time - cfg.start_utc_s
    keep = np.ones(len(fix_time), bool)
    for start, length in gnss.outages:
        keep &= ~((rel >= start) & (rel < start + length))
    fix_time, rel = fix_time[keep], rel[keep]
    if not -1.0 <= gnss.time_offset_s <= 1.0:
        raise ValueError(f"GNSS time offset must be within 1 s, got {gnss.time_offset_s}")
    idx = np.round((rel - gnss.time_offset_s) * fine_rate).astype(int)
    C_b_n = euler_to_dcm(fine.roll[idx], fine.pitch[idx], fine.yaw[idx])
    r_e = geodetic_to_ecef(fine.lat[idx], fine.lon[idx], fine.height[idx])
    r_ant = r_e + lever_arm_ecef(fine.lat[idx], fine.lon[idx], C_b_n, cfg.lever_arm_gnss_m)
    noise_n = rng.standard_normal((len(idx), 3)) * np.asarray(gnss.sigma_neu_m) * np.array([1, 1, -1])
    outlier = np.zeros(len(idx), bool)
    for when, size in gnss.outliers:
        k = int(np.argmin(np.abs(rel - when)))
        direction = rng.standard_normal(3)
        noise_n[k] += size * direction / np.linalg.norm(direction)
        outlier[k] = True
    r_meas = r_ant + np.einsum("nij,nj->ni", C_n_e(fine.lat[idx], fine.lon[idx]), noise_n)
    lat, lon, h = ecef_to_geodetic(r_meas)
    speed = np.hypot(fine.v_n[idx, 0], fine.v_n[idx, 1]) + 0.05 * rng.standard_normal(len(idx))
    fixes = pd.DataFrame({"time": fix_time, "lat": np.degrees(lat), "lon": np.degrees(lon), "height": h,
                          "speed": speed, "is_outlier": outlier})
    latency = (min(gnss.latency_s[0], 0.5 * period), min(gnss.latency_s[1], 0.9 * period))
    appear = fix_time + rng.uniform(*latency, len(fix_time))
    held = np.searchsorted(appear, row_time, side="right") - 1
    return fixes, held


def frame_truth(cfg: SimConfig, fine: Trajectory, fine_time: np.ndarray, frame_time: np.ndarray,
                 yaw_offset_of: np.ndarray | None) -> pd.DataFrame:
    """Per-frame truth: camera position and attitude, body attitude, track [deg, m]; the unit's yaw origin."""
    r_e, v_e = _ecef_track(fine)
    r_imu = CubicHermiteSpline(fine_time, r_e, v_e, axis=0)(frame_time)
    v_n_frame = np.stack([np.interp(frame_time, fine_time, fine.v_n[:, k]) for k in range(3)], -1)
    rot = Slerp(fine_time, Rotation.from_matrix(fine.C_b_n))(frame_time)
    C_b_n = rot.as_matrix()
    lat_i, lon_i, _ = ecef_to_geodetic(r_imu)
    r_cam = r_imu + lever_arm_ecef(lat_i, lon_i, C_b_n, cfg.lever_arm_camera_m)
    lat, lon, h = ecef_to_geodetic(r_cam)
    C_c_n = camera_attitude(C_b_n, np.radians(cfg.boresight_deg))
    roll, pitch, yaw = dcm_to_euler(C_c_n)
    body_roll, body_pitch, body_yaw = dcm_to_euler(C_b_n)
    track = np.degrees(np.arctan2(v_n_frame[:, 1], v_n_frame[:, 0]))
    table = pd.DataFrame({
        "time": frame_time, "lat": np.degrees(lat), "lon": np.degrees(lon), "height": h,
        "roll": np.degrees(roll), "pitch": np.degrees(pitch), "yaw": wrap_360(np.degrees(yaw)),
        "body_roll": np.degrees(body_roll), "body_pitch": np.degrees(body_pitch),
        "body_yaw": wrap_360(np.degrees(body_yaw)), "track": wrap_360(track),
    })
    if yaw_offset_of is not None:  # only a POS unit has a yaw origin
        table["unit_yaw_offset"] = np.degrees(yaw_offset_of)
    return table


def simulate(cfg: SimConfig) -> SimulatedFlight:
    """Simulate a flight: truth, IMU, unit outputs, GNSS, exposures and the POS table (vectorised)."""
    if isinstance(cfg.plan, DronePlan):
        # imported here: the drone's assembly builds on this module's SimConfig and SimulatedFlight
        from georef.sim.drone_flight import simulate_drone

        return simulate_drone(cfg)
    rng = np.random.default_rng(cfg.seed)
    fine_rate, oversample = fine_grid_rate(cfg.pos_rate_hz)
    fine = vehicle_trajectory(cfg.plan, float(fine_rate))
    fine_time = cfg.start_utc_s + np.arange(len(fine.time)) / fine_rate
    first = int(round(cfg.first_row_offset_s * fine_rate))
    rows = np.arange(first, len(fine.time), oversample)
    nav = fine.subsample(rows)
    nav.time = fine_time[rows]
    row_time = nav.time

    model = imu_preset(cfg.imu_preset)
    gyro, accel, gyro_bias, accel_bias = corrupt_imu(nav.omega_ib_b, nav.f_ib_b, row_time, model,
                                                     cfg.vibration, rng, gyro_turn_on=cfg.gyro_bias_rad_s,
                                                     accel_turn_on=cfg.accel_bias_mps2,
                                                     gyro_scale=np.asarray(cfg.gyro_scale_ppm) * 1e-6,
                                                     accel_scale=np.asarray(cfg.accel_scale_ppm) * 1e-6)
    temperature = None
    if cfg.thermal is not None:
        temperature = add_thermal_bias(cfg.thermal, row_time - cfg.start_utc_s, gyro, accel, gyro_bias, accel_bias)
    unit = _unit_outputs(cfg, nav, accel - nav.f_ib_b, rng) if cfg.unit is not None else None
    fixes, held = _gnss(cfg, fine, fine_rate, row_time, rng)
    pos = _pos_table(cfg, nav, rows, fine_rate, _ImuRows(gyro=gyro, accel=accel, temperature=temperature), unit,
                     fixes, held)

    t0 = fixes["time"].iloc[0] + 3.0 if len(fixes) else row_time[0] + 3.0
    nominal = np.arange(t0, row_time[-1] - 3.0, 1.0 / cfg.camera_rate_hz)
    jitter = rng.uniform(-cfg.camera_jitter_ms, cfg.camera_jitter_ms, len(nominal)) / 1000.0
    frame_time = np.round((nominal + jitter) * 1000.0) / 1000.0
    exposures = pd.DataFrame({"frame": np.arange(1, len(frame_time) + 1), "time": frame_time})
    offset_at_frame = np.interp(frame_time, row_time, unit["yaw_offset"]) if unit is not None else None
    truth = frame_truth(cfg, fine, fine_time, frame_time, offset_at_frame)
    truth.insert(0, "frame", exposures["frame"].to_numpy())
    mag = autopilot = None
    if cfg.magnetometer is not None:
        mag = magnetometer(nav.C_b_n, cfg.magnetometer, np.random.default_rng((cfg.seed, MAG_STREAM)))
    if cfg.autopilot is not None:
        autopilot = autopilot_attitude(row_time, nav.roll, nav.pitch, nav.yaw, cfg.autopilot,
                                       np.random.default_rng((cfg.seed, AUTOPILOT_STREAM)))
    return SimulatedFlight(config=cfg, pos=pos, exposures=exposures, truth_frames=truth, truth_nav=nav,
                           gnss_fixes=fixes, gyro_bias=gyro_bias, accel_bias=accel_bias, mag=mag,
                           autopilot_rpy=autopilot, imu_temperature_degc=temperature)


@dataclass(frozen=True)
class _ImuRows:
    """The simulated IMU on the POS rows: ``gyro`` [rad/s] and ``accel`` [m/s^2] (N, 3, body), and the IMU
    temperature [degC] (N,) when a thermal model is simulated (None: a slow default ramp is logged)."""

    gyro: np.ndarray
    accel: np.ndarray
    temperature: np.ndarray | None


def _pos_table(cfg: SimConfig, nav: Trajectory, rows: np.ndarray, fine_rate: int, imu: _ImuRows,
               unit: dict[str, np.ndarray] | None, fixes: pd.DataFrame, held: np.ndarray) -> pd.DataFrame:
    """The POS.txt table of the simulated rows (fine-grid indices ``rows``): the IMU in the log's units, the
    unit's outputs when simulated, TRIG_TIME/SAMPL_TIME with the configured logger quirks, and the fix each row
    holds (``held``, -1: none)."""
    gyro, accel, row_time = imu.gyro, imu.accel, nav.time
    whole_s = cfg.start_utc_s + rows // fine_rate
    micro = (rows % fine_rate) * (1_000_000 // fine_rate)
    trig = (whole_s % 86400) * 100
    for quirk in cfg.trig_quirk_seconds:
        block = whole_s == cfg.start_utc_s + quirk
        if block.any() and quirk > 0:
            trig[block] = ((cfg.start_utc_s + quirk - 1) % 86400) * 100 + 1

    has_fix = held >= 0
    imu_temp = 35.0 + 0.002 * (row_time - row_time[0]) if imu.temperature is None else imu.temperature
    hold = np.where(has_fix, held, 0)
    earth_b = np.einsum("nji,nj->ni", nav.C_b_n, earth_rate_n(nav.lat))
    n = len(rows)
    unit_columns = {"IACC_X": unit["IACC"][:, 0], "IACC_Y": unit["IACC"][:, 1], "IACC_Z": unit["IACC"][:, 2],
                    "ROLL": unit["ROLL"], "PITCH": unit["PITCH"], "YAW": unit["YAW"]} if unit is not None else {}
    return pd.DataFrame({
        "CNT[HEX]": np.char.mod("%X", 0xA4 + np.arange(n)),
        "ACCS_X": accel[:, 0], "ACCS_Y": accel[:, 1], "ACCS_Z": accel[:, 2],
        **unit_columns,  # placed by the column selection below
        "OMGS_X": np.degrees(gyro[:, 0]), "OMGS_Y": np.degrees(gyro[:, 1]), "OMGS_Z": np.degrees(gyro[:, 2]),
        "IOMG_X": np.degrees(gyro[:, 0] - earth_b[:, 0]), "IOMG_Y": np.degrees(gyro[:, 1] - earth_b[:, 1]),
        "IOMG_Z": np.degrees(gyro[:, 2] - earth_b[:, 2]),
        "VELX": np.zeros(n), "ODO_TICKS": np.zeros(n, int), "MAGNMTR": np.zeros(n, int),
        "TRIG_TIME": trig, "SAMPL_TIME": micro,
        "IMU_TEMP": imu_temp, "SENS_TEMP": 33.0 + 0.002 * (row_time - row_time[0]),
        "LONGITUDE": np.where(has_fix, fixes["lon"].to_numpy()[hold], 0.0),
        "LATITUDE": np.where(has_fix, fixes["lat"].to_numpy()[hold], 0.0),
        "ALTITUDE": np.where(has_fix, fixes["height"].to_numpy()[hold], 0.0),
        "VELOCITY": np.where(has_fix, fixes["speed"].to_numpy()[hold], 0.0),
        "STATUS[HEX]": np.where(has_fix, "49", "0"),
    })[[name for name in POS_HEADER if unit is not None or name not in UNIT_COLUMNS]]


def vehicle_trajectory(plan: FlightPlan | MulticopterPlan | CarPlan | DronePlan, fine_rate_hz: float) -> Trajectory:
    """The truth and ideal IMU of the vehicle the plan's type names, on a ``fine_rate_hz`` [Hz] grid."""
    if isinstance(plan, DronePlan):
        return fly_drone(plan, fine_rate_hz).trajectory
    if isinstance(plan, MulticopterPlan):
        return fly_multicopter(plan, fine_rate_hz)
    if isinstance(plan, CarPlan):
        return drive(plan, fine_rate_hz)
    return fly(plan, fine_rate_hz)
