"""Interpolation of a navigation solution to exposure times.

* Positions: cubic Hermite in ECEF between the bracketing IMU rows, using the ECEF velocities.
* Attitude: SLERP on the rotation group (correct across the +-180 deg yaw wrap).
* Variances and sigmas: linear between rows.
* Between rows farther apart than the log's rows are (an IMU gap: rows lost or deleted), the interpolation's own
  error is added: the vehicle moved in ways the two rows do not show. Its size is measured on the same flight
  (:func:`gap_departure`): how far the solution's attitude and position depart, over spans of the gap's length,
  from the SLERP and the Hermite curve between the span's ends. Such exposures carry the gap's length
  (``imu_gap_s``) for their flag.
* Times outside the solution's valid span are *not* extrapolated; they are marked so the frame gets a
  flagged row with empty values.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from georef.frames import C_e_n, dcm_to_quat, euler_to_dcm
from georef.frames.rotations import attitude_at, quat_to_rotvec, rotvec_to_dcm
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
    #: the length [s] of the span without IMU rows an exposure falls in (0 elsewhere), for its flag
    imu_gap_s: np.ndarray | None = None
    #: the length [s] of such a span that ends or starts within GAP_NEAR_S (or its own length) of an exposure
    #: outside it (0 elsewhere): the smoother's solution there leans on the rows the gap took
    near_imu_gap_s: np.ndarray | None = None


#: rows farther apart than this many times the median row interval bracket an IMU gap
GAP_ROW_FACTOR = 3.0
#: exposures this close to an IMU gap [s] (or the gap's length, when longer) are flagged as near it
GAP_NEAR_S = 1.0
#: the motion of the flight within this many seconds of an IMU gap sizes the interpolation's error there
GAP_LOCAL_S = 20.0


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
    imu_gap_s = np.zeros(k)
    span = nav.time[i1] - nav.time[i0]
    gap = span > GAP_ROW_FACTOR * float(np.median(np.diff(t_valid)))
    if gap.any():
        where = np.flatnonzero(inside)[gap]
        imu_gap_s[where] = span[gap]
        shape = (4.0 * w[gap, 0] * (1.0 - w[gap, 0]))[:, None]   # 0 at the rows, 1 midway
        for start in np.unique(nav.time[i0][gap]):
            this = nav.time[i0][gap] == start
            length = float(span[gap][this][0])
            att_var, pos_var_gap = gap_departure(nav, rows, length, float(start) + 0.5 * length)
            pos_var[where[this]] += (shape[this] ** 2) * pos_var_gap
            if att_cov is not None:
                att_cov[where[this]] += (shape[this, :, None] ** 2) * np.diag(att_var)
            att_sigma[where[this]] = np.sqrt(att_sigma[where[this]] ** 2 + (shape[this] ** 2) * att_var)
    near_imu_gap_s = np.zeros(k)
    wide = np.flatnonzero(np.diff(t_valid) > GAP_ROW_FACTOR * float(np.median(np.diff(t_valid))))
    for start, end in zip(t_valid[wide], t_valid[wide + 1], strict=True):
        margin = max(GAP_NEAR_S, end - start)
        near = inside & (imu_gap_s == 0.0) & (times >= start - margin) & (times <= end + margin)
        near_imu_gap_s[near] = np.maximum(near_imu_gap_s[near], end - start)
    return ExposureStates(times, inside, r_e, v_e, C_b_n, pos_var, att_sigma, att_cov, omega_n, imu_gap_s,
                          near_imu_gap_s)


def gap_departure(nav: NavSolution, rows: np.ndarray, length: float, centre: float) -> tuple[np.ndarray, np.ndarray]:
    """How far the vehicle's motion departs, midway, from what two rows ``length`` [s] apart show: the mean square
    over the spans of that length within GAP_LOCAL_S of ``centre`` [s] (without a gap of their own) of the NED
    rotation from the SLERP between the span's ends to the solution's attitude midway [rad^2] (3,), and of the NED
    offset from the Hermite curve (ends' positions and velocities) to the solution's position midway [m^2] (3,).
    The flight's own dynamics around the gap, so a hovering drone, a turning helicopter and a straight leg each get
    theirs; zeros when there is no span that long."""
    t = nav.time[rows]
    step = float(np.median(np.diff(t)))
    first, last = max(t[0], centre - GAP_LOCAL_S), min(t[-1], centre + GAP_LOCAL_S)
    starts = np.arange(first, last - length, max(length / 4.0, step))
    a = np.searchsorted(t, starts)
    b = np.searchsorted(t, t[a] + length)
    ok = b < len(t)
    a, b = a[ok], b[ok]
    m = np.searchsorted(t, 0.5 * (t[a] + t[b]))
    clean = np.array([np.all(np.diff(t[i:j + 1]) <= GAP_ROW_FACTOR * step) for i, j in zip(a, b, strict=True)],
                     dtype=bool)
    a, b, m = a[clean], b[clean], m[clean]
    if not len(a):
        return np.zeros(3), np.zeros(3)
    ra, rb, rm = rows[a], rows[b], rows[m]
    s = (t[m] - t[a]) / (t[b] - t[a])
    C_a = euler_to_dcm(nav.roll[ra], nav.pitch[ra], nav.yaw[ra])
    C_b = euler_to_dcm(nav.roll[rb], nav.pitch[rb], nav.yaw[rb])
    C_m = euler_to_dcm(nav.roll[rm], nav.pitch[rm], nav.yaw[rm])
    turn = quat_to_rotvec(dcm_to_quat(C_b @ np.swapaxes(C_a, -1, -2)))
    C_line = rotvec_to_dcm(s[:, None] * turn) @ C_a
    departure = quat_to_rotvec(dcm_to_quat(C_m @ np.swapaxes(C_line, -1, -2)))
    curve = hermite(t[m], t[a], t[b], nav.r_e[ra], nav.r_e[rb], nav.v_e[ra], nav.v_e[rb])
    offset = np.einsum("nij,nj->ni", C_e_n(nav.lat[rm], nav.lon[rm]), nav.r_e[rm] - curve)
    return np.mean(departure**2, axis=0), np.mean(offset**2, axis=0)


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
