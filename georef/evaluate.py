"""Accuracy against a reference: per-frame errors, RMS figures, sigma coverage, and the naive baseline.

Used by the tests, the benchmarks and ``georef evaluate`` on any pair of EO tables (estimate, truth).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from georef.config import MountingSection, OutputSection
from georef.eo import camera_eo_table
from georef.exposure import ExposureStates
from georef.frames import C_e_n, geodetic_to_ecef, wrap_pi
from georef.frames.mounting import lever_arm_ecef
from georef.frames.rotations import attitude_at
from georef.fusion.solution import NavSolution
from georef.io.camera import Exposures
from georef.timing import GnssEpochs

ANGLES = ("roll", "pitch", "yaw")


def frame_errors(estimate: pd.DataFrame, truth: pd.DataFrame) -> pd.DataFrame:
    """Errors of ``estimate`` against ``truth`` (matched by row order and time): NED metres, angles deg."""
    if len(estimate) != len(truth) or not np.allclose(estimate["time"], truth["time"], atol=1e-6):
        raise ValueError("estimate and truth must list the same frames at the same times")
    lat_t, lon_t = np.radians(truth["lat"].to_numpy()), np.radians(truth["lon"].to_numpy())
    r_true = geodetic_to_ecef(lat_t, lon_t, truth["height"].to_numpy())
    r_est = geodetic_to_ecef(np.radians(estimate["lat"].to_numpy()), np.radians(estimate["lon"].to_numpy()),
                             estimate["height"].to_numpy())
    err_n = np.einsum("nij,nj->ni", C_e_n(lat_t, lon_t), r_est - r_true)
    out = pd.DataFrame({"frame": estimate["frame"].to_numpy(), "time": estimate["time"].to_numpy(),
                        "north": err_n[:, 0], "east": err_n[:, 1], "up": -err_n[:, 2]})
    for angle in ANGLES:
        out[angle] = np.degrees(wrap_pi(np.radians(estimate[angle].to_numpy() - truth[angle].to_numpy())))
    return out


def accuracy(errors: pd.DataFrame) -> dict[str, float]:
    """RMS figures [m, deg] of :func:`frame_errors` output, ignoring frames without values."""
    ok = errors[["north", "east", "up"]].notna().all(axis=1)
    e = errors[ok]
    out = {"horizontal_rms_m": float(np.sqrt(np.mean(e["north"] ** 2 + e["east"] ** 2))),
           "vertical_rms_m": float(np.sqrt(np.mean(e["up"] ** 2)))}
    for angle in ANGLES:
        out[f"{angle}_rms_deg"] = float(np.sqrt(np.mean(e[angle] ** 2)))
    return out


def sigma_coverage(estimate: pd.DataFrame, errors: pd.DataFrame, k: float = 2.0) -> dict[str, float]:
    """Share of frames whose error lies inside +-k sigma, per EO component."""
    pairs = {"north": "sigma_n", "east": "sigma_e", "up": "sigma_u", "roll": "sigma_roll",
             "pitch": "sigma_pitch", "yaw": "sigma_yaw"}
    out = {}
    for component, sigma in pairs.items():
        ok = errors[component].notna() & estimate[sigma].notna()
        out[component] = float(np.mean(np.abs(errors[component][ok]) <= k * estimate[sigma][ok]))
    return out


def gnss_interpolation_baseline(exposures: Exposures, gnss: GnssEpochs, nav: NavSolution, mounting: MountingSection,
                                output: OutputSection | None = None) -> pd.DataFrame:
    """The pre-thesis practice, improved by the lever arms: GNSS antenna fixes linearly interpolated in ECEF
    to the exposure times, moved to the camera through both lever arms of ``mounting`` [m, body] with the attitude
    of ``nav``; the table's coordinates as ``output`` asks (default WGS 84 ellipsoidal)."""
    row_time = nav.time
    r_ant = geodetic_to_ecef(np.radians(gnss.lat_deg), np.radians(gnss.lon_deg), gnss.height)
    t = exposures.time
    inside = (t >= max(gnss.time[0], row_time[0])) & (t <= min(gnss.time[-1], row_time[-1]))
    r_at = np.stack([np.interp(t[inside], gnss.time, r_ant[:, k]) for k in range(3)], -1)
    C_b_n = attitude_at(row_time, nav.roll, nav.pitch, nav.yaw, t[inside])
    lat = np.radians(np.interp(t[inside], gnss.time, gnss.lat_deg))
    lon = np.radians(np.interp(t[inside], gnss.time, gnss.lon_deg))
    r_imu = r_at - lever_arm_ecef(lat, lon, C_b_n, mounting.lever_arm_gnss)
    n = len(t)
    states = ExposureStates(time=t, inside=inside, r_e=np.full((n, 3), np.nan), v_e=np.full((n, 3), np.nan),
                            C_b_n=np.full((n, 3, 3), np.nan), pos_var_n=np.full((n, 3), np.nan),
                            att_sigma=np.full((n, 3), np.nan))
    states.r_e[inside] = r_imu
    states.v_e[inside] = 0.0
    states.C_b_n[inside] = C_b_n
    return camera_eo_table(exposures, states, gnss, mounting, output)
