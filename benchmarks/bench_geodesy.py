"""Geodesy throughput: 10^6 points geodetic <-> ECEF, closed form and iterative, against pyproj."""

from __future__ import annotations

import time

import numpy as np
from pyproj import Transformer

from georef.frames import ecef_to_geodetic, ecef_to_geodetic_iterative, geodetic_to_ecef


def timed(label: str, func, *args, repeat: int = 3):
    best = np.inf
    for _ in range(repeat):
        start = time.perf_counter()
        result = func(*args)
        best = min(best, time.perf_counter() - start)
    print(f"  {label:<34} {best * 1e3:8.1f} ms")
    return result


def main() -> None:
    n = 1_000_000
    rng = np.random.default_rng(0)
    lat = np.arcsin(rng.uniform(-1, 1, n))
    lon = rng.uniform(-np.pi, np.pi, n)
    h = rng.uniform(-5000, 50000, n)
    print(f"{n:,} points, best of 3:")
    r = timed("geodetic_to_ecef", geodetic_to_ecef, lat, lon, h)
    timed("ecef_to_geodetic (closed form)", ecef_to_geodetic, r)
    timed("ecef_to_geodetic_iterative", ecef_to_geodetic_iterative, r)
    to_ecef = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    timed("pyproj forward (reference)", to_ecef.transform, np.degrees(lon), np.degrees(lat), h)
    timed("pyproj inverse (reference)", lambda: to_ecef.transform(r[:, 0], r[:, 1], r[:, 2], direction="INVERSE"))


if __name__ == "__main__":
    main()
