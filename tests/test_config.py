"""flight.toml sections: each checks its own keys, names a bad one as section.key, and writes back unchanged."""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path

import pytest

from georef.config import (
    AxisSettings,
    ConfigValueError,
    GraphSettings,
    InsSettings,
    MountingSection,
    ProcessingConfig,
    config_to_toml,
    load_config,
    load_configs,
)
from georef.io.errors import InputError

DATA = Path(__file__).resolve().parent.parent / "data"

#: (section, key, bad TOML value, words the message must hold); one or more per section
BAD_VALUES = [
    ("processing", "method", '"kalman"', "'rts', 'ekf', 'axis' or 'graph'"),
    ("processing", "attitude_source", '"gps"', "'unit' or 'imu'"),
    ("mounting", "lever_arm_gnss", "[1, 2]", "three numbers"),
    ("mounting", "boresight", '["a", "b", "c"]', "three numbers"),
    ("mounting", "lever_arm_gnss_sigma", "-0.1", "positive metres"),
    ("gnss", "gnss_sigma", "[1, 0, 2]", "positive metres"),
    ("gnss", "gnss_rate_hz", "0", "positive Hz"),
    ("gnss", "gnss_latency_sigma", "0", "positive seconds"),
    ("gnss", "gnss_latency", '"0.1"', "must be float"),
    ("gnss", "gnss_correlation_time", "-5", "0 (white errors) or positive seconds"),
    ("camera", "camera_utc_offset", '"+2"', "must be float"),
    ("camera", "camera_time_offset", "true", "must be float"),
    ("output", "height", '"geoid"', "'ellipsoidal' or 'orthometric'"),
    ("output", "crs", "3765", "must be str"),
    ("output", "odm_angles", '"yes"', "must be bool"),
    ("yaw_offset", "yaw_step", "0", "positive seconds"),
    ("unit", "unit_level_sigma", "-1", "positive degrees"),
    ("unit", "unit_drift_change", "-0.1", "must not be negative"),
    ("unit", "unit_aiding", "1", "must be bool"),
    ("axis", "axis_accel_sigma", "0", "positive m/s^2"),
    ("gnss_gate", "gate_chi2", "-3", "must be positive"),
    ("ins", "imu_preset", '"navigation-grade"', "not a known IMU preset"),
    ("ins", "covariance_rate", "0", "positive Hz"),
    ("ins", "vehicle", '"boat"', "'auto', 'ground' or 'air'"),
    ("graph", "graph_solver", '"gauss-newton"', "'lm' or 'isam2'"),
    ("graph", "graph_scale_factor_sigma", "0.5", "between 0"),
    ("graph", "graph_robust", '"no"', "must be bool"),
    ("pos_columns", "lat", '""', "header name as a string"),
    ("camera_columns", "frame_number", '"Frame"', "known: number, time, milliseconds"),
    ("imu", "gyro_arw_deg_rt_h", '"0.1"', "must be a number"),
    ("imu", "gyro_noise", "0.1", "unknown key"),
    # NaN passes every comparison: a NaN latency once froze the alignment for good, a NaN lever arm reached LAPACK
    ("gnss", "gnss_latency", "nan", "must be finite"),
    ("gnss", "gnss_latency", "inf", "must be finite"),
    ("mounting", "lever_arm_gnss", "[0.45, nan, -1.65]", "three finite numbers [m]"),
    ("gnss", "gnss_sigma", "[1.0, 1.0, nan]", "finite"),
    ("camera", "camera_time_offset", "-inf", "must be finite"),
    ("ins", "magnetic_declination", "nan", "must be finite"),
]


@pytest.mark.parametrize(("section", "key", "value", "words"), BAD_VALUES, ids=[f"{s}.{k}" for s, k, *_ in BAD_VALUES])
def test_each_section_rejects_its_own_bad_values_naming_section_key(tmp_path, section, key, value, words):
    path = tmp_path / "flight.toml"
    path.write_text(f'# a flight\n[processing]\nmethod = "rts"\n\n[{section}]\n{key} = {value}\n', encoding="utf-8")
    if section == "processing":
        path.write_text(f"# a flight\n[{section}]\n\n{key} = {value}\n", encoding="utf-8")
    with pytest.raises(InputError) as caught:
        load_config(path)
    error = caught.value
    assert error.column == f"{section}.{key}"
    assert error.line == 4 if section == "processing" else error.line == 6
    assert words in error.message
    assert f"line {error.line}" in str(error) and str(path) in str(error)


@pytest.mark.parametrize(("key", "value", "where"), [
    ("vehicle", "boat", "ins.vehicle"), ("gnss_sigma", (1.0, -1.0, 2.0), "gnss.gnss_sigma"),
    ("graph_solver", "cg", "graph.graph_solver"), ("image_names", 7, "output.image_names"),
    ("camera_columns", {"frame": "F"}, "camera_columns.frame")])
def test_updated_refuses_a_bad_value_naming_section_key(key, value, where):
    with pytest.raises(ConfigValueError) as caught:
        ProcessingConfig().updated(**{key: value})
    assert caught.value.key == where and where in str(caught.value)


def _non_default() -> ProcessingConfig:
    """A configuration whose every value differs from the defaults (floats with all their digits)."""
    return ProcessingConfig().updated(
        method="graph", attitude_source="imu",
        lever_arm_gnss=(0.4512345678901, -0.15, -1.65), lever_arm_camera=(1.1, -0.25, 0.55),
        boresight=(0.35, -0.6, 1.2), lever_arm_gnss_sigma=(0.02, 0.03, 0.1),
        gnss_sigma=(0.05, 0.06, 0.1), gnss_rate_hz=5.0, gnss_latency=0.012, gnss_latency_sigma=0.004,
        gnss_correlation_time=120.0,
        camera_utc_offset=2.0, camera_time_offset=-0.0375, camera_time_sigma=0.004,
        crs="EPSG:3765+5773", height="orthometric", vertical_crs="EPSG:3900", image_names="IMG_{frame:04d}.JPG",
        odm_angles=True,
        yaw_window=90.0, yaw_step=10.0, yaw_bandwidth=600.0,
        unit_level_sigma=0.03, unit_yaw_sigma=0.08, unit_level_time=120.0, unit_angle_noise=0.005,
        unit_drift_change=0.01, unit_aiding=False,
        axis_accel_sigma=0.3, axis_bias_sigma=0.01, axis_bias_time=90.0,
        gate_chi2=1.0 / 3.0,
        imu_preset="tactical-fog", covariance_rate=5.0, magnetic_declination=4.5, vehicle="ground",
        graph_solver="isam2", graph_robust=False, graph_scale_factor_sigma=0.002,
        pos_columns={"lat": "Latitude \"deg\"", "lon": "Longitude"},
        camera_columns={"number": "Frame", "time": "UTC s"},
        imu={"gyro_arw_deg_rt_h": 0.15, "accel_turn_on_bias_mg": 0.7})


def test_toml_round_trip_keeps_non_default_values_of_every_section(tmp_path):
    cfg = _non_default()
    default = ProcessingConfig()
    for section in fields(ProcessingConfig):  # the test covers every key: none is left at its default
        for f in fields(getattr(cfg, section.name)):
            assert getattr(getattr(cfg, section.name), f.name) != getattr(getattr(default, section.name), f.name), \
                f"{section.name}.{f.name}"
    path = tmp_path / "flight.toml"
    path.write_text(config_to_toml(cfg), encoding="utf-8")
    assert load_config(path) == cfg
    # a later file changes only the keys it names (flight.toml, then a campaign's calibration.toml)
    later = tmp_path / "calibration.toml"
    later.write_text("[mounting]\nlever_arm_gnss = [0.5, 0.2, -1.6]\n", encoding="utf-8")
    both = load_configs([path, later])
    assert both.mounting.lever_arm_gnss == (0.5, 0.2, -1.6)
    assert both == cfg.updated(lever_arm_gnss=(0.5, 0.2, -1.6))


def test_bundled_flight_toml_loads_into_its_sections():
    cfg = load_config(DATA / "flight.toml")
    assert cfg.processing.method == "rts"
    assert cfg.mounting == MountingSection(lever_arm_gnss=(0.45, 0.15, -1.65), lever_arm_camera=(1.1, -0.25, 0.55),
                                           boresight=(0.35, -0.6, 1.2))
    assert cfg.gnss.sigma == (1.0, 1.0, 2.0) and cfg.gnss.rate_hz == 1
    assert cfg.output.crs == "EPSG:3765"
    assert (cfg.unit.angle_noise, cfg.unit.drift_change, cfg.unit.level_sigma) == (0.01, 0.01, 0.05)
    assert cfg.ins.imu_preset == "mems-ivru" and cfg.ins.covariance_rate == 2
    # and written back it reads the same
    assert config_to_toml(cfg).count("[") >= 10


def test_unknown_section_and_key_name_their_line(tmp_path):
    path = tmp_path / "flight.toml"
    path.write_text("[mounting]\nlever_arm_gnss = [1, 2, 3]\n\n[kalman]\nq = 1\n", encoding="utf-8")
    with pytest.raises(InputError) as caught:
        load_config(path)
    assert (caught.value.line, caught.value.column) == (4, "kalman") and "known: processing" in caught.value.message
    path.write_text("[gnss]\ngnss_sigma = [1, 1, 2]\nsigma = [1, 1, 2]\n", encoding="utf-8")
    with pytest.raises(InputError) as caught:
        load_config(path)
    assert (caught.value.line, caught.value.column) == (3, "gnss.sigma")
    assert "gnss_correlation_time, gnss_latency, gnss_latency_sigma, gnss_rate_hz, gnss_sigma" in caught.value.message


def test_updated_takes_flight_toml_keys_and_whole_sections():
    cfg = ProcessingConfig()
    changed = cfg.updated(gnss_sigma=(2, 2, 4), method="axis", crs=None, vehicle="air")
    assert changed.gnss.sigma == (2.0, 2.0, 4.0) and changed.processing.method == "axis"
    assert changed.ins.vehicle == "air" and changed.output.crs is None
    assert changed.gnss.rate_hz == cfg.gnss.rate_hz and cfg.gnss.sigma == (1.0, 1.0, 2.0)  # the original is kept
    assert cfg.updated(gnss=changed.gnss).gnss is changed.gnss
    assert cfg.updated(pos_columns={"lat": "Lat"}).pos_columns.names == {"lat": "Lat"}
    with pytest.raises(TypeError, match="unknown setting 'sigma'"):
        cfg.updated(sigma=(1, 1, 1))
    with pytest.raises(TypeError, match="ProcessingConfig.gnss must be a GnssSection"):
        cfg.updated(gnss=(1, 1, 1))


def test_solver_settings_hold_only_their_sections():
    cfg = _non_default()
    ins = InsSettings.of(cfg)
    assert (ins.lever_arm_gnss, ins.gnss, ins.gnss_gate, ins.unit, ins.ins, ins.imu, ins.yaw_offset) == (
        cfg.mounting.lever_arm_gnss, cfg.gnss, cfg.gnss_gate, cfg.unit, cfg.ins, cfg.imu, cfg.yaw_offset)
    assert not hasattr(ins, "output") and not hasattr(ins, "graph")
    assert ins.imu_error_model().gyro_arw_deg_rt_h == 0.15
    moved = ins.with_lever_arm([0, 0, 1])
    assert moved.lever_arm_gnss == (0.0, 0.0, 1.0) and moved.gnss is ins.gnss
    graph = GraphSettings.of(cfg)
    assert graph.graph == cfg.graph and graph.lever_arm_gnss_sigma == (0.02, 0.03, 0.1)
    assert type(graph.with_lever_arm((0, 0, 0))) is GraphSettings
    axis = AxisSettings.of(cfg)
    assert axis.axis == cfg.axis and not hasattr(axis, "ins")


def test_a_calibration_prior_is_refused_by_the_methods_without_one(tmp_path):
    from georef.pipeline import process

    prior = ([0.4, 0.1, -1.6, 0.0], [[0.01, 0, 0, 0], [0, 0.01, 0, 0], [0, 0, 0.01, 0], [0, 0, 0, 1e-6]])
    with pytest.raises(ValueError, match="needs method 'graph'"):
        process(tmp_path / "POS.txt", tmp_path / "Kamera.txt", ProcessingConfig(), calibration_prior=prior)


def test_solvers_narrow_a_whole_configuration_to_their_sections(flight_dir, flight_defaults):
    """A library user may hand a solver the whole ``ProcessingConfig``: it is narrowed to the solver's settings at
    the boundary, and the solution is the one the settings give (no AttributeError from deep inside)."""
    import numpy as np

    from georef.config import AxisSettings, InsSettings
    from georef.fusion.axis import solve_axis
    from georef.fusion.ins import inputs_from_pos, solve_ins
    from georef.io.pos import read_pos

    log = read_pos(flight_dir[1]["POS.txt"])
    whole = solve_ins(inputs_from_pos(log), flight_defaults, smooth=False)
    narrowed = solve_ins(inputs_from_pos(log), InsSettings.of(flight_defaults), smooth=False)
    np.testing.assert_array_equal(whole.r_e, narrowed.r_e)
    np.testing.assert_array_equal(whole.att_sigma, narrowed.att_sigma)
    np.testing.assert_array_equal(solve_axis(log, flight_defaults).r_e,
                                  solve_axis(log, AxisSettings.of(flight_defaults)).r_e)


def test_config_round_trip_and_unknown_keys(tmp_path):
    cfg = ProcessingConfig().updated(lever_arm_gnss=(0.5, 0.1, -1.6), boresight=(0.1, 0.2, 0.3), crs="EPSG:3765",
                                     pos_columns={"lat": "Lat"})
    path = tmp_path / "flight.toml"
    path.write_text(config_to_toml(cfg))
    assert load_config(path) == cfg
    path.write_text("[mounting]\nlever_arm = [1, 2, 3]\n")
    with pytest.raises(InputError, match="mounting.lever_arm"):
        load_config(path)
    path.write_text("[mounting\n")
    with pytest.raises(InputError, match="not valid TOML"):
        load_config(path)
