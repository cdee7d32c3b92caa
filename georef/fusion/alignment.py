"""Alignment from any motion: optimisation-based alignment of attitude, velocity and biases against GNSS.

No heading source is assumed: the track is not taken as the heading. Over a window that starts at the first
row, the IMU is integrated in its own initial body frame (:mod:`georef.fusion.alignment_kernel`), and the
attitude ``C0`` at the window's start is the rotation that carries those body-frame integrals onto the GNSS
positions (the position-integration form of optimisation-based alignment; Wu & Pan 2013, "Velocity/position
integration formula part I: application to in-flight coarse alignment", IEEE T-AES 49(2); Silson 2011). In the
local tangent frame at the first fix (NED, metres):

    r_ant(t) = r0 + v0 τ + ∫∫ g - c(t) + C0 (β(t) + λ(t)) - [ω_ie x] C0 γ(t) - τ [ω_ie x] C0 λ(t)

with ``τ = t - t0``, β, γ, λ the body-frame integrals, ``ω_ie`` the Earth rate and ``c`` the known Coriolis and
gravity-tilt terms (from the GNSS velocity and the horizontal displacement). The steps:

1. the gyro bias starts from the mean rate over a quasi-static start (GNSS speed under 0.5 m/s: a hover or a
   standstill), else from zero (or, on a restart, the filter's estimate);
2. a linear solve with ``C0`` as a general 3x3 matrix (no quadrant or heading guess), projected onto the
   rotations;
3. Gauss-Newton over the rotation, ``r0``, ``v0``, the gyro and accelerometer biases, with Huber weights;
4. when that fits badly (variance factor over ``VARIANCE_FACTOR_RETRY``: a large gyro bias, a poor linear
   start), the bias about the initial vertical is screened on a grid up to consumer grade (0.12 rad/s) and the
   best candidates are refitted from four headings; the best fit wins.

The heading is *observable* when the window holds horizontal acceleration in more than one direction of the
body, or turns. The window grows (30, 60, 120 s, ... the whole log) until the heading *at the window's start* is
known to better than ``HEADING_SIGMA_OK`` (which needs the gyro bias about the vertical too). When no window
gets there but one knows the heading at some later time (a long hover before the first manoeuvre), that
window is used: the filter starts at the first row with the solution and its full covariance (the heading's
correlation with the gyro bias included), and the smoother carries the well-determined heading back to the
first row. A hovering start therefore aligns once the aircraft moves.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from georef.aot import load as load_kernel
from georef.distributions import f_sf
from georef.frames import (
    C_e_n,
    C_n_e,
    earth_rate_n,
    ecef_to_geodetic,
    euler_to_dcm,
    geodetic_to_ecef,
    normal_gravity,
    normal_gravity_gradient,
    skew,
)
from georef.frames.mounting import lever_arm_offset
from georef.frames.rotations import rotvec_to_dcm
from georef.fusion import ins_layout as layout

#: a heading known to better than this [rad] somewhere in the window ends the search
HEADING_SIGMA_OK = np.radians(2.0)
#: quasi-static: GNSS ground speed below this [m/s]
STATIC_SPEED = 0.5
#: the grid over the vertical gyro bias [rad/s]: +- this range
GYRO_BIAS_RANGE = 0.12
WINDOWS_S = (30.0, 60.0, 120.0, 240.0, 480.0)
HUBER_K = 2.5
#: a first fit whose variance factor exceeds this is retried from other starting points, when the window's
#: motion shows the heading to better than RETRY_HEADING_SIGMA [rad] somewhere
VARIANCE_FACTOR_RETRY = 4.0
RETRY_HEADING_SIGMA = np.radians(20.0)
#: confidence of the test of the datasheet's bias prior against the data (see ``_fit_window``)
PRIOR_TEST_LEVEL = 0.999
#: an IMU gap this soon after the start [s] moves the start after the gap
GAP_SKIP_S = 10.0
#: prior sigmas of the biases in the fit (consumer grade: turn-on up to 0.1 rad/s and 0.5 m/s^2)
PRIOR_GYRO_BIAS = 0.2
PRIOR_ACCEL_BIAS = 1.0


@dataclass
class Alignment:
    """The filter's starting point: state at ``start_row`` and its covariance, with how it was found.

    ``covariance`` (15, 15) is in the filter's error-state order and sign (estimate minus truth): NED position
    [m], NED velocity [m/s], attitude φ [rad] (``Ĉ = (I - [φ x]) C``), gyro bias [rad/s], accelerometer bias
    [m/s^2]. ``position`` is the IMU's latitude, longitude [rad] and height [m].
    """

    start_row: int
    position: np.ndarray
    v_n: np.ndarray
    C_b_n: np.ndarray
    gyro_bias: np.ndarray
    accel_bias: np.ndarray
    covariance: np.ndarray
    heading_source: str
    observable: bool
    heading_sigma: float       # best heading sigma inside the window [rad]
    heading_time: float        # when [s]
    window: tuple[float, float]
    variance_factor: float     # a-posteriori variance factor of the GNSS fit (1 = as the sigmas say)
    #: the POS unit's yaw-origin drift rate and its sigma [rad/s] when its IACC gives it, else None
    unit_drift: tuple[float, float] | None = None
    #: the start heading's sigma [rad] when it came from the unit's yaw and its IACC-recovered origin
    heading_prior_sigma: float | None = None
    #: that recovery (georef.fusion.yaw_offset.YawOffsetSolution), for reports
    yaw_offset: object = None
    #: the bias prior sigmas the fit kept [rad/s, m/s^2]: the datasheet's, or wider where the data rejected it
    bias_prior_sigma: tuple[float, float] | None = None
    #: the covariance is a prior (gravity and the datasheet, :func:`georef.fusion.start.level_covariance`), not a
    #: fit to the fixes the filter will use: it is taken whole
    prior_covariance: bool = False
    #: the heading is still to be found (the heading bank, :func:`georef.fusion.ins.decide_heading`)
    needs_heading: bool = False
    #: how the level was read (georef.fusion.start.Level), when it was read from gravity
    level: object = None


@dataclass
class _Fixes:
    time: np.ndarray       # (K,) s
    r: np.ndarray          # (K, 3) tangent-frame NED antenna positions [m]
    sigma: np.ndarray      # (K, 3) NED sigmas [m]
    v: np.ndarray          # (K, 3) GNSS-derived NED velocity [m/s] (central differences)


def _tangent_frame(lat0: float, lon0: float, h0: float, lat: np.ndarray, lon: np.ndarray, h: np.ndarray) -> np.ndarray:
    r0 = geodetic_to_ecef(lat0, lon0, h0)
    return (geodetic_to_ecef(lat, lon, h) - r0) @ C_e_n(lat0, lon0).T


def _fix_velocity(time: np.ndarray, r: np.ndarray) -> np.ndarray:
    """NED velocity [m/s] at each fix from neighbouring fixes (central where possible)."""
    v = np.zeros_like(r)
    if len(time) < 2:
        return v
    v[1:-1] = (r[2:] - r[:-2]) / (time[2:] - time[:-2])[:, None]
    v[0] = (r[1] - r[0]) / (time[1] - time[0])
    v[-1] = (r[-1] - r[-2]) / (time[-1] - time[-2])
    return v


def _known_terms(fixes: _Fixes, t0: float, lat0: float, h0: float, omega_ie: np.ndarray) -> np.ndarray:
    """``∫∫ g - c`` at each fix [m]: normal gravity at the fix heights, Coriolis ``-2 ω_ie x v`` and the tilt of
    gravity ``-(g/(R+h)) r_h`` over the tangent plane (:func:`georef.frames.normal_gravity_gradient`), integrated
    twice from t0 on a 0.1 s grid."""
    t_end = fixes.time[-1]
    grid = np.arange(t0, t_end + 0.1, 0.1)
    v = np.stack([np.interp(grid, fixes.time, fixes.v[:, k]) for k in range(3)], -1)
    r = np.stack([np.interp(grid, fixes.time, fixes.r[:, k]) for k in range(3)], -1)
    g = normal_gravity(lat0, h0 - r[:, 2])
    tilt, _ = normal_gravity_gradient(lat0, h0 - r[:, 2])
    acc = -2.0 * np.cross(omega_ie, v)
    acc[:, 0] -= tilt * r[:, 0]
    acc[:, 1] -= tilt * r[:, 1]
    acc[:, 2] += g
    dt = np.diff(grid)[:, None]
    vel = np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (acc[1:] + acc[:-1]) * dt, axis=0)])
    pos = np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (vel[1:] + vel[:-1]) * dt, axis=0)])
    return np.stack([np.interp(fixes.time, grid, pos[:, k]) for k in range(3)], -1)


def _nearest_rotation(M: np.ndarray) -> np.ndarray:
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


class _Window:
    """One alignment window: the fixes in it and the model of their antenna positions."""

    def __init__(self, t: np.ndarray, gyro: np.ndarray, accel: np.ndarray, row0: int, fixes: _Fixes,
                 lever: np.ndarray, known: np.ndarray, omega_ie: np.ndarray):
        self.t, self.gyro, self.accel, self.row0 = t, gyro, accel, row0
        self.fixes, self.lever, self.known, self.omega = fixes, lever, known, omega_ie
        self.tau = fixes.time - t[row0]
        self.W = skew(omega_ie)
        self.kernel = load_kernel("align")

    def integrals(self, bias_g: np.ndarray, bias_a: np.ndarray):
        return self.kernel.preintegrate(self.t, self.gyro, self.accel, self.row0, bias_g, bias_a, self.lever,
                                        self.fixes.time)

    def linear_attitude(self, pre) -> tuple[np.ndarray, float]:
        """``C0`` from the linear fit with ``C0`` a general matrix; returns it projected, and the weighted RSS."""
        _, _, beta, gamma, lam = pre[:5]
        K = len(self.tau)
        y = (self.fixes.r - self.known).reshape(-1)
        w = 1.0 / self.fixes.sigma.reshape(-1)
        eye = np.eye(3)
        # the linear fit's parameters: r0 [m], v0 [m/s] and vec(M), M the 3x3 matrix in place of C0
        r0, v0, vec_m = slice(0, 3), slice(3, 6), slice(6, 15)
        A = np.zeros((K, 3, vec_m.stop))
        A[:, :, r0] = eye
        A[:, :, v0] = self.tau[:, None, None] * eye
        # vec(M) column-major: M x = (xᵀ ⊗ I) vec(M); -[ω x] M γ = -(γᵀ ⊗ [ω x]) vec(M)
        x = beta + lam
        A[:, :, vec_m] = (np.einsum("kj,ab->kajb", x, eye) - np.einsum("kj,ab->kajb", gamma, self.W)).reshape(K, 3, 9)
        A = A.reshape(3 * K, vec_m.stop)
        sol, *_ = np.linalg.lstsq(A * w[:, None], y * w, rcond=1e-10)
        M = sol[vec_m].reshape(3, 3, order="F")
        rss = float(np.sum(((A @ sol - y) * w) ** 2))
        return _nearest_rotation(M), rss

    def residual_and_jacobian(self, C0, r0, v0, pre):
        """Residuals (measured minus modelled, (3K,)) and their Jacobian (3K, 15) with respect to the
        corrections (rotation ρ with C0 ← exp([ρ x]) C0, r0, v0, b_g, b_a)."""
        _, _, beta, gamma, lam, _, _, _, db_g, db_a, dl_g = pre
        K = len(self.tau)
        tau = self.tau[:, None]
        Cb = beta @ C0.T
        Cl = lam @ C0.T
        Cg = gamma @ C0.T
        model = r0 + v0 * tau + self.known + Cb + Cl - Cg @ self.W.T - tau * (Cl @ self.W.T)
        res = self.fixes.r - model
        Jac = np.zeros((K, 3, FIT_N))
        Jac[:, :, _ROT] = -skew(Cb + Cl) + self.W @ skew(Cg) + tau[:, :, None] * (self.W @ skew(Cl))
        Jac[:, :, _POS] = np.eye(3)
        Jac[:, :, _VEL] = tau[:, :, None] * np.eye(3)
        Jac[:, :, _BG] = C0 @ (db_g + dl_g)
        Jac[:, :, _BA] = C0 @ db_a
        return res.reshape(-1), Jac.reshape(3 * K, FIT_N)


def _static_start(t: np.ndarray, gyro: np.ndarray, accel: np.ndarray, row0: int, fixes: _Fixes,
                  lat0: float) -> tuple[np.ndarray | None, float]:
    """Mean gyro [rad/s] over a quasi-static start (GNSS speed < STATIC_SPEED for >= 3 s), minus the vertical
    Earth rate; and its length [s]. ``None`` when the start is not quasi-static."""
    speed = np.hypot(fixes.v[:, 0], fixes.v[:, 1])
    moving = np.flatnonzero(speed >= STATIC_SPEED)
    t_end = fixes.time[moving[0]] if len(moving) else fixes.time[-1]
    length = t_end - t[row0]
    if length < 3.0:
        return None, 0.0
    rows = slice(row0, int(np.searchsorted(t, t_end)))
    f = accel[rows].mean(axis=0)
    down_b = -f / np.linalg.norm(f)
    omega_vertical = earth_rate_n(lat0)[2]  # Earth rate along down, NED
    return gyro[rows].mean(axis=0) - omega_vertical * down_b, float(length)


#: the alignment fit's parameter order: rotation correction ρ [rad], start position r0 and velocity v0 [NED m, m/s],
#: gyro and accelerometer biases [rad/s, m/s^2]; true = estimate + correction (:func:`filter_order` maps it to the
#: filter's error states)
FIT_ROT, FIT_POS, FIT_VEL, FIT_BG, FIT_BA = 0, 3, 6, 9, 12
FIT_N = 15
_ROT, _POS, _VEL = slice(FIT_ROT, FIT_ROT + 3), slice(FIT_POS, FIT_POS + 3), slice(FIT_VEL, FIT_VEL + 3)
_BG, _BA = slice(FIT_BG, FIT_BG + 3), slice(FIT_BA, FIT_BA + 3)


def _gauss_newton(win: _Window, C0: np.ndarray, r0: np.ndarray, v0: np.ndarray, bias_g: np.ndarray,
                  bias_a: np.ndarray, iterations: int = 12, prior_sigma: tuple[float, float] | None = None):
    """Robust Levenberg-Marquardt from a starting point (Huber weights, a zero-mean prior on the biases with
    sigmas ``prior_sigma`` [rad/s, m/s^2], consumer grade by default); returns the
    solution, its covariance (15, 15) in the correction order (ρ, r0, v0, b_g, b_a; true = estimate +
    correction), the variance factor and the preintegration at the solution. The damping keeps a window whose
    motion does not show the heading from wandering off along that direction."""
    sigma_g, sigma_a = prior_sigma or (PRIOR_GYRO_BIAS, PRIOR_ACCEL_BIAS)
    prior = np.zeros(FIT_N)
    prior[_BG], prior[_BA] = 1.0 / sigma_g**2, 1.0 / sigma_a**2
    sigma = win.fixes.sigma.reshape(-1)

    def evaluate(C0, r0, v0, bias_g, bias_a, pre):
        res, Jac = win.residual_and_jacobian(C0, r0, v0, pre)
        z = res / sigma
        scale = max(1.4826 * float(np.median(np.abs(z))), 1.0)
        weights = np.minimum(1.0, HUBER_K * scale / np.maximum(np.abs(z), 1e-12))
        w = weights / sigma**2
        x_b = np.zeros(FIT_N)
        x_b[_BG], x_b[_BA] = bias_g, bias_a
        cost = float(np.sum(w * res**2) + np.sum(prior * x_b**2))
        return res, Jac, w, cost, x_b

    pre = win.integrals(bias_g, bias_a)
    res, Jac, w, cost, x_b = evaluate(C0, r0, v0, bias_g, bias_a, pre)
    damping = 1e-3
    for _ in range(iterations):
        N = Jac.T @ (Jac * w[:, None]) + np.diag(prior)
        b = Jac.T @ (res * w) - prior * x_b
        improved = False
        while damping < 1e8:
            delta = np.linalg.solve(N + damping * np.diag(np.diag(N)), b)
            trial = (rotvec_to_dcm(delta[_ROT]) @ C0, r0 + delta[_POS], v0 + delta[_VEL], bias_g + delta[_BG],
                     bias_a + delta[_BA])
            trial_pre = win.integrals(trial[3], trial[4])
            t_res, t_Jac, t_w, t_cost, t_xb = evaluate(*trial, trial_pre)
            if t_cost <= cost:
                C0, r0, v0, bias_g, bias_a = trial
                pre, res, Jac, w, cost, x_b = trial_pre, t_res, t_Jac, t_w, t_cost, t_xb
                damping = max(damping / 10.0, 1e-9)
                improved = True
                break
            damping *= 10.0
        if not improved or (np.all(np.abs(delta[_ROT]) < 1e-6) and np.all(np.abs(delta[_BG]) < 1e-8)):
            break
    N = Jac.T @ (Jac * w[:, None]) + np.diag(prior)
    dof = max(len(res) - FIT_N, 1)
    variance_factor = float(np.sum(w * res**2) / dof)
    cov = np.linalg.inv(N) * max(variance_factor, 1.0)
    return C0, r0, v0, bias_g, bias_a, cov, variance_factor, pre


def _heading_sigmas(C0: np.ndarray, pre, cov: np.ndarray) -> np.ndarray:
    """1-sigma [rad] of the heading at each fix time: ``φ(t) = ρ + C(t) J(t) δb_g`` (about down)."""
    dC, J = pre[0], pre[5]
    G = np.zeros((len(dC), 3, FIT_N))
    G[:, :, _ROT] = np.eye(3)
    G[:, :, _BG] = C0 @ dC @ J
    down = G[:, 2, :]
    return np.sqrt(np.maximum(np.einsum("ki,ij,kj->k", down, cov, down), 0.0))


def align(t: np.ndarray, gyro: np.ndarray, accel: np.ndarray, fix_time: np.ndarray, lat: np.ndarray,
          lon: np.ndarray, height: np.ndarray, sigma_neu: np.ndarray, lever_arm: np.ndarray,
          start_time: float | None = None, bias_g: np.ndarray | None = None,
          bias_a: np.ndarray | None = None, gaps: list[tuple[int, int]] | None = None,
          datasheet_bias_sigma: tuple[float, float] | None = None) -> Alignment:
    """Align the INS from the motion over a growing window that starts at the first row at or after the first
    fix (or at ``start_time``).

    Inputs: IMU row times [s] (N,), gyro [rad/s] and specific force [m/s^2] (N, 3) in the body frame; GNSS
    antenna fixes: times [s], latitude and longitude [rad], height [m], NED sigmas [m] (K, 3); the body lever arm
    IMU -> antenna [m]; optional starting bias guesses (a restart carries the filter's); the datasheet's turn-on
    bias sigmas [rad/s, m/s^2], the prior of the fit unless the data reject it (then consumer grade, see
    ``_fit_window``). No window spans an IMU
    gap (``gaps``: (row before, row after) pairs): a gap in the first ``GAP_SKIP_S`` seconds moves the start after
    it, and the window ends before the next one. Raises ``ValueError`` when fewer than 6 fixes follow the start.
    """
    row0, last_row = _start_rows(t, fix_time[0] if start_time is None else start_time, gaps)
    first = int(np.searchsorted(fix_time, t[min(row0, len(t) - 1)], side="left"))
    if row0 >= len(t) - 2 or len(fix_time) - first < 6:
        raise ValueError("fewer than 6 GNSS fixes inside the IMU span after the start")
    lat0, lon0, h0 = float(lat[first]), float(lon[first]), float(height[first])
    r_all = _tangent_frame(lat0, lon0, h0, lat[first:], lon[first:], height[first:])
    all_fixes = _Fixes(time=fix_time[first:], r=r_all, sigma=sigma_neu[first:],
                       v=_fix_velocity(fix_time[first:], r_all))
    static_bias, _ = _static_start(t, gyro, accel, row0, all_fixes, lat0)
    guess_g = np.zeros(3) if bias_g is None else np.asarray(bias_g, float).copy()
    if bias_g is None and static_bias is not None:
        guess_g = static_bias
    guess_a = np.zeros(3) if bias_a is None else np.asarray(bias_a, float).copy()
    prior = tuple(datasheet_bias_sigma) if datasheet_bias_sigma is not None else (PRIOR_GYRO_BIAS, PRIOR_ACCEL_BIAS)
    imu = _Imu(t=t, gyro=gyro, accel=accel, row0=row0, lever=np.asarray(lever_arm, dtype=float))
    tried = _growing_windows(imu, all_fixes, min(t[last_row], all_fixes.time[-1]), lat0, h0, guess_g, guess_a, prior)
    at_start = [w for w in tried if w.start_sigma < HEADING_SIGMA_OK]
    later = [w for w in tried if w.heading_sigma < HEADING_SIGMA_OK]
    best = at_start[0] if at_start else later[0] if later else tried[-1]
    # the IMU's geodetic position at the start row from the tangent-frame position
    r_e = geodetic_to_ecef(lat0, lon0, h0) + C_n_e(lat0, lon0) @ best.r0
    lat_s, lon_s, h_s = ecef_to_geodetic(r_e[None, :])
    # tangent frame -> local NED at the start position (they differ by the small angle of the displacement)
    C_t_n = C_e_n(lat_s[0], lon_s[0]) @ C_n_e(lat0, lon0)
    return Alignment(start_row=row0, position=np.array([lat_s[0], lon_s[0], h_s[0]]), v_n=C_t_n @ best.v0,
                     C_b_n=C_t_n @ best.C0, gyro_bias=best.bias_g, accel_bias=best.bias_a,
                     covariance=filter_order(best.cov), heading_source="motion",
                     observable=bool(best.heading_sigma < HEADING_SIGMA_OK),
                     heading_sigma=float(best.heading_sigma), heading_time=float(best.heading_time),
                     window=(float(t[row0]), float(best.t_end)), variance_factor=best.variance_factor,
                     bias_prior_sigma=(float(best.prior[0]), float(best.prior[1])))


def _start_rows(t: np.ndarray, t0_fix: float, gaps: list[tuple[int, int]] | None) -> tuple[int, int]:
    """The first row of the alignment (at or after ``t0_fix`` [s], moved past an IMU gap within ``GAP_SKIP_S``)
    and the last row it may use (before the next gap)."""
    row0 = int(np.searchsorted(t, t0_fix, side="left"))
    gap_after = np.array([b for _, b in (gaps or [])], dtype=int)  # first row after each gap
    early = gap_after[(gap_after > row0) & (t[np.minimum(gap_after, len(t) - 1)] <= t[min(row0, len(t) - 1)]
                                              + GAP_SKIP_S)]
    if len(early):
        row0 = int(early[-1])
    later_gaps = gap_after[gap_after > row0]
    last_row = int(later_gaps[0]) - 1 if len(later_gaps) else len(t) - 1
    return row0, last_row


@dataclass(frozen=True)
class _WindowFit:
    """One window's fit: the start attitude ``C0`` (body to tangent frame), position ``r0`` [m] and velocity ``v0``
    [m/s] in the tangent frame, the biases [rad/s, m/s^2], the covariance (FIT_N, FIT_N) and a-posteriori variance
    factor; the window's ``fixes`` and end ``t_end`` [s]; the smallest heading sigma [rad] over its fixes and the
    time [s] of that fix, the heading sigma at the start; the bias prior sigmas it used."""

    C0: np.ndarray
    r0: np.ndarray
    v0: np.ndarray
    bias_g: np.ndarray
    bias_a: np.ndarray
    cov: np.ndarray
    variance_factor: float
    fixes: _Fixes
    heading_sigma: float
    heading_time: float
    t_end: float
    start_sigma: float
    prior: tuple[float, float]


@dataclass(frozen=True)
class _Imu:
    """The IMU rows an alignment integrates: times [s], gyro [rad/s] and specific force [m/s^2] (body), the start
    row ``row0``, and the body lever arm IMU -> antenna [m]."""

    t: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    row0: int
    lever: np.ndarray


def _growing_windows(imu: _Imu, all_fixes: _Fixes, t_end_data: float, lat0: float, h0: float, guess_g: np.ndarray,
                     guess_a: np.ndarray, prior: tuple[float, float]) -> list[_WindowFit]:
    """Fits over windows of :data:`WINDOWS_S` from the start row and then all the data (fixes in the tangent frame
    at ``lat0`` [rad], ``h0`` [m]; the data end at ``t_end_data`` [s]), until one knows the heading at the start.
    Raises ``ValueError`` when no window has 6 fixes."""
    t, row0 = imu.t, imu.row0
    omega_ie = earth_rate_n(lat0)
    tried = []
    for length in (*WINDOWS_S, np.inf):
        t_end = min(t[row0] + length, t_end_data)
        inside = all_fixes.time <= t_end
        if inside.sum() < 6:
            continue
        fixes = _Fixes(time=all_fixes.time[inside], r=all_fixes.r[inside], sigma=all_fixes.sigma[inside],
                       v=all_fixes.v[inside])
        known = _known_terms(fixes, t[row0], lat0, h0, omega_ie)
        win = _Window(t, imu.gyro, imu.accel, row0, fixes, imu.lever, known, omega_ie)
        # a prior rejected by a shorter window stays rejected for the longer ones
        solution, prior = _fit_window(win, guess_g, guess_a, prior)
        C0, r0, v0, b_g_fit, b_a_fit, cov, vf, pre = solution
        sig = _heading_sigmas(C0, pre, cov)
        k_best = int(np.argmin(sig))
        tried.append(_WindowFit(C0=C0, r0=r0, v0=v0, bias_g=b_g_fit, bias_a=b_a_fit, cov=cov, variance_factor=vf,
                                fixes=fixes, heading_sigma=sig[k_best], heading_time=fixes.time[k_best], t_end=t_end,
                                start_sigma=sig[0], prior=prior))
        # done when the heading is known at the start; a window that knows it only later is kept in reserve
        if sig[0] < HEADING_SIGMA_OK or t_end >= t_end_data:
            break
    if not tried:
        raise ValueError("fewer than 6 GNSS fixes inside the IMU span after the start")
    return tried


#: where each block of the fit's correction vector (true = estimate + correction) starts: rotation ρ (with
#: C0 <- exp([ρ x]) C0), r0 [m], v0 [m/s], gyro bias [rad/s], accelerometer bias [m/s^2]


def filter_order(cov: np.ndarray) -> np.ndarray:
    """The fit's covariance (FIT_N, FIT_N) in the filter's error-state order and sign (:mod:`ins_layout`: errors
    are estimate minus truth, so every correction but the rotation changes sign; the rotation's sign is the
    filter's already, ``Ĉ = (I - [φ x]) C``), first ``FIT_N`` filter states."""
    source = {FIT_ROT: layout.ATT, FIT_POS: layout.POS, FIT_VEL: layout.VEL, FIT_BG: layout.BG, FIT_BA: layout.BA}
    index = np.empty(FIT_N, dtype=int)
    sign = np.empty(FIT_N)
    for fit_start, filter_start in source.items():
        index[filter_start:filter_start + 3] = np.arange(fit_start, fit_start + 3)
        sign[filter_start:filter_start + 3] = 1.0 if fit_start == FIT_ROT else -1.0
    return cov[np.ix_(index, index)] * np.outer(sign, sign)


def _fit(win: _Window, bias_g: np.ndarray, bias_a: np.ndarray, heading_turn: float = 0.0,
         prior_sigma: tuple[float, float] | None = None):
    """Linear attitude (turned by ``heading_turn`` [rad] about down), then Gauss-Newton."""
    C0, _ = win.linear_attitude(win.integrals(bias_g, bias_a))
    if heading_turn:
        C0 = euler_to_dcm(0.0, 0.0, heading_turn) @ C0
    r0 = win.fixes.r[0] - lever_arm_offset(C0, win.lever)
    return _gauss_newton(win, C0, r0, win.fixes.v[0], bias_g, bias_a, prior_sigma=prior_sigma)


def _fit_window(win: _Window, bias_g: np.ndarray, bias_a: np.ndarray,
                prior: tuple[float, float]) -> tuple[tuple, tuple[float, float]]:
    """The window's fit with the bias prior ``prior`` (sigmas [rad/s, m/s^2]) where the data allow it, and the
    prior it used (for the longer windows).

    The prior starts as the datasheet's: a good IMU's biases are not to be invented from a few minutes of data.
    It is tested against the data: refitted with consumer-grade bias sigmas, the fit's GNSS misfit may fall by
    no more than chance allows (an F-test on the weighted residuals, the freed biases in the numerator, at
    ``PRIOR_TEST_LEVEL``; the ratio does not depend on how right the GNSS sigmas are). A phone gyro with
    0.07 rad/s of turn-on bias, read with a survey unit's datasheet, fitted a helicopter's first minute with a
    variance factor of 1.7 and the heading 188 deg wrong; the consumer-grade fit had 1.07. (Freeing only the
    gyro's prior when that explains the data as well was tried: it kept a hovering multicopter's roll, but lost a
    phone-IMU helicopter whose accelerometer bias was beyond the datasheet too.) When the prior is rejected, or
    any fit is bad (variance factor over
    ``VARIANCE_FACTOR_RETRY``) in a window whose motion shows the heading, other starting points are tried (a
    large gyro bias, a poor linear start); the best fit wins."""
    consumer = (PRIOR_GYRO_BIAS, PRIOR_ACCEL_BIAS)
    n_obs = len(win.fixes.sigma.reshape(-1))
    wide = _fit(win, bias_g, bias_a, prior_sigma=consumer)
    retry = False
    if tuple(prior) == consumer:
        # freed biases, possibly large: the other starting points too
        best, used, retry = wide, consumer, True
    else:
        first = _fit(win, bias_g, bias_a, prior_sigma=prior)
        if not _prior_rejected(first, wide, n_obs, 6):
            if first[6] <= VARIANCE_FACTOR_RETRY:
                return first, tuple(prior)
            best, used = min((first, wide), key=lambda s: s[6]), tuple(prior)
        else:
            retry = True
            best, used = wide, consumer
    if (retry or best[6] > VARIANCE_FACTOR_RETRY) and \
            np.min(_heading_sigmas(best[0], best[7], best[5])) < RETRY_HEADING_SIGMA:
        best = min([best, *_multi_start(win, bias_g, bias_a, used)], key=lambda s: s[6])
    return best, used


def _prior_rejected(constrained, free, n_obs: int, freed: int) -> bool:
    """F-test: does freeing ``freed`` (even) bias parameters reduce the weighted GNSS misfit more than chance
    allows? The statistic exceeds the F(freed, dof) quantile at ``PRIOR_TEST_LEVEL`` exactly when its tail
    probability is below ``1 - PRIOR_TEST_LEVEL`` (:func:`georef.distributions.f_sf`; scipy.special would cost
    every run 0.2 s of import)."""
    dof_free = max(n_obs - FIT_N, 1)
    misfit_c = constrained[6] * dof_free
    misfit_f = free[6] * dof_free
    statistic = max(misfit_c - misfit_f, 0.0) / freed / max(misfit_f / dof_free, 1e-12)
    return bool(f_sf(statistic, freed, dof_free) < 1.0 - PRIOR_TEST_LEVEL)


def _multi_start(win: _Window, bias_g: np.ndarray, bias_a: np.ndarray, prior: tuple[float, float]) -> list:
    """Fits (with the bias prior ``prior``) from other starting points, for when the first one fits badly: the
    gyro bias about the initial vertical screened on a grid (+-GYRO_BIAS_RANGE, step ~ 1/(2 T)) by the linear
    fit's residual, and the best three screened biases each from four headings."""
    f0 = win.accel[win.row0:win.row0 + 50].mean(axis=0)
    down_b = -f0 / np.linalg.norm(f0)
    span = max(float(win.tau[-1]), 1.0)
    step = 0.5 / span
    offsets = np.arange(-GYRO_BIAS_RANGE, GYRO_BIAS_RANGE + step / 2, step)
    rss = np.array([win.linear_attitude(win.integrals(bias_g + o * down_b, bias_a))[1] for o in offsets])
    starts = offsets[np.argsort(rss)[:3]]
    out = []
    for offset in starts:
        for turn in (0.0, 0.5 * np.pi, np.pi, 1.5 * np.pi):
            out.append(_fit(win, bias_g + offset * down_b, bias_a, turn, prior_sigma=prior))
    return out
