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

DATA = Path(__file__).resolve().parents[1] / "data"

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
    origin = re.search(r"unit yaw origin (-?[\d.]+) ± ([\d.]+) deg at the start.*?drift (-?[\d.]+) deg/min", text)
    assert origin, result.output
    # the simulated unit's origin drifts 0.5 deg/min
    assert 0.0 < float(origin.group(2)) < 1.0 and abs(float(origin.group(3)) - 0.5) < 0.2
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
    assert re.search(r"QC failed: [a-z, ]*lever arm", page) and "the configuration says 45.00 m" in page
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
    assert "vehicle must be 'auto', 'ground' or 'air', got 'boat'" in result.output


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
