"""Full-state INS/GNSS fusion (``ekf``, ``rts``) against truth: accuracy, ordering, honesty, robustness.

Flights: like the foundation issue's (MEMS IMU with rotor vibration, 30 m/s, ~4 deg crab, GNSS sigma 1/1/2 m,
50 Hz, unknown and drifting unit yaw origin, lever arms and boresight), 3 minutes each.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from georef_cli.main import app
from typer.testing import CliRunner

from georef.evaluate import accuracy, frame_errors
from georef.pipeline import process
from georef.sim.files import processing_config_for, write_flight, write_generic
from georef.sim.flight import SimConfig, simulate
from georef.sim.sensors import GnssModel, UnitModel

MONTE_CARLO_SEEDS = range(1, 21)
METHODS = ("axis", "ekf", "rts")
FIGURES = ("horizontal_rms_m", "vertical_rms_m", "roll_rms_deg", "pitch_rms_deg", "yaw_rms_deg")
COMPONENTS = ("north", "east", "up", "roll", "pitch", "yaw")
SIGMAS = ("sigma_n", "sigma_e", "sigma_u", "sigma_roll", "sigma_pitch", "sigma_yaw")


def _run(folder, sim: SimConfig, methods=METHODS):
    flight = simulate(sim)
    paths = write_flight(flight, folder)
    results = {m: process(paths["POS.txt"], paths["Kamera.txt"], processing_config_for(flight).updated(method=m))
               for m in methods}
    return flight, results


@pytest.fixture(scope="module")
def monte_carlo(tmp_path_factory):
    """Twenty flights, all three methods: per-flight figures and normalised errors of rts."""
    rows, normalised = [], []
    for seed in MONTE_CARLO_SEEDS:
        flight, results = _run(tmp_path_factory.mktemp(f"mc{seed}"), SimConfig(seed=seed))
        for method, result in results.items():
            errors = frame_errors(result.table, flight.truth_frames)
            rows.append({"seed": seed, "method": method, **accuracy(errors)})
            if method == "rts":
                normalised.append(np.stack([errors[c] / result.table[s] for c, s in zip(COMPONENTS, SIGMAS,
                                                                                      strict=True)], -1))
    return pd.DataFrame(rows), np.concatenate(normalised)


def test_rts_meets_the_accuracy_targets_on_every_flight(monte_carlo):
    figures, _ = monte_carlo
    rts = figures[figures["method"] == "rts"]
    assert (rts["horizontal_rms_m"] <= 0.4).all()
    assert (rts["vertical_rms_m"] <= 0.7).all()
    assert (rts["roll_rms_deg"] <= 0.03).all()
    assert (rts["pitch_rms_deg"] <= 0.03).all()
    assert (rts["yaw_rms_deg"] <= 0.15).all()


def test_rts_beats_ekf_on_every_flight_and_figure(monte_carlo):
    figures, _ = monte_carlo
    wide = figures.pivot(index="seed", columns="method")
    for figure in FIGURES:
        assert (wide[figure]["rts"] < wide[figure]["ekf"]).all(), figure


def test_ekf_beats_axis_on_every_figure(monte_carlo):
    """On the Monte-Carlo RMS of every figure, and on every single flight for position and pitch."""
    figures, _ = monte_carlo
    mean = figures.groupby("method")[list(FIGURES)].mean()
    for figure in FIGURES:
        assert mean.loc["ekf", figure] < mean.loc["axis", figure], figure
    wide = figures.pivot(index="seed", columns="method")
    for figure in ("horizontal_rms_m", "vertical_rms_m", "pitch_rms_deg"):
        assert (wide[figure]["ekf"] < wide[figure]["axis"]).all(), figure


@pytest.mark.xfail(strict=True, reason="known limit: per flight, the forward EKF's yaw beats the axis method's on only "
                                       "about half the flights; the axis method fits its yaw offset to the whole "
                                       "flight (non-causal), which a forward filter cannot")
def test_ekf_beats_axis_in_yaw_on_every_flight(monte_carlo):
    figures, _ = monte_carlo
    wide = figures.pivot(index="seed", columns="method")["yaw_rms_deg"]
    assert (wide["ekf"] < wide["axis"]).all()


@pytest.mark.parametrize("component", COMPONENTS)
def test_rts_sigmas_are_honest(monte_carlo, component):
    """Share of frames whose error lies inside 2 sigma: between 90 % and 98 %; NEES-like rms(z) near 1."""
    _, normalised = monte_carlo
    z = normalised[:, COMPONENTS.index(component)]
    share = float(np.mean(np.abs(z) <= 2.0))
    assert 0.90 <= share <= 0.98, share
    assert 0.75 <= float(np.sqrt(np.mean(z**2))) <= 1.25


@pytest.fixture(scope="module")
def outage_flights(tmp_path_factory):
    out = []
    for seed in range(1, 11):
        sim = SimConfig(seed=seed, gnss=GnssModel(outages=[(80.0, 40.0)],
                                                  outliers=[(30.0, 25.0), (55.0, 40.0), (140.0, 20.0)]))
        flight, results = _run(tmp_path_factory.mktemp(f"outage{seed}"), sim, methods=("rts",))
        out.append((sim, flight, results["rts"]))
    return out


def test_outliers_are_rejected_and_named(outage_flights):
    for sim, _, result in outage_flights:
        gnss = result.nav.gnss
        rejected_times = gnss.time[gnss.status == 0] - sim.start_utc_s
        np.testing.assert_allclose(np.sort(rejected_times), [30.0, 55.0, 140.0])
        assert len(result.summary()["gnss_rejected_lines"]) == 3


def test_outage_frames_are_flagged_and_inside_their_sigma(outage_flights):
    normalised = []
    for sim, flight, result in outage_flights:
        table = result.table
        t_rel = table["time"] - sim.start_utc_s
        in_outage = table["flag"].str.contains("GNSS outage")
        # every frame strictly between the last fix before and the first fix after the outage is flagged
        assert in_outage[(t_rel > 80.5) & (t_rel < 119.5)].all()
        assert not in_outage[(t_rel < 78.0) | (t_rel > 122.0)].any()
        errors = frame_errors(table, flight.truth_frames)[in_outage.to_numpy()]
        sub = table[in_outage]
        normalised.append(np.stack([errors[c].to_numpy() / sub[s].to_numpy()
                                    for c, s in zip(COMPONENTS, SIGMAS, strict=True)], -1))
        assert np.hypot(errors["north"], errors["east"]).max() < 1.5  # the INS bridges 40 s
    z = np.abs(np.concatenate(normalised))
    share = (z <= 2.0).mean(axis=0)
    assert (share >= 0.90).all(), dict(zip(COMPONENTS, share.round(3), strict=True))
    assert (z <= 4.0).all()


@pytest.mark.parametrize("offset_deg", [-180.0, -135.0, -90.0, -45.0, 0.0, 45.0, 90.0, 135.0, 179.0])
def test_alignment_from_any_initial_yaw(tmp_path, offset_deg):
    flight, results = _run(tmp_path, SimConfig(seed=12, unit=UnitModel(yaw_offset_deg=offset_deg)),
                           methods=("rts",))
    figures = accuracy(frame_errors(results["rts"].table, flight.truth_frames))
    assert figures["yaw_rms_deg"] <= 0.15
    assert figures["horizontal_rms_m"] <= 0.4


def test_fuse_generic_files_with_heading_from_the_track(tmp_path):
    """No unit attitude at all: heading from the GNSS track (off by the ~4 deg crab), refined by the filter."""
    flight = simulate(SimConfig(seed=3))
    paths = write_generic(flight, tmp_path)
    runner = CliRunner()
    result = runner.invoke(app, ["fuse", "--imu", str(paths["imu.csv"]), "--gnss", str(paths["gnss.csv"]),
                                 "--gnss-lever-arm", "0.45,0.15,-1.65", "-o", str(tmp_path / "traj.csv")])
    assert result.exit_code == 0, result.output
    assert "GNSS track" in result.output
    traj = pd.read_csv(tmp_path / "traj.csv")
    truth = pd.read_csv(paths["truth_traj.csv"])
    truth = truth[truth["time"].isin(traj["time"])].reset_index(drop=True)
    assert len(truth) == len(traj) > 0.95 * len(flight.truth_nav.time)
    for column in ("vn", "ve", "vd", "sigma_n", "sigma_vn", "sigma_yaw"):
        assert column in traj.columns
    traj["frame"] = truth["frame"] = 0
    figures = accuracy(frame_errors(traj, truth))
    assert figures["horizontal_rms_m"] <= 0.4
    assert figures["roll_rms_deg"] <= 0.03 and figures["pitch_rms_deg"] <= 0.03
    assert figures["yaw_rms_deg"] <= 0.15
    assert np.sqrt(np.mean((traj["vn"] - truth["vn"]) ** 2)) < 0.1


def test_ekf_and_rts_are_deterministic(tmp_path):
    _, first = _run(tmp_path / "a", SimConfig(seed=5), methods=("rts",))
    _, second = _run(tmp_path / "b", SimConfig(seed=5), methods=("rts",))
    np.testing.assert_array_equal(first["rts"].table.drop(columns="flag").to_numpy(float),
                                  second["rts"].table.drop(columns="flag").to_numpy(float))


def test_attitude_source_imu_ignores_the_units_angles(tmp_path):
    """--attitude-source imu: the unit's ROLL/PITCH are replaced by the raw-IMU MEKF's and not fused by rts."""
    flight = simulate(SimConfig(seed=2))
    paths = write_flight(flight, tmp_path)
    cfg = processing_config_for(flight).updated(method="rts", attitude_source="imu")
    result = process(paths["POS.txt"], paths["Kamera.txt"], cfg)
    assert result.nav.info["unit_aiding"] is False
    assert any("recomputed from the raw IMU" in str(n) for n in result.notices)
    figures = accuracy(frame_errors(result.table, flight.truth_frames))
    assert figures["roll_rms_deg"] <= 0.03 and figures["pitch_rms_deg"] <= 0.03
    assert figures["horizontal_rms_m"] <= 0.4


@pytest.mark.parametrize("case", ["midnight", "no_unit_attitude", "consumer_imu"])
def test_rts_edge_cases(tmp_path, case):
    """Across midnight; a POS log without the unit's attitude (levelling + GNSS-track heading); a consumer IMU."""
    sim = SimConfig(seed=3, start_utc_s=86400 - 60 if case == "midnight" else 24513,
                    imu_preset="mems-consumer" if case == "consumer_imu" else "mems-ivru")
    flight = simulate(sim)
    paths = write_flight(flight, tmp_path)
    if case == "no_unit_attitude":
        frame = pd.read_csv(paths["POS.txt"], sep="\t", dtype=str)
        frame.drop(columns=["IACC_X", "IACC_Y", "IACC_Z", "ROLL", "PITCH", "YAW"]).to_csv(paths["POS.txt"], sep="\t",
                                                                                         index=False)
    result = process(paths["POS.txt"], paths["Kamera.txt"], processing_config_for(flight).updated(method="rts"))
    figures = accuracy(frame_errors(result.table, flight.truth_frames))
    assert result.table["lat"].notna().all()
    assert figures["horizontal_rms_m"] <= 0.4 and figures["yaw_rms_deg"] <= 0.15
    assert figures["roll_rms_deg"] <= 0.03 and figures["pitch_rms_deg"] <= 0.03
    if case == "midnight":
        assert result.table["time"].max() > 86400.0
        assert any("midnight" in str(n) for n in result.notices)
    if case == "no_unit_attitude":
        assert result.nav.info["heading_source"] == "GNSS track"
