"""A whole simulated flight: POS log, exposure times and the truth of every frame.

``simulate(SimConfig(...))`` returns a :class:`SimulatedFlight`; :func:`georef.sim.files.write_flight`
writes it as ``POS.txt``, ``Kamera.txt``, ``truth.csv`` and a ``flight.toml`` that processes it.
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
from georef.sim.sensors import GnssModel, UnitModel, VibrationModel, corrupt_imu, gauss_markov
from georef.sim.trajectory import FlightPlan, Trajectory, fly

POS_HEADER = [
    "CNT[HEX]", "ACCS_X", "ACCS_Y", "ACCS_Z", "IACC_X", "IACC_Y", "IACC_Z", "OMGS_X", "OMGS_Y", "OMGS_Z",
    "IOMG_X", "IOMG_Y", "IOMG_Z", "ROLL", "PITCH", "YAW", "VELX", "ODO_TICKS", "MAGNMTR", "TRIG_TIME",
    "SAMPL_TIME", "IMU_TEMP", "SENS_TEMP", "LONGITUDE", "LATITUDE", "ALTITUDE", "VELOCITY", "STATUS[HEX]",
]


@dataclass
class SimConfig:
    """Everything that defines a simulated flight. Units: s, m, deg, Hz."""

    plan: FlightPlan = field(default_factory=FlightPlan)
    imu_preset: str = "mems-ivru"
    vibration: VibrationModel | None = field(default_factory=VibrationModel)
    unit: UnitModel = field(default_factory=UnitModel)
    gnss: GnssModel = field(default_factory=GnssModel)
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


@dataclass
class SimulatedFlight:
    """The simulator's output: the POS table, exposures, per-frame truth and the navigation truth."""

    config: SimConfig
    pos: pd.DataFrame
    exposures: pd.DataFrame          # frame, time [UTC s]
    truth_frames: pd.DataFrame       # per frame: camera position and attitude, deg / m
    truth_nav: Trajectory            # at POS rows, time in UTC s
    gnss_fixes: pd.DataFrame         # time, measured antenna lat/lon/height, is_outlier
    gyro_bias: np.ndarray
    accel_bias: np.ndarray


def _fine_rate(pos_rate_hz: float) -> tuple[int, int]:
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
    c, s = np.cos(yaw_offset), np.sin(yaw_offset)
    iacc = np.stack([c * a_n[:, 0] + s * a_n[:, 1], -s * a_n[:, 0] + c * a_n[:, 1], a_n[:, 2]], axis=-1)
    return {"ROLL": np.degrees(roll), "PITCH": np.degrees(pitch),
            "YAW": (np.degrees(yaw) + 180.0) % 360.0 - 180.0, "IACC": iacc, "yaw_offset": yaw_offset}


def _gnss(cfg: SimConfig, fine: Trajectory, fine_rate: int, row_time: np.ndarray,
          rng: np.random.Generator) -> tuple[pd.DataFrame, np.ndarray]:
    """Measured fixes on whole seconds and, for each POS row, the index of the fix it holds (-1: none)."""
    gnss = cfg.gnss
    period = 1.0 / gnss.rate_hz
    first = np.ceil(row_time[0] + 2.0)
    fix_time = np.arange(first, row_time[-1] - 0.5, period)
    rel = fix_time - cfg.start_utc_s
    keep = np.ones(len(fix_time), bool)
    for start, length in gnss.outages:
        keep &= ~((rel >= start) & (rel < start + length))
    fix_time, rel = fix_time[keep], rel[keep]
    idx = np.round(rel * fine_rate).astype(int)
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
    appear = fix_time + rng.uniform(*gnss.latency_s, len(fix_time))
    held = np.searchsorted(appear, row_time, side="right") - 1
    return fixes, held


def _frame_truth(cfg: SimConfig, fine: Trajectory, fine_time: np.ndarray, frame_time: np.ndarray,
                 yaw_offset_of: np.ndarray) -> pd.DataFrame:
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
    return pd.DataFrame({
        "time": frame_time, "lat": np.degrees(lat), "lon": np.degrees(lon), "height": h,
        "roll": np.degrees(roll), "pitch": np.degrees(pitch), "yaw": wrap_360(np.degrees(yaw)),
        "body_roll": np.degrees(body_roll), "body_pitch": np.degrees(body_pitch),
        "body_yaw": wrap_360(np.degrees(body_yaw)), "track": wrap_360(track),
        "unit_yaw_offset": np.degrees(yaw_offset_of),
    })


def simulate(cfg: SimConfig) -> SimulatedFlight:
    """Simulate a flight: truth, IMU, unit outputs, GNSS, exposures and the POS table (vectorised)."""
    rng = np.random.default_rng(cfg.seed)
    fine_rate, oversample = _fine_rate(cfg.pos_rate_hz)
    fine = fly(cfg.plan, float(fine_rate))
    fine_time = cfg.start_utc_s + np.arange(len(fine.time)) / fine_rate
    first = int(round(cfg.first_row_offset_s * fine_rate))
    rows = np.arange(first, len(fine.time), oversample)
    nav = fine.subsample(rows)
    nav.time = fine_time[rows]
    row_time = nav.time

    model = imu_preset(cfg.imu_preset)
    gyro, accel, gyro_bias, accel_bias = corrupt_imu(nav.omega_ib_b, nav.f_ib_b, row_time, model,
                                                     cfg.vibration, rng)
    unit = _unit_outputs(cfg, nav, accel - nav.f_ib_b, rng)
    fixes, held = _gnss(cfg, fine, fine_rate, row_time, rng)

    whole_s = cfg.start_utc_s + rows // fine_rate
    micro = (rows % fine_rate) * (1_000_000 // fine_rate)
    trig = (whole_s % 86400) * 100
    for quirk in cfg.trig_quirk_seconds:
        block = whole_s == cfg.start_utc_s + quirk
        if block.any() and quirk > 0:
            trig[block] = ((cfg.start_utc_s + quirk - 1) % 86400) * 100 + 1

    has_fix = held >= 0
    hold = np.where(has_fix, held, 0)
    earth_b = np.einsum("nji,nj->ni", nav.C_b_n, earth_rate_n(nav.lat))
    n = len(rows)
    pos = pd.DataFrame({
        "CNT[HEX]": np.char.mod("%X", 0xA4 + np.arange(n)),
        "ACCS_X": accel[:, 0], "ACCS_Y": accel[:, 1], "ACCS_Z": accel[:, 2],
        "IACC_X": unit["IACC"][:, 0], "IACC_Y": unit["IACC"][:, 1], "IACC_Z": unit["IACC"][:, 2],
        "OMGS_X": np.degrees(gyro[:, 0]), "OMGS_Y": np.degrees(gyro[:, 1]), "OMGS_Z": np.degrees(gyro[:, 2]),
        "IOMG_X": np.degrees(gyro[:, 0] - earth_b[:, 0]), "IOMG_Y": np.degrees(gyro[:, 1] - earth_b[:, 1]),
        "IOMG_Z": np.degrees(gyro[:, 2] - earth_b[:, 2]),
        "ROLL": unit["ROLL"], "PITCH": unit["PITCH"], "YAW": unit["YAW"],
        "VELX": np.zeros(n), "ODO_TICKS": np.zeros(n, int), "MAGNMTR": np.zeros(n, int),
        "TRIG_TIME": trig, "SAMPL_TIME": micro,
        "IMU_TEMP": 35.0 + 0.002 * (row_time - row_time[0]), "SENS_TEMP": 33.0 + 0.002 * (row_time - row_time[0]),
        "LONGITUDE": np.where(has_fix, fixes["lon"].to_numpy()[hold], 0.0),
        "LATITUDE": np.where(has_fix, fixes["lat"].to_numpy()[hold], 0.0),
        "ALTITUDE": np.where(has_fix, fixes["height"].to_numpy()[hold], 0.0),
        "VELOCITY": np.where(has_fix, fixes["speed"].to_numpy()[hold], 0.0),
        "STATUS[HEX]": np.where(has_fix, "49", "0"),
    })[POS_HEADER]

    t0 = fixes["time"].iloc[0] + 3.0 if len(fixes) else row_time[0] + 3.0
    nominal = np.arange(t0, row_time[-1] - 3.0, 1.0 / cfg.camera_rate_hz)
    jitter = rng.uniform(-cfg.camera_jitter_ms, cfg.camera_jitter_ms, len(nominal)) / 1000.0
    frame_time = np.round((nominal + jitter) * 1000.0) / 1000.0
    exposures = pd.DataFrame({"frame": np.arange(1, len(frame_time) + 1), "time": frame_time})
    offset_at_frame = np.interp(frame_time, row_time, unit["yaw_offset"])
    truth = _frame_truth(cfg, fine, fine_time, frame_time, offset_at_frame)
    truth.insert(0, "frame", exposures["frame"].to_numpy())
    return SimulatedFlight(config=cfg, pos=pos, exposures=exposures, truth_frames=truth, truth_nav=nav,
                           gnss_fixes=fixes, gyro_bias=gyro_bias, accel_bias=accel_bias)
