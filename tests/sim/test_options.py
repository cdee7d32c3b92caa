"""georef.sim.options: georef simulate's options checked against the vehicle and turned into its configuration."""

from __future__ import annotations

import numpy as np
import pytest

from georef.option_values import OptionError
from georef.sim.options import SimOptions, sim_config


@pytest.mark.parametrize(("options", "message"), [
    (SimOptions(vehicle="boat"), "--vehicle must be one of"),
    (SimOptions(hover=3.0), "--hover applies to --vehicle multicopter only"),
    (SimOptions(speed=5.0), "--speed applies to --vehicle multicopter, drone or car"),
    (SimOptions(vehicle="car", start="ground"), "--start applies to --vehicle drone only"),
    (SimOptions(vehicle="drone", gnss_sigma="1,1,1"), "--gnss-sigma applies to --vehicle helicopter"),
    (SimOptions(vehicle="car", unit_yaw_drift=3.0), "--unit-yaw-drift applies to --vehicle helicopter only"),
    (SimOptions(gnss_sigma="1,1,0"), "--gnss-sigma must be three positive metres"),
    (SimOptions(unit_yaw_drift=float("nan")), "--unit-yaw-drift must be a finite number"),
    (SimOptions(vehicle="drone", vibration="rotor"), "--vibration for the drone: only none"),
])
def test_an_option_the_vehicle_does_not_take_is_refused(options, message):
    with pytest.raises(OptionError, match=message):
        sim_config(options)


def test_the_options_given_reach_the_configuration():
    cfg = sim_config(SimOptions(vehicle="car", duration=30.0, rate=100.0, gnss_rate=5.0, gyro_bias="0,0,1",
                                accel_bias="0.1,0,0", outage=["5,2"], speed=10.0))
    assert cfg.pos_rate_hz == 100.0 and cfg.gnss.rate_hz == 5.0 and cfg.gnss.outages == [(5.0, 2.0)]
    assert cfg.gyro_bias_rad_s == pytest.approx((0.0, 0.0, np.radians(1.0)))
    assert cfg.accel_bias_mps2 == (0.1, 0.0, 0.0) and cfg.plan.cruise_speed_mps == 10.0
    drone = sim_config(SimOptions(vehicle="drone", seed=3, camera_rate=2.0, vibration="none", hover=12.0))
    assert drone.vibration is None and drone.camera_trigger.mode == "time"
    assert drone.camera_trigger.interval_s == 0.5 and drone.plan.survey.hover_s == 12.0
