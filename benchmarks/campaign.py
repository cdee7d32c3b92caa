"""Campaign calibration (``georef batch --method graph --shared-calibration``) on simulated flights of one
installation: is the campaign's sigma about 1/sqrt(n) of one flight's, does the estimate cover the truth, is a
flight with a moved antenna flagged, and is no flight of an unchanged installation flagged?

Each flight: a helicopter survey (``SimConfig`` defaults, its own seed), PPK-grade GNSS (white, ``--gnss-sigma``
horizontal, twice that vertical), the lever arm (0.45, 0.15, -1.65) m NOT given to georef (free), the time offset
at its default prior (zero, 2 ms). Two campaigns: all flights unchanged, and the last flight with its antenna
moved by ``--moved`` metres along body y. Run: ``python benchmarks/campaign.py [--flights 8] [--duration 600]``.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from georef.batch import discover, run_batch
from georef.config import config_to_toml
from georef.sim.files import processing_config_for, write_flight
from georef.sim.flight import SimConfig, simulate
from georef.sim.sensors import GnssModel

TRUE_LEVER = np.array([0.45, 0.15, -1.65])


def make_campaign(root: Path, flights: int, duration: float, sigma: float, moved: float | None) -> None:
    """Write ``flights`` flight folders (POS.txt, Kamera.txt, flight.toml without the lever arm) under ``root``."""
    for seed in range(1, flights + 1):
        lever = TRUE_LEVER + (np.array([0.0, moved, 0.0]) if moved and seed == flights else 0.0)
        sim = SimConfig(seed=seed, lever_arm_gnss_m=tuple(lever),
                        gnss=GnssModel(sigma_neu_m=(sigma, sigma, 2 * sigma)))
        sim = replace(sim, plan=replace(sim.plan, duration_s=duration))
        flight = simulate(sim)
        folder = root / f"flight{seed:02d}"
        write_flight(flight, folder)
        cfg = processing_config_for(flight).updated(lever_arm_gnss=(0.0, 0.0, 0.0),
                                                    gnss_sigma=(sigma, sigma, 2 * sigma), method="graph")
        (folder / "flight.toml").write_text(config_to_toml(cfg), encoding="utf-8")


def run(flights: int, duration: float, sigma: float, moved: float | None, workers: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "flights"
        make_campaign(root, flights, duration, sigma, moved)
        start = time.perf_counter()
        summary = run_batch(discover(root), Path(tmp) / "out", method="graph", workers=workers,
                            shared_calibration=True)
        seconds = time.perf_counter() - start
        calibration = json.loads((Path(tmp) / "out" / "calibration.json").read_text())
    calibration["seconds"] = seconds
    calibration["statuses"] = summary["status"].tolist()
    return calibration


def report(title: str, calibration: dict, flights: int, moved: float | None) -> None:
    mean = np.array(calibration["gnss_lever_arm_m"])
    sigma = np.array(calibration["gnss_lever_arm_sigma_m"])
    own_sigma = np.array([f["gnss_lever_arm_sigma_m"] for f in calibration["flights"].values()], float)
    used = [name for name, f in calibration["flights"].items() if f["consistent"]]
    flagged = [name for name, f in calibration["flights"].items() if not f["consistent"]]
    print(f"{title}: {flights} flights, {calibration['rounds']} rounds, {calibration['seconds']:.0f} s wall")
    print(f"  campaign lever arm {np.round(mean, 4)} +- {np.round(sigma, 4)} m; truth {TRUE_LEVER}; "
          f"error/sigma {np.round((mean - TRUE_LEVER) / sigma, 2)}")
    print(f"  time offset {calibration['gnss_time_offset_s'] * 1e3:.2f} +- "
          f"{calibration['gnss_time_offset_sigma_s'] * 1e3:.2f} ms (truth 0)")
    median = np.median(own_sigma, axis=0)
    print(f"  one flight's sigma (median) {np.round(median, 4)} m; campaign/one flight "
          f"{np.round(sigma / median, 3)} against 1/sqrt({len(used)}) = {1 / np.sqrt(len(used)):.3f}")
    for name, f in calibration["flights"].items():
        print(f"  {name}: {np.round(f['gnss_lever_arm_m'], 3)} +- {np.round(f['gnss_lever_arm_sigma_m'], 3)}; "
              f"chi2 {f['chi2']:.1f} ({f['dof']} dof, p {f['p_value']:.2g}) "
              f"{'consistent' if f['consistent'] else 'FLAGGED'}")
    print(f"  flagged: {flagged or 'none'}" + (f" (moved by {moved} m: flight{flights:02d})" if moved else ""))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--flights", type=int, default=8)
    parser.add_argument("--duration", type=float, default=600.0, help="seconds per flight")
    parser.add_argument("--gnss-sigma", type=float, default=0.01, help="horizontal GNSS sigma [m]")
    parser.add_argument("--moved", type=float, default=0.10, help="the last flight's antenna moved along y [m]")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    for title, moved in (("unchanged installation", None), (f"antenna moved {args.moved} m", args.moved)):
        report(title, run(args.flights, args.duration, args.gnss_sigma, moved, args.workers), args.flights, moved)


if __name__ == "__main__":
    main()
