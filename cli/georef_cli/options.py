"""Option definitions shared by the ``georef`` commands: one definition each, reused by every command that takes it.

Each is a ``typing.Annotated`` type for a command's parameter; the default value stays in the command's signature,
e.g. ``quiet: Quiet = False``. Options whose values come from a fixed list are choices (a string ``Enum``, matched
case-insensitively), so a wrong value is refused before anything runs, with the list in the message and in
``--help``; :func:`plain` turns the member back into the plain string the library takes.
"""

from __future__ import annotations

from enum import Enum
from pathlib import Path
from typing import Annotated, Any

import typer

from georef.config import METHODS, VEHICLE_KINDS
from georef.imu_errors import presets_help

#: the methods of ``georef fuse`` (full-state filters on generic inputs)
FUSE_METHODS = ("rts", "ekf", "graph")
#: the filters of ``georef attitude``
ATTITUDE_METHODS = ("complementary", "kf", "mekf", "ukf")
#: the ``--time-scale`` values: georef.io.pos_time_scale.CHOICES, written out here because importing that module
#: imports pyproj (0.3 s on every command)
TIME_SCALES = ("auto", "utc-day", "gps-week", "unix")


def georef_version() -> str:
    """The installed georef's version (``pyproject.toml``), or ``"unknown"`` when it runs from an uninstalled tree."""
    from importlib import metadata  # its import costs every run ~20 ms; only --version and summaries need it

    try:
        return metadata.version("georef")
    except metadata.PackageNotFoundError:
        return "unknown"


def choice(name: str, values: tuple[str, ...]) -> type[Enum]:
    """A string ``Enum`` called ``name`` whose members are ``values`` (member name = value)."""
    return Enum(name, {v: v for v in values}, type=str)  # type: ignore[return-value]


def plain(member: Enum | str | None) -> str | None:
    """The plain string of a choice (``None`` stays ``None``)."""
    return member.value if isinstance(member, Enum) else member


def output_option(what: str, *, stdout: bool = True) -> Any:
    """``-o/--output``: the file to write ``what`` to; with ``stdout``, ``-`` writes it to standard output (and
    everything else the command prints goes to standard error)."""
    hint = " '-' writes it to standard output (all messages go to standard error)." if stdout else ""
    return typer.Option("-o", "--output", help=f"{what}{hint}")


def method_option(what: str) -> Any:
    """``--method``: a choice (its values are listed by ``--help`` and in the message about a wrong one)."""
    return typer.Option(case_sensitive=False, help=what)


Method = choice("Method", METHODS)
FuseMethodChoice = choice("FuseMethod", FUSE_METHODS)
AttitudeMethodChoice = choice("AttitudeMethod", ATTITUDE_METHODS)
VehicleChoice = choice("Vehicle", VEHICLE_KINDS)
TimeScaleChoice = choice("TimeScale", TIME_SCALES)


ImuPreset = Annotated[str | None, typer.Option(
    "--imu-preset", help="IMU error preset: the datasheet prior of the noise model the data then fit. " + presets_help()
    + ".")]
ImuFile = Annotated[Path | None, typer.Option(
    "--imu", help="imu.csv: time [s], gyro_x..z [rad/s], acc_x..z [m/s^2], body axes forward-right-down; optional "
                  "mag_x..z and an autopilot's roll, pitch, yaw [deg] (docs/formats.md).")]
GnssFile = Annotated[Path | None, typer.Option(
    "--gnss", help="gnss.csv: time [s, imu.csv's clock], lat, lon [deg], height [m, ellipsoidal] of the antenna, "
                   "optional sigma_n, sigma_e, sigma_u [m]; or an RTKLIB/Emlid .pos solution (recognised by its "
                   "header; its times put on imu.csv's scale, see --time-scale; docs/rtklib.md).")]
EventsFile = Annotated[Path | None, typer.Option(
    "--events", help="events.csv: the exposures, time [s, the IMU's clock: imu.csv's, or UTC seconds of the day "
                     "for an autopilot log] and an optional image name; replaces an autopilot log's own camera "
                     "events. An Emlid/RTKLIB demo5 _events.pos (recognised by its header) has its events' times "
                     "put on the IMU's scale (--time-scale; with --bag, Unix seconds).")]
TimeScale = Annotated[TimeScaleChoice, typer.Option(  # type: ignore[valid-type]
    "--time-scale", case_sensitive=False,
    help="The IMU's clock, onto which an RTKLIB/Emlid .pos and _events.pos are put [s]: utc-day (UTC seconds of "
         "the day, going on past 86400 after midnight), gps-week (GPS seconds of the week, no leap seconds), unix "
         "(UTC seconds since 1970-01-01), or auto: the one of these on which the file's times overlap imu.csv's "
         "(on a Sunday, when the first two differ only by the leap seconds, it is an error asking for the scale); "
         "with --bag, auto is unix. docs/rtklib.md.")]
ImuInstance = Annotated[int | None, typer.Option(
    "--imu-instance", help="Which of an autopilot log's IMUs to use (default the primary: ArduPilot's IMU 0, "
                                  "PX4's sensor_combined; N picks ArduPilot's IMU N or PX4's vehicle_imu N); "
                                  "georef info lists them.")]
Quiet = Annotated[bool, typer.Option(
    "--quiet", "-q", help="Print nothing but errors (and failed quality checks, for the commands that run them).")]
Verbose = Annotated[bool, typer.Option("--verbose", "-v", help="Also list every input notice.")]
ConfigFile = Annotated[list[Path] | None, typer.Option(
    "--config", help="flight.toml with the flight's settings (docs/formats.md: its sections and keys); repeatable, "
                     "later files win key by key (e.g. flight.toml, then a campaign's calibration.toml); "
                     "command-line options win.")]
SummaryJson = Annotated[Path | None, typer.Option(
    "--summary-json", help="Also write a machine-readable summary (JSON: the figures, the QC verdict with its "
                           "checks, the outputs written, the georef version; docs/qc.md) to this file; '-' "
                           "writes it to standard output.")]

_METHODS_HELP = ("rts (full-state EKF + RTS smoother; default), ekf (the forward filter alone), axis (the thesis's "
                 "per-axis method) or graph (GTSAM factor-graph smoother; it also estimates the GNSS lever arm and "
                 "time offset, with priors from the config's lever_arm_gnss_sigma [m] and gnss_latency_sigma [s]; "
                 "its solver, robust kernel and scale factors are set in the config's [graph] section)")
ProcessMethod = Annotated[Method | None, method_option(f"Fusion method: {_METHODS_HELP}.")]  # type: ignore[valid-type]
FuseMethod = Annotated[FuseMethodChoice, method_option(  # type: ignore[valid-type]
    "rts (EKF + smoother), ekf (forward filter only) or graph (GTSAM factor-graph smoother started from rts; its "
    "settings: the config's [graph] section, lever_arm_gnss_sigma and gnss_latency_sigma).")]
BatchMethod = Annotated[Method | None, method_option(  # type: ignore[valid-type]
    f"Override every flight's method (default: each flight's flight.toml): {_METHODS_HELP}.")]
AttitudeMethod = Annotated[AttitudeMethodChoice, method_option(  # type: ignore[valid-type]
    "complementary, kf (angle + gyro-bias Kalman), mekf or ukf.")]

GnssLeverArm = Annotated[str | None, typer.Option(
    help="IMU -> GNSS antenna lever arm X,Y,Z in metres, body frame (x fwd, y right, z down).")]
GnssSigma = Annotated[str | None, typer.Option(
    help="GNSS fix standard deviation N,E,U in metres, for fixes without their own sigmas (default 1,1,2).")]
GnssLatency = Annotated[float | None, typer.Option(
    help="GNSS time-tag latency in seconds (the fix was measured this long before its time tag); default: "
         "estimated and reported, not applied.")]
MagneticDeclination = Annotated[float | None, typer.Option(
    help="Magnetic declination [deg, east of true north] for a heading from the magnetometer (an autopilot log's "
         "MAG or vehicle_magnetometer, imu.csv's mag_x..z), used only when the motion never shows the heading and "
         "no autopilot yaw is logged (default 0).")]
Vehicle = Annotated[VehicleChoice | None, typer.Option(  # type: ignore[valid-type]
    case_sensitive=False,
    help="auto (non-holonomic constraints when the motion shows a ground vehicle; default), ground (always) "
         "or air (never).")]
SbetRate = Annotated[float | None, typer.Option(
    "--sbet-rate", help="Record rate of --export sbet:FILE in Hz (the first IMU row of every 1/rate s of GPS time; "
                        "at most the IMU's rate). Default: every IMU row with a solution.")]
UtcDate = Annotated[str | None, typer.Option(
    "--utc-date", help="UTC date YYYY-MM-DD from whose 00:00 the times count, in seconds (POS.txt, imu.csv and "
                       "events.csv carry none): --export sbet needs it for GPS seconds of the week; image copies "
                       "take it for their GPS date stamp. Not needed where the inputs date themselves (an "
                       "autopilot log, an RTKLIB/Emlid .pos, Unix time stamps such as a bag's); given there, it "
                       "must agree.")]
BagFile = Annotated[Path | None, typer.Option(
    "--bag", help="A ROS 1 .bag file or a ROS 2 bag's folder (metadata.yaml with .db3 or .mcap): its sensor_msgs/Imu "
                  "[rad/s, m/s^2, REP 103 forward-left-up] and sensor_msgs/NavSatFix [deg, m above the WGS 84 "
                  "ellipsoid] in place of --imu and --gnss, on header.stamp's clock [s] (docs/rosbags.md).")]
ImuTopic = Annotated[str | None, typer.Option(
    "--imu-topic", help="The bag's sensor_msgs/Imu topic to read (default: the only one).")]
GnssTopic = Annotated[str | None, typer.Option(
    "--gnss-topic", help="The bag's sensor_msgs/NavSatFix topic to read (default: the only one).")]
ImagesFolder = Annotated[Path | None, typer.Option(
    "--images", help="Folder of the flight's photos (.jpg, .jpeg, .tif, .tiff) for --export images:DIR, which "
                     "writes geotagged copies of them into DIR (the photos are only read; docs/images.md).")]
CameraClockOffset = Annotated[float | None, typer.Option(
    "--camera-clock-offset", help="Camera clock minus UTC in seconds (e.g. 7200.25 for a clock on UTC+2 running "
                                  "0.25 s fast), for matching photos to exposures by capture time when the "
                                  "triggering is too regular to find it (default: estimated and reported).")]

# georef process's own options and arguments (one parameter each, so its signature stays one line per option)
PosArgument = Annotated[Path | None, typer.Argument(
    help="The flight's log: an autopilot log (ArduPilot .bin or .log, PX4 .ulg; the format is read from the "
         "content, gzip too) with its camera events, or a POS unit's POS.txt (with CAMERA). Leave it out with "
         "--imu/--gnss/--events or --bag/--events.", show_default=False)]
CameraArgument = Annotated[Path | None, typer.Argument(
    help="POS.txt's exposure times: Kamera.txt, or the camera's raw log (needs --camera-utc-offset).",
    show_default=False)]
EoOutput = Annotated[Path | None, output_option("EO table to write (default eo.csv); a .kml, .geojson or geo.txt "
                                                "name writes that format.")]
OutputFormat = Annotated[str | None, typer.Option(
    "--format", help="Format of -o: csv (the EO table), metashape, pix4d, odm (geo.txt), parge, geojson or kml; "
                     "metashape/pix4d/odm need --crs. Default: from -o's extension, else csv.")]
ProcessExport = Annotated[list[str] | None, typer.Option("--export", help="Also write FORMAT:FILE (metashape:ms.csv, "
                                                         "odm:geo.txt) or FILE with a .kml/.geojson/.csv extension; "
                                                         "repeatable. sbet:FILE writes the trajectory as an Applanix "
                                                         "SBET with its smrmsg_<name>.out (docs/sbet.md).")]
Height = Annotated[str | None, typer.Option("--height", help="Heights of the exports: ellipsoidal (WGS 84, "
                                            "default) or orthometric (EGM96 from PROJ's grid, or the vertical "
                                            "CRS of a compound --crs such as EPSG:3765+5773).")]
ImageNamesOption = Annotated[str | None, typer.Option("--image-names", help="Image file names: a pattern such as "
                                                      "IMG_{frame:04d}.JPG, or a CSV of frame,name.")]
CameraLeverArm = Annotated[str | None, typer.Option(
    help="IMU -> camera perspective centre lever arm X,Y,Z in metres, body frame.")]
Boresight = Annotated[str | None, typer.Option(help="Camera boresight R,P,Y in degrees (C_c_b = Rz(Y) Ry(P) Rx(R)).")]
GnssRate = Annotated[float | None, typer.Option(help="GNSS fix rate in Hz (default 1).")]
CameraUtcOffset = Annotated[float | None, typer.Option(
    help="UTC offset of the camera's local clock in hours (raw camera log only), e.g. 2 for UTC+2.")]
CameraTimeOffset = Annotated[float | None, typer.Option(
    help="Camera trigger latency in seconds, added to every exposure time (the exposure happened this long "
         "after its logged time); default 0.")]
CameraTimeSigma = Annotated[float | None, typer.Option(
    help="Standard deviation in seconds of every exposure time, after --camera-time-offset; it widens each "
         "camera position's sigma by the speed times it. Default: each source's own (0.002 s for a camera's "
         "feedback, 0.1 s for a trigger command, an events.csv time_sigma column).")]
Crs = Annotated[str | None, typer.Option(
    help="Projected CRS for easting/northing columns, e.g. EPSG:3765 (HTRS96/TM), or a compound CRS with its "
         "height system, e.g. EPSG:3765+5773 (with --height orthometric).")]
AttitudeSource = Annotated[str | None, typer.Option(
    help="Roll and pitch from the POS unit ('unit', default) or recomputed from the raw IMU ('imu').")]
Report = Annotated[Path | None, typer.Option(
    help="Also write the quality report here: one self-contained HTML file (docs/report.md).")]


def settings_given(table: dict[str, tuple[str, ...]], values: dict[str, Any]) -> dict[str, Any]:
    """The flight.toml settings a command's options give: ``table`` maps a flight.toml key to (option, parameter
    name[, unit of its three numbers]), ``values`` holds the parameters; :class:`georef.preflight.OptionValue`
    each, in ``table``'s order (the order they are checked in)."""
    from georef.preflight import OptionValue

    return {key: OptionValue(option, plain(values[name]), *unit) for key, (option, name, *unit) in table.items()}
