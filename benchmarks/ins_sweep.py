"""The INS Monte-Carlo sweep that was a fixture of tests/fusion/test_ins.py: eighty flights, every check printed.

Twenty flights (seeds 1-20) of each vibration kind, processed with ``rts`` and the defaults plus the flight's
installation (:func:`georef.sim.files.installation_config`: lever arms, boresight, GNSS rate); today's flights
(``rotor``, ``SimConfig(seed)``) with ``ekf`` too. The kinds: ``rotor`` (MEMS unit, rotor vibration), ``none``
(no vibration), ``white`` and ``narrowband`` at 0.5, 1 and 2 times their reference level, cycled over the seeds.

The checks, with the bounds they had in the suite (each prints its figures and PASS, FAIL or XFAIL):

* ``honest``: per kind and component (north, east, up, roll, pitch, yaw) 90-98 % of the frames' errors inside
  +-2 sigma, pooled over the kind's flights; over 98 % is a known shortfall on the safe side (XFAIL) for the
  pairs in ``PESSIMISTIC``;
* ``normalised``: on today's flights the RMS of error / sigma in 0.75-1.25 for every component (NEES-like);
* ``targets``: every one of today's flights within 0.4 m horizontal, 0.7 m vertical RMS, 0.03 deg roll and
  pitch, 0.15 deg yaw;
* ``before``: today's flights against the code before the rewrite (tests/data/todays_flights_before.json): per
  figure the mean paired difference new - before under two standard errors;
* ``rts-beats-ekf``: the smoother beats the forward filter on the mean of every figure and on position on every
  flight;
* ``vibration``: white vibration (the hardest kind) keeps every flight within 0.6 m horizontal, 1.0 m vertical,
  0.5 deg yaw, and its mean horizontal RMS is worse than without vibration.

The suite keeps a cheap check of the sigmas on two flights (tests/fusion/test_ins.py); benchmarks/honesty.py and
benchmarks/robustness.py (``--only honesty before``) give the same kinds with other figures. Exits 1 when a check
fails.

Usage: python benchmarks/ins_sweep.py [--flights 20] [--workers 2]
"""

from __future__ import annotations

import os

for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):  # one core per worker
    os.environ.setdefault(_name, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import NamedTuple  # noqa: E402

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

#: white and narrow-band vibration at three levels (x the kind's reference RMS), cycled over the seeds
LEVELS = (0.5, 1.0, 2.0)
KINDS = ("rotor", "none", "white", "narrowband")
FIGURES = ("horizontal_rms_m", "vertical_rms_m", "roll_rms_deg", "pitch_rms_deg", "yaw_rms_deg")
COMPONENTS = ("north", "east", "up", "roll", "pitch", "yaw")
SIGMAS = ("sigma_n", "sigma_e", "sigma_u", "sigma_roll", "sigma_pitch", "sigma_yaw")
BEFORE = Path(__file__).resolve().parents[1] / "tests" / "data" / "todays_flights_before.json"

#: (kind, component) whose sigmas are measured too large (over 98 % of errors inside 2 sigma), never too small
PESSIMISTIC = {
    ("rotor", "yaw"): "0.9870 measured 2026-11-26 (0.967 before): every pass keeps the alignment's prior mean, and "
                      "the unit's yaw drift may change at 0.2 deg/min per sqrt(min) (0.05 before), what two-minute "
                      "flights need; this simulator's unit drifts at a constant rate, so its sigma is spare here",
    ("none", "yaw"): "0.9893 measured 2026-11-26 (0.963 before), for the same two reasons",
}


class Sweep(NamedTuple):
    """The sweep's results: one row of figures per flight and method, and per kind the frames' errors divided by
    their sigmas (rts; columns in ``COMPONENTS`` order), pooled over the kind's flights."""

    figures: pd.DataFrame
    normalised: dict[str, np.ndarray]


def sim_of(kind: str, seed: int):
    """``rotor``: today's flights (``SimConfig(seed)``: MEMS unit, rotor vibration); the other kinds at three
    levels."""
    from georef.sim.flight import SimConfig
    from georef.sim.sensors import VibrationModel

    if kind == "rotor":
        return SimConfig(seed=seed)
    vibration = None if kind == "none" else VibrationModel.of_kind(kind, LEVELS[seed % len(LEVELS)])
    return SimConfig(seed=seed, vibration=vibration)


def _normalised(errors: pd.DataFrame, table: pd.DataFrame) -> np.ndarray:
    return np.stack([errors[c].to_numpy() / table[s].to_numpy() for c, s in zip(COMPONENTS, SIGMAS, strict=True)],
                    -1)


def run_flight(job: tuple[str, int]) -> tuple[str, int, list[dict], np.ndarray]:
    """One flight simulated, written, processed (rts; ekf too for ``rotor``) and scored against its truth."""
    from georef.evaluate import accuracy, frame_errors
    from georef.pipeline import process
    from georef.sim.files import installation_config, write_flight
    from georef.sim.flight import simulate

    kind, seed = job
    methods = ("rts", "ekf") if kind == "rotor" else ("rts",)
    flight = simulate(sim_of(kind, seed))
    figures, normalised = [], np.empty((0, len(COMPONENTS)))
    with tempfile.TemporaryDirectory() as folder:
        paths = write_flight(flight, Path(folder))
        cfg = installation_config(flight)
        for method in methods:
            result = process(paths["POS.txt"], paths["Kamera.txt"], cfg.updated(method=method))
            errors = frame_errors(result.table, flight.truth_frames)
            figures.append({"kind": kind, "seed": seed, "method": method, **accuracy(errors)})
            if method == "rts":
                normalised = _normalised(errors, result.table)
    return kind, seed, figures, normalised


def run_sweep(seeds: range, workers: int) -> Sweep:
    jobs = [(kind, seed) for kind in KINDS for seed in seeds]
    with ProcessPoolExecutor(workers) as pool:
        done = list(pool.map(run_flight, jobs))
    figures = pd.DataFrame([row for _, _, rows, _ in done for row in rows])
    normalised = {kind: np.concatenate([z for k, _, _, z in done if k == kind]) for kind in KINDS}
    return Sweep(figures, normalised)


def check_honest(sweep: Sweep, seeds: range) -> bool:
    """90-98 % of the frames' errors inside +-2 sigma, per kind and component, pooled over the kind's flights."""
    ok = True
    for kind in KINDS:
        for index, component in enumerate(COMPONENTS):
            share = float(np.mean(np.abs(sweep.normalised[kind][:, index]) <= 2.0))
            verdict = "PASS" if 0.90 <= share <= 0.98 else "FAIL"
            if share > 0.98 and (kind, component) in PESSIMISTIC:
                verdict = "XFAIL (known shortfall, on the safe side)"
            ok &= not verdict.startswith("FAIL")
            print(f"  {kind:<10} {component:<5} inside 2 sigma {share:.4f}  {verdict}")
    return ok


def check_normalised(sweep: Sweep, seeds: range) -> bool:
    """NEES-like: the RMS of error / sigma in 0.75-1.25 for every component on today's flights."""
    rms = np.sqrt(np.mean(sweep.normalised["rotor"] ** 2, axis=0))
    print("  rms(error / sigma):", dict(zip(COMPONENTS, rms.round(3).tolist(), strict=True)))
    return bool(((rms >= 0.75) & (rms <= 1.25)).all())


def check_targets(sweep: Sweep, seeds: range) -> bool:
    """Every one of today's flights within the accuracy targets."""
    rts = sweep.figures.query("kind == 'rotor' and method == 'rts'")
    limits = {"horizontal_rms_m": 0.4, "vertical_rms_m": 0.7, "roll_rms_deg": 0.03, "pitch_rms_deg": 0.03,
              "yaw_rms_deg": 0.15}
    ok = True
    for figure, limit in limits.items():
        worst = float(rts[figure].max())
        ok &= worst <= limit
        print(f"  {figure:<17} worst {worst:.4f} (limit {limit}), mean {rts[figure].mean():.4f}")
    return ok


def check_before(sweep: Sweep, seeds: range) -> bool:
    """For every figure, the mean per-flight difference new - before not significantly positive (under two
    standard errors of the paired differences)."""
    before = json.loads(BEFORE.read_text())["flights"]
    rts = sweep.figures.query("kind == 'rotor' and method == 'rts'").set_index("seed")
    ok = True
    compared = [seed for seed in seeds if str(seed) in before]
    for figure in FIGURES:
        difference = np.array([rts.loc[seed, figure] - before[str(seed)][figure] for seed in compared])
        standard_error = difference.std(ddof=1) / np.sqrt(len(difference))
        ok &= difference.mean() <= 2.0 * standard_error
        print(f"  {figure:<17} mean new - before {difference.mean():+.4f}, two standard errors "
              f"{2.0 * standard_error:.4f}")
    return ok


def check_rts_beats_ekf(sweep: Sweep, seeds: range) -> bool:
    """The smoother beats the forward filter on the mean of every figure and on position on every flight."""
    wide = sweep.figures.query("kind == 'rotor'").pivot(index="seed", columns="method")
    ok = True
    for figure in FIGURES:
        ok &= wide[figure]["rts"].mean() < wide[figure]["ekf"].mean()
        print(f"  {figure:<17} mean rts {wide[figure]['rts'].mean():.4f}, ekf {wide[figure]['ekf'].mean():.4f}")
    for figure in ("horizontal_rms_m", "vertical_rms_m"):
        beaten = int((wide[figure]["rts"] < wide[figure]["ekf"]).sum())
        ok &= beaten == len(wide)
        print(f"  {figure:<17} rts better on {beaten} of {len(wide)} flights")
    return ok


def check_vibration(sweep: Sweep, seeds: range) -> bool:
    """White vibration (up to twice the reference level) keeps every flight within metre-level position and
    sub-degree attitude, and its mean horizontal RMS is worse than without vibration."""
    rts = sweep.figures.query("method == 'rts'")
    white = rts[rts["kind"] == "white"]
    none = rts[rts["kind"] == "none"]
    print(f"  white: worst horizontal {white['horizontal_rms_m'].max():.3f} m (limit 0.6), vertical "
          f"{white['vertical_rms_m'].max():.3f} m (1.0), yaw {white['yaw_rms_deg'].max():.3f} deg (0.5); mean "
          f"horizontal {white['horizontal_rms_m'].mean():.3f} m against {none['horizontal_rms_m'].mean():.3f} m "
          "without vibration")
    return bool((white["horizontal_rms_m"] <= 0.6).all() and (white["vertical_rms_m"] <= 1.0).all()
                and (white["yaw_rms_deg"] <= 0.5).all()
                and white["horizontal_rms_m"].mean() > none["horizontal_rms_m"].mean())


CHECKS: dict[str, Callable[[Sweep, range], bool]] = {
    "honest": check_honest, "normalised": check_normalised, "targets": check_targets, "before": check_before,
    "rts-beats-ekf": check_rts_beats_ekf, "vibration": check_vibration,
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--flights", type=int, default=20, help="flights per kind, seeds 1..N (default 20; "
                        "'before' compares seeds 1-20 only)")
    parser.add_argument("--workers", type=int, default=2, help="processes (default 2)")
    args = parser.parse_args()
    seeds = range(1, args.flights + 1)
    start = time.perf_counter()
    sweep = run_sweep(seeds, args.workers)
    print(f"{len(seeds)} flights of each of {', '.join(KINDS)} in {time.perf_counter() - start:.0f} s "
          f"({args.workers} workers)")
    failed = []
    for name, check in CHECKS.items():
        print(f"{name}: {' '.join(check.__doc__.split())}")
        passed = check(sweep, seeds)
        print(f"{name}: {'PASS' if passed else 'FAIL'}")
        if not passed:
            failed.append(name)
    print("all checks pass" if not failed else f"FAILED: {', '.join(failed)}")
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
