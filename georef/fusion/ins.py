"""Full-state INS/GNSS fusion (``ekf``, ``rts``): alignment from the motion, a noise model fitted to the data,
an error-state EKF that restarts when it diverges, and the RTS smoother.

Inputs are the raw body-frame rates and specific forces (POS.txt ``OMGS_*`` in deg/s and ``ACCS_*`` in m/s^2,
or the generic ``imu.csv``) and GNSS antenna fixes; optionally the POS unit's own roll/pitch/yaw. The steps
(``docs/method-ins.md``):

1. **Alignment** (:mod:`georef.fusion.alignment`): attitude, velocity and biases from the motion over a window
   that grows until the heading is observable; no track-equals-heading assumption. When the motion never shows
   the heading: the unit's yaw with its recovered origin (POS.txt with IACC), a magnetometer, an autopilot's yaw.
2. **Noise model** (:mod:`georef.fusion.noise`): the datasheet preset is the prior; the first pass starts from
   the larger of it and the data's white-noise bound; expectation-maximisation steps over filter + smoother
   passes (covariance epochs at the GNSS rate) fit every noise block, GNSS variances included, to the data.
   These passes also carry the GNSS lever arm and the GNSS time-tag latency as states with loose priors: what
   the data say about them is checked against the given lever arm and reported.
3. **Final pass** at ``cfg.covariance_rate`` with the fitted noise, the given lever arm and the latency (given,
   or the estimate when it is significant), the chi-square gate ``cfg.gate_chi2``.

In every pass, ``MAX_CONSECUTIVE_REJECTS`` fixes rejected in a row mean the filter has diverged: it is
re-aligned from the data at the epoch before the first of them and restarted there (the smoother does not carry
information across a restart), rather than gating the data out.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from georef.align import GnssEpochs
from georef.config import ProcessingConfig
from georef.frames import C_n_e, dcm_to_quat, euler_to_dcm, geodetic_to_ecef
from georef.frames.rotations import dcm_to_euler, euler_error_jacobian, wrap_pi
from georef.fusion import ins_kernel as layout
from georef.fusion.alignment import Alignment, align
from georef.fusion.noise import UNIT_BLOCKS, NoiseModel, datasheet_prior, em_step, starting_point
from georef.fusion.solution import GnssUse, NavSolution
from georef.io.errors import GeorefError
from georef.kernels import load as load_kernel

REQUIRED_ROLES = ("gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z")
#: this many GNSS fixes rejected in a row is a divergence: re-align and restart
MAX_CONSECUTIVE_REJECTS = 4
#: restarts allowed in one pass; after that the remaining fixes are no longer gated into a restart
MAX_RESTARTS = 10
#: EM steps at most after the likelihood search; they stop earlier once every block's smoothed residuals match
#: their modelled covariance to EM_TOLERANCE (the EM ratio (T + U)/N within 1 +- EM_TOLERANCE)
EM_ITERATIONS = 5
EM_TOLERANCE = 0.05
#: the likelihood search scales the IMU's white noise down to at most this factor of its starting point
IMU_LEVEL_MIN = 1e-4
#: its step [decades]
IMU_LEVEL_STEP = 1.0
#: covariance epochs of the estimation passes [Hz] (every GNSS epoch is one as well)
ESTIMATION_RATE_HZ = 1.0
#: the estimation passes run on the IMU averaged in blocks down to about this rate [Hz]: the white-noise
#: densities they fit are the low-frequency level, which block means keep
ESTIMATION_IMU_RATE_HZ = 10.0
#: the estimation passes' gate: chi-square(3) 99.999 %, only gross outliers, while the noise is being fitted
ESTIMATION_GATE = 25.9
#: prior sigma of the latency state [s] and of the lever-arm state [m] (plus the given lever arm's size)
LATENCY_PRIOR_S = 0.2
LEVER_PRIOR_M = 1.0
#: floor added to the alignment's covariance: it models neither IMU noise nor bias instability
ALIGNMENT_FLOOR = np.concatenate([np.full(3, 0.1), np.full(3, 0.05), np.radians([0.05, 0.05, 0.2]),
                                  np.full(3, 2e-5), np.full(3, 5e-3)]) ** 2


@dataclass
class InsInputs:
    """Everything the full-state filters use, SI units.

    ``time`` [s], ``gyro`` [rad/s] and ``accel`` [m/s^2] (N, 3) in the body frame; GNSS fixes; optionally the
    unit's own roll/pitch/yaw [rad] (N, 3) whose yaw has an unknown origin, its level-frame acceleration IACC
    [m/s^2] (N, 3), a magnetometer (N, 3) in the body frame (any unit), and an autopilot's absolute yaw [rad] (N,).
    """

    time: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    gnss: GnssEpochs
    unit_rpy: np.ndarray | None = None
    iacc: np.ndarray | None = None
    source: str = "IMU"
    mag: np.ndarray | None = None
    autopilot_yaw: np.ndarray | None = None


@dataclass
class Restart:
    """A re-alignment after a divergence: the row and time [s] it restarted from, and why."""

    row: int
    time: float
    reason: str


@dataclass
class Calibration:
    """What the data say about the GNSS lever arm [m, body] and the GNSS time-tag latency [s], with 1-sigma."""

    lever_arm: np.ndarray
    lever_arm_sigma: np.ndarray
    latency: float
    latency_sigma: float


@dataclass
class InsDiagnostics:
    """How the full-state solution was reached, for the summary, the report and the quality checks."""

    alignment: Alignment
    heading_source: str
    noise_prior: NoiseModel
    noise: NoiseModel
    em_ratios: list[dict[int, float]]
    restarts: list[Restart]
    calibration: Calibration | None
    lever_arm_given: np.ndarray
    latency_applied: float
    gate_chi2: float
    nis: np.ndarray                 # per GNSS fix of the final pass, NaN where not processed
    unit_aiding: bool
    estimation_restarts: int = 0
    imu_noise_factor: float = 1.0
    estimation_passes: int = 0
    notes: list[str] = field(default_factory=list)


@dataclass
class _Fixes:
    row: np.ndarray      # the IMU row at or after each fix
    lag: np.ndarray      # t[row] - t_fix [s]
    z: np.ndarray        # lat, lon [rad], h [m]
    r: np.ndarray        # NED variances [m^2]
    index: np.ndarray    # index into the GnssEpochs


@dataclass
class _Pass:
    """One complete filter (and smoother) pass over the log, all segments merged."""

    nav: np.ndarray
    ep_row: np.ndarray
    ep_Pp: np.ndarray       # smoothed covariances after the backward pass
    ep_Pm: np.ndarray
    seg_start: np.ndarray
    fix_status: np.ndarray
    fix_z: np.ndarray
    fix_S: np.ndarray
    fix_d2: np.ndarray
    stats: np.ndarray | None
    restarts: list[Restart]
    rows: tuple | None     # finish_rows outputs (None when not asked for)
    loglik: np.ndarray     # innovation log-likelihood of the forward pass: GNSS fixes, unit updates
    first_state: np.ndarray | None = None   # smoothed nominal state at the first epoch
    last_state: np.ndarray | None = None    # and at the last epoch


def _fix_table(inputs: InsInputs, cfg: ProcessingConfig, start_row: int) -> _Fixes:
    gnss, t = inputs.gnss, inputs.time
    use = np.flatnonzero((gnss.time > t[start_row]) & (gnss.time <= t[-1]))
    row = np.searchsorted(t, gnss.time[use], side="left")
    z = np.stack([np.radians(gnss.lat_deg[use]), np.radians(gnss.lon_deg[use]), gnss.height[use]], -1)
    sigma = _fix_sigmas(gnss, cfg)[use]
    return _Fixes(row=row, lag=t[row] - gnss.time[use], z=z, r=sigma**2, index=use)


def _fix_sigmas(gnss: GnssEpochs, cfg: ProcessingConfig) -> np.ndarray:
    """NED sigmas [m] of every fix: the file's own where given, else ``cfg.gnss_sigma``."""
    default = np.tile(np.asarray(cfg.gnss_sigma, float), (len(gnss), 1))
    if gnss.sigma_neu is None:
        return default
    return np.where(np.isfinite(gnss.sigma_neu), gnss.sigma_neu, default)


def unit_drift_psd(cfg: ProcessingConfig) -> float:
    """Density [rad^2/s^3] of the random walk of the unit's yaw-origin drift rate, from
    ``cfg.unit_drift_change`` [deg/min per sqrt(min)]."""
    return float((np.radians(cfg.unit_drift_change) / 60.0 / np.sqrt(60.0)) ** 2)


def noise_prior(cfg: ProcessingConfig) -> NoiseModel:
    """The datasheet prior of ``cfg`` (IMU preset + overrides, the unit's error settings)."""
    return datasheet_prior(cfg.imu_error_model(), cfg.unit_level_sigma, cfg.unit_level_time, unit_drift_psd(cfg),
                           cfg.unit_angle_noise)


# ---- alignment and its fallbacks ---------------------------------------------------------------------------
def initial_alignment(inputs: InsInputs, cfg: ProcessingConfig, start_time: float | None = None,
                      bias_g: np.ndarray | None = None, bias_a: np.ndarray | None = None) -> Alignment:
    """Alignment from the motion; when the motion never shows the heading, the best other heading source."""
    gnss = inputs.gnss
    sigma = _fix_sigmas(gnss, cfg)
    try:
        result = align(inputs.time, inputs.gyro, inputs.accel, gnss.time, np.radians(gnss.lat_deg),
                       np.radians(gnss.lon_deg), gnss.height, sigma, np.asarray(cfg.lever_arm_gnss), start_time,
                       bias_g, bias_a)
    except ValueError as exc:
        raise GeorefError(f"{inputs.source}: cannot align the INS: {exc}") from None
    if result.observable:
        result.heading_source = (f"motion (optimisation-based alignment over {result.window[1] - result.window[0]:.0f}"
                                 f" s, heading sigma {np.degrees(result.heading_sigma):.2f} deg)")
        return result
    heading, heading_sigma, source = _other_heading(inputs, cfg, result)
    if heading is None:
        result.heading_source = ("none: the heading is not observable from the motion and there is no unit yaw, "
                                 "magnetometer or autopilot yaw")
        return result
    roll, pitch, yaw = dcm_to_euler(result.C_b_n)
    result.C_b_n = euler_to_dcm(roll, pitch, heading)
    P = result.covariance
    P[layout.ATT + 2, :] = 0.0
    P[:, layout.ATT + 2] = 0.0
    P[layout.ATT + 2, layout.ATT + 2] = heading_sigma**2
    result.heading_sigma = heading_sigma
    result.heading_source = source
    return result


def _other_heading(inputs: InsInputs, cfg: ProcessingConfig, alignment: Alignment):
    """(heading [rad], sigma [rad], description) at the alignment's start row, or (None, None, None)."""
    row = alignment.start_row
    roll, pitch, _ = dcm_to_euler(alignment.C_b_n)
    if inputs.unit_rpy is not None and inputs.iacc is not None:
        from georef.fusion.yaw_offset import recover_yaw_offset

        gnss = inputs.gnss
        try:
            solution = recover_yaw_offset(gnss.time, gnss.lat_deg, gnss.lon_deg, gnss.height, inputs.time,
                                          inputs.iacc, inputs.unit_rpy, np.asarray(cfg.lever_arm_gnss),
                                          cfg.gnss_sigma[:2], window=cfg.yaw_window, step=cfg.yaw_step,
                                          bandwidth=cfg.yaw_bandwidth)
            offset, offset_sigma = solution.at(np.array([inputs.time[row]]))
            return (float(wrap_pi(inputs.unit_rpy[row, 2] + offset[0])), max(float(offset_sigma[0]), np.radians(0.1)),
                    "unit yaw + origin recovered from IACC and GNSS")
        except ValueError:
            pass
    if inputs.mag is not None:
        m = inputs.mag[row:row + 50].mean(axis=0)
        C_level = euler_to_dcm(roll, pitch, 0.0)  # body -> heading-free level frame
        m_level = C_level @ m
        heading = float(wrap_pi(-np.arctan2(m_level[1], m_level[0]) + np.radians(cfg.magnetic_declination)))
        return heading, np.radians(10.0), "magnetometer (declination from the configuration, sigma 10 deg)"
    if inputs.autopilot_yaw is not None:
        return float(inputs.autopilot_yaw[row]), np.radians(5.0), "autopilot yaw (sigma 5 deg)"
    return None, None, None


def _initial_state(inputs: InsInputs, cfg: ProcessingConfig, alignment: Alignment, noise: NoiseModel,
                   calibrate: bool, lever: np.ndarray, latency: float) -> tuple[np.ndarray, np.ndarray]:
    """Nominal state (NS,) and covariance (nx, nx) at the alignment's start row."""
    nx = layout.NX_CAL if calibrate else layout.NX_NAV
    x0 = np.zeros(layout.NS)
    x0[layout.X_LAT:layout.X_HGT + 1] = alignment.position
    x0[layout.X_VEL:layout.X_VEL + 3] = alignment.v_n
    x0[layout.X_QUAT:layout.X_QUAT + 4] = dcm_to_quat(alignment.C_b_n)
    x0[layout.X_BG:layout.X_BG + 3] = alignment.gyro_bias
    x0[layout.X_BA:layout.X_BA + 3] = alignment.accel_bias
    x0[layout.X_LEVER:layout.X_LEVER + 3] = lever
    x0[layout.X_LATENCY] = latency
    P0 = np.zeros((nx, nx))
    P0[:15, :15] = 4.0 * alignment.covariance + np.diag(ALIGNMENT_FLOOR)
    level = np.radians(cfg.unit_level_sigma)
    P0[layout.UNIT_LEVEL, layout.UNIT_LEVEL] = P0[layout.UNIT_LEVEL + 1, layout.UNIT_LEVEL + 1] = level**2
    P0[layout.UNIT_DRIFT, layout.UNIT_DRIFT] = (np.radians(2.0) / 60.0) ** 2
    if inputs.unit_rpy is not None:
        row = alignment.start_row
        roll, pitch, yaw = dcm_to_euler(alignment.C_b_n)
        x0[layout.X_UNIT_YAW] = float(wrap_pi(yaw - inputs.unit_rpy[row, 2]))
        # the origin's error equals the yaw error: d_est - d = yaw_est - yaw = -(J φ)_yaw
        j_yaw = euler_error_jacobian(roll, pitch, yaw)[2]
        row_att = -j_yaw @ P0[layout.ATT:layout.ATT + 3, :15]
        P0[layout.UNIT_YAW, :15] = row_att
        P0[:15, layout.UNIT_YAW] = row_att
        att = slice(layout.ATT, layout.ATT + 3)
        P0[layout.UNIT_YAW, layout.UNIT_YAW] = float(j_yaw @ P0[att, att] @ j_yaw) + noise.r_unit_yaw
    else:
        P0[layout.UNIT_YAW, layout.UNIT_YAW] = 1.0
    if calibrate:
        for i in range(3):
            P0[layout.LEVER + i, layout.LEVER + i] = (LEVER_PRIOR_M + abs(lever[i])) ** 2
        P0[layout.LATENCY, layout.LATENCY] = LATENCY_PRIOR_S**2
    return x0, P0


# ---- one pass ------------------------------------------------------------------------------------------------
def _run_pass(inputs: InsInputs, cfg: ProcessingConfig, alignment: Alignment, noise: NoiseModel, fixes: _Fixes,
              stride: int, gate: float, calibrate: bool, smooth: bool, want_stats: bool, lever: np.ndarray,
              latency: float, start_state: np.ndarray | None = None, rows_wanted: bool = True) -> _Pass:
    """Forward filter over every segment (restarting after divergences), then the smoother if ``smooth``."""
    kernel = load_kernel("ins")
    t = inputs.time
    n = len(t)
    aiding = bool(cfg.unit_aiding and inputs.unit_rpy is not None)
    unit_rpy = inputs.unit_rpy if inputs.unit_rpy is not None else np.zeros((n, 3))
    noise_vec = noise.as_array()
    nav = np.full((n, layout.NS), np.nan)
    m = len(fixes.row)
    nx = layout.NX_CAL if calibrate else layout.NX_NAV
    fix_epoch = np.full(m, -1, dtype=np.int64)
    fix_status = np.full(m, layout.FIX_UNUSED, dtype=np.int64)
    fix_z = np.full((m, 3), np.nan)
    fix_H = np.zeros((m, 3, nx))
    fix_S = np.full((m, 3, 3), np.nan)
    fix_d2 = np.full(m, np.nan)
    epochs: list[tuple] = []
    units: list[tuple] = []
    restarts: list[Restart] = []
    x0, P0 = _initial_state(inputs, cfg, alignment, noise, calibrate, lever, latency)
    if start_state is not None:
        # an earlier pass's smoothed state at the start row: a better point to linearise about (the covariance
        # stays the alignment's)
        x0 = start_state.copy()
        x0[layout.X_LEVER:layout.X_LEVER + 3] = lever
        x0[layout.X_LATENCY] = latency
    loglik = np.zeros(2)
    start_row = alignment.start_row
    max_rejects = MAX_CONSECUTIVE_REJECTS
    offset = 0
    while True:
        out = kernel.ekf_forward(t, inputs.gyro, inputs.accel, start_row, x0, P0, fixes.row, fixes.lag, fixes.z,
                                 fixes.r, noise_vec, stride, gate, max_rejects, unit_rpy, aiding, nav)
        (ep_row, ep_dT, ep_Pm, ep_Pp, ep_Phi, ep_dx, f_epoch, f_z, f_H, f_S, f_d2, f_status, u_epoch, u_z, u_H,
         u_status, stop, segment_loglik) = out
        loglik += segment_loglik
        keep = len(ep_row)
        if stop[2] == layout.STOP_DIVERGED:
            first = int(stop[1])
            # restart at the epoch before the one that rejected the first of the run
            keep = max(int(f_epoch[first]), 1)
        processed = (f_epoch >= 0) & (f_epoch < keep)
        fix_epoch[processed] = f_epoch[processed] + offset
        for target, source in ((fix_status, f_status), (fix_z, f_z), (fix_H, f_H),
                               (fix_S, f_S), (fix_d2, f_d2)):
            target[processed] = source[processed]
        later = (f_epoch >= keep)
        fix_status[later] = layout.FIX_UNUSED
        unit_keep = u_epoch < keep
        epochs.append((ep_row[:keep], ep_dT[:keep], ep_Pm[:keep], ep_Pp[:keep], ep_Phi[:keep], ep_dx[:keep]))
        units.append((u_epoch[unit_keep] + offset, u_z[unit_keep], u_H[unit_keep], u_status[unit_keep]))
        offset += keep
        if stop[2] != layout.STOP_DIVERGED:
            break
        start_row = int(ep_row[keep - 1])
        first_fix = fixes.index[int(stop[1])]
        reason = (f"{MAX_CONSECUTIVE_REJECTS} GNSS fixes in a row rejected from {inputs.gnss.time[first_fix]:.1f} s "
                  f"(line {int(inputs.gnss.line[first_fix])})")
        restarts.append(Restart(row=start_row, time=float(t[start_row]), reason=reason))
        if len(restarts) >= MAX_RESTARTS:
            max_rejects = 0
        x_prev = nav[start_row].copy()
        try:
            again = initial_alignment(inputs, cfg, start_time=float(t[start_row]),
                                      bias_g=x_prev[layout.X_BG:layout.X_BG + 3],
                                      bias_a=x_prev[layout.X_BA:layout.X_BA + 3])
            again.start_row = start_row
            x0, P0 = _initial_state(inputs, cfg, again, noise, calibrate, x_prev[layout.X_LEVER:layout.X_LEVER + 3],
                                    float(x_prev[layout.X_LATENCY]))
            x0[layout.X_UNIT_LEVEL:layout.X_UNIT_DRIFT + 1] = x_prev[layout.X_UNIT_LEVEL:layout.X_UNIT_DRIFT + 1]
            if inputs.unit_rpy is not None:
                _, _, yaw = dcm_to_euler(again.C_b_n)
                x0[layout.X_UNIT_YAW] = float(wrap_pi(yaw - inputs.unit_rpy[start_row, 2]))
        except GeorefError:
            # not enough data left to re-align: go on from the old state with an open covariance, ungated
            x0 = x_prev
            P0 = np.diag(np.diag(P0)) * 100.0
            max_rejects = 0
    ep_row = np.concatenate([e[0] for e in epochs])
    ep_dT = np.concatenate([e[1] for e in epochs])
    ep_Pm = np.concatenate([e[2] for e in epochs])
    ep_Pp = np.concatenate([e[3] for e in epochs])
    ep_Phi = np.concatenate([e[4] for e in epochs])
    ep_dx = np.concatenate([e[5] for e in epochs])
    seg_start = np.zeros(len(ep_row), dtype=bool)
    seg_start[np.cumsum([0, *[len(e[0]) for e in epochs[:-1]]])] = True
    u_epoch = np.concatenate([u[0] for u in units])
    u_z = np.concatenate([u[1] for u in units])
    u_H = np.concatenate([u[2] for u in units])
    u_status = np.concatenate([u[3] for u in units])
    stats = None
    rows = None
    first_state = last_state = None
    if smooth:
        err_post, err_pre, stats = kernel.rts_backward(ep_dT, ep_Pm, ep_Pp, ep_Phi, ep_dx, seg_start, noise_vec,
                                                       fix_epoch, fix_z, fix_H, fixes.r, fix_status, u_epoch, u_z, u_H,
                                                       u_status, want_stats)
        first_state = kernel.corrected(nav[ep_row[0]], err_post[0])
        last_state = kernel.corrected(nav[ep_row[-1]], err_post[-1])
        if rows_wanted:
            rows = kernel.finish_rows(t, nav, ep_row, err_post, err_pre, ep_Pp, ep_Pp)
    elif rows_wanted:
        zeros = np.zeros((len(ep_row), nx))
        rows = kernel.finish_rows(t, nav, ep_row, zeros, zeros, ep_Pp, ep_Pm)
    return _Pass(nav=nav, ep_row=ep_row, ep_Pp=ep_Pp, ep_Pm=ep_Pm, seg_start=seg_start, fix_status=fix_status,
                 fix_z=fix_z, fix_S=fix_S, fix_d2=fix_d2, stats=stats if want_stats else None, restarts=restarts,
                 rows=rows, loglik=loglik, first_state=first_state, last_state=last_state)


def _calibration(run: _Pass) -> Calibration:
    """The smoothed lever arm and latency (random constants) of an estimation pass, from its last epoch."""
    sigma = np.sqrt(np.maximum(np.diag(run.ep_Pp[-1]), 0.0))
    return Calibration(lever_arm=run.last_state[layout.X_LEVER:layout.X_LEVER + 3].copy(),
                       lever_arm_sigma=sigma[layout.LEVER:layout.LEVER + 3],
                       latency=float(run.last_state[layout.X_LATENCY]), latency_sigma=float(sigma[layout.LATENCY]))


def _decimated(inputs: InsInputs, start_row: int, factor: int) -> tuple[InsInputs, int]:
    """The IMU averaged over blocks of ``factor`` rows, one block centred on every ``factor``-th row counted from
    ``start_row`` (which stays a sample, at its own time); the unit's angles sampled at those rows. Returns the
    inputs and the start row's new index."""
    if factor <= 1:
        return inputs, start_row
    n = len(inputs.time)
    centres = np.arange(start_row % factor, n, factor)
    lo = np.clip(centres - factor // 2, 0, n)
    hi = np.clip(lo + factor, 0, n)

    def block_mean(values: np.ndarray) -> np.ndarray:
        cum = np.concatenate([np.zeros((1, values.shape[1])), np.cumsum(values, axis=0)])
        return (cum[hi] - cum[lo]) / (hi - lo)[:, None]

    decimated = InsInputs(time=inputs.time[centres], gyro=block_mean(inputs.gyro), accel=block_mean(inputs.accel),
                          gnss=inputs.gnss, unit_rpy=None if inputs.unit_rpy is None else inputs.unit_rpy[centres],
                          source=inputs.source)
    return decimated, int(np.searchsorted(centres, start_row))


class _Estimation:
    """The estimation passes: noise blocks by EM, the IMU's white-noise level by the innovation likelihood, the
    lever arm and latency as states. Covariance epochs at ``ESTIMATION_RATE_HZ``; every pass starts from the
    previous one's smoothed state at the start row."""

    def __init__(self, inputs: InsInputs, cfg: ProcessingConfig, alignment: Alignment, prior: NoiseModel,
                 blocks: tuple[int, ...], lever: np.ndarray, latency: float):
        rate = 1.0 / float(np.median(np.diff(inputs.time)))
        factor = max(1, int(round(rate / ESTIMATION_IMU_RATE_HZ)))
        self.inputs, start_row = _decimated(inputs, alignment.start_row, factor)
        self.alignment = replace(alignment, start_row=start_row)
        self.fixes = _fix_table(self.inputs, cfg, start_row)
        stride = max(1, int(round(rate / factor / ESTIMATION_RATE_HZ)))
        self.cfg = cfg
        self.prior, self.blocks, self.lever, self.latency, self.stride = prior, blocks, lever, latency, stride
        self.ratios: list[dict[int, float]] = []
        self.start_state: np.ndarray | None = None
        self.calibration: Calibration | None = None
        self.restarts = 0
        self.passes = 0
        self.imu_factor = 1.0

    def _pass(self, noise: NoiseModel, smooth: bool, calibrate: bool = False) -> _Pass:
        self.passes += 1
        run = _run_pass(self.inputs, self.cfg, self.alignment, noise, self.fixes, self.stride, ESTIMATION_GATE,
                        calibrate=calibrate, smooth=smooth, want_stats=smooth, lever=self.lever, latency=self.latency,
                        start_state=self.start_state, rows_wanted=False)
        self.restarts = len(run.restarts)
        return run

    def _em(self, noise: NoiseModel, calibrate: bool = False) -> tuple[NoiseModel, float]:
        """One accelerated EM step; returns the new model and the largest inconsistency of a block before the
        step, ``|(T + U)/N - 1|`` (0 when the smoothed residuals match their modelled covariance)."""
        run = self._pass(noise, smooth=True, calibrate=calibrate)
        self.start_state = run.first_state
        if calibrate:
            self.calibration = _calibration(run)
        new, ratios = em_step(noise, self.prior, run.stats, self.blocks)
        self.ratios.append(ratios)
        return new, max(abs(r - 1.0) for r in ratios.values())

    def _imu_level(self, noise: NoiseModel) -> NoiseModel:
        """Scale all four white-noise densities of the IMU by the factor that maximises the forward innovation
        likelihood: down from 1 a decade at a time while it improves, then the vertex of a parabola through the
        best three (in log factor). EM-type steps alone crawl along this direction when the start is far too
        large."""
        def loglik(factor: float) -> float:
            run = self._pass(_scale_imu(noise, factor), smooth=False)
            return float(run.loglik.sum())

        logs = [0.0]
        values = [loglik(1.0)]
        while 10.0 ** logs[-1] > IMU_LEVEL_MIN:
            logs.append(logs[-1] - IMU_LEVEL_STEP)
            values.append(loglik(10.0 ** logs[-1]))
            if values[-1] <= values[-2]:
                break
        k = int(np.argmax(values))
        best = logs[k]
        if 0 < k < len(logs) - 1:
            # vertex of the parabola through the three points around the maximum (equal spacing in log factor)
            a, b, c = values[k - 1], values[k], values[k + 1]
            curvature = a - 2.0 * b + c
            if curvature < 0:
                best = logs[k] + 0.5 * IMU_LEVEL_STEP * (a - c) / curvature
        factor = 10.0**best
        self.imu_factor *= factor
        return _scale_imu(noise, factor)

    def run(self, start: NoiseModel) -> NoiseModel:
        noise = self._imu_level(start)
        for _ in range(EM_ITERATIONS):
            noise, inconsistency = self._em(noise)
            if inconsistency < EM_TOLERANCE:
                break
        # a last step with the lever arm and latency as states: what the data say about them
        noise, _ = self._em(noise, calibrate=True)
        return noise


def _scale_imu(noise: NoiseModel, factor: float) -> NoiseModel:
    return replace(noise, q_vel_h=noise.q_vel_h * factor, q_vel_v=noise.q_vel_v * factor,
                   q_att_h=noise.q_att_h * factor, q_att_v=noise.q_att_v * factor)


def solve_ins(inputs: InsInputs, cfg: ProcessingConfig, smooth: bool = True) -> NavSolution:
    """EKF (``smooth=False``) or EKF + RTS smoother solution at every IMU row (see the module docstring)."""
    t = np.ascontiguousarray(inputs.time, dtype=float)
    if len(t) < 10 or np.any(np.diff(t) <= 0):
        raise GeorefError(f"{inputs.source}: IMU times must increase strictly")
    inputs.time = t
    gnss = inputs.gnss
    if np.count_nonzero((gnss.time >= t[0]) & (gnss.time <= t[-1])) < 6:
        raise GeorefError(f"{inputs.source}: the full-state filter needs at least six GNSS fixes inside the IMU span "
                          f"({t[0]:.1f} - {t[-1]:.1f} s)")
    alignment = initial_alignment(inputs, cfg)
    fixes = _fix_table(inputs, cfg, alignment.start_row)
    rate = 1.0 / float(np.median(np.diff(t)))
    lever = np.asarray(cfg.lever_arm_gnss, dtype=float)
    prior = noise_prior(cfg)
    aiding = bool(cfg.unit_aiding and inputs.unit_rpy is not None)
    blocks = tuple(b for b in range(layout.N_BLOCKS) if aiding or b not in UNIT_BLOCKS)
    given_latency = cfg.gnss_latency
    estimation = _Estimation(inputs, cfg, alignment, prior, blocks, lever, given_latency or 0.0)
    noise = estimation.run(starting_point(prior, t, inputs.gyro, inputs.accel))
    calibration = estimation.calibration
    latency = given_latency if given_latency is not None else 0.0
    if given_latency is None and calibration is not None and \
            abs(calibration.latency) > 3.0 * calibration.latency_sigma:
        latency = calibration.latency
    stride = max(1, int(round(rate / cfg.covariance_rate)))
    final = _run_pass(inputs, cfg, alignment, noise, fixes, stride, cfg.gate_chi2, calibrate=False, smooth=smooth,
                      want_stats=False, lever=lever, latency=latency, start_state=estimation.start_state)
    valid, pos_var, vel_var, att_cov, angles, att_sigma, epoch_sigma = final.rows
    states = final.nav
    start_row = alignment.start_row
    lat = np.where(valid, states[:, layout.X_LAT], states[start_row, layout.X_LAT])
    lon = np.where(valid, states[:, layout.X_LON], states[start_row, layout.X_LON])
    height = np.where(valid, states[:, layout.X_HGT], states[start_row, layout.X_HGT])
    v_e = np.einsum("nij,nj->ni", C_n_e(lat, lon), states[:, layout.X_VEL:layout.X_VEL + 3])
    r_e = geodetic_to_ecef(lat, lon, height)
    for array in (r_e, v_e, pos_var, vel_var):
        array[~valid] = np.nan
    full_status = np.full(len(gnss), -1, dtype=int)
    full_innov = np.full((len(gnss), 3), np.nan)
    full_var = np.full((len(gnss), 3), np.nan)
    full_nis = np.full(len(gnss), np.nan)
    full_status[fixes.index] = final.fix_status
    full_innov[fixes.index] = final.fix_z
    full_var[fixes.index] = np.diagonal(final.fix_S, axis1=1, axis2=2)
    full_nis[fixes.index] = final.fix_d2
    diagnostics = InsDiagnostics(
        alignment=alignment, heading_source=alignment.heading_source, noise_prior=prior, noise=noise,
        em_ratios=estimation.ratios, restarts=final.restarts, calibration=calibration, lever_arm_given=lever,
        latency_applied=latency, gate_chi2=cfg.gate_chi2, nis=full_nis, unit_aiding=aiding,
        estimation_restarts=estimation.restarts, imu_noise_factor=estimation.imu_factor,
        estimation_passes=estimation.passes)
    info = {"vel_var_n": vel_var, "gyro_bias": states[:, layout.X_BG:layout.X_BG + 3],
            "accel_bias": states[:, layout.X_BA:layout.X_BA + 3], "unit_yaw_origin": states[:, layout.X_UNIT_YAW],
            "epoch_rows": final.ep_row, "epoch_sigma": epoch_sigma, "start_row": start_row,
            "smoothed": smooth, "heading_source": alignment.heading_source, "unit_aiding": aiding}
    return NavSolution(
        method="rts" if smooth else "ekf", time=t, r_e=r_e, v_e=v_e, lat=lat, lon=lon, height=height,
        roll=angles[:, 0], pitch=angles[:, 1], yaw=angles[:, 2], pos_var_n=pos_var, att_sigma=att_sigma, valid=valid,
        gnss=GnssUse(time=gnss.time, status=full_status, innovation=full_innov, innovation_var=full_var,
                     line=gnss.line, nis=full_nis),
        info=info, att_cov_n=att_cov, diagnostics=diagnostics,
    )


def inputs_from_pos(log, use_unit_attitude: bool = True) -> InsInputs:
    """INS inputs from a POS log: OMGS [deg/s] -> rad/s, ACCS [m/s^2]; the unit's angles when present."""
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
