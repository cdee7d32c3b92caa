"""Generic inputs for users without an iMAR unit, and the fused trajectory table.

* ``imu.csv``: ``time, gyro_x, gyro_y, gyro_z, acc_x, acc_y, acc_z`` — seconds (any epoch, increasing),
  rad/s, m/s^2, body axes forward-right-down; optionally ``mag_x, mag_y, mag_z`` (any unit, body axes) and an
  autopilot's own ``yaw`` [deg from true north] (with ``roll, pitch``, which are not used): ``georef fuse``
  takes its heading from them when the motion never shows it, ``georef attitude`` reads the magnetometer.
* ``gnss.csv``: ``time, lat, lon, height`` [+ ``sigma_n, sigma_e, sigma_u``] — degrees, metres, antenna
  position, the IMU's time scale.
* Both are read by :func:`georef.io.table.read_table` (any separator, header names ignoring case) and checked
  against :data:`georef.io.plausibility.GENERIC_LIMITS`; a GNSS fix far from both neighbours is dropped with a
  notice, a lasting jump is an error.
* ``traj.csv`` (written by ``georef fuse``): ``time, lat, lon, height, vn, ve, vd, roll, pitch, yaw`` and
  their standard deviations.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

import numpy as np
import pandas as pd

from georef.frames import wrap_360
from georef.fusion.solution import NavSolution
from georef.io.atomic import atomic_write
from georef.io.errors import InputError
from georef.io.plausibility import GENERIC_LIMITS, check_gnss_jumps, check_ranges
from georef.io.pos import PosLog
from georef.io.table import Table, read_table
from georef.timing import GnssEpochs, check_increasing

IMU_COLUMNS = ("time", "gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z")
GNSS_COLUMNS = ("time", "lat", "lon", "height")
MAG_COLUMNS = ("mag_x", "mag_y", "mag_z")
AUTOPILOT_YAW = "yaw"


def read_imu_csv(path: Path | str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``imu.csv`` -> time [s], gyro [rad/s] (N, 3), specific force [m/s^2] (N, 3), file lines."""
    time, gyro, accel, _, lines = read_marg_csv(path)
    return time, gyro, accel, lines


def read_imu_heading_sources(path: Path | str) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The heading sources of ``imu.csv`` beside the IMU: the magnetometer (N, 3) and the autopilot's yaw [rad]
    (N,), each None when the file has no such columns."""
    if os.path.exists(path) and stat.S_ISFIFO(os.stat(path).st_mode):
        raise InputError(path, None, None, "a pipe can be read only once, and imu.csv is read twice here (the IMU, "
                         "then its heading sources): save it to a file")
    wanted = dict.fromkeys((*IMU_COLUMNS, *MAG_COLUMNS, AUTOPILOT_YAW), "float")
    table = read_table(path, wanted, required=set(IMU_COLUMNS))
    c = table.columns
    check_ranges(table.path, {name: c[name] for name in ("yaw",) if name in c}, table.lines, table.names,
                 GENERIC_LIMITS)
    present = [name for name in MAG_COLUMNS if name in c]
    if present and len(present) < 3:
        missing = [name for name in MAG_COLUMNS if name not in c][0]
        raise InputError(table.path, 1, missing, "magnetometer columns come as mag_x, mag_y, mag_z together")
    mag = np.stack([c[name] for name in MAG_COLUMNS], -1) if present else None
    yaw = np.radians(c[AUTOPILOT_YAW]) if AUTOPILOT_YAW in c else None
    return mag, yaw


def _imu_table(path: Path | str, columns: tuple[str, ...]) -> Table:
    """imu.csv's ``columns`` (the IMU's required), its time strictly increasing and every value in range; an
    error names the file, line and column."""
    table = read_table(path, dict.fromkeys(columns, "float"), required=set(IMU_COLUMNS))
    c = table.columns
    check_increasing(table.path, c["time"], table.lines, table.names.get("time", "time"))
    check_ranges(table.path, c, table.lines, table.names, GENERIC_LIMITS)
    same = np.flatnonzero(np.diff(c["time"]) == 0)
    if len(same):
        raise InputError(table.path, int(table.lines[same[0] + 1]), "time", "repeated time stamp")
    return table


def read_marg_csv(path: Path | str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]:
    """``imu.csv`` with optional ``mag_x, mag_y, mag_z`` -> time, gyro, specific force, field or None, lines."""
    table = _imu_table(path, (*IMU_COLUMNS, *MAG_COLUMNS))
    c = table.columns
    gyro = np.stack([c["gyro_x"], c["gyro_y"], c["gyro_z"]], -1)
    accel = np.stack([c["acc_x"], c["acc_y"], c["acc_z"]], -1)
    present = [name for name in MAG_COLUMNS if name in c]
    if present and len(present) < 3:
        missing = [name for name in MAG_COLUMNS if name not in c][0]
        raise InputError(table.path, 1, missing, "magnetometer columns come as mag_x, mag_y, mag_z together")
    mag = np.stack([c[name] for name in MAG_COLUMNS], -1) if present else None
    return c["time"], gyro, accel, mag, table.lines


def read_generic_log(imu_path: Path | str, gnss_path: Path | str, time_scale: str = "auto") -> PosLog:
    """``imu.csv`` and ``gnss.csv`` as the pipeline's typed input (:class:`~georef.io.pos.PosLog`; ``data`` in
    POS.txt's units, deg/s and m/s^2), with the magnetometer and the autopilot's roll, pitch, yaw on the rows when
    imu.csv has them. imu.csv is read once. An RTKLIB/Emlid .pos as ``gnss_path`` is put on imu.csv's time scale:
    ``time_scale`` (:data:`georef.io.pos_time_scale.CHOICES`; ``auto`` detects it from imu.csv's span)."""
    from georef.io.pos_time_scale import is_solution_file, read_gnss_on_imu_scale
    from georef.timing import TimeRepairReport

    table = _imu_table(imu_path, (*IMU_COLUMNS, *MAG_COLUMNS, "roll", "pitch", AUTOPILOT_YAW))
    c = table.columns
    present = [name for name in MAG_COLUMNS if name in c]
    if present and len(present) < 3:
        missing = [name for name in MAG_COLUMNS if name not in c][0]
        raise InputError(table.path, 1, missing, "magnetometer columns come as mag_x, mag_y, mag_z together")
    mag = np.stack([c[name] for name in MAG_COLUMNS], -1) if present else None
    rpy = None
    if AUTOPILOT_YAW in c:
        rpy = np.radians(np.stack([c.get("roll", np.full(len(table), np.nan)),
                                   c.get("pitch", np.full(len(table), np.nan)), c[AUTOPILOT_YAW]], -1))
    data = {f"gyro_{a}": np.degrees(c[f"gyro_{a}"]) for a in "xyz"}
    data.update({f"acc_{a}": c[f"acc_{a}"] for a in "xyz"})
    names = {role: table.names.get(role, role) for role in data}
    fixes = read_gnss_on_imu_scale(gnss_path, c["time"], time_scale, Path(imu_path).name)
    kind = "imu.csv + RTKLIB .pos" if is_solution_file(gnss_path) else "imu.csv + gnss.csv"
    return PosLog(path=table.path, time=c["time"], data=data, lines=table.lines, gnss=fixes,
                  time_repairs=TimeRepairReport(), notices=[*table.notices, *fixes.notices], column_names=names,
                  kind=kind, mag=mag, autopilot_rpy=rpy)


def read_gnss_csv(path: Path | str) -> GnssEpochs:
    """``gnss.csv`` -> GNSS antenna fixes (optional per-fix sigmas); an RTKLIB/Emlid ``.pos`` solution, recognised
    by its content (:func:`georef.io.rtklib.is_rtklib_pos`), is read by :func:`georef.io.rtklib.read_rtklib_gnss`."""
    from georef.io.rtklib import is_rtklib_pos, read_rtklib_gnss

    if is_rtklib_pos(path):
        return read_rtklib_gnss(path)
    wanted = dict.fromkeys((*GNSS_COLUMNS, "sigma_n", "sigma_e", "sigma_u"), "float")
    table = read_table(path, wanted, required=set(GNSS_COLUMNS))
    c = table.columns
    check_increasing(table.path, c["time"], table.lines, table.names.get("time", "time"))
    check_ranges(table.path, c, table.lines, table.names, GENERIC_LIMITS)
    bad = np.flatnonzero((np.abs(c["lat"]) > 90) | (np.abs(c["lon"]) > 180))
    if len(bad):
        raise InputError(table.path, int(table.lines[bad[0]]), "lat/lon", "coordinate outside the valid range")
    sigma = None
    if all(name in c for name in ("sigma_n", "sigma_e", "sigma_u")):
        sigma = np.stack([c["sigma_n"], c["sigma_e"], c["sigma_u"]], -1)
        nonpositive = np.flatnonzero(np.any(sigma <= 0, axis=1))
        if len(nonpositive):
            raise InputError(table.path, int(table.lines[nonpositive[0]]), "sigma_n/e/u", "sigma must be positive")
    fixes = GnssEpochs(time=c["time"], lat_deg=c["lat"], lon_deg=c["lon"], height=c["height"], line=table.lines,
                       repeated=np.zeros(len(table), bool), notices=list(table.notices), sigma_neu=sigma)
    fixes, notices = check_gnss_jumps(table.path, fixes, "lat/lon/height")
    fixes.notices.extend(notices)
    return fixes


def trajectory_table(nav: NavSolution) -> pd.DataFrame:
    """The fused trajectory at every IMU row with a solution: degrees, metres, m/s, 1-sigma."""
    v = nav.valid
    v_n = nav.v_n
    vel_var = nav.ins_info.vel_var_n if nav.ins_info is not None else np.full((len(nav.time), 3), np.nan)
    return pd.DataFrame({
        "time": nav.time[v], "lat": np.degrees(nav.lat[v]), "lon": np.degrees(nav.lon[v]), "height": nav.height[v],
        "vn": v_n[v, 0], "ve": v_n[v, 1], "vd": v_n[v, 2],
        "roll": np.degrees(nav.roll[v]), "pitch": np.degrees(nav.pitch[v]), "yaw": wrap_360(np.degrees(nav.yaw[v])),
        "sigma_n": np.sqrt(nav.pos_var_n[v, 0]), "sigma_e": np.sqrt(nav.pos_var_n[v, 1]),
        "sigma_u": np.sqrt(nav.pos_var_n[v, 2]),
        "sigma_vn": np.sqrt(vel_var[v, 0]), "sigma_ve": np.sqrt(vel_var[v, 1]), "sigma_vd": np.sqrt(vel_var[v, 2]),
        "sigma_roll": np.degrees(nav.att_sigma[v, 0]), "sigma_pitch": np.degrees(nav.att_sigma[v, 1]),
        "sigma_yaw": np.degrees(nav.att_sigma[v, 2]),
    })


def write_trajectory_csv(nav: NavSolution, path: Path | str) -> Path:
    """Write ``traj.csv`` atomically."""
    table = trajectory_table(nav)
    # time to the microsecond: %.10g keeps only the whole seconds of a Unix time (a ROS bag's stamps, 1.8e9 s)
    table["time"] = np.char.mod("%.6f", table["time"].to_numpy())
    with atomic_write(path) as handle:
        table.to_csv(handle, index=False, float_format="%.10g", lineterminator="\n")
    return Path(path)
