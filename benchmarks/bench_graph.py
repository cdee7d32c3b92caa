"""Runtime of --method graph (GTSAM, LM and ISAM2) against rts, and how it grows with flight length."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from georef.pipeline import process
from georef.sim.files import processing_config_for, write_flight
from georef.sim.flight import SimConfig, simulate
from georef.sim.trajectory import FlightPlan


def main() -> None:
    root = Path(tempfile.mkdtemp(prefix="georef-graph-"))
    print(f"{'minutes':>7} {'rts s':>7} {'graph LM s':>10} {'graph ISAM2 s':>13}   (50 Hz, in-process, warm)")
    for minutes in (3, 15, 30):
        flight = simulate(SimConfig(plan=FlightPlan(duration_s=minutes * 60.0)))
        paths = write_flight(flight, root / f"{minutes}")
        cfg = processing_config_for(flight)
        process(paths["POS.txt"], paths["Kamera.txt"], cfg)  # warm caches
        times = []
        for change in ({"method": "rts"}, {"method": "graph"}, {"method": "graph", "graph_solver": "isam2"}):
            start = time.perf_counter()
            process(paths["POS.txt"], paths["Kamera.txt"], cfg.updated(**change))
            times.append(time.perf_counter() - start)
        print(f"{minutes:>7} {times[0]:7.2f} {times[1]:10.2f} {times[2]:13.2f}")


if __name__ == "__main__":
    main()
