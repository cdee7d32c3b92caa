"""End-to-end wall time of `georef process` (EKF + RTS smoother, EO, write) against KF-GINS, a C++ forward-only
loosely coupled EKF (i2Nav, Wuhan University; Niu et al. 2025, GPS Solutions 29:202), on the same simulated
helicopter flight (default 870 s at 50 Hz, the files of ``georef simulate --duration 870 --rate 50``).

georef reads POS.txt and Kamera.txt as a user would; KF-GINS reads text files converted beforehand (the
conversion is not timed): ``imu.txt`` (time, angle and velocity increments of each interval, the trapezoid of
the row rates, as georef's mechanisation takes them), ``gnss.txt`` (the antenna fixes with their sigmas) and a
configuration with the true initial state (KF-GINS does not align), the IMU preset's noise densities and the
GNSS lever arm. KF-GINS propagates its 21-state covariance at every IMU row and writes its navigation result,
IMU errors and sigmas at every row; georef aligns, fits its noise model (several estimation passes), runs the
forward filter and the smoother at full rate and writes one EO row per exposure.

The two commands run alternately, each pinned to one core (``taskset -c 0`` when present), a first round not
counted; the medians of the wall time (and of the CPU time, steadier on a loaded machine) and the ratio
georef / KF-GINS are printed with the load average before and after, and KF-GINS's horizontal position error
against the truth (a check that it really filtered the flight). georef runs with its bytecode cached
(``PYTHONDONTWRITEBYTECODE`` is dropped from the environment), as an installed georef does after its first run.

KF-GINS is not a dependency of georef: ``--kfgins`` (or ``$KFGINS``) names its built binary, its source tree
(built here with cmake into ``<tree>/build``) or a git repository of it (its sources are exported into a
temporary folder and built there). Without it the benchmark times georef alone and says so.

``--kind`` names flights of other characters, each the helicopter flight of ``georef simulate`` with one thing
changed (:data:`KINDS`): ``rotor`` (the default: the MEMS unit's rotor vibration), ``white`` and ``narrow-band``
vibration at twice their reference level, ``gnss-3m`` (GNSS noise 3/3/5 m north/east/up, as ``--gnss-sigma
3,3,5``), ``outage40`` (two 40-s GNSS outages and three outliers), ``multicopter`` (``georef simulate --vehicle
multicopter``: consumer IMU, narrow-band vibration, no POS unit). KF-GINS gets each flight's GNSS sigmas and the
IMU preset's noise densities. The noise fit's pass count (``noise_fit_passes`` of ``--summary-json``, from the
first, uncounted round) is printed: georef's cost grows with it.

Run: ``python benchmarks/vs_kfgins.py --kfgins ~/src/KF-GINS [--kind rotor] [--duration 870] [--rate 50]
[--runs 5]``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from georef.frames import C_e_n, geodetic_to_ecef
from georef.imu_errors import imu_preset
from georef.sim.files import write_flight
from georef.sim.flight import SimConfig, SimulatedFlight, simulate
from georef.sim.sensors import GnssModel, VibrationModel

#: flight kind -> what it changes in the helicopter flight of ``georef simulate`` (:func:`sim_config`)
KINDS: dict[str, str] = {
    "rotor": "the helicopter as simulated by default (MEMS unit, 16 Hz rotor vibration)",
    "white": "white (broad-band) vibration at twice its reference level",
    "narrow-band": "narrow-band vibration (20 +- 2 Hz) at twice its reference level",
    "gnss-3m": "GNSS noise 3/3/5 m north/east/up",
    "outage40": "GNSS outages of 40 s at 200 and 520 s, outliers of 25, 40 and 20 m at 150, 400 and 700 s",
    "multicopter": "a multicopter: consumer IMU, narrow-band vibration, no POS unit",
}


def sim_config(kind: str, duration_s: float, seed: int, rate_hz: float) -> SimConfig:
    """The simulated flight of ``kind`` (:data:`KINDS`): ``duration_s`` [s], IMU rows at ``rate_hz`` [Hz]."""
    changes: dict[str, object] = {"pos_rate_hz": rate_hz}
    if kind in ("white", "narrow-band"):
        changes["vibration"] = VibrationModel.of_kind(kind.replace("-", ""), 2.0)
    elif kind == "gnss-3m":
        changes["gnss"] = GnssModel(sigma_neu_m=(3.0, 3.0, 5.0))
    elif kind == "outage40":
        changes["gnss"] = GnssModel(outages=[(200.0, 40.0), (520.0, 40.0)],
                                    outliers=[(150.0, 25.0), (400.0, 40.0), (700.0, 20.0)])
    elif kind not in KINDS:
        raise ValueError(f"unknown kind {kind!r}; one of {', '.join(KINDS)}")
    vehicle = "multicopter" if kind == "multicopter" else "helicopter"
    return SimConfig.for_vehicle(vehicle, duration_s=duration_s, seed=seed, **changes)


def _run(command: list[str], cwd: Path | None = None) -> None:
    done = subprocess.run(command, cwd=cwd, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(command)} failed ({done.returncode}):\n{done.stdout[-2000:]}{done.stderr[-2000:]}")


def _build(tree: Path) -> Path:
    """KF-GINS built in ``tree`` (its own CMake project: Release, into ``tree/bin``)."""
    binary = tree / "bin" / "KF-GINS"
    if binary.exists():
        return binary
    if not shutil.which("cmake") or not (shutil.which("g++") or shutil.which("c++")):
        raise SystemExit("building KF-GINS needs cmake and a C++ compiler (Debian: apt-get install cmake g++)")
    build = tree / "build"
    build.mkdir(exist_ok=True)
    print(f"building KF-GINS in {build} (a few minutes)", flush=True)
    _run(["cmake", "..", "-DCMAKE_BUILD_TYPE=Release"], cwd=build)
    _run(["make", f"-j{os.cpu_count() or 1}", "KF-GINS"], cwd=build)
    return binary


def locate_kfgins(where: str | None, scratch: Path) -> Path | None:
    """The KF-GINS binary from a binary, a source tree or a git repository (None: not given)."""
    if not where:
        return None
    path = Path(where).expanduser()
    if path.is_file() and os.access(path, os.X_OK):
        return path
    if (path / "CMakeLists.txt").exists() and (path / "src" / "kf_gins.cpp").exists():
        return _build(path)
    git_dir = path / ".git" if (path / ".git").exists() else path
    if (git_dir / "HEAD").exists() and (git_dir / "objects").exists():
        commit = subprocess.run(["git", "--git-dir", str(git_dir), "rev-parse", "HEAD"], capture_output=True,
                                text=True, check=True).stdout.strip()
        tree = scratch / f"kfgins-{commit[:12]}"
        if not (tree / "bin" / "KF-GINS").exists():
            tree.mkdir(parents=True, exist_ok=True)
            archive = subprocess.run(["git", "--git-dir", str(git_dir), "archive", "--format=tar", "HEAD",
                                      "CMakeLists.txt", "src", "ThirdParty"], capture_output=True, check=True)
            subprocess.run(["tar", "x", "-C", str(tree)], input=archive.stdout, check=True)
        print(f"KF-GINS {commit[:12]} from {git_dir}")
        return _build(tree)
    raise SystemExit(f"--kfgins {where}: not a KF-GINS binary, source tree or git repository")


def write_kfgins_inputs(flight: SimulatedFlight, folder: Path) -> Path:
    """KF-GINS's inputs for ``flight`` in ``folder``; returns its configuration file."""
    nav = flight.truth_nav
    pos = flight.pos
    t = nav.time
    gyro = np.radians(pos[["OMGS_X", "OMGS_Y", "OMGS_Z"]].to_numpy())
    accel = pos[["ACCS_X", "ACCS_Y", "ACCS_Z"]].to_numpy()
    dt = np.diff(t)[:, None]
    # increments over (t[k-1], t[k]]: the trapezoid of the point samples, as georef.fusion.strapdown.increments
    dtheta = 0.5 * (gyro[1:] + gyro[:-1]) * dt
    dvel = 0.5 * (accel[1:] + accel[:-1]) * dt
    np.savetxt(folder / "imu.txt", np.column_stack([t[1:], dtheta, dvel]), fmt="%.9f")
    fixes = flight.gnss_fixes
    sigma = np.asarray(flight.config.gnss.sigma_neu_m, dtype=float)
    gnss = np.column_stack([fixes["time"], fixes["lat"], fixes["lon"], fixes["height"],
                            np.tile(sigma, (len(fixes), 1))])
    np.savetxt(folder / "gnss.txt", gnss, fmt=["%.6f", "%.10f", "%.10f", "%.4f", "%.3f", "%.3f", "%.3f"])
    model = imu_preset(flight.config.imu_preset)
    # KF-GINS's units: ARW deg/sqrt(h), VRW m/s/sqrt(h), bias sigmas deg/h and mGal (1 mg = 1000 mGal), one
    # correlation time in hours
    gyro_bias = float(np.hypot(model.gyro_turn_on_bias_deg_h, model.gyro_bias_instability_deg_h))
    accel_bias = float(np.hypot(model.accel_turn_on_bias_mg, model.accel_bias_instability_mg)) * 1000.0
    start = 0  # the first IMU row; the first increment ends at t[1]
    lever = flight.config.lever_arm_gnss_m
    config = folder / "kf-gins.yaml"
    config.write_text(
        f'imupath: "{folder / "imu.txt"}"\n'
        f'gnsspath: "{folder / "gnss.txt"}"\n'
        f'outputpath: "{folder}"\n'
        "imudatalen: 7\n"
        f"imudatarate: {round(1.0 / float(np.median(np.diff(t))))}\n"
        f"starttime: {t[start + 1]:.9f}\n"
        "endtime: -1\n"
        f"initpos: [{np.degrees(nav.lat[start + 1]):.10f}, {np.degrees(nav.lon[start + 1]):.10f}, "
        f"{nav.height[start + 1]:.4f}]\n"
        f"initvel: [{nav.v_n[start + 1, 0]:.6f}, {nav.v_n[start + 1, 1]:.6f}, {nav.v_n[start + 1, 2]:.6f}]\n"
        f"initatt: [{np.degrees(nav.roll[start + 1]):.6f}, {np.degrees(nav.pitch[start + 1]):.6f}, "
        f"{np.degrees(nav.yaw[start + 1]) % 360.0:.6f}]\n"
        "initgyrbias: [0, 0, 0]\ninitaccbias: [0, 0, 0]\ninitgyrscale: [0, 0, 0]\ninitaccscale: [0, 0, 0]\n"
        "initposstd: [1.0, 1.0, 2.0]\ninitvelstd: [0.1, 0.1, 0.1]\ninitattstd: [0.5, 0.5, 1.0]\n"
        "imunoise:\n"
        f"  arw: [{model.gyro_arw_deg_rt_h}, {model.gyro_arw_deg_rt_h}, {model.gyro_arw_deg_rt_h}]\n"
        f"  vrw: [{model.accel_vrw_mps_rt_h}, {model.accel_vrw_mps_rt_h}, {model.accel_vrw_mps_rt_h}]\n"
        f"  gbstd: [{gyro_bias:.4f}, {gyro_bias:.4f}, {gyro_bias:.4f}]\n"
        f"  abstd: [{accel_bias:.2f}, {accel_bias:.2f}, {accel_bias:.2f}]\n"
        "  gsstd: [300.0, 300.0, 300.0]\n  asstd: [300.0, 300.0, 300.0]\n"
        f"  corrtime: {model.gyro_bias_corr_time_s / 3600.0:.6f}\n"
        f"antlever: [{lever[0]}, {lever[1]}, {lever[2]}]\n")
    return config


def kfgins_position_error(flight: SimulatedFlight, folder: Path) -> tuple[float, int]:
    """RMS horizontal position error [m] of KF-GINS's result against the truth, and its number of rows."""
    result = np.loadtxt(folder / "KF_GINS_Navresult.nav")
    nav = flight.truth_nav
    rows = np.searchsorted(nav.time, result[:, 1])
    ok = (rows < len(nav.time)) & np.isclose(nav.time[np.minimum(rows, len(nav.time) - 1)], result[:, 1], atol=1e-6)
    rows, result = rows[ok], result[ok]
    lat, lon = np.radians(result[:, 2]), np.radians(result[:, 3])
    diff = geodetic_to_ecef(lat, lon, result[:, 4]) - geodetic_to_ecef(nav.lat[rows], nav.lon[rows],
                                                                      nav.height[rows])
    ned = np.einsum("nij,nj->ni", C_e_n(nav.lat[rows], nav.lon[rows]), diff)
    return float(np.sqrt(np.mean(ned[:, 0] ** 2 + ned[:, 1] ** 2))), len(result)


def _timed(command: list[str], env: dict[str, str]) -> tuple[float, float]:
    """Wall time and CPU time (user + system) [s] of one run of ``command``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run(command, env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode not in (0, 4):
        raise SystemExit(f"{command[0]} exited {done.returncode}: {done.stdout[-600:]}{done.stderr[-600:]}")
    return seconds, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration", type=float, default=870.0, help="flight length [s]")
    parser.add_argument("--rate", type=float, default=50.0, help="POS row rate [Hz]")
    parser.add_argument("--seed", type=int, default=1, help="simulation seed")
    parser.add_argument("--kind", choices=list(KINDS), default="rotor",
                        help="the flight's character: " + "; ".join(f"{k}: {v}" for k, v in KINDS.items()))
    parser.add_argument("--runs", type=int, default=5, help="counted alternating pairs")
    parser.add_argument("--kfgins", default=os.environ.get("KFGINS"),
                        help="KF-GINS binary, source tree or git repository (default $KFGINS)")
    parser.add_argument("--method", default="rts", help="georef's --method (default rts: EKF + smoother)")
    parser.add_argument("--folder", type=Path, default=None, help="keep the flight and the outputs here")
    args = parser.parse_args()
    scratch = Path(tempfile.gettempdir()) / "georef-bench"
    binary = locate_kfgins(args.kfgins, scratch)
    georef = str(Path(sys.executable).with_name("georef"))
    pin = ["taskset", "-c", "0"] if shutil.which("taskset") else []
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    env.pop("PYTHONDONTWRITEBYTECODE", None)  # an installed georef has its bytecode cached, as after a first run
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.folder or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        # the flight of `georef simulate FOLDER --duration D --rate R --seed S` with the kind's change
        flight = simulate(sim_config(args.kind, args.duration, args.seed, args.rate))
        paths = write_flight(flight, folder)
        commands = {"georef": [*pin, georef, "process", str(paths["POS.txt"]), str(paths["Kamera.txt"]),
                               "--config", str(paths["flight.toml"]), "--method", args.method, "-q",
                               "-o", str(folder / "eo.csv")]}
        if binary is not None:
            kf_folder = folder / "kfgins"
            kf_folder.mkdir(exist_ok=True)
            commands["KF-GINS"] = [*pin, str(binary), str(write_kfgins_inputs(flight, kf_folder))]
        print(f"flight {args.kind} ({KINDS[args.kind]}), seed {args.seed}: {args.duration:g} s at {args.rate:g} Hz, "
              f"{len(flight.pos)} IMU rows, "
              f"{len(flight.gnss_fixes)} GNSS fixes, {len(flight.exposures)} exposures; georef --method "
              f"{args.method}; {'pinned to core 0' if pin else 'not pinned'}; "
              + ", ".join(f"{name}={os.environ.get(name, '(unset)')}"
                          for name in ("GEOREF_FIT_BUDGET", "GEOREF_KERNELS")))
        load_before = os.getloadavg()
        times: dict[str, list[float]] = {name: [] for name in commands}
        cpu: dict[str, list[float]] = {name: [] for name in commands}
        summary = folder / "summary.json"
        for run in range(args.runs + 1):  # the first round warms the caches and is not counted
            for name, command in commands.items():
                if not run and name == "georef":  # its summary, for the noise fit's pass count
                    command = [*command, "--summary-json", str(summary)]
                seconds, used = _timed(command, env)
                if run:
                    times[name].append(seconds)
                    cpu[name].append(used)
        load_after = os.getloadavg()
        figures = json.loads(summary.read_text())["summary"]
        print(f"georef: noise fit {figures.get('noise_fit_passes', 'n/a')} passes (noise_fit_passes), GNSS error "
              f"model {figures.get('gnss_error_model')}, QC exit {json.loads(summary.read_text()).get('exit_code')}")
        if binary is not None:
            rms, rows = kfgins_position_error(flight, folder / "kfgins")
            print(f"KF-GINS: {rows} rows written, horizontal position RMS against the truth {rms:.2f} m")
    print(f"load average (1, 5, 15 min) before {', '.join(f'{v:.2f}' for v in load_before)}, after "
          f"{', '.join(f'{v:.2f}' for v in load_after)} on {os.cpu_count()} cores")
    medians = {}
    for name, values in times.items():
        medians[name] = float(np.median(values))
        print(f"{name:>8}: median {medians[name]:.2f} s, best {min(values):.2f} s, runs "
              f"{', '.join(f'{v:.2f}' for v in values)}; CPU (user + system) median {np.median(cpu[name]):.2f} s")
    if binary is None:
        print("KF-GINS not given (--kfgins or $KFGINS): georef timed alone, no ratio")
        return
    print(f"georef / KF-GINS: median {medians['georef'] / medians['KF-GINS']:.2f}x, pairs "
          f"{', '.join(f'{g / k:.2f}' for g, k in zip(times['georef'], times['KF-GINS'], strict=True))}; CPU time "
          f"median {np.median(cpu['georef']) / np.median(cpu['KF-GINS']):.2f}x")


if __name__ == "__main__":
    main()
