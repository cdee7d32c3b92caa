"""``--method graph`` (GTSAM) against the RTS smoother and against outliers."""

from __future__ import annotations

import numpy as np
import pytest

from georef.config import InsSettings
from georef.evaluate import accuracy, frame_errors
from georef.pipeline import process
from georef.sim.files import processing_config_for, write_flight
from georef.sim.flight import SimConfig, simulate
from georef.sim.sensors import GnssModel

OUTLIERS = [(30.0, 25.0), (55.0, 40.0), (140.0, 20.0)]
PAIRS = [("north", "sigma_n"), ("east", "sigma_e"), ("up", "sigma_u"), ("roll", "sigma_roll"),
         ("pitch", "sigma_pitch"), ("yaw", "sigma_yaw")]


def _run(tmp_path, sim, **changes):
    flight = simulate(sim)
    paths = write_flight(flight, tmp_path)
    cfg = processing_config_for(flight)
    return flight, {name: process(paths["POS.txt"], paths["Kamera.txt"], cfg.updated(**change))
                    for name, change in changes.items()}


@pytest.mark.parametrize("seed", [1, 2])
def test_graph_and_rts_agree_within_their_sigmas(tmp_path, seed):
    flight, results = _run(tmp_path, SimConfig(seed=seed), rts={"method": "rts"}, graph={"method": "graph"})
    rts, graph = results["rts"].table, results["graph"].table
    difference = frame_errors(graph, rts)
    for component, sigma in PAIRS:
        combined = np.hypot(rts[sigma], graph[sigma])
        assert np.mean(np.abs(difference[component]) <= 2.0 * combined) >= 0.95, component
    figures = accuracy(frame_errors(graph, flight.truth_frames))
    assert figures["horizontal_rms_m"] <= 0.4 and figures["vertical_rms_m"] <= 0.7


def test_robust_kernel_resists_outliers(tmp_path):
    """Three outliers of 20-40 m: the robust pass drops them before the Gaussian refit, and the result is better
    than the plain (Gaussian-only) graph's. Claims that hold on any flight, not on this seed alone: "exactly the
    three outliers" does not (seeds 1-4 dropped 3, 3, 4 and 3 fixes: the 99.9 % gate loses about one good fix in
    a thousand), nor "within rts + 5 %" (seed 4: 1.058; test_graph_at_least_as_accurate_as_rts covers it)."""
    sim = SimConfig(seed=2, gnss=GnssModel(outliers=OUTLIERS))
    flight, results = _run(tmp_path, sim, robust={"method": "graph"},
                           plain={"method": "graph", "graph_robust": False})
    robust = accuracy(frame_errors(results["robust"].table, flight.truth_frames))
    plain = accuracy(frame_errors(results["plain"].table, flight.truth_frames))
    assert robust["horizontal_rms_m"] < plain["horizontal_rms_m"]
    # the outliers and at most one good fix of the 177 (expected 0.18 at the gate)
    assert len(OUTLIERS) <= results["robust"].nav.graph_info.rejected_fixes <= len(OUTLIERS) + 1


#: the target: on the simulated helicopter flights the graph's horizontal RMS is no worse than rts + 5 %
RTS_MARGIN = 1.05




@pytest.mark.parametrize("outliers", [OUTLIERS], ids=["outliers"])  # clean flights: within 0.2 % of these
@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_graph_at_least_as_accurate_as_rts(tmp_path, seed, outliers):
    """Horizontal RMS at the frames within rts + 5 % (measured 2026-11-26: 1.022, 0.998, 0.964 and 1.031 on seeds
    1-4; seeds 1 and 4 were 1.054 and 1.061 while every rts pass moved its prior mean to the previous pass's
    smoothed start). The graph estimates the lever arm and the GNSS time offset, which rts holds at the configured
    values: 1-m fixes over 3 minutes barely inform them, so their estimates follow the fixes' noise and shift the
    frames along track by a few cm, for better or worse (docs/method-graph.md)."""
    sim = SimConfig(seed=seed, gnss=GnssModel(outliers=outliers))
    flight, results = _run(tmp_path, sim, graph={"method": "graph"}, rts={"method": "rts"})
    graph = accuracy(frame_errors(results["graph"].table, flight.truth_frames))
    rts = accuracy(frame_errors(results["rts"].table, flight.truth_frames))
    assert graph["horizontal_rms_m"] <= RTS_MARGIN * rts["horizontal_rms_m"]


def test_graph_takes_the_unit_error_model_the_data_show(tmp_path):
    """The POS unit's attitude is 5 times noisier than configured (white 0.05 deg, level errors 0.15 deg; the
    configuration says 0.01 and 0.05): the graph must weigh it as the EKF + RTS's fit of this flight does, not as
    configured. With the configured model it gave 0.317 m against rts 0.265 (1.19) and a yaw error 1.26 times its
    sigma; with the fitted one 0.271 (1.02) and 0.78."""
    from georef.sim.sensors import UnitModel

    sim = SimConfig(seed=1, unit=UnitModel(angle_noise_deg=0.05, level_error_deg=0.15))
    flight = simulate(sim)
    paths = write_flight(flight, tmp_path)
    cfg = processing_config_for(flight).updated(unit_angle_noise=0.01, unit_level_sigma=0.05)
    results = {method: process(paths["POS.txt"], paths["Kamera.txt"], cfg.updated(method=method))
               for method in ("graph", "rts")}
    errors = {method: frame_errors(result.table, flight.truth_frames) for method, result in results.items()}
    figures = {method: accuracy(error) for method, error in errors.items()}
    assert figures["graph"]["horizontal_rms_m"] <= RTS_MARGIN * figures["rts"]["horizontal_rms_m"]
    graph = results["graph"].table
    for component, sigma in (("roll", "sigma_roll"), ("pitch", "sigma_pitch"), ("yaw", "sigma_yaw")):
        assert np.sqrt(np.mean((errors["graph"][component] / graph[sigma]) ** 2)) <= 1.1, component


def test_isam2_matches_batch(tmp_path):
    _, results = _run(tmp_path, SimConfig(seed=5), lm={"method": "graph"},
                           isam2={"method": "graph", "graph_solver": "isam2"})
    difference = frame_errors(results["isam2"].table, results["lm"].table)
    lm = results["lm"].table
    for component, sigma in PAIRS[:3]:
        assert np.mean(np.abs(difference[component]) <= lm[sigma]) >= 0.95


def test_isam2_with_scale_factors_solves(flight_dir, flight_defaults):
    """ISAM2 fed one keyframe at a time with the scale-factor variable and the unit's attitude: GTSAM's default
    Cholesky factorisation called the unit variables indeterminate ("Symbol: u2", exit 3) on this flight;
    ISAM2 now factorises with QR, as the marginals do. Its solution stays within the batch solution's sigmas."""
    _, paths = flight_dir
    changes = {"method": "graph", "graph_scale_factor_sigma": 0.002}
    lm = process(paths["POS.txt"], paths["Kamera.txt"], flight_defaults.updated(**changes)).table
    isam2 = process(paths["POS.txt"], paths["Kamera.txt"],
                    flight_defaults.updated(graph_solver="isam2", **changes)).table
    difference = frame_errors(isam2, lm)
    for component, sigma in PAIRS[:3]:
        assert np.mean(np.abs(difference[component]) <= lm[sigma]) >= 0.95


def test_graph_covers_every_row_and_frame_rts_does(flight_dir, flight_defaults):
    """The graph adds keyframes at the first and last rows RTS solved: no frame is left "outside navigation span"
    (the first exposure was, when the graph began at the first fix)."""
    from georef.fusion.graph import solve_graph
    from georef.fusion.ins import inputs_from_pos, solve_ins
    from georef.io.pos import read_pos

    _, paths = flight_dir
    log = read_pos(paths["POS.txt"])
    nav = solve_graph(log, flight_defaults)
    rts = solve_ins(inputs_from_pos(log), InsSettings.of(flight_defaults))
    assert np.array_equal(nav.valid, rts.valid)
    assert np.isfinite(nav.pos_var_n[nav.valid]).all() and np.isfinite(nav.att_sigma[nav.valid]).all()
    graph_table = process(paths["POS.txt"], paths["Kamera.txt"], flight_defaults.updated(method="graph")).table
    rts_table = process(paths["POS.txt"], paths["Kamera.txt"], flight_defaults).table
    assert list(graph_table["lat"].notna()) == list(rts_table["lat"].notna())
    assert graph_table["lat"].notna().all()


def test_graph_does_not_crash_on_a_short_tactical_flight_with_an_outage(tmp_path):
    """A reported reproducer: 20 s at 125 Hz, tactical FOG, a 10-s outage and a 10-m outlier made the marginals'
    Cholesky fail ("indeterminate system", exit 3). It runs now; the flight's heading is not observable, so its
    quality checks fail (exit 4), as they do for rts."""
    from georef_cli.main import app
    from typer.testing import CliRunner

    runner = CliRunner()
    folder = tmp_path / "repro"
    result = runner.invoke(app, ["simulate", str(folder), "--seed", "655725", "--duration", "20", "--rate", "125",
                                 "--camera-rate", "10", "--imu", "tactical-fog", "--outage", "6,10", "--outlier",
                                 "10,10", "-q"])
    assert result.exit_code == 0, result.output
    codes = {}
    for method in ("graph", "rts"):
        result = runner.invoke(app, ["process", str(folder / "POS.txt"), str(folder / "Kamera.txt"), "--config",
                                     str(folder / "flight.toml"), "--method", method, "-o",
                                     str(tmp_path / f"{method}.csv"), "-q"])
        codes[method] = result.exit_code
        assert "internal error" not in result.output
    assert codes == {"graph": 4, "rts": 4}


def test_graph_on_kitti_outages_with_ground_vehicle_constraints():
    """KITTI (a real car; the last 20 s of every minute of fixes withheld): with the non-holonomic factors and the
    EKF's process noise over the log's interpolated IMU dropouts, the graph's horizontal RMS at the withheld fixes
    is at most 1.0 m (0.88 m measured; 29.7 m without either). QC still fails it against the RTS: the free lever
    arm takes up the fixes' time-tag offset (0.5 m forward) and the attitudes differ by up to 31 of the graph's
    sigma after the longest run of interpolated IMU samples; the check must keep saying so."""
    from georef.config import GraphSettings, ProcessingConfig
    from georef.datasets.kitti import load_kitti, score_outages, subset, withheld
    from georef.fusion.graph import solve_graph_inputs
    from georef.fusion.ins import InsInputs
    from georef.qc import assess

    log = load_kitti()
    fixes = subset(log.gnss, ~withheld(log.gnss_time))
    nav = solve_graph_inputs(InsInputs(time=log.time, gyro=log.gyro, accel=log.accel, gnss=fixes),
                             GraphSettings.of(ProcessingConfig()))
    v = nav.valid
    score = score_outages(log, nav.time[v], np.degrees(nav.lat[v]), np.degrees(nav.lon[v]), nav.height[v],
                          np.sqrt(nav.pos_var_n[v, 0]), np.sqrt(nav.pos_var_n[v, 1]), 0)
    assert score.withheld > 100
    assert nav.diagnostics.ground_vehicle and nav.graph_info.nhc_factors >= 0.95 * nav.graph_info.keyframes
    assert score.fused_rms_m <= 1.0, score
    verdict = assess(nav)
    assert "graph vs rts" in [c.name for c in verdict.failures]


def test_nhc_factor_matches_the_constraint_it_linearises():
    """The linearised non-holonomic factor against the exact residual ``(R^T v)_y,z / sigma`` evaluated directly
    (numpy, no GTSAM) at a small perturbation ``R Exp(xi)``, ``v + dv``: agreement to second order."""
    import gtsam
    from gtsam.symbol_shorthand import V, X

    from georef.frames import euler_to_dcm
    from georef.frames.rotations import quat_to_dcm, rotvec_to_quat
    from georef.fusion.graph import _nhc_factor

    rng = np.random.default_rng(3)
    R = euler_to_dcm(0.05, -0.03, 2.0)
    v = np.array([-9.0, 4.0, 0.3])
    sigma = np.array([0.05, 0.08])
    factor = _nhc_factor(gtsam, X(0), V(0), gtsam.Pose3(gtsam.Rot3(R), np.zeros(3)), v, sigma)
    for _ in range(5):
        xi, dv = rng.normal(0.0, 1e-3, 3), rng.normal(0.0, 0.01, 3)
        R1 = R @ quat_to_dcm(rotvec_to_quat(xi))
        at = gtsam.Values()
        at.insert(X(0), gtsam.Pose3(gtsam.Rot3(R1), rng.normal(0.0, 5.0, 3)))  # translation plays no part
        at.insert(V(0), v + dv)
        exact = 0.5 * np.sum(((R1.T @ (v + dv))[1:] / sigma) ** 2)
        assert factor.error(at) == pytest.approx(exact, rel=1e-3, abs=1e-6)


def test_fuse_accepts_the_graph(tmp_path):
    from georef_cli.main import app
    from typer.testing import CliRunner

    runner = CliRunner()
    folder = tmp_path / "flight"
    assert runner.invoke(app, ["simulate", str(folder), "--duration", "90", "--generic", "-q"]).exit_code == 0
    result = runner.invoke(app, ["fuse", "--imu", str(folder / "imu.csv"), "--gnss", str(folder / "gnss.csv"),
                                 "--method", "graph", "-o", str(tmp_path / "traj.csv"), "-q"])
    assert result.exit_code in (0, 4), result.output
    import pandas as pd

    traj = pd.read_csv(tmp_path / "traj.csv")
    assert len(traj) > 0 and traj["lat"].notna().mean() > 0.9


def test_graph_process_imports_no_more_than_rts_plus_gtsam(tmp_path):
    """``georef process --method graph`` loads gtsam and nothing else that ``rts`` does not: the graph's lever-arm
    check once pulled in scipy.stats through the campaign module (1.4 s of import, half the graph's own cost on a
    15-minute flight)."""
    import subprocess
    import sys
    from pathlib import Path

    data = Path(__file__).resolve().parents[2] / "data"
    code = ("import sys\nfrom georef_cli.main import app\ntry:\n"
            f"    app(['process', {str(data / 'POS.txt')!r}, {str(data / 'Kamera.txt')!r}, '--config', "
            f"{str(data / 'flight.toml')!r}, '-q', '-o', {str(tmp_path / 'eo.csv')!r}, '--method', sys.argv[1]])\n"
            "except SystemExit as exc:\n    assert exc.code in (0, None, 4), exc.code\n"
            "print(' '.join(sorted(m for m in sys.modules if not m.startswith('_'))))\n")
    loaded = {}
    for method in ("rts", "graph"):
        run = subprocess.run([sys.executable, "-c", code, method], capture_output=True, text=True, timeout=120,
                             check=False)
        assert run.returncode == 0, run.stderr[-2000:]
        loaded[method] = set(run.stdout.split())
    extra = {name.split(".")[0] + ("." + name.split(".")[1] if "." in name else "")
             for name in loaded["graph"] - loaded["rts"]}
    assert "gtsam" in extra
    assert {name for name in extra if not name.startswith("gtsam") and not name.startswith("georef.")} == set(), extra

def test_graph_weighs_each_fix_by_its_own_sigma(tmp_path):
    """gnss.csv with its own sigma_n/e/u per fix: PPK fixes (2/2/4 cm) and, every other half minute, float fixes
    (0.5/0.5/1 m noise, their sigma columns saying so). The graph weighs each fix by its own sigma, as rts does:
    within 1.5 times rts's horizontal RMS and QC passes. (With one sigma for every fix it was 0.126 m against rts's
    0.034 m on seed 1, 3.7 times, and QC failed it.)"""
    import pandas as pd
    from georef_cli.main import app
    from typer.testing import CliRunner

    from georef.frames.earth import geodetic_to_ecef
    from georef.sim.files import write_generic

    flight = simulate(SimConfig(seed=1, gnss=GnssModel(sigma_neu_m=(0.02, 0.02, 0.04))))
    paths = write_generic(flight, tmp_path)
    gnss = pd.read_csv(paths["gnss.csv"])
    floating = ((gnss["time"] - gnss["time"].iloc[0]) % 60.0) >= 30.0
    noise = np.random.default_rng(1).standard_normal((int(floating.sum()), 3)) * [0.5, 0.5, 1.0]
    lat = np.radians(gnss["lat"].mean())
    gnss.loc[floating, "lat"] += np.degrees(noise[:, 0] / 6.371e6)
    gnss.loc[floating, "lon"] += np.degrees(noise[:, 1] / (6.371e6 * np.cos(lat)))
    gnss.loc[floating, "height"] += noise[:, 2]
    gnss.loc[floating, ["sigma_n", "sigma_e", "sigma_u"]] = [0.5, 0.5, 1.0]
    gnss.to_csv(tmp_path / "mixed.csv", index=False)
    truth = pd.read_csv(paths["truth_traj.csv"])
    rms = {}
    for method in ("rts", "graph"):
        result = CliRunner().invoke(app, [
            "fuse", "--imu", str(paths["imu.csv"]), "--gnss", str(tmp_path / "mixed.csv"), "--gnss-lever-arm",
            ",".join(str(v) for v in flight.config.lever_arm_gnss_m), "--gnss-sigma", "0.02,0.02,0.04",
            "--method", method, "-o", str(tmp_path / f"{method}.csv"), "-q"])
        assert result.exit_code == 0, result.output
        traj = pd.read_csv(tmp_path / f"{method}.csv").merge(truth, on="time", suffixes=("", "_true"))
        r_est = geodetic_to_ecef(np.radians(traj["lat"]), np.radians(traj["lon"]), traj["height"])
        r_true = geodetic_to_ecef(np.radians(traj["lat_true"]), np.radians(traj["lon_true"]), traj["height"])
        rms[method] = float(np.sqrt(np.mean(np.sum((r_est - r_true) ** 2, axis=1))))
    assert rms["graph"] <= 1.5 * rms["rts"], rms


def test_graph_estimates_the_lever_arm_it_is_not_told(flight_dir, flight_defaults):
    """The lever arm is a variable of the graph: not told (zeros, free prior), the estimate lands within 3 of its
    marginal sigmas of the simulated one on every axis; told with the default prior (0.05 m), it stays there and
    its sigma is no larger than the prior. (Coverage over many flights: docs/method-graph.md.)"""
    from georef.fusion.graph import solve_graph
    from georef.io.pos import read_pos

    flight, paths = flight_dir
    log = read_pos(paths["POS.txt"])
    truth = np.asarray(flight.config.lever_arm_gnss_m)
    free = solve_graph(log, flight_defaults.updated(lever_arm_gnss=(0.0, 0.0, 0.0)))
    estimate, sigma = free.graph_info.lever_arm_m, free.graph_info.lever_arm_sigma_m
    assert (sigma > 0.05).all() and (sigma < 2.0).all()
    assert (np.abs(estimate - truth) < 3.0 * sigma).all(), (estimate, sigma)
    told = solve_graph(log, flight_defaults)
    assert (np.abs(told.graph_info.lever_arm_m - truth) < 0.1).all()
    assert (told.graph_info.lever_arm_sigma_m <= 0.05 + 1e-9).all()


def test_graph_lever_arm_check_judges_the_data_against_the_given_lever_arm(flight_dir, flight_defaults):
    """``--method graph`` checks the lever arm with its own estimate: not given, the graph's estimate is applied and
    passes (the EKF's calibration pass, on the same data, agrees); given correctly, passes; given with z's sign
    flipped, the flight's data alone (the prior divided out) put the antenna elsewhere on z and the check fails
    naming z only, although the graph's applied lever arm sits at the configured one."""
    from georef.fusion.graph import solve_graph
    from georef.io.pos import read_pos
    from georef.qc import assess, check_lever_arm

    flight, paths = flight_dir
    log = read_pos(paths["POS.txt"])
    truth = np.asarray(flight.config.lever_arm_gnss_m)
    free = check_lever_arm(solve_graph(log, flight_defaults.updated(lever_arm_gnss=(0.0, 0.0, 0.0))))
    assert free.status == "pass", free
    assert free.message.startswith("no GNSS lever arm given: the graph estimated and applied") and \
        "in agreement" in free.message
    told = check_lever_arm(solve_graph(log, flight_defaults))
    assert told.status == "pass" and "agrees with the configured one" in told.message, told
    flipped = solve_graph(log, flight_defaults.updated(lever_arm_gnss=(truth[0], truth[1], -truth[2])))
    check = check_lever_arm(flipped)
    assert check.status == "fail", check
    assert "GNSS lever arm z (down)" in check.message and "lever arm x" not in check.message \
        and "lever arm y" not in check.message
    assert f"the configuration says {-truth[2]:.2f} +- 0.05 m" in check.message
    assert abs(flipped.graph_info.lever_arm_m[2] + truth[2]) < 0.1   # the prior held the applied one there
    assert not assess(flipped).passed


@pytest.mark.parametrize("seed", [1, 2])
def test_graph_vs_rts_check_fails_exactly_when_the_attitudes_depart(tmp_path, seed):
    """QC's ``graph vs rts`` compares attitudes as well as horizontal positions. On simulated 3-minute cars, the
    separation is computed here from the two EO tables (graph minus rts at the frames, in the graph's sigmas):
    the check fails exactly when more than 2 % of the frames lie beyond 3 sigma in a camera angle or in
    horizontal position. Measured: seeds 1 and 3 agree (at most 1.5 and 2.3 sigma), seeds 2, 4 and 5 depart in
    attitude only (81 %, 66 % and 81 % of the keyframes beyond 3 sigma; positions within 1.5 sigma)."""
    from georef.qc import GRAPH_SEPARATION_SHARE, GRAPH_SEPARATION_SIGMA, assess_result

    flight = simulate(SimConfig.for_vehicle("car", 180.0, seed=seed))
    paths = write_flight(flight, tmp_path / "car")
    cfg = processing_config_for(flight)
    result = process(paths["POS.txt"], paths["Kamera.txt"], cfg.updated(method="graph"))
    graph = result.table
    rts = process(paths["POS.txt"], paths["Kamera.txt"], cfg.updated(method="rts")).table
    difference = frame_errors(graph, rts)
    both = (graph["lat"].notna() & rts["lat"].notna()).to_numpy()
    angles = np.max([np.abs(difference[a]) / graph[f"sigma_{a}"] for a in ("roll", "pitch", "yaw")], axis=0)
    horizontal = np.hypot(difference["north"], difference["east"]) / np.hypot(graph["sigma_n"], graph["sigma_e"])
    shares = {what: float(np.mean(np.asarray(z)[both] > GRAPH_SEPARATION_SIGMA))
              for what, z in (("attitudes", angles), ("horizontal positions", horizontal))}
    check = [c for c in assess_result(result).checks if c.name == "graph vs rts"][0]
    departs = [what for what, share in shares.items() if share > GRAPH_SEPARATION_SHARE]
    assert (check.status == "fail") == bool(departs), (shares, check.message)
    assert "attitudes" in check.message and "horizontal positions" in check.message


@pytest.mark.parametrize("command", [
    # 21.6 s car, tactical FOG, 100 Hz, outliers: GTSAM's Cholesky marginals failed ("indeterminate system", exit 3)
    # on a positive-definite Hessian of condition 6e11; the marginals now come from a QR elimination
    ["simulate", "--vehicle", "car", "--duration", "21.6", "--rate", "100", "--seed", "226215", "--imu",
     "tactical-fog", "--outlier", "11.1,56", "--outlier", "1.4,51", "--outlier", "1.4,22.6"],
    # 56.1 s multicopter, 125 Hz, a 25-s outage and outliers, through georef fuse: the same failure
    ["simulate", "--vehicle", "multicopter", "--duration", "56.1", "--rate", "125", "--seed", "315983", "--imu",
     "mems-consumer", "--outage", "20,24.8", "--outlier", "37.9,34.8", "--outlier", "21.7,38.6", "--generic"],
])
def test_graph_marginals_survive_ill_conditioned_graphs(tmp_path, command):
    """Two crashes found by benchmarks/graph_property_sweep.py: both now write their outputs (exit 0 or 4)."""
    from georef_cli.main import app
    from typer.testing import CliRunner

    runner = CliRunner()
    folder = tmp_path / "flight"
    assert runner.invoke(app, [command[0], str(folder), *command[1:], "-q"]).exit_code == 0
    if "--generic" in command:
        args = ["fuse", "--imu", str(folder / "imu.csv"), "--gnss", str(folder / "gnss.csv"), "-o",
                str(tmp_path / "out.csv")]
    else:
        args = ["process", str(folder / "POS.txt"), str(folder / "Kamera.txt"), "--config",
                str(folder / "flight.toml"), "-o", str(tmp_path / "out.csv")]
    result = runner.invoke(app, [*args, "--method", "graph", "-q"])
    assert "internal error" not in result.output
    assert result.exit_code in (0, 4), result.output
    assert (tmp_path / "out.csv").exists()


def test_qr_marginals_equal_gtsams_cholesky_marginals(tmp_path):
    """The QR marginals against ``gtsam.Marginals`` (Cholesky) on a well-conditioned 60-s flight's graph."""
    import gtsam

    from georef.fusion import graph as graph_module
    from georef.fusion.graph import solve_graph
    from georef.io.pos import read_pos

    flight = simulate(SimConfig.for_vehicle("helicopter", 60.0, seed=2))
    paths = write_flight(flight, tmp_path)
    captured = {}
    qr = graph_module._QrMarginals

    def capture(gtsam_module, graph, result):
        captured.update(graph=graph, result=result)
        return qr(gtsam_module, graph, result)

    graph_module._QrMarginals = capture
    try:
        solve_graph(read_pos(paths["POS.txt"]), processing_config_for(flight))
    finally:
        graph_module._QrMarginals = qr
    ours = qr(gtsam, captured["graph"], captured["result"])
    theirs = gtsam.Marginals(captured["graph"], captured["result"])
    for key in (gtsam.symbol("x", 0), gtsam.symbol("x", 30), gtsam.symbol("v", 10), gtsam.symbol("b", 20),
                gtsam.symbol("c", 0)):
        a, b = ours.marginalCovariance(key), theirs.marginalCovariance(key)
        scale = np.sqrt(np.outer(np.diag(b), np.diag(b)))
        assert np.max(np.abs(a - b) / scale) < 1e-3, key


def test_qr_marginals_fall_back_to_qr_where_the_default_elimination_fails():
    """Where GTSAM's default (Cholesky) elimination of a clique's marginal throws, the marginal is taken with QR:
    a chain of two 3-vectors, x0 ~ N(0, diag(1, 4, 9)) and x1 - x0 ~ N(0, I), whose covariances are known."""
    import gtsam

    from georef.fusion.graph import _QrMarginals

    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorVector(0, np.zeros(3), gtsam.noiseModel.Diagonal.Sigmas(np.array([1.0, 2.0, 3.0]))))
    graph.add(gtsam.BetweenFactorVector(0, 1, np.zeros(3), gtsam.noiseModel.Unit.Create(3)))
    values = gtsam.Values()
    values.insert(0, np.zeros(3))
    values.insert(1, np.zeros(3))
    marginals = _QrMarginals(gtsam, graph, values)
    tree, calls = marginals._tree, []

    class FailingCholesky:
        def marginalFactor(self, key, *eliminate):  # noqa: N802
            calls.append(eliminate)
            if not eliminate:
                raise RuntimeError("Indeterminant linear system detected")
            return tree.marginalFactor(key, *eliminate)

    marginals._tree = FailingCholesky()
    np.testing.assert_allclose(marginals.marginalCovariance(1), np.diag([2.0, 5.0, 10.0]), rtol=1e-12)
    assert calls == [(), (gtsam.EliminateQR,)]


def test_compensated_rates_make_gtsams_preintegration_exact_for_a_constant_rotation():
    """A body turning at a constant 0.5 rad/s about x, with a constant specific force: the exact velocity change
    over 1 s in the starting frame is ``∫ Exp(ω t) f dt`` (Rodrigues, integrated in closed form). GTSAM's
    preintegration of the plain trapezoid rates misses it by ``½ ω × f dt`` per unit time (0.05 m/s here, 50
    Hz); of :func:`georef.fusion.increments.compensated_rates` only by the next term the strapdown leaves out
    too, ``⅙ |ω|² |f| dt`` per unit time (measured 1.6e-4 m/s)."""
    import gtsam

    from georef.fusion.increments import compensated_rates

    rate, span = 50.0, 1.0
    t = np.arange(0.0, span + 0.5 / rate, 1.0 / rate)
    omega = np.array([0.5, 0.0, 0.0])
    force = np.array([0.3, 1.0, -9.8])
    gyro, accel = np.tile(omega, (len(t), 1)), np.tile(force, (len(t), 1))
    w = np.linalg.norm(omega)
    K = np.array([[0.0, -omega[2], omega[1]], [omega[2], 0.0, -omega[0]], [-omega[1], omega[0], 0.0]]) / w
    exact = (span * np.eye(3) + (1.0 - np.cos(w * span)) / w * K + (span - np.sin(w * span) / w) * K @ K) @ force

    def preintegrated(a_steps, w_steps):
        pim = gtsam.PreintegratedImuMeasurements(gtsam.PreintegrationParams.MakeSharedD(0.0),
                                                 gtsam.imuBias.ConstantBias())
        for k in range(len(t) - 1):
            pim.integrateMeasurement(a_steps[k], w_steps[k], t[k + 1] - t[k])
        return pim.deltaVij()

    zero = np.zeros_like(gyro)
    plain = preintegrated(0.5 * (accel[:-1] + accel[1:]), 0.5 * (gyro[:-1] + gyro[1:]))
    compensated = preintegrated(*compensated_rates(t, gyro, accel, zero, zero))
    assert np.linalg.norm(plain - exact) > 0.04
    third_order = w**2 * np.linalg.norm(force) * span / rate / 6.0  # 1.64e-4 m/s
    assert np.linalg.norm(compensated - exact) < 1.1 * third_order


def _ppk_flight(tmp_path, duration, **sim_changes):
    """A helicopter survey with PPK-grade fixes (2/2/4 cm) and its configuration, read back from its files."""
    from dataclasses import replace

    from georef.io.pos import read_pos

    sim = SimConfig(seed=1, gnss=GnssModel(sigma_neu_m=(0.02, 0.02, 0.04)), **sim_changes)
    flight = simulate(replace(sim, plan=replace(sim.plan, duration_s=duration)))
    paths = write_flight(flight, tmp_path)
    return flight, read_pos(paths["POS.txt"]), processing_config_for(flight)


@pytest.mark.slow
def test_graph_fits_its_noise_with_the_lever_arm_the_data_show(tmp_path):
    """Lever arm not told: the EKF + RTS, applying zero, fits a horizontal GNSS variance several times the fixes'
    (6.4 on a 10-minute flight); the graph runs it again with the lever arm its robust pass found, so that the
    noise model it takes matches the fixes, and the quality checks still compare the data with the user's (zero)
    lever arm."""
    from georef.fusion.graph import solve_graph
    from georef.fusion.ins import inputs_from_pos, solve_ins

    flight, log, cfg = _ppk_flight(tmp_path, 180.0)
    untold = cfg.updated(lever_arm_gnss=(0.0, 0.0, 0.0))
    rts = solve_ins(inputs_from_pos(log), InsSettings.of(untold), smooth=True)
    first = rts.diagnostics.noise.r_scale_h
    assert first > 3.0
    graph = solve_graph(log, untold)
    assert graph.diagnostics.noise.r_scale_h < 1.5
    truth = np.asarray(flight.config.lever_arm_gnss_m)
    assert np.all(np.abs(graph.graph_info.noise_refit_lever_arm_m - truth) < 0.15)
    estimate, sigma = graph.graph_info.lever_arm_m, graph.graph_info.lever_arm_sigma_m
    assert np.all(np.abs(estimate - truth) < 3.0 * sigma), (estimate, sigma)
    np.testing.assert_array_equal(graph.diagnostics.lever_arm_given, 0.0)


@pytest.mark.slow
def test_graph_estimates_the_yaw_gyro_scale_factor_in_turns(tmp_path):
    """A yaw gyro reading 3000 ppm too much: the survey's turns make its scale factor observable (sigma well below
    the 2000-ppm prior; estimate within 3 sigma), and the other five, all zero, are estimated as zero within
    3 sigma: nothing invented."""
    from georef.fusion.graph import solve_graph

    _, log, cfg = _ppk_flight(tmp_path, 300.0, gyro_scale_ppm=(0.0, 0.0, 3000.0))
    scale = solve_graph(log, cfg.updated(method="graph", graph_scale_factor_sigma=0.002)).graph_info.scale_factors
    gyro, gyro_sigma = scale.gyro_ppm, scale.gyro_sigma_ppm
    assert gyro_sigma[2] < 500.0
    assert abs(gyro[2] - 3000.0) < 3.0 * gyro_sigma[2], (gyro, gyro_sigma)
    others = np.concatenate([scale.accel_ppm, gyro[:2]])
    others_sigma = np.concatenate([scale.accel_sigma_ppm, gyro_sigma[:2]])
    assert np.all(np.abs(others) < 3.0 * others_sigma), (others, others_sigma)


def test_bias_factor_is_the_random_walk_of_the_scaled_bias():
    """``_bias_factor``'s whitened error at any values is ``(B_b - B_a - diag(rate change) s) / sigma``, and without
    scale factors GTSAM's own between factor ``B_b - B_a``."""
    import gtsam

    from georef.fusion.graph import SCALE, _bias_factor

    rng = np.random.default_rng(3)
    sigma = np.array([1e-3, 2e-3, 3e-3, 1e-5, 2e-5, 3e-5])
    change = rng.normal(size=6) * [0.5, 0.5, 2.0, 0.1, 0.1, 0.3]
    at = gtsam.Values()
    at.insert(1, gtsam.imuBias.ConstantBias(rng.normal(size=3) * 0.01, rng.normal(size=3) * 1e-4))
    at.insert(2, gtsam.imuBias.ConstantBias(rng.normal(size=3) * 0.01, rng.normal(size=3) * 1e-4))
    at.insert(SCALE, rng.normal(size=6) * 1e-3)
    factor = _bias_factor(gtsam, 1, 2, np.diag(sigma**2), change, at)
    plain = _bias_factor(gtsam, 1, 2, np.diag(sigma**2), None, at)
    for _ in range(3):
        values = gtsam.Values()
        a, b = rng.normal(size=6) * 0.01, rng.normal(size=6) * 0.01
        scale = rng.normal(size=6) * 1e-3
        values.insert(1, gtsam.imuBias.ConstantBias(a[:3], a[3:]))
        values.insert(2, gtsam.imuBias.ConstantBias(b[:3], b[3:]))
        values.insert(SCALE, scale)
        expected = (b - a - change * scale) / sigma
        assert factor.error(values) == pytest.approx(0.5 * expected @ expected, rel=1e-9)
        walk = (b - a) / sigma
        assert plain.error(values) == pytest.approx(0.5 * walk @ walk, rel=1e-9)
