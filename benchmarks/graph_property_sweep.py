"""``--method graph`` never exits 3 (internal error): many random simulated flights, end to end through the CLI.

Each case draws a seed, a POS rate (50-200 Hz), an IMU class, a vehicle, a duration (20-120 s), zero to three
GNSS outages (some at the very start or running past the end, some long) and zero to three outliers (3-60 m),
simulates it with ``georef simulate`` and runs ``georef process --method graph`` on POS.txt/Kamera.txt, or
``georef fuse --method graph`` on the generic imu.csv/gnss.csv (one case in three). Exit 0 and 4 are fine,
2 must name genuinely invalid input (printed for review), 3 is a bug. The same cases are drawn for the same
``--seed``. ``tests/fusion/test_graph_properties.py`` runs a few of the same kind in CI.

Usage: python benchmarks/graph_property_sweep.py [--cases 60] [--workers 2] [--seed 0] [--keep DIR]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

IMUS = ("mems-ivru", "mems-consumer", "consumer-phone", "tactical-fog")
VEHICLES = ("helicopter", "multicopter", "car")
GEOREF = [sys.executable, "-m", "georef_cli.main"]


def draw_case(rng: np.random.Generator, index: int) -> dict:
    """One random valid flight: simulate arguments and the command (process or fuse) to run on it."""
    duration = float(np.round(rng.uniform(20.0, 120.0), 1))
    outages = []
    for _ in range(rng.integers(0, 4)):
        where = rng.choice(["start", "end", "middle", "long"])
        length = float(np.round(rng.uniform(2.0, 15.0), 1))
        if where == "start":
            start = 0.0
        elif where == "end":
            start = float(np.round(duration - rng.uniform(0.5, length), 1))
        elif where == "long":
            length = float(np.round(rng.uniform(0.3, 0.7) * duration, 1))
            start = float(np.round(rng.uniform(0.0, duration - length), 1))
        else:
            start = float(np.round(rng.uniform(0.0, duration), 1))
        outages.append((start, length))
    outliers = [(float(np.round(rng.uniform(0.0, duration), 1)), float(np.round(rng.uniform(3.0, 60.0), 1)))
                for _ in range(rng.integers(0, 4))]
    return {"index": index, "seed": int(rng.integers(1, 1_000_000)), "rate": float(rng.integers(50, 201)),
            "imu": str(rng.choice(IMUS)), "vehicle": str(rng.choice(VEHICLES)), "duration": duration,
            "outages": outages, "outliers": outliers, "command": "fuse" if rng.random() < 1 / 3 else "process"}


def simulate_args(case: dict, folder: Path) -> list[str]:
    """``georef simulate`` arguments for ``case``."""
    args = ["simulate", str(folder), "--vehicle", case["vehicle"], "--duration", str(case["duration"]),
            "--rate", str(case["rate"]), "--seed", str(case["seed"]), "--imu", case["imu"], "-q"]
    for start, length in case["outages"]:
        args += ["--outage", f"{start},{length}"]
    for when, size in case["outliers"]:
        args += ["--outlier", f"{when},{size}"]
    if case["command"] == "fuse":
        args.append("--generic")
    return args


def run_args(case: dict, folder: Path) -> list[str]:
    """``georef process`` or ``georef fuse`` arguments (``--method graph``) on the simulated files."""
    if case["command"] == "fuse":
        return ["fuse", "--imu", str(folder / "imu.csv"), "--gnss", str(folder / "gnss.csv"), "--method", "graph",
                "-o", str(folder / "traj.csv"), "-q"]
    return ["process", str(folder / "POS.txt"), str(folder / "Kamera.txt"), "--config", str(folder / "flight.toml"),
            "--method", "graph", "-o", str(folder / "eo.csv"), "-q"]


def describe(case: dict) -> str:
    """The case as the two shell commands that reproduce it."""
    folder = Path(f"case{case['index']}")
    return f"georef {' '.join(simulate_args(case, folder))} && georef {' '.join(run_args(case, folder))}"


def run_case(case: dict, keep: str | None) -> dict:
    """Simulate and run one case in a scratch folder; its exit codes, time and the last line it printed."""
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    with tempfile.TemporaryDirectory(dir=keep) as scratch:
        folder = Path(scratch) / f"case{case['index']}"
        sim = subprocess.run(GEOREF + simulate_args(case, folder), capture_output=True, text=True, env=env)
        if sim.returncode != 0:
            return {**case, "stage": "simulate", "code": sim.returncode, "seconds": 0.0,
                    "message": (sim.stdout + sim.stderr).strip()[-400:]}
        start = time.perf_counter()
        done = subprocess.run(GEOREF + run_args(case, folder), capture_output=True, text=True, env=env)
        return {**case, "stage": case["command"], "code": done.returncode, "seconds": time.perf_counter() - start,
                "message": " ".join((done.stdout + done.stderr).split())[-400:]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=60)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--keep", default=None, help="make the scratch folders under this directory")
    options = parser.parse_args()
    rng = np.random.default_rng(options.seed)
    cases = [draw_case(rng, i) for i in range(options.cases)]
    start = time.perf_counter()
    with ProcessPoolExecutor(options.workers) as pool:
        results = list(pool.map(run_case, cases, [options.keep] * len(cases)))
    counts = Counter((r["stage"], r["code"]) for r in results)
    print(f"{len(results)} cases in {time.perf_counter() - start:.0f} s ({options.workers} workers)")
    for (stage, code), n in sorted(counts.items()):
        print(f"  {stage:8s} exit {code}: {n}")
    by_kind = Counter((r["vehicle"], r["code"]) for r in results)
    print("  by vehicle:", ", ".join(f"{v} exit {c}: {n}" for (v, c), n in sorted(by_kind.items())))
    for r in results:
        if r["code"] not in (0, 4) or r["stage"] == "simulate":
            print(f"\nexit {r['code']} at {r['stage']}: {describe(r)}\n  {r['message']}")
    if any(r["code"] == 3 for r in results):
        sys.exit(1)


if __name__ == "__main__":
    main()
