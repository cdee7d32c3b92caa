"""Cost per step of every attitude filter (compiled), on 60 s of 200 Hz MARG data, one core.

The MATLAB MEKF of [A1] (docs/attitude.md, References) took 718 us per iteration; the target here is at
most 2 us for the MEKF.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import time  # noqa: E402

import numpy as np  # noqa: E402

from georef.attitude.mekf import run_mekf  # noqa: E402
from georef.attitude.tilt import accel_tilt, angle_bias_kalman, complementary  # noqa: E402
from georef.attitude.ukf import run_ukf  # noqa: E402
from georef.sim.marg import MargConfig, simulate_marg  # noqa: E402


def per_step(func, n: int, repeat: int = 5) -> float:
    func()  # compile / load the cache
    best = np.inf
    for _ in range(repeat):
        start = time.perf_counter()
        func()
        best = min(best, time.perf_counter() - start)
    return best / n * 1e6


def main() -> None:
    data = simulate_marg(MargConfig(duration_s=60.0))
    n = len(data.time)
    roll_acc, pitch_acc = accel_tilt(data.accel)
    cases = {
        "complementary (roll+pitch)": lambda: complementary(data.time, data.gyro, roll_acc, pitch_acc, 0.02),
        "angle+bias KF (roll+pitch)": lambda: angle_bias_kalman(data.time, data.gyro, roll_acc, pitch_acc, 1e-5,
                                                                 1e-7, 1e-4),
        "MEKF (acc + mag)": lambda: run_mekf(data.time, data.gyro, data.accel, data.mag, data.mag_reference),
        "MEKF (acc only)": lambda: run_mekf(data.time, data.gyro, data.accel),
        "UKF (acc + mag)": lambda: run_ukf(data.time, data.gyro, data.accel, data.mag, data.mag_reference),
    }
    print(f"{n} samples, best of 5, including the Python wrapper and output conversion:")
    for name, func in cases.items():
        cost = per_step(func, n)
        print(f"  {name:<28} {cost:8.3f} us/step   ({718.0 / cost:,.0f}x faster than [A1]'s MATLAB)")


if __name__ == "__main__":
    main()
