"""The command line on the bundled flight, as a user would run it."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from georef_cli.main import app
from typer.testing import CliRunner

from georef.evaluate import accuracy, frame_errors
from georef.io.eo_table import read_eo_csv

DATA = Path(__file__).resolve().parents[2] / "data"

RUNNER = CliRunner()


def test_process_bundled_flight(tmp_path):
    output = tmp_path / "eo.csv"
    result = RUNNER.invoke(app, ["process", str(DATA / "POS.txt"), str(DATA / "Kamera.txt"), "--config",
                                 str(DATA / "flight.toml"), "-o", str(output)])
    assert result.exit_code == 0, result.output
    for text in ("frames written", "GNSS epochs", "heading source", "unit yaw origin", "noise",
                 "time quirks repaired", "rejected fixes", "QC passed"):
        assert text in result.output
    # rts: the unit's yaw origin (true yaw = unit yaw + origin), not the axis method's yaw offset
    assert "yaw offset" not in result.output
    text = re.sub(r"[│\s]+", " ", result.output)   # the table's cells unwrapped
    origin = re.search(r"unit yaw origin (-?[\d.]+) ± ([\d.]+) deg at the start.*?drift (-?[\d.]+) ± ([\d.]+) deg/min",
                       text)
    assert origin, result.output
    # the simulated unit's origin drifts 0.5 deg/min, shown with its sigma
    drift, drift_sigma = float(origin.group(3)), float(origin.group(4))
    assert 0.0 < float(origin.group(2)) < 1.0 and abs(drift - 0.5) < 0.2 and abs(drift - 0.5) <= 3.0 * drift_sigma
    noise = re.search(r"GNSS σ h ([\d.]+) m, v ([\d.]+) m \(fitted\); VRW ([\d.]+) m/s/√h, ARW ([\d.]+) deg/√h", text)
    assert noise, result.output
    assert 0.5 < float(noise.group(1)) < 2.0 and 1.0 < float(noise.group(2)) < 4.0
    table = read_eo_csv(output)
    kamera = pd.read_csv(DATA / "Kamera.txt", sep="\t")
    assert len(table) == len(kamera)
    for column in ("frame", "time", "lat", "lon", "height", "roll", "pitch", "yaw", "sigma_n", "sigma_e",
                   "sigma_u", "sigma_roll", "sigma_pitch", "sigma_yaw", "track", "yaw_minus_track",
                   "easting", "northing", "omega", "phi", "kappa", "flag"):
        assert column in table.columns
    # omega/phi/kappa are the same rotation as the camera's roll/pitch/yaw, in the grid frame
    from georef.frames import euler_to_dcm
    from georef.frames.mapping import MapProjection
    from georef.frames.photogrammetry import image_to_map, opk_to_rotation

    gamma, _ = MapProjection("EPSG:3765").convergence_and_scale(table["lat"], table["lon"])
    R_from_euler = image_to_map(euler_to_dcm(*np.radians(table[["roll", "pitch", "yaw"]].to_numpy().T)), gamma)
    R_from_opk = opk_to_rotation(*np.radians(table[["omega", "phi", "kappa"]].to_numpy().T))
    np.testing.assert_allclose(R_from_opk, R_from_euler, atol=2e-7)
    assert table["flag"].str.contains("GNSS outage").any()
    truth = pd.read_csv(DATA / "truth.csv")
    figures = accuracy(frame_errors(table, truth))
    assert figures["yaw_rms_deg"] < 1.0
    assert (table["yaw"].between(0, 360)).all()
    # HTRS96/TM coordinates of the Benkovac area
    assert table["easting"].between(380_000, 480_000).all()


def test_axis_method_keeps_the_yaw_offset_row(tmp_path):
    result = RUNNER.invoke(app, ["process", str(DATA / "POS.txt"), str(DATA / "Kamera.txt"), "--config",
                                 str(DATA / "flight.toml"), "-o", str(tmp_path / "eo.csv"), "--method", "axis"])
    assert result.exit_code == 0, result.output
    assert "yaw offset" in result.output and "heading source" not in result.output
    assert "QC passed" in result.output


def test_quiet_prints_nothing(tmp_path):
    result = RUNNER.invoke(app, ["process", str(DATA / "POS.txt"), str(DATA / "Kamera.txt"), "--config",
                                 str(DATA / "flight.toml"), "-o", str(tmp_path / "eo.csv"), "--quiet"])
    assert result.exit_code == 0 and result.output.strip() == ""


def test_help_states_units():
    result = RUNNER.invoke(app, ["process", "--help"], terminal_width=200)
    assert result.exit_code == 0
    text = re.sub(r"\s+", " ", result.output)
    for phrase in ("in metres, body frame", "in degrees", "in hours", "in Hz", "EPSG:3765",
                   "Camera trigger latency in seconds", "GNSS time-tag latency in seconds (the fix was measured this "
                   "long before its time tag); default: estimated and reported, not applied", "--vehicle"):
        assert phrase in text
    fuse = re.sub(r"\s+", " ", RUNNER.invoke(app, ["fuse", "--help"], terminal_width=200).output)
    assert "GNSS time-tag latency in seconds" in fuse and "--vehicle" in fuse


def test_simulate_then_process_and_evaluate(tmp_path):
    folder = tmp_path / "sim"
    result = RUNNER.invoke(app, ["simulate", str(folder), "--duration", "120", "--seed", "4", "--quiet"])
    assert result.exit_code == 0, result.output
    assert {p.name for p in folder.iterdir()} >= {"POS.txt", "Kamera.txt", "truth.csv", "flight.toml"}
    result = RUNNER.invoke(app, ["process", str(folder / "POS.txt"), str(folder / "Kamera.txt"), "--config",
                                 str(folder / "flight.toml"), "-o", str(folder / "eo.csv"), "-q"])
    assert result.exit_code == 0, result.output
    result = RUNNER.invoke(app, ["evaluate", str(folder / "eo.csv"), str(folder / "truth.csv")])
    assert result.exit_code == 0 and "yaw_rms_deg" in result.output


def _unique_fixes(folder: Path) -> pd.DataFrame:
    """The GNSS fixes POS.txt holds (rows before the first fix hold zeros; each fix is held for many rows)."""
    pos = pd.read_csv(folder / "POS.txt", sep="\t", usecols=["LATITUDE", "LONGITUDE", "ALTITUDE"])
    return pos[pos["LATITUDE"] != 0.0].drop_duplicates().reset_index(drop=True)


def test_simulate_gnss_sigma_and_unit_yaw_drift_reach_the_files(tmp_path):
    """--gnss-sigma 3,3,5 scales the fixes' noise (same seed: the same standard normal draws, so the fixes move
    from the default 1,1,2 run by z x (2, 2, 3) m) and reaches flight.toml; --unit-yaw-drift 4 makes truth.csv's
    unit_yaw_offset ramp at 4 deg/h instead of the default 30 deg/h."""
    import tomllib

    common = ["simulate", "--seed", "1", "--duration", "60", "--quiet"]
    plain, changed = tmp_path / "plain", tmp_path / "changed"
    assert RUNNER.invoke(app, [common[0], str(plain), *common[1:]]).exit_code == 0
    result = RUNNER.invoke(app, [common[0], str(changed), *common[1:], "--gnss-sigma", "3,3,5",
                                 "--unit-yaw-drift", "4"])
    assert result.exit_code == 0, result.output
    a, b = _unique_fixes(plain), _unique_fixes(changed)
    assert len(a) == len(b) > 50
    lat = np.radians(a["LATITUDE"].to_numpy())
    d_north = np.radians(b["LATITUDE"] - a["LATITUDE"]).to_numpy() * 6.371e6
    d_east = np.radians(b["LONGITUDE"] - a["LONGITUDE"]).to_numpy() * 6.371e6 * np.cos(lat)
    d_up = (b["ALTITUDE"] - a["ALTITUDE"]).to_numpy()
    for diff, extra in ((d_north, 2.0), (d_east, 2.0), (d_up, 3.0)):
        assert 0.7 * extra < np.sqrt(np.mean(diff**2)) < 1.3 * extra
    gnss = tomllib.loads((changed / "flight.toml").read_text())["gnss"]
    assert gnss["gnss_sigma"] == [3, 3, 5]
    for folder, deg_per_h in ((plain, 30.0), (changed, 4.0)):
        truth = pd.read_csv(folder / "truth.csv")
        ramp = truth["unit_yaw_offset"].iloc[-1] - truth["unit_yaw_offset"].iloc[0]
        span_h = (truth["time"].iloc[-1] - truth["time"].iloc[0]) / 3600.0
        assert ramp == pytest.approx(deg_per_h * span_h, rel=1e-4)
    # the POS unit's own yaw carries the new origin: it differs from the plain run by the ramps' difference
    yaw = [pd.read_csv(f / "POS.txt", sep="\t", usecols=["YAW"])["YAW"].to_numpy() for f in (plain, changed)]
    moved = (yaw[0] - yaw[1] + 180.0) % 360.0 - 180.0
    assert moved[-1] - moved[0] == pytest.approx(-(30.0 - 4.0) * 60.0 / 3600.0, abs=0.01)


@pytest.mark.parametrize(("args", "message"), [
    (["--gnss-sigma", "3,0,5"], "--gnss-sigma must be three positive metres"),
    (["--gnss-sigma", "3,3"], "--gnss-sigma needs three comma-separated numbers in metres"),
    (["--unit-yaw-drift", "nan"], "--unit-yaw-drift must be a finite number of deg/h"),
    (["--unit-yaw-drift", "4", "--vehicle", "car"], "--unit-yaw-drift applies to --vehicle helicopter only"),
    (["--gnss-sigma", "3,3,5", "--vehicle", "drone"], "--gnss-sigma applies to --vehicle helicopter"),
])
def test_simulate_refuses_bad_gnss_sigma_and_unit_yaw_drift(tmp_path, args, message):
    result = RUNNER.invoke(app, ["simulate", str(tmp_path / "x"), *args, "--quiet"])
    assert result.exit_code == 2
    assert message in re.sub(r"\s+", " ", result.output)
    assert not (tmp_path / "x").exists()


def test_options_override_the_config(tmp_path):
    base = tmp_path / "a.csv"
    moved = tmp_path / "b.csv"
    common = ["process", str(DATA / "POS.txt"), str(DATA / "Kamera.txt"), "--config", str(DATA / "flight.toml"), "-q"]
    assert RUNNER.invoke(app, [*common, "-o", str(base)]).exit_code == 0
    assert RUNNER.invoke(app, [*common, "-o", str(moved), "--camera-lever-arm=11.1,-0.25,0.55"]).exit_code == 0
    a, b = read_eo_csv(base), read_eo_csv(moved)
    # 10 m further forward: along the heading, horizontally
    shift = np.hypot(b["easting"] - a["easting"], b["northing"] - a["northing"])
    assert np.allclose(shift, 10.0, atol=0.5)


def test_info_describes_the_log():
    result = RUNNER.invoke(app, ["info", str(DATA / "POS.txt")])
    assert result.exit_code == 0
    assert "GNSS epochs" in result.output and "TRIG_TIME" in result.output


@pytest.fixture(scope="module")
def sim_flight(tmp_path_factory) -> Path:
    """A 2-minute simulated helicopter flight with the generic files too (imu.csv, gnss.csv)."""
    folder = tmp_path_factory.mktemp("cli") / "sim"
    result = RUNNER.invoke(app, ["simulate", str(folder), "--duration", "120", "--seed", "4", "--generic", "-q"])
    assert result.exit_code == 0, result.output
    return folder


def test_failed_quality_checks_exit_4_with_the_outputs_written(sim_flight, tmp_path):
    output = tmp_path / "eo.csv"
    report = tmp_path / "report.html"
    common = ["process", str(sim_flight / "POS.txt"), str(sim_flight / "Kamera.txt"), "--config",
              str(sim_flight / "flight.toml"), "--gnss-lever-arm", "45,0.15,-1.65"]
    result = RUNNER.invoke(app, [*common, "-o", str(output), "--report", str(report)])
    assert result.exit_code == 4, result.output
    assert "QC fail lever arm: GNSS lever arm x (forward)" in result.output
    assert "the configuration says 45.00 m" in result.output and "QC failed" in result.output
    assert "frames written" in result.output
    assert len(read_eo_csv(output)) == len(pd.read_csv(sim_flight / "Kamera.txt", sep="\t"))
    page = report.read_text()
    # the innovations fail too on this 2-minute flight; the lever arm is among the named failures
    assert re.search(r"QC failed: [a-z, -]*lever arm", page) and "the configuration says 45.00 m" in page
    # --quiet: the failures only
    quiet = RUNNER.invoke(app, [*common, "-o", str(tmp_path / "q.csv"), "-q"])
    assert quiet.exit_code == 4
    assert "QC fail lever arm" in quiet.output and "frames written" not in quiet.output
    assert "notice" not in quiet.output and "QC warning" not in quiet.output


def test_fuse_prints_heading_and_verdict(sim_flight, tmp_path):
    common = ["fuse", "--imu", str(sim_flight / "imu.csv"), "--gnss", str(sim_flight / "gnss.csv"), "--config",
              str(sim_flight / "flight.toml")]
    result = RUNNER.invoke(app, [*common, "-o", str(tmp_path / "traj.csv")])
    assert result.exit_code == 0, result.output
    assert "heading source: motion" in result.output and "QC passed" in result.output
    assert "noise: GNSS σ h" in result.output and "ground vehicle" not in result.output
    # --gnss-latency is applied (each fix moved 0.3 s along a ~30 m/s track), --vehicle ground forces the
    # non-holonomic constraints
    moved = RUNNER.invoke(app, [*common, "-o", str(tmp_path / "moved.csv"), "--gnss-latency", "0.3", "--vehicle",
                                "ground"])
    assert moved.exit_code in (0, 4), moved.output
    assert "ground vehicle: non-holonomic constraints" in moved.output
    a, b = pd.read_csv(tmp_path / "traj.csv"), pd.read_csv(tmp_path / "moved.csv")
    shift = np.hypot((b["lat"] - a["lat"]) * 111_000.0, (b["lon"] - a["lon"]) * 111_000.0 * np.cos(np.radians(44)))
    assert 5.0 < np.median(shift) < 13.0, np.median(shift)
    wrong = RUNNER.invoke(app, [*common, "-o", str(tmp_path / "wrong.csv"), "--gnss-lever-arm", "45,0.15,-1.65"])
    assert wrong.exit_code == 4, wrong.output
    assert "QC fail lever arm" in wrong.output and (tmp_path / "wrong.csv").stat().st_size > 0


def test_camera_time_offset_moves_the_exposures(tmp_path):
    common = ["process", str(DATA / "POS.txt"), str(DATA / "Kamera.txt"), "--config", str(DATA / "flight.toml"), "-q"]
    assert RUNNER.invoke(app, [*common, "-o", str(tmp_path / "a.csv")]).exit_code == 0
    result = RUNNER.invoke(app, [*common, "-o", str(tmp_path / "b.csv"), "--camera-time-offset", "0.25"])
    assert result.exit_code == 0, result.output
    a, b = read_eo_csv(tmp_path / "a.csv"), read_eo_csv(tmp_path / "b.csv")
    np.testing.assert_allclose(b["time"] - a["time"], 0.25, atol=1e-9)
    # 0.25 s later along a ~30 m/s track
    moved = np.hypot(b["easting"] - a["easting"], b["northing"] - a["northing"])
    assert 5.0 < np.median(moved) < 10.0


def test_bad_vehicle_is_a_user_error(tmp_path):
    result = RUNNER.invoke(app, ["process", str(DATA / "POS.txt"), str(DATA / "Kamera.txt"), "-o",
                                 str(tmp_path / "eo.csv"), "--vehicle", "boat"])
    assert result.exit_code == 2
    assert "'boat' is not one of 'auto', 'ground', 'air'" in result.output
    # the same value in flight.toml is refused by the library, with its own message
    config = tmp_path / "flight.toml"
    config.write_text((DATA / "flight.toml").read_text() + '\nvehicle = "boat"\n')
    result = RUNNER.invoke(app, ["process", str(DATA / "POS.txt"), str(DATA / "Kamera.txt"), "-o",
                                 str(tmp_path / "eo.csv"), "--config", str(config)])
    assert result.exit_code == 2
    assert "vehicle must be 'auto', 'ground' or 'air', got 'boat'" in result.output
    assert not (tmp_path / "eo.csv").exists()


def test_a_refused_option_value_names_the_option(tmp_path):
    """A value the configuration refuses, given on the command line, is reported against the option (not the
    flight.toml key the user never typed), exit 2, nothing written."""
    result = RUNNER.invoke(app, ["process", str(DATA / "POS.txt"), str(DATA / "Kamera.txt"), "-o",
                                 str(tmp_path / "eo.csv"), "--gnss-sigma", "1,0,2"])
    assert result.exit_code == 2
    assert "--gnss-sigma: must be positive metres, got (1.0, 0.0, 2.0)" in result.output
    assert "gnss.gnss_sigma" not in result.output
    assert not (tmp_path / "eo.csv").exists()


def test_user_text_is_printed_as_is(tmp_path):
    folder = tmp_path / "flight[red]"
    folder.mkdir()
    missing = RUNNER.invoke(app, ["process", str(folder / "POS.txt"), str(DATA / "Kamera.txt"), "-o",
                                  str(folder / "eo.csv")])
    assert missing.exit_code == 2
    assert "flight[red]/POS.txt" in missing.output
    for name in ("POS.txt", "Kamera.txt", "flight.toml"):
        shutil.copy(DATA / name, folder / name)
    result = RUNNER.invoke(app, ["process", str(folder / "POS.txt"), str(folder / "Kamera.txt"), "--config",
                                 str(folder / "flight.toml"), "-o", str(folder / "eo.csv")])
    assert result.exit_code == 0, result.output
    assert "flight[red]/POS.txt, lines 1852, 6052" in result.output     # the notice, path intact


# ---- CLI conventions: --version, stdout, choices, markup, evaluate's checks, shared options, summaries -------------
def _pyproject_version() -> str:
    import tomllib

    return tomllib.loads((Path(__file__).resolve().parents[2] / "pyproject.toml").read_text())["project"]["version"]


def _strict_json(text: str) -> dict:
    """JSON as a strict parser reads it: NaN or Infinity (which Python's json would accept) fail the test."""
    import json

    def refuse(name: str) -> None:
        raise AssertionError(f"not valid JSON: {name}")

    return json.loads(text, parse_constant=refuse)


def test_version_prints_the_installed_version():
    result = RUNNER.invoke(app, ["--version"])
    assert result.exit_code == 0, result.output
    assert result.stdout == f"georef {_pyproject_version()}\n"
    # eager: given with a command, it still prints the version and runs nothing
    result = RUNNER.invoke(app, ["--version", "process", "missing.txt", "missing.txt"])
    assert result.exit_code == 0 and result.stdout.startswith("georef ")


@pytest.fixture(scope="module")
def bundled_run(tmp_path_factory) -> dict:
    """One `georef process` of the bundled flight to a file, with its summary JSON and report."""
    folder = tmp_path_factory.mktemp("bundled")
    eo, summary, report = folder / "eo.csv", folder / "summary.json", folder / "report.html"
    result = RUNNER.invoke(app, ["process", str(DATA / "POS.txt"), str(DATA / "Kamera.txt"), "--config",
                                 str(DATA / "flight.toml"), "-o", str(eo), "--summary-json", str(summary),
                                 "--report", str(report)])
    assert result.exit_code == 0, result.output
    return {"eo": eo, "summary": summary, "report": report, "output": result.output}


def test_stdout_output_gives_a_clean_table(bundled_run, tmp_path):
    """`georef process ... -o - > eo.csv`, as a shell runs it: stdout holds the table and nothing else, byte for
    byte what -o FILE writes; the run summary and the verdict are on stderr; no file named '-' appears."""
    import subprocess
    import sys

    georef = Path(sys.executable).parent / "georef"
    with (tmp_path / "eo.csv").open("wb") as stdout:
        run = subprocess.run([str(georef), "process", str(DATA / "POS.txt"), str(DATA / "Kamera.txt"), "--config",
                              str(DATA / "flight.toml"), "-o", "-"], stdout=stdout, stderr=subprocess.PIPE,
                             cwd=tmp_path, timeout=300, check=False)
    assert run.returncode == 0, run.stderr.decode()
    assert (tmp_path / "eo.csv").read_bytes() == bundled_run["eo"].read_bytes()
    assert not (tmp_path / "-").exists()
    stderr = run.stderr.decode()
    assert "frames written" in stderr and "standard output" in stderr and "QC passed" in stderr


def test_stdout_for_fuse_and_attitude_and_stdin_for_evaluate(sim_flight, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    common = ["fuse", "--imu", str(sim_flight / "imu.csv"), "--gnss", str(sim_flight / "gnss.csv"), "--config",
              str(sim_flight / "flight.toml")]
    result = RUNNER.invoke(app, [*common, "-o", "-", "--summary-json", "summary.json"])
    assert result.exit_code == 0, result.output
    assert result.stdout.startswith("time,") and "QC passed" not in result.stdout
    assert "trajectory rows -> standard output" in result.stderr and "QC passed" in result.stderr
    trajectory = pd.read_csv(__import__("io").StringIO(result.stdout))
    summary = _strict_json((tmp_path / "summary.json").read_text())
    assert summary["summary"]["trajectory_rows"] == trajectory["lat"].notna().sum() > 1000
    assert not (tmp_path / "-").exists()
    # attitude: the table on stdout, its one-line summary on stderr
    result = RUNNER.invoke(app, ["attitude", "--imu", str(sim_flight / "imu.csv"), "--method", "complementary",
                                 "-o", "-"])
    assert result.exit_code == 0, result.output
    assert result.stdout.startswith("time,") and "samples -> standard output" in result.stderr
    # evaluate reads the EO table from stdin: georef process ... -o - | georef evaluate - truth.csv
    eo = RUNNER.invoke(app, ["process", str(sim_flight / "POS.txt"), str(sim_flight / "Kamera.txt"), "--config",
                             str(sim_flight / "flight.toml"), "-o", "-", "-q"])
    assert eo.exit_code == 0, eo.output
    piped = RUNNER.invoke(app, ["evaluate", "-", str(sim_flight / "truth.csv")], input=eo.stdout)
    (tmp_path / "eo.csv").write_text(eo.stdout)
    on_disk = RUNNER.invoke(app, ["evaluate", str(tmp_path / "eo.csv"), str(sim_flight / "truth.csv")])
    assert piped.exit_code == 0 and on_disk.exit_code == 0, piped.output
    figures = re.findall(r"(\w+_rms_\w+)\s+│\s+([\d.]+)", piped.stdout)
    assert len(figures) == 5 and figures == re.findall(r"(\w+_rms_\w+)\s+│\s+([\d.]+)", on_disk.stdout)


def test_stdout_is_refused_where_it_cannot_work(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    base = ["process", str(DATA / "POS.txt"), str(DATA / "Kamera.txt"), "--config", str(DATA / "flight.toml")]
    both = RUNNER.invoke(app, [*base, "-o", "-", "--summary-json", "-"])
    assert both.exit_code == 2 and "only one output can go to standard output" in both.output
    report = RUNNER.invoke(app, [*base, "-o", "eo.csv", "--report", "-"])
    assert report.exit_code == 2 and "--report cannot be '-'" in report.output
    batch = RUNNER.invoke(app, ["batch", str(tmp_path), "-o", "-"])
    assert batch.exit_code == 2 and "-o cannot be '-'" in batch.output
    # refused before any processing: nothing written
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("args, wrong", [
    (["process", "no_pos.txt", "no_cam.txt", "--method", "kalman"], "'kalman' is not one of 'rts', 'ekf', 'axis', "
                                                                     "'graph'"),
    (["fuse", "--imu", "no.csv", "--gnss", "no.csv", "--method", "axis"], "'axis' is not one of 'rts', 'ekf'"),
    (["batch", "nowhere", "--method", "lsq"], "'lsq' is not one of 'rts', 'ekf', 'axis', 'graph'"),
    (["attitude", "--imu", "no.csv", "--method", "madgwick"], "'madgwick' is not one of 'complementary', 'kf', "
                                                              "'mekf', 'ukf'"),
    (["fuse", "--imu", "no.csv", "--gnss", "no.csv", "--vehicle", "boat"], "'boat' is not one of 'auto', 'ground'"),
])
def test_choices_are_checked_before_any_file_is_read(args, wrong):
    """The files do not exist: a choice checked after reading them would report the missing file instead."""
    result = RUNNER.invoke(app, args)
    assert result.exit_code == 2
    assert wrong in result.output and "not found" not in result.output


def test_choice_lists_match_the_library_and_ignore_case(sim_flight, tmp_path):
    from georef_cli import options

    from georef.attitude.run import METHODS as ATTITUDE_METHODS
    from georef.config import METHODS

    assert [m.value for m in options.Method] == list(METHODS)
    assert [m.value for m in options.AttitudeMethodChoice] == list(ATTITUDE_METHODS)
    help_text = RUNNER.invoke(app, ["process", "--help"], terminal_width=200).output
    assert "<rts|ekf|axis|graph>" in help_text and "<auto|ground|air>" in help_text
    upper = RUNNER.invoke(app, ["attitude", "--imu", str(sim_flight / "imu.csv"), "--method", "KF", "-o",
                                str(tmp_path / "upper.csv")])
    lower = RUNNER.invoke(app, ["attitude", "--imu", str(sim_flight / "imu.csv"), "--method", "kf", "-o",
                                str(tmp_path / "lower.csv")])
    assert upper.exit_code == lower.exit_code == 0, upper.output
    assert "(kf)" in upper.output
    assert (tmp_path / "upper.csv").read_bytes() == (tmp_path / "lower.csv").read_bytes()


def test_shared_options_have_one_definition():
    """Every command that takes --quiet, --config, --verbose, --summary-json, --gnss-lever-arm, --gnss-sigma,
    --gnss-latency or --vehicle takes the same option: same names, same help, same type."""
    import typer

    group = typer.main.get_command(app)
    seen: dict[str, list[tuple]] = {}
    takers: dict[str, set[str]] = {}
    for name, command in group.commands.items():
        for param in command.params:
            if param.name in ("quiet", "config", "verbose", "summary_json", "gnss_lever_arm", "gnss_sigma",
                              "gnss_latency", "vehicle") and name != "simulate":
                seen.setdefault(param.name, []).append(
                    (tuple(param.opts), tuple(param.secondary_opts), param.help, param.type_descriptor.annotation))
                takers.setdefault(param.name, set()).add(name)
    assert takers["summary_json"] == {"process", "fuse", "batch", "calibrate-boresight"}
    assert len(seen["quiet"]) >= 5 and len(seen["config"]) >= 2
    for name, definitions in seen.items():
        assert len(set(definitions)) == 1, (name, definitions)


def test_markup_in_user_text_is_printed_as_is(sim_flight, tmp_path):
    """Square brackets in paths, TOML sections and column names reach the terminal unchanged."""
    folder = tmp_path / "flight[red]"
    folder.mkdir()
    config = folder / "flight.toml"
    config.write_text("[bar]\nx = 1\n")
    section = RUNNER.invoke(app, ["process", str(DATA / "POS.txt"), str(DATA / "Kamera.txt"), "--config",
                                  str(config), "-o", str(folder / "eo.csv")])
    assert section.exit_code == 2 and "flight[red]/flight.toml" in section.output
    assert "unknown section [bar]" in section.output
    config.write_text("[imu]\nbogus = 1\n")
    key = RUNNER.invoke(app, ["process", str(DATA / "POS.txt"), str(DATA / "Kamera.txt"), "--config", str(config),
                              "-o", str(folder / "eo.csv")])
    assert key.exit_code == 2 and "unknown key; [imu] takes accel_bias_corr_time_s" in key.output
    config.write_text('[pos_columns]\nacc_x = "ACC[X]"\n')
    column = RUNNER.invoke(app, ["process", str(DATA / "POS.txt"), str(DATA / "Kamera.txt"), "--config",
                                 str(config), "-o", str(folder / "eo.csv")])
    assert column.exit_code == 2
    assert "required column 'ACC[X]' is missing" in column.output and "STATUS[HEX]" in column.output
    for args in (["info", str(folder / "POS.txt")], ["fuse", "--imu", str(folder / "imu.csv"), "--gnss",
                                                      str(folder / "gnss.csv")],
                 ["attitude", "--imu", str(folder / "imu.csv")], ["evaluate", str(folder / "eo.csv"),
                                                                   str(folder / "truth.csv")]):
        result = RUNNER.invoke(app, args)
        assert result.exit_code == 2 and "flight[red]/" in result.output, (args, result.output)
    # what the commands print on success
    simulated = RUNNER.invoke(app, ["simulate", str(folder / "sim[bold]"), "--duration", "60", "--seed", "2"])
    assert simulated.exit_code == 0 and "flight[red]/sim[bold]/POS.txt" in simulated.output
    fused = RUNNER.invoke(app, ["fuse", "--imu", str(sim_flight / "imu.csv"), "--gnss", str(sim_flight / "gnss.csv"),
                                "-o", str(folder / "traj[x].csv")])
    assert fused.exit_code in (0, 4) and "flight[red]/traj[x].csv" in fused.output
    attitude = RUNNER.invoke(app, ["attitude", "--imu", str(sim_flight / "imu.csv"), "--method", "kf", "-o",
                                   str(folder / "att[i].csv")])
    assert attitude.exit_code == 0 and "flight[red]/att[i].csv" in attitude.output
    # emoji codes in user text stay text (rich turned --export images:x: into a cross mark)
    emoji = RUNNER.invoke(app, ["info", str(tmp_path / "run:x:1" / "POS.txt")])
    assert emoji.exit_code == 2 and "run:x:1/POS.txt" in emoji.output, emoji.output


def test_evaluate_names_what_is_wrong(bundled_run, tmp_path):
    eo, truth = bundled_run["eo"], DATA / "truth.csv"
    # the arguments swapped: the reference has no sigma columns, the EO table has them
    swapped = RUNNER.invoke(app, ["evaluate", str(truth), str(eo)])
    assert swapped.exit_code == 2, swapped.output
    text = re.sub(r"\s+", " ", swapped.output)
    assert f"{truth}, line 1, column 'sigma_n': the EO table lacks column(s) sigma_n, sigma_e" in text
    assert "the arguments look swapped" in text and "Traceback" not in text
    # a reference without a column
    reference = pd.read_csv(truth)
    reference.drop(columns="yaw").to_csv(tmp_path / "no_yaw.csv", index=False)
    no_yaw = RUNNER.invoke(app, ["evaluate", str(eo), str(tmp_path / "no_yaw.csv")])
    assert no_yaw.exit_code == 2
    assert "no_yaw.csv, line 1, column 'yaw': the reference lacks column(s) yaw" in re.sub(r"\s+", " ", no_yaw.output)
    assert "swapped" not in no_yaw.output
    # a cell that is not a number, on its line
    bad = reference.astype({"height": object})
    bad.loc[6, "height"] = "12,5"
    bad.to_csv(tmp_path / "bad.csv", index=False)
    cell = RUNNER.invoke(app, ["evaluate", str(eo), str(tmp_path / "bad.csv")])
    assert cell.exit_code == 2 and "bad.csv, line 8, column 'height': not a number: '12,5'" in cell.output
    # other frames: fewer rows, or a row at another time
    reference.iloc[:-3].to_csv(tmp_path / "short.csv", index=False)
    short = RUNNER.invoke(app, ["evaluate", str(eo), str(tmp_path / "short.csv")])
    assert short.exit_code == 2 and f"513 frames, but the reference {tmp_path / 'short.csv'} has 510" in \
        re.sub(r"\s+", " ", short.output)
    later = reference.copy()
    later.loc[40:, "time"] += 0.5
    later.to_csv(tmp_path / "later.csv", index=False)
    moved = RUNNER.invoke(app, ["evaluate", str(eo), str(tmp_path / "later.csv")])
    assert moved.exit_code == 2
    assert f"{eo}, line 42, column 'time': frame '41'" in re.sub(r"\s+", " ", moved.output)
    # an empty file, a folder
    (tmp_path / "empty.csv").write_text("")
    empty = RUNNER.invoke(app, ["evaluate", str(tmp_path / "empty.csv"), str(truth)])
    assert empty.exit_code == 2 and "empty.csv: EO table: the file is empty" in empty.output
    folder = RUNNER.invoke(app, ["evaluate", str(eo), str(tmp_path)])
    assert folder.exit_code == 2 and "reference: a folder, not a CSV file" in folder.output
    # and the right way round it works
    right = RUNNER.invoke(app, ["evaluate", str(eo), str(truth)])
    assert right.exit_code == 0 and "yaw_rms_deg" in right.output


def test_summary_json_of_process(bundled_run):
    summary = _strict_json(bundled_run["summary"].read_text())
    assert summary["schema"] == 1 and summary["command"] == "process" and summary["exit_code"] == 0
    assert summary["georef_version"] == _pyproject_version()
    assert summary["inputs"] == {"pos": str(DATA / "POS.txt"), "camera": str(DATA / "Kamera.txt"),
                                 "config": str(DATA / "flight.toml")}
    assert summary["outputs"] == [{"what": "table", "format": "csv", "path": str(bundled_run["eo"])},
                                  {"what": "report", "format": "html", "path": str(bundled_run["report"])}]
    assert summary["settings"]["lever_arm_gnss"] == [0.45, 0.15, -1.65] and summary["settings"]["crs"] == "EPSG:3765"
    table = read_eo_csv(bundled_run["eo"])
    figures = summary["summary"]
    assert figures["frames_written"] == len(table) == 513
    assert figures["frames_flagged"] == int((table["flag"] != "").sum())
    assert figures["gnss_rejected_lines"] == [3016] and figures["method"] == "rts"
    assert len(figures["time_span_s"]) == 2 and figures["unit_yaw_drift_deg_per_min"] == pytest.approx(0.5, abs=0.2)
    # the bundled flight's unit drifts 0.5 deg/min: the drift's own sigma covers its error and says something
    drift_sigma = figures["unit_yaw_drift_sigma_deg_per_min"]
    assert 0.0 < drift_sigma < 0.2 and abs(figures["unit_yaw_drift_deg_per_min"] - 0.5) <= 3.0 * drift_sigma
    qc = summary["qc"]
    assert qc["passed"] is True and qc["verdict"].startswith("passed")
    assert {"innovations", "lever arm", "frames"} <= {c["name"] for c in qc["checks"]}
    assert all(set(c) == {"name", "status", "message"} and c["status"] in ("pass", "warn") for c in qc["checks"])
    # every key is documented
    documented = (Path(__file__).resolve().parents[2] / "docs" / "qc.md").read_text()
    undocumented = [key for key in [*summary, *figures, *summary["outputs"][0], *qc]
                    if f"`{key}`" not in documented]
    assert not undocumented, undocumented


def test_summary_json_of_a_failed_qc_run(sim_flight, tmp_path):
    result = RUNNER.invoke(app, ["process", str(sim_flight / "POS.txt"), str(sim_flight / "Kamera.txt"), "--config",
                                 str(sim_flight / "flight.toml"), "--gnss-lever-arm", "45,0.15,-1.65", "-o",
                                 str(tmp_path / "eo.csv"), "--summary-json", "-", "-q"])
    assert result.exit_code == 4
    summary = _strict_json(result.stdout)        # stdout holds the JSON alone; the QC lines are on stderr
    assert summary["exit_code"] == 4 and summary["qc"]["passed"] is False
    lever = next(c for c in summary["qc"]["checks"] if c["name"] == "lever arm")
    assert lever["status"] == "fail" and "the configuration says 45.00 m" in lever["message"]
    assert "QC fail lever arm" in result.stderr


def _broken_copy(source: Path, target: Path) -> Path:
    shutil.copytree(source, target)
    lines = (target / "POS.txt").read_text().splitlines(keepends=True)
    cells = lines[499].split("\t")
    cells[1] = "12..5"
    lines[499] = "\t".join(cells)
    (target / "POS.txt").write_text("".join(lines))
    return target


def test_batch_exits_non_zero_when_a_flight_failed(sim_flight, tmp_path):
    """One good flight, one with a broken POS.txt, one that fails its quality checks: exit 2 (a flight did not
    run on its input; that outranks the QC failure), every other flight written, all of it in the summary JSON."""
    flights = tmp_path / "flights"
    flights.mkdir()
    for name in ("good", "lever"):
        shutil.copytree(sim_flight, flights / name)
    toml = flights / "lever" / "flight.toml"
    toml.write_text(re.sub(r"lever_arm_gnss = \[[^\]]*\]", "lever_arm_gnss = [45, 0.15, -1.65]", toml.read_text()))
    _broken_copy(sim_flight, flights / "broken[red]")
    out = tmp_path / "out"
    result = RUNNER.invoke(app, ["batch", str(flights), "-o", str(out), "--workers", "1", "--summary-json",
                                 str(tmp_path / "batch.json")])
    assert result.exit_code == 2, result.output
    assert "failed: broken[red]: InputError" in result.output and "QC failed: lever" in result.output
    assert len(read_eo_csv(out / "good" / "eo.csv")) == len(read_eo_csv(out / "lever" / "eo.csv")) > 300
    summary = pd.read_csv(out / "batch_summary.csv", keep_default_na=False)
    assert list(summary["flight"]) == ["broken[red]", "good", "lever"]
    assert list(summary["failure"]) == ["input", "", ""]
    document = _strict_json((tmp_path / "batch.json").read_text())
    assert document["command"] == "batch" and document["exit_code"] == 2
    assert document["georef_version"] == _pyproject_version()
    assert document["counts"] == {"flights": 3, "ok": 2, "failed_input": 1, "failed_internal": 0, "qc_failed": 1}
    broken, good, lever = document["flights"]
    assert broken["status"] == "failed" and broken["failure"] == "input" and broken["qc"] is None
    assert "line 500" in broken["message"]
    assert good["qc"]["passed"] is True and good["summary"]["frames_written"] == good["frames"]
    assert {"what": "table", "format": "csv", "path": str(out / "good" / "eo.csv")} in good["outputs"]
    assert lever["qc"]["passed"] is False
    assert any(c["name"] == "lever arm" and c["status"] == "fail" for c in lever["qc"]["checks"])


def test_batch_with_an_internal_error_exits_3(sim_flight, tmp_path, monkeypatch):
    """A flight that fails on a bug (not on its input) makes the batch exit 3, with the traceback in its log.
    The flights run in this process (run_batch replaced by a sequential loop) so that the bug can be planted."""
    import georef.batch
    import georef.pipeline

    flights = tmp_path / "flights"
    flights.mkdir()
    shutil.copytree(sim_flight, flights / "bug")
    def buggy(*args, **kwargs):
        raise ZeroDivisionError("a planted bug")

    def sequential(jobs, output_root, method=None, scheduler=None, workers=2, on_done=None, exports=(),
                   shared_calibration=False):
        rows = []
        for job in jobs:
            rows.append(georef.batch.process_flight(job, str(output_root), method, exports))
            if on_done:
                on_done(rows[-1])
        return pd.DataFrame(rows, columns=georef.batch.SUMMARY_COLUMNS)

    monkeypatch.setattr(georef.pipeline, "process", buggy)
    monkeypatch.setattr(georef.batch, "run_batch", sequential)
    result = RUNNER.invoke(app, ["batch", str(flights), "-o", str(tmp_path / "out"), "--method", "axis",
                                 "--summary-json", "-"])
    assert result.exit_code == 3, result.output
    assert "internal error: bug: ZeroDivisionError: a planted bug" in result.stderr
    document = _strict_json(result.stdout)
    assert document["exit_code"] == 3 and document["flights"][0]["failure"] == "internal"
    log = (tmp_path / "out" / "bug" / "georef.log").read_text()
    assert "FAILED (internal)" in log and "Traceback" in log and "ZeroDivisionError" in log


def test_graph_summary_shows_its_calibration_and_the_campaign_table_its_units(tmp_path):
    """``process --method graph`` prints the lever arm and time offset it estimated, with their sigmas, in its
    summary (they were only in --summary-json and the report); the campaign table's title keeps its units (rich read
    ``[m, body x y z]`` and ``[ms]`` as markup and dropped them)."""
    from georef_cli import main
    from georef_cli.tables import print_campaign

    result = CliRunner().invoke(main.app, ["process", str(DATA / "POS.txt"), str(DATA / "Kamera.txt"), "--config",
                                           str(DATA / "flight.toml"), "--method", "graph", "-o",
                                           str(tmp_path / "eo.csv")])
    assert result.exit_code == 0, result.output
    text = " ".join(result.output.split())
    axis = r"-?\d\.\d{3} ± 0\.\d{3}"
    assert re.search(rf"GNSS lever arm │ {axis}, {axis}, {axis} m", text), text
    assert re.search(r"GNSS time offset │ -?\d+\.\d{2} ± \d+\.\d{2} ms", text), text
    calibration = {"rounds": 2, "gnss_lever_arm_m": [0.45, 0.15, -1.65], "gnss_lever_arm_sigma_m": [0.01] * 3,
                   "gnss_time_offset_s": 0.001, "gnss_time_offset_sigma_s": 0.0005,
                   "flights": {"f1": {"gnss_lever_arm_m": [0.45, 0.15, -1.65], "gnss_lever_arm_sigma_m": [0.02] * 3,
                                      "gnss_time_offset_s": 0.001, "gnss_time_offset_sigma_s": 0.001, "chi2": 1.0,
                                      "dof": 4, "consistent": True}}}
    with main.out.capture() as captured:
        print_campaign(calibration, None)
    printed = " ".join(captured.get().split())
    assert "lever arm [m, body x y z], GNSS time offset [ms]" in printed
    assert "lever arm [m]" in printed and "time offset [ms]" in printed
