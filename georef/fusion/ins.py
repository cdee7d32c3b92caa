"""Full-state INS/GNSS fusion: strapdown mechanisation, error-state EKF (``ekf``) and RTS smoother (``rts``).

Inputs are the raw body-frame rates and specific forces (POS.txt ``OMGS_*`` in deg/s and ``ACCS_*`` in
m/s^2, or the generic ``imu.csv``) and GNSS antenna fixes. The equations, the state and the noise model
are documented in ``docs/method-ins.md``.

Alignment in motion: position and velocity from the first GNSS fixes; roll and pitch from the unit
(when its ROLL/PITCH are given) or accelerometer levelling; heading from the unit's yaw plus the recovered
yaw offset (when YAW and IACC are given) or from the GNSS track. The filter refines all three.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from georef.align import GnssEpochs
from georef.config import ProcessingConfig
from georef.frames import C_n_e, dcm_to_quat, euler_to_dcm, geodetic_to_ecef, radii_of_curvature
from georef.frames.rotations import wrap_pi
from georef.fusion.solution import GnssUse, NavSolution
from georef.fusion.yaw_offset import recover_yaw_offset
from georef.imu_errors import white_noise_sigma
from georef.io.errors import GeorefError
from georef.kernels import load as load_kernel

REQUIRED_ROLES = ("gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z")
MAX_CONSECUTIVE_REJECTS = 5


@dataclass
class InsInputs:
    """Everything the full-state filters use, SI units.

    ``time`` [s], ``gyro`` [rad/s] and ``accel`` [m/s^2] (N, 3) in the body frame; GNSS fixes; optionally the
    unit's own roll/pitch/yaw [rad] (N, 3) and level-frame acceleration IACC [m/s^2] (N, 3) for alignment.
    """

    time: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    gnss: GnssEpochs
    unit_rpy: np.ndarray | None = None
    iacc: np.ndarray | None = None
    source: str = "IMU"


@dataclass
class NoiseModel:
    """Continuous-time noise densities used by the filter (SI) and where they came from."""

    q_vel: float      # m^2/s^3, white specific force
    q_att: float      # rad^2/s, white angular rate
    q_bg: float       # rad^2/s^3, gyro-bias random walk
    q_ba: float       # m^2/s^5, accelerometer-bias random walk
    sigma_bg0: float  # rad/s, initial gyro-bias sigma
    sigma_ba0: float  # m/s^2, initial accelerometer-bias sigma
    from_data: bool

    def as_array(self, cfg: ProcessingConfig) -> np.ndarray:
        """The kernel's noise vector, with the unit-attitude error model of ``cfg``."""
        level = np.radians(cfg.unit_level_sigma)
        return np.array([self.q_vel, self.q_att, self.q_bg, self.q_ba, 0.0, 0.0,
                         2.0 * level**2 / cfg.unit_level_time, 1.0 / cfg.unit_level_time, unit_drift_psd(cfg),
                         np.radians(cfg.unit_angle_noise) ** 2, np.radians(cfg.unit_angle_noise) ** 2])


def unit_drift_psd(cfg: ProcessingConfig) -> float:
    """Density [rad^2/s^3] of the random walk of the unit's yaw-origin drift rate, from
    ``cfg.unit_drift_change`` [deg/min per sqrt(min)]."""
    return float((np.radians(cfg.unit_drift_change) / 60.0 / np.sqrt(60.0)) ** 2)


def noise_model(inputs: InsInputs, cfg: ProcessingConfig) -> NoiseModel:
    """Datasheet noise (preset + overrides), raised to the white noise the data show when that is larger.

    Rotor vibration sampled at the IMU rate looks like white noise far above the datasheet's ARW/VRW;
    ignoring it would make the filter overconfident. Biases are random walks whose density equals the
    Gauss-Markov instability's ``2 sigma^2 / tau``; their initial sigma covers turn-on and instability.
    """
    model = cfg.imu_error_model()
    q_att, q_vel = model.gyro_white_psd, model.accel_white_psd
    from_data = False
    if cfg.imu_noise_from_data:
        dt = float(np.median(np.diff(inputs.time)))
        measured_att = float(np.mean(white_noise_sigma(inputs.gyro) ** 2)) * dt
        measured_vel = float(np.mean(white_noise_sigma(inputs.accel) ** 2)) * dt
        from_data = measured_att > q_att or measured_vel > q_vel
        q_att, q_vel = max(q_att, measured_att), max(q_vel, measured_vel)
    q_bg = 2.0 * model.gyro_markov_sigma**2 / model.gyro_bias_corr_time_s
    q_ba = 2.0 * model.accel_markov_sigma**2 / model.accel_bias_corr_time_s
    return NoiseModel(q_vel=q_vel, q_att=q_att, q_bg=q_bg, q_ba=q_ba,
                      sigma_bg0=float(np.hypot(model.gyro_turn_on_sigma, model.gyro_markov_sigma)),
                      sigma_ba0=float(np.hypot(model.accel_turn_on_sigma, model.accel_markov_sigma)),
                      from_data=from_data)


def _initial_state(inputs: InsInputs, cfg: ProcessingConfig) -> tuple[int, int, np.ndarray, np.ndarray, dict]:
    """Start row, start fix, nominal state and covariance for alignment in motion."""
    gnss, t = inputs.gnss, inputs.time
    usable = np.flatnonzero((gnss.time >= t[0]) & (gnss.time <= t[-1]))
    if len(usable) < 3:
        raise GeorefError("the full-state filter needs at least three GNSS fixes inside the IMU span")
    # first fix with neighbours one period either side (central-difference velocity)
    start_fix = None
    for k in usable[1:-1]:
        if gnss.time[k + 1] - gnss.time[k - 1] <= 2.5:
            start_fix = int(k)
            break
    if start_fix is None:
        raise GeorefError("no three consecutive GNSS fixes to start the full-state filter")
    k = start_fix
    lat, lon = np.radians(gnss.lat_deg[k - 1:k + 2]), np.radians(gnss.lon_deg[k - 1:k + 2])
    r_e = geodetic_to_ecef(lat, lon, gnss.height[k - 1:k + 2])
    d_n = (r_e - r_e[1]) @ C_n_e(lat[1], lon[1])
    v_n = (d_n[2] - d_n[0]) / (gnss.time[k + 1] - gnss.time[k - 1])
    start_row = int(np.searchsorted(t, gnss.time[k], side="left"))
    lag = t[start_row] - gnss.time[k]
    info: dict = {}

    # attitude
    if inputs.unit_rpy is not None:
        roll, pitch = inputs.unit_rpy[start_row, 0], inputs.unit_rpy[start_row, 1]
        level_sigma = np.radians(max(cfg.unit_level_sigma, 0.05)) * 3.0
    else:
        window = slice(max(0, start_row - 25), start_row + 25)
        f = inputs.accel[window].mean(axis=0)
        roll, pitch = np.arctan2(-f[1], -f[2]), np.arctan2(f[0], np.hypot(f[1], f[2]))
        level_sigma = np.radians(3.0)
    yaw, yaw_sigma = None, None
    drift, drift_sigma = 0.0, np.radians(2.0) / 60.0
    if inputs.unit_rpy is not None and inputs.iacc is not None:
        try:
            solution = recover_yaw_offset(gnss.time, gnss.lat_deg, gnss.lon_deg, gnss.height, t, inputs.iacc,
                                          inputs.unit_rpy, np.asarray(cfg.lever_arm_gnss), cfg.gnss_sigma[:2],
                                          window=cfg.yaw_window, step=cfg.yaw_step, bandwidth=cfg.yaw_bandwidth)
            offset, offset_sigma = solution.at(np.array([t[start_row]]))
            yaw = float(wrap_pi(inputs.unit_rpy[start_row, 2] + offset[0]))
            yaw_sigma = max(float(offset_sigma[0]), np.radians(0.1))
            drift, drift_sigma = solution.drift, max(solution.drift_sigma, np.radians(0.05) / 60.0)
            info["yaw_offset"] = solution
            info["heading_source"] = "unit yaw + recovered offset"
        except ValueError:
            yaw = None
    if yaw is None:
        if np.hypot(v_n[0], v_n[1]) < 3.0:
            raise GeorefError("cannot align the heading: no usable unit yaw and the GNSS ground speed at the start "
                              f"is {np.hypot(v_n[0], v_n[1]):.1f} m/s (< 3 m/s)")
        yaw = float(np.arctan2(v_n[1], v_n[0]))
        yaw_sigma = np.radians(15.0)
        info["heading_source"] = "GNSS track"
    C_b_n = euler_to_dcm(roll, pitch, yaw)
    M, N = radii_of_curvature(lat[1])
    lever_n = C_b_n @ np.asarray(cfg.lever_arm_gnss)
    x0 = np.zeros(20)
    pos_n = v_n * lag - lever_n  # IMU at the start row, relative to the antenna fix
    x0[0] = lat[1] + pos_n[0] / (M + gnss.height[k])
    x0[1] = lon[1] + pos_n[1] / ((N + gnss.height[k]) * np.cos(lat[1]))
    x0[2] = gnss.height[k] - pos_n[2]
    x0[3:6] = v_n
    x0[6:10] = dcm_to_quat(C_b_n)
    unit_level = np.radians(cfg.unit_level_sigma)
    if inputs.unit_rpy is not None:
        # the unit's yaw origin: yaw_u = yaw - d
        x0[16] = float(wrap_pi(yaw - inputs.unit_rpy[start_row, 2]))
        x0[17] = drift
    noise = noise_model(inputs, cfg)
    sigma = np.asarray(cfg.gnss_sigma)
    P0 = np.diag(np.concatenate([
        sigma**2, (sigma / np.sqrt(2.0)) ** 2 + 0.5**2,
        [level_sigma**2, level_sigma**2, yaw_sigma**2],
        np.full(3, noise.sigma_bg0**2), np.full(3, noise.sigma_ba0**2),
        [unit_level**2, unit_level**2, yaw_sigma**2, drift_sigma**2]]))
    # d_est - d = yaw_est - yaw = -phi_D at the start: fully (anti-)correlated with the heading error
    P0[8, 17] = P0[17, 8] = -yaw_sigma**2
    info["noise"] = noise
    return start_row, start_fix, x0, P0, info


def solve_ins(inputs: InsInputs, cfg: ProcessingConfig, smooth: bool = True) -> NavSolution:
    """EKF (``smooth=False``) or EKF + RTS smoother solution at every IMU row."""
    t = np.ascontiguousarray(inputs.time, dtype=float)
    if len(t) < 10 or np.any(np.diff(t) <= 0):
        raise GeorefError("IMU times must increase strictly")
    gnss = inputs.gnss
    start_row, start_fix, x0, P0, info = _initial_state(inputs, cfg)
    noise = info["noise"]
    use = np.flatnonzero((gnss.time > gnss.time[start_fix]) & (gnss.time <= t[-1]))
    fix_row = np.searchsorted(t, gnss.time[use], side="left")
    fix_lag = t[fix_row] - gnss.time[use]
    z_fix = np.stack([np.radians(gnss.lat_deg[use]), np.radians(gnss.lon_deg[use]), gnss.height[use]], -1)
    if gnss.sigma_neu is not None:
        r_fix = np.square(np.where(np.isfinite(gnss.sigma_neu[use]), gnss.sigma_neu[use], cfg.gnss_sigma))
    else:
        r_fix = np.tile(np.square(cfg.gnss_sigma), (len(use), 1))
    rate = 1.0 / float(np.median(np.diff(t)))
    stride = max(1, int(round(rate / cfg.covariance_rate)))
    aiding = bool(cfg.unit_aiding and inputs.unit_rpy is not None)
    unit_rpy = inputs.unit_rpy if inputs.unit_rpy is not None else np.zeros((len(t), 3))
    info["unit_aiding"] = aiding
    (states, pos_var, vel_var, att_cov, valid, angles, att_sigma, ep_row, epoch_sigma, innov, innov_var,
     status) = load_kernel("ins").run_ins(t, inputs.gyro, inputs.accel, start_row, x0, P0, fix_row, fix_lag, z_fix,
                                          r_fix, cfg.lever_arm_gnss, noise.as_array(cfg), stride, cfg.gate_chi2,
                                          MAX_CONSECUTIVE_REJECTS, unit_rpy, aiding, smooth)
    roll, pitch, yaw = angles[:, 0], angles[:, 1], angles[:, 2]
    lat = np.where(valid, states[:, 0], states[start_row, 0])
    lon = np.where(valid, states[:, 1], states[start_row, 1])
    height = np.where(valid, states[:, 2], states[start_row, 2])
    v_e = np.einsum("nij,nj->ni", C_n_e(lat, lon), states[:, 3:6])
    r_e = geodetic_to_ecef(lat, lon, height)
    for array in (r_e, v_e, pos_var):
        array[~valid] = np.nan
    full_status = np.full(len(gnss), -1, dtype=int)
    full_innov = np.full((len(gnss), 3), np.nan)
    full_var = np.full((len(gnss), 3), np.nan)
    full_status[use], full_innov[use], full_var[use] = status, innov, innov_var
    full_status[start_fix] = 1
    vel_var[~valid] = np.nan
    info.update({"vel_var_n": vel_var, "gyro_bias": states[:, 10:13], "accel_bias": states[:, 13:16],
                 "unit_yaw_origin": states[:, 16], "epoch_rows": ep_row,
                 "epoch_sigma": epoch_sigma, "start_row": start_row,
                 "covariance_stride": stride, "smoothed": smooth})
    return NavSolution(
        method="rts" if smooth else "ekf", time=t, r_e=r_e, v_e=v_e, lat=lat, lon=lon, height=height,
        roll=roll, pitch=pitch, yaw=yaw, pos_var_n=pos_var, att_sigma=att_sigma, valid=valid,
        gnss=GnssUse(time=gnss.time, status=full_status, innovation=full_innov, innovation_var=full_var,
                     line=gnss.line),
        info=info, att_cov_n=att_cov,
    )


def inputs_from_pos(log, use_unit_attitude: bool = True) -> InsInputs:
    """INS inputs from a POS log: OMGS [deg/s] -> rad/s, ACCS [m/s^2]; the unit's angles for alignment."""
    unit_rpy = None
    iacc = None
    if use_unit_attitude and all(r in log.data for r in ("roll", "pitch", "yaw")):
        unit_rpy = np.radians(np.stack([log.data["roll"], log.data["pitch"], log.data["yaw"]], -1))
        if all(f"iacc_{a}" in log.data for a in "xyz"):
            iacc = log.vector("iacc")
    return InsInputs(time=log.time, gyro=np.radians(log.vector("gyro")), accel=log.vector("acc"), gnss=log.gnss,
                     unit_rpy=unit_rpy, iacc=iacc, source=str(log.path))


def solve_rts(log, cfg: ProcessingConfig) -> NavSolution:
    """``--method rts``: EKF and RTS smoother on a POS log."""
    return solve_ins(inputs_from_pos(log), cfg, smooth=True)


def solve_ekf(log, cfg: ProcessingConfig) -> NavSolution:
    """``--method ekf``: the forward EKF alone on a POS log."""
    return solve_ins(inputs_from_pos(log), cfg, smooth=False)
