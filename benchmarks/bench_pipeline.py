"""End-to-end benchmark: a simulated one-hour 200 Hz flight through every stage of `georef process`.

Prints seconds per stage (read, fuse, interpolate, write), the end-to-end command time with Python
start-up, and peak memory. Usage: python benchmarks/bench_pipeline.py [--minutes 60] [--rate 200]
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

from bench_ins import run_measured  # same folder: the command's own peak memory

from georef.config import load_config
from georef.io.eo_table import write_eo_csv
from georef.pipeline import process
from georef.sim.files import write_flight
from georef.sim.flight import SimConfig, simulate
from georef.sim.trajectory import FlightPlan


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--minutes", type=float, default=60.0)
    parser.add_argument("--rate", type=float, default=200.0, help="POS rows per second")
    parser.add_argument("--method", default="axis")
    parser.add_argument("--folder", type=Path, default=None, help="reuse/keep the simulated files here")
    args = parser.parse_args()

    folder = args.folder or Path(tempfile.mkdtemp(prefix="georef-bench-"))
    pos = folder / "POS.txt"
    if not pos.exists():
        start = time.perf_counter()
        flight = simulate(SimConfig(plan=FlightPlan(duration_s=args.minutes * 60.0), pos_rate_hz=args.rate))
        simulated = time.perf_counter() - start
        write_flight(flight, folder)
        print(f"simulated {args.minutes:g} min at {args.rate:g} Hz in {simulated:.1f} s "
              f"(+{time.perf_counter() - start - simulated:.1f} s writing); "
              f"POS.txt {pos.stat().st_size / 1e6:.0f} MB, {len(flight.pos)} rows")
        del flight
    cfg = load_config(folder / "flight.toml").updated(method=args.method)

    # warm the numba cache once so the figures below are steady-state
    process(pos, folder / "Kamera.txt", cfg)
    start = time.perf_counter()
    result = process(pos, folder / "Kamera.txt", cfg)
    total = time.perf_counter() - start
    start = time.perf_counter()
    write_eo_csv(result.table, folder / "eo.csv")
    written = time.perf_counter() - start
    rows = len(result.log)
    print(f"rows {rows}, frames {len(result.table)}, method {args.method}")
    for stage, seconds in result.timings.items():
        print(f"  {stage:<12} {seconds:7.3f} s")
    print(f"  {'write':<12} {written:7.3f} s")
    print(f"  {'total':<12} {total + written:7.3f} s in-process ({rows / (total + written):,.0f} rows/s)")
    print(f"  in-process peak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB "
          "(includes the benchmark's own set-up)")

    georef = Path(sys.executable).with_name("georef")
    wall, peak = run_measured([str(georef), "process", str(pos), str(folder / "Kamera.txt"), "--config",
                               str(folder / "flight.toml"), "--method", args.method, "-o",
                               str(folder / "eo_cli.csv"), "--quiet"], dict(os.environ))
    print(f"  georef process command: {wall:.2f} s end to end (Python start-up included), peak RSS {peak:.0f} MB")


if __name__ == "__main__":
    main()
