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

import os
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from georef.aot import load as load_kernel
from georef.config import InsSettings, ProcessingConfig, UnitSection
from georef.frames import (
    STANDARD_GRAVITY,
    C_e_n,
    C_n_e,
    dcm_to_quat,
    ecef_to_geodetic,
    euler_to_dcm,
    geodetic_to_ecef,
)
from georef.frames.earth import lat_lon_to_ned
from georef.frames.mounting import lever_arm_ecef
from georef.frames.rotations import dcm_to_euler, euler_error_jacobian, quat_to_dcm, quat_to_rotvec, wrap_pi
from georef.fusion import ins_layout as layout
from georef.fusion.alignment import VARIANCE_FACTOR_RETRY, Alignment, align
from georef.fusion.noise import (
    GNSS_CORRELATED_SHARE,
    GNSS_GM_BLOCKS,
    NHC_BLOCKS,
    UNIT_BLOCKS,
    WHITE_BLOCKS,
    NoiseModel,
    data_prior,
    datasheet_prior,
    em_step,
    inflated,
    starting_point,
    still_rate_variance,
    with_gnss_correlation,
)
from georef.fusion.solution import ForwardSeparation, GnssUse, HeldOutCheck, InsInfo, NavSolution
from georef.fusion.start import (
    BANK_HEADINGS,
    BANK_SIGMA,
    bank_choice,
    first_motion,
    heading_prior,
    level_at_start,
    level_covariance,
    quasi_static_start,
    still_rows,
)
from georef.io.errors import GeorefError
from georef.timing import GnssEpochs

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
#: the environment variable that switches off the noise fit's fixed budget (:func:`fit_budget`) with ``0``, for
#: paired comparisons against the unbounded fit (docs/method-ins.md, section 4)
FIT_BUDGET_VARIABLE = "GEOREF_FIT_BUDGET"
#: with the budget: once the noise fit has run this many passes (cross-validation passes count as one each) it
#: starts no further EM step, white-noise candidate or GNSS model (it still scores the models it has fitted, and
#: runs its calibration pass); GNSS_MODEL_PASSES of them are kept for the GNSS model's choice when there is one.
#: Measured on KITTI (tests/end_to_end/test_robust.py): 10 cut the white fit short, whose held-out score then lost
#: to the correlated model's, and the 20-s outages were bridged to 2.96 m instead of 0.77 m; 20 keeps 0.77 m
FIT_PASSES = 20
GNSS_MODEL_PASSES = 3
#: with the budget: the correlated GNSS model gets this many EM steps before its held-out score is first compared
#: with the white model's; it is fitted on (as without the budget) only when it is then within
#: GNSS_MODEL_SLACK of winning (log-likelihood)
GNSS_MODEL_EM_STEPS = 1
GNSS_MODEL_SLACK = 3.0
#: with the budget: the fit runs on at most this span [s] of the flight from its start row (a longer flight's
#: cost stays that of this span)
FIT_SPAN_S = 900.0
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
#: the most sigma [rad] a motion fit's start heading is taken with: its fourfold-widened variance without the
#: heading's correlation with the gyro bias is no prior the filter's linearisation can start from
START_HEADING_SIGMA_MAX = np.radians(10.0)
#: the held-out check (:func:`held_out_check`): windows of HELD_S [s] every HELD_PERIOD_S [s] from HELD_START_S
#: after the first fix; at least HELD_MIN held-out fixes
HELD_S = 15.0
HELD_PERIOD_S = 45.0
HELD_START_S = 10.0
HELD_MIN = 10
#: a held-out window needs kept fixes within this [s] (or three fix intervals) on either side
HELD_FLANK_S = 2.0
#: sigmas [rad] of the other heading sources, wide enough for their errors: an autopilot's own heading (its EKF
#: leans on a magnetometer beside motors and wires), a magnetometer read here with the configured declination
AUTOPILOT_YAW_SIGMA = np.radians(15.0)
MAGNETOMETER_SIGMA = np.radians(30.0)
#: sigma [rad] of the heading carried over a re-alignment whose data do not show the heading
RESTART_HEADING_SIGMA = np.radians(20.0)


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
    #: rows where the vehicle stands still (N,) (:func:`georef.fusion.start.still_rows`), filled in by
    #: :func:`solve_ins`: zero-velocity updates there
    still: np.ndarray | None = None


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
    #: the GNSS errors were modelled with a correlated (Gauss-Markov) part: the held-out fixes favoured it; the
    #: held-out log-likelihoods of the white and the correlated model (None: only one was tried)
    gnss_correlated: bool = False
    gnss_model_scores: tuple[float, float] | None = None
    #: spans [s] where the vehicle stood still (zero-velocity updates)
    still_spans: list[tuple[float, float]] = field(default_factory=list)
    #: how the solution predicts fixes it was not given (:func:`held_out_check`); None when too few could be
    held_out: HeldOutCheck | None = None
    #: the receiver's reported variance the noise model leaves out [m^2, NED], added to the positions' variance
    #: (:func:`unmodelled_gnss_variance`)
    gnss_unmodelled_var: np.ndarray = field(default_factory=lambda: np.zeros(3))


@dataclass
class _Fixes:
    row: np.ndarray      # the IMU row at or after each fix
    lag: np.ndarray      # t[row] - t_fix [s]
    z: np.ndarray        # lat, lon [rad], h [m]
    r: np.ndarray        # NED variances [m^2]
    rho: np.ndarray      # correlation coefficients north-east, north-down, east-down (zeros: independent axes)
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
    epoch_loglik: np.ndarray | None = None  # the same per covariance epoch, all kinds summed (E,)
    first_state: np.ndarray | None = None   # smoothed nominal state at the first epoch
    last_state: np.ndarray | None = None    # and at the last epoch
    diverged: bool = False                  # an estimation pass that stopped at a divergence (no restart)
    smoothed: bool = False                  # ep_Pp holds the smoother's covariances (else the filter's P+)
    #: smoothed passes with rows: the forward filter's nominal state (E, NS) and its position, velocity and
    #: attitude covariance (E, 9, 9) at the epochs, copied before the smoother overwrote the covariances
    forward: tuple[np.ndarray, np.ndarray] | None = None


def _fix_table(inputs: InsInputs, cfg: InsSettings, start_row: int) -> _Fixes:
    gnss, t = inputs.gnss, inputs.time
    use = np.flatnonzero((gnss.time > t[start_row]) & (gnss.time <= t[-1]))
    row = np.searchsorted(t, gnss.time[use], side="left")
    z = np.stack([np.radians(gnss.lat_deg[use]), np.radians(gnss.lon_deg[use]), gnss.height[use]], -1)
    sigma = _fix_sigmas(gnss, cfg)[use]
    return _Fixes(row=row, lag=t[row] - gnss.time[use], z=z, r=sigma**2, rho=_fix_correlations(gnss)[use], index=use)


def _fix_correlations(gnss: GnssEpochs) -> np.ndarray:
    """(K, 3) correlation coefficients north-east, north-down, east-down of every fix's NED covariance when the
    source gives one (``cov_ned``: an RTKLIB .pos, a NavSatFix), else zeros; zeros where it is not finite."""
    if gnss.cov_ned is None:
        return np.zeros((len(gnss), 3))
    from georef.frames.position_covariance import correlations

    rho = correlations(gnss.cov_ned)
    return np.where(np.isfinite(rho), np.clip(rho, -1.0, 1.0), 0.0)


def _fix_sigmas(gnss: GnssEpochs, cfg: InsSettings) -> np.ndarray:
    """NED sigmas [m] of every fix: the file's own where given, else ``cfg.gnss.sigma``."""
    default = np.tile(np.asarray(cfg.gnss.sigma, float), (len(gnss), 1))
    if gnss.sigma_neu is None:
        return default
    return np.where(np.isfinite(gnss.sigma_neu), gnss.sigma_neu, default)


def unmodelled_gnss_variance(gnss: GnssEpochs, noise: NoiseModel) -> np.ndarray:
    """The part of the receiver's reported accuracy [m^2, NED (3,)] the fitted noise model leaves out: the reported
    variance (median over the fixes, per axis) less the fitted white part and the fitted correlated part, floored at
    0. Zero without reported accuracies (a configured sigma is a guess, not a receiver's statement).

    A receiver's error wanders over minutes; consecutive fixes agree with each other far better than with the
    truth, so the fit to the fixes' scatter (and to held-out fixes, which wander with them) finds a white sigma of
    centimetres for a u-blox that reports, and has, a metre. That wander shifts the whole trajectory, which the
    fixes cannot show; it is added to the solution's position variance so the EO sigmas state the accuracy the
    receiver gives."""
    if gnss.sigma_neu is None or not np.isfinite(gnss.sigma_neu).any():
        return np.zeros(3)
    reported = np.nanmedian(gnss.sigma_neu**2, axis=0)
    white = reported * np.array([noise.r_scale_h, noise.r_scale_h, noise.r_scale_v])
    gm_h, gm_v = noise.gnss_gm_sigma()
    return np.maximum(reported - white - np.array([gm_h, gm_h, gm_v]) ** 2, 0.0)


def _spans(time: np.ndarray, mask: np.ndarray | None) -> list[tuple[float, float]]:
    """The runs of ``mask`` as (first, last) times [s]."""
    if mask is None or not mask.any():
        return []
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    return [(float(time[a]), float(time[b - 1])) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def _typical_fix_sigma(gnss: GnssEpochs, cfg: InsSettings) -> tuple[float, float]:
    """The median horizontal (per axis) and vertical sigma [m] of the fixes."""
    sigma = _fix_sigmas(gnss, cfg)
    return float(np.median(sigma[:, :2])), float(np.median(sigma[:, 2]))


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
def _fix_ned(gnss: GnssEpochs) -> np.ndarray:
    """The fixes' antenna positions in the tangent frame (NED) at the first fix [m] (K, 3)."""
    lat, lon = np.radians(gnss.lat_deg), np.radians(gnss.lon_deg)
    r = geodetic_to_ecef(lat, lon, gnss.height)
    return (r - r[0]) @ C_e_n(lat[0], lon[0]).T


def _start_row(inputs: InsInputs, start_time: float | None) -> int:
    t0 = inputs.gnss.time[0] if start_time is None else start_time
    return int(np.searchsorted(inputs.time, t0, side="left"))


def initial_alignment(inputs: InsInputs, cfg: InsSettings, start_time: float | None = None,
                      bias_g: np.ndarray | None = None, bias_a: np.ndarray | None = None) -> Alignment:
    """The filter's starting point: the alignment from the motion (:func:`georef.fusion.alignment.align`) where
    it shows the heading and fits; otherwise, at a start where the vehicle stands still or hovers, the level from
    gravity (:func:`_level_alignment`), and in motion the fit's level; the heading then left to the bank
    (:func:`decide_heading`). A still start long enough to measure the gyro bias
    (:func:`georef.fusion.start.level_at_start`) takes gravity's level without trying the fit.

    The motion alignment is refused when its window's motion never shows the heading, when it fits the fixes
    badly (variance factor over ``VARIANCE_FACTOR_RETRY``: a window of real consumer-MEMS flight that a constant
    bias does not describe), or, at a still or hovering start, when its level disagrees with gravity's by more
    than the accelerometer bias allows (a standstill lets the level trade against the bias: on a real drone log
    the fit's roll came out 73 deg with a bias of 8.9 m/s^2)."""
    gnss = inputs.gnss
    row0 = _start_row(inputs, start_time)
    if row0 >= len(inputs.time) - 2:
        raise GeorefError(f"{inputs.source}: cannot align the INS: no IMU data after the first GNSS fix")
    ned = _fix_ned(gnss)
    still = inputs.still is not None and bool(inputs.still[row0])
    static = still or quasi_static_start(gnss.time, ned, float(inputs.time[row0]))
    sigma = _fix_sigmas(gnss, cfg)
    try:
        result = align(inputs.time, inputs.gyro, inputs.accel, gnss.time, np.radians(gnss.lat_deg),
                       np.radians(gnss.lon_deg), gnss.height, sigma, np.asarray(cfg.lever_arm_gnss), start_time,
                       bias_g, bias_a, gaps=inputs.gaps,
                       datasheet_bias_sigma=_datasheet_bias_sigma(cfg))
    except ValueError as exc:
        raise GeorefError(f"{inputs.source}: cannot align the INS: {exc}") from None
    level = _level_alignment(inputs, cfg, result.start_row, ned, bias_g, bias_a) if static else None
    if still and level is not None and level.level.gyro_bias is not None:
        # standing still long enough to measure the gyro bias, gravity gives the level and the heading waits for
        # the motion (the bank): a fit over a slow first minute can trade its heading against the accelerometer
        # bias and land far off with a small sigma (a simulated drone: 152 deg off, sigma 1.4 deg, level within
        # the bias's allowance). A shorter stop leaves the gyro bias unmeasured, and a bank of filters with a
        # large one (a phone's 0.07 rad/s) all fail, where the fit estimates it: such a start takes the rules below
        return level
    if result.observable and result.variance_factor <= VARIANCE_FACTOR_RETRY and \
            (level is None or _level_agrees(result, level)):
        start_sigma = float(np.sqrt(result.covariance[layout.ATT + 2, layout.ATT + 2]))
        result.heading_source = (f"motion (optimisation-based alignment over {result.window[1] - result.window[0]:.0f}"
                                 f" s, heading sigma {np.degrees(result.heading_sigma):.2f} deg, "
                                 f"{np.degrees(start_sigma):.1f} deg at the start)")
        if start_time is None:
            _unit_yaw_origin(inputs, cfg, result)
        return result
    if level is not None:
        return level
    return _without_heading(cfg, result)


def _level_agrees(fit: Alignment, level: Alignment) -> bool:
    """Does the motion fit's roll and pitch at the start agree with gravity's within what the accelerometer bias
    the fit allowed can tilt gravity's (three times its sigma over g: the datasheet's, or consumer grade where the
    fit's data rejected the datasheet, as a phone's 50 mg did) and 1 deg?"""
    roll_f, pitch_f, _ = dcm_to_euler(fit.C_b_n)
    roll_l, pitch_l, _ = dcm_to_euler(level.C_b_n)
    rows = slice(layout.ATT, layout.ATT + 2)
    sigma = float(np.sqrt(np.max(np.diag(level.covariance[rows, rows]))))
    if fit.bias_prior_sigma is not None:
        sigma = max(sigma, fit.bias_prior_sigma[1] / STANDARD_GRAVITY)
    limit = max(3.0 * sigma, np.radians(1.0))
    return bool(abs(wrap_pi(roll_f - roll_l)) <= limit and abs(wrap_pi(pitch_f - pitch_l)) <= limit)


def _without_heading(cfg: InsSettings, result: Alignment) -> Alignment:
    """A motion fit whose heading is left to the bank. Where its window's motion showed the heading at some time,
    the gyro bias about the vertical that carries it back stands (a phone gyro's 0.07 rad/s); where it never
    did, that bias goes back to its prior too (it trades against the heading: a hovering multicopter's fits
    ranged over +-0.09 rad/s at equal misfit)."""
    start_sigma = float(np.sqrt(result.covariance[layout.ATT + 2, layout.ATT + 2]))
    result.needs_heading = True
    result.heading_source = ("pending: the alignment's motion did not show the heading (sigma "
                             f"{np.degrees(start_sigma):.0f} deg at the start)")
    P = result.covariance
    P[layout.ATT + 2, :] = 0.0
    P[:, layout.ATT + 2] = 0.0
    P[layout.ATT + 2, layout.ATT + 2] = np.pi**2
    result.heading_sigma = np.pi
    if result.observable:
        return result
    down_b = result.C_b_n.T @ np.array([0.0, 0.0, 1.0])
    bias_sigma = (result.bias_prior_sigma or _datasheet_bias_sigma(cfg))[0]
    result.gyro_bias = result.gyro_bias - (result.gyro_bias @ down_b) * down_b
    block = slice(layout.BG, layout.BG + 3)
    keep = np.eye(3) - np.outer(down_b, down_b)
    P[block, :] = keep @ P[block, :]
    P[:, block] = P[:, block] @ keep
    P[block, block] += bias_sigma**2 * np.outer(down_b, down_b)
    return result


def _level_alignment(inputs: InsInputs, cfg: InsSettings, row0: int, ned: np.ndarray, bias_g: np.ndarray | None,
                     bias_a: np.ndarray | None) -> Alignment:
    """A still or hovering start: roll and pitch from gravity, the gyro bias from a still span, position and
    velocity from the first fixes; the heading left to the bank. The covariance is a prior (gravity, the
    datasheet, the fixes' sigmas), in filter order, with the level's correlation to the accelerometer bias."""
    gnss, t = inputs.gnss, inputs.time
    lat0 = np.radians(gnss.lat_deg[0])
    still = inputs.still if inputs.still is not None else np.zeros(len(t), bool)
    level = level_at_start(t, inputs.gyro, inputs.accel, row0, still, gnss.time, ned, float(lat0))
    C_b_n = euler_to_dcm(level.roll, level.pitch, 0.0)
    sigma_g, sigma_a = _datasheet_bias_sigma(cfg)
    gyro_bias = (level.gyro_bias if level.gyro_bias is not None
                 else np.zeros(3) if bias_g is None else np.asarray(bias_g, float))
    accel_bias = np.zeros(3) if bias_a is None else np.asarray(bias_a, float)
    lever = np.asarray(cfg.lever_arm_gnss, float)
    # the antenna at the start row, carried to the IMU through the lever arm; without the heading its horizontal
    # part's direction is unknown, and its length goes into the position's sigma
    t0 = float(t[row0])
    r_ant = np.array([np.interp(t0, gnss.time, ned[:, k]) for k in range(3)])
    r_imu = r_ant - C_b_n @ lever
    lat_f, lon_f = np.radians(gnss.lat_deg[0]), np.radians(gnss.lon_deg[0])
    r_e = geodetic_to_ecef(lat_f, lon_f, gnss.height[0]) + C_n_e(lat_f, lon_f) @ r_imu
    lat_s, lon_s, h_s = ecef_to_geodetic(r_e[None, :])
    fix_sigma = np.median(_fix_sigmas(gnss, cfg)[: max(5, min(len(gnss), 25))], axis=0)
    i = int(np.clip(np.searchsorted(gnss.time, t0), 1, len(gnss) - 1))
    j = min(i + 1, len(gnss) - 1)
    span = max(gnss.time[j] - gnss.time[i - 1], 1e-3)
    v_n = (ned[j] - ned[i - 1]) / span if j > i - 1 else np.zeros(3)
    P = np.zeros((15, 15))
    horizontal_lever = float(np.hypot(lever[0], lever[1]))
    pos_var = fix_sigma**2 + np.array([horizontal_lever**2, horizontal_lever**2, 0.0])
    P[layout.POS:layout.POS + 3, layout.POS:layout.POS + 3] = np.diag(pos_var)
    P[layout.VEL:layout.VEL + 3, layout.VEL:layout.VEL + 3] = np.diag(2.0 * fix_sigma**2 / span**2
                                                                    + START_SPEED_SIGMA**2)
    P[layout.ATT + 2, layout.ATT + 2] = np.pi**2
    bg = slice(layout.BG, layout.BG + 3)
    # a mean rate far beyond the datasheet's bias (a phone's 0.07 rad/s read with a survey unit's sheet) overrules
    # the sheet: the sigma is then the mean rate's own, not the sheet's
    P[bg, bg] = np.eye(3) * (level.gyro_bias_sigma if level.gyro_bias is not None else sigma_g) ** 2
    where = "standing still" if level.still else "hovering"
    alignment = Alignment(start_row=row0, position=np.array([lat_s[0], lon_s[0], h_s[0]]), v_n=v_n, C_b_n=C_b_n,
                     gyro_bias=gyro_bias, accel_bias=accel_bias, covariance=P,
                     heading_source=f"pending: level from gravity ({where})", observable=False,
                     heading_sigma=np.pi, heading_time=t0, window=level.window, variance_factor=1.0,
                     bias_prior_sigma=(sigma_g, sigma_a), prior_covariance=True, needs_heading=True, level=level)
    _level_covariance_into(alignment)
    return alignment


def _level_covariance_into(alignment: Alignment) -> None:
    """The level's covariance with the accelerometer bias (:func:`georef.fusion.start.level_covariance`) into the
    alignment's covariance, for its attitude as it now is: the level error a bias causes is the bias turned into
    NED, so it depends on the heading, and is set again whenever the heading is."""
    if alignment.level is None:
        return
    level_cov, bias_cov, cross = level_covariance(alignment.level, alignment.C_b_n, alignment.bias_prior_sigma[1])
    P = alignment.covariance
    level_rows, ba = slice(layout.ATT, layout.ATT + 2), slice(layout.BA, layout.BA + 3)
    P[level_rows, level_rows] = level_cov
    P[ba, ba] = bias_cov
    P[level_rows, ba] = cross
    P[ba, level_rows] = cross.T


def _bank_prior(inputs: InsInputs, cfg: InsSettings, alignment: Alignment) -> tuple[np.ndarray, str]:
    """Prior weights of the bank's headings from the magnetometer or the autopilot's yaw, with sigmas wide
    enough for their errors (a magnetometer beside motors and wires, an autopilot's own heading estimate);
    uniform without either."""
    heading, sigma, source = _other_heading(inputs, cfg, alignment)
    if heading is None:
        return heading_prior(BANK_HEADINGS, None, None), "no prior"
    return heading_prior(BANK_HEADINGS, heading, sigma), f"prior: {source}"


def decide_heading(inputs: InsInputs, cfg: InsSettings, alignment: Alignment, noise: NoiseModel) -> Alignment:
    """The heading of an alignment that needs one, from the bank (:mod:`georef.fusion.start`): the forward filter
    from each of BANK_HEADINGS on the IMU averaged to ESTIMATION_IMU_RATE_HZ, weighed by its innovations. When the
    bank stays undecided: the magnetometer or the autopilot's yaw with their sigma; else the heading stays
    unknown (sigma pi) and the frames say so."""
    if not alignment.needs_heading:
        return alignment
    rate = 1.0 / float(np.median(np.diff(inputs.time)))
    factor = max(1, int(round(rate / ESTIMATION_IMU_RATE_HZ)))
    coarse, start = _decimated(inputs, alignment.start_row, factor)
    fixes = _fix_table(coarse, cfg, start)
    stride = max(1, int(round(rate / factor / ESTIMATION_RATE_HZ)))
    roll, pitch, _ = dcm_to_euler(alignment.C_b_n)
    lever = np.asarray(cfg.lever_arm_gnss, float)
    grid = coarse.time[fixes.row]
    K, G = len(BANK_HEADINGS), len(grid)
    cum = np.full((G, K), -np.inf)
    yaw = np.full((G, K), np.nan)
    yaw_sigma = np.full((G, K), np.nan)
    for k, heading in enumerate(BANK_HEADINGS):
        trial = replace(alignment, start_row=start, C_b_n=euler_to_dcm(roll, pitch, heading),
                        heading_prior_sigma=BANK_SIGMA)
        run = _run_pass(coarse, cfg, trial, noise, fixes, PassSettings(
            stride, ESTIMATION_GATE, lever, cfg.gnss.latency or 0.0, smooth=False, restart_on_divergence=False))
        epoch_time = coarse.time[run.ep_row]
        upto = np.searchsorted(epoch_time, grid, side="right") - 1
        reached = upto >= 0
        if run.diverged:
            reached &= grid <= epoch_time[-1]
        cum[reached, k] = np.cumsum(run.epoch_loglik)[upto[reached]]
        _, _, _, _, angles, att_sigma, _ = run.rows
        rows = fixes.row
        ok = np.isfinite(angles[rows, 2])
        yaw[ok, k] = angles[rows[ok], 2]
        yaw_sigma[ok, k] = att_sigma[rows[ok], 2]
    prior, prior_text = _bank_prior(inputs, cfg, alignment)
    choice = bank_choice(BANK_HEADINGS, grid, cum, yaw, yaw_sigma, prior,
                         first_motion(inputs.gnss.time, _fix_ned(inputs.gnss)))
    alignment.needs_heading = False
    if choice.heading is not None:
        # the winning filter found the heading where the motion showed it; its smoother carries it back to the
        # start, which is where the filter starts from (with the bank's sigma: the same fixes follow)
        winner = replace(alignment, start_row=start, C_b_n=euler_to_dcm(roll, pitch, choice.heading),
                         heading_prior_sigma=BANK_SIGMA)
        run = _run_pass(coarse, cfg, winner, noise, fixes, PassSettings(
            stride, ESTIMATION_GATE, lever, cfg.gnss.latency or 0.0, rows_wanted=False, restart_on_divergence=False))
        heading = choice.heading
        if not run.diverged and run.first_state is not None:
            _, _, heading = dcm_to_euler(quat_to_dcm(run.first_state[layout.X_QUAT:layout.X_QUAT + 4]))
        alignment.C_b_n = euler_to_dcm(roll, pitch, float(heading))
        _level_covariance_into(alignment)
        alignment.heading_prior_sigma = BANK_SIGMA
        alignment.heading_sigma = BANK_SIGMA
        alignment.heading_time = float(choice.decided_at)
        alignment.observable = True
        alignment.heading_source = f"motion (heading bank, {choice.text}; {prior_text})"
        _unit_yaw_origin(inputs, cfg, alignment)
        return alignment
    heading, sigma, source = _other_heading(inputs, cfg, alignment)
    if heading is None:
        alignment.heading_source = (f"none: the motion never showed the heading (bank {choice.text}) and there is "
                                    "no magnetometer or autopilot yaw")
        alignment.heading_prior_sigma = np.pi
        return alignment
    alignment.C_b_n = euler_to_dcm(roll, pitch, heading)
    _level_covariance_into(alignment)
    alignment.heading_prior_sigma = sigma
    alignment.heading_sigma = sigma
    alignment.heading_source = f"{source}: the motion never showed the heading (bank {choice.text})"
    return alignment


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
    _level_covariance_into(alignment)
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
    if inputs.autopilot_yaw is not None:
        yaw = np.asarray(inputs.autopilot_yaw, float)
        finite = np.flatnonzero(np.isfinite(yaw))
        if len(finite):
            near = finite[np.argmin(np.abs(finite - row))]
            return (float(yaw[near]), AUTOPILOT_YAW_SIGMA,
                    f"autopilot yaw (sigma {np.degrees(AUTOPILOT_YAW_SIGMA):.0f} deg)")
    if inputs.mag is not None:
        m = np.nanmean(inputs.mag[row:row + 50], axis=0)
        if np.all(np.isfinite(m)):
            C_level = euler_to_dcm(roll, pitch, 0.0)  # body -> heading-free level frame
            m_level = C_level @ m
            heading = float(wrap_pi(-np.arctan2(m_level[1], m_level[0]) + np.radians(cfg.ins.magnetic_declination)))
            return (heading, MAGNETOMETER_SIGMA, "magnetometer (declination from the configuration, sigma "
                    f"{np.degrees(MAGNETOMETER_SIGMA):.0f} deg)")
    return None, None, None


#: the alignment's states: position, velocity, attitude and the two biases (POS .. BA, the first of the layout)
N_ALIGNED = layout.BA + 3


def _navigation_prior(cfg: InsSettings, alignment: Alignment) -> np.ndarray:
    """The filter's prior (N_ALIGNED, N_ALIGNED) on the alignment's states.

    A fit of the alignment to the fixes gives the point to linearise about; its covariance came from the same
    fixes the filter is about to use, so it is not the prior: starting from it counted the first minutes' fixes
    twice (the smoothed height sigma at the start was 0.10 m for an error of 0.21 m). The prior is then what one
    fix, the datasheet and the fit's resolution widened fourfold allow, whichever is wider, without
    correlations (the fit's correlations, widened with it, misled the filter: a consumer-IMU helicopter's yaw came
    out 50 deg off). A level from gravity is a prior already (no fix in it) and is taken whole, its level-bias
    correlation with it. A heading from the bank, the unit's IACC or another source brings its own sigma."""
    sigma_fix = np.asarray(cfg.gnss.sigma, dtype=float)
    sigma_g, sigma_a = _datasheet_bias_sigma(cfg)
    P = np.zeros((N_ALIGNED, N_ALIGNED))
    if alignment.prior_covariance:
        P[:, :] = alignment.covariance
    else:
        fit = np.diag(alignment.covariance) * 4.0
        floor = np.zeros(N_ALIGNED)
        floor[layout.POS:layout.POS + 3] = sigma_fix**2
        floor[layout.VEL:layout.VEL + 3] = (sigma_fix / np.sqrt(2.0)) ** 2 + START_SPEED_SIGMA**2
        floor[layout.ATT:layout.ATT + 3] = np.radians([START_LEVEL_SIGMA_DEG, START_LEVEL_SIGMA_DEG,
                                                       START_HEADING_SIGMA_DEG]) ** 2
        floor[layout.BG:layout.BG + 3] = sigma_g**2
        floor[layout.BA:layout.BA + 3] = sigma_a**2
        P[np.arange(N_ALIGNED), np.arange(N_ALIGNED)] = np.maximum(fit, floor)
        # the heading at the start of a window whose motion showed it only later is known through the gyro bias
        # about the vertical; widened fourfold and without that correlation it would be a guess (a consumer IMU's
        # fit: 93 deg at the start): the filter takes it, loosely, at START_HEADING_SIGMA_MAX
        P[layout.ATT + 2, layout.ATT + 2] = min(P[layout.ATT + 2, layout.ATT + 2], START_HEADING_SIGMA_MAX**2)
    if alignment.heading_prior_sigma is not None:
        P[layout.ATT + 2, :] = 0.0
        P[:, layout.ATT + 2] = 0.0
        P[layout.ATT + 2, layout.ATT + 2] = alignment.heading_prior_sigma**2
    return P


def _heading_capped(alignment: Alignment) -> bool:
    """Whether :func:`_navigation_prior` capped the start heading's sigma at START_HEADING_SIGMA_MAX below what the
    alignment's fit knows (a heading the window's motion showed only later, carried back through a gyro bias)."""
    if alignment.prior_covariance or alignment.heading_prior_sigma is not None:
        return False
    return bool(4.0 * alignment.covariance[layout.ATT + 2, layout.ATT + 2] > START_HEADING_SIGMA_MAX**2)


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
    P0 = np.zeros((nx, nx))
    nav = slice(layout.POS, N_ALIGNED)
    P0[nav, nav] = _navigation_prior(cfg, alignment)
    gm_h, gm_v = noise.gnss_gm_sigma()
    for i, sigma in enumerate((gm_h, gm_h, gm_v)):
        P0[layout.GNSS_GM + i, layout.GNSS_GM + i] = sigma**2
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
        row_att = -j_yaw @ P0[layout.ATT:layout.ATT + 3, nav]
        P0[layout.UNIT_YAW, nav] = row_att
        P0[nav, layout.UNIT_YAW] = row_att
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


def _linearisation_start(x0: np.ndarray, start_state: np.ndarray, level_from_gravity: bool) -> np.ndarray:
    """The start of a pass after an earlier one: the earlier pass's smoothed state at the start row, a better point
    to linearise about. With a level read from gravity (a still or hovering start) the level and the accelerometer
    bias stay the alignment's (``x0``), whose covariance the pass starts with: the two trade against each other
    wherever the motion does not separate them (a hover, a straight flight at one heading), and taken from the
    earlier pass under the alignment's covariance they counted the data twice, every noise pass moving the start
    further along their trade (simulated drones ended 2-5 deg off in roll or pitch with sigmas near 0.5 deg). A
    start from a motion fit keeps the whole smoothed state: there the fit's level is the weaker one, and the
    re-linearisation is what carries a phone IMU's 0.07 rad/s of gyro bias (docs/method-ins.md section 9). The
    lever arm and latency are the caller's."""
    x = start_state.copy()
    if level_from_gravity:
        roll, pitch, _ = dcm_to_euler(quat_to_dcm(x0[layout.X_QUAT:layout.X_QUAT + 4]))
        _, _, yaw = dcm_to_euler(quat_to_dcm(start_state[layout.X_QUAT:layout.X_QUAT + 4]))
        x[layout.X_QUAT:layout.X_QUAT + 4] = dcm_to_quat(euler_to_dcm(roll, pitch, yaw))
        x[layout.X_BA:layout.X_BA + 3] = x0[layout.X_BA:layout.X_BA + 3]
    return x


def state_error(x_est: np.ndarray, x_ref: np.ndarray, nx: int) -> np.ndarray:
    """The error state (nx,) of the nominal state ``x_est`` (NS,) against ``x_ref`` taken as the truth, in the
    filter's convention (estimate minus truth; removing it from ``x_est`` with
    :func:`georef.fusion.ins_kernel.correct_state` gives ``x_ref`` to first order): NED position [m], velocity,
    attitude ``φ`` with ``C_ref = exp([φ x]) C_est`` [rad], then the other states as differences."""
    dx = np.zeros(nx)
    lat = float(x_ref[layout.X_LAT])
    north, east = lat_lon_to_ned(x_est[layout.X_LAT] - x_ref[layout.X_LAT], x_est[layout.X_LON] - x_ref[layout.X_LON],
                                 lat, x_ref[layout.X_HGT])
    dx[layout.POS:layout.POS + 3] = north, east, x_ref[layout.X_HGT] - x_est[layout.X_HGT]
    C_est = quat_to_dcm(x_est[layout.X_QUAT:layout.X_QUAT + 4])
    C_ref = quat_to_dcm(x_ref[layout.X_QUAT:layout.X_QUAT + 4])
    dx[layout.ATT:layout.ATT + 3] = quat_to_rotvec(dcm_to_quat(C_ref @ C_est.T))
    pairs = [(layout.VEL, layout.X_VEL, 3), (layout.BG, layout.X_BG, 3), (layout.BA, layout.X_BA, 3),
             (layout.UNIT_LEVEL, layout.X_UNIT_LEVEL, 2), (layout.UNIT_YAW, layout.X_UNIT_YAW, 1),
             (layout.UNIT_DRIFT, layout.X_UNIT_DRIFT, 1), (layout.GNSS_GM, layout.X_GNSS_GM, 3)]
    if nx > layout.LEVER:
        pairs += [(layout.LEVER, layout.X_LEVER, 3), (layout.LATENCY, layout.X_LATENCY, 1)]
    for error, nominal, size in pairs:
        dx[error:error + size] = x_est[nominal:nominal + size] - x_ref[nominal:nominal + size]
    dx[layout.UNIT_YAW] = wrap_pi(dx[layout.UNIT_YAW])
    return dx


def _restart_heading(inputs: InsInputs, cfg: InsSettings, alignment: Alignment, x_prev: np.ndarray) -> None:
    """The heading of a re-alignment whose data do not show it at once: another source's (the unit's yaw with
    its IACC origin, the autopilot's, a magnetometer), else the one the filter had, loosely."""
    roll, pitch, _ = dcm_to_euler(alignment.C_b_n)
    heading, sigma, source = _other_heading(inputs, cfg, alignment)
    if heading is None:
        _, _, heading = dcm_to_euler(quat_to_dcm(x_prev[layout.X_QUAT:layout.X_QUAT + 4]))
        sigma, source = RESTART_HEADING_SIGMA, "the filter's before the restart"
    alignment.C_b_n = euler_to_dcm(roll, pitch, float(heading))
    _level_covariance_into(alignment)
    alignment.heading_prior_sigma = float(sigma)
    alignment.heading_source = source
    alignment.needs_heading = False


# ---- one pass ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PassSettings:
    """How one pass of the filter (and smoother) runs (:func:`_run_pass`)."""

    stride: int                  # IMU rows between covariance epochs
    gate: float                  # chi-square gate of the GNSS fixes and the unit's attitude
    lever: np.ndarray            # GNSS lever arm to start from [m, body]
    latency: float               # GNSS time-tag latency to start from [s]
    calibrate: bool = False      # estimate the lever arm and latency (NX_CAL error states)
    smooth: bool = True          # run the RTS smoother after the filter
    want_stats: bool = False     # the smoother adds up the EM statistics of the noise blocks
    rows_wanted: bool = True     # per-row outputs (finish_rows)
    #: re-align and go on after a divergence; else (estimation passes) the pass ends there, marked ``diverged``:
    #: its noise model is not one to keep
    restart_on_divergence: bool = True
    nhc: bool = False            # a ground vehicle's non-holonomic constraint
    #: the nominal start state (NS,) to linearise about (an earlier pass's smoothed start), else the alignment's
    start_state: np.ndarray | None = None

    @property
    def nx(self) -> int:
        """The number of error states."""
        return layout.NX_CAL if self.calibrate else layout.NX_NAV

    def options(self, time: np.ndarray, max_rejects: int, unit_aiding: bool) -> np.ndarray:
        """The forward kernel's options vector (``layout.OPT_*``)."""
        options = np.zeros(layout.N_OPTIONS)
        options[layout.OPT_STRIDE] = self.stride
        options[layout.OPT_GATE] = self.gate
        options[layout.OPT_MAX_REJECTS] = max_rejects
        options[layout.OPT_MAX_GAP] = imu_gap_limit(time)
        options[layout.OPT_OUTAGE_S] = OUTAGE_S
        options[layout.OPT_UNIT_AIDING] = unit_aiding
        options[layout.OPT_NHC] = self.nhc
        return options


@dataclass(frozen=True)
class ForwardOutputs:
    """One segment of the forward filter by name, in the order :func:`georef.fusion.ins_kernel.ekf_forward`
    returns them: per covariance epoch (E), per GNSS fix (M), per auxiliary update (A)."""

    ep_row: np.ndarray      # (E,) IMU row of the epoch
    ep_dT: np.ndarray       # (E,) interval from the previous epoch [s]
    ep_Pm: np.ndarray       # (E, nx, nx) P⁻
    ep_Pp: np.ndarray       # (E, nx, nx) P⁺
    ep_Phi: np.ndarray      # (E, nx, nx) Φ from the previous epoch
    ep_dx: np.ndarray       # (E, nx) the correction fed back at the epoch
    fix_epoch: np.ndarray   # (M,) epoch of the fix (-1: not processed)
    fix_z: np.ndarray       # (M, 3) innovation relative to the epoch's pre-update error [m, NED]
    fix_H: np.ndarray       # (M, 3, nx)
    fix_S: np.ndarray       # (M, 3, 3) innovation covariance [m^2]
    fix_d2: np.ndarray      # (M,) normalised innovation squared
    fix_status: np.ndarray  # (M,) layout.FIX_*
    aux_epoch: np.ndarray   # (A,) epoch of the update
    aux_kind: np.ndarray    # (A,) layout.AUX_*
    aux_z: np.ndarray       # (A, 3) innovation relative to the epoch's pre-update error
    aux_H: np.ndarray       # (A, 3, nx)
    aux_status: np.ndarray  # (A,) layout.FIX_USED or FIX_REJECTED
    aux_r: np.ndarray       # (A, 3) measurement variances used
    stop: np.ndarray        # (last row, first fix of the rejected run, layout.STOP_*)
    ep_loglik: np.ndarray   # (E, 3) innovation log-likelihood of the fixes, unit and NHC updates


@dataclass
class _EpochRecords:
    """The covariance epochs a segment keeps (``ForwardOutputs``' ``ep_*``); ``restart``: the filter restarted
    at the first (a continuation's first epoch is the previous segment's last, dropped)."""

    row: np.ndarray
    dT: np.ndarray
    Pm: np.ndarray
    Pp: np.ndarray
    Phi: np.ndarray
    dx: np.ndarray
    loglik: np.ndarray
    restart: bool = False


@dataclass
class _AuxRecords:
    """The auxiliary updates a segment keeps (``ForwardOutputs``' ``aux_*``), epochs counted over the pass."""

    epoch: np.ndarray
    kind: np.ndarray
    z: np.ndarray
    H: np.ndarray
    status: np.ndarray
    r: np.ndarray


@dataclass
class _FixRecords:
    """The GNSS fixes' records over a pass (``ForwardOutputs``' ``fix_*``), epochs counted over the pass."""

    epoch: np.ndarray
    z: np.ndarray
    H: np.ndarray
    S: np.ndarray
    d2: np.ndarray
    status: np.ndarray

    @classmethod
    def unused(cls, m: int, nx: int) -> _FixRecords:
        """Records of ``m`` fixes none of which was processed, with ``nx`` error states."""
        return cls(np.full(m, -1, dtype=np.int64), np.full((m, 3), np.nan), np.zeros((m, 3, nx)),
                   np.full((m, 3, 3), np.nan), np.full(m, np.nan), np.full(m, layout.FIX_UNUSED, dtype=np.int64))


@dataclass
class _SegmentLoop:
    """Where the segment loop stands: the next segment's start row, nominal state and covariance, the rejected
    fixes in a row that stop it (0: never), the drift re-runs so far (in all, and per fix site), whether it
    continues the previous segment, and the epochs kept so far."""

    start_row: int
    x0: np.ndarray
    P0: np.ndarray
    max_rejects: int = MAX_CONSECUTIVE_REJECTS
    drift_reruns: int = 0
    attempts: dict[int, int] = field(default_factory=dict)
    continuation: bool = False
    offset: int = 0


@dataclass
class _Segments:
    """The forward filter's segments of one pass: the nominal state of every row, the fixes' records over the
    pass, the kept epochs and auxiliary updates per segment, the restarts, and the process-noise factors."""

    nav: np.ndarray
    fixes: _FixRecords
    epochs: list[_EpochRecords]
    auxes: list[_AuxRecords]
    restarts: list[Restart]
    q_scale: np.ndarray
    outage_rows: np.ndarray
    prior_error: np.ndarray
    diverged: bool = False

    def keep(self, out: ForwardOutputs, keep: int, loop: _SegmentLoop) -> None:
        """Add a segment's epochs before ``keep`` (a continuation's first dropped) and their updates."""
        dup = 1 if loop.continuation else 0
        kept = slice(dup, keep)
        processed = (out.fix_epoch >= dup) & (out.fix_epoch < keep)
        self.fixes.epoch[processed] = out.fix_epoch[processed] - dup + loop.offset
        for name in ("status", "z", "H", "S", "d2"):
            getattr(self.fixes, name)[processed] = getattr(out, f"fix_{name}")[processed]
        self.fixes.status[out.fix_epoch >= keep] = layout.FIX_UNUSED
        aux_keep = (out.aux_epoch >= dup) & (out.aux_epoch < keep)
        self.epochs.append(_EpochRecords(out.ep_row[kept], out.ep_dT[kept], out.ep_Pm[kept], out.ep_Pp[kept],
                                         out.ep_Phi[kept], out.ep_dx[kept], out.ep_loglik[kept],
                                         not loop.continuation))
        self.auxes.append(_AuxRecords(out.aux_epoch[aux_keep] - dup + loop.offset, out.aux_kind[aux_keep],
                                      out.aux_z[aux_keep], out.aux_H[aux_keep], out.aux_status[aux_keep],
                                      out.aux_r[aux_keep]))
        loop.offset += keep - dup


def _pass_start(inputs: InsInputs, cfg: InsSettings, alignment: Alignment, noise: NoiseModel,
                settings: PassSettings) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The first segment's nominal state (NS,) and covariance (nx, nx), and the nominal start's error against the
    prior's mean (nx,): the prior's mean stays the alignment's whatever point the pass linearises about, the error
    carried through the filter and the smoother (kernel.prior_shift)."""
    x0, P0 = _initial_state(inputs, cfg, alignment, noise, settings.calibrate, settings.lever, settings.latency)
    prior_error = np.zeros(settings.nx)
    if settings.start_state is not None:
        x_prior = x0
        x0 = _linearisation_start(x0, settings.start_state, alignment.level is not None)
        x0[layout.X_LEVER:layout.X_LEVER + 3] = settings.lever
        x0[layout.X_LATENCY] = settings.latency
        prior_error = state_error(x0, x_prior, settings.nx)
        if _heading_capped(alignment) and abs(prior_error[layout.ATT + 2]) > 2.0 * START_HEADING_SIGMA_MAX:
            # the start heading's sigma was capped below what the fit knows, and the passes moved the heading
            # beyond twice the cap: the alignment's start is no prior to hold them to (a phone IMU's fit 96 deg off
            # with 94 deg of sigma at the start ended 21.9 deg off held to it, 1.8 deg not). The pass then takes
            # the earlier pass's smoothed start as its prior mean, all states together (the heading alone let a
            # consumer IMU's flight run off to 104 deg)
            prior_error[:] = 0.0
    return x0, P0, prior_error


def _segment_end(out: ForwardOutputs, fixes: _Fixes, q_scale: np.ndarray, loop: _SegmentLoop) -> tuple[int, int]:
    """Why the segment ended (layout.STOP_*, a divergence or drift turned into a re-run with more process noise
    while re-runs help, else a re-alignment) and how many of its epochs are kept. A re-run raises ``q_scale``
    over the stretch from the last fix before it."""
    reason = int(out.stop[2])
    keep = len(out.ep_row)
    if reason in (layout.STOP_DRIFT, layout.STOP_DIVERGED):
        site = int(out.stop[1])
        loop.attempts[site] = loop.attempts.get(site, 0) + 1
        if loop.drift_reruns < MAX_DRIFT_RERUNS and loop.attempts[site] <= SITE_RERUNS:
            # the model under-predicted the error growth since the last fix (an outage, an IMU gap, or just
            # dynamics): run that stretch again with more process noise, which the smoother keeps bridging
            reason = layout.STOP_DRIFT
        else:
            # that did not help: re-align from the data there (once; then gate without restarting)
            reason = layout.STOP_DIVERGED
            if loop.attempts[site] > SITE_RERUNS + 1:
                loop.max_rejects = 0
    if reason == layout.STOP_DIVERGED:
        # restart at the epoch before the one that rejected the first of the run
        keep = max(int(out.fix_epoch[int(out.stop[1])]), 1)
    elif reason == layout.STOP_DRIFT:
        # go back to the epoch of the last fix before the outage and run the outage again with more
        # process noise: as much more as the first fix after it asks for
        first = int(out.stop[1])
        before = first - 1
        keep = int(out.fix_epoch[before]) + 1 if before >= 0 and out.fix_epoch[before] >= 0 else 1
        r0 = int(out.ep_row[keep - 1])
        r1 = int(fixes.row[first])
        q_scale[r0 + 1:r1 + 1, :] *= float(np.clip(out.fix_d2[first] / DRIFT_TARGET_CHI2, 4.0, 1e4))
        loop.drift_reruns += 1
    return reason, keep


def _restart(inputs: InsInputs, fixes: _Fixes, out: ForwardOutputs, reason: int, keep: int) -> Restart:
    """Where and why the filter restarts after a segment that ended for ``reason`` (an IMU gap: after it; a
    divergence: at the last epoch kept)."""
    t = inputs.time
    if reason == layout.STOP_GAP:
        row = int(out.stop[0]) + 1
        why = f"IMU gap of {t[row] - t[row - 1]:.2f} s before {t[row]:.2f} s: re-aligned after it"
    else:
        row = int(out.ep_row[keep - 1])
        first_fix = fixes.index[int(out.stop[1])]
        why = (f"{MAX_CONSECUTIVE_REJECTS} GNSS fixes in a row rejected from "
               f"{inputs.gnss.time[first_fix]:.1f} s (line {int(inputs.gnss.line[first_fix])})")
    return Restart(row=row, time=float(t[row]), reason=why)


def _realign(inputs: InsInputs, cfg: InsSettings, noise: NoiseModel, calibrate: bool, nav: np.ndarray,
             loop: _SegmentLoop) -> None:
    """The next segment's start (``loop.x0``, ``loop.P0``) from a re-alignment at ``loop.start_row``, the unit's
    errors, lever arm and latency carried over; without data left to re-align, the old state with an open
    covariance, ungated."""
    start_row = loop.start_row
    t = inputs.time
    x_prev = nav[start_row].copy() if np.isfinite(nav[start_row, 0]) else nav[start_row - 1].copy()
    try:
        again = initial_alignment(inputs, cfg, start_time=float(t[start_row]),
                                  bias_g=x_prev[layout.X_BG:layout.X_BG + 3],
                                  bias_a=x_prev[layout.X_BA:layout.X_BA + 3])
        again.start_row = start_row
        if again.needs_heading:
            _restart_heading(inputs, cfg, again, x_prev)
        loop.x0, loop.P0 = _initial_state(inputs, cfg, again, noise, calibrate,
                                          x_prev[layout.X_LEVER:layout.X_LEVER + 3], float(x_prev[layout.X_LATENCY]))
        loop.x0[layout.X_UNIT_LEVEL:layout.X_UNIT_DRIFT + 1] = x_prev[layout.X_UNIT_LEVEL:layout.X_UNIT_DRIFT + 1]
        if inputs.unit_rpy is not None:
            _, _, yaw = dcm_to_euler(again.C_b_n)
            loop.x0[layout.X_UNIT_YAW] = float(wrap_pi(yaw - inputs.unit_rpy[start_row, 2]))
    except GeorefError:
        # not enough data left to re-align: go on from the old state with an open covariance, ungated
        loop.x0 = x_prev
        loop.P0 = np.diag(np.diag(loop.P0)) * 100.0
        loop.max_rejects = 0


def _run_segments(inputs: InsInputs, cfg: InsSettings, alignment: Alignment, noise: NoiseModel, fixes: _Fixes,
                  settings: PassSettings) -> _Segments:
    """The forward filter over every segment: re-aligning and restarting after divergences and IMU gaps, running
    a stretch again with more process noise after a drift; without ``settings.restart_on_divergence`` a divergence
    ends the pass (``diverged``)."""
    kernel = load_kernel("ins")
    t = inputs.time
    n = len(t)
    aiding = bool(cfg.unit.aiding and inputs.unit_rpy is not None)
    unit_rpy = inputs.unit_rpy if inputs.unit_rpy is not None else np.zeros((n, 3))
    still = inputs.still if inputs.still is not None else np.zeros(n, dtype=bool)
    noise_vec = noise.as_array()
    x0, P0, prior_error = _pass_start(inputs, cfg, alignment, noise, settings)
    run = _Segments(nav=np.full((n, layout.NS), np.nan), fixes=_FixRecords.unused(len(fixes.row), settings.nx),
                    epochs=[], auxes=[], restarts=[],
                    q_scale=_gap_scale(t, inputs.gaps, noise), outage_rows=_outage_rows(t, fixes),
                    prior_error=prior_error)
    run.q_scale[run.outage_rows, :] *= noise.outage_scale
    loop = _SegmentLoop(start_row=alignment.start_row, x0=x0, P0=P0)
    while True:
        out = ForwardOutputs(*kernel.ekf_forward(
            t, inputs.gyro, inputs.accel, run.q_scale, still, unit_rpy, loop.start_row, loop.x0, loop.P0, fixes.row,
            fixes.lag, fixes.z, fixes.r, fixes.rho, noise_vec, settings.options(t, loop.max_rejects, aiding), run.nav))
        reason, keep = _segment_end(out, fixes, run.q_scale, loop)
        run.keep(out, keep, loop)
        if reason == layout.STOP_END:
            break
        if reason == layout.STOP_DRIFT:
            loop.start_row = int(out.ep_row[keep - 1])
            loop.x0 = run.nav[loop.start_row].copy()
            loop.P0 = out.ep_Pp[keep - 1].copy()
            loop.continuation = True
            continue
        loop.continuation = False
        if reason == layout.STOP_DIVERGED and not settings.restart_on_divergence:
            run.diverged = True
            break
        run.restarts.append(_restart(inputs, fixes, out, reason, keep))
        loop.start_row = run.restarts[-1].row
        if len(run.restarts) >= MAX_RESTARTS:
            loop.max_rejects = 0
        if loop.start_row >= n - 2:
            break
        _realign(inputs, cfg, noise, settings.calibrate, run.nav, loop)
    return run


def _merge_segments(t: np.ndarray, noise: NoiseModel, fixes: _Fixes, settings: PassSettings,
                    run: _Segments) -> _Pass:
    """The segments' epochs end to end, then the smoother if ``settings.smooth``, and the rows if wanted."""
    kernel = load_kernel("ins")
    ep = _EpochRecords(*(_joined([getattr(e, name) for e in run.epochs])
                         for name in ("row", "dT", "Pm", "Pp", "Phi", "dx", "loglik")))
    seg_start = np.zeros(len(ep.row), dtype=bool)
    starts = np.cumsum([0, *[len(e.row) for e in run.epochs[:-1]]])
    seg_start[starts[[e.restart for e in run.epochs]]] = True
    aux = _AuxRecords(*(_joined([getattr(a, name) for a in run.auxes])
                        for name in ("epoch", "kind", "z", "H", "status", "r")))
    f = run.fixes
    stats = rows = first_state = last_state = forward = None
    if np.any(run.prior_error):
        m_plus, m_minus = kernel.prior_shift(ep.Pm, ep.Pp, ep.Phi, seg_start, run.prior_error)
    else:
        m_plus = m_minus = np.zeros((len(ep.row), settings.nx))
    nav = run.nav
    if settings.smooth:
        if settings.rows_wanted:
            forward = (_shifted(nav[ep.row], m_plus), ep.Pp[:, :layout.ATT + 3, :layout.ATT + 3].copy())
        err_post, err_pre, stats = kernel.rts_backward(
            ep.dT, ep.Pm, ep.Pp, ep.Phi, ep.dx, seg_start, run.outage_rows[ep.row], noise.as_array(), f.epoch, f.z,
            f.H, fixes.r, f.status, aux.epoch, aux.kind, aux.z, aux.H, aux.status, aux.r,
            settings.want_stats, m_plus)
        first_state = kernel.corrected(nav[ep.row[0]], err_post[0])
        last_state = kernel.corrected(nav[ep.row[-1]], err_post[-1])
        if settings.rows_wanted:
            rows = kernel.finish_rows(t, nav, ep.row, err_post, err_pre, ep.Pp, ep.Pp)
    elif settings.rows_wanted:
        rows = kernel.finish_rows(t, nav, ep.row, m_plus, m_minus, ep.Pp, ep.Pm)
    return _Pass(nav=nav, ep_row=ep.row, ep_Pp=ep.Pp, ep_Pm=ep.Pm, seg_start=seg_start, fix_status=f.status,
                 fix_z=f.z, fix_S=f.S, fix_d2=f.d2, stats=stats if settings.want_stats else None,
                 restarts=run.restarts, rows=rows, loglik=ep.loglik.sum(axis=0), first_state=first_state,
                 last_state=last_state, diverged=run.diverged, forward=forward,
                 epoch_loglik=ep.loglik.sum(axis=1), smoothed=settings.smooth)


def _run_pass(inputs: InsInputs, cfg: InsSettings, alignment: Alignment, noise: NoiseModel, fixes: _Fixes,
              settings: PassSettings) -> _Pass:
    """Forward filter over every segment (:func:`_run_segments`), then the smoother if ``settings.smooth``
    (:func:`_merge_segments`)."""
    return _merge_segments(inputs.time, noise, fixes, settings,
                           _run_segments(inputs, cfg, alignment, noise, fixes, settings))


def _shifted(states: np.ndarray, errors: np.ndarray) -> np.ndarray:
    """Nominal states (E, NS) with the error means (E, nx) removed, a copy; rows without an error as they are."""
    out = states.copy()
    kernel = load_kernel("ins")
    for j in np.flatnonzero(np.any(errors != 0.0, axis=1)):
        out[j] = kernel.corrected(states[j], errors[j])
    return out


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


def fit_budget() -> bool:
    """Is the noise fit's fixed budget on (the default; ``GEOREF_FIT_BUDGET=0`` turns it off)? With it the fit
    runs at most FIT_PASSES passes over at most FIT_SPAN_S of the flight, chooses the GNSS model after
    GNSS_MODEL_EM_STEPS steps of the correlated one unless that comes close, and the held-out check runs at the
    fit's rates."""
    return os.environ.get(FIT_BUDGET_VARIABLE, "1").strip() != "0"


def _head(inputs: InsInputs, last: int) -> InsInputs:
    """The IMU rows before ``last`` of ``inputs`` (the GNSS epochs all kept; the unit's angles, the IMU gaps and
    the still rows cut to match; no magnetometer or autopilot yaw: the estimation passes do not re-align)."""
    return InsInputs(time=inputs.time[:last], gyro=inputs.gyro[:last], accel=inputs.accel[:last], gnss=inputs.gnss,
                     unit_rpy=None if inputs.unit_rpy is None else inputs.unit_rpy[:last], source=inputs.source,
                     gaps=[(a, b) for a, b in inputs.gaps if b < last],
                     still=None if inputs.still is None else inputs.still[:last])


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
    still = None
    if inputs.still is not None:  # a block stands still when all its rows do
        still = block_mean(inputs.still[:, None].astype(float))[:, 0] >= 1.0 - 1e-9
    decimated = InsInputs(time=inputs.time[centres], gyro=block_mean(inputs.gyro), accel=block_mean(inputs.accel),
                          gnss=inputs.gnss, unit_rpy=None if inputs.unit_rpy is None else inputs.unit_rpy[centres],
                          source=inputs.source, gaps=[(max(a, 0), b) for a, b in gaps if b > a], mag=inputs.mag,
                          autopilot_yaw=inputs.autopilot_yaw, still=still)
    return decimated, int(np.searchsorted(centres, start_row))


def _fix_ecef(z: np.ndarray) -> np.ndarray:
    """ECEF positions [m] of fixes ``z`` (lat, lon [rad], h [m]) (K, 3)."""
    return geodetic_to_ecef(z[:, 0], z[:, 1], z[:, 2])


def _fix_residual_ned(nav: np.ndarray, angles: np.ndarray, lever: np.ndarray, back: np.ndarray,
                      z: np.ndarray) -> np.ndarray:
    """Predicted minus logged fix [m] (K, 3), resolved in NED at each fix (:func:`_predicted_fix`'s arguments)."""
    return np.einsum("nij,nj->ni", C_e_n(z[:, 0], z[:, 1]), _predicted_fix(nav, angles, lever, back) - _fix_ecef(z))


def _predicted_fix(nav: np.ndarray, angles: np.ndarray, lever: np.ndarray, back: np.ndarray) -> np.ndarray:
    """Where the fixes at these rows are predicted [m, ECEF]: the antenna (the IMU plus the lever arm ``lever``
    [m, body]) moved back along the velocity by ``back`` [s], plus the correlated GNSS error (NED, nominal state
    ``nav`` (K, NS), ZYX angles (K, 3) [rad]). Subtract a fix's ECEF position and resolve in NED at the fix for the
    residual (:func:`_fix_residual_ned`)."""
    lat, lon, h = nav[:, layout.X_LAT], nav[:, layout.X_LON], nav[:, layout.X_HGT]
    C_b_n = euler_to_dcm(angles[:, 0], angles[:, 1], angles[:, 2])
    v_n = nav[:, layout.X_VEL:layout.X_VEL + 3]
    offset_n = nav[:, layout.X_GNSS_GM:layout.X_GNSS_GM + 3] - v_n * back[:, None]
    r = geodetic_to_ecef(lat, lon, h) + lever_arm_ecef(lat, lon, C_b_n, lever)
    return r + np.einsum("nij,nj->ni", C_n_e(lat, lon), offset_n)


def _fix_prediction_variance(run: _Pass, t: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Variance [m^2] (K, 3) NED of the predicted fix (antenna position plus correlated GNSS error) at ``rows``
    (times ``t`` [s] of every row): that of the sum at the covariance epochs on either side, interpolated in time
    as the rows' own variances are (:func:`georef.fusion.ins_kernel.finish_rows`), so it is never negative."""
    epoch = np.clip(np.searchsorted(run.ep_row, rows, side="right") - 1, 0, len(run.ep_row) - 1)
    following = np.minimum(epoch + 1, len(run.ep_row) - 1)
    r0, r1 = run.ep_row[epoch], run.ep_row[following]
    span = np.where(r1 > r0, t[np.maximum(r1, r0)] - t[r0], 1.0)
    w = np.where(r1 > r0, (t[rows] - t[r0]) / span, 0.0)[:, None]
    before = run.ep_Pp[epoch]
    after = (run.ep_Pp if run.smoothed else run.ep_Pm)[following]

    def of_sum(P: np.ndarray) -> np.ndarray:
        pos, gm = np.arange(layout.POS, layout.POS + 3), np.arange(layout.GNSS_GM, layout.GNSS_GM + 3)
        return P[:, pos, pos] + P[:, gm, gm] + 2.0 * P[:, pos, gm]

    return (1.0 - w) * of_sum(before) + w * of_sum(after)


def held_out_check(inputs: InsInputs, cfg: InsSettings, alignment: Alignment, noise: NoiseModel, fixes: _Fixes,
                   stride: int, smooth: bool, lever: np.ndarray, latency: float, start_state: np.ndarray | None,
                   nhc: bool) -> HeldOutCheck | None:
    """The delivered solution's prediction of fixes it was not given (:class:`HeldOutCheck`): from HELD_START_S
    after the first fix, the fixes of the first HELD_S of every HELD_PERIOD_S are left out, the rest fused exactly as
    the final pass was (same noise, start, gate, smoother or not), and every left-out fix between two kept ones
    predicted: the antenna plus the correlated GNSS error, with the variance of that sum and the fix's own. None
    when fewer than HELD_MIN fixes could be left out; ``diverged`` when the filter could not bridge them (it is not
    restarted here: a re-alignment would bridge nothing)."""
    t = inputs.time
    fix_time = t[fixes.row] - fixes.lag
    phase = fix_time - (fix_time[0] + HELD_START_S)
    held = (phase >= 0) & (np.mod(phase, HELD_PERIOD_S) < HELD_S)
    # a window next to a gap the fixes already have would be bridged for longer than HELD_S: only windows whose
    # fixes are continued on both sides within a few fix intervals are held out
    flank = max(HELD_FLANK_S, 3.0 * float(np.median(np.diff(fix_time))) if len(fix_time) > 1 else HELD_FLANK_S)
    window = np.floor(phase / HELD_PERIOD_S)
    for w in np.unique(window[held]):
        inside = held & (window == w)
        before = fix_time[~held & (fix_time < fix_time[inside].min())]
        after = fix_time[~held & (fix_time > fix_time[inside].max())]
        if not len(before) or not len(after) or fix_time[inside].min() - before[-1] > flank \
                or after[0] - fix_time[inside].max() > flank:
            held &= ~inside
    kept = ~held
    kept_time = fix_time[kept]
    if len(kept_time) < 2:
        return None
    held &= (fix_time > kept_time[0]) & (fix_time < kept_time[-1])  # straight lines need a kept fix either side
    if held.sum() < HELD_MIN:
        return None
    subset = _Fixes(row=fixes.row[kept], lag=fixes.lag[kept], z=fixes.z[kept], r=fixes.r[kept],
                    rho=fixes.rho[kept], index=fixes.index[kept])
    run = _run_pass(inputs, cfg, alignment, noise, subset, PassSettings(
        stride, cfg.gnss_gate.chi2, lever, latency, smooth=smooth, restart_on_divergence=False, nhc=nhc,
        start_state=start_state))
    if run.diverged:
        return HeldOutCheck(windows=[], held=int(held.sum()), error_rms_h=np.nan, interpolation_rms_h=np.nan,
                            fix_sigma_h=float(np.median(np.sqrt(fixes.r[:, :2]))), z_rms=np.nan,
                            window_error_rms_h=[], window_interpolation_rms_h=[], diverged=True)
    valid, angles = run.rows[0], run.rows[4]
    index = np.flatnonzero(held)
    index = index[valid[fixes.row[index]]]
    if len(index) < HELD_MIN:
        return None
    rows, z = fixes.row[index], fixes.z[index]
    r_fix = _fix_ecef(z)
    C = C_e_n(z[:, 0], z[:, 1])
    error = _fix_residual_ned(run.nav[rows], angles[rows], lever, fixes.lag[index] + latency, z)
    r_kept = _fix_ecef(fixes.z[kept])
    line = np.stack([np.interp(fix_time[index], kept_time, r_kept[:, k]) for k in range(3)], -1)
    interpolation = np.einsum("nij,nj->ni", C, line - r_fix)
    var = _fix_prediction_variance(run, t, rows) + fixes.r[index] * np.array([noise.r_scale_h, noise.r_scale_h,
                                                                            noise.r_scale_v])
    z_h = error[:, :2] / np.sqrt(var[:, :2])
    window = np.floor((fix_time[index] - fix_time[0] - HELD_START_S) / HELD_PERIOD_S).astype(int)

    def rms_h(e: np.ndarray) -> float:
        return float(np.sqrt(np.mean(np.sum(e[:, :2] ** 2, axis=1))))

    ids = np.unique(window)
    spans = [(float(fix_time[index][window == w].min()), float(fix_time[index][window == w].max())) for w in ids]
    return HeldOutCheck(windows=spans, held=len(index), error_rms_h=rms_h(error),
                        interpolation_rms_h=rms_h(interpolation),
                        fix_sigma_h=float(np.median(np.sqrt(fixes.r[:, :2]))), z_rms=float(np.sqrt(np.mean(z_h**2))),
                        window_error_rms_h=[rms_h(error[window == w]) for w in ids],
                        window_interpolation_rms_h=[rms_h(interpolation[window == w]) for w in ids])


class _Estimation:
    """The estimation passes: noise blocks by EM, the IMU's white-noise level by cross-validation, the lever arm
    and latency as states. Covariance epochs at ``ESTIMATION_RATE_HZ``; every pass starts from the previous one's
    smoothed state at the start row."""

    def __init__(self, inputs: InsInputs, cfg: InsSettings, alignment: Alignment, prior: NoiseModel,
                 blocks: tuple[int, ...], lever: np.ndarray, latency: float, datasheet: NoiseModel | None = None):
        rate = 1.0 / float(np.median(np.diff(inputs.time)))
        factor = max(1, int(round(rate / ESTIMATION_IMU_RATE_HZ)))
        self.decimated, start_row = _decimated(inputs, alignment.start_row, factor)
        self.inputs = self.decimated
        #: with the budget (:func:`fit_budget`): the passes' cap (None: none) and the fit's span
        self.budget = FIT_PASSES if fit_budget() else None
        if self.budget is not None:
            t = self.decimated.time
            last = int(np.searchsorted(t, t[start_row] + FIT_SPAN_S, side="right"))
            if last < len(t):
                self.inputs = _head(self.decimated, last)
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
        self.gnss_correlated = False
        self.gnss_model_scores: tuple[float, float] | None = None
        #: the last EM loop stopped because the blocks had settled (or no step kept the likelihood)
        self.em_settled = False

    def _spent(self) -> bool:
        """Has the fit used up its budget of passes (never without the budget)?"""
        return self.budget is not None and self.passes >= self.budget

    def _pass(self, noise: NoiseModel, smooth: bool, calibrate: bool = False, rows: bool = False) -> _Pass:
        self.passes += 1
        run = _run_pass(self.inputs, self.cfg, self.alignment, noise, self.fixes, PassSettings(
            self.stride, self.gate, self.lever, self.latency, calibrate=calibrate, smooth=smooth, want_stats=smooth,
            rows_wanted=rows, restart_on_divergence=False, nhc=self.nhc, start_state=self.start_state))
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
        self.em_settled = False
        for _ in range(iterations):
            step, ratios = em_step(noise, self.prior, run.stats, self.blocks)
            accepted = False
            for fraction in EM_STEP_FRACTIONS:
                if self._spent():
                    return noise, run
                candidate = _partial_step(noise, step, self.blocks, fraction)
                trial = self._smoothed(candidate)
                if not trial.diverged and trial.loglik.sum() >= run.loglik.sum() - LOGLIK_TOLERANCE:
                    noise, run, accepted = candidate, trial, True
                    self.ratios.append(ratios)
                    break
            if not accepted or max(abs(r - 1.0) for r in ratios.values()) < EM_TOLERANCE:
                self.em_settled = True
                break
        return noise, run

    def cross_validate(self, noise: NoiseModel) -> tuple[float, float, int]:
        """Cross-validated fit of ``noise``: over the first ``CV_SPAN_S`` of the log, the last ``CV_HOLD_S`` of
        every ``CV_PERIOD_S`` of fixes are held out, the rest smoothed, and the held fixes scored against their
        prediction: the smoothed antenna position plus the smoothed correlated GNSS error, with the variance of
        that sum (from the smoothed covariance of the nearest epoch) plus the fix's white variance. Returns the
        held fixes' Gaussian log-likelihood, their mean normalised squared residual (3 when the sigmas in gaps are
        right) and their number; minus infinity when the pass diverges."""
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
        span = _head(inputs, last)
        subset = _Fixes(row=fixes.row[kept], lag=fixes.lag[kept], z=fixes.z[kept], r=fixes.r[kept],
                        rho=fixes.rho[kept], index=fixes.index[kept])
        self.passes += 1
        run = _run_pass(span, self.cfg, self.alignment, noise, subset, PassSettings(
            self.stride, self.gate, self.lever, self.latency, restart_on_divergence=False, nhc=self.nhc,
            start_state=self.start_state))
        if run.diverged:
            return -np.inf, np.inf, int(held.sum())
        valid = run.rows[0]
        angles = run.rows[4]
        rows = fixes.row[held]
        ok = rows < last
        rows, z, r_fix, lag = rows[ok], fixes.z[held][ok], fixes.r[held][ok], fixes.lag[held][ok]
        ok = valid[rows]
        rows, z, r_fix, lag = rows[ok], z[ok], r_fix[ok], lag[ok]
        if len(rows) < CV_MIN_HELD:
            return 0.0, np.nan, 0
        residual = _fix_residual_ned(run.nav[rows], angles[rows], self.lever, lag + self.latency, z)
        var = _fix_prediction_variance(run, t, rows) + r_fix * np.array([noise.r_scale_h, noise.r_scale_h,
                                                                      noise.r_scale_v])
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

    def _fit(self, start: NoiseModel, iterations: int = EM_ITERATIONS) -> tuple[NoiseModel, _Pass | None]:
        """The first pass from ``start`` (opened up until it holds; the ground-vehicle test once), then at most
        ``iterations`` EM steps on the blocks the innovations identify. Returns the model and its last pass (None
        when it diverged)."""
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
        return self._em_loop(noise, run, iterations)

    def run(self, start: NoiseModel, correlated: NoiseModel | None = None) -> NoiseModel:
        """For each white-noise hypothesis (:meth:`_white_candidates`): the first pass and EM on the blocks the
        innovations identify; when there are two, the one that better predicts held-out fixes
        (:meth:`cross_validate`) wins. Innovations one epoch ahead hardly see the white-noise densities and, on
        real data, prefer whatever follows the fixes best, while a georeferencing run needs the model that
        bridges what it does not see. Then the GNSS error model (:meth:`_gnss_model`, when ``correlated`` gives
        the correlated model's prior), and a last pass with the lever arm and latency as states."""
        candidates = self._white_candidates(start)
        best, best_score, best_state = start, -np.inf, self.start_state
        if self.budget is not None and correlated is not None:  # passes kept for the GNSS model's choice
            self.budget = FIT_PASSES - GNSS_MODEL_PASSES
        for index, candidate in enumerate(candidates):
            if index and self._spent():
                break
            state = self.start_state
            noise, run = self._fit(candidate)
            if run is None:
                self.start_state = state
                continue
            score, mean_d2, count = self.cross_validate(noise) if len(candidates) > 1 else (0.0, np.nan, 0)
            self.cv_scores.append((noise.q_vel_h, score, mean_d2, count))
            # the spectral floor (first) is what the data show; the datasheet has to predict clearly better (the
            # margin decides, the score kept is the model's own: the GNSS model is compared with it next)
            margin = CV_MARGIN if best_score > -np.inf else 0.0
            if score - margin > best_score:
                best, best_score, best_state = noise, score, self.start_state
            self.start_state = state
        self.start_state = best_state
        if self.budget is not None:
            self.budget = FIT_PASSES
        if correlated is not None:
            best = self._gnss_model(best, correlated, best_score if len(candidates) > 1 else None)
        # a last pass with the lever arm and latency as states: what the data say about them
        self._calibrate(best)
        return best

    def _gnss_model(self, white: NoiseModel, correlated: NoiseModel, white_score: float | None) -> NoiseModel:
        """White GNSS errors (``white``, fitted) or with a correlated (Gauss-Markov) part: the correlated model is
        fitted from ``white`` with the correlated part of the ``correlated`` prior, and kept when it predicts
        held-out fixes clearly better (by CV_MARGIN). Both explain the fixes the filter sees; what differs is how
        they bridge the ones it does not: a drone's u-blox fixes wander together, and the correlated model bridges
        them; a car's RTK fixes (KITTI) do not, and a correlated part fitted there bridged its 20-s outages worse
        (0.99 m against 0.77 m). Sets :attr:`gnss_correlated` and :attr:`gnss_model_scores`."""
        state, prior, blocks = self.start_state, self.prior, self.blocks
        if white_score is None:
            white_score = self.cross_validate(white)[0]
        share = GNSS_CORRELATED_SHARE
        start = replace(white, q_gnss_gm_h=correlated.q_gnss_gm_h, q_gnss_gm_v=correlated.q_gnss_gm_v,
                        tau_gnss=correlated.tau_gnss, r_scale_h=white.r_scale_h * (1.0 - share),
                        r_scale_v=white.r_scale_v * (1.0 - share))
        self.prior = correlated
        self.blocks = (*blocks, *GNSS_GM_BLOCKS)
        if self.budget is None:
            noise, run = self._fit(start)
            score = -np.inf if run is None else self.cross_validate(noise)[0]
        elif self._spent():
            noise, run, score = white, None, -np.inf
        else:
            noise, run, score = self._correlated_within_budget(start, white_score)
        self.gnss_model_scores = (float(white_score), float(score))
        if score > white_score + CV_MARGIN:
            self.gnss_correlated = True
            return noise
        self.start_state, self.prior, self.blocks = state, prior, blocks
        return white

    def _correlated_within_budget(self, start: NoiseModel, white_score: float
                                  ) -> tuple[NoiseModel, _Pass | None, float]:
        """The correlated GNSS model fitted from ``start`` with the budget: GNSS_MODEL_EM_STEPS EM steps and its
        held-out score; only when that comes within GNSS_MODEL_SLACK of beating ``white_score`` by CV_MARGIN are
        the remaining EM steps taken (the same steps as without the budget) and the model scored again. Returns
        the model, its last pass (None: diverged) and its score."""
        noise, run = self._fit(start, iterations=GNSS_MODEL_EM_STEPS)
        if run is None:
            return noise, None, -np.inf
        score = self.cross_validate(noise)[0]
        if self.em_settled or score < white_score + CV_MARGIN - GNSS_MODEL_SLACK:
            return noise, run, score
        noise, run = self._em_loop(noise, run, EM_ITERATIONS - GNSS_MODEL_EM_STEPS)
        return noise, run, self.cross_validate(noise)[0]

    def held_out(self, noise: NoiseModel, smooth: bool, latency: float) -> HeldOutCheck | None:
        """:func:`held_out_check` at the fit's rates (the IMU block-averaged, covariance epochs at
        ESTIMATION_RATE_HZ) over the whole flight, with the fitted ``noise``, the given lever arm and ``latency``
        [s]: with the budget, the check costs a fit pass instead of a full-rate one."""
        fixes = self.fixes if self.inputs is self.decimated else \
            _fix_table(self.decimated, self.cfg, self.alignment.start_row)
        return held_out_check(self.decimated, self.cfg, self.alignment, noise, fixes, self.stride, smooth, self.lever,
                              latency, self.start_state, self.nhc)

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
    inside = np.count_nonzero((gnss.time >= t[0]) & (gnss.time <= t[-1]))
    if inside < 6:
        # both spans, so that fixes on another clock than the IMU's (UTC seconds of day against GPS seconds of
        # week or Unix seconds) show as such
        fixes = (f"{len(gnss)} GNSS fixes span {gnss.time.min():.3f} - {gnss.time.max():.3f} s" if len(gnss)
                 else "there are no GNSS fixes")
        raise GeorefError(f"{inputs.source}: the full-state filter needs at least six GNSS fixes inside the IMU span "
                          f"({t[0]:.3f} - {t[-1]:.3f} s); {fixes}, {inside} of them inside. The IMU's and the "
                          "GNSS's times must be on one clock (UTC seconds of the day, GPS seconds of the week or Unix "
                          "seconds): an RTKLIB .pos is put on the IMU's with --time-scale (docs/rtklib.md)")
    inputs.still = still_rows(t, inputs.gyro, inputs.accel, gnss.time, _fix_ned(gnss))
    rate = 1.0 / float(np.median(np.diff(t)))
    lever = np.asarray(cfg.lever_arm_gnss, dtype=float)
    sigma_h, sigma_v = _typical_fix_sigma(gnss, cfg)
    datasheet = noise_prior(cfg)
    prior = data_prior(datasheet, t, inputs.gyro, inputs.accel)
    rate_variance = still_rate_variance(inputs.gyro, inputs.still)
    if rate_variance is not None:
        prior = replace(prior, r_zaru=rate_variance)
    correlated = (with_gnss_correlation(prior, sigma_h, sigma_v, cfg.gnss.correlation_time)
                  if cfg.gnss.correlation_time > 0 else None)
    alignment = decide_heading(inputs, cfg, initial_alignment(inputs, cfg), starting_point(correlated or prior))
    fixes = _fix_table(inputs, cfg, alignment.start_row)
    aiding = bool(cfg.unit.aiding and inputs.unit_rpy is not None)
    blocks = tuple(b for b in range(layout.N_BLOCKS)
                   if (aiding or b not in UNIT_BLOCKS) and b not in (*NHC_BLOCKS, *WHITE_BLOCKS, *GNSS_GM_BLOCKS))
    given_latency = cfg.gnss.latency
    estimation = _Estimation(inputs, cfg, alignment, prior, blocks, lever, given_latency or 0.0, datasheet)
    noise = estimation.run(starting_point(prior), correlated)
    calibration = estimation.calibration
    # the estimate is reported, not applied: it trades off against the lever arm's forward component when the
    # heading follows the track, and its sigma is then optimistic (a simulated car: -0.089 +- 0.026 s estimated,
    # no latency simulated; applying it made the position error 0.83 m instead of 0.34 m)
    latency = given_latency if given_latency is not None else 0.0
    stride = max(1, int(round(rate / cfg.ins.covariance_rate)))
    final = _run_pass(inputs, cfg, alignment, noise, fixes, PassSettings(
        stride, cfg.gnss_gate.chi2, lever, latency, smooth=smooth, nhc=estimation.nhc,
        start_state=estimation.start_state))
    held_out = (estimation.held_out(noise, smooth, latency) if estimation.budget is not None else
                held_out_check(inputs, cfg, alignment, noise, fixes, stride, smooth, lever, latency,
                               estimation.start_state, estimation.nhc))
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
    unmodelled = unmodelled_gnss_variance(gnss, noise)
    pos_var = pos_var + unmodelled
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
        cross_validation=estimation.cv_scores, gnss_correlated=estimation.gnss_correlated,
        gnss_model_scores=estimation.gnss_model_scores, still_spans=_spans(t, inputs.still), held_out=held_out,
        gnss_unmodelled_var=unmodelled,
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
    """INS inputs from a POS log: OMGS [deg/s] -> rad/s, ACCS [m/s^2]; the unit's angles when present; an
    autopilot log's magnetometer and its own yaw (a heading source of last resort, not the unit's attitude)."""
    unit_rpy = None
    iacc = None
    if use_unit_attitude and all(r in log.data for r in ("roll", "pitch", "yaw")):
        unit_rpy = np.radians(np.stack([log.data["roll"], log.data["pitch"], log.data["yaw"]], -1))
        if all(f"iacc_{a}" in log.data for a in "xyz"):
            iacc = log.vector("iacc")
    autopilot_yaw = None if log.autopilot_rpy is None else log.autopilot_rpy[:, 2]
    return InsInputs(time=log.time, gyro=np.radians(log.vector("gyro")), accel=log.vector("acc"), gnss=log.gnss,
                     unit_rpy=unit_rpy, iacc=iacc, source=str(log.path), mag=log.mag, autopilot_yaw=autopilot_yaw)


def solve_rts(log: PosLog, cfg: ProcessingConfig) -> NavSolution:
    """``--method rts``: EKF and RTS smoother on a POS log, with the sections of ``cfg`` it reads."""
    return solve_ins(inputs_from_pos(log), InsSettings.of(cfg), smooth=True)


def solve_ekf(log: PosLog, cfg: ProcessingConfig) -> NavSolution:
    """``--method ekf``: the forward EKF alone on a POS log, with the sections of ``cfg`` it reads."""
    return solve_ins(inputs_from_pos(log), InsSettings.of(cfg), smooth=False)
