"""End-to-end `georef process` wall time, `--method graph` against `--method rts`, on a simulated 15-minute
(or ``--minutes``) 50 Hz flight: alternating runs on one core (``taskset -c 0`` when available), Python start-up,
reading and writing included. Prints each method's best and median and the ratio graph / rts.

Run: ``python benchmarks/graph_vs_rts_cli.py [--minutes 15] [--runs 3]``.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from georef.sim.files import write_flight
from georef.sim.flight import FlightPlan, SimConfig, simulate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--minutes", type=float, default=15.0)
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()
    georef = str(Path(sys.executable).with_name("georef"))
    pin = ["taskset", "-c", "0"] if shutil.which("taskset") else []
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    with tempfile.TemporaryDirectory() as tmp:
        paths = write_flight(simulate(SimConfig(plan=FlightPlan(duration_s=args.minutes * 60.0))), tmp)
        times: dict[str, list[float]] = {"rts": [], "graph": []}
        for run in range(args.runs + 1):  # the first round warms the caches and is not counted
            for method in times:
                start = time.perf_counter()
                done = subprocess.run([*pin, georef, "process", str(paths["POS.txt"]), str(paths["Kamera.txt"]),
                                       "--config", str(paths["flight.toml"]), "--method", method, "-q", "-o",
                                       str(Path(tmp) / f"{method}.csv")], env=env, capture_output=True, text=True)
                seconds = time.perf_counter() - start
                if done.returncode not in (0, 4):
                    raise SystemExit(f"{method} exited {done.returncode}: {done.stderr[-400:]}")
                if run:
                    times[method].append(seconds)
    for method, values in times.items():
        values.sort()
        print(f"{method:>5}: best {values[0]:.2f} s, median {values[len(values) // 2]:.2f} s, runs "
              f"{', '.join(f'{v:.2f}' for v in values)}")
    best = times["graph"][0] / times["rts"][0]
    median = times["graph"][len(times["graph"]) // 2] / times["rts"][len(times["rts"]) // 2]
    print(f"graph / rts ({args.minutes:g} min, 50 Hz, end to end): best {best:.2f}x, median {median:.2f}x "
          "(target <= 2x)")


if __name__ == "__main__":
    main()
