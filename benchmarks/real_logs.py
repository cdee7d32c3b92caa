"""georef on the real autopilot logs of tests/data/logs, scored without truth (``georef.scoring``).

For every log, method (rts, ekf) and IMU preset (the log default ``autopilot``, and the presets a user might
honestly pick for the hardware) it prints, at the GNSS fixes withheld in 15-s windows every 45 s from the first
speed of 3 m/s: the horizontal RMS of the solution and of linear interpolation of the kept fixes, the receiver's
median eph, rms(error/sigma), and the target max(0.5 x interpolation, 2 x eph) for a ground or hover start;
then roll, pitch and yaw against the autopilot's own estimate (mean difference removed and printed), the QC
verdict of the run and the solve time.

Usage: python benchmarks/real_logs.py [--logs PATH ...] [--methods rts ekf] [--presets autopilot mems-consumer]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import pandas as pd

from georef.config import ProcessingConfig
from georef.scoring import score_log

LOGS = Path(__file__).resolve().parents[1] / "tests" / "data" / "logs"
DEFAULT_LOGS = ("ardupilot_copter_log171.bin.gz", "px4_quad_ground_start.ulg", "px4_quad_hover_start.ulg")
#: the issue's targets for a log that starts on the ground or hovering
INTERPOLATION_SHARE = 0.5
EPH_FACTOR = 2.0
TILT_TARGET_DEG = 3.0
YAW_TARGET_DEG = 10.0


def _row(path: Path, method: str, preset: str) -> dict[str, object]:
    cfg = ProcessingConfig().updated(method=method, imu_preset=preset)
    start = time.perf_counter()
    score = score_log(path, cfg)
    seconds = time.perf_counter() - start
    held = score.withheld
    target = max(INTERPOLATION_SHARE * held.interpolation_rms_h, EPH_FACTOR * held.eph)
    row: dict[str, object] = {
        "log": path.name.split(".")[0], "method": method, "preset": preset,
        "windows": held.windows, "error_h_m": held.error_rms_h, "interp_h_m": held.interpolation_rms_h,
        "eph_m": held.eph, "target_m": target, "position_ok": held.error_rms_h <= target, "z_rms": held.z_rms,
        "verdict": "pass" if score.verdict.passed else "FAIL", "solve_s": seconds,
        "heading": score.heading_source.split(":")[0],
    }
    attitude = score.attitude
    if attitude is not None:
        rms, mean = attitude.rms_deg, attitude.mean_difference_deg
        row.update(roll_rms=rms[0], pitch_rms=rms[1], yaw_rms=rms[2], roll_mean=mean[0], pitch_mean=mean[1],
                   yaw_mean=mean[2],
                   attitude_ok=bool(np.all(rms[:2] <= TILT_TARGET_DEG) and not rms[2] > YAW_TARGET_DEG))
    row["estimators_deg"] = score.estimators_deg
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--logs", type=Path, nargs="+", default=[LOGS / name for name in DEFAULT_LOGS])
    parser.add_argument("--methods", nargs="+", default=["rts", "ekf"])
    parser.add_argument("--presets", nargs="+", default=["autopilot", "mems-consumer"])
    args = parser.parse_args()
    rows = [_row(path, method, preset) for path in args.logs for method in args.methods for preset in args.presets]
    table = pd.DataFrame(rows)
    pd.set_option("display.width", 250)
    pd.set_option("display.max_columns", 30)
    print(table.round(2).to_string(index=False))
    worse = table[table["error_h_m"] > table["interp_h_m"]]
    print(f"\nruns worse than interpolation at the withheld fixes: {len(worse)} of {len(table)}")
    for _, row in worse.iterrows():
        print(f"  {row['log']} {row['method']} {row['preset']}: {row['error_h_m']:.2f} m against "
              f"{row['interp_h_m']:.2f} m, verdict {row['verdict']}")
    passed_bad = worse[worse["verdict"] == "pass"]
    print(f"of those passed by the verdict: {len(passed_bad)}")


if __name__ == "__main__":
    main()
