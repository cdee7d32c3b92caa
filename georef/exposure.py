"""Interpolation of a navigation solution to exposure times.

* Positions: cubic Hermite in ECEF between the bracketing IMU rows, using the ECEF velocities.
* Attitude: SLERP on the rotation group (correct across the +-180 deg yaw wrap).
* Variances and sigmas: linear between rows.
* Times outside the solution's valid span are *not* extrapolated; they are marked so the frame gets a
  flagged row with empty values.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from georef.frames.rotations import attitude_at
from georef.fusion.solution import NavSolution

#: half the span [s] over which the angular velocity at an exposure is read off the attitudes
RATE_STEP_S = 0.05


@dataclass
class ExposureStates:
    """IMU state at each exposure (NaN where ``inside`` is False). Units as in :class:`NavSolution`."""

    time: np.ndarray
    inside: np.ndarray
    r_e: np.ndarray
    v_e: np.ndarray
    C_b_n: np.ndarray
    pos_var_n: np.ndarray
    att_sigma: np.ndarray
    att_cov_n: np.ndarray | None = None
    #: the body's angular velocity in NED [rad/s] (K, 3), for the share of an uncertain exposure time
    omega_n: np.ndarray | None = None


def hermite(t: np.ndarray, t0: np.ndarray, t1: np.ndarray, p0: np.ndarray, p1: np.ndarray,
            v0: np.ndarray, v1: np.ndarray) -> np.ndarray:
    """Cubic Hermite interpolation of (K, 3) positions with velocities between times t0 and t1 [s]."""
    h = (t1 - t0)[:, None]
    s = ((t - t0) / (t1 - t0))[:, None]
    h00 = 2 * s**3 - 3 * s**2 + 1
    h10 = s**3 - 2 * s**2 + s
    h01 = -2 * s**3 + 3 * s**2
    h11 = s**3 - s**2
    return h00 * p0 + h10 * h * v0 + h01 * p1 + h11 * h * v1


def interpolate_to_exposures(nav: NavSolution, times: np.ndarray) -> ExposureStates:
    """The IMU state of ``nav`` at exposure ``times`` [s] (same continuous UTC scale)."""
    times = np.asarray(times, dtype=float)
    rows = np.flatnonzero(nav.valid)
    k = len(times)
    r_e = np.full((k, 3), np.nan)
    v_e = np.full((k, 3), np.nan)
    C_b_n = np.full((k, 3, 3), np.nan)
    pos_var = np.full((k, 3), np.nan)
    att_sigma = np.full((k, 3), np.nan)
    att_cov = None if nav.att_cov_n is None else np.full((k, 3, 3), np.nan)
    if len(rows) < 2:
        return ExposureStates(times, np.zeros(k, bool), r_e, v_e, C_b_n, pos_var, att_sigma, att_cov)
    t_valid = nav.time[rows]
    inside = (times >= t_valid[0]) & (times <= t_valid[-1])
    ti = times[inside]
    upper = np.clip(np.searchsorted(t_valid, ti, side="right"), 1, len(t_valid) - 1)
    i0, i1 = rows[upper - 1], rows[upper]
    r_e[inside] = hermite(ti, nav.time[i0], nav.time[i1], nav.r_e[i0], nav.r_e[i1], nav.v_e[i0], nav.v_e[i1])
    w = ((ti - nav.time[i0]) / (nav.time[i1] - nav.time[i0]))[:, None]
    v_e[inside] = (1 - w) * nav.v_e[i0] + w * nav.v_e[i1]
    pos_var[inside] = (1 - w) * nav.pos_var_n[i0] + w * nav.pos_var_n[i1]
    att_sigma[inside] = (1 - w) * nav.att_sigma[i0] + w * nav.att_sigma[i1]
    if att_cov is not None:
        att_cov[inside] = (1 - w)[:, :, None] * nav.att_cov_n[i0] + w[:, :, None] * nav.att_cov_n[i1]
    C_b_n[inside] = attitude_at(nav.time[rows], nav.roll[rows], nav.pitch[rows], nav.yaw[rows], ti)
    omega_n = np.full((k, 3), np.nan)
    omega_n[inside] = _angular_velocity_n(nav, rows, ti)
    return ExposureStates(times, inside, r_e, v_e, C_b_n, pos_var, att_sigma, att_cov, omega_n)


def _angular_velocity_n(nav: NavSolution, rows: np.ndarray, t: np.ndarray, h: float = RATE_STEP_S) -> np.ndarray:
    """NED angular velocity [rad/s] (K, 3) at times ``t`` from the attitudes ``h`` [s] either side:
    ``C(t+h) C(t-h)^T = exp([ω 2h x])``."""
    t_valid = nav.time[rows]
    before = np.clip(t - h, t_valid[0], t_valid[-1])
    after = np.clip(t + h, t_valid[0], t_valid[-1])
    C0 = attitude_at(t_valid, nav.roll[rows], nav.pitch[rows], nav.yaw[rows], before)
    C1 = attitude_at(t_valid, nav.roll[rows], nav.pitch[rows], nav.yaw[rows], after)
    D = np.einsum("nij,nkj->nik", C1, C0)
    rotvec = 0.5 * np.stack([D[:, 2, 1] - D[:, 1, 2], D[:, 0, 2] - D[:, 2, 0], D[:, 1, 0] - D[:, 0, 1]], -1)
    span = np.maximum(after - before, 1e-6)
    return rotvec / span[:, None]
