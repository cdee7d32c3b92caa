"""``--method graph``: a GTSAM factor-graph smoother over GNSS keyframes.

* Frame: a local NED tangent plane at the flight's centre (GTSAM's navigation frame is Cartesian). Earth
  rotation enters through ``omegaCoriolis = ω_ie`` at the centre; GTSAM's gravity is the normal gravity at the
  centre along the plane's down axis, and each accelerometer row is compensated by ``C_t_b (g_t - g_plane)``
  (its own normal gravity, along its own vertical, in the plane), so the d/R tilt of the vertical (0.16 mrad at
  1 km) is modelled, not absorbed. Results are turned back into each point's own NED frame exactly.
* Keyframes at every GNSS fix (the first IMU row after it) and, where fixes are more than 1.5 s apart, about
  once a second; IMU preintegration between them (``CombinedImuFactor``: pose, velocity and bias random walks);
  of per-step rates carrying the strapdown's rotation, sculling and coning corrections
  (:mod:`georef.fusion.increments`); GNSS fixes through the lever arm and time offset (the calibration
  variable): a robust pass (Cauchy, k = 4 sigma), then a Gaussian refit on its inliers; loose priors at the
  first keyframe. Over IMU gaps the preintegration noise is
  raised as the EKF raises it (:func:`_process_noise_scale`).
* A ground vehicle (when the EKF + RTS applied the non-holonomic constraint): zero lateral and vertical body
  velocity at every keyframe with the EKF's sigmas (:func:`_add_ground_vehicle`), linearised at the RTS
  solution, then once more at the optimum.
* The POS unit's own attitude (``cfg.unit.aiding`` and ROLL/PITCH/YAW in the log), the same model as the EKF
  with the EKF's fitted values: a variable ``U = (e_r, e_p, d, d_dot)`` [rad, rad, rad, rad/s] per keyframe; a
  factor ``(roll + e_r, pitch + e_p, yaw - d) - (roll_u, pitch_u, yaw_u)`` with the fitted white sigmas
  (linearised at the RTS solution and kept as a ``LinearContainerFactor``, evaluated in C++); between
  keyframes a linear factor for the Gauss-Markov level errors (``e_k = exp(-dt/tau) e_k-1``, variance
  ``sigma^2 (1 - exp(-2 dt/tau))``) and the yaw origin with its random-walk drift (the fitted density).
* Initial values from the EKF + RTS solution; batch Levenberg-Marquardt, or ISAM2 fed one keyframe at a time
  (``graph_solver = "isam2"``). Per-keyframe covariances from a QR elimination (:class:`_QrMarginals`); IMU-rate
  states are the RTS trajectory corrected by the graph-minus-RTS difference interpolated between keyframes.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from types import ModuleType
from typing import TYPE_CHECKING, Any

import numpy as np

from georef.config import GraphSettings, ProcessingConfig
from georef.frames import (
    C_e_n,
    C_n_e,
    dcm_to_euler,
    earth_rate_n,
    ecef_to_geodetic,
    euler_to_dcm,
    geodetic_to_ecef,
    normal_gravity,
)
from georef.frames.mounting import lever_arm_offset, lever_arm_rotation_jacobian
from georef.frames.rotations import (
    dcm_to_quat,
    euler_error_jacobian,
    quat_multiply,
    quat_to_dcm,
    quat_to_rotvec,
    rotvec_to_quat,
    skew,
    wrap_pi,
)
from georef.fusion.increments import compensated_rates
from georef.fusion.ins import InsInputs, _fix_sigmas, _gap_scale, inputs_from_pos, solve_ins
from georef.fusion.ins_layout import BA, BG, NHC_GATE, NHC_LEVER
from georef.fusion.solution import GraphCalibration, GraphInfo, NavSolution, ScaleFactors

if TYPE_CHECKING:  # gtsam is imported where it is used; importing this module needs no gtsam
    import gtsam

    from georef.fusion.noise import NoiseModel
    from georef.io.pos import PosLog
    from georef.timing import GnssEpochs

#: a gtsam.symbol_shorthand key function, e.g. ``X``: keyframe index -> key
Symbol = Callable[[int], int]

CAUCHY_K = 4.0
#: the calibration variable's entries: GNSS lever arm x, y, z [m, body], GNSS time offset [s]
CAL_LEVER = slice(0, 3)
CAL_TIME_OFFSET = 3
#: a Pose3's tangent-space order (gtsam): rotation [rad] then translation [m], both in body axes
POSE_ROT = slice(0, 3)
POSE_TRANS = slice(3, 6)
MAX_KEY_GAP = 1.5  # s; longer gaps between fixes get keyframes about once a second
#: [m^2/s] position integration noise of the preintegration. GTSAM's examples use 1e-8; with a tactical-grade gyro
#: (ARW 0.02 deg/sqrt(h)) over a 20-s flight the IMU factors then reached 1.8e7 in the whitened Jacobian against
#: 0.045 for the loosest direction (the position before the first fix), and the marginals' Cholesky failed
#: ("indeterminate system"). 1e-6 (1 mm over a second between keyframes, against metre-level GNSS) keeps the
#: system solvable and moves no position by more than a millimetre on the bundled flight.
INTEGRATION_COVARIANCE = 1e-6
MIN_EDGE_GAP = 0.5  # s; the first/last solved row gets its own keyframe when it is farther than this from a fix
#: [m] the EKF + RTS and the graph run again with the robust pass's lever arm when that differs from the applied
#: one by more than this (and the horizontal fix sigma) on an axis (:func:`_noise_refit`)
LEVER_REFIT_MIN = 0.05


def solve_graph(log: PosLog, cfg: ProcessingConfig, prior: CalibrationPrior | None = None) -> NavSolution:
    """Graph smoother on a POS log (body-frame OMGS deg/s, ACCS m/s^2, GNSS antenna fixes, optionally the unit's
    ROLL/PITCH/YAW deg): :func:`solve_graph_inputs` on :func:`georef.fusion.ins.inputs_from_pos`, with the
    sections of ``cfg`` the graph reads."""
    return solve_graph_inputs(inputs_from_pos(log), GraphSettings.of(cfg), prior=prior)


def solve_graph_inputs(inputs: InsInputs, cfg: GraphSettings | ProcessingConfig, noise_lever: np.ndarray | None = None,
                       prior: CalibrationPrior | None = None) -> NavSolution:
    """Graph smoother on INS inputs (a POS log's or ``georef fuse``'s imu.csv and gnss.csv). Returns a
    :class:`NavSolution` at every IMU row that the EKF + RTS solves: ECEF position [m] and velocity [m/s], geodetic
    lat/lon [rad] and height [m], body-to-NED roll/pitch/yaw [rad], NED position variances [m^2], NED
    attitude-error covariance [rad^2] and Euler sigmas [rad]. ``noise_lever`` [m, body]: the GNSS lever arm the
    EKF + RTS apply instead of the configured one (set by the run itself when its robust pass finds the lever arm
    elsewhere, :func:`_noise_refit`); the graph's own lever-arm prior stays the configured one. ``prior``: a
    campaign's prior on the calibration variable replacing the configured one (:func:`calibration_prior`). A whole
    configuration is narrowed to ``GraphSettings.of(cfg)`` here."""
    if isinstance(cfg, ProcessingConfig):
        cfg = GraphSettings.of(cfg)
    import gtsam
    from gtsam.symbol_shorthand import U, V, X

    # the lever arm the EKF + RTS applies, and so fits its noise model with: the configured one, or
    # ``noise_lever``, the robust pass's estimate when that differs from the configured one (:func:`_noise_refit`)
    rts_lever = np.asarray(cfg.lever_arm_gnss if noise_lever is None else noise_lever, float)
    rts = solve_ins(inputs, cfg if noise_lever is None else cfg.with_lever_arm(noise_lever), smooth=True)
    kf = _keyframes(inputs, rts)
    prior_mean, prior_cov = calibration_prior(cfg, prior)
    values = _initial_values(gtsam, kf, rts)
    factors_at = {0: _first_priors(gtsam, kf, rts, values, prior_mean, prior_cov, rts_lever)}
    _add_imu_factors(gtsam, inputs, cfg, kf, rts, values, factors_at)
    if cfg.unit.aiding and inputs.unit_rpy is not None:
        _add_unit_attitude(gtsam, U, X, inputs.unit_rpy, rts, kf.t, kf.key_rows, kf.C_n_t_rows, rts.diagnostics.noise,
                           values, factors_at)
    nhc_sigma = _add_ground_vehicle(gtsam, X, V, rts, inputs.gyro, kf.key_rows, values, factors_at)
    fixes = _graph_fixes(inputs, cfg, kf, rts)
    calibration = rts.diagnostics.calibration
    lever_start = np.asarray(calibration.lever_arm if calibration is not None else prior_mean[CAL_LEVER], float)
    start = gtsam.Values(values)
    if cfg.graph.robust:
        start, lever_start = _robust_pass(gtsam, cfg, kf, fixes, factors_at, values, lever_start, prior_mean,
                                          prior_cov)
        if noise_lever is None and _noise_refit(lever_start, rts_lever, cfg):
            nav = solve_graph_inputs(inputs, cfg, noise_lever=lever_start, prior=prior)
            # the quality checks compare what the data show with the user's configuration, not with the refit's
            nav.diagnostics.calibration = rts.diagnostics.calibration
            nav.diagnostics.lever_arm_given = rts.diagnostics.lever_arm_given
            return nav
    inlier = _inliers(start, fixes, lever_start, prior_mean[CAL_TIME_OFFSET], cfg.gnss_gate.chi2) \
        if cfg.graph.robust else np.ones(len(fixes.key), bool)
    start.insert(CALIBRATION, np.concatenate([lever_start, prior_mean[CAL_TIME_OFFSET:]]))
    solved = _solve(gtsam, cfg, kf, factors_at, fixes, inlier, start, prior_mean, prior_cov, nhc_sigma)
    corrections = _keyframe_corrections(kf, solved)
    rows = _rows_from_keyframes(kf, rts, corrections)
    info = _graph_info(cfg, kf, solved, corrections, inlier, prior_mean, prior_cov, len(nhc_sigma),
                       rts_lever if noise_lever is not None else None)
    return NavSolution(method="graph", time=kf.t, r_e=rows.r_e, v_e=rows.v_e, lat=rows.lat, lon=rows.lon,
                       height=rows.height, roll=rows.roll, pitch=rows.pitch, yaw=rows.yaw, pos_var_n=rows.pos_var_n,
                       att_sigma=rows.att_sigma, valid=rows.valid, gnss=rts.gnss, ins_info=rts.ins_info,
                       graph_info=info, att_cov_n=rows.att_cov_n, diagnostics=rts.diagnostics)


@dataclass(frozen=True)
class _Keyframes:
    """The RTS solution the graph starts from, in the local tangent plane at the flight's centre.

    ``t`` (N,) [s] the IMU rows' times; ``use`` the GNSS fixes (indices) within the RTS's solved span;
    ``key_rows`` the keyframes' rows; the plane's origin ``r0`` [m, ECEF], rotation ``C_e_t`` (ECEF to plane),
    normal ``gravity`` at the origin [m/s^2] and Earth rate ``omega`` [rad/s, plane]; per row: ``C_n_t_rows``
    (N, 3, 3) each row's NED to the plane, ``C_b_t`` (N, 3, 3) body to plane, ``p_t`` (N, 3) [m] and ``v_t``
    (N, 3) [m/s] position and velocity in the plane."""

    t: np.ndarray
    use: np.ndarray
    key_rows: np.ndarray
    r0: np.ndarray
    C_e_t: np.ndarray
    gravity: float
    omega: np.ndarray
    C_n_t_rows: np.ndarray
    C_b_t: np.ndarray
    p_t: np.ndarray
    v_t: np.ndarray

    def to_plane(self, r_e: np.ndarray) -> np.ndarray:
        """ECEF positions [m] into the plane [m]."""
        return (r_e - self.r0) @ self.C_e_t.T


def _keyframes(inputs: InsInputs, rts: NavSolution) -> _Keyframes:
    """The keyframes (:func:`_key_rows`) of the fixes within the RTS's solved rows, the tangent plane at the
    central keyframe, and the RTS's states in that plane."""
    t = rts.time
    valid_rows = np.flatnonzero(rts.valid)
    gnss = inputs.gnss
    use = np.flatnonzero((gnss.time >= t[valid_rows[0]]) & (gnss.time <= t[valid_rows[-1]])
                         & (rts.gnss.status >= 0))
    key_rows = _key_rows(t, valid_rows, np.searchsorted(t, gnss.time[use], side="left"))
    # tangent plane at the centre of the flight
    centre = len(key_rows) // 2
    lat0, lon0, h0 = rts.lat[key_rows[centre]], rts.lon[key_rows[centre]], rts.height[key_rows[centre]]
    r0 = geodetic_to_ecef(lat0, lon0, h0)
    C_e_t = C_e_n(lat0, lon0)
    # rotation of each point's NED into the plane: C_n_t = C_e_t C_n_e(lat, lon)
    C_n_t_rows = C_e_t @ C_n_e(rts.lat, rts.lon)
    gravity, omega = float(normal_gravity(lat0, h0)), C_e_t @ C_n_e(lat0, lon0) @ earth_rate_n(lat0)
    return _Keyframes(t=t, use=use, key_rows=key_rows, r0=r0, C_e_t=C_e_t, gravity=gravity, omega=omega,
                      C_n_t_rows=C_n_t_rows, C_b_t=C_n_t_rows @ euler_to_dcm(rts.roll, rts.pitch, rts.yaw),
                      p_t=(rts.r_e - r0) @ C_e_t.T,
                      v_t=rts.v_e @ C_e_t.T)  # ECEF velocity into the tangent plane


def _initial_values(gtsam: ModuleType, kf: _Keyframes, rts: NavSolution) -> gtsam.Values:
    """Pose ``X(k)``, velocity ``V(k)`` and bias ``B(k)`` of every keyframe at the RTS solution."""
    from gtsam.symbol_shorthand import B, V, X

    values = gtsam.Values()
    gyro_bias, accel_bias = rts.ins_info.gyro_bias, rts.ins_info.accel_bias
    for k, row in enumerate(kf.key_rows):
        values.insert(X(k), gtsam.Pose3(gtsam.Rot3(kf.C_b_t[row]), kf.p_t[row]))
        values.insert(V(k), kf.v_t[row])
        values.insert(B(k), gtsam.imuBias.ConstantBias(accel_bias[row], gyro_bias[row]))
    return values


def _first_priors(gtsam: ModuleType, kf: _Keyframes, rts: NavSolution, values: gtsam.Values, prior_mean: np.ndarray,
                  prior_cov: np.ndarray, rts_lever: np.ndarray) -> list:
    """Loose priors on the first keyframe's pose, velocity and bias. The RTS's position there rests on the lever arm
    it applied (``rts_lever`` [m, body]), so its prior also allows for the lever-arm prior's uncertainty and its
    distance from the configured one (else an untold lever arm is pulled towards zero: 10 sigma in z on a PPK
    flight, 12 sigma under a campaign's prior)."""
    from gtsam.symbol_shorthand import B, V, X

    first = kf.key_rows[0]
    lever_doubt = np.hypot(np.sqrt(np.trace(prior_cov[CAL_LEVER, CAL_LEVER])),
                           np.linalg.norm(prior_mean[CAL_LEVER] - rts_lever))
    pos_sigma = np.hypot(np.sqrt(rts.pos_var_n[first]) * 3.0, lever_doubt)
    return [
        gtsam.PriorFactorPose3(X(0), values.atPose3(X(0)), gtsam.noiseModel.Diagonal.Sigmas(
            np.concatenate([np.full(3, np.radians(1.0)), pos_sigma]))),
        gtsam.PriorFactorVector(V(0), kf.v_t[first], gtsam.noiseModel.Isotropic.Sigma(3, 0.5)),
        gtsam.PriorFactorConstantBias(B(0), values.atConstantBias(B(0)), gtsam.noiseModel.Diagonal.Sigmas(
            np.sqrt(np.concatenate([np.diag(rts.diagnostics.alignment.covariance)[BA:BA + 3],
                                    np.diag(rts.diagnostics.alignment.covariance)[BG:BG + 3]])) * 3.0))]


def _add_imu_factors(gtsam: ModuleType, inputs: InsInputs, cfg: GraphSettings, kf: _Keyframes, rts: NavSolution,
                     values: gtsam.Values, factors_at: dict[int, list]) -> None:
    """An IMU factor and a bias random-walk factor per interval between keyframes (and, with scale factors, the
    :data:`SCALE` variable and its prior at the first keyframe), added to ``factors_at``."""
    from gtsam.symbol_shorthand import B, V, X

    t, key_rows = kf.t, kf.key_rows
    noise = rts.diagnostics.noise
    params = _preintegration_params(gtsam, noise, kf.gravity, kf.omega, 1.0)
    q_scale = _process_noise_scale(rts, inputs)
    # each row's own normal gravity, turned into the plane: f' = f + C_t_b (g_t - g_plane) makes GTSAM's constant
    # plane gravity exact (the local vertical is tilted by d/R from the plane's down axis)
    g_t = kf.C_n_t_rows[:, :, 2] * normal_gravity(rts.lat, rts.height)[:, None]
    g_fix = np.einsum("nji,nj->ni", kf.C_b_t, g_t - np.array([0.0, 0.0, kf.gravity]))
    accel = inputs.accel + np.where(np.isfinite(g_fix), g_fix, 0.0)
    # per-interval rates with the strapdown's rotation, sculling and coning corrections: GTSAM holds the attitude
    # at the start of each step (georef.fusion.increments; without them the graph lost accuracy against rts:
    # docs/performance.md, "Graph smoother")
    accel_step, gyro_step = compensated_rates(t, inputs.gyro, accel, rts.ins_info.gyro_bias, rts.ins_info.accel_bias)
    scale_sigma = cfg.graph.scale_factor_sigma
    # B(k) is the bias the IMU factor of the interval from keyframe k to k + 1 corrects its rates by: the sensor's
    # bias plus, with scale factors, diag(mean rates over the interval) s (:func:`_bias_factor`)
    mean_rates = _interval_means(t, key_rows, np.hstack([accel_step, gyro_step]))
    if scale_sigma > 0:
        values.insert(SCALE, np.zeros(6))
        factors_at[0].append(gtsam.PriorFactorVector(SCALE, np.zeros(6),
                                                     gtsam.noiseModel.Isotropic.Sigma(6, scale_sigma)))
    # rows as Python objects once: indexing numpy per measurement cost more than GTSAM's integration itself
    accel_rows, gyro_rows, dt_rows = list(accel_step), list(gyro_step), np.diff(t).tolist()
    for k in range(1, len(key_rows)):
        a, b = key_rows[k - 1], key_rows[k]
        # the EKF's process-noise factors over this interval (IMU gaps, GNSS outages), averaged over its rows: the
        # preintegrated rotation and velocity variances (integrals of the noise density) are then the EKF's
        segment = q_scale[a + 1:b + 1]
        scale = np.average(segment, axis=0, weights=np.diff(t[a:b + 1])) if np.any(segment != 1.0) else (1.0, 1.0)
        step = params if scale[0] == 1.0 else _preintegration_params(gtsam, noise, kf.gravity, kf.omega, scale[0])
        pim = gtsam.PreintegratedImuMeasurements(step, values.atConstantBias(B(k - 1)))
        for r in range(a, b):
            pim.integrateMeasurement(accel_rows[r], gyro_rows[r], dt_rows[r])
        rate_change = mean_rates[min(k, len(mean_rates) - 1)] - mean_rates[k - 1]
        factors_at.setdefault(k, []).extend([
            gtsam.ImuFactor(X(k - 1), V(k - 1), X(k), V(k), B(k - 1), pim),
            _bias_factor(gtsam, B(k - 1), B(k), _bias_drive(noise, scale[1]) * (t[b] - t[a]),
                         rate_change if scale_sigma > 0 else None, values)])


def _graph_fixes(inputs: InsInputs, cfg: GraphSettings, kf: _Keyframes, rts: NavSolution) -> _Fixes:
    """The GNSS antenna fixes at their keyframes with the sigmas the EKF + RTS fitted to this flight: each fix's own
    (gnss.csv sigma_n/e/u) or the configured ones, scaled by the fitted variance factors. They constrain the
    calibration variable too: the GNSS lever arm [m, body] and the GNSS time offset [s] (each fix was measured
    that long before its time tag, the EKF's ``gnss_latency``)."""
    noise = rts.diagnostics.noise
    sigma = _fix_sigmas(inputs.gnss, cfg) * np.sqrt([noise.r_scale_h, noise.r_scale_h, noise.r_scale_v])
    return _fixes_at_keyframes(inputs.gnss, kf.use, kf.t, kf.key_rows, kf.to_plane, sigma)


def _robust_pass(gtsam: ModuleType, cfg: GraphSettings, kf: _Keyframes, fixes: _Fixes, factors_at: dict[int, list],
                 values: gtsam.Values, lever_start: np.ndarray, prior_mean: np.ndarray,
                 prior_cov: np.ndarray) -> tuple[gtsam.Values, np.ndarray]:
    """The robust pass: a Cauchy kernel on every fix, the lever arm a variable (from ``lever_start`` [m, body]),
    the time offset held at its prior mean. Returns its solution (without the lever-arm variable) and its lever arm
    [m, body]; the fixes it leaves as outliers are then dropped (:func:`_inliers`) and the graph refitted with
    Gaussian factors."""
    from gtsam.symbol_shorthand import X

    cauchy = gtsam.noiseModel.mEstimator.Cauchy.Create(CAUCHY_K)
    offset = prior_mean[CAL_TIME_OFFSET]
    robust_factors = {k: [gtsam.GPSFactorArmCalib(X(k), LEVER, z + kf.v_t[kf.key_rows[k]] * (offset - lag),
                                                  gtsam.noiseModel.Robust.Create(
                                                      cauchy, gtsam.noiseModel.Diagonal.Sigmas(fix_sigma)))]
                      for k, z, lag, fix_sigma in zip(fixes.key, fixes.z, fixes.lag, fixes.sigma, strict=True)}
    robust_factors[0] = robust_factors.get(0, []) + [gtsam.PriorFactorPoint3(
        LEVER, prior_mean[CAL_LEVER], gtsam.noiseModel.Gaussian.Covariance(prior_cov[CAL_LEVER, CAL_LEVER]))]
    robust_start = gtsam.Values(values)
    robust_start.insert(LEVER, lever_start)
    start = _optimise(gtsam, cfg, factors_at, robust_factors, robust_start, len(kf.key_rows))
    lever = np.asarray(start.atPoint3(LEVER), float)
    start.erase(LEVER)
    return start, lever


@dataclass(frozen=True)
class _Solved:
    """The optimised graph: its ``result`` (gtsam.Values), the whole factor ``graph`` and its ``marginals``."""

    result: Any
    graph: Any
    marginals: _QrMarginals


def _solve(gtsam: ModuleType, cfg: GraphSettings, kf: _Keyframes, factors_at: dict[int, list], fixes: _Fixes,
           inlier: np.ndarray, start: gtsam.Values, prior_mean: np.ndarray, prior_cov: np.ndarray,
           nhc_sigma: dict[int, np.ndarray]) -> _Solved:
    """The Gaussian fit: the calibration variable's prior and the ``inlier`` fixes' factors (linearised at
    ``start``) added to ``factors_at``, optimised from ``start``; a ground vehicle's non-holonomic factors
    linearised once more at the optimum (batch solver); the marginals from QR."""
    from gtsam.symbol_shorthand import V, X

    gnss_factors: dict[int, list] = {0: [gtsam.PriorFactorVector(CALIBRATION, prior_mean,
                                                                 gtsam.noiseModel.Gaussian.Covariance(prior_cov))]}
    kept = _Fixes(key=fixes.key[inlier], z=fixes.z[inlier], lag=fixes.lag[inlier], sigma=fixes.sigma[inlier])
    for k, factor in zip(kept.key, _gnss_factors(gtsam, kept, start), strict=True):
        gnss_factors.setdefault(k, []).append(factor)
    result = _optimise(gtsam, cfg, factors_at, gnss_factors, start, len(kf.key_rows))
    graph = gtsam.NonlinearFactorGraph()
    for k in range(len(kf.key_rows)):
        for factor in factors_at.get(k, []) + gnss_factors.get(k, []):
            graph.add(factor)
    if nhc_sigma and cfg.graph.solver != "isam2":
        result = _relinearise_ground_vehicle(gtsam, X, V, graph, result, nhc_sigma)
    return _Solved(result=result, graph=graph, marginals=_QrMarginals(gtsam, graph, result))


@dataclass(frozen=True)
class _KeyframeCorrections:
    """Graph minus RTS at the keyframes (K of them), and the graph's own uncertainty there.

    ``R`` (K, 3, 3) the graph's body-to-plane rotations; ``d_pos`` (K, 3) [m] and ``d_vel`` (K, 3) [m/s] the
    position and velocity differences in the plane; ``d_rot`` (K, 3) [rad] the rotation ``R C_t_b(RTS)`` as a
    plane-frame rotation vector; ``pos_var`` (K, 3) [m^2] the NED position variances; ``att_cov`` (K, 3, 3)
    [rad^2] the NED attitude-error covariances."""

    R: np.ndarray
    d_pos: np.ndarray
    d_vel: np.ndarray
    d_rot: np.ndarray
    pos_var: np.ndarray
    att_cov: np.ndarray


def _keyframe_corrections(kf: _Keyframes, solved: _Solved) -> _KeyframeCorrections:
    """The graph minus the RTS at every keyframe, with the graph's marginal covariances in each keyframe's NED."""
    from gtsam.symbol_shorthand import X

    key_rows = kf.key_rows
    n_keys = len(key_rows)
    R_keys, p_keys, v_keys = _keyframe_states(solved.result, np.arange(n_keys))
    cov = solved.marginals.marginalCovariances([X(k) for k in range(n_keys)])  # (K, 6, 6), Pose3 tangent: body axes
    C_b_n_keys = np.swapaxes(kf.C_n_t_rows[key_rows], -1, -2) @ R_keys
    pos_var = np.diagonal(C_b_n_keys @ cov[:, POSE_TRANS, POSE_TRANS] @ np.swapaxes(C_b_n_keys, -1, -2), axis1=1,
                          axis2=2)
    att_cov = C_b_n_keys @ cov[:, POSE_ROT, POSE_ROT] @ np.swapaxes(C_b_n_keys, -1, -2)
    d_rot = quat_to_rotvec(dcm_to_quat(R_keys @ np.swapaxes(kf.C_b_t[key_rows], -1, -2)))  # plane-frame rotations
    return _KeyframeCorrections(R=R_keys, d_pos=p_keys - kf.p_t[key_rows], d_vel=v_keys - kf.v_t[key_rows],
                                d_rot=d_rot, pos_var=pos_var, att_cov=att_cov)


@dataclass(frozen=True)
class _GraphRows:
    """The graph's solution at every IMU row (N): ECEF ``r_e`` [m] and ``v_e`` [m/s], geodetic ``lat``, ``lon``
    [rad] and ``height`` [m], body-to-NED ``roll``, ``pitch``, ``yaw`` [rad], NED ``pos_var_n`` [m^2] and
    ``att_cov_n`` (N, 3, 3) [rad^2], Euler ``att_sigma`` [rad], and ``valid`` (rows the RTS solved)."""

    r_e: np.ndarray
    v_e: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    height: np.ndarray
    roll: np.ndarray
    pitch: np.ndarray
    yaw: np.ndarray
    pos_var_n: np.ndarray
    att_cov_n: np.ndarray
    att_sigma: np.ndarray
    valid: np.ndarray


def _rows_from_keyframes(kf: _Keyframes, rts: NavSolution, corrections: _KeyframeCorrections) -> _GraphRows:
    """IMU-rate states: the RTS trajectory corrected by the graph-minus-RTS difference interpolated between
    keyframes, turned back into each row's own NED frame; covariances interpolated likewise."""
    key_rows = kf.key_rows
    rows = np.arange(len(kf.t))
    interp = lambda data: np.stack([np.interp(rows, key_rows, data[:, j]) for j in range(data.shape[1])], -1)  # noqa: E731
    p_new = kf.p_t + interp(corrections.d_pos)
    v_new = kf.v_t + interp(corrections.d_vel)
    rot = rotvec_to_quat(interp(corrections.d_rot))
    C_b_t_new = quat_to_dcm(quat_multiply(rot, dcm_to_quat(kf.C_b_t)))
    r_e = kf.r0 + p_new @ kf.C_e_t
    lat, lon, height = ecef_to_geodetic(r_e)
    C_b_n_new = np.swapaxes(kf.C_e_t @ C_n_e(lat, lon), -1, -2) @ C_b_t_new
    roll, pitch, yaw = dcm_to_euler(C_b_n_new)
    v_e = v_new @ kf.C_e_t
    pos_var_rows = interp(corrections.pos_var)
    att_cov_rows = interp(corrections.att_cov.reshape(len(key_rows), 9)).reshape(-1, 3, 3)
    J = euler_error_jacobian(roll, pitch, yaw)
    att_sigma = np.sqrt(np.einsum("nij,njk,nik->ni", J, att_cov_rows, J))
    valid = rts.valid.copy()  # rows beyond the end keyframes (< MIN_EDGE_GAP) take the end keyframes' corrections
    for array in (r_e, v_e, pos_var_rows, att_sigma):
        array[~valid] = np.nan
    return _GraphRows(r_e=r_e, v_e=v_e, lat=lat, lon=lon, height=height, roll=roll, pitch=pitch, yaw=yaw,
                      pos_var_n=pos_var_rows, att_cov_n=att_cov_rows, att_sigma=att_sigma, valid=valid)


def _graph_info(cfg: GraphSettings, kf: _Keyframes, solved: _Solved, corrections: _KeyframeCorrections,
                inlier: np.ndarray, prior_mean: np.ndarray, prior_cov: np.ndarray, nhc_factors: int,
                noise_refit_lever: np.ndarray | None) -> GraphInfo:
    """The graph's calibration estimate (lever arm, time offset, scale factors) with its marginal covariance, its
    fixes and outliers, and its separation from the RTS it started from."""
    result, marginals = solved.result, solved.marginals
    d_pos, pos_var, att_cov = corrections.d_pos, corrections.pos_var, corrections.att_cov
    # the graph against the RTS it started from, in units of the graph's own horizontal sigma at each keyframe:
    # both smoothers carry the same information, so a separation of several sigma means one of them went wrong
    separation = np.hypot(d_pos[:, 0], d_pos[:, 1]) / np.sqrt(pos_var[:, 0] + pos_var[:, 1])
    # and the attitude: the graph-minus-RTS rotation in each keyframe's NED frame, per axis in units of the graph's
    # own sigma of that axis, the largest of the three
    d_rot_n = np.einsum("kji,kj->ki", kf.C_n_t_rows[kf.key_rows], corrections.d_rot)
    attitude_separation = np.max(np.abs(d_rot_n) / np.sqrt(np.diagonal(att_cov, axis1=1, axis2=2)), axis=1)
    estimate = np.asarray(result.atVector(CALIBRATION), float)
    covariance = marginals.marginalCovariance(CALIBRATION)
    scale_sigma = cfg.graph.scale_factor_sigma
    scale_factors = None
    if scale_sigma > 0:
        scale, scale_sigmas = np.asarray(result.atVector(SCALE), float), np.sqrt(np.diag(
            marginals.marginalCovariance(SCALE)))
        scale_factors = ScaleFactors(accel_ppm=scale[:3] * 1e6, accel_sigma_ppm=scale_sigmas[:3] * 1e6,
                                     gyro_ppm=scale[3:] * 1e6, gyro_sigma_ppm=scale_sigmas[3:] * 1e6,
                                     prior_sigma_ppm=scale_sigma * 1e6)
    return GraphInfo(lever_arm_m=estimate[CAL_LEVER], lever_arm_sigma_m=np.sqrt(np.diag(covariance)[CAL_LEVER]),
                     time_offset_s=float(estimate[CAL_TIME_OFFSET]),
                     time_offset_sigma_s=float(np.sqrt(covariance[CAL_TIME_OFFSET, CAL_TIME_OFFSET])),
                     calibration=GraphCalibration(mean=estimate, covariance=covariance, prior_mean=prior_mean,
                                                  prior_covariance=prior_cov),
                     rejected_fixes=int(np.sum(~inlier)), fixes=len(inlier), rts_separation_sigma=separation,
                     rts_attitude_separation_sigma=attitude_separation, keyframes=len(kf.key_rows),
                     nhc_factors=nhc_factors, error_final=solved.graph.error(result), scale_factors=scale_factors,
                     noise_refit_lever_arm_m=noise_refit_lever)


class _QrMarginals:
    """Marginal covariances of a solved graph, from a multifrontal QR elimination of the graph linearised at
    ``result`` (COLAMD ordering), in the same tangent-space convention as ``gtsam.Marginals``.

    ``gtsam.Marginals`` eliminates the Hessian with Cholesky, which squares the Jacobian's condition number. The
    graph's variables span ten decades of information (a tactical gyro's bias between keyframes a second apart:
    1e10 rad^-2 s^2, a position before the first fix: 1), and on a 20-s tactical car (condition number of the
    Jacobian 7e5, of the Hessian 6e11, positive definite: numpy's Cholesky of the dense Hessian succeeds)
    GTSAM's Cholesky met a non-positive pivot with COLAMD's frontal blocks ("indeterminate system", exit 3).
    QR works on the whitened Jacobian itself; on a 60-s helicopter flight its covariances equal
    ``gtsam.Marginals``' to 4e-5 relative.

    Each marginal is then taken from the QR tree with GTSAM's default elimination (Cholesky on the small joint of a
    clique and its separator's marginal), and with QR only where that fails: the tree's square-root factors keep
    these small systems well conditioned, and it is faster than QR throughout (docs/method-graph.md, "Speed"). On
    two ill-conditioned flights, the 21.6-s tactical car of the property sweep and a
    20-s tactical helicopter with an outage, the two agree to 7e-8 relative on every variable and neither fails."""

    def __init__(self, gtsam: ModuleType, graph: gtsam.NonlinearFactorGraph, result: gtsam.Values) -> None:
        self._gtsam = gtsam
        linear = graph.linearize(result)
        self._tree = linear.eliminateMultifrontal(gtsam.Ordering.ColamdGaussianFactorGraph(linear), gtsam.EliminateQR)

    def marginalCovariance(self, key: int) -> np.ndarray:  # noqa: N802 (gtsam.Marginals' name)
        return np.linalg.inv(self._information(key))

    def marginalCovariances(self, keys: list[int]) -> np.ndarray:  # noqa: N802 (as marginalCovariance)
        """The marginal covariances (K, d, d) of ``keys``, variables of one dimension d."""
        return np.linalg.inv(np.array([self._information(key) for key in keys]))

    def _information(self, key: int) -> np.ndarray:
        try:
            factor = self._tree.marginalFactor(key)
        except RuntimeError:  # GTSAM's IndeterminantLinearSystemException
            factor = self._tree.marginalFactor(key, self._gtsam.EliminateQR)
        return factor.information()


#: a campaign's prior on the calibration variable: (mean (4,), covariance (4, 4)), lever arm [m, body] and GNSS time
#: offset [s]; not a flight.toml setting but an estimate from the campaign's other flights (georef.campaign)
CalibrationPrior = tuple[Any, Any]
LEVER_ARM_GIVEN_SIGMA = 0.05  # m, a lever arm taped on the installation
LEVER_ARM_FREE_SIGMA = 10.0  # m, no lever arm given: only keeps the variable determinate
TIME_OFFSET_GIVEN_SIGMA = 0.01  # s, a GNSS latency given in the configuration
#: s, none given: a POS log time-tags its fixes from the receiver's PPS, so the offset is zero unless a latency is
#: misconfigured (which the EKF's latency check reports). The offset is a time shift of the whole trajectory
#: against the IMU's clock, so its error moves every frame along track by speed x error: 1-m fixes determine it
#: to 13 ms in 3 minutes (0.4 m at 30 m/s; a looser prior made the bundled flight's kind worse:
#: docs/performance.md, "Graph smoother"), PPK-grade fixes to 0.6 ms in 10 minutes. Set ``gnss_latency_sigma`` to
#: calibrate it.
TIME_OFFSET_DEFAULT_SIGMA = 0.002
#: the calibration variable: (lever arm x, y, z [m, body], GNSS time offset [s]), one per flight
CALIBRATION = 0x6300000000000000  # gtsam.symbol("c", 0), spelt out so that importing this module needs no gtsam
LEVER = 0x6C00000000000000  # gtsam.symbol("l", 0): the lever arm alone (Point3), in the robust pass
#: the scale-factor errors (accelerometer x, y, z, gyro x, y, z; unitless, measured = (1 + s) true), one per flight
SCALE = 0x7300000000000000  # gtsam.symbol("s", 0)


def calibration_prior(cfg: GraphSettings, prior: CalibrationPrior | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The graph's prior on its calibration variable ``(lever arm x, y, z [m, body], time offset [s])``: mean (4,)
    and covariance (4, 4).

    ``prior`` (a campaign's estimate, ``georef batch --shared-calibration``) when given; else the given lever arm
    with ``cfg.lever_arm_gnss_sigma`` (0.05 m when a lever arm is given, free, 10 m, without one) and the given
    ``gnss.latency`` with ``cfg.gnss.latency_sigma`` (0.01 s when given, else zero with 2 ms), uncorrelated.
    """
    if prior is not None:
        mean, covariance = prior
        return np.asarray(mean, float).reshape(4), np.asarray(covariance, float).reshape(4, 4)
    lever_sigma = cfg.lever_arm_gnss_sigma
    if lever_sigma is None:
        lever_sigma = LEVER_ARM_GIVEN_SIGMA if any(v != 0.0 for v in cfg.lever_arm_gnss) else LEVER_ARM_FREE_SIGMA
    offset_sigma = cfg.gnss.latency_sigma
    if offset_sigma is None:
        offset_sigma = TIME_OFFSET_GIVEN_SIGMA if cfg.gnss.latency is not None else TIME_OFFSET_DEFAULT_SIGMA
    mean = np.array([*cfg.lever_arm_gnss, cfg.gnss.latency or 0.0])
    sigmas = np.concatenate([np.broadcast_to(np.asarray(lever_sigma, float), 3), [offset_sigma]])
    return mean, np.diag(sigmas**2)


@dataclass(frozen=True)
class _Fixes:
    """GNSS fixes used by the graph: the keyframe of each (``key``), its antenna position in the plane ``z`` [m],
    ``lag`` = fix time - keyframe row time [s] (at most one IMU interval, negative) and its white-noise ``sigma``
    (north, east, vertical [m]; applied on the plane's axes, which the flight's NED tilts by at most its extent
    over the Earth's radius)."""

    key: np.ndarray
    z: np.ndarray
    lag: np.ndarray
    sigma: np.ndarray


def _fixes_at_keyframes(gnss: GnssEpochs, use: np.ndarray, t: np.ndarray, key_rows: np.ndarray,
                        to_plane: Callable[[np.ndarray], np.ndarray], sigma: np.ndarray) -> _Fixes:
    """The fixes ``use`` (indices into ``gnss``) at their keyframes (the first IMU row at or after each), one per
    keyframe, with their rows of ``sigma`` (one per fix of ``gnss``, north, east, vertical [m])."""
    rows = np.searchsorted(t, gnss.time[use], side="left")
    k = np.searchsorted(key_rows, rows)
    at_key = (k < len(key_rows)) & (key_rows[np.minimum(k, len(key_rows) - 1)] == rows)
    use, rows, k = use[at_key], rows[at_key], k[at_key]
    k, first = np.unique(k, return_index=True)
    use, rows = use[first], rows[first]
    r_ant = geodetic_to_ecef(np.radians(gnss.lat_deg[use]), np.radians(gnss.lon_deg[use]), gnss.height[use])
    return _Fixes(key=k, z=to_plane(r_ant), lag=gnss.time[use] - t[rows], sigma=sigma[use])


def _keyframe_states(values: gtsam.Values, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rotations ``R`` (K, 3, 3) (body to plane), positions ``p`` (K, 3) [m, plane] and velocities ``v`` (K, 3)
    [m/s, plane] of keyframes ``keys`` (indices) in ``values``."""
    from gtsam.symbol_shorthand import V, X

    poses = np.array([values.atPose3(X(k)).matrix() for k in keys]).reshape(-1, 4, 4)
    velocities = np.array([values.atVector(V(k)) for k in keys]).reshape(-1, 3)
    return poses[:, :3, :3], poses[:, :3, 3], velocities


def _antenna_residuals(values: gtsam.Values, fixes: _Fixes,
                       calibration: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """GNSS residuals (F, 3) [m, plane] ``p + R l + v (lag - dt) - z`` of ``fixes`` at their keyframes in ``values``
    (pose ``R, p``, velocity ``v`` [m/s]) with calibration ``(l [m, body], dt [s])``; and the keyframes' rotations
    ``R`` (F, 3, 3) and velocities (F, 3)."""
    R, p, v = _keyframe_states(values, fixes.key)
    lag = fixes.lag[:, None] - calibration[CAL_TIME_OFFSET]
    return p + lever_arm_offset(R, calibration[CAL_LEVER]) + v * lag - fixes.z, R, v


def _gnss_factors(gtsam: ModuleType, fixes: _Fixes, at: gtsam.Values) -> list[gtsam.LinearContainerFactor]:
    """One factor per GNSS fix: the antenna position ``z`` [m, plane], measured ``dt`` seconds before its tag
    (``lag`` [s] before the keyframe), equals ``p + R l + v (lag - dt)`` at its keyframe, white noise ``sigma``
    [m].

    Linearised at ``at`` (the robust pass's solution, or the RTS's, with the calibration variable) and kept as
    ``LinearContainerFactor`` s (evaluated in C++; GTSAM has no GNSS factor with a time offset). The factor is
    linear in ``p``, ``v``, ``l`` and ``dt`` but for the products ``R l`` and ``v dt``: the graph moves the attitude
    by hundredths of a degree (``R l`` then changes by a fraction of a millimetre at a 2-m lever arm) and the
    neglected ``dv ddt`` is 0.5 mm for a 5-cm/s velocity change and a 10-ms offset change. Pose3 tangent order:
    rotation (body), then translation (body). Residuals and Jacobians are computed for all fixes at once.
    """
    from gtsam.symbol_shorthand import V, X

    calibration = np.asarray(at.atVector(CALIBRATION), float)
    residual, R, v = _antenna_residuals(at, fixes, calibration)
    weight = 1.0 / fixes.sigma[:, :, None]
    H_pose = np.concatenate([lever_arm_rotation_jacobian(R, calibration[CAL_LEVER]), R], axis=2) * weight
    H_v = np.eye(3) * (fixes.lag - calibration[CAL_TIME_OFFSET])[:, None, None] * weight
    H_c = np.concatenate([R, -v[:, :, None]], axis=2) * weight
    b = -residual / fixes.sigma
    unit = gtsam.noiseModel.Unit.Create(3)
    return [gtsam.LinearContainerFactor(gtsam.JacobianFactor(X(k), H_pose[i], V(k), H_v[i], CALIBRATION, H_c[i],
                                                             b[i], unit), at)
            for i, k in enumerate(fixes.key)]


def _inliers(values: gtsam.Values, fixes: _Fixes, lever: np.ndarray, offset: float, threshold: float) -> np.ndarray:
    """Fixes whose whitened residual after the robust pass is within ``threshold`` (chi-square, 3 degrees of
    freedom; ``cfg.gnss_gate.chi2``, 99.9 % by default: one good fix in a thousand is lost). The residual is against
    the robust solution, which the fix itself pulled only weakly (the Cauchy kernel)."""
    residual, _, _ = _antenna_residuals(values, fixes, np.concatenate([lever, [offset]]))
    return np.sum((residual / fixes.sigma) ** 2, axis=1) <= threshold


#: Levenberg-Marquardt stops when an iteration lowers the cost by less than this fraction of it (GTSAM's default
#: 1e-5). The graph starts from the RTS solution, close to its optimum, where the Gauss-Newton steps converge
#: quadratically: against the default, positions moved by a negligible amount for fewer iterations and less time
#: (docs/method-graph.md, "Speed").
LM_RELATIVE_TOLERANCE = 1e-3


def _lm_params(gtsam: ModuleType) -> gtsam.LevenbergMarquardtParams:
    """GTSAM's Levenberg-Marquardt defaults but for the stopping tolerance :data:`LM_RELATIVE_TOLERANCE`."""
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(LM_RELATIVE_TOLERANCE)
    return params


def _optimise(gtsam: ModuleType, cfg: GraphSettings, factors_at: dict[int, list], extra: dict[int, list],
              values: gtsam.Values, n_keys: int) -> gtsam.Values:
    """Optimise the graph of ``factors_at`` and ``extra`` (factors by keyframe) from ``values``: batch
    Levenberg-Marquardt, or ISAM2 fed one keyframe at a time (``cfg.graph.solver``) as a real-time user would."""
    if cfg.graph.solver != "isam2":
        graph = gtsam.NonlinearFactorGraph()
        for k in range(n_keys):
            for factor in factors_at.get(k, []) + extra.get(k, []):
                graph.add(factor)
        return gtsam.LevenbergMarquardtOptimizer(graph, values, _lm_params(gtsam)).optimize()
    from gtsam.symbol_shorthand import B, U, V, X

    params = gtsam.ISAM2Params()
    # QR, as the marginals (_QrMarginals): with the scale-factor variable, the default Cholesky called the unit
    # variables indeterminate on a 3-minute helicopter flight (exit 3)
    params.setFactorization("QR")
    isam = gtsam.ISAM2(params)
    for k in range(n_keys):
        new_graph = gtsam.NonlinearFactorGraph()
        for factor in factors_at.get(k, []) + extra.get(k, []):
            new_graph.add(factor)
        new_values = gtsam.Values()
        keys = [X(k), V(k), B(k), U(k)] + ([LEVER, CALIBRATION, SCALE] if k == 0 else [])
        for key in keys:
            if values.exists(key):
                _copy_value(new_values, values, key)
        isam.update(new_graph, new_values)
    isam.update()
    return isam.calculateEstimate()


def _interval_means(t: np.ndarray, key_rows: np.ndarray, data: np.ndarray) -> np.ndarray:
    """Means of per-step ``data`` (N - 1, m) over each interval between consecutive keyframes, (len(key_rows) - 1,
    m): row ``r`` is the step from ``t[r]`` to ``t[r + 1]`` [s], weighted by its length."""
    steps = np.diff(t)[:, None] * data
    cumulative = np.vstack([np.zeros((1, data.shape[1])), np.cumsum(steps, axis=0)])
    a, b = key_rows[:-1], key_rows[1:]
    return (cumulative[b] - cumulative[a]) / (t[b] - t[a])[:, None]


def _bias_factor(gtsam: ModuleType, key_a: int, key_b: int, covariance: np.ndarray, rate_change: np.ndarray | None,
                 values: gtsam.Values) -> gtsam.NonlinearFactor:
    """The bias random walk from one IMU interval's bias ``B_a`` to the next's ``B_b``: ``B_b - B_a`` ~ N(0,
    ``covariance``) (6 x 6 diagonal; accelerometer [m/s^2], then gyro [rad/s], GTSAM's ``ConstantBias`` order).

    With scale-factor errors ``s`` (:data:`SCALE`; ``rate_change`` (6,) not None: the next interval's mean specific
    force [m/s^2] and rate [rad/s] minus this one's), a sensor measuring ``(1 + s) x`` adds ``diag(x) s`` to its
    bias; over an interval that is ``diag(mean rates) s``, and ``B_b - B_a - diag(rate_change) s`` is the random
    walk. Linear (a bias is a vector), so it is kept as a ``LinearContainerFactor`` at ``values`` (evaluated in
    C++) and is exact. The rates' variation inside an interval (a second) is neglected: a 30 deg/s change of rate
    within it with s = 0.002 moves the rotation by 0.001 deg."""
    noise = gtsam.noiseModel.Gaussian.Covariance(covariance)
    if rate_change is None:
        return gtsam.BetweenFactorConstantBias(key_a, key_b, gtsam.imuBias.ConstantBias(), noise)
    weight = 1.0 / np.sqrt(np.diag(covariance))[:, None]
    bias_a, bias_b = values.atConstantBias(key_a), values.atConstantBias(key_b)
    scale = values.atVector(SCALE)
    error = bias_b.vector() - bias_a.vector() - rate_change * scale
    linear = gtsam.JacobianFactor(key_a, -np.eye(6) * weight, key_b, np.eye(6) * weight, SCALE,
                                  -np.diag(rate_change) * weight, -error * weight[:, 0],
                                  gtsam.noiseModel.Unit.Create(6))
    return gtsam.LinearContainerFactor(linear, values)  # keeps the values of its own keys only


def _copy_value(target: gtsam.Values, source: gtsam.Values, key: int) -> None:
    """Copy variable ``key`` of ``source`` into ``target`` (gtsam.Values), by its symbol's type."""
    import gtsam

    kind = chr(gtsam.Symbol(key).chr())
    if kind == "x":
        target.insert(key, source.atPose3(key))
    elif kind == "b":
        target.insert(key, source.atConstantBias(key))
    elif kind == "l":
        target.insert(key, source.atPoint3(key))
    else:  # v, u, c: vectors
        target.insert(key, source.atVector(key))


def _preintegration_params(gtsam: ModuleType, noise: NoiseModel, gravity: float, omega: np.ndarray,
                           nav_scale: float) -> gtsam.PreintegrationParams:
    """GTSAM preintegration parameters with the noise model the EKF + RTS fitted (``noise``: white specific force
    [m^2/s^3] and angular rate [rad^2/s]) scaled by ``nav_scale``; plane gravity [m/s^2] down and the Earth rate
    ``omega`` [rad/s] in the plane. The bias random walk is a factor of its own (:func:`_bias_factor`)."""
    params = gtsam.PreintegrationParams.MakeSharedD(gravity)
    params.setAccelerometerCovariance(np.diag([noise.q_vel_h, noise.q_vel_h, noise.q_vel_v]) * nav_scale)
    params.setGyroscopeCovariance(np.diag([noise.q_att_h, noise.q_att_h, noise.q_att_v]) * nav_scale)
    params.setIntegrationCovariance(np.eye(3) * INTEGRATION_COVARIANCE)
    params.setOmegaCoriolis(omega)
    return params


def _bias_drive(noise: NoiseModel, bias_scale: float) -> np.ndarray:
    """Covariance rate (6, 6) of the bias random walk, accelerometer [m^2/s^5] then gyro [rad^2/s^3] (GTSAM's
    ``ConstantBias`` order), the EKF's fitted drives times ``bias_scale``."""
    return np.diag(np.repeat([max(noise.q_ba, 1e-12), max(noise.q_bg, 1e-16)], 3)) * bias_scale


def _process_noise_scale(rts: NavSolution, inputs: InsInputs) -> np.ndarray:
    """Per-row factors (N, 2) on the navigation noise and the bias drives of the interval ending at each row: the
    EKF's over IMU gaps (time gaps and a logger's linearly interpolated dropouts, found by
    :func:`georef.fusion.ins.imu_gaps` while ``solve_ins`` ran; the KITTI log has runs of 0.1-0.5 s). Preintegrating
    the interpolated samples with the sensor's own noise made the KITTI graph's IMU factors disagree with the
    RTS by up to 15 deg of yaw over one second and drift 30 m in the outages. The EKF's fitted factor inside GNSS
    outages (``outage_scale``) is not applied: on KITTI it made the outages worse (docs/method-graph.md, "The
    graph")."""
    return _gap_scale(rts.time, inputs.gaps, rts.diagnostics.noise)




def _noise_refit(lever: np.ndarray, applied: np.ndarray, cfg: GraphSettings) -> bool:
    """Whether the robust pass's GNSS lever arm ``lever`` [m, body] is far enough from the one the EKF + RTS
    ``applied`` to run them again with it: more than ``LEVER_REFIT_MIN`` and the configured horizontal fix sigma
    on some axis.

    The EKF fits its noise model, the GNSS variances above all, with the lever arm it applies, and the graph takes
    that model. With the lever arm not told (zero applied, 1.7 m true) a 10-minute PPK helicopter flight's
    fitted horizontal GNSS variance was 6.4 times the fixes' (1.04 with the true one): the graph, which estimates
    the lever arm itself, then weighted its fixes 2.5 times too loosely in sigma and claimed lever-arm sigmas
    1.4-1.9 times its errors (docs/method-graph.md, "Calibration, measured"). The EKF's own calibration pass is
    no substitute: on a 3-minute flight it put z at -1.00 +- 0.04 m against -1.65, moving in steps."""
    threshold = max(LEVER_REFIT_MIN, float(cfg.gnss.sigma[0]))
    return bool(np.any(np.abs(lever - applied) > threshold))


def _key_rows(t: np.ndarray, valid_rows: np.ndarray, fix_rows: np.ndarray) -> np.ndarray:
    """Keyframe rows: every fix's, about one a second where fixes are more than ``MAX_KEY_GAP`` apart, and the
    first and last rows that RTS solved, so that the graph covers every row it does. An end row closer than
    ``MIN_EDGE_GAP`` [s] to the nearest fix's keyframe is left out: two keyframes milliseconds apart make an IMU
    factor whose information (a tactical-grade gyro over 8 ms: 5e-7 rad) swamps the rest of the system and
    leaves it numerically indeterminate; rows beyond the last keyframe take its correction (``solve_graph_inputs``)."""
    rows = np.unique(fix_rows[(fix_rows >= valid_rows[0]) & (fix_rows <= valid_rows[-1])])
    first, last = valid_rows[0], valid_rows[-1]
    if not len(rows) or t[rows[0]] - t[first] > MIN_EDGE_GAP:
        rows = np.concatenate([[first], rows])
    if t[last] - t[rows[-1]] > MIN_EDGE_GAP:
        rows = np.concatenate([rows, [last]])
    return _fill_gaps(t, rows, MAX_KEY_GAP)


def _fill_gaps(t: np.ndarray, key_rows: np.ndarray, max_gap: float) -> np.ndarray:
    """Keyframe rows with extra rows about once a second wherever fixes are more than ``max_gap`` [s] apart."""
    extra = []
    for a, b in zip(key_rows[:-1], key_rows[1:], strict=True):
        span = t[b] - t[a]
        if span > max_gap:
            steps = int(np.ceil(span - 1e-9))
            extra.append(np.searchsorted(t, t[a] + span * np.arange(1, steps) / steps))
    return np.unique(np.concatenate([key_rows, *extra])) if extra else key_rows


def _unit_factor(gtsam: ModuleType, key_x: int, key_u: int, error: np.ndarray, H_rot: np.ndarray, sigma: np.ndarray,
                 at: gtsam.Values) -> gtsam.LinearContainerFactor:
    """The unit's roll, pitch, yaw [rad] at one keyframe: ``roll_u = roll + e_r``, ``pitch_u = pitch + e_p``,
    ``yaw_u = yaw - d``, with (roll, pitch, yaw) of ``C_b_n = C_t_n R`` and ``U = (e_r, e_p, d, d_dot)``,
    white noise ``sigma`` (3,) [rad] on roll, pitch, yaw.

    Linearised once, at the initial values ``at`` (of which the factor keeps its own two), and kept as a
    ``LinearContainerFactor``: GTSAM evaluates it in C++ at every iteration (a Python ``CustomFactor`` made each
    Levenberg-Marquardt iteration much slower, docs/performance.md, "Graph smoother"). The initial values are the
    RTS solution, which the graph moves by hundredths of a degree, so the Jacobian's change (second order in that
    move) is negligible: on the 15-minute benchmark flight the optimised graph error agrees with the
    CustomFactor's to 1e-8 relative.
    A body rotation ``xi`` in ``R Exp(xi)`` is the NED rotation ``C xi``, and ``euler_error_jacobian = E C^T``:
    ``error`` (3,) [rad] and ``H_rot = E C`` (3, 3) come vectorised over the keyframes from
    :func:`_unit_linearisation`.
    """
    H_x = np.hstack([H_rot, np.zeros((3, 3))])
    weight = 1.0 / sigma[:, None]
    linear = gtsam.JacobianFactor(key_x, H_x * weight, key_u, UNIT_H * weight, -error / sigma,
                                  gtsam.noiseModel.Unit.Create(3))
    return gtsam.LinearContainerFactor(linear, at)


def _nhc_factor(gtsam: ModuleType, key_x: int, key_v: int, pose: gtsam.Pose3, v_t: np.ndarray,
                sigma: np.ndarray) -> gtsam.LinearContainerFactor:
    """A ground vehicle's non-holonomic constraint at one keyframe: the body-frame lateral and vertical velocity
    ``(C_b_t^T v_t)_y,z`` [m/s] are zero, with sigmas ``sigma`` (2,) [m/s]; ``pose`` (``gtsam.Pose3``: body-to-plane
    rotation, plane position) and ``v_t`` (plane velocity [m/s]) are the linearisation point.

    Linearised once at the RTS solution and kept as a ``LinearContainerFactor`` (evaluated in C++; see
    :func:`_unit_factor`). With the body rotation ``R Exp(xi)``, ``v_b = R^T v`` moves by ``[v_b x] xi``
    (:func:`georef.frames.skew`); the Pose3 tangent is (rotation, translation) and the constraint does not depend
    on the translation; ``dv_b / dv_t = R^T``.
    """
    R = pose.rotation().matrix()
    v_b = R.T @ v_t
    H_x = np.hstack([skew(v_b)[1:], np.zeros((2, 3))]) / sigma[:, None]
    H_v = R.T[1:] / sigma[:, None]
    linear = gtsam.JacobianFactor(key_x, H_x, key_v, H_v, -v_b[1:] / sigma, gtsam.noiseModel.Unit.Create(2))
    at = gtsam.Values()
    at.insert(key_x, pose)
    at.insert(key_v, v_t)
    return gtsam.LinearContainerFactor(linear, at)


def _add_ground_vehicle(gtsam: ModuleType, X: Symbol, V: Symbol, rts: NavSolution, gyro: np.ndarray,
                        key_rows: np.ndarray, values: gtsam.Values,
                        factors_at: dict[int, list]) -> dict[int, np.ndarray]:
    """Non-holonomic factors (:func:`_nhc_factor`) at every keyframe when the EKF + RTS applied the constraint
    (``cfg.ins.vehicle = "ground"``, or ``"auto"`` and its ground-vehicle test passed), with its variances: the fitted
    ``r_nhc`` [m^2/s^2] plus, as the EKF, the IMU's motion about the point ``NHC_LEVER`` [m] away where the
    constraint holds (yaw rate for the lateral, pitch rate for the vertical; gyro minus the RTS gyro bias).
    Keyframes where the RTS solution itself violates the constraint beyond the EKF's gate (a skid) get none.
    Returns the sigmas [m/s] (2,) of the factors added, by keyframe."""
    if not rts.diagnostics.ground_vehicle:
        return {}
    r_nhc = rts.diagnostics.noise.r_nhc
    rate = gyro[key_rows] - rts.ins_info.gyro_bias[key_rows]
    sigma = np.sqrt(r_nhc + (NHC_LEVER * rate[:, [2, 1]]) ** 2)
    added = {}
    for k in range(len(key_rows)):
        pose, v_t = values.atPose3(X(k)), values.atVector(V(k))
        v_b = pose.rotation().matrix().T @ v_t
        if not np.all(np.isfinite(sigma[k])) or np.sum((v_b[1:] / sigma[k]) ** 2) > NHC_GATE:
            continue
        factors_at.setdefault(k, []).append(_nhc_factor(gtsam, X(k), V(k), pose, v_t, sigma[k]))
        added[k] = sigma[k]
    return added


def _relinearise_ground_vehicle(gtsam: ModuleType, X: Symbol, V: Symbol, graph: gtsam.NonlinearFactorGraph,
                                result: gtsam.Values, sigma: dict[int, np.ndarray]) -> gtsam.Values:
    """The non-holonomic factors of ``graph`` linearised again at the optimised ``result`` (replaced in place),
    and Levenberg-Marquardt run again from there. Where the graph turns the attitude far from the RTS (on KITTI
    up to 6.3 deg after a run of interpolated IMU samples) the first linearisation is off by up to 1.1 in a
    factor's error; once more moves positions by decimetres at most, for little time (docs/method-graph.md, "The
    graph")."""
    for index in range(graph.size()):
        factor = graph.at(index)
        if not isinstance(factor, gtsam.LinearContainerFactor):
            continue
        keys = list(factor.keys())
        if len(keys) != 2 or gtsam.Symbol(keys[1]).chr() != ord("v"):
            continue
        k = gtsam.Symbol(keys[0]).index()
        graph.replace(index, _nhc_factor(gtsam, X(k), V(k), result.atPose3(X(k)), result.atVector(V(k)), sigma[k]))
    return gtsam.LevenbergMarquardtOptimizer(graph, result, _lm_params(gtsam)).optimize()


def _unit_linearisation(C_t_n: np.ndarray, R: np.ndarray, u: np.ndarray,
                        z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The unit-attitude factors' errors (K, 3) [rad] and rotation Jacobians ``E C`` (K, 3, 3) at K keyframes:
    ``C = C_t_n R`` (plane-to-NED times the pose's rotation), ``u`` (K, 4) the unit variables, ``z`` (K, 3) the
    unit's roll, pitch, yaw [rad] (see :func:`_unit_factor`)."""
    C = C_t_n @ R
    roll, pitch, yaw = dcm_to_euler(C)
    errors = np.stack([roll + u[:, 0] - z[:, 0], pitch + u[:, 1] - z[:, 1], wrap_pi(yaw - u[:, 2] - z[:, 2])], -1)
    return errors, euler_error_jacobian(roll, pitch, yaw) @ C


DRIFT_PRIOR = np.radians(2.0) / 60.0  # rad/s, as the EKF without a recovered yaw offset
UNIT_H = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0]])


def _linear(gtsam: ModuleType, keys: list[int], blocks: list[np.ndarray], b: np.ndarray,
            zero: gtsam.Values) -> gtsam.LinearContainerFactor:
    """A linear Gaussian factor ``sum A_i x_i - b`` (whitened) on 4-vector variables, linearised at zero (``zero``
    holds a zero for each of ``keys``, and maybe for others)."""
    args = [item for key, A in zip(keys, blocks, strict=True) for item in (key, A)]
    factor = gtsam.JacobianFactor(*args, b, gtsam.noiseModel.Unit.Create(len(b)))
    return gtsam.LinearContainerFactor(factor, zero)


def _add_unit_attitude(gtsam: ModuleType, U: Symbol, X: Symbol, unit_rpy: np.ndarray, rts: NavSolution, t: np.ndarray,
                       key_rows: np.ndarray, C_n_t_rows: np.ndarray, noise: NoiseModel, values: gtsam.Values,
                       factors_at: dict[int, list]) -> None:
    """Unit-attitude variables ``U(k) = (e_r, e_p, d, d_dot)`` [rad, rad/s] and their factors (see the module),
    with the unit's error model the EKF + RTS fitted to this flight (``noise``: the level errors' Gauss-Markov
    drive and correlation time, the yaw origin's drift density, the white angle variances), not the configured
    one: the configuration is the EM's prior, and the data may say otherwise."""
    tau = noise.tau_unit
    level = float(np.sqrt(noise.q_unit_level * tau / 2.0))  # rad, the stationary sigma of q = 2 sigma^2 / tau
    q_drift = noise.q_unit_drift  # rad^2/s^3
    z = unit_rpy[key_rows]
    e_level = z[:, :2] - np.stack([rts.roll[key_rows], rts.pitch[key_rows]], -1)
    d = np.unwrap(wrap_pi(rts.yaw[key_rows] - z[:, 2]))
    tk = t[key_rows] - t[key_rows[0]]
    if len(tk) > 1:  # initial values on a straight line: the drift's random walk is slow
        d_dot, d_start = np.polyfit(tk, d, 1)
        d = d_start + d_dot * tk
    else:
        d_dot = 0.0
    u_values = np.column_stack([e_level, d, np.full(len(d), d_dot)])
    zero = gtsam.Values()
    for k in range(len(key_rows)):
        values.insert(U(k), u_values[k])
        zero.insert(U(k), np.zeros(4))
    R, _, _ = _keyframe_states(values, np.arange(len(key_rows)))
    errors, H_rot = _unit_linearisation(np.swapaxes(C_n_t_rows[key_rows], -1, -2), R, u_values, z)
    sigma = np.sqrt([noise.r_unit_level, noise.r_unit_level, noise.r_unit_yaw])
    for k in range(len(key_rows)):
        factors_at.setdefault(k, []).append(_unit_factor(gtsam, X(k), U(k), errors[k], H_rot[k], sigma, values))
    # priors at the first keyframe: the level errors' stationary Gauss-Markov sigma; the yaw origin is free (pi,
    # only to keep the first incremental update determinate), its drift within the EKF's default 2 deg/min
    prior_sigma = np.array([level, level, np.pi, DRIFT_PRIOR])
    factors_at[0].append(_linear(gtsam, [U(0)], [np.diag(1.0 / prior_sigma)],
                                 np.array([0.0, 0.0, d[0], 0.0]) / prior_sigma, zero))
    # between keyframes: U_k = A U_k-1 + w, w ~ N(0, Q), whitened by W = chol(Q)^-1, for all intervals at once
    dt = np.diff(tk)
    phi = np.exp(-dt / tau)
    A = np.zeros((len(dt), 4, 4))
    A[:, 0, 0] = A[:, 1, 1] = phi
    A[:, 2, 2] = A[:, 3, 3] = 1.0
    A[:, 2, 3] = dt
    Q = np.zeros((len(dt), 4, 4))
    Q[:, 0, 0] = Q[:, 1, 1] = level**2 * (1.0 - phi**2)
    Q[:, 2, 2] = q_drift * dt**3 / 3.0
    Q[:, 2, 3] = Q[:, 3, 2] = q_drift * dt**2 / 2.0
    Q[:, 3, 3] = q_drift * dt
    W = np.linalg.inv(np.linalg.cholesky(Q))
    W_A = -W @ A
    for k in range(1, len(key_rows)):
        factors_at.setdefault(k, []).append(_linear(gtsam, [U(k - 1), U(k)], [W_A[k - 1], W[k - 1]], np.zeros(4),
                                                    zero))
