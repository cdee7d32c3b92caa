"""RMS table of every attitude filter on synthetic MARG data, with and without a 0.1 rad/s gyro bias.

Errors after the first 20 s (bias learning), degrees. Also the yaw of pure gyro integration, and the
closed-form yaw offset between the accelerometer-only MEKF and the truth (its yaw origin is arbitrary).
"""

from __future__ import annotations

import numpy as np

from georef.attitude.compare import yaw_offset
from georef.attitude.run import estimate_attitude
from georef.frames import wrap_pi
from georef.sim.marg import MargConfig, simulate_marg

SETTLED = 4000


def main() -> None:
    print(f"{'method':<14} {'gyro bias':>9} {'roll':>7} {'pitch':>7} {'yaw':>7}   (RMS deg after 20 s)")
    for bias in ((0.1, -0.1, 0.1), (0.0, 0.0, 0.0)):
        data = simulate_marg(MargConfig(amplitude_deg=(20.0, 15.0, 90.0), gyro_bias=bias))
        truth = np.stack([data.roll, data.pitch, data.yaw], -1)
        for method in ("complementary", "kf", "mekf", "ukf"):
            table = estimate_attitude(method, data.time, data.gyro, data.accel, data.mag)
            cells = []
            for i, axis in enumerate(("roll", "pitch", "yaw")):
                if axis not in table:
                    cells.append(f"{'-':>7}")
                    continue
                error = wrap_pi(np.radians(table[axis].to_numpy()) - truth[:, i])[SETTLED:]
                cells.append(f"{np.degrees(np.sqrt(np.mean(error**2))):7.3f}")
            print(f"{method:<14} {bias[0]:9.2f} {' '.join(cells)}")
        acc_only = estimate_attitude("mekf", data.time, data.gyro, data.accel)
        estimate = np.radians(acc_only[["roll", "pitch", "yaw"]].to_numpy())
        found = yaw_offset(estimate, truth)
        print(f"{'mekf, no mag':<14} {bias[0]:9.2f} yaw offset to truth {np.degrees(found.offset):.2f} deg, "
              f"yaw RMS after removing it {np.degrees(found.residual_rms):.3f} deg")


if __name__ == "__main__":
    main()
