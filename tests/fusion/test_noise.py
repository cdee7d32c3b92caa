"""The noise model (georef.fusion.noise) against what was injected: the spectral white-noise floor read off a
simulated log, and the GNSS noise scales estimated from the innovations when the configured sigma is misstated."""

from __future__ import annotations

import numpy as np
import pytest

from georef.config import InsSettings, ProcessingConfig
from georef.evaluate import frame_errors
from georef.fusion.ins import inputs_from_pos
from georef.fusion.noise import spectral_white_noise
from georef.io.pos import read_pos
from georef.pipeline import process
from georef.sim.files import installation_config, write_flight
from georef.sim.flight import SimConfig, simulate
from georef.sim.sensors import GnssModel, VibrationModel


# ---- the spectral floor --------------------------------------------------------------------------------------
@pytest.mark.parametrize(("kind", "level"), [("none", 0.0), ("white", 1.0), ("white", 2.0), ("rotor", 1.0)])
def test_spectral_floor_reads_the_injected_white_noise(tmp_path, kind, level):
    """The white-noise densities read off a simulated log against what was injected: the datasheet's angle and
    velocity random walk plus, for white vibration, its variance at 200 Hz over 200 Hz (averaged to the row
    rate). A rotor's blade-pass line is narrow: it must not raise the floor."""
    vibration = None if kind == "none" else VibrationModel.of_kind(kind, level)
    flight = simulate(SimConfig(seed=4, vibration=vibration))
    paths = write_flight(flight, tmp_path)
    inputs = inputs_from_pos(read_pos(paths["POS.txt"]))
    t, gyro, accel = inputs.time, inputs.gyro, inputs.accel
    q_vel_h, q_vel_v, q_att_h, q_att_v = spectral_white_noise(t, gyro, accel)
    model = InsSettings.of(ProcessingConfig()).imu_error_model()
    q_att = model.gyro_white_psd
    q_vel = model.accel_white_psd
    if kind == "white":
        accel_sigma, gyro_sigma = VibrationModel.of_kind("white", level).amplitudes()
        q_att = q_att + gyro_sigma[0] ** 2 / 200.0
        q_vel = q_vel + accel_sigma[0] ** 2 / 200.0
        q_vel_down = model.accel_white_psd + accel_sigma[2] ** 2 / 200.0
    else:
        q_vel_down = q_vel
    for measured, injected in ((q_att_h, q_att), (q_att_v, q_att), (q_vel_h, q_vel), (q_vel_v, q_vel_down)):
        assert injected / 1.3 <= measured <= injected * 1.3, (measured, injected)


# ---- the noise estimation against a misstated GNSS sigma ---------------------------------------------------------
def test_a_misstated_gnss_sigma_is_estimated_from_the_innovations(tmp_path):
    """The receiver's fixes scatter twice as much as the configured (default) sigmas say: the GNSS variance
    scales come out near 4, the innovations agree with their chi-square distribution, and the sigmas of the
    frames stay honest."""
    z_all = []
    for seed in (1, 2, 3):
        flight = simulate(SimConfig(seed=seed, gnss=GnssModel(sigma_neu_m=(2.0, 2.0, 4.0))))
        paths = write_flight(flight, tmp_path / str(seed))
        result = process(paths["POS.txt"], paths["Kamera.txt"], installation_config(flight))
        noise = result.nav.diagnostics.noise
        assert 2.5 <= noise.r_scale_h <= 6.0 and 2.5 <= noise.r_scale_v <= 6.0, (noise.r_scale_h, noise.r_scale_v)
        used = result.nav.gnss.status == 1
        assert 2.5 <= float(np.mean(result.nav.diagnostics.nis[used])) <= 3.5
        errors = frame_errors(result.table, flight.truth_frames)
        z_all.append(np.stack([errors[c] / result.table[s] for c, s in
                               (("north", "sigma_n"), ("east", "sigma_e"), ("up", "sigma_u"))], -1))
    z = np.concatenate(z_all)
    share = np.mean(np.abs(z) <= 2.0, axis=0)
    rms = np.sqrt(np.mean(z**2, axis=0))
    print("inside 2 sigma", share, "rms(z)", rms)
    assert (share >= 0.90).all(), share
    assert (rms >= 0.5).all(), rms
