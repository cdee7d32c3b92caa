"""Recovery of the POS unit's unknown yaw origin (the idea of Bošnjak 2014, ``docs/method-axis.md``; made robust).

The unit logs its level-frame kinematic acceleration ``a_u`` (IACC) and its yaw on an azimuth reference
that is rotated by an unknown, drifting angle ``d(t)`` from true north: ``yaw_true = yaw_unit + d`` and,
horizontally, ``a_n = R(d) a_u`` with ``R(d) = [[cos d, -sin d], [sin d, cos d]]`` (north, east).

Within a window of GNSS fixes, double integration of ``a_u`` must reproduce the GNSS track:

    r_n(t) = p0 + v0 tau + b_n tau^2 / 2 + R(d) [A(t) + L(t) - sum_j b_j B_j(t)]

* ``A`` is the double integral of the horizontal ``a_u`` from the window centre;
* ``L`` is the horizontal GNSS lever arm ``C_b_u l_gnss`` (``C_b_u`` from the unit's roll, pitch and yaw),
  so the antenna's motion about the IMU in turns is modelled, not ignored;
* ``B_j`` is the double integral of column j (x, y) of ``C_b_u``: a body-frame accelerometer bias ``b``
  turns with the aircraft and is not a constant in the level frame;
* a level-frame bias ``b_n`` (from the unit's own tilt errors) adds ``b_n tau^2 / 2``.

The model is linear in ``p0, v0, b_n, b`` for a given ``d``. Each window is solved in two steps:

1. a linear start: with ``(c, s) = (cos d, sin d)`` free and the bias taken constant in the level frame,
   ``R(d) v = c v + s J v`` (``J v = [-v_E, v_N]``) makes the model linear, and ``d0 = atan2(s, c)``
   has no quadrant ambiguity;
2. variable projection: ``d`` minimises the residual of the linear least squares in ``(p0, v0, b_n, b)``,
   by Gauss-Newton from ``d0`` (the linear parameters re-solved exactly at each step), with Huber
   reweighting against outliers. The covariance of ``d``
   comes from the full Jacobian at the solution, scaled by the a-posteriori variance factor.

Both steps run compiled (:mod:`georef.fusion.yaw_offset_kernel`): a window solves about twenty small least-squares
problems, and numpy's per-call overhead made them slow (``docs/method-ins.md``, section 10).

Windows slide over the flight; a robust global fit gives the offset and its drift, and a kernel-weighted
local-linear fit follows the drift.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from georef.aot import load as load_kernel
from georef.frames import C_e_n, euler_to_dcm, geodetic_to_ecef, wrap_pi
from georef.frames.mounting import lever_arm_offset

HUBER_K = 1.5


@dataclass
class WindowEstimate:
    """Yaw offsets [rad] estimated per window, at window-centre times [s]."""

    time: np.ndarray
    offset: np.ndarray
    sigma: np.ndarray
    accepted: np.ndarray


@dataclass
class YawOffsetSolution:
    """The recovered yaw offset: ``yaw_true = yaw_unit + offset(t)`` [rad]."""

    windows: WindowEstimate
    reference_time: float
    offset: float            # at reference_time [rad]
    offset_sigma: float      # [rad]
    drift: float             # [rad/s]
    drift_sigma: float       # [rad/s]
    bandwidth: float         # kernel bandwidth of the drift-following fit [s]
    overlap_factor: float    # variance inflation for overlapping windows

    def at(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Offset [rad] and its 1-sigma [rad] at times ``t`` [s], following drift (local-linear kernel fit)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        grid = np.arange(t.min(), t.max() + 1.0, 1.0) if len(t) > 1 else t
        value, sigma = self._local_fit(grid)
        return np.interp(t, grid, value), np.interp(t, grid, sigma)

    def _global(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        dt = t - self.reference_time
        return self.offset + self.drift * dt, np.sqrt(self.offset_sigma**2 + (dt * self.drift_sigma) ** 2)

    def _local_fit(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        w = self.windows
        ok = w.accepted
        if ok.sum() < 3:
            return self._global(t)
        tw = w.time[ok]
        dev = wrap_pi(w.offset[ok] - self.offset)
        var = w.sigma[ok] ** 2 * self.overlap_factor
        kernel = np.exp(-0.5 * ((t[:, None] - tw[None, :]) / self.bandwidth) ** 2)
        weight = kernel / var[None, :]
        x = tw[None, :] - t[:, None]
        s0, s1, s2 = weight.sum(1), (weight * x).sum(1), (weight * x**2).sum(1)
        det = s0 * s2 - s1**2
        support = kernel.sum(1)
        good = (support >= 2.0) & (det > 1e-12 * np.maximum(s0 * s2, 1e-300))
        det = np.where(good, det, 1.0)
        # local-linear estimate at x = 0: weights l_i = (s2 - s1 x_i) w_i / det
        ell = (s2[:, None] - s1[:, None] * x) * weight / det[:, None]
        value = self.offset + (ell * dev[None, :]).sum(1)
        sigma = np.sqrt((ell**2 * var[None, :]).sum(1))
        g_value, g_sigma = self._global(t)
        return np.where(good, value, g_value), np.where(good, np.maximum(sigma, 0.0), g_sigma)


def _cumulative_trapezoid(values: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Running trapezoid integral along axis 0, starting at 0 (scipy's ``cumulative_trapezoid(initial=0)``)."""
    steps = 0.5 * (values[1:] + values[:-1]) * np.diff(t)[:, None]
    return np.concatenate([np.zeros((1, values.shape[1])), np.cumsum(steps, axis=0)])


def _double_integral(values: np.ndarray, imu_time: np.ndarray, at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cumulative single and double trapezoid integrals of (N, ...) samples, interpolated to ``at``."""
    flat = values.reshape(len(values), -1)
    vel = _cumulative_trapezoid(flat, imu_time)
    pos = _cumulative_trapezoid(vel, imu_time)
    interp = [np.stack([np.interp(at, imu_time, x[:, k]) for k in range(flat.shape[1])], -1) for x in (pos, vel)]
    shape = (len(at),) + values.shape[1:]
    return interp[0].reshape(shape), interp[1].reshape(shape)


def window_offsets(
    gnss_time: np.ndarray, gnss_lat_deg: np.ndarray, gnss_lon_deg: np.ndarray, gnss_height: np.ndarray,
    imu_time: np.ndarray, iacc_u: np.ndarray, unit_rpy: np.ndarray, lever_arm_gnss: np.ndarray,
    sigma_ne: tuple[float, float], window: float = 40.0, step: float = 10.0, min_fill: float = 0.7,
) -> WindowEstimate:
    """Yaw offset [rad] per sliding window.

    GNSS fixes: times [s], latitude/longitude [deg], height [m], sigma north/east [m]. IMU rows: times [s],
    IACC [m/s^2] on the unit's level frame, the unit's roll/pitch/yaw [rad] (N, 3), and the body-frame
    GNSS lever arm [m].
    """
    r_e = geodetic_to_ecef(np.radians(gnss_lat_deg), np.radians(gnss_lon_deg), gnss_height)
    C_b_u = euler_to_dcm(unit_rpy[:, 0], unit_rpy[:, 1], unit_rpy[:, 2])
    A_pos, A_vel = _double_integral(iacc_u[:, :2], imu_time, gnss_time)
    B_pos, B_vel = _double_integral(C_b_u[:, :2, :2], imu_time, gnss_time)
    lever_u = lever_arm_offset(C_b_u, lever_arm_gnss)[:, :2]
    L_at = np.stack([np.interp(gnss_time, imu_time, lever_u[:, k]) for k in range(2)], -1)
    inside = (gnss_time >= imu_time[0]) & (gnss_time <= imu_time[-1])
    centres = np.arange(gnss_time[inside][0] + window / 2, gnss_time[inside][-1] - window / 2 + 1e-9, step) \
        if inside.sum() > 1 else np.empty(0)
    rate = 1.0 / np.median(np.diff(gnss_time)) if len(gnss_time) > 1 else 1.0
    out: dict[str, list] = {k: [] for k in ("time", "offset", "sigma", "accepted")}
    sig = np.asarray(sigma_ne, dtype=float)
    solve = load_kernel("yaw").window_solve  # once: a load hashes the kernel's inputs
    for centre in centres:
        sel = np.flatnonzero(inside & (np.abs(gnss_time - centre) <= window / 2))
        n = len(sel)
        if n < max(12, min_fill * window * rate):
            continue
        mid = sel[n // 2]
        C = C_e_n(np.radians(gnss_lat_deg[mid]), np.radians(gnss_lon_deg[mid]))
        r_n = (r_e[sel] - r_e[mid]) @ C.T
        tau = gnss_time[sel] - gnss_time[mid]
        # double integrals from the window centre (their affine parts are absorbed by p0, v0)
        A = A_pos[sel] - A_pos[mid] - A_vel[mid] * tau[:, None] + L_at[sel] - L_at[mid]
        B = B_pos[sel] - B_pos[mid] - B_vel[mid] * tau[:, None, None]
        # the window's solve (module docstring), compiled: georef.fusion.yaw_offset_kernel.window_solve
        d, sigma = solve(r_n, tau, A, B, sig, HUBER_K)
        offset = float(wrap_pi(d))
        out["time"].append(gnss_time[mid])
        out["offset"].append(offset)
        out["sigma"].append(sigma)
        out["accepted"].append(bool(sigma < np.radians(3.0)))
    arrays = {k: np.asarray(v, dtype=float if k != "accepted" else bool) for k, v in out.items()}
    return WindowEstimate(**arrays)


def recover_yaw_offset(
    gnss_time: np.ndarray, gnss_lat_deg: np.ndarray, gnss_lon_deg: np.ndarray, gnss_height: np.ndarray,
    imu_time: np.ndarray, iacc_u: np.ndarray, unit_rpy: np.ndarray, lever_arm_gnss: np.ndarray,
    sigma_ne: tuple[float, float] = (1.0, 1.0), window: float = 40.0, step: float = 10.0,
    bandwidth: float = 300.0,
) -> YawOffsetSolution:
    """Robust yaw offset and drift over the whole flight, with per-window estimates that follow drift.

    Raises ``ValueError`` when no window carries enough horizontal acceleration to see the offset
    (a flight without turns or speed changes cannot reveal it).
    """
    windows = window_offsets(gnss_time, gnss_lat_deg, gnss_lon_deg, gnss_height, imu_time, iacc_u, unit_rpy,
                             lever_arm_gnss, sigma_ne, window=window, step=step)
    # Overlapping windows share fixes, but each window's sigma already carries its a-posteriori variance
    # factor; treated as independent, the offset and drift sigmas were still conservative over simulated flights
    # (docs/performance.md, "Yaw-offset recovery"), so no further inflation is applied.
    overlap = 1.0
    ok = windows.accepted
    if ok.sum() == 0:
        raise ValueError("the yaw offset cannot be recovered: no window of GNSS fixes has enough horizontal "
                         "acceleration (turns or speed changes) to observe it")
    weights = 1.0 / windows.sigma[ok] ** 2
    reference = float(np.arctan2((weights * np.sin(windows.offset[ok])).sum(),
                                 (weights * np.cos(windows.offset[ok])).sum()))
    t_ok = windows.time[ok]
    t_ref = float(np.average(t_ok, weights=weights))
    dev = wrap_pi(windows.offset[ok] - reference)
    sigma_eff = windows.sigma[ok] * np.sqrt(overlap)
    huber_lstsq = load_kernel("yaw").huber_lstsq  # Huber IRLS with the a-posteriori variance factor
    if ok.sum() >= 3 and np.ptp(t_ok) > 0:
        design = np.stack([np.ones(ok.sum()), t_ok - t_ref], -1) / sigma_eff[:, None]
        solution, cov = huber_lstsq(np.ascontiguousarray(design), dev / sigma_eff, HUBER_K)
        offset, drift = solution
        offset_sigma, drift_sigma = np.sqrt(np.diag(cov))
    else:
        design = np.ones((ok.sum(), 1)) / sigma_eff[:, None]
        solution, cov = huber_lstsq(np.ascontiguousarray(design), dev / sigma_eff, HUBER_K)
        offset, drift, offset_sigma, drift_sigma = solution[0], 0.0, float(np.sqrt(cov[0, 0])), 0.0
    return YawOffsetSolution(windows=windows, reference_time=t_ref, offset=float(wrap_pi(reference + offset)),
                             offset_sigma=float(offset_sigma), drift=float(drift), drift_sigma=float(drift_sigma),
                             bandwidth=bandwidth, overlap_factor=overlap)
