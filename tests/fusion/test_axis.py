"""The per-axis method of Bošnjak (2014; docs/method-axis.md) against truth on simulated flights like his.

Flights: MEMS IMU with rotor vibration, 30 m/s, ~4 deg crab, GNSS sigma 1/1/2 m, 50 Hz POS rows,
unknown and drifting unit yaw origin, lever arms and boresight.
"""

from __future__ import annotations

import numpy as np
import pytest

from georef.evaluate import accuracy, frame_errors, gnss_interpolation_baseline
from georef.frames import wrap_pi
from georef.pipeline import process
from georef.sim.files import processing_config_for, write_flight
from georef.sim.flight import SimConfig, simulate
from georef.sim.sensors import UnitModel

SEEDS = [1, 2, 3, 4, 5]
#: camera yaw RMS bound [deg]. Measured on this file's flights: at most 0.227 (seed 4; the nine yaw origins 0.179,
#: the drifting unit 0.138); the worst of the twenty flights of ``benchmarks/accuracy.py --methods axis`` is 0.370.
#: An origin left uncorrected by 0.4 deg, or a drift not followed, exceeds it.
YAW_RMS_DEG = 0.4


def _run(tmp_path, cfg: SimConfig):
    flight = simulate(cfg)
    paths = write_flight(flight, tmp_path / f"seed{cfg.seed}")
    processing = processing_config_for(flight).updated(method="axis")
    result = process(paths["POS.txt"], paths["Kamera.txt"], processing)
    return flight, result, processing


def _true_offset_at(flight, t):
    return np.interp(t, flight.truth_frames["time"], flight.truth_frames["unit_yaw_offset"])


@pytest.mark.parametrize("seed", SEEDS)
def test_axis_method_against_truth(tmp_path, seed):
    flight, result, processing = _run(tmp_path, SimConfig(seed=seed))
    table = result.table
    # every frame present, none flagged on a clean flight
    assert len(table) == len(flight.exposures)
    assert (table["frame"].astype(int).to_numpy() == flight.exposures["frame"].to_numpy()).all()
    assert table[["lat", "lon", "height", "roll", "pitch", "yaw"]].notna().all().all()

    errors = frame_errors(table, flight.truth_frames)
    figures = accuracy(errors)
    nav = result.nav
    baseline = gnss_interpolation_baseline(result.exposures, result.log.gnss, nav, processing.mounting,
                                          processing.output)
    baseline_figures = accuracy(frame_errors(baseline, flight.truth_frames))
    assert figures["horizontal_rms_m"] < baseline_figures["horizontal_rms_m"]

    solution = nav.axis_info.yaw_offset
    true_offset = _true_offset_at(flight, solution.reference_time)
    assert abs(np.degrees(solution.offset) - true_offset) < 0.5
    assert figures["yaw_rms_deg"] <= YAW_RMS_DEG


def test_axis_method_is_deterministic(tmp_path):
    _, first, _ = _run(tmp_path / "a", SimConfig(seed=3))
    _, second, _ = _run(tmp_path / "b", SimConfig(seed=3))
    np.testing.assert_array_equal(first.table.drop(columns="flag").to_numpy(float),
                                  second.table.drop(columns="flag").to_numpy(float))


@pytest.mark.parametrize("offset_deg", [-179.5, -135.0, -90.0, -30.0, 0.0, 45.0, 90.0, 150.0, 179.5])
def test_yaw_offset_recovered_in_every_quadrant(tmp_path, offset_deg):
    """Bošnjak (2014) used atan and a rounding trick; atan2 on (cos, sin) must work across the whole circle."""
    flight, result, _ = _run(tmp_path, SimConfig(seed=11, unit=UnitModel(yaw_offset_deg=offset_deg)))
    solution = result.nav.axis_info.yaw_offset
    true_offset = np.radians(_true_offset_at(flight, solution.reference_time))
    assert abs(np.degrees(wrap_pi(solution.offset - true_offset))) < 0.5
    errors = frame_errors(result.table, flight.truth_frames)
    assert accuracy(errors)["yaw_rms_deg"] <= YAW_RMS_DEG


def test_yaw_drift_is_followed(tmp_path):
    """A fast-drifting unit (3 deg/min) over 6 minutes: the sliding windows must follow it."""
    cfg = SimConfig(seed=4, unit=UnitModel(yaw_offset_deg=-20.0, yaw_drift_deg_min=3.0))
    cfg.plan.duration_s = 360.0
    flight, result, _ = _run(tmp_path, cfg)
    errors = frame_errors(result.table, flight.truth_frames)
    assert accuracy(errors)["yaw_rms_deg"] <= YAW_RMS_DEG
    assert np.degrees(result.nav.axis_info.yaw_offset.drift) * 60 == pytest.approx(3.0, abs=0.5)
