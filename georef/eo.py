"""Exterior orientation of every frame: lever arm and boresight applied, sigmas propagated, flags set.

Columns (``docs/formats.md``): ``frame`` [+ ``image`` with image names], ``time, lat, lon, height, roll, pitch,
yaw, sigma_n, sigma_e, sigma_u, sigma_roll, sigma_pitch, sigma_yaw, track, yaw_minus_track``
[+ ``height_orthometric`` with orthometric heights] [+ ``easting, northing, omega, phi, kappa, sigma_x, sigma_y,
sigma_omega, sigma_phi, sigma_kappa`` with a CRS], ``flag``.
Angles in degrees (yaw and track in [0, 360)), ``height`` ellipsoidal [m], sigmas 1-sigma in m and deg;
``sigma_x``, ``sigma_y`` along the grid's easting and northing axes (grid metres), ``sigma_omega..kappa`` of the
photogrammetric angles (:mod:`georef.frames.opk_covariance`).
Roll, pitch and yaw are the ZYX Euler angles of the *camera* frame relative to local NED.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from georef.config import MountingSection, OutputSection
from georef.exposure import ExposureStates
from georef.frames import C_e_n, dcm_to_euler, ecef_to_geodetic, skew, wrap_360
from georef.frames.mounting import camera_attitude, lever_arm_ecef, lever_arm_offset
from georef.frames.rotations import euler_error_jacobian
from georef.io.camera import Exposures, repeated_frames
from georef.io.image_names import ImageNames
from georef.timing import GnssEpochs

if TYPE_CHECKING:
    from collections.abc import Mapping

    import pandas as pd

    from georef.frames.heights import OutputFrames

#: an EO table as columns (name -> one value per exposure, in the order of ``docs/formats.md``): what the CLI
#: checks and writes without pandas (its import is slow: docs/performance.md, "Imports"); :func:`eo_frame` makes the
#: DataFrame
EoColumns = dict[str, np.ndarray]

EO_COLUMNS = ["frame", "time", "lat", "lon", "height", "roll", "pitch", "yaw", "sigma_n", "sigma_e", "sigma_u",
              "sigma_roll", "sigma_pitch", "sigma_yaw", "track", "yaw_minus_track"]

FLAG_OUTSIDE = "outside navigation span"
FLAG_OUTAGE = "in GNSS outage"
#: between IMU rows farther apart than the log's rows (rows lost or deleted): "in IMU gap (0.92 s)"; the sigmas
#: there carry the flight's own motion over that span (georef.exposure.gap_departure)
FLAG_IMU_GAP = "in IMU gap"
#: within a second (or the gap's length) of an IMU gap: "near an IMU gap (0.92 s)"
FLAG_NEAR_IMU_GAP = "near an IMU gap"
FLAG_DUPLICATE = "duplicate frame number"
FLAG_ORDER = "time earlier than previous frame"
#: inertial only at the ends of the log: "after the last GNSS fix (12 s of inertial only)"
FLAG_AFTER_LAST_FIX = "after the last GNSS fix"
FLAG_BEFORE_FIRST_FIX = "before the first GNSS fix"
FLAG_NO_SIGMA = "no valid sigma (the solution's covariance is broken here; do not use)"


def _flags(exposures: Exposures, states: ExposureStates, gnss: GnssEpochs, outage_min_s: float) -> np.ndarray:
    flags: list[list[str]] = [[] for _ in range(len(exposures))]
    problem = exposures.problem if exposures.problem is not None else np.full(len(exposures), "", dtype=object)
    for i in np.flatnonzero(~states.inside):
        # a row without a usable time (a cut-short line) says why instead of "outside the span"
        flags[i].append(problem[i] or FLAG_OUTSIDE)
    for start, end in gnss.gaps():
        if end - start >= outage_min_s:
            for i in np.flatnonzero(states.inside & (exposures.time > start) & (exposures.time < end)):
                flags[i].append(f"{FLAG_OUTAGE} ({end - start:.0f} s)")
    if len(gnss.time):
        # a GNSS outage that runs to the end of the log (or from its start): inertial only, from or to the fix
        first, last = float(np.min(gnss.time)), float(np.max(gnss.time))
        for i in np.flatnonzero(states.inside & (exposures.time > last + outage_min_s)):
            flags[i].append(f"{FLAG_AFTER_LAST_FIX} ({exposures.time[i] - last:.0f} s of inertial only)")
        for i in np.flatnonzero(states.inside & (exposures.time < first - outage_min_s)):
            flags[i].append(f"{FLAG_BEFORE_FIRST_FIX} ({first - exposures.time[i]:.0f} s of inertial only)")
    if states.imu_gap_s is not None:
        for i in np.flatnonzero(states.inside & (states.imu_gap_s > 0.0)):
            flags[i].append(f"{FLAG_IMU_GAP} ({states.imu_gap_s[i]:.2f} s)")
    if states.near_imu_gap_s is not None:
        for i in np.flatnonzero(states.inside & (states.near_imu_gap_s > 0.0)):
            flags[i].append(f"{FLAG_NEAR_IMU_GAP} ({states.near_imu_gap_s[i]:.2f} s)")
    for i in np.flatnonzero(repeated_frames(exposures.frame)):
        flags[i].append(FLAG_DUPLICATE)
    for i in np.flatnonzero(np.diff(exposures.time) < 0) + 1:
        flags[i].append(FLAG_ORDER)
    return np.array(["; ".join(f) for f in flags], dtype=object)


def flag_mask(table: Mapping[str, object], text: str) -> np.ndarray:
    """Rows of an EO table (columns or a DataFrame) whose flag contains ``text``."""
    flags = np.asarray(table["flag"], dtype=str)
    return np.char.find(flags, text) >= 0 if len(flags) else np.zeros(0, dtype=bool)


def eo_frame(columns: EoColumns) -> pd.DataFrame:
    """The EO table ``columns`` as a pandas DataFrame (text columns as pandas' string dtype)."""
    import pandas as pd

    return pd.DataFrame(columns)


def camera_eo_table(exposures: Exposures, states: ExposureStates, gnss: GnssEpochs, mounting: MountingSection,
                    output: OutputSection | None = None, outage_min_s: float = 2.5, frames: OutputFrames | None = None,
                    image_names: ImageNames | None = None) -> pd.DataFrame:
    """The EO table of every exposure as a DataFrame (:func:`camera_eo_columns`, which says what is in it)."""
    return eo_frame(camera_eo_columns(exposures, states, gnss, mounting, output, outage_min_s, frames, image_names))


def camera_eo_columns(exposures: Exposures, states: ExposureStates, gnss: GnssEpochs, mounting: MountingSection,
                      output: OutputSection | None = None, outage_min_s: float = 2.5,
                      frames: OutputFrames | None = None, image_names: ImageNames | None = None,
                      position_lag_s: float = 0.0) -> EoColumns:
    """The EO table of every exposure, as columns (rows outside the navigation span have empty values and a flag).

    ``position_lag_s`` [s]: a GNSS latency the run did not apply (:func:`georef.qc.unapplied_latency`); each
    camera position's variance gains the IMU's velocity times it, squared.

    Flags (joined by ``"; "``): outside the navigation span; in a GNSS outage of at least ``outage_min_s`` [s];
    between IMU rows farther apart than the log's (an IMU gap, with its length) or near such a gap;
    more than ``outage_min_s`` after the last GNSS fix or before the first one (with the seconds of inertial-only
    navigation); a duplicate frame number; a time earlier than the previous frame's.

    ``mounting``: the camera's lever arm [m, body] and boresight [deg]. ``frames`` (default: from ``output.crs``,
    ``output.height``, ``output.vertical_crs``) gives the grid and the heights; ``image_names`` (default: from
    ``output.image_names``) the ``image`` column; without them and ``output``, WGS 84 ellipsoidal, no names.
    """
    output = output or OutputSection()
    if frames is None and (output.crs or output.height != "ellipsoidal"):
        from georef.frames.heights import OutputFrames  # pyproj only when a CRS or a geoid is asked for

        frames = OutputFrames(output.crs, output.height, output.vertical_crs)
    if image_names is None and output.image_names:
        image_names = ImageNames.parse(output.image_names)
    inside = states.inside
    n = len(exposures)
    out = {name: np.full(n, np.nan) for name in EO_COLUMNS[2:]}
    camera = None
    if inside.any():
        camera = _camera_states(exposures, states, mounting, position_lag_s)
        for name, value in _camera_values(camera).items():
            out[name][inside] = value
    table: EoColumns = {"frame": exposures.frame}
    if image_names is not None:
        table["image"] = np.array(image_names.names([str(f) for f in exposures.frame]), dtype=object)
    table.update({"time": exposures.time, **out})
    if frames is not None and frames.height == "orthometric":
        table["height_orthometric"] = frames.output_heights(out["lat"], out["lon"], out["height"])
    if frames is not None and frames.horizontal is not None:
        table.update(_grid_columns(frames, out, inside, camera))
    table["flag"] = _flag_column(table, exposures, states, gnss, outage_min_s)
    return table


@dataclass(frozen=True)
class _CameraStates:
    """The camera at the exposures inside the navigation span (M of them): geodetic ``lat``, ``lon`` [rad] and
    ``height`` [m]; camera-to-NED ``C_c_n`` (M, 3, 3) and its ZYX Euler ``roll``, ``pitch``, ``yaw`` [rad]; NED
    position variances ``pos_var`` (M, 3) [m^2]; NED attitude-error covariance ``att_cov_n`` (M, 3, 3) [rad^2]
    and Euler sigmas ``euler_sigma`` (M, 3) [rad]; the IMU's NED velocity ``v_n`` (M, 3) [m/s]."""

    lat: np.ndarray
    lon: np.ndarray
    height: np.ndarray
    C_c_n: np.ndarray
    roll: np.ndarray
    pitch: np.ndarray
    yaw: np.ndarray
    pos_var: np.ndarray
    att_cov_n: np.ndarray
    euler_sigma: np.ndarray
    v_n: np.ndarray


def _camera_states(exposures: Exposures, states: ExposureStates, mounting: MountingSection,
                   position_lag_s: float) -> _CameraStates:
    """The camera's position and attitude at the exposures inside the span (lever arm and boresight applied), with
    the navigation's covariances carried to it, plus a latency not applied (``position_lag_s`` [s]) and the
    exposure times' own uncertainty."""
    inside = states.inside
    r_imu = states.r_e[inside]
    lat_i, lon_i, _ = ecef_to_geodetic(r_imu)
    C_b_n = states.C_b_n[inside]
    lever_cam = np.asarray(mounting.lever_arm_camera)
    r_cam = r_imu + lever_arm_ecef(lat_i, lon_i, C_b_n, lever_cam)
    lat, lon, height = ecef_to_geodetic(r_cam)
    C_c_n = camera_attitude(C_b_n, np.radians(mounting.boresight))
    roll, pitch, yaw = dcm_to_euler(C_c_n)
    # Position covariance at the camera: IMU position plus the lever arm turned by attitude errors,
    # d(C_b_n l) = -[(C_b_n l) x] phi for a small NED rotation phi.
    lever_n = lever_arm_offset(C_b_n, lever_cam)
    S = skew(lever_n)
    if states.att_cov_n is not None:
        att_cov = states.att_cov_n[inside]
        att_cov_n = att_cov
        lever_var = np.einsum("nij,njk,nik->ni", S, att_cov, S)
        J = euler_error_jacobian(roll, pitch, yaw)
        euler_var = np.einsum("nij,njk,nik->ni", J, att_cov, J)
        euler_sigma = np.sqrt(np.where(euler_var >= 0.0, euler_var, np.nan))
    else:
        # Euler sigmas taken as NED tilt sigmas (small roll and pitch)
        att_var = states.att_sigma[inside] ** 2
        lever_var = np.einsum("nij,nj->ni", S**2, att_var)
        euler_sigma = states.att_sigma[inside]
        att_cov_n = np.einsum("ni,ij->nij", att_var, np.eye(3))
    pos_var = states.pos_var_n[inside] + lever_var
    v_n = np.einsum("nij,nj->ni", C_e_n(lat_i, lon_i), states.v_e[inside])
    if position_lag_s:
        # a GNSS latency the data show and the run did not apply: the solution trails by the speed times it
        pos_var = pos_var + (v_n * position_lag_s) ** 2
    time_sigma = None if exposures.time_sigma is None else np.asarray(exposures.time_sigma, float)[inside]
    if time_sigma is not None and states.omega_n is not None:
        # an exposure time known to sigma_t moves the camera by its velocity (the IMU's plus omega x lever) times
        # sigma_t and turns it by omega sigma_t, independently of the navigation errors: the variances add
        omega_n = states.omega_n[inside]
        v_cam = v_n + np.cross(omega_n, lever_n)
        pos_var = pos_var + (v_cam * time_sigma[:, None]) ** 2
        turn = omega_n * time_sigma[:, None]
        att_cov_n = att_cov_n + np.einsum("ni,nj->nij", turn, turn)
        turn_euler = np.einsum("nij,nj->ni", euler_error_jacobian(roll, pitch, yaw), turn)
        euler_sigma = np.sqrt(euler_sigma**2 + turn_euler**2)
    return _CameraStates(lat=lat, lon=lon, height=height, C_c_n=C_c_n, roll=roll, pitch=pitch, yaw=yaw,
                         pos_var=pos_var, att_cov_n=att_cov_n, euler_sigma=euler_sigma, v_n=v_n)


def _camera_values(camera: _CameraStates) -> dict[str, np.ndarray]:
    """The EO columns from ``lat`` to ``yaw_minus_track`` at the exposures inside the span, in degrees and metres."""
    # a negative or missing variance (a numerically broken smoother) gives no sigma and a flag, never a NaN
    # that looks like a number was attempted
    pos_sigma = np.sqrt(np.where(camera.pos_var >= 0.0, camera.pos_var, np.nan))
    euler_sigma = camera.euler_sigma
    track = np.degrees(np.arctan2(camera.v_n[:, 1], camera.v_n[:, 0]))
    yaw_deg = np.degrees(camera.yaw)
    return {
        "lat": np.degrees(camera.lat), "lon": np.degrees(camera.lon), "height": camera.height,
        "roll": np.degrees(camera.roll), "pitch": np.degrees(camera.pitch), "yaw": wrap_360(yaw_deg),
        "sigma_n": pos_sigma[:, 0], "sigma_e": pos_sigma[:, 1], "sigma_u": pos_sigma[:, 2],
        "sigma_roll": np.degrees(euler_sigma[:, 0]),
        "sigma_pitch": np.degrees(euler_sigma[:, 1]),
        "sigma_yaw": np.degrees(euler_sigma[:, 2]),
        "track": wrap_360(track), "yaw_minus_track": (yaw_deg - track + 180.0) % 360.0 - 180.0,
    }


def _grid_columns(frames: OutputFrames, out: EoColumns, inside: np.ndarray,
                  camera: _CameraStates | None) -> EoColumns:
    """The map-grid columns (``easting`` to ``sigma_kappa``) in ``frames``' horizontal CRS: grid position
    [m] and photogrammetric omega, phi, kappa [deg] with their sigmas; empty outside the span."""
    from georef.frames.mapping import MapProjection  # pyproj only when a CRS is asked for
    from georef.frames.opk_covariance import grid_position_covariance, opk_covariance
    from georef.frames.photogrammetry import image_to_map, rotation_to_opk

    projection = MapProjection(frames.horizontal_name or "")
    n = len(inside)
    grid = {name: np.full(n, np.nan) for name in ("easting", "northing", "omega", "phi", "kappa", "sigma_x",
                                                    "sigma_y", "sigma_omega", "sigma_phi", "sigma_kappa")}
    if camera is not None:
        lat_deg, lon_deg = out["lat"][inside], out["lon"][inside]
        grid["easting"][inside], grid["northing"][inside] = projection.forward(lat_deg, lon_deg)
        convergence, scale = projection.convergence_and_scale(lat_deg, lon_deg)
        omega, phi, kappa = rotation_to_opk(image_to_map(camera.C_c_n, convergence))
        grid["omega"][inside], grid["phi"][inside] = np.degrees(omega), np.degrees(phi)
        grid["kappa"][inside] = np.degrees(kappa)
        var_x, var_y, _ = grid_position_covariance(camera.pos_var[:, 0], camera.pos_var[:, 1], convergence, scale)
        grid["sigma_x"][inside] = np.sqrt(np.where(var_x >= 0.0, var_x, np.nan))
        grid["sigma_y"][inside] = np.sqrt(np.where(var_y >= 0.0, var_y, np.nan))
        opk_var = np.diagonal(opk_covariance(omega, phi, convergence, camera.att_cov_n), axis1=-2, axis2=-1)
        opk_sigma = np.degrees(np.sqrt(np.where(opk_var >= 0.0, opk_var, np.nan)))
        for i, name in enumerate(("sigma_omega", "sigma_phi", "sigma_kappa")):
            grid[name][inside] = opk_sigma[:, i]
    return grid


def _flag_column(table: EoColumns, exposures: Exposures, states: ExposureStates, gnss: GnssEpochs,
                 outage_min_s: float) -> np.ndarray:
    """The ``flag`` column (:func:`_flags`), with :data:`FLAG_NO_SIGMA` where a row inside the span has no sigma."""
    flags = _flags(exposures, states, gnss, outage_min_s)
    sigmas = np.column_stack([table[name] for name in ("sigma_n", "sigma_e", "sigma_u", "sigma_roll", "sigma_pitch",
                                                        "sigma_yaw")])
    broken = states.inside & ~np.all(np.isfinite(sigmas), axis=1)
    for i in np.flatnonzero(broken):
        flags[i] = f"{flags[i]}; {FLAG_NO_SIGMA}" if flags[i] else FLAG_NO_SIGMA
    return flags
