"""End-to-end benchmark: simulated flights through every stage of `georef process` (default: one hour at 200 Hz,
``--method rts``, the command's default).

For each length it prints seconds per stage (read, fuse, interpolate, write) of an in-process run (after one run
that warms numba's cache), then the whole ``georef process`` command from a small launcher: wall time, CPU time
(user + system) and peak RSS, Python start-up included, and the noise fit's pass count (``noise_fit_passes`` of
its ``--summary-json``). Several lengths (``--minutes 5 15 30 60 120``) end with a table of how the command's time
grows. The simulated files are kept in ``--folder`` (one sub-folder per length and rate) and reused.

Usage: python benchmarks/bench_pipeline.py [--minutes 60 ...] [--rate 200] [--method rts] [--command-only]
                                           [--folder DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import NamedTuple

from georef.config import load_config
from georef.io.eo_table import write_eo_csv
from georef.pipeline import process
from georef.sim.files import write_flight
from georef.sim.flight import SimConfig, simulate
from georef.sim.trajectory import FlightPlan

# Runs a command from a small launcher process and prints its wall time [s], CPU time [s] and peak RSS [kB]. A child
# forked straight from this (large) benchmark process would start with the benchmark's pages counted in its RSS
# high-water mark.
LAUNCHER = ("import resource, subprocess, sys, time; start = time.perf_counter(); "
            "subprocess.run(sys.argv[1:], check=False); wall = time.perf_counter() - start; "
            "use = resource.getrusage(resource.RUSAGE_CHILDREN); "
            "print(wall, use.ru_utime + use.ru_stime, use.ru_maxrss)")


class CommandRun(NamedTuple):
    """One ``georef process`` command: wall and CPU time [s], peak RSS [MB], the noise fit's passes."""

    wall_s: float
    cpu_s: float
    peak_mb: float
    passes: int | None


def ensure_flight(folder: Path, minutes: float, rate: float) -> Path:
    """The simulated flight of ``minutes`` at ``rate`` [Hz] in ``folder`` (simulated and written once)."""
    if not (folder / "POS.txt").exists():
        start = time.perf_counter()
        flight = simulate(SimConfig(plan=FlightPlan(duration_s=minutes * 60.0), pos_rate_hz=rate))
        simulated = time.perf_counter() - start
        write_flight(flight, folder)
        print(f"simulated {minutes:g} min at {rate:g} Hz in {simulated:.1f} s "
              f"(+{time.perf_counter() - start - simulated:.1f} s writing); "
              f"POS.txt {(folder / 'POS.txt').stat().st_size / 1e6:.0f} MB, {len(flight.pos)} rows", flush=True)
    return folder


def in_process(folder: Path, method: str) -> None:
    """Seconds per stage of ``process`` in this process, after a run that warms numba's cache."""
    cfg = load_config(folder / "flight.toml").updated(method=method)
    process(folder / "POS.txt", folder / "Kamera.txt", cfg)
    start = time.perf_counter()
    result = process(folder / "POS.txt", folder / "Kamera.txt", cfg)
    total = time.perf_counter() - start
    start = time.perf_counter()
    write_eo_csv(result.table, folder / "eo.csv")
    written = time.perf_counter() - start
    rows = len(result.log)
    print(f"rows {rows}, frames {len(result.table)}, method {method}")
    for stage, seconds in result.timings.items():
        print(f"  {stage:<12} {seconds:7.3f} s")
    print(f"  {'write':<12} {written:7.3f} s")
    print(f"  {'total':<12} {total + written:7.3f} s in-process ({rows / (total + written):,.0f} rows/s)")
    print(f"  in-process peak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB "
          "(includes the benchmark's own set-up)")


def command(folder: Path, method: str) -> CommandRun:
    """The ``georef process`` command on the flight in ``folder``, from a small launcher."""
    georef = Path(sys.executable).with_name("georef")
    summary = folder / "summary.json"
    summary.unlink(missing_ok=True)
    args = [str(georef), "process", str(folder / "POS.txt"), str(folder / "Kamera.txt"), "--config",
            str(folder / "flight.toml"), "--method", method, "-o", str(folder / "eo_cli.csv"), "--quiet",
            "--summary-json", str(summary)]
    done = subprocess.run([sys.executable, "-c", LAUNCHER, *args], check=True, env=dict(os.environ),
                          capture_output=True, text=True)
    wall, cpu, peak_kb = (float(v) for v in done.stdout.split())
    passes = json.loads(summary.read_text())["summary"].get("noise_fit_passes") if summary.exists() else None
    return CommandRun(wall, cpu, peak_kb / 1024, passes)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--minutes", type=float, nargs="+", default=[60.0], help="flight lengths [min]")
    parser.add_argument("--rate", type=float, default=200.0, help="POS rows per second")
    parser.add_argument("--method", default="rts", help="georef's --method (default rts, the command's default)")
    parser.add_argument("--command-only", action="store_true", help="time the command only (no in-process stages)")
    parser.add_argument("--runs", type=int, default=1, help="command runs per length (the median is printed)")
    parser.add_argument("--folder", type=Path, default=None, help="reuse/keep the simulated files here")
    args = parser.parse_args()

    root = args.folder or Path(tempfile.mkdtemp(prefix="georef-bench-"))
    table = []
    for minutes in args.minutes:
        folder = ensure_flight(root / f"{minutes:g}min-{args.rate:g}hz", minutes, args.rate)
        if not args.command_only:
            in_process(folder, args.method)
        runs = sorted((command(folder, args.method) for _ in range(args.runs)), key=lambda r: r.wall_s)
        run = runs[len(runs) // 2]
        print(f"  georef process command, {minutes:g} min: {run.wall_s:.2f} s wall, {run.cpu_s:.2f} s CPU, peak RSS "
              f"{run.peak_mb:.0f} MB, noise fit {run.passes} passes (Python start-up included)", flush=True)
        table.append((minutes, run))
    if len(table) > 1:
        print(f"\n| minutes at {args.rate:g} Hz | rows | wall s | CPU s | CPU s per minute | peak RSS MB | "
              "fit passes |")
        print("|---|---|---|---|---|---|---|")
        for minutes, run in table:
            print(f"| {minutes:g} | {round(minutes * 60 * args.rate):,} | {run.wall_s:.2f} | {run.cpu_s:.2f} | "
                  f"{run.cpu_s / minutes:.3f} | {run.peak_mb:.0f} | {run.passes} |")


if __name__ == "__main__":
    main()
