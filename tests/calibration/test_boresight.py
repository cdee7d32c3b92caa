"""Boresight / camera lever-arm calibration (docs/boresight.md): conventions, readers, the estimate, the CLI.

The simulated blocks are flights of georef.sim processed by georef with a wrong boresight and lever arm; the
"adjusted" cameras are the simulator's true camera poses plus adjustment noise (georef.sim.adjusted_block). The
benchmark (benchmarks/boresight_recovery.py) runs 20 of them; here 3 blocks with the same assertions.
"""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats
from typer.testing import CliRunner

from georef.calibration.boresight import (
    MIN_PHOTOS,
    CalibrationInputError,
    MatchedPhotos,
    calibrate,
    match_photos,
    split_strips,
)
from georef.config import load_config, load_configs
from georef.frames import dcm_to_euler, euler_to_dcm
from georef.frames.calibration import (
    accel_bias_body_tilt,
    accel_bias_tilt_covariance_camera,
    boresight_angle_jacobian,
    camera_rotation_residual,
    corrected_boresight,
    grid_offset_to_ned,
    image_to_ned,
    opensfm_to_image_map,
)
from georef.frames.photogrammetry import image_to_map, opk_to_rotation, rotation_to_opk
from georef.frames.rotations import rotvec_to_dcm
from georef.io.adjusted_cameras import read_adjusted_cameras
from georef.io.eo_table import write_eo_csv
from georef.io.errors import InputError
from georef.io.process_summary import ProcessFigures, figures_of_summary, read_process_summary
from georef.sim.adjusted_block import (
    BLOCK_CRS,
    accel_bias_tilt_deg,
    adjusted_cameras,
    body_fixed_tilt_deg,
    simulate_block,
    write_adjusted,
)

RNG = np.random.default_rng(5)


# ---------------------------------------------------------------- conventions (georef/frames/calibration.py)

def test_rotation_residual_is_the_camera_frame_rotation():
    C = euler_to_dcm(0.1, -0.05, 2.0)
    rho = np.radians([0.3, -0.2, 0.5])
    assert np.allclose(camera_rotation_residual(C, C @ rotvec_to_dcm(rho)), rho, atol=1e-12)
    # a NED-frame error eps is C_n_c eps in the camera frame, to first order
    eps = np.radians([0.01, 0.02, -0.03])
    assert np.allclose(camera_rotation_residual(C, rotvec_to_dcm(eps) @ C), C.T @ eps, atol=1e-8)


def test_image_to_ned_inverts_image_to_map():
    C_c_n = euler_to_dcm(RNG.normal(0, 0.1, 20), RNG.normal(0, 0.1, 20), RNG.uniform(-np.pi, np.pi, 20))
    gamma = RNG.uniform(-2, 2, 20)
    assert np.allclose(image_to_ned(image_to_map(C_c_n, gamma), gamma), C_c_n, atol=1e-12)


def test_opensfm_rotation_of_nadir_cameras():
    """OpenSfM doc/source/geometry.rst (mapillary/OpenSfM 054a1d8): x_cam = R X_world + t, camera x right, y down,
    z forward; ODM opendm/shots.py (OpenDroneMap/ODM 32cfaac) writes R as an angle-axis vector and the centre
    -R^T t in grid E, N, up. A nadir camera heading north sees east on its right and south at its image bottom."""
    R_north = np.diag([1.0, -1.0, -1.0])            # rows: x_o = E, y_o = S, z_o = down
    rotation = np.array([np.pi, 0.0, 0.0])           # angle-axis of R_north
    assert np.allclose(rotvec_to_dcm(rotation), R_north, atol=1e-12)
    roll, pitch, yaw = dcm_to_euler(image_to_ned(opensfm_to_image_map(rotation), 0.0))
    assert np.allclose(np.degrees([roll, pitch, yaw]), 0.0, atol=1e-9)
    # heading east: right = south, image bottom = west
    R_east = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    from georef.frames.rotations import dcm_to_quat, quat_to_rotvec

    roll, pitch, yaw = dcm_to_euler(image_to_ned(opensfm_to_image_map(quat_to_rotvec(dcm_to_quat(R_east))), 0.0))
    assert np.allclose(np.degrees([roll, pitch]), 0.0, atol=1e-9) and np.isclose(np.degrees(yaw), 90.0)
    # a grid 1.5 deg east of true north (convergence 1.5): the same grid-north camera heads 1.5 deg true
    _, _, yaw = dcm_to_euler(image_to_ned(opensfm_to_image_map(rotation), 1.5))
    assert np.isclose(np.degrees(yaw), 1.5)


def test_grid_offsets_to_ned_use_convergence_and_scale():
    # one grid metre north, grid north 2 deg east of true north, scale 0.9996
    d = grid_offset_to_ned(0.0, 1.0, 0.5, 2.0, 0.9996)
    assert np.allclose(d, [np.cos(np.radians(2)) / 0.9996, np.sin(np.radians(2)) / 0.9996, -0.5])


def test_corrected_boresight_and_its_jacobian():
    boresight = np.radians([0.35, -0.6, 1.2])
    b = np.radians([0.2, 0.1, -0.3])
    new = corrected_boresight(boresight, b)
    C = euler_to_dcm(*boresight) @ rotvec_to_dcm(b)
    assert np.allclose(euler_to_dcm(*new), C, atol=1e-12)
    J = boresight_angle_jacobian(boresight)
    step = 1e-7
    numeric = np.column_stack([(corrected_boresight(boresight, step * e) - boresight) / step for e in np.eye(3)])
    assert np.allclose(J, numeric, atol=1e-6)


def test_accel_bias_error_tilts_the_levelled_attitude_about_the_other_axis():
    """Level on specific force with an accelerometer-bias error: roll from f_y, pitch from f_x (the filter's
    levelling); the tilt error is (δb_y/g, -δb_x/g) about body x, y, whatever the heading."""
    g = 9.81
    for roll, pitch, yaw in ((0.01, -0.02, 0.3), (-0.005, 0.015, 2.5)):
        f_b = euler_to_dcm(roll, pitch, yaw).T @ np.array([0.0, 0.0, -g])  # C_n_b f_n, f_n = -gravity
        delta = np.array([0.004, -0.007, 0.002])  # bias estimate minus truth [m/s^2]
        f_hat = f_b - delta
        roll_hat = np.arctan2(-f_hat[1], -f_hat[2])
        pitch_hat = np.arctan2(f_hat[0], np.hypot(f_hat[1], f_hat[2]))
        tilt = accel_bias_body_tilt(delta, g)
        assert tilt[0] == pytest.approx(roll_hat - roll, abs=1e-5)  # -7.1e-4 rad; second order: the z bias
        assert tilt[1] == pytest.approx(pitch_hat - pitch, abs=1e-5)  # -4.1e-4 rad
        assert tilt[2] == 0.0


def test_accel_bias_tilt_covariance_follows_the_boresight_into_the_camera_frame():
    g = 9.8
    sigma = np.array([0.002, 0.005, 0.01])  # x, y, z [m/s^2]
    nadir = accel_bias_tilt_covariance_camera(sigma, g, np.eye(3))
    assert np.allclose(np.diag(nadir), [(0.005 / g) ** 2, (0.002 / g) ** 2, 0.0])  # y bias -> roll, x -> pitch
    # camera turned 90 deg about body z: camera x is body y, so the camera's x tilt is the body's pitch
    turned = accel_bias_tilt_covariance_camera(sigma, g, euler_to_dcm(0.0, 0.0, np.pi / 2))
    assert np.allclose(np.diag(turned), [(0.002 / g) ** 2, (0.005 / g) ** 2, 0.0], atol=1e-15)
    rng = np.random.default_rng(2)
    C_c_b = euler_to_dcm(0.3, -0.2, 1.1)
    samples = accel_bias_body_tilt(rng.normal(0.0, sigma, (200_000, 3)), g) @ C_c_b  # rows: C_c_bᵀ tilt_b
    assert np.allclose(np.cov(samples.T), accel_bias_tilt_covariance_camera(sigma, g, C_c_b), atol=3e-9)


# ---------------------------------------------------------------- readers (georef/io/adjusted_cameras.py)

def _truth(n: int = 12) -> pd.DataFrame:
    return pd.DataFrame({"frame": np.arange(1, n + 1), "lat": 44.05 + 1e-4 * np.arange(n),
                         "lon": 15.62 + 1e-4 * np.arange(n), "height": 200.0 + np.arange(n),
                         "roll": RNG.normal(0, 2, n), "pitch": RNG.normal(0, 2, n), "yaw": RNG.uniform(0, 360, n)})


@pytest.mark.parametrize("fmt", ["metashape", "pix4d", "odm"])
def test_readers_return_the_written_cameras_value_by_value(tmp_path, fmt):
    truth = _truth()
    cameras = adjusted_cameras(truth, np.random.default_rng(1), sigma_position_m=0.0, sigma_angle_deg=0.0)
    path = write_adjusted(cameras, tmp_path / f"cams.{fmt}", fmt)
    read = read_adjusted_cameras(path, fmt)
    assert read.label == [f"IMG_{f:04d}.JPG" for f in truth["frame"]]
    assert np.allclose(read.easting, cameras["easting"], atol=1e-4)
    assert np.allclose(read.northing, cameras["northing"], atol=1e-4)
    assert np.allclose(read.height, truth["height"], atol=1e-4)
    from georef.frames.mapping import MapProjection

    gamma, _ = MapProjection(BLOCK_CRS).convergence_and_scale(truth["lat"], truth["lon"])
    roll, pitch, yaw = (np.degrees(a) for a in dcm_to_euler(image_to_ned(read.R_i_m, gamma)))
    assert np.allclose(roll, truth["roll"], atol=1e-6)
    assert np.allclose(pitch, truth["pitch"], atol=1e-6)
    assert np.allclose((yaw - truth["yaw"] + 180) % 360 - 180, 0.0, atol=1e-6)


def test_metashape_prefers_the_estimated_columns_and_reads_georef_own_export(tmp_path):
    path = tmp_path / "ms.csv"
    path.write_text("# Cameras (1)\n#Label,X/Easting,Y/Northing,Z/Altitude,Omega,Phi,Kappa,X_est,Y_est,Z_est,"
                    "Omega_est,Phi_est,Kappa_est\nA.JPG,1,2,3,0,0,0,10,20,30,1,2,3\n", encoding="utf-8")
    cams = read_adjusted_cameras(path)
    assert (cams.easting[0], cams.northing[0], cams.height[0]) == (10.0, 20.0, 30.0)
    assert np.allclose(np.degrees(rotation_to_opk(cams.R_i_m[0])), [1, 2, 3])
    own = tmp_path / "own.csv"  # georef process --format metashape
    own.write_text("label,x,y,z,omega,phi,kappa,x_accuracy,y_accuracy,z_accuracy,omega_accuracy,phi_accuracy,"
                   "kappa_accuracy\n7,5,6,7,0.5,-0.5,90,0.1,0.1,0.2,0.01,0.01,0.05\n", encoding="utf-8")
    cams = read_adjusted_cameras(own, "metashape")
    assert np.allclose(cams.R_i_m[0], opk_to_rotation(*np.radians([0.5, -0.5, 90])))
    assert np.allclose(cams.sigma_position[0], [0.1, 0.1, 0.2])


@pytest.mark.parametrize(("text", "line", "column", "words"), [
    ("#Label,X,Y,Z,Omega,Phi,Kappa\nA,1,2,x3,0,0,0\n", 2, "z", "not a number"),
    ("#Label,X,Y,Z,Omega,Phi,Kappa\nA,1,2,3,0,0,0\nA,1,2,3,0,0,0\n", 3, None, "twice"),
    ("#Label,X,Y,Z,Yaw,Pitch,Roll\nA,1,2,3,0,0,0\n", 1, "Yaw", "omega, phi, kappa"),
    ("#Label,X,Y,Omega,Phi,Kappa\nA,1,2,0,0,0\n", 1, None, "no Z"),
    ("A,1,2,3,0,0,0\n", 1, None, "no header"),
])
def test_reader_errors_name_line_and_column(tmp_path, text, line, column, words):
    path = tmp_path / "bad.csv"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(InputError) as info:
        read_adjusted_cameras(path, "metashape")
    assert info.value.line == line and info.value.column == column and words in info.value.message


def test_odm_reader_errors(tmp_path):
    path = tmp_path / "shots.geojson"
    path.write_text(json.dumps({"type": "FeatureCollection", "features": [
        {"properties": {"filename": "a.jpg", "translation": [1, 2, 3]}}]}), encoding="utf-8")
    with pytest.raises(InputError, match=r"features\[0\]\.properties\.rotation"):
        read_adjusted_cameras(path)
    path.write_text(json.dumps({"a.jpg": {"focal": 0.7}}), encoding="utf-8")  # cameras.json
    with pytest.raises(InputError, match="interior orientation"):
        read_adjusted_cameras(path)


# ---------------------------------------------------------------- the estimate on synthetic photos

def _synthetic(headings: list[float], b_deg, dl_m, tau_deg=0.01, tilt_deg=(0.02, -0.015), yaw_err_deg=0.2,
               n_per_strip: int = 40, seed: int = 0, eo_position_sigma: float = 0.04,
               body_tilt_deg=(0.0, 0.0)) -> MatchedPhotos:
    """Photos on strips of the given headings: boresight correction b, lever correction dl, a flight-constant
    INS tilt and yaw error, a strip-constant INS error of tau, a body-fixed INS tilt (about body x, y; truth
    relative to the EO), adjustment noise."""
    rng = np.random.default_rng(seed)
    boresight = np.radians([0.35, -0.6, 1.2])
    C_c_b = euler_to_dcm(*boresight)
    rows = []
    t = 0.0
    eps0 = np.radians([*tilt_deg, yaw_err_deg])
    for heading in headings:
        eps_s = eps0 + np.radians(rng.normal(0, tau_deg, 3))
        e_s = np.array([0.3, -0.2, 0.1]) + rng.normal(0, 0.05, 3)
        for _ in range(n_per_strip):
            C_b_n = euler_to_dcm(rng.normal(0, 0.01), rng.normal(0, 0.01), np.radians(heading))
            C_c_n_true = C_b_n @ C_c_b @ rotvec_to_dcm(np.radians(b_deg))
            C_b_n_eo = C_b_n @ rotvec_to_dcm(-np.radians([*body_tilt_deg, 0.0]))  # C_true = C_eo exp(tilt_b)
            C_c_n_eo = rotvec_to_dcm(-eps_s) @ C_b_n_eo @ C_c_b  # INS error: C_true = exp(eps) C_eo
            adj = C_c_n_true @ rotvec_to_dcm(np.radians(rng.normal(0, 0.003, 3)))
            d_ned = C_b_n @ np.asarray(dl_m) + e_s + rng.normal(0, 0.015, 3)
            rows.append((t, C_c_n_eo, adj, d_ned, heading))
            t += 0.5
        t += 30.0
    n = len(rows)
    return MatchedPhotos(label=np.array([f"{k}" for k in range(n)], dtype=object),
                         frame=np.array([f"{k}" for k in range(n)], dtype=object), time=np.array([r[0] for r in rows]),
                         C_c_n_eo=np.array([r[1] for r in rows]), C_c_n_adjusted=np.array([r[2] for r in rows]),
                         d_ned=np.array([r[3] for r in rows]),
                         sigma_attitude=np.tile(np.radians([0.02, 0.02, yaw_err_deg]), (n, 1)),
                         sigma_position=np.tile([eo_position_sigma, eo_position_sigma, 0.3], (n, 1)),
                         roll_deg=np.zeros(n),
                         heading_deg=np.array([r[4] for r in rows]), grid=np.zeros((n, 2)))


def test_split_strips_cuts_at_turns_and_gaps():
    t = np.arange(60) * 0.5
    heading = np.r_[np.full(20, 10.0), np.linspace(10, 190, 10), np.full(30, 190.0)]
    strips = split_strips(t, heading, np.zeros(60))
    assert strips.count == 2 and strips.in_turns >= 8
    assert set(strips.index[:19]) == {0} and set(strips.index[32:]) == {1}


def test_synthetic_block_recovers_the_corrections():
    b, dl = [0.3, -0.2, 0.5], [0.05, -0.15, 0.03]
    photos = _synthetic([0, 180, 0, 180, 90, 270, 90, 270], b, dl)
    result = calibrate(photos, [0.35, -0.6, 1.2], [1.1, -0.25, 0.55])
    assert result.tilt_estimated and not result.problems
    for c, truth in zip(result.boresight, b, strict=True):
        assert abs(c.value - truth) < 3 * c.sigma, (c.name, c.value, truth, c.sigma)
    # the flight-constant yaw error (0.2 deg) is not averaged out: it is in the estimate and in its sigma
    assert result.boresight[2].sigma >= 0.2 * 0.9
    assert abs(result.boresight[2].value - b[2] - 0.2) < 0.05
    # tilt separated: the constant 0.02/-0.015 deg does not bias roll and pitch
    assert abs(result.boresight[0].value - b[0]) < 0.01 and abs(result.boresight[1].value - b[1]) < 0.01
    assert np.allclose(result.ins_tilt_deg, [0.02, -0.015], atol=0.012)
    lever_y = result.lever_arm[1]
    assert lever_y.estimated and abs(lever_y.value - dl[1]) < 3 * lever_y.sigma
    assert not result.lever_arm[0].estimated and "latency" in result.lever_arm[0].why
    assert not result.lever_arm[2].estimated and "vertical datum" in result.lever_arm[2].why
    assert result.lever_arm[0].calibrated == 1.1
    assert result.lever_arm[1].calibrated == pytest.approx(-0.25 + lever_y.value)
    # the roll and pitch sigma include the EO tilt sigma the strips do not explain (a possible body-fixed tilt)
    assert result.boresight[0].sigma > result.boresight[0].model_sigma


def _process(accel_sigma=(0.001, 0.0015, 0.001), lever_sigma=None, span=(-10.0, 1e5)) -> ProcessFigures:
    return ProcessFigures(accel_bias_sigma_m_s2=None if accel_sigma is None else np.array(accel_sigma),
                          gnss_lever_arm_sigma_m=None if lever_sigma is None else np.array(lever_sigma),
                          time_span_s=span, method="rts", path="summary.json")


def test_accel_bias_sigma_replaces_the_conservative_body_tilt_bound():
    """A body-fixed INS tilt (0.006, -0.004 deg) lands in the roll and pitch estimates on every heading; with the
    filter's accelerometer-bias sigma (0.001, 0.0015 m/s^2: 0.0088 deg about x from y, 0.0058 deg about y from x)
    the sigma is the between-strip part plus that tilt sigma, not the bound from the EO's tilt sigma (0.02 deg,
    0.017 deg once the strips' scatter is taken off)."""
    b, body = [0.3, -0.2, 0.5], (0.006, -0.004)
    photos = _synthetic([0, 180, 0, 180, 90, 270, 90, 270], b, [0.05, -0.15, 0.03], body_tilt_deg=body)
    old = calibrate(photos, [0.35, -0.6, 1.2], [1.1, -0.25, 0.55])
    new = calibrate(photos, [0.35, -0.6, 1.2], [1.1, -0.25, 0.55], process=_process())
    level = _synthetic([0, 180, 0, 180, 90, 270, 90, 270], b, [0.05, -0.15, 0.03])  # same noise, no body tilt
    without = calibrate(level, [0.35, -0.6, 1.2], [1.1, -0.25, 0.55], process=_process())
    g = photos.gravity_m_s2
    body_sigma = np.degrees([0.0015 / g, 0.001 / g])  # about body x (from the y bias), about body y (from x)
    C_c_b = euler_to_dcm(*np.radians([0.35, -0.6, 1.2]))
    tilt_c = C_c_b.T @ np.array([*body, 0.0])  # the body tilt in the camera frame [deg, small angles]
    for k in range(2):
        c, o = new.boresight[k], old.boresight[k]
        assert c.value == pytest.approx(o.value)  # the estimate does not change, only its sigma
        # the body-fixed tilt is in the estimate, whole: no heading separates it ...
        assert c.value - without.boresight[k].value == pytest.approx(tilt_c[k], abs=5e-4)
        expected = np.hypot(c.model_sigma, body_sigma[k])  # ... and in the sigma; yaw leak: roll ~0.5 deg, tiny
        assert c.sigma == pytest.approx(expected, rel=0.05), (c.name, c.sigma, expected)
        assert o.sigma > 1.3 * c.sigma and "CONSERVATIVE" in o.why and "0.00" in c.why and "process summary" in c.why
    assert new.sigma_source != old.sigma_source and "process summary" in new.sigma_source
    assert any("--process-summary" in a for a in old.advice) and not any("CONSERVATIVE" in a for a in new.advice)
    # lever y keeps the EO's bound (here 0: the strips' scatter explains the EO's 4 cm); an estimated GNSS lever
    # arm's sigma (body-fixed, different on every flight) raises it
    y_new, y_old = new.lever_arm[1], old.lever_arm[1]
    assert y_new.sigma == pytest.approx(y_old.sigma) == pytest.approx(y_new.model_sigma)
    y_lever = calibrate(photos, [0.35, -0.6, 1.2], [1.1, -0.25, 0.55],
                        process=_process(lever_sigma=(0.01, 0.02, 0.03))).lever_arm[1]
    assert y_lever.sigma == pytest.approx(np.hypot(y_new.model_sigma, 0.02)) and "lever-arm y sigma" in y_lever.why
    # a summary without the bias sigma (method graph or axis): roll and pitch stay conservative, and say so
    graph = calibrate(photos, [0.35, -0.6, 1.2], [1.1, -0.25, 0.55], process=_process(accel_sigma=None))
    assert graph.boresight[0].sigma == pytest.approx(old.boresight[0].sigma)
    assert any("method rts" in a for a in graph.advice)


def test_a_summary_of_another_flight_is_refused():
    photos = _synthetic([0, 180, 90, 270], [0.3, -0.2, 0.5], [0, 0, 0])
    with pytest.raises(CalibrationInputError, match="outside this run's POS time span") as info:
        calibrate(photos, [0, 0, 0], [0, 0, 0], process=_process(span=(5000.0, 9000.0)))
    assert info.value.column == "summary.time_span_s" and info.value.path == "summary.json"


def test_process_summary_reader(tmp_path):
    path = tmp_path / "s.json"
    path.write_text(json.dumps({"command": "process", "summary": {
        "time_span_s": [10.0, 20.0], "method": "rts", "accel_bias_sigma_m_s2": [0.001, 0.002, 0.003],
        "gnss_lever_arm_sigma_m": None, "graph_lever_arm_sigma_m": [0.01, 0.02, 0.03]}}))
    figures = read_process_summary(path)
    assert figures.time_span_s == (10.0, 20.0) and figures.method == "rts"
    assert np.array_equal(figures.accel_bias_sigma_m_s2, [0.001, 0.002, 0.003])
    assert np.array_equal(figures.gnss_lever_arm_sigma_m, [0.01, 0.02, 0.03])
    for document, column, words in (({"command": "fuse", "summary": {}}, "command", "not a summary of georef "
                                      "process"),
                                     ({"command": "process", "summary": {"time_span_s": [1, 2],
                                                                         "accel_bias_sigma_m_s2": [1, 2]}},
                                      "summary.accel_bias_sigma_m_s2", "three non-negative numbers")):
        path.write_text(json.dumps(document))
        with pytest.raises(InputError, match=words) as info:
            read_process_summary(path)
        assert info.value.column == column
    path.write_text("{\n  \"command\": \"process\",\n  oops\n}")
    with pytest.raises(InputError, match="not a JSON summary") as info:
        read_process_summary(path)
    assert info.value.line == 3


def test_process_summary_bias_sigmas_are_the_rms_of_the_solved_epochs():
    """``accel_bias_sigma_m_s2`` / ``gyro_bias_sigma_deg_h`` [body x, y, z]: the named states' 1-sigma, RMS over
    the covariance epochs from the filter's first row; None for the graph (no bias marginals)."""
    from types import SimpleNamespace

    from georef.fusion.ins_layout import BA, BG, LEVER, NX_CAL, NX_NAV
    from georef.run_summary import _bias_sigma_figures

    sigma = np.full((4, NX_NAV), 7.0)
    sigma[:, BA:BA + 3] = [[9.0, 9.0, 9.0], [0.003, 0.004, 0.001], [0.004, 0.002, 0.001], [0.0, 0.004, 0.001]]
    sigma[:, BG:BG + 3] = np.radians(10.0 / 3600.0)  # 10 deg/h
    info = SimpleNamespace(epoch_rows=np.array([0, 10, 20, 30]), epoch_sigma=sigma, start_row=5)
    figures = _bias_sigma_figures(SimpleNamespace(ins_info=info, graph_info=None))
    assert figures["accel_bias_sigma_m_s2"] == pytest.approx([np.sqrt((0.003**2 + 0.004**2) / 3),
                                                              np.sqrt((0.004**2 + 0.002**2 + 0.004**2) / 3), 0.001])
    assert figures["gyro_bias_sigma_deg_h"] == pytest.approx([10.0, 10.0, 10.0])
    assert figures["gnss_lever_arm_sigma_m"] is None  # no calibration states
    calibrating = np.hstack([sigma, np.zeros((4, NX_CAL - NX_NAV))])
    calibrating[:, LEVER:LEVER + 3] = [0.01, 0.02, 0.03]
    info.epoch_sigma = calibrating
    assert _bias_sigma_figures(SimpleNamespace(ins_info=info, graph_info=None))["gnss_lever_arm_sigma_m"] == \
        pytest.approx([0.01, 0.02, 0.03])
    graph = _bias_sigma_figures(SimpleNamespace(ins_info=info, graph_info=object()))
    assert graph == {"accel_bias_sigma_m_s2": None, "gyro_bias_sigma_deg_h": None, "gnss_lever_arm_sigma_m": None}


def test_georef_process_summary_json_carries_the_bias_sigmas(tmp_path):
    """`georef process --summary-json` on the bundled flight writes what --process-summary reads: the bias sigmas
    of the RTS (three positive numbers each, m/s^2 and deg/h), no GNSS lever-arm sigma (configured, not estimated),
    and a POS time span holding every EO row's time."""
    from georef_cli.main import app

    from georef.io.eo_table import read_eo_csv

    data = Path(__file__).resolve().parents[2] / "data"
    eo, summary = tmp_path / "eo.csv", tmp_path / "summary.json"
    run = CliRunner().invoke(app, ["process", str(data / "POS.txt"), str(data / "Kamera.txt"), "--config",
                                   str(data / "flight.toml"), "-o", str(eo), "--summary-json", str(summary), "-q"])
    assert run.exit_code == 0, run.output
    figures = read_process_summary(summary)
    assert figures.method == "rts" and figures.gnss_lever_arm_sigma_m is None
    ba = figures.accel_bias_sigma_m_s2
    assert ba.shape == (3,) and np.all((ba > 1e-5) & (ba < 0.1)), ba  # m/s^2, not mg nor rad
    gyro = json.loads(summary.read_text())["summary"]["gyro_bias_sigma_deg_h"]
    assert len(gyro) == 3 and all(0.01 < v < 1000 for v in gyro), gyro  # deg/h
    times = read_eo_csv(eo)["time"].to_numpy(float)
    assert figures.time_span_s[0] <= times.min() and times.max() <= figures.time_span_s[1]


def test_lever_y_within_its_noise_is_not_applied():
    """EO positions good to 0.2 m: a body-fixed position error of that size cannot be told from the lever arm, so a
    4 cm correction is not significant and the configured lever arm is kept (reported with its sigma)."""
    photos = _synthetic([0, 180, 0, 180, 90, 270, 90, 270], [0.3, -0.2, 0.5], [0.0, -0.04, 0.0],
                        eo_position_sigma=0.2)
    result = calibrate(photos, [0.35, -0.6, 1.2], [1.1, -0.25, 0.55])
    y = result.lever_arm[1]
    assert y.observed and not y.estimated and "not significant" in y.why
    assert y.sigma > 0.15 and y.calibrated == -0.25 and abs(y.value + 0.04) < 3 * y.sigma


def test_one_heading_does_not_separate_tilt_nor_lever_y():
    photos = _synthetic([0, 0, 0, 0], [0.3, -0.2, 0.5], [0.05, -0.04, 0.03])
    result = calibrate(photos, [0.35, -0.6, 1.2], [1.1, -0.25, 0.55])
    assert not result.tilt_estimated and not result.lever_arm[1].estimated
    assert any("heading" in p for p in result.problems)
    # the flight-constant tilt is inside the sigma, not averaged away: sigma >= the per-photo 0.02 deg
    assert result.boresight[0].sigma >= 0.019 and result.boresight[1].sigma >= 0.019


def test_too_few_photos_and_one_strip():
    photos = _synthetic([0], [0.3, -0.2, 0.5], [0, 0, 0], n_per_strip=MIN_PHOTOS - 1)
    with pytest.raises(CalibrationInputError, match=f"{MIN_PHOTOS - 1} usable photos"):
        calibrate(photos, [0, 0, 0], [0, 0, 0])
    result = calibrate(_synthetic([0], [0.3, -0.2, 0.5], [0, 0, 0]), [0, 0, 0], [0, 0, 0])
    assert result.weak and any("1 strip" in p for p in result.problems)


def test_inconsistent_block_fails_the_chi_square():
    photos = _synthetic([0, 180, 0, 180, 90, 270, 90, 270], [0.3, -0.2, 0.5], [0, 0, 0], tau_deg=0.2)
    result = calibrate(photos, [0.35, -0.6, 1.2], [0, 0, 0])
    assert any("attitude residuals" in p and "chi-square" in p for p in result.problems)


# ---------------------------------------------------------------- simulated blocks (georef simulate + process)

BLOCK_SEEDS = (1, 2, 3)


@pytest.fixture(scope="module")
def blocks():
    out = {}
    for seed in BLOCK_SEEDS:
        rng = np.random.default_rng(1000 + seed)
        errors = (tuple(rng.uniform(-0.5, 0.5, 3)), tuple(rng.uniform(-0.05, 0.05, 3)))
        out[seed] = (simulate_block(seed, *errors), errors, rng)
    return out


def _rms_z_band(n: int) -> tuple[float, float]:
    """Two-sided 99 % band of rms(z) over ``n`` independent estimates whose sigmas are right:
    sqrt(chi-square(n) quantiles / n)."""
    lo, hi = stats.chi2.ppf([0.005, 0.995], n)
    return float(np.sqrt(lo / n)), float(np.sqrt(hi / n))


def _rms(values) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


@pytest.mark.slow
def test_simulated_blocks_recover_the_boresight(blocks, tmp_path):
    """The benchmark's assertions on 3 of its 20 blocks, with the process run's figures (``--process-summary``).

    * The simulator's body-fixed INS tilt (truth) is the filter's accelerometer-bias error over g (opposite signs:
      the truth is "true relative to the EO", the bias error "estimate minus truth"; a swapped axis or sign fails),
      and its z against the bias sigma over g has an rms inside the 99 % band of 6 estimates, [0.34, 1.76].
    * >= 90 % of the 12 observed components (roll, pitch, yaw, lever y) within 2 sigma; roll and pitch's rms(z)
      (6 estimates) inside the same band. 6 estimates cannot tell a factor 1.4 in the sigma apart (the old bound
      gives 0.33 here, the between-strip sigma alone 1.53), so the sigma's make-up is asserted too: the between-strip
      part plus the tilt sigma of the bias (fails for the model sigma alone) and at most 0.8 x the old bound's (fails
      for the old sigma), and below 0.9 x the per-frame sigma (the old bound: 1.07 x)."""
    z_tilt, z, z_level = [], [], []
    for seed, (block, (b_err, l_err), rng) in blocks.items():
        fmt = ("metashape", "pix4d", "odm")[seed % 3]
        path = write_adjusted(adjusted_cameras(block.truth, rng), tmp_path / f"b{seed}.{fmt}", fmt)
        photos = match_photos(block.eo, "eo", read_adjusted_cameras(path, fmt), BLOCK_CRS)
        process = figures_of_summary(block.process_summary)
        result = calibrate(photos, block.configured_boresight_deg, block.configured_lever_arm_m, process=process)
        old = calibrate(photos, block.configured_boresight_deg, block.configured_lever_arm_m)
        assert result.tilt_estimated and len(result.strips) >= 8 and not result.problems
        for c, truth in zip(result.boresight + result.lever_arm, list(b_err) + list(l_err), strict=True):
            if c.observed:
                z.append((c.value - truth) / c.sigma)
        body_tilt = body_fixed_tilt_deg(block, photos)
        predicted = accel_bias_tilt_deg(block, photos)
        sigma_ba = process.accel_bias_sigma_m_s2
        tilt_sigma = np.degrees([sigma_ba[1], sigma_ba[0]]) / photos.gravity_m_s2  # y bias -> roll, x -> pitch
        for k in range(2):
            assert abs(body_tilt[k] + predicted[k]) < 0.5 * abs(predicted[k]) + 0.002, (seed, body_tilt, predicted)
            z_tilt.append(body_tilt[k] / tilt_sigma[k])
            c = result.boresight[k]
            z_level.append((c.value - b_err[k]) / c.sigma)
            assert 0.3 < c.jackknife_sigma / c.model_sigma < 2.5
            assert np.hypot(c.model_sigma, tilt_sigma[k]) * 0.97 <= c.sigma <= 0.8 * old.boresight[k].sigma
            assert c.sigma < 0.9 * float(block.eo[("sigma_roll", "sigma_pitch")[k]].median())
    lo, hi = _rms_z_band(6)
    assert lo <= _rms(z_tilt) <= hi, z_tilt
    assert len(z) == 12 and np.mean(np.abs(z) <= 2.0) >= 0.9, z
    assert lo <= _rms(z_level) <= hi, z_level


@pytest.mark.slow
def test_lever_x_and_trigger_latency_move_the_camera_alike(blocks, tmp_path):
    """Process block 1 again with 0.03 s of camera time offset the exposures do not have: the lever-arm x estimate
    moves by -v dt (v = 10 m/s: -0.30 m), y and z and the boresight do not (within their sigmas)."""
    block, (b_err, l_err), _ = blocks[BLOCK_SEEDS[0]]
    shifted = simulate_block(BLOCK_SEEDS[0], b_err, l_err, camera_time_offset_s=0.03)
    results = []
    for eo in (block.eo, shifted.eo):
        cams = write_adjusted(adjusted_cameras(block.truth, np.random.default_rng(7)), tmp_path / "c.txt", "pix4d")
        photos = match_photos(eo, "eo", read_adjusted_cameras(cams, "pix4d"), BLOCK_CRS)
        results.append(calibrate(photos, block.configured_boresight_deg, block.configured_lever_arm_m))
    speed = np.median([s["speed_mps"] for s in results[0].strips if s["speed_mps"] > 5])
    dx = results[1].lever_arm[0].value - results[0].lever_arm[0].value
    assert dx == pytest.approx(-speed * 0.03, rel=0.1)
    for k in (1, 2):
        assert abs(results[1].lever_arm[k].value - results[0].lever_arm[k].value) < 0.3 * abs(dx)
    for k in range(3):
        assert abs(results[1].boresight[k].value - results[0].boresight[k].value) < results[0].boresight[k].sigma


# ---------------------------------------------------------------- the CLI

def _cli_inputs(blocks, tmp_path: Path) -> tuple[Path, Path, Path, object]:
    block, _, rng = blocks[BLOCK_SEEDS[1]]
    eo = write_eo_csv(block.eo, tmp_path / "eo.csv")
    adjusted = write_adjusted(adjusted_cameras(block.truth, np.random.default_rng(3)), tmp_path / "shots.geojson",
                              "odm")
    config = tmp_path / "flight.toml"
    boresight = ", ".join(repr(float(v)) for v in block.configured_boresight_deg)
    lever = ", ".join(repr(float(v)) for v in block.configured_lever_arm_m)
    config.write_text(f"[mounting]\nboresight = [{boresight}]\nlever_arm_camera = [{lever}]\n"
                      "lever_arm_gnss = [0.02, 0, -0.12]\n", encoding="utf-8")
    return eo, adjusted, config, block


@pytest.mark.slow
def test_cli_writes_a_calibration_process_reads(blocks, tmp_path):
    from georef_cli.main import app
    from georef_cli.output import write_json

    eo, adjusted, config, block = _cli_inputs(blocks, tmp_path)
    out = tmp_path / "calibration.toml"
    summary = tmp_path / "summary.json"
    process_summary = tmp_path / "process.json"  # what georef process --summary-json writes under "summary"
    write_json(process_summary, {"command": "process", "exit_code": 0, "summary": block.process_summary})
    run = CliRunner().invoke(app, ["calibrate-boresight", str(eo), str(adjusted), "--crs", BLOCK_CRS,
                                   "--config", str(config), "-o", str(out), "--summary-json", str(summary),
                                   "--process-summary", str(process_summary)])
    assert run.exit_code == 0, run.output
    assert "boresight yaw" in run.output and "latency" in run.output
    text = " ".join(run.output.split())  # the console wraps at 80 columns
    assert "bias sigmas (process summary)" in text and "CONSERVATIVE" not in text
    document = json.loads(summary.read_text())
    assert document["inputs"]["process_summary"] == str(process_summary)
    figures = document["figures"]
    assert figures["sigma_body_fixed_source"].endswith("(process summary)")
    ba = block.process_summary["accel_bias_sigma_m_s2"]
    assert f"{ba[1]:.2g} m/s^2 along body y" in figures["boresight_deg"]["roll"]["why"]
    # without the summary: the same corrections, larger roll and pitch sigmas, and the advice how to tighten them
    conservative = CliRunner().invoke(app, ["calibrate-boresight", str(eo), str(adjusted), "--crs", BLOCK_CRS,
                                            "--config", str(config), "-o", str(tmp_path / "c.toml"),
                                            "--summary-json", str(tmp_path / "c.json")])
    assert conservative.exit_code == 0 and "--process-summary summary.json" in " ".join(conservative.output.split())
    wide = json.loads((tmp_path / "c.json").read_text())["figures"]["boresight_deg"]
    for name in ("roll", "pitch"):
        assert wide[name]["correction"] == figures["boresight_deg"][name]["correction"]
        assert wide[name]["sigma"] > 1.2 * figures["boresight_deg"][name]["sigma"]
    cfg = load_configs([config, out])  # the calibration loads as a second --config
    for k, name in enumerate(("roll", "pitch", "yaw")):
        entry = figures["boresight_deg"][name]
        assert cfg.mounting.boresight[k] == pytest.approx(block.configured_boresight_deg[k] + entry["correction"],
                                                          abs=1e-6)
    lever = figures["lever_arm_camera_m"]
    assert not lever["x"]["estimated"] and not lever["z"]["estimated"]  # latency, vertical datum: not applied
    for k, name in enumerate(("x", "y", "z")):
        applied = lever[name]["correction"] if lever[name]["estimated"] else 0.0
        assert cfg.mounting.lever_arm_camera[k] == pytest.approx(block.configured_lever_arm_m[k] + applied, abs=1e-6)
    assert cfg.mounting.lever_arm_gnss == (0.02, 0.0, -0.12)  # untouched: the calibration names two keys only
    assert set(tomllib.loads(out.read_text())) == {"mounting"}
    assert load_config(out).mounting.boresight == cfg.mounting.boresight


@pytest.mark.slow
def test_cli_exit_codes(blocks, tmp_path):
    from georef_cli.main import app

    eo, adjusted, config, block = _cli_inputs(blocks, tmp_path)
    runner = CliRunner()
    base = ["calibrate-boresight", str(eo), "--crs", BLOCK_CRS, "--config", str(config), "-o",
            str(tmp_path / "c.toml")]
    # no matching names
    document = json.loads(adjusted.read_text())
    for feature in document["features"]:
        feature["properties"]["filename"] = "DSC_" + feature["properties"]["filename"]
    renamed = tmp_path / "renamed.geojson"
    renamed.write_text(json.dumps(document))
    run = runner.invoke(app, [*base[:2], str(renamed), *base[2:]])
    assert run.exit_code == 2 and "no camera label matches" in run.output
    # one strip only: written, but weak (exit 4), with the reason
    eo_table = pd.read_csv(eo, dtype={"frame": str, "image": str, "flag": str}, keep_default_na=False)
    strip = eo_table.iloc[200:240]
    one = tmp_path / "one.csv"
    write_eo_csv(strip, one)
    run = runner.invoke(app, [*base[:1], str(one), str(adjusted), *base[2:]])
    assert run.exit_code == 4, run.output
    assert "1 strip" in run.output and (tmp_path / "c.toml").exists()
    # too few photos
    few = tmp_path / "few.csv"
    write_eo_csv(eo_table.iloc[200:205], few)
    run = runner.invoke(app, [*base[:1], str(few), str(adjusted), *base[2:]])
    assert run.exit_code == 2 and "5 usable photos" in run.output
    # the summary of another flight (its POS time span misses the photos)
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"command": "process", "summary": {**block.process_summary,
                                                                   "time_span_s": [0.0, 10.0]}}))
    run = runner.invoke(app, [*base[:2], str(adjusted), *base[2:], "--process-summary", str(other)])
    assert run.exit_code == 2 and "summary.time_span_s" in run.output and "another flight" in run.output
    # a bad adjusted file names line and column
    bad = tmp_path / "bad.txt"
    bad.write_text("imageName X Y Z Omega Phi Kappa\nIMG_0001.JPG 1 2 3 0 zero 0\n")
    run = runner.invoke(app, [*base[:2], str(bad), *base[2:], "--format", "pix4d"])
    assert run.exit_code == 2 and "line 2" in run.output and "phi" in run.output
