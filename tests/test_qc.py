"""Quality checks with a verdict (georef.qc) on real runs of simulated flights, each processed once here."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from georef.eo import FLAG_AFTER_LAST_FIX, FLAG_BEFORE_FIRST_FIX, FLAG_OUTSIDE
from georef.fusion.ins import Calibration, Restart
from georef.pipeline import ProcessResult, process
from georef.qc import (
    LEVER_FLOOR_M,
    LEVER_RESOLUTION_M,
    LEVER_RESOLUTION_REL,
    NIS_WINDOW_LIMIT,
    Check,
    Verdict,
    assess,
    assess_result,
    nis_band,
)
from georef.sim.files import installation_config, write_flight
from georef.sim.flight import SimConfig, simulate
from georef.sim.sensors import GnssModel

TRUE_LEVER = (0.45, 0.15, -1.65)


@pytest.fixture(scope="module")
def clean(flight_dir, flight_defaults) -> ProcessResult:
    """The default 3-minute flight (conftest's, seed 1) with its installation and the defaults."""
    _, paths = flight_dir
    return process(paths["POS.txt"], paths["Kamera.txt"], flight_defaults)


@pytest.fixture(scope="module")
def typo(flight_dir, flight_defaults) -> ProcessResult:
    """The same flight with a 45 m typo in the GNSS lever arm's x."""
    _, paths = flight_dir
    assert tuple(flight_defaults.mounting.lever_arm_gnss) == TRUE_LEVER
    return process(paths["POS.txt"], paths["Kamera.txt"], flight_defaults.updated(lever_arm_gnss=(45.0, 0.15, -1.65)))


@pytest.fixture(scope="module")
def shifted(flight_dir, flight_defaults, tmp_path_factory) -> ProcessResult:
    """The same flight with a camera file two hours off (a wrong UTC offset)."""
    _, paths = flight_dir
    kamera = pd.read_csv(paths["Kamera.txt"], sep="\t")
    kamera["Time"] += 7200
    path = tmp_path_factory.mktemp("shifted") / "Kamera.txt"
    kamera.to_csv(path, sep="\t", index=False)
    return process(paths["POS.txt"], path, flight_defaults)


@pytest.fixture(scope="module")
def outage_to_end(tmp_path_factory) -> ProcessResult:
    """A 3-minute flight whose GNSS stops 150 s after the start, for good."""
    flight = simulate(SimConfig(seed=1, gnss=GnssModel(outages=[(150.0, 100.0)])))
    paths = write_flight(flight, tmp_path_factory.mktemp("outage"))
    return process(paths["POS.txt"], paths["Kamera.txt"], installation_config(flight))


def _by_name(verdict: Verdict) -> dict[str, Check]:
    return {check.name: check for check in verdict.checks}


def _with(result: ProcessResult, gnss=None, **diagnostics) -> Verdict:
    """The verdict of ``result`` with some of its diagnostics (or its GNSS use) replaced."""
    nav = result.nav
    changed = dataclasses.replace(nav, diagnostics=dataclasses.replace(nav.diagnostics, **diagnostics),
                                  gnss=gnss if gnss is not None else nav.gnss)
    return assess(changed, result.table, result.config)


# ---- real runs -----------------------------------------------------------------------------------------------
def test_clean_flight_passes(clean):
    verdict = assess_result(clean)
    checks = _by_name(verdict)
    assert verdict.passed, verdict
    assert {"innovations", "innovation bursts", "rejected fixes", "lever arm", "latency", "heading", "restarts",
            "IMU gaps", "frames", "GNSS at the ends"} <= set(checks)
    for name in ("innovations", "lever arm", "heading", "restarts", "IMU gaps", "frames", "GNSS at the ends"):
        assert checks[name].status == "pass", checks[name]
    # the figures in the message are the run's own
    used = clean.nav.gnss.status == 1
    mean = float(np.mean(clean.nav.diagnostics.nis[used]))
    assert f"{mean:.2f} over {int(used.sum())} used GNSS fixes" in checks["innovations"].message
    assert "agrees with the configured 0.45, 0.15, -1.65 m" in checks["lever arm"].message
    assert verdict.short() in ("passed", f"passed (warnings: {', '.join(c.name for c in verdict.warnings)})")


def test_lever_arm_typo_fails_naming_the_lever_arm(typo):
    verdict = assess_result(typo)
    assert not verdict.passed
    failure = _by_name(verdict)["lever arm"]
    assert failure.status == "fail"
    assert "GNSS lever arm x (forward): the data put the antenna at" in failure.message
    assert "the configuration says 45.00 m" in failure.message and "--gnss-lever-arm" in failure.message
    # only x is wrong: y and z agree with the data
    assert "lever arm y" not in failure.message and "lever arm z" not in failure.message
    estimate = typo.nav.diagnostics.calibration.lever_arm[0]
    assert abs(estimate - 45.0) > LEVER_RESOLUTION_M + LEVER_RESOLUTION_REL * 45.0
    assert verdict.short().startswith("failed: ") and "lever arm" in verdict.short()


def test_calibration_pass_finds_a_lever_arm_it_is_not_told(tmp_path):
    """PPK-grade fixes (2/2/4 cm), lever arm not told: the calibration pass's estimate lies within 3 of its sigmas
    of the simulated lever arm on every axis, with a vertical sigma under 0.15 m. (Its start position ignored the
    lever arm's uncertainty: z came out at -1.00 +- 0.04 m against -1.65 m.)"""
    from georef.config import InsSettings
    from georef.fusion.ins import inputs_from_pos, solve_ins
    from georef.io.pos import read_pos

    sim = SimConfig(seed=1, lever_arm_gnss_m=TRUE_LEVER, gnss=GnssModel(sigma_neu_m=(0.02, 0.02, 0.04)))
    flight = simulate(sim)
    paths = write_flight(flight, tmp_path)
    cfg = installation_config(flight).updated(lever_arm_gnss=(0.0, 0.0, 0.0), gnss_sigma=(0.02, 0.02, 0.04))
    calibration = solve_ins(inputs_from_pos(read_pos(paths["POS.txt"])), InsSettings.of(cfg),
                            smooth=True).diagnostics.calibration
    error = np.abs(calibration.lever_arm - np.asarray(TRUE_LEVER))
    assert (error < 3.0 * calibration.lever_arm_sigma).all(), (calibration.lever_arm, calibration.lever_arm_sigma)
    assert calibration.lever_arm_sigma[2] < 0.15


def test_camera_two_hours_off_fails_on_frames(shifted):
    assert shifted.table["flag"].str.contains(FLAG_OUTSIDE).all()
    verdict = assess_result(shifted)
    checks = _by_name(verdict)
    assert not verdict.passed and [c.name for c in verdict.failures] == ["frames"]
    message = checks["frames"].message
    assert f"{len(shifted.table)} of {len(shifted.table)} frames lie outside" in message
    # the shift itself, for the user to recognise: two hours
    match = re.search(r"the exposures lie (\d+) s \((\d+\.\d+) h\) later than the navigation", message)
    assert match and abs(int(match.group(1)) - 7200) < 30 and match.group(2) == "2.00", message
    assert "--camera-utc-offset" in message and "--camera-time-offset" in message
    assert checks["lever arm"].status == "pass"


def test_gnss_outage_to_the_end_flags_frames_and_warns(outage_to_end):
    table, gnss = outage_to_end.table, outage_to_end.nav.gnss
    last = float(gnss.time[-1])
    assert outage_to_end.log.time[-1] - last > 25.0        # the outage runs to the end of the log
    after = table["time"].to_numpy() > last + 2.5
    flagged = table["flag"].str.contains(FLAG_AFTER_LAST_FIX).to_numpy()
    assert after.sum() > 60
    np.testing.assert_array_equal(flagged, after)
    assert not table["flag"].str.contains(FLAG_BEFORE_FIRST_FIX).any()
    # the flag says how long the frame has been inertial only
    row = table[after].iloc[-1]
    assert f"{FLAG_AFTER_LAST_FIX} ({row['time'] - last:.0f} s of inertial only)" in row["flag"]
    assert outage_to_end.summary()["frames_after_last_fix"] == int(after.sum())
    verdict = assess_result(outage_to_end)
    check = _by_name(verdict)["GNSS at the ends"]
    assert check.status == "warn"
    assert check.message.startswith(f"{int(after.sum())} frame(s) after the last GNSS fix at {last:.1f} s")
    assert verdict.passed, verdict


def test_axis_method_gets_the_checks_that_apply(flight_dir, flight_config):
    _, paths = flight_dir
    result = process(paths["POS.txt"], paths["Kamera.txt"], flight_config.updated(method="axis"))
    verdict = assess_result(result)
    assert [c.name for c in verdict.checks] == ["rejected fixes", "frames", "GNSS at the ends"]
    assert verdict.passed, verdict


# ---- thresholds, on the clean run with one thing changed ---------------------------------------------------------
def test_innovation_level_fails_high_and_warns_low(clean):
    nis = clean.nav.diagnostics.nis
    n = int((clean.nav.gnss.status == 1).sum())
    lo, hi = nis_band(n)
    assert 1.5 < lo < 2.5 and 3.8 < hi < 5.0, (lo, hi)
    high = _by_name(_with(clean, nis=nis * 2.0))["innovations"]
    low = _by_name(_with(clean, nis=nis * 0.4))["innovations"]
    assert high.status == "fail" and "more than the fitted model explains" in high.message
    # pessimistic sigmas are safe to use: a warning that points at the held-out check, never a failure
    assert low.status == "warn" and "may be pessimistic" in low.message and "held-out" in low.message


def test_a_burst_of_large_innovations_warns_with_its_span(clean):
    nav = clean.nav
    used = np.flatnonzero(nav.gnss.status == 1)
    t = nav.gnss.time
    burst = used[(t[used] >= t[used[60]]) & (t[used] < t[used[60]] + 20.0)]
    nis = nav.diagnostics.nis.copy()
    nis[burst] = 40.0
    check = _by_name(_with(clean, nis=nis))["innovation bursts"]
    assert check.status == "warn"
    window = re.search(r"mean normalised innovation squared ([\d.]+) over \d+ fixes from ([\d.]+) to ([\d.]+) s",
                       check.message)
    assert window, check.message
    mean, start, end = (float(v) for v in window.groups())
    assert mean > NIS_WINDOW_LIMIT
    assert start <= t[burst[0]] and end >= t[burst[-1]] and end - start <= 60.0


def test_rejected_fixes_warn_then_fail(clean):
    gnss = clean.nav.gnss
    used = np.flatnonzero(gnss.status == 1)
    processed = int((gnss.status >= 0).sum())
    for count, status in ((3, "warn"), (12, "fail")):
        changed = gnss.status.copy()
        changed[used[10:10 + count]] = 0
        check = _by_name(_with(clean, gnss=dataclasses.replace(gnss, status=changed)))["rejected fixes"]
        assert check.status == status, check
        assert check.message.startswith(f"{count} of {processed} processed GNSS fixes rejected "
                                        f"({100 * count / processed:.1f} %; the gate chi-square 16.27 rejects 0.10 %")
        assert f"{gnss.time[used[10]]:.1f} s (line {int(gnss.line[used[10]])})" in check.message
    assert "and 2 more" in check.message        # 12 rejected, 10 listed


def test_lever_arm_threshold_needs_both_sigma_and_resolution(clean):
    given = np.asarray(TRUE_LEVER)

    def status(delta_y: float, sigma: float) -> str:
        calibration = Calibration(lever_arm=given + [0.0, delta_y, 0.0], lever_arm_sigma=np.full(3, sigma),
                                  latency=0.0, latency_sigma=0.01)
        return _by_name(_with(clean, calibration=calibration, lever_arm_given=given))["lever arm"].status

    resolution = LEVER_RESOLUTION_M + LEVER_RESOLUTION_REL * 0.15
    assert status(resolution - 0.02, 0.01) == "pass"          # many sigmas off, but within the resolution
    assert status(resolution + 0.02, 0.01) == "fail"
    wide = 0.5
    assert status(2.5 * np.hypot(wide, LEVER_FLOOR_M), wide) == "pass"   # beyond the resolution, within 3 sigma
    assert status(3.5 * np.hypot(wide, LEVER_FLOOR_M), wide) == "fail"


def test_latency_warns_only_when_significant_and_not_given(clean):
    diagnostics = clean.nav.diagnostics

    def check(latency: float, sigma: float, cfg=None) -> Check | None:
        calibration = dataclasses.replace(diagnostics.calibration, latency=latency, latency_sigma=sigma)
        nav = dataclasses.replace(clean.nav, diagnostics=dataclasses.replace(diagnostics, calibration=calibration))
        return _by_name(assess(nav, clean.table, cfg or clean.config)).get("latency")

    assert clean.config.gnss.latency is None
    significant = check(0.15, 0.02)
    assert significant.status == "warn" and "--gnss-latency 0.150" in significant.message
    assert check(0.015, 0.001).status == "pass"       # many sigmas, but under 0.02 s
    assert check(0.05, 0.02).status == "pass"         # 2.5 sigma
    assert check(0.15, 0.02, clean.config.updated(gnss_latency=0.0)) is None   # given by the user


def test_heading_restarts_and_imu_gaps(clean):
    none = _by_name(_with(clean, heading_source="none: the heading is not observable from the motion"))["heading"]
    # the advice fits what a POS user holds: the unit's own yaw
    assert none.status == "fail" and "POS.txt" in none.message
    # a magnetometer heading (sigma 10 deg): a warning while the yaw claims no better than that source can give,
    # a failure when it claims more (the motion never showed the heading, so that information is spurious)
    nav = clean.nav
    alignment = dataclasses.replace(nav.diagnostics.alignment, heading_sigma=np.radians(10.0))
    diagnostics = dataclasses.replace(nav.diagnostics, alignment=alignment,
                                      heading_source="magnetometer (declination from the configuration, sigma 10 deg)")
    for yaw_sigma_deg, status in ((9.0, "warn"), (2.0, "fail")):
        att_sigma = nav.att_sigma.copy()
        att_sigma[:, 2] = np.radians(yaw_sigma_deg)
        changed = dataclasses.replace(nav, diagnostics=diagnostics, att_sigma=att_sigma)
        check = _by_name(assess(changed, clean.table, clean.config))["heading"]
        assert check.status == status, check
    assert "claims a yaw sigma of 2.0 deg" in check.message
    restarts = _by_name(_with(clean, restarts=[Restart(row=4000, time=24593.0, reason="4 GNSS fixes in a row "
                                                                                       "rejected")]))["restarts"]
    assert restarts.status == "warn" and "at 24593.0 s: 4 GNSS fixes in a row rejected" in restarts.message
    # a restart that gets no further repeats at one place: listed once, with its count
    stuck = [Restart(row=4000, time=24593.0, reason="4 GNSS fixes in a row rejected")] * 4 + \
        [Restart(row=5000, time=24610.0, reason="IMU gap")]
    repeated = _by_name(_with(clean, restarts=stuck))["restarts"].message
    assert repeated.startswith("5 restart(s)") and repeated.count("24593.0") == 1, repeated
    assert "at 24593.0 s: 4 GNSS fixes in a row rejected (4 times); at 24610.0 s: IMU gap" in repeated
    gaps = _by_name(_with(clean, imu_gaps=[(24550.0, 24551.5), (24600.0, 24600.3)]))["IMU gaps"]
    assert gaps.status == "warn" and gaps.message.startswith("2 span(s) without IMU data, 1.80 s in all")
    assert not _with(clean, heading_source="none: no heading").passed


def test_some_frames_outside_warn(clean):
    table = clean.table.copy()
    table.loc[:2, "flag"] = FLAG_OUTSIDE
    check = _by_name(assess(clean.nav, table, clean.config))["frames"]
    assert check.status == "warn" and f"3 of {len(table)} frames lie outside" in check.message
    assert "(frames 1, 2, 3)" in check.message
    table.loc[: len(table) // 2 + 1, "flag"] = FLAG_OUTSIDE
    assert _by_name(assess(clean.nav, table, clean.config))["frames"].status == "fail"


def test_verdict_is_plain_data():
    verdict = Verdict((Check("frames", "fail", "all frames outside"), Check("restarts", "warn", "one"),
                       Check("heading", "pass", "motion")))
    assert Verdict.from_dicts(verdict.to_dicts()) == verdict
    assert verdict.short() == "failed: frames" and not verdict.passed
    assert verdict.details() == "fail frames: all frames outside\nwarn restarts: one"
    assert Verdict(verdict.checks[1:]).short() == "passed (warnings: restarts)"
    with pytest.raises(ValueError, match="status"):
        Check("x", "ok", "no such status")


def test_docs_name_every_check():
    text = (Path(__file__).resolve().parents[1] / "docs" / "qc.md").read_text()
    for name in ("innovations", "innovation bursts", "rejected fixes", "lever arm", "latency", "heading",
                 "restarts", "IMU gaps", "frames", "GNSS at the ends"):
        assert f"`{name}`" in text, name
    assert "exit code" in text.lower() and "| 4 |" in text


def test_frames_without_a_valid_sigma_fail(clean):
    """A frame whose covariance broke (a negative variance gives no sigma) is flagged, and QC fails on it."""
    from georef.eo import FLAG_NO_SIGMA

    table = clean.table.copy()
    table.loc[5, "sigma_u"] = np.nan
    table.loc[5, "flag"] = FLAG_NO_SIGMA
    check = _by_name(assess(clean.nav, table, clean.config))["frames"]
    assert check.status == "fail" and check.message.startswith(f"1 of {len(table)} frames have no valid sigma")


def _graph_nav(own: np.ndarray, own_sigma: np.ndarray, prior: np.ndarray, prior_sigma: np.ndarray,
               ekf: np.ndarray, ekf_sigma: np.ndarray):
    """A stand-in for a graph solution: its calibration posterior made from a prior (lever arm x, y, z [m] and a
    time offset of 0 +- 2 ms) and a flight's data-only estimate, and the EKF's calibration pass."""
    from types import SimpleNamespace

    from georef.fusion.solution import GraphCalibration

    prior_mean = np.append(prior, 0.0)
    prior_cov = np.diag(np.append(prior_sigma, 0.002) ** 2)
    data_info = np.diag(1.0 / np.append(own_sigma, 0.002) ** 2)
    covariance = np.linalg.inv(np.linalg.inv(prior_cov) + data_info)
    mean = covariance @ (np.linalg.solve(prior_cov, prior_mean) + data_info @ np.append(own, 0.0))
    calibration = GraphCalibration(mean=mean, covariance=covariance, prior_mean=prior_mean, prior_covariance=prior_cov)
    ekf_pass = Calibration(lever_arm=ekf, lever_arm_sigma=ekf_sigma, latency=0.0, latency_sigma=0.01)
    return SimpleNamespace(graph_info=SimpleNamespace(calibration=calibration),
                           diagnostics=SimpleNamespace(calibration=ekf_pass))


def test_graph_lever_arm_check_is_contested_by_an_agreeing_ekf():
    """The graph's data put the antenna elsewhere than configured: a failure naming the lever arm, unless the EKF's
    calibration pass, which sees the same data and resolves the axis about as well, agrees with the configuration;
    then the data do not single out the configuration and the check warns, naming both (a multicopter with a
    consumer IMU, measured: graph 1.69 +- 0.54 m, EKF -0.51 +- 0.52 m, configured and true 0.02 m)."""
    from georef.qc import check_graph_lever_arm

    prior, prior_sigma = np.array([0.02, 0.0, -0.12]), np.full(3, 0.05)
    own, own_sigma = np.array([1.69, 0.0, -0.12]), np.array([0.54, 0.5, 1.0])
    contested = check_graph_lever_arm(_graph_nav(own, own_sigma, prior, prior_sigma, np.array([-0.51, 0.0, -0.12]),
                                                 np.array([0.52, 0.5, 0.8])))
    assert contested.status == "warn"
    assert "1.69 +- 0.54" in contested.message and "-0.51 +- 0.52" in contested.message
    # a clearer error (2.5 m), which the EKF sees too: the configuration is at fault
    own = np.array([2.5, 0.0, -0.12])
    agreed = check_graph_lever_arm(_graph_nav(own, own_sigma, prior, prior_sigma, np.array([2.3, 0.0, -0.12]),
                                              np.array([0.52, 0.5, 0.8])))
    assert agreed.status == "fail" and "typo" in agreed.message
    # the EKF cannot resolve the axis (sigma 3 m against the graph's 0.54): it contests nothing
    blind = check_graph_lever_arm(_graph_nav(own, own_sigma, prior, prior_sigma, np.array([0.0, 0.0, -0.12]),
                                             np.array([3.0, 0.5, 0.8])))
    assert blind.status == "fail"


@pytest.mark.slow
def test_an_imu_read_with_two_axes_flipped_fails_the_attitude_check(tmp_path):
    """An IMU published forward-right-down where forward-left-up is expected (or the reverse) reads with y and z
    negated: roll turns upside down and the forward filter strays from the smoother by hundreds of sigmas. That is
    a failed run (exit 4), not a warning beside "QC passed"; the same flight read the right way passes the check."""
    from georef_cli.main import app
    from typer.testing import CliRunner

    runner = CliRunner()
    folder = tmp_path / "drone"
    made = runner.invoke(app, ["simulate", str(folder), "--vehicle", "multicopter", "--duration", "120", "--seed",
                               "3", "--generic", "-q"])
    assert made.exit_code == 0, made.output
    imu = pd.read_csv(folder / "imu.csv")
    for column in ("gyro_y", "gyro_z", "acc_y", "acc_z"):
        imu[column] = -imu[column]
    imu.to_csv(folder / "imu_flipped.csv", index=False, float_format="%.10g")
    outputs = {}
    for name in ("imu.csv", "imu_flipped.csv"):
        run = runner.invoke(app, ["fuse", "--imu", str(folder / name), "--gnss", str(folder / "gnss.csv"),
                                  "--config", str(folder / "flight.toml"), "-o", str(tmp_path / f"{name}.traj.csv")])
        outputs[name] = run
    flipped = outputs["imu_flipped.csv"]
    assert flipped.exit_code == 4, flipped.output
    assert re.search(r"QC fail attitude sigmas: .*disagree by \d+ times", flipped.output), flipped.output
    assert "QC fail attitude sigmas" not in outputs["imu.csv"].output, outputs["imu.csv"].output
