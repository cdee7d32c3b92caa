"""``georef``: direct georeferencing from the command line.

Exit codes: 0 done and the quality checks passed; 2 an error in the user's input, printed as one actionable
line (file, line, column), never a traceback; 3 an internal error (a bug in georef); 4 the outputs are written
but the quality checks failed (``docs/qc.md``). Text from the user's files and options is escaped before rich
prints it (a path such as ``flight[red]/POS.txt`` prints as it is).

Conventions: ``georef --version``; ``-o -`` writes the table to standard output and every message to standard
error; ``--summary-json FILE`` writes a machine-readable summary (``docs/qc.md``); options shared by several
commands are defined once, in :mod:`georef_cli.options`.
"""

from __future__ import annotations

import contextlib
import functools
import json
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import numpy as np
import typer
from rich.console import Console
from rich.markup import escape

from georef.config import (
    ConfigValueError,
    GraphSettings,
    InsSettings,
    ProcessingConfig,
    configured_keys,
    load_configs,
)
from georef.io.errors import GeorefError

from .coercion import PlainCoercionCommand, PlainCoercionGroup
from .handoffs import (
    bag_or_files,
    check_image_request,
    check_sbet_request,
    check_time_scale,
    export_images,
    fuse_sbet_specs,
    process_sbet_clock,
    sbet_clock,
    with_image_checks,
    write_fuse_outputs,
)
from .options import (
    AttitudeMethod,
    BagFile,
    BatchMethod,
    CameraClockOffset,
    ConfigFile,
    EventsFile,
    FuseMethod,
    GnssFile,
    GnssLatency,
    GnssLeverArm,
    GnssSigma,
    GnssTopic,
    ImagesFolder,
    ImuFile,
    ImuInstance,
    ImuPreset,
    ImuTopic,
    MagneticDeclination,
    ProcessMethod,
    Quiet,
    SbetRate,
    SummaryJson,
    TimeScale,
    UtcDate,
    Vehicle,
    Verbose,
    georef_version,
    output_option,
    plain,
)
from .output import is_stdout, write_json, write_target
from .terminal import filter_rows, print_summary, target_text

if TYPE_CHECKING:
    from rich.progress import Progress

    from georef.sim.flight import SimConfig

#: exit codes (docs/qc.md)
EXIT_USER_ERROR = 2
EXIT_INTERNAL_ERROR = 3
EXIT_QC_FAILED = 4

app = typer.Typer(
    cls=PlainCoercionGroup, add_completion=False, no_args_is_help=True, rich_markup_mode=None,
    pretty_exceptions_enable=False,
    help="georef: GPS/INS direct georeferencing of aerial imagery. Units: metres, degrees, seconds; "
         "body axes x forward, y right, z down.",
)
# emoji off: user text (a path, an option such as images:x:...) is printed as it is, never as :x: -> an emoji
console = Console(stderr=True, soft_wrap=True, emoji=False)
out = Console(emoji=False)


def _version_callback(show: bool) -> None:
    if show:
        out.print(f"georef {escape(georef_version())}", highlight=False)
        raise typer.Exit()


@app.callback()
def _main(
    version: Annotated[bool, typer.Option("--version", callback=_version_callback, is_eager=True,
                                          help="Print georef's version and exit.")] = False,
) -> None:
    """The options before the command (``georef --version``); the help text is the app's."""


def _messages(*stdout_outputs: Path | None) -> Console:
    """The console for the run's summary: standard output, unless one of ``stdout_outputs`` is ``-`` (then standard
    output carries that data and nothing else, and the summary goes to standard error)."""
    return console if any(is_stdout(p) for p in stdout_outputs) else out


def _one_stdout(**paths: Path | None) -> None:
    """Refuse two outputs on standard output before anything runs."""
    named = [name for name, path in paths.items() if is_stdout(path)]
    if len(named) > 1:
        raise typer.BadParameter(f"only one output can go to standard output ('-'), got {' and '.join(named)}")


def _not_stdout(path: Path | None, option: str, why: str) -> None:
    if is_stdout(path):
        raise typer.BadParameter(f"{option} cannot be '-' (standard output): {why}")


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


def _with_options(cfg: ProcessingConfig, **options: tuple[str, Any]) -> ProcessingConfig:
    """``cfg`` with the command-line options given (``flight.toml key=(option, value)``; ``None`` values are not
    given) applied over it; a value its section refuses is reported against the option that gave it."""
    try:
        return cfg.updated(**{key: value for key, (_, value) in options.items()})
    except ConfigValueError as exc:
        key = exc.key.rsplit(".", 1)[-1]
        option, value = options.get(key, (None, None))
        if option is None or value is None:
            raise
        raise typer.BadParameter(f"{option}: {str(exc).removeprefix(exc.key + ' ')}") from None


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
    from rich.progress import BarColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    progress = Progress(SpinnerColumn(), TextColumn("{task.description}"), BarColumn(), TimeElapsedColumn(),
                        console=console, transient=True)
    task = progress.add_task("starting", total=total)
    state = {"first": True}

    def step(description: str) -> None:
        if not state["first"]:
            progress.advance(task)
        state["first"] = False
        progress.update(task, description=escape(description))

    return progress, step


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


@app.command(cls=PlainCoercionCommand)
@_user_errors
def process(
    pos: Annotated[Path | None, typer.Argument(
        help="The flight's log: an autopilot log (ArduPilot .bin or .log, PX4 .ulg; the format is read from the "
             "content, gzip too) with its camera events, or a POS unit's POS.txt (with CAMERA). Leave it out with "
             "--imu/--gnss/--events or --bag/--events.", show_default=False)] = None,
    camera: Annotated[Path | None, typer.Argument(
        help="POS.txt's exposure times: Kamera.txt, or the camera's raw log (needs --camera-utc-offset).",
        show_default=False)] = None,
    imu: ImuFile = None,
    gnss: GnssFile = None,
    events: EventsFile = None,
    imu_instance: ImuInstance = None,
    bag: BagFile = None,
    imu_topic: ImuTopic = None,
    gnss_topic: GnssTopic = None,
    time_scale: TimeScale = "auto",
    imu_preset: ImuPreset = None,
    output: Annotated[Path | None, output_option("EO table to write (default eo.csv); a .kml, .geojson or geo.txt "
                                                 "name writes that format.")] = None,
    output_format: Annotated[str | None, typer.Option(
        "--format", help="Format of -o: csv (the EO table), metashape, pix4d, odm (geo.txt), parge, geojson or kml; "
                         "metashape/pix4d/odm need --crs. Default: from -o's extension, else csv.")] = None,
    export: Annotated[list[str] | None, typer.Option("--export", help="Also write FORMAT:FILE (metashape:ms.csv, "
                                                     "odm:geo.txt) or FILE with a .kml/.geojson/.csv extension; "
                                                     "repeatable. sbet:FILE writes the trajectory as an Applanix "
                                                     "SBET with its smrmsg_<name>.out (docs/sbet.md).")] = None,
    sbet_rate: SbetRate = None,
    utc_date: UtcDate = None,
    images: ImagesFolder = None,
    camera_clock_offset: CameraClockOffset = None,
    height: Annotated[str | None, typer.Option("--height", help="Heights of the exports: ellipsoidal (WGS 84, "
                                               "default) or orthometric (EGM96 from PROJ's grid, or the vertical "
                                               "CRS of a compound --crs such as EPSG:3765+5773).")] = None,
    image_names: Annotated[str | None, typer.Option("--image-names", help="Image file names: a pattern such as "
                                                    "IMG_{frame:04d}.JPG, or a CSV of frame,name.")] = None,
    config: ConfigFile = None,
    method: ProcessMethod = None,
    gnss_lever_arm: GnssLeverArm = None,
    camera_lever_arm: Annotated[str | None, typer.Option(
        help="IMU -> camera perspective centre lever arm X,Y,Z in metres, body frame.")] = None,
    boresight: Annotated[str | None, typer.Option(
        help="Camera boresight R,P,Y in degrees (C_c_b = Rz(Y) Ry(P) Rx(R)).")] = None,
    gnss_sigma: GnssSigma = None,
    gnss_rate: Annotated[float | None, typer.Option(help="GNSS fix rate in Hz (default 1).")] = None,
    camera_utc_offset: Annotated[float | None, typer.Option(
        help="UTC offset of the camera's local clock in hours (raw camera log only), e.g. 2 for UTC+2.")] = None,
    camera_time_offset: Annotated[float | None, typer.Option(
        help="Camera trigger latency in seconds, added to every exposure time (the exposure happened this long "
             "after its logged time); default 0.")] = None,
    camera_time_sigma: Annotated[float | None, typer.Option(
        help="Standard deviation in seconds of every exposure time, after --camera-time-offset; it widens each "
             "camera position's sigma by the speed times it. Default: each source's own (0.002 s for a camera's "
             "feedback, 0.1 s for a trigger command, an events.csv time_sigma column).")] = None,
    gnss_latency: GnssLatency = None,
    vehicle: Vehicle = None,
    magnetic_declination: MagneticDeclination = None,
    crs: Annotated[str | None, typer.Option(
        help="Projected CRS for easting/northing columns, e.g. EPSG:3765 (HTRS96/TM), or a compound CRS with its "
             "height system, e.g. EPSG:3765+5773 (with --height orthometric).")] = None,
    attitude_source: Annotated[str | None, typer.Option(
        help="Roll and pitch from the POS unit ('unit', default) or recomputed from the raw IMU ('imu').")] = None,
    report: Annotated[Path | None, typer.Option(
        help="Also write the quality report here: one self-contained HTML file (docs/report.md).")] = None,
    quiet: Quiet = False,
    verbose: Verbose = False,
    summary_json: SummaryJson = None,
) -> None:
    """The exterior orientation of every frame: from an autopilot log and its camera events, from POS.txt and
    Kamera.txt, from imu.csv, gnss.csv and events.csv, or from a ROS bag and events.csv.

    Exit code 4: the outputs are written but the quality checks failed (docs/qc.md).
    """
    from georef.io.exports import ExportError, ExportSpec, check_exports, format_of, parse_export, write_export
    from georef.io.image_names import ImageNames
    from georef.qc import assess_result

    from .summary import run_document

    _one_stdout(**{"-o": output, "--summary-json": summary_json})
    _not_stdout(report, "--report", "the report is written atomically as a file")
    source = _process_inputs(pos, camera, imu, gnss, events, imu_instance, bag, imu_topic, gnss_topic,
                             plain(time_scale))
    cfg = load_configs(config)
    cfg = _with_options(
        cfg, method=("--method", plain(method)), imu_preset=("--imu-preset", imu_preset),
        lever_arm_gnss=("--gnss-lever-arm", _triple(gnss_lever_arm, "--gnss-lever-arm", "metres")),
        lever_arm_camera=("--camera-lever-arm", _triple(camera_lever_arm, "--camera-lever-arm", "metres")),
        boresight=("--boresight", _triple(boresight, "--boresight", "degrees")),
        gnss_sigma=("--gnss-sigma", _triple(gnss_sigma, "--gnss-sigma", "metres")),
        gnss_rate_hz=("--gnss-rate", gnss_rate), camera_utc_offset=("--camera-utc-offset", camera_utc_offset),
        crs=("--crs", crs), attitude_source=("--attitude-source", attitude_source),
        camera_time_offset=("--camera-time-offset", camera_time_offset),
        camera_time_sigma=("--camera-time-sigma", camera_time_sigma),
        gnss_latency=("--gnss-latency", gnss_latency), vehicle=("--vehicle", plain(vehicle)),
        magnetic_declination=("--magnetic-declination", magnetic_declination),
        height=("--height", height), image_names=("--image-names", image_names),
    )
    # every output, its format, the CRS, the geoid grid and the image names are checked before processing
    if output is None:
        if output_format not in (None, "csv"):
            raise typer.BadParameter(f"--format {output_format} needs -o FILE (eo.csv is the EO table's default); "
                                     f"or add --export {output_format}:FILE to write it beside eo.csv")
        output = Path("eo.csv")
    if output_format is None:
        try:
            output_format = format_of(output)
        except ExportError:
            output_format = "csv"
    # --export images:DIR is a folder of photo copies, not a file of the EO table (georef/io/image_export.py)
    if "images" in (export or []):
        raise typer.BadParameter("--export images:DIR: name the folder for the geotagged copies of --images")
    image_targets = [Path(text.partition(":")[2]) for text in export or [] if text.startswith("images:")]
    export = [text for text in export or [] if not text.startswith("images:")]
    specs = [ExportSpec(format_of(output, output_format), output), *(parse_export(text) for text in export or [])]
    _one_stdout(**{"-o": output, "--summary-json": summary_json,
                   **{f"--export {text}": spec.path for text, spec in zip(export or [], specs[1:], strict=True)}})
    frames = None
    if cfg.output.crs or cfg.output.height != "ellipsoidal":
        from georef.frames.heights import OutputFrames  # pyproj only when a CRS or a geoid is asked for

        frames = OutputFrames(cfg.output.crs, cfg.output.height, cfg.output.vertical_crs)
    check_exports(specs, frames)
    check_image_request(images, image_targets, camera_clock_offset, frames, cfg.output.image_names)
    sbet_specs = [spec for spec in specs if spec.fmt == "sbet"]
    if specs[0].fmt == "sbet":
        raise typer.BadParameter("an SBET is the trajectory, not the EO table: write it with --export sbet:FILE")
    # an autopilot log dates itself; a bag or imu.csv may (Unix stamps, a .pos): checked once read
    check_sbet_request(sbet_specs, utc_date, sbet_rate, dated=bool({"log", "bag", "imu"} & source.files.keys()))
    if cfg.output.image_names:
        ImageNames.parse(cfg.output.image_names)
    progress, step = _stage_progress(quiet, total=5 if report is not None else 4)
    from georef.io.atomic import atomic_group, resolve_target

    for target in (*(spec.path for spec in specs), report):  # a device, a directory or a write-protected file:
        if target is not None and not is_stdout(target):     # refused before processing
            resolve_target(target)
    given = configured_keys(config) | {key for key, option in (("lever_arm_gnss", gnss_lever_arm),
                                                                ("imu_preset", imu_preset)) if option is not None}
    with progress if progress is not None else contextlib.nullcontext():
        result = source.run(cfg, step, given)
        sbet_exports: list[Any] = []
        sbet_day = process_sbet_clock(result, utc_date, source.files, plain(time_scale)) if sbet_specs else None

        def write(spec: Any) -> None:
            if spec.fmt == "sbet":
                from georef.io.sbet import imu_rows_of_log, write_sbet

                sbet_exports.append(write_sbet(result.nav, imu_rows_of_log(result.log), spec.path, sbet_day,
                                               sbet_rate))
                return
            write_target(spec.path, lambda path: write_export(result.columns, path, spec.fmt, frames=result.frames,
                                                              odm_angles=cfg.output.odm_angles))

        with atomic_group():  # the files and the report together, or none of them (a full disk, a refused target)
            step("writing table" if len(specs) == 1 else f"writing {len(specs)} outputs")
            for spec in specs:
                if not is_stdout(spec.path):
                    write(spec)
            image_exports = [export_images(result, images, target, camera_clock_offset, utc_date, source.files,
                                           plain(time_scale)) for target in image_targets]
            verdict = with_image_checks(assess_result(result), image_exports)
            if report is not None:
                import shlex

                from georef.report import write_report

                step("writing report")
                command = shlex.join(["georef", *sys.argv[1:]]) if Path(sys.argv[0]).name == "georef" else None
                configs = {f"configuration {i + 1}" if len(config or []) > 1 else "configuration": path
                           for i, path in enumerate(config or [])}
                write_report(result, report, verdict=verdict, inputs=configs, command=command)
        for spec in specs:  # standard output last, once the files are in place
            if is_stdout(spec.path):
                write(spec)
    code = 0 if verdict.passed else EXIT_QC_FAILED
    if summary_json is not None:
        outputs = [{"what": "table" if index == 0 else "export", "format": spec.fmt, "path": str(spec.path)}
                   for index, spec in enumerate(specs)]
        if report is not None:
            outputs.append({"what": "report", "format": "html", "path": str(report)})
        outputs += [{"what": "export", "format": "smrmsg", "path": str(done.smrmsg_path)} for done in sbet_exports]
        outputs += [{"what": "export", "format": "images", "path": str(done.target_dir)} for done in image_exports]
        summary = result.summary()
        from georef.io.pos_time_scale import time_scale_summaries

        summary["time_scale"] = time_scale_summaries(result.notices)  # the .pos files' scale, [] for none
        if image_exports:
            summary["images"] = [done.to_dict() for done in image_exports]
        if sbet_exports:
            summary["sbet"] = [{**done.summary(), "notes": done.notes} for done in sbet_exports]
        write_json(summary_json, run_document(
            "process", code, inputs={**source.files, "config": config}, settings=result.config.settings(),
            outputs=outputs, summary=summary, verdict=verdict))
    if not quiet:
        messages = _messages(output, summary_json, *(spec.path for spec in specs[1:]))
        print_summary(result, output, verbose, messages)
        for spec in specs[1:]:
            messages.print(f"also wrote {escape(spec.fmt)} -> {escape(str(spec.path))}", highlight=False)
        for done in sbet_exports:
            messages.print(f"also wrote smrmsg -> {escape(str(done.smrmsg_path))}; SBET times: GPS week "
                           f"{done.records.gps_week}, from {escape(done.records.time_basis)}", highlight=False)
            for note in done.notes:
                console.print(f"[yellow]warning:[/] {escape(note)}", highlight=False)
        for done in image_exports:
            for line in done.lines():
                messages.print(escape(line), highlight=False)
        for warning in result.summary()["geodesy_warnings"]:
            console.print(f"[yellow]warning:[/] {escape(str(warning))}", highlight=False)
    _print_verdict(verdict, quiet)
    if code:
        raise typer.Exit(code=code)


class _Inputs:
    """What ``georef process`` was given and how to run it: ``files`` for the summary, ``run(cfg, step, given)``."""

    def __init__(self, files: dict[str, Path | None], run: Callable[[ProcessingConfig, Any, set[str]], Any]):
        self.files, self.run = files, run


def _process_inputs(pos: Path | None, camera: Path | None, imu: Path | None, gnss: Path | None,
                    events: Path | None, imu_instance: int | None, bag: Path | None = None,
                    imu_topic: str | None = None, gnss_topic: str | None = None,
                    time_scale: str = "auto") -> _Inputs:
    """Which of the four ways in the arguments name (checked before anything is read but a log's first bytes)."""
    from georef.io.logs import sniff
    from georef.pipeline import process as run_pos
    from georef.pipeline import process_bag, process_generic, process_log

    if bag is not None or imu_topic is not None or gnss_topic is not None:
        bag_or_files(bag, imu_topic, gnss_topic, {"--imu": imu, "--gnss": gnss})
        if pos is not None or camera is not None:
            raise typer.BadParameter("--bag takes the place of a log: give either a log (and CAMERA for POS.txt) or "
                                     "--bag and --events")
        if events is None:
            raise typer.BadParameter("--bag needs --events events.csv: the exposures, time [s] on the clock of the "
                                     "bag's header.stamp (for a wall clock, Unix seconds)")
        if imu_instance is not None:
            raise typer.BadParameter("--imu-instance is for autopilot logs; a bag's IMU is chosen with --imu-topic")
        check_time_scale(time_scale, {"--events": events})
        # auto: a bag's stamps are Unix seconds for a wall clock, and an _events.pos goes there
        return _Inputs({"bag": bag, "events": events},
                       lambda cfg, step, _given: process_bag(bag, events, cfg, progress=step, imu_topic=imu_topic,
                                                             gnss_topic=gnss_topic, time_scale=time_scale))
    if imu is not None or gnss is not None:
        if pos is not None or camera is not None:
            raise typer.BadParameter("--imu/--gnss take the place of a log: give either a log (and CAMERA for "
                                     "POS.txt) or --imu, --gnss and --events")
        if imu is None or gnss is None or events is None:
            missing = ", ".join(n for n, v in (("--imu", imu), ("--gnss", gnss), ("--events", events)) if v is None)
            raise typer.BadParameter(f"generic inputs need --imu, --gnss and --events together; missing {missing}")
        check_time_scale(time_scale, {"--gnss": gnss, "--events": events})
        return _Inputs({"imu": imu, "gnss": gnss, "events": events},
                       lambda cfg, step, _given: process_generic(imu, gnss, events, cfg, progress=step,
                                                                 time_scale=time_scale))
    if pos is None:
        raise typer.BadParameter("give the flight's log (an autopilot log, or POS.txt with Kamera.txt), or --imu, "
                                 "--gnss and --events")
    if time_scale != "auto":
        raise typer.BadParameter(f"--time-scale {time_scale} is for --imu/--gnss/--events and --bag/--events with "
                                 "an RTKLIB/Emlid .pos or _events.pos; a log's times are on its own UTC-of-day scale")
    from georef.io.rosbag import is_bag

    if is_bag(pos):
        raise typer.BadParameter(f"{pos} is a ROS bag: give it as --bag, with the exposures as --events events.csv")
    if sniff(pos) is not None:
        if camera is not None:
            raise typer.BadParameter(f"{camera}: an autopilot log brings its own camera events; give other exposure "
                                     "times with --events events.csv (CAMERA is POS.txt's Kamera.txt)")
        return _Inputs({"log": pos, "events": events},
                       lambda cfg, step, given: process_log(pos, cfg, events, progress=step,
                                                            imu_instance=imu_instance, given=given))
    if camera is None:
        raise typer.BadParameter(f"{pos} is not an autopilot log, so it is read as POS.txt, which needs its "
                                 "exposure times: give Kamera.txt (or the camera's raw log) as CAMERA")
    for option, value in (("--events", events), ("--imu-instance", imu_instance)):
        if value is not None:
            raise typer.BadParameter(f"{option} is for autopilot logs and generic inputs; POS.txt takes Kamera.txt")
    return _Inputs({"pos": pos, "camera": camera}, lambda cfg, step, _given: run_pos(pos, camera, cfg, progress=step))


@app.command(cls=PlainCoercionCommand)
@_user_errors
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
    import dataclasses

    from georef.sim.files import write_flight, write_generic
    from georef.sim.flight import VEHICLES, SimConfig
    from georef.sim.flight import simulate as run
    from georef.sim.sensors import AutopilotModel, GnssModel, MagnetometerModel, UnitModel, VibrationModel

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
        if value is not None and vehicle not in ("multicopter", "drone"):
            raise typer.BadParameter(f"--{name} applies to --vehicle multicopter only (and to the drone's survey)")
    if speed is not None and vehicle == "helicopter":
        raise typer.BadParameter("--speed applies to --vehicle multicopter, drone or car")
    for name, value in {"start": start, "gnss-drop": gnss_drop}.items():
        if value is not None and vehicle != "drone":
            raise typer.BadParameter(f"--{name} applies to --vehicle drone only")
    if gnss_sigma is not None and vehicle == "drone":
        raise typer.BadParameter("--gnss-sigma applies to --vehicle helicopter, multicopter or car (the drone's "
                                 "receiver errors are drawn by --seed)")
    if unit_yaw_drift is not None and vehicle != "helicopter":
        raise typer.BadParameter("--unit-yaw-drift applies to --vehicle helicopter only (the others have no POS "
                                 "unit)")
    sigma_neu = _triple(gnss_sigma, "--gnss-sigma", "metres")
    if sigma_neu is not None and not all(np.isfinite(v) and v > 0 for v in sigma_neu):
        raise typer.BadParameter(f"--gnss-sigma must be three positive metres N,E,U, got {gnss_sigma!r}")
    if unit_yaw_drift is not None and not np.isfinite(unit_yaw_drift):
        raise typer.BadParameter(f"--unit-yaw-drift must be a finite number of deg/h, got {unit_yaw_drift!r}")
    if vehicle == "drone":
        cfg = _drone_config(duration, seed, start, rate, camera_rate, imu, gyro_bias, accel_bias, vibration,
                            vibration_level, gnss_rate, pairs(outage, "--outage"), pairs(outlier, "--outlier"),
                            gnss_drop, hover, heading_policy, speed, magnetometer, autopilot)
        _write_drone(cfg, folder, crs, quiet)
        return
    rate = 50.0 if rate is None else rate
    gnss_rate = 1.0 if gnss_rate is None else gnss_rate
    changes: dict[str, Any] = {
        "pos_rate_hz": rate, "camera_rate_hz": 3.0 if camera_rate is None else camera_rate,
        "gnss": GnssModel(rate_hz=gnss_rate, outages=pairs(outage, "--outage"), outliers=pairs(outlier, "--outlier"),
                          **({} if sigma_neu is None else {"sigma_neu_m": sigma_neu})),
    }
    if unit_yaw_drift is not None:
        changes["unit"] = UnitModel(yaw_drift_deg_min=unit_yaw_drift / 60.0)
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
    cfg = SimConfig.for_vehicle(vehicle, duration_s=180.0 if duration is None else duration, seed=seed, **changes)
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
        out.print(f"wrote {escape(', '.join(str(p) for p in paths.values()))}", highlight=False, soft_wrap=True)
        out.print(f"{vehicle}: {len(flight.pos)} POS rows at {rate:g} Hz, {len(flight.exposures)} exposures, "
                  f"{len(flight.gnss_fixes)} GNSS fixes at {gnss_rate:g} Hz")


def _drone_config(duration: float | None, seed: int, start: str | None, rate: float | None,
                  camera_rate: float | None, imu: str | None, gyro_bias: str | None, accel_bias: str | None,
                  vibration: str | None, vibration_level: float, gnss_rate: float | None,
                  outages: list[tuple[float, float]], outliers: list[tuple[float, float]], gnss_drop: float | None,
                  hover: float | None, heading_policy: str | None, speed: float | None, magnetometer: bool,
                  autopilot: bool) -> SimConfig:
    """``georef simulate --vehicle drone``: the configuration drawn by ``seed``, with what the user gave."""
    import dataclasses

    from georef.sim.flight import SimConfig

    changes: dict[str, Any] = {}
    if rate is not None:
        changes["pos_rate_hz"] = rate
    if imu is not None:
        changes["imu_preset"] = imu
    if gyro_bias is not None:
        changes["gyro_bias_rad_s"] = tuple(np.radians(_triple(gyro_bias, "--gyro-bias", "deg/s")))
    if accel_bias is not None:
        changes["accel_bias_mps2"] = _triple(accel_bias, "--accel-bias", "m/s^2")
    cfg = SimConfig.for_vehicle("drone", duration_s=duration, seed=seed, start=start or "ground",
                                with_magnetometer=magnetometer, with_autopilot=autopilot, **changes)
    gnss_changes: dict[str, Any] = {name: value for name, value in (("rate_hz", gnss_rate),
                                                                    ("drop_fraction", gnss_drop)) if value is not None}
    gnss_changes.update({name: value for name, value in (("outages", outages), ("outliers", outliers)) if value})
    cfg.gnss = dataclasses.replace(cfg.gnss, **gnss_changes)
    if camera_rate is not None:
        cfg.camera_trigger = dataclasses.replace(cfg.camera_trigger, mode="time", interval_s=1.0 / camera_rate)
    if vibration not in (None, "none"):
        raise typer.BadParameter("--vibration for the drone: only none (its rotor harmonics follow the thrust; "
                                 "--vibration-level scales them)")
    cfg.vibration = None if vibration == "none" else dataclasses.replace(cfg.vibration, level=vibration_level)
    survey = {name: value for name, value in (("hover_s", hover), ("heading_policy", heading_policy),
                                              ("speed_mps", speed)) if value is not None}
    if survey:
        cfg.plan = dataclasses.replace(cfg.plan, survey=dataclasses.replace(cfg.plan.survey, **survey))
    return cfg


def _write_drone(cfg: SimConfig, folder: Path, crs: str | None, quiet: bool) -> None:
    """Simulate the drone flight and write its generic files and flight.toml."""
    from georef.sim.files import write_generic, write_processing_config
    from georef.sim.flight import simulate as run

    progress, step = _stage_progress(quiet, total=2)
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


@app.command(cls=PlainCoercionCommand)
@_user_errors
def fuse(
    imu: Annotated[Path | None, typer.Option(help="imu.csv: time [s], gyro_x..z [rad/s], acc_x..z [m/s^2], body "
                                                  "FRD (or --bag).")] = None,
    gnss: Annotated[Path | None, typer.Option(help="gnss.csv: time [s], lat, lon [deg], height [m] of the antenna, "
                                                   "optional sigma_n, sigma_e, sigma_u [m] (or --bag); or an RTKLIB/"
                                                   "Emlid .pos solution (recognised by its header; its times put on "
                                                   "imu.csv's scale, see --time-scale).")] = None,
    bag: BagFile = None,
    imu_topic: ImuTopic = None,
    gnss_topic: GnssTopic = None,
    time_scale: TimeScale = "auto",
    output: Annotated[Path, output_option("Trajectory to write (traj.csv).")] = Path("traj.csv"),
    config: ConfigFile = None,
    method: FuseMethod = "rts",
    gnss_lever_arm: GnssLeverArm = None,
    gnss_sigma: GnssSigma = None,
    imu_preset: ImuPreset = None,
    gnss_latency: GnssLatency = None,
    vehicle: Vehicle = None,
    magnetic_declination: MagneticDeclination = None,
    export: Annotated[list[str] | None, typer.Option(
        "--export", help="Also write sbet:FILE, the trajectory as an Applanix SBET with its smrmsg_<name>.out "
                         "(docs/sbet.md). The date: a .pos's, or Unix stamps' (a bag's), else imu.csv's times are "
                         "UTC seconds of --utc-date.")] = None,
    sbet_rate: SbetRate = None,
    utc_date: UtcDate = None,
    quiet: Quiet = False,
    summary_json: SummaryJson = None,
) -> None:
    """Fuse generic IMU and GNSS files (or a ROS bag's IMU and GNSS topics) into a trajectory (position,
    velocity, attitude with sigmas).

    Exit code 4: the trajectory is written but the quality checks failed (docs/qc.md).
    """
    from georef.fusion.ins import InsInputs, solve_ins
    from georef.io.generic import read_imu_csv, read_imu_heading_sources
    from georef.pipeline import solution_figures
    from georef.qc import assess

    from .summary import run_document

    bag_or_files(bag, imu_topic, gnss_topic, {"--imu": imu, "--gnss": gnss})
    time_scale = plain(time_scale)
    check_time_scale(time_scale, {"--gnss": gnss})
    method = plain(method)
    _one_stdout(**{"-o": output, "--summary-json": summary_json})
    sbet_specs = fuse_sbet_specs(export, output)
    check_sbet_request(sbet_specs, utc_date, sbet_rate, dated=True)  # checked once the IMU is read
    cfg = load_configs(config)
    cfg = _with_options(
        cfg, lever_arm_gnss=("--gnss-lever-arm", _triple(gnss_lever_arm, "--gnss-lever-arm", "metres")),
        gnss_sigma=("--gnss-sigma", _triple(gnss_sigma, "--gnss-sigma", "metres")),
        imu_preset=("--imu-preset", imu_preset), gnss_latency=("--gnss-latency", gnss_latency),
        vehicle=("--vehicle", plain(vehicle)), magnetic_declination=("--magnetic-declination", magnetic_declination))
    progress, step = _stage_progress(quiet, total=3)
    with progress if progress is not None else contextlib.nullcontext():
        step("reading inputs")
        from_pos = False
        if bag is not None:
            from georef.io.rosbag import read_bag

            read = read_bag(bag, imu_topic, gnss_topic)
            time_s, gyro, accel, fixes, mag, autopilot_yaw = read.time, read.gyro, read.accel, read.gnss, None, None
            kind, files = read.kind, {"bag": bag, "imu_topic": read.imu_topic, "gnss_topic": read.gnss_topic}
        else:
            from georef.io.pos_time_scale import is_solution_file, read_gnss_on_imu_scale

            time_s, gyro, accel, _ = read_imu_csv(imu)
            mag, autopilot_yaw = read_imu_heading_sources(imu)
            fixes = read_gnss_on_imu_scale(gnss, time_s, time_scale, imu.name)
            from_pos = is_solution_file(gnss)
            kind, files = ("imu.csv + RTKLIB .pos" if from_pos else "imu.csv + gnss.csv"), {"imu": imu, "gnss": gnss}
        # the SBET's time scale and date, before the fusion's minutes: refused here, nothing written
        sbet_time = sbet_clock(time_s, utc_date, {"--gnss": gnss}, time_scale, bag=bag is not None,
                               imu_label="the bag's IMU" if bag is not None else imu.name) if sbet_specs else None
        step(f"fusing ({method})")
        inputs = InsInputs(time=time_s, gyro=gyro, accel=accel, gnss=fixes, source=str(bag or imu), mag=mag,
                           autopilot_yaw=autopilot_yaw)
        if method == "graph":
            from georef.fusion.graph import solve_graph_inputs

            nav = solve_graph_inputs(inputs, GraphSettings.of(cfg))
        else:
            nav = solve_ins(inputs, InsSettings.of(cfg), smooth=method == "rts")
        step("writing trajectory")
        sbet_exports = write_fuse_outputs(nav, gyro, accel, output, sbet_specs, sbet_rate, sbet_time)
    verdict = assess(nav, cfg=cfg, kind=kind)
    code = 0 if verdict.passed else EXIT_QC_FAILED
    used = int((nav.gnss.status >= 1).sum())
    rejected = nav.gnss.rejected_lines
    figures = solution_figures(nav, cfg.gnss, fixes.sigma_neu)
    from georef.io.pos_time_scale import time_scale_lines, time_scale_summaries

    if summary_json is not None:
        summary = {"method": method, "trajectory_rows": int(nav.valid.sum()), "gnss_fixes": len(fixes),
                   "gnss_used": used, "gnss_rejected_lines": rejected, **figures,
                   "time_scale": time_scale_summaries(fixes.notices)}
        outputs = [{"what": "trajectory", "format": "csv", "path": str(output)}]
        for done in sbet_exports:
            outputs += [{"what": "export", "format": "sbet", "path": str(done.sbet_path)},
                        {"what": "export", "format": "smrmsg", "path": str(done.smrmsg_path)}]
            summary.setdefault("sbet", []).append({**done.summary(), "notes": done.notes})
        write_json(summary_json, run_document(
            "fuse", code, inputs={**files, "config": config}, settings=cfg.settings(),
            outputs=outputs, summary=summary, verdict=verdict))
    if not quiet:
        to = _messages(output, summary_json)
        named = f" (lines {', '.join(map(str, rejected[:10]))})" if rejected else ""
        to.print(f"{int(nav.valid.sum())} trajectory rows -> {target_text(output)}; GNSS {len(fixes)} fixes, "
                 f"{used} used, {len(rejected)} rejected{named}", highlight=False, soft_wrap=True)
        for line in time_scale_lines(fixes.notices):  # which scale the .pos was put on: GPST and UTC are 18 s apart
            to.print(f"time scale: {escape(line)}", highlight=False, soft_wrap=True)
        for what, text in filter_rows(figures):
            to.print(f"{what}: {text}", highlight=False, soft_wrap=True)
        for done in sbet_exports:
            to.print(f"also wrote sbet -> {escape(str(done.sbet_path))}, smrmsg -> {escape(str(done.smrmsg_path))}; "
                     f"SBET times: GPS week {done.records.gps_week}, from {escape(done.records.time_basis)}",
                     highlight=False, soft_wrap=True)
            for note in done.notes:
                to.print(f"[yellow]warning:[/] {escape(note)}", highlight=False, soft_wrap=True)
        if bag is not None:  # what the bag reader converted or skipped: never silent
            for notice in read.all_notices:
                to.print(f"[yellow]notice:[/] {escape(str(notice))}", highlight=False, soft_wrap=True)
        elif from_pos:  # what the .pos reader converted, floored or dropped (the time scale is printed above)
            from georef.io.pos_time_scale import TimeScaleNotice

            for notice in (n for n in fixes.notices if not isinstance(n, TimeScaleNotice)):
                to.print(f"[yellow]notice:[/] {escape(str(notice))}", highlight=False, soft_wrap=True)
    _print_verdict(verdict, quiet)
    if code:
        raise typer.Exit(code=code)


@app.command(cls=PlainCoercionCommand)
@_user_errors
def attitude(
    imu: Annotated[Path, typer.Option(help="imu.csv: time [s], gyro_x..z [rad/s], acc_x..z [m/s^2], optional "
                                           "mag_x..z (any unit); body axes forward-right-down.")],
    method: AttitudeMethod = "mekf",
    output: Annotated[Path, output_option("Attitude table to write (CSV, degrees).")] = Path("attitude.csv"),
    inclination: Annotated[float, typer.Option(help="Magnetic inclination in degrees (field reference "
                                                    "[cos I, 0, sin I] in NED).")] = 60.0,
    gain: Annotated[float, typer.Option(help="Complementary filter: accelerometer weight per sample (0-1).")] = 0.02,
    gyro_noise: Annotated[float, typer.Option(help="Gyro white noise per sample in rad/s (mekf, ukf).")] = 0.01,
    accel_sigma: Annotated[float, typer.Option(help="Noise of the normalised gravity direction (unitless, "
                                                    "~ radians); also the kf's angle sigma.")] = 0.01,
    alpha: Annotated[float, typer.Option(help="UKF sigma-point spread alpha.")] = 0.01,
    beta: Annotated[float, typer.Option(help="UKF prior-knowledge beta (2 for Gaussian).")] = 2.0,
    kappa: Annotated[float, typer.Option(help="UKF secondary scaling kappa.")] = 0.0,
    quiet: Quiet = False,
) -> None:
    """Roll, pitch (and yaw with mekf/ukf) from raw gyro, accelerometer and optional magnetometer data."""
    from georef.attitude.run import estimate_attitude
    from georef.io.atomic import atomic_write
    from georef.io.generic import read_marg_csv

    method = plain(method)
    time_s, gyro, accel, mag, _ = read_marg_csv(imu)
    table = estimate_attitude(method, time_s, gyro, accel, mag, inclination_deg=inclination, gain=gain,
                              gyro_noise=gyro_noise, accel_sigma=accel_sigma, alpha=alpha, beta=beta, kappa=kappa)
    def write(path: Path) -> None:
        with atomic_write(path) as handle:
            table.to_csv(handle, index=False, float_format="%.8g", lineterminator="\n")

    write_target(output, write)
    if not quiet:
        _messages(output).print(f"{len(table)} samples -> {target_text(output)} ({escape(method)}"
                                f"{', magnetometer' if mag is not None else ''})", highlight=False,
                                soft_wrap=True)


@app.command(cls=PlainCoercionCommand)
@_user_errors
def batch(
    source: Annotated[Path, typer.Argument(help="A folder of flight folders (POS.txt, Kamera.txt, flight.toml each) "
                                                "or a manifest CSV with columns flight, pos, camera[, config].")],
    output: Annotated[Path, output_option("Output folder: <flight>/eo.csv, <flight>/georef.log, batch_summary.csv.",
                                          stdout=False)] = Path("batch_out"),
    method: BatchMethod = None,
    scheduler: Annotated[str | None, typer.Option(help="Dask scheduler address, e.g. tcp://host:8786; default: a "
                                                       "LocalCluster on this machine.")] = None,
    workers: Annotated[int, typer.Option(help="LocalCluster worker processes (one thread each).")] = 2,
    export: Annotated[list[str] | None, typer.Option(
        "--export", help="Also write, in every flight's folder, FORMAT (metashape, pix4d, odm, parge, geojson, kml; "
                         "default file names metashape.csv, pix4d.csv, geo.txt, parge.txt, stations.geojson, "
                         "stations.kml) or FORMAT:NAME; repeatable. CRS, heights and image names come from each "
                         "flight's flight.toml. images[:NAME] writes geotagged copies of each flight's photos "
                         "(its folder images/, or the manifest's images column) into NAME (default images).")] = None,
    shared_calibration: Annotated[bool, typer.Option(
        "--shared-calibration", help="With --method graph: estimate one GNSS lever arm [m, body] and time offset "
                                     "[s] from all flights (one installation), re-solve every flight with it, and "
                                     "flag flights that disagree (chi-square); writes calibration.json and "
                                     "calibration.toml (give it to process or fuse as a second --config).")] = False,
    quiet: Quiet = False,
    summary_json: SummaryJson = None,
) -> None:
    """Process many flights, one Dask task each; a failed flight is reported and the others go on.

    Exit code 0 when every flight ran and passed its quality checks; else 3 when any flight failed with an internal
    error (a bug in georef, a worker that died), else 2 when any flight failed to run on its input, else 4 when
    any flight's quality checks failed (docs/qc.md). The other flights' outputs are written in every case.
    """
    from georef.batch import SUMMARY_COLUMNS, discover, run_batch

    from .summary import batch_document, batch_exit_code

    _not_stdout(output, "-o", "batch writes a folder of files")
    from georef.io.exports import parse_folder_export

    # images[:NAME]: geotagged copies of each flight's photos (<flight>/images/) in <out>/<flight>/NAME (images)
    images = tuple(("images", text.partition(":")[2] or "images") for text in export or []
                   if text == "images" or text.startswith("images:"))
    for _, name in images:
        if Path(name).name != name or name in (".", ".."):
            raise typer.BadParameter(f"--export images:{name}: give a plain folder name; each flight's copies go in "
                                     "its own folder")
    specs = [parse_folder_export(text) for text in export or []  # checked before any flight runs
             if not (text == "images" or text.startswith("images:"))]
    exports = tuple((spec.fmt, str(spec.path)) for spec in specs) + images
    if shared_calibration and plain(method) != "graph":
        raise typer.BadParameter("needs --method graph (the calibration is a variable of the factor graph)",
                                 param_hint="--shared-calibration")
    jobs = discover(source)
    rows: list[dict] = []
    settings = {"method": plain(method), "scheduler": scheduler, "workers": workers,
                "exports": [f"{fmt}:{name}" for fmt, name in exports], "shared_calibration": shared_calibration}

    def keep(row: dict) -> None:  # a campaign's earlier rounds are superseded by its last
        rows[:] = [r for r in rows if r["flight"] != row["flight"]] + [row]

    if quiet:
        summary = run_batch(jobs, output, method=plain(method), scheduler=scheduler, workers=workers,
                            on_done=keep, exports=exports, shared_calibration=shared_calibration)
    else:
        from rich.progress import BarColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

        progress = Progress(SpinnerColumn(), TextColumn("{task.description}"), BarColumn(),
                            TextColumn("{task.completed}/{task.total} flights"), TimeElapsedColumn(),
                            console=console, transient=True)
        with progress:
            task = progress.add_task("processing flights", total=len(jobs))

            current = {"round": 1}

            def done(row: dict) -> None:
                keep(row)
                step = f"round {row['round']}: " if "round" in row else ""
                if row.get("round", 1) != current["round"]:  # a campaign's next round
                    current["round"] = row["round"]
                    progress.reset(task, total=len(jobs))
                progress.advance(task)
                progress.update(task, description=f"{step}{escape(str(row['flight']))}: "
                                                  f"{escape(str(row['status']))}")

            summary = run_batch(jobs, output, method=plain(method), scheduler=scheduler, workers=workers,
                                on_done=done, exports=exports, shared_calibration=shared_calibration)
    order = {job.flight: i for i, job in enumerate(jobs)}
    rows.sort(key=lambda row: order.get(row["flight"], len(order)))
    code = batch_exit_code(rows, EXIT_USER_ERROR, EXIT_INTERNAL_ERROR, EXIT_QC_FAILED)
    outputs = [{"what": "summary", "format": "csv", "path": str(output / "batch_summary.csv")}]
    calibration_file = output / "calibration.json"
    if shared_calibration and calibration_file.exists():
        outputs += [{"what": "calibration", "format": "json", "path": str(calibration_file)},
                    {"what": "calibration config", "format": "toml", "path": str(output / "calibration.toml")}]
    if summary_json is not None:
        write_json(summary_json, batch_document(
            code, source=source, settings=settings, rows=rows, columns=SUMMARY_COLUMNS, outputs=outputs))
    if not quiet and len(outputs) > 1:
        _print_campaign(json.loads(calibration_file.read_text(encoding="utf-8")), summary_json)
    if not quiet:
        shown = ("flight", "status", "method", "frames", "rejected_fixes", "qc", "runtime_s", "message")
        from rich.table import Table

        table = Table(title=f"georef batch -> {escape(str(output))}/batch_summary.csv", title_justify="left")
        for column in shown:
            table.add_column(column)
        for row in summary.itertuples(index=False):
            table.add_row(*(escape(_cell(getattr(row, c))) for c in shown))
        _messages(summary_json).print(table)
    failed = summary[summary["status"] != "ok"]
    for row in failed.itertuples(index=False):
        if row.failure == "internal":
            console.print(f"[bold red]internal error:[/] {escape(str(row.flight))}: {escape(str(row.message))}. "
                          "This is a bug in georef; please report it with the flight's georef.log (it has the "
                          "traceback).", highlight=False)
        else:
            console.print(f"[bold red]failed:[/] {escape(str(row.flight))}: {escape(str(row.message))}",
                          highlight=False)
    qc_failed = summary[summary["qc"].fillna("").astype(str).str.startswith("failed")]
    for row in qc_failed.itertuples(index=False):
        console.print(f"[bold red]QC failed:[/] {escape(str(row.flight))}: {escape(str(row.qc_details))}",
                      highlight=False)
    if code:
        raise typer.Exit(code=code)


def _print_campaign(calibration: dict, summary_json: Path | None) -> None:
    """The campaign's calibration and each flight's own estimate, as a table."""
    def fmt(values, sigmas, scale: float = 1.0, digits: int = 3) -> str:
        values, sigmas = np.atleast_1d(values), np.atleast_1d(sigmas)
        return ", ".join("-" if v is None else f"{v * scale:.{digits}f} ± {s * scale:.{digits}f}"
                         for v, s in zip(values, sigmas, strict=True))

    from rich.table import Table

    table = Table(title=escape(f"campaign calibration ({calibration['rounds']} rounds): lever arm [m, body x y z], "
                               "GNSS time offset [ms]"), title_justify="left")
    for column in ("flight", "lever arm [m]", "time offset [ms]", "chi2 (dof)", "consistent"):
        table.add_column(escape(column))
    table.add_row("campaign", fmt(calibration["gnss_lever_arm_m"], calibration["gnss_lever_arm_sigma_m"]),
                  fmt(calibration["gnss_time_offset_s"], calibration["gnss_time_offset_sigma_s"], 1e3, 1), "", "")
    for name, flight in calibration["flights"].items():
        lever = [v if v is not None else np.nan for v in flight["gnss_lever_arm_m"]]
        lever_sigma = [v if v is not None else np.nan for v in flight["gnss_lever_arm_sigma_m"]]
        offset = flight["gnss_time_offset_s"] if flight["gnss_time_offset_s"] is not None else np.nan
        offset_sigma = flight["gnss_time_offset_sigma_s"] if flight["gnss_time_offset_sigma_s"] is not None else np.nan
        table.add_row(escape(name), fmt(lever, lever_sigma), fmt(offset, offset_sigma, 1e3, 1),
                      f"{flight['chi2']:.1f} ({flight['dof']})",
                      "yes" if flight["consistent"] else "[bold red]NO[/]")
    _messages(summary_json).print(table)
    from georef.campaign import WEAK_DATA_SHARE

    names = ("lever arm x", "lever arm y", "lever arm z", "time offset")
    weak = [f"{name} ({100 * share:.0f} %)" for name, share in zip(names, calibration.get("data_share", [1.0] * 4),
                                                                     strict=True) if share < WEAK_DATA_SHARE]
    if weak:
        console.print(f"[yellow]notice:[/] the flights' data removed little of the configured prior's variance on "
                      f"{', '.join(weak)}: those campaign values are mostly the prior handed back, not a measured "
                      "calibration (longer flights, turns and speed changes observe them)", highlight=False)


def _print_rows(title: str, rows: list[tuple[str, str]]) -> None:
    """A two-column table of (what, value) rows on standard output."""
    from rich.table import Table

    table = Table(title=escape(title), show_header=False, title_justify="left")
    table.add_column("what", style="bold")
    table.add_column("value")
    for what, value in rows:
        table.add_row(escape(what), escape(value))
    out.print(table)


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


@app.command("calibrate-boresight", cls=PlainCoercionCommand)
@_user_errors
def calibrate_boresight(
    eo: Annotated[Path, typer.Argument(help="The EO table georef process wrote (eo.csv; with an image column, "
                                            "--image-names), processed with the mounting of --config / "
                                            "--boresight / --camera-lever-arm.")],
    adjusted: Annotated[Path, typer.Argument(help="The block's adjusted cameras (bundle adjustment with ground "
                                                  "control): a Metashape camera export (CSV with X, Y, Z [m] and "
                                                  "Omega, Phi, Kappa [deg]; the _est columns when present), Pix4D's "
                                                  "calibrated_external_camera_parameters.txt or ODM's "
                                                  "odm_report/shots.geojson.")],
    crs: Annotated[str, typer.Option(help="Projected CRS the block was adjusted in (its X, Y in metres), e.g. "
                                          "EPSG:32633; the photos' ω, φ, κ refer to its grid north.")],
    adjusted_format: Annotated[str | None, typer.Option(
        "--format", help="metashape, pix4d or odm (default: odm for .geojson/.json, pix4d for "
                         "*calibrated_external*, else metashape).")] = None,
    config: ConfigFile = None,
    boresight: Annotated[str | None, typer.Option(
        help="The boresight roll,pitch,yaw [deg] the EO was processed with (default: --config's).")] = None,
    camera_lever_arm: Annotated[str | None, typer.Option(
        help="The camera lever arm x,y,z [m, body: x forward, y right, z down] the EO was processed with "
             "(default: --config's).")] = None,
    ellipsoidal: Annotated[bool, typer.Option(
        "--ellipsoidal-heights", help="Compare the block's heights with the EO's ellipsoidal height even when the "
                                      "EO has height_orthometric (only the not-estimated vertical terms change).")
    ] = False,
    process_summary: Annotated[Path | None, typer.Option(
        help="The --summary-json of the georef process run that wrote the EO table: its accelerometer-bias sigma "
             "[m/s^2] over g is the sigma of the INS tilt fixed in the body frame in the roll and pitch sigmas "
             "[deg]. Without it those sigmas are conservative (bounded by the EO's tilt sigma).")] = None,
    output: Annotated[Path, output_option("calibration.toml to write: [mounting] boresight [deg] and "
                                          "lever_arm_camera [m] for georef process --config.", stdout=False)
                      ] = Path("calibration.toml"),
    quiet: Quiet = False,
    summary_json: SummaryJson = None,
) -> None:
    """Calibrate the camera boresight [deg] and lever arm [m] from a block adjusted with ground control.

    Per photo the EO's camera attitude and position are compared with the adjusted ones; strips (straight runs)
    give the estimate, its sigma includes the INS's flight-constant yaw error and its body-fixed tilt (the
    accelerometer-bias sigma of --process-summary over g; without it a conservative bound), and a jackknife over
    strips checks it. The lever arm's x (trigger latency) and z (vertical datum) are reported, not applied; y is
    applied only with strips in opposite headings and when over twice its sigma. Exit code 0: written; 2: bad
    input, no matching names, too few photos or strips; 4: written but weak or inconsistent (fewer than 3 strips,
    one heading, a failed chi-square or jackknife check).
    """
    from .calibrate import print_result, run

    _not_stdout(output, "-o", "calibrate-boresight writes calibration.toml")
    cfg = _with_options(load_configs(config),
                        boresight=("--boresight", _triple(boresight, "--boresight", "deg")),
                        lever_arm_camera=("--camera-lever-arm", _triple(camera_lever_arm, "--camera-lever-arm",
                                                                        "m")))
    result = run(eo, adjusted, adjusted_format, crs, cfg.mounting.boresight, cfg.mounting.lever_arm_camera, output,
                 ellipsoidal, process_summary)
    code = EXIT_QC_FAILED if result.weak else 0
    if summary_json is not None:
        from .summary import SCHEMA_VERSION

        inputs = {"eo": str(eo), "adjusted": str(adjusted), "config": [str(p) for p in config or []], "crs": crs,
                  "process_summary": None if process_summary is None else str(process_summary)}
        write_json(summary_json, {"schema": SCHEMA_VERSION, "georef_version": georef_version(),
                                  "command": "calibrate-boresight", "exit_code": code, "inputs": inputs,
                                  "outputs": [{"what": "calibration config", "format": "toml", "path": str(output)}],
                                  "figures": result.summary()})
    if not quiet:
        print_result(result, output, _messages(summary_json), console)
    elif result.weak:
        for problem in result.problems:
            console.print(f"[bold red]weak:[/] {escape(problem)}", highlight=False)
    if code:
        raise typer.Exit(code=code)


@app.command(cls=PlainCoercionCommand)
@_user_errors
def info(
    pos: Annotated[Path, typer.Argument(help="The log: an autopilot log (ArduPilot .bin/.log, PX4 .ulg, gzip too), "
                                             "a POS unit's POS.txt, a ROS bag (.bag, a ROS 2 bag's folder) or an "
                                             "RTKLIB/Emlid .pos solution (gzip too).")],
    config: ConfigFile = None,
    gnss_rate: Annotated[float | None, typer.Option(help="GNSS fix rate in Hz, if known (default: the config's, "
                                                         "else 1).")] = None,
    imu_instance: ImuInstance = None,
) -> None:
    """Describe a log: for an autopilot log its vehicle, span, IMU streams, GNSS fixes and accuracy, clock, camera
    events and lever-arm parameters; for POS.txt its format, span, rates, GNSS epochs and gaps, quirks repaired,
    columns found; for an RTKLIB/Emlid .pos its layout, time system (GPST: the leap seconds), span, epochs, gaps
    and solution qualities."""
    from georef.io.logs import read_flight_log, sniff
    from georef.io.pos import read_pos
    from georef.io.rosbag import describe_bag, is_bag

    if is_bag(pos):  # a ROS bag: its topics, and which ones --bag reads
        _print_rows(str(pos), describe_bag(pos))
        return
    from georef.io.rtklib import check_not_headerless, describe_pos, is_rtklib_pos

    if is_rtklib_pos(pos):  # an RTKLIB/Emlid .pos (gzip too): its time system, span, qualities
        _print_rows(str(pos), describe_pos(pos))
        return
    check_not_headerless(pos)
    if sniff(pos) is not None:
        from georef.io.logs.flightlog import describe

        flight = read_flight_log(pos, imu_instance)
        _print_rows(str(pos), describe(flight))
        for notice in flight.notices:
            console.print(f"[yellow]notice:[/] {escape(str(notice))}", highlight=False)
        return
    cfg = load_configs(config)
    rate = gnss_rate if gnss_rate is not None else cfg.gnss.rate_hz
    log = read_pos(pos, column_names=cfg.pos_columns.names, gnss_rate_hz=rate)
    from rich.table import Table

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


@app.command("build-kernels", cls=PlainCoercionCommand)
@_user_errors
def build_kernels(
    force: Annotated[bool, typer.Option("--force", help="Compile even the kernels whose build is up to date.")] = False,
    quiet: Quiet = False,
) -> None:
    """Compile the filters' inner loops ahead of time (10-45 s each; nothing to do when up to date).

    The modules are written inside the installed georef package, or into $GEOREF_KERNEL_DIR when set (the
    runs then load them from there). Without this step georef runs the same loops through numba's JIT, which
    costs every run about 0.5 s of start-up. A build whose sources, numba, numpy or Python have changed since
    is never run; this command replaces it.
    """
    import os
    from concurrent.futures import ProcessPoolExecutor

    from georef.aot import KERNELS, BuildUnavailableError, build

    # one process per kernel, as many at once as there are cores: each compile is single-threaded (numba.pycc),
    # and on a 2-core machine the six kernels took 2 min one after the other
    notices: list[str] = []
    workers = max(1, min(len(KERNELS), os.cpu_count() or 1))
    try:
        with ProcessPoolExecutor(workers) as pool:
            futures = [pool.submit(build, name, force=force) for name in KERNELS]
            for name, future in zip(KERNELS, futures, strict=True):
                if quiet:
                    result = future.result()
                else:
                    with console.status(f"compiling the {name} kernel ({workers} at a time)"):
                        result = future.result()
                    console.print(f"{'built' if result.compiled else 'up to date'} {escape(str(result.path))}",
                                  highlight=False)
                notices += [notice for notice in result.notices if notice not in notices]
    except BuildUnavailableError as exc:  # a numba without pycc: the user can install the tested range
        console.print(f"[bold red]error:[/] {escape(str(exc))}", highlight=False)
        raise typer.Exit(code=EXIT_USER_ERROR) from None
    if not quiet:
        for notice in notices:  # numba.pycc's pending deprecation, shown rather than filtered (docs/aot.md)
            console.print(f"[yellow]notice from numba:[/] {escape(notice)}", highlight=False)


@app.command(cls=PlainCoercionCommand)
@_user_errors
def evaluate(
    eo: Annotated[Path, typer.Argument(help="EO table written by georef process ('-': read it from standard "
                                            "input, e.g. piped from georef process -o -).")],
    truth: Annotated[Path, typer.Argument(help="Reference EO table (e.g. truth.csv of georef simulate): frame, "
                                               "time, lat, lon, height, roll, pitch, yaw; same frames, same order.")],
) -> None:
    """Accuracy of an EO table against a reference: RMS and the share of errors inside 2 sigma.

    Both tables are checked first: a missing or non-numeric column, a different number of frames or different
    times are reported with the file, line and column (and arguments given the wrong way round are named so).
    """
    from georef.evaluate import accuracy, frame_errors, sigma_coverage

    from .evaluate_inputs import read_inputs

    estimate, reference = read_inputs(eo, truth)
    errors = frame_errors(estimate, reference)
    from rich.table import Table

    table = Table(title=escape(f"{eo} against {truth}"), title_justify="left")
    table.add_column("figure")
    table.add_column("value", justify="right")
    for name, value in accuracy(errors).items():
        table.add_row(name, f"{value:.3f}")
    for name, value in sigma_coverage(estimate, errors).items():
        table.add_row(f"inside 2 sigma: {name}", f"{100 * value:.1f} %")
    out.print(table)


def _exit_now(code: object) -> None:
    """End the process with ``code`` as ``sys.exit`` would, without the interpreter's teardown.

    The command is done: its files are written atomically and closed. What remains of a normal exit is the
    ``atexit`` handlers, flushing the standard streams and then tearing down every module the run imported
    (numpy, pandas, scipy, pyproj...; about 900 of them), which gives the user nothing and cost 0.25 s of CPU
    in a 2.5-s ``georef process`` (measured: the same imports, then exiting normally or with ``os._exit``).
    The handlers run and the streams are flushed here, then ``os._exit``. With another thread still alive, or
    when a stream cannot be flushed (a closed pipe), the normal exit runs instead, with its usual messages."""
    import atexit
    import threading

    if code is None:
        status = 0
    elif isinstance(code, int):
        status = code
    else:
        sys.exit(code)  # a message: printed by the interpreter, status 1
    if threading.active_count() > 1:
        sys.exit(status)
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except (OSError, ValueError):
        sys.exit(status)
    atexit._run_exitfuncs()
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except (OSError, ValueError):
        sys.exit(status)
    os._exit(status & 0xFF)


def main() -> None:  # pragma: no cover - console entry point (tests/test_cli.py runs it as a process)
    """The ``georef`` command: :data:`app`, then :func:`_exit_now` with its exit code. Tests call :data:`app`
    in-process (typer's runner), which never ends the process."""
    try:
        app()
    except SystemExit as exc:
        _exit_now(exc.code)
    _exit_now(0)


if __name__ == "__main__":  # pragma: no cover
    main()
