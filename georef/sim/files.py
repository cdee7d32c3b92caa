"""Write a simulated flight as the files a user holds, plus the truth and a matching flight.toml.

A helicopter, multicopter or car flight: :func:`write_flight` (POS.txt, Kamera.txt, truth.csv, flight.toml) and
:func:`write_generic` (imu.csv, gnss.csv, truth_traj.csv). A drone's log has no POS.txt: :func:`write_generic`
writes imu.csv, gnss.csv (arrival time tags, the receiver's reported sigmas), events.csv (logged trigger times),
truth.csv (at the true exposures) and truth_traj.csv; :func:`write_processing_config` its flight.toml.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from georef.config import (
    CameraSection,
    GnssSection,
    InsSection,
    MountingSection,
    OutputSection,
    ProcessingConfig,
    UnitSection,
    config_to_toml,
)
from georef.frames import wrap_360
from georef.io.atomic import atomic_write
from georef.sim.flight import SimulatedFlight
from georef.sim.receiver import ReceiverGnssModel

#: Decimals written per POS column (about what the iMAR export carries, GNSS to 1 mm).
_DECIMALS = {"ACCS": 5, "IACC": 5, "OMGS": 5, "IOMG": 5, "ROLL": 5, "PITCH": 5, "YAW": 5,
             "LONGITUDE": 9, "LATITUDE": 9, "ALTITUDE": 4, "VELOCITY": 3, "IMU_TEMP": 2, "SENS_TEMP": 2}


def _rounded(pos: pd.DataFrame) -> pd.DataFrame:
    out = pos.copy()
    for column in out.columns:
        key = column.split("_")[0] if column.split("_")[0] in _DECIMALS else column
        if key in _DECIMALS:
            out[column] = np.round(out[column].to_numpy(float), _DECIMALS[key])
    return out


def processing_config_for(flight: SimulatedFlight, crs: str | None = None) -> ProcessingConfig:
    """The processing configuration that matches the simulated installation (a drone's: its GNSS latency and
    camera trigger latency too)."""
    cfg = flight.config
    unit = UnitSection() if cfg.unit is None else UnitSection(
        level_sigma=cfg.unit.level_error_deg, level_time=cfg.unit.level_error_corr_s,
        angle_noise=cfg.unit.angle_noise_deg, drift_change=0.01)
    if isinstance(cfg.gnss, ReceiverGnssModel):  # the drone's receiver: true sigma, arrival latency
        gnss = GnssSection(sigma=cfg.gnss.total_sigma_neu_m, rate_hz=cfg.gnss.rate_hz, latency=cfg.gnss.latency_s)
    else:
        gnss = GnssSection(sigma=cfg.gnss.sigma_neu_m, rate_hz=cfg.gnss.rate_hz)
    camera = CameraSection(time_offset=cfg.camera_trigger.latency_s) if cfg.camera_trigger is not None else \
        CameraSection()
    return ProcessingConfig(mounting=_mounting(flight), gnss=gnss, output=OutputSection(crs=crs),
                            ins=InsSection(imu_preset=cfg.imu_preset), unit=unit, camera=camera)


def _mounting(flight: SimulatedFlight) -> MountingSection:
    """The simulated installation's lever arms [m, body] and boresight [deg]."""
    cfg = flight.config
    return MountingSection(lever_arm_gnss=cfg.lever_arm_gnss_m, lever_arm_camera=cfg.lever_arm_camera_m,
                           boresight=cfg.boresight_deg)


def installation_config(flight: SimulatedFlight, crs: str | None = None) -> ProcessingConfig:
    """Only what a user knows of the installation: lever arms, boresight, the GNSS rate of the log and the
    output CRS. Everything else, the IMU's noise and biases, the GNSS sigmas, the unit's errors, stays at the
    defaults; the tests and benchmarks of the full-state filters run with this (no tuning to the simulator)."""
    cfg = flight.config
    return ProcessingConfig(mounting=_mounting(flight), gnss=GnssSection(rate_hz=cfg.gnss.rate_hz),
                            output=OutputSection(crs=crs))


def write_flight(flight: SimulatedFlight, folder: Path | str, crs: str | None = None) -> dict[str, Path]:
    """Write ``POS.txt``, ``Kamera.txt``, ``truth.csv`` and ``flight.toml`` into ``folder``.

    A drone's flight has no POS log: write it with :func:`write_generic` and :func:`write_processing_config`.
    """
    if flight.config.vehicle == "drone":
        raise ValueError("a drone flight has no POS.txt / Kamera.txt: write it with write_generic (imu.csv, "
                         "gnss.csv, events.csv, truth.csv) and write_processing_config (flight.toml)")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = {name: folder / name for name in ("POS.txt", "Kamera.txt", "truth.csv", "flight.toml")}
    with atomic_write(paths["POS.txt"]) as handle:
        _rounded(flight.pos).to_csv(handle, sep="\t", index=False, lineterminator="\n")
    seconds = np.floor(flight.exposures["time"].to_numpy() + 1e-9).astype(int)
    millis = np.round((flight.exposures["time"].to_numpy() - seconds) * 1000).astype(int)
    kamera = pd.DataFrame({"Number": flight.exposures["frame"], "Time": seconds % 86400, "Milliseconds": millis})
    with atomic_write(paths["Kamera.txt"]) as handle:
        kamera.to_csv(handle, sep="\t", index=False, lineterminator="\n")
    _write_truth_frames(flight, paths["truth.csv"])
    write_processing_config(flight, folder, crs)
    return paths


def write_processing_config(flight: SimulatedFlight, folder: Path | str, crs: str | None = None) -> Path:
    """Write ``flight.toml`` (:func:`processing_config_for`) into ``folder``; returns its path."""
    path = Path(folder) / "flight.toml"
    with atomic_write(path) as handle:
        handle.write("# Processing settings matching the simulated installation (georef simulate).\n")
        handle.write(config_to_toml(processing_config_for(flight, crs)))
    return path


def _write_truth_frames(flight: SimulatedFlight, path: Path) -> None:
    with atomic_write(path) as handle:
        flight.truth_frames.to_csv(handle, index=False, float_format="%.10g", lineterminator="\n")


def write_generic(flight: SimulatedFlight, folder: Path | str) -> dict[str, Path]:
    """Write the flight as the generic inputs: ``imu.csv``, ``gnss.csv`` and ``truth_traj.csv`` (IMU truth).

    ``imu.csv``: ``time`` [s], ``gyro_x..z`` [rad/s], ``acc_x..z`` [m/s^2] (body x forward, y right, z down);
    when the flight has them (``SimConfig.magnetometer`` / ``SimConfig.autopilot`` / ``SimConfig.thermal``),
    also ``mag_x, mag_y, mag_z`` [uT, body axes], the autopilot's ``roll, pitch, yaw`` [deg, ZYX to NED, yaw in
    [0, 360) from true north] and the IMU board's ``temperature`` [degC]. ``gnss.csv``: ``time, lat, lon,
    height, sigma_n, sigma_e, sigma_u`` (deg, m) of the antenna at every fix (any GNSS rate; a drone's: the
    logged arrival time and the receiver's reported sigmas). ``truth_traj.csv``: the IMU's true position, NED
    velocity and attitude. A drone flight with exposures also gets ``events.csv`` (``time`` [s, the IMU's time
    scale] when the trigger was logged, ``image``) and ``truth.csv`` (the camera's truth at each real exposure,
    a latency after its event; frame k is row k of events.csv).
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    pos = flight.pos
    nav = flight.truth_nav
    imu = pd.DataFrame({"time": nav.time,
                        "gyro_x": np.radians(pos["OMGS_X"]), "gyro_y": np.radians(pos["OMGS_Y"]),
                        "gyro_z": np.radians(pos["OMGS_Z"]),
                        "acc_x": pos["ACCS_X"], "acc_y": pos["ACCS_Y"], "acc_z": pos["ACCS_Z"]})
    if flight.mag is not None:
        imu["mag_x"], imu["mag_y"], imu["mag_z"] = flight.mag[:, 0], flight.mag[:, 1], flight.mag[:, 2]
    if flight.autopilot_rpy is not None:
        rpy = np.degrees(flight.autopilot_rpy)
        imu["roll"], imu["pitch"], imu["yaw"] = rpy[:, 0], rpy[:, 1], wrap_360(rpy[:, 2])
    if flight.imu_temperature_degc is not None:
        imu["temperature"] = flight.imu_temperature_degc
    fixes = flight.gnss_fixes
    if {"sigma_n", "sigma_e", "sigma_u"} <= set(fixes.columns):  # each fix's reported accuracy
        sigma = (fixes["sigma_n"], fixes["sigma_e"], fixes["sigma_u"])
    else:
        sigma = flight.config.gnss.sigma_neu_m
    gnss = pd.DataFrame({"time": fixes["time"], "lat": fixes["lat"], "lon": fixes["lon"], "height": fixes["height"],
                         "sigma_n": sigma[0], "sigma_e": sigma[1], "sigma_u": sigma[2]})
    truth = pd.DataFrame({"time": nav.time, "lat": np.degrees(nav.lat), "lon": np.degrees(nav.lon),
                          "height": nav.height, "vn": nav.v_n[:, 0], "ve": nav.v_n[:, 1], "vd": nav.v_n[:, 2],
                          "roll": np.degrees(nav.roll), "pitch": np.degrees(nav.pitch),
                          "yaw": np.degrees(nav.yaw) % 360.0})
    tables = {"imu.csv": imu, "gnss.csv": gnss, "truth_traj.csv": truth}
    if flight.config.vehicle == "drone" and len(flight.exposures):
        tables["events.csv"] = flight.exposures[["time", "image"]]
    paths = {name: folder / name for name in tables}
    for name, table in tables.items():
        with atomic_write(paths[name]) as handle:
            table.to_csv(handle, index=False, float_format="%.12g", lineterminator="\n")
    if "events.csv" in tables:
        paths["truth.csv"] = folder / "truth.csv"
        _write_truth_frames(flight, paths["truth.csv"])
    return paths
