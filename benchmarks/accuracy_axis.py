"""Accuracy of `--method axis` against truth over several simulated seed-like flights.

Prints, per seed: camera-position RMS (horizontal, vertical), roll/pitch/yaw RMS, the GNSS-interpolation
baseline, the yaw-offset error, and the share of errors inside 2 sigma.
Usage: python benchmarks/accuracy_axis.py [--seeds 1 2 3 ...] [--minutes 3]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from georef.evaluate import accuracy, frame_errors, gnss_interpolation_baseline, sigma_coverage
from georef.pipeline import process
from georef.sim.files import processing_config_for, write_flight
from georef.sim.flight import SimConfig, simulate
from georef.sim.trajectory import FlightPlan


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seeds", type=int, nargs="+", default=list(range(1, 11)))
    parser.add_argument("--minutes", type=float, default=3.0)
    args = parser.parse_args()
    folder = Path(tempfile.mkdtemp(prefix="georef-acc-"))
    header = (f"{'seed':>4} {'horiz m':>8} {'base m':>7} {'vert m':>7} {'roll':>6} {'pitch':>6} {'yaw':>6} "
              f"{'offset err':>10} {'2s N/E/U %':>13} {'2s yaw %':>8}")
    print(header)
    rows = []
    for seed in args.seeds:
        flight = simulate(SimConfig(seed=seed, plan=FlightPlan(duration_s=args.minutes * 60.0, seed=seed)))
        paths = write_flight(flight, folder / str(seed))
        cfg = processing_config_for(flight).updated(method="axis")
        result = process(paths["POS.txt"], paths["Kamera.txt"], cfg)
        errors = frame_errors(result.table, flight.truth_frames)
        fig = accuracy(errors)
        base = accuracy(frame_errors(gnss_interpolation_baseline(result.exposures, result.log.gnss, result.nav, cfg),
                                     flight.truth_frames))
        cover = sigma_coverage(result.table, errors)
        yaw = result.nav.info["yaw_offset"]
        true = np.interp(yaw.reference_time, flight.truth_frames["time"], flight.truth_frames["unit_yaw_offset"])
        offset_error = np.degrees(yaw.offset) - true
        rows.append([fig["horizontal_rms_m"], base["horizontal_rms_m"], fig["vertical_rms_m"], fig["roll_rms_deg"],
                     fig["pitch_rms_deg"], fig["yaw_rms_deg"], abs(offset_error)])
        print(f"{seed:>4} {fig['horizontal_rms_m']:8.3f} {base['horizontal_rms_m']:7.3f} {fig['vertical_rms_m']:7.3f} "
              f"{fig['roll_rms_deg']:6.3f} {fig['pitch_rms_deg']:6.3f} {fig['yaw_rms_deg']:6.3f} "
              f"{offset_error:+10.3f} {100 * cover['north']:4.0f}/{100 * cover['east']:3.0f}/{100 * cover['up']:3.0f} "
              f"{100 * cover['yaw']:8.0f}")
    mean = np.mean(rows, axis=0)
    print(f"{'mean':>4} {mean[0]:8.3f} {mean[1]:7.3f} {mean[2]:7.3f} {mean[3]:6.3f} {mean[4]:6.3f} {mean[5]:6.3f} "
          f"{mean[6]:10.3f} (|offset error|)")


if __name__ == "__main__":
    main()
