"""``georef simulate``: a flight or drive with its truth, written as georef's inputs (the options' checks and the
simulator's configuration: :mod:`georef.sim.options`)."""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.markup import escape

from ..options import Quiet
from ..running import out, stage_progress

if TYPE_CHECKING:
    from georef.sim.flight import SimConfig


def simulate(
    folder: Annotated[Path, typer.Argument(help="Folder to write POS.txt, Kamera.txt, truth.csv, flight.toml "
                                                "(a drone: imu.csv, gnss.csv, events.csv, truth.csv, truth_traj.csv, "
                                                "flight.toml).")],
    vehicle: Annotated[str, typer.Option(
        help="helicopter (survey strips, POS unit with its own attitude), multicopter (hover, then legs flown "
             "sideways with the heading held; no POS unit), car (roads, turns, stops; no POS unit) or drone (a "
             "drone's whole log: on the ground, spin-up, take-off, hover, survey legs, maybe a landing; rotor "
             "vibration, thermal IMU bias, GNSS receiver with latency, camera trigger latency; every parameter "
             "drawn by --seed; writes the generic files).")
    ] = "helicopter",
    duration: Annotated[float | None, typer.Option(
        help="Flight length in seconds (default 180; the drone's is drawn by --seed).")] = None,
    rate: Annotated[float | None, typer.Option(help="POS row (drone: IMU) rate in Hz, 50-400 (default 50; drone "
                                                     "200).")] = None,
    camera_rate: Annotated[float | None, typer.Option(
        help="Exposures per second (default 3). Drone: triggers by time at this rate instead of by distance.")
    ] = None,
    seed: Annotated[int, typer.Option(help="Random seed: the same seed gives the same files.")] = 1,
    imu: Annotated[str | None, typer.Option(
        help="IMU error preset: mems-ivru, mems-consumer, consumer-phone, tactical-fog (default: mems-ivru for "
             "the helicopter, mems-consumer otherwise).")] = None,
    gyro_bias: Annotated[str | None, typer.Option(
        help="Force the gyro turn-on bias X,Y,Z in deg/s, body axes (x fwd, y right, z down), e.g. 0,0,4 "
             "(0.07 rad/s, a phone's z bias).")] = None,
    accel_bias: Annotated[str | None, typer.Option(
        help="Force the accelerometer turn-on bias X,Y,Z in m/s^2, body axes, e.g. 0.3,-0.2,0.5.")] = None,
    vibration: Annotated[str | None, typer.Option(
        help="Vibration: none, rotor (16 Hz blade-pass sinusoids + harmonic, 0.4 m/s^2, 0.2 deg/s), white "
             "(Gaussian 0.25/0.25/0.4 m/s^2, 0.1 deg/s at 200 Hz averaged to the row rate) or narrowband "
             "(random, 20 +- 2 Hz, 0.3/0.3/0.5 m/s^2, 0.15 deg/s RMS). Default: rotor for the helicopter, "
             "narrowband for the multicopter, white for the car. The drone's rotor harmonics follow its thrust: "
             "only none switches them off.")] = None,
    vibration_level: Annotated[float, typer.Option(
        help="Multiplies the vibration amplitudes (1 = the values above, 0 = none).")] = 1.0,
    gnss_rate: Annotated[float | None, typer.Option(
        help="GNSS fix rate in Hz (1, 5, 10...; default 1, drone 5). POS.txt tags fixes to whole seconds, so above "
             "1 Hz use --generic and georef fuse.")] = None,
    gnss_sigma: Annotated[str | None, typer.Option(
        help="GNSS fix noise N,E,U in metres (1-sigma white noise of each fix, north, east, up; default 1,1,2). "
             "Helicopter, multicopter, car (the drone's receiver errors are drawn by --seed). Also written to "
             "flight.toml's gnss_sigma, as the simulated installation's.")] = None,
    unit_yaw_drift: Annotated[float | None, typer.Option(
        help="Helicopter: drift of the POS unit's yaw origin in degrees per hour (default 30 = 0.5 deg/min); "
             "truth.csv's unit_yaw_offset ramps by it.")] = None,
    gnss_drop: Annotated[float | None, typer.Option(
        help="Drone: fraction of GNSS fixes missing, single or in runs of 2-5 (e.g. 0.03 with --gnss-rate 1).")
    ] = None,
    start: Annotated[str | None, typer.Option(
        help="Drone: ground (the log starts at power-on on the ground; default) or hover (already airborne).")
    ] = None,
    outage: Annotated[list[str] | None, typer.Option(
        help="GNSS outage START,LENGTH in seconds from the flight start; repeatable.")] = None,
    outlier: Annotated[list[str] | None, typer.Option(
        help="GNSS outlier TIME,SIZE (s from start, metres); repeatable.")] = None,
    hover: Annotated[float | None, typer.Option(
        help="Multicopter: seconds of hover at the start (default 15); drone: after the take-off.")] = None,
    heading_policy: Annotated[str | None, typer.Option(
        help="Multicopter, drone: fixed (heading held north, legs flown sideways; default), track (heading "
             "along each leg) or rotating (6 deg/s).")] = None,
    speed: Annotated[float | None, typer.Option(
        help="Multicopter / drone leg speed (2-12 m/s, default 8) or car cruising speed (up to 15 m/s, default "
             "12), m/s.")] = None,
    crs: Annotated[str | None, typer.Option(
        help="Projected CRS to put in the written flight.toml, e.g. EPSG:3765.")] = None,
    generic: Annotated[bool, typer.Option(
        help="Also write imu.csv, gnss.csv and truth_traj.csv (the generic inputs of georef fuse).")] = False,
    magnetometer: Annotated[bool, typer.Option(
        help="Add mag_x, mag_y, mag_z [uT, body axes] to imu.csv (48 uT field, inclination 60 deg, declination "
             "4 deg, hard iron, 0.3 uT noise; drone: plus the motor currents' field); implies --generic.")] = False,
    autopilot: Annotated[bool, typer.Option(
        help="Add the autopilot's roll, pitch, yaw [deg; yaw from true north with a ~3 deg error; drone: plus a "
             "mounting offset of up to 2 deg] to imu.csv; implies --generic.")] = False,
    quiet: Quiet = False,
) -> None:
    """Simulate a flight or drive with its truth: helicopter survey (default), multicopter, car or drone."""
    from georef.sim.options import SimOptions, sim_config

    cfg = sim_config(SimOptions(vehicle, duration, rate, camera_rate, seed, imu, gyro_bias, accel_bias, vibration,
                                vibration_level, gnss_rate, gnss_sigma, unit_yaw_drift, gnss_drop, start, outage or [],
                                outlier or [], hover, heading_policy, speed, magnetometer, autopilot))
    if vehicle == "drone":
        _write_drone(cfg, folder, crs, quiet)
    else:
        _write_flight(cfg, vehicle, folder, crs, generic or magnetometer or autopilot, quiet)


def _write_flight(cfg: SimConfig, vehicle: str, folder: Path, crs: str | None, generic: bool, quiet: bool) -> None:
    """Simulate the helicopter, multicopter or car and write its files (POS.txt, Kamera.txt, truth.csv,
    flight.toml; with ``generic`` also imu.csv, gnss.csv and truth_traj.csv)."""
    from georef.sim.files import write_flight, write_generic
    from georef.sim.flight import simulate as run

    progress, step = stage_progress(quiet, total=2)
    with progress if progress is not None else contextlib.nullcontext():
        step("simulating")
        flight = run(cfg)
        step("writing files")
        paths = write_flight(flight, folder, crs=crs)
        if generic:
            paths.update(write_generic(flight, folder))
    if not quiet:
        out.print(f"wrote {escape(', '.join(str(p) for p in paths.values()))}", highlight=False, soft_wrap=True)
        out.print(f"{vehicle}: {len(flight.pos)} POS rows at {cfg.pos_rate_hz:g} Hz, "
                  f"{len(flight.exposures)} exposures, {len(flight.gnss_fixes)} GNSS fixes at {cfg.gnss.rate_hz:g} Hz")


def _write_drone(cfg: SimConfig, folder: Path, crs: str | None, quiet: bool) -> None:
    """Simulate the drone flight and write its generic files and flight.toml."""
    from georef.sim.files import write_generic, write_processing_config
    from georef.sim.flight import simulate as run

    progress, step = stage_progress(quiet, total=2)
    with progress if progress is not None else contextlib.nullcontext():
        step("simulating")
        flight = run(cfg)
        step("writing files")
        paths = write_generic(flight, folder)
        paths["flight.toml"] = write_processing_config(flight, folder, crs)
    if not quiet:
        plan = cfg.plan
        out.print(f"wrote {escape(', '.join(str(p) for p in paths.values()))}", highlight=False, soft_wrap=True)
        out.print(f"drone ({plan.start} start{', landing' if plan.land else ''}): {plan.duration_s:.0f} s, "
                  f"{len(flight.pos)} IMU rows at {cfg.pos_rate_hz:g} Hz, {len(flight.exposures)} camera events, "
                  f"{len(flight.gnss_fixes)} GNSS fixes at {cfg.gnss.rate_hz:g} Hz")
