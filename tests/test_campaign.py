"""Campaign calibration (georef/campaign.py, ``batch --shared-calibration``): the combination against the joint
linear-Gaussian solution, the chi-square flag's false-alarm rate and power, and the command end to end."""

from __future__ import annotations

import json

import numpy as np
import pytest

from georef.campaign import CONSISTENCY_P, FlightReduction, combine, leave_one_out

PRIOR_MEAN = np.zeros(4)
PRIOR_COV = np.diag([10.0, 10.0, 10.0, 0.002]) ** 2  # a free lever arm, the default time-offset prior


def _flight(rng: np.random.Generator, truth: np.ndarray, scale: float = 1.0):
    """A flight's data about the calibration: information L (SPD, sigmas a few cm / ms, correlated) and the
    data estimate drawn from N(truth, L^-1); returned as the posterior with the configured prior, as the graph
    reports it."""
    A = rng.standard_normal((4, 4)) * np.array([0.004, 0.004, 0.004, 0.0005]) * scale
    covariance = A @ A.T + np.diag([0.012, 0.012, 0.012, 0.001]) ** 2 * scale**2  # sigmas about 1.5 cm, 1.1 ms
    information = np.linalg.inv(covariance)
    estimate = rng.multivariate_normal(truth, covariance)
    post_info = information + np.linalg.inv(PRIOR_COV)
    post_cov = np.linalg.inv(post_info)
    post_mean = post_cov @ (information @ estimate + np.linalg.inv(PRIOR_COV) @ PRIOR_MEAN)
    return FlightReduction(post_mean, post_cov, PRIOR_MEAN, PRIOR_COV), information, estimate


def test_combination_is_the_joint_solution_and_each_flight_resolves_to_it():
    rng = np.random.default_rng(7)
    truth = np.array([0.45, 0.15, -1.65, 0.0])
    flights = {f"f{i}": _flight(rng, truth) for i in range(6)}
    reductions = {name: item[0] for name, item in flights.items()}
    estimate = combine(reductions, {name: (PRIOR_MEAN, PRIOR_COV) for name in flights})
    # joint: every flight's data once, the shared prior once
    joint_info = np.linalg.inv(PRIOR_COV) + sum(item[1] for item in flights.values())
    joint_cov = np.linalg.inv(joint_info)
    joint_mean = joint_cov @ (np.linalg.inv(PRIOR_COV) @ PRIOR_MEAN + sum(i @ e for _, i, e in flights.values()))
    np.testing.assert_allclose(estimate.mean, joint_mean, atol=1e-9)
    np.testing.assert_allclose(estimate.covariance, joint_cov, rtol=1e-6, atol=1e-14)
    assert all(flight["consistent"] for flight in estimate.flights.values())
    # a flight's own data estimate is recovered from its posterior
    for name, (_, _, data_estimate) in flights.items():
        np.testing.assert_allclose(
            np.r_[estimate.flights[name]["gnss_lever_arm_m"], estimate.flights[name]["gnss_time_offset_s"]],
            data_estimate, atol=1e-8)
    # re-solving a flight with its leave-one-out prior gives the campaign estimate back
    name = "f3"
    loo_mean, loo_cov = leave_one_out(estimate, reductions, name)
    _, own_info, own_estimate = flights[name]
    info = np.linalg.inv(loo_cov) + own_info
    resolved = np.linalg.solve(info, np.linalg.inv(loo_cov) @ loo_mean + own_info @ own_estimate)
    np.testing.assert_allclose(resolved, estimate.mean, atol=1e-9)


def test_data_share_says_when_the_campaign_value_is_the_prior():
    """Sixteen flights whose data observe the calibration remove most of the priors' variance; flights whose
    data are a hundred times weaker than a taped prior (5 cm, 2 ms) leave it, and calibration.toml says so."""
    rng = np.random.default_rng(3)
    truth = np.array([0.45, 0.15, -1.65, 0.0])
    strong = {f"f{i}": _flight(rng, truth)[0] for i in range(16)}
    estimate = combine(strong, {name: (PRIOR_MEAN, PRIOR_COV) for name in strong})
    assert np.all(estimate.data_share() > 0.7), estimate.data_share()
    assert "barely observed" not in estimate.config_toml()
    taped = (truth, np.diag([0.05, 0.05, 0.05, 0.002]) ** 2)
    weak = {}
    for i in range(3):
        A = rng.standard_normal((4, 4)) * np.array([0.4, 0.4, 0.4, 0.05])
        information = np.linalg.inv(A @ A.T + np.diag([1.0, 1.0, 1.0, 0.1]) ** 2)  # sigmas ~1 m, 0.1 s
        post_cov = np.linalg.inv(information + np.linalg.inv(taped[1]))
        weak[f"w{i}"] = FlightReduction(truth.copy(), post_cov, *taped)
    estimate = combine(weak, {name: taped for name in weak})
    share = estimate.data_share()
    assert np.all(share < 0.05), share
    assert "barely observed: lever arm x, lever arm y, lever arm z, time offset (their" in estimate.config_toml()
    assert estimate.to_json()["data_share"] == pytest.approx(list(share))


def test_configured_priors_count_once_per_distinct_prior():
    rng = np.random.default_rng(3)
    truth = np.array([0.45, 0.15, -1.65, 0.0])
    taped = (np.array([0.40, 0.10, -1.60, 0.0]), np.diag([0.05, 0.05, 0.05, 0.002]) ** 2)
    flights = {f"f{i}": _flight(rng, truth) for i in range(4)}
    reductions = {}
    for name, (_, information, data_estimate) in flights.items():
        post_info = information + np.linalg.inv(taped[1])
        post_cov = np.linalg.inv(post_info)
        post_mean = post_cov @ (information @ data_estimate + np.linalg.inv(taped[1]) @ taped[0])
        reductions[name] = FlightReduction(post_mean, post_cov, *taped)
    estimate = combine(reductions, {name: taped for name in flights})
    joint_info = np.linalg.inv(taped[1]) + sum(item[1] for item in flights.values())
    np.testing.assert_allclose(estimate.covariance, np.linalg.inv(joint_info), rtol=1e-6, atol=1e-14)


def test_chi_square_flag_false_alarms_and_a_moved_antenna():
    """Unchanged installations: flights flagged at about the test's level; a flight whose antenna moved by about
    seven of its sigmas (10 cm at 1.5 cm) along y is flagged and left out, and no more than one other flight with
    it."""
    rng = np.random.default_rng(11)
    truth = np.array([0.45, 0.15, -1.65, 0.0])
    flagged = trials = 0
    for _ in range(300):
        flights = {f"f{i}": _flight(rng, truth)[0] for i in range(8)}
        estimate = combine(flights, {name: (PRIOR_MEAN, PRIOR_COV) for name in flights})
        flagged += sum(not f["consistent"] for f in estimate.flights.values())
        trials += len(flights)
    assert flagged / trials <= 5 * CONSISTENCY_P
    caught = 0
    for _ in range(50):
        flights = {f"f{i}": _flight(rng, truth)[0] for i in range(7)}
        moved = truth + np.array([0.0, 0.10, 0.0, 0.0])
        flights["moved"] = _flight(rng, moved)[0]
        estimate = combine(flights, {name: (PRIOR_MEAN, PRIOR_COV) for name in flights})
        caught += not estimate.flights["moved"]["consistent"]
        assert sum(not f["consistent"] for name, f in estimate.flights.items() if name != "moved") <= 1
    assert caught >= 45


@pytest.mark.parametrize("method", ["rts", None])
def test_shared_calibration_needs_the_graph(tmp_path, method):
    from georef_cli.main import app
    from typer.testing import CliRunner

    (tmp_path / "flights" / "a").mkdir(parents=True)
    args = ["batch", str(tmp_path / "flights"), "--shared-calibration", "-o", str(tmp_path / "out"), "-q"]
    result = CliRunner().invoke(app, args + (["--method", method] if method else []))
    assert result.exit_code == 2
    assert "--method graph" in result.output


@pytest.mark.slow  # three flights on a dask LocalCluster: about 20 s
def test_batch_shared_calibration_end_to_end(tmp_path):
    """Three short flights of one installation (the lever arm not told) on a LocalCluster: calibration.json as
    the docs specify, every flight consistent, the campaign sigma below each flight's, and calibration.toml
    fed back with --config."""
    from dataclasses import replace

    from georef_cli.main import app
    from typer.testing import CliRunner

    from georef.config import config_to_toml, load_configs
    from georef.sim.files import processing_config_for, write_flight
    from georef.sim.flight import SimConfig, simulate
    from georef.sim.sensors import GnssModel

    for seed in (1, 2, 3):
        sim = SimConfig(seed=seed, gnss=GnssModel(sigma_neu_m=(0.02, 0.02, 0.04)))
        flight = simulate(replace(sim, plan=replace(sim.plan, duration_s=90.0)))
        folder = tmp_path / "flights" / f"f{seed}"
        write_flight(flight, folder)
        cfg = processing_config_for(flight).updated(lever_arm_gnss=(0.0, 0.0, 0.0), gnss_sigma=(0.02, 0.02, 0.04))
        (folder / "flight.toml").write_text(config_to_toml(cfg), encoding="utf-8")
    out = tmp_path / "out"
    runner = CliRunner()
    result = runner.invoke(app, ["batch", str(tmp_path / "flights"), "--method", "graph", "--shared-calibration",
                                 "-o", str(out), "-q"])
    assert result.exit_code in (0, 4), result.output
    assert "campaign calibration" not in result.output  # no flight flagged
    document = json.loads((out / "calibration.json").read_text())
    for key in ("gnss_lever_arm_m", "gnss_lever_arm_sigma_m"):
        assert len(document[key]) == 3
    for key in ("gnss_time_offset_s", "gnss_time_offset_sigma_s"):
        assert isinstance(document[key], float)
    assert set(document["flights"]) == {"f1", "f2", "f3"}
    truth = np.array([0.45, 0.15, -1.65])
    campaign_sigma = np.array(document["gnss_lever_arm_sigma_m"])
    assert np.all(np.abs(np.array(document["gnss_lever_arm_m"]) - truth) <= 3 * campaign_sigma)
    for flight in document["flights"].values():
        assert flight["consistent"] is True
        assert set(flight) >= {"gnss_lever_arm_m", "gnss_lever_arm_sigma_m", "gnss_time_offset_s",
                               "gnss_time_offset_sigma_s", "consistent"}
        assert np.all(campaign_sigma < np.array(flight["gnss_lever_arm_sigma_m"]))
    for name in ("f1", "f2", "f3"):
        assert (out / name / "eo.csv").exists()
    # fed back: flight.toml, then the campaign's calibration.toml
    cfg = load_configs([tmp_path / "flights" / "f1" / "flight.toml", out / "calibration.toml"])
    np.testing.assert_allclose(cfg.mounting.lever_arm_gnss, document["gnss_lever_arm_m"], atol=1e-4)
    assert cfg.gnss.latency == pytest.approx(document["gnss_time_offset_s"], abs=1e-5)
    result = runner.invoke(app, ["process", str(tmp_path / "flights" / "f1" / "POS.txt"),
                                 str(tmp_path / "flights" / "f1" / "Kamera.txt"), "--config",
                                 str(tmp_path / "flights" / "f1" / "flight.toml"), "--config",
                                 str(out / "calibration.toml"), "--method", "graph", "-o", str(tmp_path / "eo.csv"),
                                 "-q"])
    assert result.exit_code in (0, 4), result.output
