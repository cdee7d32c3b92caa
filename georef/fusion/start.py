"""How a flight starts: standing still, hovering or already moving; the level from gravity; the heading bank.

A drone log starts on the ground or in a hover, where the motion shows no heading and, before the rotors turn,
no motion at all. Three things are read off the data here (:mod:`georef.fusion.ins` uses them):

* **Still rows** (:func:`still_rows`): windows of ``STILL_WINDOW_S`` whose specific force and angular rate
  scatter no more than the sensor's own noise floor (the quietest windows of the log) allows, whose mean
  specific force has gravity's magnitude, and where the GNSS fixes around them do not move (an IMU alone cannot
  tell standing from cruising smoothly). The vehicle stands: the filter
  gets zero-velocity updates there. Spinning rotors shake a drone on the ground far above its noise floor; those
  rows are not still, and need not be (the fixes hold the position).
* **The level** (:func:`level_at_start`): while the vehicle stands or hovers its mean specific force is
  gravity's reaction, ``f_b = -C_n_b g_n`` plus the accelerometer bias; roll and pitch follow, with the bias's
  share ``b / g`` as their uncertainty and the correlation between the two that this implies (the motion later
  separates them).
* **The heading bank** (:func:`bank_choice`): the forward filter run from the level with each of
  ``BANK_HEADINGS`` headings around the circle; the headings are weighed by the likelihood of the GNSS
  innovations each filter met, as in a Gaussian sum filter (Alspach & Sorenson 1972, "Nonlinear Bayesian
  estimation using Gaussian sum approximations", IEEE T-AC 17(4); ArduPilot's and PX4's EKF-GSF yaw estimators
  do the same with a smaller filter per heading). While the vehicle stands or hovers every heading explains the
  fixes equally; once it accelerates, the wrong ones stop explaining them. A heading from the magnetometer or
  the autopilot, with a sigma wide enough for their errors, weighs the headings as a prior.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from georef.frames import STANDARD_GRAVITY, earth_rate_n, euler_to_dcm, wrap_pi

#: length of the windows the stillness is judged over [s]
STILL_WINDOW_S = 1.0
#: a still window scatters at most this many times the noise floor (the 5th percentile of all windows), and at
#: least the absolute floors below (a log that never stands still has no quiet windows to learn from)
STILL_FLOOR_FACTOR = 4.0
STILL_ACCEL_MIN = 0.03      # m/s^2
STILL_GYRO_MIN = 0.003      # rad/s
STILL_ACCEL_MAX = 0.3       # m/s^2: above this scatter nothing is still, whatever the floor
STILL_GYRO_MAX = 0.03       # rad/s
#: the mean specific force of a still window lies within this of the log's still-window median [m/s^2]
STILL_GRAVITY_TOLERANCE = 0.2
#: GNSS fixes move less than this [m/s] across a still window (speed between the fixes around it)
STILL_GNSS_SPEED = 0.5
#: a run of still windows shorter than this [s] is not used
STILL_MIN_S = 3.0
#: a still window's mean specific force lies within this of its run's median on every axis [m/s^2]
STILL_STEADY = 0.05
#: quasi-static start (hover or standstill): the fixes of the first QUASI_STATIC_S seconds move slower than
#: STILL_GNSS_SPEED
QUASI_STATIC_S = 10.0
#: the level is read over at most this much of the start's still or quasi-static span [s]
LEVEL_WINDOW_S = 10.0
#: what the level's mean specific force misses besides the bias [rad] (the ground's give, the average's noise): a
#: level tied to the bias exactly leaves the start covariance singular along their difference
LEVEL_NOISE = np.radians(0.2)
#: the mean acceleration of a hover over the level window [m/s^2]: its share of the level's uncertainty
HOVER_ACCEL_SIGMA = 0.15
#: the mean angular rate of a hover over the level window [rad/s]: its share of the gyro bias's uncertainty
HOVER_RATE_SIGMA = 0.005
#: headings of the bank [rad] and the sigma each filter starts with
BANK_HEADINGS = np.radians(np.arange(0.0, 360.0, 30.0))
BANK_SIGMA = np.radians(12.0)
#: the heading is decided when the winning heading's weight exceeds this share of the bank (its neighbours that
#: converged to the same heading count with it: headings within BANK_SAME of the winner's at the decision)
BANK_DECIDED_WEIGHT = 0.99
BANK_SAME = np.radians(10.0)
#: ... or when the whole mixture (every heading with its weight, each filter's own sigma included) is within this
#: sigma [rad] of its mean: the winner then starts with BANK_SIGMA, which covers it
BANK_MIXTURE_SIGMA = np.radians(10.0)
#: ... and the fixes have shown a change of horizontal velocity of at least MOTION_DV [m/s] within MOTION_WINDOW_S
#: [s]: an acceleration the accelerometers cannot fake with their bias. Without it (a hover, a standstill, a
#: straight leg at constant speed) the heading is not observable, however sure a linearised filter is: in a
#: two-minute hover with 0.3 m of position hold every filter of the bank claimed 2-5 deg, and the likeliest
#: was 180 deg off by the end.
MOTION_DV = 1.0
MOTION_WINDOW_S = 10.0
#: the velocities compared are straight-line fits over this much of the fixes [s], and a change counts only when it
#: also exceeds this many of its sigmas (1 Hz fixes of 1 m scatter by about 1 m/s from one to the next)
MOTION_FIT_S = 4.0
MOTION_FIT_FIXES = 4
MOTION_FIT_MAX_S = 10.0
MOTION_SIGMAS = 5.0


@dataclass(frozen=True)
class Level:
    """Roll and pitch [rad] at the start, the specific force they came from [m/s^2, body], the window [s] and
    whether the vehicle stood still (else it hovered); ``gyro_bias`` [rad/s] the window's mean rate (Earth's
    vertical rate removed) with its sigma, or None when the window is too short."""

    roll: float
    pitch: float
    f_mean: np.ndarray
    window: tuple[float, float]
    still: bool
    gyro_bias: np.ndarray | None
    gyro_bias_sigma: float


def _window_stats(time: np.ndarray, values: np.ndarray, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per window [edges[i], edges[i+1]): mean (W, 3) and the rms of the per-axis standard deviations (W,)."""
    index = np.searchsorted(time, edges)
    cum = np.concatenate([np.zeros((1, 3)), np.cumsum(values, axis=0)])
    cum2 = np.concatenate([np.zeros((1, 3)), np.cumsum(values**2, axis=0)])
    count = np.maximum(np.diff(index), 1)[:, None]
    mean = (cum[index[1:]] - cum[index[:-1]]) / count
    var = (cum2[index[1:]] - cum2[index[:-1]]) / count - mean**2
    return mean, np.sqrt(np.maximum(var, 0.0).mean(axis=1))


def _gnss_speed(fix_time: np.ndarray, fix_ned: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Horizontal speed [m/s] at each time ``at`` from a straight line through the fixes within MOTION_FIT_S / 2
    of it (NaN where fewer than three): a line over seconds of fixes, not the step between two, which a 5 Hz
    receiver's noise turns into half a metre per second."""
    if len(fix_time) < 3:
        return np.full(len(at), np.nan)
    velocity, _ = _grid_velocity(fix_time, fix_ned, at)
    return np.hypot(velocity[:, 0], velocity[:, 1])


def still_rows(time: np.ndarray, gyro: np.ndarray, accel: np.ndarray, fix_time: np.ndarray,
               fix_ned: np.ndarray) -> np.ndarray:
    """The rows [bool (N,)] where the vehicle stands still (see the module docstring). ``fix_ned`` are the
    fixes' positions in any local NED frame [m]."""
    edges = np.arange(time[0], time[-1] + STILL_WINDOW_S, STILL_WINDOW_S)
    if len(edges) < 3:
        return np.zeros(len(time), bool)
    f_mean, f_scatter = _window_stats(time, accel, edges)
    _, w_scatter = _window_stats(time, gyro, edges)
    filled = np.diff(np.searchsorted(time, edges)) >= 5
    if not filled.any():
        return np.zeros(len(time), bool)
    floor_f = np.percentile(f_scatter[filled], 5)
    floor_w = np.percentile(w_scatter[filled], 5)
    limit_f = min(max(STILL_FLOOR_FACTOR * floor_f, STILL_ACCEL_MIN), STILL_ACCEL_MAX)
    limit_w = min(max(STILL_FLOOR_FACTOR * floor_w, STILL_GYRO_MIN), STILL_GYRO_MAX)
    quiet = filled & (f_scatter <= limit_f) & (w_scatter <= limit_w)
    norm = np.linalg.norm(f_mean, axis=1)
    if quiet.any():
        quiet &= np.abs(norm - np.median(norm[quiet])) <= STILL_GRAVITY_TOLERANCE
    # a quiet IMU is also a vehicle cruising on a smooth road or creeping away from a stop: only the fixes tell
    # standing from going, so a window without fixes around it is never still (a car's 20-s outages, KITTI, were
    # taken for standstills) and one whose fixes move is not either
    speed = _gnss_speed(fix_time, fix_ned, 0.5 * (edges[:-1] + edges[1:]))
    quiet &= speed <= STILL_GNSS_SPEED
    quiet = _steady_runs(quiet, f_mean)
    quiet = _long_runs(quiet, int(np.ceil(STILL_MIN_S / STILL_WINDOW_S)))
    # the first and the last window of a run hold the stop and the start of the motion
    quiet &= np.concatenate([[False], quiet[:-1]]) & np.concatenate([quiet[1:], [False]])
    window = np.clip(np.searchsorted(edges, time, side="right") - 1, 0, len(quiet) - 1)
    return quiet[window]


def _steady_runs(quiet: np.ndarray, f_mean: np.ndarray) -> np.ndarray:
    """``quiet`` without the windows whose mean specific force differs from its run's median by more than
    STILL_STEADY [m/s^2] on any axis: a vehicle that accelerates (a car creeping away at 0.5 m/s^2) tilts it."""
    out = quiet.copy()
    edges = np.flatnonzero(np.diff(np.concatenate([[0], quiet.astype(np.int8), [0]])))
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        median = np.median(f_mean[a:b], axis=0)
        out[a:b] &= np.all(np.abs(f_mean[a:b] - median) <= STILL_STEADY, axis=1)
    return out


def _long_runs(mask: np.ndarray, length: int) -> np.ndarray:
    """``mask`` with its runs of fewer than ``length`` True entries cleared."""
    out = mask.copy()
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        if b - a < length:
            out[a:b] = False
    return out


def quasi_static_start(fix_time: np.ndarray, fix_ned: np.ndarray, t0: float) -> bool:
    """Do the fixes of the first QUASI_STATIC_S seconds after ``t0`` lie on a line slower than STILL_GNSS_SPEED
    (or three times that line's sigma, for noisy fixes: 1 Hz fixes of 1 m give a speed of 0.3 m/s sigma over
    10 s)?"""
    inside = (fix_time >= t0) & (fix_time <= t0 + QUASI_STATIC_S)
    if inside.sum() < 3:
        return False
    t, r = fix_time[inside], fix_ned[inside, :2]
    tau = t - t.mean()
    velocity = tau @ (r - r.mean(axis=0)) / (tau @ tau)
    scatter = np.sqrt(np.sum((r - r.mean(axis=0) - np.outer(tau, velocity)) ** 2) / max(2 * len(t) - 4, 1))
    sigma = scatter / np.sqrt(tau @ tau)
    return bool(np.hypot(*velocity) < max(STILL_GNSS_SPEED, 3.0 * sigma))


def level_at_start(time: np.ndarray, gyro: np.ndarray, accel: np.ndarray, row0: int, still: np.ndarray,
                   fix_time: np.ndarray, fix_ned: np.ndarray, lat: float) -> Level:
    """Roll and pitch at row ``row0`` from the mean specific force over the still (else quasi-static) span that
    follows it, at most LEVEL_WINDOW_S long; the gyro bias from its mean rate when the span lasts STILL_MIN_S."""
    t0 = time[row0]
    is_still = bool(still[row0])
    if is_still:
        end = row0 + int(np.argmin(still[row0:])) if not still[row0:].all() else len(time)
    else:
        # a hover holds until the fixes show an acceleration (a fit's velocity, not the noise between two fixes)
        after = fix_time >= t0
        motion = first_motion(fix_time[after], fix_ned[after])
        end = int(np.searchsorted(time, motion - MOTION_FIT_S)) if np.isfinite(motion) else len(time)
    end = min(end, int(np.searchsorted(time, t0 + LEVEL_WINDOW_S)), len(time))
    end = max(end, min(row0 + 10, len(time)))
    f = accel[row0:end].mean(axis=0)
    roll = float(np.arctan2(-f[1], -f[2]))
    pitch = float(np.arctan2(f[0], np.hypot(f[1], f[2])))
    bias = None
    bias_sigma = np.inf
    if time[end - 1] - t0 >= STILL_MIN_S:
        C_b_n = euler_to_dcm(roll, pitch, 0.0)
        omega_ie = earth_rate_n(lat)
        # Earth's rate in the body: its vertical part is known from the level; the horizontal part needs the
        # heading, and its size is left in the sigma
        vertical = C_b_n.T @ np.array([0.0, 0.0, omega_ie[2]])
        bias = gyro[row0:end].mean(axis=0) - vertical
        spread = gyro[row0:end].std(axis=0).max() / np.sqrt(end - row0)
        bias_sigma = float(np.hypot(spread, np.hypot(omega_ie[0], omega_ie[1])))
        if not is_still:
            # a hover turns a little about every axis (position hold, a pilot's yaw): its mean rate is the bias
            # to within that
            bias_sigma = float(np.hypot(bias_sigma, HOVER_RATE_SIGMA))
    return Level(roll=roll, pitch=pitch, f_mean=f, window=(float(t0), float(time[end - 1])), still=is_still,
                 gyro_bias=bias, gyro_bias_sigma=bias_sigma)


def level_covariance(level: Level, C_b_n: np.ndarray, accel_bias_sigma: float) -> tuple[np.ndarray, np.ndarray,
                                                                                        np.ndarray]:
    """Covariances of the level's error (NED attitude error about north and east [rad]) and of the accelerometer
    bias [m/s^2], and their cross-covariance ((2, 2), (3, 3), (2, 3)).

    With the bias estimate left at zero, its error ``δb`` (estimate minus truth, ``-b``) tilts the level by
    ``φ_N = -(C δb)_E / g``, ``φ_E = (C δb)_N / g`` (the filter's attitude error, ``Ĉ = (I - [φ x]) C``): a bias
    along body y reads as a roll. LEVEL_NOISE and, in a hover, its mean acceleration over the window add to the
    level, uncorrelated."""
    g = STANDARD_GRAVITY
    M = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0]]) @ C_b_n / g
    bias_cov = accel_bias_sigma**2 * np.eye(3)
    level_cov = M @ bias_cov @ M.T + LEVEL_NOISE**2 * np.eye(2)
    if not level.still:
        level_cov += (HOVER_ACCEL_SIGMA / g) ** 2 * np.eye(2)
    cross = M @ bias_cov
    return level_cov, bias_cov, cross


@dataclass(frozen=True)
class BankChoice:
    """The heading bank's outcome: the winning start heading [rad] (None when undecided), the time [s] from
    which the heading was decided (None: never), the weights of the headings at the end, and a sentence."""

    heading: float | None
    decided_at: float | None
    weights: np.ndarray
    text: str


def _weights(loglik: np.ndarray, prior: np.ndarray) -> np.ndarray:
    """Normalised weights (..., K) from log-likelihoods (..., K; minus infinity for none) and prior weights (K,);
    rows without any finite likelihood get zero weights."""
    log_w = loglik + np.log(np.maximum(prior, 1e-300))
    top = np.max(log_w, axis=-1, keepdims=True)
    w = np.exp(log_w - np.where(np.isfinite(top), top, 0.0))
    total = w.sum(axis=-1, keepdims=True)
    return np.where(total > 0, w / np.where(total > 0, total, 1.0), 0.0)


def heading_prior(headings: np.ndarray, heading: float | None, sigma: float | None) -> np.ndarray:
    """Prior weights of the bank's headings: uniform, or a wrapped normal about ``heading`` [rad] with ``sigma``
    (flattened by the bank's own spacing)."""
    if heading is None or sigma is None:
        return np.full(len(headings), 1.0 / len(headings))
    spread = np.hypot(sigma, BANK_SIGMA)
    d = wrap_pi(headings - heading)
    w = np.exp(-0.5 * (d / spread) ** 2)
    return w / w.sum()


def _grid_velocity(fix_time: np.ndarray, fix_ned: np.ndarray, grid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal velocity [m/s] (G, 2) at each grid time from a straight line through the fixes within
    MOTION_FIT_S / 2 of it, or the MOTION_FIT_FIXES nearest within MOTION_FIT_MAX_S / 2 where the fixes are sparse
    (a 1 Hz log with gaps), and its sigma [m/s] (G,) from the line's residual scatter (NaN with fewer than 3
    fixes)."""
    velocity = np.full((len(grid), 2), np.nan)
    sigma = np.full(len(grid), np.nan)
    centre = np.searchsorted(fix_time, grid)
    lo = np.searchsorted(fix_time, grid - MOTION_FIT_S / 2.0)
    hi = np.searchsorted(fix_time, grid + MOTION_FIT_S / 2.0, side="right")
    for k, g in enumerate(grid):
        index = np.arange(lo[k], hi[k])
        if len(index) < MOTION_FIT_FIXES:
            near = np.arange(max(centre[k] - MOTION_FIT_FIXES, 0), min(centre[k] + MOTION_FIT_FIXES, len(fix_time)))
            near = near[np.abs(fix_time[near] - g) <= MOTION_FIT_MAX_S / 2.0]
            index = near[np.argsort(np.abs(fix_time[near] - g), kind="stable")[:MOTION_FIT_FIXES]]
        if len(index) < 3:
            continue
        t = fix_time[index]
        tau = t - t.mean()
        if tau @ tau <= 0:
            continue
        r = fix_ned[index, :2] - fix_ned[index, :2].mean(axis=0)
        v = tau @ r / (tau @ tau)
        scatter = float(np.sqrt(np.sum((r - np.outer(tau, v)) ** 2) / max(2 * len(index) - 4, 1)))
        velocity[k] = v
        sigma[k] = scatter / np.sqrt(tau @ tau)
    return velocity, sigma


def first_motion(fix_time: np.ndarray, fix_ned: np.ndarray) -> float:
    """The first time [s] by which the fixes show a change of horizontal velocity within MOTION_WINDOW_S of at
    least MOTION_DV and MOTION_SIGMAS times the velocity difference's typical sigma (velocities fitted over
    MOTION_FIT_S of fixes, on a 1-s grid); infinity when they never do."""
    if len(fix_time) < 3:
        return np.inf
    grid = np.arange(fix_time[0] + MOTION_FIT_S / 2, fix_time[-1] - MOTION_FIT_S / 2, 1.0)
    if len(grid) < 2:
        return np.inf
    velocity, sigma = _grid_velocity(fix_time, fix_ned, grid)
    if not np.isfinite(sigma).any():
        return np.inf
    # the velocities' typical noise over the log: a window's own scatter of three or four fixes is too uncertain
    limit = max(MOTION_DV, MOTION_SIGMAS * np.sqrt(2.0) * float(np.nanmedian(sigma)))
    steps = int(MOTION_WINDOW_S)
    for k in range(len(grid)):
        if not np.isfinite(sigma[k]):
            continue
        ahead = slice(k + 1, k + 1 + steps)
        change = np.hypot(*(velocity[ahead] - velocity[k]).T)
        hit = np.flatnonzero(change >= limit)
        if len(hit):
            return float(grid[k + 1 + hit[0]])
    return np.inf


def bank_choice(headings: np.ndarray, epoch_time: np.ndarray, cum_loglik: np.ndarray, yaw: np.ndarray,
                yaw_sigma: np.ndarray, prior: np.ndarray, motion_from: float = -np.inf) -> BankChoice:
    """The heading the bank decides on. Inputs: the start headings (K,) [rad]; per epoch (E,) and heading: the
    cumulative innovation log-likelihood (E, K), each filter's yaw and its sigma (E, K) [rad]; the heading prior
    weights (K,).

    The mixture's yaw and sigma at each epoch are the weighted circular mean of the filters' yaws and the spread
    about it (each filter's own sigma included). The heading is decided at the first epoch where the filters
    agreeing with the best one within BANK_SAME hold more than BANK_DECIDED_WEIGHT of the weight, or the mixture's
    sigma is at most BANK_MIXTURE_SIGMA, not before ``motion_from`` [s] (:func:`first_motion`), and stays decided
    to the end. The start heading returned
    is the one of the filter with the most weight at the end."""
    # a filter that stopped (diverged) has no likelihood from there on, nor a yaw: it weighs nothing
    reached = np.isfinite(cum_loglik) & np.isfinite(yaw)
    alive = reached.any(axis=1)
    weights = _weights(np.where(reached, cum_loglik, -np.inf), prior[None, :])
    yaw0 = np.where(reached, yaw, 0.0)
    mean = np.angle(np.sum(weights * np.exp(1j * yaw0), axis=1))
    spread = np.sqrt(np.sum(weights * (wrap_pi(yaw0 - mean[:, None]) ** 2 + np.where(reached, yaw_sigma, 0.0) ** 2),
                            axis=1))
    best = np.argmax(weights, axis=1)
    agree = reached & (np.abs(wrap_pi(yaw0 - yaw0[np.arange(len(best)), best][:, None])) <= BANK_SAME)
    share = np.sum(weights * agree, axis=1)
    decided = alive & ((share > BANK_DECIDED_WEIGHT) | (spread <= BANK_MIXTURE_SIGMA)) & (epoch_time >= motion_from)
    undecided = np.flatnonzero(~decided)
    first = 0 if not len(undecided) else int(undecided[-1]) + 1
    alive_rows = np.flatnonzero(alive)
    final = weights[alive_rows[-1]] if len(alive_rows) else weights[-1]
    if first >= len(epoch_time) or not len(alive_rows):
        if not np.isfinite(motion_from):
            return BankChoice(None, None, final, "undecided: the fixes never show an acceleration (a change of "
                              f"{MOTION_DV:g} m/s within {MOTION_WINDOW_S:g} s)")
        return BankChoice(None, None, final, f"undecided: the best heading holds {100 * share[-1]:.0f} % of the "
                          f"weight, the mixture's sigma {np.degrees(spread[-1]):.0f} deg at the end")
    winner = int(np.argmax(final))
    return BankChoice(heading=float(headings[winner]), decided_at=float(epoch_time[first]), weights=final,
                      text=f"decided {epoch_time[first] - epoch_time[0]:.0f} s after the start (mixture sigma "
                           f"{np.degrees(spread[first]):.1f} deg)")
