"""IMU error models in the units datasheets use, with named presets.

The same description drives the simulator (to corrupt ideal measurements) and the fusion filters (as
process noise), so a user who types in a datasheet gets a consistent model everywhere.

Datasheet units -> SI:

* angle random walk ARW [deg/sqrt(h)] -> white rate noise PSD ``(ARW * pi/180 / 60)^2`` [rad^2/s];
* velocity random walk VRW [m/s/sqrt(h)] -> white specific-force noise PSD ``(VRW / 60)^2`` [m^2/s^3];
* bias instability [deg/h] or [mg] with correlation time [s] -> first-order Gauss-Markov process;
* turn-on bias [deg/h] or [mg] -> a random constant per run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from georef.frames.earth import STANDARD_GRAVITY

G0 = STANDARD_GRAVITY  # m/s^2 per g, for mg conversions
DEG_PER_HOUR = math.pi / 180.0 / 3600.0  # rad/s per deg/h


@dataclass(frozen=True)
class ImuErrorModel:
    """A strapdown IMU's stochastic errors, in datasheet units."""

    gyro_arw_deg_rt_h: float
    gyro_turn_on_bias_deg_h: float
    gyro_bias_instability_deg_h: float
    gyro_bias_corr_time_s: float
    accel_vrw_mps_rt_h: float
    accel_turn_on_bias_mg: float
    accel_bias_instability_mg: float
    accel_bias_corr_time_s: float

    # --- SI views -------------------------------------------------------------------------------
    @property
    def gyro_white_psd(self) -> float:
        """White rate-noise power spectral density [rad^2/s]."""
        return (math.radians(self.gyro_arw_deg_rt_h) / 60.0) ** 2

    @property
    def accel_white_psd(self) -> float:
        """White specific-force noise power spectral density [m^2/s^3]."""
        return (self.accel_vrw_mps_rt_h / 60.0) ** 2

    @property
    def gyro_turn_on_sigma(self) -> float:
        """Turn-on gyro bias standard deviation [rad/s]."""
        return self.gyro_turn_on_bias_deg_h * DEG_PER_HOUR

    @property
    def gyro_markov_sigma(self) -> float:
        """Steady-state standard deviation of the Gauss-Markov gyro bias [rad/s]."""
        return self.gyro_bias_instability_deg_h * DEG_PER_HOUR

    @property
    def accel_turn_on_sigma(self) -> float:
        """Turn-on accelerometer bias standard deviation [m/s^2]."""
        return self.accel_turn_on_bias_mg * 1e-3 * G0

    @property
    def accel_markov_sigma(self) -> float:
        """Steady-state standard deviation of the Gauss-Markov accelerometer bias [m/s^2]."""
        return self.accel_bias_instability_mg * 1e-3 * G0


#: Named presets. Values are representative of the class, not of one serial number.
IMU_PRESETS: dict[str, ImuErrorModel] = {
    # MEMS IMU of the iMAR iVRU-RSSC class flown by Bošnjak (2014; docs/method-axis.md, References).
    "mems-ivru": ImuErrorModel(
        gyro_arw_deg_rt_h=0.15, gyro_turn_on_bias_deg_h=20.0, gyro_bias_instability_deg_h=3.0,
        gyro_bias_corr_time_s=300.0, accel_vrw_mps_rt_h=0.06, accel_turn_on_bias_mg=2.0,
        accel_bias_instability_mg=0.05, accel_bias_corr_time_s=300.0,
    ),
    # Consumer-grade MEMS (drones).
    "mems-consumer": ImuErrorModel(
        gyro_arw_deg_rt_h=0.6, gyro_turn_on_bias_deg_h=360.0, gyro_bias_instability_deg_h=15.0,
        gyro_bias_corr_time_s=100.0, accel_vrw_mps_rt_h=0.2, accel_turn_on_bias_mg=20.0,
        accel_bias_instability_mg=0.2, accel_bias_corr_time_s=100.0,
    ),
    # Consumer / phone-grade MEMS (smartphone or cheap flight-controller IMU): noise densities of about
    # 0.008 deg/s/sqrt(Hz) and 200 ug/sqrt(Hz), zero-rate offset of about 1 deg/s (0.017 rad/s) and
    # zero-g offset of about 30 mg (0.3 m/s^2) at turn-on. Larger forced biases: SimConfig.gyro_bias_rad_s.
    "consumer-phone": ImuErrorModel(
        gyro_arw_deg_rt_h=0.5, gyro_turn_on_bias_deg_h=3600.0, gyro_bias_instability_deg_h=20.0,
        gyro_bias_corr_time_s=100.0, accel_vrw_mps_rt_h=0.12, accel_turn_on_bias_mg=30.0,
        accel_bias_instability_mg=0.2, accel_bias_corr_time_s=100.0,
    ),
    # The IMU of an autopilot's flight controller (ArduPilot, PX4: InvenSense/TDK, Bosch parts) as its log holds
    # it: the autopilot removes the gyro offsets it measures at boot (a tenth of a deg/s stays) and its accelerometer
    # calibration leaves tens of mg; the board warms by 10-20 degC over the first minutes of a flight, and the
    # biases follow (about 0.01-0.05 deg/s and 1-5 mg per degC; ICM-20602 datasheet: +-0.05 deg/s/degC zero-rate
    # and +-1 mg/degC zero-g), which a Gauss-Markov process of that size and a few minutes describes; noise
    # densities of about 0.005 deg/s/sqrt(Hz) and 100-200 ug/sqrt(Hz).
    "autopilot": ImuErrorModel(
        gyro_arw_deg_rt_h=0.3, gyro_turn_on_bias_deg_h=360.0, gyro_bias_instability_deg_h=720.0,
        gyro_bias_corr_time_s=300.0, accel_vrw_mps_rt_h=0.1, accel_turn_on_bias_mg=50.0,
        accel_bias_instability_mg=15.0, accel_bias_corr_time_s=300.0,
    ),
    # Tactical-grade FOG IMU.
    "tactical-fog": ImuErrorModel(
        gyro_arw_deg_rt_h=0.02, gyro_turn_on_bias_deg_h=1.0, gyro_bias_instability_deg_h=0.3,
        gyro_bias_corr_time_s=1000.0, accel_vrw_mps_rt_h=0.03, accel_turn_on_bias_mg=0.5,
        accel_bias_instability_mg=0.02, accel_bias_corr_time_s=1000.0,
    ),
}


#: which hardware each preset fits, in a line (``--help``)
PRESET_FITS: dict[str, str] = {
    "mems-ivru": "a survey POS unit's MEMS IMU (iMAR iVRU class; the default for POS.txt)",
    "mems-consumer": "consumer MEMS at a steady temperature (warmed up or temperature-compensated)",
    "consumer-phone": "a phone's or a cheap board's IMU without calibration (deg/s of gyro bias)",
    "autopilot": "an autopilot's flight controller (ArduPilot, PX4) with its warm-up drift (the default for their "
                 "logs)",
    "tactical-fog": "a tactical-grade fibre-optic-gyro IMU",
}


def presets_help() -> str:
    """Every preset with the hardware it fits, for a command's ``--help``."""
    return "; ".join(f"{name}: {PRESET_FITS.get(name, '')}" for name in IMU_PRESETS)


def imu_preset(name: str) -> ImuErrorModel:
    """The preset called ``name``; raises ``KeyError`` naming the known presets."""
    try:
        return IMU_PRESETS[name]
    except KeyError:
        raise KeyError(f"unknown IMU preset {name!r}; known: {', '.join(IMU_PRESETS)}") from None


def white_noise_sigma(samples: np.ndarray) -> np.ndarray:
    """Per-column white-noise standard deviation estimated from first differences (robust MAD)."""
    diffs = np.diff(samples, axis=0)
    mad = np.median(np.abs(diffs - np.median(diffs, axis=0)), axis=0)
    return 1.4826 * mad / np.sqrt(2.0)
