"""The simulator makes what it claims: flight geometry as in Bošnjak (2014), consistent truth, stated noise levels."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from georef_cli.main import app
from typer.testing import CliRunner

from georef.frames import C_e_n, geodetic_to_ecef, normal_gravity, radii_of_curvature
from georef.frames.mounting import lever_arm_ecef
from georef.imu_errors import imu_preset
from georef.sim.flight import SimConfig, simulate
from georef.sim.trajectory import FlightPlan, fly


@pytest.fixture(scope="module")
def flight():
    return simulate(SimConfig(seed=2))


def test_flight_geometry_is_seed_like(flight):
    truth = flight.truth_frames
    speed = np.hypot(flight.truth_nav.v_n[:, 0], flight.truth_nav.v_n[:, 1])
    assert 27.0 < np.median(speed) < 33.0
    crab = (truth["body_yaw"] - truth["track"] + 180) % 360 - 180
    assert 3.0 < np.max(np.abs(crab)) < 5.0
    assert np.ptp(flight.truth_nav.height) > 15.0  # climbs
    assert np.degrees(np.max(np.abs(flight.truth_nav.roll))) > 15.0  # coordinated turns


def test_positions_integrate_the_velocities():
    traj = fly(FlightPlan(duration_s=60.0), 400.0)
    M, N = radii_of_curvature(traj.lat)
    lat_rate = np.gradient(traj.lat, traj.time)
    np.testing.assert_allclose(lat_rate[5:-5] * (M + traj.height)[5:-5], traj.v_n[5:-5, 0], atol=2e-3)
    lon_rate = np.gradient(np.unwrap(traj.lon), traj.time)
    np.testing.assert_allclose((lon_rate * (N + traj.height) * np.cos(traj.lat))[5:-5], traj.v_n[5:-5, 1], atol=2e-3)


def test_straight_level_specific_force_is_gravity():
    traj = fly(FlightPlan(duration_s=40.0, turbulence_deg=0.0, climb_every_n_strips=0), 400.0)
    straight = traj.time < 45.0
    g = normal_gravity(traj.lat, traj.height)
    magnitude = np.linalg.norm(traj.f_ib_b, axis=1)
    # Coriolis and transport terms at 30 m/s are a few 1e-3 m/s^2
    np.testing.assert_allclose(magnitude[straight][10:-10], g[straight][10:-10], atol=5e-3)


def test_gnss_noise_has_the_stated_sigma():
    flight = simulate(SimConfig(seed=3, plan=FlightPlan(duration_s=900.0)))
    fixes = flight.gnss_fixes
    nav = flight.truth_nav
    idx = np.searchsorted(nav.time, fixes["time"].to_numpy())
    # truth antenna at the fix time (rows are 12.5 ms after the second: interpolate linearly)
    w = ((fixes["time"].to_numpy() - nav.time[idx - 1]) / (nav.time[idx] - nav.time[idx - 1]))[:, None]
    r_imu = (1 - w) * geodetic_to_ecef(nav.lat[idx - 1], nav.lon[idx - 1], nav.height[idx - 1]) + \
        w * geodetic_to_ecef(nav.lat[idx], nav.lon[idx], nav.height[idx])
    r_ant = r_imu + lever_arm_ecef(nav.lat[idx], nav.lon[idx], nav.C_b_n[idx], flight.config.lever_arm_gnss_m)
    r_fix = geodetic_to_ecef(np.radians(fixes["lat"]), np.radians(fixes["lon"]), fixes["height"])
    err_n = np.einsum("nij,nj->ni", C_e_n(nav.lat[idx], nav.lon[idx]), r_fix - r_ant)
    np.testing.assert_allclose(err_n.std(axis=0), [1.0, 1.0, 2.0], rtol=0.1)


def test_imu_white_noise_matches_the_datasheet():
    from georef.sim.sensors import corrupt_imu

    model = imu_preset("mems-ivru")
    rng = np.random.default_rng(0)
    t = np.arange(200_000) / 200.0
    gyro, accel, gyro_bias, accel_bias = corrupt_imu(np.zeros((len(t), 3)), np.zeros((len(t), 3)), t, model,
                                                     None, rng)
    noise = np.diff(gyro - gyro_bias, axis=0).std(axis=0) / np.sqrt(2)
    np.testing.assert_allclose(noise, np.sqrt(model.gyro_white_psd * 200.0), rtol=0.05)
    noise = np.diff(accel - accel_bias, axis=0).std(axis=0) / np.sqrt(2)
    np.testing.assert_allclose(noise, np.sqrt(model.accel_white_psd * 200.0), rtol=0.05)


def test_same_seed_same_files(tmp_path):
    from georef.sim.files import write_flight

    a = write_flight(simulate(SimConfig(seed=9)), tmp_path / "a")
    b = write_flight(simulate(SimConfig(seed=9)), tmp_path / "b")
    for name in ("POS.txt", "Kamera.txt", "truth.csv"):
        assert a[name].read_bytes() == b[name].read_bytes()


#: Values of the default ``SimConfig()`` flight, computed with the simulator as it was *before* the vehicles,
#: vibration kinds, forced biases and extra outputs were added (git 2514927, unmodified georef/sim). They pin
#: the order of the random draws of the default configuration: any change to it moves every value.
_DEFAULT_POS_ROWS = {
    0: {"ACCS_X": 0.40348450436411504, "ACCS_Y": -0.3746887609562474, "ACCS_Z": -10.040505845403846,
        "OMGS_X": 1.0126313548463302, "OMGS_Y": 3.1420263770803465, "OMGS_Z": -0.6469784407952678,
        "IACC_X": -0.16542612960623265, "ROLL": -0.2137558709214221, "PITCH": 1.7978946259080355,
        "YAW": -36.998760122411085, "LATITUDE": 0.0, "TRIG_TIME": 2451300, "SAMPL_TIME": 12500},
    1234: {"ACCS_X": 0.7352000961722077, "ACCS_Y": 0.17458635869502268, "ACCS_Z": -9.819333051547408,
           "OMGS_X": -0.6847717272103861, "OMGS_Y": -0.8895387063282834, "OMGS_Z": -0.45542919410025073,
           "IACC_X": 0.3885726099382145, "ROLL": -0.6395519891298371, "PITCH": 1.7713141277468005,
           "YAW": -37.1552281303147, "LATITUDE": 44.05294284375384, "LONGITUDE": 15.623659379408785,
           "ALTITUDE": 760.4736488536, "TRIG_TIME": 2453700, "SAMPL_TIME": 692500},
    5000: {"ACCS_X": 0.9281732475727222, "ACCS_Y": -0.3299015485383915, "ACCS_Z": -10.006846488804436,
           "OMGS_X": 0.7503771330918382, "OMGS_Y": -0.7361827944078791, "OMGS_Z": -0.2716360524301891,
           "IACC_X": 0.2012676810178326, "ROLL": -0.4602940828068251, "PITCH": 5.033742505410103,
           "YAW": 142.16818494024028, "LATITUDE": 44.053218895621505, "LONGITUDE": 15.63353947974311,
           "ALTITUDE": 767.2496474897489, "TRIG_TIME": 2461300, "SAMPL_TIME": 12500},
    8999: {"ACCS_X": 0.7119134512089994, "ACCS_Y": 0.3906937570798804, "ACCS_Z": -9.641715987842488,
           "OMGS_X": 0.9943899505297983, "OMGS_Y": 0.2581845945386919, "OMGS_Z": 0.00029216489329884367,
           "IACC_X": 0.4709278642900525, "ROLL": -0.6476486549197529, "PITCH": 2.105228440734848,
           "YAW": -38.540667621579814, "LATITUDE": 44.045623153934265, "LONGITUDE": 15.639529132185894,
           "ALTITUDE": 780.0641668792814, "TRIG_TIME": 2469200, "SAMPL_TIME": 992500},
}


def test_default_flight_is_unchanged():
    """The default configuration gives the flight it gave before the simulator was broadened.

    The expected values were computed from the unmodified code before any edit (see ``_DEFAULT_POS_ROWS``):
    POS rows, turn-on biases, GNSS fixes and per-frame truth of ``SimConfig()`` (seed 1, plan seed 0).
    """
    flight = simulate(SimConfig())
    assert len(flight.pos) == 9000 and len(flight.exposures) == 513 and len(flight.gnss_fixes) == 177
    assert list(flight.pos.columns) == [
        "CNT[HEX]", "ACCS_X", "ACCS_Y", "ACCS_Z", "IACC_X", "IACC_Y", "IACC_Z", "OMGS_X", "OMGS_Y", "OMGS_Z",
        "IOMG_X", "IOMG_Y", "IOMG_Z", "ROLL", "PITCH", "YAW", "VELX", "ODO_TICKS", "MAGNMTR", "TRIG_TIME",
        "SAMPL_TIME", "IMU_TEMP", "SENS_TEMP", "LONGITUDE", "LATITUDE", "ALTITUDE", "VELOCITY", "STATUS[HEX]"]
    for row, values in _DEFAULT_POS_ROWS.items():
        for column, value in values.items():
            np.testing.assert_allclose(flight.pos[column].iloc[row], value, rtol=1e-10, atol=1e-12,
                                       err_msg=f"row {row} {column}")
    np.testing.assert_allclose(flight.gyro_bias[0], [2.4897648485348342e-05, 1.0113852004885259e-04,
                                                     2.5013115836766387e-05], rtol=1e-10)
    np.testing.assert_allclose(flight.accel_bias[0], [0.0337114347646519, -0.03468293962779884,
                                                      -0.00436243498637568], rtol=1e-10)
    fixes = flight.gnss_fixes.iloc[[0, 50, 150]]
    np.testing.assert_array_equal(fixes["time"], [24516.0, 24566.0, 24666.0])
    np.testing.assert_allclose(fixes["lat"], [44.047744099276365, 44.06008433437476, 44.04041693240099], rtol=1e-12)
    np.testing.assert_allclose(fixes["height"], [761.566760676913, 758.9238499542698, 783.7928912574425],
                               rtol=1e-12)
    frames = flight.truth_frames.iloc[[0, 200]]
    np.testing.assert_array_equal(frames["time"], [24519.001, 24585.665])
    np.testing.assert_allclose(frames["lat"], [44.04849371680777, 44.06010909573533], rtol=1e-12)
    np.testing.assert_allclose(frames["height"], [759.46950069163, 759.5827494030818], rtol=1e-10)
    np.testing.assert_allclose(frames["roll"], [0.8017546496150133, 18.405755756848833], rtol=1e-9)
    np.testing.assert_allclose(frames["yaw"], [21.16335135635487, 147.93085836628356], rtol=1e-10)
    np.testing.assert_allclose(frames["unit_yaw_offset"], [57.049904166666664, 57.6054375], rtol=1e-12)


def test_bundled_flight_regenerates(tmp_path):
    """``georef simulate data ...`` (the command in docs/simulator.md) still writes the bundled data/ files.

    Compared value by value to within the last written decimal (the files are byte-identical on the machine
    that made them).
    """
    data = Path(__file__).resolve().parents[2] / "data"
    result = CliRunner().invoke(app, ["simulate", str(tmp_path), "--seed", "1", "--outage", "95,10",
                                      "--outlier", "60,25", "--crs", "EPSG:3765", "--quiet"])
    assert result.exit_code == 0, result.output
    for name, sep in (("POS.txt", "\t"), ("Kamera.txt", "\t"), ("truth.csv", ",")):
        new, old = pd.read_csv(tmp_path / name, sep=sep), pd.read_csv(data / name, sep=sep)
        assert list(new.columns) == list(old.columns) and len(new) == len(old), name
        for column in old.columns:
            if old[column].dtype.kind not in "fi":
                assert (new[column] == old[column]).all(), f"{name} {column}"
                continue
            atol = {"LATITUDE": 1.01e-9, "LONGITUDE": 1.01e-9, "ALTITUDE": 1.01e-4}.get(column, 1.01e-5)
            np.testing.assert_allclose(new[column], old[column], rtol=1e-9, atol=atol if name == "POS.txt" else 0,
                                       err_msg=f"{name} {column}")
