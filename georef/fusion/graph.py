"""``--method graph``: a GTSAM factor-graph smoother over GNSS keyframes.

* Frame: a local NED tangent plane at the flight's centre (GTSAM's navigation frame is Cartesian). Earth
  rotation enters through ``omegaCoriolis = ω_ie`` at the centre; GTSAM's gravity is the normal gravity at the
  centre along the plane's down axis, and each accelerometer row is compensated by ``C_t_b (g_t - g_plane)``
  (its own normal gravity, along its own vertical, in the plane), so the d/R tilt of the vertical (0.16 mrad at
  1 km) is modelled, not absorbed. Results are turned back into each point's own NED frame exactly.
* Keyframes at every GNSS fix (the first IMU row after it) and, where fixes are more than 1.5 s apart, about
  once a second; IMU preintegration between them (``CombinedImuFactor``: pose, velocity and bias random walks)
  of per-step rates carrying the strapdown's rotation, sculling and coning corrections
  (:mod:`georef.fusion.increments`); GNSS position factors through the antenna lever arm (``GPSFactorArmCalib``)
  with a Cauchy robust kernel (k = 4 sigma) against outliers, then a Gaussian refit on the fixes whose whitened
  residual stays within ``cfg.gate_chi2`` (:func:`_refit_on_inliers`); loose priors at the first keyframe.
* The POS unit's own attitude (``cfg.unit_aiding`` and ROLL/PITCH/YAW in the log), the same model as the EKF:
  a variable ``U = (e_r, e_p, d, d_dot)`` [rad, rad, rad, rad/s] per keyframe; a factor
  ``(roll + e_r, pitch + e_p, yaw - d) - (roll_u, pitch_u, yaw_u)`` with white sigma ``unit_angle_noise``
  (linearised at the RTS solution and kept as a ``LinearContainerFactor``, evaluated in C++); between
  keyframes a linear factor for the Gauss-Markov level errors (``e_k = exp(-dt/tau) e_k-1``, variance
  ``sigma^2 (1 - exp(-2 dt/tau))``) and the yaw origin with its random-walk drift (``unit_drift_change``).
* Initial values from the EKF + RTS solution; batch Levenberg-Marquardt, or ISAM2 fed one keyframe at a time
  (``graph_solver = "isam2"``). Per-keyframe covariances from a QR elimination (:class:`_QrMarginals`); IMU-rate
  states are the RTS trajectory corrected by the graph-minus-RTS difference interpolated between keyframes.
"""
from __future__ import annotations

import numpy as np

from georef.config import ProcessingConfig
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
from georef.frames.rotations import (
    dcm_to_quat,
    euler_error_jacobian,
    quat_multiply,
    quat_to_dcm,
    quat_to_rotvec,
    rotvec_to_quat,
    wrap_pi,
)
from georef.fusion.increments import compensated_rates
from georef.fusion.ins import InsInputs, inputs_from_pos, solve_ins, unit_drift_psd
from georef.fusion.solution import NavSolution

CAUCHY_K = 4.0
MAX_KEY_GAP = 1.5  # s; longer gaps between fixes get keyframes about once a second
#: [m^2/s] position integration noise of the preintegration. GTSAM's examples use 1e-8; with a tactical-grade gyro
#: (ARW 0.02 deg/sqrt(h)) over a 20-s flight the IMU factors then reached 1.8e7 in the whitened Jacobian against
#: 0.045 for the loosest direction (the position before the first fix), and the marginals' Cholesky failed
#: ("indeterminate system"). 1e-6 (1 mm over a second between keyframes, against metre-level GNSS) keeps the
#: system solvable and moves no position by more than a millimetre on the bundled flight.
INTEGRATION_COVARIANCE = 1e-6
MIN_EDGE_GAP = 0.5  # s; the first/last solved row gets its own keyframe when it is farther than this from a fix


def solve_graph(log, cfg: ProcessingConfig) -> NavSolution:
    """Graph smoother on a POS log (body-frame OMGS deg/s, ACCS m/s^2, GNSS antenna fixes, optionally the unit's
    ROLL/PITCH/YAW deg): :func:`solve_graph_inputs` on :func:`georef.fusion.ins.inputs_from_pos`."""
    return solve_graph_inputs(inputs_from_pos(log), cfg)


def solve_graph_inputs(inputs: InsInputs, cfg: ProcessingConfig) -> NavSolution:
    """Graph smoother on INS inputs (a POS log's or ``georef fuse``'s imu.csv and gnss.csv). Returns a
    :class:`NavSolution` at every IMU row that the EKF + RTS solves: ECEF position [m] and velocity [m/s], geodetic
    lat/lon [rad] and height [m], body-to-NED roll/pitch/yaw [rad], NED position variances [m^2], NED
    attitude-error covariance [rad^2] and Euler sigmas [rad]."""
    import gtsam
    from gtsam.symbol_shorthand import B, U, V, X

    rts = solve_ins(inputs, cfg, smooth=True)
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

    def to_plane(r_e: np.ndarray) -> np.ndarray:
        return (r_e - r0) @ C_e_t.T

    # rotation of each point's NED into the plane: C_n_t = C_e_t C_n_e(lat, lon)
    C_n_t_rows = C_e_t @ C_n_e(rts.lat, rts.lon)
    # the noise model the EKF + RTS fitted to this flight's data
    noise = rts.diagnostics.noise
    params = gtsam.PreintegrationCombinedParams.MakeSharedD(float(normal_gravity(lat0, h0)))
    params.setAccelerometerCovariance(np.diag([noise.q_vel_h, noise.q_vel_h, noise.q_vel_v]))
    params.setGyroscopeCovariance(np.diag([noise.q_att_h, noise.q_att_h, noise.q_att_v]))
    params.setIntegrationCovariance(np.eye(3) * INTEGRATION_COVARIANCE)
    params.setBiasAccCovariance(np.eye(3) * max(noise.q_ba, 1e-12))
    params.setBiasOmegaCovariance(np.eye(3) * max(noise.q_bg, 1e-16))
    params.setOmegaCoriolis(C_e_t @ C_n_e(lat0, lon0) @ earth_rate_n(lat0))

    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    factors_at: dict[int, list] = {}
    C_b_t = C_n_t_rows @ euler_to_dcm(rts.roll, rts.pitch, rts.yaw)
    p_t = to_plane(rts.r_e)
    v_t = rts.v_e @ C_e_t.T  # ECEF velocity into the tangent plane
    gyro_bias, accel_bias = rts.info["gyro_bias"], rts.info["accel_bias"]
    for k, row in enumerate(key_rows):
        values.insert(X(k), gtsam.Pose3(gtsam.Rot3(C_b_t[row]), p_t[row]))
        values.insert(V(k), v_t[row])
        values.insert(B(k), gtsam.imuBias.ConstantBias(accel_bias[row], gyro_bias[row]))
    first = key_rows[0]
    pos_sigma = np.sqrt(rts.pos_var_n[first]) * 3.0
    factors_at[0] = [
        gtsam.PriorFactorPose3(X(0), values.atPose3(X(0)), gtsam.noiseModel.Diagonal.Sigmas(
            np.concatenate([np.full(3, np.radians(1.0)), pos_sigma]))),
        gtsam.PriorFactorVector(V(0), v_t[first], gtsam.noiseModel.Isotropic.Sigma(3, 0.5)),
        gtsam.PriorFactorConstantBias(B(0), values.atConstantBias(B(0)), gtsam.noiseModel.Diagonal.Sigmas(
            np.sqrt(np.concatenate([np.diag(rts.diagnostics.alignment.covariance)[12:15],
                                    np.diag(rts.diagnostics.alignment.covariance)[9:12]])) * 3.0))]
    gyro = inputs.gyro
    # each row's own normal gravity, turned into the plane: f' = f + C_t_b (g_t - g_plane) makes GTSAM's constant
    # plane gravity exact (the local vertical is tilted by d/R from the plane's down axis)
    g_t = C_n_t_rows[:, :, 2] * normal_gravity(rts.lat, rts.height)[:, None]
    g_fix = np.einsum("nji,nj->ni", C_b_t, g_t - np.array([0.0, 0.0, float(normal_gravity(lat0, h0))]))
    accel = inputs.accel + np.where(np.isfinite(g_fix), g_fix, 0.0)
    # per-interval rates with the strapdown's rotation, sculling and coning corrections: GTSAM holds the attitude
    # at the start of each step (georef.fusion.increments; without them the graph lost 3-7 % to rts)
    accel_step, gyro_step = compensated_rates(t, gyro, accel, gyro_bias, accel_bias)
    for k in range(1, len(key_rows)):
        a, b = key_rows[k - 1], key_rows[k]
        pim = gtsam.PreintegratedCombinedMeasurements(params, values.atConstantBias(B(k - 1)))
        for r in range(a, b):
            pim.integrateMeasurement(accel_step[r], gyro_step[r], t[r + 1] - t[r])
        factors_at.setdefault(k, []).append(gtsam.CombinedImuFactor(X(k - 1), V(k - 1), X(k), V(k), B(k - 1), B(k),
                                                                    pim))
    # GNSS antenna fixes, moved to the keyframe row's time along the velocity, with the sigmas the EKF + RTS
    # fitted to this flight (the configured ones scaled by the fitted variance factors)
    sigma = np.asarray(cfg.gnss_sigma) * np.sqrt([noise.r_scale_h, noise.r_scale_h, noise.r_scale_v])
    base = gtsam.noiseModel.Diagonal.Sigmas(sigma)
    # the GNSS lever arm [m, body] as a variable, estimated jointly with the trajectory
    lever_key = gtsam.symbol("l", 0)
    lever_given = np.asarray(cfg.lever_arm_gnss, float)
    lever_prior = _lever_arm_prior_sigma(cfg)
    calibration = rts.diagnostics.calibration
    values.insert(lever_key, np.asarray(calibration.lever_arm if calibration is not None else lever_given, float))
    factors_at[0].append(gtsam.PriorFactorPoint3(lever_key, lever_given,
                                                 gtsam.noiseModel.Isotropic.Sigma(3, lever_prior)))
    robust = (gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Cauchy.Create(CAUCHY_K), base)
              if cfg.graph_robust else base)
    fix_of_key = {}
    gnss_factors: list[tuple] = []  # (factor in the graph, its Gaussian twin) per fix
    for index in use:
        row = int(np.searchsorted(t, gnss.time[index], side="left"))
        k = int(np.searchsorted(key_rows, row))
        if k >= len(key_rows) or key_rows[k] != row or k in fix_of_key:
            continue
        fix_of_key[k] = index
        r_ant = geodetic_to_ecef(np.radians(gnss.lat_deg[index]), np.radians(gnss.lon_deg[index]), gnss.height[index])
        z = to_plane(r_ant) + v_t[row] * (t[row] - gnss.time[index])
        factors_at.setdefault(k, []).append(gtsam.GPSFactorArmCalib(X(k), lever_key, z, robust))
        gnss_factors.append((factors_at[k][-1], gtsam.GPSFactorArmCalib(X(k), lever_key, z, base)))
    aiding = bool(cfg.unit_aiding and inputs.unit_rpy is not None)
    if aiding:
        _add_unit_attitude(gtsam, U, X, inputs.unit_rpy, rts, t, key_rows, C_n_t_rows, cfg, values, factors_at)
    for k in range(len(key_rows)):
        for factor in factors_at.get(k, []):
            graph.add(factor)
    if cfg.graph_solver == "isam2":
        # incremental: one keyframe (its IMU and GNSS factors) per update, as a real-time user would
        isam = gtsam.ISAM2(gtsam.ISAM2Params())
        for k in range(len(key_rows)):
            new_graph = gtsam.NonlinearFactorGraph()
            for factor in factors_at.get(k, []):
                new_graph.add(factor)
            new_values = gtsam.Values()
            new_values.insert(X(k), values.atPose3(X(k)))
            new_values.insert(V(k), values.atVector(V(k)))
            new_values.insert(B(k), values.atConstantBias(B(k)))
            if aiding:
                new_values.insert(U(k), values.atVector(U(k)))
            if k == 0:
                new_values.insert(lever_key, values.atPoint3(lever_key))
            isam.update(new_graph, new_values)
        isam.update()
        result = isam.calculateEstimate()
    else:
        result = gtsam.LevenbergMarquardtOptimizer(graph, values, gtsam.LevenbergMarquardtParams()).optimize()
    rejected = 0
    if cfg.graph_robust:
        graph, result, rejected = _refit_on_inliers(
            gtsam, [f for k in range(len(key_rows)) for f in factors_at.get(k, [])], gnss_factors, result,
            cfg.gate_chi2)
    marginals = _QrMarginals(gtsam, graph, result)

    # graph minus RTS at the keyframes, interpolated to every row
    n_keys = len(key_rows)
    d_pos = np.empty((n_keys, 3))
    d_vel = np.empty((n_keys, 3))
    d_rot = np.empty((n_keys, 3))
    pos_var = np.empty((n_keys, 3))
    att_cov = np.empty((n_keys, 3, 3))
    for k, row in enumerate(key_rows):
        pose = result.atPose3(X(k))
        R = pose.rotation().matrix()
        d_pos[k] = pose.translation() - p_t[row]
        d_vel[k] = result.atVector(V(k)) - v_t[row]
        d_rot[k] = quat_to_rotvec(dcm_to_quat(R @ C_b_t[row].T))  # plane-frame rotation
        cov = marginals.marginalCovariance(X(k))
        C_t_n = C_n_t_rows[row].T
        pos_cov_n = C_t_n @ R @ cov[3:, 3:] @ R.T @ C_t_n.T
        pos_var[k] = np.diag(pos_cov_n)
        att_cov[k] = C_t_n @ R @ cov[:3, :3] @ R.T @ C_t_n.T
    rows = np.arange(len(t))
    interp = lambda data: np.stack([np.interp(rows, key_rows, data[:, j]) for j in range(data.shape[1])], -1)  # noqa: E731
    p_new = p_t + interp(d_pos)
    v_new = v_t + interp(d_vel)
    rot = rotvec_to_quat(interp(d_rot))
    C_b_t_new = quat_to_dcm(quat_multiply(rot, dcm_to_quat(C_b_t)))
    r_e = r0 + p_new @ C_e_t
    lat, lon, height = ecef_to_geodetic(r_e)
    C_b_n_new = np.swapaxes(C_e_t @ C_n_e(lat, lon), -1, -2) @ C_b_t_new
    roll, pitch, yaw = dcm_to_euler(C_b_n_new)
    v_e = v_new @ C_e_t
    pos_var_rows = interp(pos_var)
    att_cov_rows = interp(att_cov.reshape(n_keys, 9)).reshape(-1, 3, 3)
    J = euler_error_jacobian(roll, pitch, yaw)
    att_sigma = np.sqrt(np.einsum("nij,njk,nik->ni", J, att_cov_rows, J))
    valid = rts.valid.copy()  # rows beyond the end keyframes (< MIN_EDGE_GAP) take the end keyframes' corrections
    for array in (r_e, v_e, pos_var_rows, att_sigma):
        array[~valid] = np.nan
    info = dict(rts.info)
    # the graph against the RTS it started from, in units of the graph's own horizontal sigma at each keyframe:
    # both smoothers carry the same information, so a separation of several sigma means one of them went wrong
    separation = np.hypot(d_pos[:, 0], d_pos[:, 1]) / np.sqrt(pos_var[:, 0] + pos_var[:, 1])
    # and the attitude: the graph-minus-RTS rotation in each keyframe's NED frame, per axis in units of the graph's
    # own sigma of that axis, the largest of the three
    d_rot_n = np.einsum("kji,kj->ki", C_n_t_rows[key_rows], d_rot)
    attitude_separation = np.max(np.abs(d_rot_n) / np.sqrt(np.diagonal(att_cov, axis1=1, axis2=2)), axis=1)
    info.update({"graph_lever_arm_m": np.asarray(result.atPoint3(lever_key), float),
                 "graph_lever_arm_sigma_m": np.sqrt(np.diag(marginals.marginalCovariance(lever_key))),
                 "graph_lever_arm_prior_sigma_m": lever_prior,
                 "graph_rts_separation_sigma": separation,
                 "graph_rts_attitude_separation_sigma": attitude_separation, "keyframes": n_keys,
                 "graph_rejected_fixes": rejected,
                 "graph_error_initial": graph.error(values), "graph_error_final": graph.error(result)})
    return NavSolution(method="graph", time=t, r_e=r_e, v_e=v_e, lat=lat, lon=lon, height=height, roll=roll,
                       pitch=pitch, yaw=yaw, pos_var_n=pos_var_rows, att_sigma=att_sigma, valid=valid, gnss=rts.gnss,
                       info=info, att_cov_n=att_cov_rows, diagnostics=rts.diagnostics)


class _QrMarginals:
    """Marginal covariances of a solved graph, from a multifrontal QR elimination of the graph linearised at
    ``result`` (COLAMD ordering), in the same tangent-space convention as ``gtsam.Marginals``.

    ``gtsam.Marginals`` eliminates the Hessian with Cholesky, which squares the Jacobian's condition number. The
    graph's variables span ten decades of information (a tactical gyro's bias between keyframes a second apart:
    1e10 rad^-2 s^2, a position before the first fix: 1), and on a 20-s tactical car (condition number of the
    Jacobian 7e5, of the Hessian 6e11, positive definite: numpy's Cholesky of the dense Hessian succeeds)
    GTSAM's Cholesky met a non-positive pivot with COLAMD's frontal blocks ("indeterminate system", exit 3).
    QR works on the whitened Jacobian itself; on a 60-s helicopter flight its covariances equal
    ``gtsam.Marginals``' to 4e-5 relative."""

    def __init__(self, gtsam, graph, result):
        self._gtsam = gtsam
        linear = graph.linearize(result)
        self._tree = linear.eliminateMultifrontal(gtsam.Ordering.ColamdGaussianFactorGraph(linear), gtsam.EliminateQR)

    def marginalCovariance(self, key: int) -> np.ndarray:  # noqa: N802 (gtsam.Marginals' name)
        return np.linalg.inv(self._tree.marginalFactor(key, self._gtsam.EliminateQR).information())


def _refit_on_inliers(gtsam, factors: list, gnss_factors: list[tuple], result, threshold: float):
    """After the robust (Cauchy) solve, drop the fixes whose whitened residual at ``result`` exceeds
    ``threshold`` (the squared Mahalanobis distance of the 3-D antenna residual, with the fix's own sigmas) and
    solve again with a plain Gaussian model on the others, starting from ``result``.

    Why: the Cauchy kernel weights every fix by ``1 / (1 + r^2 / k^2)``, good ones too (the posterior north
    sigma of a 3-minute flight grew from 0.193 to 0.205 m), so the robust solution is less accurate than the
    Gaussian one on the same inliers. The threshold is the EKF's gate ``cfg.gate_chi2`` (default 16.27, chi-square
    with 3 degrees of freedom at 99.9 %): a smoothed residual's covariance is smaller than the fix's own, so an
    inlier passes with at least that probability and the graph rejects no more good fixes than the filter does.
    ``factors`` are all the graph's factors, ``gnss_factors`` pairs of (robust GNSS factor among them, its
    Gaussian twin). Returns the new graph (the robust GNSS factors replaced by the inliers' Gaussian twins), its
    solution and the number of fixes dropped."""
    robust = {id(factor) for factor, _ in gnss_factors}
    inliers = []
    for _, plain in gnss_factors:
        e = plain.whitenedError(result)
        if float(e @ e) <= threshold:
            inliers.append(plain)
    refit = gtsam.NonlinearFactorGraph()
    for factor in factors:
        if id(factor) not in robust:
            refit.add(factor)
    for factor in inliers:
        refit.add(factor)
    solution = gtsam.LevenbergMarquardtOptimizer(refit, result, gtsam.LevenbergMarquardtParams()).optimize()
    return refit, solution, len(gnss_factors) - len(inliers)


LEVER_ARM_GIVEN_SIGMA = 0.05  # m, a lever arm taped on the installation
LEVER_ARM_FREE_SIGMA = 10.0  # m, no lever arm given: only keeps the variable determinate


def _lever_arm_prior_sigma(cfg: ProcessingConfig) -> float:
    """1-sigma [m] of the prior on the graph's lever-arm variable (``cfg.lever_arm_gnss_sigma``, else 0.05 m for
    a given lever arm and a free estimate without one)."""
    if cfg.lever_arm_gnss_sigma is not None:
        return float(cfg.lever_arm_gnss_sigma)
    return LEVER_ARM_GIVEN_SIGMA if any(v != 0.0 for v in cfg.lever_arm_gnss) else LEVER_ARM_FREE_SIGMA


def _key_rows(t: np.ndarray, valid_rows: np.ndarray, fix_rows: np.ndarray) -> np.ndarray:
    """Keyframe rows: every fix's, about one a second where fixes are more than ``MAX_KEY_GAP`` apart, and the
    first and last rows that RTS solved, so that the graph covers every row it does. An end row closer than
    ``MIN_EDGE_GAP`` [s] to the nearest fix's keyframe is left out: two keyframes milliseconds apart make an IMU
    factor whose information (a tactical-grade gyro over 8 ms: 5e-7 rad) swamps the rest of the system and
    leaves it numerically indeterminate; rows beyond the last keyframe take its correction (``_solve``)."""
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


def _unit_factor(gtsam, key_x: int, key_u: int, z: np.ndarray, C_t_n: np.ndarray, pose, u: np.ndarray,
                 sigma: float):
    """The unit's roll, pitch, yaw [rad] at one keyframe: ``roll_u = roll + e_r``, ``pitch_u = pitch + e_p``,
    ``yaw_u = yaw - d``, with (roll, pitch, yaw) of ``C_b_n = C_t_n R`` and ``U = (e_r, e_p, d, d_dot)``,
    white noise ``sigma`` [rad].

    Linearised once, at the initial values ``pose`` (a ``gtsam.Pose3``) and ``u``, and kept as a
    ``LinearContainerFactor``: GTSAM evaluates it in C++ at every iteration (a Python ``CustomFactor`` made each
    Levenberg-Marquardt iteration about 30x slower). The initial values are the RTS solution, which the graph
    moves by hundredths of a degree, so the Jacobian's change (second order in that move) is negligible: on the
    15-minute benchmark flight the optimised graph error agrees with the CustomFactor's to 1e-8 relative.
    A body rotation ``xi`` in ``R Exp(xi)`` is the NED rotation ``C xi``, and ``euler_error_jacobian = E C^T``.
    """
    C = C_t_n @ pose.rotation().matrix()
    roll, pitch, yaw = dcm_to_euler(C)
    e = np.array([roll + u[0] - z[0], pitch + u[1] - z[1], wrap_pi(yaw - u[2] - z[2])])
    H_x = np.hstack([euler_error_jacobian(roll, pitch, yaw) @ C, np.zeros((3, 3))])
    linear = gtsam.JacobianFactor(key_x, H_x / sigma, key_u, UNIT_H / sigma, -e / sigma,
                                  gtsam.noiseModel.Unit.Create(3))
    at = gtsam.Values()
    at.insert(key_x, pose)
    at.insert(key_u, u)
    return gtsam.LinearContainerFactor(linear, at)


DRIFT_PRIOR = np.radians(2.0) / 60.0  # rad/s, as the EKF without a recovered yaw offset
UNIT_H = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0]])


def _linear(gtsam, keys: list[int], blocks: list[np.ndarray], b: np.ndarray):
    """A linear Gaussian factor ``sum A_i x_i - b`` (whitened) on 4-vector variables, linearised at zero."""
    args = [item for key, A in zip(keys, blocks, strict=True) for item in (key, A)]
    factor = gtsam.JacobianFactor(*args, b, gtsam.noiseModel.Unit.Create(len(b)))
    zero = gtsam.Values()
    for key in keys:
        zero.insert(key, np.zeros(4))
    return gtsam.LinearContainerFactor(factor, zero)


def _add_unit_attitude(gtsam, U, X, unit_rpy, rts, t, key_rows, C_n_t_rows, cfg, values, factors_at) -> None:
    """Unit-attitude variables ``U(k) = (e_r, e_p, d, d_dot)`` [rad, rad/s] and their factors (see the module)."""
    level = np.radians(cfg.unit_level_sigma)
    tau = cfg.unit_level_time
    q_drift = unit_drift_psd(cfg)  # rad^2/s^3, as the EKF
    z = unit_rpy[key_rows]
    e_level = z[:, :2] - np.stack([rts.roll[key_rows], rts.pitch[key_rows]], -1)
    d = np.unwrap(wrap_pi(rts.yaw[key_rows] - z[:, 2]))
    tk = t[key_rows] - t[key_rows[0]]
    if len(tk) > 1:  # initial values on a straight line: the drift's random walk is slow
        d_dot, d_start = np.polyfit(tk, d, 1)
        d = d_start + d_dot * tk
    else:
        d_dot = 0.0
    for k in range(len(key_rows)):
        values.insert(U(k), np.array([e_level[k, 0], e_level[k, 1], d[k], d_dot]))
    for k, row in enumerate(key_rows):
        factors_at.setdefault(k, []).append(_unit_factor(gtsam, X(k), U(k), z[k], C_n_t_rows[row].T,
                                                         values.atPose3(X(k)), values.atVector(U(k)),
                                                         np.radians(cfg.unit_angle_noise)))
    # priors at the first keyframe: the level errors' stationary Gauss-Markov sigma; the yaw origin is free (pi,
    # only to keep the first incremental update determinate), its drift within the EKF's default 2 deg/min
    prior_sigma = np.array([level, level, np.pi, DRIFT_PRIOR])
    factors_at[0].append(_linear(gtsam, [U(0)], [np.diag(1.0 / prior_sigma)],
                                 np.array([0.0, 0.0, d[0], 0.0]) / prior_sigma))
    for k in range(1, len(key_rows)):
        dt = tk[k] - tk[k - 1]
        phi = np.exp(-dt / tau)
        A = np.zeros((4, 4))
        A[:2, :2] = np.eye(2) * phi
        A[2:, 2:] = [[1.0, dt], [0.0, 1.0]]
        Q = np.zeros((4, 4))
        Q[:2, :2] = np.eye(2) * level**2 * (1.0 - phi**2)
        Q[2:, 2:] = q_drift * np.array([[dt**3 / 3.0, dt**2 / 2.0], [dt**2 / 2.0, dt]])
        W = np.linalg.inv(np.linalg.cholesky(Q))  # whitening: W (U_k - A U_k-1)
        factors_at.setdefault(k, []).append(_linear(gtsam, [U(k - 1), U(k)], [-W @ A, W], np.zeros(4)))
