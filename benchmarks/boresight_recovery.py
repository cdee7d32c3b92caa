"""Boresight / camera lever-arm recovery on simulated blocks (``docs/boresight.md``).

Each block: a flight simulated by ``georef.sim`` (default: the multicopter block of
``georef.sim.adjusted_block.cross_strip_plan``, north-south strips then east-west cross strips, heading along the
track, mems-consumer IMU, GNSS 1/1/2 m), processed by ``georef.pipeline.process`` with a WRONG boresight (errors
uniform in +-0.5 deg per axis) and camera lever arm (+-5 cm), and "adjusted" cameras made from the simulator's
true camera poses plus adjustment noise (1.5 cm, 0.003 deg), written as a Metashape export (the format rotates
over Metashape, Pix4D and ODM by block) and read back. ``georef.calibration.boresight.calibrate`` then estimates
the corrections, once with the process run's figures (``ProcessResult.summary()``, what ``georef process
--summary-json`` writes and ``calibrate-boresight --process-summary`` reads: the filter's accelerometer-bias sigma)
and once without (the conservative bound); the truth is the true mounting minus the configured one.

Printed: per block the errors and sigmas; for both runs, pooled over blocks and observed components, the share of
estimates within 2 sigma of the truth (target >= 90 %) and rms(error / sigma) (1 when the sigmas are honest), the
same with the model's between-strip sigma and with the jackknife sigma, per quantity; the ratio of the roll and
pitch sigma to the median per-frame EO sigma (target <= 0.5 with cross strips); the yaw sigma. Then the check of
the body-fixed tilt against the simulator: the truth's strip-averaged body-frame INS tilt against the filter's
accelerometer-bias error over g (regression slope -1 expected: opposite sign conventions) and against its sigma;
the flight-mean yaw error against the EO's yaw sigma; the exit status (weak estimates). ``--vehicle helicopter``
runs parallel strips without cross strips (opposite headings only) instead.

Usage: python benchmarks/boresight_recovery.py [--blocks 20] [--seed 1] [--vehicle multicopter|helicopter]
                                               [--json OUT.json]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from georef.calibration.boresight import calibrate, match_photos
from georef.io.adjusted_cameras import read_adjusted_cameras
from georef.io.process_summary import figures_of_summary
from georef.sim.adjusted_block import (
    BLOCK_CRS,
    accel_bias_tilt_deg,
    adjusted_cameras,
    body_fixed_tilt_deg,
    flight_yaw_error_deg,
    simulate_block,
    write_adjusted,
)

FORMATS = ("metashape", "pix4d", "odm")


def run_block(seed: int, vehicle: str, folder: Path) -> dict:
    rng = np.random.default_rng(1000 + seed)
    boresight_error = tuple(rng.uniform(-0.5, 0.5, 3))
    lever_error = tuple(rng.uniform(-0.05, 0.05, 3))
    start = time.perf_counter()
    block = simulate_block(seed, boresight_error, lever_error, vehicle=vehicle)
    fmt = FORMATS[seed % 3]
    path = write_adjusted(adjusted_cameras(block.truth, rng), folder / f"block{seed}.{fmt}", fmt)
    photos = match_photos(block.eo, "eo", read_adjusted_cameras(path, fmt), BLOCK_CRS)
    process = figures_of_summary(block.process_summary)
    result = calibrate(photos, block.configured_boresight_deg, block.configured_lever_arm_m, process=process)
    conservative = calibrate(photos, block.configured_boresight_deg, block.configured_lever_arm_m)
    record = {"seed": seed, "format": fmt, "runtime_s": time.perf_counter() - start, "strips": len(result.strips),
              "photos": result.photos_used, "tilt_estimated": result.tilt_estimated, "problems": result.problems,
              "median_sigma_deg": [float(block.eo[c].median()) for c in ("sigma_roll", "sigma_pitch", "sigma_yaw")],
              "body_fixed_tilt_deg": [float(v) for v in body_fixed_tilt_deg(block, photos)],
              "accel_bias_tilt_deg": [float(v) for v in accel_bias_tilt_deg(block, photos)],
              "accel_bias_tilt_sigma_deg": [float(np.degrees(process.accel_bias_sigma_m_s2[k] / photos.gravity_m_s2))
                                            for k in (1, 0)],
              "flight_yaw_error_deg": flight_yaw_error_deg(block, photos),
              "components": _components(result, boresight_error, lever_error),
              "conservative": _components(conservative, boresight_error, lever_error)}
    return record


def _components(result, boresight_error, lever_error) -> list[dict]:
    out = []
    truths = list(boresight_error) + list(lever_error)
    for c, truth in zip(result.boresight + result.lever_arm, truths, strict=True):
        out.append({"name": f"{'boresight' if c.unit == 'deg' else 'lever'} {c.name}", "estimated": c.estimated,
                    "observed": c.observed, "truth": float(truth), "value": c.value, "sigma": c.sigma,
                    "model_sigma": c.model_sigma, "jackknife_sigma": c.jackknife_sigma})
    return out


NAMES = ("boresight roll", "boresight pitch", "boresight yaw", "lever y")


def pooled(records: list[dict], key: str, label: str) -> None:
    """Coverage and rms z of the observed components of ``records[*][key]`` (``components``: the sigma with the
    process summary; ``conservative``: without it)."""
    z_all, z_model, z_jk, ratios = [], [], [], []
    for r in records:
        for c in r[key]:
            if c["observed"]:
                error = c["value"] - c["truth"]
                z_all.append(error / c["sigma"])
                z_model.append(error / c["model_sigma"])
                if c["jackknife_sigma"]:
                    z_jk.append(error / c["jackknife_sigma"])
        ratios += [r[key][k]["sigma"] / r["median_sigma_deg"][k] for k in range(2)]
    z_all, z_model, z_jk = np.abs(z_all), np.abs(z_model), np.abs(z_jk)
    print(f"[{label}] observed components pooled: {len(z_all)}; within 2 sigma {100 * np.mean(z_all <= 2):.1f} % "
          f"(target >= 90 %), rms z {np.sqrt(np.mean(z_all**2)):.2f}")
    print(f"[{label}]   between-strip model sigma only: within 2 sigma {100 * np.mean(z_model <= 2):.1f} %, rms z "
          f"{np.sqrt(np.mean(z_model**2)):.2f}; jackknife sigma: within 2 sigma {100 * np.mean(z_jk <= 2):.1f} %, "
          f"rms z {np.sqrt(np.mean(z_jk**2)):.2f} ({len(z_jk)})")
    for name in NAMES:
        zs = np.array([abs((c["value"] - c["truth"]) / c["sigma"]) for r in records for c in r[key]
                       if c["name"] == name and c["observed"]])
        jk = np.array([abs((c["value"] - c["truth"]) / c["jackknife_sigma"]) for r in records for c in r[key]
                       if c["name"] == name and c["observed"] and c["jackknife_sigma"]])
        to_jk = [c["sigma"] / c["jackknife_sigma"] for r in records for c in r[key]
                 if c["name"] == name and c["observed"] and c["jackknife_sigma"]]
        if len(zs):
            print(f"[{label}]   {name:>16}: within 2 sigma {100 * np.mean(zs <= 2):.0f} % of {len(zs)}, rms z "
                  f"{np.sqrt(np.mean(zs**2)):.2f}; jackknife rms z {np.sqrt(np.mean(jk**2)):.2f}, median "
                  f"sigma/jackknife {np.median(to_jk):.2f}")
    applied = sum(c["estimated"] for r in records for c in r[key] if c["name"] == "lever y")
    print(f"[{label}]   lever y applied (significant at 2 sigma): {applied} of {len(records)}")
    print(f"[{label}]   roll/pitch sigma / median per-frame EO sigma: median {np.median(ratios):.2f}, max "
          f"{np.max(ratios):.2f} (target <= 0.5)")
    yaw = [r[key][2]["sigma"] for r in records]
    print(f"[{label}]   yaw sigma [deg]: median {np.median(yaw):.3f}, range {np.min(yaw):.3f}-{np.max(yaw):.3f}")


def report(records: list[dict]) -> None:
    print(f"{'seed':>4} {'fmt':>9} {'strips':>6} {'name':>15} {'truth':>9} {'error':>9} {'sigma':>8} {'z':>6} "
          f"{'jk':>8} {'old sigma':>9}")
    weak = 0
    for r in records:
        weak += bool(r["problems"])
        for c, old in zip(r["components"], r["conservative"], strict=True):
            if c["observed"]:
                error = c["value"] - c["truth"]
                jk = f"{c['jackknife_sigma']:.4f}" if c["jackknife_sigma"] else "-"
                print(f"{r['seed']:>4} {r['format']:>9} {r['strips']:>6} {c['name']:>15} {c['truth']:>9.4f} "
                      f"{error:>9.4f} {c['sigma']:>8.4f} {error / c['sigma']:>6.2f} {jk:>8} {old['sigma']:>9.4f}")
    print()
    print(f"blocks: {len(records)}")
    pooled(records, "components", "with --process-summary")
    pooled(records, "conservative", "without (conservative)")
    body = np.array([r["body_fixed_tilt_deg"] for r in records])
    predicted = np.array([r["accel_bias_tilt_deg"] for r in records])
    sigma = np.array([r["accel_bias_tilt_sigma_deg"] for r in records])
    per_frame = np.array([r["median_sigma_deg"][:2] for r in records])
    print(f"INS tilt fixed in the body frame (truth, strip-averaged, about body x, y): median |.| "
          f"{np.median(np.abs(body)):.4f} deg, max {np.max(np.abs(body)):.4f} deg = median "
          f"{np.median(np.abs(body) / per_frame):.2f} x the per-frame sigma")
    for k, axis in enumerate("xy"):
        slope = float(np.sum(body[:, k] * predicted[:, k]) / np.sum(predicted[:, k] ** 2))
        corr = float(np.corrcoef(body[:, k], predicted[:, k])[0, 1])
        rms = np.sqrt(np.mean((body[:, k] / sigma[:, k]) ** 2))
        print(f"  about body {axis}: truth vs the filter's accel-bias error / g: regression slope {slope:+.2f}, "
              f"correlation {corr:+.2f}; truth / (accel-bias sigma / g): rms {rms:.2f}, within 2 sigma "
              f"{100 * np.mean(np.abs(body[:, k]) <= 2 * sigma[:, k]):.0f} %; sigma / per-frame sigma median "
              f"{np.median(sigma[:, k] / per_frame[:, k]):.2f}")
    yaw = np.array([r["flight_yaw_error_deg"] for r in records])
    yaw_eo = np.array([r["median_sigma_deg"][2] for r in records])
    print(f"INS yaw error averaged over the flight (truth): rms {np.sqrt(np.mean(yaw**2)):.3f} deg, rms over the EO's "
          f"median yaw sigma {np.sqrt(np.mean((yaw / yaw_eo) ** 2)):.2f}")
    print(f"weak estimates (exit 4): {weak} of {len(records)}")
    print(f"median time per block: {np.median([r['runtime_s'] for r in records]):.1f} s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--blocks", type=int, default=20)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--vehicle", choices=("multicopter", "helicopter"), default="multicopter")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    records = []
    with tempfile.TemporaryDirectory(prefix="georef-boresight-") as folder:
        for seed in range(args.seed, args.seed + args.blocks):
            records.append(run_block(seed, args.vehicle, Path(folder)))
            print(f"block {seed}: {records[-1]['runtime_s']:.1f} s", flush=True)
    report(records)
    if args.json:
        args.json.write_text(json.dumps(records, indent=2), encoding="utf-8")


if __name__ == "__main__":
    main()
