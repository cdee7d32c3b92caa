"""A simulated block for the boresight calibration (``docs/boresight.md``): a flight processed with a *wrong*
boresight and camera lever arm, and the "adjusted" cameras a bundle adjustment would give (the simulator's true
camera poses plus adjustment noise), written as Metashape, Pix4D or ODM files.

The EO carries the real INS errors of georef's own processing of the simulated IMU and GNSS; the truth's
boresight and lever arm minus the configured ones are the corrections a calibration must find.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from georef.frames import euler_to_dcm
from georef.frames.calibration import C_i_o
from georef.frames.mapping import MapProjection
from georef.frames.photogrammetry import image_to_map, rotation_to_opk
from georef.frames.rotations import dcm_to_quat, quat_to_rotvec
from georef.sim.flight import SimConfig, simulate
from georef.sim.multicopter import MulticopterPlan
from georef.sim.trajectory import FlightPlan

if TYPE_CHECKING:
    from georef.calibration.boresight import MatchedPhotos

#: UTM zone 33N: the simulator's flights start at 15.62 E
BLOCK_CRS = "EPSG:32633"
IMAGE_NAMES = "IMG_{frame:04d}.JPG"


@dataclass
class SimulatedBlock:
    """``eo``: the EO table (DataFrame) processed with ``configured_boresight_deg`` and
    ``configured_lever_arm_m``; ``truth``: the simulator's per-frame camera truth; the true mounting;
    ``process_summary``: the run's figures (``ProcessResult.summary()``, what ``georef process --summary-json``
    writes under ``summary``); ``accel_bias_error_m_s2`` (N, 3) the filter's accelerometer bias minus the
    simulator's [m/s^2, body] at the POS rows, ``row_time`` (N,) their times [s UTC of day] (NaN where the filter
    did not solve)."""

    eo: pd.DataFrame
    truth: pd.DataFrame
    configured_boresight_deg: tuple[float, float, float]
    configured_lever_arm_m: tuple[float, float, float]
    true_boresight_deg: tuple[float, float, float]
    true_lever_arm_m: tuple[float, float, float]
    process_summary: dict
    accel_bias_error_m_s2: np.ndarray
    row_time: np.ndarray


def cross_strip_plan(seed: int, legs: int = 10, leg_length_m: float = 300.0, speed_mps: float = 10.0
                     ) -> MulticopterPlan:
    """A multicopter block: legs along north and south, then east and west (cross strips), heading along the
    track, at one height."""
    directions = tuple((0.0, 180.0)[k % 2] if k < legs // 2 + legs % 2 else (90.0, 270.0)[k % 2]
                       for k in range(legs))
    duration = 25.0 + legs * (leg_length_m / speed_mps + 12.0)
    return MulticopterPlan(duration_s=duration, seed=seed, heading_policy="track", leg_directions_deg=directions,
                           leg_heights_m=(80.0,) * legs, leg_length_m=leg_length_m, speed_mps=speed_mps,
                           second_hover_after_leg=-1)


def simulate_block(seed: int, boresight_error_deg: tuple[float, float, float],
                   lever_arm_error_m: tuple[float, float, float], vehicle: str = "multicopter",
                   duration_s: float = 400.0, camera_time_offset_s: float = 0.0, legs: int = 10) -> SimulatedBlock:
    """Simulate a flight (``multicopter``: :func:`cross_strip_plan` with ``legs`` legs; ``helicopter``: parallel
    strips in opposite headings, ``duration_s``), process it with the true mounting minus the given errors (and a
    camera time offset [s] the exposures do not have: an unmodelled trigger latency of minus that), keep its
    truth."""
    from georef.pipeline import process
    from georef.sim.files import processing_config_for, write_flight

    if vehicle == "multicopter":
        plan = cross_strip_plan(seed, legs=legs)
        cfg = SimConfig.for_vehicle("multicopter", duration_s=plan.duration_s, seed=seed, plan=plan)
    else:
        cfg = SimConfig(plan=FlightPlan(duration_s=duration_s, seed=seed), seed=seed)
    flight = simulate(cfg)
    true_boresight = tuple(float(v) for v in cfg.boresight_deg)
    true_lever = tuple(float(v) for v in cfg.lever_arm_camera_m)
    configured_boresight = tuple(float(t - e) for t, e in zip(true_boresight, boresight_error_deg, strict=True))
    configured_lever = tuple(float(t - e) for t, e in zip(true_lever, lever_arm_error_m, strict=True))
    import tempfile

    with tempfile.TemporaryDirectory(prefix="georef-block-") as folder:
        paths = write_flight(flight, folder)
        processing = processing_config_for(flight).updated(boresight=configured_boresight,
                                                           lever_arm_camera=configured_lever,
                                                           image_names=IMAGE_NAMES,
                                                           camera_time_offset=camera_time_offset_s or None)
        result = process(paths["POS.txt"], paths["Kamera.txt"], processing)
    eo = result.table.copy()
    bias_error = np.full(np.shape(flight.accel_bias), np.nan)
    if result.nav.ins_info is not None:
        solved = np.asarray(result.nav.valid, bool)
        bias_error[solved] = (result.nav.ins_info.accel_bias - flight.accel_bias)[solved]
    return SimulatedBlock(eo=eo, truth=flight.truth_frames.copy(), configured_boresight_deg=configured_boresight,
                          configured_lever_arm_m=configured_lever, true_boresight_deg=true_boresight,
                          true_lever_arm_m=true_lever, process_summary=result.summary(),
                          accel_bias_error_m_s2=bias_error, row_time=np.asarray(result.nav.time, float))


def adjusted_cameras(truth: pd.DataFrame, rng: np.random.Generator, sigma_position_m: float = 0.015,
                     sigma_angle_deg: float = 0.003, crs: str = BLOCK_CRS) -> pd.DataFrame:
    """The truth's cameras as a bundle adjustment gives them: label, easting, northing, height [m] and
    ``R_i_m`` in ``crs``, with independent noise of ``sigma_position_m`` per axis and ``sigma_angle_deg`` per
    axis of the camera frame."""
    projection = MapProjection(crs)
    lat, lon = truth["lat"].to_numpy(float), truth["lon"].to_numpy(float)
    easting, northing = projection.forward(lat, lon)
    convergence, _ = projection.convergence_and_scale(lat, lon)
    n = len(truth)
    noise = rng.normal(0.0, sigma_position_m, (n, 3))
    C_c_n = euler_to_dcm(*(np.radians(truth[c].to_numpy(float)) for c in ("roll", "pitch", "yaw")))
    from georef.frames.rotations import rotvec_to_dcm

    C_c_n = C_c_n @ rotvec_to_dcm(rng.normal(0.0, np.radians(sigma_angle_deg), (n, 3)))
    R_i_m = image_to_map(C_c_n, convergence)
    frames = truth["frame"].to_numpy()
    return pd.DataFrame({"label": [IMAGE_NAMES.format(frame=int(f)) for f in frames],
                         "easting": easting + noise[:, 0], "northing": northing + noise[:, 1],
                         "height": truth["height"].to_numpy(float) + noise[:, 2], "R_i_m": list(R_i_m)})


def write_adjusted(cameras: pd.DataFrame, path: Path | str, fmt: str) -> Path:
    """Write ``cameras`` (:func:`adjusted_cameras`) as a Metashape Reference export with estimated columns, a
    Pix4D calibrated external camera parameters file or an ODM shots.geojson."""
    path = Path(path)
    R = np.array(list(cameras["R_i_m"]))
    omega, phi, kappa = (np.degrees(a) for a in rotation_to_opk(R))
    if fmt == "metashape":
        rows = [f"# Cameras ({len(cameras)})",
                "#Label,X/Easting,Y/Northing,Z/Altitude,Omega,Phi,Kappa,X_est,Y_est,Z_est,Omega_est,Phi_est,Kappa_est"]
        for k, r in enumerate(cameras.itertuples(index=False)):
            # the measured (reference) values are the EO-like a priori ones; only the _est columns are adjusted
            rows.append(f"{r.label},{r.easting + 1.0:.4f},{r.northing - 1.0:.4f},{r.height + 2.0:.4f},0,0,0,"
                        f"{r.easting:.4f},{r.northing:.4f},{r.height:.4f},{omega[k]:.7f},{phi[k]:.7f},{kappa[k]:.7f}")
        path.write_text("\n".join(rows) + "\n", encoding="utf-8")
    elif fmt == "pix4d":
        rows = ["imageName X Y Z Omega Phi Kappa"]
        for k, r in enumerate(cameras.itertuples(index=False)):
            rows.append(f"{r.label} {r.easting:.6f} {r.northing:.6f} {r.height:.6f} {omega[k]:.9f} {phi[k]:.9f} "
                        f"{kappa[k]:.9f}")
        path.write_text("\n".join(rows) + "\n", encoding="utf-8")
    elif fmt == "odm":
        features = []
        for k, r in enumerate(cameras.itertuples(index=False)):
            R_world_to_o = C_i_o @ R[k].T
            rotation = quat_to_rotvec(dcm_to_quat(R_world_to_o))
            features.append({"type": "Feature", "properties": {
                "filename": r.label, "camera": "sim", "translation": [r.easting, r.northing, r.height],
                "rotation": [float(v) for v in rotation]}, "geometry": {"type": "Point", "coordinates": [0, 0, 0]}})
        path.write_text(json.dumps({"type": "FeatureCollection", "features": features}), encoding="utf-8")
    else:
        raise ValueError(f"unknown format {fmt!r}")
    return path


def body_fixed_tilt_deg(block: SimulatedBlock, photos: MatchedPhotos) -> np.ndarray:
    """The INS tilt error averaged over the strips in the *body* frame (about body x, y) [deg], from the truth's
    body attitude: the part of the INS error that adds onto the boresight roll and pitch on every heading."""
    return _strip_averaged_errors(block, photos).body_tilt_deg


def accel_bias_tilt_deg(block: SimulatedBlock, photos: MatchedPhotos) -> np.ndarray:
    """The body-fixed tilt (about body x, y) [deg] the filter's accelerometer-bias error predicts
    (:func:`georef.frames.calibration.accel_bias_body_tilt`), averaged like :func:`body_fixed_tilt_deg`: the
    bias error at the photos' times, strip means, their mean."""
    from georef.calibration.boresight import split_strips
    from georef.frames.calibration import accel_bias_body_tilt

    solved = np.all(np.isfinite(block.accel_bias_error_m_s2), axis=1)
    error = np.column_stack([np.interp(photos.time, block.row_time[solved], block.accel_bias_error_m_s2[solved, k])
                             for k in range(3)])
    tilt = accel_bias_body_tilt(error, photos.gravity_m_s2)
    strips = split_strips(photos.time, photos.heading_deg, photos.roll_deg)
    means = np.array([tilt[strips.index == s].mean(axis=0) for s in range(strips.count)])
    return np.degrees(means.mean(axis=0)[:2])


def flight_yaw_error_deg(block: SimulatedBlock, photos: MatchedPhotos) -> float:
    """The INS yaw error ``eps_D`` (``C_b_n_true = exp([eps x]) C_b_n_eo``, about NED down) averaged over the
    strips [deg]: the part that adds onto the boresight yaw."""
    return float(_strip_averaged_errors(block, photos).yaw_deg)


@dataclass
class _StripAveragedErrors:
    body_tilt_deg: np.ndarray
    yaw_deg: float


def _strip_averaged_errors(block: SimulatedBlock, photos: MatchedPhotos) -> _StripAveragedErrors:
    from georef.calibration.boresight import split_strips

    eo = block.eo.set_index("image").loc[list(photos.label)]
    truth = block.truth.set_index("frame").loc[eo["frame"].astype(int)]
    C_b_n_eo = photos.C_c_n_eo @ euler_to_dcm(*np.radians(block.configured_boresight_deg)).T
    C_b_n_true = euler_to_dcm(*(np.radians(truth[c].to_numpy(float)) for c in ("body_roll", "body_pitch",
                                                                                "body_yaw")))
    eps_b = quat_to_rotvec(dcm_to_quat(np.swapaxes(C_b_n_eo, -1, -2) @ C_b_n_true))  # body-frame INS error
    eps_n = quat_to_rotvec(dcm_to_quat(C_b_n_true @ np.swapaxes(C_b_n_eo, -1, -2)))  # NED INS error
    strips = split_strips(photos.time, photos.heading_deg, photos.roll_deg)
    means = np.array([eps_b[strips.index == s].mean(axis=0) for s in range(strips.count)])
    yaw = np.mean([eps_n[strips.index == s, 2].mean() for s in range(strips.count)])
    return _StripAveragedErrors(np.degrees(means.mean(axis=0)[:2]), float(np.degrees(yaw)))
