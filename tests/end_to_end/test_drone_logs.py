"""``georef process`` on a simulated drone's own logs, end to end, against the truth at every exposure.

The simulator's realistic drone (ground phase, spin-up, lift-off jolt, hover, survey legs; rotor vibration,
thermal bias drift, 5 Hz fixes tagged at arrival with time-correlated errors; camera exposures 0.15 s after their
trigger) written as an ArduPilot DataFlash log (binary, text, gzipped) and a PX4 ULog with camera events, and as
imu.csv, gnss.csv and events.csv. Installation known to the log (lever arm parameters) or not; every figure with
the defaults.
"""

from __future__ import annotations

import gzip

import numpy as np
import pandas as pd
import pytest
from georef_cli.main import app
from typer.testing import CliRunner

from georef.evaluate import frame_errors
from georef.sim.autopilot_logs import write_dataflash, write_ulog
from georef.sim.files import write_generic
from georef.sim.flight import SimConfig, simulate

SEED = 4


@pytest.fixture(scope="module")
def flight():
    return simulate(SimConfig.for_vehicle("drone", duration_s=200.0, seed=SEED))


@pytest.fixture(scope="module")
def truth(flight):
    return flight.truth_frames


def _latency(flight) -> float:
    return float(flight.config.camera_trigger.latency_s)


def _process(args: list[str]) -> tuple[int, str]:
    result = CliRunner().invoke(app, ["process", *args])
    return result.exit_code, result.output


def _assess(eo_path, truth: pd.DataFrame) -> dict[str, float]:
    eo = pd.read_csv(eo_path)
    assert len(eo) == len(truth)
    errors = frame_errors(eo.assign(time=truth["time"].to_numpy()), truth)
    horizontal = np.hypot(errors["north"], errors["east"])
    sigma_h = np.hypot(eo["sigma_n"], eo["sigma_e"])
    inside = {axis: float(np.mean(np.abs(errors[axis]) <= 2.0 * eo[f"sigma_{axis[0] if axis != 'up' else 'u'}"]))
              for axis in ("north", "east", "up")}
    return {"horizontal_rms": float(np.sqrt(np.mean(horizontal**2))), "sigma_h": float(np.median(sigma_h)),
            "roll_rms": float(np.sqrt(np.mean(errors["roll"] ** 2))), **inside,
            "max_tilt": float(np.max(np.abs(errors[["roll", "pitch"]].to_numpy())))}


def _write(flight, tmp_path, form: str):
    """The flight as an autopilot log of ``form`` (bin, log, bin.gz, ulg), its camera events at the exposures."""
    path = tmp_path / f"flight.{form}"
    if form == "ulg":
        write_ulog(flight, path, capture_delay_s=_latency(flight))
        return path
    raw = path.with_suffix("") if form == "bin.gz" else path
    write_dataflash(flight, raw, text=form == "log", capture_delay_s=_latency(flight))
    if form == "bin.gz":
        path.write_bytes(gzip.compress(raw.read_bytes()))
    return path


@pytest.mark.parametrize("form", ["bin", "ulg"])
def test_an_autopilot_log_gives_a_row_per_exposure(flight, truth, tmp_path, form):
    """One row per camera event (a CAM and a TRIG of one image are one), the camera's feedback at the exposure;
    the lever arm from the log's parameters (with a notice); exit 0 on a normal flight; camera positions inside
    their 2 sigma. (The text and gzipped DataFlash forms give the binary form's inputs: the next test.)"""
    path = _write(flight, tmp_path, form)
    eo = tmp_path / "eo.csv"
    code, output = _process([str(path), "-o", str(eo), "--export", f"geojson:{tmp_path / 'eo.geojson'}"])
    print(output)
    assert code == 0, output
    assert "taken from the autopilot's parameters" in output
    figures = _assess(eo, truth)
    print(figures)
    assert figures["horizontal_rms"] < 2.0 and figures["max_tilt"] < 5.0
    assert min(figures["north"], figures["east"]) >= 0.85
    assert (tmp_path / "eo.geojson").exists()


@pytest.mark.parametrize("form", ["log", "bin.gz"])
def test_text_and_gzipped_dataflash_give_the_binary_forms_inputs(flight, tmp_path, form):
    """The same flight as a text log and as a gzipped binary log reads as the binary log does: the same IMU,
    fixes, camera events and lever arm (the text form to its printed precision), so ``process`` gives the same
    EO (the binary form is processed end to end above)."""
    from georef.io.logs import read_flight_log

    folder = tmp_path / "binary"
    folder.mkdir()
    binary = read_flight_log(_write(flight, folder, "bin"))
    other = read_flight_log(_write(flight, tmp_path, form))
    exact = form == "bin.gz"
    close = (lambda a, b, **_: np.testing.assert_array_equal(a, b)) if exact else np.testing.assert_allclose
    close(other.imu.time, binary.imu.time, rtol=0, atol=1e-6)
    close(other.imu.gyro, binary.imu.gyro, rtol=1e-5, atol=1e-6)
    close(other.imu.accel, binary.imu.accel, rtol=1e-5, atol=1e-5)
    close(other.gnss.time, binary.gnss.time, rtol=0, atol=1e-6)
    close(other.gnss.lat_deg, binary.gnss.lat_deg, rtol=0, atol=1e-7)
    close(other.gnss.lon_deg, binary.gnss.lon_deg, rtol=0, atol=1e-7)
    close(other.gnss.height, binary.gnss.height, rtol=0, atol=1e-3)
    assert other.events is not None and binary.events is not None
    np.testing.assert_array_equal(other.events.frame, binary.events.frame)
    close(other.events.time, binary.events.time, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(other.events.time_sigma, binary.events.time_sigma)
    assert other.lever_arm == binary.lever_arm
    assert (other.vehicle, other.imu.name) == (binary.vehicle, binary.imu.name)


def test_generic_files_with_trigger_times(flight, truth, tmp_path):
    """imu.csv, gnss.csv and events.csv of trigger times (0.10-0.20 s before each exposure, the latency unknown to
    georef): the camera positions' sigmas carry the exposure time's own sigma, 0.1 s by default, so the along-track
    offset the latency makes lies inside them.

    The offset is measured against the same flight processed with the true exposure times: whether the fixes'
    own correlated error (sigma about 0.5 m, correlated over a minute) lies inside the sigmas is a question over
    many flights (benchmarks/drone_monte_carlo.py), not one."""
    paths = write_generic(flight, tmp_path)
    exact = tmp_path / "exact.csv"
    pd.read_csv(paths["events.csv"]).assign(time=truth["time"].to_numpy(), time_sigma=0.001).to_csv(exact, index=False)
    lever = ",".join(str(v) for v in flight.config.lever_arm_gnss_m)
    tables = {}
    for name, events in (("trigger", paths["events.csv"]), ("exact", exact)):
        eo = tmp_path / f"eo_{name}.csv"
        code, output = _process(["--imu", str(paths["imu.csv"]), "--gnss", str(paths["gnss.csv"]), "--events",
                                 str(events), "--gnss-lever-arm", lever, "-o", str(eo)])
        print(output)
        assert code == 0, output
        assert ("no time_sigma column" in output) == (name == "trigger")
        tables[name] = pd.read_csv(eo)
    offset = frame_errors(tables["trigger"].assign(time=truth["time"].to_numpy()),
                          tables["exact"].assign(time=truth["time"].to_numpy()))
    speed = np.hypot(*np.gradient(_local_ne(truth), truth["time"].to_numpy(), axis=0).T)
    expected = speed * _latency(flight)
    horizontal = np.hypot(offset["north"], offset["east"])
    assert np.median(np.abs(horizontal - expected)) < 0.2 * np.median(expected)   # the latency is what moved
    for axis, column in (("north", "sigma_n"), ("east", "sigma_e")):
        added = np.sqrt(np.maximum(tables["trigger"][column] ** 2 - tables["exact"][column] ** 2, 0.0))
        assert np.all(np.abs(offset[axis]) <= 2.0 * added + 0.05), axis
        # the added sigma is the speed along that axis times 0.1 s, not a blanket inflation
        assert np.max(added) <= 1.2 * 0.1 * np.max(speed)


def _local_ne(frames: pd.DataFrame) -> np.ndarray:
    """North and east [m] of the frames from the first, on a local tangent plane (short flights)."""
    lat, lon = np.radians(frames["lat"].to_numpy()), np.radians(frames["lon"].to_numpy())
    radius = 6378137.0
    return np.column_stack([(lat - lat[0]) * radius, (lon - lon[0]) * radius * np.cos(lat[0])])


def test_the_arguments_name_one_way_in(flight, tmp_path):
    paths = write_generic(flight, tmp_path)
    code, output = _process(["--imu", str(paths["imu.csv"]), "--gnss", str(paths["gnss.csv"])])
    assert code == 2 and "--events" in output
    write_dataflash(flight, tmp_path / "flight.bin")
    code, output = _process([str(tmp_path / "flight.bin"), str(paths["events.csv"])])
    assert code == 2 and "brings its own camera events" in output
    code, output = _process([str(paths["imu.csv"])])
    assert code == 2 and "needs its exposure times" in output
