"""The command line on the bundled flight, as a user would run it."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd
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
    for text in ("frames written", "GNSS epochs", "yaw offset", "time quirks repaired", "rejected fixes"):
        assert text in result.output
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


def test_quiet_prints_nothing(tmp_path):
    result = RUNNER.invoke(app, ["process", str(DATA / "POS.txt"), str(DATA / "Kamera.txt"), "--config",
                                 str(DATA / "flight.toml"), "-o", str(tmp_path / "eo.csv"), "--quiet"])
    assert result.exit_code == 0 and result.output.strip() == ""


def test_help_states_units():
    result = RUNNER.invoke(app, ["process", "--help"], terminal_width=200)
    assert result.exit_code == 0
    text = re.sub(r"\s+", " ", result.output)
    for phrase in ("in metres, body frame", "in degrees", "in hours", "in Hz", "EPSG:3765"):
        assert phrase in text


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
