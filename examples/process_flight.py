"""Library use: simulate a flight, georeference every frame, and compare with the truth.

Run: .venv/bin/python examples/process_flight.py
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from georef.config import GnssSection, MountingSection, OutputSection, ProcessingConfig, ProcessingSection
from georef.evaluate import accuracy, frame_errors
from georef.io.eo_table import write_eo_csv
from georef.pipeline import process
from georef.qc import assess_result
from georef.sim.files import write_flight
from georef.sim.flight import SimConfig, simulate


def main() -> None:
    folder = Path(tempfile.mkdtemp(prefix="georef-example-"))
    flight = simulate(SimConfig(seed=7))
    paths = write_flight(flight, folder)

    # The installation, as a photogrammetrist would type it from the survey report.
    # One section per flight.toml section ([processing], [mounting], [gnss], [output]).
    cfg = ProcessingConfig(
        processing=ProcessingSection(method="axis"),
        mounting=MountingSection(
            lever_arm_gnss=(0.45, 0.15, -1.65),     # m, body frame: IMU -> GNSS antenna
            lever_arm_camera=(1.10, -0.25, 0.55),   # m, body frame: IMU -> camera perspective centre
            boresight=(0.35, -0.6, 1.2),            # deg, camera in body frame
        ),
        gnss=GnssSection(sigma=(1.0, 1.0, 2.0)),   # m, N/E/U
        output=OutputSection(crs="EPSG:3765"),      # HTRS96/TM easting/northing
    )
    result = process(paths["POS.txt"], paths["Kamera.txt"], cfg)
    write_eo_csv(result.table, folder / "eo.csv")

    summary = result.summary()
    print(f"{summary['frames_written']} frames -> {folder / 'eo.csv'}")
    print(f"yaw offset {summary['yaw_offset_deg']:.2f} ± {summary['yaw_offset_sigma_deg']:.2f} deg")
    for name, value in accuracy(frame_errors(result.table, flight.truth_frames)).items():
        print(f"  {name:<18} {value:.3f}")
    print(assess_result(result))    # the quality checks: "QC passed" or what failed and what to do


if __name__ == "__main__":
    main()
