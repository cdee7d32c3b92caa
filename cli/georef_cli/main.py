"""``georef``: direct georeferencing from the command line.

Exit codes: 0 done and the quality checks passed; 2 an error in the user's input, printed as one actionable
line (file, line, column), never a traceback; 3 an internal error (a bug in georef); 4 the outputs are written
but the quality checks failed (``docs/qc.md``). Text from the user's files and options is escaped before rich
prints it (a path such as ``flight[red]/POS.txt`` prints as it is).
"""

from __future__ import annotations

import contextlib
import functools
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn
from rich.table import Table

from georef.config import METHODS, ProcessingConfig, load_config
from georef.io.errors import GeorefError

#: exit codes (docs/qc.md)
EXIT_USER_ERROR = 2
EXIT_INTERNAL_ERROR = 3
EXIT_QC_FAILED = 4

app = typer.Typer(
    add_completion=False, no_args_is_help=True, rich_markup_mode=None, pretty_exceptions_enable=False,
    help="georef: GPS/INS direct georeferencing of aerial imagery. Units: metres, degrees, seconds; "
         "body axes x forward, y right, z down.",
)
console = Console(stderr=True, soft_wrap=True)
out = Console()


def _triple(text: str | None, what: str, unit: str) -> tuple[float, float, float] | None:
    if text is None:
        return None
    try:
        values = tuple(float(v) for v in text.replace(" ", "").split(","))
    except ValueError:
        values = ()
    if len(values) != 3:
        raise typer.BadParameter(f"{what} needs three comma-separated numbers in {unit}, e.g. 0.5,0,-1.2; "
                                 f"got {text!r}")
    return values  # type: ignore[return-value]


def _user_errors(func: Callable[..., Any]) -> Callable[..., Any]:
    """Turn georef's user-facing errors into one red line and exit code 2."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except (GeorefError, ValueError, KeyError, OSError) as exc:  # CRSChoiceError is a ValueError
            console.print(f"[bold red]error:[/] {escape(str(exc))}", highlight=False)
            raise typer.Exit(code=EXIT_USER_ERROR) from None
        except typer.BadParameter as exc:
            console.print(f"[bold red]error:[/] {escape(exc.format_message())}", highlight=False)
            raise typer.Exit(code=EXIT_USER_ERROR) from None
        except (typer.Exit, typer.Abort, SystemExit, KeyboardInterrupt):
            raise
        except Exception as exc:  # a bug in georef, not in the user's input
            if os.environ.get("GEOREF_DEBUG"):
                raise
            console.print(f"[bold red]internal error:[/] {type(exc).__name__}: {escape(str(exc))}. This is a bug in "
                          "georef; please report it with the command you ran (GEOREF_DEBUG=1 shows the traceback).",
                          highlight=False)
            raise typer.Exit(code=EXIT_INTERNAL_ERROR) from None

    return wrapper


def _stage_progress(quiet: bool, total: int) -> tuple[Progress | None, Callable[[str], None]]:
    if quiet:
        return None, lambda _step: None
    progress = Progress(SpinnerColumn(), TextColumn("{task.description}"), BarColumn(), TimeElapsedColumn(),
                        console=console, transient=True)
    task = progress.add_task("starting", total=total)
    state = {"first": True}

    def step(description: str) -> None:
        if not state["first"]:
            progress.advance(task)
        state["first"] = False
        progress.update(task, description=description)

    return progress, step


GNSS_LATENCY_HELP = ("GNSS time-tag latency in seconds (the fix was measured this long before its time tag); "
                     "default: estimated and reported, not applied.")
VEHICLE_HELP = ("auto (non-holonomic constraints when the motion shows a ground vehicle; default), ground (always) "
                "or air (never).")


def _print_verdict(verdict: Any, quiet: bool) -> None:
    """The quality checks on stderr: one line per failing (and, unless ``quiet``, warning) check, then the
    verdict; a green "QC passed" when nothing is wrong."""
    for check in verdict.checks:
        if check.status == "fail":
            console.print(f"[bold red]QC fail[/] {escape(check.name)}: {escape(check.message)}", highlight=False)
        elif check.status == "warn" and not quiet:
            console.print(f"[yellow]QC warning[/] {escape(check.name)}: {escape(check.message)}", highlight=False)
    if not verdict.passed:
        console.print(f"[bold red]QC failed[/] ({len(verdict.failures)} check(s)): the outputs are written; exit "
                      f"code {EXIT_QC_FAILED} (docs/qc.md)", highlight=False)
    elif not quiet:
        extra = f" with {len(verdict.warnings)} warning(s)" if verdict.warnings else ""
        console.print(f"[bold green]QC passed[/]{extra}", highlight=False)


@app.command()
@_user_errors
def process(
    pos: Annotated[Path, typer.Argument(help="POS unit log (POS.txt, tab separated, iMAR layout).")],
    camera: Annotated[Path, typer.Argument(help="Exposure times: Kamera.txt, or the camera's raw log "
                                                "(needs --camera-utc-offset).")],
    output: Annotated[Path, typer.Option("-o", "--output", help="EO table to write.")] = Path("eo.csv"),
    output_format: Annotated[str, typer.Option("--format", help="csv (the EO table), metashape, pix4d, odm (geo.txt), "
                                               "parge, geojson or kml; metashape/pix4d/odm need --crs.")] = "csv",
    config: Annotated[Path | None, typer.Option("--config", help="flight.toml with any of these settings; "
                                                "command-line options win.")] = None,
    method: Annotated[str | None, typer.Option(help=f"Fusion method: {', '.join(METHODS)}.")] = None,
    gnss_lever_arm: Annotated[str | None, typer.Option(
        help="IMU -> GNSS antenna lever arm X,Y,Z in metres, body frame (x fwd, y right, z down).")] = None,
    camera_lever_arm: Annotated[str | None, typer.Option(
        help="IMU -> camera perspective centre lever arm X,Y,Z in metres, body frame.")] = None,
    boresight: Annotated[str | None, typer.Option(
        help="Camera boresight R,P,Y in degrees (C_c_b = Rz(Y) Ry(P) Rx(R)).")] = None,
    gnss_sigma: Annotated[str | None, typer.Option(
        help="GNSS fix standard deviation N,E,U in metres (default 1,1,2).")] = None,
    gnss_rate: Annotated[float | None, typer.Option(help="GNSS fix rate in Hz (default 1).")] = None,
    camera_utc_offset: Annotated[float | None, typer.Option(
        help="UTC offset of the camera's local clock in hours (raw camera log only), e.g. 2 for UTC+2.")] = None,
    camera_time_offset: Annotated[float | None, typer.Option(
        help="Camera trigger latency in seconds, added to every exposure time (the exposure happened this long "
             "after its logged time); default 0.")] = None,
    gnss_latency: Annotated[float | None, typer.Option(help=GNSS_LATENCY_HELP)] = None,
    vehicle: Annotated[str | None, typer.Option(help=VEHICLE_HELP)] = None,
    crs: Annotated[str | None, typer.Option(
        help="Projected CRS for easting/northing columns, e.g. EPSG:3765 (HTRS96/TM).")] = None,
    attitude_source: Annotated[str | None, typer.Option(
        help="Roll and pitch from the POS unit ('unit', default) or recomputed from the raw IMU ('imu').")] = None,
    report: Annotated[Path | None, typer.Option(
        help="Also write an HTML quality report here (PNG plots beside it).")] = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="Print nothing but errors and failed quality "
                                                               "checks.")] = False,
    verbose: Annotated[bool, typer.Option("--verbose", "-v", help="Also list every input notice.")] = False,
) -> None:
    """Turn POS.txt + exposure times into the exterior orientation of every frame.

    Exit code 4: the outputs are written but the quality checks failed (docs/qc.md).
    """
    from georef.io.exports import NEEDS_CRS, write_export
    from georef.pipeline import process as run
    from georef.qc import assess_result

    cfg = load_config(config) if config else ProcessingConfig()
    cfg = cfg.updated(
        method=method, lever_arm_gnss=_triple(gnss_lever_arm, "--gnss-lever-arm", "metres"),
        lever_arm_camera=_triple(camera_lever_arm, "--camera-lever-arm", "metres"),
        boresight=_triple(boresight, "--boresight", "degrees"),
        gnss_sigma=_triple(gnss_sigma, "--gnss-sigma", "metres"), gnss_rate_hz=gnss_rate,
        camera_utc_offset=camera_utc_offset, crs=crs, attitude_source=attitude_source,
        camera_time_offset=camera_time_offset, gnss_latency=gnss_latency, vehicle=vehicle,
    )
    if output_format in NEEDS_CRS and not cfg.crs:
        raise typer.BadParameter(f"--format {output_format} writes projected coordinates: give --crs EPSG:xxxx")
    progress, step = _stage_progress(quiet, total=5 if report is not None else 4)
    with progress if progress is not None else contextlib.nullcontext():
        result = run(pos, camera, cfg, progress=step)
        step("writing table")
        write_export(result.table, output, output_format, cfg.crs)
        verdict = assess_result(result)
        if report is not None:
            from georef.report import write_report

            step("writing report")
            write_report(result, report, verdict=verdict)
    if not quiet:
        _print_summary(result, output, verbose)
    _print_verdict(verdict, quiet)
    if not verdict.passed:
        raise typer.Exit(code=EXIT_QC_FAILED)


def _filter_rows(s: dict[str, Any]) -> list[tuple[str, str]]:
    """Summary rows of the full-state filters (``georef.pipeline.solution_figures``): heading source, the unit's
    yaw origin, the fitted noise, the ground-vehicle constraints. Empty for the other methods."""
    rows: list[tuple[str, str]] = []
    if s.get("heading_source") is None:
        return rows
    rows.append(("heading source", escape(str(s["heading_source"]))))
    if s.get("unit_yaw_origin_deg") is not None:
        drift = s.get("unit_yaw_drift_deg_per_min")
        rows.append(("unit yaw origin", f"{s['unit_yaw_origin_deg']:.3f} ± {s['unit_yaw_origin_sigma_deg']:.3f} deg "
                     "at the start (true yaw = unit yaw + origin)"
                     + (f", drift {drift:.3f} deg/min" if drift is not None else "")))
    sigma_n, sigma_e, sigma_u = s["gnss_sigma_fitted_m"]
    horizontal = f"{sigma_n:.2f}" if abs(sigma_n - sigma_e) < 0.005 else f"{sigma_n:.2f}/{sigma_e:.2f}"
    rows.append(("noise", f"GNSS σ h {horizontal} m, v {sigma_u:.2f} m (fitted); VRW {s['vrw_m_s_sqrt_h']:.3f} "
                 f"m/s/√h, ARW {s['arw_deg_sqrt_h']:.3f} deg/√h"))
    if s.get("ground_vehicle"):
        rows.append(("ground vehicle", "non-holonomic constraints"))
    return rows


def _print_summary(result: Any, output: Path, verbose: bool) -> None:
    s = result.summary()
    table = Table(title=f"georef process ({s['method']}) -> {escape(str(output))}", show_header=False,
                  title_justify="left")
    table.add_column("what", style="bold")
    table.add_column("value")
    t0, t1 = s["time_span_s"]
    table.add_row("frames written", f"{s['frames_written']} ({s['frames_flagged']} flagged)")
    if s["frames_outside_span"]:
        table.add_row("outside nav span", f"{s['frames_outside_span']} frames: rows kept, values empty")
    if s["frames_in_outage"]:
        table.add_row("in GNSS outage", f"{s['frames_in_outage']} frames")
    if s["frames_after_last_fix"] or s["frames_before_first_fix"]:
        table.add_row("beyond the GNSS fixes", f"{s['frames_before_first_fix']} frames before the first fix, "
                      f"{s['frames_after_last_fix']} after the last (inertial only)")
    table.add_row("time span", f"{t0:.2f} - {t1:.2f} s UTC of day ({t1 - t0:.1f} s), "
                  f"{s['imu_rows']} IMU rows at {s['imu_rate_hz']:.1f} Hz")
    gaps = s["gnss_gaps"]
    table.add_row("GNSS epochs", f"{s['gnss_epochs']} ({s['gnss_used']} used, "
                  f"{len(s['gnss_rejected_lines'])} rejected, {len(gaps)} gaps)")
    if s["gnss_rejected_lines"]:
        rejected = result.nav.gnss
        shown = [f"{t:.0f} s (line {line})" for t, line in
                 zip(rejected.time[rejected.status == 0], rejected.line[rejected.status == 0], strict=True)]
        table.add_row("rejected fixes", ", ".join(shown[:20]) + (" ..." if len(shown) > 20 else ""))
    for start, end in gaps[:10]:
        table.add_row("GNSS gap", f"{start:.0f} - {end:.0f} s ({end - start:.0f} s)")
    if s["yaw_offset_deg"] is not None:
        table.add_row("yaw offset", f"{s['yaw_offset_deg']:.3f} ± {s['yaw_offset_sigma_deg']:.3f} deg, drift "
                      f"{s['yaw_drift_deg_per_min']:.3f} ± {s['yaw_drift_sigma_deg_per_min']:.3f} deg/min")
    for what, value in _filter_rows(s):
        table.add_row(what, value)
    table.add_row("time quirks repaired", str(s["time_quirks_repaired"]))
    valid = result.table.dropna(subset=["sigma_n"])
    if len(valid):
        horizontal = np.hypot(valid["sigma_n"], valid["sigma_e"])
        table.add_row("median sigma", f"horizontal {np.median(horizontal):.2f} m, vertical "
                      f"{np.median(valid['sigma_u']):.2f} m, yaw {np.median(valid['sigma_yaw']):.2f} deg")
    out.print(table)
    notices = result.notices
    if notices:
        shown = notices if verbose else notices[:5]
        for notice in shown:
            console.print(f"[yellow]notice:[/] {escape(str(notice))}", highlight=False)
        if len(notices) > len(shown):
            console.print(f"[yellow]notice:[/] ... {len(notices) - len(shown)} more (use --verbose)")


@app.command()
@_user_errors
def simulate(
    folder: Annotated[Path, typer.Argument(help="Folder to write POS.txt, Kamera.txt, truth.csv, flight.toml.")],
    vehicle: Annotated[str, typer.Option(
        help="helicopter (survey strips, POS unit with its own attitude), multicopter (hover, then legs flown "
             "sideways with the heading held; no POS unit) or car (roads, turns, stops; no POS unit).")
    ] = "helicopter",
    duration: Annotated[float, typer.Option(help="Flight length in seconds.")] = 180.0,
    rate: Annotated[float, typer.Option(help="POS row rate in Hz (50-200).")] = 50.0,
    camera_rate: Annotated[float, typer.Option(help="Exposures per second.")] = 3.0,
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
             "narrowband for the multicopter, white for the car.")] = None,
    vibration_level: Annotated[float, typer.Option(
        help="Multiplies the vibration amplitudes (1 = the values above, 0 = none).")] = 1.0,
    gnss_rate: Annotated[float, typer.Option(
        help="GNSS fix rate in Hz (1, 5, 10...). POS.txt tags fixes to whole seconds, so above 1 Hz use "
             "--generic and georef fuse.")] = 1.0,
    outage: Annotated[list[str] | None, typer.Option(
        help="GNSS outage START,LENGTH in seconds from the flight start; repeatable.")] = None,
    outlier: Annotated[list[str] | None, typer.Option(
        help="GNSS outlier TIME,SIZE (s from start, metres); repeatable.")] = None,
    hover: Annotated[float | None, typer.Option(
        help="Multicopter: seconds of hover at the start (default 15).")] = None,
    heading_policy: Annotated[str | None, typer.Option(
        help="Multicopter: fixed (heading held north, legs flown sideways; default), track (heading along "
             "each leg) or rotating (6 deg/s).")] = None,
    speed: Annotated[float | None, typer.Option(
        help="Multicopter leg speed (2-12 m/s, default 8) or car cruising speed (up to 15 m/s, default 12), "
             "m/s.")] = None,
    crs: Annotated[str | None, typer.Option(
        help="Projected CRS to put in the written flight.toml, e.g. EPSG:3765.")] = None,
    generic: Annotated[bool, typer.Option(
        help="Also write imu.csv, gnss.csv and truth_traj.csv (the generic inputs of georef fuse).")] = False,
    magnetometer: Annotated[bool, typer.Option(
        help="Add mag_x, mag_y, mag_z [uT, body axes] to imu.csv (48 uT field, inclination 60 deg, declination "
             "4 deg, hard iron, 0.3 uT noise); implies --generic.")] = False,
    autopilot: Annotated[bool, typer.Option(
        help="Add the autopilot's roll, pitch, yaw [deg; yaw from true north with a ~3 deg error] to imu.csv; "
             "implies --generic.")] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="Print nothing but errors.")] = False,
) -> None:
    """Simulate a flight or drive with its truth: helicopter survey (default), multicopter or car."""
    import dataclasses

    from georef.sim.files import write_flight, write_generic
    from georef.sim.flight import VEHICLES, SimConfig
    from georef.sim.flight import simulate as run
    from georef.sim.sensors import AutopilotModel, GnssModel, MagnetometerModel, VibrationModel

    def pairs(values: list[str] | None, what: str) -> list[tuple[float, float]]:
        result = []
        for text in values or []:
            parts = text.split(",")
            if len(parts) != 2:
                raise typer.BadParameter(f"{what} takes two numbers A,B; got {text!r}")
            result.append((float(parts[0]), float(parts[1])))
        return result

    if vehicle not in VEHICLES:
        raise typer.BadParameter(f"--vehicle must be one of {', '.join(VEHICLES)}, got {vehicle!r}")
    plan_options = {"hover": hover, "heading-policy": heading_policy}
    for name, value in plan_options.items():
        if value is not None and vehicle != "multicopter":
            raise typer.BadParameter(f"--{name} applies to --vehicle multicopter only")
    if speed is not None and vehicle == "helicopter":
        raise typer.BadParameter("--speed applies to --vehicle multicopter or car")
    changes: dict[str, Any] = {
        "pos_rate_hz": rate, "camera_rate_hz": camera_rate,
        "gnss": GnssModel(rate_hz=gnss_rate, outages=pairs(outage, "--outage"), outliers=pairs(outlier, "--outlier")),
    }
    if imu is not None:
        changes["imu_preset"] = imu
    if vibration is not None or vibration_level != 1.0:
        kind = vibration or {"helicopter": "rotor", "multicopter": "narrowband", "car": "white"}[vehicle]
        changes["vibration"] = VibrationModel.of_kind(kind, level=vibration_level)
    if gyro_bias is not None:
        changes["gyro_bias_rad_s"] = tuple(np.radians(_triple(gyro_bias, "--gyro-bias", "deg/s")))
    if accel_bias is not None:
        changes["accel_bias_mps2"] = _triple(accel_bias, "--accel-bias", "m/s^2")
    if magnetometer:
        changes["magnetometer"] = MagnetometerModel()
    if autopilot:
        changes["autopilot"] = AutopilotModel()
    cfg = SimConfig.for_vehicle(vehicle, duration_s=duration, seed=seed, **changes)
    plan_changes = {"hover_s": hover, "heading_policy": heading_policy,
                    "speed_mps" if vehicle == "multicopter" else "cruise_speed_mps": speed}
    plan_changes = {k: v for k, v in plan_changes.items() if v is not None}
    if plan_changes:
        cfg.plan = dataclasses.replace(cfg.plan, **plan_changes)
    generic = generic or magnetometer or autopilot
    progress, step = _stage_progress(quiet, total=2)
    with progress if progress is not None else contextlib.nullcontext():
        step("simulating")
        flight = run(cfg)
        step("writing files")
        paths = write_flight(flight, folder, crs=crs)
        if generic:
            paths.update(write_generic(flight, folder))
    if not quiet:
        out.print(f"wrote {escape(', '.join(str(p) for p in paths.values()))}", highlight=False)
        out.print(f"{vehicle}: {len(flight.pos)} POS rows at {rate:g} Hz, {len(flight.exposures)} exposures, "
                  f"{len(flight.gnss_fixes)} GNSS fixes at {gnss_rate:g} Hz")


@app.command()
@_user_errors
def fuse(
    imu: Annotated[Path, typer.Option(help="imu.csv: time [s], gyro_x..z [rad/s], acc_x..z [m/s^2], body FRD.")],
    gnss: Annotated[Path, typer.Option(help="gnss.csv: time [s], lat, lon [deg], height [m] of the antenna, "
                                            "optional sigma_n, sigma_e, sigma_u [m].")],
    output: Annotated[Path, typer.Option("-o", "--output", help="Trajectory to write (traj.csv).")] = Path("traj.csv"),
    config: Annotated[Path | None, typer.Option("--config", help="flight.toml with any of these settings.")] = None,
    method: Annotated[str, typer.Option(help="rts (EKF + smoother) or ekf (forward filter only).")] = "rts",
    gnss_lever_arm: Annotated[str | None, typer.Option(
        help="IMU -> GNSS antenna lever arm X,Y,Z in metres, body frame (x fwd, y right, z down).")] = None,
    gnss_sigma: Annotated[str | None, typer.Option(
        help="GNSS sigma N,E,U in metres for fixes without their own sigmas (default 1,1,2).")] = None,
    imu_preset: Annotated[str | None, typer.Option(
        help="IMU error preset: mems-ivru, mems-consumer, tactical-fog (datasheet values in docs).")] = None,
    gnss_latency: Annotated[float | None, typer.Option(help=GNSS_LATENCY_HELP)] = None,
    vehicle: Annotated[str | None, typer.Option(help=VEHICLE_HELP)] = None,
    magnetic_declination: Annotated[float | None, typer.Option(
        help="Magnetic declination [deg, east of true north] for a heading from imu.csv's mag_x..z, used only when "
             "the motion never shows the heading (default 0).")] = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="Print nothing but errors and failed quality "
                                                               "checks.")] = False,
) -> None:
    """Fuse generic IMU and GNSS files into a trajectory (position, velocity, attitude with sigmas).

    Exit code 4: the trajectory is written but the quality checks failed (docs/qc.md).
    """
    from georef.fusion.ins import InsInputs, solve_ins
    from georef.io.generic import read_gnss_csv, read_imu_csv, read_imu_heading_sources, write_trajectory_csv
    from georef.pipeline import solution_figures
    from georef.qc import assess

    if method not in ("rts", "ekf"):
        raise typer.BadParameter(f"--method must be rts or ekf for georef fuse, got {method!r}")
    cfg = load_config(config) if config else ProcessingConfig()
    cfg = cfg.updated(lever_arm_gnss=_triple(gnss_lever_arm, "--gnss-lever-arm", "metres"),
                      gnss_sigma=_triple(gnss_sigma, "--gnss-sigma", "metres"), imu_preset=imu_preset,
                      gnss_latency=gnss_latency, vehicle=vehicle, magnetic_declination=magnetic_declination)
    progress, step = _stage_progress(quiet, total=3)
    with progress if progress is not None else contextlib.nullcontext():
        step("reading inputs")
        time_s, gyro, accel, _ = read_imu_csv(imu)
        mag, autopilot_yaw = read_imu_heading_sources(imu)
        fixes = read_gnss_csv(gnss)
        step(f"fusing ({method})")
        nav = solve_ins(InsInputs(time=time_s, gyro=gyro, accel=accel, gnss=fixes, source=str(imu), mag=mag,
                                  autopilot_yaw=autopilot_yaw), cfg, smooth=method == "rts")
        step("writing trajectory")
        write_trajectory_csv(nav, output)
    verdict = assess(nav, cfg=cfg)
    if not quiet:
        used = int((nav.gnss.status >= 1).sum())
        rejected = nav.gnss.rejected_lines
        named = f" (lines {', '.join(map(str, rejected[:10]))})" if rejected else ""
        out.print(f"{int(nav.valid.sum())} trajectory rows -> {escape(str(output))}; GNSS {len(fixes)} fixes, "
                  f"{used} used, {len(rejected)} rejected{named}", highlight=False, soft_wrap=True)
        for what, value in _filter_rows(solution_figures(nav, cfg)):
            out.print(f"{what}: {value}", highlight=False, soft_wrap=True)
    _print_verdict(verdict, quiet)
    if not verdict.passed:
        raise typer.Exit(code=EXIT_QC_FAILED)


@app.command()
@_user_errors
def attitude(
    imu: Annotated[Path, typer.Option(help="imu.csv: time [s], gyro_x..z [rad/s], acc_x..z [m/s^2], optional "
                                           "mag_x..z (any unit); body axes forward-right-down.")],
    method: Annotated[str, typer.Option(help="complementary, kf (angle + gyro-bias Kalman), mekf or ukf.")] = "mekf",
    output: Annotated[Path, typer.Option("-o", "--output", help="Attitude table to write (CSV, degrees).")] = Path(
        "attitude.csv"),
    inclination: Annotated[float, typer.Option(help="Magnetic inclination in degrees (field reference "
                                                    "[cos I, 0, sin I] in NED).")] = 60.0,
    gain: Annotated[float, typer.Option(help="Complementary filter: accelerometer weight per sample (0-1).")] = 0.02,
    gyro_noise: Annotated[float, typer.Option(help="Gyro white noise per sample in rad/s (mekf, ukf).")] = 0.01,
    accel_sigma: Annotated[float, typer.Option(help="Noise of the normalised gravity direction (unitless, "
                                                    "~ radians); also the kf's angle sigma.")] = 0.01,
    alpha: Annotated[float, typer.Option(help="UKF sigma-point spread alpha.")] = 0.01,
    beta: Annotated[float, typer.Option(help="UKF prior-knowledge beta (2 for Gaussian).")] = 2.0,
    kappa: Annotated[float, typer.Option(help="UKF secondary scaling kappa.")] = 0.0,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="Print nothing but errors.")] = False,
) -> None:
    """Roll, pitch (and yaw with mekf/ukf) from raw gyro, accelerometer and optional magnetometer data."""
    from georef.attitude.run import estimate_attitude
    from georef.io.atomic import atomic_write
    from georef.io.generic import read_marg_csv

    time_s, gyro, accel, mag, _ = read_marg_csv(imu)
    table = estimate_attitude(method, time_s, gyro, accel, mag, inclination_deg=inclination, gain=gain,
                              gyro_noise=gyro_noise, accel_sigma=accel_sigma, alpha=alpha, beta=beta, kappa=kappa)
    with atomic_write(output) as handle:
        table.to_csv(handle, index=False, float_format="%.8g", lineterminator="\n")
    if not quiet:
        out.print(f"{len(table)} samples -> {escape(str(output))} ({escape(method)}"
                  f"{', magnetometer' if mag is not None else ''})", highlight=False)


@app.command()
@_user_errors
def batch(
    source: Annotated[Path, typer.Argument(help="A folder of flight folders (POS.txt, Kamera.txt, flight.toml each) "
                                                "or a manifest CSV with columns flight, pos, camera[, config].")],
    output: Annotated[Path, typer.Option("-o", "--output", help="Output folder: <flight>/eo.csv, <flight>/georef.log, "
                                                                 "batch_summary.csv.")] = Path("batch_out"),
    method: Annotated[str | None, typer.Option(help="Override every flight's method (rts, ekf, axis).")] = None,
    scheduler: Annotated[str | None, typer.Option(help="Dask scheduler address, e.g. tcp://host:8786; default: a "
                                                       "LocalCluster on this machine.")] = None,
    workers: Annotated[int, typer.Option(help="LocalCluster worker processes (one thread each).")] = 2,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="Print nothing but errors and failed quality "
                                                               "checks.")] = False,
) -> None:
    """Process many flights, one Dask task each; a failed flight is reported and the others go on.

    Exit code 2 when every flight failed to run, 4 when a flight's quality checks failed (docs/qc.md).
    """
    from georef.batch import discover, run_batch

    jobs = discover(source)
    if quiet:
        summary = run_batch(jobs, output, method=method, scheduler=scheduler, workers=workers)
    else:
        progress = Progress(SpinnerColumn(), TextColumn("{task.description}"), BarColumn(),
                            TextColumn("{task.completed}/{task.total} flights"), TimeElapsedColumn(),
                            console=console, transient=True)
        with progress:
            task = progress.add_task("processing flights", total=len(jobs))

            def done(row: dict) -> None:
                progress.advance(task)
                progress.update(task, description=f"{escape(str(row['flight']))}: {row['status']}")

            summary = run_batch(jobs, output, method=method, scheduler=scheduler, workers=workers, on_done=done)
    if not quiet:
        shown = ("flight", "status", "method", "frames", "rejected_fixes", "qc", "runtime_s", "message")
        table = Table(title=f"georef batch -> {escape(str(output))}/batch_summary.csv", title_justify="left")
        for column in shown:
            table.add_column(column)
        for row in summary.itertuples(index=False):
            table.add_row(*(escape(_cell(getattr(row, c))) for c in shown))
        out.print(table)
    failed = summary[summary["status"] != "ok"]
    for row in failed.itertuples(index=False):
        console.print(f"[bold red]failed:[/] {escape(str(row.flight))}: {escape(str(row.message))}", highlight=False)
    qc_failed = summary[summary["qc"].fillna("").astype(str).str.startswith("failed")]
    for row in qc_failed.itertuples(index=False):
        console.print(f"[bold red]QC failed:[/] {escape(str(row.flight))}: {escape(str(row.qc_details))}",
                      highlight=False)
    if len(failed) == len(summary):
        raise typer.Exit(code=EXIT_USER_ERROR)
    if len(qc_failed):
        raise typer.Exit(code=EXIT_QC_FAILED)


def _cell(value: Any) -> str:
    """A summary value as table text: empty for None/NaN/NA."""
    if value is None:
        return ""
    try:
        import pandas as pd

        if pd.isna(value):
            return ""
    except (TypeError, ValueError):
        pass
    return str(value)


@app.command()
@_user_errors
def info(
    pos: Annotated[Path, typer.Argument(help="POS unit log (POS.txt).")],
    config: Annotated[Path | None, typer.Option("--config", help="flight.toml: its [pos_columns] remapping and "
                                                                 "[gnss] gnss_rate_hz are used.")] = None,
    gnss_rate: Annotated[float | None, typer.Option(help="GNSS fix rate in Hz, if known (default: the config's, "
                                                         "else 1).")] = None,
) -> None:
    """Describe a POS log: format, span, rates, GNSS epochs and gaps, quirks repaired, columns found."""
    from georef.io.pos import read_pos

    cfg = load_config(config) if config else ProcessingConfig()
    rate = gnss_rate if gnss_rate is not None else cfg.gnss_rate_hz
    log = read_pos(pos, column_names=cfg.pos_columns, gnss_rate_hz=rate)
    table = Table(title=escape(str(pos)), show_header=False, title_justify="left")
    table.add_column("what", style="bold")
    table.add_column("value")
    if log.dialect is not None:
        table.add_row("format", escape(log.dialect.describe()))
    table.add_row("rows", f"{len(log)} at {log.sample_rate_hz:.2f} Hz")
    table.add_row("time span", f"{log.time[0]:.3f} - {log.time[-1]:.3f} s UTC of day "
                  f"({log.time[-1] - log.time[0]:.1f} s)")
    table.add_row("GNSS epochs", f"{len(log.gnss)}, {len(log.gnss.gaps())} gaps")
    for start, end in log.gnss.gaps()[:10]:
        table.add_row("GNSS gap", f"{start:.0f} - {end:.0f} s")
    table.add_row("time quirks repaired", str(log.time_repairs.n_quirks))
    table.add_row("columns found", escape(", ".join(f"{role}={name}" for role, name in log.column_names.items())))
    out.print(table)
    for notice in log.notices:
        console.print(f"[yellow]notice:[/] {escape(str(notice))}", highlight=False)


@app.command("build-kernels")
@_user_errors
def build_kernels(
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="Print nothing but errors.")] = False,
) -> None:
    """Compile the filters' inner loops ahead of time (about 10 s each, once per install).

    The modules are written inside the installed georef package (which must be writable). Without this step
    georef runs the same loops through numba's JIT, which costs every run about 0.5 s of start-up. A build
    whose sources have changed since is ignored, never run.
    """
    from georef.kernels import KERNELS, build

    for name in KERNELS:
        if quiet:
            build(name)
            continue
        with console.status(f"compiling the {name} kernel"):
            path = build(name)
        console.print(f"built {escape(str(path))}", highlight=False)


@app.command()
@_user_errors
def evaluate(
    eo: Annotated[Path, typer.Argument(help="EO table written by georef process.")],
    truth: Annotated[Path, typer.Argument(help="Reference EO table (e.g. truth.csv of georef simulate).")],
) -> None:
    """Accuracy of an EO table against a reference: RMS and the share of errors inside 2 sigma."""
    import pandas as pd

    from georef.evaluate import accuracy, frame_errors, sigma_coverage
    from georef.io.eo_table import read_eo_csv

    estimate = read_eo_csv(eo)
    reference = pd.read_csv(truth)
    errors = frame_errors(estimate, reference)
    table = Table(title=escape(f"{eo} against {truth}"), title_justify="left")
    table.add_column("figure")
    table.add_column("value", justify="right")
    for name, value in accuracy(errors).items():
        table.add_row(name, f"{value:.3f}")
    for name, value in sigma_coverage(estimate, errors).items():
        table.add_row(f"inside 2 sigma: {name}", f"{100 * value:.1f} %")
    out.print(table)


def main() -> None:  # pragma: no cover - console entry point
    app()


if __name__ == "__main__":  # pragma: no cover
    sys.exit(app())
