"""The per-axis method of Bošnjak (2014; ``docs/method-axis.md``) as ``--method axis``, without its flaws.

1. The unit's yaw origin is recovered (:mod:`georef.fusion.yaw_offset`) and follows drift.
2. The level-frame accelerations IACC are rotated by that offset into NED, then into ECEF through
   ``C_n_e`` at the current position.
3. Three independent ``[p, v]`` Kalman filters, one per ECEF axis, are driven by those accelerations and
   updated with GNSS positions moved from the antenna to the IMU through the lever arm. State and
   covariance run across GNSS epochs: no resets, no random numbers. Fixes that fail a chi-square gate
   are rejected and reported.
4. Attitude: the unit's roll and pitch; yaw = unit yaw + recovered offset.

What the per-axis model cannot do, and the full-state filters do: estimate attitude or sensor biases,
or couple the axes (the ECEF covariance is kept diagonal).
"""

from __future__ import annotations

import numpy as np

from georef.aot import load as load_kernel
from georef.config import AxisSettings, ProcessingConfig
from georef.frames import C_e_n, C_n_e, ecef_to_geodetic, euler_to_dcm, geodetic_to_ecef, wrap_pi
from georef.frames.mounting import lever_arm_ecef
from georef.frames.rotations import attitude_at
from georef.fusion.solution import AxisInfo, GnssUse, NavSolution, ecef_variances_to_ned, ned_variances_to_ecef
from georef.fusion.yaw_offset import recover_yaw_offset
from georef.imu_errors import white_noise_sigma
from georef.io.errors import GeorefError
from georef.io.pos import PosLog

REQUIRED_ROLES = ("iacc_x", "iacc_y", "iacc_z", "roll", "pitch", "yaw")
MAX_CONSECUTIVE_REJECTS = 5


def solve_axis(log: PosLog, cfg: AxisSettings | ProcessingConfig) -> NavSolution:
    """Per-axis GPS/INS solution at the POS rows (see the module docstring), with the sections of the
    configuration the method reads (``AxisSettings.of(cfg)``; a whole configuration is narrowed to them here)."""
    if isinstance(cfg, ProcessingConfig):
        cfg = AxisSettings.of(cfg)
    gnss = log.gnss
    t = log.time
    iacc_u = log.vector("iacc")
    unit_rpy = np.radians(np.stack([log.data["roll"], log.data["pitch"], log.data["yaw"]], -1))
    lever_gnss = np.asarray(cfg.lever_arm_gnss)
    sigma_n, sigma_e = cfg.gnss.sigma[:2]
    try:
        yaw_solution = recover_yaw_offset(gnss.time, gnss.lat_deg, gnss.lon_deg, gnss.height, t, iacc_u,
                                          unit_rpy, lever_gnss, (sigma_n, sigma_e), window=cfg.yaw_offset.window,
                                          step=cfg.yaw_offset.step, bandwidth=cfg.yaw_offset.bandwidth)
    except ValueError as exc:
        raise GeorefError(f"{log.path}: {exc}") from None
    offset, offset_sigma = yaw_solution.at(t)
    roll, pitch = unit_rpy[:, 0], unit_rpy[:, 1]
    yaw = wrap_pi(unit_rpy[:, 2] + offset)

    # Level-frame acceleration -> NED (rotate by the offset) -> ECEF at the current position.
    lat_row = np.radians(np.interp(t, gnss.time, gnss.lat_deg))
    lon_row = np.radians(np.interp(t, gnss.time, gnss.lon_deg))
    a_n = np.einsum("nij,nj->ni", euler_to_dcm(0.0, 0.0, offset), iacc_u)
    a_e = np.einsum("nij,nj->ni", C_n_e(lat_row, lon_row), a_n)

    # GNSS antenna fixes -> IMU positions through the lever arm, at the fix times.
    in_span = (gnss.time >= t[0]) & (gnss.time <= t[-1])
    fix_t = gnss.time[in_span]
    lat_f, lon_f = np.radians(gnss.lat_deg[in_span]), np.radians(gnss.lon_deg[in_span])
    C_b_n_fix = attitude_at(t, roll, pitch, yaw, fix_t)
    r_ant = geodetic_to_ecef(lat_f, lon_f, gnss.height[in_span])
    z_fix = r_ant - lever_arm_ecef(lat_f, lon_f, C_b_n_fix, lever_gnss)
    r_fix = ned_variances_to_ecef(lat_f, lon_f, np.tile(np.square(cfg.gnss.sigma), (len(fix_t), 1)))

    if cfg.axis.accel_sigma is None:
        sigma_acc_n = white_noise_sigma(a_n)
    else:
        sigma_acc_n = np.full(3, cfg.axis.accel_sigma)
    q_white = ned_variances_to_ecef(lat_row[:1], lon_row[:1], sigma_acc_n[None, :] ** 2)[0]
    s_cont = np.full(3, cfg.axis.bias_sigma**2 * cfg.axis.bias_time)
    v_init = (z_fix[1] - z_fix[0]) / (fix_t[1] - fix_t[0]) if len(fix_t) > 1 else np.zeros(3)

    pos, vel, var_p, _, _, innov, innov_var, status = load_kernel("axis").axis_filter(
        t, a_e, fix_t, z_fix, r_fix, v_init, q_white, s_cont, cfg.gnss_gate.chi2, MAX_CONSECUTIVE_REJECTS)
    valid = np.isfinite(pos[:, 0])
    lat, lon, height = ecef_to_geodetic(np.where(valid[:, None], pos, r_ant[0]))
    pos_var_n = ecef_variances_to_ned(lat, lon, var_p)
    att_sigma = np.stack([np.full(len(t), np.radians(cfg.unit.level_sigma)),
                          np.full(len(t), np.radians(cfg.unit.level_sigma)),
                          np.sqrt(offset_sigma**2 + np.radians(cfg.unit.yaw_sigma) ** 2)], -1)
    full_status = np.full(len(gnss), -1, dtype=int)
    full_innov = np.full((len(gnss), 3), np.nan)
    full_var = np.full((len(gnss), 3), np.nan)
    full_nis = np.full(len(gnss), np.nan)
    full_status[in_span] = status
    # the filters' innovations are measured minus predicted along ECEF axes: reported as GnssUse has them,
    # predicted minus measured in NED, with their chi-square over the filters' own (ECEF) variances
    full_innov[in_span] = np.einsum("nij,nj->ni", C_e_n(lat_f, lon_f), -innov)
    full_var[in_span] = ecef_variances_to_ned(lat_f, lon_f, innov_var)
    full_nis[in_span] = np.sum(innov**2 / innov_var, axis=1)
    return NavSolution(
        method="axis", time=t, r_e=pos, v_e=vel, lat=lat, lon=lon, height=height, roll=roll, pitch=pitch,
        yaw=yaw, pos_var_n=pos_var_n, att_sigma=att_sigma, valid=valid,
        gnss=GnssUse(time=gnss.time, status=full_status, innovation=full_innov, innovation_var=full_var,
                     line=gnss.line, nis=full_nis),
        axis_info=AxisInfo(yaw_offset=yaw_solution, accel_sigma_n=sigma_acc_n),
    )
