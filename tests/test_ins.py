"""Full-state INS/GNSS fusion (``rts``, ``ekf``) with the defaults, against truth: honesty over twenty flights of
each vibration kind, accuracy against the code before the rewrite, outages and outliers, alignment from any
unit yaw origin, edge cases.

Every run here uses :func:`georef.sim.files.installation_config`: the lever arms, the boresight and the GNSS
rate, nothing else. The IMU preset, the GNSS sigmas and the unit's errors stay at the defaults whatever the
simulator drew (no tuning to the simulator).
"""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
from georef_cli.main import app
from shared_runs import computed_once
from typer.testing import CliRunner

from georef.evaluate import accuracy, frame_errors
from georef.pipeline import process
from georef.sim.files import installation_config, write_flight, write_generic
from georef.sim.flight import SimConfig, simulate
from georef.sim.sensors import GnssModel, UnitModel, VibrationModel

SEEDS = range(1, 21)
#: white and narrow-band vibration at three levels (x the kind's reference RMS), cycled over the seeds
LEVELS = (0.5, 1.0, 2.0)
KINDS = ("rotor", "none", "white", "narrowband")
FIGURES = ("horizontal_rms_m", "vertical_rms_m", "roll_rms_deg", "pitch_rms_deg", "yaw_rms_deg")
COMPONENTS = ("north", "east", "up", "roll", "pitch", "yaw")
SIGMAS = ("sigma_n", "sigma_e", "sigma_u", "sigma_roll", "sigma_pitch", "sigma_yaw")
BEFORE = Path(__file__).parent / "data" / "todays_flights_before.json"


#: (kind, component) whose sigmas are measured too large (over 98 % of errors inside 2 sigma), never too small
PESSIMISTIC = {
    ("rotor", "yaw"): "0.9870 measured 2026-11-26 (0.967 before): every pass keeps the alignment's prior mean, and "
                      "the unit's yaw drift may change at 0.2 deg/min per sqrt(min) (0.05 before), what two-minute "
                      "flights need; this simulator's unit drifts at a constant rate, so its sigma is spare here",
    ("none", "yaw"): "0.9893 measured 2026-11-26 (0.963 before), for the same two reasons",
}


def sim_of(kind: str, seed: int) -> SimConfig:
    """``rotor``: today's flights (``SimConfig(seed)``: MEMS unit, rotor vibration); the other kinds at three
    levels."""
    if kind == "rotor":
        return SimConfig(seed=seed)
    vibration = None if kind == "none" else VibrationModel.of_kind(kind, LEVELS[seed % len(LEVELS)])
    return SimConfig(seed=seed, vibration=vibration)


def _run(folder, sim: SimConfig, methods=("rts",)):
    flight = simulate(sim)
    paths = write_flight(flight, folder)
    cfg = installation_config(flight)
    return flight, {m: process(paths["POS.txt"], paths["Kamera.txt"], cfg.updated(method=m)) for m in methods}


def _normalised(errors: pd.DataFrame, table: pd.DataFrame) -> np.ndarray:
    return np.stack([errors[c].to_numpy() / table[s].to_numpy() for c, s in zip(COMPONENTS, SIGMAS, strict=True)],
                    -1)


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    """Twenty flights of each vibration kind with rts (today's flights with ekf too): per-flight figures and the
    errors normalised by their sigmas. Each flight is run by one xdist worker only (``shared_runs``)."""

    def one(key: str) -> tuple[list[dict], np.ndarray]:
        kind, seed = key.split("-")[0], int(key.split("-")[1])
        methods = ("rts", "ekf") if kind == "rotor" else ("rts",)
        flight, results = _run(tmp_path_factory.mktemp(key), sim_of(kind, seed), methods)
        figures, normalised = [], None
        for method, result in results.items():
            errors = frame_errors(result.table, flight.truth_frames)
            figures.append({"kind": kind, "seed": seed, "method": method, **accuracy(errors)})
            if method == "rts":
                normalised = _normalised(errors, result.table)
        return figures, normalised

    keys = [f"{kind}-{seed}" for kind in KINDS for seed in SEEDS]
    runs = computed_once(tmp_path_factory, "ins-honesty", keys, one)
    figures = [row for key in keys for row in runs[key][0]]
    normalised = {kind: np.concatenate([runs[f"{kind}-{seed}"][1] for seed in SEEDS]) for kind in KINDS}
    return pd.DataFrame(figures), normalised


@pytest.mark.slow  # the Monte-Carlo fixture: eighty simulated flights
@pytest.mark.parametrize("component", COMPONENTS)
@pytest.mark.parametrize("kind", KINDS)
def test_sigmas_are_honest_for_every_vibration_kind(flights, kind, component):
    """The target: 90-98 % of the frames' errors inside +-2 sigma, per component, pooled over 20
    flights of the kind."""
    z = flights[1][kind][:, COMPONENTS.index(component)]
    share = float(np.mean(np.abs(z) <= 2.0))
    assert share >= 0.90, share
    if share > 0.98 and (kind, component) in PESSIMISTIC:
        pytest.xfail(f"known shortfall, on the safe side: {share:.4f} inside 2 sigma; {PESSIMISTIC[kind, component]}")
    assert share <= 0.98, share


@pytest.mark.slow  # the Monte-Carlo fixture: eighty simulated flights
def test_normalised_errors_on_todays_flights(flights):
    """NEES-like: the RMS of error / sigma near 1 for every component on today's flights."""
    z = flights[1]["rotor"]
    rms = np.sqrt(np.mean(z**2, axis=0))
    assert ((rms >= 0.75) & (rms <= 1.25)).all(), dict(zip(COMPONENTS, rms.round(2), strict=True))


@pytest.mark.slow  # the Monte-Carlo fixture: eighty simulated flights
def test_todays_flights_meet_the_accuracy_targets(flights):
    rts = flights[0].query("kind == 'rotor' and method == 'rts'")
    assert (rts["horizontal_rms_m"] <= 0.4).all()
    assert (rts["vertical_rms_m"] <= 0.7).all()
    assert (rts["roll_rms_deg"] <= 0.03).all()
    assert (rts["pitch_rms_deg"] <= 0.03).all()
    assert (rts["yaw_rms_deg"] <= 0.15).all()


@pytest.mark.slow  # the Monte-Carlo fixture: eighty simulated flights
def test_no_worse_than_before(flights):
    """Today's flights against the code before the rewrite (tests/data/todays_flights_before.json): for every
    figure, the mean per-flight difference new - before is not significantly positive (under two standard
    errors of the paired differences)."""
    before = json.loads(BEFORE.read_text())["flights"]
    rts = flights[0].query("kind == 'rotor' and method == 'rts'").set_index("seed")
    for figure in FIGURES:
        difference = np.array([rts.loc[seed, figure] - before[str(seed)][figure] for seed in SEEDS])
        standard_error = difference.std(ddof=1) / np.sqrt(len(difference))
        assert difference.mean() <= 2.0 * standard_error, (figure, difference.mean(), standard_error)


@pytest.mark.slow  # the Monte-Carlo fixture: eighty simulated flights
def test_rts_beats_ekf(flights):
    """The smoother beats the forward filter on the mean of every figure and on position on every flight."""
    wide = flights[0].query("kind == 'rotor'").pivot(index="seed", columns="method")
    for figure in FIGURES:
        assert wide[figure]["rts"].mean() < wide[figure]["ekf"].mean(), figure
    for figure in ("horizontal_rms_m", "vertical_rms_m"):
        assert (wide[figure]["rts"] < wide[figure]["ekf"]).all(), figure


@pytest.mark.slow  # the Monte-Carlo fixture: eighty simulated flights
def test_vibration_costs_accuracy_but_stays_within_targets(flights):
    """White vibration at twice the reference level is the hardest case; even there every flight stays within
    metre-level position and sub-degree attitude, and the mean is worse than without vibration."""
    rts = flights[0].query("method == 'rts'")
    white = rts[rts["kind"] == "white"]
    none = rts[rts["kind"] == "none"]
    assert (white["horizontal_rms_m"] <= 0.6).all() and (white["vertical_rms_m"] <= 1.0).all()
    assert (white["yaw_rms_deg"] <= 0.5).all()
    assert white["horizontal_rms_m"].mean() > none["horizontal_rms_m"].mean()


@pytest.fixture(scope="module")
def outage_flights(tmp_path_factory):
    """Ten of today's flights with a 40-s outage and three outliers, rts; each run by one xdist worker only. Per
    flight what the tests read of it: the simulation's start [UTC s of day], the EO table, the truth at the
    frames, every GNSS fix's time [UTC s of day] and status, the lines the summary names as rejected."""

    def one(key: str) -> SimpleNamespace:
        sim = SimConfig(seed=int(key), gnss=GnssModel(outages=[(80.0, 40.0)],
                                                      outliers=[(30.0, 25.0), (55.0, 40.0), (140.0, 20.0)]))
        flight, results = _run(tmp_path_factory.mktemp(f"outage{key}"), sim)
        result = results["rts"]
        return SimpleNamespace(start_utc_s=sim.start_utc_s, table=result.table, truth_frames=flight.truth_frames,
                               gnss_time=result.nav.gnss.time, gnss_status=result.nav.gnss.status,
                               rejected_lines=list(result.summary()["gnss_rejected_lines"]))

    keys = [str(seed) for seed in range(1, 11)]
    return list(computed_once(tmp_path_factory, "ins-outages", keys, one).values())


@pytest.mark.slow  # the outage fixture: ten simulated flights
def test_outliers_are_rejected_and_named(outage_flights):
    for run in outage_flights:
        rejected_times = run.gnss_time[run.gnss_status == 0] - run.start_utc_s
        np.testing.assert_allclose(np.sort(rejected_times), [30.0, 55.0, 140.0])
        assert len(run.rejected_lines) == 3


@pytest.mark.slow  # the outage fixture: ten simulated flights
def test_outage_frames_are_flagged_and_inside_their_sigma(outage_flights):
    normalised = []
    for run in outage_flights:
        table = run.table
        t_rel = table["time"] - run.start_utc_s
        in_outage = table["flag"].str.contains("GNSS outage")
        # every frame strictly between the last fix before and the first fix after the outage is flagged
        assert in_outage[(t_rel > 80.5) & (t_rel < 119.5)].all()
        assert not in_outage[(t_rel < 78.0) | (t_rel > 122.0)].any()
        errors = frame_errors(table, run.truth_frames)[in_outage.to_numpy()]
        normalised.append(_normalised(errors, table[in_outage]))
        assert np.hypot(errors["north"], errors["east"]).max() < 1.5  # the INS bridges 40 s
    z = np.abs(np.concatenate(normalised))
    share = dict(zip(COMPONENTS, (z <= 2.0).mean(axis=0).round(3), strict=True))
    assert all(share[c] >= 0.90 for c in COMPONENTS if c != "pitch"), share
    assert (z <= 4.0).all()


@pytest.mark.slow  # the outage fixture: ten simulated flights
def test_outage_pitch_inside_its_sigma(outage_flights):
    normalised = []
    for run in outage_flights:
        table = run.table
        in_outage = table["flag"].str.contains("GNSS outage").to_numpy()
        errors = frame_errors(table, run.truth_frames)[in_outage]
        normalised.append(errors["pitch"].to_numpy() / table["sigma_pitch"].to_numpy()[in_outage])
    share = np.mean(np.abs(np.concatenate(normalised)) <= 2.0)
    assert share >= 0.90, f"pitch inside 2 sigma in the outages: {share:.3f}"


@pytest.mark.parametrize("offset_deg", [-180.0, -135.0, -90.0, -45.0, 0.0, 45.0, 90.0, 135.0, 179.0])
def test_alignment_from_any_unit_yaw_origin(tmp_path, offset_deg):
    flight, results = _run(tmp_path, SimConfig(seed=12, unit=UnitModel(yaw_offset_deg=offset_deg)))
    figures = accuracy(frame_errors(results["rts"].table, flight.truth_frames))
    assert figures["yaw_rms_deg"] <= 0.15
    assert figures["horizontal_rms_m"] <= 0.4


def test_fuse_generic_files_aligns_from_the_motion(tmp_path):
    """No unit attitude at all: the heading comes from the motion (not the track, ~4 deg of crab away)."""
    flight = simulate(SimConfig(seed=3))
    paths = write_generic(flight, tmp_path)
    runner = CliRunner()
    result = runner.invoke(app, ["fuse", "--imu", str(paths["imu.csv"]), "--gnss", str(paths["gnss.csv"]),
                                 "--gnss-lever-arm", "0.45,0.15,-1.65", "-o", str(tmp_path / "traj.csv")])
    assert result.exit_code == 0, result.output
    assert "optimisation-based alignment" in result.output
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


def test_rts_is_deterministic(tmp_path):
    _, first = _run(tmp_path / "a", SimConfig(seed=5))
    _, second = _run(tmp_path / "b", SimConfig(seed=5))
    np.testing.assert_array_equal(first["rts"].table.drop(columns="flag").to_numpy(float),
                                  second["rts"].table.drop(columns="flag").to_numpy(float))


def test_attitude_source_imu_ignores_the_units_angles(tmp_path):
    """--attitude-source imu: the unit's ROLL/PITCH are replaced by the raw-IMU MEKF's and not fused by rts."""
    flight = simulate(SimConfig(seed=2))
    paths = write_flight(flight, tmp_path)
    cfg = installation_config(flight).updated(method="rts", attitude_source="imu")
    result = process(paths["POS.txt"], paths["Kamera.txt"], cfg)
    assert result.nav.ins_info.unit_aiding is False
    assert any("recomputed from the raw IMU" in str(n) for n in result.notices)
    figures = accuracy(frame_errors(result.table, flight.truth_frames))
    assert figures["roll_rms_deg"] <= 0.03 and figures["pitch_rms_deg"] <= 0.03
    assert figures["horizontal_rms_m"] <= 0.4


@pytest.mark.parametrize("case", ["midnight", "no_unit_attitude", "consumer_imu"])
def test_rts_edge_cases(tmp_path, case):
    """Across midnight; a POS log without the unit's attitude (heading from the motion); a consumer IMU (read
    with the default preset's datasheet)."""
    sim = SimConfig(seed=3, start_utc_s=86400 - 60 if case == "midnight" else 24513,
                    imu_preset="mems-consumer" if case == "consumer_imu" else "mems-ivru")
    flight = simulate(sim)
    paths = write_flight(flight, tmp_path)
    if case == "no_unit_attitude":
        frame = pd.read_csv(paths["POS.txt"], sep="\t", dtype=str)
        frame.drop(columns=["IACC_X", "IACC_Y", "IACC_Z", "ROLL", "PITCH", "YAW"]).to_csv(paths["POS.txt"], sep="\t",
                                                                                         index=False)
    result = process(paths["POS.txt"], paths["Kamera.txt"], installation_config(flight))
    figures = accuracy(frame_errors(result.table, flight.truth_frames))
    assert result.table["lat"].notna().all()
    assert figures["horizontal_rms_m"] <= 0.4 and figures["yaw_rms_deg"] <= 0.15
    assert figures["roll_rms_deg"] <= 0.03 and figures["pitch_rms_deg"] <= 0.03
    if case == "midnight":
        assert result.table["time"].max() > 86400.0
        assert any("midnight" in str(n) for n in result.notices)
    if case == "no_unit_attitude":
        assert result.nav.diagnostics.heading_source.startswith("motion")
