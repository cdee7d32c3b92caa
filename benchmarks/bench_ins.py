"""Full-state fusion speed: EKF and EKF+RTS throughput, end-to-end `georef process`, peak memory.

Runs on one core (BLAS and numba threads pinned to 1; ``taskset -c 0`` pins the process too). For each case it
simulates the flight once (kept in --folder), then prints IMU epochs per second of the compiled filter and
smoother, and the wall time and peak RSS of the whole `georef process --method rts` command (Python start-up
included, numba cache warm), with the ahead-of-time kernels of ``georef build-kernels`` and with numba's
JIT (``GEOREF_KERNELS=jit``).
Usage: python benchmarks/bench_ins.py [--cases 15:50 60:200] [--folder /tmp/georef-bench]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from types import SimpleNamespace  # noqa: E402

from georef.config import InsSettings, load_config  # noqa: E402
from georef.fusion.ins import inputs_from_pos, solve_ins  # noqa: E402
from georef.io.pos import read_pos  # noqa: E402
from georef.sim.files import write_flight  # noqa: E402
from georef.sim.flight import SimConfig, simulate  # noqa: E402
from georef.sim.trajectory import FlightPlan  # noqa: E402


def ensure_flight(folder: Path, minutes: float, rate: float) -> Path:
    if not (folder / "POS.txt").exists():
        start = time.perf_counter()
        flight = simulate(SimConfig(plan=FlightPlan(duration_s=minutes * 60.0), pos_rate_hz=rate))
        write_flight(flight, folder)
        print(f"  simulated and wrote {minutes:g} min at {rate:g} Hz in {time.perf_counter() - start:.1f} s")
    return folder


# Runs a command from a small launcher process and prints its wall time [s] and peak RSS [kB]. A child forked
# straight from this (large) benchmark process would start with the benchmark's pages counted in its RSS
# high-water mark, so RUSAGE_CHILDREN here would report the benchmark's memory, not the command's.
LAUNCHER = ("import resource, subprocess, sys, time; start = time.perf_counter(); "
            "subprocess.run(sys.argv[1:], check=True); wall = time.perf_counter() - start; "
            "print(wall, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)")


def run_measured(command: list[str], env: dict[str, str]) -> tuple[float, float]:
    """Wall time [s] and peak RSS [MB] of ``command`` alone."""
    result = subprocess.run([sys.executable, "-c", LAUNCHER, *command], check=True, env=env, capture_output=True,
                            text=True)
    wall, peak_kb = result.stdout.split()
    return float(wall), float(peak_kb) / 1024


KERNEL_CALLS = ("ekf_forward", "rts_backward", "corrected", "finish_rows")


def time_compiled_kernel() -> dict[str, float]:
    """Make solve_ins time its compiled calls: the dict holds the seconds spent in the ins kernel's functions and
    the number of forward passes since the last reset (the noise fit runs several passes, section 4 of
    docs/method-ins.md), and the last forward + backward pass alone."""
    from georef import aot
    from georef.fusion import ins

    totals = {"all": 0.0, "passes": 0.0, "last_pass": 0.0}

    def load(name):
        kernel = aot.load(name)
        if name != "ins":
            return kernel
        wrapped = {}
        for call in KERNEL_CALLS:
            function = getattr(kernel, call)

            def timed(*args, _function=function, _call=call):
                start = time.perf_counter()
                out = _function(*args)
                seconds = time.perf_counter() - start
                totals["all"] += seconds
                if _call == "ekf_forward":
                    totals["passes"] += 1
                    totals["last_pass"] = 0.0
                totals["last_pass"] += seconds
                return out

            wrapped[call] = timed
        return SimpleNamespace(**{**vars(kernel), **wrapped})

    ins.load_kernel = load
    return totals


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--cases", nargs="+", default=["15:50", "60:200"], help="MINUTES:RATE_HZ")
    parser.add_argument("--folder", type=Path, default=Path("/tmp/georef-bench"))
    args = parser.parse_args()
    georef = Path(sys.executable).with_name("georef")
    for case in args.cases:
        minutes, rate = (float(x) for x in case.split(":"))
        folder = ensure_flight(args.folder / f"{minutes:g}min_{rate:g}hz", minutes, rate)
        print(f"{minutes:g} min at {rate:g} Hz:")
        cfg = InsSettings.of(load_config(folder / "flight.toml"))
        log = read_pos(folder / "POS.txt", gnss_rate_hz=1.0)
        inputs = inputs_from_pos(log)
        solve_ins(inputs, cfg, smooth=True)  # warm the numba cache
        compiled = time_compiled_kernel()
        for smooth, label in ((False, "EKF"), (True, "EKF+RTS")):
            compiled.update(all=0.0, passes=0.0, last_pass=0.0)
            start = time.perf_counter()
            nav = solve_ins(inputs, cfg, smooth=smooth)
            seconds = time.perf_counter() - start
            epochs = int(nav.valid.sum())
            print(f"  {label:<8} {seconds:6.2f} s  {epochs / seconds:>9,.0f} IMU epochs/s for all of solve_ins "
                  f"(alignment, {compiled['passes']:.0f} passes of the noise fit, calibration); compiled "
                  f"kernels {compiled['all']:.2f} s in all, the final pass {compiled['last_pass']:.2f} s = "
                  f"{epochs / compiled['last_pass']:,.0f} epochs/s")
        from georef import aot

        print(f"  kernels in this process: {aot.LOADED}")
        for mode in ("auto", "jit"):
            runs = [run_measured([str(georef), "process", str(folder / "POS.txt"), str(folder / "Kamera.txt"),
                                  "--config", str(folder / "flight.toml"), "--method", "rts", "-o",
                                  str(folder / "eo.csv"), "--quiet"], {**os.environ, "GEOREF_KERNELS": mode})
                    for _ in range(4)]  # the first run may refresh a cache; the machine's timing is noisy
            warm = sorted(wall for wall, _ in runs[1:])
            label = "ahead-of-time kernels" if mode == "auto" else "numba JIT from its cache"
            print(f"  georef process --method rts, {label}: {warm[0]:.2f} s best, {warm[1]:.2f} s median of 3 "
                  f"warm runs end to end (Python start-up included); peak RSS {max(p for _, p in runs):.0f} MB")

if __name__ == "__main__":
    main()
