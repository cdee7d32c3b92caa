"""One flight's calibration by the graph: does the estimated GNSS lever arm lie within 2 sigma of the truth in
>= 90 % of flights, and how large is its sigma on a survey pattern with turns?

Each flight: a helicopter survey (``SimConfig`` defaults: strips with turns, rotor vibration, its own seed),
PPK-grade GNSS (white, ``--gnss-sigma`` horizontal, twice that vertical), the lever arm (0.45, 0.15, -1.65) m NOT
given to georef (free: 10 m prior). The time offset (truth zero) at its default prior (zero, 2 ms), or held
to ``--latency-sigma`` seconds when the user knows it. The graph runs in-process (``solve_graph``), one flight
per worker process.

Run: ``python benchmarks/calibration_coverage.py [--flights 20] [--duration 600] [--workers 2]``.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace

import numpy as np

TRUE_LEVER = np.array([0.45, 0.15, -1.65])


def one_flight(seed: int, duration: float, sigma: float, latency_sigma: float | None) -> dict:
    """Simulate, write and read one flight; the graph's lever arm, time offset and their sigmas."""
    from georef.fusion.graph import solve_graph
    from georef.io.pos import read_pos
    from georef.sim.files import processing_config_for, write_flight
    from georef.sim.flight import SimConfig, simulate
    from georef.sim.sensors import GnssModel

    sim = SimConfig(seed=seed, lever_arm_gnss_m=tuple(TRUE_LEVER),
                    gnss=GnssModel(sigma_neu_m=(sigma, sigma, 2 * sigma)))
    sim = replace(sim, plan=replace(sim.plan, duration_s=duration))
    flight = simulate(sim)
    with tempfile.TemporaryDirectory() as tmp:
        paths = write_flight(flight, tmp)
        cfg = processing_config_for(flight).updated(lever_arm_gnss=(0.0, 0.0, 0.0),
                                                    gnss_sigma=(sigma, sigma, 2 * sigma), method="graph")
        if latency_sigma is not None:
            cfg = cfg.updated(gnss_latency=0.0, gnss_latency_sigma=latency_sigma)
        start = time.perf_counter()
        nav = solve_graph(read_pos(paths["POS.txt"]), cfg)
        seconds = time.perf_counter() - start
    return {"seed": seed, "lever": np.asarray(nav.graph_info.lever_arm_m, float),
            "lever_sigma": np.asarray(nav.graph_info.lever_arm_sigma_m, float),
            "offset": float(nav.graph_info.time_offset_s),
            "offset_sigma": float(nav.graph_info.time_offset_sigma_s),
            "seconds": seconds}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--flights", type=int, default=20)
    parser.add_argument("--duration", type=float, default=600.0, help="flight length [s]")
    parser.add_argument("--gnss-sigma", type=float, default=0.02, help="horizontal fix sigma [m]")
    parser.add_argument("--latency-sigma", type=float, default=None,
                        help="hold the time offset at zero with this sigma [s] (default: georef's prior)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--first-seed", type=int, default=1)
    args = parser.parse_args()
    seeds = range(args.first_seed, args.first_seed + args.flights)
    start = time.perf_counter()
    with ProcessPoolExecutor(args.workers) as pool:
        results = list(pool.map(one_flight, seeds, [args.duration] * args.flights,
                                [args.gnss_sigma] * args.flights, [args.latency_sigma] * args.flights))
    wall = time.perf_counter() - start
    held = "default prior (0 +- 2 ms)" if args.latency_sigma is None else f"0 +- {args.latency_sigma * 1e3:g} ms"
    print(f"{args.flights} helicopter surveys of {args.duration:.0f} s, fixes {args.gnss_sigma} m, lever arm "
          f"{TRUE_LEVER} m not given, time offset {held}; {wall:.0f} s wall, {args.workers} workers")
    z = np.array([(r["lever"] - TRUE_LEVER) / r["lever_sigma"] for r in results])
    sigma = np.array([r["lever_sigma"] for r in results])
    z_offset = np.array([r["offset"] / r["offset_sigma"] for r in results])
    for r, zi in zip(results, z, strict=True):
        print(f"  seed {r['seed']:3d}: lever arm {np.round(r['lever'], 3)} +- {np.round(r['lever_sigma'], 3)} m, "
              f"error/sigma {np.round(zi, 2)}; time offset {r['offset'] * 1e3:+.2f} +- "
              f"{r['offset_sigma'] * 1e3:.2f} ms ({r['seconds']:.1f} s)")
    inside = np.abs(z) <= 2.0
    print(f"within 2 sigma per axis x/y/z: {np.round(100 * inside.mean(axis=0), 0)} %; all three axes: "
          f"{100 * inside.all(axis=1).mean():.0f} %; time offset: {100 * (np.abs(z_offset) <= 2).mean():.0f} % "
          f"(target >= 90 %)")
    print(f"RMS error/sigma x/y/z: {np.round(np.sqrt((z**2).mean(axis=0)), 2)} (1 when sigma is honest)")
    print(f"sigma x/y/z median {np.round(np.median(sigma, axis=0), 4)} m, max {np.round(sigma.max(axis=0), 4)} m "
          f"(target <= 0.05 m per axis)")


if __name__ == "__main__":
    main()
