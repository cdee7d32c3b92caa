"""What any inertial solution can do with a log's IMU as logged: a bound from the log's own sample scatter.

PX4's low-rate logging profile writes ``sensor_combined`` at about 10 Hz, each sample the mean of a few
milliseconds: the motion between samples is not in the log, and the rotor vibration, sampled rather than
integrated, appears as white noise of the full vibration amplitude. A full-rate log resolves the vibration and
its integral over a tenth of a second nearly cancels. What matters for navigation is the noise at low
frequencies, so this script takes means over blocks of about 0.1 s (one sample of the low-rate log), measures
their scatter (first differences over sqrt(2), robust: 1.4826 x median absolute deviation), and puts it, as a
white noise of that density, into the linear model every strapdown filter linearises to, per horizontal axis:

    x' = v,   v' = g phi + w_a,   phi' = w_g      (w_a, w_g white: PSD = scatter^2 x sample interval)

with the log's fixes (its median eph, at its fix rate) except in one 15-s window in the middle of 90 s, as the
scoring withholds them. The Kalman smoother of this model gives the RMS horizontal error inside the window and
the tilt sigma between fixes of the best estimator for such an IMU.

It is an estimate, not a proof: the scatter of 0.1-s means also holds the vehicle's own motion. Where the motion
dominates it (the full-rate logs: a tenth of a m/s^2, about what a flying multicopter's manoeuvres change in a
tenth of a second) the figure overstates the noise and georef does better than it. On the low-rate log a
hovering multicopter's 0.1-s accelerations scatter by 3-8 m/s^2: that is vibration, not motion, and the figure
is what the IMU as logged allows.

Usage: python benchmarks/low_rate_imu_bound.py [LOG ...]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from georef.frames.earth import STANDARD_GRAVITY as G

LOGS = Path(__file__).resolve().parents[1] / "tests" / "data" / "logs"
SPAN_S = 90.0
HOLD_S = 15.0


BLOCK_S = 0.1


def block_means(samples: np.ndarray, per_block: int) -> np.ndarray:
    """Means (M, 3) of consecutive blocks of ``per_block`` samples (N, 3)."""
    m = len(samples) // per_block
    return samples[:m * per_block].reshape(m, per_block, -1).mean(axis=1)


def scatter(samples: np.ndarray) -> np.ndarray:
    """Per-column white scatter of samples (N, 3): robust std of first differences over sqrt(2)."""
    d = np.diff(samples, axis=0)
    mad = np.median(np.abs(d - np.median(d, axis=0)), axis=0)
    return 1.4826 * mad / np.sqrt(2.0)


def smoother_bound(q_accel: float, q_gyro: float, dt: float, fix_every_s: float, sigma_fix: float) -> tuple[float,
                                                                                                            float]:
    """RMS position sigma [m] inside the withheld window and median tilt sigma [deg] where fixes are kept, of the
    linear model of the module doc (one horizontal axis), by a Kalman filter and RTS smoother at step ``dt``."""
    F = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, G], [0.0, 0.0, 0.0]])
    Phi = np.eye(3) + F * dt + F @ F * dt**2 / 2.0
    Q = np.diag([0.0, q_accel * dt, q_gyro * dt])
    Q[0, 1] = Q[1, 0] = q_accel * dt**2 / 2.0
    Q[0, 0] = q_accel * dt**3 / 3.0
    H = np.array([[1.0, 0.0, 0.0]])
    n = int(SPAN_S / dt) + 1
    t = np.arange(n) * dt
    hold = np.abs(t - SPAN_S / 2.0) < HOLD_S / 2.0
    step = max(1, int(round(fix_every_s / dt)))
    P = np.diag([100.0, 100.0, 0.1])
    Pp, Pm = np.empty((n, 3, 3)), np.empty((n, 3, 3))
    for k in range(n):
        if k:
            P = Phi @ P @ Phi.T + Q
        Pm[k] = P
        if k % step == 0 and not hold[k]:
            S = H @ P @ H.T + sigma_fix**2
            K = P @ H.T / S
            P = P - K @ S @ K.T
        Pp[k] = P
    Ps = Pp[-1]
    smoothed = np.empty(n)
    tilt = np.empty(n)
    smoothed[-1], tilt[-1] = Ps[0, 0], Ps[2, 2]
    for k in range(n - 2, -1, -1):
        A = Pp[k] @ Phi.T @ np.linalg.inv(Pm[k + 1])
        Ps = Pp[k] + A @ (Ps - Pm[k + 1]) @ A.T
        smoothed[k], tilt[k] = Ps[0, 0], Ps[2, 2]
    settled = (t > 20.0) & (t < SPAN_S - 20.0) & ~hold
    return float(np.sqrt(np.mean(smoothed[hold]))), float(np.degrees(np.sqrt(np.median(tilt[settled]))))


def main() -> None:
    from georef.io.logs import read_flight_log

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("logs", type=Path, nargs="*", default=sorted(LOGS.glob("*.ulg")) + sorted(LOGS.glob("*.gz")))
    args = parser.parse_args()
    for path in args.logs:
        flight = read_flight_log(path)
        imu = flight.imu
        interval = float(np.median(np.diff(imu.time)))
        per_block = max(1, int(round(BLOCK_S / interval)))
        dt = per_block * interval
        accel, gyro = scatter(block_means(imu.accel, per_block)), scatter(block_means(imu.gyro, per_block))
        fix_every = float(np.median(np.diff(flight.gnss.time)))
        eph = float(np.median(flight.gnss.sigma_neu[:, 0])) if flight.gnss.sigma_neu is not None else 1.0
        print(f"{path.name}: IMU {1 / interval:.1f} Hz, scatter of {dt:.3f}-s means: accel {np.round(accel, 2)} "
              f"m/s^2, gyro {np.round(np.degrees(gyro), 2)} deg/s; fixes every {fix_every:.2f} s, eph {eph:.2f} m")
        per_axis = [smoother_bound(accel[k] ** 2 * dt, gyro[k] ** 2 * dt, dt, fix_every, eph) for k in (0, 1)]
        horizontal = float(np.hypot(per_axis[0][0], per_axis[1][0]))
        print(f"  best possible inside a {HOLD_S:.0f}-s window: {horizontal:.2f} m horizontal RMS; tilt sigma "
              f"between fixes {per_axis[0][1]:.2f} / {per_axis[1][1]:.2f} deg (body x / y axis)")


if __name__ == "__main__":
    main()
