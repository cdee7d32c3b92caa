"""Sigma honesty per kind of flight, with the project's defaults (Monte-Carlo).

Every flight is simulated, written as its files (POS.txt, Kamera.txt, truth.csv, flight.toml) in a folder of its
own, processed with ``georef.pipeline.process`` (``rts``, the default method) and scored against its truth at the
frames (``georef.evaluate.frame_errors``): per frame and component (north, east, up, roll, pitch, yaw) the
normalised error z = error / sigma. The kinds, each made and processed as the tests and benchmarks do today:

* ``two-minute``: ``georef simulate DIR --duration 120 --seed S`` (the CLI's configuration,
  ``SimConfig.for_vehicle("helicopter", 120, S, ...)``, is ``SimConfig(seed=S, plan=FlightPlan(120, seed=S))``);
* ``gnss335-drift4``: ``georef simulate DIR --gnss-sigma 3,3,5 --unit-yaw-drift 4 --seed S`` (180 s), built here
  in Python so that a checkout without those options runs it too;
* ``multicopter-consumer``: ``SimConfig.for_vehicle("multicopter", 180, S)`` processed with
  ``processing_config_for`` (its true IMU preset, ``mems-consumer``; docs/method-ins.md section 9, known limits);
* ``outage40``: the 40-s outage flights of tests/fusion/test_ins.py (outage 80-120 s, outliers at 30, 55 and 140 s);
* ``phone-helicopter``, ``phone-multicopter``, ``phone-car``: benchmarks/robustness.py's phone IMU (consumer-phone
  preset, 0.07 rad/s z gyro bias);
* ``rotor``, ``white``, ``narrowband``: tests/fusion/test_ins.py's ``sim_of`` (white and narrow-band at 0.5, 1 and 2 x
  their reference level, cycled by seed).

All but ``multicopter-consumer`` are processed with ``installation_config`` (lever arms, boresight, GNSS rate
only: the IMU preset, GNSS sigma and unit errors stay at georef's defaults whatever the simulator drew), as
tests/fusion/test_ins.py and benchmarks/robustness.py do; ``--processing`` overrides that for every kind.

Per kind it prints the pooled share of frame errors inside 2 sigma per component (target 88-98 %), the share of
(flight, component) pairs with rms(z) > 3 (target <= 2 %), the QC failures (``georef process`` exit code 4;
target <= 5 % of flights), the mean RMS figures and the median time per flight (simulation, files, processing
and scoring; the first flight of each worker also compiles the kernels when their cache is cold, minutes on a
fresh checkout). ``--json`` keeps every flight's record; ``--compare OLD.json`` prints the paired differences
(flights matched by kind and seed) against an earlier run, e.g. one made with
``PYTHONPATH=/old/checkout python benchmarks/honesty.py --json old.json``.

Usage: python benchmarks/honesty.py [--kinds rotor white ...] [--flights N] [--seeds START] [--workers 2]
                                    [--json OUT.json] [--compare OLD.json] [--processing as-today]
"""

from __future__ import annotations

import os

for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):  # one core per worker
    os.environ.setdefault(_name, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import traceback  # noqa: E402
from concurrent.futures import ProcessPoolExecutor, as_completed  # noqa: E402
from concurrent.futures.process import BrokenProcessPool  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

COMPONENTS = ("north", "east", "up", "roll", "pitch", "yaw")
SIGMAS = ("sigma_n", "sigma_e", "sigma_u", "sigma_roll", "sigma_pitch", "sigma_yaw")
FIGURES = ("horizontal_rms_m", "vertical_rms_m", "roll_rms_deg", "pitch_rms_deg", "yaw_rms_deg")
#: white and narrow-band vibration levels (x the kind's reference), cycled by seed as in tests/fusion/test_ins.py
LEVELS = (0.5, 1.0, 2.0)
#: benchmarks/robustness.py's phone IMU
PHONE = {"imu_preset": "consumer-phone", "gyro_bias_rad_s": (0.0, 0.0, 0.07)}
#: targets: share inside 2 sigma per component, share of (flight, component) pairs with rms(z) > 3, QC failures
INSIDE_2SIGMA = (0.88, 0.98)
RMS_Z_LIMIT, RMS_Z_SHARE = 3.0, 0.02
QC_FAILED_SHARE = 0.05
#: kind -> (default number of flights, processing as today: "installation" or "simulated")
KINDS: dict[str, tuple[int, str]] = {
    "two-minute": (40, "installation"),
    "gnss335-drift4": (40, "installation"),
    "multicopter-consumer": (20, "simulated"),
    "outage40": (20, "installation"),
    "phone-helicopter": (20, "installation"),
    "phone-multicopter": (20, "installation"),
    "phone-car": (20, "installation"),
    "rotor": (20, "installation"),
    "white": (20, "installation"),
    "narrowband": (20, "installation"),
}


def _helicopter_cli(seed: int, duration_s: float, gnss_sigma: tuple[float, float, float] | None = None,
                    unit_yaw_drift_deg_h: float | None = None) -> Any:
    """The configuration ``georef simulate DIR --duration D --seed S [--gnss-sigma ...] [--unit-yaw-drift ...]``
    builds for the helicopter (cli/georef_cli/main.py ``simulate``), made here without the CLI."""
    from georef.sim.flight import SimConfig
    from georef.sim.sensors import GnssModel, UnitModel

    sigma = {} if gnss_sigma is None else {"sigma_neu_m": tuple(float(v) for v in gnss_sigma)}
    gnss = GnssModel(rate_hz=1.0, outages=[], outliers=[], **sigma)
    changes: dict[str, Any] = {"pos_rate_hz": 50.0, "camera_rate_hz": 3.0, "gnss": gnss}
    if unit_yaw_drift_deg_h is not None:
        changes["unit"] = UnitModel(yaw_drift_deg_min=unit_yaw_drift_deg_h / 60.0)
    return SimConfig.for_vehicle("helicopter", duration_s=duration_s, seed=seed, **changes)


def sim_config(kind: str, seed: int) -> Any:
    """The ``SimConfig`` of flight ``seed`` of ``kind``."""
    from georef.sim.flight import SimConfig
    from georef.sim.sensors import GnssModel, VibrationModel

    if kind == "two-minute":
        return _helicopter_cli(seed, 120.0)
    if kind == "gnss335-drift4":
        return _helicopter_cli(seed, 180.0, gnss_sigma=(3.0, 3.0, 5.0), unit_yaw_drift_deg_h=4.0)
    if kind == "multicopter-consumer":
        return SimConfig.for_vehicle("multicopter", 180, seed)
    if kind == "outage40":  # tests/fusion/test_ins.py outage_flights
        return SimConfig(seed=seed, gnss=GnssModel(outages=[(80.0, 40.0)],
                                                   outliers=[(30.0, 25.0), (55.0, 40.0), (140.0, 20.0)]))
    if kind.startswith("phone-"):  # benchmarks/robustness.py _sim("phone:<vehicle>")
        vehicle = kind.removeprefix("phone-")
        return SimConfig(seed=seed, unit=None, **PHONE) if vehicle == "helicopter" else \
            SimConfig.for_vehicle(vehicle, 180, seed, **PHONE)
    if kind == "rotor":  # tests/fusion/test_ins.py sim_of
        return SimConfig(seed=seed)
    if kind in ("white", "narrowband"):
        return SimConfig(seed=seed, vibration=VibrationModel.of_kind(kind, LEVELS[seed % len(LEVELS)]))
    raise ValueError(f"unknown kind {kind!r}; one of {', '.join(KINDS)}")


def _qc_passed(result: Any) -> tuple[bool | None, str]:
    """Whether the run's quality checks passed (``georef process`` exits 4 when not) and their short verdict;
    None when the checkout has no QC."""
    try:
        from georef.qc import assess_result
    except ImportError:
        return None, "no georef.qc.assess_result"
    verdict = assess_result(result)
    return bool(verdict.passed), str(verdict.short())


def _finite(value: Any) -> float | None:
    value = float(value)
    return value if math.isfinite(value) else None


def _clean(value: Any) -> Any:
    """``value`` with every non-finite float as None and numpy scalars as Python ones (strict JSON)."""
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return _finite(value)
    return value


def run_flight(job: tuple[str, int, str, str, bool]) -> dict[str, Any]:
    """Simulate, write, process and score one flight; any exception is recorded, never raised. The flight's folder
    is removed afterwards unless ``keep`` or the flight raised."""
    kind, seed, root, processing, keep = job
    record: dict[str, Any] = {"kind": kind, "seed": seed, "processing": processing, "error": None}
    start = time.perf_counter()
    folder: Path | None = None
    try:
        from georef.evaluate import accuracy, frame_errors
        from georef.pipeline import process
        from georef.sim.files import installation_config, processing_config_for, write_flight
        from georef.sim.flight import simulate

        flight = simulate(sim_config(kind, seed))
        folder = Path(tempfile.mkdtemp(prefix=f"{kind}-{seed}-", dir=root))
        paths = write_flight(flight, folder)
        cfg = processing_config_for(flight) if processing == "simulated" else installation_config(flight)
        began = time.perf_counter()
        result = process(paths["POS.txt"], paths["Kamera.txt"], cfg)
        record["process_s"] = time.perf_counter() - began
        table = result.table
        errors = frame_errors(table, flight.truth_frames)
        record.update({name: _finite(value) for name, value in accuracy(errors).items() if name in FIGURES})
        record["frames"] = len(table)
        outage = table["flag"].astype(str).str.contains("GNSS outage").to_numpy() if "flag" in table else \
            np.zeros(len(table), bool)
        record["frames_in_outage"] = int(outage.sum())
        for component, sigma in zip(COMPONENTS, SIGMAS, strict=True):
            z = errors[component].to_numpy(float) / table[sigma].to_numpy(float)
            ok = np.isfinite(z)
            record[f"n_{component}"] = int(ok.sum())
            record[f"inside2_{component}"] = _finite(np.mean(np.abs(z[ok]) <= 2.0)) if ok.any() else None
            record[f"rms_z_{component}"] = _finite(np.sqrt(np.mean(z[ok] ** 2))) if ok.any() else None
            in_outage = ok & outage
            record[f"n_outage_{component}"] = int(in_outage.sum())
            record[f"inside2_outage_{component}"] = _finite(np.mean(np.abs(z[in_outage]) <= 2.0)) \
                if in_outage.any() else None
        record["qc_passed"], record["qc"] = _qc_passed(result)
        # the attitude check's ratios (forward filter against the smoother): how far legitimate flights go
        record["sigma_scale_attitude"] = result.summary().get("sigma_scale_attitude")
        processing_section = getattr(result.config, "processing", None)
        record["method"] = getattr(processing_section, "method", None)
    except Exception as exc:  # a flight that fails is recorded with its error; the run goes on
        record["error"] = f"{type(exc).__name__}: {exc}"
        record["traceback"] = traceback.format_exc(limit=6)
        record["folder"] = None if folder is None else str(folder)
    record["wall_s"] = time.perf_counter() - start
    if folder is not None and not keep and not record["error"]:
        shutil.rmtree(folder, ignore_errors=True)
    return _clean(record)


def _number(value: Any, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def _progress(record: dict[str, Any], done: int, total: int) -> None:
    if record["error"]:
        text = f"ERROR {record['error'][:160]}"
    else:
        text = (f"h {_number(record['horizontal_rms_m'], '.3f')} m  v {_number(record['vertical_rms_m'], '.3f')} m  "
                f"yaw {_number(record['yaw_rms_deg'], '.3f')} deg  min inside 2 sigma "
                f"{min(record[f'inside2_{c}'] or 0.0 for c in COMPONENTS):.2f}  QC {record['qc']}")
    print(f"[{done}/{total}] {record['kind']:<20} seed {record['seed']:<4} {_number(record['wall_s'], '6.1f')} s  "
          f"{text}",
          file=sys.stderr, flush=True)


def _dead_worker(job: tuple[str, int, str, str, bool], exc: BaseException) -> dict[str, Any]:
    return {"kind": job[0], "seed": job[1], "processing": job[3], "error": f"worker process died: {exc!r}",
            "wall_s": None}


def run_all(jobs: list[tuple[str, int, str, str, bool]], workers: int) -> list[dict[str, Any]]:
    """Every job in a pool of ``workers`` processes. Jobs whose worker died (a crash in compiled code breaks the
    whole pool) are run again one by one, each in a fresh process, so that only the culprit is lost."""
    records: list[dict[str, Any]] = []
    broken: list[tuple[str, int, str, str, bool]] = []
    with ProcessPoolExecutor(workers) as pool:
        futures = {pool.submit(run_flight, job): job for job in jobs}
        for future in as_completed(futures):
            try:
                records.append(future.result())
            except BrokenProcessPool:
                broken.append(futures[future])
                continue
            _progress(records[-1], len(records), len(jobs))
    for job in broken:
        with ProcessPoolExecutor(1) as pool:
            try:
                records.append(pool.submit(run_flight, job).result())
            except BrokenProcessPool as exc:
                records.append(_dead_worker(job, exc))
        _progress(records[-1], len(records), len(jobs))
    order = {(job[0], job[1]): i for i, job in enumerate(jobs)}
    return sorted(records, key=lambda r: order[(r["kind"], r["seed"])])


def _mark(ok: bool) -> str:
    return "✓" if ok else "✗"


def summarise(records: list[dict[str, Any]], kinds: list[str]) -> None:
    """Per kind: pooled share inside 2 sigma per component, rms(z) > 3 pairs, QC failures, mean figures."""
    low, high = INSIDE_2SIGMA
    print(f"Sigma honesty with the defaults (targets: {low:.0%}-{high:.0%} of frame errors inside 2 sigma per "
          f"component, pooled; <= {RMS_Z_SHARE:.0%} of (flight, component) pairs with rms(error/sigma) > "
          f"{RMS_Z_LIMIT:g}; QC failures <= {QC_FAILED_SHARE:.0%} of flights). flights: scored (+N! that raised)")
    header = (f"{'kind':<21} {'flights':>7}  {'inside 2 sigma %: north east up roll pitch yaw':<56} "
              f"{'rms(z)>3':>9}  {'QC failed':>9}  {'h m':>6} {'v m':>6} {'roll':>7} {'pitch':>7} {'yaw':>7}  "
              f"{'median s':>8}")
    print(header)
    for kind in kinds:
        mine = [r for r in records if r["kind"] == kind]
        good = [r for r in mine if not r["error"]]
        errored = len(mine) - len(good)
        flights = f"{len(good)}" + (f"+{errored}!" if errored else "")
        if not good:
            print(f"{kind:<21} {flights:>7}  every flight raised: {mine[0]['error'] if mine else '-'}")
            continue
        shares = []
        for c in COMPONENTS:
            n = np.array([r[f"n_{c}"] for r in good], float)
            inside = np.array([r[f"inside2_{c}"] or 0.0 for r in good], float)
            share = float((n * inside).sum() / n.sum()) if n.sum() else float("nan")
            shares.append(f"{100 * share:5.1f}{_mark(low <= share <= high)}")
        rms_z = [r[f"rms_z_{c}"] for r in good for c in COMPONENTS]
        over = sum(1 for v in rms_z if v is None or v > RMS_Z_LIMIT) / len(rms_z)
        qc_known = [r for r in good if r.get("qc_passed") is not None]
        failed = sum(1 for r in qc_known if not r["qc_passed"])
        qc_share = failed / len(qc_known) if qc_known else float("nan")
        means = {f: np.nanmean([np.nan if r[f] is None else r[f] for r in good]) for f in FIGURES}
        seconds = np.median([r["wall_s"] for r in good if r["wall_s"] is not None])
        qc_text = f"{failed}/{len(qc_known)}{_mark(qc_share <= QC_FAILED_SHARE)}" if qc_known else "n/a"
        print(f"{kind:<21} {flights:>7}  {' '.join(shares):<56} {100 * over:6.1f}%{_mark(over <= RMS_Z_SHARE)} "
              f"{qc_text:>10}  {means['horizontal_rms_m']:6.3f} {means['vertical_rms_m']:6.3f} "
              f"{means['roll_rms_deg']:7.4f} {means['pitch_rms_deg']:7.4f} {means['yaw_rms_deg']:7.4f}  "
              f"{seconds:8.1f}")
        outage = [r for r in good if r.get("frames_in_outage")]
        if outage:
            parts = []
            for c in COMPONENTS:
                n = np.array([r[f"n_outage_{c}"] for r in outage], float)
                inside = np.array([r[f"inside2_outage_{c}"] or 0.0 for r in outage], float)
                parts.append(f"{100 * (n * inside).sum() / max(n.sum(), 1):5.1f}")
            print(f"{'':<21} {'':>7}  {' '.join(parts):<56} (frames in GNSS outages only, "
                  f"{sum(r['frames_in_outage'] for r in outage)} frames)")
    failures = [r for r in records if r["error"]]
    for r in failures:
        print(f"raised: {r['kind']} seed {r['seed']}: {r['error']}")
    qc_failed = [r for r in records if not r["error"] and r.get("qc_passed") is False]
    for r in qc_failed:
        print(f"QC failed: {r['kind']} seed {r['seed']}: {r['qc']}")
    print("attitude check (forward filter against the smoother, RMS ratio, worst of roll/pitch/yaw; fails beyond "
          "20): median / max per kind")
    for kind in kinds:
        worst = [max(v for v in r["sigma_scale_attitude"] if v is not None) for r in records
                 if r["kind"] == kind and not r["error"] and r.get("sigma_scale_attitude")
                 and any(v is not None for v in r["sigma_scale_attitude"])]
        if worst:
            print(f"  {kind:<21} {np.median(worst):6.2f} / {max(worst):6.2f}  ({len(worst)} flights)")


def compare(records: list[dict[str, Any]], old_path: Path, kinds: list[str]) -> None:
    """Mean paired difference (this run - the old one) of every RMS figure per kind, with its standard error."""
    old = {(r["kind"], int(r["seed"])): r for r in json.loads(old_path.read_text())["flights"] if not r.get("error")}
    print(f"Paired differences, this run - {old_path} (flights matched by kind and seed; mean +- one standard "
          "error; worse on: flights where this run is larger)")
    for kind in kinds:
        pairs = [(r, old[(kind, r["seed"])]) for r in records
                 if r["kind"] == kind and not r["error"] and (kind, r["seed"]) in old]
        if not pairs:
            print(f"  {kind:<21} no flight in both runs")
            continue
        parts = []
        for figure in FIGURES:
            d = np.array([new[figure] - was[figure] for new, was in pairs
                          if new.get(figure) is not None and was.get(figure) is not None], float)
            se = d.std(ddof=1) / np.sqrt(len(d)) if len(d) > 1 else float("nan")
            parts.append(f"{figure.removesuffix('_m').removesuffix('_deg')} {d.mean():+.4f} +- {se:.4f} "
                         f"(worse {int((d > 0).sum())})")
        qc_new = sum(1 for new, _ in pairs if new.get("qc_passed") is False)
        qc_old = sum(1 for _, was in pairs if was.get("qc_passed") is False)
        print(f"  {kind:<21} {len(pairs):>3} pairs  " + "  ".join(parts) + f"  QC failed {qc_new} (was {qc_old})")


def _georef_source() -> dict[str, Any]:
    """Which georef this run used: its folder and, when it is a git checkout, the commit and whether it is dirty."""
    import georef

    folder = Path(georef.__file__).resolve().parent
    info: dict[str, Any] = {"path": str(folder)}
    try:
        head = subprocess.run(["git", "-C", str(folder), "rev-parse", "HEAD"], capture_output=True, text=True,
                              timeout=10)
        dirty = subprocess.run(["git", "-C", str(folder), "status", "--porcelain", "--", "."], capture_output=True,
                               text=True, timeout=10)
        if head.returncode == 0:
            info["commit"] = head.stdout.strip()
            info["dirty"] = bool(dirty.stdout.strip())
    except (OSError, subprocess.SubprocessError):
        pass
    return info


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--kinds", nargs="+", choices=list(KINDS), default=list(KINDS), metavar="KIND",
                        help=f"kinds of flight (default: all): {', '.join(KINDS)}")
    parser.add_argument("--flights", type=int, default=None,
                        help="flights per kind (default: 40 two-minute and gnss335-drift4, 20 the others)")
    parser.add_argument("--seeds", type=int, default=1, metavar="START",
                        help="first seed: the flights of each kind are seeds START, START+1, ... (default 1)")
    parser.add_argument("--workers", type=int, default=2, help="processes (default 2)")
    parser.add_argument("--json", type=Path, default=None, metavar="OUT", help="write every flight's record here")
    parser.add_argument("--compare", type=Path, default=None, metavar="OLD.json",
                        help="paired differences against an earlier run's --json")
    parser.add_argument("--keep", action="store_true", help="keep every flight's folder (default: only those "
                                                                   "of flights that raised)")
    parser.add_argument("--processing", choices=("as-today", "installation", "simulated"), default="as-today",
                        help="as-today (default): installation facts only, but multicopter-consumer with the "
                             "simulated installation (processing_config_for); or either for every kind")
    args = parser.parse_args()
    if args.flights is not None and args.flights < 1:
        parser.error("--flights must be at least 1")
    if args.workers < 1:
        parser.error("--workers must be at least 1")
    if args.compare is not None and not args.compare.is_file():
        parser.error(f"--compare: no file {args.compare}")
    root = tempfile.mkdtemp(prefix="georef-honesty-")
    jobs = [(kind, seed, root, KINDS[kind][1] if args.processing == "as-today" else args.processing, args.keep)
            for kind in args.kinds
            for seed in range(args.seeds, args.seeds + (args.flights or KINDS[kind][0]))]
    source = _georef_source()
    print(f"{len(jobs)} flights, {args.workers} worker(s), georef from {source['path']}"
          + (f" at {source['commit'][:12]}{' (modified)' if source.get('dirty') else ''}" if "commit" in source
             else "") + f", flights in {root}", file=sys.stderr, flush=True)
    started = time.perf_counter()
    records = run_all(jobs, args.workers)
    elapsed = time.perf_counter() - started
    try:
        os.rmdir(root)  # empty unless --keep or a flight raised
    except OSError:
        print(f"flight folders kept in {root}", file=sys.stderr)
    summarise(records, args.kinds)
    print(f"{len(records)} flights in {elapsed:.0f} s")
    if args.json is not None:
        document = {"georef": source, "arguments": {k: str(v) if isinstance(v, Path) else v
                                                     for k, v in vars(args).items()},
                    "kernels": os.environ.get("GEOREF_KERNELS"), "elapsed_s": elapsed, "flights": records}
        args.json.write_text(json.dumps(document, indent=1, allow_nan=False))
        print(f"wrote {args.json}")
    if args.compare is not None:
        compare(records, args.compare, args.kinds)


if __name__ == "__main__":
    main()
