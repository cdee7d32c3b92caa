"""Scoring a solution on a real log, without truth: GNSS fixes withheld, and the autopilot's own attitude.

A real log has no truth. Two references stand in for it (the benchmark ``benchmarks/real_logs.py`` and
``tests/end_to_end/test_real_logs.py`` use them):

* **Withheld fixes** (:func:`withheld_windows`, :func:`score_withheld`): from the first GNSS speed of at least
  ``MIN_SPEED`` m/s, the fixes of ``HOLD_S`` of every ``PERIOD_S`` are withheld from the solution and compared with
  its antenna position there, and with straight lines between the kept fixes on either side (linear
  interpolation, what users did before). A window counts only where interpolation's RMS is at least
  ``COUNT_FACTOR`` times the receiver's median reported horizontal accuracy: on straight, slow legs interpolation is
  already at the fixes' noise and shows nothing.
* **The autopilot's attitude** (:func:`compare_attitude`): it comes from the same sensors, so it is not
  independent; its mean difference (the AHRS trim, the board's mounting) is removed and reported, the comparison
  starts at take-off, and yaw is compared only where the heading came from the motion. Logs whose own two
  estimators disagree by more than ``ESTIMATORS_AGREE_DEG`` are not compared (:func:`estimators_agree`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from georef.frames import C_e_n, euler_to_dcm, geodetic_to_ecef, wrap_pi
from georef.frames.mounting import lever_arm_ecef
from georef.fusion.solution import NavSolution
from georef.timing import GnssEpochs

MIN_SPEED = 3.0
HOLD_S = 15.0
PERIOD_S = 45.0
COUNT_FACTOR = 3.0
ESTIMATORS_AGREE_DEG = 5.0


def _fix_ecef(gnss: GnssEpochs) -> np.ndarray:
    return geodetic_to_ecef(np.radians(gnss.lat_deg), np.radians(gnss.lon_deg), gnss.height)


def fix_speed(gnss: GnssEpochs) -> np.ndarray:
    """Horizontal speed [m/s] at each fix, from the fixes on either side."""
    r = _fix_ecef(gnss)
    v = np.gradient(r, gnss.time, axis=0)
    C = C_e_n(np.radians(gnss.lat_deg), np.radians(gnss.lon_deg))
    v_n = np.einsum("nij,nj->ni", C, v)
    return np.hypot(v_n[:, 0], v_n[:, 1])


def withheld_windows(gnss: GnssEpochs) -> np.ndarray:
    """The fixes withheld [bool (K,)]: the first HOLD_S of every PERIOD_S from the first fix whose speed reaches
    MIN_SPEED (none when no fix does)."""
    moving = np.flatnonzero(fix_speed(gnss) >= MIN_SPEED)
    if not len(moving):
        return np.zeros(len(gnss), bool)
    phase = gnss.time - gnss.time[moving[0]]
    return (phase >= 0) & (np.mod(phase, PERIOD_S) < HOLD_S)


@dataclass
class WithheldScore:
    """The solution at the withheld fixes: horizontal RMS [m] of its antenna minus the fix over the counted windows
    (``error_rms_h``), of linear interpolation (``interpolation_rms_h``), the receiver's median horizontal accuracy
    ``eph`` [m], rms(error / sigma) with sigma the solution's and the fix's (``z_rms``), how many windows and fixes
    counted, and per counted window the two RMS."""

    error_rms_h: float
    interpolation_rms_h: float
    eph: float
    z_rms: float
    windows: int
    fixes: int
    window_error_rms_h: list[float]
    window_interpolation_rms_h: list[float]


def _rms_h(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(e[:, :2] ** 2, axis=1)))) if len(e) else float("nan")


def score_withheld(nav: NavSolution, gnss: GnssEpochs, withheld: np.ndarray, lever_arm: np.ndarray) -> WithheldScore:
    """Score ``nav`` (solved without the fixes ``withheld`` of ``gnss``) at those fixes (see the module doc).
    ``lever_arm`` [m, body]: IMU -> antenna."""
    valid = nav.valid
    t = nav.time[valid]
    kept = gnss.without(withheld)
    held = np.flatnonzero(withheld & (gnss.time >= t[0]) & (gnss.time <= t[-1]) & (gnss.time > kept.time[0])
                          & (gnss.time < kept.time[-1]))
    when = gnss.time[held]

    def at(values: np.ndarray) -> np.ndarray:
        return np.interp(when, t, values[valid])

    lat, lon, height = at(nav.lat), at(nav.lon), at(nav.height)
    C_b_n = euler_to_dcm(at(nav.roll), at(nav.pitch), np.interp(when, t, np.unwrap(nav.yaw[valid])))
    antenna = geodetic_to_ecef(lat, lon, height) + lever_arm_ecef(lat, lon, C_b_n, np.asarray(lever_arm, float))
    r_fix = _fix_ecef(gnss)[held]
    C = C_e_n(np.radians(gnss.lat_deg[held]), np.radians(gnss.lon_deg[held]))
    error = np.einsum("nij,nj->ni", C, antenna - r_fix)
    r_kept = _fix_ecef(kept)
    line = np.stack([np.interp(when, kept.time, r_kept[:, k]) for k in range(3)], -1)
    interpolation = np.einsum("nij,nj->ni", C, line - r_fix)
    sigma_fix = gnss.sigma_neu[held] if gnss.sigma_neu is not None else np.ones((len(held), 3))
    eph = float(np.median(gnss.sigma_neu[:, 0])) if gnss.sigma_neu is not None else 1.0
    variance = np.stack([at(nav.pos_var_n[:, k]) for k in range(2)], -1) + sigma_fix[:, :2] ** 2
    z = error[:, :2] / np.sqrt(variance)
    window = np.concatenate([[0], np.cumsum(np.diff(when) > PERIOD_S - HOLD_S)]) if len(when) else np.zeros(0, int)
    counted = np.zeros(len(held), bool)
    per_error, per_line = [], []
    for w in np.unique(window):
        inside = window == w
        if _rms_h(interpolation[inside]) >= COUNT_FACTOR * eph:
            counted |= inside
            per_error.append(_rms_h(error[inside]))
            per_line.append(_rms_h(interpolation[inside]))
    return WithheldScore(error_rms_h=_rms_h(error[counted]), interpolation_rms_h=_rms_h(interpolation[counted]),
                         eph=eph, z_rms=float(np.sqrt(np.mean(z[counted] ** 2))) if counted.any() else float("nan"),
                         windows=len(per_error), fixes=int(counted.sum()), window_error_rms_h=per_error,
                         window_interpolation_rms_h=per_line)


@dataclass
class AttitudeComparison:
    """The solution's roll, pitch, yaw against the autopilot's: the mean difference [deg] (solution minus
    autopilot, reported and removed) and the RMS of the rest [deg]; yaw NaN where not compared; rows compared."""

    mean_difference_deg: np.ndarray
    rms_deg: np.ndarray
    rows: int


def compare_attitude(nav: NavSolution, autopilot_rpy: np.ndarray, since: float, compare_yaw: bool
                     ) -> AttitudeComparison:
    """Compare ``nav`` with the autopilot's roll, pitch, yaw [rad] on the same rows (N, 3), from time ``since``
    [s] (take-off), yaw only when ``compare_yaw`` (the heading came from the motion)."""
    ok = nav.valid & np.all(np.isfinite(autopilot_rpy), axis=1) & (nav.time >= since)
    mine = np.stack([nav.roll, nav.pitch, nav.yaw], -1)[ok]
    difference = np.degrees(wrap_pi(mine - autopilot_rpy[ok]))
    mean = np.degrees(np.angle(np.mean(np.exp(1j * np.radians(difference)), axis=0)))
    rest = np.degrees(wrap_pi(np.radians(difference - mean)))
    rms = np.sqrt(np.mean(rest**2, axis=0))
    if not compare_yaw:
        mean[2] = rms[2] = np.nan
    return AttitudeComparison(mean_difference_deg=mean, rms_deg=rms, rows=int(ok.sum()))


def takeoff_time(gnss: GnssEpochs) -> float:
    """The time [s] of the first fix whose speed reaches MIN_SPEED (the comparisons start there), else the last."""
    moving = np.flatnonzero(fix_speed(gnss) >= MIN_SPEED)
    return float(gnss.time[moving[0]] if len(moving) else gnss.time[-1])


def estimators_agree(first: np.ndarray, second: np.ndarray) -> float:
    """The largest RMS difference [deg] of roll and pitch between an autopilot's two attitude estimates on the same
    rows (N, 3) [rad] (ArduPilot's ATT and AHR2): the autopilot's attitude is a reference only when they agree
    within ESTIMATORS_AGREE_DEG."""
    ok = np.all(np.isfinite(first), axis=1) & np.all(np.isfinite(second), axis=1)
    difference = np.degrees(wrap_pi(first[ok, :2] - second[ok, :2]))
    return float(np.max(np.sqrt(np.mean(difference**2, axis=0))))


@dataclass
class LogScore:
    """A real log scored (:func:`score_log`): the withheld fixes, the attitude against the autopilot's (None
    without one, or when its two estimators disagree: ``estimators_deg`` says by how much, NaN with only one), the
    QC verdict of the run with every fix (the user's), and the heading's source and the solution of the run without
    the withheld fixes."""

    withheld: WithheldScore
    attitude: AttitudeComparison | None
    estimators_deg: float
    verdict: object
    heading_source: str
    nav: NavSolution


def score_log(path, cfg=None, imu_instance: int | None = None) -> LogScore:
    """Read an autopilot log, solve it with every fix for the verdict and without its withheld fixes for the
    scores (the defaults plus what the log says: :func:`georef.pipeline.with_log_defaults`; module doc)."""
    from georef.config import InsSettings, ProcessingConfig
    from georef.fusion.ins import inputs_from_pos, solve_ins
    from georef.io.logs import read_flight_log
    from georef.io.logs.flightlog import rows_of, to_pos_log
    from georef.pipeline import with_log_defaults
    from georef.qc import assess

    flight = read_flight_log(path, imu_instance)
    cfg, _ = with_log_defaults(cfg or ProcessingConfig(), flight)
    withheld = withheld_windows(flight.gnss)
    settings, smooth = InsSettings.of(cfg), cfg.processing.method != "ekf"
    log = to_pos_log(flight)
    # the verdict is the one of the run a user makes, with every fix
    verdict = assess(solve_ins(inputs_from_pos(log), settings, smooth=smooth), cfg=cfg, kind=flight.kind)
    log.gnss = flight.gnss.without(withheld)
    nav = solve_ins(inputs_from_pos(log), settings, smooth=smooth)
    score = score_withheld(nav, flight.gnss, withheld, np.asarray(cfg.mounting.lever_arm_gnss))
    agree = float("nan")
    comparison = None
    if flight.attitude is not None:
        autopilot = rows_of(flight.attitude, nav.time, angles=True)
        if flight.attitude_backup is not None:
            agree = estimators_agree(autopilot, rows_of(flight.attitude_backup, nav.time, angles=True))
        if not agree > ESTIMATORS_AGREE_DEG:
            heading = str(nav.diagnostics.heading_source)
            comparison = compare_attitude(nav, autopilot, takeoff_time(flight.gnss), heading.startswith("motion"))
    return LogScore(withheld=score, attitude=comparison, estimators_deg=agree, verdict=verdict,
                    heading_source=str(nav.diagnostics.heading_source), nav=nav)
