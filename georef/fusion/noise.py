"""The full-state filters' noise model: a prior from the datasheet and the data, adapted to the innovations.

The preset (or the ``[imu]`` datasheet values) is a *prior*, not the answer. The answer is fitted to the data
by expectation-maximisation over the smoother (Shumway & Stoffer 1982, "An approach to time series smoothing
and forecasting using the EM algorithm", J. Time Series Analysis 3(4); Särkkä 2013, "Bayesian Filtering and
Smoothing", ch. 12): each noise *block* — GNSS horizontal and vertical variance, the unit's angle noise, white
specific force and angular rate (horizontal and vertical), bias drives, the unit's error drives — has one scale
factor. A pass of the filter and smoother gives, per block, the smoothed residuals normalised by the block's
modelled covariance (``T``), the normalised posterior variance (``U``) and the number of scalar residuals
(``N``). The EM update of the block's variance ``s`` is ``s (T + U) / N``. It is taken as a maximum a
posteriori step with a conjugate (inverse-gamma) prior of ``PRIOR_WEIGHT`` pseudo-residuals at the datasheet
value, ``s_new = (s (T + U) + ν s_0) / (N + ν)``, so a block the data cannot see stays at its prior instead of
wandering. At the fixed point the smoothed residuals of every block are consistent with their modelled
covariance, which is what the normalised innovations are then checked against.

Units: ``q_*`` are continuous-time densities (m^2/s^3 for specific force, rad^2/s for angular rate, rad^2/s^3
and m^2/s^5 for bias drives), ``r_*`` variances [rad^2], ``tau_*`` correlation times [s], ``r_scale_*``
factors on the GNSS variances.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from georef.fusion import ins_layout as layout
from georef.imu_errors import ImuErrorModel

#: prior sigma [m/s] of a ground vehicle's lateral and vertical body velocity (non-holonomic constraint)
NHC_SIGMA = 0.1
#: sigma [m/s] of the velocity of a vehicle standing still: the ground's give and the IMU's own vibration
ZUPT_SIGMA = 0.02
#: steady-state sigma [m] of the correlated GNSS error when the errors are white: a millimetre, so that its states
#: keep a covariance the smoother can invert and change no result
GNSS_GM_FLOOR_M = 1e-3
#: the spectral floor of the IMU data is read above this frequency [Hz] (a vehicle's own motion is below it),
#: from at most this many 4-s segments spread over the log
MOTION_BAND_HZ = 2.0
MAX_SEGMENTS = 64
#: pseudo-residuals of the prior in the MAP step. Lighter priors let the weakly informed blocks (bias drives, the
#: unit's errors) follow the data further, which made the pitch inside GNSS outages more honest but cost accuracy
#: elsewhere (KITTI's outages, the simulated flights' yaw): docs/performance.md, "INS noise model".
PRIOR_WEIGHT = 10.0
#: one update changes a block by at most this factor
MAX_STEP_FACTOR = 10.0

#: EM block -> the NoiseModel field it scales
BLOCK_FIELDS: dict[int, str] = {
    layout.B_GNSS_H: "r_scale_h", layout.B_GNSS_V: "r_scale_v", layout.B_UNIT_R_LEVEL: "r_unit_level",
    layout.B_UNIT_R_YAW: "r_unit_yaw", layout.B_VEL_H: "q_vel_h", layout.B_VEL_V: "q_vel_v", layout.B_ATT_H: "q_att_h",
    layout.B_ATT_V: "q_att_v", layout.B_BG: "q_bg", layout.B_BA: "q_ba", layout.B_UNIT_LEVEL: "q_unit_level",
    layout.B_UNIT_DRIFT: "q_unit_drift", layout.B_NHC: "r_nhc", layout.B_OUTAGE: "outage_scale",
    layout.B_GNSS_GM_H: "q_gnss_gm_h", layout.B_GNSS_GM_V: "q_gnss_gm_v",
}
#: the white specific force and angular rate: taken from the spectrum of the data (:func:`data_prior`), not
#: fitted to the innovations, which hardly see them and, on real data, mistake correlated GNSS errors for them
WHITE_BLOCKS = (layout.B_VEL_H, layout.B_VEL_V, layout.B_ATT_H, layout.B_ATT_V)
#: the block that only means something with the non-holonomic constraint
NHC_BLOCKS = (layout.B_NHC,)
#: the correlated GNSS error's blocks, estimated when the data favour that model (``ins._Estimation.gnss_model``)
GNSS_GM_BLOCKS = (layout.B_GNSS_GM_H, layout.B_GNSS_GM_V)
#: blocks that only mean something when the unit's attitude aids the filter
UNIT_BLOCKS = (layout.B_UNIT_R_LEVEL, layout.B_UNIT_R_YAW, layout.B_UNIT_LEVEL, layout.B_UNIT_DRIFT)


@dataclass(frozen=True)
class NoiseModel:
    """Noise densities and variances of the full-state filters (SI units, see the module docstring)."""

    q_vel_h: float
    q_vel_v: float
    q_att_h: float
    q_att_v: float
    q_bg: float
    tau_g: float
    q_ba: float
    tau_a: float
    q_unit_level: float
    tau_unit: float
    q_unit_drift: float
    r_unit_level: float
    r_unit_yaw: float
    r_scale_h: float = 1.0
    r_scale_v: float = 1.0
    r_nhc: float = NHC_SIGMA**2
    #: factor on all process noise inside GNSS outages (the error sources that show only without fixes)
    outage_scale: float = 1.0
    #: the correlated part of the GNSS error: Gauss-Markov drives [m^2/s] (north/east, down), correlation time [s];
    #: white errors keep a numerical floor of GNSS_GM_FLOOR_M (the smoother inverts the states' covariance)
    q_gnss_gm_h: float = 2.0 * GNSS_GM_FLOOR_M**2 / 60.0
    q_gnss_gm_v: float = 2.0 * GNSS_GM_FLOOR_M**2 / 60.0
    tau_gnss: float = 60.0
    #: velocity variance of a vehicle standing still [m^2/s^2] (zero-velocity updates)
    r_zupt: float = ZUPT_SIGMA**2
    #: angular-rate variance of one IMU row of a vehicle standing still [rad^2/s^2] (zero angular-rate updates):
    #: the gyros' scatter there (:func:`still_rate_variance`)
    r_zaru: float = 1e-4

    def as_array(self) -> np.ndarray:
        """The kernel's noise vector (``ins_layout.N_NOISE`` entries in the order of its named indices)."""
        out = np.full(layout.N_NOISE, np.nan)
        out[layout.Q_VEL_H], out[layout.Q_VEL_V] = self.q_vel_h, self.q_vel_v
        out[layout.Q_ATT_H], out[layout.Q_ATT_V] = self.q_att_h, self.q_att_v
        # the accelerometer bias's error is a random walk (no decay): a Gauss-Markov decay of tau told the filter
        # that the turn-on bias fades, so over a few tau it learnt the bias, and the level it trades against, from
        # nothing (a hovering or straight-flying drone does not separate them: 2-5 deg off with sigmas of 0.5 deg);
        # tau only sets the drive, q = 2 sigma^2 / tau, which the data then fit. The gyro bias keeps its decay: its
        # trade partner, the heading's drift, is what the motion and the fixes observe
        out[layout.Q_BG], out[layout.INV_TAU_G] = self.q_bg, 1.0 / self.tau_g
        out[layout.Q_BA], out[layout.INV_TAU_A] = self.q_ba, 0.0
        out[layout.Q_UNIT_LEVEL], out[layout.INV_TAU_UNIT] = self.q_unit_level, 1.0 / self.tau_unit
        out[layout.Q_UNIT_DRIFT] = self.q_unit_drift
        out[layout.R_UNIT_LEVEL], out[layout.R_UNIT_YAW] = self.r_unit_level, self.r_unit_yaw
        out[layout.R_SCALE_H], out[layout.R_SCALE_V] = self.r_scale_h, self.r_scale_v
        out[layout.R_NHC] = self.r_nhc
        out[layout.Q_GNSS_GM_H], out[layout.Q_GNSS_GM_V] = self.q_gnss_gm_h, self.q_gnss_gm_v
        out[layout.INV_TAU_GNSS] = 1.0 / self.tau_gnss
        out[layout.R_ZUPT] = self.r_zupt
        out[layout.R_ZARU] = self.r_zaru
        if not np.all(np.isfinite(out)):
            raise AssertionError(f"noise vector slots left unset: {np.flatnonzero(~np.isfinite(out)).tolist()}")
        return out

    def block_value(self, block: int) -> float:
        return float(getattr(self, BLOCK_FIELDS[block]))

    def with_blocks(self, values: dict[int, float]) -> NoiseModel:
        return replace(self, **{BLOCK_FIELDS[b]: float(v) for b, v in values.items()})

    # readable figures for summaries and reports -----------------------------------------------------------
    def gnss_gm_sigma(self) -> tuple[float, float]:
        """Steady-state sigmas [m] of the correlated GNSS error, horizontal (per axis) and vertical."""
        return (float(np.sqrt(self.q_gnss_gm_h * self.tau_gnss / 2.0)),
                float(np.sqrt(self.q_gnss_gm_v * self.tau_gnss / 2.0)))

    @property
    def vrw_h(self) -> float:
        """Horizontal velocity random walk [m/s/sqrt(h)]."""
        return float(np.sqrt(self.q_vel_h) * 60.0)

    @property
    def arw_h(self) -> float:
        """Angle random walk about north/east [deg/sqrt(h)]."""
        return float(np.degrees(np.sqrt(self.q_att_h)) * 60.0)


def datasheet_prior(model: ImuErrorModel, unit_level_sigma_deg: float, unit_level_time_s: float,
                    unit_drift_psd: float, unit_angle_noise_deg: float) -> NoiseModel:
    """The prior from a datasheet model (preset + overrides) and the unit's attitude error settings.

    Biases are Gauss-Markov processes with the datasheet's instability as steady-state sigma, driven by
    ``2 sigma^2 / tau``.
    """
    level = np.radians(unit_level_sigma_deg)
    angle = np.radians(unit_angle_noise_deg) ** 2
    return NoiseModel(
        q_vel_h=model.accel_white_psd, q_vel_v=model.accel_white_psd,
        q_att_h=model.gyro_white_psd, q_att_v=model.gyro_white_psd,
        q_bg=2.0 * model.gyro_markov_sigma**2 / model.gyro_bias_corr_time_s, tau_g=model.gyro_bias_corr_time_s,
        q_ba=2.0 * model.accel_markov_sigma**2 / model.accel_bias_corr_time_s, tau_a=model.accel_bias_corr_time_s,
        q_unit_level=2.0 * level**2 / unit_level_time_s, tau_unit=unit_level_time_s, q_unit_drift=unit_drift_psd,
        r_unit_level=angle, r_unit_yaw=angle)


def spectral_white_noise(time: np.ndarray, gyro: np.ndarray, accel: np.ndarray,
                         motion_hz: float = MOTION_BAND_HZ) -> tuple[float, float, float, float]:
    """White-noise densities the IMU data show, vibration included, at the row rate: the floor of their spectrum.

    Periodograms of 4 s segments (each with its straight line removed and a Hann window; up to
    ``MAX_SEGMENTS`` of them spread over the log) averaged per axis; the density is the median of the bins from
    ``motion_hz`` (above a vehicle's own motion) to 0.9 x Nyquist, halved (two-sided). The median ignores
    narrow-band lines (a rotor's blade-pass frequency and its aliases), which integrate to almost nothing;
    broad-band vibration that does act like white noise raises it. Returns (q_vel_h, q_vel_v [m^2/s^3], q_att_h,
    q_att_v [rad^2/s]), with the body x, y axes taken as horizontal. (Welch's method, written out with numpy:
    scipy's per-segment detrending was slow, ``docs/performance.md``, "INS noise model".)
    """
    dt = float(np.median(np.diff(time)))
    rate = 1.0 / dt
    length = int(round(4.0 * rate))
    count = min(len(time) // max(length, 1), MAX_SEGMENTS)
    if length < 32 or count < 1 or 0.9 * rate / 2.0 <= motion_hz:
        return 0.0, 0.0, 0.0, 0.0
    starts = np.linspace(0, len(time) - length, count).astype(int)
    index = starts[:, None] + np.arange(length)[None, :]
    data = np.concatenate([accel, gyro], axis=1)[index]          # (segments, length, 6)
    x = np.linspace(-1.0, 1.0, length)
    slope = np.einsum("k,skc->sc", x, data) / np.dot(x, x)
    data = data - data.mean(axis=1, keepdims=True) - slope[:, None, :] * x[None, :, None]
    window = np.hanning(length)
    spectrum = np.abs(np.fft.rfft(data * window[None, :, None], axis=1)) ** 2
    density = spectrum.mean(axis=0) * 2.0 / (rate * np.sum(window**2))  # one-sided PSD
    freq = np.fft.rfftfreq(length, dt)
    band = (freq >= motion_hz) & (freq <= 0.9 * rate / 2.0)
    floor = np.median(density[band], axis=0) / 2.0
    return (float(floor[:2].mean()), float(floor[2]), float(floor[3:5].mean()), float(floor[5]))


def data_prior(prior: NoiseModel, time: np.ndarray, gyro: np.ndarray, accel: np.ndarray) -> NoiseModel:
    """The datasheet prior with its white-noise blocks raised to the spectral floor of the data where that is
    larger: vibration that acts as white noise is part of the sensor's noise on this installation."""
    q_vel_h, q_vel_v, q_att_h, q_att_v = spectral_white_noise(time, gyro, accel)
    return replace(prior, q_vel_h=max(prior.q_vel_h, q_vel_h), q_vel_v=max(prior.q_vel_v, q_vel_v),
                   q_att_h=max(prior.q_att_h, q_att_h), q_att_v=max(prior.q_att_v, q_att_v))


def starting_point(prior: NoiseModel) -> NoiseModel:
    """The first pass's noise: the prior with the bias drives raised to consumer grade (``CONSUMER_BIAS_DRIVE``,
    the ``mems-consumer`` preset's instability over its correlation time) where that is larger. An overestimate
    keeps the first pass from trusting the inertial solution more than the data allow (a filter with too little
    process noise diverges and locks out the fixes that could save it); the estimation then brings every block
    to what the data support.
    """
    q_bg, q_ba = consumer_bias_drives()
    return replace(prior, q_bg=max(prior.q_bg, q_bg * prior.tau_g / CONSUMER_TAU),
                   q_ba=max(prior.q_ba, q_ba * prior.tau_a / CONSUMER_TAU))


CONSUMER_TAU = 100.0


def consumer_bias_drives() -> tuple[float, float]:
    """Gauss-Markov drives (q_bg [rad^2/s^3], q_ba [m^2/s^5]) of the ``mems-consumer`` preset's instability."""
    from georef.imu_errors import imu_preset

    model = imu_preset("mems-consumer")
    return (2.0 * model.gyro_markov_sigma**2 / model.gyro_bias_corr_time_s,
            2.0 * model.accel_markov_sigma**2 / model.accel_bias_corr_time_s)


#: the share of a fix's variance the correlated GNSS error starts with (the white rest keeps 1 - this); EM moves it
GNSS_CORRELATED_SHARE = 0.5


def with_gnss_correlation(noise: NoiseModel, sigma_h: float, sigma_v: float, tau: float) -> NoiseModel:
    """``noise`` with the GNSS error split between a white part and a first-order Gauss-Markov part of correlation
    time ``tau`` [s] (0: all white), GNSS_CORRELATED_SHARE of the typical fix variance (``sigma_h``, ``sigma_v``
    [m], per axis) each at the start: a receiver's errors wander together over tens of seconds, and fixes
    treated as independent make the filter follow the wander with sigmas far too small."""
    if tau <= 0.0:
        return noise
    share = GNSS_CORRELATED_SHARE
    return replace(noise, q_gnss_gm_h=2.0 * share * sigma_h**2 / tau, q_gnss_gm_v=2.0 * share * sigma_v**2 / tau,
                   tau_gnss=float(tau), r_scale_h=noise.r_scale_h * (1.0 - share),
                   r_scale_v=noise.r_scale_v * (1.0 - share))


def still_rate_variance(gyro: np.ndarray, still: np.ndarray) -> float | None:
    """The variance [rad^2/s^2] of one gyro sample of a vehicle standing still, from the still rows' scatter about
    their mean (largest axis); None without still rows."""
    if still is None or still.sum() < 10:
        return None
    return float(np.max(np.var(gyro[still], axis=0)))


def inflated(noise: NoiseModel, factor: float) -> NoiseModel:
    """The bias drives and the outage noise multiplied by ``factor``; the white noise (a hypothesis under test)
    and the measurement variances unchanged."""
    return replace(noise, q_bg=noise.q_bg * factor, q_ba=noise.q_ba * factor,
                   outage_scale=noise.outage_scale * factor)


def em_step(noise: NoiseModel, prior: NoiseModel, stats: np.ndarray, blocks: tuple[int, ...],
            prior_weight: float = PRIOR_WEIGHT, accelerated: bool = True,
            max_factor: float = MAX_STEP_FACTOR) -> tuple[NoiseModel, dict[int, float]]:
    """One update of the given blocks from the smoother's statistics (N_BLOCKS, 3) = (T, U, N).

    Plain MAP-EM: ``s (T + U) + ν s0`` over ``N + ν``. Accelerated (default): the variance-component form
    ``(s T + ν s0) / (N - U + ν)`` (Förstner 1979; Koch 1999, "Parameter estimation and hypothesis testing in
    linear models", 3.6), the same fixed point, whose log-step is EM's divided by the share of the block that
    the data inform, ``1 - U/N``: it moves as fast along a weakly informed block as along a well informed one.
    Each step is limited to a factor ``max_factor``. Returns the new model and, per block, the EM ratio
    ``(T + U) / N`` (1 at the fixed point).
    """
    values: dict[int, float] = {}
    ratios: dict[int, float] = {}
    for block in blocks:
        T, U, N = stats[block]
        if N <= 0:
            continue
        current = noise.block_value(block)
        s0 = prior.block_value(block)
        ratios[block] = float((T + U) / N)
        if accelerated:
            new = (current * T + prior_weight * s0) / max(N - U + prior_weight, 1e-9)
        else:
            new = (current * (T + U) + prior_weight * s0) / (N + prior_weight)
        values[block] = float(np.clip(new, current / max_factor, current * max_factor))
    return noise.with_blocks(values), ratios
