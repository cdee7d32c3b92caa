"""Full-state INS/GNSS fusion (``ekf``, ``rts``): alignment from the motion, a noise model fitted to the data,
an error-state EKF that recovers from drift and divergence, and the RTS smoother.

Inputs are the raw body-frame rates and specific forces (POS.txt ``OMGS_*`` in deg/s and ``ACCS_*`` in m/s^2,
or the generic ``imu.csv``) and GNSS antenna fixes; optionally the POS unit's own roll/pitch/yaw. The steps
(``docs/method-ins.md``):

1. **IMU gaps** (:func:`imu_gaps`): time gaps and linearly interpolated dropouts get the process noise of the
   vehicle's unknown departure from the interpolated line.
2. **Alignment** (:mod:`georef.fusion.alignment`): attitude, velocity and biases from the motion over a window
   that grows until the heading is observable; no track-equals-heading assumption. When the motion never shows
   the heading: the unit's yaw with its recovered origin (POS.txt with IACC), a magnetometer, an autopilot's yaw.
3. **Noise model** (:mod:`georef.fusion.noise`, :class:`_Estimation`): the white noise of the gyros and
   accelerometers from the spectral floor of the data, or the datasheet, whichever predicts held-out fixes
   better (cross-validation); GNSS and unit-attitude variances, bias drives, the non-holonomic constraint's
   variance and the noise inside GNSS outages by expectation-maximisation over filter + smoother passes
   (covariance epochs at the GNSS rate, the IMU block-averaged to about 10 Hz). A ground vehicle is recognised
   from its motion and gets the non-holonomic constraint. A last pass carries the GNSS lever arm and time-tag
   latency as states with loose priors: what the data say about them, checked against the given values.
4. **Final pass** at ``cfg.ins.covariance_rate`` with the fitted noise, the given lever arm and the given latency,
   the chi-square gate ``cfg.gnss_gate.chi2``.

Recovery, in every pass: a run of rejected fixes (two after a GNSS outage or an IMU gap, else
``MAX_CONSECUTIVE_REJECTS``) means the model under-predicted the error growth since the last fix; that stretch
is run again with more process noise, so the smoother still bridges it. The first fixes after an outage are
gated only against gross outliers (re-acquisition). Only when the re-runs fail at one place is the filter
re-aligned from the data there and restarted (the smoother does not carry information across a restart).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from georef.align import GnssEpochs
from georef.config import InsSettings, ProcessingConfig, UnitSection
from georef.frames import C_e_n, C_n_e, dcm_to_quat, euler_to_dcm, geodetic_to_ecef
from georef.frames.mounting import lever_arm_ecef
from georef.frames.rotations import dcm_to_euler, euler_error_jacobian, quat_to_dcm, wrap_pi
from georef.fusion import ins_layout as layout
from georef.fusion.alignment import Alignment, align
from georef.fusion.noise import (
    NHC_BLOCKS,
    UNIT_BLOCKS,
    WHITE_BLOCKS,
    NoiseModel,
    data_prior,
    datasheet_prior,
    em_step,
    inflated,
    starting_point,
)
from georef.fusion.solution import ForwardSeparation, GnssUse, InsInfo, NavSolution
from georef.io.errors import GeorefError
from georef.kernels import load as load_kernel

if TYPE_CHECKING:
    from georef.io.pos import PosLog

REQUIRED_ROLES = ("gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z")
#: this many GNSS fixes rejected in a row is a divergence: re-align and restart
MAX_CONSECUTIVE_REJECTS = 4
#: process noise over an IMU gap. Across a gap the mechanisation integrates the straight line between the real
#: samples on either side (the trapezoid rule; a logger's interpolation does the same), so what is unknown is the
#: vehicle's departure from that line: about jerk * T^2 / 8, for T = 0.5 s and 5 m/s^3 some 0.16 m/s^2, and for
#: an angular acceleration of 0.5 rad/s^2 some 0.016 rad/s. As white noise over the gap: [m^2/s^3], [rad^2/s]
GAP_Q_VEL = 0.02
GAP_Q_ATT = 5e-5
#: restarts allowed in one pass; after that the remaining fixes are no longer gated into a restart
MAX_RESTARTS = 10
#: a GNSS outage longer than this [s], followed by rejected fixes, is re-run with more process noise (the
#: smoother keeps bridging it) instead of a restart, at most MAX_DRIFT_RERUNS times in a pass; the factor is
#: the first fix's normalised innovation over DRIFT_TARGET_CHI2 (between 4 and 1e4)
OUTAGE_S = 3.0
MAX_DRIFT_RERUNS = 20
DRIFT_TARGET_CHI2 = 3.0
#: re-runs with more process noise tried at one place before a re-alignment
SITE_RERUNS = 3
#: EM steps at most after the likelihood search; they stop earlier once every block's smoothed residuals match
#: their modelled covariance to EM_TOLERANCE (the EM ratio (T + U)/N within 1 +- EM_TOLERANCE)
EM_ITERATIONS = 5
EM_TOLERANCE = 0.05
#: when the estimation's first smoothed pass diverges, its process noise is raised tenfold up to this many times
INFLATE_TRIES = 4
#: ground-vehicle test (``cfg.ins.vehicle = "auto"``): speed [m/s], median lateral/speed, rms vertical body
#: velocity [m/s], share of the log moving
GROUND_MIN_SPEED = 3.0
GROUND_MAX_SLIP = 0.03
GROUND_MAX_VERTICAL = 0.3
GROUND_MIN_MOVING = 0.3
#: cross-validation: within the first CV_SPAN_S [s], the last CV_HOLD_S of every CV_PERIOD_S of fixes are held out
#: (at least CV_MIN_HELD of them); white-noise hypotheses closer than WHITE_DISTINCT (ratio) count as one
CV_SPAN_S = 300.0
CV_PERIOD_S = 40.0
CV_HOLD_S = 10.0
CV_MIN_HELD = 5
WHITE_DISTINCT = 3.0
#: the datasheet's white noise replaces the spectral floor only when its held-out log-likelihood is higher by
#: this much (a likelihood ratio of e^2); when the two predict alike, the floor keeps the sigmas honest
CV_MARGIN = 2.0
#: fractions of an EM step tried in turn until one keeps the likelihood
EM_STEP_FRACTIONS = (1.0, 0.5, 0.25)
#: an EM step may lower the innovation log-likelihood by at most this much and still be kept
LOGLIK_TOLERANCE = 0.5
#: covariance epochs of the estimation passes [Hz] (every GNSS epoch is one as well)
ESTIMATION_RATE_HZ = 1.0
#: the estimation passes run on the IMU averaged in blocks down to about this rate [Hz]: the white-noise
#: densities they fit are the low-frequency level, which block means keep
ESTIMATION_IMU_RATE_HZ = 10.0
#: the first estimation pass's gate: chi-square(3) 1 - 1e-8, only gross outliers while the GNSS variances are
#: unknown; the later ones gate as the final pass
ESTIMATION_GATE = 40.1
#: prior sigma of the latency state [s] and of the lever-arm state [m] (plus the given lever arm's size)
LATENCY_PRIOR_S = 0.2
LEVER_PRIOR_M = 1.0
#: re-linearised calibration passes at most, while the lever-arm estimate moves by more than 3 sigma and this [m]
CALIBRATION_ITERATIONS = 3
CALIBRATION_STEP_M = 0.1
#: the filter's prior at the start, where wider than the alignment's resolution: velocity [m/s] (on top of a
#: fix's sigma over sqrt(2)), roll and pitch, heading [deg]
START_SPEED_SIGMA = 0.5
START_LEVEL_SIGMA_DEG = 1.0
START_HEADING_SIGMA_DEG = 2.0


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
    #: IMU gaps as (row before, row after) pairs (:func:`imu_gaps`), filled in by :func:`solve_ins`
    gaps: list[tuple[int, int]] = field(default_factory=list)


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
    estimation_passes: int = 0
    ground_vehicle: bool = False                 # non-holonomic constraints applied
    imu_gaps: list[tuple[float, float]] = field(default_factory=list)  # [s] spans without real IMU data
    ground_test: dict[str, float] = field(default_factory=dict)
    #: per white-noise hypothesis: (q_vel_h [m^2/s^3], held-out log-likelihood, mean normalised squared residual,
    #: number of held fixes)
    cross_validation: list[tuple[float, float, float, int]] = field(default_factory=list)
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
    loglik: np.ndarray     # innovation log-likelihood of the forward pass: GNSS fixes, unit updates, NHC
    first_state: np.ndarray | None = None   # smoothed nominal state at the first epoch
    last_state: np.ndarray | None = None    # and at the last epoch
    diverged: bool = False                  # an estimation pass that stopped at a divergence (no restart)
    #: smoothed passes with rows: the forward filter's nominal state (E, NS) and its position, velocity and
    #: attitude covariance (E, 9, 9) at the epochs, copied before the smoother overwrote the covariances
    forward: tuple[np.ndarray, np.ndarray] | None = None


def _fix_table(inputs: InsInputs, cfg: InsSettings, start_row: int) -> _Fixes:
    gnss, t = inputs.gnss, inputs.time
    use = np.flatnonzero((gnss.time > t[start_row]) & (gnss.time <= t[-1]))
    row = np.searchsorted(t, gnss.time[use], side="left")
    z = np.stack([np.radians(gnss.lat_deg[use]), np.radians(gnss.lon_deg[use]), gnss.height[use]], -1)
    sigma = _fix_sigmas(gnss, cfg)[use]
    return _Fixes(row=row, lag=t[row] - gnss.time[use], z=z, r=sigma**2, index=use)


def _fix_sigmas(gnss: GnssEpochs, cfg: InsSettings) -> np.ndarray:
    """NED sigmas [m] of every fix: the file's own where given, else ``cfg.gnss.sigma``."""
    default = np.tile(np.asarray(cfg.gnss.sigma, float), (len(gnss), 1))
    if gnss.sigma_neu is None:
        return default
    return np.where(np.isfinite(gnss.sigma_neu), gnss.sigma_neu, default)


def imu_gap_limit(time: np.ndarray) -> float:
    """The longest IMU interval [s] the mechanisation bridges (with the process noise of :func:`imu_gaps`):
    5 s or ten sample periods, whichever is longer. Across a longer gap the filter stops and re-aligns after it."""
    return max(5.0, 10.0 * float(np.median(np.diff(time))))


def imu_gaps(time: np.ndarray, gyro: np.ndarray, accel: np.ndarray) -> list[tuple[int, int]]:
    """Spans without a real IMU measurement, as (row before, row after) pairs: time gaps, and runs of samples
    that lie exactly on the straight line between their neighbours in all six channels — a logger's linear
    interpolation over a dropout (the KITTI log has 0.3-0.5 s of them), which no real sensor noise produces.
    A span counts when the real samples on either side are more than ``max(0.15 s, 5 sample periods)`` apart.
    """
    x = np.concatenate([gyro, accel], axis=1)
    second = np.abs(x[2:] - 2.0 * x[1:-1] + x[:-2])
    tol = 1e-9 * (1.0 + np.abs(x[1:-1]))
    dt = np.diff(time)
    uniform = np.abs(dt[1:] - dt[:-1]) <= 1e-6 * np.maximum(dt[1:], 1e-9)
    interpolated = np.concatenate([[False], np.all(second <= tol, axis=1) & uniform, [False]])
    real = np.flatnonzero(~interpolated)
    limit = 5.0 * float(np.median(dt))
    wide = np.flatnonzero(np.diff(time[real]) > limit)
    return [(int(real[i]), int(real[i + 1])) for i in wide]


def _outage_rows(time: np.ndarray, fixes: _Fixes) -> np.ndarray:
    """Rows inside GNSS outages: after a fix that the next one follows by more than OUTAGE_S, up to that next
    fix's row (inclusive), and after the last fix to the end of the log when that is more than OUTAGE_S."""
    rows = np.zeros(len(time), dtype=bool)
    fix_time = time[fixes.row] - fixes.lag
    bounds = list(zip(fixes.row[:-1], fixes.row[1:], np.diff(fix_time), strict=True))
    if len(fixes.row) and time[-1] - fix_time[-1] > OUTAGE_S:
        bounds.append((fixes.row[-1], len(time) - 1, time[-1] - fix_time[-1]))
    for a, b, span in bounds:
        if span > OUTAGE_S:
            rows[a + 1:b + 1] = True
    return rows


def _gap_scale(time: np.ndarray, gaps: list[tuple[int, int]], noise: NoiseModel) -> np.ndarray:
    """Per-row process-noise factors (N, 2) on the white specific force and angular rate, and on the bias drives:
    1, and over IMU gaps the navigation noise raised to the dynamics of a vehicle whose motion is unknown there
    (GAP_Q_VEL, GAP_Q_ATT). The biases do not change because data are missing: their factor stays 1."""
    scale = np.ones((len(time), 2))
    factor = max(GAP_Q_VEL / max(noise.q_vel_h, 1e-30), GAP_Q_ATT / max(noise.q_att_h, 1e-30), 1.0)
    for a, b in gaps:
        scale[a + 1:b + 1, 0] = factor
    return scale


def unit_drift_psd(unit: UnitSection) -> float:
    """Density [rad^2/s^3] of the random walk of the unit's yaw-origin drift rate, from
    ``unit.drift_change`` [deg/min per sqrt(min)]."""
    return float((np.radians(unit.drift_change) / 60.0 / np.sqrt(60.0)) ** 2)


def noise_prior(cfg: InsSettings) -> NoiseModel:
    """The datasheet prior of ``cfg`` (IMU preset + overrides, the unit's error settings)."""
    return datasheet_prior(cfg.imu_error_model(), cfg.unit.level_sigma, cfg.unit.level_time, unit_drift_psd(cfg.unit),
                           cfg.unit.angle_noise)


# ---- alignment and its fallbacks ---------------------------------------------------------------------------
def initial_alignment(inputs: InsInputs, cfg: InsSettings, start_time: float | None = None,
                      bias_g: np.ndarray | None = None, bias_a: np.ndarray | None = None) -> Alignment:
    """Alignment from the motion; when the motion never shows the heading, the best other heading source."""
    gnss = inputs.gnss
    sigma = _fix_sigmas(gnss, cfg)
    try:
        result = align(inputs.time, inputs.gyro, inputs.accel, gnss.time, np.radians(gnss.lat_deg),
                       np.radians(gnss.lon_deg), gnss.height, sigma, np.asarray(cfg.lever_arm_gnss), start_time,
                       bias_g, bias_a, gaps=inputs.gaps,
                       datasheet_bias_sigma=_datasheet_bias_sigma(cfg))
    except ValueError as exc:
        raise GeorefError(f"{inputs.source}: cannot align the INS: {exc}") from None
    if result.observable:
        result.heading_source = (f"motion (optimisation-based alignment over {result.window[1] - result.window[0]:.0f}"
                                 f" s, heading sigma {np.degrees(result.heading_sigma):.2f} deg)")
        if start_time is None:
            _unit_yaw_origin(inputs, cfg, result)
        return result
    heading, heading_sigma, source = _other_heading(inputs, cfg, result)
    if heading is None:
        result.heading_source = ("none: the heading is not observable from the motion and there is no unit yaw, "
                                 "magnetometer or autopilot yaw")
        return result
    roll, pitch, _ = dcm_to_euler(result.C_b_n)
    result.C_b_n = euler_to_dcm(roll, pitch, heading)
    P = result.covariance
    P[layout.ATT + 2, :] = 0.0
    P[:, layout.ATT + 2] = 0.0
    P[layout.ATT + 2, layout.ATT + 2] = heading_sigma**2
    # Without the heading, the gyro bias about the vertical is not observable either: the fit's value is one of
    # many that fit as well (a hovering multicopter's fits ranged over +-0.09 rad/s at equal misfit). It goes back
    # to the prior (zero, with the prior's sigma), so that the yaw's sigma grows as the gyro lets it.
    down_b = result.C_b_n.T @ np.array([0.0, 0.0, 1.0])
    bias_sigma = (result.bias_prior_sigma or _datasheet_bias_sigma(cfg))[0]
    result.gyro_bias = result.gyro_bias - (result.gyro_bias @ down_b) * down_b
    block = slice(layout.BG, layout.BG + 3)
    keep = np.eye(3) - np.outer(down_b, down_b)
    P[block, :] = keep @ P[block, :]
    P[:, block] = P[:, block] @ keep
    P[block, block] += bias_sigma**2 * np.outer(down_b, down_b)
    result.heading_sigma = heading_sigma
    result.heading_source = source
    return result


def _unit_yaw_origin(inputs: InsInputs, cfg: InsSettings, alignment: Alignment) -> None:
    """With the POS unit's level accelerations (IACC): its yaw origin recovered against GNSS over the whole flight
    (:mod:`georef.fusion.yaw_offset`), which the filter does not otherwise see (it has the unit's yaw only
    relative to an origin). When it agrees with the motion's heading (within 3 sigma), the start heading becomes
    the unit's yaw plus the recovered origin with its sigma, and the origin's drift rate its prior; otherwise the
    alignment is left as it is."""
    if inputs.unit_rpy is None or inputs.iacc is None:
        return
    from georef.fusion.yaw_offset import recover_yaw_offset

    gnss = inputs.gnss
    # Overlapping windows (the configured step): side by side, a 3-minute flight had three windows and a
    # 2-deg sigma, and the yaw got worse (today's 20 flights: 0.092 deg against 0.057).
    try:
        solution = recover_yaw_offset(gnss.time, gnss.lat_deg, gnss.lon_deg, gnss.height, inputs.time, inputs.iacc,
                                      inputs.unit_rpy, np.asarray(cfg.lever_arm_gnss), cfg.gnss.sigma[:2],
                                      window=cfg.yaw_offset.window, step=cfg.yaw_offset.step,
                                      bandwidth=cfg.yaw_offset.bandwidth)
    except ValueError:
        return
    row = alignment.start_row
    offset, offset_sigma = solution.at(np.array([inputs.time[row]]))
    heading = float(wrap_pi(inputs.unit_rpy[row, 2] + offset[0]))
    # The recovery treats its overlapping windows as independent, and the filter sees the same GNSS fixes again:
    # its sigmas are widened by sqrt(window / step) (2 with the defaults). Taken at face value, the prior made
    # the yaw overconfident under white vibration (20 flights: 83 % of yaw errors inside 2 sigma; widened 91 %,
    # with the rotor flights' yaw RMS unchanged, 0.057 deg).
    widen = float(np.sqrt(max(cfg.yaw_offset.window / cfg.yaw_offset.step, 1.0)))
    sigma = max(float(offset_sigma[0]) * widen, np.radians(0.05))
    roll, pitch, yaw = dcm_to_euler(alignment.C_b_n)
    if abs(float(wrap_pi(heading - yaw))) > 3.0 * np.hypot(sigma, alignment.heading_sigma):
        return
    alignment.C_b_n = euler_to_dcm(roll, pitch, heading)
    alignment.heading_prior_sigma = sigma
    alignment.unit_drift = (float(solution.drift), max(float(solution.drift_sigma) * widen, np.radians(0.05) / 60.0))
    alignment.yaw_offset = solution
    alignment.heading_source += f"; unit yaw origin from IACC ({np.degrees(sigma):.2f} deg)"


def _datasheet_bias_sigma(cfg: InsSettings) -> tuple[float, float]:
    """Turn-on plus instability sigmas of the gyro [rad/s] and accelerometer [m/s^2] biases of the preset."""
    model = cfg.imu_error_model()
    return (float(np.hypot(model.gyro_turn_on_sigma, model.gyro_markov_sigma)),
            float(np.hypot(model.accel_turn_on_sigma, model.accel_markov_sigma)))


def _other_heading(inputs: InsInputs, cfg: InsSettings, alignment: Alignment):
    """(heading [rad], sigma [rad], description) at the alignment's start row, or (None, None, None)."""
    row = alignment.start_row
    roll, pitch, _ = dcm_to_euler(alignment.C_b_n)
    if inputs.unit_rpy is not None and inputs.iacc is not None:
        from georef.fusion.yaw_offset import recover_yaw_offset

        gnss = inputs.gnss
        try:
            solution = recover_yaw_offset(gnss.time, gnss.lat_deg, gnss.lon_deg, gnss.height, inputs.time,
                                          inputs.iacc, inputs.unit_rpy, np.asarray(cfg.lever_arm_gnss),
                                          cfg.gnss.sigma[:2], window=cfg.yaw_offset.window, step=cfg.yaw_offset.step,
                                          bandwidth=cfg.yaw_offset.bandwidth)
            offset, offset_sigma = solution.at(np.array([inputs.time[row]]))
            return (float(wrap_pi(inputs.unit_rpy[row, 2] + offset[0])), max(float(offset_sigma[0]), np.radians(0.1)),
                    "unit yaw + origin recovered from IACC and GNSS")
        except ValueError:
            pass
    if inputs.mag is not None:
        m = inputs.mag[row:row + 50].mean(axis=0)
        C_level = euler_to_dcm(roll, pitch, 0.0)  # body -> heading-free level frame
        m_level = C_level @ m
        heading = float(wrap_pi(-np.arctan2(m_level[1], m_level[0]) + np.radians(cfg.ins.magnetic_declination)))
        return heading, np.radians(10.0), "magnetometer (declination from the configuration, sigma 10 deg)"
    if inputs.autopilot_yaw is not None:
        return float(inputs.autopilot_yaw[row]), np.radians(5.0), "autopilot yaw (sigma 5 deg)"
    return None, None, None


def _initial_state(inputs: InsInputs, cfg: InsSettings, alignment: Alignment, noise: NoiseModel,
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
    # The alignment gives the point to linearise about. Its covariance came from the same fixes the filter is
    # about to use, so it is not the prior: starting from it counted the first minutes' fixes twice (the
    # smoothed height sigma at the start was 0.10 m for an error of 0.21 m). The prior is what one fix, the
    # datasheet and the alignment's own resolution allow, whichever is wider; no correlations.
    P0 = np.zeros((nx, nx))
    fit = np.diag(alignment.covariance) * 4.0
    sigma_fix = np.asarray(cfg.gnss.sigma, dtype=float)
    sigma_g, sigma_a = _datasheet_bias_sigma(cfg)
    prior = np.concatenate([sigma_fix**2, (sigma_fix / np.sqrt(2.0)) ** 2 + START_SPEED_SIGMA**2,
                            np.radians([START_LEVEL_SIGMA_DEG, START_LEVEL_SIGMA_DEG, START_HEADING_SIGMA_DEG]) ** 2,
                            np.full(3, sigma_g**2), np.full(3, sigma_a**2)])
    P0[np.arange(15), np.arange(15)] = np.maximum(fit, prior)
    if alignment.heading_prior_sigma is not None:
        # the heading from the unit's yaw and its origin recovered from IACC: information of its own
        P0[layout.ATT + 2, layout.ATT + 2] = alignment.heading_prior_sigma**2
    level = np.radians(cfg.unit.level_sigma)
    P0[layout.UNIT_LEVEL, layout.UNIT_LEVEL] = P0[layout.UNIT_LEVEL + 1, layout.UNIT_LEVEL + 1] = level**2
    P0[layout.UNIT_DRIFT, layout.UNIT_DRIFT] = (np.radians(2.0) / 60.0) ** 2
    if alignment.unit_drift is not None:
        # the unit's yaw-origin drift recovered from its own level accelerations (IACC) and GNSS
        x0[layout.X_UNIT_DRIFT] = alignment.unit_drift[0]
        P0[layout.UNIT_DRIFT, layout.UNIT_DRIFT] = alignment.unit_drift[1] ** 2
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
        # The start position is the first fixes' antenna position carried to the IMU through the lever arm and
        # back along the velocity by the latency, both as assumed: r = fix - C_b_n l + v tau. Its error therefore
        # holds the lever arm's and the latency's, dr = -C_b_n dl + v dtau (errors estimate minus truth, NED m).
        # Without these correlations the start position claimed the fixes' few centimetres whatever the lever
        # arm, and each pass moved an untold 1.65 m vertical lever arm only about 0.2 m (to -1.0 +- 0.04 m after
        # the passes allowed).
        P_lever = np.diag((LEVER_PRIOR_M + np.abs(lever)) ** 2)
        P0[layout.LEVER:layout.LEVER + 3, layout.LEVER:layout.LEVER + 3] = P_lever
        P0[layout.LATENCY, layout.LATENCY] = LATENCY_PRIOR_S**2
        pos, lev = slice(layout.POS, layout.POS + 3), slice(layout.LEVER, layout.LEVER + 3)
        G_lever = -alignment.C_b_n
        g_latency = np.asarray(alignment.v_n, float)
        P0[pos, pos] += G_lever @ P_lever @ G_lever.T + np.outer(g_latency, g_latency) * LATENCY_PRIOR_S**2
        P0[pos, lev] = G_lever @ P_lever
        P0[lev, pos] = P0[pos, lev].T
        P0[pos, layout.LATENCY] = g_latency * LATENCY_PRIOR_S**2
        P0[layout.LATENCY, pos] = P0[pos, layout.LATENCY]
    return x0, P0


# ---- one pass ------------------------------------------------------------------------------------------------
def _run_pass(inputs: InsInputs, cfg: InsSettings, alignment: Alignment, noise: NoiseModel, fixes: _Fixes,
              stride: int, gate: float, calibrate: bool, smooth: bool, want_stats: bool, lever: np.ndarray,
              latency: float, start_state: np.ndarray | None = None, rows_wanted: bool = True,
              restart_on_divergence: bool = True, nhc: bool = False) -> _Pass:
    """Forward filter over every segment (re-aligning and restarting after divergences and IMU gaps), then the
    smoother if ``smooth``. Without ``restart_on_divergence`` (estimation passes) a divergence ends the pass and
    marks it ``diverged``: its noise model is not one to keep."""
    kernel = load_kernel("ins")
    t = inputs.time
    n = len(t)
    aiding = bool(cfg.unit.aiding and inputs.unit_rpy is not None)
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
    auxes: list[tuple] = []
    restarts: list[Restart] = []
    x0, P0 = _initial_state(inputs, cfg, alignment, noise, calibrate, lever, latency)
    if start_state is not None:
        # an earlier pass's smoothed state at the start row: a better point to linearise about (the covariance
        # stays the alignment's)
        x0 = start_state.copy()
        x0[layout.X_LEVER:layout.X_LEVER + 3] = lever
        x0[layout.X_LATENCY] = latency
    diverged = False
    start_row = alignment.start_row
    max_rejects = MAX_CONSECUTIVE_REJECTS
    q_scale = _gap_scale(t, inputs.gaps, noise)
    outage_rows = _outage_rows(t, fixes)
    q_scale[outage_rows, :] *= noise.outage_scale
    drift_reruns = 0
    attempts: dict[int, int] = {}
    continuation = False   # the segment continues the previous one from its last kept epoch (a duplicate)
    offset = 0
    while True:
        out = kernel.ekf_forward(t, inputs.gyro, inputs.accel, start_row, x0, P0, fixes.row, fixes.lag, fixes.z,
                                 fixes.r, noise_vec, q_scale, stride, gate, max_rejects, imu_gap_limit(t),
                                 OUTAGE_S, unit_rpy, aiding, nhc, nav)
        (ep_row, ep_dT, ep_Pm, ep_Pp, ep_Phi, ep_dx, f_epoch, f_z, f_H, f_S, f_d2, f_status, a_epoch, a_kind, a_z,
         a_H, a_status, a_r, stop, ep_loglik) = out
        reason_code = int(stop[2])
        keep = len(ep_row)
        if reason_code in (layout.STOP_DRIFT, layout.STOP_DIVERGED):
            site = int(stop[1])
            attempts[site] = attempts.get(site, 0) + 1
            if drift_reruns < MAX_DRIFT_RERUNS and attempts[site] <= SITE_RERUNS:
                # the model under-predicted the error growth since the last fix (an outage, an IMU gap, or just
                # dynamics): run that stretch again with more process noise, which the smoother keeps bridging
                reason_code = layout.STOP_DRIFT
            else:
                # that did not help: re-align from the data there (once; then gate without restarting)
                reason_code = layout.STOP_DIVERGED
                if attempts[site] > SITE_RERUNS + 1:
                    max_rejects = 0
        if reason_code == layout.STOP_DIVERGED:
            # restart at the epoch before the one that rejected the first of the run
            keep = max(int(f_epoch[int(stop[1])]), 1)
        elif reason_code == layout.STOP_DRIFT:
            # go back to the epoch of the last fix before the outage and run the outage again with more
            # process noise: as much more as the first fix after it asks for
            first = int(stop[1])
            before = first - 1
            keep = int(f_epoch[before]) + 1 if before >= 0 and f_epoch[before] >= 0 else 1
            r0 = int(ep_row[keep - 1])
            r1 = int(fixes.row[first])
            q_scale[r0 + 1:r1 + 1, :] *= float(np.clip(f_d2[first] / DRIFT_TARGET_CHI2, 4.0, 1e4))
            drift_reruns += 1
        dup = 1 if continuation else 0
        kept = slice(dup, keep)
        processed = (f_epoch >= dup) & (f_epoch < keep)
        fix_epoch[processed] = f_epoch[processed] - dup + offset
        for target, source in ((fix_status, f_status), (fix_z, f_z), (fix_H, f_H), (fix_S, f_S), (fix_d2, f_d2)):
            target[processed] = source[processed]
        fix_status[f_epoch >= keep] = layout.FIX_UNUSED
        aux_keep = (a_epoch >= dup) & (a_epoch < keep)
        epochs.append((ep_row[kept], ep_dT[kept], ep_Pm[kept], ep_Pp[kept], ep_Phi[kept], ep_dx[kept],
                       ep_loglik[kept], not continuation))
        auxes.append((a_epoch[aux_keep] - dup + offset, a_kind[aux_keep], a_z[aux_keep], a_H[aux_keep],
                      a_status[aux_keep], a_r[aux_keep]))
        offset += keep - dup
        if reason_code == layout.STOP_END:
            break
        if reason_code == layout.STOP_DRIFT:
            start_row = int(ep_row[keep - 1])
            x0 = nav[start_row].copy()
            P0 = ep_Pp[keep - 1].copy()
            continuation = True
            continue
        continuation = False
        if reason_code == layout.STOP_DIVERGED and not restart_on_divergence:
            diverged = True
            break
        if reason_code == layout.STOP_GAP:
            start_row = int(stop[0]) + 1
            reason = (f"IMU gap of {t[start_row] - t[start_row - 1]:.2f} s before {t[start_row]:.2f} s: re-aligned "
                      "after it")
        else:
            start_row = int(ep_row[keep - 1])
            first_fix = fixes.index[int(stop[1])]
            reason = (f"{MAX_CONSECUTIVE_REJECTS} GNSS fixes in a row rejected from "
                      f"{inputs.gnss.time[first_fix]:.1f} s (line {int(inputs.gnss.line[first_fix])})")
        restarts.append(Restart(row=start_row, time=float(t[start_row]), reason=reason))
        if len(restarts) >= MAX_RESTARTS:
            max_rejects = 0
        if start_row >= n - 2:
            break
        x_prev = nav[start_row].copy() if np.isfinite(nav[start_row, 0]) else nav[start_row - 1].copy()
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
    ep_row, ep_dT, ep_Pm, ep_Pp, ep_Phi, ep_dx, loglik = (_joined([e[i] for e in epochs]) for i in range(7))
    loglik = loglik.sum(axis=0)
    seg_start = np.zeros(len(ep_row), dtype=bool)
    starts = np.cumsum([0, *[len(e[0]) for e in epochs[:-1]]])
    seg_start[starts[[e[7] for e in epochs]]] = True
    aux = [_joined([a[i] for a in auxes]) for i in range(6)]
    stats = None
    rows = None
    first_state = last_state = None
    forward = None
    if smooth:
        if rows_wanted:
            forward = (nav[ep_row].copy(), ep_Pp[:, :layout.ATT + 3, :layout.ATT + 3].copy())
        err_post, err_pre, stats = kernel.rts_backward(ep_dT, ep_Pm, ep_Pp, ep_Phi, ep_dx, seg_start,
                                                       outage_rows[ep_row], noise_vec,
                                                       fix_epoch, fix_z, fix_H, fixes.r, fix_status, *aux, want_stats)
        first_state = kernel.corrected(nav[ep_row[0]], err_post[0])
        last_state = kernel.corrected(nav[ep_row[-1]], err_post[-1])
        if rows_wanted:
            rows = kernel.finish_rows(t, nav, ep_row, err_post, err_pre, ep_Pp, ep_Pp)
    elif rows_wanted:
        zeros = np.zeros((len(ep_row), nx))
        rows = kernel.finish_rows(t, nav, ep_row, zeros, zeros, ep_Pp, ep_Pm)
    return _Pass(nav=nav, ep_row=ep_row, ep_Pp=ep_Pp, ep_Pm=ep_Pm, seg_start=seg_start, fix_status=fix_status,
                 fix_z=fix_z, fix_S=fix_S, fix_d2=fix_d2, stats=stats if want_stats else None, restarts=restarts,
                 rows=rows, loglik=loglik, first_state=first_state, last_state=last_state, diverged=diverged,
                 forward=forward)


def _joined(parts: list[np.ndarray]) -> np.ndarray:
    """The segments' arrays end to end; a single segment's array as it is (the usual run: no copy of its three
    (E, nx, nx) covariance histories, 15 MB a pass on a 15-minute flight)."""
    return parts[0] if len(parts) == 1 else np.concatenate(parts)


def forward_separation(t: np.ndarray, run: _Pass) -> ForwardSeparation | None:
    """The forward filter's solution against the smoothed one at the epochs of a smoothed pass with rows (see
    :class:`~georef.fusion.solution.ForwardSeparation`); None when the pass kept no forward solution.

    Where a restart put several epochs on one row, the last one counts (the rows carry that one's solution)."""
    if run.forward is None or len(run.ep_row) == 0:
        return None
    forward_nav, forward_P = run.forward
    last = np.r_[run.ep_row[1:] != run.ep_row[:-1], True]
    rows = run.ep_row[last]
    fwd, smoothed = forward_nav[last], run.nav[rows]
    P_f, P_s = forward_P[last], run.ep_Pp[last][:, :layout.ATT + 3, :layout.ATT + 3]
    ok = np.isfinite(fwd[:, layout.X_LAT]) & np.isfinite(smoothed[:, layout.X_LAT])
    fwd, smoothed, P_f, P_s, rows = fwd[ok], smoothed[ok], P_f[ok], P_s[ok], rows[ok]
    lat, lon = smoothed[:, layout.X_LAT], smoothed[:, layout.X_LON]
    r_f = geodetic_to_ecef(fwd[:, layout.X_LAT], fwd[:, layout.X_LON], fwd[:, layout.X_HGT])
    r_s = geodetic_to_ecef(lat, lon, smoothed[:, layout.X_HGT])
    position = np.einsum("nij,nj->ni", C_e_n(lat, lon), r_f - r_s)
    angles_f = np.stack(dcm_to_euler(quat_to_dcm(fwd[:, layout.X_QUAT:layout.X_QUAT + 4])), -1)
    angles_s = np.stack(dcm_to_euler(quat_to_dcm(smoothed[:, layout.X_QUAT:layout.X_QUAT + 4])), -1)
    attitude = angles_f - angles_s
    attitude[:, 2] = wrap_pi(attitude[:, 2])
    pos = slice(layout.POS, layout.POS + 3)
    att = slice(layout.ATT, layout.ATT + 3)

    def euler_sigma(P: np.ndarray, angles: np.ndarray) -> np.ndarray:
        """1-sigma of roll, pitch, yaw [rad] of a NED attitude-error covariance, linearised at ``angles``."""
        J = euler_error_jacobian(angles[:, 0], angles[:, 1], angles[:, 2])
        return np.sqrt(np.maximum(np.diagonal(J @ P @ np.swapaxes(J, -1, -2), axis1=1, axis2=2), 0.0))

    return ForwardSeparation(
        time=t[rows], position=position, attitude=attitude,
        position_sigma=np.sqrt(np.maximum(np.diagonal(P_f[:, pos, pos] - P_s[:, pos, pos], axis1=1, axis2=2), 0.0)),
        attitude_sigma=euler_sigma(P_f[:, att, att] - P_s[:, att, att], angles_s),
        forward_position_sigma=np.sqrt(np.maximum(np.diagonal(P_f[:, pos, pos], axis1=1, axis2=2), 0.0)),
        forward_attitude_sigma=euler_sigma(P_f[:, att, att], angles_f))


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

    gaps = [(int(np.searchsorted(centres, a, side="right")) - 1, int(np.searchsorted(centres, b)))
            for a, b in inputs.gaps]
    decimated = InsInputs(time=inputs.time[centres], gyro=block_mean(inputs.gyro), accel=block_mean(inputs.accel),
                          gnss=inputs.gnss, unit_rpy=None if inputs.unit_rpy is None else inputs.unit_rpy[centres],
                          source=inputs.source, gaps=[(max(a, 0), b) for a, b in gaps if b > a])
    return decimated, int(np.searchsorted(centres, start_row))


class _Estimation:
    """The estimation passes: noise blocks by EM, the IMU's white-noise level by cross-validation, the lever arm
    and latency as states. Covariance epochs at ``ESTIMATION_RATE_HZ``; every pass starts from the previous one's
    smoothed state at the start row."""

    def __init__(self, inputs: InsInputs, cfg: InsSettings, alignment: Alignment, prior: NoiseModel,
                 blocks: tuple[int, ...], lever: np.ndarray, latency: float, datasheet: NoiseModel | None = None):
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
        self.nhc = cfg.ins.vehicle == "ground"
        self.ground_test: dict[str, float] = {}
        self.datasheet = datasheet or prior
        #: the first pass gates only gross outliers (the GNSS variances are not fitted yet); every later one
        #: gates as the final pass will
        self.gate = ESTIMATION_GATE
        self.cv_scores: list[tuple[float, float, float, int]] = []

    def _pass(self, noise: NoiseModel, smooth: bool, calibrate: bool = False, rows: bool = False) -> _Pass:
        self.passes += 1
        run = _run_pass(self.inputs, self.cfg, self.alignment, noise, self.fixes, self.stride, self.gate,
                        calibrate=calibrate, smooth=smooth, want_stats=smooth, lever=self.lever, latency=self.latency,
                        start_state=self.start_state, rows_wanted=rows, restart_on_divergence=False, nhc=self.nhc)
        self.restarts = len(run.restarts)
        return run

    def _smoothed(self, noise: NoiseModel, calibrate: bool = False, rows: bool = False) -> _Pass:
        run = self._pass(noise, smooth=True, calibrate=calibrate, rows=rows)
        if not run.diverged:
            self.start_state = run.first_state
            if calibrate:
                self.calibration = _calibration(run)
        return run

    def _em_loop(self, noise: NoiseModel, run: _Pass, iterations: int) -> tuple[NoiseModel, _Pass]:
        """Accelerated EM steps, each kept only when its pass does not diverge and its innovation likelihood does
        not drop; otherwise the step is shortened (in log scale) until it is: EM's monotonicity, restored for the
        accelerated steps (compare Varadhan & Roland 2008, "Simple and globally convergent methods for
        accelerating the convergence of any EM algorithm", Scand. J. Stat. 35)."""
        for _ in range(iterations):
            step, ratios = em_step(noise, self.prior, run.stats, self.blocks)
            accepted = False
            for fraction in EM_STEP_FRACTIONS:
                candidate = _partial_step(noise, step, self.blocks, fraction)
                trial = self._smoothed(candidate)
                if not trial.diverged and trial.loglik.sum() >= run.loglik.sum() - LOGLIK_TOLERANCE:
                    noise, run, accepted = candidate, trial, True
                    self.ratios.append(ratios)
                    break
            if not accepted or max(abs(r - 1.0) for r in ratios.values()) < EM_TOLERANCE:
                break
        return noise, run

    def cross_validate(self, noise: NoiseModel) -> tuple[float, float, int]:
        """Cross-validated fit of ``noise``: over the first ``CV_SPAN_S`` of the log, the last ``CV_HOLD_S`` of
        every ``CV_PERIOD_S`` of fixes are held out, the rest smoothed, and the held fixes scored against the
        smoothed antenna position and its variance (plus the fix's). Returns the held fixes' Gaussian
        log-likelihood, their mean normalised squared residual (3 when the sigmas in gaps are right) and their
        number; minus infinity when the pass diverges."""
        inputs, fixes = self.inputs, self.fixes
        t = inputs.time
        t_end = t[self.alignment.start_row] + CV_SPAN_S
        fix_time = t[fixes.row] - fixes.lag
        inside = fix_time <= t_end
        held = inside & (np.mod(fix_time - fix_time[0], CV_PERIOD_S) >= CV_PERIOD_S - CV_HOLD_S)
        kept = inside & ~held
        if held.sum() < CV_MIN_HELD:
            return 0.0, np.nan, 0
        last = min(int(np.searchsorted(t, t_end)) + 1, len(t))
        span = InsInputs(time=t[:last], gyro=inputs.gyro[:last], accel=inputs.accel[:last], gnss=inputs.gnss,
                         unit_rpy=None if inputs.unit_rpy is None else inputs.unit_rpy[:last], source=inputs.source,
                         gaps=[(a, b) for a, b in inputs.gaps if b < last])
        subset = _Fixes(row=fixes.row[kept], lag=fixes.lag[kept], z=fixes.z[kept], r=fixes.r[kept],
                        index=fixes.index[kept])
        self.passes += 1
        run = _run_pass(span, self.cfg, self.alignment, noise, subset, self.stride, self.gate,
                        calibrate=False, smooth=True, want_stats=False, lever=self.lever, latency=self.latency,
                        start_state=self.start_state, rows_wanted=True, restart_on_divergence=False, nhc=self.nhc)
        if run.diverged:
            return -np.inf, np.inf, int(held.sum())
        valid, pos_var, _, _, angles, _, _ = run.rows
        nav = run.nav
        rows = fixes.row[held]
        ok = rows < last
        rows, z, r_fix, lag = rows[ok], fixes.z[held][ok], fixes.r[held][ok], fixes.lag[held][ok]
        ok = valid[rows]
        rows, z, r_fix, lag = rows[ok], z[ok], r_fix[ok], lag[ok]
        if len(rows) < CV_MIN_HELD:
            return 0.0, np.nan, 0
        lat, lon, h = nav[rows, layout.X_LAT], nav[rows, layout.X_LON], nav[rows, layout.X_HGT]
        C_b_n = euler_to_dcm(angles[rows, 0], angles[rows, 1], angles[rows, 2])
        v_n = nav[rows, layout.X_VEL:layout.X_VEL + 3]
        r_pred = geodetic_to_ecef(lat, lon, h) + lever_arm_ecef(lat, lon, C_b_n, self.lever)
        r_pred -= np.einsum("nij,nj->ni", C_n_e(lat, lon), v_n * (lag + self.latency)[:, None])
        r_fix_e = geodetic_to_ecef(z[:, 0], z[:, 1], z[:, 2])
        residual = np.einsum("nij,nj->ni", C_e_n(z[:, 0], z[:, 1]), r_pred - r_fix_e)
        var = pos_var[rows] + r_fix * np.array([noise.r_scale_h, noise.r_scale_h, noise.r_scale_v])
        d2 = np.sum(residual**2 / var, axis=1)
        loglik = float(-0.5 * np.sum(np.log(var).sum(axis=1) + d2 + 3.0 * np.log(2.0 * np.pi)))
        return loglik, float(np.mean(d2)), len(rows)

    def _white_candidates(self, start: NoiseModel) -> list[NoiseModel]:
        """The white-noise hypotheses: the spectral floor of the data (vibration that acts like sensor noise),
        and the datasheet (vibration that is real motion, measured correctly, or none); one when they agree."""
        names = ("q_vel_h", "q_vel_v", "q_att_h", "q_att_v")
        sheet = replace(start, **{name: getattr(self.datasheet, name) for name in names})
        ratio = max(getattr(start, name) / getattr(sheet, name) for name in names)
        return [start] if ratio < WHITE_DISTINCT else [start, sheet]

    def _fit(self, start: NoiseModel) -> tuple[NoiseModel, _Pass | None]:
        """The first pass from ``start`` (opened up until it holds; the ground-vehicle test once), then EM on
        the blocks the innovations identify. Returns the model and its last pass (None when it diverged)."""
        noise = start
        test_ground = self.cfg.ins.vehicle == "auto" and not self.ground_test
        run = self._smoothed(noise, rows=test_ground)
        for _ in range(INFLATE_TRIES):
            if not run.diverged:
                break
            # even the starting point is too tight for these data: open it up until the filter holds
            noise = inflated(noise, 10.0)
            run = self._smoothed(noise, rows=test_ground)
        if run.diverged:
            return noise, None
        if test_ground:
            self.ground_test = _ground_vehicle_test(run)
            if self.ground_test["ground"]:
                self.nhc = True
                self.blocks = (*self.blocks, layout.B_NHC)
        if self.gate != self.cfg.gnss_gate.chi2:
            # the GNSS variances from the first pass, then the final gate
            step, _ = em_step(noise, self.prior, run.stats, (layout.B_GNSS_H, layout.B_GNSS_V))
            noise = step
            self.gate = self.cfg.gnss_gate.chi2
            run = self._smoothed(noise)
        elif test_ground and self.nhc:
            run = self._smoothed(noise)
        return self._em_loop(noise, run, EM_ITERATIONS)

    def run(self, start: NoiseModel) -> NoiseModel:
        """For each white-noise hypothesis (:meth:`_white_candidates`): the first pass and EM on the blocks the
        innovations identify; when there are two, the one that better predicts held-out fixes
        (:meth:`cross_validate`) wins. Innovations one epoch ahead hardly see the white-noise densities and, on
        real data, prefer whatever follows the fixes best, while a georeferencing run needs the model that
        bridges what it does not see. Then a last pass with the lever arm and latency as states."""
        candidates = self._white_candidates(start)
        best, best_score, best_state = start, -np.inf, self.start_state
        for candidate in candidates:
            state = self.start_state
            noise, run = self._fit(candidate)
            if run is None:
                self.start_state = state
                continue
            score, mean_d2, count = self.cross_validate(noise) if len(candidates) > 1 else (0.0, np.nan, 0)
            self.cv_scores.append((noise.q_vel_h, score, mean_d2, count))
            # the spectral floor (first) is what the data show; the datasheet has to predict clearly better
            if best_score > -np.inf:
                score -= CV_MARGIN
            if score > best_score:
                best, best_score, best_state = noise, score, self.start_state
            self.start_state = state
        self.start_state = best_state
        # a last pass with the lever arm and latency as states: what the data say about them
        self._calibrate(best)
        return best

    def _calibrate(self, noise: NoiseModel) -> None:
        """The lever arm and latency as states (:attr:`calibration`), re-linearised: a lever arm far from the
        given one is reached in steps, each pass starting from the last one's estimate (one pass moved a 45 m
        typo only to 19 m). When the data disagree with the given lever arm, or the pass diverges, the
        calibration is also run from no lever arm, re-aligned without it (a gross typo drags the alignment and
        the start state along), and the one whose innovations are likelier is kept. The given lever arm stays
        the one the final pass applies, and the final pass starts from the noise passes' state, not from a
        calibration pass's: the calibration's extra freedom (a lever arm that trades against the position and, in a
        hover, the heading) must not move the navigation."""
        given, start_state = self.lever.copy(), self.start_state
        try:
            kept = self._calibration_from(noise, given)
            if kept is None or _moved(kept[0], given):
                alignment, start_state = self.alignment, self.start_state
                try:
                    self.alignment = initial_alignment(self.inputs, self.cfg.with_lever_arm((0.0, 0.0, 0.0)))
                    self.start_state = None
                    other = self._calibration_from(noise, np.zeros(3))
                except GeorefError:
                    other = None
                finally:
                    self.alignment, self.start_state = alignment, start_state
                if other is not None and (kept is None or other[1] > kept[1]):
                    kept = other
            self.calibration = None if kept is None else kept[0]
        finally:
            self.lever, self.start_state = given, start_state

    def _calibration_from(self, noise: NoiseModel, lever: np.ndarray) -> tuple[Calibration, float] | None:
        """Calibration passes from ``lever`` until the estimate stops moving: (calibration, innovation
        log-likelihood of the last pass), or None when a pass diverges."""
        self.lever = lever.copy()
        self.calibration = None
        run = self._smoothed(noise, calibrate=True)
        for _ in range(CALIBRATION_ITERATIONS):
            if run.diverged or not _moved(self.calibration, self.lever):
                break
            self.lever = self.calibration.lever_arm.copy()
            run = self._smoothed(noise, calibrate=True)
        if run.diverged or self.calibration is None:
            return None
        return self.calibration, float(run.loglik.sum())


def _moved(calibration: Calibration | None, lever: np.ndarray) -> bool:
    """Is the lever-arm estimate off ``lever`` [m] by more than 3 sigma and CALIBRATION_STEP_M on some axis?"""
    if calibration is None:
        return False
    moved = np.abs(calibration.lever_arm - lever)
    return bool(np.any((moved > 3.0 * calibration.lever_arm_sigma) & (moved > CALIBRATION_STEP_M)))


def _ground_vehicle_test(run: _Pass) -> dict[str, float]:
    """Does the smoothed motion look like a ground vehicle's? While moving faster than GROUND_MIN_SPEED, the
    body's lateral velocity must stay under GROUND_MAX_SLIP of the speed (median) and its vertical velocity under
    GROUND_MAX_VERTICAL (rms), for at least GROUND_MIN_MOVING of the log. An aircraft's crab or angle of attack, a
    multicopter flying sideways fail it; a car passes it."""
    from georef.frames import euler_to_dcm

    valid, _, _, _, angles, _, _ = run.rows
    v_n = run.nav[:, layout.X_VEL:layout.X_VEL + 3]
    speed = np.hypot(v_n[:, 0], v_n[:, 1])
    moving = valid & (speed > GROUND_MIN_SPEED)
    share = float(moving.sum()) / max(int(valid.sum()), 1)
    if moving.sum() < 10:
        return {"ground": False, "moving_share": share, "slip": np.nan, "vertical_rms": np.nan}
    C = euler_to_dcm(angles[moving, 0], angles[moving, 1], angles[moving, 2])
    v_b = np.einsum("nji,nj->ni", C, v_n[moving])
    slip = float(np.median(np.abs(v_b[:, 1]) / speed[moving]))
    vertical = float(np.sqrt(np.mean(v_b[:, 2] ** 2)))
    ground = share >= GROUND_MIN_MOVING and slip < GROUND_MAX_SLIP and vertical < GROUND_MAX_VERTICAL
    return {"ground": bool(ground), "moving_share": share, "slip": slip, "vertical_rms": vertical}


def _partial_step(noise: NoiseModel, step: NoiseModel, blocks: tuple[int, ...], fraction: float) -> NoiseModel:
    """``noise`` moved by ``fraction`` of the way to ``step``, block by block, in log scale."""
    return noise.with_blocks({b: noise.block_value(b) * (step.block_value(b) / noise.block_value(b)) ** fraction
                              for b in blocks})


def solve_ins(inputs: InsInputs, cfg: InsSettings | ProcessingConfig, smooth: bool = True) -> NavSolution:
    """EKF (``smooth=False``) or EKF + RTS smoother solution at every IMU row (see the module docstring), with the
    sections of the configuration the filters read (``InsSettings.of(cfg)``; a whole configuration is narrowed to
    them here)."""
    if isinstance(cfg, ProcessingConfig):
        cfg = InsSettings.of(cfg)
    t = np.ascontiguousarray(inputs.time, dtype=float)
    if len(t) < 10 or np.any(np.diff(t) <= 0):
        raise GeorefError(f"{inputs.source}: IMU times must increase strictly")
    inputs.time = t
    inputs.gaps = imu_gaps(t, inputs.gyro, inputs.accel)
    gnss = inputs.gnss
    if np.count_nonzero((gnss.time >= t[0]) & (gnss.time <= t[-1])) < 6:
        raise GeorefError(f"{inputs.source}: the full-state filter needs at least six GNSS fixes inside the IMU span "
                          f"({t[0]:.1f} - {t[-1]:.1f} s)")
    alignment = initial_alignment(inputs, cfg)
    fixes = _fix_table(inputs, cfg, alignment.start_row)
    rate = 1.0 / float(np.median(np.diff(t)))
    lever = np.asarray(cfg.lever_arm_gnss, dtype=float)
    datasheet = noise_prior(cfg)
    prior = data_prior(datasheet, t, inputs.gyro, inputs.accel)
    aiding = bool(cfg.unit.aiding and inputs.unit_rpy is not None)
    blocks = tuple(b for b in range(layout.N_BLOCKS)
                   if (aiding or b not in UNIT_BLOCKS) and b not in (*NHC_BLOCKS, *WHITE_BLOCKS))
    given_latency = cfg.gnss.latency
    estimation = _Estimation(inputs, cfg, alignment, prior, blocks, lever, given_latency or 0.0, datasheet)
    noise = estimation.run(starting_point(prior))
    calibration = estimation.calibration
    # the estimate is reported, not applied: it trades off against the lever arm's forward component when the
    # heading follows the track, and its sigma is then optimistic (a simulated car: -0.089 +- 0.026 s estimated,
    # no latency simulated; applying it made the position error 0.83 m instead of 0.34 m)
    latency = given_latency if given_latency is not None else 0.0
    stride = max(1, int(round(rate / cfg.ins.covariance_rate)))
    final = _run_pass(inputs, cfg, alignment, noise, fixes, stride, cfg.gnss_gate.chi2, calibrate=False, smooth=smooth,
                      want_stats=False, lever=lever, latency=latency, start_state=estimation.start_state,
                      nhc=estimation.nhc)
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
        latency_applied=latency, gate_chi2=cfg.gnss_gate.chi2, nis=full_nis, unit_aiding=aiding,
        estimation_restarts=estimation.restarts,
        estimation_passes=estimation.passes, ground_vehicle=estimation.nhc, ground_test=estimation.ground_test,
        cross_validation=estimation.cv_scores,
        imu_gaps=[(float(t[a]), float(t[b])) for a, b in inputs.gaps])
    info = InsInfo(vel_var_n=vel_var, gyro_bias=states[:, layout.X_BG:layout.X_BG + 3],
                   accel_bias=states[:, layout.X_BA:layout.X_BA + 3], unit_yaw_origin=states[:, layout.X_UNIT_YAW],
                   epoch_rows=final.ep_row, epoch_sigma=epoch_sigma, start_row=start_row,
                   smoothed=smooth, heading_source=alignment.heading_source, unit_aiding=aiding)
    return NavSolution(
        method="rts" if smooth else "ekf", time=t, r_e=r_e, v_e=v_e, lat=lat, lon=lon, height=height,
        roll=angles[:, 0], pitch=angles[:, 1], yaw=angles[:, 2], pos_var_n=pos_var, att_sigma=att_sigma, valid=valid,
        gnss=GnssUse(time=gnss.time, status=full_status, innovation=full_innov, innovation_var=full_var,
                     line=gnss.line, nis=full_nis),
        ins_info=info, att_cov_n=att_cov, diagnostics=diagnostics, forward=forward_separation(t, final),
    )


def inputs_from_pos(log: PosLog, use_unit_attitude: bool = True) -> InsInputs:
    """INS inputs from a POS log: OMGS [deg/s] -> rad/s, ACCS [m/s^2]; the unit's angles when present."""
    unit_rpy = None
    iacc = None
    if use_unit_attitude and all(r in log.data for r in ("roll", "pitch", "yaw")):
        unit_rpy = np.radians(np.stack([log.data["roll"], log.data["pitch"], log.data["yaw"]], -1))
        if all(f"iacc_{a}" in log.data for a in "xyz"):
            iacc = log.vector("iacc")
    return InsInputs(time=log.time, gyro=np.radians(log.vector("gyro")), accel=log.vector("acc"), gnss=log.gnss,
                     unit_rpy=unit_rpy, iacc=iacc, source=str(log.path))


def solve_rts(log: PosLog, cfg: ProcessingConfig) -> NavSolution:
    """``--method rts``: EKF and RTS smoother on a POS log, with the sections of ``cfg`` it reads."""
    return solve_ins(inputs_from_pos(log), InsSettings.of(cfg), smooth=True)


def solve_ekf(log: PosLog, cfg: ProcessingConfig) -> NavSolution:
    """``--method ekf``: the forward EKF alone on a POS log, with the sections of ``cfg`` it reads."""
    return solve_ins(inputs_from_pos(log), InsSettings.of(cfg), smooth=False)
