"""``--method graph``: a GTSAM factor-graph smoother over GNSS keyframes.

* Frame: a local NED tangent plane at the flight's centre (GTSAM's navigation frame is Cartesian). Earth
  rotation enters through ``omegaCoriolis = ω_ie`` at the centre; gravity is the normal gravity at the centre
  along the plane's down axis. At a distance d from the centre the true vertical is tilted by d/R from the
  plane's down axis (0.16 mrad, 1.5 mg of horizontal gravity at 1 km): the graph absorbs it into the
  accelerometer bias and attitude; results are turned back into each point's own NED frame exactly.
* Keyframes at every GNSS fix (the first IMU row after it); IMU preintegration between them
  (``CombinedImuFactor``: pose, velocity and bias random walks); GNSS position factors through the antenna
  lever arm (``GPSFactorArm``) with a Cauchy robust kernel (k = 4 sigma) against outliers; priors from the EKF.
* Initial values from the EKF + RTS solution; batch Levenberg-Marquardt, or ISAM2 fed one keyframe at a time
  (``graph_solver = "isam2"``). Per-keyframe covariances from
  ``Marginals``; IMU-rate states are the RTS trajectory corrected by the graph-minus-RTS difference
  interpolated between keyframes.
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
)
from georef.fusion.ins import inputs_from_pos, noise_model, solve_ins
from georef.fusion.solution import NavSolution

CAUCHY_K = 4.0


def solve_graph(log, cfg: ProcessingConfig) -> NavSolution:
    import gtsam
    from gtsam.symbol_shorthand import B, V, X

    inputs = inputs_from_pos(log)
    rts = solve_ins(inputs, cfg, smooth=True)
    t = rts.time
    valid_rows = np.flatnonzero(rts.valid)
    gnss = log.gnss
    use = np.flatnonzero((gnss.time >= t[valid_rows[0]]) & (gnss.time <= t[valid_rows[-1]])
                         & (rts.gnss.status >= 0))
    key_rows = np.unique(np.searchsorted(t, gnss.time[use], side="left"))
    key_rows = key_rows[key_rows >= valid_rows[0]]
    # tangent plane at the centre of the flight
    centre = len(key_rows) // 2
    lat0, lon0, h0 = rts.lat[key_rows[centre]], rts.lon[key_rows[centre]], rts.height[key_rows[centre]]
    r0 = geodetic_to_ecef(lat0, lon0, h0)
    C_e_t = C_e_n(lat0, lon0)

    def to_plane(r_e: np.ndarray) -> np.ndarray:
        return (r_e - r0) @ C_e_t.T

    # rotation of each point's NED into the plane: C_n_t = C_e_t C_n_e(lat, lon)
    C_n_t_rows = C_e_t @ C_n_e(rts.lat, rts.lon)
    noise = noise_model(inputs, cfg)
    params = gtsam.PreintegrationCombinedParams.MakeSharedD(float(normal_gravity(lat0, h0)))
    params.setAccelerometerCovariance(np.eye(3) * noise.q_vel)
    params.setGyroscopeCovariance(np.eye(3) * noise.q_att)
    params.setIntegrationCovariance(np.eye(3) * 1e-8)
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
            np.concatenate([np.full(3, noise.sigma_ba0), np.full(3, noise.sigma_bg0)])))]
    gyro, accel = inputs.gyro, inputs.accel
    for k in range(1, len(key_rows)):
        a, b = key_rows[k - 1], key_rows[k]
        pim = gtsam.PreintegratedCombinedMeasurements(params, values.atConstantBias(B(k - 1)))
        for r in range(a, b):
            dt = t[r + 1] - t[r]
            pim.integrateMeasurement(0.5 * (accel[r] + accel[r + 1]), 0.5 * (gyro[r] + gyro[r + 1]), dt)
        factors_at.setdefault(k, []).append(gtsam.CombinedImuFactor(X(k - 1), V(k - 1), X(k), V(k), B(k - 1), B(k),
                                                                    pim))
    # GNSS antenna fixes, moved to the keyframe row's time along the velocity
    sigma = np.asarray(cfg.gnss_sigma)
    base = gtsam.noiseModel.Diagonal.Sigmas(sigma)
    robust = (gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Cauchy.Create(CAUCHY_K), base)
              if cfg.graph_robust else base)
    fix_of_key = {}
    for index in use:
        row = int(np.searchsorted(t, gnss.time[index], side="left"))
        k = int(np.searchsorted(key_rows, row))
        if k >= len(key_rows) or key_rows[k] != row or k in fix_of_key:
            continue
        fix_of_key[k] = index
        r_ant = geodetic_to_ecef(np.radians(gnss.lat_deg[index]), np.radians(gnss.lon_deg[index]), gnss.height[index])
        z = to_plane(r_ant) + v_t[row] * (t[row] - gnss.time[index])
        factors_at.setdefault(k, []).append(gtsam.GPSFactorArm(X(k), z, np.asarray(cfg.lever_arm_gnss, float),
                                                               robust))
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
            isam.update(new_graph, new_values)
        isam.update()
        result = isam.calculateEstimate()
    else:
        result = gtsam.LevenbergMarquardtOptimizer(graph, values, gtsam.LevenbergMarquardtParams()).optimize()
    marginals = gtsam.Marginals(graph, result)

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
    inside = (rows >= key_rows[0]) & (rows <= key_rows[-1])
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
    valid = inside & rts.valid
    for array in (r_e, v_e, pos_var_rows, att_sigma):
        array[~valid] = np.nan
    info = dict(rts.info)
    info.update({"keyframes": n_keys, "graph_error_initial": graph.error(values),
                 "graph_error_final": graph.error(result)})
    return NavSolution(method="graph", time=t, r_e=r_e, v_e=v_e, lat=lat, lon=lon, height=height, roll=roll,
                       pitch=pitch, yaw=yaw, pos_var_n=pos_var_rows, att_sigma=att_sigma, valid=valid, gnss=rts.gnss,
                       info=info, att_cov_n=att_cov_rows)
